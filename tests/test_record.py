"""The Rerun recording: layout (blueprint), encoded frames, robot and table, read back with the
pinned rerun-sdk's RRD reader."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest
from objslam import _native
from objslam.world import panda_urdf_path

rr_experimental = pytest.importorskip("rerun.experimental")

TABLE = {"center": [0.5, 0.0], "size": [0.8, 1.2]}


def frames(n: int = 12, w: int = 160, h: int = 120) -> list[tuple[np.ndarray, np.ndarray]]:
    """A textured image and a tilted plane, as the camera sees a table."""
    yy, xx = np.mgrid[0:h, 0:w]
    out = []
    for i in range(n):
        rgb = np.stack([(xx * 1.5 + i) % 256, (yy * 2) % 256, 120 + 0 * xx], axis=-1).astype(np.uint8)
        depth = (0.5 + 0.002 * yy + 0.001 * i).astype(np.float32)
        out.append((rgb, depth))
    return out


def record(path: Path, **options) -> Path:
    rec = _native.Recorder(str(path), "objslam", json.dumps(options))
    k = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
    planner = _native.Planner(str(panda_urdf_path()))
    for i, (rgb, depth) in enumerate(frames()):
        rec.set_frame(i, 0.25 * i)
        rec.log_camera(world_from_camera=np.eye(4), intrinsics=k, width=160, height=120)
        rec.log_rgb(rgb)
        rec.log_depth(depth)
        if options.get("robot_urdf"):
            rec.log_robot_pose(planner.link_poses(np.full(7, 0.1 * i)))
    rec.close()
    return path


def entities(path: Path) -> dict[str, list[str]]:
    """Entity path → column names of the recording store."""
    out: dict[str, list[str]] = {}
    for chunk in rr_experimental.RrdReader(path).stream():
        out.setdefault(chunk.entity_path, []).extend(chunk.to_record_batch().schema.names)
    return out


def test_recording_carries_its_layout(tmp_path: Path) -> None:
    path = record(tmp_path / "run.rrd", table=TABLE)
    reader = rr_experimental.RrdReader(path)
    assert [s.application_id for s in reader.recordings()] == ["objslam"]
    blueprints = reader.blueprints()
    assert [s.application_id for s in blueprints] == ["objslam"]
    bp = {c.entity_path: c.to_record_batch().schema.names for c in reader.stream(store=blueprints[0])}
    views = [p for p, cols in bp.items() if any(c.startswith("ViewBlueprint:") for c in cols)]
    assert len(views) == 6  # world, camera, depth, metrics, timings, events
    assert any(p.endswith("/EyeControls3D") for p in bp)
    hidden = [p for p in bp if p.endswith("/world/camera/image/depth/visualizers")]
    assert len(hidden) == 1 and any("EntityBehavior:visible" in c for c in bp[hidden[0]])
    assert "/viewport" in bp


def test_frames_are_encoded_and_a_third_of_raw(tmp_path: Path) -> None:
    raw = record(tmp_path / "raw.rrd", jpeg_quality=0, depth_png=False)
    enc = record(tmp_path / "enc.rrd")
    cols = entities(enc)
    assert any(c.startswith("EncodedImage:") for c in cols["/world/camera/image/rgb"])
    assert any(c.startswith("EncodedDepthImage:") for c in cols["/world/camera/image/depth"])
    assert any(c.startswith("Image:") for c in entities(raw)["/world/camera/image/rgb"])
    assert enc.stat().st_size * 3 < raw.stat().st_size


def test_jpeg_frames_export_to_video(tmp_path: Path) -> None:
    import export_video

    enc = record(tmp_path / "run.rrd", jpeg_quality=90)
    got = export_video.camera_frames(enc)
    assert [f for f, _ in got] == list(range(12))
    decoded = export_video._bgr(got[3][1])[..., ::-1]
    assert np.abs(decoded.astype(int) - frames()[3][0].astype(int)).mean() < 4.0  # JPEG at quality 90
    mp4 = export_video.write_mp4(got, tmp_path / "camera.mp4", 4.0)
    assert mp4.stat().st_size > 1000


def test_robot_and_table_are_drawn(tmp_path: Path) -> None:
    path = record(tmp_path / "run.rrd", table=TABLE, robot_urdf=str(panda_urdf_path()))
    cols = entities(path)
    meshes = [p for p, c in cols.items() if p.startswith("/world/robot/") and any("Asset3D:blob" in x for x in c)]
    assert len(meshes) >= 9  # link0-7 and the hand (the fingers are not in the planner's chain)
    moved = [p for p, c in cols.items() if p.count("/") == 3 and p.startswith("/world/robot/")]
    assert any("Transform3D:translation" in x for p in moved for x in cols[p])
    assert any(c.startswith("Boxes3D:") for c in cols["/world/table"])
    # The collision meshes keep the recording light.
    assert path.stat().st_size < 1_000_000


def test_bad_options_are_named(tmp_path: Path) -> None:
    with pytest.raises(_native.InputError, match="jpeg_quality"):
        _native.Recorder(str(tmp_path / "a.rrd"), "objslam", json.dumps({"jpeg_quality": 101}))
    with pytest.raises(_native.InputError, match="options_json"):
        _native.Recorder(str(tmp_path / "b.rrd"), "objslam", json.dumps({"jpg": 50}))
    with pytest.raises(_native.RecordingError, match="robot model"):
        _native.Recorder(str(tmp_path / "c.rrd"), "objslam", json.dumps({"robot_urdf": str(tmp_path / "x.urdf")}))


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # the server is stopped, not closed
def test_live_stream_reaches_a_viewer(tmp_path: Path) -> None:
    """``live_url`` streams the recording (blueprint included) to a viewer's gRPC proxy as well."""
    import socket
    import subprocess
    import time

    from objslam.cli import rerun_executable

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    received = tmp_path / "received.rrd"
    # Its own process group: the launcher may start the viewer binary as a child, and the whole
    # group is stopped at the end (no server outlives the test).
    server = subprocess.Popen(
        [rerun_executable(), "--port", str(port), "--save", str(received)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 20
        while socket.socket().connect_ex(("127.0.0.1", port)) != 0:
            assert time.monotonic() < deadline, "the rerun server did not start"
            time.sleep(0.1)
        record(tmp_path / "run.rrd", live_url=f"rerun+http://127.0.0.1:{port}/proxy")
        time.sleep(1.0)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=10)
    reader = rr_experimental.RrdReader(received)
    assert [s.application_id for s in reader.blueprints()] == ["objslam"]
    assert any(c.startswith("EncodedImage:") for c in entities(received)["/world/camera/image/rgb"])


def camera_images(path: Path) -> dict[str, list[tuple[int, object, bytes]]]:
    """The encoded camera images of a recording: entity → ``(frame, sim_time, blob)`` in frame order."""
    out: dict[str, list[tuple[int, object, bytes]]] = {}
    for chunk in rr_experimental.RrdReader(path).stream():
        if chunk.entity_path not in ("/world/camera/image/rgb", "/world/camera/image/depth"):
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        blob = next(n for n in names if n.endswith("Image:blob"))
        rows = zip(*(batch.column(names.index(n)).to_pylist() for n in ("frame", "sim_time", blob)))
        out.setdefault(chunk.entity_path, []).extend((f, t, bytes(b[0])) for f, t, b in rows if b)
    return {k: sorted(v) for k, v in out.items()}


def test_the_encoder_thread_logs_the_same_images_and_close_waits_for_them(tmp_path: Path) -> None:
    """Images encoded on the recorder's thread (the default) are the bytes the calling thread
    encodes, at the same frames and times; the file is complete as soon as close returns."""
    background = camera_images(record(tmp_path / "thread.rrd"))
    calling = camera_images(record(tmp_path / "calling.rrd", encoder_thread=False))
    assert background == calling
    for entity in ("/world/camera/image/rgb", "/world/camera/image/depth"):
        assert [f for f, _, _ in background[entity]] == list(range(12))
    import cv2

    jpeg = background["/world/camera/image/rgb"][5][2]
    decoded = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    assert np.abs(decoded.astype(int) - frames()[5][0].astype(int)).mean() < 4.0
    png = background["/world/camera/image/depth"][5][2]
    depth_mm = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(depth_mm, np.round(frames()[5][1] * 1000).astype(np.uint16))


def test_a_recorder_dropped_without_close_keeps_its_images(tmp_path: Path) -> None:
    import gc

    rec = _native.Recorder(str(tmp_path / "run.rrd"), "objslam", "{}")
    for i, (rgb, depth) in enumerate(frames()):
        rec.set_frame(i, 0.25 * i)
        rec.log_rgb(rgb)
        rec.log_depth(depth)
    del rec
    gc.collect()
    got = camera_images(tmp_path / "run.rrd")
    assert [len(got[e]) for e in ("/world/camera/image/rgb", "/world/camera/image/depth")] == [12, 12]
