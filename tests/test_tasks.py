"""Tasks: cost rows, the eq. 23 gain, the critical point and its hysteresis (Caruso 2021 eq. 13–23)."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.control.tasks import (
    LeaderTracking,
    ObstacleEvasion,
    StepContext,
    TetherRegulation,
    joint_limit_gain_coefficients,
)
from tmr.errors import ParameterError
from tmr.model.chain import Chain

LIMITS = np.array([[0.5, 5.6], [1.0, 5.6], [1.0, 5.6]])


def make_ctx(env, positions, base=(1.0, 6.0), ref=None, refv=None):
    chain = Chain(len(positions), base=base)
    q = chain.q_from_positions(positions)
    ref = np.array([positions[-1]]) if ref is None else np.atleast_2d(ref)
    refv = np.zeros_like(ref) if refv is None else np.atleast_2d(refv)
    ctx = StepContext(chain, env, ref, refv, 0.05, 20, LIMITS[: len(positions)])
    ctx.update(0, q, np.zeros(chain.dof))
    return chain, q, ctx


def test_leader_tracking_rows_are_clik_eq20(open_room):
    chain, q, ctx = make_ctx(open_room, [[2.0, 6.0], [3.5, 6.0], [5.0, 6.0]], ref=[[5.2, 6.1]], refv=[[0.3, -0.1]])
    task = LeaderTracking(gain=4.0)
    J, v = task.compute(ctx)
    assert task.space == "robot"
    np.testing.assert_array_equal(J, [[0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]])  # selects the leader's velocity
    np.testing.assert_allclose(ctx.rows_in("joint", J, task.space), chain.end_effector_jacobian(q))  # J_e, eq. 9
    np.testing.assert_allclose(v, [0.3 + 4.0 * 0.2, -0.1 + 4.0 * 0.1])
    with pytest.raises(ParameterError):
        LeaderTracking(gain=-1.0)


def test_eq23_gain_is_edge_plus_floor_at_limits():
    a1, b1, a2, b2 = joint_limit_gain_coefficients(1.0, 5.6, edge=5.0, length=0.2)
    assert a1 * np.exp(b1 * 5.6) == pytest.approx(5.0)
    assert a2 * np.exp(b2 * 1.0) == pytest.approx(5.0)
    chain = Chain(3)
    same = LIMITS[1:2].repeat(3, 0)
    task = TetherRegulation(chain, same, target_fraction=0.5, gain_floor=0.5, gain_edge=5.0, gain_length=0.2)
    g = task.gain(np.array([1.0, 3.3, 5.6]))
    # each limit: its own exponential (5) + floor (0.5) + the far one (negligible); mid-range ≈ floor
    assert g[0] == pytest.approx(5.5, abs=1e-3)
    assert g[1] == pytest.approx(0.5, abs=0.01)
    assert g[2] == pytest.approx(5.5, abs=1e-3)
    # beyond a limit the exponential is capped so explicit Euler cannot overshoot (K·Ts ≤ 1 with the default cap)
    capped = TetherRegulation(chain, same, max_gain=20.0)
    assert capped.gain(np.array([9.0]))[0] == 20.0
    # convex: gain grows towards both limits
    d = np.linspace(1.0, 5.6, 50)
    k = TetherRegulation(Chain(1), [[1.0, 5.6]]).gain(d)
    assert np.argmin(k) not in (0, 49)


def test_tether_regulation_rows_select_prismatic_joints(open_room):
    chain, q, ctx = make_ctx(open_room, [[2.0, 6.0], [3.5, 6.0], [6.5, 6.0]])
    task = TetherRegulation(chain, LIMITS, target_fraction=0.5)
    J, v = task.compute(ctx)
    np.testing.assert_array_equal(J @ q, ctx.spans)
    np.testing.assert_allclose(task.target, [3.3, 3.3, 3.3])
    # spans 1.0, 1.5, 3.0 are all below target → positive velocity; each term is gain × error
    np.testing.assert_allclose(v, task.gain(ctx.spans) * (task.target - ctx.spans))
    assert np.all(v > 0)
    with pytest.raises(ParameterError, match="d_lo < d_max"):
        TetherRegulation(chain, [[2.0, 1.0]] * 3)


def test_critical_point_excludes_anchor_and_leader_and_has_hysteresis(column_room):
    # a chain that passes right next to the column at (6, 6) (inflated radius 1.0)
    chain, q, ctx = make_ctx(column_room, [[3.0, 7.3], [6.0, 7.3], [9.0, 7.3]], base=(1.0, 7.3))
    task = ObstacleEvasion(d_min=0.5, k_v0=0.05, hysteresis=0.1)
    assert task.update(ctx)
    assert task.critical_clearance == pytest.approx(0.3, abs=0.03)
    link, s = ctx.sample_links[task.critical_index], ctx.sample_fractions[task.critical_index]
    assert (link, s) == (2, 1.0)  # robot 2 is closest, at (6, 7.3)
    J, v = task.compute(ctx)
    assert J.shape == (1, chain.dof)
    assert v[0] == pytest.approx(0.05 / task.critical_clearance)
    # the row is n_cᵀ J_c with n_c ≈ +y (away from the column) and the paper's eq. 15 zero columns
    Jc = chain.point_jacobians(q, [2], [1.0], fixed="distance")[0]
    np.testing.assert_allclose(J[0], np.array([0.0, 1.0]) @ Jc, atol=0.05)
    # hysteresis: at 0.55 m the task stays active (< d_min + ε), at 0.65 m it is released
    chain, q, ctx = make_ctx(column_room, [[3.0, 7.55], [6.0, 7.55], [9.0, 7.55]], base=(1.0, 7.55))
    assert task.update(ctx)
    chain, q, ctx = make_ctx(column_room, [[3.0, 7.65], [6.0, 7.65], [9.0, 7.65]], base=(1.0, 7.65))
    assert not task.update(ctx)
    chain, q, ctx = make_ctx(column_room, [[3.0, 7.55], [6.0, 7.55], [9.0, 7.55]], base=(1.0, 7.55))
    assert not task.update(ctx)  # not re-activated above d_min


def test_points_next_to_anchor_or_leader_are_never_critical(open_room):
    # base and leader both 0.2 m from the (inflated) wall at y = 0.5; the middle of the chain is far from it
    chain, q, ctx = make_ctx(open_room, [[3.0, 3.0], [6.0, 3.0], [8.0, 0.7]], base=(1.0, 0.7))
    task = ObstacleEvasion(d_min=0.5, k_v0=0.05, hysteresis=0.1, end_radius=0.5)
    task.update(ctx)
    p = ctx.sample_points[task.critical_index]
    assert np.linalg.norm(p - chain.base) >= 0.5 - 1e-9
    assert np.linalg.norm(p - ctx.x_e) >= 0.5 - 1e-9
