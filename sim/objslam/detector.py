"""A simulated 2D object detector: segmentation masks → boxes + labels + scores, with seeded noise.

It stands in for a learned detector (the paper uses YOLO) so that association and
parameterization can be tested against known truth at a controlled noise level. Per frame:

1. Each ground-truth object with at least :attr:`DetectorConfig.min_pixels` visible pixels gives a
   box (tight around its visible mask, hence truncated at the image border like a real detector).
2. Misses: each is dropped with probability :attr:`miss_rate`.
3. Box jitter: each edge moves by ``N(0, box_jitter_frac · side)``; the box is clipped to the image.
4. Label confusion: with probability :attr:`label_confusion_rate` the label becomes another class.
5. Scores: true detections ``U(score_range)``; boxes touching the border lose
   :attr:`truncation_score_penalty`.
6. False positives: ``Poisson(false_positives_per_frame)`` random boxes with a random class and a
   score from :attr:`false_positive_score_range`.

Every random draw comes from the generator passed in (seeded from the run seed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import CLASSES


@dataclass(frozen=True)
class Detection:
    """One detection. ``gt_id`` is evaluation-only ground truth (None for false positives); it never
    enters the core."""

    u0: float
    v0: float
    u1: float
    v1: float
    label: str
    score: float
    gt_id: int | None
    truncated: bool

    def as_tuple(self) -> tuple[float, float, float, float, str, float]:
        """The ``(u0, v0, u1, v1, label, score)`` tuple the core takes."""
        return (self.u0, self.v0, self.u1, self.v1, self.label, self.score)


@dataclass(frozen=True)
class DetectorConfig:
    """Noise of the simulated detector. Defaults model a good but imperfect detector."""

    min_pixels: int = 150
    """Objects with fewer visible pixels are not detected (about a 12x12 px patch)."""
    miss_rate: float = 0.05
    """Probability of dropping a detectable object in a frame."""
    box_jitter_frac: float = 0.02
    """Standard deviation of each box edge, as a fraction of the box side."""
    label_confusion_rate: float = 0.02
    """Probability that a detection's label is replaced by another class."""
    false_positives_per_frame: float = 0.05
    """Mean number of false-positive boxes per frame (Poisson)."""
    score_range: tuple[float, float] = (0.6, 0.99)
    """Scores of true detections are uniform in this range."""
    false_positive_score_range: tuple[float, float] = (0.3, 0.6)
    """Scores of false positives are uniform in this range."""
    truncation_score_penalty: float = 0.1
    """Score reduction for boxes touching the image border (truncated objects)."""
    border_px: int = 2
    """A box within this many pixels of the border counts as truncated."""

    def validate(self) -> None:
        """Raise ``ValueError`` naming the field if a value is out of range."""
        for name in ("miss_rate", "label_confusion_rate", "box_jitter_frac"):
            v = getattr(self, name)
            if not (0.0 <= v <= 1.0):
                raise ValueError(f"detector.{name}: {v} outside [0, 1]")
        if self.false_positives_per_frame < 0:
            raise ValueError("detector.false_positives_per_frame: must be ≥ 0")
        if self.min_pixels < 1:
            raise ValueError("detector.min_pixels: must be ≥ 1")

    @staticmethod
    def perfect() -> DetectorConfig:
        """A noise-free detector (for ablations and tests)."""
        return DetectorConfig(
            miss_rate=0.0, box_jitter_frac=0.0, label_confusion_rate=0.0, false_positives_per_frame=0.0,
            truncation_score_penalty=0.0,
        )


class SimulatedDetector:
    """Turns a segmentation image into detections."""

    def __init__(self, config: DetectorConfig, rng: np.random.Generator) -> None:
        config.validate()
        self.config = config
        self.rng = rng

    def detect(self, segmentation: np.ndarray, id_to_object: dict[int, tuple[int, str]]) -> list[Detection]:
        """``segmentation``: (H, W) actor ids; ``id_to_object``: actor id → (gt id, class)."""
        if segmentation.ndim != 2:
            raise ValueError(f"segmentation: expected shape (H, W), got {segmentation.shape}")
        c = self.config
        h, w = segmentation.shape
        out: list[Detection] = []
        for actor_id in sorted(id_to_object):
            gt_id, cls = id_to_object[actor_id]
            mask = segmentation == actor_id
            n = int(mask.sum())
            if n < c.min_pixels:
                continue
            if self.rng.random() < c.miss_rate:
                continue
            rows = np.flatnonzero(mask.any(axis=1))
            cols = np.flatnonzero(mask.any(axis=0))
            u0, u1 = float(cols[0]), float(cols[-1] + 1)
            v0, v1 = float(rows[0]), float(rows[-1] + 1)
            if c.box_jitter_frac > 0:
                bw, bh = u1 - u0, v1 - v0
                j = self.rng.normal(0.0, c.box_jitter_frac, size=4) * np.array([bw, bh, bw, bh])
                u0, v0, u1, v1 = u0 + j[0], v0 + j[1], u1 + j[2], v1 + j[3]
            u0, u1 = sorted((float(np.clip(u0, 0, w)), float(np.clip(u1, 0, w))))
            v0, v1 = sorted((float(np.clip(v0, 0, h)), float(np.clip(v1, 0, h))))
            if u1 - u0 < 2 or v1 - v0 < 2:
                continue
            label = cls
            if self.rng.random() < c.label_confusion_rate:
                others = [k for k in CLASSES if k != cls]
                label = others[int(self.rng.integers(len(others)))]
            truncated = u0 <= c.border_px or v0 <= c.border_px or u1 >= w - c.border_px or v1 >= h - c.border_px
            score = float(self.rng.uniform(*c.score_range))
            if truncated:
                score = max(0.0, score - c.truncation_score_penalty)
            out.append(Detection(u0, v0, u1, v1, label, score, gt_id, truncated))
        for _ in range(int(self.rng.poisson(c.false_positives_per_frame))):
            bw, bh = float(self.rng.uniform(20, w / 4)), float(self.rng.uniform(20, h / 4))
            u0, v0 = float(self.rng.uniform(0, w - bw)), float(self.rng.uniform(0, h - bh))
            label = CLASSES[int(self.rng.integers(len(CLASSES)))]
            score = float(self.rng.uniform(*c.false_positive_score_range))
            out.append(Detection(u0, v0, u0 + bw, v0 + bh, label, score, None, False))
        return out
