"""docs/python.md runs as written (at the CI overlay's reduced resolution, into a temporary runs
folder), and everything ``objslam`` lists as public is importable."""

from __future__ import annotations

import re
from pathlib import Path

import objslam
import pytest

REPO = Path(__file__).resolve().parents[1]


def test_public_names_import() -> None:
    missing = [name for name in objslam.__all__ if getattr(objslam, name, None) is None]
    assert missing == []
    assert objslam.RunConfig().scene.endswith(".toml")


def code_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.DOTALL)


def test_python_quick_start_runs(tmp_path, ci_overlay, monkeypatch, capsys) -> None:
    import objslam.config

    real = objslam.config.load_run_config

    def cheap(*, overlays=(), overrides=(), strategy=None):
        # The page's calls, at quarter resolution and into tmp_path.
        return real(
            overlays=[ci_overlay, *overlays],
            overrides=[*overrides, f'runs_dir="{tmp_path}"'],
            strategy=strategy,
        )

    monkeypatch.setattr(objslam.config, "load_run_config", cheap)
    monkeypatch.chdir(REPO)
    blocks = code_blocks(REPO / "docs" / "python.md")
    assert len(blocks) >= 4
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "docs/python.md", "exec"), namespace)  # noqa: S102 - the page is the test
    result = namespace["result"]
    assert result.run_dir.parent.parent == tmp_path
    assert 0.3 < result.metrics["mean"]["iou3d"] <= 1.0
    assert namespace["evaluation"]["n_objects_gt"] == result.metrics["n_objects_gt"]
    # The scene file's truth and the simulator's final poses give nearly the same evaluation.
    assert namespace["evaluation"]["mean"]["iou3d"] == pytest.approx(result.metrics["mean"]["iou3d"], abs=0.05)
    assert namespace["quiet"].record.enabled is False
    out = capsys.readouterr().out
    assert "3D IoU" in out and "matched" in out


def test_the_docs_stay_short_and_nothing_edits_the_import_path() -> None:
    """The newcomer's docs keep their size (README at most 150 lines and 12,000 characters,
    ARCHITECTURE at most 15,000 characters), and no Python file of the repository edits
    ``sys.path`` (the package is installed; scripts import their neighbours as scripts do)."""
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 150 and len(readme) <= 12_000, (len(readme.splitlines()), len(readme))
    assert len((REPO / "ARCHITECTURE.md").read_text()) <= 15_000
    offenders = [
        str(p.relative_to(REPO))
        for folder in ("sim", "experiments", "tests", "studies", "scripts")
        for p in (REPO / folder).rglob("*.py")
        if "sys.path." + "insert" in p.read_text()
    ]
    assert offenders == []
