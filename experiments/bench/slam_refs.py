"""Reference timings for the `slam` benchmarks (issue 3).

Prints {"entries": {"cv2_orb_640x480": {"median_ms": ...}}} to stdout.

Frames: a bit-exact NumPy port of `objslam_core::slam::synthetic::shapes_texture(640, 480, seed)`
for seeds 0..8 (SplitMix64, integer arithmetic), the same frames `core/benches/slam.rs` times
for `orb_extract_640x480`. Run: /work/main/.venv/bin/python experiments/bench/slam_refs.py
"""

import json
import sys
import time

import cv2
import numpy as np

MASK = (1 << 64) - 1
N_FRAMES = 8
REPEATS = 25
AREA_PER_SHAPE = 600


class SplitMix64:
    def __init__(self, seed: int) -> None:
        self.state = seed & MASK

    def __call__(self) -> int:
        self.state = (self.state + 0x9E3779B97F4A7C15) & MASK
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
        return z ^ (z >> 31)


def shapes_texture(width: int, height: int, seed: int) -> np.ndarray:
    r = SplitMix64(seed)
    img = np.full((height, width), 64 + r() % 128, dtype=np.uint8)
    for _ in range(width * height // AREA_PER_SHAPE):
        kind = r() % 2
        grey = r() % 256
        if kind == 0:
            sw = 4 + r() % 60
            sh = 4 + r() % 60
            x0 = r() % width
            y0 = r() % height
            img[y0 : min(y0 + sh, height), x0 : min(x0 + sw, width)] = grey
        else:
            radius = 2 + r() % 30
            cx = r() % width
            cy = r() % height
            y0, y1 = max(cy - radius, 0), min(cy + radius, height - 1)
            x0, x1 = max(cx - radius, 0), min(cx + radius, width - 1)
            ys, xs = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
            mask = (xs - cx) ** 2 + (ys - cy) ** 2 <= radius * radius
            img[y0 : y1 + 1, x0 : x1 + 1][mask] = grey
    return img


def main() -> None:
    cv2.setNumThreads(1)
    frames = [shapes_texture(640, 480, s) for s in range(N_FRAMES)]
    orb = cv2.ORB_create(1000)
    for f in frames:  # warm-up
        orb.detectAndCompute(f, None)
    times = []
    for _ in range(REPEATS):
        for f in frames:
            t0 = time.perf_counter()
            orb.detectAndCompute(f, None)
            times.append((time.perf_counter() - t0) * 1e3)
    json.dump({"entries": {"cv2_orb_640x480": {"median_ms": float(np.median(times))}}}, sys.stdout)
    print()


if __name__ == "__main__":
    main()
