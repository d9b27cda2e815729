"""Procedural textures generated from the scene's seed (nothing is downloaded).

Two styles (:attr:`TextureConfig.style`):

- ``"varied"`` (the realistic preset): each object draws its content: shapes (rectangles, ellipses,
  bars) at random orientations, printed-label bands at a random angle, smooth colour blotches, or a
  texture-poor surface (a near-uniform colour with faint low-frequency shading,
  :attr:`TextureConfig.poor_fraction` of the objects). No cue is aligned with an object's edges by
  construction; the table carries rotated shapes over a muted base (tracking needs its texture).
- ``"shapes"`` (the ideal preset): high-contrast axis-aligned rectangles and discs of 3-30 px over a
  random base colour, as measured in ECOSYSTEM.md (250-980 cv2 ORB keypoints per 640x480 frame);
  their sides run parallel to the box edges, which the line-alignment yaw then finds for free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Texture styles of :attr:`TextureConfig.style`.
TEXTURE_STYLES = ("varied", "shapes")


@dataclass(frozen=True)
class TextureConfig:
    """Surface textures of the simulated scene (run configuration ``[textures]``)."""

    style: str = "varied"
    """``"varied"`` (random orientations and contents, some texture-poor objects; the realistic
    preset) or ``"shapes"`` (axis-aligned rectangles and discs; the ideal preset)."""
    poor_fraction: float = 0.2
    """With ``"varied"``: share of objects with a texture-poor surface."""

    def validate(self) -> None:
        """Raise ``ValueError`` naming the key if a value is out of range."""
        if self.style not in TEXTURE_STYLES:
            raise ValueError(f"textures.style: unknown {self.style!r}; known: {', '.join(TEXTURE_STYLES)}")
        if not (0.0 <= self.poor_fraction <= 1.0):
            raise ValueError(f"textures.poor_fraction: {self.poor_fraction} outside [0, 1]")


def shapes_texture(
    rng: np.random.Generator,
    size: int = 512,
    n_shapes: int = 400,
    base: tuple[int, int, int] | None = None,
    min_px: int = 3,
    max_px: int = 30,
) -> np.ndarray:
    """An RGBA uint8 texture (size, size, 4) of random rectangles and discs on a base colour."""
    if size < 8 or n_shapes < 0 or not (0 < min_px <= max_px):
        raise ValueError("shapes_texture: size ≥ 8, n_shapes ≥ 0, 0 < min_px ≤ max_px required")
    if base is None:
        base = tuple(int(v) for v in rng.integers(40, 216, size=3))  # type: ignore[assignment]
    img = np.empty((size, size, 4), dtype=np.uint8)
    img[..., :3] = np.array(base, dtype=np.uint8)
    img[..., 3] = 255
    yy, xx = np.mgrid[0:size, 0:size]
    for _ in range(n_shapes):
        color = rng.integers(0, 256, size=3).astype(np.uint8)
        # Push colours towards the extremes for contrast.
        color = np.where(color > 127, np.minimum(255, color + 60), np.maximum(0, color.astype(int) - 60)).astype(np.uint8)
        s = int(rng.integers(min_px, max_px + 1))
        x0, y0 = int(rng.integers(0, size - s)), int(rng.integers(0, size - s))
        if rng.random() < 0.5:
            w = int(rng.integers(min_px, max_px + 1))
            img[y0 : y0 + s, x0 : min(size, x0 + w), :3] = color
        else:
            r = s / 2
            cy, cx = y0 + r, x0 + r
            y1, x1 = y0 + s, x0 + s
            sub = (yy[y0:y1, x0:x1] - cy) ** 2 + (xx[y0:y1, x0:x1] - cx) ** 2 <= r * r
            img[y0:y1, x0:x1, :3][sub] = color
    return img


def _contrast(rng: np.random.Generator) -> np.ndarray:
    c = rng.integers(0, 256, size=3)
    return np.where(c > 127, np.minimum(255, c + 60), np.maximum(0, c - 60)).astype(np.uint8)


def _smooth(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """A (size, size) smooth field in [0, 1]: random values on a cells × cells grid, bilinear."""
    g = rng.random((cells + 1, cells + 1))
    t = np.linspace(0, cells, size, endpoint=False)
    i = np.minimum(t.astype(int), cells - 1)
    a = t - i
    rows = g[i] * (1 - a)[:, None] + g[i + 1] * a[:, None]
    return rows[:, i] * (1 - a)[None, :] + rows[:, i + 1] * a[None, :]


def rotated_shapes(
    img: np.ndarray, rng: np.random.Generator, n_shapes: int, min_px: int, max_px: int, colours: list | None = None
) -> None:
    """Paint ``n_shapes`` rectangles, ellipses and thin bars of random size (``min_px``-``max_px``)
    at random orientations into ``img`` (H, W, ≥3) in place."""
    h, w = img.shape[:2]
    for _ in range(n_shapes):
        colour = _contrast(rng) if colours is None else colours[int(rng.integers(len(colours)))]
        kind = int(rng.integers(3))
        a = rng.uniform(min_px, max_px) / 2
        b = rng.uniform(min_px, max_px) / 2 if kind != 2 else rng.uniform(0.6, 1.5)
        th = rng.uniform(0, math.pi)
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        r = math.ceil(max(a, b)) + 1
        x0, x1, y0, y1 = max(0, int(cx) - r), min(w, int(cx) + r + 1), max(0, int(cy) - r), min(h, int(cy) + r + 1)
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        dx, dy = xx + 0.5 - cx, yy + 0.5 - cy
        u = math.cos(th) * dx + math.sin(th) * dy
        v = -math.sin(th) * dx + math.cos(th) * dy
        mask = (u / a) ** 2 + (v / b) ** 2 <= 1.0 if kind == 1 else (np.abs(u) <= a) & (np.abs(v) <= b)
        img[y0:y1, x0:x1, :3][mask] = colour


def varied_texture(rng: np.random.Generator, size: int, *, poor: bool) -> np.ndarray:
    """An RGBA uint8 object texture of the ``"varied"`` style (module docs)."""
    base = rng.integers(40, 216, size=3).astype(float)
    img = np.empty((size, size, 4), dtype=np.uint8)
    img[..., 3] = 255
    shade = _smooth(rng, size, 3)[..., None]
    if poor:
        # A plain surface: faint low-frequency shading, nothing a detector of lines or corners finds.
        img[..., :3] = np.clip(base * (0.93 + 0.14 * shade), 0, 255).astype(np.uint8)
        return img
    kind = int(rng.integers(3))
    if kind == 0:  # shapes at random orientations
        img[..., :3] = np.clip(base * (0.85 + 0.3 * shade), 0, 255).astype(np.uint8)
        rotated_shapes(img, rng, size * size // 700, 2, max(4, size // 14))
    elif kind == 1:  # printed bands at a random angle, with small marks
        th = rng.uniform(0, math.pi)
        period = rng.uniform(size / 12, size / 4)
        yy, xx = np.mgrid[0:size, 0:size]
        phase = (math.cos(th) * xx + math.sin(th) * yy) / period
        band = (np.floor(phase) % 2).astype(bool)
        other = _contrast(rng).astype(float)
        img[..., :3] = np.where(band[..., None], other, base).astype(np.uint8)
        rotated_shapes(img, rng, size * size // 1500, 2, max(4, size // 20))
    else:  # smooth blotches of two colours, with small marks
        other = _contrast(rng).astype(float)
        t = _smooth(rng, size, 8)[..., None]
        img[..., :3] = np.clip(base * (1 - t) + other * t, 0, 255).astype(np.uint8)
        rotated_shapes(img, rng, size * size // 1500, 2, max(4, size // 20))
    return img


def object_texture(scene_seed: int, object_id: int, size: int = 256, *, style: str = "varied", poor_fraction: float = 0.2) -> np.ndarray:
    """The texture of object ``object_id`` in a scene seeded by ``scene_seed``."""
    if style == "shapes":
        rng = np.random.default_rng([scene_seed, 1000 + object_id])
        return shapes_texture(rng, size=size, n_shapes=size * size // 650, min_px=2, max_px=max(4, size // 16))
    rng = np.random.default_rng([scene_seed, 1000 + object_id, 1])
    return varied_texture(rng, size, poor=bool(rng.random() < poor_fraction))


def table_texture(scene_seed: int, size: int = 1024, *, style: str = "varied") -> np.ndarray:
    """The table-top texture of a scene (muted base so objects stand out)."""
    if style == "shapes":
        rng = np.random.default_rng([scene_seed, 7])
        return shapes_texture(rng, size=size, n_shapes=1600, base=(150, 130, 105), min_px=3, max_px=30)
    rng = np.random.default_rng([scene_seed, 7, 1])
    img = np.empty((size, size, 4), dtype=np.uint8)
    img[..., 3] = 255
    shade = _smooth(rng, size, 6)[..., None]
    img[..., :3] = np.clip(np.array([150.0, 130.0, 105.0]) * (0.85 + 0.3 * shade), 0, 255).astype(np.uint8)
    rotated_shapes(img, rng, 1600, 3, 30)
    return img
