"""The coarse pass of the horizon NLP (``tmr.control.horizon_coarse``, ``formulations/horizon.md`` "Coarse knots"):
the NLP on every M-th knot, its optimum interpolated to every knot and returned only if every row of the whole NLP
holds there; else the whole NLP starts from it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

import tmr.control.horizon as horizon_module
import tmr.control.horizon_coarse as coarse
import tmr.control.horizon_model as horizon_model
from tests.test_horizon import small_problem, spy_ipopt_calls
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
    # a shorter horizon of many robots (stop 73): knots × robots N (K + 1) ≥ from_size, the bound included
    assert (
        coarse.stride(483, 100, 500, from_size=3000, N=8) == 5
        and coarse.stride(374, 100, 500, from_size=3000, N=8) == 4
    )
    assert (
        coarse.stride(373, 100, 500, from_size=3000, N=8) == 1
        and coarse.stride(483, 100, 500, from_size=3000, N=6) == 1
    )
    assert coarse.stride(483, 100, 500, N=8) == 1 and coarse.stride(2999, None, 500, from_size=3000, N=8) == 1
    with pytest.raises(ValueError, match="needs the robots"):
        coarse.stride(483, 100, 500, from_size=3000)
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
        assert "repaired" not in d["horizon_note"]
    metrics = check(plan, problem.env)  # exact clearances of robots and tether segments at every step
    assert plan.success and metrics.n_violation_steps == 0
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(warm_metrics, f) * (1 + 1e-9)
    terms = objective_terms(plan.q, 0.05)
    assert terms["f1"] == pytest.approx(d["f1"], rel=1e-9)
    # no coarse pass below coarse_from: the records hold no "coarse" entry
    plain = plan_horizon(problem, warm)
    assert "coarse" not in plain.diagnostics["horizon_summary"]


def test_a_short_horizon_of_many_robots_gets_the_same_coarse_pass(problem_and_warm):
    """``coarse_from_size``: a horizon shorter than ``coarse_from`` gets the coarse pass where its knots × robots
    reach the size, the very pass the knots rule gives (the same plan, bit for bit); one knot-robot short, none."""
    problem, warm, _ = problem_and_warm
    size = problem.chain.n_robots * 31  # K = 30
    by_knots = plan_horizon(problem, warm, coarse_polish_iter=0, coarse_from_size=None, **ON)
    by_size = plan_horizon(
        problem, warm, coarse_knots=10, coarse_from=10**6, coarse_from_size=size, coarse_polish_iter=0
    )
    assert by_size.diagnostics["horizon_summary"]["coarse"]["stride"] == 3
    np.testing.assert_array_equal(by_size.q, by_knots.q)
    assert by_size.diagnostics["horizon_note"] == by_knots.diagnostics["horizon_note"]
    below = plan_horizon(problem, warm, coarse_knots=10, coarse_from=10**6, coarse_from_size=size + 1)
    assert "coarse" not in below.diagnostics["horizon_summary"]


def test_the_polish_starts_with_the_rows_near_the_coarse_optimum_only(problem_and_warm, monkeypatch):
    """The polish's first round holds the rows near the accepted coarse optimum it starts from (``_Model.near``), not
    also those near the warm start, whose near rows are no rows of its (stop 61, on the 155 generated-room runs with an
    accepted coarse optimum: 8 more polished optima, 8 % less time in all, f1 + f2 + f4 a geometric mean 0.96×)."""
    problem, warm, _ = problem_and_warm
    built: list[tuple[object, dict[str, np.ndarray]]] = []
    init = horizon_model._Transcription.__init__

    def spy(tr, model, masks):
        built.append((model, {g: m.copy() for g, m in masks.items()}))
        init(tr, model, masks)

    monkeypatch.setattr(horizon_model._Transcription, "__init__", spy)
    calls = spy_ipopt_calls(monkeypatch)
    d = plan_horizon(problem, warm, coarse_polish_retry=None, **ON).diagnostics
    monkeypatch.undo()
    assert d["horizon_summary"]["coarse"]["result"] == "accepted" and d["horizon_result"] == "optimal"
    polish = [r for r in d["round_log"] if r["phase"] == "polish"]
    model, masks = built[-len(polish)]  # the polish's first transcription (fine knots: K = 30)
    x0 = np.asarray(calls[-len(polish)][0]["x0"], dtype=float).ravel()  # where it started: the coarse optimum
    assert model.su.K == 30 and polish[0]["rows"] == sum(int(m.sum()) for m in masks.values())
    near = model.near_masks(model.values(x0))
    for g in masks:
        np.testing.assert_array_equal(masks[g], near[g], err_msg=g)
    # the warm start's near rows that are not near the coarse optimum: rows the union held
    Qw, _ = horizon_model._warm_start(model.su, warm)
    at_warm = model.near_masks(model.values(model.project(model.x_of(Qw))))
    assert sum(int((at_warm[g] & ~near[g]).sum()) for g in near) > 0


def test_the_polish_runs_with_its_own_floor(problem_and_warm):
    """The polish's IPOPT floor is ``coarse_polish_min_hessian_perturbation`` (10⁻⁴), recorded in its rounds and the
    note; ``None`` gives the fast attempt's (10⁻⁵); an ``ipopt`` floor, merged last, wins and is the one named."""
    problem, warm, _ = problem_and_warm
    for given, floor in ((None, 1e-4), ({"coarse_polish_min_hessian_perturbation": None}, 1e-5)):
        d = plan_horizon(problem, warm, coarse_polish_iter=15, coarse_polish_retry=None, **ON, **(given or {}))
        d = d.diagnostics
        polish = [r for r in d["round_log"] if r["phase"] == "polish"]
        assert polish and all(r["min_hessian_perturbation"] == floor for r in polish)
        note = d["horizon_note"]
        assert f"the whole NLP from its optimum: IPOPT min_hessian_perturbation {floor:g} (exact Hessian)" in note
    opts = horizon_model._options({"ipopt": {"min_hessian_perturbation": 3e-6}})
    assert horizon_module._polish_floor(opts) == 3e-6
    assert horizon_module._polish_phases(opts)[0][1][0][1]["min_hessian_perturbation"] == 3e-6


def test_the_polish_curvature_test_is_its_first_attempts_alone():
    """``coarse_polish_curvature_test`` is IPOPT's ``neg_curv_test_tol`` in the polish's first attempt and nowhere
    else (its retry keeps the inertia test); ``None`` leaves IPOPT's inertia test everywhere."""
    (_, attempts), *_ = horizon_module._polish_phases(horizon_model._options({"coarse_polish_curvature_test": 3e-4}))
    assert [name for name, _ in attempts] == ["primary", "retry"]
    assert attempts[0][1]["neg_curv_test_tol"] == 3e-4 and "neg_curv_test_tol" not in attempts[1][1]
    (_, attempts), *_ = horizon_module._polish_phases(horizon_model._options({"coarse_polish_curvature_test": None}))
    assert all("neg_curv_test_tol" not in extra for _, extra in attempts)


def test_the_polish_hessian_shift_is_in_its_primary_attempts_alone(problem_and_warm, monkeypatch):
    """``coarse_polish_hessian_shift`` δ is added to the Hessian of each polish round's primary attempt and of no
    other attempt (its retry, the coarse NLP, the whole NLP without a coarse pass) — the shift the solver's
    derivatives are built with, recorded in every round and named in the note; ``None``: no shift anywhere."""
    problem, warm, _ = problem_and_warm
    built: list[float] = []  # the shift of every solver's derivatives, in build order
    real = horizon_model._Transcription.derivatives

    def spy(self, obj_scale, hessian=None, shift=0.0):
        built.append(shift)
        return real(self, obj_scale, hessian, shift)

    monkeypatch.setattr(horizon_model._Transcription, "derivatives", spy)
    opts = horizon_model._options({"coarse_polish_hessian_shift": 3e-4})
    assert horizon_module._hessian_shift(opts, "polish", "primary", "exact") == 3e-4
    for phase, label, hessian in (
        ("polish", "retry", "exact"),
        ("polish", "primary", "limited-memory"),  # no Hessian to shift
        ("fast", "primary", "exact"),
        ("fallback", "primary", "exact"),
        ("default", "primary", "gauss-newton"),
    ):
        assert horizon_module._hessian_shift(opts, phase, label, hessian) == 0.0
    none = horizon_model._options({"coarse_polish_hessian_shift": None})
    assert horizon_module._hessian_shift(none, "polish", "primary", "exact") == 0.0
    for shift in (3e-4, None):
        built.clear()
        d = plan_horizon(problem, warm, coarse_polish_hessian_shift=shift, **ON).diagnostics
        assert d["horizon_result"] in ("optimal", "coarse_optimal")
        primary = sum(r["phase"] == "polish" and r["attempt"] == "primary" for r in d["round_log"])
        assert primary and built.count(3e-4) == (primary if shift else 0)  # the coarse NLP's solvers: 0
        assert set(built) == ({0.0, 3e-4} if shift else {0.0})
        polish = [r for r in d["round_log"] if r["phase"] == "polish"]
        assert polish and polish[0]["attempt"] == "primary"
        assert [r["hessian_shift"] for r in polish if r["attempt"] == "primary"] == [shift or 0.0] * sum(
            r["attempt"] == "primary" for r in polish
        )
        assert all(r["hessian_shift"] == 0.0 for r in d["round_log"] if r["phase"] != "polish")
        assert ("(exact Hessian + 0.0003 I)" in d["horizon_note"]) == (shift is not None)
    d = plan_horizon(problem, warm, coarse_polish_hessian_shift=3e-4).diagnostics  # K = 30: no coarse pass
    assert d["round_log"] and all(r["hessian_shift"] == 0.0 for r in d["round_log"])


def test_a_polish_stopped_at_its_cap_is_retried_from_its_last_iterate(problem_and_warm, monkeypatch):
    """The polish capped at 2 iterations stops at the cap: its retry (``coarse_polish_retry``, 10⁻²) goes on from the
    last iterate and its multipliers and converges, so the plan is the optimum, and the note and the summary say so;
    without the retry the polish's best feasible iterate is returned (stop 53: three generated rooms)."""
    problem, warm, _ = problem_and_warm
    calls = spy_ipopt_calls(monkeypatch)
    d = plan_horizon(problem, warm, coarse_polish_iter=2, **ON).diagnostics
    monkeypatch.undo()
    (primary_args, primary_x), (retry_args, _) = calls[-2:]  # the polish's two solves, after the coarse NLP's
    np.testing.assert_array_equal(np.asarray(retry_args["x0"], dtype=float).ravel(), primary_x)  # its last iterate
    assert "lam_g0" in retry_args and "lam_x0" in retry_args  # and its multipliers
    assert not np.array_equal(np.asarray(primary_args["x0"], dtype=float).ravel(), primary_x)
    first, retry = [r for r in d["round_log"] if r["phase"] == "polish"]
    assert (first["attempt"], first["status"], first["iterations"], first["from_last"]) == (
        "primary",
        "Maximum_Iterations_Exceeded",
        2,
        False,
    )
    assert (retry["attempt"], retry["min_hessian_perturbation"], retry["from_last"]) == ("retry", 1e-2, True)
    assert retry["status"] == "Solve_Succeeded" and d["horizon_result"] == "optimal"
    assert "at most 2 iterations, its retry 0.01 (exact Hessian) from the polish's last iterate" in d["horizon_note"]
    assert d["horizon_summary"]["min_hessian_perturbation"] == 1e-2  # the floor of the solve that was returned
    without = plan_horizon(problem, warm, coarse_polish_iter=2, coarse_polish_retry=None, **ON).diagnostics
    assert without["horizon_result"] == "best_feasible_iterate"
    assert [r["attempt"] for r in without["round_log"]] == ["primary"]
    with pytest.raises(ParameterError, match="coarse_polish_retry"):
        plan_horizon(problem, warm, coarse_polish_retry=1e-2)


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


def _kink(monkeypatch, knot=15, up=0.05):
    """The interpolation with robot 1 ``up`` [m] higher at one ``knot`` (5 cm: |ÿ| = 0.05 / Ts² = 20 m/s² > a_rob)."""
    real = coarse.interpolate

    def kinked(robots, t, M, ends=0, grid=None):
        F = real(robots, t, M, ends, grid=grid)
        F[knot, 0, 1] += up
        return F

    monkeypatch.setattr(horizon_module, "interpolate", kinked)


def test_refine_cuts_the_steps_round_the_failing_knots():
    """Each step of the grid that holds a failing knot, and ``pad`` steps either side, is cut into ``parts`` steps as
    equal as the fine knots allow; the grid's own knots stay; a step shorter than ``parts`` fine steps gets every fine
    knot; knots on the grid's last knot fall in its last step."""
    fine = np.arange(31)
    np.testing.assert_array_equal(coarse.refine(GRID, [16], 3), np.r_[0:12:3, 12:22, 24:31:3])  # steps 12–21
    np.testing.assert_array_equal(coarse.refine(GRID, [16], 3, pad=0), np.r_[0:15:3, 15:19, 21:31:3])
    np.testing.assert_array_equal(coarse.refine(GRID, [0, 30], 4, pad=0), np.r_[0:4, 6:27:3, 27:31])
    grid = np.array([0, 10, 20, 30])
    np.testing.assert_array_equal(coarse.refine(grid, [12], 4, pad=0), [0, 10, 12, 15, 18, 20, 30])  # 2.5 → 12, 15…
    np.testing.assert_array_equal(coarse.refine(grid, [5, 25], 2, pad=5), [0, 5, 10, 15, 20, 25, 30])  # pad clipped
    refined = coarse.refine(coarse.refine(GRID, [16], 3), [16], 3)
    np.testing.assert_array_equal(refined, coarse.refine(GRID, [16], 3))  # every fine knot there already
    assert set(GRID) <= set(coarse.refine(GRID, fine, 2)) and coarse.refine(GRID, fine, 3).tolist() == fine.tolist()


def test_rows_failing_between_coarse_knots_refine_the_grid_there(problem_and_warm, monkeypatch):
    """Robot 1 moved towards the column at knot 16 of the interpolation on the first grid (between its knots 15 and
    18), to d_safe / 2 from it: clearance rows fail there (a graze, not deeper than ``coarse_refine_depth``) and,
    unrepaired (``coarse_repair=0``), the coarse NLP is solved again on the grid cut finer round knot 16
    (:func:`coarse.refine`, ``coarse_refine_parts`` = 3: every knot of 12–21) from that interpolation sampled there;
    its own interpolation holds every row and is accepted. With ``coarse_refine=0``, or a depth below the graze's,
    the pass rejects it as before."""
    problem, warm, warm_metrics = problem_and_warm
    real = coarse.interpolate
    grids, starts = [], []
    env, d_safe = problem.env, problem.qp_params.d_safe

    def to_the_edge(robots, t, M, ends=0, grid=None):
        F = real(robots, t, M, ends, grid=grid)
        grids.append(np.asarray(grid).tolist())
        if np.array_equal(grid, GRID):  # along the line to the column's centre, to clearance 0 (d_safe inside)
            p, c = F[16, 0].copy(), np.array([4.2, 2.0])
            s = brentq(lambda s: env.exact_clearance((1 - s) * p + s * c) - d_safe / 2, 0.0, 1.0)
            F[16, 0] = (1 - s) * p + s * c
        return F

    real_plan = horizon_module._plan_horizon

    def spy(problem, warm_start, **kw):
        starts.append(kw.get("_start"))
        return real_plan(problem, warm_start, **kw)

    monkeypatch.setattr(horizon_module, "interpolate", to_the_edge)
    monkeypatch.setattr(horizon_module, "_plan_horizon", spy)
    ipopt = spy_ipopt_calls(monkeypatch)
    options = dict(ON, coarse_repair=0, coarse_polish_iter=0, coarse_refine_parts=3)
    for off in (dict(coarse_refine=0), dict(coarse_refine_depth=0.01)):
        log = plan_horizon(problem, warm, **off, **options).diagnostics["horizon_summary"]["coarse"]
        assert log["result"] == "rejected" and "refined" not in log
        assert "clearance: 1 knot(s), k = 16 (t = 0.80 s), worst: " in log["reason"]
    grids.clear()
    starts.clear()
    ipopt.clear()
    plan = plan_horizon(problem, warm, **options)
    d = plan.diagnostics
    log = d["horizon_summary"]["coarse"]
    fine = np.r_[0:12:3, 12:22, 24:31:3]
    assert grids == [GRID.tolist(), fine.tolist()] and log["knots"] == fine.size
    assert log["refined"] == [{"between": 1, "knots": fine.size}] and log["result"] == "accepted"
    # the whole NLP and the first coarse NLP from the warm start, the refined one from the first interpolation there
    assert [None if q is None else q.shape for q in starts] == [None, None, (fine.size, 4)]
    P = problem.chain.robots(starts[2][fine.tolist().index(16)])
    assert env.exact_clearance(P[0]) == pytest.approx(d_safe / 2, abs=1e-6)
    # and IPOPT's first iterate on the refined grid is there: positions (knots, [x_1 x_2 y_1 y_2])
    x0 = next(np.asarray(kw["x0"]).ravel() for kw, _ in ipopt if np.asarray(kw["x0"]).size >= 4 * fine.size)
    at16 = x0[: 4 * fine.size].reshape(fine.size, 4)[fine.tolist().index(16)]
    assert env.exact_clearance(at16[[0, 2]]) == pytest.approx(d_safe / 2, abs=1e-6)
    assert d["horizon_result"] == "coarse_optimal"
    assert (
        "IPOPT solved the NLP on every 3rd knot, its steps round 1 knot where rows failed between them cut into 3 ("
        in (d["horizon_note"])
    )
    metrics = check(plan, problem.env)  # exact clearances of robots and tether segments at every step
    assert plan.success and metrics.n_violation_steps == 0
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(warm_metrics, f) * (1 + 1e-9)


def test_a_refined_round_that_fails_or_goes_deeper_leaves_the_last_one(problem_and_warm, monkeypatch):
    """The refined grid's NLP finding no optimum, or its interpolation breaking clearance deeper than the last one's,
    leaves the last round's interpolation the pass's result (rejected here; the log's knots the first grid's, the
    refinement's ``result`` says why). ``_start`` is no user option."""
    problem, warm, _ = problem_and_warm
    real, real_plan = coarse.interpolate, horizon_module._plan_horizon
    c = np.array([4.2, 2.0])
    env, d_safe = problem.env, problem.qp_params.d_safe

    def towards_the_column(F, knot, clearance):
        p = F[knot, 0].copy()
        s = brentq(lambda s: env.exact_clearance((1 - s) * p + s * c) - clearance, 0.0, 1.0)
        F[knot, 0] = (1 - s) * p + s * c

    def graze_then_deeper(robots, t, M, ends=0, grid=None):
        F = real(robots, t, M, ends, grid=grid)
        towards_the_column(F, 16, d_safe / 2) if np.array_equal(grid, GRID) else towards_the_column(F, 13, -0.3)
        return F

    options = dict(ON, coarse_repair=0, coarse_polish_iter=0, coarse_refine_parts=3)
    monkeypatch.setattr(horizon_module, "interpolate", graze_then_deeper)
    d = plan_horizon(problem, warm, **options).diagnostics
    log = d["horizon_summary"]["coarse"]
    assert log["result"] == "rejected" and log["knots"] == GRID.size and "k = 16 (t = 0.80 s)" in log["reason"]
    assert log["refined"][0]["result"].startswith("deeper: ") and len(log["refined"]) == 1
    # the run's note says so: "…, its optimum rejected (…), its grid refined 1 time(s) … (the last: deeper: …)"
    assert (
        ", its grid refined 1 time(s) round knots where clearance failed between its knots (the last: deeper: "
        in (d["horizon_note"])
    )

    def refined_fails(problem, warm_start, **kw):
        if kw.get("_start") is not None:
            raise horizon_model.HorizonInfeasible("horizon NLP: no", [], status="Infeasible_Problem_Detected")
        return real_plan(problem, warm_start, **kw)

    monkeypatch.setattr(horizon_module, "_plan_horizon", refined_fails)
    log = plan_horizon(problem, warm, **options).diagnostics["horizon_summary"]["coarse"]
    assert log["result"] == "rejected" and log["knots"] == GRID.size and "k = 16 (t = 0.80 s)" in log["reason"]
    assert log["refined"][0]["result"] == "Infeasible_Problem_Detected: no"
    with pytest.raises(ParameterError, match="_start"):
        plan_horizon(problem, warm, _start=warm.q)


def test_repair_spans_pad_and_merge_the_failing_knots():
    assert horizon_module._repair_spans([0, 1], 30, 6) == [(1, 7)]  # knot 0 is fixed: windows start at 1
    assert horizon_module._repair_spans([15], 30, 6) == [(9, 21)]
    assert horizon_module._repair_spans([3, 17, 30], 30, 6) == [(1, 9), (11, 30)]  # 23 and 24 adjacent: merged
    assert horizon_module._repair_spans([3, 15, 29], 30, 6) == [(1, 21), (23, 30)]  # 1–9 and 9–21 overlap
    assert horizon_module._repair_spans([], 30, 6) == []


def test_rows_failing_at_a_few_knots_of_the_interpolation_are_repaired_in_windows(problem_and_warm, monkeypatch):
    """Interpolated with a kink that breaks the robot acceleration rows at knots 14–16, the coarse optimum is repaired:
    the whole NLP in one window of knots 14–16 ± 2 coarse steps (``coarse_repair`` = 2, M = 3), every other knot held;
    every row then holds, so it is accepted (here without the polish: ``coarse_polish_iter=0``). Only the window's
    knots moved."""
    problem, warm, warm_metrics = problem_and_warm
    _kink(monkeypatch)
    seen = {}
    real_windowed = horizon_module._windowed

    def spy(model, masks, xv, *args, **kwargs):
        out = real_windowed(model, masks, xv, *args, **kwargs)
        seen.update(before=xv.copy(), after=out[0].copy(), width=2 * model.su.N)
        seen["window_solve"] = sum(w["solve_time"] for w in out[1])
        return out

    monkeypatch.setattr(horizon_module, "_windowed", spy)
    plan = plan_horizon(problem, warm, coarse_polish_iter=0, **ON)
    d = plan.diagnostics
    log = d["horizon_summary"]["coarse"]
    assert log["result"] == "accepted" and [w["knots"] for w in log["repair"]] == [(8, 22)]
    assert log["repair"][0]["kept"] and log["repair_iterations"] == log["repair"][0]["iterations"] > 0
    assert d["horizon_result"] == "coarse_optimal"
    assert d["ipopt_iterations"] == log["iterations"] + log["repair_iterations"]
    assert "then the whole NLP in 1 window(s) around the knots where rows failed (knots 8–22;" in d["horizon_note"]
    assert "returned the optimum on every 3rd knot, interpolated and repaired" in d["horizon_note"]
    # the repair's seconds are counted once: its IPOPT time in the solve time, the rest in the transcription time
    assert d["solve_time"] >= seen["window_solve"] > 0
    assert d["solve_time"] + d["transcription_time"] <= d["total_time"] + 1e-6
    knots = np.unique(np.flatnonzero(seen["before"] != seen["after"]) // seen["width"])  # the knots that moved
    assert knots.min() >= 8 and knots.max() <= 22 and 15 in knots
    metrics = check(plan, problem.env)  # exact clearances of robots and tether segments at every step
    assert plan.success and metrics.n_violation_steps == 0
    a = np.diff(plan.robots, 2, axis=0) / 0.05**2
    assert np.abs(a).max() <= problem.qp_params.robot_accel_max * (1 + 1e-6)  # the kink is gone
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(warm_metrics, f) * (1 + 1e-9)


def test_the_repairs_window_on_its_own_model_is_the_window_of_the_whole_model(problem_and_warm, monkeypatch):
    """The repair solves each window on the model of its knots alone (``_windowed(mode="local")``,
    ``_Model.window``). From the same state, the window of the whole model (``mode="sub"``: every knot a variable,
    those outside fixed, the whole cost) takes the same IPOPT iterations to the same trajectory and row multipliers,
    bit for bit (IPOPT drops fixed variables, and the cost's terms of fixed knots are constants)."""
    problem, warm, _ = problem_and_warm
    _kink(monkeypatch)
    calls = []
    real_windowed = horizon_module._windowed

    def spy(model, masks, xv, obj_scale, pool, bar, deadline, limit, **kwargs):
        out = real_windowed(model, masks, xv, obj_scale, pool, bar, deadline, limit, **kwargs)
        scratch = horizon_module._Pool(8, 1e-6, np.inf)
        whole = real_windowed(model, masks, xv, obj_scale, scratch, bar, deadline, limit, **dict(kwargs, mode="sub"))
        calls.append((kwargs["mode"], out, whole))
        return out

    monkeypatch.setattr(horizon_module, "_windowed", spy)
    windows = []
    real_window = horizon_model._Model.window

    def window(self, a, b):
        out = real_window(self, a, b)
        windows.append((a, b, None if out is None else (out[0].su.K, out[1], self.su.K)))
        return out

    monkeypatch.setattr(horizon_model._Model, "window", window)
    plan_horizon(problem, warm, coarse_polish_iter=0, **ON)
    assert len(calls) == 1 and windows == [(8, 22, (18, 6, 30))]  # knots 6–24 of 0–30
    mode, (x_own, log_own, lam_own), (x_whole, log_whole, lam_whole) = calls[0]
    assert mode == "local" and [w["iterations"] for w in log_own] == [w["iterations"] for w in log_whole]
    assert log_own[0]["kept"] and log_own[0]["iterations"] > 0
    np.testing.assert_array_equal(x_own, x_whole)
    for name in lam_whole:
        np.testing.assert_array_equal(lam_own[name], lam_whole[name])


def test_a_whole_horizon_row_gets_no_window_and_the_check_after_the_repair_decides(problem_and_warm, monkeypatch):
    """A kink of 0.5 m also makes f4 worse than the warm start's: a fitness row (a sum over every knot, reported at
    knot K) fails besides the local ones. The windows go round the local rows only (knots 8–22, not K); the check
    after the repair, of every row, the fitness ones included, accepts the repaired trajectory."""
    problem, warm, warm_metrics = problem_and_warm
    _kink(monkeypatch, up=0.5)
    seen = {}
    real_violations = horizon_module._violations

    def first(model, vals, xv, tol):  # the violations at the interpolation, before the repair
        out = real_violations(model, vals, xv, tol)
        seen.setdefault("groups", {v.group for v in out})
        return out

    monkeypatch.setattr(horizon_module, "_violations", first)
    plan = plan_horizon(problem, warm, coarse_polish_iter=0, **ON)
    d = plan.diagnostics
    log = d["horizon_summary"]["coarse"]
    assert "fitness" in seen["groups"] and [w["knots"] for w in log["repair"]] == [(8, 22)]
    assert log["result"] == "accepted" and d["horizon_result"] == "coarse_optimal"
    metrics = check(plan, problem.env)
    assert plan.success and metrics.n_violation_steps == 0
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(warm_metrics, f) * (1 + 1e-9)


def test_the_repair_is_checked_padded_by_coarse_repair_and_bounded(problem_and_warm, monkeypatch):
    """What the windows return is checked like the interpolation (a repair that mends nothing is rejected, with the
    rows named); ``coarse_repair`` = 1 pads the failing knots 14–16 by one coarse step (3 knots); windows over more
    than half the knots are not solved (``coarse_repair`` = 10: knots 1–30), and the log says why. The log holds no
    seconds (it is written to metrics.json)."""
    problem, warm, _ = problem_and_warm
    _kink(monkeypatch)
    d = plan_horizon(problem, warm, coarse_polish_iter=0, coarse_repair=1, **ON).diagnostics
    log = d["horizon_summary"]["coarse"]
    assert [w["knots"] for w in log["repair"]] == [(11, 19)] and log["result"] == "accepted"
    assert set(log["repair"][0]) == {"knots", "status", "iterations", "kept"}
    d = plan_horizon(problem, warm, coarse_polish_iter=0, coarse_repair=10, **ON).diagnostics
    log = d["horizon_summary"]["coarse"]
    assert "repair" not in log and log["repair_skipped"] == "windows of 30 of 30 knots (more than 50 %)"
    assert log["result"] == "rejected" and log["reason"].startswith("interpolated, it violates joint_accel")
    monkeypatch.setattr(horizon_module, "REPAIR_MAX_ITER", 1)  # a window cut at its cap is not kept
    log = plan_horizon(problem, warm, coarse_polish_iter=0, **ON).diagnostics["horizon_summary"]["coarse"]
    assert [(w["iterations"], w["kept"]) for w in log["repair"]] == [(1, False)] and log["result"] == "rejected"
    assert log["reason"].startswith("interpolated, it violates")
    assert log["fine_start"] == "the interpolated coarse optimum"
    monkeypatch.setattr(horizon_module, "_windowed", lambda model, masks, xv, *a, **k: (xv, [], {}))
    d = plan_horizon(problem, warm, coarse_polish_iter=0, **ON).diagnostics
    log = d["horizon_summary"]["coarse"]
    assert log["repair"] == [] and log["result"] == "rejected" and "robot_accel" in log["reason"]
    assert d["horizon_result"] == "optimal"  # the whole NLP from the interpolation


def test_a_rejected_interpolation_starts_the_whole_nlp_from_it(problem_and_warm, monkeypatch):
    """Interpolated with a kink that breaks the robot acceleration rows, the coarse optimum is rejected when it is
    not repaired (``coarse_repair=0``; the log names the rows); the whole NLP then starts from it and its optimum is
    returned, every row holding."""
    problem, warm, warm_metrics = problem_and_warm
    _kink(monkeypatch)
    unrepaired = dict(ON, coarse_repair=0)
    plan = plan_horizon(problem, warm, **unrepaired)
    d = plan.diagnostics
    log = d["horizon_summary"]["coarse"]
    assert log["result"] == "rejected" and "robot_accel" in log["reason"] and "repair" not in log
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
    d = plan_horizon(problem, warm, **unrepaired, fast_max_iter=1).diagnostics
    fast = d["horizon_summary"]["fast_attempt"]
    assert fast["result"] == "fell_back" and "fallback_start" not in fast  # its one iterate holds no row more
    assert ", so fell back to 0.001 (Gauss–Newton Hessian) from the interpolated coarse optimum;" in d["horizon_note"]


def test_coarse_options_are_checked(problem_and_warm):
    problem, warm, _ = problem_and_warm
    bad_options = (
        dict(coarse_knots=1),
        dict(coarse_from=0),
        dict(coarse_from=True),
        dict(coarse_from=None),
        dict(coarse_from_size=0),
        dict(coarse_from_size=True),
        dict(coarse_from_size="3000"),
        dict(coarse_from_size=2.5e3),
        dict(coarse_margin=-0.1),
        dict(coarse_rate_scale=0),
        dict(coarse_time_share=2),
        dict(clearance_margin=-0.01),
        dict(coarse_ends=-1),
        dict(coarse_repair=-1),
        dict(coarse_repair=0.5),
        dict(coarse_repair="2"),
        dict(coarse_repair=None),
        dict(coarse_refine=-1),
        dict(coarse_refine=1.5),
        dict(coarse_refine=True),
        dict(coarse_refine_parts=1),
        dict(coarse_refine_parts=None),
        dict(coarse_refine_depth=-0.1),
        dict(coarse_refine_depth=float("nan")),
        dict(coarse_polish_min_hessian_perturbation=0),
        dict(coarse_polish_min_hessian_perturbation=float("inf")),
        dict(coarse_polish_curvature_test=0),
        dict(coarse_polish_curvature_test=-1e-4),
        dict(coarse_polish_curvature_test=True),
        dict(coarse_polish_hessian_shift=0),
        dict(coarse_polish_hessian_shift=-1e-4),
        dict(coarse_polish_hessian_shift=float("nan")),
        dict(coarse_polish_hessian_shift=True),
    )
    for bad in bad_options:
        with pytest.raises(ParameterError):
            plan_horizon(problem, warm, **bad)
    fine = horizon_model._options({"coarse_polish_min_hessian_perturbation": np.float32(1e-4), "coarse_repair": 3})
    assert horizon_module._polish_floor(fine) == pytest.approx(1e-4) and fine.coarse_repair == 3
