"""Example Python strategy (``objslam.strategy``), the template to start from: the paper's
object-driven rule written against the strategy interface.

Stop when the paper's rule says so (every object's s(x) = 0, or the budget); else sample the
paper's candidate views around the objects still to explore, score them with the paper's utility
f = Σ ((1 − R_o) H_obj + λ (H_IoU + H_V)) s(x), and take the best reachable one. It chooses the same
views as the built-in ``object-driven``, so the same seed gives the same metrics (``tests/test_strategy.py``). Its config:
``experiments/configs/strategies/paper-argmax.toml``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from objslam.strategy import DecisionStep, paper_scores, take_best


class PaperArgmax:
    """The paper's stopping rule, then the argmax of a utility over the reachable candidates."""

    def __init__(self, utility: str = "object-driven") -> None:
        self.utility = utility

    def next_view(self, step: DecisionStep) -> npt.NDArray[np.float64] | None:
        # objslam.strategy.paper_scores spells the rule out through the step's calls (paper_stop,
        # features, candidates, utilities); take_best asks reachability (IK and collisions) in
        # score order, so it runs only for the best.
        return take_best(step, paper_scores(step, self.utility))
