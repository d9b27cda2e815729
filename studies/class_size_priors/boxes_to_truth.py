"""Which true object each box of a map object boxes: per observation, the true objects whose projected
boxes overlap it most (2D IoU, camera at its true pose).

Usage: python studies/class_size_priors/boxes_to_truth.py <capture dir> <dumped map.json> <map id>
"""

from __future__ import annotations

import json
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np


def corners(g: dict) -> np.ndarray:
    c, he, yaw = np.array(g["center"]), np.array(g["half_extents"]), g["yaw_rad"]
    if g["shape"] == "cylinder":
        ang = np.linspace(0, 2 * math.pi, 16, endpoint=False)
        return np.array([c + [he[0] * math.cos(a), he[0] * math.sin(a), s * he[2]] for a in ang for s in (-1, 1)])
    rot = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    return np.array([c + rot @ (he * [sx, sy, sz]) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])


def iou(a: list[float], b: list[float]) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def main() -> None:
    cap, map_file, map_id = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
    truth = {o["id"]: corners(o["geometry"]) for o in json.loads((cap / "system.json").read_text())["ground_truth"]}
    frames = {}
    for line in (cap / "events.jsonl").read_text().splitlines():
        e = json.loads(line)
        if e.get("event") == "frame":
            frames[e["index"]] = e
    obj = next(o for o in json.loads(map_file.read_text())["objects"] if o["id"] == map_id)
    best = Counter()
    for ob in obj["observations"]:
        e = frames[ob["frame"]]
        k = np.array(e["intrinsics"]).reshape(3, 3)
        camera_from_world = np.linalg.inv(np.array(e["world_from_camera_gt"]).reshape(4, 4))
        box = [*ob["bbox"]["min"], *ob["bbox"]["max"]]
        scores = []
        for gid, pts in truth.items():
            pc = pts @ camera_from_world[:3, :3].T + camera_from_world[:3, 3]
            if (pc[:, 2] <= 0).any():
                continue
            uv = pc @ k.T
            uv = uv[:, :2] / uv[:, 2:]
            scores.append((iou(box, [*uv.min(axis=0), *uv.max(axis=0)]), gid))
        scores.sort(reverse=True)
        labels = [d[4] for d in e["detections"] if abs(d[0] - box[0]) < 1e-6]
        print(ob["frame"], [round(v) for v in box], [(g, round(s, 2)) for s, g in scores[:3]], labels)
        if scores:
            best[scores[0][1]] += 1
    print("best-matching true object per box:", dict(best))


if __name__ == "__main__":
    main()
