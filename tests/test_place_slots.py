"""Placement slot lines (pure geometry, no simulator)."""

import itertools
import math

from objslam.place import free_line
from objslam.task_config import PlaceConfig


def _box(x: float, y: float, half: float = 0.03) -> dict:
    return {"label": "block", "geometry": {"shape": "cuboid", "center": [x, y, half], "yaw_rad": 0.0,
                                           "half_extents": [half, half, half]}}


def test_slots_are_spaced_as_asked_and_clear_the_map() -> None:
    cfg = PlaceConfig()
    for spacing in (cfg.slot_spacing_m, cfg.tall_slot_spacing_m):
        slots = free_line([], 3, cfg, spacing)
        assert slots is not None and len(slots) == 3
        gaps = [math.dist(a, b) for a, b in itertools.pairwise(slots)]
        assert all(abs(g - spacing) < 1e-9 for g in gaps)
    # An object on the nearest line pushes the line away from it by at least the clearance.
    blocked = free_line([_box(0.28, 0.0)], 3, cfg, cfg.tall_slot_spacing_m)
    assert blocked is not None
    assert all(math.dist(s, (0.28, 0.0)) >= 0.03 + cfg.slot_clearance_m - 1e-9 for s in blocked)


def test_the_letting_go_table_counts_how_each_item_was_let_go() -> None:

    import place

    def td(how: str | None, depth: float | None, gap: float | None) -> dict:
        d: dict = {"true_gap_m": gap}
        if how is not None:
            d.update(felt=how != "none", how=how, depth_m=depth, force_n=5.0)
        return d

    rows = [
        {"task": "cups_by_volume", "steps": [{"pick": 1, "touchdown": td("contact", 0.018, 0.0002)},
                                             {"pick": 2, "touchdown": td("contact", 0.020, 0.0004)},
                                             {"pick": 3, "touchdown": {"felt": False, "cause": "no_path", "true_gap_m": 0.019}}]},
        {"task": "cups_by_volume", "steps": [{"pick": 4, "touchdown": td("stuck", 0.0005, 0.0001)},
                                             {"pick": 5, "touchdown": None}]},
        {"task": "bottles_by_height", "steps": [{"pick": 6, "touchdown": td(None, None, 0.004)}]},
    ]
    lines = place.release_table(rows, ["block_in_cup", "cups_by_volume", "bottles_by_height"])
    assert "| cups_by_volume | 4 | 2 | 1 | 1 | 18.0 / 20.0 | 0.3 / 19.0 |" in lines
    # Without the feel: no slow descent, the drop's true gap.
    assert "| bottles_by_height | 1 | 0 | 0 | 1 | - | 4.0 / 4.0 |" in lines
    assert not any(line.startswith("| block_in_cup") for line in lines)
