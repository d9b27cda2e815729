"""World-model presets and the RGB-D sensor model: the preset overlay, errors naming the key, the
depth model's statistics through the binding against its closed form, the detector's persistent
errors, texture orientation, and one real SAPIEN render under the realistic preset."""

from __future__ import annotations

import json

import numpy as np
import pytest
from objslam import _native
from objslam.camera import CameraConfig, RgbdSensor
from objslam.config import ConfigError, load_run_config
from objslam.detector import DetectorConfig, DetectorView, SimulatedDetector
from objslam.textures import object_texture

from .conftest import SCENES

W, H = 320, 240


def _plane(z: float, k: np.ndarray, box: tuple[float, slice] | None = None) -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    zz = np.full((H, W), z, dtype=np.float32)
    if box is not None:
        zz[60:180, box[1]] = box[0]
    pts = np.stack([(u + 0.5 - k[0, 2]) / k[0, 0] * zz, (v + 0.5 - k[1, 2]) / k[1, 1] * zz, zz], axis=-1)
    normals = np.zeros((H, W, 3), dtype=np.float32)
    normals[..., 2] = -1.0
    return pts.astype(np.float32), normals


def test_default_is_realistic_and_ideal_preset_overlays_the_ideal_world() -> None:
    real = load_run_config()
    assert real.preset == "realistic" and real.camera.model == "d435" and real.textures.style == "varied"
    assert real.detector.box_bias_frac > 0 and real.detector.distractors > 0
    for ideal in (load_run_config(preset="ideal"), load_run_config(overrides=['preset="ideal"'])):
        assert ideal.preset == "ideal"
        assert ideal.camera.model == "ideal" and ideal.textures.style == "shapes"
        assert (ideal.camera.depth_noise.sigma_rel, ideal.camera.depth_noise.quantisation_m) == (0.001, 0.001)
        d = ideal.detector
        assert (d.miss_rate, d.box_jitter_frac, d.label_confusion_rate, d.false_positives_per_frame) == (
            0.05, 0.02, 0.02, 0.05,
        )
        assert not d.persistent
    # Overrides still apply over the preset.
    assert load_run_config(preset="ideal", overrides=["detector.miss_rate=0.2"]).detector.miss_rate == 0.2


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ('preset="foggy"', "preset"),
        ("camera.stereo.baseline_m=-0.05", "camera.stereo.baseline_m"),
        ("camera.stereo.grazing_end_deg=10.0", "camera.stereo.grazing_end_deg"),
        ("camera.colour.exposure_s=2.0", "camera.colour.exposure_s"),
        ("camera.calibration.extrinsic_rot_sigma_deg=90.0", "camera.calibration.extrinsic_rot_sigma_deg"),
        ('camera.model="lidar"', "camera.model"),
        ("detector.view_miss_rate=1.5", "detector.view_miss_rate"),
        ('textures.style="marble"', "textures.style"),
    ],
)
def test_bad_parameter_is_a_config_error_naming_the_key(override: str, key: str) -> None:
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_run_config(overrides=[override])


def test_plane_noise_follows_the_closed_form_and_is_correlated() -> None:
    cam = CameraConfig(width=W, height=H)
    k = cam.intrinsics()
    s = cam.stereo
    for z in (0.3, 0.5, 0.7):
        pts, nrm = _plane(z, k)
        errs = []
        for frame in range(6):
            req = cam.sensor_request(seed=1, frame_index=frame)
            depth, rgb, _ = _native.sensor_model(json.dumps(req), pts, nrm, None)
            assert rgb is None and depth.shape == (H, W)
            d = depth[20:-20, 20:-20].astype(np.float64)
            # Plane fit removes the unit's scale and registration error, as the datasheet's RMS does.
            v, u = np.nonzero(d > 0)
            a = np.stack([u, v, np.ones_like(u)], axis=1).astype(np.float64)
            coef, *_ = np.linalg.lstsq(a, d[v, u], rcond=None)
            res = np.zeros_like(d)
            res[v, u] = d[v, u] - a @ coef
            errs.append(res)
        e = np.stack(errs)
        rms = float(np.sqrt(np.mean(e**2)))
        want = float(np.hypot(z * z * s.subpixel_rms_px / (s.focal_px * s.baseline_m), s.unit_m / np.sqrt(12)))
        assert abs(rms / want - 1) < 0.15, (z, rms, want)
        lag1 = float(np.mean(e[:, :, 1:] * e[:, :, :-1]) / np.mean(e**2))
        assert lag1 > 0.5, lag1  # correlation length > 1 px


def test_shadow_beside_a_step_edge_range_and_per_seed_scale() -> None:
    cam = CameraConfig(width=W, height=H)
    k = cam.intrinsics()
    pts, nrm = _plane(0.6, k, (0.4, slice(120, 200)))
    depth, _, info = _native.sensor_model(json.dumps(cam.sensor_request(seed=3)), pts, nrm, None)
    row = depth[120]
    fb = json.loads(info)["unit"]["colour_true"]["fx"] * cam.stereo.baseline_m
    width = fb * (1 / 0.4 - 1 / 0.6)
    # Left of the box (the right imager sits at +x) about f·B·(1/z_near − 1/z_far) px have no return,
    # give or take the registration shift and the mixed band; right of it none.
    left = int(np.sum(row[90:125] == 0))
    assert abs(left - width) <= 3, (left, width)
    assert np.all(row[205:260] > 0)
    near, _ = _plane(0.1, k)
    assert np.all(_native.sensor_model(json.dumps(cam.sensor_request(seed=3)), near, nrm, None)[0] == 0)
    units = [RgbdSensor(cam, seed).unit["depth_scale"] for seed in (5, 5, 6)]
    assert units[0] == units[1] != units[2]


def test_sensor_binding_rejects_bad_buffers() -> None:
    cam = CameraConfig(width=W, height=H)
    pts, nrm = _plane(0.5, cam.intrinsics())
    with pytest.raises(_native.InputError, match="normals"):
        _native.sensor_model(json.dumps(cam.sensor_request(seed=0)), pts, nrm[:, :10], None)
    with pytest.raises(_native.InputError, match="request_json"):
        _native.sensor_model("{}", pts, nrm, None)


def test_renderer_buffers_give_the_frame_of_their_opencv_form() -> None:
    """The renderer's own (H, W, 4) buffers (OpenGL axes, w >= 1 = no surface, RGBA in [0, 1])
    give exactly the depth and colour of the same frame converted to OpenCV axes and 8 bits."""
    cam = CameraConfig(width=W, height=H)
    pts, nrm = _plane(0.5, cam.intrinsics(), box=(0.4, slice(100, 200)))
    rng = np.random.default_rng(3)
    gl = np.array([1.0, -1.0, -1.0], dtype=np.float32)
    pos = np.concatenate([pts * gl, np.zeros((H, W, 1), np.float32)], axis=-1)
    pos[:20, :, 3] = 1.0  # nothing hit
    normal = np.concatenate([nrm * gl, np.zeros((H, W, 1), np.float32)], axis=-1)
    rgba = rng.uniform(-0.1, 1.1, size=(H, W, 4)).astype(np.float32)
    points = pos[..., :3] * gl
    points[pos[..., 3] >= 1] = 0.0
    rgb = (np.clip(rgba[..., :3] * np.float32(255.0), 0.0, 255.0) + np.float32(0.5)).astype(np.uint8)
    motion = np.eye(4)
    motion[0, 3] = 0.004
    sensor = RgbdSensor(cam, seed=2)
    for m in (None, motion):
        want = sensor.apply(points, nrm, rgb, frame_index=1, camera_end_from_start=m)
        got = sensor.apply(pos, normal, rgba, frame_index=1, camera_end_from_start=m)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
    with pytest.raises(_native.InputError, match="rgb"):
        _native.sensor_model(json.dumps(cam.sensor_request(seed=0)), pos, normal, rgb)
    with pytest.raises(_native.InputError, match="normals"):
        _native.sensor_model(json.dumps(cam.sensor_request(seed=0)), pos, normal[:, :, :3].copy(), rgba)
    # Pixels of dropped segmentation ids (the robot's) are the same as pixels marked w = 1.
    seg = (np.arange(H * W, dtype=np.uint32).reshape(H, W) // 997) % 7
    marked = pos.copy()
    marked[np.isin(seg, [2, 5]), 3] = 1.0
    for m in (None, motion):
        want = sensor.apply(marked, normal, rgba, frame_index=1, camera_end_from_start=m)
        got = sensor.apply(pos, normal, rgba, frame_index=1, camera_end_from_start=m, segmentation=seg, dropped_ids=[5, 2])
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        assert not np.array_equal(got[1], sensor.apply(pos, normal, rgba, frame_index=1, camera_end_from_start=m)[1])
    with pytest.raises(_native.InputError, match="segmentation"):
        sensor.apply(pos, normal, rgba, frame_index=1, segmentation=seg[:, :10], dropped_ids=[5])


def _view(eye: np.ndarray, centre: np.ndarray) -> DetectorView:
    m = np.eye(4)
    m[:3, 3] = eye
    return DetectorView(world_from_camera=m, intrinsics=np.eye(3), object_centres={5: centre})


def test_detector_errors_persist_per_object_and_view() -> None:
    seg = np.zeros((120, 160), dtype=np.uint32)
    seg[10:70, 20:100] = 5
    ids = {5: (0, "cup")}
    cfg = DetectorConfig(miss_rate=0.0, box_jitter_frac=0.0, label_confusion_rate=0.0, false_positives_per_frame=0.0,
                         view_miss_rate=0.5, view_confusion_rate=0.0, box_bias_frac=0.08, distractors=0)
    det = SimulatedDetector(cfg, np.random.default_rng(4))
    centre = np.zeros(3)
    seen = {}
    for k in range(60):
        a = np.radians(6 * k)
        eye = 0.5 * np.array([np.cos(a), np.sin(a), 1.0])
        # The same view twice gives the same decision and the same box (bias, no jitter); scores vary.
        d1, d2 = (det.detect(seg, ids, _view(eye, centre)) for _ in range(2))
        assert [(d.u0, d.v0, d.u1, d.v1, d.label) for d in d1] == [(d.u0, d.v0, d.u1, d.v1, d.label) for d in d2]
        seen[k] = bool(d1)
        if d1:
            assert (d1[0].u0, d1[0].u1) != (20.0, 100.0)  # biased box
    # Misses come in runs of neighbouring views, about half of the directions.
    hits = np.array([seen[k] for k in range(60)])
    assert 0.15 < hits.mean() < 0.85
    assert np.sum(hits[1:] != hits[:-1]) < 20


def test_varied_textures_are_not_axis_aligned() -> None:
    def axis_share(img: np.ndarray) -> float:
        g = img[..., :3].astype(np.float64).mean(axis=2)
        gy, gx = np.gradient(g)
        mag = np.hypot(gx, gy)
        ang = np.degrees(np.arctan2(gy, gx)) % 90
        near_axis = (ang < 5) | (ang > 85)
        return float(mag[near_axis].sum() / mag.sum())

    shapes = np.mean([axis_share(object_texture(101, i, style="shapes")) for i in range(6)])
    varied = np.mean([axis_share(object_texture(101, i, style="varied", poor_fraction=0.0)) for i in range(6)])
    assert shapes > 0.7 and varied < 0.45, (shapes, varied)
    poor = object_texture(101, 0, style="varied", poor_fraction=1.0)[..., :3].astype(float)
    assert np.abs(np.diff(poor, axis=1)).max() <= 3


def test_realistic_render_in_sapien() -> None:
    """One real frame under the realistic preset: depth has silhouette / shadow holes and range
    like the model, colour is noisy, the frame carries the assumed intrinsics."""
    from objslam.camera_path import look_at
    from objslam.scene import load_scene
    from objslam.world import SimWorld

    cfg = load_run_config()
    cam = CameraConfig(width=W, height=H)
    world = SimWorld(load_scene(SCENES[0]), cam, np.random.default_rng(0), textures=cfg.textures)
    world.set_qpos(world.solve_ik(look_at(np.array([0.5, 0.0, 0.6]), np.array([0.5, 0.0, 0.0])), "overview"))
    f = world.render()
    assert np.allclose(f.intrinsics, cam.intrinsics())
    assert not np.allclose(world.sensor.true_intrinsics(), cam.intrinsics())
    stats = world.sensor.last_stats
    assert stats["shadow"] > 0 and stats["mixed"] > 0
    assert 0.8 < np.mean(f.depth_m > 0) < 1.0
    f2 = world.render()
    assert np.mean(f.rgb != f2.rgb) > 0.3  # fresh sensor noise every frame
