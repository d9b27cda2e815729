"""Hostile and careless input: names that become paths, impossible values, oversized arrays,
damaged map files, interrupted runs. Every case ends in a typed error naming the field (or a
true run status), never a crash or a write outside the run folder."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from objslam import _native
from objslam.config import ConfigError, load_run_config
from objslam.episode import _make_run_dir, _write_atomic
from objslam.runs import list_runs, run_info
from objslam.scene import SceneFileError, load_scene, parse_scene

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "scenes" / "scene01.toml"


def _scene_doc(name: object) -> dict:
    import tomllib

    doc = tomllib.loads(SCENE.read_text())
    doc["scene"]["name"] = name
    return doc


@pytest.mark.parametrize("name", ["../x", "a/b", "x\ny", ".hidden", "..", "a b", "é", "a" * 65, "", 3])
def test_scene_names_that_are_not_safe_path_parts_are_refused(name) -> None:
    with pytest.raises(SceneFileError) as e:
        parse_scene(_scene_doc(name), "s.toml")
    assert e.value.field == "scene.name"


def test_safe_scene_names_are_kept() -> None:
    assert parse_scene(_scene_doc("scene-01_v2.b"), "s.toml").name == "scene-01_v2.b"


def test_no_run_folder_outside_runs_dir(tmp_path: Path, ci_overlay: Path) -> None:
    cfg = load_run_config(overlays=[ci_overlay], overrides=[f'runs_dir="{tmp_path / "runs"}"'])
    scene = load_scene(SCENE)
    # A scene built in memory (not through the file checks) and a Python strategy's label.
    with pytest.raises(SceneFileError, match="scene.name"):
        _make_run_dir(cfg, dataclasses.replace(scene, name="../../../x"))
    with pytest.raises(ConfigError, match="strategy"):
        _make_run_dir(dataclasses.replace(cfg, strategy="../x"), scene)
    assert not any(p for p in tmp_path.rglob("*") if "x" == p.name or p.name.endswith("_x_0"))
    d = _make_run_dir(cfg, scene)
    assert d.resolve().is_relative_to((tmp_path / "runs").resolve())


def test_scene_file_with_invalid_utf8_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "bad.toml"
    p.write_bytes(SCENE.read_bytes().replace(b"scene01", b"scene\xff01"))
    with pytest.raises(SceneFileError, match="bad.toml") as e:
        load_scene(p)
    assert "UTF-8" in e.value.reason


def test_a_failed_write_keeps_the_previous_file(tmp_path: Path, monkeypatch) -> None:
    p = tmp_path / "map.json.partial"
    p.write_text("complete content")

    def full_disk(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space"):
        _write_atomic(p, "new content that does not fit")
    assert p.read_text() == "complete content"
    assert not (tmp_path / "map.json.partial.tmp").exists()


def _fake_run(root: Path, name: str, status: dict | None, incomplete: bool = True) -> Path:
    d = root / "2026-01-01" / name
    d.mkdir(parents=True)
    if status is not None:
        (d / "status.json").write_text(json.dumps(status))
    if incomplete:
        (d / "INCOMPLETE").write_text("")
    return d


def test_runs_are_listed_with_dead_runs_told_from_live_ones(tmp_path: Path) -> None:
    host = socket.gethostname()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], check=True, capture_output=True, text=True)
    dead_pid = int(dead.stdout)
    runs = {
        "a_live": {"status": "running", "pid": os.getpid(), "host": host},
        "b_dead": {"status": "running", "pid": dead_pid, "host": host},
        "c_elsewhere": {"status": "running", "pid": 1, "host": host + "-other"},
        "d_done": {"status": "complete", "pid": 1, "host": host},
        "e_term": {"status": "terminated", "pid": 1, "host": host, "error": "RunStopped"},
        "f_nostatus": None,
    }
    for name, st in runs.items():
        _fake_run(tmp_path, name, st, incomplete=name != "d_done")
    got = {Path(r.path).name: r.status for r in list_runs(tmp_path)}
    assert got == {
        "a_live": "running",
        "b_dead": "dead",
        "c_elsewhere": "running?",
        "d_done": "complete",
        "e_term": "terminated",
        "f_nostatus": "unknown",
    }
    assert run_info(tmp_path / "2026-01-01" / "b_dead").pid == dead_pid
    out = subprocess.run(
        [sys.executable, "-m", "objslam.runs", str(tmp_path), "--status", "dead"], check=False, capture_output=True, text=True
    )
    assert out.returncode == 0 and "b_dead" in out.stdout and "a_live" not in out.stdout


# --- native entry points -------------------------------------------------------------------------


def _map_json() -> str:
    m = _native.NaiveMapper()
    return m.map_json()


def _saved_map(tmp_path: Path) -> tuple[Path, dict]:
    obj = {
        "id": 0,
        "label": "book",
        "world_from_object": {"rotation": [0.0, 0.0, 0.0, 1.0], "translation": [0.4, 0.0, 0.02]},
        "half_extents": [0.1, 0.07, 0.02],
        "observations": [],
        "points_in_world": [],
        "stage": "raw",
    }
    v1 = {"format": "objslam-map", "version": 1, "objects": [obj], "next_id": 1}
    p = tmp_path / "map.json"
    _native.save_map(json.dumps(v1), str(p))
    return p, json.loads(p.read_text())


def test_saved_maps_carry_a_hash_and_load(tmp_path: Path) -> None:
    p, doc = _saved_map(tmp_path)
    assert doc["version"] == 2 and doc["content_hash"].startswith("fnv1a64:")
    assert json.loads(_native.load_map(str(p)))["objects"][0]["id"] == 0


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["objects"][0]["world_from_object"].update(rotation=[0.0, 0.0, 0.0, 0.0]), "rotation"),
        (lambda d: d["objects"][0].update(half_extents=[0.1, -0.07, 0.02]), r"half_extents\[1\]"),
        (lambda d: d["objects"][0].update(half_extents=[0.1, 1e308, 0.02]), r"half_extents\[1\]"),
        (lambda d: d.update(next_id=0), "next_id"),
    ],
)
def test_load_map_refuses_impossible_values(tmp_path: Path, edit, match) -> None:
    p, doc = _saved_map(tmp_path)
    edit(doc)
    # Written with a matching content hash, so only the value checks can refuse it.
    p.write_text(_with_hash(doc))
    with pytest.raises(_native.MapFileError, match=match):
        _native.load_map(str(p))


def _with_hash(doc: dict) -> str:
    """A map file's text with its content hash (FNV-1a 64 of the text, the hash written as
    ``fnv1a64:0000000000000000``), as ``objslam_core::map`` writes it."""
    placeholder = "fnv1a64:" + "0" * 16
    text = json.dumps({**doc, "content_hash": placeholder})
    h = 0xCBF29CE484222325
    for b in text.encode():
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return text.replace(placeholder, f"fnv1a64:{h:016x}", 1)


def test_the_hash_of_a_saved_map_is_reproducible(tmp_path: Path) -> None:
    p, doc = _saved_map(tmp_path)
    p.write_text(_with_hash(doc))
    _native.load_map(str(p))


def test_load_map_refuses_a_flipped_digit(tmp_path: Path) -> None:
    p, _ = _saved_map(tmp_path)
    text = p.read_text()
    i = text.index("0.07")
    p.write_text(text[:i] + "0.08" + text[i + 4 :])
    with pytest.raises(_native.MapFileError, match="content_hash"):
        _native.load_map(str(p))


def test_a_map_without_hash_file_is_refused_with_the_way_out(tmp_path: Path) -> None:
    p = tmp_path / "old.json"
    p.write_text(json.dumps({"format": "objslam-map", "version": 1, "objects": [], "next_id": 0}))
    with pytest.raises(_native.MapFileError, match="save_map"):
        _native.load_map(str(p))


def test_evaluation_inputs_are_checked() -> None:
    gt = [
        {
            "id": 0,
            "label": "cup",
            "geometry": {"shape": "cylinder", "center": [0.5, 0, 0.05], "yaw_rad": 0, "half_extents": [0.04, 0.04, 0.05]},
        }
    ]
    ok = json.loads(_native.evaluate_map(json.dumps(gt), _map_json()))
    assert ok["n_objects_gt"] == 1
    with pytest.raises(_native.InputError, match="max_match_distance_m"):
        _native.evaluate_map(json.dumps(gt), _map_json(), json.dumps({"max_match_distance_m": -0.1, "square_tolerance": 0.05}))
    with pytest.raises(_native.InputError, match=r"\[0\]\.geometry\.half_extents"):
        gt[0]["geometry"]["half_extents"] = [0.04, 0.0, 0.05]
        _native.evaluate_map(json.dumps(gt), _map_json())
    gt[0]["geometry"]["half_extents"] = [0.04, 0.04, 0.05]
    with pytest.raises(_native.InputError, match=r"\[1\]\.id"):
        _native.evaluate_map(json.dumps(gt + gt), _map_json())
    with pytest.raises(_native.InputError, match=r"gt: \[0\]\.id"):
        gt[0]["id"] = -1
        _native.evaluate_map(json.dumps(gt), _map_json())


def test_native_configs_refuse_impossible_values() -> None:
    with pytest.raises(_native.InputError, match="voxel_m"):
        _native.NaiveMapper(json.dumps({"voxel_m": 0.0}))
    with pytest.raises(_native.InputError, match=r"config: pixel_stride"):
        _native.NaiveMapper(json.dumps({"pixel_stride": "4"}))
    table = (0.5, 0.0, 0.8, 1.2)
    for cfg, match in [
        ({"min_observations": 0}, "min_observations"),
        ({"param": {"iforest": {"passes": 0}}}, "param.iforest.passes"),
        ({"relabel_vote_ratio": -1.0}, "relabel_vote_ratio"),
        ({"naive": {"voxel_m": 0.0}}, "naive.voxel_m"),
    ]:
        with pytest.raises(_native.InputError, match=match):
            _native.ActiveMapper(mapper_config_json=json.dumps(cfg), active_config_json="{}", table=table)


def test_a_huge_table_is_refused_before_allocating() -> None:
    for size in (1e4, 1e12):
        with pytest.raises(_native.InputError, match="table"):
            _native.ActiveMapper(mapper_config_json="{}", active_config_json="{}", table=(0.5, 0.0, size, size))


def test_planner_steps_near_zero_are_refused() -> None:
    from objslam.world import panda_urdf_path

    for key in ("edge_resolution_rad", "sample_dt_s"):
        with pytest.raises(_native.InputError, match=key):
            _native.Planner(str(panda_urdf_path()), json.dumps({key: 1e-12}))
    with pytest.raises(_native.InputError, match="velocity_scale"):
        _native.Planner(str(panda_urdf_path()), json.dumps({"velocity_scale": 0.0}))


def test_broadcast_views_are_refused_not_copied() -> None:
    k = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    huge = np.broadcast_to(np.float32(0.5), (100_000, 100_000))  # 40 GB if copied
    m = _native.NaiveMapper()
    with pytest.raises(_native.InputError, match="depth"):
        m.update(index=0, intrinsics=k, depth=huge, world_from_camera=np.eye(4), detections=[])
    # A small non-contiguous view is read as is.
    depth = np.full((480, 640), 0.5, dtype=np.float32)[::2, ::2]
    assert m.update(index=0, intrinsics=k, depth=depth, world_from_camera=np.eye(4), detections=[]) == []


def test_recorder_refuses_broadcast_views(tmp_path: Path) -> None:
    rec = _native.Recorder(str(tmp_path / "r.rrd"))
    with pytest.raises(_native.InputError, match="rgb"):
        rec.log_rgb(np.broadcast_to(np.uint8(7), (60_000, 60_000, 3)))
    with pytest.raises(_native.InputError, match="points"):
        rec.log_points("p", np.broadcast_to(np.zeros(3), (10**9, 3)))
    rec.close()


# --- signals -------------------------------------------------------------------------------------


def _start_run(tmp_path: Path) -> subprocess.Popen:
    args = [
        "--config",
        str(REPO / "experiments" / "configs" / "ci.toml"),
        "--set",
        f'runs_dir="{tmp_path}"',
        "--strategy",
        "init",
        "--no-progress",
        "--no-compare",
    ]
    # experiments/run.py as its own process. A shell starts background jobs with SIGINT ignored and
    # Python keeps an ignored SIGINT, so the run first takes Python's default handler back: the test
    # does not depend on how the test session was started.
    script = str(REPO / "experiments" / "run.py")
    boot = (
        "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        f"sys.argv = [{script!r}, *sys.argv[1:]]; sys.path[0] = {str(Path(script).parent)!r}; "
        f"runpy.run_path({script!r}, run_name='__main__')"
    )
    cmd = [sys.executable, "-c", boot, *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)


def _wait_running(tmp_path: Path, proc: subprocess.Popen, timeout_s: float = 240.0) -> Path:
    """The run folder once the run has started moving (the first view's partial map is written)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        found = list(tmp_path.glob("*/*/map.json.partial"))
        if found:
            return found[0].parent
        if proc.poll() is not None:
            pytest.fail(f"run ended early ({proc.returncode}): {proc.stderr.read() if proc.stderr else ''}")
        time.sleep(0.2)
    proc.kill()
    pytest.fail("run did not start")


@pytest.mark.slow
@pytest.mark.parametrize(("signum", "code", "status"), [(signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted")])
def test_a_signal_ends_a_run_with_a_true_status(tmp_path: Path, signum: int, code: int, status: str) -> None:
    proc = _start_run(tmp_path)
    run_dir = _wait_running(tmp_path, proc)
    st = json.loads((run_dir / "status.json").read_text())
    assert st["status"] == "running" and st["pid"] == proc.pid and st["host"] == socket.gethostname()
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == code, err
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.startswith("run ")]
    assert lines == [f"run {status}: its folder is kept, marked incomplete: {run_dir}"], err
    st = json.loads((run_dir / "status.json").read_text())
    assert st["status"] == status and st["pid"] == proc.pid and st["host"] == socket.gethostname()
    assert "finished" in st and "started" in st
    assert (run_dir / "INCOMPLETE").exists()
    # The partial map is whole (written atomically) and readable by the core.
    _native.map_objects_json((run_dir / "map.json.partial").read_text())
    assert not list(run_dir.glob("*.tmp"))
    assert run_info(run_dir).status == status


def test_a_value_the_core_refuses_is_named_as_written_before_any_folder(tmp_path: Path, ci_overlay: Path) -> None:
    """The core checks its tables when the run config is loaded: the error names the key as written
    and no run folder exists yet."""
    with pytest.raises(ConfigError, match=r"explore\.done_occupied_ratio"):
        load_run_config(
            overlays=[ci_overlay], overrides=[f'runs_dir="{tmp_path}"', "explore.done_occupied_ratio=7.0"]
        )
    assert not any(tmp_path.iterdir())


def _small_mapper():
    return _native.ActiveMapper(mapper_config_json="{}", active_config_json="{}", table=(0.5, 0.0, 0.8, 1.2))


def test_active_mapper_arguments_are_checked_by_name() -> None:
    m = _small_mapper()
    k = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    with pytest.raises(TypeError, match="reachable: expected a callable"):
        m.next_view(intrinsics=k, width=320, height=240, world_from_camera=np.eye(4), reachable=3)
    with pytest.raises(_native.InputError, match="id: an object id"):
        m.resolve_id(-1)
    with pytest.raises(_native.InputError, match="query_json: .*integer `-1`, expected u32"):
        m.query('{"query": "candidate_views", "around": [-1]}', intrinsics=k, width=320, height=240)
    with pytest.raises(_native.InputError, match="active_config"):
        _native.ActiveMapper(
            mapper_config_json="{}", active_config_json='{"explore": {"max_views": "ten"}}', table=(0.5, 0.0, 0.8, 1.2)
        )


def test_a_broadcast_grey_image_is_refused_before_it_is_copied() -> None:
    m = _small_mapper()
    k = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    huge = np.broadcast_to(np.zeros(1, dtype=np.uint8), (100_000, 100_000))
    with pytest.raises(_native.InputError, match="grey"):
        m.update(
            index=0,
            intrinsics=k,
            depth=np.zeros((240, 320), dtype=np.float32),
            world_from_camera=np.eye(4),
            detections=[],
            grey=huge,
        )


@pytest.mark.parametrize("value", ["-0.001", "nan"])
def test_impossible_depth_noise_is_a_config_error(value: str) -> None:
    with pytest.raises(ConfigError, match="camera.depth_noise.sigma_rel"):
        load_run_config(overrides=[f"camera.depth_noise.sigma_rel={value}"])
