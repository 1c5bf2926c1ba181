"""A :class:`tmr.views.motion.Motion` as a ROS 2 bag (rosbag2, MCAP storage) written with the ``rosbags`` library.

No ROS installation is needed: messages are serialised to CDR with the ROS 2 Jazzy type definitions shipped in
``rosbags``. Topics (frame ``map``; every stamp is the plan's time t_k, stored as ``round(t_k · 1e9)`` ns):

========================================  ======================================  ====================================
topic                                     type                                    messages
========================================  ======================================  ====================================
``/tmr/<body>/pose``                      ``geometry_msgs/msg/PoseStamped``       one per sample and body
``/tmr/<body>/path``                      ``nav_msgs/msg/Path``                   one (at t_0, latched): all samples
``/tmr/team/trajectory``                  ``trajectory_msgs/msg/                  one (at t_0, latched): every sample,
                                          MultiDOFJointTrajectory``               one transform per body
``/tmr/lines``                            ``visualization_msgs/msg/MarkerArray``  one per sample: tethers (catenary,
                                                                                  sagging), cables, links as
                                                                                  LINE_STRIPs
``/tmr/bodies``                           ``visualization_msgs/msg/MarkerArray``  one per sample: robot / base discs
                                                                                  (CYLINDER), points (SPHERE)
``/tmr/scene``                            ``visualization_msgs/msg/MarkerArray``  one (at t_0, latched): obstacles,
                                                                                  inflated outlines, room, anchor,
                                                                                  goal, task points
``/tf``                                   ``tf2_msgs/msg/TFMessage``              one per sample: map → every body
                                                                                  (diff drive: also map → odom →
                                                                                  robot<i>/base_link)
``/robot<i>/cmd_vel``                     ``geometry_msgs/msg/Twist``             differential-drive runs only: one
                                                                                  per sample and robot
``/robot<i>/odom``                        ``nav_msgs/msg/Odometry``               differential-drive runs only: one
                                                                                  per sample and robot
========================================  ======================================  ====================================

Bodies are the motion's tracks: ``robot1..N`` (chain), ``base1..p`` and ``platform`` (MoPICK), the agents and
``end_effector`` (CCMA). Orientation is the body's yaw when it has one (MoPICK bases, CCMA agents), else identity
(omnidirectional chain robots carry no heading; a differential-drive chain's robots carry theta at their exit point).

A differential-drive chain (``--drive diff``, :class:`tmr.views.motion.DiffDrive`) adds, per robot i and sample k
(stamp t_k as above), the command the robot executes over [t_k, t_k+1] and its odometry:

* ``/robot<i>/cmd_vel`` — ``geometry_msgs/msg/Twist``: ``linear.x`` = v [m/s], ``angular.z`` = omega [rad/s], every
  other component 0 (v = omega = 0 at the last sample);
* ``/robot<i>/odom`` — ``nav_msgs/msg/Odometry``: header stamp t_k, frame ``odom`` (:data:`ODOM_FRAME`, coincident
  with ``map``: the plan's positions are exact), ``child_frame_id`` ``robot<i>/base_link``; pose = the axle centre
  (x, y, 0) [m] and the heading quaternion (0, 0, sin(theta/2), cos(theta/2)); twist in the body frame = (v, 0, 0)
  [m/s], (0, 0, omega) [rad/s]; both covariances zero (the plan is not an estimate);
* on ``/tf`` with every sample: ``map`` → ``odom`` (identity) and ``odom`` → ``robot<i>/base_link`` (the odometry's
  pose), so a viewer places the odometry and the robot's body on the map (``map`` → ``robot<i>`` stays the tether's
  exit point).

An omnidirectional chain's bag has none of these topics and its bytes are unchanged.

A tethered drone chain (issue 32) has its own writer, :func:`write_drone_bag`, with the same topics from a
``DronePlan`` and its ``World3D``: 3-D poses, each tether's catenary as a ``LINE_STRIP``, the drones as spheres and the
obstacles' surfaces as ``TRIANGLE_LIST`` markers.

The bag is deterministic: the same motion gives the same bytes (no wall-clock time is written).
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from tmr.views.motion import OBSTACLE_HEIGHT, Motion

__all__ = ["FRAME", "ODOM_FRAME", "TOPIC_TYPES", "drone_topics", "stamp_ns", "topics", "write_bag", "write_drone_bag"]

FRAME = "map"
#: Frame of a differential-drive robot's ``nav_msgs/Odometry`` (``/robot<i>/odom``).
ODOM_FRAME = "odom"

TOPIC_TYPES = {
    "pose": "geometry_msgs/msg/PoseStamped",
    "path": "nav_msgs/msg/Path",
    "trajectory": "trajectory_msgs/msg/MultiDOFJointTrajectory",
    "markers": "visualization_msgs/msg/MarkerArray",
    "tf": "tf2_msgs/msg/TFMessage",
    "cmd_vel": "geometry_msgs/msg/Twist",
    "odom": "nav_msgs/msg/Odometry",
}

_COLORS = {  # r, g, b, a
    "tether": (0.12, 0.47, 0.71, 1.0),
    "cable": (0.84, 0.15, 0.16, 1.0),
    "link": (0.17, 0.63, 0.17, 1.0),
    "robot": (0.5, 0.5, 0.5, 0.5),
    "leader": (1.0, 0.5, 0.05, 0.6),
    "base": (0.3, 0.3, 0.3, 0.7),
    "platform": (0.84, 0.15, 0.16, 1.0),
    "agent": (0.58, 0.4, 0.74, 0.8),
    "end_effector": (0.86, 0.08, 0.24, 1.0),
    "obstacle": (0.62, 0.62, 0.62, 1.0),
    "inflated": (0.33, 0.33, 0.33, 1.0),
    "room": (0.0, 0.0, 0.0, 1.0),
    "point": (1.0, 0.5, 0.05, 1.0),
}


def stamp_ns(t: float) -> int:
    """Bag timestamp [ns] of a plan time ``t`` [s]."""
    return int(round(float(t) * 1e9))


def topics(motion: Motion) -> dict[str, str]:
    """Every topic :func:`write_bag` writes for ``motion`` → its message type."""
    out = _topics(tr.name for tr in motion.tracks)
    for name in _diff_robots(motion):
        out[f"/{name}/cmd_vel"] = TOPIC_TYPES["cmd_vel"]
        out[f"/{name}/odom"] = TOPIC_TYPES["odom"]
    return out


def _diff_robots(motion: Motion) -> list[str]:
    """The robot names ``robot1..N`` of a differential-drive chain's motion (in the order of its ``diff_drive``
    arrays), else []."""
    if getattr(motion, "diff_drive", None) is None:
        return []
    return [f"robot{i + 1}" for i in range(np.shape(motion.diff_drive.theta)[1])]


def _topics(bodies: Iterable[str]) -> dict[str, str]:
    """The topics of a bag whose moving bodies are ``bodies`` (a pose and a path each) → their message types."""
    out: dict[str, str] = {}
    for name in bodies:
        out[f"/tmr/{name}/pose"] = TOPIC_TYPES["pose"]
        out[f"/tmr/{name}/path"] = TOPIC_TYPES["path"]
    out["/tmr/team/trajectory"] = TOPIC_TYPES["trajectory"]
    out["/tmr/lines"] = TOPIC_TYPES["markers"]
    out["/tmr/bodies"] = TOPIC_TYPES["markers"]
    out["/tmr/scene"] = TOPIC_TYPES["markers"]
    out["/tf"] = TOPIC_TYPES["tf"]
    return out


class _Msgs:
    """Message constructors over a rosbags typestore."""

    def __init__(self, ts: Any) -> None:
        self.ts = ts
        self.T = ts.types

    def time(self, ns: int) -> Any:
        return self.T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def duration(self, ns: int) -> Any:
        return self.T["builtin_interfaces/msg/Duration"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def header(self, ns: int, frame: str = FRAME) -> Any:
        return self.T["std_msgs/msg/Header"](stamp=self.time(ns), frame_id=frame)

    def point(self, p: Any) -> Any:
        return self.T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2]))

    def vector(self, p: Any) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2]))

    def quat(self, yaw: float | None) -> Any:
        q = self.T["geometry_msgs/msg/Quaternion"]
        if yaw is None:
            return q(x=0.0, y=0.0, z=0.0, w=1.0)
        return q(x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw))

    def pose(self, p: Any, yaw: float | None) -> Any:
        return self.T["geometry_msgs/msg/Pose"](position=self.point(p), orientation=self.quat(yaw))

    def transform(self, p: Any, yaw: float | None) -> Any:
        return self.T["geometry_msgs/msg/Transform"](translation=self.vector(p), rotation=self.quat(yaw))

    def twist(self, v: float, omega: float) -> Any:
        """A body-frame ``geometry_msgs/Twist``: forward speed ``v`` [m/s], yaw rate ``omega`` [rad/s]."""
        return self.T["geometry_msgs/msg/Twist"](
            linear=self.vector((v, 0.0, 0.0)), angular=self.vector((0.0, 0.0, omega))
        )

    def odometry(self, ns_stamp: int, child: str, xy: Any, theta: float, v: float, omega: float) -> Any:
        """A ``nav_msgs/Odometry`` in :data:`ODOM_FRAME`: axle centre ``xy`` [m] at z = 0, heading ``theta`` [rad],
        body-frame twist (``v`` [m/s], ``omega`` [rad/s]); zero covariances."""
        T = self.T
        zero = np.zeros(36, dtype=np.float64)
        return T["nav_msgs/msg/Odometry"](
            header=self.header(ns_stamp, ODOM_FRAME),
            child_frame_id=child,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=self.pose((xy[0], xy[1], 0.0), float(theta)), covariance=zero
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=self.twist(v, omega), covariance=zero.copy()),
        )

    def color(self, key: str) -> Any:
        r, g, b, a = _COLORS[key]
        return self.T["std_msgs/msg/ColorRGBA"](r=r, g=g, b=b, a=a)

    def marker(
        self,
        ns_stamp: int,
        ns: str,
        mid: int,
        mtype: str,
        color: str,
        scale: tuple[float, float, float],
        points: Any = (),
        pose: tuple[Any, float | None] | None = None,
        text: str = "",
    ) -> Any:
        M = self.T["visualization_msgs/msg/Marker"]
        return M(
            header=self.header(ns_stamp),
            ns=ns,
            id=mid,
            type=getattr(M, mtype),
            action=M.ADD,
            pose=self.pose(*pose) if pose is not None else self.pose((0.0, 0.0, 0.0), None),
            scale=self.vector(scale),
            color=self.color(color),
            lifetime=self.duration(0),
            frame_locked=False,
            points=[self.point(p) for p in points],
            colors=[],
            texture_resource="",
            texture=self.T["sensor_msgs/msg/CompressedImage"](
                header=self.header(0), format="", data=np.zeros(0, np.uint8)
            ),
            uv_coordinates=[],
            text=text,
            mesh_resource="",
            mesh_file=self.T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )


def _yaw(tr: Any, k: int) -> float | None:
    return None if tr.yaw is None else float(tr.yaw[k])


def _line_width(ln: Any) -> float:
    return 0.03 if ln.kind == "tether" else 0.015


def _prism_markers(m: _Msgs, ns0: int, ns: str, polys: Any, height: float, start: int) -> list[Any]:
    """Wireframe of polygons extruded from the floor to ``height`` [m]: each ring at z = 0 and at the top, and its
    vertical edges (markers ``start``, ``start + 1``, … of namespace ``ns``)."""
    out: list[Any] = []
    i = start
    for poly in polys:
        for ring in [poly.exterior, *poly.interiors]:
            xy = np.asarray(ring.coords)[:, :2]
            for z in (0.0, height):
                pts = np.column_stack([xy, np.full(len(xy), z)])
                out.append(m.marker(ns0, ns, i, "LINE_STRIP", "obstacle", (0.03, 0, 0), pts))
                i += 1
            edges = np.repeat(np.column_stack([xy, np.zeros(len(xy))]), 2, axis=0)
            edges[1::2, 2] = height
            out.append(m.marker(ns0, ns, i, "LINE_LIST", "obstacle", (0.02, 0, 0), edges))
            i += 1
    return out


def _scene_markers(m: _Msgs, motion: Motion, ns0: int) -> list[Any]:
    out: list[Any] = _prism_markers(m, ns0, "obstacles", motion.obstacles, OBSTACLE_HEIGHT, 0)
    # low obstacles (a step, a cable tray) at their own height: the tethers may pass over them
    for low in getattr(motion, "low_obstacles", ()):
        fp = low.footprint
        parts = list(getattr(fp, "geoms", [fp]))
        out += _prism_markers(m, ns0, "low_obstacles", parts, float(low.height), len(out))
    for j, poly in enumerate(motion.inflated_in_room()):
        for ring in [poly.exterior, *poly.interiors]:
            xy = np.asarray(ring.coords)[:, :2]
            pts = np.column_stack([xy, np.zeros(len(xy))])
            out.append(m.marker(ns0, "inflated", j * 1000 + len(out), "LINE_STRIP", "inflated", (0.01, 0, 0), pts))
    if motion.system != "ccma":  # a CCMA run has no room (its bounds only frame the views)
        x0, y0, x1, y1 = motion.bounds
        room = [(x0, y0, 0.0), (x1, y0, 0.0), (x1, y1, 0.0), (x0, y1, 0.0), (x0, y0, 0.0)]
        out.append(m.marker(ns0, "room", 0, "LINE_STRIP", "room", (0.05, 0, 0), room))
    for j, (name, p) in enumerate(motion.points.items()):
        out.append(m.marker(ns0, "points", j, "SPHERE", "point", (0.15, 0.15, 0.15), pose=(p, None)))
        top = (float(p[0]), float(p[1]), float(p[2]) + 0.25)
        out.append(m.marker(ns0, "labels", j, "TEXT_VIEW_FACING", "room", (0, 0, 0.2), pose=(top, None), text=name))
    return out


@contextmanager
def _staged_bag(path: Path, overwrite: bool, storage: str, topic_types: dict[str, str]) -> Iterator[Any]:
    """A rosbags ``Writer`` on a temporary sibling of ``path`` with a connection per topic (latched: the topics
    written once, ``/path``, ``/tmr/team/trajectory``, ``/tmr/scene``), its connections and typestore; the bag is
    moved to ``path`` only when the block ends without error (replacing an older one if ``overwrite``)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from tmr.errors import TmrError

    plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
    if storage not in plugins:
        raise TmrError(f"unknown bag storage {storage!r}; choose one of {', '.join(plugins)}")
    path = Path(path)
    if path.exists() and not overwrite:
        raise TmrError(f"{path} exists; choose another output or allow overwriting")
    if path.exists() and not path.is_dir():
        raise TmrError(f"{path} is a file, not a bag directory")
    ts = get_typestore(Stores.ROS2_JAZZY)
    zero = QosTime(sec=0, nsec=0)
    latched = Qos(
        QosHistory.KEEP_LAST,
        1,
        QosReliability.RELIABLE,
        QosDurability.TRANSIENT_LOCAL,
        zero,
        zero,
        QosLiveliness.AUTOMATIC,
        zero,
        False,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp_parent = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    tmp = tmp_parent / path.name
    try:
        with Writer(tmp, version=9, storage_plugin=plugins[storage]) as w:
            conns = {}
            for topic, msgtype in topic_types.items():
                once = topic.endswith("/path") or topic in ("/tmr/team/trajectory", "/tmr/scene")
                conns[topic] = w.add_connection(
                    topic, msgtype, typestore=ts, offered_qos_profiles=[latched] if once else []
                )
            yield w, conns, ts
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    finally:
        shutil.rmtree(tmp_parent, ignore_errors=True)


def write_bag(
    motion: Motion, path: str | os.PathLike[str], overwrite: bool = True, storage: str = "mcap", progress: bool = False
) -> Path:
    """Write ``motion`` as a rosbag2 directory (rosbag2 metadata version 9) at ``path``; return the path.

    ``storage``: ``"mcap"`` (default; Foxglove opens it directly, ``ros2 bag play`` with the MCAP plugin) or
    ``"sqlite3"`` (rosbag2's older default). ``progress``: a tqdm bar over the samples on stderr.

    The bag is written into a temporary sibling directory and moved to ``path`` only when complete, replacing an
    older bag there if ``overwrite`` (else :class:`tmr.errors.TmrError` when ``path`` exists).
    """
    path = Path(path)
    t = np.asarray(motion.t, dtype=float)
    logging.getLogger("tmr").debug("ROS bag: %d samples, storage %s", t.size, storage)
    stamps = [stamp_ns(v) for v in t]
    ns0 = stamps[0]
    with _staged_bag(path, overwrite, storage, topics(motion)) as (w, conns, ts):
        m = _Msgs(ts)
        ser = ts.serialize_cdr
        # once, at t_0: scene, paths, team trajectory
        scene = ts.types["visualization_msgs/msg/MarkerArray"](markers=_scene_markers(m, motion, ns0))
        w.write(conns["/tmr/scene"], ns0, ser(scene, TOPIC_TYPES["markers"]))
        for tr in motion.tracks:
            poses = [
                ts.types["geometry_msgs/msg/PoseStamped"](header=m.header(s), pose=m.pose(tr.xyz[k], _yaw(tr, k)))
                for k, s in enumerate(stamps)
            ]
            msg = ts.types["nav_msgs/msg/Path"](header=m.header(ns0), poses=poses)
            w.write(conns[f"/tmr/{tr.name}/path"], ns0, ser(msg, TOPIC_TYPES["path"]))
        P = ts.types["trajectory_msgs/msg/MultiDOFJointTrajectoryPoint"]
        points = [
            P(
                transforms=[m.transform(tr.xyz[k], _yaw(tr, k)) for tr in motion.tracks],
                velocities=[],
                accelerations=[],
                time_from_start=m.duration(s - ns0),
            )
            for k, s in enumerate(stamps)
        ]
        traj = ts.types["trajectory_msgs/msg/MultiDOFJointTrajectory"](
            header=m.header(ns0), joint_names=[tr.name for tr in motion.tracks], points=points
        )
        w.write(conns["/tmr/team/trajectory"], ns0, ser(traj, TOPIC_TYPES["trajectory"]))
        # per sample
        TS = ts.types["geometry_msgs/msg/TransformStamped"]
        MA = ts.types["visualization_msgs/msg/MarkerArray"]
        from tqdm import tqdm

        diff_robots, dd = _diff_robots(motion), motion.diff_drive  # differential drive: its robots, poses, commands
        for k, s in enumerate(tqdm(stamps, desc="bag samples", unit="sample", leave=False, disable=not progress)):
            for tr in motion.tracks:
                msg = ts.types["geometry_msgs/msg/PoseStamped"](header=m.header(s), pose=m.pose(tr.xyz[k], _yaw(tr, k)))
                w.write(conns[f"/tmr/{tr.name}/pose"], s, ser(msg, TOPIC_TYPES["pose"]))
            lines = [
                m.marker(s, ln.kind, i, "LINE_STRIP", ln.kind, (_line_width(ln), 0, 0), ln.points[k])
                for i, ln in enumerate(motion.lines)
            ]
            w.write(conns["/tmr/lines"], s, ser(MA(markers=lines), TOPIC_TYPES["markers"]))
            bodies = []
            for i, tr in enumerate(motion.tracks):
                if tr.radius > 0:
                    d = 2.0 * tr.radius
                    p = (tr.xyz[k][0], tr.xyz[k][1], 0.5 * tr.xyz[k][2] if tr.xyz[k][2] > 0 else 0.05)
                    h = max(float(tr.xyz[k][2]), 0.1)
                    bodies.append(m.marker(s, "bodies", i, "CYLINDER", tr.role, (d, d, h), pose=(p, _yaw(tr, k))))
                else:
                    bodies.append(
                        m.marker(s, "bodies", i, "SPHERE", tr.role, (0.06, 0.06, 0.06), pose=(tr.xyz[k], None))
                    )
            w.write(conns["/tmr/bodies"], s, ser(MA(markers=bodies), TOPIC_TYPES["markers"]))
            tfs = [
                TS(header=m.header(s), child_frame_id=tr.name, transform=m.transform(tr.xyz[k], _yaw(tr, k)))
                for tr in motion.tracks
            ]
            if diff_robots:  # map → odom (identity: the plan is exact) → robot<i>/base_link (the odometry's pose)
                tfs.append(TS(header=m.header(s), child_frame_id=ODOM_FRAME, transform=m.transform((0, 0, 0), None)))
                for i, name in enumerate(diff_robots):
                    xy, th = dd.axle[k, i], float(dd.theta[k, i])
                    tfs.append(
                        TS(
                            header=m.header(s, ODOM_FRAME),
                            child_frame_id=f"{name}/base_link",
                            transform=m.transform((xy[0], xy[1], 0.0), th),
                        )
                    )
            w.write(conns["/tf"], s, ser(ts.types["tf2_msgs/msg/TFMessage"](transforms=tfs), TOPIC_TYPES["tf"]))
            for i, name in enumerate(diff_robots):  # differential drive: the command and the odometry
                v, omega = float(dd.v[k, i]), float(dd.omega[k, i])
                w.write(conns[f"/{name}/cmd_vel"], s, ser(m.twist(v, omega), TOPIC_TYPES["cmd_vel"]))
                odom = m.odometry(s, f"{name}/base_link", dd.axle[k, i], dd.theta[k, i], v, omega)
                w.write(conns[f"/{name}/odom"], s, ser(odom, TOPIC_TYPES["odom"]))
    return path


# ----------------------------------------------------------------------------------------------------------
# drone chains (issue 32): 3-D poses, catenary line strips, obstacle surfaces
# ----------------------------------------------------------------------------------------------------------
#: Points per tether LINE_STRIP of a drone bag (ends included), equally spaced in arc length.
DRONE_CURVE_POINTS = 24


def drone_topics(n: int) -> dict[str, str]:
    """Every topic :func:`write_drone_bag` writes for ``n`` drones → its message type (the chain bag's topics)."""
    return _topics(f"robot{i}" for i in range(1, n + 1))


def _drone_scene(m: _Msgs, plan: Any, world: Any, ns0: int) -> list[Any]:
    """Obstacles (TRIANGLE_LIST surface + LINE_LIST edges each), the room's 12 edges, the leader's reference,
    anchor and goal (SPHERE + label)."""
    from tmr.views.drones import _room_edges, obstacle_mesh

    out: list[Any] = []
    for i, ob in enumerate(world.obstacles):
        dr = obstacle_mesh(ob)
        tris = dr.vertices[dr.faces].reshape(-1, 3)
        out.append(m.marker(ns0, "obstacles", i, "TRIANGLE_LIST", "obstacle", (1.0, 1.0, 1.0), tris, text=dr.name))
        out.append(m.marker(ns0, "obstacle_edges", i, "LINE_LIST", "inflated", (0.02, 0, 0), dr.edges.reshape(-1, 3)))
    room = np.array([p for edge in _room_edges(world.bounds) for p in edge])
    out.append(m.marker(ns0, "room", 0, "LINE_LIST", "room", (0.03, 0, 0), room))
    ref = np.asarray(plan.reference, dtype=float)
    out.append(m.marker(ns0, "reference", 0, "LINE_STRIP", "point", (0.02, 0, 0), ref))
    for j, (name, p) in enumerate((("anchor", plan.base), ("goal", plan.goal))):
        p = np.asarray(p, dtype=float)
        out.append(m.marker(ns0, "points", j, "SPHERE", "point", (0.15, 0.15, 0.15), pose=(p, None)))
        top = (float(p[0]), float(p[1]), float(p[2]) + 0.25)
        out.append(m.marker(ns0, "labels", j, "TEXT_VIEW_FACING", "room", (0, 0, 0.2), pose=(top, None), text=name))
    return out


def write_drone_bag(
    plan: Any,
    world: Any,
    path: str | os.PathLike[str],
    overwrite: bool = True,
    storage: str = "mcap",
    progress: bool = False,
) -> Path:
    """Write a drone chain's plan (:class:`tmr.control.plan3d.DronePlan` and its :class:`tmr.world.world3d.World3D`)
    as a rosbag2 directory at ``path``, with the chain bag's topics (:func:`drone_topics`, frame ``map``, stamps
    ``round(t_k · 1e9)`` ns):

    - ``/tmr/robot<i>/pose``, ``/tf`` (per step), ``/tmr/robot<i>/path``, ``/tmr/team/trajectory`` (once): the
      drones' 3-D positions (identity orientation: the plan carries no attitude);
    - ``/tmr/lines`` (per step): one ``LINE_STRIP`` per tether (ns ``tether``, id j - 1 for tether j), its catenary
      rebuilt from the two ends and the recorded ``a`` at :data:`DRONE_CURVE_POINTS` points of equal arc length
      (:func:`tmr.views.drones.tether_curves`);
    - ``/tmr/bodies`` (per step): each drone a ``SPHERE`` of diameter 2r;
    - ``/tmr/scene`` (once, latched): each obstacle's surface as a ``TRIANGLE_LIST`` and its edges as a ``LINE_LIST``,
      the room's edges, the leader's reference, anchor and goal.

    Storage, overwrite and atomicity as :func:`write_bag`; the same plan gives the same bytes.
    """
    from tmr.views.drones import tether_curves

    path = Path(path)
    robots = np.asarray(plan.robots, dtype=float)
    k_steps, n = robots.shape[:2]
    stamps = [stamp_ns(v) for v in np.asarray(plan.t, dtype=float)]
    ns0 = stamps[0]
    curves = tether_curves(plan, DRONE_CURVE_POINTS)
    names = [f"robot{i}" for i in range(1, n + 1)]
    roles = ["robot"] * (n - 1) + ["leader"]
    d = 2.0 * float(plan.safety_radius)
    logging.getLogger("tmr").debug("ROS bag (drones): %d steps, storage %s", k_steps, storage)
    with _staged_bag(path, overwrite, storage, drone_topics(n)) as (w, conns, ts):
        m = _Msgs(ts)
        ser = ts.serialize_cdr
        T = ts.types
        MA = T["visualization_msgs/msg/MarkerArray"]
        w.write(conns["/tmr/scene"], ns0, ser(MA(markers=_drone_scene(m, plan, world, ns0)), TOPIC_TYPES["markers"]))
        for i, name in enumerate(names):
            poses = [
                T["geometry_msgs/msg/PoseStamped"](header=m.header(s), pose=m.pose(robots[k, i], None))
                for k, s in enumerate(stamps)
            ]
            msg = T["nav_msgs/msg/Path"](header=m.header(ns0), poses=poses)
            w.write(conns[f"/tmr/{name}/path"], ns0, ser(msg, TOPIC_TYPES["path"]))
        P = T["trajectory_msgs/msg/MultiDOFJointTrajectoryPoint"]
        points = [
            P(
                transforms=[m.transform(robots[k, i], None) for i in range(n)],
                velocities=[],
                accelerations=[],
                time_from_start=m.duration(s - ns0),
            )
            for k, s in enumerate(stamps)
        ]
        traj = T["trajectory_msgs/msg/MultiDOFJointTrajectory"](header=m.header(ns0), joint_names=names, points=points)
        w.write(conns["/tmr/team/trajectory"], ns0, ser(traj, TOPIC_TYPES["trajectory"]))
        TS = T["geometry_msgs/msg/TransformStamped"]
        from tqdm import tqdm

        for k, s in enumerate(tqdm(stamps, desc="bag samples", unit="sample", leave=False, disable=not progress)):
            for i, name in enumerate(names):
                msg = T["geometry_msgs/msg/PoseStamped"](header=m.header(s), pose=m.pose(robots[k, i], None))
                w.write(conns[f"/tmr/{name}/pose"], s, ser(msg, TOPIC_TYPES["pose"]))
            lines = [m.marker(s, "tether", j, "LINE_STRIP", "tether", (0.03, 0, 0), curves[k, j]) for j in range(n)]
            w.write(conns["/tmr/lines"], s, ser(MA(markers=lines), TOPIC_TYPES["markers"]))
            bodies = [
                m.marker(s, "bodies", i, "SPHERE", roles[i], (d, d, d), pose=(robots[k, i], None)) for i in range(n)
            ]
            w.write(conns["/tmr/bodies"], s, ser(MA(markers=bodies), TOPIC_TYPES["markers"]))
            tfs = [
                TS(header=m.header(s), child_frame_id=name, transform=m.transform(robots[k, i], None))
                for i, name in enumerate(names)
            ]
            w.write(conns["/tf"], s, ser(T["tf2_msgs/msg/TFMessage"](transforms=tfs), TOPIC_TYPES["tf"]))
    return path
