"""Run configuration: typed dataclasses composed from TOML layers.

A run's configuration is ``experiments/configs/default.toml``, then the world-model preset's file
``experiments/configs/presets/<preset>.toml`` when another preset than the default's is chosen,
then the strategy's file ``experiments/configs/strategies/<strategy>.toml``, then any ``--config``
overlays, then ``--set key.sub=value`` overrides (N scenes + M methods = O(N + M) files). The
resolved result is written to the run folder as ``config.toml`` and can be re-run as is. Unknown
keys are errors that name the key.

World-model presets: ``default.toml`` is the ``realistic`` world (``preset = "realistic"``: the
D435-class RGB-D camera, a detector with persistent errors, varied textures, ...); the overlay
``presets/ideal.toml`` sets ``preset = "ideal"`` and every world-model parameter back to the ideal
world (exact depth with 0.1 % noise, perfect registration and colour, per-frame detector noise,
axis-aligned textures), kept as an ablation. ``--preset ideal`` on the experiment scripts, the
``preset`` argument of :func:`load_run_config` and ``--set preset=ideal`` all overlay that file.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, get_type_hints

import tomllib

from .calibration import ContactConfig, RobotConfig, TableConfig
from .camera import CalibrationConfig, CameraConfig, ColourConfig, DepthNoiseConfig, StereoDepthConfig
from .detector import DetectorConfig
from .textures import TextureConfig

REPO_ROOT = Path(__file__).resolve().parents[2]
CONFIG_DIR = REPO_ROOT / "experiments" / "configs"
PRESET_DIR = CONFIG_DIR / "presets"


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names the key."""


@dataclass(frozen=True)
class ExploreRunConfig:
    """Exploration (mirrors ``objslam_core::active::ActiveConfig``; meanings in the core's
    ``explore`` module docs). Every strategy starts with the same Init step: four views over the
    table corners (inset by ``init_inset_m``), ``init_height_m`` high, tilted ``init_tilt_deg``
    towards the centre."""

    max_views: int = 10
    """Views after Init (paper: 10)."""
    utility_lambda: float = 0.2
    """λ of the utility (paper: 0.2)."""
    cell_m: float = 0.01
    """Surface grid cell, metres (paper: 1 cm)."""
    views_per_object: int = 12
    """Candidate views sampled around each object still to explore."""
    distance_m: tuple[float, float] = (0.35, 0.6)
    """Candidate camera distance from the object centre, metres."""
    elevation_deg: tuple[float, float] = (45.0, 80.0)
    """Candidate elevation above the object's horizontal plane, degrees (the paper gives none).
    Views below ~45° look across the crowded table: neighbours occlude the target, boxes take in
    their surfaces and the association merges objects. Exploration benchmark, seed 0,
    object-driven: 25-75° → 3D IoU 0.790 / CDE 0.60 cm (2 merged and 2 missed objects in scene07);
    45-80° → 0.834 / 0.40 cm; 60-88° → 0.834 / 0.50 cm (chosen on seed 0; the 3-seed report is
    the check)."""
    init_height_m: float = 0.5
    init_inset_m: float = 0.3
    init_tilt_deg: float = 20.0
    coverage_height_m: float = 0.45
    coverage_inset_m: float = 0.15
    done_occupied_ratio: float = 0.5
    done_normalized_entropy: float = 0.5
    motion_cost_bits_per_m: float = 20.0
    stop_when_explored: bool = True
    """object-driven / expected-gain: stop once every object is explored (the paper's rule).
    ``false``: keep choosing views by the same utility, every object counted (s(x) = 1), until
    ``max_views`` — the equal-budget comparison with random and coverage."""
    discovery_before_stop: bool = True
    """object-driven / expected-gain, beyond the paper: when every mapped object is explored, do
    not stop while a view aimed at the unseen table top would still see
    ``discovery_min_new_cells`` cells not seen yet; go there. The paper's utility knows only the
    objects already mapped, so an object the Init views missed is never looked for (core
    ``explore::discovery`` module docs); how much of the table the Init views leave unseen is in
    each episode's ``table_known_curve`` and the reports' table-known tables (``init`` row of
    ``reports/exploration_narrow_fov``). ``false`` = the paper's stopping rule
    (the reports' commands say which they ran)."""
    discovery_weight: float = 0.0
    """object-driven / expected-gain, beyond the paper: weight of the table discovery gain (bits
    per cm² of table top not seen yet) added to every candidate's utility, candidates aimed at the
    unseen table joining those around objects. 0 = the paper's utility. On a seed-0 pilot with the default
    camera (not kept as a report) 1.0 spent the first views on the empty table margins the Init
    views miss and ended with a lower 3D IoU than 0; hence off."""
    discovery_cell_m: float = 0.02
    """Table coverage cell, metres."""
    discovery_min_new_cells: int = 25
    """Cells a view must newly see to keep exploring after every object is done (25 × 2 cm × 2 cm
    = 100 cm², about the footprint of the smallest object class)."""
    discovery_reserve: bool = True
    """object-driven / expected-gain, beyond the paper: the budget reserve. At each decision,
    estimate how many discovery views are still worth taking (greedy cover of the unseen table by
    reachable candidates, each revealing ``discovery_min_new_cells`` new cells); when the views
    left in ``max_views`` are no more than that, take a discovery view instead of the object NBV.
    Objects first, the table's share of the budget last (core ``explore::discovery``)."""
    discovery_min_frames: int = 3
    """A table cell counts as seen once depth returns of this many frames landed in it (the map
    confirms an object after ``pipeline.min_observations`` = 3 untruncated detections; a cell seen
    in fewer frames may hold an object the map has not confirmed)."""
    discovery_margin_frac: float = 0.1
    """Returns within this fraction of the image width / height of the border do not mark table
    cells, and predicted views count only the inner image (truncated detections do not seed
    map objects)."""
    discovery_exclude_truncated_px: float = 0.0
    """Pixels inside a detection box within this many pixels of the image edge (a truncated
    detection; the association's ``border_margin_px`` is 2) do not mark table cells: the object
    there may never be confirmed. 0 = off (the default; the reports were made without it).
    Measured on scene06, seed 6, 35° camera, exact poses: a block detected truncated in all but two
    frames was never mapped while its cells counted as seen (core ``explore::discovery``)."""
    discovery_evidence_height_m: float = 0.02
    """Depth returns more than this above the table top are evidence of an object, not a sight of
    the table (counted from the whole image, border included): they do not mark table cells seen,
    so the cells stay unknown until a map object covers them; cells with such evidence far from
    every map object are *unexplained* (the depth shows an object the map does not have: detected
    only truncated, or too few times) and draw discovery views centred on them. 0 = off.
    Core ``explore::discovery``; measured in ``studies/discovery_evidence/``."""
    discovery_evidence_weight: float = 10.0
    """An unexplained table cell counts as this many unseen cells in the discovery count, gain
    and budget reserve (a 5 cm block overlaps 9-16 cells of 2 cm; ``discovery_min_new_cells`` is 25)."""
    discovery_evidence_explained_m: float = 0.025
    """Evidence within this distance of a map object's primitive is explained by it, metres."""
    discovery_evidence_max_views: int = 2
    """After this many views taken for unexplained cells they count as plain unseen cells (an
    object a centred view cannot get into the map does not take the budget)."""


@dataclass(frozen=True)
class NaiveMapperConfig:
    """Configuration of the naive mapper (mirrors ``objslam_core::naive::NaiveConfig``)."""

    pixel_stride: int = 4
    iou_threshold: float = 0.3
    voxel_m: float = 0.005
    trim_fraction: float = 0.02
    min_points: int = 20
    max_depth_m: float = 3.0


WINDOW_KEEP = ("latest", "most_segments", "most_segments_yaw")


@dataclass(frozen=True)
class ParamRunConfig:
    """Parameterization knobs a run usually changes (the rest keep the core's ``ParamConfig``
    defaults, documented in ``core/src/objects``)."""

    refine_center: bool = True
    """Let the yaw/scale refinement also move the centre (the paper refines yaw and scale only)."""
    refine_prior_px_per_m: float = 200.0
    """Weight of the refinement's prior on centre and scale, pixels per metre."""
    iforest_passes: int = 1
    """Isolation-forest fits per estimate, each on the points the previous kept. 1 = the paper's
    Algorithm 1 (the run default: the local clouds are already cut to the object's surface, and
    more passes trim its extremes — Init sweep refined 3D IoU 0.656 with 1 pass vs 0.620 with 4);
    the core's own default of 4 suits heavily contaminated clouds (``core/src/objects/iforest.rs``)."""
    iforest_readmit_rings: int = 3
    """Beyond the paper: after removal, rings of re-admission of removed points lying within
    ``iforest_readmit_gap`` × the kept cloud's median point spacing of a kept point (border points
    of a clean surface come back; points behind a gap stay out). 0 = the paper's plain removal.
    Chosen on the Init sweep, seed 0 (iForest-stage 3D IoU 0.399 → 0.415, refined 0.656 → 0.672)
    and confirmed on held-out seed 1 (0.390 → 0.403, refined 0.635 → 0.651); rings 1-10 and gaps
    2-4 were tried (``core/examples/param_replay.rs`` on recorded estimator inputs)."""
    iforest_readmit_gap: float = 4.0
    """Gap separating an outlier from the cloud, in median point spacings (2 gave back too few
    border points on the Init sweep; 3 and 4 both beat plain removal, 4 by a little more)."""
    cylinder_fit: bool = True
    """Beyond the paper: the ``refined`` stage of cylinders is a circle fitted to their side-wall
    points with the height centred on the points' vertical extent (``core/src/objects/cylinder.rs``);
    False = the paper (cylinders end at the iForest mean and axis-aligned extent)."""
    support_snap_m: float = 0.015
    """Beyond the paper: an estimate whose bottom lies within this of the table top (z = 0) is
    extended down to it, its top kept (objects stand on the table; the local clouds cut the
    points within 5 mm of the table, so bottoms sit ~3 mm high: ``ParamConfig::support_z_m`` in
    ``core/src/objects/mod.rs``). 0 = off (the paper). Default 0.015 m; measured in ``studies/support_snap/``."""
    cylinder_consensus_iterations: int = 200
    """Circles through three random side-wall points tried as a second start of the cylinder fit
    (the one with more points on the circle is kept); 0 = the algebraic start only (a neighbour's points merged into a bottle's cloud can pull that
    start off the wall). Default 200."""
    window_keep: str = "most_segments_yaw"
    """Which frames the line-alignment window (``ParamConfig::window_frames`` = 10) keeps once full
    (``WindowKeep`` in ``core/src/objects/mod.rs``): ``"most_segments_yaw"`` (default, beyond the
    paper) = Alg. 2's yaw sampling on the ten frames with the most LSD segments in the object's box,
    the refinement on the last ten; ``"latest"`` = the last ten for both (the paper's "t consecutive
    images"); ``"most_segments"`` = the most-segment ten for both. Alg. 2 weighs every frame by its
    share of aligned segments, so frames that see an object small (two to five segments) can decide
    its yaw with noisy votes. Measurements: ``studies/window_keep/``."""
    cylinder_top_from_face: bool = True
    """Beyond the paper: a cylinder's top from the median height of its top face's points instead
    of its highest point, which depth noise lifts ~3 σ above the face (``core/src/objects/cylinder.rs``).
    Default true; false = the highest point (the paper). Measurements:
    ``studies/cylinder_top_from_face/``."""

@dataclass(frozen=True)
class PriorNoiseConfig:
    """The estimator's assumed error of the kinematic pose prior (core ``PriorNoiseConfig``): the
    SLAM's world ← map gauge weights and its prior and motion gates. Its own tuning, never read from
    the simulator: the robot's actual error is ``[robot]`` (:mod:`objslam.calibration`)."""

    bias_trans_m: float = 0.01
    """Assumed translation error constant over a view, metres (its magnitude). Default 0.01."""
    bias_rot_deg: float = 1.0
    """Assumed rotation error constant over a view, degrees. Default 1.0."""
    jitter_trans_m: float = 0.0005
    """Assumed per-frame translation error, standard deviation per axis, metres. Default 0.0005."""
    jitter_rot_deg: float = 0.05
    """Assumed per-frame rotation error, standard deviation per axis, degrees. Default 0.05."""


@dataclass(frozen=True)
class EvalConfig:
    """Evaluation (mirrors ``objslam_core::eval::EvalConfig``)."""

    max_match_distance_m: float = 0.10
    square_tolerance: float = 0.05


@dataclass(frozen=True)
class RecordConfig:
    """What goes into ``run.rrd``."""

    enabled: bool = True
    rgb: bool = True
    depth: bool = True
    every_n_frames: int = 1
    """Log images every n-th frame (poses, detections and the map are logged every frame)."""
    grids: bool = True
    """Log the surface grid cells coloured by state after every view."""
    estimator_inputs: bool = False
    """Write ``estimator_inputs.json`` to the run folder: every confirmed object's accumulated
    points and line-frame window (the parameterization's inputs) plus the ground-truth objects
    (for evaluation only), for offline replay with ``cargo run --release -p objslam-core
    --example param_replay``."""
    map_points: bool = True
    """Log the SLAM map points (``world/map/points``, world frame) after every view (pose sources
    other than ``fk``, which has no tracker)."""
    jpeg_quality: int = 85
    """JPEG quality (1-100) of the colour frames in ``run.rrd``; depth frames are then lossless
    16-bit PNG in millimetres (the simulated depth is quantised to 1 mm). 0 stores both raw (RGB24
    and float32 metres: 2.1 MB per 640×480 frame)."""
    depth_every_n_frames: int = 2
    """Log depth on every n-th logged colour frame: a lossless depth PNG is about 140 kB, four
    times a JPEG colour frame, so every 2nd (default) keeps a recording near a quarter of the raw
    size; 1 logs depth with every colour frame."""
    robot: bool = True
    """Draw the Panda (``world/robot``): its URDF collision meshes (0.15 MB, logged once) moved to
    the simulated links' poses every frame."""
    live_url: str = ""
    """Also stream the recording to a viewer's gRPC proxy while the run goes, e.g.
    ``rerun+http://127.0.0.1:9876/proxy`` (``experiments/run.py --spawn`` / ``--serve`` start a
    viewer and set it); empty (default) = file only."""


@dataclass(frozen=True)
class RunConfig:
    """One episode."""

    preset: str = "realistic"
    """World-model preset the run was composed with: ``realistic`` (``default.toml``) or a file of
    ``experiments/configs/presets/`` (``ideal``); reports say which made them."""
    scene: str = "scenes/scene01.toml"
    """Scene file (relative to the repository root or absolute)."""
    strategy: str = "object-driven"
    """View-selection strategy: object-driven (the paper's utility), expected-gain, random,
    coverage or init; or the label of a Python strategy (``python_strategy``)."""
    python_strategy: str = ""
    """A view-selection strategy written in Python (``objslam.strategy``): ``path/to/file.py:Class``
    (relative to the repository root, or absolute) or ``package.module:Class``; empty (default) =
    the built-in ``strategy``. With it, ``strategy`` is its label in metrics and reports and must
    not be a built-in name."""
    python_strategy_params: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments of the Python strategy's constructor (a TOML table)."""
    seed: int = 0
    """Seeds sensor noise, the detector, random strategies and (mixed with the scene file's seed)
    the kinematic prior noise."""
    seed_algorithms: bool = False
    """Also seed the mapper's own random streams from the run and scene seeds: the isolation
    forest's subsamples, the cylinder fit's three-point circles and the tracker's PnP RANSAC
    (``episode.algorithm_seeds``). False (default): those streams keep the core's fixed seeds, so
    the run seed varies the simulated world (noise, detector, random views) and not the estimator,
    and every report stays reproducible with its recorded command. True: repeating a run over
    seeds also samples the estimator's own randomness (its spread over seeds then includes it)."""
    runs_dir: str = "runs"
    """Where run folders are created."""
    frame_rate_hz: float = 4.0
    """Frames rendered per simulated second while the arm moves."""
    max_joint_speed: float = 1.0
    """Speed cap of every joint during camera moves, rad/s (the planner's limits apply below it:
    half the Panda's datasheet velocity, 1.09 rad/s for joints 1-4)."""
    camera_path: str = "cartesian"
    """How the arm moves between views: ``cartesian`` (the camera travels the straight line between
    the two views with its orientation slerped, IK every 2 cm / 5°, so the tracker keeps the scene in
    view; falls back to ``joint`` when a waypoint is unreachable) or ``joint`` (the planner's
    joint-space path, during which the camera can swing off the table); both timed by the planner's
    Ruckig trajectories (``SimWorld.move_along``)."""
    association_mode: str = "ensemble"
    """Association: ``naive`` (the foundation baseline), ``iou``, ``iou_np``, ``iou_t`` or
    ``ensemble`` (the paper's method; see the core's ``association`` module)."""
    parameterize: bool = True
    """Run object parameterization (iForest, line-alignment yaw, refinement) after association."""
    pose_source: str = "slam"
    """Camera pose used by the mapper: ``slam`` (default: visual tracking seeded by the kinematic
    prior, the paper's ORB-SLAM2 role), ``kinematics`` (the prior as is, with the tracker's map
    points), ``ground_truth`` (oracle, an ablation: the only source the true pose reaches), ``fk``
    (the prior as is, no tracker; fast runs). The prior is forward kinematics of the nominal robot
    model on the joint readings; its error is the simulated robot's (``[robot]``)."""
    object_points: str = "depth"
    """Local object point clouds for the association: ``depth`` (depth pixels in each box) or
    ``slam_map`` (the SLAM map points observed in each box, the paper's Sec. III-B; needs a
    pose source other than ``fk``, which runs no tracker)."""
    consolidate: bool = True
    """Beyond the paper: fold same-label objects whose boxes overlap into one after each view (the
    statistical tests split objects seen from very different viewpoints). False = the paper's
    pipeline."""
    consolidate_cloud_overlap: float = 0.5
    """With ``consolidate``: two same-label objects whose boxes intersect are also folded when at
    least this share of the smaller cloud lies within 1 cm of the other cloud (they see the same
    surface). Above 1 disables this test."""
    relabel_vote_ratio: float = 4.0
    """With ``consolidate``: an object seen under another label at the place of an object with at
    least this many times its observations is folded into it (a detector label confusion, not a
    second object); the label is then the majority vote. 0 disables."""
    min_observations: int = 3
    """Objects seen fewer times are left out of the map (false positives, label confusions)."""
    follow_slam_gauge: bool = True
    """With a tracker: when the SLAM re-fits its world ← map gauge to the views' kinematic priors
    (millimetres per view), move the whole object map with it so points fused under different
    gauges stay one rigid map (``ObjectPipeline::transform_world``). False keeps each point where
    its frame's pose put it. Exploration benchmark, seed 0, mean over the 7 scenes: object-driven
    3D IoU 0.707 → 0.790 and CDE 1.01 → 0.60 cm with it; Init 0.743 → 0.822."""
    slam_motion_gate_m: float = 0.01
    """With the ``slam`` pose source: a tracked pose farther than this, metres, from the last
    tracked frame of the same view moved by the prior's motion is lost and dead-reckoned instead
    (the core's ``TrackerConfig::motion_gate_floor_m``): a frame that sees little of the scene
    cannot track to a consensus centimetres off and corrupt the map. Default 0.01; 0 disables.
    Measurements: ``studies/motion_gate/``."""
    slam_motion_gate_deg: float = 2.0
    """The same gate's rotation floor, degrees (``motion_gate_floor_deg``). Default 2; 0 disables."""
    slam_motion_gate_references: int = 2
    """How many of the last tracked frames of the view the motion gate predicts from; a pose
    passes when it agrees with any, so one reference accepted slightly off is outvoted
    (``motion_gate_references``, at least 1). Default 2."""
    slam_extend_after_unmapped: int = 3
    """With the ``slam`` pose source: after this many consecutive lost frames that show the scene
    but little of the SLAM map (the camera looks where the map has no points), insert a fixed
    keyframe at the frame's estimated pose and track on from it, keeping the old map (the core's
    ``TrackerConfig::extend_after_unmapped``). Default 3; 0 = such frames count towards a map
    reset. Measurements: ``studies/narrow_fov/``."""
    camera: CameraConfig = field(default_factory=CameraConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    textures: TextureConfig = field(default_factory=TextureConfig)
    naive: NaiveMapperConfig = field(default_factory=NaiveMapperConfig)
    param: ParamRunConfig = field(default_factory=ParamRunConfig)
    prior_noise: PriorNoiseConfig = field(default_factory=PriorNoiseConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    table: TableConfig = field(default_factory=TableConfig)
    contact: ContactConfig = field(default_factory=ContactConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    explore: ExploreRunConfig = field(default_factory=ExploreRunConfig)
    record: RecordConfig = field(default_factory=RecordConfig)

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the key if a value is out of range."""
        if self.python_strategy:
            if self.strategy in STRATEGIES:
                raise ConfigError(
                    f"strategy: {self.strategy!r} is a built-in strategy; give the python_strategy its own label"
                )
            if not self.strategy or "/" in self.strategy:
                raise ConfigError(f"strategy: {self.strategy!r} is not a usable label (non-empty, no '/')")
            from .strategy import StrategyError, load_strategy_class

            try:
                load_strategy_class(self.python_strategy)
            except StrategyError as e:
                raise ConfigError(f"python_strategy: {e}") from e
        elif self.python_strategy_params:
            raise ConfigError("python_strategy_params: given without a python_strategy")
        elif self.strategy not in STRATEGIES:
            raise ConfigError(
                f"strategy: unknown {self.strategy!r}; known: {', '.join(STRATEGIES)} "
                "(or set python_strategy for a strategy written in Python)"
            )
        if self.association_mode not in ASSOCIATION_MODES:
            raise ConfigError(
                f"association_mode: unknown {self.association_mode!r}; known: {', '.join(ASSOCIATION_MODES)}"
            )
        if self.preset not in available_presets():
            raise ConfigError(f"preset: unknown {self.preset!r}; known: {', '.join(available_presets())}")
        if self.seed < 0:
            raise ConfigError("seed: must be ≥ 0")
        if not (0 < self.frame_rate_hz <= 60):
            raise ConfigError("frame_rate_hz: must be in (0, 60]")
        if not (0 < self.max_joint_speed <= 2.5):
            raise ConfigError("max_joint_speed: must be in (0, 2.5] rad/s")
        if self.camera_path not in CAMERA_PATHS:
            raise ConfigError(f"camera_path: unknown {self.camera_path!r}; known: {', '.join(CAMERA_PATHS)}")
        if self.pose_source not in POSE_SOURCES:
            raise ConfigError(f"pose_source: unknown {self.pose_source!r}; known: {', '.join(POSE_SOURCES)}")
        if not (0.0 < self.consolidate_cloud_overlap):
            raise ConfigError("consolidate_cloud_overlap: must be > 0 (above 1 disables the test)")
        if self.relabel_vote_ratio < 0.0:
            raise ConfigError("relabel_vote_ratio: must be ≥ 0 (0 disables the label-confusion fold)")
        if self.object_points not in OBJECT_POINT_SOURCES:
            raise ConfigError(
                f"object_points: unknown {self.object_points!r}; known: {', '.join(OBJECT_POINT_SOURCES)}"
            )
        if self.object_points == "slam_map" and self.pose_source == "fk":
            raise ConfigError(
                "object_points: slam_map needs a tracker (pose_source kinematics, slam or ground_truth)"
            )
        if self.param.iforest_passes < 1:
            raise ConfigError("param.iforest_passes: must be ≥ 1")
        if self.param.iforest_readmit_rings < 0:
            raise ConfigError("param.iforest_readmit_rings: must be ≥ 0")
        if not (self.param.support_snap_m >= 0.0 and math.isfinite(self.param.support_snap_m)):
            raise ConfigError("param.support_snap_m: must be a finite number ≥ 0")
        if self.param.window_keep not in WINDOW_KEEP:
            raise ConfigError(f"param.window_keep: unknown {self.param.window_keep!r}; known: {', '.join(WINDOW_KEEP)}")
        if self.param.cylinder_consensus_iterations < 0:
            raise ConfigError("param.cylinder_consensus_iterations: must be ≥ 0")
        if not (self.param.iforest_readmit_gap > 0 and math.isfinite(self.param.iforest_readmit_gap)):
            raise ConfigError("param.iforest_readmit_gap: must be a finite number > 0")
        if self.slam_extend_after_unmapped < 0:
            raise ConfigError("slam_extend_after_unmapped: must be ≥ 0 (0 disables)")
        if self.min_observations < 1:
            raise ConfigError("min_observations: must be ≥ 1")
        if self.explore.max_views < 0:
            raise ConfigError("explore.max_views: must be ≥ 0")
        if self.record.every_n_frames < 1:
            raise ConfigError("record.every_n_frames: must be ≥ 1")
        if self.record.depth_every_n_frames < 1:
            raise ConfigError("record.depth_every_n_frames: must be ≥ 1")
        if not 0 <= self.record.jpeg_quality <= 100:
            raise ConfigError(f"record.jpeg_quality: expected 0 (raw) to 100, got {self.record.jpeg_quality}")
        try:
            self.camera.validate()
            self.detector.validate()
            self.textures.validate()
            self.robot.validate()
            self.table.validate()
            self.contact.validate()
        except ValueError as e:
            raise ConfigError(str(e)) from e


POSE_SOURCES = ("fk", "kinematics", "slam", "ground_truth")
CAMERA_PATHS = ("cartesian", "joint")
OBJECT_POINT_SOURCES = ("depth", "slam_map")
ASSOCIATION_MODES = ("naive", "iou", "iou_np", "iou_t", "ensemble")
STRATEGIES = ("init", "object-driven", "random", "coverage", "expected-gain")


def _build(cls: type, data: dict[str, Any], prefix: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix or '<root>'}: expected a table")
    hints = get_type_hints(cls)
    names = {f.name for f in fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"{prefix}{min(unknown)}: unknown key (known: {', '.join(sorted(names))})")
    kwargs: dict[str, Any] = {}
    for f in fields(cls):
        if f.name not in data:
            continue
        v = data[f.name]
        t = hints[f.name]
        key = f"{prefix}{f.name}"
        if is_dataclass(t):
            kwargs[f.name] = _build(t, v, key + ".")  # type: ignore[arg-type]
            continue
        kwargs[f.name] = _coerce(key, t, v)
    return cls(**kwargs)


def _coerce(key: str, t: Any, v: Any) -> Any:
    origin = getattr(t, "__origin__", None)
    if t is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"{key}: expected true/false, got {v!r}")
        return v
    if t is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"{key}: expected an integer, got {v!r}")
        return v
    if t is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {v!r}")
        return float(v)
    if t is str:
        if not isinstance(v, str):
            raise ConfigError(f"{key}: expected a string, got {v!r}")
        return v
    if origin is dict:
        if not isinstance(v, dict):
            raise ConfigError(f"{key}: expected a table, got {v!r}")
        return dict(v)
    if origin is tuple:
        args = t.__args__
        if not isinstance(v, list) or len(v) != len(args):
            raise ConfigError(f"{key}: expected a list of {len(args)} values, got {v!r}")
        return tuple(_coerce(f"{key}[{i}]", a, x) for i, (a, x) in enumerate(zip(args, v)))
    return v


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _parse_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_override(item: str) -> dict[str, Any]:
    """``"camera.width=320"`` → ``{"camera": {"width": 320}}`` (values parsed as TOML, else strings)."""
    if "=" not in item:
        raise ConfigError(f"--set {item!r}: expected key=value")
    key, value = item.split("=", 1)
    parts = key.strip().split(".")
    d: dict[str, Any] = {parts[-1]: _parse_value(value.strip())}
    for p in reversed(parts[:-1]):
        d = {p: d}
    return d


def _read(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads(path.read_text())
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror})") from e
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: {e}") from e


def available_presets() -> tuple[str, ...]:
    """The default's preset (``realistic``) and the overlays in ``experiments/configs/presets/``."""
    default = _read(CONFIG_DIR / "default.toml").get("preset", "realistic")
    files = sorted(p.stem for p in PRESET_DIR.glob("*.toml")) if PRESET_DIR.is_dir() else []
    return (default, *(f for f in files if f != default))


def load_run_config(
    *,
    overlays: list[str | Path] = (),
    overrides: list[str] = (),
    strategy: str | None = None,
    preset: str | None = None,
) -> RunConfig:
    """Compose default.toml ← preset file ← strategy file ← overlays ← overrides, validate, return.
    The preset is ``preset`` if given, else the last ``preset`` key of the overlays and overrides,
    else the default's; a preset other than the default's overlays ``presets/<preset>.toml``."""
    data = _read(CONFIG_DIR / "default.toml")
    layers = [parse_override(o) for o in overrides]
    overlay_data = [_read(Path(p)) for p in overlays]
    chosen_preset = preset
    if chosen_preset is None:
        for layer in [*overlay_data, *layers]:
            chosen_preset = layer.get("preset", chosen_preset)
    default_preset = data.get("preset", "realistic")
    chosen_preset = chosen_preset or default_preset
    if not isinstance(chosen_preset, str) or chosen_preset not in available_presets():
        raise ConfigError(f"preset: unknown {chosen_preset!r}; known: {', '.join(available_presets())}")
    if chosen_preset != default_preset:
        data = _merge(data, _read(PRESET_DIR / f"{chosen_preset}.toml"))
    chosen = strategy
    for layer in [*overlay_data, *layers]:
        chosen = layer.get("strategy", chosen)
    chosen = chosen or data.get("strategy", "init")
    strategy_file = CONFIG_DIR / "strategies" / f"{chosen}.toml"
    if strategy_file.exists():
        data = _merge(data, _read(strategy_file))
    for layer in overlay_data:
        data = _merge(data, layer)
    for layer in layers:
        data = _merge(data, layer)
    if strategy is not None:
        data["strategy"] = strategy
    data["preset"] = chosen_preset
    cfg = _build(RunConfig, data, "")
    cfg.validate()
    return cfg


def to_dict(cfg: Any) -> dict[str, Any]:
    """A dataclass as plain TOML-able data."""

    def conv(v: Any) -> Any:
        if is_dataclass(v):
            return {f.name: conv(getattr(v, f.name)) for f in fields(v)}
        if isinstance(v, tuple):
            return [conv(x) for x in v]
        return v

    return conv(cfg)


def replace(cfg: RunConfig, **changes: Any) -> RunConfig:
    """A copy with top-level fields changed."""
    return dataclasses.replace(cfg, **changes)


__all__ = [
    "CalibrationConfig",
    "CameraConfig",
    "ColourConfig",
    "ConfigError",
    "ContactConfig",
    "DepthNoiseConfig",
    "DetectorConfig",
    "EvalConfig",
    "ExploreRunConfig",
    "NaiveMapperConfig",
    "PriorNoiseConfig",
    "RecordConfig",
    "RobotConfig",
    "RunConfig",
    "StereoDepthConfig",
    "TableConfig",
    "TextureConfig",
    "available_presets",
    "load_run_config",
    "parse_override",
    "to_dict",
]
