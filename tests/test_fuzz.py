"""Fuzz the native entry points: seeded random mutations of valid inputs (JSON documents, numpy
arrays, plain arguments) must raise only typed errors (``ObjslamError`` and its subclasses,
``TypeError``, ``ValueError``, ``OverflowError``), never a panic (``PanicException`` is not an
``Exception``) or an abort.

Brief by default (200 cases per entry point); at length with ``OBJSLAM_FUZZ_CASES=20000`` (``make
fuzz``). The seed of a failing case is in the assertion message (``OBJSLAM_FUZZ_SEED`` moves the
whole run).
"""

from __future__ import annotations

import json
import os
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from objslam import _native

CASES = int(os.environ.get("OBJSLAM_FUZZ_CASES", "200"))
SEED = int(os.environ.get("OBJSLAM_FUZZ_SEED", "0"))
TYPED = (_native.ObjslamError, TypeError, ValueError, OverflowError)

ODD_VALUES: list[Any] = [
    0, -1, -0.0, 1e308, -1e308, 1e-300, 2**32, 2**64, -(2**63), float("nan"), float("inf"),
    "x", "", None, True, [], {}, [1, 2], 0.5, 1, 7,
]  # fmt: skip

GT = [
    {"id": 0, "label": "cup", "geometry": {"shape": "cylinder", "center": [0.5, 0.0, 0.05], "yaw_rad": 0.0,
                                            "half_extents": [0.04, 0.04, 0.05]}},
    {"id": 1, "label": "book", "geometry": {"shape": "cuboid", "center": [0.4, 0.2, 0.02], "yaw_rad": 0.5,
                                             "half_extents": [0.09, 0.06, 0.02]}},
]  # fmt: skip


def _valid_map() -> str:
    obj = lambda i, label, x: {
        "id": i,
        "label": label,
        "world_from_object": {"rotation": [0.0, 0.0, 0.2, 0.9797958971132712], "translation": [x, 0.1, 0.03]},
        "half_extents": [0.05, 0.04, 0.03],
        "observations": [{"frame": 1, "bbox": {"min": [1.0, 2.0], "max": [50.0, 60.0]}, "score": 0.8,
                          "centroid_in_world": [x, 0.1, 0.03]}],
        "points_in_world": [[x, 0.1, 0.03]],
        "stage": "refined",
    }  # fmt: skip
    doc = {"format": "objslam-map", "version": 1, "objects": [obj(0, "cup", 0.5), obj(1, "book", 0.4)], "next_id": 2}
    return json.loads(_native.map_objects_json(json.dumps(doc))) and json.dumps(doc)


def _scalars(tree: Any, path: tuple = ()) -> list[tuple]:
    if isinstance(tree, dict):
        return [p for k, v in tree.items() for p in _scalars(v, (*path, k))]
    if isinstance(tree, list):
        return [p for i, v in enumerate(tree) for p in _scalars(v, (*path, i))] or [path]
    return [path]


def _set(tree: Any, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        tree = tree[k]
    if path:
        tree[path[-1]] = value


def mutate_json(text: str, rng: random.Random) -> str:
    """A random edit of a JSON document: an odd value put into a scalar, a key dropped or added,
    or a few byte edits of the text."""
    kind = rng.randrange(4)
    if kind == 3:
        b = bytearray(text.encode())
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(b))
            op = rng.randrange(3)
            if op == 0:
                b[i] = rng.randrange(256)
            elif op == 1:
                b.insert(i, rng.randrange(256))
            elif len(b) > 1:
                del b[i]
        return b.decode("utf-8", errors="replace")
    tree = json.loads(text)
    paths = _scalars(tree)
    path = rng.choice(paths)
    if kind == 0 or not path:
        _set(tree, path, rng.choice(ODD_VALUES))
        if not path:
            tree = rng.choice(ODD_VALUES)
    elif kind == 1:
        parent = tree
        for k in path[:-2]:
            parent = parent[k]
        container = parent[path[-2]] if len(path) > 1 else tree
        if isinstance(container, dict) and path[-1] in container:
            del container[path[-1]]
    else:
        parent = tree
        for k in path[:-1]:
            parent = parent[k]
        if isinstance(parent, dict):
            parent[rng.choice(["bogus", "id", "next_id", "version"])] = rng.choice(ODD_VALUES)
    return json.dumps(tree)


def _fuzz(name: str, call: Callable[[random.Random], None]) -> None:
    for case in range(CASES):
        rng = random.Random(f"{SEED}:{name}:{case}")
        try:
            call(rng)
        except TYPED:
            pass
        except KeyboardInterrupt:
            raise
        except BaseException as e:  # noqa: BLE001 - a PanicException or anything untyped is a finding
            pytest.fail(f"{name} case {case} (OBJSLAM_FUZZ_SEED={SEED}): {type(e).__name__}: {e}")


MAP = _valid_map()


def test_fuzz_map_readers(tmp_path: Path) -> None:
    def call(rng: random.Random) -> None:
        text = mutate_json(MAP, rng)
        which = rng.randrange(3)
        if which == 0:
            _native.map_objects_json(text)
        elif which == 1:
            p = tmp_path / "m.json"
            p.write_text(mutate_json(_native.load_map(str(tmp_path / "ok.json")), rng))
            out = _native.load_map(str(p))
            json.loads(out)
        else:
            _native.save_map(text, str(tmp_path / "s.json"))
            _native.load_map(str(tmp_path / "s.json"))

    _native.save_map(MAP, str(tmp_path / "ok.json"))
    _fuzz("map", call)


def test_fuzz_evaluation() -> None:
    gt = json.dumps(GT)
    cfg = json.dumps({"max_match_distance_m": 0.1, "square_tolerance": 0.05})

    def call(rng: random.Random) -> None:
        args = [gt, MAP, cfg]
        k = rng.randrange(3)
        args[k] = mutate_json(args[k], rng)
        json.loads(_native.evaluate_map(*args))

    _fuzz("evaluate_map", call)


def test_fuzz_native_configs() -> None:
    mapper = json.dumps({"min_observations": 3, "relabel_vote_ratio": 4.0, "param": {"iforest": {"passes": 1}},
                         "naive": {"voxel_m": 0.005}})  # fmt: skip
    active = json.dumps({"cell_m": 0.01, "max_views": 4, "discovery_cell_m": 0.02, "distance_m": 0.4})

    def call(rng: random.Random) -> None:
        which = rng.randrange(3)
        if which == 0:
            _native.NaiveMapper(mutate_json(json.dumps({"voxel_m": 0.005, "pixel_stride": 4}), rng))
        else:
            table = tuple(rng.choice([0.5, 0.0, 0.8, 1.2, -1.0, 1e4, 1e12, float("nan")]) for _ in range(4))
            m = _native.ActiveMapper(
                mapper_config_json=mutate_json(mapper, rng) if which == 1 else mapper,
                active_config_json=mutate_json(active, rng) if which == 2 else active,
                table=table if rng.random() < 0.3 else (0.5, 0.0, 0.8, 1.2),
            )
            m.query('{"query": "initial_views"}')

    _fuzz("configs", call)


def test_fuzz_arrays() -> None:
    k = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    mapper = _native.NaiveMapper()

    def odd_array(rng: random.Random) -> Any:
        choice = rng.randrange(7)
        if choice == 0:
            return np.broadcast_to(np.float32(0.5), (rng.choice([1, 10**5, 2**31]), rng.choice([1, 10**5])))
        if choice == 1:
            return np.full((rng.randint(0, 50), rng.randint(0, 50)), rng.choice([0.5, np.nan, -1.0, np.inf]), np.float32)
        if choice == 2:
            return np.zeros((20, 30), dtype=rng.choice([np.float64, np.int32, np.uint8]))
        if choice == 3:
            return np.zeros((4, 4, 4), np.float32)
        if choice == 4:
            return np.full((240, 320), 0.5, np.float32)[:: rng.randint(1, 4), :: rng.randint(1, 4)]
        if choice == 5:
            return rng.choice(ODD_VALUES)
        return np.full((240, 320), 0.5, np.float32).T

    def odd_pose(rng: random.Random) -> Any:
        p = np.eye(4)
        if rng.random() < 0.5:
            p[rng.randrange(4), rng.randrange(4)] = rng.choice([np.nan, 1e308, 2.0, -1.0, 0.0])
        return p if rng.random() < 0.8 else rng.choice([np.eye(3), np.zeros((4, 4)), "x", None])

    def call(rng: random.Random) -> None:
        dets = [(rng.uniform(-1e3, 1e3), 0.0, rng.choice([10.0, np.nan]), 20.0, rng.choice(["cup", "chair"]), 0.9)]
        mapper.update(
            index=rng.choice([0, 1, 2**31]),
            intrinsics=k if rng.random() < 0.8 else odd_pose(rng),
            depth=odd_array(rng),
            world_from_camera=odd_pose(rng),
            detections=dets if rng.random() < 0.7 else rng.choice(ODD_VALUES),
        )

    _fuzz("arrays", call)


def test_fuzz_topology() -> None:
    def call(rng: random.Random) -> None:
        a, b = MAP, MAP
        if rng.random() < 0.5:
            a = mutate_json(MAP, rng)
        else:
            b = mutate_json(MAP, rng)
        _native.match_maps(a, b)

    _fuzz("topo", call)
