"""Simulated detector: exact boxes without noise, stated noise rates with it, seeded."""

from __future__ import annotations

import math

import numpy as np
import pytest
from objslam.detector import DetectorConfig, SimulatedDetector


def _seg() -> tuple[np.ndarray, dict[int, tuple[int, str]]]:
    seg = np.zeros((120, 160), dtype=np.uint32)
    seg[10:40, 20:60] = 5  # 30 x 40 block
    seg[50:120, 100:160] = 7  # touches the bottom-right border
    seg[0:3, 0:3] = 9  # too small
    return seg, {5: (0, "block"), 7: (1, "cup"), 9: (2, "can")}


def test_perfect_detector_boxes_are_exact() -> None:
    seg, ids = _seg()
    dets = SimulatedDetector(DetectorConfig.perfect(), np.random.default_rng(0)).detect(seg, ids)
    assert [(d.gt_id, d.label) for d in dets] == [(0, "block"), (1, "cup")]
    b = dets[0]
    assert (b.u0, b.v0, b.u1, b.v1) == (20, 10, 60, 40) and not b.truncated
    assert dets[1].truncated


def test_noise_rates_match_config() -> None:
    seg, ids = _seg()
    cfg = DetectorConfig(miss_rate=0.2, label_confusion_rate=0.1, false_positives_per_frame=0.5, box_jitter_frac=0.05)
    det = SimulatedDetector(cfg, np.random.default_rng(1))
    n = 4000
    true_dets, confused, fps, widths = 0, 0, 0, []
    for _ in range(n):
        for d in det.detect(seg, ids):
            if d.gt_id is None:
                fps += 1
                continue
            true_dets += 1
            confused += d.label != ids[{0: 5, 1: 7}[d.gt_id]][1]
            if d.gt_id == 0:
                widths.append(d.u1 - d.u0)
    # Binomial / Poisson 4-sigma envelopes.
    assert abs(true_dets / (2 * n) - 0.8) < 4 * np.sqrt(0.16 / (2 * n))
    assert abs(confused / true_dets - 0.1) < 4 * np.sqrt(0.09 / true_dets)
    assert abs(fps / n - 0.5) < 4 * np.sqrt(0.5 / n)
    # Width = 40 + two independent edges each N(0, 0.05 * 40): std 40 * 0.05 * sqrt(2).
    assert abs(np.std(widths) - 40 * 0.05 * np.sqrt(2)) < 0.3


def test_seeded_and_validated() -> None:
    seg, ids = _seg()
    a = SimulatedDetector(DetectorConfig(), np.random.default_rng(3)).detect(seg, ids)
    b = SimulatedDetector(DetectorConfig(), np.random.default_rng(3)).detect(seg, ids)
    assert a == b
    with pytest.raises(ValueError, match="detector.miss_rate"):
        SimulatedDetector(DetectorConfig(miss_rate=1.5), np.random.default_rng(0))
    with pytest.raises(ValueError, match="segmentation"):
        SimulatedDetector(DetectorConfig(), np.random.default_rng(0)).detect(seg[None], ids)


def test_scenes_of_one_run_draw_independent_persistent_fields() -> None:
    """Each object's persistent confusion field is keyed by its index in the scene; the detector's
    stream mixes the scene seed in, so over many scenes of one run object 0 is mislabelled from a
    given direction in about ``view_confusion_rate`` of them (with the run seed alone: all or
    none), and one (run, scene) pair always draws the same field."""
    from objslam.calibration import STREAM_DETECTOR, episode_rng

    cfg = DetectorConfig()
    direction = np.array([-0.4, 0.1, 0.6])

    def confused(run_seed: int, scene_seed: int) -> bool:
        det = SimulatedDetector(cfg, episode_rng(run_seed, scene_seed, STREAM_DETECTOR))
        return det._object(0, "can")[2](direction) > det._confuse_z

    n = 400
    share = np.mean([confused(0, s) for s in range(n)])
    sd = math.sqrt(cfg.view_confusion_rate * (1 - cfg.view_confusion_rate) / n)
    assert abs(share - cfg.view_confusion_rate) < 4 * sd, share
    assert all(confused(3, s) == confused(3, s) for s in range(20))
