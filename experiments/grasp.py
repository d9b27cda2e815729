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
``--maps-from-benchmark <out>/exploration.json`` maps nothing: it grasps on an exploration sweep's
object-driven and init run folders, so the grasp and exploration reports describe the same maps.

Reports (from the session files): ``<out>/grasping.json`` = {"command", "sessions", "rows":
[{"scene", "seed", "object", "class", "map_source", "success", "cause", ...}]} and
``<out>/grasping.md``: success overall, per class, per scene, failure causes, per map source.
One process, one simulator at a time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shlex
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import tomllib
from objslam.provenance import provenance, report_files
from objslam.reloc import wilson

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("estimated", "ground_truth", "init_only")
CAUSES = (
    "no_ik",
    "no_path",
    "too_wide",
    "collided",
    "missed",
    "slipped",
    "wrong_object",
    "phantom",
    "not_found",
    "not_in_map",
    "wrongly_skipped",
)


def perturb_centres(map_objects: list[dict], error_mm: float, seed: int) -> list[dict]:
    """The map with every object's centre moved ``error_mm`` in a horizontal direction drawn per
    object (seeded by the run seed and the object id): a map error of known size, to measure how
    much of it the grasp absorbs (``--centre-error-mm``). The sizes, yaws and heights are kept."""
    import numpy as np

    out = []
    for o in map_objects:
        theta = np.random.default_rng([seed, 11, int(o["id"])]).uniform(0.0, 2.0 * math.pi)
        c = list(o["geometry"]["center"])
        c[0] += 1e-3 * error_mm * math.cos(theta)
        c[1] += 1e-3 * error_mm * math.sin(theta)
        out.append({**o, "geometry": {**o["geometry"], "center": c}})
    return out


def _session(
    scene: Any,
    cfg: Any,
    map_objects: list[dict],
    source: str,
    run_dir: Path,
    gcfg: Any,
    tag: str,
    centre_error_mm: float = 0.0,
) -> Path:
    from objslam import _native
    from objslam.grasp import config_dict, run_grasp_session

    if centre_error_mm:
        map_objects = perturb_centres(map_objects, centre_error_mm, cfg.seed)
    t0 = time.perf_counter()
    rec = (
        _native.Recorder(str(run_dir / f"grasp_{source}{tag}.rrd"), "objslam-grasp")
        if cfg.record.enabled
        else None
    )
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
        "centre_error_mm": centre_error_mm,
        "rows": rows,
    }
    path = run_dir / f"grasp_{source}{tag}.json"
    path.write_text(json.dumps(out, indent=2) + "\n")
    return path


def _grasp_config(a: argparse.Namespace, source: str, cfg: Any) -> Any:
    """The run's ``[grasp]`` settings, re-observing when ``--reobserve`` names the map source."""
    return dataclasses.replace(cfg.grasp, reobserve=cfg.grasp.reobserve or source in a.reobserve)


def _map_objects(source: str, scene: Any, run_dir: Path) -> list[dict]:
    from objslam import _native
    from objslam.scene import gt_objects

    if source == "ground_truth":
        return [{**g, "n_observations": 0} for g in gt_objects(scene)]
    return json.loads(_native.map_objects_json(_native.load_map(str(run_dir / "map.json"))))


def _print_session(path: Path, note: str) -> None:
    d = json.loads(path.read_text())
    att = [r for r in d["rows"] if not r.get("skipped")]
    print(
        f"{d['scene']} seed {d['seed']} {d['map_source']:<12} {sum(r['success'] for r in att)}/{len(att)} "
        f"({note}grasping {d['wall_s']:.0f} s)",
        flush=True,
    )


def _write_manifest(sessions: list[str], command: str, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"command": command, "sessions": sessions}, indent=2) + "\n")


def regrasp(a: argparse.Namespace, command: str) -> list[str]:
    """Grasp sessions again on the maps of the sweep in ``runs/grasp_sweep.json`` (no new mapping)."""
    from objslam.config import load_run_config
    from objslam.scene import load_scene, scene_file

    old = json.loads(Path(a.maps_from).read_text())["sessions"]
    sessions: list[str] = []
    for p in old:
        d = json.loads(Path(p).read_text())
        if d["map_source"] not in a.sources or d["scene"] not in {Path(s).stem for s in a.scenes}:
            continue
        if d["seed"] not in a.seeds:
            continue
        run_dir = Path(d["map_run"])
        rel = scene_file(d["scene"], REPO)
        overrides = [*a.set, f'scene="{rel}"', f"seed={d['seed']}"]
        cfg = load_run_config(overlays=a.config, overrides=overrides, strategy="object-driven")
        scene = load_scene(REPO / rel)
        objs = _map_objects(d["map_source"], scene, run_dir)
        path = _session(
            scene,
            cfg,
            objs,
            d["map_source"],
            run_dir,
            _grasp_config(a, d["map_source"], cfg),
            a.tag,
            a.centre_error_mm,
        )
        sessions.append(str(path))
        _print_session(path, "reused map, ")
        _write_manifest(sessions, command, Path(a.manifest))
    return sessions


def _grasp_on(
    a: argparse.Namespace, scene: Any, cfg: Any, source: str, run_dir: Path, note: str
) -> str | None:
    """One grasp session of ``source`` on the map in ``run_dir``; its file, or None when it failed
    (said on stderr: one failed session never stops the sweep)."""
    try:
        objs = _map_objects(source, scene, run_dir)
        path = _session(
            scene, cfg, objs, source, run_dir, _grasp_config(a, source, cfg), a.tag, a.centre_error_mm
        )
    except Exception as e:  # noqa: BLE001 - one failed session never stops the sweep
        print(
            f"{scene.name} seed {cfg.seed} {source}: grasp session failed: {type(e).__name__}: {e}",
            file=sys.stderr,
        )
        return None
    _print_session(path, note)
    return str(path)


def grasp_benchmark_maps(a: argparse.Namespace, command: str) -> list[str]:
    """Grasp sessions on the maps of an exploration benchmark sweep (``--maps-from-benchmark
    <out>/exploration.json``): its ``object-driven`` run folders give the ``estimated`` and
    ``ground_truth`` sessions, its ``init`` ones the ``init_only`` sessions, so the grasp report
    and the exploration report describe the same maps. The world is built from the mapping run's
    own ``config.toml`` (plus ``--set``), so it is the world that was mapped."""
    from objslam.config import load_run_config
    from objslam.scene import load_scene

    rows = json.loads(Path(a.maps_from_benchmark).read_text())["rows"]
    runs_by: dict[tuple[str, int, str], Path] = {}
    for r in rows:
        if r.get("run_dir"):
            d = Path(r["run_dir"])
            runs_by[(r["scene"], int(r["seed"]), r["strategy"])] = d if d.is_absolute() else REPO / d
    sessions: list[str] = []
    for scene_file in a.scenes:
        scene = load_scene(REPO / scene_file)
        for seed in a.seeds:
            runs = {
                "estimated": runs_by.get((scene.name, seed, "object-driven")),
                "init_only": runs_by.get((scene.name, seed, "init")),
            }
            for source in a.sources:
                run_dir = runs["estimated" if source == "ground_truth" else source]
                if run_dir is None or not (run_dir / "map.json").exists():
                    print(
                        f"{scene.name} seed {seed} {source}: no map in {a.maps_from_benchmark}",
                        file=sys.stderr,
                    )
                    continue
                cfg = load_run_config(
                    overlays=[run_dir / "config.toml"], overrides=a.set, strategy="object-driven"
                )
                if cfg.seed != seed or Path(cfg.scene).stem != scene.name:
                    print(
                        f"{run_dir}: its config is {cfg.scene} seed {cfg.seed}, not {scene.name} seed {seed}",
                        file=sys.stderr,
                    )
                    continue
                path = _grasp_on(a, scene, cfg, source, run_dir, "benchmark map, ")
                if path is not None:
                    sessions.append(path)
                    _write_manifest(sessions, command, Path(a.manifest))
    return sessions


def run_sweep(a: argparse.Namespace, command: str) -> list[str]:
    from objslam.config import load_run_config
    from objslam.episode import run_episode
    from objslam.scene import load_scene

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
                    runs["init_only"] = run_episode(
                        dataclasses.replace(cfg, strategy="init"), progress=False
                    ).run_dir
            except Exception as e:  # noqa: BLE001 - the run folder records it; the sweep goes on
                print(f"{scene.name} seed {seed}: mapping failed: {type(e).__name__}: {e}", file=sys.stderr)
                continue
            t_map = time.perf_counter() - t0
            for source in a.sources:
                path = _grasp_on(
                    a,
                    scene,
                    cfg,
                    source,
                    runs["estimated" if source == "ground_truth" else source],
                    f"mapping {t_map:.0f} s, ",
                )
                if path is not None:
                    sessions.append(path)
            _write_manifest(sessions, command, Path(a.manifest))
    return sessions


def _rate(rows: list[dict]) -> str:
    n = len(rows)
    s = sum(r["success"] for r in rows)
    return f"{s}/{n} ({100.0 * s / n:.1f} %)" if n else "-"


def _centre_errors_mm(d: dict[str, Any]) -> dict[Any, tuple[float, float]]:
    """Re-observation sessions: per map object id, the x-y distance (mm) to its true object of the
    centre that was grasped (``target_geometry``) and of the map's own estimate. Empty for
    sessions without re-observation (the map's estimate is what they grasp)."""
    if not any("target_geometry" in r for r in d["rows"]):
        return {}
    from objslam.scene import gt_objects, load_scene, scene_file

    truth = {
        g["id"]: g["geometry"]["center"] for g in gt_objects(load_scene(REPO / scene_file(d["scene"], REPO)))
    }
    mapped = (
        {o["id"]: o["geometry"]["center"] for o in _map_objects(d["map_source"], None, Path(d["map_run"]))}
        if d["map_source"] != "ground_truth"
        else truth
    )
    out = {}
    for r in d["rows"]:
        gt, mid = r.get("gt_id"), r.get("map_id")
        if "target_geometry" in r and gt in truth and mid in mapped:
            t = truth[gt]
            out[mid] = (
                1000.0 * math.dist(r["target_geometry"]["center"][:2], t[:2]),
                1000.0 * math.dist(mapped[mid][:2], t[:2]),
            )
    return out


def _median_p90(v: list[float]) -> str:
    """``median / 90th percentile`` (linear interpolation, numpy's default) of non-empty ``v``."""
    import numpy as np

    return f"{float(np.median(v)):.1f} / {float(np.percentile(v, 90)):.1f}"


def _rows(sessions: list[str]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for p in sessions:
        d = json.loads(Path(p).read_text())
        errs = _centre_errors_mm(d)
        for r in d["rows"]:
            if r.get("skipped"):
                continue
            grasped_err, map_err = errs.get(r.get("map_id"), (None, None))
            rows.append(
                {
                    "scene": d["scene"],
                    "seed": d["seed"],
                    "object": r["object"],
                    "class": r["class"],
                    "map_source": d["map_source"],
                    "reobserve": bool(d["config"].get("reobserve", False)),
                    # Sessions written before these options existed behaved as False.
                    "reobserve_register": bool(d["config"].get("reobserve_register", False)),
                    "reobserve_return_ready": bool(d["config"].get("reobserve_return_ready", False)),
                    "contact_retries": int(d["config"].get("contact_retries", 0)),
                    "centre_error_mm": float(d.get("centre_error_mm", 0.0)),
                    "touches": len(r.get("contact_shifts_m", [])),
                    "success": bool(r["success"]),
                    "cause": r["cause"],
                    "map_id": r.get("map_id"),
                    "map_label": r.get("map_label"),
                    "closed_gap_m": r.get("closed_gap_m"),
                    "expected_closed_width_m": r.get("expected_closed_width_m"),
                    "rise_m": r.get("rise_m"),
                    "deferred": r.get("deferred", 0),
                    "grasped_xy_err_mm": grasped_err,
                    "map_xy_err_mm": map_err,
                    "run_dir": d["map_run"],
                }
            )
    return rows


def _run_preset(run_dir: Path) -> str | None:
    """The world preset of the run folder a session grasped on (its resolved ``config.toml``)."""
    try:
        return tomllib.loads((run_dir / "config.toml").read_text()).get("preset")
    except (OSError, tomllib.TOMLDecodeError):
        return None


def _summary(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per map source (plain attempts: no re-observation, no added centre error): attempts,
    successes, rate and its Wilson 95 % interval."""
    out = []
    for src in SOURCES:
        sel = [r for r in rows if r["map_source"] == src and not r["reobserve"] and not r["centre_error_mm"]]
        if sel:
            k = sum(bool(r["success"]) for r in sel)
            lo, hi = wilson(k, len(sel))
            out.append(
                {
                    "map_source": src,
                    "attempts": len(sel),
                    "successes": k,
                    "success_rate": k / len(sel),
                    "ci_low": lo,
                    "ci_high": hi,
                }
            )
    return out


def write_reports(
    sessions: list[str],
    out: Path,
    command: str,
    comparison: list[str] | None = None,
    comparison_note: str = "",
) -> dict[str, Any]:
    """grasping.json / grasping.md from session files (``comparison``: sessions of another variant,
    reported apart in ``comparison_rows`` and their own table)."""
    rows = _rows(sessions)
    comp = _rows(comparison or [])
    out.mkdir(parents=True, exist_ok=True)
    session_configs = [json.loads(Path(s).read_text()).get("config") for s in sessions]
    grasp_configs = {json.dumps(c, sort_keys=True) for c in session_configs}
    prov = provenance(command, {"grasp": [json.loads(c) for c in sorted(grasp_configs)]})
    presets = sorted({_run_preset(Path(x).parent) for x in sessions} - {None})
    report = {
        **prov,
        "preset": presets[0] if len(presets) == 1 else presets,
        "sessions": sessions,
        "summary": _summary(rows),
        "rows": rows,
    }
    if comp:
        report.update(comparison_sessions=comparison, comparison_rows=comp, comparison_note=comparison_note)
    (report_files(out, "grasping")[0]).write_text(json.dumps(report, indent=2) + "\n")

    def variant(r: dict[str, Any]) -> str:
        blind = " (blind approach)" if r["contact_retries"] == 0 else ""
        if r["centre_error_mm"]:
            blind = f" + {r['centre_error_mm']:g} mm centre error" + blind
        if not r["reobserve"]:
            return r["map_source"] + blind
        how = [
            w
            for w, on in (
                ("registered", r["reobserve_register"]),
                ("from the close view", not r["reobserve_return_ready"]),
            )
            if on
        ]
        return r["map_source"] + " + re-observation" + (f" ({', '.join(how)})" if how else "") + blind

    def variant_key(v: str) -> tuple[int, str]:
        return (SOURCES.index(v.split(" ")[0]), v)

    sources = sorted({variant(r) for r in rows}, key=variant_key)
    by = {s: [r for r in rows if variant(r) == s] for s in sources}
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
        "after another (grasped objects set aside; an object with no collision-free grasp among its",
        "neighbours is deferred until an executed attempt has changed the scene, `deferred` in the rows),",
        "plus one `not_in_map` row per",
        "graspable true object no map object targets, plus `too_wide` rows where the map made a graspable",
        "object too wide. Success = the true object ends ≥ 10 cm above its start after the lift and a",
        "1 s hold (SAPIEN ground truth). Sources: `estimated` = object-driven exploration map,",
        "`ground_truth` = true poses and sizes (upper bound), `init_only` = the four Init views' map;",
        "`+ re-observation` = before each attempt two close top-down views of the target are fused into a",
        "fresh local map by the core's pipeline; its centre / yaw with the map's top height are grasped and",
        "its objects are the obstacles (a phantom the close views do not find is skipped); the arm returns to",
        "its ready posture before the grasp is planned (`from the close view`: it did not;",
        "`registered`: the local map shifted onto the map by its neighbours). Planner: fingers",
        "open fully, grasp up to 4 cm below the estimated top (`sim/objslam/grasp.py`, `GraspRunConfig`).",
        "",
        "## Overall",
        "",
        f"World preset: {', '.join(presets) or 'unknown'}. Intervals: Wilson 95 % over the attempts (taken",
        "as independent).",
        "",
        "| map source | attempts | success | 95 % interval |",
        "|---|---:|---:|---:|",
    ]
    for s in sources:
        lo, hi = wilson(sum(r["success"] for r in by[s]), len(by[s]))
        lines.append(f"| {s} | {len(by[s])} | {_rate(by[s])} | {100 * lo:.1f}-{100 * hi:.1f} % |")
    for title, key, values in (("Per class", "class", classes), ("Per scene", "scene", scenes)):
        lines += [
            "",
            f"## {title}",
            "",
            f"| {key} | " + " | ".join(sources) + " |",
            "|---|" + "---:|" * len(sources),
        ]
        for v in values:
            lines.append(
                f"| {v} | " + " | ".join(_rate([r for r in by[s] if r[key] == v]) for s in sources) + " |"
            )
    lines += [
        "",
        "## Failure causes",
        "",
        "| cause | " + " | ".join(sources) + " |",
        "|---|" + "---:|" * len(sources),
    ]
    counts = {s: Counter(r["cause"] for r in by[s] if not r["success"]) for s in sources}
    for c in CAUSES:
        if any(counts[s][c] for s in sources):
            lines.append(f"| {c} | " + " | ".join(str(counts[s][c]) for s in sources) + " |")
    if not any(counts.values()):
        lines.append("| (no failure) | " + " | ".join("0" for _ in sources) + " |")
    lines += [
        "",
        "Causes: `no_ik` no collision-free IK for any candidate; `no_path` IK but no collision-free path;",
        "`too_wide` the map's estimate is wider than the gripper; `collided` an object moved > 2 cm",
        "before closing or the arm was blocked; `missed` closed without lifting the object; `slipped`",
        "lifted ≥ 2 cm but not held ≥ 10 cm; `wrong_object` another true object was lifted; `phantom` an",
        "attempt on a map object with no true object there; `not_found` the close views found nothing at a",
        "real object's estimate; `not_in_map` no map object for a graspable true object. Rows skipped (not",
        "attempts): phantoms the close views did not find, duplicates of already grasped objects, map",
        "objects too wide both in the map and in truth.",
        "",
    ]
    if comp:
        lines += [
            "## Comparison: " + comparison_note,
            "",
            "From `comparison_rows` in `grasping.json` (not part of the tables above).",
            "",
            "| map source | attempts | success | causes |",
            "|---|---:|---:|---|",
        ]
        for src in sorted({variant(r) for r in comp}, key=variant_key):
            rs = [r for r in comp if variant(r) == src]
            cs = Counter(r["cause"] for r in rs if not r["success"])
            lines.append(
                f"| {src} | {len(rs)} | {_rate(rs)} | "
                + ", ".join(f"{c} {n}" for c, n in cs.most_common())
                + " |"
            )
        lines.append("")
    comp_by = {
        f"comparison: {v}": [r for r in comp if variant(r) == v] for v in sorted({variant(r) for r in comp})
    }
    failed = [(name, r) for name, rs in [*by.items(), *comp_by.items()] for r in rs if not r["success"]]
    if failed:
        lines += [
            "## Failed attempts",
            "",
            "| rows | scene | seed | object | class | width across the fingers in the map, cm | cause | touches |",
            "|---|---|---:|---|---|---:|---|---:|",
        ]
        for name, r in failed:
            w = r["expected_closed_width_m"]
            width = f"{100.0 * w:.1f}" if w is not None else "-"
            lines.append(
                f"| {name} | {r['scene']} | {r['seed']} | {r['object']} | {r['class']} | {width} | {r['cause']} | {r['touches']} |"
            )
        lines.append("")
    touched = [
        (name, rs) for name, rs in [*by.items(), *comp_by.items()] if rs and rs[0]["contact_retries"] > 0
    ]
    if touched:
        lines += [
            "## Touches during the approach",
            "",
            "A finger that lands on something on the way down (an upward force ≥ `contact_force_n` on a",
            "finger) stops the descent; the hand backs up, moves towards the touched side by the clearance",
            "the plan left on each side + 1 mm and descends again (`GraspRunConfig.contact_retries`).",
            "",
            "| rows | attempts | attempts with a touch | of them lifted | touches |",
            "|---|---:|---:|---:|---:|",
        ]
        for name, rs in touched:
            t = [r for r in rs if r["touches"]]
            lines.append(
                f"| {name} | {len(rs)} | {len(t)} | {sum(r['success'] for r in t)} | {sum(r['touches'] for r in t)} |"
            )
        lines.append("")
    measured = [
        (name, rs)
        for name, rs in [*by.items(), *comp_by.items()]
        if any(r["grasped_xy_err_mm"] is not None for r in rs)
    ]
    if measured:
        lines += [
            "## Grasped centre after re-observation",
            "",
            "x-y distance to the true object's centre, mm (median / 90th percentile over attempts): the",
            "centre grasped after the close views, and the map's own estimate of the same objects.",
            "",
            "| rows | attempts | grasped centre | map's estimate |",
            "|---|---:|---:|---:|",
        ]
        for name, rs in measured:
            g = sorted(r["grasped_xy_err_mm"] for r in rs if r["grasped_xy_err_mm"] is not None)
            m = sorted(r["map_xy_err_mm"] for r in rs if r["grasped_xy_err_mm"] is not None)
            lines.append(f"| {name} | {len(g)} | {_median_p90(g)} | {_median_p90(m)} |")
        lines.append("")
    (report_files(out, "grasping")[1]).write_text("\n".join(lines))
    return report


def _select(spec: str) -> tuple[list[str], dict[str, Any]]:
    """Sessions of a manifest ``PATH[=SRC,SRC]`` (only those map sources when given)."""
    path, _, srcs = spec.partition("=")
    m = json.loads(Path(path).read_text())
    keep = set(srcs.split(",")) if srcs else set(SOURCES)
    return [p for p in m["sessions"] if json.loads(Path(p).read_text())["map_source"] in keep], m


def build_parser() -> argparse.ArgumentParser:
    from objslam.cli import HelpFormatter

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    hard = [str(p.relative_to(REPO)) for p in sorted((REPO / "scenes" / "hard").glob("*.toml"))]
    ap.add_argument(
        "--scenes", nargs="+", default=hard, help="scene files (default: the hard suite, scenes/hard/)"
    )
    ap.add_argument("--seeds", nargs="+", type=int, default=[0], help="run seeds")
    ap.add_argument(
        "--sources", nargs="+", default=list(SOURCES), choices=SOURCES, help="maps the grasps are planned on"
    )
    ap.add_argument("--config", action="append", default=[], help="run-config overlay (repeatable)")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key (repeatable)"
    )
    ap.add_argument("--out", default="reports", help="report folder")
    ap.add_argument(
        "--reobserve",
        nargs="*",
        default=[],
        choices=SOURCES,
        help=(
            "map sources whose grasps re-observe the target from close views first (default: none; "
            "the grasp settings themselves: --set grasp.<key>=<value>, [grasp] in the run config)"
        ),
    )
    ap.add_argument(
        "--centre-error-mm",
        type=float,
        default=0.0,
        metavar="D",
        help="move every map object's centre D mm in a seeded horizontal direction before grasping (robustness to map error)",
    )
    ap.add_argument("--tag", default="", help="suffix of the session files (grasp_<source><tag>.json)")
    ap.add_argument(
        "--manifest",
        default=str(REPO / "runs" / "grasp_sweep.json"),
        help="the sweep's list of session files",
    )
    ap.add_argument(
        "--maps-from",
        default=str(REPO / "runs" / "grasp_sweep.json"),
        help="manifest whose maps --reuse-maps grasps on",
    )
    ap.add_argument("--report-only", action="store_true", help="rebuild the reports from the manifest")
    ap.add_argument(
        "--also",
        action="append",
        default=[],
        metavar="MANIFEST[=SRC,SRC]",
        help="with --report-only: more sessions for the main tables (optionally only these sources)",
    )
    ap.add_argument(
        "--compare",
        action="append",
        default=[],
        metavar="MANIFEST[=SRC,SRC]",
        help="with --report-only: sessions of another variant, reported apart (comparison_rows)",
    )
    ap.add_argument("--compare-note", default="", help="title of the comparison table (default: none)")
    ap.add_argument(
        "--reuse-maps",
        action="store_true",
        help="grasp again on the maps of the sweep in runs/grasp_sweep.json instead of mapping anew",
    )
    ap.add_argument(
        "--maps-from-benchmark",
        metavar="EXPLORATION_JSON",
        help=(
            "grasp on the maps of an exploration benchmark sweep (its object-driven and init run "
            "folders) instead of mapping anew"
        ),
    )
    return ap


def main(argv: list[str] | None = None) -> int:
    a = build_parser().parse_args(argv)
    command = (
        "python experiments/grasp.py "
        + " ".join(shlex.quote(x) for x in (argv if argv is not None else sys.argv[1:]))
    ).strip()
    comparison: list[str] = []
    if a.report_only:
        manifest = json.loads(Path(a.manifest).read_text())
        sessions = manifest["sessions"]
        made_by = [manifest.get("command", a.manifest)]
        for extra in a.also:
            sel, m = _select(extra)
            sessions += sel
            made_by.append(m.get("command", extra))
        for extra in a.compare:
            sel, m = _select(extra)
            comparison += sel
            made_by.append(m.get("command", extra))
        command += "` on the sessions of `" + "`, `".join(made_by)
    elif a.reuse_maps:
        sessions = regrasp(a, command)
    elif a.maps_from_benchmark:
        sessions = grasp_benchmark_maps(a, command)
    else:
        sessions = run_sweep(a, command)
    report = write_reports(sessions, REPO / a.out, command, comparison, a.compare_note)
    print(f"{len(report['rows'])} rows → {a.out}/pages/grasping.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
