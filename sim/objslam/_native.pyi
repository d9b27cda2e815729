"""Type stubs of the private native module (checked against the compiled module by stubtest)."""

from collections.abc import Callable, Sequence
from typing import Any, TypeAlias

import numpy as np
import numpy.typing as npt

__version__: str

class ObjslamError(ValueError): ...
class InputError(ObjslamError): ...
class MapFileError(ObjslamError): ...
class RecordingError(ObjslamError): ...

Det: TypeAlias = tuple[float, float, float, float, str, float]

class NaiveMapper:
    def __init__(self, config_json: str | None = None) -> None: ...
    def update(
        self,
        *,
        index: int,
        intrinsics: npt.NDArray[np.float64],
        depth: npt.NDArray[np.float32],
        world_from_camera: npt.NDArray[np.float64],
        detections: Sequence[Det],
    ) -> list[int | None]: ...
    def map_json(self) -> str: ...
    def objects_json(self) -> str: ...
    def __len__(self) -> int: ...

class Recorder:
    def __init__(self, path: str, application_id: str = "objslam", options_json: str | None = None) -> None: ...
    def set_frame(self, frame: int, sim_time_s: float) -> None: ...
    def log_robot_pose(self, links: dict[str, npt.NDArray[np.float64]]) -> None: ...
    def log_camera(
        self,
        *,
        world_from_camera: npt.NDArray[np.float64],
        intrinsics: npt.NDArray[np.float64],
        width: int,
        height: int,
    ) -> None: ...
    def log_rgb(self, rgb: npt.NDArray[np.uint8]) -> None: ...
    def log_depth(self, depth: npt.NDArray[np.float32]) -> None: ...
    def log_detections(self, detections: Sequence[Det]) -> None: ...
    def log_trajectory(self, which: str, positions: npt.NDArray[np.float64]) -> None: ...
    def log_objects(self, root: str, objects_json: str) -> None: ...
    def log_points(
        self,
        entity: str,
        points: npt.NDArray[np.float64],
        group_keys: list[str] | None = None,
        *,
        colors: npt.NDArray[np.uint8] | None = None,
        radius_m: float = 0.004,
    ) -> None: ...
    def log_arrows(
        self,
        entity: str,
        origins: npt.NDArray[np.float64],
        vectors: npt.NDArray[np.float64],
        colors: npt.NDArray[np.uint8],
    ) -> None: ...
    def log_scalar(self, entity: str, value: float) -> None: ...
    def log_event(self, text: str) -> None: ...
    def close(self) -> None: ...

class ActiveMapper:
    def __init__(
        self,
        *,
        mapper_config_json: str,
        active_config_json: str,
        table: tuple[float, float, float, float],
        tracker_config_json: str | None = None,
    ) -> None: ...
    def update(
        self,
        *,
        index: int,
        intrinsics: npt.NDArray[np.float64],
        depth: npt.NDArray[np.float32],
        world_from_camera: npt.NDArray[np.float64],
        detections: Sequence[Det],
        grey: npt.NDArray[np.uint8] | None = None,
        world_from_camera_gt: npt.NDArray[np.float64] | None = None,
        view_index: int = 0,
    ) -> list[int | None]: ...
    def view_done(self, counts_as_view: bool) -> None: ...
    def next_view(
        self,
        *,
        intrinsics: npt.NDArray[np.float64],
        width: int,
        height: int,
        world_from_camera: npt.NDArray[np.float64],
        reachable: Callable[[npt.NDArray[np.float64]], bool],
    ) -> dict[str, Any]:
        """``{"action": "move", "world_from_camera", "utility" (None without one), "candidates":
        [{"world_from_camera", "utility", "reachable"}]}`` or ``{"action": "stop", "reason"}``."""

    def query(
        self,
        query_json: str,
        *,
        intrinsics: npt.NDArray[np.float64] | None = None,
        width: int = 0,
        height: int = 0,
        views: Sequence[npt.NDArray[np.float64]] = (),
        world_from_camera: npt.NDArray[np.float64] | None = None,
        reachable: Callable[[npt.NDArray[np.float64]], bool] | None = None,
    ) -> Any:
        """One question (``objslam_core::system::Query``): ``{"query": "initial_views" | "progress" |
        "last_pose" | "pose_metrics"}``; with the camera, ``"object_features"``, ``"candidate_views"``
        (``"around"``), ``"score_views"`` (``"utility"``, ``"explore_every_object"``; ``views``,
        ``world_from_camera``), ``"paper_stop"``, ``"table_candidate_views"``, ``"table_gain"``
        (``views``), ``"table_views_needed"`` (``"limit"``; ``reachable``). Views come back as
        ``{"world_from_camera", "target_object"}`` dicts, poses as 4x4 arrays."""

    def note_chosen_view(
        self,
        *,
        intrinsics: npt.NDArray[np.float64],
        width: int,
        height: int,
        world_from_camera: npt.NDArray[np.float64],
    ) -> None: ...
    def map_points(self) -> npt.NDArray[np.float64] | None: ...
    def table_unknown_cells(self) -> tuple[npt.NDArray[np.float64], list[bool]]: ...
    def map_json(self, stage: str | None = None) -> str: ...
    def objects_json(self) -> str: ...
    def last_pose(self) -> npt.NDArray[np.float64] | None:
        """The pose the last frame was mapped with (4x4 ``world_from_camera``), None before one."""
    def refresh_estimates(self) -> None: ...
    def estimator_inputs_json(self) -> str: ...
    def resolve_id(self, id: int) -> int: ...
    def association_metrics_json(self, pairs: list[tuple[int, int | None]], gt_ids: list[int]) -> str: ...
    def grid_cells(self) -> tuple[npt.NDArray[np.float64], bytes]: ...
    def __len__(self) -> int: ...

def evaluate_map(gt_json: str, map_json: str, config_json: str | None = None) -> str: ...
def resolve_config(config_json: str) -> str: ...
def load_map(path: str) -> str: ...
def save_map(map_json: str, path: str) -> None: ...
def map_objects_json(map_json: str) -> str: ...
def ar_run(
    request_json: str, real_depth: np.ndarray | None = None, grey: np.ndarray | None = None
) -> tuple[str, np.ndarray, np.ndarray | None]:
    """AR request (``objslam_core::ar::request``): ``(answer_json, coverage, depth)``. ``real_depth``
    float32 (H, W) is a live frame fused with the map's depth (``grey`` uint8 (H, W): its image, for
    the registration shift), or with ``config.live.source = "exact"`` the real depth itself."""
def match_maps(
    prior_map_json: str, query_map_json: str, config_json: str | None = None, *, relocalise: bool = False
) -> dict[str, Any]:
    """``objslam_core::topo::report::MatchReport`` as a dict (rotation, translation and matrix as
    arrays; ``inliers``, ``matched_pairs`` and, with ``relocalise``, ``matched_ids`` as lists of
    lists)."""

def relocalise_appearance(
    request_json: str,
    prior_grey: npt.NDArray[np.uint8],
    prior_depth: npt.NDArray[np.float32],
    query_grey: npt.NDArray[np.uint8],
    query_depth: npt.NDArray[np.float32],
) -> str: ...
def sensor_model(
    request_json: str,
    points: npt.NDArray[np.float32] | None = None,
    normals: npt.NDArray[np.float32] | None = None,
    rgb: npt.NDArray[np.uint8] | None = None,
) -> tuple[npt.NDArray[np.float32] | None, npt.NDArray[np.uint8] | None, str]:
    """The RGB-D sensor model (``objslam_core::sensor``) on one rendered frame: ``(depth, rgb,
    info_json)``; without ``points`` only the unit's calibration state (``info_json["unit"]``)."""

def orb_extract(
    grey: npt.NDArray[np.uint8], config_json: str | None = None
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """The core's ORB extractor on one uint8 (H, W) image: keypoints float32 (N, 5) as x, y, level,
    angle (rad), FAST score; descriptors uint8 (N, 32)."""

class PlanningError(ObjslamError): ...

class Planner:
    """The Panda motion planner of the core (``objslam_core::plan``).

    Per-attempt outcomes come back as dicts: ``{"ok": True, ...}`` or ``{"ok": False, "cause":
    "no_ik" | "no_path" | "too_wide" | "trajectory", "message": str}``. Trajectory dicts hold
    ``times_s`` (N,), ``positions`` / ``velocities`` (N, 7), ``waypoints`` (M, 7), ``dt_s``,
    ``duration_s``. Obstacles are JSON lists of ObjectGeometry (``{"shape", "center", "yaw_rad",
    "half_extents"}``). ``config_json`` keys: object_margin_m, table_margin_m, edge_resolution_rad,
    rrt_max_iterations, shortcut_iterations, rng_seed, ik_seed, ik_random_restarts, sample_dt_s,
    velocity_scale, acceleration_scale, jerk_scale, opening_clearance_m, max_grasp_depth_m,
    shallow_grasp_depth_m, min_tcp_height_m, pregrasp_height_m, lift_height_m, allow_long_side,
    cylinder_yaw_count, trim_overlapping_neighbours, min_trimmed_half_extent_m,
    narrow_opening_fallback, narrow_opening_clearance_m, off_centre_steps, off_centre_inset_m,
    tilt_steps, max_tilt_rad, linear_step_m, linear_max_joint_step_rad (an unknown key is an
    ``InputError``). ``plan_to_pose(..., linear=True)`` moves the TCP along a straight line (IK every
    ``linear_step_m`` continuing the previous solution; a line that cannot be followed is
    ``no_path``). ``held_json`` (the ObjectGeometry of the object in the hand, where it stood
    when grasped) with ``held_world_from_tcp`` (that grasp's TCP pose, 4x4): the held object moves
    with the hand and is kept clear of the obstacles too (not of the table, where it is put down);
    give both or neither (``InputError``)."""

    def __init__(self, urdf_path: str, config_json: str | None = None) -> None: ...
    def forward_tcp(self, q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
    def tcp_jacobian(self, q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
    def link_poses(self, q: npt.NDArray[np.float64]) -> dict[str, npt.NDArray[np.float64]]: ...
    def joint_limits(self) -> npt.NDArray[np.float64]: ...
    def plan_to_joints(
        self,
        q_start: npt.NDArray[np.float64],
        q_goal: npt.NDArray[np.float64],
        obstacles_json: str,
        held_json: str | None = None,
        held_world_from_tcp: npt.NDArray[np.float64] | None = None,
    ) -> dict[str, Any]: ...
    def plan_to_pose(
        self,
        q_start: npt.NDArray[np.float64],
        world_from_tcp: npt.NDArray[np.float64],
        obstacles_json: str,
        held_json: str | None = None,
        held_world_from_tcp: npt.NDArray[np.float64] | None = None,
        *,
        linear: bool = False,
    ) -> dict[str, Any]: ...
    def inverse_tcp(
        self,
        world_from_tcp: npt.NDArray[np.float64],
        seed: npt.NDArray[np.float64],
        obstacles_json: str = "[]",
        restarts: bool = True,
    ) -> npt.NDArray[np.float64] | None: ...
    def path_is_free(self, positions: npt.NDArray[np.float64], obstacles_json: str) -> bool: ...
    def time_parameterize_path(
        self, positions: npt.NDArray[np.float64], max_joint_speed: float | None = None
    ) -> dict[str, Any]: ...
    def plan_grasp(self, q_start: npt.NDArray[np.float64], target_json: str, neighbours_json: str) -> dict[str, Any]: ...
