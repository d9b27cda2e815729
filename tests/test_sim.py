"""The SAPIEN body: every scene renders; segmentation ids match the GT objects; poses and depth agree
with the simulator's ground truth; unreachable poses raise."""

from __future__ import annotations

import json

import numpy as np
import objslam
import pytest
from objslam.camera import CameraConfig, DepthNoiseConfig
from objslam.camera_path import look_at
from objslam.scene import load_scene
from objslam.world import SimWorld, UnreachablePoseError

from .conftest import SCENES

SMALL = CameraConfig(width=320, height=240, model="ideal", depth_noise=DepthNoiseConfig(0.0, 0.0))


@pytest.fixture(scope="module")
def scene1_world():
    return SimWorld(load_scene(SCENES[0]), SMALL, np.random.default_rng(0))


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_every_scene_renders_and_segmentation_matches_gt(path) -> None:
    spec = load_scene(path)
    world = SimWorld(spec, SMALL, np.random.default_rng(0))
    # Look at the table centre from high up so every object is in view.
    world.set_qpos(world.solve_ik(look_at(np.array([0.5, 0.0, 0.75]), np.array([0.5, 0.0, 0.0])), "overview"))
    f = world.render()
    assert f.rgb.shape == (240, 320, 3) and f.rgb.dtype == np.uint8
    assert f.depth_m.shape == (240, 320) and f.depth_m.dtype == np.float32
    ids_in_image = set(np.unique(f.segmentation).tolist())
    object_ids = set(world.actor_to_object)
    assert {world.actor_to_object[a][0] for a in object_ids} == {o.id for o in spec.objects}
    # Every GT object is visible in the overview, and no unknown object id appears.
    assert object_ids <= ids_in_image, f"missing objects: {object_ids - ids_in_image}"
    # Objects have not fallen or moved while settling.
    for oid, (center, yaw) in world.ground_truth().items():
        o = spec.objects[oid]
        assert np.allclose(center[:2], o.position, atol=2e-3), (oid, center, o.position)
        assert abs(center[2] - o.half_extents[2]) < 2e-3


def test_fk_pose_matches_renderer_and_depth_matches_geometry(scene1_world) -> None:
    w = scene1_world
    spec = w.spec
    o = max(spec.objects, key=lambda o: o.half_extents[0] * o.half_extents[1])
    top = np.array([o.position[0], o.position[1], 2 * o.half_extents[2]])
    eye = top + np.array([0.0, 0.0, 0.4])
    frames = list(w.move_camera_to(look_at(eye, top), frame_rate_hz=4.0))
    f = frames[-1]
    assert np.abs(f.world_from_camera_fk - f.world_from_camera_gt).max() < 1e-5
    # Back-project the centre pixel: it must land on the object's top face.
    c = f.world_from_camera_gt
    u, v = 160, 120
    d = float(f.depth_m[v, u])
    kinv = np.linalg.inv(f.intrinsics)
    p = c[:3, :3] @ (kinv @ np.array([u, v, 1.0]) * d) + c[:3, 3]
    assert abs(p[2] - top[2]) < 3e-3, (p, top)
    assert np.linalg.norm(p[:2] - top[:2]) < 0.02


def test_core_back_projection_matches_the_renderers_position_buffer(scene1_world) -> None:
    """The core's camera model and the renderer agree on where a pixel is: pixel (i, j) is the ray
    through image point (i + 0.5, j + 0.5). The naive mapper's extent of an object box (every pixel,
    no trimming, exact depth and pose) equals the extent of the same pixels' points in SAPIEN's
    position buffer; integer pixel coordinates would shift it by half a pixel (~0.5 mm here)."""
    w = scene1_world
    o = max(w.spec.objects, key=lambda o: o.half_extents[0] * o.half_extents[1])
    top = np.array([o.position[0], o.position[1], 2 * o.half_extents[2]])
    eye = top + np.array([-0.12, -0.06, 0.35])
    f = list(w.move_camera_to(look_at(eye, top), frame_rate_hz=4.0))[-1]
    pos = w.camera.get_picture("Position")  # OpenGL camera axes: x right, y up, z back
    ids = [a for a, (oid, _) in w.actor_to_object.items() if oid == o.id]
    mask = np.isin(f.segmentation, ids)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    u0, u1, v0, v1 = int(cols[0]), int(cols[-1]) + 1, int(rows[0]), int(rows[-1]) + 1
    m = objslam.NaiveMapper(json.dumps({"pixel_stride": 1, "trim_fraction": 0.0, "voxel_m": 1e-4}))
    ids_out = m.update(
        index=0,
        intrinsics=f.intrinsics,
        depth=f.depth_m,
        world_from_camera=f.world_from_camera_gt,
        detections=[(float(u0), float(v0), float(u1), float(v1), "book", 0.9)],
    )
    assert ids_out == [0]
    g = json.loads(m.objects_json())[0]["geometry"]
    lo_core = np.array(g["center"]) - np.array(g["half_extents"])
    hi_core = np.array(g["center"]) + np.array(g["half_extents"])
    box = pos[v0:v1, u0:u1]
    valid = (f.depth_m[v0:v1, u0:u1] > 0).ravel()
    p_cv = box[..., :3].reshape(-1, 3)[valid] * np.array([1.0, -1.0, -1.0])
    c = f.world_from_camera_gt
    p_world = p_cv @ c[:3, :3].T + c[:3, 3]
    np.testing.assert_allclose(lo_core, p_world.min(axis=0), atol=5e-5)
    np.testing.assert_allclose(hi_core, p_world.max(axis=0), atol=5e-5)


def test_unreachable_pose_raises(scene1_world) -> None:
    with pytest.raises(UnreachablePoseError, match="unreachable"):
        list(
            scene1_world.move_camera_to(
                look_at(np.array([2.0, 0.0, 0.5]), np.array([2.5, 0, 0])), frame_rate_hz=4
            )
        )


def test_cartesian_move_keeps_the_table_in_view(scene1_world) -> None:
    """A move between two views across the table: the camera travels close to the straight line
    between them and keeps looking at the table (a joint-space move swings it off), while the
    joint-space move between the same views deviates from the line."""
    w = scene1_world
    target = np.array([0.5, 0.0, 0.0])
    a = look_at(np.array([0.35, 0.25, 0.45]), target)
    b = look_at(np.array([0.40, -0.30, 0.40]), target)
    list(w.move_camera_to(a, frame_rate_hz=4.0, path="joint"))
    q_goal = w.solve_ik(b, "b")
    path = w.camera_path(w.qpos(), b, q_goal)
    assert path is not None
    p0, p1 = a[:3, 3], b[:3, 3]
    line = (p1 - p0) / np.linalg.norm(p1 - p0)

    def off_line(m: np.ndarray) -> float:
        d = m[:3, 3] - p0
        return float(np.linalg.norm(d - np.dot(d, line) * line))

    def off_target_deg(m: np.ndarray) -> float:
        to = target - m[:3, 3]
        return float(np.degrees(np.arccos(np.clip(np.dot(m[:3, 2], to / np.linalg.norm(to)), -1, 1))))

    poses = [w.world_from_camera_fk(q) for q in path]
    assert max(off_line(m) for m in poses) < 0.005
    # Both views look at the target, so every waypoint aims at it (the roll about the axis is free).
    assert max(off_target_deg(m) for m in poses) < 1.0
    assert np.allclose(poses[-1][:3, 3], p1, atol=2e-3)
    assert abs(path[-1][6] - q_goal[6]) < np.radians(3.0)
    frames = list(w.move_camera_to(b, frame_rate_hz=8.0))
    assert w.last_move_path == "cartesian"
    # Executed by the PD drives: every streamed frame still looks at the table centre.
    assert max(off_target_deg(f.world_from_camera_gt) for f in frames) < 5.0
    assert np.allclose(frames[-1].world_from_camera_gt[:3, 3], p1, atol=5e-3)
    # Timed as one Ruckig move of the path parameter: the camera speeds up once and slows down
    # once (no stop at the 2 cm waypoints): frame-to-frame steps are unimodal.
    steps = np.linalg.norm(np.diff([f.world_from_camera_gt[:3, 3] for f in frames[:-1]], axis=0), axis=1)
    peak, tol = int(np.argmax(steps)), 0.1 * float(steps.max())
    assert len(steps) >= 6 and steps.max() > 0.01, steps
    assert np.all(np.diff(steps[: peak + 1]) > -tol) and np.all(np.diff(steps[peak:]) < tol), steps.round(4)
