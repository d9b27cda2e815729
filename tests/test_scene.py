"""Scene files: the benchmark scenes are valid; malformed files get errors naming file and field."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from objslam.scene import (
    CLASSES,
    SceneFileError,
    generate_scene,
    load_scene,
    parse_scene,
    scene_to_toml,
)

from .conftest import SCENES


def test_seven_benchmark_scenes_with_growing_counts() -> None:
    assert len(SCENES) >= 7
    specs = [load_scene(p) for p in SCENES]
    counts = [len(s.objects) for s in specs]
    assert counts[:5] == sorted(counts[:5]) and counts[0] <= 4 and counts[4] >= 12
    for s in specs:
        assert s.character, f"{s.name} must state its character"
        classes = {o.cls for o in s.objects}
        assert classes <= set(CLASSES)
        graspable = sum(o.graspable for o in s.objects)
        assert graspable / len(s.objects) > 0.5, f"{s.name}: most objects must be graspable"
    all_classes = {o.cls for s in specs for o in s.objects}
    assert {"block", "book", "cup"} <= all_classes and all_classes & {"can", "bottle"}


GOOD = {
    "scene": {"name": "t", "character": "test", "seed": 1},
    "table": {"center": [0.5, 0.0], "size": [0.8, 1.2]},
    "objects": [{"class": "block", "position": [0.5, 0.0], "yaw_deg": 0.0, "size": [0.05, 0.05, 0.05]}],
}


def _with(path: tuple, value) -> dict:
    import copy

    d = copy.deepcopy(GOOD)
    cur = d
    for k in path[:-1]:
        cur = cur[k]
    if value is KeyError:
        del cur[path[-1]]
    else:
        cur[path[-1]] = value
    return d


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        (("scene", "seed"), -1, "scene.seed"),
        (("scene", "name"), KeyError, "scene.name"),
        (("table", "size"), [0.8], "table.size"),
        (("objects", 0, "class"), "chair", "objects[0].class"),
        (("objects", 0, "size"), [0.05, float("nan"), 0.05], "objects[0].size[1]"),
        (("objects", 0, "size"), [0.05, 0.05, -0.05], "objects[0].size[2]"),
        (("objects", 0, "position"), [2.0, 0.0], "objects[0].position"),
        (("objects", 0, "colour"), "red", "objects[0]"),
        (("objects",), [], "objects"),
    ],
)
def test_malformed_scene_names_the_field(path, value, field) -> None:
    with pytest.raises(SceneFileError) as e:
        parse_scene(_with(path, value), "bad.toml")
    assert e.value.field == field
    assert "bad.toml" in str(e.value) and field in str(e.value)


def test_overlapping_objects_and_bad_toml_are_rejected(tmp_path: Path) -> None:
    d = _with(("objects",), GOOD["objects"] * 2)
    with pytest.raises(SceneFileError, match="overlaps"):
        parse_scene(d, "x.toml")
    p = tmp_path / "broken.toml"
    p.write_text("[scene\nname=")
    with pytest.raises(SceneFileError) as e:
        load_scene(p)
    assert e.value.field == "<toml>" and "broken.toml" in str(e.value)
    with pytest.raises(SceneFileError, match="cannot read"):
        load_scene(tmp_path / "missing.toml")


def test_cylinder_needs_radius_and_height() -> None:
    d = _with(("objects", 0), {"class": "cup", "position": [0.5, 0.0], "size": [0.05, 0.05, 0.1]})
    with pytest.raises(SceneFileError, match="radius and height"):
        parse_scene(d, "c.toml")


def test_generator_is_deterministic_valid_and_round_trips(tmp_path: Path) -> None:
    a = generate_scene(seed=5, n_objects=9, name="g")
    b = generate_scene(seed=5, n_objects=9, name="g")
    c = generate_scene(seed=6, n_objects=9, name="g")
    assert a.objects == b.objects and a.objects != c.objects
    p = tmp_path / "g.toml"
    p.write_text(scene_to_toml(a))
    back = load_scene(p)
    for x, y in zip(a.objects, back.objects):
        assert x.cls == y.cls and math.isclose(x.position[0], y.position[0], abs_tol=1e-3)
    with pytest.raises(ValueError, match="could not place"):
        generate_scene(seed=1, n_objects=60, name="full", max_tries=200)
