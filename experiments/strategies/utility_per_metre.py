"""Example Python strategy (``objslam.strategy``): the paper's utility discounted by the distance
the camera travels to the view, ``f(x) · 2^(−d / metres_per_halving)``.

Information gain discounted exponentially by path length is the classic trade-off of
next-best-view planners that pay for motion (e.g. Bircher et al.'s receding-horizon NBV planner,
gain · exp(−λ d)); the paper's object-driven utility has no motion term. Distance here is the
straight line between camera centres (the default Cartesian camera path travels it). Everything
else is the paper's: its candidate views around the objects still to explore, its utility, its
stopping rule (every object done, or the budget). With ``metres_per_halving`` → ∞ it is the
built-in strategy named by ``utility`` (``objslam.strategy.built_in_scores``): the paper's
``object-driven`` (default), or ``object-driven-discovery`` with the table-discovery extension.

Run it like a built-in strategy (its config is ``experiments/configs/strategies/utility-per-metre.toml``):
``python experiments/run.py --strategy utility-per-metre``, or in the benchmark with
``--strategies object-driven utility-per-metre``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from objslam.strategy import DecisionStep, built_in_scores, take_best


class UtilityPerMetre:
    """The paper's utility × 2^(−distance / ``metres_per_halving``), argmax over reachable views."""

    def __init__(self, metres_per_halving: float = 0.3, utility: str = "object-driven") -> None:
        if not (np.isfinite(metres_per_halving) and metres_per_halving > 0.0):
            raise ValueError(f"metres_per_halving: must be a finite number > 0, got {metres_per_halving!r}")
        self.metres_per_halving = float(metres_per_halving)
        self.utility = utility

    def _discount(self, step: DecisionStep, views: list[npt.NDArray[np.float64]]) -> npt.NDArray[np.float64]:
        here = step.world_from_camera[:3, 3]
        dist = np.array([np.linalg.norm(v[:3, 3] - here) for v in views])
        return np.exp2(-dist / self.metres_per_halving)

    def next_view(self, step: DecisionStep) -> npt.NDArray[np.float64] | None:
        s = built_in_scores(step, self.utility)
        return take_best(step, s, s.scores * self._discount(step, s.views) if s.views else None)
