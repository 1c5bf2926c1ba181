"""Physics replay of a tethered-chain plan (Caruso 2021) in MuJoCo: model builder and runner.

The model (``formulations/replay.md``): the floor; walls round the room; the plan's raw obstacles extruded into
convex prisms (:mod:`tmr.replay.world`); the fixed anchor at its height; N robots, each a cylinder of the plan's
robot radius on two slides (x, y) and a hinge (yaw), driven by force-limited actuators that track the planned
trajectory (feed-forward of mass × reference acceleration and of the planned tethers' horizontal pull, plus PD
feedback); N tethers (:mod:`tmr.replay.tether`), tether j leaving robot j's winch at the exit height and held at
robot j-1's exit point (the anchor for j = 1). Differential-drive robots (``wheels=``, :mod:`tmr.replay.wheels`) are
instead chassis on two driven wheels and two casters, the tether leaving at the exit point ahead of the axle.

:func:`replay_chain` steps the model over the plan and records, at every plan sample, the robots' positions, each
tether's lowest point, paid-out length and end tensions next to the static catenary of the same ends
(:func:`tmr.model.catenary.solve`), and every contact of the physics steps (tether-obstacle, tether-floor,
robot-obstacle, robot-robot).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray

from tmr.replay.errors import ReplayError
from tmr.replay.tether import TETHER_RADIUS, TetherSpec, TetherState, tether_body_xml, tether_extra_xml
from tmr.replay.timing import RealTimeFactors
from tmr.replay.world import OBSTACLE_HEIGHT, ROBOT_BITS, TETHER_BITS, world_xml

Array = NDArray[np.float64]

__all__ = ["ChainReplay", "ReplayConfig", "build_chain_model", "replay_chain"]


#: The most links per tether (``--links``): a tether of 1000 links already takes minutes to simulate.
MAX_LINKS = 1000


@dataclass(frozen=True)
class ReplayConfig:
    """Choices of the replay (``formulations/replay.md`` gives the reasons). Units: m, kg, N, s.

    Attributes:
        n_links: links per tether (16: lowest point, length and end tensions of the static catenary within 1e-3
            relative, ``tests/test_replay_tether.py``).
        timestep: physics step [s] (implicit-in-velocity integrator ``implicitfast``).
        robot_mass: mass of a robot [kg] (not in Caruso 2021; a small ground robot).
        robot_height: height of the robot cylinder [m] (below the tether exit).
        frequency: closed-loop natural frequency of the robots' position loops [Hz]; kp = m ω², kv = 2 ζ m ω.
        damping_ratio: ζ of the position loops.
        force_limit: actuator force bound per axis [N].
        track: "filtered" (the low-passed trajectories a robot is given, default) or "raw" (the planner's).
        tolerance: tracking error beyond which the replay fails [m] (0.05 = the plan's clearance margin d_safe).
        winch: "horizontal" (the winch holds the horizontal tension T0, the planner's assumption) or "torque"
            (it holds the tension at the winch end at T0).
        obstacle_height: height of the extruded obstacles [m].
        settle: extra simulated time after the plan's last sample [s].
    """

    n_links: int = 16
    timestep: float = 0.005
    robot_mass: float = 10.0
    robot_height: float = 0.35
    frequency: float = 2.0
    damping_ratio: float = 1.0
    force_limit: float = 100.0
    track: str = "filtered"
    tolerance: float = 0.05
    winch: str = "horizontal"
    obstacle_height: float = OBSTACLE_HEIGHT
    settle: float = 0.0

    def __post_init__(self) -> None:
        if not 1 <= self.n_links <= MAX_LINKS:  # refused before a model of 10**23 bodies is built
            raise ReplayError(f"--links must be 1 … {MAX_LINKS} links per tether, got {self.n_links}")

    @property
    def kp(self) -> float:
        w = 2 * math.pi * self.frequency
        return self.robot_mass * w * w

    @property
    def kv(self) -> float:
        return 2 * self.damping_ratio * self.robot_mass * 2 * math.pi * self.frequency


@dataclass
class ChainModel:
    """A compiled chain model: MuJoCo model, the tethers' states, and index maps."""

    model: Any
    xml: str
    tethers: list[TetherState]
    robot_q: NDArray[np.int64]  # (N, 3) qpos addresses of x, y, yaw
    robot_act: NDArray[np.int64]  # (N, 3) actuator ids x, y, yaw (wheeled robots: (N, 2) left, right wheel)
    start: Array  # (N, 2) robot positions at qpos0 [m]
    geom_kind: NDArray[np.int64]  # 0 floor, 1 obstacle/wall, 2 tether, 3 robot, -1 other
    geom_owner: NDArray[np.int64]  # tether or robot index (0-based) of a geom
    geom_names: list[str]


@dataclass
class ChainReplay(RealTimeFactors):
    """What a replay measured (arrays per plan sample k; tethers j = 0..N-1, robots i = 0..N-1). Units: m, N, s."""

    t: Array
    reference: Array  # (K, N, 2) tracked reference
    actual: Array  # (K, N, 2)
    tracking_error: Array  # (K, N)
    lowest: Array  # (K, N) lowest node height of each tether
    lowest_catenary: Array  # (K, N) static catenary's lowest point for the same ends
    span: Array  # (K, N) horizontal span of each tether
    length: Array  # (K, N) paid-out length
    length_catenary: Array
    tension_winch: Array  # (K, N) tension at the winch end (robot j)
    tension_far: Array  # (K, N) tension at the far end (robot j-1 / anchor)
    tension_winch_catenary: Array
    tension_far_catenary: Array
    contacts: dict[str, dict[str, Any]]
    nodes: list[Array]  # per sample, (N, n_links+1, 3) tether nodes (for figures and the GIF)
    sim_time: float
    wall_time: float
    cpu_time: float
    steps: int
    diverged: str | None = None
    config: ReplayConfig = field(default_factory=ReplayConfig)
    qpos: list[Array] = field(default_factory=list)  # per sample, the full MuJoCo state (for the GIF)
    built: ChainModel | None = None
    #: (K, N) the simulated cable's least height above the top of a low obstacle it hangs over [m] (+inf: over
    #: none); None without low obstacles (:func:`low_obstacle_gaps`)
    low_gap: Array | None = None
    #: wheeled robots (:mod:`tmr.replay.wheels`): what the wheels did; None for the omnidirectional bodies
    wheels: Any = None


#: simulated time at the start pose before the plan's first sample [s] (lets the constraint forces settle).
WARMUP = 0.25

CONTACT_KINDS = ("robot-obstacle", "robot-robot", "tether-obstacle", "tether-floor")


def build_chain_model(run: Any, cfg: ReplayConfig, track: Array | None = None, wheels: Any = None) -> ChainModel:
    """Compile the MuJoCo model of a :class:`tmr.io.rundir.ChainRun` (robots start at the tracked trajectory's first
    sample, yaw 0); ``wheels``: a :class:`tmr.replay.wheels.WheelSetup` for differential-drive robots on wheels
    (chassis at the start axle and heading, tethers from the exit points), None for the omnidirectional bodies."""
    import mujoco

    rec = run.record
    teth = rec["tether"]
    params = run.catenary_params()
    traj = run.filtered if track is None else track
    start = np.asarray(traj[0], dtype=float)
    n = start.shape[0]
    H, Hb = float(teth["exit_height"]), float(teth["anchor_height"])
    r = run.robot_radius
    anchor = [float(run.anchor[0]), float(run.anchor[1]), Hb]
    sl = start.tolist()
    assets, world, _ = world_xml(run.obstacles, run.bounds, cfg.obstacle_height)
    for o, low in enumerate(getattr(run, "low_obstacles", ())):  # extruded to their own height: a tether may pass over
        pieces = list(shapely.get_parts(low.footprint))
        a_low, w_low, _ = world_xml(pieces, run.bounds, low.height, prefix=f"obs_low{o}_", floor_and_walls=False)
        assets, world = assets + a_low, world + w_low
    rt, ra = ROBOT_BITS
    specs = []
    for j in range(n):
        root_world = (sl[j][0], sl[j][1], H)
        root_local = (0.0, 0.0, H)
        if wheels is not None:  # the exit point, b ahead of the axle at the start heading (chassis frame world-aligned)
            b, th0 = wheels.config.model.exit_offset, float(wheels.start_theta[j])
            root_local = (b * math.cos(th0), b * math.sin(th0), H)
        far_world = tuple(anchor) if j == 0 else (sl[j - 1][0], sl[j - 1][1], H)
        specs.append(
            TetherSpec(
                name=f"t{j + 1}",
                n_links=cfg.n_links,
                root_body=f"r{j + 1}",
                root_local=root_local,
                root_world=root_world,
                end_body="world" if j == 0 else f"r{j}",
                end_world=far_world,  # type: ignore[arg-type]
                params=params,
                contype=TETHER_BITS[0],
                conaffinity=TETHER_BITS[1],
            )
        )
    bodies = []
    hz = cfg.robot_height / 2
    izz = 0.5 * cfg.robot_mass * r * r
    for i in range(n if wheels is None else 0):
        bodies.append(
            f'<body name="r{i + 1}" pos="{sl[i][0]!r} {sl[i][1]!r} 0">'
            f'<joint name="r{i + 1}_x" type="slide" axis="1 0 0"/>'
            f'<joint name="r{i + 1}_y" type="slide" axis="0 1 0"/>'
            f'<joint name="r{i + 1}_yaw" type="hinge" axis="0 0 1"/>'
            f'<inertial pos="0 0 {hz + 0.05!r}" mass="{cfg.robot_mass!r}" diaginertia="{izz!r} {izz!r} {izz!r}"/>'
            f'<geom name="r{i + 1}_body" type="cylinder" size="{r!r} {hz!r}" pos="0 0 {hz + 0.05!r}" '
            f'contype="{rt}" conaffinity="{ra}" rgba="0.15 0.35 0.75 0.55" solref="0.01 1" '
            f'solimp="0.99 0.9999 0.0005 0.5 2"/>'
            f'<geom type="cylinder" size="0.03 {H / 2!r}" pos="0 0 {H / 2!r}" contype="0" conaffinity="0" '
            f'rgba="0.2 0.2 0.2 1"/>' + tether_body_xml(specs[i]) + "</body>"
        )
    if wheels is not None:
        bodies = [wheels.body_xml(i, H, cfg.robot_height, tether_body_xml(specs[i])) for i in range(n)]
    extras = [tether_extra_xml(s) for s in specs]
    kp, kv, fl = cfg.kp, cfg.kv, cfg.force_limit
    acts = [] if wheels is None else [wheels.actuator_xml(i) for i in range(n)]
    for i in range(n if wheels is None else 0):
        for ax in ("x", "y"):
            acts.append(
                f'<general name="r{i + 1}_a{ax}" joint="r{i + 1}_{ax}" gainprm="{kp!r}" biastype="affine" '
                f'biasprm="0 {-kp!r} {-kv!r}" '
                f'forcelimited="true" forcerange="{-fl!r} {fl!r}"/>'
            )
        kyaw = izz * (2 * math.pi * cfg.frequency) ** 2
        dyaw = 2 * izz * 2 * math.pi * cfg.frequency
        acts.append(
            f'<general name="r{i + 1}_ayaw" joint="r{i + 1}_yaw" gainprm="{kyaw!r}" biastype="affine" '
            f'biasprm="0 {-kyaw!r} {-dyaw!r}" '
            f'forcelimited="true" forcerange="{-fl!r} {fl!r}"/>'
        )
    g = float(teth["g"])
    xml = (
        '<mujoco model="tmr-replay-chain"><compiler angle="radian"/>'
        f'<option timestep="{cfg.timestep!r}" integrator="implicitfast" gravity="0 0 {-g!r}"/>'
        '<visual><global offwidth="960" offheight="720"/><quality shadowsize="2048"/></visual>'
        f"<asset>{assets}</asset><worldbody>"
        '<light pos="0 0 12" dir="0 0 -1" directional="true" diffuse="0.7 0.7 0.7"/>'
        f"{world}"
        f'<site name="anchor" pos="{anchor[0]!r} {anchor[1]!r} {Hb!r}" size="0.05" rgba="0 0 0 1"/>'
        f'<geom type="box" pos="{anchor[0]!r} {anchor[1]!r} {Hb / 2!r}" size="0.08 0.08 {Hb / 2!r}" contype="0" '
        f'conaffinity="0" rgba="0.1 0.1 0.1 1"/>' + "".join(bodies) + "</worldbody>"
        "<equality>" + "".join(e["equality"] for e in extras) + "</equality>"
        "<tendon>" + "".join(e["tendon"] for e in extras) + "</tendon>"
        "<actuator>" + "".join(acts) + "".join(e["actuator"] for e in extras) + "</actuator>"
        "<sensor>" + "".join(e["sensor"] for e in extras) + "</sensor></mujoco>"
    )
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:
        raise ReplayError(f"MuJoCo could not compile the replay model: {exc}") from None
    tethers = [TetherState(model, s, cfg.winch) for s in specs]

    def jq(name: str) -> int:
        return int(model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)])

    def aid(name: str) -> int:
        return int(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name))

    robot_q = np.array([[jq(f"r{i + 1}_{a}") for a in ("x", "y", "yaw")] for i in range(n)])
    axes = ("x", "y", "yaw") if wheels is None else ("l", "r")
    robot_act = np.array([[aid(f"r{i + 1}_a{a}") for a in axes] for i in range(n)])
    kinds = np.full(model.ngeom, -1)
    owner = np.full(model.ngeom, -1)
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, k) or "" for k in range(model.ngeom)]
    for k, nm in enumerate(names):
        if nm == "floor":
            kinds[k] = 0
        elif nm.startswith(("obs", "wall_")):
            kinds[k] = 1
        elif nm.startswith("t") and "_g" in nm:
            kinds[k], owner[k] = 2, int(nm[1:].split("_")[0]) - 1
        elif nm.startswith("r") and nm.endswith("_body"):
            kinds[k], owner[k] = 3, int(nm[1:].split("_")[0]) - 1
    return ChainModel(model, xml, tethers, robot_q, robot_act, start, kinds, owner, names)


def _reference(t: Array, traj: Array, times: Array) -> tuple[Array, Array, Array]:
    """Position, velocity, acceleration of the tracked trajectory at ``times`` (C² cubic spline through the plan's
    samples, zero end slopes: the plan starts and ends at rest)."""
    from scipy.interpolate import CubicSpline

    sp = CubicSpline(t, traj, axis=0, bc_type="clamped")
    tt = np.clip(times, t[0], t[-1])
    return sp(tt), sp(tt, 1), sp(tt, 2)


def _contact_kind(k1: int, k2: int) -> str | None:
    pair = {k1, k2}
    if pair == {2, 0}:
        return "tether-floor"
    if pair == {2, 1}:
        return "tether-obstacle"
    if pair == {3, 1}:
        return "robot-obstacle"
    if pair == {3}:
        return "robot-robot"
    return None


def replay_chain(run: Any, cfg: ReplayConfig | None = None, progress: Any = None, wheels: Any = None) -> ChainReplay:
    """Simulate the run's plan in MuJoCo and measure it (see the module docstring).

    Args:
        run: a :class:`tmr.io.rundir.ChainRun`.
        cfg: replay choices.
        progress: optional callable(fraction) called every plan sample.
        wheels: a :class:`tmr.replay.wheels.WheelConfig`: differential-drive robots on two wheels and casters
            (:mod:`tmr.replay.wheels`) instead of the omnidirectional bodies; their report is ``ChainReplay.wheels``.
    """
    import mujoco

    cfg = cfg or ReplayConfig()
    if cfg.track not in ("filtered", "raw"):
        raise ReplayError(f"track must be 'filtered' or 'raw', got {cfg.track!r}")
    traj = run.filtered if cfg.track == "filtered" else run.robots
    setup = None
    if wheels is not None:
        from tmr.replay.wheels import WheelSetup, wheel_reference

        t_ = np.asarray(run.t, dtype=float)
        Ts_ = float(run.record["Ts"])
        sub_ = max(1, int(round(Ts_ / cfg.timestep)))
        K_ = t_.size + int(round(cfg.settle / Ts_))
        times_ = t_[0] + np.arange((K_ - 1) * sub_ + 1) * cfg.timestep
        wref = wheel_reference(run, wheels, t_, times_, traj)
        setup = WheelSetup(wheels, cfg.robot_mass, wref.axle[0].copy(), wref.theta[0].copy(), wref)
        traj = np.concatenate([wref.exit[:1], np.asarray(traj)[1:]], axis=0)  # the tethers leave the exit points
    cm = build_chain_model(run, cfg, traj, wheels=setup)
    m = cm.model
    d = mujoco.MjData(m)
    n = traj.shape[1]
    H = float(run.record["tether"]["exit_height"])
    Hb = float(run.record["tether"]["anchor_height"])
    anchor3 = np.array([run.anchor[0], run.anchor[1], Hb])
    for j, ts in enumerate(cm.tethers):
        root = np.array([cm.start[j, 0], cm.start[j, 1], H])
        far = anchor3 if j == 0 else np.array([cm.start[j - 1, 0], cm.start[j - 1, 1], H])
        ts.set_initial(d, root, far)
    mujoco.mj_kinematics(m, d)  # node positions for the winch law
    for ts in cm.tethers:
        ts.update(m, d)
    mujoco.mj_forward(m, d)

    t = np.asarray(run.t, dtype=float)
    Ts = float(run.record["Ts"])
    sub = max(1, int(round(Ts / cfg.timestep)))
    if abs(sub * cfg.timestep - Ts) > 1e-9 * Ts:
        raise ReplayError(f"the physics step {cfg.timestep} s must divide the plan's sample time Ts = {Ts} s")
    n_settle = int(round(cfg.settle / Ts))
    K = t.size + n_settle
    times = t[0] + np.arange((K - 1) * sub + 1) * cfg.timestep
    p_ref, v_ref, a_ref = _reference(t, traj, times)
    T0 = float(run.record["tether"]["horizontal_tension"])
    # the tension each winch holds at every physics step: T0, or an active winch's plan (linear between its samples,
    # its last value while the chain settles)
    planned = getattr(run, "winch_tension", None)
    if planned is None:
        tension = np.full((len(times), n), T0)
    else:
        tt = np.clip(times, t[0], t[-1])
        tension = np.column_stack([np.interp(tt, t, planned[:, j]) for j in range(n)])
    kp, kv, mass = cfg.kp, cfg.kv, cfg.robot_mass

    contacts: dict[str, dict[str, Any]] = {
        kind: {"count": 0, "first_time": None, "where": None, "between": None, "max_depth": 0.0}
        for kind in CONTACT_KINDS
    }
    rec_actual = np.zeros((K, n, 2))
    rec_nodes: list[Array] = []
    rec_qpos: list[Array] = []
    rec_len = np.zeros((K, n))
    rec_tw = np.zeros((K, n))
    rec_tf = np.zeros((K, n))
    ax_ids = cm.robot_act[:, :2]
    yaw_ids = cm.robot_act[:, 2] if setup is None else cm.robot_act[:, :0]
    rq = cm.robot_q
    diverged = None
    drv = None
    if setup is not None:
        from tmr.replay.wheels import WheelDriver

        drv = WheelDriver.build(setup, m)
        rec_axle = np.zeros((K, n, 2))
        rec_theta = np.zeros((K, n))

    def record(k: int) -> None:
        if drv is None:
            rec_actual[k] = cm.start + d.qpos[rq[:, :2]]
        else:
            rec_actual[k] = drv.exit(d)
            rec_axle[k], rec_theta[k] = drv.pose(d)
        rec_nodes.append(np.stack([ts.nodes(d) for ts in cm.tethers]))
        rec_qpos.append(np.array(d.qpos))
        for j, ts in enumerate(cm.tethers):
            rec_len[k, j] = ts.length(d)
            rec_tw[k, j] = ts.root_tension(d)
            rec_tf[k, j] = ts.end_tension(d)

    # actuator commands of every physics step: reference + feed-forward (mass × acceleration, minus the planned pull
    # of the tethers: the held tension along each tether's chord)
    prev = np.concatenate([np.broadcast_to(run.anchor, (len(times), 1, 2)), p_ref[:, :-1]], axis=1)
    chord = prev - p_ref  # tether j pulls robot j towards robot j-1 (or the anchor) ...
    unit = chord / np.maximum(np.linalg.norm(chord, axis=2, keepdims=True), 1e-9)
    pull = tension[:, :, None] * unit
    pull[:, :-1] -= tension[:, 1:, None] * unit[:, 1:]  # ... and robot j-1 towards robot j
    u_ref = (p_ref - cm.start) + (kv * v_ref + mass * a_ref - pull) / kp
    u_hold = (p_ref[0] - cm.start) - pull[0] / kp  # at rest at the start pose
    if planned is not None:  # the winches start at the plan's first tension
        for j, ts in enumerate(cm.tethers):
            ts.t0 = float(tension[0, j])
    # warm-up at the start pose (not recorded): the soft constraints build up the cable's static forces
    for _ in range(int(round(WARMUP / cfg.timestep))):
        if drv is None:
            d.ctrl[ax_ids] = u_hold
            d.ctrl[yaw_ids] = 0.0
        else:
            drv.hold(d)
        for ts in cm.tethers:
            ts.update(m, d)
        mujoco.mj_step(m, d)
    d.time = 0.0
    wall0, cpu0 = time.perf_counter(), time.process_time()
    record(0)
    step = 0
    for k in range(1, K):
        for _ in range(sub):
            if drv is None:
                d.ctrl[ax_ids] = u_ref[step]
                d.ctrl[yaw_ids] = 0.0
            else:
                drv.command(d, step)
            if planned is not None:
                for j, ts in enumerate(cm.tethers):
                    ts.t0 = float(tension[step, j])
            for ts in cm.tethers:
                ts.update(m, d)
            mujoco.mj_step(m, d)
            step += 1
            if drv is not None:
                drv.measure(d, times[step])
            if d.ncon:
                _log_contacts(d, cm, contacts, times[step])
        if not np.all(np.isfinite(d.qpos)) or d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:
            diverged = f"the simulation diverged at t = {times[step]:.3f} s (non-finite accelerations)"
            rec_actual = rec_actual[:k]
            break
        record(k)
        if progress is not None:
            progress(k / (K - 1))
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    K = rec_actual.shape[0]
    ref_k = np.asarray(p_ref[::sub][:K]) if setup is None else setup.reference.exit[::sub][:K]
    wheel_report = None
    if drv is not None:
        wheel_report = _wheel_report(setup, drv, rec_axle[:K], rec_theta[:K], sub, cfg.timestep)
    nodes = rec_nodes[:K]
    lowest = np.array([[float(tn[:, 2].min()) for tn in nd] for nd in nodes])
    root = np.array([[tn[0] for tn in nd] for nd in nodes])  # (K, N, 3) winch exits
    far = np.array([[tn[-1] for tn in nd] for nd in nodes])
    span = np.hypot(*(far - root)[..., :2].transpose(2, 0, 1))
    cat = _static_catenary(root[..., 2], far[..., 2], np.maximum(span, 1e-6), run.catenary_params(), tension[::sub][:K])
    return ChainReplay(
        t=t[0] + np.arange(K) * Ts,
        reference=ref_k,
        actual=rec_actual,
        tracking_error=np.linalg.norm(rec_actual - ref_k, axis=2),
        lowest=lowest,
        lowest_catenary=np.asarray(cat.z_min, dtype=float),
        span=span,
        length=rec_len[:K],
        length_catenary=np.asarray(cat.length, dtype=float),
        tension_winch=rec_tw[:K],
        tension_far=rec_tf[:K],
        tension_winch_catenary=np.asarray(cat.tension_1, dtype=float),
        tension_far_catenary=np.asarray(cat.tension_2, dtype=float),
        contacts=contacts,
        nodes=nodes,
        sim_time=float(step * cfg.timestep),
        wall_time=wall,
        cpu_time=cpu,
        steps=step,
        diverged=diverged,
        config=cfg,
        qpos=rec_qpos[:K],
        built=cm,
        low_gap=low_obstacle_gaps(nodes, run.low_obstacles) if getattr(run, "low_obstacles", None) else None,
        wheels=wheel_report,
    )


def _wheel_report(setup: Any, drv: Any, axle: Array, theta: Array, sub: int, dt: float) -> Any:
    """The :class:`tmr.replay.wheels.WheelReport` of a wheeled replay (per plan sample: the physics step's pose
    against the reference of the same instant)."""
    from tmr.replay.wheels import WheelReport

    ref = setup.reference
    K = axle.shape[0]
    c_ref, th_ref = ref.axle[::sub][:K], ref.theta[::sub][:K]
    return WheelReport(
        config=setup.config,
        axle=axle,
        theta=theta,
        axle_reference=c_ref,
        theta_reference=th_ref,
        axle_error=np.linalg.norm(axle - c_ref, axis=2),
        heading_error=np.abs(np.angle(np.exp(1j * (theta - th_ref)))),
        lateral_demand=np.abs(ref.lateral[::sub][:K]),
        peak_wheel=drv.peak_wheel,
        peak_wheel_at=drv.peak_wheel_at,
        peak_cmd=drv.peak_cmd,
        saturated_time=drv.saturated_steps * dt,
        peak_slip=drv.peak_slip,
        peak_slip_at=drv.peak_slip_at,
    )


def low_obstacle_gaps(nodes: list[Array], low_obstacles: Any, per_link: int = 4) -> Array:
    """(K, N) the least height [m] of each simulated tether above the top of a low obstacle it hangs over, per
    sample (+inf where it hangs over none): the tether's node polyline, ``per_link`` points along each link, tested
    against every footprint in plan view (shapely), the underside of its capsules (height − ``TETHER_RADIUS``) minus
    the obstacle's height. The planner keeps ≥ the
    clearance (5 cm) on its static catenary; this is what the physics makes of it."""
    import shapely

    nd = np.asarray(nodes, dtype=float)  # (K, N, n+1, 3)
    K, N, n1 = nd.shape[:3]
    s = np.arange(per_link) / per_link
    pts = nd[:, :, :-1, None, :] + s[None, None, None, :, None] * np.diff(nd, axis=2)[:, :, :, None, :]
    pts = np.concatenate([pts.reshape(K, N, -1, 3), nd[:, :, -1:, :]], axis=2)  # (K, N, M, 3)
    gap = np.full((K, N), np.inf)
    for o in low_obstacles:
        over = shapely.contains_xy(o.footprint, pts[..., 0], pts[..., 1])
        z = np.where(over, pts[..., 2] - TETHER_RADIUS - float(o.height), np.inf)  # the capsule's underside
        gap = np.minimum(gap, z.min(axis=2))
    return gap


def _static_catenary(h1: Array, h2: Array, span: Array, params: Any, tension: Array) -> Any:
    """The planner's static catenary of every sample and tether (K, N), at the tension the winch held then (T0, or an
    active winch's planned tension per sample)."""
    from tmr.model.catenary import solve

    held = None if np.all(tension == params.horizontal_tension) else tension
    return solve(h1, h2, span, params, tension=held)


def _log_contacts(
    d: Any,
    cm: Any,
    contacts: dict[str, dict[str, Any]],
    now: float,
    kind_of: Any = None,
    label: Any = None,
) -> None:
    """Log the penetrating contacts of this physics step by kind (``kind_of(kind1, kind2)`` of two geom kinds, the
    chain's by default; ``label(model, geom)`` names a geom); ``cm`` has ``geom_kind``, ``geom_owner``,
    ``geom_names`` (a :class:`ChainModel` or the drone replay's model)."""
    kind_of = kind_of or _contact_kind
    label = label or _label
    seen: set[str] = set()
    for c in _iter_contacts(d):
        g1, g2, dist, pos = c
        kind = kind_of(int(cm.geom_kind[g1]), int(cm.geom_kind[g2]))
        if kind is None or dist > 0:
            continue
        entry = contacts[kind]
        entry["max_depth"] = max(entry["max_depth"], float(-dist))
        if kind in seen:
            continue
        seen.add(kind)
        entry["count"] += 1
        if entry["first_time"] is None:
            entry["first_time"] = float(now)
            entry["where"] = [float(v) for v in pos]
            first, second = (g1, g2) if cm.geom_kind[g1] >= cm.geom_kind[g2] else (g2, g1)  # the mover first
            entry["between"] = [label(cm, first), label(cm, second)]


def _iter_contacts(d: Any) -> Any:
    n = d.ncon
    con = d.contact
    g1, g2, dist, pos = con.geom1[:n], con.geom2[:n], con.dist[:n], con.pos[:n]
    for i in range(n):
        yield int(g1[i]), int(g2[i]), float(dist[i]), pos[i]


def _label(cm: ChainModel, g: int) -> str:
    kind, owner = int(cm.geom_kind[g]), int(cm.geom_owner[g])
    if kind == 2:
        return f"tether {owner + 1}"
    if kind == 3:
        return f"robot {owner + 1}"
    return cm.geom_names[g] or f"geom {g}"
