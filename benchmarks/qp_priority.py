"""Strict priority of the lexicographic QP under stress, on every backend, against an independent reference.

    python benchmarks/qp_priority.py [--solvers osqp daqp proxqp clarabel] [--every 3] [--scenarios A B C D]
                                     [--no-long] [--out benchmarks/results]

A benchmark, not a test. For scenarios A–D, each with the default route (``shortest``: route followers in the tether
level) and the paper's RRT* route (``rrt``), it plans with ``--method qp`` in three settings — the defaults,
``robot_speed_max = 0.25`` (the leader lags: its level is solved alone and the levels below are frozen on an active
bound) and ``tether_smoothness = 0`` (the energy level is solved) — and two long chains (N = 10, 30, on the cluttered
band of ``qp_step.py``, ``tether_smoothness = 0``, first 120 steps), with every backend. Reported per plan:

* how many steps had a level ``relaxed`` (solved with a higher level's freeze loosened), ``failed``/``skipped`` (no
  backend solved it; the step kept the higher levels' optimum) or ``implied`` (no freedom left: nothing to solve),
  and the level solves taken over by a fallback backend (``metrics.json``: ``qp_levels``, ``qp_fallback_solves``);
* on every ``--every``-th step, the excess of each level's residual over the lexicographic optimum of the same step
  computed level by level from its definition with cvxpy + Clarabel (``reference_optima`` of
  ``tests/test_qp_priority.py``), relative to 1 + the optimum; the max over the sampled steps per level (≤ 0 means no
  worse than the reference), and the min over all levels (below 0: the QP's motion was better than the reference,
  possible within the feasibility tolerance 1e-5 of the hard rows or the reference's own accuracy);
* the largest joint difference from the ``osqp`` plan of the same case [rad, m], and the median QP step time.

Writes ``benchmarks/results/qp_priority.md`` and ``qp_priority.csv``.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import io
import math
import os
import platform
import sys
import time
import warnings
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))  # the reference solver lives in the tests

import numpy as np  # noqa: E402
from provenance import source_version, versions  # noqa: E402
from qp_step import cluttered_band  # noqa: E402
from tests.test_qp_priority import excess  # noqa: E402

from tmr.control.qp import solvers as qp_solvers  # noqa: E402
from tmr.planner import Problem, build_problem, check, make_qp, plan  # noqa: E402
from tmr.world.scenario import load_scenario  # noqa: E402

PACKAGES = ("numpy", "scipy", "osqp", "qpsolvers", "daqp", "proxsuite", "clarabel", "cvxpy")
DEFAULT_SOLVERS = ("osqp", "daqp", "proxqp", "clarabel")
VARIANTS: dict[str, dict[str, float]] = {
    "default": {},
    "lagging": {"robot_speed_max": 0.25},
    "no smoothness": {"tether_smoothness": 0.0},
}
LONG = ((10, 120), (30, 120))  # (N, steps) on the band

COLUMNS = [
    ("case", "case", "{}"),
    ("route", "route", "{}"),
    ("solver", "backend", "{}"),
    ("steps", "steps", "{}"),
    ("result", "plan", "{}"),
    ("lag_steps", "leader lags", "{}"),
    ("relaxed_steps", "relaxed", "{}"),
    ("failed_steps", "failed/skipped", "{}"),
    ("implied_steps", "implied", "{}"),
    ("fallbacks", "fallback solves", "{}"),
    ("sampled", "sampled", "{}"),
    ("excess_1", "max excess L1", "{:.1e}"),
    ("excess_2", "L2", "{:.1e}"),
    ("excess_3", "L3", "{:.1e}"),
    ("min_excess", "min excess", "{:.1e}"),
    ("dq", "max \\|q − q_osqp\\|", "{:.1e}"),
    ("ms", "ms/step", "{:.3f}"),
]


def with_params(problem: Problem, solver: str, steps: int | None = None) -> Problem:
    problem = dataclasses.replace(problem, qp_params=dataclasses.replace(problem.qp_params, solver=solver))
    if steps is None or steps >= problem.trajectory.t.size - 1:
        return problem
    tr = problem.trajectory
    k = steps + 1
    return dataclasses.replace(problem, trajectory=tr._replace(t=tr.t[:k], x=tr.x[:k], xd=tr.xd[:k], xdd=tr.xdd[:k]))


def steps_with(diag: dict[str, np.ndarray], codes: tuple[int, ...]) -> int:
    """Number of steps at which at least one level has one of the status ``codes``."""
    keys = [k for k in diag if k.startswith("qp_level:")]
    if not keys:
        return 0
    status = np.vstack([diag[k] for k in keys])
    return int(np.count_nonzero(np.isin(status, codes).any(axis=0)))


def run_case(problem: Problem, solver: str, every: int, steps: int | None) -> tuple[dict[str, Any], np.ndarray]:
    problem = with_params(problem, solver, steps)
    qp = make_qp(problem)
    K = problem.trajectory.t.size - 1
    qp.record_steps = set(range(0, K, every))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # a stray numerical warning is a bug: let it show
        p = plan(problem, qp)
    m = check(p, problem.env, goal_tolerance=problem.path_params.goal_tolerance if steps is None else math.inf)
    d = p.diagnostics
    ex = np.array([[np.nan if e is None else e for e in excess(r)] for _, r in sorted(qp.records.items())])
    ex = ex.reshape(-1, len(qp.levels))
    done = p.t.size - 1
    row = {
        "steps": done,
        "result": "ok" if p.success else "FAIL: " + (p.failure or "")[:60],
        "lag_steps": int(np.count_nonzero(d["leader_residual"][:done] > 1e-6)),
        "relaxed_steps": steps_with(d, (1,)),
        "failed_steps": steps_with(d, (3, 4)),
        "implied_steps": steps_with(d, (2,)),
        "fallbacks": m.qp_fallback_solves,
        "sampled": ex.shape[0],
        "min_excess": float(np.nanmin(ex)) if ex.size else math.nan,
        "ms": 1000 * float(np.nanmedian(d["step_time"])),
    }
    for i in range(3):
        col = ex[:, i] if ex.size and i < ex.shape[1] else np.array([])
        row[f"excess_{i + 1}"] = float(np.nanmax(col)) if col.size and np.isfinite(col).any() else math.nan
    return row, p.q


def cases(scenarios: list[str], long: bool) -> list[tuple[str, str, Problem, int | None]]:
    out = []
    for name in scenarios:
        for route in ("shortest", "rrt"):
            for variant, over in VARIANTS.items():
                problem = build_problem(load_scenario(name), seed=0, route=route, overrides=over)
                out.append((f"{name} {variant}", route, problem, None))
    if long:
        for n, steps in LONG:
            problem = build_problem(
                cluttered_band(n, 0), seed=0, n_robots=n, route="rrt", overrides={"tether_smoothness": 0.0}
            )
            out.append((f"band N={n} no smoothness", "rrt", problem, steps))
    return out


def fmt(value: Any, spec: str) -> str:
    if value is None or value == "" or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return spec.format(value) if spec != "{}" else str(value)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--solvers", nargs="+", default=list(DEFAULT_SOLVERS))
    ap.add_argument("--scenarios", nargs="+", default=list("ABCD"))
    ap.add_argument("--every", type=int, default=3, help="compare every k-th step with the reference")
    ap.add_argument("--no-long", action="store_true", help="skip the long chains (N = 10, 30)")
    ap.add_argument("--out", type=Path, default=HERE / "results")
    args = ap.parse_args()
    solvers = [s for s in args.solvers if s in qp_solvers()]
    t_start = time.perf_counter()
    rows = []
    for label, route, problem, steps in cases(args.scenarios, not args.no_long):
        base_q = None
        for solver in solvers:
            try:
                row, q = run_case(problem, solver, args.every, steps)
            except Exception as exc:  # a benchmark row, not a crash: the error is the result
                row, q = {"result": f"ERROR: {type(exc).__name__}: {exc}"[:120]}, None
            if solver == solvers[0]:
                base_q = q
            dq = math.nan
            if q is not None and base_q is not None and q.shape == base_q.shape:
                dq = float(np.max(np.abs(q - base_q)))
            row.update(case=label, route=route, solver=solver, dq=dq)
            rows.append(row)
            print(" | ".join(fmt(row.get(k), spec) for k, _, spec in COLUMNS), flush=True)
    total = time.perf_counter() - t_start
    write(args, rows, solvers, total)


def summary(rows: list[dict[str, Any]], solvers: list[str]) -> list[str]:
    lines = [
        "| backend | plans | steps with a relaxed level | with a failed level | fallback solves | max excess L1 | "
        "L2 | L3 | min excess | max \\|q − q_osqp\\| |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in solvers:
        r = [row for row in rows if row["solver"] == s and "steps" in row]

        def mx(key: str, rows: list[dict[str, Any]] = r) -> float:
            v = [row[key] for row in rows if isinstance(row.get(key), float) and math.isfinite(row[key])]
            return max(v) if v else math.nan

        mn = [row["min_excess"] for row in r if math.isfinite(row.get("min_excess", math.nan))]
        cells = [
            s,
            len(r),
            sum(row["relaxed_steps"] for row in r),
            sum(row["failed_steps"] for row in r),
            sum(row["fallbacks"] for row in r),
            *(fmt(mx(f"excess_{i}"), "{:.1e}") for i in (1, 2, 3)),
            fmt(min(mn) if mn else math.nan, "{:.1e}"),
            fmt(mx("dq"), "{:.1e}"),
        ]
        lines.append("| " + " | ".join(map(str, cells)) + " |")
    return lines


def write(args: argparse.Namespace, rows: list[dict[str, Any]], solvers: list[str], total: float) -> None:
    args.out.mkdir(parents=True, exist_ok=True)
    keys = [k for k, _, _ in COLUMNS]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, extrasaction="ignore")
    w.writeheader()
    for row in rows:
        w.writerow({k: row.get(k, "") for k in keys})
    (args.out / "qp_priority.csv").write_text(buf.getvalue())
    cmd = "python benchmarks/qp_priority.py " + " ".join(sys.argv[1:])
    head = [
        "# Strict priority of the lexicographic QP under stress, per backend",
        "",
        f"`{cmd.strip()}` — {datetime.date.today()}, machine `{platform.machine()}`, nproc {os.cpu_count()}, Python "
        f"{platform.python_version()}; {versions(PACKAGES)}; {source_version()}. Total run time {total:.0f} s.",
        "",
        "Each case is one plan per backend (`--method qp`, seed 0). *steps*: steps planned (the long chains stop",
        "at 120); *plan*: the checker's verdict (the lagging cases miss the goal by design: the reference outruns",
        "the 0.25 m/s bound); *leader lags*: steps where level 1 could not be met (solved on its own); *relaxed*,",
        "*failed/skipped*, *implied*: steps with at least one level in that status (`metrics.json` → `qp_levels`);",
        "*fallback solves*: level solves taken over by another backend (`qp_fallback_solves`: the primary failed,",
        "or its answer was not verified optimal and a second opinion was taken). *max excess Li*: over every",
        "`--every`-th step (*sampled*), the largest (f_i(x_QP) − f_i*) / (1 + f_i*), f_i the level's weighted",
        "residual and f_i* the lexicographic optimum of the same step from its definition (cvxpy + Clarabel,",
        "`reference_optima` in `tests/test_qp_priority.py`); *min excess*: the smallest over all levels (negative:",
        "the QP's motion beat the reference, within the 1e-5 feasibility tolerance of the hard rows or the",
        "reference's own accuracy). The tests accept an excess up to 1e-6. *max |q − q_osqp|*: largest joint",
        "difference from the `osqp` plan of the same case [rad, m]. *ms/step*: median QP step time (this machine,",
        "shared: compare within a column only).",
        "",
        "## Per backend, over every case",
        "",
        *summary(rows, solvers),
        "",
        "## Per case",
        "",
        "| " + " | ".join(h for _, h, _ in COLUMNS) + " |",
        "|" + "---|" * len(COLUMNS),
    ]
    body = ["| " + " | ".join(fmt(row.get(k), spec) for k, _, spec in COLUMNS) + " |" for row in rows]
    (args.out / "qp_priority.md").write_text("\n".join(head + body) + "\n")
    print(f"total {total:.0f} s; wrote {args.out / 'qp_priority.md'} and {args.out / 'qp_priority.csv'}")


if __name__ == "__main__":
    main()
