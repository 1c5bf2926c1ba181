"""Chain kinematics: D–H products vs closed form, Jacobians vs finite differences (Caruso 2021 eq. 1–2, 10–15)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tmr.errors import ParameterError
from tmr.model.chain import Chain, dh_transform


def random_q(chain: Chain, rng: np.random.Generator) -> np.ndarray:
    q = rng.uniform(-np.pi, np.pi, chain.dof)
    q[chain.prismatic_index] = rng.uniform(0.5, 5.0, chain.n_robots)
    return q


def fd_point(chain: Chain, q, links, s, fixed, h=1e-6):
    """Central finite differences of the point positions, with the point defined as `fixed` says."""
    q = np.asarray(q, float)
    links = np.asarray(links)
    s = np.asarray(s, float)

    def pos(qq):
        if fixed == "fraction":
            return chain.link_points(qq, links, s)
        # fixed distance from the link start: distance = s * d_link at the nominal q
        P = chain.points(qq)
        start, end = P[links - 1], P[links]
        dist = s * np.linalg.norm(chain.points(q)[links] - chain.points(q)[links - 1], axis=1)
        u = (end - start) / np.linalg.norm(end - start, axis=1)[:, None]
        return start + dist[:, None] * u

    J = np.zeros((links.size, chain.dim, chain.dof))
    for i in range(chain.dof):
        dq = np.zeros_like(q)
        dq[i] = h
        J[:, :, i] = (pos(q + dq) - pos(q - dq)) / (2 * h)
    return J


@pytest.mark.parametrize("n", [1, 3, 10])
@pytest.mark.parametrize("spatial", [False, True])
@pytest.mark.parametrize("fixed", ["fraction", "distance"])
def test_point_jacobians_match_finite_differences(n, spatial, fixed):
    rng = np.random.default_rng(100 + n + 7 * spatial)
    chain = Chain(n, base=(0.3, -1.2, 0.4)[: 3 if spatial else 2], spatial=spatial)
    for _ in range(5):
        q = random_q(chain, rng)
        links = rng.integers(1, n + 1, size=8)
        s = rng.uniform(0, 1, size=8)
        J = chain.point_jacobians(q, links, s, fixed=fixed)
        np.testing.assert_allclose(J, fd_point(chain, q, links, s, fixed), atol=1e-6, rtol=1e-6)


@pytest.mark.parametrize("n", [1, 3, 10])
@pytest.mark.parametrize("spatial", [False, True])
def test_robot_jacobians_and_zero_columns(n, spatial):
    rng = np.random.default_rng(n)
    chain = Chain(n, spatial=spatial)
    q = random_q(chain, rng)
    J = chain.robot_jacobians(q)
    np.testing.assert_allclose(J, fd_point(chain, q, np.arange(1, n + 1), np.ones(n), "fraction"), atol=1e-6)
    # eq. 15: robot k does not depend on the joints of later links
    for k in range(n):
        later = chain.joint_link > k + 1
        assert np.all(J[k][:, later] == 0.0)
    np.testing.assert_allclose(chain.end_effector_jacobian(q), J[-1])


def test_paper_eq15_distance_mode_zeroes_own_prismatic():
    chain = Chain(3)
    q = np.array([0.2, 2.0, 0.3, 2.5, -0.4, 1.5])
    J = chain.point_jacobians(q, [2], [0.5], fixed="distance")[0]
    # link 2: columns θ1, d1, θ2 nonzero, d2 and link 3 zero — [J1 J2 J3 0 0 0]
    assert np.all(np.abs(J[:, :3]).sum(axis=0) > 0)
    assert np.all(J[:, 3:] == 0.0)


@pytest.mark.parametrize("n", [1, 3, 10])
def test_dh_products_equal_closed_form(n):
    rng = np.random.default_rng(n)
    chain = Chain(n, base=(1.0, 2.0))
    q = random_q(chain, rng)
    F = chain.frames(q)
    np.testing.assert_allclose(F[chain.prismatic_index + 1, :2, 3], chain.robots(q), atol=1e-12)
    np.testing.assert_allclose(F[chain.prismatic_index + 1, 2, 3], 0.0, atol=1e-12)  # planar: stays on the floor
    # every revolute axis of the planar chain is vertical (Table 1)
    np.testing.assert_allclose(F[chain.revolute_index, :3, 2], np.tile([0, 0, 1.0], (n, 1)), atol=1e-12)


def test_dh_transform_is_rigid():
    rng = np.random.default_rng(0)
    T = dh_transform(*rng.uniform(-2, 2, (4, 6)))
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0)


def test_table1_geometry_example():
    """θ1 = 0 points link 1 along +x; relative angles accumulate."""
    chain = Chain(2, base=(0.0, 0.0))
    P = chain.points([0.0, 2.0, np.pi / 2, 1.0])
    np.testing.assert_allclose(P, [[0, 0], [2, 0], [2, 1]], atol=1e-12)
    np.testing.assert_allclose(chain.spans([0.0, 2.0, np.pi / 2, 1.0]), [2.0, 1.0])


def test_spatial_zero_pose_is_straight_and_yaw_matches_planar():
    sp = Chain(3, base=(0, 0, 0), spatial=True)
    pl = Chain(3, base=(0, 0))
    np.testing.assert_allclose(
        sp.points(np.tile([0, 0, 1.0], 3)), [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], atol=1e-12
    )
    yaw = np.array([0.3, 0.5, -0.2])
    d = np.array([1.0, 2.0, 1.5])
    qs = np.column_stack([yaw, np.zeros(3), d]).ravel()
    qp = np.column_stack([yaw, d]).ravel()
    np.testing.assert_allclose(sp.points(qs)[:, :2], pl.points(qp), atol=1e-12)
    # pitch lifts the tether: robot 1 at height d1 sin β1
    q = np.array([0.0, 0.4, 2.0, 0, 0, 1, 0, 0, 1])
    assert sp.points(q)[1, 2] == pytest.approx(2.0 * np.sin(0.4))


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 6), st.integers(0, 2**31 - 1))
def test_q_from_positions_round_trip(n, seed):
    rng = np.random.default_rng(seed)
    chain = Chain(n, base=rng.uniform(-5, 5, 2))
    q = random_q(chain, rng)
    q2 = chain.q_from_positions(chain.robots(q))
    np.testing.assert_allclose(chain.robots(q2), chain.robots(q), atol=1e-9)
    assert np.all(np.abs(q2[0::2]) <= np.pi + 1e-12)


def test_bad_inputs():
    with pytest.raises(ParameterError, match="at least one robot"):
        Chain(0)
    with pytest.raises(ParameterError):
        Chain(2.5)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="base"):
        Chain(2, base=(np.nan, 0.0))
    chain = Chain(2)
    with pytest.raises(ParameterError, match="shape"):
        chain.check_q([0.0, 1.0])
    with pytest.raises(ParameterError, match="NaN"):
        chain.check_q([0.0, np.nan, 0.0, 1.0])
    with pytest.raises(ParameterError, match="coincides"):
        chain.q_from_positions([[0.0, 0.0], [1.0, 1.0]])
    with pytest.raises(ParameterError, match="link indices"):
        chain.point_jacobians([0, 1, 0, 1], [3], [0.5])


@pytest.mark.parametrize("n", [1, 3, 5])
def test_spatial_q_from_positions_round_trip_and_finite_differences(n):
    rng = np.random.default_rng(40 + n)
    chain = Chain(n, base=(1.0, 2.0, 0.3), spatial=True)
    for _ in range(5):
        q = rng.uniform(-3.0, 3.0, chain.dof)
        q[chain.prismatic_index] = rng.uniform(0.5, 3.0, n)
        P = chain.robots(q)
        q2 = chain.q_from_positions(P)
        np.testing.assert_allclose(chain.robots(q2), P, atol=1e-12)
        np.testing.assert_allclose(q2[chain.prismatic_index], q[chain.prismatic_index], atol=1e-12)
        # finite differences: the robots' Jacobian times dq/dP is the identity on the positions
        delta = rng.normal(size=(n, 3))
        eps = 1e-6
        dq = (chain.q_from_positions(P + eps * delta) - chain.q_from_positions(P - eps * delta)) / (2 * eps)
        J = chain.robot_jacobians(q2).reshape(3 * n, chain.dof)
        np.testing.assert_allclose(J @ dq, delta.reshape(-1), atol=1e-6)
    # vertical links (gimbal lock of the yaw) still round-trip
    P = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 5.0], [2.0, 2.0, 5.0], [2.0, 2.0, 1.0], [0.0, 0.0, 0.5]])[:n]
    np.testing.assert_allclose(chain.robots(chain.q_from_positions(P)), P, atol=1e-12)
    with pytest.raises(ParameterError):
        chain.q_from_positions(np.vstack([chain.base, P[1:]]) if n > 1 else chain.base[None, :])
