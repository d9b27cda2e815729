"""Why do grasps fail `no_ik` on the estimated map but succeed on the ground-truth map?

For every scene of the exploration sweep (``--benchmark``), replays the planner on the obstacles left
when the grasp session gave up (the map objects whose attempt was not felt as a grasp) and, for
each `no_ik` target, plans again with: no neighbours, each neighbour left out in turn, no object
margin, the true geometry of the target. Planner only (no simulation).

    python studies/grasp_reach/diagnose.py \
        --benchmark runs/exploration_h13.json [--manifest runs/grasp_x/a.json]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from objslam import _native
from objslam.scene import gt_objects, load_scene
from objslam.world import READY_QPOS, panda_urdf_path

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--benchmark", required=True)
    p.add_argument("--tag", default="")
    p.add_argument("--set", action="append", default=[], help="planner key=value")
    a = p.parse_args()
    rows = json.loads(Path(a.benchmark).read_text())["rows"]
    extra = {k: json.loads(v) for k, v in (s.split("=", 1) for s in a.set)}
    for r in rows:
        if r["strategy"] != "object-driven":
            continue
        run = Path(r["run_dir"])
        scene = load_scene(
            REPO / "scenes" / ("hard" if r["scene"].startswith("hard") else "test") / f"{r['scene']}.toml"
        )
        gt = {g["id"]: g for g in gt_objects(scene)}
        est = json.loads(_native.map_objects_json(_native.load_map(str(run / "map.json"))))
        by_id = {o["id"]: o for o in est}
        sess = json.loads((run / f"grasp_estimated{a.tag}.json").read_text())
        held = {x["map_id"] for x in sess["rows"] if x.get("held")}
        cfg = {
            "rng_seed": int(r["seed"]) + 1,
            "opening_clearance_m": 0.08,
            "max_grasp_depth_m": 0.04,
            **extra,
        }
        planner = _native.Planner(str(panda_urdf_path()), json.dumps(cfg))
        q0 = READY_QPOS[:7]
        gts = json.loads((run / f"grasp_ground_truth{a.tag}.json").read_text())
        gt_ok = {x["object"] for x in gts["rows"] if x["success"]}
        for x in sess["rows"]:
            if x["cause"] != "no_ik":
                continue
            t = by_id[x["map_id"]]
            left = [o for o in est if o["id"] not in held and o["id"] != t["id"]]

            def plan(target, neigh, p=planner, q0=q0):
                return p.plan_grasp(
                    q0, json.dumps(target["geometry"]), json.dumps([n["geometry"] for n in neigh])
                )["ok"]

            g = t["geometry"]
            c = np.array(g["center"])
            line = (
                f"{r['scene']} {x['object']:5s} map{t['id']:<3d} {t['label']:6s} gt_ok={x['object'] in gt_ok} "
                f"r={math.hypot(c[0], c[1]):.3f} est c=({c[0]:.3f},{c[1]:.3f},{c[2]:.3f}) h={np.round(np.array(g['half_extents']) * 2, 3).tolist()} yaw={g['yaw_rad']:.2f}"
            )
            gid = x.get("gt_id")
            if gid is not None:
                tg = gt[gid]["geometry"]
                line += f" | gt c=({tg['center'][0]:.3f},{tg['center'][1]:.3f},{tg['center'][2]:.3f}) h={np.round(np.array(tg['half_extents']) * 2, 3).tolist()} yaw={tg['yaw_rad']:.2f}"
            print(line)
            alone = plan(t, [])
            with_all = plan(t, left)
            blockers = [n for n in left if plan(t, [m for m in left if m is not n])] if not with_all else []
            p0 = _native.Planner(str(panda_urdf_path()), json.dumps({**cfg, "object_margin_m": 0.0}))
            nomargin = plan(t, left, p0)
            truth = plan({**t, "geometry": gt[gid]["geometry"]}, left) if gid is not None else None
            near = sorted(left, key=lambda n: math.dist(n["geometry"]["center"][:2], c[:2]))[:4]
            desc = []
            for n in near:
                ng = n["geometry"]
                gm = [x2 for x2 in sess["rows"] if x2["map_id"] == n["id"]]
                desc.append(
                    f"map{n['id']}({n['label']},{gm[0]['object'] if gm else '?'}:{gm[0]['cause'] if gm else '?'}) d={math.dist(ng['center'][:2], c[:2]):.3f} "
                    f"size={np.round(np.array(ng['half_extents']) * 2, 3).tolist()}"
                )
            print(
                f"   with_all={with_all} alone={alone} nomargin={nomargin} true_target={truth} blockers={[b['id'] for b in blockers]}"
            )
            print("   near: " + "; ".join(desc))


if __name__ == "__main__":
    main()
