"""Command line: ``python -m tmr.plan --scenario A --method pinv --out runs/A``.

Plans the chain for a scenario (built-in A–D, a scenario TOML file, or a map with ``--base/--goal``), checks every
hard constraint on the recorded states, writes trajectories (JSON + CSV), metrics (JSON) and figures into ``--out``,
and prints a metrics summary. Inputs are validated before anything is written; all files are written to a temporary
directory first and moved into ``--out`` only when every one of them is complete.

Before any motion is planned, the shortest free route from the anchor to the goal tells whether the goal can be
reached and with how many robots (:mod:`tmr.route.route`); ``--robots auto`` takes the fewest that plan (with
``--method horizon``: the fewest whose ``qp`` warm start passes, the NLP run once, from it).

One robot radius r (``--robot-radius R``, or ``--set safety_radius=R``; default the scenario's) is used everywhere:
the obstacles are grown by it, the robots kept 2r apart, the route and the messages use it.

Messages go through :mod:`logging` (``--quiet``, ``--verbose``; ``--debug`` shows tracebacks, :mod:`tmr.io.console`).
``metrics.json`` holds no timing, so two runs with the same inputs write the same bytes; the planner's wall time is
in ``timings.json``. Outputs are staged and published into ``--out`` in one step (:mod:`tmr.io.outdir`): a re-used
``--out`` keeps no output of an older run (:data:`OWNED_NAMES`), and a file tmr did not write is never replaced or
removed (such a file under an output's name is refused up front, exit 2).

Exit codes: 0 plan succeeded; 1 no plan found or the plan failed a check (the reason printed; outputs of a computed
plan written); 2 bad input or a task proven impossible up front (one line, nothing written); 130 interrupted (Ctrl-C,
nothing written).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tmr.errors import NoPathFound, ParameterError, TmrError
from tmr.io.cli_args import (
    ArgumentParser,
    add_common,
    bounds,
    count,
    goal_pose,
    param,
    path_arg,
    point,
    points,
    positive_float,
    robot_model_arg,
)
from tmr.io.console import LOG, progress_enabled
from tmr.io.console import run as run_cli
from tmr.views.flags import VIEW_NAMES, write_views
from tmr.views.motion import chain_motion

#: Every file ``python -m tmr.plan`` writes into ``--out`` besides the views (:data:`tmr.views.flags.VIEW_NAMES`).
OUTPUT_NAMES = (
    "trajectories.json",
    "trajectories.csv",
    "metrics.json",
    "timings.json",
    "run.json",
    "chain_poses.png",
    "trajectories.png",
    "distance_errors.png",
    "speeds.png",
    "drive.png",
)
#: Keys of the metrics that are timings [s] (``ms_per_step`` [ms]): written to ``timings.json``, not ``metrics.json``.
#: ``wall_time`` is the whole planning time, from the route to the checked plan (every ``--robots auto`` attempt);
#: the parts: ``route_time`` (the route and its robot counts, before anything else), ``other_attempts_time`` (the
#: ``--robots auto`` attempts before the one kept), ``problem_time`` (the leader's path, references and start of the
#: plan kept), ``qp_time`` (its qp runs; the warm start of ``horizon``), ``nlp_time`` (the horizon NLP) — their sum
#: is at most ``wall_time`` (the rest: the checks). ``outputs_time``: writing the files before ``timings.json``.
TIMING_KEYS = (
    "wall_time",
    "ms_per_step",
    "route_time",
    "other_attempts_time",
    "problem_time",
    "qp_time",
    "nlp_time",
    "outputs_time",
)
#: Every entry of ``--out`` a plan owns: its files, its views, and the physics replay of the plan (``tmr replay``
#: writes ``replay/``). Those tmr wrote before and a new run does not write are removed when it publishes; an entry
#: of one of these names that tmr did not write makes the run refuse its ``--out`` (:mod:`tmr.io.outdir`).
OWNED_NAMES = (
    OUTPUT_NAMES
    + ("chain_poses_3d.png", "altitude.png", "tether_clearance.png", "tensions.png", "world_meshes")
    + VIEW_NAMES
    + ("replay", "cmd_vel")
)  # the drone figures (tmr.plan3d.DRONE_FIGURES), meshes (tmr.io.drones)
#: Outputs whose bytes change from run to run (listed in the manifest without a hash).
VOLATILE_NAMES = ("timings.json",)


def _robots(text: str) -> int | str:
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return count(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"must be a whole number ≥ 1 or 'auto', got {text!r}") from exc


#: ``--robots auto`` tries N_min, N_min + 1, ... up to AUTO_EXTRA robots more than the route chain needs.
AUTO_EXTRA = 3


#: Default cut-off of the trajectory filter [Hz] (``--filter-cutoff``).
FILTER_CUTOFF = 1.0


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``python -m tmr.plan``; ``prog``: the name it shows (``tmr plan`` through the dispatcher)."""
    p = ArgumentParser(
        prog=prog or "python -m tmr.plan",
        description="Plan the motion of a chain of tethered mobile robots (Caruso 2021) and write trajectories, "
        "metrics and figures.",
    )
    src = p.add_argument_group("scenario")
    src.add_argument(
        "--scenario",
        type=path_arg,
        help="built-in scenario A, B, C, D (Caruso 2021), E (tmr's), F, G, H (tethered drones in 3-D), or a path to a "
        'scenario TOML file (kind = "drone" for a drone chain)',
    )
    src.add_argument(
        "--map", type=path_arg, help="map file: ROS map_server .yaml (+ .pgm), .geojson or .wkt (needs --base, --goal)"
    )
    src.add_argument("--bounds", type=bounds, help="room bounds xmin,ymin,xmax,ymax [m] for a GeoJSON/WKT --map")
    src.add_argument("--base", type=point, help="tether anchor X,Y [m]")
    src.add_argument(
        "--goal",
        type=goal_pose,
        help="leader goal X,Y [m], or X,Y,THETA with the leader's final heading THETA in degrees (90, 90deg; "
        "1.57rad for radians; --drive diff only)",
    )
    src.add_argument(
        "--start",
        type=points,
        help="robot start positions 'x1,y1;x2,y2;...' [m], one per robot (N: --robots, else the scenario's; "
        "default: computed); with --drive diff the tethers' exit points (each axle is b behind its exit point, the "
        "start heading along the robot's first motion)",
    )
    src.add_argument(
        "--robots",
        type=_robots,
        help="number of robots N, or 'auto' for the fewest that plan (with --method horizon: whose qp warm start "
        "passes; default: the scenario's, 3)",
    )
    src.add_argument(
        "--robot-radius",
        type=positive_float,
        metavar="R",
        help="robot radius r [m] (default: the scenario's; 0.5 for ground robots, 0.3 for drones; a --map run of "
        "--drive diff robots: the model's exit_offset + radius, 0.185 for turtlebot3_burger): obstacles grown "
        "by r, robots kept 2r apart, the route and the messages use it; same as --set safety_radius=R",
    )
    p.add_argument(
        "--method",
        default="qp",
        choices=["pinv", "qp", "horizon"],
        help="qp: lexicographic QP with hard constraints (default); pinv: the paper's pseudoinverse CLIK; horizon: "
        "whole-horizon NLP (CasADi/IPOPT) warm-started from qp",
    )
    p.add_argument(
        "--route",
        default="shortest",
        choices=["shortest", "rrt"],
        help="shortest: the tether-aware shortest free route, references for every robot, duration from the route "
        "length (default); rrt: the paper's RRT* leader path over T_end = 15 s (Caruso 2021)",
    )
    p.add_argument(
        "--time-limit",
        type=positive_float,
        default=None,
        help="wall-clock limit of the horizon NLP [s] (default 60); on expiry the best feasible plan is returned",
    )
    p.add_argument(
        "--solver",
        help="QP solver for --method qp: osqp (persistent workspace, default) or a qpsolvers "
        "backend (daqp, proxqp, clarabel, qpsolvers-osqp, ...)",
    )
    p.add_argument("--iterations", type=count, help="RRT* iterations (default 1000)")
    p.add_argument(
        "--drive",
        choices=["omni", "diff"],
        help="ground robots' kinematics: omni (omnidirectional, Caruso 2021; default) or diff (differential drive: "
        "heading, no sideways motion, v/ω limits; --method qp and horizon); same as --set drive=...",
    )
    p.add_argument(
        "--robot-model",
        type=robot_model_arg,
        metavar="NAME|FILE",
        help="differential-drive robot: turtlebot3_burger (default), turtlebot3_waffle_pi, clearpath_jackal (short: "
        "burger, waffle_pi, jackal), or a "
        "TOML file with radius, v_max, omega_max, a_max, alpha_max, exit_offset (SI units); implies --drive diff",
    )
    p.add_argument(
        "--set",
        type=param,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a parameter of tmr.model.params by its field name, e.g. --set d_min=0.6 (repeatable)",
    )
    p.add_argument(
        "--filter-cutoff",
        type=positive_float,
        metavar="HZ",
        help="cut-off of the trajectory filter [Hz], below the Nyquist frequency 1/(2 Ts) "
        f"(default {FILTER_CUTOFF:g}); omnidirectional ground chains only: a differential-drive or drone plan is not "
        "filtered",
    )
    add_common(p, out="runs/plan", seed_help="seed of the leader's RRT* (--route rrt)")
    return p


def filter_cutoff(args: argparse.Namespace) -> float:
    """The trajectory filter's cut-off [Hz]: ``--filter-cutoff`` or :data:`FILTER_CUTOFF`."""
    return FILTER_CUTOFF if args.filter_cutoff is None else float(args.filter_cutoff)


def robot_radius(args: argparse.Namespace) -> float | None:
    """The robot radius r [m] the command line gives (``--robot-radius``, ``--set safety_radius=``), or None for
    the scenario's own (its ``[params]``/``[map]`` ``safety_radius``, 0.5 m by default)."""
    given = {float(v) for k, v in args.set if k == "safety_radius"}
    if getattr(args, "robot_radius", None) is not None:
        given.add(float(args.robot_radius))
    if len(given) > 1:
        raise TmrError(f"two robot radii given: {sorted(given)} m (--robot-radius and --set safety_radius=); give one")
    return given.pop() if given else None


#: Robots of a ``--map`` run without ``--robots`` (a scenario file says its own, 3 by default).
MAP_ROBOTS = 3


def check_start_count(args: argparse.Namespace, scenario_robots: int, owner: str) -> None:
    """``--start`` lists one position per robot: N from ``--robots N``, else the scenario's own count
    (``scenario_robots``; ``owner`` says whose, e.g. "scenario A has"). TmrError (exit 2) naming both numbers and the
    fix otherwise: a shorter or longer list never changes N by itself."""
    if args.start is None or args.robots == "auto":  # auto with --start is refused on its own
        return
    k = len(args.start)
    if isinstance(args.robots, int):
        if k != args.robots:
            raise TmrError(
                f"--start lists {k} position{'s' if k != 1 else ''} but --robots is {args.robots}: give one "
                f"position per robot ({args.robots}), or --robots {k}"
            )
    elif k != scenario_robots:
        raise TmrError(
            f"--start lists {k} position{'s' if k != 1 else ''} but {owner} {scenario_robots} robots: give "
            f"{scenario_robots} positions, or add --robots {k} to plan with {k}"
        )


def diff_map_radius(args: argparse.Namespace) -> float | None:
    """A ``--map`` run of differential-drive robots without a robot radius: r = b + r_f [m] of the robot model (the
    smallest disc round the tether's exit point that holds the footprint, ``tmr.model.diffdrive.model_for``), instead
    of the 0.5 m of Caruso 2021's robots; None otherwise (omni, a scenario, or a radius given)."""
    given = dict(args.set)
    if not args.map or robot_radius(args) is not None or str(given.get("drive", "")).strip() != "diff":
        return None
    from tmr.model.diffdrive import DEFAULT_MODEL, load_robot_model

    model = load_robot_model(str(given.get("robot_model") or DEFAULT_MODEL))
    return model.exit_offset + model.radius


def load_inputs(args: argparse.Namespace) -> Any:
    """Scenario object from the arguments (built-in, TOML, or map + base + goal)."""
    from dataclasses import replace

    from tmr.world.scenario import load_scenario, scenario_from_map

    r = robot_radius(args)  # one r: the obstacles are grown by it and the chain keeps it (tmr.world.scenario)
    if args.map:
        r = diff_map_radius(args) or r
        if args.scenario:
            raise TmrError("give either --scenario or --map, not both")
        if args.base is None or args.goal is None:
            raise TmrError("--map needs --base X,Y and --goal X,Y")
        kwargs: dict[str, Any] = {}
        if args.bounds:
            kwargs["bounds"] = args.bounds
        n = args.robots if isinstance(args.robots, int) else MAP_ROBOTS
        check_start_count(args, n, "a --map run without --robots plans")
        if r is not None:
            kwargs["safety_radius"] = r
        sc = scenario_from_map(args.map, args.base, args.goal[:2], start=args.start, n_robots=n, **kwargs)
        if len(args.goal) == 3:
            sc = replace(sc, goal_heading=args.goal[2])
    else:
        sc = load_scenario(args.scenario or "A", safety_radius=r)
        check_start_count(args, sc.n_robots, f"scenario {sc.name} has")
        changes: dict[str, Any] = {}
        if args.base is not None:
            changes["base"] = np.array(args.base)
        if args.goal is not None:
            changes["goal"] = np.array(args.goal[:2])  # X,Y replaces the scenario's goal pose, heading included
            changes["goal_heading"] = args.goal[2] if len(args.goal) == 3 else None
        if changes:
            sc = replace(sc, **changes)
    return sc


def write_outputs(
    out: Path,
    plan: Any,
    metrics: Any,
    env: Any,
    filtered: np.ndarray,
    plots: bool,
    extra: dict[str, Any] | None = None,
    route: Any = None,
    pool: Any = None,
) -> list[str]:
    """Write every output of a plan into the directory ``out`` (a :class:`tmr.io.outdir.Stage`'s directory when run
    from the command line) and return the names written; the figures are rendered by ``pool`` (a
    :class:`tmr.views.plotpool.FigurePool`) if given, else here."""
    from tmr.io import outputs as io

    start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    io.write_trajectories_json(plan, out / "trajectories.json", filtered=filtered)
    io.write_trajectories_csv(plan, out / "trajectories.csv", filtered=filtered)
    values = metrics.to_dict() | (extra or {})
    timings = {key: values.pop(key) for key in TIMING_KEYS if key in values}
    io.write_metrics_json(values, out / "metrics.json")
    from tmr.io.rundir import write_chain_run

    write_chain_run(out / "run.json", plan, env, extra)  # scenario, map and tether parameters (tmr.replay)
    names = ["trajectories.json", "trajectories.csv", "metrics.json", "timings.json", "run.json"]
    if getattr(plan, "heading", None) is not None:  # differential drive: one velocity command file per robot
        io.write_cmd_vel(plan, out / io.CMD_VEL_DIR)
        names.append(io.CMD_VEL_DIR)
    if plots:
        diff = getattr(plan, "heading", None) is not None  # not filtered: no filtered curve beside the plan's
        shown = None if diff else filtered
        figures = {
            "chain_poses.png": ("plot_chain_poses", (plan, env), {"route": route}),
            "trajectories.png": ("plot_trajectories", (plan, shown), {}),
            "distance_errors.png": ("plot_distance_errors", (plan,), {}),
            "speeds.png": ("plot_speeds", (plan, shown), {}),
        }
        if diff:
            figures["drive.png"] = ("plot_drive", (plan,), {})
        if getattr(plan, "winch_tension", None) is not None:
            figures["winch_tension.png"] = ("plot_winch", (plan,), {})
        rendered = _pooled(pool, figures)
        if rendered is not None:
            for name, data in rendered.items():
                io.atomic_write_bytes(out / name, data)
        else:
            from tmr.views import plot

            for name, (function, args, kwargs) in figures.items():
                plot.save_figure(getattr(plot, function)(*args, **kwargs), out / name)
        names += list(figures)
    timings["outputs_time"] = time.perf_counter() - start
    io.write_metrics_json(timings, out / "timings.json")  # kept apart: metrics.json is reproducible
    return sorted(names)


def summary(plan: Any, metrics: Any) -> str:
    d = metrics.to_dict()
    d["violations"] = {kind: len(steps) for kind, steps in d.pop("violation_steps").items()}
    d["fitness_raw"] = " ".join(f"{float(v):.6g}" for v in d["fitness_raw"])
    keys = [
        "success",
        "failure",
        "f1",
        "f2",
        "f3",
        "f4",
        "fitness_raw",
        "min_robot_clearance",
        "min_tether_clearance",
        "max_span_ratio",
        "min_separation",
        "peak_speed",
        "peak_acceleration",
        "final_speed",
        "max_abs_distance_error",
        "final_leader_error",
        "final_heading_error",
        "violations",
        "wall_time",
        "ms_per_step",
    ]
    if d.get("qp_levels"):  # --method qp: what each level of the QP stack did, counted over the steps
        d["qp_levels"] = "; ".join(
            f"{name}: " + ", ".join(f"{n} {status}" for status, n in counts.items() if n)
            for name, counts in d["qp_levels"].items()
        )
        at = keys.index("violations") + 1
        keys[at:at] = ["qp_levels", "qp_fallback_solves"]
    dd = d.get("diff_drive") or {}
    model = (plan.params or {}).get("robot_model") if dd else None
    drive = f", differential drive ({model})" if model else ""
    lines = [
        f"tmr plan: scenario {plan.scenario}, method {plan.method}, {plan.n_robots} robots{drive}, "
        f"{plan.t.size - 1} steps"
    ]
    if dd.get("v_max"):  # the peaks the independent check measured against the robot's limits
        lines.append(
            f"  {'drive peaks':<24} v {dd['peak_v']:.3g} of {dd['v_max']:g} m/s, ω {dd['peak_omega']:.3g} of "
            f"{dd['omega_max']:g} rad/s, wheel rim {dd.get('peak_wheel_rim_speed', 0.0):.3g} m/s; turn in place "
            f"{sum(dd.get('turn_in_place_steps', [])):d} steps"
        )
    if "final_heading_error" in dd:  # a goal heading (--goal X,Y,THETA): the leader's final heading error [deg]
        err, tol = math.degrees(dd["final_heading_error"]), dd["heading_tolerance_deg"]
        d["final_heading_error"] = f"{err:.4g} deg (tolerance {tol:g} deg)"
    else:
        keys.remove("final_heading_error")
    for k in keys:
        v = d[k]
        lines.append(f"  {k:24s} {v:.6g}" if isinstance(v, float) else f"  {k:24s} {v}")
    tension = getattr(plan, "winch_tension", None)
    if tension is not None:  # the active winch: the tensions it planned and the floor clearance they keep
        p = getattr(plan, "params", None) or {}
        rate = p.get("span_approach_rate")
        lines.insert(
            len(lines) - 2,
            f"  {'winch':24s} active: T0 {float(np.min(tension)):.1f}–{float(np.max(tension)):.1f} N "
            f"(range {p.get('winch_tension_min', 0):g}–{p.get('winch_tension_max', 0):g} N); tethers kept "
            f"≥ {p.get('ground_clearance', 0.0):g} m above the floor"
            + (f", pay-out damped at {rate:g} 1/s near the reach" if rate else ""),
        )
    return "\n".join(lines)


def _plan_once(
    args: argparse.Namespace, scenario: Any, n_robots: int | None, route: Any, qp_first: bool = False
) -> tuple[Any, Any, Any]:
    """Build and solve with ``n_robots``, reusing the precheck's ``route`` (its span limits are those of any N ≥ 2,
    and for N ≥ its N_min no tighter margin is tried): the route is not computed twice. With ``qp_first`` (``--robots
    auto``) the horizon NLP runs only from a ``qp`` plan that passes every check: where that plan fails, it is
    returned, failed, without an NLP (the NLP from a failed ``qp`` plan found none in any run of the rooms benchmark,
    and ran up to its time limit for each such N of ``--robots auto``: ``formulations/horizon.md``, "Warm start")."""
    from tmr.planner import build_problem, qp_run, solve

    start = time.perf_counter()
    overrides = dict(args.set) | ({"solver": args.solver} if args.solver else {})
    problem = build_problem(
        scenario,
        seed=args.seed,
        n_robots=n_robots,
        start=args.start,
        overrides=overrides,
        path_iterations=args.iterations,
        route=args.route,
        known_route=route if _route_fits(args, route, n_robots or 0) else None,
    )
    problem_time = time.perf_counter() - start
    LOG.debug("planning with %d robots: %s", problem.chain.n_robots, args.method)
    qp = qp_run(problem, progress=progress_enabled()) if qp_first and args.method == "horizon" else None
    if qp is not None and not qp.plan.success:
        plan, metrics = qp.plan, qp.metrics
        plan.method = "horizon"
        plan.failure = f"qp warm start: {plan.failure}; --robots auto runs the horizon NLP only from one that passes"
        plan.diagnostics["timings"] = dict(qp_time=qp.seconds, problem_time=problem_time)
        return qp.problem, plan, metrics
    plan, metrics = solve(problem, args.method, time_limit=args.time_limit, progress=progress_enabled(), qp=qp)
    plan.diagnostics["timings"] = dict(plan.diagnostics.get("timings", {}), problem_time=problem_time)
    return problem, plan, metrics


def _route_fits(args: argparse.Namespace, route: Any, n: int) -> bool:
    """Whether the precheck's route serves N = ``n`` robots: N ≥ its N_min, and either it was computed for that N
    (not ``auto``: its guide is already the chain off the route if that is what N needs) or N is at least what
    the route chain needs."""
    return n >= max(2, route.n_min) and (args.robots != "auto" or n >= route.n_route)


def _whole_planning(
    plan: Any, metrics: Any, start: float, route_time: float, other_attempts_time: float
) -> tuple[Any, Any, dict[str, float]]:
    """The plan and metrics with the whole planning time since ``start`` [s] (route, every attempt, warm start, NLP,
    checks) as ``wall_time`` (and ``ms_per_step``), and the parts for ``timings.json`` (:data:`TIMING_KEYS`)."""
    wall = time.perf_counter() - start
    plan.wall_time = wall
    steps = plan.t.size - 1
    metrics = replace(metrics, wall_time=wall, ms_per_step=1000.0 * wall / steps if steps > 0 else float("nan"))
    parts = {"route_time": route_time, "other_attempts_time": other_attempts_time}
    parts |= {key: float(v) for key, v in plan.diagnostics.get("timings", {}).items() if key in TIMING_KEYS}
    return plan, metrics, parts


def _short(reason: Any, width: int = 90) -> str:
    """The first clause of a failure reason, at most ``width`` characters (for the ``--robots auto`` summary)."""
    text = str(reason).split(";")[0].strip()
    return text if len(text) <= width else text[: width - 1] + "…"


def _extras(problem: Any, plan: Any, auto_note: str | None) -> dict[str, Any]:
    """What ``metrics.json`` records beyond the metrics: the route and its robot counts, the ``--robots auto``
    choice, and for ``horizon`` which plan it returned (optimum, best feasible iterate, or its warm start)."""
    out: dict[str, Any] = {"n_robots": problem.chain.n_robots, "route": problem.route_mode}
    if problem.route is not None:
        rt = problem.route
        out.update(route_length=rt.length, n_min=rt.n_min, n_lower=rt.n_lower, n_lower_by=rt.lower_by)
        out.update(n_route=rt.n_route)
    if auto_note:
        out["robots_auto"] = auto_note
    if problem.references is not None:
        out["references"] = plan.diagnostics.get("references", problem.references.mode)
    for key in ("references_note", "horizon_result", "horizon_note"):
        if isinstance(plan.diagnostics.get(key), str):
            out[key] = plan.diagnostics[key]
    if isinstance(plan.diagnostics.get("horizon_summary"), dict):
        out["horizon"] = plan.diagnostics["horizon_summary"]
    return out


def precheck(args: argparse.Namespace, scenario: Any) -> tuple[Any, int | None]:
    """The route and the robots it needs, before the planner (and its solvers) are even imported.

    Returns the route and the N to plan with (``args.robots``; its N_min for ``auto``). Raises
    :class:`tmr.route.route.NoRouteError` / :class:`tmr.route.route.TooFewRobotsError` /
    :class:`tmr.route.route.TooManyRobotsError`
    (exit 2) for a task proven impossible: no free route, fewer robots than the route needs, or more than fit in
    the free space at once (before the route search).
    """
    from tmr.model.params import (
        PARAM_CLASSES,
        ChainParams,
        QPParams,
        TimeParams,
        apply_overrides,
        refuse_method_limits,
        with_winch_defaults,
    )
    from tmr.model.spans import span_limits
    from tmr.route.route import TooFewRobotsError, check_fit, plan_route

    values = {"safety_radius": scenario.environment.safety_radius} | dict(scenario.params or {}) | dict(args.set)
    values = with_winch_defaults(values)[0]  # the planner's own defaults (tmr.planner.build_problem)
    rest = dict(values)
    made = {}
    try:
        for cls in PARAM_CLASSES:  # bad values: exit 2 now
            made[cls], rest = apply_overrides(cls(), rest)
    except ParameterError as exc:  # a value of the scenario's own file: say which file
        given = {k for k, _ in args.set}
        own = [k for k in (scenario.params or {}) if k not in given and re.search(rf"\b{re.escape(k)}\b", str(exc))]
        if own and scenario.source is not None:
            raise TmrError(f"scenario file {scenario.source}: {exc}") from None
        raise
    chain_params = made[ChainParams]
    if rest:
        raise TmrError(f"unknown parameter(s) {sorted(rest)}; the names are the fields of tmr.model.params")
    if scenario.goal_heading is not None and not chain_params.diff_drive:
        raise TmrError("a goal heading (--goal X,Y,THETA, goal = [x, y, theta]) needs --drive diff")
    if chain_params.diff_drive:  # exit 2 before the route: the model, its footprint, the methods that plan it
        from tmr.model.diffdrive import model_for

        model_for(chain_params.robot_model, chain_params.safety_radius)
        if args.filter_cutoff is not None:
            raise TmrError(
                "--filter-cutoff: a differential-drive plan is not filtered (its robots execute cmd_vel/robotK.csv, "
                "whose poses are the checked plan)"
            )
        if args.method not in ("qp", "horizon"):
            raise TmrError(f"--drive diff is planned by --method qp and horizon (not --method {args.method})")
    from tmr.world.environment import refuse_impassable_low_obstacles

    top = max(chain_params.exit_height, chain_params.base_height)
    refuse_impassable_low_obstacles(scenario.environment, top, chain_params.low_obstacle_clearance)
    refuse_method_limits(args.method, chain_params, made[QPParams])  # before the route (and --robots auto's N): exit 2
    if args.method == "horizon":  # before the route: exit 2
        from tmr.world.environment import refuse_low_obstacles

        refuse_low_obstacles(
            scenario.environment, "--method horizon", "its NLP keeps no cable height above them; use --method qp"
        )
    nyquist = 0.5 / made[TimeParams].Ts
    cutoff = filter_cutoff(args)
    if not chain_params.diff_drive and not cutoff < nyquist:  # refused before the route and the plan, not after them
        raise TmrError(
            f"--filter-cutoff {cutoff:g} Hz must be below the Nyquist frequency {nyquist:g} Hz "
            f"(Ts = {made[TimeParams].Ts:g} s)"
        )
    n = args.robots if isinstance(args.robots, int) else scenario.n_robots  # --start has n positions (load_inputs)
    if args.robots != "auto":  # before span_limits allocates a row per robot (--robots 10**23 is refused, not a crash)
        check_fit(scenario.environment, scenario.base, n)
    rt = plan_route(
        scenario.environment,
        scenario.base,
        scenario.goal,
        span_limits(max(n, 2), chain_params),
        robots=n if args.robots != "auto" else None,
    )
    if args.robots == "auto":
        return rt, rt.n_min
    why = rt.refusal(n)
    # a search verdict (N_min at the route's resolution) binds only the route-guided planner from its own start
    if why is not None and (n < rt.n_lower or (args.route == "shortest" and args.start is None)):
        if args.start is not None:  # --robots N takes N start positions (check_start_count)
            why += f" and {rt.n_min} --start positions (or none: computed)"
        raise TooFewRobotsError(why, rt.n_min, proven=n < rt.n_lower)
    return rt, n


#: Options whose values are coordinates: a value such as ``-2.0,0.0`` is not a flag.
_COORDINATE_OPTIONS = ("--base", "--goal", "--start", "--bounds")


def _join_negative(argv: list[str]) -> list[str]:
    """``--base -2.0,0.0`` → ``--base=-2.0,0.0`` (argparse reads a value that starts with '-' and is not a plain
    number as a flag)."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        nxt = argv[i + 1] if i + 1 < len(argv) else ""
        if tok in _COORDINATE_OPTIONS and len(nxt) > 1 and nxt[0] == "-" and (nxt[1].isdigit() or nxt[1] == "."):
            out.append(f"{tok}={nxt}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


def check_out(out: Path) -> None:
    """Refuse, before any planning, an ``--out`` that cannot take a plan (:func:`tmr.io.outdir.check_out`)."""
    from tmr.io.outdir import check_out as check

    check(out, OWNED_NAMES)


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Entry point of ``python -m tmr.plan`` and ``tmr plan`` (``prog``: the name messages use); returns the exit
    code."""
    parser = build_parser(prog)
    args = parser.parse_args(_join_negative(list(sys.argv[1:] if argv is None else argv)))
    return run_cli(_main, args)


def _figure_pool(args: argparse.Namespace) -> Any:
    """Workers that import matplotlib while the plan is computed (:mod:`tmr.views.plotpool`), when figures are wanted
    and
    there is a core to spare; else None (figures rendered in this process)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if args.no_plots or cores < 2:
        return None
    from tmr.views.plotpool import FigurePool

    try:
        return FigurePool()
    except OSError as exc:  # no processes to spare (a resource limit): render here
        LOG.debug("figures rendered in this process: %s", exc)
        return None


def _pooled(pool: Any, figures: dict[str, Any]) -> dict[str, bytes] | None:
    """The figures rendered by ``pool``; None without a pool or if its workers died (then render them here)."""
    if pool is None:
        return None
    import pickle
    from concurrent.futures.process import BrokenProcessPool

    try:
        return pool.render(figures)
    except (BrokenProcessPool, pickle.PicklingError) as exc:
        LOG.debug("figure workers stopped (%s): rendering here", exc)
        return None


def _drive_args(args: argparse.Namespace) -> None:
    """``--drive`` and ``--robot-model`` as the parameters ``drive`` and ``robot_model`` (``--robot-model`` implies
    ``--drive diff``); TmrError (exit 2) if ``--set`` gives them too."""
    given = {k for k, _ in args.set}
    extra: list[tuple[str, str]] = []
    drive = getattr(args, "drive", None)
    model = getattr(args, "robot_model", None)
    if model is not None:
        if drive == "omni":
            raise TmrError("--robot-model is a differential-drive robot: it needs --drive diff (or no --drive)")
        drive = drive or "diff"
        extra.append(("robot_model", model))  # burger -> turtlebot3_burger in the records (robot_model_arg)
    if drive is not None:
        extra.insert(0, ("drive", drive))
    twice = sorted(given & {k for k, _ in extra})
    if twice:
        raise TmrError(f"{', '.join(twice)} given twice (--drive/--robot-model and --set): give one")
    args.set = list(args.set) + extra


def _main(args: argparse.Namespace) -> int:
    from tmr.route.route import RouteVerdict

    try:
        if args.robots == "auto" and args.start is not None:
            raise TmrError("--robots auto chooses the number of robots, so it cannot take --start; give --robots N")
        if args.time_limit is not None and args.method != "horizon":
            raise TmrError(
                f"--time-limit is the horizon NLP's limit: --method {args.method} has none (add --method horizon)"
            )
        check_out(Path(args.out))
        _drive_args(args)
        if args.scenario and not args.map:
            from tmr.world.scenario import scenario_kind  # reads the file only: no 3-D import for ground

            if scenario_kind(args.scenario) == "drone":  # a tethered drone chain in 3-D (formulations/drones.md)
                if any(k in ("drive", "robot_model") for k, _ in args.set):
                    raise TmrError("--drive and --robot-model are ground robots' kinematics: not for a drone scenario")
                from tmr.plan3d import main_drones

                return main_drones(args, OWNED_NAMES, VOLATILE_NAMES)
        scenario = load_inputs(args)
        start = time.perf_counter()
        rt, n_first = precheck(args, scenario)
        route_time = time.perf_counter() - start
        env = scenario.environment
        LOG.debug(
            "map %s: room %s m, robot radius r = %g m (obstacles grown by r, robots >= %g m apart)",
            env.source or scenario.name,
            env.bounds,
            env.safety_radius,
            2 * env.safety_radius,
        )
        LOG.debug(
            "route %.3f m, N_lower = %d, N_min = %d; planning with N = %s", rt.length, rt.n_lower, rt.n_min, n_first
        )

        pool = _figure_pool(args)
        try:
            from tmr.checks.metrics import filter_within_limits

            auto_note = None
            if args.robots == "auto":
                from tmr.route.route import packing_bound

                tried = []
                fit = packing_bound(env, scenario.base).n_max  # no more robots than fit in the free space at once
                last = min(rt.n_route + AUTO_EXTRA, fit)  # n_route ≥ n_min
                capped = f" (at most {fit} robots fit in the free area)" if last < rt.n_route + AUTO_EXTRA else ""
                problem = None
                attempts_time = kept_time = 0.0  # [s]: every attempt, the one whose plan is kept
                for n in range(rt.n_min, last + 1):
                    attempt_start = time.perf_counter()
                    try:
                        attempt = _plan_once(args, scenario, n, rt, qp_first=True)
                    except TmrError as exc:  # refused, no start placement or no path with this N: try the next one
                        tried.append(f"{n}: {_short(exc)}")
                        continue
                    finally:
                        attempts_time += time.perf_counter() - attempt_start
                    problem, plan, metrics = attempt
                    kept_time = time.perf_counter() - attempt_start
                    tried.append(f"{n}: {'planned' if plan.success else _short(plan.failure)}")
                    if plan.success:
                        break
                summary_line = f"--robots auto: N_min = {rt.n_min}{capped}; " + "; ".join(tried)
                if problem is None:
                    LOG.error("no plan found: %s", summary_line)
                    return 1
                auto_note = f"{summary_line}; chose N = {problem.chain.n_robots}"
                other_attempts_time = attempts_time - kept_time
            else:
                problem, plan, metrics = _plan_once(args, scenario, n_first, rt)
                other_attempts_time = 0.0
            plan, metrics, timings = _whole_planning(plan, metrics, start, route_time, other_attempts_time)
            LOG.debug("writing the outputs")
            if getattr(plan, "heading", None) is None:
                filtered, filter_note = filter_within_limits(
                    plan, problem.env, problem.time_params.Ts, cutoff_hz=filter_cutoff(args)
                )
            else:  # differential drive: the robots execute cmd_vel/ (a low-passed pose would slip sideways)
                filtered = np.asarray(plan.robots, dtype=float).copy()
                filter_note = "differential drive: not filtered, the robots execute cmd_vel/robot1.csv …"
            extra = _extras(problem, plan, auto_note) | ({"filter_note": filter_note} if filter_note else {}) | timings
            from tmr.io.outdir import Stage

            with Stage(args.out, OWNED_NAMES, VOLATILE_NAMES) as stage:  # everything staged, then one publication
                write_outputs(
                    stage.path,
                    plan,
                    metrics,
                    problem.env,
                    filtered,
                    not args.no_plots,
                    extra,
                    route=problem.route,
                    pool=pool,
                )
                write_views(args, stage.path, lambda: chain_motion(plan, problem.env, problem.chain_params))
                names = stage.publish()
        except BaseException:
            if pool is not None:  # Ctrl-C or an error: do not wait for a figure being rendered
                pool.terminate()
                pool = None
            raise
        finally:
            if pool is not None:
                pool.close()
    except (RouteVerdict, NoPathFound) as exc:  # a verdict of a search (not proven impossible): exit 1
        if getattr(exc, "proven", False):
            raise  # a TmrError: one line, exit 2 (tmr.io.console.run)
        LOG.error("no plan found: %s", exc)
        return 1
    if auto_note:
        LOG.info(auto_note)
    LOG.info(summary(plan, metrics))
    if "filter_note" in extra:
        LOG.info("  filter: %s", extra["filter_note"])
    if "references_note" in extra:
        LOG.info("  references: %s", extra["references_note"])
    if "horizon_note" in extra:
        nlp = plan.diagnostics.get("timings", {}).get("nlp_time", math.nan)
        LOG.info("  horizon: %s (the NLP ran %.1f s): %s", extra["horizon_result"], nlp, extra["horizon_note"])
    LOG.info("  wrote %s to %s", ", ".join(names), args.out)
    if not plan.success:
        LOG.error("plan FAILED: %s", plan.failure)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
