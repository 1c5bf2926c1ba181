"""Per-step time of the formulations: ``pinv`` vs the lexicographic ``qp`` with each QP solver, N = 3 … 100 robots.

    python benchmarks/qp_step.py [--sizes 3 10 30 100] [--repeats 3] [--seed 0]
                                 [--solvers osqp osqp-cold qpsolvers-osqp daqp proxqp] [--steps 30:150 100:20]

A benchmark, not a test. For every chain size N it builds one deterministic problem on a cluttered band (see
:func:`cluttered_band`), then runs ``pinv`` and ``qp`` with every solver ``--repeats`` times (interleaved: repeat r of
every formulation before repeat r + 1) with :func:`tmr.control.clik.run`, exactly as :func:`tmr.planner.solve` does, and
checks every plan with :func:`tmr.planner.check`. Reported per (N, method, solver):

* ``ms/step`` — loop wall time ``plan.wall_time`` / steps attempted (the loop includes the per-step distance-field
  sampling ``StepContext.update`` and the Euler integration), median over the repeats; ``× pinv`` divides by the
  ``pinv`` value of the same N in the same run.
* ``step`` — median over every step of every repeat of the time of ``formulation.step(ctx)`` alone (building the
  task/limit matrices and solving), measured by a thin timing wrapper around the formulation; ``× pinv`` as above.
* ``QP step_time`` — median of the QP's own ``plan.diagnostics["step_time"]`` (the same span, timed inside
  ``LexicographicQP.step``), and the median of ``solver_iterations`` (OSQP only; qpsolvers backends report 0) and the
  number of steps where the acceleration limits had to be relaxed.

BLAS runs on one thread (``OPENBLAS_NUM_THREADS=OMP_NUM_THREADS=1``) unless one of those variables is set by the caller,
e.g. ``OPENBLAS_NUM_THREADS=2 python benchmarks/qp_step.py`` measures the multithreaded default. The distance field of
the map is built (it is lazy) before anything is timed. ``--steps N:K`` caps the run at size N
to the first K steps of the same leader trajectory (the trajectory is truncated, not re-timed, so every formulation
sees the same reference; the goal check is skipped for a truncated run). Writes ``benchmarks/results/qp_step.md`` and
``qp_step.csv``.
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
import statistics
import sys
import time
import traceback
from pathlib import Path
from typing import Any

#: Environment variables that set the BLAS / OpenMP thread count (recorded in the note).
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
#: One control step is serial: unless the caller sets a thread count, BLAS runs on one thread (set before numpy is
#: imported). On a shared 2-core machine the multithreaded default is slower and far noisier at N = 100.
PINNED = not any(v in os.environ for v in THREAD_VARS)
if PINNED:
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = "1"

import numpy as np  # noqa: E402
from provenance import source_version, versions  # noqa: E402
from shapely.geometry import Point  # noqa: E402

#: Distributions whose versions the table records.
PACKAGES = ("numpy", "scipy", "osqp", "qpsolvers", "daqp", "proxsuite", "shapely")

from tmr.control.qp import solvers as qp_solvers  # noqa: E402
from tmr.planner import Problem, build_problem, check, make_pinv, make_qp  # noqa: E402
from tmr.planner import plan as run_formulation  # noqa: E402
from tmr.world.environment import Environment  # noqa: E402
from tmr.world.scenario import Scenario  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

DEFAULT_SIZES = (3, 10, 30, 100)
DEFAULT_SOLVERS = ("osqp", "osqp-cold", "qpsolvers-osqp", "daqp", "proxqp")
#: ``osqp`` without the warm active-set layer (:mod:`tmr.control.activeset`): OSQP alone, its answers unpolished.
COLD = "osqp-cold"
DEFAULT_STEPS = ("30:150", "100:20")

#: Initial robot spacing of :func:`tmr.planner.default_start` (largest d_lo 1.0 m + margin 0.2 m) [m].
START_SPACING = 1.2
#: Targets of the project issue.
TARGET_N3_US = 150.0  # µs per step at N = 3, including building the matrices
TARGET_N3_RATIO = 3.0  # × the pinv step at N = 3
TARGET_N100_MS = 10.0  # ms per step at N = 100
TARGET_N30_MAX_MS = 5.0  # no step above this at N = 30 (issue 14)

COLUMNS = [
    ("n_robots", "N", "{}"),
    ("method", "method", "{}"),
    ("solver", "solver", "{}"),
    ("steps", "steps", "{}"),
    ("ms_per_step", "ms/step (loop)", "{:.3f}"),
    ("ratio_loop", "× pinv", "{:.2f}"),
    ("step_ms", "step median [ms]", "{:.3f}"),
    ("ratio_step", "× pinv", "{:.2f}"),
    ("step_max_ms", "step max [ms]", "{:.1f}"),
    ("cpu_ms", "step CPU median [ms]", "{:.3f}"),
    ("cpu_max_ms", "step CPU max [ms]", "{:.1f}"),
    ("qp_step_ms", "QP step_time median [ms]", "{:.3f}"),
    ("iterations", "OSQP iters (median)", "{:.0f}"),
    ("relaxed", "relaxed steps", "{}"),
    ("result", "result", "{}"),
]


# ----------------------------------------------------------------------------------------------------- problem
def travel(n_robots: int) -> float:
    """Leader travel beyond its start [m]: 1.5 m per robot, between 4 and 12 m (≤ 1.5 m/s peak over 15 s)."""
    return float(np.clip(1.5 * n_robots, 4.0, 12.0))


def cluttered_band(n_robots: int, seed: int, width: float = 10.0, density: float = 1 / 6) -> Scenario:
    """A ``width`` m wide band with seeded random disc obstacles, the base at its left end, the goal to the right.

    The chain starts along the band's centre line (``default_start`` spaces the robots 1.2 m apart along the straight
    base–goal path), so the leader starts at x ≈ 1 + 1.2 N and drives :func:`travel` m further to the goal. Discs
    (radius 0.15–0.45 m, about one per 1/density m², surfaces ≥ 1.2 m apart) fill the band except a corridor of
    half-width 1.2 m round the centre line: the inflated obstacles stay ≥ 0.7 m from the start placement and the
    leader's straight path (more than the 0.6 m path clearance), and well inside the QP's 1.5 m clearance activation
    distance, so clearance rows are active all along the chain. The chain length is the room's: spans grow from
    1.2 m towards the tether target (3.3 m) only by bending round the obstacles.
    """
    rng = np.random.default_rng([seed, n_robots])
    lead_x = 1.0 + START_SPACING * n_robots
    length = lead_x + travel(n_robots) + 3.0
    yc = width / 2
    base, goal = np.array([1.0, yc]), np.array([lead_x + travel(n_robots), yc])
    discs: list[tuple[float, float, float]] = []
    wanted = int(length * width * density)
    for _ in range(50 * wanted):
        if len(discs) >= wanted:
            break
        x, y, r = rng.uniform(0, length), rng.uniform(0, width), rng.uniform(0.15, 0.45)
        if abs(y - yc) < 1.2 + r:
            continue
        if any((x - u) ** 2 + (y - v) ** 2 < (r + s + 1.2) ** 2 for u, v, s in discs):
            continue
        discs.append((x, y, r))
    env = Environment.from_geometry(
        [Point(x, y).buffer(r) for x, y, r in discs], (0.0, 0.0, length, width), safety_radius=0.5, resolution=0.1
    )
    return Scenario(
        name=f"band{n_robots}",
        description=f"{len(discs)} random discs in a {length:.1f} m × {width:.0f} m band (seed {seed})",
        environment=env,
        base=base,
        goal=goal,
        start=None,
        n_robots=n_robots,
    )


def truncated(problem: Problem, steps: int | None) -> Problem:
    """``problem`` with its leader trajectory cut to the first ``steps`` steps (None or ≥ K: unchanged)."""
    tr = problem.trajectory
    if steps is None or steps >= tr.t.size - 1:
        return problem
    k = steps + 1
    return dataclasses.replace(problem, trajectory=tr._replace(t=tr.t[:k], x=tr.x[:k], xd=tr.xd[:k], xdd=tr.xdd[:k]))


# ----------------------------------------------------------------------------------------------------- timing
class Timed:
    """A formulation wrapper recording the wall time of every ``step`` call and its CPU time (``thread_time``: what
    the step itself used, not the time other processes held the core; the machine is shared)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.name = inner.name
        self.times: list[float] = []
        self.cpu: list[float] = []

    def reset(self) -> None:
        self.times = []
        self.cpu = []
        self.inner.reset()

    def step(self, ctx: Any) -> Any:
        c0 = time.thread_time()
        t0 = time.perf_counter()
        try:
            return self.inner.step(ctx)
        finally:
            self.times.append(time.perf_counter() - t0)
            self.cpu.append(time.thread_time() - c0)


def formulation(problem: Problem, method: str, solver: str) -> Any:
    if method == "pinv":
        return make_pinv(problem)
    qp = dataclasses.replace(problem.qp_params, solver="osqp" if solver == COLD else solver)
    f = make_qp(dataclasses.replace(problem, qp_params=qp))
    if solver == COLD:
        f.warm_start = False  # no warm active set, no KKT polish: the persistent OSQP workspace alone
    return f


def outcome(plan: Any, metrics: Any, planned: int) -> str:
    """Short result label: ok, infeasible/stopped at step k, or the constraint violations the checker found."""
    if plan.success:
        return "ok"
    done = plan.t.size - 1
    if done < planned:
        kind = "infeasible" if "no common solution" in (plan.failure or "") else "stopped"
        return f"FAIL: {kind} at step {done}"
    parts = [f"{kind} ×{len(steps)}" for kind, steps in metrics.violation_steps.items() if steps]
    if "from the goal" in (plan.failure or ""):
        parts.append(f"goal missed by {metrics.final_leader_error:.2f} m")
    return "FAIL: " + ", ".join(parts) if parts else f"FAIL: {plan.failure}"


def run_once(problem: Problem, method: str, solver: str, full: bool) -> dict[str, Any]:
    wrapped = Timed(formulation(problem, method, solver))
    plan = run_formulation(problem, wrapped)
    metrics = check(plan, problem.env, goal_tolerance=problem.path_params.goal_tolerance if full else math.inf)
    diag = plan.diagnostics
    n_attempted = len(wrapped.times)

    def finite(key: str) -> list[float]:
        if key not in diag:
            return []
        v = np.asarray(diag[key], float)
        return v[np.isfinite(v)].tolist()

    return {
        "wall": plan.wall_time,
        "steps": n_attempted,
        "ms_per_step": 1000 * plan.wall_time / max(n_attempted, 1),
        "step_times": wrapped.times,
        "step_cpu": wrapped.cpu,
        "qp_step_times": finite("step_time"),
        "iterations": finite("solver_iterations"),
        "relaxed": int(np.nansum(diag["relaxed"])) if "relaxed" in diag else None,
        "result": outcome(plan, metrics, problem.trajectory.t.size - 1),
        "failure": plan.failure or "",
    }


def summarise(n: int, method: str, solver: str, runs: list[dict[str, Any]], full: bool) -> dict[str, Any]:
    def med(values: list[float], scale: float = 1.0) -> float:
        return scale * statistics.median(values) if values else math.nan

    results = sorted({r["result"] for r in runs})
    relaxed = sorted({r["relaxed"] for r in runs if r["relaxed"] is not None})
    return {
        "n_robots": n,
        "method": method,
        "solver": solver,
        "steps": runs[0]["steps"] if len({r["steps"] for r in runs}) == 1 else "/".join(str(r["steps"]) for r in runs),
        "full_trajectory": full,
        "repeats": len(runs),
        "ms_per_step": med([r["ms_per_step"] for r in runs]),
        "ms_per_step_runs": " ".join(f"{r['ms_per_step']:.4f}" for r in runs),
        "step_ms": med([t for r in runs for t in r["step_times"]], 1000),
        "step_p90_ms": 1000 * float(np.percentile([t for r in runs for t in r["step_times"]], 90)),
        "step_max_ms": 1000 * max(t for r in runs for t in r["step_times"]),
        "cpu_ms": med([t for r in runs for t in r["step_cpu"]], 1000),
        "cpu_max_ms": 1000 * max(t for r in runs for t in r["step_cpu"]),
        "qp_step_ms": med([t for r in runs for t in r["qp_step_times"]], 1000),
        "iterations": med([t for r in runs for t in r["iterations"]]) if solver in ("osqp", COLD) else "",
        "iterations_max": max((t for r in runs for t in r["iterations"]), default="")
        if solver in ("osqp", COLD)
        else "",
        "relaxed": "/".join(map(str, relaxed)) if relaxed else "",
        "result": results[0] if len(results) == 1 else "varies: " + " | ".join(results),
        "failure": " | ".join(sorted({r["failure"] for r in runs if r["failure"]})),
    }


def error_row(n: int, method: str, solver: str, exc: BaseException) -> dict[str, Any]:
    row = {key: "" for key, _, _ in COLUMNS}
    row.update(n_robots=n, method=method, solver=solver, result=f"ERROR: {type(exc).__name__}: {exc}"[:200])
    row["failure"] = "".join(traceback.format_exception_only(type(exc), exc)).strip()
    return row


# ----------------------------------------------------------------------------------------------------- output
def fmt(value: Any, spec: str) -> str:
    if value is None or value == "" or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return spec.format(value) if spec != "{}" else str(value)


def markdown(rows: list[dict[str, Any]]) -> str:
    out = io.StringIO()
    out.write("| " + " | ".join(h for _, h, _ in COLUMNS) + " |\n")
    out.write("|" + "---|" * len(COLUMNS) + "\n")
    for r in rows:
        out.write("| " + " | ".join(fmt(r.get(k), f) for k, _, f in COLUMNS) + " |\n")
    return out.getvalue()


def targets(rows: list[dict[str, Any]]) -> str:
    """The project issue's targets, checked against the measured rows."""

    def get(n: int, method: str, solver: str) -> dict[str, Any] | None:
        return next((r for r in rows if r["n_robots"] == n and r["method"] == method and r["solver"] == solver), None)

    def yes(ok: bool) -> str:
        return "**met**" if ok else "**not met**"

    lines = []
    pinv3 = get(3, "pinv", "–")
    for r in rows:
        if r["method"] != "qp" or not isinstance(r["ms_per_step"], float):
            continue
        if r["n_robots"] == 3 and pinv3 is not None:
            loop_us, step_us = 1000 * r["ms_per_step"], 1000 * r["step_ms"]
            lines.append(
                f"- N = 3, qp/{r['solver']}: {loop_us:.0f} µs per loop step ({r['ratio_loop']:.1f}× pinv), "
                f"{step_us:.0f} µs per formulation step ({r['ratio_step']:.1f}× pinv) — ≤ {TARGET_N3_US:.0f} µs: "
                f"{yes(step_us <= TARGET_N3_US)}; ≤ {TARGET_N3_RATIO:.0f}× pinv: "
                f"loop {yes(r['ratio_loop'] <= TARGET_N3_RATIO)}, "
                f"formulation step {yes(r['ratio_step'] <= TARGET_N3_RATIO)}."
            )
        if r["n_robots"] == 30:
            lines.append(
                f"- N = 30, qp/{r['solver']}: worst step {r['step_max_ms']:.1f} ms wall, {r['cpu_max_ms']:.1f} ms CPU "
                f"(median {r['step_ms']:.2f} ms wall, {r['cpu_ms']:.2f} ms CPU) — no step above "
                f"{TARGET_N30_MAX_MS:.0f} ms: wall {yes(r['step_max_ms'] <= TARGET_N30_MAX_MS)}, "
                f"CPU {yes(r['cpu_max_ms'] <= TARGET_N30_MAX_MS)}."
            )
        if r["n_robots"] == 100:
            lines.append(
                f"- N = 100, qp/{r['solver']}: {r['ms_per_step']:.1f} ms per loop step, {r['step_ms']:.1f} ms per "
                f"formulation step (median; first {r['steps']} steps) — ≤ {TARGET_N100_MS:.0f} ms "
                f"{yes(max(r['ms_per_step'], r['step_ms']) <= TARGET_N100_MS)}."
            )
    return "\n".join(lines) if lines else "- (N = 3 or N = 100 not in this run)"


def parse_steps(specs: list[str]) -> dict[int, int]:
    caps = {}
    for spec in specs:
        try:
            n, k = spec.split(":")
            caps[int(n)] = int(k)
        except ValueError:
            raise SystemExit(f"--steps wants N:K pairs (e.g. 100:30), got {spec!r}") from None
        if caps[int(n)] < 1:
            raise SystemExit(f"--steps: K must be ≥ 1, got {spec!r}")
    return caps


# ----------------------------------------------------------------------------------------------------- main
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="+", type=int, default=list(DEFAULT_SIZES), help="chain sizes N")
    ap.add_argument("--repeats", type=int, default=3, help="runs per (N, method, solver); the median is reported")
    ap.add_argument("--solvers", nargs="+", default=list(DEFAULT_SOLVERS), help="QP solvers (see qp.solvers())")
    ap.add_argument("--seed", type=int, default=0, help="seed of the obstacles and of the leader's RRT*")
    ap.add_argument(
        "--steps",
        nargs="*",
        default=list(DEFAULT_STEPS),
        metavar="N:K",
        help="run size N for its first K steps only (default: %(default)s; '--steps' alone: full trajectories)",
    )
    ap.add_argument("--out", type=Path, default=RESULTS, help="directory of qp_step.md / qp_step.csv")
    args = ap.parse_args()
    if args.repeats < 1:
        raise SystemExit("--repeats must be ≥ 1")
    available = qp_solvers()
    unknown = [s for s in args.solvers if s not in [*available, COLD]]
    if unknown:
        raise SystemExit(f"unknown or uninstalled QP solver(s) {unknown}; available: {', '.join(available)}")
    caps = parse_steps(args.steps)
    variants = [("pinv", "–"), *(("qp", s) for s in args.solvers)]

    t_start = time.perf_counter()
    load_start = os.getloadavg()
    rows: list[dict[str, Any]] = []
    problems_note = []
    for n in args.sizes:
        t0 = time.perf_counter()
        scenario = cluttered_band(n, args.seed)
        problem = build_problem(scenario, seed=args.seed, n_robots=n, route="rrt")
        problem.env.clearance_and_gradient(np.array([problem.chain.base]))  # build the lazy distance field now
        K_full = problem.trajectory.t.size - 1
        problem = truncated(problem, caps.get(n))
        K = problem.trajectory.t.size - 1
        full = K == K_full
        build = time.perf_counter() - t0
        problems_note.append(
            f"N = {n}: {scenario.description}, goal {travel(n):.1f} m beyond the leader's start, "
            f"{K}/{K_full} steps{'' if full else ' (truncated)'}, built in {build:.1f} s"
        )
        print(f"N = {n}: {scenario.description}; {K}/{K_full} steps; build {build:.1f} s", file=sys.stderr)
        runs: dict[tuple[str, str], list[dict[str, Any]]] = {v: [] for v in variants}
        errors: dict[tuple[str, str], BaseException] = {}
        for rep in range(args.repeats):
            for method, solver in variants:
                if (method, solver) in errors:
                    continue
                try:
                    res = run_once(problem, method, solver, full)
                except Exception as exc:  # noqa: BLE001 - a library error is a result of the benchmark
                    errors[(method, solver)] = exc
                    print(f"  {method}/{solver}: ERROR\n{traceback.format_exc()}", file=sys.stderr)
                    continue
                runs[(method, solver)].append(res)
                print(
                    f"  rep {rep + 1} {method:4s} {solver:15s} {res['ms_per_step']:9.3f} ms/step  {res['result']}",
                    file=sys.stderr,
                )
        size_rows = [
            error_row(n, m, s, errors[(m, s)]) if (m, s) in errors else summarise(n, m, s, runs[(m, s)], full)
            for m, s in variants
        ]
        base = size_rows[0]
        for r in size_rows:
            for key, ref in (("ratio_loop", "ms_per_step"), ("ratio_step", "step_ms")):
                ok = isinstance(r.get(ref), float) and isinstance(base.get(ref), float) and base[ref] > 0
                r[key] = r[ref] / base[ref] if ok else math.nan
        rows.extend(size_rows)
    total = time.perf_counter() - t_start
    load = f"load average (1/5/15 min) {'/'.join(f'{x:.1f}' for x in load_start)} at the start, " + (
        f"{'/'.join(f'{x:.1f}' for x in os.getloadavg())} at the end"
    )

    table = markdown(rows)
    machine = platform.processor() or platform.machine()
    capped = ", ".join(f"N = {n}: first {k} steps" for n, k in sorted(caps.items()) if n in args.sizes) or "none"
    nproc = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    threads = ", ".join(f"{v}={os.environ[v]}" for v in THREAD_VARS if v in os.environ)
    threads += " (set by the script: one thread per step)" if PINNED else " (from the environment)"
    note = f"""\
`{" ".join(["python benchmarks/qp_step.py", *sys.argv[1:]])}` — {datetime.date.today().isoformat()}, machine
`{machine}`, nproc {nproc}, Python {platform.python_version()}; {versions(PACKAGES)}; {threads}; {source_version()}.
Total run time {total:.0f} s;
{load} (a load above 1 on an otherwise idle machine means other processes competed for the {nproc} cores).

Problem per N: a cluttered band (`cluttered_band` in the script: seeded random discs, a free corridor of half-width
1.2 m on the centre line), the chain placed by `build_problem(..., n_robots=N)` 1.2 m apart along the base–goal line,
default parameters (Ts = 0.05 s, T_end = 15 s, 300 steps), seed {args.seed}. The leader drives 1.5 m per robot
(4–12 m) beyond its start; the spans start at 1.2 m and the tether task pulls them towards 3.3 m, so the chain has to
bend round the obstacles.

{chr(10).join("- " + p for p in problems_note)}

Columns: *ms/step (loop)* = `plan.wall_time` / steps attempted (includes the per-step distance-field sampling of
`StepContext.update`), median of {args.repeats} repeats; *step median* = median over all steps and repeats of
`formulation.step(ctx)` alone (task and limit matrices + solve), *step max* its maximum; *× pinv* = ratio to the
`pinv` row of the same N in this run; *QP step_time* = median of the QP's own `diagnostics["step_time"]`; *OSQP
iters* = median over steps of the iterations summed over the levels (the qpsolvers backends report none); *relaxed
steps* = steps where the acceleration limits were dropped to find a solution. *result*: `ok`, or what the checker
found (`FAIL: <violated constraint> ×<samples>`; `infeasible at step k` = `InfeasibleStep`, the run stopped and its
timing covers the steps done). Step caps: {capped}; a capped run uses the first K steps of the same trajectory and
skips the goal check. `qpsolvers-osqp` sets up a fresh OSQP problem per level and step; `osqp` keeps a persistent
workspace per level, with the warm active-set layer (`tmr.control.activeset`: the previous step's active set
solved by one KKT solve and verified; on a miss a coarse OSQP pass, 1e-5 and ≤ 400 iterations, then its KKT polish);
`osqp-cold` is the same workspace without that layer (OSQP alone at 1e-8, unpolished); `daqp` and `proxqp` are the
warm-startable active-set / proximal solvers through qpsolvers (their answers polished by the same KKT check).
*step CPU* is the step's `thread_time` (what the step used, not time other processes held the core). `pinv` is
the paper's baseline, with no hard limits: its clearance violations are its own, the timing is still valid.

Targets of the project issues: N = 3 ≤ {TARGET_N3_US:.0f} µs per step including building the matrices and ≤
{TARGET_N3_RATIO:.0f}× the pinv step; N = 30 no step above {TARGET_N30_MAX_MS:.0f} ms (issue 14); N = 100 ≤
{TARGET_N100_MS:.0f} ms per step.

{targets(rows)}
"""
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "qp_step.md").write_text("# Per-step time: pinv vs lexicographic QP\n\n" + note + "\n" + table)
    keys = [k for k, _, _ in COLUMNS] + [
        "full_trajectory",
        "repeats",
        "ms_per_step_runs",
        "step_p90_ms",
        "iterations_max",
        "failure",
    ]
    with open(args.out / "qp_step.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in keys})
    print(table)
    print(targets(rows))
    print(f"\ntotal {total:.0f} s; wrote {args.out / 'qp_step.md'} and {args.out / 'qp_step.csv'}")


if __name__ == "__main__":
    main()
