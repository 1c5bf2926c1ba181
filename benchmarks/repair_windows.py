"""The coarse pass's repair on each window's own model (``tmr.control.horizon_model._Model.window``, since stop 71):
where rows of the whole NLP fail at single knots of the interpolated coarse optimum, the repair solves windows of
knots around them with every other knot held. Each window was a transcription of the whole horizon (every knot a
variable, those outside fixed; the whole cost, its gradient and Hessian evaluated at every IPOPT iteration); it is
now the model of the window's knots and two on either side, the same IPOPT iterates at a window's size.

    python benchmarks/repair_windows.py [--run long_walls-corner-1800594380:8 ...] [--repeats 3]

Each run (a room of the 216-room set and a robot count) is planned with ``tmr plan --method horizon --time-limit 60``
(as ``benchmarks/horizon.py`` runs the table), ``--repeats`` times with the windows' own models and ``--repeats``
times with the whole model's windows (``_Model.window`` answering ``None``: the code before), alternating, a new
process each. The table gives the repair's windows and IPOPT iterations (from ``metrics.json``), the medians of the
plan's ``nlp_time`` and ``wall_time``, and compares ``trajectories.csv`` and ``metrics.json`` byte for byte. With
a time limit, a run that reaches it may end elsewhere when any part of it is faster: different bytes there would
not by themselves be a fault (none of these runs reaches it).

Writes ``benchmarks/results/repair_windows.md``.
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from segment_margin import _room_args, alternating_cold_runs, comparison_table  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: Misses of issue 33's table (``horizon_rooms_216_64fa0ec_misses_s70``) whose coarse optimum was repaired, in two
#: windows to eight (on every grid of the coarse pass).
RUNS = (
    "long_walls-corner-1800594380:8",
    "narrow-far-3708056060:5",
    "narrow-corner-1142507027:8",
    "long_walls-corner-1536391021:8",
    "long_walls-far-661176739:8",
    "long_walls-corner-3202507196:8",
)

#: A child process: ``tmr plan`` with the windows' own models (argv[1] "own") or the whole model's ("whole").
CHILD = """
import sys
if sys.argv[1] == "whole":
    import tmr.control.horizon_model as horizon_model
    horizon_model._Model.window = lambda self, a, b: None
from tmr.plan import main
sys.exit(main(sys.argv[2:]))
"""

LABELS = ("whole", "own")


def _measure(run: str, repeats: int) -> str:
    """The table's row for one run."""
    with tempfile.TemporaryDirectory() as d:
        run_args = [a if a != "qp" else "horizon" for a in _room_args(run, Path(d))] + ["--time-limit", "60"]
        t, same = alternating_cold_runs(CHILD, LABELS, run_args, Path(d), repeats)
        metrics = json.loads((Path(d) / "own0" / "metrics.json").read_text())

    def med(label: str, key: str) -> float:
        return statistics.median(x[key] for x in t[label])

    summary = metrics.get("horizon") or {}  # the plan's horizon_summary
    coarse = summary.get("coarse") or {}
    repair = coarse.get("repair") or []
    room, robots = run.rsplit(":", 1)
    nlp = [med(k, "nlp_time") for k in LABELS]
    wall = [med(k, "wall_time") for k in LABELS]
    return (
        f"| `{room}` | {robots} | {summary.get('result')} | {len(repair)} | "
        f"{coarse.get('repair_iterations', 0)} | {nlp[0]:.2f} → {nlp[1]:.2f} | {wall[0]:.2f} → {wall[1]:.2f} | "
        f"{wall[1] / wall[0]:.3f} | {'yes' if same else '**NO**'} |"
    )


def main() -> None:
    comparison_table(
        __doc__,
        RUNS,
        _measure,
        RESULTS / "repair_windows.md",
        "The coarse pass's repair on each window's own model",
        ["casadi", "numpy"],
        lambda repeats: (
            f"`tmr plan --method horizon --time-limit 60`; medians of {repeats} new processes per version, "
            "alternating, one BLAS thread. *Result*: the plan's (`horizon.result` of `metrics.json`). *Windows*: the "
            "repair's windows in the coarse pass's last grid (`horizon.coarse.repair`); *iterations*: the repair's "
            "IPOPT iterations on every grid (`horizon.coarse.repair_iterations`). *NLP*: `nlp_time` of `timings.json` "
            "(the whole-horizon optimiser, the coarse pass and its repair included); *whole run*: `wall_time`; "
            "*ratio*: own / whole. *Same bytes*: `trajectories.csv` and `metrics.json` of every repeat, the whole "
            "model's windows against the windows' own."
        ),
        [
            "| room | N | result | windows | iterations | NLP [s], whole → own | whole run [s] | ratio | same bytes |",
            "|---|---|---|---|---|---|---|---|---|",
        ],
    )


if __name__ == "__main__":
    main()
