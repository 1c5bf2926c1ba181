"""Scenario → problem → plan: limits from the catenary, start placement, the plan verdict."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tmr.checks.metrics import evaluate
from tmr.errors import ParameterError, ScenarioError
from tmr.model import catenary
from tmr.model.chain import Chain
from tmr.model.params import ChainParams, PathParams, PinvParams, QPParams, TimeParams, apply_overrides
from tmr.planner import build_problem, check, default_start, qp_run, solve, span_limits
from tmr.world.scenario import load_scenario


def test_span_limits_from_bubbles_and_catenary():
    lim = span_limits(3, ChainParams())
    np.testing.assert_allclose(lim[:, 0], [0.5, 1.0, 1.0])
    np.testing.assert_allclose(lim[:, 1], catenary.max_span(0.43, 0.43), rtol=1e-12)
    assert lim[0, 1] == pytest.approx(5.596, abs=1e-3)
    # a heavier cable shortens d_max; when it drops below 2r there is no feasible chain
    heavy = span_limits(2, ChainParams(cable_mass_per_length=0.6))
    assert heavy[1, 1] < lim[1, 1]
    with pytest.raises(ParameterError, match="catenary limit"):
        span_limits(2, ChainParams(cable_mass_per_length=40.0))


def test_params_validation_and_overrides():
    with pytest.raises(ParameterError):
        PinvParams(dls_damping=1.5)
    with pytest.raises(ParameterError):
        TimeParams(Ts=-0.1)
    with pytest.raises(ParameterError, match="finite"):
        ChainParams(safety_radius=float("nan"))
    p, rest = apply_overrides(PinvParams(), {"k_v0": 0.1, "other": 1})
    assert p.k_v0 == 0.1 and rest == {"other": 1}
    assert TimeParams().steps == 300
    assert PathParams(path_clearance=0.6).clearances == (0.6, 0.3, 0.05)


def test_default_start_is_free_and_heads_for_the_goal(open_room, column_room):
    chain = Chain(3, base=(1.0, 6.0))
    lim = span_limits(3, ChainParams())
    P = default_start(chain, open_room, np.array([10.0, 6.0]), lim)
    np.testing.assert_allclose(P, [[2.2, 6.0], [3.4, 6.0], [4.6, 6.0]], atol=1e-12)
    # blocked straight ahead by the column: another heading, still free
    chain = Chain(3, base=(3.0, 6.0))
    P = default_start(chain, column_room, np.array([10.0, 6.0]), lim)
    assert np.all(column_room.exact_clearance(P) > 0.2)
    assert np.all(column_room.segment_clearance(np.vstack([chain.base, P[:-1]]), P) > 0.2)


def test_build_problem_rejects_unknown_parameters_and_bad_start():
    sc = load_scenario("A")
    with pytest.raises(ScenarioError, match="unknown parameter"):
        build_problem(sc, overrides={"kv0": 1.0}, path_iterations=200)
    with pytest.raises(ScenarioError, match="inside an"):
        build_problem(sc, start=[[5.0, 5.0], [6.0, 6.0], [7.0, 7.0]], path_iterations=200)
    with pytest.raises(ScenarioError, match="start lists 1 position for 3 robots"):
        build_problem(sc, start=[[2.0, 5.0]], path_iterations=200)
    with pytest.raises(ScenarioError, match=r"start must be 3 \(x, y\) positions \[m\], got shape \(3, 3\)"):
        build_problem(sc, start=np.ones((3, 3)), path_iterations=200)


def test_plan_verdict_is_taken_from_recorded_states():
    sc = load_scenario("A")
    problem = build_problem(sc, seed=0, path_iterations=300, route="rrt")  # the paper's RRT* leader over 15 s
    plan, metrics = solve(problem, "pinv")
    assert problem.trajectory.t.size == 301
    np.testing.assert_allclose(plan.robots[0], problem.chain.robots(problem.q0))
    assert metrics.final_leader_error < 0.01
    # the verdict agrees with the recorded states
    assert plan.success == (metrics.n_violation_steps == 0)
    if not plan.success:
        assert np.isinf(metrics.f1) and np.all(np.isfinite(metrics.fitness_raw))
    # push a robot into a column at one step: the checker must catch exactly that
    plan.success, plan.failure = True, None
    plan.robots = plan.robots.copy()
    plan.robots[150, 1] = [5.0, 5.0]
    m = check(plan, problem.env)
    assert not plan.success and "robot_clearance" in plan.failure
    assert 150 in m.violation_steps["robot_clearance"] and np.isinf(m.f4)
    # the failed plan's metrics are exactly those a fresh evaluation of the failed plan gives (check evaluates once)
    fresh = evaluate(plan, problem.env)
    assert json.dumps(m.to_dict(), default=str) == json.dumps(fresh.to_dict(), default=str)


def test_rrt_route_plans_one_rrt_star_path_for_start_and_leader(monkeypatch):
    """--route rrt: the anchor→goal RRT* path places the robots and its tail is the leader's path (issue 14)."""
    import tmr.planner
    import tmr.route.path

    calls = []
    real = tmr.planner.plan_leader_path

    def counting(*args, **kwargs):
        calls.append(args[1:3])
        return real(*args, **kwargs)

    monkeypatch.setattr(tmr.planner, "plan_leader_path", counting)
    monkeypatch.setattr(tmr.route.path, "plan_leader_path", counting)  # what tmr.route.path.leader_trajectory calls
    sc = load_scenario("A")
    problem = build_problem(sc, seed=0, path_iterations=300, route="rrt")
    assert len(calls) == 1  # one RRT*, from the anchor
    np.testing.assert_array_equal(calls[0][0], sc.base)
    W = real(sc.environment, sc.base, sc.goal, seed=0, iterations=300, clearance=PathParams().path_clearance)
    leader0 = problem.chain.robots(problem.q0)[-1]
    wp = problem.trajectory.waypoints
    np.testing.assert_allclose(wp[0], leader0, atol=1e-9)  # the leader starts where it was placed ...
    np.testing.assert_array_equal(wp[-1], sc.goal)  # ... and ends at the goal ...
    # ... along the anchor's path: every waypoint after the first is one of its vertices, in order
    idx = [int(np.flatnonzero(np.all(W == p, axis=1))[0]) for p in wp[1:]]
    assert idx == list(range(len(W) - len(idx), len(W)))
    # the leader's position lies on the anchor path's segment that precedes those vertices
    a, b = W[idx[0] - 1], W[idx[0]]
    cross = (b - a)[0] * (leader0 - a)[1] - (b - a)[1] * (leader0 - a)[0]
    assert abs(cross) < 1e-9 * np.linalg.norm(b - a) and np.dot(leader0 - a, b - a) > 0
    # a given start cannot reuse the anchor's path: the leader plans its own (a second RRT* call from its position)
    calls.clear()
    start = problem.chain.robots(problem.q0) + [0.0, 0.3]
    build_problem(sc, seed=0, path_iterations=300, route="rrt", start=start)
    assert len(calls) == 1 and np.array_equal(calls[0][0], start[-1])


@pytest.mark.parametrize(
    ("cls", "field"),
    [(ChainParams, "safety_radius"), (QPParams, "robot_accel_max"), (QPParams, "accel_max"), (PinvParams, "k_v0")],
)
def test_bounds_of_every_parameter_set(cls, field):
    with pytest.raises(ParameterError, match=field):
        cls(**{field: -1.0})


def test_build_problem_takes_the_environments_robot_radius():
    """One robot radius: the chain's r is the one the obstacles are grown by, a different one is refused."""
    sc = load_scenario("A", safety_radius=0.3)
    problem = build_problem(sc)
    assert problem.chain_params.safety_radius == 0.3
    assert problem.span_limits[0, 0] == pytest.approx(0.3) and problem.span_limits[1, 0] == pytest.approx(0.6)
    with pytest.raises(ParameterError, match="grown by 0.3 m"):
        build_problem(sc, overrides={"safety_radius": 0.5})


@pytest.fixture(scope="module")
def scenario_a_qp():
    problem = build_problem(load_scenario("A"))
    return problem, *solve(problem, "qp")


@pytest.mark.parametrize("limit", [1e-3, 0.5], ids=["before IPOPT", "IPOPT stopped"])
def test_horizon_stopped_early_is_never_worse_than_qp_in_any_term(scenario_a_qp, limit, monkeypatch):
    """``solve(problem, "horizon")`` starts from the very plan ``solve(problem, "qp")`` returns: stopped by its time
    limit before IPOPT runs it returns that plan itself (same joints, bit for bit); stopped during IPOPT, a plan
    whose f1, f2, f3, f4 are each ≤ the qp plan's, passing every check."""
    problem, qp, qp_metrics = scenario_a_qp
    if limit >= 0.01:  # the horizon reads its clock 14 times before IPOPT, then once an iteration: 20 ms a reading
        # stops IPOPT after about 11 of the 18 iterations it takes on A, on any machine
        import itertools
        from types import SimpleNamespace

        import tmr.control.horizon as horizon

        ticks = itertools.count()
        monkeypatch.setattr(horizon, "time", SimpleNamespace(perf_counter=lambda: 0.02 * next(ticks)))
    plan, metrics = solve(problem, "horizon", time_limit=limit)
    d = plan.diagnostics
    assert plan.success and metrics.n_violation_steps == 0 and d["time_limit_hit"]
    for k in ("f1", "f2", "f3", "f4"):
        assert getattr(metrics, k) <= getattr(qp_metrics, k), k
    if limit < 0.01:
        assert d["horizon_result"] == "warm_start" and d["ipopt_iterations"] == 0
        np.testing.assert_array_equal(plan.q, qp.q)
        assert "the warm-start qp plan as given" in d["horizon_note"]
    else:
        assert d["ipopt_iterations"] > 0 and d["horizon_stop"] == "time_limit"  # IPOPT ran, and was stopped
    assert "vs its qp warm start: f1 " in d["horizon_note"] and "IPOPT iterations in all" in d["horizon_note"]
    assert d["horizon_summary"]["warm_start_terms"]["f1"] == pytest.approx(qp_metrics.f1, rel=1e-9)


def test_horizon_converged_is_no_worse_than_qp_in_any_term(scenario_a_qp):
    """IPOPT converges on A; its plan improves on the qp plan in every term (f1, f2, f4 are rows f_i ≤ f_i,qp)."""
    problem, qp, qp_metrics = scenario_a_qp
    plan, metrics = solve(problem, "horizon")
    d = plan.diagnostics
    assert d["horizon_result"] == "optimal" and plan.success and metrics.n_violation_steps == 0
    assert metrics.f1 < qp_metrics.f1 and metrics.f2 < qp_metrics.f2 and metrics.f4 < qp_metrics.f4
    assert metrics.f3 <= qp_metrics.f3  # the leader on its reference: ~0
    assert d["horizon_summary"]["result"] == "optimal" and d["horizon_summary"]["iterations"] > 0


def test_horizon_from_a_qp_run_is_the_horizon_that_plans_its_own(scenario_a_qp, monkeypatch):
    """``solve(problem, "horizon", qp=qp_run(problem))`` starts from that run's plan without planning it again and
    returns the plan ``solve(problem, "horizon")`` does (the same joints, bit for bit), the run's seconds counted
    once in its ``qp_time`` and ``wall_time``; ``qp=`` with another method, or made for another problem, is
    refused."""
    import dataclasses

    import tmr.planner

    problem = scenario_a_qp[0]
    own, _ = solve(problem, "horizon")
    run = qp_run(problem)
    assert run.plan.success and run.problem is run.source is problem and run.seconds > 0
    with pytest.raises(ParameterError, match="method 'horizon' only"):
        solve(problem, "qp", qp=run)
    with pytest.raises(ParameterError, match="made for another problem"):
        solve(dataclasses.replace(problem), "horizon", qp=run)

    def again(*a, **k):
        raise AssertionError("the qp plan was planned again")

    monkeypatch.setattr(tmr.planner, "_solve_qp", again)
    run = dataclasses.replace(run, seconds=1000.0)  # a qp run of 1000 s: counted once, not twice, not left out
    plan, metrics = solve(problem, "horizon", qp=run)
    np.testing.assert_array_equal(plan.q, own.q)
    assert plan.diagnostics["horizon_result"] == own.diagnostics["horizon_result"] == "optimal"
    timings = plan.diagnostics["timings"]
    assert 1000.0 <= timings["qp_time"] < 1001.0 and 1000.0 + timings["nlp_time"] <= plan.wall_time < 1100.0
    assert metrics.wall_time == plan.wall_time


def test_a_start_of_another_count_is_refused_before_the_route(monkeypatch):
    """build_problem(start=2 positions) on a 3-robot scenario: the start never changes N by itself; refused naming
    both counts, before any route is searched."""
    import tmr.planner

    def boom(*a, **k):
        raise AssertionError("searched a route for a start of the wrong count")

    monkeypatch.setattr(tmr.planner, "plan_route", boom)
    sc = load_scenario("A")
    with pytest.raises(ScenarioError, match=r"start lists 2 positions for 3 robots: give one \(x, y\) per robot"):
        build_problem(sc, start=[[2.0, 4.0], [3.2, 4.0]])
    with pytest.raises(ScenarioError, match="start lists 3 positions for 4 robots"):
        build_problem(sc, n_robots=4, start=[[2.0, 4.0], [3.2, 4.0], [4.4, 4.0]])


def test_horizon_without_a_solution_returns_the_qp_plan_with_its_summary(scenario_a_qp, monkeypatch):
    """When the NLP finds nothing its own (stricter) rows accept, the planner returns the very qp plan, which passed
    every check, and says so: the run summary and metrics.json's ``horizon`` block name it, f1–f4 unchanged."""
    from tmr.control import horizon
    from tmr.control.horizon_model import HorizonInfeasible

    problem, qp, qp_metrics = scenario_a_qp

    def fails(*args, **kwargs):
        raise HorizonInfeasible(
            "horizon NLP: made to fail by the test; details", [], status="Infeasible_Problem_Detected"
        )

    monkeypatch.setattr(horizon, "plan_horizon", fails)
    plan, metrics = solve(problem, "horizon")
    d = plan.diagnostics
    assert plan.success and d["horizon_result"] == "warm_start"
    np.testing.assert_array_equal(plan.q, qp.q)
    assert (
        d["horizon_note"]
        == "horizon NLP: made to fail by the test; returned its qp warm start, which passes every check"
    )
    summary = d["horizon_summary"]
    assert summary["result"] == "warm_start" and summary["stop"] == "Infeasible_Problem_Detected"
    assert summary["terms"] == summary["warm_start_terms"] and summary["terms"]["f1"] == pytest.approx(qp_metrics.f1)
