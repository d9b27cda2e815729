"""The simulated cell's calibration errors (objslam.calibration): seeded draws of the stated size, the
prior they give against the true camera in SAPIEN, and config errors that name the key."""

from __future__ import annotations

import math

import numpy as np
import pytest
from objslam.calibration import (
    ArmErrors,
    ContactConfig,
    RobotConfig,
    TableConfig,
    draw_arm_errors,
    draw_table_plane,
    pose_error,
)
from objslam.config import ConfigError, load_run_config
from objslam.scene import load_scene

from .conftest import SCENES


def test_arm_errors_are_seeded_and_of_the_stated_size() -> None:
    cfg = RobotConfig()
    a, b, c = draw_arm_errors(cfg, 5), draw_arm_errors(cfg, 5), draw_arm_errors(cfg, 6)
    assert np.array_equal(a.camera_from_true_camera, b.camera_from_true_camera)
    assert np.array_equal(a.joint_offsets_rad, b.joint_offsets_rad) and a.time_offset_s == b.time_offset_s
    assert not np.array_equal(a.joint_offsets_rad, c.joint_offsets_rad)
    t, r = pose_error(a.camera_from_true_camera, np.eye(4))
    assert t == pytest.approx(cfg.hand_eye_trans_m, abs=1e-12)
    assert r == pytest.approx(cfg.hand_eye_rot_deg, abs=1e-6)
    # Joint offsets: Gaussian with the stated sigma (7 x 400 draws, within 6 %).
    offsets = np.concatenate([draw_arm_errors(cfg, s).joint_offsets_rad for s in range(400)])
    assert np.degrees(offsets.std()) == pytest.approx(cfg.joint_offset_deg, rel=0.06)
    times = [draw_arm_errors(cfg, s).time_offset_s for s in range(400)]
    assert 0.0 <= min(times) and max(times) <= cfg.time_offset_max_s
    # Under realistic the per-view bias and jitter are identity: the prior is the nominal FK.
    pose = np.eye(4)
    pose[:3, 3] = [0.4, 0.1, 0.5]
    assert np.array_equal(a.prior(pose, 3, 17), pose)


def test_the_ideal_model_draws_an_independent_bias_per_view() -> None:
    ideal = RobotConfig(0.0, 0.0, 0.0, 0.0, 0.01, 1.0, 0.0005, 0.05)
    e = draw_arm_errors(ideal, 3)
    assert not np.any(e.joint_offsets_rad) and e.time_offset_s == 0.0
    for v in range(5):
        t, r = pose_error(e.view_bias(v), np.eye(4))
        assert t == pytest.approx(0.01, abs=1e-12) and r == pytest.approx(1.0, abs=1e-6)
    assert not np.allclose(e.view_bias(1), e.view_bias(2))
    assert np.array_equal(e.view_bias(2), draw_arm_errors(ideal, 3).view_bias(2))  # order-independent
    jit = np.array([e.frame_jitter(f)[:3, 3] for f in range(3000)])
    assert jit.std() == pytest.approx(0.0005, rel=0.05)
    assert ArmErrors.none().is_exact and not e.is_exact


def test_table_plane_error_has_the_stated_tilt_and_height_statistics() -> None:
    cfg = TableConfig()
    centre = (0.5, 0.1)
    planes = [draw_table_plane(cfg, s, centre) for s in range(500)]
    for a, b, _ in planes[:20]:
        assert math.degrees(math.atan(math.hypot(a, b))) == pytest.approx(cfg.tilt_error_deg, abs=1e-9)
    heights = np.array([a * centre[0] + b * centre[1] + c for a, b, c in planes])
    assert heights.std() == pytest.approx(cfg.height_error_m, rel=0.1)
    assert abs(heights.mean()) < 3 * cfg.height_error_m / math.sqrt(len(heights))
    assert draw_table_plane(TableConfig(0.0, 0.0), 1, centre) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("robot.hand_eye_trans_m=-0.001", "robot.hand_eye_trans_m"),
        ("robot.time_offset_max_s=1.0", "robot.time_offset_max_s"),
        ("table.tilt_error_deg=10.0", "table.tilt_error_deg"),
        ("contact.objects='rubber'", "contact.objects"),
        ("contact.finger_friction=0.0", "contact.finger_friction"),
    ],
)
def test_out_of_range_values_are_config_errors_naming_the_key(override: str, key: str) -> None:
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_run_config(overrides=[override])


def test_household_contact_differs_from_the_uniform_ideal() -> None:
    household, uniform = ContactConfig(), ContactConfig(objects="uniform", finger_friction=2.0)
    assert uniform.object_physics("can") == (300.0, 1.0)
    density, mu = household.object_physics("can")
    assert density == 900.0 and 0.2 <= (mu + household.finger_friction) / 2 <= 0.8


def test_the_true_camera_differs_from_the_prior_by_the_drawn_errors(ci_overlay) -> None:
    # A robot with only a hand-eye error: at rest the prior (nominal FK of the readings) differs from
    # the rendered camera by exactly that error. With joint offsets the readings are the true joints
    # plus the offsets, and the arm still goes where it is commanded in readings.
    from objslam.camera_path import look_at
    from objslam.world import SimWorld

    scene = load_scene(SCENES[0])
    cam = load_run_config(overlays=[ci_overlay]).camera
    hand_eye = draw_arm_errors(RobotConfig(0.003, 0.3, 0.0, 0.0), 11)
    w = SimWorld(scene, cam, np.random.default_rng(0), arm_errors=hand_eye)
    f = w.render()
    err = np.linalg.inv(f.world_from_camera_fk) @ f.world_from_camera_gt
    np.testing.assert_allclose(err, hand_eye.camera_from_true_camera, atol=2e-5)
    joints = draw_arm_errors(RobotConfig(0.0, 0.0, 0.2, 0.0), 12)
    w = SimWorld(scene, cam, np.random.default_rng(0), arm_errors=joints)
    target = look_at(np.array([0.45, 0.05, 0.45]), np.array([0.5, 0.0, 0.0]))
    frames = list(w.move_camera_to(target, frame_rate_hz=4.0))
    np.testing.assert_allclose(w.qpos()[:7] - w._true_qpos()[:7], joints.joint_offsets_rad, atol=1e-9)
    t_prior, _ = pose_error(frames[-1].world_from_camera_fk, target)
    t_true, _ = pose_error(frames[-1].world_from_camera_gt, target)
    assert t_prior < 0.002  # the nominal model says the camera reached the goal ...
    assert t_true > 0.001  # ... where the true camera is not: 0.2° offsets move it millimetres
