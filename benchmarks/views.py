"""Views and exports of a plan: time and size of the GIF, the HTML view and the ROS 2 bag.

    python benchmarks/views.py [--scenarios A E] [--repeats 3]

A benchmark, not a test. For each built-in chain scenario it plans with ``qp`` (the default route), builds the
:class:`tmr.views.motion.Motion` once, then writes ``--repeats`` times (interleaved) the animation
(:func:`tmr.views.animate.write_gif`), the interactive view (:func:`tmr.views.htmlview.write_html`) and the bag in MCAP
and SQLite 3
storage (:func:`tmr.export.rosbag.write_bag`), and reports the median wall time, the file size, the frames, and the
bag's message count. Also writes the scenario A animation shown at the top of the README,
``benchmarks/results/A_qp_motion.gif`` (the same bytes as ``python -m tmr.plan --scenario A --gif``).

Writes ``benchmarks/results/views.md`` and ``views.csv``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from provenance import source_version, versions

PACKAGES = ("matplotlib", "pillow", "plotly", "rosbags")
RESULTS = Path(__file__).resolve().parent / "results"


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*")) if path.is_dir() else path.stat().st_size


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["A", "E"])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    from rosbags.rosbag2 import Reader

    from tmr.export.rosbag import write_bag
    from tmr.planner import build_problem, solve
    from tmr.views.animate import frame_indices, write_gif
    from tmr.views.htmlview import write_html
    from tmr.views.motion import chain_motion
    from tmr.world.scenario import load_scenario

    measured = source_version()  # before measuring: the code the timings belong to
    rows = []
    work = Path(tempfile.mkdtemp(prefix="tmr-views-"))
    try:
        for name in args.scenarios:
            sc = load_scenario(name)
            problem = build_problem(sc, n_robots=None if name != "E" else 6)
            plan, _ = solve(problem, "qp")
            motion = chain_motion(plan, problem.env, problem.chain_params)
            writers = {
                "gif": lambda m, p: write_gif(m, p / "motion.gif"),
                "html": lambda m, p: write_html(m, p / "motion.html"),
                "mcap": lambda m, p: write_bag(m, p / "bag_mcap", storage="mcap"),
                "sqlite3": lambda m, p: write_bag(m, p / "bag_sqlite3", storage="sqlite3"),
            }
            times: dict[str, list[float]] = {k: [] for k in writers}
            cpu: dict[str, list[float]] = {k: [] for k in writers}
            out: dict[str, Path] = {}
            for _ in range(args.repeats):
                for kind, fn in writers.items():
                    d = work / name / kind
                    shutil.rmtree(d, ignore_errors=True)
                    d.mkdir(parents=True)
                    t0, c0 = time.perf_counter(), time.process_time()
                    out[kind] = fn(motion, d)
                    times[kind].append(time.perf_counter() - t0)
                    cpu[kind].append(time.process_time() - c0)
            if name == "A":
                shutil.copyfile(out["gif"], RESULTS / "A_qp_motion.gif")
            for kind, path in out.items():
                detail = ""
                if kind == "gif":
                    detail = f"{len(frame_indices(motion))} frames at 10 fps"
                elif kind == "html":
                    detail = f"{len(frame_indices(motion, max_frames=200))} frames, plotly.js embedded"
                else:
                    with Reader(path) as r:
                        detail = f"{r.message_count} messages, {len(r.topics)} topics"
                rows.append(
                    {
                        "scenario": name,
                        "robots": plan.robots.shape[1],
                        "samples": motion.n_samples,
                        "plan_s": round(float(plan.t[-1]), 2),
                        "output": kind,
                        "median_s": round(statistics.median(times[kind]), 3),
                        "median_cpu_s": round(statistics.median(cpu[kind]), 3),
                        "size_MB": round(_size(path) / 1e6, 2),
                        "detail": detail,
                    }
                )
                print(rows[-1], file=sys.stderr)
    finally:
        shutil.rmtree(work, ignore_errors=True)

    RESULTS.mkdir(exist_ok=True)
    with open(RESULTS / "views.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    head = ["scenario", "robots", "samples", "plan [s]", "output", "median write [s]", "median CPU [s]", "size [MB]"]
    head.append("detail")
    lines = [
        "# Views and exports of a plan",
        "",
        f"`python benchmarks/views.py --scenarios {' '.join(args.scenarios)} --repeats {args.repeats}`; "
        f"{datetime.date.today().isoformat()}, {platform.machine()} ({platform.python_version()}), "
        f"{versions(PACKAGES)}, {measured}, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores. "
        f"Median of {args.repeats} interleaved repeats of wall time and of the process's CPU time (less sensitive to "
        "other load); the plan and the motion are built once and not timed.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for r in rows:
        lines.append("| " + " | ".join(str(v) for v in r.values()) + " |")
    (RESULTS / "views.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
