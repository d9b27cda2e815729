"""Provenance of a generated report: the commit, command, machine and resolved config it was made with.

Every report writer in ``experiments/`` merges ``provenance(argv, config)`` into the JSON it writes, so
a report names the code that made it (``commit``, with ``-dirty`` when the work tree had uncommitted
changes), how to make it again (``command``), where it ran (``machine``) and with which settings
(``config``).
"""

from __future__ import annotations

import os
import platform
import shlex
import subprocess
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=30, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout


def commit() -> str:
    """``git rev-parse HEAD`` of the repository, ``-dirty`` appended when ``git status --porcelain`` lists
    anything outside ``reports/`` (the generated reports themselves, which a writer may rewrite while it
    runs, do not make the code dirty); ``"unknown"`` outside a git checkout."""
    head = _git("rev-parse", "HEAD")
    if head is None:
        return "unknown"
    status = _git("status", "--porcelain", "--", ".", ":(exclude)reports")
    return head.strip() + ("-dirty" if status else "")


def machine() -> str:
    """Host name, CPU model and count, memory and OS, one line."""
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        mem = f"{os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') / 2**30:.0f} GiB, "
    except (ValueError, OSError, AttributeError):
        mem = ""
    return (
        f"{platform.node()}: {cpu}, {os.cpu_count()} cores, {mem}{platform.system()} {platform.release()}, "
        f"Python {platform.python_version()}"
    )


def provenance(command_argv: list[str] | str, config: dict[str, Any] | None) -> dict[str, Any]:
    """``{"commit", "command", "machine", "config"}`` for a report's JSON.

    ``command_argv``: the command line that made the report (a list is shell-quoted and joined; a string is
    kept as given). ``config``: the resolved settings the report was made with (JSON-serialisable).
    """
    command = command_argv if isinstance(command_argv, str) else shlex.join(command_argv)
    return {"commit": commit(), "command": command, "machine": machine(), "config": config or {}}


def run_config(
    overlays: list[str] | tuple[str, ...] = (), overrides: list[str] | tuple[str, ...] = ()
) -> dict[str, Any]:
    """The run config a sweep's episodes start from (``default.toml`` ← overlays ← ``--set`` overrides),
    resolved, with the overlays and overrides that made it; per-episode settings (strategy, scene,
    seed, a sweep's own rows) come on top and are recorded by the report's rows."""
    from objslam.config import load_run_config, to_dict

    resolved = to_dict(load_run_config(overlays=list(overlays), overrides=list(overrides)))
    return {"overlays": list(overlays), "overrides": list(overrides), "resolved": resolved}


def report_files(out: Path | str, name: str) -> tuple[Path, Path]:
    """Where report ``name`` goes under the reports folder ``out``: its JSON at ``out/<name>.json``
    and its Markdown page (with its figures beside it) at ``out/pages/<name>.md``; makes the folders."""
    out = Path(out)
    (out / "pages").mkdir(parents=True, exist_ok=True)
    return out / f"{name}.json", out / "pages" / f"{name}.md"
