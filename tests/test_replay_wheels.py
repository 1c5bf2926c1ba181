"""Differential-drive robots on wheels in the MuJoCo chain replay (``tmr.replay.wheels``): a diff-drive plan of
scenario A (TurtleBot3 Burger) is confirmed on two wheels and casters within the wheel-speed limit; omni plans
replayed on wheels (``--drive diff``) are confirmed when they move along the heading and caught when they move
sideways."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco")

from tests.test_replay_chain import min_jerk, write_run  # noqa: E402
from tmr import cli  # noqa: E402
from tmr.replay.wheels import WHEEL_SPEED_SLACK  # noqa: E402


@pytest.fixture(scope="module")
def diff_a(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheels") / "Adiff"
    args = ["plan", "--scenario", "A", "--drive", "diff", "--robot-model", "turtlebot3_burger"]
    assert cli.main([*args, "--out", str(out), "--no-plots", "-q"]) == 0
    return out


def test_diff_plan_of_a_is_confirmed_on_wheels(diff_a: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["replay", str(diff_a), "--no-plots"]) == 0
    cap = capsys.readouterr()
    text = cap.out + cap.err
    assert "diff plan on turtlebot3_burger wheels" in text and "replay OK" in text
    doc = json.loads((diff_a / "replay" / "replay.json").read_text())
    assert doc["verdict"]["ok"] is True
    w = doc["wheels"]
    assert w["config"]["wheel_radius"] == 0.033 and w["config"]["track"] == 0.16
    limit = 0.22 / 0.033  # a wheel's rim is as fast as the robot driving straight
    assert w["config"]["wheel_limit"] == pytest.approx(limit)
    for r in w["robots"]:
        assert r["axle_error_max"] < 0.05  # the replay's tolerance (the plan's clearance margin)
        assert r["heading_error_max"] < w["config"]["heading_tolerance"]
        assert r["wheel_speed_peak"] <= limit * (1 + WHEEL_SPEED_SLACK)  # the wheel-speed limit holds
        assert r["lateral_demand_max"] == 0.0  # a diff-drive plan never asks for sideways motion
        assert r["lateral_slip_peak"] < 0.01  # the wheels grip: < 1 cm/s sideways
    assert all(t["lowest_min"] > 0.2 for t in doc["tethers"])
    assert all(c["count"] == 0 for c in doc["contacts"].values())
    assert cli.main(["replay", str(diff_a), "--drive", "omni", "--out", str(diff_a / "r2")]) == 2
    assert "differential-drive" in capsys.readouterr().err


def _one_robot(tmp_path: Path, name: str, end: tuple[float, float], T: float = 4.0) -> Path:
    start = np.array([4.0, 5.0])
    return write_run(tmp_path / name, [], (2.0, 5.0), min_jerk(start, np.array(end), T))


def test_omni_sideways_move_is_caught_on_wheels(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _one_robot(tmp_path, "side", (4.0, 6.0))  # 1 m along +y, the omni robot's heading is 0 (+x)
    assert cli.main(["replay", str(run), "--no-plots"]) == 0  # the omnidirectional body: fine
    capsys.readouterr()
    out = tmp_path / "side_wheels"
    args = ["replay", str(run), "--drive", "diff", "--robot-model", "clearpath_jackal", "--out", str(out)]
    assert cli.main([*args, "--no-plots"]) == 1
    cap = capsys.readouterr()
    err = cap.out + cap.err
    assert "replay FAILED: robot 1 is asked to move sideways" in err and "t = " in err
    doc = json.loads((out / "replay.json").read_text())
    checks = {f["check"] for f in doc["verdict"]["failures"]}
    assert {"sideways", "axle-tracking"} <= checks  # demanded, and the physics cannot follow
    r = doc["wheels"]["robots"][0]
    assert r["lateral_demand_max"] > 0.3 and r["axle_error_max"] > 0.05
    assert r["lateral_slip_peak"] < 0.05  # the wheels did not slide sideways to follow


def test_omni_move_along_the_heading_is_confirmed_on_wheels(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 1 m along +x in 10 s (peak 0.19 m/s, a burger does 0.22 m/s): what a unicycle at heading 0 can do
    run = _one_robot(tmp_path, "ahead", (5.0, 5.0), T=10.0)
    out = tmp_path / "ahead_wheels"
    assert cli.main(["replay", str(run), "--drive", "diff", "--out", str(out), "--no-plots"]) == 0
    r = json.loads((out / "replay.json").read_text())["wheels"]["robots"][0]
    assert r["lateral_demand_max"] < 1e-9 and r["axle_error_max"] < 0.05


def test_wheel_speed_limit_holds_when_the_plan_is_too_fast(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _one_robot(tmp_path, "fast", (6.0, 5.0), T=2.0)  # 2 m in 2 s: peak 1.9 m/s, a burger does 0.22 m/s
    out = tmp_path / "fast_wheels"
    assert cli.main(["replay", str(run), "--drive", "diff", "--out", str(out), "--no-plots"]) == 1
    doc = json.loads((out / "replay.json").read_text())
    r = doc["wheels"]["robots"][0]
    limit = doc["wheels"]["config"]["wheel_limit"]
    assert r["wheel_command_peak"] > 3 * limit and r["saturated_time"] > 0.5  # the law asks for more ...
    assert r["wheel_speed_peak"] <= limit * (1 + WHEEL_SPEED_SLACK)  # ... the wheels never turn faster than w_max
    assert doc["verdict"]["failures"][0]["check"] in ("tracking", "axle-tracking")  # it falls behind


def test_bad_wheel_options_exit_2(diff_a: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _one_robot(tmp_path, "opts", (5.0, 5.0))
    for args in (
        [str(run), "--robot-model", "turtlebot3_burger"],  # without --drive diff
        [str(run), "--drive", "diff", "--robot-model", "turtlebot9"],
        [str(diff_a), "--robot-model", "clearpath_jackal"],  # a diff plan replays on its own model
    ):
        out = tmp_path / "refused"
        assert cli.main(["replay", *args, "--out", str(out)]) == 2, args
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err, err
        assert not out.exists()
