"""The drone chain's per-step world queries and limit rows (tmr.control.drones) against plain constructions: the
candidate-pair queries against each obstacle queried alone, the scattered row blocks against the rows written out
one tether at a time, VelocityMap3D's T against its definition."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.control.drones import (
    DroneClearance,
    TetherClearance,
    TetherLength,
    TetherTension,
    make_drone_qp,
    point_nearest_k,
    segment_box_distance,
    segment_nearest_k,
)
from tmr.control.run3d import line_references
from tmr.model.catenary3d import DroneTetherParams
from tmr.model.params import DroneParams
from tmr.model.velocity import VelocityMap3D
from tmr.world.world3d import World3D, box_obstacle, prism_obstacle

TP = DroneTetherParams()
PRM = DroneParams()
FAR = [-50, -50, -50, 50, 50, 50]


def _mixed_world(r: float = 0.0) -> World3D:
    """A box (closed form), a convex prism (coal hull) and an L-shaped prism (a triangle BVH, unsigned: its sign
    from the winding number)."""
    obstacles = [box_obstacle([2, 2, 0], [4, 5, 1.5]), prism_obstacle([[6, 6], [8, 6], [7, 8]], [0.0, 2.5]),
                 prism_obstacle([[1, 6], [4, 6], [4, 7], [2, 7], [2, 9], [1, 9]], [0.0, 2.0])]  # fmt: skip
    return World3D(obstacles, [0, 0, 0, 10, 10, 5], r)


def test_segment_box_distance_with_a_box_per_segment_is_each_box_alone():
    rng = np.random.default_rng(11)
    a = rng.uniform(0, 10, (200, 3))
    b = a + rng.normal(scale=2.0, size=a.shape)
    boxes = [(np.array([2.0, 2, 0]), np.array([4.0, 5, 1.5])), (np.array([6.0, 1, 1]), np.array([7.0, 3, 4]))]
    pick = rng.integers(0, 2, len(a))
    lo = np.array([boxes[i][0] for i in pick])
    hi = np.array([boxes[i][1] for i in pick])
    d, t = segment_box_distance(a, b, lo, hi)
    for i, (blo, bhi) in enumerate(boxes):
        di, ti = segment_box_distance(a[pick == i], b[pick == i], blo, bhi)
        assert np.array_equal(d[pick == i], di) and np.array_equal(t[pick == i], ti)
    assert np.any(d == 0.0) and np.any(d > 0.0)  # segments crossing a box and free ones


def test_segment_queries_on_boxes_hulls_and_meshes_match_each_obstacle_alone():
    """Every kind of pair: box pairs in closed form, segments crossing the box (coal), the convex hull and the BVH
    (segments with an end inside it: negative clearance from the winding number)."""
    world = _mixed_world()
    rng = np.random.default_rng(4)
    a = np.vstack([rng.uniform([0.5, 1.5, 0.1], [8.5, 9.5, 3.0], (300, 3)),
                   rng.uniform([1.1, 6.1, 0.1], [1.9, 8.9, 1.9], (20, 3))])  # fmt: skip  # 20 inside the L
    b = a + rng.normal(scale=0.7, size=a.shape)
    c, g, t, count = segment_nearest_k(world, a, b, 9)
    assert np.all(count == 9) and np.all(np.diff(c, axis=1) >= 0)
    for ob in world.obstacles:
        alone = World3D([ob], FAR, 0.0).segment_clearance(a, b)
        assert np.all(np.min(np.abs(c - alone[:, None]), axis=1) < 1e-7), ob.name
    inside_l = World3D([world.obstacles[2]], FAR, 0.0).segment_clearance(a[300:], b[300:])
    assert np.all(inside_l < 0.0)  # the BVH's pairs of segments starting inside it are negative
    crossing_box = World3D([world.obstacles[0]], FAR, 0.0).segment_clearance(a, b) <= 0.0
    assert np.any(crossing_box)  # box pairs that went to coal
    np.testing.assert_allclose(np.linalg.norm(g[np.isfinite(c)], axis=-1), 1.0, atol=1e-9)
    assert np.all((t >= 0.0) & (t <= 1.0))


def test_point_queries_on_boxes_hulls_and_meshes_match_each_obstacle_alone():
    r = 0.3
    world = _mixed_world(r)
    rng = np.random.default_rng(8)
    P = np.vstack([rng.uniform([0.5, 1.5, 0.1], [8.5, 9.5, 3.0], (300, 3)),
                   rng.uniform([2.2, 2.2, 0.1], [3.8, 4.8, 1.4], (10, 3)),  # inside the box
                   rng.uniform([1.1, 6.1, 0.1], [1.9, 8.9, 1.9], (10, 3))])  # fmt: skip  # inside the L
    cp, gp, n = point_nearest_k(world, P, 3)
    assert np.all(n == 3)
    for ob in world.obstacles:
        alone, ga = World3D([ob], FAR, r).clearance_and_gradient(P)
        slot = np.argmin(np.abs(cp - alone[:, None]), axis=1)
        np.testing.assert_allclose(cp[np.arange(len(P)), slot], alone, atol=1e-7)
        ok = alone > -r + 1e-6
        np.testing.assert_allclose(gp[np.arange(len(P)), slot][ok], ga[ok], atol=1e-6)
    assert np.all(cp[300:, 0] < -r)  # inside: negative, beyond the radius


def test_point_queries_do_not_depend_on_earlier_segment_queries():
    """The queries reuse coal objects across calls: a segment query's rotated placement must not leak into the
    points' (it did, by the last bits)."""
    world = _mixed_world(0.3)
    rng = np.random.default_rng(2)
    P = rng.uniform([0.5, 1.5, 0.1], [8.5, 9.5, 3.0], (100, 3))
    before = point_nearest_k(world, P, 3)
    segment_nearest_k(world.with_safety_radius(0.0), P, P + rng.normal(size=P.shape), 4)
    after = point_nearest_k(world, P, 3)
    for x, y in zip(before, after, strict=True):
        assert np.array_equal(x, y)


@pytest.fixture(scope="module")
def ctx_and_qp():
    world = World3D([box_obstacle([4.0, 3.0, 0.0], [6.0, 7.0, 1.0])], [0, 0, 0, 10, 10, 5], TP.drone_radius)
    ref = line_references([1.0, 5.0, 0.5], [3.0, 5.0, 1.6], [9.0, 5.0, 2.0], 3, Ts=PRM.Ts)
    f = make_drone_qp(world, TP, PRM, 3, ref)
    ctx = f.context
    v_prev = np.array([0.1, 0.0, 0.2, -0.1, 0.3, 0.0, 0.0, 0.0, 0.1])
    ctx.update(0, [[2.5, 5.2, 1.4], [4.5, 5.0, 1.7], [5.8, 4.6, 1.9]], v_prev)
    return ctx, f


def test_tether_rows_touch_each_tethers_two_ends(ctx_and_qp):
    ctx, f = ctx_and_qp
    N, Ts, S = 3, ctx.Ts, ctx.sens
    (lim_len,) = [lim for lim in f.qp.limits if isinstance(lim, TetherLength)]
    (lim_ten,) = [lim for lim in f.qp.limits if isinstance(lim, TetherTension)]
    A = lim_len.compute(ctx).A
    B = lim_ten.compute(ctx).A
    want_A, want_B = np.zeros((N, 3 * N)), np.zeros((2 * N, 3 * N))
    for j in range(N):
        want_A[j, 3 * j : 3 * j + 3] = Ts * S.dlength_dq[j]
        want_B[2 * j, 3 * j : 3 * j + 3] = Ts * S.dtension_p_dq[j]
        want_B[2 * j + 1, 3 * j : 3 * j + 3] = Ts * S.dtension_q_dq[j]
        if j:  # point j−1 is a drone (for j = 0 the fixed anchor: no columns; its tension row is the winch's)
            want_A[j, 3 * j - 3 : 3 * j] = Ts * S.dlength_dp[j]
            want_B[2 * j, 3 * j - 3 : 3 * j] = Ts * S.dtension_p_dp[j]
            want_B[2 * j + 1, 3 * j - 3 : 3 * j] = Ts * S.dtension_q_dp[j]
    want_B[0] = 0.0
    assert np.array_equal(A, want_A) and np.array_equal(B, want_B)


def test_clearance_rows_are_the_gradients_through_the_catenary(ctx_and_qp):
    ctx, f = ctx_and_qp
    N, Ts, S = 3, ctx.Ts, ctx.sens
    (tc,) = [lim for lim in f.qp.limits if isinstance(lim, TetherClearance)]
    (dc,) = [lim for lim in f.qp.limits if isinstance(lim, DroneClearance)]
    A = tc.compute(ctx).A
    m, k = tc.m, tc.nearest
    eye, zero = np.eye(3), np.zeros((3, 3))
    row = 0
    for j in range(N):
        Jp = [eye, *S.dpoints_dp[j], zero]
        Jq = [zero, *S.dpoints_dq[j], eye]
        for i in range(m + 1):
            for s in range(k):
                n, t = ctx.piece_gradient[j, i, s], ctx.piece_t[j, i, s]
                want = np.zeros(3 * N)
                want[3 * j : 3 * j + 3] = Ts * n @ ((1 - t) * Jq[i] + t * Jq[i + 1])
                if j:
                    want[3 * j - 3 : 3 * j] = Ts * n @ ((1 - t) * Jp[i] + t * Jp[i + 1])
                np.testing.assert_allclose(A[row], want, atol=1e-12)
                row += 1
    D = dc.compute(ctx).A
    kd = dc.nearest
    for i in range(N):
        for s in range(kd):
            want = np.zeros(3 * N)
            want[3 * i : 3 * i + 3] = Ts * ctx.drone_obstacle_gradient[i, s]
            assert np.array_equal(D[i * kd + s], want)


@pytest.mark.parametrize("vertical", [False, True])
def test_velocity_map_T_is_block_bidiagonal_with_the_link_rows(vertical):
    rng = np.random.default_rng(7)
    P = rng.normal(size=(5, 3))
    if vertical:
        P[2, :2] = P[1, :2]  # link 2 vertical
    vm = VelocityMap3D(P)
    N = 4
    want = np.zeros((3 * N, 3 * N))
    for j in range(N):
        want[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = vm.R[j]
        if j:
            want[3 * j : 3 * j + 3, 3 * j - 3 : 3 * j] = -vm.R[j]
    assert np.array_equal(vm.T, want)
    # the frame: orthonormal, right-handed, e1 ⟂ u
    for j in range(N):
        F = np.stack([vm.e1[j], vm.e2[j], vm.u[j]])
        np.testing.assert_allclose(F @ F.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(F) == pytest.approx(1.0)
    v = rng.normal(size=3 * N)
    np.testing.assert_allclose(vm.T @ v, vm.joint_rates(v), atol=1e-12)
