"""The clearance spline's evaluation per IPOPT iterate: casadi and scipy against the one numpy pass.

    python benchmarks/horizon_spline.py [--points 5000 28195 80000] [--repeats 30]

The whole-horizon NLP (``--method horizon``) evaluates its clearance rows, their Jacobian and the Lagrangian's Hessian
at every iterate: the spline's value, gradient and Hessian at every sample point of the rows. Measured here at
``--points`` points spread over scenario E's room (the medium-far room with 8 robots has 28,195 clearance rows at its
start; E with 6 robots 80,876 rows in all):

- **casadi value**: casadi's B-spline node mapped over the points (``distance_spline(env).map(n)``);
- **scipy, one order**: scipy's ``NdBSpline`` for one derivative order; it takes one call per order;
- **before** (tmr up to stop 45): per iterate the casadi value twice (IPOPT's rows and the Jacobian's ``g`` output),
  scipy's gradient (2 calls) and scipy's Hessian (3 calls);
- **numpy pass**: :meth:`tmr.control.horizon_spline.ClearanceSpline.evaluate`, all six at once;
- **node**: :class:`tmr.control.horizon_spline.SplineRows` called through casadi with new points each time (what an
  iterate costs now: the rows, Jacobian and Hessian of one iterate share it).

Median of ``--repeats`` [ms]; the ratio is "before" over "node". Writes ``benchmarks/results/horizon_spline.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import casadi as ca
import numpy as np
from scipy.interpolate import NdBSpline

sys.path.insert(0, str(Path(__file__).resolve().parent))
from horizon_cases import median_ms  # noqa: E402
from provenance import source_version, versions  # noqa: E402

from tmr.control.horizon_spline import ClearanceSpline, SplineRows, distance_spline, spline_tables  # noqa: E402
from tmr.world.scenario import load_scenario  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, nargs="+", default=[5000, 28195, 80000])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    env = load_scenario("E").environment
    kx, ky, d = spline_tables(env)
    scipy_spline = NdBSpline((np.asarray(kx), np.asarray(ky)), d, 3)
    ours = ClearanceSpline(env)
    rng = np.random.default_rng(args.seed)
    rows = []
    for n in args.points:
        P = np.stack([rng.uniform(kx[3], kx[-4], n), rng.uniform(ky[3], ky[-4], n)])
        PT = np.ascontiguousarray(P.T)
        value = distance_spline(env).map(n)
        node = SplineRows(ours, n)
        sym = ca.MX.sym("P", 2, n)
        call = ca.Function("call", [sym], node(sym))
        shifts = [ca.DM(P + 1e-9 * k) for k in range(args.repeats + 2)]
        state = {"k": 0}

        def node_new_points(call=call, shifts=shifts, state=state):
            state["k"] = (state["k"] + 1) % len(shifts)
            call(shifts[state["k"]])

        def before(value=value, P=P, PT=PT):
            value(P)
            value(P)
            for nu in ((1, 0), (0, 1), (2, 0), (1, 1), (0, 2)):
                scipy_spline(PT, nu=nu)

        r = {
            "n": n,
            "casadi value": median_ms(lambda value=value, P=P: value(P), args.repeats),
            "scipy, one order": median_ms(lambda PT=PT: scipy_spline(PT, nu=(1, 0)), args.repeats),
            "before": median_ms(before, args.repeats),
            "numpy pass": median_ms(lambda P=P: ours.evaluate(P), args.repeats),
            "node": median_ms(node_new_points, args.repeats),
        }
        r["ratio"] = r["before"] / r["node"]
        rows.append(r)
        print({k: round(v, 2) if isinstance(v, float) else v for k, v in r.items()}, flush=True)
    cols = ["casadi value", "scipy, one order", "before", "numpy pass", "node"]
    lines = [
        "# The clearance spline per IPOPT iterate",
        "",
        f"`python benchmarks/horizon_spline.py --points {' '.join(map(str, args.points))} --repeats {args.repeats}`"
        f" ({source_version()}; {versions(['casadi', 'numpy', 'scipy'])}). Median of {args.repeats} [ms] at n points"
        " of scenario E's room; see the script's docstring for each column.",
        "",
        "| points | " + " | ".join(cols) + " | before / node |",
        "|---:|" + "---:|" * (len(cols) + 1),
    ]
    for r in rows:
        lines.append(f"| {r['n']:,} | " + " | ".join(f"{r[c]:.1f}" for c in cols) + f" | {r['ratio']:.1f}× |")
    lines += [
        "",
        "The node evaluates the value, gradient and Hessian once an iterate and reads and writes casadi's buffers"
        " directly; scipy's `NdBSpline` takes one call per derivative order and casadi's B-spline node gives only the"
        " value (its own second derivative costs more, see `formulations/horizon.md`).",
    ]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "horizon_spline.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
