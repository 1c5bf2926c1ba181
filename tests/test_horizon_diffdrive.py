"""``--method horizon`` with differential-drive robots (issue 35): the unicycle rows of the NLP against the exact arcs,
a plan of scenario A checked from its recorded poses and no worse than the diff-drive ``qp`` plan in f1–f4, and the
``qp`` plan returned honestly when the time limit leaves no room for IPOPT."""

from __future__ import annotations

from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest

from tmr.control.horizon_model import _diff_rows
from tmr.model.diffdrive import exit_point, load_robot_model, step_velocities, unicycle_step


def test_unicycle_rows_are_the_exact_arcs_and_safe_at_zero_turn():
    """Poses integrated along exact arcs (straight steps with Δθ = 0 exactly among them): the NLP's lateral row is 0
    to rounding, its v, ω equal the checker's (step_velocities), and the rows' Jacobian is finite at Δθ = 0."""
    model = load_robot_model("turtlebot3_burger")
    N, K, Ts, b = 2, 40, 0.05, model.exit_offset
    rng = np.random.default_rng(7)
    v = rng.uniform(-0.2, 0.2, (K, N))
    w = rng.uniform(-2.5, 2.5, (K, N))
    w[::4] = 0.0  # straight steps: sinc(0)
    axle, th = np.zeros((K + 1, N, 2)), np.zeros((K + 1, N))
    axle[0], th[0] = rng.normal(size=(N, 2)), rng.uniform(-3, 3, N)
    for k in range(K):
        axle[k + 1], th[k + 1] = unicycle_step(axle[k], th[k], v[k], w[k], Ts)
    p = exit_point(axle, th, b)
    su = SimpleNamespace(drive=model, N=N, K=K, Ts=Ts)
    X, Y, TH = ca.MX.sym("X", N, K + 1), ca.MX.sym("Y", N, K + 1), ca.MX.sym("TH", N, K + 1)
    rows = _diff_rows(su, X, Y, TH)
    x = ca.vertcat(ca.vec(X), ca.vec(Y), ca.vec(TH))
    f = ca.Function("f", [x], [rows[g].expr for g in ("diff_lateral", "diff_speed", "diff_accel")])
    jac = ca.Function("j", [x], [ca.jacobian(ca.vec(rows["diff_speed"].expr), x)])
    xv = np.concatenate([p[..., 0].T.ravel(order="F"), p[..., 1].T.ravel(order="F"), th.T.ravel(order="F")])
    lat, speed, acc = (np.asarray(a) for a in f(xv))
    assert np.max(np.abs(lat)) < 1e-12
    vc, wc, _ = step_velocities(axle, th, Ts)
    assert np.allclose(speed[:N].T, vc, atol=1e-12) and np.allclose(speed[N : 2 * N].T, wc, atol=1e-12)
    h = 0.5 * su.drive.track  # the wheels' rim speeds v ± ω L/2
    assert np.allclose(speed[2 * N : 3 * N].T, vc + h * wc, atol=1e-12)
    assert np.allclose(speed[3 * N :].T, vc - h * wc, atol=1e-12)
    assert np.allclose(speed[: 2 * N], np.vstack([v.T, w.T]), atol=1e-12)
    dv = np.diff(np.vstack([np.zeros((1, N)), v]), axis=0) / Ts
    assert np.allclose(acc[:N].T, dv, atol=1e-9)
    assert np.all(np.isfinite(np.asarray(jac(xv).full())))


@pytest.fixture(scope="module")
def problem_A():
    from tmr.planner import build_problem
    from tmr.world.scenario import load_scenario

    return build_problem(load_scenario("A"), overrides={"drive": "diff"})


def _check_diff(plan, metrics):
    assert plan.success, plan.failure
    assert plan.heading is not None and plan.axle is not None
    assert np.max(np.abs(step_velocities(plan.axle, plan.heading, plan.Ts)[2])) <= 1e-9
    for kind in ("lateral_velocity", "linear_speed", "angular_speed", "linear_acceleration", "angular_acceleration"):
        assert not metrics.violation_steps[kind], kind


def test_diff_horizon_of_A_passes_the_diff_checks_and_is_no_worse_than_qp(problem_A):
    from tmr.planner import solve

    qp, mq = solve(problem_A, "qp")
    plan, metrics = solve(problem_A, "horizon")
    _check_diff(plan, metrics)
    assert plan.method == "horizon" and plan.diagnostics["horizon_result"] in ("optimal", "best_feasible_iterate")
    for k in ("f1", "f2", "f3", "f4"):
        assert getattr(metrics, k) <= getattr(mq, k), k
    assert metrics.f2 < 0.1 * mq.f2  # the NLP did improve on the qp plan, not only return it


def test_diff_horizon_with_a_tiny_time_limit_returns_the_qp_plan(problem_A):
    from tmr.planner import solve

    qp, mq = solve(problem_A, "qp")
    plan, metrics = solve(problem_A, "horizon", time_limit=1e-3)
    _check_diff(plan, metrics)
    assert plan.diagnostics["horizon_result"] == "warm_start"
    assert "time limit" in plan.diagnostics["horizon_note"]
    assert np.array_equal(plan.q, qp.q) and np.array_equal(plan.heading, qp.heading)
    assert np.array_equal(plan.axle, qp.axle) and np.array_equal(plan.drive_v, qp.drive_v)
    for k in ("f1", "f2", "f3", "f4"):
        assert getattr(metrics, k) == getattr(mq, k), k
