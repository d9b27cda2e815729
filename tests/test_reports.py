"""Reports as a product: every report records its provenance, and the index lists every report."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REPORTS = REPO / "reports"


def report_files(root: Path) -> list[Path]:
    return sorted(root.glob("*.json"))


def test_every_report_json_records_commit_command_machine_and_config() -> None:
    files = report_files(REPORTS)
    assert files, "no report JSON under reports/"
    for f in files:
        data = json.loads(f.read_text())
        missing = [k for k in ("commit", "command", "machine", "config") if k not in data]
        assert not missing, f"{f.relative_to(REPO)} lacks {missing}"
        assert re.fullmatch(r"[0-9a-f]{40}(-dirty)?", data["commit"]), (
            f"{f.relative_to(REPO)}: commit {data['commit']!r}"
        )


def test_reports_keep_at_most_fifteen_top_level_entries() -> None:
    entries = [p.name for p in REPORTS.iterdir()]
    assert len(entries) <= 15, entries


def test_the_index_has_one_row_per_report(tmp_path: Path) -> None:
    shutil.copytree(REPORTS, tmp_path / "reports")
    subprocess.run(
        [
            sys.executable,
            str(REPO / "experiments" / "report_index.py"),
            "--reports",
            str(tmp_path / "reports"),
        ],
        check=True,
        capture_output=True,
    )
    index = (tmp_path / "reports" / "README.md").read_text()
    rows = [line for line in index.splitlines() if line.startswith("| [")]
    names = sorted(f.stem for f in report_files(tmp_path / "reports"))
    assert sorted(re.match(r"\| \[([^\]]+)\]", r).group(1) for r in rows) == names
    for r in rows:
        assert "`make " in r or "`python" in r or "`cargo" in r, r


def test_provenance_names_the_checked_out_commit() -> None:
    from objslam.provenance import provenance

    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True)
    p = provenance(["python", "experiments/x.py", "--set", "a=b c"], {"k": 1})
    assert p["commit"].removesuffix("-dirty") == head.stdout.strip()
    # Dirty means changed code: a rewritten report under reports/ does not count.
    code = subprocess.run(
        ["git", "status", "--porcelain", "--", ".", ":(exclude)reports"], cwd=REPO, capture_output=True, text=True, check=True
    )
    assert p["commit"].endswith("-dirty") == bool(code.stdout.strip())
    assert p["command"] == "python experiments/x.py --set 'a=b c'"
    assert p["config"] == {"k": 1}
    assert f"{os.cpu_count()} cores" in p["machine"]
