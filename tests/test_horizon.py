"""Whole-horizon NLP (``tmr.control.horizon``): feasibility, optimality, cost vs warm start, fallbacks (never
worse than the warm start), time limit, clear failures, no import of the planner."""

from __future__ import annotations

import ast
import dataclasses
import io
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Point

import tmr.control.horizon as horizon_module
import tmr.control.horizon_model as horizon_model
import tmr.control.horizon_pool as horizon_pool
from tmr.checks.metrics import fitness
from tmr.control.clik import Plan
from tmr.control.horizon import (
    DEFAULT_TIME_LIMIT,
    GROUPS,
    HorizonInfeasible,
    HorizonOptions,
    distance_spline,
    objective,
    objective_terms,
    plan_horizon,
    samples_needed,
)
from tmr.control.horizon_spline import ClearanceSpline
from tmr.errors import InfeasibleStep, ParameterError, TmrError
from tmr.model.chain import Chain
from tmr.model.params import ChainParams, PathParams, PinvParams, QPParams, TaskParams, TimeParams
from tmr.planner import Problem, check, solve, span_limits
from tmr.route.path import time_law
from tmr.world.environment import Environment
from tmr.world.scenario import Scenario

COLUMN = (4.2, 2.0)  # a disc column of radius 0.3 m (0.8 m once inflated) right under the follower's tether
PAST = ((3.2, 2.9), (3.9, 2.95), (4.6, 2.9))  # the leader passes above the column: feasible
THROUGH = ((3.2, 2.9), (4.2, 2.3), (5.2, 2.9))  # the reference dips 0.5 m into the inflated column
GRAZING = ((3.2, 2.9), (4.2, 2.8), (5.2, 2.9))  # the reference touches the inflated column (clearance ≈ 0 < d_safe)


def small_problem(waypoints=PAST, T_end: float = 1.5, limits=None, columns=(COLUMN,)) -> Problem:
    """N = 2 robots in an 8 m × 5 m room with one column, K = 30 steps (T_end = 1.5 s, Ts = 0.05 s)."""
    env = Environment.from_geometry([Point(*c).buffer(0.3, 64) for c in columns], (0.0, 0.0, 8.0, 5.0))
    start = np.array([[2.0, 2.5], list(waypoints[0])])
    sc = Scenario(
        name="small",
        description="two robots past a column",
        environment=env,
        base=np.array([0.8, 2.5]),
        goal=np.array(waypoints[-1]),
        start=start,
        n_robots=2,
    )
    chain = Chain(2, base=sc.base)
    cp = ChainParams()
    lim = span_limits(2, cp) if limits is None else np.asarray(limits, float)
    traj = time_law(np.array(waypoints), T_end=T_end, Ts=0.05)
    return Problem(
        sc,
        chain,
        cp,
        TimeParams(T_end=T_end),
        PathParams(),
        TaskParams(),
        PinvParams(),
        QPParams(),
        lim,
        chain.q_from_positions(start),
        traj,
        0,
    )


@pytest.fixture(scope="module")
def solved():
    problem = small_problem()
    warm, warm_metrics = solve(problem, "qp")
    assert warm.success
    plan = plan_horizon(problem, warm)
    return problem, warm, warm_metrics, plan


def test_plan_fields_and_exact_check(solved):
    problem, warm, _, plan = solved
    K, n = 30, problem.chain.dof
    assert isinstance(plan, Plan) and plan.method == "horizon" and plan.success and plan.failure is None
    assert plan.q.shape == (K + 1, n) and plan.qdot.shape == (K + 1, n)
    np.testing.assert_array_equal(plan.q[0], problem.q0)
    np.testing.assert_allclose(plan.qdot[:-1], np.diff(plan.q, axis=0) / 0.05, atol=1e-12)
    assert np.all(plan.qdot[-1] == 0)
    np.testing.assert_allclose(plan.robots, np.stack([problem.chain.robots(q) for q in plan.q]), atol=1e-12)
    np.testing.assert_allclose(plan.spans, plan.q[:, 1::2])
    np.testing.assert_allclose(plan.reference, problem.trajectory.x)
    assert plan.wall_time > 0 and plan.diagnostics["total_time"] <= plan.wall_time
    # tmr.planner.check: exact shapely clearances of robots and tether segments, spans, separation, goal
    metrics = check(plan, problem.env)
    assert plan.success and metrics.n_violation_steps == 0
    assert metrics.min_robot_clearance > 0 and metrics.min_tether_clearance > 0
    assert metrics.min_separation >= 2 * problem.chain_params.safety_radius
    # the clearance constraint is active somewhere (the column is in the way), at d_safe = 0.05 m in the spline field
    assert plan.diagnostics["min_field_clearance"][1:].min() == pytest.approx(0.05, abs=1e-4)
    # equality leader: on the reference at every knot
    assert metrics.max_tracking_error < 1e-6 and metrics.final_leader_error < 1e-6


def test_rate_limits_hold(solved):
    problem, _, _, plan = solved
    p, Ts = problem.qp_params, 0.05
    tol = 1e-6
    qd = plan.qdot
    assert np.all(np.abs(qd[:, 0::2]) <= p.joint_speed_max + tol)
    assert np.all(np.abs(qd[:, 1::2]) <= p.span_speed_max + tol)
    qdd = np.diff(np.vstack([np.zeros((1, qd.shape[1])), qd]), axis=0) / Ts
    assert np.all(np.abs(qdd) <= p.accel_max + tol)
    v = np.diff(plan.robots, axis=0) / Ts
    assert np.all(np.abs(v) <= p.robot_speed_max + tol)
    vz = np.concatenate([np.zeros((1,) + v.shape[1:]), v, np.zeros((1,) + v.shape[1:])])
    assert np.all(np.abs(np.diff(vz, axis=0) / Ts) <= p.robot_accel_max + tol)
    lo, hi = problem.span_limits[:, 0] + p.span_margin, problem.span_limits[:, 1] - p.span_margin
    assert np.all(plan.spans[1:] >= lo - tol) and np.all(plan.spans[1:] <= hi + tol)


def test_ipopt_reports_optimality(solved):
    _, _, _, plan = solved
    d = plan.diagnostics
    assert d["ipopt_status"] == "Solve_Succeeded" and d["ipopt_success"]
    assert d["constraint_violation"] <= 1e-6
    assert d["ipopt_iterations"] >= 1 and d["rounds"] >= 1
    assert d["samples_per_link"] == samples_needed(5.596082144752006, 0.5, 0.05, 0.015) == 15


def test_cost_never_above_warm_start_and_beats_qp(solved):
    problem, warm, warm_metrics, plan = solved
    J_warm, J_opt = objective(warm.q, problem), objective(plan.q, problem)
    assert J_opt <= J_warm
    assert J_opt <= plan.diagnostics["objective_warm_start"]
    assert plan.diagnostics["objective"] == pytest.approx(J_opt, rel=1e-9)
    metrics = check(plan, problem.env)
    assert metrics.f1 < warm_metrics.f1 and metrics.f4 < warm_metrics.f4


def test_fast_attempt_first_and_its_fallback_to_the_default_floor(solved):
    """The fast attempt (min_hessian_perturbation 1e-5) solves the small problem; forced to stop after one iteration
    (fast_max_iter=1) it falls back to 1e-3 from the warm start — the very plan of a run without the fast attempt,
    never worse than qp in any term — and the note and the summary say which attempt produced the plan."""
    problem, warm, warm_metrics, plan = solved
    fast = plan.diagnostics["horizon_summary"]["fast_attempt"]
    assert fast["result"] == "accepted" and fast["min_hessian_perturbation"] == 1e-5
    assert plan.diagnostics["horizon_summary"]["min_hessian_perturbation"] == 1e-5
    assert "IPOPT min_hessian_perturbation 1e-05 (exact Hessian, the fast attempt)" in plan.diagnostics["horizon_note"]
    assert {r["phase"] for r in plan.diagnostics["round_log"]} == {"fast"}
    without = plan_horizon(problem, warm, fast_min_hessian_perturbation=None)
    assert without.diagnostics["horizon_summary"]["fast_attempt"] is None
    assert {r["phase"] for r in without.diagnostics["round_log"]} == {"default"}
    assert "IPOPT min_hessian_perturbation 0.001 (Gauss–Newton Hessian);" in without.diagnostics["horizon_note"]
    fell = plan_horizon(problem, warm, fast_max_iter=1)
    d = fell.diagnostics
    assert d["horizon_result"] == "optimal" and d["horizon_stop"] == "converged"
    assert d["horizon_summary"]["fast_attempt"] == dict(
        min_hessian_perturbation=1e-5,
        hessian="exact",
        max_iter_per_round=1,
        iterations=1,
        rounds=1,
        result="fell_back",
        reason="round 1 stopped with 'Maximum_Iterations_Exceeded' after 1 iterations",
    )
    assert d["horizon_summary"]["min_hessian_perturbation"] == 1e-3
    assert (
        "IPOPT min_hessian_perturbation 1e-05 (exact Hessian) first (1 iterations): round 1 stopped with "
        "'Maximum_Iterations_Exceeded' after 1 iterations, so fell back to 0.001 (Gauss–Newton Hessian) from the "
        "warm start" in d["horizon_note"]
    )
    np.testing.assert_array_equal(fell.q, without.q)  # the fallback is the procedure without the fast attempt
    both = without.diagnostics["ipopt_iterations"] + 1
    assert d["ipopt_iterations"] == both and d["horizon_summary"]["iterations"] == both  # both attempts count
    assert [r["phase"] for r in d["round_log"]][:2] == ["fast", "fallback"]
    assert d["rounds"] == len(d["round_log"])
    metrics = check(fell, problem.env)
    assert metrics.n_violation_steps == 0
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(warm_metrics, f) * (1 + 1e-9)


def test_the_recorded_floor_is_the_one_ipopt_used(solved):
    """An ``ipopt`` ``min_hessian_perturbation`` is merged last and wins over every attempt's own (no fast attempt):
    the round log, the summary and the note give that floor, not the default 10⁻³. And for a kept iterate the floor
    is the one of the round and attempt it came from (a retry's 10⁻², the fast attempt's 10⁻⁵), for an optimum the
    last round's."""
    import tmr.control.horizon as horizon_module
    from tmr.control.horizon_pool import _Candidate

    problem, warm, _, _ = solved
    d = plan_horizon(problem, warm, ipopt={"min_hessian_perturbation": 2e-3}).diagnostics
    assert d["horizon_result"] == "optimal" and d["horizon_summary"]["fast_attempt"] is None
    assert d["round_log"] and all(r["min_hessian_perturbation"] == 2e-3 for r in d["round_log"])
    assert d["horizon_summary"]["min_hessian_perturbation"] == 2e-3
    assert "IPOPT min_hessian_perturbation 0.002 (Gauss–Newton Hessian);" in d["horizon_note"]
    opts = horizon_model._options({})
    rounds = [
        dict(round=1, phase="fast", attempt="primary", min_hessian_perturbation=1e-5),
        dict(round=1, phase="fallback", attempt="primary", min_hessian_perturbation=1e-3),
        dict(round=1, phase="fallback", attempt="retry", min_hessian_perturbation=1e-2),
    ]
    Q = np.zeros(1)

    def floor(result: str, detail: str) -> float | None:
        return horizon_module._floor_used(opts, rounds, rounds[1:], _Candidate(Q, 0.0, result, detail, Q))

    assert floor("best_feasible_iterate", "its best feasible iterate (round 1 retry, iteration 7)") == 1e-2
    assert floor("best_feasible_iterate", "its best feasible iterate (round 1 fast, iteration 6)") == 1e-5
    assert floor("best_feasible_iterate", "its best feasible iterate (round 1 primary, iteration 3)") == 1e-3
    assert floor("best_feasible_iterate", "its best feasible iterate (, iteration 3)") == 1e-3  # a window's
    assert floor("optimal", "the optimum") == 1e-2  # the retry converged: the phase's last round entry
    assert floor("warm_start", "the qp plan") is None


def test_fallback_starts_from_the_fast_attempts_best_feasible_iterate(solved):
    """Cut at 12 iterations, the fast attempt falls back; its best feasible iterate (every row, cheaper than qp) is
    where the 1e-3 fallback starts — the note and the summary say so — and the plan is never worse than qp: the
    fitness rows still refer to the qp plan. Fewer fallback iterations than from the warm start."""
    problem, warm, warm_metrics, _ = solved
    fell = plan_horizon(problem, warm, fast_max_iter=12)
    d = fell.diagnostics
    fast = d["horizon_summary"]["fast_attempt"]
    assert fast["result"] == "fell_back" and fast["iterations"] == 12
    assert fast["fallback_start"].startswith("round 1 fast, iteration ")
    seed_cost = float(fast["fallback_start"].rsplit("objective ", 1)[1])
    assert seed_cost < d["objective_warm_start"]
    assert (
        "so fell back to 0.001 (Gauss–Newton Hessian) from the fast attempt's best feasible iterate (round 1 fast, "
        "iteration " in (d["horizon_note"])
    )
    assert d["horizon_result"] == "optimal" and d["objective"] <= seed_cost
    fallback = [r for r in d["round_log"] if r["phase"] == "fallback"]
    assert fallback and fallback[0]["min_hessian_perturbation"] == 1e-3
    cold = plan_horizon(problem, warm, fast_min_hessian_perturbation=None)  # 1e-3 from the warm start
    assert sum(r["iterations"] for r in fallback) < cold.diagnostics["ipopt_iterations"]
    metrics = check(fell, problem.env)
    assert metrics.n_violation_steps == 0
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(warm_metrics, f) * (1 + 1e-9)
    few = plan_horizon(problem, warm, fast_max_iter=1)  # no feasible iterate cheaper than qp yet: the warm start
    assert "fallback_start" not in few.diagnostics["horizon_summary"]["fast_attempt"]
    assert "so fell back to 0.001 (Gauss–Newton Hessian) from the warm start" in few.diagnostics["horizon_note"]


def test_objective_terms_are_the_paper_fitness(solved):
    problem, warm, _, plan = solved
    for p in (warm, plan):
        terms = objective_terms(p.q, 0.05, problem.trajectory.x, problem.chain.base)
        f1, f2, f3, f4 = fitness(p, 0.05)
        assert terms["f1"] == pytest.approx(f1, rel=1e-12)
        assert terms["f2"] == pytest.approx(f2, rel=1e-12)
        assert terms["f3"] == pytest.approx(f3, rel=1e-9, abs=1e-18)
        assert terms["f4"] == pytest.approx(f4, rel=1e-12)


def test_start_outside_span_limit_names_group_and_knot():
    problem = small_problem(limits=[[0.5, 5.596], [1.0, 1.2]])  # the start's second span is 1.26 m
    warm = solve(problem, "qp")[0]  # any plan: the start is checked first
    with pytest.raises(HorizonInfeasible) as info:
        plan_horizon(problem, warm_start=warm)
    err = info.value
    assert isinstance(err, InfeasibleStep) and isinstance(err, TmrError)
    assert err.groups == ["span"] and err.status == "start_infeasible"
    (v,) = err.violations
    assert v.knot == 0 and "tether 2" in v.item and v.amount == pytest.approx(math.hypot(1.2, 0.4) - 1.2, abs=1e-9)
    assert "span" in str(err) and "knot 0" in str(err) and "d_max" in str(err)


def test_unreachable_reference_reports_the_overstretched_tethers():
    """Both tethers limited to 1.5 m: the end of the reference is out of reach; IPOPT proves local infeasibility and
    the message names the span rows at knots where the reference is beyond the chain's reach (the leader is on its
    reference by construction: a fixed variable)."""
    problem = small_problem(limits=[[0.5, 1.5], [1.0, 1.5]])
    warm = solve(problem, "qp")[0]
    assert not warm.success  # the qp plan fails too: no fallback
    with pytest.raises(HorizonInfeasible) as info:
        plan_horizon(problem, warm)
    err = info.value
    assert err.status == "Infeasible_Problem_Detected" and "span" in err.groups
    reach = 1.5 + 1.5 - 2 * problem.qp_params.span_margin
    far = np.linalg.norm(problem.trajectory.x - problem.chain.base, axis=1) > reach
    worst = max((v for v in err.violations if v.group == "span"), key=lambda v: v.amount)
    assert far[worst.knot]
    assert "span" in str(err) and f"knot {worst.knot}" in str(err)


def test_reference_through_obstacle_with_equality_leader_fails_clearly():
    """The leader's reference crosses the column: with the equality leader kept (``leader_release=None``) no
    trajectory exists, said before IPOPT runs, naming the knots where the reference is inside."""
    problem = small_problem(THROUGH)
    inside = problem.env.exact_clearance(problem.trajectory.x) < 0
    assert inside.any()
    with pytest.raises(HorizonInfeasible) as info:
        plan_horizon(problem, solve(problem, "qp")[0], leader_release=None)
    err = info.value
    assert err.status == "reference_infeasible" and err.groups == ["clearance"]
    assert all(v.item == "robot 2" for v in err.violations)
    worst = max(err.violations, key=lambda v: v.amount)
    assert inside[worst.knot]
    # where it is outside but nearer than d_safe, its bound is its own clearance (a constant): only the inside knots
    assert {v.knot for v in err.violations} == set(np.flatnonzero(inside[1:]) + 1)
    msg = str(err)
    assert "leader's reference passes inside the inflated obstacles" in msg and f"knot {worst.knot}" in msg
    for v in err.violations:
        assert v.group in GROUPS and 0 < v.knot <= 30 and v.amount > 0 and v.t == pytest.approx(0.05 * v.knot)


def test_a_reference_nearer_than_d_safe_but_clear_keeps_its_own_clearance(monkeypatch):
    """The reference passes 2 cm over the inflated column (0 < c < d_safe = 5 cm): the equality leader's own sample is
    a constant there, so its bound is its own clearance and it is no row; the rest of the chain keeps d_safe, and the
    plan passes the exact check (which asks c ≥ 0). Before, the NLP was refused (``reference_infeasible``)."""
    problem = small_problem(((3.2, 2.9), (4.2, 2.82), (5.2, 2.9)), T_end=3.0)
    ref, d_safe = problem.trajectory.x, problem.qp_params.d_safe
    assert problem.env.exact_clearance(ref).min() >= 0
    spline = ClearanceSpline(problem.env).evaluate(ref.T)[0]
    near = np.flatnonzero(spline[1:] < d_safe) + 1  # the spline's own entries below d_safe, knots ≥ 1
    assert near.size
    warm = solve(problem, "qp")[0]
    rows: list[np.ndarray] = []  # the leader sample's clearance entries that were rows, in every transcription
    init = horizon_model._Transcription.__init__

    def spy(self, model, masks):
        rows.append(masks["clearance"][model.su.N * model.su.S - 1].copy())
        init(self, model, masks)

    monkeypatch.setattr(horizon_model._Transcription, "__init__", spy)
    plan = plan_horizon(problem, warm)
    d = plan.diagnostics
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    assert d["reference_clearance_entries"] == near.size
    assert rows and not any(r[near].any() for r in rows)  # constants: never rows
    assert any(r[near.min() - 3 : near.min()].any() for r in rows)  # its knots nearer than 0.6 m but ≥ d_safe: rows
    assert check(plan, problem.env).n_violation_steps == 0
    assert np.linalg.norm(plan.robots[:, -1] - ref, axis=1).max() < 1e-6  # on its reference
    # the follower keeps d_safe (its robot: the spline may overestimate the exact clearance by field_error)
    assert problem.env.exact_clearance(plan.robots[1:, 0]).min() >= d_safe - 0.015


def test_a_horizon_plan_that_fails_the_exact_check_gives_way_to_the_qp_plan(monkeypatch):
    """The NLP keeps the spline field's clearance at sampled tether points; should its plan still fail the exact
    (shapely) check, ``solve`` returns the verified qp plan (``horizon_result`` "warm_start", stop "exact_check") and
    says why, instead of a failed plan. Here the NLP's plan is made to put the follower inside the column."""
    problem = small_problem()
    real = horizon_module.plan_horizon

    def inside(problem, warm, **kw):
        plan = real(problem, warm, **kw)
        robots = plan.robots.copy()
        robots[10:13, 0] = (4.2, 2.0)  # the column's centre
        return dataclasses.replace(plan, robots=robots)

    monkeypatch.setattr(horizon_module, "plan_horizon", inside)
    plan, metrics = solve(problem, "horizon")
    d = plan.diagnostics
    assert metrics.violation_free and plan.success and plan.method == "horizon"
    assert d["horizon_result"] == "warm_start" and d["horizon_summary"]["stop"] == "exact_check"
    assert d["horizon_summary"]["iterations"] > 0  # what the NLP did before its plan was checked
    assert "fails the exact check (robot_clearance at 3 step(s) from 10" in d["horizon_note"]
    assert d["horizon_note"].endswith("returned its qp warm start, which passes every check")
    qp, _ = solve(problem, "qp")
    np.testing.assert_array_equal(plan.q, qp.q)


def test_a_start_inside_d_safe_keeps_the_warm_starts_clearance_until_it_reaches_d_safe(monkeypatch):
    """A second column 3 cm (inflated) below the first tether's midpoint at the start: from rest a robot moves
    ≤ a_rob Ts² = 1.5 cm in its first step, so d_safe = 5 cm cannot hold at knot 1. Those samples keep the warm
    start's clearance until it reaches d_safe; the plan is an optimum and clear of the obstacles (exact check).
    Without that, the NLP has no feasible point near the start."""
    problem = small_problem(columns=(COLUMN, (1.4, 2.5 - 0.83)))
    warm, _ = solve(problem, "qp")
    assert warm.success
    plan = plan_horizon(problem, warm)
    d = plan.diagnostics
    assert d["start_clearance_entries"] > 0 and d["horizon_result"] == "optimal"
    assert min(d["min_field_clearance"][:3]) < 0.05  # the first knots are inside d_safe, as the start is
    metrics = check(plan, problem.env)
    assert plan.success and metrics.n_violation_steps == 0 and metrics.min_tether_clearance > 0
    assert objective(plan.q, problem) < objective(warm.q, problem)
    monkeypatch.setattr(horizon_model._Model, "keep_start_clearance", lambda self, c: 0)
    try:
        plain = plan_horizon(problem, warm)
    except InfeasibleStep:
        return
    assert plain.diagnostics["horizon_result"] != "optimal"


def test_a_leader_starting_inside_d_safe_is_not_refused_as_a_reference_too_close():
    """The leader starts 3 cm (inflated) under a column: its own sample keeps the warm start's clearance until the
    reference reaches d_safe, and the check of the fixed reference reads that row's own bounds (it read row 0's)."""
    problem = small_problem(columns=(COLUMN, (3.2, 2.9 + 0.83)))
    warm, _ = solve(problem, "qp")
    assert warm.success
    plan = plan_horizon(problem, warm)
    assert plan.diagnostics["horizon_result"] == "optimal" and plan.diagnostics["start_clearance_entries"] > 0
    metrics = check(plan, problem.env)
    assert plan.success and metrics.n_violation_steps == 0


def _leader_lag(plan, problem) -> np.ndarray:
    """The leader's distance to its reference at every knot [m]."""
    return np.linalg.norm(plan.robots[:, -1] - problem.trajectory.x[:, :2], axis=1)


def test_a_leader_whose_warm_start_lags_far_or_cannot_be_on_its_reference_is_released():
    """THROUGH: the reference crosses the column and the qp plan goes round it, 0.93 m off the reference — more than
    ``leader_release`` = 0.5 m, so the leader is released: every NLP of the call with ``leader_tolerance`` = that lag
    + 1 mm, w3 f3 in the cost. Optimal, the exact check passes, the leader within the tolerance at every knot, and
    no worse than the qp plan in f1–f4, f3 included. With ``leader_release`` above the lag the equality leader is
    tried, found infeasible before IPOPT (its reference inside the inflated column), and released all the same; with
    ``None`` it is refused (the test above). GRAZING: the qp plan lags 0.27 m, under ``leader_release``, but the
    reference dips 0.2 mm into the inflated column: released for that reason."""
    from tmr.control.horizon import _leader_release

    problem = small_problem(THROUGH)
    warm = solve(problem, "qp")[0]
    lag = _leader_lag(warm, problem)
    assert warm.success and lag.max() > HorizonOptions().leader_release == 0.5
    for options, why in (({}, "more than leader_release = 0.5 m"), ({"leader_release": 2.0}, "inside the inflated")):
        plan = plan_horizon(problem, warm, **options)
        d = plan.diagnostics
        assert d["horizon_result"] == "optimal", d["horizon_note"]
        assert plan.success and check(plan, problem.env).n_violation_steps == 0
        released = d["leader_released"]
        assert released["lag"] == pytest.approx(lag.max()) and released["knot"] == int(np.argmax(lag))
        assert released["tolerance"] == pytest.approx(lag.max() + 1e-3)
        assert _leader_lag(plan, problem).max() <= released["tolerance"] + 1e-6
        assert why in d["horizon_note"] and "so the leader was released" in d["horizon_note"]
        terms, before = d["horizon_summary"]["terms"], d["horizon_summary"]["warm_start_terms"]
        assert all(terms[k] <= before[k] for k in ("f1", "f2", "f3", "f4")), (terms, before)
        assert terms["f3"] < 0.5 * before["f3"]  # w3 f3 in the cost: nearer the reference than the qp plan
    problem = small_problem(GRAZING)
    warm = solve(problem, "qp")[0]
    assert 0 < _leader_lag(warm, problem).max() < 0.5
    plan = plan_horizon(problem, warm)
    d = plan.diagnostics
    assert d["horizon_result"] == "optimal" and check(plan, problem.env).n_violation_steps == 0
    assert "the equality leader is infeasible (its reference passes inside the inflated obstacles" in d["horizon_note"]
    # only a verified plan lends its leader, only with the equality leader, only omnidirectional robots
    opts = HorizonOptions()
    assert _leader_release(problem, warm, opts, why="x") is not None
    assert _leader_release(problem, dataclasses.replace(warm, success=False), opts, why="x") is None
    assert _leader_release(problem, warm, dataclasses.replace(opts, leader_release=None), why="x") is None
    assert _leader_release(problem, warm, dataclasses.replace(opts, leader_tolerance=0.1), why="x") is None
    assert _leader_release(dataclasses.replace(problem, robot_model=object()), warm, opts, why="x") is None
    assert _leader_release(problem, warm, opts) is None  # 0.27 m: under leader_release, nothing proven
    # the planner returning the qp plan (here: a time limit before IPOPT starts) still says the leader was released
    plan, _ = solve(small_problem(THROUGH), "horizon", time_limit=0.01)
    d = plan.diagnostics
    assert plan.success and d["horizon_result"] == "warm_start" and d["horizon_summary"]["leader_released"]
    assert (
        "(the leader released within 0.934 m of its reference, the qp plan's largest lag + 1 mm)" in d["horizon_note"]
    )
    assert d["horizon_summary"]["leader_released"]["slack"] == 1e-3
    with pytest.raises(ParameterError, match="_started"):
        plan_horizon(problem, warm, _started=0.0)
    with pytest.raises(ParameterError, match="leader_release"):
        plan_horizon(problem, warm, leader_release=0.0)


def test_bounded_leader_error_passes_where_equality_cannot():
    problem = small_problem(GRAZING)
    warm = solve(problem, "qp")[0]
    with pytest.raises(HorizonInfeasible, match="leader"):
        plan_horizon(problem, warm, leader_release=None)
    plan = plan_horizon(problem, warm, leader_tolerance=0.1)
    metrics = check(plan, problem.env)
    assert plan.success and metrics.n_violation_steps == 0
    assert 0.0 < metrics.max_tracking_error <= 0.1 + 1e-6
    assert plan.diagnostics["horizon_result"] == "optimal"


def test_bad_options_and_warm_start():
    problem = small_problem()
    warm = solve(problem, "qp")[0]
    with pytest.raises(ParameterError, match="unknown horizon option"):
        plan_horizon(problem, warm, nonsense=1)
    with pytest.raises(ParameterError):
        plan_horizon(problem, warm, hessian="bfgs")
    bad = dataclasses.replace(warm, q=np.zeros((31, 3)))
    with pytest.raises(ParameterError, match="warm start"):
        plan_horizon(problem, bad)
    # the warm start is required (the planner passes its qp plan), the time limit is a positive number of seconds
    with pytest.raises(ParameterError, match=r"needs a warm start.*solve\(problem, 'qp'\)"):
        plan_horizon(problem, None)
    with pytest.raises(TypeError):
        plan_horizon(problem)  # type: ignore[call-arg]
    for limit in (0.0, -1.0, True, "60"):
        with pytest.raises(ParameterError, match="time_limit"):
            plan_horizon(problem, warm, time_limit=limit)
    assert DEFAULT_TIME_LIMIT == 60.0
    with pytest.raises(ParameterError, match="retry_hessian"):
        plan_horizon(problem, warm, retry_hessian="bfgs")
    for bad_activation in (0.0, -1.0):
        with pytest.raises(ParameterError, match="coarse_train_activation"):
            plan_horizon(problem, warm, coarse_train_activation=bad_activation)
    with pytest.raises(ParameterError, match="keep_warm_margins"):
        plan_horizon(problem, warm, keep_warm_margins="yes")
    # a ceiling on IPOPT's regularisation at or below a floor it caps (the retry's 10⁻², the fast attempt's 10⁻⁵)
    for ceiling in (1e-2, 1e-3, 0.0):
        with pytest.raises(ParameterError, match="max_hessian_perturbation"):
            plan_horizon(problem, warm, max_hessian_perturbation=ceiling)
    with pytest.raises(ParameterError, match="fast_max_hessian_perturbation"):
        plan_horizon(problem, warm, fast_max_hessian_perturbation=1e-5)
    horizon_model._options({"max_hessian_perturbation": None, "fast_max_hessian_perturbation": None})  # IPOPT's


def test_keep_warm_margins_lowers_only_the_entries_the_warm_start_keeps_less_than():
    """The coarse NLP from a train plan (``keep_warm_margins``): a clearance entry nearer than d_safe + margin, or a
    pair nearer than its raised separation, takes the warm start's own value as its bound, never below the fine
    NLP's (d_safe; (2r + separation margin)²); every other bound is unchanged, the fixed start's entries are neither
    lowered nor counted, and the warm start then holds every clearance and separation row it can."""
    problem = small_problem()
    warm, _ = solve(problem, "qp")
    margin, sep = 0.4, problem.qp_params.separation_margin
    opts = horizon_model._options({"clearance_margin": margin, "keep_warm_margins": True})
    raised = dataclasses.replace(problem.qp_params, separation_margin=sep + margin)  # as the coarse pass raises it
    su = horizon_model._Setup(dataclasses.replace(problem, qp_params=raised), opts)
    Q, info = horizon_model._warm_start(su, warm)
    env = problem.env
    model = horizon_model._Model(su, distance_spline(env), bounds=info["warm_start_terms"], spline=ClearanceSpline(env))
    vals = {g: v.copy() for g, v in model.values(model.project(model.x_of(Q))).items()}
    floors = {"clearance": su.d_safe, "separation": (2 * su.r + sep) ** 2}
    vals["clearance"][0, 5] = su.d_safe - 0.01  # inside the fine bound too: lowered to the floor only
    vals["separation"][0, 5] = floors["separation"] - 0.1
    vals["clearance"][:, 0] = 0.0  # the fixed start: not a row
    before = {g: np.array(model.lower(g), dtype=float) for g in floors}
    inside = {g: vals[g] < before[g] for g in floors}
    for m in inside.values():
        m[:, 0] = False
    assert inside["clearance"][:, 1:].sum() > 1 and inside["separation"].sum() > 1  # the margins reach the warm start
    assert model.keep_warm_margins(vals) == sum(int(m.sum()) for m in inside.values())
    for g, floor in floors.items():
        after = model.lower(g)
        np.testing.assert_array_equal(after[~inside[g]], before[g][~inside[g]])
        np.testing.assert_array_equal(after[inside[g]], np.maximum(vals[g][inside[g]], floor))
        assert after[0, 5] == pytest.approx(floor)  # clamped, not the value inside the fine bound
        held = inside[g] & (vals[g] >= floor)  # where the warm start itself keeps the floor, its row now holds
        assert held.any() and np.all(model.violation(g, vals[g])[held] <= 0.0)
    assert model.keep_warm_margins(vals) == 2  # a second call finds only the two entries below the fine bounds


# ----------------------------------------------------------------------------------------------------------------
# the planner ↔ horizon import circle is gone
# ----------------------------------------------------------------------------------------------------------------
def test_module_does_not_import_the_planner():
    """Neither at import time (fresh process, the ``tmr`` package's own ``__init__`` — which imports the planner for
    ``tmr.solve`` — bypassed) nor anywhere in the source (a function-level ``from tmr.planner import …`` included)."""
    code = (
        "import importlib.util, sys, types\n"
        "spec = importlib.util.find_spec('tmr')\n"
        "pkg = types.ModuleType('tmr'); pkg.__path__ = list(spec.submodule_search_locations)\n"
        "sys.modules['tmr'] = pkg\n"
        "import tmr.control.horizon\n"
        "print(sorted(m for m in sys.modules if m.startswith('tmr')))\n"
        "assert 'tmr.planner' not in sys.modules\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "'tmr.control.horizon'" in out.stdout and "tmr.planner" not in out.stdout
    imported = set()
    for node in (
        node
        for module in (horizon_module, horizon_model, horizon_pool)  # the solve rounds, transcription, fallbacks
        for node in ast.walk(ast.parse(Path(module.__file__).read_text(encoding="utf-8")))
    ):
        if isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module)
        elif isinstance(node, ast.Import):
            imported.update(a.name for a in node.names)
    assert not any(m == "tmr.planner" or m.startswith("tmr.planner.") for m in imported), imported
    assert "tmr" not in imported  # no `import tmr` / `from tmr import planner` either


def test_plans_with_the_planner_blocked(monkeypatch, feasible_warm):
    problem, warm, _ = feasible_warm
    monkeypatch.setitem(sys.modules, "tmr.planner", None)  # any `import tmr.planner` now raises ImportError
    plan = plan_horizon(problem, warm, **WEIGHTED)
    assert plan.diagnostics["horizon_result"] == "optimal"


# ----------------------------------------------------------------------------------------------------------------
# never worse than the warm start: fallbacks, time limit
# ----------------------------------------------------------------------------------------------------------------
#: The fixture's warm start is the optimum of other weights, so it is better than any other optimum in one term at
#: least: the tests of the weighted objective's fallbacks drop the rows f_i ≤ f_i,warm (tested apart below).
WEIGHTED = {"no_worse_terms": False}


@pytest.fixture(scope="module")
def feasible_warm():
    """A warm start that satisfies every row of the NLP but is not its optimum: the optimum of other weights (the
    small problem's qp plan is no such start: its followers are still moving at t_K, against the to-rest rows)."""
    problem = small_problem()
    warm = plan_horizon(problem, solve(problem, "qp")[0], w_uniformity=100.0)
    assert warm.success and warm.diagnostics["horizon_result"] == "optimal"
    J_warm = objective(warm.q, problem)
    return problem, warm, J_warm


def test_normal_run_is_optimal_and_not_worse(feasible_warm):
    problem, warm, J_warm = feasible_warm
    plan = plan_horizon(problem, warm, **WEIGHTED)
    d = plan.diagnostics
    assert d["horizon_result"] == "optimal" and d["horizon_stop"] == "converged" and not d["time_limit_hit"]
    assert d["ipopt_status"] == "Solve_Succeeded"
    assert d["warm_start_fallback"] == "the warm-start horizon plan"
    assert d["objective_warm_start"] == pytest.approx(J_warm, rel=1e-6)  # on the reference to 10⁻⁶ m already
    J = objective(plan.q, problem)
    assert J == pytest.approx(d["objective"], rel=1e-9)
    assert J < J_warm - 0.1  # 119.77 vs 120.15
    assert "IPOPT solved the NLP" in d["horizon_note"] and "returned the optimum" in d["horizon_note"]
    assert check(plan, problem.env).n_violation_steps == 0 and plan.success


@pytest.mark.parametrize(
    "limit",
    # with max_iter alone the retry would go on from the capped primary's last iterate (it holds its rows) and
    # reach the optimum of this small problem in 2 × 2 iterations: IPOPT is stopped early only with the retry off
    [{"max_iter": 1, "retry": False}, {"max_iter": 2, "retry": False}, {"max_iter": 3, "retry": False},
     {"time_limit": 1e-3}],
    ids=["max_iter=1", "max_iter=2", "max_iter=3", "time_limit=1ms"],
)  # fmt: skip
def test_stopped_ipopt_returns_a_feasible_plan_not_worse_than_warm_start(feasible_warm, limit):
    problem, warm, J_warm = feasible_warm
    plan = plan_horizon(problem, warm, **WEIGHTED, **limit)
    d = plan.diagnostics
    assert plan.method == "horizon" and plan.success and plan.failure is None
    assert d["horizon_result"] in ("warm_start", "best_feasible_iterate")
    assert d["horizon_stop"] == ("time_limit" if "time_limit" in limit else "ipopt_failed")
    assert d["time_limit_hit"] == ("time_limit" in limit)
    assert J_warm >= objective(plan.q, problem) == pytest.approx(d["objective"], rel=1e-9)
    assert d["constraint_violation"] <= 1e-5  # every row of every group, every clearance sample
    metrics = check(plan, problem.env)
    assert plan.success and metrics.n_violation_steps == 0 and metrics.max_tracking_error < 1e-6
    if d["horizon_result"] == "warm_start":
        np.testing.assert_array_equal(plan.q, warm.q)
        assert "returned the warm-start horizon plan" in d["horizon_note"]
    else:
        assert "returned its best feasible iterate (round 1" in d["horizon_note"]
    if "max_iter" in limit:
        assert "Maximum_Iterations_Exceeded" in d["horizon_note"] and d["ipopt_status"] == "Maximum_Iterations_Exceeded"
    else:  # spent before the first IPOPT call (the transcription alone takes longer than 1 ms)
        assert d["horizon_note"].startswith("time limit of 0.001 s reached before IPOPT started")
        assert d["ipopt_iterations"] == 0 and d["rounds"] == 0


def test_iterate_fallback_beats_warm_start(feasible_warm):
    """Two IPOPT iterations already lower the cost from a feasible start; the iterate is kept, projected on the
    reference and checked on every row."""
    problem, warm, J_warm = feasible_warm
    plan = plan_horizon(problem, warm, **WEIGHTED, max_iter=2, retry=False)  # the retry would go on to the optimum
    d = plan.diagnostics
    assert d["horizon_result"] == "best_feasible_iterate"
    assert objective(plan.q, problem) < J_warm - 0.01  # 120.10 vs 120.15 (every span row in since this change)
    went_on = plan_horizon(problem, warm, **WEIGHTED, max_iter=2).diagnostics  # the retry continues the primary
    primary, retry = [r for r in went_on["round_log"] if r["phase"] == "fallback"][:2]  # after the fast attempt's
    assert primary["status"] == "Maximum_Iterations_Exceeded" and retry["from_last"] and retry["iterations"] <= 2
    assert went_on["horizon_result"] == "optimal" and went_on["objective"] < d["objective"]
    assert d["iterates_kept"] >= 1 and check(plan, problem.env).n_violation_steps == 0


def test_warm_start_as_given_with_a_lagging_leader_is_the_last_fallback(feasible_warm, monkeypatch):
    """A warm start whose leader lags its reference by a few mm (as a CLIK qp plan does) is still a fallback when its
    projection on the reference is not feasible: as given, if every other row holds and the leader stays within
    ``warm_start_leader_error`` (1 cm) of the reference."""
    problem, warm, _ = feasible_warm
    q = warm.q.copy()
    s = np.linspace(0.0, 1.0, q.shape[0])
    q[:, -1] += 0.003 * np.sin(np.pi * s) ** 2  # the leader's tether up to 3 mm longer mid-way, smoothly
    lagging = dataclasses.replace(warm, q=q, method="lagging")
    real = horizon_model._Model.project

    def spoiled(self, xv):
        out = real(self, xv)
        out[2 * problem.chain.n_robots :: 2 * problem.chain.n_robots] += 0.5  # robot 1 jumps 0.5 m at knot 1
        return out

    monkeypatch.setattr(horizon_model._Model, "project", spoiled)  # every projection: warm start's and fallback's
    plan = plan_horizon(problem, lagging, **WEIGHTED, time_limit=1e-3)
    d = plan.diagnostics
    assert d["horizon_result"] == "warm_start"
    assert d["warm_start_fallback"] == "the warm-start lagging plan as given, leader within 3.0 mm of the reference"
    np.testing.assert_array_equal(plan.q, q)
    assert check(plan, problem.env).n_violation_steps == 0
    with pytest.raises(HorizonInfeasible, match=r"warm start is no fallback.*as given: leader up to 0.003 m"):
        plan_horizon(problem, lagging, **WEIGHTED, time_limit=1e-3, warm_start_leader_error=0.002)


def test_warm_start_clearance_within_the_field_error_budget(feasible_warm):
    """A warm start whose samples read up to ``field_error`` below d_safe in the spline field (its own formulation
    kept d_safe in another distance field) is a fallback (5.1 mm here); beyond the budget it is not (nor is it as
    given: its leader is off the reference, more than ``warm_start_leader_error``)."""
    problem, warm, _ = feasible_warm
    q = warm.q.copy()
    s = np.linspace(0.0, 1.0, q.shape[0])
    q[:, 0] -= 0.01 * s**3 * (10 - 15 * s + 6 * s**2)  # θ1 turned by up to 10 mrad: tether 2 towards the column
    dipping = dataclasses.replace(warm, q=q, method="dipping")
    plan = plan_horizon(problem, dipping, **WEIGHTED, time_limit=1e-3)
    d = plan.diagnostics
    assert d["horizon_result"] == "warm_start"
    assert d["warm_start_fallback"].startswith("the warm-start dipping plan, leader projected on the reference; ")
    assert d["warm_start_fallback"].endswith("mm below d_safe in the spline field")
    assert 5e-4 < 0.05 - d["min_field_clearance"][1:].min() < 0.015
    assert check(plan, problem.env).n_violation_steps == 0
    with pytest.raises(HorizonInfeasible, match="warm start is no fallback: the dipping plan violates clearance"):
        plan_horizon(
            problem, dipping, time_limit=1e-3, field_error=5e-4, samples_per_link=15, warm_start_leader_error=0
        )


def test_no_feasible_point_raises_with_the_warm_start_reason():
    """From the qp plan (infeasible for the NLP: followers still moving at t_K), two iterations find nothing."""
    problem = small_problem()
    warm = solve(problem, "qp")[0]
    with pytest.raises(HorizonInfeasible) as info:
        plan_horizon(problem, warm, **WEIGHTED, max_iter=2)
    err = info.value
    msg = str(err)
    assert err.status == "Maximum_Iterations_Exceeded"
    assert "IPOPT found no solution in round 1" in msg and "no iterate satisfies the hard constraints" in msg
    assert "the warm start is no fallback: the qp plan violates" in msg and "robot_accel" in msg
    assert err.violations and err.diagnostics["horizon_stop"] == "ipopt_failed"


def test_time_limit_not_reached_gives_the_same_plan(feasible_warm):
    problem, warm, _ = feasible_warm
    a = plan_horizon(problem, warm, **WEIGHTED)
    b = plan_horizon(problem, warm, **WEIGHTED, time_limit=DEFAULT_TIME_LIMIT)
    np.testing.assert_array_equal(a.q, b.q)
    assert a.params == b.params
    assert b.diagnostics["time_limit"] == DEFAULT_TIME_LIMIT and not b.diagnostics["time_limit_hit"]


def test_progress_bar_only_on_a_terminal(feasible_warm, monkeypatch, capfd):
    problem, warm, _ = feasible_warm

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    plan_horizon(problem, warm, **WEIGHTED, progress=True)  # pytest's stderr is not a terminal: no bar
    assert capfd.readouterr().err == ""
    term = Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    plan = plan_horizon(problem, warm, **WEIGHTED, progress=True)
    text = term.getvalue()
    assert "horizon NLP, round 1 (primary solve): " in text and " IPOPT iterations [" in text and ": : " not in text
    term2 = Terminal()
    monkeypatch.setattr(sys, "stderr", term2)
    plan_horizon(problem, warm, **WEIGHTED, progress=False)
    assert term2.getvalue() == "" and plan.diagnostics["horizon_result"] == "optimal"


def test_spline_field_close_to_exact_and_sagitta_bound():
    env = Environment.from_geometry([Point(*COLUMN).buffer(0.3, 64)], (0.0, 0.0, 8.0, 5.0))
    f = distance_spline(env)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0.5, 7.5, 4000), rng.uniform(0.5, 4.5, 4000)])
    exact = env.exact_clearance(pts)
    near = (exact > -0.05) & (exact < 0.5)
    spline = np.asarray(f.map(int(near.sum()))(pts[near].T)).ravel()
    assert np.max(spline - exact[near]) < 0.015  # the field_error budget of samples_needed
    assert np.max(np.abs(spline - exact[near])) < 0.03
    # sagitta, worst case: a point obstacle (inflated to a disc of radius r); a chord of the longest sample spacing with
    # both ends at clearance d_safe − field_error keeps the whole segment clear (exact shapely check)
    r, c = 0.5, 0.05 - 0.015
    S = samples_needed(5.596, r, 0.05, 0.015)
    delta = 5.596 / S
    post = Environment.from_geometry([Point(4.0, 2.5)], (0.0, 0.0, 8.0, 5.0))
    h = math.sqrt((r + c) ** 2 - delta**2 / 4)  # distance of the chord's midpoint to the point
    a, b = np.array([4.0 - delta / 2, 2.5 + h]), np.array([4.0 + delta / 2, 2.5 + h])
    np.testing.assert_allclose(post.exact_clearance(np.array([a, b])), c, atol=2e-3)
    assert post.segment_clearance(a, b) > 0
    # one more sample per tether is not needed, one fewer breaks the bound
    d2 = 5.596 / (S - 1)
    assert (r + c) ** 2 - d2**2 / 4 < r**2 <= h**2


def test_ctrl_c_during_the_nlp_stops_ipopt_and_is_raised_after_it() -> None:
    """casadi swallows a KeyboardInterrupt raised inside IPOPT's callback (the first Ctrl-C of a horizon run was
    lost): inside the guard SIGINT only sets the flag the iteration callback turns into a stop request, and the
    KeyboardInterrupt comes once the solver has returned; the previous handler is restored."""
    import os
    import signal

    from tmr.control import horizon as hz

    outer = signal.getsignal(signal.SIGINT)  # a shell's background job starts with SIGINT ignored: test as a user's
    signal.signal(signal.SIGINT, signal.default_int_handler)  # foreground run, whatever launched pytest
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        with hz._ctrl_c_stops_ipopt():
            os.kill(os.getpid(), signal.SIGINT)  # delivered here, inside the guard: no exception yet
            assert hz._INTERRUPT.is_set()
    assert signal.getsignal(signal.SIGINT) is before
    with hz._ctrl_c_stops_ipopt():  # no Ctrl-C: nothing raised, the flag cleared
        pass
    assert not hz._INTERRUPT.is_set()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a sweep worker ignores Ctrl-C: the guard leaves it so
    try:
        with hz._ctrl_c_stops_ipopt():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, outer)


def test_ctrl_c_while_the_nlp_is_built_is_not_swallowed_by_casadi(monkeypatch) -> None:
    """A Ctrl-C while a round's transcription is built (casadi calls Python helpers there and swallowed the
    KeyboardInterrupt raised in them: the run went on to its end) stops the run: the whole of plan_horizon records
    SIGINT, nested blocks keep the flag, and KeyboardInterrupt is raised before IPOPT finishes; the handler is
    restored."""
    import os
    import signal

    from tmr.control import horizon as hz

    problem = small_problem()
    warm, _ = solve(problem, "qp")
    built = horizon_model._Transcription.__init__
    solves: list[int] = []

    def interrupted_build(self, *args, **kwargs):
        built(self, *args, **kwargs)
        if not solves:
            solves.append(1)
            os.kill(os.getpid(), signal.SIGINT)  # as if it landed inside casadi's own Python helpers

    outer = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    before = signal.getsignal(signal.SIGINT)
    monkeypatch.setattr(horizon_model._Transcription, "__init__", interrupted_build)
    try:
        with pytest.raises(KeyboardInterrupt):
            plan_horizon(problem, warm)
        assert signal.getsignal(signal.SIGINT) is before and hz._DEPTH == [0]
        nested: list[bool] = []
        with pytest.raises(KeyboardInterrupt):  # a flag set in an inner block is raised at its end, not cleared
            with hz._ctrl_c_stops_ipopt():
                with hz._ctrl_c_stops_ipopt():
                    os.kill(os.getpid(), signal.SIGINT)
                nested.append(True)  # not reached: the inner block raised
        assert not nested and hz._DEPTH == [0]
    finally:
        signal.signal(signal.SIGINT, outer)


def test_time_limit_stops_ipopt_at_the_next_iteration(feasible_warm, monkeypatch):
    """IPOPT's own ``max_wall_time`` starts after casadi built the solver (seconds on long routes), so the iteration
    callback stops IPOPT at the first iteration past the deadline: a deadline already passed stops it after one
    initial point, reported as the time limit, with a feasible plan no worse than the warm start."""
    from tmr.control import horizon

    problem, warm, J_warm = feasible_warm

    class Late(horizon._IterationCallback):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.deadline = -math.inf  # already passed

    monkeypatch.setattr(horizon, "_IterationCallback", Late)
    plan = plan_horizon(problem, warm, **WEIGHTED, time_limit=DEFAULT_TIME_LIMIT)
    d = plan.diagnostics
    assert d["horizon_stop"] == "time_limit" and d["time_limit_hit"]
    assert d["ipopt_iterations"] <= 1 and d["round_log"][0]["status"] == "Maximum_WallTime_Exceeded"
    assert plan.success and objective(plan.q, problem) <= J_warm
    assert "time limit of 60 s reached in round 1" in d["horizon_note"]


def test_an_nlp_too_big_to_build_within_the_limit_is_not_started(feasible_warm, monkeypatch):
    """Building the solver cannot be interrupted: if its rows times the measured seconds per row exceed the remaining
    time, IPOPT is not started and the warm start is returned, with the reason (and no limit: it is built)."""
    from tmr.control import horizon

    problem, warm, _ = feasible_warm
    monkeypatch.setattr(horizon, "BUILD_SECONDS_PER_ROW", 1.0)  # a 200-row NLP would take minutes
    plan = plan_horizon(problem, warm, **WEIGHTED, time_limit=DEFAULT_TIME_LIMIT)
    d = plan.diagnostics
    assert d["horizon_result"] == "warm_start" and d["ipopt_iterations"] == 0 and d["time_limit_hit"]
    assert d["horizon_note"].startswith("IPOPT not started: the NLP has ") and "raise --time-limit" in d["horizon_note"]
    assert plan_horizon(problem, warm, **WEIGHTED).diagnostics["horizon_result"] == "optimal"


def full_transcription(spline: bool = True, leader_tolerance: float = 0.0):
    """The small problem's NLP at its warm start with every row of every group in it (clearance included): the
    problem, its setup, model, IPOPT's initial point and the transcription; ``spline=False``: the model without the
    numpy spline (casadi's B-spline node in the rows, differentiated by casadi); ``leader_tolerance`` > 0: the leader
    free within it of its reference (its rows, f3 in the cost)."""
    problem = small_problem()
    warm, _ = solve(problem, "qp")
    su = horizon_model._Setup(problem, horizon_model._options({"leader_tolerance": leader_tolerance}))
    Q, info = horizon_model._warm_start(su, warm)
    env = problem.env
    model = horizon_model._Model(
        su, distance_spline(env), bounds=info["warm_start_terms"], spline=ClearanceSpline(env) if spline else None
    )
    xv = model.project(model.x_of(Q))
    vals = model.values(xv)
    masks = {name: np.ones_like(vals[name], dtype=bool) for name in model.rows}
    for name in masks:
        masks[name][:, model.fixed_columns(name)] = False
    return problem, su, model, xv, horizon_model._Transcription(model, masks)


def casadis_own_hessian(model, tr, obj_scale: float, x, lam_f: float, lam):
    """The upper triangle of the Lagrangian's Hessian λ_f J / ``obj_scale`` + λᵀ g of the transcription ``tr`` (of
    ``model``) at ``x``, by casadi's automatic differentiation (DM)."""
    import casadi as ca

    lf, lg = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", tr.size)
    L = lf * model.J / obj_scale + ca.dot(lg, tr.g)
    return ca.Function("H", [model.x, lf, lg], [ca.triu(ca.hessian(L, model.x)[0])])(x, lam_f, lam)


def test_structured_jacobian_and_hessian_equal_casadis_automatic_ones():
    """The NLP's rows, Jacobian and Lagrangian Hessian assembled from the numpy spline's derivatives and the sparse
    point maps (``_Transcription.derivatives``) are casadi's own (automatic differentiation of the same rows with
    casadi's B-spline node), at a point off the warm start with random multipliers."""
    import casadi as ca

    problem, su, model, xv, tr = full_transcription()
    _, _, ref_model, _, ref = full_transcription(spline=False)
    assert ref.size == tr.size and ref_model.spline is None and ref.derivatives(2.5, "exact") == {}
    assert tr.index["clearance"].size > 0
    custom = tr.derivatives(2.5, "exact")
    assert set(custom) == {"jac_g", "hess_lag"}
    rng = np.random.default_rng(3)
    x = xv + rng.normal(0.0, 0.02, xv.size)
    lam = rng.normal(0.0, 1.0, tr.size)
    g1, J1 = custom["jac_g"](x, [])
    H1 = custom["hess_lag"](x, [], 0.7, lam)
    rx = ref_model.x
    J2 = ca.Function("J", [rx], [ca.jacobian(ref.g, rx)])(x)
    H2 = casadis_own_hessian(ref_model, ref, 2.5, x, 0.7, lam)
    g2 = np.asarray(ca.Function("g", [rx], [ref.g])(x)).ravel()
    np.testing.assert_allclose(np.asarray(g1).ravel(), g2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(ca.Function("g", [model.x], [tr.g])(x)).ravel(), g2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(J1.full(), J2.full(), rtol=0, atol=1e-9 * max(1.0, float(np.abs(J2.full()).max())))
    np.testing.assert_allclose(H1.full(), H2.full(), rtol=0, atol=1e-9 * max(1.0, float(np.abs(H2.full()).max())))
    # the Gauss–Newton Hessian is the same whether the clearance curvature is assembled here or by casadi
    gn1 = tr.derivatives(2.5, "gauss-newton")["hess_lag"](x, [], 0.7, lam).full()
    gn2 = ref.derivatives(2.5, "gauss-newton")["hess_lag"](x, [], 0.7, lam).full()
    np.testing.assert_allclose(gn1, gn2, rtol=0, atol=1e-9 * max(1.0, float(np.abs(gn2).max())))
    assert np.abs(gn1 - H1.full()).max() > 1e-3  # and not the exact one
    # the comparison is not empty: the clearance rows carry curvature of their own
    lam0 = lam.copy()
    off = tr.offset["clearance"]
    lam0[off : off + tr.index["clearance"].size] = 0.0
    assert np.abs((H1 - custom["hess_lag"](x, [], 0.7, lam0)).full()).max() > 1e-3
    # the sparse point maps are the model's own sample points (Px, Py) at every sample
    idx = np.arange(int(model.Px.numel()))
    Ax, Ay, b = model.point_maps(idx)
    P = np.asarray(ca.Function("P", [model.x], [ca.horzcat(model.Px, model.Py)])(x))
    np.testing.assert_allclose((Ax @ x).full().ravel() + b[:, 0], P[:, 0], atol=1e-12)
    np.testing.assert_allclose((Ay @ x).full().ravel() + b[:, 1], P[:, 1], atol=1e-12)


def test_both_hessians_share_the_models_constants_built_once(monkeypatch):
    """``_Model.rows_hessian``'s constants in z (the terms' Hessians, the linear rows' matrices) and ∂z/∂x are built
    once per model: the Gauss–Newton Hessian built first and the exact one after it (as the coarse pass's repair and
    its polish do) cost one build of them, and the exact Hessian is, to the last bit, that of a model that built only
    it."""
    _, _, model, xv, tr = full_transcription()
    _, _, alone, _, tr_alone = full_transcription()
    built = []
    real = horizon_model._joint_terms
    monkeypatch.setattr(horizon_model, "_joint_terms", lambda *a, **k: built.append(1) or real(*a, **k))
    gn = tr.derivatives(2.5, "gauss-newton")["hess_lag"]
    exact = tr.derivatives(2.5, "exact")["hess_lag"]
    assert len(built) == 1 and model._z_constants() is model._z_constants()
    assert model._z_jacobian() is model._z_jacobian()
    only = tr_alone.derivatives(2.5, "exact")["hess_lag"]
    assert len(built) == 2  # the other model: its own
    rng = np.random.default_rng(11)
    x = xv + rng.normal(0.0, 0.02, xv.size)
    lam = rng.normal(0.0, 1.0, tr.size)
    np.testing.assert_array_equal(exact(x, [], 0.7, lam).full(), only(x, [], 0.7, lam).full())
    assert np.abs(exact(x, [], 0.7, lam).full() - gn(x, [], 0.7, lam).full()).max() > 1e-3


def test_a_hessian_shift_adds_it_to_the_diagonal_and_nothing_else():
    """``shift`` δ (``HorizonOptions.coarse_polish_hessian_shift``) adds δ I to the Hessian of the Lagrangian given to
    IPOPT, exact or Gauss–Newton, with the clearance curvature assembled here or by casadi (whose exact Hessian then
    becomes a ``hess_lag`` of ours); the rows and their Jacobian are the same."""

    _, _, model, xv, tr = full_transcription()
    _, _, ref_model, _, ref = full_transcription(spline=False)
    rng = np.random.default_rng(5)
    x = xv + rng.normal(0.0, 0.02, xv.size)
    lam = rng.normal(0.0, 1.0, tr.size)
    delta = 3e-4
    eye = np.eye(xv.size)
    own = casadis_own_hessian(ref_model, ref, 2.5, x, 0.7, lam).full()  # ``ref`` leaves it to IPOPT without a shift
    assert ref.derivatives(2.5, "exact") == {}
    for t in (tr, ref):
        for kind in ("exact", "gauss-newton"):
            H1, H3 = (t.derivatives(2.5, kind, d)["hess_lag"](x, [], 0.7, lam).full() for d in (delta, 3 * delta))
            # the shift exactly: the same entries off the diagonal, its own to rounding on it
            rounding = 8 * np.finfo(float).eps * float(np.abs(np.diag(H1)).max())
            np.testing.assert_allclose(H3 - H1, 2 * delta * eye, rtol=0, atol=rounding)
            np.testing.assert_array_equal((H3 - H1)[~eye.astype(bool)], 0.0)
            # and the Hessian under it: the same function's without a shift, or casadi's own (exact, ``ref``)
            plain = t.derivatives(2.5, kind).get("hess_lag")
            H0 = own if plain is None else plain(x, [], 0.7, lam).full()
            np.testing.assert_allclose(H1 - delta * eye, H0, rtol=0, atol=1e-9 * max(1.0, float(np.abs(H0).max())))
    _, J0 = tr.derivatives(2.5, "exact")["jac_g"](x, [])
    _, J1 = tr.derivatives(2.5, "exact", delta)["jac_g"](x, [])
    np.testing.assert_array_equal(J0.full(), J1.full())
    assert "hess_lag" not in tr.derivatives(2.5, "limited-memory", delta)  # no Hessian to shift


def test_the_rest_jacobian_group_by_group_is_casadis_jacobian_of_the_stacked_rows():
    """``_Transcription.rest_jacobian`` (casadi's Jacobian of each non-clearance group, stacked) is casadi's Jacobian
    of the non-clearance rows stacked in their order in g, and ``jac_g`` places it around the clearance rows — with
    every row, and with a round's lazy rows (the rows near the warm start, one group left out)."""
    import casadi as ca

    problem, su, model, xv, full = full_transcription()
    masks = model.near_masks(model.values(xv))
    masks["joint_accel"][:] = False  # a group without a row in the round
    lazy = horizon_model._Transcription(model, masks)
    assert 0 < sum(lazy.index[g].size for g in model.rest_groups) < sum(full.index[g].size for g in model.rest_groups)
    rng = np.random.default_rng(7)
    x = xv + rng.normal(0.0, 0.02, xv.size)
    for tr in (full, lazy):
        before, after = tr._rest
        stacked = ca.Function("J", [model.x], [ca.jacobian(ca.vertcat(before, after), model.x)])(x).full()
        ours = ca.Function("J", [model.x], [tr.rest_jacobian()])(x).full()
        assert ours.shape == stacked.shape == (before.shape[0] + after.shape[0], xv.size)
        np.testing.assert_allclose(ours, stacked, rtol=0, atol=1e-12 * max(1.0, float(np.abs(stacked).max())))
        # in jac_g: the rows before the clearance rows, the clearance rows, the rows after them
        _, J = tr.derivatives(2.5, "exact")["jac_g"](x, [])
        J = J.full()
        nb, nc = before.shape[0], tr.index["clearance"].size
        np.testing.assert_array_equal(J[:nb], ours[:nb])
        np.testing.assert_array_equal(J[nb + nc :], ours[nb:])
        # and those are the rows of g itself: casadi's Jacobian of the whole g, outside the clearance rows
        whole = ca.Function("J", [model.x], [ca.jacobian(tr.g, model.x)])(x).full()
        rest = np.r_[0:nb, nb + nc : tr.size]
        np.testing.assert_allclose(J[rest], whole[rest], rtol=0, atol=1e-12 * max(1.0, float(np.abs(whole).max())))


def test_gauss_newton_hessian_is_the_residuals_jacobian_product_and_the_rows_exact_curvature():
    """hessian="gauss-newton": the cost's part is 2 Σ w_i J_iᵀJ_i with J_i the finite-difference Jacobian of the
    paper's residuals written here from their definitions (q̇, d_i − d_j, q̈ of eq. 24, 25, 27; Σ r² = f_i), it is
    positive semidefinite, a fitness row adds its own Gauss–Newton term (multiplier clipped at 0), and every other
    row keeps casadi's exact curvature."""
    problem, su, model, xv, tr = full_transcription()
    scale, Ts = 2.5, problem.time_params.Ts
    gn = tr.derivatives(scale, "gauss-newton")["hess_lag"]
    exact = tr.derivatives(scale, "exact")["hess_lag"]
    rng = np.random.default_rng(5)
    x = xv + rng.normal(0.0, 0.02, xv.size)
    lam = rng.normal(0.0, 1.0, tr.size)
    fit = slice(tr.offset["fitness"], tr.offset["fitness"] + tr.index["fitness"].size)
    lam[fit] = 0.0

    def residuals(xx):
        q = model.q_of(xx)
        qd = np.diff(q, axis=0) / Ts
        qdd = np.diff(np.vstack([qd, np.zeros((1, q.shape[1]))]), axis=0) / Ts  # q̈_1 … q̈_K (q̇_K = 0)
        d = q[:, 1::2]
        pairs = [(i, j) for i in range(d.shape[1]) for j in range(i + 1, d.shape[1])]
        return {"f1": qd.ravel(), "f2": np.concatenate([d[:, i] - d[:, j] for i, j in pairs]), "f4": qdd.ravel()}

    terms = objective_terms(model.q_of(x), Ts)
    r0 = residuals(x)
    for k in ("f1", "f2", "f4"):
        assert np.sum(r0[k] ** 2) == pytest.approx(terms[k], rel=1e-9)
    h = 1e-6
    jac = {k: np.zeros((r0[k].size, x.size)) for k in r0}
    for c in range(x.size):
        e = np.zeros(x.size)
        e[c] = h
        rp, rm = residuals(x + e), residuals(x - e)
        for k in r0:
            jac[k][:, c] = (rp[k] - rm[k]) / (2 * h)
    free = slice(2 * su.N, x.size)  # knot 0 is the fixed start (q_of returns q_0 exactly)
    jac = {k: J[:, free] for k, J in jac.items()}
    want = sum(2 * 0.7 / scale * J.T @ J for J in jac.values())
    H_obj = (gn(x, [], 0.7, lam) - gn(x, [], 0.0, lam)).full()
    H_obj = (np.triu(H_obj) + np.triu(H_obj, 1).T)[free, free]
    np.testing.assert_allclose(H_obj, want, rtol=0, atol=1e-5 * np.abs(want).max())
    assert np.linalg.eigvalsh(H_obj).min() > -1e-9 * np.abs(want).max()  # positive semidefinite
    # the rows' curvature (fitness multipliers 0) is the exact one
    np.testing.assert_allclose(gn(x, [], 0.0, lam).full(), exact(x, [], 0.0, lam).full(), rtol=0, atol=1e-9)
    # a fitness row adds 2 μ / f_i,warm JᵣᵀJᵣ of its term, and nothing for a negative multiplier
    mu = np.zeros(tr.size)
    mu[fit.start] = 0.3
    k = [t for t in ("f1", "f2", "f4") if model.bounds.get(t, 0.0) > 0][0]
    H_fit = gn(x, [], 0.0, mu).full()
    H_fit = (np.triu(H_fit) + np.triu(H_fit, 1).T)[free, free]
    want_fit = 2 * 0.3 / model.bounds[k] * jac[k].T @ jac[k]
    np.testing.assert_allclose(H_fit, want_fit, rtol=0, atol=1e-5 * np.abs(want_fit).max())
    assert np.abs(gn(x, [], 0.0, -mu).full()).max() == 0.0
    H_ex = exact(x, [], 0.0, mu).full()
    H_ex = (np.triu(H_ex) + np.triu(H_ex, 1).T)[free, free]
    assert np.abs(H_ex - H_fit).max() > 1e-3 * np.abs(want_fit).max()  # not the exact one


# windowed solves along the route, then the whole NLP (HorizonOptions.window)
def test_window_spans_cover_the_free_knots_with_the_overlap():
    spans = horizon_module._window_spans(30, 12, 4)
    assert spans == [(1, 12), (9, 20), (17, 28), (25, 30)]
    assert horizon_module._window_spans(30, 40, 10) == [(1, 30)]


@pytest.mark.parametrize("mode", ["fixed", "sub"])
def test_windowed_and_polished_equals_the_monolithic_optimum(solved, mode):
    """On the short route (K = 30) windows of 12 knots, 4 shared, then the polishing pass of the whole NLP reach the
    monolithic NLP's optimum to IPOPT's tolerance: the same joints to 5e-4 (rad | m) and the same objective to 1e-5
    relative (on long routes they do not: formulations/horizon.md, "Windowed solves")."""
    problem, warm, _, plan = solved
    windowed = plan_horizon(problem, warm, window=12, window_overlap=4, window_mode=mode)
    d = windowed.diagnostics
    assert d["horizon_result"] == "optimal" and len(d["window_log"]) == 4
    assert all(w["kept"] for w in d["window_log"])  # every window was solved and moved the trajectory
    assert d["ipopt_iterations"] == sum(w["iterations"] for w in d["window_log"]) + sum(
        r["iterations"] for r in d["round_log"]
    )
    assert "after 4 windows of 12 knots" in d["horizon_note"]
    np.testing.assert_allclose(windowed.q, plan.q, atol=5e-4)  # measured 1.4e-4 (fixed), 1.7e-4 (sub)
    J = plan.diagnostics["horizon_summary"]["objective"]
    assert d["horizon_summary"]["objective"] == pytest.approx(J, rel=1e-5)  # measured 3.5e-7
    assert windowed.params["horizon_window"] == 12 and "horizon_window" not in plan.params  # runs without: unchanged


@pytest.mark.parametrize("leader_tolerance", [0.0, 0.05])
@pytest.mark.parametrize("a, b", [(1, 9), (12, 20), (23, 30), (1, 30)])
def test_a_windows_own_model_has_the_whole_models_cost_derivatives_and_rows_there(a, b, leader_tolerance):
    """``_Model.window(a, b)``: the model of knots a − 2 … b + 2 alone. At a point off the warm start, its cost's
    gradient and Hessian in the free knots a … b equal the whole model's (the terms it leaves out are those of
    fixed knots: constants), every row that depends on a knot of [a, b] has the whole model's value and lower bound
    there (per-entry bounds sliced), its variable bounds are the whole model's, and it has no fitness row; with the
    leader free (a leader tolerance) too, its rows and f3. With one knot of padding instead of two, the acceleration
    at knot a − 1 would be taken from rest and all of this would fail (checked)."""
    import casadi as ca

    problem, su, model, xv, _ = full_transcription(leader_tolerance=leader_tolerance)
    rng = np.random.default_rng(3)
    x = model.project(xv + rng.normal(0.0, 0.02, xv.size))
    lo = model.lower("clearance") - rng.uniform(0.0, 0.01, model.lower("clearance").shape)
    model.lo_entries["clearance"] = lo  # per-entry bounds, as keep_start_clearance sets them
    sub, a0 = model.window(a, b)
    w = 2 * su.N
    b0 = a0 + sub.su.K
    assert (a0, b0) == (max(0, a - 2), min(su.K, b + 2))
    xs = x[a0 * w : (b0 + 1) * w]
    free, whole = slice((a - a0) * w, (b - a0 + 1) * w), slice(a * w, (b + 1) * w)

    def derivatives(m, at):
        H, g = ca.hessian(m.J, m.x)
        return [np.asarray(v) for v in ca.Function("d", [m.x], [g, H])(at)]

    g, H = derivatives(model, x)
    gs, Hs = derivatives(sub, xs)
    np.testing.assert_allclose(gs[free], g[whole], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(Hs[free, free], H[whole, whole], rtol=1e-12, atol=1e-9)
    vals, svals = model.values(x), sub.values(xs)
    for name in sub.rows:
        cols = model.window_columns(sub, name, a0)
        dep = horizon_module._window_columns(model, name, a, b)[cols]
        assert dep.any(), name
        np.testing.assert_allclose(svals[name][:, dep], vals[name][:, cols[dep]], rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(sub.lower(name)[:, dep], model.lower(name)[:, cols[dep]])
    assert "fitness" in model.rows and "fitness" not in sub.rows
    assert ("leader" in sub.rows) == (leader_tolerance > 0)
    np.testing.assert_array_equal(sub.lbx, model.lbx[a0 * w : (b0 + 1) * w])
    np.testing.assert_array_equal(sub.ubx, model.ubx[a0 * w : (b0 + 1) * w])


def test_window_options_are_checked(solved):
    problem, warm, _, _ = solved
    for bad in ({"window": 1}, {"window": 10, "window_overlap": 10}, {"window": 10, "window_mode": "parallel"}):
        with pytest.raises(ParameterError, match="window"):
            plan_horizon(problem, warm, **bad)


def test_windows_stop_at_the_time_limit_and_the_plan_is_never_worse(feasible_warm, monkeypatch):
    """A deadline already passed stops the first window after its initial point and no further window is solved; the
    whole NLP is stopped the same way and the fallbacks apply as without windows."""
    from tmr.control import horizon

    problem, warm, J_warm = feasible_warm

    class Late(horizon._IterationCallback):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.deadline = -math.inf  # already passed

    monkeypatch.setattr(horizon, "_IterationCallback", Late)
    plan = plan_horizon(problem, warm, **WEIGHTED, window=12, time_limit=DEFAULT_TIME_LIMIT)
    d = plan.diagnostics
    assert len(d["window_log"]) == 1 and d["window_log"][0]["iterations"] <= 1
    assert d["horizon_stop"] == "time_limit" and d["horizon_result"] in ("warm_start", "best_feasible_iterate")
    assert plan.success and objective(plan.q, problem) <= J_warm and d["constraint_violation"] <= 1e-5


def test_crossed_is_the_deepest_violated_clearance_row():
    """_crossed: how far [m] the deepest violated clearance row is past its bound; other groups (other units) do not
    count."""
    V = horizon_model.Violation
    viol = [
        V("clearance", 3, 0.15, "tether 1 at s = 0.5", 0.2, "m"),
        V("separation", 4, 0.2, "robots 1–2 (distance²)", 5.0, "m²"),
        V("clearance", 9, 0.45, "tether 2 at s = 0.1", 0.7, "m"),
    ]
    assert horizon_module._crossed(viol) == 0.7
    assert horizon_module._crossed(viol[1:2]) == 0.0 and horizon_module._crossed([]) == 0.0


def spy_ipopt_calls(monkeypatch: pytest.MonkeyPatch) -> list[tuple[dict, np.ndarray]]:
    """Every IPOPT solve of the horizon NLP from now on (``_Transcription.solver`` wrapped): a list that fills with
    each call's keyword arguments (x0, lam_g0, …) and the x it returned."""
    calls: list[tuple[dict, np.ndarray]] = []
    build = horizon_model._Transcription.solver

    class Spy:
        def __init__(self, solver):
            self.solver = solver

        def __call__(self, **kwargs):
            sol = self.solver(**kwargs)
            calls.append((kwargs, np.asarray(sol["x"], dtype=float).ravel()))
            return sol

        def stats(self):
            return self.solver.stats()

    monkeypatch.setattr(horizon_model._Transcription, "solver", lambda tr, *a, **k: Spy(build(tr, *a, **k)))
    return calls


def test_a_fast_round_that_crossed_obstacles_falls_back_and_other_rounds_restart_inside_the_rows(monkeypatch):
    """crossing_depth: a round whose optimum leaves a left-out clearance row more than that past d_safe crossed an
    obstacle (the walls rooms: 0.65–0.82 m, and IPOPT's next round, started there, crawls in restoration): the fast
    attempt falls back at once; any other round's successor starts from the cheapest kept iterate that holds every
    row, primal only, and reaches the same optimum. The small problem's round 1 (activation 0.3 m) ends 1.2 cm past
    d_safe: the default depth (0.6 m) lets the next round start there, 5 mm does not."""
    problem = small_problem()
    warm, _ = solve(problem, "qp")
    single = dict(activation=0.3, fast_min_hessian_perturbation=None)
    plain = plan_horizon(problem, warm, **single)
    first = plain.diagnostics["round_log"][0]
    assert 0.005 < first["crossed"] < 0.3 and len(plain.diagnostics["round_log"]) == 2 and "next_start" not in first

    calls = spy_ipopt_calls(monkeypatch)
    plan = plan_horizon(problem, warm, crossing_depth=0.005, **single)
    d = plan.diagnostics
    log = d["round_log"]
    assert [r["round"] for r in log] == [1, 2] and log[0]["next_start"].startswith("round 1 primary, iteration ")
    assert log[1]["rows"] >= plain.diagnostics["round_log"][1]["rows"]  # the rows the optimum crossed, and more
    (args1, x1), (args2, _) = calls
    assert "lam_g0" not in args2 and not np.allclose(np.asarray(args2["x0"], dtype=float).ravel(), x1, atol=1e-6)
    assert d["horizon_result"] == "optimal" and check(plan, problem.env).n_violation_steps == 0
    assert d["objective"] == pytest.approx(plain.diagnostics["objective"], rel=1e-5)

    # no kept iterate holds every row: the next round starts from the attempt's initial point (primal only)
    best = horizon_pool._Pool.best
    monkeypatch.setattr(
        horizon_pool._Pool, "best", lambda pool, m, tol, J, *a: None if J == math.inf else best(pool, m, tol, J, *a)
    )
    calls.clear()
    plan = plan_horizon(problem, warm, crossing_depth=0.005, **single)
    d = plan.diagnostics
    assert d["round_log"][0]["next_start"] == "the attempt's initial point (no kept iterate holds every row)"
    (args1, _), (args2, _) = calls[:2]
    assert "lam_g0" not in args2 and np.array_equal(np.asarray(args2["x0"]), np.asarray(args1["x0"]))
    assert d["horizon_result"] == "optimal" and check(plan, problem.env).n_violation_steps == 0
    monkeypatch.setattr(horizon_pool._Pool, "best", best)

    plan = plan_horizon(problem, warm, activation=0.3, crossing_depth=0.005)  # the fast attempt falls back
    d = plan.diagnostics
    assert [r["phase"] for r in d["round_log"]][:2] == ["fast", "fallback"]
    assert d["horizon_summary"]["fast_attempt"]["result"] == "fell_back"
    assert f"a tether sample {d['round_log'][0]['crossed']:.3g} m past its clearance bound" in d["horizon_note"]
    assert (
        "crossed obstacles whose rows were left out" in d["horizon_note"]
        and "crossing_depth = 0.005 m" in d["horizon_note"]
    )
    assert d["horizon_result"] == "optimal" and check(plan, problem.env).n_violation_steps == 0
    real_build = horizon_module._expected_build
    builds = iter([False])  # the fast round's solver is built, the fallback's would take "too long"
    monkeypatch.setattr(
        horizon_module, "_expected_build", lambda rows: real_build(rows) if next(builds, True) is False else 1e9
    )
    d = plan_horizon(problem, warm, activation=0.3, crossing_depth=0.005, time_limit=60.0).diagnostics
    assert d["horizon_stop"] == "rows_crossed" and d["horizon_summary"]["fast_attempt"]["fallback"] == "no time left"
    assert "the optimum of round 1 (primary: 'Solve_Succeeded' after" in d["horizon_note"]
    assert f"crossed obstacles whose rows were left out, {d['round_log'][0]['crossed']:.3g} m past" in d["horizon_note"]
    monkeypatch.setattr(horizon_module, "_expected_build", real_build)
    plan = plan_horizon(problem, warm, activation=0.3)  # 1.2 cm: its round 2 starts at its round 1's optimum
    assert [r["phase"] for r in plan.diagnostics["round_log"]] == ["fast", "fast"]
    with pytest.raises(ParameterError, match="crossing_depth"):
        plan_horizon(problem, warm, crossing_depth=0.0)


@pytest.mark.parametrize(
    "name", ["crossing_depth", "fast_min_hessian_perturbation", "coarse_polish_min_hessian_perturbation"]
)
def test_positive_or_none_options_share_one_rule(name):
    """The three options that are a positive number or None take the same values: a finite real > 0 (numpy's too),
    or None; not 0, a negative, inf, NaN, a bool or a string."""
    for good in (None, 0.3, 1e-5, np.float32(1e-4), 2):
        horizon_model._options({name: good})
    for bad in (0, 0.0, -1e-3, math.inf, math.nan, True, "1e-4"):
        with pytest.raises(ParameterError, match=name):
            horizon_model._options({name: bad})


def test_a_stalled_fast_attempt_stops_and_falls_back(monkeypatch):
    """fast_stall_iter: the iteration callback stops a fast round once that many iterations passed without a cheaper
    iterate holding the round's rows (status "Stalled"), and the fallback starts; iterates outside the rows never
    count as progress; the fallback's own rounds never stall."""
    from tmr.control import horizon

    problem = small_problem()
    warm, _ = solve(problem, "qp")
    _, _, _, xv, tr = full_transcription()
    pool = horizon_pool._Pool(4, 1e-6, math.inf)
    from tqdm import tqdm

    cb = horizon._IterationCallback(tr, pool, tqdm(disable=True), "round 1 fast", math.inf, 3)
    names = [str(n) for n in __import__("casadi").nlpsol_out()]
    g_ok = np.clip(np.zeros(tr.size), tr.lbg, tr.ubg)
    g_bad = np.where(np.isfinite(tr.lbg), tr.lbg - 1.0, tr.ubg + 1.0)

    def step(f, g):
        a = {"x": tr.lbx.clip(-1e9, 1e9), "f": f, "g": g, "lam_x": np.zeros(tr.lbx.size), "lam_g": np.zeros(tr.size)}
        return int(cb.eval([a.get(n, np.zeros(0)) for n in names])[0])

    assert [step(f, g_ok) for f in (1.0, 0.9, 0.95)] == [0, 0, 0]
    assert step(0.1, g_bad) == 0  # cheaper but outside the rows: no progress
    assert step(0.97, g_ok) == 1 and cb.stalled  # three iterations after the cheapest (0.9)

    class NeverCheaper(horizon._IterationCallback):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._best = (-math.inf, 0)  # every iterate is "no cheaper"

    monkeypatch.setattr(horizon, "_IterationCallback", NeverCheaper)
    d = plan_horizon(problem, warm, fast_stall_iter=2).diagnostics
    fast = [r for r in d["round_log"] if r["phase"] == "fast"]
    assert fast and fast[0]["status"] == "Stalled" and fast[0]["iterations"] <= 3
    assert any(r["phase"] == "fallback" for r in d["round_log"]) and d["horizon_result"] == "optimal"
    assert "'Stalled'" in d["horizon_note"]
    with pytest.raises(ParameterError, match="fast_stall_iter"):
        plan_horizon(problem, warm, fast_stall_iter=0)
    for bad in (0, 1.5, True):
        with pytest.raises(ParameterError, match="retry_first_after"):
            plan_horizon(problem, warm, retry_first_after=bad)
        with pytest.raises(ParameterError, match="retry_first_max_iter"):
            plan_horizon(problem, warm, retry_first_max_iter=bad)
    for bad in (0, 1, "yes", None):
        with pytest.raises(ParameterError, match="retry_goes_on"):
            plan_horizon(problem, warm, retry_goes_on=bad)
    for bad in (1e-2, {"max_iter": 0}, {"min_hessian_perturbation": -1.0}):
        with pytest.raises(ParameterError, match="coarse_polish_retry"):
            plan_horizon(problem, warm, coarse_polish_retry=bad)


def _transcriptions(problem, options, clearance=True, warm=None):
    """The problem's NLP at its warm start (default: the qp plan) with about half of every group's entries as rows
    (the fitness rows all; no clearance rows with ``clearance=False``), once with the numpy spline and once with
    casadi's B-spline node: (model, reference model, point off the warm start, transcription, reference
    transcription)."""
    from tmr.control.horizon import _warm_poses

    if warm is None:
        warm, _ = solve(problem, "qp")
    built = []
    for spline in (True, False):
        su = horizon_model._Setup(problem, horizon_model._options(options))
        Q, info = horizon_model._warm_start(su, warm)
        if su.drive is not None:
            _warm_poses(su, warm)
        env = problem.env
        model = horizon_model._Model(
            su, distance_spline(env), bounds=info["warm_start_terms"], spline=ClearanceSpline(env) if spline else None
        )
        built.append((model, model.project(model.x_of(Q))))
    (model, xv), (ref_model, _) = built
    rng = np.random.default_rng(11)
    masks = {}
    for name, v in model.values(xv).items():
        m = np.ones_like(v, dtype=bool) if name == "fitness" else rng.random(v.shape) < 0.5
        if name == "clearance" and not clearance:
            m[:] = False
        m[:, model.fixed_columns(name)] = False
        masks[name] = m
    x = xv + np.random.default_rng(3).normal(0.0, 0.01, xv.size)
    x = np.where(model.lbx == model.ubx, model.lbx, x)
    return (
        model,
        ref_model,
        x,
        horizon_model._Transcription(model, masks),
        horizon_model._Transcription(ref_model, masks),
    )


@pytest.mark.parametrize(
    "case", ["leader tolerance", "no clearance rows", "differential drive", "coarse grid", "without the tolerance"]
)
def test_assembled_derivatives_on_partial_rows_with_a_leader_tolerance(case):
    """With a leader tolerance (its rows before the fitness rows, the tracking term f3 in the cost and a fitness row),
    half of every group's entries as rows, and also without clearance rows, with differential drive, on the coarse
    pass's non-uniform grid (every 3rd knot, the 2 end steps fine) or with the equality leader: the assembled
    Jacobian and exact Hessian are casadi's automatic ones of the same rows through casadi's B-spline node, and the
    Gauss–Newton Hessian is written here from its definition — the rows' exact curvature with the fitness rows'
    multipliers set to 0, plus Σ 2 c_k J_kᵀJ_k with c_k = w_k λ_f / scale + max(μ_k, 0) / f_k,warm."""
    import casadi as ca

    problem = small_problem()
    warm = None
    if case == "differential drive":
        from tmr.model.diffdrive import DEFAULT_MODEL, load_robot_model

        problem = dataclasses.replace(problem, robot_model=load_robot_model(DEFAULT_MODEL))
    if case == "coarse grid":
        from tmr.control.horizon_coarse import coarse_problem

        problem, warm = coarse_problem(problem, solve(problem, "qp")[0], 3, 1.0, ends=2)
        assert np.ptp(np.diff(problem.trajectory.t)) > 0.04  # steps of Ts and 3 Ts
    options = {} if case == "without the tolerance" else {"leader_tolerance": 0.05}
    model, ref_model, x, tr, ref = _transcriptions(problem, options, clearance=case != "no clearance rows", warm=warm)
    if case == "without the tolerance":
        coef_terms = ("f1", "f2", "f4")
        assert "leader" not in tr.offset and tr.offset["fitness"] == 0
    else:
        coef_terms = ("f1", "f2", "f4", "f3")
        assert "f3" in model.fitness_terms  # a free leader: f3 ≤ the warm start's is a row too (stop 60)
    assert tr.size == ref.size and (tr.offset["fitness"] > 0 or case == "without the tolerance")  # the leader first
    lam = np.random.default_rng(4).normal(0.0, 1.0, tr.size)
    lf, scale = 0.7, 2.5
    rx = ref_model.x
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ref.size)

    def full(H):
        H = H.full()
        return np.triu(H) + np.triu(H, 1).T

    def close(a, b):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * max(1.0, float(np.abs(b).max())))

    exact = tr.derivatives(scale, "exact")
    if case == "no clearance rows":
        assert exact == {}  # nothing to assemble: casadi's own derivatives
    else:
        g1, J1 = exact["jac_g"](x, [])
        close(np.asarray(g1).ravel(), np.asarray(ca.Function("g", [rx], [ref.g])(x)).ravel())
        close(J1.full(), ca.Function("J", [rx], [ca.jacobian(ref.g, rx)])(x).full())
        L = lam_f * ref_model.J / scale + ca.dot(lam_g, ref.g)
        close(
            full(exact["hess_lag"](x, [], lf, lam)),
            ca.Function("H", [rx, lam_f, lam_g], [ca.hessian(L, rx)[0]])(x, lf, lam).full(),
        )
    o = model.su.opts
    coef = {"f1": o.w_energy, "f2": o.w_uniformity, "f4": o.w_smoothness, "f3": o.w_tracking}
    coef = {k: w * lf / scale for k, w in coef.items() if k in coef_terms}
    keep = np.ones(tr.size)
    for i, k in enumerate(model.fitness_terms):
        row = tr.offset["fitness"] + i
        keep[row] = 0.0
        coef[k] += max(lam[row], 0.0) / model.bounds[k]
    want = ca.Function("Hg", [rx, lam_g], [ca.hessian(ca.dot(lam_g, ref.g), rx)[0]])(x, lam * keep).full()
    for k, c in coef.items():
        Jr = ca.Function("Jr", [rx], [ca.jacobian(ref_model.residuals[k], rx)])(x).full()
        want += 2 * c * Jr.T @ Jr
    assert model.fitness_terms and any(lam[tr.offset["fitness"] + i] > 0 for i in range(len(model.fitness_terms)))
    close(full(tr.derivatives(scale, "gauss-newton")["hess_lag"](x, [], lf, lam)), want)
    close(full(ref.derivatives(scale, "gauss-newton")["hess_lag"](x, [], lf, lam)), want)


def test_ipopts_own_hessian_option_decides_whether_a_hessian_is_built():
    """``ipopt={"hessian_approximation": "exact"}`` with ``hessian="limited-memory"``: the Hessian is assembled (the
    clearance node has no second derivatives of casadi's own, so casadi could not build it); the plan is optimal."""
    problem = small_problem()
    warm, _ = solve(problem, "qp")
    kw = dict(hessian="limited-memory", fast_hessian="limited-memory", ipopt={"hessian_approximation": "exact"})
    d = plan_horizon(problem, warm, **kw).diagnostics
    assert d["horizon_result"] == "optimal" and d["round_log"][0]["iterations"] < 60


def test_the_fallback_checks_stop_a_share_of_the_limit_past_the_deadline(monkeypatch):
    """The kept iterates are checked cheapest first, every row each (``_Pool.best``); past the time limit by more
    than LATE_CHECK_SHARE of it, no check starts but the first, so a run stopped by the limit overruns it by no more
    than that: here the only feasible iterate is the dearest one, found without a limit and not after it."""
    from tmr.control import horizon

    problem, su, model, xv, _ = full_transcription()
    x_opt = model.project(model.x_of(plan_horizon(problem, solve(problem, "qp")[0]).q))  # every row holds there
    rng = np.random.default_rng(0)
    pool = horizon_pool._Pool(8, 1.0, math.inf)
    for i in range(5):  # cheaper, each with a robot 0.5 m off: infeasible
        pool.offer(0.1 * (i + 1), 0.0, xv + 0.5 * rng.standard_normal(xv.size), f"bad {i}")
    pool.offer(1.0, 0.0, x_opt, "the optimum")
    calls = []
    values = model.values
    monkeypatch.setattr(model, "values", lambda x: calls.append(1) or values(x))
    now = time.perf_counter()
    found = horizon._best_of([pool], model, 1e-5, math.inf, now - 10.0, math.inf)  # no limit
    assert found is not None and found.detail.endswith("(the optimum)") and len(calls) == 6
    calls.clear()
    late = horizon._best_of([pool], model, 1e-5, math.inf, now - 10.0, now - 8.8)  # 10 s past a 60 s limit, 2 %: 1.2 s
    assert late is None and len(calls) == 1
    calls.clear()
    assert horizon._best_of([pool], model, 1e-5, math.inf, now + 60.0, now + 61.2) is not None and len(calls) == 6


def test_a_later_rounds_feasible_iterates_are_kept_beside_an_earlier_rounds_cheaper_ones():
    """_Pool.new_round: a round's iterates, cheaper because they violate rows left out of it, no longer crowd out the
    next round's, which hold them (each round its own places; the earlier rounds share the other ``keep``); an
    earlier round's feasible iterate cheaper than the current round's is still preferred."""
    problem, su, model, xv, _ = full_transcription()
    qp_plan = solve(problem, "qp")[0]
    x_opt = model.project(model.x_of(plan_horizon(problem, qp_plan).q))  # every row holds there
    rng = np.random.default_rng(0)
    bad = [xv + 0.5 * rng.standard_normal(xv.size) for _ in range(6)]  # a robot 0.5 m off: infeasible
    pool = horizon_pool._Pool(4, 1.0, math.inf)
    for i, x in enumerate(bad):  # round 1: cheap and infeasible, more than the pool keeps
        pool.offer(0.1 * (i + 1), 0.0, x, f"round 1, iteration {i}")
    pool.new_round()
    pool.offer(2.0, 0.0, x_opt, "round 2, iteration 0")  # dearer than every round-1 iterate
    pool.offer(3.0, 0.0, bad[0], "round 2, iteration 1")
    assert len(pool) == 6 and [w for _, _, w in pool.sorted()][:4] == [f"round 1, iteration {i}" for i in range(4)]
    found = pool.best(model, 1e-5, math.inf)
    assert found is not None and found.detail == "its best feasible iterate (round 2, iteration 0)"
    one_heap = horizon_pool._Pool(4, 1.0, math.inf)  # the round-1 iterates fill every place: none holds every row
    for i, x in enumerate(bad):
        one_heap.offer(0.1 * (i + 1), 0.0, x, f"round 1, iteration {i}")
    one_heap.offer(2.0, 0.0, x_opt, "round 2, iteration 0")
    assert one_heap.best(model, 1e-5, math.inf) is None
    pool.new_round()  # round 3: the earlier rounds keep their 4 cheapest, the optimum among them only if it is one
    pool.offer(5.0, 0.0, x_opt, "round 3, iteration 0")
    assert pool.best(model, 1e-5, math.inf).detail.endswith("(round 3, iteration 0)")
    x_alt = model.project(model.x_of(plan_horizon(problem, qp_plan, w_uniformity=100.0).q))  # feasible, dearer
    earlier = horizon_pool._Pool(4, 1.0, math.inf)
    earlier.offer(0.5, 0.0, x_opt, "round 1, iteration 0")  # feasible, cheaper than any of round 2
    earlier.new_round()
    earlier.offer(0.7, 0.0, x_alt, "round 2, iteration 0")
    assert earlier.best(model, 1e-5, math.inf, until=-math.inf).detail.endswith("(round 2, iteration 0)")  # 1 check
    assert earlier.best(model, 1e-5, math.inf).detail.endswith("(round 1, iteration 0)")


def test_every_round_after_the_first_and_the_whole_nlp_after_its_windows_start_a_new_round_of_the_pool(monkeypatch):
    """plan_horizon calls _Pool.new_round before each round ≥ 2 of an attempt (the small problem with activation 0.3 m:
    two rounds) and after the windowed solves (the whole NLP's iterates apart from the windows'), never before an
    attempt's round 1 (a new pool)."""
    problem = small_problem()
    warm, _ = solve(problem, "qp")
    calls: list[int] = []
    real = horizon_pool._Pool.new_round
    monkeypatch.setattr(horizon_pool._Pool, "new_round", lambda self: calls.append(len(self)) or real(self))
    d = plan_horizon(problem, warm, activation=0.3, fast_min_hessian_perturbation=None).diagnostics
    assert [r["round"] for r in d["round_log"]] == [1, 2] and len(calls) == 1 and calls[0] > 0  # round 1's kept
    calls.clear()
    d = plan_horizon(problem, warm, window=12, window_overlap=4, fast_min_hessian_perturbation=None).diagnostics
    rounds = [r["round"] for r in d["round_log"]]
    assert len(calls) == 1 + sum(r > 1 for r in rounds) and calls[0] > 0  # the windows' iterates, then each round


@pytest.mark.parametrize("found", ["nothing", "cheaper", "dearer"])
def test_the_fast_attempts_best_feasible_iterate_is_kept_when_the_fallback_finds_nothing(
    feasible_warm, monkeypatch, found
):
    """The fallback starts from the fast attempt's best feasible iterate (checked then, under the late-check bound
    deadline + LATE_CHECK_SHARE × limit); if the fallback then ends without a plan, the plan is the cheaper of that
    iterate and what the final checks find (under the same bound) — not the qp warm start when they find nothing."""
    from tmr.control import horizon

    problem, warm, J_warm = feasible_warm

    class LateFallback(horizon._IterationCallback):
        def __init__(self, tr, pool, bar, label, *args, **kwargs):
            super().__init__(tr, pool, bar, label, *args, **kwargs)
            if "fast" not in label:
                self.deadline = -math.inf  # the fallback's rounds stop at their first iteration

    bounds, seeds = [], []
    best = horizon_pool._Pool.best

    def seed_check(self, model, tol, J_limit, until=math.inf):
        seeds.append(until)
        return best(self, model, tol, J_limit, until)

    def final_checks(pools, model, tol, J_limit, deadline, until):
        bounds.append((deadline, until))
        seed = seeds and pools[0].best(model, tol, J_limit)
        if found == "nothing" or not seed:
            return None
        J = seed.J * (0.5 if found == "cheaper" else 2.0)
        return horizon_pool._Candidate(
            seed.Q, J, "best_feasible_iterate", f"its best feasible iterate ({found})", seed.x
        )

    monkeypatch.setattr(horizon, "_IterationCallback", LateFallback)
    monkeypatch.setattr(horizon_pool._Pool, "best", seed_check)
    monkeypatch.setattr(horizon, "_best_of", final_checks)
    plan = plan_horizon(problem, warm, **WEIGHTED, fast_max_iter=4, fast_stall_iter=None, time_limit=60.0)
    d = plan.diagnostics
    assert "fallback_start" in d["horizon_summary"]["fast_attempt"]
    assert d["horizon_result"] == "best_feasible_iterate"
    detail = "(cheaper)" if found == "cheaper" else "(round 1 fast"
    assert f"returned its best feasible iterate {detail}" in d["horizon_note"]
    assert objective(plan.q, problem, **WEIGHTED) < J_warm
    ((deadline, until),) = bounds
    assert until == pytest.approx(deadline + horizon.LATE_CHECK_SHARE * 60.0, abs=1e-9)
    assert seeds[0] == until  # the seed's check: the same bound
