"""Run one episode: ``python experiments/run.py [--scene S] [--strategy X] [--seed N] [--preset P] [--set k=v ...]``.

Writes ``runs/<date>/<time>_<strategy>_<scene>_<seed>/`` and prints a per-object table and the means.
Its ``run.rrd`` opens in the Rerun viewer with ``make view``; ``--spawn`` / ``--serve`` show the
run live while it goes.
Exit status 0 on success, 1 on a failed run (its folder is kept and marked), 2 on a bad config,
130 on Ctrl-C (SIGINT) and 143 on SIGTERM (the folder is kept, marked interrupted or terminated;
one line says where it is).
"""

from __future__ import annotations

import argparse
import faulthandler
import signal
import sys

from objslam.cli import HelpFormatter, has_display, start_viewer
from objslam.config import STRATEGIES, ConfigError, RunConfig, load_run_config
from objslam.episode import RunStopped, format_table, run_episode
from objslam.scene import SceneFileError


def main(argv: list[str] | None = None) -> int:
    """Run, and turn a signal into one line and the shell's exit status (no traceback). A crash in
    native code (renderer, core) prints every thread's Python stack before the process dies."""
    faulthandler.enable()
    try:
        return _main(argv)
    except RunStopped as e:
        print(f"run {e.status}: its folder is kept, marked incomplete: {e.run_dir}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("interrupted before a run folder was made", file=sys.stderr)
        return 128 + signal.SIGINT


def _main(argv: list[str] | None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    try:  # the true defaults: experiments/configs/default.toml over the dataclass defaults
        base = load_run_config()
    except (ConfigError, SceneFileError):
        base = RunConfig()
    ap.add_argument("--scene", help=f"scene file (default: {base.scene}, from experiments/configs/default.toml)")
    ap.add_argument(
        "--strategy",
        metavar="{" + ",".join(STRATEGIES) + "}",
        help=f"view-selection strategy, or the label of a python_strategy (default: {base.strategy}; "
        "experiments/strategies/<name>.toml holds each one's settings)",
    )
    ap.add_argument("--seed", type=int, help=f"run seed (default: {base.seed})")
    ap.add_argument(
        "--preset",
        choices=("realistic", "ideal"),
        help="world-model preset: realistic (default.toml) or ideal (overlays configs/presets/ideal.toml)",
    )
    ap.add_argument("--config", action="append", default=[], help="extra TOML overlay (repeatable)")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key, e.g. record.jpeg_quality=0"
    )
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument(
        "--no-compare", action="store_true", help="do not also run the Init-only episode for comparison"
    )
    live = ap.add_mutually_exclusive_group()
    live.add_argument(
        "--spawn", action="store_true", help="show the run live in a native Rerun viewer window as it goes"
    )
    live.add_argument(
        "--serve",
        action="store_true",
        help="show the run live in a web viewer served over HTTP (no display needed; prints the address)",
    )
    a = ap.parse_args(argv)
    overrides = list(a.set)
    if a.scene:
        overrides.append(f'scene="{a.scene}"')
    if a.seed is not None:
        overrides.append(f"seed={a.seed}")
    if a.spawn or a.serve:
        if a.spawn and not has_display():
            print("no display: serving a web viewer instead of opening a window", file=sys.stderr)
        overrides.append(f'record.live_url="{start_viewer(web=a.serve or not has_display())}"')
    try:
        cfg = load_run_config(overlays=a.config, overrides=overrides, strategy=a.strategy, preset=a.preset)
    except (ConfigError, SceneFileError) as e:
        print(f"config error: {e}", file=sys.stderr)
        return 2
    try:
        result = run_episode(cfg, progress=not a.no_progress)
    except SceneFileError as e:
        print(f"scene error: {e}", file=sys.stderr)
        return 2
    except ConfigError as e:
        print(f"config error: {e}", file=sys.stderr)
        return 2
    except RunStopped:
        raise
    except Exception as e:  # noqa: BLE001 - the run folder already records the traceback
        print(f"run failed: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    print(format_table(result.metrics))
    print(f"run folder: {result.run_dir}")
    if cfg.strategy != "init" and not a.no_compare:
        import dataclasses

        base = run_episode(dataclasses.replace(cfg, strategy="init", builtin_strategy=""), progress=not a.no_progress)
        print(compare_line(result.metrics, base.metrics))
        print(f"init run folder: {base.run_dir}")
        # runs/latest stays on the main run.
        from objslam.episode import _update_latest

        _update_latest(result.run_dir)
    return 0


def compare_line(m: dict, base: dict) -> str:
    """How a strategy's means compare with the Init-only episode on the same scene and seed."""

    def f(v, spec: str) -> str:
        return "-" if v is None else format(v, spec)

    a, b = m["mean"], base["mean"]
    return (
        f"{m['strategy']} vs init on {m['scene']} (seed {m['seed']}): "
        f"3D IoU {f(a['iou3d'], '.3f')} vs {f(b['iou3d'], '.3f')}, "
        f"2D IoU {f(a['iou2d'], '.3f')} vs {f(b['iou2d'], '.3f')}, "
        f"CDE {f(a['cde_cm'], '.2f')} vs {f(b['cde_cm'], '.2f')} cm, "
        f"YAE {f(a['yae_deg'], '.1f')} vs {f(b['yae_deg'], '.1f')} deg, "
        f"views {m['views']} vs {base['views']}"
    )


if __name__ == "__main__":
    raise SystemExit(main())
