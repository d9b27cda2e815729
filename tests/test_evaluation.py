"""Offset-removed evaluation and accuracy-after-k-views (closed forms on ground-truth maps)."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from objslam import _native
from objslam.evaluation import offset_removed
from objslam.scene import gt_objects, load_scene

REPO = Path(__file__).resolve().parents[1]

from benchmark import curve_value


def _map_of(gt: list[dict], shift: np.ndarray) -> dict:
    """A map whose objects are the ground truth moved by ``shift``."""
    objs = []
    for i, g in enumerate(gt):
        y = g["geometry"]["yaw_rad"]
        objs.append(
            {
                "id": 10 + i,
                "label": g["label"],
                "world_from_object": {
                    "rotation": [0.0, 0.0, math.sin(y / 2), math.cos(y / 2)],
                    "translation": [float(v) for v in np.array(g["geometry"]["center"]) + shift],
                },
                "half_extents": g["geometry"]["half_extents"],
                "observations": [],
                "points_in_world": [],
            }
        )
    return {"format": "objslam-map", "version": 1, "objects": objs, "next_id": 100}


def test_a_rigidly_shifted_true_map_is_perfect_after_offset_removal() -> None:
    gt = gt_objects(load_scene(REPO / "scenes" / "scene03.toml"))
    shift = np.array([0.004, -0.003, 0.002])
    mp = _map_of(gt, shift)
    before = copy.deepcopy(mp)
    ev = json.loads(_native.evaluate_map(json.dumps(gt), json.dumps(mp)))
    assert ev["mean"]["iou3d"] < 0.9  # a 5.4 mm shift costs small objects a lot of overlap
    assert ev["mean"]["cde_cm"] == pytest.approx(np.linalg.norm(shift) * 100, abs=1e-9)
    al = offset_removed(gt, mp, ev["objects"])
    assert al["iou3d_oracle_aligned"] == pytest.approx(1.0, abs=1e-9)
    assert al["cde_oracle_aligned_cm"] == pytest.approx(0.0, abs=1e-9)
    assert al["map_offset_mm"] == pytest.approx(np.linalg.norm(shift) * 1000, abs=1e-9)
    assert mp == before  # the input map is not modified


def test_offset_is_the_median_so_one_wrong_object_does_not_move_it() -> None:
    gt = gt_objects(load_scene(REPO / "scenes" / "scene03.toml"))
    shift = np.array([0.003, 0.0, 0.0])
    mp = _map_of(gt, shift)
    t = mp["objects"][0]["world_from_object"]["translation"]
    mp["objects"][0]["world_from_object"]["translation"] = [t[0] + 0.01, t[1], t[2]]  # one object 1 cm further
    ev = json.loads(_native.evaluate_map(json.dumps(gt), json.dumps(mp)))
    al = offset_removed(gt, mp, ev["objects"])
    assert al["map_offset_mm"] == pytest.approx(3.0, abs=1e-9)
    assert al["iou3d_oracle_aligned"] < 1.0


def test_no_matched_object_gives_no_aligned_metrics() -> None:
    gt = gt_objects(load_scene(REPO / "scenes" / "scene03.toml"))
    empty = {"format": "objslam-map", "version": 1, "objects": [], "next_id": 0}
    ev = json.loads(_native.evaluate_map(json.dumps(gt), json.dumps(empty)))
    assert offset_removed(gt, empty, ev["objects"]) == {
        "iou3d_oracle_aligned": None,
        "cde_oracle_aligned_cm": None,
        "map_offset_mm": None,
    }


def test_curve_value_keeps_the_map_an_episode_stopped_with() -> None:
    curve = [{"views": 1, "iou3d": 0.5}, {"views": 2, "iou3d": 0.6}, {"views": 2, "iou3d": 0.61}, {"views": 3, "iou3d": 0.7}]
    assert curve_value(curve, 0, "iou3d") is None
    assert curve_value(curve, 1, "iou3d") == 0.5
    assert curve_value(curve, 2, "iou3d") == 0.61  # a skipped view adds a snapshot without a view
    assert curve_value(curve, 9, "iou3d") == 0.7
