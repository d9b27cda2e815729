"""``make reloc``: relocalisation of short query trajectories against a prior map, binned by
parallax, object-level vs appearance-based → ``reports/relocalisation.json`` (page
``reports/pages/relocalisation.md``).

Per scene (the realistic world, one SAPIEN process, scenes one after another):

1. Prior: one object-driven exploration episode (run seed ``--seed``) of the 4 Init views and
   ``--prior-views`` next-best views (default 3: a prior that has not seen the scene from every side,
   so that queries can have large parallax to it); its run folder keeps the map
   and ``keyframes.npz`` (:class:`objslam.reloc.KeyframeRecorder`: grey, depth and estimated pose of
   every frame that moved ≥ 5 cm or turned ≥ 10° since the last kept one).
2. Query pool: in a fresh world of the same scene (another session: run seed ``--seed`` + 1000, its
   own arm errors and sensor and detector noise), the hand camera is placed on rings around the
   table centre looking at it (:data:`RINGS`: elevations 5°, 10°, 25°, 50°, 70°; poses the arm cannot
   reach are skipped) and one frame is rendered and detected at each.
3. Trials: a query trajectory is ``--keyframes`` consecutive reachable poses of a ring (4-6 cm
   apart) from every start on every ring. Its parallax is the smallest angle between the optical axis of one of
   its frames and that of the nearest prior frame (true poses; it only bins the trial).
   - *objects*: the query frames fused by the same per-frame system as the episode (a fresh mapper:
     association, parameterization, SLAM tracking) into an object map, moved by a random similarity
     (yaw uniform, scale log-uniform in [0.5, 2], translation uniform in ±1 m, seeded by ``--seed``,
     the scene and the trial), relocalised by ``objslam.match_maps(prior, query)``.
   - *appearance*: each query frame relocalised against the prior keyframes by ORB features
     (exhaustive matching, 3D–3D RANSAC, robust refinement; ``objslam_core::slam::relocalise``);
     the frame with the most inliers gives the query camera in the prior's frame, composed with the
     query session's own pose of that frame into the same similarity.
   Success as in the scene-matching report: rotation error < 5° and translation error < 5 cm
   (‖t_est − t_true‖ / s_true). Rows per parallax bin and method with the Wilson 95 % interval.
4. The paper's hypothesis (low rates come from objects observed incompletely from few keyframes):
   the same trials extended to each of ``--more-keyframes`` frames by the reachable poses of their ring
   nearest in azimuth (where the ring has that many), binned by the base trial's parallax, with the share of true objects the query map holds
   (``observed_fraction``).

Every scene's query maps, similarities and appearance estimates are kept in
``runs/reloc/<scene>_seed<seed>.json``; ``--rematch`` takes them from there and runs only the object
matching again (for work on the matcher).

``--reuse`` takes the prior run folders listed in the existing report when they are complete, else
the newest complete one of the scene and seed under ``runs/`` that has ``keyframes.npz``.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import objslam
from benchmark import scene_split
from objslam import _native
from objslam.cli import HelpFormatter
from objslam.config import load_run_config, to_dict
from objslam.provenance import provenance, report_files
from objslam.reloc import (
    ROT_OK_DEG,
    TRANS_OK_CM,
    KeyframeRecorder,
    Ring,
    appearance_poses,
    build_query_map,
    parallax_deg,
    render_pool,
    wilson,
)
from objslam.scene import gt_objects, load_scene
from objslam.topo import similarity_matrix, transform_errors, transform_map_json

REPO = Path(__file__).resolve().parents[1]
RINGS = [
    Ring(5.0, 0.65, 5.0),
    Ring(10.0, 0.60, 5.0),
    Ring(25.0, 0.50, 5.0),
    Ring(50.0, 0.50, 10.0),
    Ring(70.0, 0.45, 20.0),
]
"""Query rings (elevation °, distance m, azimuth step °): the steps move the camera 4-6 cm between
neighbouring poses on every ring."""
QUERY_SEED_OFFSET = 1000
BINS = [(0.0, 20.0), (20.0, 50.0), (50.0, 100.0)]
METHODS = ("objects", "appearance")


def bin_name(lo: float, hi: float) -> str:
    return f"{lo:.0f}-{hi:.0f}"


def bin_of(parallax: float) -> str | None:
    for lo, hi in BINS:
        if lo <= parallax < hi:
            return bin_name(lo, hi)
    return None


def _rel(p: Path) -> str:
    return str(p.relative_to(REPO)) if p.is_relative_to(REPO) else str(p)


def _complete(run_dir: Path) -> bool:
    status = run_dir / "status.json"
    return (
        status.exists()
        and json.loads(status.read_text()).get("status") == "complete"
        and (run_dir / "map.json").exists()
        and (run_dir / "keyframes.npz").exists()
    )


def _latest_prior(scene_name: str, seed: int, prior_views: int) -> Path | None:
    """The newest complete prior run folder (with keyframes) of a scene, seed and view budget under
    ``runs/``."""
    import tomllib

    runs = sorted((REPO / "runs").glob(f"*/*_object-driven_{scene_name}_{seed}*"), reverse=True)
    for r in runs:
        config = r / "config.toml"
        if (
            _complete(r)
            and config.exists()
            and tomllib.loads(config.read_text())["explore"]["max_views"] == prior_views
        ):
            return r
    return None


def prior_episode(scene: str, seed: int, reuse: Path | None, prior_views: int = 3) -> Path:
    """The prior's run folder: reused when complete, else a new object-driven episode."""
    if reuse is not None and _complete(reuse):
        print(f"  prior: reusing {_rel(reuse)}", flush=True)
        return reuse
    from objslam.episode import run_episode

    cfg = load_run_config(
        overrides=[
            f'scene="{scene}"',
            f"seed={seed}",
            f"explore.max_views={prior_views}",
            "record.enabled=false",
        ],
        strategy="object-driven",
    )
    keyframes = KeyframeRecorder()
    t0 = time.perf_counter()
    result = run_episode(cfg, progress=False, on_fused=keyframes)
    keyframes.save(result.run_dir / "keyframes.npz")
    print(
        f"  prior: {_rel(result.run_dir)} ({result.metrics['frames']} frames, {len(keyframes.grey)} keyframes, "
        f"{result.metrics['n_objects_est']} objects, {time.perf_counter() - t0:.0f} s)",
        flush=True,
    )
    return result.run_dir


def _estimate_appearance(
    frames: list[int], app: list[dict[str, Any]], query_poses: list[np.ndarray], truth: np.ndarray
) -> np.ndarray | None:
    """query_from_prior from the trial frame that relocalised with the most inliers."""
    ok = [(app[f]["inliers"], i) for i, f in enumerate(frames) if app[f]["ok"]]
    if not ok:
        return None
    _, i = max(ok)
    prior_from_camera = np.asarray(app[frames[i]]["world_from_camera"], dtype=np.float64)
    return truth @ query_poses[i] @ np.linalg.inv(prior_from_camera)


def _score(estimate: np.ndarray | None, truth: np.ndarray) -> dict[str, Any]:
    if estimate is None:
        return {"matched": False, "rotation_error_deg": None, "translation_error_cm": None, "success": False}
    e = transform_errors(estimate, truth)
    return {
        "matched": True,
        "rotation_error_deg": e["rotation_deg"],
        "translation_error_cm": e["translation_cm"],
        "success": e["rotation_deg"] < ROT_OK_DEG and e["translation_cm"] < TRANS_OK_CM,
    }


def scene_trials(
    scene_path: str,
    index: int,
    seed: int,
    ks: list[int],
    reuse: Path | None,
    max_trials: int | None,
    prior_views: int = 3,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Prior, query pool and every trial's query map and appearance estimate of one scene."""
    scene = load_scene(REPO / scene_path)
    prior_dir = prior_episode(scene_path, seed, reuse, prior_views)
    keyframes = dict(np.load(prior_dir / "keyframes.npz"))
    prior_json = (prior_dir / "map.json").read_text()
    qseed = seed + QUERY_SEED_OFFSET
    cfg = load_run_config(overrides=[f'scene="{scene_path}"', f"seed={qseed}"], strategy="object-driven")
    t0 = time.perf_counter()
    pool = render_pool(cfg, scene, RINGS, qseed)
    gt_json = json.dumps(gt_objects(scene))
    t_pool = time.perf_counter() - t0
    t0 = time.perf_counter()
    app = appearance_poses(keyframes, pool)
    t_app = time.perf_counter() - t0
    print(
        f"  pool: {len(pool)} frames ({t_pool:.0f} s); appearance: {sum(a['ok'] for a in app)}/{len(pool)} frames "
        f"relocalised ({t_app:.0f} s)",
        flush=True,
    )
    axes = np.asarray(keyframes["axes_gt"], dtype=np.float64)
    par = [parallax_deg(p.world_from_camera_gt, axes) for p in pool]
    where = {(p.ring, round(p.azimuth_deg)): i for i, p in enumerate(pool)}
    starts = []
    for (ring, az), i in sorted(where.items()):
        step = round(RINGS[ring].azimuth_step_deg)
        base = [where.get((ring, (az + j * step) % 360)) for j in range(ks[0])]
        if any(r is None for r in base):
            continue
        # Longer queries: the base frames, then the ring's other frames nearest to the base's middle.
        mid = az + (ks[0] - 1) * step / 2
        rest = sorted(
            (j for (rg, a_), j in where.items() if rg == ring and j not in base),
            key=lambda j: (abs((pool[j].azimuth_deg - mid + 180) % 360 - 180), pool[j].azimuth_deg),
        )
        starts.append(base + rest)
    if max_trials is not None and len(starts) > max_trials:
        starts = random.Random(seed * 7919 + index).sample(starts, max_trials)
    queries = []
    t0 = time.perf_counter()
    for ti, run in enumerate(starts):
        base = run[: ks[0]]
        parallax = min(par[f] for f in base)
        rng = random.Random((seed * 1000 + index) * 100_000 + ti)
        yaw = rng.uniform(-math.pi, math.pi)
        scale = math.exp(rng.uniform(math.log(0.5), math.log(2.0)))
        t = [rng.uniform(-1.0, 1.0) for _ in range(3)]
        truth = similarity_matrix(yaw, t, scale)
        for k in ks:
            if len(run) < k:
                continue
            frames = run[:k]
            query_raw, poses = build_query_map(cfg, scene, [pool[f] for f in frames])
            ev = json.loads(_native.evaluate_map(gt_json, query_raw, None))
            est = _estimate_appearance(frames, app, poses, truth)
            queries.append(
                {
                    "scene": scene.name,
                    "trial": ti,
                    "query_keyframes": k,
                    "ring": pool[run[0]].ring,
                    "start_azimuth_deg": pool[run[0]].azimuth_deg,
                    "parallax_deg": parallax,
                    "parallax_bin": bin_of(parallax),
                    "query_objects": len(json.loads(query_raw)["objects"]),
                    "observed_fraction": ev["n_matched"] / max(1, ev["n_objects_gt"]),
                    "similarity": {"yaw": yaw, "translation": t, "scale": scale},
                    "query_map": json.loads(query_raw),
                    "appearance": None if est is None else est.tolist(),
                }
            )
    print(f"  queries: {len(starts)} × {ks} keyframes ({time.perf_counter() - t0:.0f} s)", flush=True)
    info = {
        "scene": scene.name,
        "prior_run": _rel(prior_dir),
        "prior_keyframes": len(keyframes["grey"]),
        "prior_frames": len(axes),
        "prior_objects": len(json.loads(prior_json)["objects"]),
        "pool_frames": len(pool),
        "appearance_frames_relocalised": int(sum(a["ok"] for a in app)),
        "trials": len(starts),
    }
    return info, queries


def match_queries(prior_json: str, queries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Both methods' trial records of a scene's queries: the object map matched against the prior
    now, the appearance estimate as the query pool gave it."""
    trials = []
    for q in queries:
        sim = q["similarity"]
        truth = similarity_matrix(sim["yaw"], sim["translation"], sim["scale"])
        common = {k: v for k, v in q.items() if k not in ("similarity", "query_map", "appearance")}
        common["split"] = scene_split(q["scene"])
        moved = transform_map_json(json.dumps(q["query_map"]), sim["yaw"], sim["translation"], sim["scale"])
        r = objslam.match_maps(prior_json, moved)
        obj = _score(np.asarray(r["matrix"]) if r["matched"] else None, truth)
        trials.append({**common, "method": "objects", **obj, "reason": r["reason_kind"]})
        est = None if q["appearance"] is None else np.asarray(q["appearance"], dtype=np.float64)
        trials.append({**common, "method": "appearance", **_score(est, truth), "reason": None})
    return trials


def rows_of(trials: list[dict[str, Any]], k: int, split: str | None = None) -> list[dict[str, Any]]:
    """Per parallax bin and method: trials, successes, rate and Wilson interval of the ``k``-keyframe
    queries (of one split, or all)."""
    trials = [t for t in trials if split is None or t["split"] == split]
    rows = []
    for lo, hi in BINS:
        name = bin_name(lo, hi)
        for method in METHODS:
            sel = [
                t
                for t in trials
                if t["parallax_bin"] == name and t["method"] == method and t["query_keyframes"] == k
            ]
            n, s = len(sel), sum(t["success"] for t in sel)
            lo_ci, hi_ci = wilson(s, n)
            rows.append(
                {
                    **({} if split is None else {"split": split}),
                    "parallax_bin": name,
                    "method": method,
                    "query_keyframes": k,
                    "trials": n,
                    "successes": s,
                    "success_rate": s / n if n else None,
                    "ci_low": lo_ci,
                    "ci_high": hi_ci,
                    "observed_fraction": float(np.mean([t["observed_fraction"] for t in sel]))
                    if sel
                    else None,
                }
            )
    return rows


def _pct(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.1f}"


def markdown(report: dict[str, Any]) -> str:
    p = report["protocol"]
    lines = [
        "# Relocalisation under parallax",
        "",
        f"Generated by `{report['command']}` (do not edit by hand) at commit `{report['commit']}`.",
        "",
        (
            f"Prior: one object-driven exploration episode per scene (realistic world, run seed {p['seed']}, "
            f"4 Init views + {p['prior_views']} next-best views). "
            f"Query: {p['keyframes']} consecutive hand-camera poses (4-6 cm apart on a ring around the table) "
            "rendered in another session of the same robot, fused by the same per-frame system into an object "
            "map and moved by a random similarity. *objects*: topological scene matching of the query map "
            "against the prior map; *appearance*: ORB relocalisation of each query frame against the prior's "
            "keyframes (exhaustive matching, 3D–3D RANSAC, robust refinement; the frame with most inliers). "
            f"Success: rotation error < {ROT_OK_DEG:.0f}° and translation error < {TRANS_OK_CM:.0f} cm. Parallax: "
            "smallest angle between a query frame's optical axis and the nearest prior frame's. Interval: Wilson 95 %."
        ),
        "",
        f"Scenes: {', '.join(s['scene'] for s in report['scenes'])}.",
        "",
        "| parallax (°) | method | trials | successes | success rate (%) | 95 % CI (%) | true objects in query map (%) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['parallax_bin']} | {r['method']} | {r['trials']} | {r['successes']} | {_pct(r['success_rate'])} | "
            f"{_pct(r['ci_low'])}–{_pct(r['ci_high'])} | {_pct(r['observed_fraction'])} |"
        )
    if report["hypothesis_rows"]:
        lines += [
            "",
            "## More query keyframes (observation completeness)",
            "",
            (
                "The same trials extended along their ring (binned by the parallax of their first "
                f"{p['keyframes']} frames): success against the number of query keyframes and the share of "
                "true objects the query map holds."
            ),
            "",
            "| parallax (°) | method | query keyframes | trials | success rate (%) | 95 % CI (%) | true objects in query map (%) |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in sorted(
            report["rows"] + report["hypothesis_rows"],
            key=lambda r: (r["parallax_bin"], r["method"], r["query_keyframes"]),
        ):
            lines.append(
                f"| {r['parallax_bin']} | {r['method']} | {r['query_keyframes']} | {r['trials']} | "
                f"{_pct(r['success_rate'])} | {_pct(r['ci_low'])}–{_pct(r['ci_high'])} | {_pct(r['observed_fraction'])} |"
            )
    if report.get("split_rows"):
        lines += [
            "",
            "## By split",
            "",
            "The matcher's settings are tuned on the hard suite; the test split is judged without re-tuning.",
            "",
            "| split | parallax (°) | method | query keyframes | trials | success rate (%) | 95 % CI (%) |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in report["split_rows"]:
            if r["trials"]:
                lines.append(
                    f"| {r['split']} | {r['parallax_bin']} | {r['method']} | {r['query_keyframes']} | {r['trials']} | "
                    f"{_pct(r['success_rate'])} | {_pct(r['ci_low'])}–{_pct(r['ci_high'])} |"
                )
    lines += [
        "",
        "## Scenes",
        "",
        "| scene | prior run | prior frames / keyframes / objects | query pool frames | frames relocalised by appearance | trials |",
        "|---|---|---|---|---|---|",
    ]
    for s in report["scenes"]:
        lines.append(
            f"| {s['scene']} | `{s['prior_run']}` | {s['prior_frames']} / {s['prior_keyframes']} / {s['prior_objects']} | "
            f"{s['pool_frames']} | {s['appearance_frames_relocalised']} | {s['trials']} |"
        )
    lines += ["", f"Machine: {report['machine']}.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument(
        "--scenes",
        nargs="*",
        default=None,
        help="scene files (default: scenes/hard/*.toml and scenes/test/*.toml)",
    )
    ap.add_argument("--seed", type=int, default=0, help="run seed of the prior episodes (queries: +1000)")
    ap.add_argument(
        "--prior-views",
        type=int,
        default=3,
        help="next-best views of the prior episode after its 4 Init views",
    )
    ap.add_argument("--keyframes", type=int, default=3, help="query keyframes of a trial")
    ap.add_argument(
        "--more-keyframes", type=int, nargs="*", default=[6], help="longer queries for the hypothesis rows"
    )
    ap.add_argument(
        "--max-trials", type=int, default=None, help="at most this many trials per scene (seeded draw)"
    )
    ap.add_argument(
        "--reuse",
        action="store_true",
        help="reuse complete prior run folders (the report's, else the newest in runs/)",
    )
    ap.add_argument(
        "--rematch",
        action="store_true",
        help="take each scene's query maps and appearance estimates from runs/reloc/<scene>_seed<seed>.json "
        "(written by every full run; the scene's record keeps the commit that made them) and run only the "
        "object matching again",
    )
    ap.add_argument("--out", default="reports", help="report folder")
    a = ap.parse_args(argv)
    scenes = a.scenes or [
        _rel(p)
        for p in [
            *sorted((REPO / "scenes/hard").glob("*.toml")),
            *sorted((REPO / "scenes/test").glob("*.toml")),
        ]
    ]
    out = REPO / a.out if not Path(a.out).is_absolute() else Path(a.out)
    json_path, md_path = report_files(out, "relocalisation")
    previous: dict[str, str] = {}
    if a.reuse and json_path.exists():
        previous = {s["scene"]: s["prior_run"] for s in json.loads(json_path.read_text()).get("scenes", [])}
    ks = [a.keyframes, *sorted(k for k in set(a.more_keyframes) if k > a.keyframes)]
    protocol = {
        "seed": a.seed,
        "query_seed": a.seed + QUERY_SEED_OFFSET,
        "keyframes": a.keyframes,
        "more_keyframes": ks[1:],
        "max_trials": a.max_trials,
        "rings": [
            {
                "elevation_deg": r.elevation_deg,
                "distance_m": r.distance_m,
                "azimuth_step_deg": r.azimuth_step_deg,
            }
            for r in RINGS
        ],
        "prior_views": a.prior_views,
        "bins_deg": BINS,
        "similarity": "yaw uniform [-180, 180) deg, scale log-uniform [0.5, 2], translation uniform [-1, 1]^3 m",
        "success": f"rotation error < {ROT_OK_DEG} deg and |t_est - t_true| / s_true < {TRANS_OK_CM} cm",
        "scenes": scenes,
        "run_config": to_dict(load_run_config(strategy="object-driven")),
    }
    argv_list = ["python", "experiments/reloc.py", *(argv if argv is not None else sys.argv[1:])]
    prov = provenance(argv_list, protocol)  # the code and tree the run starts from
    infos, trials = [], []
    for i, scene in enumerate(scenes):
        name = Path(scene).stem
        print(f"{name}:", flush=True)
        reuse = (
            REPO / previous[name]
            if name in previous
            else (_latest_prior(name, a.seed, a.prior_views) if a.reuse else None)
        )
        cache = REPO / "runs" / "reloc" / f"{name}_seed{a.seed}.json"
        key = {"ks": ks, "max_trials": a.max_trials, "prior_views": a.prior_views}
        stored = json.loads(cache.read_text()) if a.rematch and cache.exists() else None
        if stored is not None and stored["key"] == key:
            info, queries = stored["info"], stored["queries"]
            print(f"  queries: {len(queries)} from {_rel(cache)} (commit {stored['commit']})", flush=True)
        else:
            info, queries = scene_trials(scene, i, a.seed, ks, reuse, a.max_trials, a.prior_views)
            info["queries_commit"] = prov["commit"]
            cache.parent.mkdir(parents=True, exist_ok=True)
            tmp = cache.with_suffix(".tmp")
            tmp.write_text(json.dumps({"commit": prov["commit"], "key": key, "info": info, "queries": queries}))
            tmp.replace(cache)
        infos.append(info)
        trials.extend(match_queries((REPO / info["prior_run"] / "map.json").read_text(), queries))
    report = {
        **prov,
        "protocol": protocol,
        "scenes": infos,
        "rows": rows_of(trials, a.keyframes),
        "hypothesis_rows": [r for k in ks[1:] for r in rows_of(trials, k)],
        "split_rows": [r for k in ks for split in ("hard", "test") for r in rows_of(trials, k, split)],
        "trials": trials,
    }
    json_path.write_text(json.dumps(report, indent=1) + "\n")
    md_path.write_text(markdown(report))
    for r in report["rows"]:
        print(
            f"{r['parallax_bin']:>7} {r['method']:<10} {r['successes']:>4}/{r['trials']:<4} "
            f"{_pct(r['success_rate'])} % [{_pct(r['ci_low'])}, {_pct(r['ci_high'])}]"
        )
    print(f"wrote {_rel(json_path)} and {_rel(md_path)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
