"""Search planner of a MoPICK-type MCDPR: a graph over base placements along the platform path, lazy certification
of the motions, shortcut smoothing, and verdicts (our planner; Rasheed 2019 eq. 5-8 for the statics).

1. **Up-front refusals** (:class:`~tmr.mcdpr.errors.TaskRefused`, < 0.1 s): the platform weight plus the vertical
   external wrench is at least m·t_max (no placement can hold it: each cable lifts at most t_max), or the start pose
   has μ ≤ 0 (which limit: the tension box alone, or the tipping bound of which base, and μ).
2. **Stations**: the platform flies straight between consecutive task points; stations every ``station_step`` m.
3. **Placements** per station: a fixed Halton set of formations (base j at angle α + 2πj/p + β_j and distance
   ρ_j from the platform's ground point, in the cyclic order of the start bases), plus the previous station's
   placements (so the bases may stay); kept when every base is free against the exact shapes (:mod:`clearance`),
   the bases are > 2 r_mb apart and μ at the *worst* heading of every base (``headings`` grid) is ≥ ``margin``;
   the ``keep`` best, spread at least ``spread`` m apart, survive. No placement at a task point →
   :class:`~tmr.mcdpr.errors.NoPlanFound` (``no-placement``, the best μ found) before any graph is built.
4. **Graph**: an edge joins placements of consecutive stations (the platform moves) or of the same station (the
   platform waits) when every base moves ≤ ``max_move``, each drive is collision-free (exact) and the bases stay
   2 r_mb apart while driving simultaneously (closed form). Cost: total base travel + a small per-edge cost +
   ``mu_weight``/μ. Dijkstra (scipy.sparse.csgraph) from the start to any placement of the last station; none →
   ``not-connectable`` with the farthest platform position reached.
5. **Lazy certification** (Bohlin & Kavraki's lazy PRM): the edges of the shortest path are executed as in-place
   turns of the moving bases together (to the drive direction or its opposite) and straight drives, the bases
   together with the platform, and certified by :func:`tmr.mcdpr.certify.certify` (μ's lower bound > 0 on every
   piece, adaptive bisection); a failing edge is deleted and the search repeats. Only when the goal is then out of
   reach are the failed edges tried again in a fallback execution: the bases turning one at a time, then (failing
   again) one base at a time turning and driving while the platform holds, then the platform alone. The start
   formation carried along with the platform is a node of every station while valid (an extra way through the
   graph: it does not steer where the other placements are sampled).
6. **Shortcuts**: within each task segment, consecutive path nodes are replaced by one straight motion from node i
   to the farthest node j (≤ ``shortcut`` ahead) whose motion is collision-free and certified; never past a task
   point (by station index: a route back to an earlier task point keeps every visit).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.errors import fmt_point
from tmr.mcdpr.capacity import capacity, capacity_margin, required_wrench_set
from tmr.mcdpr.certify import certify, wrap
from tmr.mcdpr.clearance import point_clearance, segment_clearance
from tmr.mcdpr.errors import NoPlanFound, ParameterError, TaskRefused
from tmr.mcdpr.planner import Plan, PlannerParams, _min_pair_distance, tensions
from tmr.mcdpr.robot import Robot
from tmr.mcdpr.scene import Scene
from tmr.mcdpr.tipping import tension_bounds, tipping

__all__ = ["SearchParams", "placements", "plan_search", "refuse_upfront", "stations", "worst_heading_mu"]


@dataclass(frozen=True)
class SearchParams:
    """Resolution and limits of the search planner (SI units).

    station_step: platform distance between stations [m]. n_formations: formations tried per station. keep:
    placements kept per station (fresh ones; the previous station's best ``keep`` are added). radii: (min, max)
    base distance from the platform's ground point [m]. spread_angle: max angular deviation β of a base from its
    formation slot [rad]. spread: min distance between kept placements (largest base displacement) [m]. margin: μ
    required at the worst heading of a kept placement [N]. headings: heading grid for that worst case. max_move:
    largest base displacement of one edge [m]. mu_weight: cost weight of 1/μ [m·N]. d_platform: platform step of
    the output samples [m]. max_rounds: lazy re-searches. shortcut: look-ahead of the shortcut smoothing [nodes].
    expand, expand_samples, seed: local expansion, ``expand_samples`` random placements (every base moved by up
    to ``max_move``, seeded) around each of the ``expand`` best reachable placements of the previous station.
    best_heading: placements need μ ≥ margin at the best heading of every base instead of at every heading.
    stall_rounds: repositioning rounds at a station before ``not-connectable``. escalate: retry a failed search at
    the best heading, then with more formations (see :func:`plan_search`).
    """

    station_step: float = 0.25
    n_formations: int = 768
    keep: int = 48
    radii: tuple[float, float] = (0.55, 2.4)
    spread_angle: float = math.pi / 5
    spread: float = 0.12
    margin: float = 0.3
    headings: int = 8
    max_move: float = 0.6
    mu_weight: float = 0.2
    d_platform: float = 0.05
    max_rounds: int = 300
    shortcut: int = 40
    expand: int = 16
    expand_samples: int = 12
    seed: int = 0
    best_heading: bool = False
    stall_rounds: int = 8
    escalate: bool = True


def stations(tasks: NDArray[np.float64], step: float) -> tuple[NDArray[np.float64], NDArray[np.int64], list[int]]:
    """Platform stations (S, 3) [m] along the straight segments between task points, their segment index (S,)
    and the station index of every task point."""
    pts, seg, at = [tasks[0]], [0], [0]
    for i in range(len(tasks) - 1):
        d = tasks[i + 1] - tasks[i]
        n = max(1, math.ceil(max(float(np.hypot(d[0], d[1])), abs(float(d[2]))) / step - 1e-9))
        for k in range(1, n + 1):
            pts.append(tasks[i] + d * k / n)
            seg.append(i)
        at.append(len(pts) - 1)
    return np.array(pts), np.array(seg), at


def worst_heading_mu(
    robot: Robot,
    P: NDArray[np.float64],
    B: NDArray[np.float64],
    rws: NDArray[np.float64],
    n_head: int,
    best: bool = False,
) -> NDArray[np.float64]:
    """μ [N] (Rasheed 2019 eq. 8) of placements B (n, p, 2) for the platform at P (3,) with every base at the worst
    of ``n_head`` headings in [0, 2π) (a cable's tipping bound depends only on its own base's heading, so the worst
    case is the per-cable minimum of the bounds)."""
    hi_min = None
    for g in range(n_head):
        tip = tipping(robot, P, B, np.full(B.shape[:-1], 2 * math.pi * g / n_head))
        lo, hi = tension_bounds(robot, tip)
        hi_min = hi if hi_min is None else (np.maximum if best else np.minimum)(hi_min, hi)
    return capacity_margin(tip.W, lo, hi_min, rws)


def _halton(n: int, d: int) -> NDArray[np.float64]:
    from scipy.stats import qmc

    return qmc.Halton(d=d, scramble=False).random(n + 1)[1:]


def _formations(robot: Robot, params: SearchParams, order: NDArray[np.intp]) -> NDArray[np.float64]:
    """Base offsets (n, p, 2) [m] from the platform's ground point, bases in the cyclic ``order``."""
    p = robot.n_bases
    u = _halton(params.n_formations, 1 + 2 * p)
    alpha = 2 * math.pi * u[:, :1]
    r0, r1 = params.radii
    rho = r0 + (r1 - r0) * u[:, 1 : 1 + p]
    beta = params.spread_angle * (2 * u[:, 1 + p :] - 1)
    slot = np.empty(p)
    slot[order] = 2 * math.pi * np.arange(p) / p
    ang = alpha + slot + beta
    return np.stack([rho * np.cos(ang), rho * np.sin(ang)], axis=-1)


def _apart(robot: Robot, B: NDArray[np.float64]) -> NDArray[np.bool_]:
    iu = np.triu_indices(robot.n_bases, 1)
    return np.all(np.linalg.norm(B[:, iu[0]] - B[:, iu[1]], axis=-1) > 2 * robot.base_radius, axis=-1)


def _diverse(B: NDArray[np.float64], score: NDArray[np.float64], k: int, spread: float) -> NDArray[np.intp]:
    """Up to k indices of B (n, p, 2), best score first, each ≥ ``spread`` m (largest base distance) from the others."""
    chosen: list[int] = []
    for i in np.argsort(-score, kind="stable"):
        if chosen and np.min(np.max(np.linalg.norm(B[chosen] - B[i], axis=-1), axis=-1)) < spread:
            continue
        chosen.append(int(i))
        if len(chosen) >= k:
            break
    return np.array(chosen, dtype=np.intp)


def placements(
    robot: Robot,
    scene: Scene,
    P: NDArray[np.float64],
    offsets: NDArray[np.float64],
    rws: NDArray[np.float64],
    params: SearchParams,
    extra: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float, NDArray[np.float64] | None]:
    """Kept placements (k, p, 2) [m] and their worst-heading μ (k,) [N] for the platform at P (3,), plus the best
    μ among all free, apart formations and its placement (for a refusal message)."""
    B = P[:2] + offsets
    if extra is not None and len(extra):
        B = np.concatenate([B, extra])
    free = np.all(point_clearance(scene, robot.base_radius, B) > 0, axis=-1) & _apart(robot, B)
    B = B[free]
    if not len(B):
        return B, np.zeros(0), -np.inf, None
    mu = worst_heading_mu(robot, P, B, rws, params.headings, params.best_heading)
    best = int(np.argmax(mu))
    ok = mu >= params.margin
    n_fresh = len(B) - (0 if extra is None else int(np.sum(free[len(offsets) :])))
    fresh = np.flatnonzero(ok[:n_fresh])
    half = params.keep // 2
    idx = fresh[_diverse(B[fresh], mu[fresh], params.keep - half, params.spread)] if len(fresh) else fresh
    if extra is not None and len(extra) and len(fresh):
        # the other half: the fresh placements nearest to the previous station's (so the search can progress)
        near = np.min(np.max(np.linalg.norm(B[fresh][:, None] - extra[None], axis=-1), axis=-1), axis=1)
        rest = np.setdiff1d(fresh, idx)
        if len(rest):
            nr = near[np.searchsorted(fresh, rest)]
            idx = np.concatenate([idx, rest[_diverse(B[rest], -nr, half, params.spread)]])
    old = np.flatnonzero(ok[n_fresh:]) + n_fresh
    old = old[np.argsort(-mu[old], kind="stable")[: params.keep]]
    idx = np.concatenate([idx, old]).astype(np.intp)
    return B[idx], mu[idx], float(mu[best]), B[best]


def refuse_upfront(robot: Robot, scene: Scene, rws: NDArray[np.float64]) -> float:
    """Raise TaskRefused when the task is impossible for every placement or the start already violates a limit;
    return μ of the start pose [N]."""
    m = robot.n_cables
    fz = float(np.max(rws[:, 2]))
    if fz >= m * robot.t_max:
        raise TaskRefused(
            f"the platform needs up to {fz:.4g} N of vertical cable force (weight {robot.platform_mass:g} kg × "
            f"{robot.gravity:g} m/s² + external {float(scene.external[2]):g} N) but {m} cables of at most "
            f"{robot.t_max:g} N lift at most {m * robot.t_max:g} N: short by {fz - m * robot.t_max:.4g} N for any "
            "placement of the bases",
            "tension",
            m * robot.t_max - fz,
        )
    P0, B0, H0 = scene.tasks[0], scene.bases.astype(float), scene.headings.astype(float)
    cap = capacity(robot, P0, B0, H0, rws)
    mu = float(cap.mu)
    if mu > 0:
        return mu
    mu_box = float(capacity_margin(cap.W, np.full(m, robot.t_min), np.full(m, robot.t_max), rws))
    if mu_box <= 0:
        raise TaskRefused(
            f"start infeasible: with the bases at their start positions the cables cannot hold the platform at "
            f"{fmt_point(P0)} even without tipping (tension limit {robot.t_max:g} N): capacity margin "
            f"{mu_box:.4g} N (tipping included {mu:.4g} N)",
            "tension",
            mu,
        )
    k = int(np.argmin(cap.hi))
    j = robot.cable_base[k]
    raise TaskRefused(
        f"start infeasible: base {j + 1} would tip: its tipping-tightened tension bound is {float(cap.hi[k]):.4g} N "
        f"(t_max {robot.t_max:g} N) and the capacity margin is {mu:.4g} N (it would be {mu_box:.4g} N without "
        "tipping); move the bases closer to the platform or lower the payload",
        "tipping",
        mu,
    )


#: Execution modes of a graph edge (:func:`_motion`), tried in this order by the lazy certification: the moving
#: bases turn in place together, then drive together with the platform (the planner's motion);
TOGETHER = 0
#: the same, but the bases turn in place one at a time (a start safe only at its own headings, e.g. bases heading
#: across the travel, may pass μ < 0 when they all turn at once);
SINGLE_TURNS = 1
#: one base at a time turns and drives alone while the others and the platform hold, then the platform moves alone.
ONE_BY_ONE = 2


def _motion(
    Bn: NDArray[np.float64],
    Pn: NDArray[np.float64],
    th0: NDArray[np.float64],
    d_platform: float,
    mode: NDArray[np.integer] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]]:
    """Samples of the executed motion through the nodes Bn (K, p, 2), Pn (K, 3) starting with headings th0 (p,).

    Per edge e, the moving bases turn in place to their drive direction (or its opposite, the nearer; ≤ 90°), then
    drive straight, as ``mode[e]`` says (default :data:`TOGETHER` for every edge):

    * :data:`TOGETHER`: all moving bases turn at once (one sample), then drive simultaneously with the platform;
    * :data:`SINGLE_TURNS`: they turn one at a time, in base order, while the others and the platform hold (one
      sample per single-base turn), then drive simultaneously with the platform;
    * :data:`ONE_BY_ONE`: each moving base in turn turns and drives alone to its target while the others and the
      platform hold (base-only reconfiguration), then the platform moves alone.

    Drives are sampled in steps of ≤ d_platform of the platform (or of the lone base of a base-only drive). Returns
    P, B, H and the edge index of each piece (T − 1,)."""
    P, B, H, edge = [Pn[0]], [Bn[0]], [th0.astype(float)], []
    th = th0.astype(float).copy()

    def drive(p0: NDArray[np.float64], p1: NDArray[np.float64], b0: NDArray[np.float64], b1: NDArray[np.float64],
              e: int) -> None:  # fmt: skip
        dp, db = p1 - p0, b1 - b0
        length = max(float(np.hypot(dp[0], dp[1])), abs(float(dp[2])))
        if length == 0:  # a base-only drive (ONE_BY_ONE): steps of the base
            length = float(np.max(np.linalg.norm(db, axis=-1)))
        n = max(1, math.ceil(length / d_platform - 1e-9))
        for k in range(1, n + 1):
            P.append(p0 + dp * k / n)
            B.append(b0 + db * k / n)
            H.append(th)
            edge.append(e)

    for e in range(len(Bn) - 1):
        d = Bn[e + 1] - Bn[e]
        new = _turned(th, d)
        m = TOGETHER if mode is None else int(mode[e])
        cur = Bn[e].copy()
        if m == TOGETHER:
            if np.any(np.abs(wrap(new - th)) > 1e-12):
                P.append(Pn[e])
                B.append(cur)
                H.append(new)
                edge.append(e)
        else:
            for j in range(len(th)):
                if abs(float(wrap(new[j] - th[j]))) > 1e-12:
                    th = th.copy()
                    th[j] = new[j]
                    P.append(Pn[e])
                    B.append(cur.copy())
                    H.append(th)
                    edge.append(e)
                if m == ONE_BY_ONE and np.linalg.norm(d[j]) > 1e-9:
                    th = th.copy()
                    th[j] = new[j]
                    nxt = cur.copy()
                    nxt[j] = Bn[e + 1, j]
                    drive(Pn[e], Pn[e], cur, nxt, e)
                    cur = nxt
        th = new  # (turns below 1e-12 rad get no sample of their own)
        if m == ONE_BY_ONE:
            if np.linalg.norm(Pn[e + 1] - Pn[e]) > 0:
                drive(Pn[e], Pn[e + 1], Bn[e + 1], Bn[e + 1], e)
        else:
            drive(Pn[e], Pn[e + 1], Bn[e], Bn[e + 1], e)
    return np.array(P), np.array(B), np.array(H), np.array(edge, dtype=np.intp)


def _turned(th: NDArray[np.float64], d: NDArray[np.float64]) -> NDArray[np.float64]:
    """Headings (p,) [rad] after the in-place turns before the drives d (p, 2) [m]: a moving base turns to its drive
    direction or the opposite one, whichever is nearer (≤ 90°, a differential drive also reverses); the others keep
    theirs."""
    moving = np.linalg.norm(d, axis=-1) > 1e-9
    fwd = wrap(np.arctan2(d[:, 1], d[:, 0]) - th)
    turn = np.where(np.abs(fwd) <= np.pi / 2, fwd, wrap(fwd - np.pi))
    return np.where(moving, wrap(th + turn), th)


def _edges_ok(
    robot: Robot,
    scene: Scene,
    Ba: NDArray[np.float64],
    Bb: NDArray[np.float64],
    mode: NDArray[np.integer] | None = None,
) -> NDArray[np.bool_]:
    """Straight drives Ba → Bb (n, p, 2): collision-free (exact) and bases 2 r_mb apart, the bases driving
    simultaneously or, where ``mode`` (n,) is :data:`ONE_BY_ONE`, one by one in base order (see :func:`_motion`)."""
    if not len(Ba):
        return np.zeros(0, bool)
    free = np.all(segment_clearance(scene, robot.base_radius, Ba, Bb) > 0, axis=-1)
    if robot.n_bases > 1:
        iu = np.triu_indices(robot.n_bases, 1)
        two = 2 * robot.base_radius
        one = np.zeros(len(Ba), bool) if mode is None else np.asarray(mode) == ONE_BY_ONE
        if np.any(~one):
            free[~one] &= _min_pair_distance(Ba[~one], Bb[~one], iu) > two
        if np.any(one):
            free[one] &= _one_by_one_apart(Ba[one], Bb[one], iu, two)
    return free


def _one_by_one_apart(
    Ba: NDArray[np.float64], Bb: NDArray[np.float64], iu: tuple[NDArray[np.intp], NDArray[np.intp]], two: float
) -> NDArray[np.bool_]:
    """(n,) the bases stay more than ``two`` m apart when they drive Ba → Bb (n, p, 2) one at a time, in base order
    (base j drives while the bases before it are at Bb and the ones after it at Ba; closed form per drive)."""
    ok = np.ones(len(Ba), bool)
    cur = Ba.copy()
    for j in range(Ba.shape[1]):
        nxt = cur.copy()
        nxt[:, j] = Bb[:, j]
        ok &= _min_pair_distance(cur, nxt, iu) > two
        cur = nxt
    return ok


class _GraphBuilder:
    """Nodes (placements per station) and candidate edges of the search graph, append-only."""

    def __init__(
        self, robot: Robot, scene: Scene, rws: NDArray[np.float64], params: SearchParams, mu_start: float
    ) -> None:
        self.robot, self.scene, self.rws, self.params = robot, scene, rws, params
        self.B = scene.bases.astype(float)[None]
        self.st = np.zeros(1, np.intp)
        self.mu = np.array([mu_start])
        self.clear = point_clearance(scene, robot.base_radius, self.B)
        self.src: list[NDArray[np.intp]] = []
        self.dst: list[NDArray[np.intp]] = []
        self.rng = np.random.default_rng(params.seed)
        self.parent: dict[int, int] = {}  # follow node → the node it was translated from

    def follow(self, i: int, P_from: NDArray[np.float64], P: NDArray[np.float64], s: int) -> NDArray[np.intp]:
        """Node i's placement (platform at P_from) translated with the platform to station s at P (3,) [m], added
        when free, apart and with μ ≥ margin (at every or the best heading, as the other placements); its id (1,)
        or none."""
        Bi = self.B[i] + (P[:2] - P_from[:2])
        cand = Bi[None]
        ok = np.all(point_clearance(self.scene, self.robot.base_radius, cand) > 0, axis=-1) & _apart(self.robot, cand)
        if not ok[0]:
            return np.zeros(0, np.intp)
        p = self.params
        mu = worst_heading_mu(self.robot, P, cand, self.rws, p.headings, p.best_heading)
        if not mu[0] >= p.margin:
            return np.zeros(0, np.intp)
        ids = self.add(cand, mu, s)
        self.parent[int(ids[0])] = i
        return ids

    def carried(self, ids: NDArray[np.intp]) -> NDArray[np.bool_]:
        """(n,) which of the node ids are the carried start formation (added by :meth:`follow`)."""
        return np.isin(ids, np.fromiter(self.parent, np.intp, len(self.parent)))

    def add(self, Bs: NDArray[np.float64], mus: NDArray[np.float64], s: int) -> NDArray[np.intp]:
        ids = np.arange(len(self.B), len(self.B) + len(Bs))
        self.B = np.concatenate([self.B, Bs])
        self.st = np.concatenate([self.st, np.full(len(Bs), s, np.intp)])
        self.mu = np.concatenate([self.mu, mus])
        self.clear = np.concatenate([self.clear, point_clearance(self.scene, self.robot.base_radius, Bs)])
        return ids

    def reach(self, sources: NDArray[np.intp], targets: NDArray[np.intp], here: NDArray[np.intp]) -> NDArray[np.intp]:
        """Connect sources → targets and here ↔ here; return the nodes of ``here`` reachable from the sources."""
        a1, b1 = _connect(self.robot, self.scene, self.B, sources, targets, self.clear, self.params)
        a2, b2 = _connect(self.robot, self.scene, self.B, here, here, self.clear, self.params)
        self.src += [a1, a2]
        self.dst += [b1, b2]
        reached = np.zeros(len(self.B), bool)
        reached[b1] = True
        while True:
            more = b2[reached[a2] & ~reached[b2]]
            if not len(more):
                break
            reached[more] = True
        return here[reached[here]]

    def expand(self, P: NDArray[np.float64], s: int, reach: NDArray[np.intp]) -> NDArray[np.intp]:
        """One round of repositioning at station s (the platform waits at P): random placements around diverse
        reachable ones (every base moved by up to max_move), kept when valid, connected; returns the enlarged
        reachable set of station s."""
        p = self.params
        pick = reach[_diverse(self.B[reach], self.rng.uniform(size=len(reach)), p.expand, p.spread)]
        steps = self.rng.uniform(-1.0, 1.0, (len(pick), 2 * p.expand_samples, self.robot.n_bases, 2))
        cand = (self.B[pick][:, None] + steps * p.max_move).reshape(-1, self.robot.n_bases, 2)
        free = np.all(point_clearance(self.scene, self.robot.base_radius, cand) > 0, axis=-1)
        cand = cand[free & _apart(self.robot, cand)]
        if not len(cand):
            return reach
        mu = worst_heading_mu(self.robot, P, cand, self.rws, p.headings, p.best_heading)
        ok = mu >= p.margin
        ids = self.add(cand[ok], mu[ok], s)
        if not len(ids):
            return reach
        back_a, back_b = _connect(self.robot, self.scene, self.B, ids, reach, self.clear, p)  # and back again
        self.src.append(back_a)
        self.dst.append(back_b)
        return np.union1d(reach, self.reach(reach, ids, ids))


def _connect(
    robot: Robot,
    scene: Scene,
    B: NDArray[np.float64],
    ia: NDArray[np.intp],
    ib: NDArray[np.intp],
    clear: NDArray[np.float64],
    params: SearchParams,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Candidate edges between node sets ia × ib: every base moves ≤ max_move, drives free, bases apart."""
    A, C = np.meshgrid(ia, ib, indexing="ij")
    A, C = A.ravel(), C.ravel()
    keep = A != C
    A, C = A[keep], C[keep]
    dist = np.linalg.norm(B[C] - B[A], axis=-1)  # (n, p)
    near = np.all(dist <= params.max_move, axis=-1)
    A, C, dist = A[near], C[near], dist[near]
    # a drive shorter than an end point's clearance is free (the disc around that end point is free)
    sure = np.all((dist < clear[A]) | (dist < clear[C]), axis=-1)
    ok = sure.copy()
    todo = np.flatnonzero(~sure)
    if len(todo):
        ok[todo] = _edges_ok(robot, scene, B[A[todo]], B[C[todo]])
    if robot.n_bases > 1 and len(A):
        iu = np.triu_indices(robot.n_bases, 1)
        ok &= _min_pair_distance(B[A], B[C], iu) > 2 * robot.base_radius
    return A[ok], C[ok]


def plan_search(
    robot: Robot,
    scene: Scene,
    params: SearchParams | None = None,
    external: NDArray[np.float64] | None = None,
    progress: bool = False,
) -> Plan:
    """Plan the task of ``scene`` with the search planner (see the module docstring); raises TaskRefused (refused
    up front) or NoPlanFound (nothing found at the search resolution).

    Placements are first required to keep μ ≥ margin at *every* heading of their bases (robust to the in-place
    turns); when that finds nothing (``escalate``), the search is repeated with μ ≥ margin at the *best* heading of
    every base (``best_heading``: more placements, the motions' turns are then certified one by one), then at every
    heading with 8/3 × the formations and twice the placements kept per station. The verdict is the last search's
    (its message lists the resolutions tried). ``progress``: a tqdm bar of the stations on stderr, shown once a
    search has taken 0.5 s."""
    params = params or SearchParams()
    attempts = [params]
    if params.escalate:
        if not params.best_heading:
            attempts.append(dataclasses.replace(params, best_heading=True))
        finer = dataclasses.replace(params, n_formations=params.n_formations * 8 // 3, keep=params.keep * 2)
        attempts.append(finer)
    t0 = time.perf_counter()
    failed: list[str] = []
    for k, attempt in enumerate(attempts):
        try:
            res = _plan_search(robot, scene, attempt, external, progress, f"search {k + 1}/{len(attempts)}")
        except NoPlanFound as exc:
            failed.append(f"{_describe(attempt)}: {exc.kind}: {exc}")
            if k == len(attempts) - 1:
                if len(attempts) > 1:
                    exc.args = (f"{exc} [tried: {'; '.join(_describe(a) for a in attempts)}]",)
                raise
            continue
        res.search["failed_attempts"] = failed
        res.search["attempt"] = _describe(attempt)
        res.times["total"] = time.perf_counter() - t0
        return res
    raise AssertionError("unreachable")  # pragma: no cover


def _describe(p: SearchParams) -> str:
    """Short label of a search resolution, for messages."""
    where = "the best" if p.best_heading else "every"
    return f"{p.n_formations} formations, keep {p.keep}, μ ≥ {p.margin:g} N at {where} heading"


def _plan_search(
    robot: Robot,
    scene: Scene,
    params: SearchParams,
    external: NDArray[np.float64] | None = None,
    progress: bool = False,
    label: str = "search",
) -> Plan:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    if not robot.one_cable_per_base:
        raise ParameterError(f"{robot.name}: the search planner needs one cable per base")
    t0 = time.perf_counter()
    scene.validate(robot)
    ext = np.asarray(scene.external if external is None else external, dtype=float)
    rws = required_wrench_set(robot, ext)
    mu_start = refuse_upfront(robot, scene, rws)
    t_refuse = time.perf_counter() - t0

    S, seg, task_at = stations(scene.tasks, params.station_step)
    rel = scene.bases - scene.tasks[0, :2]
    order = np.argsort(np.arctan2(rel[:, 1], rel[:, 0]), kind="stable")
    offsets = _formations(robot, params, order)

    # task points first: a refusal there costs a fraction of a second
    for k, s in enumerate(task_at):
        Bk, _, best, bestB = placements(robot, scene, S[s], offsets, rws, params)
        if not len(Bk) and not (k == 0):
            where = tuple(float(v) for v in np.round(S[s], 4))
            at = fmt_point(where)
            raise NoPlanFound(
                f"no base placement for task point {k + 1} {at}: none of {len(offsets)} formations (bases "
                f"{params.radii[0]:g}-{params.radii[1]:g} m from the platform) is free with μ ≥ {params.margin:g} N "
                f"at {'the best' if params.best_heading else 'every'} heading of its bases; best μ found {best:.4g} N"
                + (f" with the bases at {', '.join(map(fmt_point, bestB))}" if bestB is not None else " (no free one)"),
                "no-placement",
                where,
                best,
            )
    t_tasks = time.perf_counter() - t0

    # nodes, built forward station by station: fresh formations, the reachable placements of the previous
    # station (the bases stay) and the same translated with the platform (the formation follows it)
    g = _GraphBuilder(robot, scene, rws, params, mu_start)
    reach_prev = np.zeros(1, np.intp)  # global indices of the reachable nodes of the previous station
    # the start formation carried along with the platform (every base drives the platform's step), kept as a node of
    # every station while valid whatever its μ ranks: the bases turn in place to the travel direction (one at a time
    # where turning together fails the certification), then drive with the platform, which may be the only way out
    # of a start that is safe at its headings only
    follow: int | None = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(S), desc=f"MoPICK {label}: stations", unit="station", leave=False, delay=0.5)
    for s in range(len(S)):
        if bar is not None:
            bar.update(1)
        reach = np.zeros(0, np.intp)
        for attempt in range(params.stall_rounds + 1):
            # the sampling (anchors, kept placements, repositioning) draws on the reachable nodes other than the
            # carried start formation, unless it is the only one: it is an extra way through the graph, not one that
            # steers where the other placements are sampled (which shifted them and cost fig2 45 % of its μ at the
            # samples: 2.45 → 1.34 N)
            carried = g.carried(reach_prev)
            own = reach_prev[~carried] if not carried.all() else reach_prev
            if attempt:  # stalled: the bases reposition while the platform waits at the previous station
                reach_prev = np.union1d(g.expand(S[s - 1], s - 1, own), reach_prev)
                carried = g.carried(reach_prev)
                own = reach_prev[~carried] if not carried.all() else reach_prev
            Bprev = g.B[own]
            top = np.argsort(-g.mu[own], kind="stable")[: params.keep]
            shift = S[s, :2] - S[max(s - 1, 0), :2]
            # local expansion: every base of the best reachable placements moved by up to max_move (seeded)
            anchors = Bprev[top[: params.expand]]
            steps = g.rng.uniform(-1.0, 1.0, (len(anchors), params.expand_samples, robot.n_bases, 2))
            local = (anchors[:, None] + shift + steps * params.max_move).reshape(-1, robot.n_bases, 2)
            extra = np.concatenate([Bprev[top], Bprev[top] + shift, local])
            Bs, mus, best, bestB = placements(robot, scene, S[s], offsets, rws, params, extra)
            if not len(Bs) and s > 0:
                where = tuple(float(v) for v in np.round(S[s], 4))
                raise NoPlanFound(
                    f"no base placement for the platform at {fmt_point(where)} (between task points {int(seg[s]) + 1} "
                    f"and {int(seg[s]) + 2}) with μ ≥ {params.margin:g} N; best μ found {best:.4g} N",
                    "no-placement",
                    where,
                    best,
                )
            ids = g.add(Bs, mus, s)
            if attempt == 0:
                fid = g.follow(follow, S[s - 1], S[s], s) if follow is not None and s > 0 else np.zeros(0, np.intp)
            ids = np.concatenate([ids, fid])
            prev_ids = reach_prev if s > 0 else np.zeros(1, np.intp)
            targets = np.concatenate([ids, prev_ids]) if s == 0 else ids
            reach = g.reach(prev_ids, targets, ids)
            if s == 0:
                reach = np.union1d([0], reach)
            if len(reach):
                break
        if s > 0 and follow is not None:
            nxt = np.flatnonzero(g.st[reach] == s)
            mine = [int(i) for i in reach[nxt] if g.parent.get(int(i)) == follow]
            follow = mine[0] if mine else None
        if not len(reach):
            where = tuple(float(v) for v in np.round(S[max(s - 1, 0)], 4))
            raise NoPlanFound(
                f"placements exist but no collision-free base motion (each base ≤ {params.max_move:g} m per step, "
                f"bases 2 r_mb apart) follows the platform beyond {fmt_point(where)} (station {s} of {len(S)}, between "
                f"task points {int(seg[s]) + 1} and {min(int(seg[s]) + 2, len(scene.tasks))}), after "
                f"{params.stall_rounds} rounds of repositioning the bases there",
                "not-connectable",
                where,
                float(np.max(g.mu[reach_prev], initial=-np.inf)),
            )
        reach_prev = reach
    B, st, mu = g.B, g.st, g.mu
    P = S[st]
    if bar is not None:
        bar.close()
    # one edge per ordered pair (a pair found twice, e.g. by a stall round, would count twice in the sparse sum)
    pairs = np.unique(np.stack([np.concatenate(g.src), np.concatenate(g.dst)], axis=1), axis=0)
    src_a, dst_a = pairs[:, 0], pairs[:, 1]
    pair_id = {(int(a), int(b)): i for i, (a, b) in enumerate(pairs)}
    w = (
        np.linalg.norm(B[dst_a] - B[src_a], axis=-1).sum(axis=-1)
        + 0.01
        + params.mu_weight / np.maximum(mu[dst_a], 1e-3)
    )
    t_graph = time.perf_counter() - t0

    N = len(B)
    alive = np.ones(len(src_a), bool)
    # how each edge is executed (_motion): TOGETHER first; an edge that fails the certification is deleted, and only
    # when the goal is then out of reach are the failed ones tried again in their next mode (SINGLE_TURNS, then
    # ONE_BY_ONE), so a plan that certifies with the bases turning together keeps them turning together
    mode = np.full(len(src_a), TOGETHER, np.int8)
    failed = np.zeros(len(src_a), bool)  # deleted after failing in a mode that has a fallback
    goal = np.flatnonzero(st == len(S) - 1)
    th0 = scene.headings.astype(float)
    rounds = 0
    removed = 0
    fallbacks = 0
    while True:
        rounds += 1
        G = coo_matrix((w[alive], (src_a[alive], dst_a[alive])), shape=(N, N)).tocsr()
        dist, pred = dijkstra(G, directed=True, indices=0, return_predecessors=True)
        reach = np.isfinite(dist)
        if not reach[goal].any() and failed.any():
            again = np.flatnonzero(failed)
            mode[again] += 1
            failed[again] = False
            fallbacks += len(again)
            # one base at a time has its own spacing check (a base passes the others at their start or goal)
            alive[again] = _edges_ok(robot, scene, B[src_a[again]], B[dst_a[again]], mode[again])
            continue
        if not reach[goal].any():
            far = int(st[reach].max())
            where = tuple(float(v) for v in np.round(S[far], 4))
            at = fmt_point(where)
            raise NoPlanFound(
                f"placements exist at every platform position but no certified base motion joins them: the bases "
                f"follow the platform only up to {at} (station {far + 1} of {len(S)}, between task points "
                f"{int(seg[far]) + 1} and {min(int(seg[far]) + 2, len(scene.tasks))}); {removed} motions failed the "
                f"μ certification, {len(src_a)} were tried",
                "not-connectable",
                where,
                float(np.max(mu[st == min(far + 1, len(S) - 1)], initial=-np.inf)),
            )
        end = int(goal[np.argmin(dist[goal])])
        path = [end]
        while path[-1] != 0:
            path.append(int(pred[path[-1]]))
        path = path[::-1]
        ids = np.array([pair_id[(a, b)] for a, b in zip(path[:-1], path[1:], strict=True)], dtype=np.intp)
        Pm, Bm, Hm, edge = _motion(B[path], P[path], th0, params.d_platform, mode[ids])
        cert = certify(robot, Pm, Bm, Hm, rws)
        if cert.ok:
            break
        bad_pieces = np.flatnonzero(~(cert.lower > 0))
        bad = ids[np.unique(edge[np.floor(cert.u[bad_pieces]).astype(np.intp)])]
        alive[bad] = False
        failed[bad] = mode[bad] < ONE_BY_ONE
        removed += len(bad)
        if rounds >= params.max_rounds:
            raise NoPlanFound(
                f"no certified motion after {rounds} searches ({removed} motions removed); last failure near the "
                f"platform at {fmt_point(Pm[cert.fail])}",
                "not-connectable",
                tuple(float(v) for v in Pm[cert.fail]),
            )
    t_search = time.perf_counter() - t0

    # smoothing: relax the nodes towards their neighbours' midpoints, then shortcut inside each task segment;
    # every change is checked (exact collision, spacing, certified μ) and the whole result certified again
    Bn, Pn, sn, mode_p = B[path].copy(), P[path].copy(), st[path].copy(), mode[ids]
    Bn = _relax(robot, scene, Bn, Pn, th0, rws, params, mode_p)
    idx, shortcuts, mode_s = _shortcut(robot, scene, Bn, Pn, sn, th0, rws, params, task_at, mode_p)
    Pm, Bm, Hm, edge = _motion(Bn[idx], Pn[idx], th0, params.d_platform, mode_s)
    cert = certify(robot, Pm, Bm, Hm, rws)
    out, sn_out = idx, sn[idx]
    if not cert.ok:  # the local checks do not see a changed turn further on: keep the certified search path
        out, sn_out = path, sn
        Pm, Bm, Hm, edge = _motion(B[path], P[path], th0, params.d_platform, mode_p)
        cert = certify(robot, Pm, Bm, Hm, rws)
    t_smooth = time.perf_counter() - t0

    # per original piece: the smallest guaranteed bound over its refined sub-pieces
    piece = np.floor(cert.u[:-1]).astype(np.intp)
    lower = np.full(len(Pm) - 1, np.inf)
    np.minimum.at(lower, piece, cert.lower)
    labels = _labels(edge, seg[sn_out], np.linalg.norm(np.diff(Pm, axis=0), axis=-1) > 1e-12)
    cap = capacity(robot, Pm, Bm, Hm, rws)
    tens = tensions(robot, cap.W, cap.lo, cap.hi)
    t_end = time.perf_counter() - t0
    info: dict[str, Any] = {
        "stations": len(S),
        "nodes": int(N),
        "edges": int(len(src_a)),
        "rounds": rounds,
        "edges_removed": removed,
        "edges_fallback": fallbacks,
        "path_single_turns": int(np.sum((mode_s if out is idx else mode_p) == SINGLE_TURNS)),
        "path_one_by_one": int(np.sum((mode_s if out is idx else mode_p) == ONE_BY_ONE)),
        "path_nodes": len(path),
        "smoothed_nodes": len(out),
        "shortcuts": shortcuts,
        "refined_samples": int(len(cert.P)),
        "mu_lower_min": float(np.min(cert.lower)) if len(cert.lower) else float("nan"),
        "placement_headings": "best" if params.best_heading else "every",
    }
    return Plan(
        waypoints=np.asarray(scene.tasks, float),
        bases=Bm,
        headings=Hm,
        platform=Pm,
        segment=labels,
        mu=cap.mu,
        tensions=tens,
        lo=cap.lo,
        hi=cap.hi,
        stage1=[],
        times={
            "refusal_checks": t_refuse,
            "task_placements": t_tasks - t_refuse,
            "graph": t_graph - t_tasks,
            "search": t_search - t_graph,
            "smoothing": t_smooth - t_search,
            "evaluation": t_end - t_smooth,
            "total": t_end,
        },
        params=PlannerParams(d_platform=params.d_platform),
        external=ext.copy(),
        planner="search",
        mu_lower=lower,
        search=info,
    )


def _arrival_headings(Bn: NDArray[np.float64], th0: NDArray[np.float64]) -> NDArray[np.float64]:
    """Headings (K, p) [rad] on arrival at each node of the path (before its turn), as :func:`_motion` drives."""
    out = np.empty((len(Bn), len(th0)))
    th = th0.astype(float).copy()
    out[0] = th
    for e in range(len(Bn) - 1):
        th = _turned(th, Bn[e + 1] - Bn[e])
        out[e + 1] = th
    return out


def _local_ok(
    robot: Robot,
    scene: Scene,
    Bn: NDArray[np.float64],
    Pn: NDArray[np.float64],
    th: NDArray[np.float64],
    rws: NDArray[np.float64],
    d_platform: float,
    mode: NDArray[np.integer] | None = None,
) -> bool:
    """The motion through the nodes Bn, Pn (starting with headings th; each edge executed in its ``mode``, default
    :data:`TOGETHER`, see :func:`_motion`) is collision-free, spaced and certified."""
    if not np.all(_edges_ok(robot, scene, Bn[:-1], Bn[1:], mode)):
        return False
    Pm, Bm, Hm, _ = _motion(Bn, Pn, th, d_platform, mode)
    return certify(robot, Pm, Bm, Hm, rws).ok


def _relax(
    robot: Robot,
    scene: Scene,
    Bn: NDArray[np.float64],
    Pn: NDArray[np.float64],
    th0: NDArray[np.float64],
    rws: NDArray[np.float64],
    params: SearchParams,
    mode: NDArray[np.integer] | None = None,
    sweeps: int = 4,
) -> NDArray[np.float64]:
    """Move every inner node's bases half-way towards the midpoint of their neighbours when the motion from the
    node before to the node two after stays collision-free, spaced and certified (removes zig-zags and spurs).

    Nodes k ≡ r (mod 3) are tried together (their windows k−1…k+2 share no moved node), all windows certified in
    one batched :func:`certify` call; the whole smoothed path is certified again by the caller. ``mode`` (K − 1,):
    how each edge is executed (:func:`_motion`; default :data:`TOGETHER`), kept as it is."""
    Bn = Bn.copy()
    mode = np.full(len(Bn) - 1, TOGETHER, np.int8) if mode is None else np.asarray(mode)
    for _ in range(sweeps):
        moved = False
        for r in range(1, 4):
            ks = [k for k in range(r, len(Bn) - 1, 3)]
            new = {}
            for k in ks:
                cand = Bn[k] + 0.5 * (0.5 * (Bn[k - 1] + Bn[k + 1]) - Bn[k])
                if np.max(np.linalg.norm(cand - Bn[k], axis=-1)) >= 0.01:
                    new[k] = cand
            if not new:
                continue
            ks = list(new)
            pts = np.array([new[k] for k in ks])
            free = np.all(point_clearance(scene, robot.base_radius, pts) > 0, axis=-1)
            arrive = _arrival_headings(Bn, th0)
            parts, owner, windows = [], [], []
            for k, ok in zip(ks, free, strict=True):
                if not ok:
                    continue
                hi = min(k + 3, len(Bn))
                trial = Bn[k - 1 : hi].copy()
                trial[1] = new[k]
                how = mode[k - 1 : hi - 1]
                if not np.all(_edges_ok(robot, scene, trial[:-1], trial[1:], how)):
                    continue
                Pm, Bm, Hm, _ = _motion(trial, Pn[k - 1 : hi], arrive[k - 1], params.d_platform, how)
                parts.append((Pm, Bm, Hm))
                owner += [len(windows)] * (len(Pm) - 1) + [-1]
                windows.append(k)
            if not windows:
                continue
            P = np.concatenate([q[0] for q in parts])
            B = np.concatenate([q[1] for q in parts])
            H = np.concatenate([q[2] for q in parts])
            own = np.array(owner[:-1])
            cert = certify(robot, P, B, H, rws, skip=own < 0)
            piece_owner = own[np.floor(cert.u[:-1]).astype(np.intp)]
            bad = set(piece_owner[~(cert.lower > 0)].tolist())
            for w, k in enumerate(windows):
                if w not in bad:
                    Bn[k] = new[k]
                    moved = True
        if not moved:
            break
    return Bn


def _shortcut(
    robot: Robot,
    scene: Scene,
    Bn: NDArray[np.float64],
    Pn: NDArray[np.float64],
    sn: NDArray[np.intp],
    th0: NDArray[np.float64],
    rws: NDArray[np.float64],
    params: SearchParams,
    task_at: list[int],
    mode: NDArray[np.integer] | None = None,
) -> tuple[list[int], int, NDArray[np.int8]]:
    """Indices of the nodes kept: from node i, a straight motion (:data:`TOGETHER`) to the farthest node j of the
    same task segment whose motion is collision-free, spaced and certified (the nodes in between are dropped), and
    the mode of each kept edge (``mode`` (K − 1,), default :data:`TOGETHER`: kept for an edge not shortcut).

    Never shortcut away: a task point. The nodes i … j of a shortcut have non-decreasing stations with no task
    point's station strictly between stations i and j (:func:`_same_line`, on the station *indices*, so a route
    that returns to an earlier task point, e.g. t0 → t1 → t0, keeps the visit of t1 although the nodes before and
    after it are at the same place)."""
    mode = np.full(len(Bn) - 1, TOGETHER, np.int8) if mode is None else np.asarray(mode)
    out = [0]
    modes: list[int] = []
    th = th0.astype(float).copy()
    i = 0
    shortcuts = 0
    while i < len(Bn) - 1:
        j_best = i + 1
        last = i + 1
        while last + 1 < len(Bn) and _same_line(sn[i : last + 2], task_at):
            last += 1
        for j in range(min(last, i + params.shortcut), i + 1, -1):
            pair = np.array([i, j])
            if _local_ok(robot, scene, Bn[pair], Pn[pair], th, rws, params.d_platform):
                j_best = j
                shortcuts += 1
                break
        th = _arrival_headings(Bn[[i, j_best]], th)[-1]
        modes.append(int(mode[i]) if j_best == i + 1 else TOGETHER)
        out.append(j_best)
        i = j_best
    return out, shortcuts, np.array(modes, np.int8)


def _same_line(sts: NDArray[np.intp], task_at: list[int]) -> bool:
    """True when the stations ``sts`` (in path order) lie on one task segment, monotonically (a straight platform
    motion from the first to the last passes through all of them and through no task point in between)."""
    lo, hi = int(sts.min()), int(sts.max())
    if np.any(np.diff(sts) < 0):
        return False
    inner = [t for t in task_at if lo < t < hi]
    return not inner


def _labels(edge: NDArray[np.intp], seg: NDArray[np.int64], moves: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Task segment index (T,) of each sample of a :func:`_motion`: ``edge`` (T − 1,) the path edge of each piece,
    ``seg`` (K,) the segment of each path node's station, ``moves`` (T − 1,) the platform moves on the piece. A piece
    on which the platform moves takes its edge's target segment; turns and waits keep the label (so the last sample
    of segment i is the platform at task point i + 1). From the path, not from the geometry: on a route back to an
    earlier task point the segments overlap."""
    out = np.zeros(len(edge) + 1, np.int64)
    cur = 0
    for r, e in enumerate(edge):
        if moves[r]:
            cur = int(seg[e + 1])
        out[r + 1] = cur
    return out
