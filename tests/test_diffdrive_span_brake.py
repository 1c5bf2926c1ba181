"""Differential-drive chains near their tethers' reach and behind corners: a span meets its band by braking within
a_max, not by dropping the acceleration comfort limit, and the followers' references do not outrun the robots
(``formulations/diffdrive.md``, "Span band: a braking curve", "Followers' trailing references")."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.control.clik import run
from tmr.control.diffdrive import DiffDriveAcceleration, DiffDriveQP, DiffDriveSpeed, span_brake
from tmr.control.limits import JointBox, braking_rate
from tmr.control.qp import Level, LexicographicQP
from tmr.control.tasks import LeaderTracking
from tmr.model.chain import Chain
from tmr.model.diffdrive import load_robot_model
from tmr.route.path import Trajectory
from tmr.world.environment import Environment


@pytest.mark.parametrize("decel", [0.3, 1.25, 2.5])
def test_braking_rate_is_the_discrete_braking_curve(decel):
    Ts = 0.05
    g = np.linspace(0.0, 0.4, 40001)
    v = braking_rate(g, decel, Ts)
    assert v[0] == 0.0 and np.all(np.diff(v) >= -1e-15)  # 0 at the bound, increasing
    assert np.all(v <= g / Ts + 1e-15)  # never past the bound in one step
    # recursively feasible: after a step at the curve the next step's bound is at most decel Ts lower
    assert np.min(braking_rate(g - Ts * v, decel, Ts) - (v - decel * Ts)) >= -1e-12
    # its definition: braking from v by decel Ts per step covers exactly the gap
    for gap in (0.0004, 0.01, 0.05, 0.3):
        u = float(braking_rate(np.array([gap]), decel, Ts)[0])
        speeds = u - decel * Ts * np.arange(200)
        assert Ts * np.sum(speeds[speeds > 0]) == pytest.approx(gap, rel=1e-9)
    assert braking_rate(np.array([-0.1]), decel, Ts)[0] == 0.0  # a span past its bound must not get worse


def _run(brake: bool):
    """One Burger heading +x from 1 m off the anchor, its leader reference driving straight out past the reach
    d_max = 2 m at the diff leader speed (0.6 v_max = 0.132 m/s > a_max Ts = 0.125 m/s)."""
    model = load_robot_model("turtlebot3_burger")
    Ts, speed = 0.05, 0.6 * model.v_max
    chain = Chain(1, base=np.zeros(2))
    limits = np.array([[0.5, 2.0]])
    t = np.arange(0.0, 12.0 + Ts / 2, Ts)
    x = np.column_stack([1.0 + speed * t, np.zeros_like(t)])
    xd = np.tile([speed, 0.0], (t.size, 1))
    traj = Trajectory(t, x, xd, np.zeros_like(x), x[[0, -1]])
    box = JointBox(chain, limits, 3.0, 3.0, 20.0, 0.01, None, span_brake(model) if brake else None)
    qp = LexicographicQP(
        chain,
        [Level([(LeaderTracking(5.0), 1.0)], "leader")],
        [DiffDriveSpeed(model), DiffDriveAcceleration(model)],
        box,
    )
    form = DiffDriveQP(qp, chain, model, np.zeros(1))
    env = Environment.from_geometry(None, (-5.0, -5.0, 5.0, 5.0), safety_radius=0.2)
    q0 = chain.q_from_positions(np.array([[1.0, 0.0]]))
    plan = run(chain, env, traj, form, q0, span_limits=limits, safety_radius=0.2, samples_per_link=5)
    axle, heading, v, w = form.poses(plan.t.size)
    return plan, model, v, np.asarray(plan.diagnostics["relaxed"])


def test_span_reaches_its_reach_within_the_acceleration_bound():
    plan, model, v, relaxed = _run(brake=True)
    Ts = plan.Ts
    assert np.nansum(relaxed) == 0  # the comfort limit held at every step
    dv = np.abs(np.diff(v[:-1, 0]))  # the last state is at rest by convention (after the last step)
    assert np.max(dv) <= model.a_max * Ts * (1 + 1e-9)
    assert np.max(plan.spans[:, 0]) <= 2.0 - 0.01 + 1e-6  # the hard band holds
    assert plan.spans[-1, 0] > 2.0 - 0.01 - 1e-3  # and the robot stopped at it, not short of it
    # without the braking curve the robot ran into the band at the leader's speed and had to stop in one step
    _, _, v_old, relaxed_old = _run(brake=False)
    assert np.nansum(relaxed_old) >= 1
    assert np.max(np.abs(np.diff(v_old[:-1, 0]))) > model.a_max * Ts


def test_diff_followers_references_rise_no_faster_than_the_robots_drive():
    """A trailing reference rising at a corner at the omnidirectional 1.2 m/s runs away from a Burger (0.198 m/s):
    a diff chain's references rise at most at the speed its wheels' rim rows leave."""
    from tmr.control.diffdrive import WHEEL_RESERVE
    from tmr.planner import build_problem
    from tmr.route.references import CATCH_UP
    from tmr.world.scenario import load_scenario

    def peak(problem):  # the followers' fastest reference speed [m/s]
        return float(np.max(np.linalg.norm(problem.references.velocities[:, :-1], axis=2)))

    omni = build_problem(load_scenario("A"))
    diff = build_problem(load_scenario("A"), overrides={"drive": "diff"})
    assert peak(omni) == pytest.approx(CATCH_UP)  # the corner's catch-up binds in A
    assert peak(diff) <= (1 - WHEEL_RESERVE) * diff.robot_model.v_max * (1 + 1e-9)
