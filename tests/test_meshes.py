"""Mesh objects and hard scenes: the ground-truth primitives enclose the scanned meshes tightly, a
mesh scene renders in SAPIEN and its depth agrees with the ground truth, the validator allows
touching and names interpenetration, the hard-scene generator is deterministic, and the committed
hard and test scenes have the properties the suite promises."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import tomllib
from objslam.camera import CameraConfig, DepthNoiseConfig
from objslam.clutter import ClutterConfig, generate_hard_scene
from objslam.meshes import (
    ASSETS,
    get_asset,
    min_area_rectangle,
    min_enclosing_circle,
    placed_mesh,
    read_obj_vertices,
)
from objslam.scene import SceneFileError, footprint_gap_m, load_scene, parse_scene, scene_to_toml

REPO = Path(__file__).resolve().parents[1]
HARD = sorted((REPO / "scenes" / "hard").glob("hard*.toml"))
TEST = sorted((REPO / "scenes" / "test").glob("test*.toml"))


def _mesh_in_object_frame(name: str, scale: float, yaw_rad: float, shape: str) -> tuple[np.ndarray, object]:
    """The asset's visual vertices in its ground-truth primitive's frame, and the placement."""
    m = placed_mesh(name, scale=scale, mesh_yaw_rad=yaw_rad, shape=shape)
    a = get_asset(name)
    v = np.concatenate([read_obj_vertices(a.path(f)) for f in a.visual]) * a.unit_m * scale
    t = m.object_from_mesh
    return v @ t[:3, :3].T + t[:3, 3], m


def test_rectangle_and_circle_against_closed_forms() -> None:
    rng = np.random.default_rng(0)
    # A 6 x 2 rectangle turned by 25°, sampled on its boundary: the minimum-area rectangle is itself.
    u = rng.uniform(-1, 1, 400)
    local = np.concatenate(
        [
            np.stack([3 * u, np.sign(rng.uniform(-1, 1, 400))], 1),
            np.stack([3 * np.sign(rng.uniform(-1, 1, 400)), u], 1),
        ]
    )
    local = np.concatenate([local, [[3, 1], [-3, 1], [-3, -1], [3, -1]]])
    a = math.radians(25.0)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    centre, angle, half = min_area_rectangle(local @ rot.T + [0.4, -0.2])
    assert np.allclose(centre, [0.4, -0.2], atol=1e-9)
    assert math.isclose(angle, a, abs_tol=1e-9)
    assert np.allclose(half, [3, 1], atol=1e-9)
    # Points on a circle of radius 0.7 and inside it: the circle is the minimum enclosing one.
    th = rng.uniform(0, 2 * math.pi, 50)
    pts = np.concatenate([np.stack([np.cos(th), np.sin(th)], 1) * 0.7, rng.uniform(-0.4, 0.4, (200, 2))]) + [
        1.0,
        2.0,
    ]
    c, r = min_enclosing_circle(pts)
    assert np.allclose(c, [1.0, 2.0], atol=1e-9) and math.isclose(r, 0.7, rel_tol=1e-9)


@pytest.mark.parametrize("name", sorted(ASSETS))
def test_ground_truth_primitive_encloses_the_mesh_tightly(name: str) -> None:
    """Every visual vertex lies inside the primitive, and the mesh touches each of its sides (the
    box's faces, the cylinder's wall, top and bottom) to within 0.1 mm."""
    a = ASSETS[name]
    shape = "cylinder" if a.label in ("cup", "can", "bottle", "bowl", "ball") else "cuboid"
    v, m = _mesh_in_object_frame(name, sum(a.scale_range) / 2, math.radians(37.0), shape)
    hx, hy, hz = m.half_extents
    tol = 1e-4
    assert np.isclose(v[:, 2].min(), -hz, atol=tol) and np.isclose(v[:, 2].max(), hz, atol=tol)
    if shape == "cuboid":
        for k, h in enumerate((hx, hy)):
            assert np.isclose(v[:, k].min(), -h, atol=tol) and np.isclose(v[:, k].max(), h, atol=tol)
    else:
        r = np.linalg.norm(v[:, :2], axis=1)
        assert hx == hy and r.max() <= hx + tol and r.max() >= hx - tol


def _mesh_scene(objects: list[dict]) -> dict:
    return {
        "scene": {"name": "m", "seed": 1},
        "table": {"center": [0.5, 0.0], "size": [0.8, 1.2]},
        "objects": objects,
    }


def _butter_pair(gap_m: float) -> dict:
    """Two butter cartons at yaw 0, side by side along x, their hulls ``gap_m`` apart (< 0: overlapping)."""
    m = placed_mesh("butter", scale=1.0, mesh_yaw_rad=0.0, shape="cuboid")
    c, s = math.cos(m.box_yaw_rad), math.sin(m.box_yaw_rad)
    x = m.footprint_local @ np.array([c, -s])  # world x of the hull, relative to the centre
    dx = float(x.max() - x.min()) + gap_m
    one = {"class": "block", "asset": "butter", "scale": 1.0, "yaw_deg": 0.0}
    return _mesh_scene([{**one, "position": [0.5, 0.1]}, {**one, "position": [round(0.5 + dx, 4), 0.1]}])


def test_validator_accepts_a_3_mm_gap_and_rejects_interpenetration() -> None:
    spec = parse_scene(_butter_pair(0.003))
    gap = footprint_gap_m(*spec.objects)
    assert 0.0029 <= gap <= 0.005  # ≥ the x separation; the hulls' nearest points need not face along x
    with pytest.raises(SceneFileError) as e:
        parse_scene(_butter_pair(-0.002))
    assert e.value.field == "objects[1].position"
    assert "objects[1] (block, asset butter) overlaps objects[0] (block, asset butter)" in str(e.value)
    depth_mm = float(str(e.value).split("interpenetrate by ")[1].split(" mm")[0])
    assert 0.5 <= depth_mm <= 2.1


def test_mesh_object_errors_name_the_field() -> None:
    bad = {"class": "can", "asset": "no_such_asset", "position": [0.5, 0.0]}
    with pytest.raises(SceneFileError, match="objects\\[0\\].asset: unknown asset"):
        parse_scene(_mesh_scene([bad]))
    with pytest.raises(SceneFileError, match="objects\\[0\\].scale"):
        parse_scene(_mesh_scene([{**bad, "asset": "alphabet_soup", "scale": 9.0}]))
    with pytest.raises(SceneFileError, match="unknown keys \\['radius'\\]"):
        parse_scene(_mesh_scene([{**bad, "asset": "alphabet_soup", "radius": 0.03}]))


def test_generator_is_deterministic_per_seed() -> None:
    cfg = ClutterConfig(n_objects=(14, 14))
    a = scene_to_toml(generate_hard_scene(seed=7, name="d", config=cfg), position_decimals=4)
    b = scene_to_toml(generate_hard_scene(seed=7, name="d", config=cfg), position_decimals=4)
    c = scene_to_toml(generate_hard_scene(seed=8, name="d", config=cfg), position_decimals=4)
    assert a == b and a != c


@pytest.mark.parametrize("path", HARD + TEST, ids=lambda p: p.stem)
def test_hard_and_test_scenes_have_the_promised_layouts(path: Path) -> None:
    spec = load_scene(path)
    n = len(spec.objects)
    assert 10 <= n <= 20
    assert sum(o.mesh is not None for o in spec.objects) >= 0.4 * n
    gaps = [(footprint_gap_m(a, b), a, b) for i, a in enumerate(spec.objects) for b in spec.objects[i + 1 :]]
    # Same-label neighbours 2-5 mm apart (pairs and rows), nothing interpenetrating.
    assert sum(1 for g, a, b in gaps if a.cls == b.cls and 0.0015 <= g <= 0.0055) >= 3
    assert min(g for g, _, _ in gaps) > 0.0
    # Objects at the reach limit.
    assert sum(1 for o in spec.objects if math.hypot(*o.position) >= 0.72) >= 2
    # The file is what the generator writes for its seed (its header says so).
    assert tomllib.loads(path.read_text())["scene"]["seed"] == spec.seed


def test_hard_and_test_seeds_differ() -> None:
    hard = {load_scene(p).seed for p in HARD}
    test = {load_scene(p).seed for p in TEST}
    assert len(HARD) >= 7 and len(TEST) >= 7 and not hard & test


SMALL = CameraConfig(width=320, height=240, model="ideal", depth_noise=DepthNoiseConfig(0.0, 0.0))


@pytest.mark.slow
def test_mesh_scene_renders_and_depth_matches_the_ground_truth() -> None:
    """A scene of four meshes in SAPIEN: each is visible, stands where its file says, and the points
    its depth pixels back-project to lie inside its ground-truth primitive (grown by 4 mm for the
    settling and the depth quantisation) and reach its top."""
    from objslam.camera_path import look_at
    from objslam.world import SimWorld

    objects = [
        {"class": "can", "asset": "alphabet_soup", "scale": 0.9, "yaw_deg": 30.0, "position": [0.45, -0.12]},
        {"class": "block", "asset": "orange_juice", "scale": 0.85, "yaw_deg": 20.0, "position": [0.55, 0.02]},
        {"class": "cup", "asset": "red_mug", "scale": 0.7, "yaw_deg": -60.0, "position": [0.45, 0.14]},
        {"class": "book", "asset": "popcorn", "scale": 1.0, "yaw_deg": 75.0, "position": [0.62, -0.14]},
    ]
    spec = parse_scene(_mesh_scene(objects))
    world = SimWorld(spec, SMALL, np.random.default_rng(0))
    world.set_qpos(world.solve_ik(look_at(np.array([0.5, 0.0, 0.75]), np.array([0.5, 0.0, 0.0])), "overview"))
    f = world.render()
    k_inv = np.linalg.inv(f.intrinsics)
    truth = world.ground_truth()
    for actor_id, (oid, _) in world.actor_to_object.items():
        o = spec.objects[oid]
        centre, yaw = truth[oid]
        assert math.dist(centre[:2], o.position) < 0.004, o
        assert abs(centre[2] - o.half_extents[2]) < 0.004, o
        rows, cols = np.nonzero((f.segmentation == actor_id) & (f.depth_m > 0))
        assert len(rows) > 50, f"{o.mesh.asset} not visible"
        rays = k_inv @ np.stack([cols + 0.5, rows + 0.5, np.ones_like(rows)]).astype(float)
        p_cam = rays * f.depth_m[rows, cols]
        p_world = f.world_from_camera_gt[:3, :3] @ p_cam + f.world_from_camera_gt[:3, 3:4]
        c, s = math.cos(yaw), math.sin(yaw)
        local = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ (p_world - centre[:, None])
        hx, hy, hz = o.half_extents
        grow = 0.004
        if o.shape == "cuboid":
            assert np.all(np.abs(local[0]) <= hx + grow) and np.all(np.abs(local[1]) <= hy + grow), (
                o.mesh.asset
            )
        else:
            assert np.all(np.hypot(local[0], local[1]) <= hx + grow), o.mesh.asset
        assert np.all(local[2] <= hz + grow) and local[2].max() >= hz - grow, o.mesh.asset
