"""Grasping from an object map in SAPIEN: plan with the core's planner, execute, judge from ground truth.

Entry point: :func:`run_grasp_session` — a fresh :class:`~objslam.world.SimWorld` of the scene with
the grasp physics settings, then every map object in turn: ``Planner.plan_grasp`` (from the map
estimates only: the target's estimate, the other estimates as obstacles) → fingers open to the
planned width → pre-grasp trajectory → approach → close → lift → hold → judge from the simulator's
ground truth → the grasped object is set aside (removed from the scene and from the obstacles) →
open, back to the ready configuration, next object. An object the planner cannot reach among
its neighbours is deferred until an executed attempt has changed the scene
(``defer_unreachable``: the order a robot clearing a table would take). Results: one row per attempt (and per
ground-truth graspable object the map gave no attempt for), written by the caller.

Choices (config fields of :class:`GraspRunConfig`):
- Success: the target's true centre ends ≥ ``lift_success_m`` (0.10 m) above where it started, after
  the lift and a ``hold_s`` (1 s) hold with the fingers squeezing.
- The target of an attempt in ground truth: the true object whose centre is nearest (in x, y) to the
  map estimate's centre, within ``match_radius_m``; none → a phantom attempt (counts as missed).
- Causes: ``no_ik`` / ``no_path`` / ``too_wide`` (planner), ``collided`` (before closing, the target
  or another object moved more than ``disturb_m``, or the arm was blocked), ``missed`` (the fingers
  closed without lifting the target ≥ ``slip_rise_m``), ``slipped`` (the target rose ≥ ``slip_rise_m``
  but did not stay ≥ ``lift_success_m`` up), ``not_in_map`` (a graspable true object no map object
  matches), ``phantom`` (an attempt on a map object with no true object near it), ``not_found``
  (with re-observation: the close views found no object at the map's estimate; for phantoms this
  is the right call and the row is skipped, not an attempt), ``wrong_object`` (another true object
  was lifted). A map object no true object is matched to that, on the attempt, lifts exactly one
  true object is a duplicate resolved by the grasp: a success for that object (whose own map
  object is then skipped as ``already_grasped``). Success rows have cause ``"none"``.
- Graspable in ground truth: narrowest horizontal width ≤ the gripper's 8 cm opening minus 4 mm.
  Map objects the planner finds too wide are attempts only when their true object is graspable.
- Touches (``contact_retries``, beyond the paper): the hand senses only what a Panda senses — its
  external wrench estimate (:meth:`~objslam.world.SimWorld.external_wrench`, from the joint
  torques) and its joint readings, never the simulator's contact points. A finger that lands on
  something during the approach (the target's rim when the map's centre is off by more than the
  fingers' clearance) stalls the hand: its TCP lags the commanded one by ``contact_lag_m`` while the
  upward force rises by ``contact_force_n`` within ``contact_window_s``; the rise's moment about the
  TCP says on which side along the closing axis it pushes. The descent stops; the hand backs up,
  moves towards the touched side by the planned clearance + 1 mm (the least the centre can be off
  for that finger to land on the object) and descends again. The target's centre (for placing)
  moves with the hand.
- Ground truth only judges: the loop decides from the map and from what the hand senses. An
  attempt the hand feels as a grasp (the closed fingers stopped at least ``min_held_gap_m`` apart
  after the lift) removes its map object from the obstacles; a later map object that shares its
  place with one grasped so (each centre in the other's footprint plus ``duplicate_margin_m``) is
  taken for the same object and skipped (``already_grasped``; judged ``wrongly_skipped`` when its true object was never lifted).
  What the hand holds is set aside (the simulator removes the objects that actually left the table
  with it). The true poses enter only the outcome: success, cause, ``lifted``, ``not_in_map``, and
  whether a too-wide map object counts as an attempt.
- The simulated robot is the episode's (``[robot]``: hand-eye, joint offsets, timing errors drawn
  from the run and scene seeds, :mod:`objslam.calibration`), and the objects' masses and friction are
  those of ``[contact]``.
- Re-observation (``reobserve``, off by default): before each attempt, close views of the target
  (``reobserve_views``: two top-down by default, or top-down and two obliques) are fused into a
  fresh local map by the core's pipeline (same settings as the exploration); the local object
  nearest the map estimate is grasped (optionally registered to the map first), the local objects
  are the obstacles, and the arm returns to its ready posture before the grasp is planned. The
  exploration map itself is not updated.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import numpy as np

from . import _native
from .calibration import (
    STREAM_GRASP_DETECTOR,
    STREAM_GRASP_SENSOR,
    arm_error_seed,
    draw_arm_errors,
    episode_rng,
)
from .camera_path import look_at
from .config import RunConfig
from .detector import SimulatedDetector
from .scene import SceneSpec, gt_objects
from .task_config import GraspRunConfig
from .world import (
    GRIPPER_OPEN_M,
    PHYSICS_HZ,
    READY_QPOS,
    MotionError,
    SimWorld,
    UnreachablePoseError,
    panda_urdf_path,
)

#: Planning outcomes after which an object is deferred (see ``GraspRunConfig.defer_unreachable``).
DEFERRABLE = ("no_ik", "no_path")

#: Largest graspable width (gripper 8 cm minus the planner's 4 mm minimum clearance), metres.
MAX_GRASP_WIDTH_M = 0.076


def narrowest_width(geometry: dict[str, Any]) -> float:
    """Narrowest horizontal width of an ObjectGeometry dict, metres."""
    h = geometry["half_extents"]
    return 2.0 * (min(h[0], h[1]) if geometry["shape"] == "cuboid" else (h[0] + h[1]) / 2.0)


class GraspSession:
    """One simulated world and the planner, executing grasps of map objects."""

    def __init__(self, scene: SceneSpec, run_cfg: RunConfig, cfg: GraspRunConfig, rec: Any = None) -> None:
        self.scene = scene
        self.cfg = cfg
        self.run_cfg = run_cfg
        seed = run_cfg.seed
        # The same robot as the mapping episode of this run and scene (its calibration errors).
        self.arm = draw_arm_errors(run_cfg.robot, arm_error_seed(seed, scene.seed))
        self.world = SimWorld(
            scene,
            run_cfg.camera,
            episode_rng(seed, scene.seed, STREAM_GRASP_SENSOR),
            grasp_physics=True,
            arm_errors=self.arm,
            contact=run_cfg.contact,
        )
        self.detector = SimulatedDetector(run_cfg.detector, episode_rng(seed, scene.seed, STREAM_GRASP_DETECTOR))
        planner_cfg = {"rng_seed": int(seed) + 1, **cfg.planner}
        self.fallback_planner: Any = None
        """The planner with fallback grasps, for the last round of deferred objects
        (``GraspRunConfig.fallback_last``); None when the regular planner decides alone."""
        if cfg.fallback_last and planner_cfg.get("narrow_opening_fallback", True):
            self.fallback_planner = _native.Planner(str(panda_urdf_path()), json.dumps(planner_cfg))
            planner_cfg = {**planner_cfg, "narrow_opening_fallback": False}
        self.planner = _native.Planner(str(panda_urdf_path()), json.dumps(planner_cfg))
        self.grasp_planner = self.planner
        """The planner of the current attempt's grasps (regular or fallback)."""
        self.limits = self.planner.joint_limits()
        self.rec = rec
        self.removed: set[int] = set()
        self.frame = 0
        self.last_plan: dict[str, Any] | None = None
        """The grasp plan of the last executed attempt (for placing)."""
        self.last_target: dict[str, Any] | None = None
        """The (refined) map object of the last executed attempt."""

    # ----- low-level execution ---------------------------------------------------------------------
    def q_arm(self) -> np.ndarray:
        """Measured arm joints, clipped into the URDF limits (the planner rejects values outside)."""
        q = self.world.qpos()[:7]
        return np.clip(q, self.limits[:, 0], self.limits[:, 1])

    def finger_gap_m(self) -> float:
        """Gap between the fingers (sum of both finger joints), metres."""
        q = self.world.qpos()
        return float(q[7] + q[8])

    def execute(
        self,
        traj: dict[str, Any],
        finger_m: float,
        on_step: Callable[[], None] | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> float:
        """Track a planned joint trajectory (:meth:`SimWorld.track`), then settle; returns the final
        joint error, rad. ``stop`` (checked after every physics step): when it returns True the arm
        holds where it is (it settles there) and the error is measured from that posture."""
        goal = np.asarray(traj["positions"], dtype=np.float64)[-1]
        for _ in self.world.track(traj, finger_m):
            if on_step is not None:
                on_step()
            if stop is not None and stop():
                goal = self.world.qpos()[:7].copy()
                self.world.set_arm_targets(goal, finger_m)
                break
        for _ in range(int(self.cfg.settle_s * PHYSICS_HZ)):
            self.world._step()
            if on_step is not None:
                on_step()
            if float(np.max(np.abs(self.world.qpos()[:7] - goal))) < 2e-3:
                break
        return float(np.max(np.abs(self.world.qpos()[:7] - goal)))

    def hold(self, seconds: float, finger_m: float, on_step: Callable[[], None] | None = None) -> None:
        """Keep the current arm targets and the finger target for ``seconds``."""
        q = self.world.qpos()[:7]
        self.world.set_arm_targets(q, finger_m)
        for _ in range(int(seconds * PHYSICS_HZ)):
            self.world._step()
            if on_step is not None:
                on_step()

    def gt_positions(self) -> dict[int, np.ndarray]:
        """True object centres now (objects set aside excluded). Judging only."""
        return {oid: p for oid, (p, _) in self.world.ground_truth().items() if oid not in self.removed}

    def set_aside(self, oid: int) -> None:
        """Remove a grasped object from the scene (it is 'set aside')."""
        actor = self.world.object_actors.pop(oid)
        self.world.scene.remove_entity(actor)
        self.removed.add(oid)

    def go_ready(self, obstacles: list[dict[str, Any]]) -> None:
        """Open the fingers and return to the ready configuration (planned around the map objects,
        else around the table only)."""
        self.hold(0.3, GRIPPER_OPEN_M)
        for obs in (obstacles, []):
            r = self.planner.plan_to_joints(self.q_arm(), READY_QPOS[:7], json.dumps(obs))
            if r["ok"]:
                self.execute(r, GRIPPER_OPEN_M)
                return

    # ----- recording -------------------------------------------------------------------------------
    def _log(self, fn: str, *args: Any) -> None:
        if self.rec is not None:
            getattr(self.rec, fn)(*args)

    def _log_plan(self, k: int, plan: dict[str, Any]) -> None:
        if self.rec is None:
            return
        self.rec.set_frame(self.frame, self.world.sim_time_s)
        for part in ("to_pregrasp", "approach", "lift"):
            pts = np.array([self.planner.forward_tcp(q)[:3, 3] for q in plan[part]["positions"][::5]])
            self.rec.log_points(f"world/grasp/{k}/{part}", pts, None)
        g = plan["world_from_tcp_grasp"]
        o = np.repeat(g[None, :3, 3], 3, axis=0)
        v = 0.08 * g[:3, :3].T
        self.rec.log_arrows(f"world/grasp/{k}/frame", o, v, np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], dtype=np.uint8))

    # ----- re-observation ---------------------------------------------------------------------------
    def reobserve(
        self, target: dict[str, Any], neighbours: list[dict[str, Any]] = ()
    ) -> tuple[dict[str, Any] | None, list[dict[str, Any]], int]:
        """Close views of ``target`` (top-down, then two obliques from the robot's side) fused into a
        fresh local map; returns the local object that refines the target (nearest centre within
        ``reobserve_match_m``, same label first) or None, all local objects, and the frames used."""
        from .episode import new_mapper

        cfg, rc = self.cfg, self.run_cfg
        mapper = new_mapper(rc, self.scene)
        c = np.array(target["geometry"]["center"], dtype=float)
        c[2] = 0.5 * c[2]
        side = -1.0 if c[1] > 0 else 1.0
        if cfg.reobserve_views == "top":
            # Straight above the estimate from two heights: every side is seen alike, so the centre
            # is not pulled toward the camera.
            eyes = [c + [0.0, 0.0, cfg.reobserve_height_m], c + [0.0, 0.0, cfg.reobserve_height_m - 0.07]]
        else:
            eyes = [
                c + [0.0, 0.0, cfg.reobserve_height_m],
                c + [-cfg.reobserve_offset_m, 0.0, cfg.reobserve_height_m - 0.05],
                c + [0.0, side * cfg.reobserve_offset_m, cfg.reobserve_height_m - 0.05],
            ]
        frames = 0
        for vi, eye in enumerate(eyes):
            top = cfg.reobserve_views == "top" or vi == 0
            # The camera's roll about its axis decides reachability (joint 7 limits): try four.
            hints = [np.array(h, dtype=float) for h in ((1, 0, 0), (0, 1, 0), (0, -1, 0), (-1, 0, 0))] if top else [None]
            view = None
            for h in hints:
                v = look_at(eye, c, h)
                if self.world.is_reachable(v):
                    view = v
                    break
            if view is None:
                continue
            try:
                moved = list(
                    self.world.move_camera_to(
                        view,
                        frame_rate_hz=cfg.reobserve_frame_rate_hz,
                        max_joint_speed=rc.max_joint_speed,
                        what="re-observation",
                    )
                )
            except (UnreachablePoseError, MotionError):
                continue
            # A few more frames from the settled view (fresh sensor noise and detector draws), so a
            # short move still gives the pipeline enough observations to confirm the object.
            for frame in moved + [self.world.render() for _ in range(cfg.reobserve_still_frames)]:
                dets = self.detector.detect(frame.segmentation, self.world.actor_to_object)
                mapper.update(
                    index=frames,
                    intrinsics=frame.intrinsics,
                    depth=frame.depth_m,
                    world_from_camera=self.arm.prior(frame.world_from_camera_fk, vi, frame.index),
                    detections=[d.as_tuple() for d in dets],
                    grey=frame.rgb if (rc.map["parameterize"] or rc.pose_source != "fk") else None,
                    world_from_camera_gt=frame.world_from_camera_gt,
                    view_index=vi,
                )
                frames += 1
            mapper.view_done(False)
        mapper.refresh_estimates()
        local = json.loads(mapper.objects_json())
        if cfg.reobserve_register and local:
            local = register_local(
                local, target, list(neighbours), cfg.reobserve_match_m, cfg.reobserve_register_pair_m
            )
        best = None
        for o in local:
            d = math.dist(o["geometry"]["center"][:2], target["geometry"]["center"][:2])
            if d > cfg.reobserve_match_m:
                continue
            key = (o["label"] != target["label"], d)
            if best is None or key < best[0]:
                best = (key, o)
        return (best[1] if best else None), local, frames

    # ----- contact during the approach ---------------------------------------------------------------
    def touch_sensor(self) -> Callable[[], np.ndarray | None]:
        """A fresh touch detector for one motion (call it after every physics step): where the hand
        feels an upward push — the TCP lags the commanded TCP by ``contact_lag_m`` while the upward
        external force has risen by ``contact_force_n`` within ``contact_window_s`` — as a world point
        (the TCP moved by the rise's moment arm, ``r = (−Δm_y, Δm_x) / Δf_z``), else None."""
        cfg, world = self.cfg, self.world
        window = max(1, round(cfg.contact_window_s * PHYSICS_HZ))
        history: list[np.ndarray] = []

        def sense() -> np.ndarray | None:
            w = world.external_wrench()
            history.append(w)
            if len(history) <= window:
                return None
            dw = w - history[-1 - window]
            rise = float(dw[2])
            if rise < cfg.contact_force_n:
                return None
            tcp = self.planner.forward_tcp(self.q_arm())
            commanded = self.planner.forward_tcp(np.clip(world.arm_targets(), self.limits[:, 0], self.limits[:, 1]))
            if float(tcp[2, 3] - commanded[2, 3]) < cfg.contact_lag_m:
                return None
            return np.array([tcp[0, 3] - float(dw[4]) / rise, tcp[1, 3] + float(dw[3]) / rise, tcp[2, 3]])

        return sense

    def approach(
        self, plan: dict[str, Any], target: dict[str, Any], neighbours: list[dict[str, Any]], open_half: float
    ) -> tuple[float, dict[str, Any], dict[str, Any], list[float]]:
        """Execute the plan's approach; on a touch (``GraspRunConfig.contact_retries``) back up,
        move the target's estimate towards the touched side and grasp it with a fresh plan from
        there; with no retry left or none plannable, go on down as planned (the blind approach).
        Returns the final joint error, the plan and target as grasped (the target's centre moved by
        the shifts) and the signed shifts along the closing axis, metres (empty: no touch)."""
        cfg = self.cfg
        touched: list[np.ndarray] = []

        def stopper() -> Callable[[], bool]:
            sense = self.touch_sensor()

            def stop() -> bool:
                p = sense()
                if p is not None:
                    touched.append(p)
                    return True
                return False

            return stop

        err = self.execute(plan["approach"], open_half, stop=stopper() if cfg.contact_retries > 0 else None)
        shifts: list[float] = []
        obs = json.dumps([n["geometry"] for n in neighbours])
        while touched:
            p = touched.pop()
            tcp = self.planner.forward_tcp(self.q_arm())
            if len(shifts) < cfg.contact_retries:
                axis = np.asarray(plan["world_from_tcp_grasp"], dtype=np.float64)[:3, 1]  # the closing axis
                clearance = 0.5 * (float(plan["open_width_m"]) - float(plan["expected_closed_width_m"]))
                side = 1.0 if float(np.dot(p - tcp[:3, 3], axis)) > 0.0 else -1.0
                shift = side * (max(clearance, 0.0) + cfg.contact_extra_shift_m)
                c = np.array(target["geometry"]["center"], dtype=np.float64)
                c[:2] += shift * axis[:2]
                moved = {**target, "geometry": {**target["geometry"], "center": c.tolist()}}
                up = tcp.copy()
                up[2, 3] += cfg.contact_backoff_m
                r = self.planner.plan_to_pose(self.q_arm(), up, obs, linear=True)
                if r["ok"]:
                    self.execute(r, open_half)
                # A fresh plan for the moved target from here: its own pre-grasp, approach and lift.
                g = self.grasp_planner.plan_grasp(self.q_arm(), json.dumps(moved["geometry"]), obs)
                if g["ok"]:
                    shifts.append(round(shift, 5))
                    plan, target = g, moved
                    self.execute(plan["to_pregrasp"], open_half)
                    err = self.execute(plan["approach"], open_half, stop=stopper())
                    continue
            # No retry left (or none plannable): go on down as planned, as a blind approach would.
            r = self.planner.plan_to_pose(self.q_arm(), np.asarray(plan["world_from_tcp_grasp"], dtype=np.float64), obs, linear=True)
            if r["ok"]:
                err = self.execute(r, open_half)
            break
        return err, plan, target, shifts

    # ----- one attempt ------------------------------------------------------------------------------
    def attempt(
        self,
        k: int,
        target: dict[str, Any],
        neighbours: list[dict[str, Any]],
        gt_id: int | None,
        fallback: bool = False,
    ) -> dict[str, Any]:
        """Plan and execute one grasp of map object ``target`` (``fallback``: with the planner's
        fallback grasps, :attr:`fallback_planner`); returns the outcome record: what the
        hand sensed (``held``, ``closed_gap_m``, ``held_gap_m``, ``contact_shifts_m``) and, judged from
        the ground truth (``gt_id``: the true object the judge matched to the target; it never steers
        the attempt), ``success``, ``cause``, ``rise_m``, ``lifted``."""
        cfg = self.cfg
        out: dict[str, Any] = {"success": False, "cause": None, "gt_id": gt_id}
        if cfg.reobserve:
            refined, local, frames = self.reobserve(target, neighbours)
            out.update(reobserved=refined is not None, reobserve_frames=frames)
            if refined is None:
                # Nothing there on a close look: the map object was a phantom (or has gone).
                out.update(cause="not_found", skipped=gt_id is None)
                return out
            target = {**target, "geometry": combine(target["geometry"], refined["geometry"], cfg)}
            # Near the target the close views know better: their objects replace the map's there.
            c = target["geometry"]["center"]
            near = [n for n in local if n["id"] != refined["id"]]
            far = [
                n for n in neighbours if math.dist(n["geometry"]["center"][:2], c[:2]) > cfg.reobserve_replace_m
            ]
            neighbours = near if cfg.reobserve_obstacles == "local" else far + near
            out["target_geometry"] = target["geometry"]
            if cfg.reobserve_return_ready:
                self.go_ready([n["geometry"] for n in neighbours] + [target["geometry"]])
        self.grasp_planner = self.fallback_planner if fallback and self.fallback_planner else self.planner
        plan = self.grasp_planner.plan_grasp(
            self.q_arm(), json.dumps(target["geometry"]), json.dumps([n["geometry"] for n in neighbours])
        )
        if not plan["ok"]:
            out.update(cause=plan["cause"], message=plan["message"])
            return out
        self._log_plan(k, plan)
        self.last_plan, self.last_target = plan, target
        open_half = float(plan["open_width_m"]) / 2.0
        out.update(
            open_width_m=float(plan["open_width_m"]),
            expected_closed_width_m=float(plan["expected_closed_width_m"]),
            hand_yaw_rad=float(plan["hand_yaw_rad"]),
        )
        start = self.gt_positions()
        # Open the fingers while moving to the pre-grasp pose.
        err_pre = self.execute(plan["to_pregrasp"], open_half)
        err_app, plan, target, touches = self.approach(plan, target, neighbours, open_half)
        if touches:
            out["contact_shifts_m"] = touches
            self._log_plan(k, plan)
            self.last_plan, self.last_target = plan, target
        now = self.gt_positions()
        moved = {oid: float(np.linalg.norm(now[oid] - start[oid])) for oid in start}
        collided = max(err_pre, err_app) > 0.02 or any(d > cfg.disturb_m for d in moved.values())
        out["disturbed"] = {str(o): round(d, 4) for o, d in moved.items() if d > cfg.disturb_m}
        # Close.
        self.hold(cfg.close_s, 0.0)
        out["closed_gap_m"] = self.finger_gap_m()
        z0 = start[gt_id][2] if gt_id is not None else 0.0
        max_rise = [0.0]

        def track() -> None:
            if gt_id is not None:
                max_rise[0] = max(max_rise[0], float(self.gt_positions()[gt_id][2] - z0))

        self.execute(plan["lift"], 0.0, track)
        self.hold(cfg.hold_s, 0.0, track)
        now = self.gt_positions()
        rise = float(now[gt_id][2] - z0) if gt_id is not None else 0.0
        lifted = [oid for oid in now if oid in start and now[oid][2] - start[oid][2] >= cfg.lift_success_m]
        held_gap = self.finger_gap_m()
        out.update(
            rise_m=rise, max_rise_m=max_rise[0], held_gap_m=held_gap, held=held_gap >= cfg.min_held_gap_m, lifted=lifted
        )
        if gt_id is not None and rise >= cfg.lift_success_m:
            out.update(success=True, cause="none")
        elif gt_id is None and len(lifted) == 1:
            # A map object no true object was matched to (a duplicate of one matched to another map
            # object) turned out to be that object: it was grasped and lifted.
            out.update(success=True, cause="none", gt_id=lifted[0], resolved_duplicate=True)
        elif gt_id is None:
            out["cause"] = "phantom"  # no true object where the map put one
        elif lifted:
            out["cause"] = "wrong_object"
        elif collided:
            out["cause"] = "collided"
        elif max_rise[0] >= cfg.slip_rise_m:
            out["cause"] = "slipped"
        else:
            out["cause"] = "missed"
        self.frame += 1
        self._log("set_frame", self.frame, self.world.sim_time_s)
        self._log("log_scalar", "grasp/finger_gap_m", out["closed_gap_m"])
        return out


def register_local(
    local: list[dict[str, Any]],
    target: dict[str, Any],
    neighbours: list[dict[str, Any]],
    match_m: float,
    pair_max_m: float = math.inf,
) -> list[dict[str, Any]]:
    """The local objects shifted in x-y by minus their calibration offset against the map (see
    ``GraspRunConfig.reobserve_register``): the median over local objects matched to a map
    neighbour (nearest centre within ``match_m`` and ``pair_max_m``), else the local object nearest the target
    (within ``match_m``) against the target. No match at all: unchanged."""

    def xy(o: dict[str, Any]) -> np.ndarray:
        return np.asarray(o["geometry"]["center"][:2], dtype=float)

    def nearest(o: dict[str, Any], pool: list[dict[str, Any]], radius: float) -> dict[str, Any] | None:
        best = min(pool, key=lambda m: float(np.linalg.norm(xy(m) - xy(o))), default=None)
        return best if best is not None and float(np.linalg.norm(xy(best) - xy(o))) <= radius else None

    t_local = nearest(target, local, match_m)
    pair_radius = min(match_m, pair_max_m)
    diffs = []
    for o in local:
        if o is t_local:
            continue
        m = nearest(o, neighbours, pair_radius)
        if m is not None:
            diffs.append(xy(o) - xy(m))
    if diffs:
        off = np.median(np.array(diffs), axis=0)
    elif t_local is not None:
        off = xy(t_local) - xy(target)
    else:
        return local
    out = []
    for o in local:
        g = dict(o["geometry"])
        g["center"] = [g["center"][0] - float(off[0]), g["center"][1] - float(off[1]), *g["center"][2:]]
        out.append({**o, "geometry": g})
    return out


def combine(mapped: dict[str, Any], local: dict[str, Any], cfg: GraspRunConfig) -> dict[str, Any]:
    """The target geometry grasped after re-observation (``cfg.reobserve_combine``):
    ``"local"`` = the local estimate as is; ``"hybrid"`` = centre x-y and yaw from the close
    top-down views (accurate there), horizontal size the larger of both unless the map's is too
    wide for the gripper, top height from the map (top-down views see little of the sides), and
    the bottom on the table (objects stand on it)."""
    if cfg.reobserve_combine == "local":
        return local
    mh, lh = mapped["half_extents"], local["half_extents"]
    if narrowest_width(mapped) <= MAX_GRASP_WIDTH_M:
        hx, hy = max(mh[0], lh[0]), max(mh[1], lh[1])
        if mapped["shape"] == "cuboid" and local["shape"] == "cuboid":
            # Same sides after the yaw change (the local yaw may be off by 90 degrees).
            d = abs(math.remainder(local["yaw_rad"] - mapped["yaw_rad"], math.pi))
            if d > math.pi / 4:
                hx, hy = max(mh[1], lh[0]), max(mh[0], lh[1])
    else:
        hx, hy = lh[0], lh[1]
    top = mapped["center"][2] + mh[2]
    hz = max(top / 2.0, 0.005)
    return {
        "shape": local["shape"],
        "center": [local["center"][0], local["center"][1], hz],
        "yaw_rad": local["yaw_rad"],
        "half_extents": [hx, hy, hz],
    }


def in_footprint(obj: dict[str, Any], other: dict[str, Any], margin_m: float) -> bool:
    """Whether map object ``obj``'s centre lies in ``other``'s footprint grown by ``margin_m`` (x-y;
    a box in its own yaw, a cylinder's disc)."""
    g, c = other["geometry"], np.asarray(obj["geometry"]["center"][:2], dtype=float)
    d = c - np.asarray(g["center"][:2], dtype=float)
    h = g["half_extents"]
    if g["shape"] == "cylinder":
        return float(np.linalg.norm(d)) <= (h[0] + h[1]) / 2.0 + margin_m
    ca, sa = math.cos(g["yaw_rad"]), math.sin(g["yaw_rad"])
    local = (ca * d[0] + sa * d[1], -sa * d[0] + ca * d[1])
    return abs(local[0]) <= h[0] + margin_m and abs(local[1]) <= h[1] + margin_m


def same_place(a: dict[str, Any], b: dict[str, Any], margin_m: float) -> bool:
    """Whether map objects ``a`` and ``b`` describe one object: each centre lies in the other's
    footprint grown by ``margin_m`` (an oversized estimate's footprint reaches its neighbours'
    centres, but their footprints do not reach its centre)."""
    return in_footprint(a, b, margin_m) and in_footprint(b, a, margin_m)


def match_gt(map_objects: list[dict[str, Any]], gt: list[dict[str, Any]], radius_m: float) -> dict[int, int | None]:
    """Map object id → the true object id it targets (nearest centre in x-y within ``radius_m``;
    each true object at most once, closest pairs first)."""
    pairs = []
    for m in map_objects:
        for g in gt:
            d = math.dist(m["geometry"]["center"][:2], g["geometry"]["center"][:2])
            if d <= radius_m:
                pairs.append((d, m["id"], g["id"]))
    out: dict[int, int | None] = {m["id"]: None for m in map_objects}
    used: set[int] = set()
    for _, mid, gid in sorted(pairs):
        if out[mid] is None and gid not in used:
            out[mid] = gid
            used.add(gid)
    return out


def run_grasp_session(
    scene: SceneSpec,
    run_cfg: RunConfig,
    map_objects: list[dict[str, Any]],
    cfg: GraspRunConfig,
    rec: Any = None,
) -> list[dict[str, Any]]:
    """Grasp every map object of ``map_objects`` (records ``{"id", "label", "geometry"}``) one after
    another in a fresh world (camera, detector and mapper settings from ``run_cfg``); returns one
    row per attempt (+ ``not_in_map`` rows)."""
    session = GraspSession(scene, run_cfg, cfg, rec)
    gt = gt_objects(scene, session.world.ground_truth())
    gt_by_id = {g["id"]: g for g in gt}
    graspable_gt = {g["id"] for g in gt if narrowest_width(g["geometry"]) <= MAX_GRASP_WIDTH_M}
    if rec is not None:
        rec.set_frame(0, session.world.sim_time_s)
        rec.log_objects("world/ground_truth", json.dumps(gt))
        rec.log_objects("world/map", json.dumps(map_objects))
    match = match_gt(map_objects, gt, cfg.match_radius_m)
    remaining = list(map_objects)
    rows: list[dict[str, Any]] = []
    queue = list(map_objects)
    # Objects the planner found no grasp for (nothing moved): retried after the next executed attempt.
    deferred: list[tuple[dict[str, Any], dict[str, Any]]] = []
    n_deferred: dict[int, int] = {}
    grasped: list[dict[str, Any]] = []  # map objects the hand felt it grasped (as grasped)
    k = 0
    fallback = False  # the last round of deferred objects, with the planner's fallback grasps
    while queue or deferred:
        if not queue and not fallback and session.fallback_planner is not None:
            fallback = True
            queue = [t for t, _ in deferred]
            deferred = []
            continue
        if not queue:
            # Nothing executed since these were deferred: the scene is unchanged, so they stay
            # unreachable; their last planning outcome is the row.
            for target, res in deferred:
                rows.append(_row(target, res, gt_by_id, n_deferred.get(target["id"], 0)))
            break
        target = queue.pop(0)
        gt_id = match[target["id"]]  # the judge's; never steers the loop
        neighbours = [m for m in remaining if m["id"] != target["id"]]
        if any(same_place(target, g, cfg.duplicate_margin_m) for g in grasped):
            # The hand already took the object here (through another map object of it): skip.
            # Judged: right when its true object was lifted, else a wrongly skipped object.
            right = gt_id is None or gt_id in session.removed
            rows.append({"map_id": target["id"], "map_label": target["label"],
                         "object": f"gt{gt_id}" if gt_id is not None else f"map{target['id']}",
                         "class": gt_by_id[gt_id]["label"] if gt_id is not None else target["label"],
                         "success": False, "cause": "already_grasped" if right else "wrongly_skipped",
                         "gt_id": gt_id, "skipped": right})
            remaining = [m for m in remaining if m["id"] != target["id"]]
            continue
        res = session.attempt(k, target, neighbours, gt_id, fallback)
        k += 1
        executed = "open_width_m" in res
        if cfg.defer_unreachable and not executed and res["cause"] in DEFERRABLE:
            n_deferred[target["id"]] = n_deferred.get(target["id"], 0) + 1
            deferred.append((target, res))
            continue
        gt_id = res["gt_id"]
        if res["cause"] == "too_wide" and (gt_id is None or gt_id not in graspable_gt):
            res["skipped"] = True  # too wide in the map and in truth: not an attempt
        row = _row(target, res, gt_by_id, n_deferred.get(target["id"], 0))
        rows.append(row)
        session._log("log_event", f"grasp {k} map {target['id']} ({target['label']}) → {row['object']}: "
                     f"{'success' if res['success'] else res['cause']}")
        if res.get("held"):
            # The hand feels it holds something: it is set aside (the simulator removes whatever
            # actually left the table with the hand), and the map object leaves the obstacles.
            for oid in res.get("lifted", []):
                if oid not in session.removed:
                    session.set_aside(oid)
            grasped.append(session.last_target or target)
            remaining = [m for m in remaining if m["id"] != target["id"]]
        if executed:
            session.go_ready([m["geometry"] for m in remaining])
            # The scene changed (an object left, or was pushed): the deferred objects get another plan.
            queue.extend(t for t, _ in deferred)
            deferred = []
            fallback = False
    attempted = {r["gt_id"] for r in rows if r["gt_id"] is not None}
    for gid in sorted(graspable_gt - attempted):
        rows.append(
            {"map_id": None, "map_label": None, "object": f"gt{gid}", "class": gt_by_id[gid]["label"],
             "success": False, "cause": "not_in_map", "gt_id": gid}
        )
    return rows


def _row(target: dict[str, Any], res: dict[str, Any], gt_by_id: dict[int, Any], deferred: int) -> dict[str, Any]:
    gt_id = res["gt_id"]
    return {
        "map_id": target["id"],
        "map_label": target["label"],
        "object": f"gt{gt_id}" if gt_id is not None else f"map{target['id']}",
        "class": gt_by_id[gt_id]["label"] if gt_id is not None else target["label"],
        "deferred": deferred,
        **res,
    }


def config_dict(cfg: GraspRunConfig) -> dict[str, Any]:
    """The config as a plain dict (for run folders)."""
    return asdict(cfg)
