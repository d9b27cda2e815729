"""Run one episode: ``python experiments/run.py [--scene S] [--strategy X] [--seed N] [--preset P] [--set k=v ...]``.

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
    ap.add_argument(
        "--preset", help="world-model preset: realistic (default.toml) or ideal (overlays configs/presets/ideal.toml)"
    )
    ap.add_argument("--config", action="append", default=[], help="extra TOML overlay (repeatable)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument(
        "--no-compare", action="store_true", help="do not also run the Init-only episode for comparison"
    )
    a = ap.parse_args(argv)
    overrides = list(a.set)
    if a.scene:
        overrides.append(f'scene="{a.scene}"')
    if a.seed is not None:
        overrides.append(f"seed={a.seed}")
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
    except Exception as e:  # noqa: BLE001 - the run folder already records the traceback
        print(f"run failed: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    print(format_table(result.metrics))
    print(f"run folder: {result.run_dir}")
    if cfg.strategy != "init" and not a.no_compare:
        import dataclasses

        base = run_episode(dataclasses.replace(cfg, strategy="init"), progress=not a.no_progress)
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
