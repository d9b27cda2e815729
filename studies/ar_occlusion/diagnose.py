"""Where the AR occlusion IoU is lost: every view of ``experiments/ar.py`` scored with several
occluders, each isolating one error source (truth only judges; the variants that use it are
oracles that say how much a source costs, never candidates for the composite).

Occluders per view (the virtual model and camera are the report's):

- ``map``: the map's primitives and the table (the report's map-only composite);
- ``map_aligned``: the same primitives shifted by the map's global offset (oracle: median
  centre difference of the map objects matched to true ones);
- ``map_matched``: only the map objects matched to a true object (oracle: phantoms dropped);
- ``true_prims``: the true objects' primitives (oracle: a perfect map of boxes and cylinders,
  so what is left is the meshes' shape against their bounding primitives);
- ``live``: the sensor's depth image alone (the run's d435 model);
- ``fused_<tau>``: the map's depth clamped into ``live ± tau`` (``tau`` in mm; the map decides
  where the sensor cannot: no return, or closer than ``tau`` to the model);
- ``naive``: no occlusion.

Per view it also records the anchor's match (phantom / mesh / primitive), the true visible pixels,
and how many of the model's pixels have no live return. Output: one JSON line per view.

    PYTHONPATH=experiments python studies/ar_occlusion/diagnose.py --runs RUN_DIR ... --out runs/studies/ar_occlusion.jsonl
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
from objslam import _native
from objslam.config import load_run_config
from objslam.scene import load_scene

REPO = Path(__file__).resolve().parents[2]
import ar  # experiments/ar.py: run with PYTHONPATH=experiments (see the README's command)

TAUS_MM = (3, 6, 10, 20)


def _match(map_objects: list[dict[str, Any]], truth: list[dict[str, Any]]) -> dict[int, dict[str, Any] | None]:
    out: dict[int, dict[str, Any] | None] = {}
    for o in map_objects:
        c = np.asarray(o["geometry"]["center"][:2])
        same = [g for g in truth if g["label"] == o["label"]]
        best = min(same, key=lambda g: np.linalg.norm(np.asarray(g["geometry"]["center"][:2]) - c), default=None)
        ok = best is not None and np.linalg.norm(np.asarray(best["geometry"]["center"][:2]) - c) < ar.MATCH_RADIUS_M
        out[o["id"]] = best if ok else None
    return out


def _score(ours: np.ndarray, visible_true: np.ndarray) -> float:
    iou = ar._iou(ours, visible_true)
    return 1.0 if iou is None else iou


def diagnose(run_dir: str) -> list[dict[str, Any]]:
    cfg = load_run_config(overlays=[Path(run_dir) / "config.toml"])
    scene = load_scene(REPO / cfg.scene if not Path(cfg.scene).is_absolute() else cfg.scene)
    truth = ar.Truth(cfg, scene)
    table = {"center_xy_m": list(scene.table.center), "size_xy_m": list(scene.table.size), "height_m": 0.0}
    map_json = (Path(run_dir) / "map.json").read_text()
    map_objects = json.loads(_native.map_objects_json(map_json))
    matched = _match(map_objects, truth.objects)
    pairs = [(o, g) for o in map_objects if (g := matched[o["id"]]) is not None]
    offset = np.median(
        [np.subtract(o["geometry"]["center"], g["geometry"]["center"]) for o, g in pairs], axis=0
    )
    aligned = [
        {**o, "geometry": {**o["geometry"], "center": list(np.subtract(o["geometry"]["center"], offset))}}
        for o in map_objects
    ]
    true_mesh = {o.id: o.mesh is not None for o in scene.objects}
    rows = []
    for plan in ar.view_plans(map_objects, table, cfg.seed):
        depth, world_from_camera = truth.depth(plan["look_at"])
        live = truth.live
        req = {"table": table, "models": [plan["model"]], "camera": ar._camera(truth, world_from_camera)}

        def run(
            extra: dict[str, Any], real_depth: np.ndarray | None = None, req: dict[str, Any] = req
        ) -> tuple[np.ndarray, np.ndarray]:
            _, cov, d = _native.ar_run(json.dumps({**req, **extra}), real_depth=real_depth)
            return cov[0], d

        cov_map, d_map = run({"map": json.loads(map_json)})
        if not np.any(cov_map > 0):
            continue
        cov_true, _ = run({"objects": truth.objects}, depth)
        visible_true = cov_true == 2
        silhouette = cov_map > 0
        g = matched[plan["object"]]
        row: dict[str, Any] = {
            "scene": scene.name,
            "seed": cfg.seed,
            "kind": plan["kind"],
            "object": plan["object"],
            "anchor": "phantom" if g is None else ("mesh" if true_mesh[g["id"]] else "primitive"),
            "anchor_label": next(o["label"] for o in map_objects if o["id"] == plan["object"]),
            "silhouette_px": int(silhouette.sum()),
            "visible_true_px": int(visible_true.sum()),
            "live_missing_px": int((silhouette & ~(live > 0)).sum()),
            "map_offset_mm": [float(x * 1000) for x in offset],
            "iou": {
                "naive": _score(silhouette, visible_true),
                "map": _score(cov_map == 2, visible_true),
                "map_aligned": _score(run({"objects": aligned})[0] == 2, visible_true),
                "map_matched": _score(
                    run({"objects": [o for o in map_objects if matched[o["id"]] is not None]})[0] == 2, visible_true
                ),
                "true_prims": _score(run({"objects": truth.objects})[0] == 2, visible_true),
                "live": _score(run({"objects": []}, live)[0] == 2, visible_true),
            },
        }
        d_map_inf = np.where(d_map > 0, d_map, np.inf)
        for tau in TAUS_MM:
            t = tau / 1000
            fused = np.where(live > 0, np.clip(d_map_inf, live - t, live + t), d_map_inf)
            fused = np.where(np.isfinite(fused), fused, 0.0).astype(np.float32)
            row["iou"][f"fused_{tau}"] = _score(run({"objects": []}, fused)[0] == 2, visible_true)
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", nargs="+", required=True, help="run folders (config.toml + map.json)")
    ap.add_argument("--out", required=True, help="JSON-lines output, one view per line")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w") as f:
        for rd in a.runs:
            rows = diagnose(rd)
            for r in rows:
                f.write(json.dumps(r) + "\n")
            f.flush()
            means = {k: np.mean([r["iou"][k] for r in rows]) for k in rows[0]["iou"]} if rows else {}
            print(Path(rd).name, len(rows), " ".join(f"{k}={v:.3f}" for k, v in means.items()), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
