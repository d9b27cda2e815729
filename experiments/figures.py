"""Paper figures of the experiment reports (matplotlib, Agg).

Every figure: a title that says what is shown (the command that made it goes in the report's
text, not the figure), a 95 % confidence interval on every point, curve and bar (Student-t over
the episodes pooled from all scenes and seeds: mean ± t(0.975, n-1)·s/√n), value axes that start
where the data are, the same view axis for every plot of the same runs, markers and line styles
that keep overlapping series visible, and each figure written as PNG (200 dpi) and PDF.

Entry points: :func:`exploration_figures` (``benchmark.py``), :func:`robustness_figure`
(``grasp_robustness.py``), :func:`mean_ci`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

#: Confidence level of every interval drawn.
CI_LEVEL = 0.95
#: Formats every figure is written in.
FORMATS = ("png", "pdf")
PNG_DPI = 200
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
LINESTYLES = ("-", "--", "-.", ":", (0, (5, 1)), (0, (3, 1, 1, 1)))


def mean_ci(values: Sequence[float | None], level: float = CI_LEVEL) -> tuple[float, float, float] | None:
    """``(mean, low, high)``: the Student-t ``level`` interval of the mean of the non-None values
    (zero width with one value); None without values."""
    v = [float(x) for x in values if x is not None and math.isfinite(x)]
    if not v:
        return None
    m = sum(v) / len(v)
    if len(v) < 2:
        return m, m, m
    from scipy.stats import t

    s = math.sqrt(sum((x - m) ** 2 for x in v) / (len(v) - 1))
    half = float(t.ppf(0.5 + level / 2, len(v) - 1)) * s / math.sqrt(len(v))
    return m, m - half, m + half


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 9, "axes.titlesize": 9, "legend.fontsize": 8, "pdf.fonttype": 42})
    return plt


def save(fig: Any, out: Path, stem: str) -> list[Path]:
    """Write ``fig`` as ``<out>/<stem>.<fmt>`` for every format of :data:`FORMATS`."""
    paths = []
    for fmt in FORMATS:
        p = out / f"{stem}.{fmt}"
        fig.savefig(p, dpi=PNG_DPI if fmt == "png" else None, bbox_inches="tight")
        paths.append(p)
    return paths


def _style(i: int) -> dict[str, Any]:
    return {
        "color": f"C{i % 10}",
        "marker": MARKERS[i % len(MARKERS)],
        "linestyle": LINESTYLES[i % len(LINESTYLES)],
    }


def _dodge(i: int, n: int, width: float) -> float:
    """Offset of series ``i`` of ``n`` on the x axis so coincident points stay apart."""
    return 0.0 if n < 2 else (i - (n - 1) / 2) * width / (n - 1)


def _value_after(curve: list[dict[str, Any]], k: int, metric: str) -> float | None:
    v = None
    for p in curve:
        if p["views"] <= k:
            v = p.get(metric)
    return v


def _entropy_points(row: dict[str, Any]) -> list[dict[str, Any]]:
    """A row's entropy curve as ``{"views", "entropy"}`` points on the accuracy curve's view axis
    (one entropy value per view, Init views included)."""
    ent = row.get("entropy_curve") or []
    acc = row.get("accuracy_curve") or []
    if len(acc) == len(ent):
        return [{"views": p["views"], "entropy": e} for p, e in zip(acc, ent)]
    return [{"views": i + 1, "entropy": e} for i, e in enumerate(ent)]


METRIC_PANELS = (
    ("iou3d", "3D IoU"),
    ("iou2d", "2D IoU"),
    ("cde_cm", "centre distance error (cm)"),
    ("yae_deg", "yaw error (deg)"),
)


def _pooled(rows: list[dict[str, Any]]) -> str:
    return f"{len({r['scene'] for r in rows})} scenes × {len({r['seed'] for r in rows})} seeds"


def metrics_figure(rows: list[dict[str, Any]], strategies: list[str]) -> Any:
    """Final-map metrics per strategy: mean and 95 % CI over the episodes, one panel per metric."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(METRIC_PANELS), figsize=(12, 3.0))
    for ax, (metric, label) in zip(axes, METRIC_PANELS):
        for i, s in enumerate(strategies):
            ci = mean_ci([r.get(metric) for r in rows if r["strategy"] == s])
            if ci is None:
                continue
            m, lo, hi = ci
            st = _style(i)
            ax.errorbar([i], [m], yerr=[[m - lo], [hi - m]], fmt=st["marker"], color=st["color"], capsize=3, ms=5)
        ax.set_xticks(range(len(strategies)), strategies, rotation=30, ha="right")
        ax.set_xlim(-0.5, len(strategies) - 0.5)
        ax.set_title(label)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"Final map accuracy per view-selection strategy (mean and 95 % CI, {_pooled(rows)})")
    fig.tight_layout()
    return fig


def view_axis(rows: list[dict[str, Any]]) -> list[int]:
    """The view counts 1..k_max every curve of these runs is drawn on (one axis for all plots)."""
    kmax = max(
        [p["views"] for r in rows for p in (r.get("accuracy_curve") or [])]
        + [len(r.get("entropy_curve") or []) for r in rows]
        + [1]
    )
    return list(range(1, kmax + 1))


def _curves(ax: Any, rows: list[dict[str, Any]], strategies: list[str], metric: str, points_of: Any) -> None:
    ks = view_axis(rows)
    n = len(strategies)
    for i, s in enumerate(strategies):
        runs = [c for c in (points_of(r) for r in rows if r["strategy"] == s) if c]
        if not runs:
            continue
        xs, ms, los, his = [], [], [], []
        for k in ks:
            ci = mean_ci([_value_after(c, k, metric) for c in runs])
            if ci is not None:
                xs.append(k + _dodge(i, n, 0.3))
                ms.append(ci[0])
                los.append(ci[1])
                his.append(ci[2])
        st = _style(i)
        ax.plot(xs, ms, label=s, ms=4, lw=1.3, **st)
        ax.fill_between(xs, los, his, color=st["color"], alpha=0.15, lw=0)
    ax.set_xlabel("views taken (Init + next-best views)")
    ax.set_xlim(0.5, ks[-1] + 0.5)
    ax.grid(alpha=0.3)


def entropy_figure(rows: list[dict[str, Any]], strategies: list[str]) -> Any:
    """Mean normalised entropy after k views per strategy (mean and 95 % CI)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    _curves(ax, rows, strategies, "entropy", _entropy_points)
    ax.set_ylabel("mean normalised entropy H̄")
    ax.legend()
    ax.set_title(f"Map uncertainty after k views (mean and 95 % CI, {_pooled(rows)})")
    fig.tight_layout()
    return fig


def accuracy_figure(rows: list[dict[str, Any]], strategies: list[str]) -> Any:
    """3D IoU after k views per strategy, world frame and with the map's global offset removed."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharex=True)
    for ax, (metric, label) in zip(
        axes, (("iou3d", "3D IoU (world frame)"), ("iou3d_aligned", "3D IoU, map's global offset removed"))
    ):
        _curves(ax, rows, strategies, metric, lambda r: r.get("accuracy_curve"))
        ax.set_ylabel(label)
    axes[0].legend()
    fig.suptitle(f"Map accuracy after k views (mean and 95 % CI, {_pooled(rows)}; a stopped episode keeps its last map)")
    fig.tight_layout()
    return fig


def paired_figure(paired: list[dict[str, Any]], metric: str = "iou3d") -> Any:
    """Paired differences a − b at the end of the episode (``exploration.json`` ``paired``): one
    panel per split, one row per (a, b), the mean with its 95 % bootstrap interval."""
    plt = _pyplot()
    rows = [p for p in paired if p["metric"] == metric and p["at"] == "end"]
    splits = list(dict.fromkeys(p["split"] for p in rows))
    fig, axes = plt.subplots(1, len(splits), figsize=(4.2 * len(splits), 0.3 * len(rows) / len(splits) + 1.6), squeeze=False)
    for ax, split in zip(axes[0], splits):
        mine = [p for p in rows if p["split"] == split]
        y = list(range(len(mine)))[::-1]
        ax.errorbar(
            [p["mean_diff"] for p in mine],
            y,
            xerr=[[p["mean_diff"] - p["ci_low"] for p in mine], [p["ci_high"] - p["mean_diff"] for p in mine]],
            fmt="o",
            capsize=3,
        )
        ax.axvline(0.0, color="grey", lw=0.8)
        ax.set_yticks(y, [f"{p['a']} − {p['b']}" for p in mine], fontsize=7)
        ax.set_title(f"{split} (n = {max(p['n'] for p in mine)} pairs)")
        ax.set_xlabel(f"{metric} difference")
    fig.suptitle("Paired differences, mean and 95 % bootstrap interval (same scene and seed)")
    fig.tight_layout()
    return fig


def exploration_figures(
    rows: list[dict[str, Any]], strategies: list[str], out: Path, paired: list[dict[str, Any]] | None = None
) -> dict[str, list[Path]]:
    """The exploration report's figures from its successful rows (``exploration.json``):
    ``exploration_metrics`` (:func:`metrics_figure`), ``exploration_entropy``
    (:func:`entropy_figure`), with ``accuracy_curve`` in the rows ``exploration_accuracy``
    (:func:`accuracy_figure`) and with ``paired`` differences ``exploration_paired``
    (:func:`paired_figure`). Returns the written files by figure stem."""
    plt = _pyplot()
    out.mkdir(parents=True, exist_ok=True)
    makers = {"exploration_metrics": metrics_figure, "exploration_entropy": entropy_figure}
    if any(r.get("accuracy_curve") for r in rows):
        makers["exploration_accuracy"] = accuracy_figure
    written = {}
    for stem, make in makers.items():
        fig = make(rows, strategies)
        written[stem] = save(fig, out, stem)
        plt.close(fig)
    if paired and any(p["metric"] == "iou3d" and p["at"] == "end" for p in paired):
        fig = paired_figure(paired)
        written["exploration_paired"] = save(fig, out, "exploration_paired")
        plt.close(fig)
    return written


def robustness_figure(
    points: list[dict[str, Any]], series_key: str, series_label: Any, out: Path, stem: str = "robustness"
) -> list[Path]:
    """Grasp success against the injected map centre error, one series per ``series_key`` value:
    ``points`` carry ``centre_error_mm``, ``successes`` and ``attempts``; the interval is the
    Wilson 95 % score interval of a binomial proportion (successes out of attempts)."""
    plt = _pyplot()
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    keys = sorted({p[series_key] for p in points})
    errors = sorted({p["centre_error_mm"] for p in points})
    step = min((b - a for a, b in itertools.pairwise(errors)), default=1.0)
    for i, key in enumerate(keys):
        pts = sorted((p for p in points if p[series_key] == key), key=lambda p: p["centre_error_mm"])
        xs = [p["centre_error_mm"] + _dodge(i, len(keys), 0.15 * step) for p in pts]
        ys, los, his = [], [], []
        for p in pts:
            rate, lo, hi = wilson(p["successes"], p["attempts"])
            ys.append(100 * rate)
            los.append(100 * (rate - lo))
            his.append(100 * (hi - rate))
        st = _style(i)
        ax.errorbar(xs, ys, yerr=[los, his], label=series_label(key), capsize=3, ms=5, **st)
    ax.set_xlabel("injected map centre error (mm)")
    ax.set_ylabel("grasp success (%)")
    ax.set_xticks(errors)
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title("Grasp success vs map centre error (95 % Wilson CI)")
    fig.tight_layout()
    paths = save(fig, out, stem)
    plt.close(fig)
    return paths


def wilson(successes: int, n: int, level: float = CI_LEVEL) -> tuple[float, float, float]:
    """``(rate, low, high)``: the Wilson score interval of a binomial proportion."""
    if n <= 0:
        return 0.0, 0.0, 1.0
    from scipy.stats import norm

    z = float(norm.ppf(0.5 + level / 2))
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    # The interval contains p; clamping removes rounding at p = 0 or 1.
    return p, max(0.0, min(p, centre - half)), min(1.0, max(p, centre + half))
