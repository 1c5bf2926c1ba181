"""Whole-horizon NLP (``horizon``) vs the per-step lexicographic QP (``qp``) on scenarios A–D, with cold wall times.

    python benchmarks/horizon.py [--scenarios A B C D] [--repeats 3] [--seed 0]

A benchmark, not a test. Every repeat of every scenario runs in a **new Python process** (cold: imports, the lazy
distance field of the map, the casadi transcription and IPOPT's first call all count), which

1. builds the problem (``tmr.build_problem(load_scenario(X), seed)``: RRT* + time law; timed as ``build``),
2. solves ``qp`` (its metrics and its loop time; ``warm`` is that solve's whole time) and passes it to
   ``plan_horizon(problem, qp_plan)`` as the warm start — ``horizon wall`` is ``warm`` plus that call's
   ``plan.wall_time`` (transcription + IPOPT rounds, in the columns ``transcr.``, ``IPOPT``),
3. checks both plans with :func:`tmr.planner.check` (exact shapely clearances of robots and tether segments, spans,
   separation, goal).

``process`` is the whole child process (interpreter start to exit) seen from the parent. Times are medians over the
repeats; metrics come from the first repeat (both planners are deterministic: same inputs, same bytes). Writes
``benchmarks/results/horizon.md`` and ``horizon.csv``.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"

METRIC_KEYS = (
    "success",
    "f1",
    "f2",
    "f3",
    "f4",
    "min_robot_clearance",
    "min_tether_clearance",
    "max_span_ratio",
    "min_separation",
    "peak_speed",
    "peak_acceleration",
    "max_tracking_error",
    "n_violation_steps",
)


def child(scenario: str, seed: int) -> dict:
    """One cold run (in its own process); returns a JSON-ready dict."""
    t0 = time.perf_counter()
    from tmr.control.horizon import plan_horizon
    from tmr.planner import build_problem, check, solve
    from tmr.world.scenario import load_scenario

    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    problem = build_problem(load_scenario(scenario), seed=seed, route="rrt")  # the paper's setting
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    qp_plan, qp = solve(problem, "qp")
    t_warm = time.perf_counter() - t0
    plan = plan_horizon(problem, qp_plan)  # the planner passes the qp plan in the same way
    d = plan.diagnostics
    hz = check(plan, problem.env, goal_tolerance=problem.path_params.goal_tolerance)
    out = {
        "import_s": t_import,
        "build_s": t_build,
        "horizon_wall_s": t_warm + plan.wall_time,
        "warm_s": t_warm,
        "transcription_s": d["transcription_time"],
        "ipopt_s": d["solve_time"],
        "iterations": d["ipopt_iterations"],
        "rounds": d["rounds"],
        "rows": d["rows"],
        "clearance_rows": d["clearance_rows"],
        "samples_per_link": d["samples_per_link"],
        "status": d["ipopt_status"],
        "objective_warm": d["objective_warm_start"],
        "objective": d["objective"],
        "qp_wall_s": qp_plan.wall_time,
        "qp": {k: getattr(qp, k) for k in METRIC_KEYS},
        "horizon": {k: getattr(hz, k) for k in METRIC_KEYS},
    }
    return json.loads(json.dumps(out, default=float))


def run_cold(scenario: str, seed: int) -> dict:
    env = dict(os.environ)
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, __file__, "--child", scenario, "--seed", str(seed)],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"scenario {scenario}: child failed\n{res.stderr[-3000:]}")
    out = json.loads(res.stdout.strip().splitlines()[-1])
    out["process_s"] = wall
    return out


def fmt(v: float, spec: str) -> str:
    return format(float(v), spec)


def tables(rows: dict[str, list[dict]], seed: int, repeats: int) -> tuple[str, list[list]]:
    md = io.StringIO()
    csv_rows: list[list] = [
        [
            "scenario", "method", "success", "f1", "f2", "f3", "f4", "min_robot_clearance", "min_tether_clearance",
            "max_span_ratio", "min_separation", "peak_speed", "peak_acceleration", "wall_s", "f1_ratio", "f4_ratio",
        ]
    ]  # fmt: skip
    md.write("| scenario | method | success | f1 | f2 [m²] | f3 [m²] | f4 | min robot clr [m] | min tether clr [m] | "
             "max span/d_max | min sep [m] | peak speed [m/s] | peak acc [m/s²] | wall [s] |\n")  # fmt: skip
    md.write("|" + "---|" * 14 + "\n")
    for sc, runs in rows.items():
        first = runs[0]
        walls = {
            "qp": statistics.median(r["qp_wall_s"] for r in runs),
            "horizon": statistics.median(r["horizon_wall_s"] for r in runs),
        }
        for method in ("qp", "horizon"):
            m = first[method]
            ratio1 = m["f1"] / first["qp"]["f1"]
            ratio4 = m["f4"] / first["qp"]["f4"]
            md.write(
                f"| {sc} | {method} | {m['success']} | {fmt(m['f1'], '.4g')} | {fmt(m['f2'], '.4g')} | "
                f"{fmt(m['f3'], '.3g')} | {fmt(m['f4'], '.4g')} | {fmt(m['min_robot_clearance'], '+.3f')} | "
                f"{fmt(m['min_tether_clearance'], '+.3f')} | {fmt(m['max_span_ratio'], '.3f')} | "
                f"{fmt(m['min_separation'], '.3f')} | {fmt(m['peak_speed'], '.2f')} | "
                f"{fmt(m['peak_acceleration'], '.2f')} | {fmt(walls[method], '.2f')} |\n"
            )
            csv_rows.append(
                [sc, method, m["success"], m["f1"], m["f2"], m["f3"], m["f4"], m["min_robot_clearance"],
                 m["min_tether_clearance"], m["max_span_ratio"], m["min_separation"], m["peak_speed"],
                 m["peak_acceleration"], walls[method], ratio1, ratio4]
            )  # fmt: skip
    md.write("\n### Ratios horizon / qp (lower is better)\n\n")
    md.write("| scenario | f1 | f2 | f4 | cost w1 f1 + w2 f2 + w4 f4 (horizon / warm start) |\n")
    md.write("|---|---|---|---|---|\n")
    for sc, runs in rows.items():
        r = runs[0]
        md.write(
            f"| {sc} | {r['horizon']['f1'] / r['qp']['f1']:.3f} | {r['horizon']['f2'] / r['qp']['f2']:.4f} | "
            f"{r['horizon']['f4'] / r['qp']['f4']:.4f} | {r['objective'] / r['objective_warm']:.4f} |\n"
        )
    md.write(f"\n### Wall time, cold (new process per run), median of {repeats}\n\n")
    md.write(
        "| scenario | horizon wall [s] | = warm (qp) [s] | + transcr. [s] | + IPOPT [s] | IPOPT iter. | rounds | "
        "NLP rows (clearance) | build [s] | process [s] | qp loop [s] | status |\n|" + "---|" * 12 + "\n"
    )
    for sc, runs in rows.items():

        def med(key: str, runs: list[dict] = runs) -> float:
            return statistics.median(r[key] for r in runs)

        r = runs[0]
        walls = ", ".join(f"{x['horizon_wall_s']:.2f}" for x in runs)
        md.write(
            f"| {sc} | **{med('horizon_wall_s'):.2f}** ({walls}) | {med('warm_s'):.2f} | "
            f"{med('transcription_s'):.2f} | {med('ipopt_s'):.2f} | {r['iterations']} | {r['rounds']} | "
            f"{r['rows']} ({r['clearance_rows']}) | "
            f"{med('build_s'):.2f} | {med('process_s'):.2f} | {med('qp_wall_s'):.2f} | {r['status']} |\n"
        )
    md.write(
        f"\nSeed {seed}; {platform.machine()} with {os.cpu_count()} cores, Python {platform.python_version()}. "
        "f1–f4: Caruso 2021 eq. 24–27 (`tmr.checks.metrics.fitness`). Clearances are exact (shapely) signed distances "
        "to the "
        "obstacles grown by the 0.5 m safety radius. `horizon wall` = the qp warm start plus "
        "`plan_horizon(problem, qp_plan)`, so it includes the qp plan, the transcription and every IPOPT round; "
        "`build` (RRT* + time law) and `process` (interpreter, imports, build, both planners, checks) are outside it.\n"
    )
    return md.getvalue(), csv_rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["A", "B", "C", "D"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.seed)))
        return
    rows: dict[str, list[dict]] = {s: [] for s in args.scenarios}
    for rep in range(args.repeats):  # interleaved: repeat r of every scenario before repeat r + 1
        for s in args.scenarios:
            rows[s].append(run_cold(s, args.seed))
            print(f"[{rep + 1}/{args.repeats}] {s}: horizon {rows[s][-1]['horizon_wall_s']:.2f} s", file=sys.stderr)
    table, csv_rows = tables(rows, args.seed, args.repeats)
    RESULTS.mkdir(parents=True, exist_ok=True)
    head = (
        "# horizon vs qp, scenarios A–D\n\n`python benchmarks/horizon.py` — the whole-horizon NLP "
        "([formulations/horizon.md](../../formulations/horizon.md)) against the per-step lexicographic QP "
        "([formulations/qp.md](../../formulations/qp.md)), both with the default parameters.\n\n"
    )
    (RESULTS / "horizon.md").write_text(head + table)
    with open(RESULTS / "horizon.csv", "w", newline="") as fh:
        csv.writer(fh).writerows(csv_rows)
    print(table)


if __name__ == "__main__":
    main()
