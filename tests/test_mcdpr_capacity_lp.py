"""Tests of tmr.mcdpr.capacity_lp: candidate normals, DPP support LP, coupled tipping constraints vs the hull method."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.mcdpr.capacity import aws_hrep, capacity, required_wrench_set
from tmr.mcdpr.capacity_hull import capacity_margin_hull
from tmr.mcdpr.capacity_lp import SupportLP, candidate_normals, capacity_margin_lp
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.tipping import constraint_rows, tipping

R = mopick()
#: two bases; base 1 carries cables 1 and 2 (exits 0.4 m either side of its axis on a wide frame), base 2 cable 3
COUPLED = mopick().replace(
    name="coupled",
    n_bases=2,
    cable_base=(0, 0, 1),
    exit_points=np.array([[0.4, 0.0, 1.2], [-0.4, 0.0, 1.2], [0.0, 0.0, 1.2]]),
    base_mass=15.0,
)


def test_support_lp_is_dpp_and_exact() -> None:
    lp = SupportLP(3, 6)
    assert lp.problem.is_dpp()
    A = np.vstack([np.eye(3), -np.eye(3)])
    b = np.r_[[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]
    val, t = lp.support([1.0, -1.0, 2.0], A, b)
    assert val == pytest.approx(7.0, abs=1e-12)
    np.testing.assert_allclose(t, [1.0, 0.0, 3.0], atol=1e-12)
    val, t = lp.support([1.0, 0, 0], A, np.r_[[1.0, 1, 1], [-2.0, 0, 0]])  # t1 >= 2 and t1 <= 1: empty
    assert val == -np.inf and t is None


def test_single_cable_normals_are_the_zonotope_normals() -> None:
    tip = tipping(R, [1.0, 1.0, 0.8], [[0, 0], [2, 0.2], [2.3, 2], [-0.1, 2]], [0.3, 0.1, -1.0, 2.0])
    A, _ = constraint_rows(R, tip)
    N = candidate_normals(tip.W, A)
    Nz, _ = aws_hrep(tip.W, np.zeros(4), np.ones(4))
    assert len(N) == len(Nz) == 12
    # same set of directions
    d = np.abs(N @ Nz.T - 1.0).min(axis=1)
    assert np.all(d < 1e-12)


def test_coupled_lp_path_matches_hull_method() -> None:
    rng = np.random.default_rng(7)
    rws = required_wrench_set(COUPLED, (0.3, 0.3, 0.3))
    signs = []
    for _ in range(12):
        P = np.r_[rng.normal(0, 0.15), rng.uniform(0.4, 1.0), rng.uniform(0.5, 0.9)]
        B = np.array([[0.0, 0.0], [0.0, 1.6]]) + rng.normal(0, 0.1, (2, 2))
        H = np.r_[rng.normal(0, 0.2), rng.uniform(-3, 3)]
        tip = tipping(COUPLED, P, B, H)
        A, b = constraint_rows(COUPLED, tip)
        mu_lp, N, h = capacity_margin_lp(tip.W, A, b, rws)
        mu_hull = capacity_margin_hull(tip.W, A, b, rws)
        # coupled rows add candidate planes that only support the AWS: exact for mu >= 0, same sign otherwise
        if mu_hull >= 0:
            assert mu_lp == pytest.approx(mu_hull, abs=1e-8)
        else:
            assert mu_lp < 0
        signs.append(mu_hull > 0)
        # every candidate plane supports the AWS: some vertex of the tension polytope attains it
        from tmr.mcdpr.capacity_hull import polytope_vertices

        F = polytope_vertices(A, b) @ tip.W.T
        np.testing.assert_allclose((F @ N.T).max(axis=0), h, atol=1e-8)
    assert any(signs) and not all(signs)


def test_lp_path_and_fast_path_on_one_pose() -> None:
    rws = required_wrench_set(R, (1.0, 1.0, 1.0))
    P, B, H = [1.0, 1.0, 0.8], np.array([[0, 0], [2, 0.2], [2.3, 2], [-0.1, 2]]), np.array([0.3, 0.1, -1.0, 2.0])
    tip = tipping(R, P, B, H)
    A, b = constraint_rows(R, tip)
    mu_lp = capacity_margin_lp(tip.W, A, b, rws)[0]
    assert mu_lp == pytest.approx(float(capacity(R, P, B, H, rws).mu), abs=1e-9)
