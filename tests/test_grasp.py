"""Grasping in SAPIEN through the core's planner: a known box closes at its width and is lifted
≥ 10 cm (judged from the simulator's ground truth); per-attempt failures are outcomes, not crashes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from objslam import _native
from objslam.config import load_run_config
from objslam.grasp import GraspSession, run_grasp_session, same_place
from objslam.scene import gt_objects, load_scene
from objslam.task_config import GraspRunConfig
from objslam.world import READY_QPOS, panda_urdf_path

from .conftest import SCENES

#: A robot exactly like its model (the grasp mechanics tested here, not the arm's accuracy).
EXACT_ROBOT = ["robot.hand_eye_trans_m=0", "robot.hand_eye_rot_deg=0", "robot.joint_offset_deg=0",
               "robot.time_offset_max_s=0"]


@pytest.fixture(scope="module")
def scene01_session(ci_overlay):
    scene = load_scene(SCENES[0])
    cfg = load_run_config(overlays=[ci_overlay], overrides=EXACT_ROBOT, strategy="init")
    return scene, cfg


def test_grasp_of_a_known_box_closes_at_its_width_and_lifts_it(scene01_session) -> None:
    scene, cfg = scene01_session
    session = GraspSession(scene, cfg, GraspRunConfig())
    gt = gt_objects(scene, session.world.ground_truth())
    book = next(g for g in gt if g["label"] == "book")  # a 6.2 cm wide box
    z0 = book["geometry"]["center"][2]
    others = [g for g in gt if g["id"] != book["id"]]
    out = session.attempt(0, book, others, book["id"])
    width = 2 * min(book["geometry"]["half_extents"][:2])
    assert out["expected_closed_width_m"] == pytest.approx(width, abs=1e-6)
    assert out["open_width_m"] > width + 0.01
    # The fingers stop on the box's faces: the gap equals its true width within 3 mm.
    assert out["closed_gap_m"] == pytest.approx(width, abs=0.003)
    z1 = session.world.ground_truth()[book["id"]][0][2]
    assert z1 - z0 >= 0.10
    assert out["success"] and out["cause"] == "none"
    # The other objects were not disturbed.
    assert not out["disturbed"]


def test_a_reobserved_grasp_is_planned_from_the_ready_posture(scene01_session) -> None:
    # The close views leave the wrist wherever their camera roll put it; the grasp is planned from
    # the ready posture (GraspRunConfig.reobserve_return_ready), as without re-observation.
    scene, cfg = scene01_session
    session = GraspSession(scene, cfg, GraspRunConfig(reobserve=True))
    gt = gt_objects(scene, session.world.ground_truth())
    can = next(g for g in gt if g["label"] == "can")
    out = session.attempt(0, can, [g for g in gt if g["id"] != can["id"]], can["id"])
    assert out["reobserved"] and out["reobserve_frames"] > 0
    start = np.asarray(session.last_plan["to_pregrasp"]["positions"], dtype=float)[0]
    assert np.max(np.abs(start - READY_QPOS[:7])) < 0.02
    # The local map's own estimate of the can (its own SLAM gauge): within 1.5 cm of the truth.
    assert np.hypot(*np.subtract(out["target_geometry"]["center"][:2], can["geometry"]["center"][:2])) < 0.015
    assert out["success"] and out["cause"] == "none"


def test_unreachable_and_degenerate_targets_are_outcomes(scene01_session) -> None:
    scene, cfg = scene01_session
    far = {"id": 99, "label": "block", "geometry": {"shape": "cuboid", "center": [1.6, 0.0, 0.03], "yaw_rad": 0.0,
                                                    "half_extents": [0.02, 0.02, 0.03]}}
    wide = {"id": 98, "label": "book", "geometry": {"shape": "cuboid", "center": [0.5, 0.0, 0.02], "yaw_rad": 0.0,
                                                    "half_extents": [0.1, 0.1, 0.02]}}
    rows = run_grasp_session(scene, cfg, [far, wide], GraspRunConfig())
    by_map = {r["map_id"]: r for r in rows}
    assert by_map[99]["cause"] == "no_ik" and not by_map[99]["success"]
    assert by_map[98]["cause"] == "too_wide"
    # Every graspable true object without an attempt gets a not_in_map row.
    assert sum(r["cause"] == "not_in_map" for r in rows) == 4


def test_planner_rejects_bad_input_with_named_fields() -> None:
    p = _native.Planner(str(panda_urdf_path()))
    q = READY_QPOS[:7].copy()
    box = json.dumps({"shape": "cuboid", "center": [0.5, 0.0, 0.03], "yaw_rad": 0.0, "half_extents": [0.02, 0.02, 0.03]})
    with pytest.raises(_native.InputError, match="q_start"):
        p.plan_grasp(np.array([0.0, 1.0]), box, "[]")
    with pytest.raises(_native.InputError, match="q_start"):
        p.plan_grasp(np.full(7, np.nan), box, "[]")
    with pytest.raises(_native.InputError, match="target_json"):
        p.plan_grasp(q, "{}", "[]")
    with pytest.raises(_native.InputError, match="unknown field `bogus`"):
        _native.Planner(str(panda_urdf_path()), json.dumps({"bogus": 1}))
    with pytest.raises(_native.PlanningError):
        _native.Planner("/nonexistent/panda.urdf")
    with pytest.raises(_native.InputError, match="outside the joint limits"):
        p.plan_to_joints(q + 10.0, q, "[]")


def test_an_object_blocked_by_a_neighbour_is_grasped_once_the_neighbour_is_set_aside(ci_overlay) -> None:
    # scene06: the book (gt2) lies 13 cm from a 10 cm tall can; across its 5 cm side the 20 cm hand
    # body reaches the can, and along its 15 cm side it does not fit. With the true poses as the map
    # it has no collision-free grasp until the can has been grasped and set aside.
    scene = load_scene(SCENES[5])
    cfg = load_run_config(overlays=[ci_overlay], overrides=EXACT_ROBOT, strategy="init")
    gt_map = [{**g, "n_observations": 0} for g in gt_objects(scene)]
    book = next(g["id"] for g in gt_map if g["label"] == "book")
    fixed = {r["gt_id"]: r for r in run_grasp_session(scene, cfg, gt_map, GraspRunConfig(defer_unreachable=False))}
    assert fixed[book]["cause"] == "no_ik" and not fixed[book]["success"]
    rows = run_grasp_session(scene, cfg, gt_map, GraspRunConfig())
    by_gt = {r["gt_id"]: r for r in rows}
    assert by_gt[book]["success"] and by_gt[book]["deferred"] >= 1
    # One row per object, every graspable one lifted (the keyboard is too wide in truth).
    assert len(rows) == len(gt_map)
    assert all(r["success"] for r in rows if r["class"] != "keyboard")


def test_benchmark_maps_are_used_only_for_their_own_scene_and_seed(tmp_path, capsys) -> None:
    """--maps-from-benchmark grasps on an exploration sweep's run folders; a row whose folder's
    config is another seed, or whose folder has no map, makes no session (nothing is grasped
    in the wrong world) and says why."""

    import grasp as grasp_cli
    import tomli_w
    from objslam.config import to_dict

    run = tmp_path / "run_od"
    run.mkdir()
    cfg = load_run_config(overrides=["seed=1"], strategy="object-driven")
    (run / "config.toml").write_text(tomli_w.dumps(to_dict(cfg)))
    (run / "map.json").write_text("{}")
    bench = tmp_path / "exploration.json"
    bench.write_text(json.dumps({"rows": [
        {"scene": "scene01", "seed": 0, "strategy": "object-driven", "run_dir": str(run)},
        {"scene": "scene01", "seed": 0, "strategy": "init", "run_dir": str(tmp_path / "no_such_run")},
    ]}))
    manifest = tmp_path / "manifest.json"
    args = ["--maps-from-benchmark", str(bench), "--scenes", "scenes/scene01.toml", "--seeds", "0",
            "--manifest", str(manifest), "--out", str(tmp_path / "out")]
    a = grasp_cli.build_parser().parse_args(args)
    assert grasp_cli.grasp_benchmark_maps(a, "test") == []
    assert not manifest.exists()
    err = capsys.readouterr().err
    # estimated and ground_truth: the folder is seed 1's world; init_only: no map there.
    assert err.count("seed 1, not scene01 seed 0") == 2, err
    assert "scene01 seed 0 init_only: no map" in err, err


def test_register_local_removes_the_local_maps_common_offset() -> None:
    """The local map's objects share one calibration offset: registered against the map's
    neighbours it is removed, and what the close views add to the target's centre is kept; with
    no neighbour in view the target falls back to the map's centre."""
    from objslam.grasp import register_local

    def obj(i: int, x: float, y: float) -> dict:
        return {"id": i, "label": "can", "geometry": {"shape": "cylinder", "center": [x, y, 0.05], "yaw_rad": 0.0, "half_extents": [0.03, 0.03, 0.05]}}

    target = obj(0, 0.50, 0.00)
    neighbours = [obj(1, 0.60, 0.05), obj(2, 0.45, -0.10)]
    off = np.array([0.006, -0.005])
    refine = np.array([0.002, 0.001])  # what the close views know better about the target
    local = [
        obj(10, *(np.array([0.50, 0.00]) + off + refine)),
        obj(11, *(np.array([0.60, 0.05]) + off)),
        obj(12, *(np.array([0.45, -0.10]) + off)),
    ]
    reg = register_local(local, target, neighbours, 0.06)
    np.testing.assert_allclose(reg[0]["geometry"]["center"][:2], np.array([0.50, 0.00]) + refine, atol=1e-12)
    np.testing.assert_allclose(reg[1]["geometry"]["center"][:2], [0.60, 0.05], atol=1e-12)
    assert reg[0]["geometry"]["center"][2] == 0.05 and local[0]["geometry"]["center"][0] != reg[0]["geometry"]["center"][0]
    alone = register_local(local[:1], target, [], 0.06)
    np.testing.assert_allclose(alone[0]["geometry"]["center"][:2], [0.50, 0.00], atol=1e-12)
    assert register_local([obj(20, 0.9, 0.9)], target, neighbours, 0.06)[0]["geometry"]["center"][:2] == [0.9, 0.9]
    # A neighbour the close views saw only in part (its estimate 4 cm off) does not set the offset.
    # One good pair and one bad: the median of two is their mean, so only the bound removes it.
    partial = [*local[:2], obj(13, 0.72, -0.02)]
    far_nb = [*neighbours, obj(3, 0.75, 0.01)]
    reg = register_local(partial, target, far_nb, 0.06, pair_max_m=0.02)
    np.testing.assert_allclose(reg[0]["geometry"]["center"][:2], np.array([0.50, 0.00]) + refine, atol=1e-12)
    skewed = register_local(partial, target, far_nb, 0.06)  # without the bound
    assert abs(skewed[0]["geometry"]["center"][0] - 0.502) > 0.005


@pytest.mark.parametrize("retries", [0, 2])
def test_a_finger_landing_on_the_rim_moves_the_hand_over_and_the_grasp_succeeds(ci_overlay, retries) -> None:
    # scene03's 7.4 cm cup leaves the open fingers 3 mm a side. A map centre 5 mm off along the
    # closing axis puts a finger on its rim: blind, the approach collides; with contact retries the
    # touch (felt through the external wrench estimate: the hand stalls, the upward force rises, its
    # moment says which side) stops the descent, the hand moves towards the touched side and the
    # grasp lifts the cup.
    scene = load_scene(SCENES[2])
    cfg = load_run_config(overlays=[ci_overlay], overrides=EXACT_ROBOT, strategy="init")
    session = GraspSession(scene, cfg, GraspRunConfig(contact_retries=retries))
    gt = gt_objects(scene, session.world.ground_truth())
    cup = next(g for g in gt if g["label"] == "cup" and 2 * g["geometry"]["half_extents"][0] > 0.072)
    true_c = np.array(cup["geometry"]["center"])
    off = {**cup, "geometry": {**cup["geometry"], "center": (true_c + [0.0, 0.005, 0.0]).tolist()}}
    out = session.attempt(0, off, [g for g in gt if g["id"] != cup["id"]], cup["id"])
    if retries == 0:
        assert not out["success"] and out["cause"] == "collided"
        assert "contact_shifts_m" not in out
        return
    assert out["success"] and out["cause"] == "none"
    assert len(out["contact_shifts_m"]) == 1
    # The hand moved back towards the true centre: the grasped centre is within 2 mm of it.
    grasped = np.asarray(session.last_plan["world_from_tcp_grasp"])[:2, 3]
    assert np.hypot(*(grasped - true_c[:2])) < 0.002
    assert np.hypot(*np.subtract(session.last_target["geometry"]["center"][:2], true_c[:2])) < 0.002


def test_centre_errors_are_seeded_and_of_the_stated_size() -> None:

    import grasp as grasp_cli

    scene = load_scene(SCENES[2])
    gt = gt_objects(scene)
    a = grasp_cli.perturb_centres(gt, 6.0, seed=3)
    assert a == grasp_cli.perturb_centres(gt, 6.0, seed=3)
    moved = [np.subtract(p["geometry"]["center"], g["geometry"]["center"]) for p, g in zip(a, gt)]
    for d in moved:
        assert np.hypot(d[0], d[1]) == pytest.approx(0.006, abs=1e-12) and d[2] == 0.0
    # Directions differ between objects and between seeds.
    assert len({round(float(np.arctan2(d[1], d[0])), 6) for d in moved}) == len(gt)
    assert a != grasp_cli.perturb_centres(gt, 6.0, seed=4)
    assert all(p["geometry"]["half_extents"] == g["geometry"]["half_extents"] for p, g in zip(a, gt))


def test_robustness_report_counts_success_failures_and_touches_per_cell(tmp_path) -> None:

    import grasp_robustness

    def row(err: float, retries: int, ok: bool, cause: str, touches: int = 0, cls: str = "cup") -> dict:
        return {"scene": "scene03", "seed": 0, "map_source": "ground_truth", "centre_error_mm": err,
                "contact_retries": retries, "object": "gt2", "class": cls, "success": ok, "cause": cause,
                "touches": touches}

    rows = [row(6, 0, False, "collided"), row(6, 0, True, "none", cls="can"),
            row(6, 2, True, "none", touches=1), row(6, 2, False, "no_ik", cls="can")]
    rep = grasp_robustness.write(rows, tmp_path, "test")
    cells = {(s["centre_error_mm"], s["contact_retries"]): s for s in rep["summary"]}
    assert cells[(6.0, 0)]["successes"] == 1 and cells[(6.0, 0)]["collided"] == 1
    assert cells[(6.0, 2)]["with_touch"] == 1 and cells[(6.0, 2)]["failures"] == {"no_ik": 1}
    md = (tmp_path / "robustness.md").read_text()
    assert "| 6 | 1/2 (50.0 %) | 1/2 (50.0 %) |" in md
    assert "| 6 | blind approach | collided 1 | 0 |" in md
    assert (tmp_path / "robustness.png").stat().st_size > 0


def test_an_oversized_estimate_does_not_swallow_its_neighbours() -> None:
    def box(x: float, hx: float, hy: float = 0.03) -> dict:
        return {"geometry": {"shape": "cuboid", "center": [x, 0.0, 0.05], "yaw_rad": 0.0,
                             "half_extents": [hx, hy, 0.05]}}

    def can(x: float, r: float) -> dict:
        return {"geometry": {"shape": "cylinder", "center": [x, 0.0, 0.05], "yaw_rad": 0.0,
                             "half_extents": [r, r, 0.05]}}

    # A 12.5 cm long estimate over a row of 6 cm blocks: its footprint holds the next block's
    # centre 6 cm away, but that block's footprint does not reach its centre.
    long_box, next_block = box(0.5, 0.0625), box(0.56, 0.03)
    assert not same_place(next_block, long_box, 0.01)
    assert not same_place(long_box, next_block, 0.01)
    # Two estimates of one object, 1.5 cm apart: the same place either way round.
    assert same_place(box(0.5, 0.03), box(0.515, 0.03), 0.01)
    assert same_place(can(0.5, 0.03), box(0.51, 0.03), 0.01)
    # The margin: centres 4.5 cm apart with 3 cm half-sizes need a margin of at least 1.5 cm.
    assert not same_place(can(0.5, 0.03), can(0.545, 0.03), 0.01)
    assert same_place(can(0.5, 0.03), can(0.545, 0.03), 0.02)


def test_fallback_grasps_are_planned_only_in_the_last_round(scene01_session) -> None:
    """``fallback_last``: the regular planner has no fallback grasps (a block in a staggered row
    of touching blocks is ``no_ik`` for it); the fallback planner, used for the objects still
    deferred when nothing else can be executed, plans it tilted and off-centre."""
    scene, cfg = scene01_session
    yaw = 0.25
    u, v = np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])

    def block(k: float) -> dict:
        c = np.array([0.44, -0.24]) + 0.027 * k * u - 0.0545 * k * v
        return {"shape": "cuboid", "center": [*c.tolist(), 0.0115], "yaw_rad": yaw,
                "half_extents": [0.05, 0.026, 0.0115]}

    target, row = json.dumps(block(0)), json.dumps([block(1), block(2)])
    session = GraspSession(scene, cfg, GraspRunConfig())
    q = READY_QPOS[:7]
    assert session.planner.plan_grasp(q, target, row)["cause"] == "no_ik"
    plan = session.fallback_planner.plan_grasp(q, target, row)
    assert plan["ok"] and plan["fingers_at_opening"] and plan["tilt_rad"] != 0.0 and plan["off_centre_m"] < 0.0
    off = GraspSession(scene, cfg, GraspRunConfig(fallback_last=False))
    assert off.fallback_planner is None and off.planner.plan_grasp(q, target, row)["ok"]
