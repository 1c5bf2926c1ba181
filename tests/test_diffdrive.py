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
    (tmp_path / "m.toml").write_text('robot_model = "jackal"\n' + body)  # a model implies drive = "diff"
    implied = build_problem(load_scenario(tmp_path / "m.toml"))
    assert implied.chain_params.drive == "diff" and implied.robot_model.name == "clearpath_jackal"
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


def test_model_name_and_exit_offset_are_checked(tmp_path):
    """A model's name must be text, and b ≥ MIN_EXIT_OFFSET: a b of 1e-12 m passed '> 0' and then failed the plan with
    rows violated by 4e9 and advice about the speed bounds."""
    from tmr.model.diffdrive import MIN_EXIT_OFFSET

    own = tmp_path / "m.toml"
    body = "radius = 0.1\nv_max = 0.5\nomega_max = 2.0\na_max = 1.0\nalpha_max = 3.0\n"
    own.write_text(body + "exit_offset = 1e-12\n")
    with pytest.raises(ParameterError, match="exit_offset = 1e-12 m is below"):
        load_robot_model(str(own))
    own.write_text(body + f"exit_offset = {MIN_EXIT_OFFSET}\n")
    assert load_robot_model(str(own)).exit_offset == MIN_EXIT_OFFSET
    own.write_text(body + "exit_offset = 0.1\nname = 5\n")
    with pytest.raises(ParameterError, match="name must be non-empty text"):
        load_robot_model(str(own))


def test_cli_robot_model_flags_set_and_records(tmp_path, capsys):
    """``--set drive=diff --set robot_model=burger`` (either order) plans like ``--robot-model burger``; the records
    keep the preset's full name, the default model's too; an empty or unknown --robot-model, --set robot_model
    without drive = diff and --filter-cutoff with diff drive exit 2 with one line naming the flag."""
    from tmr import cli

    runs = {
        "flag": ["--robot-model", "burger"],
        "set": ["--set", "robot_model=burger", "--set", "drive=diff"],
        "default": ["--drive", "diff"],
    }
    for name, args in runs.items():
        out = tmp_path / name
        assert cli.main(["plan", "--scenario", "A", *args, "--out", str(out), "--no-plots", "-q"]) == 0, name
        assert json.loads((out / "run.json").read_text())["params"]["robot_model"] == "turtlebot3_burger"
    assert (tmp_path / "flag" / "trajectories.json").read_bytes() == (
        tmp_path / "set" / "trajectories.json"
    ).read_bytes()
    for args, where in (
        (["--robot-model", ""], "tmr plan: error: --robot-model: must name"),
        (["--robot-model", "burgr"], "tmr plan: error: --robot-model: unknown robot model 'burgr'"),
        (["--set", "robot_model=burgr", "--set", "drive=diff"], "unknown robot model 'burgr'"),
        (["--set", "robot_model=burger"], "is a differential-drive robot but drive = 'omni'"),
        (["--drive", "diff", "--filter-cutoff", "1"], "--filter-cutoff: a differential-drive plan is not filtered"),
    ):
        out = tmp_path / "refused"
        assert cli.main(["plan", "--scenario", "A", *args, "--out", str(out), "--no-plots"]) == 2, args
        err = capsys.readouterr().err.strip()
        assert where in err and err.count("\n") == 0, (args, err)
        assert not out.exists()


def test_a_motion_longer_than_max_steps_is_refused_up_front(tmp_path, capsys):
    """A robot model with v_max = 1e-6 m/s asks for 1.6e8 steps: refused with exit 2 before any array of that length
    is allocated (it took 24 GB and the kernel's OOM killer), as is a T_end / Ts above MAX_STEPS."""
    from tmr import cli
    from tmr.model.params import MAX_STEPS, TimeParams

    slow = tmp_path / "slow.toml"
    slow.write_text(
        "radius = 0.105\nv_max = 1e-6\nomega_max = 2.84\na_max = 2.5\nalpha_max = 3.2\nexit_offset = 0.08\n"
    )
    out = tmp_path / "o"
    assert cli.main(["plan", "--scenario", "A", "--robot-model", str(slow), "--out", str(out), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"above the planner's limit of {MAX_STEPS:,} steps" in err and err.count("\n") == 0
    assert not out.exists()
    with pytest.raises(ParameterError, match="MAX_STEPS"):
        TimeParams(T_end=MAX_STEPS * 0.05 + 1.0, Ts=0.05)
    assert TimeParams(T_end=MAX_STEPS * 0.05, Ts=0.05).steps == MAX_STEPS


def test_rrt_route_is_retimed_to_the_robot(tmp_path, capsys):
    """``--route rrt`` keeps the paper's 15 s for omni robots; with differential drive the same RRT* path is retimed
    so the leader's reference stays within leader_speed (0.6 v_max) and the plan passes; a T_end the user sets that
    asks for more than v_max is refused up front."""
    from tmr import cli
    from tmr.planner import DIFF_SPEED_FRACTION

    out = tmp_path / "rrt"
    assert (
        cli.main(
            ["plan", "--scenario", "A", "--drive", "diff", "--route", "rrt", "--out", str(out), "--no-plots", "-q"]
        )
        == 0
    )
    doc = json.loads((out / "run.json").read_text())
    T_end = doc["params"]["T_end"]
    assert T_end > 15.0
    traj = json.loads((out / "trajectories.json").read_text())
    assert traj["robots"][-1]["t"][-1] == pytest.approx(T_end)
    lead = np.column_stack([traj["robots"][-1]["exit_x"], traj["robots"][-1]["exit_y"]])
    speed = np.linalg.norm(np.diff(lead, axis=0), axis=1) / 0.05
    assert speed.max() <= 0.22 * (1 + 1e-9) and np.median(speed[speed > 1e-3]) <= DIFF_SPEED_FRACTION * 0.22 * 1.05
    refused = tmp_path / "fast"
    args = ["plan", "--scenario", "A", "--drive", "diff", "--route", "rrt", "--set", "T_end=15", "--out", str(refused)]
    assert cli.main([*args, "--no-plots"]) == 2
    err = capsys.readouterr().err.strip()
    assert "above the robot's v_max 0.22 m/s" in err and err.count("\n") == 0 and not refused.exists()


def test_drive_figure_of_a_diff_plan(tmp_path):
    """A diff plan with figures writes drive.png; plot_drive draws v, both wheel rims and ω per robot with the limits
    (±v_max, the planned rim bound, ±ω_max), and trajectories.png of a diff plan has no 'filtered' curve."""
    from tmr import cli
    from tmr.control.diffdrive import WHEEL_RESERVE
    from tmr.views.plot import plot_drive, plot_trajectories

    out = tmp_path / "figs"
    assert cli.main(["plan", "--scenario", "A", "--drive", "diff", "--out", str(out), "-q"]) == 0
    assert (out / "drive.png").stat().st_size > 10_000
    doc = json.loads((out / "trajectories.json").read_text())
    params = json.loads((out / "run.json").read_text())["params"]
    robots = doc["robots"]
    plan = SimpleNamespace(
        t=np.array(robots[0]["t"]),
        drive_v=np.column_stack([r["v"] for r in robots]),
        drive_omega=np.column_stack([r["omega"] for r in robots]),
        robots=np.stack([np.column_stack([r["exit_x"], r["exit_y"]]) for r in robots], axis=1),
        heading=np.column_stack([r["theta"] for r in robots]),
        params=params, scenario="A", method="qp", success=True, failure=None,
    )  # fmt: skip
    fig = plot_drive(plan)
    assert len(fig.axes) == 2 * len(robots)
    m = params["robot_model_params"]
    av, aw = fig.axes[0], fig.axes[1]
    levels = {round(float(ln.get_ydata()[0]), 9) for ln in av.lines if len(set(ln.get_ydata())) == 1}
    assert {m["v_max"], -m["v_max"], round((1 - WHEEL_RESERVE) * m["v_max"], 9)} <= levels
    assert np.allclose(av.lines[0].get_ydata(), plan.drive_v[:, 0]) and np.allclose(
        aw.lines[0].get_ydata(), plan.drive_omega[:, 0]
    )
    legend = [t.get_text() for t in av.get_legend().get_texts()]
    assert "right wheel rim" in legend and "left wheel rim" in legend
    traj_fig = plot_trajectories(plan)
    labels = {t.get_text() for ax in traj_fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()}
    assert labels == {"tether exit point (planned)"}


def test_set_judges_t_end_and_ts_together_and_catch_up():
    """``--set T_end=12000 --set Ts=0.1`` is 120,000 steps (within MAX_STEPS): each is parsed on its own, and the pair
    is judged where both are known; ``catch_up`` is a parameter (off = the robots' default) and is left out of the
    records while it is the default."""
    import argparse

    from tmr.io.cli_args import param
    from tmr.model.params import PathParams

    assert param("T_end=12000") == ("T_end", 12000.0) and param("Ts=0.1") == ("Ts", 0.1)
    with pytest.raises(argparse.ArgumentTypeError, match="T_end"):
        param("T_end=-1")
    assert param("catch_up=0.5") == ("catch_up", 0.5) and param("catch_up=off") == ("catch_up", None)
    with pytest.raises(argparse.ArgumentTypeError, match="catch_up"):
        param("catch_up=0")
    assert "catch_up" not in PathParams().record() and PathParams(catch_up=0.5).record()["catch_up"] == 0.5


def test_catch_up_reaches_the_references():
    """A follower's reference rises at a corner at most at ``catch_up`` (and follows the leader's progress
    otherwise): the default is 1.2 m/s for omni robots and the wheels' 0.198 m/s for Burgers
    (tmr.planner.diff_catch_up); a set value is used for either."""
    from tmr.planner import build_problem
    from tmr.world.scenario import load_scenario

    def peak(params):
        problem = build_problem(load_scenario("A"), overrides=params)
        ref = problem.references
        return float(np.linalg.norm(np.asarray(ref.velocities)[:, :-1], axis=-1).max())

    assert peak({}) == pytest.approx(1.2)  # A's corner: the catch-up binds
    assert peak({"catch_up": 0.3, "leader_speed": 0.2}) == pytest.approx(0.3)  # (the leader's 0.8 m/s binds else)
    assert peak({"drive": "diff"}) == pytest.approx(0.198)
    assert peak({"drive": "diff", "catch_up": 1.2}) == pytest.approx(1.2)  # a set value wins


def test_a_train_longer_than_max_steps_is_a_train_verdict(monkeypatch):
    """A train-reference plan longer than MAX_STEPS is a search verdict (TrainError, exit 1 after the trailing plan's
    failure), not a ParameterError blaming a T_end the user did not set."""
    import tmr.planner as planner
    from tmr.route.train import TrainError
    from tmr.world.scenario import load_scenario

    problem = planner.build_problem(load_scenario("A"))
    monkeypatch.setattr(planner, "MAX_STEPS", 10)
    with pytest.raises(TrainError, match="above the planner's limit of 10 steps"):
        planner.train_problem(problem)


def test_a_diff_plan_with_a_long_step_is_not_held_to_the_filter(tmp_path):
    """A diff plan is not filtered, so Ts = 0.5 s (filter Nyquist 1 Hz, the default cut-off's own) is not refused."""
    from tmr import cli

    out = tmp_path / "ts"
    assert cli.main(
        ["plan", "--scenario", "A", "--drive", "diff", "--set", "Ts=0.5", "--out", str(out), "--no-plots", "-q"]
    ) in (0, 1)
    assert (out / "trajectories.json").is_file()


def test_a_bad_value_in_a_scenario_file_names_the_file(tmp_path, capsys):
    """``drive = 1`` in a scenario file: exit 2, one line naming the file (it named only ChainParams.drive)."""
    from tmr import cli
    from tmr.world.scenario import all_builtins

    a = all_builtins()["A"]
    body = a.read_text().replace('file = "A.geojson"', f'file = "{a.parent / "A.geojson"}"')
    (tmp_path / "s.toml").write_text("drive = 1\n" + body)
    out = tmp_path / "o"
    assert cli.main(["plan", "--scenario", str(tmp_path / "s.toml"), "--out", str(out), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err == f"error: scenario file {tmp_path / 's.toml'}: ChainParams.drive takes text, got 1" and not out.exists()
    )


def test_goal_forms_are_named_in_refusals(tmp_path, capsys):
    """``--goal 1,2,3,4`` and a scenario's ``goal = [x, y, theta, z]`` name both accepted forms; a heading written as
    text (``"90"``) is refused (numpy would have converted it)."""
    from tmr import cli
    from tmr.world.scenario import all_builtins

    out = tmp_path / "o"
    assert cli.main(["plan", "--scenario", "A", "--drive", "diff", "--goal", "1,2,3,4", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "expected X,Y or X,Y,THETA" in err and err.count("\n") == 0
    a = all_builtins()["A"]
    body = a.read_text().replace('file = "A.geojson"', f'file = "{a.parent / "A.geojson"}"')
    for goal, why in (('[6.7, 5.0, "90"]', "must be numbers"), ("[6.7, 5.0, 90, 1]", "or [x, y, theta]")):
        lines = [f"goal = {goal}" if ln.startswith("goal =") else ln for ln in body.splitlines()]
        (tmp_path / "s.toml").write_text('drive = "diff"\n' + "\n".join(lines) + "\n")
        assert cli.main(["plan", "--scenario", str(tmp_path / "s.toml"), "--out", str(out), "--no-plots"]) == 2
        err = capsys.readouterr().err.strip()
        assert why in err and err.count("\n") == 0, err
    assert not out.exists()
