"""The faithful pseudoinverse baseline: DLS inverse, projectors, priorities, tracking (Caruso 2021 eq. 5–7, 20)."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.control.clik import run
from tmr.control.pinv import PinvController, dls_inverse, null_space_projector
from tmr.control.tasks import LeaderTracking, ObstacleEvasion, StepContext, TetherRegulation
from tmr.model.chain import Chain

from .conftest import straight_trajectory

LIMITS = np.array([[0.5, 5.596], [1.0, 5.596], [1.0, 5.596]])


def controller(chain, obstacle=True, **kw):
    return PinvController(
        leader=LeaderTracking(kw.get("gain", 5.0)),
        tether=TetherRegulation(chain, LIMITS[: chain.n_robots], kw.get("target", 0.5), max_gain=20.0),
        obstacle=ObstacleEvasion(0.5, kw.get("k_v0", 0.05), 0.1) if obstacle else None,
        damping=0.01,
    )


def test_dls_inverse_formula_and_limit():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(2, 6))
    np.testing.assert_allclose(dls_inverse(J, 0.3), J.T @ np.linalg.inv(J @ J.T + 0.3 * np.eye(2)))
    np.testing.assert_allclose(dls_inverse(J, 1e-12), np.linalg.pinv(J), atol=1e-8)
    # near a singularity the damped inverse stays bounded while the plain one explodes
    Js = np.array([[1.0, 0, 0], [1.0, 1e-9, 0]])
    assert np.abs(dls_inverse(Js, 0.01)).max() < 100
    assert np.abs(np.linalg.pinv(Js)).max() > 1e6


def test_null_space_projector_properties():
    rng = np.random.default_rng(1)
    JA = rng.normal(size=(3, 6))
    P = null_space_projector(JA)
    np.testing.assert_allclose(JA @ P, 0, atol=1e-12)
    np.testing.assert_allclose(P @ P, P, atol=1e-12)
    np.testing.assert_allclose(P, P.T, atol=1e-12)
    assert np.trace(P) == pytest.approx(3.0)


def test_secondary_tasks_do_not_disturb_the_leader(column_room):
    """Everything after the primary task lies in the null space of J_e (eq. 5)."""
    chain = Chain(3, base=(1.0, 7.3))
    q = chain.q_from_positions([[3.0, 7.3], [6.0, 7.3], [9.0, 7.3]])  # robot 2 next to the column: obstacle active
    ref = np.array([[9.2, 7.1]])
    refv = np.array([[0.4, 0.1]])
    ctx = StepContext(chain, column_room, ref, refv, 0.05, 20, LIMITS)
    ctx.update(0, q, np.zeros(chain.dof))
    full = controller(chain)
    qdot, diag = full.step(ctx)
    assert diag["obstacle_active"] == 1.0
    leader_only = dls_inverse(ctx.J_e, 0.01) @ (refv[0] + 5.0 * (ref[0] - ctx.x_e))
    np.testing.assert_allclose(ctx.J_e @ qdot, ctx.J_e @ leader_only, atol=1e-9)
    assert not np.allclose(qdot, leader_only)  # the secondary terms do move the chain
    # eq. 5 term by term: leader + P1 J_n^# v0 + P2 q̇_opt, with P2 the projector of [J_e; J_n]
    J_n, v0 = full.obstacle.compute(ctx)
    obstacle_term = null_space_projector(ctx.J_e) @ dls_inverse(J_n, 0.01) @ v0
    J_t, v_t = full.tether.compute(ctx)
    gpm_term = null_space_projector(np.vstack([ctx.J_e, J_n])) @ (J_t.T @ v_t)
    np.testing.assert_allclose(qdot, leader_only + obstacle_term + gpm_term, atol=1e-12)
    # the obstacle term alone pushes the critical point away from the column (positive speed along n_c) ...
    assert (J_n @ obstacle_term)[0] > 0
    # ... but in this singularity-robust form it does not compensate the leader's drag (Chiaverini 1997): here the
    # critical point still approaches the column, which is why the baseline can fail where the QP cannot
    assert (J_n @ qdot)[0] < 0


def test_tracking_in_free_space_and_integration(open_room):
    chain = Chain(3, base=(1.0, 6.0))
    start = np.array([[2.0, 6.0], [3.5, 6.0], [5.0, 6.0]])
    traj = straight_trajectory(start[-1], [10.0, 8.0])
    plan = run(
        chain,
        open_room,
        traj,
        controller(chain),
        chain.q_from_positions(start),
        span_limits=LIMITS,
        safety_radius=0.5,
        samples_per_link=20,
    )
    assert plan.success and plan.q.shape == (301, 6) and plan.robots.shape == (301, 3, 2)
    # explicit Euler: q_{k+1} = q_k + Ts q̇_k; robots are FK(q); q̇_K = 0
    np.testing.assert_allclose(plan.q[1:], plan.q[:-1] + 0.05 * plan.qdot[:-1], atol=1e-12)
    np.testing.assert_allclose(plan.robots[120], chain.robots(plan.q[120]))
    assert np.all(plan.qdot[-1] == 0)
    err = np.linalg.norm(plan.robots[:, -1] - plan.reference, axis=1)
    assert err.max() < 0.02  # CLIK with K = 5 s⁻¹ on a smooth reference
    # the tether regulation pulls the spans toward their common target (3.3 m) from 1.0–1.5 m
    assert np.all(plan.spans[-1] > plan.spans[0] + 0.5)


def test_tether_regulation_converges_with_the_leader_still(open_room):
    chain = Chain(3, base=(1.0, 6.0))
    start = np.array([[2.0, 6.0], [4.0, 7.0], [6.0, 6.0]])
    traj = straight_trajectory(start[-1], start[-1])  # leader holds its position
    plan = run(
        chain,
        open_room,
        traj,
        controller(chain, obstacle=False, target=0.0),
        chain.q_from_positions(start),
        span_limits=LIMITS,
        safety_radius=0.5,
        samples_per_link=20,
    )
    # targets are the lower limits, but the leader 5 m from the base holds still: the null-space motion pulls the
    # slack chain (5.47 m of tether) taut along the straight line to the leader (5 m)
    assert np.linalg.norm(plan.robots[-1, -1] - start[-1]) < 1e-3
    assert plan.spans[0].sum() == pytest.approx(1.0 + 2 * np.sqrt(5.0))
    assert plan.spans[-1].sum() < 5.05
    assert abs(plan.robots[-1, 1, 1] - 6.0) < 0.2


def test_divergence_is_reported_not_hidden(open_room):
    class Exploding:
        name = "exploding"

        def reset(self):
            pass

        def step(self, ctx):
            return np.full(ctx.chain.dof, np.nan if ctx.k == 7 else 0.0), {}

    chain = Chain(2, base=(1.0, 6.0))
    traj = straight_trajectory([3.0, 6.0], [5.0, 6.0])
    plan = run(
        chain,
        open_room,
        traj,
        Exploding(),
        chain.q_from_positions([[2.0, 6.0], [3.0, 6.0]]),
        span_limits=LIMITS[:2],
        safety_radius=0.5,
        samples_per_link=5,
    )
    assert not plan.success and "step 7" in plan.failure
    assert plan.q.shape[0] == 8 and np.all(np.isfinite(plan.q))
