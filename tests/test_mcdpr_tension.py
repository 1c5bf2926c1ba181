"""Tests of tmr.mcdpr.tension: null-space closed form vs cvxpy QP/LPs, infeasible wrenches."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.mcdpr.capacity import capacity, required_wrench_set
from tmr.mcdpr.capacity_hull import box_rows
from tmr.mcdpr.errors import InfeasibleWrench
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.tension import TensionProblem, closed_form, closed_form_batch, wrench_feasible

R = mopick()
F = np.array([0.0, 0.0, R.platform_mass * R.gravity])


def _feasible_poses(n: int, seed: int):
    rng = np.random.default_rng(seed)
    P = np.column_stack([rng.uniform(0.5, 1.5, (n, 2)), rng.uniform(0.6, 0.9, n)])
    B = np.array([[0, 0], [2, 0], [2, 2], [0, 2.0]]) + rng.normal(0, 0.25, (n, 4, 2))
    H = rng.uniform(-np.pi, np.pi, (n, 4))
    return capacity(R, P, B, H, required_wrench_set(R, (1, 1, 1)))


def test_closed_form_equals_the_min_norm_qp() -> None:
    cap = _feasible_poses(12, 0)
    qp = TensionProblem(3, 4, 8, "2norm")
    res = closed_form_batch(cap.W, F, cap.lo, cap.hi)
    assert res.feasible.all()
    for i in range(12):
        A, b = box_rows(cap.lo[i], cap.hi[i])
        t_qp = qp.solve(cap.W[i], F, A, b)
        np.testing.assert_allclose(res.t[i], t_qp, atol=1e-6)
        np.testing.assert_allclose(cap.W[i] @ res.t[i], F, atol=1e-12)
        assert np.all(res.t[i] >= cap.lo[i] - 1e-12) and np.all(res.t[i] <= cap.hi[i] + 1e-12)
        np.testing.assert_allclose(closed_form(cap.W[i], F, cap.lo[i], cap.hi[i]), res.t[i], atol=1e-14)
        # the closed form is the minimum over the null-space line: any feasible λ gives a larger norm
        for lam in np.linspace(res.lam_lo[i], res.lam_hi[i], 7):
            t = res.particular[i] + lam * res.null[i]
            assert np.linalg.norm(t) >= np.linalg.norm(res.t[i]) - 1e-12


def test_lp_objectives() -> None:
    cap = _feasible_poses(6, 1)
    mx = TensionProblem(3, 4, 8, "maxnorm")
    l1 = TensionProblem(3, 4, 8, "1norm")
    for i in range(6):
        A, b = box_rows(cap.lo[i], cap.hi[i])
        t_inf = mx.solve(cap.W[i], F, A, b)
        t_1 = l1.solve(cap.W[i], F, A, b)
        t_2 = closed_form(cap.W[i], F, cap.lo[i], cap.hi[i])
        for t in (t_inf, t_1):
            np.testing.assert_allclose(cap.W[i] @ t, F, atol=1e-7)
            assert np.all(t >= cap.lo[i] - 1e-7) and np.all(t <= cap.hi[i] + 1e-7)
        assert t_inf.max() <= t_2.max() + 1e-7
        assert t_1.sum() <= t_2.sum() + 1e-7
        # min-max along the null-space line, by brute force on the feasible λ interval
        res = closed_form_batch(cap.W[i], F, cap.lo[i], cap.hi[i])
        lam = np.linspace(res.lam_lo, res.lam_hi, 20001)
        brute = (res.particular[None] + lam[:, None] * res.null[None]).max(axis=1).min()
        assert t_inf.max() == pytest.approx(brute, abs=1e-3)


def test_infeasible_wrench_raises_in_every_method() -> None:
    cap = _feasible_poses(1, 2)
    W, lo, hi = cap.W[0], cap.lo[0], cap.hi[0]
    f = np.array([0.0, 0.0, 200.0])  # far more than four 15 N cables can lift
    A, b = box_rows(lo, hi)
    with pytest.raises(InfeasibleWrench, match="cannot be produced"):
        closed_form(W, f, lo, hi)
    with pytest.raises(InfeasibleWrench, match="outside the available wrench set"):
        TensionProblem(3, 4, 8).solve(W, f, A, b)
    assert not closed_form_batch(W, f, lo, hi).feasible
    assert np.isnan(closed_form_batch(W, f, lo, hi).t).all()
    assert not wrench_feasible(W, f, A, b) and wrench_feasible(W, F, A, b)


def test_closed_form_needs_m_equal_n_plus_one() -> None:
    with pytest.raises(ParameterError, match="m = n"):
        closed_form_batch(np.eye(3), F, np.zeros(3), np.ones(3))
    with pytest.raises(ParameterError, match="objective"):
        TensionProblem(3, 4, 8, "bogus")  # type: ignore[arg-type]


def test_closed_form_rejects_rank_deficient_w_where_the_lp_finds_tensions() -> None:
    # documented limit (tension.md): the closed form needs full rank; the QP/LP handle this pose
    W = np.array([[1.0, 0, -1.0, 0], [0, 1.0, 0, -1.0], [0, 0, 0, 0]])
    f = np.array([1.0, 0.0, 0.0])
    lo, hi = np.zeros(4), np.full(4, 2.0)
    A, b = box_rows(lo, hi)
    assert wrench_feasible(W, f, A, b)
    assert not closed_form_batch(W, f, lo, hi).feasible
    with pytest.raises(InfeasibleWrench, match="rank-deficient"):
        closed_form(W, f, lo, hi)
    t = TensionProblem(3, 4, 8).solve(W, f, A, b)
    np.testing.assert_allclose(W @ t, f, atol=1e-7)


# --- tension-distribution methods: DAQP min-norm QP, HiGHS min-max LP, distribute() -------------------------------
def test_daqp_qp_equals_the_closed_form() -> None:
    from tmr.mcdpr.tension import min_norm_qp

    cap = _feasible_poses(10, 3)
    ref = closed_form_batch(cap.W, F, cap.lo, cap.hi)
    for i in np.flatnonzero(ref.feasible):
        np.testing.assert_allclose(min_norm_qp(cap.W[i], F, cap.lo[i], cap.hi[i]), ref.t[i], atol=1e-6)


def test_min_max_lp_reaches_the_cvxpy_optimum_and_is_feasible() -> None:
    from tmr.mcdpr.tension import min_max_lp

    cap = _feasible_poses(10, 4)
    ref = TensionProblem(3, 4, 8, "maxnorm")
    for i in range(10):
        if not np.all(cap.lo[i] <= cap.hi[i]):
            continue
        try:
            best = float(np.max(ref.solve(cap.W[i], F, *box_rows(cap.lo[i], cap.hi[i]))))
        except InfeasibleWrench:
            with pytest.raises(InfeasibleWrench):
                min_max_lp(cap.W[i], F, cap.lo[i], cap.hi[i])
            continue
        t = min_max_lp(cap.W[i], F, cap.lo[i], cap.hi[i])
        assert float(np.max(t)) == pytest.approx(best, abs=1e-6)
        np.testing.assert_allclose(cap.W[i] @ t, F, atol=1e-7)
        assert np.all(t >= cap.lo[i] - 1e-9) and np.all(t <= cap.hi[i] + 1e-9)


def test_lp_max_is_at_most_the_min_norm_max() -> None:
    from tmr.mcdpr.tension import distribute

    cap = _feasible_poses(8, 5)
    qp = distribute("qp", cap.W, F, cap.lo, cap.hi)
    lp = distribute("lp", cap.W, F, cap.lo, cap.hi)
    ok = np.all(np.isfinite(qp), axis=1)
    assert ok.any()
    assert np.all(lp[ok].max(axis=1) <= qp[ok].max(axis=1) + 1e-7)
    assert np.all(np.sum(qp[ok] ** 2, axis=1) <= np.sum(lp[ok] ** 2, axis=1) + 1e-7)


def test_distribute_infeasible_rows_and_bad_method() -> None:
    from tmr.mcdpr.tension import distribute

    cap = _feasible_poses(2, 6)
    heavy = np.array([0.0, 0.0, 100.0])  # more than 4 x 15 N can lift
    for method in ("closed-form", "qp", "lp"):
        assert np.all(np.isnan(distribute(method, cap.W, heavy, cap.lo, cap.hi)))
    with pytest.raises(ParameterError, match="tension method"):
        distribute("pinv", cap.W, F, cap.lo, cap.hi)
