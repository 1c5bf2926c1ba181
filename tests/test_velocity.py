"""Robot-velocity coordinates: T inverts the robot Jacobians, rows convert both ways, finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.model.chain import Chain
from tmr.model.velocity import VelocityMap, robot_pattern


def chain_and_q(N: int, seed: int) -> tuple[Chain, np.ndarray]:
    rng = np.random.default_rng(seed)
    chain = Chain(N, base=(1.0, 2.0))
    q = rng.normal(size=2 * N)
    q[1::2] = rng.uniform(0.5, 3.0, N) * rng.choice([-1.0, 1.0], N)  # signed spans are allowed
    return chain, q


@pytest.mark.parametrize("N", [1, 2, 5, 12])
def test_T_inverts_the_stacked_robot_jacobians(N):
    chain, q = chain_and_q(N, N)
    vm = VelocityMap(chain.points(q), q[1::2])
    J_R = chain.robot_jacobians(q).reshape(2 * N, -1)
    np.testing.assert_allclose(vm.T @ J_R, np.eye(2 * N), atol=1e-12)
    np.testing.assert_allclose(J_R @ vm.T, np.eye(2 * N), atol=1e-12)
    v = np.random.default_rng(0).normal(size=2 * N)
    np.testing.assert_allclose(vm.joint_rates(v), vm.T @ v, atol=1e-13)
    qd = np.random.default_rng(1).normal(size=2 * N)
    np.testing.assert_allclose(vm.robot_velocities(qd), J_R @ qd, atol=1e-12)


def test_joint_rates_match_finite_differences_of_the_placement():
    chain, q = chain_and_q(4, 3)
    q[1::2] = np.abs(q[1::2])  # q_from_positions returns positive spans
    q = chain.q_from_positions(chain.robots(q))
    vm = VelocityMap(chain.points(q), q[1::2])
    v = np.random.default_rng(2).normal(size=8)
    h = 1e-6
    q1 = chain.q_from_positions(chain.robots(q) + h * v.reshape(4, 2))
    dq = q1 - q
    dq[0::2] = (dq[0::2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(dq / h, vm.joint_rates(v), rtol=1e-4, atol=1e-5)


def test_rows_convert_both_ways_and_keep_their_sparsity():
    chain, q = chain_and_q(6, 7)
    vm = VelocityMap(chain.points(q), q[1::2])
    A = np.random.default_rng(3).normal(size=(5, 12))
    B = vm.to_robot(A)
    np.testing.assert_allclose(B, A @ np.linalg.inv(chain.robot_jacobians(q).reshape(12, -1)), atol=1e-10)
    np.testing.assert_allclose(VelocityMap.to_joint(B, chain.robot_jacobians(q)), A, atol=1e-10)
    # a robot's Jacobian (dense up to its link in q̇, eq. 15) is a selector in robot velocities, without noise
    Jr3 = chain.robot_jacobians(q)[2]
    S = vm.to_robot(Jr3)
    expected = np.zeros((2, 12))
    expected[:, 4:6] = np.eye(2)
    assert np.count_nonzero(S[:, :4]) == 0 and np.count_nonzero(S[:, 6:]) == 0
    np.testing.assert_allclose(S, expected, atol=1e-12)
    # structural pattern: a row on one joint of link j touches at most robots j−2 … j
    mask = np.zeros((2, 12), dtype=bool)
    mask[0, 4] = True  # θ3
    mask[1, 5] = True  # d3
    pat = robot_pattern(mask)
    assert np.array_equal(np.flatnonzero(pat[0]), np.arange(0, 6))  # θ3 = φ̇3 − φ̇2: robots 1, 2, 3
    assert np.array_equal(np.flatnonzero(pat[1]), np.arange(2, 6))  # ḋ3 = u3ᵀ(ṗ3 − ṗ2): robots 2, 3
    B = vm.to_robot(mask.astype(float))
    assert not np.any(B[~pat])


def test_bad_geometry_is_a_clear_error():
    with pytest.raises(ParameterError, match="nonzero spans"):
        VelocityMap(np.zeros((3, 2)), np.array([0.0, 1.0]))
    with pytest.raises(ParameterError, match="planar"):
        VelocityMap(np.zeros((3, 3)), np.array([1.0, 1.0]))
