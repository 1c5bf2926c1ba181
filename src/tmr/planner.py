"""From a scenario to a checked plan: scenario → route → chain, limits, start → references → formulation → plan →
checks → metrics.

The route (:mod:`tmr.route.route`) comes first: a goal with no free route, or a chain with fewer robots than the route
needs, is refused before any motion is planned (:class:`tmr.route.route.NoRouteError`, :class:`TooFewRobotsError`).

This is the library entry point behind ``python -m tmr.plan``::

    import tmr
    problem = tmr.build_problem(tmr.load_scenario("A"), seed=0)
    plan, metrics = tmr.solve(problem, "pinv")
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.checks.metrics import Metrics, evaluate, fitness
from tmr.control.clik import Formulation, Plan, run
from tmr.control.limits import JointBox, Limit, ObstacleClearance, RobotAcceleration, RobotSeparation, RobotSpeed
from tmr.control.tasks import (
    Damping,
    LeaderTracking,
    ObstacleEvasion,
    RouteFollowers,
    Smoothness,
    SpanUniformity,
    Task,
    TetherRegulation,
)
from tmr.errors import ParameterError, PathError, ScenarioError, fmt_point
from tmr.model.chain import Chain
from tmr.model.diffdrive import RobotModel
from tmr.model.params import (
    MAX_STEPS,
    WINCH_FIELDS,
    ChainParams,
    PathParams,
    PinvParams,
    QPParams,
    TaskParams,
    TimeParams,
    apply_overrides,
    as_dict,
    refuse_method_limits,
    with_winch_defaults,
)
from tmr.model.spans import span_limits
from tmr.route.path import Trajectory, leader_trajectory, path_length, plan_leader_path, time_law
from tmr.route.references import CATCH_UP, ChainReference, chain_reference, start_placement
from tmr.route.route import Route, TooFewRobotsError, check_fit, plan_route
from tmr.world.environment import refuse_impassable_low_obstacles, refuse_low_obstacles
from tmr.world.scenario import Scenario

if TYPE_CHECKING:  # the formulations import their solvers (osqp, qpsolvers): loaded by the method that runs
    from tmr.control.pinv import PinvController
    from tmr.control.qp import Level, LexicographicQP

Array = NDArray[np.float64]

METHODS = ("pinv", "qp", "horizon")
_LOG = logging.getLogger("tmr")

#: Leader routes: ``shortest`` — the tether-aware shortest route with references for every robot (default);
#: ``rrt`` — the paper's RRT* leader path with the fixed 15 s time law (Caruso 2021 §4.2), for the faithful comparison.
ROUTES = ("shortest", "rrt")


@dataclass
class Problem:
    """Everything a formulation needs, built once from a scenario (see :func:`build_problem`)."""

    scenario: Scenario
    chain: Chain
    chain_params: ChainParams
    time_params: TimeParams
    path_params: PathParams
    task_params: TaskParams
    pinv_params: PinvParams
    qp_params: QPParams
    span_limits: Array  # (N, 2) [d_lo, d_max] [m]
    q0: Array
    trajectory: Trajectory
    seed: int
    route: Route | None = None
    references: ChainReference | None = None
    route_mode: str = "rrt"
    fixed_duration: bool = False  # T_end was set by the user (the train references cannot keep it)
    robot_model: RobotModel | None = None  # drive = "diff": the robots' model (tmr.model.diffdrive)
    #: drive = "diff" with a goal heading: the leader's final heading [rad] and the state at which its route ends
    #: (the final manoeuvre, :class:`tmr.control.diffdrive.GoalHeading`, follows it)
    goal_heading: float | None = None
    goal_arrive: int | None = None

    @property
    def env(self) -> Any:
        return self.scenario.environment

    def params_dict(self) -> dict[str, Any]:
        out = as_dict(
            self.chain_params, self.time_params, self.path_params, self.task_params, self.pinv_params, self.qp_params
        )
        if not getattr(self.env, "low_obstacles", ()):  # only a world with low obstacles uses it: other plans' bytes
            out.pop("low_obstacle_clearance", None)
        out.update(seed=self.seed, n_robots=self.chain.n_robots, d_max=float(self.span_limits[0, 1]))
        out.update(route=self.route_mode, T_end=float(self.trajectory.t[-1]))
        if self.route is not None:
            out.update(route_length=self.route.length, n_min=self.route.n_min, n_lower=self.route.n_lower)
        if self.robot_model is not None:  # differential drive only: an omnidirectional plan's records keep their bytes
            from tmr.model.diffdrive import DEFAULT_MODEL, canonical_model_name

            # the preset's full name (the default one too, or a short name from a scenario file), or the file
            out.update(robot_model=canonical_model_name(out.get("robot_model") or DEFAULT_MODEL))
            out.update(robot_model_params=self.robot_model.record())
        if self.goal_heading is not None:  # only with --goal X,Y,THETA: other plans' records keep their bytes
            out.update(goal_heading=self.goal_heading, goal_arrive_time=float(self.trajectory.t[self.goal_arrive]))
        return out


def default_start(
    chain: Chain,
    env: Any,
    goal: Array,
    limits: Array,
    margin: float = 0.2,
    *,
    clear: float = 0.05,
    seed: int = 0,
    iterations: int = 1000,
    path_clearance: float = 0.6,
) -> Array:
    """A feasible initial placement near the base, with the chain already pointing the way the leader will go.

    Robots are evenly spaced by the largest ``d_lo`` plus ``margin`` along the RRT* path (``path_clearance`` from the
    obstacles where possible) from the anchor to the goal, so the chain does not have to turn round at the start; if
    that path is too short or a tether chord is not free,
    along the free straight ray from the anchor whose heading is closest to the goal direction (72 headings tried).
    Robots and tethers must be free by ``clear`` [m]. ``ScenarioError`` if no placement is found.
    """
    W = _anchor_path(env, chain.base, goal, seed=seed, iterations=iterations, clearance=path_clearance)
    return _start_from_path(chain, env, goal, limits, W, margin, clear)[0]


def _anchor_path(env: Any, base: Array, goal: Array, *, seed: int, iterations: int, clearance: float) -> Array | None:
    """The RRT* path from the anchor to the goal (:func:`tmr.route.path.plan_leader_path`), or None if it finds none."""
    try:
        return plan_leader_path(env, base, goal, seed=seed, iterations=iterations, clearance=clearance)
    except PathError:
        return None


def _start_from_path(
    chain: Chain, env: Any, goal: Array, limits: Array, W: Array | None, margin: float = 0.2, clear: float = 0.05
) -> tuple[Array, float | None]:
    """:func:`default_start` on an anchor→goal path ``W`` already planned (None: there is none).

    Returns the placement and the arc length [m] of the leader's position along ``W`` (None if the robots were
    placed on a straight ray instead, off the path).
    """
    spacing = limits[:, 0].max() + margin
    offsets = np.arange(1, chain.n_robots + 1) * spacing

    def free(P: Array) -> bool:
        starts = np.vstack([chain.base, P[:-1]])
        chords = getattr(env, "tether_environment", env).segment_clearance(starts, P)  # over low obstacles too
        return bool(np.all(env.exact_clearance(P) > clear) and np.all(chords > clear))

    if W is not None:
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(W, axis=0), axis=1))]
        if arc[-1] > offsets[-1] + spacing:  # leave the leader some path to follow
            P = np.column_stack([np.interp(offsets, arc, W[:, 0]), np.interp(offsets, arc, W[:, 1])])
            if free(P):
                return P, float(offsets[-1])
    to_goal = np.arctan2(goal[1] - chain.base[1], goal[0] - chain.base[0])
    steps = np.arange(72) * (2 * np.pi / 72)
    headings = to_goal + np.where(np.arange(72) % 2 == 0, 1, -1) * steps[(np.arange(72) + 1) // 2]
    for h in headings:
        P = chain.base + offsets[:, None] * np.array([np.cos(h), np.sin(h)])
        if free(P):
            return P, None
    raise ScenarioError(
        "no free placement of the robots near the base was found; give the start positions explicitly "
        "(scenario 'start' or --start)"
    )


def _path_tail(W: Array, at: float) -> Array:
    """The part of the polyline ``W`` (M, 2) [m] beyond arc length ``at`` [m], starting at the point at ``at``."""
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(W, axis=0), axis=1))]
    first = np.array([np.interp(at, arc, W[:, 0]), np.interp(at, arc, W[:, 1])])
    rest = W[arc > at + 1e-9]
    return np.vstack([first, rest])


def build_problem(
    scenario: Scenario,
    *,
    seed: int = 0,
    n_robots: int | None = None,
    start: ArrayLike | None = None,
    overrides: dict[str, Any] | None = None,
    path_iterations: int | None = None,
    route: str = "shortest",
    known_route: Route | None = None,
) -> Problem:
    """Assemble route, chain, limits, start configuration and references for ``scenario``.

    Args:
        scenario: loaded scenario; its ``params`` table overrides parameter defaults by field name.
        seed: seed of the leader's RRT* (same seed → same plan, byte for byte).
        n_robots: override the scenario's number of robots (then the start placement is recomputed).
        start: (N, 2) robot positions overriding the scenario's.
        overrides: extra parameter overrides (after the scenario's).
        path_iterations: RRT* iterations (overrides ``PathParams.path_iterations``).
        route: ``"shortest"`` (default): the leader follows the shortest free route, its duration from the route
            length and ``leader_speed``/``leader_accel`` unless ``T_end`` is set, and every follower gets a route
            reference; ``"rrt"``: the paper's RRT* leader path over ``T_end`` (15 s).
        known_route: the route of this anchor and goal with the same span limits, already computed (the command
            line computes it before importing the planner); None: computed here.

    Raises:
        NoRouteError: the goal is not connected to the anchor through free space.
        TooFewRobotsError: N < the robots the route needs (checked before any motion planning).
        TooManyRobotsError: N robots do not fit in the free space at once (:func:`tmr.route.route.check_fit`).
    """
    if route not in ROUTES:
        raise ParameterError(f"unknown route {route!r}; available: {', '.join(ROUTES)}")
    values = dict(scenario.params or {})
    values.update(overrides or {})
    r_env = scenario.environment.safety_radius  # one robot radius: the obstacles' growth is the chain's r
    if "safety_radius" not in values:
        values["safety_radius"] = r_env
    elif not float(values["safety_radius"]) == r_env:
        raise ParameterError(
            f"safety_radius = {values['safety_radius']} m, but the environment's obstacles are grown by {r_env:g} m; "
            "use one robot radius (e.g. Environment.with_safety_radius, or load the scenario with it)"
        )
    values = with_winch_defaults(values)[0]
    chain_params, rest = apply_overrides(ChainParams(), values)
    top = max(chain_params.exit_height, chain_params.base_height)
    refuse_impassable_low_obstacles(scenario.environment, top, chain_params.low_obstacle_clearance)
    idle = sorted(k for k in (*WINCH_FIELDS[1:], "sag_allowance") if k in values and not chain_params.active_winch)
    if idle:  # a range or rate of a winch that does not use them: refused, not silently dropped
        raise ParameterError(f"{', '.join(idle)} set but winch = {chain_params.winch!r}: add winch = 'active'")
    time_params, rest = apply_overrides(TimeParams(), rest)
    path_params, rest = apply_overrides(PathParams(), rest)
    task_params, rest = apply_overrides(TaskParams(), rest)
    pinv_params, rest = apply_overrides(PinvParams(), rest)
    qp_params, rest = apply_overrides(QPParams(), rest)
    if rest:
        raise ScenarioError(f"unknown parameter(s) {sorted(rest)} in scenario {scenario.name!r}")
    if path_iterations is not None:
        path_params = replace(path_params, path_iterations=int(path_iterations))
    robot_model = None
    if chain_params.diff_drive:
        robot_model, path_params = _diff_drive_setup(chain_params, path_params)
    elif scenario.goal_heading is not None:
        raise ParameterError("a goal heading needs --drive diff (an omnidirectional robot has no heading)")
    N = int(n_robots if n_robots is not None else scenario.n_robots)
    if start is not None:  # before the route: a start never changes N by itself
        try:
            start = np.asarray(start, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"start must be {N} (x, y) positions [m], got {start!r}") from None
        k = len(np.atleast_2d(start))
        if start.shape != (N, 2):
            raise ScenarioError(
                f"start lists {k} position{'s' if k != 1 else ''} for {N} robots: give one (x, y) per robot, or "
                f"n_robots={k}"
                if start.ndim == 2 and start.shape[1] == 2
                else f"start must be {N} (x, y) positions [m], got shape {start.shape}"
            )
    env = scenario.environment
    check_fit(env, scenario.base, N)  # before anything sized by N: n_robots=10**23 is refused, not a MemoryError
    chain = Chain(N, base=scenario.base)
    limits = span_limits(N, chain_params)
    goal = np.asarray(scenario.goal, float)
    rt = known_route if known_route is not None else plan_route(env, scenario.base, goal, limits, robots=N)
    why = rt.refusal(N)
    # N_min is a verdict of the route-guided search; only the proven bound binds other routes and given starts
    if why is not None and (N < rt.n_lower or (route == "shortest" and start is None)):
        raise TooFewRobotsError(why, rt.n_min, proven=N < rt.n_lower)
    parked = 0
    anchor_path: Array | None = None
    leader_at: float | None = None
    given = start is not None or (scenario.start is not None and n_robots in (None, scenario.n_robots))
    if start is not None:
        P = np.asarray(start, dtype=float)
    elif scenario.start is not None and n_robots in (None, scenario.n_robots):
        P = np.asarray(scenario.start, dtype=float)
    elif route == "shortest":
        spacing = limits[:, 0].max() + 0.2
        P, parked = start_placement(env, rt, N, spacing, span_limits=limits)
    else:  # the paper's RRT*, planned once: the start placement and the leader's path share it (issue 14)
        anchor_path = _anchor_path(
            env,
            chain.base,
            goal,
            seed=seed,
            iterations=path_params.path_iterations,
            clearance=path_params.path_clearance,
        )
        P, leader_at = _start_from_path(chain, env, goal, limits, anchor_path)
    if P.shape != (N, 2) or not np.all(np.isfinite(P)):
        raise ScenarioError(f"start must be {N} finite (x, y) positions, got shape {P.shape}")
    clear = env.exact_clearance(P)
    if np.any(clear <= 0):
        k = int(np.argmin(clear))
        raise ScenarioError(
            f"start position of robot {k + 1} {fmt_point(P[k])} is inside an (inflated) obstacle "
            f"(clearance {clear[k]:.3f} m)"
        )
    if given:
        _check_given_start(P, np.asarray(scenario.base, float), limits, float(env.safety_radius))
    q0 = chain.q_from_positions(P)
    ref: ChainReference | None = None
    if route == "shortest":
        ref = chain_reference(
            env,
            rt,
            P,
            limits,
            parked=parked,
            T_end=time_params.T_end if "T_end" in values else None,
            Ts=time_params.Ts,
            speed=path_params.leader_speed,
            accel=path_params.leader_accel,
            spacing=limits[:, 0].max() + 0.2,
            settle=0.0 if "T_end" in values else path_params.route_settle,
            catch_up=_catch_up(path_params, robot_model),
        )
        traj = ref.trajectory
        time_params = replace(time_params, T_end=float(traj.t[-1]))
    else:
        traj = along = None
        if anchor_path is not None and leader_at is not None:  # the leader is on the anchor's path: follow its tail
            along = _path_tail(anchor_path, leader_at)
            traj = _trajectory_along(env, along, time_params, path_params)
            along = along if traj is not None else None
        if traj is None:
            traj = _rrt_trajectory(env, P[-1], goal, seed, time_params, path_params)
        if robot_model is not None:  # the paper's 15 s are an omnidirectional robot's: slowed to the robot's reach

            def rebuild(tp: TimeParams) -> Trajectory | None:  # the same path as above, over tp.T_end
                if along is not None:
                    return _trajectory_along(env, along, tp, path_params)
                try:
                    return _rrt_trajectory(env, P[-1], goal, seed, tp, path_params)
                except PathError:
                    return None

            traj = _within_robot_reach(traj, time_params, path_params, robot_model, "T_end" in values, rebuild)
            time_params = replace(time_params, T_end=float(traj.t[-1]))
    problem = Problem(
        scenario,
        chain,
        chain_params,
        time_params,
        path_params,
        task_params,
        pinv_params,
        qp_params,
        limits,
        q0,
        traj,
        int(seed),
        route=rt,
        references=ref,
        route_mode=route,
        fixed_duration="T_end" in values,
        robot_model=robot_model,
    )
    return _with_goal_heading(problem)


#: Time [s] the leader's reference holds the goal pose after the longest goal-heading manoeuvre (the CLIK settles).
GOAL_HEADING_SETTLE = 1.0


def goal_heading_manoeuvre(problem: Problem) -> Any:
    """The leader's final manoeuvre (:class:`tmr.control.diffdrive.GoalHeading`) of a problem with a goal heading,
    at the leader time law's fractions of the robot's limits (:data:`DIFF_SPEED_FRACTION`, :data:`DIFF_ACCEL_FRACTION`
    of v_max, ω_max and a_max, α_max); None without one."""
    from tmr.control.diffdrive import GoalHeading

    m = problem.robot_model
    if problem.goal_heading is None or m is None:
        return None
    k = problem.goal_arrive if problem.goal_arrive is not None else problem.trajectory.t.size - 1
    return GoalHeading(
        problem.goal_heading,
        np.asarray(problem.trajectory.x, dtype=float)[k],
        k,
        m.exit_offset,
        DIFF_SPEED_FRACTION * m.v_max,
        DIFF_ACCEL_FRACTION * m.a_max,
        DIFF_SPEED_FRACTION * m.omega_max,
        DIFF_ACCEL_FRACTION * m.alpha_max,
    )


def _with_goal_heading(problem: Problem) -> Problem:
    """``problem`` with its leader's reference (and every route reference) held at the route's end for the longest
    goal-heading manoeuvre plus :data:`GOAL_HEADING_SETTLE` (``goal_arrive`` = the route's last state); as is without
    a goal heading."""
    heading = problem.scenario.goal_heading
    if heading is None or problem.robot_model is None:
        return problem
    problem = replace(problem, goal_heading=float(heading), goal_arrive=None)
    tr = problem.trajectory
    Ts = problem.time_params.Ts
    K = tr.t.size - 1
    man = goal_heading_manoeuvre(problem)
    M = int(math.ceil((man.budget() + GOAL_HEADING_SETTLE) / Ts - 1e-9))

    def hold(a: Array, zero: bool) -> Array:
        a = np.asarray(a, dtype=float)
        last = np.zeros_like(a[-1:]) if zero else a[-1:]
        return np.concatenate([a, np.repeat(last, M, axis=0)])

    t = np.concatenate([tr.t, tr.t[-1] + Ts * np.arange(1, M + 1)])
    traj = tr._replace(t=t, x=hold(tr.x, False), xd=hold(tr.xd, True), xdd=hold(tr.xdd, True))
    ref = problem.references
    if ref is not None:
        ref = replace(ref, trajectory=traj, positions=hold(ref.positions, False), velocities=hold(ref.velocities, True))
    return replace(
        problem,
        trajectory=traj,
        references=ref,
        time_params=replace(problem.time_params, T_end=float(t[-1])),
        goal_arrive=K,
    )


#: With differential drive the leader's time law is capped at these fractions of the robot's v_max and a_max: the
#: rest is the CLIK correction's room (Caruso 2021 eq. 20) and the heading's turns (``formulations/diffdrive.md``).
DIFF_SPEED_FRACTION = 0.6
DIFF_ACCEL_FRACTION = 0.5


def _catch_up(path_params: PathParams, model: RobotModel | None) -> float:
    """The followers' catch-up speed [m/s]: ``PathParams.catch_up`` if set, else :data:`CATCH_UP` (omnidirectional)
    or :func:`diff_catch_up` (differential drive)."""
    if path_params.catch_up is not None:
        return float(path_params.catch_up)
    return CATCH_UP if model is None else diff_catch_up(model)


def diff_catch_up(model: RobotModel) -> float:
    """The fastest rise [m/s] of a differential-drive follower's trailing reference at a corner
    (:func:`tmr.route.references.chain_reference` ``catch_up``; :data:`~tmr.route.references.CATCH_UP` = 1.2 m/s for
    omnidirectional robots): the straight-line speed the wheels' rim rows leave, (1 −
    :data:`tmr.control.diffdrive.WHEEL_RESERVE`) v_max. References rising at 1.2 m/s ran away from Burgers
    (0.198 m/s): their chain was pulled taut and the leader stalled (``formulations/diffdrive.md``)."""
    from tmr.control.diffdrive import WHEEL_RESERVE

    return min(CATCH_UP, (1.0 - WHEEL_RESERVE) * model.v_max)


def _diff_drive_setup(chain_params: ChainParams, path_params: PathParams) -> tuple[RobotModel, PathParams]:
    """The robot model of ``drive = "diff"`` (:func:`tmr.model.diffdrive.load_robot_model`) and the path parameters
    with the leader's speed and acceleration within the robot's reach (:data:`DIFF_SPEED_FRACTION`,
    :data:`DIFF_ACCEL_FRACTION`). Refuses (ParameterError, exit 2) a footprint that the safety disc round the exit
    point does not hold (b + r_f > r)."""
    from tmr.model.diffdrive import model_for

    model = model_for(chain_params.robot_model, chain_params.safety_radius)
    return model, diff_leader_law(path_params, model)


def diff_leader_law(path_params: PathParams, model: RobotModel) -> PathParams:
    """``path_params`` with the leader's speed [m/s] and acceleration [m/s²] capped at :data:`DIFF_SPEED_FRACTION`
    of the robot's v_max and :data:`DIFF_ACCEL_FRACTION` of its a_max (the time law of ``drive = "diff"``)."""
    return replace(
        path_params,
        leader_speed=min(path_params.leader_speed, DIFF_SPEED_FRACTION * model.v_max),
        leader_accel=min(path_params.leader_accel, DIFF_ACCEL_FRACTION * model.a_max),
    )


def initial_headings(problem: Problem) -> Array:
    """Every robot's heading θ_0 [rad] at the start of a differential-drive plan: along the first motion of its
    reference (the leader's trajectory; a follower's route reference), else along its tether from the previous
    robot (the anchor for robot 1): the chain pays out away from the anchor."""
    chain = problem.chain
    P = chain.points(problem.q0) if not chain.spatial else None
    assert P is not None
    N = chain.n_robots
    out = np.empty(N)
    refs: list[Array | None] = [None] * N
    if problem.references is not None:
        for i in range(N):
            refs[i] = np.asarray(problem.references.velocities, dtype=float)[:, i, :]
    refs[-1] = np.asarray(problem.trajectory.xd, dtype=float)[:, :2]
    for i in range(N):
        link = P[i + 1] - P[i]
        out[i] = math.atan2(link[1], link[0])
        V = refs[i]
        if V is not None:
            moving = np.flatnonzero(np.linalg.norm(V, axis=1) > 1e-9)
            if moving.size:
                out[i] = math.atan2(V[moving[0], 1], V[moving[0], 0])
    return out


def _trajectory_along(
    env: Any, waypoints: Array, time_params: TimeParams, path_params: PathParams
) -> Trajectory | None:
    """The leader's B-spline time law over T_end (Caruso 2021 §4.2) along ``waypoints`` already planned, with the
    spline clearance :func:`tmr.route.path.leader_trajectory` uses; None if the path is too short or no spline through
    it
    keeps that clearance (the caller then plans the leader's own RRT* path)."""
    if len(waypoints) < 2 or path_length(waypoints) <= 1e-9:
        return None
    kept = float(np.min(env.segment_clearance(waypoints[:-1], waypoints[1:])))
    spline_clearance = max(0.0, 0.5 * min(float(path_params.path_clearance), kept))
    try:
        return time_law(waypoints, T_end=time_params.T_end, Ts=time_params.Ts, env=env, clearance=spline_clearance)
    except (PathError, ParameterError):
        return None


def _within_robot_reach(
    traj: Trajectory,
    time_params: TimeParams,
    path_params: PathParams,
    model: Any,
    user_T: bool,
    rebuild: Callable[[TimeParams], Trajectory | None],
) -> Trajectory:
    """``--route rrt`` with differential drive: the leader's B-spline time law over the paper's T_end (15 s) retimed
    to the longest of T_end, the time that keeps its peak speed ≤ ``leader_speed`` and the one that keeps its peak
    acceleration ≤ ``leader_accel`` (both capped for the robot, :func:`diff_leader_law`; speed scales as 1/T,
    acceleration as 1/T²), rounded up to whole steps. ``rebuild(time_params)`` builds the same path and spline again
    over the new T_end (the same inputs and seed: only the time law changes). A T_end the user set is kept, unless
    its peak speed is above the robot's v_max; a retimed motion longer than ``MAX_STEPS`` is refused (both
    ParameterError, exit 2)."""
    T, Ts = float(traj.t[-1]), time_params.Ts
    v_peak = float(np.max(np.linalg.norm(traj.xd, axis=1), initial=0.0))
    a_peak = float(np.max(np.linalg.norm(traj.xdd, axis=1), initial=0.0))
    if user_T:
        if v_peak > model.v_max:
            need = T * v_peak / model.v_max
            raise ParameterError(
                f"T_end = {T:g} s asks the leader for {v_peak:.3g} m/s along its path, above the robot's v_max "
                f"{model.v_max:g} m/s ({model.name}): give T_end ≥ {need:.4g} s, or leave T_end out (it is then "
                "chosen from the robot's speed)"
            )
        return traj
    scale = max(1.0, v_peak / path_params.leader_speed, math.sqrt(a_peak / path_params.leader_accel))
    if scale <= 1.0:
        return traj
    steps = math.ceil(T * scale / Ts - 1e-9)
    if steps > MAX_STEPS:
        raise ParameterError(
            f"the leader's motion at {path_params.leader_speed:.3g} m/s would take {steps * Ts:.6g} s, {steps:,} "
            f"steps of Ts = {Ts:g} s: above the planner's limit of {MAX_STEPS:,} steps (tmr.model.params.MAX_STEPS); "
            "a faster leader (leader_speed, or a robot model's v_max) or a shorter route"
        )
    slow = rebuild(replace(time_params, T_end=steps * Ts))
    if slow is None:  # not expected: the same inputs built the 15 s law
        _LOG.warning(
            "--route rrt: the leader's path could not be retimed to %.4g s for %s; it keeps %.4g s (peak %.3g m/s)",
            steps * Ts,
            model.name,
            T,
            v_peak,
        )
        return traj
    return slow


def _rrt_trajectory(
    env: Any, start: Array, goal: Array, seed: int, time_params: TimeParams, path_params: PathParams
) -> Trajectory:
    """The paper's leader: RRT* path and B-spline time law over T_end (Caruso 2021 §4.2), with the path margins of
    ``path_params.clearances`` tried in turn."""
    for clearance in path_params.clearances:
        try:
            return leader_trajectory(
                env,
                start,
                goal,
                seed=seed,
                T_end=time_params.T_end,
                Ts=time_params.Ts,
                iterations=path_params.path_iterations,
                clearance=clearance,
            )
        except PathError:
            if clearance == path_params.clearances[-1]:
                raise
    raise AssertionError("unreachable: the last clearance re-raises")  # pragma: no cover


def _check_given_start(P: Array, base: Array, limits: Array, r: float) -> None:
    """A start given by the user breaks no span or separation limit at t = 0 (else nothing could be planned from
    it): every tether in [d_lo, d_max], robots at least 2r apart. ScenarioError naming the first one that does."""
    spans = np.linalg.norm(np.diff(np.vstack([base, P]), axis=0), axis=1)
    for k, (d, (lo, hi)) in enumerate(zip(spans, limits, strict=True)):
        if not lo - 1e-9 <= d <= hi + 1e-9:
            ends = "the base" if k == 0 else f"robot {k}"
            raise ScenarioError(
                f"start: the tether from {ends} to robot {k + 1} spans {d:.3f} m, outside its limits "
                f"[{lo:.3f}, {hi:.3f}] m (d_lo, d_max)"
            )
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    i, j = np.triu_indices(len(P), 1)
    if len(i) and float(D[i, j].min()) < 2 * r - 1e-9:
        m = int(np.argmin(D[i, j]))
        raise ScenarioError(
            f"start: robots {i[m] + 1} and {j[m] + 1} are {D[i[m], j[m]]:.3f} m apart, nearer than 2r = {2 * r:g} m"
        )


def make_tasks(problem: Problem) -> tuple[LeaderTracking, TetherRegulation]:
    """The tasks every formulation shares: leader tracking (eq. 20) and tether regulation (eq. 13, 23)."""
    p = problem.task_params
    leader = LeaderTracking(p.clik_gain)
    tether = TetherRegulation(
        problem.chain,
        problem.span_limits,
        p.span_target_fraction,
        p.gain_floor,
        p.gain_edge,
        p.gain_length,
        max_gain=1.0 / problem.time_params.Ts,
    )
    return leader, tether


def make_pinv(problem: Problem, extra_tasks: tuple[Task, ...] = ()) -> PinvController:
    """The faithful baseline controller with the problem's parameters (Caruso 2021 §4).

    ``extra_tasks`` are appended to the priority stack after the obstacle task (eq. 5), highest first.
    """
    from tmr.control.pinv import PinvController

    p = problem.pinv_params
    leader, tether = make_tasks(problem)
    return PinvController(
        leader=leader,
        tether=tether,
        obstacle=ObstacleEvasion(
            p.d_min, p.k_v0, p.hysteresis, p.min_evasion_distance, problem.chain_params.safety_radius
        ),
        damping=p.dls_damping,
        extra=tuple(extra_tasks),
    )


def make_qp(
    problem: Problem, extra_limits: tuple[Limit, ...] = (), extra_levels: tuple[Level, ...] = ()
) -> LexicographicQP:
    """The lexicographic QP with hard clearance, span, separation and speed limits (``formulations/qp.md``).

    ``extra_limits`` are added to the hard limits of every level; ``extra_levels`` are inserted after the leader
    level (so they outrank tether regulation and energy), highest first. Train references (:mod:`tmr.route.train`, every
    state checked) are tracked in a level of their own after those; trailing ones are a task of the tether level.
    """
    from tmr.control.qp import Level, LexicographicQP

    p, chain = problem.qp_params, problem.chain
    leader, tether = make_tasks(problem)
    tether_tasks: list[tuple[Task, float]] = [
        (tether, 1.0),
        (SpanUniformity(chain, p.uniformity_gain), 1.0),
        (Smoothness(chain), p.tether_smoothness),
    ]
    ref = problem.references
    route_levels: list[Level] = []
    if ref is not None and chain.n_robots > 1:
        follow = RouteFollowers(ref.positions, ref.velocities, problem.path_params.route_gain)
        if ref.mode == "train":  # checked references: tracked first
            route_levels.append(Level([(follow, 1.0)], "route"))
        elif problem.path_params.route_weight > 0:
            tether_tasks.append((follow, problem.path_params.route_weight))
    levels = [
        Level([(leader, 1.0)], "leader"),
        *extra_levels,
        *route_levels,
        Level(tether_tasks, "tethers"),
        Level([(Damping(chain), p.energy_weight), (Smoothness(chain), p.smoothness_weight)], "energy"),
    ]
    limits: list[Limit] = [
        ObstacleClearance(
            chain,
            problem.task_params.samples_per_link,
            p.d_safe,
            p.clearance_rows_per_link,
            p.clearance_activation,
            p.approach_rate,
        ),
        RobotSpeed(chain, p.robot_speed_max),
        RobotAcceleration(chain, p.robot_accel_max),
    ]
    if chain.n_robots > 1:
        limits.append(
            RobotSeparation(
                chain,
                problem.chain_params.safety_radius,
                p.separation_margin,
                p.separation_neighbours,
                approach_rate=p.approach_rate,
            )
        )
    low = tuple(getattr(problem.env, "low_obstacles", ()))
    if low:  # tethers may pass over a low obstacle, high enough (tmr.control.cable)
        from tmr.control.cable import CableOverLowObstacles

        cp = problem.chain_params
        reach = float(np.max(problem.span_limits[:, 1]))
        limits.append(CableOverLowObstacles(chain, problem.env, cp, cp.low_obstacle_clearance, p.approach_rate, reach))
    limits.extend(extra_limits)
    model = getattr(problem, "robot_model", None)
    brake = None
    if model is not None:  # diff drive: the spans reach their band at a rate the robots can brake
        from tmr.control.diffdrive import span_brake

        brake = span_brake(model)
    box = JointBox(
        chain, problem.span_limits, p.joint_speed_max, p.span_speed_max, p.accel_max, p.span_margin,
        p.span_approach_rate, brake,
    )  # fmt: skip
    if model is not None:  # diff drive: v, ω rows, poses (tmr.control.diffdrive)
        from tmr.control.diffdrive import DiffDriveAcceleration, DiffDriveSpeed, make_diffdrive_qp

        limits += [DiffDriveSpeed(problem.robot_model), DiffDriveAcceleration(problem.robot_model)]
        if problem.chain_params.active_winch:  # x = [v, Ṫ], the v/ω rows padded like every limit
            from tmr.control.winch import make_winch_qp

            inner: Any = make_winch_qp(
                chain, levels, limits, box, problem.chain_params, p.span_margin, p.solver, p.span_approach_rate
            )
        else:
            inner = LexicographicQP(chain, levels, limits, box, solver=p.solver)
        return make_diffdrive_qp(  # type: ignore[return-value]
            inner, chain, problem.robot_model, initial_headings(problem), goal_heading_manoeuvre(problem)
        )
    if problem.chain_params.active_winch:  # x = [v, Ṫ] (tmr.control.winch)
        from tmr.control.winch import make_winch_qp

        return make_winch_qp(
            chain, levels, limits, box, problem.chain_params, p.span_margin, p.solver, p.span_approach_rate
        )  # type: ignore[return-value]
    return LexicographicQP(chain, levels, limits, box, solver=p.solver)


def formulation(problem: Problem, method: str | Formulation) -> Formulation:
    """The formulation object for ``method``: ``"pinv"``, ``"qp"``, or a formulation object (returned as is)."""
    if getattr(problem, "robot_model", None) is not None and method == "pinv":
        raise ParameterError("drive = 'diff' is planned by --method qp and horizon (not --method pinv)")
    if method == "pinv":
        refuse_method_limits("pinv", problem.chain_params, problem.qp_params)
        return make_pinv(problem)
    if method == "qp":
        return make_qp(problem)
    if isinstance(method, str):
        raise ParameterError(f"unknown method {method!r}; available: {', '.join(METHODS)}")
    return method


def plan(problem: Problem, method: str | Formulation = "pinv", *, progress: bool = False) -> Plan:
    """Run ``method`` along the problem's leader trajectory (:func:`tmr.control.clik.run`); the plan is not checked yet.
    ``progress``: a bar of the steps on stderr once the run takes 2 s. With an active winch the plan's
    ``winch_tension`` holds every tether's planned horizontal tension per state."""
    form = formulation(problem, method)
    result = run(
        problem.chain,
        problem.env,
        problem.trajectory,
        form,
        problem.q0,
        span_limits=problem.span_limits,
        safety_radius=problem.chain_params.safety_radius,
        samples_per_link=problem.task_params.samples_per_link,
        scenario=problem.scenario.name,
        params=problem.params_dict(),
        goal=np.asarray(problem.scenario.goal, float),
        progress=progress,
    )
    tensions = getattr(form, "tensions", None)
    if tensions is not None:
        result.winch_tension = tensions(result.t.size)
    poses = getattr(form, "poses", None)
    if poses is not None:  # differential drive: axle centres, headings, v, ω per state
        result.axle, result.heading, result.drive_v, result.drive_omega = poses(result.t.size)
    gh = getattr(form, "goal_heading", None)
    if gh is not None and gh.reference:  # the leader's reference of the final manoeuvre, as tracked
        for k, x_d in gh.reference.items():
            if k < result.t.size:
                result.reference[k] = x_d
        if result.t.size - 1 > gh.k_arrive:
            result.reference[-1] = gh.at((result.t.size - 1 - gh.k_arrive) * problem.time_params.Ts)[0]
    for lim in getattr(getattr(form, "qp", form), "limits", ()):
        note = lim.note() if hasattr(lim, "note") else None
        if note:  # what held the chain at the end (a leader that stops short says why)
            result.diagnostics["held_by"] = note
    return result


@dataclass(frozen=True)
class QPRun:
    """The plan ``--method qp`` returns for a problem (:func:`qp_run`): the problem it was made for (``source``), the
    problem it was planned on (``problem``: the train references' if the trailing ones failed), the plan, its metrics
    and the run's wall time [s]. For one ``solve(source, "horizon", qp=...)``: that call may change the plan in place
    (it is the plan returned when the NLP finds none better)."""

    source: Problem
    problem: Problem
    plan: Plan
    metrics: Metrics
    seconds: float


def _refuse_for_horizon(problem: Problem) -> None:
    """What ``--method horizon`` refuses before its ``qp`` warm start (ParameterError): low obstacles, a passive
    winch's pay-out damper."""
    refuse_low_obstacles(problem.env, "--method horizon", "its NLP keeps no cable height above them; use --method qp")
    refuse_method_limits("horizon", problem.chain_params, problem.qp_params)


def qp_run(problem: Problem, *, progress: bool = False) -> QPRun:
    """The horizon NLP's warm start: the plan ``solve(problem, "qp")`` returns (trailing references, then train
    references if those fail; its ``wall_time`` the last loop's, the whole run's in ``seconds``), kept with the problem
    it was planned on, so that ``solve(problem, "horizon", qp=...)`` starts from it without planning it again
    (``--robots auto`` chooses N by it). What ``solve(problem, "horizon")`` refuses is refused first, before the plan
    (ParameterError)."""
    _refuse_for_horizon(problem)
    start = time.perf_counter()
    used, result, metrics = _solve_qp(problem, progress)
    return QPRun(problem, used, result, metrics, time.perf_counter() - start)


def solve(
    problem: Problem,
    method: str | Formulation = "qp",
    *,
    time_limit: float | None = None,
    progress: bool = False,
    qp: QPRun | None = None,
) -> tuple[Plan, Metrics]:
    """Plan with ``method`` and check every hard constraint on the recorded states.

    Args:
        problem: from :func:`build_problem`.
        method: ``"pinv"``, ``"qp"``, ``"horizon"`` (the whole-horizon NLP of ``formulations/horizon.md``, warm
            started from the ``qp`` plan), or any per-step formulation object with ``name``, ``reset()`` and
            ``step(ctx)`` (e.g. ``make_qp(problem, extra_limits=...)`` or your own).
        time_limit: wall-clock limit of the horizon NLP [s] (None: its default); progress: progress bars (the
            steps, once they take 2 s; the horizon NLP's iterations).
        qp: for ``"horizon"`` only: its ``qp`` warm start, already made for this very problem by :func:`qp_run` (not
            planned again; its seconds count in the plan's ``wall_time`` and ``qp_time``; ParameterError if it was
            made for another problem).

    Returns the plan (``success`` False with the reason if a constraint is violated anywhere) and its metrics. The
    horizon NLP starts from the very plan ``solve(problem, "qp")`` returns (trailing or train references, whichever
    it used) and is never worse than it, in each of f1–f4 (rows of the NLP): if IPOPT fails, it is the best feasible
    iterate or the ``qp`` plan itself (``diagnostics["horizon_result"]`` says which); a horizon plan that fails the
    exact check (:func:`check`: the NLP keeps the spline field's clearance at sampled tether points) is replaced by the
    ``qp`` plan if that one passes (``horizon_summary["stop"]`` "exact_check"); if nothing feasible is found, the
    failed plan names the violated limits.

    The plan's ``wall_time`` (and its metrics' ``wall_time``, ``ms_per_step``) is the whole of this call [s]: every
    qp run (the train-reference retry too), the horizon's warm start and NLP, and the checks;
    ``plan.diagnostics["timings"]`` holds the parts [s]: ``qp_time`` (for ``horizon``: its qp warm start) and
    ``nlp_time`` (``horizon`` only; IPOPT's rounds with their transcription and fallback choice).
    """
    start = time.perf_counter()
    if qp is not None and method != "horizon":
        raise ParameterError(f"qp= is the horizon NLP's warm start: method 'horizon' only, got {method!r}")
    if qp is not None and qp.source is not problem:
        raise ParameterError("qp= was made for another problem: pass qp_run(problem) of this very problem")
    if method == "qp":
        result, metrics = _solve_qp(problem, progress)[1:]
        return _whole(result, metrics, start, qp_time=time.perf_counter() - start)
    if method != "horizon":
        result, metrics = _checked(problem, method, progress)
        return _whole(result, metrics, start)
    # a whole-trajectory NLP, not a per-step formulation
    _refuse_for_horizon(problem)
    from tmr.control.horizon import DEFAULT_TIME_LIMIT, HorizonInfeasible, plan_horizon  # casadi: when used

    if qp is None:
        problem, warm, warm_metrics = _solve_qp(problem, progress)  # the very plan ``--method qp`` returns
    else:  # made by qp_run: its seconds are the start of this call's
        start -= qp.seconds
        problem, warm, warm_metrics = qp.problem, qp.plan, qp.metrics
    qp_done = time.perf_counter()
    limit = DEFAULT_TIME_LIMIT if time_limit is None else time_limit
    try:
        result = plan_horizon(problem, warm, time_limit=limit, progress=progress)
    except HorizonInfeasible as exc:
        parts = dict(qp_time=qp_done - start, nlp_time=time.perf_counter() - qp_done)
        warm.method = "horizon"
        first = str(exc).split(";")[0]
        if warm.success:  # the NLP's own rows are stricter than the checks: the verified warm start stands
            floor = exc.diagnostics.get("horizon_floor_note")  # which IPOPT attempts ran (the fast one, a fallback)
            floor = f"; {floor}" if floor else ""
            warm_metrics = _qp_plan_returned(warm, problem, f"{first}{floor}", exc.diagnostics, exc.status)
            return _whole(warm, warm_metrics, start, **parts)
        warm.success = False
        reason = f"horizon: {exc}"
        warm.failure = reason if warm.failure is None else f"{reason}; its qp warm start: {warm.failure}"
        return _whole(warm, evaluate(warm, problem.env), start, **parts)
    parts = dict(qp_time=qp_done - start, nlp_time=time.perf_counter() - qp_done)
    if problem.chain_params.active_winch:  # the NLP chose the positions within T_max's reach; the least tension here
        from tmr.control.winch import least_tension_schedule

        q = problem.qp_params  # its pay-out damper kept through the tension
        result.winch_tension = least_tension_schedule(
            result.spans, problem.chain_params, result.Ts, q.span_margin, q.span_approach_rate
        )
    metrics = check(result, problem.env, goal_tolerance=problem.path_params.goal_tolerance)
    if not metrics.violation_free and warm.success:  # the NLP's rows held, the exact check did not: the qp plan
        bad = ", ".join(f"{k} at {len(ks)} step(s) from {ks[0]}" for k, ks in metrics.violation_steps.items() if ks)
        d = result.diagnostics
        why = f"horizon NLP: its plan ({d.get('horizon_result')}) fails the exact check ({bad})"
        summary = d.get("horizon_summary", {})  # what the NLP did: its fast attempt, its coarse pass
        diagnostics = dict(
            d,
            horizon_stop="exact_check",
            ipopt_iterations=d.get("ipopt_iterations", summary.get("iterations", 0)),
            horizon_fast_attempt=summary.get("fast_attempt"),
            horizon_coarse=summary.get("coarse"),
        )
        warm.method = "horizon"
        warm_metrics = _qp_plan_returned(warm, problem, why, diagnostics, "exact_check")
        return _whole(warm, warm_metrics, start, **parts)
    return _whole(result, metrics, start, **parts)


def _qp_plan_returned(warm: Plan, problem: Problem, why: str, diagnostics: dict[str, Any], status: str) -> Metrics:
    """The verified ``qp`` plan ``warm`` as the horizon's plan (``horizon_result`` "warm_start"), its note ``why`` and
    "returned its qp warm start", its summary from the NLP's ``diagnostics``; returns its metrics."""
    warm_metrics = evaluate(warm, problem.env)
    terms = {k: float(getattr(warm_metrics, k)) for k in ("f1", "f2", "f3", "f4")}
    warm.diagnostics = dict(warm.diagnostics, horizon_result="warm_start")
    released = diagnostics.get("leader_released")  # the NLP ran with the leader free (tmr.control.horizon)
    if released:
        why = (
            f"{why} (the leader released within {released['tolerance']:.4g} m of its reference, the qp plan's "
            f"largest lag + {1e3 * released['slack']:g} mm)"
        )
    warm.diagnostics["horizon_note"] = f"{why}; returned its qp warm start, which passes every check"
    warm.diagnostics["horizon_summary"] = dict(
        result="warm_start",
        stop=diagnostics.get("horizon_stop", status),
        iterations=int(diagnostics.get("ipopt_iterations", 0)),
        rounds=int(diagnostics.get("rounds", 0)),
        terms=terms,
        warm_start_terms=dict(terms),
        min_hessian_perturbation=None,  # the plan is no IPOPT point
        fast_attempt=diagnostics.get("horizon_fast_attempt"),
    )
    if diagnostics.get("horizon_coarse") is not None:  # long or large horizons: what the coarse pass did
        warm.diagnostics["horizon_summary"]["coarse"] = diagnostics["horizon_coarse"]
    if released:
        warm.diagnostics["horizon_summary"]["leader_released"] = dict(released)
    return warm_metrics


def _whole(result: Plan, metrics: Metrics, start: float, **parts: float) -> tuple[Plan, Metrics]:
    """``result`` and its ``metrics`` with the wall time [s] since ``start`` (:func:`perf_counter
    <time.perf_counter>`) in place of the last loop's; the parts [s] in ``result.diagnostics["timings"]``."""
    wall = time.perf_counter() - start
    result.wall_time = wall
    result.diagnostics["timings"] = {key: float(value) for key, value in parts.items()}
    steps = result.t.size - 1
    return result, replace(metrics, wall_time=wall, ms_per_step=1000.0 * wall / steps if steps > 0 else math.nan)


def _checked(problem: Problem, method: str | Formulation, progress: bool) -> tuple[Plan, Metrics]:
    """:func:`plan` with ``method``, then :func:`check` with the problem's goal tolerance."""
    result = plan(problem, method, progress=progress)
    return result, check(result, problem.env, goal_tolerance=problem.path_params.goal_tolerance)


def train_problem(problem: Problem) -> Problem:
    """``problem`` with train references (:mod:`tmr.route.train`: the robots in turn, every state checked) in place of
    its trailing ones: same route, start and stations; the leader's trajectory and the duration come from the
    train. The train keeps the QP's own limits plus a little (clearance d_safe + 5 mm, separation 2r + margin +
    5 mm, spans ≥ d_lo + span margin). Raises :class:`tmr.route.train.TrainError` if the train stalls."""
    from tmr.route.train import TRAIN_CLEARANCE, TrainError, TrainLimits, train_reference

    if problem.references is None:
        raise ParameterError("train references need a route-guided problem (route='shortest')")
    qp, path = problem.qp_params, problem.path_params
    spans = problem.span_limits.copy()
    spans[:, 0] += qp.span_margin
    limits = TrainLimits(
        spans,
        2 * problem.chain_params.safety_radius + qp.separation_margin + TRAIN_MARGIN,
        max(TRAIN_CLEARANCE, qp.d_safe + TRAIN_MARGIN),
    )
    ref = train_reference(
        problem.env,
        problem.references,
        np.asarray(problem.scenario.base, float),
        limits,
        Ts=problem.time_params.Ts,
        speed=path.leader_speed,
        accel=path.leader_accel,
        settle=path.route_settle,
    )
    T_end = float(ref.trajectory.t[-1])
    steps = round(T_end / problem.time_params.Ts)
    if steps > MAX_STEPS:  # a search verdict (exit 1), not the user's T_end: the train is longer than a plan may be
        raise TrainError(
            f"the train references take {T_end:.6g} s ({steps:,} steps), above the planner's limit of {MAX_STEPS:,} "
            "steps (tmr.model.params.MAX_STEPS)"
        )
    return _with_goal_heading(
        replace(
            problem, references=ref, trajectory=ref.trajectory, time_params=replace(problem.time_params, T_end=T_end)
        )
    )


#: What the train references keep beyond the QP's own clearance and separation [m].
TRAIN_MARGIN = 0.005


def _solve_qp(problem: Problem, progress: bool) -> tuple[Problem, Plan, Metrics]:
    """The QP along the problem's references; if the plan fails with trailing route references (and T_end is not
    fixed by the user), again along train references (:func:`train_problem`), whose plan is returned if it passes
    every check (``diagnostics["references"]`` says which were used, ``["references_note"]`` why)."""
    result, metrics = _checked(problem, "qp", progress)
    ref = problem.references
    if ref is None or result.success or ref.mode != "trail" or problem.fixed_duration or problem.chain.n_robots < 2:
        return problem, result, metrics
    from tmr.route.train import TrainError

    first = str(result.failure).split(";")[0]
    try:
        trained = train_problem(problem)
    except TrainError as exc:
        result.diagnostics["references_note"] = f"trailing references failed ({first}); train references: {exc}"
        return problem, result, metrics
    retry, retry_metrics = _checked(trained, "qp", progress)
    if not retry.success:
        result.diagnostics["references_note"] = (
            f"trailing references failed ({first}); along train references too ({retry.failure})"
        )
        return problem, result, metrics
    retry.diagnostics["references"] = "train"
    retry.diagnostics["references_note"] = (
        f"the trailing references failed ({first}); planned along train references (the robots in turn)"
    )
    return trained, retry, retry_metrics


def check(plan: Plan, env: Any, goal_tolerance: float = 0.1) -> Metrics:
    """Check every hard constraint on the plan's recorded states and return its metrics.

    A plan that completed its steps fails (``plan.success = False``, f1–f4 = +∞ as in Caruso 2021 §4.2.2) if at any
    step a robot or a tether enters the inflated obstacles, a span leaves [d_lo, d_max], two robots come closer than
    2r, or if the leader ends farther than ``goal_tolerance`` [m] from the goal, or (a differential-drive plan with a
    goal heading) its final heading is more than :data:`tmr.checks.diffdrive.HEADING_TOLERANCE_DEG` from it.
    """
    metrics = evaluate(plan, env)
    if not plan.success:
        return metrics
    reasons = [
        f"{kind} violated at {len(steps)} step(s), first at t = {plan.t[steps[0]]:.2f} s"
        for kind, steps in metrics.violation_steps.items()
        if steps
    ]
    if metrics.final_leader_error > goal_tolerance:
        held = plan.diagnostics.get("held_by")
        reasons.append(
            f"leader ends {metrics.final_leader_error:.3f} m from the goal (tolerance {goal_tolerance} m)"
            + (f", held back: {held}" if held else "")
        )
    dd = metrics.diff_drive or {}
    if "final_heading_error" in dd and math.degrees(dd["final_heading_error"]) > dd["heading_tolerance_deg"]:
        reasons.append(
            f"leader ends {math.degrees(dd['final_heading_error']):.3g} deg from the goal heading "
            f"{math.degrees(dd['goal_heading']):.6g} deg (tolerance {dd['heading_tolerance_deg']:g} deg)"
        )
    if reasons:
        plan.success = False
        plan.failure = "; ".join(reasons)
        # only the verdict and the fitness (+∞ for a failed plan) change: no second pass over every recorded state
        f1, f2, f3, f4 = fitness(plan, metrics.Ts)
        metrics = replace(metrics, success=False, failure=plan.failure, f1=f1, f2=f2, f3=f3, f4=f4)
    return metrics
