"""The train search's segment pre-filter (``tmr.route.train._Fast.segment_is_free``) against the ``covers`` test it
replaced, on the very calls a train search makes.

    python benchmarks/train_filter.py [--run dense-corner-4091284932:8] [--repeats 3]

The run (a room of the 216-room set and a robot count; the default one ends with exit 1, its leader short of the
goal, after the search measured here) is planned once in this process with ``--method qp``
(``tmr.plan.main``, as the CLI: its train references are searched where the trailing ones fail), every call of the
pre-filter at the train's clearance recorded (its segments and clearance). The calls are then replayed, in their
order, through both pre-filters, alternating, ``--repeats`` times. Both hand the segments they cannot decide to the
same exact test (``Environment.segment_is_free``), so both give the exact answer; the table checks that they agree on
every segment of every call.

* ``covers`` (stop 61 and before): a segment covered by the free region eroded by c + 2 mm is free, one not covered
  by it eroded by c − 2 mm is not (GEOS ``covers`` on the prepared polygons);
* ``boundary`` (stop 62): a segment whose start is inside a region lies in it iff it does not meet the region's
  prepared boundary (GEOS ``intersects``), the test ``Environment.segment_is_free`` makes.

Writes ``benchmarks/results/train_filter.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import shapely

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402

import tmr.route.train as train  # noqa: E402
from tmr.sweep.room_runs import xy_arg  # noqa: E402
from tmr.sweep.rooms import room_from_spec, room_set, write_geojson  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: A run whose qp plan searches train references for long (its ``--robots auto`` run: 55 s of 66 s at stop 59).
RUN = "dense-corner-4091284932:8"


def _covers(fast: train._Fast, A: np.ndarray, B: np.ndarray, margin: float) -> np.ndarray:
    """The pre-filter as it was before stop 62: ``covers`` on the prepared eroded polygons."""
    out = np.zeros(len(A), dtype=bool)
    ends = shapely.contains_xy(fast.outer, A[:, 0], A[:, 1]) & shapely.contains_xy(fast.outer, B[:, 0], B[:, 1])
    idx = np.flatnonzero(ends)
    lines = shapely.linestrings(np.stack([A[idx], B[idx]], axis=1))
    inside = shapely.covers(fast.inner, lines)
    out[idx[inside]] = True
    unsure = idx[~inside][shapely.covers(fast.outer, lines[~inside])]
    if len(unsure):
        out[unsure] = fast.env.segment_is_free(A[unsure], B[unsure], margin)
    return out


def _record(run: str) -> tuple[list[tuple[Any, np.ndarray, np.ndarray, float]], int]:
    """Every call of the pre-filter at the train's clearance while ``tmr plan --method qp`` plans ``run``: (the
    pre-filter object, starts, ends, clearance); and the command's exit code."""
    name, robots = run.rsplit(":", 1)
    spec = {s[0]: s for s in room_set(216)}.get(int(name.rsplit("-", 1)[1]))
    room = room_from_spec(spec) if spec is not None else None
    if room is None or isinstance(room, str) or room.name != name:
        sys.exit(f"{name}: not a room of the 216-room set")
    calls: list[tuple[Any, np.ndarray, np.ndarray, float]] = []
    original = train._Fast.segment_is_free

    def spy(self: train._Fast, a: Any, b: Any, margin: float = 0.0) -> Any:
        if abs(float(margin) - self.c) <= 1e-6:
            A, B = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
            calls.append((self, A.reshape(-1, 2).copy(), B.reshape(-1, 2).copy(), float(margin)))
        return original(self, a, b, margin)

    from tmr.plan import main

    train._Fast.segment_is_free = spy  # type: ignore[method-assign]
    try:
        with tempfile.TemporaryDirectory() as d:
            write_geojson(room, Path(d) / "room.geojson")
            code = main([
                "--map", str(Path(d) / "room.geojson"), f"--base={xy_arg(room.base)}", f"--goal={xy_arg(room.goal)}",
                "--robots", robots, "--method", "qp", "--no-plots", "--out", str(Path(d) / "out"), "--seed", "0",
                "--quiet",
            ])  # fmt: skip
    finally:
        train._Fast.segment_is_free = original  # type: ignore[method-assign]
    return calls, code


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default=RUN, help="ROOM:N, a room of the 216-room set and a robot count")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    calls, code = _record(args.run)
    if not calls:
        sys.exit(f"{args.run}: its qp plan searched no train references (exit {code})")
    agree = all(np.array_equal(_covers(f, A, B, m), train._Fast.segment_is_free(f, A, B, m)) for f, A, B, m in calls)
    times: dict[str, list[float]] = {"covers": [], "boundary": []}
    for _ in range(args.repeats):
        for label, test in (("covers", _covers), ("boundary", train._Fast.segment_is_free)):
            t0 = time.perf_counter()
            for f, A, B, m in calls:
                test(f, A, B, m)
            times[label].append(time.perf_counter() - t0)
    tc, tb = (statistics.median(times[k]) for k in ("covers", "boundary"))
    segments = sum(len(A) for _, A, _, _ in calls)
    vertices = max(int(shapely.get_num_coordinates(f.inner)) for f, *_ in calls)
    text = "\n".join([
        "# The train search's segment pre-filter: prepared boundaries (`intersects`) against `covers`",
        "",
        f"`python benchmarks/train_filter.py --run {args.run} --repeats {args.repeats}` — "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {source_version()}; "
        f"{versions(['shapely', 'numpy'])}; {platform.machine()}, {os.cpu_count()} cores.",
        "",
        f"`tmr plan --method qp` on `{args.run.replace(':', '` with ')} robots (exit {code}) called the pre-filter "
        f"{len(calls):,} times at the train's clearance ({calls[0][3]:g} m), on {segments:,} segments; the eroded "
        f"free region has {vertices:,} vertices. Every call replayed in order through each pre-filter, alternating; "
        f"medians of {args.repeats} repeats (the pre-filters built once, not timed; the new one's calls include its "
        "margin test and reshaping, which the old code's replay here skips). Both give the same answer on every "
        "segment: "
        f"**{'yes' if agree else 'NO'}**.",
        "",
        "| pre-filter | time [s] | per call [µs] | per segment [µs] |",
        "|---|---|---|---|",
        *(f"| {k} | {t:.2f} | {1e6 * t / len(calls):.0f} | {1e6 * t / segments:.2f} |"
          for k, t in (("covers (before)", tc), ("boundary (now)", tb))),  # fmt: skip
        "",
        f"Ratio (boundary / covers): **{tb / tc:.3f}**.",
        "",
    ])  # fmt: skip
    (RESULTS / "train_filter.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
