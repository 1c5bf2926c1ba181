"""Tests of tmr.mcdpr.capacity (fast zonotope path) against the LP path, the hull method and feasibility LPs."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.mcdpr.capacity import aws_hrep, capacity, capacity_margin, required_wrench_set
from tmr.mcdpr.capacity_hull import box_rows, capacity_margin_hull
from tmr.mcdpr.capacity_lp import capacity_lp
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.tension import wrench_feasible
from tmr.mcdpr.tipping import constraint_rows, tipping

R = mopick()
RWS = required_wrench_set(R, (1.0, 1.0, 1.0))


def _poses(n: int, seed: int):
    rng = np.random.default_rng(seed)
    P = np.column_stack([rng.uniform(0, 2, (n, 2)), rng.uniform(0.5, 1.0, n)])
    B = rng.uniform(-1.0, 3.0, (n, 4, 2))
    H = rng.uniform(-np.pi, np.pi, (n, 4))
    return P, B, H


def test_required_wrench_set() -> None:
    V = required_wrench_set(R, (1.0, 2.0, 0.5))
    assert V.shape == (8, 3)
    np.testing.assert_allclose(V.mean(axis=0), [0, 0, R.platform_mass * R.gravity])
    np.testing.assert_allclose(np.ptp(V, axis=0), [2.0, 4.0, 1.0])
    assert required_wrench_set(R).shape == (1, 3)
    with pytest.raises(ParameterError):
        required_wrench_set(R, (1.0, 1.0, 1.0), external_lo=(2.0, 0.0, 0.0))


def test_fast_path_agrees_with_lp_path_to_1e9() -> None:
    P, B, H = _poses(16, 0)
    fast = capacity(R, P, B, H, RWS).mu
    lp = capacity_lp(R, P, B, H, RWS)
    np.testing.assert_allclose(fast, lp, rtol=0, atol=1e-9)
    assert (fast > 0).any() and (fast < 0).any()


def _independent_w_and_bounds(P, B, H) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """W (eq. 1-3) and the tipping-tightened bounds (eq. 5-6) of one MoPICK pose, written out per base and edge."""
    W = np.empty((3, 4))
    lo, hi = np.full(4, R.t_min), np.full(4, R.t_max)
    for j in range(4):
        A = np.array([B[j][0], B[j][1], 1.2])  # exit point on the base axis
        u = (A - P) / np.linalg.norm(A - P)
        W[:, j] = u
        c, s = np.cos(H[j]), np.sin(H[j])
        rot = np.array([[c, -s], [s, c]])
        pts = [np.r_[B[j] + rot @ q, 0.0] for q in R.footprint]
        G = np.r_[B[j] + rot @ R.cog[:2], R.cog[2]]
        for o in range(len(pts)):
            C, C2 = pts[o], pts[(o + 1) % len(pts)]
            e = (C2 - C) / np.linalg.norm(C2 - C)
            m0 = e @ np.cross(G - C, [0.0, 0.0, -R.base_mass * R.gravity])  # weight moment (< 0)
            slope = e @ np.cross(C - P, u)  # moment per newton of cable tension
            if slope > 0:
                hi[j] = min(hi[j], -m0 / slope)
            elif slope < 0:
                lo[j] = max(lo[j], -m0 / slope)
    return W, lo, hi


def test_fast_path_agrees_with_hull_method() -> None:
    P, B, H = _poses(40, 1)
    cap = capacity(R, P, B, H, RWS)
    for i in range(len(P)):
        # W and bounds computed independently of tmr.mcdpr.wrench/tipping, polytope hull independently of capacity
        W, lo, hi = _independent_w_and_bounds(P[i], B[i], H[i])
        np.testing.assert_allclose(W, cap.W[i], atol=1e-12)
        A, b = box_rows(lo, hi)
        assert capacity_margin_hull(W, A, b, RWS) == pytest.approx(cap.mu[i], abs=1e-9)
        # the hull of the general constraint rows (box + tipping) is the same polytope
        A2, b2 = constraint_rows(R, tipping(R, P[i], B[i], H[i]))
        assert capacity_margin_hull(cap.W[i], A2, b2, RWS) == pytest.approx(cap.mu[i], abs=1e-8)


def test_negative_mu_exactly_when_a_required_wrench_is_infeasible() -> None:
    P, B, H = _poses(30, 2)
    cap = capacity(R, P, B, H, RWS)
    checked = 0
    for i in range(len(P)):
        if abs(cap.mu[i]) < 1e-6:
            continue
        A, b = box_rows(cap.lo[i], cap.hi[i])
        all_feasible = all(wrench_feasible(cap.W[i], f, A, b) for f in RWS)
        assert (cap.mu[i] > 0) == all_feasible
        checked += 1
    assert checked > 20


def test_batch_shapes_and_broadcasting() -> None:
    P, B, H = _poses(6, 3)
    mu = capacity(R, P, B, H, RWS).mu
    assert mu.shape == (6,)
    for i in range(6):
        assert capacity(R, P[i], B[i], H[i], RWS).mu == pytest.approx(mu[i], abs=1e-13)
    # one base placement, many platform positions
    many = capacity(R, P, B[0], H[0], RWS).mu
    assert many[0] == pytest.approx(mu[0], abs=1e-13)


def test_tipping_only_shrinks_the_aws() -> None:
    P, B, H = _poses(30, 4)
    cap = capacity(R, P, B, H, RWS)
    free = capacity_margin(cap.W, np.zeros(4), np.full(4, 15.0), RWS)
    assert np.all(cap.mu <= free + 1e-12)
    assert np.any(cap.mu < free - 1e-6)


def test_hrep_contains_generated_wrenches_and_is_tight() -> None:
    P, B, H = _poses(5, 5)
    cap = capacity(R, P, B, H, RWS)
    N, h = aws_hrep(cap.W, cap.lo, cap.hi)
    rng = np.random.default_rng(0)
    for i in range(5):
        t = rng.uniform(cap.lo[i], cap.hi[i], (200, 4))
        f = t @ cap.W[i].T
        assert np.all(f @ N[i].T <= h[i] + 1e-9)
        corners = np.array(np.meshgrid(*zip(cap.lo[i], cap.hi[i], strict=True))).reshape(4, -1).T @ cap.W[i].T
        np.testing.assert_allclose((corners @ N[i].T).max(axis=0), h[i], atol=1e-9)  # every facet touched


def test_mu_is_the_distance_to_the_boundary_for_a_simple_box() -> None:
    # W = [I | -1/√3(1,1,1)]: a known polytope; a point inside is at distance min(h − n·f) from the boundary
    W = np.column_stack([np.eye(3), -np.ones(3) / np.sqrt(3)])
    lo, hi = np.zeros(4), np.ones(4)
    f = np.array([[0.3, 0.3, 0.3]])
    mu = capacity_margin(W, lo, hi, f)
    A, b = box_rows(lo, hi)
    assert mu == pytest.approx(capacity_margin_hull(W, A, b, f), abs=1e-12)
    assert mu > 0


def test_all_columns_parallel_has_no_interior() -> None:
    # every cable along ±x: the AWS is a segment, so no required wrench is strictly inside (was +inf)
    W = np.array([[1.0, -1.0, 1.0, -1.0], [0, 0, 0, 0], [0, 0, 0, 0]])
    mu = capacity_margin(W, np.zeros(4), np.ones(4), np.zeros((1, 3)))
    assert mu == -np.inf
    # a flat (rank-2) AWS still gets a finite margin <= 0 from its two facets
    W2 = np.array([[1.0, 0, -1.0, 0], [0, 1.0, 0, -1.0], [0, 0, 0, 0]])
    mu2 = capacity_margin(W2, np.zeros(4), np.ones(4), np.zeros((1, 3)))
    assert np.isfinite(mu2) and mu2 <= 0


def test_coupled_robot_rejected_by_fast_path() -> None:
    r = mopick().replace(n_bases=2, cable_base=(0, 0, 1, 1))
    with pytest.raises(ParameterError, match="one cable per base"):
        capacity(r, [1.0, 1.0, 0.8], [[0, 0], [2, 2]], None, RWS)
