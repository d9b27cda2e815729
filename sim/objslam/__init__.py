"""objslam: an object-SLAM active-mapping testbed.

The Rust core (``objslam._native``, private) owns the object map, estimation and evaluation; this
package is the body: SAPIEN scenes (:mod:`objslam.scene`, :mod:`objslam.world`), the hand camera
(:mod:`objslam.camera`), a simulated detector (:mod:`objslam.detector`) and the episode runner
(:mod:`objslam.episode`). Public surface:

- :func:`load_scene`, :func:`generate_scene`, :class:`SceneSpec`, :class:`SceneFileError`
- :class:`RunConfig`, :func:`load_run_config`
- :func:`run_episode`
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
    relocalise,
    save_map,
)
from .scene import SceneFileError, SceneSpec, generate_scene, load_scene

__all__ = [
    "InputError",
    "MapFileError",
    "NaiveMapper",
    "ObjslamError",
    "Planner",
    "PlanningError",
    "Recorder",
    "RecordingError",
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


def __getattr__(name: str):  # lazy: these import SAPIEN
    if name == "run_episode":
        from .episode import run_episode

        return run_episode
    if name == "load_run_config":
        from .config import load_run_config

        return load_run_config
    raise AttributeError(name)
