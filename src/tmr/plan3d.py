"""The drone branch of ``tmr plan``: a scenario with ``kind = "drone"`` (built-in F, G, H or a TOML file) is planned
by :mod:`tmr.planner3d` and written by :mod:`tmr.io.drones` and :mod:`tmr.views.drones` (``formulations/drones.md``).

Same verdicts as the ground chain: exit 0 a plan that passed every check of the independent checker
(:mod:`tmr.checks.drones`); 1 no plan found or a check failed (outputs of a computed plan written, the reason
printed); 2 bad input or a task proven impossible up front (no free route, fewer drones than the proven bound: one
line, nothing written). Options of the ground chain that have no meaning for drones are refused with one line;
``--seed`` is accepted and changes nothing (the drone pipeline has no random part: its route is a lattice search).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from tmr.errors import TmrError
from tmr.io.console import LOG, progress_enabled

#: The figures of a drone plan (:func:`tmr.views.drones.figures`), written into ``--out`` unless ``--no-plots``.
DRONE_FIGURES = ("chain_poses_3d.png", "altitude.png", "tether_clearance.png", "tensions.png")


def _refuse_ground_options(args: argparse.Namespace) -> None:
    """One line for every option that a drone scenario does not take (exit 2)."""
    given = [
        flag
        for flag, value in (
            ("--map", args.map),
            ("--base", args.base),
            ("--goal", args.goal),
            ("--start", args.start),
            ("--bounds", args.bounds),
            ("--iterations", args.iterations),
        )
        if value is not None
    ]
    if given:
        raise TmrError(
            f'{", ".join(given)}: not taken by a drone scenario (kind = "drone"): its base, goal and world are in '
            "the scenario file"
        )
    if args.filter_cutoff is not None:
        raise TmrError("--filter-cutoff: a drone plan is written as checked, without a trajectory filter")
    if args.route != "shortest":
        raise TmrError(f"--route {args.route}: a drone chain follows its 3-D shortest route (--route shortest)")


def load_drone_inputs(args: argparse.Namespace) -> Any:
    """The drone scenario of ``--scenario``, with ``--robot-radius`` (or ``--set drone_radius=``) applied to the
    world, the scenario's record and the tether's drone radius at once."""
    from tmr.world.drones import load_drone_scenario

    sc = load_drone_scenario(args.scenario)
    radii = {float(v) for k, v in args.set if k in ("safety_radius", "drone_radius")}
    if args.robot_radius is not None:
        radii.add(float(args.robot_radius))
    if len(radii) > 1:
        raise TmrError(f"two drone radii given: {sorted(radii)} m; give one (--robot-radius R)")
    if radii:
        r = radii.pop()
        sc = replace(
            sc,
            world=sc.world.with_safety_radius(r),
            world_table={**sc.world_table, "safety_radius": r},
            tether=replace(sc.tether, drone_radius=r),
        )
    return sc


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    out = {k: v for k, v in args.set if k not in ("safety_radius", "drone_radius")}
    if args.solver:
        out["solver"] = args.solver
    return out


def summary(plan: Any, metrics: Any) -> str:
    """The run's summary lines: verdict, the fitness, every limit's least margin and where it binds."""
    lines = [
        f"tmr plan: drone scenario {plan.scenario}, method {plan.method}, {plan.n_robots} drones, "
        f"{plan.t.size - 1} steps ({plan.t[-1]:.2f} s)"
    ]
    rows = [
        ("success", metrics.success),
        ("failure", metrics.failure),
        ("f1 f2 f3 f4", " ".join(f"{v:.6g}" for v in (metrics.f1, metrics.f2, metrics.f3, metrics.f4))),
        ("leader_path_length", metrics.leader_path_length),
        ("final_leader_error", metrics.final_leader_error),
        ("min_drone_clearance", metrics.min_drone_clearance),
        ("min_separation", metrics.min_separation),
        ("min_tether_clearance", metrics.min_tether_clearance),
        ("max_tether_length", metrics.max_tether_length),
        ("max_drone_tension", metrics.max_drone_tension),
        ("peak_speed", metrics.peak_speed),
        ("peak_acceleration", metrics.peak_acceleration),
        ("binding_limit", metrics.binding_limit),
        ("wall_time", plan.wall_time),
    ]
    notes = {
        "min_drone_clearance": "m beyond r",
        "min_separation": "m between centres",
        "min_tether_clearance": "m, whole curves",
        "peak_speed": "m/s, per axis",
        "peak_acceleration": "m/s², per axis",
        "max_drone_tension": "N at a drone end",
        "wall_time": "s",
    }
    for key, value in rows:
        text = f"{value:.6g}" if isinstance(value, float) else f"{value}"
        lines.append(f"  {key:24s} {text}" + (f"  ({notes[key]})" if key in notes else ""))
    tc = metrics.binding.get("tether_clearance")
    if tc:
        lines.append(
            f"  {'tether curve closest':24s} {tc['what']} at t = {tc['t']:.2f} s: curve {tc['curve_clearance']:.3f} m, "
            f"chord {tc['chord_clearance']:.3f} m (c_t {metrics.tether_clearance_limit:g} m)"
        )
    wm = getattr(metrics, "winch", None)
    if wm:
        lines.append(
            f"  {'winch (active)':24s} T_w {wm['min_tension_used']:.3f} .. {wm['max_tension_used']:.3f} N used, "
            f"|dT_w/dt| <= {wm['max_rate_used']:.3f} N/s (range [{wm['tension_min']:g}, {wm['tension_max']:g}] N, "
            f"rate {wm['tension_rate']:g} N/s)"
        )
    return "\n".join(lines)


def main_drones(args: argparse.Namespace, owned: tuple[str, ...], volatile: tuple[str, ...]) -> int:
    """``tmr plan`` for a drone scenario (``args`` already parsed; ``--out`` already checked). Returns the exit code."""
    from tmr.planner3d import plan_drones
    from tmr.route.route3d import StartError

    _refuse_ground_options(args)
    scenario = load_drone_inputs(args)
    start = time.perf_counter()
    details: dict[str, Any] = {}
    try:
        plan, metrics = plan_drones(
            scenario, args.robots, args.method, overrides=_overrides(args), progress=progress_enabled(),
            details=details, time_limit=args.time_limit,
        )  # fmt: skip
    except StartError as exc:  # a verdict of the start search along the route, not a proof: no plan found
        LOG.error("no plan found: %s", exc)
        return 1
    route = details.get("route")
    extra: dict[str, Any] = {"n_robots": plan.n_robots}
    for key in ("route_length", "route_lower_bound", "n_min", "robots_auto", "slowed_down", "horizon_result",
                "horizon_note"):  # fmt: skip
        if key in plan.diagnostics:
            extra[key] = plan.diagnostics[key]
    if isinstance(plan.diagnostics.get("horizon_summary"), dict):
        extra["horizon"] = plan.diagnostics["horizon_summary"]
    timings = {k: float(v) for k, v in plan.diagnostics.get("timings", {}).items()}
    extra |= {k: v for k, v in timings.items() if k.endswith("_time")}
    from tmr.io.drones import write_drone_outputs
    from tmr.io.outdir import Stage

    with Stage(args.out, owned, volatile) as stage:  # staged, then published in one step (tmr.io.outdir)
        write_drone_outputs(stage.path, plan, metrics, scenario, extra=extra)
        if not args.no_plots or args.gif or args.html or args.export:  # matplotlib only then (0.4 s to import)
            from tmr.views.drones import save_figures, write_drone_views

            if not args.no_plots:
                save_figures(plan, scenario.world, stage.path, route=route)  # the DRONE_FIGURES
            write_drone_views(
                plan, scenario.world, stage.path, gif=args.gif, html=args.html, export=args.export,
                progress=progress_enabled(),
            )  # fmt: skip
        published = stage.publish()
    LOG.debug("drone run written in %.2f s after planning", time.perf_counter() - start - plan.wall_time)
    if "robots_auto" in extra:
        LOG.info("--robots auto: %s; chose N = %d", extra["robots_auto"], plan.n_robots)
    LOG.info(summary(plan, metrics))
    if "slowed_down" in extra:
        LOG.info(
            "  slowed down              at %s (the hard limits had no common solution at full speed: the plan went "
            "back 1 s and took the next 3 s of the route at half speed)",
            ", ".join(extra["slowed_down"]),
        )
    if "horizon_note" in extra:
        nlp = plan.diagnostics.get("timings", {}).get("nlp_time", float("nan"))
        LOG.info("  horizon: %s (the NLP ran %.1f s): %s", extra["horizon_result"], nlp, extra["horizon_note"])
    LOG.info("  wrote %s to %s", ", ".join(published), Path(args.out))
    if not plan.success:
        LOG.error("plan FAILED: %s", plan.failure)
        return 1
    return 0
