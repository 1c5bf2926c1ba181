"""The margin test of ``Environment.segment_is_free`` (a segment inside the free space is free iff its distance to the
boundary is > the margin): only the boundary segments near it (``Environment._farther_than``) against the nearest
segment of each (``STRtree.query_nearest``, ``Environment._boundary_distance``, until stop 67), on the very calls a
train search makes, and the whole ``tmr plan --method qp`` run with each.

    python benchmarks/segment_margin.py [--run narrow-far-2856891376:8] [--repeats 3] [--end-to-end 3]

The run (a room of the 216-room set and a robot count; the default one's trailing references fail, so its qp plan
follows train references, whose search makes most of these tests) is planned once in this process with ``--method
qp`` (``tmr.plan.main``, as the CLI), every call of the margin test recorded (its segments and margins). The calls
are then replayed, in their order, through both tests, alternating, ``--repeats`` times; the table checks that they
agree on every segment. With ``--end-to-end R`` the whole CLI run is timed R times with each test, alternating, a new
process each (its ``wall_time``), and its ``trajectories.csv`` compared byte for byte.

Writes ``benchmarks/results/segment_margin.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402

from tmr.sweep.room_runs import xy_arg  # noqa: E402
from tmr.sweep.rooms import room_from_spec, room_set, write_geojson  # noqa: E402
from tmr.world.environment import Environment  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: A run whose qp plan follows train references (the trailing ones fail): its train search 17 of the 23 s profiled.
RUN = "narrow-far-2856891376:8"


def _nearest(env: Environment, lines: Any, margin: np.ndarray) -> np.ndarray:
    """The test until stop 67: the distance to the nearest boundary segment, > the margin."""
    return env._boundary_distance(lines) > margin


def _room_args(run: str, where: Path) -> list[str]:
    """``tmr plan``'s arguments for ``run`` (its map written into ``where``), up to ``--out``."""
    name, robots = run.rsplit(":", 1)
    spec = {s[0]: s for s in room_set(216)}.get(int(name.rsplit("-", 1)[1]))
    room = room_from_spec(spec) if spec is not None else None
    if room is None or isinstance(room, str) or room.name != name:
        sys.exit(f"{name}: not a room of the 216-room set")
    return plan_args(room, robots, where)


def plan_args(room: Any, robots: str, where: Path, method: str = "qp") -> list[str]:
    """``tmr plan``'s arguments for a generated ``room`` with ``robots`` (its map written into ``where``), up to
    ``--out``. Also used by ``coarse_size.py``."""
    write_geojson(room, where / "room.geojson")
    return [
        "--map", str(where / "room.geojson"), f"--base={xy_arg(room.base)}", f"--goal={xy_arg(room.goal)}",
        "--robots", robots, "--method", method, "--no-plots", "--seed", "0", "--quiet",
    ]  # fmt: skip


#: A child process: ``tmr plan`` with the margin test of argv[1] ("nearest": :func:`_nearest`, until stop 67).
CHILD = f"""
import sys
sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})
from tmr.world.environment import Environment
if sys.argv[1] == "nearest":
    from segment_margin import _nearest
    Environment._farther_than = _nearest
from tmr.plan import main
sys.exit(main(sys.argv[2:]))
"""


def cold_timings(child: str, label: str, args: list[str], out: Path, exits: tuple[int, ...] = (0,)) -> dict[str, float]:
    """``timings.json`` of ``tmr plan`` with ``args`` written to ``out``, in a new process running ``child`` (a
    ``python -c`` script given ``label`` and the arguments), one BLAS thread; an exit code not in ``exits`` stops the
    benchmark. Also used by ``train_repair.py`` and :func:`alternating_cold_runs`."""
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", child, label, *args, "--out", str(out)], env=env)
    if done.returncode not in exits:
        sys.exit(f"tmr plan {' '.join(args)}: exit {done.returncode}")
    return json.loads((out / "timings.json").read_text())


def alternating_cold_runs(
    child: str, labels: tuple[str, str], args: list[str], out: Path, repeats: int
) -> tuple[dict[str, list[dict[str, float]]], bool]:
    """``repeats`` :func:`cold_timings` of each of the two ``labels`` (exit 0 or 1), the order alternating from one
    repeat to the next, written to ``out / f"{label}{r}"``: the timings per label, and whether every repeat wrote the
    same ``trajectories.csv`` and ``metrics.json`` bytes (or neither file) with both. Used by ``route_verdicts.py``,
    ``placement_answers.py`` and ``repair_windows.py``."""
    t: dict[str, list[dict[str, float]]] = {k: [] for k in labels}
    same = True
    for r in range(repeats):
        for label in labels if r % 2 == 0 else labels[::-1]:
            t[label].append(cold_timings(child, label, args, out / f"{label}{r}", (0, 1)))
        for name in ("trajectories.csv", "metrics.json"):
            a, b = (out / f"{k}{r}" / name for k in labels)
            same &= a.exists() == b.exists() and (not a.exists() or a.read_bytes() == b.read_bytes())
    return t, same


def comparison_table(
    doc: str,
    runs: tuple[str, ...],
    measure: Callable[[str, int], str],
    out: Path,
    title: str,
    libraries: list[str],
    legend: Callable[[int], str],
    columns: list[str],
) -> None:
    """The command line of a benchmark of :func:`alternating_cold_runs` (``--run ROOM:N`` …, default ``runs``;
    ``--repeats``) and its Markdown table, written to ``out`` (``benchmarks/results/<script>.md``) and printed:
    ``title``, the command with the time, source and ``libraries``' versions, ``legend(repeats)``, the ``columns``
    (header and rule) and ``measure(run, repeats)``'s row for each run, printed as it comes. ``doc``: the script's
    docstring (its first paragraph is the command's description). Used by ``route_verdicts.py``,
    ``placement_answers.py`` and ``repair_windows.py``."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--run", action="append", help="ROOM:N, a room of the 216-room set and a robot count")
    ap.add_argument("--repeats", type=int, default=3, help="new processes per version and run (medians)")
    args = ap.parse_args()
    chosen = args.run or list(runs)
    lines = [
        f"# {title}",
        "",
        f"`python benchmarks/{out.stem}.py {' '.join(f'--run {r}' for r in chosen)} --repeats {args.repeats}` — "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {source_version()}; "
        f"{versions(libraries)}; {platform.machine()}, {os.cpu_count()} cores.",
        "",
        legend(args.repeats),
        "",
        *columns,
    ]
    for run in chosen:
        lines.append(measure(run, args.repeats))
        print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    out.write_text(text)
    print(text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default=RUN, help="ROOM:N, a room of the 216-room set and a robot count")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--end-to-end", type=int, default=0, metavar="R", help="time the whole CLI run R times with each")
    args = ap.parse_args()
    calls: list[tuple[Environment, Any, np.ndarray]] = []
    original = Environment._farther_than

    def spy(self: Environment, lines: Any, margin: np.ndarray) -> np.ndarray:
        calls.append((self, lines, np.array(margin, dtype=float)))
        return original(self, lines, margin)

    with tempfile.TemporaryDirectory() as d:
        run_args = _room_args(args.run, Path(d))
        Environment._farther_than = spy  # type: ignore[method-assign]
        try:
            from tmr.plan import main as plan_main

            code = plan_main([*run_args, "--out", str(Path(d) / "recorded")])
        finally:
            Environment._farther_than = original  # type: ignore[method-assign]
        if not calls:
            sys.exit(f"{args.run}: no margin test was made (exit {code})")
        agree = all(np.array_equal(original(e, g, m), _nearest(e, g, m)) for e, g, m in calls)
        times: dict[str, list[float]] = {"nearest": [], "near": []}
        for _ in range(args.repeats):
            for label, test in (("nearest", _nearest), ("near", original)):
                t0 = time.perf_counter()
                for e, g, m in calls:
                    test(e, g, m)
                times[label].append(time.perf_counter() - t0)
        walls: dict[str, list[float]] = {"nearest": [], "near": []}
        same_bytes = True
        for r in range(args.end_to_end):
            for label in ("nearest", "near"):
                walls[label].append(cold_timings(CHILD, label, run_args, Path(d) / f"{label}{r}")["wall_time"])
            a, b = (Path(d) / f"{k}{r}" / "trajectories.csv" for k in ("nearest", "near"))
            same_bytes &= a.read_bytes() == b.read_bytes()
    tn, tm = (statistics.median(times[k]) for k in ("nearest", "near"))
    segments = sum(len(g) for _, g, _ in calls)
    lines = [
        "# The margin test of `Environment.segment_is_free`: the boundary segments near each segment against the "
        "nearest one",
        "",
        f"`python benchmarks/segment_margin.py --run {args.run} --repeats {args.repeats} --end-to-end "
        f"{args.end_to_end}` — {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {source_version()}; "
        f"{versions(['shapely', 'numpy'])}; {platform.machine()}, {os.cpu_count()} cores.",
        "",
        f"`tmr plan --method qp` on `{args.run.replace(':', '` with ')} robots (exit {code}) made the margin test "
        f"{len(calls):,} times, on {segments:,} segments (those inside the free space and clear of its boundary). "
        f"Every call replayed in order through each test, alternating; medians of {args.repeats} repeats. Both give "
        f"the same answer on every segment: **{'yes' if agree else 'NO'}**.",
        "",
        "| margin test | time [s] | per segment [µs] |",
        "|---|---|---|",
        *(
            f"| {k} | {t:.2f} | {1e6 * t / segments:.2f} |"
            for k, t in (
                ("nearest segment (`query_nearest`, before)", tn),
                ("segments near it (`_farther_than`, now)", tm),
            )
        ),  # fmt: skip
        "",
        f"Ratio (near / nearest): **{tm / tn:.3f}**.",
        "",
    ]
    if args.end_to_end:
        wn, wm = (statistics.median(walls[k]) for k in ("nearest", "near"))
        lines += [
            f"The whole CLI run (its `wall_time`, a new process each, medians of {args.end_to_end}, alternating): "
            f"**{wn:.1f} s** with the nearest segment, **{wm:.1f} s** now (ratio {wm / wn:.3f}; each run: "
            f"{', '.join(f'{t:.1f}' for t in walls['nearest'])} and {', '.join(f'{t:.1f}' for t in walls['near'])} s)"
            f"; `trajectories.csv` the same byte for byte: **{'yes' if same_bytes else 'NO'}**.",
            "",
        ]
    text = "\n".join(lines)
    (RESULTS / "segment_margin.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
