"""The train search's repair (``tmr.route.train._repair``: the grid point within 1 m from which a blocked robot can
advance farthest): tested lazily, best first (since stop 68), against testing every grid point (until stop 68), on
the very calls a train search makes; and the whole ``tmr plan --method qp`` run with the train search of stop 68
against that of stop 67 (every grid point tested; each state's limits tested on every point: no group or prefix
dropped once its answer is known, ``_State.valid_groups`` and ``_State.valid_prefix``; the nearest guide sample of
each point by every sample's distance, not a k-d tree's few, ``_Paths.nearest_arcs``).

    python benchmarks/train_repair.py [--run narrow-far-2856891376:8 ...] [--end-to-end 3]

Each run (a room of the 216-room set and a robot count; the default one's trailing references fail, so its qp plan
follows train references) is planned once in this process with ``--method qp`` (``tmr.plan.main``, as the CLI). At
every repair the search makes, both versions run on the same state, in alternating order, each timed; the table
checks that they return the same point (or none) every time. With ``--end-to-end R`` the whole CLI run is timed R
times with each search, alternating, a new process each (its ``wall_time``; a run whose plan fails, exit 1, counts
too), and its ``trajectories.csv`` and ``metrics.json`` compared byte for byte.

Writes ``benchmarks/results/train_repair.md``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402
from segment_margin import _room_args, cold_timings  # noqa: E402

import tmr.route.train as train  # noqa: E402
from tmr.route.route import point_at  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: A run whose qp plan follows train references (the trailing ones fail); its repairs took 12.6 of the 17.2 s of its
#: train search under stop 67's profiler (which inflates the many small calls).
RUN = "narrow-far-2856891376:8"


def every_point(state: Any, paths: Any, mover: int, other: int, step: float) -> np.ndarray | None:
    """The repair until stop 68: every grid point tested (the limits at it; for a neighbour, the tether's clearance
    at each of ``other``'s steps while the point's prefix lasts), ranked, the first 50 tried."""
    lim, X, tenv = state.lim, state.X, state.tenv
    r = np.arange(-train.REPAIR_RADIUS, train.REPAIR_RADIUS + 1e-9, train.REPAIR_GRID)
    G = X[mover] + np.stack(np.meshgrid(r, r, indexing="ij"), axis=-1).reshape(-1, 2)
    G = G[np.linalg.norm(G - X[mover], axis=1) <= train.REPAIR_RADIUS]
    u = np.arange(paths.u[other] + step, min(paths.length[other], paths.u[other] + train.REPAIR_LOOKAHEAD) + 1e-9, step)
    if not len(u):
        return None
    ahead = paths.at(other, u)
    neighbours = abs(mover - other) == 1
    if neighbours:
        G = G[tenv.segment_is_free(G, ahead[0], lim.clearance)]
    G = G[state.valid(mover, G)] if len(G) else G
    if not len(G):
        return None
    length = np.linalg.norm(G[:, None] - ahead[None], axis=2)
    ok = length >= lim.separation
    if neighbours:
        lo, hi = lim.spans[max(mover, other)]
        ok &= (length >= lo) & (length <= hi)
    gain = np.zeros(len(G), dtype=int)
    alive = np.arange(len(G))
    for col in range(len(u)):
        alive = alive[ok[alive, col]]
        if neighbours and len(alive):
            alive = alive[tenv.segment_is_free(G[alive], ahead[col], lim.clearance)]
        if not len(alive):
            break
        gain[alive] += 1
    order = np.lexsort((np.linalg.norm(G - X[mover], axis=1), -gain))
    for k in order[: train.REPAIR_TRIES]:
        if gain[k] == 0:
            return None
        m = max(2, math.ceil(float(np.linalg.norm(G[k] - X[mover])) / step) + 1)
        line = X[mover] + np.linspace(0.0, 1.0, m)[:, None] * (G[k] - X[mover])
        if state.valid(mover, line).all():
            return G[k]
    return None


def every_valid(self: Any, i: int, pts: Any, checks: Any = None) -> np.ndarray:
    """``_State.valid`` of stops 67 and 68, its own loop: the cheap checks first, each on the points still passing.
    Since stop 69 ``valid`` is ``valid_groups`` with a group per point, which the "every" child replaces."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    ok = np.ones(len(pts), dtype=bool)
    for _, _, test in sorted(self._checks(i) if checks is None else checks, key=lambda check: check[1]):
        idx = np.flatnonzero(ok)
        if not len(idx):
            break
        ok[idx] = test(pts[idx])
    return ok


def every_group(self: Any, i: int, pts: Any, owner: Any, n: int, checks: Any = None) -> np.ndarray:
    """``_State.valid_groups`` until stop 68: every point tested with every check, then grouped."""
    return np.bincount(owner[~every_valid(self, i, pts, checks)], minlength=n) == 0


def every_prefix(self: Any, i: int, pts: Any, checks: Any = None) -> int:
    """``_State.valid_prefix`` until stop 68: every point tested with every check, then the first failure."""
    ok = every_valid(self, i, pts, checks)
    return int(np.argmin(ok)) if not ok.all() else len(ok)


def every_sample(self: Any, pts: Any, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """``_Paths.nearest_arcs`` until stop 68: every guide sample's distance to every point."""
    s = np.linspace(lo, hi, max(2, int((hi - lo) / 0.02) + 1))
    G = point_at(self.guide, self.garcs, s)
    out = np.empty(len(pts))
    for k in range(0, len(pts), 256):
        out[k : k + 256] = s[np.argmin(np.linalg.norm(pts[k : k + 256, None] - G[None], axis=2), axis=1)]
    return s, out


#: A child process: ``tmr plan`` with the train search of argv[1] ("every": stop 67's, :func:`every_point`,
#: :func:`every_valid`, :func:`every_group`, :func:`every_prefix`, :func:`every_sample`).
CHILD = f"""
import sys
sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})
import tmr.route.train as train
if sys.argv[1] == "every":
    from train_repair import every_group, every_point, every_prefix, every_sample, every_valid
    train._repair = every_point
    train._State.valid = every_valid
    train._State.valid_groups = every_group
    train._State.valid_prefix = every_prefix
    train._Paths.nearest_arcs = every_sample
from tmr.plan import main
sys.exit(main(sys.argv[2:]))
"""


def _measure(run: str, end_to_end: int) -> list[str]:
    """The table's section for one run."""
    lazy = train._repair
    times: dict[str, list[float]] = {"every": [], "lazy": []}
    found = [0, 0]  # repairs that return a point, that return none
    agree = True

    def both(state: Any, paths: Any, mover: int, other: int, step: float) -> np.ndarray | None:
        nonlocal agree
        out = {}
        order = (("every", every_point), ("lazy", lazy))
        for label, repair in order if len(times["lazy"]) % 2 == 0 else order[::-1]:
            t0 = time.perf_counter()
            out[label] = repair(state, paths, mover, other, step)
            times[label].append(time.perf_counter() - t0)
        a, b = out["every"], out["lazy"]
        agree &= (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))
        found[b is None] += 1
        return b

    with tempfile.TemporaryDirectory() as d:
        run_args = _room_args(run, Path(d))
        train._repair = both
        try:
            from tmr.plan import main as plan_main

            code = plan_main([*run_args, "--out", str(Path(d) / "recorded")])
        finally:
            train._repair = lazy
        walls: dict[str, list[float]] = {"every": [], "lazy": []}
        same_bytes = True
        for r in range(end_to_end):
            for label in ("every", "lazy"):
                walls[label].append(cold_timings(CHILD, label, run_args, Path(d) / f"{label}{r}", (0, 1))["wall_time"])
            for name in ("trajectories.csv", "metrics.json"):
                a, b = (Path(d) / f"{k}{r}" / name for k in ("every", "lazy"))
                same_bytes &= a.read_bytes() == b.read_bytes()
    room, robots = run.rsplit(":", 1)
    lines = [f"## `{room}` with {'`--robots auto`' if robots == 'auto' else robots + ' robots'}", ""]
    if times["lazy"]:
        te, tl = (sum(times[k]) for k in ("every", "lazy"))
        ratios = [b / a for a, b in zip(times["every"], times["lazy"], strict=True)]
        lines += [
            f"`tmr plan --method qp` (exit {code}): its train search made {len(times['lazy']):,} repairs ({found[0]:,} "
            f"found a point, {found[1]:,} none). At each, both versions ran on the same state, in alternating order. "
            f"They return the same point (or none) every time: **{'yes' if agree else 'NO'}**.",
            "",
            "| repair | time, all repairs [s] | median repair [ms] |",
            "|---|---|---|",
            f"| every grid point tested (before) | {te:.2f} | {1e3 * statistics.median(times['every']):.1f} |",
            f"| lazily, best first (now) | {tl:.2f} | {1e3 * statistics.median(times['lazy']):.1f} |",
            "",
            f"Ratio (lazy / every), all repairs: **{tl / te:.3f}**; per repair: median "
            f"{statistics.median(ratios):.3f}, range {min(ratios):.3f}–{max(ratios):.3f}.",
            "",
        ]
    else:
        lines += [f"`tmr plan --method qp` (exit {code}): its train search made no repair.", ""]
    if end_to_end:
        we, wl = (statistics.median(walls[k]) for k in ("every", "lazy"))
        lines += [
            f"The whole CLI run (its `wall_time`, a new process each, medians of {end_to_end}, alternating): "
            f"**{we:.1f} s** with stop 67's train search, **{wl:.1f} s** now (ratio {wl / we:.3f}; each run: "
            f"{', '.join(f'{t:.1f}' for t in walls['every'])} and {', '.join(f'{t:.1f}' for t in walls['lazy'])} s)"
            f"; `trajectories.csv` and `metrics.json` the same byte for byte: **{'yes' if same_bytes else 'NO'}**.",
            "",
        ]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", action="append", help=f"ROOM:N, a room of the 216-room set and a robot count ({RUN})")
    ap.add_argument("--end-to-end", type=int, default=0, metavar="R", help="time the whole CLI run R times with each")
    args = ap.parse_args()
    runs = args.run or [RUN]
    lines = [
        "# The train search's repair: the grid tested lazily, best first, against every grid point",
        "",
        f"`python benchmarks/train_repair.py {' '.join(f'--run {r}' for r in runs)} --end-to-end {args.end_to_end}` — "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {source_version()}; "
        f"{versions(['shapely', 'numpy'])}; {platform.machine()}, {os.cpu_count()} cores.",
        "",
    ]
    for run in runs:
        lines += _measure(run, args.end_to_end)
    text = "\n".join(lines)
    (RESULTS / "train_repair.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
