"""objslam: an object-SLAM active-mapping testbed.

The Rust core (``objslam._native``, private) owns the object map, estimation and evaluation; this
package is the body: SAPIEN scenes (:mod:`objslam.scene`, :mod:`objslam.world`), the hand camera
(:mod:`objslam.camera`), a simulated detector (:mod:`objslam.detector`) and the episode runner
(:mod:`objslam.episode`). Public surface:

- :func:`load_scene`, :func:`generate_scene`, :class:`SceneSpec`, :class:`SceneFileError`
- :class:`RunConfig`, :class:`ConfigError`, :func:`load_run_config`
- :func:`run_episode` (returns an :class:`EpisodeResult`)
- :class:`NaiveMapper`, :class:`Planner` (Panda motion planning, grasps), :class:`Recorder`, :func:`evaluate_map`, :func:`load_map`, :func:`save_map`
- :func:`match_maps`, :func:`relocalise` (scene matching of two map JSONs; helpers in
  :mod:`objslam.topo`)
- exceptions :class:`ObjslamError` (base), :class:`InputError`, :class:`MapFileError`,
  :class:`RecordingError`, :class:`PlanningError` raised by the core.
"""

from ._native import (
    InputError,
    MapFileError,
    NaiveMapper,
    ObjslamError,
    Planner,
    PlanningError,
    Recorder,
    RecordingError,
    __version__,
    evaluate_map,
    load_map,
    map_objects_json,
    match_maps,
    save_map,
)
from .scene import SceneFileError, SceneSpec, generate_scene, load_scene
from .topo import relocalise

__all__ = [
    "ConfigError",
    "EpisodeResult",
    "InputError",
    "MapFileError",
    "NaiveMapper",
    "ObjslamError",
    "Planner",
    "PlanningError",
    "Recorder",
    "RecordingError",
    "RunConfig",
    "SceneFileError",
    "SceneSpec",
    "__version__",
    "evaluate_map",
    "generate_scene",
    "load_map",
    "load_run_config",
    "load_scene",
    "map_objects_json",
    "match_maps",
    "relocalise",
    "run_episode",
    "save_map",
]


_LAZY = {
    "run_episode": "episode",
    "EpisodeResult": "episode",
    "load_run_config": "config",
    "RunConfig": "config",
    "ConfigError": "config",
}
"""Names imported on first use: the episode runner imports SAPIEN."""


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'objslam' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f".{module}", __name__), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
