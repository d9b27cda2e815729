"""The map's class size priors (``map.class_sizes``) hold every object the scene generators make.

The core holds back an estimate outside its label's sizes (``map.class_size_tolerance``); a prior
narrower than the world's objects would hold back real ones. Checked against the primitives'
ranges (``objslam.scene.CLASS_SIZES``), every mesh asset at both ends of its scale range, and the
ground truth of every scene file.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from objslam import _native
from objslam.meshes import ASSETS, placed_mesh
from objslam.scene import CLASS_SIZES, CUBOID_CLASSES, CYLINDER_CLASSES, load_scene

REPO = Path(__file__).resolve().parents[1]
PRIORS = json.loads(_native.resolve_config("{}"))["map"]["class_sizes"]
SCENES = sorted(REPO.glob("scenes/*.toml")) + sorted(REPO.glob("scenes/hard/*.toml")) + sorted(REPO.glob("scenes/test/*.toml"))


def _inside(label: str, extent: float, height: float, what: str) -> None:
    p = PRIORS[label]
    (e0, e1), (h0, h1) = p["extent_m"], p["height_m"]
    assert e0 <= extent <= e1, f"{what}: {label} extent {extent:.4f} m outside [{e0}, {e1}]"
    assert h0 <= height <= h1, f"{what}: {label} height {height:.4f} m outside [{h0}, {h1}]"


def test_every_label_has_a_prior() -> None:
    assert set(PRIORS) == set(CUBOID_CLASSES) | set(CYLINDER_CLASSES)


@pytest.mark.parametrize("label", sorted(CLASS_SIZES))
def test_the_primitive_ranges_lie_inside(label: str) -> None:
    ranges = CLASS_SIZES[label]
    if label in CUBOID_CLASSES:
        (x0, x1), (y0, y1), (z0, z1) = ranges
        for ext, h in ((max(x0, y0), z0), (max(x1, y1), z1)):
            _inside(label, ext, h, "CLASS_SIZES")
    else:
        (r0, r1), (h0, h1) = ranges
        _inside(label, 2 * r0, h0, "CLASS_SIZES")
        _inside(label, 2 * r1, h1, "CLASS_SIZES")


@pytest.mark.parametrize("name", sorted(ASSETS))
def test_every_mesh_at_its_scale_ends_lies_inside(name: str) -> None:
    a = ASSETS[name]
    shape = "cylinder" if a.label in CYLINDER_CLASSES else "cuboid"
    for scale in a.scale_range:
        m = placed_mesh(name, scale=scale, mesh_yaw_rad=0.0, shape=shape)
        hx, hy, hz = m.half_extents
        _inside(a.label, 2 * max(hx, hy), 2 * hz, f"{name} at scale {scale}")


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_every_scene_object_lies_inside(path: Path) -> None:
    for o in load_scene(path).objects:
        hx, hy, hz = o.half_extents
        assert math.isfinite(hx + hy + hz)
        _inside(o.cls, 2 * max(hx, hy), 2 * hz, f"{path.stem} object {o.id}")
