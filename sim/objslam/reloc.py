"""Relocalisation of short query trajectories against a prior map: object-level (topological scene
matching, :func:`objslam.match_maps`) and appearance-based (ORB keyframes, the core's
``slam::relocalise``), with the query's parallax to the prior's views.

Pieces, used by ``experiments/reloc.py``:

- :class:`KeyframeRecorder`: passed as ``on_fused`` to :func:`objslam.episode.run_episode`; keeps the
  prior episode's keyframes (a frame whose estimated pose moved ≥ ``min_move_m`` or turned ≥
  ``min_turn_deg`` since the last kept one): grey image, depth and the pose the mapper used, and
  the true viewing direction of every fused frame (for the parallax only). Saved as
  ``keyframes.npz`` in the run folder.
- :func:`render_pool`: a pool of query frames rendered once per scene in a fresh world (another
  session of the same robot: its own arm errors, sensor and detector noise), on rings of camera
  poses around the table looking at its centre; unreachable poses are skipped. Each frame keeps
  its detections, so trials drawn from the pool differ only in which frames they use.
- :func:`build_query_map`: the per-frame system (a fresh :func:`objslam.episode.new_mapper`) on a
  few pool frames: the query's object map and the query session's pose of each frame.
- :func:`appearance_poses`: every pool frame relocalised against the prior keyframes
  (:func:`objslam._native.relocalise_appearance`).
- :func:`parallax_deg`: the angle between a query camera's optical axis and that of the nearest
  prior frame (ground truth; it only bins the trials).
- :func:`wilson`: the Wilson 95 % interval of a success rate.

Ground truth only judges: the query frames' true poses give the parallax, the truth of a trial is
the known similarity applied to the query map (both sessions map in the robot-base frame).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import _native

#: Success of a relocalisation, as the scene-matching report counts it (``experiments/match_sim.py``).
ROT_OK_DEG, TRANS_OK_CM = 5.0, 5.0


def wilson(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default); (0, 1) without trials."""
    if trials <= 0:
        return 0.0, 1.0
    p = successes / trials
    d = 1.0 + z * z / trials
    c = (p + z * z / (2 * trials)) / d
    h = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / d
    return max(0.0, c - h), min(1.0, c + h)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(
        math.acos(max(-1.0, min(1.0, float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))))))
    )


def parallax_deg(world_from_camera_gt: np.ndarray, prior_axes: np.ndarray) -> float:
    """Angle (degrees) between a camera's optical axis and the nearest of ``prior_axes`` (N, 3)."""
    z = world_from_camera_gt[:3, 2]
    cos = prior_axes @ z / (np.linalg.norm(prior_axes, axis=1) * np.linalg.norm(z))
    return math.degrees(math.acos(float(np.clip(cos.max(), -1.0, 1.0))))


@dataclass
class KeyframeRecorder:
    """Keeps a mapping episode's keyframes (see the module docs); call as ``on_fused``."""

    min_move_m: float = 0.05
    """A frame becomes a keyframe when its estimated camera moved at least this far (metres) ..."""
    min_turn_deg: float = 10.0
    """... or turned at least this much (degrees) since the last keyframe."""
    grey: list[np.ndarray] = field(default_factory=list)
    depth_mm: list[np.ndarray] = field(default_factory=list)
    world_from_camera: list[np.ndarray] = field(default_factory=list)
    intrinsics: np.ndarray | None = None
    axes_gt: list[np.ndarray] = field(default_factory=list)

    def __call__(self, frame: Any, world_from_camera: np.ndarray) -> None:
        from .episode import grey_of

        self.axes_gt.append(frame.world_from_camera_gt[:3, 2].copy())
        if self.world_from_camera:
            last = self.world_from_camera[-1]
            moved = float(np.linalg.norm(last[:3, 3] - world_from_camera[:3, 3]))
            turned = _angle_deg(last[:3, 2], world_from_camera[:3, 2])
            if moved < self.min_move_m and turned < self.min_turn_deg:
                return
        self.grey.append(grey_of(frame.rgb))
        self.depth_mm.append(np.clip(np.round(frame.depth_m * 1000.0), 0, 65535).astype(np.uint16))
        self.world_from_camera.append(np.asarray(world_from_camera, dtype=np.float64).copy())
        self.intrinsics = np.asarray(frame.intrinsics, dtype=np.float64)

    def save(self, path: Path) -> None:
        """Write ``keyframes.npz``-style arrays to ``path``."""
        np.savez_compressed(
            path,
            grey=np.stack(self.grey),
            depth_mm=np.stack(self.depth_mm),
            world_from_camera=np.stack(self.world_from_camera),
            intrinsics=self.intrinsics,
            axes_gt=np.stack(self.axes_gt),
        )


@dataclass
class PoolFrame:
    """A rendered query frame with its detections."""

    ring: int
    azimuth_deg: float
    grey: np.ndarray
    depth_m: np.ndarray
    intrinsics: np.ndarray
    detections: list[tuple]
    world_from_camera_fk: np.ndarray
    world_from_camera_gt: np.ndarray
    """True pose (parallax and scoring only)."""


@dataclass(frozen=True)
class Ring:
    """Query camera poses on a circle around the table centre, looking at it."""

    elevation_deg: float
    """Elevation of the camera above the table top seen from the centre, degrees."""
    distance_m: float
    """Distance from the table centre, metres."""
    azimuth_step_deg: float
    """Azimuth between neighbouring poses, degrees (a query trajectory steps by it)."""


def ring_pose(center_xy: tuple[float, float], ring: Ring, azimuth_deg: float) -> np.ndarray:
    """``world_from_camera`` on ``ring`` at ``azimuth_deg`` (0 = +x from the table centre, away from
    the robot), looking at the table centre."""
    from .camera_path import look_at

    a, e = math.radians(azimuth_deg), math.radians(ring.elevation_deg)
    c = np.array([center_xy[0], center_xy[1], 0.0])
    eye = c + ring.distance_m * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    return look_at(eye, c)


def render_pool(cfg: Any, scene: Any, rings: list[Ring], seed: int, progress: bool = True) -> list[PoolFrame]:
    """Render the query pool of one scene (see the module docs). ``cfg`` is the run config of the
    query session (its seed draws the arm errors and the sensor and detector noise)."""
    from .calibration import STREAM_DETECTOR, STREAM_SENSOR, episode_rng
    from .detector import SimulatedDetector
    from .episode import episode_arm_errors, grey_of
    from .world import SimWorld, UnreachablePoseError

    rng_sensor = episode_rng(seed, scene.seed, STREAM_SENSOR)
    rng_detector = episode_rng(seed, scene.seed, STREAM_DETECTOR)
    world = SimWorld(
        scene, cfg.camera, rng_sensor, textures=cfg.textures, arm_errors=episode_arm_errors(cfg, scene)
    )
    detector = SimulatedDetector(cfg.detector, rng_detector)
    center = (float(scene.table.center[0]), float(scene.table.center[1]))
    pool: list[PoolFrame] = []
    for ri, ring in enumerate(rings):
        n_az = round(360.0 / ring.azimuth_step_deg)
        for k in range(n_az):
            az = k * ring.azimuth_step_deg
            view = ring_pose(center, ring, az)
            try:
                q = world.solve_ik(view, "query view")
            except UnreachablePoseError:
                continue
            world.set_qpos(q)
            frame = world.render()
            dets = detector.detect(frame.segmentation, world.actor_to_object, frame.detector_view)
            pool.append(
                PoolFrame(
                    ring=ri,
                    azimuth_deg=az,
                    grey=grey_of(frame.rgb),
                    depth_m=frame.depth_m,
                    intrinsics=frame.intrinsics,
                    detections=[d.as_tuple() for d in dets],
                    world_from_camera_fk=frame.world_from_camera_fk,
                    world_from_camera_gt=frame.world_from_camera_gt,
                )
            )
        if progress:
            print(f"    ring {ri}: {sum(1 for p in pool if p.ring == ri)}/{n_az} poses reachable", flush=True)
    return pool


def build_query_map(cfg: Any, scene: Any, frames: list[PoolFrame]) -> tuple[str, list[np.ndarray]]:
    """The query session's object map (JSON) from ``frames`` fused in order by a fresh mapper, and
    the pose the mapper used for each frame (the query session's frame)."""
    from .episode import episode_arm_errors, new_mapper

    mapper = new_mapper(cfg, scene)
    arm = episode_arm_errors(cfg, scene)
    poses = []
    for i, f in enumerate(frames):
        mapper.update(
            index=i,
            intrinsics=f.intrinsics,
            depth=f.depth_m,
            world_from_camera=arm.prior(f.world_from_camera_fk, i, i),
            detections=f.detections,
            grey=f.grey,
            world_from_camera_gt=f.world_from_camera_gt,
            view_index=i,
        )
        poses.append(np.asarray(mapper.query('{"query": "last_pose"}')["world_from_camera"], dtype=np.float64))
        mapper.view_done(False)
    mapper.refresh_estimates()
    return mapper.map_json(), poses


def appearance_poses(
    keyframes: dict[str, np.ndarray], pool: list[PoolFrame], config: dict[str, Any] | None = None
) -> list[dict[str, Any]]:
    """Every pool frame relocalised against the prior keyframes by appearance: one record per frame
    (``ok``, ``world_from_camera`` in the prior's frame, ``keyframe``, ``matches``, ``inliers``)."""
    request = {
        "config": config or {},
        "intrinsics": np.asarray(keyframes["intrinsics"]).tolist(),
        "prior_world_from_camera": np.asarray(keyframes["world_from_camera"]).tolist(),
    }
    out = _native.relocalise_appearance(
        json.dumps(request),
        np.ascontiguousarray(keyframes["grey"]),
        np.ascontiguousarray(keyframes["depth_mm"].astype(np.float32) / 1000.0),
        np.ascontiguousarray(np.stack([p.grey for p in pool])),
        np.ascontiguousarray(np.stack([p.depth_m for p in pool]).astype(np.float32)),
    )
    return json.loads(out)
