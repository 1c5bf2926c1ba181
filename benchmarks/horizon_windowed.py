"""Windowed solves along the route (+ one polishing pass of the full NLP) against the monolithic horizon NLP.

    python benchmarks/horizon_windowed.py CASE [--window W] [--overlap O] [--mode fixed|sub] [--time-limit S]

CASE: ``E6`` (scenario E, 6 robots) or ``ROOMSEED:DENSITY:GOAL:N`` (a generated room, :func:`tmr.sweep.rooms.
generate_room`, N robots), both built as the command line builds them (shortest route, seed 0). The problem and its
``qp`` warm start are cached in /tmp/hw (pickled) so that only ``plan_horizon`` is timed. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from horizon_cases import build  # noqa: E402

CACHE = Path("/tmp/hw")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("case")
    ap.add_argument("--window", type=int, default=None)
    ap.add_argument("--overlap", type=int, default=None)
    ap.add_argument("--mode", default=None)
    ap.add_argument("--time-limit", type=float, default=None)
    a = ap.parse_args()
    CACHE.mkdir(exist_ok=True)
    f = CACHE / (a.case.replace(":", "_") + ".pkl")
    if not f.is_file():
        f.write_bytes(pickle.dumps(build(a.case)))
    problem, warm = pickle.loads(f.read_bytes())
    import logging

    from tmr.control.horizon import plan_horizon

    logging.basicConfig(level=logging.DEBUG if os.environ.get("HW_DEBUG") else logging.WARNING, format="%(message)s")

    opts = {}
    if a.window:
        opts["window"] = a.window
        if a.overlap is not None:
            opts["window_overlap"] = a.overlap
        if a.mode:
            opts["window_mode"] = a.mode
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    plan = plan_horizon(problem, warm, time_limit=a.time_limit, **opts)
    wall = time.perf_counter() - t0
    d = plan.diagnostics
    out = dict(
        case=a.case,
        window=a.window,
        overlap=a.overlap,
        mode=a.mode,
        knots=int(plan.q.shape[0]),
        wall=round(wall, 2),
        load=round(load, 2),
        result=d["horizon_result"],
        stop=d["horizon_stop"],
        iterations=d["ipopt_iterations"],
        rounds=[
            (
                r["round"],
                r["attempt"],
                r["iterations"],
                r["rows"],
                round(r["solve_time"], 2),
                round(r["transcription_time"], 2),
            )
            for r in d["round_log"]
        ],
        windows=d.get("window_log"),
        objective=d["horizon_summary"]["objective"],
        f=[round(d[k], 6) for k in ("f1", "f2", "f3", "f4")],
        t_wall=[r["t_wall"] for r in d["round_log"]],
        warm_time=round(d["warm_start_time"], 2),
        trans=round(d["transcription_time"], 2),
        solve=round(d["solve_time"], 2),
    )
    if os.environ.get("HW_SAVE"):
        import numpy as np

        np.save(os.environ["HW_SAVE"], plan.q)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
