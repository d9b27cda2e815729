"""The report figures (experiments/figures.py) on small synthetic report rows."""

from __future__ import annotations

from pathlib import Path

import figures
import numpy as np
import pytest

STRATEGIES = ["object-driven", "random", "init"]


def synthetic_rows() -> list[dict]:
    """3 scenes × 3 seeds × 3 strategies with 3D IoU near 0.81, 0.86 and 0.91 and curves of 6 views."""
    rng = np.random.default_rng(0)
    rows = []
    for si, s in enumerate(STRATEGIES):
        for scene in ("scene01", "scene02", "scene03"):
            for seed in range(3):
                n = 6 if s != "init" else 4
                iou = 0.91 - 0.05 * si + 0.01 * rng.standard_normal()
                curve = [
                    {"views": k, "iou3d": iou - 0.02 * (n - k), "iou3d_aligned": iou + 0.03 - 0.02 * (n - k)}
                    for k in range(1, n + 1)
                ]
                rows.append(
                    {
                        "scene": scene,
                        "strategy": s,
                        "seed": seed,
                        "iou3d": iou,
                        "iou2d": iou + 0.05,
                        "cde_cm": 0.4 + 0.1 * si,
                        "yae_deg": 1.0 + si,
                        "entropy_curve": [0.6 - 0.05 * k for k in range(n)],
                        "accuracy_curve": curve,
                    }
                )
    return rows


def test_mean_ci_is_the_student_t_interval() -> None:
    from scipy import stats

    v = [0.81, 0.84, 0.86, 0.83, 0.9]
    m, lo, hi = figures.mean_ci(v)
    ref = stats.t.interval(0.95, len(v) - 1, loc=np.mean(v), scale=stats.sem(v))
    assert m == pytest.approx(np.mean(v))
    assert (lo, hi) == pytest.approx(ref)
    assert figures.mean_ci([None, 0.5]) == (0.5, 0.5, 0.5)
    assert figures.mean_ci([None]) is None


def test_wilson_interval_matches_the_closed_form() -> None:
    rate, lo, hi = figures.wilson(8, 10)
    assert rate == 0.8
    assert (lo, hi) == pytest.approx((0.4902, 0.9433), abs=1e-4)
    rate, lo, hi = figures.wilson(470, 470)
    assert rate == hi == 1.0 and lo == pytest.approx(0.99190, abs=1e-4)


def test_exploration_figures_are_written_as_png_and_pdf(tmp_path: Path) -> None:
    written = figures.exploration_figures(synthetic_rows(), STRATEGIES, tmp_path)
    assert set(written) == {"exploration_metrics", "exploration_entropy", "exploration_accuracy"}
    for paths in written.values():
        assert sorted(p.suffix for p in paths) == [".pdf", ".png"]
        assert all(p.stat().st_size > 5000 for p in paths)
        assert paths[1].read_bytes()[:4] == b"%PDF"


def test_metric_axes_start_where_the_data_are() -> None:
    rows = synthetic_rows()
    fig = figures.metrics_figure(rows, STRATEGIES)
    ax = fig.axes[0]  # 3D IoU: means 0.81 to 0.91
    lo, hi = ax.get_ylim()
    assert 0.75 < lo < 0.81 and 0.9 < hi < 1.0  # not from zero
    assert "python" not in fig._suptitle.get_text()  # no command line in the title
    # one error bar (with its interval) per strategy
    assert len(ax.containers) == len(STRATEGIES)


def test_curves_share_one_view_axis_and_every_series_is_drawn() -> None:
    rows = synthetic_rows()
    ent = figures.entropy_figure(rows, STRATEGIES)
    acc = figures.accuracy_figure(rows, STRATEGIES)
    xlims = {ax.get_xlim() for ax in [*ent.axes, *acc.axes]}
    assert xlims == {(0.5, 6.5)}
    for ax in [*ent.axes, *acc.axes]:
        assert len(ax.get_lines()) == len(STRATEGIES)
        assert len(ax.collections) == len(STRATEGIES)  # one confidence band per series
        styles = {(line.get_marker(), line.get_linestyle()) for line in ax.get_lines()}
        assert len(styles) == len(STRATEGIES)  # coincident series stay distinguishable
