"""Whole-horizon NLP (``tmr.formulations.horizon``): feasibility, optimality, cost vs warm start, clear failures."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from shapely.geometry import Point

from tmr.chain import Chain
from tmr.clik import Plan
from tmr.environment import Environment
from tmr.errors import InfeasibleStep, ParameterError, TmrError
from tmr.formulations.horizon import (
    GROUPS,
    HorizonInfeasible,
    distance_spline,
    objective,
    objective_terms,
    plan_horizon,
    samples_needed,
)
from tmr.metrics import fitness
from tmr.params import ChainParams, PathParams, PinvParams, QPParams, TaskParams, TimeParams
from tmr.path import time_law
from tmr.planner import Problem, check, solve, span_limits
from tmr.scenario import Scenario

COLUMN = (4.2, 2.0)  # a disc column of radius 0.3 m (0.8 m once inflated) right under the follower's tether
PAST = ((3.2, 2.9), (3.9, 2.95), (4.6, 2.9))  # the leader passes above the column: feasible
THROUGH = ((3.2, 2.9), (4.2, 2.3), (5.2, 2.9))  # the reference dips 0.5 m into the inflated column
GRAZING = ((3.2, 2.9), (4.2, 2.8), (5.2, 2.9))  # the reference touches the inflated column (clearance ≈ 0 < d_safe)


def small_problem(waypoints=PAST, T_end: float = 1.5, limits=None) -> Problem:
    """N = 2 robots in an 8 m × 5 m room with one column, K = 30 steps (T_end = 1.5 s, Ts = 0.05 s)."""
    env = Environment.from_geometry([Point(*COLUMN).buffer(0.3, 64)], (0.0, 0.0, 8.0, 5.0))
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
    with pytest.raises(HorizonInfeasible) as info:
        plan_horizon(problem, warm_start=None)
    err = info.value
    assert isinstance(err, InfeasibleStep) and isinstance(err, TmrError)
    assert err.groups == ["span"] and err.status == "start_infeasible"
    (v,) = err.violations
    assert v.knot == 0 and "tether 2" in v.item and v.amount == pytest.approx(math.hypot(1.2, 0.4) - 1.2, abs=1e-9)
    assert "span" in str(err) and "knot 0" in str(err) and "d_max" in str(err)


def test_unreachable_reference_reports_leader_knots():
    """Both tethers limited to 1.5 m: the end of the reference is out of reach; IPOPT proves local infeasibility."""
    problem = small_problem(limits=[[0.5, 1.5], [1.0, 1.5]])
    with pytest.raises(HorizonInfeasible) as info:
        plan_horizon(problem)
    err = info.value
    assert err.status == "Infeasible_Problem_Detected" and "leader" in err.groups
    reach = 1.5 + 1.5 - 2 * problem.qp_params.span_margin
    far = np.linalg.norm(problem.trajectory.x - problem.chain.base, axis=1) > reach
    worst = max((v for v in err.violations if v.group == "leader"), key=lambda v: v.amount)
    assert far[worst.knot]
    assert "leader" in str(err) and f"knot {worst.knot}" in str(err)


def test_reference_through_obstacle_with_equality_leader_fails_clearly():
    problem = small_problem(THROUGH)
    inside = problem.env.exact_clearance(problem.trajectory.x) < 0
    assert inside.any()
    with pytest.raises(HorizonInfeasible) as info:
        plan_horizon(problem)
    err = info.value
    assert err.status == "Infeasible_Problem_Detected"
    assert set(err.groups) <= {"leader", "clearance"} and "leader" in err.groups
    worst = max((v for v in err.violations if v.group == "leader"), key=lambda v: v.amount)
    assert inside[worst.knot]  # the leader is pulled off its reference where the reference is inside the column
    msg = str(err)
    assert "Infeasible_Problem_Detected" in msg and "leader" in msg and f"knot {worst.knot}" in msg
    for v in err.violations:
        assert v.group in GROUPS and 0 <= v.knot <= 30 and v.amount > 0 and v.t == pytest.approx(0.05 * v.knot)


def test_bounded_leader_error_passes_where_equality_cannot():
    problem = small_problem(GRAZING)
    with pytest.raises(HorizonInfeasible, match="leader"):
        plan_horizon(problem)
    plan = plan_horizon(problem, leader_tolerance=0.1)
    metrics = check(plan, problem.env)
    assert plan.success and metrics.n_violation_steps == 0
    assert 0.0 < metrics.max_tracking_error <= 0.1 + 1e-6


def test_bad_options_and_warm_start():
    problem = small_problem()
    with pytest.raises(ParameterError, match="unknown horizon option"):
        plan_horizon(problem, nonsense=1)
    with pytest.raises(ParameterError):
        plan_horizon(problem, hessian="bfgs")
    bad = dataclasses.replace(solve(problem, "qp")[0], q=np.zeros((31, 3)))
    with pytest.raises(ParameterError, match="warm start"):
        plan_horizon(problem, bad)


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
