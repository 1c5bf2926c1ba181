"""The drones' jerk bound (``DroneParams.drone_jerk_max``, off by default; ``formulations/drones.md`` "Jerk"): set to
50 m/s³, the QP's rows hold at every step of the built-in plans F and H, measured independently (third differences
of the positions); the checker rejects a plan with a jerk spike the acceleration bound lets through; unset, the
plans are those without the rows (H's jerk reaches 160 m/s³) and no jerk is checked."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tmr.checks.drones import DRONE_VIOLATION_KINDS, check_drone_plan
from tmr.model.params import DroneParams

#: the bound these tests plan with [m/s³] (the lowest at which F, G, H, I all plan, formulations/drones.md "Jerk")
J_MAX = 50.0


@pytest.fixture(scope="module")
def plans():
    from tmr.planner3d import plan_drones
    from tmr.world.drones import load_drone_scenario

    out = {}
    for name in ("F", "H"):
        scenario = load_drone_scenario(name)
        out[name] = (scenario, *plan_drones(scenario, overrides={"drone_jerk_max": J_MAX}))
    return out


def _jerk(robots: np.ndarray, Ts: float) -> np.ndarray:
    """Per axis jerk [m/s³] at steps 0..K and the stop, from the positions alone, the chain at rest before and after
    (p_{-2} = p_{-1} = p_0, p_{K+1} = p_{K+2} = p_K)."""
    p = np.concatenate([robots[:1], robots[:1], robots[:1], robots, robots[-1:], robots[-1:]])
    return np.diff(p, n=3, axis=0) / Ts**3


@pytest.mark.parametrize("name", ["F", "H"])
def test_the_jerk_rows_hold_at_every_step(plans, name):
    scenario, plan, metrics = plans[name]
    assert plan.success and metrics.success, metrics.failure
    j_max = J_MAX
    Ts = float(plan.t[1] - plan.t[0])
    jerk = _jerk(np.asarray(plan.robots), Ts)
    assert np.abs(jerk).max() <= j_max + 8e-6 / Ts**3
    assert np.abs(jerk).max() > 0.5 * j_max  # it binds somewhere (the rows are not idle)
    assert metrics.peak_jerk == pytest.approx(np.abs(jerk).max(), rel=1e-9)
    acc = np.diff(robots_pad(plan.robots), n=2, axis=0) / Ts**2
    assert np.abs(acc).max() <= DroneParams().drone_accel_max + 4e-6 / Ts**2


def robots_pad(robots):
    r = np.asarray(robots)
    return np.concatenate([r[:1], r, r[-1:]])


def test_the_checker_rejects_a_jerk_spike(plans):
    """H's plan tampered at one quiet step of drone 2: 4 mm along x (the tethers' recorded catenaries re-solved for
    it). The acceleration swings by d/Ts², −2d/Ts², d/Ts² (≤ 3.2 m/s² more: within the 4 m/s² bound), the jerk by
    3d/Ts³ = 96 m/s³ (> 50): the checker rejects it for its jerk alone, and passes it with the bound lifted."""
    from tmr.model.catenary3d import solve3d

    scenario, plan, metrics = plans["H"]
    Ts = float(plan.t[1] - plan.t[0])
    acc = np.diff(robots_pad(plan.robots), n=2, axis=0) / Ts**2
    quiet = np.abs(acc[:, 1, 0]) + np.abs(np.roll(acc[:, 1, 0], 1)) + np.abs(np.roll(acc[:, 1, 0], -1))
    k = int(np.argmin(quiet[10:-10])) + 10
    assert np.abs(acc[k - 1 : k + 2, 1, 0]).max() < 0.5
    bad = dataclasses.replace(
        plan, robots=np.array(plan.robots, dtype=float), tether_a=np.array(plan.tether_a, dtype=float), diagnostics={}
    )
    bad.robots[k, 1, 0] += 4e-3
    pts = np.vstack([plan.base[None, :], bad.robots[k]])
    for j in range(pts.shape[0] - 1):
        a = solve3d(pts[j], pts[j + 1], plan.tether).a
        bad.tether_a[k, j] = np.nan if a is None else a
    m = check_drone_plan(bad, scenario, update_plan=False)  # the bound from the plan's own params
    failed = [kind for kind in DRONE_VIOLATION_KINDS if m.first_violation[kind] is not None]
    assert failed == ["jerk"], m.failures
    assert m.first_violation["jerk"] in (k - 1, k, k + 1)
    assert "m/s³" in m.failure and m.peak_jerk > J_MAX
    assert m.peak_acceleration <= DroneParams().drone_accel_max
    assert check_drone_plan(bad, scenario, update_plan=False, params={"drone_jerk_max": 1e4}).success
    assert check_drone_plan(plan, scenario, update_plan=False).success


def test_without_the_bound_the_rows_are_absent_and_nothing_is_checked():
    """The default (None): the plan is the one without jerk rows (H flips an acceleration of 4 m/s² per axis in one
    step: 160 m/s³), the checker reports the peak but checks no bound."""
    from tmr.planner3d import plan_drones
    from tmr.world.drones import load_drone_scenario

    assert DroneParams().drone_jerk_max is None
    scenario = load_drone_scenario("F")
    plan, metrics = plan_drones(scenario)
    assert metrics.success and metrics.jerk_max is None and metrics.first_violation["jerk"] is None
    assert metrics.peak_jerk == pytest.approx(160.0, rel=1e-6)
    with pytest.raises(Exception, match="drone_jerk_max must be a finite number > 0 or None"):
        DroneParams(drone_jerk_max=0.0)


def test_jerk_reach_is_the_largest_step_within_the_room():
    """``_jerk_reach`` (the jerk-aware speed rows' closed form) against its definition: Δ + S(Δ) ≤ room with
    S(Δ) = Σ_{i≥1} max(Δ − iJ, 0), and Δ + 1e-6 breaks it; a negative room is returned as it is."""
    from tmr.control.drones import _jerk_reach

    rng = np.random.default_rng(5)
    J = 10.0 ** rng.uniform(-4, 0, 400)
    room = rng.uniform(0, 40, 400) * rng.uniform(0, 1, 400) ** 2

    def total(d, j):
        i = np.arange(1, int(d / j) + 2)
        return d + np.maximum(d - i * j, 0.0).sum()

    for j, r in zip(J, room, strict=True):
        d = float(_jerk_reach(np.array([r]), j)[0])
        assert total(d, j) <= r + 1e-9 * max(1.0, r)
        assert total(d + 1e-6, j) > r
    assert float(_jerk_reach(np.array([-0.3]), 0.1)[0]) == -0.3


def test_the_bound_is_switched_off_by_none_and_refused_when_meaningless():
    from tmr.errors import ParameterError
    from tmr.model.params import apply_overrides

    params, _ = apply_overrides(DroneParams(), {"drone_jerk_max": "50"})
    assert params.drone_jerk_max == 50.0
    for off in ("none", "off", None):
        assert apply_overrides(params, {"drone_jerk_max": off})[0].drone_jerk_max is None
    for bad in ("0", "-1", "abc", "inf"):
        with pytest.raises(ParameterError):
            apply_overrides(DroneParams(), {"drone_jerk_max": bad})
