"""Paired differences between two ``map_replay`` outputs of the same captures (second minus
first) in mean 3D IoU, recall and precision at 3D IoU 0.25, with 95 % bootstrap intervals over
the captures (10,000 resamples, seed 0).

    map_replay '<patch A>' <captures> > a.txt; map_replay '<patch B>' <captures> > b.txt
    python studies/shape_evidence/paired.py a.txt b.txt
"""

from __future__ import annotations

import random
import re
import sys
from pathlib import Path

LINE = re.compile(r"\s*(\S+): *(\d+) for *(\d+)\*? *recall ([\d.]+) precision ([\d.]+) IoU ([\d.]+)")


def load(path: str) -> dict[str, dict[str, float]]:
    out = {}
    for line in Path(path).read_text().splitlines():
        m = LINE.match(line)
        if m:
            out[m[1]] = {"recall": float(m[4]), "precision": float(m[5]), "iou": float(m[6])}
    return out


def main() -> None:
    a, b = load(sys.argv[1]), load(sys.argv[2])
    keys = [k for k in a if k in b]
    rng = random.Random(0)
    for metric in ("iou", "recall", "precision"):
        d = [b[k][metric] - a[k][metric] for k in keys]
        boot = sorted(sum(rng.choice(d) for _ in d) / len(d) for _ in range(10_000))
        print(f"{metric}: n {len(d)} mean diff {sum(d) / len(d):+.4f} [{boot[250]:+.4f}, {boot[9750]:+.4f}]")


if __name__ == "__main__":
    main()
