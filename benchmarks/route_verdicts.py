"""The route's remembered verdicts (``tmr.route.witness._VERDICTS``, since stop 69): ``tmr plan --robots auto`` plans
the route twice — the precheck's for any N (which finds N_min), then the route for N_min itself
(``tmr.planner.build_problem``) — and both ask the corner proof (``proven_too_few``) and the search off the route
(``_witness``) the same questions. Each question is now answered once per world; before, the second route searched
again.

    python benchmarks/route_verdicts.py [--run dense-far-2845717476:auto ...] [--repeats 3]

Each run (a room of the 216-room set and a robot count) is planned with ``tmr plan --method qp`` (as the CLI),
first once in this process, counting the questions asked and those answered from memory; then ``--repeats`` times
with the verdicts remembered and ``--repeats`` times without (every question searched, as until stop 69),
alternating, a new process each. The table gives the medians of the plan's ``wall_time`` and of the route and
problem parts of ``timings.json`` (the precheck's route, and the problem's build with its route and start
placement), and compares ``trajectories.csv`` and ``metrics.json`` byte for byte.

Writes ``benchmarks/results/route_verdicts.md``.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from segment_margin import _room_args, alternating_cold_runs, comparison_table  # noqa: E402

import tmr.route.witness as witness  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: ``--robots auto`` runs of the 216-room set whose route searches off the route (N_min below the route chain's
#: count), the near misses of issue 33's table among them; and one run with N given, whose route is planned once.
RUNS = (
    "dense-far-2845717476:auto",
    "narrow-far-2856891376:auto",
    "long_walls-far-661176739:auto",
    "long_walls-corner-1800594380:auto",
    "narrow-corner-1142507027:auto",
    "medium-far-2413201021:auto",
    "dense-far-2845717476:5",
)

#: A child process: ``tmr plan`` with the verdicts remembered (argv[1] "remembered") or every question searched
#: ("searched": stop 68's route).
CHILD = """
import sys
import tmr.route.witness as witness
if sys.argv[1] == "searched":
    witness._remembered = lambda env, key, compute: compute()
from tmr.plan import main
sys.exit(main(sys.argv[2:]))
"""

LABELS = ("searched", "remembered")


def _questions(run_args: list[str], out: Path) -> tuple[int, int, int]:
    """(exit code, questions asked, answered from memory) of one ``tmr plan`` in this process."""
    asked = [0, 0]
    remembered = witness._remembered

    def counted(env: Any, key: tuple[Any, ...], compute: Any) -> Any:
        asked[0] += 1
        asked[1] += key in witness._VERDICTS.get(env, {})
        return remembered(env, key, compute)

    witness._remembered = counted
    try:
        from tmr.plan import main as plan_main

        code = plan_main([*run_args, "--out", str(out)])
    finally:
        witness._remembered = remembered
    return code, asked[0], asked[1]


def _measure(run: str, repeats: int) -> str:
    """The table's row for one run."""
    with tempfile.TemporaryDirectory() as d:
        run_args = _room_args(run, Path(d))
        code, asked, known = _questions(run_args, Path(d) / "counted")
        t, same = alternating_cold_runs(CHILD, LABELS, run_args, Path(d), repeats)

    def med(label: str, *keys: str) -> float:
        return statistics.median(sum(x[k] for k in keys) for x in t[label])

    room, robots = run.rsplit(":", 1)
    wall = [med(k, "wall_time") for k in LABELS]
    route = [med(k, "route_time", "problem_time") for k in LABELS]
    return (
        f"| `{room}` | {robots} | {code} | {asked} | {known} | {route[0]:.2f} → {route[1]:.2f} | "
        f"{wall[0]:.2f} → {wall[1]:.2f} | {wall[1] / wall[0]:.3f} | {'yes' if same else '**NO**'} |"
    )


def main() -> None:
    comparison_table(
        __doc__,
        RUNS,
        _measure,
        RESULTS / "route_verdicts.md",
        "The route's verdicts remembered: `--robots auto` asks the corner proof and the search off the route once",
        ["shapely", "numpy", "scipy"],
        lambda repeats: (
            f"`tmr plan --method qp`; medians of {repeats} new processes per version, alternating. *Questions*: calls "
            "of `proven_too_few` and `_witness` in one run, and how many of them were asked before in the same run "
            "(answered from memory now, searched again before). *Route + problem*: `route_time` + `problem_time` of "
            "`timings.json` (the precheck's route; the problem's build, with its own route and the start placement). "
            "*Same bytes*: `trajectories.csv` and `metrics.json` of every repeat, searched against remembered."
        ),
        [
            "| room | N | exit | questions | asked before | route + problem [s], searched → remembered | "
            "whole run [s] | ratio | same bytes |",
            "|---|---|---|---|---|---|---|---|---|",
        ],
    )


if __name__ == "__main__":
    main()
