"""Command line: ``python -m tmr.ccma run --example 4dof-reduced --path vcircle --out runs/ccma``.

``run`` first checks every target of the path against the reach bound of the linkage (:mod:`tmr.ccma.reach`), then
tracks the end-effector path of small increments (Kumar 2019 §III-D) with the sensitivity-based IK
(:mod:`tmr.ccma.control`), records the joint angles (:mod:`tmr.ccma.angles`) and the conditioning of every step, and
writes into ``--out``: ``trajectory.csv`` and ``trajectory.json`` (targets, reached
end-effector pose, agent poses and controls, errors, residual energy, iteration counts per step), ``summary.json``
(tolerance checks and timings) and, unless ``--no-plots``, ``mechanism.png`` (3D + top view) and
``convergence.png`` (objective against time, Kumar 2019 Fig. 5). Files of these names left in ``--out`` by an earlier
run that this run does not write (e.g. the figures under ``--no-plots``) are deleted; other files are not touched.
``list`` prints the shipped examples.

Everything is deterministic except the timings (``summary.json`` "timing" and ``convergence.png``): the same inputs
give the same trajectory bytes. Nothing in this command is random, so there is no ``--seed``.

Exit codes: 0 every target reached; 1 tracked but some target missed (outputs written, reason printed); 2 bad input
or a path proven impossible before control (one line, nothing written): an ``--out`` that is an existing file or
cannot be created or written (checked first), a path of more than :data:`tmr.ccma.paths.MAX_STEPS` targets (checked
before anything is allocated), or a target beyond the reach of the linkage or past a singular configuration of a leg
(:mod:`tmr.ccma.reach`, checked before any IK step: :class:`tmr.ccma.errors.ReachError`).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from tmr.ccma.motion import ccma_track_motion
from tmr.io.cli_args import ArgumentParser, add_common, count, path_arg
from tmr.io.cli_args import positive_float as _positive
from tmr.io.console import LOG, add_manners, progress_enabled
from tmr.io.console import run as run_cli
from tmr.views.flags import VIEW_NAMES, write_views

TRAJECTORY_FORMAT = "tmr-ccma-trajectory/1"
#: Every file name ``run`` may write into ``--out``.
OUTPUT_NAMES = ("trajectory.csv", "trajectory.json", "summary.json", "mechanism.png", "convergence.png")
#: Every entry of ``--out`` a run owns (its files and views): those tmr wrote before and a run does not produce are
#: removed when it publishes, so no file of an earlier run survives next to the new ones; other files are never
#: touched, and a file tmr did not write under one of these names makes the run refuse its ``--out``
#: (:mod:`tmr.io.outdir`).
OWNED_NAMES = OUTPUT_NAMES + VIEW_NAMES


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``python -m tmr.ccma``; ``prog``: the name it shows (``tmr ccma`` through the dispatcher)."""
    from tmr.ccma.paths import PATHS

    p = ArgumentParser(
        prog=prog or "python -m tmr.ccma",
        description="Simulate and control constrained collaborative mobile agents (Kumar 2019).",
    )
    sub = p.add_subparsers(dest="command", required=True)
    add_manners(sub.add_parser("list", help="list the shipped example systems"))
    r = sub.add_parser("run", help="track an end-effector path and write trajectories and figures")
    src = r.add_mutually_exclusive_group()
    src.add_argument(
        "--example", type=path_arg, default="4dof-reduced", help="shipped example (see 'list'; default 4dof-reduced)"
    )
    src.add_argument(
        "--description", type=path_arg, help="path of a system description TOML file instead of an example"
    )
    r.add_argument(
        "--path",
        default="vcircle",
        choices=list(PATHS),
        help="end-effector path (default vcircle); vcircle, figure8, tilt and roll bend the joints, circle and line "
        "only slide a level mechanism",
    )
    r.add_argument("--radius", type=_positive, default=0.05, help="size of circle/vcircle/figure8 [m] (default 0.05)")
    r.add_argument("--amplitude", type=_positive, default=0.2, help="tilt/roll sweep amplitude [rad] (default 0.2)")
    r.add_argument("--step", type=_positive, default=1e-3, help="translation increment per step [m] (default 0.001)")
    r.add_argument("--rot-step", type=_positive, default=0.01, help="rotation increment per step [rad] (default 0.01)")
    r.add_argument("--steps", type=count, default=20, help="steps of line/yaw/combined paths (default 20)")
    r.add_argument("--gtol", type=_positive, default=1e-9, help="BFGS tolerance on |dO/du| [m] (default 1e-9)")
    r.add_argument("--compile", action="store_true", help="compile the CasADi functions to C (cached; ~30x faster)")
    add_common(r, out="runs/ccma")  # no --seed: nothing in a run is random (module doc)
    return p


def _csv_text(model: Any, path: Any, res: Any, joint_names: list[str], angles: np.ndarray) -> str:
    sysm = model.system
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["step", "target_x", "target_y", "target_z", "ee_x", "ee_y", "ee_z", "ee_yaw"]
    head += [
        "position_error",
        "rotation_error",
        "residual_energy",
        "bfgs_iterations",
        "evaluations",
        "newton_iterations",
    ]
    for a in sysm.agents:
        head += [f"{a.name}_x", f"{a.name}_y", f"{a.name}_yaw"]
    head += [f"u_{n}" for n in sysm.control_names]
    head += ["condition", "sigma_min", "damped", "substeps"] + [f"angle_{n}" for n in joint_names]
    w.writerow(head)
    for k in range(len(path.positions)):
        yaw = math.atan2(res.ee_rotation[k, 1, 0], res.ee_rotation[k, 0, 0])
        row: list[Any] = [k + 1, *path.positions[k], *res.ee_position[k], yaw]
        row += [res.position_error[k], res.rotation_error[k], res.residual[k]]
        row += [int(res.iterations[k]), int(res.evaluations[k]), int(res.newton_iterations[k])]
        row += list(res.agents[k].ravel()) + list(res.u[k])
        row += [res.condition[k], res.sigma_min[k], int(res.damped[k]), int(res.substeps[k])] + list(angles[k])
        w.writerow([repr(float(v)) if isinstance(v, (float, np.floating)) else v for v in row])
    return buf.getvalue()


def _trajectory_doc(
    model: Any, args: argparse.Namespace, path: Any, res: Any, joint_names: list[str], angles: np.ndarray
) -> dict[str, Any]:
    sysm = model.system
    return {
        "format": TRAJECTORY_FORMAT,
        "system": sysm.name,
        "path": args.path,
        "control_names": sysm.control_names,
        "agents": [{"name": a.name, "actuation": a.actuation} for a in sysm.agents],
        "target_position": path.positions,
        "target_rotation": path.rotations,
        "ee_position": res.ee_position,
        "ee_rotation": res.ee_rotation,
        "agent_poses": res.agents,
        "controls": res.u,
        "position_error": res.position_error,
        "rotation_error": res.rotation_error,
        "residual_energy": res.residual,
        "bfgs_iterations": res.iterations,
        "evaluations": res.evaluations,
        "newton_iterations": res.newton_iterations,
        "condition": res.condition,
        "sigma_min": res.sigma_min,
        "damped": res.damped.astype(int),
        "substeps": res.substeps,
        "joint_names": joint_names,
        "joint_angles": angles,
    }


def run(args: argparse.Namespace) -> int:
    from tmr.ccma.angles import joint_angles, joint_ranges, rotary_joints
    from tmr.ccma.control import CONDITION_LIMIT, reached, track
    from tmr.ccma.energy import EnergyModel
    from tmr.ccma.errors import ReachError
    from tmr.ccma.paths import make_path
    from tmr.ccma.reach import check_reach, height_range
    from tmr.ccma.sim import end_effector_pose, reference_state
    from tmr.ccma.system import described_system
    from tmr.checks.metrics import json_safe

    # ---- validate and compute everything before writing
    from tmr.io.outdir import check_out

    out = check_out(Path(args.out), OWNED_NAMES)
    desc, system = described_system(args.description or args.example)
    model = EnergyModel(system, compile=args.compile)
    st0 = reference_state(model)
    p0, r0 = end_effector_pose(model, st0)
    path = make_path(
        args.path,
        p0,
        r0,
        model.system.tilt_axes,
        step=args.step,
        rot_step=args.rot_step,
        radius=args.radius,
        steps=args.steps,
        amplitude=args.amplitude,
    )
    verdict = check_reach(model.system, path.positions, path.rotations)
    if not verdict.ok:  # proven before any IK step: one line, nothing written (like any task proven impossible)
        raise ReachError(f"path refused before control: {verdict.message()}", verdict)
    z_lo, z_hi = height_range(model.system)
    reach = {
        "ok": verdict.ok,
        "legs_bounded": verdict.legs,
        "ee_height_range_m": [z_lo, z_hi],
        "min_margin_m": float(verdict.margin.min()),
        "message": verdict.message(),
    }
    n_snap = 5
    res = track(
        model, path.positions, path.rotations, state=st0, gtol=args.gtol, keep_states=True, progress=progress_enabled()
    )
    ok = reached(res)
    joint_names = [model.system.joints[k].name for k in rotary_joints(model)]
    angles = joint_angles(model, res.states)
    ranges = joint_ranges(model, angles)
    widest = max(ranges, key=lambda r: r.span, default=None)
    near = np.flatnonzero(res.condition > CONDITION_LIMIT)
    summary = {
        "system": model.system.name,
        "path": args.path,
        "steps": len(path.positions),
        "controls": model.nu,
        "bodies": model.system.n_bodies,
        "constraint_rows": model.system.n_constraints,
        "all_reached": bool(ok.all()),
        "missed_steps": [int(k) + 1 for k in np.flatnonzero(~ok)],
        "max_position_error": float(res.position_error.max()),
        "max_rotation_error": float(res.rotation_error.max()),
        "max_residual_energy": float(res.residual.max()),
        "median_bfgs_iterations": float(np.median(res.iterations)),
        "median_newton_iterations_per_step": float(np.median(res.newton_iterations)),
        "reach": reach,
        "joint_ranges_rad": {r.name: [r.low, r.high] for r in ranges},
        "max_joint_range_rad": widest.span if widest else 0.0,
        "max_condition": float(res.condition.max()),
        "min_sigma_m": float(res.sigma_min.min()),
        "condition_limit": CONDITION_LIMIT,
        "near_singular_steps": [int(k) + 1 for k in near],
        "damped_steps": [int(k) + 1 for k in np.flatnonzero(res.damped)],
        "subdivided_steps": {str(int(k) + 1): int(res.substeps[k]) for k in np.flatnonzero(res.substeps > 1)},
        "timing": {
            "compiled": model.compiled,
            "median_step_ms": 1e3 * float(np.median(res.step_time)),
            "max_step_ms": 1e3 * float(res.step_time.max()),
            "total_s": float(res.step_time.sum()),
        },
    }
    texts = {
        "trajectory.csv": _csv_text(model, path, res, joint_names, angles),
        "trajectory.json": json.dumps(
            json_safe(_trajectory_doc(model, args, path, res, joint_names, angles)), allow_nan=False
        )
        + "\n",
        "summary.json": json.dumps(json_safe(summary), indent=2, allow_nan=False) + "\n",
    }
    figures = {}
    if not args.no_plots:
        from tmr.ccma.plot import plot_convergence, plot_mechanism

        idx = np.unique(np.linspace(0, len(res.states) - 1, n_snap).round().astype(int))
        title = f"{model.system.name}: {args.path} path, {len(path.positions)} steps"
        figures["mechanism.png"] = plot_mechanism(
            model, res, [st0] + [res.states[i] for i in idx], title, angles=angles, joint_names=joint_names
        )
        slow = int(np.argmax(res.step_time[1:])) + 1 if len(res.step_time) > 1 else 0
        mid = len(res.step_time) // 2
        curves = {"step 1 (from the reference)": res.histories[0], f"step {mid + 1}": res.histories[mid]}
        curves[f"step {slow + 1} (slowest warm)"] = res.histories[slow]
        figures["convergence.png"] = plot_convergence(curves, f"{model.system.name}: objective vs time")
    names = _write_outputs(
        out, texts, figures, lambda where: write_views(args, where, lambda: ccma_track_motion(model, res, args.path))
    )
    t = summary["timing"]
    LOG.info(
        f"tmr ccma: {model.system.name}, path {args.path}, {summary['steps']} steps, {model.nu} controls\n"
        f"  max position error   {summary['max_position_error']:.3g} m\n"
        f"  max rotation error   {summary['max_rotation_error']:.3g} rad\n"
        f"  max residual energy  {summary['max_residual_energy']:.3g} m²\n"
        f"  median BFGS its      {summary['median_bfgs_iterations']:g}\n"
        f"  median step time     {t['median_step_ms']:.3g} ms (compiled: {t['compiled']})\n"
        f"  joint range          {_range_text(widest)}\n"
        f"  reach                {_reach_text(reach)}\n"
        f"  conditioning         max {summary['max_condition']:.3g} (near-singular above {CONDITION_LIMIT:g}: "
        f"{len(near)} step(s), {int(res.damped.sum())} damped, {int((res.substeps > 1).sum())} subdivided)\n"
        f"  wrote {', '.join(names)} to {out}"
    )
    if near.size:
        LOG.warning(
            f"warning: {len(near)} step(s) near a singular configuration (sensitivity condition number up to "
            f"{summary['max_condition']:.3g} at step {int(np.argmax(res.condition)) + 1}; smallest end-effector "
            f"singular value {summary['min_sigma_m']:.3g} m); the steps after them were damped, and missed steps "
            f"retried in smaller increments"
        )
    if not ok.all():
        LOG.error("path FAILED: %s", _miss_reason(res, ok))
        return 1
    return 0


def _reach_text(reach: dict[str, Any]) -> str:
    if not reach["legs_bounded"]:
        return "not checked: no leg of rigid links joins an agent to the end-effector (no analytic bound)"
    z_lo, z_hi = reach["ee_height_range_m"]
    return (
        f"smallest margin {reach['min_margin_m']:.3g} m (end-effector height {z_lo:.3g} … {z_hi:.3g} m at the "
        f"reference rotation; {reach['legs_bounded']} legs bounded)"
    )


def _range_text(widest: Any) -> str:
    if widest is None:
        return "no rotary joint"
    return f"{widest.span:.3g} rad ({widest.name}: {widest.low:.3g} … {widest.high:.3g} rad)"


def _miss_reason(res: Any, ok: np.ndarray) -> str:
    """One line: how many targets were missed, the first, and which tolerance it broke by how much."""
    from tmr.ccma.control import CONDITION_LIMIT
    from tmr.ccma.sim import ASSEMBLY_TOL

    missed = np.flatnonzero(~ok)
    k = int(missed[0])
    why = []
    if res.position_error[k] > 1e-5:
        why.append(f"position error {res.position_error[k]:.3g} m > 1e-05 m")
    if res.rotation_error[k] > 1e-4:
        why.append(f"rotation error {res.rotation_error[k]:.3g} rad > 0.0001 rad")
    if res.residual[k] > ASSEMBLY_TOL:
        why.append(
            f"residual energy {res.residual[k]:.3g} m² > {ASSEMBLY_TOL:g} m² (the agents' commands do not assemble)"
        )
    if res.condition[k] > CONDITION_LIMIT:
        why.append(f"near-singular (condition number {res.condition[k]:.3g})")
    near = np.flatnonzero(res.condition[:k] > CONDITION_LIMIT)
    if near.size and near[-1] >= k - 3:
        j = int(near[-1])
        why.append(
            f"right after a near-singular configuration (condition number {res.condition[j]:.3g} at step {j + 1}): "
            f"the linkage cannot be followed through it"
        )
    return f"{len(missed)} target(s) missed, first at step {k + 1}: {'; '.join(why)}"


def _write_outputs(
    out: Path, texts: dict[str, str], figures: dict[str, Any] | None = None, views: Any = None
) -> list[str]:
    """Stage the files (``views(directory)`` writes the views asked for) and publish them into ``out`` in one step
    (:mod:`tmr.io.outdir`: outputs of an earlier run this one does not produce are removed, other files left alone);
    return the names written. A write error is one line, exit 2 (:class:`tmr.io.outdir.OutDirError`)."""
    from tmr.io.outdir import Stage
    from tmr.io.outputs import atomic_write_text

    with Stage(out, OWNED_NAMES) as stage:
        for name, text in texts.items():
            atomic_write_text(stage.path / name, text)
        if figures:
            from tmr.views.plot import save_figure

            for name, fig in figures.items():
                save_figure(fig, stage.path / name)
        if views is not None:
            views(stage.path)
        return stage.publish()


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Entry point of ``python -m tmr.ccma`` and ``tmr ccma`` (``prog``: the name messages use); returns the exit
    code (module doc)."""
    args = build_parser(prog).parse_args(argv)
    return run_cli(_main, args)  # --quiet/--verbose/--debug, one-line errors (exit 2), Ctrl-C (130)


def _main(args: argparse.Namespace) -> int:
    if args.command == "list":
        from tmr.ccma.system import example_names, load_system

        for name in example_names():
            s = load_system(name)
            acts = sorted({a.actuation for a in s.agents})
            print(
                f"{name:16s} {len(s.agents)} agents, {s.n_controls} controls, {s.n_bodies} bodies, "
                f"{'/'.join(acts)} actuation; {s.description.get('figure', 'no figure')}"
            )  # the listing is the product of 'list': on stdout even with --quiet
        return 0
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
