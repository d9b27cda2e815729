"""Map evaluation helpers shared by the episode runner and the exploration benchmark.

The world-frame metrics come from the core (``_native.evaluate_map``: per-object rows, means over
matched and over all objects, precision and recall at 3D IoU 0.25 and 0.5). This module adds the
*oracle-aligned* evaluation: the map's placement in the world comes from the kinematic prior (the
robot's calibration errors, shared by every object of an episode), so the whole map is moved by the
median offset between matched true and estimated centres (translation only, objects whose
world-frame 3D IoU is above ``min_iou``) and evaluated again. The offset is measured against the
ground truth — an oracle no robot has — so these figures isolate what the views did for the map's
shape from where the SLAM gauge put it; they are labelled ``oracle_aligned`` everywhere.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from . import _native

#: Matched objects below this world-frame 3D IoU do not vote on the map's offset.
OFFSET_MIN_IOU = 0.3


def offset_removed(
    gt: list[dict[str, Any]], map_dict: dict[str, Any], matched: list[dict[str, Any]], min_iou: float = OFFSET_MIN_IOU
) -> dict[str, float | None]:
    """Oracle-aligned 3D IoU and CDE of ``map_dict``: after removing its global translation offset.

    ``gt``: ground truth in the core's ``GtObject`` layout; ``map_dict``: a parsed map JSON;
    ``matched``: the per-object rows of the world-frame evaluation (``evaluate_map``'s
    ``objects``: ``gt_id``, ``est_id``, ``iou3d``), whose matching is kept. Returns
    ``iou3d_oracle_aligned``, ``cde_oracle_aligned_cm`` and ``map_offset_mm`` (all None when no matched object
    reaches ``min_iou``). ``map_dict`` is not modified."""
    centre = {g["id"]: np.array(g["geometry"]["center"], dtype=float) for g in gt}
    by_id = {o["id"]: o for o in map_dict["objects"]}
    offsets = [
        centre[o["gt_id"]] - np.array(by_id[o["est_id"]]["world_from_object"]["translation"], dtype=float)
        for o in matched
        if o.get("est_id") is not None and o["est_id"] in by_id and (o.get("iou3d") or 0.0) > min_iou
    ]
    if not offsets:
        return {"iou3d_oracle_aligned": None, "cde_oracle_aligned_cm": None, "map_offset_mm": None}
    off = np.median(np.array(offsets), axis=0)
    # A new map with new poses; the rest (clouds, observations) is shared with ``map_dict``.
    moved = {
        **map_dict,
        "objects": [
            {
                **o,
                "world_from_object": {
                    **o["world_from_object"],
                    "translation": [float(o["world_from_object"]["translation"][i] + off[i]) for i in range(3)],
                },
            }
            for o in map_dict["objects"]
        ],
    }
    ev = json.loads(_native.evaluate_map(json.dumps(gt), json.dumps(moved)))
    return {
        "iou3d_oracle_aligned": ev["mean"]["iou3d"],
        "cde_oracle_aligned_cm": ev["mean"]["cde_cm"],
        "map_offset_mm": float(np.linalg.norm(off) * 1000.0),
    }
