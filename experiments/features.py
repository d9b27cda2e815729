"""``make features``: the core's ORB extractor against OpenCV's on real photographs and rendered
frames under warps with known homographies → ``reports/features.json`` (page
``reports/pages/features.md``).

Images: the photographs shipped with installed packages (matplotlib's ``grace_hopper.jpg``,
scikit-learn's ``china.jpg`` and ``flower.jpg``), resized to 640x480, and SAPIEN renders of
``scenes/scene01.toml`` at the run config's camera (640x480) from ``--views`` poses above the table on the robot's side
(``--no-render`` leaves them out). Each image is warped by a homography ``H`` about its centre
(``rot10``, ``rot30``: rotation by 10 / 30 degrees; ``scale0.8``; ``persp``: a mild perspective
tilt with a 5 degree rotation), bilinear, zero outside.

Both extractors run with the same settings, single-threaded: 1000 features, 8 levels, scale
factor 1.2, FAST threshold 20, patch 31 px (OpenCV: ``cv2.ORB_create`` with those arguments,
Harris ranking; the core: ``OrbConfig`` with those fields and its defaults otherwise: Harris
ranking with ``spread_share`` 0.2 of each level's features spread over 30 px grid cells).

Per image, warp and extractor:

- ``repeatability`` (Mikolajczyk and Schmid's, for points): keypoints of both images are kept when
  they fall, mapped by ``H`` (or ``H⁻¹``), at least ``MARGIN_PX`` inside the other image (the
  common region). A correspondence is a pair ``(a, b)`` that are each other's nearest neighbour
  with ``‖H a − b‖ ≤ EPS_PX`` (one-to-one). Repeatability = correspondences / min(n_a, n_b) over
  the common region.
- ``precision``: the common-region descriptors matched by brute-force Hamming distance with
  cross-check (``cv2.BFMatcher(NORM_HAMMING, crossCheck=True)``, the same matcher for both);
  a match is correct when ``‖H a − b‖ ≤ EPS_PX``; ``correct`` counts them, precision = correct /
  matches.
- ``ms``: median wall time of one extraction of the unwarped image (``--repeats`` calls).
- ``coverage``: share of 32 px cells of the unwarped image holding at least one keypoint (the
  spatial spread).

``python experiments/features.py [--out reports] [--repeats 15] [--views 2] [--no-render]``
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from objslam import _native
from objslam.provenance import commit, machine, report_files

REPO = Path(__file__).resolve().parents[1]
#: Correspondence tolerance, pixels of the warped image.
EPS_PX = 3.0
#: Keypoints mapped closer than this to the other image's border are outside the common region.
MARGIN_PX = 16.0
#: Cell side for the spatial coverage, pixels.
COVERAGE_CELL_PX = 32
#: Extractor settings shared by both sides.
SETTINGS = {"n_features": 1000, "n_levels": 8, "scale_factor": 1.2, "fast_threshold": 20, "patch_px": 31}
SIZE = (640, 480)


def photographs() -> dict[str, np.ndarray]:
    """The real photographs of installed packages, grey, 640x480."""
    import matplotlib
    import sklearn

    paths = {
        "grace_hopper": Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg",
        "china": Path(sklearn.__file__).parent / "datasets" / "images" / "china.jpg",
        "flower": Path(sklearn.__file__).parent / "datasets" / "images" / "flower.jpg",
    }
    out = {}
    for name, p in paths.items():
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise FileNotFoundError(p)
        out[name] = cv2.resize(img, SIZE, interpolation=cv2.INTER_AREA)
    return out


def renders(n_views: int) -> dict[str, np.ndarray]:
    """SAPIEN renders of scene01 (grey), the camera looking at the table centre from above."""
    from objslam.camera_path import look_at
    from objslam.config import load_run_config
    from objslam.episode import grey_of
    from objslam.scene import load_scene
    from objslam.world import SimWorld

    cfg = load_run_config(overrides=['scene="scenes/scene01.toml"', "seed=0"])
    spec = load_scene(REPO / cfg.scene)
    world = SimWorld(spec, cfg.camera, np.random.default_rng([cfg.seed, 1]), textures=cfg.textures)
    target = np.array([spec.table.center[0], spec.table.center[1], 0.0])
    out = {}
    for v in range(n_views):
        # On the robot's side of the table, spread sideways.
        side = 0.0 if n_views == 1 else -0.12 + 0.24 * v / (n_views - 1)
        eye = target + np.array([-0.2, side, 0.45])
        for _ in world.move_camera_to(
            look_at(eye, target), frame_rate_hz=cfg.frame_rate_hz, what="features view"
        ):
            pass
        out[f"scene01_view{v}"] = grey_of(world.render().rgb)
    return out


def homographies(w: int, h: int) -> dict[str, np.ndarray]:
    """The warps, about the image centre."""
    c = np.array([[1, 0, w / 2], [0, 1, h / 2], [0, 0, 1]], float)
    ci = np.linalg.inv(c)

    def rot(deg: float, s: float = 1.0) -> np.ndarray:
        t = np.deg2rad(deg)
        return np.array([[s * np.cos(t), -s * np.sin(t), 0], [s * np.sin(t), s * np.cos(t), 0], [0, 0, 1]])

    persp = rot(5.0) @ np.array([[1, 0, 0], [0, 1, 0], [3e-4, 2e-4, 1]])
    return {
        k: c @ m @ ci
        for k, m in {"rot10": rot(10), "rot30": rot(30), "scale0.8": rot(0, 0.8), "persp": persp}.items()
    }


def objslam_orb(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cfg = {
        "n_features": SETTINGS["n_features"],
        "n_levels": SETTINGS["n_levels"],
        "scale_factor": SETTINGS["scale_factor"],
        "fast_threshold": SETTINGS["fast_threshold"],
    }
    kp, desc = _native.orb_extract(np.ascontiguousarray(img), json.dumps(cfg))
    return kp[:, :2].astype(np.float64), desc


_CV_ORB = None


def opencv_orb(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    global _CV_ORB
    if _CV_ORB is None:
        s = SETTINGS
        _CV_ORB = cv2.ORB_create(
            nfeatures=s["n_features"],
            scaleFactor=s["scale_factor"],
            nlevels=s["n_levels"],
            edgeThreshold=s["patch_px"],
            patchSize=s["patch_px"],
            fastThreshold=s["fast_threshold"],
        )
    kps, desc = _CV_ORB.detectAndCompute(img, None)
    pts = np.array([k.pt for k in kps], np.float64).reshape(-1, 2)
    return pts, (desc if desc is not None else np.zeros((0, 32), np.uint8))


EXTRACTORS = {"objslam": objslam_orb, "opencv": opencv_orb}


def apply_h(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    p = np.c_[pts, np.ones(len(pts))] @ h.T
    return p[:, :2] / p[:, 2:3]


def inside(pts: np.ndarray, w: int, h: int) -> np.ndarray:
    return (
        (pts[:, 0] >= MARGIN_PX)
        & (pts[:, 1] >= MARGIN_PX)
        & (pts[:, 0] < w - MARGIN_PX)
        & (pts[:, 1] < h - MARGIN_PX)
    )


def evaluate(pa, da, pb, db, hom: np.ndarray, w: int, h: int) -> dict[str, Any]:
    """Repeatability, matches and precision of one pair (module docs)."""
    ka = inside(apply_h(hom, pa), w, h) & inside(pa, w, h)
    kb = inside(apply_h(np.linalg.inv(hom), pb), w, h) & inside(pb, w, h)
    pa, da, pb, db = pa[ka], da[ka], pb[kb], db[kb]
    if len(pa) == 0 or len(pb) == 0:
        return {"repeatability": 0.0, "precision": 0.0, "correct": 0, "matches": 0}
    qa = apply_h(hom, pa)
    dist = np.linalg.norm(qa[:, None, :] - pb[None, :, :], axis=2)
    nn_ab, nn_ba = dist.argmin(1), dist.argmin(0)
    mutual = nn_ba[nn_ab] == np.arange(len(pa))
    n_corr = int(np.sum(mutual & (dist[np.arange(len(pa)), nn_ab] <= EPS_PX)))
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(da, db)
    correct = sum(1 for m in matches if dist[m.queryIdx, m.trainIdx] <= EPS_PX)
    return {
        "repeatability": n_corr / min(len(pa), len(pb)),
        "precision": correct / max(len(matches), 1),
        "correct": correct,
        "matches": len(matches),
    }


def coverage(pts: np.ndarray, w: int, h: int) -> float:
    nx, ny = -(-w // COVERAGE_CELL_PX), -(-h // COVERAGE_CELL_PX)
    cells = {(int(x) // COVERAGE_CELL_PX, int(y) // COVERAGE_CELL_PX) for x, y in pts}
    return len(cells) / (nx * ny)


def timed_ms(fn, img: np.ndarray, repeats: int) -> float:
    fn(img)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(img)
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def measure(images: dict[str, np.ndarray], repeats: int) -> list[dict[str, Any]]:
    rows = []
    for name, img in images.items():
        h, w = img.shape
        for ex_name, fn in EXTRACTORS.items():
            ms = timed_ms(fn, img, repeats)
            pa, da = fn(img)
            cov = coverage(pa, w, h)
            for warp, hom in homographies(w, h).items():
                warped = cv2.warpPerspective(img, hom, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
                pb, db = fn(warped)
                r = evaluate(pa, da, pb, db, hom, w, h)
                rows.append(
                    {
                        "image": name,
                        "warp": warp,
                        "extractor": ex_name,
                        **r,
                        "ms": ms,
                        "coverage": cov,
                        "n_keypoints": len(pa),
                    }
                )
    return rows


def summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    out = {}
    for ex in EXTRACTORS:
        rs = [r for r in rows if r["extractor"] == ex]
        per_image_ms = {r["image"]: r["ms"] for r in rs}
        out[ex] = {
            "repeatability": statistics.mean(r["repeatability"] for r in rs),
            "precision": statistics.mean(r["precision"] for r in rs),
            "correct": statistics.mean(r["correct"] for r in rs),
            "ms": statistics.median(per_image_ms.values()),
            "coverage": statistics.mean({r["image"]: r["coverage"] for r in rs}.values()),
        }
    return out


def write_report(out: Path, result: dict[str, Any]) -> None:
    json_path, md_path = report_files(out, "features")
    json_path.write_text(json.dumps(result, indent=1) + "\n")
    s = result["summary"]
    lines = [
        "# ORB features: the core's extractor against OpenCV's under known warps",
        "",
        f"Made by `{result['command']}` at commit `{result['commit']}` on {result['machine']}.",
        "",
        "Settings (both): " + ", ".join(f"{k} {v}" for k, v in SETTINGS.items()) + "; single thread.",
        f"Repeatability: mutual nearest keypoints within {EPS_PX:g} px after the warp over the common",
        f"region ({MARGIN_PX:g} px margin), / min(n_a, n_b). Precision: cross-checked brute-force Hamming",
        f"matches within {EPS_PX:g} px of the true position / all matches. Time: median of one extraction",
        f"per image, the median over images. Coverage: share of {COVERAGE_CELL_PX} px cells with a keypoint.",
        "",
        "| extractor | mean repeatability | mean precision | mean correct | median ms | coverage |",
        "|---|---|---|---|---|---|",
    ]
    for ex, v in s.items():
        lines.append(
            f"| {ex} | {v['repeatability']:.3f} | {v['precision']:.3f} | {v['correct']:.0f} | {v['ms']:.2f} | "
            f"{v['coverage']:.2f} |"
        )
    lines += [
        "",
        "| image | warp | extractor | repeatability | precision | correct | matches | ms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        lines.append(
            f"| {r['image']} | {r['warp']} | {r['extractor']} | {r['repeatability']:.3f} | {r['precision']:.3f} | "
            f"{r['correct']} | {r['matches']} | {r['ms']:.2f} |"
        )
    md_path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--out", type=Path, default=REPO / "reports", help="reports folder (default: reports)")
    p.add_argument("--repeats", type=int, default=15, help="timed extractions per image and extractor")
    p.add_argument("--views", type=int, default=2, help="SAPIEN renders of scene01 (default 2)")
    p.add_argument("--no-render", action="store_true", help="photographs only (no SAPIEN)")
    a = p.parse_args(argv)
    cv2.setNumThreads(1)
    images = photographs()
    if not a.no_render and a.views > 0:
        images.update(renders(a.views))
    rows = measure(images, a.repeats)
    s = summary(rows)
    o, c = s["objslam"], s["opencv"]
    result = {
        "question": "Does the core's ORB match OpenCV's repeatability, match precision and time under known warps?",
        "headline": (
            f"repeatability {o['repeatability']:.3f} vs OpenCV {c['repeatability']:.3f}, precision "
            f"{o['precision']:.3f} vs {c['precision']:.3f}, {o['ms']:.2f} vs {c['ms']:.2f} ms"
        ),
        "commit": commit(),
        "command": shlex.join(["python", "experiments/features.py", *(sys.argv[1:] if argv is None else argv)]),
        "machine": machine(),
        "config": {
            **SETTINGS,
            "eps_px": EPS_PX,
            "margin_px": MARGIN_PX,
            "repeats": a.repeats,
            "views": 0 if a.no_render else a.views,
            "images": list(images),
            "opencv": cv2.__version__,
        },
        "summary": s,
        "rows": rows,
    }
    write_report(a.out, result)
    print(json.dumps(s, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
