"""The hard-scene generator: cluttered tables of scanned meshes and primitives, built from seeds.

Task
    As every scene: map every object (class, centre, size, yaw) from the hand camera.
Randomisations
    Everything below is drawn from the scene's seed (``numpy.random.default_rng(seed)``); the same
    seed and :class:`ClutterConfig` give the same file.
Success
    Judged against the file's ground truth (for meshes, their bounding primitives: see
    :mod:`objslam.meshes`).

A scene is assembled from motifs, each a group of objects placed relative to each other, then
filled with single objects:

- occluders: a tall object (bottle, carton, standing book) with a short one (butter, popcorn box,
  small block) just behind it, on the side away from the table centre, where the Init views
  (over the table's middle) look past the tall one;
- same-label pairs: two objects of one label (twin meshes or equal primitives) 2-5 mm apart;
- rows of look-alikes: three or four identical objects in a line, 2-5 mm between neighbours;
- reach-limit objects: graspable objects 0.72-0.78 m from the robot base;
- singles, at least :attr:`ClutterConfig.min_gap_m` from everything else.

At least :attr:`ClutterConfig.mesh_fraction` of the objects are meshes. Positions are rounded to
0.1 mm and yaws to 0.01° before any check, so the written file validates exactly as generated.
Entry point: :func:`generate_hard_scene` (CLI: ``python -m objslam.scene --hard``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import tomllib

from .meshes import ASSETS, placed_mesh
from .scene import (
    CLASS_SIZES,
    CUBOID_CLASSES,
    ObjectSpec,
    SceneFileError,
    SceneSpec,
    TableSpec,
    _check_on_table,
    footprint_gap_m,
    parse_scene,
    scene_to_toml,
)


@dataclass(frozen=True)
class ClutterConfig:
    """Settings of :func:`generate_hard_scene` (lengths in metres)."""

    n_objects: tuple[int, int] = (14, 18)
    """Object count, drawn uniformly from this inclusive range (at least the motifs' count:
    2 per occluder and pair, the longest row, the reach-limit objects)."""
    mesh_fraction: float = 0.5
    """At least this fraction of the objects are scanned meshes."""
    region: tuple[float, float, float, float] = (0.32, 0.70, -0.34, 0.34)
    """(x0, x1, y0, y1) where motif anchors and singles are placed."""
    reach_radius_m: tuple[float, float] = (0.72, 0.78)
    """Distance from the robot base of the reach-limit objects."""
    n_reach: int = 2
    """Reach-limit objects."""
    n_occluders: int = 2
    """Tall objects each hiding a short one."""
    occluder_gap_m: tuple[float, float] = (0.004, 0.015)
    """Gap between a tall object and the short one behind it."""
    n_pairs: int = 2
    """Same-label pairs."""
    n_rows: int = 1
    """Rows of look-alikes."""
    row_length: tuple[int, int] = (3, 4)
    """Objects per row, inclusive range."""
    near_gap_m: tuple[float, float] = (0.002, 0.005)
    """Gap within a same-label pair and between neighbours of a row."""
    min_gap_m: float = 0.012
    """Smallest gap between objects of different motifs."""
    max_tries: int = 400
    """Placement attempts per object before the scene is drawn again."""


#: Tall objects that hide short ones (asset names; ``"bottle"`` is a primitive bottle).
_TALL = ("wine_bottle", "white_bottle", "orange_juice", "yellow_milk", "yellow_book", "ketchup", "bottle")
#: Short objects hidden behind tall ones (``"block"``: a primitive block at most 5 cm high).
_SHORT = ("butter", "green_butter", "popcorn", "block")
#: Same-label pairs.
_PAIRS = (
    ("alphabet_soup", "alphabet_soup"),
    ("butter", "green_butter"),
    ("orange_juice", "yellow_milk"),
    ("ketchup", "ketchup"),
    ("red_mug", "red_mug"),
    ("wine_bottle", "white_bottle"),
    ("can", "can"),
    ("block", "block"),
)
#: Rows of look-alikes (members cycle through the tuple; all share one scale).
_ROWS = (("alphabet_soup",), ("butter", "green_butter"), ("orange_juice", "yellow_milk"), ("can",))
#: Graspable objects placed at the reach limit.
_REACH = ("alphabet_soup", "ketchup", "butter", "red_mug", "can", "block")
#: Singles.
_SINGLE_MESHES = tuple(sorted(ASSETS))
_SINGLE_PRIMITIVES = ("block", "book", "cup", "can", "bottle")
#: The table every hard scene uses (as the benchmark scenes).
_TABLE = TableSpec(center=(0.5, 0.0), size=(0.8, 1.2))


class _Retry(Exception):
    """A motif did not fit: draw the scene again."""


def _make(
    rng: np.random.Generator,
    kind: str,
    *,
    scale: float | None = None,
    yaw_deg: float | None = None,
    sizes: tuple[float, ...] | None = None,
    short: bool = False,
) -> ObjectSpec:
    """An object of ``kind`` (an asset name or a primitive class) at the origin."""
    if yaw_deg is None:
        yaw_deg = round(float(rng.uniform(-180.0, 180.0)), 2)
    if kind in ASSETS:
        a = ASSETS[kind]
        s = scale if scale is not None else round(float(rng.uniform(*a.scale_range)), 4)
        shape = "cuboid" if a.label in CUBOID_CLASSES else "cylinder"
        m = placed_mesh(kind, scale=s, mesh_yaw_rad=math.radians(yaw_deg), shape=shape)
        return ObjectSpec(
            id=-1,
            cls=a.label,
            position=(0.0, 0.0),
            yaw_rad=m.box_yaw_rad,
            half_extents=m.half_extents,
            mesh=m,
        )
    ranges = CLASS_SIZES[kind]
    if sizes is None:
        sizes = tuple(round(float(rng.uniform(*r)), 3) for r in ranges)
        if short and kind in CUBOID_CLASSES:
            sizes = (*sizes[:2], min(sizes[2], 0.05))
    if kind in CUBOID_CLASSES:
        yaw = math.radians(round(yaw_deg, 1))
        return ObjectSpec(
            id=-1,
            cls=kind,
            position=(0.0, 0.0),
            yaw_rad=yaw,
            half_extents=(sizes[0] / 2, sizes[1] / 2, sizes[2] / 2),
        )
    r, h = sizes
    return ObjectSpec(id=-1, cls=kind, position=(0.0, 0.0), yaw_rad=0.0, half_extents=(r, r, h / 2))


def _sizes(o: ObjectSpec) -> tuple[float, ...]:
    h = o.half_extents
    return (2 * h[0], 2 * h[1], 2 * h[2]) if o.cls in CUBOID_CLASSES else (h[0], 2 * h[2])


def _twin(rng: np.random.Generator, kind: str, like: ObjectSpec) -> ObjectSpec:
    """An object of ``kind`` the size of ``like`` (same scale, or the same primitive sizes)."""
    if like.mesh is not None and kind in ASSETS:
        return _make(rng, kind, scale=like.mesh.scale)
    return _make(rng, kind, sizes=_sizes(like) if like.mesh is None and kind == like.cls else None)


def _at(o: ObjectSpec, xy: np.ndarray) -> ObjectSpec:
    return dataclasses.replace(o, position=(round(float(xy[0]), 4), round(float(xy[1]), 4)))


def _next_to(anchor: ObjectSpec, o: ObjectSpec, direction: np.ndarray, gap_m: float) -> ObjectSpec:
    """``o`` moved from ``anchor``'s centre along ``direction`` until their footprints are ``gap_m``
    apart (bisection on the distance)."""
    d = direction / np.linalg.norm(direction)
    p0 = np.asarray(anchor.position)
    lo, hi = 0.0, 0.6
    for _ in range(40):
        mid = (lo + hi) / 2
        if footprint_gap_m(anchor, _at(o, p0 + mid * d)) < gap_m:
            lo = mid
        else:
            hi = mid
    return _at(o, p0 + hi * d)


class _Layout:
    """Objects placed so far, with their motif group."""

    def __init__(self, cfg: ClutterConfig) -> None:
        self.cfg = cfg
        self.objects: list[ObjectSpec] = []
        self.groups: list[int] = []

    def fits(self, o: ObjectSpec, group: int, exempt: tuple[int, ...] = ()) -> bool:
        """On the table, in the workspace, clear of other motifs by ``min_gap_m`` and of its own by
        1.5 mm (objects listed in ``exempt`` are checked by the caller)."""
        try:
            _check_on_table("<generator>", "object", o, _TABLE)
        except SceneFileError:
            return False
        x, y = o.position
        if not (0.2 <= x <= 0.85 and abs(y) <= 0.5):
            return False
        r = _radius(o)
        for k, (p, g) in enumerate(zip(self.objects, self.groups)):
            if k in exempt:
                continue
            need = 0.0015 if g == group else self.cfg.min_gap_m
            if math.dist(o.position, p.position) > r + _radius(p) + need:
                continue  # bounding circles already clear
            if footprint_gap_m(o, p) < need:
                return False
        return True

    def add(self, o: ObjectSpec, group: int) -> int:
        self.objects.append(dataclasses.replace(o, id=len(self.objects)))
        self.groups.append(group)
        return len(self.objects) - 1

    def random_xy(self, rng: np.random.Generator) -> np.ndarray:
        r = self.cfg.region
        return np.array([rng.uniform(r[0], r[1]), rng.uniform(r[2], r[3])])


def _radius(o: ObjectSpec) -> float:
    """Radius of a circle about the object's position holding its footprint."""
    return float(np.linalg.norm(o.footprint_polygon() - np.asarray(o.position), axis=1).max())


def _unit(rng: np.random.Generator) -> np.ndarray:
    a = rng.uniform(-math.pi, math.pi)
    return np.array([math.cos(a), math.sin(a)])


def _place_anchor(lay: _Layout, rng: np.random.Generator, o: ObjectSpec, group: int, xy=None) -> ObjectSpec:
    for _ in range(lay.cfg.max_tries):
        cand = _at(o, lay.random_xy(rng) if xy is None else xy(rng))
        if lay.fits(cand, group):
            return cand
    raise _Retry


def _place_near(
    lay: _Layout,
    rng: np.random.Generator,
    anchor_id: int,
    o: ObjectSpec,
    group: int,
    gap: tuple[float, float],
    direction=None,
) -> ObjectSpec:
    anchor = lay.objects[anchor_id]
    for _ in range(lay.cfg.max_tries // 10):
        d = _unit(rng) if direction is None else direction(rng)
        want = float(rng.uniform(*gap))
        cand = _next_to(anchor, o, d, want)
        g = footprint_gap_m(anchor, cand)
        if gap[0] - 5e-4 <= g <= gap[1] + 5e-4 and lay.fits(cand, group, exempt=(anchor_id,)):
            return cand
    raise _Retry


def _occluder(lay: _Layout, rng: np.random.Generator, group: int, tall_kind: str) -> list[str]:
    tall = _make(rng, tall_kind)
    t = lay.add(_place_anchor(lay, rng, tall, group), group)
    short = _make(rng, _SHORT[int(rng.integers(len(_SHORT)))], short=True)
    out = np.asarray(lay.objects[t].position) - np.asarray(_TABLE.center)

    def behind(r: np.random.Generator) -> np.ndarray:
        a = math.atan2(out[1], out[0]) + r.uniform(-0.4, 0.4)
        return np.array([math.cos(a), math.sin(a)])

    lay.add(_place_near(lay, rng, t, short, group, lay.cfg.occluder_gap_m, behind), group)
    return [_name(lay.objects[t]), _name(lay.objects[-1])]


def _pair(lay: _Layout, rng: np.random.Generator, group: int, kinds: tuple[str, str]) -> str:
    ka, kb = kinds
    a = _make(rng, ka)
    ia = lay.add(_place_anchor(lay, rng, a, group), group)
    b = _twin(rng, kb, a)
    lay.add(_place_near(lay, rng, ia, b, group, lay.cfg.near_gap_m), group)
    return f"{_name(lay.objects[ia])} + {_name(lay.objects[-1])}"


def _row(lay: _Layout, rng: np.random.Generator, group: int) -> str:
    kinds = _ROWS[int(rng.integers(len(_ROWS)))]
    n = int(rng.integers(lay.cfg.row_length[0], lay.cfg.row_length[1] + 1))
    first = _make(rng, kinds[0])
    yaw = round(float(rng.uniform(-180.0, 180.0)), 2)
    if first.mesh is not None:
        first = _make(rng, kinds[0], scale=first.mesh.scale, yaw_deg=yaw)
    prev = lay.add(_place_anchor(lay, rng, first, group), group)
    axis = _unit(rng)
    for k in range(1, n):
        kind = kinds[k % len(kinds)]
        like = lay.objects[prev]
        o = (
            _make(rng, kind, scale=like.mesh.scale, yaw_deg=yaw)
            if like.mesh is not None
            else _make(rng, kind, sizes=_sizes(like), yaw_deg=yaw)
        )

        def along(r: np.random.Generator) -> np.ndarray:
            return axis + r.normal(0.0, 0.05, 2)

        prev = lay.add(_place_near(lay, rng, prev, o, group, lay.cfg.near_gap_m, along), group)
    return f"a row of {n} {'/'.join(kinds)}"


def _reach(lay: _Layout, rng: np.random.Generator, group: int) -> str:
    o = _make(rng, _REACH[int(rng.integers(len(_REACH)))])

    def on_arc(r: np.random.Generator) -> np.ndarray:
        rad, a = r.uniform(*lay.cfg.reach_radius_m), r.uniform(-0.6, 0.6)
        return np.array([rad * math.cos(a), rad * math.sin(a)])

    i = lay.add(_place_anchor(lay, rng, o, group, on_arc), group)
    return _name(lay.objects[i])


def _name(o: ObjectSpec) -> str:
    return o.mesh.asset if o.mesh is not None else o.cls


def _draw(rng: np.random.Generator, cfg: ClutterConfig, n: int) -> tuple[list[ObjectSpec], str]:
    lay = _Layout(cfg)
    group = 0
    occl, pairs, rows, reach = [], [], [], []
    for k in rng.choice(len(_TALL), size=cfg.n_occluders, replace=False):
        occl.append(_occluder(lay, rng, group, _TALL[int(k)]))
        group += 1
    for k in rng.choice(len(_PAIRS), size=cfg.n_pairs, replace=False):
        pairs.append(_pair(lay, rng, group, _PAIRS[int(k)]))
        group += 1
    for _ in range(cfg.n_rows):
        rows.append(_row(lay, rng, group))
        group += 1
    for _ in range(cfg.n_reach):
        reach.append(_reach(lay, rng, group))
        group += 1
    if len(lay.objects) > n:
        raise _Retry
    need_meshes = math.ceil(cfg.mesh_fraction * n)
    while len(lay.objects) < n:
        n_mesh = sum(o.mesh is not None for o in lay.objects)
        left = n - len(lay.objects)
        use_mesh = n_mesh + left <= need_meshes or rng.random() < 0.5
        pool = _SINGLE_MESHES if use_mesh else _SINGLE_PRIMITIVES
        lay.add(_place_anchor(lay, rng, _make(rng, pool[int(rng.integers(len(pool)))]), group), group)
        group += 1
    n_mesh = sum(o.mesh is not None for o in lay.objects)
    if n_mesh < need_meshes:
        raise _Retry
    character = (
        f"hard: {n} objects ({n_mesh} meshes); tall hiding short: {'; '.join(' > '.join(p) for p in occl)}; "
        f"same-label pairs 2-5 mm apart: {'; '.join(pairs)}; {'; '.join(rows)}; at the reach limit: {', '.join(reach)}"
    )
    return lay.objects, character


def generate_hard_scene(
    *, seed: int, name: str, config: ClutterConfig | None = None, max_draws: int = 200
) -> SceneSpec:
    """A hard scene (see the module doc) from ``seed``, validated by :func:`objslam.scene.parse_scene`
    after a round trip through the file format. Raises ``ValueError`` if no layout fits in
    ``max_draws`` draws."""
    cfg = config or ClutterConfig()
    if not 0.0 <= cfg.mesh_fraction <= 1.0:
        raise ValueError(f"mesh_fraction: must be in [0, 1], got {cfg.mesh_fraction}")
    motifs = 2 * cfg.n_occluders + 2 * cfg.n_pairs + cfg.n_rows * cfg.row_length[1] + cfg.n_reach
    if cfg.n_objects[0] < motifs or cfg.n_objects[1] < cfg.n_objects[0]:
        raise ValueError(f"n_objects: need {motifs} (the motifs' objects) ≤ lo ≤ hi, got {cfg.n_objects}")
    if cfg.n_occluders > len(_TALL) or cfg.n_pairs > len(_PAIRS):
        raise ValueError(f"n_occluders ≤ {len(_TALL)} and n_pairs ≤ {len(_PAIRS)} (each motif kind once)")
    rng = np.random.default_rng(seed)
    n = int(rng.integers(cfg.n_objects[0], cfg.n_objects[1] + 1))
    for _ in range(max_draws):
        try:
            objects, character = _draw(rng, cfg, n)
        except _Retry:
            continue
        spec = SceneSpec(name=name, character=character, seed=seed, table=_TABLE, objects=tuple(objects))
        return parse_scene(tomllib.loads(scene_to_toml(spec, position_decimals=4)), f"<generated {name}>")
    raise ValueError(f"seed {seed}: no layout of {n} objects fits after {max_draws} draws")
