"""Objects outside their label's sizes in replayed maps, and how much of their clouds the others claim.

Usage::

    map_replay --objects --dump DUMPS '{"class_size_tolerance":0}' <captures> > objects.txt
    python studies/class_size_priors/misfits.py DUMPS objects.txt [--tolerance 1.5]

For every map object of ``DUMPS/<capture>.map.json`` whose footprint extent or height lies outside
its label's range of the core's ``map.class_sizes`` widened by the tolerance, prints its observation
count, size, the share of its cloud claimed by the objects that fit their labels (another cloud has
more points than its own within 5 mm, the core's ownership rule) and whether ``map_replay`` matched
it to a true object ("matched") or listed it as an extra estimate ("EXTRA").
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
from objslam import _native
from scipy.spatial import cKDTree

RADIUS_M = 0.005


def extras_by_capture(text: Path) -> dict[str, set[int]]:
    """``extra est N`` lines precede their capture's summary line."""
    out: dict[str, set[int]] = {}
    pending: set[int] = set()
    for line in text.read_text().splitlines():
        m = re.match(r"\s*extra est (\d+)", line)
        if m:
            pending.add(int(m[1]))
        m = re.match(r"\s*(\S+): +\d+ for", line)
        if m:
            out[m[1]] = pending
            pending = set()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dumps", type=Path)
    ap.add_argument("objects", type=Path)
    ap.add_argument("--tolerance", type=float, default=1.5)
    a = ap.parse_args()
    priors = json.loads(_native.resolve_config("{}"))["map"]["class_sizes"]
    extras = extras_by_capture(a.objects)

    def size(o: dict) -> tuple[float, float]:
        h = o["half_extents"]
        return 2 * max(h[0], h[1]), 2 * h[2]

    def misfit(o: dict) -> bool:
        ext, height = size(o)
        (e0, e1), (h0, h1) = priors[o["label"]]["extent_m"], priors[o["label"]]["height_m"]
        f = a.tolerance
        return not (e0 / f <= ext <= e1 * f and h0 / f <= height <= h1 * f)

    for path in sorted(a.dumps.glob("*.map.json")):
        cap = path.name.split(".")[0]
        objs = json.loads(path.read_text())["objects"]
        pts = {o["id"]: np.asarray(o["points_in_world"], float).reshape(-1, 3) for o in objs}
        odd = {o["id"] for o in objs if misfit(o)}
        for o in objs:
            if o["id"] not in odd or len(pts[o["id"]]) == 0:
                continue
            own = pts[o["id"]]
            mine = np.array([len(n) for n in cKDTree(own).query_ball_point(own, RADIUS_M)])
            owned = np.ones(len(own), bool)
            for k, p in pts.items():
                if k == o["id"] or k in odd or len(p) == 0:
                    continue
                theirs = np.array([len(n) for n in cKDTree(p).query_ball_point(own, RADIUS_M)])
                owned &= theirs <= mine
            ext, height = size(o)
            tag = "EXTRA" if o["id"] in extras.get(cap, set()) else "matched"
            print(f"{cap:9s} {o['id']:4d} {o['label']:7s} obs {len(o['observations']):3d} "
                  f"extent {100 * ext:5.1f} cm height {100 * height:5.1f} cm claimed {1 - owned.mean():.2f} {tag}")


if __name__ == "__main__":
    main()
