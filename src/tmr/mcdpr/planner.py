"""Two-stage path planner of an MCDPR (Rasheed 2019 sec. 5, Algorithms 1-2), vectorised.

Stage 1 (:func:`base_search`, Algorithm 1): the platform target jumps to the next way-point while the bases stay;
then, each iteration, every base may stay or take a differential-drive step (forward, backward, or a ±45° diagonal
forward/backward: turn in place, then drive) of length d on a circular grid; a blocked direction retries with the
step halved (down to ``min_step``). All s_1 × … × s_p collision-free combinations (bases at least 2 r_mb apart
during the simultaneous straight moves) are scored by ONE batched capacity-margin call
(:func:`tmr.mcdpr.capacity.capacity`) and the best is taken; the search stops when μ no longer increases (while
μ <= 0, a μ-preserving move towards the target is taken instead of stopping). Each base polyline is then smoothed
by a clamped cubic B-spline whose control points are the iterates (scipy ``BSpline``; the curve keeps the end
points), sampled ten times as densely; a smoothed path that would hit an obstacle or another base falls back to the
(collision-free) polyline.

Stage 2 (:func:`platform_search`, Algorithm 2): along the smoothed base paths, the platform stays or moves by
d_MP in one of 8 directions, or straight towards the next way-point, picking the candidate with the largest μ among
those from which the way-point is still reachable in the remaining steps (the paper notes a plain greedy step can
miss the way-point). The segment has at least ceil(max(‖Δxy‖, |Δz|)/d_MP) + 1 samples (the smoothed base path is
resampled more densely when the stage-1 iterates give fewer), so the platform arrives exactly at every way-point
with steps of at most d_MP; the next segment starts from the pose actually reached. Heights are interpolated
linearly between way-points.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from itertools import product
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import BSpline

from tmr.errors import fmt_point
from tmr.mcdpr.capacity import capacity, required_wrench_set
from tmr.mcdpr.capacity_hull import box_rows
from tmr.mcdpr.errors import InfeasibleWrench, ParameterError
from tmr.mcdpr.robot import Robot
from tmr.mcdpr.scene import Scene, waypoints
from tmr.mcdpr.tension import TensionProblem, closed_form_batch
from tmr.world.environment import Environment

__all__ = ["Plan", "PlannerParams", "base_search", "check", "plan", "platform_search", "smooth_paths"]

#: Differential-drive moves: (direction relative to heading [rad], new heading relative to heading [rad]).
#: stay, forward, backward, forward-left, forward-right, backward-left, backward-right.
MOVES = np.array(
    [
        [np.nan, 0.0],
        [0.0, 0.0],
        [np.pi, 0.0],
        [np.pi / 4, np.pi / 4],
        [-np.pi / 4, -np.pi / 4],
        [np.pi - np.pi / 4, np.pi / 4 * -1.0],
        [np.pi + np.pi / 4, np.pi / 4],
    ]
)


@dataclass(frozen=True)
class PlannerParams:
    """Tuning of the planner (Rasheed 2019 sec. 6): step sizes d_j, d_MP [m] and limits.

    d_base: base step d_j [m] (keep it below the smallest obstacle diameter). min_step: smallest retried step [m].
    d_platform: platform step d_MP [m]. max_iter: cap of stage-1 iterations per way-point. upsample: samples of the
    smoothed base path per stage-1 iterate (the paper: 10). tol: μ increase that counts as an improvement [N].
    plateau_escape: while μ <= 0 and no move increases it, take the μ-preserving move that brings the bases closest
    to the platform target (sum of distances, must shrink by min_step/2) instead of stopping (our addition).
    """

    d_base: float = 0.2
    min_step: float = 0.05
    d_platform: float = 0.05
    max_iter: int = 200
    upsample: int = 10
    tol: float = 1e-6
    plateau_escape: bool = True


@dataclass
class Plan:
    """Output of :func:`plan` (T samples along the whole task; p bases, m cables).

    waypoints (l, 3) [m]; bases (T, p, 2) [m]; headings (T, p) [rad]; platform (T, 3) [m]; segment (T,) index i of
    the way-point pair; mu (T,) capacity margin [N] (eq. 8); tensions (T, m) minimum 2-norm tensions holding the
    platform weight [N] (NaN if infeasible); lo, hi (T, m) tipping-tightened tension bounds [N]; stage1: per segment
    the raw iterates (k_i, p, 2) and μ history; times: wall time of the stages [s]; params: the planner settings
    (:func:`check` uses ``params.d_platform`` to bound the platform steps); external (3,) the external wrench box
    half-widths of the scene [N] (:func:`check` recomputes μ with it). planner: ``"greedy"`` (this module) or
    ``"search"`` (:mod:`tmr.mcdpr.search`); mu_lower (T − 1,): guaranteed lower bound of μ on each piece between
    consecutive samples [N] (:mod:`tmr.mcdpr.certify`; search plans only); search: statistics of the search;
    tension_method: how ``tensions`` were distributed (:data:`tmr.mcdpr.tension.METHODS`).
    """

    waypoints: NDArray[np.float64]
    bases: NDArray[np.float64]
    headings: NDArray[np.float64]
    platform: NDArray[np.float64]
    segment: NDArray[np.int64]
    mu: NDArray[np.float64]
    tensions: NDArray[np.float64]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    stage1: list[dict[str, Any]] = field(default_factory=list)
    times: dict[str, float] = field(default_factory=dict)
    params: PlannerParams = field(default_factory=PlannerParams)
    external: NDArray[np.float64] = field(default_factory=lambda: np.ones(3))
    planner: str = "greedy"
    mu_lower: NDArray[np.float64] | None = None
    search: dict[str, Any] = field(default_factory=dict)
    tension_method: str = "closed-form"


def _combos(p: int, k: int) -> NDArray[np.intp]:
    return np.array(list(product(range(k), repeat=p)), dtype=np.intp)


def _candidates(
    env: Environment, xy: NDArray[np.float64], th: NDArray[np.float64], params: PlannerParams
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Per base: the 7 move end points (p, 7, 2), headings (p, 7) and validity (p, 7); blocked moves shrink."""
    p = len(xy)
    steps = [params.d_base]
    while steps[-1] / 2 >= params.min_step - 1e-12:
        steps.append(steps[-1] / 2)
    steps_a = np.array(steps)
    ang = th[:, None] + MOVES[None, 1:, 0]  # (p, 6)
    dirs = np.stack([np.cos(ang), np.sin(ang)], axis=-1)  # (p, 6, 2)
    ends = xy[:, None, None, :] + steps_a[None, None, :, None] * dirs[:, :, None, :]  # (p, 6, S, 2)
    starts = np.broadcast_to(xy[:, None, None, :], ends.shape)
    ok = env.segment_clearance(starts, ends) > 0.0  # (p, 6, S)
    first = np.argmax(ok, axis=-1)
    valid_move = ok.any(axis=-1)
    chosen = np.take_along_axis(ends, first[..., None, None], axis=2)[:, :, 0, :]
    cand = np.concatenate([xy[:, None, :], chosen], axis=1)
    heads = np.concatenate([th[:, None], th[:, None] + MOVES[None, 1:, 1]], axis=1)
    valid = np.concatenate([np.ones((p, 1), bool), valid_move], axis=1)
    return cand, np.mod(heads + np.pi, 2 * np.pi) - np.pi, valid


def base_search(
    robot: Robot,
    env: Environment,
    target: NDArray[np.float64],
    xy0: NDArray[np.float64],
    th0: NDArray[np.float64],
    rws: NDArray[np.float64],
    params: PlannerParams,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], int]:
    """Stage 1 for one way-point (Rasheed 2019 Algorithm 1): iterates (k, p, 2), headings (k, p), μ (k,), combos.

    Greedy: every iteration evaluates all collision-free combinations of the bases' moves in one batched μ call and
    takes the best; stops when μ does not increase by more than ``params.tol`` (unless ``params.plateau_escape``
    applies: μ <= 0 and a μ-preserving move brings the bases closer to the target). Returns also the total number of
    combinations scored.
    """
    p = robot.n_bases
    combos = _combos(p, len(MOVES))
    iu = np.triu_indices(p, 1)
    xy, th = xy0.copy(), th0.copy()
    mu = float(capacity(robot, target, xy, th, rws).mu)
    path, heads, mus = [xy.copy()], [th.copy()], [mu]
    closeness = float(np.linalg.norm(xy - target[:2], axis=-1).sum())
    scored = 0
    for _ in range(params.max_iter):
        cand, chead, valid = _candidates(env, xy, th, params)
        ok = np.all(valid[np.arange(p), combos], axis=1)
        C = combos[ok]
        XY = cand[np.arange(p), C]  # (n, p, 2)
        H = chead[np.arange(p), C]
        apart = _min_pair_distance(xy, XY, iu) >= 2 * robot.base_radius
        XY, H = XY[apart], H[apart]
        if len(XY) == 0:
            break
        res = capacity(robot, target, XY, H, rws).mu
        scored += len(XY)
        best = int(np.argmax(res))
        if not res[best] > mu + params.tol:
            if not (params.plateau_escape and mu <= 0.0):
                break
            # μ <= 0 on a plateau: among the moves that keep μ, take the one bringing the bases closest to the target
            close = np.linalg.norm(XY - target[:2], axis=-1).sum(axis=1)
            ok_moves = (res >= mu - params.tol) & (close < closeness - 0.5 * params.min_step)
            if not ok_moves.any():
                break
            best = int(np.argmin(np.where(ok_moves, close, np.inf)))
        closeness = float(np.linalg.norm(XY[best] - target[:2], axis=-1).sum())
        xy, th, mu = XY[best].copy(), H[best].copy(), float(res[best])
        path.append(xy.copy())
        heads.append(th.copy())
        mus.append(mu)
    return np.array(path), np.array(heads), np.array(mus), scored


def _min_pair_distance(
    xy: NDArray[np.float64], XY: NDArray[np.float64], iu: tuple[NDArray[np.intp], NDArray[np.intp]]
) -> NDArray[np.float64]:
    """Smallest distance (n,) [m] between any two bases while all move straight and simultaneously from xy (p, 2)
    or (n, p, 2) to XY (n, p, 2): per pair, min over s in [0, 1] of |d0 + s (d1 - d0)| (closed form)."""
    d0 = xy[..., iu[0], :] - xy[..., iu[1], :]
    if d0.ndim == 2:
        d0 = d0[None]  # (1, P, 2)
    d1 = XY[:, iu[0]] - XY[:, iu[1]]  # (n, P, 2)
    v = d1 - d0
    vv = np.einsum("npi,npi->np", v, v)
    s = np.clip(-np.einsum("npi,npi->np", np.broadcast_to(d0, v.shape), v) / np.where(vv > 0, vv, 1.0), 0.0, 1.0)
    closest = d0 + s[..., None] * v
    return np.min(np.linalg.norm(closest, axis=-1), axis=1)


def _clamped_bspline(ctrl: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    """Sample n points of the clamped uniform B-spline (degree ≤ 3) with control points ctrl (k, ...)."""
    k = len(ctrl)
    if k == 1:
        return np.repeat(ctrl, n, axis=0)
    deg = min(3, k - 1)
    inner = np.linspace(0.0, 1.0, k - deg + 1)
    knots = np.concatenate([np.zeros(deg), inner, np.ones(deg)])
    spl = BSpline(knots, ctrl.reshape(k, -1), deg)
    return spl(np.linspace(0.0, 1.0, n)).reshape(n, *ctrl.shape[1:])


def _polyline(ctrl: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    k = len(ctrl)
    s = np.linspace(0.0, k - 1, n)
    i = np.minimum(np.floor(s).astype(int), max(k - 2, 0))
    w = (s - i)[:, None, None]
    if k == 1:
        return np.repeat(ctrl, n, axis=0)
    return (1 - w) * ctrl[i] + w * ctrl[i + 1]


def smooth_paths(
    robot: Robot, env: Environment, path: NDArray[np.float64], upsample: int, n_min: int = 1
) -> tuple[NDArray[np.float64], bool]:
    """B-spline smoothing of the stage-1 iterates (k, p, 2) into max(upsample·k, n_min) samples (n, p, 2);
    returns (samples, smoothed?).

    Falls back to the piecewise-linear path when the spline leaves the free space or brings two bases closer than
    2 r_mb (at a sample or between consecutive samples).
    """
    n = max(upsample * len(path), n_min)
    S = _clamped_bspline(path, n)
    if _path_ok(robot, env, S):
        return S, True
    return _polyline(path, n), False


def _path_ok(robot: Robot, env: Environment, S: NDArray[np.float64]) -> bool:
    """Every base sample and sample-to-sample segment of S (n, p, 2) free, and the bases >= 2 r_mb apart at the
    samples and while they move straight and simultaneously between consecutive samples."""
    p = S.shape[1]
    if p > 1:
        iu = np.triu_indices(p, 1)
        gap = 2 * robot.base_radius - 1e-9
        if np.linalg.norm(S[:, iu[0]] - S[:, iu[1]], axis=-1).min() < gap:
            return False
        if len(S) > 1 and _min_pair_distance(S[:-1], S[1:], iu).min() < gap:
            return False
    if len(S) == 1:
        return bool(env.is_free(S).all())
    return bool((env.segment_clearance(S[:-1], S[1:]) > 0.0).all())


def path_headings(S: NDArray[np.float64], th0: NDArray[np.float64]) -> NDArray[np.float64]:
    """Headings (n, p) [rad] of differential-drive bases along samples S (n, p, 2): the tangent or its opposite,
    whichever is nearer the previous heading (driving backwards is allowed); unchanged while a base stands still."""
    n, p, _ = S.shape
    out = np.empty((n, p))
    th = th0.astype(float).copy()
    out[0] = th
    d = np.diff(S, axis=0)
    moving = np.linalg.norm(d, axis=-1) > 1e-9
    tang = np.arctan2(d[..., 1], d[..., 0])
    for r in range(1, n):
        fwd = np.angle(np.exp(1j * (tang[r - 1] - th)))
        step = np.where(np.abs(fwd) <= np.pi / 2, fwd, np.angle(np.exp(1j * (fwd - np.pi))))
        th = np.where(moving[r - 1], np.angle(np.exp(1j * (th + step))), th)
        out[r] = th
    return out


_DIRS = np.vstack([[0.0, 0.0], np.stack([np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)], 1)])


def platform_search(
    robot: Robot,
    start: NDArray[np.float64],
    goal: NDArray[np.float64],
    S: NDArray[np.float64],
    H: NDArray[np.float64],
    rws: NDArray[np.float64],
    params: PlannerParams,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Stage 2 for one way-point pair (Rasheed 2019 Algorithm 2): platform poses (n, 3) [m] and μ (n,) [N].

    At sample r the bases are at S[r] with headings H[r]; candidates are stay, 8 neighbours at d_MP and the step
    towards ``goal``; only candidates within (n−1−r)·d_MP of the goal are kept, so the last pose is the goal and
    every step is at most d_MP. Needs n >= :func:`samples_needed` (else ParameterError: the goal is out of reach).
    """
    n = len(S)
    d = params.d_platform
    need = samples_needed(start, goal, d)
    if n < need:
        raise ParameterError(
            f"platform_search: {n} samples cannot reach the way-point {fmt_point(goal)} from "
            f"{fmt_point(start)} with steps of d_MP = {d} m; at least {need} are needed"
        )
    out = np.empty((n, 3))
    mus = np.empty(n)
    xy = start[:2].astype(float).copy()
    g = goal[:2].astype(float)
    zs = np.linspace(start[2], goal[2], n)
    out[0] = [*xy, zs[0]]
    mus[0] = float(capacity(robot, out[0], S[0], H[0], rws).mu)
    for r in range(1, n):
        to_goal = g - xy
        dist = float(np.hypot(*to_goal))
        step = to_goal / dist * min(d, dist) if dist > 0 else np.zeros(2)
        cand = np.vstack([xy + d * _DIRS, xy + step])
        budget = (n - 1 - r) * d + _REACH_TOL * d
        keep = np.hypot(*(cand - g).T) <= budget
        if r == n - 1 and dist <= d * (1 + _REACH_TOL):
            cand, keep = g[None], np.ones(1, bool)  # land exactly on the way-point
        elif r == n - 1 or not keep.any():  # unreachable (n too small): cannot happen after the check above
            cand, keep = (xy + step)[None], np.ones(1, bool)
        cand = cand[keep]
        P = np.column_stack([cand, np.full(len(cand), zs[r])])
        mu = capacity(robot, P, S[r], H[r], rws).mu
        best = int(np.argmax(mu))
        xy = cand[best]
        out[r] = P[best]
        mus[r] = mu[best]
    return out, mus


#: Relative slack (of d_MP) in the stage-2 reachability test, absorbing rounding in distance / d_MP.
_REACH_TOL = 1e-9


def samples_needed(start: NDArray[np.float64], goal: NDArray[np.float64], d_platform: float) -> int:
    """Smallest number of stage-2 samples (start included) that moves the platform from ``start`` to ``goal`` with
    horizontal steps and (linearly interpolated) height steps of at most d_platform [m]; at least 2."""
    dxy = float(np.hypot(*(np.asarray(goal[:2], float) - np.asarray(start[:2], float))))
    dz = abs(float(goal[2]) - float(start[2]))
    return max(2, math.ceil(max(dxy, dz) / d_platform - _REACH_TOL) + 1)


def plan(robot: Robot, scene: Scene, params: PlannerParams | None = None, env: Environment | None = None) -> Plan:
    """Plan the whole task of ``scene``: way-points, stage 1 + smoothing per way-point, stage 2, tensions.

    Raises ScenarioError for an invalid scene. A way-point where stage 1 ends with μ <= 0 is not an error: the
    plan is returned and :func:`check` reports the samples.
    """
    params = params or PlannerParams()
    if not robot.one_cable_per_base:
        raise ParameterError(
            f"{robot.name}: the planner needs one cable per base (cable_base a permutation of 0..{robot.n_bases - 1}), "
            f"got cable_base = {list(robot.cable_base)}"
        )
    env = scene.validate(robot, env)
    rws = required_wrench_set(robot, scene.external)
    wps = waypoints(scene)
    xy, th = scene.bases.astype(float).copy(), scene.headings.astype(float).copy()
    start = wps[0].astype(float).copy()
    all_b, all_h, all_p, seg, stage1 = [], [], [], [], []
    t_stage1 = t_stage2 = 0.0
    for i in range(len(wps) - 1):
        t0 = time.perf_counter()
        path, heads, mus, scored = base_search(robot, env, wps[i + 1], xy, th, rws, params)
        n_min = samples_needed(start, wps[i + 1], params.d_platform)
        S, smoothed = smooth_paths(robot, env, path, params.upsample, n_min)
        H = path_headings(S, th)
        t1 = time.perf_counter()
        P, _ = platform_search(robot, start, wps[i + 1], S, H, rws, params)
        t2 = time.perf_counter()
        t_stage1 += t1 - t0
        t_stage2 += t2 - t1
        stage1.append({"iterates": path, "headings": heads, "mu": mus, "smoothed": smoothed, "combinations": scored})
        sl = slice(0 if i == 0 else 1, None)  # drop the duplicated first sample of later segments
        all_b.append(S[sl])
        all_h.append(H[sl])
        all_p.append(P[sl])
        seg.append(np.full(len(S[sl]), i))
        xy, th, start = path[-1].copy(), H[-1].copy(), P[-1].copy()
    bases = np.concatenate(all_b)
    headings = np.concatenate(all_h)
    platform = np.concatenate(all_p)
    t3 = time.perf_counter()
    cap = capacity(robot, platform, bases, headings, rws)
    tens = tensions(robot, cap.W, cap.lo, cap.hi)
    t4 = time.perf_counter()
    return Plan(
        waypoints=wps,
        bases=bases,
        headings=headings,
        platform=platform,
        segment=np.concatenate(seg),
        mu=cap.mu,
        tensions=tens,
        lo=cap.lo,
        hi=cap.hi,
        stage1=stage1,
        times={"stage1": t_stage1, "stage2": t_stage2, "evaluation": t4 - t3, "total": t_stage1 + t_stage2 + t4 - t3},
        params=params,
        external=np.asarray(scene.external, dtype=float).copy(),
    )


def tensions(
    robot: Robot, W: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Minimum 2-norm tensions (T, m) [N] holding the platform weight within [lo, hi] (NaN where infeasible).

    ``W`` (T, 3, m). The null-space closed form when m = n + 1 = 4 (fast, needs W of full rank); the cvxpy QP
    (:class:`~tmr.mcdpr.tension.TensionProblem`) for any other m and for the poses the closed form rejects.
    """
    T, n, m = W.shape
    f = np.array([0.0, 0.0, robot.platform_mass * robot.gravity])
    t = closed_form_batch(W, f, lo, hi).t if m == n + 1 else np.full((T, m), np.nan)
    todo = np.flatnonzero(~np.all(np.isfinite(t), axis=1))
    if len(todo):
        qp = TensionProblem(n, m, 2 * m, "2norm")
        for i in todo:
            if np.any(lo[i] > hi[i]):
                continue
            try:
                t[i] = qp.solve(W[i], f, *box_rows(lo[i], hi[i]))
            except InfeasibleWrench:
                t[i] = np.nan
    return t


@dataclass(frozen=True)
class Check:
    """Guarantees verified on a plan, all recomputed from its poses (the stored μ, bounds and tensions are not
    trusted). ok: all hold. mu_min [N] (recomputed); nonpositive: sample indices with μ ≤ 0; tension_ok: the stored
    tensions exist, balance the weight and respect the recomputed tipping-tightened bounds; collision_free: every
    base sample and sample-to-sample segment in the free space and the bases 2 r_mb apart at the samples and while
    moving straight between them; waypoints_ok: the platform starts at the first way-point and ends every segment
    at its way-point (within 1e-6 m); steps_ok: every platform step is at most d_MP horizontally and vertically;
    max_tension [N]; mu_between: for plans that claim a bound between samples (``mu_lower``, search planner), the
    guaranteed lower bound of μ over the whole motion [N], recomputed by :func:`tmr.mcdpr.certify.certify` (the
    claim fails the check when it is not > 0 or exceeds the recomputed one); NaN otherwise."""

    ok: bool
    mu_min: float
    nonpositive: tuple[int, ...]
    tension_ok: bool
    collision_free: bool
    max_tension: float
    messages: tuple[str, ...]
    waypoints_ok: bool = True
    steps_ok: bool = True
    mu_between: float = float("nan")


#: Distance [m] within which the platform counts as arriving at a way-point.
ARRIVAL_TOL = 1e-6


def check(robot: Robot, env: Environment, result: Plan, external: NDArray[np.float64] | None = None) -> Check:
    """Check μ > 0, cable tensions within bounds (and W t = f), no base collision, way-point arrival and platform
    steps ≤ d_MP along the plan. μ, W and the tipping bounds are recomputed from the poses with the external wrench
    box half-widths ``external`` [N] (default: the scene's, stored in ``result.external``)."""
    msgs = []
    rws = required_wrench_set(robot, result.external if external is None else external)
    cap = capacity(robot, result.platform, result.bases, result.headings, rws)
    mu = cap.mu
    nonpos = tuple(int(i) for i in np.flatnonzero(~(mu > 0)))
    if nonpos:
        msgs.append(
            f"capacity margin <= 0 at {len(nonpos)} of {len(mu)} samples (first {nonpos[0]}, segment "
            f"{int(result.segment[nonpos[0]])}, min {float(np.min(mu)):.4g} N)"
        )
    if not np.allclose(mu, result.mu, rtol=1e-9, atol=1e-9, equal_nan=True):
        bad = np.flatnonzero(~np.isclose(mu, result.mu, rtol=1e-9, atol=1e-9, equal_nan=True))
        msgs.append(f"stored capacity margin differs from the recomputed one at {len(bad)} samples (first {bad[0]})")
    t = np.asarray(result.tensions, dtype=float)
    if t.shape != cap.lo.shape:
        msgs.append(f"tensions have shape {t.shape}, expected {cap.lo.shape} (samples, cables)")
        tension_ok = False
        t = np.full(cap.lo.shape, np.nan)
    else:
        finite = np.all(np.isfinite(t), axis=1)
        f = np.array([0.0, 0.0, robot.platform_mass * robot.gravity])
        tf = np.where(finite[:, None], t, 0.0)
        balance = np.linalg.norm(np.einsum("tij,tj->ti", cap.W, tf) - f, axis=1) <= 1e-6
        inb = np.all((tf >= cap.lo - 1e-9) & (tf <= cap.hi + 1e-9) & (tf <= robot.t_max + 1e-9), axis=1)
        good = finite & balance & inb
        tension_ok = bool(np.all(good))
        if not tension_ok:
            bad = np.flatnonzero(~good)
            msgs.append(f"tensions infeasible or out of bounds at {len(bad)} samples (first {int(bad[0])})")
    collision_free = _path_ok(robot, env, result.bases)
    if not collision_free:
        msgs.append("a base path leaves the free space or two bases come closer than 2 r_mb")
    # way-point arrival: first sample at way-point 0, last sample of segment i at way-point i + 1
    wps, seg, P = result.waypoints, result.segment, result.platform
    miss = [(0, float(np.linalg.norm(P[0] - wps[0])))]
    for i in range(len(wps) - 1):
        idx = np.flatnonzero(seg == i)
        miss.append((i + 1, float(np.linalg.norm(P[idx[-1]] - wps[i + 1])) if len(idx) else float("inf")))
    missed = [(k, e) for k, e in miss if not e <= ARRIVAL_TOL]
    waypoints_ok = not missed
    if missed:
        worst = max(missed, key=lambda x: x[1])
        msgs.append(
            f"the platform misses {len(missed)} way-point(s) {[k for k, _ in missed]} (worst: way-point {worst[0]} "
            f"by {worst[1]:.4g} m)"
        )
    d = result.params.d_platform
    dP = np.diff(P, axis=0)
    step = np.maximum(np.hypot(dP[:, 0], dP[:, 1]), np.abs(dP[:, 2])) if len(dP) else np.zeros(0)
    long = np.flatnonzero(~(step <= d + 1e-9))
    steps_ok = not len(long)
    if not steps_ok:
        msgs.append(
            f"the platform jumps: {len(long)} step(s) longer than d_MP = {d} m (first between samples "
            f"{int(long[0])} and {int(long[0]) + 1}, longest {float(np.max(step)):.4g} m)"
        )
    mu_between = float("nan")
    if result.mu_lower is not None:
        from tmr.mcdpr.certify import certify

        cert = certify(robot, result.platform, result.bases, result.headings, rws)
        mu_between = float(np.min(cert.lower)) if len(cert.lower) else float(np.min(mu))
        if not cert.ok:
            msgs.append(
                f"μ is not certified > 0 between samples: lower bound {mu_between:.4g} N on a piece starting near "
                f"the platform at {fmt_point(cert.P[max(cert.fail, 0)])}"
            )
        elif float(np.min(result.mu_lower)) > mu_between + 1e-9:
            msgs.append(
                f"the plan claims μ >= {float(np.min(result.mu_lower)):.4g} N between samples, the recomputed bound "
                f"is {mu_between:.4g} N"
            )
    return Check(
        ok=not msgs,
        mu_between=mu_between,
        mu_min=float(np.min(mu)),
        nonpositive=nonpos,
        tension_ok=tension_ok,
        collision_free=collision_free,
        max_tension=float(np.nanmax(t)) if np.isfinite(t).any() else float("nan"),
        messages=tuple(msgs),
        waypoints_ok=waypoints_ok,
        steps_ok=steps_ok,
    )
