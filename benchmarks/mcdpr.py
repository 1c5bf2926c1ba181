"""MoPICK mobile cable-driven parallel robot (Rasheed 2019): capacity margin, tension distribution, two-stage plan.

    python benchmarks/mcdpr.py [--repeats 5] [--batch 2401] [--lp-poses 20] [--hull-poses 200] [--plan-repeats 3]

A benchmark, not a test. Random MoPICK poses (seeded: platform over a 2 m × 2 m square at 0.5-1.0 m, bases around
it, random headings) are evaluated by

* capacity margin μ (Rasheed 2019 eq. 8) — ``numpy batched``: :func:`tmr.mcdpr.capacity.capacity` (W, tipping bounds,
  zonotope hyperplane shifting) on a batch of ``--batch`` poses in one call (2401 = 7⁴, one stage-1 iteration);
  ``numpy 1 pose``: the same call per pose; ``cvxpy LP``: :func:`tmr.mcdpr.capacity_lp.capacity_lp` (a DPP support LP
  per facet normal, HiGHS); ``hull``: vertex enumeration + Qhull (:mod:`tmr.mcdpr.capacity_hull`);
* tension distribution (min 2-norm for the platform weight) — closed form batched / per pose vs the cvxpy QP
  (Clarabel) and the min-max LP (HiGHS);
* the whole two-stage plan of the shipped ``fig2`` scene (:func:`tmr.mcdpr.planner.plan`).

Every method is checked against the batched result (max |Δμ|, max |Δt|). Timings are medians over ``--repeats``
(``--plan-repeats`` for the plan). BLAS runs on one thread unless OPENBLAS_NUM_THREADS/OMP_NUM_THREADS is set. Writes
``benchmarks/results/mcdpr.md``, ``mcdpr.csv``, ``mcdpr_topview.png``, ``mcdpr_mu.png`` and ``mcdpr_tensions.png``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import importlib.metadata
import io
import os
import platform
import statistics
import sys
import time
from pathlib import Path

THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
if not any(v in os.environ for v in THREAD_VARS):
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = "1"

import numpy as np  # noqa: E402

from tmr.io.outputs import atomic_write_text  # noqa: E402
from tmr.mcdpr.capacity import capacity, required_wrench_set  # noqa: E402
from tmr.mcdpr.capacity_hull import box_rows, capacity_margin_hull  # noqa: E402
from tmr.mcdpr.capacity_lp import capacity_lp  # noqa: E402
from tmr.mcdpr.planner import PlannerParams, check, plan  # noqa: E402
from tmr.mcdpr.robot import mopick  # noqa: E402
from tmr.mcdpr.scene import load_scene  # noqa: E402
from tmr.mcdpr.tension import TensionProblem, closed_form, closed_form_batch  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
TARGET_US_PER_POSE = 20.0
TARGET_PLAN_S = 10.0


def poses(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    P = np.column_stack([rng.uniform(0, 2, (n, 2)), rng.uniform(0.5, 1.0, n)])
    B = np.array([[0, 0], [2, 0], [2, 2], [0, 2.0]]) + rng.normal(0, 0.5, (n, 4, 2))
    H = rng.uniform(-np.pi, np.pi, (n, 4))
    return P, B, H


def timed(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--batch", type=int, default=2401)
    ap.add_argument("--lp-poses", type=int, default=20)
    ap.add_argument("--hull-poses", type=int, default=200)
    ap.add_argument("--plan-repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    load0 = os.getloadavg()
    R = mopick()
    rws = required_wrench_set(R, (1.0, 1.0, 1.0))
    f = np.array([0.0, 0.0, R.platform_mass * R.gravity])
    P, B, H = poses(args.batch, args.seed)
    rows: list[dict[str, object]] = []

    def row(group: str, method: str, n: int, seconds: float, err: float | str, note: str = "") -> None:
        rows.append(
            {
                "group": group,
                "method": method,
                "poses": n,
                "us_per_pose": 1e6 * seconds / n,
                "max_abs_diff": err,
                "note": note,
            }
        )

    # ---------------------------------------------------------------- capacity margin
    capacity(R, P[:10], B[:10], H[:10], rws)  # warm-up
    sec, cap = timed(lambda: capacity(R, P, B, H, rws), args.repeats)
    ref = cap.mu
    row(
        "capacity margin μ",
        "numpy batched (zonotope)",
        args.batch,
        sec,
        0.0,
        f"target ≤ {TARGET_US_PER_POSE:g} µs/pose",
    )
    n1 = min(args.batch, 500)
    sec, mu1 = timed(lambda: np.array([float(capacity(R, P[i], B[i], H[i], rws).mu) for i in range(n1)]), args.repeats)
    row("capacity margin μ", "numpy, one call per pose", n1, sec, float(np.max(np.abs(mu1 - ref[:n1]))))
    nl = args.lp_poses
    capacity_lp(R, P[:1], B[:1], H[:1], rws)  # compile the DPP problem once
    sec, mul = timed(lambda: capacity_lp(R, P[:nl], B[:nl], H[:nl], rws), max(1, args.repeats // 2))
    row("capacity margin μ", "cvxpy support LP per facet (HiGHS)", nl, sec, float(np.max(np.abs(mul - ref[:nl]))))
    nh = args.hull_poses

    def hull() -> np.ndarray:
        return np.array([capacity_margin_hull(cap.W[i], *box_rows(cap.lo[i], cap.hi[i]), rws) for i in range(nh)])

    sec, muh = timed(hull, args.repeats)
    row("capacity margin μ", "vertices + Qhull (independent)", nh, sec, float(np.max(np.abs(muh - ref[:nh]))))
    frac = float(np.mean(ref > 0))

    # ---------------------------------------------------------------- tension distribution
    sec, cf = timed(lambda: closed_form_batch(cap.W, f, cap.lo, cap.hi), args.repeats)
    feas = np.flatnonzero(cf.feasible)
    row("tension distribution", "closed form batched (null space)", args.batch, sec, 0.0, f"{len(feas)} feasible")
    idx = feas[:n1]
    sec, t1 = timed(lambda: np.array([closed_form(cap.W[i], f, cap.lo[i], cap.hi[i]) for i in idx]), args.repeats)
    row("tension distribution", "closed form, one call per pose", len(idx), sec, float(np.max(np.abs(t1 - cf.t[idx]))))
    for name, obj in (("cvxpy QP min ‖t‖₂ (Clarabel)", "2norm"), ("cvxpy LP min max t (HiGHS)", "maxnorm")):
        prob = TensionProblem(3, 4, 8, obj)  # type: ignore[arg-type]
        il = feas[:nl]
        prob.solve(cap.W[il[0]], f, *box_rows(cap.lo[il[0]], cap.hi[il[0]]))

        def solve_all(prob: TensionProblem = prob, il: np.ndarray = il) -> np.ndarray:
            return np.array([prob.solve(cap.W[i], f, *box_rows(cap.lo[i], cap.hi[i])) for i in il])

        sec, tq = timed(solve_all, max(1, args.repeats // 2))
        err = float(np.max(np.abs(tq - cf.t[il]))) if obj == "2norm" else "— (other objective)"
        row("tension distribution", name, len(il), sec, err)

    # ---------------------------------------------------------------- whole plan
    scene = load_scene("fig2")
    env = scene.validate(R)
    params = PlannerParams()
    plans = []
    walls = []
    for _ in range(args.plan_repeats):
        t0 = time.perf_counter()
        plans.append(plan(R, scene, params, env))
        walls.append(time.perf_counter() - t0)
    res = plans[-1]
    chk = check(R, env, res)
    s1 = statistics.median(p.times["stage1"] for p in plans)
    s2 = statistics.median(p.times["stage2"] for p in plans)
    wall = statistics.median(walls)
    combos = sum(s["combinations"] for s in res.stage1)
    from tmr.mcdpr import plot

    plot.plot_topview(R, scene, env, res, RESULTS / "mcdpr_topview.png")
    plot.plot_mu(res, RESULTS / "mcdpr_mu.png")
    plot.plot_tensions(R, res, RESULTS / "mcdpr_tensions.png")

    # ---------------------------------------------------------------- report
    total = time.perf_counter() - t_start
    load1 = os.getloadavg()
    vers = ", ".join(
        f"{m} {importlib.metadata.version(m)}" for m in ("numpy", "scipy", "cvxpy", "highspy", "clarabel", "shapely")
    )
    threads = ", ".join(f"{v}={os.environ[v]}" for v in THREAD_VARS if v in os.environ)
    buf = io.StringIO()
    w = buf.write
    w("# MoPICK: capacity margin, tension distribution, two-stage plan\n\n")
    w(f"`python benchmarks/{Path(__file__).name} {' '.join(argv if argv is not None else sys.argv[1:])}`".rstrip())
    w(f" — {datetime.date.today().isoformat()}, `{platform.machine()}`, nproc {os.cpu_count()}, ")
    w(f"Python {platform.python_version()}; {vers}; {threads}.\n")
    w(f"Total run time {total:.0f} s; load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end.\n\n")
    w(f"Poses: {args.batch} random MoPICK poses (seed {args.seed}; {100 * frac:.0f} % with μ > 0), RWS = platform ")
    w("weight ± 1 N box (8 vertices). Formulations: [capacity](../../formulations/capacity.md), ")
    w("[tension](../../formulations/tension.md). *µs/pose* = median wall time of the call / poses; ")
    w("*max |Δ|* = largest difference to the batched numpy result on the same poses (μ [N] or t [N]).\n\n")
    w("| group | method | poses | µs/pose | max abs diff | note |\n|---|---|---:|---:|---:|---|\n")
    for r in rows:
        d = r["max_abs_diff"]
        ds = f"{d:.1e}" if isinstance(d, float) else str(d)
        w(f"| {r['group']} | {r['method']} | {r['poses']} | {r['us_per_pose']:.2f} | {ds} | {r['note']} |\n")
    w("\n## Two-stage plan of the shipped `fig2` scene\n\n")
    w(f"Median of {args.plan_repeats} runs (default `PlannerParams`: d_j = {params.d_base} m, d_MP = ")
    w(f"{params.d_platform} m). Paper (MATLAB, its own scene): 109.9 min (bases) + 15.92 min (platform).\n\n")
    w("| way-points | samples | stage-1 combinations | stage 1 [s] | stage 2 [s] | whole plan [s] | μ min [N] | ")
    w("max tension [N] | checks |\n|---:|---:|---:|---:|---:|---:|---:|---:|---|\n")
    w(f"| {len(res.waypoints)} | {len(res.mu)} | {combos} | {s1:.2f} | {s2:.2f} | {wall:.2f} | {chk.mu_min:.3f} | ")
    w(f"{chk.max_tension:.2f} | {'ok' if chk.ok else '; '.join(chk.messages)} |\n\n")
    w(f"Target: whole plan < {TARGET_PLAN_S:g} s. Figures: `mcdpr_topview.png` (cf. Rasheed 2019 Fig. 4), ")
    w("`mcdpr_mu.png`, `mcdpr_tensions.png`.\n")
    RESULTS.mkdir(exist_ok=True)
    atomic_write_text(RESULTS / "mcdpr.md", buf.getvalue())
    cbuf = io.StringIO()
    cw = csv.DictWriter(cbuf, fieldnames=list(rows[0]), lineterminator="\n")
    cw.writeheader()
    cw.writerows(rows)
    cw.writerow(
        {
            "group": "plan fig2",
            "method": "two-stage planner",
            "poses": len(res.mu),
            "us_per_pose": 1e6 * wall,
            "max_abs_diff": "",
            "note": f"stage1 {s1:.3f} s; stage2 {s2:.3f} s; mu_min {chk.mu_min:.4f}; max_tension {chk.max_tension:.3f}",
        }
    )
    atomic_write_text(RESULTS / "mcdpr.csv", cbuf.getvalue())
    print(buf.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
