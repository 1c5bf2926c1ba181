"""Leader (end-effector) path and trajectory: the "Planner" and "Trajectory Generator" blocks of Caruso 2021 §4.2.

* :func:`plan_leader_path` — collision-free polyline from start to goal with OMPL's RRT* (the planner of Caruso 2021
  §4.2, ref. [41]), seeded and terminated by an **iteration count** so that the same seed gives the same path, byte for
  byte.  Every state and every straight segment of the tree is checked exactly against the inflated obstacles of the
  environment (``env.is_free`` / ``env.segment_clearance``), so the returned polyline is free, not just sampled free.
* :func:`time_law` — cubic B-spline through the waypoints (chord-length parametrisation), re-parametrised by arc
  length and traversed with a quintic minimum-jerk time law ``s(t)`` (zero velocity and acceleration at both ends),
  sampled at ``t = 0, Ts, ..., T_end``; position, velocity and acceleration are analytic (chain rule).
* :func:`leader_trajectory` — both, i.e. ``w = [X, Xdot, Xddot] = f(T_end, Ts, z)`` of Caruso 2021 §4.2.

The environment is duck-typed: only ``env.bounds``, ``env.is_free(points, margin)``, ``env.exact_clearance(points)`` and
``env.segment_clearance(a, b)`` are used (see :class:`tmr.environment.Environment`); clearances are signed distances
[m] to the obstacles inflated by the robot safety radius.
"""

from __future__ import annotations

import contextlib
import math
import operator
from collections.abc import Iterator
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicHermiteSpline, make_interp_spline

from tmr.errors import ParameterError, PathError

Array = NDArray[np.float64]

__all__ = ["Trajectory", "plan_leader_path", "time_law", "leader_trajectory", "path_length"]

#: Largest step [m] of OMPL's discrete motion checking (only used by OMPL helpers that interpolate states; the
#: motion validator itself is exact).
CHECK_STEP = 0.05
#: Arc-length spacing [m] of the dense spline samples checked against the obstacles in :func:`time_law`.
DENSE_STEP = 0.02
#: Points closer than this [m] are the same waypoint.
SAME_POINT = 1e-9
#: Rounds of local waypoint refinement :func:`time_law` tries before giving up on a spline that cuts a corner.
MAX_REFINEMENTS = 12


class Trajectory(NamedTuple):
    """Leader reference of Caruso 2021 §4.2, ``w = [X, Xdot, Xddot]`` sampled at ``t``.

    Attributes:
        t: (K+1,) sample times [s], ``0, Ts, ..., T_end`` (K = round(T_end / Ts); 300 steps for the defaults).
        x: (K+1, 2) leader reference position [m].
        xd: (K+1, 2) velocity [m/s].
        xdd: (K+1, 2) acceleration [m/s^2].
        waypoints: (M, 2) the path (e.g. RRT*) the trajectory was built from [m].
    """

    t: Array
    x: Array
    xd: Array
    xdd: Array
    waypoints: Array


# ----------------------------------------------------------------------------------------------------------------------
# input validation


def _as_point(p: ArrayLike, name: str) -> Array:
    try:
        a = np.asarray(p, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be an (x, y) position in metres, got {p!r}") from exc
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ParameterError(
            f"{name} must be a finite (x, y) position in metres, got {np.asarray(p).tolist()!r}"
        )
    return a


def _as_int(v: Any, name: str, lo: int, hi: int | None = None) -> int:
    try:
        i = operator.index(v)
    except TypeError as exc:
        raise ParameterError(f"{name} must be an integer, got {v!r}") from exc
    if i < lo or (hi is not None and i > hi):
        rng = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise ParameterError(f"{name} must be {rng}, got {i}")
    return int(i)


def _as_float(v: Any, name: str, *, positive: bool = False, nonneg: bool = False) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a number, got {v!r}") from exc
    if not math.isfinite(f):
        raise ParameterError(f"{name} must be finite, got {f}")
    if positive and f <= 0:
        raise ParameterError(f"{name} must be > 0, got {f}")
    if nonneg and f < 0:
        raise ParameterError(f"{name} must be >= 0, got {f}")
    return f


def _env_bounds(env: Any) -> tuple[float, float, float, float]:
    b = np.asarray(env.bounds, dtype=float)
    if b.shape != (4,) or not np.all(np.isfinite(b)) or b[2] <= b[0] or b[3] <= b[1]:
        raise ParameterError(
            f"env.bounds must be finite (xmin, ymin, xmax, ymax) with max > min, got {env.bounds!r}"
        )
    return float(b[0]), float(b[1]), float(b[2]), float(b[3])


def path_length(waypoints: ArrayLike) -> float:
    """Length [m] of the polyline through ``waypoints`` (M, 2)."""
    w = np.asarray(waypoints, dtype=float)
    return float(np.sum(np.linalg.norm(np.diff(w, axis=0), axis=1))) if len(w) > 1 else 0.0


# ----------------------------------------------------------------------------------------------------------------------
# planner: OMPL RRT*


@contextlib.contextmanager
def _ompl_log_level(ou: Any, level: Any) -> Iterator[None]:
    """Set OMPL's (process-global) log level for the duration of the block, then restore the caller's."""
    previous = ou.getLogLevel()
    ou.setLogLevel(level)
    try:
        yield
    finally:
        ou.setLogLevel(previous)


def _segment_clearance(env: Any, a: Array, b: Array) -> Array:
    return np.asarray(env.segment_clearance(a, b), dtype=float)


def _rrt_star(
    env: Any,
    start: Array,
    goal: Array,
    *,
    seed: int,
    iterations: int,
    margin: float,
    range_: float | None,
    simplify: bool,
) -> tuple[Array, Array, bool]:
    """Run RRT* (and optionally OMPL's path simplifier); return (raw path, simplified path, exact solution found)."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    class _ExactMotionValidator(ob.MotionValidator):
        """A straight motion is valid iff its exact clearance to the inflated obstacles exceeds ``margin``."""

        def __init__(self, si: Any) -> None:
            super().__init__(si)

        def checkMotion(self, s1: Any, s2: Any) -> bool:  # OMPL's name
            a = np.array((s1[0], s1[1]))
            b = np.array((s2[0], s2[1]))
            return bool(_segment_clearance(env, a, b) > margin)

    def state_valid(s: Any) -> bool:
        return bool(env.is_free(np.array((s[0], s[1])), margin=margin))

    xmin, ymin, xmax, ymax = _env_bounds(env)
    with _ompl_log_level(ou, ou.LOG_WARN):
        space = ob.RealVectorStateSpace(2)
        bounds = ob.RealVectorBounds(2)
        bounds.setLow(0, xmin)
        bounds.setLow(1, ymin)
        bounds.setHigh(0, xmax)
        bounds.setHigh(1, ymax)
        space.setBounds(bounds)
        si = ob.SpaceInformation(space)
        si.setStateValidityChecker(state_valid)
        si.setMotionValidator(_ExactMotionValidator(si))
        # Discrete checking step <= CHECK_STEP metres (the resolution is a fraction of the space's extent).
        si.setStateValidityCheckingResolution(min(0.5, CHECK_STEP / si.getMaximumExtent()))
        si.setup()

        s_state = space.allocState()
        g_state = space.allocState()
        for i in range(2):
            s_state[i] = float(start[i])
            g_state[i] = float(goal[i])
        pdef = ob.ProblemDefinition(si)
        pdef.setStartAndGoalStates(s_state, g_state)  # goal threshold = machine epsilon: the goal exactly
        objective = ob.PathLengthOptimizationObjective(si)
        pdef.setOptimizationObjective(objective)

        # OMPL seeds every RNG it constructs from one global seed generator; re-seeding it right before the planner
        # (and the simplifier) are built makes their samples a function of ``seed`` only.  OMPL reports an error when
        # the generator had already been used in this process, but it does reseed it (tested: same seed, same
        # path), so that message is silenced.  OMPL rejects seed 0, hence seed + 1.
        with _ompl_log_level(ou, ou.LOG_NONE):
            ou.RNG.setSeed(seed + 1)
        planner = og.RRTstar(si)
        if range_ is not None:
            planner.setRange(range_)
        planner.setProblemDefinition(pdef)
        planner.setup()
        # Termination by iteration count, not wall-clock: the condition is evaluated once per RRT* iteration.
        ptc = ob.PlannerTerminationCondition(lambda: planner.numIterations() >= iterations)
        planner.solve(ptc)
        exact = bool(pdef.hasExactSolution())
        if not exact:
            return np.empty((0, 2)), np.empty((0, 2)), False
        path = pdef.getSolutionPath()
        raw = np.array([(st[0], st[1]) for st in path.getStates()], dtype=float)
        simplified = raw
        if simplify:
            # Deterministic: no time limit (simplifyMax) and the simplifier's RNG comes from the seeded generator.
            simplifier = og.PathSimplifier(si, pdef.getGoal(), objective)
            simplifier.simplifyMax(path)
            simplified = np.array([(st[0], st[1]) for st in path.getStates()], dtype=float)
    return raw, simplified, True


def _dedupe(points: Array) -> Array:
    """Merge consecutive points closer than SAME_POINT; the last point is kept exactly (unless all coincide)."""
    keep = [points[0]]
    for p in points[1:]:
        if np.linalg.norm(p - keep[-1]) > SAME_POINT:
            keep.append(p)
    out = np.array(keep, dtype=float)
    if len(out) > 1:
        out[-1] = points[-1]
    return out


def _densify(points: Array, step: float) -> Array:
    """Insert equally spaced points on every segment so that no segment is longer than ``step`` [m]."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(1, math.ceil(np.linalg.norm(b - a) / step))
        f = np.arange(1, n + 1)[:, None] / n
        out.append(a + f * (b - a))
    res = np.vstack(out)
    res[-1] = points[-1]
    return res


def _string_pull(env: Any, points: Array, margin: float, step: float = 0.1) -> Array:
    """Deterministic shortcutting: from each kept point jump to the farthest point of the densified path that is
    visible through an exactly free segment (clearance > ``margin``); repeat from there."""
    dense = _densify(points, step)
    keep = [0]
    i = 0
    n = len(dense)
    while i < n - 1:
        cands = np.arange(i + 1, n)
        clear = _segment_clearance(env, np.broadcast_to(dense[i], (len(cands), 2)), dense[cands])
        ok = cands[clear > margin]
        j = int(ok.max()) if len(ok) else i + 1  # i + 1 is always valid (sub-segment of a valid segment)
        keep.append(j)
        i = j
    return dense[keep]


def plan_leader_path(
    env: Any,
    start: ArrayLike,
    goal: ArrayLike,
    *,
    seed: int = 0,
    iterations: int = 3000,
    clearance: float = 0.1,
    range: float | None = None,  # OMPL's name for the RRT* step
    simplify: bool = True,
) -> Array:
    """Collision-free leader path with RRT* (Caruso 2021 §4.2, "Planner", ref. [41]) via OMPL.

    States must have ``env.is_free(p, margin=clearance)`` and straight motions ``env.segment_clearance > clearance``
    (exact, a custom OMPL motion validator), i.e. ``clearance`` [m] is an extra margin beyond the obstacles inflated by
    the safety radius (RRT* paths hug obstacles).  If the start or the goal is free but closer than ``clearance`` to an
    obstacle, the margin is lowered to half of its clearance so that a path can leave it.  RRT* runs exactly
    ``iterations`` iterations (termination by count, never by wall-clock), seeded with ``seed``; with ``simplify`` the
    path is shortened by OMPL's ``PathSimplifier.simplifyMax`` (seeded, no time limit) and by a deterministic
    string-pulling pass with exact segment checks.  Same inputs give the same path, byte for byte.

    Args:
        env: environment (``bounds``, ``is_free``, ``exact_clearance``, ``segment_clearance``); the RRT* state
            space is the rectangle ``env.bounds`` [m].
        start, goal: (2,) positions [m].
        seed: integer in [0, 2**32 - 2] (OMPL is seeded with ``seed + 1``; it rejects 0).
        iterations: RRT* iterations (>= 1).
        clearance: extra margin [m] (>= 0) of every state and segment of the path.
        range: RRT* maximum extension [m] (None: OMPL's default, 20 % of the map diagonal).
        simplify: shorten the path (True) or return the raw RRT* tree path.

    Returns:
        (M, 2) waypoints [m], ``M >= 2``, first exactly ``start``, last exactly ``goal``; every segment has exact
        clearance > the margin used.

    Raises:
        ParameterError: malformed arguments.
        PathError: the start or the goal is in collision, or RRT* found no exact solution within ``iterations``.
    """
    start = _as_point(start, "start")
    goal = _as_point(goal, "goal")
    seed = _as_int(seed, "seed", 0, 2**32 - 2)
    iterations = _as_int(iterations, "iterations", 1)
    clearance = _as_float(clearance, "clearance", nonneg=True)
    range_ = None if range is None else _as_float(range, "range", positive=True)
    xmin, ymin, xmax, ymax = _env_bounds(env)

    margin = clearance
    for name, p in (("start", start), ("goal", goal)):
        c = float(np.asarray(env.exact_clearance(p), dtype=float))
        inside = xmin <= p[0] <= xmax and ymin <= p[1] <= ymax
        if not inside or c <= 0.0:
            where = "outside the room" if not inside else "inside an (inflated) obstacle"
            raise PathError(
                f"{name} {p.tolist()} is {where}: clearance {c:.3f} m to the obstacles grown by the safety radius "
                f"(must be > 0); move the {name} into free space"
            )
        margin = min(margin, 0.5 * c)

    if np.linalg.norm(goal - start) <= SAME_POINT:
        return np.vstack([start, goal])
    if float(_segment_clearance(env, start, goal)) > margin:
        return np.vstack([start, goal])  # the straight line is free: it is the optimal path

    raw, simplified, exact = _rrt_star(
        env, start, goal, seed=seed, iterations=iterations, margin=margin, range_=range_, simplify=simplify
    )
    if not exact:
        raise PathError(
            f"RRT* found no collision-free path from start {start.tolist()} to goal {goal.tolist()} in {iterations} "
            f"iterations (seed {seed}, clearance margin {margin:.3f} m); the goal may be unreachable (enclosed by "
            "obstacles or behind a gap narrower than the robot). Try more iterations, a smaller clearance, or a "
            "different goal"
        )

    candidates = [simplified, raw] if simplify else [raw]
    for k, path in enumerate(candidates):
        if simplify and k == 0:
            path = _string_pull(env, path, margin)
        path = _dedupe(path)
        if np.linalg.norm(path[0] - start) > 1e-9 or np.linalg.norm(path[-1] - goal) > 1e-9:
            continue
        path[0], path[-1] = start, goal
        if len(path) < 2:
            path = np.vstack([start, goal])
        if np.all(_segment_clearance(env, path[:-1], path[1:]) > margin):
            return np.ascontiguousarray(path)
    raise PathError(  # pragma: no cover - the motion validator is exact, so this means an inconsistent env
        f"the RRT* path from {start.tolist()} to {goal.tolist()} failed the exact segment check; the environment's "
        "segment_clearance and is_free disagree"
    )


# ----------------------------------------------------------------------------------------------------------------------
# trajectory generator: B-spline + arc length + quintic time law

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)


class _ArcLengthSpline:
    """Cubic interpolating B-spline p(u) through the points, u = cumulative chord length, with its arc length s(u)
    and the inverse u(s) (Hermite guess + Newton on the exact Gauss-Legendre arc length)."""

    def __init__(self, points: Array) -> None:
        self.points = points
        chords = np.linalg.norm(np.diff(points, axis=0), axis=1)
        self.u_knots = np.concatenate([[0.0], np.cumsum(chords)])
        self.p = make_interp_spline(self.u_knots, points, k=3)  # not-a-knot cubic B-spline
        self.dp = self.p.derivative(1)
        self.ddp = self.p.derivative(2)
        # arc-length table on a grid fine enough for an accurate Hermite inverse (<= 0.02 in u, 8 per interval)
        grid = []
        for a, b in zip(self.u_knots[:-1], self.u_knots[1:]):
            n = max(8, math.ceil((b - a) / 0.02))
            grid.append(np.linspace(a, b, n + 1)[:-1])
        grid.append(self.u_knots[-1:])
        self.u_grid = np.concatenate(grid)
        ds = self._integrate(self.u_grid[:-1], self.u_grid[1:])
        self.s_grid = np.concatenate([[0.0], np.cumsum(ds)])
        self.length = float(self.s_grid[-1])
        self._u_of_s = CubicHermiteSpline(self.s_grid, self.u_grid, 1.0 / self.speed(self.u_grid))

    def speed(self, u: Array) -> Array:
        """|dp/du| (dimensionless, ~1 for the chord-length parametrisation)."""
        return np.linalg.norm(self.dp(u), axis=-1)

    def _integrate(self, a: Array, b: Array) -> Array:
        """Arc length between parameters a and b (8-point Gauss-Legendre, exact to ~1e-12 on these spans)."""
        half = 0.5 * (b - a)
        mid = 0.5 * (b + a)
        u = mid[:, None] + half[:, None] * _GL_X[None, :]
        return half * (self.speed(u.ravel()).reshape(u.shape) @ _GL_W)

    def arc_length(self, u: Array) -> Array:
        j = np.clip(np.searchsorted(self.u_grid, u, side="right") - 1, 0, len(self.u_grid) - 2)
        return self.s_grid[j] + self._integrate(self.u_grid[j], u)

    def u_of_s(self, s: Array) -> Array:
        s = np.clip(s, 0.0, self.length)
        u = self._u_of_s(s)
        for _ in range(3):
            u = np.clip(u - (self.arc_length(u) - s) / self.speed(u), 0.0, self.u_knots[-1])
        return u

    def geometry(self, s: Array) -> tuple[Array, Array, Array, Array]:
        """Position, unit tangent dx/ds and d2x/ds2 at arc lengths s, and the parameters u."""
        u = self.u_of_s(s)
        x = self.p(u)
        d1 = self.dp(u)
        d2 = self.ddp(u)
        sp2 = np.sum(d1 * d1, axis=-1, keepdims=True)
        sp = np.sqrt(sp2)
        tangent = d1 / sp
        x_ss = (d2 - tangent * np.sum(tangent * d2, axis=-1, keepdims=True)) / sp2
        return x, tangent, x_ss, u


def _min_jerk(t: Array, T_end: float, L: float) -> tuple[Array, Array, Array]:
    """Quintic minimum-jerk time law s(t) = L (10 tau^3 - 15 tau^4 + 6 tau^5), tau = t / T_end, and its derivatives;
    zero velocity and acceleration at t = 0 and t = T_end."""
    tau = np.clip(t / T_end, 0.0, 1.0)
    s = L * tau**3 * (10.0 + tau * (-15.0 + 6.0 * tau))
    sd = (L / T_end) * 30.0 * tau**2 * (1.0 - tau) ** 2
    sdd = (L / T_end**2) * 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return s, sd, sdd


def _ensure_four(points: Array) -> Array:
    """A cubic spline needs >= 4 points: split the longest segment at its midpoint until there are."""
    pts = points
    while len(pts) < 4:
        i = int(np.argmax(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
        pts = np.insert(pts, i + 1, 0.5 * (pts[i] + pts[i + 1]), axis=0)
    return pts


def _check_spline(env: Any, spline: _ArcLengthSpline, clearance: float) -> tuple[bool, Array, float]:
    """Exact clearance of the spline, sampled every <= DENSE_STEP of arc length (segments between samples, minus the
    chord sagitta bound). Returns (ok, parameters u of the offending samples, min clearance)."""
    n = max(50, math.ceil(spline.length / DENSE_STEP))
    s = np.linspace(0.0, spline.length, n + 1)
    x, _, x_ss, u = spline.geometry(s)
    h = spline.length / n
    sagitta = h * h * float(np.max(np.linalg.norm(x_ss, axis=1))) / 8.0
    clear = _segment_clearance(env, x[:-1], x[1:]) - sagitta
    bad = clear < clearance
    return not bool(np.any(bad)), 0.5 * (u[:-1][bad] + u[1:][bad]), float(np.min(clear))


def _refine(points: Array, u_knots: Array, u_bad: Array) -> Array:
    """Insert the midpoint of every waypoint interval containing an offending parameter, and of its neighbours."""
    idx = np.clip(np.searchsorted(u_knots, u_bad, side="right") - 1, 0, len(points) - 2)
    marked = np.unique(np.clip(np.concatenate([idx - 1, idx, idx + 1]), 0, len(points) - 2))
    mids = 0.5 * (points[marked] + points[marked + 1])
    return np.insert(points, marked + 1, mids, axis=0)


def time_law(
    waypoints: ArrayLike,
    T_end: float = 15.0,
    Ts: float = 0.05,
    env: Any = None,
    clearance: float = 0.05,
) -> Trajectory:
    """Leader trajectory through ``waypoints`` (Caruso 2021 §4.2, "Trajectory Generator": B-spline, T_end, Ts).

    Cubic interpolating B-spline p(u) (scipy ``make_interp_spline``, not-a-knot) on the cumulative chord length u,
    re-parametrised by its arc length s (Gauss-Legendre quadrature, Newton inverse), traversed with the quintic
    minimum-jerk law s(t) = L (10 tau^3 - 15 tau^4 + 6 tau^5), tau = t / T_end, so the leader starts and stops with zero
    velocity and acceleration.  Derivatives are analytic: ``xd = x'(s) s_dot``, ``xdd = x''(s) s_dot^2 + x'(s) s_ddot``.

    If ``env`` is given, the whole spline (not only the samples) must have exact clearance >= ``clearance`` [m]; where
    it cuts a corner, midpoints are inserted into the offending waypoint intervals and the spline is rebuilt (at most
    MAX_REFINEMENTS rounds, deterministic).

    Args:
        waypoints: (M, 2) positions [m], M >= 2 (e.g. from :func:`plan_leader_path`); coincident consecutive points
            are merged; if all coincide the trajectory is constant.
        T_end: duration [s] (> 0).
        Ts: sampling period [s] (> 0); T_end / Ts must be an integer K (within 1e-6).
        env: optional environment (``segment_clearance``, ``exact_clearance``) to keep the spline free.
        clearance: required clearance [m] of the spline when ``env`` is given (>= 0).

    Returns:
        :class:`Trajectory` with K + 1 samples at ``t = linspace(0, T_end, K + 1)`` (step T_end / K = Ts); ``x[0]`` and
        ``x[-1]`` are exactly the first and last waypoint; ``waypoints`` is the input (M, 2).

    Raises:
        ParameterError: NaN/inf, fewer than 2 waypoints, T_end or Ts <= 0, T_end / Ts not an integer.
        PathError: the waypoint polyline itself, or the spline after refinement, violates ``clearance``.
    """
    try:
        wp = np.array(waypoints, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"waypoints must be an (M, 2) array of positions in metres: {exc}") from exc
    if wp.ndim != 2 or wp.shape[1] != 2 or wp.shape[0] < 2:
        raise ParameterError(f"waypoints must be an (M, 2) array with M >= 2, got shape {wp.shape}")
    if not np.all(np.isfinite(wp)):
        raise ParameterError("waypoints contain NaN or inf")
    T_end = _as_float(T_end, "T_end", positive=True)
    Ts = _as_float(Ts, "Ts", positive=True)
    clearance = _as_float(clearance, "clearance", nonneg=True)
    ratio = T_end / Ts
    K = round(ratio)
    if K < 1 or abs(ratio - K) > 1e-6 * max(1.0, ratio):
        raise ParameterError(
            f"T_end / Ts must be a positive integer number of steps, got T_end={T_end} s, Ts={Ts} s (ratio {ratio:.6g})"
        )
    t = np.linspace(0.0, T_end, K + 1)

    pts = _dedupe(wp)
    if len(pts) == 1:  # start == goal: stand still
        if env is not None:
            c = float(np.asarray(env.exact_clearance(pts[0]), dtype=float))
            if c < clearance:
                raise PathError(
                    f"the (single) waypoint {pts[0].tolist()} has clearance {c:.3f} m < {clearance} m"
                )
        x = np.repeat(pts[:1], K + 1, axis=0)
        return Trajectory(t, x, np.zeros_like(x), np.zeros_like(x), wp)

    if env is not None:
        poly = _segment_clearance(env, pts[:-1], pts[1:])
        if np.any(poly < clearance):
            i = int(np.argmin(poly))
            raise PathError(
                f"waypoint segment {i} {pts[i].tolist()} -> {pts[i + 1].tolist()} has clearance {poly[i]:.3f} m < the "
                f"required {clearance} m, so no spline through the waypoints can keep it; plan the path with a larger "
                "clearance or pass a smaller one"
            )

    pts = _ensure_four(pts)
    for _ in range(MAX_REFINEMENTS + 1):
        spline = _ArcLengthSpline(pts)
        if env is None:
            break
        ok, u_bad, cmin = _check_spline(env, spline, clearance)
        if ok:
            break
        pts = _refine(pts, spline.u_knots, u_bad)
    else:
        raise PathError(
            f"the B-spline through the waypoints cuts a corner (clearance {cmin:.3f} m < {clearance} m) even after "
            f"{MAX_REFINEMENTS} refinements; pass a smaller clearance or waypoints with more clearance"
        )

    s, sd, sdd = _min_jerk(t, T_end, spline.length)
    x, tangent, x_ss, _ = spline.geometry(s)
    xd = tangent * sd[:, None]
    xdd = x_ss * (sd**2)[:, None] + tangent * sdd[:, None]
    x[0], x[-1] = wp[0], wp[-1]
    return Trajectory(t, x, xd, xdd, wp)


def leader_trajectory(
    env: Any,
    start: ArrayLike,
    goal: ArrayLike,
    *,
    seed: int = 0,
    T_end: float = 15.0,
    Ts: float = 0.05,
    iterations: int = 3000,
    clearance: float = 0.1,
    spline_clearance: float | None = None,
    range: float | None = None,
) -> Trajectory:
    """Leader trajectory from ``start`` to ``goal``: :func:`plan_leader_path` then :func:`time_law` (Caruso 2021 §4.2).

    Args:
        env, start, goal, seed, iterations, clearance, range: see :func:`plan_leader_path`.
        T_end, Ts: see :func:`time_law`.
        spline_clearance: clearance [m] the spline must keep (default: half of the smallest segment clearance of the
            planned path, at most ``clearance / 2``), so the spline may cut corners into the planning margin only.
    """
    waypoints = plan_leader_path(
        env, start, goal, seed=seed, iterations=iterations, clearance=clearance, range=range
    )
    if spline_clearance is None:
        seg = _segment_clearance(env, waypoints[:-1], waypoints[1:])
        spline_clearance = max(
            0.0, min(0.5 * _as_float(clearance, "clearance", nonneg=True), 0.5 * float(seg.min()))
        )
    return time_law(waypoints, T_end=T_end, Ts=Ts, env=env, clearance=spline_clearance)
