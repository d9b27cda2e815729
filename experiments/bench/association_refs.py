"""Reference timings for the association benchmarks (scipy), same inputs as core/benches/association.rs.

Prints {"entries": {"scipy_mannwhitney_500": {"median_ms": ...}}} to stdout.
Data: SplitMix64 (seed 42), x_i = 0.45 + 0.1 u, y_i = 0.46 + 0.1 u, u = (next >> 11) * 2**-53,
500 values each, x drawn first (identical to the Rust bench's `mw_data`).
Run: /work/main/.venv/bin/python experiments/bench/association_refs.py
"""

import json
import sys
import time

import numpy as np
from scipy import stats

MASK = (1 << 64) - 1


def splitmix64(seed):
    state = seed
    while True:
        state = (state + 0x9E3779B97F4A7C15) & MASK
        z = state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
        z ^= z >> 31
        yield (z >> 11) * (1.0 / (1 << 53))


def mw_data():
    g = splitmix64(42)
    x = np.array([0.45 + 0.1 * next(g) for _ in range(500)])
    y = np.array([0.46 + 0.1 * next(g) for _ in range(500)])
    return x, y


def median_ms(fn, repeats=300, warmup=20):
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def main():
    x, y = mw_data()
    res = stats.mannwhitneyu(x, y, alternative="two-sided", method="asymptotic", use_continuity=False)
    print(f"scipy mannwhitneyu U1={res.statistic} p={res.pvalue}", file=sys.stderr)
    entries = {
        "scipy_mannwhitney_500": {
            "median_ms": median_ms(
                lambda: stats.mannwhitneyu(x, y, alternative="two-sided", method="asymptotic", use_continuity=False)
            )
        }
    }
    print(json.dumps({"entries": entries}))


if __name__ == "__main__":
    main()
