"""The measured try of ``formulations/horizon3d.md``, "Active winch": after the held-tension NLP of scenario I
converges, one more IPOPT solve with every tether's tension a variable within ±``--radius`` N of the qp schedule
(knot 0 fixed, the range and the rate as bounds and rows), warm-started from the converged held-tension solution;
then the least schedule for its positions. Prints status, time, f1–f4 and the tensions of both.

    PYTHONPATH=src python benchmarks/horizon3d_winch_trust.py [--radius 0.5]
"""

from __future__ import annotations

import argparse
import time

import casadi as ca
import numpy as np

from tmr.checks.drones import check_drone_plan
from tmr.control import horizon3d as h3
from tmr.control.horizon3d_winch import TetherRule, least_drone_tensions, thrust_need
from tmr.control.horizon_model import _solver_opts
from tmr.planner3d import build_drone_problem, drone_parameters, solve_drones
from tmr.world.drones import load_drone_scenario


def solve_round(model: h3._Model, x0: np.ndarray, opts: h3.DroneHorizonOptions, J_warm: float, rounds: int = 4):
    """Rounds of lazy rows from x0 as plan_horizon_drones does (no time limit): (x, status, iterations, seconds)."""
    vals = model.values(x0)
    masks = {n: model.near(n, vals[n]) for n in h3.DRONE_GROUPS if n in vals}
    x, its, t0, status = x0, 0, time.perf_counter(), ""
    for _ in range(rounds):
        tr = h3._Transcription(model, masks)
        nlp = dict(tr.nlp, f=tr.nlp["f"] / J_warm)
        solver = ca.nlpsol("trust", "ipopt", nlp, _solver_opts(opts, {}))
        sol = solver(x0=x, lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg)
        st = solver.stats()
        status, its = str(st["return_status"]), its + int(st["iter_count"])
        x = np.asarray(sol["x"], float).ravel()
        vals = model.values(x)
        viol, where = model.worst(vals)
        print(f"    round: {status}, {st['iter_count']} iterations, {tr.size} rows, worst {viol:.2e} ({where})")
        if status not in ("Solve_Succeeded", "Solved_To_Acceptable_Level") or viol <= 1e-6:
            break
        masks = {n: masks[n] | model.near(n, vals[n]) for n in masks}
    return x, status, its, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--radius", type=float, default=0.5)
    args = ap.parse_args()
    scenario = load_drone_scenario("I")
    params, tether = drone_parameters(scenario)
    problem = build_drone_problem(scenario, scenario.n_robots, params=params, tether=tether)
    warm, wm = solve_drones(problem, "qp")
    opts = h3.DroneHorizonOptions()
    held = warm.winch_tension
    m1 = h3._Model(problem, warm, opts)
    J_warm = h3._weighted(m1.warm_terms, opts)
    x1, st1, it1, t1 = solve_round(m1, m1.x0, opts, J_warm)
    print(f"held: {st1}, {it1} iterations, {t1:.1f} s, terms {m1.terms_fn(x1)}")
    lo = np.clip(held - args.radius, tether.winch_tension_min, tether.winch_tension_max)
    hi = np.clip(held + args.radius, tether.winch_tension_min, tether.winch_tension_max)
    lo[0] = hi[0] = held[0]
    m2 = h3._Model(problem, warm, opts, tension_box=(lo, hi))
    x0 = np.concatenate([x1, held.ravel()])
    x2, st2, it2, t2 = solve_round(m2, x0, opts, J_warm)
    T2 = x2[m2.x.shape[0] - held.size :].reshape(held.shape)
    print(f"free ±{args.radius} N: {st2}, {it2} iterations, {t2:.1f} s, terms {m2.terms_fn(x2)}")
    rule = TetherRule.of_problem(problem.world, tether, params, warm.base)
    for name, model, x, T in (("held", m1, x1, held), ("free", m2, x2, T2)):
        robots = model.positions(x).copy()
        robots[0] = warm.robots[0]
        robots[:, -1] = model.lead
        T = np.clip(T, tether.winch_tension_min, tether.winch_tension_max)
        for label, sched in (("NLP schedule", T), ("least", None)):
            if sched is None:
                sched, _ = least_drone_tensions(rule, warm.base, robots, T, tether.winch_tension, 2.0, warm.Ts)
            try:
                plan = h3._plan_of(robots, warm, {}, {}, tensions=sched)
            except Exception as exc:  # noqa: BLE001
                print(f"  {name} / {label}: no plan ({exc})")
                continue
            met = check_drone_plan(plan, scenario, params=params)
            need, pull = thrust_need(warm.base, robots, tether, sched)
            f = [round(float(v), 3) for v in met.fitness_raw]
            print(
                f"  {name} / {label}: passes {met.success} {met.failures[:1]}; f1-f4 {f} (qp "
                f"{[round(float(v), 3) for v in wm.fitness_raw]}); T mean {sched.mean():.3f} peak {sched.max():.3f} "
                f"N; pull mean {pull.mean():.3f} N; thrust need peak {need.max():.3f} mean {need.mean():.3f} N"
            )


if __name__ == "__main__":
    main()
