"""The Hessian of the horizon NLP's cost and non-clearance rows: casadi's automatic one against the assembled product.

    python benchmarks/horizon_hessian.py [--cases E6 150917237:walls:corner:8] [--repeats 20]

``--method horizon`` builds, once per model and Hessian kind, the Hessian (variables × variables) of the cost and of
every non-clearance row weighted by its multiplier, and evaluates it at every IPOPT iterate
(:meth:`tmr.control.horizon_model._Model.rows_hessian`, ``formulations/horizon.md``, "The Hessian of the cost and the
other rows"). For each case (scenario E with 6 robots, or a generated room ``seed:density:goal:robots`` of
``tmr.sweep.rooms``) at its ``qp`` plan, with random multipliers:

- **casadi**: casadi's symbolic Hessian of the weighted sum (``ca.hessian(c J + λᵀ rows, x)``; Gauss–Newton: of the
  rows without the fitness rows, plus Σ 2 c_k J_kᵀJ_k of the stacked residual Jacobians) — what tmr built up to
  stop 46;
- **tmr**: ``rows_hessian``, one product Jᵀ W J through z = (Δθ, D), the link vectors' closed-form curvature and the
  separation rows' constant map.

Reported: the build time [s] (one build each: a build is what a new model costs), the evaluation's median over
``--repeats`` [ms], the ratio casadi / tmr of each, and the largest entry of the difference relative to the largest
entry (the two are the same matrix). Writes ``benchmarks/results/horizon_hessian.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from horizon_cases import build, median_ms, model_at, record  # noqa: E402
from provenance import source_version, versions  # noqa: E402

from tmr.control import horizon_model as hm  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def casadis(model: hm._Model, kind: str) -> ca.Function:
    """casadi's own Hessian of the same weighted sum, ``H(x, c, λ)`` as :meth:`_Model.rows_hessian`."""
    x = model.x
    rest = ca.vertcat(*[ca.vec(model.rows[g].expr) for g in model.rest_groups])
    lam = ca.MX.sym("lam", model.rest_size)
    if kind == "exact":
        c = ca.MX.sym("c", 1)
        H = ca.hessian(c * model.J + ca.dot(lam, rest), x)[0]
    else:
        c = ca.MX.sym("c", len(model.gn_terms))
        keep = np.ones(model.rest_size)
        if "fitness" in model.rest_offset:
            o = model.rest_offset["fitness"]
            keep[o : o + len(model.fitness_terms)] = 0.0
        root = ca.sqrt(2 * ca.fmax(c, 0))
        Js = ca.vertcat(*[root[i] * ca.jacobian(model.residuals[k], x) for i, k in enumerate(model.gn_terms)])
        H = ca.hessian(ca.dot(lam * ca.DM(keep), rest), x)[0] + ca.mtimes(Js.T, Js)
    return ca.Function("casadi_" + kind.replace("-", "_"), [x, c, lam], [H])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=["E6", "150917237:walls:corner:8"])
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    rows = []
    for case in args.cases:
        problem, warm = build(case)
        su, model, xv = model_at(problem, warm)
        rng = np.random.default_rng(0)
        lam = rng.normal(0.0, 1.0, model.rest_size)
        for kind, c in (("exact", 0.7), ("gauss-newton", np.array([0.5, 1.5, 2.0]))):
            r = {"case": case, "knots": su.K + 1, "robots": su.N, "kind": kind}
            t0 = time.perf_counter()
            theirs = casadis(model, kind)
            r["casadi build"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            ours = model.rows_hessian(kind)
            r["tmr build"] = time.perf_counter() - t0
            r["casadi eval"] = median_ms(lambda f=theirs, c=c, x=xv, m=lam: f(x, c, m), args.repeats)
            r["tmr eval"] = median_ms(lambda f=ours, c=c, x=xv, m=lam: f(x, c, m), args.repeats)
            record(rows, r, theirs(xv, c, lam), ours(xv, c, lam))
    lines = [
        "# The Hessian of the cost and the non-clearance rows: casadi's against the assembled product",
        "",
        f"`python benchmarks/horizon_hessian.py --cases {' '.join(args.cases)} --repeats {args.repeats}`"
        f" ({source_version()}; {versions(['casadi', 'numpy', 'scipy'])}). At the `qp` plan, random multipliers;"
        f" build: one each [s]; evaluation: median of {args.repeats} [ms]; see the script's docstring.",
        "",
        "| case | knots | robots | kind | entries | casadi build [s] | tmr build [s] | × | casadi eval [ms]"
        " | tmr eval [ms] | × | max difference / max entry |",
        "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['knots']:,} | {r['robots']} | {r['kind']} | {r['entries']:,} | {r['casadi build']:.2f}"
            f" | {r['tmr build']:.2f} | {r['casadi build'] / r['tmr build']:.1f}× | {r['casadi eval']:.1f}"
            f" | {r['tmr eval']:.1f} | {r['casadi eval'] / r['tmr eval']:.1f}× | {r['difference']:.1e} |"
        )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "horizon_hessian.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
