"""Record the core system's inputs of one episode for offline replay.

``python experiments/capture.py --scene scenes/scene05.toml --out /tmp/capture05 [--set k=v ...]``

Runs one episode and writes, in the format of ``objslam_core::system::capture`` (its module docs
describe it): ``system.json`` (the episode's mapper, session and tracker configs, the table and the
scene's ground truth), ``events.jsonl`` (every frame the core receives, with its intrinsics, prior
and true camera pose and detections, and every view's end) and each frame's grey image and depth,
gzip-compressed. ``cargo run --release -p objslam-core --example slam_replay -- <out>`` replays the
tracker on it; the core's ``system_replay`` test replays the whole system on the fixture in
``core/tests/fixtures/capture_scene01``.

``--keep-every N`` keeps one frame in N while the arm moves (the frames of each view's end are
always kept), for a small capture.
"""

from __future__ import annotations

import argparse
import gzip
import json
from pathlib import Path

import numpy as np
from objslam import episode
from objslam.config import load_run_config
from objslam.scene import gt_objects, load_scene


class _Capturing:
    """Wraps the native ActiveMapper and writes every frame and view end it receives."""

    def __init__(self, inner, out: Path, keep_every: int) -> None:
        self._inner = inner
        self._out = out
        self._keep_every = keep_every
        self._seen_in_view = 0
        self._pending: dict | None = None
        self._log = (out / "events.jsonl").open("w")

    def _write(self, rec: dict, grey: np.ndarray, depth: np.ndarray) -> None:
        i = rec["index"]
        with gzip.open(self._out / f"grey_{i}.u8.gz", "wb", compresslevel=9) as f:
            f.write(np.ascontiguousarray(grey, dtype=np.uint8).tobytes())
        with gzip.open(self._out / f"depth_{i}.f32.gz", "wb", compresslevel=9) as f:
            f.write(np.ascontiguousarray(depth, dtype="<f4").tobytes())
        self._log.write(json.dumps({"event": "frame", **rec}) + "\n")
        self._log.flush()

    def update(self, **kw):
        grey = kw.get("grey")
        if grey is not None and np.ndim(grey) == 3:
            grey = episode.grey_of(grey)  # the RGB image the core takes the luma of, as the core does
        if grey is not None:
            rec = {
                "index": int(kw["index"]),
                "view_index": int(kw.get("view_index", 0)),
                "width": int(grey.shape[1]),
                "height": int(grey.shape[0]),
                "intrinsics": np.asarray(kw["intrinsics"], dtype=float).ravel().tolist(),
                "world_from_camera_prior": np.asarray(kw["world_from_camera"], dtype=float).ravel().tolist(),
                "world_from_camera_gt": np.asarray(kw["world_from_camera_gt"], dtype=float).ravel().tolist(),
                "detections": [list(d[:4]) + [str(d[4]), float(d[5])] for d in kw["detections"]],
            }
            frame = (rec, np.array(grey), np.array(kw["depth"]))
            if self._seen_in_view % self._keep_every == 0:
                self._write(*frame)
                self._pending = None
            else:
                self._pending = frame
            self._seen_in_view += 1
        return self._inner.update(**kw)

    def view_done(self, counts_as_view: bool):
        if self._pending is not None:
            self._write(*self._pending)
            self._pending = None
        self._seen_in_view = 0
        self._log.write(json.dumps({"event": "view_done", "counts_as_view": bool(counts_as_view)}) + "\n")
        self._log.flush()
        return self._inner.view_done(counts_as_view)

    def __getattr__(self, name):
        return getattr(self._inner, name)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, help="scene file")
    ap.add_argument("--strategy", default="object-driven", help="strategy (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=0, help="run seed (default: %(default)s)")
    ap.add_argument("--out", required=True, type=Path, help="capture folder to write")
    ap.add_argument("--keep-every", type=int, default=1, help="keep one moving frame in N (default: %(default)s)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    a = ap.parse_args(argv)
    if a.keep_every < 1:
        ap.error("--keep-every must be at least 1")
    a.out.mkdir(parents=True, exist_ok=True)
    cfg = load_run_config(overrides=[f'scene="{a.scene}"', f"seed={a.seed}", *a.set], strategy=a.strategy)
    scene = load_scene(cfg.scene)
    native = episode._native
    orig = native.ActiveMapper

    class _Patched:
        @staticmethod
        def ActiveMapper(**kw):  # stands in for the native class, recording what it receives
            header = {
                "mapper_config": json.loads(kw["mapper_config_json"]),
                "active_config": json.loads(kw["active_config_json"]),
                "tracker_config": json.loads(kw["tracker_config_json"]) if kw.get("tracker_config_json") else None,
                "table": list(kw["table"]),
                "ground_truth": gt_objects(scene),
            }
            (a.out / "system.json").write_text(json.dumps(header, indent=1) + "\n")
            return _Capturing(orig(**kw), a.out, a.keep_every)

        def __getattr__(self, name):
            return getattr(native, name)

    episode._native = _Patched()
    try:
        result = episode.run_episode(cfg, progress=False)
    finally:
        episode._native = native
    m = result.metrics
    print(json.dumps({k: m.get(k) for k in ("frames", "views", "mean_iou3d", "ate_rmse_m", "n_objects_est")}))
    print(f"run folder: {result.run_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
