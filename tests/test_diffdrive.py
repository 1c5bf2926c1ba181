"""Differential-drive robots (issue 35): the exit point's kinematics against finite differences, the robot models,
the checker on hand-made pose sequences, and a diff-drive plan of scenario A checked from its recorded poses."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from tmr.checks.diffdrive import diff_drive_check
from tmr.errors import ParameterError
from tmr.model.diffdrive import (
    exit_jacobian,
    exit_point,
    exit_velocity,
    load_robot_model,
    model_for,
    preset_names,
    step_velocities,
    unicycle_step,
)
from tmr.model.params import ChainParams

BURGER = dict(radius=0.105, v_max=0.22, omega_max=2.84, a_max=2.5, alpha_max=3.2, exit_offset=0.08)


@pytest.mark.parametrize("b", [0.08, -0.05, 0.3])
def test_exit_velocity_matches_finite_differences(b):
    rng = np.random.default_rng(3)
    for _ in range(20):
        c, th = rng.normal(size=2), rng.uniform(-np.pi, np.pi)
        v, w = rng.uniform(-1, 1), rng.uniform(-3, 3)
        h = 1e-6
        (c1, th1), (c0, th0) = unicycle_step(c, th, v, w, h), unicycle_step(c, th, -v, -w, h)  # ±h along the arc
        fd = (exit_point(c1, th1, b) - exit_point(c0, th0, b)) / (2 * h)
        assert np.allclose(fd, exit_velocity(th, v, w, b), atol=1e-8)
        # the Jacobian of ṗ in (v, ω), and its determinant b: the exit point is fully actuated for b ≠ 0
        J = exit_jacobian(th, b)
        assert np.allclose(J @ [v, w], exit_velocity(th, v, w, b), atol=1e-14)
        assert np.isclose(np.linalg.det(J), b)


def test_unicycle_step_is_the_arc_and_step_velocities_invert_it():
    rng = np.random.default_rng(5)
    c, th = np.zeros(2), 0.3
    poses = [(c, th)]
    cmds = rng.uniform([-0.2, -2.0], [0.2, 2.0], size=(50, 2))
    for v, w in cmds:
        # the arc against a fine Euler integration of ẋ = v cos θ, ẏ = v sin θ, θ̇ = ω over the same 0.05 s
        ce, te = poses[-1][0].copy(), poses[-1][1]
        for _ in range(2000):
            ce, te = ce + 2.5e-5 * v * np.array([np.cos(te), np.sin(te)]), te + 2.5e-5 * w
        c1, th1 = unicycle_step(poses[-1][0], poses[-1][1], v, w, 0.05)
        assert np.allclose(c1, ce, atol=1e-6) and np.isclose(th1, te)
        poses.append((c1, th1))
    C = np.array([p[0] for p in poses])
    T = np.array([p[1] for p in poses])
    v, w, lat = step_velocities(C, T, 0.05)
    assert np.allclose(v, cmds[:, 0], atol=1e-12) and np.allclose(w, cmds[:, 1], atol=1e-12)
    assert np.max(np.abs(lat)) < 1e-12


def _plan(axle, heading, b=BURGER["exit_offset"], Ts=0.05):
    axle, heading = np.asarray(axle, float), np.asarray(heading, float)
    return SimpleNamespace(
        axle=axle, heading=heading, robots=exit_point(axle, heading, b), params={"robot_model_params": BURGER}, Ts=Ts
    )


def _straight(n=10, v=0.1, Ts=0.05):
    """One robot driving straight along x at v, from rest (accelerating within a_max)."""
    speeds = np.minimum(v, 2.0 * Ts * np.arange(1, n + 1))
    x = np.concatenate([[0.0], np.cumsum(speeds * Ts)])
    return np.column_stack([x, np.zeros(n + 1)])[:, None, :], np.zeros((n + 1, 1))


def test_check_passes_a_unicycle_and_flags_a_sideways_step():
    axle, heading = _straight()
    masks, summary = diff_drive_check(_plan(axle, heading), 0.05)
    assert not any(m.any() for m in masks.values())
    assert summary["max_lateral_velocity"] < 1e-12
    slid = axle.copy()
    slid[6:, 0, 1] += 1e-6  # 1 µm sideways between samples 5 and 6: 2e-5 m/s of lateral velocity
    masks, summary = diff_drive_check(_plan(slid, heading), 0.05)
    assert np.flatnonzero(masks["lateral_velocity"]).tolist() == [5]
    assert summary["max_lateral_velocity"] == pytest.approx(2e-5, rel=1e-6)


def test_check_flags_speed_acceleration_and_exit_point():
    axle, heading = _straight(v=0.3)  # above the burger's 0.22 m/s
    masks, _ = diff_drive_check(_plan(axle, heading), 0.05)
    assert masks["linear_speed"].any() and not masks["lateral_velocity"].any()
    axle, heading = _straight(v=0.2)
    axle[1:, 0, 0] += 0.01  # a jump of 0.2 m/s in the first step: 4 m/s² > a_max = 2.5 m/s²
    masks, _ = diff_drive_check(_plan(axle, heading), 0.05)
    assert masks["linear_acceleration"][0]
    spin = _plan(np.zeros((4, 1, 2)), np.array([[0.0], [0.2], [0.4], [0.6]]))  # 4 rad/s in place > 2.84 rad/s
    masks, summary = diff_drive_check(spin, 0.05)
    assert masks["angular_speed"][:3].all() and summary["turn_in_place_steps"] == [3]
    off = _plan(*_straight())
    off.robots = off.robots + 1e-6  # the tether's point off its pose
    assert diff_drive_check(off, 0.05)[0]["exit_point"].all()
    # a wheel's rim: driving at 0.2 m/s while turning at 1 rad/s puts the outer wheel at 0.2 + 0.08 = 0.28 m/s
    axle, heading = [np.zeros((1, 2))], [np.zeros(1)]
    for _ in range(8):
        c, th = unicycle_step(axle[-1], heading[-1], np.array([0.2]), np.array([1.0]), 0.05)
        axle.append(c)
        heading.append(th)
    arc = _plan(np.array(axle), np.array(heading))
    masks, summary = diff_drive_check(arc, 0.05)
    assert not masks["wheel_speed"].any()  # without a track: no wheel rows
    arc.params = {"robot_model_params": BURGER | {"track": 0.16}}
    masks, summary = diff_drive_check(arc, 0.05)
    assert masks["wheel_speed"][1:8].all() and summary["peak_wheel_rim_speed"] == pytest.approx(0.28)


def test_robot_models(tmp_path):
    assert preset_names() == ["clearpath_jackal", "turtlebot3_burger", "turtlebot3_waffle_pi"]
    burger = load_robot_model("turtlebot3_burger")
    assert (burger.radius, burger.v_max, burger.omega_max) == (0.105, 0.22, 2.84)
    waffle = load_robot_model("turtlebot3_waffle_pi")
    assert (waffle.radius, waffle.v_max, waffle.omega_max) == (0.22, 0.26, 1.82)
    assert load_robot_model("clearpath_jackal").v_max == 2.0
    own = tmp_path / "mine.toml"
    own.write_text("radius = 0.2\nv_max = 0.5\nomega_max = 2.0\na_max = 1.0\nalpha_max = 3.0\nexit_offset = 0.1\n")
    mine = load_robot_model(str(own))
    assert mine.name == "mine" and mine.lateral_max == pytest.approx(0.2)
    with pytest.raises(ParameterError, match="unknown robot model"):
        load_robot_model("turtlebot9")
    own.write_text("radius = 0.2\nv_max = 0.5\n")
    with pytest.raises(ParameterError, match="missing"):
        load_robot_model(str(own))
    own.write_text("radius = 0.2\nv_max = -1\nomega_max = 2.0\na_max = 1.0\nalpha_max = 3.0\nexit_offset = 0.1\n")
    with pytest.raises(ParameterError, match="v_max"):
        load_robot_model(str(own))
    with pytest.raises(ParameterError, match="safety disc"):  # 0.15 + 0.333 > 0.4
        model_for("clearpath_jackal", 0.4)
    # an omnidirectional chain's records keep their fields
    assert "drive" not in ChainParams().record() and "robot_model" not in ChainParams().record()
    assert ChainParams(drive="diff").record()["drive"] == "diff"
    with pytest.raises(ParameterError, match="drive"):
        ChainParams(robot_model="turtlebot3_burger")


def test_scenario_keys_drive_and_robot_model(tmp_path):
    """A scenario's top-level ``drive``/``robot_model`` (or ``[params]``) select the robots; a model file is relative to
    the scenario file, like its map."""
    from tmr.errors import ScenarioError
    from tmr.planner import build_problem
    from tmr.world.scenario import all_builtins, load_scenario

    a = all_builtins()["A"]
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "mybot.toml").write_text(
        'name = "mybot"\nradius = 0.2\nv_max = 0.4\nomega_max = 2.0\na_max = 1.0\nalpha_max = 2.0\nexit_offset = 0.1\n'
    )
    body = a.read_text().replace('file = "A.geojson"', f'file = "{a.parent / "A.geojson"}"')
    (tmp_path / "s.toml").write_text('drive = "diff"\nrobot_model = "models/mybot.toml"\n' + body)
    problem = build_problem(load_scenario(tmp_path / "s.toml"))
    from tmr.planner import DIFF_SPEED_FRACTION

    assert problem.robot_model.name == "mybot"
    assert problem.path_params.leader_speed == pytest.approx(DIFF_SPEED_FRACTION * 0.4)  # the model's v_max, capped
    (tmp_path / "t.toml").write_text('drive = "diff"\n' + body + '\n[params]\ndrive = "omni"\n')
    with pytest.raises(ScenarioError, match="given at the top and in"):
        load_scenario(tmp_path / "t.toml")


def test_diff_plan_of_A_passes_with_no_lateral_velocity():
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    problem = build_problem(load_scenario("A"), overrides={"drive": "diff"})
    plan, metrics = solve(problem, "qp")
    assert plan.success, plan.failure
    v, w, lat = step_velocities(plan.axle, plan.heading, plan.Ts)  # from the recorded poses only
    assert np.max(np.abs(lat)) <= 1e-9
    model = problem.robot_model
    assert np.max(np.abs(v)) <= model.v_max * (1 + 1e-9) and np.max(np.abs(w)) <= model.omega_max * (1 + 1e-9)
    from tmr.control.diffdrive import WHEEL_RESERVE

    rim = np.abs(v) + np.abs(w) * model.track / 2  # each wheel's rim speed: within v_max less the feedback's reserve
    bound = (1 - WHEEL_RESERVE) * model.v_max
    assert np.max(rim) <= bound * (1 + 1e-6) and np.max(rim) > 0.99 * bound
    dv = np.diff(np.vstack([np.zeros((1, 3)), v]), axis=0) / plan.Ts
    assert np.max(np.abs(dv)) <= model.a_max * (1 + 1e-9)
    assert np.allclose(exit_point(plan.axle, plan.heading, model.exit_offset), plan.robots, atol=1e-9)
    assert metrics.diff_drive["max_lateral_velocity"] <= 1e-9
    assert not any(metrics.violation_steps.values())
    assert metrics.final_leader_error < 0.1
    assert plan.params["drive"] == "diff" and plan.params["robot_model_params"]["name"] == "turtlebot3_burger"


def test_diff_drive_with_an_active_winch():
    """The v/ω rows padded with the tension columns: the winch's QP wraps them, the poses stay non-holonomic."""
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    problem = build_problem(load_scenario("A"), overrides={"drive": "diff", "winch": "active"})
    plan, metrics = solve(problem, "qp")
    assert plan.success, plan.failure
    assert plan.winch_tension is not None and plan.winch_tension.shape == (plan.t.size, 3)
    assert np.max(np.abs(step_velocities(plan.axle, plan.heading, plan.Ts)[2])) <= 1e-9
    assert {"winch_range", "lateral_velocity"} <= set(metrics.violation_steps)


def test_cli_refusals_and_outputs(tmp_path, capsys):
    from tmr import cli

    for args in (
        ["--drive", "diff", "--method", "pinv"],
        ["--robot-model", "turtlebot9"],
        ["--drive", "omni", "--robot-model", "turtlebot3_burger"],
        ["--drive", "diff", "--set", "drive=diff"],
        ["--robot-model", "clearpath_jackal", "--robot-radius", "0.4"],
    ):
        out = tmp_path / "refused"
        assert cli.main(["plan", "--scenario", "A", *args, "--out", str(out), "--no-plots"]) == 2, args
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err, err
        assert not out.exists()
    out = tmp_path / "A"
    assert cli.main(["plan", "--scenario", "A", "--drive", "diff", "--out", str(out), "--no-plots", "-q"]) == 0
    doc = json.loads((out / "trajectories.json").read_text())
    assert doc["drive"] == "diff" and "filtered" not in doc
    r = doc["robots"][2]
    assert {"x", "y", "theta", "v", "omega", "exit_x", "exit_y"} <= set(r)
    cmd = (out / "cmd_vel" / "robot3.csv").read_text().splitlines()
    assert cmd[0] == "t,linear_x,angular_z,turn_in_place" and len(cmd) == len(r["t"]) + 1
    header = (out / "trajectories.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["t", "robot1_x", "robot1_y"] and "robot3_omega" in header
    assert cli.main(["replay", str(out), "--drive", "omni"]) == 2  # a diff-drive plan replays on wheels only
    assert "differential-drive" in capsys.readouterr().err
