"""Tests of tmr.mcdpr.certify: the lower bound of μ between samples holds (dense sampling, independent hull
margin), it is not vacuous, in-place turns are checked, and a dip between two good samples is caught."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.mcdpr.capacity import capacity, required_wrench_set
from tmr.mcdpr.capacity_hull import box_rows, capacity_margin_hull
from tmr.mcdpr.certify import certify, interval_bounds, sample_stats, wrap
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.tipping import tension_bounds, tipping

R = mopick()
RWS = required_wrench_set(R, [1.0, 1.0, 1.0])


def _dense(P, B, H, n=201):
    """μ along the straight interpolation of two poses (headings along the shorter arc), n samples."""
    s = np.linspace(0.0, 1.0, n)
    Pd = P[0] + s[:, None] * (P[1] - P[0])
    Bd = B[0] + s[:, None, None] * (B[1] - B[0])
    Hd = H[0] + s[:, None] * wrap(H[1] - H[0])
    return capacity(R, Pd, Bd, Hd, RWS).mu, (Pd, Bd, Hd)


def _square(rho: float, c=(2.0, 2.0)) -> np.ndarray:
    ang = np.deg2rad([225.0, 315.0, 45.0, 135.0])
    return np.asarray(c) + rho * np.c_[np.cos(ang), np.sin(ang)]


def test_bound_holds_on_random_pieces() -> None:
    rng = np.random.default_rng(7)
    finite = 0
    for _ in range(120):
        c = rng.uniform(1.0, 3.0, 2)
        P0 = np.r_[c, rng.uniform(0.5, 1.0)]
        P = np.array([P0, P0 + np.r_[rng.normal(0, 0.04, 2), 0.0]])
        ang = np.deg2rad([225, 315, 45, 135]) + rng.normal(0, 0.3, 4)
        B0 = c + rng.uniform(0.6, 2.2, 4)[:, None] * np.c_[np.cos(ang), np.sin(ang)]
        B = np.array([B0, B0 + rng.normal(0, 0.04, (4, 2))])
        H0 = rng.uniform(-np.pi, np.pi, 4)
        H = np.array([H0, H0 + rng.normal(0, 0.15, 4)])
        low = interval_bounds(R, sample_stats(R, P, B, H, RWS), P, B, H)[0]
        mu, _ = _dense(P, B, H)
        if np.isfinite(low):
            finite += 1
            assert mu.min() >= low - 1e-9
    assert finite > 60


def test_bound_against_the_hull_margin() -> None:
    # the dense reference computed with the vertex-enumeration hull margin (independent of the zonotope formula)
    P = np.array([[2.0, 2.0, 0.8], [2.006, 2.004, 0.8]])
    B = np.array([_square(1.2), _square(1.2) + [[0.006, -0.004], [0.0, 0.004], [-0.004, 0.0], [0.002, 0.002]]])
    H = np.array([np.zeros(4), [0.01, -0.01, 0.02, 0.0]])
    low = interval_bounds(R, sample_stats(R, P, B, H, RWS), P, B, H)[0]
    _, (Pd, Bd, Hd) = _dense(P, B, H, 21)
    tip = tipping(R, Pd, Bd, Hd)
    lo, hi = tension_bounds(R, tip)
    ref = [capacity_margin_hull(tip.W[i], *box_rows(lo[i], hi[i]), RWS) for i in range(len(Pd))]
    assert 0 < low <= min(ref) + 1e-9


def test_bound_tends_to_mu_for_short_pieces() -> None:
    P = np.array([[2.0, 2.0, 0.8], [2.0 + 1e-6, 2.0, 0.8]])
    B = np.array([_square(1.3), _square(1.3)])
    H = np.zeros((2, 4))
    st = sample_stats(R, P, B, H, RWS)
    low = interval_bounds(R, st, P, B, H)[0]
    assert low == pytest.approx(st.mu[0], abs=1e-4)


def test_in_place_turn_through_the_weak_heading_is_caught() -> None:
    # bases 2.5 m out: with the footprint's wheel towards the cable (45°) μ ≈ 2.4 N, edge-on (90°) μ < 0. Turning all
    # bases in place from 45° to 135° passes through 90°: both samples are fine, the motion is not.
    B = np.array([_square(2.5), _square(2.5)])
    P = np.array([[2.0, 2.0, 0.8], [2.0, 2.0, 0.8]])
    H = np.array([np.full(4, np.pi / 4), np.full(4, 3 * np.pi / 4)])
    mu, _ = _dense(P, B, H)
    assert mu[0] > 2 and mu[-1] > 2 and mu.min() < 0
    cert = certify(R, P, B, H, RWS)
    assert not cert.ok and cert.violated
    assert cert.mu.min() < 0  # the refinement found a real pose with μ <= 0


def test_certified_turn_and_drive_bound_every_piece() -> None:
    # a 60° turn then a 0.4 m drive with the platform moving: certified; every refined piece's bound is below the
    # densely sampled μ of that piece
    B0 = _square(1.2)
    B1 = B0 + [0.4, 0.1]
    P = np.array([[2.0, 2.0, 0.8], [2.0, 2.0, 0.8], [2.3, 2.1, 0.75]])
    B = np.array([B0, B0, B1])
    H = np.array([np.zeros(4), np.full(4, np.pi / 3), np.full(4, np.pi / 3)])
    cert = certify(R, P, B, H, RWS)
    assert cert.ok and not cert.violated
    assert len(cert.P) > 3  # pieces were split
    for i in range(len(cert.P) - 1):
        mu, _ = _dense(cert.P[i : i + 2], cert.B[i : i + 2], cert.H[i : i + 2], 11)
        assert mu.min() >= cert.lower[i] - 1e-9
        assert cert.lower[i] >= 0.5 * min(cert.mu[i], cert.mu[i + 1]) - 1e-9  # refined to half the samples' μ
    np.testing.assert_array_equal(cert.u[np.isin(cert.u, [0.0, 1.0, 2.0])], [0.0, 1.0, 2.0])
