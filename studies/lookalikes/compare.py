"""Table of run folders for the look-alikes study: objects est/gt, mean 3D IoU, per-object 3D IoU.

``python studies/lookalikes/compare.py LABEL=RUN_DIR [LABEL=RUN_DIR ...]`` reads each folder's
``metrics.json`` and prints one Markdown row per folder.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def row(label: str, run_dir: Path) -> str:
    """One Markdown table row for a run folder."""
    m = json.loads((run_dir / "metrics.json").read_text())
    ious = [o["iou3d"] for o in m["objects"]]
    mean = sum(ious) / len(ious) if ious else float("nan")
    per = " ".join(f"{v:.2f}" for v in ious)
    return (
        f"| {label} | {m['scene']} | {m['strategy']} | {m['seed']} | {m['n_objects_est']}/{m['n_objects_gt']} "
        f"| {mean:.3f} | {per} |"
    )


def main(argv: list[str]) -> None:
    """Print the table for ``LABEL=RUN_DIR`` arguments."""
    print("| code | scene | strategy | seed | objects est/gt | mean 3D IoU | 3D IoU per true object |")
    print("|---|---|---|---|---|---|---|")
    for arg in argv:
        label, _, path = arg.partition("=")
        print(row(label, Path(path)))


if __name__ == "__main__":
    main(sys.argv[1:])
