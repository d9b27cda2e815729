"""Placement tasks from object maps: ``python experiments/place.py [--maps-from runs/grasp_sweep.json ...]
[--tasks ...] [--scenes ...] [--seeds ...] [--reobserve] [--no-feel-support] [--tag T] [--out reports]``.

The maps are the object-driven exploration maps of ``make grasp`` sweeps (their manifests list the
run folders; mapping is not repeated). For every scene and seed, each of the paper's three tasks
(:mod:`objslam.place`: ``block_in_cup``, ``cups_by_volume``, ``bottles_by_height``) runs in a fresh
simulated world when the scene has the classes it needs; the result goes to
``place_<task><tag>.json`` in the map's run folder. Reports: ``<out>/placement.json`` = {"command",
"rows": [{"task", "seed", "scene", "success", "reason", ...}]} and ``<out>/placement.md`` (success
per task over scenes × seeds, failure reasons), built from those files.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
from collections import Counter
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    from objslam import _native
    from objslam.cli import HelpFormatter
    from objslam.config import load_run_config
    from objslam.place import TASKS, run_place_task
    from objslam.provenance import provenance, report_files, run_config
    from objslam.scene import load_scene, scene_file

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--maps-from", nargs="+", default=[str(REPO / "runs" / "grasp_sweep.json")], help="grasp sweep manifests")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS, help="placement tasks")
    ap.add_argument("--scenes", nargs="*", default=None, help="scene names (default: all in the manifest)")
    ap.add_argument("--seeds", nargs="*", type=int, default=None, help="run seeds (default: all in the manifest)")
    ap.add_argument("--tag", default="", help="suffix of the task files (place_<task><tag>.json): variants beside the defaults")
    ap.add_argument("--config", action="append", default=[], help="run-config TOML overlay (repeatable)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key (repeatable)")
    ap.add_argument("--out", default="reports", help="report folder")
    a = ap.parse_args(argv)
    command = ("python experiments/place.py " + " ".join(shlex.quote(x) for x in (argv if argv is not None else sys.argv[1:]))).strip()
    manifests = [json.loads(Path(m).read_text()) for m in a.maps_from]
    maps = []
    for p in [p for m in manifests for p in m["sessions"]]:
        d = json.loads(Path(p).read_text())
        if d["map_source"] != "estimated":
            continue
        if (a.scenes and d["scene"] not in a.scenes) or (a.seeds is not None and d["seed"] not in a.seeds):
            continue
        maps.append((d["scene"], d["seed"], Path(d["map_run"])))
    files = []
    not_run: list[dict[str, Any]] = []
    for scene_name, seed, run_dir in sorted(set(maps)):
        rel = scene_file(scene_name, REPO)  # scenes/, scenes/hard/ or scenes/test/
        scene = load_scene(REPO / rel)
        run_cfg = load_run_config(overlays=a.config, overrides=[*a.set, f'scene="{rel}"', f"seed={seed}"], strategy="object-driven")
        objs = json.loads(_native.map_objects_json(_native.load_map(str(run_dir / "map.json"))))
        for task in a.tasks:
            try:
                res = run_place_task(task, scene, run_cfg, objs, run_cfg.place)
            except Exception as e:  # noqa: BLE001 - one failed task never stops the sweep
                res = {"task": task, "success": False, "reason": f"error: {type(e).__name__}: {e}"}
            if res.get("reason") == "not_applicable":
                if res.get("detail"):
                    not_run.append({"task": task, "scene": scene_name, "seed": seed, "detail": res["detail"]})
                continue
            res.update(scene=scene_name, seed=seed, map_run=str(run_dir), reobserve=run_cfg.grasp.reobserve, feel_support=run_cfg.place.feel_support)
            f = run_dir / f"place_{task}{a.tag}.json"
            f.write_text(json.dumps(res, indent=2) + "\n")
            files.append(str(f))
            print(f"{scene_name} seed {seed} {task:<18} {'success' if res['success'] else res['reason']}", flush=True)
    rows = [json.loads(Path(f).read_text()) for f in files]
    out = REPO / a.out
    out.mkdir(parents=True, exist_ok=True)
    (report_files(out, "placement")[0]).write_text(
        json.dumps(
            {
                **provenance(
                    command,
                    {**run_config(a.config, a.set), "tasks": a.tasks},
                ),
                "files": files,
                "rows": rows,
                "not_run": not_run,
            },
            indent=2,
        )
        + "\n"
    )
    lines = [
        "# Placement tasks from the estimated map",
        "",
        f"Generated by `{command}` from the task files listed in `placement.json`; maps: the object-driven",
        "exploration maps of `" + "`, `".join(m.get("command", f) for m, f in zip(manifests, a.maps_from)) + "`. Grasps "
        + ("re-observe the target first." if load_run_config(overlays=a.config, overrides=a.set).grasp.reobserve else "use the map estimates as they are."),
        "Tasks (see `sim/objslam/place.py`): `block_in_cup` = the smallest block onto the largest cup (the",
        "simulator's cups are solid); `cups_by_volume` / `bottles_by_height` = all of them along a line of",
        "free table, ordered. Success judged from SAPIEN ground truth. Scenes without the classes a task needs",
        "do not run it.",
        "",
        "| task | runs (scene × seed) | success | bar (≥ 90 %) |",
        "|---|---:|---:|---|",
    ]
    for t in a.tasks:
        r = [x for x in rows if x["task"] == t]
        n, s = len(r), sum(x["success"] for x in r)
        rate = f"{s}/{n} ({100.0 * s / n:.0f} %)" if n else "-"
        lines.append(f"| {t} | {n} | {rate} | {'met' if n and s / n >= 0.9 else 'not met'} |")
    lines += ["", "## Failure reasons", "", "| task | reason | count |", "|---|---|---:|"]
    for t in a.tasks:
        for reason, c in sorted(Counter(x["reason"] for x in rows if x["task"] == t and not x["success"]).items()):
            lines.append(f"| {t} | {reason} | {c} |")
    lines += release_table(rows, a.tasks)
    if not_run:
        lines += ["", "## Not run (infeasible for the gripper)", "", "| task | scene | seed | why |", "|---|---|---:|---|"]
        lines += [f"| {r['task']} | {r['scene']} | {r['seed']} | {r['detail']} |" for r in not_run]
    lines.append("")
    (report_files(out, "placement")[1]).write_text("\n".join(lines))
    print(f"{len(rows)} rows → {a.out}/pages/placement.md")
    return 0


def release_table(rows: list[dict[str, Any]], tasks: list[str]) -> list[str]:
    """Markdown lines: per task, how the items were let go (``PlaceConfig.feel_support``: contact
    felt, stuck, no slow descent) and how high above their support in ground truth."""
    out = [
        "",
        "## Letting go",
        "",
        (
            "Every put-down of a task's items (set-aside moves excluded). Slow descent: from 1 cm above the"
            " release gap the hand goes on down until it feels the support (`PlaceConfig.feel_support`)."
            " True gap: the item's true bottom above the true surface under it when the fingers open"
            " (ground truth, judging only)."
        ),
        "",
        "| task | put-downs | contact felt | stuck at the start | no slow descent | slow descent, mm (median / max) | true gap, mm (median / max) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]

    def spread(v: list[float]) -> str:
        return f"{statistics.median(v):.1f} / {max(v):.1f}" if v else "-"

    for t in tasks:
        td = [st["touchdown"] for r in rows if r["task"] == t for st in r.get("steps", []) if st.get("touchdown") is not None]
        if not td:
            continue
        how = Counter(x.get("how", "none") for x in td)
        depth = [1000 * x["depth_m"] for x in td if "depth_m" in x]
        gaps = [1000 * x["true_gap_m"] for x in td if x.get("true_gap_m") is not None]
        out.append(
            f"| {t} | {len(td)} | {how['contact']} | {how['stuck']} | {len(td) - how['contact'] - how['stuck']} | "
            f"{spread(depth)} | {spread(gaps)} |"
        )
    return out


if __name__ == "__main__":
    raise SystemExit(main())
