"""The true camera pose cannot reach the estimate: with the ``slam`` and ``kinematics`` pose sources
the mapper's poses are the same whatever true pose is passed for evaluation; only the
``ground_truth`` ablation uses it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from objslam import _native
from objslam.config import load_run_config
from objslam.episode import active_config


def _frames(n: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """A textured plane 0.5 m in front of a camera sliding 5 mm per frame (grey, depth, prior)."""
    rng = np.random.default_rng(4)
    h, w = 120, 160
    tex = (rng.random((h // 4, (w + 4 * n) // 4)) * 255).astype(np.uint8).repeat(4, 0).repeat(4, 1)
    out = []
    for i in range(n):
        grey = np.ascontiguousarray(tex[:, 4 * i : 4 * i + w])
        depth = np.full((h, w), 0.5, dtype=np.float32)
        prior = np.eye(4)
        prior[0, 3] = 0.005 * i
        out.append((grey, depth, prior))
    return out


def _run(pose_source: str, gt_shift: np.ndarray) -> list[np.ndarray]:
    cfg = load_run_config(overrides=[f"pose_source={pose_source!r}".replace("'", '"')])
    mapper = _native.ActiveMapper(
        mapper_config_json=json.dumps({"parameterize": False}),
        active_config_json=json.dumps(active_config(cfg)),
        table=(0.5, 0.0, 1.0, 1.0),
        tracker_config_json=json.dumps({"pose_source": pose_source, "min_init_points": 20, "min_tracked_inliers": 10}),
    )
    k = np.array([[150.0, 0.0, 80.0], [0.0, 150.0, 60.0], [0.0, 0.0, 1.0]])
    assert mapper.last_pose() is None
    poses = []
    for i, (grey, depth, prior) in enumerate(_frames(4)):
        gt = prior @ np.vstack([np.c_[np.eye(3), gt_shift], [0, 0, 0, 1]])
        mapper.update(
            index=i, intrinsics=k, depth=depth, world_from_camera=prior, detections=[], grey=grey,
            world_from_camera_gt=gt, view_index=0,
        )
        poses.append(np.asarray(mapper.query('{"query": "last_pose"}')["world_from_camera"]))
        # The episode's per-frame accessor gives the query's pose bit for bit.
        np.testing.assert_array_equal(mapper.last_pose(), poses[-1])
    return poses


@pytest.mark.parametrize("pose_source", ["slam", "kinematics"])
def test_the_true_pose_does_not_change_the_estimate(pose_source: str) -> None:
    # (The mapper records the used pose beside the true one for ATE; two different true poses.)
    exact = _run(pose_source, np.zeros(3))
    far = _run(pose_source, np.array([0.3, -0.2, 0.1]))
    for a, b in zip(exact, far):
        np.testing.assert_array_equal(a, b)


def test_only_the_ground_truth_ablation_uses_it() -> None:
    shift = np.array([0.03, 0.0, 0.0])
    poses = _run("ground_truth", shift)
    for i, (_, _, prior) in enumerate(_frames(4)):
        np.testing.assert_allclose(poses[i][:3, 3], prior[:3, 3] + shift, atol=1e-9)
