"""ROS 2 export of a differential-drive run (issue 35): ``/robotK/cmd_vel`` (Twist) and ``/robotK/odom``
(Odometry), read back with rosbags and compared with trajectories.json; an omnidirectional bag has neither."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_JAZZY)


def _read(path):
    """{topic: [(bag stamp [ns], message)]} and {topic: msgtype} of the bag at ``path``."""
    out, types = {}, {}
    with Reader(path) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        for conn, stamp, raw in r.messages():
            out.setdefault(conn.topic, []).append((stamp, TS.deserialize_cdr(raw, conn.msgtype)))
    return out, types


@pytest.fixture(scope="module")
def diff_run(tmp_path_factory):
    from tmr import cli

    out = tmp_path_factory.mktemp("dexport") / "A"
    args = ["plan", "--scenario", "A", "--drive", "diff", "--out", str(out), "--no-plots", "-q", "--export", "mcap"]
    assert cli.main(args) == 0
    return out


def test_cmd_vel_and_odom_equal_trajectories_json(diff_run):
    doc = json.loads((diff_run / "trajectories.json").read_text())
    msgs, types = _read(diff_run / "ros2_bag")
    robots = doc["robots"]
    assert len(robots) == 3
    for i, r in enumerate(robots, start=1):
        assert types[f"/robot{i}/cmd_vel"] == "geometry_msgs/msg/Twist"
        assert types[f"/robot{i}/odom"] == "nav_msgs/msg/Odometry"
        stamps = [int(round(t * 1e9)) for t in r["t"]]
        cmd, odom = msgs[f"/robot{i}/cmd_vel"], msgs[f"/robot{i}/odom"]
        assert [s for s, _ in cmd] == stamps and [s for s, _ in odom] == stamps
        for k, ((_, tw), (_, od)) in enumerate(zip(cmd, odom, strict=True)):
            v, w, th = r["v"][k], r["omega"][k], r["theta"][k]
            assert abs(tw.linear.x - v) <= 1e-9 and abs(tw.angular.z - w) <= 1e-9
            assert (tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y) == (0.0, 0.0, 0.0, 0.0)
            assert od.header.frame_id == "odom" and od.child_frame_id == f"robot{i}/base_link"
            assert od.header.stamp.sec * 1_000_000_000 + od.header.stamp.nanosec == stamps[k]
            p, q = od.pose.pose.position, od.pose.pose.orientation
            assert abs(p.x - r["x"][k]) <= 1e-9 and abs(p.y - r["y"][k]) <= 1e-9 and p.z == 0.0
            assert q.x == 0.0 and q.y == 0.0
            assert abs(q.z - math.sin(th / 2)) <= 1e-9 and abs(q.w - math.cos(th / 2)) <= 1e-9
            assert abs(od.twist.twist.linear.x - v) <= 1e-9 and abs(od.twist.twist.angular.z - w) <= 1e-9
            assert not np.any(od.pose.covariance) and not np.any(od.twist.covariance)
            assert od.pose.covariance.size == 36 and od.twist.covariance.size == 36


def test_tmr_export_of_the_run_dir_writes_the_same_bag(diff_run, tmp_path):
    """``tmr export RUN_DIR`` (from the files) and ``tmr plan --export mcap`` (from the plan) write the same bytes."""
    from tmr.export.__main__ import main

    assert main([str(diff_run), "--out", str(tmp_path / "ros2_bag"), "-q"]) == 0
    name = "ros2_bag/ros2_bag.mcap"
    assert (tmp_path / name).read_bytes() == (diff_run / name).read_bytes()


def test_omni_bag_has_no_drive_topics(tmp_path):
    from tmr import cli

    out = tmp_path / "omni"
    assert cli.main(["plan", "--scenario", "A", "--out", str(out), "--no-plots", "-q", "--export", "mcap"]) == 0
    with Reader(out / "ros2_bag") as r:
        topics = {c.topic for c in r.connections}
    assert not any(t.endswith(("/cmd_vel", "/odom")) for t in topics)


def test_motion_refuses_misshapen_drive_arrays():
    from tmr.errors import ParameterError
    from tmr.views.motion import DiffDrive, Motion, Track

    t = np.array([0.0, 0.05])
    tracks = (Track("robot1", np.zeros((2, 3)), "leader"),)
    ok = DiffDrive(np.zeros((2, 1, 2)), np.zeros((2, 1)), np.zeros((2, 1)), np.zeros((2, 1)))
    Motion("chain", "x", t, tracks, (), (), (), (0, 0, 1, 1), diff_drive=ok)
    bad = DiffDrive(np.zeros((2, 1, 2)), np.zeros((3, 1)), np.zeros((2, 1)), np.zeros((2, 1)))
    with pytest.raises(ParameterError, match="diff_drive.theta"):
        Motion("chain", "x", t, tracks, (), (), (), (0, 0, 1, 1), diff_drive=bad)


def test_tf_tree_places_the_odometry_on_the_map(diff_run):
    """/tf links map → odom (identity) → robotK/base_link at every sample, the base_link at the odometry's pose, so a
    viewer can place /robotK/odom; map → robotK stays the tether's exit point (b ahead of the axle)."""
    doc = json.loads((diff_run / "trajectories.json").read_text())
    msgs, _ = _read(diff_run / "ros2_bag")
    tf = msgs["/tf"]
    assert len(tf) == len(doc["robots"][0]["t"])
    for k, (_, m) in enumerate(tf):
        by_child = {t.child_frame_id: t for t in m.transforms}
        odom = by_child["odom"]
        assert odom.header.frame_id == "map"
        tr, q = odom.transform.translation, odom.transform.rotation
        assert (tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
        for i, r in enumerate(doc["robots"], start=1):
            base = by_child[f"robot{i}/base_link"]
            assert base.header.frame_id == "odom"
            p, q = base.transform.translation, base.transform.rotation
            assert abs(p.x - r["x"][k]) <= 1e-9 and abs(p.y - r["y"][k]) <= 1e-9
            assert abs(q.z - math.sin(r["theta"][k] / 2)) <= 1e-9 and abs(q.w - math.cos(r["theta"][k] / 2)) <= 1e-9
            ex = by_child[f"robot{i}"].transform.translation
            assert abs(ex.x - r["exit_x"][k]) <= 1e-9 and abs(ex.y - r["exit_y"][k]) <= 1e-9


def test_filtered_export_of_a_diff_run_is_refused(diff_run, tmp_path, capsys):
    """A differential-drive plan is not filtered: --trajectory filtered exits 2 with one line, nothing written."""
    from tmr.export.__main__ import main

    out = tmp_path / "bag"
    assert main([str(diff_run), "--out", str(out), "--trajectory", "filtered", "-q"]) == 2
    err = capsys.readouterr().err
    assert "not filtered" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
