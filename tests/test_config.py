"""The run configuration: one model, the core's tables passed through untouched."""

from __future__ import annotations

import json

import pytest
import tomllib
from objslam import _native
from objslam.config import CONFIG_DIR, CORE_TABLES, ConfigError, load_run_config


def _leaves(d: dict, prefix: str = "") -> dict[str, object]:
    out: dict[str, object] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_leaves(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def test_default_toml_core_tables_equal_the_core_defaults() -> None:
    """Every core value written in default.toml is the core's own default (one source of truth)."""
    written = tomllib.loads((CONFIG_DIR / "default.toml").read_text())
    core = json.loads(_native.resolve_config("{}"))
    for table in CORE_TABLES:
        assert table in written, f"default.toml has no [{table}]"
        theirs = _leaves(core[table])
        for key, value in _leaves(written[table]).items():
            assert key in theirs, f"{table}.{key}: not a core key"
            expected = theirs[key]
            if isinstance(value, float) or isinstance(expected, float):
                assert value == pytest.approx(expected, rel=1e-12), f"{table}.{key}: {value} vs core {expected}"
            else:
                assert value == expected, f"{table}.{key}: {value!r} vs core {expected!r}"


def test_a_run_config_holds_every_core_key_resolved() -> None:
    cfg = load_run_config()
    core = json.loads(_native.resolve_config("{}"))
    assert cfg.explore["max_views"] == 10 and cfg.explore["lambda"] == 0.2
    assert set(_leaves(cfg.map)) == {k for k, v in _leaves(core["map"]).items() if v is not None}
    assert "strategy" not in cfg.explore and "pose_source" not in cfg.slam


def test_core_keys_change_with_set_and_reach_the_core_tables() -> None:
    cfg = load_run_config(overrides=["map.param.iforest.passes=4", 'map.association_mode="iou"'])
    assert cfg.map["param"]["iforest"]["passes"] == 4
    assert cfg.map["association_mode"] == "iou"


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("map.min_observations=0", "map.min_observations"),
        ("map.param.iforest.passes=0", "map.param.iforest.passes"),
        ("map.param.iforest.pases=2", "map.param.iforest"),
        ('map.association_mode="nearest"', "map.association_mode"),
        ("explore.lambda=-1", "explore"),
        ("explore.max_view=3", "explore"),
        ("eval.max_match_distance_m=0", "eval.max_match_distance_m"),
        ("slam.motion_gate_floor_m=-1", "slam.motion_gate_floor_m"),
        ('slam.pose_source="fk"', "slam.pose_source"),
        ('explore.strategy="random"', "explore.strategy"),
        ("map=3", "map"),
    ],
)
def test_bad_core_values_name_the_key(override: str, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_run_config(overrides=[override])


def test_grasp_and_place_settings_are_run_config_tables() -> None:
    cfg = load_run_config(overrides=["grasp.contact_retries=0", "place.feel_support=false"])
    assert cfg.grasp.contact_retries == 0 and cfg.place.feel_support is False
    with pytest.raises(ConfigError, match=r"grasp\.contact_retry"):
        load_run_config(overrides=["grasp.contact_retry=1"])


def test_a_run_folder_config_with_a_retired_key_still_loads(tmp_path) -> None:
    """A stored run config that names a setting the code no longer has loads with a warning; the
    same key given as an override is an error naming it."""
    from objslam.config import RETIRED_KEYS, ConfigError, load_run_config

    key = next(iter(RETIRED_KEYS))
    stored = tmp_path / "config.toml"
    stored.write_text('[slam.orb]\npattern_seed = 7\nn_features = 900\n')
    with pytest.warns(UserWarning, match=key):
        cfg = load_run_config(overlays=[stored])
    assert cfg.slam["orb"]["n_features"] == 900
    with pytest.raises(ConfigError, match="pattern_seed"):
        load_run_config(overrides=[f"{key}=7"])
