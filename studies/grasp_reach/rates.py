"""Grasp success per split (hard, test) and map source, with Wilson 95 % intervals and causes.

    python studies/grasp_reach/rates.py reports/grasping.json
    python studies/grasp_reach/rates.py runs/grasp_x/trim_a.json runs/grasp_x/trim_b.json

A ``grasping.json`` report gives its rows; manifests give their sessions (rows as the experiment
counts them: ``experiments/grasp.py``'s ``_rows``).
"""

from __future__ import annotations

import importlib.util
import json
import sys
from collections import Counter
from pathlib import Path

from objslam.reloc import wilson

REPO = Path(__file__).resolve().parents[2]
# The experiment script, loaded from its file (its row counting is the report's).
_spec = importlib.util.spec_from_file_location("grasp_experiment", REPO / "experiments" / "grasp.py")
assert _spec is not None and _spec.loader is not None
exp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(exp)


def main() -> None:
    rows: list[dict] = []
    sessions: list[str] = []
    for a in sys.argv[1:]:
        d = json.loads(Path(a).read_text())
        if "rows" in d:
            rows += d["rows"]
        else:
            sessions += [s for s in d["sessions"] if s not in sessions]
    rows += exp._rows(sessions)
    for split in ("hard", "test"):
        for src in exp.SOURCES:
            sel = [
                r
                for r in rows
                if r["scene"].startswith(split)
                and r["map_source"] == src
                and not r.get("reobserve")
                and not r.get("centre_error_mm")
            ]
            if not sel:
                continue
            k = sum(bool(r["success"]) for r in sel)
            lo, hi = wilson(k, len(sel))
            causes = Counter(r["cause"] for r in sel if not r["success"])
            print(
                f"{split:4s} {src:12s} {k:3d}/{len(sel):3d} = {k / len(sel):5.1%}  "
                f"[{lo:5.1%}, {hi:5.1%}]  {dict(causes.most_common())}"
            )


if __name__ == "__main__":
    main()
