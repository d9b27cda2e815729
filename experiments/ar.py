"""``make ar``: augmented reality on maps built by exploration episodes, measured against the
simulator's truth → ``reports/ar.json`` (page ``reports/pages/ar.md``).

For every scene × seed an object-driven episode builds the object map (or ``--runs`` reuses run
folders). Then, in a fresh simulator world of the same scene (objects settled as in the episode):

- Occlusion. For each map object a free camera (the hand camera's intrinsics, 640x480) looks at
  it from 0.4 m away and 0.3 m up, and a virtual model (a box or a cylinder, alternating) is
  placed on the table *behind* it, *in front* of it, and *between* it and its nearest neighbour
  (placements from the map, as an AR application would). Ours: the model's visible pixels against
  the map's depth fused with the live frame an RGB-D camera at that pose delivers (the run's
  sensor model on SAPIEN's render: noise, scale error, flying pixels, stereo shadow, dropouts,
  depth-to-colour registration error; ``objslam.ar_run`` with ``real_depth`` and ``grey``); map
  only: against the map's depth alone; truth: the same model's visible pixels against the exact
  depth SAPIEN renders of the real scene at that camera pose (robot pixels count as no surface,
  in the live frame too, as the episodes mask them); naive: the model's whole silhouette (an
  overlay without occlusion). Score: IoU of visible pixels against the truth's.
- Collision. For each map object a 3 cm cube is dropped from 8 cm above its top (*onto*), and a
  flat 4x4x2.4 cm box slides along the table towards it from 10 cm beyond its side (*against*,
  fast enough to reach it). The same drops run in a world whose static colliders are the scene's
  true shapes at their settled poses; score: distance between the two rest positions (cm) and
  whether the virtual body touches the same real objects (and the table) in both.

Rows: ``scene``, ``seed``, ``occlusion_iou`` (mean over views), ``occlusion_iou_map``, ``occlusion_iou_naive``,
``rest_error_cm`` (median over drops), ``same_contact`` (share of drops), plus per-placement
breakdowns. Re-run on other scenes: ``python experiments/ar.py --scenes scenes/hard*.toml --seeds 0 1``.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import statistics
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import sapien
from objslam import _native
from objslam.calibration import STREAM_AR_LIVE, STREAM_AR_UNIT, STREAM_SENSOR, episode_rng
from objslam.camera import SAPIEN_FROM_CV, RgbdSensor
from objslam.camera_path import look_at
from objslam.config import load_run_config, to_dict
from objslam.episode import run_episode
from objslam.provenance import commit, machine, report_files
from objslam.scene import gt_objects, load_scene
from objslam.world import SimWorld

REPO = Path(__file__).resolve().parents[1]

VIEW_DISTANCE_M = 0.40
"""Horizontal distance from the looked-at object to the AR camera, metres."""
VIEW_HEIGHT_M = 0.30
"""Height of the AR camera above the table, metres."""
GAP_M = 0.02
"""Free gap between a placed virtual model and the map objects, metres."""
BOX = {"kind": "cuboid", "half_extents_m": [0.02, 0.02, 0.04]}
CYLINDER = {"kind": "cylinder", "radius_m": 0.025, "half_height_m": 0.05}
ONTO_CUBE = {"kind": "cuboid", "half_extents_m": [0.015, 0.015, 0.015]}
SLIDER = {"kind": "cuboid", "half_extents_m": [0.02, 0.02, 0.012]}
DROP_HEIGHT_M = 0.08
"""Height of the dropped cube's base above the map object's top, metres."""
SLIDE_START_M = 0.10
"""Free distance between the sliding box's start and the map object's side, metres."""
MATCH_RADIUS_M = 0.05
"""A map object is the true object of the same class with the nearest centre within this, metres."""


def footprint_radius(o: dict[str, Any]) -> float:
    """Radius of a circle around the object's footprint."""
    g = o["geometry"]
    h = g["half_extents"]
    return math.hypot(h[0], h[1]) if g["shape"] == "cuboid" else (h[0] + h[1]) / 2


def model_radius(shape: dict[str, Any]) -> float:
    return math.hypot(*shape["half_extents_m"][:2]) if shape["kind"] == "cuboid" else shape["radius_m"]


def model_half_height(shape: dict[str, Any]) -> float:
    return shape["half_extents_m"][2] if shape["kind"] == "cuboid" else shape["half_height_m"]


class Truth:
    """The simulator's view of a scene: settled true objects, a free camera for AR views, and the
    live depth an RGB-D camera at that pose would deliver."""

    def __init__(self, cfg: Any, scene: Any) -> None:
        self.world = SimWorld(scene, cfg.camera, episode_rng(cfg.seed, scene.seed, STREAM_SENSOR))
        self.objects = gt_objects(scene, self.world.ground_truth())
        c = cfg.camera
        self.intrinsics = c.intrinsics()
        self.size = (c.width, c.height)
        self.camera = self.world.scene.add_camera(
            "ar_view", c.width, c.height, math.radians(c.fovy_deg), c.near_m, c.far_m
        )
        self.camera_config = c
        # The AR camera's sensor unit: the run's sensor model (depth noise, scale error, flying pixels,
        # shadow, dropouts, depth-to-colour registration error); its colour intrinsics are the ones the
        # AR composite is drawn with (the free camera renders with them).
        exact_colour = replace(c.calibration, colour_focal_sigma_rel=0.0, colour_pp_sigma_px=0.0)
        self.sensor = (
            RgbdSensor(
                replace(c, calibration=exact_colour),
                seed=int(episode_rng(cfg.seed, scene.seed, STREAM_AR_UNIT).integers(1 << 62)),
            )
            if c.model == "d435"
            else None
        )
        self.live_rng = episode_rng(cfg.seed, scene.seed, STREAM_AR_LIVE)
        self.frames = 0
        self.rgb = np.zeros((c.height, c.width, 3), np.uint8)
        """Colour image of the last view."""
        self.live = np.zeros((c.height, c.width), np.float32)
        """The sensor's depth of the last view (metres, 0 = no return): what the robot would have."""
        self.grey = np.zeros((c.height, c.width), np.uint8)
        """The sensor's colour image of the last view in grey (the image the AR composite is drawn into)."""

    def depth(self, world_from_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """True depth (metres, 0 = nothing or robot) at a camera pose, and the pose SAPIEN used
        (the colour image of that view is kept in :attr:`rgb`, the sensor's depth in :attr:`live`)."""
        r = world_from_camera[:3, :3] @ SAPIEN_FROM_CV.T
        q = _quat_wxyz(r)
        self.camera.entity.set_pose(sapien.Pose(world_from_camera[:3, 3], q))
        self.world.scene.update_render()
        self.camera.take_picture()
        pos = self.camera.get_picture("Position")
        seg = self.camera.get_picture("Segmentation")[..., 1].astype(np.uint32)
        robot = np.isin(seg, list(self.world.robot_actor_ids))
        depth = np.where(pos[..., 3] < 1, -pos[..., 2], 0.0).astype(np.float32)
        depth[robot] = 0.0
        self.rgb = (np.clip(self.camera.get_picture("Color")[..., :3], 0, 1) * 255).astype(np.uint8)
        # The live depth: the run's sensor model on the same render; the robot's own pixels are
        # masked as the episodes' hand camera masks them (camera.mask_robot_depth).
        if self.sensor is not None:
            pos[robot, 3] = 1.0  # no surface, as the sensor model's renderer buffers mark it
            colour, self.live = self.sensor.apply(
                pos, self.camera.get_picture("Normal"), self.camera.get_picture("Color"), frame_index=self.frames
            )
        else:
            colour, self.live = self.rgb, self.camera_config.depth_noise.apply(depth, self.live_rng)
        self.grey = np.round(colour.astype(np.float32).mean(axis=2)).astype(np.uint8)
        self.frames += 1
        used = np.asarray(self.camera.get_model_matrix(), dtype=np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
        return depth, used


def _quat_wxyz(r: np.ndarray) -> list[float]:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(r).as_quat()
    return [float(w), float(x), float(y), float(z)]


def _camera(truth: Truth, world_from_camera: np.ndarray) -> dict[str, Any]:
    k = truth.intrinsics
    w, h = truth.size
    return {
        "intrinsics": {"width": w, "height": h, "fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2]},
        "world_from_camera": world_from_camera.tolist(),
    }


def _clear(xy: np.ndarray, radius: float, objects: list[dict[str, Any]], table: dict[str, Any]) -> bool:
    """Whether a footprint circle is on the table and clear of every object by ``GAP_M``."""
    c, s = np.asarray(table["center_xy_m"]), np.asarray(table["size_xy_m"])
    if np.any(np.abs(xy - c) > s / 2 - radius):
        return False
    return all(
        np.linalg.norm(xy - np.asarray(o["geometry"]["center"][:2]))
        > radius + footprint_radius(o) + GAP_M * 0.99
        for o in objects
    )


def _iou(a: np.ndarray, b: np.ndarray) -> float | None:
    union = int(np.count_nonzero(a | b))
    return None if union == 0 else int(np.count_nonzero(a & b)) / union


def save_composite(
    path: Path, rgb: np.ndarray, naive: np.ndarray, ours: np.ndarray, true: np.ndarray
) -> None:
    """Three AR composites side by side: the naive overlay, ours (occluded where the map and the live
    depth say), and the truth (occluded where the simulator's depth says); virtual pixels in orange."""
    import cv2

    panels = []
    for mask, title in ((naive, "naive overlay"), (ours, "map + live depth"), (true, "truth")):
        img = rgb.copy()
        img[mask] = (0.3 * img[mask] + 0.7 * np.array([255, 140, 0])).astype(np.uint8)
        cv2.putText(img, title, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2)
        panels.append(img)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(panels, axis=1), cv2.COLOR_RGB2BGR))


def view_plans(map_objects: list[dict[str, Any]], table: dict[str, Any], seed: int) -> list[dict[str, Any]]:
    """The AR views of a map: per map object a virtual box or cylinder (alternating) on the table
    behind it, in front of it, and between it and its nearest neighbour, each with the camera pose
    that looks at it and the model request. Placements come from the map only, as an AR
    application's would; a placement not clear of every map object is skipped."""
    rng = np.random.default_rng([seed, 39])
    out = []
    for i, o in enumerate(map_objects):
        c = np.asarray(o["geometry"]["center"], dtype=float)
        shape = BOX if i % 2 == 0 else CYLINDER
        rm, hz = model_radius(shape), model_half_height(shape)
        ro = footprint_radius(o)
        azimuth = rng.uniform(-0.6, 0.6)  # radians about +x: the AR viewer stands across the table
        u = np.array([math.cos(azimuth), math.sin(azimuth)])
        side = np.array([-u[1], u[0]])
        others = [p for p in map_objects if p is not o]
        placements = []
        d = ro + rm + GAP_M
        placements.append(("behind", c[:2] - u * d + side * rng.uniform(-0.5, 0.5) * rm, u))
        placements.append(("front", c[:2] + u * d + side * rng.uniform(-0.5, 0.5) * rm, u))
        if others:
            n = min(
                others, key=lambda p: float(np.linalg.norm(np.asarray(p["geometry"]["center"][:2]) - c[:2]))
            )
            nc = np.asarray(n["geometry"]["center"][:2], dtype=float)
            dist = float(np.linalg.norm(nc - c[:2]))
            gap = dist - ro - footprint_radius(n)
            if dist > 1e-6 and gap >= 2 * (rm + GAP_M):
                v = (c[:2] - nc) / dist  # from the neighbour towards o: the camera looks past o at n
                placements.append(("between", c[:2] - v * (ro + gap / 2), v))
        for kind, xy, view_u in placements:
            if not _clear(xy, rm, map_objects, table):
                continue
            eye = np.array([*(c[:2] + view_u * VIEW_DISTANCE_M), VIEW_HEIGHT_M])
            target = np.array([*((c[:2] + xy) / 2), min(c[2], hz)])
            model = {
                "name": f"{kind}_{o['id']}",
                "shape": shape,
                "placement": {
                    "mode": "world",
                    "position_m": [float(xy[0]), float(xy[1]), hz],
                    "yaw_rad": azimuth,
                },
            }
            out.append({"kind": kind, "object": o["id"], "look_at": look_at(eye, target), "model": model})
    return out


def occlusion_views(
    map_objects: list[dict[str, Any]],
    map_json: str,
    table: dict[str, Any],
    truth: Truth,
    seed: int,
    images: Path | None = None,
) -> list[dict[str, Any]]:
    """One IoU pair per view of :func:`view_plans`. With ``images``, the first view of each
    placement is saved there as composites."""
    out = []
    for plan in view_plans(map_objects, table, seed):
        kind = plan["kind"]
        depth, world_from_camera = truth.depth(plan["look_at"])
        req = {"table": table, "models": [plan["model"]], "camera": _camera(truth, world_from_camera)}
        with_map = json.dumps({**req, "map": json.loads(map_json)})
        answer, ours, _ = _native.ar_run(with_map, real_depth=truth.live, grey=truth.grey)
        _, map_only, _ = _native.ar_run(with_map)
        exact = {**req, "objects": truth.objects, "config": {"live": {"source": "exact"}}}
        _, true, _ = _native.ar_run(json.dumps(exact), real_depth=depth)
        visible_true = true[0] == 2
        if not np.any(ours[0] > 0):
            continue  # the model is out of view
        # Both hiding the whole model is perfect agreement.
        iou = _iou(ours[0] == 2, visible_true)
        iou_map = _iou(map_only[0] == 2, visible_true)
        iou_naive = _iou(ours[0] > 0, visible_true) or 0.0
        if images is not None and not any(v["kind"] == kind for v in out):
            save_composite(images / f"{kind}.png", truth.rgb, ours[0] > 0, ours[0] == 2, visible_true)
        live = json.loads(answer)["live"]
        out.append(
            {
                "kind": kind,
                "object": plan["object"],
                "iou": 1.0 if iou is None else iou,
                "iou_map": 1.0 if iou_map is None else iou_map,
                "iou_naive": iou_naive,
                "silhouette_px": int(np.count_nonzero(true[0] > 0)),
                "visible_true_px": int(np.count_nonzero(visible_true)),
                "live_holes_px": int(np.count_nonzero((ours[0] > 0) & ~(truth.live > 0))),
                "live_shift_px": live["shift_px"],
                "live_scale": live["scale"],
            }
        )
    return out


def _contacts(body: dict[str, Any], id_map: dict[int, int | None]) -> list[str]:
    names = []
    for c in body["contacts"]:
        if c["kind"] == "table":
            names.append("table")
        elif c["kind"] == "object":
            gid = id_map.get(c["id"], c["id"])
            names.append(f"object{gid}" if gid is not None else f"unmatched{c['id']}")
    return sorted(names)


def collision_drops(
    map_objects: list[dict[str, Any]], map_json: str, table: dict[str, Any], truth: Truth, seed: int
) -> list[dict[str, Any]]:
    """Onto / against drops per map object; rest error and contact agreement per drop."""
    rng = np.random.default_rng([seed, 40])
    matched: dict[int, int | None] = {}
    for o in map_objects:
        c = np.asarray(o["geometry"]["center"][:2])
        same = [g for g in truth.objects if g["label"] == o["label"]]
        best = min(
            same, key=lambda g: np.linalg.norm(np.asarray(g["geometry"]["center"][:2]) - c), default=None
        )
        ok = (
            best is not None
            and np.linalg.norm(np.asarray(best["geometry"]["center"][:2]) - c) < MATCH_RADIUS_M
        )
        matched[o["id"]] = best["id"] if ok else None
    truth_ids = {g["id"]: g["id"] for g in truth.objects}
    out = []
    for o in map_objects:
        g = o["geometry"]
        c = np.asarray(g["center"], dtype=float)
        top = c[2] + g["half_extents"][2]
        drops = []
        offset = rng.uniform(-0.005, 0.005, size=2)
        onto_z = top + DROP_HEIGHT_M + ONTO_CUBE["half_extents_m"][2]
        drops.append(("onto", ONTO_CUBE, [c[0] + offset[0], c[1] + offset[1], onto_z], [0.0, 0.0, 0.0]))
        ro, rs = footprint_radius(o), model_radius(SLIDER)
        for a in rng.permutation(8) * (math.pi / 4):
            u = np.array([math.cos(a), math.sin(a)])
            start = c[:2] + u * (ro + SLIDE_START_M + rs)
            path_clear = all(
                _clear(c[:2] + u * (ro + s + rs), rs, [p for p in map_objects if p is not o], table)
                for s in np.linspace(0.0, SLIDE_START_M, 6)
            )
            if path_clear and _clear(start, rs, map_objects, table):
                # Enough speed to slide 5 cm past the object's side on friction alone.
                speed = math.sqrt(2 * 0.8 * 9.81 * (SLIDE_START_M + 0.05))
                hz = SLIDER["half_extents_m"][2]
                drops.append(("against", SLIDER, [start[0], start[1], hz + 1e-4], [*(-u * speed), 0.0]))
                break
        for kind, shape, pos, vel in drops:
            model = {
                "name": kind,
                "shape": shape,
                "placement": {"mode": "world", "position_m": pos, "yaw_rad": 0.0},
            }
            req = {"table": table, "models": [model], "drop": [vel]}
            ours = json.loads(_native.ar_run(json.dumps({**req, "map": json.loads(map_json)}))[0])["drop"]
            true = json.loads(_native.ar_run(json.dumps({**req, "objects": truth.objects}))[0])["drop"]
            p_ours = np.asarray(ours["bodies"][0]["world_from_model"]["translation"])
            p_true = np.asarray(true["bodies"][0]["world_from_model"]["translation"])
            contacts_ours = _contacts(ours["bodies"][0], matched)
            contacts_true = _contacts(true["bodies"][0], truth_ids)
            out.append(
                {
                    "kind": kind,
                    "object": o["id"],
                    "true_object": matched[o["id"]],
                    "rest_error_cm": float(np.linalg.norm(p_ours - p_true) * 100),
                    "same_contact": contacts_ours == contacts_true,
                    "contacts_ours": contacts_ours,
                    "contacts_true": contacts_true,
                    "settled": bool(ours["settled"] and true["settled"]),
                }
            )
    return out


def _mean(v: list[float]) -> float | None:
    return float(np.mean(v)) if v else None


def _median(v: list[float]) -> float | None:
    return float(statistics.median(v)) if v else None


def evaluate(cfg: Any, map_json: str, run_dir: str, images: Path | None = None) -> dict[str, Any]:
    scene = load_scene(REPO / cfg.scene if not Path(cfg.scene).is_absolute() else cfg.scene)
    truth = Truth(cfg, scene)
    table = {"center_xy_m": list(scene.table.center), "size_xy_m": list(scene.table.size), "height_m": 0.0}
    map_objects = json.loads(_native.map_objects_json(map_json))
    images = images / f"{scene.name}_seed{cfg.seed}" if images is not None else None
    views = occlusion_views(map_objects, map_json, table, truth, cfg.seed, images)
    drops = collision_drops(map_objects, map_json, table, truth, cfg.seed)
    row: dict[str, Any] = {
        "scene": scene.name,
        "seed": cfg.seed,
        "run_dir": run_dir,
        "map_objects": len(map_objects),
        "true_objects": len(truth.objects),
        "views": len(views),
        "drops": len(drops),
        "occlusion_iou": _mean([v["iou"] for v in views]),
        "occlusion_iou_map": _mean([v["iou_map"] for v in views]),
        "occlusion_iou_naive": _mean([v["iou_naive"] for v in views]),
        "rest_error_cm": _median([d["rest_error_cm"] for d in drops]),
        "same_contact": _mean([float(d["same_contact"]) for d in drops]),
    }
    for kind in ("behind", "front", "between"):
        row[f"occlusion_iou_{kind}"] = _mean([v["iou"] for v in views if v["kind"] == kind])
        row[f"occlusion_iou_naive_{kind}"] = _mean([v["iou_naive"] for v in views if v["kind"] == kind])
    for kind in ("onto", "against"):
        row[f"rest_error_cm_{kind}"] = _median([d["rest_error_cm"] for d in drops if d["kind"] == kind])
        row[f"same_contact_{kind}"] = _mean([float(d["same_contact"]) for d in drops if d["kind"] == kind])
    row["view_details"], row["drop_details"] = views, drops
    return row


def _fmt(v: Any, spec: str = ".3f") -> str:
    return "–" if v is None else format(v, spec)


def write_reports(
    rows: list[dict[str, Any]], config: dict[str, Any], command: str, out: Path
) -> dict[str, Any]:
    views = [v for r in rows for v in r["view_details"]]
    drops = [d for r in rows for d in r["drop_details"]]
    summary = {
        "mean_occlusion_iou": _mean([r["occlusion_iou"] for r in rows if r["occlusion_iou"] is not None]),
        "mean_occlusion_iou_map": _mean(
            [r["occlusion_iou_map"] for r in rows if r["occlusion_iou_map"] is not None]
        ),
        "mean_occlusion_iou_naive": _mean(
            [r["occlusion_iou_naive"] for r in rows if r["occlusion_iou_naive"] is not None]
        ),
        "median_rest_error_cm": _median([d["rest_error_cm"] for d in drops]),
        "same_contact_rate": _mean([float(d["same_contact"]) for d in drops]),
        "views": len(views),
        "drops": len(drops),
        "unsettled_drops": sum(not d["settled"] for d in drops),
    }
    for kind in ("behind", "front", "between"):
        summary[f"mean_iou_{kind}"] = _mean([v["iou"] for v in views if v["kind"] == kind])
        summary[f"mean_iou_naive_{kind}"] = _mean([v["iou_naive"] for v in views if v["kind"] == kind])
    for kind in ("onto", "against"):
        summary[f"median_rest_error_cm_{kind}"] = _median(
            [d["rest_error_cm"] for d in drops if d["kind"] == kind]
        )
        summary[f"same_contact_rate_{kind}"] = _mean(
            [float(d["same_contact"]) for d in drops if d["kind"] == kind]
        )
    s = summary
    targets = {
        "mean_occlusion_iou >= 0.9": s["mean_occlusion_iou"] is not None and s["mean_occlusion_iou"] >= 0.9,
        "mean_occlusion_iou > naive": (s["mean_occlusion_iou"] or 0) > (s["mean_occlusion_iou_naive"] or 0),
        "median_rest_error_cm <= 1.0": s["median_rest_error_cm"] is not None
        and s["median_rest_error_cm"] <= 1.0,
    }
    report = {
        "commit": commit(),
        "command": command,
        "machine": machine(),
        "config": config,
        "summary": summary,
        "targets": targets,
        "rows": rows,
    }
    out.mkdir(parents=True, exist_ok=True)
    (report_files(out, "ar")[0]).write_text(json.dumps(report, indent=2) + "\n")
    lines = [
        "# Augmented reality on the object map, against the simulator's truth",
        "",
        f"Generated by `{command}` (commit {report['commit']}). Machine: {report['machine']}.",
        "",
        "Method (details in `experiments/ar.py`): maps from object-driven episodes; per map object a",
        "virtual box or cylinder is placed behind, in front of, and between it and its nearest neighbour,",
        "seen by a free 640x480 camera 0.4 m away and 0.3 m up. *ours* = its visible pixels against the",
        "map's depth (objects and table) fused with the live frame of the run's RGB-D sensor model at",
        "that pose, *map only* = against the map's depth alone, *naive* = its whole silhouette, truth =",
        "its visible pixels against SAPIEN's exact depth of the real scene (robot pixels count as empty).",
        "Drops: a 3 cm",
        "cube falls onto each map object from 8 cm above its top; a flat box slides against its side;",
        "truth = the same drop among the scene's true shapes (rapier3d in both).",
        "",
        (
            f"- mean occlusion IoU **{_fmt(s['mean_occlusion_iou'])}**"
            f" (map only {_fmt(s['mean_occlusion_iou_map'])}, naive overlay"
            f" {_fmt(s['mean_occlusion_iou_naive'])}), over {s['views']} views;"
            f" behind {_fmt(s['mean_iou_behind'])} (naive {_fmt(s['mean_iou_naive_behind'])}),"
            f" front {_fmt(s['mean_iou_front'])} (naive {_fmt(s['mean_iou_naive_front'])}),"
            f" between {_fmt(s['mean_iou_between'])} (naive {_fmt(s['mean_iou_naive_between'])})"
        ),
        (
            f"- median rest error **{_fmt(s['median_rest_error_cm'], '.2f')} cm** over {s['drops']} drops"
            f" (onto {_fmt(s['median_rest_error_cm_onto'], '.2f')},"
            f" against {_fmt(s['median_rest_error_cm_against'], '.2f')});"
            f" same contact {_fmt(s['same_contact_rate'])} (onto {_fmt(s['same_contact_rate_onto'])},"
            f" against {_fmt(s['same_contact_rate_against'])}); unsettled drops: {s['unsettled_drops']}"
        ),
        "- targets: " + ", ".join(f"{k}: {'met' if v else 'NOT met'}" for k, v in targets.items()),
        "",
        "| scene | seed | map / true objects | views | occlusion IoU | map only | naive IoU | drops | rest error (cm, median) | same contact |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['seed']} | {r['map_objects']} / {r['true_objects']} | {r['views']} |"
            f" {_fmt(r['occlusion_iou'])} | {_fmt(r['occlusion_iou_map'])} | {_fmt(r['occlusion_iou_naive'])} |"
            f" {r['drops']} |"
            f" {_fmt(r['rest_error_cm'], '.2f')} | {_fmt(r['same_contact'], '.2f')} |"
        )
    lines += [
        "",
        "Time per AR frame: criterion entry `ar_frame_640x480` in `reports/bench.json` (`make bench`).",
    ]
    (report_files(out, "ar")[1]).write_text("\n".join(lines) + "\n")
    return report


def run_config(configs: list[dict[str, Any]]) -> dict[str, Any]:
    """The resolved configuration recorded in the report."""
    return {
        "episodes": configs[0] if configs else {},
        "scenes": sorted({c["scene"] for c in configs}),
        "seeds": sorted({c["seed"] for c in configs}),
        "ar": {
            "view_distance_m": VIEW_DISTANCE_M,
            "view_height_m": VIEW_HEIGHT_M,
            "gap_m": GAP_M,
            "models": {"box": BOX, "cylinder": CYLINDER, "onto_cube": ONTO_CUBE, "slider": SLIDER},
            "drop_height_m": DROP_HEIGHT_M,
            "slide_start_m": SLIDE_START_M,
            "match_radius_m": MATCH_RADIUS_M,
            "core": "objslam_core::ar::ArConfig defaults",
        },
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--scenes",
        nargs="+",
        default=sorted(str(p.relative_to(REPO)) for p in (REPO / "scenes").glob("scene*.toml")),
        help="scene files (default: scenes/scene*.toml)",
    )
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1], help="episode seeds (default: 0 1)")
    ap.add_argument("--strategy", default="object-driven", help="exploration strategy of the episodes")
    ap.add_argument(
        "--config", action="append", default=[], help="extra TOML overlay of the episodes (repeatable)"
    )
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override an episode config key"
    )
    ap.add_argument(
        "--runs", nargs="+", help="reuse these run folders (their config.toml and map.json) instead"
    )
    ap.add_argument(
        "--episodes-too", action="store_true", help="with --runs: also run the --scenes x --seeds episodes"
    )
    ap.add_argument("--out", default=str(REPO / "reports"), help="report folder (default: reports)")
    ap.add_argument(
        "--images", type=int, default=1, help="save AR composites of the first N scene/seed rows (default 1)"
    )
    a = ap.parse_args(argv)
    command = "python experiments/ar.py " + " ".join(
        shlex.quote(x) for x in (argv if argv is not None else sys.argv[1:])
    )
    rows, configs = [], []
    jobs: list[tuple[Any, str | None]] = []
    for rd in a.runs or []:
        jobs.append((load_run_config(overlays=[Path(rd) / "config.toml"]), rd))
    if not a.runs or a.episodes_too:
        for scene in a.scenes:
            for seed in a.seeds:
                overrides = [*a.set, f'scene="{scene}"', f"seed={seed}", "record.enabled=false"]
                jobs.append(
                    (load_run_config(overlays=a.config, overrides=overrides, strategy=a.strategy), None)
                )
    for cfg, rd in jobs:
        if rd is None:
            result = run_episode(cfg, progress=False)
            rd, map_json = str(result.run_dir), result.map_json
        else:
            map_json = (Path(rd) / "map.json").read_text()
        images = Path(a.out) / "pages" / "ar_images" if len(rows) < a.images else None
        row = evaluate(cfg, map_json, rd, images)
        rows.append(row)
        configs.append(to_dict(cfg))
        print(
            f"{row['scene']} seed {row['seed']}: occlusion IoU {_fmt(row['occlusion_iou'])} "
            f"(naive {_fmt(row['occlusion_iou_naive'])}, {row['views']} views), rest error "
            f"{_fmt(row['rest_error_cm'], '.2f')} cm, same contact {_fmt(row['same_contact'], '.2f')} "
            f"({row['drops']} drops)",
            flush=True,
        )
        # The report is rewritten after every row, so an interrupted run keeps what it measured.
        report = write_reports(rows, run_config(configs), command, Path(a.out))
    if rows:
        print(json.dumps(report["summary"], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
