"""The start placement's answers kept (``tmr.route.references._Answers``, since stop 70): the depth-first search
that stands robots along a polyline (``_along``) asks the clearance of the same candidate points and the same chords
again and again. Each is now asked of the world once, where first asked, and a chord only to a candidate that keeps
its clearance; before, every step of the search asked the world for all its candidates.

    python benchmarks/placement_answers.py [--run long_walls-corner-3202507196:8 ...] [--repeats 3]

Each run (a room of the 216-room set and a robot count) is planned with ``tmr plan --method qp`` (as the CLI),
first once in this process, counting the searches and what they ask of the world; then ``--repeats`` times with the
answers kept and ``--repeats`` times asking every time (stop 69's search), alternating, a new process each. The
table gives the medians of the plan's ``wall_time`` and of ``problem_time`` (the problem's build: its route and the
start placement), and compares ``trajectories.csv`` and ``metrics.json`` byte for byte.

Writes ``benchmarks/results/placement_answers.md``.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from segment_margin import _room_args, alternating_cold_runs, comparison_table  # noqa: E402

import tmr.route.references as references  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: Runs of the 216-room set whose robots do not all fit along the route (parkings, each with its own search along
#: the route from the walk's end), near misses of issue 33's table among them; and one run whose robots stand on
#: the route at the first try.
RUNS = (
    "long_walls-corner-3202507196:8",
    "long_walls-far-1139795748:8",
    "long_walls-corner-1536391021:8",
    "long_walls-corner-1883971893:8",
    "dense-far-2845717476:5",
)


class EveryTime(references._Answers):
    """Stop 69's search: every candidate's clearance and every chord to it asked of the world at every step (no answer
    kept; ``tests/test_references.py`` checks the same reference)."""

    def robot_clear(self, idx: Any, clear: float) -> Any:
        self.clear_now = np.asarray(self.env.exact_clearance(self.S[idx]), float) > clear
        return np.ones(len(idx), dtype=bool)  # so the search asks every chord as well

    def chord_free(self, k: int, idx: Any, need: float) -> Any:
        free = self.tenv.segment_is_free(np.repeat(self.S[k][None], len(idx), 0), self.S[idx], need)
        return free & self.clear_now


#: A child process: ``tmr plan`` with the answers kept (argv[1] "kept") or asked every time ("asked").
CHILD = f"""
import sys
sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})
if sys.argv[1] == "asked":
    import tmr.route.references as references
    from placement_answers import EveryTime
    references._Answers = EveryTime
from tmr.plan import main
sys.exit(main(sys.argv[2:]))
"""

LABELS = ("asked", "kept")


def _asks(run_args: list[str], out: Path) -> tuple[int, int, int, int, int]:
    """(exit code, searches, candidate points asked at the search's steps, points asked of the world, chords asked
    of the world) of one ``tmr plan`` in this process (the steps ask as many chords as points before)."""
    counts = [0, 0, 0, 0]
    kept = references._Answers

    class Counted(kept):  # type: ignore[misc,valid-type]
        def __init__(self, env: Any, S: Any) -> None:
            super().__init__(env, S)
            counts[0] += 1

        def robot_clear(self, idx: Any, clear: float) -> Any:
            counts[1] += len(idx)
            counts[2] += int(np.isnan(self.clearance[idx]).sum())
            return super().robot_clear(idx, clear)

        def chord_free(self, k: int, idx: Any, need: float) -> Any:
            row = self.chords.get(k)
            counts[3] += len(idx) if row is None else int((row[idx] < 0).sum())
            return super().chord_free(k, idx, need)

    references._Answers = Counted
    try:
        from tmr.plan import main as plan_main

        code = plan_main([*run_args, "--out", str(out)])
    finally:
        references._Answers = kept
    return code, *counts  # type: ignore[return-value]


def _measure(run: str, repeats: int) -> str:
    """The table's row for one run."""
    with tempfile.TemporaryDirectory() as d:
        run_args = _room_args(run, Path(d))
        code, searches, steps, points, chords = _asks(run_args, Path(d) / "counted")
        t, same = alternating_cold_runs(CHILD, LABELS, run_args, Path(d), repeats)

    def med(label: str, key: str) -> float:
        return statistics.median(x[key] for x in t[label])

    room, robots = run.rsplit(":", 1)
    wall = [med(k, "wall_time") for k in LABELS]
    problem = [med(k, "problem_time") for k in LABELS]
    return (
        f"| `{room}` | {robots} | {code} | {searches} | {steps:,} | {points:,} | {chords:,} | "
        f"{problem[0]:.2f} → {problem[1]:.2f} | {wall[0]:.2f} → {wall[1]:.2f} | {wall[1] / wall[0]:.3f} | "
        f"{'yes' if same else '**NO**'} |"
    )


def main() -> None:
    comparison_table(
        __doc__,
        RUNS,
        _measure,
        RESULTS / "placement_answers.md",
        "The start placement's answers kept: each candidate's clearance and each chord asked of the world once",
        ["shapely", "numpy", "scipy"],
        lambda repeats: (
            f"`tmr plan --method qp`; medians of {repeats} new processes per version, alternating. *Searches*: the "
            "searches along a polyline (`_along`) in one run. *Candidates*: the candidate points their steps ask "
            "about, each asked of the world as a clearance and as a chord before. *Points*, *chords*: what is asked "
            "of the world now. *Problem*: `problem_time` of `timings.json` (the problem's build, with its route and "
            "the start placement). *Whole run*: `wall_time` (the plan, from the route to the checked plan); *ratio*: "
            "kept / asked. *Same bytes*: `trajectories.csv` and `metrics.json` of every repeat, asked against kept."
        ),
        [
            "| room | N | exit | searches | candidates | points | chords | problem [s], asked → kept | whole run [s] | "
            "ratio | same bytes |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ],
    )


if __name__ == "__main__":
    main()
