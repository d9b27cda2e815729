"""Success of the object relocalisation per parallax bin for MatchConfig variants, on the query maps
kept by `experiments/reloc.py` in runs/reloc/<scene>_seed0.json.

    PYTHONPATH=experiments python studies/reloc_matcher/grid.py hard01,hard02,hard03,hard04,hard05,hard06,hard07 "{}" \\
        "{'size_tolerance':0.25,'noise':{'size_rel':0.05},'descriptor':{'label_match':'exact'}}"

K=6 in the environment takes the 6-keyframe queries.
"""

from __future__ import annotations

import ast
import json
import os
import sys

import numpy as np
import objslam
import reloc  # experiments/reloc.py: run with PYTHONPATH=experiments
from objslam.topo import transform_map_json


def main() -> None:
    k = int(os.environ.get("K", "3"))
    data = []
    for scene in sys.argv[1].split(","):
        stored = json.loads((reloc.REPO / "runs" / "reloc" / f"{scene}_seed0.json").read_text())
        prior = (reloc.REPO / stored["info"]["prior_run"] / "map.json").read_text()
        for q in stored["queries"]:
            if q["query_keyframes"] != k:
                continue
            sim = q["similarity"]
            moved = transform_map_json(json.dumps(q["query_map"]), sim["yaw"], sim["translation"], sim["scale"])
            truth = reloc.similarity_matrix(sim["yaw"], sim["translation"], sim["scale"])
            data.append((prior, moved, truth, q["parallax_bin"]))
    for text in sys.argv[2:]:
        config = json.dumps(ast.literal_eval(text))
        bins: dict[str, list[bool]] = {}
        for prior, moved, truth, b in data:
            r = objslam.match_maps(prior, moved, config)
            s = reloc._score(np.asarray(r["matrix"]) if r["matched"] else None, truth)
            bins.setdefault(b, []).append(s["success"])
        rates = {b: (len(v), round(sum(v) / len(v), 3)) for b, v in sorted(bins.items())}
        print(text, rates, flush=True)


if __name__ == "__main__":
    main()
