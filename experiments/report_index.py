"""Write ``reports/README.md``: one line per report in ``reports/`` (its question, its headline figure, the
make target that makes it, the commit it was made from).

    python3 experiments/report_index.py [--reports reports]   (``make reports-index``; standard library only)

Every ``reports/<name>.json`` is read (its page is ``reports/pages/<name>.md``). The question and the headline
come from the JSON's own ``question`` / ``headline`` keys when it has them, else from this module's table
for the built-in reports, else from the title of the report's Markdown file. The make target is the one
whose ``make help`` line names the report's folder.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

QUESTIONS = {
    "exploration": "Which view-selection strategy maps the table best within the view budget?",
    "association": "Which data association keeps one map object per true object?",
    "parameterization": "What does each estimation stage (iForest, line-alignment yaw, refinement) add?",
    "slam": "How accurate are the camera poses of the visual SLAM, against the noisy kinematics?",
    "grasping": "Can the arm grasp every object from the map it built?",
    "placement": "Can it do the paper's placement tasks from that map?",
    "scene_matching": "Are two maps of the same scene matched, and how many objects must they share?",
    "relocalisation": "Does a short query relocalise against a prior map at large parallax, by objects or by appearance?",
    "bench": "How fast are the core's stages, against reference libraries?",
    "foundation_run": "Where does the time of one episode go?",
    "features": "Does the core's ORB match OpenCV's repeatability, match precision and time under known warps?",
}


def _ok(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in rows if "error" not in r]


def _mean_by(rows: list[dict[str, Any]], key: str, value: str) -> dict[str, float]:
    groups: dict[str, list[float]] = defaultdict(list)
    for r in _ok(rows):
        if r.get(value) is not None:
            groups[r[key]].append(r[value])
    return {k: statistics.mean(v) for k, v in groups.items()}


def _exploration(d: dict[str, Any]) -> str:
    ok = _ok(d["rows"])
    seeds = len({r["seed"] for r in ok})
    # The headline is the test split when the report has one (judged without re-tuning).
    split = "test" if any(r.get("split") == "test" for r in ok) else None
    rows = [r for r in ok if r.get("split") == split] if split else ok
    iou = _mean_by(rows, "strategy", "iou3d")
    parts = ", ".join(f"{s} {v:.3f}" for s, v in sorted(iou.items(), key=lambda kv: -kv[1]))
    where = f"test split, {seeds} seed{'s' if seeds != 1 else ''}" if split else f"{seeds} seeds"
    line = f"mean 3D IoU ({where}): {parts}"
    best = max(iou, key=iou.get) if iou else None
    for p in d.get("paired", []):
        if (p["a"], p["b"], p["metric"], p["split"], p["at"]) == (best, "random", "iou3d", split, "end"):
            line += f"; {best} − random {p['mean_diff']:+.3f} [{p['ci_low']:+.3f}, {p['ci_high']:+.3f}] (n {p['n']})"
    return line


def _association(d: dict[str, Any]) -> str:
    est: dict[str, int] = defaultdict(int)
    gt: dict[str, int] = defaultdict(int)
    for r in _ok(d["rows"]):
        est[r["mode"]] += r["n_objects_est"]
        gt[r["mode"]] += r["n_objects_gt"]
    return "objects in the map / true objects: " + ", ".join(f"{m} {est[m]}/{gt[m]}" for m in est)


def _parameterization(d: dict[str, Any]) -> str:
    iou = _mean_by(d["rows"], "stage", "iou3d")
    return "mean 3D IoU per stage: " + " → ".join(f"{s} {v:.3f}" for s, v in iou.items())


def _slam(d: dict[str, Any]) -> str:
    online = _mean_by(d["rows"], "pose_source", "ate_rmse_m")
    final = _mean_by(d["rows"], "pose_source", "ate_final_rmse_m")
    return "ATE online / final: " + ", ".join(
        f"{s} {online[s] * 1000:.1f} / {final[s] * 1000:.1f} mm"
        if s in final
        else f"{s} {online[s] * 1000:.1f} mm"
        for s in online
    )


def _grasping(d: dict[str, Any]) -> str:
    n: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for r in d["rows"]:
        if r.get("skipped"):
            continue
        n[r["map_source"]][0] += bool(r["success"])
        n[r["map_source"]][1] += 1
    return "grasped: " + ", ".join(f"{s} {k}/{t}" for s, (k, t) in n.items())


def _placement(d: dict[str, Any]) -> str:
    n: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for r in d["rows"]:
        n[r["task"]][0] += bool(r["success"])
        n[r["task"]][1] += 1
    return "successful: " + ", ".join(f"{s} {k}/{t}" for s, (k, t) in n.items())


def _scene_matching(d: dict[str, Any]) -> str:
    rows = sorted(d["rows"], key=lambda r: -r["shared_ratio"])
    text = "success rate by shared-object ratio: " + ", ".join(
        f"{r['shared_ratio']:.2f} → {r['success_rate']:.3f}" for r in rows
    )
    sim = [p for p in d.get("sim_pairs", []) if isinstance(p, dict)]
    if sim:
        text += f"; maps of two simulator runs: {sum(bool(p.get('success')) for p in sim)}/{len(sim)} scenes"
    return text


def _relocalisation(d: dict[str, Any]) -> str:
    return "success rate by parallax: " + ", ".join(
        f"{r['parallax_bin']}° {r['method']} {r['successes']}/{r['trials']}" for r in d["rows"]
    )


def _bench(d: dict[str, Any]) -> str:
    e = d["entries"]
    keys = [k for k in ("track_frame", "associate_frame_20x10", "utility_100x12", "iforest_500") if k in e]
    return "median: " + ", ".join(f"{k} {e[k]['median_ms']:.2f} ms" for k in keys)


def _foundation_run(d: dict[str, Any]) -> str:
    t = d["timings_ms_median"]
    per_frame = ", ".join(f"{k} {v:.1f} ms" for k, v in t.items() if v is not None)
    b = d.get("frame_budget_ms_median") or {}
    budget = f"; core + sensor + record / render {b['ratio']:.2f}" if b.get("ratio") is not None else ""
    return (
        f"{d['strategy']} on {d['scene']}: mean 3D IoU {d['mean']['iou3d']:.3f}; "
        f"per frame (median): {per_frame}{budget}"
    )


def _ar(d: dict[str, Any]) -> str:
    s = d["summary"]
    return (
        f"occlusion mask IoU {s['mean_occlusion_iou']:.3f} (map only {s['mean_occlusion_iou_map']:.3f}, "
        f"naive overlay {s['mean_occlusion_iou_naive']:.3f}); "
        f"dropped objects' rest error (median) {s['median_rest_error_cm']:.2f} cm over {s['drops']} drops"
    )


def _sensor(d: dict[str, Any]) -> str:
    checks = d.get("checks") or []
    passed = sum(1 for c in checks if c.get("ok"))
    details = "; ".join(f"{c['name']}: {c['detail']}" for c in checks)
    return f"checks passed {passed}/{len(checks)}: {details}"


HEADLINES: dict[str, Callable[[dict[str, Any]], str]] = {
    "ar": _ar,
    "sensor": _sensor,
    "exploration": _exploration,
    "association": _association,
    "parameterization": _parameterization,
    "slam": _slam,
    "grasping": _grasping,
    "placement": _placement,
    "scene_matching": _scene_matching,
    "relocalisation": _relocalisation,
    "bench": _bench,
    "foundation_run": _foundation_run,
}


def make_targets(makefile: Path) -> dict[str, str]:
    """Report folder name → the make target whose help line names ``reports/<folder>``."""
    out: dict[str, str] = {}
    for line in makefile.read_text().splitlines():
        m = re.match(r"^([a-zA-Z_-]+):.*## .*reports/([a-z_]+)", line)
        if m and m.group(2) not in out:
            out[m.group(2)] = m.group(1)
    return out


def _title(md: Path) -> str | None:
    if not md.exists():
        return None
    for line in md.read_text().splitlines():
        if line.startswith("# "):
            return line[2:].strip()
    return None


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def world(data: dict) -> str:
    """The world preset(s) a report was made in: its own ``preset``, its resolved config's, or its
    rows'; a report made before the presets existed ran in the world the ``ideal`` preset keeps."""
    config = data.get("config") if isinstance(data.get("config"), dict) else {}
    found = data.get("preset") or config.get("preset")
    if found:
        return str(found)
    rows = data.get("rows") if isinstance(data.get("rows"), list) else []
    presets = sorted({str(r["preset"]) for r in rows if isinstance(r, dict) and r.get("preset")})
    if presets:
        return ", ".join(presets)
    return "ideal (predates presets)" if "provenance_note" in data else "?"


def entry(path: Path, reports: Path, targets: dict[str, str]) -> str:
    data = json.loads(path.read_text())
    name = path.stem
    md = reports / "pages" / f"{name}.md"
    question = data.get("question") or QUESTIONS.get(name) or _title(md) or name
    try:
        headline = data.get("headline") or (HEADLINES[name](data) if name in HEADLINES else "see the report")
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as e:
        headline = f"see the report (no headline: {type(e).__name__} {e})"
    target = targets.get(name)
    command = f"`make {target}`" if target else f"`{data.get('command', '?')}`"
    commit = str(data.get("commit", "?"))
    commit = commit[:7] + ("-dirty" if commit.endswith("-dirty") else "")
    link = md.relative_to(reports).as_posix() if md.exists() else path.relative_to(reports).as_posix()
    if "provenance_note" in data:
        commit += " (backfilled)"
    return f"| [{name}]({link}) | {_cell(question)} | {_cell(headline)} | {_cell(world(data))} | {command} | {commit} |"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reports", default=str(REPO / "reports"))
    a = ap.parse_args(argv)
    reports = Path(a.reports)
    targets = make_targets(REPO / "Makefile")
    files = sorted(reports.glob("*.json"), key=lambda p: p.stem)
    lines = [
        "# Reports",
        "",
        "Generated by `make reports-index` (`experiments/report_index.py`) from the JSON of each report; do not",
        "edit by hand. Each report's JSON records the `commit`, `command`, `machine` and resolved `config` it was",
        'made with; its Markdown names the run folders. "backfilled": the report predates that record, and its',
        "provenance was reconstructed from git history (its `provenance_note` says how). One-off experiments are",
        "in [`studies/`](../studies/README.md).",
        "",
        "| report | question | headline | world | made by | commit |",
        "|---|---|---|---|---|---|",
        *(entry(p, reports, targets) for p in files),
        "",
    ]
    (reports / "README.md").write_text("\n".join(lines))
    print(f"{len(files)} reports → {reports / 'README.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
