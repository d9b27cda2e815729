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
from .scene import SceneSpec, gt_objects, load_scene
from .world import MotionError, SensorFrame, SimWorld, UnreachablePoseError, look_at

#: Timing stages reported per frame (milliseconds).
STAGES = ("render", "detect", "core", "record")


@dataclass
class EpisodeResult:
    """What :func:`run_episode` returns."""

    run_dir: Path
    metrics: dict[str, Any]
    map_json: str
    frame_times_ms: dict[str, list[float]] = field(default_factory=dict)


def init_views(cfg: RunConfig) -> list[np.ndarray]:
    """The paper's initialisation: four views over the corners of the object area, looking down and
    slightly inward (``init.inward``), as ``world_from_camera`` (OpenCV axes)."""
    c = np.array([*cfg.init.center, 0.0])
    out = []
    # Near-left, far-left, far-right, near-right: a loop around the table without crossing it.
    for sx, sy in ((-1, 1), (1, 1), (1, -1), (-1, -1)):
        off = np.array([sx * cfg.init.half_span[0], sy * cfg.init.half_span[1], 0.0])
        eye = c + off + np.array([0.0, 0.0, cfg.init.height_m])
        target = c + (1.0 - cfg.init.inward) * off
        out.append(look_at(eye, target))
    return out


def views_for(cfg: RunConfig) -> list[np.ndarray]:
    """The view sequence of the configured strategy."""
    if cfg.strategy == "init":
        return init_views(cfg)
    raise ValueError(f"strategy: unknown {cfg.strategy!r}")


def _scene_path(cfg: RunConfig) -> Path:
    p = Path(cfg.scene)
    return p if p.is_absolute() else REPO_ROOT / p


def _make_run_dir(cfg: RunConfig, scene: SceneSpec) -> Path:
    runs = Path(cfg.runs_dir)
    if not runs.is_absolute():
        runs = REPO_ROOT / runs
    now = datetime.now()
    base = runs / now.strftime("%Y-%m-%d") / f"{now.strftime('%H%M%S')}_{cfg.strategy}_{scene.name}_{cfg.seed}"
    d, k = base, 1
    while d.exists():  # never reuse (and so never overwrite) a folder
        k += 1
        d = base.with_name(f"{base.name}-{k}")
    d.mkdir(parents=True)
    return d


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

    def __init__(self, path: Path | None) -> None:
        self.rec = _native.Recorder(str(path), "objslam") if path is not None else None

    def __getattr__(self, name: str) -> Callable[..., None]:
        if self.rec is None:
            return lambda *a, **k: None
        return getattr(self.rec, name)


def run_episode(cfg: RunConfig, *, progress: bool = True, on_frame: Callable[[SensorFrame], None] | None = None) -> EpisodeResult:
    """Run one episode and write its run folder. Raises on failure after marking the folder."""
    cfg.validate()
    scene = load_scene(_scene_path(cfg))
    run_dir = _make_run_dir(cfg, scene)
    (run_dir / "INCOMPLETE").write_text("this run has not finished (or failed: see status.json)\n")
    _write_json(run_dir / "status.json", {"status": "running", "started": datetime.now().isoformat()})
    import tomli_w

    (run_dir / "config.toml").write_text(tomli_w.dumps(to_dict(cfg)))
    rec = _Recorder(run_dir / "run.rrd" if cfg.record.enabled else None)
    mapper = _native.NaiveMapper(json.dumps(to_dict(cfg.naive)))
    t_start = time.perf_counter()
    times: dict[str, list[float]] = {s: [] for s in STAGES}
    events: list[str] = []
    est_positions: list[np.ndarray] = []
    gt_positions: list[np.ndarray] = []
    frames = 0
    views_done = 0
    try:
        rng_sensor = np.random.default_rng([cfg.seed, 1])
        rng_detector = np.random.default_rng([cfg.seed, 2])
        world = SimWorld(scene, cfg.camera, rng_sensor)
        detector = SimulatedDetector(cfg.detector, rng_detector)
        rec.log_objects("world/ground_truth", json.dumps(gt_objects(scene, world.ground_truth())))
        views = views_for(cfg)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(views), desc=f"{cfg.strategy} {scene.name} seed {cfg.seed}", unit="view")

        def process(frame: SensorFrame) -> None:
            nonlocal frames
            t0 = time.perf_counter()
            dets: list[Detection] = detector.detect(frame.segmentation, world.actor_to_object)
            t1 = time.perf_counter()
            mapper.update(
                index=frame.index,
                intrinsics=frame.intrinsics,
                depth=frame.depth_m,
                world_from_camera=frame.world_from_camera_fk,
                detections=[d.as_tuple() for d in dets],
            )
            t2 = time.perf_counter()
            est_positions.append(frame.world_from_camera_fk[:3, 3].copy())
            gt_positions.append(frame.world_from_camera_gt[:3, 3].copy())
            rec.set_frame(frame.index, frame.sim_time_s)
            rec.log_camera(
                world_from_camera=frame.world_from_camera_fk,
                intrinsics=frame.intrinsics,
                width=cfg.camera.width,
                height=cfg.camera.height,
            )
            if frame.index % cfg.record.every_n_frames == 0:
                if cfg.record.rgb:
                    rec.log_rgb(frame.rgb)
                if cfg.record.depth:
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

        for vi, view in enumerate(views):
            try:
                it = world.move_camera_to(view, frame_rate_hz=cfg.frame_rate_hz, max_joint_speed=cfg.max_joint_speed, what=f"view {vi}")
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
                views_done += 1
            except (UnreachablePoseError, MotionError) as e:
                events.append(f"view {vi} skipped: {e}")
                rec.log_event(f"view {vi} skipped: {e}")
            if bar is not None:
                bar.update(1)
            (run_dir / "map.json.partial").write_text(mapper.map_json())
        if bar is not None:
            bar.close()

        map_json = mapper.map_json()
        _native.save_map(map_json, str(run_dir / "map.json"))
        (run_dir / "map.json.partial").unlink(missing_ok=True)
        gt = gt_objects(scene, world.ground_truth())
        rec.log_objects("world/ground_truth", json.dumps(gt))
        evaluation = json.loads(
            _native.evaluate_map(json.dumps(gt), map_json, json.dumps(to_dict(cfg.eval)))
        )
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
            "wall_s": wall_s,
            "mean": evaluation["mean"],
            "objects": evaluation["objects"],
            "n_matched": evaluation["n_matched"],
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
            (run_dir / "map.json.partial").write_text(mapper.map_json())
            rec.close()
        except Exception:  # noqa: BLE001 - best effort while already failing
            pass
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
        f"scene {metrics['scene']}  strategy {metrics['strategy']}  seed {metrics['seed']}  "
        f"views {metrics['views']}  frames {metrics['frames']}  objects est/gt "
        f"{metrics['n_objects_est']}/{metrics['n_objects_gt']}  path {metrics['path_length_m']:.2f} m  "
        f"wall {metrics['wall_s']:.1f} s",
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
    t = metrics.get("timings_ms_median", {})
    lines.append("median ms/frame: " + "  ".join(f"{k} {f(v, '.1f')}" for k, v in t.items()))
    return "\n".join(lines)
