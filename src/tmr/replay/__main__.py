"""Command line: ``python -m tmr.replay RUN_DIR [--gif]``.

Replays the plan of a ``tmr.plan`` output directory (a tethered ground chain or a drone chain) or of ``tmr.mcdpr
plan`` (MoPICK) in MuJoCo,
writes ``RUN_DIR/replay/`` (``replay.json``, ``timing.json``, figures, optionally ``replay.gif``) and prints the
verdict.

Exit codes: 0 the replay confirms the plan (every check passed); 1 it does not (the first reason printed: which
check, when, where, by how much); 2 bad input (a missing, older or corrupt run directory, a bad option, an
``--out`` that cannot take the replay): one line on stderr, nothing written. The outputs are staged and published
into ``--out`` in one step (:mod:`tmr.io.outdir`).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from tmr.errors import TmrError
from tmr.io.cli_args import ArgumentParser, add_common, count, path_arg, positive_float, robot_model_arg
from tmr.io.console import LOG, progress_enabled
from tmr.io.console import run as run_command

#: Every file ``tmr replay`` may write into its ``--out`` (chain, drone-chain and MoPICK replays).
OWNED_NAMES = (
    "replay.json",
    "timing.json",
    "tether_heights.png",
    "tensions.png",
    "tracking.png",
    "topview.png",
    "rotor_thrust.png",
    "mcdpr_replay.png",
    "replay.gif",
)
#: Outputs whose bytes change from run to run.
VOLATILE_NAMES = ("timing.json",)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``python -m tmr.replay``; ``prog``: the name it shows (``tmr replay`` through the dispatcher)."""
    p = ArgumentParser(
        prog=prog or "python -m tmr.replay",
        description="Replay a plan in the MuJoCo physics engine and check that it holds up: tethers off the floor "
        "and the obstacles, robots on their trajectories (tmr.plan: ground chains; drone chains flown by quadrotors "
        "within their thrust), or the MoPICK platform held with its bases on the ground (tmr.mcdpr plan).",
    )
    p.add_argument("run", type=path_arg, help="output directory of tmr.plan or tmr.mcdpr plan")
    p.add_argument("--gif", action="store_true", help="also write replay.gif, rendered offscreen from the simulation")
    p.add_argument("--links", type=count, help="links per tether (chain, default 16)")
    p.add_argument("--timestep", type=_timestep, help="physics step [s] (default 0.005; must divide Ts)")
    p.add_argument(
        "--track",
        choices=["filtered", "raw"],
        help="ground chains: trajectory the robots track: the filtered one a robot is given (default) or the "
        "planner's raw one",
    )
    p.add_argument(
        "--tolerance", type=positive_float, help="tracking error that fails the replay [m] (0.05; drones 0.1)"
    )
    p.add_argument(
        "--tether-density",
        type=positive_float,
        metavar="RHO",
        help="drone chains: simulate tethers of this mass per length [kg/m] instead of the plan's (the drones' "
        "feed-forward keeps the plan's): does the plan survive a heavier cable?",
    )
    p.add_argument(
        "--winch",
        choices=["horizontal", "torque"],
        help="ground chains: winch law: hold the horizontal tension T0 (the planner's model, default) or the "
        "winch-end tension (drone chains always hold the planner's: T_w at its winch_end)",
    )
    p.add_argument(
        "--drive",
        choices=["omni", "diff"],
        help="ground chains: the robots' bodies: omnidirectional (an omni plan's default) or differential drives on "
        "two wheels and casters (a diff-drive plan's, and the only one it takes); --drive diff on an omni plan "
        "replays it on wheels (its sideways motions are caught)",
    )
    p.add_argument(
        "--robot-model",
        type=robot_model_arg,
        metavar="NAME|FILE.toml",
        help="--drive diff on an omni plan: the robot model (a preset of tmr plan --robot-model or a file; default "
        "turtlebot3_burger); a diff-drive plan replays on its own model",
    )
    p.add_argument("--wheel-radius", type=positive_float, help="--drive diff: wheel radius [m] (default: the preset's)")
    p.add_argument(
        "--wheel-track",
        type=positive_float,
        help="--drive diff: distance between the two wheels [m] (default: the preset's)",
    )
    # no --seed (nothing random), no --html/--export: the replay's --gif is its own (rendered from the simulation)
    add_common(p, out=None, out_help="where to write the replay (default RUN/replay)", views=False)
    return p


@contextlib.contextmanager
def _bar(desc: str) -> Iterator[Callable[[float], None] | None]:
    """A tqdm bar of the simulated fraction on stderr (terminal only, not with --quiet; shown after 2 s)."""
    if not progress_enabled():
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(total=1000, desc=desc, unit="‰", leave=False, delay=2.0, mininterval=0.5)

    def update(fraction: float) -> None:
        bar.update(int(1000 * fraction) - bar.n)

    try:
        yield update
    finally:
        bar.close()


#: The smallest physics step [s] (``--timestep``): 5000 steps per 0.05 s sample already take hours.
MIN_TIMESTEP = 1e-5


def _timestep(text: str) -> float:
    v = positive_float(text)
    if v < MIN_TIMESTEP:  # 1e-300 would ask for 5e298 physics steps per sample
        raise argparse.ArgumentTypeError(f"must be ≥ {MIN_TIMESTEP:g} s, got {text!r}")
    return v


def _chain(args: argparse.Namespace, run: Any, out: Path) -> tuple[int, list[str], str]:
    from dataclasses import replace

    from tmr.replay.chain import ReplayConfig, replay_chain
    from tmr.replay.report import chain_verdict, write_chain_outputs

    cfg = ReplayConfig(track=args.track or "filtered", winch=args.winch or "horizontal")
    for name, value in (("n_links", args.links), ("timestep", args.timestep), ("tolerance", args.tolerance)):
        if value is not None:
            cfg = replace(cfg, **{name: value})
    LOG.debug("MuJoCo replay of %s", run.label)
    with _bar("replay") as progress:
        rp = replay_chain(run, cfg, progress=progress, wheels=args.wheels)
    verdict = chain_verdict(rp, run)
    names = write_chain_outputs(out, rp, run, verdict, plots=not args.no_plots)
    if args.gif:
        from tmr.replay.gif import render_gif

        used = render_gif(rp, run, out / "replay.gif")
        names = sorted([*names, "replay.gif"])
        gif_note = f"  replay.gif rendered with {used}"
    lines = [f"tmr replay: {run.label}, {run.n_robots} robots, {rp.sim_time:.2f} s simulated, {rp.steps} steps"]
    if args.gif:
        lines.append(gif_note)
    for i in range(rp.actual.shape[1]):
        e = rp.tracking_error[:, i]
        rms = 1000 * float((e**2).mean()) ** 0.5
        lines.append(f"  robot{i + 1}   tracking error max {1000 * e.max():.2f} mm, rms {rms:.2f} mm")
    if rp.wheels is not None:
        wc = rp.wheels.config
        lines.append(
            f"  wheels    {wc.plan_drive} plan on {wc.model.name} wheels (radius {wc.wheel_radius:g} m, track "
            f"{wc.track:g} m, limit {wc.wheel_limit:.2f} rad/s); tracking error above: the tethers' exit points"
        )
        lines += rp.wheels.summary()
    for j in range(rp.lowest.shape[1]):
        k = int(rp.lowest[:, j].argmin())
        line = (
            f"  tether{j + 1}  lowest point {rp.lowest[k, j]:.4f} m at t = {rp.t[k]:.2f} s (catenary "
            f"{rp.lowest_catenary[k, j]:.4f} m), winch tension max {rp.tension_winch[:, j].max():.2f} N"
        )
        gap = getattr(rp, "low_gap", None)
        if gap is not None and (gap[:, j] < float("inf")).any():
            kg = int(gap[:, j].argmin())
            line += f"; over low obstacles ≥ {gap[kg, j]:.4f} m above their top (t = {rp.t[kg]:.2f} s)"
        lines.append(line)
    counts = ", ".join(f"{kind} {c['count']}" for kind, c in rp.contacts.items())
    lines.append(f"  contacts  {counts} (physics steps in contact)")
    lines.append(
        f"  real-time factor {rp.real_time_factor:.1f}x ({rp.wall_time:.2f} s wall; "
        f"{rp.cpu_real_time_factor:.1f}x of this process's CPU time)"
    )
    return (0 if verdict.ok else 1), names, "\n".join(lines) + ("" if verdict.ok else f"\nFAILED: {verdict.reason}")


def _drones(args: argparse.Namespace, run: Any, out: Path) -> tuple[int, list[str], str]:
    import math
    from dataclasses import replace

    import numpy as np

    from tmr.replay.drones import DroneReplayConfig, chain_of_run, drone_verdict, replay_drones
    from tmr.replay.report import write_drone_outputs

    cfg = DroneReplayConfig(tether_density=args.tether_density)
    for name, value in (("n_links", args.links), ("timestep", args.timestep), ("tolerance", args.tolerance)):
        if value is not None:
            cfg = replace(cfg, **{name: value})
    chain = chain_of_run(run)
    LOG.debug("MuJoCo replay of %s", run.label)
    with _bar("replay") as progress:
        rp = replay_drones(chain, cfg, progress=progress)
    verdict = drone_verdict(rp)
    if run.record.get("success") is False:  # the replay cannot confirm a plan that failed its own checks
        why = run.record.get("failure") or "no reason recorded"
        msg = f"the plan itself failed its checks (run.json success false): {why}"
        verdict = replace(verdict, ok=False, reason=msg, failures=((-math.inf, "plan", msg), *verdict.failures))
    names = write_drone_outputs(out, rp, run, verdict, plots=not args.no_plots)
    lines = [f"tmr replay: {run.label}, {run.n_robots} drones, {rp.sim_time:.2f} s simulated, {rp.steps} steps"]
    if args.gif:
        from tmr.replay.gif import render_drone_gif

        used = render_drone_gif(rp, run, out / "replay.gif")
        names = sorted([*names, "replay.gif"])
        lines.append(f"  replay.gif rendered with {used}")
    if cfg.tether_density is not None:
        lines.append(
            f"  tethers simulated with rho = {cfg.tether_density:g} kg/m (the plan's: {chain.params.mass_per_length:g})"
        )
    for i in range(rp.actual.shape[1]):
        e = rp.tracking_error[:, i]
        rms = 1000 * float((e**2).mean()) ** 0.5
        lines.append(
            f"  drone{i + 1}   tracking error max {1000 * e.max():.1f} mm, rms {rms:.1f} mm; rotor thrust peak "
            f"{rp.rotor_peak[i]:.2f} N, mean {rp.rotor_mean[i]:.2f} N of {rp.rotor_limit:.2f} N, saturated "
            f"{100 * rp.saturation_fraction[i]:.2f} % of steps (longest {1000 * rp.saturation_run[i]:.0f} ms); "
            f"tether pull max {np.nanmax(rp.pull[:, i]):.2f} N of {rp.spare_thrust:.2f} N spare; "
            f"tilt max {math.degrees(np.nanmax(rp.tilt[:, i])):.1f} deg"
        )
    for j in range(rp.lowest.shape[1]):
        k = int(rp.lowest[:, j].argmin())
        dt = np.abs(rp.tension_to[:, j] - rp.tension_to_plan[:, j])
        lines.append(
            f"  tether{j + 1}  lowest point {rp.lowest[k, j]:.3f} m at t = {rp.t[k]:.2f} s (plan "
            f"{rp.lowest_plan[k, j]:.3f} m), drone-end tension max {rp.tension_to[:, j].max():.2f} N "
            f"(plan {np.nanmax(rp.tension_to_plan[:, j]):.2f} N, largest gap {np.nanmax(dt):.3f} N), "
            f"sag below the chord max {np.nanmax(rp.sag[:, j]):.3f} m (plan {np.nanmax(rp.sag_plan[:, j]):.3f} m), "
            f"least distance to the world "
            f"{np.nanmin(rp.clearance[:, j]):.3f} m "
            f"(c_t {rp.tether_clearance:g} m), {int(rp.tether_contact_steps[j])} contact steps"
        )
    counts = ", ".join(f"{kind} {c['count']}" for kind, c in rp.contacts.items())
    lines.append(f"  contacts  {counts} (physics steps in contact)")
    if rp.warnings:
        listed = ", ".join(f"{k} {v}" for k, v in rp.warnings.items())
        lines.append(f"  MuJoCo warnings  {listed} (in replay.json)")
    lines.append(
        f"  real-time factor {rp.real_time_factor:.1f}x ({rp.wall_time:.2f} s wall; "
        f"{rp.cpu_real_time_factor:.1f}x of this process's CPU time)"
    )
    return (0 if verdict.ok else 1), names, "\n".join(lines) + ("" if verdict.ok else f"\nFAILED: {verdict.reason}")


def _mcdpr(args: argparse.Namespace, run: Any, out: Path) -> tuple[int, list[str], str]:
    from tmr.replay.mcdpr import McdprConfig, mcdpr_summary, replay_mcdpr, write_mcdpr_outputs

    cfg = McdprConfig()
    if args.timestep is not None:
        from dataclasses import replace

        cfg = replace(cfg, timestep=args.timestep)
    with _bar("replay") as progress:
        rp = replay_mcdpr(run, cfg, progress=progress)
    names = write_mcdpr_outputs(out, rp, run, plots=not args.no_plots, gif=args.gif)
    text = mcdpr_summary(rp, run)
    return (0 if rp.verdict.ok else 1), names, text


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Exit code (module docstring); messages through logging (``tmr.io.console``: --quiet, --verbose, --debug, one
    line per error, Ctrl-C exits 130); ``prog``: the name messages use (``tmr replay`` through the dispatcher)."""
    return run_command(_main, build_parser(prog).parse_args(argv))


def _main(args: argparse.Namespace) -> int:
    from tmr.io.outdir import Stage, check_out
    from tmr.io.rundir import RunDirError, load_run

    out = check_out(Path(args.out) if args.out else Path(args.run) / "replay", OWNED_NAMES)  # first: exit 2 at once
    try:
        run = load_run(args.run)
    except RunDirError as exc:
        ccma = Path(args.run) / "trajectory.json"
        if ccma.is_file():
            raise TmrError(
                f"{args.run} is a tmr.ccma run: the physics replay covers tmr.plan and tmr.mcdpr runs"
            ) from exc
        raise
    wheel_flags = (
        ("--drive", args.drive),
        ("--robot-model", args.robot_model),
        ("--wheel-radius", args.wheel_radius),
        ("--wheel-track", args.wheel_track),
    )
    for flag, value in wheel_flags:
        if value is not None and run.kind != "chain":
            raise TmrError(f"{flag} applies to ground-chain runs; {args.run} is a {run.kind} run")
    args.wheels = None
    if run.kind == "chain":
        plan_diff = (run.record.get("params") or {}).get("drive") == "diff"
        if plan_diff and args.drive == "omni":
            raise TmrError(f"{args.run} is a differential-drive plan: it replays on wheels only (no --drive omni)")
        if plan_diff or args.drive == "diff":
            from tmr.replay.wheels import wheel_config

            args.wheels = wheel_config(run, args.robot_model, args.wheel_radius, args.wheel_track)
        elif any(v is not None for _, v in wheel_flags[1:]):
            raise TmrError("--robot-model, --wheel-radius and --wheel-track go with --drive diff")
    if args.tether_density is not None and run.kind != "drone":
        raise TmrError(f"--tether-density applies to drone-chain runs; {args.run} is a {run.kind} run")
    for flag, value in (("--track", args.track), ("--winch", args.winch)):
        if value is not None and run.kind != "chain":
            raise TmrError(f"{flag} applies to ground-chain runs; {args.run} is a {run.kind} run")
    if args.gif:
        from tmr.replay.gif import select_backend

        select_backend()
    try:
        import mujoco  # noqa: F401
    except ImportError as exc:
        raise TmrError(f"the replay needs MuJoCo: pip install 'mujoco>=4.0' ({exc})") from None
    with Stage(out, OWNED_NAMES, VOLATILE_NAMES, kind="replay") as stage:  # staged, then published in one step
        replay = {"chain": _chain, "drone": _drones}.get(run.kind, _mcdpr)
        code, names, text = replay(args, run, stage.path)
        names = stage.publish()
    LOG.info(text.split("\nFAILED: ")[0])
    LOG.info(f"  wrote {', '.join(names)} to {out}")
    if code:
        LOG.error(f"replay FAILED: {text.split(chr(10) + 'FAILED: ')[1]}")
    else:
        LOG.info("replay OK: the physics confirms the plan")
    return code


if __name__ == "__main__":
    sys.exit(main())
