"""Reference timings for the `objects` benchmarks (core/benches/objects.rs), same inputs.

Prints {"entries": {"sklearn_iforest_500": {"median_ms": ..}, "cv2_lsd_640x480": {"median_ms": ..}}}.
- sklearn_iforest_500: IsolationForest(n_estimators=100, max_samples=256) fit + score_samples on the
  500 points of `bench_points()` (splitmix64 stream, identical to `bench_points` in the Rust bench).
- cv2_lsd_640x480: cv2.createLineSegmentDetector().detect on core/tests/fixtures/lsd/frame0.pgm
  (the `lsd_640x480` input).
Run: /work/main/.venv/bin/python experiments/bench/objects_refs.py
"""

import json
import pathlib
import statistics
import time

import cv2
import numpy as np
from sklearn.ensemble import IsolationForest

ROOT = pathlib.Path(__file__).resolve().parents[2]
MASK64 = (1 << 64) - 1


def splitmix64(state):
    state = (state + 0x9E3779B97F4A7C15) & MASK64
    z = state
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK64
    return state, z ^ (z >> 31)


def bench_points(seed=2024):
    """400 points uniform in a 10 x 6 x 8 cm box + 100 uniform outliers in a 40 cm cube around it."""
    state = seed
    out = []

    def uniform(lo, hi):
        nonlocal state
        state, z = splitmix64(state)
        return lo + (hi - lo) * ((z >> 11) * (1.0 / (1 << 53)))

    for _ in range(400):
        out.append([uniform(0.45, 0.55), uniform(0.07, 0.13), uniform(0.0, 0.08)])
    for _ in range(100):
        out.append([uniform(0.3, 0.7), uniform(-0.1, 0.3), uniform(-0.16, 0.24)])
    return np.array(out)


def median_ms(fn, repeats, warmup=2):
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def read_pgm(path):
    data = path.read_bytes()
    parts = data.split(maxsplit=3)  # b"P5", width, height, then maxval + pixels
    w, h = int(parts[1]), int(parts[2])
    return np.frombuffer(data[-w * h :], dtype=np.uint8).reshape(h, w)


def main():
    pts = bench_points()

    def iforest():
        m = IsolationForest(n_estimators=100, max_samples=256, random_state=0).fit(pts)
        m.score_samples(pts)

    frame = read_pgm(ROOT / "core/tests/fixtures/lsd/frame0.pgm")
    lsd = cv2.createLineSegmentDetector()

    entries = {
        "sklearn_iforest_500": {"median_ms": median_ms(iforest, 15)},
        "cv2_lsd_640x480": {"median_ms": median_ms(lambda: lsd.detect(frame), 50)},
    }
    print(json.dumps({"entries": entries}))


if __name__ == "__main__":
    main()
