"""The native module: typed errors naming the argument, no panics, map round trip, evaluation."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import objslam
import pytest
from objslam.scene import gt_objects, load_scene

K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
POSE = np.eye(4)


def _update(mapper, **kw):
    args = {"index": 0, "intrinsics": K, "depth": np.full((48, 64), 0.5, np.float32), "world_from_camera": POSE, "detections": []}
    args.update(kw)
    return mapper.update(**args)


@pytest.mark.parametrize(
    ("kw", "exc", "needle"),
    [
        ({"depth": np.full((48, 64), 0.5, np.float64)}, TypeError, "depth: expected a float32"),
        ({"depth": np.full((48, 64, 1), 0.5, np.float32)}, TypeError, "depth"),
        ({"depth": np.full((48, 64), -1.0, np.float32)}, objslam.InputError, "depth: negative"),
        ({"intrinsics": np.eye(4)}, objslam.InputError, "intrinsics: expected shape (3, 3)"),
        ({"intrinsics": K * np.nan}, objslam.InputError, "intrinsics: non-finite"),
        ({"world_from_camera": np.diag([1.0, 1.0, -1.0, 1.0])}, objslam.InputError, "world_from_camera: not a rigid"),
        ({"world_from_camera": np.eye(4, dtype=np.float32)}, TypeError, "world_from_camera: expected a float64"),
        ({"detections": [(0, 0, 10, 10, "chair", 0.9)]}, objslam.InputError, "detections[0].label"),
        ({"detections": [(0, 0, 10, 10, "cup", 1.5)]}, objslam.InputError, "detections[0]: score"),
        ({"detections": [(0, 0, float("nan"), 10, "cup", 0.5)]}, objslam.InputError, "detections[0]"),
        ({"detections": "nope"}, TypeError, "detections"),
    ],
)
def test_bad_input_raises_typed_error_naming_the_argument(kw, exc, needle) -> None:
    m = objslam.NaiveMapper()
    with pytest.raises(exc) as e:
        _update(m, **kw)
    assert needle in str(e.value)
    assert len(m) == 0  # a rejected frame changes nothing


def test_zero_and_nan_depth_are_no_return() -> None:
    m = objslam.NaiveMapper()
    depth = np.zeros((48, 64), np.float32)
    depth[0, 0] = np.nan
    assert _update(m, depth=depth, detections=[(0, 0, 64, 48, "cup", 0.9)]) == [None]


def test_depth_box_gives_object_at_expected_place(tmp_path: Path) -> None:
    # A fronto-parallel plate at 0.5 m seen by an identity camera: the box (20..40, 14..34) holds
    # columns 20..39, whose centres (image x 20.5..39.5) back-project to x ∈ [(20.5-32)/100·0.5,
    # (39.5-32)/100·0.5] = [-0.0575, 0.0375] m.
    m = objslam.NaiveMapper(json.dumps({"pixel_stride": 1, "trim_fraction": 0.0}))
    ids = _update(m, detections=[(20, 14, 40, 34, "book", 0.9)])
    assert ids == [0]
    obj = json.loads(m.objects_json())[0]
    g = obj["geometry"]
    assert obj["label"] == "book" and g["shape"] == "cuboid"
    assert math.isclose(g["center"][2], 0.5, abs_tol=1e-6)
    assert math.isclose(g["center"][0], (-0.0575 + 0.0375) / 2, abs_tol=1e-6)
    assert math.isclose(g["half_extents"][0], (0.0375 + 0.0575) / 2, abs_tol=1e-6)
    path = tmp_path / "map.json"
    objslam.save_map(m.map_json(), str(path))
    assert json.loads(objslam.load_map(str(path))) == json.loads(m.map_json())
    bad = tmp_path / "bad.json"
    bad.write_text(m.map_json().replace('"version": 2', '"version": 7'))
    with pytest.raises(objslam.MapFileError, match="version 7"):
        objslam.load_map(str(bad))
    with pytest.raises(objslam.MapFileError):
        objslam.load_map(str(tmp_path / "missing.json"))


def test_evaluate_perfect_and_empty_maps(repo) -> None:
    spec = load_scene(repo / "scenes" / "scene01.toml")
    gt = gt_objects(spec)
    empty = objslam.NaiveMapper().map_json()
    ev = json.loads(objslam.evaluate_map(json.dumps(gt), empty))
    assert ev["n_objects_est"] == 0 and ev["mean"]["iou3d"] == 0.0 and ev["mean"]["cde_cm"] is None
    with pytest.raises(objslam.InputError, match="gt"):
        objslam.evaluate_map("[{]", empty)


def test_recorder_validates_and_writes(tmp_path: Path) -> None:
    r = objslam.Recorder(str(tmp_path / "r.rrd"))
    with pytest.raises(TypeError, match="rgb: expected a uint8"):
        r.log_rgb(np.zeros((4, 4, 3), np.float32))
    with pytest.raises(objslam.InputError, match="which"):
        r.log_trajectory("sideways", np.zeros((2, 3)))
    with pytest.raises(objslam.InputError, match="positions: non-finite"):
        r.log_trajectory("estimated", np.array([[0.0, np.inf, 0.0]]))
    r.log_rgb(np.zeros((4, 4, 3), np.uint8))
    r.close()
    with pytest.raises(objslam.RecordingError, match="closed"):
        r.log_event("late")
    assert (tmp_path / "r.rrd").stat().st_size > 0


def test_stub_lists_every_public_native_name() -> None:
    """The hand-written _native.pyi covers the compiled module (a light stubtest)."""
    import ast

    import objslam._native as native

    stub = ast.parse((Path(objslam.__file__).parent / "_native.pyi").read_text())
    stubbed = {n.name for n in stub.body if isinstance(n, (ast.ClassDef, ast.FunctionDef))}
    stubbed |= {t.id for n in stub.body if isinstance(n, ast.AnnAssign) for t in [n.target] if isinstance(t, ast.Name)}
    compiled = {n for n in dir(native) if not n.startswith("_") or n == "__version__"}
    assert compiled - stubbed == set(), f"missing from _native.pyi: {sorted(compiled - stubbed)}"
    for cls in (c for c in stub.body if isinstance(c, ast.ClassDef) and c.body and isinstance(c.body[0], ast.FunctionDef)):
        methods = {f.name for f in cls.body if isinstance(f, ast.FunctionDef)} - {"__init__", "__len__"}
        real = getattr(native, cls.name)
        assert all(hasattr(real, m) for m in methods), (cls.name, [m for m in methods if not hasattr(real, m)])
        public = {m for m in dir(real) if not m.startswith("_")}
        assert public - methods == set(), (cls.name, sorted(public - methods))


def test_tcp_jacobian_is_the_derivative_of_forward_tcp() -> None:
    from objslam.world import READY_QPOS, panda_urdf_path

    planner = objslam._native.Planner(str(panda_urdf_path()))
    rng = np.random.default_rng(3)
    lim = planner.joint_limits()
    for q in (READY_QPOS[:7], rng.uniform(lim[:, 0] + 0.1, lim[:, 1] - 0.1)):
        jac = planner.tcp_jacobian(q)
        assert jac.shape == (6, 7)
        t0, h = planner.forward_tcp(q), 1e-6
        for i in range(7):
            d = q.copy()
            d[i] += h
            t1 = planner.forward_tcp(d)
            np.testing.assert_allclose(jac[:3, i], (t1[:3, 3] - t0[:3, 3]) / h, atol=1e-5)
            r = t1[:3, :3] @ t0[:3, :3].T
            w = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / h
            np.testing.assert_allclose(jac[3:, i], w, atol=1e-5)
    with pytest.raises(ValueError, match="q"):
        planner.tcp_jacobian(np.zeros(6))


def test_orb_extract_matches_itself_under_a_shift() -> None:
    """The ORB binding: shapes and dtypes; an image shifted by 7 px gives mostly the same descriptors."""
    from objslam import _native

    rng = np.random.default_rng(0)
    img = np.full((240, 320), 100, np.uint8)
    for _ in range(120):
        x, y, s = rng.integers(0, 300), rng.integers(0, 220), rng.integers(4, 20)
        img[y : y + s, x : x + s] = rng.integers(0, 256)
    kp, desc = _native.orb_extract(img)
    assert kp.dtype == np.float32 and kp.shape[1] == 5 and desc.shape == (len(kp), 32) and len(kp) > 100
    shifted = np.roll(img, 7, axis=1)
    kp2, desc2 = _native.orb_extract(shifted)
    same = {tuple(d) for d, k in zip(desc, kp) if k[2] == 0}
    moved = {tuple(d) for d, k in zip(desc2, kp2) if k[2] == 0}
    assert len(same & moved) >= 0.5 * len(same)
    with pytest.raises(objslam.InputError, match="config_json"):
        _native.orb_extract(img, '{"scale_factor": 1.0, "nope": 1}')
