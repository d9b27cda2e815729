"""Strategies written in Python (objslam.strategy): the interface reproduces the built-in
object-driven decisions, bad strategies are typed errors naming the key, a bad view fails the run
without losing what was written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from objslam.config import ConfigError, load_run_config
from objslam.episode import run_episode
from objslam.strategy import StrategyError, as_view, load_strategy_class

HERE = Path(__file__).resolve().parent
ARGMAX = "experiments/strategies/paper_argmax.py:PaperArgmax"
BAD = HERE / "strategies_for_tests.py"
# The run's default [explore] has the discovery extension on; object-driven (the paper's rule) ignores it.
PAPER_RULE = ["explore.max_views=2"]


def _cfg(tmp_path: Path, ci_overlay: Path, strategy: str, sets: list[str]):
    return load_run_config(overlays=[ci_overlay], overrides=[f'runs_dir="{tmp_path}"', "seed=5", *sets], strategy=strategy)


def test_a_python_argmax_of_the_paper_utility_takes_the_built_in_views(tmp_path, ci_overlay) -> None:
    built_in = run_episode(_cfg(tmp_path, ci_overlay, "object-driven", PAPER_RULE), progress=False).metrics
    # The strategy file experiments/configs/strategies/paper-argmax.toml names the class.
    python = run_episode(_cfg(tmp_path, ci_overlay, "paper-argmax", PAPER_RULE), progress=False).metrics
    assert python["strategy"] == "paper-argmax"
    assert built_in["nbv_views"] >= 1, "the comparison needs a next-best view"
    # Same views → same frames → the same map, to the bit.
    for key in ("views", "nbv_views", "frames", "path_length_m", "stop_reason"):
        assert python[key] == built_in[key], key
    assert python["mean"] == built_in["mean"]
    assert python["entropy_curve"] == built_in["entropy_curve"]


def test_the_python_object_driven_example_takes_the_built_in_discovery_views(tmp_path, ci_overlay) -> None:
    # The run's default [explore]: the budget reserve and before-stop discovery are on; with two
    # views after Init the reserve hands (at least) one to the unseen table.
    sets = ["explore.max_views=2"]
    built_in = run_episode(_cfg(tmp_path, ci_overlay, "object-driven-discovery", sets), progress=False).metrics
    counting = load_strategy_class(f"{BAD}:CountingObjectDriven")
    counting.table_drawn_steps = 0
    cfg = _cfg(tmp_path, ci_overlay, "object-driven-test", [f'python_strategy="{BAD}:CountingObjectDriven"', *sets])
    python = run_episode(cfg, progress=False).metrics
    assert counting.table_drawn_steps >= 1, "the comparison needs a view the table gain chose"
    for key in ("views", "nbv_views", "frames", "path_length_m", "stop_reason", "table_known_curve"):
        assert python[key] == built_in[key], key
    assert python["mean"] == built_in["mean"]
    assert python["entropy_curve"] == built_in["entropy_curve"]
    # Its config file makes the name work like a built-in one.
    cfg = load_run_config(overlays=[ci_overlay], strategy="object-driven-py")
    assert cfg.python_strategy.endswith("object_driven.py:ObjectDriven")
    # utility-per-metre on the built-in object-driven-discovery scores with a discount that is 1 to
    # the last bit is the built-in too.
    sets_upm = ['python_strategy_params.utility="object-driven-discovery"', "python_strategy_params.metres_per_halving=1e300", *sets]
    upm = run_episode(_cfg(tmp_path, ci_overlay, "utility-per-metre", sets_upm), progress=False).metrics
    for key in ("views", "frames", "path_length_m", "stop_reason", "table_known_curve", "mean"):
        assert upm[key] == built_in[key], key


def test_a_strategy_that_returns_no_view_fails_the_run_and_keeps_the_map(tmp_path, ci_overlay) -> None:
    cfg = _cfg(tmp_path, ci_overlay, "not-a-view", [f'python_strategy="{BAD}:NotAView"'])
    with pytest.raises(StrategyError, match=r"shape \(3, 3\)"):
        run_episode(cfg, progress=False)
    (run_dir,) = [d for d in tmp_path.glob("*/*not-a-view*") if d.is_dir()]
    assert json.loads((run_dir / "status.json").read_text())["status"] == "failed"
    assert (run_dir / "INCOMPLETE").exists()
    # The Init views' map was written before the strategy was asked.
    assert json.loads((run_dir / "map.json.partial").read_text())["objects"]


def test_bad_python_strategies_are_config_errors_naming_the_key(ci_overlay) -> None:
    def load(*sets: str):
        return load_run_config(overlays=[ci_overlay], overrides=list(sets))

    with pytest.raises(ConfigError, match="python_strategy: .*no such file"):
        load('strategy="mine"', 'python_strategy="experiments/strategies/nothing_here.py:X"')
    with pytest.raises(ConfigError, match="python_strategy: .*has no 'Missing'"):
        load('strategy="mine"', f'python_strategy="{BAD}:Missing"')
    with pytest.raises(ConfigError, match="python_strategy: .*next_view"):
        load('strategy="mine"', f'python_strategy="{BAD}:NoNextView"')
    with pytest.raises(ConfigError, match="python_strategy: expected"):
        load('strategy="mine"', 'python_strategy="no_colon_here"')
    with pytest.raises(ConfigError, match="strategy: 'random' is a built-in"):
        load('strategy="random"', f'python_strategy="{ARGMAX}"')
    with pytest.raises(ConfigError, match="python_strategy_params: given without"):
        load("python_strategy_params.x=1")
    with pytest.raises(ConfigError, match="python_strategy_params: expected a table"):
        load('strategy="mine"', f'python_strategy="{ARGMAX}"', "python_strategy_params=3")
    with pytest.raises(ConfigError, match="or set python_strategy"):
        load('strategy="mine"')
    # The example strategy's file makes its name work like a built-in one.
    cfg = load_run_config(overlays=[ci_overlay], strategy="utility-per-metre")
    assert cfg.python_strategy.endswith("utility_per_metre.py:UtilityPerMetre")
    assert cfg.python_strategy_params == {"metres_per_halving": 0.3}


def test_returned_views_are_checked() -> None:
    pose = np.eye(4)
    pose[:3, 3] = [0.4, 0.0, 0.5]
    assert np.array_equal(as_view(pose.tolist(), "s"), pose)
    assert as_view(None, "s") is None
    bad = {
        "shape": np.eye(3),
        "non-finite": np.where(np.eye(4) > 0, np.nan, 0.0),
        "last row": np.vstack([np.eye(4)[:3], [0.0, 0.0, 1.0, 1.0]]),
        "not a rotation": np.diag([1.0, 1.0, -1.0, 1.0]),
        "not a 4x4": "up",
    }
    for value in bad.values():
        with pytest.raises(StrategyError, match="s returned"):
            as_view(value, "s")


def test_a_strategy_sees_the_unseen_table_cells_the_coverage_counts(tmp_path, ci_overlay) -> None:
    from objslam.scene import load_scene

    cfg = _cfg(tmp_path, ci_overlay, "table-cells", [f'python_strategy="{BAD}:TableCells"'])
    m = run_episode(cfg, progress=False).metrics
    _, n, _, unexplained, _, _, on_table = m["stop_reason"].split("_")
    assert on_table == "True"
    n, unexplained = int(n), int(unexplained)
    # As many unknown cells as the recorded coverage after Init leaves (2 cm cells).
    sx, sy = load_scene(Path(cfg.scene) if Path(cfg.scene).is_absolute() else HERE.parent / cfg.scene).table.size
    total = (sx / cfg.explore["discovery_cell_m"]) * (sy / cfg.explore["discovery_cell_m"])
    known = m["table_known_curve"][-1]
    assert 0 < n < total
    assert abs(n - (1.0 - known) * total) <= 0.01 * total, (n, known, total)
    assert 0 <= unexplained <= n


def _bare_mapper():
    from objslam import _native

    # An empty map over a 0.8 m × 1.2 m table centred at (0.5, 0): every table cell is unknown.
    return _native.ActiveMapper(mapper_config_json="{}", active_config_json="{}", table=(0.5, 0.0, 0.8, 1.2))


def _look_down(x: float, y: float, z: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # OpenCV camera: z (optical axis) down, x along world x
    pose[:3, 3] = [x, y, z]
    return pose


def test_the_table_discovery_view_of_an_empty_map() -> None:
    m = _bare_mapper()
    cam = {"intrinsics": np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]]), "width": 320, "height": 240}
    # 2 cm cells over the whole table, each weighing 1 (no unexplained evidence).
    assert m.query('{"query": "progress"}')["table_unknown_weight"] == pytest.approx((0.8 / 0.02) * (1.2 / 0.02))
    views = m.query('{"query": "table_candidate_views"}', **cam)
    assert views and all(v["world_from_camera"].shape == (4, 4) and v["target_object"] is None for v in views)
    high, low, away = _look_down(0.5, 0.0, 0.8), _look_down(0.5, 0.0, 0.4), _look_down(3.0, 0.0, 0.8)
    gains = m.query('{"query": "table_gain"}', **cam, views=[high, low, away])
    # The inner image (a 10 % border excluded) of a camera looking straight down from height z
    # covers a (0.8 w z / f) × (0.8 h z / f) rectangle of the table: the 2 cm cells whose centres
    # fall in it number between the rectangle shrunk and grown by a cell on each side.
    for g, z in zip(gains[:2], (0.8, 0.4)):
        w, h = 0.8 * 320 * z / 300, 0.8 * 240 * z / 300
        assert (w - 0.04) * (h - 0.04) / 0.02**2 <= g["cells"] <= (w + 0.04) * (h + 0.04) / 0.02**2, (z, g)
        assert g["bits"] == pytest.approx(4.0 * g["cells"])  # (2 cm / 1 cm)² bits per cell
    assert gains[2] == {"cells": 0.0, "unexplained": False, "bits": 0.0}, "looking at the floor"
    # The reserve's greedy count: at most the limit, none when nothing is reachable.
    needed = '{"query": "table_views_needed", "limit": 3}'
    assert 1 <= m.query(needed, **cam, reachable=lambda p: True) <= 3
    assert m.query(needed, **cam, reachable=lambda p: False) == 0


def test_bad_input_to_the_decision_step_bindings_is_a_typed_error() -> None:
    m = _bare_mapper()
    cam = {"intrinsics": np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]]), "width": 320, "height": 240}
    score = '{"query": "score_views", "utility": "object-driven"}'
    with pytest.raises(ValueError, match=r"views\[1\]"):
        m.query('{"query": "table_gain"}', **cam, views=[_look_down(0.5, 0.0, 0.8), np.eye(3)])
    with pytest.raises(ValueError, match=r"views\[0\]"):
        m.query(score, **cam, views=[np.full((4, 4), np.nan)], world_from_camera=np.eye(4))
    with pytest.raises(ValueError, match="unknown variant `greedy`"):
        m.query('{"query": "score_views", "utility": "greedy"}', **cam, views=[np.eye(4)])
    with pytest.raises(ValueError, match="utility"):
        m.query('{"query": "score_views", "utility": "random"}', **cam, views=[np.eye(4)])
    with pytest.raises(ValueError, match="query_json"):
        m.query('{"query": "everything"}', **cam)

    def broken(_pose):
        raise RuntimeError("IK server down")

    # The callback's own error reaches the caller, not a panic or a silent "unreachable".
    with pytest.raises(RuntimeError, match="IK server down"):
        m.query('{"query": "table_views_needed", "limit": 3}', **cam, reachable=broken)
