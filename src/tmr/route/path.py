"""Leader path and trajectory: the "Planner" and "Trajectory Generator" blocks of Caruso 2021 §4.2.

* :func:`plan_leader_path` -- collision-free polyline from start to goal with OMPL's RRT* (the planner of
  Caruso 2021 §4.2, ref. [41]), seeded and stopped after a fixed **number of iterations**, so the same seed
  gives the same path, byte for byte. Every state and every straight motion is checked exactly against the
  inflated obstacles (``env.is_free`` / ``env.segment_is_free``): the polyline is free, not sampled free.
* :func:`time_law` -- not-a-knot cubic spline through the waypoints (chord-length parametrisation), re-parametrised by
  arc length and traversed with the quintic minimum-jerk law ``s(t)`` (zero velocity and acceleration at both
  ends), sampled at ``t = 0, Ts, ..., T_end``; position, velocity and acceleration are analytic.
* :func:`leader_trajectory` -- both: ``w = [X, Xdot, Xddot] = f(T_end, Ts, z)`` of Caruso 2021 §4.2.

The environment is duck-typed: only ``env.bounds``, ``env.is_free(points, margin)``,
``env.exact_clearance(points)``, ``env.segment_clearance(a, b)`` and ``env.segment_is_free(a, b, margin)`` are used (see
:class:`tmr.world.environment.Environment`). Clearances are signed distances [m] to the obstacles inflated by the
robot safety radius. The leader is a robot: low obstacles (:class:`tmr.world.environment.LowObstacle`) are
obstacles here like any other (the whole ``env``, never its ``tether_environment``).
"""

from __future__ import annotations

import contextlib
import functools
import math
import operator
import threading
from collections.abc import Iterator
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.errors import NoPathFound, ParameterError, PathError, fmt_point
from tmr.model.params import MAX_STEPS
from tmr.route.splines import HermiteSpline, NotAKnotSpline

Array = NDArray[np.float64]

__all__ = ["Trajectory", "leader_trajectory", "min_jerk", "path_length", "plan_leader_path", "time_law"]

#: Default number of RRT* iterations of :func:`plan_leader_path`.
DEFAULT_ITERATIONS = 3000
#: OMPL's state-checking step [m] (motions themselves are checked exactly: ``env.segment_is_free``).
CHECK_STEP = 0.05
#: Arc-length spacing [m] of the dense spline samples checked against the obstacles in :func:`time_law`.
DENSE_STEP = 0.02
#: Points closer than this [m] are the same waypoint.
SAME_POINT = 1e-9
#: OMPL's seed generator and log level are process-global, and the environment's prepared shapely geometry is
#: not thread-safe: whole planning calls are serialised so that concurrent threads still get their seed's path.
_OMPL_LOCK = threading.RLock()


def _serialised(fn: Any) -> Any:
    """Run ``fn`` under :data:`_OMPL_LOCK`."""

    @functools.wraps(fn)
    def locked(*args: Any, **kwargs: Any) -> Any:
        with _OMPL_LOCK:
            return fn(*args, **kwargs)

    return locked


#: Rounds of local waypoint refinement :func:`time_law` tries before giving up on a spline that cuts a corner.
MAX_REFINEMENTS = 12


class Trajectory(NamedTuple):
    """Leader reference of Caruso 2021 §4.2, ``w = [X, Xdot, Xddot]`` sampled at ``t``.

    Attributes:
        t: (K+1,) sample times [s], ``0, Ts, ..., T_end`` (K = round(T_end / Ts); 300 for the defaults).
        x: (K+1, 2) leader reference position [m].
        xd: (K+1, 2) velocity [m/s].
        xdd: (K+1, 2) acceleration [m/s^2].
        waypoints: (M, 2) the path (e.g. from RRT*) the trajectory was built from [m].
    """

    t: Array
    x: Array
    xd: Array
    xdd: Array
    waypoints: Array


# ------------------------------------------------------------------------------------------------------------
# input validation


def _as_point(p: ArrayLike, name: str) -> Array:
    try:
        a = np.asarray(p, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be an (x, y) position in metres, got {p!r}") from exc
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be a finite (x, y) position in metres, got {a.tolist()!r}")
    return a


def _as_int(v: Any, name: str, lo: int, hi: int | None = None) -> int:
    try:
        i = operator.index(v)
    except TypeError as exc:
        raise ParameterError(f"{name} must be an integer, got {v!r}") from exc
    if i < lo or (hi is not None and i > hi):
        allowed = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise ParameterError(f"{name} must be {allowed}, got {i}")
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
        raise ParameterError(f"env.bounds must be finite (xmin, ymin, xmax, ymax) with max > min, got {env.bounds!r}")
    return float(b[0]), float(b[1]), float(b[2]), float(b[3])


def path_length(waypoints: ArrayLike) -> float:
    """Length [m] of the polyline through ``waypoints`` (M, 2)."""
    w = np.asarray(waypoints, dtype=float)
    return float(np.sum(np.linalg.norm(np.diff(w, axis=0), axis=1))) if len(w) > 1 else 0.0


# ------------------------------------------------------------------------------------------------------------
# exact segment tests


def _segment_clearance(env: Any, a: ArrayLike, b: ArrayLike) -> Array:
    return np.asarray(env.segment_clearance(a, b), dtype=float)


@functools.cache
def _motion_validator_class() -> type:
    """The OMPL motion validator class, defined on first use (OMPL is imported only when RRT* runs)."""
    from ompl import base as ob

    class _ExactMotionValidator(ob.MotionValidator):
        """OMPL motion validator: a straight motion is valid iff its exact clearance exceeds ``margin`` [m]."""

        def __init__(self, si: Any, env: Any, margin: float) -> None:
            super().__init__(si)
            self._env = env
            self._margin = margin

        def checkMotion(self, s1: Any, s2: Any) -> bool:  # OMPL's method name
            a = np.array((s1[0], s1[1]))
            b = np.array((s2[0], s2[1]))
            return bool(self._env.segment_is_free(a, b, self._margin))

    return _ExactMotionValidator


# ------------------------------------------------------------------------------------------------------------
# planner: OMPL RRT*


@contextlib.contextmanager
def _ompl_log_level(level: Any) -> Iterator[None]:
    """Set OMPL's (process-global) log level for the duration of the block, then restore the caller's."""
    from ompl import util as ou

    previous = ou.getLogLevel()
    ou.setLogLevel(level)
    try:
        yield
    finally:
        ou.setLogLevel(previous)


def _states(path: Any) -> Array:
    return np.array([(st[0], st[1]) for st in path.getStates()], dtype=float).reshape(-1, 2)


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
) -> tuple[Array, Array] | None:
    """RRT*, then optionally OMPL's simplifier: (raw path, simplified path), or None if no exact solution."""
    from ompl import base as ob  # imported here: only the --route rrt planner needs OMPL
    from ompl import geometric as og
    from ompl import util as ou

    xmin, ymin, xmax, ymax = _env_bounds(env)

    def state_valid(s: Any) -> bool:
        return bool(env.is_free(np.array((s[0], s[1])), margin=margin))

    with _OMPL_LOCK, _ompl_log_level(ou.LOG_WARN):
        space = ob.RealVectorStateSpace(2)
        bounds = ob.RealVectorBounds(2)
        bounds.setLow(0, xmin)
        bounds.setLow(1, ymin)
        bounds.setHigh(0, xmax)
        bounds.setHigh(1, ymax)
        space.setBounds(bounds)
        si = ob.SpaceInformation(space)
        si.setStateValidityChecker(state_valid)
        si.setMotionValidator(_motion_validator_class()(si, env, margin))
        # State-checking step <= CHECK_STEP [m] (OMPL takes it as a fraction of the space's extent); only
        # used by OMPL helpers that interpolate states, motions are validated exactly.
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

        # OMPL seeds every RNG it constructs from one global seed generator. Re-seeding it right before the
        # planner and the simplifier are built makes their samples a function of ``seed`` only. OMPL logs an
        # error if the generator was used before in this process, but it does reseed it (tested: same seed,
        # same path), so that message is silenced. OMPL rejects seed 0, hence seed + 1.
        with _ompl_log_level(ou.LOG_NONE):
            ou.RNG.setSeed(seed + 1)
        planner = og.RRTstar(si)
        if range_ is not None:
            planner.setRange(range_)
        planner.setProblemDefinition(pdef)
        planner.setup()
        # Termination by iteration count, never wall-clock: OMPL evaluates the condition once per iteration.
        ptc = ob.PlannerTerminationCondition(lambda: planner.numIterations() >= iterations)
        planner.solve(ptc)
        if not pdef.hasExactSolution():
            return None
        path = pdef.getSolutionPath()
        raw = _states(path)
        simplified = raw
        if simplify:
            # Deterministic: no time limit (simplifyMax); the simplifier's RNG is from the seeded generator.
            simplifier = og.PathSimplifier(si, pdef.getGoal(), objective)
            simplifier.simplifyMax(path)
            simplified = _states(path)
    return raw, simplified


def _dedupe(points: Array) -> Array:
    """Merge consecutive points closer than SAME_POINT; the last point is kept exactly unless all coincide."""
    keep = [points[0]]
    for p in points[1:]:
        if np.linalg.norm(p - keep[-1]) > SAME_POINT:
            keep.append(p)
    out = np.array(keep, dtype=float)
    if len(out) > 1:
        out[-1] = points[-1]
    return out


def _densify(points: Array, step: float) -> Array:
    """Insert equally spaced points on every segment so that none is longer than ``step`` [m]."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:], strict=True):
        n = max(1, math.ceil(np.linalg.norm(b - a) / step))
        out.append(a + (np.arange(1, n + 1)[:, None] / n) * (b - a))
    res = np.vstack(out)
    res[-1] = points[-1]
    return res


def _string_pull(env: Any, points: Array, margin: float, step: float = 0.1) -> Array:
    """Deterministic shortcutting with exact segment tests: from the current point, jump to the farthest point
    of the path (densified every ``step`` [m]) joined to it by a free segment (clearance > ``margin``)."""
    dense = _densify(points, step)
    keep = [0]
    i = 0
    n = len(dense)
    while i < n - 1:
        cands = np.arange(i + 1, n)
        ok = cands[env.segment_is_free(np.repeat(dense[i : i + 1], len(cands), axis=0), dense[cands], margin)]
        # dense[i] -> dense[i + 1] lies on a free segment of the input path, so it is free too
        i = int(ok.max()) if len(ok) else i + 1
        keep.append(i)
    return dense[keep]


@_serialised
def plan_leader_path(
    env: Any,
    start: ArrayLike,
    goal: ArrayLike,
    *,
    seed: int = 0,
    iterations: int = DEFAULT_ITERATIONS,
    clearance: float = 0.1,
    range: float | None = None,  # OMPL's name for the RRT* extension length
    simplify: bool = True,
) -> Array:
    """Collision-free leader path with RRT* (Caruso 2021 §4.2, "Planner", ref. [41]) via OMPL.

    States need ``env.is_free(p, margin)`` and straight motions ``env.segment_clearance > margin`` (an exact
    OMPL motion validator), with ``margin = clearance`` [m]: an extra margin beyond the obstacles inflated by
    the safety radius (RRT* paths hug obstacles). If the start or the goal is free but closer than
    ``clearance`` to an obstacle, the margin is lowered to half its clearance so that a path can leave it.

    RRT* runs exactly ``iterations`` iterations (termination by count, never by wall-clock), seeded with
    ``seed``. With ``simplify`` the path is shortened by OMPL's ``PathSimplifier.simplifyMax`` (seeded RNG, no
    time limit) and a string-pulling pass with exact segment tests. Same inputs give the same path, byte for
    byte. If the straight segment start-goal is free it is returned without planning.

    Args:
        env: environment (``bounds``, ``is_free``, ``exact_clearance``, ``segment_clearance``); the RRT* state
            space is the rectangle ``env.bounds`` [m].
        start, goal: (2,) positions [m].
        seed: integer in [0, 2**32 - 2]; OMPL is seeded with ``seed + 1`` (it rejects 0).
        iterations: RRT* iterations (>= 1).
        clearance: extra margin [m] (>= 0) kept by every state and segment of the path.
        range: RRT* maximum extension [m] (None: OMPL's default, 20 % of the room's diagonal).
        simplify: shorten the path (True) or return the raw RRT* path.

    Returns:
        (M, 2) waypoints [m], M >= 2, first exactly ``start``, last exactly ``goal``; every segment has exact
        clearance > the margin used.

    Raises:
        ParameterError: malformed arguments.
        PathError: start or goal outside the room or in collision (with its clearance).
        NoPathFound: (a PathError) RRT* found no exact solution within ``iterations`` (a verdict of the search).
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
                f"{name} {fmt_point(p)} is {where}: clearance {c:.3f} m to the obstacles grown by the safety "
                f"radius (must be > 0); move the {name} into free space"
            )
        margin = min(margin, 0.5 * c)

    if np.linalg.norm(goal - start) <= SAME_POINT:
        return np.vstack([start, goal])
    if env.segment_is_free(start, goal, margin):
        return np.vstack([start, goal])  # the straight line is free: it is the shortest path

    found = _rrt_star(
        env, start, goal, seed=seed, iterations=iterations, margin=margin, range_=range_, simplify=simplify
    )
    if found is None:
        raise NoPathFound(
            f"RRT* found no collision-free path from start {fmt_point(start)} to goal {fmt_point(goal)} in "
            f"{iterations} iterations (seed {seed}, clearance margin {margin:.3f} m): the goal may be "
            "unreachable (enclosed by obstacles, or behind a gap too narrow for the robot). Try more "
            "iterations, a smaller clearance, or a different goal"
        )
    raw, simplified = found
    candidates = [_string_pull(env, simplified, margin), raw] if simplify else [raw]
    for path in candidates:
        path = _dedupe(path)
        if len(path) < 2 or np.linalg.norm(path[0] - start) > 1e-9 or np.linalg.norm(path[-1] - goal) > 1e-9:
            continue
        path[0], path[-1] = start, goal
        # final exact check of every segment (the motion validator is exact, so this is a safeguard)
        if np.all(_segment_clearance(env, path[:-1], path[1:]) > margin):
            return np.ascontiguousarray(path)
    raise PathError(  # pragma: no cover - the motion validator is exact: an inconsistent env gets here
        f"the RRT* path from {fmt_point(start)} to {fmt_point(goal)} failed the final exact segment check; "
        "env.is_free and env.segment_clearance disagree"
    )


# ------------------------------------------------------------------------------------------------------------
# trajectory generator: cubic spline, arc length, minimum-jerk time law

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)


class _Cusp(ParameterError):
    """The spline's tangent turns by 90° or more within 0.02 m (or stops): a cusp or a loop, at parameter ``u`` of the
    spline whose waypoint parameters are ``u_knots``."""

    def __init__(self, message: str, u: float, u_knots: Array) -> None:
        super().__init__(message)
        self.u, self.u_knots = u, u_knots


class _ArcLengthSpline:
    """Cubic interpolating spline p(u) (not-a-knot, :class:`tmr.route.splines.NotAKnotSpline`) through the points
    (u = cumulative chord length [m]), its arc length s(u) (Gauss-Legendre) and the inverse u(s) (Hermite
    interpolation of a table, :class:`tmr.route.splines.HermiteSpline`, then Newton steps). Raises :class:`_Cusp`
    where the spline turns back on itself."""

    def __init__(self, points: Array) -> None:
        chords = np.linalg.norm(np.diff(points, axis=0), axis=1)
        self.u_knots = np.concatenate([[0.0], np.cumsum(chords)])
        self._p = NotAKnotSpline(self.u_knots, points)
        grid = [
            np.linspace(a, b, max(8, math.ceil((b - a) / 0.02)) + 1)[:-1]
            for a, b in zip(self.u_knots[:-1], self.u_knots[1:], strict=True)
        ]
        self.u_grid = np.concatenate([*grid, self.u_knots[-1:]])
        d1 = self._p(self.u_grid, 1)
        speed = np.linalg.norm(d1, axis=1)
        turn = np.sum(d1[:-1] * d1[1:], axis=1)  # <= 0: the tangent turns >= 90 deg within 0.02 m: a cusp
        if np.min(speed) < 1e-9 or np.any(turn <= 0.0):
            i = int(np.argmin(turn)) if np.any(turn <= 0.0) else int(np.argmin(speed))
            raise _Cusp(
                f"the waypoints turn back on themselves near {fmt_point(self._p(self.u_grid[i]))} (a cusp "
                "of the spline); remove the reversal from the waypoints",
                float(self.u_grid[i]),
                self.u_knots,
            )
        ds = self._integrate(self.u_grid[:-1], self.u_grid[1:])
        self.s_grid = np.concatenate([[0.0], np.cumsum(ds)])
        self.length = float(self.s_grid[-1])
        self._u_of_s = HermiteSpline(self.s_grid, self.u_grid, 1.0 / speed)

    def speed(self, u: Array) -> Array:
        """|dp/du| (dimensionless, about 1 for the chord-length parametrisation)."""
        return np.linalg.norm(self._p(u, 1), axis=-1)

    def _integrate(self, a: Array, b: Array) -> Array:
        """Arc length [m] from parameter a to b (8-point Gauss-Legendre on spans <= 0.02)."""
        half = 0.5 * (b - a)
        u = (0.5 * (b + a))[:, None] + half[:, None] * _GL_X[None, :]
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
        """At arc lengths s [m]: position x, unit tangent dx/ds, curvature vector d2x/ds2 [1/m], and u."""
        u = self.u_of_s(s)
        x = self._p(u)
        d1 = self._p(u, 1)
        d2 = self._p(u, 2)
        sp2 = np.sum(d1 * d1, axis=-1, keepdims=True)
        tangent = d1 / np.sqrt(sp2)
        x_ss = (d2 - tangent * np.sum(tangent * d2, axis=-1, keepdims=True)) / sp2
        return x, tangent, x_ss, u


def min_jerk(t: Array, T_end: float, L: float) -> tuple[Array, Array, Array]:
    """Quintic minimum-jerk law s = L (10 tau^3 - 15 tau^4 + 6 tau^5), tau = t / T_end [m], with s_dot [m/s]
    and s_ddot [m/s^2]; zero velocity and acceleration at t = 0 and t = T_end."""
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
    """Exact clearance of the whole spline: segments between samples every <= DENSE_STEP of arc length, minus
    the chord-to-arc gap bound h^2 kappa_max / 8. Returns (ok, parameters u of offending spans, min)."""
    n = max(50, math.ceil(spline.length / DENSE_STEP))
    s = np.linspace(0.0, spline.length, n + 1)
    x, _, x_ss, u = spline.geometry(s)
    h = spline.length / n
    sagitta = h * h * float(np.max(np.linalg.norm(x_ss, axis=1))) / 8.0
    clear = _segment_clearance(env, x[:-1], x[1:]) - sagitta
    bad = clear < clearance
    return not bool(np.any(bad)), 0.5 * (u[:-1][bad] + u[1:][bad]), float(np.min(clear))


def _refine(points: Array, u_knots: Array, u_bad: Array) -> Array:
    """Insert the midpoint of each waypoint interval holding an offending parameter and of its neighbours."""
    idx = np.clip(np.searchsorted(u_knots, u_bad, side="right") - 1, 0, len(points) - 2)
    marked = np.unique(np.clip(np.concatenate([idx - 1, idx, idx + 1]), 0, len(points) - 2))
    return np.insert(points, marked + 1, 0.5 * (points[marked] + points[marked + 1]), axis=0)


def time_law(
    waypoints: ArrayLike,
    T_end: float = 15.0,
    Ts: float = 0.05,
    env: Any = None,
    clearance: float = 0.05,
) -> Trajectory:
    """Leader trajectory through ``waypoints`` (Caruso 2021 §4.2, "Trajectory Generator").

    Cubic interpolating spline p(u) (not-a-knot, :class:`tmr.route.splines.NotAKnotSpline`) on the cumulative chord
    length u, re-parametrised by its arc length s (Gauss-Legendre quadrature, Newton inverse), traversed with
    the quintic minimum-jerk law s(t) = L (10 tau^3 - 15 tau^4 + 6 tau^5), tau = t / T_end: the leader starts
    and stops with zero velocity and acceleration. Derivatives are analytic (chain rule):
    ``xd = x'(s) s_dot`` and ``xdd = x''(s) s_dot^2 + x'(s) s_ddot``.

    If ``env`` is given, the whole spline (not only the samples) must keep exact clearance >= ``clearance``
    [m]. Where it cuts a corner, midpoints are inserted into the offending waypoint intervals and the spline
    is rebuilt (at most MAX_REFINEMENTS rounds, deterministic). The same where the spline loops round a sharp turn
    between short segments (its tangent turning by 90° or more within 0.02 m: a cusp of the spline, not of the
    waypoints): the midpoints there keep it close to the polyline; a polyline that itself turns back along its path
    keeps its cusp and is refused.

    Args:
        waypoints: (M, 2) positions [m], M >= 2 (e.g. from :func:`plan_leader_path`). Coincident consecutive
            points are merged; if all coincide the trajectory is constant (the leader stays put).
        T_end: duration [s] (> 0); Caruso 2021 uses 15 s.
        Ts: sampling period [s] (> 0); T_end / Ts must be an integer K (within 1e-6); Caruso 2021 uses 0.05 s.
        env: optional environment (``segment_clearance``, ``exact_clearance``) the spline must stay free in.
        clearance: clearance [m] (>= 0) the spline must keep when ``env`` is given.

    Returns:
        :class:`Trajectory` with K + 1 samples at ``t = linspace(0, T_end, K + 1)`` (step T_end / K = Ts).
        ``x[0]`` and ``x[-1]`` are exactly the first and last waypoint; ``waypoints`` is the input.

    Raises:
        ParameterError: NaN/inf, fewer than 2 waypoints, T_end or Ts <= 0, T_end / Ts not an integer,
            waypoints reversing onto themselves (a cusp that MAX_REFINEMENTS rounds of midpoints do not remove).
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
            f"T_end / Ts must be a whole number of steps, got T_end = {T_end} s, Ts = {Ts} s "
            f"(ratio {ratio:.6g}); choose Ts dividing T_end"
        )
    if K > MAX_STEPS:  # before any array of K samples: a very slow leader is refused, not an out-of-memory crash
        raise ParameterError(
            f"the leader's motion would take {T_end:.6g} s, {K:,} steps of Ts = {Ts:g} s: above the planner's limit of "
            f"{MAX_STEPS:,} steps (tmr.model.params.MAX_STEPS); a faster leader (leader_speed, or a robot model's "
            "v_max) or a shorter route"
        )
    t = np.linspace(0.0, T_end, K + 1)

    pts = _dedupe(wp)
    if len(pts) == 1:  # zero-length path (start == goal): stand still
        if env is not None:
            c = float(np.asarray(env.exact_clearance(pts[0]), dtype=float))
            if c < clearance:
                raise PathError(f"the waypoint {fmt_point(pts[0])} has clearance {c:.3f} m < {clearance} m")
        x = np.repeat(wp[:1], K + 1, axis=0)
        return Trajectory(t, x, np.zeros_like(x), np.zeros_like(x), wp)

    if env is not None:
        poly = _segment_clearance(env, pts[:-1], pts[1:])
        if np.any(poly < clearance):
            i = int(np.argmin(poly))
            raise PathError(
                f"waypoint segment {i} {fmt_point(pts[i])} -> {fmt_point(pts[i + 1])} has clearance "
                f"{poly[i]:.3f} m < the required {clearance} m, so no spline through the waypoints can keep "
                "it; plan the path with a larger clearance or pass a smaller one"
            )

    pts = _ensure_four(pts)
    cusp: _Cusp | None = None
    for _ in range(MAX_REFINEMENTS + 1):
        try:
            spline = _ArcLengthSpline(pts)
        except _Cusp as exc:  # the spline loops round a sharp turn between short segments: denser waypoints there
            cusp = exc
            pts = _refine(pts, exc.u_knots, np.array([exc.u]))
            continue
        cusp = None
        if env is None:
            break
        ok, u_bad, cmin = _check_spline(env, spline, clearance)
        if ok:
            break
        pts = _refine(pts, spline.u_knots, u_bad)
    else:
        if cusp is not None:  # still a cusp: the waypoints themselves turn back (a reversal no refinement removes)
            raise ParameterError(str(cusp))
        raise PathError(
            f"the cubic spline through the waypoints cuts a corner (clearance {cmin:.3f} m < {clearance} m) even "
            f"after {MAX_REFINEMENTS} refinements; pass a smaller clearance or waypoints with more clearance"
        )

    s, sd, sdd = min_jerk(t, T_end, spline.length)
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
    iterations: int = DEFAULT_ITERATIONS,
    clearance: float = 0.1,
    spline_clearance: float | None = None,
    range: float | None = None,
) -> Trajectory:
    """Leader trajectory from ``start`` to ``goal`` (Caruso 2021 §4.2): :func:`plan_leader_path`, then
    :func:`time_law` with the environment.

    Args:
        env, start, goal, seed, iterations, clearance, range: see :func:`plan_leader_path`.
        T_end, Ts: see :func:`time_law` (defaults 15 s and 0.05 s as in Caruso 2021).
        spline_clearance: clearance [m] the spline must keep. Default: half the planning margin actually
            kept by the path (at most ``clearance / 2``), so the spline may only cut into that margin.
    """
    waypoints = plan_leader_path(env, start, goal, seed=seed, iterations=iterations, clearance=clearance, range=range)
    if spline_clearance is None:
        kept = float(np.min(_segment_clearance(env, waypoints[:-1], waypoints[1:])))
        spline_clearance = max(0.0, 0.5 * min(float(clearance), kept))
    return time_law(waypoints, T_end=T_end, Ts=Ts, env=env, clearance=spline_clearance)
