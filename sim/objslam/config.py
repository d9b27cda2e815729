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
import json
import warnings
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, get_type_hints

import tomllib

from .calibration import ContactConfig, RobotConfig, TableConfig
from .camera import CalibrationConfig, CameraConfig, ColourConfig, DepthNoiseConfig, StereoDepthConfig
from .detector import DetectorConfig
from .task_config import GraspRunConfig, PlaceConfig
from .textures import TextureConfig

REPO_ROOT = Path(__file__).resolve().parents[2]
CONFIG_DIR = REPO_ROOT / "experiments" / "configs"
PRESET_DIR = CONFIG_DIR / "presets"


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names the key."""


CORE_TABLES = ("slam", "map", "explore", "eval")
"""The run config's tables of core settings (``objslam_core::system::SystemConfig``, documented in
``core/src/system/config.rs`` and the structs it names: ``[slam]`` = ``TrackerConfig``, ``[map]`` =
``PipelineConfig``, ``[explore]`` = ``ActiveConfig``, ``[eval]`` = ``EvalConfig``). They pass to the
core untouched: their names, units, defaults and range checks are the core's, and a run's resolved
``config.toml`` holds them complete."""

RUNTIME_KEYS = {"slam": ("pose_source",), "explore": ("strategy", "seed")}
"""Core keys the episode fills from the run config's top level (``pose_source``, ``strategy``,
``seed``); setting them in a core table is an error."""


def resolve_core_tables(tables: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The core tables complete (missing keys take the core's defaults), range-checked by the core;
    a :class:`ConfigError` names the key as ``table.key``. Keys whose value is unset (null) are
    left out (TOML has no null)."""
    from . import _native

    for table, keys in RUNTIME_KEYS.items():
        given = tables.get(table)
        if isinstance(given, dict):
            for k in keys:
                if k in given:
                    raise ConfigError(f"{table}.{k}: set by the run's top-level {k!r}, not in [{table}]")
    for table in CORE_TABLES:
        if table in tables and not isinstance(tables[table], dict):
            raise ConfigError(f"{table}: expected a table")
    try:
        resolved = json.loads(_native.resolve_config(json.dumps(tables)))
    except ValueError as e:
        raise ConfigError(str(e)) from e
    for table, keys in RUNTIME_KEYS.items():
        for k in keys:
            resolved[table].pop(k, None)
    return {t: _drop_none(resolved[t]) for t in CORE_TABLES}


def _drop_none(d: dict[str, Any]) -> dict[str, Any]:
    return {k: _drop_none(v) if isinstance(v, dict) else v for k, v in d.items() if v is not None}


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
    strategy: str = "object-driven-discovery"
    """View-selection strategy: object-driven-discovery (the project's: the paper's utility and the
    table-discovery extension), object-driven (the paper's rule exactly), expected-gain, random,
    coverage or init; or the label of a Python strategy (``python_strategy``)."""
    builtin_strategy: str = ""
    """A labelled variant of a built-in strategy: the built-in this run executes, with ``strategy``
    as its label in metrics and reports (a strategy file such as ``paper-pipeline.toml`` sets it
    together with the settings that make the variant). Empty: ``strategy`` is the built-in."""
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
    pose_source: str = "slam"
    """Camera pose used by the mapper: ``slam`` (default: visual tracking seeded by the kinematic
    prior, the paper's ORB-SLAM2 role), ``kinematics`` (the prior as is, with the tracker's map
    points), ``ground_truth`` (oracle, an ablation: the only source the true pose reaches), ``fk``
    (the prior as is, no tracker; fast runs). The prior is forward kinematics of the nominal robot
    model on the joint readings; its error is the simulated robot's (``[robot]``)."""
    camera: CameraConfig = field(default_factory=CameraConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    textures: TextureConfig = field(default_factory=TextureConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    table: TableConfig = field(default_factory=TableConfig)
    contact: ContactConfig = field(default_factory=ContactConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    grasp: GraspRunConfig = field(default_factory=GraspRunConfig)
    place: PlaceConfig = field(default_factory=PlaceConfig)
    slam: dict[str, Any] = field(default_factory=dict)
    """Visual tracking (core ``TrackerConfig``; ``pose_source`` comes from the top level)."""
    map: dict[str, Any] = field(default_factory=dict)
    """The object map: association, consolidation, parameterization (core ``PipelineConfig``)."""
    explore: dict[str, Any] = field(default_factory=dict)
    """Exploration (core ``ActiveConfig``; ``strategy`` and ``seed`` come from the top level)."""
    eval: dict[str, Any] = field(default_factory=dict)
    """Scoring against the truth (core ``EvalConfig``)."""

    @property
    def core_strategy(self) -> str:
        """The built-in strategy the core's session runs: ``init`` under a Python strategy (which
        decides itself), the ``builtin_strategy`` of a labelled variant, else ``strategy``."""
        return "init" if self.python_strategy else (self.builtin_strategy or self.strategy)

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the key if a value is out of range."""
        if self.builtin_strategy:
            if self.python_strategy:
                raise ConfigError("builtin_strategy: given together with python_strategy; set one")
            if self.builtin_strategy not in STRATEGIES:
                raise ConfigError(
                    f"builtin_strategy: unknown {self.builtin_strategy!r}; known: {', '.join(STRATEGIES)}"
                )
            if self.strategy in STRATEGIES or not self.strategy or "/" in self.strategy:
                raise ConfigError(
                    f"strategy: {self.strategy!r} must be the variant's own label (not a built-in name, no '/')"
                )
        elif self.python_strategy:
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
        elif self.strategy not in STRATEGIES and not self.builtin_strategy:
            raise ConfigError(
                f"strategy: unknown {self.strategy!r}; known: {', '.join(STRATEGIES)} "
                "(or set python_strategy for a strategy written in Python)"
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
        if self.map.get("object_points") == "slam_map" and self.pose_source == "fk":
            raise ConfigError(
                "map.object_points: slam_map needs a tracker (pose_source kinematics, slam or ground_truth)"
            )
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
STRATEGIES = ("init", "object-driven", "object-driven-discovery", "random", "coverage", "expected-gain")


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


RETIRED_KEYS: dict[str, str] = {
    "slam.orb.pattern_seed": "the BRIEF test pattern is a fixed table (OpenCV's learned pattern), not drawn from a seed",
    "camera.colour.max_blur_taps": "the motion blur integrates each pixel's whole path (prefix sums), not a number of samples",
}
"""Settings the code no longer has, with why. A run folder's ``config.toml`` written when they existed
still loads: they are dropped from overlay files with a warning (given as ``--set`` they are errors)."""


def _drop_retired(layer: dict[str, Any], source: Path) -> dict[str, Any]:
    for key, why in RETIRED_KEYS.items():
        *parents, leaf = key.split(".")
        table = layer
        for p in parents:
            table = table.get(p) if isinstance(table, dict) else None
        if isinstance(table, dict) and leaf in table:
            del table[leaf]
            warnings.warn(f"{source}: {key} ignored ({why})", stacklevel=3)
    return layer


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
    overlay_data = [_drop_retired(_read(Path(p)), Path(p)) for p in overlays]
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
    data.update(resolve_core_tables({t: data.get(t, {}) for t in CORE_TABLES}))
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
