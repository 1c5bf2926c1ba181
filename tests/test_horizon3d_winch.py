"""The drone horizon's own winch schedule (an active winch; ``formulations/horizon3d.md``, "Active winch"): the least
rate-bounded tension for drone positions already chosen (:mod:`tmr.control.horizon3d_winch`), its envelope core shared
with the ground chain (:func:`tmr.control.winch.rate_bounded_envelope`), and the fallback to the held qp schedule
when the checker rejects it. On scenario I's qp plan (≈ 1 s to plan)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tmr.checks.drones import check_drone_plan
from tmr.control import horizon3d_winch
from tmr.control.horizon3d import _choose_tensions, _plan_of
from tmr.control.horizon3d_winch import TetherRule, least_drone_tensions, thrust_need
from tmr.control.winch import rate_bounded_envelope
from tmr.planner3d import build_drone_problem, drone_parameters, solve_drones
from tmr.world.drones import load_drone_scenario


def test_rate_bounded_envelope_is_the_least_rate_bounded_cover():
    """Against its definition T_k = max_i (need_i − step |k − i|): equal, above need, rate-bounded, and any
    rate-bounded cover of need is above it (here: need itself lifted to a rate-bounded sequence by hand)."""
    rng = np.random.default_rng(3)
    need = rng.uniform(0.5, 6.0, size=(40, 3))
    step = 0.1
    T = rate_bounded_envelope(need, step)
    k = np.arange(40)
    want = np.max(need[None, :, :] - step * np.abs(k[:, None] - k[None, :])[:, :, None], axis=1)
    assert np.allclose(T, want, atol=1e-12, rtol=0)
    assert np.all(T >= need) and np.abs(np.diff(T, axis=0)).max() <= step + 1e-12
    cover = np.full_like(need, need.max())  # a constant cover is rate-bounded: the envelope lies below it
    assert np.all(T <= cover)
    # step 0: a constant winch, each column's maximum
    assert np.allclose(rate_bounded_envelope(need, 0.0), np.broadcast_to(need.max(axis=0), need.shape))


@pytest.fixture(scope="module")
def i_qp():
    """Scenario I (active winches, 2 drones) planned by the per-step QP, its problem and its rule."""
    scenario = load_drone_scenario("I")
    params, tether = drone_parameters(scenario)
    problem = build_drone_problem(scenario, scenario.n_robots, params=params, tether=tether)
    plan, metrics = solve_drones(problem, "qp")
    assert metrics.success, metrics.failures
    rule = TetherRule.of_problem(problem.world, tether, params, plan.base)
    return problem, plan, metrics, rule


def test_least_schedule_respects_range_rate_held_and_the_rule(i_qp):
    """On the qp plan's own positions: the schedule lies in [T_min, T_max], changes by at most rate Ts per step, is
    ≤ the qp schedule at every knot and ≥ min(T_ref, T^qp); the rule holds at every knot at the schedule, fails
    just below each per-knot least tension that is above its floor (the bisection's bracket), and the schedule is
    lower than the held one somewhere (I's qp raises its winches earlier than its positions need)."""
    problem, plan, _, rule = i_qp
    teth = plan.tether
    held = plan.winch_tension
    T, info = least_drone_tensions(rule, plan.base, plan.robots, held, teth.winch_tension, teth.winch_tension_rate,
                                   plan.Ts)  # fmt: skip
    assert T.shape == held.shape
    assert T.min() >= teth.winch_tension_min and T.max() <= teth.winch_tension_max
    assert np.abs(np.diff(T, axis=0)).max() <= teth.winch_tension_rate * plan.Ts * (1 + 1e-9)
    assert np.all(T <= held) and np.all(T >= np.minimum(teth.winch_tension, held))
    assert info["unverified"] == 0
    K1, N = T.shape
    ends = np.concatenate([np.broadcast_to(plan.base, (K1, 1, 3)), plan.robots], axis=1)
    kk, jj = np.meshgrid(np.arange(K1), np.arange(N), indexing="ij")
    kk, jj = kk.ravel(), jj.ravel()
    assert rule.holds(ends[kk, jj], ends[kk, jj + 1], jj, T.ravel()).all()
    need = info["need"].ravel()
    up = np.flatnonzero((need > np.minimum(teth.winch_tension, held).ravel() + 1e-12) & (need < held.ravel()))
    assert up.size > 0  # some knot needs more than the nominal tension (the tethers over the wall)
    below = need[up] - horizon3d_winch.TENSION_TOL
    assert not rule.holds(ends[kk[up], jj[up]], ends[kk[up], jj[up] + 1], jj[up], below).any()
    assert T.mean() < held.mean() - 0.1


def test_least_schedule_passes_the_checker_and_pulls_less(i_qp):
    """The plan at the least schedule (the same positions, tethers solved at the new tensions) passes the
    independent checker with f1–f4 unchanged, and its drones need no more thrust at any knot than at the held one
    where the tension fell (here: in total and at the peak)."""
    problem, plan, metrics, rule = i_qp
    teth = plan.tether
    T, _ = least_drone_tensions(rule, plan.base, plan.robots, plan.winch_tension, teth.winch_tension,
                                teth.winch_tension_rate, plan.Ts)  # fmt: skip
    cand = _plan_of(plan.robots, plan, {}, {}, tensions=T)
    assert np.array_equal(cand.winch_tension, T)
    met = check_drone_plan(cand, problem.scenario, params=problem.params)
    assert met.success, met.failures
    assert [float(v) for v in met.fitness_raw] == [float(v) for v in metrics.fitness_raw]
    need_held, pull_held = thrust_need(plan.base, plan.robots, teth, plan.winch_tension)
    need_new, pull_new = thrust_need(plan.base, plan.robots, teth, T)
    assert need_new.max() <= need_held.max() and need_new.mean() < need_held.mean()
    assert pull_new.max() <= pull_held.max() + 1e-9 and pull_new.mean() < pull_held.mean()
    assert met.max_drone_tension <= metrics.max_drone_tension + 1e-9


def test_the_held_schedule_is_kept_when_the_checker_rejects_the_least_one(i_qp, monkeypatch):
    """A schedule the checker rejects (forced here: tether 1's winch jumps by 0.5 N in one step, 10 N/s against
    2 N/s) or one with no catenary (every winch at T_min: the tethers over the wall cannot span) is not returned: the
    plan keeps the held qp schedule and the note says why."""
    problem, plan, metrics, _ = i_qp
    teth = plan.tether
    jump = plan.winch_tension.copy()
    jump[100, 0] += 0.5
    low = np.full_like(plan.winch_tension, teth.winch_tension_min)
    horizon = dataclasses.replace(plan, method="horizon")
    for forced, why in ((jump, "fails the check (winch of tether 1 changes by"), (low, "has no catenary")):
        fake = (forced, dict(passes=1, raised=0, unverified=0))
        monkeypatch.setattr(horizon3d_winch, "least_drone_tensions", lambda *a, fake=fake, **k: fake)
        out, met, info = _choose_tensions(problem, False, plan, horizon, metrics, {}, True)
        assert out is horizon and met is metrics and info["schedule"] == "held"
        assert why in info["note"] and np.array_equal(out.winch_tension, plan.winch_tension)
    monkeypatch.undo()
    out, met, info = _choose_tensions(problem, False, plan, horizon, metrics, {}, True)
    assert info["schedule"] == "least" and met.success and "least tension schedule" in info["note"]
    assert info["returned"]["mean_thrust_need"] < info["held"]["mean_thrust_need"]
    assert info["returned"]["mean_pull"] < info["held"]["mean_pull"]
