"""The Jacobian of the horizon NLP's non-clearance rows: casadi's Jacobian of the stacked rows against one group at a
time.

    python benchmarks/horizon_jacobian.py [--cases E6 150917237:walls:corner:8 1355359843:narrow:corner:8]
                                          [--repeats 20]

Every round of ``--method horizon`` transcribes a new NLP (the lazy rows near its start, ``formulations/horizon.md``,
"Lazy rows") and builds its constraint Jacobian: the clearance rows' is assembled from the spline's derivatives, the
other rows' (leader, fitness, span, separation, joint and robot rates) is casadi's
(:meth:`tmr.control.horizon_model._Transcription.rest_jacobian`). For each case (scenario E with 6 robots, or a
generated room ``seed:density:goal:robots`` of ``tmr.sweep.rooms``) at its ``qp`` plan, with round 1's rows:

- **stacked**: ``ca.jacobian`` of the non-clearance rows stacked in one column (what tmr built up to stop 54);
- **by group**: ``ca.jacobian`` of each group's rows, stacked (``rest_jacobian``).

Reported: the build time [s] (the symbolic Jacobian and its ``casadi.Function``; one build each, as a round builds
it), the evaluation's median over ``--repeats`` [ms], and the largest entry of the difference relative to the largest
entry (the two are the same matrix). Writes ``benchmarks/results/horizon_jacobian.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import casadi as ca

sys.path.insert(0, str(Path(__file__).resolve().parent))
from horizon_cases import build, median_ms, model_at, record  # noqa: E402
from provenance import source_version, versions  # noqa: E402

from tmr.control import horizon_model as hm  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
DEFAULT_CASES = ["E6", "150917237:walls:corner:8", "1355359843:narrow:corner:8"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEFAULT_CASES)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    rows = []
    for case in args.cases:
        problem, warm = build(case)
        su, model, xv = model_at(problem, warm)
        tr = hm._Transcription(model, model.near_masks(model.values(xv)))  # round 1's rows
        before, after = tr._rest
        r = {"case": case, "knots": su.K + 1, "robots": su.N, "rows": int(before.shape[0] + after.shape[0])}
        t0 = time.perf_counter()
        stacked = ca.Function("stacked", [model.x], [ca.jacobian(ca.vertcat(before, after), model.x)])
        r["stacked build"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        ours = ca.Function("by_group", [model.x], [tr.rest_jacobian()])
        r["by group build"] = time.perf_counter() - t0
        r["stacked eval"] = median_ms(lambda f=stacked, x=xv: f(x), args.repeats)
        r["by group eval"] = median_ms(lambda f=ours, x=xv: f(x), args.repeats)
        record(rows, r, stacked(xv), ours(xv))
    lines = [
        "# The Jacobian of the non-clearance rows: casadi's of the stacked rows against one group at a time",
        "",
        f"`python benchmarks/horizon_jacobian.py --cases {' '.join(args.cases)} --repeats {args.repeats}`"
        f" ({source_version()}; {versions(['casadi', 'numpy'])}). At the `qp` plan, round 1's rows; build: one each"
        f" [s]; evaluation: median of {args.repeats} [ms]; see the script's docstring.",
        "",
        "| case | knots | robots | rows | entries | stacked build [s] | by group build [s] | × | stacked eval [ms]"
        " | by group eval [ms] | max difference / max entry |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['knots']:,} | {r['robots']} | {r['rows']:,} | {r['entries']:,}"
            f" | {r['stacked build']:.2f} | {r['by group build']:.2f} | {r['stacked build'] / r['by group build']:.1f}×"
            f" | {r['stacked eval']:.1f} | {r['by group eval']:.1f} | {r['difference']:.1e} |"
        )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "horizon_jacobian.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
