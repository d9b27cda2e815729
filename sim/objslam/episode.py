"""One exploration episode: scene → simulator → core → object map → metrics → Rerun recording.

Entry point: :func:`run_episode` (and the CLI ``experiments/run.py``), which runs an
:class:`Episode` step by step (setup, Init views, the view loop, finish). Per frame, data flows one
way: the body senses (:meth:`SimWorld.render`), the simulated detector boxes the objects, the core
fuses the frame into the object map, the recorder logs everything. Ground truth goes only to the
evaluation and to its own entity paths in the recording.

Run folder: ``<runs_dir>/<YYYY-MM-DD>/<HHMMSS>_<strategy>_<scene>_<seed>/`` holding ``config.toml``
(resolved), ``status.json``, ``map.json``, ``metrics.json`` and ``run.rrd``. While a run is going,
and if it stops early, the folder holds an ``INCOMPLETE`` marker and ``status.json`` says why;
earlier run folders are never touched, and no folder is made outside ``runs_dir`` (scene names and
strategy labels are checked by :func:`objslam.scene.path_name_problem`). ``<runs_dir>/latest`` is
re-pointed at a run when it completes.

``status.json`` records ``pid``, ``host`` and ``started`` from the start, and at the end
``status`` = ``complete``, ``failed`` (an error, e.g. a full disk), ``interrupted`` (SIGINT,
Ctrl-C) or ``terminated`` (SIGTERM, as sent by ``timeout``, docker or Slurm) with ``finished``. A
run killed outright (SIGKILL, power loss) stays ``running``: ``python -m objslam.runs`` tells it
from a live run by its pid and host. Every file is written atomically (a temporary file, flushed,
renamed), so a failed write never truncates what was already complete; the map so far is kept in
``map.json.partial`` after every view.
"""

from __future__ import annotations

import copy
import gc
import json
import os
import signal
import socket
import statistics
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from . import _native
from .calibration import (
    STREAM_DETECTOR,
    STREAM_SENSOR,
    STREAM_STRATEGY,
    ArmErrors,
    arm_error_seed,
    draw_arm_errors,
    draw_table_plane,
    episode_rng,
    pose_error,
)
from .config import REPO_ROOT, ConfigError, RunConfig, to_dict
from .detector import Detection, SimulatedDetector
from .evaluation import offset_removed
from .scene import SceneFileError, SceneSpec, gt_objects, load_scene, path_name_problem
from .strategy import DecisionStep, as_view, make_strategy
from .world import MotionError, SensorFrame, SimWorld, UnreachablePoseError, panda_urdf_path, pose_to_matrix

#: Timing stages reported per frame (milliseconds).
STAGES = ("render", "sensor", "motion", "detect", "core", "record")


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


def _progress(mapper: Any) -> dict[str, Any]:
    """The core session's progress (``objslam_core::system::Progress``: ``views_taken``,
    ``max_views`` and the curves after each view)."""
    return mapper.query('{"query": "progress"}')


def _log_table(rec: Any, mapper: Any, cells: bool) -> None:
    """Record the table-top coverage after a view: the known fraction and the unexplained cell
    count as scalars and, with ``cells``, the unknown cells (``world/map/table_unseen``) and the
    unexplained ones (``world/map/table_unexplained``) as points."""
    progress = _progress(mapper)
    rec.log_scalar("explore/table_known_fraction", progress["table_known_curve"][-1])
    rec.log_scalar("explore/table_unexplained_cells", float(progress["table_unexplained_curve"][-1]))
    if not cells:
        return
    pts, unexplained = mapper.table_unknown_cells()
    mask = np.asarray(unexplained, dtype=bool).reshape(-1)
    for entity, sel, colour in (
        ("world/map/table_unseen", ~mask, TABLE_UNSEEN_COLOR),
        ("world/map/table_unexplained", mask, TABLE_UNEXPLAINED_COLOR),
    ):
        rec.log_points(entity, pts[sel], colors=np.tile(colour, (int(sel.sum()), 1)), radius_m=0.008)


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
    # A Python strategy decides in Python; the core session only keeps the grids and the history.
    return {**cfg.explore, "strategy": cfg.core_strategy, "seed": cfg.seed}


def _log_decision(rec: Any, decision: dict[str, Any]) -> None:
    """Candidate views as arrows coloured by utility (blue low → red high), the chosen one white."""
    cands = decision.get("candidates") or []
    if cands:
        poses = np.array([c["world_from_camera"] for c in cands])
        util = np.array([c["utility"] for c in cands], dtype=float)
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
    utility = decision.get("utility")
    if utility is not None and np.isfinite(utility):
        rec.log_scalar("explore/utility", float(utility))


def _python_decision(
    strategy: Any, cfg: RunConfig, scene: SceneSpec, mapper: Any, world: SimWorld, rng: np.random.Generator
) -> dict[str, Any]:
    """One decision of a Python strategy (``objslam.strategy``), in the built-in decision's form."""
    progress = _progress(mapper)
    if progress["views_taken"] >= progress["max_views"]:
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
        explore=dict(cfg.explore),
    )
    view = as_view(strategy.next_view(step), f"{cfg.python_strategy}.next_view")
    if view is None:
        return {"action": "stop", "reason": step.stop_reason or "strategy_done"}
    if step.table_drawn:
        # A view the table gain helped choose counts towards discovery_evidence_max_views when
        # it sees unexplained cells, as the built-in strategies count theirs.
        mapper.note_chosen_view(
            intrinsics=world.intrinsics,
            width=cfg.camera.width,
            height=cfg.camera.height,
            world_from_camera=view,
        )
    decision: dict[str, Any] = {"action": "move", "world_from_camera": view, "utility": None}
    if step.logged is not None:
        views, scores = step.logged
        decision["candidates"] = [
            {"world_from_camera": v, "utility": sc, "reachable": None} for v, sc in zip(views, scores)
        ]
        same = [sc for v, sc in zip(views, scores) if np.allclose(v, view, atol=1e-12)]
        if same:
            decision["utility"] = same[0]
    return decision


def _scene_path(cfg: RunConfig) -> Path:
    p = Path(cfg.scene)
    return p if p.is_absolute() else REPO_ROOT / p


class RunStopped(BaseException):
    """A run stopped by a signal (SIGINT or SIGTERM) after its folder was marked ``interrupted`` or
    ``terminated``. Like :class:`KeyboardInterrupt` it is not an :class:`Exception`, so sweeps that
    catch failed runs still stop."""

    def __init__(self, signum: int, run_dir: Path) -> None:
        super().__init__(f"run {_STOP_STATUS[signum]} by {signal.Signals(signum).name}: {run_dir}")
        self.signum = signum
        self.run_dir = run_dir

    @property
    def status(self) -> str:
        """``interrupted`` (SIGINT) or ``terminated`` (SIGTERM)."""
        return _STOP_STATUS[self.signum]

    @property
    def exit_code(self) -> int:
        """The shell's exit status for the signal: 130 for SIGINT, 143 for SIGTERM."""
        return 128 + self.signum


_STOP_STATUS = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}


class _Terminated(BaseException):
    """Raised in the main thread by the SIGTERM handler of :func:`run_episode`."""


def _on_sigterm(signum: int, frame: Any) -> None:
    raise _Terminated()


def frame_budget(times: dict[str, list[float]]) -> dict[str, float | None]:
    """The per-frame budget: medians over frames of core + sensor + record (the work beside the
    renderer on the robot's side of every frame) and of render, ms, and their ratio (target: at most
    1/3)."""
    n = min(len(times.get(s, [])) for s in ("render", "sensor", "core", "record"))
    if n == 0:
        return {"core_sensor_record": None, "render": None, "ratio": None}
    own = statistics.median(times["core"][i] + times["sensor"][i] + times["record"][i] for i in range(n))
    render = statistics.median(times["render"][:n])
    return {"core_sensor_record": own, "render": render, "ratio": own / render if render > 0 else None}


def _make_run_dir(cfg: RunConfig, scene: SceneSpec) -> Path:
    runs = Path(cfg.runs_dir)
    if not runs.is_absolute():
        runs = REPO_ROOT / runs
    problem = path_name_problem(scene.name)
    if problem is not None:
        raise SceneFileError(scene.path or "<scene>", "scene.name", problem)
    problem = path_name_problem(cfg.strategy)
    if problem is not None:
        raise ConfigError(f"strategy: {problem} (the label becomes part of the run folder's name)")
    now = datetime.now()
    base = (
        runs / now.strftime("%Y-%m-%d") / f"{now.strftime('%H%M%S')}_{cfg.strategy}_{scene.name}_{cfg.seed}"
    )
    if not base.resolve().is_relative_to(runs.resolve()):
        raise ConfigError(f"runs_dir: the run folder {base} would lie outside {runs}")
    base.parent.mkdir(parents=True, exist_ok=True)
    d, k = base, 1
    while True:  # never reuse (and so never overwrite) a folder, even when workers start together
        try:
            d.mkdir()
            return d
        except FileExistsError:
            k += 1
            d = base.with_name(f"{base.name}-{k}")


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically: a temporary file beside it, flushed to disk, renamed
    over ``path``. On failure (a full disk) the temporary file is removed and ``path`` keeps its
    previous content."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _write_json(path: Path, data: Any) -> None:
    _write_atomic(path, json.dumps(data, indent=2, allow_nan=False))


def _status_start() -> dict[str, Any]:
    """The fields of ``status.json`` that let a reader tell a live run from a dead one."""
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": datetime.now().isoformat(timespec="seconds"),
        "command": sys.argv,
    }


def _finish_status(run_dir: Path, start: dict[str, Any], status: str, **extra: Any) -> None:
    """Write the final ``status.json``; when even that fails (a full disk), say so on stderr: the
    ``INCOMPLETE`` marker and the recorded pid still tell a reader the run did not complete."""
    try:
        _write_json(
            run_dir / "status.json",
            {"status": status, **start, "finished": datetime.now().isoformat(timespec="seconds"), **extra},
        )
    except OSError as e:
        print(f"run folder {run_dir}: could not write status.json ({status}): {e}", file=sys.stderr)


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


def mapper_config(
    cfg: RunConfig, table: tuple[float, float, float], seeds: dict[str, int] | None
) -> dict[str, Any]:
    """The core's ``PipelineConfig``: the run's ``[map]`` table with the episode's inputs filled in:
    the table plane the cell's calibration gives (``[table]``: the local clouds cut the table around
    it, and with ``param.support_snap_m`` > 0 estimates resting near it are extended down to it),
    and, with ``seed_algorithms``, the iForest and cylinder-fit seeds."""
    m = copy.deepcopy(cfg.map)
    m.setdefault("local", {})["table_prior"] = list(table)
    param = m.setdefault("param", {})
    if param.get("support_snap_m", 0.0) > 0.0:
        param["support_z_m"] = table[2]
        param["support_slope"] = [table[0], table[1]]
    if seeds:
        param.setdefault("iforest", {})["seed"] = seeds["iforest"]
        param.setdefault("cylinder", {})["seed"] = seeds["cylinder"]
    return m


def new_mapper(cfg: RunConfig, scene: SceneSpec) -> Any:
    """A fresh :class:`_native.ActiveMapper` (association, parameterization, grids, tracker) for
    a run config and scene (also used for the local re-observation maps of :mod:`objslam.grasp`)."""
    seeds = algorithm_seeds(cfg.seed, scene.seed) if cfg.seed_algorithms else None
    table = episode_table_plane(cfg, scene)
    return _native.ActiveMapper(
        mapper_config_json=json.dumps(mapper_config(cfg, table, seeds)),
        active_config_json=json.dumps(active_config(cfg)),
        table=(*scene.table.center, *scene.table.size),
        tracker_config_json=None
        if cfg.pose_source == "fk"
        else json.dumps(
            {
                **cfg.slam,
                "pose_source": cfg.pose_source,
                **({"ransac": {**cfg.slam.get("ransac", {}), "seed": seeds["ransac"]}} if seeds else {}),
            }
        ),
    )


def kinematic_noise_seed(run_seed: int, scene_seed: int) -> int:
    """The episode's seed: the run seed mixed with the scene file's seed (the arm and table
    calibration draws, :func:`objslam.calibration.arm_error_seed`, and the algorithm seeds), so every
    episode of a benchmark draws its own. (With the run seed alone, strategies whose views do not
    depend on the scene, coverage and init, carried one shared draw through all seven scenes.)"""
    return arm_error_seed(run_seed, scene_seed)


def episode_arm_errors(cfg: RunConfig, scene: SceneSpec) -> ArmErrors:
    """How the episode's simulated robot differs from its nominal model (``[robot]``), drawn from the
    run and scene seeds; the grasp and placement worlds of the same run and scene get the same robot."""
    return draw_arm_errors(cfg.robot, arm_error_seed(cfg.seed, scene.seed))


def episode_table_plane(cfg: RunConfig, scene: SceneSpec) -> tuple[float, float, float]:
    """The table plane ``(a, b, c)`` (z = a·x + b·y + c) the mapper is given: the true top with the
    episode's calibration error (``[table]``)."""
    center = (float(scene.table.center[0]), float(scene.table.center[1]))
    return draw_table_plane(cfg.table, arm_error_seed(cfg.seed, scene.seed), center)


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
    return {
        name: splitmix(base ^ (tag << 56)) for tag, name in enumerate(("iforest", "cylinder", "ransac"), 1)
    }


class Episode:
    """One exploration episode, step by step; :func:`run_episode` runs it.

    Building it loads the scene and the core's system (config values the core refuses raise
    :class:`ConfigError` here) and makes the run folder. :meth:`run` then takes the steps:
    :meth:`setup` (folder marked running, resolved config, recording, simulated world and
    detector), :meth:`take_init_views`, :meth:`explore` (one :meth:`decide` and :meth:`step` per
    view until the strategy stops) and :meth:`finish` (final map, evaluation, ``metrics.json``,
    status ``complete``). Every view goes through :meth:`move_to`, which fuses the streamed frames
    (:meth:`fuse`), and is evaluated by :meth:`evaluate_view`.

    ``on_frame(frame)`` is called after each frame is fused; ``on_fused(frame, world_from_camera)``
    too, with the pose the mapper used for it (its estimate, in the map's frame), e.g. to keep
    keyframes for relocalisation (:mod:`objslam.reloc`)."""

    def __init__(
        self,
        cfg: RunConfig,
        *,
        progress: bool = True,
        on_frame: Callable[[SensorFrame], None] | None = None,
        on_fused: Callable[[SensorFrame, np.ndarray], None] | None = None,
    ) -> None:
        cfg.validate()
        self.cfg = cfg
        self.scene = load_scene(_scene_path(cfg))
        try:
            self.mapper = new_mapper(cfg, self.scene)
        except _native.InputError as e:
            raise ConfigError(str(e)) from None
        self.run_dir = _make_run_dir(cfg, self.scene)
        self.show_progress = progress
        self.on_frame = on_frame
        self.on_fused = on_fused
        self.t_start = time.perf_counter()
        self.times: dict[str, list[float]] = {s: [] for s in STAGES}
        """Per-stage timings of every frame, ms."""
        self.events: list[str] = []
        self.est_positions: list[np.ndarray] = []
        self.gt_positions: list[np.ndarray] = []
        self.frames = 0
        self.views_done = 0
        """Views reached (Init views included; a skipped view does not count)."""
        self.view_index = 0
        """Views attempted so far (the per-view index of the kinematic errors)."""
        self.assignments: list[tuple[int, int | None]] = []
        """(map object id, true object id) of every assigned detection, for the association metrics."""
        self.prior_errors: list[tuple[float, float]] = []
        self.move_paths: dict[str, int] = {"cartesian": 0, "joint": 0}
        self.accuracy_curve: list[dict[str, Any]] = []
        self.stop_reason = "strategy_done"
        self.start = _status_start()
        self.world: SimWorld | None = None
        self.rec: Any = _Recorder(None)
        self.bar: Any = None

    # ----- the run -------------------------------------------------------------------------------
    def run(self) -> EpisodeResult:
        """Take every step and return the result. Raises on failure after marking the folder;
        SIGINT (Ctrl-C) and SIGTERM raise :class:`RunStopped` after marking it ``interrupted`` or
        ``terminated``."""
        previous_sigterm = None
        if threading.current_thread() is threading.main_thread():
            previous_sigterm = signal.signal(signal.SIGTERM, _on_sigterm)
        try:
            self.setup()
            self.take_init_views()
            self.explore()
            return self.finish()
        except BaseException as e:
            stopped = self._mark_stopped(e, signals_handled=previous_sigterm is not None)
            if stopped is e:
                raise
            raise stopped from e
        finally:
            if previous_sigterm is not None:
                signal.signal(signal.SIGTERM, previous_sigterm)

    def setup(self) -> None:
        """Mark the folder as running, write the resolved config, open the recording, build the
        simulated world and the detector, and record the truth and the arm at time 0."""
        import tomli_w

        cfg, scene = self.cfg, self.scene
        (self.run_dir / "INCOMPLETE").write_text(
            "this run has not finished (or stopped early: see status.json)\n"
        )
        _write_json(self.run_dir / "status.json", {"status": "running", **self.start})
        _write_atomic(self.run_dir / "config.toml", tomli_w.dumps(to_dict(cfg)))
        self.rec = _Recorder(
            self.run_dir / "run.rrd" if cfg.record.enabled else None, recording_options(cfg, scene)
        )
        rng_sensor = episode_rng(cfg.seed, scene.seed, STREAM_SENSOR)
        rng_detector = episode_rng(cfg.seed, scene.seed, STREAM_DETECTOR)
        self.arm = episode_arm_errors(cfg, scene)
        self.world = SimWorld(scene, cfg.camera, rng_sensor, textures=cfg.textures, arm_errors=self.arm)
        self.detector = SimulatedDetector(cfg.detector, rng_detector)
        # The truth and the arm's start pose at the first frame's time, so the viewer shows them from the start.
        self.rec.set_frame(0, 0.0)
        self.rec.log_objects("world/ground_truth", json.dumps(gt_objects(scene, self.world.ground_truth())))
        if cfg.record.robot:
            _log_robot(self.rec, self.world)
        self.gt_scene_file = gt_objects(scene)

    def take_init_views(self) -> None:
        """Visit the session's Init views (they do not count against the view budget)."""
        init_views = [v["world_from_camera"] for v in self.mapper.query('{"query": "initial_views"}')]
        if self.show_progress:
            from tqdm import tqdm

            budget = len(init_views) + (0 if self.cfg.core_strategy == "init" else self.cfg.explore["max_views"])
            desc = f"{self.cfg.strategy} {self.scene.name} seed {self.cfg.seed}"
            self.bar = tqdm(total=budget, desc=desc, unit="view")
        for vi, view in enumerate(init_views):
            self.views_done += self.move_to(view, f"init view {vi}")
            self.mapper.view_done(False)
            self.evaluate_view()
        self._log_exploration()

    def explore(self) -> None:
        """Decide and take views until the strategy (built-in or ``python_strategy``) stops."""
        cfg = self.cfg
        user_strategy = (
            make_strategy(cfg.python_strategy, cfg.python_strategy_params) if cfg.python_strategy else None
        )
        rng_strategy = episode_rng(cfg.seed, self.scene.seed, STREAM_STRATEGY)
        while True:
            decision = self.decide(user_strategy, rng_strategy)
            if decision["action"] == "stop":
                self.stop_reason = decision["reason"]
                self.rec.log_event(f"stop: {self.stop_reason}")
                break
            self.step(decision)
        if self.bar is not None:
            self.bar.close()

    def decide(self, user_strategy: Any, rng: np.random.Generator) -> dict[str, Any]:
        """The next decision: the core session's for a built-in strategy, else the Python
        strategy's (:func:`_python_decision`)."""
        world, cfg = self.world, self.cfg
        assert world is not None
        # Candidate views are reachable only with a collision-free arm among the mapped objects.
        world.set_obstacles(self.mapper.objects_json())
        if user_strategy is not None:
            return _python_decision(user_strategy, cfg, self.scene, self.mapper, world, rng)
        return self.mapper.next_view(
            intrinsics=world.intrinsics,
            width=cfg.camera.width,
            height=cfg.camera.height,
            world_from_camera=world.world_from_camera_fk(world.qpos()),
            reachable=world.is_reachable,
        )

    def step(self, decision: dict[str, Any]) -> None:
        """Take one decided view: record the decision, move there fusing the frames, evaluate."""
        _log_decision(self.rec, decision)
        what = f"view {_progress(self.mapper)['views_taken'] + 1}"
        self.views_done += self.move_to(decision["world_from_camera"], what)
        self.mapper.view_done(True)
        self.evaluate_view()
        self._log_exploration()
        if self.cfg.record.grids:
            pts, states = self.mapper.grid_cells()
            colors = GRID_COLORS[np.frombuffer(states, dtype=np.uint8)]
            self.rec.log_points("world/map/grids", pts, colors=colors, radius_m=0.004)

    def finish(self) -> EpisodeResult:
        """Save the final map, evaluate it (and each parameterization stage), write
        ``metrics.json`` and mark the run complete."""
        cfg, scene, mapper, rec, world = self.cfg, self.scene, self.mapper, self.rec, self.world
        assert world is not None
        mapper.refresh_estimates()
        map_json = mapper.map_json()
        _native.save_map(map_json, str(self.run_dir / "map.json"))
        (self.run_dir / "map.json.partial").unlink(missing_ok=True)
        gt = gt_objects(scene, world.ground_truth())
        rec.log_objects("world/ground_truth", json.dumps(gt))
        if cfg.record.estimator_inputs:
            inputs = json.loads(mapper.estimator_inputs_json())
            _write_atomic(
                self.run_dir / "estimator_inputs.json", json.dumps({"objects": inputs, "ground_truth": gt})
            )
        evaluation = json.loads(_native.evaluate_map(json.dumps(gt), map_json, json.dumps(cfg.eval)))
        stages = {}
        for stage in ("raw", "iforest", "lines", "refined"):
            ev = json.loads(
                _native.evaluate_map(json.dumps(gt), mapper.map_json(stage), json.dumps(cfg.eval))
            )
            stages[stage] = ev["mean"]
        association = json.loads(
            mapper.association_metrics_json(self.assignments, [o.id for o in scene.objects])
        )
        progress = _progress(mapper)
        metrics = {
            "scene": scene.name,
            "strategy": cfg.strategy,
            "seed": cfg.seed,
            "preset": cfg.preset,
            "n_objects_gt": evaluation["n_objects_gt"],
            "n_objects_est": evaluation["n_objects_est"],
            "views": self.views_done,
            "frames": self.frames,
            "path_length_m": world.camera_path_length_m,
            "moves_by_path": dict(self.move_paths),
            "wall_s": time.perf_counter() - self.t_start,
            "mean": evaluation["mean"],
            "objects": evaluation["objects"],
            "n_matched": evaluation["n_matched"],
            "nbv_views": progress["views_taken"],
            "association_mode": cfg.map["association_mode"],
            "pose_source": cfg.pose_source,
            **(mapper.query('{"query": "pose_metrics"}') or {}),
            "prior_error": prior_error_summary(self.prior_errors),
            "arm_errors": self._arm_errors(),
            "association": association,
            "stages": stages,
            "stop_reason": self.stop_reason,
            "entropy_curve": progress["entropy_curve"],
            "table_known_curve": progress["table_known_curve"],
            "table_unexplained_curve": progress["table_unexplained_curve"],
            "accuracy_curve": self.accuracy_curve,
            "timings_ms_median": {s: (statistics.median(v) if v else None) for s, v in self.times.items()},
            "frame_budget_ms_median": frame_budget(self.times),
            "events": self.events,
        }
        self.write_metrics(metrics)
        return EpisodeResult(
            run_dir=self.run_dir, metrics=metrics, map_json=map_json, frame_times_ms=self.times
        )

    def write_metrics(self, metrics: dict[str, Any]) -> None:
        """Write ``metrics.json``, close the recording, mark the run complete and point
        ``<runs_dir>/latest`` at it."""
        _write_json(self.run_dir / "metrics.json", metrics)
        self.rec.log_event(f"done: mean 3D IoU {metrics['mean']['iou3d']:.3f}")
        self.rec.close()
        _write_json(
            self.run_dir / "status.json",
            {"status": "complete", **self.start, "finished": datetime.now().isoformat(timespec="seconds")},
        )
        (self.run_dir / "INCOMPLETE").unlink()
        _update_latest(self.run_dir)

    # ----- per view and per frame ----------------------------------------------------------------
    def move_to(self, view: np.ndarray, what: str) -> bool:
        """Move to a view while fusing the streamed frames; False if it was skipped (unreachable,
        or the motion failed). Afterwards the SLAM map points are recorded and the map so far is
        kept in ``map.json.partial``."""
        world, cfg, rec = self.world, self.cfg, self.rec
        assert world is not None
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
                step_ms = (time.perf_counter() - t0) * 1e3
                self.times["render"].append(world.last_timings_ms["render"])
                self.times["sensor"].append(world.last_timings_ms["sensor"])
                self.times["motion"].append(
                    max(step_ms - self.times["render"][-1] - self.times["sensor"][-1], 0.0)
                )
                rec.set_frame(frame.index, frame.sim_time_s)
                for s in ("render", "sensor", "motion"):
                    rec.log_scalar(f"timings/{s}_ms", self.times[s][-1])
                self.fuse(frame)
            ok = True
            self.move_paths[world.last_move_path] += 1
        except (UnreachablePoseError, MotionError) as e:
            self.events.append(f"{what} skipped: {e}")
            rec.log_event(f"{what} skipped: {e}")
            ok = False
        self.view_index += 1
        if cfg.record.map_points:
            pts = self.mapper.map_points()
            if pts is not None and len(pts):
                colors = np.tile(MAP_POINT_COLOR, (len(pts), 1))
                rec.log_points("world/map/points", pts, colors=colors, radius_m=0.002)
        if self.bar is not None:
            self.bar.update(1)
        _write_atomic(self.run_dir / "map.json.partial", self.mapper.map_json())
        return ok

    def fuse(self, frame: SensorFrame) -> None:
        """Detect the objects in one frame, fuse it into the core at the kinematic prior, and
        record it."""
        world, cfg, rec, mapper = self.world, self.cfg, self.rec, self.mapper
        assert world is not None
        t0 = time.perf_counter()
        dets: list[Detection] = self.detector.detect(
            frame.segmentation, world.actor_to_object, frame.detector_view
        )
        t1 = time.perf_counter()
        # The prior: nominal forward kinematics of the joint readings (the robot's errors are in
        # them), with the per-view / per-frame errors of [robot] (identity under realistic).
        prior = self.arm.prior(frame.world_from_camera_fk, self.view_index, frame.index)
        self.prior_errors.append(pose_error(prior, frame.world_from_camera_gt))
        assigned = mapper.update(
            index=frame.index,
            intrinsics=frame.intrinsics,
            depth=frame.depth_m,
            world_from_camera=prior,
            detections=[d.as_tuple() for d in dets],
            grey=frame.rgb if (cfg.map["parameterize"] or cfg.pose_source != "fk") else None,
            world_from_camera_gt=frame.world_from_camera_gt,
            view_index=self.view_index,
        )
        used_pose = mapper.last_pose()
        assert used_pose is not None
        self.assignments.extend((oid, d.gt_id) for oid, d in zip(assigned, dets) if oid is not None)
        t2 = time.perf_counter()
        self.est_positions.append(used_pose[:3, 3].copy())
        self.gt_positions.append(frame.world_from_camera_gt[:3, 3].copy())
        self._record_frame(frame, dets, used_pose)
        t3 = time.perf_counter()
        self.times["detect"].append((t1 - t0) * 1e3)
        self.times["core"].append((t2 - t1) * 1e3)
        self.times["record"].append((t3 - t2) * 1e3)
        for s in ("detect", "core", "record"):
            rec.log_scalar(f"timings/{s}_ms", self.times[s][-1])
        self.frames += 1
        if self.on_frame is not None:
            self.on_frame(frame)
        if self.on_fused is not None:
            self.on_fused(frame, used_pose)
        if self.bar is not None:
            self.bar.set_postfix(frames=self.frames, objects=len(mapper))

    def _record_frame(self, frame: SensorFrame, dets: list[Detection], used_pose: np.ndarray) -> None:
        """One fused frame in the recording: the arm, the camera at the pose used, the images,
        the detections, both trajectories and the map."""
        rec, record = self.rec, self.cfg.record
        rec.set_frame(frame.index, frame.sim_time_s)
        if record.robot:
            _log_robot(rec, self.world)
        rec.log_camera(
            world_from_camera=used_pose,
            intrinsics=frame.intrinsics,
            width=self.cfg.camera.width,
            height=self.cfg.camera.height,
        )
        if frame.index % record.every_n_frames == 0:
            if record.rgb:
                rec.log_rgb(frame.rgb)
            if record.depth and frame.index % (record.every_n_frames * record.depth_every_n_frames) == 0:
                rec.log_depth(frame.depth_m)
        rec.log_detections([d.as_tuple() for d in dets])
        rec.log_trajectory("estimated", np.array(self.est_positions))
        rec.log_trajectory("ground_truth", np.array(self.gt_positions))
        rec.log_objects("world/map", self.mapper.objects_json())

    def evaluate_view(self) -> None:
        """Evaluate the map as it stands after a view (``accuracy_curve`` in metrics.json; ground
        truth judges only, on its own entity paths in the recording)."""
        assert self.world is not None
        map_json = self.mapper.map_json()
        gt = json.dumps(gt_objects(self.scene, self.world.ground_truth()))
        ev = json.loads(_native.evaluate_map(gt, map_json, json.dumps(self.cfg.eval)))
        self.accuracy_curve.append(
            {
                "views": self.views_done,
                **{
                    k: ev["mean"].get(k)
                    for k in ("iou3d", "iou2d", "cde_cm", "precision_iou50", "recall_iou50")
                },
                "n_objects_est": ev["n_objects_est"],
                **offset_removed(self.gt_scene_file, json.loads(map_json), ev["objects"]),
            }
        )
        for k in ("iou3d", "cde_cm", "iou3d_oracle_aligned"):
            if self.accuracy_curve[-1][k] is not None:
                self.rec.log_scalar(f"eval/{k}", self.accuracy_curve[-1][k])

    def _log_exploration(self) -> None:
        """The exploration state after a view: mean entropy and the table's coverage."""
        self.rec.log_scalar("explore/mean_normalized_entropy", _progress(self.mapper)["entropy_curve"][-1])
        _log_table(self.rec, self.mapper, self.cfg.record.grids)

    def _arm_errors(self) -> dict[str, Any]:
        """The episode's drawn robot errors (evaluation only)."""
        arm = self.arm
        return {
            "hand_eye_trans_mm": round(pose_error(arm.camera_from_true_camera, np.eye(4))[0] * 1e3, 3),
            "hand_eye_rot_deg": round(pose_error(arm.camera_from_true_camera, np.eye(4))[1], 4),
            "joint_offsets_deg": np.degrees(arm.joint_offsets_rad).round(4).tolist(),
            "time_offset_ms": round(arm.time_offset_s * 1e3, 3),
            "table_plane": list(episode_table_plane(self.cfg, self.scene)),
        }

    def _mark_stopped(self, e: BaseException, *, signals_handled: bool) -> BaseException:
        """Keep everything written so far, mark the folder and say why; returns what to raise. A
        second signal while cleaning up must not leave the status at "running"."""
        status = _stop_status(e)
        if signals_handled:
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            previous_sigint = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            _write_atomic(self.run_dir / "map.json.partial", self.mapper.map_json())
            self.rec.close()
        except Exception as cleanup:  # noqa: BLE001 - best effort while already failing
            print(f"run folder {self.run_dir}: could not save the partial map: {cleanup}", file=sys.stderr)
        extra: dict[str, Any] = {"error": f"{type(e).__name__}: {e}"}
        if status == "failed":
            extra["traceback"] = traceback.format_exc()
        _finish_status(self.run_dir, self.start, status, **extra)
        # Shut the renderer down before the interpreter exits (it may otherwise still be rendering
        # while Python tears down): drop the world and the frames (a signal's traceback is not
        # shown) that hold it.
        self.world = None
        if status != "failed":
            traceback.clear_frames(e.__traceback__)
        gc.collect()
        if signals_handled:
            signal.signal(signal.SIGINT, previous_sigint)
        return _stopped(e, self.run_dir)


def run_episode(
    cfg: RunConfig,
    *,
    progress: bool = True,
    on_frame: Callable[[SensorFrame], None] | None = None,
    on_fused: Callable[[SensorFrame, np.ndarray], None] | None = None,
) -> EpisodeResult:
    """Run one episode (:class:`Episode`) and write its run folder. Raises on failure after marking
    the folder; SIGINT (Ctrl-C) and SIGTERM raise :class:`RunStopped` after marking it
    ``interrupted`` or ``terminated``. Config values the core refuses raise before any folder is
    made. ``on_frame`` / ``on_fused``: see :class:`Episode`."""
    return Episode(cfg, progress=progress, on_frame=on_frame, on_fused=on_fused).run()


def _stop_status(e: BaseException) -> str:
    """The final status of a run that raised ``e``."""
    if isinstance(e, KeyboardInterrupt):
        return "interrupted"
    if isinstance(e, _Terminated):
        return "terminated"
    if isinstance(e, RunStopped):
        return e.status
    return "failed"


def _stopped(e: BaseException, run_dir: Path) -> BaseException:
    """What :func:`run_episode` raises for ``e``: :class:`RunStopped` for a signal, ``e`` itself
    otherwise."""
    if isinstance(e, KeyboardInterrupt):
        return RunStopped(signal.SIGINT, run_dir)
    if isinstance(e, _Terminated):
        return RunStopped(signal.SIGTERM, run_dir)
    return e


def prior_error_summary(errors: list[tuple[float, float]]) -> dict[str, float | None]:
    """The kinematic prior's error against the true camera pose over an episode's frames (evaluation
    only): RMS and 90th percentile of the translation (mm) and rotation (deg) differences."""
    if not errors:
        return {
            "trans_rms_mm": None,
            "trans_p90_mm": None,
            "rot_rms_deg": None,
            "rot_p90_deg": None,
            "frames": 0,
        }
    t = np.array([e[0] for e in errors]) * 1e3
    r = np.array([e[1] for e in errors])
    return {
        "trans_rms_mm": float(np.sqrt(np.mean(t**2))),
        "trans_p90_mm": float(np.percentile(t, 90)),
        "rot_rms_deg": float(np.sqrt(np.mean(r**2))),
        "rot_p90_deg": float(np.percentile(r, 90)),
        "frames": len(errors),
    }


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
