"""Tether-aware global route: is the goal reachable, with how many robots, and where does the chain lie?

The single source of "is this possible, and how many robots" (``formulations/route.md``):

1. **Free space.** The room minus the obstacles grown by the safety radius r (``env.free``), eroded by a route
   margin δ (so the route keeps clearance δ > the QP's d_safe) and simplified conservatively (erode by δ + t,
   then Douglas–Peucker with tolerance t: the simplified region lies inside the region eroded by δ).
2. **Shortest route** from the anchor to the goal: a visibility graph on the *reflex* vertices of that region only
   (the convex corners of the obstacles: a shortest path bends only there), keeping only *bitangent* edges (both
   neighbours of each end vertex on one side of the edge), visibility tested with vectorised shapely ``covers``;
   Dijkstra (:func:`shortest_path_tree`). Exact on the polygonal region (Lozano-Pérez and Wesley 1979).
3. **Fewest robots.** Tethers are straight chords of at most d_max, clear of the grown obstacles, robots at least
   2r apart. Two numbers come out:

   * ``n_lower``, a proof: ⌈L_lower / d_max⌉ (any chain is a free path from the anchor to the goal, at least as
     long as the shortest path in a region that contains the free space (grown by t, then simplified by t),
     L_lower), raised where corners make a chain of that many robots impossible (:mod:`tmr.route.reach`, conservative
     reachable sets on a grid);
   * ``n_min``: the robots of the *route chain*: stations on the route, each the farthest route point (step
     ``STATION_STEP``) whose chord from the previous station is free, no longer than d_max and homotopic to the
     route (the region between chord and route holds no obstacle). Corners cost robots here, so
     ``n_min ≥ n_lower``; it is what the route-guided planner can realise, and a plan with N ≥ n_min starts
     from a placement along the route and ends with the robots at these stations. Where
     :func:`tmr.route.reach.find_chain` finds a chain of fewer robots off the route, ``n_min`` is its count
     (``n_route`` keeps the route chain's) and, for N below ``n_route``, that chain's polyline is the guide.

A goal in another connected piece of free space raises :class:`NoRouteError`. Nothing here plans motion.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from shapely.geometry.base import BaseGeometry

from tmr.errors import ParameterError, TmrError

Array = NDArray[np.float64]

__all__ = [
    "BlockedRouteError",
    "NoRouteError",
    "Route",
    "RouteVerdict",
    "ROUTE_MARGIN",
    "STATION_STEP",
    "TooFewRobotsError",
    "TooManyRobotsError",
    "Packing",
    "check_fit",
    "guide_arcs",
    "packing_bound",
    "plan_route",
    "point_at",
    "proven_too_few",
    "stations",
]

#: δ [m]: clearance the route keeps from the obstacles grown by r (above the QP's d_safe = 0.05 m, so the robots'
#: references are feasible); halved, then ``NARROW_MARGIN``, where a passage is too narrow for it.
ROUTE_MARGIN = 0.15
#: t [m]: Douglas–Peucker tolerance of the conservative simplification of the free region.
SIMPLIFY_TOLERANCE = 0.02
#: Segments per quarter circle of the erosion (its chord error δ (1 − cos(π/8)) ≤ 0.012 m is inside δ).
QUAD_SEGS = 4
#: Smallest δ [m], tried in a narrow passage: above the QP's d_safe = 0.05 m, which every robot keeps.
NARROW_MARGIN = 0.06
#: δ [m] of the last rung, tried only when the chain has too few robots for the routes keeping ``NARROW_MARGIN``: a
#: route nearer the obstacles than the QP's d_safe, whose plan the QP and the checks keep within every limit or fail.
RETRY_MARGIN = 0.03
#: Spacing [m] of the candidate stations along the route.
STATION_STEP = 0.1
#: Clearance [m] a chord between stations keeps from the obstacles grown by r (the QP keeps d_safe = 0.05 m, but a
#: tether sample that starts nearer may stay there).
CHORD_CLEARANCE = 0.06
#: Extra distance [m] between two robots beyond 2r in a station placement.
SPACING_MARGIN = 0.1


class RouteVerdict(TmrError):
    """A task refused by the route before any motion is planned. ``proven``: impossible (the command line exits 2),
    else a verdict of the search at its resolution (no plan found: exit 1)."""

    proven = True


class NoRouteError(RouteVerdict):
    """The goal cannot be reached from the anchor through free space (the obstacles grown by r separate them)."""


class BlockedRouteError(RouteVerdict):
    """The goal is connected, but no chain of straight tethers was found along the route (a passage too narrow for
    the tethers' clearance, or a corner the chords cannot cut at the search resolution)."""

    proven = False


class TooFewRobotsError(RouteVerdict):
    """The chain has fewer robots than the route needs (``needed``; ``proven``: fewer than the lower bound)."""

    def __init__(self, message: str, needed: int, proven: bool) -> None:
        super().__init__(message)
        self.needed = needed
        self.proven = proven


class TooManyRobotsError(RouteVerdict):
    """More robots than can stand in the free space at once (:func:`packing_bound`): proven, exit 2. ``fit``: the
    most that may fit."""

    def __init__(self, message: str, fit: int) -> None:
        super().__init__(message)
        self.fit = fit


@dataclass(frozen=True)
class Route:
    """The shortest free route of the chain and what it implies (see the module docstring).

    Attributes:
        points: (M, 2) polyline from the anchor to the goal [m]; every segment keeps clearance ``margin``.
        length: L [m].
        margin: δ kept from the obstacles grown by r [m].
        d_max: longest tether chord [m] (per tether: ``d_max_first`` for the anchor tether).
        turning: Θ, total turning angle of the route [rad].
        n_lower: a proven lower bound on the number of robots: ⌈L_lower / d_max⌉ (``lower_by`` "length"), or one
            more than a chain proven impossible round the corners by :func:`tmr.route.reach.chain_is_impossible`
            ("corners").
        lower_length: L_lower [m], the shortest path in a region containing the free space (≤ any chain's length).
        n_min: the fewest robots of a chain found: the route chain (stations on the route; corners cost robots), or
            fewer where :func:`tmr.route.reach.find_chain` finds a chain off the route.
        n_route: robots of the route chain; for N < n_route, ``plan_route(..., robots=N)`` returns a route whose
            guide is the chain found off the route (``points``: its polyline, ``stations``: its robots).
        tight_chain: for ``robots=N`` with n_lower ≤ N < n_min (not proven too few): a chain of at most N robots
            that only the clearance of a tether keeps from being a witness (:func:`tight_chain`); None if none was
            found.
        stations: (n_route, 2) stations of the route chain, the last one the goal [m] (of the chain off the route
            when that is the guide).
        station_arcs: their arc lengths along the guide [m], one per station.
        vertices: number of reflex vertices of the visibility graph; edges: its edges.
        time: seconds spent.
    """

    points: Array
    length: float
    margin: float
    d_max: float
    d_max_first: float
    turning: float
    n_lower: int
    n_min: int
    lower_length: float
    stations: Array
    station_arcs: Array
    vertices: int
    edges: int
    time: float
    notes: tuple[str, ...] = field(default_factory=tuple)
    lower_by: str = "length"
    n_route: int = 0
    tight_chain: TightChain | None = None

    @property
    def arcs(self) -> Array:
        """Cumulative arc length at each route point [m]."""
        return guide_arcs(self.points)

    def refusal(self, n_robots: int) -> str | None:
        """One line saying why ``n_robots`` cannot reach the goal along this route, or None if it can."""
        if n_robots >= self.n_min:
            return None
        if n_robots < self.n_lower and self.lower_by == "corners":
            return (
                f"the goal needs at least {self.n_lower} robots: no chain of {n_robots} straight tethers of ≤ "
                f"{self.d_max:.2f} m clear of the obstacles wraps the corners of the shortest tether route "
                f"({self.lower_length:.1f} m); rerun with --robots {self.n_min}"
            )
        if n_robots < self.n_lower:
            corners = (
                ""
                if self.n_min == self.n_lower == self.n_route
                else f" (its corners make it {self.n_route} for a chain along the route"
                + (f", {self.n_min} off it)" if self.n_min < self.n_route else ")")
            )
            return (
                f"the goal needs at least {self.n_lower} robots: shortest tether route {self.lower_length:.1f} m, "
                f"each tether ≤ {self.d_max:.2f} m{corners}; rerun with --robots {self.n_min}"
            )
        where = f"the shortest tether route ({self.length:.1f} m, {len(self.points) - 2} corner(s))"
        need = (
            f"{self.n_min} robots along {where}"
            if self.n_min >= self.n_route
            else f"{self.n_route} robots along {where}, {self.n_min} off it"
        )
        robots = f"{n_robots} robot{'s' if n_robots != 1 else ''}"
        if self.tight_chain is not None:  # the clearance stops it, not the count: floored, never shown as enough
            t = self.tight_chain
            decimals = max(3, 1 - math.floor(math.log10(t.clearance)))  # two significant digits below 1 mm
            passes = math.floor(t.clearance * 10**decimals) / 10**decimals
            return (
                f"no chain of {robots} keeping {CHORD_CLEARANCE:g} m from the obstacles was found, only closer ones: "
                f"in {t.searched}, a tether passes {passes:.{decimals}f} m from them where {t.needed:.3g} m is needed "
                f"(tethers ≤ {self.d_max:.2f} m); keeping it takes {need}; rerun with --robots {self.n_min}"
            )
        return (
            f"no chain of {robots} was found: straight tethers of ≤ {self.d_max:.2f} m keeping "
            f"{CHORD_CLEARANCE:g} m from the obstacles need {need}, and no chain of {n_robots} keeping it was found "
            f"off the route, nor proven impossible (proven: at least {self.n_lower}); rerun with --robots {self.n_min}"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no timing)."""
        return {
            "route_length": self.length,
            "route_margin": self.margin,
            "route_turning": self.turning,
            "route_points": self.points.tolist(),
            "n_lower": self.n_lower,
            "n_lower_by": self.lower_by,
            "n_route": self.n_route,
            "route_lower_length": self.lower_length,
            "n_min": self.n_min,
            "stations": self.stations.tolist(),
        }


# ----------------------------------------------------------------------------------------------------------------
# polylines
# ----------------------------------------------------------------------------------------------------------------
def guide_arcs(points: ArrayLike) -> Array:
    """Cumulative arc length [m] at each point of a polyline (M, 2)."""
    p = np.asarray(points, dtype=float)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def point_at(points: Array, arcs: Array, s: ArrayLike) -> Array:
    """Points of the polyline at arc lengths ``s`` [m] (clipped to [0, L]); shape ``s.shape + (2,)``."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, arcs[-1])
    return np.stack([np.interp(s, arcs, points[:, 0]), np.interp(s, arcs, points[:, 1])], axis=-1)


def _turning(points: Array) -> float:
    d = np.diff(points, axis=0)
    if len(d) < 2:
        return 0.0
    a = np.arctan2(d[:, 1], d[:, 0])
    return float(np.sum(np.abs((np.diff(a) + np.pi) % (2 * np.pi) - np.pi)))


# ----------------------------------------------------------------------------------------------------------------
# visibility graph
# ----------------------------------------------------------------------------------------------------------------
def free_region(
    env: Any, margin: float, tolerance: float = SIMPLIFY_TOLERANCE, *, outward: bool = False
) -> BaseGeometry:
    """The free space eroded by ``margin + tolerance`` and simplified with ``tolerance`` (⊂ free eroded by margin);
    with ``outward``, grown by ``tolerance`` and simplified instead (⊇ free: its shortest paths bound from below)."""
    if outward:
        region = env.free.buffer(tolerance, quad_segs=QUAD_SEGS).simplify(tolerance, preserve_topology=True)
        return shapely.make_valid(region) if not region.is_valid else region
    region = env.free.buffer(-(margin + tolerance), quad_segs=QUAD_SEGS)
    if tolerance > 0 and not region.is_empty:
        region = region.simplify(tolerance, preserve_topology=True)
    return shapely.make_valid(region) if not region.is_valid else region


def _reflex_vertices(region: BaseGeometry) -> tuple[Array, Array, Array]:
    """Reflex vertices of the region (its boundary turns away from the interior) with their ring neighbours."""
    pts, prev, nxt = [], [], []
    for poly in shapely.get_parts(region):
        if poly.geom_type != "Polygon" or poly.is_empty:
            continue
        poly = shapely.geometry.polygon.orient(poly, sign=1.0)  # exterior CCW, holes CW: interior on the left
        for ring in (poly.exterior, *poly.interiors):
            c = np.asarray(ring.coords)[:-1]
            if len(c) < 3:
                continue
            a, b = np.roll(c, 1, axis=0), np.roll(c, -1, axis=0)
            e1, e2 = c - a, b - c
            cross = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
            keep = cross < -1e-12  # a right turn with the interior on the left: a reflex vertex
            pts.append(c[keep])
            prev.append(a[keep])
            nxt.append(b[keep])
    if not pts:
        z = np.zeros((0, 2))
        return z, z, z
    return np.vstack(pts), np.vstack(prev), np.vstack(nxt)


def _cross(u: Array, v: Array) -> Array:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _tangent_at(p: Array, q: Array, a: Array, b: Array) -> NDArray[np.bool_]:
    """Whether the line p→q is tangent to the boundary at p (neighbours a, b of p on one side of it)."""
    d = q - p
    sa, sb = _cross(d, a - p), _cross(d, b - p)
    scale = np.linalg.norm(d, axis=-1) * 1e-9
    return (sa >= -scale) & (sb >= -scale) | (sa <= scale) & (sb <= scale)


def _visible(test: BaseGeometry, a: Array, b: Array) -> NDArray[np.bool_]:
    if len(a) == 0:
        return np.zeros(0, dtype=bool)
    return shapely.covers(test, shapely.linestrings(np.stack([a, b], axis=1)))


def shortest_path_tree(
    n: int, src: NDArray[np.intp], dst: NDArray[np.intp], w: Array, source: int, target: int
) -> list[int] | None:
    """Dijkstra (binary heap) on the undirected graph of ``n`` nodes and edges src–dst of lengths ``w`` ≥ 0 [m],
    stopped when ``target`` is settled: the predecessor of every settled node (−1 for none), or None if
    ``target`` is unreachable.

    Written here rather than taken from ``scipy.sparse.csgraph``: importing that takes 0.2–0.3 s of the 1 s a
    refusal may take (``benchmarks/results/random_rooms.md``), for a graph of a few hundred to a few thousand
    nodes; ``tests/test_route.py`` checks it against ``scipy.sparse.csgraph.dijkstra``.
    """
    u = np.concatenate([src, dst])
    v = np.concatenate([dst, src])
    length = np.concatenate([w, w])
    order = np.argsort(u, kind="stable")
    start = np.searchsorted(u[order], np.arange(n + 1)).tolist()
    nbr, cost = v[order].tolist(), length[order].tolist()
    dist = [math.inf] * n
    pred = [-1] * n
    dist[source] = 0.0
    heap = [(0.0, source)]
    while heap:
        d, x = heapq.heappop(heap)
        if d > dist[x]:
            continue
        if x == target:
            return pred
        for e in range(start[x], start[x + 1]):
            y, nd = nbr[e], d + cost[e]
            if nd < dist[y]:
                dist[y] = nd
                pred[y] = x
                heapq.heappush(heap, (nd, y))
    return None


class _Graph:
    """Visibility graph of one eroded free region with the anchor and the goal as extra nodes."""

    def __init__(self, env: Any, margin: float, outward: bool = False) -> None:
        self.margin = margin
        self.region = free_region(env, margin, outward=outward)
        self.test = self.region.buffer(1e-7, quad_segs=1)  # grazing along the boundary counts as free
        shapely.prepare(self.test)
        self.env = env
        self.V, self.Va, self.Vb = _reflex_vertices(self.region)
        n = len(self.V)
        i, j = np.triu_indices(n, 1)
        ok = _tangent_at(self.V[i], self.V[j], self.Va[i], self.Vb[i]) & _tangent_at(
            self.V[j], self.V[i], self.Va[j], self.Vb[j]
        )
        i, j = i[ok], j[ok]
        vis = _visible(self.test, self.V[i], self.V[j])
        self.i, self.j = i[vis], j[vis]

    def _endpoint_edges(self, p: Array) -> tuple[Array, NDArray[np.bool_]]:
        """Vertices visible from the free point p (tangent at the vertex end)."""
        n = len(self.V)
        P = np.repeat(p[None], n, axis=0)
        ok = _tangent_at(self.V, P, self.Va, self.Vb)
        idx = np.flatnonzero(ok)
        inside = bool(shapely.covers(self.test, shapely.points(p)))
        if inside:
            vis = _visible(self.test, P[idx], self.V[idx])
        else:  # the point itself is nearer than δ to an obstacle: its own edges need clearance > 0 only
            vis = np.asarray(self.env.segment_clearance(P[idx], self.V[idx]), float) > 0.0
        return idx[vis], np.array(inside)

    def shortest(self, base: Array, goal: Array) -> Array | None:
        """Shortest polyline base → goal in the graph, or None."""
        n = len(self.V)
        direct = _visible(self.test, base[None], goal[None])[0] or (
            float(np.asarray(self.env.segment_clearance(base, goal))) > self.margin
        )
        if direct:
            return np.vstack([base, goal])
        eb, _ = self._endpoint_edges(base)
        eg, _ = self._endpoint_edges(goal)
        nodes = np.vstack([self.V, base, goal])
        src = np.concatenate([self.i, np.full(len(eb), n), np.full(len(eg), n + 1)])
        dst = np.concatenate([self.j, eb, eg])
        w = np.linalg.norm(nodes[src] - nodes[dst], axis=1)
        pred = shortest_path_tree(n + 2, src, dst, w, n, n + 1)
        if pred is None:
            return None
        path = [n + 1]
        while path[-1] != n:
            path.append(int(pred[path[-1]]))
        return nodes[path[::-1]]

    @property
    def edges(self) -> int:
        return int(len(self.i))


# ----------------------------------------------------------------------------------------------------------------
# stations
# ----------------------------------------------------------------------------------------------------------------
def hole_points(env: Any) -> Array:
    """One point inside each hole of the free space (an obstacle a closed loop of free space can go round)."""
    pts = []
    for poly in shapely.get_parts(env.free):
        for ring in getattr(poly, "interiors", ()):
            pts.append(np.asarray(shapely.Polygon(ring).representative_point().coords[0]))
    return np.array(pts).reshape(-1, 2)


def _ray_crossings(h: Array, a: Array, b: Array) -> NDArray[np.int_]:
    """Whether the ray from each point h (H, 2) towards +x crosses each segment a→b (..., 2): shape (..., H)."""
    a, b = a[..., None, :], b[..., None, :]
    ay, by = a[..., 1], b[..., 1]
    straddle = (ay > h[:, 1]) != (by > h[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = a[..., 0] + (h[:, 1] - ay) * (b[..., 0] - a[..., 0]) / (by - ay)
    return (straddle & (x > h[:, 0])).astype(np.int_)


#: Offsets [m] of the candidate stations off a bend of the route, along its outward bisector.
BEND_OFFSETS = (0.1, 0.25, 0.5, 0.8, 1.2, 1.8)
#: Cumulative turning [rad] of the route between two bends that get offset candidates.
BEND_TURN = math.radians(12.0)
#: Offsets [m] of the candidate stations to either side of the route, every ``LATERAL_EVERY`` [m] along it (a chain
#: that swings wide of the route can pass a wall's end with fewer robots).
LATERAL_OFFSETS = (0.5, 1.2, 2.0)
LATERAL_EVERY = 0.5


def bend_offsets(
    env: Any, guide: Array, arcs: Array, start_arc: float = 0.0, offsets: tuple[float, ...] = BEND_OFFSETS
) -> tuple[NDArray[np.intp], Array]:
    """Points off the bends of ``guide`` (one bend every ``BEND_TURN`` of accumulated turning, after ``start_arc``
    [m]) along the outward bisector (towards the larger clearance) at ``offsets`` [m]: where a taut tether wraps an
    obstacle the robot sits there, and round a wall's end a chain needs them to turn. Returns the bend vertex of
    each point (k,) and the points (k, 2); the points are not checked for clearance."""
    d = np.diff(guide, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi)
    vs: list[int] = []
    pts: list[Array] = []
    acc = 0.0
    for v in range(1, len(guide) - 1):
        acc += turn[v - 1]
        if acc < BEND_TURN and v < len(guide) - 2:
            continue
        acc = 0.0
        if arcs[v] <= start_arc:
            continue
        u = (guide[v - 1] - guide[v]) / max(np.linalg.norm(guide[v - 1] - guide[v]), 1e-12) + (
            guide[v + 1] - guide[v]
        ) / max(np.linalg.norm(guide[v + 1] - guide[v]), 1e-12)
        if np.linalg.norm(u) < 1e-9:
            continue
        u /= np.linalg.norm(u)
        probe = np.asarray(env.exact_clearance(np.array([guide[v] + 0.2 * u, guide[v] - 0.2 * u])), float)
        if probe[1] > probe[0]:
            u = -u
        for off in offsets:
            vs.append(v)
            pts.append(guide[v] + off * u)
    return np.array(vs, dtype=np.intp), np.array(pts).reshape(-1, 2)


class _Samples:
    """Candidate stations: guide points every ``step`` and its vertices (offset 0), and points off the guide's
    bends along their outward bisector (where a taut tether wraps a round obstacle, the robot sits off the route).

    Each candidate has a *foot*: the guide sample it hangs from (itself on the guide). ``arc`` is the foot's arc
    length, the order of progress along the guide.
    """

    def __init__(self, env: Any, guide: Array, step: float, start_arc: float = 0.0) -> None:
        arcs = guide_arcs(guide)
        L = float(arcs[-1])
        n = max(2, math.ceil((L - start_arc) / step) + 1)
        s = np.union1d(np.linspace(start_arc, L, n), arcs[(arcs > start_arc) & (arcs < L)])
        R = point_at(guide, arcs, s)
        self.holes = hole_points(env)
        H = len(self.holes)
        # parity of the crossings of the +x ray from every hole with the guide up to each guide sample
        if H:
            c = _ray_crossings(self.holes, R[:-1], R[1:])
            route_par = np.vstack([np.zeros((1, H), np.int_), np.cumsum(c, axis=0)]) % 2
        else:
            route_par = np.zeros((len(s), 0), np.int_)
        # bends: interior guide vertices, one every BEND_TURN of accumulated turning
        d = np.diff(guide, axis=0)
        vs, pts_b = bend_offsets(env, guide, arcs, start_arc)
        feet = np.minimum(np.searchsorted(s, arcs[vs]), len(s) - 1).tolist()
        pts = list(pts_b)
        seg = np.clip(np.searchsorted(arcs, s, side="right") - 1, 0, len(guide) - 2)
        tangent = d[seg] / np.maximum(np.linalg.norm(d[seg], axis=1, keepdims=True), 1e-12)
        normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
        every = max(1, round(LATERAL_EVERY / max(step, 1e-9)))
        for f in range(every, len(s) - 1, every):
            for off in LATERAL_OFFSETS:
                for sign in (1.0, -1.0):
                    feet.append(f)
                    pts.append(R[f] + sign * off * normal[f])
        n_route = len(s)
        if pts:
            Q = np.array(pts)
            F = np.array(feet)
            ok = np.asarray(env.exact_clearance(Q), float) > CHORD_CLEARANCE
            ok &= env.segment_is_free(R[F], Q, CHORD_CLEARANCE)
            Q, F = Q[ok], F[ok]
        else:
            Q, F = np.zeros((0, 2)), np.zeros(0, np.intp)
        # candidates: guide samples, then offsets; goal (the last guide sample) moved to the end
        self.P = np.vstack([R[:-1], Q, R[-1:]])
        self.foot = np.concatenate([np.arange(n_route - 1), F, [n_route - 1]]).astype(np.intp)
        self.arc = s[self.foot]
        self.off = np.linalg.norm(self.P - R[self.foot], axis=1)  # 0 on the guide
        off_par = _ray_crossings(self.holes, R[F], Q) if H and len(Q) else np.zeros((len(Q), H), np.int_)
        self.off_par = np.vstack([np.zeros((n_route - 1, H), np.int_), off_par, np.zeros((1, H), np.int_)])
        self.route_par = route_par
        self.s = self.arc

    def homotopic(self, i: int, js: NDArray[np.int_]) -> NDArray[np.bool_]:
        """Chords i→j that enclose no hole together with the guide between their feet (and the offsets)."""
        if not len(self.holes):
            return np.ones(len(js), dtype=bool)
        chord = _ray_crossings(self.holes, np.repeat(self.P[i : i + 1], len(js), 0), self.P[js])  # (m, H)
        loop = self.route_par[self.foot[js]] - self.route_par[self.foot[i]] + self.off_par[js] + self.off_par[i] + chord
        return ~np.any(loop % 2 == 1, axis=1)


def anchor_tether_clearance(env: Any, anchor: Array, clearance: float) -> float:
    """Clearance [m] the anchor's own tether must keep: ``clearance``, or half the anchor's own clearance if that is
    less (an anchor next to a wall)."""
    return min(clearance, 0.5 * float(np.asarray(env.exact_clearance(anchor))))


def stations(
    env: Any,
    guide: Array,
    span_max: ArrayLike,
    span_min: ArrayLike | None = None,
    *,
    start_arc: float = 0.0,
    step: float = STATION_STEP,
    clearance: float = CHORD_CLEARANCE,
) -> tuple[Array, Array]:
    """Arc lengths of the fewest stations along ``guide`` (from arc ``start_arc`` to the guide's end, the goal).

    Breadth-first search over candidate stations (every ``step`` [m] and every guide vertex): a tether k joins two
    candidates if its straight chord is between ``span_min[k]`` and ``span_max[k]`` long (the last value repeats),
    keeps clearance > ``clearance`` [m] from the obstacles grown by r (exact: ``env.segment_is_free``; the anchor's
    own tether: half the anchor's clearance if that is less) and is homotopic to the guide (the chord and the
    guide between its ends enclose no obstacle: parity of the crossings of a ray from every hole). Returns the
    arcs (n,) and positions (n, 2) of the stations after the start, the last one the goal: the fewest hops at this
    resolution. Raises :class:`BlockedRouteError` if no chain reaches the goal.
    """
    smax = np.atleast_1d(np.asarray(span_max, float))
    smin = np.atleast_1d(np.asarray(span_min, float)) if span_min is not None else np.zeros(1)
    sm = _Samples(env, guide, step, start_arc)
    P, n = sm.P, len(sm.s)
    first = anchor_tether_clearance(env, P[0], clearance)
    parent = np.full(n, -1)
    seen = np.zeros(n, dtype=bool)
    seen[0] = True
    frontier = [0]
    hop = 0
    while frontier and not seen[-1]:
        dmax, dmin = smax[min(hop, len(smax) - 1)], smin[min(hop, len(smin) - 1)]
        nxt: list[int] = []
        # on-guide stations first, then farther along: they become the parents (a chain along the route rather
        # than one zig-zagging between offsets)
        for i in sorted(frontier, key=lambda i: (sm.off[i] > 1e-9, -sm.arc[i], -i)):
            js = np.flatnonzero(~seen)
            js = js[sm.arc[js] > sm.arc[i]]
            if not len(js):
                continue
            d = np.linalg.norm(P[js] - P[i], axis=1)
            js = js[(d <= dmax) & (d >= dmin)]
            if not len(js):
                continue
            js = js[env.segment_is_free(np.repeat(P[i : i + 1], len(js), 0), P[js], clearance if i else first)]
            js = js[sm.homotopic(i, js)] if len(js) else js
            if len(js):
                parent[js] = i
                seen[js] = True
                nxt.extend(js.tolist())
        frontier = nxt
        hop += 1
    if not seen[-1]:
        far = int(np.argmax(np.where(seen, sm.arc, -np.inf)))
        where = _xy(point_at(guide, guide_arcs(guide), sm.arc[far]))
        raise BlockedRouteError(
            f"no chain of straight tethers of ≤ {smax.max():.2f} m keeping {clearance:.2f} m from the obstacles "
            f"follows the route past {where} ({sm.arc[far]:.1f} m of {sm.arc[-1]:.1f} m): a passage too "
            "narrow or a corner too sharp for the tethers"
        )
    path = [n - 1]
    while path[-1] != 0:
        path.append(int(parent[path[-1]]))
    path = path[::-1]
    return sm.arc[path[1:]], sm.P[path[1:]]


# ----------------------------------------------------------------------------------------------------------------
# the route
# ----------------------------------------------------------------------------------------------------------------
def _xy(p: Array) -> str:
    return f"({p[0]:.4g}, {p[1]:.4g})"


def _check_point(env: Any, p: ArrayLike, name: str) -> Array:
    try:
        a = np.asarray(p, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be an (x, y) position in metres, got {p!r}") from exc
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be a finite (x, y) position in metres, got {p!r}")
    xmin, ymin, xmax, ymax = env.bounds
    if not (xmin <= a[0] <= xmax and ymin <= a[1] <= ymax):
        raise NoRouteError(f"the {name} {_xy(a)} is outside the room {tuple(env.bounds)}")
    c = float(np.asarray(env.exact_clearance(a)))
    if c <= 0:
        raise NoRouteError(
            f"the {name} {_xy(a)} is inside an obstacle grown by the safety radius "
            f"{env.safety_radius:g} m (clearance {c:.3f} m)"
        )
    return a


def _same_component(env: Any, a: Array, b: Array) -> bool:
    ra, rb = env.free_region(np.array([a, b]))
    return bool(ra >= 0 and ra == rb)


#: Slack s [m] of :func:`packing_bound`: a plan that passes the checks keeps its robots within s of the free space and
#: at least 2r − s apart (the checks' tolerance, :func:`tmr.checks.metrics.evaluate`, is 1e-6 m; s also absorbs
#: rounding).
PACKING_SLACK = 1e-3


class Packing(NamedTuple):
    """An upper bound on how many robots fit in the free space at once (:func:`packing_bound`).

    Attributes:
        n_max: no more than this many robots fit.
        area: the area [m²] the robots' discs can cover: the free space reachable from the anchor grown back by r
            (the room's floor minus the obstacles, less the gaps too narrow for a robot).
        by: ``"area"`` (disjoint discs) or ``"hexagonal"`` (Oler's bound on the convex hull), whichever is lower.
    """

    n_max: int
    area: float
    by: str


def packing_bound(env: Any, base: ArrayLike) -> Packing:
    """How many robots of radius r can stand at once in the free space the anchor ``base`` reaches: a proof, not a
    search (a few milliseconds).

    Every robot of a plan that passes the checks stands in the free space F (the room eroded by r minus the
    obstacles grown by r, ``env.free``) and keeps 2r from every other robot, both up to the slack s
    (``PACKING_SLACK``); its tether chain joins it to the anchor inside F, so it lies in the connected piece F_a
    of F ⊕ s that holds the anchor. With ρ = r − s/2 and d = 2r − s, the minimum of two bounds:

    * area: the open discs of radius ρ round the robots are disjoint and lie in F_a ⊕ (r + s/2), so
      N π ρ² ≤ area(F_a ⊕ (r + s/2)); the buffer is taken with radius (r + s/2) / cos(π/64) so that its polygon
      (16 segments per quarter circle, vertices on the circle) contains the round one;
    * hexagonal (Oler 1961, "An inequality in the geometry of numbers", Acta Math. 105): points pairwise ≥ d apart
      in a compact convex set K number at most 2/√3 · A(K)/d² + P(K)/(2d) + 1; K = the convex hull of F_a.
    """
    r = float(env.safety_radius)
    s = PACKING_SLACK
    p = shapely.Point(np.asarray(base, dtype=float))
    parts = [g for g in shapely.get_parts(env.free.buffer(s, quad_segs=QUAD_SEGS)) if g.covers(p)]
    piece = parts[0] if parts else env.free.buffer(s, quad_segs=QUAD_SEGS)  # the anchor is in F (checked before)
    rho, d = r - s / 2, 2 * r - s
    area = float(piece.buffer((r + s / 2) / math.cos(math.pi / 64), quad_segs=16).area)
    by_area = math.floor(area / (math.pi * rho * rho) + 1e-9)
    hull = piece.convex_hull
    by_hex = math.floor(2 / math.sqrt(3) * hull.area / (d * d) + hull.length / (2 * d) + 1 + 1e-9)
    return Packing(min(by_area, by_hex), area, "area" if by_area <= by_hex else "hexagonal")


def check_fit(env: Any, base: ArrayLike, robots: int) -> None:
    """:class:`TooManyRobotsError` if ``robots`` robots cannot stand in the free space at once
    (:func:`packing_bound`), naming how many may."""
    fit = packing_bound(env, base)
    if robots <= fit.n_max:
        return
    r = float(env.safety_radius)
    how = (
        f"each robot covers πr² = {math.pi * r * r:.3f} m²"
        if fit.by == "area"
        else f"robots {2 * r:g} m apart pack at best hexagonally"
    )
    bound = f"at most {fit.n_max} robots of radius {r:g} m fit in the free area ({fit.area:.1f} m² reachable from "
    bound += f"the anchor; {how})"
    raise TooManyRobotsError(
        f"{robots} robots do not fit: {bound}; rerun with --robots {fit.n_max} or fewer", fit.n_max
    )


def plan_route(
    env: Any,
    base: ArrayLike,
    goal: ArrayLike,
    span_limits: ArrayLike,
    *,
    margin: float = ROUTE_MARGIN,
    robots: int | None = None,
    fewest: bool = True,
) -> Route:
    """Shortest free route from the anchor ``base`` to ``goal`` and the robots it needs (module docstring).

    Args:
        env: :class:`tmr.world.environment.Environment` (``free``, ``inflated``, ``bounds``, exact clearance queries).
        base, goal: (2,) positions [m].
        span_limits: (N, 2) [d_lo, d_max] per tether [m] (the first row is the anchor tether), or (2,) for all.
        margin: δ [m] the route keeps from the obstacles grown by r; smaller margins are tried in narrow passages.
        robots: the chain's N, if known: refused first if more than fit in the free space (:func:`check_fit`); when
            the route at ``margin`` needs more robots than that, the routes with the smaller margins (δ/2,
            ``NARROW_MARGIN``, then ``RETRY_MARGIN``: through narrower passages, often shorter) are tried too and the
            one needing the fewest robots is returned, unless N is first proven too few round the corners
            (:mod:`tmr.route.reach`). Without it, ``n_lower`` is raised to ``n_min`` when N_min − 1 robots are
            proven too few.
        fewest: search for the fewest robots (the corner proof, the chain off the route, :func:`tight_chain`);
            False: the route and its station chain only (``n_lower`` by length, ``n_min`` = ``n_route``), for callers
            that only follow the route (start placements try many).

    Raises:
        NoRouteError: base or goal outside the room or in an obstacle, or in different pieces of free space.
        TooManyRobotsError: ``robots`` more than fit in the free space at once (:func:`check_fit`), before any
            search.
    """
    t0 = time.perf_counter()
    base = _check_point(env, base, "anchor")
    goal = _check_point(env, goal, "goal")
    lim = np.atleast_2d(np.asarray(span_limits, dtype=float))
    if lim.shape[1] != 2 or np.any(~np.isfinite(lim)) or np.any(lim[:, 0] >= lim[:, 1]):
        raise ParameterError(f"span_limits must be rows [d_lo, d_max] with d_lo < d_max, got {lim.tolist()}")
    if float(np.linalg.norm(goal - base)) < 1e-9:
        raise ParameterError(f"the anchor and the goal coincide at {_xy(base)}: there is no route to plan")
    if not _same_component(env, base, goal):
        raise NoRouteError(
            f"no free route from the anchor {_xy(base)} to the goal {_xy(goal)}: the "
            f"obstacles grown by the safety radius {env.safety_radius:g} m separate them"
        )
    if robots is not None:  # before any search: more robots than fit in the room at once (a proof, milliseconds)
        check_fit(env, base, robots)
    # lower bound: the shortest path in a region that contains the free space (grown by t, then simplified)
    lower = _Graph(env, 0.0, outward=True).shortest(base, goal)
    L_lower = float(guide_arcs(lower)[-1]) if lower is not None else 0.0
    d_max = float(lim[:, 1].max())
    ladder = [m for m in dict.fromkeys((margin, margin / 2, NARROW_MARGIN)) if m >= min(margin, NARROW_MARGIN)]
    ladder += [RETRY_MARGIN] if RETRY_MARGIN < ladder[-1] else []
    best: _Along | None = None
    n_lower, lower_by = 0, "length"
    for m in ladder:
        if best is not None and not (robots is not None and best.n_min > robots >= n_lower):
            break
        if best is None and m == RETRY_MARGIN:  # a retry only: no route keeps NARROW_MARGIN
            break
        try:
            found = _along(env, base, goal, lim, m, L_lower)
        except RouteVerdict:
            if best is None:
                raise
            continue
        if found is None:
            continue
        if best is None:
            n_lower = _length_bound(L_lower, found.length, d_max)
            # corners: a proof that the chain given cannot reach the goal saves retrying narrower routes
            if (
                fewest
                and robots is not None
                and n_lower <= robots < found.n_min
                and proven_too_few(env, base, goal, lim, robots)
            ):
                n_lower, lower_by = robots + 1, "corners"
        if best is None or found.n_min < best.n_min:
            best = found
    if best is None:
        raise BlockedRouteError(
            f"no route from the anchor {_xy(base)} to the goal {_xy(goal)} keeps {NARROW_MARGIN:g} m from the "
            f"obstacles grown by {env.safety_radius:g} m: a passage is too narrow for the chain"
        )
    n_min = max(best.n_min, n_lower)
    if fewest and robots is None and n_lower < n_min and proven_too_few(env, base, goal, lim, n_min - 1):
        n_lower, lower_by = n_min, "corners"
    notes = [f"route margin lowered to {best.margin:.3f} m in a narrow passage"] if best.margin < margin else []
    n_route = n_min
    witness = None
    if fewest and n_lower < n_min and (robots is None or robots >= n_lower):
        # fewer robots than the route chain needs: a chain anywhere in the free space (the same search whatever N;
        # none for an N already proven too few: its refusal stands, and names the route's count)
        witness = _witness(env, base, goal, lim, n_min - 1, n_lower)
        if witness is not None:
            n_min = max(len(witness) - 1, n_lower)  # a real chain: never below a sound proof
    tight = None
    if fewest and robots is not None and n_lower <= robots < n_min:
        # not proven too few: the wider search for a chain merely clear of the obstacles, which names the clearance
        # as what stops the plan, or, widened, may keep the clearances after all (then it is the witness)
        found = clear_chain(env, base, goal, lim, robots)
        tight = None if found is None else _shortfall(env, base, lim, *found)
        if found is not None and tight is None:
            witness = found[0]
            n_min = max(len(witness) - 1, n_lower)
    if witness is not None and robots is not None and n_min <= robots < n_route:  # plan along it: the guide
        best = _witness_along(witness, best)
        notes.append(
            f"no chain of {robots} robots along the shortest route ({n_route} needed there): the guide is a "
            f"chain of {n_min} found off it"
        )
    return Route(
        points=best.points,
        length=best.length,
        margin=float(best.margin),
        d_max=d_max,
        d_max_first=float(lim[0, 1]),
        turning=_turning(best.points),
        n_lower=int(n_lower),
        n_min=int(n_min),
        lower_length=min(L_lower, best.length),
        lower_by=lower_by,
        n_route=int(n_route),
        stations=best.stations,
        station_arcs=best.arcs,
        vertices=best.vertices,
        edges=best.edges,
        time=time.perf_counter() - t0,
        notes=tuple(notes),
        tight_chain=tight,
    )


def _length_bound(L_lower: float, L: float, d_max: float) -> int:
    """⌈L_lower / d_max⌉ (L_lower ≤ L, the route's length, up to rounding)."""
    return max(1, math.ceil(min(L_lower, L) / d_max - 1e-9))


def proven_too_few(env: Any, base: ArrayLike, goal: ArrayLike, lim: ArrayLike, robots: int) -> bool:
    """Whether ``robots`` robots are proven too few to chain from ``base`` to ``goal`` with the tethers' upper limits
    of ``lim`` (N, 2) [m]: :func:`tmr.route.reach.chain_is_impossible` with the refinement and narrowing budgets the
    route
    uses (``REFINE_WORK``, ``NARROW_WORK``)."""
    from tmr.route.reach import NARROW_WORK, REFINE_WORK, chain_is_impossible

    return robots >= 1 and chain_is_impossible(
        env, base, goal, np.asarray(lim, float)[:, 1], robots, refine_work=REFINE_WORK, narrow_work=NARROW_WORK
    )


def _witness_requirements(env: Any, base: Array, lim: Array) -> tuple[float, Array, float]:
    """What a chain off the route must keep, as the stations do: the anchor tether's clearance [m], the span rows
    [d_lo + ``SPACING_MARGIN``, d_max] of ``lim`` (N, 2), and the robots' spacing 2r + ``SPACING_MARGIN`` [m]."""
    first = anchor_tether_clearance(env, base, CHORD_CLEARANCE)
    spans = np.column_stack([lim[:, 0] + SPACING_MARGIN, lim[:, 1]])
    return first, spans, 2 * env.safety_radius + SPACING_MARGIN


def _witness(env: Any, base: Array, goal: Array, lim: Array, robots: int, n_lower: int) -> Array | None:
    """A chain of at most ``robots`` robots keeping the stations' clearance and spacing: 2 robots by the grid
    search of :func:`best_pair` when no proof rules them out, else :func:`tmr.route.reach.find_chain`; then, for one
    robot
    fewer than it found (or ``robots`` if it found none), a chain searched with the obstacles grown less
    (:data:`WIDEN_RELAX`) and widened to the clearances (:func:`_widened`)."""
    from tmr.route.reach import find_chain

    first, spans, spacing = _witness_requirements(env, base, lim)
    if robots >= 2 and n_lower <= 2:
        pair = best_pair(env, base, goal, spans, spacing, (first, CHORD_CLEARANCE))
        if pair is not None and pair[1] > 0:
            return np.array([base, pair[0], goal])
    chain = find_chain(env, base, goal, spans, robots, CHORD_CLEARANCE, first, spacing=spacing, at_least=n_lower)
    fewer = robots if chain is None else len(chain) - 2
    if fewer >= max(n_lower, 3):
        wide = _widened(env, base, goal, spans, spacing, _needs(first, fewer), fewer, n_lower)
        if wide is not None and wide.margin > 0:
            return wide.chain
    return chain


#: [m] the obstacles are grown by r − δ, δ in turn each of these, for the search that seeds
#: :func:`tmr.route.chain_clearance.widen_chain`: its chords may pass up to δ into the grown obstacles, and the widening
#: moves them out (a larger δ finds chains in other homotopies, which may or may not widen).
WIDEN_RELAX = (0.1, 0.15, 0.2)


def _needs(first: float, robots: int, clearance: float = CHORD_CLEARANCE) -> Array:
    """The clearance [m] each tether of a chain of ``robots`` must keep: ``first`` for the anchor's."""
    need = np.full(robots, clearance)
    need[0] = min(first, clearance)
    return need


def _widened(
    env: Any, base: Array, goal: Array, spans: Array, spacing: float, need: Array, robots: int, at_least: int
) -> Any:
    """A chain of ``robots`` robots widened to ``need`` (:func:`tmr.route.chain_clearance.widen_chain`), from a chain of
    at most that many found with the obstacles grown by r − δ (δ in :data:`WIDEN_RELAX` until one keeps ``need``;
    the chain with its own count first, then padded to ``robots``); the widest tried, or None if the relaxed searches
    find none."""
    from tmr.route.chain_clearance import pad_chain, widen_chain
    from tmr.route.reach import find_chain

    best = None
    for delta in WIDEN_RELAX:
        relaxed = env.with_safety_radius(max(env.safety_radius - delta, 0.0))
        seed = find_chain(relaxed, base, goal, spans, robots, 0.0, 0.0, spacing=spacing, at_least=at_least)
        if seed is None:
            continue
        for n in dict.fromkeys((len(seed) - 1, robots)):
            wide = widen_chain(env, pad_chain(seed, n), spans, spacing, need[:n])
            if wide is not None and (best is None or wide.margin > best.margin):
                best = wide
            if best is not None and best.margin > 0:
                return best
    return best


#: Spacing [m] of the sample points of robot 1 in :func:`best_pair`, and the most samples it takes (a larger region
#: is sampled more coarsely: a wide one needs no fine search).
PAIR_STEP = 0.02
PAIR_SAMPLES = 20_000


def best_pair(
    env: Any, base: Array, goal: Array, spans: Array, spacing: float, keep: tuple[float, float] = (0.0, 0.0)
) -> tuple[Array, float, float] | None:
    """Robot 1 of a 2-robot chain, searched where it can be: the intersection of the anchor's and the goal's visible
    regions (:meth:`Environment.visible_region`, radii the span limits), sampled on a grid of :data:`PAIR_STEP` [m]
    (coarser if that would exceed :data:`PAIR_SAMPLES` points over its bounding box) and kept within ``spans``
    (rows [d_lo, d_max] of the anchor's tether and the next) and ``spacing`` [m] from the goal.

    Returns the sample p whose chords do best against the clearances ``keep`` (anchor chord, goal chord) [m], its
    score min(clearance(anchor, p) − keep[0], clearance(p, goal) − keep[1]) [m] (> 0: both chords keep them) and the
    grid step [m]; None if no sample qualifies. A search on a grid, not a proof: a point between samples may do
    better.
    """
    lo, hi = spans[0], spans[min(1, len(spans) - 1)]
    both = env.visible_region(base, lo[1]).intersection(env.visible_region(goal, hi[1]))
    if both.is_empty:
        return None
    x0, y0, x1, y1 = both.bounds
    step = max(PAIR_STEP, math.sqrt((x1 - x0 + PAIR_STEP) * (y1 - y0 + PAIR_STEP) / PAIR_SAMPLES))
    xs, ys = np.meshgrid(np.arange(x0, x1 + step, step), np.arange(y0, y1 + step, step))
    P = np.stack([xs.ravel(), ys.ravel()], axis=1)
    P = P[shapely.contains_xy(both, P[:, 0], P[:, 1])]
    da, dg = np.linalg.norm(P - base, axis=1), np.linalg.norm(P - goal, axis=1)
    P = P[(da >= lo[0]) & (da <= lo[1]) & (dg >= max(hi[0], spacing)) & (dg <= hi[1])]
    if not len(P):
        return None
    score = np.minimum(env.segment_clearance(base, P) - keep[0], env.segment_clearance(P, goal) - keep[1])
    i = int(np.argmax(score))
    return P[i], float(score[i]), step


#: Width of the fine search of :func:`tight_chain` (twice the witness search's: it runs only for a verdict in the
#: band, where a closer chain found names the clearance instead of leaving the count undecided).
TIGHT_BEAM = 80
#: Width of its last resort, when neither that search nor the widening of a nearer chain finds one: 5× wider, about
#: 2 s. narrow-corner-2929554679 with 5 robots: a chain round the other side of two walls from the route, through
#: two doors its widening leaves 0.036 m clear, which the narrower beams (ordered by the distance to the goal through
#: the route's doors) miss.
WIDE_BEAM = 400


class TightChain(NamedTuple):
    """A chain that meets every requirement of the stations but the clearance of one tether (:func:`tight_chain`)."""

    robots: int  #: its robots (≤ the N asked)
    clearance: float  #: clearance [m] of its tether with the largest shortfall
    needed: float  #: what the stations need of that tether [m]: ``CHORD_CLEARANCE``, or less for the anchor's
    searched: str  #: how it was found, for the verdict: "the best on a 0.02 m grid" (2 robots), "the widest found"


def tight_chain(env: Any, base: Array, goal: Array, lim: Array, robots: int) -> TightChain | None:
    """A chain of at most ``robots`` robots that meets every requirement of the stations and of :func:`_witness`
    except the clearance of its tethers, which are merely clear of the grown obstacles (:func:`clear_chain`); None
    if none was found, or if the one found keeps the clearances too (then it is a witness, which
    :func:`plan_route` plans along). Such a chain shows that the count is not what stops the plan: N is at least the
    fewest robots of the problem's definition (chords clear of the grown obstacles), and only the clearance the
    plans keep takes more."""
    found = clear_chain(env, base, goal, lim, robots)
    return None if found is None else _shortfall(env, base, lim, *found)


def _shortfall(env: Any, base: Array, lim: Array, chain: Array, searched: str) -> TightChain | None:
    """The tether of ``chain`` that falls shortest of what the stations need of it, or None if none falls short."""
    first = _witness_requirements(env, base, lim)[0]
    c = np.asarray(env.segment_clearance(chain[:-1], chain[1:]), float)
    need = _needs(first, len(c))
    k = int(np.argmin(c - need))
    if c[k] > need[k]:  # no shortfall: a witness, no explanation
        return None
    return TightChain(len(chain) - 1, float(c[k]), float(need[k]), searched)


def clear_chain(env: Any, base: Array, goal: Array, lim: Array, robots: int) -> tuple[Array, str] | None:
    """A chain (n + 1, 2) of n ≤ ``robots`` robots from ``base`` to ``goal`` with the stations' spans (in
    [d_lo + ``SPACING_MARGIN``, d_max] of ``lim`` (N, 2)) and spacing (2r + ``SPACING_MARGIN``) whose every tether is
    clear of the grown obstacles (exact clearance > 0), and how it was found (for the verdict); None if none is
    found. A search, not a proof.

    2 robots: :func:`best_pair` (on its grid, the chain whose worse tether does best against what it needs); more:
    :func:`tmr.route.reach.find_chain` at zero clearance, or if it finds none, a chain found with the obstacles grown
    less
    (:data:`WIDEN_RELAX`) and widened until clear (:func:`_widened`), or last the fine search alone with the wider
    beam :data:`WIDE_BEAM`; then widened towards the clearances the plans keep
    (:func:`tmr.route.chain_clearance.widen_chain`: a local optimum, not the best; kept only if every tether stays
    clear).
    """
    from tmr.route.chain_clearance import widen_chain
    from tmr.route.reach import find_chain

    first, spans, spacing = _witness_requirements(env, base, lim)
    if robots == 2:
        pair = best_pair(env, base, goal, spans, spacing, (first, CHORD_CLEARANCE))
        if pair is None:
            return None
        chain = np.array([base, pair[0], goal])
        return (chain, f"the best on a {pair[2]:.2g} m grid") if _all_clear(env, chain) else None
    # clear by construction: find_chain's chords keep > 0, the widened one's margin over zero is > 0
    chain = find_chain(env, base, goal, spans, robots, 0.0, 0.0, spacing=spacing, beam=TIGHT_BEAM)
    if chain is None:  # one nearer still, widened until clear of the obstacles
        wide = _widened(env, base, goal, spans, spacing, np.zeros(robots), robots, 1)
        chain = wide.chain if wide is not None and wide.margin > 0 else None
    if chain is None:
        chain = find_chain(env, base, goal, spans, robots, 0.0, 0.0, spacing=spacing, at_least=robots, beam=WIDE_BEAM)
    if chain is None:
        return None
    wide = widen_chain(env, chain, spans, spacing, _needs(first, len(chain) - 1))
    if wide is not None and _all_clear(env, wide.chain):
        chain = wide.chain
    return chain, "the widest found"


def _all_clear(env: Any, chain: Array) -> bool:
    """Whether every tether of ``chain`` (n + 1, 2) is clear of the grown obstacles (exact clearance > 0)."""
    return bool(np.all(np.asarray(env.segment_clearance(chain[:-1], chain[1:])) > 0))


def _witness_along(chain: Array, route: _Along) -> _Along:
    """The witness chain as the guide: its polyline, stations at its robots."""
    arcs = guide_arcs(chain)
    return _Along(chain, float(arcs[-1]), CHORD_CLEARANCE, len(chain) - 1, chain[1:].copy(), arcs[1:], route.vertices,
                  route.edges)  # fmt: skip


@dataclass(frozen=True)
class _Along:
    """The route at one margin and its stations."""

    points: Array
    length: float
    margin: float
    n_min: int
    stations: Array
    arcs: Array
    vertices: int
    edges: int


def _along(env: Any, base: Array, goal: Array, lim: Array, margin: float, L_lower: float) -> _Along | None:
    """The shortest route keeping ``margin`` [m] and its station chain; None if no route keeps it."""
    graph = _Graph(env, margin)
    points = graph.shortest(base, goal)
    if points is None:
        return None
    points = _dedupe(points)
    L = float(guide_arcs(points)[-1])
    spacing_min = np.concatenate([lim[:1, 0], lim[1:, 0]]) + SPACING_MARGIN
    arcs, st = stations(env, points, lim[:, 1], spacing_min)
    st = st.copy()
    st[-1] = goal
    n_min = max(len(arcs), _length_bound(L_lower, L, float(lim[:, 1].max())))
    return _Along(points, L, float(margin), n_min, st, arcs, len(graph.V), graph.edges)


def _dedupe(points: Array) -> Array:
    keep = np.r_[True, np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9]
    out = points[keep]
    out[-1] = points[-1]
    return out
