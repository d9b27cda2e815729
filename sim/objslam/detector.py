"""A simulated 2D object detector: segmentation masks → boxes + labels + scores, with seeded noise.

It stands in for a learned detector (the paper uses YOLO) so that association and
parameterization can be tested against known truth at a controlled noise level. Per frame:

1. Each ground-truth object with at least :attr:`DetectorConfig.min_pixels` visible pixels gives a
   box (tight around its visible mask, hence truncated at the image border like a real detector).
2. Misses: each is dropped with probability :attr:`miss_rate` (redrawn every frame), and, from the
   viewing directions where the object's persistent miss field is high
   (:attr:`view_miss_rate` of all directions), in every frame: a learned detector misses an object
   from the same angles again and again.
3. Box error: a per-object bias of each edge, ``N(0, box_bias_frac · side)`` drawn once per
   episode, plus per-frame jitter ``N(0, box_jitter_frac · side)``; clipped to the image. A learned
   detector's boxes are off by 5-10 % of the side, and consistently so for one object.
4. Label confusion: from :attr:`view_confusion_rate` of the viewing directions (a persistent field)
   an object is labelled as its look-alike class (:data:`LOOKALIKES`, one drawn per object), and
   with probability :attr:`label_confusion_rate` per frame as any other class.
5. Scores: true detections ``U(score_range)``; boxes touching the border lose
   :attr:`truncation_score_penalty`.
6. False positives: ``Poisson(false_positives_per_frame)`` random boxes with a random class, and
   :attr:`distractors` persistent distractor regions on the table top (flat patterns, 4-10 cm,
   each with a class) that fire whenever visible from :attr:`distractor_fire_rate` of the viewing
   directions; scores from :attr:`false_positive_score_range`.

The persistent fields are smooth random functions of the viewing direction (object → camera):
random Fourier features with an angular scale :attr:`view_correlation_deg`, thresholded at the
quantile that gives the stated share of directions. The detector uses the frame's true geometry
(:class:`DetectorView`: camera pose, object centres, the table) only to simulate; it is simulator
side, and none of it reaches the estimator except through the boxes. Every random draw comes from
the generator passed in (an episode's is seeded from the run and scene seeds,
:func:`objslam.calibration.episode_rng`); the persistent draws from one seed taken from
it when any persistent effect is on, so with them all off the draws are those of the per-frame
model alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist

import numpy as np

from .scene import CLASSES

#: Look-alike classes: the labels a detector confuses a class with (similar shape and size).
LOOKALIKES: dict[str, tuple[str, ...]] = {
    "block": ("book", "can"),
    "book": ("keyboard", "block"),
    "keyboard": ("book",),
    "cup": ("can", "bowl"),
    "can": ("cup", "bottle"),
    "bottle": ("can",),
    "bowl": ("cup", "ball"),
    "ball": ("bowl", "cup"),
}

#: Random Fourier features per persistent field.
_FIELD_FEATURES = 32


@dataclass(frozen=True)
class DetectorView:
    """The frame's true geometry, as the simulated detector may use it (simulator side only)."""

    world_from_camera: np.ndarray
    """True camera pose (4x4, OpenCV axes)."""
    intrinsics: np.ndarray
    """True colour intrinsics (3x3) the image was rendered with."""
    object_centres: dict[int, np.ndarray] = field(default_factory=dict)
    """Segmentation actor id → object centre (world, metres)."""
    table_actor_id: int = -1
    """Segmentation id of the table (distractors are visible only where the table is)."""
    table_center: tuple[float, float] = (0.5, 0.0)
    """Table centre (x, y), metres; its top is z = 0."""
    table_size: tuple[float, float] = (0.8, 1.2)
    """Table size (x, y), metres."""


class _ViewField:
    """A smooth random function of the unit viewing direction, ≈ N(0, 1) over directions."""

    def __init__(self, rng: np.random.Generator, correlation_rad: float) -> None:
        self.omega = rng.normal(0.0, 1.0 / correlation_rad, size=(_FIELD_FEATURES, 3))
        self.phase = rng.uniform(0, 2 * math.pi, size=_FIELD_FEATURES)

    def __call__(self, direction: np.ndarray) -> float:
        d = direction / max(float(np.linalg.norm(direction)), 1e-9)
        return float(math.sqrt(2.0 / _FIELD_FEATURES) * np.cos(self.omega @ d + self.phase).sum())


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
    """Noise of the simulated detector. Defaults are the realistic preset's: a learned detector
    whose errors persist per object and viewpoint; ``experiments/configs/presets/ideal.toml`` gives
    the ideal preset's per-frame-only noise."""

    min_pixels: int = 150
    """Objects with fewer visible pixels are not detected (about a 12x12 px patch)."""
    miss_rate: float = 0.03
    """Probability of dropping a detectable object in a frame (ideal preset 0.05, all misses then
    per frame)."""
    box_jitter_frac: float = 0.03
    """Per-frame standard deviation of each box edge, as a fraction of the box side (ideal 0.02)."""
    label_confusion_rate: float = 0.01
    """Probability per frame that a detection's label is replaced by any other class (ideal 0.02)."""
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
    box_bias_frac: float = 0.05
    """Persistent per-object bias of each box edge, standard deviation as a fraction of the side
    (with ``box_jitter_frac`` 0.03 about 6 % of the side per edge; ideal preset 0)."""
    view_miss_rate: float = 0.1
    """Share of viewing directions from which an object is missed in every frame (ideal 0)."""
    view_confusion_rate: float = 0.05
    """Share of viewing directions from which an object gets its look-alike label (ideal 0)."""
    view_correlation_deg: float = 25.0
    """Angular scale of the persistent miss / confusion / distractor fields, degrees."""
    distractors: int = 3
    """Persistent distractor regions on the table top per episode (ideal 0)."""
    distractor_fire_rate: float = 0.3
    """Share of viewing directions from which a visible distractor gives a false positive."""

    def validate(self) -> None:
        """Raise ``ValueError`` naming the field if a value is out of range."""
        for name in (
            "miss_rate", "label_confusion_rate", "box_jitter_frac", "box_bias_frac", "view_miss_rate",
            "view_confusion_rate", "distractor_fire_rate",
        ):
            v = getattr(self, name)
            if not (0.0 <= v <= 1.0):
                raise ValueError(f"detector.{name}: {v} outside [0, 1]")
        if self.false_positives_per_frame < 0:
            raise ValueError("detector.false_positives_per_frame: must be ≥ 0")
        if self.min_pixels < 1:
            raise ValueError("detector.min_pixels: must be ≥ 1")
        if not (1.0 <= self.view_correlation_deg <= 180.0):
            raise ValueError(f"detector.view_correlation_deg: {self.view_correlation_deg} outside [1, 180]")
        if not (0 <= self.distractors <= 50):
            raise ValueError(f"detector.distractors: {self.distractors} outside [0, 50]")

    @property
    def persistent(self) -> bool:
        """Whether any persistent (per object / viewpoint / episode) error is on."""
        return bool(self.box_bias_frac or self.view_miss_rate or self.view_confusion_rate or self.distractors)

    @staticmethod
    def perfect() -> DetectorConfig:
        """A noise-free detector (for ablations and tests)."""
        return DetectorConfig(
            miss_rate=0.0, box_jitter_frac=0.0, label_confusion_rate=0.0, false_positives_per_frame=0.0,
            truncation_score_penalty=0.0, box_bias_frac=0.0, view_miss_rate=0.0, view_confusion_rate=0.0,
            distractors=0,
        )


class SimulatedDetector:
    """Turns a segmentation image into detections."""

    def __init__(self, config: DetectorConfig, rng: np.random.Generator) -> None:
        config.validate()
        self.config = config
        self.rng = rng
        self._seed = int(rng.integers(1 << 62)) if config.persistent else 0
        self._objects: dict[int, tuple[np.ndarray, _ViewField, _ViewField, str]] = {}
        self._distractors: list[tuple[np.ndarray, float, float, str, _ViewField]] | None = None
        nd = NormalDist()
        self._miss_z = nd.inv_cdf(1.0 - config.view_miss_rate) if 0 < config.view_miss_rate < 1 else math.inf
        self._confuse_z = nd.inv_cdf(1.0 - config.view_confusion_rate) if 0 < config.view_confusion_rate < 1 else math.inf
        self._fire_z = nd.inv_cdf(config.distractor_fire_rate) if 0 < config.distractor_fire_rate < 1 else (
            math.inf if config.distractor_fire_rate >= 1 else -math.inf
        )

    def _object(self, gt_id: int, cls: str) -> tuple[np.ndarray, _ViewField, _ViewField, str]:
        """An object's persistent state: edge biases (fractions of the side), miss and confusion
        fields, look-alike class."""
        if gt_id not in self._objects:
            rng = np.random.default_rng([self._seed, 1, gt_id])
            corr = math.radians(self.config.view_correlation_deg)
            bias = rng.normal(0.0, self.config.box_bias_frac, size=4) if self.config.box_bias_frac > 0 else np.zeros(4)
            miss, confuse = _ViewField(rng, corr), _ViewField(rng, corr)
            alike = LOOKALIKES.get(cls, tuple(k for k in CLASSES if k != cls))
            self._objects[gt_id] = (bias, miss, confuse, alike[int(rng.integers(len(alike)))])
        return self._objects[gt_id]

    def _distractor_boxes(self, view: DetectorView, segmentation: np.ndarray) -> list[Detection]:
        """False positives of the persistent distractor regions visible in this frame."""
        c = self.config
        if self._distractors is None:
            rng = np.random.default_rng([self._seed, 2])
            corr = math.radians(c.view_correlation_deg)
            (cx, cy), (sx, sy) = view.table_center, view.table_size
            self._distractors = []
            for _ in range(c.distractors):
                centre = np.array([cx + rng.uniform(-0.4, 0.4) * sx, cy + rng.uniform(-0.4, 0.4) * sy, 0.0])
                half = (float(rng.uniform(0.02, 0.05)), float(rng.uniform(0.02, 0.05)))
                cls = CLASSES[int(rng.integers(len(CLASSES)))]
                self._distractors.append((centre, half[0], half[1], cls, _ViewField(rng, corr)))
        h, w = segmentation.shape
        camera_from_world = np.linalg.inv(view.world_from_camera)
        eye = view.world_from_camera[:3, 3]
        out = []
        for centre, hx, hy, cls, fire in self._distractors:
            if fire(eye - centre) >= self._fire_z:
                continue
            corners = centre + np.array([[sx * hx, sy * hy, 0.001] for sx in (-1, 1) for sy in (-1, 1)])
            p = (camera_from_world[:3, :3] @ corners.T).T + camera_from_world[:3, 3]
            if np.any(p[:, 2] <= 0.05):
                continue
            uv = (view.intrinsics @ (p / p[:, 2:3]).T).T[:, :2]
            u0, v0 = np.clip(uv.min(axis=0), 0, [w, h])
            u1, v1 = np.clip(uv.max(axis=0), 0, [w, h])
            if u1 - u0 < 8 or v1 - v0 < 8:
                continue
            cu, cv = int((u0 + u1) / 2), int((v0 + v1) / 2)
            if not (0 <= cu < w and 0 <= cv < h) or int(segmentation[cv, cu]) != view.table_actor_id:
                continue
            score = float(self.rng.uniform(*c.false_positive_score_range))
            out.append(Detection(float(u0), float(v0), float(u1), float(v1), cls, score, None, False))
        return out

    def detect(
        self, segmentation: np.ndarray, id_to_object: dict[int, tuple[int, str]], view: DetectorView | None = None
    ) -> list[Detection]:
        """``segmentation``: (H, W) actor ids; ``id_to_object``: actor id → (gt id, class);
        ``view``: the frame's true geometry, needed by the viewpoint-persistent misses, confusions
        and distractors (without it those are off; the per-object box bias still applies)."""
        if segmentation.ndim != 2:
            raise ValueError(f"segmentation: expected shape (H, W), got {segmentation.shape}")
        c = self.config
        h, w = segmentation.shape
        out: list[Detection] = []
        eye = None if view is None else view.world_from_camera[:3, 3]
        for actor_id in sorted(id_to_object):
            gt_id, cls = id_to_object[actor_id]
            mask = segmentation == actor_id
            n = int(mask.sum())
            if n < c.min_pixels:
                continue
            if self.rng.random() < c.miss_rate:
                continue
            persistent = self._object(gt_id, cls) if c.persistent else None
            direction = None
            if persistent is not None and eye is not None and actor_id in view.object_centres:
                direction = eye - view.object_centres[actor_id]
                if persistent[1](direction) > self._miss_z:
                    continue
            rows = np.flatnonzero(mask.any(axis=1))
            cols = np.flatnonzero(mask.any(axis=0))
            u0, u1 = float(cols[0]), float(cols[-1] + 1)
            v0, v1 = float(rows[0]), float(rows[-1] + 1)
            if persistent is not None and c.box_bias_frac > 0:
                bw, bh = u1 - u0, v1 - v0
                b = persistent[0] * np.array([bw, bh, bw, bh])
                u0, v0, u1, v1 = u0 + b[0], v0 + b[1], u1 + b[2], v1 + b[3]
            if c.box_jitter_frac > 0:
                bw, bh = u1 - u0, v1 - v0
                j = self.rng.normal(0.0, c.box_jitter_frac, size=4) * np.array([bw, bh, bw, bh])
                u0, v0, u1, v1 = u0 + j[0], v0 + j[1], u1 + j[2], v1 + j[3]
            u0, u1 = sorted((float(np.clip(u0, 0, w)), float(np.clip(u1, 0, w))))
            v0, v1 = sorted((float(np.clip(v0, 0, h)), float(np.clip(v1, 0, h))))
            if u1 - u0 < 2 or v1 - v0 < 2:
                continue
            label = cls
            if direction is not None and persistent is not None and persistent[2](direction) > self._confuse_z:
                label = persistent[3]
            elif self.rng.random() < c.label_confusion_rate:
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
        if view is not None and c.distractors > 0:
            out.extend(self._distractor_boxes(view, segmentation))
        return out
