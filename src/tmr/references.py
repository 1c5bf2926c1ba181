"""Route-guided references for every robot of the chain (``formulations/route.md``).

From a :class:`tmr.route.Route` (the shortest free route and its stations) this module builds:

* the **start placement**: robots evenly spaced along the route from the anchor (spacing 2r + margin), so the chain
  already lies along the way it will go; when the route is too short for N robots, the robots that do not fit are
  *parked* on a free straight ray from the anchor and the active chain starts from the last parked robot;
* the **guide**: the polyline anchor → start positions → shortest route from the leader's start to the goal; every
  reference lies on it (or on a short offset to a station off a bend), so the chain keeps the route's homotopy class;
* the **final stations** for N robots: the fewest stations of :func:`tmr.route.stations`, and the extra robots
  splitting the longest tethers (a sub-chord of a free chord is free and homotopic);
* the **time law**: the leader moves along the guide with the quintic minimum-jerk law of :func:`tmr.path.time_law`
  over a duration chosen from the route length and the leader's speed and acceleration limits
  (peak speed 15 L / (8 T), peak acceleration 10 L / (√3 T²)) unless T_end is given;
* **follower references**: robot i trails the leader along the guide by (N − i) spacings and stops at its station,
  so robots fill the stations from the back as the leader advances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ScenarioError
from tmr.path import Trajectory, time_law
from tmr.route import (
    CHORD_CLEARANCE,
    SPACING_MARGIN,
    NoRouteError,
    Route,
    guide_arcs,
    plan_route,
    point_at,
    stations,
)

Array = NDArray[np.float64]

__all__ = ["ChainReference", "chain_reference", "leader_duration", "start_placement"]

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


def _free_chain(env: Any, base: Array, P: Array, clear: float) -> bool:
    starts = np.vstack([base, P[:-1]])
    return bool(
        np.all(np.asarray(env.exact_clearance(P), float) > clear)
        and np.all(np.asarray(env.segment_clearance(starts, P), float) > clear)
    )


def start_placement(env: Any, route: Route, n_robots: int, spacing: float, clear: float = 0.05) -> tuple[Array, int]:
    """Start positions (N, 2) along the route, spacing ``spacing`` [m], and the number of parked robots.

    The leader needs route ahead of it: robots are placed at arcs i·spacing while the last one stays at least one
    spacing before the goal. The robots that do not fit are parked on the free straight ray from the anchor whose
    heading is farthest from the route's first direction (72 headings), the rest follow the route from there.
    """
    N = int(n_robots)
    arcs = guide_arcs(route.points)
    L = float(arcs[-1])
    fit = max(0, min(N, int(math.floor((L - spacing) / spacing + 1e-9))))
    base = route.points[0]
    if fit == N:
        P = point_at(route.points, arcs, spacing * np.arange(1, N + 1))
        if _free_chain(env, base, P, clear):
            return P, 0
    active = max(fit, 1)
    while active >= 1:
        parked = N - active
        Pp = _snake(env, base, parked, spacing, clear)
        if Pp is not None:
            tail = Pp[-1] if parked else base
            try:
                sub = plan_route(env, tail, route.points[-1], np.array([[2 * env.safety_radius, route.d_max]]))
            except NoRouteError:
                sub = None
            if sub is not None:
                sarcs = guide_arcs(sub.points)
                step = min(spacing, float(sarcs[-1]) / (active + 1))
                Pa = point_at(sub.points, sarcs, step * np.arange(1, active + 1))
                P = np.vstack([Pp, Pa]) if parked else Pa
                if _free_chain(env, base, P, clear) and _separated(P, 2 * env.safety_radius + 0.02):
                    return P, parked
        active -= 1
    raise ScenarioError(
        f"no free start placement of {N} robots along the route or parked near the anchor was found; give the "
        "start positions explicitly (scenario 'start' or --start)"
    )


def _snake(env: Any, base: Array, count: int, spacing: float, clear: float) -> Array | None:
    """``count`` parked robots, each ``spacing`` [m] from the previous one (the first from the anchor), on free
    chords, each in the heading (of 36) that keeps it farthest from the robots already placed and the obstacles."""
    pts = [base]
    h = spacing * np.stack([np.cos(np.arange(36) * np.pi / 18), np.sin(np.arange(36) * np.pi / 18)], axis=1)
    for _ in range(count):
        C = pts[-1] + h
        ok = np.asarray(env.exact_clearance(C), float) > clear + 0.1
        ok &= np.asarray(env.segment_clearance(np.repeat(pts[-1][None], len(C), 0), C), float) > clear + 0.05
        if not ok.any():
            return None
        prev = np.array(pts)
        sep = np.min(np.linalg.norm(C[:, None] - prev[None], axis=-1), axis=1)
        ok &= sep >= 2 * env.safety_radius + 0.05 if len(pts) > 1 else ok
        if not ok.any():
            return None
        score = np.minimum(sep, 3.0) + np.minimum(np.asarray(env.clearance(C), float), 1.0)
        score[~ok] = -np.inf
        pts.append(C[int(np.argmax(score))])
    return np.array(pts[1:]).reshape(-1, 2)


def _distance_to_polyline(points: Array, p: Array) -> float:
    a, b = points[:-1], points[1:]
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * d - p, axis=1)))


def _arc_of(points: Array, arcs: Array, p: Array) -> float:
    """Arc length [m] of the point of the polyline nearest to p."""
    a, b = points[:-1], points[1:]
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    k = int(np.argmin(np.linalg.norm(a + t[:, None] * d - p, axis=1)))
    return float(arcs[k] + t[k] * (arcs[k + 1] - arcs[k]))


def _separated(P: Array, d: float) -> bool:
    if len(P) < 2:
        return True
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    return bool(np.all(D[np.triu_indices(len(P), 1)] >= d))


def _split_extra(final: Array, arcs: Array, start_pt: Array, extra: int, d_min: float) -> tuple[Array, Array]:
    """Add ``extra`` stations by splitting the longest tethers at their midpoint (sub-chords of free chords)."""
    pts, ar = list(final), list(arcs)
    for _ in range(extra):
        prev = [start_pt, *pts[:-1]]
        prev_arc = [ar[0] - np.linalg.norm(pts[0] - start_pt), *ar[:-1]]
        lengths = [float(np.linalg.norm(b - a)) for a, b in zip(prev, pts, strict=True)]
        k = int(np.argmax(lengths))
        if lengths[k] / 2 < d_min:
            return np.array(pts[: len(pts)]), np.array(ar)  # no tether long enough to split
        pts.insert(k, 0.5 * (prev[k] + pts[k]))
        ar.insert(k, 0.5 * (prev_arc[k] + ar[k]))
    return np.array(pts), np.array(ar)


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
) -> ChainReference:
    """References of every robot from ``start`` (N, 2) along the route to the final stations.

    Args:
        env: environment; route: from :func:`tmr.route.plan_route` (anchor → goal).
        start: (N, 2) start positions [m] (robot N the leader).
        span_limits: (N, 2) [d_lo, d_max] per tether [m].
        parked: robots 1..parked stay where they start.
        T_end: the leader's duration [s], or None to derive it from the guide length, ``speed`` [m/s] and
            ``accel`` [m/s²] (:func:`leader_duration`).
        Ts: sampling period [s]; spacing: trailing distance between consecutive robots along the guide [m].
        spline_clearance: clearance [m] the leader's spline keeps from the obstacles grown by r.
    """
    P = np.asarray(start, dtype=float)
    N = len(P)
    base = route.points[0]
    goal = route.points[-1]
    lim = np.asarray(span_limits, dtype=float)
    # guide: anchor → parked robots → the route they start on (when the active robots lie on it), else
    # anchor → every start position → shortest route from the leader to the goal
    tail_start = P[parked - 1] if parked else base
    sub = route if not parked else plan_route(env, tail_start, goal, np.array([[lim[-1, 0], route.d_max]]))
    on_sub = all(_distance_to_polyline(sub.points, p) < 1e-6 for p in P[parked:])
    if on_sub:
        guide = np.vstack([base, P[:parked], sub.points[1:]]) if parked else sub.points.copy()
    else:
        tail = plan_route(env, P[-1], goal, np.array([[lim[-1, 0], route.d_max]]))
        guide = np.vstack([base, P, tail.points[1:]])
    keep = np.r_[True, np.linalg.norm(np.diff(guide, axis=0), axis=1) > 1e-9]
    guide = guide[keep]
    garcs = guide_arcs(guide)
    start_arcs = np.array([_arc_of(guide, garcs, p) for p in P])
    # final stations of the active robots parked+1..N, from the last parked robot's position
    s0 = float(start_arcs[parked - 1]) if parked else 0.0
    active = N - parked
    d_lo = lim[parked:, 0] + SPACING_MARGIN
    try:
        f_arcs, f_pts = stations(env, guide, lim[parked:, 1], d_lo, start_arc=s0, clearance=CHORD_CLEARANCE)
    except NoRouteError as exc:
        raise NoRouteError(f"from the start placement: {exc}") from exc
    if len(f_arcs) > active:
        raise NoRouteError(
            f"the {active} active robot(s) cannot reach the goal along the route from their start placement: "
            f"{len(f_arcs)} are needed"
        )
    if len(f_arcs) < active:
        f_pts, f_arcs = _split_extra(f_pts, f_arcs, point_at(guide, garcs, s0), active - len(f_arcs), float(d_lo.max()))
    if len(f_arcs) < active:  # the remaining robots stay at their start
        extra = active - len(f_arcs)
        parked += extra
        f_pts = np.vstack([P[parked - extra : parked], f_pts])
        f_arcs = np.concatenate([start_arcs[parked - extra : parked], f_arcs])
    final = np.vstack([P[: N - len(f_pts)], f_pts])
    final_arcs = np.concatenate([start_arcs[: N - len(f_arcs)], f_arcs])
    final[-1] = goal
    final_arcs = np.maximum(final_arcs, start_arcs)
    # leader: quintic law along the guide from its start
    lead = guide[garcs >= start_arcs[-1] - 1e-9]
    lead = np.vstack([P[-1], lead[np.linalg.norm(lead - P[-1], axis=1) > 1e-9]])
    L_lead = float(guide_arcs(lead)[-1])
    if T_end is None:
        T_end = leader_duration(L_lead, speed, accel, Ts)
    traj = time_law(lead, T_end=T_end, Ts=Ts, env=env, clearance=spline_clearance)
    # leader progress along the guide: s_N(t) = start arc + travelled fraction of the guide's remainder
    K = len(traj.t) - 1
    steps = np.linalg.norm(np.diff(traj.x, axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])
    frac = travelled / travelled[-1] if travelled[-1] > 0 else np.ones(K + 1)
    s_lead = start_arcs[-1] + frac * (garcs[-1] - start_arcs[-1])
    pos = np.empty((K + 1, N, 2))
    for i in range(N - 1):
        if final_arcs[i] <= start_arcs[i] + 1e-9 and np.linalg.norm(final[i] - P[i]) < 1e-9:
            pos[:, i] = P[i]
            continue
        target = s_lead - (N - 1 - i) * spacing
        a = np.clip(target, start_arcs[i], final_arcs[i])
        on_guide = point_at(guide, garcs, a)
        foot = point_at(guide, garcs, final_arcs[i])
        off = final[i] - foot  # offset of a station off a bend, walked once the foot is reached
        extra = np.clip(target - final_arcs[i], 0.0, None)
        span = float(np.linalg.norm(off))
        w = np.clip(extra / span, 0.0, 1.0)[:, None] if span > 1e-9 else np.zeros((K + 1, 1))
        pos[:, i] = on_guide + w * off
    pos[:, -1] = traj.x
    vel = np.gradient(pos, traj.t, axis=0)
    vel[:, -1] = traj.xd
    return ChainReference(
        guide=guide,
        start=P.copy(),
        start_arcs=start_arcs,
        final=final,
        final_arcs=final_arcs,
        parked=int(parked),
        trajectory=traj,
        positions=pos,
        velocities=vel,
    )
