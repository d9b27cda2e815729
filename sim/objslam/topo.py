"""Helpers around scene matching (:func:`objslam.match_maps`, :func:`objslam.relocalise`).

- :func:`relocalise`: :func:`objslam.match_maps` the other way round, for a map built in a new
  session: ``prior_from_query`` and the matched object ids.
- :func:`map_json_from_objects`: a versioned map JSON from object records (label, centre, yaw,
  half-extents), e.g. a scene's ground truth, for tests and synthetic experiments.
- :func:`transform_map_json`: a map moved by a gravity-aligned similarity q = s R_z(yaw) p + t
  (centres, orientations, half-extents, observation centroids and object points), so that the
  true transform between two maps is known.
- :func:`similarity_matrix`, :func:`transform_errors`: the 4x4 matrix s R | t and the errors of an
  estimate against the truth (rotation angle in degrees, translation with the scale undone, relative
  scale error), as the scene-matching report defines them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from . import _native

MAP_FORMAT = "objslam-map"
MAP_VERSION = 1


def relocalise(prior_map_json: str, query_map_json: str, config_json: str | None = None) -> dict[str, Any]:
    """Relocalise a map built in a new session against a prior map: the dict of
    :func:`objslam.match_maps` with the transform keys holding ``prior_from_query`` (p = s R q + t)
    and ``matched_ids`` [[prior id, query id]] sorted by prior id."""
    return _native.match_maps(prior_map_json, query_map_json, config_json, relocalise=True)


def _quat_z(yaw: float) -> list[float]:
    """Quaternion [x, y, z, w] of a rotation by ``yaw`` about z."""
    return [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]


def _quat_mul(a: list[float], b: list[float]) -> list[float]:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]


def map_json_from_objects(objects: Iterable[Mapping[str, Any]]) -> str:
    """A map JSON with one object per record ``{"label", "center", "yaw_rad", "half_extents"}``
    (optional ``"id"``; default: the record's index). No observations, no points."""
    out = []
    for i, o in enumerate(objects):
        out.append(
            {
                "id": int(o.get("id", i)),
                "label": str(o["label"]),
                "world_from_object": {
                    "rotation": _quat_z(float(o.get("yaw_rad", 0.0))),
                    "translation": [float(c) for c in o["center"]],
                },
                "half_extents": [float(h) for h in o["half_extents"]],
                "observations": [],
                "points_in_world": [],
            }
        )
    next_id = max((o["id"] for o in out), default=-1) + 1
    return json.dumps({"format": MAP_FORMAT, "version": MAP_VERSION, "objects": out, "next_id": next_id})


def map_json_from_gt(gt: Iterable[Mapping[str, Any]]) -> str:
    """A map JSON from ground truth in the core's ``GtObject`` layout (:func:`objslam.scene.gt_objects`)."""
    return map_json_from_objects(
        {
            "id": g["id"],
            "label": g["label"],
            "center": g["geometry"]["center"],
            "yaw_rad": g["geometry"].get("yaw_rad", 0.0),
            "half_extents": g["geometry"]["half_extents"],
        }
        for g in gt
    )


def similarity_matrix(yaw_rad: float, translation: Iterable[float], scale: float) -> np.ndarray:
    """4x4 matrix of q = s R_z(yaw) p + t."""
    c, s_ = math.cos(yaw_rad), math.sin(yaw_rad)
    m = np.eye(4)
    m[:3, :3] = scale * np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    m[:3, 3] = np.asarray(list(translation), dtype=float)
    return m


def transform_map_json(map_json: str, yaw_rad: float, translation: Iterable[float], scale: float) -> str:
    """``map_json`` moved by q = s R_z(yaw) p + t: object centres, orientations (yaw added),
    half-extents (× s), observation centroids and object points. Image-space data are unchanged."""
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale: expected a finite positive number, got {scale}")
    m = similarity_matrix(yaw_rad, translation, scale)
    doc = json.loads(map_json)

    def move(p: list[float]) -> list[float]:
        return [float(v) for v in m[:3, :3] @ np.asarray(p, dtype=float) + m[:3, 3]]

    q = _quat_z(yaw_rad)
    for o in doc.get("objects", []):
        pose = o["world_from_object"]
        pose["translation"] = move(pose["translation"])
        pose["rotation"] = _quat_mul(q, pose["rotation"])
        o["half_extents"] = [float(h) * scale for h in o["half_extents"]]
        o["points_in_world"] = [move(p) for p in o.get("points_in_world", [])]
        for obs in o.get("observations", []):
            if "centroid_in_world" in obs:
                obs["centroid_in_world"] = move(obs["centroid_in_world"])
    return json.dumps(doc)


def transform_errors(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Errors of a 4x4 similarity ``estimate`` against ``truth`` (both q = s R p + t):
    ``rotation_deg`` (angle of R_trueᵀ R_est), ``translation_cm`` (‖t_est − t_true‖ / s_true, in the
    units of the map being mapped, ×100) and ``scale_pct`` (|s_est / s_true − 1| × 100)."""
    s_est = float(np.cbrt(np.linalg.det(estimate[:3, :3])))
    s_true = float(np.cbrt(np.linalg.det(truth[:3, :3])))
    r_est, r_true = estimate[:3, :3] / s_est, truth[:3, :3] / s_true
    cos = (np.trace(r_true.T @ r_est) - 1.0) / 2.0
    return {
        "rotation_deg": math.degrees(math.acos(max(-1.0, min(1.0, float(cos))))),
        "translation_cm": float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]) / s_true * 100.0),
        "scale_pct": abs(s_est / s_true - 1.0) * 100.0,
    }
