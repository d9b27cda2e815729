"""Shared fixtures. Tests run at reduced resolution (experiments/configs/ci.toml) to keep CI fast."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCENES = sorted((REPO / "scenes").glob("scene*.toml"))


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def ci_overlay() -> Path:
    return REPO / "experiments" / "configs" / "ci.toml"
