"""Whole pipeline on seeded random rooms: does `python -m tmr.plan` plan, refuse and keep every hard limit?

    python benchmarks/random_rooms.py [--rooms 216] [--seed 0] [--methods qp[,pinv,horizon]] [--subset K]
                                      [--robots 2,3,5,8,auto] [--jobs N | --scheduler tcp://host:port]
                                      [--timeout 600] [--keep-failures DIR] [--quick]
                                      [--drive diff [--robot-model NAME|FILE.toml] [--repeat R]]

A benchmark, not a test. Rooms come from the project's own generator (:mod:`tmr.sweep.rooms`): 20 m × 20 m,
densities sparse / medium / dense / walls / narrow / long_walls × goal classes near / mid / corner / far, evenly
(``room_set``), base and goal with clearance > 0.3 m from the obstacles grown by r = 0.5 m; a quarter of the corner
rooms wall the goal off (a "no free route" refusal test). Every (room, method, N) runs the whole command line in a
subprocess (``python -m tmr.plan --map ROOM.geojson --base=X,Y --goal=X,Y --robots N --method M --no-plots``),
timed from process start to exit, through ``tmr.sweep.executor.make_executor`` (all cores by default, or Dask).

What a run should do, from the shortest tether route of :func:`tmr.route.route.plan_route` (N_min = fewest robots):

* goal not connected to the base (another piece of free space, checked with shapely): exit 2, "no free route";
* N < N_min: exit 2 with one line, fast;
* N ≥ N_min or ``--robots auto``: exit 0 with a plan keeping every hard limit.

Each plan's raw trajectories are checked **independently** of tmr's own metrics (shapely distances to the raw
obstacles and walls minus r for every robot centre and every straight tether chord anchor → robot 1 → … → robot N,
spans vs d_max, every robot pair ≥ 2r; :func:`tmr.sweep.room_runs.independent_check`, 1 mm tolerance on clearances).

Writes ``benchmarks/results/random_rooms.md``, ``.csv`` (one row per run) and ``.png`` (success per density × N,
histograms of whole-process times). BLAS runs on one thread per process unless OPENBLAS_NUM_THREADS/OMP_NUM_THREADS
is set. ``--quick``: the first 16 rooms (every density, every goal class), for smoke runs.

``--drive diff`` (issue 35, ``formulations/diffdrive.md``): every (room, N) is planned twice on the same inputs, with
the omnidirectional robots of Caruso 2021 and with ``--drive diff --robot-model M`` (M: ``--robot-model``, default the
planner's own default, :data:`tmr.model.diffdrive.DEFAULT_MODEL`); the report compares them (success of each, diff's
failures where omni plans and why, the planner's wall time ratio diff / omni per room both plan, median of
``--repeat`` runs each, f1, f4, the motion's duration, the diff checker's lateral velocity and v / ω peaks) and is
written to ``benchmarks/results/diffdrive_rooms.md`` / ``.csv`` (``--name``); the omni report is not touched.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import io
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
PINNED = not any(v in os.environ for v in THREAD_VARS)
if PINNED:
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = "1"

import numpy as np  # noqa: E402
from provenance import source_version, versions  # noqa: E402

from tmr.route.route import CHORD_CLEARANCE  # noqa: E402
from tmr.sweep.executor import make_executor  # noqa: E402
from tmr.sweep.room_runs import RoomRun, decide_count, run_room  # noqa: E402
from tmr.sweep.rooms import (  # noqa: E402
    DENSITIES,
    GOAL_CLASSES,
    SAFETY_RADIUS,
    Room,
    default_d_max,
    room_from_spec,
    room_set,
)

RESULTS = Path(__file__).resolve().parent / "results"
PACKAGES = ("numpy", "scipy", "shapely", "osqp", "ompl")
DEFAULT_ROOMS = 216  # 9 per density x goal class
QUICK_ROOMS = 16
ROBOTS = ("2", "3", "5", "8", "auto")

#: Targets of the project issue ("tether-aware global planning", item 6).
TARGET_AUTO_SUCCESS = 0.98  # fraction of connected goals planned with --robots auto (qp)
TARGET_REFUSE_S = 1.0  # s, whole process, every N < N_min
#: Part of tmr.plan's exit-1 verdict when a chain of N was found that only a tether's clearance keeps from being
#: planned (tmr.route.route.Route.refusal with ``tight_chain``).
TIGHT_VERDICT = f"keeping {CHORD_CLEARANCE:g} m from the obstacles was found, only closer ones"
TARGET_MEDIAN_PLAN_S = 2.0  # s, whole process, median

# ----------------------------------------------------------------------------------------------------------------
# classification
# ----------------------------------------------------------------------------------------------------------------
EXPECT_PLAN = "plan"  # route found and N >= N_min (or auto)
#: N < n_proven: proven too few (tmr.route.reach, tmr.sweep.room_runs.decide_count)
EXPECT_REFUSE_NMIN = "refuse: N < N_min"
#: n_clear ≤ N < n_min: a chain of N merely clear of the grown obstacles exists (found, checked independently), so N
#: is not below the problem's N_min; the plans keep 0.06 m, which takes n_min: exit 1 naming the clearance, or a plan
EXPECT_CLOSER = "plan, or name the clearance: only a chain nearer the obstacles than plans keep is known"
#: n_proven ≤ N < n_clear (or n_min when no clear chain is known): neither proven too few nor a chain found
EXPECT_UNDECIDED = "undecided: N_min unknown (no proof, no chain)"
EXPECT_REFUSE_DISCONNECTED = "refuse: not connected"
EXPECT_ROUTE_GAP = (
    "route module refuses a connected goal"  # shapely connects base and goal, tmr.route.route finds no chain
)


def expectation(row: dict[str, Any]) -> str:
    if not row["connected"]:
        return EXPECT_REFUSE_DISCONNECTED
    if row["n_min"] is None:
        return EXPECT_ROUTE_GAP
    if row["robots"] == "auto" or int(row["robots"]) >= int(row["n_min"]):
        return EXPECT_PLAN
    n = int(row["robots"])
    if n < int(row.get("n_proven") or row["n_lower"]):
        return EXPECT_REFUSE_NMIN
    if row.get("n_clear") is not None and n >= int(row["n_clear"]):
        return EXPECT_CLOSER
    return EXPECT_UNDECIDED


def as_expected(row: dict[str, Any]) -> bool:
    """The run did what its expectation asks (an undecided run: anything but a crash, a timeout or a refusal,
    which only a proof, absent here, could give)."""
    code = row["exit_code"]
    if row["expect"] == EXPECT_PLAN:
        return code == 0 and row.get("independent_ok") is True
    if row["expect"] in (EXPECT_REFUSE_NMIN, EXPECT_REFUSE_DISCONNECTED):
        return code == 2
    if row["expect"] == EXPECT_CLOSER:
        return (code == 0 and row.get("independent_ok") is True) or (
            code == 1 and TIGHT_VERDICT in str(row.get("stderr_last", ""))
        )
    if row["expect"] == EXPECT_UNDECIDED:
        return code in (0, 1) and (code == 1 or row.get("independent_ok") is True)
    return False


def outcome(row: dict[str, Any]) -> str:
    code = row["exit_code"]
    if code is None:
        return "timeout"
    if code == 0:
        return "planned" if row.get("independent_ok") is True else "planned, independent violation"
    if code == 1:
        return "failed" if row.get("n_robots") is not None else "no plan found (exit 1, nothing written)"
    if code == 2:
        return "refused"
    return f"crash ({code})"


# ----------------------------------------------------------------------------------------------------------------
# statistics helpers
# ----------------------------------------------------------------------------------------------------------------
def _vals(rows: list[dict[str, Any]], key: str) -> list[float]:
    return [float(r[key]) for r in rows if r.get(key) is not None and not math.isnan(float(r[key]))]


def _med(v: list[float]) -> float | None:
    return statistics.median(v) if v else None


def _fmt(v: Any, spec: str = ".2f") -> str:
    if v is None:
        return "—"
    if isinstance(v, float) and math.isinf(v):
        return "∞"
    return format(v, spec)


def _frac(k: int, n: int) -> str:
    return f"{k}/{n} ({100 * k / n:.0f} %)" if n else "—"


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Table cells of one (method, N) group."""
    reach = [r for r in rows if r["expect"] == EXPECT_PLAN]
    others = [r for r in rows if r["expect"] in (EXPECT_REFUSE_NMIN, EXPECT_REFUSE_DISCONNECTED)]
    gap = [r for r in rows if r["expect"] == EXPECT_ROUTE_GAP]
    ok_plans = [r for r in reach if r["exit_code"] == 0]
    closer = [r for r in rows if r["expect"] == EXPECT_CLOSER]
    undecided = [r for r in rows if r["expect"] == EXPECT_UNDECIDED]
    auto = [r for r in ok_plans if r["robots"] == "auto" and r.get("n_robots") is not None]
    all_plans = [r for r in rows if r["exit_code"] == 0]
    refusals = [r for r in others if r["exit_code"] == 2]
    planned_any = [r for r in rows if r["exit_code"] in (0, 1)]
    return {
        "rooms": len(rows),
        "reachable": len(reach),
        "success": len(ok_plans),
        "failed": sum(r["exit_code"] == 1 for r in reach),
        "wrong_refusals": sum(r["exit_code"] == 2 for r in reach),
        "timeouts": sum(r["exit_code"] not in (0, 1, 2) for r in rows),
        "others": len(others),
        "correct_refusals": len(refusals),
        "closer": len(closer),
        "closer_ok": sum(as_expected(r) for r in closer),
        "undecided": len(undecided),
        "auto_extra": Counter(int(r["n_robots"]) - int(r["n_min"]) for r in auto),
        "gap": len(gap),
        "gap_refused": sum(r["exit_code"] == 2 for r in gap),
        "gap_planned": sum(r["exit_code"] == 0 for r in gap),
        "refuse_med": _med(_vals(refusals, "wall_time")),
        "refuse_max": max(_vals(refusals, "wall_time"), default=None),
        "slow_refusals": sum(r["wall_time"] >= TARGET_REFUSE_S for r in refusals),
        "plan_med": _med(_vals(planned_any, "wall_time")),
        "plan_max": max(_vals(planned_any, "wall_time"), default=None),
        "ratio_med": _med(_vals(ok_plans, "route_ratio")),
        "min_robot": min(
            _vals(all_plans, "ind_robot_clearance") + _vals(all_plans, "ind_wall_clearance"), default=None
        ),
        "min_tether": min(_vals(all_plans, "ind_tether_clearance"), default=None),
        "max_span": max(_vals(all_plans, "ind_max_span_ratio"), default=None),
        "violations": sum(r.get("independent_ok") is False for r in all_plans),
        "filtered_violations": sum(r.get("filtered_ok") is False for r in all_plans),
        "unplanned_success": sum(r["exit_code"] == 0 and r["expect"] != EXPECT_PLAN for r in rows),
    }


# ----------------------------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------------------------
CSV_COLUMNS = [
    "room", "room_seed", "density", "goal_class", "n_obstacles", "base_x", "base_y", "goal_x", "goal_y",
    "connected", "straight", "route_found", "route_length", "n_lower", "n_min", "n_proven", "n_clear",
    "clear_margin", "route_error",
    "method", "robots", "expect", "outcome", "exit_code", "wall_time", "stderr_last",
    "success", "failure", "n_robots", "robots_auto", "route_length_cli", "n_lower_cli", "n_min_cli",
    "plan_wall_time", "d_max",
    "min_robot_clearance", "min_tether_clearance", "max_span_ratio", "final_leader_error",
    "leader_length", "leader_route_length", "route_ratio",
    "ind_robot_clearance", "ind_robot_clearance_step", "ind_wall_clearance", "ind_tether_clearance",
    "ind_tether_clearance_step", "ind_max_span_ratio", "ind_min_anchor_span", "ind_min_separation",
    "ind_violations", "independent_ok",
    "ind_filtered_robot_clearance", "ind_filtered_tether_clearance", "ind_filtered_max_span_ratio", "filtered_ok",
]  # fmt: skip


def write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    buf = io.StringIO()
    cw = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, extrasaction="ignore", lineterminator="\n")
    cw.writeheader()
    for r in rows:
        cw.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in CSV_COLUMNS})
    path.write_text(buf.getvalue())


def write_figure(rows: list[dict[str, Any]], method: str, robots: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mine = [r for r in rows if r["method"] == method]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    # (a) success among reachable, per density x N
    grid = np.full((len(DENSITIES), len(robots)), np.nan)
    text = [["" for _ in robots] for _ in DENSITIES]
    for i, d in enumerate(DENSITIES):
        for j, n in enumerate(robots):
            cell = [r for r in mine if r["density"] == d and r["robots"] == n]
            reach = [r for r in cell if r["expect"] == EXPECT_PLAN]
            ok = sum(r["exit_code"] == 0 and r.get("independent_ok") is True for r in reach)
            refused_ok = sum(
                r["exit_code"] == 2 for r in cell if r["expect"] in (EXPECT_REFUSE_NMIN, EXPECT_REFUSE_DISCONNECTED)
            )
            others = sum(r["expect"] in (EXPECT_REFUSE_NMIN, EXPECT_REFUSE_DISCONNECTED) for r in cell)
            if reach:
                grid[i, j] = ok / len(reach)
            text[i][j] = f"{ok}/{len(reach)}\nref {refused_ok}/{others}"
    ax = axes[0]
    im = ax.imshow(grid, vmin=0, vmax=1, cmap="RdYlGn", aspect="auto")
    for i in range(len(DENSITIES)):
        for j in range(len(robots)):
            ax.text(j, i, text[i][j], ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(robots)), [f"N={n}" for n in robots])
    ax.set_yticks(range(len(DENSITIES)), DENSITIES)
    ax.set_title(f"{method}: planned / reachable (N ≥ N_min)\n'ref': correct refusals / expected refusals", fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.046, label="success among reachable")
    # (b) whole-process times
    ax = axes[1]
    planned = _vals([r for r in mine if r["exit_code"] in (0, 1)], "wall_time")
    refused = _vals([r for r in mine if r["exit_code"] == 2], "wall_time")
    hi = max(planned + refused + [1.0])
    bins = np.geomspace(0.1, hi * 1.1, 40)
    ax.hist(planned, bins=bins, alpha=0.7, label=f"planned (exit 0/1), n={len(planned)}")
    ax.hist(refused, bins=bins, alpha=0.7, label=f"refused (exit 2), n={len(refused)}")
    ax.axvline(TARGET_REFUSE_S, color="k", ls=":", lw=1, label=f"refusal target {TARGET_REFUSE_S:g} s")
    ax.axvline(TARGET_MEDIAN_PLAN_S, color="k", ls="--", lw=1, label=f"median plan target {TARGET_MEDIAN_PLAN_S:g} s")
    ax.set_xscale("log")
    ax.set_xlabel("whole `python -m tmr.plan` process [s]")
    ax.set_ylabel("runs")
    ax.legend(fontsize=7)
    ax.set_title(f"{method}: whole-process time", fontsize=9)
    # (c) leader path length over shortest route
    ax = axes[2]
    ratios = _vals([r for r in mine if r["exit_code"] == 0], "route_ratio")
    if ratios:
        ax.hist(ratios, bins=30)
    ax.set_xlabel("leader path length / shortest free route from its start")
    ax.set_ylabel("plans")
    ax.set_title(f"{method}: route-length ratio of successful plans", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def generate_rooms(executor: Any, n_rooms: int, seed: int) -> tuple[list[Room], list[Any], float]:
    """The seeded rooms of ``room_set(n_rooms, seed)`` built on ``executor``: those generated, the errors of the
    others, and the time it took [s]."""
    t0 = time.perf_counter()
    generated = executor.map(room_from_spec, room_set(n_rooms, seed), desc="rooms")
    t_gen = time.perf_counter() - t0
    return [g for g in generated if isinstance(g, Room)], [g for g in generated if not isinstance(g, Room)], t_gen


def import_baseline(repeats: int = 3) -> float:
    """Median wall time [s] of importing what a refusal needs (tmr.plan, tmr.world.scenario, tmr.route.route) in a new
    process: the floor of every whole-process time."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import tmr.plan, tmr.world.scenario, tmr.route.route"], check=True)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", type=int, default=DEFAULT_ROOMS, help=f"number of rooms (default {DEFAULT_ROOMS})")
    ap.add_argument("--seed", type=int, default=0, help="seed of the room set (default 0)")
    ap.add_argument("--methods", default="qp", help="comma-separated methods: qp, pinv, horizon (default qp)")
    ap.add_argument("--subset", type=int, help="methods after the first run on the first K rooms only")
    ap.add_argument("--robots", default=",".join(ROBOTS), help="comma-separated N values (default 2,3,5,8,auto)")
    ap.add_argument("--plan-seed", type=int, default=0, help="--seed passed to tmr.plan (default 0)")
    ap.add_argument("--jobs", type=int, help="worker processes (default: every core; 1 = serial)")
    ap.add_argument("--scheduler", help="Dask scheduler address tcp://host:port (workers need tmr installed)")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per run before it is killed (default 600)")
    ap.add_argument("--keep-failures", help="copy the room and outputs of every unexpected run into this directory")
    ap.add_argument("--quick", action="store_true", help=f"smoke run: the first {QUICK_ROOMS} rooms")
    ap.add_argument("--out", default=str(RESULTS), help="output directory (default benchmarks/results)")
    ap.add_argument("--name", default="random_rooms", help="output file stem (default random_rooms)")
    ap.add_argument(
        "--drive",
        choices=("omni", "diff"),
        default="omni",
        help="diff: plan every room with omni and with differential-drive robots and compare them",
    )
    ap.add_argument("--robot-model", help="differential-drive preset or TOML file (implies --drive diff)")
    ap.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="--drive diff: runs per (room, N, drive); times are their median (default 1)",
    )
    args = ap.parse_args(argv)
    if args.robot_model:
        args.drive = "diff"
    if args.drive == "diff":
        if args.name == "random_rooms":
            args.name = "diffdrive_rooms"
        return drive_comparison(args, argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    robots = [n.strip() for n in args.robots.split(",") if n.strip()]
    n_rooms = QUICK_ROOMS if args.quick else args.rooms
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)

    t_start = time.perf_counter()
    load0 = os.getloadavg()
    baseline = import_baseline()
    executor = make_executor(args.jobs, args.scheduler, progress=True)
    try:
        rooms_ok, gen_errors, t_gen = generate_rooms(executor, n_rooms, args.seed)
        # where N_min lies when the proven bound is below the plans' count (a proof for each N, a clear chain)
        gap_rooms = [r for r in rooms_ok if r.n_min is not None and r.n_lower is not None and r.n_lower < r.n_min]
        t0 = time.perf_counter()
        decided = {d["room"]: d for d in executor.map(decide_count, gap_rooms, desc="N_min")}
        t_decide = time.perf_counter() - t0
        tasks = []
        for k, method in enumerate(methods):
            chosen = rooms_ok if k == 0 or args.subset is None else rooms_ok[: args.subset]
            for room in chosen:
                for n in robots:
                    tasks.append(RoomRun(room, method, n, args.plan_seed, args.timeout, args.keep_failures))
        t0 = time.perf_counter()
        rows = executor.map(run_room, tasks, desc="plans")
        t_runs = time.perf_counter() - t0
    finally:
        executor.close()
    for r in rows:
        d = decided.get(r["room"], {})
        r["n_proven"] = d.get("n_proven", r["n_lower"])
        r["n_clear"], r["clear_margin"] = d.get("n_clear"), d.get("clear_margin")
        r["expect"] = expectation(r)
        r["outcome"] = outcome(r)
    total = time.perf_counter() - t_start
    load1 = os.getloadavg()
    jobs_desc = (
        f"Dask scheduler {args.scheduler}" if args.scheduler else
        ("serial" if args.jobs == 1 else f"{args.jobs or os.cpu_count()} local worker processes")
    )  # fmt: skip

    # ------------------------------------------------------------------ report
    stem = out_dir / args.name
    write_csv(rows, stem.with_suffix(".csv"))
    write_figure(rows, methods[0], robots, stem.with_suffix(".png"))

    buf = io.StringIO()
    w = buf.write
    cmd = " ".join(argv if argv is not None else sys.argv[1:])
    w("# Random rooms: the whole `python -m tmr.plan` on seeded rooms\n\n")
    if args.quick:
        w(f"**Quick smoke run ({n_rooms} rooms)**: not the full benchmark; run without `--quick` for it.\n\n")
    w(f"`python benchmarks/random_rooms.py {cmd}`".replace(" `", "`") + f" — {datetime.date.today().isoformat()}, ")
    w(f"`{platform.machine()}`, nproc {os.cpu_count()}, Python {platform.python_version()}; {versions(PACKAGES)}; ")
    threads = ", ".join(f"{v}={os.environ[v]}" for v in THREAD_VARS if v in os.environ)
    w(f"{threads}; {source_version()}.\n")
    w(f"{jobs_desc}; total {total:.0f} s (room generation {t_gen:.0f} s, N_min bounds {t_decide:.0f} s, ")
    w(f"{len(tasks)} runs {t_runs:.0f} s); ")
    w(f"load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end. Whole-process times are measured while ")
    w("the other workers run, so they include contention on a loaded machine.\n\n")

    w("## Rooms\n\n")
    w(f"{len(rooms_ok)} rooms (`tmr.sweep.rooms.room_set({n_rooms}, seed={args.seed})`, 20 m × 20 m, r = 0.5 m, ")
    w(f"d_max = {default_d_max():.3f} m)")
    w(f"; {len(gen_errors)} could not be generated: {'; '.join(gen_errors)}" if gen_errors else "")
    w(
        ". Goal classes by the shortest free route of `tmr.route.route.plan_route`: near 2–6 m, mid 6–12 m, far > 3 "
        "d_max; "
    )
    w("corner = within 3 m of the corner farthest from the base (a quarter walled off).\n\n")
    w("| density | " + " | ".join(GOAL_CLASSES) + " | goal not connected | connected, no route (tmr.route.route) | ")
    w("N_min median (max) |\n|---|" + "---:|" * (len(GOAL_CLASSES) + 3) + "\n")
    for d in DENSITIES:
        rs = [r for r in rooms_ok if r.density == d]
        counts = Counter(r.goal_class for r in rs)
        nm = [r.n_min for r in rs if r.n_min is not None]
        w(f"| {d} | " + " | ".join(str(counts[g]) for g in GOAL_CLASSES))
        w(f" | {sum(not r.connected for r in rs)} | {sum(r.connected and r.n_min is None for r in rs)} | ")
        w(f"{_fmt(_med(nm), '.0f')} ({max(nm, default='—')}) |\n")
    w("| **all** | " + " | ".join(str(sum(r.goal_class == g for r in rooms_ok)) for g in GOAL_CLASSES))
    w(f" | {sum(not r.connected for r in rooms_ok)} | {sum(r.connected and r.n_min is None for r in rooms_ok)} | |\n\n")
    w(
        "*goal not connected*: base and goal lie in different pieces of the free space (shapely, independent of "
        "tmr.route.route); every run should refuse. *connected, no route*: shapely connects them but "
        "`tmr.route.route` finds no "
        "chain of free tether chords (a gap it judges too narrow); these are reported apart from the targets.\n\n"
    )
    exact = sum(d["n_clear"] is not None and d["n_clear"] == d["n_proven"] for d in decided.values())
    routed = [r for r in rooms_ok if r.n_min is not None and r.n_lower is not None]
    w(
        f"In {len(gap_rooms)} of the {len(routed)} rooms with a route, `tmr.route.route`'s proven bound N_lower is "
        f"below "
        "N_min, the plans' count (tethers keeping 0.06 m). There `tmr.sweep.room_runs.decide_count` tries the proof "
        "for "
        "every N below N_min and searches a chain merely clear of the grown obstacles (the problem's definition of "
        f"N_min), checked independently ({t_decide:.0f} s): the problem's N_min is decided in {exact} of them, so in "
        f"{len(routed) - len(gap_rooms) + exact} of the {len(routed)} in all.\n\n"
    )

    w("## Per method and N\n\n")
    w(
        "*reachable*: the goal is connected, `tmr.route.route` finds a route and N ≥ N_min (every connected goal with "
        "a "
        "route for `auto`). *success*: exit 0 among reachable. *correct refusals*: exit 2 among the others (N proven "
        "below N_min, goal not connected). *closer*: runs with N below the plans' count whose N is not below the "
        "N_min of chords merely clear of the grown obstacles (a chain of N found and checked independently), as "
        "runs that plan or exit 1 naming the clearance / runs. *undecided*: runs with N neither proven too few nor "
        "matched by a chain found (N_min unknown). *wrong ref.*: exit 2 for a reachable goal; *fail*: exit 1 for a "
        "reachable goal; "
        "*t/o*: timeouts or crashes. Times are whole-process wall times [s] (refusals: the expected ones; plan: every "
        "run that wrote a plan, exit 0 or 1). *ratio*: median leader path length / shortest free route from the "
        "leader's start to the goal (successful plans). Independent minima over every successful plan (exit 0): "
        "robot = min over robots and steps of the distance of the centre to the raw obstacles and walls − r; tether = "
        "the same for every straight chord; *viol.*: successful plans breaking an independent check (raw "
        "trajectories; in brackets: the filtered ones). *gap*: runs on connected goals `tmr.route.route` refuses, as "
        "refused / planned.\n\n"
    )
    w(
        "| method | N | rooms | reachable | success | fail | wrong ref. | t/o | correct refusals | closer | undecided "
        "| refuse med / max [s] | plan med / max [s] | ratio | min robot clr [m] | min tether clr [m] "
        "| max span/d_max | viol. | gap |\n"
    )
    w("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n")
    table: list[tuple[str, str, dict[str, Any]]] = []
    for method in methods:
        for n in robots:
            s = summarise([r for r in rows if r["method"] == method and r["robots"] == n])
            table.append((method, n, s))
            w(f"| {method} | {n} | {s['rooms']} | {s['reachable']} | {_frac(s['success'], s['reachable'])} | ")
            w(f"{s['failed']} | {s['wrong_refusals']} | {s['timeouts']} | {_frac(s['correct_refusals'], s['others'])}")
            w(f" | {s['closer_ok']}/{s['closer']} | {s['undecided']} ")
            w(f"| {_fmt(s['refuse_med'])} / {_fmt(s['refuse_max'])} | {_fmt(s['plan_med'])} / {_fmt(s['plan_max'])} ")
            w(f"| {_fmt(s['ratio_med'], '.3f')} | {_fmt(s['min_robot'], '.3f')} | {_fmt(s['min_tether'], '.3f')} ")
            w(f"| {_fmt(s['max_span'], '.3f')} | {s['violations']} ({s['filtered_violations']}) ")
            w(f"| {s['gap_refused']} / {s['gap_planned']} of {s['gap']} |\n")
    w(
        f"\n`python -c 'import tmr.plan, tmr.world.scenario, tmr.route.route'` (what a refusal imports) takes "
        f"{baseline:.2f} s "
        "here (median of 3, before the runs): the floor under every whole-process time above.\n\n"
    )
    for method in methods:
        s = summarise([r for r in rows if r["method"] == method and r["robots"] == "auto"])
        if s["auto_extra"]:
            parts = ", ".join(f"N_min + {k}: {v}" for k, v in sorted(s["auto_extra"].items()))
            w(f"{method}, `--robots auto`, successful plans by the N chosen: {parts}.\n\n")

    # per density x N for the first method
    method = methods[0]
    w(f"## {method}: success among reachable per density × N\n\n")
    w("| density | " + " | ".join(f"N={n}" for n in robots) + " |\n|---|" + "---:|" * len(robots) + "\n")
    for d in DENSITIES:
        cells = []
        for n in robots:
            s = summarise([r for r in rows if r["method"] == method and r["robots"] == n and r["density"] == d])
            cells.append(_frac(s["success"], s["reachable"]))
        w(f"| {d} | " + " | ".join(cells) + " |\n")
    w("\n")

    # targets
    w("## Targets\n\n")
    autos = [r for r in rows if r["method"] == "qp" and r["robots"] == "auto"]
    lines = []
    if autos:
        conn = [r for r in autos if r["connected"]]
        ok = [r for r in conn if r["exit_code"] == 0 and r.get("independent_ok") is True]
        frac = len(ok) / len(conn) if conn else math.nan
        lines.append(
            (
                f"qp, `--robots auto`: plans ≥ {100 * TARGET_AUTO_SUCCESS:.0f} % of the rooms whose goal is "
                f"connected (shapely), independent checks passed",
                f"{_frac(len(ok), len(conn))}",
                frac >= TARGET_AUTO_SUCCESS,
            )
        )
    plans = [r for r in rows if r["exit_code"] == 0]
    bad = [r for r in plans if r.get("independent_ok") is not True or r.get("success") is not True]
    lines.append(
        (
            "every plan (exit 0) keeps every hard limit (tmr's metrics and the independent check)",
            f"{len(plans) - len(bad)}/{len(plans)}",
            not bad,
        )
    )
    low = [r for r in rows if r["expect"] == EXPECT_REFUSE_NMIN]
    low_ok = [r for r in low if r["exit_code"] == 2 and r["wall_time"] < TARGET_REFUSE_S]
    low_ref = [r for r in low if r["exit_code"] == 2]
    undecided = [r for r in rows if r["expect"] == EXPECT_UNDECIDED]
    lines.append(
        (
            f"every N < N_min refused (exit 2) in < {TARGET_REFUSE_S:g} s (whole process)",
            f"N proven below N_min: {len(low_ref)}/{len(low)} refused, {len(low_ok)}/{len(low)} in time; median "
            f"{_fmt(_med(_vals(low_ref, 'wall_time')))} s, max {_fmt(max(_vals(low_ref, 'wall_time'), default=None))}"
            f" s. N_min unknown (neither proven nor matched by a chain found): {len(undecided)} runs"
            + (f" ({', '.join(sorted(r['room'] + ' N=' + r['robots'] for r in undecided))})" if undecided else ""),
            len(low_ok) == len(low) and not undecided,
        )
    )
    closer = [r for r in rows if r["expect"] == EXPECT_CLOSER]
    closer_ok = [r for r in closer if as_expected(r)]
    margins = _vals(closer, "clear_margin")
    lines.append(
        (
            "N below the plans' count (tethers keeping 0.06 m) but not below N_min (a chain of N whose tethers are "
            "merely clear of the grown obstacles, found by `tmr.route.route.clear_chain` and checked independently): "
            "exit 1 naming the clearance, or a plan",
            f"{len(closer_ok)}/{len(closer)}"
            + (f" (those chains' least tether clearance {min(margins):.3f}–{max(margins):.3f} m)" if margins else ""),
            len(closer_ok) == len(closer),
        )
    )
    disc = [r for r in rows if r["expect"] == EXPECT_REFUSE_DISCONNECTED]
    disc_ok = [r for r in disc if r["exit_code"] == 2]
    lines.append(
        ("every goal not connected refused (exit 2)", _frac(len(disc_ok), len(disc)), len(disc_ok) == len(disc))
    )
    high = [r for r in rows if r["expect"] == EXPECT_PLAN and r["robots"] != "auto"]
    wrong = [r for r in high if r["exit_code"] == 2]
    lines.append(("no N ≥ N_min refused", f"{len(wrong)} of {len(high)} refused", not wrong))
    pt = _vals([r for r in rows if r["exit_code"] in (0, 1)], "wall_time")
    pt0 = _vals(plans, "wall_time")
    lines.append(
        (
            f"median whole `tmr.plan` time < {TARGET_MEDIAN_PLAN_S:g} s (runs that wrote a plan)",
            f"{_fmt(_med(pt))} s (exit 0 only: {_fmt(_med(pt0))} s; all runs: "
            f"{_fmt(_med(_vals(rows, 'wall_time')))} s)",
            (_med(pt) or math.inf) < TARGET_MEDIAN_PLAN_S,
        )
    )
    w("| target | measured | met |\n|---|---|---|\n")
    for what, measured, met in lines:
        w(f"| {what} | {measured} | {'yes' if met else '**no**'} |\n")
    w("\n")

    # what went wrong
    unexpected = [r for r in rows if not as_expected(r)]
    w(f"## Runs that did not do what was expected ({len(unexpected)} of {len(rows)})\n\n")
    if unexpected:
        reasons = Counter((r["expect"], r["outcome"]) for r in unexpected)
        w("| expected | outcome | runs |\n|---|---|---:|\n")
        for (e, o), c in reasons.most_common():
            w(f"| {e} | {o} | {c} |\n")
        w("\nLast stderr line, most frequent first (numbers replaced by #):\n\n")
        import re

        msgs = Counter(re.sub(r"-?\d+(\.\d+)?", "#", r["stderr_last"] or r.get("ind_violations") or "")[:160]
                       for r in unexpected)  # fmt: skip
        w("| runs | message |\n|---:|---|\n")
        for m, c in msgs.most_common(15):
            w(f"| {c} | {m.replace('|', '/')} |\n")
        w("\nEvery run: `" + stem.with_suffix(".csv").name + "` (`expect`, `outcome`, `stderr_last`).\n")
    else:
        w("None.\n")
    w(f"\nFigure: `{stem.with_suffix('.png').name}` (success per density × N, whole-process times, route ratios).\n")
    stem.with_suffix(".md").write_text(buf.getvalue())
    print(buf.getvalue())
    print(f"wrote {stem.with_suffix('.md')}, .csv, .png")
    return 0


# ----------------------------------------------------------------------------------------------------------------
# --drive diff: omni and differential drive on the same rooms
# ----------------------------------------------------------------------------------------------------------------
#: Targets of issue 35 for differential drive on the random rooms.
TARGET_DIFF_SUCCESS = 0.95  # diff's successes / omni's successes, same rooms and N
TARGET_DIFF_TIME_RATIO = 2.0  # planner wall time diff / omni per room both plan (median; reported with the max)

DIFF_COLUMNS = [
    "room", "room_seed", "density", "goal_class", "n_obstacles", "connected", "route_length", "n_min", "robots",
    "omni_exit", "omni_ok", "omni_n_robots", "omni_plan_s", "omni_wall_s", "omni_steps", "omni_duration_s",
    "omni_f1", "omni_f4",
    "diff_exit", "diff_ok", "diff_n_robots", "diff_plan_s", "diff_wall_s", "diff_steps", "diff_duration_s",
    "diff_f1", "diff_f4", "diff_max_lateral_m_s", "diff_peak_v", "diff_v_max", "diff_peak_omega", "diff_omega_max",
    "diff_turn_in_place_steps", "diff_min_robot_clr", "diff_min_tether_clr",
    "omni_references", "diff_references", "diff_references_note",
    "plan_time_ratio", "wall_time_ratio", "duration_ratio", "diff_failure",
    "same_exit", "same_ok", "same_plan_s", "same_steps", "same_duration_s", "same_references",
    "plan_time_ratio_same", "duration_ratio_same",
]  # fmt: skip


def _ok(r: dict[str, Any]) -> bool:
    """A success: exit 0 and the independent check of the raw trajectories passed."""
    return r["exit_code"] == 0 and r.get("independent_ok") is True


def _reason(r: dict[str, Any]) -> str:
    """Why a run is not a success, in one line."""
    if _ok(r):
        return ""
    if r["exit_code"] is None:
        return "timeout"
    if r["exit_code"] == 0:
        return f"independent check: {r.get('ind_violations') or 'failed'}"
    parts = [f"exit {r['exit_code']}"]
    if r.get("violation_kinds"):
        parts.append(f"violations: {r['violation_kinds']}")
    if r.get("failure"):
        parts.append(str(r["failure"]))
    if r.get("stderr_last"):
        parts.append(str(r["stderr_last"]))
    return "; ".join(parts)[:300]


def _merge_repeats(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The first run's row with ``plan_wall_time`` and ``wall_time`` [s] replaced by the medians of the runs."""
    row = dict(runs[0])
    for key in ("plan_wall_time", "wall_time"):
        v = [float(r[key]) for r in runs if r.get(key) is not None]
        row[key] = statistics.median(v) if v else None
    row["repeats"] = len(runs)
    return row


def _ratio(a: Any, b: Any) -> float | None:
    return float(a) / float(b) if a is not None and b is not None and float(b) > 0 else None


def same_speed_args(model: Any) -> tuple[str, ...]:
    """``--set`` arguments that give the omnidirectional chain the differential-drive robot's speeds: the leader's
    time law of ``--drive diff`` (:func:`tmr.planner.diff_leader_law`), the followers' references rising at most
    at the diff run's catch-up speed (:func:`tmr.planner.diff_catch_up`), every robot's speed bound at v_max [m/s]
    (per axis, the omni model's bound: up to √2 v_max diagonally) and its acceleration bound at a_max [m/s²]. With
    them, diff against omni measures what the drive costs (its heading, the wheel rows, the span braking curve), not
    that the robot is slower than the paper's (0.8 m/s leader)."""
    from tmr.model.params import PathParams, QPParams
    from tmr.planner import diff_catch_up, diff_leader_law

    path, qp = diff_leader_law(PathParams(), model), QPParams()
    values = {
        "leader_speed": path.leader_speed,
        "leader_accel": path.leader_accel,
        "robot_speed_max": min(qp.robot_speed_max, model.v_max),
        "robot_accel_max": min(qp.robot_accel_max, model.a_max),
        "catch_up": diff_catch_up(model),
    }
    return tuple(a for k, v in values.items() for a in ("--set", f"{k}={v:.12g}"))


def drive_comparison(args: argparse.Namespace, argv: list[str] | None) -> int:
    """``--drive diff``: omni and diff on the same rooms (see the module docstring); writes ``args.name`` .md/.csv."""
    from tmr.model.diffdrive import DEFAULT_MODEL, load_robot_model
    from tmr.model.params import PathParams

    model = load_robot_model(args.robot_model or DEFAULT_MODEL)
    model_arg = args.robot_model or DEFAULT_MODEL
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if methods != ["qp"]:
        raise SystemExit("--drive diff is planned by --method qp only")
    robots = [n.strip() for n in args.robots.split(",") if n.strip()]
    n_rooms = QUICK_ROOMS if args.quick else args.rooms
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    # the rooms' r (0.5 m, what the omni runs use and the independent check keeps): a diff-drive --map run would
    # otherwise take the model's footprint reach b + r_f (tmr.plan.diff_map_radius), not the same problem
    diff_args = ("--drive", "diff", "--robot-model", model_arg, "--robot-radius", f"{SAFETY_RADIUS:g}")
    same_args = same_speed_args(model)

    t_start = time.perf_counter()
    load0 = os.getloadavg()
    executor = make_executor(args.jobs, args.scheduler, progress=True)
    try:
        rooms_ok, gen_errors, t_gen = generate_rooms(executor, n_rooms, args.seed)
        keys, tasks = [], []
        for room in rooms_ok:
            for n in robots:
                for drive, extra in (("omni", ()), ("same", same_args), ("diff", diff_args)):
                    for _ in range(max(1, args.repeat)):
                        keys.append((room.name, n, drive))
                        tasks.append(
                            RoomRun(room, "qp", n, args.plan_seed, args.timeout, args.keep_failures, tuple(extra))
                        )
        t0 = time.perf_counter()
        results = executor.map(run_room, tasks, desc="plans")
        t_runs = time.perf_counter() - t0
    finally:
        executor.close()
    grouped: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for k, r in zip(keys, results, strict=True):
        grouped.setdefault(k, []).append(r)
    pairs = []
    for room in rooms_ok:
        for n in robots:
            o = _merge_repeats(grouped[(room.name, n, "omni")])
            d = _merge_repeats(grouped[(room.name, n, "diff")])
            s = _merge_repeats(grouped[(room.name, n, "same")])
            both = _ok(o) and _ok(d)
            both_same = _ok(s) and _ok(d)
            pairs.append(
                {
                    "room": room.name, "room_seed": o.get("room_seed"), "density": o.get("density"),
                    "goal_class": o.get("goal_class"), "n_obstacles": o.get("n_obstacles"),
                    "connected": o.get("connected"), "route_length": o.get("route_length"), "n_min": o.get("n_min"),
                    "robots": n,
                    "omni_exit": o["exit_code"], "omni_ok": _ok(o), "omni_n_robots": o.get("n_robots"),
                    "omni_plan_s": o.get("plan_wall_time"), "omni_wall_s": o.get("wall_time"),
                    "omni_steps": o.get("n_steps"), "omni_duration_s": o.get("duration"),
                    "omni_f1": o.get("f1"), "omni_f4": o.get("f4"),
                    "diff_exit": d["exit_code"], "diff_ok": _ok(d), "diff_n_robots": d.get("n_robots"),
                    "diff_plan_s": d.get("plan_wall_time"), "diff_wall_s": d.get("wall_time"),
                    "diff_steps": d.get("n_steps"), "diff_duration_s": d.get("duration"),
                    "diff_f1": d.get("f1"), "diff_f4": d.get("f4"),
                    "diff_max_lateral_m_s": d.get("max_lateral_velocity"), "diff_peak_v": d.get("peak_v"),
                    "diff_v_max": d.get("v_max"), "diff_peak_omega": d.get("peak_omega"),
                    "diff_omega_max": d.get("omega_max"), "diff_turn_in_place_steps": d.get("turn_in_place_steps"),
                    "diff_min_robot_clr": d.get("ind_robot_clearance"),
                    "diff_min_tether_clr": d.get("ind_tether_clearance"),
                    "plan_time_ratio": _ratio(d.get("plan_wall_time"), o.get("plan_wall_time")) if both else None,
                    "wall_time_ratio": _ratio(d.get("wall_time"), o.get("wall_time")) if both else None,
                    "duration_ratio": _ratio(d.get("duration"), o.get("duration")) if both else None,
                    "omni_references": o.get("references"),
                    "diff_references": d.get("references"),
                    "diff_references_note": d.get("references_note"),
                    "diff_failure": _reason(d),
                    "omni_failure": _reason(o),
                    "same_exit": s["exit_code"], "same_ok": _ok(s), "same_plan_s": s.get("plan_wall_time"),
                    "same_steps": s.get("n_steps"), "same_duration_s": s.get("duration"),
                    "same_references": s.get("references"),
                    "plan_time_ratio_same": (
                        _ratio(d.get("plan_wall_time"), s.get("plan_wall_time")) if both_same else None
                    ),
                    "duration_ratio_same": _ratio(d.get("duration"), s.get("duration")) if both_same else None,
                }
            )  # fmt: skip
    total = time.perf_counter() - t_start
    load1 = os.getloadavg()

    stem = out_dir / args.name
    buf = io.StringIO()
    cw = csv.DictWriter(buf, fieldnames=DIFF_COLUMNS, extrasaction="ignore", lineterminator="\n")
    cw.writeheader()
    for r in pairs:
        cw.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in DIFF_COLUMNS})
    stem.with_suffix(".csv").write_text(buf.getvalue())

    buf = io.StringIO()
    w = buf.write
    cmd = " ".join(argv if argv is not None else sys.argv[1:])
    jobs_desc = "serial" if args.jobs == 1 else f"{args.jobs or os.cpu_count()} local worker processes"
    w(f"# Random rooms: omni against differential drive ({model.name})\n\n")
    if args.quick:
        w(f"**Quick smoke run ({n_rooms} rooms)**: not the full benchmark.\n\n")
    w(f"`python benchmarks/random_rooms.py {cmd}` — {datetime.date.today().isoformat()}, `{platform.machine()}`, ")
    w(f"nproc {os.cpu_count()}, Python {platform.python_version()}; {versions(PACKAGES)}; {source_version()}.\n")
    w(f"{jobs_desc}; total {total:.0f} s (room generation {t_gen:.0f} s, {len(tasks)} runs {t_runs:.0f} s); load ")
    w(f"average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end (other work shares the 2 cores).\n\n")
    w(f"{len(rooms_ok)} rooms of `tmr.sweep.rooms.room_set({n_rooms}, seed={args.seed})` (the rooms of ")
    w("`random_rooms.md`, 20 m × 20 m, safety radius r = 0.5 m)")
    w(f"; {len(gen_errors)} could not be generated" if gen_errors else "")
    w(f"; N ∈ {{{', '.join(robots)}}}. Every (room, N) runs `python -m tmr.plan --map ROOM --base … --goal … ")
    w("--robots N --method qp` three times: omni (Caruso 2021, leader at ")
    w(f"{_fmt(PathParams().leader_speed, 'g')} m/s), ")
    w(f"*omni at the robot's speeds* (`{' '.join(same_args)}`: the diff run's leader time law and followers' ")
    w("catch-up speed, the robot's v_max (per axis: up to √2 v_max diagonally) and a_max as the omni bounds; ")
    w(f"`same_speed_args`) and with `{' '.join(diff_args)}` ")
    w(f"(r_f {model.radius:g} m, v_max {model.v_max:g} m/s, ω_max {model.omega_max:g} rad/s, a_max ")
    w(f"{model.a_max:g} m/s², α_max {model.alpha_max:g} rad/s², b {model.exit_offset:g} m). *Success*: exit 0 and ")
    w("the independent shapely check of the raw trajectories (diff: of the tethers' exit points) passed. ")
    w("*plan time*: the planner's `wall_time` in `timings.json` (route, loop, checks; no interpreter start), ")
    w(f"median of {max(1, args.repeat)} run(s); *process*: the whole subprocess.\n\n")

    w("Two time ratios per room: **diff / omni** compares with the paper's faster robots, so it mostly measures ")
    w("the longer motion (column *motion duration ratio*: the same route at the robot's speed takes that many more ")
    w("0.05 s steps); **diff / same-speed omni** compares the same route, time law, reference speeds and step count; ")
    w("what differs is the drive (the heading and exact arcs, v/ω and wheel-rim rows, the span braking curve; the ")
    w("omni bound is per axis), so it measures what the non-holonomic drive itself costs the planner. The issue's ")
    w("≤ 2× target is read on the second (the first is reported beside it).\n\n")
    w("## Success and time\n\n")
    w("| N | rooms | omni success | diff success | diff / omni successes | both | diff fails, omni plans | ")
    w("omni fails, diff plans | plan time ratio median / max | process time ratio median / max | ")
    w("motion duration ratio median / max | same-speed omni success | diff / same-speed plan time ratio median / ")
    w("max | diff / same-speed motion duration median / max |\n|---|" + "---:|" * 13 + "\n")
    lines = []
    for n in [*robots, "all"]:
        rs = [r for r in pairs if n == "all" or r["robots"] == n]
        if n == "all" and len(robots) == 1:
            continue
        o_ok = sum(r["omni_ok"] for r in rs)
        d_ok = sum(r["diff_ok"] for r in rs)
        both = [r for r in rs if r["omni_ok"] and r["diff_ok"]]
        pr, wr, dr = (_vals(both, k) for k in ("plan_time_ratio", "wall_time_ratio", "duration_ratio"))
        lines.append((n, o_ok, d_ok, pr))
        w(f"| {n} | {len(rs)} | {o_ok} | {d_ok} | {_fmt(d_ok / o_ok if o_ok else None, '.3f')} | {len(both)} | ")
        w(f"{sum(r['omni_ok'] and not r['diff_ok'] for r in rs)} | ")
        w(f"{sum(r['diff_ok'] and not r['omni_ok'] for r in rs)}")
        w(f" | {_fmt(_med(pr))} / {_fmt(max(pr, default=None))} | {_fmt(_med(wr))} / {_fmt(max(wr, default=None))} ")
        w(f"| {_fmt(_med(dr))} / {_fmt(max(dr, default=None))} | {sum(r['same_ok'] for r in rs)} ")
        ps, ds = (_vals(rs, k) for k in ("plan_time_ratio_same", "duration_ratio_same"))
        w(f"| {_fmt(_med(ps))} / {_fmt(max(ps, default=None))} | {_fmt(_med(ds))} / {_fmt(max(ds, default=None))} |\n")
    w("\n")
    both = [r for r in pairs if r["omni_ok"] and r["diff_ok"]]
    pr = _vals(both, "plan_time_ratio")
    w("Plan time ratio per density (rooms both plan): ")
    w("; ".join(f"{d} {_fmt(_med(_vals([r for r in both if r['density'] == d], 'plan_time_ratio')))}"
                for d in DENSITIES))  # fmt: skip
    w(". Per goal class: ")
    w("; ".join(f"{g} {_fmt(_med(_vals([r for r in both if r['goal_class'] == g], 'plan_time_ratio')))}"
                for g in GOAL_CLASSES))  # fmt: skip
    over = sum(v > TARGET_DIFF_TIME_RATIO for v in pr)
    w(f". {over} of {len(pr)} rooms both plan have a plan time ratio above {TARGET_DIFF_TIME_RATIO:g}.\n\n")

    both_train = [r for r in both if r["diff_references"] == "train" and r["omni_references"] != "train"]
    w("Rooms both plan where diff needed the train references (one robot at a time; its trailing-reference plan ")
    w(f"failed) and omni did not: {len(both_train)}")
    if both_train:
        w(" — " + "; ".join(f"{r['room']}: ratio {_fmt(r['plan_time_ratio'])}, {r['diff_references_note'] or ''}"
                            for r in both_train))  # fmt: skip
    rest = _vals([r for r in both if r not in both_train], "plan_time_ratio")
    w(f". Plan time ratio over the other rooms: median {_fmt(_med(rest))}, max {_fmt(max(rest, default=None))}.\n\n")

    w("## Differential-drive checks (successful diff plans)\n\n")
    dok = [r for r in pairs if r["diff_ok"]]
    if dok:
        w(f"max lateral velocity of an axle centre {_fmt(max(_vals(dok, 'diff_max_lateral_m_s')), '.3g')} m/s; ")
        w(f"peak v {_fmt(max(_vals(dok, 'diff_peak_v')), '.4f')} m/s (v_max {model.v_max:g}); peak ω ")
        w(f"{_fmt(max(_vals(dok, 'diff_peak_omega')), '.3f')} rad/s (ω_max {model.omega_max:g}); turn-in-place ")
        tip = _vals(dok, "diff_turn_in_place_steps")
        w(f"steps per plan median {_fmt(_med(tip), '.0f')}, max {_fmt(max(tip), '.0f')}; least robot clearance ")
        w(f"{_fmt(min(_vals(dok, 'diff_min_robot_clr')), '.3f')} m, tether ")
        w(f"{_fmt(min(_vals(dok, 'diff_min_tether_clr')), '.3f')} m ")
        w("(independent, exit points). f1 and f4 (Caruso 2021 eq. 24, 27) per room are in the CSV; medians over the ")
        w(f"rooms both plan: f1 omni {_fmt(_med(_vals(both, 'omni_f1')), '.4g')}, diff ")
        w(f"{_fmt(_med(_vals(both, 'diff_f1')), '.4g')}; f4 omni {_fmt(_med(_vals(both, 'omni_f4')), '.4g')}, diff ")
        w(f"{_fmt(_med(_vals(both, 'diff_f4')), '.4g')}.\n\n")
    else:
        w("No successful diff plan.\n\n")

    w("## Targets (issue 35)\n\n| target | measured | met |\n|---|---|---|\n")
    o_all = sum(r["omni_ok"] for r in pairs)
    d_all = sum(r["diff_ok"] for r in pairs)
    frac = d_all / o_all if o_all else math.nan
    w(f"| diff plans ≥ {100 * TARGET_DIFF_SUCCESS:.0f} % of omni's successes on the same rooms | {d_all} / {o_all} ")
    w(f"= {100 * frac:.1f} % | {'yes' if frac >= TARGET_DIFF_SUCCESS else '**no**'} |\n")
    both_same = [r for r in pairs if r["same_ok"] and r["diff_ok"]]
    ps = _vals(both_same, "plan_time_ratio_same")
    over_same = sum(v > TARGET_DIFF_TIME_RATIO for v in ps)
    s_all = sum(r["same_ok"] for r in pairs)
    w(f"| diff plans ≥ {100 * TARGET_DIFF_SUCCESS:.0f} % of same-speed omni's successes | {d_all} / {s_all} ")
    w(f"= {_fmt(100 * d_all / s_all if s_all else None, '.1f')} % | ")
    w(f"{'yes' if s_all and d_all / s_all >= TARGET_DIFF_SUCCESS else '**no**'} |\n")
    for label, vals, n_over in (("same-speed omni", ps, over_same), ("omni at the paper's speed", pr, over)):
        med = _med(vals)
        w(f"| plan time diff / {label} ≤ {TARGET_DIFF_TIME_RATIO:g}× per plan | median {_fmt(med)}, max ")
        w(f"{_fmt(max(vals, default=None))}, {n_over} of {len(vals)} above | ")
        if vals and max(vals) <= TARGET_DIFF_TIME_RATIO:
            met = "yes"
        elif med is not None and med <= TARGET_DIFF_TIME_RATIO:
            met = "median only"
        else:
            met = "**no**"
        w(f"{met}{'' if label.startswith('same') else ' (not the target: the motion is longer, see above)'} |\n")
    w("\n")
    over_rows = sorted((r for r in both_same if (r["plan_time_ratio_same"] or 0.0) > TARGET_DIFF_TIME_RATIO),
                       key=lambda r: -r["plan_time_ratio_same"])  # fmt: skip
    if over_rows:
        w("Rooms above the target against same-speed omni: ")
        w("; ".join(f"{r['room']} N={r['robots']}: {_fmt(r['plan_time_ratio_same'])} (motion ×"
                    f"{_fmt(r['duration_ratio_same'])}, references {r['diff_references']} / {r['same_references']})"
                    for r in over_rows))  # fmt: skip
        w(".\n\n")

    fails = [r for r in pairs if r["omni_ok"] and not r["diff_ok"]]
    w(f"## Rooms where diff fails and omni plans ({len(fails)})\n\n")
    if fails:
        w("| room | N | density | goal | diff exit | reason |\n|---|---|---|---|---:|---|\n")
        for r in fails:
            w(f"| {r['room']} | {r['robots']} | {r['density']} | {r['goal_class']} | {r['diff_exit']} | ")
            w(f"{r['diff_failure'].replace('|', '/')} |\n")
    else:
        w("None.\n")
    rev = [r for r in pairs if r["diff_ok"] and not r["omni_ok"]]
    if rev:
        w(f"\nRooms where omni fails and diff plans ({len(rev)}): ")
        w("; ".join(f"{r['room']} N={r['robots']} ({r['omni_failure'][:120]})" for r in rev) + ".\n")
    neither = [r for r in pairs if not r["diff_ok"] and not r["omni_ok"]]
    w(f"\nNeither plans: {len(neither)} (room, N) (goal not connected: "
      f"{sum(not r['connected'] for r in neither)}). Every row: `{stem.with_suffix('.csv').name}`.\n")  # fmt: skip
    stem.with_suffix(".md").write_text(buf.getvalue())
    print(buf.getvalue())
    print(f"wrote {stem.with_suffix('.md')}, .csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
