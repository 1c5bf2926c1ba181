"""A goal heading for a differential-drive leader (issue 35): ``--goal X,Y,THETA`` (degrees) and ``goal = [x, y,
theta]``; the leader's final manoeuvre (turn, drive, turn) and the check of its final heading."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tmr.checks.diffdrive import HEADING_TOLERANCE_DEG, heading_error
from tmr.control.diffdrive import GoalHeading, rest_to_rest
from tmr.io.cli_args import goal_pose

A_GOAL = "6.7,5.0"  # scenario A's goal [m]


def test_goal_pose_parses_degrees_and_radians():
    import argparse

    assert goal_pose("1,2") == (1.0, 2.0)
    assert goal_pose("1, 2, 90") == pytest.approx((1.0, 2.0, math.pi / 2), abs=1e-15)
    assert goal_pose("1,2,-45deg") == pytest.approx((1.0, 2.0, -math.pi / 4), abs=1e-15)
    assert goal_pose("1,2,1.5rad") == (1.0, 2.0, 1.5)
    for bad in ("1,2,abc", "1,2,nan", "1,2,3,4", "1"):
        with pytest.raises(argparse.ArgumentTypeError):
            goal_pose(bad)


def test_rest_to_rest_profile():
    for dist, v, a in ((math.pi, 2.0, 1.6), (0.16, 0.176, 1.25), (5.0, 0.5, 1.0)):
        T, f = rest_to_rest(dist, v, a)
        assert f(0.0) == (0.0, 0.0) and f(T) == pytest.approx((dist, 0.0), abs=1e-12)
        ts = np.linspace(0.0, T, 2001)
        s, sd = np.array([f(t) for t in ts]).T
        assert np.max(sd) <= v * (1 + 1e-12) and np.all(np.diff(s) >= -1e-15)
        assert np.max(np.abs(np.diff(sd))) / (ts[1] - ts[0]) <= a * (1 + 1e-6)
        assert np.allclose(np.gradient(s, ts), sd, atol=2 * a * (ts[1] - ts[0]))
    assert rest_to_rest(0.0, 1.0, 1.0)[0] == 0.0


@pytest.mark.parametrize("theta0, goal_deg", [(0.3, 90.0), (-2.5, 90.0), (math.pi / 2, 90.0), (1.0, -170.0)])
def test_manoeuvre_is_a_unicycle_path_ending_at_the_goal_pose(theta0, goal_deg):
    b, G = 0.08, np.array([6.7, 5.0])
    axle = G - b * np.array([math.cos(theta0), math.sin(theta0)])
    gh = GoalHeading(math.radians(goal_deg), G, 0, b, 0.176, 1.25, 2.27, 1.6)
    gh.start(axle, theta0)
    c_f, theta_f = gh.end_pose
    assert heading_error(theta_f, math.radians(goal_deg)) <= 1e-12
    assert np.allclose(c_f + b * np.array([math.cos(theta_f), math.sin(theta_f)]), G, atol=1e-12)
    T = gh.budget()
    p0, v0 = gh.at(0.0)
    assert np.allclose(p0, G, atol=1e-12) and np.allclose(v0, 0.0)  # starts where the leader stands, at rest
    pT, vT = gh.at(T + 1.0)
    assert np.allclose(pT, G, atol=1e-12) and np.allclose(vT, 0.0)
    ts = np.linspace(0.0, T, 4001)
    P = np.array([gh.at(t)[0] for t in ts])
    V = np.array([gh.at(t)[1] for t in ts])
    assert np.allclose(np.gradient(P, ts, axis=0), V, atol=5e-3)  # the velocity is the position's derivative
    assert np.max(np.linalg.norm(P - G, axis=1)) <= 2 * b + 1e-12  # the exit point stays within 2b of the goal


def test_goal_heading_in_a_scenario_file(tmp_path):
    from tmr.world.scenario import load_scenario

    src = (load_scenario("A").source).read_text()
    (tmp_path / "A.geojson").write_text((load_scenario("A").source.parent / "A.geojson").read_text())
    (tmp_path / "h.toml").write_text(src.replace("goal = [6.7, 5.0]", "goal = [6.7, 5.0, 90]"))
    sc = load_scenario(tmp_path / "h.toml")
    assert sc.goal.tolist() == [6.7, 5.0] and sc.goal_heading == pytest.approx(math.pi / 2, abs=1e-15)
    assert load_scenario("A").goal_heading is None


def test_plan_A_ends_at_the_goal_heading(tmp_path):
    from tmr import cli

    out = tmp_path / "A90"
    args = ["plan", "--scenario", "A", "--drive", "diff", "--goal", f"{A_GOAL},90", "--out", str(out), "--no-plots"]
    assert cli.main([*args, "-q"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    dd = metrics["diff_drive"]
    assert metrics["success"] and dd["goal_heading"] == pytest.approx(math.pi / 2, abs=1e-15)
    assert math.degrees(dd["final_heading_error"]) <= HEADING_TOLERANCE_DEG
    assert metrics["final_leader_error"] <= 1e-6  # the exit point still ends at the goal
    leader = json.loads((out / "trajectories.json").read_text())["robots"][-1]
    assert heading_error(leader["theta"][-1], math.pi / 2) == pytest.approx(dd["final_heading_error"], abs=1e-15)
    assert math.degrees(heading_error(leader["theta"][0], math.pi / 2)) > 45  # it had to turn
    run = json.loads((out / "run.json").read_text())
    assert run["params"]["goal_heading"] == pytest.approx(math.pi / 2, abs=1e-15)


def test_refusals_exit_2_one_line_nothing_written(tmp_path, capsys):
    from tmr import cli

    for args, needle in (
        (["--goal", f"{A_GOAL},90"], "needs --drive diff"),
        (["--goal", f"{A_GOAL},90", "--drive", "omni"], "needs --drive diff"),
        (["--goal", f"{A_GOAL},ninety", "--drive", "diff"], "X,Y,THETA"),
        (["--goal", f"{A_GOAL},inf", "--drive", "diff"], "X,Y,THETA"),
    ):
        out = tmp_path / "refused"
        assert cli.main(["plan", "--scenario", "A", *args, "--out", str(out), "--no-plots"]) == 2, args
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and needle in err and "Traceback" not in err, err
        assert not out.exists()


def test_scenario_file_goal_heading_refused_for_omni(tmp_path, capsys):
    from tmr import cli
    from tmr.world.scenario import load_scenario

    a = load_scenario("A").source
    (tmp_path / "A.geojson").write_text((a.parent / "A.geojson").read_text())
    (tmp_path / "h.toml").write_text(a.read_text().replace("goal = [6.7, 5.0]", "goal = [6.7, 5.0, 90]"))
    out = tmp_path / "refused"
    assert cli.main(["plan", "--scenario", str(tmp_path / "h.toml"), "--out", str(out), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "needs --drive diff" in err and not out.exists()
    # --goal X,Y replaces the whole goal pose: the file's heading goes with it
    out = tmp_path / "omni"
    assert (
        cli.main(
            ["plan", "--scenario", str(tmp_path / "h.toml"), "--goal", A_GOAL, "--out", str(out), "-q", "--no-plots"]
        )
        == 0
    )
