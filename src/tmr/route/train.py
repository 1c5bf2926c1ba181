"""Sequential ("train") references: the chain advances along the route robot by robot, every state checked.

The trailing references of :func:`tmr.route.references.chain_reference` move every robot at once and leave the hard
limits
to the QP; in a narrow door or round a wrapped corner that can deadlock (a follower overtaken by the one behind it, a
tether pressed on a jamb). This module builds references that keep every hard limit by construction, at the cost of a
longer plan (``formulations/route.md``, "Train references"):

* robot i has its own **path**: the guide from its start to its station's foot, then the short offset to the station
  (the :class:`tmr.route.references.ChainReference` it refines: same guide, same start, same stations);
* **sweeps**, leader first: robot i advances along its path as far as every limit lets it while the others stand
  still — its clearance, the clearance and length of both its tethers, its distance to every other robot — tested
  at every ``step`` [m] of the advance (vectorised). A limit the start already breaks (a start tether nearer than the
  margin) may not get worse, the QP's own rule;
* until every robot is at its station. When no robot can advance, local **repairs** (:func:`_unblock`): a straight
  cut along a robot's own path, a follower reeling in along its tether, a blocking robot stepping aside, a robot
  paying out along its tether; after ``MAX_STUCK_PER_ROBOT`` × N repairs without progress, :class:`TrainError` names
  every robot short of its station, where it stopped and the limits its next step breaks. A stalled search runs
  again with every path pulled taut (:func:`_pulled`); then along a guide that crosses each narrow door straight
  along the door's axis (:func:`_axial`: a robot in a door has its neighbours on the axis, not round a jamb); then
  along that guide pulled taut, no robot passing, along the guide, the robot ahead of it (:func:`_attempts`);
* **timing**: every advance follows the minimum-jerk law within the leader's speed and acceleration limits, stopping
  at each turn of its path sharper than :data:`TURN_STOP`; the advances of one sweep run in consecutive groups, the
  advances of a group together: all the sweep's advances left if every sampled joint state keeps the same limits,
  else the next one joined by those after it, one at a time, while the joint states keep them (an advance alone
  always does).

The result is a :class:`tmr.route.references.ChainReference` (the leader's trajectory and every robot's reference), so
the
QP tracks it exactly as it tracks the trailing references.

Low obstacles: the robots' positions and moves are tested in ``env``, the tethers' chords in
``env.tether_environment`` (:func:`tmr.route.geodesic.tether_env`; a chord may pass over a low obstacle).
"""

from __future__ import annotations

import heapq
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray

from tmr.route.geodesic import tether_env
from tmr.route.path import Trajectory, min_jerk
from tmr.route.references import ChainReference, leader_duration
from tmr.route.route import RouteVerdict, guide_arcs, point_at

Array = NDArray[np.float64]

__all__ = ["TRAIN_CLEARANCE", "TrainError", "TrainLimits", "train_reference"]

#: Clearance [m] every robot and tether keeps in the train's states: more than the QP's d_safe (0.05 m), less than
#: the route's chords in a narrow door (0.06 m), so the stations themselves are valid states.
TRAIN_CLEARANCE = 0.055
#: Clearance [m] of the straight cuts that pull each robot's path taut (the route's own margin).
TAUT_CLEARANCE = 0.15
#: Arc step [m] at which an advance is tested.
TRAIN_STEP = 0.05
#: Turn [rad] of a robot's path beyond which its advance stops at the vertex (the reference's velocity keeps a
#: direction: no acceleration spike at a corner of the polyline).
TURN_STOP = math.radians(10.0)
#: Shortest duration [s] of one timed piece of an advance.
MIN_PIECE = 0.3


class TrainError(RouteVerdict):
    """The train found no sequence of advances to the stations (a search verdict, not a proof: exit 1)."""

    proven = False


@dataclass(frozen=True)
class TrainLimits:
    """Limits every state of the train keeps.

    Attributes:
        spans: (N, 2) [d_lo, d_max] of each tether [m] (tether i joins robot i − 1, or the anchor, to robot i).
        separation: least distance between two robots' centres [m] (2r + margin).
        clearance: least clearance of every robot and tether from the obstacles grown by r [m].
    """

    spans: Array
    separation: float
    clearance: float = TRAIN_CLEARANCE


#: Fewest points for which :meth:`_Paths.nearest_arcs` uses a k-d tree, and how many nearest samples it measures
#: (at least 2: the last is compared with the nearest).
NEAREST_TREE = 16
NEAREST_K = 4


def _sub(P: Array, arcs: Array, u0: float, u1: float) -> Array:
    """The part of polyline P (arcs) between arc lengths u0 ≤ u1 [m], as a polyline."""
    inner = P[(arcs > u0 + 1e-9) & (arcs < u1 - 1e-9)]
    return np.vstack([point_at(P, arcs, u0), inner, point_at(P, arcs, u1)])


def _dedupe(P: Array) -> Array:
    return P[np.r_[True, np.linalg.norm(np.diff(P, axis=0), axis=1) > 1e-9]]


class _Paths:
    """Every robot's path (polyline, arcs, length [m]) and how far along it the robot is; the guide it follows."""

    def __init__(self, ref: ChainReference, env: Any = None, taut: float | None = None, order: bool = False) -> None:
        self.env, self.taut, self.order = env, taut, order
        self.guide, self.garcs = ref.guide, guide_arcs(ref.guide)
        self.foot = np.asarray(ref.final_arcs, dtype=float)
        self.station = np.asarray(ref.final, dtype=float)
        self.garc = np.asarray(ref.start_arcs, dtype=float).copy()  # each robot's progress along the guide [m]
        self.near = self.garc.copy()  # the guide arc nearest each robot (the progress less a rejoin's look-ahead) [m]
        N = len(ref.start)
        self.points: list[Array] = [np.zeros((1, 2))] * N
        self.arcs: list[Array] = [np.zeros(1)] * N
        self.u = np.zeros(N)
        for i in range(N):
            self.rebase(i, np.asarray(ref.start[i], dtype=float), float(self.garc[i]))

    @property
    def length(self) -> Array:
        return np.array([float(a[-1]) for a in self.arcs])

    def rebase(self, i: int, here: Array, garc: float) -> None:
        """Robot i's path from ``here``: straight to the guide at arc ``garc``, along it to its station's foot,
        then to the station."""
        garc = min(max(garc, float(self.garc[i])), float(self.foot[i]))
        if garc > self.garc[i] + 1e-9:
            self.near[i] = self.nearest(here, float(self.garc[i]), garc)[1]
        self.garc[i] = garc
        pts = [here[None]]
        if self.foot[i] > garc + 1e-9:
            pts.append(_sub(self.guide, self.garcs, garc, float(self.foot[i])))
        pts.append(self.station[i][None])
        P = _dedupe(np.vstack(pts))
        if self.env is not None and self.taut is not None and len(P) > 2:
            P = _pulled(self.env, P, self.taut)
        self.points[i], self.arcs[i], self.u[i] = P, guide_arcs(P), 0.0

    def at(self, i: int, u: Array | float) -> Array:
        return point_at(self.points[i], self.arcs[i], u)

    def advance(self, i: int, u1: float) -> Array:
        """Move robot i to arc u1 of its path; returns the polyline it travelled."""
        part = _sub(self.points[i], self.arcs[i], float(self.u[i]), u1)
        self.u[i] = u1
        here = self.at(i, u1)
        lo = float(self.garc[i])
        hi = min(float(self.foot[i]), lo + float(self.arcs[i][-1]) + 1.0)
        if hi > lo:  # progress along the guide: the nearest guide point in [lo, hi]
            self.garc[i] = self.near[i] = self.nearest(here, lo, hi)[1]
        return part

    def nearest(self, Q: Array, lo: float, hi: float) -> tuple[Array, float]:
        """Guide arcs sampled every 0.02 m over [lo, hi] (lo < hi) [m] and the one nearest the point Q."""
        s, arcs = self.nearest_arcs(np.asarray(Q, dtype=float).reshape(1, 2), lo, hi)
        return s, float(arcs[0])

    def nearest_arcs(self, pts: Array, lo: float, hi: float) -> tuple[Array, Array]:
        """Guide arcs sampled every 0.02 m over [lo, hi] (lo < hi) [m] and, for each of ``pts`` (m, 2), the one
        nearest it: the first sample of the least distance (``np.linalg.norm`` of the differences, ``np.argmin``).

        For many points, a k-d tree (``scipy.spatial.cKDTree``) gives each point its ``NEAREST_K`` nearest samples,
        and those samples' distances, measured as above, give the same first sample of the least distance — unless
        the k-th is no farther than the nearest up to rounding (a sample beyond the k could tie it): such points,
        and small queries, measure every sample (256 points at a time)."""
        s = np.linspace(lo, hi, max(2, int((hi - lo) / 0.02) + 1))
        G = point_at(self.guide, self.garcs, s)
        pts = np.asarray(pts, dtype=float).reshape(-1, 2)
        best = np.empty(len(pts), dtype=np.intp)
        every = np.arange(len(pts))
        if len(pts) >= NEAREST_TREE and len(G) > NEAREST_K:
            from scipy.spatial import cKDTree

            d, j = cKDTree(G).query(pts, k=NEAREST_K)
            j = np.sort(j, axis=1)  # sample order: argmin's first of the least is the first sample
            best = j[np.arange(len(pts)), np.argmin(np.linalg.norm(pts[:, None] - G[j], axis=2), axis=1)]
            every = np.flatnonzero(d[:, -1] <= d[:, 0] * (1.0 + 1e-9) + 1e-12)
        for k in range(0, len(every), 256):
            rows = every[k : k + 256]
            best[rows] = np.argmin(np.linalg.norm(pts[rows, None] - G[None], axis=2), axis=1)
        return s, s[best]


def _pulled(env: Any, P: Array, clearance: float, step: float = 0.1, reach: int = 150) -> Array:
    """Polyline P pulled taut: from each kept point straight to the farthest later point (samples every ``step``
    [m], at most ``reach`` samples on) joined to it by a segment keeping ``clearance`` [m]; where none is, the next
    sample (the path itself). A start placement's hairpin (the guide running on past a robot and back) is cut."""
    arcs = guide_arcs(P)
    S = point_at(P, arcs, np.union1d(np.arange(0.0, arcs[-1], step), arcs))
    out, i = [S[0]], 0
    while i < len(S) - 1:
        js = np.arange(i + 1, min(len(S), i + 1 + reach))
        free = np.flatnonzero(env.segment_is_free(S[i], S[js], clearance))
        i = int(js[free[-1]]) if len(free) else i + 1
        out.append(S[i])
    return _dedupe(np.asarray(out))


#: Clearance [m] below which a guide point is in a narrow passage; how far [m] across the passage its other side is
#: looked for; the half-lengths [m] of the straight crossing tried, longest first (:func:`_axial`).
DOOR_CLEARANCE = 0.3
DOOR_ACROSS = 0.4
DOOR_HALF = (1.6, 1.3, 1.0)
#: How far [m] beyond the ends of a straight crossing, along its axis, the guide is rejoined.
DOOR_BEYOND = 0.3


def _axial(env: Any, ref: ChainReference, clearance: float) -> ChainReference | None:
    """``ref`` with its guide crossing each narrow door straight along the door's axis: the guide is cut before the
    door, runs to a point ``h`` (:data:`DOOR_HALF`) before the door's narrowest point on the line through it
    perpendicular to its jambs, through it, to the point ``h`` after, and rejoins the guide beyond; a robot in the
    door then has both neighbours on its axis, not round a jamb. Start and station arcs are mapped onto the new
    guide. None if the guide crosses no door so."""
    G, arcs = ref.guide, guide_arcs(ref.guide)
    L = float(arcs[-1])
    s = np.arange(0.0, L, 0.02)
    P = point_at(G, arcs, s)
    clr = np.asarray(env.exact_clearance(P), float)
    narrow = np.flatnonzero(clr < DOOR_CLEARANCE)
    if not len(narrow):
        return None
    runs = np.split(narrow, np.flatnonzero(np.diff(narrow) > 1) + 1)
    boundary = shapely.boundary(env.free)
    old, new, pieces, last = [0.0], [0.0], [], 0.0
    for run in runs:
        Q = P[run]
        B = shapely.get_coordinates(shapely.shortest_line(boundary, shapely.points(Q)))[0::2]
        n = (B - Q) / np.maximum(np.linalg.norm(B - Q, axis=1), 1e-12)[:, None]
        rays = shapely.linestrings(np.stack([Q, Q - DOOR_ACROSS * n], axis=1))
        across = shapely.distance(shapely.points(Q), shapely.intersection(rays, boundary))
        width = clr[run] + np.where(np.isfinite(across), across, np.inf)
        j = int(np.argmin(width))
        if not np.isfinite(width[j]) or float(s[run[j]]) < last + 1e-9:
            continue  # open on the other side: a corner, not a door
        sc = float(s[run[j]])
        c = 0.5 * (B[j] + Q[j] - float(across[j]) * n[j])  # the middle of the door
        b = shapely.get_coordinates(shapely.shortest_line(boundary, shapely.points(c)))[0]
        if np.linalg.norm(b - c) < 1e-9:
            continue
        normal = (b - c) / np.linalg.norm(b - c)  # towards the nearer jamb
        t = np.array([-normal[1], normal[0]])  # the door's axis
        ahead = point_at(G, arcs, min(sc + 0.3, L)) - point_at(G, arcs, max(sc - 0.3, 0.0))
        if float(np.dot(t, ahead)) < 0:
            t = -t
        for h in DOOR_HALF:
            a, z = c - h * t, c + h * t
            if not bool(env.segment_is_free(a, z, clearance)):
                continue
            back = np.arange(max(last, sc - 3 * h - 1.0), sc, 0.05)[::-1]
            fwd = np.arange(sc, min(L, sc + 3 * h + 1.0), 0.05)
            Pb, Pf = point_at(G, arcs, back), point_at(G, arcs, fwd)
            beyond_b = (a - Pb) @ t > DOOR_BEYOND  # the guide rejoined behind a and ahead of z, along the axis
            beyond_f = (Pf - z) @ t > DOOR_BEYOND
            fb = np.flatnonzero(beyond_b & env.segment_is_free(Pb, a, clearance))
            ff = np.flatnonzero(beyond_f & env.segment_is_free(z, Pf, clearance))
            if not len(ff):
                continue
            s_out = float(fwd[ff[0]])
            if len(fb):
                pieces.append((float(back[fb[0]]), s_out, np.vstack([a, c, z])))
            elif pieces and _joins(env, pieces[-1][2][-1], a, t, clearance):  # straight on from the last door
                pieces[-1] = (pieces[-1][0], s_out, np.vstack([pieces[-1][2], a, c, z]))
            else:
                continue
            last = s_out
            break
    if not pieces:
        return None
    parts, pos = [], 0.0
    for s_in, s_out, mid in pieces:
        head = _sub(G, arcs, pos, s_in)
        parts.append(head)
        before = new[-1] + (s_in - pos)
        seg = np.vstack([head[-1:], mid, point_at(G, arcs, s_out)[None]])
        old += [s_in, s_out]
        new += [before, before + float(guide_arcs(seg)[-1])]
        parts.append(mid)
        pos = s_out
    parts.append(_sub(G, arcs, pos, L))
    old.append(L)
    new.append(new[-1] + (L - pos))
    guide = _dedupe(np.vstack(parts))
    scale = float(guide_arcs(guide)[-1]) / new[-1]
    remap = partial(np.interp, xp=np.asarray(old), fp=np.asarray(new) * scale)
    return replace(
        ref,
        guide=guide,
        start_arcs=remap(np.asarray(ref.start_arcs, float)),
        final_arcs=remap(np.asarray(ref.final_arcs, float)),
    )


def _joins(env: Any, p: Array, a: Array, t: Array, clearance: float) -> bool:
    """Whether point a lies beyond p along axis t (by :data:`DOOR_BEYOND`) and is joined to it by a free segment."""
    return float((a - p) @ t) > DOOR_BEYOND and bool(env.segment_is_free(p, a, clearance))


class _Fast:
    """The environment's exact tests, with a fast exact pre-filter for segments at the train's clearance c: a
    segment inside the free region eroded by c + 2 mm is free, one not covered by it eroded by c − 2 mm is
    not; only the others get the exact distance. A segment whose start is inside a region lies in its interior iff it
    does not meet the region's boundary (GEOS ``intersects`` on the prepared boundary: the test
    :meth:`tmr.world.environment.Environment.segment_is_free` makes, far cheaper than ``covers`` on a polygon with
    many holes). A segment that only touches a boundary from inside counts as meeting it: at the inner region's
    it goes to the exact distance, at the outer region's its clearance there is c − 2 mm < c, not free."""

    BAND = 0.002  # [m]

    def __init__(self, env: Any, clearance: float) -> None:
        self.env, self.c = env, float(clearance)
        self.inner = env.free.buffer(-(self.c + self.BAND), quad_segs=16)
        self.outer = env.free.buffer(-max(0.0, self.c - self.BAND), quad_segs=16)
        self.inner_edge = shapely.boundary(self.inner)
        self.outer_edge = shapely.boundary(self.outer)
        for geom in (self.inner, self.outer, self.inner_edge, self.outer_edge):
            shapely.prepare(geom)

    def exact_clearance(self, points: Any) -> Any:
        return self.env.exact_clearance(points)

    def segment_clearance(self, a: Any, b: Any) -> Any:
        return self.env.segment_clearance(a, b)

    def clear_above(self, pts: Array, least: float) -> NDArray[np.bool_]:
        """Whether each point's exact clearance is > ``least`` [m]: inside the inner region it is ≥ c + 2 mm,
        outside the outer one < c − 2 mm; only the points between get the exact distance."""
        out = np.zeros(len(pts), dtype=bool)
        unsure = np.ones(len(pts), dtype=bool)
        if least < self.c + self.BAND:
            sure = shapely.contains_xy(self.inner, pts[:, 0], pts[:, 1])
            out[sure], unsure[sure] = True, False
        if least >= self.c - self.BAND:
            unsure &= shapely.contains_xy(self.outer, pts[:, 0], pts[:, 1])
        idx = np.flatnonzero(unsure)
        if len(idx):
            out[idx] = np.asarray(self.env.exact_clearance(pts[idx]), float) > least
        return out

    def segment_is_free(self, a: Any, b: Any, margin: float = 0.0) -> NDArray[np.bool_]:
        if abs(float(margin) - self.c) > 1e-6:
            return self.env.segment_is_free(a, b, margin)
        A, B = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
        shape = A.shape[:-1]
        A, B = A.reshape(-1, 2), B.reshape(-1, 2)
        out = np.zeros(len(A), dtype=bool)
        # an end outside the outer region: not free (a point test, far cheaper than ``covers`` on a segment)
        ends = shapely.contains_xy(self.outer, A[:, 0], A[:, 1]) & shapely.contains_xy(self.outer, B[:, 0], B[:, 1])
        idx = np.flatnonzero(ends)
        lines = shapely.linestrings(np.stack([A[idx], B[idx]], axis=1))
        inside = shapely.contains_xy(self.inner, A[idx, 0], A[idx, 1])
        inside[inside] = ~shapely.intersects(self.inner_edge, lines[inside])
        out[idx[inside]] = True
        unsure = idx[~inside][~shapely.intersects(self.outer_edge, lines[~inside])]
        if len(unsure):
            out[unsure] = self.env.segment_is_free(A[unsure], B[unsure], margin)
        return out.reshape(shape)


def _environments(env: Any, clearance: float) -> tuple[_Fast, _Fast]:
    """The robots' and the tethers' environments (:func:`tmr.route.geodesic.tether_env`: low obstacles left out) at
    the train's ``clearance`` [m], pre-filtered (:class:`_Fast`; one object if they are the same)."""
    robots = _Fast(env, clearance)
    tenv = tether_env(env)
    return robots, robots if tenv is env else _Fast(tenv, clearance)


def _clear(env: _Fast, least: float, pts: Array) -> NDArray[np.bool_]:
    return env.clear_above(np.asarray(pts, dtype=float).reshape(-1, 2), least)


def _tether_clear(env: Any, end: Array, margin: float, pts: Array) -> NDArray[np.bool_]:
    return np.asarray(env.segment_is_free(end, pts, margin))


def _within(centre: Array, lo: float, hi: float, pts: Array) -> NDArray[np.bool_]:
    """lo ≤ |pts − centre| ≤ hi."""
    n = np.linalg.norm(pts - centre, axis=1)
    return (n >= lo) & (n <= hi)


def _behind(paths: _Paths, i: int, pts: Array) -> NDArray[np.bool_]:
    """Whether the guide point nearest each of pts (within robot i's reach along the guide) is not beyond the one
    nearest robot i + 1 (nor robot i's own, if robot i is already beyond it)."""
    lo = float(paths.near[i])
    hi = min(float(paths.foot[i]), float(paths.garc[i]) + float(paths.arcs[i][-1]) + 1.0)
    bound = max(float(paths.near[i + 1]), lo) + 1e-9
    if hi <= bound:
        return np.ones(len(pts), dtype=bool)
    return paths.nearest_arcs(pts, lo, hi)[1] <= bound


#: (name, cost, test) of each limit of a move of one robot (:meth:`_State._checks`).
_Checks = list[tuple[str, int, Callable[[Array], NDArray[np.bool_]]]]


class _State:
    """The train's current positions and the tests of a move of one robot."""

    def __init__(
        self,
        env: Any,
        base: Array,
        X: Array,
        limits: TrainLimits,
        paths: _Paths | None = None,
        tenv: Any = None,
    ) -> None:
        self.env, self.base, self.X, self.lim, self.paths = env, base, X, limits, paths
        self.tenv = env if tenv is None else tenv  # the tethers' world (without the low obstacles)
        self.compact = True  # the SLACK rule (advances along the paths; repairs may stretch a tether)

    def _tethers(self, i: int) -> list[tuple[Array, int, str]]:
        """(other end, span-limit row, name) of robot i's tethers."""
        out = [(self.base if i == 0 else self.X[i - 1], i, "the anchor" if i == 0 else f"robot {i}")]
        if i < len(self.X) - 1:
            out.append((self.X[i + 1], i + 1, f"robot {i + 2}"))
        return out

    def _checks(self, i: int) -> _Checks:
        """(name, cost, test) of every limit for robot i moved to points (m, 2), the others where they are; cost 0:
        arithmetic, 1: point clearance, 2: segment clearance. A limit robot i already breaks may not get worse."""
        env, c, X, here = self.env, self.lim.clearance, self.X, self.X[i]
        now = float(env.exact_clearance(here))
        out = [("clearance", 1, partial(_clear, env, min(c, now) - 1e-9))]
        for end, row, name in self._tethers(i):
            now = float(self.tenv.segment_clearance(end, here))
            margin = c if now > c else max(0.0, now - 1e-9)
            out.append((f"clearance of the tether to {name}", 2, partial(_tether_clear, self.tenv, end, margin)))
            d = float(np.linalg.norm(here - end))
            lo, hi = self.lim.spans[row]
            out.append(
                (f"length of the tether to {name}", 0, partial(_within, end, min(lo, d) - 1e-9, max(hi, d) + 1e-9))
            )
        if self.compact and i > 0 and self.paths is not None and self.paths.u[i - 1] < self.paths.length[i - 1] - 1e-9:
            # compact: a robot does not run farther than SLACK ahead of a follower short of its station
            slack = max(SLACK, float(np.linalg.norm(here - X[i - 1])))
            out.append((f"slack of the tether to robot {i}", 0, partial(_within, X[i - 1], -np.inf, slack)))
        paths = self.paths
        if paths is not None and paths.order and i < len(X) - 1 and paths.u[i + 1] < paths.length[i + 1] - 1e-9:
            # ordered: a robot does not pass, along the guide, the robot ahead of it short of its station
            out.append(("order behind the next robot", 1, partial(_behind, paths, i)))
        for j in range(len(X)):
            if j != i:
                need = min(self.lim.separation, float(np.linalg.norm(X[j] - here))) - 1e-9
                out.append((f"distance to robot {j + 1}", 0, partial(_within, X[j], need, np.inf)))
        return out

    def tests(self, i: int, pts: Array) -> list[tuple[str, NDArray[np.bool_]]]:
        """(name, passes) of every limit for robot i at each of ``pts`` (m, 2), the others where they are."""
        return [(name, test(pts)) for name, _, test in self._checks(i)]

    def _ordered(self, i: int, checks: _Checks | None) -> _Checks:
        """``checks`` (default: robot i's :meth:`_checks` in the present state), the cheapest first."""
        return sorted(self._checks(i) if checks is None else checks, key=lambda check: check[1])

    def valid(self, i: int, pts: Array, checks: _Checks | None = None) -> NDArray[np.bool_]:
        """All of :meth:`tests` at once, the cheap ones first: the exact geometry only where those pass; ``checks``:
        robot i's :meth:`_checks` in the present state, if the caller has them. :meth:`valid_groups` with a group
        per point."""
        pts = np.asarray(pts, dtype=float).reshape(-1, 2)
        return self.valid_groups(i, pts, np.arange(len(pts)), len(pts), checks)

    def valid_groups(
        self, i: int, pts: Array, owner: NDArray[np.intp], n: int, checks: _Checks | None = None
    ) -> NDArray[np.bool_]:
        """Whether every point of each of ``n`` groups keeps all of :meth:`tests` (``owner``: each point's group;
        ``checks`` as in :meth:`valid`), each group passing iff all its points pass — but a group that fails a check
        is dropped at once, so the costlier checks test only the points of groups still passing."""
        pts = np.asarray(pts, dtype=float).reshape(-1, 2)
        alive = np.ones(n, dtype=bool)
        idx = np.arange(len(pts))
        for _, _, test in self._ordered(i, checks):
            if not len(idx):
                break
            alive[owner[idx[~test(pts[idx])]]] = False
            idx = idx[alive[owner[idx]]]
        return alive

    def valid_prefix(self, i: int, pts: Array, checks: _Checks | None = None) -> int:
        """How many of ``pts``, from the first, keep all of :meth:`tests`: the first failure of :meth:`valid` (or all
        of them) — each check testing only the points before the first failure so far; ``checks`` as in
        :meth:`valid`."""
        pts = np.asarray(pts, dtype=float).reshape(-1, 2)
        k = len(pts)
        for _, _, test in self._ordered(i, checks):
            if not k:
                break
            ok = test(pts[:k])
            if not ok.all():
                k = int(np.argmin(ok))
        return k


#: Radius [m] and grid step [m] of the positions a follower may step to, off its path, so that the robot ahead can
#: go on (:func:`_repair`); how far ahead [m] that robot's progress is scored.
REPAIR_RADIUS = 1.0
REPAIR_GRID = 0.03
REPAIR_LOOKAHEAD = 2.0
#: How many of the best grid points a repair tries (a straight move to each).
REPAIR_TRIES = 50
#: Grid points in a repair's first batch of costly tests (then four times as many, :func:`_repair`).
REPAIR_BATCH = 64
#: Longest tether [m] between a robot and a follower that has not reached its station, in a normal advance: the
#: chain stays compact, so that no robot runs so far ahead that the one behind cannot follow it round a corner.
SLACK = 2.0
#: Most moves of the search before it gives up (a guard against a cycle of repairs).
MAX_MOVES = 5000
#: Most repairs in a row, per robot, that bring no progress along the guide before the search gives up.
MAX_STUCK_PER_ROBOT = 6


def _repair(state: _State, paths: _Paths, mover: int, other: int, step: float) -> Array | None:
    """A free position Q within ``REPAIR_RADIUS`` of robot ``mover``, reachable by a straight move keeping every
    limit, that lets robot ``other`` advance farthest along its path — far enough from it and, for a neighbour,
    joined to it by a free tether of allowed length (ties: the nearest Q); None if no Q lets ``other`` advance.

    The grid points that keep every limit are ranked by (−gain, distance to the mover, grid order), and the first
    ``REPAIR_TRIES`` are tried in turn (a straight move to each). Only the cheap limits (cost ≤ 1: arithmetic, the
    point's clearance, the order along the guide) are tested on every point. A point's gain from the distances and
    spans alone bounds its gain from above; the costly tests (the clearance of the mover's tethers, of the tether to
    each of ``other``'s steps) run lazily, in the order of that bound, in batches (``REPAIR_BATCH`` points, then four
    times as many, or all the rest when no tested point is left to try), and a tested point that ranks before every
    untested point's bound is the next in the ranking. The ranking is that of testing every point
    (``tests/test_train.py::test_a_repair_is_the_exhaustive_rankings_first_reachable_point``). On the 316 repairs
    of the 8-robot train search of narrow-far-2856891376 it takes 0.25× the time in all; a single repair where few
    points pass, tested in more than one batch, can take longer (up to 1.5×; ``benchmarks/train_repair.py``).
    """
    lim, X, tenv = state.lim, state.X, state.tenv
    r = np.arange(-REPAIR_RADIUS, REPAIR_RADIUS + 1e-9, REPAIR_GRID)
    G = X[mover] + np.stack(np.meshgrid(r, r, indexing="ij"), axis=-1).reshape(-1, 2)
    G = G[np.linalg.norm(G - X[mover], axis=1) <= REPAIR_RADIUS]
    u = np.arange(paths.u[other] + step, min(paths.length[other], paths.u[other] + REPAIR_LOOKAHEAD) + 1e-9, step)
    if not len(u):
        return None
    checks = state._checks(mover)  # the state does not change here
    cheap = [check for check in checks if check[1] < 2]  # arithmetic, the point's clearance, the guide's order
    costly = [check for check in checks if check[1] >= 2]
    G = G[state.valid(mover, G, cheap)]
    ahead = paths.at(other, u)
    neighbours = abs(mover - other) == 1
    length = np.linalg.norm(G[:, None] - ahead[None], axis=2)
    ok = length >= lim.separation
    if neighbours:  # their tether too
        lo, hi = lim.spans[max(mover, other)]
        ok &= (length >= lo) & (length <= hi)
    bound = np.where(ok.all(axis=1), len(u), np.argmin(ok, axis=1))  # the prefix of ``other``'s steps ok allows
    dist = np.linalg.norm(G - X[mover], axis=1)
    pending = np.lexsort((dist, -bound))  # by bound; ties: the nearest, then the grid's order (lexsort is stable)
    pending = pending[bound[pending] > 0]  # a point of gain 0 ends the ranking's useful part: never tested

    def gains(idx: NDArray[np.intp]) -> tuple[NDArray[np.intp], NDArray[np.int_]]:
        """The points of ``idx`` that keep the limits, and the prefix of ``other``'s steps each allows."""
        if neighbours:  # ``other``'s first step at least
            idx = idx[tenv.segment_is_free(G[idx], ahead[0], lim.clearance)]
        idx = idx[state.valid(mover, G[idx], costly)] if len(idx) else idx
        gain = np.zeros(len(idx), dtype=int)
        alive = np.arange(len(idx))
        for col in range(len(u)):  # column by column
            alive = alive[ok[idx[alive], col]]
            if neighbours and col and len(alive):  # (step 0's tether: tested above)
                alive = alive[tenv.segment_is_free(G[idx[alive]], ahead[col], lim.clearance)]
            if not len(alive):
                break
            gain[alive] += 1
        return idx, gain

    ranked: list[tuple[int, float, int]] = []  # tested points not yet tried, as a heap of (−gain, distance, index)
    tried, batch, p = 0, REPAIR_BATCH, 0
    while tried < REPAIR_TRIES:
        q = int(pending[p]) if p < len(pending) else -1
        if q >= 0 and (not ranked or ranked[0] > (-int(bound[q]), float(dist[q]), q)):
            # an untested point may rank before every tested one: test the next batch of them
            idx, gain = gains(pending[p : p + batch])
            ranked.extend((-g, float(dist[k]), k) for k, g in zip(idx.tolist(), gain.tolist(), strict=True))
            heapq.heapify(ranked)
            # none left to try: few points pass here, so test all the rest at once
            p, batch = p + batch, 4 * batch if ranked else len(pending)
            continue
        if not ranked:
            return None
        g, _, k = heapq.heappop(ranked)
        if g == 0:
            return None
        tried += 1
        m = max(2, math.ceil(float(np.linalg.norm(G[k] - X[mover])) / step) + 1)
        line = X[mover] + np.linspace(0.0, 1.0, m)[:, None] * (G[k] - X[mover])
        if state.valid_prefix(mover, line, checks) == len(line):
            return G[k]
    return None


def _search(
    fast: tuple[_Fast, _Fast], base: Array, paths: _Paths, limits: TrainLimits, step: float
) -> list[list[tuple[int, Array]]]:
    """Moves (robot, polyline travelled), grouped by sweep (module docstring); ``fast``: the robots' and the tethers'
    environments at the train's clearance (:func:`_environments`)."""
    N = len(paths.length)
    X = np.array([paths.at(i, 0.0) for i in range(N)])
    state = _State(fast[0], base, X, limits, paths, fast[1])
    sweeps: list[list[tuple[int, Array]]] = []
    count = 0
    stuck, best = 0, float(paths.garc.sum() + np.sum(paths.u >= paths.length - 1e-9))
    while np.any(paths.u < paths.length - 1e-9):
        moves = []
        for i in range(N - 1, -1, -1):
            L = float(paths.length[i])
            if paths.u[i] >= L - 1e-9:
                continue
            cand = np.append(np.arange(paths.u[i] + step, L - 1e-9, step), L)
            k = state.valid_prefix(i, paths.at(i, cand))
            if k == 0:
                continue
            moves.append((i, paths.advance(i, float(cand[k - 1]))))
            X[i] = paths.at(i, paths.u[i])
        if not moves:
            moves = _unblock(state, paths, step)
            stuck += 1
        progress = float(paths.garc.sum() + np.sum(paths.u >= paths.length - 1e-9))
        if progress > best + step:
            stuck, best = 0, progress
        count += len(moves)
        if not moves or count > MAX_MOVES or stuck > MAX_STUCK_PER_ROBOT * N:
            raise TrainError(_deadlock(state, paths, step))
        sweeps.append(moves)
    return sweeps


def _unblock(state: _State, paths: _Paths, step: float) -> list[tuple[int, Array]]:
    """One repair move when no robot can advance along its path (tried in this order, leader-most robot first):
    a straight cut to a point farther along its own path (:func:`_shortcut`); for a robot j whose next step a
    neighbour's tether or another robot's distance blocks: its follower reels in along their tether
    (:func:`_along_tether`), the blocking robot steps aside so that j can go on (:func:`_repair`), j steps aside so
    that its follower can close up, or j pays out along their tether; [] if nothing helps."""
    todo = [int(j) for j in np.flatnonzero(paths.u < paths.length - 1e-9)[::-1]]
    state.compact = False  # repairs may stretch a tether beyond SLACK
    try:
        for j in todo:
            move = _shortcut(state, paths, j, step)
            if move is not None:
                return [move]
        return _repairs(state, paths, todo, step)
    finally:
        state.compact = True


def _repairs(state: _State, paths: _Paths, todo: list[int], step: float) -> list[tuple[int, Array]]:
    """The repairs of :func:`_unblock` after the straight cuts."""
    for j in todo:
        broken = _broken(state, paths, j, step)
        blockers = sorted({int(m.group(1)) - 1 for name in broken for m in [_ROBOT.search(name)] if m}, reverse=True)
        follower = any(name.endswith(f"tether to robot {j}") for name in broken) and j > 0
        if follower:
            Q = _along_tether(state, j - 1, True, step)  # the follower reels in along the tether
            if Q is not None:
                return [_step_to(state, paths, j - 1, Q)]
        for k in blockers:
            Q = _repair(state, paths, k, j, step)
            if Q is not None:
                return [_step_to(state, paths, k, Q)]
        if follower:
            Q = _repair(state, paths, j, j - 1, step)
            if Q is not None:
                return [_step_to(state, paths, j, Q)]
            Q = _along_tether(state, j - 1, False, step)  # j pays out along it, if that is forward
            if Q is not None and _forward(paths, j, Q - state.X[j]):
                return [_step_to(state, paths, j, Q)]
    return []


_ROBOT = re.compile(r"robot (\d+)")


def _broken(state: _State, paths: _Paths, i: int, step: float) -> list[str]:
    """Names of the limits robot i's next step along its path breaks."""
    nxt = paths.at(i, np.array([min(paths.u[i] + step, paths.length[i])]))
    return [name for name, passes in state.tests(i, nxt) if not passes[0]]


def _forward(paths: _Paths, i: int, d: Array) -> bool:
    """Whether direction d points within 60° of the guide's direction at robot i's progress."""
    a = float(paths.garc[i])
    t = point_at(paths.guide, paths.garcs, min(a + 0.2, float(paths.garcs[-1]))) - point_at(paths.guide, paths.garcs, a)
    n = float(np.linalg.norm(t) * np.linalg.norm(d))
    return n > 0 and float(np.dot(t, d)) > 0.5 * n


#: How far ahead along its path [m] a blocked robot looks for a straight cut.
SHORTCUT_AHEAD = 4.0


def _shortcut(state: _State, paths: _Paths, i: int, step: float) -> tuple[int, Array] | None:
    """Robot i moves straight to the farthest point of its path within :data:`SHORTCUT_AHEAD` that it can reach
    so, keeping every limit at each ``step``; None if there is none beyond its next step."""
    u0, L = float(paths.u[i]), float(paths.length[i])
    end = min(L, u0 + SHORTCUT_AHEAD)
    targets = np.append(np.arange(u0 + 2 * step, end - 1e-9, 2 * step), end)
    here = state.X[i].copy()
    Q = paths.at(i, targets)
    counts = np.maximum(1, np.ceil(np.linalg.norm(Q - here, axis=1) / step).astype(int))
    owner = np.repeat(np.arange(len(targets)), counts)
    frac = (np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts) + 1) / counts[owner]
    lines = here + frac[:, None] * (Q[owner] - here)  # every line's samples after ``here``, its end included
    good = np.flatnonzero(state.valid_groups(i, lines, owner, len(targets)))
    if not len(good):
        return None
    k = int(good[-1])
    paths.advance(i, float(targets[k]))
    state.X[i] = Q[k]
    return i, np.vstack([here, Q[k]])


def _step_to(state: _State, paths: _Paths, i: int, Q: Array) -> tuple[int, Array]:
    """Move robot i straight to Q (already checked) and re-base its path there."""
    part = np.vstack([state.X[i], Q])
    state.X[i] = Q
    paths.rebase(i, Q, _rejoin_arc(state.env, paths, i, Q, state.lim.clearance))
    return i, part


#: Longest pay-out [m] of the robot ahead along its tether in one repair.
PAY_OUT = 1.0


def _along_tether(state: _State, i: int, reel_in: bool, step: float) -> Array | None:
    """The farthest position, along the line of the tether between robots i and i + 1 and in the direction from i
    to i + 1, of robot i (``reel_in``: toward robot i + 1, until their separation) or robot i + 1 (pay out, away
    from robot i, at most :data:`PAY_OUT`) reachable keeping every limit at each ``step``; None if it cannot move
    one step."""
    X = state.X
    mover = i if reel_in else i + 1
    d = X[i + 1] - X[i]
    n = float(np.linalg.norm(d))
    if n < 1e-9:
        return None
    reach = n - state.lim.separation if reel_in else PAY_OUT
    if reach < step:
        return None
    t = np.append(np.arange(step, reach, step), reach)
    pts = X[mover] + (d / n)[None] * t[:, None]
    k = state.valid_prefix(mover, pts)
    return pts[k - 1] if k > 0 and t[k - 1] >= step - 1e-9 else None


#: How far ahead [m] of the guide point nearest a robot that stepped off it the robot may rejoin the guide.
REJOIN_AHEAD = 2.0


def _rejoin_arc(env: Any, paths: _Paths, i: int, Q: Array, clearance: float) -> float:
    """Where robot i, off its path at Q, rejoins the guide: the farthest arc within :data:`REJOIN_AHEAD` of the
    guide point nearest Q (in [its progress, its station's foot]) joined to Q by a free segment."""
    lo, hi = float(paths.garc[i]), float(paths.foot[i])
    if hi <= lo:
        return lo
    s, near = paths.nearest(Q, lo, hi)
    ahead = s[(s >= near) & (s <= near + REJOIN_AHEAD)]
    free = env.segment_is_free(Q, point_at(paths.guide, paths.garcs, ahead), clearance)
    return float(ahead[np.flatnonzero(free)[-1]]) if free.any() else near


def _deadlock(state: _State, paths: _Paths, step: float) -> str:
    """Why no robot can advance: each robot short of its station and the limits its next step breaks."""
    parts = []
    for i in np.flatnonzero(paths.u < paths.length - 1e-9)[::-1]:
        broken = _broken(state, paths, int(i), step)
        x, y = state.X[i]
        parts.append(
            f"robot {i + 1} at ({x:.2f}, {y:.2f}), {paths.length[i] - paths.u[i]:.2f} m before its station "
            f"({', '.join(broken)})"
        )
    return "the chain's sequential advance stalls: " + "; ".join(parts)


def _timed(P: Array, speed: float, accel: float, Ts: float) -> tuple[Array, Array]:
    """Samples (k, 2) of a walk along polyline P and their velocities: minimum-jerk pieces between its turns
    sharper than :data:`TURN_STOP`, each within ``speed`` [m/s] and ``accel`` [m/s²] (:func:`leader_duration`)."""
    arcs = guide_arcs(P)
    d = np.diff(P, axis=0)
    seg = np.linalg.norm(d, axis=1)
    tang = d / np.maximum(seg, 1e-300)[:, None]
    heading = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi)
    cuts = [0.0, *arcs[1:-1][turn > TURN_STOP].tolist(), float(arcs[-1])]
    xs, vs = [], []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        T = leader_duration(b - a, speed, accel, Ts, minimum=MIN_PIECE)
        s, sd, _ = min_jerk(Ts * np.arange(1, round(T / Ts) + 1), T, b - a)  # at Ts, 2Ts, ..., T
        uu = a + s
        k = np.clip(np.searchsorted(arcs, uu - 1e-9, side="right") - 1, 0, len(seg) - 1)  # the segment u is on
        xs.append(point_at(P, arcs, uu))
        vs.append(sd[:, None] * tang[k])
    return np.vstack(xs), np.vstack(vs)


def _timed_sweep(
    env: tuple[_Fast, _Fast],
    base: Array,
    X0: Array,
    limits: TrainLimits,
    moves: list[tuple[int, Array]],
    speed: float,
    accel: float,
    Ts: float,
) -> list[tuple[Array, Array]]:
    """Sampled (positions (k, N, 2), velocities) of one sweep from positions X0 (``env``: the robots' and the tethers'
    environments at the train's clearance, :func:`_states_valid`): its moves in consecutive groups, one group after
    the other, the moves of a group together (the robots that finish early wait). A group is all the sweep's moves
    left if every sampled joint state of them keeps the limits; else its next move, joined by the moves after it one
    at a time while the joint states keep the limits. A move alone always keeps them (the search tested it from the
    state it starts in)."""
    N = len(X0)
    walks = [(i, *_timed(P, speed, accel, Ts)) for i, P in moves]
    out: list[tuple[Array, Array]] = []
    now = X0.copy()
    a, n = 0, len(walks)
    while a < n:
        b = n
        block = _together(now, walks[a:], N)
        if n - a > 1 and not _states_valid(env, base, block[0], limits):  # not all the rest: the next, then more
            b = a + 1
            block = _together(now, walks[a:b], N)
            while b + 1 < n:  # walks[a:n] failed already
                wider = _together(now, walks[a : b + 1], N)
                if not _states_valid(env, base, wider[0], limits):
                    break
                block, b = wider, b + 1
        out.append(block)
        now = block[0][-1].copy()
        a = b
    return out


def _together(X0: Array, walks: list[tuple[int, Array, Array]], N: int) -> tuple[Array, Array]:
    """Positions (k, N, 2) and velocities of ``walks`` (robot, samples, velocities) run together from X0, k the
    longest walk's samples (a robot that finishes early waits where its walk ends; the others hold still)."""
    K = max(len(x) for _, x, _ in walks)
    X = np.repeat(X0[None], K, axis=0)
    V = np.zeros((K, N, 2))
    for i, x, v in walks:
        X[: len(x), i], X[len(x) :, i], V[: len(x), i] = x, x[-1], v
    return X, V


def _states_valid(env: tuple[_Fast, _Fast], base: Array, X: Array, limits: TrainLimits) -> bool:
    """Every state (k, N, 2) keeps the train's limits (clearances > ``limits.clearance``, spans, separation); ``env``:
    the robots' and the tethers' environments (:class:`_Fast` at that clearance: exact, pre-filtered)."""
    k, N, _ = X.shape
    c = limits.clearance
    robots, tethers = env
    if not np.all(robots.clear_above(X.reshape(-1, 2), c)):
        return False
    starts = np.concatenate([np.broadcast_to(base, (k, 1, 2)), X[:, :-1]], axis=1)
    if not np.all(tethers.segment_is_free(starts, X, c)):
        return False
    length = np.linalg.norm(X - starts, axis=2)
    if np.any(length < limits.spans[:, 0] - 1e-9) or np.any(length > limits.spans[:, 1] + 1e-9):
        return False
    iu = np.triu_indices(N, 1)
    D = np.linalg.norm(X[:, :, None] - X[:, None, :], axis=3)[:, iu[0], iu[1]]
    return bool(np.all(D >= limits.separation - 1e-9))


def _attempts(env: Any, ref: ChainReference, clearance: float) -> Iterator[_Paths]:
    """The paths the search tries, in turn until one succeeds: along the guide; pulled taut (no start hairpin);
    along the guide crossing each door straight (:func:`_axial`); that pulled taut, each robot kept behind the next
    along the guide."""
    yield _Paths(ref)
    yield _Paths(ref, env, TAUT_CLEARANCE)
    axial = _axial(env, ref, clearance)
    if axial is not None:
        yield _Paths(axial)
        yield _Paths(axial, env, TAUT_CLEARANCE, order=True)


def train_reference(
    env: Any,
    ref: ChainReference,
    base: Array,
    limits: TrainLimits,
    *,
    Ts: float,
    speed: float,
    accel: float,
    settle: float = 0.0,
    step: float = TRAIN_STEP,
) -> ChainReference:
    """Train references along ``ref``'s guide, from its start to its stations (module docstring).

    Args:
        env: environment; ref: the trailing references (guide, start, stations) this refines.
        base: the anchor (x, y) [m]; limits: what every state keeps.
        Ts: sampling period [s]; speed, accel: peak speed [m/s] and acceleration [m/s²] of every advance.
        settle: time [s] every robot holds still at its station at the end.
        step: arc step [m] at which advances are tested.

    Raises:
        TrainError: no robot can advance and some are short of their stations.
    """
    base = np.asarray(base, dtype=float)
    first: TrainError | None = None
    fast = _environments(env, limits.clearance)
    for paths in _attempts(env, ref, limits.clearance):
        try:
            sweeps = _search(fast, base, paths, limits, step)
            break
        except TrainError as exc:
            first = first or exc
    else:
        if first is None:  # pragma: no cover - _attempts always yields the guide first
            raise RuntimeError("train_reference: no paths to try")
        raise first
    N = len(paths.length)
    X0 = np.asarray(ref.start, dtype=float).copy()  # every path starts where its robot stands
    now = X0.copy()
    blocks_x, blocks_v = [X0[None]], [np.zeros((1, N, 2))]
    for moves in sweeps:
        for X, V in _timed_sweep(fast, base, now, limits, moves, speed, accel, Ts):
            blocks_x.append(X)
            blocks_v.append(V)
        now = blocks_x[-1][-1].copy()
    hold = int(round(settle / Ts))
    if hold:
        blocks_x.append(np.repeat(blocks_x[-1][-1:], hold, axis=0))
        blocks_v.append(np.zeros((hold, N, 2)))
    pos = np.concatenate(blocks_x)
    vel = np.concatenate(blocks_v)
    t = Ts * np.arange(len(pos))
    acc = np.gradient(vel[:, -1], t, axis=0) if len(t) > 1 else np.zeros((1, 2))
    traj = Trajectory(t, pos[:, -1].copy(), vel[:, -1].copy(), acc, ref.guide.copy())
    return replace(ref, trajectory=traj, positions=pos, velocities=vel, mode="train")
