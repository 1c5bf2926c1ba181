"""Solver levers for the whole-horizon NLP at scale (issue 33): IPOPT options, linear solvers, fatrop.

    python benchmarks/horizon_solvers.py [--cases E6 walls5 medium5 narrow8] [--variants base ...] [--repeats 2]
    python benchmarks/horizon_solvers.py --probe     # which nlpsol/linear solvers load in this casadi build

Every run is the whole command line ``python -m tmr.plan ... --method horizon --no-plots`` in its **own process**
(cold: imports, the route, the ``qp`` warm start, the NLP), one at a time, with :func:`tmr.control.horizon.plan_horizon`
wrapped so that a variant's :class:`tmr.control.horizon.HorizonOptions` fields are passed to it (nothing else
changes: the planner, the fallbacks and the checks are the CLI's). The child prints one JSON line: the process time,
the NLP's result (optimal / best feasible iterate / warm start), stop, IPOPT iterations, the NLP time and the
ratios f_i(horizon) / f_i(qp) from ``metrics.json``. Times are medians over ``--repeats``; the machine has 2 cores
shared with other work, so single timings are noisy. Writes ``benchmarks/results/horizon_solvers.md`` and ``.csv``.

Cases: scenario E with 6 robots, and the slowest generated rooms of ``benchmarks/results/horizon_rooms.md``
(:func:`tmr.sweep.rooms.generate_room` of the room's seed, density and goal class; ``--seed 0``).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

#: case → (room name or None for a built-in scenario, scenario, robots or None for the scenario's own)
CASES: dict[str, tuple[str | None, str | None, int | None]] = {
    # E with 4 robots and the active winch, the damper and the sag allowance off: the NLP of
    # tests/test_winch_ground.py::test_horizon_with_the_active_winch_is_never_worse_than_qp
    "E4active": (None, "E", 4),
    "E4winch": (None, "E", 4),  # E, 4 robots, --set winch=active only (the CLI command of the fast-attempt work)
    "E": (None, "E", None),
    "A": (None, "A", None),
    "B": (None, "B", None),
    "C": (None, "C", None),
    "D": (None, "D", None),
    "E6": (None, "E", 6),
    "walls5": ("walls-corner-150917237", None, 5),
    "walls8": ("walls-corner-150917237", None, 8),
    "wallsfar5": ("walls-far-2884920346", None, 5),
    "wallsfar8": ("walls-far-2884920346", None, 8),
    "medium5": ("medium-far-634801725", None, 5),
    "medium8": ("medium-far-634801725", None, 8),
    "mediummid2": ("medium-mid-3677149159", None, 2),
    "mediumnear5": ("medium-near-742431198", None, 5),
    "mediumnear8": ("medium-near-742431198", None, 8),
    "narrow8": ("narrow-near-2642120001", None, 8),
    "narrow2": ("narrow-near-2642120001", None, 2),  # --robots auto picks 2 here
    "dense8": ("dense-near-533521220", None, 8),
    "sparse8": ("sparse-near-2968811710", None, 8),
}

#: variant → HorizonOptions fields (``ipopt`` merged last into IPOPT's options)
VARIANTS: dict[str, dict] = {
    "base": {},
    "log": {"ipopt": {"print_level": 5, "print_timing_statistics": "yes"}},  # IPOPT's iteration log on stdout
    "log_1e-3": {"min_hessian_perturbation": 1e-3, "ipopt": {"print_level": 5, "print_timing_statistics": "yes"}},
    "ma27": {"linear_solver": "ma27"},
    "ma57": {"linear_solver": "ma57"},
    "spral": {"linear_solver": "spral"},
    "mumps_auto": {"mumps_pivot_order": 7},
    "lbfgs": {"hessian": "limited-memory"},
    "mu_monotone": {"mu_strategy": "monotone", "mu_init": 1e-2},
    "mu_probing": {"ipopt": {"mu_oracle": "probing"}},
    "mu_loqo": {"ipopt": {"mu_oracle": "loqo"}},
    "no_perturb": {"min_hessian_perturbation": 1e-8},
    "perturb_1e-3": {"min_hessian_perturbation": 1e-3},  # the default until this change
    "perturb_1e-4": {"min_hessian_perturbation": 1e-4},
    "perturb_1e-5": {"min_hessian_perturbation": 1e-5},
    "perturb_1e-6": {"min_hessian_perturbation": 1e-6},
    "unscaled": {"scale_objective": False},
    # IPOPT's curvature test (Zavala and Chiang 2014): wrong inertia ignored when the step has positive curvature
    "negcurv": {"ipopt": {"neg_curv_test_tol": 1e-11}},
    "negcurv_1e-8": {"ipopt": {"neg_curv_test_tol": 1e-8}},
    # per-iteration cost: one round of 15 IPOPT iterations, no retry (the NLP is not solved: compare CPU only)
    "it15_mumps": {"max_iter": 15, "max_rounds": 1, "retry": False},
    "it15_spral": {"max_iter": 15, "max_rounds": 1, "retry": False, "linear_solver": "spral"},
    "it15_mumps_auto": {"max_iter": 15, "max_rounds": 1, "retry": False, "mumps_pivot_order": 7},
    "p4_restart": {"min_hessian_perturbation": 1e-4, "restart_rounds": True},
    "p5_restart": {"min_hessian_perturbation": 1e-5, "restart_rounds": True},
    "p5_spral": {"min_hessian_perturbation": 1e-5, "linear_solver": "spral"},
    "p5_mumps_auto": {"min_hessian_perturbation": 1e-5, "mumps_pivot_order": 7},
    "p5_probing": {"min_hessian_perturbation": 1e-5, "ipopt": {"mu_oracle": "probing"}},
    "p5_retry3": {"min_hessian_perturbation": 1e-5, "retry_ipopt": {"min_hessian_perturbation": 1e-3}},
    "perturb_1e-2": {"min_hessian_perturbation": 1e-2},
    "act_0.3": {"activation": 0.3},
    "rate_0.8": {"rate_activation": 0.8},
    "no_soc": {"ipopt": {"max_soc": 0}},
    "filter_reset": {"ipopt": {"accept_every_trial_step": "no", "watchdog_shortened_iter_trigger": 0}},
    "fatrop": {"solver": "fatrop"},
}


def _argv(case: str, tmp: Path, time_limit: float) -> list[str]:
    room_name, scenario, robots = CASES[case]
    argv = ["--method", "horizon", "--no-plots", "--out", str(tmp / "out"), "--seed", "0"]
    argv += ["--robots", str(robots)] if robots is not None else []
    if case == "E4active":
        sets = ("winch=active", "ground_clearance=0.05", "span_approach_rate=off", "sag_allowance=0")
        argv += [a for kv in sets for a in ("--set", kv)]
    if case == "E4winch":
        argv += ["--set", "winch=active"]
    argv += ["--time-limit", f"{time_limit:g}"]
    if scenario is not None:
        return ["--scenario", scenario, *argv]
    from tmr.sweep.room_runs import xy_arg
    from tmr.sweep.rooms import generate_room, room_spec, write_geojson

    room = generate_room(*room_spec(room_name))
    path = write_geojson(room, tmp / f"{room.name}.geojson")
    return ["--map", str(path), f"--base={xy_arg(room.base)}", f"--goal={xy_arg(room.goal)}", *argv]


def child(case: str, variant: str, time_limit: float = 60.0) -> dict:
    """One run of the CLI with the variant's options (in this process, which the parent started for it)."""
    t0 = time.perf_counter()
    import tmr.control.horizon as hz
    from tmr.plan import main

    options = dict(VARIANTS[variant])
    captured: dict = {}
    original = hz.plan_horizon

    def wrapped(problem, warm, **kw):  # the CLI's call with the variant's options added
        kw.update(options)
        plan = original(problem, warm, **kw)
        captured.update(knots=int(plan.t.size), rounds=plan.diagnostics.get("rounds"))
        return plan

    hz.plan_horizon = wrapped
    # per IPOPT attempt and iterate: (largest move of a robot coordinate from the attempt's start [m], rows left out of
    # the transcription that the iterate violates, the worst such clearance row [m])
    trace: list[list[tuple[float, int, float]]] = []
    if os.environ.get("HS_TRACE"):
        import numpy as np

        first: dict = {}
        eval_original = hz._IterationCallback.eval

        def traced(self, arg):  # the iteration callback, recording max |x − x_start| of every iterate
            x = np.asarray(arg[0], dtype=float).ravel()
            if self.iteration == 0:
                first[id(self)] = x.copy()
                trace.append([])
            move = round(float(np.max(np.abs(x - first[id(self)]))), 3)
            # rows left out of this transcription that the iterate violates: how many, and the worst clearance [m]
            model, vals = self.tr.model, self.tr.model.values(x)
            left_out, worst = 0, 0.0
            for name, idx in self.tr.index.items():
                v = model.violation(name, vals[name]).ravel(order="F")
                out_rows = np.ones(v.size, dtype=bool)
                out_rows[idx] = False
                bad = out_rows & (v > 1e-5)
                left_out += int(bad.sum())
                if name == "clearance" and bad.any():
                    worst = max(worst, float(v[bad].max()))
            trace[-1].append((move, left_out, round(worst, 3)))
            return eval_original(self, arg)

        hz._IterationCallback.eval = traced
    with tempfile.TemporaryDirectory(prefix="tmr-hs-") as tmp:
        tmpd = Path(tmp)
        argv = _argv(case, tmpd, time_limit)
        code = main(argv)
        files = {name: tmpd / "out" / f"{name}.json" for name in ("metrics", "timings")}
        read = {name: json.loads(f.read_text()) if f.is_file() else {} for name, f in files.items()}
        metrics, timings = read["metrics"], read["timings"]
    h = metrics.get("horizon", {}) or {}
    terms, warm = h.get("terms", {}), h.get("warm_start_terms", {})
    out = dict(
        case=case,
        variant=variant,
        exit=code,
        result=h.get("result"),
        stop=h.get("stop"),
        iterations=h.get("iterations"),
        rounds=h.get("rounds"),
        nlp_time=timings.get("nlp_time"),
        qp_time=timings.get("qp_time"),
        knots=captured.get("knots"),
        success=metrics.get("success"),
        process=time.perf_counter() - t0,
        wall_time=timings.get("wall_time"),
        floor=h.get("min_hessian_perturbation", "n/a"),  # the attempt that produced the plan (absent before it)
        fast=(h.get("fast_attempt") or {}).get("result"),
        fast_iterations=(h.get("fast_attempt") or {}).get("iterations"),
        fast_reason=(h.get("fast_attempt") or {}).get("reason"),
        fallback_start=(h.get("fast_attempt") or {}).get("fallback_start"),  # the fast attempt's iterate, if any
    )
    if trace:
        out["max_move_per_iteration"] = trace
    for k in ("f1", "f2", "f4"):
        if terms.get(k) is not None and warm.get(k):
            out[f"{k}_ratio"] = terms[k] / warm[k]
    return out


def run(case: str, variant: str, timeout: float, time_limit: float) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    t0 = time.perf_counter()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        proc = subprocess.run(
            [sys.executable, __file__, "--child", case, variant, "--time-limit", f"{time_limit:g}"],
            capture_output=True,
            text=True,
            timeout=timeout,
            env=env,
        )
    except subprocess.TimeoutExpired:
        return dict(case=case, variant=variant, exit=None, result="timeout", process=time.perf_counter() - t0)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        tail = (proc.stderr.strip().splitlines() or [""])[-1]
        return dict(case=case, variant=variant, exit=proc.returncode, result=f"error: {tail[:120]}", process=wall)
    out = json.loads(lines[-1])
    out["process"] = wall  # interpreter start to exit, seen from here
    out["cpu"] = cpu  # user + system CPU of the child and its descendants: less sensitive to other load than wall
    return out


_PROBE = """
import casadi as ca
x = ca.MX.sym("x", 2)
opts = {"ipopt": {"linear_solver": LS, "print_level": 0, "sb": "yes"}, "print_time": False, "error_on_fail": False}
s = ca.nlpsol("p", "ipopt", {"x": x, "f": ca.sumsqr(x - 1), "g": x[0] + x[1]}, opts)
s(x0=0, lbg=-10, ubg=10)
print(s.stats()["return_status"])
"""


def probe() -> str:
    """Which nlpsol plugins and IPOPT linear solvers load in this casadi build (each linear solver in its own
    process: a missing HSL library may crash it)."""
    import casadi as ca

    lines = [f"casadi {ca.__version__}"]
    for name in ("ipopt", "fatrop", "sqpmethod", "blocksqp", "madnlp", "knitro", "snopt", "worhp"):
        lines.append(f"nlpsol {name}: has_nlpsol = {ca.has_nlpsol(name)}")
    for ls in ("mumps", "ma27", "ma57", "ma86", "ma97", "pardiso", "pardisomkl", "spral", "wsmp"):
        proc = subprocess.run(
            [sys.executable, "-c", f"LS = {ls!r}" + _PROBE], capture_output=True, text=True, timeout=120
        )
        out = [ln for ln in proc.stdout.splitlines() if ln.strip()]
        got = out[-1] if proc.returncode == 0 and out else f"exit {proc.returncode}"
        lines.append(f"ipopt linear_solver {ls}: {got}")
    return "\n".join(lines)


def fatrop_probe(scenario: str, structure: str) -> dict:
    """fatrop on the first transcription of the horizon NLP of a built-in scenario (``--method horizon``'s rows from
    its ``qp`` plan), with casadi's automatic derivatives (fatrop takes the full symmetric Hessian, not IPOPT's
    triangle). ``structure``: fatrop's ``structure_detection`` ("auto": find the stages from the Jacobian; "none":
    one stage holding every variable). Returns the outcome or the error casadi raises."""
    import casadi as ca
    import numpy as np

    from tmr.control.horizon_model import _Model, _options, _Setup, _Transcription, _warm_start
    from tmr.control.horizon_spline import distance_spline
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    problem = build_problem(load_scenario(scenario), seed=0)
    warm = solve(problem, "qp")[0]
    su = _Setup(problem, _options({}))
    Qraw, info = _warm_start(su, warm)
    model = _Model(su, distance_spline(problem.env), bounds=info["warm_start_terms"])
    xv = model.project(model.x_of(Qraw))
    vals = model.values(xv)
    tr = _Transcription(model, {name: model.near(name, vals[name]) for name in model.rows})
    J0 = float(ca.Function("J", [model.x], [model.J])(xv))
    free = tr.lbx < tr.ubx
    out = dict(scenario=scenario, structure=structure, variables=int(tr.lbx.size), free=int(free.sum()),
               rows=int(tr.size), equality_rows=int(np.sum(tr.lbg == tr.ubg)))  # fmt: skip
    opts: dict = {"structure_detection": structure, "print_time": False, "error_on_fail": False}
    if structure == "auto":
        opts["equality"] = [bool(v) for v in tr.lbg == tr.ubg]
    nlp = dict(tr.nlp, f=tr.nlp["f"] / J0)
    t0 = time.perf_counter()
    try:
        solver = ca.nlpsol("horizon_fatrop", "fatrop", nlp, opts)
        out["build_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        sol = solver(x0=xv, lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg)
        out["solve_s"] = time.perf_counter() - t0
        st = solver.stats()
        out.update(status=st.get("return_status"), iterations=st.get("iter_count"), objective=float(sol["f"]))
    except Exception as exc:  # noqa: BLE001  (the finding is the message)
        out["error_after_s"] = time.perf_counter() - t0
        out["error"] = " ".join(str(exc).split())[:600]
    return out


def e4_library(options: dict, time_limit: float) -> dict:
    """The library call on the NLP of ``test_horizon_with_the_active_winch_is_never_worse_than_qp`` (E, 4 robots,
    active winch, damper and sag allowance off): ``plan_horizon(problem, qp_plan, time_limit, **options)``."""
    t0, c0 = time.perf_counter(), time.process_time()
    from tmr.control.horizon import HorizonInfeasible, plan_horizon
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    overrides = {"winch": "active", "ground_clearance": 0.05, "span_approach_rate": "off", "sag_allowance": 0.0}
    problem = build_problem(load_scenario("E"), n_robots=4, overrides=overrides)
    qp = solve(problem, "qp")[0]
    out: dict = dict(case="E4active-library", options=options, time_limit=time_limit)
    try:
        plan = plan_horizon(problem, qp, time_limit=time_limit, **options)
        d = plan.diagnostics
        out.update(result=d.get("horizon_result"), stop=d.get("horizon_stop"))
        out.update(objective=d.get("horizon_summary", {}).get("objective"), note=d.get("horizon_note"))
    except HorizonInfeasible as exc:
        d = exc.diagnostics
        out.update(result="HorizonInfeasible", stop=d.get("horizon_stop"), note=str(exc)[:400])
    # (round, attempt, IPOPT status, iterations, rows violated after it)
    out["rounds"] = [
        (r["round"], r["attempt"], r["status"], r["iterations"], r["violated"]) for r in d.get("round_log", [])
    ]
    out.update(wall=time.perf_counter() - t0, cpu=time.process_time() - c0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--child", nargs=2, metavar=("CASE", "VARIANT"), help=argparse.SUPPRESS)
    ap.add_argument("--cases", nargs="+", default=list(CASES))
    ap.add_argument("--variants", nargs="+", default=["base"])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=150.0, help="per process [s]")
    ap.add_argument("--time-limit", type=float, default=60.0, help="the CLI's --time-limit of the horizon NLP [s]")
    ap.add_argument("--probe", action="store_true")
    ap.add_argument("--e4-library", metavar="OPTIONS_JSON", help="the E4active NLP through the library call")
    ap.add_argument("--fatrop", nargs=2, metavar=("SCENARIO", "STRUCTURE"), help="fatrop on a scenario's NLP")
    ap.add_argument("--out", default="horizon_solvers", help="results file stem under benchmarks/results")
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(*args.child, time_limit=args.time_limit)))
        return
    if args.e4_library:
        print(json.dumps(e4_library(json.loads(args.e4_library), args.time_limit), default=str))
        return
    if args.fatrop:
        print(json.dumps(fatrop_probe(*args.fatrop)))
        return
    if args.probe:
        print(probe())
        return
    rows = []
    for case in args.cases:
        for variant in args.variants:
            for rep in range(args.repeats):
                r = run(case, variant, args.timeout, args.time_limit)
                r["repeat"] = rep
                rows.append(r)
                print(json.dumps(r), flush=True)
    keys = sorted({k for r in rows for k in r})
    with open(RESULTS / f"{args.out}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    md = [
        f"`python benchmarks/horizon_solvers.py --cases {' '.join(args.cases)} --variants {' '.join(args.variants)} "
        f"--repeats {args.repeats} --time-limit {args.time_limit:g}` — {when}, {os.cpu_count()} cores (shared), "
        f"{versions(['casadi', 'numpy', 'scipy'])}, {source_version()}.\n",
        "| case | variant | result | stop | IPOPT iterations | NLP [s] | process [s] | process CPU [s] | f1 / qp | "
        "f2 / qp | f4 / qp |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for case in args.cases:
        for variant in args.variants:
            rs = [r for r in rows if r["case"] == case and r["variant"] == variant]
            first = rs[0]

            def med(k: str, rs: list = rs) -> str:
                v = [r[k] for r in rs if isinstance(r.get(k), (int, float))]
                return f"{statistics.median(v):.1f}" if v else "–"

            def ratio(k: str, first: dict = first) -> str:
                v = first.get(k)
                return f"{v:.3f}" if isinstance(v, (int, float)) else "–"

            md.append(
                f"| {case} | {variant} | {first.get('result')} | {first.get('stop')} | {first.get('iterations')} | "
                f"{med('nlp_time')} | {med('process')} | {med('cpu')} | {ratio('f1_ratio')} | {ratio('f2_ratio')} | "
                f"{ratio('f4_ratio')} |"
            )
    print("\n".join(md))
    (RESULTS / f"{args.out}.table.md").write_text("\n".join(md) + "\n")


if __name__ == "__main__":
    main()
