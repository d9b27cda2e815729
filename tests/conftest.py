"""Shared fixtures. Tests run at reduced resolution (experiments/configs/ci.toml) to keep CI fast."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCENES = sorted((REPO / "scenes").glob("scene*.toml"))


# Fixtures and modules that run the SAPIEN simulator: their tests are marked slow.
SIMULATOR_FIXTURES = {"ci_overlay", "scene01_session"}
SIMULATOR_MODULES = {"test_episode", "test_sim", "test_place_feel"}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        module = item.module.__name__.rsplit(".", 1)[-1] if item.module else ""
        if SIMULATOR_FIXTURES & set(getattr(item, "fixturenames", ())) or module in SIMULATOR_MODULES:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def ci_overlay() -> Path:
    return REPO / "experiments" / "configs" / "ci.toml"
