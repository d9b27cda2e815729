"""Episodes end to end: run folder contract, determinism, failure marking, readable recording."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from objslam.config import ConfigError, load_run_config
from objslam.episode import run_episode

KEYS = {"scene", "strategy", "seed", "n_objects_gt", "n_objects_est", "views", "frames", "path_length_m", "wall_s", "mean", "objects"}


def _cfg(tmp_path: Path, ci_overlay: Path, strategy: str = "init", **over):
    sets = [f'runs_dir="{tmp_path}"'] + [f"{k}={v}" for k, v in over.items()]
    return load_run_config(overlays=[ci_overlay], overrides=sets, strategy=strategy)


def _stable(m: dict) -> dict:
    return {k: v for k, v in m.items() if k not in ("wall_s", "timings_ms_median", "frame_budget_ms_median")}


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory, ci_overlay):
    tmp = tmp_path_factory.mktemp("runs")
    cfg = _cfg(tmp, ci_overlay, seed=3)
    return tmp, run_episode(cfg, progress=False), run_episode(cfg, progress=False)


def test_run_folder_contract(two_runs) -> None:
    tmp, a, _ = two_runs
    d = a.run_dir
    for name in ("config.toml", "metrics.json", "map.json", "run.rrd", "status.json"):
        assert (d / name).exists(), name
    assert not (d / "INCOMPLETE").exists()
    m = json.loads((d / "metrics.json").read_text())
    assert KEYS <= set(m)
    assert set(m["mean"]) >= {"iou3d", "iou2d", "cde_cm", "yae_deg"}
    assert m["views"] == 4 and m["frames"] > 8 and m["n_objects_gt"] == 4
    assert m["path_length_m"] > 0.5
    for o in m["objects"]:
        assert {"gt_id", "label", "est_id", "iou3d", "iou2d", "cde_cm", "yae_deg"} <= set(o)
    # The objects of the sparse scene (well apart) are found and matched.
    assert sum(o["est_id"] is not None for o in m["objects"]) >= 3
    assert m["association"]["n_objects_gt"] == 4 and 0.5 <= m["association"]["purity"] <= 1.0
    assert set(m["stages"]) == {"raw", "iforest", "lines", "refined"}
    assert (tmp / "latest").resolve() in (a.run_dir.resolve(), two_runs[2].run_dir.resolve())


def test_same_seed_same_metrics(two_runs) -> None:
    _, a, b = two_runs
    assert a.run_dir != b.run_dir
    assert _stable(a.metrics) == _stable(b.metrics)
    assert a.map_json == b.map_json


def test_recording_is_read_by_rerun_cli(two_runs) -> None:
    rerun = shutil.which("rerun") or str(Path(__file__).resolve().parents[1] / ".venv" / "bin" / "rerun")
    out = subprocess.run([rerun, "rrd", "stats", str(two_runs[1].run_dir / "run.rrd")], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    text = out.stdout + out.stderr
    assert "chunk" in text.lower() or "row" in text.lower(), text[:500]


def test_failed_run_is_marked_and_earlier_runs_untouched(two_runs, ci_overlay) -> None:
    tmp, a, _ = two_runs
    before = {p: p.stat().st_mtime_ns for p in a.run_dir.iterdir()}
    cfg = _cfg(tmp, ci_overlay, seed=4)

    def boom(frame):
        if frame.index >= 2:
            raise RuntimeError("injected failure")

    with pytest.raises(RuntimeError, match="injected"):
        run_episode(cfg, progress=False, on_frame=boom)
    failed = [d for d in tmp.glob("*/*_4") if d.is_dir()]
    assert len(failed) == 1
    status = json.loads((failed[0] / "status.json").read_text())
    assert status["status"] == "failed" and "injected failure" in status["error"]
    assert (failed[0] / "INCOMPLETE").exists() and (failed[0] / "config.toml").exists()
    assert {p: p.stat().st_mtime_ns for p in a.run_dir.iterdir()} == before


def test_bad_config_names_the_key(ci_overlay) -> None:
    with pytest.raises(ConfigError, match="camera.widht"):
        load_run_config(overlays=[ci_overlay], overrides=["camera.widht=3"])
    with pytest.raises(ConfigError, match="strategy"):
        load_run_config(overrides=['strategy="teleport"'])
    with pytest.raises(ConfigError, match="detector.miss_rate"):
        load_run_config(overrides=["detector.miss_rate=2.0"])
    with pytest.raises(ConfigError, match="map.param.support_snap_m"):
        load_run_config(overrides=["map.param.support_snap_m=-0.01"])
    with pytest.raises(ConfigError, match="map.param.window_keep"):
        load_run_config(overrides=['map.param.window_keep="newest"'])
    with pytest.raises(ConfigError, match="slam.extend_after_unmapped"):
        load_run_config(overrides=["slam.extend_after_unmapped=-1"])


def test_object_driven_episode_takes_next_best_views(tmp_path, ci_overlay) -> None:
    cfg = _cfg(tmp_path, ci_overlay, strategy="object-driven", **{"explore.max_views": 2})
    r = run_episode(cfg, progress=False)
    m = r.metrics
    assert m["strategy"] == "object-driven"
    assert 1 <= m["nbv_views"] <= 2 and m["views"] == 4 + m["nbv_views"]
    curve = m["entropy_curve"]
    assert len(curve) == 4 + m["nbv_views"]  # after each Init view and each NBV view
    assert all(0.0 <= h <= 1.0 for h in curve), curve
    # The map is evaluated after every view; the last snapshot is the final map's evaluation.
    acc = m["accuracy_curve"]
    assert len(acc) == len(curve) and [p["views"] for p in acc] == sorted(p["views"] for p in acc)
    assert acc[-1]["views"] == m["views"]
    assert acc[-1]["iou3d"] == pytest.approx(m["mean"]["iou3d"], abs=1e-12)
    assert acc[-1]["cde_cm"] == pytest.approx(m["mean"]["cde_cm"], abs=1e-12)
    # The map found the scene's objects (NBV views add frames on top of the Init ones).
    assert m["frames"] > 10 and sum(o["est_id"] is not None for o in m["objects"]) >= 3
    # The table-top coverage is recorded after every view and grows from Init to the end.
    known = m["table_known_curve"]
    assert len(known) == len(curve) and all(0.0 <= k <= 1.0 for k in known), known
    assert known[-1] >= known[3] > 0.3


def missed(m: dict) -> int:
    """Ground-truth objects without a matched estimate."""
    return sum(o["est_id"] is None for o in m["objects"])


def test_discovery_finds_the_object_the_paper_rule_leaves_unmapped(tmp_path, ci_overlay) -> None:
    """Against the scene file: with a 35° camera the Init views of scene06 (seed 0) miss objects;
    the paper's stopping rule (object-driven-discovery with its discovery settings off) ends once the
    mapped objects are explored and never maps them, while looking at the unseen table before
    stopping (explore.discovery_before_stop, with the budget reserve of the run defaults) finds
    them. The scenario is common: it holds on 9 of 13 scene / seed pairs tried (scenes 02 and 04-07,
    seeds 7, 0 and 1). It was found with a cylinder's top at its highest point, which the test keeps,
    to test the stopping rule rather than the estimator."""
    common = {
        "preset": '"ideal"',  # the scenario was found in the ideal world
        "scene": '"scenes/scene06.toml"',
        "camera.fovy_deg": 35.0,
        "seed": 0,
        "map.param.cylinder.top_from_face": "false",
    }
    paper = run_episode(
        _cfg(tmp_path, ci_overlay, strategy="object-driven-discovery", **common, **{"explore.discovery_before_stop": "false", "explore.discovery_reserve": "false"}),
        progress=False,
    ).metrics
    disc = run_episode(_cfg(tmp_path, ci_overlay, strategy="object-driven-discovery", **common), progress=False).metrics
    assert missed(paper) >= 1 and paper["stop_reason"] == "all_explored", (missed(paper), paper["stop_reason"])
    assert missed(disc) < missed(paper), (missed(disc), missed(paper))
    assert disc["table_known_curve"][-1] > paper["table_known_curve"][-1] + 0.2


def test_object_evidence_maps_the_object_seen_only_at_the_border(tmp_path, ci_overlay) -> None:
    """Against the scene file and simulator ground truth: with a 35° camera and exact poses, the
    Init views of scene06 (seed 2) see an object only truncated at the image border; without object
    evidence its returns count as table and the budget goes elsewhere, so it is never mapped. With
    ``explore.discovery_evidence_height_m`` its cells stay unexplained and draw a view centred on
    it: every object mapped. Of 16 scene / seed pairs tried (scenes 02, 05, 06 and 07, seeds 0-4),
    8 leave an object unmapped without the evidence and 4 of those show the whole effect (scene02
    seeds 0 and 1, scene05 seed 4, scene06 seed 2)."""
    common = {
        "preset": '"ideal"',  # the scenario was found in the ideal world
        "scene": '"scenes/scene06.toml"',
        "camera.fovy_deg": 35.0,
        "seed": 2,
        "pose_source": '"fk"',
        "record.enabled": "false",
    }
    without = run_episode(
        _cfg(tmp_path, ci_overlay, strategy="object-driven-discovery", **common, **{"explore.discovery_evidence_height_m": 0.0}),
        progress=False,
    ).metrics
    recorded = run_episode(
        _cfg(
            tmp_path,
            ci_overlay,
            strategy="object-driven-discovery",
            **{**common, "record.enabled": "true", "record.rgb": "false", "record.depth": "false", "explore.discovery_evidence_height_m": 0.02},
        ),
        progress=False,
    )
    evidence = recorded.metrics
    assert missed(without) >= 1, without["objects"]
    assert missed(evidence) == 0, evidence["objects"]
    # The object the plain run never mapped is mapped well (the others' estimates vary with the
    # different views either way).
    lost = [o["gt_id"] for o in without["objects"] if o["est_id"] is None]
    assert all(o["iou3d"] >= 0.5 for o in evidence["objects"] if o["gt_id"] in lost), evidence["objects"]
    # The per-view unexplained-cell count: the can's cells while the map lacks it, a few (1 cm
    # cells) at the objects' borders once it is mapped; always none with the option off.
    curve = evidence["table_unexplained_curve"]
    assert len(curve) == len(evidence["table_known_curve"]) and max(curve) >= 5 and curve[-1] <= 5, curve
    assert curve[-1] <= max(curve) / 4, curve
    assert not any(without["table_unexplained_curve"]), without["table_unexplained_curve"]
    # ... and recorded for the viewer: the unexplained cells as points, their count as a scalar.
    rerun = shutil.which("rerun") or str(Path(__file__).resolve().parents[1] / ".venv" / "bin" / "rerun")
    out = subprocess.run(
        [rerun, "rrd", "print", str(recorded.run_dir / "run.rrd")], capture_output=True, text=True, timeout=300, check=False
    )
    assert out.returncode == 0, out.stderr
    assert "world/map/table_unexplained" in out.stdout and "explore/table_unexplained_cells" in out.stdout


def test_slam_pose_source_beats_noisy_kinematics(tmp_path, ci_overlay) -> None:
    """Pipeline against simulator ground truth, in the ideal world (the prior's error independent
    per view, 1 cm / 1°, zero mean): visual tracking seeded by it ends with a lower ATE than the
    prior itself, and is never lost."""
    kin = run_episode(_cfg(tmp_path, ci_overlay, pose_source='"kinematics"', preset='"ideal"'), progress=False).metrics
    slam = run_episode(_cfg(tmp_path, ci_overlay, pose_source='"slam"', preset='"ideal"'), progress=False).metrics
    assert kin["ate_rmse_m"] > 0.004  # the prior's bias is there
    assert slam["lost_frames"] == 0
    assert slam["ate_rmse_m"] < kin["ate_rmse_m"], (slam["ate_rmse_m"], kin["ate_rmse_m"])
    assert slam["rpe_trans_m"] < kin["rpe_trans_m"]
    # The final trajectory (all frames re-expressed with the last gauge) is scored too, absolute.
    assert 0.0 < slam["ate_final_rmse_m"] < kin["ate_rmse_m"], (slam["ate_final_rmse_m"], kin["ate_rmse_m"])
    assert slam["lost_frames_scene_hidden"] == 0 and slam["lost_by_reason"] == {}
    assert slam["map_resets"] == 0 and slam["map_extensions"] == 0


def test_object_clouds_from_slam_map_points(tmp_path, ci_overlay) -> None:
    """object_points = slam_map: the association works on the SLAM map points inside each box (the
    paper's local objects) and still finds the scene's objects; the map points are recorded."""
    cfg = _cfg(tmp_path, ci_overlay, pose_source='"slam"', **{"map.object_points": '"slam_map"'})
    r = run_episode(cfg, progress=False)
    m = r.metrics
    assert m["lost_frames"] == 0
    matched = [o for o in m["objects"] if o["est_id"] is not None]
    assert len(matched) >= 2, m["objects"]
    assert m["mean"]["cde_cm"] is not None and m["mean"]["cde_cm"] < 5.0, m["mean"]
    rerun = shutil.which("rerun") or str(Path(__file__).resolve().parents[1] / ".venv" / "bin" / "rerun")
    out = subprocess.run(
        [rerun, "rrd", "print", str(r.run_dir / "run.rrd")], capture_output=True, text=True, timeout=300, check=False
    )
    assert out.returncode == 0, out.stderr
    assert "world/map/points" in out.stdout + out.stderr
    assert "eval/iou3d" in out.stdout + out.stderr  # the per-view evaluation, plotted by the viewer


def test_map_follows_the_slam_gauge(tmp_path, ci_overlay) -> None:
    """With the SLAM pose source the object map is moved with each re-fit of the world ← map gauge
    (``follow_slam_gauge``): the option changes the map, the run stays tracked, and the map is
    still accurate against simulator ground truth."""
    follow = run_episode(_cfg(tmp_path, ci_overlay), progress=False)
    fixed = run_episode(_cfg(tmp_path, ci_overlay, **{"map.follow_slam_gauge": "false"}), progress=False)
    assert follow.metrics["lost_frames"] == 0 and fixed.metrics["lost_frames"] == 0
    # Same frames and poses (the option moves the map, not the camera): same trajectory error.
    assert follow.metrics["ate_rmse_m"] == fixed.metrics["ate_rmse_m"]
    assert follow.map_json != fixed.map_json
    # Quarter-resolution CI frames track less well than the 640x480 runs of the reports.
    assert follow.metrics["mean"]["cde_cm"] < 2.5, follow.metrics["mean"]
    assert follow.metrics["mean"]["iou3d"] > 0.5, follow.metrics["mean"]


def test_algorithm_seeds_are_distinct_and_reproducible() -> None:
    from objslam.episode import algorithm_seeds

    a = algorithm_seeds(3, 101)
    assert a == algorithm_seeds(3, 101)
    assert set(a) == {"iforest", "cylinder", "ransac"}
    assert len(set(a.values())) == 3 and all(0 <= v < 1 << 63 for v in a.values())
    others = [algorithm_seeds(4, 101), algorithm_seeds(3, 102)]
    assert all(set(a.values()).isdisjoint(o.values()) for o in others)


def test_seed_algorithms_reaches_the_estimator(two_runs, ci_overlay) -> None:
    """With ``seed_algorithms`` the isolation forest draws other subsamples: the same world (run
    seed 3) gives a slightly different map of the same quality, and the core accepts the seeds."""
    tmp, a, _ = two_runs
    b = run_episode(_cfg(tmp, ci_overlay, seed=3, seed_algorithms="true"), progress=False)
    assert b.map_json != a.map_json
    assert b.metrics["n_objects_est"] == a.metrics["n_objects_est"]
    assert abs(b.metrics["mean"]["iou3d"] - a.metrics["mean"]["iou3d"]) < 0.05
