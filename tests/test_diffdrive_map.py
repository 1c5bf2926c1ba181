"""TurtleBot3 Burgers on the TurtleBot3 world map (issue 35): the bundled map, the preset's short name, the robot
radius of a diff-drive ``--map`` run, and the issue's command ``tmr plan --map turtlebot3_world.yaml --base=-2,0
--goal 1.7,0.55 --robot-model burger --robots auto --export mcap``."""

from __future__ import annotations

import argparse
import hashlib
import json
import os

import numpy as np
import pytest

from tmr.model.diffdrive import DEFAULT_MODEL, canonical_model_name, load_robot_model
from tmr.world.maps import BUNDLED_MAP_DIR, bundled_maps, load_map, resolve_map_path

#: SHA-256 of turtlebot3_navigation2/map/map.pgm at ROBOTIS-GIT/turtlebot3 da785b7 (src/tmr/world/maps/README.md).
TB3_PGM_SHA256 = "57eaad9291fcf02e068cbcd1874990694838a74a3304755bae1bd7b726c4522f"


def test_short_names_of_the_presets():
    assert canonical_model_name(" burger ") == "turtlebot3_burger"
    assert canonical_model_name("jackal") == "clearpath_jackal"
    assert canonical_model_name("turtlebot3_waffle_pi") == "turtlebot3_waffle_pi"
    assert load_robot_model("burger") == load_robot_model("turtlebot3_burger")
    assert load_robot_model("waffle_pi").v_max == 0.26
    assert DEFAULT_MODEL == "turtlebot3_burger"


def test_the_bundled_turtlebot3_world_map(tmp_path, monkeypatch):
    assert "turtlebot3_world.yaml" in bundled_maps()
    pgm = (BUNDLED_MAP_DIR / "turtlebot3_world.pgm").read_bytes()
    assert hashlib.sha256(pgm).hexdigest() == TB3_PGM_SHA256  # the ROBOTIS file, byte for byte
    monkeypatch.chdir(tmp_path)
    assert resolve_map_path("turtlebot3_world.yaml") == BUNDLED_MAP_DIR / "turtlebot3_world.yaml"
    assert str(resolve_map_path("sub/turtlebot3_world.yaml")) == "sub/turtlebot3_world.yaml"  # a path: not bundled
    (tmp_path / "turtlebot3_world.yaml").write_text("x")
    assert resolve_map_path("turtlebot3_world.yaml").resolve() == tmp_path / "turtlebot3_world.yaml"  # a file wins
    os.remove(tmp_path / "turtlebot3_world.yaml")
    geo = load_map("turtlebot3_world.yaml")
    # 384 x 384 cells of 0.05 m from origin (-10, -10): the room is the image; base and goal of the issue are free
    assert geo.bounds == pytest.approx((-10.0, -10.0, 9.2, 9.2))
    from shapely.geometry import Point

    for xy in ((-2.0, 0.0), (1.7, 0.55)):
        assert not geo.obstacles.contains(Point(xy)), xy


def test_diff_map_radius_is_the_footprint_reach():
    from tmr.plan import diff_map_radius

    def ns(sets, map_="m.yaml", radius=None):
        return argparse.Namespace(map=map_, set=sets, robot_radius=radius)

    burger = load_robot_model("burger")
    assert diff_map_radius(ns([("drive", "diff")])) == pytest.approx(burger.exit_offset + burger.radius)
    assert diff_map_radius(ns([("drive", "diff"), ("robot_model", "jackal")])) == pytest.approx(0.483)
    assert diff_map_radius(ns([("drive", "diff")], radius=0.3)) is None  # given: kept
    assert diff_map_radius(ns([("drive", "diff"), ("safety_radius", "0.3")])) is None
    assert diff_map_radius(ns([])) is None  # omni: the scenario's 0.5 m
    assert diff_map_radius(ns([("drive", "diff")], map_=None)) is None  # a scenario keeps its radius


def test_burgers_plan_on_the_turtlebot3_world(tmp_path, monkeypatch):
    """The issue's command: 2 Burgers (N_min), every diff-drive check passed, a ROS 2 bag written."""
    pytest.importorskip("rosbags")
    from tmr import cli

    monkeypatch.chdir(tmp_path)
    out = tmp_path / "tb3"
    argv = ["plan", "--map", "turtlebot3_world.yaml", "--base=-2,0", "--goal", "1.7,0.55", "--robot-model", "burger"]
    assert cli.main([*argv, "--robots", "auto", "--export", "mcap", "--out", str(out), "--no-plots", "-q"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    run = json.loads((out / "run.json").read_text())
    assert m["success"] and m["n_robots"] in (2, 3) and m["n_min"] == 2
    assert run["params"]["robot_model"] == "turtlebot3_burger" and run["params"]["safety_radius"] == pytest.approx(
        0.185
    )
    d = m["diff_drive"]
    assert d["max_lateral_velocity"] <= 1e-9 and d["peak_v"] <= 0.22 * (1 + 1e-9)
    assert d["peak_omega"] <= 2.84 * (1 + 1e-9) and d["max_exit_point_error"] <= 1e-9
    assert m["final_leader_error"] < 1e-3 and m["min_robot_clearance"] > 0
    assert not any(m["violation_steps"].values())
    assert (out / "ros2_bag" / "metadata.yaml").is_file() and any((out / "ros2_bag").glob("*.mcap"))
    traj = json.loads((out / "trajectories.json").read_text())
    leader = traj["robots"][-1]
    assert np.hypot(leader["exit_x"][-1] - 1.7, leader["exit_y"][-1] - 0.55) < 1e-3
