"""One-off: add commit / command / machine / config to the report JSONs written before the report
writers recorded provenance (run once; kept as the record of what was done).

commit  = the commit that last changed the file (``git log -1 --format=%H -- <file>``);
command = the command the file already records (the one that made it), else the one that makes it;
machine = the machine string the file already records, else the machine the reports name;
config  = the protocol the file records (scene matching), else the defaults file at that commit
          plus the ``--set`` overrides of the command (the files do not hold the resolved config;
          each run folder's ``config.toml`` did, and run folders are not kept in git).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MACHINE = "2-core 24 GiB CPU-only (lavapipe)"
#: Commands for files that do not record one.
COMMANDS = {"foundation_run": "python experiments/report_run.py {run}"}


def main(paths: list[str]) -> int:
    for p in map(Path, paths):
        data = json.loads(p.read_text())
        if "commit" in data:
            print(f"{p}: has a commit, left alone")
            continue
        rel = p.resolve().relative_to(REPO)
        commit = subprocess.run(
            ["git", "log", "-1", "--format=%H", "--", str(rel)], cwd=REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
        command = data.get("command") or COMMANDS[p.stem].format(**data)
        overrides = re.findall(r"--set\s+('[^']*'|\S+)", command)
        config = data.get("config") or data.get("protocol") or {
            "defaults_file": f"experiments/configs/default.toml at {commit[:7]}",
            "show": f"git show {commit[:7]}:experiments/configs/default.toml",
            "overrides": [o.strip("'") for o in overrides],
        }
        note = (
            "backfilled from git history: commit is the last commit that changed this file, not a record "
            "made when the report was written (the report was made from the tree of about that commit, "
            "possibly with the uncommitted changes that commit then added); config is the defaults file "
            "at that commit with the command's --set overrides, not the resolved config"
        )
        if "protocol" in data and "config" not in data:
            note = note.replace(
                "config is the defaults file at that commit with the command's --set overrides, not the resolved config",
                "config is the protocol the file records",
            )
        if "machine" not in data:
            note += f"; machine is the machine the reports name ({MACHINE})"
        out = {
            "commit": commit,
            "provenance_note": note,
            "command": command,
            "machine": data.get("machine", MACHINE),
            "config": config,
            **{k: v for k, v in data.items() if k not in ("command", "machine", "config")},
        }
        p.write_text(json.dumps(out, indent=2) + "\n")
        print(f"{p}: commit {commit[:7]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
