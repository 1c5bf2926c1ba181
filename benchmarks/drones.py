"""Tethered drone chains in 3-D on seeded worlds: does the planner plan, refuse and keep every hard limit? (issue 32)

    python benchmarks/drones.py [--seed 0] [--worlds 100] [--robots 2,3,5,8,auto] [--jobs 2]
                                [--whole-process all|sample|none] [--h-repeats 3] [--timeout 300] [--quick]

A benchmark, not a test. Worlds come from :mod:`tmr.sweep.rooms3d` (pillars of mixed heights, a wall with a window,
a low wall to pass over, a warehouse with shelves; rooms 10–30 m, 4–8 m high, tether length 6–14 m per world; every
5th window and low-wall world closed: its goal is unreachable). Each world is written as a ``kind = "drone"``
scenario TOML under ``--work`` and, in a worker process (``--jobs``, default 2), for each N of ``--robots``:

1. **in-process** (the figures of the tables but the whole-process time): the scenario is loaded with
   ``tmr.world.drones.load_drone_scenario``; the proven bound once per world with
   ``tmr.route.route3d.plan_route3d(world, base, goal, tether, grid=..., goal_tolerance=...)`` (``min_robots``,
   ``lower_bound_length``; NoRouteError: no route), timed; then ``tmr.planner3d.plan_drones(scenario, robots=N,
   method="qp")``, timed from the call to its return or its refusal (TooFewRobotsError /
   NoRouteError: the refusal time, target < 1 s). A returned plan carries the independent checker's verdict
   (``plan.success``; ``plan.failure`` with one reason per violated limit, joined by "; ") and the per-step QP times
   ``plan.diagnostics["step_time"]`` [s];
2. **whole process** (``--whole-process all``, the default: every case; ``sample``: the first world of each family
   and every N; ``none``): ``python -m tmr.plan --scenario FILE.toml --robots N --method qp --out DIR --no-plots``
   (the ``tmr plan`` command line) in a subprocess, timed from process start to exit (imports, loading, route,
   plan, check, writing; no figures), with its exit code, which must agree with the in-process verdict (0 plan
   passing every check, 1 a failed check, 2 a refusal).

Then the H arena (30 × 30 × 8 m, 9 pillars, corner to corner) with 5 drones, the setting of NEPTUNE (Cao et al.,
T-RO 2023): in-process once, whole process ``--h-repeats`` times (median), serially after the worlds so that no
other worker competes. BLAS runs on one thread per process unless OPENBLAS_NUM_THREADS/OMP_NUM_THREADS is set.

Writes ``benchmarks/results/drones.md`` and ``drones.csv`` (one row per world × N, plus the H rows). ``--quick``: the
first 8 worlds (two per family), whole process sampled, for smoke runs.

Needs the drone scenario loader (``tmr.world.drones``), the 3-D route (``tmr.route.route3d``) and the glue
(``tmr.planner3d.plan_drones``); without them it stops with one line naming what is missing.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import importlib
import io
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
if not any(v in os.environ for v in THREAD_VARS):
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = "1"

import numpy as np  # noqa: E402
from provenance import source_version, versions  # noqa: E402

from tmr.errors import TmrError  # noqa: E402
from tmr.model.params import DroneParams  # noqa: E402
from tmr.sweep.rooms3d import FAMILIES, DroneWorld, drone_worlds  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
PACKAGES = ("numpy", "scipy", "osqp", "coal", "shapely")
ROBOTS = ("2", "3", "5", "8", "auto")
DEFAULT_WORLDS = 100
QUICK_WORLDS = 8

#: Targets of issue 32 ("Must show").
TARGET_AUTO_SUCCESS = 0.95  # fraction of reachable goals planned (and passing the check) with auto
TARGET_REFUSE_S = 1.0  # s, every N below the proven bound refused within this
TARGET_MEDIAN_WHOLE_S = 3.0  # s, median whole-process time
TARGET_STEP_MS = 2.0  # ms, median per-step QP time for 8 drones
TARGET_H_S = 2.0  # s, H with 5 drones, whole process

#: NEPTUNE's published setting (Cao, Cheng, Sun, Zhang, Wang — "NEPTUNE: Nonentangling Trajectory Planning for
#: Multiple Tethered Unmanned Vehicles", IEEE T-RO 2023), as the issue quotes it.
NEPTUNE = {
    "drones": "5",
    "obstacles": "9 pillars",
    "arena": "30 m × 30 m",
    "tethers": "each drone to its own base (5 bases); tethers must not entangle",
    "planning": "receding-horizon replanning, 0.3–1.6 s per replan",
    "software": "C++, ROS, Gurobi (commercial MIQP solver)",
}


def _median_ms(seconds: Any) -> float | None:
    """Median [ms] of the finite entries of a per-step series [s] (None if there are none)."""
    x = np.asarray([] if seconds is None else seconds, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.median(x)) * 1e3 if x.size else None


def _why(message: str) -> str:
    """The kind of a planner's own failure, from its message."""
    if message.startswith(("the leader stopped", "the leader stalled")):
        return "the leader held back short of the goal (stalled)"
    if message.startswith("the chain did not come to rest"):
        return "the chain not at rest at the goal when the settling time ran out"
    if "no catenary" in message or "span" in message:
        return "a tether span no catenary holds"
    return "a step without a solution" if message else "(no message)"


# ----------------------------------------------------------------------------------------------------------------
# one world, every N (runs in a worker process)
# ----------------------------------------------------------------------------------------------------------------
def _missing() -> str | None:
    """The first module of the 3-D pipeline that cannot be imported (None: all there)."""
    for mod in ("tmr.world.drones", "tmr.route.route3d", "tmr.planner3d"):
        try:
            importlib.import_module(mod)
        except ImportError as exc:
            return f"{mod} ({exc})"
    return None


def _last_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1][:300] if lines else ""


#: What the checker reports that is not a broken hard limit: the planner's own failure (it stopped: an infeasible
#: step, a span no catenary holds, the leader held back) and the leader short of the goal (the task, not a limit).
NOT_LIMITS = ("planner", "goal")


def _violations(metrics: Any) -> list[str]:
    """The kinds of hard limit the independent checker found broken in a plan (``plan.failure`` has their first
    step's reasons); the planner's own failure and the goal are not limits (:data:`NOT_LIMITS`)."""
    return [k for k, step in metrics.first_violation.items() if step is not None and k not in NOT_LIMITS]


def _bound(scenario: Any) -> dict[str, Any]:
    params = DroneParams(**scenario.params)
    plan_route3d = importlib.import_module("tmr.route.route3d").plan_route3d
    t0 = time.perf_counter()
    try:
        route = plan_route3d(
            scenario.world, scenario.base, scenario.goal, scenario.tether, grid=params.grid,
            goal_tolerance=params.goal_tolerance,
        )  # fmt: skip
    except Exception as exc:  # NoRouteError (or whatever A raises for it): recorded, not fatal
        return {"bound": None, "route": type(exc).__name__, "route_s": time.perf_counter() - t0}
    return {
        "bound": int(route.min_robots),
        "route": "found",
        "route_s": time.perf_counter() - t0,
        "route_length": float(route.length),
        "lower_bound_length": float(route.lower_bound_length),
    }


def _in_process(scenario: Any, robots: str, plan_seed: int) -> dict[str, Any]:
    plan_drones = importlib.import_module("tmr.planner3d").plan_drones
    n: int | str = robots if robots == "auto" else int(robots)
    row: dict[str, Any] = {}
    t0 = time.perf_counter()
    try:
        plan, metrics = plan_drones(scenario, robots=n, method="qp")
    except TmrError as exc:
        row["call_s"] = time.perf_counter() - t0
        kind = type(exc).__name__
        row["outcome"] = {"TooFewRobotsError": "refused: too few", "NoRouteError": "refused: no route"}.get(
            kind, f"error: {kind}"
        )
        row["needed"] = getattr(exc, "needed", None)
        row["proven"] = getattr(exc, "proven", None)
        row["message"] = str(exc).splitlines()[0][:300] if str(exc) else kind
        return row
    except Exception as exc:  # a bug, not a verdict: recorded (and listed in the report) so the sweep goes on
        row["call_s"] = time.perf_counter() - t0
        row["outcome"] = f"crash: {type(exc).__name__}"
        row["message"] = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
        return row
    row["call_s"] = time.perf_counter() - t0
    violations = _violations(metrics)
    step = np.asarray(plan.diagnostics.get("step_time", []), dtype=float)
    step = step[np.isfinite(step)]
    row.update(
        outcome="planned" if plan.success else "failed check" if violations else "no plan",
        n_used=plan.n_robots,
        steps=int(plan.t.size - 1),
        plan_duration=float(plan.t[-1]) if plan.t.size else 0.0,
        violations=len(violations),
        message=(plan.failure or "")[:300],
        step_ms_median=float(np.median(step)) * 1e3 if step.size else None,
        step_ms_p90=float(np.percentile(step, 90)) * 1e3 if step.size else None,
        step_ms_max=float(step.max()) * 1e3 if step.size else None,
        qp_ms_median=_median_ms(plan.diagnostics.get("qp_step_time")),
        leader_error=float(np.linalg.norm(plan.robots[-1, -1] - plan.goal)),
    )
    return row


def _whole_process(path: Path, robots: str, out: Path, plan_seed: int, timeout: float) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "tmr.plan", "--scenario", str(path), "--robots", robots, "--method", "qp"]
    cmd += ["--seed", str(plan_seed), "--out", str(out), "--no-plots"]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=os.environ.copy())
    except subprocess.TimeoutExpired:
        return {"exit_code": None, "whole_s": time.perf_counter() - t0, "stderr_last": "timeout"}
    return {"exit_code": proc.returncode, "whole_s": time.perf_counter() - t0, "stderr_last": _last_line(proc.stderr)}


def _expected_exit(row: dict[str, Any]) -> int | None:
    """The exit code ``tmr plan`` should give for the in-process verdict (a refusal that is not proven: 1)."""
    if row["outcome"].startswith("refused") and row.get("proven") is False:
        return 1
    return {"planned": 0, "failed check": 1, "no plan": 1, "refused: too few": 2, "refused: no route": 2}.get(
        row["outcome"]
    )


def run_world(task: dict[str, Any]) -> list[dict[str, Any]]:
    """Every N of one world: the bound, the in-process plan or refusal, the whole process (see the module doc)."""
    load_drone_scenario = importlib.import_module("tmr.world.drones").load_drone_scenario
    path = Path(task["path"])
    t0 = time.perf_counter()
    scenario = load_drone_scenario(path)
    load_s = time.perf_counter() - t0
    bound = _bound(scenario)
    rows = []
    for robots in task["robots"]:
        row: dict[str, Any] = {k: task[k] for k in ("world", "family", "reachable", "tether_length")}
        row.update(robots=robots, load_s=load_s, **bound)
        row.update(_in_process(scenario, robots, task["plan_seed"]))
        if task["whole_process"]:
            with tempfile.TemporaryDirectory(prefix="tmr-drones-") as tmp:
                row.update(_whole_process(path, robots, Path(tmp) / "run", task["plan_seed"], task["timeout"]))
            row["exit_agrees"] = row["exit_code"] == _expected_exit(row)
        rows.append(row)
    return rows


def run_h(robots: str, repeats: int, plan_seed: int, timeout: float) -> list[dict[str, Any]]:
    """The built-in H arena: in-process once (after one warm-up call), whole process ``repeats`` times."""
    load_drone_scenario = importlib.import_module("tmr.world.drones").load_drone_scenario
    scenario = load_drone_scenario("H")
    bound = _bound(scenario)
    _in_process(scenario, robots, plan_seed)  # warm-up (imports, caches)
    row: dict[str, Any] = {"world": "H", "family": "H (NEPTUNE's setting)", "reachable": True, "robots": robots}
    row.update(tether_length=scenario.tether.tether_length, **bound)
    row.update(_in_process(scenario, robots, plan_seed))
    times, codes = [], []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory(prefix="tmr-drones-H-") as tmp:
            r = _whole_process(Path("H"), robots, Path(tmp) / "run", plan_seed, timeout)
        times.append(r["whole_s"])
        codes.append(r["exit_code"])
        row["stderr_last"] = r["stderr_last"]
    row.update(whole_s=statistics.median(times), whole_s_min=min(times), whole_s_max=max(times))
    row["exit_code"] = codes[0] if len(set(codes)) == 1 else str(codes)
    row["exit_agrees"] = row["exit_code"] == _expected_exit(row)
    return [row]


# ----------------------------------------------------------------------------------------------------------------
# summary
# ----------------------------------------------------------------------------------------------------------------
def _vals(rows: list[dict[str, Any]], key: str) -> list[float]:
    return [float(r[key]) for r in rows if r.get(key) is not None and not math.isnan(float(r[key]))]


def _med(v: list[float]) -> float | None:
    return statistics.median(v) if v else None


def _fmt(v: Any, spec: str = ".2f") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "—"
    return format(v, spec)


def _frac(k: int, n: int) -> str:
    return f"{k}/{n} ({100.0 * k / n:.0f} %)" if n else "—"


def _ok(flag: bool) -> str:
    return "**yes**" if flag else "**NO**"


def _below_bound(row: dict[str, Any]) -> bool:
    return row["robots"] != "auto" and row.get("bound") is not None and int(row["robots"]) < int(row["bound"])


CSV_FIELDS = [
    "world", "family", "reachable", "tether_length", "robots", "route", "bound", "route_length",
    "lower_bound_length", "route_s", "load_s", "outcome", "needed", "proven", "call_s", "n_used", "steps",
    "plan_duration", "violations", "step_ms_median", "step_ms_p90", "step_ms_max", "qp_ms_median", "leader_error",
    "exit_code",
    "exit_agrees", "whole_s", "whole_s_min", "whole_s_max", "message", "stderr_last",
]  # fmt: skip


def write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


def report(rows: list[dict[str, Any]], h_rows: list[dict[str, Any]], worlds: list[DroneWorld], info: dict) -> str:
    buf = io.StringIO()
    w = buf.write
    w("# Tethered drone chains in 3-D: seeded worlds and the H arena (issue 32)\n\n")
    if info["quick"]:
        w(f"**Quick smoke run ({len(worlds)} worlds)**: not the full benchmark; run without `--quick` for it.\n\n")
    w(f"`python benchmarks/drones.py {info['cmd']}`".replace(" `", "`") + f" — {datetime.date.today().isoformat()}, ")
    w(f"`{platform.machine()}`, nproc {os.cpu_count()}, Python {platform.python_version()}; {versions(PACKAGES)}; ")
    threads = ", ".join(f"{v}={os.environ[v]}" for v in THREAD_VARS if v in os.environ)
    w(f"{threads}; {source_version()}.\n{info['jobs']} worker processes; total {info['total']:.0f} s. ")
    w("In-process figures come from `tmr.planner3d.plan_drones` in a warm worker; whole-process times from ")
    w("`python -m tmr.plan --scenario FILE.toml --robots N --method qp --out DIR --no-plots` in a subprocess ")
    w(f"({info['whole_process']}), while the other workers run (contention included).\n\n")

    # ---------------------------------------------------------------- targets
    reach = {wd.name for wd in worlds if wd.reachable}
    auto = [r for r in rows if r["robots"] == "auto"]
    auto_reach = [r for r in auto if r["world"] in reach]
    auto_ok = [r for r in auto_reach if r["outcome"] == "planned"]
    below = [r for r in rows if _below_bound(r)]
    below_refused = [r for r in below if r["outcome"] == "refused: too few"]
    refuse_t = _vals(below_refused, "call_s")
    no_route = [r for r in rows if r["world"] not in reach]
    # an unreachable goal is refused by the route's proof, or before it by the straight line (too few for any curve)
    no_route_ok = [r for r in no_route if r["outcome"] in ("refused: no route", "refused: too few")]
    no_route_t = _vals(no_route_ok, "call_s")
    plans = [r for r in rows if r["outcome"] in ("planned", "failed check", "no plan")]
    violations = sum(int(r.get("violations") or 0) for r in plans)
    whole = _vals(rows, "whole_s")
    step8 = _vals([r for r in plans if r.get("n_used") == 8], "step_ms_median")
    h5 = h_rows[0] if h_rows else None
    w("## Targets (issue 32, Must show)\n\n| target | measured | met |\n|---|---|---|\n")
    rate = len(auto_ok) / len(auto_reach) if auto_reach else 0.0
    w(f"| `auto` plans ≥ {TARGET_AUTO_SUCCESS:.0%} of the reachable goals (passing the check) | ")
    w(f"{_frac(len(auto_ok), len(auto_reach))} | {_ok(rate >= TARGET_AUTO_SUCCESS)} |\n")
    slow = max(refuse_t, default=0.0)
    w(f"| every N below the proven bound refused, in < {TARGET_REFUSE_S:g} s (in-process) | ")
    w(f"{_frac(len(below_refused), len(below))}; median {_fmt(_med(refuse_t), '.3f')} s, ")
    w(f"max {_fmt(max(refuse_t, default=None), '.3f')} s | ")
    w(f"{_ok(len(below_refused) == len(below) and slow < TARGET_REFUSE_S)} |\n")
    slow_nr = max(no_route_t, default=0.0)
    w(f"| unreachable goals refused (no route, or too few for the straight line), in < {TARGET_REFUSE_S:g} s ")
    w("(in-process) | ")
    w(f"{_frac(len(no_route_ok), len(no_route))}; median {_fmt(_med(no_route_t), '.3f')} s, max ")
    w(f"{_fmt(max(no_route_t, default=None), '.3f')} s; {sum(r.get('proven') is not False for r in no_route_ok)} ")
    w("proven (exit 2), the others exit 1 (a tether fits through the gap, a drone does not) | ")
    w(f"{_ok(len(no_route_ok) == len(no_route) and slow_nr < TARGET_REFUSE_S)} |\n")
    w(f"| 0 violations by the independent check (hard limits broken, in every plan computed) | {violations} in ")
    w(f"{len(plans)} plans | {_ok(violations == 0)} |\n")
    mw = _med(whole)
    w(f"| median whole-process time < {TARGET_MEDIAN_WHOLE_S:g} s | {_fmt(mw)} s over {len(whole)} runs | ")
    w(f"{_ok(mw is not None and mw < TARGET_MEDIAN_WHOLE_S)} |\n")
    m8 = _med(step8)
    q8 = _med(_vals([r for r in plans if r.get("n_used") == 8], "qp_ms_median"))
    w(f"| per-step QP time for 8 drones ≤ {TARGET_STEP_MS:g} ms median | {_fmt(m8, '.3f')} ms for the whole step ")
    w(f"(catenaries, world queries, rows, QP), of which the QP {_fmt(q8, '.3f')} ms (medians of the {len(step8)} ")
    w(f"plans' medians) | {_ok(m8 is not None and m8 <= TARGET_STEP_MS)} |\n")
    if h5:
        hw = h5.get("whole_s")
        w(f"| H arena, 5 drones, whole process < {TARGET_H_S:g} s | {_fmt(hw)} s (median of {info['h_repeats']}), ")
        w(f"{h5['outcome']} | {_ok(hw is not None and hw < TARGET_H_S and h5['outcome'] == 'planned')} |\n")
    agree = [r for r in rows if "exit_agrees" in r]
    w(f"| exit codes agree with the in-process verdict | {_frac(sum(r['exit_agrees'] for r in agree), len(agree))} ")
    w(f"| {_ok(all(r['exit_agrees'] for r in agree))} |\n\n")

    # ---------------------------------------------------------------- worlds
    w("## Worlds\n\n")
    w(f"{len(worlds)} worlds, `tmr.sweep.rooms3d.drone_worlds({len(worlds)}, seed={info['seed']})`; r = 0.3 m, ")
    w("base = the ground winch at z = 0.4 m, tether length 6–14 m per world (`[tether] tether_length`). *Route* is ")
    w("the verdict of `tmr.route.route3d.plan_route3d`; *reachable* is the generator's construction (checked by an ")
    w("independent voxel flood fill in tests/test_rooms3d.py).\n\n")
    w("| family | worlds | reachable | route found | bound median (max) | route length median [m] | ")
    w("`auto` planned | N used median |\n|---|---:|---:|---:|---:|---:|---:|---:|\n")
    for fam in FAMILIES:
        names = {wd.name for wd in worlds if wd.family == fam}
        fr = [r for r in auto if r["world"] in names]
        bounds = [int(r["bound"]) for r in fr if r.get("bound") is not None]
        ok = [r for r in fr if r["outcome"] == "planned"]
        w(f"| {fam} | {len(names)} | {len(names & reach)} | {sum(r['route'] == 'found' for r in fr)} | ")
        w(f"{_fmt(_med(bounds), '.0f')} ({max(bounds, default='—')}) | {_fmt(_med(_vals(fr, 'route_length')), '.1f')}")
        w(f" | {_frac(len(ok), len(names & reach))} | {_fmt(_med(_vals(ok, 'n_used')), '.0f')} |\n")
    mismatch = [r["world"] for r in auto if (r["route"] == "found") != (r["world"] in reach)]
    w(f"\nRoute verdict vs construction: {len(auto) - len(mismatch)}/{len(auto)} agree")
    w(f" (differ: {', '.join(mismatch)})" if mismatch else "")
    w(". Proven bound computed in median ")
    route_s = _vals(auto, "route_s")
    w(f"{_fmt(_med(route_s), '.3f')} s, max {_fmt(max(route_s, default=None), '.3f')} s.\n\n")

    # ---------------------------------------------------------------- per N
    w("## Per N\n\n*No plan*: the planner stopped and said why (the leader held back short of the goal by the hard ")
    w("limits, or a step where they have no common solution): exit 1, with no limit broken. *Failed check*: a plan ")
    w("in which the independent checker found a hard limit broken.\n\n")
    w("| N | runs | below bound | refused (too few) | refused (no route) | planned | no plan | failed check | ")
    w("other | refusal median / max [s] | violations | whole process median / max [s] | step median [ms] |\n")
    w("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n")
    for n in info["robots"]:
        rs = [r for r in rows if r["robots"] == n]
        c = Counter(r["outcome"] for r in rs)
        other = len(rs) - c["refused: too few"] - c["refused: no route"] - c["planned"] - c["failed check"]
        other -= c["no plan"]
        ref = _vals([r for r in rs if r["outcome"].startswith("refused")], "call_s")
        wt = _vals(rs, "whole_s")
        st = _vals([r for r in rs if r["outcome"] in ("planned", "failed check", "no plan")], "step_ms_median")
        w(f"| {n} | {len(rs)} | {sum(_below_bound(r) for r in rs)} | {c['refused: too few']} | ")
        w(f"{c['refused: no route']} | {c['planned']} | {c['no plan']} | {c['failed check']} | {other} | ")
        w(f"{_fmt(_med(ref), '.3f')} / {_fmt(max(ref, default=None), '.3f')} | ")
        w(f"{sum(int(r.get('violations') or 0) for r in rs)} | {_fmt(_med(wt))} / {_fmt(max(wt, default=None))} | ")
        w(f"{_fmt(_med(st), '.3f')} |\n")
    odd = [
        r
        for r in rows
        if r["outcome"].startswith(("error", "crash")) or (r["outcome"] == "planned" and _below_bound(r))
    ]
    if odd:
        w("\nUnexpected outcomes (an error or a crash, or a plan below the proven bound):\n\n")
        for r in odd[:30]:
            w(f"- {r['world']} N = {r['robots']}: {r['outcome']} — {r.get('message', '')}\n")
    stopped = Counter(_why(r.get("message", "")) for r in plans if r["outcome"] == "no plan")
    if stopped:
        w("\nWhy the planner stopped (*no plan*): ")
        w("; ".join(f"{why}: {c}" for why, c in stopped.most_common()) + ".\n")
    failed = [r for r in plans if r["outcome"] == "failed check"]
    if failed:
        w("\nPlans the independent check refused:\n\n")
        for r in failed[:30]:
            w(f"- {r['world']} N = {r['robots']}: {r.get('message', '')}\n")

    # ---------------------------------------------------------------- NEPTUNE
    w("\n## The H arena beside NEPTUNE's published setting\n\n")
    w("Not a like-for-like comparison: NEPTUNE plans drones each tethered to its own base and replans in a receding ")
    w("horizon; tmr plans one chain of drones tethered to each other from one ground winch, whole motion at once. ")
    w("NEPTUNE's figures are the paper's (Cao et al., T-RO 2023, as quoted in issue 32), not measured here.\n\n")
    w("| | NEPTUNE (Cao et al., T-RO 2023) | tmr, built-in H |\n|---|---|---|\n")
    if h5:
        w(f"| drones | {NEPTUNE['drones']} | {h5.get('n_used', h5['robots'])} |\n")
        w(f"| obstacles | {NEPTUNE['obstacles']} | 9 pillars |\n")
        w(f"| arena | {NEPTUNE['arena']} | 30 m × 30 m × 8 m, corner to corner |\n")
        w(f"| tethers | {NEPTUNE['tethers']} | a chain: winch → drone 1 → … → ")
        w(f"drone {h5.get('n_used', h5['robots'])}, catenaries ")
        w(f"(L_max {_fmt(h5.get('tether_length'), '.1f')} m each) |\n")
        w(f"| planning time | {NEPTUNE['planning']} | whole plan in {_fmt(h5.get('call_s'))} s in-process; whole ")
        w(f"process {_fmt(h5.get('whole_s'))} s (median of {info['h_repeats']}, min {_fmt(h5.get('whole_s_min'))}, ")
        w(f"max {_fmt(h5.get('whole_s_max'))}) |\n")
        w(f"| per-step QP | — | {_fmt(h5.get('step_ms_median'), '.3f')} ms median, ")
        w(f"{_fmt(h5.get('step_ms_p90'), '.3f')} ms p90 over {h5.get('steps', '—')} steps |\n")
        w(f"| outcome | — | {h5['outcome']}, {h5.get('violations', '—')} violations by the independent check, ")
        w(f"exit {h5.get('exit_code')} |\n")
        w(f"| software | {NEPTUNE['software']} | Python, `pip install` (numpy, scipy, OSQP, coal) |\n")
    else:
        w("(H not run.)\n")
    w("\nOne row per world × N in `drones.csv` (outcome, bound, refusal and call times, violations, step times, ")
    w("exit code, whole-process time).\n")
    return buf.getvalue()


# ----------------------------------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="seed of the worlds (default 0)")
    ap.add_argument("--worlds", type=int, default=DEFAULT_WORLDS, help=f"number of worlds (default {DEFAULT_WORLDS})")
    ap.add_argument("--robots", default=",".join(ROBOTS), help="comma-separated N values (default 2,3,5,8,auto)")
    ap.add_argument("--plan-seed", type=int, default=0, help="seed passed to plan_drones / tmr plan (default 0)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2; 1 = serial)")
    ap.add_argument(
        "--whole-process",
        choices=("all", "sample", "none"),
        help="subprocess runs: every case, the first world of each family, or none (default all; --quick: sample)",
    )
    ap.add_argument("--h-repeats", type=int, default=3, help="whole-process runs of H with 5 drones (default 3)")
    ap.add_argument("--no-h", action="store_true", help="skip the H arena")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per subprocess before it is killed")
    ap.add_argument("--quick", action="store_true", help=f"smoke run: the first {QUICK_WORLDS} worlds")
    ap.add_argument("--work", help="folder for the world TOML files (default: a temporary folder, removed)")
    ap.add_argument("--out", default=str(RESULTS), help="output directory (default benchmarks/results)")
    ap.add_argument("--name", default="drones", help="output file stem (default drones)")
    args = ap.parse_args(argv)
    missing = _missing()
    if missing:
        print(f"benchmarks/drones.py: the 3-D pipeline is not there yet: cannot import {missing}", file=sys.stderr)
        return 2
    robots = [n.strip() for n in args.robots.split(",") if n.strip()]
    n_worlds = QUICK_WORLDS if args.quick else args.worlds
    whole = args.whole_process or ("sample" if args.quick else "all")
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="tmr-drone-worlds-"))
    work.mkdir(parents=True, exist_ok=True)

    t_start = time.perf_counter()
    worlds = drone_worlds(n_worlds, args.seed)
    first_of_family = {
        next(wd.name for wd in worlds if wd.family == f) for f in FAMILIES if any(wd.family == f for wd in worlds)
    }
    tasks = [
        {
            "path": str(wd.write(work)),
            "world": wd.name,
            "family": wd.family,
            "reachable": wd.reachable,
            "tether_length": wd.tether_length,
            "robots": robots,
            "plan_seed": args.plan_seed,
            "timeout": args.timeout,
            "whole_process": whole == "all" or (whole == "sample" and wd.name in first_of_family),
        }
        for wd in worlds
    ]
    rows: list[dict[str, Any]] = []
    try:
        if args.jobs <= 1:
            for k, task in enumerate(tasks):
                rows += run_world(task)
                print(f"[{k + 1}/{len(tasks)}] {task['world']}", file=sys.stderr)
        else:
            with ProcessPoolExecutor(max_workers=args.jobs) as pool:
                for k, result in enumerate(pool.map(run_world, tasks)):
                    rows += result
                    print(f"[{k + 1}/{len(tasks)}] {tasks[k]['world']}", file=sys.stderr)
        h_rows = [] if args.no_h else run_h("5", args.h_repeats, args.plan_seed, args.timeout)
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)
    total = time.perf_counter() - t_start

    stem = out_dir / args.name
    write_csv(rows + h_rows, stem.with_suffix(".csv"))
    cmd = " ".join(argv if argv is not None else sys.argv[1:])
    info = {
        "cmd": cmd,
        "quick": args.quick,
        "jobs": args.jobs,
        "total": total,
        "seed": args.seed,
        "robots": robots,
        "h_repeats": args.h_repeats,
        "whole_process": {
            "all": "every case",
            "sample": "the first world of each family, every N",
            "none": "not run",
        }[whole],
    }
    text = report(rows, h_rows, worlds, info)
    stem.with_suffix(".md").write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
