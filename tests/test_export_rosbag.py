"""tmr.export.rosbag: the bag is read back with rosbags and every message compared with the plan."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from shapely.geometry import Polygon

from tests.motion_data import mopick_plan, scenario_a
from tmr.errors import TmrError
from tmr.export.rosbag import write_bag
from tmr.mcdpr.motion import mcdpr_motion
from tmr.views.motion import chain_motion

TS = get_typestore(Stores.ROS2_JAZZY)


def read_bag(path):
    """{topic: [(bag timestamp [ns], message), ...]} and {topic: msgtype}."""
    out, types = {}, {}
    with Reader(path) as r:
        for c in r.connections:
            types[c.topic] = c.msgtype
        for conn, stamp, raw in r.messages():
            out.setdefault(conn.topic, []).append((stamp, TS.deserialize_cdr(raw, conn.msgtype)))
    return out, types


def ns(msg_stamp) -> int:
    return msg_stamp.sec * 1_000_000_000 + msg_stamp.nanosec


def xyz(p) -> np.ndarray:
    return np.array([p.x, p.y, p.z])


def yaw_of(q) -> float:
    assert abs(q.x) < 1e-15 and abs(q.y) < 1e-15
    return 2.0 * math.atan2(q.z, q.w)


@pytest.fixture(scope="module")
def chain_bag(tmp_path_factory):
    plan, env, cp = scenario_a()
    path = write_bag(chain_motion(plan, env, cp), tmp_path_factory.mktemp("bag") / "ros2_bag")
    msgs, types = read_bag(path)
    return plan, env, cp, msgs, types, path


def test_topics_types_and_counts(chain_bag):
    plan, _, _, msgs, types, path = chain_bag
    k, n = plan.robots.shape[:2]
    assert (path / "ros2_bag.mcap").is_file() and (path / "metadata.yaml").is_file()
    expect = {f"/tmr/robot{i}/pose": ("geometry_msgs/msg/PoseStamped", k) for i in range(1, n + 1)}
    expect |= {f"/tmr/robot{i}/path": ("nav_msgs/msg/Path", 1) for i in range(1, n + 1)}
    expect |= {
        "/tmr/team/trajectory": ("trajectory_msgs/msg/MultiDOFJointTrajectory", 1),
        "/tmr/lines": ("visualization_msgs/msg/MarkerArray", k),
        "/tmr/bodies": ("visualization_msgs/msg/MarkerArray", k),
        "/tmr/scene": ("visualization_msgs/msg/MarkerArray", 1),
        "/tf": ("tf2_msgs/msg/TFMessage", k),
    }
    assert {t: (types[t], len(msgs[t])) for t in types} == expect


def test_poses_paths_and_stamps_equal_the_plan(chain_bag):
    plan, _, cp, msgs, _, _ = chain_bag
    t_ns = [int(round(v * 1e9)) for v in plan.t]
    for i in range(plan.robots.shape[1]):
        poses = msgs[f"/tmr/robot{i + 1}/pose"]
        assert [s for s, _ in poses] == t_ns
        for (stamp, m), xy, tk in zip(poses, plan.robots[:, i], t_ns, strict=True):
            assert ns(m.header.stamp) == stamp == tk and m.header.frame_id == "map"
            assert np.max(np.abs(xyz(m.pose.position) - [*xy, cp.exit_height])) <= 1e-9
            assert (m.pose.orientation.w, m.pose.orientation.z) == (1.0, 0.0)  # omnidirectional: no heading
        ((stamp, path),) = msgs[f"/tmr/robot{i + 1}/path"]
        assert stamp == t_ns[0] and len(path.poses) == len(t_ns)
        got = np.array([xyz(p.pose.position)[:2] for p in path.poses])
        assert np.max(np.abs(got - plan.robots[:, i])) <= 1e-9
        assert [ns(p.header.stamp) for p in path.poses] == t_ns


def test_team_trajectory_and_tf(chain_bag):
    plan, _, cp, msgs, _, _ = chain_bag
    k, n = plan.robots.shape[:2]
    ((_, traj),) = msgs["/tmr/team/trajectory"]
    assert list(traj.joint_names) == [f"robot{i + 1}" for i in range(n)] and len(traj.points) == k
    for j, pt in enumerate(traj.points):
        assert ns(pt.time_from_start) == int(round(plan.t[j] * 1e9)) - int(round(plan.t[0] * 1e9))
        got = np.array([[tf.translation.x, tf.translation.y] for tf in pt.transforms])
        assert np.max(np.abs(got - plan.robots[j])) <= 1e-9
    for j, (stamp, m) in enumerate(msgs["/tf"]):
        assert stamp == int(round(plan.t[j] * 1e9))
        assert [tf.child_frame_id for tf in m.transforms] == [f"robot{i + 1}" for i in range(n)]
        assert all(tf.header.frame_id == "map" for tf in m.transforms)
        got = np.array([[tf.transform.translation.x, tf.transform.translation.y] for tf in m.transforms])
        assert np.max(np.abs(got - plan.robots[j])) <= 1e-9


def test_tethers_are_the_textbook_catenary(chain_bag):
    """Every tether strip runs from the anchor / previous robot to the robot and hangs as the level catenary
    z(x) = H − c (cosh(s / 2c) − cosh((x − s/2) / c)), c = T0 / (ρ g) (Caruso 2021 eq. 22), written here from the
    textbook, not from tmr.model.catenary."""
    plan, _, cp, msgs, _, _ = chain_bag
    assert cp.base_height == cp.exit_height  # the level-ends formula below
    c = cp.horizontal_tension / (cp.cable_mass_per_length * 9.81)
    h = cp.exit_height
    n = plan.robots.shape[1]
    sags = []
    for j, (_, arr) in enumerate(msgs["/tmr/lines"]):
        assert len(arr.markers) == n
        ends = np.vstack([plan.base[:2], plan.robots[j]])
        for i, mk in enumerate(arr.markers):
            assert mk.type == mk.LINE_STRIP and mk.ns == "tether" and mk.id == i
            pts = np.array([xyz(p) for p in mk.points])
            a, b = ends[i], ends[i + 1]
            s = float(np.linalg.norm(b - a))
            assert np.max(np.abs(pts[0] - [*a, h])) <= 1e-9 and np.max(np.abs(pts[-1] - [*b, h])) <= 1e-9
            x = np.linalg.norm(pts[:, :2] - a, axis=1)  # along the span
            z = h - c * (np.cosh(s / (2 * c)) - np.cosh((x - s / 2) / c))
            assert np.max(np.abs(pts[:, 2] - z)) <= 1e-9
            # horizontal projection is the straight chord
            d = pts[:, :2] - a
            assert np.max(np.abs(d[:, 0] * (b - a)[1] - d[:, 1] * (b - a)[0])) <= 1e-9
            sags.append(h - pts[:, 2].min())
    assert min(sags) >= 0.0 and max(sags) > 0.01  # the tethers visibly sag, and never rise above the chord
    assert max(sags) < h  # the plan keeps every cable off the floor


def test_scene_markers_carry_the_obstacles(chain_bag):
    _, env, _, msgs, _, _ = chain_bag
    ((stamp, arr),) = msgs["/tmr/scene"]
    floor = [
        np.array([xyz(p)[:2] for p in mk.points])
        for mk in arr.markers
        if mk.ns == "obstacles" and mk.type == mk.LINE_STRIP and mk.points[0].z == 0.0
    ]
    raw = list(env.obstacles.geoms)
    assert len(floor) == len(raw) == 5
    for poly in raw:  # every obstacle outline exactly once (same polygon, whatever vertex it starts at)
        assert sum(Polygon(r).symmetric_difference(poly).area <= 1e-12 for r in floor) == 1
    names = {mk.text for mk in arr.markers if mk.ns == "labels"}
    assert names == {"anchor", "goal"}
    assert any(mk.ns == "inflated" for mk in arr.markers) and any(mk.ns == "room" for mk in arr.markers)


def test_mopick_bases_platform_cables(tmp_path):
    robot, scene, res = mopick_plan()
    m = mcdpr_motion(robot, scene, res, rate=4.0)
    msgs, types = read_bag(write_bag(m, tmp_path / "bag", storage="sqlite3"))
    k = len(res.platform)
    assert len(msgs["/tmr/platform/pose"]) == k and len(msgs["/tmr/base4/pose"]) == k
    assert [s for s, _ in msgs["/tmr/platform/pose"]] == [int(round(i / 4.0 * 1e9)) for i in range(k)]
    for j in range(k):
        _, p = msgs["/tmr/platform/pose"][j]
        assert np.max(np.abs(xyz(p.pose.position) - res.platform[j])) <= 1e-9
        for b in range(4):
            _, bm = msgs[f"/tmr/base{b + 1}/pose"][j]
            assert np.max(np.abs(xyz(bm.pose.position) - [*res.bases[j, b], 0.0])) <= 1e-9
            assert abs(yaw_of(bm.pose.orientation) - res.headings[j, b]) <= 1e-12
        _, lines = msgs["/tmr/lines"][j]
        assert [mk.ns for mk in lines.markers] == ["cable"] * 4
        for c, mk in enumerate(lines.markers):  # exit point 1.2 m above the base axis, straight to the platform
            a, b = xyz(mk.points[0]), xyz(mk.points[1])
            assert len(mk.points) == 2
            assert np.max(np.abs(a - [*res.bases[j, c], 1.2])) <= 1e-9
            assert np.max(np.abs(b - res.platform[j])) <= 1e-9
    ((_, traj),) = msgs["/tmr/team/trajectory"]
    assert list(traj.joint_names) == ["base1", "base2", "base3", "base4", "platform"]


def test_same_motion_same_bytes(tmp_path):
    plan, env, cp = scenario_a()
    m = chain_motion(plan, env, cp)
    a = write_bag(m, tmp_path / "a" / "bag")
    b = write_bag(m, tmp_path / "b" / "bag")
    for name in ("bag.mcap", "metadata.yaml"):
        assert (a / name).read_bytes() == (b / name).read_bytes()


def test_refusals(tmp_path):
    plan, env, cp = scenario_a()
    m = chain_motion(plan, env, cp)
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(TmrError, match="is a file"):
        write_bag(m, f)
    with pytest.raises(TmrError, match="unknown bag storage"):
        write_bag(m, tmp_path / "x", storage="rosbag1")
    write_bag(m, tmp_path / "bag")
    with pytest.raises(TmrError, match="exists"):
        write_bag(m, tmp_path / "bag", overwrite=False)
    assert not (tmp_path / "x").exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bag", "file"]


def test_ccma_agents_links_end_effector(tmp_path):
    """CCMA: agents with their yaw, the end-effector, one LINE_STRIP per link; no room (a CCMA run has none)."""
    from tmr.ccma.motion import ccma_motion

    k = 4
    s = np.linspace(0.0, 1.0, k)
    agents = np.stack([np.column_stack([s + j, -s, 0.2 * s + j]) for j in range(3)], axis=1)  # (k, 3, 3)
    ee = np.column_stack([s, s, 0.5 + 0.1 * s])
    link = np.stack([np.column_stack([s + d, s - d, np.full(k, 0.3)]) for d in (0.0, 0.1, 0.2)], axis=1)  # (k, 3, 3)
    m = ccma_motion("toy", ["a", "b", "c"], agents, 0.1, ee, [link], rate=5.0)
    msgs, types = read_bag(write_bag(m, tmp_path / "bag"))
    assert {t for t in types if t.endswith("/pose")} == {
        "/tmr/a/pose",
        "/tmr/b/pose",
        "/tmr/c/pose",
        "/tmr/end_effector/pose",
    }
    for j, name in enumerate("abc"):
        for i, (stamp, msg) in enumerate(msgs[f"/tmr/{name}/pose"]):
            assert stamp == int(round(i / 5.0 * 1e9))
            assert np.max(np.abs(xyz(msg.pose.position) - [agents[i, j, 0], agents[i, j, 1], 0.1])) <= 1e-9
            assert abs(yaw_of(msg.pose.orientation) - agents[i, j, 2]) <= 1e-12
    for i, (_, msg) in enumerate(msgs["/tmr/end_effector/pose"]):
        assert np.max(np.abs(xyz(msg.pose.position) - ee[i])) <= 1e-9
    for i, (_, arr) in enumerate(msgs["/tmr/lines"]):
        (mk,) = arr.markers
        assert mk.ns == "link" and np.max(np.abs(np.array([xyz(p) for p in mk.points]) - link[i])) <= 1e-9
    ((_, scene),) = msgs["/tmr/scene"]
    assert not any(mk.ns == "room" for mk in scene.markers)
