"""Counts, recall, precision and 3D IoU of benchmark reports, one line each:
``python studies/existence_evidence/summary.py reports/exploration.json <dir>/exploration.json ...``
(rows of the default strategy, per split)."""

import json
import sys
from pathlib import Path


def summary(rows: list[dict]) -> str:
    n = len(rows)
    within = sum(abs(x["n_objects_est"] - x["n_objects_gt"]) <= 1 for x in rows)
    recall_ok = sum(x["recall_iou25"] >= 0.9 for x in rows)
    mean = lambda k: sum(x[k] for x in rows) / n
    extra = sum(x["n_objects_est"] - x["n_objects_gt"] for x in rows)
    return (
        f"within one {within}/{n} | recall@0.25>=0.9 {recall_ok}/{n} | mean recall {mean('recall_iou25'):.3f} | "
        f"mean precision {mean('precision_iou25'):.3f} | mean 3D IoU {mean('iou3d'):.3f} | objects est-true {extra:+d}"
    )


for path in sys.argv[1:]:
    rows = [
        x for x in json.loads(Path(path).read_text())["rows"] if x["strategy"] == "object-driven-discovery"
    ]
    for split in sorted({x["split"] for x in rows}):
        print(path, split, summary([x for x in rows if x["split"] == split]))
