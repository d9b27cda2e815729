"""Run one episode: ``python experiments/run.py [--scene S] [--strategy X] [--seed N] [--set k=v ...]``.

Writes ``runs/<date>/<time>_<strategy>_<scene>_<seed>/`` and prints a per-object table and the means.
Exit status 0 on success, 1 on a failed run (its folder is kept and marked), 2 on a bad config.
"""

from __future__ import annotations

import argparse
import sys

from objslam.config import ConfigError, load_run_config
from objslam.episode import format_table, run_episode
from objslam.scene import SceneFileError


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", help="scene file (default from experiments/configs/default.toml)")
    ap.add_argument("--strategy", help="view-selection strategy (default: init)")
    ap.add_argument("--seed", type=int, help="run seed")
    ap.add_argument("--config", action="append", default=[], help="extra TOML overlay (repeatable)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    a = ap.parse_args(argv)
    overrides = list(a.set)
    if a.scene:
        overrides.append(f'scene="{a.scene}"')
    if a.seed is not None:
        overrides.append(f"seed={a.seed}")
    try:
        cfg = load_run_config(overlays=a.config, overrides=overrides, strategy=a.strategy)
    except (ConfigError, SceneFileError) as e:
        print(f"config error: {e}", file=sys.stderr)
        return 2
    try:
        result = run_episode(cfg, progress=not a.no_progress)
    except SceneFileError as e:
        print(f"scene error: {e}", file=sys.stderr)
        return 2
    except Exception as e:  # noqa: BLE001 - the run folder already records the traceback
        print(f"run failed: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    print(format_table(result.metrics))
    print(f"run folder: {result.run_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
