"""Placement slot lines (pure geometry, no simulator)."""

import itertools
import math

from objslam.place import PlaceConfig, free_line


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
