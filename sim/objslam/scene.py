"""Scene files: loading, validation and a seeded generator.

A scene file (``scenes/*.toml``) describes a tabletop for the benchmark:

Task
    Map every object on the table (class, centre, size, yaw) from the hand camera.
Randomisations
    Object textures are generated from ``[scene].seed``; the run seed mixed with it drives the
    sensor noise, the detector noise, the arm's errors and any random strategy
    (``objslam.calibration.episode_rng``).
Success
    Judged by the evaluation against the ground truth in this file (3D IoU, CDE, YAE, counts).

Format::

    [scene]
    name = "scene01"
    character = "sparse: 4 objects"   # what makes this scene hard, one line
    seed = 101                          # seeds textures
    [table]
    center = [0.5, 0.0]                 # table-top centre (x, y), metres; top at z = 0
    size = [0.8, 1.2]                   # table-top extent (x, y), metres
    [[objects]]
    class = "block"                     # block | book | keyboard | cup | can | bottle | bowl | ball
    position = [0.45, 0.10]             # (x, y) of the centre, metres
    yaw_deg = 30.0                      # cuboids only
    size = [0.05, 0.05, 0.05]           # cuboids: full extents (x, y, z), metres
    # cylinders: radius = 0.035, height = 0.10 (metres)
    [[objects]]                         # a scanned mesh (objslam.meshes.ASSETS)
    class = "can"                       # its label: any class; cuboid or cylinder ground truth
    asset = "alphabet_soup"
    scale = 0.9                         # times the asset's real size
    yaw_deg = 40.0                      # the mesh's turn about z
    position = [0.45, 0.10]             # (x, y) of the ground-truth primitive's centre, metres

A mesh object's ground truth is its upright oriented bounding box (cuboid classes) or bounding
upright cylinder (cylinder classes), computed from the scaled, turned mesh vertices
(:mod:`objslam.meshes`). Footprints may touch but not interpenetrate: the validator compares the
rectangles, circles and (for meshes) the convex hulls of the projected vertices, and names the
objects and the depth when they overlap.

Objects stand on the table: their centre is at z = height / 2. World frame: robot base at the origin,
z up. Every error names the file, the field and the reason (:class:`SceneFileError`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomllib

from .meshes import ASSETS, MeshAssetError, PlacedMesh, placed_mesh

CUBOID_CLASSES = ("block", "book", "keyboard")
CYLINDER_CLASSES = ("cup", "can", "bottle", "bowl", "ball")
CLASSES = CUBOID_CLASSES + CYLINDER_CLASSES

#: Objects must lie in this reachable band in front of the robot (x range, |y| max), metres.
WORKSPACE_X = (0.2, 0.85)
WORKSPACE_ABS_Y = 0.5
#: Size limits for any object dimension, metres.
MIN_SIZE_M = 0.01
MAX_SIZE_M = 0.5
#: The Panda's fingers open to 8 cm; an object is graspable if a horizontal side is under this.
GRASPABLE_SIDE_M = 0.07
#: Longest name that becomes part of a file or folder name (scene names, strategy labels).
MAX_NAME_CHARS = 64
_SAFE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]*")


def path_name_problem(name: object) -> str | None:
    """Why ``name`` cannot be part of a file or folder name, or None when it can: a non-empty
    string of ASCII letters, digits, ``.``, ``_`` and ``-``, not starting with ``.``, at most
    :data:`MAX_NAME_CHARS` characters (so no ``/``, ``..``, spaces or control characters)."""
    if not isinstance(name, str) or not name:
        return "expected a non-empty string"
    if len(name) > MAX_NAME_CHARS:
        return f"{len(name)} characters, at most {MAX_NAME_CHARS}"
    if not _SAFE_NAME.fullmatch(name):
        return f"{name!r}: use only letters, digits, '.', '_' and '-', not starting with '.'"
    return None
#: Sides of the polygon circumscribing a cylinder's footprint in the validator (0.2 % wider than the circle).
_CIRCLE_SIDES = 48


class SceneFileError(ValueError):
    """A scene file is missing, malformed or physically invalid. The message names file and field."""

    def __init__(self, path: str | Path, field: str, reason: str) -> None:
        super().__init__(f"{path}: {field}: {reason}")
        self.path = str(path)
        self.field = field
        self.reason = reason


@dataclass(frozen=True)
class TableSpec:
    """The table top (a box whose top face is at z = 0)."""

    center: tuple[float, float]
    """Centre of the top face (x, y), metres."""
    size: tuple[float, float]
    """Extent of the top face (x, y), metres."""


@dataclass(frozen=True)
class ObjectSpec:
    """One object on the table (ground truth)."""

    id: int
    """Index in the file; the ground-truth id everywhere."""
    cls: str
    """Class label (see :data:`CLASSES`)."""
    position: tuple[float, float]
    """(x, y) of the centre, metres."""
    yaw_rad: float
    """Rotation about z (0 for cylinders)."""
    half_extents: tuple[float, float, float]
    """Half-extents (x, y, z) in the object frame; cylinders have x = y = radius."""
    mesh: PlacedMesh | None = None
    """The scanned mesh this object is, ``None`` for a primitive (box or cylinder)."""

    @property
    def shape(self) -> str:
        """``"cuboid"`` or ``"cylinder"``."""
        return "cylinder" if self.cls in CYLINDER_CLASSES else "cuboid"

    @property
    def center(self) -> tuple[float, float, float]:
        """Centre in the world at rest on the table."""
        return (self.position[0], self.position[1], self.half_extents[2])

    @property
    def graspable(self) -> bool:
        """Whether one horizontal side is under :data:`GRASPABLE_SIDE_M`."""
        return 2 * min(self.half_extents[0], self.half_extents[1]) < GRASPABLE_SIDE_M

    def footprint_polygon(self) -> np.ndarray:
        """Top-view convex footprint (K, 2) in the world: a box's rectangle, a cylinder's circle as
        a circumscribed 48-gon, a mesh's convex hull of its projected vertices."""
        if self.mesh is not None:
            local = self.mesh.footprint_local
        elif self.shape == "cylinder":
            k = np.arange(_CIRCLE_SIDES) * 2 * math.pi / _CIRCLE_SIDES
            r = self.half_extents[0] / math.cos(math.pi / _CIRCLE_SIDES)
            return np.stack([np.cos(k), np.sin(k)], axis=1) * r + np.array(self.position)
        else:
            return self.footprint()
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return local @ np.array([[c, -s], [s, c]]).T + np.array(self.position)

    def footprint(self) -> np.ndarray:
        """Top-view corners (4, 2) of the footprint (a cylinder's bounding square)."""
        hx, hy = self.half_extents[0], self.half_extents[1]
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
        rot = np.array([[c, -s], [s, c]])
        return local @ rot.T + np.array(self.position)


@dataclass(frozen=True)
class SceneSpec:
    """A validated scene."""

    name: str
    character: str
    seed: int
    table: TableSpec
    objects: tuple[ObjectSpec, ...]
    path: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


def _number(path: Path, fld: str, v: Any, lo: float | None = None, hi: float | None = None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SceneFileError(path, fld, f"expected a number, got {type(v).__name__} {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise SceneFileError(path, fld, f"must be finite, got {v!r}")
    if lo is not None and x < lo:
        raise SceneFileError(path, fld, f"must be ≥ {lo}, got {x}")
    if hi is not None and x > hi:
        raise SceneFileError(path, fld, f"must be ≤ {hi}, got {x}")
    return x


def _vector(path: Path, fld: str, v: Any, n: int, lo: float | None = None, hi: float | None = None) -> tuple:
    if not isinstance(v, list) or len(v) != n:
        raise SceneFileError(path, fld, f"expected a list of {n} numbers, got {v!r}")
    return tuple(_number(path, f"{fld}[{i}]", x, lo, hi) for i, x in enumerate(v))


def _table(path: Path, t: Any) -> TableSpec:
    if not isinstance(t, dict):
        raise SceneFileError(path, "table", "missing [table] section")
    unknown = set(t) - {"center", "size"}
    if unknown:
        raise SceneFileError(path, "table", f"unknown keys {sorted(unknown)}")
    center = _vector(path, "table.center", t.get("center"), 2)
    size = _vector(path, "table.size", t.get("size"), 2, 0.2, 3.0)
    return TableSpec(center=center, size=size)


def _object(path: Path, i: int, o: Any, table: TableSpec) -> ObjectSpec:
    pre = f"objects[{i}]"
    if not isinstance(o, dict):
        raise SceneFileError(path, pre, "expected a table")
    cls = o.get("class")
    if cls not in CLASSES:
        raise SceneFileError(path, f"{pre}.class", f"unknown class {cls!r}; known: {', '.join(CLASSES)}")
    if "asset" in o:
        spec = _mesh_object(path, i, o, cls)
    else:
        spec = _primitive_object(path, i, o, cls)
    _check_on_table(path, pre, spec, table)
    return spec


def _primitive_object(path: Path, i: int, o: dict[str, Any], cls: str) -> ObjectSpec:
    pre = f"objects[{i}]"
    if cls in CUBOID_CLASSES:
        allowed = {"class", "position", "yaw_deg", "size"}
        size = _vector(path, f"{pre}.size", o.get("size"), 3, MIN_SIZE_M, MAX_SIZE_M)
        half = (size[0] / 2, size[1] / 2, size[2] / 2)
        yaw = math.radians(_number(path, f"{pre}.yaw_deg", o.get("yaw_deg", 0.0), -360, 360))
    else:
        allowed = {"class", "position", "radius", "height", "yaw_deg"}
        if "size" in o:
            raise SceneFileError(path, f"{pre}.size", f"a {cls} is a cylinder: give radius and height")
        r = _number(path, f"{pre}.radius", o.get("radius"), MIN_SIZE_M / 2, MAX_SIZE_M / 2)
        h = _number(path, f"{pre}.height", o.get("height"), MIN_SIZE_M, MAX_SIZE_M)
        half = (r, r, h / 2)
        yaw = 0.0
    unknown = set(o) - allowed
    if unknown:
        raise SceneFileError(path, pre, f"unknown keys {sorted(unknown)}")
    pos = _position(path, pre, o)
    return ObjectSpec(id=i, cls=cls, position=pos, yaw_rad=yaw, half_extents=half)


def _position(path: Path, pre: str, o: dict[str, Any]) -> tuple[float, float]:
    pos = _vector(path, f"{pre}.position", o.get("position"), 2)
    if not (WORKSPACE_X[0] <= pos[0] <= WORKSPACE_X[1] and abs(pos[1]) <= WORKSPACE_ABS_Y):
        raise SceneFileError(
            path, f"{pre}.position", f"{pos} outside the workspace x∈{WORKSPACE_X}, |y|≤{WORKSPACE_ABS_Y}"
        )
    return pos  # type: ignore[return-value]


#: Scales a scene may give a mesh (times the asset's real size).
MESH_SCALE_RANGE = (0.2, 3.0)


def _mesh_object(path: Path, i: int, o: dict[str, Any], cls: str) -> ObjectSpec:
    """A scanned-mesh object: ``asset``, ``scale``, ``yaw_deg``, ``position`` (the ground-truth
    primitive's centre); its ground truth from :func:`objslam.meshes.placed_mesh`."""
    pre = f"objects[{i}]"
    unknown = set(o) - {"class", "asset", "scale", "yaw_deg", "position"}
    if unknown:
        raise SceneFileError(path, pre, f"unknown keys {sorted(unknown)} (a mesh object has class, asset, "
                             "scale, yaw_deg, position)")
    name = o.get("asset")
    if not isinstance(name, str) or name not in ASSETS:
        raise SceneFileError(path, f"{pre}.asset", f"unknown asset {name!r}; known: {', '.join(sorted(ASSETS))}")
    scale = _number(path, f"{pre}.scale", o.get("scale", 1.0), *MESH_SCALE_RANGE)
    yaw = math.radians(_number(path, f"{pre}.yaw_deg", o.get("yaw_deg", 0.0), -360, 360))
    pos = _position(path, pre, o)
    shape = "cylinder" if cls in CYLINDER_CLASSES else "cuboid"
    try:
        m = placed_mesh(name, scale=scale, mesh_yaw_rad=yaw, shape=shape)
    except (MeshAssetError, OSError) as e:
        raise SceneFileError(path, f"{pre}.asset", str(e)) from e
    for k, h in enumerate(m.half_extents):
        if not MIN_SIZE_M / 2 <= h <= MAX_SIZE_M / 2:
            raise SceneFileError(path, f"{pre}.scale", f"gives a {2 * h:.3f} m extent along axis {k}, outside "
                                 f"[{MIN_SIZE_M}, {MAX_SIZE_M}] m")
    return ObjectSpec(id=i, cls=cls, position=pos, yaw_rad=m.box_yaw_rad, half_extents=m.half_extents, mesh=m)


def _check_on_table(path: Path, pre: str, spec: ObjectSpec, table: TableSpec) -> None:
    fp = spec.footprint_polygon()
    tx0, ty0 = table.center[0] - table.size[0] / 2, table.center[1] - table.size[1] / 2
    tx1, ty1 = table.center[0] + table.size[0] / 2, table.center[1] + table.size[1] / 2
    if fp[:, 0].min() < tx0 or fp[:, 0].max() > tx1 or fp[:, 1].min() < ty0 or fp[:, 1].max() > ty1:
        raise SceneFileError(path, f"{pre}.position", "object footprint hangs over the table edge")


def _overlap(a: ObjectSpec, b: ObjectSpec) -> bool:
    """Separating-axis test of two footprints (cylinders use their bounding squares; a circle test
    when both are cylinders)."""
    if a.shape == "cylinder" and b.shape == "cylinder":
        d = math.dist(a.position, b.position)
        return d < a.half_extents[0] + b.half_extents[0]
    pa, pb = a.footprint(), b.footprint()
    for poly in (pa, pb):
        for k in range(4):
            e = poly[(k + 1) % 4] - poly[k]
            axis = np.array([-e[1], e[0]])
            ra, rb = pa @ axis, pb @ axis
            if ra.max() <= rb.min() or rb.max() <= ra.min():
                return False
    return True


#: Footprints may overlap by this much (float noise of touching shapes), metres.
TOUCH_TOLERANCE_M = 1e-5


def _describe(o: ObjectSpec) -> str:
    return f"objects[{o.id}] ({o.cls}" + (f", asset {o.mesh.asset})" if o.mesh is not None else ")")


def _check_no_interpenetration(path: Path, objects: tuple[ObjectSpec, ...]) -> None:
    """Footprints may touch, not overlap; the error names both objects and the overlap depth."""
    polys = [o.footprint_polygon() for o in objects]
    for i, a in enumerate(objects):
        for j in range(i + 1, len(objects)):
            depth = polygon_penetration_m(polys[i], polys[j])
            if depth > TOUCH_TOLERANCE_M:
                b = objects[j]
                raise SceneFileError(
                    path,
                    f"objects[{b.id}].position",
                    f"{_describe(b)} overlaps {_describe(a)}: their footprints interpenetrate by "
                    f"{depth * 1000:.1f} mm (objects may touch, not overlap)",
                )


def _axes(poly: np.ndarray) -> np.ndarray:
    e = np.roll(poly, -1, axis=0) - poly
    n = np.stack([-e[:, 1], e[:, 0]], axis=1)
    norm = np.linalg.norm(n, axis=1)
    return n[norm > 1e-12] / norm[norm > 1e-12, None]


def polygon_penetration_m(p: np.ndarray, q: np.ndarray) -> float:
    """Overlap depth of two convex polygons (K, 2) by the separating-axis test over both edge
    normals: > 0 is the smallest push that separates them, ≤ 0 means they do not overlap."""
    axes = np.concatenate([_axes(p), _axes(q)])
    pp, qq = p @ axes.T, q @ axes.T
    overlap = np.minimum(pp.max(axis=0) - qq.min(axis=0), qq.max(axis=0) - pp.min(axis=0))
    return float(overlap.min())


def _point_segment_distances(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of every point (N, 2) to every segment a[k]→b[k] (K, 2): (N, K)."""
    d = b - a
    t = np.clip(((pts[:, None, :] - a[None]) * d[None]).sum(-1) / np.maximum((d * d).sum(-1), 1e-18), 0.0, 1.0)
    closest = a[None] + t[..., None] * d[None]
    return np.linalg.norm(pts[:, None, :] - closest, axis=-1)


def polygon_gap_m(p: np.ndarray, q: np.ndarray) -> float:
    """Distance between two convex polygons (K, 2), metres; negative (minus the overlap depth)
    when they overlap."""
    depth = polygon_penetration_m(p, q)
    if depth > 0:
        return -depth
    dpq = _point_segment_distances(p, q, np.roll(q, -1, axis=0)).min()
    dqp = _point_segment_distances(q, p, np.roll(p, -1, axis=0)).min()
    return float(min(dpq, dqp))


def footprint_gap_m(a: ObjectSpec, b: ObjectSpec) -> float:
    """Gap between two objects' footprints (:meth:`ObjectSpec.footprint_polygon`), metres; negative
    when they interpenetrate."""
    return polygon_gap_m(a.footprint_polygon(), b.footprint_polygon())


def parse_scene(data: dict[str, Any], path: str | Path = "<memory>") -> SceneSpec:
    """Validate a parsed scene document."""
    path = Path(path)
    s = data.get("scene")
    if not isinstance(s, dict):
        raise SceneFileError(path, "scene", "missing [scene] section")
    name = s.get("name")
    problem = path_name_problem(name)
    if problem is not None:
        raise SceneFileError(path, "scene.name", f"{problem} (the name becomes part of the run folder's name)")
    character = s.get("character", "")
    if not isinstance(character, str):
        raise SceneFileError(path, "scene.character", "expected a string")
    seed = s.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SceneFileError(path, "scene.seed", f"expected a non-negative integer, got {seed!r}")
    table = _table(path, data.get("table"))
    objs = data.get("objects")
    if not isinstance(objs, list) or not objs:
        raise SceneFileError(path, "objects", "a scene needs at least one [[objects]] entry")
    objects = tuple(_object(path, i, o, table) for i, o in enumerate(objs))
    _check_no_interpenetration(path, objects)
    unknown = set(data) - {"scene", "table", "objects"}
    if unknown:
        raise SceneFileError(path, "<top level>", f"unknown sections {sorted(unknown)}")
    return SceneSpec(name=name, character=character, seed=seed, table=table, objects=objects, path=str(path))


def load_scene(path: str | Path) -> SceneSpec:
    """Load and validate a scene file."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as e:
        raise SceneFileError(path, "<file>", f"cannot read: {e.strerror}") from e
    except UnicodeDecodeError as e:
        raise SceneFileError(path, "<file>", f"not UTF-8 text (byte {e.start}: {e.reason})") from e
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneFileError(path, "<toml>", str(e)) from e
    return parse_scene(data, path)


#: Folders (relative to the repository) holding scene files: the seven benchmark scenes, the hard
#: suite (tuning) and the test split (reporting only).
SCENE_DIRS = ("scenes", "scenes/hard", "scenes/test")


def scene_file(name: str, repo: str | Path) -> Path:
    """The scene file named ``name`` (its stem, e.g. ``"hard01"``) in :data:`SCENE_DIRS` under
    ``repo``, as a path relative to ``repo``. Raises :class:`SceneFileError` if none exists."""
    for d in SCENE_DIRS:
        rel = Path(d) / f"{name}.toml"
        if (Path(repo) / rel).is_file():
            return rel
    raise SceneFileError(f"{name}.toml", "<file>", f"no scene named {name!r} in {', '.join(SCENE_DIRS)}")


def scene_to_toml(spec: SceneSpec, *, position_decimals: int = 3) -> str:
    """Serialise a scene in the file format (inverse of :func:`load_scene`); primitives' positions
    with ``position_decimals`` decimals (metres), meshes' with 4."""
    lines = [
        "[scene]",
        f'name = "{spec.name}"',
        f'character = "{spec.character}"',
        f"seed = {spec.seed}",
        "",
        "[table]",
        f"center = [{spec.table.center[0]:.3f}, {spec.table.center[1]:.3f}]",
        f"size = [{spec.table.size[0]:.3f}, {spec.table.size[1]:.3f}]",
    ]
    for o in spec.objects:
        if o.mesh is not None:
            lines += ["", "[[objects]]", *_mesh_toml_lines(o)]
            continue
        lines += ["", "[[objects]]", f'class = "{o.cls}"', f"position = [{o.position[0]:.{position_decimals}f}, {o.position[1]:.{position_decimals}f}]"]
        if o.shape == "cuboid":
            lines.append(f"yaw_deg = {math.degrees(o.yaw_rad):.1f}")
            lines.append("size = [" + ", ".join(f"{2 * h:.3f}" for h in o.half_extents) + "]")
        else:
            lines.append(f"radius = {o.half_extents[0]:.3f}")
            lines.append(f"height = {2 * o.half_extents[2]:.3f}")
    return "\n".join(lines) + "\n"


def _mesh_toml_lines(o: ObjectSpec) -> list[str]:
    """A mesh object's file lines (positions to 0.1 mm: near-touching layouts need it)."""
    assert o.mesh is not None
    return [
        f'class = "{o.cls}"',
        f'asset = "{o.mesh.asset}"',
        f"scale = {o.mesh.scale:.4f}",
        f"yaw_deg = {math.degrees(o.mesh.mesh_yaw_rad):.2f}",
        f"position = [{o.position[0]:.4f}, {o.position[1]:.4f}]",
    ]


#: Size ranges (metres) per class used by the generator: cuboids (x, y, z) ranges; cylinders (r, h).
CLASS_SIZES: dict[str, tuple[tuple[float, float], ...]] = {
    "block": ((0.04, 0.06), (0.04, 0.06), (0.04, 0.07)),
    "book": ((0.13, 0.18), (0.05, 0.065), (0.025, 0.04)),
    "keyboard": ((0.30, 0.36), (0.10, 0.12), (0.02, 0.03)),
    "cup": ((0.03, 0.045), (0.08, 0.11)),
    "can": ((0.028, 0.034), (0.10, 0.12)),
    "bottle": ((0.025, 0.033), (0.16, 0.22)),
    "bowl": ((0.06, 0.08), (0.05, 0.07)),
    "ball": ((0.03, 0.04), (0.06, 0.08)),
}


def generate_scene(
    *,
    seed: int,
    n_objects: int,
    name: str,
    character: str = "generated",
    classes: tuple[str, ...] = ("block", "book", "cup", "can", "bottle"),
    region: tuple[float, float, float, float] = (0.35, 0.68, -0.3, 0.3),
    min_gap_m: float = 0.03,
    max_tries: int = 5000,
) -> SceneSpec:
    """A random valid scene: ``n_objects`` of ``classes`` placed without overlap (gap ≥ ``min_gap_m``)
    in ``region`` = (x0, x1, y0, y1). Deterministic for a seed; raises ``ValueError`` if the objects
    do not fit after ``max_tries`` placements."""
    for c in classes:
        if c not in CLASSES:
            raise ValueError(f"classes: unknown class {c!r}")
    if n_objects < 1:
        raise ValueError("n_objects: must be ≥ 1")
    rng = np.random.default_rng(seed)
    table = TableSpec(center=(0.5, 0.0), size=(0.8, 1.2))
    placed: list[ObjectSpec] = []
    tries = 0
    while len(placed) < n_objects:
        tries += 1
        if tries > max_tries:
            raise ValueError(f"could not place {n_objects} objects in {region} (placed {len(placed)})")
        cls = classes[int(rng.integers(len(classes)))]
        ranges = CLASS_SIZES[cls]
        if cls in CUBOID_CLASSES:
            size = [float(rng.uniform(*r)) for r in ranges]
            half = (size[0] / 2, size[1] / 2, size[2] / 2)
            yaw = float(rng.uniform(-math.pi / 2, math.pi / 2))
        else:
            r, h = float(rng.uniform(*ranges[0])), float(rng.uniform(*ranges[1]))
            half, yaw = (r, r, h / 2), 0.0
        pos = (float(rng.uniform(region[0], region[1])), float(rng.uniform(region[2], region[3])))
        cand = ObjectSpec(id=len(placed), cls=cls, position=pos, yaw_rad=yaw, half_extents=half)
        grown = ObjectSpec(
            id=-1, cls=cls, position=pos, yaw_rad=yaw, half_extents=(half[0] + min_gap_m / 2, half[1] + min_gap_m / 2, half[2])
        )
        ok = all(
            not _overlap(
                grown,
                ObjectSpec(
                    id=-1,
                    cls=p.cls,
                    position=p.position,
                    yaw_rad=p.yaw_rad,
                    half_extents=(p.half_extents[0] + min_gap_m / 2, p.half_extents[1] + min_gap_m / 2, 0),
                ),
            )
            for p in placed
        )
        if ok:
            placed.append(cand)
    spec = SceneSpec(name=name, character=character, seed=seed, table=table, objects=tuple(placed))
    # Round-trip through the file format so generated scenes are exactly what a file would give.
    return parse_scene(tomllib.loads(scene_to_toml(spec)), f"<generated {name}>")


def gt_objects(spec: SceneSpec, poses: dict[int, tuple[np.ndarray, float]] | None = None) -> list[dict[str, Any]]:
    """Ground truth in the core's ``GtObject`` JSON layout. ``poses`` optionally overrides an object's
    (centre, yaw) with the simulator's current pose."""
    out = []
    for o in spec.objects:
        center, yaw = (np.array(o.center), o.yaw_rad) if poses is None or o.id not in poses else poses[o.id]
        out.append(
            {
                "id": o.id,
                "label": o.cls,
                "geometry": {
                    "shape": o.shape,
                    "center": [float(c) for c in center],
                    "yaw_rad": float(yaw) if o.shape == "cuboid" else 0.0,
                    "half_extents": list(o.half_extents),
                },
            }
        )
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m objslam.scene --seed S --n N --name NAME [--out FILE]``: write a generated scene
    (``--hard``: a hard cluttered scene, :mod:`objslam.clutter`)."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m objslam.scene", description="Generate a random valid scene file.")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--name", required=True)
    ap.add_argument("--character", default="generated")
    ap.add_argument("--classes", default="block,book,cup,can,bottle", help="comma-separated class list")
    ap.add_argument("--region", default="0.35,0.68,-0.3,0.3", help="x0,x1,y0,y1 in metres")
    ap.add_argument("--min-gap", type=float, default=0.03, help="minimum gap between footprints, metres")
    ap.add_argument("--out", help="output file (default: stdout)")
    ap.add_argument(
        "--hard",
        action="store_true",
        help="a hard cluttered scene of meshes and primitives (objslam.clutter; uses --seed, --name, --out, "
        "--n-range, --mesh-fraction)",
    )
    ap.add_argument("--n-range", default="14,18", help="with --hard: object count range lo,hi")
    ap.add_argument("--mesh-fraction", type=float, default=0.5, help="with --hard: least fraction of meshes")
    ap.add_argument("--n", type=int, help="number of objects (not with --hard)")
    a = ap.parse_args(argv)
    if a.hard:
        return _main_hard(a)
    if a.n is None:
        ap.error("--n is required without --hard")
    region = tuple(float(v) for v in a.region.split(","))
    if len(region) != 4:
        ap.error("--region needs four numbers")
    spec = generate_scene(
        seed=a.seed,
        n_objects=a.n,
        name=a.name,
        character=a.character,
        classes=tuple(a.classes.split(",")),
        region=region,  # type: ignore[arg-type]
        min_gap_m=a.min_gap,
    )
    text = scene_to_toml(spec)
    if a.out:
        Path(a.out).write_text(text)
    else:
        print(text, end="")
    return 0


def _main_hard(a: Any) -> int:
    """``--hard``: write :func:`objslam.clutter.generate_hard_scene`'s scene."""
    from .clutter import ClutterConfig, generate_hard_scene

    lo, hi = (int(v) for v in a.n_range.split(","))
    spec = generate_hard_scene(
        seed=a.seed, name=a.name, config=ClutterConfig(n_objects=(lo, hi), mesh_fraction=a.mesh_fraction)
    )
    text = scene_to_toml(spec, position_decimals=4)
    if a.out:
        Path(a.out).write_text(text)
    else:
        print(text, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
