"""Putting an item down by feel: the hand's external-wrench estimate against a force applied in the
simulator, and a bottle let go once the hand feels the table (judged from SAPIEN ground truth)."""

from __future__ import annotations

import numpy as np
import pytest
from objslam.config import load_run_config
from objslam.grasp import GraspSession
from objslam.place import Placer, free_line, height
from objslam.scene import gt_objects, load_scene
from objslam.task_config import PlaceConfig
from objslam.world import PHYSICS_HZ, SimWorld

from .conftest import SCENES


def test_the_wrench_estimate_recovers_a_force_applied_at_the_tcp(ci_overlay) -> None:
    # Joint friction off (the estimate does not model it): the drives alone balance the force, so
    # Jᵀ w = −τ gives it back.
    scene = load_scene(SCENES[3])
    # The ideal world: the release gap is checked to the millimetre against an exact table.
    cfg = load_run_config(overlays=[ci_overlay], overrides=['preset="ideal"'], strategy="init")
    world = SimWorld(scene, cfg.camera, np.random.default_rng(0), grasp_physics=True)
    for j in world.joints[:7]:
        j.set_friction(0.0)
    hand = world.hand
    force = np.array([6.0, -4.0, -25.0])
    est = []
    for k in range(int(1.5 * PHYSICS_HZ)):
        tcp = world.planner.forward_tcp(world.qpos()[:7])[:3, 3]
        hand.add_force_at_point(force, tcp)
        world._step()
        if k >= int(1.2 * PHYSICS_HZ):
            est.append(world.external_wrench())
    w = np.mean(est, axis=0)
    np.testing.assert_allclose(w[:3], force, atol=1.5)
    # Applied at the TCP: no moment about it.
    assert np.linalg.norm(w[3:]) < 0.5
    # Nothing applied: nothing estimated.
    rest = []
    for _ in range(int(0.5 * PHYSICS_HZ)):
        world._step()
        rest.append(world.external_wrench())
    assert np.linalg.norm(np.mean(rest[-24:], axis=0)[:3]) < 0.5


@pytest.mark.parametrize("feel", [True, False])
def test_a_bottle_is_let_go_once_the_hand_feels_the_table(ci_overlay, feel) -> None:
    # scene04's tallest bottle, from an exact map: by feel, the hand stops on contact and the bottle
    # is let go within 2 mm of the table; without, it is let go at the tall items' 5 mm release gap.
    scene = load_scene(SCENES[3])
    # The ideal world: the release gap is checked to the millimetre against an exact table.
    cfg = load_run_config(overlays=[ci_overlay], overrides=['preset="ideal"'], strategy="init")
    pcfg = PlaceConfig(feel_support=feel)
    session = GraspSession(scene, cfg, cfg.grasp)
    placer = Placer(session, pcfg)
    gt = gt_objects(scene, session.world.ground_truth())
    bottle = max((g for g in gt if g["label"] == "bottle"), key=lambda g: height(g["geometry"]))
    others = [g for g in gt if g["id"] != bottle["id"]]
    assert placer.pick(bottle, others, bottle["id"])["success"]
    h = height(bottle["geometry"])
    r = max(bottle["geometry"]["half_extents"][:2])
    slot = free_line(gt, 1, pcfg, reachable=lambda sl: placer.can_place(sl, [h], others), item_radius_m=r)
    assert slot is not None
    assert placer.place(slot[0][0], slot[0][1], 0.0, others) is None
    td = placer.touchdown
    if feel:
        assert td["how"] == "contact"
        assert abs(td["true_gap_m"]) < 0.002
    else:
        assert "how" not in td
        assert td["true_gap_m"] == pytest.approx(pcfg.tall_release_gap_m, abs=0.002)
    session.go_ready([o["geometry"] for o in others])
    session.hold(1.0, 0.04)
    now = {g["id"]: g["geometry"] for g in gt_objects(scene, session.world.ground_truth())}[bottle["id"]]
    assert abs(now["center"][2] - bottle["geometry"]["half_extents"][2]) < 0.005  # upright on the table
    assert np.hypot(now["center"][0] - slot[0][0], now["center"][1] - slot[0][1]) < pcfg.slot_tolerance_m
