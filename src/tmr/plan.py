"""Command line: ``python -m tmr.plan --scenario A --method pinv --out runs/A``.

Plans the chain for a scenario (built-in A–D, a scenario TOML file, or a map with ``--base/--goal``), checks every
hard constraint on the recorded states, writes trajectories (JSON + CSV), metrics (JSON) and figures into ``--out``,
and prints a metrics summary. Inputs are validated before anything is written; all files are written to a temporary
directory first and moved into ``--out`` only when every one of them is complete.

Exit codes: 0 plan succeeded; 1 plan computed but failed a constraint (outputs written, reason printed);
2 bad input or planning error (nothing written).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from tmr.cli_args import positive_int as _positive_int
from tmr.errors import TmrError


def _xy(text: str) -> tuple[float, float]:
    try:
        parts = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}") from exc
    if len(parts) != 2 or not all(np.isfinite(parts)):
        raise argparse.ArgumentTypeError(f"expected two finite numbers X,Y, got {text!r}")
    return parts[0], parts[1]


def _points(text: str) -> np.ndarray:
    pts = [_xy(p) for p in text.split(";") if p.strip()]
    if not pts:
        raise argparse.ArgumentTypeError("expected robot positions 'x1,y1;x2,y2;...'")
    return np.array(pts)


def _param(text: str) -> tuple[str, float]:
    key, sep, value = text.partition("=")
    try:
        val = float(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}") from exc
    if not sep or not key or not np.isfinite(val):
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with a finite value, got {text!r}")
    return key, val


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m tmr.plan",
        description="Plan the motion of a chain of tethered mobile robots (Caruso 2021) and write trajectories, "
        "metrics and figures.",
    )
    src = p.add_argument_group("scenario")
    src.add_argument("--scenario", help="built-in scenario A, B, C, D, or a path to a scenario TOML file")
    src.add_argument("--map", help="map file: ROS map_server .yaml (+ .pgm), .geojson or .wkt (needs --base, --goal)")
    src.add_argument("--bounds", help="room bounds xmin,ymin,xmax,ymax for a GeoJSON/WKT --map")
    src.add_argument("--base", type=_xy, help="tether anchor X,Y [m]")
    src.add_argument("--goal", type=_xy, help="leader goal X,Y [m]")
    src.add_argument("--start", type=_points, help="robot start positions 'x1,y1;x2,y2;...' [m] (default: computed)")
    src.add_argument("--robots", type=_positive_int, help="number of robots N (default: the scenario's, 3)")
    p.add_argument(
        "--method",
        default="pinv",
        choices=["pinv", "qp", "horizon"],
        help="pinv: the paper's pseudoinverse CLIK; qp: lexicographic QP with hard constraints; horizon: whole-horizon "
        "NLP (CasADi/IPOPT) warm-started from qp (default: pinv)",
    )
    p.add_argument(
        "--solver",
        help="QP solver for --method qp: osqp (persistent workspace, default) or a qpsolvers "
        "backend (daqp, proxqp, clarabel, qpsolvers-osqp, ...)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the leader's RRT* (default 0)")
    p.add_argument("--iterations", type=_positive_int, help="RRT* iterations (default 1000)")
    p.add_argument(
        "--set",
        type=_param,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a parameter, e.g. --set d_min=0.6 (repeatable)",
    )
    p.add_argument("--filter-cutoff", type=float, default=1.0, help="cut-off of the trajectory filter [Hz]")
    p.add_argument("--out", default="runs/plan", help="output directory (default runs/plan)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    return p


def load_inputs(args: argparse.Namespace) -> Any:
    """Scenario object from the arguments (built-in, TOML, or map + base + goal)."""
    from dataclasses import replace

    from tmr.scenario import load_scenario, scenario_from_map

    if args.map:
        if args.scenario:
            raise TmrError("give either --scenario or --map, not both")
        if args.base is None or args.goal is None:
            raise TmrError("--map needs --base X,Y and --goal X,Y")
        kwargs: dict[str, Any] = {}
        if args.bounds:
            try:
                b = tuple(float(v) for v in args.bounds.split(","))
            except ValueError as exc:
                raise TmrError(f"--bounds must be xmin,ymin,xmax,ymax, got {args.bounds!r}") from exc
            kwargs["bounds"] = b
        sc = scenario_from_map(args.map, args.base, args.goal, start=args.start, n_robots=args.robots or 3, **kwargs)
    else:
        sc = load_scenario(args.scenario or "A")
        changes: dict[str, Any] = {}
        if args.base is not None:
            changes["base"] = np.array(args.base)
        if args.goal is not None:
            changes["goal"] = np.array(args.goal)
        if changes:
            sc = replace(sc, **changes)
    return sc


def write_outputs(out: Path, plan: Any, metrics: Any, env: Any, filtered: np.ndarray, plots: bool) -> list[str]:
    """Write every output into a temporary sibling directory, then move the files into ``out``."""
    from tmr import io

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        io.write_trajectories_json(plan, tmp / "trajectories.json", filtered=filtered)
        io.write_trajectories_csv(plan, tmp / "trajectories.csv", filtered=filtered)
        io.write_metrics_json(metrics.to_dict(), tmp / "metrics.json")
        if plots:
            from tmr import plot

            figs = {
                "chain_poses.png": plot.plot_chain_poses(plan, env),
                "trajectories.png": plot.plot_trajectories(plan, filtered),
                "distance_errors.png": plot.plot_distance_errors(plan),
                "speeds.png": plot.plot_speeds(plan, filtered),
            }
            for name, fig in figs.items():
                plot.save_figure(fig, tmp / name)
        out.mkdir(parents=True, exist_ok=True)
        names = sorted(p.name for p in tmp.iterdir())
        for name in names:
            os.replace(tmp / name, out / name)
        return names
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


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
        "max_abs_distance_error",
        "final_leader_error",
        "violations",
        "wall_time",
        "ms_per_step",
    ]
    lines = [
        f"tmr plan: scenario {plan.scenario}, method {plan.method}, {plan.n_robots} robots, {plan.t.size - 1} steps"
    ]
    for k in keys:
        v = d[k]
        lines.append(f"  {k:24s} {v:.6g}" if isinstance(v, float) else f"  {k:24s} {v}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        from tmr.metrics import filter_trajectories
        from tmr.planner import build_problem, solve

        scenario = load_inputs(args)
        problem = build_problem(
            scenario,
            seed=args.seed,
            n_robots=args.robots,
            start=args.start,
            overrides=dict(args.set) | ({"solver": args.solver} if args.solver else {}),
            path_iterations=args.iterations,
        )
        plan, metrics = solve(problem, args.method)
        filtered = filter_trajectories(plan.robots, problem.time_params.Ts, cutoff_hz=args.filter_cutoff)
        names = write_outputs(Path(args.out), plan, metrics, problem.env, filtered, not args.no_plots)
    except TmrError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(summary(plan, metrics))
    print(f"  wrote {', '.join(names)} to {args.out}")
    if not plan.success:
        print(f"plan FAILED: {plan.failure}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
