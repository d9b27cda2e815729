"""Grasp success from object maps: ``python experiments/grasp.py [--scenes ...] [--seeds 0 1]
[--sources estimated ground_truth init_only] [--config overlay.toml] [--set k=v] [--out reports]``.

Per scene and seed: the object-driven exploration builds the estimated map and the Init-only
episode the lower-bound map (both ordinary runs of the episode runner, each its own run folder);
then, for every map source — ``estimated`` (object-driven map), ``ground_truth`` (true poses and
sizes: the upper bound), ``init_only`` (the Init views' map) — a fresh simulated world grasps every
map object one after another (:mod:`objslam.grasp`). Each session writes
``grasp_<source>.json`` (rows + config) and ``grasp_<source>.rrd`` (planned TCP paths, grasp
frames, finger gap, outcome events) into the run folder of its map. The sweep's list of session
files goes to ``runs/grasp_sweep.json``; ``--report-only`` rebuilds the reports from it.

Reports (from the session files): ``<out>/grasping.json`` = {"command", "sessions", "rows":
[{"scene", "seed", "object", "class", "map_source", "success", "cause", ...}]} and
``<out>/grasping.md``: success overall, per class, per scene, failure causes, per map source.
One process, one simulator at a time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("estimated", "ground_truth", "init_only")
CAUSES = ("no_ik", "no_path", "too_wide", "collided", "missed", "slipped", "phantom", "not_found", "not_in_map")


def _session(scene: Any, cfg: Any, map_objects: list[dict], source: str, run_dir: Path, gcfg: Any) -> Path:
    from objslam import _native
    from objslam.grasp import config_dict, run_grasp_session

    t0 = time.perf_counter()
    rec = _native.Recorder(str(run_dir / f"grasp_{source}.rrd"), "objslam-grasp") if cfg.record.enabled else None
    try:
        rows = run_grasp_session(scene, cfg, map_objects, gcfg, rec)
    finally:
        if rec is not None:
            rec.close()
    out = {
        "scene": scene.name,
        "seed": cfg.seed,
        "map_source": source,
        "map_run": str(run_dir),
        "wall_s": time.perf_counter() - t0,
        "config": config_dict(gcfg),
        "rows": rows,
    }
    path = run_dir / f"grasp_{source}.json"
    path.write_text(json.dumps(out, indent=2) + "\n")
    return path


def run_sweep(a: argparse.Namespace) -> list[str]:
    from objslam import _native
    from objslam.config import load_run_config
    from objslam.episode import run_episode
    from objslam.grasp import GraspRunConfig
    from objslam.scene import gt_objects, load_scene

    gcfg = GraspRunConfig()
    sessions: list[str] = []
    for scene_file in a.scenes:
        for seed in a.seeds:
            overrides = [*a.set, f'scene="{scene_file}"', f"seed={seed}"]
            cfg = load_run_config(overlays=a.config, overrides=overrides, strategy="object-driven")
            scene = load_scene(REPO / scene_file)
            t0 = time.perf_counter()
            runs: dict[str, Path] = {}
            try:
                if "estimated" in a.sources or "ground_truth" in a.sources:
                    runs["estimated"] = run_episode(cfg, progress=False).run_dir
                if "init_only" in a.sources:
                    runs["init_only"] = run_episode(dataclasses.replace(cfg, strategy="init"), progress=False).run_dir
            except Exception as e:  # noqa: BLE001 - the run folder records it; the sweep goes on
                print(f"{scene.name} seed {seed}: mapping failed: {type(e).__name__}: {e}", file=sys.stderr)
                continue
            t_map = time.perf_counter() - t0
            for source in a.sources:
                if source == "ground_truth":
                    objs = [{**g, "n_observations": 0} for g in gt_objects(scene)]
                    run_dir = runs["estimated"]
                else:
                    run_dir = runs[source]
                    objs = json.loads(_native.map_objects_json(_native.load_map(str(run_dir / "map.json"))))
                try:
                    path = _session(scene, cfg, objs, source, run_dir, gcfg)
                except Exception as e:  # noqa: BLE001 - one failed session never stops the sweep
                    print(f"{scene.name} seed {seed} {source}: grasp session failed: {type(e).__name__}: {e}", file=sys.stderr)
                    continue
                sessions.append(str(path))
                d = json.loads(path.read_text())
                att = [r for r in d["rows"] if not r.get("skipped")]
                print(
                    f"{scene.name} seed {seed} {source:<12} {sum(r['success'] for r in att)}/{len(att)} "
                    f"(mapping {t_map:.0f} s, grasping {d['wall_s']:.0f} s)",
                    flush=True,
                )
            (REPO / "runs").mkdir(exist_ok=True)
            (REPO / "runs" / "grasp_sweep.json").write_text(json.dumps({"sessions": sessions}, indent=2) + "\n")
    return sessions


def _rate(rows: list[dict]) -> str:
    n = len(rows)
    s = sum(r["success"] for r in rows)
    return f"{s}/{n} ({100.0 * s / n:.1f} %)" if n else "-"


def write_reports(sessions: list[str], out: Path, command: str) -> dict[str, Any]:
    """grasping.json / grasping.md from session files."""
    rows: list[dict[str, Any]] = []
    for p in sessions:
        d = json.loads(Path(p).read_text())
        for r in d["rows"]:
            if r.get("skipped"):
                continue
            rows.append(
                {
                    "scene": d["scene"],
                    "seed": d["seed"],
                    "object": r["object"],
                    "class": r["class"],
                    "map_source": d["map_source"],
                    "success": bool(r["success"]),
                    "cause": r["cause"],
                    "map_id": r.get("map_id"),
                    "map_label": r.get("map_label"),
                    "closed_gap_m": r.get("closed_gap_m"),
                    "expected_closed_width_m": r.get("expected_closed_width_m"),
                    "rise_m": r.get("rise_m"),
                    "run_dir": d["map_run"],
                }
            )
    out.mkdir(parents=True, exist_ok=True)
    report = {"command": command, "sessions": sessions, "rows": rows}
    (out / "grasping.json").write_text(json.dumps(report, indent=2) + "\n")
    sources = [s for s in SOURCES if any(r["map_source"] == s for r in rows)]
    by = {s: [r for r in rows if r["map_source"] == s] for s in sources}
    scenes = sorted({r["scene"] for r in rows})
    seeds = sorted({r["seed"] for r in rows})
    classes = sorted({r["class"] for r in rows})
    lines = [
        "# Grasping from object maps",
        "",
        f"Generated by `{command}` from the grasp session files listed in `grasping.json`",
        f"(scenes {', '.join(scenes)}; seeds {', '.join(map(str, seeds))}).",
        "",
        "One row per attempt: every map object the planner can fit in the gripper, grasped top-down one",
        "after another (grasped objects set aside, no re-observation), plus one `not_in_map` row per",
        "graspable true object no map object targets, plus `too_wide` rows where the map made a graspable",
        "object too wide. Success = the true object ends ≥ 10 cm above its start after the lift and a",
        "1 s hold (SAPIEN ground truth). Sources: `estimated` = object-driven exploration map,",
        "`ground_truth` = true poses and sizes (upper bound), `init_only` = the four Init views' map.",
        "",
        "## Overall",
        "",
        "| map source | attempts | success |",
        "|---|---:|---:|",
    ]
    for s in sources:
        lines.append(f"| {s} | {len(by[s])} | {_rate(by[s])} |")
    lines += ["", "## Per class", "", "| class | " + " | ".join(sources) + " |", "|---|" + "---:|" * len(sources)]
    for c in classes:
        lines.append(f"| {c} | " + " | ".join(_rate([r for r in by[s] if r["class"] == c]) for s in sources) + " |")
    lines += ["", "## Per scene", "", "| scene | " + " | ".join(sources) + " |", "|---|" + "---:|" * len(sources)]
    for sc in scenes:
        lines.append(f"| {sc} | " + " | ".join(_rate([r for r in by[s] if r["scene"] == sc]) for s in sources) + " |")
    lines += ["", "## Failure causes", "", "| cause | " + " | ".join(sources) + " |", "|---|" + "---:|" * len(sources)]
    counts = {s: Counter(r["cause"] for r in by[s] if not r["success"]) for s in sources}
    for c in CAUSES:
        if any(counts[s][c] for s in sources):
            lines.append(f"| {c} | " + " | ".join(str(counts[s][c]) for s in sources) + " |")
    lines += [
        "",
        "Causes: `no_ik` no collision-free IK for any candidate; `no_path` IK but no collision-free path;",
        "`too_wide` the map's estimate is wider than the gripper; `collided` an object moved > 2 cm",
        "before closing or the arm was blocked; `missed` closed without lifting the object; `slipped`",
        "lifted ≥ 2 cm but not held ≥ 10 cm; `not_in_map` no map object for a graspable true object.",
        "",
    ]
    (out / "grasping.md").write_text("\n".join(lines))
    return report


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=[f"scenes/scene0{i}.toml" for i in range(1, 8)])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--sources", nargs="+", default=list(SOURCES), choices=SOURCES)
    ap.add_argument("--config", action="append", default=[], help="run-config overlay (repeatable)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--out", default="reports")
    ap.add_argument("--report-only", action="store_true", help="rebuild the reports from runs/grasp_sweep.json")
    a = ap.parse_args(argv)
    command = "python experiments/grasp.py " + " ".join(shlex.quote(x) for x in (argv if argv is not None else sys.argv[1:]))
    if a.report_only:
        sessions = json.loads((REPO / "runs" / "grasp_sweep.json").read_text())["sessions"]
    else:
        sessions = run_sweep(a)
    report = write_reports(sessions, REPO / a.out, command.strip())
    print(f"{len(report['rows'])} rows → {a.out}/grasping.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
