"""Hard limits: rows against finite differences, fixed patterns, velocity damper, joint box."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.control.limits import (
    JointBox,
    KeepInPolygon,
    ObstacleClearance,
    RobotAcceleration,
    RobotSeparation,
    RobotSpeed,
    approach_bound,
    link_pattern,
    robot_link_pattern,
)
from tmr.control.tasks import StepContext
from tmr.errors import ParameterError
from tmr.model.chain import Chain

LIMITS = np.array([[0.5, 5.596], [1.0, 5.596], [1.0, 5.596]])


def context(env, positions, base=(1.0, 7.3), qdot_prev=None, samples=20):
    chain = Chain(len(positions), base=base)
    q = chain.q_from_positions(positions)
    ref = np.array([positions[-1]], float)
    ctx = StepContext(chain, env, ref, np.zeros_like(ref), 0.05, samples, LIMITS[: len(positions)])
    ctx.update(0, q, np.zeros(chain.dof) if qdot_prev is None else np.asarray(qdot_prev, float))
    return chain, q, ctx


def test_approach_bound_is_a_velocity_damper():
    g = np.array([0.05, 0.55, 1.05, 0.0])
    b = approach_bound(g, 0.05, rate=2.0, Ts=0.05)
    np.testing.assert_allclose(b, [0.0, -0.05, -0.1, 0.0])  # −rate·Ts·(g − g_min); below g_min: must not shrink
    # rate ≥ 1/Ts is the plain one-step constraint g + Δg ≥ g_min
    np.testing.assert_allclose(approach_bound(g[:3], 0.05, rate=100.0, Ts=0.05), [0.0, -0.5, -1.0])


def test_clearance_rows_match_finite_differences_and_pattern(column_room):
    chain, q, ctx = context(column_room, [[3.0, 7.2], [6.0, 7.4], [9.0, 7.2]])
    lim = ObstacleClearance(chain, 20, d_safe=0.05, per_link=2, activation=1.5)
    A, lower, upper = lim.compute(ctx)
    mask = lim.pattern(chain)
    assert lim.space == "robot" and A.shape == mask.shape == (6, chain.dof)
    assert np.all(A[~mask] == 0) and np.all(np.isinf(upper))
    # rows on robot velocities are local: a point of link j moves with robots j−1 and j only
    assert np.array_equal(mask, robot_link_pattern(chain, [1, 1, 2, 2, 3, 3]))
    assert not mask[:2, 2:].any() and mask[:2, :2].all()
    A = ctx.rows_in("joint", A, lim.space)  # the same rows on joint rates, checked against the motion q + h q̇
    assert np.all(A[~link_pattern(chain, [1, 1, 2, 2, 3, 3])] == 0)  # eq. 15: no joint after the point's link
    idx, _ = lim.select(ctx)
    rng = np.random.default_rng(0)
    for _ in range(3):
        qdot = rng.normal(size=chain.dof)
        h = 1e-5
        links, s = ctx.sample_links[idx], ctx.sample_fractions[idx]
        p0 = chain.link_points(q, links, s)
        p1 = chain.link_points(q + h * qdot, links, s)
        # exact distance derivative along the motion; the rows use the field's gradient (a few % off near the
        # column, where the field is interpolated between grid nodes)
        fd = (column_room.exact_clearance(p1) - column_room.exact_clearance(p0)) / h
        np.testing.assert_allclose(A @ qdot / ctx.Ts, fd, rtol=0.05, atol=0.01)
    # the chain passes 0.3–0.4 m from the inflated column: link 2 (robot 2 side) must have an active row
    active = np.isfinite(lower)
    assert active.any()
    assert np.all(lower[active] <= 0)


def test_clearance_picks_local_minima_per_link(column_room):
    chain, q, ctx = context(column_room, [[3.0, 7.2], [6.0, 7.4], [9.0, 7.2]])
    lim = ObstacleClearance(chain, 20, per_link=2)
    idx, m = lim.select(ctx)
    d = ctx.sample_clearance
    for link in range(chain.n_robots):
        seg = d[link * m : (link + 1) * m]
        chosen = idx[2 * link : 2 * link + 2] - link * m
        assert seg[chosen[0]] == pytest.approx(seg.min())  # the lowest sample of every link has a row
    with pytest.raises(ParameterError):
        ObstacleClearance(chain, 20, d_safe=-0.1)


def test_separation_rows_match_finite_differences(open_room):
    chain, q, ctx = context(open_room, [[3.0, 6.0], [4.0, 7.0], [3.4, 6.9]], base=(1.0, 6.0))
    lim = RobotSeparation(chain, safety_radius=0.5, margin=0.02, neighbours=2)
    A, lower, _ = lim.compute(ctx)
    assert A.shape == lim.pattern(chain).shape == (6, chain.dof)
    assert np.all(np.count_nonzero(A, axis=1) == 4)  # one pair of robots per row, in robot velocities
    A = ctx.rows_in("joint", A, lim.space)
    qdot = np.random.default_rng(1).normal(size=chain.dof)
    h = 1e-6

    def dists(qq):
        P = chain.robots(qq)
        return np.linalg.norm(P[:, None] - P[None], axis=-1)

    D0, D1 = dists(q), dists(q + h * qdot)
    # with neighbours = N − 1 every pair is a row: robot i's rows are its pairs with j = 0, 1, 2 (j ≠ i) in order
    i = np.repeat(np.arange(3), 2)
    j = np.array([1, 2, 0, 2, 0, 1])
    np.testing.assert_allclose(A @ qdot / ctx.Ts, (D1[i, j] - D0[i, j]) / h, rtol=1e-4, atol=1e-5)
    # robots 2 and 3 are 0.61 m apart, below 2r + margin = 1.02 m: that pair must not get closer
    close = (i == 1) & (j == 2)
    assert np.all(lower[close] == 0.0)


def test_speed_and_acceleration_rows(open_room):
    qprev = np.array([0.1, 0.2, -0.1, 0.3, 0.2, -0.1])
    chain, q, ctx = context(open_room, [[3.0, 6.0], [4.5, 6.5], [6.0, 6.0]], base=(1.0, 6.0), qdot_prev=qprev)
    A, lo, up = RobotSpeed(chain, 2.0).compute(ctx)
    np.testing.assert_allclose(ctx.rows_in("joint", A, "robot"), chain.robot_jacobians(q).reshape(-1, chain.dof))
    np.testing.assert_array_equal(A, np.eye(chain.dof))  # the identity on robot velocities
    assert np.all(lo == -2.0) and np.all(up == 2.0)
    A2, lo2, up2 = RobotAcceleration(chain, 4.0).compute(ctx)
    np.testing.assert_allclose((lo2 + up2) / 2, chain.robot_jacobians(q).reshape(-1, chain.dof) @ qprev)
    np.testing.assert_allclose(up2 - lo2, 2 * 4.0 * 0.05)
    assert RobotAcceleration.relaxable and not RobotSpeed.relaxable
    assert np.all(A2[~RobotAcceleration(chain, 4.0).pattern(chain)] == 0)


def test_joint_box_speed_acceleration_and_spans(open_room):
    qprev = np.array([0.0, 1.0, 0.0, 0.0, 0.0, -2.0])
    chain, q, ctx = context(open_room, [[3.0, 6.0], [4.5, 6.0], [5.52, 6.0]], base=(1.0, 6.0), qdot_prev=qprev)
    box = JointBox(chain, LIMITS, omega_max=3.0, v_span_max=3.0, a_max=10.0, span_margin=0.01)
    lb, ub = box.compute(ctx)
    assert np.all(lb <= ub)
    # revolute joint 1: acceleration band around 0 → ±0.5
    assert (lb[0], ub[0]) == pytest.approx((-0.5, 0.5))
    # tether 3 is 1.02 m, 0.01 above d_lo + margin: it may shrink by at most 0.01 m in one step (0.2 m/s), even
    # though the acceleration band around −2 m/s asks for [−2.5, −1.5]: the span band wins, the box stays non-empty
    assert lb[5] == ub[5] == pytest.approx((1.01 - 1.02) / 0.05)
    lb_r, ub_r = box.compute(ctx, relax=True)
    assert lb_r[0] == -3.0 and ub_r[0] == 3.0


def test_keep_in_polygon_rows_and_example_limit(open_room):
    chain, q, ctx = context(open_room, [[3.0, 6.0], [4.5, 6.0], [6.0, 6.0]], base=(1.0, 6.0))
    square = [[4.0, 5.0], [5.0, 5.0], [5.0, 7.0], [4.0, 7.0]]
    lim = KeepInPolygon(chain, robot=2, polygon=square[::-1])  # orientation does not matter
    A, lo, up = lim.compute(ctx)
    assert A.shape == (4, chain.dof) and np.all(np.isneginf(lo))
    np.testing.assert_allclose(np.sort(up), [0.5, 0.5, 1.0, 1.0])  # distances of (4.5, 6) to the four edges
    assert np.array_equal(lim.pattern(chain), np.repeat([[False, True, False]], 4, axis=0).repeat(2, axis=1))
    Jq = ctx.rows_in("joint", A, lim.space)  # in joint rates: Ts aᵀ J_2, zero after link 2 (eq. 15)
    np.testing.assert_allclose(Jq, 0.05 * lim.normals @ chain.robot_jacobians(q)[1], atol=1e-12)
    with pytest.raises(ParameterError):
        KeepInPolygon(chain, robot=4, polygon=square)
