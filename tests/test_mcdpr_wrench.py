"""Tests of tmr.mcdpr.wrench: cable unit vectors and the wrench matrix (Rasheed 2019 eq. 1-3)."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.wrench import exit_points, wrench_matrix

R = mopick()
BASES = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])


def test_columns_are_unit_vectors_towards_the_exits() -> None:
    P = np.array([0.5, 1.5, 0.7])
    W = wrench_matrix(R, P, BASES)
    for k in range(4):
        a = np.r_[BASES[k], 1.2]
        np.testing.assert_allclose(W[:, k], (a - P) / np.linalg.norm(a - P), rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(W, axis=0), 1.0, atol=1e-15)


def test_batch_matches_loop_and_heading_irrelevant_for_axial_exits() -> None:
    rng = np.random.default_rng(0)
    P = rng.uniform([0, 0, 0.3], [2, 2, 1.0], (7, 3))
    B = BASES + rng.normal(0, 0.3, (7, 4, 2))
    H = rng.uniform(-np.pi, np.pi, (7, 4))
    Wb = wrench_matrix(R, P, B, H)
    for i in range(7):
        np.testing.assert_array_equal(Wb[i], wrench_matrix(R, P[i], B[i]))


def test_offset_exits_rotate_with_heading() -> None:
    r = mopick().replace(exit_points=np.tile([0.1, 0.0, 1.2], (4, 1)))
    A = exit_points(r, BASES, np.full(4, np.pi / 2))
    np.testing.assert_allclose(A[:, :2], BASES + [0.0, 0.1], atol=1e-15)


def test_wrench_matrix_derivative_matches_finite_differences() -> None:
    # d u / d P = -(I - u uᵀ)/L: analytic Jacobian of a cable direction w.r.t. the platform position
    P = np.array([0.8, 1.1, 0.6])
    W = wrench_matrix(R, P, BASES)
    h = 1e-6
    for k in range(4):
        L = np.linalg.norm(np.r_[BASES[k], 1.2] - P)
        J = -(np.eye(3) - np.outer(W[:, k], W[:, k])) / L
        fd = np.column_stack(
            [
                (wrench_matrix(R, P + h * e, BASES)[:, k] - wrench_matrix(R, P - h * e, BASES)[:, k]) / (2 * h)
                for e in np.eye(3)
            ]
        )
        np.testing.assert_allclose(fd, J, atol=1e-8)


def test_platform_at_an_exit_point_raises() -> None:
    with pytest.raises(ParameterError, match="coincides"):
        wrench_matrix(R, [0.0, 0.0, 1.2], BASES)
