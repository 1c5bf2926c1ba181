"""From a drone scenario to a checked plan: scenario → 3-D route (and the robots it needs) → references and start
→ per-step formulation (``qp`` or ``pinv``) → plan → independent check (``formulations/drones.md``).

Caruso 2021 states the chain in 3-D (its Fig. 1: tethered drones); this is that chain, planned as the ground one is
(:mod:`tmr.planner`): the route comes first, so a goal with no free route or a chain shorter than the route's proven
lower bound is refused before any motion is planned (:class:`NoRouteError`, :class:`TooFewRobotsError`).

Library use::

    from tmr.world.drones import load_drone_scenario
    from tmr.planner3d import plan_drones
    plan, metrics = plan_drones(load_drone_scenario("F"), robots="auto")
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from tmr.errors import ParameterError, fmt_point
from tmr.model.catenary3d import DroneTetherParams
from tmr.model.params import DroneParams, apply_overrides

if TYPE_CHECKING:
    from tmr.checks.drones import DroneMetrics
    from tmr.control.plan3d import DronePlan
    from tmr.route.route3d import DroneReferences, Route3D
    from tmr.world.drones import DroneScenario
    from tmr.world.world3d import World3D

__all__ = ["DRONE_METHODS", "DroneProblem", "drone_parameters", "route_drones", "build_drone_problem", "solve_drones",
           "plan_drones"]  # fmt: skip

#: Formulations of a drone chain: the lexicographic QP with hard limits, the paper's CLIK baseline, and the
#: whole-horizon NLP warm-started from the qp plan (:mod:`tmr.control.horizon3d`).
DRONE_METHODS = ("qp", "pinv", "horizon")
#: ``robots="auto"`` tries N_min, N_min + 1, … up to this many drones more.
AUTO_EXTRA = 3


@dataclass
class DroneProblem:
    """Everything a drone formulation needs, built once (:func:`build_drone_problem`)."""

    scenario: DroneScenario
    world: World3D
    tether: DroneTetherParams
    params: DroneParams
    route: Route3D
    references: DroneReferences
    n_robots: int


def drone_parameters(
    scenario: DroneScenario, overrides: dict[str, Any] | None = None
) -> tuple[DroneParams, DroneTetherParams]:
    """The planner's and the tether's parameters: the scenario's ``[params]`` then ``overrides`` (``--set``) applied
    by field name to :class:`DroneParams` and :class:`DroneTetherParams` (the scenario's ``[tether]`` is already in
    ``scenario.tether``). ParameterError naming any name that is neither."""
    values = dict(scenario.params or {}) | dict(overrides or {})
    params, rest = apply_overrides(DroneParams(), values)
    tether_fields = {f.name for f in fields(DroneTetherParams)}
    tether_values = {k: v for k, v in rest.items() if k in tether_fields}
    rest = {k: v for k, v in rest.items() if k not in tether_fields}
    if rest:
        raise ParameterError(
            f"unknown drone parameter(s) {sorted(rest)}; the names are the fields of DroneParams and "
            "DroneTetherParams (formulations/drones.md)"
        )
    try:
        tether = replace(scenario.tether, **tether_values)
    except TypeError as exc:  # pragma: no cover - names filtered above
        raise ParameterError(str(exc)) from None
    from tmr.model.catenary3d import WINCH_FIELDS

    given = sorted(k for k in tether_values if k in WINCH_FIELDS and k != "winch")
    if given and not tether.active:  # a constant winch has no range or rate: refused, not silently dropped
        raise ParameterError(
            f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} an active winch's: add winch=active "
            '(--set winch=active or [tether] winch = "active")'
        )
    return params, tether


def route_drones(
    scenario: DroneScenario, params: DroneParams, tether: DroneTetherParams, robots: int | Literal["auto"] | None
) -> tuple[Route3D, int]:
    """The 3-D route and the number of drones to plan with first: ``robots`` (the scenario's if None), or the
    route's proven minimum for ``"auto"``. Raises NoRouteError (no free route) and TooFewRobotsError (fewer drones
    than the proven lower bound), both exit 2, before any motion is planned.

    The straight line is a lower bound on any curve from the anchor to the goal, so a count below
    ⌈|goal − base| / L_max⌉ is refused before the route's lattice is even built."""
    import math

    from tmr.route.geodesic import TooFewRobotsError
    from tmr.route.route3d import check_drone_count, plan_route3d

    wanted = scenario.n_robots if robots is None else robots
    if wanted != "auto":
        n = int(wanted)
        # the leader must end within the goal tolerance: the chain spans at least |goal − base| − tolerance
        straight = float(np.linalg.norm(np.asarray(scenario.goal) - np.asarray(scenario.base)))
        reach = max(0.0, straight - params.goal_tolerance)
        fewest = max(1, math.ceil(reach / tether.tether_length - 1e-12))
        if n < fewest:
            raise TooFewRobotsError(
                f"{n} drone{'s' if n != 1 else ''} cannot reach the goal {fmt_point(scenario.goal)}: it is "
                f"{straight:.3f} m from the base {fmt_point(scenario.base)} in a straight line ({reach:.3f} m to "
                f"within the goal tolerance {params.goal_tolerance:g} m), more than {n} x {tether.tether_length:.3f} m "
                f"of tether; the fewest is at least {fewest}",
                fewest,
                proven=True,
            )
    route = plan_route3d(
        scenario.world, scenario.base, scenario.goal, tether, grid=params.grid, goal_tolerance=params.goal_tolerance
    )
    if wanted == "auto":
        return route, max(1, route.min_robots)
    check_drone_count(route, int(wanted))
    return route, int(wanted)


def build_drone_problem(
    scenario: DroneScenario,
    n_robots: int,
    *,
    params: DroneParams | None = None,
    tether: DroneTetherParams | None = None,
    route: Route3D | None = None,
) -> DroneProblem:
    """The problem of planning ``n_robots`` drones: the route (computed if not given), the references of every drone
    along it and the start (:func:`tmr.route.route3d.drone_references`)."""
    from tmr.route.route3d import drone_references, plan_route3d

    if params is None or tether is None:
        p, t = drone_parameters(scenario)
        params, tether = params or p, tether or t
    world = scenario.world
    if route is None:
        route = plan_route3d(
            world, scenario.base, scenario.goal, tether, grid=params.grid, goal_tolerance=params.goal_tolerance
        )
    refs = drone_references(
        route, n_robots, world=world, Ts=params.Ts, speed=params.leader_speed, accel=params.leader_accel,
        settle=params.settle, d_safe=params.d_safe, separation_margin=params.separation_margin,
    )  # fmt: skip
    return DroneProblem(scenario, world, tether, params, route, refs, n_robots)


def solve_drones(
    problem: DroneProblem,
    method: str = "qp",
    *,
    progress: bool = False,
    time_limit: float | None = None,
    horizon_options: dict[str, Any] | None = None,
) -> tuple[DronePlan, DroneMetrics]:
    """Plan with ``method`` (``"qp"``, ``"pinv"`` or ``"horizon"``) and check every hard limit with the independent
    checker.

    ``"horizon"``: the whole-horizon NLP (:func:`tmr.control.horizon3d.plan_horizon_drones`,
    ``formulations/horizon3d.md``) warm-started from the very plan ``solve_drones(problem, "qp")`` returns, never
    worse than it in any of f1–f4 of the checker (else that qp plan itself is returned, ``method="horizon"``,
    ``diagnostics["horizon_result"] = "warm_start"``); ``time_limit`` [s] bounds the NLP (None: its default,
    :data:`tmr.control.horizon.DEFAULT_TIME_LIMIT` = 60 s), ``horizon_options`` are fields of
    :class:`tmr.control.horizon3d.DroneHorizonOptions`.

    The plan's ``wall_time`` is the whole of this call [s]; ``diagnostics["timings"]`` its parts (``qp_time``, and
    for ``horizon`` its ``nlp_time``)."""
    from tmr.checks.drones import check_drone_plan
    from tmr.control.drones import make_drone_pinv, make_drone_qp
    from tmr.control.run3d import run_drones

    if method not in DRONE_METHODS:
        raise ParameterError(f"unknown method {method!r} for a drone chain; available: {', '.join(DRONE_METHODS)}")
    check_winch_method(problem.tether, method)
    if method == "horizon":
        return _solve_horizon(problem, progress=progress, time_limit=time_limit, options=horizon_options or {})
    start = time.perf_counter()
    make = make_drone_qp if method == "qp" else make_drone_pinv
    formulation = make(
        problem.world, problem.tether, problem.params, problem.n_robots, problem.references, base=problem.scenario.base
    )
    plan = run_drones(
        problem.world, problem.references, formulation, problem.references.start_positions,
        tether=problem.tether, params=problem.params, goal=problem.scenario.goal, scenario=problem.scenario.name,
    )  # fmt: skip
    run_time = time.perf_counter() - start
    metrics = check_drone_plan(plan, problem.scenario, params=problem.params)
    plan.wall_time = time.perf_counter() - start
    plan.diagnostics["timings"] = {"qp_time": run_time, "check_time": plan.wall_time - run_time}
    return plan, metrics


def _solve_horizon(
    problem: DroneProblem, *, progress: bool, time_limit: float | None, options: dict[str, Any]
) -> tuple[DronePlan, DroneMetrics]:
    """``solve_drones(problem, "horizon")``: the qp plan, then the NLP from it (casadi imported only here)."""
    from tmr.control.horizon import DEFAULT_TIME_LIMIT
    from tmr.control.horizon3d import plan_horizon_drones

    start = time.perf_counter()
    warm, warm_metrics = solve_drones(problem, "qp", progress=progress)
    qp_time = time.perf_counter() - start
    if not warm.success:  # no start for the NLP (a stalled qp plan may hold only its first steps): not run
        reason = f"horizon: not started, its qp warm start failed ({str(warm.failure).split(';')[0]})"
        warm.method, warm.failure = "horizon", reason
        warm.diagnostics = dict(warm.diagnostics, horizon_result="warm_start", horizon_note=reason)
        warm.wall_time = time.perf_counter() - start
        warm.diagnostics["timings"] = {"qp_time": qp_time, "nlp_time": 0.0}
        return warm, replace(warm_metrics, method="horizon", failure=reason)
    limit = DEFAULT_TIME_LIMIT if time_limit is None else time_limit
    plan, metrics = plan_horizon_drones(problem, warm, warm_metrics, time_limit=limit, progress=progress, **options)
    plan.wall_time = time.perf_counter() - start
    plan.diagnostics["timings"] = {"qp_time": qp_time, "nlp_time": plan.wall_time - qp_time}
    return plan, metrics


def plan_drones(
    scenario: DroneScenario,
    robots: int | Literal["auto"] | None = None,
    method: str = "qp",
    *,
    overrides: dict[str, Any] | None = None,
    progress: bool = False,
    details: dict[str, Any] | None = None,
    time_limit: float | None = None,
) -> tuple[DronePlan, DroneMetrics]:
    """Route, refuse or plan, and check: the whole of ``tmr plan`` for a drone scenario, as a library call.

    ``robots``: N, ``"auto"`` (the fewest from the route's proven minimum that give a plan passing every check,
    trying up to :data:`AUTO_EXTRA` more), or None (the scenario's). Raises NoRouteError / TooFewRobotsError (exit
    2) before planning; returns the last plan tried with its metrics (``plan.success`` says whether it passed).
    ``details``, if given, receives the ``route`` (:class:`Route3D`) and the ``problem`` of the plan returned; the
    plan's ``diagnostics`` get ``route_length``, ``route_lower_bound``, ``n_min`` [m, m, -] and, for ``auto``,
    ``robots_auto`` (every count tried and why it failed). ``time_limit`` [s]: of the ``horizon`` NLP (None: 60 s)."""
    from tmr.route.route3d import StartError

    start = time.perf_counter()
    params, tether = drone_parameters(scenario, overrides)
    check_thrust(tether)
    check_winch_method(tether, method)
    wanted = scenario.n_robots if robots is None else robots  # the file may say "auto" too
    route, n_first = route_drones(scenario, params, tether, wanted)
    route_time = time.perf_counter() - start
    auto = wanted == "auto"
    last = n_first + AUTO_EXTRA if auto else n_first
    tried: list[str] = []
    result: tuple[DronePlan, DroneMetrics] | None = None
    for n in range(n_first, last + 1):
        try:
            problem = build_drone_problem(scenario, n, params=params, tether=tether, route=route)
        except StartError as exc:
            if not auto:
                raise
            tried.append(f"{n}: {str(exc).split(';')[0]}")
            continue
        result = solve_drones(problem, method, progress=progress, time_limit=time_limit)
        if details is not None:
            details.update(route=route, problem=problem)
        tried.append(f"{n}: {'planned' if result[0].success else str(result[0].failure).split(';')[0]}")
        if result[0].success:
            break
    if result is None:
        raise StartError(f"--robots auto: no valid start for N = {n_first} … {last} drones (N = {tried[0]})")
    plan, metrics = result
    if auto:
        plan.diagnostics["robots_auto"] = f"N_min = {route.min_robots}; " + "; ".join(tried)
    plan.diagnostics.update(
        route_length=float(route.length), route_lower_bound=float(route.lower_bound_length), n_min=int(route.min_robots)
    )
    plan.diagnostics.setdefault("timings", {})["route_time"] = route_time
    plan.wall_time = time.perf_counter() - start
    return plan, metrics


def check_winch_method(tether: DroneTetherParams, method: str) -> None:
    """Refuse (ParameterError, exit 2) an active winch with a formulation that does not plan with it: ``qp`` has the
    tension as a decision variable, ``horizon`` optimises the drones' paths under the qp plan's tension schedule and
    then chooses the least rate-bounded schedule those paths need (:mod:`tmr.control.horizon3d_winch`)
    (``formulations/drones.md``, "Active winch"); ``pinv`` keeps it constant."""
    if tether.active and method not in ("qp", "horizon"):
        raise ParameterError(
            f"winch = 'active' is planned by --method qp and horizon only (the winch tension is a variable of the "
            f"per-step QP; {method} keeps it constant): use --method qp or horizon, or winch = 'constant'"
        )


def check_thrust(tether: DroneTetherParams) -> None:
    """Refuse (ParameterError, exit 2) a tether no drone can hold: with the winch at the lower end of each tether the
    tension is T_w there and grows with height (T_B = T_w + ρ g h), so every drone end of every tether pulls with at
    least T_w; a T_w above the drones' spare thrust (:attr:`DroneTetherParams.spare_thrust`) leaves no plan."""
    if tether.winch_end == "lower" and tether.winch_tension >= tether.spare_thrust:
        raise ParameterError(
            f"the winch tension {tether.winch_tension:.3f} N is at least the drones' spare thrust "
            f"{tether.spare_thrust:.3f} N (mass {tether.drone_mass:g} kg, thrust/weight {tether.thrust_to_weight:g}, "
            f"reserve {tether.control_reserve:g}): every drone end of a tether pulls with at least the winch tension, "
            "so no drone can hold one; lower winch_tension or give the drones more thrust"
        )
    if tether.active and tether.winch_end == "lower" and tether.winch_tension_min >= tether.spare_thrust:
        raise ParameterError(
            f"the active winch's least tension winch_tension_min {tether.winch_tension_min:.3f} N is at least the "
            f"drones' spare thrust {tether.spare_thrust:.3f} N: no drone can hold a tether at any tension of the range"
        )
