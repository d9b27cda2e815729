"""Python strategies for tests/test_strategy.py: two wrong on purpose, two that report what they saw."""

from __future__ import annotations

import numpy as np
from objslam.strategy import load_strategy_class

ObjectDriven = load_strategy_class("experiments/strategies/object_driven.py:ObjectDriven")


class NotAView:
    """Returns a 3x3 matrix."""

    def next_view(self, step):
        return np.eye(3)


class NoNextView:
    pass


class TableCells:
    """Stops at once, saying in its stop reason how many table cells are unknown and unexplained,
    and whether every unknown cell centre lies on the table top."""

    def next_view(self, step) -> None:
        pts, unexplained = step.table_unknown_cells()
        (cx, cy), (sx, sy) = step.table_center, step.table_size
        on_table = bool(
            len(pts) == 0
            or (
                (np.abs(pts[:, 2]) <= 0.005).all()
                and (np.abs(pts[:, 0] - cx) <= sx / 2).all()
                and (np.abs(pts[:, 1] - cy) <= sy / 2).all()
            )
        )
        step.stop_reason = f"unknown_{len(pts)}_unexplained_{int(np.sum(unexplained))}_on_table_{on_table}"


class CountingObjectDriven(ObjectDriven):
    """The example object_driven.py, counting (class-wide) the decisions the table gain drew."""

    table_drawn_steps = 0

    def next_view(self, step):
        view = super().next_view(step)
        type(self).table_drawn_steps += int(step.table_drawn)
        return view
