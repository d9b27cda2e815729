"""List run folders by status: ``python -m objslam.runs [RUNS_DIR] [--status S ...] [--json]``.

A run folder (see :mod:`objslam.episode`) has a ``status.json``: ``complete``, ``failed``,
``interrupted`` (SIGINT), ``terminated`` (SIGTERM) or ``running``. A run killed outright (SIGKILL,
a crash of the machine) never got to write its end, so its file still says ``running``; this
command reports it as ``dead`` when its pid no longer runs on this host (or no longer runs
Python), and as ``running?`` when it was started on another host, where its pid cannot be checked
(or by a build that did not record the pid).
A folder without ``status.json`` (made by an older build, or the disk was full) is ``unknown``.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from .config import REPO_ROOT

#: Every status a run can be listed with.
STATUSES = ("complete", "failed", "interrupted", "terminated", "running", "dead", "running?", "unknown")


@dataclass(frozen=True)
class RunInfo:
    """One run folder's status, as listed."""

    path: str
    """The run folder."""
    status: str
    """One of :data:`STATUSES`."""
    pid: int | None
    """Process id of the run (None in folders made before it was recorded)."""
    host: str | None
    """Host name the run was started on."""
    started: str | None
    """ISO start time."""
    finished: str | None
    """ISO end time (None while running or when it died)."""
    incomplete: bool
    """Whether the folder still has its ``INCOMPLETE`` marker."""
    error: str | None
    """Why it stopped, for failed, interrupted and terminated runs."""


def pid_alive(pid: int) -> bool:
    """Whether a process with this pid runs on this host and is a Python process (a recycled pid
    of another program does not count). Without ``/proc`` only the pid's existence is checked."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by someone else
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return True
    return b"python" in cmdline.split(b"\0")[0]


def run_info(run_dir: Path) -> RunInfo:
    """The status of one run folder, with dead runs told from live ones (see the module docs)."""
    incomplete = (run_dir / "INCOMPLETE").exists()
    try:
        data = json.loads((run_dir / "status.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        data = {}
    if not isinstance(data, dict):
        data = {}
    status = data.get("status") if isinstance(data.get("status"), str) else "unknown"
    pid = data.get("pid") if isinstance(data.get("pid"), int) else None
    host = data.get("host") if isinstance(data.get("host"), str) else None
    if status == "running":
        if pid is None or (host is not None and host != socket.gethostname()):
            status = "running?"
        elif not pid_alive(pid):
            status = "dead"
    if status not in STATUSES:
        status = "unknown"
    return RunInfo(
        path=str(run_dir),
        status=status,
        pid=pid,
        host=host,
        started=data.get("started"),
        finished=data.get("finished"),
        incomplete=incomplete,
        error=data.get("error"),
    )


def list_runs(runs_dir: Path) -> list[RunInfo]:
    """Every run folder under ``runs_dir`` (``<date>/<run>/``), oldest first."""
    if not runs_dir.is_dir():
        return []
    dirs = sorted(
        p
        for day in runs_dir.iterdir()
        if day.is_dir() and not day.is_symlink()
        for p in day.iterdir()
        if p.is_dir() and ((p / "status.json").exists() or (p / "INCOMPLETE").exists() or (p / "config.toml").exists())
    )
    return [run_info(d) for d in dirs]


def main(argv: list[str] | None = None) -> int:
    """Print the runs, one line each, and a count per status."""
    ap = argparse.ArgumentParser(
        prog="python -m objslam.runs", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("runs_dir", nargs="?", default=str(REPO_ROOT / "runs"), help="runs folder (default: runs/)")
    ap.add_argument("--status", action="append", choices=STATUSES, help="only runs with this status (repeatable)")
    ap.add_argument("--json", action="store_true", help="one JSON list instead of lines")
    a = ap.parse_args(argv)
    runs = [r for r in list_runs(Path(a.runs_dir)) if not a.status or r.status in a.status]
    if a.json:
        print(json.dumps([asdict(r) for r in runs], indent=2))
        return 0
    for r in runs:
        where = f"pid {r.pid} on {r.host}" if r.pid is not None else "no pid recorded"
        why = f"  ({r.error})" if r.error and r.status != "complete" else ""
        print(f"{r.status:<11} {r.started or '-':<19}  {r.path}  [{where}]{why}")
    counts = {s: sum(r.status == s for r in runs) for s in STATUSES}
    print(", ".join(f"{n} {s}" for s, n in counts.items() if n) or "no runs", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
