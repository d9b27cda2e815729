"""Scene matching, part (b): maps from two simulator runs of the same scene along different camera
paths, matched against each other with a known similarity applied to the query map.

``python experiments/match_sim.py [--scenes S ...] [--seed N] [--reuse] [--out reports]``

Per scene, two episodes (one at a time):

- prior run: strategy ``init`` (the paper's four top views over the table corners), run seed 0, the
  default Init geometry (0.5 m high, corners inset 0.3 m, tilted 20° towards the centre);
- query run: strategy ``init``, run seed 1, other Init views (0.42 m high, corners inset 0.22 m,
  tilted 32°): a different camera path (other viewpoints, other depth / detector / pose noise).

The query run's ``map.json`` is moved by a random similarity q = s R_z(yaw) p + t (seeded by
``--seed`` and the scene: yaw uniform in [-180°, 180°), s log-uniform in [0.5, 2], t uniform in
[-1, 1]³ m), then ``objslam.match_maps(prior, moved query)``. Both maps are in the robot-base frame
(forward-kinematics camera poses), so the known similarity is the truth up to the maps' own errors.
Errors as in part (a): rotation angle, ‖t_est − t_true‖ / s_true (cm, prior-map units), relative
scale; success = rotation < 5° and translation < 5 cm. Inlier pairs are checked against ground
truth through each run's evaluation (``metrics.json`` objects: ``gt_id`` ↔ ``est_id``).

The result is merged into ``reports/scene_matching.json`` (keys ``sim_pairs``,
``sim_pairs_protocol``, ``sim_pairs_command``; part (a)'s ``rows`` are kept) and into the section
of ``reports/pages/scene_matching.md`` between the ``sim_pairs`` markers (``make match`` keeps both).
``--reuse`` takes the run folders listed in the existing report when they are still complete.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import shlex
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

import objslam
from objslam.cli import HelpFormatter
from objslam.provenance import provenance, report_files
from objslam.sweep import Job, run_job
from objslam.topo import similarity_matrix, transform_errors, transform_map_json

PRIOR = {"strategy": "init", "seed": 0, "overrides": ()}
QUERY = {
    "strategy": "init",
    "seed": 1,
    "overrides": ("explore.init_height_m=0.42", "explore.init_inset_m=0.22", "explore.init_tilt_deg=32.0"),
}
ROT_OK_DEG, TRANS_OK_CM = 5.0, 5.0
BEGIN, END = "<!-- sim_pairs:begin -->", "<!-- sim_pairs:end -->"


def _complete(run_dir: Path) -> bool:
    status = run_dir / "status.json"
    return (
        status.exists()
        and json.loads(status.read_text()).get("status") == "complete"
        and (run_dir / "map.json").exists()
    )


def _episode(scene: str, spec: dict[str, Any], reuse: Path | None) -> Path:
    if reuse is not None and _complete(reuse):
        print(f"  reusing {reuse}", flush=True)
        return reuse
    job = Job(scene=scene, strategy=spec["strategy"], seed=spec["seed"], overrides=tuple(spec["overrides"]))
    print(
        f"  episode {Path(scene).stem} {spec['strategy']} seed {spec['seed']} {' '.join(spec['overrides'])}",
        flush=True,
    )
    r = run_job(job)
    if "error" in r:
        raise RuntimeError(f"{scene}: episode failed: {r['error']}")
    return REPO / r["run_dir"]


def _gt_of(run_dir: Path) -> dict[int, int]:
    """est id → gt id from the run's evaluation."""
    metrics = json.loads((run_dir / "metrics.json").read_text())
    return {o["est_id"]: o["gt_id"] for o in metrics.get("objects", []) if o.get("est_id") is not None}


def _rel(p: Path) -> str:
    return str(p.relative_to(REPO)) if p.is_relative_to(REPO) else str(p)


def pair(
    scene: str, index: int, seed: int, config_json: str | None, reuse: dict[str, Any] | None
) -> dict[str, Any]:
    prior_dir = _episode(scene, PRIOR, REPO / reuse["prior_run"] if reuse else None)
    query_dir = _episode(scene, QUERY, REPO / reuse["query_run"] if reuse else None)
    prior_json = (prior_dir / "map.json").read_text()
    query_raw = (query_dir / "map.json").read_text()
    rng = random.Random(seed * 1000 + index)
    yaw = rng.uniform(-math.pi, math.pi)
    scale = math.exp(rng.uniform(math.log(0.5), math.log(2.0)))
    t = [rng.uniform(-1.0, 1.0) for _ in range(3)]
    truth = similarity_matrix(yaw, t, scale)
    query_json = transform_map_json(query_raw, yaw, t, scale)
    r = objslam.match_maps(prior_json, query_json, config_json)
    gt_p, gt_q = _gt_of(prior_dir), _gt_of(query_dir)
    shared_gt = set(gt_p.values()) & set(gt_q.values())
    out: dict[str, Any] = {
        "scene": Path(scene).stem,
        "prior_run": _rel(prior_dir),
        "query_run": _rel(query_dir),
        "prior_objects": len(json.loads(prior_json)["objects"]),
        "query_objects": len(json.loads(query_raw)["objects"]),
        "shared_gt_objects": len(shared_gt),
        "truth": {"yaw_deg": math.degrees(yaw), "translation_m": t, "scale": scale},
        "matched": r["matched"],
        "reason": r["reason"],
        "inliers": len(r["inliers"]),
        "correct_inlier_pairs": sum(1 for p, q, _ in r["inliers"] if p in gt_p and gt_p[p] == gt_q.get(q)),
        "wrong_inlier_pairs": sum(
            1 for p, q, _ in r["inliers"] if p in gt_p and q in gt_q and gt_p[p] != gt_q[q]
        ),
        "confidence": r["confidence"],
        "rms_residual_cm": None if r["rms_residual"] is None else r["rms_residual"] * 100.0,
    }
    if r["matched"]:
        e = transform_errors(r["matrix"], truth)
        out.update(
            rotation_error_deg=e["rotation_deg"],
            translation_error_cm=e["translation_cm"],
            scale_error_pct=e["scale_pct"],
            success=e["rotation_deg"] < ROT_OK_DEG and e["translation_cm"] < TRANS_OK_CM,
        )
    else:
        out.update(rotation_error_deg=None, translation_error_cm=None, scale_error_pct=None, success=False)
    return out


def _f(v: float | None, spec: str) -> str:
    return "–" if v is None else format(v, spec)


def markdown(pairs: list[dict[str, Any]], command: str) -> str:
    lines = [
        BEGIN,
        "## Maps from two simulator runs (part b, `sim_pairs`)",
        "",
        f"Generated by `{command}` (do not edit by hand).",
        "",
        (
            "Per scene: prior map = strategy `init`, run seed 0, default Init views (0.5 m high, corners inset 0.3 m, "
            "tilt 20°); query map = strategy `init`, run seed 1, other Init views (0.42 m, inset 0.22 m, tilt 32°), "
            "then moved by a random similarity (yaw uniform, scale log-uniform 0.5–2, translation uniform ±1 m); "
            "`objslam.match_maps(prior, query)` with the default `MatchConfig`. Errors against the known similarity; "
            "translation error = ‖t_est − t_true‖ / s_true (prior-map metres, at the robot base); success = < 5° and "
            "< 5 cm. *correct* = inlier pairs whose two objects are matched to the same ground-truth object by "
            "each run's evaluation, *wrong* = both matched to different ones (the rest involve a map object the "
            "evaluation left unmatched: a duplicate or fragment of an object, or a false detection); "
            "*shared GT* = ground-truth objects found in both maps."
        ),
        "",
        (
            "| scene | prior + query objects | shared GT | matched | inliers (correct / wrong) | rot err (°) | trans err (cm) "
            "| scale err (%) | rms residual (cm) | confidence | success |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in pairs:
        lines.append(
            f"| {p['scene']} | {p['prior_objects']}+{p['query_objects']} | {p['shared_gt_objects']} | "
            f"{'yes' if p['matched'] else 'no: ' + str(p['reason'])} | {p['inliers']} ({p['correct_inlier_pairs']} / {p['wrong_inlier_pairs']}) | "
            f"{_f(p['rotation_error_deg'], '.2f')} | {_f(p['translation_error_cm'], '.2f')} | "
            f"{_f(p['scale_error_pct'], '.2f')} | {_f(p['rms_residual_cm'], '.2f')} | {p['confidence']:.2f} | "
            f"{'yes' if p['success'] else 'no'} |"
        )
    ok = [p for p in pairs if p["matched"]]
    if ok:
        med = sorted(p["rotation_error_deg"] for p in ok)[len(ok) // 2]
        medt = sorted(p["translation_error_cm"] for p in ok)[len(ok) // 2]
        lines += [
            "",
            (
                f"Matched {len(ok)}/{len(pairs)}, successes {sum(p['success'] for p in pairs)}/{len(pairs)}; "
                f"median rotation error {med:.2f}°, median translation error {medt:.2f} cm."
            ),
        ]
    lines.append(END)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--scenes", nargs="*", default=None, help="scene files (default: scenes/scene*.toml)")
    ap.add_argument("--seed", type=int, default=2026, help="seed of the random similarities")
    ap.add_argument("--config-json", default=None, help="partial MatchConfig JSON (default: the defaults)")
    ap.add_argument("--reuse", action="store_true", help="reuse the run folders of the existing report")
    ap.add_argument("--out", default="reports", help="report folder")
    a = ap.parse_args(argv)
    scenes = a.scenes or [_rel(p) for p in sorted((REPO / "scenes").glob("scene*.toml"))]
    out = REPO / a.out if not Path(a.out).is_absolute() else Path(a.out)
    json_path, md_path = report_files(out, "scene_matching")
    if not json_path.exists() or not md_path.exists():
        print(f"{json_path} / {md_path} missing: run `make match` (part a) first", file=sys.stderr)
        return 2
    report = json.loads(json_path.read_text())
    previous = {p["scene"]: p for p in report.get("sim_pairs", []) if isinstance(p, dict)} if a.reuse else {}
    pairs = []
    for i, scene in enumerate(scenes):
        name = Path(scene).stem
        print(f"{name}:", flush=True)
        p = pair(scene, i, a.seed, a.config_json, previous.get(name))
        print(
            f"  matched={p['matched']} inliers={p['inliers']} ({p['correct_inlier_pairs']} correct, "
            f"{p['wrong_inlier_pairs']} wrong) "
            f"rot={_f(p['rotation_error_deg'], '.2f')} deg trans={_f(p['translation_error_cm'], '.2f')} cm",
            flush=True,
        )
        pairs.append(p)
    command = "python experiments/match_sim.py" + "".join(
        f" {shlex.quote(x)}" for x in (argv if argv is not None else sys.argv[1:])
    )
    report["sim_pairs"] = pairs
    report["sim_pairs_protocol"] = {
        "prior": {**PRIOR, "overrides": list(PRIOR["overrides"])},
        "query": {**QUERY, "overrides": list(QUERY["overrides"])},
        "similarity": "yaw uniform [-180, 180) deg, scale log-uniform [0.5, 2], translation uniform [-1, 1]^3 m",
        "seed": a.seed,
        "config_json": a.config_json,
        "success": "rotation error < 5 deg and |t_est - t_true| / s_true < 5 cm",
    }
    report["sim_pairs_command"] = command
    report["sim_pairs_provenance"] = provenance(command, report["sim_pairs_protocol"])
    json_path.write_text(json.dumps(report, indent=2) + "\n")
    md = md_path.read_text()
    section = markdown(pairs, command)
    if BEGIN in md and END in md:
        md = md[: md.index(BEGIN)] + section + md[md.index(END) + len(END) :]
    else:
        md = md.rstrip("\n") + "\n\n" + section + "\n"
    md_path.write_text(md)
    print(f"wrote {_rel(json_path)} and {_rel(md_path)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
