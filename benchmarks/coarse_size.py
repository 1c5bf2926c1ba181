"""The coarse pass for shorter horizons of many robots (``HorizonOptions.coarse_from_size``, since stop 73): until
stop 73 a horizon got the coarse pass (``formulations/horizon.md``, "Coarse knots") only from ``coarse_from`` = 500
knots. The whole NLP's size is its knots × robots, so a horizon of 400 knots and 8 robots is as large as one of 640
knots and 5 robots, which got the pass. This measures, on every run of a rooms table whose horizon
is shorter than 500 knots, the plan without the coarse pass and with it, to choose the size from which it pays.

    python benchmarks/coarse_size.py [--table horizon_rooms_216_ee5f076] [--knots 200 500] [--jobs 2]
                                     [--sizes 2000 3000 4000] [--out coarse_size]

Each run of ``benchmarks/results/TABLE.csv`` (a generated room, of any seed's set, and a robot count) with ``--knots``
LO ≤ knots < HI is planned with ``tmr plan --method horizon --time-limit 60`` (as ``benchmarks/horizon.py`` runs the
table) twice, a new process each, one BLAS thread, the order alternating from one run to the next: *fine*, no coarse
pass below 500 knots (the rule before stop 73), and *coarse*, the coarse pass from LO knots (M = ⌈K / 100⌉ as on any
long horizon). ``--jobs`` runs at a time, as the table's runner. Per bucket of knots × robots: the runs, the
whole-process time summed and the median of coarse / fine, the plans' f1 + f2 + f4 (Caruso 2021 eq. 24, 25, 27; the
checker's, ``metrics.json``) coarse / fine (geometric mean, least, greatest), and the runs optimal and under 10 s either
way. Then each size of ``--sizes`` as the rule (the coarse pass where knots × robots reach it): the same sums, counts
and cost ratios for the runs it changes. The two plans of a run are deterministic: only the times depend on the load.

Writes ``benchmarks/results/OUT.md`` and ``OUT.csv``.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402
from segment_margin import cold_timings, plan_args  # noqa: E402

from tmr.sweep.rooms import room_from_spec, room_spec  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
OPTIMAL = ("optimal", "coarse_optimal")
LABELS = ("fine", "coarse")

#: A child process: ``tmr plan`` with the coarse pass only from 500 knots (argv[1] "fine") or from argv[2] knots
#: ("coarse"), whatever the robots.
CHILD = """
import sys
import tmr.control.horizon as horizon
rule = horizon.stride
if sys.argv[1] == "fine":
    horizon.stride = lambda K, knots, start, **size: rule(K, knots, start)
else:
    low = int(sys.argv.pop(2))
    horizon.stride = lambda K, knots, start, **size: rule(K, knots, min(start, low))
from tmr.plan import main
sys.exit(main(sys.argv[2:]))
"""


def _args(run: str, where: Path) -> list[str]:
    """``tmr plan --method horizon --time-limit 60`` arguments for ``run`` ("ROOM:N", a generated room of any seed:
    :func:`tmr.sweep.rooms.room_spec`), its map written into ``where``; up to ``--out``."""
    name, robots = run.rsplit(":", 1)
    room = room_from_spec(room_spec(name))
    if isinstance(room, str):
        sys.exit(f"{name}: {room}")
    return [*plan_args(room, robots, where, "horizon"), "--time-limit", "60"]


def _plan(run: str, label: str, low: int) -> dict[str, Any]:
    """One cold ``tmr plan --method horizon --time-limit 60`` of ``run`` with the ``label`` rule: result, IPOPT
    iterations, the coarse pass's result, f1 + f2 + f4 of the plan; the whole process (interpreter start to exit,
    as the table's ``wall_time``), the plan's own ``wall_time`` (``plan_time``) and its NLP's [s]."""
    with tempfile.TemporaryDirectory() as d:
        args = _args(run, Path(d))
        extra = [str(low)] if label == "coarse" else []
        t0 = time.perf_counter()
        t = cold_timings(CHILD, label, [*extra, *args], Path(d) / "out", (0, 1))
        process = time.perf_counter() - t0
        m = json.loads((Path(d) / "out" / "metrics.json").read_text())
    h = m.get("horizon") or {}
    cost = sum(float(m[f]) for f in ("f1", "f2", "f4")) if m.get("success") else math.nan
    return {
        "result": h.get("result"),
        "iterations": h.get("iterations"),
        "coarse": (h.get("coarse") or {}).get("result", ""),
        "cost": cost,
        "wall_time": process,
        "plan_time": float(t["wall_time"]),
        "nlp_time": float(t.get("nlp_time", math.nan)),
    }


def _good(row: dict[str, Any], label: str) -> bool:
    return row[f"{label}_result"] in OPTIMAL and float(row[f"{label}_wall_time"]) < 10


def _summary(rows: list[dict[str, Any]]) -> str:
    """runs | time fine → coarse (sums) | median ratio | cost coarse / fine: geometric mean, least, greatest (over the
    runs with a plan both ways; the others counted apart) | optimal and < 10 s, fine → coarse."""
    if not rows:
        return "0 | – | – | – | – |"
    tf = [float(r["fine_wall_time"]) for r in rows]
    tc = [float(r["coarse_wall_time"]) for r in rows]
    cr = [float(r["coarse_cost"]) / float(r["fine_cost"]) for r in rows]
    cr = [c for c in cr if math.isfinite(c) and c > 0]
    cost = "–"
    if cr:
        cost = f"{math.exp(statistics.fmean(math.log(c) for c in cr)):.3f} ({min(cr):.3f}–{max(cr):.3f})"
    if len(cr) < len(rows):
        cost += f"; {len(rows) - len(cr)} without a plan one way"
    good = sum(_good(r, "fine") for r in rows), sum(_good(r, "coarse") for r in rows)
    median = statistics.median(c / f for c, f in zip(tc, tf, strict=True))
    return f"{len(rows)} | {sum(tf):.1f} → {sum(tc):.1f} | {median:.2f} | {cost} | {good[0]} → {good[1]} |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--table", default="horizon_rooms_216_ee5f076", help="stem of the rooms table in results/")
    ap.add_argument("--knots", type=int, nargs=2, default=(200, 500), metavar=("LO", "HI"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--sizes", type=int, nargs="+", default=(2000, 3000, 4000))
    ap.add_argument("--out", default="coarse_size")
    args = ap.parse_args()
    lo, hi = args.knots
    with open(RESULTS / f"{args.table}.csv", newline="") as f:
        table = [r for r in csv.DictReader(f) if r["horizon_result"] and lo <= int(r["knots"]) < hi]
    table.sort(key=lambda r: -float(r["wall_time"]))  # the slowest first: the lanes end together
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    t0 = time.perf_counter()

    def measure(i: int) -> dict[str, Any]:
        r = table[i]
        run = f"{r['room']}:{r['robots']}"
        done = {k: _plan(run, k, lo) for k in (LABELS if i % 2 == 0 else LABELS[::-1])}
        n = int(r["n_robots"])
        row: dict[str, Any] = {"room": r["room"], "robots": r["robots"], "n_robots": n, "knots": int(r["knots"])}
        row["size"] = n * row["knots"]
        for k in LABELS:
            row.update({f"{k}_{key}": v for key, v in done[k].items()})
        print(
            f"{run:40s} {row['size']:5d} | {row['fine_result']} {row['fine_wall_time']:.1f} s {row['fine_cost']:.1f} | "
            f"{row['coarse_result']} {row['coarse_wall_time']:.1f} s {row['coarse_cost']:.1f}",
            flush=True,
        )
        return row

    with ThreadPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(measure, range(len(table))))
    took = time.perf_counter() - t0
    with open(RESULTS / f"{args.out}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, list(rows[0]))
        w.writeheader()
        w.writerows(rows)

    edges = [0, 1500, 2000, 2500, 3000, 4000, 10**9]
    lines = [
        "# The coarse pass for shorter horizons of many robots: from which size it pays",
        "",
        f"`python benchmarks/coarse_size.py --table {args.table} --knots {lo} {hi} --jobs {args.jobs} --sizes "
        f"{' '.join(map(str, args.sizes))} --out {args.out}` — {started}, {took / 60:.0f} min; {source_version()}; "
        f"{versions(['casadi', 'numpy'])}; {platform.machine()}, {os.cpu_count()} cores.",
        "",
        f"The {len(rows)} runs of [`{args.table}`]({args.table}.md) whose horizon has {lo} to {hi - 1} knots, each "
        "planned by `tmr plan --method horizon --time-limit 60` without the coarse pass (*fine*: the rule before stop "
        f"73, the pass from 500 knots) and with it (*coarse*: the pass from {lo} knots), a new process each, "
        f"alternating, {args.jobs} runs at a time. *Time*: the whole process [s], summed; *median*: the runs' "
        "coarse / fine; *cost*: f1 + f2 + f4 of the plan (the checker's), coarse / fine, geometric mean (least–"
        "greatest); *optimal < 10 s*: the runs whose plan is optimal (or the coarse optimum) and took under 10 s.",
        "",
        "## By size (knots × robots)",
        "",
        "| knots × robots | runs | time [s], fine → coarse | median | cost, coarse / fine | optimal < 10 s |",
        "|---|---|---|---|---|---|",
    ]
    for a, b in itertools.pairwise(edges):
        part = [r for r in rows if a <= r["size"] < b]
        label = f"{a:,}–{b - 1:,}" if b < 10**9 else f"≥ {a:,}"
        lines.append(f"| {label} | {_summary(part)}")
    lines += [
        "",
        "## Each size as the rule",
        "",
        "The runs it changes (knots × robots ≥ the size, fewer than 500 knots), their plans without and with the pass; "
        f"the other runs keep the fine plan. Over all {len(rows)} runs, optimal and under 10 s: "
        f"{sum(_good(r, 'fine') for r in rows)} fine, {sum(_good(r, 'coarse') for r in rows)} with the pass on every "
        "one.",
        "",
        "| size | runs changed | time [s], fine → coarse | median | cost, coarse / fine | optimal < 10 s |",
        "|---|---|---|---|---|---|",
    ]
    for s in args.sizes:
        lines.append(f"| {s:,} | {_summary([r for r in rows if r['size'] >= s])}")
    lines += [
        "",
        "## Runs whose verdict or cost moved",
        "",
        "Optimal and under 10 s one way only, or f1 + f2 + f4 more than 5 % apart.",
        "",
        "| room | N | knots × robots | fine: result, time [s], cost | coarse: result, time [s], cost, coarse pass |",
        "|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: r["size"]):
        ratio = float(r["coarse_cost"]) / float(r["fine_cost"])
        if _good(r, "fine") != _good(r, "coarse") or not abs(ratio - 1) <= 0.05:  # NaN (no plan one way) listed
            lines.append(
                f"| `{r['room']}` | {r['robots']} | {r['size']:,} | {r['fine_result']}, {r['fine_wall_time']:.1f}, "
                f"{r['fine_cost']:.1f} | {r['coarse_result']}, {r['coarse_wall_time']:.1f}, {r['coarse_cost']:.1f}, "
                f"{r['coarse_coarse'] or '–'} |"
            )
    (RESULTS / f"{args.out}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
