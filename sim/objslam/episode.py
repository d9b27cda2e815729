"""One exploration episode: scene → simulator → core → object map → metrics → Rerun recording.

Entry point: :func:`run_episode` (and the CLI ``experiments/run.py``). Per frame, data flows one
way: the body senses (:meth:`SimWorld.render`), the simulated detector boxes the objects, the core
fuses the frame into the object map, the recorder logs everything. Ground truth goes only to the
evaluation and to its own entity paths in the recording.

Run folder: ``<runs_dir>/<YYYY-MM-DD>/<HHMMSS>_<strategy>_<scene>_<seed>/`` holding ``config.toml``
(resolved), ``status.json``, ``map.json``, ``metrics.json`` and ``run.rrd``. While a run is going,
and if it fails, the folder holds an ``INCOMPLETE`` marker and ``status.json`` says why; earlier
run folders are never touched. ``<runs_dir>/latest`` is re-pointed at a run when it completes.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from . import _native
from .config import REPO_ROOT, RunConfig, to_dict
from .detector import Detection, SimulatedDetector
from .evaluation import offset_removed
from .scene import SceneSpec, gt_objects, load_scene
from .strategy import DecisionStep, as_view, make_strategy
from .world import MotionError, SensorFrame, SimWorld, UnreachablePoseError, panda_urdf_path, pose_to_matrix

#: Timing stages reported per frame (milliseconds).
STAGES = ("render", "detect", "core", "record")


@dataclass
class EpisodeResult:
    """What :func:`run_episode` returns."""

    run_dir: Path
    metrics: dict[str, Any]
    map_json: str
    frame_times_ms: dict[str, list[float]] = field(default_factory=dict)


#: Grid cell colours by state: unknown grey, free green, occupied red.
MAP_POINT_COLOR = np.array([240, 200, 40], dtype=np.uint8)
GRID_COLORS = np.array([[150, 150, 150], [60, 200, 60], [220, 50, 50]], dtype=np.uint8)
TABLE_UNSEEN_COLOR = np.array([200, 60, 200], dtype=np.uint8)
"""Table-top cells not seen yet (explore::discovery), recorded after each view."""
TABLE_UNEXPLAINED_COLOR = np.array([255, 140, 0], dtype=np.uint8)
"""Unexplained table-top cells: object evidence (depth returns above the table) that no map object
explains, i.e. an object the depth shows and the map lacks (explore::discovery)."""


def _log_table(rec: Any, mapper: Any, cells: bool) -> None:
    """Record the table-top coverage after a view: the known fraction and the unexplained cell
    count as scalars and, with ``cells``, the unknown cells (``world/map/table_unseen``) and the
    unexplained ones (``world/map/table_unexplained``) as points."""
    rec.log_scalar("explore/table_known_fraction", mapper.table_known_curve()[-1])
    rec.log_scalar("explore/table_unexplained_cells", float(mapper.table_unexplained_curve()[-1]))
    if not cells:
        return
    pts, unexplained = mapper.table_unknown_cells()
    mask = np.asarray(unexplained, dtype=bool).reshape(-1)
    for entity, sel, colour in (
        ("world/map/table_unseen", ~mask, TABLE_UNSEEN_COLOR),
        ("world/map/table_unexplained", mask, TABLE_UNEXPLAINED_COLOR),
    ):
        rec.log_colored_points(entity, pts[sel], np.tile(colour, (int(sel.sum()), 1)), 0.008)


def grey_of(rgb: np.ndarray) -> np.ndarray:
    """ITU-R BT.601 luma of an (H, W, 3) uint8 image, as uint8."""
    g = (
        rgb[..., 0].astype(np.float32) * 0.299
        + rgb[..., 1].astype(np.float32) * 0.587
        + rgb[..., 2].astype(np.float32) * 0.114
    )
    return np.clip(g + 0.5, 0, 255).astype(np.uint8)


def active_config(cfg: RunConfig) -> dict[str, Any]:
    """The core's ``ActiveConfig`` JSON from a run config."""
    e = to_dict(cfg.explore)
    e["lambda"] = e.pop("utility_lambda")
    # A Python strategy decides in Python; the core session only keeps the grids and the history.
    return {"strategy": "init" if cfg.python_strategy else cfg.strategy, "seed": cfg.seed, **e}


def _log_decision(rec: Any, decision: dict[str, Any]) -> None:
    """Candidate views as arrows coloured by utility (blue low → red high), the chosen one white."""
    cands = decision.get("candidates") or []
    if cands:
        poses = np.array([c[0] for c in cands])
        util = np.array([c[1] for c in cands], dtype=float)
        finite = np.isfinite(util)
        lo, hi = (util[finite].min(), util[finite].max()) if finite.any() else (0.0, 1.0)
        t = np.where(finite, (util - lo) / max(hi - lo, 1e-12), 0.0)
        colors = np.stack([255 * t, 40 + 0 * t, 255 * (1 - t)], axis=1).astype(np.uint8)
        rec.log_arrows("world/explore/candidates", poses[:, :3, 3], 0.08 * poses[:, :3, 2], colors)
    chosen = decision["world_from_camera"]
    rec.log_arrows(
        "world/explore/chosen",
        chosen[None, :3, 3],
        0.12 * chosen[None, :3, 2],
        np.array([[255, 255, 255]], dtype=np.uint8),
    )
    if np.isfinite(decision.get("utility", float("nan"))):
        rec.log_scalar("explore/utility", float(decision["utility"]))


def _python_decision(
    strategy: Any, cfg: RunConfig, scene: SceneSpec, mapper: Any, world: SimWorld, rng: np.random.Generator
) -> dict[str, Any]:
    """One decision of a Python strategy (``objslam.strategy``), in the built-in decision's form."""
    if mapper.views_taken() >= mapper.max_views():
        return {"action": "stop", "reason": "max_views"}
    step = DecisionStep(
        mapper=mapper,
        intrinsics=world.intrinsics,
        width=cfg.camera.width,
        height=cfg.camera.height,
        world_from_camera=world.world_from_camera_fk(world.qpos()),
        reachable=world.is_reachable,
        rng=rng,
        table_center=(float(scene.table.center[0]), float(scene.table.center[1])),
        table_size=(float(scene.table.size[0]), float(scene.table.size[1])),
        explore=to_dict(cfg.explore),
    )
    view = as_view(strategy.next_view(step), f"{cfg.python_strategy}.next_view")
    if view is None:
        return {"action": "stop", "reason": step.stop_reason or "strategy_done"}
    if step.table_drawn:
        # A view the table gain helped choose counts towards discovery_evidence_max_views when
        # it sees unexplained cells, as the built-in strategies count theirs.
        mapper.note_chosen_view(
            intrinsics=world.intrinsics, width=cfg.camera.width, height=cfg.camera.height, world_from_camera=view
        )
    decision: dict[str, Any] = {"action": "move", "world_from_camera": view, "utility": float("nan")}
    if step.logged is not None:
        views, scores = step.logged
        decision["candidates"] = [(v, sc, None) for v, sc in zip(views, scores)]
        same = [sc for v, sc in zip(views, scores) if np.allclose(v, view, atol=1e-12)]
        if same:
            decision["utility"] = same[0]
    return decision


def _scene_path(cfg: RunConfig) -> Path:
    p = Path(cfg.scene)
    return p if p.is_absolute() else REPO_ROOT / p


def _make_run_dir(cfg: RunConfig, scene: SceneSpec) -> Path:
    runs = Path(cfg.runs_dir)
    if not runs.is_absolute():
        runs = REPO_ROOT / runs
    now = datetime.now()
    base = (
        runs / now.strftime("%Y-%m-%d") / f"{now.strftime('%H%M%S')}_{cfg.strategy}_{scene.name}_{cfg.seed}"
    )
    base.parent.mkdir(parents=True, exist_ok=True)
    d, k = base, 1
    while True:  # never reuse (and so never overwrite) a folder, even when workers start together
        try:
            d.mkdir()
            return d
        except FileExistsError:
            k += 1
            d = base.with_name(f"{base.name}-{k}")


def _write_json(path: Path, data: Any) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, allow_nan=False))
    os.replace(tmp, path)


def _update_latest(run_dir: Path) -> None:
    latest = run_dir.parent.parent / "latest"
    tmp = latest.with_name("latest.tmp")
    if tmp.is_symlink() or tmp.exists():
        tmp.unlink()
    tmp.symlink_to(run_dir.relative_to(latest.parent))
    os.replace(tmp, latest)


class _Recorder:
    """Null-object wrapper so the pipeline does not branch on ``record.enabled``."""

    def __init__(self, path: Path | None, options: dict[str, Any] | None = None) -> None:
        self.rec = (
            _native.Recorder(str(path), "objslam", json.dumps(options or {})) if path is not None else None
        )

    def __getattr__(self, name: str) -> Callable[..., None]:
        if self.rec is None:
            return lambda *a, **k: None
        return getattr(self.rec, name)


def recording_options(cfg: RunConfig, scene: SceneSpec) -> dict[str, Any]:
    """The recorder's options (``objslam_core::record::RecordOptions``) for a run: frame encoding,
    live viewer, the table to draw and frame the 3D view on, the arm's URDF."""
    return {
        "jpeg_quality": cfg.record.jpeg_quality,
        "depth_png": cfg.record.jpeg_quality > 0,
        "live_url": cfg.record.live_url or None,
        "table": {"center": list(scene.table.center), "size": list(scene.table.size)},
        "robot_urdf": str(panda_urdf_path()) if cfg.record.robot else None,
    }


def _log_robot(rec: Any, world: SimWorld) -> None:
    """The simulated arm's link poses (``world/robot/<link>``), for drawing only."""
    rec.log_robot_pose({link.name: pose_to_matrix(link.entity_pose) for link in world.robot.get_links()})


def new_mapper(cfg: RunConfig, scene: SceneSpec) -> Any:
    """A fresh :class:`_native.ActiveMapper` (association, parameterization, grids, tracker) for
    a run config and scene (also used for the local re-observation maps of :mod:`objslam.grasp`)."""
    seeds = algorithm_seeds(cfg.seed, scene.seed) if cfg.seed_algorithms else None
    return _native.ActiveMapper(
        mapper_config_json=json.dumps(
            {
                "association_mode": cfg.association_mode,
                "parameterize": cfg.parameterize,
                "consolidate": cfg.consolidate,
                "consolidate_cloud_overlap": cfg.consolidate_cloud_overlap,
                "relabel_vote_ratio": cfg.relabel_vote_ratio,
                "min_observations": cfg.min_observations,
                "follow_slam_gauge": cfg.follow_slam_gauge,
                # Only when not the default, so a core built before the option still loads.
                **({"object_points": cfg.object_points} if cfg.object_points != "depth" else {}),
                "naive": to_dict(cfg.naive),
                "param": {
                    "iforest": {
                        **({"seed": seeds["iforest"]} if seeds else {}),
                        "passes": cfg.param.iforest_passes,
                        "readmit_rings": cfg.param.iforest_readmit_rings,
                        "readmit_gap_factor": cfg.param.iforest_readmit_gap,
                    },
                    "window_keep": cfg.param.window_keep,
                    # The table top is z = 0 (scene files); 0 = no support snap.
                    **(
                        {"support_z_m": 0.0, "support_snap_m": cfg.param.support_snap_m}
                        if cfg.param.support_snap_m > 0.0
                        else {}
                    ),
                    "cylinder": {
                        **({"seed": seeds["cylinder"]} if seeds else {}),
                        "enabled": cfg.param.cylinder_fit,
                        "consensus_iterations": cfg.param.cylinder_consensus_iterations,
                        "top_from_face": cfg.param.cylinder_top_from_face,
                    },
                    "refine": {
                        "refine_center": cfg.param.refine_center,
                        "prior_px_per_m": cfg.param.refine_prior_px_per_m,
                    },
                },
            }
        ),
        active_config_json=json.dumps(active_config(cfg)),
        table=(*scene.table.center, *scene.table.size),
        tracker_config_json=None
        if cfg.pose_source == "fk"
        else json.dumps(
            {
                "pose_source": cfg.pose_source,
                "motion_gate_floor_m": cfg.slam_motion_gate_m,
                "motion_gate_floor_deg": cfg.slam_motion_gate_deg,
                "motion_gate_references": cfg.slam_motion_gate_references,
                "extend_after_unmapped": cfg.slam_extend_after_unmapped,
                "kinematic_noise": {**to_dict(cfg.pose_noise), "seed": kinematic_noise_seed(cfg.seed, scene.seed)},
                **({"ransac": {"seed": seeds["ransac"]}} if seeds else {}),
            }
        ),
    )


def kinematic_noise_seed(run_seed: int, scene_seed: int) -> int:
    """Seed of the kinematic prior noise: the run seed mixed with the scene file's seed, so every
    episode of a benchmark draws its own per-view biases. (With the run seed alone, view k had the
    same bias in every scene: strategies whose views do not depend on the scene, coverage and
    init, then carried one shared draw of the map's placement error through all seven scenes.)"""
    return (run_seed * 1_000_003 + scene_seed) % (1 << 63)


def algorithm_seeds(run_seed: int, scene_seed: int) -> dict[str, int]:
    """Seeds of the mapper's own random streams (``RunConfig.seed_algorithms``): the isolation
    forest, the cylinder fit's consensus circles and the tracker's PnP RANSAC, each a distinct
    mix of the run and scene seeds (SplitMix64 of the kinematic noise seed and a stream tag), so
    no two streams, runs or scenes share one."""

    def splitmix(x: int) -> int:
        x = (x + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
        x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
        x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
        return (x ^ (x >> 31)) % (1 << 63)

    base = kinematic_noise_seed(run_seed, scene_seed)
    return {name: splitmix(base ^ (tag << 56)) for tag, name in enumerate(("iforest", "cylinder", "ransac"), 1)}


def run_episode(
    cfg: RunConfig, *, progress: bool = True, on_frame: Callable[[SensorFrame], None] | None = None
) -> EpisodeResult:
    """Run one episode and write its run folder. Raises on failure after marking the folder."""
    cfg.validate()
    scene = load_scene(_scene_path(cfg))
    run_dir = _make_run_dir(cfg, scene)
    (run_dir / "INCOMPLETE").write_text("this run has not finished (or failed: see status.json)\n")
    _write_json(run_dir / "status.json", {"status": "running", "started": datetime.now().isoformat()})
    import tomli_w

    (run_dir / "config.toml").write_text(tomli_w.dumps(to_dict(cfg)))
    rec = _Recorder(run_dir / "run.rrd" if cfg.record.enabled else None, recording_options(cfg, scene))
    mapper = None
    t_start = time.perf_counter()
    times: dict[str, list[float]] = {s: [] for s in STAGES}
    events: list[str] = []
    est_positions: list[np.ndarray] = []
    gt_positions: list[np.ndarray] = []
    frames = 0
    views_done = 0
    assignments: list[tuple[int, int | None]] = []
    view_counter = [0]
    move_paths: dict[str, int] = {"cartesian": 0, "joint": 0}
    accuracy_curve: list[dict[str, Any]] = []
    try:
        mapper = new_mapper(cfg, scene)
        rng_sensor = np.random.default_rng([cfg.seed, 1])
        rng_detector = np.random.default_rng([cfg.seed, 2])
        world = SimWorld(scene, cfg.camera, rng_sensor)
        detector = SimulatedDetector(cfg.detector, rng_detector)
        # The truth and the arm's start pose at the first frame's time, so the viewer shows them from the start.
        rec.set_frame(0, 0.0)
        rec.log_objects("world/ground_truth", json.dumps(gt_objects(scene, world.ground_truth())))
        if cfg.record.robot:
            _log_robot(rec, world)
        init_views = mapper.initial_views()
        budget = len(init_views) + (0 if cfg.strategy == "init" else cfg.explore.max_views)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=budget, desc=f"{cfg.strategy} {scene.name} seed {cfg.seed}", unit="view")

        def process(frame: SensorFrame) -> None:
            nonlocal frames
            t0 = time.perf_counter()
            dets: list[Detection] = detector.detect(frame.segmentation, world.actor_to_object)
            t1 = time.perf_counter()
            assigned = mapper.update(
                index=frame.index,
                intrinsics=frame.intrinsics,
                depth=frame.depth_m,
                world_from_camera=frame.world_from_camera_fk,
                detections=[d.as_tuple() for d in dets],
                grey=grey_of(frame.rgb) if (cfg.parameterize or cfg.pose_source != "fk") else None,
                world_from_camera_gt=frame.world_from_camera_gt,
                view_index=view_counter[0],
            )
            used_pose = mapper.last_pose()
            assignments.extend((oid, d.gt_id) for oid, d in zip(assigned, dets) if oid is not None)
            t2 = time.perf_counter()
            est_positions.append(used_pose[:3, 3].copy())
            gt_positions.append(frame.world_from_camera_gt[:3, 3].copy())
            rec.set_frame(frame.index, frame.sim_time_s)
            if cfg.record.robot:
                _log_robot(rec, world)
            rec.log_camera(
                world_from_camera=used_pose,
                intrinsics=frame.intrinsics,
                width=cfg.camera.width,
                height=cfg.camera.height,
            )
            if frame.index % cfg.record.every_n_frames == 0:
                if cfg.record.rgb:
                    rec.log_rgb(frame.rgb)
                depth_every = cfg.record.every_n_frames * cfg.record.depth_every_n_frames
                if cfg.record.depth and frame.index % depth_every == 0:
                    rec.log_depth(frame.depth_m)
            rec.log_detections([d.as_tuple() for d in dets])
            rec.log_trajectory("estimated", np.array(est_positions))
            rec.log_trajectory("ground_truth", np.array(gt_positions))
            rec.log_objects("world/map", mapper.objects_json())
            t3 = time.perf_counter()
            times["detect"].append((t1 - t0) * 1e3)
            times["core"].append((t2 - t1) * 1e3)
            times["record"].append((t3 - t2) * 1e3)
            for s in ("detect", "core", "record"):
                rec.log_scalar(f"timings/{s}_ms", times[s][-1])
            frames += 1
            if on_frame is not None:
                on_frame(frame)
            if bar is not None:
                bar.set_postfix(frames=frames, objects=len(mapper))

        gt_scene_file = gt_objects(scene)

        def snapshot() -> None:
            """Evaluate the map as it stands after a view (``accuracy_curve`` in metrics.json)."""
            map_json = mapper.map_json()
            ev = json.loads(
                _native.evaluate_map(
                    json.dumps(gt_objects(scene, world.ground_truth())), map_json, json.dumps(to_dict(cfg.eval))
                )
            )
            accuracy_curve.append(
                {
                    "views": views_done,
                    **{k: ev["mean"][k] for k in ("iou3d", "iou2d", "cde_cm")},
                    "n_objects_est": ev["n_objects_est"],
                    **offset_removed(gt_scene_file, json.loads(map_json), ev["objects"]),
                }
            )
            # Evaluation against ground truth, on its own entity paths (the viewer plots it over time).
            for k in ("iou3d", "cde_cm", "iou3d_aligned"):
                if accuracy_curve[-1][k] is not None:
                    rec.log_scalar(f"eval/{k}", accuracy_curve[-1][k])

        def execute(view: np.ndarray, what: str) -> bool:
            """Move to a view while fusing the streamed frames; False if it was skipped."""
            try:
                it = world.move_camera_to(
                    view,
                    frame_rate_hz=cfg.frame_rate_hz,
                    max_joint_speed=cfg.max_joint_speed,
                    what=what,
                    path=cfg.camera_path,
                )
                while True:
                    t0 = time.perf_counter()
                    try:
                        frame = next(it)
                    except StopIteration:
                        break
                    times["render"].append((time.perf_counter() - t0) * 1e3)
                    rec.set_frame(frame.index, frame.sim_time_s)
                    rec.log_scalar("timings/render_ms", times["render"][-1])
                    process(frame)
                ok = True
                move_paths[world.last_move_path] += 1
            except (UnreachablePoseError, MotionError) as e:
                events.append(f"{what} skipped: {e}")
                rec.log_event(f"{what} skipped: {e}")
                ok = False
            view_counter[0] += 1
            if cfg.record.map_points:
                pts = mapper.map_points()
                if pts is not None and len(pts):
                    rec.log_colored_points(
                        "world/map/points", pts, np.tile(MAP_POINT_COLOR, (len(pts), 1)), 0.002
                    )
            if bar is not None:
                bar.update(1)
            (run_dir / "map.json.partial").write_text(mapper.map_json())
            return ok

        for vi, view in enumerate(init_views):
            views_done += execute(view, f"init view {vi}")
            mapper.view_done(False)
            snapshot()
        rec.log_scalar("explore/mean_normalized_entropy", mapper.entropy_curve()[-1])
        _log_table(rec, mapper, cfg.record.grids)
        stop_reason = "strategy_done"
        user_strategy = make_strategy(cfg.python_strategy, cfg.python_strategy_params) if cfg.python_strategy else None
        rng_strategy = np.random.default_rng([cfg.seed, 3])
        while True:
            # Candidate views are reachable only with a collision-free arm among the mapped objects.
            world.set_obstacles(mapper.objects_json())
            if user_strategy is None:
                decision = mapper.next_view(
                    intrinsics=world.intrinsics,
                    width=cfg.camera.width,
                    height=cfg.camera.height,
                    world_from_camera=world.world_from_camera_fk(world.qpos()),
                    reachable=world.is_reachable,
                )
            else:
                decision = _python_decision(user_strategy, cfg, scene, mapper, world, rng_strategy)
            if decision["action"] == "stop":
                stop_reason = decision["reason"]
                rec.log_event(f"stop: {stop_reason}")
                break
            _log_decision(rec, decision)
            views_done += execute(decision["world_from_camera"], f"view {mapper.views_taken() + 1}")
            mapper.view_done(True)
            snapshot()
            rec.log_scalar("explore/mean_normalized_entropy", mapper.entropy_curve()[-1])
            _log_table(rec, mapper, cfg.record.grids)
            if cfg.record.grids:
                pts, states = mapper.grid_cells()
                rec.log_colored_points(
                    "world/map/grids", pts, GRID_COLORS[np.frombuffer(states, dtype=np.uint8)], 0.004
                )
        if bar is not None:
            bar.close()

        mapper.refresh_estimates()
        map_json = mapper.map_json()
        _native.save_map(map_json, str(run_dir / "map.json"))
        (run_dir / "map.json.partial").unlink(missing_ok=True)
        gt = gt_objects(scene, world.ground_truth())
        rec.log_objects("world/ground_truth", json.dumps(gt))
        if cfg.record.estimator_inputs:
            inputs = json.loads(mapper.estimator_inputs_json())
            (run_dir / "estimator_inputs.json").write_text(
                json.dumps({"objects": inputs, "ground_truth": gt})
            )
        evaluation = json.loads(_native.evaluate_map(json.dumps(gt), map_json, json.dumps(to_dict(cfg.eval))))
        stages = {}
        for stage in ("raw", "iforest", "lines", "refined"):
            ev = json.loads(
                _native.evaluate_map(
                    json.dumps(gt), mapper.stage_map_json(stage), json.dumps(to_dict(cfg.eval))
                )
            )
            stages[stage] = ev["mean"]
        association = json.loads(mapper.association_metrics_json(assignments, [o.id for o in scene.objects]))
        wall_s = time.perf_counter() - t_start
        metrics = {
            "scene": scene.name,
            "strategy": cfg.strategy,
            "seed": cfg.seed,
            "n_objects_gt": evaluation["n_objects_gt"],
            "n_objects_est": evaluation["n_objects_est"],
            "views": views_done,
            "frames": frames,
            "path_length_m": world.camera_path_length_m,
            "moves_by_path": dict(move_paths),
            "wall_s": wall_s,
            "mean": evaluation["mean"],
            "objects": evaluation["objects"],
            "n_matched": evaluation["n_matched"],
            "nbv_views": mapper.views_taken(),
            "association_mode": cfg.association_mode,
            "pose_source": cfg.pose_source,
            **(mapper.pose_metrics() or {}),
            "association": association,
            "stages": stages,
            "stop_reason": stop_reason,
            "entropy_curve": mapper.entropy_curve(),
            "table_known_curve": mapper.table_known_curve(),
            "table_unexplained_curve": mapper.table_unexplained_curve(),
            "accuracy_curve": accuracy_curve,
            "timings_ms_median": {s: (statistics.median(v) if v else None) for s, v in times.items()},
            "events": events,
        }
        _write_json(run_dir / "metrics.json", metrics)
        rec.log_event(f"done: mean 3D IoU {metrics['mean']['iou3d']:.3f}")
        rec.close()
        _write_json(run_dir / "status.json", {"status": "complete", "finished": datetime.now().isoformat()})
        (run_dir / "INCOMPLETE").unlink()
        _update_latest(run_dir)
        return EpisodeResult(run_dir=run_dir, metrics=metrics, map_json=map_json, frame_times_ms=times)
    except BaseException as e:
        # Keep everything written so far; mark the folder as failed and say why.
        try:
            if mapper is not None:
                (run_dir / "map.json.partial").write_text(mapper.map_json())
            rec.close()
        except Exception as cleanup:  # noqa: BLE001 - best effort while already failing
            print(f"run folder {run_dir}: could not save the partial map: {cleanup}", file=sys.stderr)
        _write_json(
            run_dir / "status.json",
            {"status": "failed", "error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()},
        )
        raise


def format_table(metrics: dict[str, Any]) -> str:
    """A per-object table and the means, for the terminal."""

    def f(v: Any, spec: str) -> str:
        return "-" if v is None else format(v, spec)

    lines = [
        (
            f"scene {metrics['scene']}  strategy {metrics['strategy']}  seed {metrics['seed']}  "
            f"views {metrics['views']}  frames {metrics['frames']}  objects est/gt "
            f"{metrics['n_objects_est']}/{metrics['n_objects_gt']}  path {metrics['path_length_m']:.2f} m  "
            f"wall {metrics['wall_s']:.1f} s"
        ),
        f"{'gt':>3} {'class':<9} {'est':>4} {'IoU3D':>6} {'IoU2D':>6} {'CDE cm':>7} {'YAE deg':>8}",
    ]
    for o in metrics["objects"]:
        lines.append(
            f"{o['gt_id']:>3} {o['label']:<9} {f(o['est_id'], 'd'):>4} {o['iou3d']:>6.3f} {o['iou2d']:>6.3f} "
            f"{f(o['cde_cm'], '.2f'):>7} {f(o['yae_deg'], '.1f'):>8}"
        )
    m = metrics["mean"]
    lines.append(
        f"{'mean':<18} {m['iou3d']:>6.3f} {m['iou2d']:>6.3f} {f(m['cde_cm'], '.2f'):>7} {f(m['yae_deg'], '.1f'):>8}"
    )
    curve = metrics.get("accuracy_curve") or []
    if curve:
        lines.append("3D IoU after each view: " + " ".join(format(p["iou3d"], ".3f") for p in curve))
    t = metrics.get("timings_ms_median", {})
    lines.append("median ms/frame: " + "  ".join(f"{k} {f(v, '.1f')}" for k, v in t.items()))
    return "\n".join(lines)
