"""Freed memory kept in the heap (:mod:`tmr.io.heap`) against glibc's defaults, on rooms of the rooms benchmark.

    python benchmarks/heap.py [--runs ROOM:N ...] [--repeats 3] [--out heap]

Each run is the rooms benchmark's own (``tmr.sweep.room_runs.run_room``: the whole ``python -m tmr.plan … --method
horizon --time-limit 60`` process, ``OMP_NUM_THREADS=1``), once with ``TMR_KEEP_FREED_MEMORY=0`` (glibc's defaults)
and once without it (freed memory kept), alternating, one process at a time, ``--repeats`` times. Writes
``benchmarks/results/<out>.csv`` (one row a process) and ``<out>.md``: per run the median wall and NLP times of each
variant and their ratio, whether every process took the same IPOPT iterations and result, and the median ratio.
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402

from tmr.io.heap import OPT_OUT  # noqa: E402
from tmr.sweep.room_runs import RoomRun, run_room  # noqa: E402
from tmr.sweep.rooms import room_from_spec, room_set  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: Runs of the 216-room table over 10 s (long horizons, 5 and 8 robots) and two of a few seconds.
RUNS = [
    "walls-far-3968734336:5",
    "narrow-mid-3934587917:3",
    "long_walls-corner-1536391021:8",
    "dense-far-1205791620:8",
    "dense-far-2639215061:8",
    "long_walls-far-2942714861:auto",
]
FIELDS = ["room", "robots", "repeat", "variant", "exit_code", "horizon_result", "horizon_iterations", "wall_time",
          "nlp_time", "knots"]  # fmt: skip
VARIANTS = (("glibc defaults", "0"), ("freed memory kept", "1"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", nargs="+", default=RUNS, help="ROOM:N (a room of the 216-room set, N robots or auto)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="heap")
    args = ap.parse_args()
    specs = {s[0]: s for s in room_set(216)}
    rows: list[dict[str, object]] = []
    t0 = time.perf_counter()
    for run in args.runs:
        name, robots = run.rsplit(":", 1)
        room = room_from_spec(specs[int(name.rsplit("-", 1)[1])])
        for rep in range(args.repeats):
            for variant, value in VARIANTS:
                os.environ[OPT_OUT] = value  # run_room hands this process's environment to its child
                r = run_room(RoomRun(room, "horizon", robots, 0, 300.0, None, ("--time-limit", "60")))
                rows.append({"repeat": rep, "variant": variant, **{k: r.get(k) for k in FIELDS if k in r}})
                print(name, robots, rep, variant, r.get("horizon_result"), r.get("horizon_iterations"),
                      round(float(r["wall_time"]), 2), flush=True)  # fmt: skip
    os.environ.pop(OPT_OUT, None)
    total = time.perf_counter() - t0
    with open(RESULTS / f"{args.out}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    (RESULTS / f"{args.out}.md").write_text(_table(rows, args, total))


def _runs_arg(runs: list[str]) -> str:
    return "" if runs == RUNS else " --runs " + " ".join(runs)


def _table(rows: list[dict[str, object]], args: argparse.Namespace, total: float) -> str:
    base, kept = (v for v, _ in VARIANTS)
    out = [
        "# Freed memory kept in the heap (`tmr.io.heap`) against glibc's defaults",
        "",
        f"`python benchmarks/heap.py{_runs_arg(args.runs)} --repeats {args.repeats}` — "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())},"
        f" {total:.0f} s in all; {source_version()}; {versions(['casadi', 'numpy'])}; {platform.machine()}, "
        f"{os.cpu_count()} cores, one process at a time.",
        "",
        "Each row: the whole `python -m tmr.plan … --method horizon --time-limit 60` process (the rooms benchmark's "
        "`run_room`), medians of the repeats; `same` = every process of the run took the same IPOPT iterations and "
        "result.",
        "",
        "| run | knots | result | iterations | same | wall (defaults) [s] | wall (kept) [s] | ratio | NLP (defaults) "
        "[s] | NLP (kept) [s] | ratio |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    ratios: list[float] = []
    for run in dict.fromkeys((str(r["room"]), str(r["robots"])) for r in rows):
        mine = [r for r in rows if (str(r["room"]), str(r["robots"])) == run]
        same = len({(r["horizon_result"], r["horizon_iterations"]) for r in mine}) == 1

        def med(variant: str, key: str, mine: list[dict[str, object]] = mine) -> float:
            return statistics.median(float(r[key]) for r in mine if r["variant"] == variant)  # type: ignore[arg-type]

        wb, wk, nb, nk = med(base, "wall_time"), med(kept, "wall_time"), med(base, "nlp_time"), med(kept, "nlp_time")
        ratios.append(wk / wb)
        out.append(
            f"| `{run[0]}` with {run[1]} | {mine[0]['knots']} | {mine[0]['horizon_result']} | "
            f"{mine[0]['horizon_iterations']} | {'yes' if same else 'no'} | {wb:.2f} | {wk:.2f} | {wk / wb:.3f} | "
            f"{nb:.2f} | {nk:.2f} | {nk / nb:.3f} |"
        )
    out += ["", f"Median wall-time ratio (kept / defaults) over the {len(ratios)} runs: "
            f"**{statistics.median(ratios):.3f}** (range {min(ratios):.3f}–{max(ratios):.3f}).", ""]  # fmt: skip
    return "\n".join(out)


if __name__ == "__main__":
    main()
