"""Sweeps: the Ray backend gives the same numbers as the process pool on a tiny sweep."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

from objslam.sweep import Job, run_sweep

# Wall time and timings differ between runs; everything else must be equal.
UNSTABLE = ("wall_s", "timings_ms_median", "frame_budget_ms_median", "run_dir")


def _stable(r: dict) -> dict:
    return {k: v for k, v in r.items() if k not in UNSTABLE}


def _jobs(runs: Path, ci_overlay: Path) -> list[Job]:
    sets = (f'runs_dir="{runs}"',)
    return [Job("scenes/scene01.toml", "init", seed, (str(ci_overlay),), sets) for seed in (0, 1)]


def test_bad_backend_is_named() -> None:
    with pytest.raises(ValueError, match="backend"):
        run_sweep([], backend="spark")
    with pytest.raises(ValueError, match="address"):
        run_sweep([], backend="pool", address="ray://nowhere:10001")


def test_ray_backend_matches_process_pool(tmp_path: Path, ci_overlay: Path) -> None:
    pytest.importorskip("ray", reason="ray is installed by make setup (requirements.txt)")
    pool = run_sweep(_jobs(tmp_path / "pool", ci_overlay), workers=1, backend="pool")
    ray = run_sweep(_jobs(tmp_path / "ray", ci_overlay), workers=2, backend="ray")
    assert [r["seed"] for r in pool] == [0, 1] == [r["seed"] for r in ray]
    for a, b in zip(pool, ray):
        assert "error" not in a and "error" not in b, (a.get("error"), b.get("error"))
        assert _stable(a) == _stable(b)
        # The tasks ran in this process's working directory with the given runs_dir.
        map_a = (REPO / a["run_dir"] if not Path(a["run_dir"]).is_absolute() else Path(a["run_dir"])) / "map.json"
        map_b = (REPO / b["run_dir"] if not Path(b["run_dir"]).is_absolute() else Path(b["run_dir"])) / "map.json"
        assert str(tmp_path / "ray") in str(map_b)
        assert json.loads(map_a.read_text()) == json.loads(map_b.read_text())
    # Different seeds are different episodes (the comparison above is not vacuous).
    assert _stable(pool[0]) != _stable(pool[1])


def test_compare_sweeps_pairs_one_strategy_with_another(tmp_path: Path) -> None:
    from compare_sweeps import compare

    def row(strategy: str, seed: int, iou: float, path: float) -> dict:
        return {"strategy": strategy, "scene": "scene01", "seed": seed, "iou3d": iou, "path_length_m": path}

    sweep = tmp_path / "exploration.json"
    rows = [row("a", 0, 0.90, 2.0), row("a", 1, 0.80, 3.0), row("b", 0, 0.85, 1.0), row("b", 1, 0.70, 1.0)]
    sweep.write_text(json.dumps({"command": "x", "rows": rows}))
    text = compare(sweep, sweep, {"b": "a"})
    line = next(ln for ln in text.splitlines() if ln.startswith("| b vs a |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1] == "2"  # two paired episodes
    # iou3d: baseline (a) 0.850, changed (b) 0.775, difference −0.075 ± SE of (−0.05, −0.10) = 0.025.
    assert cells[2:5] == ["0.850", "0.775", "-0.075 ± 0.025"]
    assert "--pair b=a" in text
    # Without --pair each strategy is paired with itself: no difference.
    assert "| a | 2 | 0.850 | 0.850 | +0.000 ± 0.000" in compare(sweep, sweep)


def test_the_paired_bootstrap_interval_matches_scipy_and_pairs_by_scene_and_seed() -> None:
    """``bootstrap_ci`` against scipy's percentile bootstrap of the mean (to a few thousandths at
    10,000 resamples), and ``paired_differences`` pairs a strategy's rows with the baseline's on the
    same scene and seed, per split and over all scenes."""
    import numpy as np
    from benchmark import bootstrap_ci, paired_differences
    from scipy.stats import bootstrap

    d = list(np.random.default_rng(3).normal(0.02, 0.03, size=14))
    lo, hi = bootstrap_ci(d)
    ref = bootstrap((np.array(d),), np.mean, n_resamples=10_000, method="percentile", random_state=0)
    assert lo == pytest.approx(ref.confidence_interval.low, abs=3e-3)
    assert hi == pytest.approx(ref.confidence_interval.high, abs=3e-3)
    assert lo < np.mean(d) < hi

    rows = [
        {"strategy": s, "scene": sc, "seed": sd, "split": sp, "iou3d": v + (0.1 if s == "a" else 0.0) + 0.01 * sd,
         "views": 5, "accuracy_curve": None}
        for s in ("a", "random")
        for sc, sp, v in (("hard01", "hard", 0.5), ("test01", "test", 0.6))
        for sd in (0, 1, 2)
    ]
    paired = paired_differences(rows, ["a", "random"])
    end = {p["split"]: p for p in paired if (p["a"], p["b"], p["metric"], p["at"]) == ("a", "random", "iou3d", "end")}
    assert set(end) == {"hard", "test", "all"}
    assert (end["hard"]["n"], end["test"]["n"], end["all"]["n"]) == (3, 3, 6)
    for p in end.values():
        assert p["mean_diff"] == pytest.approx(0.1) and p["ci_low"] == pytest.approx(0.1) and p["ci_high"] == pytest.approx(0.1)
