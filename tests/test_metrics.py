"""Tests of tmr.checks.metrics: fitness f1..f4 (Caruso 2021 eq. 24–27), clearances, violations, filtering."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from shapely.geometry import Point

from tmr.checks.metrics import (
    VIOLATION_KINDS,
    clearances,
    distance_errors,
    evaluate,
    filter_trajectories,
    filter_within_limits,
    fitness,
    limit_breaks,
    robot_separations,
)
from tmr.control.clik import Plan
from tmr.errors import ParameterError
from tmr.world.environment import Environment


def make_env(obstacles, bounds, safety_radius=0.5):
    return Environment.from_geometry(obstacles, bounds, safety_radius=safety_radius, resolution=0.05)


BOUNDS = (0.0, 0.0, 10.0, 10.0)


def make_plan(
    robots,
    base,
    *,
    Ts=0.05,
    reference=None,
    span_limits=(0.5, 5.6),
    success=True,
    failure=None,
    qdot=None,
    wall_time=0.6,
    r=0.5,
) -> Plan:
    """Plan from robot positions (K+1, N, 2): q from the chain geometry (absolute angles are fine here)."""
    robots = np.asarray(robots, dtype=float)
    k1, n = robots.shape[:2]
    base = np.asarray(base, dtype=float)
    pts = np.concatenate([np.broadcast_to(base, (k1, 1, 2)), robots], axis=1)
    links = np.diff(pts, axis=1)
    spans = np.linalg.norm(links, axis=-1)
    q = np.empty((k1, 2 * n))
    q[:, 0::2] = np.arctan2(links[..., 1], links[..., 0])
    q[:, 1::2] = spans
    if qdot is None:
        qdot = np.zeros_like(q)
        qdot[:-1] = np.diff(q, axis=0) / Ts
    return Plan(
        method="test",
        scenario="synthetic",
        t=np.arange(k1) * Ts,
        q=q,
        qdot=np.asarray(qdot, dtype=float),
        robots=robots,
        base=base,
        reference=robots[:, -1, :].copy() if reference is None else np.asarray(reference),
        spans=spans,
        span_limits=span_limits,
        safety_radius=r,
        success=success,
        failure=failure,
        diagnostics={},
        wall_time=wall_time,
        params={},
    )


# ----------------------------------------------------------------------------------------------------------
# fitness
# ----------------------------------------------------------------------------------------------------------
def tiny_plan(success=True):
    """K = 2 steps, N = 2 robots, Ts = 0.5 s, hand-set qdot, spans, leader and reference."""
    robots = np.array([[[9, 9], [5, 5]], [[9, 9], [1, 1]], [[9, 9], [2, 0]]], dtype=float)
    plan = make_plan(
        robots,
        (0.0, 0.0),
        Ts=0.5,
        success=success,
        failure=None if success else "collision",
        reference=np.array([[0, 0], [1, 0], [2, 2]], dtype=float),
        qdot=np.array([[1, 0, 2, 0], [0, 1, 0, 1], [0, 0, 0, 0]], dtype=float),
    )
    plan.spans = np.array([[1, 2], [2, 2], [3, 1]], dtype=float)
    return plan


def test_fitness_hand_computed():
    f1, f2, f3, f4 = fitness(tiny_plan(), Ts=0.5)
    assert f1 == pytest.approx(7.0)  # (1 + 4) + (1 + 1) + 0
    assert f2 == pytest.approx(5.0)  # (1-2)^2 + 0 + (3-1)^2
    assert f3 == pytest.approx(5.0)  # k >= 1 only: |(1,1)-(1,0)|^2 + |(2,0)-(2,2)|^2 (k = 0 would add 50)
    assert f4 == pytest.approx(36.0)  # |(-2,2,-4,2)|^2 + |(0,-2,0,-2)|^2


def test_fitness_ts_from_plan_time():
    assert fitness(tiny_plan()) == pytest.approx(fitness(tiny_plan(), Ts=0.5))


def test_fitness_infinite_on_failure():
    assert fitness(tiny_plan(success=False), Ts=0.5) == (math.inf,) * 4


def test_f2_generalises_pairs():
    rng = np.random.default_rng(0)
    spans = rng.uniform(1.0, 5.0, size=(7, 4))
    robots = rng.uniform(1.0, 9.0, size=(7, 4, 2))
    plan = make_plan(robots, (1.0, 1.0))
    plan.spans = spans
    expected = sum((spans[:, i] - spans[:, j]) ** 2 for i in range(4) for j in range(i + 1, 4)).sum()
    assert fitness(plan)[1] == pytest.approx(expected)
    # N = 3: exactly eq. 25
    plan3 = make_plan(robots[:, :3], (1.0, 1.0))
    plan3.spans = spans[:, :3]
    d1, d2, d3 = spans[:, :3].T
    assert fitness(plan3)[1] == pytest.approx(np.sum((d1 - d2) ** 2 + (d2 - d3) ** 2 + (d3 - d1) ** 2))
    # N = 1: no pair
    assert fitness(make_plan(robots[:, :1], (1.0, 1.0)))[1] == 0.0


def test_fitness_rejects_bad_ts():
    plan = tiny_plan()
    with pytest.raises(ParameterError):
        fitness(plan, Ts=0.0)


# ----------------------------------------------------------------------------------------------------------
# clearances and violations
# ----------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def disc_env():
    return make_env([Point(5.0, 5.0).buffer(1.0, quad_segs=64)], BOUNDS, 0.5)


def leader_into_disc_plan():
    """Robot 1 parked at (1.5, 5); the leader moves along y = 5 at 2 m/s and enters the inflated disc (radius
    1.5 around (5, 5), i.e. x > 3.5) at step 10 (x = 3.55); K = 15."""
    k = np.arange(16)
    robots = np.zeros((16, 2, 2))
    robots[:, 0] = (1.5, 5.0)
    robots[:, 1, 0] = 2.55 + 0.1 * k
    robots[:, 1, 1] = 5.0
    return make_plan(robots, (1.0, 5.0), span_limits=(0.4, 5.6))


def test_clearances_shapes_and_values(disc_env):
    plan = leader_into_disc_plan()
    c = clearances(plan, disc_env)
    assert c.robots.shape == (16, 2) and c.tethers.shape == (16, 2)
    np.testing.assert_allclose(c.robots[:, 0], 1.0, atol=1e-3)  # robot 1: 1.5 m from the wall, minus r
    x = 2.55 + 0.1 * np.arange(16)
    np.testing.assert_allclose(c.robots[:, 1], (5.0 - x) - 1.5, atol=2e-3)  # signed, negative inside the disc
    np.testing.assert_allclose(c.tethers[:, 0], 0.5, atol=1e-3)  # base (1, 5) is 0.5 m from the inflated wall
    np.testing.assert_allclose(c.tethers[:, 1], np.minimum(1.0, (5.0 - x) - 1.5), atol=2e-3)  # from robot 1


def test_robot_and_tether_violation_detected_at_exact_step(disc_env):
    m = evaluate(leader_into_disc_plan(), disc_env)
    assert m.first_violation["robot_clearance"] == 10
    assert m.violation_steps["robot_clearance"] == list(range(10, 16))
    assert m.first_violation["tether_clearance"] == 10  # tether 2 ends at the leader
    assert m.min_robot_clearance == pytest.approx(-0.55, abs=2e-3)  # x = 4.05: 0.95 from the centre
    assert m.min_robot_clearance_step == 15
    assert m.n_violation_steps == 6
    assert m.first_violation["separation"] is None and m.first_violation["span_max"] is None


def test_tether_crossing_obstacle_detected(disc_env):
    """One robot at x = 8 moving up from y = 0.8; base (2, 5). The tether (not the robot) crosses the inflated
    disc when |y - 5| < sqrt(12) = 3.464, i.e. from step 8 (y = 1.6)."""
    k = np.arange(21)
    robots = np.stack([np.full(21, 8.0), 0.8 + 0.1 * k], axis=-1)[:, None, :]
    m = evaluate(make_plan(robots, (2.0, 5.0), span_limits=(0.5, 10.0)), disc_env)
    assert m.first_violation["tether_clearance"] == 8
    assert m.violation_steps["tether_clearance"] == list(range(8, 21))
    assert m.first_violation["robot_clearance"] is None
    assert m.min_robot_clearance > 0.0
    u = -2.2  # last step: distance of the line to the centre 3|u|/sqrt(36 + u^2)
    assert m.min_tether_clearance == pytest.approx(3 * abs(u) / math.hypot(6.0, u) - 1.5, abs=5e-3)
    assert m.min_tether_clearance_step == 20


def test_separation_violation(disc_env):
    """Robot 3 approaches robot 2 at 0.1 m/step; 2 r = 1.0 m is crossed at step 6 (step 5 sits exactly on
    it)."""
    k = np.arange(11)
    robots = np.zeros((11, 3, 2))
    robots[:, 0] = (1.5, 2.0)
    robots[:, 1] = (3.0, 2.0)
    robots[:, 2, 0] = 4.5 - 0.1 * k
    robots[:, 2, 1] = 2.0
    m = evaluate(make_plan(robots, (1.0, 2.0), span_limits=(0.3, 5.6)), disc_env)
    assert m.first_violation["separation"] == 6
    assert m.violation_steps["separation"] == [6, 7, 8, 9, 10]
    assert m.min_separation == pytest.approx(0.5)
    assert m.separation_limit == 1.0
    sep = robot_separations(robots)
    assert sep.shape == (11, 3)


def test_span_ratio_and_limits(disc_env):
    robots = np.array([[[2.0, 2.0], [6.5, 2.0]], [[2.0, 2.2], [3.0, 2.2]]])  # spans (1, 4.5) then (~1.02, 1)
    plan = make_plan(robots, (1.0, 2.0), span_limits=(1.01, 5.0))
    m = evaluate(plan, disc_env)
    assert m.max_span == pytest.approx(4.5)
    assert m.d_max == 5.0
    assert m.max_span_ratio == pytest.approx(0.9)
    assert m.min_span == pytest.approx(1.0)
    assert m.d_lo == 1.01
    assert m.violation_steps["span_min"] == [0, 1]
    assert m.violation_steps["span_max"] == []
    # per-tether limits (N, 2): tether 2 limited to 4.0 m -> ratio 1.125 and a span_max violation at step 0
    plan.span_limits = np.array([[0.5, 5.0], [0.5, 4.0]])
    m = evaluate(plan, disc_env)
    assert m.max_span_ratio == pytest.approx(1.125)
    assert m.d_max == 4.0
    assert m.violation_steps["span_max"] == [0]
    assert m.violation_steps["span_min"] == []


def test_evaluate_speeds_errors_timing(disc_env):
    plan = leader_into_disc_plan()
    plan.robots[8:, 0, 1] += 0.05  # robot 1 jumps 5 cm at step 10: 1 m/s, then +-20 m/s^2
    plan.spans = np.tile([1.0, 2.0], (16, 1))
    plan.spans[3] = (1.0, 4.0)
    plan.goal = np.array([4.0, 5.0])
    m = evaluate(plan, disc_env)
    assert m.peak_speed_per_robot == pytest.approx([1.0, 2.0])
    assert m.peak_speed == pytest.approx(2.0)
    assert m.final_speed == pytest.approx(2.0)  # the leader still moves at 2 m/s over the last step
    assert m.peak_acceleration_per_robot == pytest.approx([20.0, 0.0], abs=1e-9)
    assert m.max_abs_distance_error == pytest.approx(1.5)
    assert m.max_abs_distance_error_per_tether == pytest.approx([1.5, 1.5])
    assert m.final_leader_error == pytest.approx(0.05)
    assert m.max_tracking_error == 0.0 and m.rms_tracking_error == 0.0
    assert m.n_steps == 15 and m.Ts == pytest.approx(0.05) and m.duration == pytest.approx(0.75)
    assert m.ms_per_step == pytest.approx(40.0)  # 0.6 s / 15 steps
    np.testing.assert_allclose(distance_errors(plan)[3], [-1.5, 1.5])
    assert evaluate(plan, disc_env, goal=(4.05, 5.3)).final_leader_error == pytest.approx(0.3)  # explicit goal wins
    plan.goal = None
    assert evaluate(plan, disc_env).final_leader_error == 0.0  # falls back to the reference's end


def test_evaluate_failed_plan_and_json(disc_env):
    plan = leader_into_disc_plan()
    plan.success, plan.failure = False, "leader entered an obstacle"
    m = evaluate(plan, disc_env)
    assert m.fitness == (math.inf,) * 4
    d = m.to_dict()
    text = json.dumps(d, allow_nan=False)  # JSON-safe
    assert d["f1"] == "inf" and float(d["f4"]) == math.inf
    assert d["failure"] == "leader entered an obstacle"
    assert list(d["violation_steps"]) == list(VIOLATION_KINDS)
    assert d["first_violation"]["separation"] is None
    assert json.loads(text)["first_violation"]["robot_clearance"] == 10


def test_single_robot_has_no_separation(disc_env):
    robots = np.stack([np.linspace(2, 3, 5), np.full(5, 2.0)], axis=-1)[:, None, :]
    m = evaluate(make_plan(robots, (1.0, 2.0)), disc_env)
    assert m.min_separation == math.inf
    assert m.violation_free


# ----------------------------------------------------------------------------------------------------------
# filtering
# ----------------------------------------------------------------------------------------------------------
def test_filter_keeps_a_line_and_raw_untouched():
    t = np.arange(301) * 0.05
    raw = np.stack([1.0 + 0.3 * t, 2.0 - 0.1 * t], axis=-1)[:, None, :].repeat(3, axis=1)
    before = raw.copy()
    out = filter_trajectories(raw, 0.05)
    np.testing.assert_allclose(out, raw, atol=1e-6)
    np.testing.assert_array_equal(raw, before)
    assert out is not raw


def test_filter_removes_spike_and_keeps_endpoints():
    t = np.arange(301) * 0.05
    s = t / t[-1]
    smooth = np.stack([8 * (10 * s**3 - 15 * s**4 + 6 * s**5), 3 * np.sin(np.pi * s)], axis=-1)[:, None, :]
    spiky = smooth.copy()
    spiky[150, 0, 1] += 0.5
    out = filter_trajectories(spiky, 0.05, cutoff_hz=1.0)
    assert abs(out[150, 0, 1] - smooth[150, 0, 1]) < 0.06  # the 0.5 m spike is cut by ~10x
    np.testing.assert_allclose(out[[0, -1]], smooth[[0, -1]], atol=1e-4)
    assert np.abs(out - smooth).max() < 0.06


def test_filter_short_series_and_bad_parameters():
    raw = np.array([[[0.0, 0.0]], [[1.0, 0.0]], [[2.0, 0.5]], [[3.0, 0.0]]])
    out = filter_trajectories(raw, 0.05)
    assert out.shape == raw.shape and np.all(np.isfinite(out))
    np.testing.assert_array_equal(filter_trajectories(raw[:2], 0.05), raw[:2])
    with pytest.raises(ParameterError, match="Nyquist"):
        filter_trajectories(raw, 0.05, cutoff_hz=10.0)
    with pytest.raises(ParameterError):
        filter_trajectories(raw, -1.0)


def test_plan_stopped_at_first_sample(disc_env):
    plan = make_plan(np.array([[[2.0, 2.0], [3.0, 2.0]]]), (1.0, 2.0))
    plan.success, plan.failure = False, "infeasible first step"
    m = evaluate(plan, disc_env)
    assert m.n_steps == 0 and math.isnan(m.Ts) and math.isnan(m.ms_per_step)
    assert m.f1 == math.inf and m.peak_speed == 0.0 and m.peak_acceleration == 0.0
    assert m.to_dict()["Ts"] == "nan"


def _radial_stop(d_max: float):
    """One robot driving straight away from the anchor at 1 m/s and stopping 1 cm short of d_max: the filter's
    overshoot at the stop carries it past d_max."""
    Ts = 0.05
    t = np.arange(0.0, 10.0 + Ts / 2, Ts)
    x = np.clip(3.0 + (t - 1.0), 3.0, 6.59)
    robots = np.stack([x, np.full_like(x, 5.0)], axis=-1)[:, None, :]
    plan = make_plan(robots, (1.0, 5.0), span_limits=(0.5, d_max))
    return plan, make_env([Point(8.5, 1.5).buffer(0.3)], BOUNDS), Ts


def test_filter_within_limits_keeps_the_raw_plan_where_the_filter_breaks_a_limit():
    plan, env, Ts = _radial_stop(5.6)
    plain = filter_trajectories(plan.robots, Ts)
    assert not limit_breaks(plan, plan.robots, env).any()
    broken = limit_breaks(plan, plain, env)
    assert broken.any() and np.linalg.norm(plain[broken, 0] - plan.base, axis=-1).max() > 5.6 + 1e-4
    out, note = filter_within_limits(plan, env, Ts)
    assert not limit_breaks(plan, out, env).any()
    assert "broke a hard limit" in note and "t = " in note
    np.testing.assert_array_equal(out[broken], plan.robots[broken])  # held: the raw plan there
    first = int(np.argmax(broken))
    far = np.arange(len(out)) < first - 1.0 / Ts - 1  # beyond the blend (1 / cut-off = 1 s): the filter's output
    np.testing.assert_array_equal(out[far], plain[far])


def test_filter_within_limits_leaves_a_clean_filter_alone():
    plan, env, Ts = _radial_stop(7.0)
    out, note = filter_within_limits(plan, env, Ts)
    assert note is None
    np.testing.assert_array_equal(out, filter_trajectories(plan.robots, Ts))


def test_filter_within_limits_says_when_it_did_not_check():
    plan, env, Ts = _radial_stop(5.6)
    plan.success, plan.failure = False, "leader ends 1 m from the goal"
    out, note = filter_within_limits(plan, env, Ts)
    np.testing.assert_array_equal(out, filter_trajectories(plan.robots, Ts))
    assert "not checked" in note
