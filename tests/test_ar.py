"""Augmented reality through Python (``objslam._native.ar_run``): masks against closed forms and
against SAPIEN's rendered depth, picks, drops, typed errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import sapien
from objslam import _native
from objslam.camera import SAPIEN_FROM_CV, CameraConfig
from objslam.camera_path import look_at
from objslam.scene import gt_objects, load_scene
from objslam.topo import map_json_from_gt
from objslam.world import SimWorld
from scipy.spatial.transform import Rotation

TABLE = {"center_xy_m": [0.0, 0.0], "size_xy_m": [1.0, 1.0]}
BLOCK = {
    "id": 3,
    "label": "block",
    "geometry": {
        "shape": "cuboid",
        "center": [0.0, 0.0, 0.1],
        "yaw_rad": 0.0,
        "half_extents": [0.05, 0.05, 0.1],
    },
}


def top_camera(w: int = 640, h: int = 480, f: float = 500.0) -> dict:
    """1 m above the origin looking straight down (image x = world x, image y = world −y)."""
    pose = [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 1], [0, 0, 0, 1]]
    return {
        "intrinsics": {"width": w, "height": h, "fx": f, "fy": f, "cx": w / 2, "cy": h / 2},
        "world_from_camera": pose,
    }


def box_model(name: str, center: list[float], half: list[float]) -> dict:
    return {
        "name": name,
        "shape": {"kind": "cuboid", "half_extents_m": half},
        "placement": {"mode": "world", "position_m": center},
    }


def px(a: float, b: float) -> int:
    """Pixels whose centres k + 0.5 fall in [a, b)."""
    return math.ceil(b - 0.5) - math.ceil(a - 0.5)


def test_box_behind_a_box_loses_exactly_the_projected_overlap() -> None:
    req = {
        "objects": [BLOCK],
        "table": TABLE,
        "models": [box_model("v", [0.05, 0.0, 0.05], [0.05, 0.05, 0.05])],
        "camera": top_camera(),
    }
    answer, coverage, depth = _native.ar_run(json.dumps(req))
    masks = json.loads(answer)["masks"]
    rows = px(240 - 0.05 * 500 / 0.9, 240 + 0.05 * 500 / 0.9)
    silhouette = px(320, 320 + 0.1 * 500 / 0.9) * rows
    hidden = px(320, 320 + 0.05 * 500 / 0.8) * rows
    assert masks[0]["silhouette_px"] == silhouette == int((coverage[0] > 0).sum())
    assert masks[0]["visible_px"] == silhouette - hidden == int((coverage[0] == 2).sum())
    assert depth.shape == (480, 640) and depth[240, 320] == pytest.approx(0.8, abs=1e-6)
    assert depth[100, 100] == pytest.approx(1.0, abs=1e-6)  # the table
    assert depth[5, 5] == 0.0  # beyond its edge


def test_pick_fires_the_class_event_and_drop_rests_on_top() -> None:
    req = {
        "map": json.loads(map_json_from_gt([BLOCK])),
        "table": TABLE,
        "models": [box_model("cube", [0.0, 0.0, 0.4], [0.02, 0.02, 0.02])],
        "camera": top_camera(),
        "picks": [[320.0, 240.0], [20.0, 20.0]],
        "drop": [[0.0, 0.0, 0.0]],
        "config": {"interaction": {"events": {"block": "open_box"}}},
    }
    out = json.loads(_native.ar_run(json.dumps(req))[0])
    assert out["picks"][0]["event"] == "open_box" and out["picks"][1] is None
    body = out["drop"]["bodies"][0]
    assert out["drop"]["settled"]
    assert body["world_from_model"]["translation"][2] == pytest.approx(0.22, abs=1e-3)
    assert [c["kind"] for c in body["contacts"]] == ["object"]


def test_bad_input_raises_input_error_naming_the_field() -> None:
    anchored = {
        "name": "m",
        "shape": {"kind": "fit"},
        "placement": {"mode": "object", "label": "cup"},
    }
    with pytest.raises(_native.InputError, match="no map object of class cup"):
        _native.ar_run(json.dumps({"objects": [], "models": [anchored]}))
    nan = box_model("n", [0.0, 0.0, 0.0], [0.01, 0.01, 0.01])
    # JSON has no NaN: json.dumps writes one anyway and the request is refused as malformed (the core
    # names the field for NaNs that reach it, see core/src/ar/mod.rs tests).
    with pytest.raises(_native.InputError, match="malformed AR request"):
        _native.ar_run(json.dumps({"models": [nan]}).replace("0.0, 0.0, 0.0", "NaN, 0.0, 0.0"))
    with pytest.raises(_native.InputError, match="real_depth"):
        _native.ar_run(json.dumps({"camera": top_camera()}), real_depth=np.zeros((10, 10), np.float32))
    answer, coverage, _ = _native.ar_run(json.dumps({"objects": [], "camera": top_camera()}))
    assert json.loads(answer)["masks"] == [] and coverage.shape[0] == 0


def test_map_depth_of_the_true_objects_matches_sapiens_rendered_depth(repo) -> None:
    """The AR depth of a scene's true primitives equals SAPIEN's depth at that camera pose (up to the
    renderer's cylinder tessellation), so occlusion errors measure the map, not the rasteriser."""
    scene = load_scene(repo / "scenes" / "scene01.toml")
    cam_cfg = CameraConfig(width=320, height=240)
    world = SimWorld(scene, cam_cfg, np.random.default_rng(0))
    camera = world.scene.add_camera("ar_test", 320, 240, math.radians(cam_cfg.fovy_deg), 0.02, 3.0)
    world_from_cv = look_at(np.array([0.95, 0.1, 0.35]), np.array([0.5, 0.0, 0.03]))
    x, y, z, w = Rotation.from_matrix(world_from_cv[:3, :3] @ SAPIEN_FROM_CV.T).as_quat()
    camera.entity.set_pose(sapien.Pose(world_from_cv[:3, 3], [w, x, y, z]))
    world.scene.update_render()
    camera.take_picture()
    pos = camera.get_picture("Position")
    seg = camera.get_picture("Segmentation")[..., 1]
    truth = np.where(pos[..., 3] < 1, -pos[..., 2], 0.0)
    used = np.asarray(camera.get_model_matrix()) @ np.diag([1.0, -1.0, -1.0, 1.0])
    k = cam_cfg.intrinsics()
    req = {
        "objects": gt_objects(scene, world.ground_truth()),
        "table": {"center_xy_m": list(scene.table.center), "size_xy_m": list(scene.table.size)},
        "camera": {
            "intrinsics": {
                "width": 320,
                "height": 240,
                "fx": k[0, 0],
                "fy": k[1, 1],
                "cx": k[0, 2],
                "cy": k[1, 2],
            },
            "world_from_camera": used.tolist(),
        },
    }
    _, _, ours = _native.ar_run(json.dumps(req))
    objects = np.isin(seg, [a.per_scene_id for a in world.object_actors.values()])
    assert objects.sum() > 500
    both = objects & (ours > 0)
    assert both.sum() / objects.sum() > 0.97
    err = np.abs(ours[both] - truth[both])
    assert np.median(err) < 1e-3 and np.mean(err < 5e-3) > 0.97


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


def test_live_depth_fixes_an_offset_oversized_map_against_sapiens_truth(repo) -> None:
    """A virtual box mostly behind a real can, seen by the d435 sensor model: with the map's
    primitives offset by 1 cm and 20 % too large, the map alone hides most of the visible strip;
    fused with the live frame (noise, scale error, shadow, registration error) the visible pixels
    match SAPIEN's exact ones."""
    from dataclasses import replace

    from objslam.camera import CV_FROM_GL, RgbdSensor

    scene = load_scene(repo / "scenes" / "scene01.toml")
    cam_cfg = CameraConfig()
    world = SimWorld(scene, cam_cfg, np.random.default_rng(0))
    exact_colour = replace(cam_cfg.calibration, colour_focal_sigma_rel=0.0, colour_pp_sigma_px=0.0)
    sensor = RgbdSensor(replace(cam_cfg, calibration=exact_colour), seed=7)
    truth_objects = gt_objects(scene, world.ground_truth())
    # The can (radius 3.3 cm, 10.3 cm tall) hides all of an 8 cm box behind it but a 2.3 cm strip.
    c = np.asarray(next(o for o in truth_objects if o["label"] == "can")["geometry"]["center"])
    eye, behind = c + np.array([0.4, 0.0, 0.3 - c[2]]), c[:2] + np.array([-0.09, 0.035])
    camera = world.scene.add_camera("ar_live", 640, 480, math.radians(cam_cfg.fovy_deg), 0.02, 3.0)
    world_from_cv = look_at(eye, np.array([*((c[:2] + behind) / 2), 0.04]))
    x, y, z, w = Rotation.from_matrix(world_from_cv[:3, :3] @ SAPIEN_FROM_CV.T).as_quat()
    camera.entity.set_pose(sapien.Pose(world_from_cv[:3, 3], [w, x, y, z]))
    world.scene.update_render()
    camera.take_picture()
    pos = camera.get_picture("Position")
    robot = np.isin(camera.get_picture("Segmentation")[..., 1], list(world.robot_actor_ids))
    exact = np.where((pos[..., 3] < 1) & ~robot, -pos[..., 2], 0.0).astype(np.float32)
    points = pos[..., :3] * CV_FROM_GL
    points[(pos[..., 3] >= 1) | robot] = 0.0
    rgb = (np.clip(camera.get_picture("Color")[..., :3], 0, 1) * 255).astype(np.uint8)
    colour, live = sensor.apply(
        points, camera.get_picture("Normal")[..., :3] * CV_FROM_GL, rgb, frame_index=0
    )
    grey = colour.mean(axis=2).round().astype(np.uint8)
    used = np.asarray(camera.get_model_matrix()) @ np.diag([1.0, -1.0, -1.0, 1.0])
    k = cam_cfg.intrinsics()
    intrinsics = {"width": 640, "height": 480, "fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2]}
    req = {
        "table": {"center_xy_m": list(scene.table.center), "size_xy_m": list(scene.table.size)},
        "models": [box_model("v", [*behind, 0.04], [0.02, 0.02, 0.04])],
        "camera": {"intrinsics": intrinsics, "world_from_camera": used.tolist()},
    }
    bad_map = [
        {
            **o,
            "geometry": {
                **o["geometry"],
                "center": list(np.asarray(o["geometry"]["center"]) + [0.0, 0.01, 0.0]),
                "half_extents": [h * 1.2 for h in o["geometry"]["half_extents"]],
            },
        }
        for o in truth_objects
    ]
    exact_req = {**req, "objects": truth_objects, "config": {"live": {"source": "exact"}}}
    _, true, _ = _native.ar_run(json.dumps(exact_req), real_depth=exact)
    _, map_only, _ = _native.ar_run(json.dumps({**req, "objects": bad_map}))
    answer, fused, _ = _native.ar_run(json.dumps({**req, "objects": bad_map}), real_depth=live, grey=grey)
    visible = true[0] == 2
    assert 200 < visible.sum() < (true[0] > 0).sum()  # partly hidden
    iou_map, iou_fused = _iou(map_only[0] == 2, visible), _iou(fused[0] == 2, visible)
    assert iou_fused > 0.85 and iou_fused > iou_map + 0.1, (iou_fused, iou_map, json.loads(answer)["live"])
