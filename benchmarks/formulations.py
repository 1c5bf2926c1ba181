"""Which formulation wins, and by how much: pinv / qp / horizon on scenarios A–D, plus the chain-size scaling run.

    python benchmarks/formulations.py [--scenarios A B C D] [--methods pinv qp horizon] [--seed 0] [--repeats 3]
                                      [--skip-scaling]

For every scenario × method it builds the problem (leader RRT* + time law, timed: *build*), plans ``--repeats`` times
(*ms/step* = median loop time / steps), and records one end-to-end time (*total* = build + plan + check). The scores
are those of :func:`tmr.sweep.runs.score` — the same as ``python -m tmr.sweep bench`` gives in parallel:
success, f1–f4 (Caruso 2021 eq. 24–27), min robot / tether clearance to the inflated obstacles, max span / d_max,
min robot–robot distance, peak robot speed and acceleration, and the bounds of the distance errors of Fig. 7
(span_i − mean span). Runs are serial so the timings are not disturbed by concurrent plans.

The scaling run (N = 3, 10, 30, 100 robots) and the QP backend comparison are ``benchmarks/qp_step.py``: it is run
first (unless ``--skip-scaling``, which embeds its last committed table) and its table is included.

Writes ``benchmarks/results/formulations.md``, ``formulations.csv``, per scenario ``formulations_<S>.png`` (chain poses
of every method side by side, Caruso 2021 Fig. 5, and the distance errors of Fig. 7 below them), and the single-run
figures ``<S>_<method>_chain_poses.png``.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from tmr.checks.metrics import distance_errors
from tmr.planner import METHODS, build_problem, solve
from tmr.sweep.bench import BENCH_HEADER, bench_cells
from tmr.sweep.report import csv_text, fmt, markdown_table
from tmr.sweep.runs import RunResult, RunSpec, score
from tmr.views.plot import plot_chain_poses, save_figure
from tmr.world.scenario import load_scenario

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"

#: Caruso 2021 §5 (Fig. 7): bounds the paper gives for |distance error| per scenario [m] (its text names C twice;
#: A has no stated bound).
PAPER_DIST_ERR = {"A": None, "B": 0.05, "C": 0.05, "D": 0.008}


def run_cell(scenario: str, method: str, seed: int, repeats: int) -> tuple[RunResult, dict[str, Any], Any, Any]:
    """Build, plan ``repeats`` times, score; returns (result, timings, last plan, problem)."""
    t0 = time.perf_counter()
    problem = build_problem(load_scenario(scenario), seed=seed, route="rrt")  # the paper's setting
    build = time.perf_counter() - t0
    walls = []
    total = math.nan
    for i in range(repeats):
        t1 = time.perf_counter()
        plan, metrics = solve(problem, method)
        if i == 0:
            total = build + time.perf_counter() - t1
        walls.append(plan.wall_time)
    spec = RunSpec(scenario, method, seed, (), None, repeats)
    res = score(spec, plan, metrics, problem.path_params.goal_tolerance, walls)
    return res, {"build_s": build, "total_s": total}, plan, problem


def scenario_figure(scenario: str, cells: list[tuple[str, Any, Any]]) -> Any:
    """Chain poses (Fig. 5) of every method side by side, distance errors (Fig. 7) below."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from tmr.views.plot import _draw_environment, _pose_indices  # house plotting helpers (private, same package)

    n = len(cells)
    fig = Figure(figsize=(5.0 * n, 8.0), layout="constrained")
    axes = fig.subplots(2, n, squeeze=False, height_ratios=[2.2, 1])
    for col, (method, plan, problem) in enumerate(cells):
        ax = axes[0, col]
        _draw_environment(ax, problem.env)
        robots = np.asarray(plan.robots)
        ax.plot(plan.reference[:, 0], plan.reference[:, 1], color="#e377c2", ls="--", lw=1.0)
        idx = _pose_indices(np.asarray(plan.t), 3.0)
        colors = matplotlib.colormaps["viridis"](np.linspace(0, 1, len(idx)))
        for c, k in zip(colors, idx, strict=True):
            pts = np.vstack([plan.base[:2], robots[k]])
            ax.plot(pts[:, 0], pts[:, 1], "-o", color=c, ms=3, lw=1.2)
        ax.plot(*plan.base[:2], "ks", ms=6)
        ax.set_aspect("equal")
        ok = "ok" if plan.success else "FAILED"
        ax.set_title(f"{scenario} / {method}: {ok}")
        ax2 = axes[1, col]
        err = distance_errors(plan)
        for i in range(err.shape[1]):
            ax2.plot(plan.t, err[:, i], lw=1.0, label=f"tether {i + 1}")
        bound = PAPER_DIST_ERR.get(scenario)
        if bound:
            ax2.axhspan(-bound, bound, color="0.85", zorder=0, label=f"paper ±{bound} m")
        ax2.set_xlabel("t [s]")
        ax2.set_ylabel("span − mean span [m]")
        ax2.legend(fontsize=7, loc="upper right")
    return fig


def qp_step_table(path: Path) -> str:
    """The table and its header note from ``qp_step.md`` (everything after the title)."""
    if not path.exists():
        return "_`benchmarks/results/qp_step.md` not found: run `python benchmarks/qp_step.py`._\n"
    text = path.read_text()
    body = text.split("\n", 1)[1] if text.startswith("#") else text
    return body.replace("\n## ", "\n#### ").replace("\n# ", "\n### ")


def winners(rows: list[RunResult]) -> str:
    """Per scenario: which methods succeed, and f1–f4 of each method divided by qp's (raw values for failed
    plans, in brackets)."""
    header = ["scenario", "method", "success", "f1 / qp", "f2 / qp", "f3 / qp", "f4 / qp", "ms/step / qp"]
    out = []
    for s in dict.fromkeys(r.spec.scenario for r in rows):
        cell = {r.spec.method: r for r in rows if r.spec.scenario == s}
        ref = cell.get("qp")
        for m, r in cell.items():
            if ref is None:
                continue
            ratios = []
            for i in range(4):
                v = r.raw[i] / ref.raw[i] if ref.raw[i] > 0 else math.nan
                ratios.append(fmt(v, ".3g") if r.success else f"({fmt(v, '.3g')})")
            out.append([s, m, fmt(r.success), *ratios, fmt(r.ms_per_step / ref.ms_per_step, ".3g")])
    return markdown_table(header, out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["A", "B", "C", "D"])
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-scaling", action="store_true", help="do not rerun benchmarks/qp_step.py")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    if not args.skip_scaling:
        subprocess.run([sys.executable, str(HERE / "qp_step.py"), "--out", str(args.out)], check=True)
    results: list[RunResult] = []
    timings: list[dict[str, Any]] = []
    for s in args.scenarios:
        cells = []
        for m in args.methods:
            res, tim, plan, problem = run_cell(s, m, args.seed, args.repeats)
            results.append(res)
            timings.append(tim)
            cells.append((m, plan, problem))
            save_figure(plot_chain_poses(plan, problem.env), args.out / f"{s}_{m}_chain_poses.png")
            print(f"{s} {m}: success {res.success}, {res.ms_per_step:.3f} ms/step", file=sys.stderr)
        save_figure(scenario_figure(s, cells), args.out / f"formulations_{s}.png")

    header = [*BENCH_HEADER, "build [s]", "plan [ms/step]", "total [s]"]
    rows = []
    for r, tim in zip(results, timings, strict=True):
        cells = bench_cells(r)
        cells += [fmt(tim["build_s"], ".2f"), fmt(r.ms_per_step, ".3f"), fmt(tim["total_s"], ".2f")]
        rows.append(cells)
    derr = markdown_table(
        ["scenario", *[f"{m}: min / max [m]" for m in args.methods], "paper bound |e| [m]"],
        [
            [
                s,
                *[
                    f"{fmt(r.distance_error_min, '+.3f')} / {fmt(r.distance_error_max, '+.3f')}"
                    + ("" if r.success else " (failed)")
                    for m in args.methods
                    for r in results
                    if r.spec.scenario == s and r.spec.method == m
                ],
                fmt(PAPER_DIST_ERR.get(s), ".3g"),
            ]
            for s in args.scenarios
        ],
    )
    load = " / ".join(f"{v:.1f}" for v in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"
    md = [
        "# Formulations on scenarios A–D: pinv vs qp vs horizon\n",
        f"`python benchmarks/formulations.py` — {datetime.date.today().isoformat()}, {platform.machine()}, "
        f"nproc {os.cpu_count()}, Python {platform.python_version()}; seed {args.seed}, {args.repeats} repeats; "
        f"load average at the end {load}; total run time {time.perf_counter() - started:.0f} s.\n",
        "Formulations: [`pinv`](../../formulations/pinv.md) (the paper's task-priority CLIK), "
        "[`qp`](../../formulations/qp.md) (lexicographic QP with hard limits), "
        "[`horizon`](../../formulations/horizon.md) (whole-horizon NLP warm-started from `qp`). "
        "f1–f4 in brackets: the plan failed a hard constraint (the paper scores it +∞); the bracketed values are "
        "those of the recorded motion. Clearances are signed distances to the obstacles grown by the 0.5 m safety "
        "radius (< 0 = collision); *min robot–robot* must stay ≥ 2r = 1 m; *dist err* = span_i − mean span "
        "(Fig. 7). *build* = leader RRT* + time law, *plan* = median loop time over the repeats per step, "
        "*total* = build + one plan + check. The same scores come out of `python -m tmr.sweep bench` "
        "(parallel, any executor).\n",
        "## Headline table\n",
        markdown_table(header, rows),
        "## Who wins, by how much (ratios to `qp` on the same scenario)\n",
        "Values < 1: smaller (better) than `qp`; in brackets: that method's plan failed.\n",
        winners(results),
        "## Distance-error bounds (Caruso 2021 Fig. 7)\n",
        derr,
        "## Figures\n",
        "\n".join(f"- `formulations_{s}.png`: chain poses every 3 s and distance errors" for s in args.scenarios)
        + "\n",
        "## Scaling with the number of robots and QP backends (`benchmarks/qp_step.py`)\n",
        ("Embedded from the last run (`--skip-scaling`).\n" if args.skip_scaling else "")
        + qp_step_table(args.out / "qp_step.md"),
    ]
    (args.out / "formulations.md").write_text("\n".join(md))
    csv_rows = []
    for r, tim in zip(results, timings, strict=True):
        row = r.row(timing=True)
        row.update(tim)
        csv_rows.append(row)
    (args.out / "formulations.csv").write_text(csv_text(csv_rows))
    print(markdown_table(header, rows))


if __name__ == "__main__":
    main()
