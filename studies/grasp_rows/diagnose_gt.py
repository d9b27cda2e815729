"""Which true-map grasps have no collision-free IK, and what blocks them?

For each scene, plans every graspable object of the ground-truth map (the planner sees the exact
geometry as if it were a map) from the ready posture among all other objects, and for failures:
alone, and each neighbour left out in turn. Planner only (no simulation).

    python studies/grasp_rows/diagnose_gt.py scenes/hard/hard07.toml ... [--set key=value]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from objslam import _native
from objslam.scene import gt_objects, load_scene
from objslam.world import READY_QPOS, panda_urdf_path

REPO = Path(__file__).resolve().parents[2]
# The grasp experiment's planner settings (reports/grasping.json `config.grasp.planner`).
BASE = {"rng_seed": 1, "opening_clearance_m": 0.08, "max_grasp_depth_m": 0.04}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("scenes", nargs="+")
    p.add_argument("--set", action="append", default=[], help="planner key=value")
    a = p.parse_args()
    cfg = {**BASE, **{k: json.loads(v) for k, v in (s.split("=", 1) for s in a.set)}}
    planner = _native.Planner(str(panda_urdf_path()), json.dumps(cfg))
    q0 = READY_QPOS[:7]
    for f in a.scenes:
        gt = gt_objects(load_scene(REPO / f))
        for t in gt:
            h = t["geometry"]["half_extents"]
            w = 2 * (min(h[0], h[1]) if t["geometry"]["shape"] == "cuboid" else h[0])
            if w > 0.076:
                continue
            others = [o for o in gt if o is not t]

            def plan(neigh, t=t):
                return planner.plan_grasp(q0, json.dumps(t["geometry"]), json.dumps([n["geometry"] for n in neigh]))

            r = plan(others)
            if r["ok"]:
                c = r["world_from_tcp_grasp"][:3, 3]
                off = math.dist(c[:2], t["geometry"]["center"][:2])
                print(f"{Path(f).stem} gt{t['id']:<2} {t['label']:6s} ok yaw={r['hand_yaw_rad']:.2f} off={off * 100:.1f}cm")
                continue
            blockers = [n["id"] for n in others if plan([m for m in others if m is not n])["ok"]]
            print(
                f"{Path(f).stem} gt{t['id']:<2} {t['label']:6s} {r['cause']} alone={plan([])['ok']} "
                f"blockers={blockers}"
            )


if __name__ == "__main__":
    main()
