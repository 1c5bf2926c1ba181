"""The coarse pass of the horizon NLP (``tmr.control.horizon_coarse``, ``formulations/horizon.md`` "Coarse knots"):
the NLP on every M-th knot, its optimum interpolated to every knot and returned only if every row of the whole NLP
holds there; else the whole NLP starts from it."""

from __future__ import annotations

import numpy as np
import pytest

import tmr.control.horizon as horizon_module
import tmr.control.horizon_coarse as coarse
import tmr.control.horizon_model as horizon_model
from tests.test_horizon import small_problem
from tmr.control.horizon import objective_terms, plan_horizon
from tmr.errors import ParameterError
from tmr.planner import check, solve

ON = dict(coarse_knots=10, coarse_from=10)  # K = 30: every 3rd knot
GRID = np.arange(0, 31, 3)
ENDS = np.array([0, 1, 2, 3, 6, 9, 12, 15, 18, 21, 24, 27, 28, 29, 30])  # coarse_ends = 3: every knot of both ends


@pytest.fixture(scope="module")
def problem_and_warm():
    problem = small_problem()
    warm, warm_metrics = solve(problem, "qp")
    assert warm.success
    return problem, warm, warm_metrics


def test_stride_indices_and_the_coarse_problem(problem_and_warm):
    problem, warm, _ = problem_and_warm
    assert coarse.stride(30, 10, 10) == 3 and coarse.stride(30, 10, 32) == 1 and coarse.stride(30, None, 0) == 1
    assert coarse.stride(1126, 200, 500) == 6
    np.testing.assert_array_equal(coarse.coarse_indices(30, 3), GRID)
    np.testing.assert_array_equal(coarse.coarse_indices(31, 3)[-3:], [24, 27, 31])  # a 1-step last step merged
    np.testing.assert_array_equal(coarse.coarse_indices(32, 3)[-3:], [27, 30, 32])  # a 2-step last step kept
    np.testing.assert_array_equal(coarse.coarse_indices(30, 3, 3), ENDS)
    np.testing.assert_array_equal(coarse.coarse_indices(30, 1), np.arange(31))
    pc, wc = coarse.coarse_problem(problem, warm, 3, 0.9, 0.02)
    t = pc.trajectory.t
    np.testing.assert_allclose(t, problem.trajectory.t[GRID])  # the knots' own times
    np.testing.assert_array_equal(pc.trajectory.x, problem.trajectory.x[GRID])
    np.testing.assert_array_equal(wc.q, warm.q[GRID])
    assert pc.qp_params.robot_accel_max == pytest.approx(0.9 * problem.qp_params.robot_accel_max)
    assert pc.qp_params.span_speed_max == pytest.approx(0.9 * problem.qp_params.span_speed_max)
    assert pc.qp_params.separation_margin == pytest.approx(problem.qp_params.separation_margin + 0.02)
    assert pc.qp_params.d_safe == problem.qp_params.d_safe  # the clearance margin is plan_horizon's d_safe option
    assert problem.trajectory.t.size == 31  # the problem itself is unchanged


def test_the_non_uniform_grid_weights_each_term_by_its_interval():
    """On the coarse grid q̇_k = Δq_k / h_k, q̈_k = (q̇_k − q̇_{k−1}) / h̄_k, and each term is weighted by its interval
    over h_0: a trajectory sampled from a uniform one gives about the uniform sums (exactly for f1 of a straight
    line at constant speed)."""
    t = np.arange(31) * 0.05
    q = np.zeros((31, 4))
    q[:, 1] = 1.0 + 0.2 * t  # span 1 grows at 0.2 m/s, span 2 constant
    q[:, 3] = 1.0
    fine = objective_terms(q, 0.05)
    on_grid = objective_terms(q[ENDS], t[ENDS])
    assert on_grid["f1"] == pytest.approx(fine["f1"], rel=1e-12)  # Σ (h_k / h_0) q̇² = Σ over the fine steps
    assert on_grid["f2"] == pytest.approx(fine["f2"], rel=0.02)
    h, hbar = horizon_model.knot_weights(t[ENDS])
    np.testing.assert_allclose(h, np.diff(t[ENDS]))
    np.testing.assert_allclose(hbar[[0, -1, 4]], [0.05, 0.05, 0.15])
    np.testing.assert_allclose(objective_terms(q, t)["f4"], fine["f4"], rtol=1e-12)  # uniform times: the same sums


def test_interpolation_passes_through_the_coarse_knots_with_the_coarse_accelerations():
    t = np.arange(31) * 0.05
    idx = coarse.coarse_indices(30, 3)
    rng = np.random.default_rng(0)
    R = np.cumsum(rng.normal(0, 0.01, (idx.size, 2, 2)), axis=0)
    F = coarse.interpolate(R, t, 3)
    np.testing.assert_allclose(F[idx], R, atol=1e-12)
    # a quadratic in time is reproduced exactly (the spline is quadratic): its accelerations are the coarse ones
    Rq = 0.5 * 2.0 * (t[idx] ** 2)[:, None, None] * np.ones((1, 2, 2))
    Fq = coarse.interpolate(Rq, t, 3)
    np.testing.assert_allclose(Fq[:, 0, 0], t**2, atol=1e-12)


@pytest.mark.parametrize("polish, ends", [(15, 0), (0, 0), (0, 3)])
def test_the_coarse_optimum_is_returned_only_where_every_row_holds(problem_and_warm, polish, ends):
    """Accepted (every row of the whole NLP holds at the interpolated coarse optimum), it is polished by the whole
    NLP (converged: "optimal"), or returned as it is without a polish ("coarse_optimal"); either passes the exact
    check and is no worse than qp. The polish reaches a lower cost than the coarse optimum."""
    problem, warm, warm_metrics = problem_and_warm
    plan = plan_horizon(problem, warm, coarse_polish_iter=polish, coarse_ends=ends, **ON)
    d = plan.diagnostics
    log = d["horizon_summary"]["coarse"]
    grid = ENDS if ends else GRID  # with ends: the non-uniform grid's NLP, end to end
    assert log["stride"] == 3 and log["knots"] == grid.size and log["result"] == "accepted"
    assert d["horizon_note"].startswith(f"IPOPT solved the NLP on every 3rd knot ({grid.size} of 31")
    if polish:
        assert log["polish"] == "converged" and d["horizon_result"] == "optimal"
        assert d["ipopt_iterations"] > log["iterations"] and "from it, IPOPT solved the NLP" in d["horizon_note"]
        coarse_only = plan_horizon(problem, warm, coarse_polish_iter=0, **ON)
        assert d["objective"] < coarse_only.diagnostics["objective"]
    else:
        assert d["horizon_result"] == "coarse_optimal" and d["ipopt_iterations"] == log["iterations"]
        assert d["rows"] == 0 and "returned the optimum on every 3rd knot, interpolated" in d["horizon_note"]
    metrics = check(plan, problem.env)  # exact clearances of robots and tether segments at every step
    assert plan.success and metrics.n_violation_steps == 0
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(warm_metrics, f) * (1 + 1e-9)
    terms = objective_terms(plan.q, 0.05)
    assert terms["f1"] == pytest.approx(d["f1"], rel=1e-9)
    # no coarse pass below coarse_from: the records hold no "coarse" entry
    plain = plan_horizon(problem, warm)
    assert "coarse" not in plain.diagnostics["horizon_summary"]


def test_an_accepted_coarse_optimum_without_time_to_polish_says_so(problem_and_warm, monkeypatch):
    """The time limit is reached once the coarse pass is done: its optimum is returned ("coarse_optimal") and the
    note says that the polish did not start, instead of describing it."""
    import time

    problem, warm, _ = problem_and_warm
    real = horizon_module._coarse_pass

    def then_out_of_time(*args):
        out = real(*args)
        deadline = args[7]
        time.sleep(max(0.0, deadline - time.perf_counter()) + 0.01)  # the rest of the limit passes
        return out

    monkeypatch.setattr(horizon_module, "_coarse_pass", then_out_of_time)
    d = plan_horizon(problem, warm, time_limit=6, **ON).diagnostics
    log = d["horizon_summary"]["coarse"]
    assert log["result"] == "accepted" and log["polish"] == "time_limit"
    assert d["horizon_result"] == "coarse_optimal" and d["ipopt_iterations"] == log["iterations"]
    assert "the whole NLP from its optimum: not started (time limit)" in d["horizon_note"]
    assert "at most 60 iterations" not in d["horizon_note"]


def test_a_rejected_interpolation_starts_the_whole_nlp_from_it(problem_and_warm, monkeypatch):
    """Interpolated with a kink that breaks the robot acceleration rows, the coarse optimum is rejected (the log names
    the rows); the whole NLP then starts from it and its optimum is returned, every row holding."""
    problem, warm, warm_metrics = problem_and_warm
    real = coarse.interpolate

    def kinked(robots, t, M, ends=0):
        F = real(robots, t, M, ends)
        F[15, 0, 1] += 0.05  # robot 1 jumps 5 cm up at one knot: |ÿ| = 0.05 / Ts² = 20 m/s² > a_rob
        return F

    monkeypatch.setattr(horizon_module, "interpolate", kinked)
    plan = plan_horizon(problem, warm, **ON)
    d = plan.diagnostics
    log = d["horizon_summary"]["coarse"]
    assert log["result"] == "rejected" and "robot_accel" in log["reason"]
    assert log["fine_start"] == "the interpolated coarse optimum" and "x" not in log
    assert d["horizon_result"] == "optimal" and d["ipopt_iterations"] > log["iterations"]
    # the note says what became of the coarse pass (its first violated group), and the fine attempt's floor
    first = log["reason"].split(" | ")[0].split("; ")[0]  # "interpolated, it violates <group>: …, worst: <row>"
    assert f"; before it, the NLP on every 3rd knot was solved, its optimum rejected ({first});" in d["horizon_note"]
    assert "IPOPT min_hessian_perturbation" in d["horizon_note"]
    metrics = check(plan, problem.env)
    assert plan.success and metrics.n_violation_steps == 0
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(warm_metrics, f) * (1 + 1e-9)
    # a fast attempt cut at 1 iteration falls back to where the procedure started: the interpolation, not the qp plan
    d = plan_horizon(problem, warm, **ON, fast_max_iter=1).diagnostics
    fast = d["horizon_summary"]["fast_attempt"]
    assert fast["result"] == "fell_back" and "fallback_start" not in fast  # its one iterate holds no row more
    assert ", so fell back to 0.001 (Gauss–Newton Hessian) from the interpolated coarse optimum;" in d["horizon_note"]


def test_coarse_options_are_checked(problem_and_warm):
    problem, warm, _ = problem_and_warm
    bad_options = (
        dict(coarse_knots=1),
        dict(coarse_margin=-0.1),
        dict(coarse_rate_scale=0),
        dict(coarse_time_share=2),
        dict(clearance_margin=-0.01),
        dict(coarse_ends=-1),
    )
    for bad in bad_options:
        with pytest.raises(ParameterError):
            plan_horizon(problem, warm, **bad)
