"""Scene matching through Python: exact recovery, no-match results, typed errors."""

from __future__ import annotations

import json
import math

import numpy as np
import objslam
import pytest
from objslam.scene import gt_objects, load_scene
from objslam.topo import (
    map_json_from_gt,
    map_json_from_objects,
    similarity_matrix,
    transform_errors,
    transform_map_json,
)

YAW, T, S = 2.1, (-0.7, 1.3, 0.25), 1.7


@pytest.fixture(scope="module")
def scene_map(repo) -> str:
    return map_json_from_gt(gt_objects(load_scene(repo / "scenes" / "scene05.toml")))


def test_exact_copy_under_a_known_similarity_is_recovered_to_1e_6(scene_map) -> None:
    truth = similarity_matrix(YAW, T, S)
    query = transform_map_json(scene_map, YAW, T, S)
    r = objslam.match_maps(scene_map, query)
    assert r["matched"] and r["reason"] is None
    assert np.abs(r["matrix"] - truth).max() < 1e-6
    assert abs(r["scale"] - S) < 1e-6
    assert np.abs(r["rotation"] - truth[:3, :3] / S).max() < 1e-6
    assert np.abs(r["translation"] - np.array(T)).max() < 1e-6
    n = len(json.loads(scene_map)["objects"])
    assert sorted((p, q) for p, q, _ in r["inliers"]) == [(i, i) for i in range(n)]
    assert all(res < 1e-6 for _, _, res in r["inliers"])
    assert len(r["matched_pairs"]) == n
    # By default labels agree by primitive and sizes gate only gross mismatches, so another transform
    # pairing look-alikes explains a few objects (the runner-up); with the paper's exact labels and
    # tight sizes the exact copy is unambiguous.
    assert 0.5 < r["confidence"] <= 1.0
    tight = json.dumps({"size_tolerance": 0.25, "noise": {"size_rel": 0.05}, "descriptor": {"label_match": "exact"}})
    assert 0.9 < objslam.match_maps(scene_map, query, tight)["confidence"] <= 1.0
    err = transform_errors(r["matrix"], truth)
    assert err["rotation_deg"] < 1e-4 and err["translation_cm"] < 1e-4 and err["scale_pct"] < 1e-4

    # relocalise: the inverse transform and the matched ids.
    back = objslam.relocalise(scene_map, query)
    assert back["matched"]
    assert np.abs(back["matrix"] - np.linalg.inv(truth)).max() < 1e-6
    assert abs(back["scale"] - 1 / S) < 1e-6
    assert back["matched_ids"] == [[i, i] for i in range(n)]


def test_ids_are_the_maps_object_ids_not_indices(scene_map) -> None:
    doc = json.loads(transform_map_json(scene_map, YAW, T, S))
    for o in doc["objects"]:
        o["id"] += 100
    doc["next_id"] = max(o["id"] for o in doc["objects"]) + 1
    doc["objects"].reverse()
    r = objslam.relocalise(scene_map, json.dumps(doc))
    assert r["matched"]
    assert all(q == p + 100 for p, q in r["matched_ids"])


def test_empty_and_tiny_maps_are_a_no_match_result(scene_map) -> None:
    empty = objslam.NaiveMapper().map_json()
    for prior, query, kind in [(empty, scene_map, "empty_map"), (scene_map, empty, "empty_map")]:
        r = objslam.match_maps(prior, query)
        assert r["matched"] is False and r["reason_kind"] == kind
        assert ("prior" if prior is empty else "query") in r["reason"]
        assert r["matrix"] is None and r["rotation"] is None and r["scale"] is None
        assert r["inliers"] == [] and r["confidence"] == 0.0
    one = map_json_from_objects(
        [{"label": "cup", "center": [0.5, 0, 0.05], "half_extents": [0.03, 0.03, 0.05]}]
    )
    r = objslam.relocalise(one, one)
    assert r["matched"] is False and r["reason_kind"] == "too_few_objects" and r["matched_ids"] == []


def test_labels_of_other_primitives_are_no_candidates() -> None:
    cups = map_json_from_objects(
        [
            {"label": "cup", "center": [0.4 + 0.1 * i, 0.1 * i, 0.05], "half_extents": [0.03, 0.03, 0.05]}
            for i in range(4)
        ]
    )
    # Labels of different primitives never pair; labels of one primitive pair unless compared exactly.
    blocks = cups.replace('"cup"', '"block"')
    r = objslam.match_maps(cups, blocks)
    assert r["matched"] is False and r["reason_kind"] == "no_candidates"
    cans = cups.replace('"cup"', '"can"')
    r = objslam.match_maps(cups, cans, json.dumps({"descriptor": {"label_match": "exact"}}))
    assert r["matched"] is False and r["reason_kind"] == "no_candidates"
    assert objslam.match_maps(cups, cans)["matched"]


@pytest.mark.parametrize(
    ("prior", "query", "config", "exc", "needles"),
    [
        ("{", None, None, objslam.MapFileError, ["prior_map_json"]),
        (None, '{"format": "objslam-map", "version": 1}', None, objslam.MapFileError, ["query_map_json"]),
        (
            None,
            '{"format": "objslam-map", "version": 1, "objects": [{}], "next_id": 1}',
            None,
            objslam.MapFileError,
            ["query_map_json", "missing field"],
        ),
        (None, '{"format": "other", "version": 1}', None, objslam.MapFileError, ["query_map_json", "format"]),
        (None, None, '{"inlier_treshold": 0.1}', objslam.InputError, ["config_json", "inlier_treshold"]),
        (None, None, '{"noise": {"yaw_rad": "x"}}', objslam.InputError, ["config_json", "invalid type"]),
    ],
)
def test_bad_json_raises_a_typed_error_naming_the_field(
    scene_map, prior, query, config, exc, needles
) -> None:
    with pytest.raises(exc) as e:
        objslam.match_maps(prior or scene_map, query or scene_map, config)
    assert all(n in str(e.value) for n in needles), str(e.value)
    assert isinstance(e.value, objslam.ObjslamError)


def test_a_partial_config_applies(scene_map) -> None:
    # Three shared objects are enough by default; demanding more than the map has gives no match.
    query = transform_map_json(scene_map, YAW, T, S)
    r = objslam.match_maps(scene_map, query, json.dumps({"min_inliers": 50}))
    assert r["matched"] is False and r["reason_kind"] == "too_few_objects"


def test_transform_errors_closed_form() -> None:
    a = similarity_matrix(0.0, (0, 0, 0), 2.0)
    b = similarity_matrix(math.radians(3.0), (0.02, 0.0, 0.0), 2.2)
    e = transform_errors(b, a)
    assert e["rotation_deg"] == pytest.approx(3.0, abs=1e-9)
    assert e["translation_cm"] == pytest.approx(1.0, abs=1e-9)  # 2 cm in query units / s_true 2
    assert e["scale_pct"] == pytest.approx(10.0, abs=1e-9)
