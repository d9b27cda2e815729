"""Example Python strategy (``objslam.strategy``): the paper's utility discounted by the distance
the camera travels to the view, ``f(x) · 2^(−d / metres_per_halving)``.

Information gain discounted exponentially by path length is the classic trade-off of
next-best-view planners that pay for motion (e.g. Bircher et al.'s receding-horizon NBV planner,
gain · exp(−λ d)); the paper's object-driven utility has no motion term. Distance here is the
straight line between camera centres (the default Cartesian camera path travels it). Everything
else is the paper's: its candidate views around the objects still to explore, its utility, its
stopping rule (every object done, or the budget). With ``metres_per_halving`` → ∞ it is the
paper's argmax. With ``discovery = true`` it discounts the built-in decision's scores instead, the
table-discovery extension included (``objslam.strategy.built_in_scores``), so that with
``metres_per_halving`` → ∞ it is the built-in ``object-driven``.

Run it like a built-in strategy (its config is ``experiments/configs/strategies/utility-per-metre.toml``):
``python experiments/run.py --strategy utility-per-metre``, or in the benchmark with
``--strategies object-driven utility-per-metre``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from objslam.strategy import DecisionStep, built_in_scores


class UtilityPerMetre:
    """The paper's utility × 2^(−distance / ``metres_per_halving``), argmax over reachable views."""

    def __init__(self, metres_per_halving: float = 0.3, utility: str = "object-driven", discovery: bool = False) -> None:
        if not (np.isfinite(metres_per_halving) and metres_per_halving > 0.0):
            raise ValueError(f"metres_per_halving: must be a finite number > 0, got {metres_per_halving!r}")
        self.metres_per_halving = float(metres_per_halving)
        self.utility = utility
        self.discovery = bool(discovery)

    def _discount(self, step: DecisionStep, views: list[npt.NDArray[np.float64]]) -> npt.NDArray[np.float64]:
        here = step.world_from_camera[:3, 3]
        dist = np.array([np.linalg.norm(v[:3, 3] - here) for v in views])
        return np.exp2(-dist / self.metres_per_halving)

    def next_view(self, step: DecisionStep) -> npt.NDArray[np.float64] | None:
        if self.discovery:
            return self._built_in_discounted(step)
        reason = step.paper_stop()
        if reason is not None:
            step.stop_reason = reason
            return None
        around = [f["object_id"] for f in step.features() if f["explore"]]
        views = step.candidates(around)
        if not views:
            step.stop_reason = "no_candidate"
            return None
        score = step.utilities(views, self.utility) * self._discount(step, views)
        step.log_candidates(views, score)
        best = step.best_reachable(views, score)
        if best is None:
            step.stop_reason = "no_reachable_view"
        return best

    def _built_in_discounted(self, step: DecisionStep) -> npt.NDArray[np.float64] | None:
        s = built_in_scores(step, self.utility)
        if s.stop is not None:
            step.stop_reason = s.stop
            return None
        if not s.views:
            step.stop_reason = "all_explored" if s.table_only else "no_candidate"
            return None
        score = s.scores * self._discount(step, s.views)
        step.table_drawn = s.table_drawn
        step.log_candidates(s.views, score)
        best = step.best_reachable(s.views, score)
        if best is None:
            step.stop_reason = "all_explored" if s.table_only else "no_reachable_view"
        return best
