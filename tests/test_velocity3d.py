"""tmr.model.velocity.VelocityMap3D (singularity-free link coordinates of a spatial chain) and the lexicographic QP
on a spatial chain: the maps against their definitions by finite differences, vertical links included."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.model.velocity import VelocityMap3D, robot_pattern3d


def _points(seed: int, n: int, vertical: bool = False) -> np.ndarray:
    rng = np.random.default_rng(seed)
    P = np.cumsum(rng.uniform(-2.0, 2.0, (n + 1, 3)), axis=0)
    if vertical:  # link 2 straight up, link 3 straight down (the D–H yaw is singular there)
        P[2] = P[1] + [0.0, 0.0, 1.5]
        P[3] = P[2] - [0.0, 0.0, 0.7]
    return P


@pytest.mark.parametrize("vertical", [False, True])
@pytest.mark.parametrize("n", [1, 3, 6])
def test_link_rates_are_the_derivatives_of_length_and_direction(n, vertical):
    if vertical and n < 3:
        pytest.skip("needs three links")
    P = _points(n, n, vertical)
    vm = VelocityMap3D(P)
    rng = np.random.default_rng(7)
    v = rng.normal(size=3 * n)
    qd = vm.joint_rates(v).reshape(n, 3)
    eps = 1e-6
    moved = lambda s: P + s * np.vstack([np.zeros(3), v.reshape(n, 3)])  # noqa: E731 - the anchor does not move
    diff = lambda Q: np.diff(Q, axis=0)  # noqa: E731
    Dp, Dm = diff(moved(eps)), diff(moved(-eps))
    d_dot = (np.linalg.norm(Dp, axis=1) - np.linalg.norm(Dm, axis=1)) / (2 * eps)
    u_dot = (Dp / np.linalg.norm(Dp, axis=1)[:, None] - Dm / np.linalg.norm(Dm, axis=1)[:, None]) / (2 * eps)
    np.testing.assert_allclose(qd[:, 2], d_dot, atol=1e-7)
    # u̇ = ω1 e1 + ω2 e2 (the direction's rate, ⟂ u)
    np.testing.assert_allclose(qd[:, :1] * vm.e1 + qd[:, 1:2] * vm.e2, u_dot, atol=1e-7)
    # the pair is orthonormal and ⟂ u for every link, vertical ones included
    F = np.stack([vm.e1, vm.e2, vm.u], axis=1)
    np.testing.assert_allclose(F @ np.swapaxes(F, 1, 2), np.broadcast_to(np.eye(3), F.shape), atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 5])
def test_maps_invert_each_other_and_T_matches(n):
    vm = VelocityMap3D(_points(10 + n, n, vertical=n >= 3))
    rng = np.random.default_rng(n)
    v, qd = rng.normal(size=3 * n), rng.normal(size=3 * n)
    np.testing.assert_allclose(vm.robot_velocities(vm.joint_rates(v)), v, atol=1e-12)
    np.testing.assert_allclose(vm.joint_rates(vm.robot_velocities(qd)), qd, atol=1e-12)
    np.testing.assert_allclose(vm.T @ v, vm.joint_rates(v), atol=1e-12)
    A = rng.normal(size=(4, 3 * n))
    np.testing.assert_allclose(vm.to_robot(A), A @ vm.T, atol=1e-12)
    # the declared pattern covers T's (and a row on one link touches robots j−1 and j only)
    mask = np.zeros((3 * n, 3 * n), dtype=bool)
    np.fill_diagonal(mask, True)
    assert not np.any((np.abs(vm.T) > 0) & ~robot_pattern3d(mask))
    if n > 2:
        assert np.all(vm.T[:3, 6:] == 0.0)


def test_zero_link_is_refused():
    with pytest.raises(ParameterError):
        VelocityMap3D(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]))
