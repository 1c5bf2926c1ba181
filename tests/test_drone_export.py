"""tmr.export.rosbag.write_drone_bag: the bag is read back with rosbags and every message compared with the plan."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from tests.drone_views_data import hand_plan, small_world
from tmr.errors import TmrError
from tmr.export.rosbag import DRONE_CURVE_POINTS, drone_topics, write_drone_bag
from tmr.model.catenary3d import solve3d
from tmr.views.drones import obstacle_mesh

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


def xyz(p) -> np.ndarray:
    return np.array([p.x, p.y, p.z])


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    plan, world = hand_plan(3, steps=21, vertical_at=4), small_world()
    path = write_drone_bag(plan, world, tmp_path_factory.mktemp("bag") / "ros2_bag")
    msgs, types = read_bag(path)
    return plan, world, path, msgs, types


def test_topics_types_and_counts(bag):
    plan, _, path, msgs, types = bag
    k = len(plan.t)
    assert (path / "ros2_bag.mcap").is_file() and (path / "metadata.yaml").is_file()
    assert types == drone_topics(3)
    once = {"/tmr/scene", "/tmr/team/trajectory"} | {f"/tmr/robot{i}/path" for i in (1, 2, 3)}
    assert {t: len(m) for t, m in msgs.items()} == {t: 1 if t in once else k for t in types}


def test_poses_are_the_drones_3d_positions(bag):
    plan, _, _, msgs, _ = bag
    t_ns = [int(round(v * 1e9)) for v in plan.t]
    for i in range(3):
        poses = msgs[f"/tmr/robot{i + 1}/pose"]
        assert [s for s, _ in poses] == t_ns
        got = np.array([xyz(m.pose.position) for _, m in poses])
        assert np.array_equal(got, plan.robots[:, i])  # z included: drones fly
        ((_, path),) = msgs[f"/tmr/robot{i + 1}/path"]
        assert np.array_equal(np.array([xyz(p.pose.position) for p in path.poses]), plan.robots[:, i])
    for k, (_, tf) in enumerate(msgs["/tf"]):
        assert [t.child_frame_id for t in tf.transforms] == ["robot1", "robot2", "robot3"]
        assert np.array_equal(np.array([xyz(t.transform.translation) for t in tf.transforms]), plan.robots[k])


def test_tether_line_strips_are_the_catenaries(bag):
    plan, _, _, msgs, _ = bag
    strip = TS.types["visualization_msgs/msg/Marker"].LINE_STRIP
    for k, (_, arr) in enumerate(msgs["/tmr/lines"]):
        assert [(m.ns, m.id, m.type) for m in arr.markers] == [("tether", j, strip) for j in range(3)]
        pts = plan.points(k)
        for j, m in enumerate(arr.markers):
            got = np.array([xyz(p) for p in m.points])
            ref = solve3d(pts[j], pts[j + 1], plan.tether).points(DRONE_CURVE_POINTS)
            assert got.shape == (DRONE_CURVE_POINTS, 3) and np.max(np.abs(got - ref)) < 1e-9
    assert np.isnan(plan.tether_a[4, 0])  # the vertical tether: a straight line up from the anchor
    line = np.array([xyz(p) for p in msgs["/tmr/lines"][4][1].markers[0].points])
    assert np.allclose(line[:, :2], plan.base[:2]) and np.all(np.diff(line[:, 2]) > 0)


def test_drone_spheres_and_scene(bag):
    plan, world, _, msgs, _ = bag
    M = TS.types["visualization_msgs/msg/Marker"]
    _, bodies = msgs["/tmr/bodies"][7]
    assert [m.type for m in bodies.markers] == [M.SPHERE] * 3
    assert all(xyz(m.scale) == pytest.approx([0.6, 0.6, 0.6]) for m in bodies.markers)
    assert np.array_equal(np.array([xyz(m.pose.position) for m in bodies.markers]), plan.robots[7])
    ((_, scene),) = msgs["/tmr/scene"]
    tris = [m for m in scene.markers if m.ns == "obstacles"]
    assert [m.type for m in tris] == [M.TRIANGLE_LIST] * 3
    for m, ob in zip(tris, world.obstacles, strict=True):
        dr = obstacle_mesh(ob)
        got = np.array([xyz(p) for p in m.points])
        assert np.array_equal(got, dr.vertices[dr.faces].reshape(-1, 3))
        assert got.min(axis=0) == pytest.approx(ob.lo) and got.max(axis=0) == pytest.approx(ob.hi)
    (room,) = [m for m in scene.markers if m.ns == "room"]
    assert room.type == M.LINE_LIST and len(room.points) == 24  # 12 edges
    labels = sorted(m.text for m in scene.markers if m.ns == "labels")
    assert labels == ["anchor", "goal"]


def test_deterministic_storage_and_errors(bag, tmp_path):
    plan, world, path, _, _ = bag
    again = write_drone_bag(plan, world, tmp_path / "ros2_bag")
    assert (again / "ros2_bag.mcap").read_bytes() == (path / "ros2_bag.mcap").read_bytes()
    sq = write_drone_bag(plan, world, tmp_path / "sq", storage="sqlite3")
    msgs, _ = read_bag(sq)
    assert len(msgs["/tmr/lines"]) == len(plan.t)
    with pytest.raises(TmrError, match="unknown bag storage"):
        write_drone_bag(plan, world, tmp_path / "x", storage="zip")
    with pytest.raises(TmrError, match="exists"):
        write_drone_bag(plan, world, again, overwrite=False)
    assert not (tmp_path / "x").exists()
