"""View-selection strategies written in Python, run by the same episode loop as the built-in ones.

The benchmark's users compare their own strategies with the paper's. A Python strategy is a class
with a method ``next_view(step) -> 4x4 world_from_camera | None`` (None = stop); a run names it in
its config::

    strategy = "utility-per-metre"        # the label in metrics.json and the benchmark's tables
    python_strategy = "experiments/strategies/utility_per_metre.py:UtilityPerMetre"

    [python_strategy_params]              # keyword arguments of the class's constructor
    metres_per_halving = 0.3

``python_strategy`` is ``path/to/file.py:Class`` (relative to the repository root, or absolute)
or ``package.module:Class`` (importable). A strategy file ``experiments/configs/strategies/<name>.toml``
holding these keys makes ``--strategy <name>`` / ``benchmark.py --strategies <name>`` work like a
built-in name (``utility-per-metre.toml`` is the example).

Every strategy starts with the same Init views; then, once per decision, the episode asks
``next_view`` with a :class:`DecisionStep`, moves the camera there along the configured path while
the frames stream into the map, and counts the view. The budget (``explore.max_views`` views after
Init) ends the episode whatever the strategy says. A step offers what the built-in utility
strategies see, from the same core code and step seed (``objslam_core::active``): the map objects,
the paper's per-object features (H_obj, H̄_obj, R_o, R_IoU, V̄_obj, s), the paper's candidate views,
both utilities with their per-object breakdown, the paper's stopping rule, the table-top cells not
seen yet with the discovery extension's candidate views, gain and budget-reserve count, the run's
``[explore]`` settings, the arm's reachability test (IK and collisions with the table and the
mapped objects) and a random generator seeded by the run seed. The tests that pin it: a Python
argmax of the paper's utility through this interface chooses the same views as the built-in
``object-driven`` (``experiments/strategies/paper_argmax.py``), and the example ``object_driven.py``
the same views as the built-in ``object-driven-discovery`` (``tests/test_strategy.py``).

A strategy that returns anything but None or a finite rigid 4x4 transform ends the run with a
:class:`StrategyError` naming what it returned; the run folder keeps the map as it was
(``map.json.partial``) and is marked INCOMPLETE, like any failed run. A returned pose the arm
cannot reach is skipped (the view is spent, as a built-in strategy's skipped view is).
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

REPO_ROOT = Path(__file__).resolve().parents[2]

UTILITIES = ("object-driven", "object-driven-discovery", "expected-gain")


class StrategyError(RuntimeError):
    """A Python strategy could not be loaded, or returned something that is not a view."""


def load_strategy_class(spec: str) -> type:
    """The class named by ``python_strategy`` (``file.py:Class`` or ``module:Class``); raises
    :class:`StrategyError` saying what is wrong with the spec."""
    if spec.count(":") != 1 or not all(spec.split(":")):
        raise StrategyError(f"expected 'path/to/file.py:Class' or 'package.module:Class', got {spec!r}")
    where, name = spec.split(":")
    if where.endswith(".py"):
        path = Path(where)
        if not path.is_absolute():
            path = REPO_ROOT / path
        if not path.is_file():
            raise StrategyError(f"{where}: no such file")
        mod_name = "objslam_user_strategy_" + re.sub(r"\W", "_", str(path.resolve()))
        module = sys.modules.get(mod_name)
        if module is None:
            loader_spec = importlib.util.spec_from_file_location(mod_name, path)
            if loader_spec is None or loader_spec.loader is None:
                raise StrategyError(f"{where}: cannot be loaded as a Python module")
            module = importlib.util.module_from_spec(loader_spec)
            sys.modules[mod_name] = module
            try:
                loader_spec.loader.exec_module(module)
            except Exception as e:
                del sys.modules[mod_name]
                raise StrategyError(f"{where}: importing it raised {type(e).__name__}: {e}") from e
    else:
        try:
            module = importlib.import_module(where)
        except Exception as e:
            raise StrategyError(f"{where}: cannot import ({type(e).__name__}: {e})") from e
    cls = getattr(module, name, None)
    if cls is None:
        raise StrategyError(f"{where} has no {name!r}")
    if not isinstance(cls, type) or not callable(getattr(cls, "next_view", None)):
        raise StrategyError(f"{spec}: expected a class with a next_view(step) method")
    return cls


def make_strategy(spec: str, params: dict[str, Any]) -> Any:
    """An instance of the strategy class, constructed with ``params`` as keyword arguments."""
    cls = load_strategy_class(spec)
    try:
        return cls(**params)
    except TypeError as e:
        raise StrategyError(f"{spec}: python_strategy_params do not fit its constructor ({e})") from e


def as_view(value: Any, who: str) -> npt.NDArray[np.float64] | None:
    """None, or ``value`` as a float64 4x4 rigid transform; :class:`StrategyError` otherwise."""
    if value is None:
        return None
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise StrategyError(f"{who} returned {type(value).__name__}, not a 4x4 world_from_camera") from e
    if m.shape != (4, 4):
        raise StrategyError(f"{who} returned an array of shape {m.shape}, expected (4, 4) world_from_camera")
    if not np.isfinite(m).all():
        raise StrategyError(f"{who} returned a pose with non-finite entries")
    r = m[:3, :3]
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise StrategyError(f"{who} returned a pose whose last row is {m[3].tolist()}, not [0, 0, 0, 1]")
    if not (np.allclose(r.T @ r, np.eye(3), atol=1e-6) and np.linalg.det(r) > 0.0):
        raise StrategyError(f"{who} returned a pose whose rotation is not a rotation (R^T R != I or det < 0)")
    return m


class DecisionStep:
    """What a Python strategy sees at one decision (built by the episode; read-only for the
    strategy apart from :meth:`log_candidates` and :attr:`stop_reason`)."""

    def __init__(
        self,
        *,
        mapper: Any,
        intrinsics: npt.NDArray[np.float64],
        width: int,
        height: int,
        world_from_camera: npt.NDArray[np.float64],
        reachable: Callable[[npt.NDArray[np.float64]], bool],
        rng: np.random.Generator,
        table_center: tuple[float, float],
        table_size: tuple[float, float],
        explore: dict[str, Any] | None = None,
    ) -> None:
        self._mapper = mapper
        self._cam = {"intrinsics": intrinsics, "width": width, "height": height}
        self._reachable = reachable
        self.world_from_camera = world_from_camera
        """The camera pose now (forward kinematics of the arm's joints), 4x4."""
        self.rng = rng
        """Random generator seeded by the run seed; one stream for the whole episode."""
        progress = mapper.query('{"query": "progress"}')
        self.views_taken: int = progress["views_taken"]
        """Views taken after Init so far."""
        self.max_views: int = progress["max_views"]
        """The budget after Init (``explore.max_views``); the episode stops there regardless."""
        self.table_center = table_center
        """Table top centre (x, y) in the world frame, metres (the top is z = 0)."""
        self.table_size = table_size
        """Table top size (x, y), metres."""
        self.explore: dict[str, Any] = dict(explore or {})
        """The run's ``[explore]`` settings (``ExploreConfig`` as a dict: ``max_views``,
        ``discovery_min_new_cells``, ``discovery_weight``, ...), read-only."""
        self.table_drawn: bool = False
        """Set it when the table gain (:meth:`table_gain`) was part of the choice: the chosen view
        then counts towards ``discovery_evidence_max_views`` if it sees unexplained cells, as the
        built-in strategies count theirs."""
        self.stop_reason: str | None = None
        """Set it before returning None to say why the strategy stopped (metrics' ``stop_reason``)."""
        self.logged: tuple[list[npt.NDArray[np.float64]], list[float]] | None = None

    def _query(self, query: str, **kwargs: Any) -> Any:
        """One question to the core's session at this step (``ActiveMapper.query``)."""
        return self._mapper.query(json.dumps({"query": query, **kwargs}), **self._cam)

    def objects(self) -> list[dict[str, Any]]:
        """The map's objects (the map file's object records: id, label, pose, size, stage)."""
        return json.loads(self._mapper.objects_json())

    def features(self) -> list[dict[str, Any]]:
        """The paper's per-object features, one dict per map object: ``object_id``,
        ``entropy_bits`` (H_obj), ``normalized_entropy`` (H̄_obj), ``occupied_ratio`` (R_o),
        ``history_iou`` (R_IoU or None), ``normalized_volume`` (V̄_obj), ``volume_probability``,
        ``explore`` (s(x) = 1: still to explore), ``cells_occupied|free|unknown``."""
        features = self._query("object_features")
        for f in features:
            grid = f.pop("grid")
            f.update(cells_occupied=grid["occupied"], cells_free=grid["free"], cells_unknown=grid["unknown"])
        return features

    def candidates(self, around: Sequence[int] | None = None) -> list[npt.NDArray[np.float64]]:
        """The paper's candidate views sampled around the objects ``around`` (map ids; None =
        every object), as the built-in utility strategies sample them at this step; not yet
        filtered by reachability."""
        return [p for p, _ in self.candidates_with_targets(around)]

    def candidates_with_targets(
        self, around: Sequence[int] | None = None
    ) -> list[tuple[npt.NDArray[np.float64], int | None]]:
        """Like :meth:`candidates`, with the map id of the object each view was sampled around."""
        views = self._query("candidate_views", around=None if around is None else [int(i) for i in around])
        return [(v["world_from_camera"], v["target_object"]) for v in views]

    def score(
        self,
        views: Sequence[npt.NDArray[np.float64]],
        utility: str = "object-driven",
        explore_every_object: bool = False,
    ) -> list[dict[str, Any]]:
        """Each view's utility and its per-object breakdown (``utility``: "object-driven", the
        paper's f, or "expected-gain", with its motion cost from the camera now). Objects done
        (s(x) = 0) add nothing unless ``explore_every_object``."""
        if utility not in UTILITIES:
            raise StrategyError(f"score(utility=...): expected one of {', '.join(UTILITIES)}, got {utility!r}")
        if not len(views):
            return []
        query = {"query": "score_views", "utility": utility, "explore_every_object": explore_every_object}
        return self._mapper.query(
            json.dumps(query),
            **self._cam,
            views=list(views),
            world_from_camera=self.world_from_camera,
        )

    def utilities(
        self,
        views: Sequence[npt.NDArray[np.float64]],
        utility: str = "object-driven",
        explore_every_object: bool = False,
    ) -> npt.NDArray[np.float64]:
        """The utilities alone, as an array aligned with ``views``."""
        return np.array([s["utility"] for s in self.score(views, utility, explore_every_object)], dtype=np.float64)

    def reachable(self, world_from_camera: npt.NDArray[np.float64]) -> bool:
        """Whether the arm can put the camera there (IK, joint limits, no collision with the table
        or the mapped objects): the test the built-in strategies ask in utility order."""
        return bool(self._reachable(np.asarray(world_from_camera, dtype=np.float64)))

    def best_reachable(
        self, views: Sequence[npt.NDArray[np.float64]], scores: Sequence[float]
    ) -> npt.NDArray[np.float64] | None:
        """The built-in strategies' argmax rule: the view with the highest finite score that the arm
        can reach (ties → the lower index), asking reachability in score order so that IK runs
        only for the best; None when no view with a finite score is reachable."""
        if len(views) != len(scores):
            raise StrategyError(f"best_reachable: {len(views)} views but {len(scores)} scores")
        s = np.asarray(scores, dtype=np.float64)
        for i in sorted(np.flatnonzero(np.isfinite(s)), key=lambda i: (-s[i], i)):
            if self.reachable(views[i]):
                return views[i]
        return None

    def table_unknown_cells(self) -> tuple[npt.NDArray[np.float64], list[bool]]:
        """Table-top cells not known yet (neither seen nor under a mapped object; the discovery
        extension's cells, ``explore.discovery_cell_m``): (N, 3) world centres and, per cell,
        whether it is unexplained (object evidence that no map object explains)."""
        return self._mapper.table_unknown_cells()

    def table_candidates(self) -> list[npt.NDArray[np.float64]]:
        """The discovery extension's candidate views (beyond the paper; core ``explore::discovery``):
        sampled at targets among the table cells not known yet, the unexplained cells' first, as
        the built-in utility strategies sample them at this step; not filtered by reachability."""
        return [v["world_from_camera"] for v in self._query("table_candidate_views")]

    def table_gain(self, views: Sequence[npt.NDArray[np.float64]]) -> list[dict[str, Any]]:
        """What each view would show of the table not known yet, one dict per view: ``cells``
        (weighted count: an unexplained cell weighs ``discovery_evidence_weight`` until
        ``discovery_evidence_max_views`` chosen views saw such cells), ``unexplained`` (such cells
        among them), ``bits`` (the discovery gain the built-in strategies add to the utility, times
        ``discovery_weight``, or alone on a table-only step)."""
        if not len(views):
            return []
        return self._mapper.query(json.dumps({"query": "table_gain"}), **self._cam, views=list(views))

    def table_unknown_weight(self) -> float:
        """The weighted count of table cells not known yet (the built-in strategies look at the
        table only while it is at least ``discovery_min_new_cells``)."""
        return float(self._mapper.query('{"query": "progress"}')["table_unknown_weight"])

    def table_views_needed(self, limit: int) -> int:
        """The budget reserve's count: how many table candidates a greedy cover takes (each
        reachable, each revealing ``discovery_min_new_cells`` new weighted cells), at most
        ``limit``; the built-in strategies switch to the table once it reaches the views left."""
        query = json.dumps({"query": "table_views_needed", "limit": int(limit)})
        return int(self._mapper.query(query, **self._cam, reachable=self.reachable))

    def paper_stop(self) -> str | None:
        """The paper's stopping rule now: "all_explored", "max_views" or None."""
        return self._query("paper_stop")

    def log_candidates(self, views: Sequence[npt.NDArray[np.float64]], scores: Sequence[float]) -> None:
        """Record the views the strategy weighed and their scores (arrows coloured by score in the
        recording, as the built-in utility strategies' candidates are)."""
        if len(views) != len(scores):
            raise StrategyError(f"log_candidates: {len(views)} views but {len(scores)} scores")
        self.logged = ([np.asarray(v, dtype=np.float64) for v in views], [float(s) for s in scores])


@dataclass
class BuiltInScores:
    """The built-in utility strategies' candidates and scores at one step (:func:`built_in_scores`)."""

    views: list[npt.NDArray[np.float64]] = field(default_factory=list)
    """Candidate views (4x4 ``world_from_camera``), not yet filtered by reachability."""
    scores: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    """Their scores; -inf for a view the built-in would never take (a table-only step's views
    revealing fewer than ``discovery_min_new_cells`` cells)."""
    stop: str | None = None
    """The built-in's stop reason when it stops here ("all_explored", "max_views"); then no views."""
    table_only: bool = False
    """The step goes to the unseen table (before-stop discovery or the budget reserve)."""
    table_drawn: bool = False
    """The table gain is part of the scores (assign it to ``step.table_drawn`` when taking one)."""


def built_in_scores(step: DecisionStep, utility: str = "object-driven-discovery") -> BuiltInScores:
    """The built-in utility strategy ``utility`` (``object-driven-discovery``, ``object-driven`` or
    ``expected-gain``) up to the argmax, through the strategy interface, with the run's ``[explore]``
    settings (as the core's ``ActiveSession::next_view``; ``object-driven`` ignores the discovery
    settings, the paper's rule):

    1. the paper's stopping rule; with ``stop_when_explored = false`` "all explored" keeps scoring
       every object; with ``discovery_before_stop`` it looks at the unseen table first while the
       weighted unseen cells are at least ``discovery_min_new_cells``;
    2. the budget reserve (``discovery_reserve``): once the table views still worth taking are no
       fewer than the views left, the rest goes to the table;
    3. candidates: the paper's views around the objects still to explore, plus the table candidates
       when ``discovery_weight`` > 0 (table candidates alone on a table-only step);
    4. scores: the utility plus ``discovery_weight`` × the table gain in bits (the gain alone on a
       table-only step, where only views revealing ``discovery_min_new_cells`` count).

    The built-in takes the best reachable view (:func:`take_best`); a strategy can re-rank the
    scores first (``experiments/strategies/utility_per_metre.py``)."""
    ex = step.explore
    min_new = float(ex["discovery_min_new_cells"])
    paper = utility == "object-driven"  # the paper's rule: no table discovery
    weight = 0.0 if paper else float(ex["discovery_weight"])
    before_stop = not paper and bool(ex["discovery_before_stop"])
    reserve = not paper and bool(ex["discovery_reserve"])
    discovery = weight > 0.0 or before_stop or reserve
    unknown = step.table_unknown_weight() if discovery else 0.0
    if unknown < min_new and weight <= 0.0:
        unknown = 0.0  # too little unseen table to be worth a view, and no mixed term
    explore_all = table_only = False
    reason = step.paper_stop()
    if reason == "all_explored" and not ex["stop_when_explored"]:
        explore_all = True
    elif reason == "all_explored" and before_stop and unknown >= min_new:
        table_only = True
    elif reason is not None:
        return BuiltInScores(stop=reason)
    if not table_only and reserve and unknown >= min_new:
        left = step.max_views - step.views_taken
        table_only = step.table_views_needed(left) >= left
    mixed = unknown > 0.0 and (table_only or weight > 0.0)
    views: list[npt.NDArray[np.float64]] = []
    if not table_only:
        views = step.candidates([f["object_id"] for f in step.features() if f["explore"] or explore_all])
    if mixed:
        views += step.table_candidates()
    out = BuiltInScores(views=views, table_only=table_only, table_drawn=mixed)
    if not views:
        return out
    score = step.utilities(views, utility, explore_every_object=explore_all)
    if mixed:
        gains = step.table_gain(views)
        score = score + (1.0 if table_only else weight) * np.array([g["bits"] for g in gains])
        if table_only:
            score[[g["cells"] < min_new for g in gains]] = -np.inf
    out.scores = score
    return out


def paper_scores(step: DecisionStep, utility: str = "object-driven") -> BuiltInScores:
    """The paper's decision up to its argmax: its stopping rule, its candidate views around the
    objects still to explore, each scored with ``utility`` (the built-in ``object-driven``)."""
    reason = step.paper_stop()
    if reason is not None:
        return BuiltInScores(stop=reason)
    views = step.candidates([f["object_id"] for f in step.features() if f["explore"]])
    return BuiltInScores(views=views, scores=step.utilities(views, utility))


def take_best(
    step: DecisionStep, s: BuiltInScores, scores: npt.NDArray[np.float64] | None = None
) -> npt.NDArray[np.float64] | None:
    """The built-in strategies' choice from :func:`built_in_scores` / :func:`paper_scores`, or from
    ``scores`` re-ranking ``s.views``: stop when ``s`` stops, else record the candidates and return
    the best reachable view (reachability asked in score order, so IK runs only for the best),
    setting ``step.stop_reason`` when there is none and ``step.table_drawn`` as ``s`` says."""
    if s.stop is not None:
        step.stop_reason = s.stop
        return None
    score = s.scores if scores is None else np.asarray(scores, dtype=np.float64)
    step.table_drawn = s.table_drawn
    step.log_candidates(s.views, score)
    best = step.best_reachable(s.views, score)
    if best is None:
        step.stop_reason = "all_explored" if s.table_only else "no_reachable_view"
    return best


__all__ = [
    "BuiltInScores",
    "DecisionStep",
    "StrategyError",
    "as_view",
    "built_in_scores",
    "load_strategy_class",
    "make_strategy",
    "paper_scores",
    "take_best",
]
