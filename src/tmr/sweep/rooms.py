"""Seeded random rooms for the whole-pipeline benchmark (``benchmarks/random_rooms.py``).

A room is a 20 m × 20 m rectangle with obstacles of one *density* and a base (tether anchor) and a leader goal of
one *goal class*; everything is drawn from ``numpy.random.default_rng(seed)``, so the same seed always gives the
same room and the same GeoJSON bytes (:func:`write_geojson`).

Densities (what the obstacles look like):

* ``sparse``, ``medium``, ``dense`` — random discs and rotated rectangles, 4–6 / 10–14 / 20–28 of them, growing
  in size;
* ``walls`` — 1–2 vertical and 1–2 horizontal 0.2 m walls across the room (rooms and corridors) with doors
  1.6–2.6 m wide, plus a little furniture;
* ``narrow`` — the same layout, but every door is narrow: passable doors are 2r + 0.1 … 2r + 0.4 m wide
  (r = 0.5 m, so a robot passes with 5–20 cm to spare each side), and some extra slits 0.5–0.9 m wide (< 2r,
  closed once the walls are grown by r);
* ``long_walls`` — 2–3 parallel walls 14–17 m long, attached alternately to opposite sides of the room
  (a serpentine: long detours).

Goal classes (route length = the shortest free route of :func:`tmr.route.route.plan_route` when that module exists,
otherwise the straight distance; see :attr:`Room.route_source`):

* ``near`` — route 2–6 m; ``mid`` — route 6–12 m; ``far`` — route > 3 d_max = 16.8 m (beyond three robots);
* ``corner`` — a goal within 3 m of the room corner farthest from the base, whatever its route; this class is
  the only one allowed to land in a pocket not connected to the base (``Room.connected`` is False then), which
  tests the planner's "no free route" refusal: a quarter of the corner rooms (:data:`CLOSED_CORNER_P`) wall a
  random corner off with two doorless walls (a 3.6 m pocket) and put the goal in it.

Base and goal keep a clearance > 0.3 m (:data:`MIN_CLEARANCE`) from the obstacles and walls grown by
r = 0.5 m (``Environment.exact_clearance``). Coordinates are rounded to 1 mm (obstacles, base, goal) before any
check, so the GeoJSON file describes exactly the room that was checked.

:func:`run_room` runs one room through the whole command line (``python -m tmr.plan --map ...``) in a
subprocess and checks its trajectories **independently** of tmr (:func:`independent_check`: shapely distances to
the raw obstacles, no ``tmr.world.environment`` or ``tmr.checks.metrics`` query).
"""

from __future__ import annotations

import functools
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry.base import BaseGeometry

from tmr.errors import TmrError
from tmr.world.environment import QUAD_SEGS, Environment

__all__ = [
    "BOUNDS",
    "DENSITIES",
    "GOAL_CLASSES",
    "MIN_CLEARANCE",
    "SAFETY_RADIUS",
    "Room",
    "RoomError",
    "default_d_max",
    "generate_room",
    "room_from_spec",
    "room_geojson",
    "room_set",
    "room_spec",
    "span_rows",
    "write_geojson",
]

BOUNDS: tuple[float, float, float, float] = (0.0, 0.0, 20.0, 20.0)  # m
SAFETY_RADIUS = 0.5  # m, r: the default of Environment / ChainParams
MIN_CLEARANCE = 0.3  # m, clearance of base and goal from the obstacles grown by r
DENSITIES = ("sparse", "medium", "dense", "walls", "narrow", "long_walls")
GOAL_CLASSES = ("near", "mid", "corner", "far")
NEAR_RANGE = (2.0, 6.0)  # m, route length of a "near" goal
MID_RANGE = (6.0, 12.0)  # m, route length of a "mid" goal
FAR_ROBOTS = 3  # a "far" goal needs a route longer than FAR_ROBOTS * d_max
CORNER_BOX = 3.0  # m, a "corner" goal lies within this distance (each axis) of the corner
WALL_WIDTH = 0.2  # m, thickness of walls
CLOSED_CORNER_P = 0.25  # probability that a "corner" room walls its goal corner off (a "no free route" test)
POCKET = 3.6  # m, side of the walled-off corner pocket
CLEARANCE_TOL = 1e-3  # m, tolerance of the independent clearance checks (see independent_check)
GEOMETRY_TOL = 1e-6  # m or ratio, tolerance of the span and separation checks
MIN_ROUTE_FOR_RATIO = 0.5  # m, no route-length ratio for a leader that starts closer than this to its goal
_DIGITS = 3  # coordinates rounded to 1 mm

_CORNERS = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0], [20.0, 20.0]])
_CANDIDATES = 512  # points drawn at once when looking for a base or a goal
_ROUTE_TRIES = 30  # goal candidates whose route is computed per base
_BASE_TRIES = 12  # bases per obstacle layout
_LAYOUT_TRIES = 8  # obstacle layouts per room


class RoomError(TmrError):
    """No room of the requested density and goal class could be drawn from this seed."""


# ------------------------------------------------------------------------------------------------------------
# room
# ------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Room:
    """One generated room (all lengths in metres).

    Attributes:
        name: ``"<density>-<goal_class>-<seed>"``.
        seed, density, goal_class: the generator inputs.
        bounds: (xmin, ymin, xmax, ymax) of the room.
        obstacles: raw obstacles (shapely polygons, not grown), one per entry of ``specs``.
        base: tether anchor (2,); goal: leader goal (2,).
        specs: how each obstacle is written to GeoJSON: ``("disc", x, y, radius)``, ``("polygon", coords)`` or
            ``("wall", ((x0, y0), (x1, y1)), width)``.
        connected: the goal lies in the free-space component of the base (shapely: one polygon of the free space
            holds both; independent of tmr.route.route).
        straight: straight base–goal distance.
        route_length, n_min, n_lower: from :func:`tmr.route.route.plan_route` (None when the module is missing or the
            goal is not connected).
        route_source: ``"route"`` (classified by tmr.route.route) or ``"straight"`` (straight distance; tmr.route.route
            missing).
        route_error: the NoRouteError message of tmr.route.route for this goal (only ``corner`` goals may have one: in
            another piece of free space, or connected but through a gap the route module finds too narrow).
        d_max: the longest tether span used for ``far`` goals and for ``n_lower``.
        base_clearance, goal_clearance: exact clearance of base and goal from the grown obstacles.
        layout_tries: obstacle layouts drawn before one fitted the goal class (1 = first).
    """

    name: str
    seed: int
    density: str
    goal_class: str
    bounds: tuple[float, float, float, float]
    obstacles: list[BaseGeometry]
    base: NDArray[np.float64]
    goal: NDArray[np.float64]
    specs: tuple[tuple[Any, ...], ...] = ()
    connected: bool = True
    straight: float = math.nan
    route_length: float | None = None
    n_min: int | None = None
    n_lower: int | None = None
    route_source: str = "straight"
    route_error: str | None = None
    d_max: float = math.nan
    base_clearance: float = math.nan
    goal_clearance: float = math.nan
    layout_tries: int = 1
    route_points: NDArray[np.float64] | None = field(default=None, repr=False)

    def environment(self, safety_radius: float = SAFETY_RADIUS) -> Environment:
        """The room as an :class:`~tmr.world.environment.Environment` (obstacles grown by ``safety_radius``)."""
        return Environment.from_geometry(self.obstacles, self.bounds, safety_radius=safety_radius)

    def summary(self) -> dict[str, Any]:
        """Flat JSON-ready description (no geometry)."""
        return {
            "room": self.name,
            "room_seed": self.seed,
            "density": self.density,
            "goal_class": self.goal_class,
            "n_obstacles": len(self.obstacles),
            "base_x": float(self.base[0]),
            "base_y": float(self.base[1]),
            "goal_x": float(self.goal[0]),
            "goal_y": float(self.goal[1]),
            "connected": self.connected,
            "straight": self.straight,
            "route_length": self.route_length,
            "n_min": self.n_min,
            "n_lower": self.n_lower,
            "route_source": self.route_source,
            "route_found": self.route_length is not None,
            "route_error": self.route_error,
            "layout_tries": self.layout_tries,
        }


@functools.lru_cache(maxsize=1)
def _default_limits() -> tuple[tuple[float, float], ...]:
    from tmr.model.params import ChainParams
    from tmr.planner import span_limits

    return tuple((float(lo), float(hi)) for lo, hi in span_limits(2, ChainParams()))


def default_d_max() -> float:
    """d_max [m] between two robots for the default parameters (≈ 5.60 m, the catenary limit)."""
    return _default_limits()[1][1]


# ------------------------------------------------------------------------------------------------------------
# obstacle specs -> geometry
# ------------------------------------------------------------------------------------------------------------
def _r(v: float) -> float:
    return round(float(v), _DIGITS) + 0.0  # + 0.0: no "-0.0" in the file


def _geometry(spec: tuple[Any, ...]) -> BaseGeometry:
    """The geometry tmr.world.maps.load_environment builds from the GeoJSON feature of ``spec`` (same buffer
    settings)."""
    kind = spec[0]
    if kind == "disc":
        _, x, y, radius = spec
        return shapely.Point(x, y).buffer(radius, quad_segs=QUAD_SEGS)
    if kind == "polygon":
        return shapely.Polygon(spec[1])
    if kind == "wall":
        _, coords, width = spec
        return shapely.LineString(coords).buffer(width / 2.0, quad_segs=QUAD_SEGS, cap_style="flat", join_style="mitre")
    raise ValueError(f"unknown obstacle kind {kind!r}")


def _disc(rng: np.random.Generator, radius: tuple[float, float]) -> tuple[Any, ...]:
    x, y = rng.uniform(1.0, 19.0, size=2)
    return ("disc", _r(x), _r(y), _r(rng.uniform(*radius)))


def _rectangle(rng: np.random.Generator, side: tuple[float, float]) -> tuple[Any, ...]:
    cx, cy = rng.uniform(1.0, 19.0, size=2)
    w, h = rng.uniform(*side, size=2)
    a = rng.uniform(0.0, math.pi)
    c, s = math.cos(a), math.sin(a)
    corners = [(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)]
    ring = [(_r(cx + c * u - s * v), _r(cy + s * u + c * v)) for u, v in corners]
    return ("polygon", tuple(ring + ring[:1]))


def _clutter(rng: np.random.Generator, count: tuple[int, int], radius: tuple[float, float], side: tuple[float, float]):
    n = int(rng.integers(count[0], count[1] + 1))
    return [_disc(rng, radius) if rng.random() < 0.5 else _rectangle(rng, side) for _ in range(n)]


def _wall(a: tuple[float, float], b: tuple[float, float]) -> tuple[Any, ...]:
    return ("wall", ((_r(a[0]), _r(a[1])), (_r(b[0]), _r(b[1]))), WALL_WIDTH)


def _positions(rng: np.random.Generator, n: int) -> list[float]:
    """Coordinates of n parallel walls across the room, at least 4 m apart and from the sides."""
    if n == 1:
        return [float(rng.uniform(6.0, 14.0))]
    return [float(rng.uniform(4.5, 8.5)), float(rng.uniform(11.5, 15.5))]


def _doors(
    rng: np.random.Generator, lo: float, hi: float, widths: list[tuple[float, float]], margin: float = 0.4
) -> list[tuple[float, float]]:
    """Openings [a, b] in the wall piece [lo, hi]: one per entry of ``widths`` (a width range), each in its own
    equal share of the piece, ``margin`` [m] from the share's ends."""
    out = []
    share = (hi - lo) / max(1, len(widths))
    order = rng.permutation(len(widths))
    for k, j in enumerate(order):
        w = float(rng.uniform(*widths[j]))
        a0, a1 = lo + k * share + margin, lo + (k + 1) * share - margin - w
        if a1 < a0:  # piece too short for this door: skip it
            continue
        a = float(rng.uniform(a0, a1))
        out.append((a, a + w))
    return sorted(out)


def _walls_with_doors(rng: np.random.Generator, narrow: bool) -> list[tuple[Any, ...]]:
    """1-2 vertical and 1-2 horizontal walls across the room; every piece between two crossings gets a door
    (probability 0.8; at least one per wall); ``narrow``: doors 2r + 0.1 ... 2r + 0.4 m and extra closed slits."""
    d = 2 * SAFETY_RADIUS
    door = (d + 0.1, d + 0.4) if narrow else (1.6, 2.6)
    slit = (0.5, d - 0.1)
    xs = _positions(rng, int(rng.integers(1, 3)))
    ys = _positions(rng, int(rng.integers(1, 3)))
    specs: list[tuple[Any, ...]] = []
    for vertical, at, cross in ((True, xs, ys), (False, ys, xs)):
        for c in at:
            cuts = [0.0, *sorted(cross), 20.0]
            pieces = list(zip(cuts[:-1], cuts[1:], strict=True))
            has_door = rng.random(len(pieces)) < 0.8
            if not has_door.any():
                has_door[int(rng.integers(len(pieces)))] = True
            openings: list[tuple[float, float]] = []
            for (lo, hi), open_ in zip(pieces, has_door, strict=True):
                widths = ([door] if open_ else []) + ([slit] if narrow and rng.random() < 0.5 else [])
                openings += _doors(rng, lo + 0.1, hi - 0.1, widths)
            edges = [0.0] + [v for o in openings for v in o] + [20.0]
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                if b - a > 0.05:
                    specs.append(_wall((c, a), (c, b)) if vertical else _wall((a, c), (b, c)))
    return specs


def _long_walls(rng: np.random.Generator) -> list[tuple[Any, ...]]:
    """2-3 parallel walls 14-17 m long, attached alternately to opposite sides (a serpentine)."""
    n = int(rng.integers(2, 4))
    vertical = bool(rng.random() < 0.5)
    first_side = int(rng.integers(2))
    specs = []
    for k in range(n):
        c = 20.0 * (k + 1) / (n + 1) + float(rng.uniform(-0.8, 0.8))
        length = float(rng.uniform(14.0, 17.0))
        a, b = (0.0, length) if (k + first_side) % 2 == 0 else (20.0 - length, 20.0)
        specs.append(_wall((c, a), (c, b)) if vertical else _wall((a, c), (b, c)))
    return specs


def _pocket(corner: NDArray) -> list[tuple[Any, ...]]:
    """Two walls closing off the POCKET × POCKET square at a room corner (no door: a separate piece of free
    space), overlapping at their joint."""
    cx, cy = corner
    sx, sy = np.sign(10.0 - corner)
    px, py = cx + sx * POCKET, cy + sy * POCKET
    h = WALL_WIDTH / 2
    return [_wall((px, cy), (px, py + sy * h)), _wall((cx, py), (px + sx * h, py))]


def _obstacle_specs(rng: np.random.Generator, density: str) -> list[tuple[Any, ...]]:
    if density == "sparse":
        return _clutter(rng, (4, 6), (0.3, 0.9), (0.5, 2.0))
    if density == "medium":
        return _clutter(rng, (10, 14), (0.4, 1.2), (0.6, 2.8))
    if density == "dense":
        return _clutter(rng, (20, 28), (0.4, 1.3), (0.6, 3.0))
    if density == "walls":
        return _walls_with_doors(rng, narrow=False) + _clutter(rng, (2, 4), (0.3, 0.6), (0.4, 1.0))
    if density == "narrow":
        return _walls_with_doors(rng, narrow=True)
    if density == "long_walls":
        return _long_walls(rng) + _clutter(rng, (0, 2), (0.3, 0.6), (0.4, 1.0))
    raise ValueError(f"unknown density {density!r}; choose from {', '.join(DENSITIES)}")


# ------------------------------------------------------------------------------------------------------------
# base and goal
# ------------------------------------------------------------------------------------------------------------
def _route_module() -> Any:
    try:
        import tmr.route.route as route
    except ImportError:
        return None
    return route if hasattr(route, "plan_route") else None


class _Free:
    """Clearance and component queries on one environment."""

    def __init__(self, env: Environment) -> None:
        self.env = env
        self.parts = list(shapely.get_parts(env.free))
        for p in self.parts:
            shapely.prepare(p)

    def sample(self, rng: np.random.Generator, lo=(0.0, 0.0), hi=(20.0, 20.0)) -> tuple[NDArray, NDArray]:
        """``_CANDIDATES`` points drawn in the box [lo, hi], rounded to 1 mm, and their exact clearances."""
        pts = np.round(rng.uniform(lo, hi, size=(_CANDIDATES, 2)), _DIGITS) + 0.0
        return pts, self.env.exact_clearance(pts)

    def component(self, p: NDArray) -> int:
        for k, part in enumerate(self.parts):
            if shapely.contains_xy(part, p[0], p[1]):
                return k
        return -1


def span_rows(d_max: float | None = None) -> NDArray[np.float64]:
    """[[d_lo, d_max] of the anchor tether, [d_lo, d_max] of the others] [m] for the default parameters
    (``tmr.planner.span_limits(2, ChainParams())``), with d_max replaced by ``d_max`` if given."""
    lim = np.array(_default_limits(), dtype=float)
    if d_max is not None:
        lim[:, 1] = d_max
    return lim


def _route(route_mod: Any, env: Environment, base: NDArray, goal: NDArray, d_max: float) -> tuple[Any, str | None]:
    """(tmr.route.route.plan_route(...), None) or (None, the refusal's message: no free route, or a blocked route)."""
    try:
        return route_mod.plan_route(env, base, goal, span_rows(d_max)), None
    except route_mod.RouteVerdict as exc:
        return None, str(exc)


def _pick_goal(
    free: _Free,
    rng: np.random.Generator,
    base: NDArray,
    goal_class: str,
    d_max: float,
    route_mod: Any,
    corner: NDArray | None = None,
) -> tuple[NDArray, bool, Any, str | None] | None:
    """(goal, connected, route or None, route error or None) for one base, or None if no goal of the class was
    found. ``connected``: base and goal in one piece of free space (shapely, independent of tmr.route.route).
    ``corner``: the corner of a ``corner`` goal (default: the room corner farthest from the base)."""
    if goal_class == "corner":
        if corner is None:
            corner = _CORNERS[int(np.argmax(np.hypot(*(_CORNERS - base).T)))]
        lo = np.minimum(corner, corner + np.sign(10.0 - corner) * CORNER_BOX)
        hi = np.maximum(corner, corner + np.sign(10.0 - corner) * CORNER_BOX)
        pts, clr = free.sample(rng, lo, hi)
        ok = np.flatnonzero(clr > MIN_CLEARANCE)
        if not ok.size:
            return None
        goal = pts[ok[0]]
        connected = free.component(goal) == free.component(base)
        route, err = _route(route_mod, free.env, base, goal, d_max) if route_mod is not None else (None, None)
        return goal, connected, route, err

    if goal_class == "near":
        lo_len, hi_len, straight_lo, straight_hi = *NEAR_RANGE, NEAR_RANGE[0], NEAR_RANGE[1]
    elif goal_class == "mid":
        lo_len, hi_len, straight_lo, straight_hi = *MID_RANGE, 3.0, MID_RANGE[1]
    elif goal_class == "far":
        lo_len, hi_len = FAR_ROBOTS * d_max, math.inf
        straight_lo, straight_hi = (6.0 if route_mod is not None else lo_len), math.inf
    else:
        raise ValueError(f"unknown goal class {goal_class!r}; choose from {', '.join(GOAL_CLASSES)}")
    pts, clr = free.sample(rng)
    dist = np.hypot(*(pts - base).T)
    ok = np.flatnonzero((clr > MIN_CLEARANCE) & (dist >= straight_lo) & (dist <= straight_hi))
    if route_mod is None:  # accept by the straight distance (the route module is not there yet)
        ok = ok[(dist[ok] >= lo_len) & (dist[ok] <= hi_len)]
    home = free.component(base)
    tried = 0
    for k in ok:
        goal = pts[k]
        if free.component(goal) != home:
            continue
        if route_mod is None:
            return goal, True, None, None
        tried += 1
        route, _ = _route(route_mod, free.env, base, goal, d_max)
        if route is not None and lo_len <= route.length <= hi_len:
            return goal, True, route, None
        if tried >= _ROUTE_TRIES:
            break
    return None


def generate_room(seed: int, density: str, goal_class: str, d_max: float | None = None) -> Room:
    """The room of ``seed`` for a density (:data:`DENSITIES`) and a goal class (:data:`GOAL_CLASSES`).

    Deterministic: everything is drawn from ``numpy.random.default_rng(seed)``. ``d_max`` [m] (default: the
    catenary limit of the default parameters, :func:`default_d_max`) sets the ``far`` threshold
    (``3 d_max``) and the route's robot count. Raises RoomError if no layout of this seed fits the class.
    """
    if density not in DENSITIES:
        raise ValueError(f"unknown density {density!r}; choose from {', '.join(DENSITIES)}")
    if goal_class not in GOAL_CLASSES:
        raise ValueError(f"unknown goal class {goal_class!r}; choose from {', '.join(GOAL_CLASSES)}")
    d_max = default_d_max() if d_max is None else float(d_max)
    route_mod = _route_module()
    rng = np.random.default_rng(seed)
    for layout in range(1, _LAYOUT_TRIES + 1):
        specs = _obstacle_specs(rng, density)
        corner = None
        if goal_class == "corner" and rng.random() < CLOSED_CORNER_P:
            corner = _CORNERS[int(rng.integers(4))]
            specs += _pocket(corner)
        obstacles = [_geometry(s) for s in specs]
        env = Environment.from_geometry(obstacles, BOUNDS, safety_radius=SAFETY_RADIUS)
        free = _Free(env)
        for _ in range(_BASE_TRIES):
            pts, clr = free.sample(rng)
            ok = clr > MIN_CLEARANCE
            if corner is not None:  # the base outside the pocket
                ok &= np.any(np.abs(pts - corner) > POCKET + WALL_WIDTH, axis=1)
            ok = np.flatnonzero(ok)
            if not ok.size:
                break
            base = pts[ok[0]]
            picked = _pick_goal(free, rng, base, goal_class, d_max, route_mod, corner)
            if picked is None:
                continue
            goal, connected, route, route_error = picked
            clear = env.exact_clearance(np.stack([base, goal]))
            return Room(
                name=f"{density}-{goal_class}-{seed}",
                seed=int(seed),
                density=density,
                goal_class=goal_class,
                bounds=BOUNDS,
                obstacles=obstacles,
                base=base.copy(),
                goal=goal.copy(),
                specs=tuple(specs),
                connected=bool(connected),
                straight=float(np.hypot(*(goal - base))),
                route_length=None if route is None else float(route.length),
                n_min=None if route is None else int(route.n_min),
                n_lower=None if route is None else int(route.n_lower),
                route_source="route" if route_mod is not None else "straight",
                route_error=route_error,
                d_max=d_max,
                base_clearance=float(clear[0]),
                goal_clearance=float(clear[1]),
                layout_tries=layout,
                route_points=None if route is None else np.asarray(route.points, dtype=float),
            )
    raise RoomError(f"seed {seed}: no {density} room with a {goal_class} goal after {_LAYOUT_TRIES} obstacle layouts")


def room_from_spec(spec: tuple[int, str, str]) -> Room | str:
    """:func:`generate_room` of a :func:`room_set` entry, or the RoomError message (a picklable task for the sweep
    executors)."""
    seed, density, goal_class = spec
    try:
        return generate_room(seed, density, goal_class)
    except RoomError as exc:
        return str(exc)


def room_spec(name: str) -> tuple[int, str, str]:
    """The (room seed, density, goal class) of a room's name ``"<density>-<goal_class>-<seed>"`` (:attr:`Room.name`,
    the ``room`` column of the rooms benchmarks), the inverse of :func:`generate_room`'s naming; ValueError if it is
    not one."""
    parts = name.split("-")
    if len(parts) != 3 or parts[0] not in DENSITIES or parts[1] not in GOAL_CLASSES or not parts[2].isdigit():
        raise ValueError(f"not a room name (<density>-<goal_class>-<seed>): {name!r}")
    return int(parts[2]), parts[0], parts[1]


def room_set(n_rooms: int, seed: int = 0) -> list[tuple[int, str, str]]:
    """``n_rooms`` deterministic (room seed, density, goal class) triples covering densities × goal classes evenly.

    Entry i has density ``DENSITIES[i % 6]`` and goal class ``GOAL_CLASSES[(i + i // 6) % 4]``: every 24
    consecutive entries hold each of the 24 pairs once, and any prefix is balanced within one room per pair.
    Room seeds come from ``numpy.random.SeedSequence(seed)`` (distinct for distinct ``seed``).
    """
    if n_rooms < 0:
        raise ValueError(f"n_rooms must be >= 0, got {n_rooms}")
    seeds = np.random.SeedSequence(seed).generate_state(max(n_rooms, 1), dtype=np.uint32)[:n_rooms]
    nd, ng = len(DENSITIES), len(GOAL_CLASSES)
    return [(int(s), DENSITIES[i % nd], GOAL_CLASSES[(i + i // nd) % ng]) for i, s in enumerate(seeds)]


# ------------------------------------------------------------------------------------------------------------
# GeoJSON
# ------------------------------------------------------------------------------------------------------------
def room_geojson(room: Room) -> dict[str, Any]:
    """The room as a GeoJSON FeatureCollection with a top-level ``bounds`` (loadable by
    tmr.world.maps.load_environment):
    discs as Points with a ``radius``, walls as LineStrings with a ``width``, the rest as Polygons. Base, goal
    and the generator inputs go into a top-level ``tmr_room`` member (ignored by the loader)."""
    features = []
    for k, spec in enumerate(room.specs):
        kind = spec[0]
        props: dict[str, Any] = {"name": f"{kind}{k}"}
        if kind == "disc":
            geom = {"type": "Point", "coordinates": [spec[1], spec[2]]}
            props["radius"] = spec[3]
        elif kind == "wall":
            geom = {"type": "LineString", "coordinates": [list(p) for p in spec[1]]}
            props["width"] = spec[2]
        else:
            geom = {"type": "Polygon", "coordinates": [[list(p) for p in spec[1]]]}
        features.append({"type": "Feature", "properties": props, "geometry": geom})
    return {
        "type": "FeatureCollection",
        "bounds": list(room.bounds),
        "tmr_room": {
            "name": room.name,
            "seed": room.seed,
            "density": room.density,
            "goal_class": room.goal_class,
            "base": room.base.tolist(),
            "goal": room.goal.tolist(),
            "safety_radius": SAFETY_RADIUS,
        },
        "features": features,
    }


def write_geojson(room: Room, path: str | os.PathLike[str]) -> Path:
    """Write :func:`room_geojson` to ``path`` (same room → same bytes); returns the path."""
    p = Path(path)
    p.write_text(json.dumps(room_geojson(room), indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return p
