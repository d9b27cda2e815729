"""Quantiles of the shape-fit ratio (cylinder cost / cuboid cost) per true primitive, from the
``shape est`` lines of ``map_replay --objects`` (objects matched to a true object only).

    map_replay --objects '{"existence_ratio":0.33}' <captures> > objects.txt
    python studies/shape_evidence/fit_ratios.py objects.txt
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

CUBOID_LABELS = {"Block", "Book", "Keyboard"}
LINE = re.compile(r"\s*shape est \d+ \w+ gt (\w+) votes .* costs Some\(\[([\d.]+), ([\d.]+)\]\)")


def main() -> None:
    ratios: dict[str, list[float]] = {"cuboid": [], "cylinder": []}
    for line in Path(sys.argv[1]).read_text().splitlines():
        m = LINE.match(line)
        if not m or float(m[2]) <= 0.0:
            continue
        ratios["cuboid" if m[1] in CUBOID_LABELS else "cylinder"].append(float(m[3]) / float(m[2]))
    print("| true primitive | n | 5 % | 10 % | median | 90 % | 95 % |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for shape, v in ratios.items():
        v.sort()
        q = [v[int(p * (len(v) - 1))] for p in (0.05, 0.1, 0.5, 0.9, 0.95)]
        print(f"| {shape} | {len(v)} | " + " | ".join(f"{x:.2f}" for x in q) + " |")


if __name__ == "__main__":
    main()
