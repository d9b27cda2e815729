"""Record the tracker's inputs of one episode for offline replay (SLAM diagnosis).

``python experiments/slam_capture.py --scene scenes/scene05.toml --out /tmp/capture05 [--set k=v ...]``

Runs one episode (default pose source ``slam``) and writes, for every frame the core receives,
``grey_<i>.u8`` (H*W bytes), ``depth_<i>.f32`` (H*W little-endian float32 metres) and one line of
``frames.jsonl`` with the frame index, view index, intrinsics, the forward-kinematics and the
ground-truth ``world_from_camera`` (row-major 4x4), and the episode's tracker config as
``tracker.json``. ``cargo run --release -p objslam-core --example slam_replay -- <out>`` replays
them through the tracker with that config (exactly reproducing the episode's poses), or with keys
of it overridden.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from objslam import episode
from objslam.cli import HelpFormatter
from objslam.config import STRATEGIES, load_run_config


class _Capturing:
    """Wraps an ActiveMapper and dumps every `update` call's tracker inputs."""

    def __init__(self, inner, out: Path) -> None:
        self._inner = inner
        self._out = out
        self._log = (out / "frames.jsonl").open("w")

    def update(self, **kw):
        i = kw["index"]
        grey = kw.get("grey")
        if grey is not None:
            np.ascontiguousarray(grey, dtype=np.uint8).tofile(self._out / f"grey_{i}.u8")
            np.ascontiguousarray(kw["depth"], dtype="<f4").tofile(self._out / f"depth_{i}.f32")
            rec = {
                "index": i,
                "view_index": kw.get("view_index", 0),
                "width": int(grey.shape[1]),
                "height": int(grey.shape[0]),
                "intrinsics": np.asarray(kw["intrinsics"], dtype=float).ravel().tolist(),
                "world_from_camera_fk": np.asarray(kw["world_from_camera"], dtype=float).ravel().tolist(),
                "world_from_camera_gt": np.asarray(kw["world_from_camera_gt"], dtype=float).ravel().tolist(),
            }
            self._log.write(json.dumps(rec) + "\n")
            self._log.flush()
        return self._inner.update(**kw)

    def __getattr__(self, name):
        return getattr(self._inner, name)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--scene", required=True, help="scene file")
    ap.add_argument("--strategy", default="object-driven", choices=STRATEGIES, help="view-selection strategy")
    ap.add_argument("--seed", type=int, default=0, help="run seed")
    ap.add_argument("--out", required=True, type=Path, help="folder of the captured frames")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key (repeatable)")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    cfg = load_run_config(
        overrides=[f'scene="{a.scene}"', f"seed={a.seed}", 'pose_source="slam"', *a.set], strategy=a.strategy
    )
    native = episode._native
    orig = native.ActiveMapper

    class _Patched:
        @staticmethod
        def ActiveMapper(**kw):  # stands in for the native class
            if kw.get("tracker_config_json"):
                (a.out / "tracker.json").write_text(kw["tracker_config_json"] + "\n")
            return _Capturing(orig(**kw), a.out)

        def __getattr__(self, name):
            return getattr(native, name)

    episode._native = _Patched()
    try:
        result = episode.run_episode(cfg, progress=False)
    finally:
        episode._native = native
    m = result.metrics
    print(json.dumps({k: m.get(k) for k in ("frames", "views", "ate_rmse_m", "lost_frames")}))
    print(f"run folder: {result.run_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
