"""Example Python strategy (``objslam.strategy``): the built-in ``object-driven`` decision in full,
the paper's rule plus the table-discovery extension as the run's ``[explore]`` settings configure
it, written against the strategy interface. Start here when a strategy should keep the
discovery behaviour of the built-in one (``paper_argmax.py`` is the paper's rule alone).

Per decision, as the core's ``ActiveSession::next_view`` does:

1. the paper's stopping rule; with ``stop_when_explored = false`` "all explored" keeps scoring
   every object; with ``discovery_before_stop`` it looks at the unseen table first while the
   weighted unseen cells are at least ``discovery_min_new_cells``;
2. the budget reserve (``discovery_reserve``): once the table views still worth taking are no
   fewer than the views left, the rest goes to the table;
3. candidates: the paper's views around the objects still to explore, plus the table candidates
   when ``discovery_weight`` > 0 (table candidates alone on a table-only step);
4. score: the utility plus ``discovery_weight`` × the table gain in bits (the gain alone on a
   table-only step, where only views revealing ``discovery_min_new_cells`` count); the best
   reachable view.

With the same seed it chooses the same views as the built-in strategy (``tests/test_strategy.py``).
Its config: ``experiments/configs/strategies/object-driven-py.toml``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from objslam.strategy import DecisionStep


class ObjectDriven:
    """The built-in object-driven (or expected-gain, ``utility``) decision with table discovery."""

    def __init__(self, utility: str = "object-driven") -> None:
        self.utility = utility

    def next_view(self, step: DecisionStep) -> npt.NDArray[np.float64] | None:
        ex = step.explore
        min_new = float(ex["discovery_min_new_cells"])
        weight = float(ex["discovery_weight"])
        discovery = weight > 0.0 or ex["discovery_before_stop"] or ex["discovery_reserve"]
        unknown = step.table_unknown_weight() if discovery else 0.0
        if unknown < min_new and weight <= 0.0:
            unknown = 0.0  # too little unseen table to be worth a view, and no mixed term
        explore_all = table_only = False
        reason = step.paper_stop()
        if reason == "all_explored" and not ex["stop_when_explored"]:
            explore_all = True
        elif reason == "all_explored" and ex["discovery_before_stop"] and unknown >= min_new:
            table_only = True
        elif reason is not None:
            step.stop_reason = reason
            return None
        if not table_only and ex["discovery_reserve"] and unknown >= min_new:
            left = step.max_views - step.views_taken
            table_only = step.table_views_needed(left) >= left
        mixed = unknown > 0.0 and (table_only or weight > 0.0)
        views = []
        if not table_only:
            around = [f["object_id"] for f in step.features() if f["explore"] or explore_all]
            views = step.candidates(around)
        if mixed:
            views += step.table_candidates()
        if not views:
            step.stop_reason = "all_explored" if table_only else "no_reachable_view"
            return None
        score = step.utilities(views, self.utility, explore_every_object=explore_all)
        if mixed:
            gains = step.table_gain(views)
            bits = np.array([g["bits"] for g in gains])
            score = score + (1.0 if table_only else weight) * bits
            if table_only:
                score[[g["cells"] < min_new for g in gains]] = -np.inf
            step.table_drawn = True
        step.log_candidates(views, score)
        best = step.best_reachable(views, score)
        if best is None:
            step.stop_reason = "all_explored" if table_only else "no_reachable_view"
        return best
