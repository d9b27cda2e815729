"""The paper's placement tasks, planned from the object map, judged from SAPIEN ground truth.

Entry point: :func:`run_place_task` (``make place`` → ``experiments/place.py``). Tasks:

- ``block_in_cup``: the smallest block (by estimated volume) goes onto the largest cup (by
  estimated volume). The simulator's cups are solid cylinders, so "into" is "onto its top".
  Success: the truly smallest block rests on the truly largest cup (its centre within the cup's
  true radius of the cup's axis, its bottom within 2 cm above the cup's top) after a 1 s wait.
- ``cups_by_volume``: every cup of the map goes to a slot of a line (along y, 10 cm apart, the first
  line found from the map clear of the other objects by 4 cm), ordered by estimated volume. Success: every true cup is
  upright within ``slot_tolerance_m`` of a slot and their true volumes increase along the line.
- ``bottles_by_height``: the same with the bottles, ordered by estimated height.

Every grasp goes through :class:`~objslam.grasp.GraspSession` (planner, PD drives, the grasp
physics); a place motion is the planner's ``plan_to_pose`` to a pre-place pose 12 cm above the slot,
a descent until the held object's estimated bottom is 1 cm above its support, opening, and a
retreat straight up. Choices are fields of :class:`PlaceConfig`. A task whose classes the scene
(or the map) lacks is not run.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .config import RunConfig
from .grasp import GraspRunConfig, GraspSession, match_gt
from .scene import SceneSpec, gt_objects
from .world import GRIPPER_OPEN_M

TASKS = ("block_in_cup", "cups_by_volume", "bottles_by_height")


@dataclass
class PlaceConfig:
    """Placement settings."""

    slot_spacing_m: float = 0.10
    """Distance between neighbouring slots of a line, metres."""
    tall_slot_spacing_m: float = 0.20
    """Slot spacing when the tallest item of the line is at least ``tall_item_height_m`` (estimated):
    the hand holds a tall item 4 cm below its top, so its body comes down beside a standing
    neighbour taller than the fingers and knocked it over at 10 cm (bottles_by_height 0/6 with
    10 cm, 4/6 with 20 cm on the maps of reports/grasping; cups keep 10 cm)."""
    tall_item_height_m: float = 0.14
    """Estimated height from which an item counts as tall, metres."""
    slot_clearance_m: float = 0.04
    """A slot is free when no map object's footprint comes closer than this to it, metres."""
    slot_tolerance_m: float = 0.04
    """A true object counts as at its slot within this x-y distance, metres."""
    preplace_height_m: float = 0.12
    """Pre-place pose above the place pose, metres."""
    release_gap_m: float = 0.01
    """The held object's estimated bottom stops this far above its support, metres."""
    grasp: GraspRunConfig = field(default_factory=GraspRunConfig)
    """Grasp settings (re-observation etc.)."""


def volume(g: dict[str, Any]) -> float:
    """Volume of an ObjectGeometry dict, m³."""
    h = g["half_extents"]
    if g["shape"] == "cylinder":
        r = (h[0] + h[1]) / 2
        return math.pi * r * r * 2 * h[2]
    return 8 * h[0] * h[1] * h[2]


def height(g: dict[str, Any]) -> float:
    """Height of an ObjectGeometry dict, metres."""
    return 2 * g["half_extents"][2]


def footprint_radius(g: dict[str, Any]) -> float:
    """Radius of the circle around an object's footprint, metres."""
    h = g["half_extents"]
    return math.hypot(h[0], h[1]) if g["shape"] == "cuboid" else (h[0] + h[1]) / 2


def top_down(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """``world_from_tcp`` pointing straight down with hand yaw ``yaw`` (as the planner's grasps)."""
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = [[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]]
    m[:3, 3] = [x, y, z]
    return m


def free_line(
    map_objects: list[dict[str, Any]], n: int, cfg: PlaceConfig, spacing_m: float | None = None
) -> list[tuple[float, float]] | None:
    """``n`` slots along y, ``spacing_m`` apart (default ``cfg.slot_spacing_m``), centred on the first
    free line found (x from near to far, then y shifts)."""
    spacing = cfg.slot_spacing_m if spacing_m is None else spacing_m
    for x in np.arange(0.28, 0.71, 0.03):
        for y0 in (0.0, -0.1, 0.1, -0.2, 0.2, -0.3, 0.3):
            slots = [(float(x), float(y0 + (i - (n - 1) / 2) * spacing)) for i in range(n)]
            if any(abs(sy) > 0.45 for _, sy in slots):
                continue
            ok = all(
                math.dist(s, o["geometry"]["center"][:2]) > footprint_radius(o["geometry"]) + cfg.slot_clearance_m
                for s in slots
                for o in map_objects
            )
            if ok:
                return slots
    return None


class Placer:
    """Grasp-and-place on top of a :class:`GraspSession`."""

    def __init__(self, session: GraspSession, cfg: PlaceConfig) -> None:
        self.s = session
        self.cfg = cfg

    def pick(self, target: dict[str, Any], obstacles: list[dict[str, Any]], gt_id: int | None) -> dict[str, Any]:
        """Grasp and lift ``target``; the result of :meth:`GraspSession.attempt`."""
        return self.s.attempt(self.s.frame, target, obstacles, gt_id)

    def place(self, x: float, y: float, support_z: float, obstacles: list[dict[str, Any]]) -> str | None:
        """Put the held object down with its bottom at ``support_z`` (+ release gap) at (x, y);
        returns None or the failing step."""
        s, plan, held = self.s, self.s.last_plan, self.s.last_target
        if plan is None or held is None:
            return "no_grasp"
        g = held["geometry"]
        tcp_above_bottom = float(plan["world_from_tcp_grasp"][2, 3]) - (g["center"][2] - g["half_extents"][2])
        yaw = float(plan["hand_yaw_rad"])
        z = support_z + tcp_above_bottom + self.cfg.release_gap_m
        obs = json.dumps([o["geometry"] for o in obstacles])
        pre = s.planner.plan_to_pose(s.q_arm(), top_down(x, y, z + self.cfg.preplace_height_m, yaw), obs)
        if not pre["ok"]:
            return f"preplace_{pre['cause']}"
        s.execute(pre, 0.0)
        down = s.planner.plan_to_pose(s.q_arm(), top_down(x, y, z, yaw), "[]")
        if not down["ok"]:
            return f"descent_{down['cause']}"
        s.execute(down, 0.0)
        s.hold(0.5, GRIPPER_OPEN_M)
        up = s.planner.plan_to_pose(s.q_arm(), top_down(x, y, z + self.cfg.preplace_height_m, yaw), "[]")
        if up["ok"]:
            s.execute(up, GRIPPER_OPEN_M)
        return None


def _by_label(objs: list[dict[str, Any]], label: str) -> list[dict[str, Any]]:
    return [o for o in objs if o["label"] == label]


def run_place_task(
    task: str, scene: SceneSpec, run_cfg: RunConfig, map_objects: list[dict[str, Any]], cfg: PlaceConfig
) -> dict[str, Any]:
    """Run one placement task; returns ``{"task", "success", "reason", ...}`` (never raises for a
    failed grasp, place or plan)."""
    if task not in TASKS:
        raise ValueError(f"task: expected one of {TASKS}, got {task!r}")
    session = GraspSession(scene, run_cfg, cfg.grasp)
    placer = Placer(session, cfg)
    gt = gt_objects(scene, session.world.ground_truth())
    gt_by_id = {g["id"]: g for g in gt}
    match = match_gt(map_objects, gt, cfg.grasp.match_radius_m)
    out: dict[str, Any] = {"task": task, "success": False, "reason": None, "steps": []}
    objs = [dict(o) for o in map_objects]

    def others(o: dict[str, Any]) -> list[dict[str, Any]]:
        return [m for m in objs if m["id"] != o["id"]]

    if task == "block_in_cup":
        blocks, cups = _by_label(objs, "block"), _by_label(objs, "cup")
        if not blocks or not cups or not any(g["label"] == "cup" for g in gt) or not any(g["label"] == "block" for g in gt):
            out["reason"] = "not_applicable"
            return out
        block = min(blocks, key=lambda o: volume(o["geometry"]))
        cup = max(cups, key=lambda o: volume(o["geometry"]))
        res = placer.pick(block, others(block), match[block["id"]])
        out["steps"].append({"pick": block["id"], **{k: res.get(k) for k in ("success", "cause")}})
        if res.get("open_width_m") is None:  # nothing was grasped (planning failed)
            out["reason"] = f"pick_{res['cause']}"
            return out
        cg = cup["geometry"]
        err = placer.place(cg["center"][0], cg["center"][1], cg["center"][2] + cg["half_extents"][2],
                           [m for m in others(block) if m["id"] != cup["id"]])
        if err:
            out["reason"] = err
        session.hold(1.0, GRIPPER_OPEN_M)
        now = gt_objects(scene, session.world.ground_truth())
        now_by = {g["id"]: g for g in now}
        true_blocks = [g for g in gt if g["label"] == "block"]
        true_cups = [g for g in gt if g["label"] == "cup"]
        smallest = min(true_blocks, key=lambda g: volume(g["geometry"]))["id"]
        largest = max(true_cups, key=lambda g: volume(g["geometry"]))["id"]
        b, c = now_by[smallest]["geometry"], now_by[largest]["geometry"]
        on_axis = math.dist(b["center"][:2], c["center"][:2]) <= c["half_extents"][0]
        bottom = b["center"][2] - b["half_extents"][2]
        top = c["center"][2] + c["half_extents"][2]
        out.update(
            chosen_block_is_smallest=match[block["id"]] == smallest,
            chosen_cup_is_largest=match[cup["id"]] == largest,
            block_offset_m=math.dist(b["center"][:2], c["center"][:2]),
            block_bottom_above_cup_top_m=bottom - top,
        )
        out["success"] = bool(on_axis and -0.01 <= bottom - top <= 0.02)
        if not out["success"] and out["reason"] is None:
            out["reason"] = "not_on_cup"
        return out

    label, key = ("cup", volume) if task == "cups_by_volume" else ("bottle", height)
    items = sorted(_by_label(objs, label), key=lambda o: key(o["geometry"]))
    true_items = [g for g in gt if g["label"] == label]
    if len(items) < 2 or len(true_items) < 2:
        out["reason"] = "not_applicable"
        return out
    # The items themselves leave their places, so only the other objects must clear the line.
    tallest = max(2 * o["geometry"]["half_extents"][2] for o in items)
    spacing = cfg.tall_slot_spacing_m if tallest >= cfg.tall_item_height_m else cfg.slot_spacing_m
    slots = free_line([o for o in objs if o["label"] != label], len(items), cfg, spacing)
    if slots is None:
        out["reason"] = "no_free_line"
        return out
    out["slots"] = slots
    for o, (x, y) in zip(items, slots):
        res = placer.pick(o, others(o), match[o["id"]])
        out["steps"].append({"pick": o["id"], **{k: res.get(k) for k in ("success", "cause")}})
        if res.get("open_width_m") is None:  # nothing was grasped (planning failed)
            out["reason"] = out["reason"] or f"pick_{res['cause']}"
            continue
        err = placer.place(x, y, 0.0, others(o))
        if err:
            out["reason"] = out["reason"] or err
        # The map object now stands at its slot (for the later motions).
        o["geometry"] = {**o["geometry"], "center": [x, y, o["geometry"]["center"][2]]}
        session.go_ready([m["geometry"] for m in objs])
    session.hold(1.0, GRIPPER_OPEN_M)
    now = {g["id"]: g for g in gt_objects(scene, session.world.ground_truth())}
    placed: list[tuple[int, int]] = []  # (slot index, true id)
    out["final"] = [
        {"id": g["id"], "center": [round(v, 4) for v in now[g["id"]]["geometry"]["center"]]} for g in true_items
    ]
    for g in true_items:
        c = now[g["id"]]["geometry"]["center"]
        upright = abs(c[2] - g["geometry"]["half_extents"][2]) < 0.01
        near = [i for i, s in enumerate(slots) if math.dist(s, c[:2]) <= cfg.slot_tolerance_m]
        if upright and near:
            placed.append((near[0], g["id"]))
    placed.sort()
    values = [key(gt_by_id[gid]["geometry"]) for _, gid in placed]
    ordered = all(a < b for a, b in itertools.pairwise(values))
    out.update(n_true=len(true_items), n_placed=len(placed), ordered=ordered)
    out["success"] = bool(len(placed) == len(true_items) and ordered)
    if not out["success"] and out["reason"] is None:
        out["reason"] = "not_all_placed" if len(placed) < len(true_items) else "wrong_order"
    return out
