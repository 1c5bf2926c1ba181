"""Whole-horizon NLP (``horizon``) vs the per-step lexicographic QP (``qp``) on scenarios A–D, with cold wall times;
and at scale, on generated rooms and robot counts.

    python benchmarks/horizon.py [--scenarios A B C D] [--repeats 3] [--seed 0]
    python benchmarks/horizon.py --rooms 16 [--robots 2,3,5,8,auto] [--time-limit 60] [--jobs 2] [--scenario-e 6]
                                 [--seed 0] [--name horizon_rooms]
    python benchmarks/horizon.py --drones F G H [--repeats 3] [--time-limit 60]
    python benchmarks/horizon.py --drone-worlds 12 [--seed 0] [--jobs 2] [--time-limit 60]
    python benchmarks/horizon.py --misses horizon_rooms_216 [--calibrate 10] [--jobs 2] [--name NAME]

``--rooms K``: the first K rooms of :func:`tmr.sweep.rooms.room_set` (every density and goal class), each with every
robot count of ``--robots``, and scenario E with ``--scenario-e`` robots: the whole command line ``python -m tmr.plan
... --method horizon --no-plots`` in its own process (:func:`tmr.sweep.room_runs.run_room`). The horizon NLP starts
from the very plan ``--method qp`` returns, and ``metrics.json`` records that plan's f1–f4 beside the horizon's, so
no second run is needed. Per room class and N: optimal / best feasible iterate / warm start, whole-process time,
f1–f4 against ``qp``, knots; a scaling plot of the whole-process time against knots × N with the exponent fitted on
the optimal runs (target ≤ 1.3). Writes ``benchmarks/results/horizon_rooms.md``, ``.csv`` and ``.png``
(``--name``: another stem, e.g. ``--seed 1 --name horizon_rooms_seed1`` for a second sample of rooms).

``--drones F G H``: the drone chain's ``horizon`` against its ``qp`` plan, each the whole command line in its own
process, one at a time (:func:`drones_main`): exit, result, f1–f4 of the checker and their ratios to ``qp``, times.
Writes ``benchmarks/results/horizon_drones.md`` and ``.csv``.

``--drone-worlds N``: the drone ``horizon`` with ``--robots auto`` on the generated worlds
``tmr.sweep.rooms3d.drone_worlds(N, seed)``, ``--jobs`` processes at a time (:func:`drone_worlds_main`): result,
rounds, iterations, time, f1–f4 against the qp plan. Writes ``benchmarks/results/horizon_drone_worlds.md``, ``.csv``.

``--misses STEM``: the runs of a committed rooms table (``benchmarks/results/STEM.csv``) whose plan was not optimal
(or the coarse optimum) within 10 s, run again with the code checked out, with the table's own ``--time-limit``
(:func:`misses_main`); beside them ``--calibrate`` of the table's optimal runs with 8 robots in a sparse room (the
first by name), whose median time now / then, over those that took the same IPOPT iterations, says how fast this
machine is against the table's. Per run: the result and time then and now, the iterations. Writes
``benchmarks/results/STEM_misses.md`` and ``.csv`` (``--name``: another stem). So the progress on the misses is
measured without the hour of the whole table, and apart from the machine's speed.

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
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
#: The rooms mode's default file stem (``--name``): ``benchmarks/results/horizon_rooms.md``, ``.csv``, ``.png``.
ROOMS_NAME = "horizon_rooms"
#: The horizon results that count as optimal: a KKT point of the whole NLP, or the accepted coarse optimum.
OPTIMAL = ("optimal", "coarse_optimal")

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


ROOM_KEYS = (
    "room", "density", "goal_class", "robots", "n_robots", "exit_code", "horizon_result", "horizon_stop",
    "horizon_iterations", "horizon_coarse", "wall_time", "nlp_time", "qp_time", "knots", "route_length_cli",
    "independent_ok",
    "horizon_f1", "qp_f1", "horizon_f2", "qp_f2", "horizon_f3", "qp_f3", "horizon_f4", "qp_f4", "stderr_last",
)  # fmt: skip


def _scenario_e(robots: int, time_limit: float) -> dict:
    """Scenario E with ``robots`` robots, ``--method horizon``, the whole command line in its own process."""
    import tempfile

    from tmr.sweep.room_runs import trajectory_positions

    with tempfile.TemporaryDirectory(prefix="tmr-horizon-E-") as tmp:
        cmd = [sys.executable, "-m", "tmr.plan", "--scenario", "E", "--robots", str(robots), "--method", "horizon",
               "--no-plots", "--time-limit", str(time_limit), "--out", str(Path(tmp) / "out")]  # fmt: skip
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        out: dict = {"room": "scenario E", "density": "E", "goal_class": "-", "robots": str(robots)}
        out["wall_time"] = time.perf_counter() - t0
        out["exit_code"] = proc.returncode
        metrics_path, timings_path = Path(tmp) / "out" / "metrics.json", Path(tmp) / "out" / "timings.json"
        m = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
        t = json.loads(timings_path.read_text()) if timings_path.is_file() else {}
        hz = m.get("horizon", {})
        out.update(n_robots=m.get("n_robots"), route_length_cli=m.get("route_length"), independent_ok=None)
        out.update(horizon_result=hz.get("result"), horizon_stop=hz.get("stop"))
        out["horizon_iterations"] = hz.get("iterations")
        out["horizon_coarse"] = (hz.get("coarse") or {}).get("result")
        out.update(nlp_time=t.get("nlp_time"), qp_time=t.get("qp_time"))
        traj = Path(tmp) / "out" / "trajectories.json"
        out["knots"] = trajectory_positions(json.loads(traj.read_text())).shape[0] if traj.is_file() else None
        for k in ("f1", "f2", "f3", "f4"):
            out[f"horizon_{k}"] = hz.get("terms", {}).get(k)
            out[f"qp_{k}"] = hz.get("warm_start_terms", {}).get(k)
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        out["stderr_last"] = lines[-1].strip() if lines else ""
        return out


def _drone_run(scenario: str, method: str, time_limit: float, extra: tuple[str, ...] = ()) -> dict:
    """``python -m tmr.plan --scenario S --method M --no-plots`` of a drone scenario in its own process: exit code,
    whole-process time [s], the checker's f1–f4 and, for ``horizon``, its summary (``metrics.json``: the qp plan's
    terms too) and NLP time."""
    import tempfile

    name = Path(scenario).stem
    with tempfile.TemporaryDirectory(prefix=f"tmr-horizon-{name}-") as tmp:
        cmd = [sys.executable, "-m", "tmr.plan", "--scenario", scenario, "--method", method, "--no-plots",
               "--time-limit", str(time_limit), "--out", str(Path(tmp) / "out"), *extra]  # fmt: skip
        if method != "horizon":
            cmd = cmd[: cmd.index("--time-limit")] + cmd[cmd.index("--time-limit") + 2 :]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        out: dict = {"scenario": name, "method": method, "exit_code": proc.returncode}
        out["process_s"] = time.perf_counter() - t0
        metrics_path, timings_path = Path(tmp) / "out" / "metrics.json", Path(tmp) / "out" / "timings.json"
        m = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
        t = json.loads(timings_path.read_text()) if timings_path.is_file() else {}
        out["n_robots"] = m.get("n_robots")
        out.update({k: m.get(k) for k in ("f1", "f2", "f3", "f4")})
        hz = m.get("horizon", {})
        out.update(result=hz.get("result", ""), stop=hz.get("stop", ""), iterations=hz.get("iterations"))
        out.update({f"qp_{k}": v for k, v in (hz.get("warm_start_terms") or {}).items()})
        out["rounds"] = hz.get("rounds")
        out.update(nlp_s=t.get("nlp_time"), qp_s=t.get("qp_time"))
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        out["stderr_last"] = lines[-1].strip() if lines else ""
        return out


def drones_main(args: argparse.Namespace) -> None:
    """``--drones F G H``: the drone chain's ``horizon`` (``formulations/horizon3d.md``) against its ``qp`` plan,
    whole processes run one at a time, ``--repeats`` each (times: median; metrics from the first run, both planners
    being deterministic). Writes ``benchmarks/results/horizon_drones.md`` and ``.csv``."""
    rows: list[dict] = []
    for s in args.drones:
        for method in ("qp", "horizon"):
            runs = [_drone_run(s, method, args.time_limit) for _ in range(args.repeats)]
            row = dict(runs[0])
            row["process_s"] = statistics.median(r["process_s"] for r in runs)
            row["process_runs"] = " ".join(f"{r['process_s']:.1f}" for r in runs)
            rows.append(row)
            print(f"{s} {method}: exit {row['exit_code']}, {row['process_s']:.1f} s {row['result']}", file=sys.stderr)
    keys = ["scenario", "method", "exit_code", "n_robots", "result", "stop", "iterations", "f1", "f2", "f3", "f4",
            "process_s", "process_runs", "qp_s", "nlp_s", "stderr_last"]  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(RESULTS / "horizon_drones.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    lines = [
        "# horizon vs qp, drone chains F, G, H",
        "",
        f"`python benchmarks/horizon.py --drones {' '.join(args.drones)} --repeats {args.repeats} --time-limit "
        f"{args.time_limit:g}` — {datetime_now()}, {platform.machine()}, {os.cpu_count()} cores, one run at a time. "
        "Every run is the whole command line `python -m tmr.plan --scenario S --method M --no-plots` in its own "
        "process (*process*: start to exit, median of the repeats); f1–f4 are the independent checker's "
        "(`tmr.checks.drones.check_drone_plan`, Caruso 2021 eq. 24–27 in robot coordinates) of the plan written; "
        "exit 0: the plan passed every check. The formulation: "
        "[formulations/horizon3d.md](../../formulations/horizon3d.md).",
        "",
        "| scenario | method | exit | N | result | IPOPT iter. | f1 | f2 | f3 | f4 | f1/qp | f2/qp | f4/qp "
        "| process [s] | runs [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    qp = {r["scenario"]: r for r in rows if r["method"] == "qp"}
    worse = 0
    for r in rows:
        base = qp[r["scenario"]]

        def ratio(k: str, r: dict = r, base: dict = base) -> str:
            a, b = r.get(k), base.get(k)
            return f"{a / b:.3f}" if a is not None and b else "-"

        if r["method"] == "horizon" and any(
            r.get(k) is not None and base.get(k) is not None and r[k] > base[k] for k in ("f1", "f2", "f3", "f4")
        ):
            worse += 1
        terms = " | ".join(fmt(r.get(k), ".4g") if r.get(k) is not None else "-" for k in ("f1", "f2", "f3", "f4"))
        lines.append(
            f"| {r['scenario']} | {r['method']} | {r['exit_code']} | {r['n_robots']} | {r['result'] or '-'} | "
            f"{r['iterations'] if r['iterations'] is not None else '-'} | {terms} | {ratio('f1')} | {ratio('f2')} | "
            f"{ratio('f4')} | {r['process_s']:.1f} | {r['process_runs']} |"
        )
    n_h = sum(r["method"] == "horizon" for r in rows)
    lines += ["", f"Never worse than `qp`: {n_h - worse}/{n_h} horizon plans have every one of f1–f4 ≤ the qp plan's."]
    (RESULTS / "horizon_drones.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def drone_worlds_main(args: argparse.Namespace) -> None:
    """``--drone-worlds N``: ``horizon`` on the generated drone worlds ``drone_worlds(N, seed)`` with ``--robots
    auto``, each the whole command line in its own process, ``--jobs`` at a time: result (optimal / best feasible
    iterate / the qp plan), rounds, iterations, time, f1–f4 against the qp plan (``metrics.json``). Writes
    ``benchmarks/results/horizon_drone_worlds.md`` and ``.csv``."""
    import tempfile
    from concurrent.futures import ThreadPoolExecutor

    from tmr.sweep.rooms3d import drone_worlds

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tmr-drone-worlds-") as tmp:
        paths = [str(w.write(tmp)) for w in drone_worlds(args.drone_worlds, args.seed)]
        extra = ("--robots", "auto")
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            rows = list(pool.map(lambda p: _drone_run(p, "horizon", args.time_limit, extra), paths))
    total = time.perf_counter() - t0
    keys = ["scenario", "exit_code", "n_robots", "result", "stop", "rounds", "iterations", "f1", "f2", "f3", "f4",
            "qp_f1", "qp_f2", "qp_f3", "qp_f4", "process_s", "qp_s", "nlp_s", "stderr_last"]  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(RESULTS / "horizon_drone_worlds.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    planned = [r for r in rows if r["exit_code"] == 0 and r["result"]]
    count = {k: sum(r["result"] == k for r in planned) for k in ("optimal", "best_feasible_iterate", "warm_start")}
    worse = [r["scenario"] for r in planned
             if any(r.get(k) is not None and r.get(f"qp_{k}") is not None and r[k] > r[f"qp_{k}"] * (1 + 1e-9)
                    for k in ("f1", "f2", "f3", "f4"))]  # fmt: skip
    times = [r["process_s"] for r in planned if r["result"] == "optimal"]
    lines = [
        "# horizon on generated drone worlds",
        "",
        f"`python benchmarks/horizon.py --drone-worlds {args.drone_worlds} --seed {args.seed} --jobs {args.jobs} "
        f"--time-limit {args.time_limit:g}` — {datetime_now()}, {platform.machine()}, {os.cpu_count()} cores, "
        f"{args.jobs} runs at a time; total {total:.0f} s. The worlds of `tmr.sweep.rooms3d.drone_worlds"
        f"({args.drone_worlds}, {args.seed})`; every run is the whole command line `python -m tmr.plan --scenario "
        "WORLD.toml --robots auto --method horizon --no-plots` in its own process (*process*: start to exit); f1–f4 "
        "are the independent checker's of the plan written, *qp* the plan `--method qp` returns (the NLP's warm "
        "start, recorded in `metrics.json`). The formulation: [formulations/horizon3d.md]"
        "(../../formulations/horizon3d.md).",
        "",
        f"**{len(planned)} plans**: {count['optimal']} optimal, {count['best_feasible_iterate']} best feasible "
        f"iterate, {count['warm_start']} the qp plan itself; {len(rows) - len(planned)} runs without a horizon plan "
        f"(no qp plan, or the goal refused). Never worse than `qp`: {len(planned) - len(worse)}/{len(planned)}. "
        + (
            f"Optimal runs: median {statistics.median(times):.1f} s, max {max(times):.1f} s (process)." if times else ""
        ),
        "",
        "| world | exit | N | result | rounds | IPOPT iter. | f1 / qp | f2 / qp | f4 / qp | process [s] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]

    def ratio(r: dict, k: str) -> str:
        a, b = r.get(k), r.get(f"qp_{k}")
        return f"{a / b:.3f}" if a is not None and b else "-"

    for r in rows:
        lines.append(
            f"| {r['scenario']} | {r['exit_code']} | {r['n_robots']} | {r['result'] or '-'} | {r.get('rounds') or '-'} "
            f"| {r['iterations'] if r['iterations'] is not None else '-'} | {ratio(r, 'f1')} | {ratio(r, 'f2')} | "
            f"{ratio(r, 'f4')} | {r['process_s']:.1f} |"
        )
    (RESULTS / "horizon_drone_worlds.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def rooms_main(args: argparse.Namespace) -> None:
    """The ``--rooms`` mode (module docstring)."""
    import numpy as np
    from provenance import source_version  # benchmarks/ is the script's directory: on sys.path

    from tmr.sweep.executor import make_executor
    from tmr.sweep.room_runs import RoomRun, run_room
    from tmr.sweep.rooms import room_from_spec, room_set

    t_start = time.perf_counter()
    measured = source_version()  # the commit and any uncommitted changes in src/, as the runs start
    robots = [r.strip() for r in args.robots.split(",") if r.strip()]
    extra = ("--time-limit", str(args.time_limit))
    executor = make_executor(args.jobs, None, progress=True)
    try:
        made = executor.map(room_from_spec, room_set(args.rooms, args.seed), desc="rooms")
        rooms = [r for r in made if not isinstance(r, str)]
        tasks = [RoomRun(room, "horizon", n, args.seed, args.timeout, None, extra) for room in rooms for n in robots]
        rows = executor.map(run_room, tasks, desc="horizon runs")
    finally:
        executor.close()
    RESULTS.mkdir(parents=True, exist_ok=True)

    def write_csv() -> None:  # after the rooms already: a failure of the E run loses nothing
        with open(RESULTS / f"{args.name}.csv", "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(ROOM_KEYS)
            for r in rows:
                wr.writerow([r.get(k) for k in ROOM_KEYS])

    write_csv()
    if args.scenario_e:
        rows.append(_scenario_e(args.scenario_e, args.time_limit))
        write_csv()

    planned = [r for r in rows if r.get("horizon_result")]
    md = io.StringIO()
    w = md.write
    w("# horizon at scale: generated rooms and robot counts\n\n")
    named = (f" --seed {args.seed}" if args.seed else "") + (f" --name {args.name}" if args.name != ROOMS_NAME else "")
    w(f"`python benchmarks/horizon.py --rooms {args.rooms} --robots {args.robots} --time-limit {args.time_limit:g} "
      f"--jobs {args.jobs} --scenario-e {args.scenario_e}{named}` — {datetime_now()}, {measured}, "
      f"{platform.machine()}, {os.cpu_count()} cores, {args.jobs} runs at a time; "
      f"total {time.perf_counter() - t_start:.0f} s. "
      "Every run is the whole command line `python -m tmr.plan --map ROOM --base --goal --robots N --method horizon "
      "--no-plots` (or `--scenario E`) in its own process; *time* is that process, interpreter start to exit. The "
      "`qp` columns are the plan `--method qp` returns for the same inputs (the horizon's warm start, recorded in "
      "`metrics.json`).\n\n")  # fmt: skip
    counts = Counter(r["horizon_result"] for r in planned)
    refused = [r for r in rows if not r.get("horizon_result")]
    polished = sum(1 for r in planned if r["horizon_result"] == "optimal" and r.get("horizon_coarse") == "accepted")
    w(f"**{len(planned)} plans**: {counts['optimal']} optimal ({polished} of them polished from the coarse optimum), "
      f"{counts['coarse_optimal']} the coarse optimum itself (the NLP on every M-th knot, interpolated, every row "
      f"holding: `formulations/horizon.md`, \"Coarse knots\"), {counts['best_feasible_iterate']} best feasible "
      f"iterate, {counts['warm_start']} the qp plan itself; {len(refused)} runs without a horizon plan (exit 2: N "
      "below the route's proven count or no route; exit 1: no qp plan to start from).\n\n")  # fmt: skip
    terms = ("f1", "f2", "f3", "f4")
    worse = [r for r in planned if any((r[f"horizon_{k}"] or 0) > (r[f"qp_{k}"] or 0) for k in terms)]
    w(f"Never worse than `qp`: {len(planned) - len(worse)}/{len(planned)} plans have every one of f1–f4 ≤ the qp "
      "plan's.\n\n")  # fmt: skip
    w("| class | N | runs | optimal | coarse optimal | best iterate | qp plan | time median [s] | max [s] | "
      "knots median | f1 / qp | f2 / qp | f4 / qp |\n|" + "---|" * 13 + "\n")  # fmt: skip
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in planned:
        groups.setdefault((str(r["density"]), str(r["robots"])), []).append(r)

    def ratio(rs: list[dict], k: str) -> str:
        vals = [r[f"horizon_{k}"] / r[f"qp_{k}"] for r in rs if r[f"qp_{k}"]]
        return f"{statistics.median(vals):.3f}" if vals else "–"

    for (cls, n), rs in sorted(groups.items()):
        times = [r["wall_time"] for r in rs]
        c = Counter(r["horizon_result"] for r in rs)
        w(f"| {cls} | {n} | {len(rs)} | {c['optimal']} | {c['coarse_optimal']} | {c['best_feasible_iterate']} | "
          f"{c['warm_start']} | "
          f"{statistics.median(times):.1f} | {max(times):.1f} | {statistics.median(r['knots'] for r in rs):.0f} | "
          f"{ratio(rs, 'f1')} | {ratio(rs, 'f2')} | {ratio(rs, 'f4')} |\n")  # fmt: skip
    ok = [r for r in planned if r["horizon_result"] in OPTIMAL and r.get("knots")
          and r.get("n_robots")]  # fmt: skip
    slope = math.nan
    if len(ok) >= 3:
        x = np.log([r["knots"] * r["n_robots"] for r in ok])
        y = np.log([r["wall_time"] for r in ok])
        slope = float(np.polyfit(x, y, 1)[0])
    within = sum(1 for r in planned if r["wall_time"] < 10)
    w(f"\nWhole process < 10 s: {within}/{len(planned)}. Fitted exponent of time ∝ (knots × N)^a over the "
      f"{len(ok)} optimal and coarse-optimal runs: **a = {slope:.2f}** (target ≤ 1.3).\n\n"
      f"![scaling]({args.name}.png)\n")  # fmt: skip
    (RESULTS / f"{args.name}.md").write_text(md.getvalue())
    _rooms_plot(planned, slope, RESULTS / f"{args.name}.png")
    print(md.getvalue())


#: A run of a rooms table that issue 33 counts as met: an optimum (or the accepted coarse optimum) within 10 s.
MET_SECONDS = 10.0


def _met(r: dict) -> bool:
    """Whether a run (a row of a rooms table, or :func:`tmr.sweep.room_runs.run_room`'s dict) is optimal (or the
    accepted coarse optimum) within :data:`MET_SECONDS` of whole process."""
    return r.get("horizon_result") in OPTIMAL and float(r["wall_time"]) < MET_SECONDS


def select_misses(rows: list[dict], calibrate: int) -> tuple[list[dict], list[dict]]:
    """The misses of a rooms table's planned ``rows`` (not :func:`_met`), and its first ``calibrate`` optimal runs
    with 8 robots in sparse rooms by name (the speed reference of the ``--misses`` mode)."""
    misses = [r for r in rows if r["horizon_result"] and not _met(r)]
    reference = sorted(
        (r for r in rows if r["density"] == "sparse" and r["robots"] == "8" and r["horizon_result"] == "optimal"),
        key=lambda r: r["room"],
    )[:calibrate]
    return misses, reference


def misses_main(args: argparse.Namespace) -> None:
    """The ``--misses`` mode (module docstring): the misses of a committed rooms table again, and a speed reference.

    Writes ``benchmarks/results/STEM_misses.md`` and ``.csv`` (``--name``: another stem). The table's scenario-E row,
    if any, is left out (it is no room). Every run takes the table's ``--time-limit`` (from its Markdown header; the
    command line's if the header has none) and ``--seed 0``, the rooms mode's default (``tmr.plan --seed`` only
    matters with ``--route rrt``, which the rooms runs do not use)."""
    from provenance import source_version  # benchmarks/ is the script's directory: on sys.path

    from tmr.sweep.executor import make_executor
    from tmr.sweep.room_runs import RoomRun, run_room
    from tmr.sweep.rooms import room_from_spec, room_spec

    source = RESULTS / f"{args.misses}.csv"
    name = args.name if args.name != ROOMS_NAME else f"{args.misses}_misses"
    if not source.is_file():
        sys.exit(f"horizon.py: no table {source}")
    if args.calibrate < 0:
        sys.exit(f"horizon.py: --calibrate must be >= 0, got {args.calibrate}")
    if name == args.misses:
        sys.exit(f"horizon.py: --name {name} would overwrite the table it reads")
    with open(source, newline="") as fh:
        table = list(csv.DictReader(fh))
    if table and not {"density", "horizon_result", "wall_time", "horizon_iterations"} <= set(table[0]):
        sys.exit(f"horizon.py: {source} is not a rooms table of `--rooms`")
    then = [r for r in table if r["density"] != "E" and r["horizon_result"]]
    head = (RESULTS / f"{args.misses}.md").read_text() if (RESULTS / f"{args.misses}.md").is_file() else ""
    given = re.search(r"--time-limit ([\d.]+)", head)
    limit, whose = (float(given.group(1)), "the table's") if given else (args.time_limit, "not in the table's header")
    misses, reference = select_misses(then, args.calibrate)
    if not misses:
        sys.exit(f"horizon.py: {source} has no misses: every run is optimal within {MET_SECONDS:g} s")
    chosen = [("miss", r) for r in misses] + [("reference", r) for r in reference]
    measured = source_version()  # the commit and any uncommitted changes in src/
    t_start = time.perf_counter()
    extra = ("--time-limit", f"{limit:g}")
    executor = make_executor(args.jobs, None, progress=True)
    try:  # the rooms made by the executor's workers too, as in the rooms mode (one at a time, ~1 s each, before)
        made = executor.map(room_from_spec, [room_spec(r["room"]) for _, r in chosen], desc="rooms")
        failed = [m for m in made if isinstance(m, str)]
        if failed:
            sys.exit(f"horizon.py: a room of the table is not made again: {failed[0]}")
        tasks = [RoomRun(room, "horizon", r["robots"], 0, args.timeout, None, extra)
                 for room, (_, r) in zip(made, chosen, strict=True)]  # fmt: skip
        now = executor.map(run_room, tasks, desc="runs")
    finally:
        executor.close()
    rows = []
    for (kind, a), b in zip(chosen, now, strict=True):
        rows.append({
            "kind": kind, "room": a["room"], "robots": a["robots"], "n_robots": b.get("n_robots"),
            "result_then": a["horizon_result"], "result_now": b.get("horizon_result"),
            "stop_now": b.get("horizon_stop"), "coarse_now": b.get("horizon_coarse"),
            "iterations_then": int(a["horizon_iterations"]) if a["horizon_iterations"] else None,
            "iterations_now": b.get("horizon_iterations"),
            "time_then": float(a["wall_time"]), "time_now": b["wall_time"], "nlp_now": b.get("nlp_time"),
            "exit_now": b.get("exit_code"), "met_then": _met(a), "met_now": _met(b),
        })  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(RESULTS / f"{name}.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    ref = [r for r in rows if r["kind"] == "reference"]
    same = [
        r["time_now"] / r["time_then"]
        for r in ref
        if r["iterations_now"] is not None and r["iterations_now"] == r["iterations_then"]
    ]
    factor = statistics.median(same) if same else None  # None: no speed reference
    miss = [r for r in rows if r["kind"] == "miss"]
    counts = Counter(str(r["result_now"]) for r in miss)
    met = [r for r in miss if r["met_now"]]
    optimal_now = [r for r in miss if r["result_now"] in OPTIMAL]
    scaled = [r for r in optimal_now if factor and r["time_now"] / factor < MET_SECONDS]
    md = io.StringIO()
    w = md.write
    named = f" --name {args.name}" if args.name != ROOMS_NAME else ""
    w(f"# The misses of `{args.misses}`, run again\n\n`python benchmarks/horizon.py --misses {args.misses} "
      f"--calibrate {args.calibrate} --jobs {args.jobs}{named}` — {datetime_now()}, {measured}, {platform.machine()}, "
      f"{os.cpu_count()} cores, {args.jobs} runs at a time, `--time-limit {limit:g}` ({whose}); total "
      f"{time.perf_counter() - t_start:.0f} s. Every run is the whole command line, as in the table "
      "(`tmr.sweep.room_runs.run_room`). A *miss* is a run of the table that was not optimal (or the accepted "
      f"coarse optimum) within {MET_SECONDS:g} s.\n\n")  # fmt: skip
    w(
        f"**This machine against the table's:** the {len(ref)} reference runs (the table's first optimal runs with 8 "
        f"robots in sparse rooms) took the same IPOPT iterations in {len(same)}; "
        + (f"their median time now / then is **{factor:.2f}**.\n\n" if factor else "so no speed reference.\n\n")
    )
    w(f"**The {len(miss)} misses now:** {', '.join(f'{v} {k}' for k, v in sorted(counts.items()))}; **{len(met)} "
      f"optimal within {MET_SECONDS:g} s** on this machine"
      + (f", {len(scaled)} with their times divided by {factor:.2f} (the table's machine).\n\n" if factor else
         ".\n\n"))  # fmt: skip
    w("| run | N | then: result, time [s], iterations | now: result, time [s], iterations | stop now |\n"
      "|---|---|---|---|---|\n")  # fmt: skip
    for r in sorted(rows, key=lambda r: (r["kind"] != "miss", r["room"], r["robots"])):
        mark = "**" if r["met_now"] and not r["met_then"] else ""
        w(f"| {r['room']}{' (reference)' if r['kind'] == 'reference' else ''} | {r['robots']} | "
          f"{r['result_then']}, {r['time_then']:.1f}, {r['iterations_then']} | {mark}{r['result_now']}, "
          f"{r['time_now']:.1f}, {r['iterations_now']}{mark} | {r['stop_now']} |\n")  # fmt: skip
    (RESULTS / f"{name}.md").write_text(md.getvalue())
    print(md.getvalue())


def datetime_now() -> str:
    import datetime

    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def _rooms_plot(rows: list[dict], slope: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=110)
    style = {
        "optimal": ("o", "tab:green"),
        "coarse_optimal": ("D", "tab:blue"),
        "best_feasible_iterate": ("s", "tab:orange"),
        "warm_start": ("x", "tab:red"),
    }
    for result, (marker, color) in style.items():
        rs = [r for r in rows if r["horizon_result"] == result and r.get("knots") and r.get("n_robots")]
        if rs:
            ax.scatter([r["knots"] * r["n_robots"] for r in rs], [r["wall_time"] for r in rs], marker=marker,
                       color=color, label=f"{result.replace('_', ' ')} ({len(rs)})")  # fmt: skip
    ax.axhline(10, color="grey", lw=0.8, ls="--", label="10 s target")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("knots × robots")
    ax.set_ylabel("whole process [s]")
    ax.set_title(f"horizon at scale: fitted exponent a = {slope:.2f} on the optimal runs")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["A", "B", "C", "D"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rooms", type=int, default=0, help="the rooms mode: this many generated rooms")
    ap.add_argument("--robots", default="2,3,5,8,auto", help="robot counts of the rooms mode")
    ap.add_argument("--time-limit", type=float, default=60.0, help="--time-limit of every run [s]")
    ap.add_argument("--timeout", type=float, default=300.0, help="a run taking longer is killed [s]")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scenario-e", type=int, default=6, help="also scenario E with this many robots (0: not)")
    ap.add_argument("--name", default=ROOMS_NAME, help=f"the rooms mode's file stem (default {ROOMS_NAME})")
    ap.add_argument("--drones", nargs="*", help="the drone mode: these drone scenarios (default F G H), qp vs horizon")
    ap.add_argument("--drone-worlds", type=int, default=0, help="the drone worlds mode: this many generated worlds")
    ap.add_argument("--misses", help="the misses mode: run again the misses of benchmarks/results/STEM.csv")
    ap.add_argument("--calibrate", type=int, default=10, help="reference runs of the misses mode (machine speed)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.misses:
        misses_main(args)
        return
    if args.child:
        print(json.dumps(child(args.child, args.seed)))
        return
    if args.rooms:
        rooms_main(args)
        return
    if args.drone_worlds:
        drone_worlds_main(args)
        return
    if args.drones is not None:  # --drones alone: F G H
        args.drones = args.drones or ["F", "G", "H"]
        drones_main(args)
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
