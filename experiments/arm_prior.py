"""The kinematic prior's pose error per world preset, the ``pose_prior`` part of ``make sensor``
(``experiments/sensor.py --prior-scenes ... --prior-seeds ...``).

Per preset, scene and seed, a simulated robot with that episode's calibration errors (``[robot]``,
drawn from the run and scene seeds as in every episode; :mod:`objslam.calibration`) moves its
camera through a fixed tour — the four Init views over the table's corners, then one view above
the table centre and back to the first corner — streaming frames at the run's frame rate. Each
frame's prior (nominal forward kinematics of the joint readings paired with the image, times the
view's bias and the frame's jitter) is compared with the renderer's true camera pose. Rows:
``{"preset", "scene", "seed", "frames", "trans_rms_mm", "trans_p90_mm", "rot_rms_deg",
"rot_p90_deg", "moving_trans_rms_mm", "still_trans_rms_mm"}`` (moving: the frames streamed during a
move; still: the settled frame at each view's end), with the resolved robot configs. One simulator
at a time.

``realistic`` is ``experiments/configs/default.toml``; ``ideal`` is that overlaid with the
``[robot]`` table of ``experiments/configs/presets/ideal.toml``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import tomllib

REPO = Path(__file__).resolve().parents[1]

PRESETS = ("realistic", "ideal")


def robot_overrides(preset: str) -> list[str]:
    """``--set``-style overrides selecting a preset's ``[robot]`` table (none for realistic)."""
    if preset == "realistic":
        return []
    data = tomllib.loads((REPO / "experiments" / "configs" / "presets" / f"{preset}.toml").read_text())
    return [f"robot.{k}={v}" for k, v in data.get("robot", {}).items()]


def tour(scene: Any) -> list[np.ndarray]:
    """The camera poses visited: the Init views (corners inset 0.3 m, 0.5 m high, looking at the
    table centre), the centre from 0.45 m above, the first corner again."""
    from objslam.camera_path import look_at

    cx, cy = scene.table.center
    sx, sy = scene.table.size
    centre = np.array([cx, cy, 0.0])
    corners = [
        np.array([cx + dx * (sx / 2 - 0.3), cy + dy * (sy / 2 - 0.3), 0.5])
        for dx, dy in ((-1, -1), (-1, 1), (1, 1), (1, -1))
    ]
    views = [look_at(c, centre) for c in corners]
    return [*views, look_at(centre + [0.0, 0.0, 0.45], centre), views[0]]


def measure(preset: str, scene_path: Path, seed: int) -> dict[str, Any]:
    """One preset × scene × seed row (see the module docs)."""
    from objslam.calibration import arm_error_seed, draw_arm_errors, pose_error
    from objslam.config import load_run_config
    from objslam.scene import load_scene
    from objslam.world import MotionError, SimWorld, UnreachablePoseError

    cfg = load_run_config(overrides=[f"seed={seed}", *robot_overrides(preset)])
    scene = load_scene(scene_path)
    arm = draw_arm_errors(cfg.robot, arm_error_seed(seed, scene.seed))
    world = SimWorld(scene, cfg.camera, np.random.default_rng([seed, 1]), arm_errors=arm)
    moving: list[tuple[float, float]] = []
    still: list[tuple[float, float]] = []
    for vi, view in enumerate(tour(scene)):
        try:
            frames = list(
                world.move_camera_to(view, frame_rate_hz=cfg.frame_rate_hz, max_joint_speed=cfg.max_joint_speed)
            )
        except (UnreachablePoseError, MotionError):
            continue
        for k, f in enumerate(frames):
            err = pose_error(arm.prior(f.world_from_camera_fk, vi, f.index), f.world_from_camera_gt)
            (still if k == len(frames) - 1 else moving).append(err)
    both = moving + still
    t = np.array([e[0] for e in both]) * 1e3
    r = np.array([e[1] for e in both])

    def rms(v: list[tuple[float, float]]) -> float | None:
        return float(np.sqrt(np.mean(np.square([e[0] * 1e3 for e in v])))) if v else None

    return {
        "preset": preset,
        "scene": scene.name,
        "seed": seed,
        "frames": len(both),
        "trans_rms_mm": float(np.sqrt(np.mean(t**2))),
        "trans_p90_mm": float(np.percentile(t, 90)),
        "rot_rms_deg": float(np.sqrt(np.mean(r**2))),
        "rot_p90_deg": float(np.percentile(r, 90)),
        "moving_trans_rms_mm": rms(moving),
        "still_trans_rms_mm": rms(still),
        "hand_eye_mm": round(pose_error(arm.camera_from_true_camera, np.eye(4))[0] * 1e3, 3),
        "time_offset_ms": round(arm.time_offset_s * 1e3, 2),
    }


def measure_all(scenes: list[str], seeds: list[int], presets: list[str]) -> dict[str, Any]:
    """``{"config": robot config per preset, "rows": one row per preset x scene x seed}``."""
    from dataclasses import asdict

    from objslam.config import load_run_config

    configs = {p: asdict(load_run_config(overrides=robot_overrides(p)).robot) for p in presets}
    rows = []
    for p in presets:
        for s in scenes:
            for seed in seeds:
                rows.append(measure(p, REPO / "scenes" / f"{s}.toml", seed))
                print(json.dumps(rows[-1]), flush=True)
    return {"config": configs, "rows": rows}


def page_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The Markdown section of the sensor report's page."""
    lines = [
        "Prior = nominal forward kinematics of the joint readings paired with each image (times the view's",
        "bias and the frame's jitter); error against the renderer's true camera pose, over every frame of a",
        "fixed six-view tour (module docs of `experiments/arm_prior.py`). Mean over the rows of each preset.",
        "",
        "| preset | rows | frames | trans RMS mm | trans p90 mm | rot RMS deg | rot p90 deg | moving trans RMS mm | still trans RMS mm |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for p in dict.fromkeys(r["preset"] for r in rows):
        sel = [r for r in rows if r["preset"] == p]

        def mean(k: str, sel: list[dict[str, Any]] = sel) -> float:
            v = [r[k] for r in sel if r[k] is not None]
            return float(np.mean(v)) if v else math.nan

        lines.append(
            f"| {p} | {len(sel)} | {sum(r['frames'] for r in sel)} | {mean('trans_rms_mm'):.2f} | "
            f"{mean('trans_p90_mm'):.2f} | {mean('rot_rms_deg'):.3f} | {mean('rot_p90_deg'):.3f} | "
            f"{mean('moving_trans_rms_mm'):.2f} | {mean('still_trans_rms_mm'):.2f} |"
        )
    lines += ["", "Per row:", "", "| preset | scene | seed | trans RMS mm | rot RMS deg | hand-eye mm | time offset ms |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(
            f"| {r['preset']} | {r['scene']} | {r['seed']} | {r['trans_rms_mm']:.2f} | {r['rot_rms_deg']:.3f} | "
            f"{r['hand_eye_mm']:.1f} | {r['time_offset_ms']:.1f} |"
        )
    return lines
