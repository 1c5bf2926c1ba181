"""Route-guided references for every robot of the chain (``formulations/route.md``).

From a :class:`tmr.route.route.Route` (the shortest free route and its stations) this module builds:

* the **start placement**: robots evenly spaced along the route from the anchor (spacing 2r + margin), so the chain
  already lies along the way it will go; when the route is too short for N robots, the robots that do not fit are
  *parked* on a free straight ray from the anchor and the active chain starts from the last parked robot;
* the **guide**: the polyline anchor → start positions → shortest route from the leader's start to the goal; every
  reference lies on it (or on a short offset to a station off a bend), so the chain keeps the route's homotopy class;
* the **final stations** for N robots: the fewest stations of :func:`tmr.route.route.stations`, and the extra robots
  splitting the longest tethers (a sub-chord of a free chord is free and homotopic);
* the **time law**: the leader moves along the guide with the quintic minimum-jerk law of
:func:`tmr.route.path.time_law`
  over a duration chosen from the route length and the leader's speed and acceleration limits
  (peak speed 15 L / (8 T), peak acceleration 10 L / (√3 T²)) unless T_end is given;
* **follower references**: robot i trails the leader along the guide by (N − i) spacings and stops at its station,
  so robots fill the stations from the back as the leader advances.

Low obstacles (:class:`tmr.world.environment.LowObstacle`): a robot's position and motion are tested in ``env``, a
tether's chord in ``env.tether_environment`` (:func:`tmr.route.geodesic.tether_env`): a chord may pass over a low
obstacle, whose cable height the per-step QP keeps.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.route.geodesic import SPACING_MARGIN, anchor_tether_clearance, bend_offsets, tether_env
from tmr.route.path import Trajectory, time_law
from tmr.route.route import (
    CHORD_CLEARANCE,
    BlockedRouteError,
    Route,
    RouteVerdict,
    guide_arcs,
    plan_route,
    point_at,
    stations,
)

Array = NDArray[np.float64]

__all__ = ["ChainReference", "PlacementError", "chain_reference", "leader_duration", "start_placement"]


class PlacementError(RouteVerdict):
    """No start placement of the robots was found (a verdict of the search, not a proof: the command line exits 1)."""

    proven = False


#: Peak speed and acceleration of the quintic law s = L(10τ³ − 15τ⁴ + 6τ⁵): 15 L / (8 T) and 10 L / (√3 T²).
_PEAK_SPEED = 15.0 / 8.0
_PEAK_ACCEL = 10.0 / math.sqrt(3.0)


def leader_duration(length: float, speed: float, accel: float, Ts: float, minimum: float = 2.0) -> float:
    """Duration T [s] of the minimum-jerk law over ``length`` [m] whose peak speed and acceleration stay within
    ``speed`` [m/s] and ``accel`` [m/s²], rounded up to a whole number of steps Ts (at least ``minimum`` s)."""
    T = max(minimum, _PEAK_SPEED * length / speed, math.sqrt(_PEAK_ACCEL * length / accel))
    return math.ceil(T / Ts - 1e-9) * Ts


@dataclass(frozen=True)
class ChainReference:
    """References of every robot along the guide (module docstring).

    Attributes:
        guide: (M, 2) polyline from the anchor through the start positions to the goal [m].
        start: (N, 2) start positions [m].
        start_arcs: (N,) their arc lengths on the guide [m].
        final: (N, 2) final stations [m] (the last one the goal).
        final_arcs: (N,) arc lengths of the stations' feet on the guide [m].
        parked: robots 1..parked do not move (the route was too short for all of them).
        trajectory: the leader's trajectory (t, x, xd, xdd, waypoints).
        positions: (K+1, N, 2) reference of every robot [m] (the last column is the leader's x).
        velocities: (K+1, N, 2) their derivatives [m/s].
        mode: ``"trail"`` (every robot at once, trailing the leader: this module) or ``"train"`` (one robot at a
            time, every state checked: :mod:`tmr.route.train`).
    """

    guide: Array
    start: Array
    start_arcs: Array
    final: Array
    final_arcs: Array
    parked: int
    trajectory: Trajectory
    positions: Array
    velocities: Array
    mode: str = "trail"


#: Clearance [m] the start's tethers keep (the robots keep ``clear``): the QP lets a tether sample that starts
#: nearer than its d_safe stay there, but not get nearer.
CHORD_START_CLEARANCE = 0.02


def _free_chain(env: Any, base: Array, P: Array, clear: float) -> bool:
    """Robots keep clearance > ``clear`` [m], tethers > ``CHORD_START_CLEARANCE`` (the anchor's only > half the
    anchor's own clearance if that is less: an anchor placed next to a wall)."""
    starts = np.vstack([base, P[:-1]])
    need = np.full(len(P), min(clear, CHORD_START_CLEARANCE))
    tenv = tether_env(env)
    need[0] = min(need[0], 0.5 * float(np.asarray(tenv.exact_clearance(base))))
    return bool(
        np.all(np.asarray(env.exact_clearance(P), float) > clear)
        and np.all(np.asarray(tenv.segment_clearance(starts, P), float) > need)
    )


def start_placement(
    env: Any,
    route: Route,
    n_robots: int,
    spacing: float,
    clear: float = 0.05,
    span_limits: Array | None = None,
) -> tuple[Array, int]:
    """Start positions (N, 2) and the number of parked robots (module docstring).

    Robots are placed at arcs i·``spacing`` [m] along the route while the leader keeps at least one spacing of route
    ahead of it. Otherwise the robots that do not fit are *parked*: a self-avoiding walk from the anchor (steps of
    ``spacing``, 36 headings, depth-first over the best few, free chords, robots 2r apart, away from the goal), and
    the active robots stand on the shortest route from the last parked robot, provided that route holds them and its
    stations need no more robots than are active (``span_limits`` (N, 2), default [2r, route.d_max]).
    Robots and tethers keep clearance > ``clear`` [m]. :class:`PlacementError` if nothing fits.
    """
    N = int(n_robots)
    arcs = guide_arcs(route.points)
    L = float(arcs[-1])
    r = float(env.safety_radius)
    lim = np.asarray(span_limits, dtype=float) if span_limits is not None else np.tile([2 * r, route.d_max], (N, 1))
    fit = max(0, int(math.floor((L - spacing) / spacing + 1e-9)))
    reach = float(lim[:, 1].min()) - SPACING_MARGIN  # no start tether longer than this [m]
    base = route.points[0]
    goal = route.points[-1]
    tried = 0
    ahead = point_at(route.points, arcs, min(spacing, L))
    heading = math.atan2(ahead[1] - base[1], ahead[0] - base[0])
    walks: dict[bool, list[tuple[int, Array, Route]]] = {False: [], True: []}  # parkings to reuse with bends

    def parkings(compact: bool) -> Iterator[tuple[int, Array, Route]]:
        """Parkings (most active robots first) whose route to the goal the active robots can chain, each
        recorded in ``walks[compact]`` (the pass with bends reuses them): rings and walks away from the goal, or
        with ``compact`` walks coiled round the anchor."""
        nonlocal tried
        for active in range(min(N - 1, fit + 2), 0, -1):
            parked = N - active
            if compact:
                candidates = _snakes(env, base, parked, spacing, clear, goal, compact=True)
            else:
                candidates = _rings(env, base, parked, spacing, clear, heading)
                candidates += _snakes(env, base, parked, spacing, clear, goal)
            for Pp in candidates:
                tried += 1
                try:
                    sub = plan_route(env, Pp[-1], goal, lim[parked:], fewest=False, at_most=active)
                except RouteVerdict:
                    continue
                if sub.n_route <= active:  # the active robots start along sub.points, the route chain's guide
                    walks[compact].append((parked, Pp, sub))
                    yield walks[compact][-1]

    # off-bend candidates only where the route's own points give no placement at all; compact parkings last, only
    # where nothing else fits (a placement found before they existed is found unchanged)
    for compact, bends in ((False, False), (False, True), (True, False), (True, True)):
        if fit >= N and not compact:
            P = _along(env, route.points, N, spacing, clear, ahead=spacing, reach=reach, bends=bends)
            if P is not None and _free_chain(env, base, P, clear):
                return P, 0
        for parked, Pp, sub in walks[compact] if bends else parkings(compact):
            Pa = _along(env, sub.points, N - parked, spacing, clear, ahead=0.0, reach=reach, bends=bends, avoid=Pp)
            if Pa is None:
                continue
            P = np.vstack([Pp, Pa])
            if _free_chain(env, base, P, clear) and _separated(P, 2 * r + 0.02):
                return P, parked
    raise PlacementError(
        f"no free start placement of {N} robots was found (along the {L:.1f} m route, or {tried} parking walks from "
        "the anchor); give the start positions explicitly (scenario 'start' or --start)"
    )


class _Answers:
    """The clearances of a polyline's candidate points ``S`` (K, 2) and the chords between them, each asked of the
    world once, where first asked: :func:`_along`'s depth-first search asks the same ones again and again. And a
    chord is asked only to a point that keeps its clearance. ``long_walls-corner-3202507196`` with 8 robots (11
    searches): 361,843 point clearances and as many chords before, 3,060 and 65,951 now; ``tmr plan --method qp``'s
    problem 3.93 → 1.60 s, the same output bytes (``benchmarks/placement_answers.py``). Each answer is the world's
    own, per point and per chord, whichever batch asks it."""

    def __init__(self, env: Any, S: Array) -> None:
        self.env, self.tenv, self.S = env, tether_env(env), S
        self.clearance = np.full(len(S), np.nan)  # env.exact_clearance(S) [m], NaN where not yet asked
        self.chords: dict[int, NDArray[np.int8]] = {}  # from S[k]: to S[c] free (1), not (0), not yet asked (-1)

    def robot_clear(self, idx: NDArray[np.intp], clear: float) -> NDArray[np.bool_]:
        """Whether the points ``S[idx]`` (distinct indices) keep clearance > ``clear`` [m] in ``env``."""
        new = idx[np.isnan(self.clearance[idx])]
        if len(new):
            self.clearance[new] = np.asarray(self.env.exact_clearance(self.S[new]), float)
        return self.clearance[idx] > clear

    def chord_free(self, k: int, idx: NDArray[np.intp], need: float) -> NDArray[np.bool_]:
        """Whether the chords ``S[k]``–``S[idx]`` (distinct indices) keep clearance > ``need`` [m] in the tethers'
        world (:func:`tether_env`). ``need`` must be the same at every call from ``k`` (in :func:`_along` it
        depends on k alone: the anchor's tether starts at k = 0 and no other does)."""
        row = self.chords.get(k)
        if row is None:
            row = self.chords[k] = np.full(len(self.S), -1, dtype=np.int8)
        new = idx[row[idx] < 0]
        if len(new):
            row[new] = self.tenv.segment_is_free(np.repeat(self.S[k][None], len(new), 0), self.S[new], need)
        return row[idx] == 1


def _along(
    env: Any,
    guide: Array,
    n: int,
    spacing: float,
    clear: float,
    ahead: float,
    reach: float = math.inf,
    bends: bool = False,
    avoid: Array | None = None,
) -> Array | None:
    """``n`` robots along the polyline from its start (depth-first with a small budget).

    Each robot stands at a point of the polyline (every 0.05 m), keeping clearance > ``clear`` [m], at least
    2r + 0.05 m from the previous one and preferably ``spacing`` [m], on a chord from the previous one that keeps
    ``CHORD_START_CLEARANCE`` (a chord must not cut a corner of the route: at a hairpin the robot sits at its
    apex); the last one at least ``ahead`` [m] of route before the end. With ``bends``, points off the
    polyline's bends are candidates too (:func:`tmr.route.geodesic.bend_offsets`: round a wall's end, robots 2r apart
    cannot both stand on a route that hugs it) and every robot keeps 2r + 0.05 m from all placed before it. No
    chord is longer than ``reach`` [m]. Every robot keeps 2r + 0.05 m from the points ``avoid`` (k, 2) too (robots
    parked before the polyline starts). None if they do not fit."""
    arcs = guide_arcs(guide)
    L = float(arcs[-1])
    s = np.arange(0.0, L + 1e-9, 0.05)
    S = point_at(guide, arcs, s)
    vs, off = bend_offsets(env, guide, arcs) if bends else (np.zeros(0, np.intp), np.zeros((0, 2)))
    if len(off):
        keep = np.asarray(env.exact_clearance(off), float) > clear
        s = np.concatenate([s, arcs[vs[keep]] + 1e-6])
        S = np.vstack([S, off[keep]])
        order = np.argsort(s, kind="stable")
        s, S = s[order], S[order]
    first = anchor_tether_clearance(env, S[0], CHORD_START_CLEARANCE)
    near = 2.0 * float(env.safety_radius) + 0.05  # robots at least 2r apart, with a little margin
    if avoid is not None and len(avoid):  # candidates too near a parked robot are dropped
        far = np.min(np.linalg.norm(S[:, None] - np.asarray(avoid, float)[None], axis=2), axis=1) >= near
        far[0] = True  # the polyline's start (the last parked robot itself) is where the walk begins
        s, S = s[far], S[far]
    budget = [300]
    asked = _Answers(env, S)

    def options(path: list[int]) -> list[int]:
        k, j = path[-1], len(path) - 1
        cur = S[k]
        if bends and j:  # off-bend points come back near the route: 2r + 0.05 m from every robot placed so far
            d = np.min(np.linalg.norm(S[k + 1 :, None] - S[path[1:]][None], axis=2), axis=1)
        else:  # along the polyline, from the previous one
            d = np.linalg.norm(S[k + 1 :] - cur, axis=1)
        cand = np.flatnonzero(d >= near) + k + 1
        cand = cand[np.linalg.norm(S[cand] - cur, axis=1) <= reach]  # no start tether beyond its span limit
        cand = cand[s[cand] <= L - ahead + 1e-9][:400]
        if not len(cand):
            return []
        need = first if j == 0 else CHORD_START_CLEARANCE
        ok = asked.robot_clear(cand, clear)
        ok[ok] = asked.chord_free(k, cand[ok], need)
        wide = ok & (np.linalg.norm(S[cand] - cur, axis=1) >= spacing)
        # the first free point one spacing away, then the free ones nearer (a hairpin's apex), then farther ones
        order = [int(c) for c in cand[wide][:1]] + [int(c) for c in cand[ok & ~wide][::-1][:2]]
        order += [int(c) for c in cand[wide][1:][::8][:2]]
        return order

    def grow(path: list[int]) -> list[int] | None:
        if len(path) - 1 == n:
            return path
        budget[0] -= 1
        if budget[0] < 0:
            return None
        for c in options(path):
            done = grow([*path, c])
            if done is not None:
                return done
        return None

    found = grow([0])
    return None if found is None else S[found[1:]]


def _rings(env: Any, base: Array, count: int, spacing: float, clear: float, heading: float) -> list[Array]:
    """Parking on a ring round the anchor: robot k of ``count`` at angle heading ± (count − k + 1) Δ on a circle of
    radius 1–2 spacings, Δ the angle of a ``spacing`` chord (+5 %), so the last parked robot sits next to the route's
    first direction and the active robots leave the ring outwards. Free and separated rings only."""
    out = []
    r = float(env.safety_radius)
    for rho in (spacing, 1.5 * spacing, 2.0 * spacing):
        delta = 2.0 * math.asin(min(1.0, 0.5 * spacing / rho)) * 1.05
        if (count + 1) * delta > 2 * math.pi:
            continue
        for sign in (1.0, -1.0):
            ang = heading + sign * delta * np.arange(count, 0, -1)
            P = base + rho * np.column_stack([np.cos(ang), np.sin(ang)])
            if _free_chain(env, base, P, clear + 0.05) and _separated(np.vstack([base, P]), 2 * r + 0.05):
                out.append(P)
    return out


#: Parking walks tried per number of parked robots, and the walk's search budget (expanded positions).
SNAKES = 4
SNAKE_BUDGET = 400


def _snakes(
    env: Any, base: Array, count: int, spacing: float, clear: float, goal: Array, compact: bool = False
) -> list[Array]:
    """Up to ``SNAKES`` parking walks of ``count`` robots from the anchor (depth-first, best headings first).

    Each robot is ``spacing`` [m] from the previous one (the first from the anchor) on a free chord, ≥ 2r + 0.05 m
    from every robot placed and the anchor; headings are ranked by distance to those robots, clearance and distance
    to the goal (the robots that follow the route from the last parked one need room before the goal), or with
    ``compact`` by nearness to the anchor instead of the goal distance: a walk that coils round the anchor, so that
    the route from its end is not much longer than the anchor's own (a near goal, many robots, and an anchor by a
    wall where no ring fits and the walks away from the goal end too far from it).
    """
    h = spacing * np.stack([np.cos(np.arange(36) * np.pi / 18), np.sin(np.arange(36) * np.pi / 18)], axis=1)
    r = float(env.safety_radius)
    found: list[Array] = []
    budget = [SNAKE_BUDGET]

    def grow(pts: list[Array]) -> None:
        if len(found) >= SNAKES or budget[0] <= 0:
            return
        if len(pts) == count + 1:
            found.append(np.array(pts[1:]))
            return
        budget[0] -= 1
        C = pts[-1] + h
        ok = np.asarray(env.exact_clearance(C), float) > clear + 0.1
        if not ok.any():
            return
        prev = np.array(pts)
        sep = np.min(np.linalg.norm(C[:, None] - prev[None], axis=-1), axis=1)
        if len(pts) > 1:
            ok &= sep >= 2 * r + 0.05
        idx = np.flatnonzero(ok)
        if not len(idx):
            return
        chords = tether_env(env).segment_clearance(np.repeat(pts[-1][None], len(idx), 0), C[idx])
        free = np.asarray(chords, float) > clear + 0.05
        idx = idx[free]
        far = (
            -np.linalg.norm(C[idx] - pts[0], axis=1)
            if compact
            else np.minimum(np.linalg.norm(C[idx] - goal, axis=1), 6.0)
        )
        score = np.minimum(sep[idx], 3.0) + np.minimum(np.asarray(env.clearance(C[idx]), float), 1.0) + 0.5 * far
        for k in idx[np.argsort(-score, kind="stable")][:3]:
            grow([*pts, C[k]])

    if count == 0:
        return [np.zeros((0, 2))]
    grow([np.asarray(base, float)])
    return found


#: Spacing [m] of the leader's waypoints along the guide (its cubic spline would overshoot long straight legs).
LEAD_STEP = 1.0

#: Clearance [m] a follower's tether to the robot ahead keeps, in the visibility rule of the references.
VISIBLE_CLEARANCE = 0.1


def _visible_back(env: Any, guide: Array, arcs: Array, step: float = 0.1) -> tuple[Array, NDArray[np.intp]]:
    """Guide samples s (every ``step`` [m]) and, for each, the first sample behind it from which every later sample
    up to it is joined to it by a chord keeping ``VISIBLE_CLEARANCE``, or the guide's own clearance between the
    two samples less 0.01 m where that is less (a narrow door, where the route keeps 0.06 m) (exact)."""
    L = float(arcs[-1])
    s = np.linspace(0.0, L, max(2, math.ceil(L / step) + 1))
    S = point_at(guide, arcs, s)
    own = np.asarray(env.segment_clearance(S[:-1], S[1:]), dtype=float)  # guide's clearance per sample interval
    tenv = tether_env(env)  # the follower's tether to the robot ahead may pass over a low obstacle
    back = np.zeros(len(s), dtype=np.intp)
    window = 80
    for j in range(1, len(s)):
        lo = max(0, j - window)
        idx = np.arange(lo, j)
        least = np.minimum.accumulate(own[lo:j][::-1])[::-1]  # guide's clearance from sample idx to sample j
        margin = np.clip(least - 0.01, 0.0, VISIBLE_CLEARANCE)
        ok = tenv.segment_is_free(S[idx], np.repeat(S[j : j + 1], len(idx), 0), margin)
        bad = np.flatnonzero(~ok)
        back[j] = idx[bad[-1]] + 1 if len(bad) else lo
    return s, back


def _project(points: Array, p: Array) -> tuple[int, float, float]:
    """Nearest point of the polyline to p: its segment k, the fraction t along it, and the distance [m]."""
    a, b = points[:-1], points[1:]
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    dist = np.linalg.norm(a + t[:, None] * d - p, axis=1)
    k = int(np.argmin(dist))
    return k, float(t[k]), float(dist[k])


def _distance_to_polyline(points: Array, p: Array) -> float:
    return _project(points, p)[2]


def _arc_of(points: Array, arcs: Array, p: Array) -> float:
    """Arc length [m] of the point of the polyline nearest to p."""
    k, t, _ = _project(points, p)
    return float(arcs[k] + t * (arcs[k + 1] - arcs[k]))


def _separated(P: Array, d: float) -> bool:
    if len(P) < 2:
        return True
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    return bool(np.all(D[np.triu_indices(len(P), 1)] >= d))


def _split_extra(
    final: Array, arcs: Array, start_pt: Array, extra: int, d_min: float, start_arc: float
) -> tuple[Array, Array]:
    """Add ``extra`` stations by splitting the longest tethers at their midpoint (sub-chords of free chords), as
    long as the halves stay ≥ ``d_min`` [m]; ``start_pt`` at arc ``start_arc`` is where the first tether starts."""
    pts, ar = list(final), list(arcs)
    for _ in range(extra):
        prev = [start_pt, *pts[:-1]]
        prev_arc = [start_arc, *ar[:-1]]
        lengths = [float(np.linalg.norm(b - a)) for a, b in zip(prev, pts, strict=True)]
        k = int(np.argmax(lengths))
        if lengths[k] / 2 < d_min:
            return np.array(pts[: len(pts)]), np.array(ar)  # no tether long enough to split
        pts.insert(k, 0.5 * (prev[k] + pts[k]))
        ar.insert(k, 0.5 * (prev_arc[k] + ar[k]))
    return np.array(pts), np.array(ar)


#: Turn [rad] of the leader's path at a waypoint beyond which the leader stops there and starts a new minimum-jerk
#: piece (a hairpin round a wall's end: one interpolating spline through it would have a cusp).
HAIRPIN_TURN = math.radians(90.0)


def _leader_law(
    lead: Array, T_end: float | None, Ts: float, speed: float, accel: float, env: Any, clearance: float
) -> Trajectory:
    """The leader's trajectory along the polyline ``lead``: one minimum-jerk piece (:func:`tmr.route.path.time_law`)
    between consecutive hairpins (turns > ``HAIRPIN_TURN``), each stopping at its end; durations from the pieces'
    lengths and the speed and acceleration limits (:func:`leader_duration`), or ``T_end`` [s] shared in
    proportion to them. The spline keeps ``clearance`` [m], or half the polyline's own clearance where that is
    less (the route keeps 0.06 m in a narrow passage)."""
    d = np.diff(lead, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi)
    cuts = [0, *(np.flatnonzero(turn > HAIRPIN_TURN) + 1).tolist(), len(lead) - 1]
    pieces = [lead[a : b + 1] for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    if T_end is None:
        T = [leader_duration(float(guide_arcs(p)[-1]), speed, accel, Ts) for p in pieces]
    else:
        K = max(len(pieces), round(T_end / Ts))
        lengths = np.array([max(float(guide_arcs(p)[-1]), 1e-9) for p in pieces])
        steps = np.maximum(1, np.floor(K * lengths / lengths.sum()).astype(int))
        steps[int(np.argmax(lengths))] += K - int(steps.sum())
        T = [int(k) * Ts for k in steps]
    if env is not None and len(lead) > 1:  # a start placement or a route through a narrow door may keep less
        least = float(np.min(env.segment_clearance(lead[:-1], lead[1:])))
        clearance = min(clearance, 0.5 * least) if least > 0 else clearance
    parts = [time_law(p, T_end=t, Ts=Ts, env=env, clearance=clearance) for p, t in zip(pieces, T, strict=True)]
    if len(parts) == 1:
        return parts[0]
    x, xd, xdd = [parts[0].x], [parts[0].xd], [parts[0].xdd]
    for part in parts[1:]:
        x.append(part.x[1:])
        xd.append(part.xd[1:])
        xdd.append(part.xdd[1:])
    K = sum(len(p.t) - 1 for p in parts)
    return Trajectory(Ts * np.arange(K + 1), np.vstack(x), np.vstack(xd), np.vstack(xdd), lead.copy())


def _anticipate(seen: Array, step: float) -> Array:
    """The least arc profile a(k) ≥ ``seen`` (K+1,) [m] that never rises faster than ``step`` [m] per step:
    a(k) = max over k' ≥ k of seen(k') − step·(k' − k). Where the robot ahead rounds a corner, the arc from which it
    stays in view jumps forward; the follower starts earlier instead of jumping."""
    ramp = step * np.arange(len(seen))
    return np.maximum.accumulate((seen - ramp)[::-1])[::-1] + ramp


def _walk_in_view(env: Any, pos: Array, final: Array, i: int, step: float = 0.05) -> None:
    """Keep follower ``i+1`` in view of robot ``i`` once ``i`` rests at its final station (in place on ``pos``).

    The stations' chords are free, but the guide from where robot i+1 is when robot i arrives to robot i+1's own
    station may turn round a corner that the chord from robot i's station cuts (an S-shaped door): the tether
    between them would be pressed on it. Then robot i+1 leaves the guide at the latest point P of its reference
    from which the triangle (station i, P, station i+1) is free (the segment P → station i+1 and every chord from
    station i to it keep the margin), and walks straight from P to its station over the same time."""
    rest = np.flatnonzero(np.linalg.norm(pos[:, i] - final[i], axis=1) < 1e-9)
    arrive = np.flatnonzero(np.linalg.norm(pos[:, i + 1] - final[i + 1], axis=1) < 1e-9)
    if not len(rest) or not len(arrive) or arrive[0] <= rest[0]:
        return
    k0, k1 = int(rest[0]), int(arrive[0])
    if np.linalg.norm(final[i + 1] - final[i]) < 1e-9:
        return
    tenv = tether_env(env)  # chords in the tethers' world, robot i+1's walk in env
    chord = float(tenv.segment_clearance(final[i], final[i + 1]))
    margin = min(VISIBLE_CLEARANCE, 0.5 * chord) if chord > 0 else 0.0
    seg = pos[k0 : k1 + 1, i + 1]
    seen = tenv.segment_is_free(np.broadcast_to(final[i], seg.shape), seg, margin)
    if seen.all():
        return
    F = final[i + 1]
    for kp in range(k0 + int(np.argmin(seen)) - 1, k0 - 1, -1):
        P = pos[kp, i + 1].copy()
        m = max(2, math.ceil(float(np.linalg.norm(F - P)) / step) + 1)
        line = P + np.linspace(0.0, 1.0, m)[:, None] * (F - P)
        fan = tenv.segment_is_free(np.broadcast_to(final[i], line.shape), line, margin)
        if env.segment_is_free(P, F, margin) and fan.all():
            break
    else:
        return
    path = pos[kp : k1 + 1, i + 1]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    u = arc / arc[-1] if arc[-1] > 0 else np.linspace(0.0, 1.0, len(arc))
    pos[kp : k1 + 1, i + 1] = P + u[:, None] * (F - P)


def _stays_joined(env: Any, P: Array, start_arcs: Array, f_arcs: Array, f_pts: Array, lim: Array) -> bool:
    """Whether the robots before the final stations ``f_pts`` (arcs ``f_arcs``) can stay where they start: the last
    of them (robot N − len(f_pts), 1-based) reaches the first station, which is not behind it on the guide, within
    its tether's span limits (``lim`` (N, 2), at least d_lo + 0.02 m) on a chord keeping ``CHORD_CLEARANCE``, and
    every staying robot is 2r + 0.02 m from every station."""
    k = len(P) - len(f_pts)  # 0-based index of the first robot that moves; robots 0..k − 1 stay
    if k < 1 or f_arcs[0] < start_arcs[k - 1]:
        return False
    lo, hi = lim[k]
    d = float(np.linalg.norm(f_pts[0] - P[k - 1]))
    gaps = np.linalg.norm(P[:k, None] - f_pts[None], axis=-1)
    return bool(
        lo + 0.02 <= d <= hi
        and gaps.min() >= 2 * float(env.safety_radius) + 0.02
        and tether_env(env).segment_is_free(P[k - 1], f_pts[0], CHORD_CLEARANCE)
    )


#: :func:`chain_reference`'s default ``catch_up`` [m/s] (omnidirectional robots; a differential-drive chain's is its
#: robots' straight-line speed, :func:`tmr.planner.diff_catch_up`).
CATCH_UP = 1.2


def chain_reference(
    env: Any,
    route: Route,
    start: ArrayLike,
    span_limits: Array,
    *,
    parked: int = 0,
    T_end: float | None,
    Ts: float,
    speed: float,
    accel: float,
    spacing: float,
    spline_clearance: float = 0.05,
    settle: float = 0.0,
    catch_up: float = CATCH_UP,
) -> ChainReference:
    """References of every robot from ``start`` (N, 2) along the route to the final stations.

    Args:
        env: environment; route: from :func:`tmr.route.route.plan_route` (anchor → goal).
        start: (N, 2) start positions [m] (robot N the leader).
        span_limits: (N, 2) [d_lo, d_max] per tether [m].
        parked: robots 1..parked stay where they start.
        T_end: the leader's duration [s], or None to derive it from the guide length, ``speed`` [m/s] and
            ``accel`` [m/s²] (:func:`leader_duration`).
        Ts: sampling period [s]; spacing: trailing distance between consecutive robots along the guide [m].
        spline_clearance: clearance [m] the leader's spline keeps from the obstacles grown by r.
        settle: time [s] every reference holds still at its end (the leader on the goal, the followers on their
            stations), so that the followers, which lag their references, come to rest before the plan ends.
        catch_up: fastest rise [m/s] of a follower's "in view of the robot ahead" bound (:func:`_anticipate`):
            where that bound jumps forward at a corner, the follower starts earlier instead of jumping.
    """
    P = np.asarray(start, dtype=float)
    N = len(P)
    base = route.points[0]
    goal = route.points[-1]
    lim = np.asarray(span_limits, dtype=float)
    # guide: anchor → parked robots → the route they start on (when the active robots lie on it), else
    # anchor → every start position → shortest route from the leader to the goal
    tail_start = P[parked - 1] if parked else base
    sub = (
        route if not parked else plan_route(env, tail_start, goal, np.array([[lim[-1, 0], route.d_max]]), fewest=False)
    )
    on_sub = all(_distance_to_polyline(sub.points, p) < 1e-6 for p in P[parked:])
    if on_sub:
        guide = np.vstack([base, P[:parked], sub.points[1:]]) if parked else sub.points.copy()
    else:
        tail = plan_route(env, P[-1], goal, np.array([[lim[-1, 0], route.d_max]]), fewest=False)
        guide = np.vstack([base, P, tail.points[1:]])
    keep = np.r_[True, np.linalg.norm(np.diff(guide, axis=0), axis=1) > 1e-9]
    guide = guide[keep]
    garcs = guide_arcs(guide)
    start_arcs = np.array([_arc_of(guide, garcs, p) for p in P])
    # final stations of the active robots parked+1..N, from the last parked robot's position; when there are more
    # robots than stations and no tether is long enough to split, one more robot stays where it starts (parked),
    # and the stations are searched again from it, so that no two final positions crowd each other; if that leaves
    # more stations than robots, the previous stations are kept when the robots before them can stay (_stays_joined)
    fewer: tuple[Array, Array] | None = None  # the last stations that were fewer than the active robots
    while True:
        s0 = float(start_arcs[parked - 1]) if parked else 0.0
        active = N - parked
        d_lo = lim[parked:, 0] + SPACING_MARGIN
        try:
            f_arcs, f_pts = stations(env, guide, lim[parked:, 1], d_lo, start_arc=s0, clearance=CHORD_CLEARANCE)
        except RouteVerdict as exc:
            raise BlockedRouteError(f"from the start placement: {exc}") from exc
        if len(f_arcs) > active:
            # parking one more robot moved the chain's start past where the stations fit (a near goal): keep the
            # previous stations, the robots before them staying where they start, if the last of those reaches the
            # first station within its span limits on a free chord
            if fewer is not None and _stays_joined(env, P, start_arcs, *fewer, lim):
                f_arcs, f_pts = fewer
                break
            raise BlockedRouteError(
                f"the {active} active robot(s) cannot reach the goal along the route from their start placement: "
                f"{len(f_arcs)} are needed"
            )
        if len(f_arcs) < active:
            start_pt = point_at(guide, garcs, s0)
            f_pts, f_arcs = _split_extra(f_pts, f_arcs, start_pt, active - len(f_arcs), float(d_lo.max()), s0)
        if len(f_arcs) == active or parked >= N - 1:
            break
        fewer = (f_arcs, f_pts)
        parked += 1
    final = np.vstack([P[: N - len(f_pts)], f_pts])
    final_arcs = np.concatenate([start_arcs[: N - len(f_arcs)], f_arcs])
    final[-1] = goal
    final_arcs = np.maximum(final_arcs, start_arcs)
    # leader: quintic law along the guide from its start
    lead = guide[garcs >= start_arcs[-1] - 1e-9]
    lead = np.vstack([P[-1], lead[np.linalg.norm(lead - P[-1], axis=1) > 1e-9]])
    L_lead = float(guide_arcs(lead)[-1])
    if L_lead > 0:  # waypoints every ≤ LEAD_STEP: the spline stays close to the route instead of overshooting
        la = guide_arcs(lead)
        extra = np.linspace(0.0, L_lead, max(2, math.ceil(L_lead / LEAD_STEP) + 1))
        lead = point_at(lead, la, np.union1d(la, extra))
    traj = _leader_law(lead, T_end, Ts, speed, accel, env, spline_clearance)
    # leader progress along the guide: s_N(t) = start arc + travelled fraction of the guide's remainder
    K = len(traj.t) - 1
    steps = np.linalg.norm(np.diff(traj.x, axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])
    frac = travelled / travelled[-1] if travelled[-1] > 0 else np.ones(K + 1)
    s_lead = start_arcs[-1] + frac * (garcs[-1] - start_arcs[-1])
    pos = np.empty((K + 1, N, 2))
    end = float(garcs[-1])
    vis_s, vis_back = _visible_back(env, guide, garcs)
    ahead = s_lead.copy()  # arc of the robot ahead (its foot on the guide), from the leader backwards
    for i in range(N - 2, -1, -1):
        if final_arcs[i] <= start_arcs[i] + 1e-9 and np.linalg.norm(final[i] - P[i]) < 1e-9:
            pos[:, i] = P[i]
            ahead = np.full(K + 1, start_arcs[i])
            continue
        foot = point_at(guide, garcs, final_arcs[i])
        off = final[i] - foot  # offset of a station off a bend, walked once the foot is reached
        span = float(np.linalg.norm(off))
        # trail the leader by the start's gap, shrinking with the leader's progress to one that reaches the station
        gap0 = float(s_lead[0] - start_arcs[i])  # the start's own gap: the reference starts at the start
        gap1 = max(0.0, min(gap0, end - final_arcs[i] - span))
        target = s_lead - (gap0 + frac * (gap1 - gap0))
        # never so far behind the robot ahead that their tether would cut a corner of the guide
        seen = vis_s[vis_back[np.clip(np.searchsorted(vis_s, ahead), 0, len(vis_s) - 1)]]
        seen = _anticipate(seen, catch_up * Ts)
        a = np.clip(np.maximum(np.clip(target, start_arcs[i], final_arcs[i]), seen), start_arcs[i], final_arcs[i])
        a = np.maximum.accumulate(a)  # progress only
        on_guide = point_at(guide, garcs, a)
        extra = np.clip(target - final_arcs[i], 0.0, None)
        w = np.clip(extra / span, 0.0, 1.0) if span > 1e-9 else np.zeros(K + 1)
        w = np.maximum.accumulate(np.where(a >= final_arcs[i] - 1e-9, w, 0.0))
        pos[:, i] = on_guide + w[:, None] * off
        ahead = a
    pos[:, -1] = traj.x
    for i in range(N - 2):
        _walk_in_view(env, pos, final, i)
    vel = np.gradient(pos, traj.t, axis=0)
    vel[:, -1] = traj.xd
    if settle > 0:  # everyone holds still at the end while the followers come to rest on their stations
        extra = int(round(settle / Ts))
        traj = Trajectory(
            Ts * np.arange(len(traj.t) + extra),
            np.vstack([traj.x, np.repeat(traj.x[-1:], extra, 0)]),
            np.vstack([traj.xd, np.zeros((extra, 2))]),
            np.vstack([traj.xdd, np.zeros((extra, 2))]),
            traj.waypoints,
        )
        pos = np.concatenate([pos, np.repeat(pos[-1:], extra, 0)])
        vel = np.concatenate([vel, np.zeros((extra, N, 2))])
    return ChainReference(
        guide=guide,
        start=P.copy(),
        start_arcs=start_arcs,
        final=final,
        final_arcs=final_arcs,
        parked=int(N - len(f_pts)),  # every robot before the stations stays where it starts
        trajectory=traj,
        positions=pos,
        velocities=vel,
    )
