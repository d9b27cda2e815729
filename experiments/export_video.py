"""Export a run's camera stream as a video: ``python experiments/export_video.py [RUN_DIR]``.

Reads the colour frames of ``RUN_DIR/run.rrd`` (``world/camera/image/rgb``: JPEG-encoded or raw,
``record.jpeg_quality``) with the pinned rerun-sdk's RRD reader and writes ``RUN_DIR/camera.mp4``
(MPEG-4 Part 2 through OpenCV, at the run's ``frame_rate_hz`` unless ``--fps`` is given: the
video plays at the simulated speed). With ``--frames`` it writes the frames as numbered JPEG files
in ``RUN_DIR/camera_frames/`` instead (lossless copies of the recorded JPEGs).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import tomllib
from objslam.cli import HelpFormatter

REPO = Path(__file__).resolve().parents[1]
RGB_ENTITY = "/world/camera/image/rgb"


def camera_frames(rrd: Path) -> list[tuple[int, bytes | np.ndarray]]:
    """The recorded colour frames in frame order: ``(frame index, JPEG bytes or an (H, W, 3)
    uint8 RGB array)``."""
    from rerun.experimental import RrdReader

    frames: dict[int, bytes | np.ndarray] = {}
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path != RGB_ENTITY:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        index = batch.column(names.index("frame")).to_pylist()
        if "EncodedImage:blob" in names:
            blobs = batch.column(names.index("EncodedImage:blob")).to_pylist()
            for f, blob in zip(index, blobs):
                if blob:
                    frames[int(f)] = bytes(blob[0])
        elif "Image:buffer" in names:
            buffers = batch.column(names.index("Image:buffer")).to_pylist()
            formats = batch.column(names.index("Image:format")).to_pylist()
            for f, buf, fmt in zip(index, buffers, formats):
                if buf and fmt:
                    w, h = fmt[0]["width"], fmt[0]["height"]
                    frames[int(f)] = np.frombuffer(bytes(buf[0]), dtype=np.uint8).reshape(h, w, 3)
    return sorted(frames.items())


def _bgr(frame: bytes | np.ndarray) -> np.ndarray:
    import cv2

    if isinstance(frame, bytes):
        return cv2.imdecode(np.frombuffer(frame, dtype=np.uint8), cv2.IMREAD_COLOR)
    return cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)


def write_mp4(frames: list[tuple[int, bytes | np.ndarray]], path: Path, fps: float) -> Path:
    """Write the frames as an MP4 (MPEG-4 Part 2, OpenCV's bundled FFmpeg)."""
    import cv2

    first = _bgr(frames[0][1])
    h, w = first.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path} (no MP4 encoder): use --frames")
    try:
        for _, f in frames:
            writer.write(_bgr(f))
    finally:
        writer.release()
    return path


def write_frames(frames: list[tuple[int, bytes | np.ndarray]], folder: Path) -> Path:
    """Write the frames as ``frame_<index>.jpg`` (recorded JPEGs copied as they are)."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    for index, f in frames:
        out = folder / f"frame_{index:05d}.jpg"
        if isinstance(f, bytes):
            out.write_bytes(f)
        else:
            cv2.imwrite(str(out), _bgr(f), [cv2.IMWRITE_JPEG_QUALITY, 95])
    return folder


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument(
        "run_dir", nargs="?", default=str(REPO / "runs" / "latest"), help="run folder (default: runs/latest)"
    )
    ap.add_argument("--fps", type=float, help="frames per second of the video (default: the run's frame_rate_hz)")
    ap.add_argument("--out", type=Path, help="output file or folder (default: RUN_DIR/camera.mp4 or RUN_DIR/camera_frames)")
    ap.add_argument("--frames", action="store_true", help="write numbered JPEG files instead of an MP4")
    a = ap.parse_args(argv)
    run = Path(a.run_dir)
    rrd = run / "run.rrd"
    if not rrd.exists():
        print(f"no recording at {rrd}", file=sys.stderr)
        return 1
    frames = camera_frames(rrd)
    if not frames:
        print(f"{rrd} has no colour frames (record.rgb = false?)", file=sys.stderr)
        return 1
    if a.frames:
        out = write_frames(frames, a.out or run / "camera_frames")
    else:
        fps = a.fps
        if fps is None:
            cfg = tomllib.loads((run / "config.toml").read_text()) if (run / "config.toml").exists() else {}
            fps = float(cfg.get("frame_rate_hz", 4.0)) / int(cfg.get("record", {}).get("every_n_frames", 1))
        out = write_mp4(frames, a.out or run / "camera.mp4", fps)
    print(f"{len(frames)} frames → {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
