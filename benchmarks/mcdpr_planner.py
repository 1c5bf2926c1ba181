"""MoPICK planners on generated scenes: the search planner (placement graph, certified μ between samples) vs the
paper's greedy two-stage planner (Rasheed 2019), from easy to infeasible.

    python benchmarks/mcdpr_planner.py [--repeats 3] [--greedy-repeats 1] [--only NAME ...]

A benchmark, not a test. Every scene is generated here (deterministic): an open room, the shipped fig2, fig2 with a
table (and its task point) moved, rings of disc obstacles the bases must go round, a task point in a corner, a wall
the bases cannot cross, heavy payloads and infeasible starts, bases starting across the direction of travel (they
must turn one at a time), routes back to an earlier task point. For each scene the expected verdict is stated (plan /
refused up front with the limit / no placement / not connectable) and compared with what the planners return:

* ``search`` — :func:`tmr.mcdpr.search.plan_search` (exit 0 plan, 1 no plan found, 2 refused);
* ``greedy`` — :func:`tmr.mcdpr.planner.plan` after the same up-front refusal, "plan" only when
  :func:`tmr.mcdpr.planner.check` passes (μ > 0 at the samples etc.).

Columns: wall time (median of ``--repeats``), samples, base path length (sum over the bases) [m], μ_min at the samples
[N] and the guaranteed lower bound between samples [N] (search). Timings are medians; BLAS runs on one thread. Writes
``benchmarks/results/mcdpr_planner.md``, ``mcdpr_planner.csv`` and top views / μ plots of a few scenes.
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
import sys
import time
from importlib import resources
from pathlib import Path
from typing import Any

THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
if not any(v in os.environ for v in THREAD_VARS):
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = "1"

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

import numpy as np  # noqa: E402

from tmr.io.outputs import atomic_write_text  # noqa: E402
from tmr.mcdpr.capacity import required_wrench_set  # noqa: E402
from tmr.mcdpr.errors import NoPlanFound, TaskRefused  # noqa: E402
from tmr.mcdpr.planner import check, plan  # noqa: E402
from tmr.mcdpr.robot import Robot, mopick  # noqa: E402
from tmr.mcdpr.scene import Scene, scene_from_dict  # noqa: E402
from tmr.mcdpr.search import plan_search, refuse_upfront  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
TARGET_S = 10.0
FIGURES = ("ring", "fig2_table2_left_up", "ring_3tasks")


def _ring(n: int, radius: float, r: float, c: tuple[float, float]) -> list[dict[str, Any]]:
    return [
        {"center": [c[0] + radius * math.cos(2 * math.pi * k / n), c[1] + radius * math.sin(2 * math.pi * k / n)],
         "radius": r}
        for k in range(n)
    ]  # fmt: skip


def _fig2() -> dict[str, Any]:
    return tomllib.loads((resources.files("tmr.mcdpr") / "scenes" / "fig2.toml").read_text())


def _moved(name: str, dx: float, dy: float) -> dict[str, Any]:
    d = _fig2()
    d["name"] = name
    c = d["tables"][1]["center"]
    d["tables"][1]["center"] = [c[0] + dx, c[1] + dy]
    t = d["tasks"][1]
    d["tasks"][1] = [t[0] + dx, t[1] + dy, t[2]]
    return d


def _across(travel_deg: int, n_tasks: int) -> dict[str, Any]:
    """Bases on the four axes of the first task point, 1.4 m out, all heading across the direction of travel;
    ``n_tasks`` task points 2 m apart along a line at 1 m height (turning the four bases together passes μ < 0, one
    at a time μ ≥ 0.319 N, then the formation drives with the platform at μ = 1.437 N)."""
    u = np.array([math.cos(math.radians(travel_deg)), math.sin(math.radians(travel_deg))])
    t0 = np.array([6.0, 6.0]) - u * (n_tasks - 1)
    return {
        "name": f"across_{travel_deg}deg_{n_tasks}tasks",
        "bounds": [0, 0, 12, 12],
        "tasks": [[*np.round(t0 + 2.0 * k * u, 9).tolist(), 1.0] for k in range(n_tasks)],
        "bases": [
            np.round(t0 + 1.4 * np.array([math.cos(a), math.sin(a)]), 9).tolist() for a in np.arange(4) * math.pi / 2
        ],
        "headings": [math.radians(travel_deg) + math.pi / 2] * 4,
    }


ACROSS = ((0, 2), (0, 3), (0, 4), (90, 3), (180, 4), (270, 2))


def scenes() -> list[tuple[str, dict[str, Any], float, str]]:
    """(name, scene mapping, platform mass [kg], expected verdict) of every benchmark scene."""
    open_room = {
        "name": "open",
        "bounds": [0, 0, 8, 6],
        "tasks": [[3, 3, 0.8], [5, 3.5, 0.8]],
        "bases": [[2, 2], [4, 2], [4, 4], [2, 4]],
    }
    ring = {
        "name": "ring",
        "bounds": [0, 0, 11, 8],
        "tasks": [[2.5, 4, 0.8], [6.5, 4, 0.8]],
        "bases": [[1.5, 3], [3.5, 3], [3.5, 5], [1.5, 5]],
        "obstacles": _ring(12, 1.5, 0.2, (6.5, 4.0)),
    }
    ring3 = {**ring, "name": "ring_3tasks", "tasks": [[2.0, 4, 0.8], [6.5, 4, 0.8], [9.5, 4, 0.8]]}
    ring3["bases"] = [[1.0, 3], [3.0, 3], [3.0, 5], [1.0, 5]]
    ring_below = {
        "name": "ring_from_below",
        "bounds": [0, 0, 10, 8],
        "tasks": [[5, 1.5, 0.8], [5, 4, 0.8]],
        "bases": [[4, 0.6], [6, 0.6], [6, 2.4], [4, 2.4]],
        "obstacles": _ring(12, 1.4, 0.2, (5.0, 4.0)),
    }
    round_trip = {  # pick and return: t0 → t1 → t0
        "name": "round_trip",
        "bounds": [0, 0, 10, 7],
        "tasks": [[3.0, 3.5, 0.8], [6.0, 3.5, 0.8], [3.0, 3.5, 0.8]],
        "bases": [[2, 2.5], [4, 2.5], [4, 4.5], [2, 4.5]],
    }
    round_trip2 = {**round_trip, "name": "round_trip_twice", "tasks": round_trip["tasks"] + round_trip["tasks"][1:]}
    corner = {**open_room, "name": "corner", "tasks": [[3, 3, 0.8], [0.3, 0.3, 0.8]]}
    wall = {
        "name": "wall",
        "bounds": [0, 0, 10, 6],
        "tasks": [[2.5, 3, 0.8], [7.5, 3, 0.8]],
        "bases": [[1.5, 2], [3.5, 2], [3.5, 4], [1.5, 4]],
        "tables": [{"center": [5, 3], "size": [0.2, 6.0]}],
    }
    far = {**open_room, "name": "far_start", "bases": [[0.3, 0.3], [7.7, 0.3], [7.7, 5.7], [0.3, 5.7]]}
    ang = np.deg2rad([225.0, 315.0, 45.0, 135.0])
    tip_bases = (np.array([4.0, 3.0]) + 2.5 * np.c_[np.cos(ang), np.sin(ang)]).tolist()
    tipping = {**open_room, "name": "tipping_start", "tasks": [[4, 3, 0.8], [4.5, 3, 0.8]], "bases": tip_bases}
    return [
        ("open", open_room, 0.5, "plan"),
        ("fig2", _fig2(), 0.5, "plan"),
        ("fig2_table2_up", _moved("fig2_table2_up", 0.0, 0.8), 0.5, "plan"),
        ("fig2_table2_left_up", _moved("fig2_table2_left_up", -1.0, 0.8), 0.5, "plan"),
        ("fig2_table2_right", _moved("fig2_table2_right", 1.0, 0.0), 0.5, "plan"),
        ("fig2_table2_far_left", _moved("fig2_table2_far_left", -1.5, -0.5), 0.5, "plan"),
        ("fig2_payload_0.8kg", {**_fig2(), "name": "fig2_payload_0.8kg"}, 0.8, "plan"),
        ("ring", ring, 0.5, "plan"),
        ("ring_3tasks", ring3, 0.5, "plan"),
        ("ring_from_below", ring_below, 0.5, "plan"),
        *((f"across_{a}deg_{n}tasks", _across(a, n), 0.5, "plan") for a, n in ACROSS),
        ("round_trip", round_trip, 0.5, "plan"),
        ("round_trip_twice", round_trip2, 0.5, "plan"),
        ("corner", corner, 0.5, "no-placement"),
        ("fig2_table2_at_wall", _moved("fig2_table2_at_wall", 0.0, 1.2), 0.5, "no-placement"),
        ("wall", wall, 0.5, "not-connectable"),
        ("payload_8kg", {**_fig2(), "name": "payload_8kg"}, 8.0, "refused:tension"),
        ("far_start", far, 0.5, "refused:tension"),
        ("tipping_start", tipping, 0.5, "refused:tipping"),
    ]


def path_length(bases: np.ndarray) -> float:
    """Sum over the bases of their travelled distance [m]."""
    return float(np.sum(np.linalg.norm(np.diff(bases, axis=0), axis=-1)))


def run_search(robot: Robot, scene: Scene) -> tuple[str, Any]:
    try:
        res = plan_search(robot, scene)
    except TaskRefused as exc:
        return f"refused:{exc.constraint}", exc
    except NoPlanFound as exc:
        return exc.kind, exc
    chk = check(robot, scene.validate(robot), res)
    return ("plan" if chk.ok else "check failed"), (res, chk)


def run_greedy(robot: Robot, scene: Scene) -> tuple[str, Any]:
    env = scene.validate(robot)
    try:
        refuse_upfront(robot, scene, required_wrench_set(robot, scene.external))
    except TaskRefused as exc:
        return f"refused:{exc.constraint}", exc
    res = plan(robot, scene, None, env)
    chk = check(robot, env, res)
    return ("plan" if chk.ok else "μ ≤ 0" if chk.nonpositive else "check failed"), (res, chk)


def timed(fn, repeats: int) -> tuple[float, float, Any]:
    """Median wall time [s], median CPU time of this process [s] (less sensitive to other jobs), last result."""
    times, cpus, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return statistics.median(times), statistics.median(cpus), out


def _f(v: float, nd: int = 3) -> str:
    return "" if v is None or not np.isfinite(v) else f"{v:.{nd}f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs of the search planner per scene (median)")
    ap.add_argument("--greedy-repeats", type=int, default=1, help="runs of the greedy planner per scene (median)")
    ap.add_argument("--only", nargs="*", help="scene names to run (default all)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    base = mopick()
    rows: list[dict[str, Any]] = []
    for name, data, mass, expected in scenes():
        if args.only and name not in args.only:
            continue
        robot = base.replace(platform_mass=mass)
        scene = scene_from_dict(data, name)
        ts, cs, (sv, sout) = timed(lambda robot=robot, scene=scene: run_search(robot, scene), args.repeats)
        tg, cg, (gv, gout) = timed(lambda robot=robot, scene=scene: run_greedy(robot, scene), args.greedy_repeats)
        row: dict[str, Any] = {
            "scene": name,
            "platform_kg": mass,
            "expected": expected,
            "search": sv,
            "search_correct": sv == expected,
            "search_s": ts,
            "search_cpu_s": cs,
            "greedy": gv,
            "greedy_correct": gv == expected,
            "greedy_s": tg,
            "greedy_cpu_s": cg,
        }
        if isinstance(sout, tuple):
            res, chk = sout
            row.update(
                search_samples=len(res.mu),
                search_path_m=path_length(res.bases),
                search_mu_min=chk.mu_min,
                search_mu_between=chk.mu_between,
                search_headings=res.search.get("placement_headings", ""),
            )
            if name in FIGURES:
                from tmr.mcdpr import plot

                env = scene.validate(robot)
                plot.plot_topview(robot, scene, env, res, args.out / f"mcdpr_planner_{name}_topview.png")
                plot.plot_mu(res, args.out / f"mcdpr_planner_{name}_mu.png")
        else:
            row["search_reason"] = str(sout)
        if isinstance(gout, tuple):
            res, chk = gout
            row.update(greedy_samples=len(res.mu), greedy_path_m=path_length(res.bases), greedy_mu_min=chk.mu_min)
            if name in FIGURES:
                from tmr.mcdpr import plot

                env = scene.validate(robot)
                plot.plot_topview(robot, scene, env, res, args.out / f"mcdpr_planner_{name}_greedy_topview.png")
        rows.append(row)
        print(
            f"{name:24s} expected {expected:18s} search {sv:18s} {ts:6.2f} s ({cs:5.2f} CPU)   greedy {gv:16s} "
            f"{tg:6.2f} s",
            flush=True,
        )
    write(rows, args)
    return 0


COLUMNS = [
    "scene",
    "platform_kg",
    "expected",
    "search",
    "search_correct",
    "search_s",
    "search_cpu_s",
    "search_samples",
    "search_path_m",
    "search_mu_min",
    "search_mu_between",
    "search_headings",
    "greedy",
    "greedy_correct",
    "greedy_s",
    "greedy_cpu_s",
    "greedy_samples",
    "greedy_path_m",
    "greedy_mu_min",
    "search_reason",
]


def write(rows: list[dict[str, Any]], args: argparse.Namespace) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, COLUMNS, lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    atomic_write_text(args.out / "mcdpr_planner.csv", buf.getvalue())
    solved = [r for r in rows if r["expected"] == "plan"]
    refused = [r for r in rows if r["expected"] != "plan"]
    lines = [
        "# MoPICK planners on generated scenes: search vs greedy",
        "",
        f"Generated by `python benchmarks/mcdpr_planner.py --repeats {args.repeats} --greedy-repeats "
        f"{args.greedy_repeats}` on {datetime.date.today().isoformat()}, {platform.machine()} × {os.cpu_count()} "
        f"cores, Python {platform.python_version()}; times are medians [s] (search: {args.repeats} runs, greedy: "
        f"{args.greedy_repeats}). The machine was shared with other jobs: times vary run to run.",
        "",
        f"- search: {sum(r['search_correct'] for r in solved)}/{len(solved)} feasible scenes planned, "
        f"{sum(r['search_correct'] for r in refused)}/{len(refused)} infeasible ones refused with the expected reason; "
        f"slowest {max(r['search_s'] for r in rows):.2f} s wall, {max(r['search_cpu_s'] for r in rows):.2f} s CPU "
        f"(target {TARGET_S:g} s); load average at the end {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores",
        f"- greedy: {sum(r['greedy_correct'] for r in solved)}/{len(solved)} feasible scenes planned with every check "
        f"passing, {sum(r['greedy_correct'] for r in refused)}/{len(refused)} infeasible ones with the expected "
        "verdict (it has no verdicts of its own beyond the shared up-front refusal)",
        "",
        "Verdicts: `plan` (exit 0), `refused:<limit>` (exit 2, before any search), `no-placement` / `not-connectable`"
        " (search, exit 1), `μ ≤ 0` (greedy: plan computed, μ ≤ 0 at some samples, exit 1). Path = sum of the four "
        "base path lengths; μ_min at the samples; μ_between = the guaranteed lower bound between samples "
        "(`tmr.mcdpr.certify`). Placement headings: `every` = placements robust to any heading, `best` = the "
        "fallback with each base at its best heading. See [formulations/mcdpr_planner.md]"
        "(../../formulations/mcdpr_planner.md).",
        "",
        "| scene | kg | expected | search | s (CPU s) | samples | path [m] | μ_min [N] | μ_between [N] | headings | "
        "greedy | s | path [m] | μ_min [N] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ok_s = "✓" if r["search_correct"] else "✗"
        ok_g = "✓" if r["greedy_correct"] else "✗"
        lines.append(
            f"| {r['scene']} | {r['platform_kg']:g} | {r['expected']} | {ok_s} {r['search']} | {r['search_s']:.2f} "
            f"({r['search_cpu_s']:.2f}) | "
            f"{r.get('search_samples', '')} | {_f(r.get('search_path_m'), 1)} | {_f(r.get('search_mu_min'))} | "
            f"{_f(r.get('search_mu_between'))} | {r.get('search_headings', '')} | {ok_g} {r['greedy']} | "
            f"{r['greedy_s']:.2f} | {_f(r.get('greedy_path_m'), 1)} | {_f(r.get('greedy_mu_min'))} |"
        )
    lines += ["", "Reasons given by the search planner for the scenes it refuses:", ""]
    for r in rows:
        if "search_reason" in r:
            lines.append(f"- **{r['scene']}**: {r['search_reason']}")
    figs = [f for f in FIGURES if any(r["scene"] == f for r in rows)]
    if figs:
        lines += ["", "Figures (search top view, μ with its guaranteed bound, greedy top view):", ""]
        for f in figs:
            lines.append(
                f"- {f}: [top view](mcdpr_planner_{f}_topview.png), [μ](mcdpr_planner_{f}_mu.png), "
                f"[greedy top view](mcdpr_planner_{f}_greedy_topview.png)"
            )
    atomic_write_text(args.out / "mcdpr_planner.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
