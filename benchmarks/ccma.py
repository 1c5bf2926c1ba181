"""CCMA sensitivity-based IK: per-step time, BFGS and Newton iterations for every shipped example.

    python benchmarks/ccma.py [--examples 4dof-reduced ...] [--steps 30] [--repeats 3] [--modes vm compiled]

A benchmark, not a test. For every example (``src/tmr/ccma/examples``) and evaluation mode (``vm``: CasADi's SX
virtual machine; ``compiled``: the same functions generated as C and compiled, cached under ``$TMR_CACHE_DIR`` or
``~/.cache/tmr/ccma``) it tracks the ``combined`` path of Kumar 2019 Fig. 5 — every step a simultaneous increment of
1 mm in x, y and z and 0.01 rad in yaw and in each tilt axis of the example — from the reference configuration with
:func:`tmr.ccma.control.track` ``--repeats`` times (interleaved over examples and modes). Every step starts BFGS from
the inverse of the Gauss–Newton estimate of ∇²O (:func:`tmr.ccma.control.gauss_newton_hessian`); step 1 starts from
the reference configuration, the later ("warm") steps from the previous step's controls and state. Reported per
(example, mode): median / 90th percentile / max of the warm step time over all repeats, the step-1 time (median over
repeats), median BFGS iterations, objective evaluations and Newton iterations per evaluation of the warm steps, the
largest position / rotation error and residual energy of any step, and whether every target was reached (1e-5 m,
1e-4 rad, residual ≤ 1e-12 m²). Also writes ``ccma_convergence.png``: objective against time of step 1 and of
the median warm step of each example (compiled mode), the analogue of Kumar 2019 Fig. 5.

BLAS runs on one thread unless the caller sets a thread count (the 60×60 Cholesky factorisations are faster serial).
Writes ``benchmarks/results/ccma.md``, ``ccma.csv`` and ``ccma_convergence.png``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import os
import platform
import statistics
import sys
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

from tmr.ccma.control import reached, track  # noqa: E402
from tmr.ccma.energy import EnergyModel  # noqa: E402
from tmr.ccma.paths import make_path  # noqa: E402
from tmr.ccma.sim import end_effector_pose, reference_state  # noqa: E402
from tmr.ccma.system import example_names, load_system  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: Target of the project issue: per small step of the 4-dof example [ms].
TARGET_4DOF_MS = 20.0

COLUMNS = [
    ("example", "example", "{}"),
    ("mode", "mode", "{}"),
    ("controls", "m", "{}"),
    ("state", "6n", "{}"),
    ("rows", "rows of C", "{}"),
    ("build_s", "build [s]", "{:.2f}"),
    ("warm_ms", "warm step median [ms]", "{:.2f}"),
    ("warm_p90_ms", "p90 [ms]", "{:.2f}"),
    ("warm_max_ms", "max [ms]", "{:.1f}"),
    ("step1_ms", "step 1 [ms]", "{:.1f}"),
    ("bfgs_its", "BFGS its", "{:g}"),
    ("evals", "O evals", "{:g}"),
    ("newton_per_eval", "Newton its / eval", "{:.2f}"),
    ("max_pos_err", "max pos err [m]", "{:.1e}"),
    ("max_rot_err", "max rot err [rad]", "{:.1e}"),
    ("max_residual", "max residual E [m²]", "{:.1e}"),
    ("reached", "all reached", "{}"),
]


def markdown(rows: list[dict[str, Any]]) -> str:
    head = "| " + " | ".join(h for _, h, _ in COLUMNS) + " |\n"
    head += "|" + "|".join("---" for _ in COLUMNS) + "|\n"
    body = "".join("| " + " | ".join(fmt.format(r[k]) for k, _, fmt in COLUMNS) + " |\n" for r in rows)
    return head + body


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--examples", nargs="+", default=example_names())
    ap.add_argument("--steps", type=int, default=30, help="steps of the combined path (default 30)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--modes", nargs="+", default=["vm", "compiled"], choices=["vm", "compiled"])
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    t_start = time.perf_counter()
    load_start = os.getloadavg()

    models: dict[tuple[str, str], EnergyModel] = {}
    build: dict[tuple[str, str], float] = {}
    for name in args.examples:
        for mode in args.modes:
            t0 = time.perf_counter()
            models[name, mode] = EnergyModel(load_system(name), compile=mode == "compiled")
            build[name, mode] = time.perf_counter() - t0
    runs: dict[tuple[str, str], list[Any]] = {k: [] for k in models}
    paths = {}
    for name in args.examples:
        m = models[name, args.modes[0]]
        p0, r0 = end_effector_pose(m, reference_state(m))
        paths[name] = make_path("combined", p0, r0, m.system.tilt_axes, steps=args.steps)
    for rep in range(args.repeats):
        for key, m in models.items():
            path = paths[key[0]]
            runs[key].append(track(m, path.positions, path.rotations, state=reference_state(m)))
            print(f"repeat {rep + 1}: {key[0]:14s} {key[1]:8s} {1e3 * np.median(runs[key][-1].step_time[1:]):7.2f} ms")

    rows = []
    for (name, mode), rs in runs.items():
        m = models[name, mode]
        warm = np.concatenate([r.step_time[1:] for r in rs]) * 1e3
        its = np.concatenate([r.iterations[1:] for r in rs])
        evals = np.concatenate([r.evaluations[1:] for r in rs])
        newton = np.concatenate([r.newton_iterations[1:] / r.evaluations[1:] for r in rs])
        rows.append(
            {
                "example": name,
                "mode": mode,
                "controls": m.nu,
                "state": m.nx,
                "rows": m.system.n_constraints,
                "build_s": build[name, mode],
                "warm_ms": float(np.median(warm)),
                "warm_p90_ms": float(np.percentile(warm, 90)),
                "warm_max_ms": float(warm.max()),
                "step1_ms": statistics.median(1e3 * r.step_time[0] for r in rs),
                "bfgs_its": float(np.median(its)),
                "evals": float(np.median(evals)),
                "newton_per_eval": float(np.median(newton)),
                "max_pos_err": max(float(r.position_error.max()) for r in rs),
                "max_rot_err": max(float(r.rotation_error.max()) for r in rs),
                "max_residual": max(float(r.residual.max()) for r in rs),
                "reached": all(bool(reached(r).all()) for r in rs),
                "steps": args.steps,
                "repeats": args.repeats,
            }
        )
    total = time.perf_counter() - t_start

    # ---- convergence figure (Kumar 2019 Fig. 5 analogue)
    from matplotlib.figure import Figure

    from tmr.plot import save_figure

    fig = Figure(figsize=(10, 4.2))
    axes = [fig.add_subplot(1, 2, k + 1) for k in range(2)]
    mode = "compiled" if "compiled" in args.modes else args.modes[0]
    for name in args.examples:
        r = runs[name, mode][-1]
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

    four = [r for r in rows if r["example"].startswith("4dof")]
    verdict = "; ".join(
        f"{r['example']} ({r['mode']}): {r['warm_ms']:.2f} ms median, {r['warm_max_ms']:.1f} ms max — "
        f"{'meets' if r['warm_ms'] < TARGET_4DOF_MS else 'misses'} the median target"
        for r in four
    )
    nproc = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    threads = ", ".join(f"{v}={os.environ[v]}" for v in THREAD_VARS if v in os.environ)
    threads += " (set by the script)" if PINNED else " (from the environment)"
    load = "/".join(f"{x:.1f}" for x in load_start) + " → " + "/".join(f"{x:.1f}" for x in os.getloadavg())
    note = f"""\
`{" ".join(["python benchmarks/ccma.py", *sys.argv[1:]])}` — {datetime.date.today().isoformat()}, machine
`{platform.processor() or platform.machine()}`, nproc {nproc}, Python {platform.python_version()}; {versions(PACKAGES)};
{threads}; {source_version("src/tmr/ccma")}. Total run time {total:.0f} s; load average (1/5/15 min) {load}.

Path: `combined`, {args.steps} steps of (+1 mm x, y, z; +0.01 rad yaw and every tilt axis) from the reference
configuration, {args.repeats} repeats. Formulation: [`formulations/ccma.md`](../../formulations/ccma.md). Columns:
*m* controls, *6n* state size, *rows of C* constraint rows; *build* = description → compiled model (the `compiled`
build includes generating and, on a cache miss, compiling the C code); *warm step* = one IK solve of steps 2…K (BFGS
warm-started with the previous step's controls and state, Gauss–Newton initial inverse Hessian) — median, 90th
percentile and max over all repeats; *step 1* = the first step, median over repeats; *BFGS its*, *O evals* (each a
warm-started Newton solve + one sensitivity evaluation) and *Newton its / eval* are medians over the warm steps;
errors and residual energy are the worst over all steps; *all reached* = every step within 1e-5 m, 1e-4 rad and
E ≤ 1e-12 m².

Target of the project issue: < {TARGET_4DOF_MS:.0f} ms per small step for the 4-dof example. {verdict}.
"""
    (args.out / "ccma.md").write_text(
        "# CCMA sensitivity IK: per-step time and iterations\n\n"
        + note
        + "\n"
        + markdown(rows)
        + "\n![convergence](ccma_convergence.png)\n"
    )
    keys = [k for k, _, _ in COLUMNS] + ["steps", "repeats"]
    with (args.out / "ccma.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in keys})
    print(markdown(rows))


if __name__ == "__main__":
    main()
