"""CCMA sensitivity-based IK: per-step time, iterations, joint range, errors and conditioning, every example × path.

    python benchmarks/ccma.py [--examples 4dof-reduced ...] [--paths vcircle figure8 ...] [--repeats 3]
                              [--modes vm compiled] [--steps 30]

A benchmark, not a test. For every shipped example (``src/tmr/ccma/examples``: Kumar 2019 Fig. 2, 3(a), 3(b), 4(a),
4(b)), every path (:func:`tmr.ccma.paths.make_path` with the CLI defaults: 1 mm / 0.01 rad increments, radius
0.05 m, sweep amplitude 0.2 rad; ``combined`` = the combined perturbation of Kumar 2019 Fig. 5, ``--steps`` steps;
``tilt`` / ``roll`` only where the example has that tilt axis) and evaluation mode (``vm``: CasADi's SX virtual
machine; ``compiled``: the same functions generated as C and compiled, cached under ``$TMR_CACHE_DIR`` or
``~/.cache/tmr/ccma``) it checks the path against the reach bound (:func:`tmr.ccma.reach.check_reach`) and tracks
it from the reference configuration with :func:`tmr.ccma.control.track` ``--repeats`` times (interleaved over
examples, paths and modes). Reported per (example, path, mode): median / 90th percentile / max of the warm step time
(steps 2…K: IK solve(s) + conditioning, BFGS warm-started from the previous step) over all repeats, the step-1 time
(median over repeats), median BFGS iterations and objective evaluations, the largest joint range (max − min angle of
any rotary joint, :mod:`tmr.ccma.angles`), the largest position / rotation error and residual energy, the largest
condition number of the end-effector sensitivity, steps subdivided, and whether every target was reached (1e-5 m,
1e-4 rad, residual ≤ 1e-12 m²). Target of the project (issue 15): median step ≤ 5 ms and max ≤ 20 ms for every
example on 2 cores.

Also writes ``ccma_convergence.png`` (objective against time of step 1 and of the median warm step of the combined
path, compiled mode: the analogue of Kumar 2019 Fig. 5) and ``ccma_mechanism.png`` (the README figure:
``python -m tmr.ccma run --example 5dof-reduced --path figure8 --radius 0.1``, the asymmetric Fig. 4(b) linkage
bending along a 3-D figure-eight). BLAS runs on one thread unless the caller sets a thread count (the 60×60 Cholesky
factorisations are faster serial). Writes ``benchmarks/results/ccma.md``, ``ccma.csv`` and the two figures.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
PINNED = not any(v in os.environ for v in THREAD_VARS)
if PINNED:
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = "1"

import numpy as np  # noqa: E402
from provenance import source_version, versions  # noqa: E402

#: Distributions whose versions the table records.
PACKAGES = ("numpy", "scipy", "casadi")

from tmr.ccma.angles import joint_angles, joint_ranges  # noqa: E402
from tmr.ccma.control import reached, track  # noqa: E402
from tmr.ccma.energy import EnergyModel  # noqa: E402
from tmr.ccma.errors import CcmaError  # noqa: E402
from tmr.ccma.paths import make_path  # noqa: E402
from tmr.ccma.reach import check_reach  # noqa: E402
from tmr.ccma.sim import end_effector_pose, reference_state  # noqa: E402
from tmr.ccma.system import example_names, load_system  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
PATHS = ("vcircle", "figure8", "combined", "tilt", "roll")
#: Targets of the project issue [ms]: median and largest warm step, every example.
TARGET_MEDIAN_MS, TARGET_MAX_MS = 5.0, 20.0
#: The README figure: the CLI run it reproduces.
README_RUN = ["--example", "5dof-reduced", "--path", "figure8", "--radius", "0.1"]

COLUMNS = [
    ("example", "example", "{}"),
    ("path", "path", "{}"),
    ("mode", "mode", "{}"),
    ("agents", "agents", "{}"),
    ("controls", "m", "{}"),
    ("steps", "K", "{}"),
    ("warm_ms", "warm step median [ms]", "{:.2f}"),
    ("warm_p90_ms", "p90 [ms]", "{:.2f}"),
    ("warm_max_ms", "max [ms]", "{:.1f}"),
    ("step1_ms", "step 1 [ms]", "{:.1f}"),
    ("cpu_ms", "CPU / step [ms]", "{:.2f}"),
    ("bfgs_its", "BFGS its", "{:g}"),
    ("evals", "O evals", "{:g}"),
    ("joint_range", "joint range [rad]", "{:.3f}"),
    ("joint", "widest joint", "{}"),
    ("max_pos_err", "max pos err [m]", "{:.1e}"),
    ("max_rot_err", "max rot err [rad]", "{:.1e}"),
    ("max_residual", "max residual E [m²]", "{:.1e}"),
    ("max_condition", "max condition", "{:.3g}"),
    ("reach_margin", "reach margin [m]", "{:.3f}"),
    ("subdivided", "subdivided", "{}"),
    ("reached", "all reached", "{}"),
]


def markdown(rows: list[dict[str, Any]]) -> str:
    head = "| " + " | ".join(h for _, h, _ in COLUMNS) + " |\n"
    head += "|" + "|".join("---" for _ in COLUMNS) + "|\n"
    body = "".join("| " + " | ".join(fmt.format(r[k]) for k, _, fmt in COLUMNS) + " |\n" for r in rows)
    return head + body


def readme_figure(out: Path) -> None:
    """Run the CLI of the README figure into a temporary directory and keep its mechanism.png."""
    from tmr.ccma.__main__ import main as ccma_main

    with tempfile.TemporaryDirectory() as tmp:
        code = ccma_main(["run", *README_RUN, "--out", tmp, "--quiet"])
        if code != 0:
            raise SystemExit(f"README figure run exited {code}")
        shutil.copyfile(Path(tmp) / "mechanism.png", out / "ccma_mechanism.png")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--examples", nargs="+", default=example_names())
    ap.add_argument("--paths", nargs="+", default=list(PATHS), choices=PATHS)
    ap.add_argument("--steps", type=int, default=30, help="steps of the combined path (default 30)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--modes", nargs="+", default=["vm", "compiled"], choices=["vm", "compiled"])
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--no-figures", action="store_true", help="skip ccma_convergence.png and ccma_mechanism.png")
    args = ap.parse_args()
    t_start = time.perf_counter()
    load_start = os.getloadavg()

    models: dict[tuple[str, str], EnergyModel] = {}
    for name in args.examples:
        for mode in args.modes:
            models[name, mode] = EnergyModel(load_system(name), compile=mode == "compiled")
    paths: dict[tuple[str, str], Any] = {}
    margins: dict[tuple[str, str], float] = {}
    for name in args.examples:
        m = models[name, args.modes[0]]
        p0, r0 = end_effector_pose(m, reference_state(m))
        for kind in args.paths:
            try:
                path = make_path(kind, p0, r0, m.system.tilt_axes, steps=args.steps)
            except CcmaError:  # tilt / roll about an axis the example does not have
                continue
            verdict = check_reach(m.system, path.positions, path.rotations)
            if not verdict.ok:
                raise SystemExit(f"{name} {kind}: {verdict.message()}")
            paths[name, kind] = path
            margins[name, kind] = float(verdict.margin.min())
    keys = [(n, k, mode) for (n, k) in paths for mode in args.modes]
    runs: dict[tuple[str, str, str], list[Any]] = {key: [] for key in keys}
    cpu: dict[tuple[str, str, str], list[float]] = {key: [] for key in keys}
    for rep in range(args.repeats):
        for key in keys:
            name, kind, mode = key
            m = models[name, mode]
            path = paths[name, kind]
            keep = rep == 0  # joint angles from the first repeat (the trajectories of all repeats are identical)
            c0 = time.process_time()
            runs[key].append(track(m, path.positions, path.rotations, state=reference_state(m), keep_states=keep))
            cpu[key].append(1e3 * (time.process_time() - c0) / len(path.positions))
            warm = runs[key][-1].step_time[1:]
            print(f"repeat {rep + 1}: {name:14s} {kind:9s} {mode:8s} {1e3 * np.median(warm):7.2f} ms", flush=True)

    rows = []
    for key, rs in runs.items():
        name, kind, mode = key
        m = models[name, mode]
        warm = np.concatenate([r.step_time[1:] for r in rs]) * 1e3
        ranges = joint_ranges(m, joint_angles(m, rs[0].states))
        widest = max(ranges, key=lambda r: r.span)
        rows.append(
            {
                "example": name,
                "path": kind,
                "mode": mode,
                "agents": len(m.system.agents),
                "controls": m.nu,
                "steps": len(paths[name, kind].positions),
                "warm_ms": float(np.median(warm)),
                "warm_p90_ms": float(np.percentile(warm, 90)),
                "warm_max_ms": float(warm.max()),
                "step1_ms": statistics.median(1e3 * r.step_time[0] for r in rs),
                "cpu_ms": statistics.median(cpu[key]),
                "bfgs_its": float(np.median(np.concatenate([r.iterations[1:] for r in rs]))),
                "evals": float(np.median(np.concatenate([r.evaluations[1:] for r in rs]))),
                "joint_range": widest.span,
                "joint": widest.name,
                "max_pos_err": max(float(r.position_error.max()) for r in rs),
                "max_rot_err": max(float(r.rotation_error.max()) for r in rs),
                "max_residual": max(float(r.residual.max()) for r in rs),
                "max_condition": max(float(r.condition.max()) for r in rs),
                "reach_margin": margins[name, kind],
                "subdivided": max(int((r.substeps > 1).sum()) for r in rs),
                "reached": all(bool(reached(r).all()) for r in rs),
                "repeats": args.repeats,
            }
        )
    total = time.perf_counter() - t_start

    def verdict(mode: str) -> str:
        rs = [r for r in rows if r["mode"] == mode]
        worst_med = max(rs, key=lambda r: r["warm_ms"])
        worst_max = max(rs, key=lambda r: r["warm_max_ms"])
        ok_med = sum(r["warm_ms"] <= TARGET_MEDIAN_MS for r in rs)
        ok_max = sum(r["warm_max_ms"] <= TARGET_MAX_MS for r in rs)
        return (
            f"**{mode}**: median ≤ {TARGET_MEDIAN_MS:g} ms in {ok_med} of {len(rs)} rows (largest median "
            f"{worst_med['warm_ms']:.2f} ms, {worst_med['example']} {worst_med['path']}); max ≤ {TARGET_MAX_MS:g} ms "
            f"in {ok_max} of {len(rs)} rows (largest {worst_max['warm_max_ms']:.1f} ms, {worst_max['example']} "
            f"{worst_max['path']})"
        )

    nproc = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    threads = ", ".join(f"{v}={os.environ[v]}" for v in THREAD_VARS if v in os.environ)
    threads += " (set by the script)" if PINNED else " (from the environment)"
    load = "/".join(f"{x:.1f}" for x in load_start) + " → " + "/".join(f"{x:.1f}" for x in os.getloadavg())
    figures = "" if args.no_figures else "\n![convergence](ccma_convergence.png)\n\n![mechanism](ccma_mechanism.png)\n"
    note = f"""\
`{" ".join(["python benchmarks/ccma.py", *sys.argv[1:]])}` — {datetime.date.today().isoformat()}, machine
`{platform.processor() or platform.machine()}`, nproc {nproc}, Python {platform.python_version()}; {versions(PACKAGES)};
{threads}; {source_version("src/tmr/ccma")}. Total run time {total:.0f} s; load average (1/5/15 min) {load}.

Paths from the reference configuration, {args.repeats} repeats: `vcircle` (vertical circle, radius 0.05 m, 1 mm
steps), `figure8` (3-D figure-eight, radius 0.05 m, 1 mm steps), `combined` ({args.steps} steps of +1 mm in x, y, z
and +0.01 rad in yaw and every tilt axis: Kumar 2019 Fig. 5), `tilt` / `roll` (±0.2 rad sweep about the first /
second tilt axis, ≤ 0.01 rad steps). Formulation: [`formulations/ccma.md`](../../formulations/ccma.md). Columns:
*m* controls, *K* targets; *warm step* = one step 2…K (IK solve, warm-started with the previous step's controls
and state, Gauss–Newton initial inverse Hessian, plus the conditioning of the reached state) — median, 90th
percentile and max over all repeats; *step 1* = the first step, median over repeats; *CPU / step* = process CPU
time of the whole tracking divided by K, median over repeats (unlike wall times, not inflated when other processes
share the cores; it includes the bookkeeping of `track` outside the steps); *BFGS its* and *O evals*
medians over the warm steps; *joint range* = the largest max − min angle of any rotary joint along the path and
*widest joint* that joint; errors, residual energy and *max condition* (condition number of the end-effector
sensitivity on the assemblable directions) are the worst over all steps; *reach margin* = the smallest distance of
any target to the analytic reach bound; *subdivided* = steps solved in sub-steps; *all reached* = every step within
1e-5 m, 1e-4 rad and E ≤ 1e-12 m².

Targets of the project (issue 15): median step ≤ {TARGET_MEDIAN_MS:g} ms and max ≤ {TARGET_MAX_MS:g} ms for every
example on 2 cores. {"; ".join(verdict(mode) for mode in args.modes)}.
"""
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ccma.md").write_text(
        "# CCMA sensitivity IK: per-step time, joint range, errors\n\n" + note + "\n" + markdown(rows) + figures
    )
    fields = [k for k, _, _ in COLUMNS] + ["repeats"]
    with (args.out / "ccma.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields, lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in fields})
    print(markdown(rows))
    if not args.no_figures:
        # ---- convergence figure (Kumar 2019 Fig. 5 analogue) and the README figure
        from matplotlib.figure import Figure

        from tmr.views.plot import save_figure

        fig = Figure(figsize=(10, 4.2))
        axes = [fig.add_subplot(1, 2, k + 1) for k in range(2)]
        mode = "compiled" if "compiled" in args.modes else args.modes[0]
        for name in args.examples:
            if (name, "combined", mode) not in runs:
                continue
            r = runs[name, "combined", mode][-1]
            k = 1 + int(np.argsort(r.step_time[1:])[len(r.step_time[1:]) // 2])
            for ax, h in zip(axes, (r.histories[0], r.histories[k]), strict=True):
                ax.semilogy(1e3 * h[:, 0], np.maximum(h[:, 1], 1e-30), marker=".", ms=4, label=name)
        axes[0].set_title("step 1 (from the reference configuration)")
        axes[1].set_title("median warm step")
        for ax in axes:
            ax.set_xlabel("time [ms]")
            ax.set_ylabel("objective O(u) [m²]")
            ax.grid(True, which="both", lw=0.3)
            ax.legend(fontsize=8)
        fig.suptitle(f"CCMA IK convergence, combined 1 mm / 0.01 rad step ({mode})")
        fig.tight_layout()
        args.out.mkdir(parents=True, exist_ok=True)
        save_figure(fig, args.out / "ccma_convergence.png")
        readme_figure(args.out)


if __name__ == "__main__":
    main()
