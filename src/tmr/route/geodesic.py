"""Geometry of the tether-aware route: its parameters and verdicts (the errors that say why a goal is refused),
polylines, the visibility graph of the free space's reflex corners and its shortest-path tree, the holes a tether
may wrap, and the stations (candidate robot places) along a route. Used by :func:`tmr.route.route.plan_route`
(``formulations/route.md``), which re-exports the parameters and verdicts.

**Low obstacles** (``env.low_obstacles``): obstacles for the robots, not for the tethers. Every query about where a
robot or the leader may be or drive reads ``env`` (the route polyline, station and offset positions); every query
about a tether's plan-view chord (free, clearance, the holes it may wrap, the anchor tether's clearance) reads
:func:`tether_env` (``env.tether_environment``, the room without them). Relaxing the tethers' obstacles keeps every
lower bound of the route a proven lower bound; the per-step QP enforces the cable's height over a low obstacle.
"""

from __future__ import annotations

import heapq
import math
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from shapely.geometry.base import BaseGeometry

from tmr.errors import TmrError

Array = NDArray[np.float64]


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
        self.holes = hole_points(tether_env(env))  # the holes a chord may wrap: the tethers' world's
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


def tether_env(env: Any) -> Any:
    """The world of the tethers' plan-view chords: ``env.tether_environment`` (without the low obstacles a tether may
    pass over, :class:`tmr.world.environment.LowObstacle`), or ``env`` itself for a world that has none or no such
    attribute."""
    return getattr(env, "tether_environment", env)


def anchor_tether_clearance(env: Any, anchor: Array, clearance: float) -> float:
    """Clearance [m] the anchor's own tether must keep: ``clearance``, or half the anchor's own clearance (in the
    tethers' world, :func:`tether_env`) if that is less (an anchor next to a wall)."""
    return min(clearance, 0.5 * float(np.asarray(tether_env(env).exact_clearance(anchor))))


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
    keeps clearance > ``clearance`` [m] from the obstacles grown by r (exact: ``segment_is_free`` of
    :func:`tether_env`, which may pass over low obstacles; the anchor's
    own tether: half the anchor's clearance if that is less) and is homotopic to the guide (the chord and the
    guide between its ends enclose no obstacle: parity of the crossings of a ray from every hole). Returns the
    arcs (n,) and positions (n, 2) of the stations after the start, the last one the goal: the fewest hops at this
    resolution. Raises :class:`BlockedRouteError` if no chain reaches the goal.
    """
    smax = np.atleast_1d(np.asarray(span_max, float))
    smin = np.atleast_1d(np.asarray(span_min, float)) if span_min is not None else np.zeros(1)
    sm = _Samples(env, guide, step, start_arc)
    tenv = tether_env(env)  # chords: over the low obstacles; stations (robots): in env
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
            js = js[tenv.segment_is_free(np.repeat(P[i : i + 1], len(js), 0), P[js], clearance if i else first)]
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


def _xy(p: Array) -> str:
    return f"({p[0]:.4g}, {p[1]:.4g})"


def _dedupe(points: Array) -> Array:
    keep = np.r_[True, np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9]
    out = points[keep]
    out[-1] = points[-1]
    return out
