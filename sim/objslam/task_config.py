"""Settings of the grasp and placement tasks: the run config's ``[grasp]`` and ``[place]`` tables
(``--set grasp.contact_retries=0``, ``--set place.feel_support=false``). Placement grasps with the
run's ``[grasp]`` settings."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any


@dataclass
class GraspRunConfig:
    """Execution and judging settings of a grasp session."""

    lift_success_m: float = 0.10
    """The target must end this far above its start, metres (the issue's bar)."""
    hold_s: float = 1.0
    """Hold after the lift before judging, seconds."""
    close_s: float = 0.8
    """Time given to the fingers to close, seconds."""
    settle_s: float = 0.3
    """Settling after each trajectory, seconds (at most)."""
    disturb_m: float = 0.02
    """Before closing, an object displaced this far (x, y, z) means the arm collided, metres."""
    slip_rise_m: float = 0.02
    """The target rose at least this far during the lift: a failure is ``slipped``, not ``missed``."""
    match_radius_m: float = 0.08
    """Largest x-y distance between a map estimate and the true object it targets, metres."""
    reobserve: bool = False
    """Before each attempt, look at the target from close views and re-estimate it in a fresh local
    map (the core's pipeline, same settings as the exploration); the refined estimate is grasped.
    Default false: on the original scenes the close views did not beat the map's own estimate
    (``studies/grasp_reobserve/``)."""
    reobserve_views: str = "top"
    """``"top"``: two top-down views above the estimate (0.36 and 0.29 m); ``"top+oblique"``: a
    top-down view and two obliques from the robot's side."""
    reobserve_still_frames: int = 2
    """Extra frames rendered at each settled re-observation view."""
    reobserve_frame_rate_hz: float = 2.0
    """Frames fused while moving between re-observation views, per simulated second."""
    reobserve_obstacles: str = "local"
    """``"local"``: only the local map's objects are obstacles of the attempt (the close views cover
    the target's neighbourhood; far map objects, phantoms included, are ignored); ``"replace"``:
    the local objects replace the map's within ``reobserve_replace_m``, farther map objects stay."""
    reobserve_combine: str = "hybrid"
    """How the local estimate refines the map's (see :func:`combine`): ``"hybrid"`` or ``"local"``."""
    reobserve_register: bool = True
    """Express the local map in the exploration map's frame before using it: the local map runs its
    own SLAM, so all its objects share one calibration offset of its two views (several mm). The
    offset is the median x-y difference between local objects and the map objects they match
    (nearest centre within ``reobserve_register_pair_m``), the target excluded; with no neighbour
    in view it is the target's own difference (the map's centre is kept, the close views still
    give sizes and obstacles). Default true; false = the local map as it is."""
    reobserve_return_ready: bool = True
    """After the close views, return to the ready configuration before the grasp is planned (planned
    around the local objects and the refined target), so the grasp starts from the posture it has
    without re-observation: the close views leave the wrist wherever their camera roll put it, and
    a flipped hand yaw near joint 7's limit can take an unusual elbow. Default true; false = plan
    from the last close view."""
    reobserve_register_pair_m: float = 0.02
    """With ``reobserve_register``: a local object and its nearest map neighbour farther apart than
    this (x-y, metres) do not enter the offset. The offset is two views' calibration bias (a few mm,
    p90 8.7 mm measured); a larger difference is an object the close views saw only in part at the
    image border (scene02 seed 8: a book 22 cm from the target estimated 4.8 cm off, which shifted
    the target 3.6 cm and the grasp collided)."""
    reobserve_height_m: float = 0.36
    """Height of the top-down re-observation view above the target's estimated centre, metres."""
    reobserve_offset_m: float = 0.20
    """Horizontal offset of the two oblique re-observation views, metres."""
    reobserve_match_m: float = 0.06
    """A local-map object within this x-y distance of the map estimate is the refined target."""
    reobserve_replace_m: float = 0.15
    """Map objects within this x-y distance of the refined target are replaced, as obstacles, by
    the local map's objects (the close views see that neighbourhood), metres."""
    contact_retries: int = 2
    """Beyond the paper: a finger that lands on something during the approach (an upward force of at
    least ``contact_force_n`` on a finger: it came down on the target's rim, the map's centre being
    off by more than the fingers' clearance) stops the descent; the hand backs up
    ``contact_backoff_m``, the target's estimate moves towards the touched side by the clearance the
    plan left on each side plus ``contact_extra_shift_m`` (the least the centre must be off for that
    finger to land on the object) and a fresh grasp plan from there descends again, at most this many
    times per attempt; with no retry left, or no plan for the moved estimate, the hand goes on down as
    planned. Default 2; 0 = the approach is executed blind."""
    contact_force_n: float = 5.0
    """Rise of the upward external force within ``contact_window_s`` that, with the hand stalled,
    stops the approach, newtons."""
    contact_window_s: float = 0.05
    """Window over which the force's rise is measured, seconds (a rise, not a level: the wrench
    estimate carries the joints' friction, tens of newtons, drifting slowly; ``PlaceConfig.feel_support``)."""
    contact_lag_m: float = 0.008
    """The hand has stalled when its TCP (forward kinematics of the readings) is this far above the
    commanded TCP (of the drive targets), metres. On scene03's 7.4 cm cup with the map centre 5 mm off
    (``tests/test_grasp.py``), 4 mm also fired on the re-descent after the first shift (a second, false
    touch: the hand ended 3 mm off); 8 and 15 mm felt the rim once and grasped 1 mm from the centre."""
    min_held_gap_m: float = 0.005
    """After the lift and hold, fingers stopped at least this far apart hold something: the attempt
    is felt as a grasp, metres (the narrowest benchmark object is ~3 cm)."""
    duplicate_margin_m: float = 0.01
    """A map object whose centre lies within the footprint (plus this, metres) of a map object the
    hand grasped earlier, and whose footprint holds that object's centre, is taken for the same
    object and skipped."""
    contact_backoff_m: float = 0.015
    """How far the hand rises after a touch before it moves sideways, metres."""
    contact_extra_shift_m: float = 0.001
    """Sideways move beyond the planned clearance per side after a touch, metres."""
    defer_unreachable: bool = True
    """An object the planner finds no collision-free grasp or path for (``no_ik`` / ``no_path``:
    nothing moved) is put back in the queue and planned again after the next executed attempt, when
    a neighbour may have been set aside; it is reported ``no_ik`` / ``no_path`` only if it is still
    unreachable when no executed attempt is left. Every object still gets at most one physical
    attempt; rows record how often it was deferred (``deferred``)."""
    fallback_last: bool = True
    """The planner's fallback grasps (``narrow_opening_fallback``: closing axes tilted and TCPs off
    the centre, fingers opened to the width plus ``narrow_opening_clearance_m``, for a block whose
    neighbours leave no room beside it) are planned only for the objects still deferred when no
    executed attempt is left: setting a neighbour aside first frees a regular grasp. After the next
    executed attempt the regular planner is tried again. False: the planner's own config decides."""
    planner: dict[str, Any] = field(
        default_factory=lambda: {"opening_clearance_m": 0.08, "max_grasp_depth_m": 0.04}
    )
    """Overrides of the core planner's config (keys in ``Planner``'s stub docs). Default: open the
    fingers fully (the most room for a centre error; the opening is capped at 8 cm) and grasp up to
    4 cm below the estimated top (room for a height error; the palm is ~5.8 cm above the pads)."""


@dataclass
class PlaceConfig:
    """Placement settings."""

    slot_spacing_m: float = 0.10
    """Distance between neighbouring slots of a line, metres."""
    tall_slot_spacing_m: float = 0.20
    """Slot spacing when the tallest item of the line is at least ``tall_item_height_m`` (estimated):
    the hand holds a tall item 4 cm below its top, so its body comes down beside a standing
    neighbour taller than the fingers and knocked it over at 10 cm (bottles_by_height 0/6 with
    10 cm, 4/6 with 20 cm on the maps of reports/grasping; cups keep 10 cm)."""
    tall_item_height_m: float = 0.14
    """Estimated height from which an item counts as tall, metres."""
    slot_clearance_m: float = 0.02
    """A slot is free when no map object's footprint comes closer than this to the item standing
    there (the line's widest estimated footprint), metres."""
    slot_tolerance_m: float = 0.04
    """A true object counts as at its slot within this x-y distance, metres."""
    preplace_height_m: float = 0.12
    """Pre-place pose above the place pose, metres."""
    release_gap_m: float = 0.01
    """The held object's estimated bottom stops this far above its support, metres."""
    tall_release_gap_m: float = 0.005
    """The release gap of a tall item (estimated height ≥ ``tall_item_height_m``): a 21.5 cm bottle
    5.2 cm wide dropped from 1 cm landed rocking, leaned on the opened fingers as they rose and
    fell over (bottles_by_height 9/12 with 1 cm on the maps of reports/grasping, 12/12 with 5 mm;
    cups and blocks keep 1 cm: with 5 mm the later grasps of a cups_by_volume run started from
    other arm configurations and one finger met a cup with 3 mm of clearance: 7/8)."""
    feel_support: bool = True
    """Beyond the paper: the descent stops ``feel_start_m`` above the release-gap pose and the hand
    goes on down slowly until it feels the support through the held item, then lets go there
    (nothing felt ``feel_depth_m`` below the release-gap pose: it lets go at the end; no slow
    descent plannable: it goes on to the release gap as without). The sense is the hand stalling
    while the upward force of :meth:`~objslam.world.SimWorld.external_wrench` rises by
    ``feel_force_n`` within ``feel_window_s`` (a guarded move). A rise, not a level: the estimate
    carries the joints' friction (PhysX joint friction, proportional to the joint loads), which it
    does not model: 17-66 N of apparent upward force in the middle of the descent before, 38-139 N
    held at the start of the slow descent, drifting by up to 2.6 N per 0.05 s during it (six slow
    descents: scene04 seed 8's bottles, scene03 seed 0's cups, on their maps). When the item
    meets its support the rise over the window is 4.3-77 N (medians: blocks 8, cups 8, bottles
    22; ``reports/placement.json``). Default true; false: let go at the release gap."""
    feel_start_m: float = 0.01
    """The slow descent starts this far above the release-gap pose, metres."""
    feel_depth_m: float = 0.02
    """The slow descent ends this far below the release-gap pose, metres."""
    feel_speed_m_s: float = 0.02
    """Speed of the slow descent, m/s."""
    feel_window_s: float = 0.05
    """Stall and force rise are measured over this window, seconds."""
    feel_stall_ratio: float = 0.5
    """The TCP has stalled when it descends less than this fraction of the commanded descent."""
    feel_armed_m: float = 0.001
    """Contact is sensed only once the TCP has descended this far: at the start the arm stands
    still until its drives overcome the joints' static friction (15-31 physics steps in seven slow
    descents of scene04 seed 8, scene03 seed 0 and scene02 seed 0), metres."""
    feel_stuck_m: float = 0.012
    """Not armed when this much descent has been commanded: the item stands on its support already,
    let go, metres. The breakaway above takes 1.3-2.6 mm of commanded descent. A slow descent
    planned from the measured joints instead of the planned end of the descent before it starts
    without the drives' preload and took 4.7-7.4 mm (six descents of scenes 02, 04, 05, 07, seed 0);
    with this at 5 mm, 53 of 161 descents stopped as stuck, the hand still 1-2 cm above the support."""
    feel_force_n: float = 4.0
    """Rise of the upward force within ``feel_window_s`` that means the item stands on its support,
    newtons."""
    clear_blockers: bool = True
    """``block_in_cup``: when the chosen block has no collision-free grasp, the neighbour without
    which it would have one is first put down elsewhere on the table (:meth:`Placer.move_aside`)."""
    place_yaw_rad: float = math.pi / 2
    """Hand yaw when putting an item down (π/2: fingers closing along x, so the 20 cm hand body lies
    across a line along y, not toward the neighbouring slots); the grasp's yaw is the fallback."""
