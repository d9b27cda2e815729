"""The exploration benchmark: scenes × strategies × seeds, in parallel worker processes.

``python experiments/benchmark.py [--scenes ...] [--strategies ...] [--seeds 0 1 2] [--workers 2]
[--backend pool|ray] [--address ray://host:10001] [--config overlay.toml] [--set k=v] [--out reports]``

By default: the hard suite (where strategies are tuned) and the test split (judged without
re-tuning), seeds 0-8 with the estimator's random streams seeded per seed, and seven rows: the
project's ``object-driven-discovery``, the paper's rule ``object-driven``, the paper's method end to
end ``paper-pipeline`` (the paper's rule on the paper's object pipeline: SLAM map points as object
clouds; ``experiments/configs/strategies/paper-pipeline.toml``), ``expected-gain``, and the
baselines ``random``, ``coverage`` and ``init``. Every strategy is compared with each baseline pair
by pair (same scene and seed): ``paired`` in the JSON holds the mean differences in 3D IoU, CDE,
recall at 3D IoU 0.5 and path length with 95 % bootstrap intervals, per split and over all scenes,
at the end and at equal view counts.

Every episode is an ordinary run (its own run folder under ``runs/``); the aggregate is computed
from those folders' ``metrics.json`` and written to ``<out>/exploration.json`` and
``<out>/exploration.md`` (the paper's Table VI layout: per scene and mean, 3D IoU, 2D IoU, CDE cm,
YAE deg, plus views, camera path length and wall time, mean ± std over seeds) and PNG plots.
Episodes are independent and seeded, so the numbers do not depend on the number of workers.

Beside the world-frame metrics (the bars), the report gives precision and recall of the map at 3D
IoU 0.25 and 0.5 (phantoms and duplicates count against precision), centre and yaw errors over all
ground-truth objects with misses counted (``cde_all_cm``, ``yae_all_deg``; core ``eval`` module docs),
and 3D IoU and CDE *oracle-aligned* (``iou3d_oracle_aligned``, ``cde_oracle_aligned_cm``): the whole
estimated map moved by the median offset between matched true and estimated centres (translation
only, measured against the ground truth, so no robot could do it), then evaluated again against the
scene file's poses. The map's placement in the world comes from the kinematic prior (the simulated
robot's calibration errors, ``[robot]``), an error shared by every object of an episode, so the
oracle-aligned metrics isolate what the views did for the map's shape.
Every episode also evaluates its map after each view (``accuracy_curve`` in its metrics.json); the
report gives the metrics after k views per strategy, and 3D IoU differences to random at equal view
counts, paired by scene and seed. The kinematic biases are drawn per (seed, scene, view index), so
at the same k two strategies' maps share the gauge's draw and the paired difference isolates what
the choice of views did; an episode that stopped earlier keeps the map it stopped with.
Each finished episode's row is appended to ``<out>/exploration.partial.jsonl`` as it arrives (the
file goes once the report is written), so an interrupted sweep keeps what finished:
``--report-only`` then makes the report from those rows.
``--report-only`` rebuilds the reports from ``<out>/exploration.json`` and its run folders;
``--also FILE[:strategies]`` joins other sweeps' rows (more seeds, or the baselines of the main
report next to a variant: ``--set explore.stop_when_explored=false`` runs the utility strategies
on the full view budget, as random and coverage always are).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

import figures
from objslam.cli import HelpFormatter
from objslam.provenance import provenance, report_files, run_config
from objslam.sweep import BACKENDS, Job, run_sweep

#: Report order: the project's strategy, the paper's rule, the paper's method end to end (the
#: paper's pipeline, a strategy file), then the baselines.
STRATEGIES = (
    "object-driven-discovery",
    "object-driven",
    "paper-pipeline",
    "expected-gain",
    "random",
    "coverage",
    "init",
)
#: What every strategy is compared with, pair by pair (same scene and seed).
BASELINES = ("random", "coverage", "init")
#: The paired metrics: metric key → whether it has a value after k views (``accuracy_curve``).
PAIRED_METRICS = {"iou3d": True, "cde_cm": True, "recall_iou50": True, "path_length_m": False}
#: Bootstrap resamples of the paired mean difference (percentile 95 % interval; seeded).
BOOTSTRAP_RESAMPLES = 10_000
METRICS = ("iou3d", "iou2d", "cde_cm", "yae_deg")
#: Map-level metrics of the core's evaluation (precision / recall at 3D IoU 0.25 and 0.5, phantoms and
#: duplicates counted; centre and yaw error over all ground-truth objects, misses counted); None for
#: runs made before the evaluation gave them.
MAP_METRICS = ("precision_iou25", "recall_iou25", "precision_iou50", "recall_iou50", "cde_all_cm", "yae_all_deg")


def _row(m: dict[str, Any]) -> dict[str, Any]:
    if "error" in m:
        return {k: m[k] for k in ("scene", "strategy", "seed", "error")}
    return {
        "scene": m["scene"],
        "strategy": m["strategy"],
        "seed": m["seed"],
        "preset": m.get("preset"),
        "run_dir": m["run_dir"],
        **{k: m["mean"][k] for k in METRICS},
        **{k: m["mean"].get(k) for k in MAP_METRICS},
        "views": m["views"],
        "nbv_views": m["nbv_views"],
        "path_length_m": m["path_length_m"],
        "wall_s": m["wall_s"],
        "n_objects_est": m["n_objects_est"],
        "n_objects_gt": m["n_objects_gt"],
        "split": scene_split(m["scene"]),
        "entropy_curve": m["entropy_curve"],
        "accuracy_curve": m.get("accuracy_curve"),
        **run_extras(m["run_dir"], m),
    }


def benchmark_scenes() -> list[str]:
    """The benchmark's scenes: the hard suite (scenes/hard/) and the test split (scenes/test/)."""
    return [str(p.relative_to(REPO)) for split in ("hard", "test") for p in sorted((REPO / "scenes" / split).glob("*.toml"))]


def scene_split(scene: str) -> str:
    """The scene's split by the folder that holds ``<scene>.toml``: ``hard`` (scenes/hard/, where
    strategies are tuned), ``test`` (scenes/test/, judged without re-tuning) or ``dev`` (scenes/)."""
    for split in ("hard", "test"):
        if (REPO / "scenes" / split / f"{scene}.toml").exists():
            return split
    return "dev"


def bootstrap_ci(d: list[float], resamples: int = BOOTSTRAP_RESAMPLES, seed: int = 0) -> tuple[float, float]:
    """Percentile 95 % bootstrap interval of the mean of paired differences ``d`` (resampling the
    pairs with replacement; seeded, so a report is reproducible)."""
    import numpy as np

    x = np.asarray(d, dtype=float)
    idx = np.random.default_rng(seed).integers(0, len(x), size=(resamples, len(x)))
    means = x[idx].mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def paired_differences(ok: list[dict[str, Any]], strategies: list[str]) -> list[dict[str, Any]]:
    """Every strategy against each of :data:`BASELINES`, paired by (scene, seed), per split and over
    all scenes: the mean difference a − b of each of :data:`PAIRED_METRICS` with its
    :func:`bootstrap_ci`, ``at = "end"`` (the final maps) and, for the metrics with an accuracy
    curve, ``at = "equal_views"`` (a's final map against b's map after as many views, b not init)."""
    out: list[dict[str, Any]] = []
    ok = [r if r.get("split") else {**r, "split": scene_split(r["scene"])} for r in ok]
    by_key = {(r["strategy"], r["scene"], r["seed"]): r for r in ok}
    splits = sorted({r["split"] for r in ok})
    for split in [*splits, "all"] if len(splits) > 1 else splits:
        for a in strategies:
            for b in BASELINES:
                if a == b or b not in strategies:
                    continue
                pairs = [
                    (r, by_key[(b, r["scene"], r["seed"])])
                    for r in ok
                    if r["strategy"] == a
                    and split in ("all", r["split"])
                    and (b, r["scene"], r["seed"]) in by_key
                ]
                for metric, has_curve in PAIRED_METRICS.items():
                    ats = ["end"] + (["equal_views"] if has_curve and b != "init" else [])
                    for at in ats:
                        d = []
                        for ra, rb in pairs:
                            va = ra.get(metric)
                            if at == "end":
                                vb = rb.get(metric)
                            else:
                                vb = curve_value(rb["accuracy_curve"], ra["views"], metric) if rb.get("accuracy_curve") else None
                            if va is not None and vb is not None:
                                d.append(va - vb)
                        if len(d) < 2:
                            continue
                        lo, hi = bootstrap_ci(d)
                        out.append(
                            {"a": a, "b": b, "metric": metric, "split": split, "at": at,
                             "mean_diff": statistics.mean(d), "ci_low": lo, "ci_high": hi, "n": len(d)}
                        )
    return out


STAGES = ("render", "sensor", "detect", "core", "motion", "record")


def throughput(ok: list[dict[str, Any]], workers: int) -> dict[str, Any]:
    """Where an episode's time goes on the machine that ran the sweep: the median over episodes of
    each stage's median milliseconds per frame (render, sensor model, detector, core, arm motion,
    recording; ``timings_ms_median`` of each run), frames and wall seconds per episode, and the
    episodes per hour of a sweep with ``workers`` processes (``3600 · workers / mean wall``, each
    episode's wall time measured while the others ran)."""
    walls = [r["wall_s"] for r in ok if r.get("wall_s")]
    timed = [r["timings_ms_median"] for r in ok if r.get("timings_ms_median")]
    stages = {
        s: statistics.median([t[s] for t in timed if t.get(s) is not None])
        for s in STAGES
        if any(t.get(s) is not None for t in timed)
    }
    frames = [r["frames"] for r in ok if r.get("frames")]
    return {
        "workers": workers,
        "episodes": len(ok),
        "wall_s_mean": statistics.mean(walls) if walls else None,
        "episodes_per_hour": 3600.0 * workers / statistics.mean(walls) if walls else None,
        "frames_median": statistics.median(frames) if frames else None,
        "frame_ms_median": stages,
    }


def _throughput_lines(t: dict[str, Any]) -> list[str]:
    if not t.get("frame_ms_median"):
        return []
    stages = t["frame_ms_median"]
    return [
        "## Where the time goes",
        "",
        (
            f"{t['episodes']} episodes, {t['workers']} worker process(es): {t['episodes_per_hour']:.0f} episodes"
            f" per hour, {t['wall_s_mean']:.0f} s and {t['frames_median']:.0f} frames per episode. Median ms per frame:"
        ),
        "",
        "| " + " | ".join(stages) + " |",
        "|---" * len(stages) + "|",
        "| " + " | ".join(f"{v:.1f}" for v in stages.values()) + " |",
        "",
    ]


def _paired_table(paired: list[dict[str, Any]]) -> list[str]:
    """The report's paired-difference tables (3D IoU first), one row per (split, a, b)."""
    if not paired:
        return []
    lines = [
        "## Paired differences against the baselines",
        "",
        "Strategy a minus baseline b on the same scene and seed: mean difference [95 % bootstrap interval]",
        f"({BOOTSTRAP_RESAMPLES} resamples of the pairs), n pairs. `end`: final maps; `equal views`: a's final",
        "map against b's after as many views.",
        "",
    ]
    for metric, spec in (("iou3d", ".3f"), ("recall_iou50", ".3f"), ("cde_cm", ".2f"), ("path_length_m", ".2f")):
        rows = [p for p in paired if p["metric"] == metric]
        if not rows:
            continue
        lines += [f"### {metric}", "", "| split | a | b | end | equal views | n |", "|---|---|---|---|---|---|"]
        keys = list(dict.fromkeys((p["split"], p["a"], p["b"]) for p in rows))
        for split, a, b in keys:
            cell = {}
            n = 0
            for p in rows:
                if (p["split"], p["a"], p["b"]) == (split, a, b):
                    cell[p["at"]] = f"{p['mean_diff']:+{spec}} [{p['ci_low']:+{spec}}, {p['ci_high']:+{spec}}]"
                    n = max(n, p["n"])
            lines.append(f"| {split} | {a} | {b} | {cell.get('end', '-')} | {cell.get('equal_views', '-')} | {n} |")
        lines.append("")
    return lines


def _run_path(run_dir: str | Path) -> Path:
    return REPO / run_dir if not Path(run_dir).is_absolute() else Path(run_dir)


def run_extras(run_dir: str | Path, metrics: dict[str, Any] | None = None) -> dict[str, float | None]:
    """What the report adds from a run folder: :func:`aligned_metrics`, the ground-truth objects
    the map never got (``missed_objects``), the fraction of the table top known at the end
    (``table_known``: seen or under a mapped object; None for runs made before episodes recorded
    ``table_known_curve``) and the table cells whose object evidence no map object explained at
    the end (``table_unexplained``; None for runs made before ``table_unexplained_curve``), the
    camera pose error the map was built with (``ate_mm``: online ATE; None for runs without
    ``ate_rmse_m``), the tracker's lost frames (``lost_frames``), the episode's frames and its median
    milliseconds per frame by stage (``timings_ms_median``).
    ``metrics``: the run's metrics.json when already loaded."""
    m = metrics if metrics is not None else json.loads((_run_path(run_dir) / "metrics.json").read_text())
    curve = m.get("table_known_curve") or [None]
    unexplained = m.get("table_unexplained_curve") or [None]
    return {
        **aligned_metrics(run_dir),
        "missed_objects": m["n_objects_gt"] - m["n_matched"],
        "table_known": curve[-1],
        "table_unexplained": unexplained[-1],
        "ate_mm": None if m.get("ate_rmse_m") is None else 1000.0 * m["ate_rmse_m"],
        "lost_frames": m.get("lost_frames"),
        "frames": m.get("frames"),
        "timings_ms_median": m.get("timings_ms_median"),
    }


def aligned_metrics(run_dir: str | Path) -> dict[str, float | None]:
    """3D IoU and CDE of a run's map after removing its global translation offset (module docs),
    against the scene file's poses, keeping the run's own matching."""
    import tomllib
    from objslam.evaluation import offset_removed
    from objslam.scene import gt_objects, load_scene

    run = _run_path(run_dir)
    cfg = tomllib.loads((run / "config.toml").read_text())
    scene = Path(cfg["scene"])
    gt = gt_objects(load_scene(scene if scene.is_absolute() else REPO / scene))
    mp = json.loads((run / "map.json").read_text())
    matched = json.loads((run / "metrics.json").read_text())["objects"]
    return offset_removed(gt, mp, matched)


def _fmt(values: list[float | None], spec: str) -> str:
    v = [x for x in values if x is not None]
    if not v:
        return "-"
    if len(v) == 1:
        return format(v[0], spec)
    return f"{format(statistics.mean(v), spec)} ± {format(statistics.stdev(v), spec)}"


def _mean(values: list[float | None]) -> float | None:
    v = [x for x in values if x is not None]
    return statistics.mean(v) if v else None


def write_reports(
    rows: list[dict[str, Any]], out: Path, command: str, config: dict[str, Any] | None = None
) -> None:
    """Tables and plots from benchmark rows; ``config``: the resolved settings recorded in the JSON."""
    out.mkdir(parents=True, exist_ok=True)
    ok = [r for r in rows if "error" not in r]
    # The built-in strategies in report order, then Python strategies (objslam.strategy) as they come.
    strategies = [s for s in STRATEGIES if any(r["strategy"] == s for r in ok)]
    strategies += list(dict.fromkeys(r["strategy"] for r in ok if r["strategy"] not in STRATEGIES))
    scenes = sorted({r["scene"] for r in ok})
    paired = paired_differences(ok, strategies)
    preset = sorted({r.get("preset") or "realistic" for r in ok})
    sweep = config or {}
    while "sweep" in sweep and "workers" not in sweep:  # joined sweeps: the first sweep's settings
        sweep = sweep["sweep"] or {}
    workers = int(sweep.get("workers") or 1)
    time_use = throughput(ok, workers)
    report = {
        **provenance(command, config),
        "preset": "+".join(preset),
        "throughput": time_use,
        "paired": paired,
        "rows": rows,
    }
    (report_files(out, "exploration")[0]).write_text(json.dumps(report, indent=2) + "\n")

    lines = [
        "# Exploration benchmark",
        "",
        f"Generated by `{command}` from the run folders listed in `exploration.json`.",
        "Values are mean ± std over seeds; the scene mean first averages seeds per scene.",
        "",
    ]
    for metric, spec, title in (
        ("iou3d", ".3f", "3D IoU (higher is better)"),
        ("iou2d", ".3f", "Top-view 2D IoU (higher is better)"),
        ("cde_cm", ".2f", "Centre distance error, cm (lower is better)"),
        ("yae_deg", ".1f", "Yaw error, degrees (lower is better)"),
        ("precision_iou50", ".3f", "Precision at 3D IoU 0.5: found objects over all map objects, phantoms and duplicates counted"),
        ("recall_iou50", ".3f", "Recall at 3D IoU 0.5: found objects over all ground-truth objects"),
        ("precision_iou25", ".3f", "Precision at 3D IoU 0.25"),
        ("recall_iou25", ".3f", "Recall at 3D IoU 0.25"),
        ("cde_all_cm", ".2f", "CDE over all ground-truth objects, a miss counting 10 cm (the match gate), cm"),
        ("yae_all_deg", ".1f", "Yaw error over all ground-truth cuboids, a miss counting 90° (45° square), degrees"),
        ("iou3d_oracle_aligned", ".3f", "Oracle-aligned 3D IoU: after removing the map's global offset measured against the ground truth (higher is better; module docs)"),
        ("cde_oracle_aligned_cm", ".2f", "Oracle-aligned CDE: after removing the map's global offset, cm (lower is better)"),
        ("map_offset_mm", ".1f", "The map's global offset (median centre offset against the ground truth), mm"),
        ("missed_objects", ".2f", "Objects never mapped (ground-truth objects without a matched estimate)"),
        ("table_known", ".2f", "Table top known at the end (seen, or under a mapped object), fraction; - = run made before episodes recorded it"),
        ("table_unexplained", ".1f", "Table cells (2 cm by default) with object evidence no map object explains at the end (0 with evidence off); - = run made before episodes recorded it"),
        ("ate_mm", ".2f", "Camera pose ATE the map was built with (online, no alignment), mm"),
        ("lost_frames", ".1f", "Frames the tracker lost (dead-reckoned or the prior)"),
        ("views", ".1f", "Views used (Init + NBV)"),
        ("path_length_m", ".2f", "Camera path length, m"),
        ("wall_s", ".0f", "Wall time per episode, s"),
    ):
        lines += [f"## {title}", "", "| strategy | " + " | ".join(scenes) + " | mean |", "|---" * (len(scenes) + 2) + "|"]
        for s in strategies:
            cells = []
            per_scene_means = []
            for sc in scenes:
                vals = [r.get(metric) for r in ok if r["strategy"] == s and r["scene"] == sc]
                cells.append(_fmt(vals, spec))
                per_scene_means.append(_mean(vals))
            seeds = sorted({r["seed"] for r in ok if r["strategy"] == s})
            seed_means = [
                _mean([r.get(metric) for r in ok if r["strategy"] == s and r["seed"] == sd]) for sd in seeds
            ]
            lines.append(f"| {s} | " + " | ".join(cells) + f" | {_fmt(seed_means, spec)} |")
        lines.append("")
    lines += _paired_table(paired)
    lines += _throughput_lines(time_use)
    lines += _accuracy_tables(ok, strategies)
    failed = [r for r in rows if "error" in r]
    if failed:
        lines += ["## Failed episodes", ""] + [f"- {r['strategy']} {r['scene']} seed {r['seed']}: {r['error']}" for r in failed]
    lines += ["", "## Figures", ""] + figure_captions(ok, command)
    (report_files(out, "exploration")[1]).write_text("\n".join(lines) + "\n")
    figures.exploration_figures(ok, strategies, out / "pages", paired)


FIGURE_CAPTIONS = {
    "exploration_metrics": "Final map accuracy per view-selection strategy",
    "exploration_entropy": "Mean normalised entropy of the map after k views",
    "exploration_accuracy": (
        "3D IoU after k views, world frame and with the map's global offset removed "
        "(an episode that stopped earlier keeps its last map)"
    ),
    "exploration_paired": "3D IoU of each strategy minus a baseline's on the same scene and seed, at the end",
}


def figure_captions(ok: list[dict[str, Any]], command: str) -> list[str]:
    """The report's figure lines: image, caption with the interval and the command that made it."""
    n = len(ok)
    lines = []
    for stem, text in FIGURE_CAPTIONS.items():
        if stem == "exploration_accuracy" and not any(r.get("accuracy_curve") for r in ok):
            continue
        if stem == "exploration_paired":
            lines += [f"![{text}]({stem}.png)", "", f"*{text}: 95 % bootstrap intervals. Made by `{command}`.*", ""]
            continue
        lines += [
            f"![{text}]({stem}.png)",
            "",
            (
                f"*{text}: mean and Student-t 95 % confidence interval over {n} episodes (scenes × seeds "
                f"pooled). Vector version: [{stem}.pdf]({stem}.pdf). Made by `{command}`.*"
            ),
            "",
        ]
    return lines


def curve_value(curve: list[dict[str, Any]], k: int, metric: str) -> float | None:
    """A run's ``metric`` after ``k`` views: its last snapshot with at most ``k`` views done (an
    episode that stopped earlier keeps the map it stopped with); None before its first view."""
    v = None
    for p in curve:
        if p["views"] <= k:
            v = p.get(metric)
    return v


def _curves(ok: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], list[int]]:
    """The rows that carry an ``accuracy_curve`` and the view counts 1..k_max they span."""
    with_curve = [r for r in ok if r.get("accuracy_curve")]
    kmax = max((p["views"] for r in with_curve for p in r["accuracy_curve"]), default=0)
    return with_curve, list(range(1, kmax + 1))


def _mean_after(runs: list[dict[str, Any]], k: int, metric: str) -> float | None:
    """Mean of ``metric`` after ``k`` views over ``runs`` (see :func:`curve_value`)."""
    return _mean([curve_value(r["accuracy_curve"], k, metric) for r in runs])


def _mean_se(d: list[float], spec: str) -> str:
    """``mean ± standard error`` of paired differences (``-`` with fewer than two)."""
    if len(d) < 2:
        return "-"
    return f"{statistics.mean(d):+{spec}} ± {statistics.stdev(d) / len(d) ** 0.5:{spec}}"


def _accuracy_tables(ok: list[dict[str, Any]], strategies: list[str]) -> list[str]:
    """Metrics after k views (from each run's ``accuracy_curve``) and the paired difference to
    random at equal views: the kinematic biases are drawn per (seed, scene, view index), so at the
    same k two strategies' maps share the SLAM gauge's draw and the difference isolates the views."""
    with_curve, ks = _curves(ok)
    if not with_curve:
        return []
    head = "| strategy | " + " | ".join(str(k) for k in ks) + " |"
    sep = "|---" * (len(ks) + 1) + "|"
    lines = [
        "## Accuracy after k views (all scenes and seeds)",
        "",
        "Each run's map is evaluated after every view (`accuracy_curve` in its metrics.json); an",
        "episode that stopped before k views keeps the map it stopped with. Mean over scenes and seeds.",
        "",
    ]
    for metric, spec, title in (
        ("iou3d", ".3f", "3D IoU"),
        ("iou3d_oracle_aligned", ".3f", "3D IoU after removing the map's global offset"),
        ("cde_cm", ".2f", "CDE, cm"),
    ):
        lines += [f"### {title}", "", head, sep]
        for s in strategies:
            runs = [r for r in with_curve if r["strategy"] == s]
            lines.append(f"| {s} | " + " | ".join(_fmt([_mean_after(runs, k, metric)], spec) for k in ks) + " |")
        lines.append("")
    if "random" not in strategies:
        return lines
    ref = {(r["scene"], r["seed"]): r["accuracy_curve"] for r in with_curve if r["strategy"] == "random"}
    # Each other strategy's runs with random's curve on the same scene and seed.
    pairs = {
        s: [(r, ref[(r["scene"], r["seed"])]) for r in with_curve if r["strategy"] == s and (r["scene"], r["seed"]) in ref]
        for s in strategies
        if s != "random"
    }
    lines += ["### 3D IoU minus random's at equal views (paired by scene and seed: mean ± standard error)", "", head, sep]
    for s, ps in pairs.items():
        cells = []
        for k in ks:
            both = [(curve_value(r["accuracy_curve"], k, "iou3d"), curve_value(c, k, "iou3d")) for r, c in ps]
            cells.append(_mean_se([a - b for a, b in both if a is not None and b is not None], ".3f"))
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "### Each episode against random after the same number of views (paired by scene and seed)",
        "",
        "An episode's final map (n views) against random's map after n views on the same scene and seed",
        "(differences: mean ± standard error).",
        "",
        "| strategy | views | 3D IoU | random's after as many views | difference | CDE cm | random's | difference |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s, ps in pairs.items():
        if len(ps) < 2:
            continue
        cells = [f"{statistics.mean(r['views'] for r, _ in ps):.1f}"]
        for metric, spec in (("iou3d", ".3f"), ("cde_cm", ".2f")):
            own = [r[metric] for r, _ in ps]
            other = [curve_value(c, r["views"], metric) for r, c in ps]
            d = [a - b for a, b in zip(own, other) if a is not None and b is not None]
            cells += [format(_mean(own), spec), format(_mean(other), spec), _mean_se(d, spec)]
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    lines.append("")
    return lines


PARTIAL = "exploration.partial.jsonl"


def _previous_sweep(out: Path) -> dict[str, Any]:
    """The sweep in ``out``: its ``exploration.json``, or the rows an interrupted sweep kept in
    ``exploration.partial.jsonl`` (its first line: the command and config)."""
    done = out / "exploration.json"
    partial = out / PARTIAL
    if partial.exists() and (not done.exists() or partial.stat().st_mtime > done.stat().st_mtime):
        head, *rows = [json.loads(line) for line in partial.read_text().splitlines() if line.strip()]
        return {"command": head["command"] + f" (partial: {len(rows)} episodes finished)", "config": head["config"], "rows": rows}
    return json.loads(done.read_text())


def _other_sweep(spec: str) -> dict[str, Any]:
    """``--also FILE`` or ``FILE:strategy,strategy``: another sweep's rows (only those strategies)."""
    path, _, only = spec.partition(":")
    sweep = json.loads(Path(path).read_text())
    if only:
        keep = only.split(",")
        sweep["rows"] = [r for r in sweep["rows"] if r["strategy"] in keep]
        suffix = f" (its {', '.join(keep)} rows)"
        if not sweep["command"].endswith(suffix):  # a sweep that was itself joined this way
            sweep["command"] += suffix
    return sweep


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument(
        "--scenes", nargs="*", default=benchmark_scenes(), metavar="SCENE", help="scene files (default: the hard suite and the test split)"
    )
    ap.add_argument(
        "--strategies",
        nargs="*",
        default=list(STRATEGIES),
        metavar="STRATEGY",
        help=f"view-selection strategies: any of {', '.join(STRATEGIES)}, or labels of Python strategies "
        "set by --config overlays",
    )
    ap.add_argument("--seeds", nargs="*", type=int, default=list(range(9)), help="run seeds")
    ap.add_argument("--workers", type=int, default=2, help="pool processes, or CPUs of a local Ray instance")
    ap.add_argument("--backend", choices=BACKENDS, default="pool", help="pool: local processes; ray: one Ray task per episode")
    ap.add_argument("--address", default=None, help="Ray cluster address (backend ray; default: a local instance)")
    ap.add_argument(
        "--preset",
        choices=("realistic", "ideal"),
        help="world-model preset: realistic (default.toml) or ideal (overlays configs/presets/ideal.toml)",
    )
    ap.add_argument("--config", action="append", default=[], help="run-config TOML overlay (repeatable)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key (repeatable)")
    ap.add_argument("--out", default=str(REPO / "reports"), help="report folder")
    ap.add_argument("--report-only", action="store_true", help="rebuild the reports from <out>/exploration.json and its run folders")
    ap.add_argument(
        "--figures-only",
        action="store_true",
        help="redraw only the figures from <out>/exploration.json (no run folders needed)",
    )
    ap.add_argument(
        "--also", nargs="*", default=[], metavar="JSON",
        help="with --report-only: rows of other sweeps' exploration.json (e.g. more seeds) join the tables; "
        "FILE:s1,s2 takes only those strategies' rows",
    )
    a = ap.parse_args(argv)
    if a.figures_only:
        rows = [r for r in json.loads((Path(a.out) / "exploration.json").read_text())["rows"] if "error" not in r]
        strategies = [s for s in STRATEGIES if any(r["strategy"] == s for r in rows)]
        strategies += list(dict.fromkeys(r["strategy"] for r in rows if r["strategy"] not in STRATEGIES))
        paired = json.loads((Path(a.out) / "exploration.json").read_text()).get("paired")
        for paths in figures.exploration_figures(rows, strategies, Path(a.out) / "pages", paired).values():
            print(" ".join(str(p) for p in paths))
        return 0
    if a.report_only:
        old = _previous_sweep(Path(a.out))
        extra = [_other_sweep(spec) for spec in a.also]
        rows = [
            r if "error" in r else {**r, **run_extras(r["run_dir"])}
            for r in old["rows"] + [r for e in extra for r in e["rows"]]
        ]
        rows.sort(key=lambda r: (r["scene"], STRATEGIES.index(r["strategy"]) if r["strategy"] in STRATEGIES else 99, r["seed"]))
        command = " + ".join([old["command"], *(e["command"] for e in extra)])
        also = {spec: e.get("config") for spec, e in zip(a.also, extra)}
        config = {"sweep": old.get("config"), "also": also} if also else old.get("config")
        write_reports(rows, Path(a.out), command, config)
        print(f"{len(rows)} episodes → {a.out}/pages/exploration.md")
        return 0
    if a.preset:
        a.set.append(f'preset="{a.preset}"')
    # The estimator's random streams (iForest, cylinder fit, PnP RANSAC) follow the run seed, so the
    # spread over seeds includes the estimator's; a --set seed_algorithms=false comes later and wins.
    a.set.insert(0, "seed_algorithms=true")
    jobs = [
        Job(sc, st, sd, tuple(a.config), tuple(a.set)) for sc in a.scenes for st in a.strategies for sd in a.seeds
    ]
    command = "python experiments/benchmark.py " + " ".join(argv if argv is not None else sys.argv[1:])
    t0 = time.perf_counter()
    config = {
        **run_config(a.config, a.set),
        "scenes": a.scenes,
        "strategies": a.strategies,
        "seeds": a.seeds,
        "workers": a.workers,
        "backend": a.backend,
    }
    partial = Path(a.out) / PARTIAL
    partial.parent.mkdir(parents=True, exist_ok=True)
    partial.write_text(json.dumps({"command": command.strip(), "config": config}) + "\n")

    def keep(m: dict[str, Any]) -> None:
        with partial.open("a") as f:
            f.write(json.dumps(_row(m)) + "\n")

    results = run_sweep(jobs, a.workers, backend=a.backend, address=a.address, on_result=keep)
    rows = [_row(m) for m in results]
    rows.sort(key=lambda r: (r["scene"], STRATEGIES.index(r["strategy"]) if r["strategy"] in STRATEGIES else 99, r["seed"]))
    write_reports(rows, Path(a.out), command.strip(), config)
    partial.unlink()
    print(f"{len(rows)} episodes in {time.perf_counter() - t0:.0f} s → {a.out}/pages/exploration.md")
    return 0 if all("error" not in r for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
