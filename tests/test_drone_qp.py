"""The drone chain's per-step QP and pinv (tmr.control.drones, tmr.control.run3d) on hand-made 3-D worlds with
straight-line references: every hard limit re-checked at every step with the catenary model's own check
(tether_limits: 128 samples with the sampling margin), World3D's exact clearances and plain geometry."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tmr.control.drones import TetherClearance, make_drone_pinv, make_drone_qp
from tmr.control.limits import Limit, LimitRows
from tmr.control.qp import LEVEL_STATUS
from tmr.control.run3d import line_references, run_drones
from tmr.model.catenary3d import DroneTetherParams, solve3d, tether_limits
from tmr.model.params import DroneParams
from tmr.world.world3d import World3D, box_obstacle

TP = DroneTetherParams()
PRM = DroneParams()


def _plan(world, ref, n, method="qp", tether=TP, params=PRM, drop=()):
    make = make_drone_qp if method == "qp" else make_drone_pinv
    f = make(world, tether, params, n, ref)
    if drop:
        f.qp.limits = [lim for lim in f.qp.limits if not isinstance(lim, drop)]
    return run_drones(world, ref, f, ref.start_positions, tether=tether, params=params)


def _violations(plan, world, tether=TP, params=PRM):
    """Every hard limit at every step, measured independently of the QP's rows."""
    bare = world.with_safety_radius(0.0)
    out = []
    N = plan.n_robots
    for k in range(len(plan.t)):
        P = plan.points(k)
        for j in range(N):
            cat = solve3d(P[j], P[j + 1], tether)
            a = np.nan if cat.a is None else cat.a
            assert np.isnan(a) == np.isnan(plan.tether_a[k, j]) and (
                np.isnan(a) or a == pytest.approx(plan.tether_a[k, j])
            )
            out += [f"k={k} tether {j + 1}: {m}" for m in tether_limits(cat, tether, drone_ends=(j > 0, True),
                                                                        distance=bare.clearance)]  # fmt: skip
        c = world.clearance(plan.robots[k])
        out += [f"k={k} drone clearance {x:.4f}" for x in c if x < -1e-9]
        for i in range(N):
            for j in range(i + 1, N):
                gap = np.linalg.norm(P[i + 1] - P[j + 1])
                if gap < 2 * world.safety_radius - 1e-9:
                    out.append(f"k={k} drones {i + 1},{j + 1} {gap:.3f} m apart")
    V = plan.velocities
    if np.max(np.abs(V)) > params.drone_speed_max + 1e-6:
        out.append(f"speed {np.max(np.abs(V)):.4f}")
    acc = np.abs(np.diff(V[:-1], axis=0)) / plan.Ts
    if acc.size and np.max(acc) > params.drone_accel_max + 1e-5 and not np.any(plan.diagnostics.get("relaxed", 0)):
        out.append(f"acceleration {np.max(acc):.4f}")
    return out


def _low_box():
    """A low box under the tether's path: the straight chord from the anchor clears it by more than c_t, the sagging
    catenary does not (checked in the test)."""
    world = World3D([box_obstacle([4.0, 3.0, 0.0], [6.0, 7.0, 1.0])], [0, 0, 0, 10, 10, 5], TP.drone_radius)
    ref = line_references([1.0, 5.0, 0.5], [3.0, 5.0, 1.6], [9.0, 5.0, 2.0], 2, Ts=PRM.Ts)
    return world, ref


def test_low_box_the_qp_keeps_the_sagging_curve_clear():
    world, ref = _low_box()
    plan = _plan(world, ref, 2)
    assert plan.success, plan.failure
    assert _violations(plan, world) == []
    assert np.linalg.norm(plan.robots[-1, -1] - plan.goal) < PRM.goal_tolerance
    assert np.all(np.isfinite(plan.diagnostics["step_time"][:-1]))  # (the last state has no step)
    assert set(np.unique(plan.diagnostics["qp_level:leader"][:-1])) == {float(LEVEL_STATUS.index("solved"))}
    # without the tether-clearance rows the same references drag the sag into the box while the chord stays clear:
    # the limit is what keeps the curve out
    free = _plan(world, ref, 2, drop=(TetherClearance,))
    bare = world.with_safety_radius(0.0)
    sag_only = []
    for k in range(len(free.t)):
        P = free.points(k)
        for j in range(2):
            chord = bare.segment_clearance(P[j], P[j + 1])
            curve = bare.clearance(solve3d(P[j], P[j + 1], TP).points(128)).min()
            if chord >= TP.clearance and curve < TP.clearance - 0.01:
                sag_only.append(k)
    assert sag_only, "the test world should make the sag, not the chord, bind"
    assert any("tether passes" in v for v in _violations(free, world))


def test_wall_with_a_window():
    wall = [  # x in [4.8, 5.2]; window y in [3.5, 6.5], z in [1.0, 3.0]
        box_obstacle([4.8, 0.0, 0.0], [5.2, 3.5, 4.0]),
        box_obstacle([4.8, 6.5, 0.0], [5.2, 10.0, 4.0]),
        box_obstacle([4.8, 3.5, 0.0], [5.2, 6.5, 1.0]),
        box_obstacle([4.8, 3.5, 3.0], [5.2, 6.5, 4.0]),
    ]
    world = World3D(wall, [0, 0, 0, 10, 10, 4], TP.drone_radius)
    ref = line_references([1.0, 5.0, 0.3], [2.5, 5.0, 2.0], [8.5, 5.0, 2.0], 3, Ts=PRM.Ts)
    plan = _plan(world, ref, 3)
    assert plan.success, plan.failure
    assert _violations(plan, world) == []
    assert np.linalg.norm(plan.robots[-1, -1] - plan.goal) < PRM.goal_tolerance
    assert np.all(plan.robots[-1, 1:, 0] > 5.2)  # drones 2 and 3 went through, tether 2 passes the window


def test_pulled_apart_until_the_arc_length_binds():
    tether = dataclasses.replace(TP, tether_length=4.0)
    world = World3D([], [0, 0, 0, 20, 10, 5], tether.drone_radius)
    ref = line_references([1.0, 5.0, 0.5], [2.0, 5.0, 2.0], [14.0, 5.0, 2.0], 2, Ts=PRM.Ts)
    plan = _plan(world, ref, 2, tether=tether)
    assert not plan.success and plan.failure.startswith("the leader stalled")  # held back by the limit, and says so
    assert _violations(plan, world, tether) == []
    lengths = np.array([[solve3d(*plan.points(k)[j : j + 2], tether).length for j in range(2)]
                        for k in range(len(plan.t))])  # fmt: skip
    bound = tether.tether_length - PRM.length_margin
    assert lengths.max() <= bound + 0.005  # the linearised row is exact to first order; the margin covers the rest
    assert lengths.max() > bound - 0.02  # it binds ...
    assert np.nanmax(plan.diagnostics["leader_residual"]) > 0.1  # ... and holds the leader back
    assert np.linalg.norm(plan.robots[-1, -1] - plan.goal) > 1.0
    # stalled: it stopped STALL_S after the references came to rest, not at the end of their settle
    k_end = int(np.flatnonzero(np.any(np.diff(ref.positions, axis=0) != 0, axis=(1, 2)))[-1]) + 1
    assert len(plan.t) - 1 == k_end + round(1.0 / PRM.Ts) < len(ref.t) - 1


def test_drone_end_tension_binds_when_climbing():
    tether = dataclasses.replace(TP, thrust_to_weight=1.5, control_reserve=0.2)  # spare thrust 2.94 N: h <= 6.1 m
    world = World3D([], [0, 0, 0, 10, 10, 12], tether.drone_radius)
    ref = line_references([5.0, 5.0, 0.3], [5.5, 5.0, 1.5], [6.0, 5.0, 11.0], 1, Ts=PRM.Ts)
    plan = _plan(world, ref, 1, tether=tether)
    assert not plan.success and plan.failure.startswith("the leader stalled")  # held back by the limit, and says so
    assert _violations(plan, world, tether) == []
    T = np.array([solve3d(plan.base, plan.robots[k, 0], tether).tension_q for k in range(len(plan.t))])
    assert T.max() <= tether.spare_thrust - PRM.tension_margin + 0.005
    assert T.max() > tether.spare_thrust - PRM.tension_margin - 0.02


def test_span_no_catenary_holds_fails_the_plan_with_the_reason():
    world = World3D([], [0, 0, 0, 40, 10, 5], TP.drone_radius)
    ref = line_references([1.0, 5.0, 0.5], [25.0, 5.0, 0.6], [30.0, 5.0, 1.0], 1, Ts=PRM.Ts)
    plan = _plan(world, ref, 1)
    assert not plan.success
    assert "step 0" in plan.failure and "longer than" in plan.failure
    assert plan.robots.shape[0] == 1


def test_pinv_runs_the_papers_clik_on_the_spatial_chain():
    world, ref = _low_box()
    plan = _plan(world, ref, 2, method="pinv")
    assert plan.success, plan.failure
    assert plan.q is not None and plan.q.shape == (len(plan.t), 6)
    f = make_drone_pinv(world, TP, PRM, 2, ref)
    for k in (0, len(plan.t) // 2, len(plan.t) - 1):
        np.testing.assert_allclose(f.context.chain.robots(plan.q[k]), plan.robots[k], atol=1e-12)
    assert np.linalg.norm(plan.robots[-1, -1] - plan.goal) < PRM.goal_tolerance
    assert np.nanmax(plan.diagnostics["obstacle_active"]) > 0  # the soft obstacle task acted


class _Impossible(Limit):
    """Drone 1 faster than the speed bound (x): contradicts DroneSpeed, a safety limit."""

    name = "impossible"
    space = "robot"

    def pattern(self, chain):
        mask = np.zeros((1, 3 * chain.n_robots), dtype=bool)
        mask[0, 0] = True
        return mask

    def compute(self, ctx):
        A = np.zeros((1, 3 * ctx.chain.n_robots))
        A[0, 0] = 1.0
        return LimitRows(A, np.array([10.0]), np.array([np.inf]))


def test_an_infeasible_step_fails_the_plan_with_the_reason():
    world = World3D([], [0, 0, 0, 10, 10, 5], TP.drone_radius)
    ref = line_references([1.0, 5.0, 0.5], [2.0, 5.0, 1.5], [6.0, 5.0, 2.0], 2, Ts=PRM.Ts)
    f = make_drone_qp(world, TP, PRM, 2, ref)
    f.qp.limits.append(_Impossible())
    plan = run_drones(world, ref, f, ref.start_positions, tether=TP, params=PRM)
    assert not plan.success
    assert plan.failure.startswith("step 0 (t = 0.00 s): the hard constraints have no common solution")
    assert plan.robots.shape[0] == 1 and np.all(plan.velocities == 0.0)


def test_segment_nearest_matches_coal_and_the_point_queries():
    from tmr.control.drones import segment_box_distance, segment_nearest
    from tmr.world.world3d import prism_obstacle

    rng = np.random.default_rng(5)
    obstacles = [box_obstacle([2, 2, 0], [4, 5, 1.5]), box_obstacle([6, 1, 1], [7, 3, 4]),
                 prism_obstacle([[1, 6], [3, 7], [2, 9]], [0.0, 2.5])]  # fmt: skip
    world = World3D(obstacles, [0, 0, 0, 10, 10, 5], 0.0)
    a = rng.uniform([0, 0, 0], [10, 10, 5], (400, 3))
    b = a + rng.normal(scale=1.5, size=a.shape)
    b = np.clip(b, 0.01, [9.99, 9.99, 4.99])
    c, g, t = segment_nearest(world, a, b)
    ref = world.segment_clearance(a, b)  # coal's capsule queries; a blocked segment's depth is one obstacle's
    np.testing.assert_allclose(c[ref > 0], ref[ref > 0], atol=1e-7)
    assert np.all(c[ref <= 0] <= 1e-9)
    X = a + t[:, None] * (b - a)
    free = c > 1e-6
    cx, gx = world.clearance_and_gradient(X[free])
    np.testing.assert_allclose(cx, c[free], atol=1e-7)  # the nearest point has the segment's clearance
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-9)
    # the same gradient, but where two walls (or a wall and an obstacle) tie, where either is one
    assert np.mean(np.all(np.abs(gx - g[free]) < 1e-5, axis=1)) > 0.97
    # the closed form against a dense sampling of the segment
    lo, hi = np.array([2.0, 2, 0]), np.array([4.0, 5, 1.5])
    d, tb = segment_box_distance(a, b, lo, hi)
    s = np.linspace(0, 1, 2001)
    P = a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]
    dense = np.linalg.norm(P - np.clip(P, lo, hi), axis=2)
    assert np.all(d <= dense.min(axis=1) + 1e-12)
    assert np.all(d >= dense.min(axis=1) - np.linalg.norm(b - a, axis=1) / 2000)


def test_few_samples_the_arc_between_them_keeps_c_t():
    """Two samples per tether: pieces of ~1 m whose arc departs from the chord by δ²/(8a) ≈ 1-3 cm, more than d_safe
    covers; the rows add that departure per tether, so the catenary itself (128 samples) keeps c_t (it did not)."""
    world, ref = _low_box()
    params = dataclasses.replace(PRM, tether_samples=2)
    plan = _plan(world, ref, 2, params=params)
    assert plan.success, plan.failure
    assert _violations(plan, world, params=params) == []


def test_chord_deviation_bounds_the_arc_between_samples():
    world, ref = _low_box()
    f = make_drone_qp(world, TP, dataclasses.replace(PRM, tether_samples=2), 2, ref)
    ctx = f.context
    ctx.update(0, [[3.0, 5.0, 1.0], [6.5, 5.0, 1.2]], np.zeros(6))
    for j, cat in enumerate(ctx.catenaries):
        X = cat.points(301)  # equal arc length: pieces of 100 points between the 2 interior samples
        worst = 0.0
        for s in range(3):
            a, b, arc = X[100 * s], X[100 * (s + 1)], X[100 * s : 100 * (s + 1) + 1]
            u = (b - a) / np.linalg.norm(b - a)
            off = (arc - a) - ((arc - a) @ u)[:, None] * u
            worst = max(worst, np.linalg.norm(off, axis=1).max())
        assert worst <= ctx.chord_deviation[j] + 1e-9  # a bound ...
        assert worst >= 0.9 * ctx.chord_deviation[j]  # ... and a tight one (the curvature is ≈ 1/a throughout)


def test_segment_and_point_queries_give_each_obstacle_its_own_slot():
    from tmr.control.drones import point_nearest_k, segment_nearest_k
    from tmr.world.world3d import prism_obstacle

    obstacles = [box_obstacle([4.8, 0.0, 0.0], [5.2, 4.0, 4.0]), box_obstacle([4.8, 4.0, 0.0], [5.2, 6.0, 1.2]),
                 prism_obstacle([[6, 6], [7, 6], [6.5, 7]], [0.0, 2.0])]  # fmt: skip
    bounds = [0, 0, 0, 10, 10, 4]
    world = World3D(obstacles, bounds, 0.0)
    rng = np.random.default_rng(3)
    a = rng.uniform([3.5, 2.5, 0.5], [7.5, 7.5, 3.0], (300, 3))
    b = a + rng.normal(scale=0.8, size=a.shape)
    c, g, t, count = segment_nearest_k(world, a, b, 9)
    assert np.all(count == 9) and np.all(np.diff(c, axis=1) >= 0)  # every obstacle and wall, nearest first
    for ob in obstacles:  # each obstacle's own clearance is one of the slots (far walls: the obstacle alone)
        alone = World3D([ob], [-50, -50, -50, 50, 50, 50], 0.0).segment_clearance(a, b)
        free = alone > 1e-6
        assert np.all(np.min(np.abs(c[free] - alone[free, None]), axis=1) < 1e-7)
    X = a[:, None, :] + t[..., None] * (b - a)[:, None, :]  # each slot's point is that obstacle's nearest one:
    free = c > 1e-6
    assert np.all(world.clearance(X)[free] <= c[free] + 1e-7)  # the world is at most that far from it
    np.testing.assert_allclose(world.clearance(X[:, 0])[free[:, 0]], c[free[:, 0], 0], atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(g[free], axis=-1), 1.0, atol=1e-9)
    # at the window's corner (jamb x sill) both boxes have a row of their own
    cc, _, _, _ = segment_nearest_k(world, np.array([[5.0, 4.3, 1.5]]), np.array([[5.0, 4.3, 1.6]]), 3, cap=1.0)
    assert cc[0, 0] == pytest.approx(0.3) and cc[0, 1] == pytest.approx(0.3)  # sill 0.3 below, jamb 0.3 aside
    # points: the obstacles only, each with its exact clearance and gradient
    r = 0.3
    P = rng.uniform([3.5, 2.5, 0.5], [7.5, 7.5, 3.0], (300, 3))
    cp, gp, n = point_nearest_k(world.with_safety_radius(r), P, 3)
    assert np.all(n == 3)
    for ob in obstacles:
        alone, ga = World3D([ob], [-50, -50, -50, 50, 50, 50], r).clearance_and_gradient(P)
        slot = np.argmin(np.abs(cp - alone[:, None]), axis=1)
        np.testing.assert_allclose(cp[np.arange(len(P)), slot], alone, atol=1e-7)
        ok = alone > -r + 1e-6
        np.testing.assert_allclose(gp[np.arange(len(P)), slot][ok], ga[ok], atol=1e-6)


def test_window_corner_tether_clearance_is_a_hard_limit():
    """Scenario F with the winch beside the window's jamb: tether 2 passes the corner where the jamb meets the sill,
    the nearest obstacle alternating between them; with one row per obstacle the checker finds the curve clear (it
    found tether 2 at 0.198 m from the jamb, less than c_t, with one row for the nearest obstacle per piece)."""
    from tmr.planner3d import plan_drones
    from tmr.world.drones import load_drone_scenario

    scenario = dataclasses.replace(load_drone_scenario("F"), base=np.array([4.55, 1.0, 0.3]))
    plan, metrics = plan_drones(scenario)
    assert plan.success, plan.failure
    assert metrics.min_tether_clearance >= TP.clearance


def test_sliding_across_a_taut_tether_does_not_creep_past_the_length():
    """The leader's reference passes the anchor farther than the tether reaches: the drone slides across its taut
    tether, which lengthens it to second order (|Δ|²/(2c) per step) where the linear row sees no change; the row's
    second-order term keeps the arc within L_max − margin (it crept 1 cm past it)."""
    tether = dataclasses.replace(TP, tether_length=4.0)
    world = World3D([], [0, 0, 0, 20, 20, 6], tether.drone_radius)
    ref = line_references([10.0, 10.0, 0.5], [7.0, 6.5, 2.0], [16.0, 6.5, 2.0], 1, Ts=PRM.Ts, speed=2.0)
    ref.start_positions[:] = [[8.5, 8.0, 1.5]]
    plan = _plan(world, ref, 1, tether=tether)
    assert not plan.success and plan.failure.startswith("the leader stalled")  # held back by the limit, and says so
    L = np.array([solve3d(*plan.points(k), tether).length for k in range(len(plan.t))])
    bound = tether.tether_length - PRM.length_margin
    assert L.max() <= bound + 1e-3
    assert L.max() > bound - 0.01  # it binds


def test_the_plan_ends_once_the_chain_rests_at_the_goal():
    """After the references stop, the plan waits at most ``settle`` for the chain: it ends at the first step where the
    leader is within half the goal tolerance and every drone at rest (no velocity component above REST_SPEED)."""
    from tmr.control.run3d import REST_SPEED

    world = World3D([], [0, 0, 0, 10, 10, 4], TP.drone_radius)
    ref = line_references([1.0, 5.0, 0.3], [2.5, 5.0, 2.0], [6.0, 5.0, 2.0], 2, Ts=PRM.Ts, settle=8.0)
    plan = _plan(world, ref, 2)
    assert plan.success, plan.failure
    k_end = int(np.ceil(3.5 / PRM.Ts))  # the references stop moving here (1 m/s over 3.5 m)
    assert k_end < len(plan.t) - 1 < len(ref.t) - 1  # ended after the references, before their 8 s tail
    assert np.linalg.norm(plan.robots[-1, -1] - plan.goal) <= PRM.goal_tolerance / 2
    assert np.abs(plan.velocities[-2]).max() <= REST_SPEED  # at rest when it stops
    assert np.abs(plan.velocities[-3]).max() > REST_SPEED  # and not one step later than that


def test_slowed_references_keep_the_path_at_half_speed():
    """The re-timed references: unchanged before k0, the same path, half the speed over the slow part, and the
    speed changed smoothly (no jump of the reference velocity at the seams), the same end."""
    from tmr.control.run3d import slowed_references

    ref = line_references([1.0, 5.0, 0.3], [2.0, 5.0, 2.0], [8.0, 5.0, 2.0], 2, Ts=PRM.Ts, settle=1.0)
    K = len(ref.t) - 1
    s = slowed_references(ref, 20, 40, ramp=20, base=[1.0, 5.0, 0.3])
    np.testing.assert_allclose(np.diff(s.t), PRM.Ts)
    np.testing.assert_allclose(s.positions[:21], ref.positions[:21])  # unchanged before k0
    np.testing.assert_allclose(s.positions[-1], ref.positions[-1])  # the same end
    assert K + 15 <= len(s.t) - 1 <= K + 25  # 40 samples' worth of motion: 20 at half speed, the ramps between
    speed = np.linalg.norm(s.xd, axis=1)
    assert speed[42:58].max() == pytest.approx(0.5, abs=1e-9)  # the hold, at half of 1 m/s
    assert np.abs(np.diff(speed[5:100])).max() / PRM.Ts < 1.0  # smooth seams: 0.75 m/s² at most (it jumped 10 m/s²)
    # the velocities are those of the positions (midpoint rule, exact to O(Ts · acceleration))
    fd = np.diff(s.positions, axis=0) / PRM.Ts
    np.testing.assert_allclose(fd[:100], 0.5 * (s.velocities[1:101] + s.velocities[:100]), atol=0.02)
    # on the original path: the leader between start and goal on the line
    np.testing.assert_allclose(s.x[:, 1:], np.tile([5.0, 2.0], (len(s.t), 1)), atol=1e-12)
    np.testing.assert_allclose(s.base, [1.0, 5.0, 0.3])


def test_a_step_without_a_solution_slows_the_chain_down_instead_of_failing(tmp_path):
    """window-0-5 of the seeded drone worlds with 4 drones: at full speed a tether's clearance rows and the
    acceleration bounds conflict at t = 15.95 s (no common solution); going back 1 s and taking the next 3 s at half
    speed gives a plan that passes the independent check."""
    from tmr.planner3d import plan_drones
    from tmr.sweep.rooms3d import drone_worlds
    from tmr.world.drones import load_drone_scenario

    world = next(w for w in drone_worlds(6, seed=0) if w.name == "window-0-5")
    scenario = load_drone_scenario(str(world.write(tmp_path)))
    plan, metrics = plan_drones(scenario, robots=4)
    assert plan.diagnostics["slowed_down"][0] == "t = 15.95 s"
    assert plan.success, plan.failure
    assert metrics.success and metrics.peak_acceleration <= PRM.drone_accel_max + 1e-6
