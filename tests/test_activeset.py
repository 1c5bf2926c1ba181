"""Warm active set: KKT solves from a guessed active set agree with an independent QP solver, or decline."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import qpsolvers
import scipy.sparse as sp

from tmr.control.activeset import WarmActiveSet, active_set


def random_qp(seed: int, n: int = 8, m: int = 14, n_eq: int = 2):
    rng = np.random.default_rng(seed)
    M = rng.normal(size=(n, n))
    P = M @ M.T + 0.1 * np.eye(n)
    q = rng.normal(size=n)
    A = rng.normal(size=(m, n))
    x0 = rng.normal(size=n) * 0.1
    lo = A @ x0 - rng.uniform(0.05, 1.0, m)
    up = A @ x0 + rng.uniform(0.05, 1.0, m)
    lo[:n_eq] = up[:n_eq] = A[:n_eq] @ x0  # equalities
    lo[n_eq : n_eq + 3] = -np.inf  # one-sided rows
    return P, q, A, lo, up


def reference(P, q, A, lo, up):
    eq = lo == up
    G = np.vstack([A[~eq & np.isfinite(up)], -A[~eq & np.isfinite(lo)]])
    h = np.concatenate([up[~eq & np.isfinite(up)], -lo[~eq & np.isfinite(lo)]])
    return qpsolvers.solve_qp(P, q, G, h, A[eq], lo[eq], solver="daqp")


@pytest.mark.parametrize("seed", range(12))
def test_from_the_right_active_set_it_is_the_optimum(seed):
    P, q, A, lo, up = random_qp(seed)
    x_ref = reference(P, q, A, lo, up)
    ws = WarmActiveSet(tol=1e-9, rounds=1)
    res = ws.solve(P, q, A, lo, up, right_set(A, lo, up, x_ref))  # the right active set, read off the reference
    assert res is not None and res.rounds == 1
    np.testing.assert_allclose(res.x, x_ref, atol=1e-7)
    # KKT: stationarity with the returned multipliers, signs on their bounds
    np.testing.assert_allclose(P @ res.x + q + A.T @ res.y, 0.0, atol=1e-8)
    act = active_set(res.y, lo, up)
    assert np.all(res.y[act == 1] > 0) and np.all(res.y[act == -1] < 0)


def right_set(A, lo, up, x):
    Ax = A @ x
    s = np.zeros(A.shape[0], np.int8)
    s[np.isclose(Ax, up, atol=1e-8)] = 1
    s[np.isclose(Ax, lo, atol=1e-8)] = -1
    return s


def test_from_a_wrong_guess_it_corrects_or_declines_never_returns_a_wrong_answer():
    corrected = 0
    for seed in range(12):
        P, q, A, lo, up = random_qp(seed)
        x_ref = reference(P, q, A, lo, up)
        right = right_set(A, lo, up, x_ref)
        rng = np.random.default_rng(100 + seed)
        for _ in range(4):  # the previous step's set, off by one row each way
            guess = right.copy()
            ineq = np.flatnonzero(lo < up)
            guess[rng.choice(ineq)] = 0  # forget one (maybe) active row
            k = rng.choice(ineq)
            guess[k] = 1 if guess[k] == 0 else guess[k]  # claim one (maybe) inactive row
            res = WarmActiveSet(rounds=6).solve(P, q, A, lo, up, guess)
            if res is not None:
                corrected += 1
                np.testing.assert_allclose(res.x, x_ref, atol=1e-7)
    assert corrected >= 24  # most one-row mistakes are repaired within a few KKT solves


def test_sparse_and_dense_kkt_agree():
    P, q, A, lo, up = random_qp(3, n=12, m=20)
    x_ref = reference(P, q, A, lo, up)
    guess = np.zeros(A.shape[0], np.int8)
    dense = WarmActiveSet(dense_below=1000, rounds=8).solve(P, q, A, lo, up, guess)
    sparse = WarmActiveSet(dense_below=0, rounds=8).solve(sp.csr_matrix(P), q, A, lo, up, guess)
    assert (dense is None) == (sparse is None)
    if dense is not None:
        np.testing.assert_allclose(dense.x, x_ref, atol=1e-7)
        np.testing.assert_allclose(sparse.x, dense.x, atol=1e-9)


def test_dependent_active_rows_are_declined():
    P = np.eye(2)
    q = np.array([-1.0, -1.0])
    A = np.array([[1.0, 0.0], [1.0, 0.0]])  # the same row twice, both as equalities: a singular KKT matrix
    lo = up = np.array([0.5, 0.5])
    assert WarmActiveSet().solve(P, q, A, lo, up, np.zeros(2, np.int8)) is None


def test_near_duplicate_and_badly_scaled_rows_never_give_a_wrong_verified_answer():
    """Nearly parallel rows guessed active together make the KKT matrix nearly singular: the solve must be declined
    (stationarity and active-row checks), never returned as the optimum."""
    rng = np.random.default_rng(1)
    ws = WarmActiveSet()
    accepted = 0
    for _ in range(1000):  # the wrong answers of the unchecked solve show up a few times in a thousand
        n = 6
        J = rng.normal(size=(3, n))
        P = J.T @ J + 1e-9 * np.eye(n)
        q = -J.T @ rng.normal(size=3)
        A = rng.normal(size=(5, n))
        A = np.vstack([A, A[0] + rng.normal(size=n) * 10 ** rng.uniform(-14, -8), 1e6 * A[1]])
        lo, up = -np.abs(rng.normal(size=7)) * 0.1, np.abs(rng.normal(size=7)) * 0.1
        lo[6] *= 1e6
        up[6] *= 1e6
        x_ref = reference(P, q, A, lo, up)
        if x_ref is None:
            continue
        for _ in range(3):
            res = ws.solve(P, q, A, lo, up, rng.integers(-1, 2, size=7).astype(np.int8))
            if res is None:
                continue
            accepted += 1
            f = 0.5 * res.x @ P @ res.x + q @ res.x
            f_ref = 0.5 * x_ref @ P @ x_ref + q @ x_ref
            assert f <= f_ref + 1e-6 * (1 + abs(f_ref))  # optimal (the minimiser need not be unique: P is singular)
    assert accepted > 0


def test_more_active_rows_than_unknowns_keeps_an_independent_subset():
    """A degenerate vertex: three rows through the optimum of a 2-variable QP. The KKT system takes two of them; the
    third is checked as an ordinary row, and the answer is the optimum (an earlier version declined such guesses)."""
    P, q = np.eye(2), np.array([-2.0, -2.0])  # unconstrained optimum (2, 2)
    A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    lo, up = np.full(3, -10.0), np.array([1.0, 1.0, 2.0])  # all three active at (1, 1)
    res = WarmActiveSet().solve(P, q, A, lo, up, np.ones(3, np.int8))
    assert res is not None
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(P @ res.x + q + A.T @ res.y, 0.0, atol=1e-12)
    assert np.all(res.y >= 0)


def test_random_degenerate_vertices_give_the_optimum_or_decline():
    """More rows active at the optimum than unknowns, built from the KKT conditions (P positive definite: the optimum
    is unique). The guess holding all of them verifies to the optimum, or is declined (the multipliers of the kept
    subset may have the wrong sign: then the caller's QP solver settles it) — never a wrong answer."""
    verified = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        n, k, m = 4, 6, 10
        M = rng.normal(size=(n, n))
        P = M @ M.T + 0.5 * np.eye(n)
        x_opt = rng.normal(size=n)
        A = rng.normal(size=(m, n))
        up = A @ x_opt + np.r_[np.zeros(k), rng.uniform(0.1, 1.0, m - k)]  # k rows at their upper bound
        lo = np.full(m, -np.inf)
        y = np.r_[rng.uniform(0.0, 2.0, k), np.zeros(m - k)]
        q = -P @ x_opt - A.T @ y  # stationarity with y ≥ 0 on the active upper bounds: x_opt is the optimum
        guess = np.r_[np.ones(k), np.zeros(m - k)].astype(np.int8)
        res = WarmActiveSet(rounds=6).solve(P, q, A, lo, up, guess)
        if res is not None:
            verified += 1
            np.testing.assert_allclose(res.x, x_opt, atol=1e-8)
    assert verified >= 30  # most are settled (all of them were declined before: more rows than unknowns)


def test_a_nearly_singular_kkt_system_is_declined_without_a_warning():
    """A pivot of 1e-300 makes LAPACK return an infinite solution: it is declined before anything is multiplied
    out (it used to print "invalid value encountered in matmul")."""
    P = np.diag([1.0, 1e-300])
    q = np.array([1.0, 1e10])
    A, lo, up = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert WarmActiveSet().solve(P, q, A, lo, up, np.zeros(0, np.int8)) is None
        assert WarmActiveSet(dense_below=0).solve(sp.csr_matrix(P), q, A, lo, up, np.zeros(0, np.int8)) is None


@pytest.mark.parametrize("seed", range(8))
def test_certify_accepts_an_exact_optimum_and_its_multipliers(seed):
    import daqp

    P, q, A, lo, up = random_qp(seed)
    sense = np.where(lo == up, 5, 0).astype(np.int32)
    x, _, flag, info = daqp.solve(P, q, A, up, lo, sense)
    assert flag == 1
    res = WarmActiveSet().certify(P, q, A, lo, up, np.asarray(x), np.asarray(info["lam"]))
    assert res is not None and res.rounds == 0
    eq = lo == up  # an independent solver: Clarabel's interior point (``reference`` is DAQP itself)
    G = np.vstack([A[~eq & np.isfinite(up)], -A[~eq & np.isfinite(lo)]])
    h = np.concatenate([up[~eq & np.isfinite(up)], -lo[~eq & np.isfinite(lo)]])
    x_ref = qpsolvers.solve_qp(
        sp.csc_matrix(P), q, sp.csc_matrix(G), h, sp.csc_matrix(A[eq]), lo[eq],
        solver="clarabel", tol_gap_abs=1e-12, tol_gap_rel=1e-12,
    )  # fmt: skip
    np.testing.assert_allclose(res.x, x_ref, atol=1e-6)
    np.testing.assert_allclose(P @ res.x + q + A.T @ res.y, 0.0, atol=1e-8)  # res.y: the multipliers, in row order


def test_certify_accepts_a_weakly_active_row():
    """The optimum sits on a row whose multiplier is 0: the answer is still optimal."""
    P, q = np.eye(2), np.array([-1.0, 0.0])  # unconstrained optimum (1, 0)
    A = np.array([[1.0, 0.0], [0.0, 1.0]])
    lo, up = np.array([-np.inf, -1.0]), np.array([1.0, 1.0])  # x1 ≤ 1 touches the optimum, its multiplier 0
    res = WarmActiveSet().certify(P, q, A, lo, up, np.array([1.0, 0.0]), np.array([1e-13, 0.0]))
    assert res is not None
    np.testing.assert_array_equal(res.x, [1.0, 0.0])


@pytest.mark.parametrize(
    "q1, x, y, why",
    [
        (-2.0, [1.0, 0.0], [0.0, 0.0], "not stationary"),  # the cost pulls x1 to 2; the bound holds it with y = 1
        (0.0, [1.0, 0.0], [-1.0, 0.0], "stationary, but a multiplier of the wrong sign for the bound x1 is on"),
        (-2.0, [1.5, 0.0], [0.5, 0.0], "stationary, but infeasible"),
        (-2.0, [0.5, 0.0], [1.5, 0.0], "stationary, but a multiplier on a row away from its bound"),
    ],
)
def test_certify_declines_what_is_not_an_optimum(q1, x, y, why):
    P, A = np.eye(2), np.eye(2)
    lo, up = np.array([-np.inf, -1.0]), np.array([1.0, 1.0])  # x1 ≤ 1
    ws = WarmActiveSet()
    q = np.array([-2.0, 0.0])  # unconstrained optimum (2, 0): the optimum is (1, 0) with y = (1, 0)
    assert ws.certify(P, q, A, lo, up, np.array([1.0, 0.0]), np.array([1.0, 0.0])) is not None
    q = np.array([q1, 0.0])
    assert ws.certify(P, q, A, lo, up, np.array(x), np.array(y)) is None, why


def test_certify_ignores_multipliers_below_the_sign_tolerance():
    """A multiplier too small to name a bound proves nothing: on a row far from its bound it must not cancel the
    gradient (a reviewer's case: min ½x² − x with the row 10⁹ x ≤ 10¹², x = 0 and y = 10⁻⁹ is stationary)."""
    P, q = np.eye(1), np.array([-1.0])
    A, lo, up = np.array([[1e9]]), np.array([-1e30]), np.array([1e12])
    ws = WarmActiveSet()
    assert ws.certify(P, q, A, lo, up, np.array([0.0]), np.array([1e-9])) is None
    assert ws.certify(P, q, A, lo, up, np.array([1.0]), np.array([0.0])) is not None  # the optimum
