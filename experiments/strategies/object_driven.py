"""Example Python strategy (``objslam.strategy``): the built-in ``object-driven-discovery`` decision
in full, the paper's utility plus the table-discovery extension as the run's ``[explore]`` settings
configure it. Start here when a strategy should keep the discovery behaviour of the built-in one
(``paper_argmax.py`` is the paper's rule alone, written out call by call).

``objslam.strategy.built_in_scores`` gives the built-in's candidates and scores at the step (its
docs list the rules); ``take_best`` takes the best reachable one, as the built-in does. With the
same seed it chooses the same views as the built-in strategy (``tests/test_strategy.py``,
``studies/python_strategy/README.md``). Its config:
``experiments/configs/strategies/object-driven-py.toml``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from objslam.strategy import DecisionStep, built_in_scores, take_best


class ObjectDriven:
    """The built-in object-driven-discovery (or expected-gain, ``utility``) decision."""

    def __init__(self, utility: str = "object-driven-discovery") -> None:
        self.utility = utility

    def next_view(self, step: DecisionStep) -> npt.NDArray[np.float64] | None:
        return take_best(step, built_in_scores(step, self.utility))
