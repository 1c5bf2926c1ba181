"""Command line: ``python -m tmr.mcdpr plan --scene fig2 --out runs/mcdpr``.

Plans a MoPICK-type MCDPR task with the two-stage planner (Rasheed 2019 sec. 5), checks the result (μ > 0, cable
tensions within the tipping-tightened bounds, no base collision), and writes ``plan.json``, ``bases.csv``,
``platform.csv`` and the figures ``topview.png``, ``mu.png``, ``tensions.png`` into ``--out``. Inputs are validated
before anything is written (``--out`` must be, or become, a directory, and hold no file tmr did not write under an
output's name); the files are staged and published into ``--out`` in one step (:mod:`tmr.io.outdir`): outputs an older
run wrote in ``--out`` that this run does not produce (e.g. the figures after ``--no-plots``) are removed, other
files are never touched. The planner is deterministic (no random choices): same inputs, same bytes.

Exit codes: 0 plan succeeded; 1 plan computed but a guarantee fails (outputs written, reason printed);
2 bad input or planning error (nothing written).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from tmr.errors import TmrError, fmt_point
from tmr.io.cli_args import ArgumentParser, add_common, count, path_arg, points
from tmr.io.cli_args import positive_float as _positive
from tmr.io.console import LOG, progress_enabled
from tmr.io.console import run as run_cli
from tmr.mcdpr.motion import mcdpr_motion
from tmr.views.flags import VIEW_NAMES, write_views

PLAN_FORMAT = "tmr-mcdpr-plan/1"


def _triple(text: str) -> tuple[float, float, float]:
    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected FX,FY,FZ in newtons, got {text!r}") from exc
    if len(parts) != 3 or not all(math.isfinite(v) and v >= 0 for v in parts):
        raise argparse.ArgumentTypeError(f"expected three non-negative finite numbers FX,FY,FZ, got {text!r}")
    return parts[0], parts[1], parts[2]


#: The smallest step of the search and of the planners' grids [m]: a finer one would not finish (1e-300 asks for
#: 1e300 stations).
MIN_STEP = 1e-3
#: The most B-spline samples per iterate (``--upsample``).
MAX_UPSAMPLE = 1000


def _step(text: str) -> float:
    """A length step [m] of the planners: finite, ≥ :data:`MIN_STEP`."""
    v = _positive(text)
    if v < MIN_STEP:
        raise argparse.ArgumentTypeError(f"must be ≥ {MIN_STEP:g} m, got {text!r}")
    return v


def _upsample(text: str) -> int:
    v = count(text)
    if v > MAX_UPSAMPLE:
        raise argparse.ArgumentTypeError(f"must be ≤ {MAX_UPSAMPLE}, got {v}")
    return v


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``python -m tmr.mcdpr``; ``prog``: the name it shows (``tmr mcdpr`` through the dispatcher)."""
    p = ArgumentParser(
        prog=prog or "python -m tmr.mcdpr",
        description="Mobile cable-driven parallel robot (MoPICK, Rasheed 2019) tools.",
    )
    sub = p.add_subparsers(dest="command", required=True)
    pl = sub.add_parser("plan", help="path planning of the bases and the platform (search or the paper's greedy)")
    pl.add_argument(
        "--scene", type=path_arg, default="fig2", help="built-in scene name (fig2) or a scene TOML file (default fig2)"
    )
    pl.add_argument("--robot", type=path_arg, help="robot TOML file (default: the shipped MoPICK description)")
    pl.add_argument(
        "--planner",
        choices=("search", "greedy"),
        default="search",
        help="search: placement graph + certified μ between samples (default); greedy: Rasheed 2019 two-stage",
    )
    pl.add_argument(
        "--tension",
        choices=("closed-form", "qp", "lp"),
        default="closed-form",
        help="tension distribution: null-space closed form (min 2-norm), qp (min 2-norm, DAQP), lp (min-max, HiGHS)",
    )
    pl.add_argument("--station-step", type=_step, default=0.25, help="search: platform station spacing [m]")
    pl.add_argument("--margin", type=_positive, default=0.3, help="search: μ of a placement at any heading [N]")
    pl.add_argument("--max-move", type=_step, default=0.6, help="search: base move per graph edge [m] (0.6)")
    pl.add_argument("--d-base", type=_step, default=0.2, help="base step d_j of the stage-1 grid [m] (0.2)")
    pl.add_argument("--min-step", type=_step, default=0.05, help="smallest retried base step [m] (0.05)")
    pl.add_argument("--d-platform", type=_step, default=0.05, help="platform step d_MP of stage 2 [m] (0.05)")
    pl.add_argument("--max-iter", type=count, default=200, help="stage-1 iterations per way-point (200)")
    pl.add_argument("--upsample", type=_upsample, default=10, help="B-spline samples per iterate (10)")
    pl.add_argument("--external", type=_triple, help="external wrench box half-widths FX,FY,FZ [N] (scene's)")
    add_common(pl, out="runs/mcdpr", seed_help="search: seed of the random base moves round the best placements")
    ws = sub.add_parser("workspace", help="map of μ over platform positions with the bases parked (wrench-feasible)")
    ws.add_argument(
        "--scene", type=path_arg, default="fig2", help="built-in scene name or scene TOML file (default fig2)"
    )
    ws.add_argument("--robot", type=path_arg, help="robot TOML file (default: the shipped MoPICK description)")
    ws.add_argument("--bases", type=points, help="parked bases X1,Y1;X2,Y2;... [m] (default: the scene's start)")
    ws.add_argument("--z", type=_positive, help="platform height [m] (default: the first task point's)")
    ws.add_argument("--cell", type=_positive, default=0.05, help="grid cell [m] (0.05)")
    ws.add_argument("--external", type=_triple, help="external wrench box half-widths FX,FY,FZ [N] (scene's)")
    add_common(ws, out="runs/mcdpr_workspace", progress=False, views=False)  # deterministic, no bar, no motion
    return p


#: Files written by ``workspace``.
WORKSPACE_NAMES = ("workspace.json", "workspace.csv", "workspace.png")


def _inputs(args: argparse.Namespace) -> tuple[Path, Any, Any]:
    """The checked ``--out``, the robot (``--robot`` or the shipped MoPICK) and the scene (with ``--external``)
    of a ``plan`` or ``workspace`` run; TmrError (exit 2) on bad input."""
    import dataclasses

    from tmr.io.outdir import check_out
    from tmr.mcdpr.robot import load_robot, mopick
    from tmr.mcdpr.scene import load_scene

    out = Path(args.out)
    check_out(out, OWNED_NAMES if args.command == "plan" else WORKSPACE_NAMES)
    robot = load_robot(args.robot) if args.robot else mopick()
    scene = load_scene(args.scene)
    if args.external is not None:
        scene = dataclasses.replace(scene, external=np.array(args.external))
    return out, robot, scene


def workspace_main(args: argparse.Namespace) -> int:
    """``python -m tmr.mcdpr workspace``: μ map (CSV), summary (JSON) and figure; exit 2 on bad input (nothing
    written)."""
    import dataclasses

    from tmr.io.outputs import atomic_write_text
    from tmr.mcdpr.capacity import required_wrench_set
    from tmr.mcdpr.plot import plot_workspace
    from tmr.mcdpr.workspace import workspace

    try:
        out, robot, scene = _inputs(args)
        if args.bases is not None:
            if len(args.bases) != robot.n_bases:
                raise TmrError(f"--bases: {robot.n_bases} base positions needed, got {len(args.bases)}")
            scene = dataclasses.replace(scene, bases=np.array(args.bases, dtype=float))
        scene.validate(robot)
        z = float(scene.tasks[0, 2]) if args.z is None else args.z
        t0 = time.perf_counter()
        rws = required_wrench_set(robot, scene.external)
        ws = workspace(robot, scene.bases, scene.headings, rws, scene.bounds, z, args.cell)
        wall = time.perf_counter() - t0
        k = int(np.argmax(ws.mu))
        summary = {
            "format": "tmr-mcdpr-workspace/1",
            "robot": robot.name,
            "scene": scene.name,
            "bases": scene.bases,
            "headings": scene.headings,
            "external": scene.external,
            "z": ws.z,
            "cell": ws.cell,
            "nx": len(ws.x),
            "ny": len(ws.y),
            "area_feasible_m2": ws.area,
            "mu_max": float(ws.mu.flat[k]),
            "mu_max_at": [float(ws.x[k % len(ws.x)]), float(ws.y[k // len(ws.x)])],
        }
        X, Y = np.meshgrid(ws.x, ws.y)
        from tmr.io.outdir import Stage

        with Stage(out, WORKSPACE_NAMES) as stage:  # staged, then published in one step (tmr.io.outdir)
            tmp = stage.path
            atomic_write_text(tmp / "workspace.json", json.dumps(_jsonable(summary), indent=1, sort_keys=True) + "\n")
            floats = np.column_stack([X.ravel(), Y.ravel(), ws.mu.ravel()])
            atomic_write_text(tmp / "workspace.csv", _csv(["x", "y", "mu"], np.zeros((X.size, 0), int), floats))
            if not args.no_plots:
                plot_workspace(robot, scene, ws, scene.bases, tmp / "workspace.png")
            names = stage.publish()
    except TmrError as exc:
        LOG.error(f"error: {exc}")
        return 2
    except OSError as exc:
        LOG.error(f"error: cannot write the outputs to {args.out}: {exc}")
        return 2
    LOG.info(f"tmr.mcdpr workspace: robot {robot.name}, scene {scene.name}, z = {ws.z:g} m, {ws.mu.size} positions")
    at = fmt_point(summary["mu_max_at"])
    LOG.info(f"  feasible area {ws.area:.4g} m² (μ > 0), max μ {summary['mu_max']:.4g} N at {at}")
    LOG.info(f"  wall_time     {wall:.3f} s")
    LOG.info(f"  wrote {', '.join(names)} to {args.out}")
    return 0


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def plan_dict(robot: Any, scene: Any, params: Any, result: Any, chk: Any) -> dict[str, Any]:
    """Everything of a plan as a JSON-able mapping (no wall times, so the bytes are reproducible)."""
    import dataclasses

    return _jsonable(
        {
            "format": PLAN_FORMAT,
            "robot": robot.name,
            "scene": scene.name,
            "params": dataclasses.asdict(params),
            "external": scene.external,
            "waypoints": result.waypoints,
            "planner": result.planner,
            "tension_method": result.tension_method,
            "search": result.search,
            "check": {
                "ok": chk.ok,
                "mu_min": chk.mu_min,
                "mu_between": chk.mu_between,
                "nonpositive_samples": list(chk.nonpositive),
                "tension_ok": chk.tension_ok,
                "collision_free": chk.collision_free,
                "waypoints_ok": chk.waypoints_ok,
                "steps_ok": chk.steps_ok,
                "max_tension": chk.max_tension,
                "messages": list(chk.messages),
            },
            "stage1": [
                {
                    "iterations": len(s["mu"]) - 1,
                    "mu": s["mu"],
                    "smoothed": s["smoothed"],
                    "combinations_scored": s["combinations"],
                    "iterates": s["iterates"],
                }
                for s in result.stage1
            ],
            "samples": {
                "segment": result.segment,
                "bases": result.bases,
                "headings": result.headings,
                "platform": result.platform,
                "mu": result.mu,
                "tensions": result.tensions,
                "tension_upper_bounds": result.hi,
                "mu_lower_between": result.mu_lower,
            },
        }
    )


def _csv(header: list[str], ints: np.ndarray, floats: np.ndarray) -> str:
    """CSV text: integer columns, then floats in shortest round-trip form (empty for NaN)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for irow, frow in zip(ints.tolist(), floats.tolist(), strict=True):
        w.writerow([*irow, *(repr(v) if math.isfinite(v) else "" for v in frow)])
    return buf.getvalue()


#: Every file name ``plan`` may write; a run deletes those of them it did not produce (stale ones of an older run).
OUTPUT_NAMES = ("plan.json", "run.json", "bases.csv", "platform.csv", "topview.png", "mu.png", "tensions.png")
#: Every entry of ``--out`` a plan owns: its files, its views and the physics replay of the plan (``replay/``).
OWNED_NAMES = OUTPUT_NAMES + VIEW_NAMES + ("replay",)


def write_outputs(
    out: Path, robot: Any, scene: Any, env: Any, params: Any, result: Any, chk: Any, plots: bool
) -> list[str]:
    """Write every output of a plan into the directory ``out`` (the staging directory of a
    :class:`tmr.io.outdir.Stage` from the command line); return the names written."""
    from tmr.io.outputs import atomic_write_text

    tmp = Path(out)
    tmp.mkdir(parents=True, exist_ok=True)
    text = json.dumps(plan_dict(robot, scene, params, result, chk), indent=1, sort_keys=True)
    atomic_write_text(tmp / "plan.json", text + "\n")
    from tmr.mcdpr.rundir import write_mcdpr_run

    write_mcdpr_run(tmp / "run.json", robot, scene, params)  # robot and scene geometry (tmr.replay)
    T, p = result.bases.shape[:2]
    ints = np.column_stack([np.arange(T), result.segment])
    brows = np.hstack([result.bases.reshape(T, -1), result.headings])
    bhead = ["sample", "segment"] + [f"{c}{j + 1}" for j in range(p) for c in ("x", "y")]
    bhead += [f"heading{j + 1}" for j in range(p)]
    atomic_write_text(tmp / "bases.csv", _csv(bhead, ints, brows))
    m = result.tensions.shape[1]
    prows = np.hstack([result.platform, result.mu[:, None], result.tensions, result.hi])
    phead = ["sample", "segment", "x", "y", "z", "mu"] + [f"t{k + 1}" for k in range(m)]
    phead += [f"t{k + 1}_max" for k in range(m)]
    atomic_write_text(tmp / "platform.csv", _csv(phead, ints, prows))
    if plots:
        from tmr.mcdpr import plot

        plot.plot_topview(robot, scene, env, result, tmp / "topview.png")
        plot.plot_mu(result, tmp / "mu.png")
        plot.plot_tensions(robot, result, tmp / "tensions.png")
    return sorted(q.name for q in tmp.iterdir())


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Entry point of ``python -m tmr.mcdpr`` and ``tmr mcdpr`` (``prog``: the name messages use); returns the exit
    code (module doc)."""
    args = build_parser(prog).parse_args(argv)
    return run_cli(_main, args)  # --quiet/--verbose/--debug, one-line errors (exit 2), Ctrl-C (130)


def _main(args: argparse.Namespace) -> int:
    if args.command == "workspace":
        return workspace_main(args)
    try:
        from tmr.mcdpr.capacity import capacity, required_wrench_set
        from tmr.mcdpr.errors import NoPlanFound
        from tmr.mcdpr.planner import PlannerParams, check, plan
        from tmr.mcdpr.search import SearchParams, plan_search, refuse_upfront

        out, robot, scene = _inputs(args)
        if args.min_step > args.d_base:
            raise TmrError(f"--min-step ({args.min_step} m) must not exceed --d-base ({args.d_base} m)")
        params = PlannerParams(
            d_base=args.d_base,
            min_step=args.min_step,
            d_platform=args.d_platform,
            max_iter=args.max_iter,
            upsample=args.upsample,
        )
        env = scene.validate(robot)
        t0 = time.perf_counter()
        if args.planner == "search":
            params = SearchParams(
                station_step=args.station_step,
                margin=args.margin,
                max_move=args.max_move,
                d_platform=args.d_platform,
                seed=args.seed,
            )
            try:
                result = plan_search(robot, scene, params, progress=progress_enabled())
            except NoPlanFound as exc:
                LOG.error(f"no plan found ({exc.kind}): {exc}")
                LOG.error(f"  searched for {time.perf_counter() - t0:.3f} s; nothing written")
                return 1
        else:
            refuse_upfront(robot, scene, required_wrench_set(robot, scene.external))
            result = plan(robot, scene, params, env)
        wall = time.perf_counter() - t0
        if args.tension != "closed-form":
            from tmr.mcdpr.tension import distribute

            cap = capacity(
                robot, result.platform, result.bases, result.headings, required_wrench_set(robot, scene.external)
            )
            weight = np.array([0.0, 0.0, robot.platform_mass * robot.gravity])
            result.tensions = distribute(args.tension, cap.W, weight, cap.lo, cap.hi)
            result.tension_method = args.tension
        chk = check(robot, env, result)
        from tmr.io.outdir import Stage

        with Stage(out, OWNED_NAMES) as stage:  # staged, then published in one step (tmr.io.outdir)
            write_outputs(stage.path, robot, scene, env, params, result, chk, not args.no_plots)
            write_views(args, stage.path, lambda: mcdpr_motion(robot, scene, result))
            names = stage.publish()
    except TmrError as exc:
        LOG.error(f"error: {exc}")
        return 2
    LOG.info(
        f"tmr.mcdpr plan: robot {robot.name}, scene {scene.name}, {len(result.waypoints)} way-points, "
        f"{len(result.mu)} samples"
    )
    LOG.info(f"  mu_min        {chk.mu_min:.6g} N")
    LOG.info(f"  max_tension   {chk.max_tension:.6g} N (t_max {robot.t_max:g} N)")
    LOG.info(f"  collision     {'none' if chk.collision_free else 'YES'}")
    LOG.info(f"  way-points    {'all reached' if chk.waypoints_ok else 'MISSED'}, steps <= d_MP: {chk.steps_ok}")
    if result.planner == "search":
        info = result.search
        LOG.info(f"  mu_between    >= {info['mu_lower_min']:.6g} N guaranteed between samples")
        LOG.info(
            f"  search        {info['stations']} stations, {info['nodes']} placements, {info['edges']} motions, "
            f"{info['rounds']} round(s), {info['smoothed_nodes']} nodes after shortcuts"
        )
    else:
        LOG.info(
            f"  stage1        {result.times['stage1']:.3f} s, "
            f"{sum(s['combinations'] for s in result.stage1)} combinations scored"
        )
        LOG.info(f"  stage2        {result.times['stage2']:.3f} s")
    LOG.info(f"  wall_time     {wall:.3f} s")
    LOG.info(f"  wrote {', '.join(names)} to {args.out}")
    if not chk.ok:
        LOG.error("plan FAILED: " + "; ".join(chk.messages))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
