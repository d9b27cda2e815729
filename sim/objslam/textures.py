"""Procedural textures generated from seeds (nothing is downloaded).

Feature tracking needs texture: smooth noise gives too few ORB corners, so textures are
high-contrast random shapes (rectangles and discs of 3-30 px) over a random base colour, as measured
in ECOSYSTEM.md (250-980 cv2 ORB keypoints per 640x480 frame).
"""

from __future__ import annotations

import numpy as np


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


def object_texture(scene_seed: int, object_id: int, size: int = 256) -> np.ndarray:
    """The texture of object ``object_id`` in a scene seeded by ``scene_seed``."""
    rng = np.random.default_rng([scene_seed, 1000 + object_id])
    return shapes_texture(rng, size=size, n_shapes=size * size // 650, min_px=2, max_px=max(4, size // 16))


def table_texture(scene_seed: int, size: int = 1024) -> np.ndarray:
    """The table-top texture of a scene (muted base so objects stand out)."""
    rng = np.random.default_rng([scene_seed, 7])
    return shapes_texture(rng, size=size, n_shapes=1600, base=(150, 130, 105), min_px=3, max_px=30)
