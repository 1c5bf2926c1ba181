"""Tests of tmr.mcdpr.tipping: eq. 5 against a direct moment computation, the tightened bounds, constraint rows."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.tipping import constraint_rows, tension_bounds, tipping

R = mopick()
rng = np.random.default_rng(3)


def _random_pose():
    P = rng.uniform([0, 0, 0.4], [3, 3, 1.0])
    B = rng.uniform(-1, 4, (4, 2))
    H = rng.uniform(-np.pi, np.pi, 4)
    return P, B, H


def _direct_moments(P, B, H, t):
    """Moment about each footprint edge from first principles: weight at G, cable force −t u at the exit point A."""
    out = np.empty((4, 4))
    for j in range(4):
        c, s = np.cos(H[j]), np.sin(H[j])
        Rz = np.array([[c, -s], [s, c]])
        C = np.column_stack([B[j] + R.footprint @ Rz.T, np.zeros(4)])
        G = np.r_[B[j] + Rz @ R.cog[:2], R.cog[2]]
        A = np.r_[B[j], 1.2]
        u = (A - P) / np.linalg.norm(A - P)
        for o in range(4):
            e = C[(o + 1) % 4] - C[o]
            e /= np.linalg.norm(e)
            m_w = np.cross(G - C[o], [0, 0, -R.base_mass * R.gravity])
            m_c = np.cross(A - C[o], -t[j] * u)
            out[j, o] = e @ (m_w + m_c)
    return out


def test_eq5_matches_direct_moments() -> None:
    for _ in range(10):
        P, B, H = _random_pose()
        t = rng.uniform(0, 15, 4)
        tip = tipping(R, P, B, H)
        np.testing.assert_allclose(tip.moments(t), _direct_moments(P, B, H, t), atol=1e-11)
        assert np.all(tip.a < 0)  # the weight alone never tips a base whose CoG is inside the footprint


def test_tension_bounds_are_the_exact_tipping_limit() -> None:
    hits = 0
    for _ in range(40):
        P, B, H = _random_pose()
        tip = tipping(R, P, B, H)
        lo, hi = tension_bounds(R, tip)
        assert np.all(lo == 0.0) and np.all(hi <= 15.0) and np.all(hi > 0)
        m_hi = tip.moments(hi)
        assert np.all(m_hi <= 1e-9)
        for k in np.flatnonzero(hi < 15.0):  # tipping-limited: the binding edge is exactly at m = 0
            hits += 1
            assert np.max(m_hi[k]) == pytest.approx(0.0, abs=1e-9)
            t = hi.copy()
            t[k] += 1e-3
            assert np.max(tip.moments(t)[k]) > 0
    assert hits > 0  # the MoPICK parameters make tipping active somewhere


def test_batch_and_constraint_rows() -> None:
    Ps, Bs, Hs = zip(*[_random_pose() for _ in range(6)], strict=True)
    tip = tipping(R, np.array(Ps), np.array(Bs), np.array(Hs))
    lo, hi = tension_bounds(R, tip)
    A, b = constraint_rows(R, tip)
    assert A.shape == (6, 8 + 16, 4)
    for i in range(6):
        single = tipping(R, Ps[i], Bs[i], Hs[i])
        np.testing.assert_allclose(single.a, tip.a[i], atol=1e-14)
        for _ in range(20):
            t = rng.uniform(-1, 16, 4)
            in_rows = np.all(A[i] @ t <= b[i])
            in_box = np.all((t >= lo[i]) & (t <= hi[i]))
            assert in_rows == in_box


def test_tension_bounds_needs_one_cable_per_base() -> None:
    r = mopick().replace(n_bases=2, cable_base=(0, 0, 1, 1))
    tip = tipping(r, [1.0, 1.0, 0.8], [[0, 0], [2, 2]])
    with pytest.raises(ParameterError, match="one cable per base"):
        tension_bounds(r, tip)
