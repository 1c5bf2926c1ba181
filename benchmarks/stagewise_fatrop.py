"""fatrop on a stage-wise chain OCP against IPOPT + MUMPS (issue 33's one unmeasured solver lever).

    python benchmarks/stagewise_fatrop.py [--stages 50 100 200 400] [--repeats 3]

The ``horizon`` NLP cannot be handed to fatrop as it is (``results/horizon_solvers.md``, "fatrop"): fatrop needs
stages, x_{k+1} = F(x_k, u_k), and the NLP is one of positions at every knot. What fatrop would gain, before anyone
writes a second transcription of the whole NLP, is measured here on an OCP of the same kind and size, written both
ways:

- *positional* (tmr's form, solved by IPOPT + MUMPS): the variables are the 8 robots' planar positions P_1 … P_N (16
  numbers a knot; P_0 = P_{-1} = the start, at rest); the acceleration a_k = P_{k+1} − 2 P_k + P_{k−1} is a row;
- *stage-wise* (solved by fatrop with the stages given, ``structure_detection="manual"``, and by IPOPT + MUMPS): the
  state x_k = (P_k, P_{k−1}) (32), the control u_k = P_{k+1} (16), the gap-closing rows x_{k+1} − (u_k, P_k) = 0, and
  x_0 = (start, start).

Both have the same cost, Σ_k 100 ‖a_k‖² + ‖P_{k+1} − P_k‖² + 100 ‖P_N − goal‖² + 100 ‖P_N − P_{N−1}‖², and the same
rows: at every knot k ≥ 1 each robot at least 0.3 m from the centres of five discs along its way (the clearance rows)
and neighbours 0.5–0.8 m apart (the spacing rows); ‖a_k‖∞ ≤ 0.2 for k = 0 … N − 1 (the acceleration rows). The
robots, a row 0.6 m apart, travel 12 m. The start is the straight line, which crosses the discs. Both solvers stop at
tol = 10⁻⁴ (fatrop's default 10⁻⁸ is not reached on this OCP: its dual infeasibility stalls near 2·10⁻⁵ with the
objective settled); IPOPT's linear solver is MUMPS with the AMD ordering, as ``horizon`` sets it; the rest are the
solvers' defaults — not ``horizon``'s IPOPT options (its adaptive barrier from 10⁻³, no scaling, its Hessian floors),
so the iteration counts here are this OCP's, not ``horizon``'s. There are no whole-horizon (fitness) rows.

Every run is its own process (one BLAS thread), the solver built (``casadi.nlpsol``) and then called from the start;
build and solve are timed apart. The answer is checked here, from the positions alone, against every row (the largest
violation in m, m² or per step²). Times are medians over ``--repeats``. Writes ``results/stagewise_fatrop.md`` and
``.csv``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

ROBOTS = 8
NP = 2 * ROBOTS  # positions a knot
START = np.array([[0.6 * r - 6.0, -2.0] for r in range(ROBOTS)]).ravel()
GOAL = START + np.tile([12.0, 0.0], ROBOTS)
DISCS = np.array([[2.0, -1.8], [4.0, -2.3], [6.0, -1.9], [8.0, -2.2], [3.0, -2.0]])
CLEAR2 = 0.3**2  # [m²]
SPACING2 = (0.5**2, 0.8**2)  # [m²]
A_MAX = 0.2  # [m a step²]
TOL = 1e-4

#: IPOPT's linear algebra as ``horizon`` sets it (``HorizonOptions``: MUMPS, AMD ordering)
IPOPT = {"linear_solver": "mumps", "mumps_pivot_order": 0}

RUNS = ("fatrop stage-wise", "ipopt stage-wise", "ipopt positional")


def _knot_rows(P):  # noqa: ANN001, ANN202  (casadi SX)
    """The clearance and spacing rows of one knot's positions: (expressions, lower, upper)."""
    import casadi as ca

    e, lo, hi = [], [], []
    for r in range(ROBOTS):
        p = P[2 * r : 2 * r + 2]
        for c in DISCS:
            e.append(ca.sumsqr(p - c))
            lo.append(CLEAR2)
            hi.append(np.inf)
        if r:
            e.append(ca.sumsqr(p - P[2 * r - 2 : 2 * r]))
            lo.append(SPACING2[0])
            hi.append(SPACING2[1])
    return e, lo, hi


def _line(k: int, n: int) -> np.ndarray:
    return START + (GOAL - START) * min(max(k, 0), n) / n


def stagewise(n: int) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]:
    """The stage-wise NLP: variables [x_0, u_0, x_1, u_1, …, x_N]; each stage's rows are its gap-closing rows, then
    its path rows. Returns (nlp, x0, lbg, ubg, fatrop's structure options)."""
    import casadi as ca

    nx, nu = 2 * NP, NP
    X = [ca.SX.sym(f"x{k}", nx) for k in range(n + 1)]
    U = [ca.SX.sym(f"u{k}", nu) for k in range(n)]
    w = [v for k in range(n + 1) for v in ([X[k], U[k]] if k < n else [X[k]])]
    g, lbg, ubg, ng, f = [], [], [], [], 0
    for k in range(n + 1):
        P, Pm = X[k][:NP], X[k][NP:]
        if k < n:  # fatrop's form: x_{k+1} − F(x_k, u_k)
            g.append(X[k + 1] - ca.vertcat(U[k], P))
            lbg += [0.0] * nx
            ubg += [0.0] * nx
        rows, lo, hi = [], [], []
        if k == 0:
            rows.append(X[0])
            lo += list(np.concatenate([START, START]))
            hi += list(np.concatenate([START, START]))
        else:
            e, l_, h_ = _knot_rows(P)
            rows += e
            lo += l_
            hi += h_
        if k < n:
            a = U[k] - 2 * P + Pm
            rows.append(a)
            lo += [-A_MAX] * NP
            hi += [A_MAX] * NP
            f += 100 * ca.sumsqr(a) + ca.sumsqr(U[k] - P)
        else:
            f += 100 * ca.sumsqr(P - GOAL) + 100 * ca.sumsqr(P - Pm)
        block = ca.vertcat(*rows)
        g.append(block)
        lbg += lo
        ubg += hi
        ng.append(int(block.numel()))
    x0 = np.concatenate(
        [np.concatenate([_line(k, n), _line(k - 1, n)] + ([_line(k + 1, n)] if k < n else [])) for k in range(n + 1)]
    )
    structure = dict(N=n, nx=[nx] * (n + 1), nu=[nu] * n + [0], ng=ng)
    return dict(x=ca.vertcat(*w), f=f, g=ca.vertcat(*g)), x0, np.array(lbg), np.array(ubg), structure


def positional(n: int) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray]:
    """tmr's form: variables P_1 … P_N, the start and the knot before it constants. Returns (nlp, x0, lbg, ubg)."""
    import casadi as ca

    P = [ca.DM(START)] + [ca.SX.sym(f"p{k}", NP) for k in range(1, n + 1)]
    g, lbg, ubg, f = [], [], [], 0
    for k in range(n):
        prev = P[k - 1] if k else ca.DM(START)
        a = P[k + 1] - 2 * P[k] + prev
        f += 100 * ca.sumsqr(a) + ca.sumsqr(P[k + 1] - P[k])
        g.append(a)
        lbg += [-A_MAX] * NP
        ubg += [A_MAX] * NP
        if k:
            e, lo, hi = _knot_rows(P[k])
            g += e
            lbg += lo
            ubg += hi
    e, lo, hi = _knot_rows(P[n])
    g += e
    lbg += lo
    ubg += hi
    f += 100 * ca.sumsqr(P[n] - GOAL) + 100 * ca.sumsqr(P[n] - P[n - 1])
    x0 = np.concatenate([_line(k, n) for k in range(1, n + 1)])
    return dict(x=ca.vertcat(*P[1:]), f=f, g=ca.vertcat(*g)), x0, np.array(lbg), np.array(ubg)


def violation(Q: np.ndarray) -> float:
    """The largest violation of any row by the positions Q (N + 1 knots × 16, knot 0 the start), from Q alone."""
    n = Q.shape[0] - 1
    full = np.vstack([START, Q])  # the knot before the start: at rest
    acc = full[2:] - 2 * full[1:-1] + full[:-2]  # a_0 … a_{N−1}
    worst = max(float(np.max(np.abs(acc))) - A_MAX, 0.0)
    R = Q[1:].reshape(n, ROBOTS, 2)
    d2 = ((R[:, :, None, :] - DISCS[None, None, :, :]) ** 2).sum(-1)
    worst = max(worst, float(CLEAR2 - d2.min()))
    s2 = ((R[:, 1:] - R[:, :-1]) ** 2).sum(-1)
    return max(worst, float(SPACING2[0] - s2.min()), float(s2.max() - SPACING2[1]), 0.0)


def child(run: str, n: int) -> dict:
    import casadi as ca

    t0 = time.perf_counter()
    if run == "ipopt positional":
        nlp, x0, lbg, ubg = positional(n)
    else:
        nlp, x0, lbg, ubg, structure = stagewise(n)
    formulate = time.perf_counter() - t0
    if run == "fatrop stage-wise":
        opts = dict(structure_detection="manual", **structure, print_time=False, fatrop=dict(print_level=0, tol=TOL))
        name = "fatrop"
    else:
        opts = dict(print_time=False, ipopt=dict(print_level=0, sb="yes", tol=TOL, **IPOPT))
        name = "ipopt"
    t0 = time.perf_counter()
    solver = ca.nlpsol("chain", name, nlp, opts)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = solver(x0=x0, lbg=lbg, ubg=ubg)
    solve = time.perf_counter() - t0
    st = solver.stats()
    x = np.asarray(sol["x"]).ravel()
    if run == "ipopt positional":
        Q = np.vstack([START, x.reshape(n, NP)])
    else:
        stride = 3 * NP  # x_k (32) then u_k (16)
        Q = np.vstack([x[k * stride : k * stride + NP] for k in range(n + 1)])
    return dict(
        run=run,
        stages=n,
        variables=int(nlp["x"].numel()),
        rows=int(nlp["g"].numel()),
        formulate_s=formulate,
        build_s=build,
        solve_s=solve,
        iterations=int(st.get("iter_count", -1)),
        success=bool(st.get("success")),
        status=f"{'solved' if st.get('success') else 'not solved'} ({st.get('return_status')})",
        objective=float(sol["f"]),
        violation=violation(Q),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--child", nargs=2, metavar=("RUN", "STAGES"), help=argparse.SUPPRESS)
    ap.add_argument("--stages", nargs="+", type=int, default=[50, 100, 200, 400])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="stagewise_fatrop", help="results file stem under benchmarks/results")
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]))))
        return
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    rows = []
    for n in args.stages:
        for rep in range(args.repeats):
            for run in RUNS:  # alternating, so that a slower minute of the machine hits every run alike
                p = subprocess.run(
                    [sys.executable, __file__, "--child", run, str(n)], capture_output=True, text=True, env=env
                )
                if p.returncode:
                    raise SystemExit(f"{run} at {n} stages failed: {p.stderr.strip().splitlines()[-1:]}")
                r = json.loads(p.stdout.strip().splitlines()[-1])
                r["repeat"] = rep
                rows.append(r)
                print(json.dumps(r), flush=True)
    RESULTS.mkdir(exist_ok=True)
    with open(RESULTS / f"{args.out}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    md = [
        "# fatrop on a stage-wise chain OCP against IPOPT + MUMPS",
        "",
        f"`python benchmarks/stagewise_fatrop.py --stages {' '.join(map(str, args.stages))} --repeats "
        f"{args.repeats}` — {when}, {os.cpu_count()} cores, one BLAS thread, {versions(['casadi', 'numpy'])}, "
        f"{source_version()}. The OCP and both forms: the script's docstring. Medians over the repeats (the "
        "iterations and objective were the same in every repeat unless a range is shown; the violation is the "
        "largest over the repeats).",
        "",
        "| stages | run | variables | rows | build [s] | iterations | solve [s] | ms / iteration | objective | "
        "largest violation | status | solve / positional IPOPT's |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def span(vals: list) -> str:
        lo, hi = min(vals), max(vals)
        if isinstance(lo, str):
            return lo if lo == hi else f"{lo}, {hi}"
        return f"{lo:g}" if lo == hi else f"{lo:g}–{hi:g}"

    for n in args.stages:
        base = statistics.median(r["solve_s"] for r in rows if r["stages"] == n and r["run"] == "ipopt positional")
        for run in RUNS:
            rs = [r for r in rows if r["stages"] == n and r["run"] == run]
            solve = statistics.median(r["solve_s"] for r in rs)
            per = statistics.median(1000 * r["solve_s"] / max(r["iterations"], 1) for r in rs)
            md.append(
                f"| {n} | {run} | {rs[0]['variables']:,} | {rs[0]['rows']:,} | "
                f"{statistics.median(r['build_s'] for r in rs):.2f} | {span([r['iterations'] for r in rs])} | "
                f"{solve:.2f} | {per:.1f} | {span([round(r['objective'], 3) for r in rs])} | "
                f"{max(r['violation'] for r in rs):.1e} | {span([r['status'] for r in rs])} | {solve / base:.2f} |"
            )
    (RESULTS / f"{args.out}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
