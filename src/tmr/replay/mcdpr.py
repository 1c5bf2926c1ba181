"""Physics replay of a MoPICK plan (Rasheed 2019) in MuJoCo: bases on wheels, winched cables, a point-mass platform.

Model (``formulations/replay.md``): each base is a free body (mass and centre of gravity of the robot file) standing
on its footprint's wheel contact points (small spheres, frictionless: the drive is modelled as a planar force at the
ground, so only the cables and gravity can tip it); a mast carries the cable exit point. Each cable is a massless
spatial tendon from its exit point to the platform with a motor (the winch) that can only pull, 0 ≤ t ≤ t_max. The
platform is a point mass on three slides. The external wrench of the scene is applied to the platform, visiting
the corners of its box in turn (:data:`EXTERNAL_PERIOD` seconds each).

Control: the bases track their planned paths (PD + feed-forward of m a and of the cable pull, force-limited);
the platform controller asks the cables for f = m_p (a_ref + PID on the position error) + m_p g and distributes it
with tmr's tension distribution (:func:`tmr.mcdpr.tension.closed_form_batch`, tensions in [t_min, t_max], *not*
tightened by tipping: tipping is what the physics shows); when no tension in the bounds gives f, the bounded
least-squares tensions (scipy ``lsq_linear``) are used and the sample is marked.

The plan has samples, not times: the replay moves along them at :data:`SPEED` (the fastest base or the platform),
a documented choice.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.replay.errors import ReplayError
from tmr.replay.timing import RealTimeFactors
from tmr.replay.world import world_xml

Array = NDArray[np.float64]

__all__ = ["McdprConfig", "McdprReplay", "mcdpr_summary", "replay_mcdpr", "write_mcdpr_outputs"]

#: travel speed of the fastest moving part along the plan [m/s] (documented choice; the paper gives no times).
SPEED = 0.15
#: seconds each corner of the external wrench box is applied.
EXTERNAL_PERIOD = 2.0
#: height of the tables (Rasheed 2019 Fig. 2 scene: table tops 0.7 m) and of the other obstacles [m].
TABLE_HEIGHT = 0.7
WHEEL_RADIUS = 0.03
#: standard deviation of the Gaussian smoothing of the plan's samples [samples] (see :class:`_Reference`).
SMOOTHING = 2.0
#: period at which the controller refreshes the tipping-tightened tension bounds [s].
BOUNDS_PERIOD = 0.1
#: period of the controllers (bases, platform, winches) [s]: 100 Hz, zero-order hold between updates.
CONTROL_PERIOD = 0.01


@dataclass(frozen=True)
class McdprConfig:
    """Replay choices (units: m, s, N). Gains as natural frequency [Hz] and damping ratio of each loop."""

    timestep: float = 0.005
    sample: float = 0.05
    base_frequency: float = 2.0
    platform_frequency: float = 3.0
    platform_integral: float = 2.0  # integral gain as a fraction of ω [1/s per rad/s]
    damping_ratio: float = 1.0
    base_force_limit: float = 200.0
    tolerance: float = 0.05
    settle: float = 1.0
    external: bool = True


@dataclass
class McdprReplay(RealTimeFactors):
    """What a MoPICK replay measured, per recorded sample (every ``config.sample`` s)."""

    t: Array
    platform_ref: Array  # (K, 3)
    platform: Array  # (K, 3)
    platform_error: Array  # (K,)
    bases_ref: Array  # (K, p, 2)
    bases: Array  # (K, p, 2)
    base_tilt: Array  # (K, p) tilt of each base from the vertical [rad]
    tensions: Array  # (K, m) cable tensions applied [N]
    tensions_plan: Array  # (K, m) tmr.mcdpr.tension's distribution for the planned pose and weight [N]
    tension_infeasible: NDArray[np.bool_]  # (K,) no tension in [t_min, t_max] gave the controller's wrench
    wheel_force: Array  # (K, p, c) normal force on every wheel [N]
    external: Array  # (K, 3) external force applied to the platform [N]
    contacts: dict[str, dict[str, Any]]
    sim_time: float
    wall_time: float
    cpu_time: float
    steps: int
    verdict: Any = None
    config: McdprConfig = field(default_factory=McdprConfig)
    qpos: list[Array] = field(default_factory=list)
    model: Any = None
    diverged: str | None = None


class _Reference:
    """References of the bases, headings and platform at any time [s].

    The samples are a geometric path, smoothed first (:data:`SMOOTHING`); a C² cubic spline in the path
    parameter s (the cumulative largest displacement of any base or the platform, [m]) passes through them; each
    way-point segment of the plan is then timed with a minimum-jerk law s(t) whose peak speed is :data:`SPEED`
    (duration 1.875 L / SPEED, at least 0.5 s),
    so the system starts and stops at rest at every way-point.
    """

    def __init__(self, bases: Array, headings: Array, platform: Array, segment: NDArray[np.int64]) -> None:
        from scipy.interpolate import CubicSpline
        from scipy.ndimage import gaussian_filter1d

        # the samples alternate base steps and platform steps (Rasheed 2019's two stages); executed together, they
        # are smoothed along the sample index (Gaussian, SMOOTHING samples) before timing
        bases = gaussian_filter1d(bases, SMOOTHING, axis=0, mode="nearest")
        platform = gaussian_filter1d(platform, SMOOTHING, axis=0, mode="nearest")
        headings = gaussian_filter1d(np.unwrap(headings, axis=0), SMOOTHING, axis=0, mode="nearest")
        step = np.maximum(
            np.linalg.norm(np.diff(bases, axis=0), axis=2).max(axis=1),
            np.linalg.norm(np.diff(platform, axis=0), axis=1),
        )
        keep = np.r_[True, step > 1e-12]
        s = np.r_[0.0, np.cumsum(step)][keep]
        b, h, P, seg = bases[keep], headings[keep], platform[keep], segment[keep]
        self.static = s.size < 2
        self.b0, self.h0, self.P0 = bases[0], headings[0], platform[0]
        if self.static:
            self.T = 0.0
            return
        self.sb = CubicSpline(s, b, axis=0)
        self.sh = CubicSpline(s, h, axis=0)
        self.sp = CubicSpline(s, P, axis=0)
        bounds = [0]
        for k in range(1, len(seg)):
            if seg[k] != seg[k - 1]:
                bounds.append(k)
        bounds.append(len(s) - 1)
        bounds = sorted(set(bounds))
        self.s_knots = s[bounds]
        L = np.diff(self.s_knots)
        self.durations = np.maximum(1.875 * L / SPEED, 0.5)
        self.t_knots = np.r_[0.0, np.cumsum(self.durations)]
        self.T = float(self.t_knots[-1])

    def __call__(self, t: float) -> tuple[Array, Array, Array, Array, Array, Array, Array]:
        """(bases, base velocities, base accelerations, headings, platform, its velocity, its acceleration)."""
        z2, z3 = np.zeros_like(self.b0), np.zeros(3)
        if self.static:
            return self.b0, z2, z2, self.h0, self.P0, z3, z3
        t = min(max(t, 0.0), self.T)
        i = min(int(np.searchsorted(self.t_knots, t, side="right")) - 1, len(self.durations) - 1)
        T, L = self.durations[i], self.s_knots[i + 1] - self.s_knots[i]
        tau = (t - self.t_knots[i]) / T
        s = self.s_knots[i] + L * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
        sd = L * (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T
        sdd = L * (60 * tau - 180 * tau**2 + 120 * tau**3) / T**2
        b1, b2 = self.sb(s, 1), self.sb(s, 2)
        p1, p2 = self.sp(s, 1), self.sp(s, 2)
        return (
            self.sb(s),
            b1 * sd,
            b2 * sd * sd + b1 * sdd,
            self.sh(s),
            self.sp(s),
            p1 * sd,
            p2 * sd * sd + p1 * sdd,
        )


def _model_xml(robot: Any, scene: Any, start: tuple[Array, Array, Array], cfg: McdprConfig) -> str:
    """MJCF of the MoPICK scene with the bases and the platform at ``start`` = (bases (p, 2), headings (p,),
    platform (3,)) [m, rad]."""
    from tmr.replay.world import ROBOT_BITS

    g = robot.gravity
    tables = [t for t in scene.tables]
    obstacles = [o for o in scene.obstacles]
    a1, w1, _ = world_xml(tables, scene.bounds, TABLE_HEIGHT, prefix="table")
    a2, w2, _ = world_xml(obstacles, scene.bounds, 1.0, prefix="obs", floor_and_walls=False)
    # wheels roll: no friction between them and the floor (MuJoCo takes the larger condim and friction of a pair, so
    # the floor must be frictionless too, else the fixed wheel spheres drag with the floor's friction 1)
    w1 = w1.replace('<geom name="floor" ', '<geom name="floor" condim="1" ', 1)
    b0 = np.asarray(start[0], float).tolist()
    h0 = np.asarray(start[1], float).tolist()
    rt, ra = ROBOT_BITS
    r = float(robot.base_radius)
    cog = robot.cog.tolist()
    m = float(robot.base_mass)
    ixx = m * (3 * r * r + 0.6**2) / 12
    izz = m * r * r / 2
    bodies = []
    for j in range(robot.n_bases):
        wheels = "".join(
            f'<geom name="b{j + 1}_w{o + 1}" type="sphere" size="{WHEEL_RADIUS}" pos="{fx!r} {fy!r} {WHEEL_RADIUS}" '
            f'contype="0" conaffinity="1" condim="1" rgba="0.1 0.1 0.1 1" solref="0.01 1" '
            f'solimp="0.99 0.9999 0.0005 0.5 2"/>'
            for o, (fx, fy) in enumerate(robot.footprint.tolist())
        )
        exits = "".join(
            f'<site name="exit{k + 1}" pos="{ex!r} {ey!r} {ez!r}" size="0.02"/>'
            for k, (ex, ey, ez) in enumerate(robot.exit_points.tolist())
            if robot.cable_base[k] == j
        )
        top = float(robot.exit_points[:, 2].max())
        qz = f"{math.cos(h0[j] / 2)!r} 0 0 {math.sin(h0[j] / 2)!r}"
        bodies.append(
            f'<body name="b{j + 1}" pos="{b0[j][0]!r} {b0[j][1]!r} 0" quat="{qz}"><freejoint name="b{j + 1}_free"/>'
            f'<inertial pos="{cog[0]!r} {cog[1]!r} {cog[2]!r}" mass="{m!r}" diaginertia="{ixx!r} {ixx!r} {izz!r}"/>'
            f"{wheels}"
            f'<geom name="b{j + 1}_body" type="cylinder" size="{r!r} 0.1" pos="0 0 0.17" contype="{rt}" '
            f'conaffinity="{ra}" mass="0" rgba="0.15 0.35 0.75 0.8"/>'
            f'<geom type="cylinder" size="0.02 {top / 2!r}" pos="0 0 {top / 2!r}" contype="0" conaffinity="0" '
            f'mass="0" rgba="0.3 0.3 0.3 1"/>{exits}</body>'
        )
    p0 = np.asarray(start[2], float).tolist()
    pm = max(float(robot.platform_mass), 1e-3)
    platform = (
        f'<body name="platform" pos="{p0[0]!r} {p0[1]!r} {p0[2]!r}">'
        '<joint name="px" type="slide" axis="1 0 0"/><joint name="py" type="slide" axis="0 1 0"/>'
        '<joint name="pz" type="slide" axis="0 0 1"/>'
        f'<inertial pos="0 0 0" mass="{pm!r}" diaginertia="1e-4 1e-4 1e-4"/>'
        '<geom name="platform" type="sphere" size="0.05" contype="16" conaffinity="1" mass="0" rgba="0.9 0.3 0.1 1"/>'
        '<site name="platform" pos="0 0 0" size="0.01"/></body>'
    )
    tendons = "".join(
        f'<spatial name="c{k + 1}" width="0.006" rgba="0.95 0.6 0.1 1"><site site="exit{k + 1}"/>'
        f'<site site="platform"/></spatial>'
        for k in range(robot.n_cables)
    )
    acts = "".join(
        f'<motor name="c{k + 1}_winch" tendon="c{k + 1}" gear="1" ctrllimited="true" '
        f'ctrlrange="{-robot.t_max!r} {-robot.t_min!r}"/>'
        for k in range(robot.n_cables)
    )
    return (
        '<mujoco model="tmr-replay-mcdpr"><compiler angle="radian"/>'
        f'<option timestep="{cfg.timestep!r}" integrator="implicitfast" gravity="0 0 {-g!r}"/>'
        '<visual><global offwidth="960" offheight="720"/></visual>'
        f"<asset>{a1}{a2}</asset><worldbody>"
        '<light pos="0 0 12" dir="0 0 -1" directional="true" diffuse="0.7 0.7 0.7"/>'
        f"{w1}{w2}{''.join(bodies)}{platform}</worldbody>"
        f"<tendon>{tendons}</tendon><actuator>{acts}</actuator></mujoco>"
    )


def _yaw(quat: Array) -> float:
    w, x, y, z = quat
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _tilt(quat: Array) -> float:
    w, x, y, z = quat
    return math.acos(max(-1.0, min(1.0, 1 - 2 * (x * x + y * y))))


def replay_mcdpr(run: Any, cfg: McdprConfig | None = None, robot: Any = None, progress: Any = None) -> McdprReplay:
    """Simulate a :class:`tmr.mcdpr.rundir.McdprRun` (``robot`` overrides the run's robot, e.g. a heavier platform);
    ``progress``: optional callable(fraction) called every plan sample."""
    import mujoco
    from scipy.optimize import lsq_linear

    from tmr.mcdpr.tension import closed_form_batch
    from tmr.mcdpr.tipping import tension_bounds, tipping
    from tmr.mcdpr.wrench import wrench_matrix

    cfg = cfg or McdprConfig()
    robot = robot or run.robot()
    scene = run.scene()
    if not np.all(np.isfinite(run.bases)) or not np.all(np.isfinite(run.platform)):
        raise ReplayError(f"{run.path}: the plan has non-finite base or platform samples; re-run tmr.mcdpr plan")
    ref = _Reference(run.bases, run.headings, run.platform, run.segment)
    r0 = ref(0.0)
    try:
        model = mujoco.MjModel.from_xml_string(_model_xml(robot, scene, (r0[0], r0[3], r0[4]), cfg))
    except ValueError as exc:
        raise ReplayError(f"MuJoCo could not compile the MoPICK model: {exc}") from None
    d = mujoco.MjData(model)
    p, mcab = robot.n_bases, robot.n_cables
    T_end = ref.T + cfg.settle

    def jid(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)

    def aid(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)

    bq = np.array([model.jnt_qposadr[jid(f"b{j + 1}_free")] for j in range(p)])
    bv = np.array([model.jnt_dofadr[jid(f"b{j + 1}_free")] for j in range(p)])
    pq = np.array([model.jnt_qposadr[jid(n)] for n in ("px", "py", "pz")])
    pv = np.array([model.jnt_dofadr[jid(n)] for n in ("px", "py", "pz")])
    a_cable = np.array([aid(f"c{k + 1}_winch") for k in range(mcab)])
    wheel = np.array(
        [
            [
                mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"b{j + 1}_w{o + 1}")
                for o in range(len(robot.footprint))
            ]
            for j in range(p)
        ]
    )
    wheel_of = {int(g): (j, o) for j in range(p) for o, g in enumerate(wheel[j])}
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, k) or "" for k in range(model.ngeom)]
    p0 = np.asarray(r0[4], float)
    pm, g = robot.platform_mass, robot.gravity
    wb = 2 * math.pi * cfg.base_frequency
    kpb, kvb = robot.base_mass * wb * wb, 2 * cfg.damping_ratio * robot.base_mass * wb
    izz = robot.base_mass * robot.base_radius**2 / 2
    wp = 2 * math.pi * cfg.platform_frequency
    kpp, kvp, kip = wp * wp, 2 * cfg.damping_ratio * wp, cfg.platform_integral * wp * wp * wp / 10
    ext_box = np.asarray(scene.external, dtype=float)
    corners = np.array(list(itertools.product(*[(-e, e) for e in ext_box]))) if cfg.external else np.zeros((1, 3))
    lo, hi = np.full(mcab, robot.t_min), np.full(mcab, robot.t_max)
    integ = np.zeros(3)
    plat_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "platform")
    base_body = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"b{j + 1}") for j in range(p)]
    bounds = [np.full(mcab, robot.t_min), np.full(mcab, robot.t_max)]
    bounds_at = [0.0]
    exit_sites = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"exit{k + 1}") for k in range(mcab)]
    ctrl_every = max(1, int(round(CONTROL_PERIOD / cfg.timestep)))
    tension = np.zeros(mcab)

    def state() -> tuple[Array, Array, Array]:
        pos = np.array([d.qpos[bq[j] : bq[j] + 2] for j in range(p)])
        quat = np.array([d.qpos[bq[j] + 3 : bq[j] + 7] for j in range(p)])
        return pos, quat, p0 + d.qpos[pq]

    def control(now: float, dt: float) -> bool:
        nonlocal integ, tension
        b_ref, b_v, b_a, h_ref, P_ref, P_v, P_a = ref(now)
        pos, quat, P = state()
        e = P_ref - P
        integ = integ + e * dt
        f = pm * (P_a + kpp * e + kvp * (P_v - d.qvel[pv]) + kip * integ) + np.array([0.0, 0.0, pm * g])
        A = np.array(d.site_xpos[exit_sites])  # exit points as they are (a tilting base moves its exit)
        D = A - P
        W = (D / np.linalg.norm(D, axis=1, keepdims=True)).T  # Rasheed 2019 eq. 1-3
        # the bounds tightened by tipping at the measured pose (Rasheed 2019 eq. 6), as the planner assumes
        if now >= bounds_at[0]:  # they change slowly: refreshed every BOUNDS_PERIOD
            bounds[:] = tension_bounds(robot, tipping(robot, P, pos, np.array([_yaw(q) for q in quat])))
            bounds_at[0] = now + BOUNDS_PERIOD
        tlo, thi = bounds
        cf = closed_form_batch(W, f, tlo, thi) if np.all(tlo <= thi) else None
        ok = cf is not None and bool(cf.feasible)
        tension = cf.t if ok else lsq_linear(W, f, bounds=(lo, hi)).x
        d.ctrl[a_cable] = -tension
        for j in range(p):
            v = d.qvel[bv[j] : bv[j] + 2]
            pull = np.zeros(2)
            for k, jb in enumerate(robot.cable_base):
                if jb == j:
                    u = P - A[k]
                    pull += tension[k] * u[:2] / max(np.linalg.norm(u), 1e-9)
            F = robot.base_mass * b_a[j] + kpb * (b_ref[j] - pos[j]) + kvb * (b_v[j] - v) - pull
            n = float(np.linalg.norm(F))
            if n > cfg.base_force_limit:
                F *= cfg.base_force_limit / n
            dyaw = (h_ref[j] - _yaw(quat[j]) + math.pi) % (2 * math.pi) - math.pi
            tau = izz * wb * wb * dyaw - 2 * izz * wb * d.qvel[bv[j] + 5]
            # wheel traction: the drive force acts at the ground under the base, so it adds no tipping moment
            rx, ry, rz = (
                pos[j, 0] - d.xipos[base_body[j], 0],
                pos[j, 1] - d.xipos[base_body[j], 1],
                -d.xipos[base_body[j], 2],
            )
            d.xfrc_applied[base_body[j]] = [F[0], F[1], 0.0, -rz * F[1], rz * F[0], rx * F[1] - ry * F[0] + tau]
        k_corner = int(now // EXTERNAL_PERIOD) % len(corners)
        d.xfrc_applied[plat_body, :3] = corners[k_corner]
        return ok

    # settle at the start pose (bases on their wheels, cables tensioned), not recorded
    mujoco.mj_forward(model, d)
    for i in range(int(round(0.5 / cfg.timestep))):
        if i % ctrl_every == 0:
            control(0.0, ctrl_every * cfg.timestep)
            d.xfrc_applied[plat_body, :3] = 0.0
        mujoco.mj_step(model, d)
    integ[:] = 0.0
    n_rec = int(math.floor(T_end / cfg.sample)) + 1
    sub = max(1, int(round(cfg.sample / cfg.timestep)))
    K = n_rec
    rec = {
        "platform": np.zeros((K, 3)),
        "bases": np.zeros((K, p, 2)),
        "tilt": np.zeros((K, p)),
        "tension": np.zeros((K, mcab)),
        "infeasible": np.zeros(K, dtype=bool),
        "wheel": np.zeros((K, p, len(robot.footprint))),
        "external": np.zeros((K, 3)),
    }
    qpos: list[Array] = []
    contacts: dict[str, dict[str, Any]] = {
        k: {"count": 0, "first_time": None, "where": None, "between": None, "max_depth": 0.0}
        for k in ("base-obstacle", "base-base", "platform-floor", "platform-obstacle")
    }
    force6 = np.zeros(6)

    def record(k: int, now: float, ok: bool) -> None:
        pos, quat, P = state()
        rec["platform"][k] = P
        rec["bases"][k] = pos
        rec["tilt"][k] = [_tilt(q) for q in quat]
        rec["tension"][k] = -np.asarray(d.actuator_force[a_cable])
        rec["infeasible"][k] = not ok
        rec["external"][k] = d.xfrc_applied[plat_body, :3]
        wf = np.zeros((p, len(robot.footprint)))
        for i in range(d.ncon):
            c = d.contact[i]
            for gid in (int(c.geom1), int(c.geom2)):
                if gid in wheel_of:
                    mujoco.mj_contactForce(model, d, i, force6)
                    j, o = wheel_of[gid]
                    wf[j, o] += force6[0]
        rec["wheel"][k] = wf
        qpos.append(np.array(d.qpos))

    kinds = ("base-obstacle", "base-base", "platform-floor", "platform-obstacle")
    pair_kind = np.full((model.ngeom, model.ngeom), -1)
    is_body = [k for k, n in enumerate(names) if n.endswith("_body")]
    is_obs = [k for k, n in enumerate(names) if n.startswith(("obs", "table", "wall"))]
    plat = names.index("platform")
    floor = names.index("floor")
    for a in is_body:
        pair_kind[a, is_obs] = pair_kind[is_obs, a] = 0
        pair_kind[a, is_body] = 1
        pair_kind[a, a] = -1
    pair_kind[plat, floor] = pair_kind[floor, plat] = 2
    pair_kind[plat, is_obs] = pair_kind[is_obs, plat] = 3

    def log_contacts(now: float) -> None:
        n = d.ncon
        con = d.contact
        g1, g2 = con.geom1[:n], con.geom2[:n]
        kind_of = pair_kind[g1, g2]
        hit = (kind_of >= 0) & (con.dist[:n] <= 0)
        if not hit.any():
            return
        seen = set()
        for i in np.flatnonzero(hit):
            kind = kinds[int(kind_of[i])]
            entry = contacts[kind]
            entry["max_depth"] = max(entry["max_depth"], float(-con.dist[i]))
            if kind in seen:
                continue
            seen.add(kind)
            entry["count"] += 1
            if entry["first_time"] is None:
                entry["first_time"] = float(now)
                entry["where"] = [float(v) for v in con.pos[i]]
                entry["between"] = [names[int(g1[i])], names[int(g2[i])]]

    diverged = None
    wall0, cpu0 = time.perf_counter(), time.process_time()
    now = 0.0
    ok = control(now, cfg.timestep)
    record(0, now, ok)
    step = 0
    for k in range(1, K):
        if progress is not None:
            progress(k / (K - 1))
        for _ in range(sub):
            if step % ctrl_every == 0:
                ok = control(now, ctrl_every * cfg.timestep) and ok
            mujoco.mj_step(model, d)
            step += 1
            now = step * cfg.timestep
            if d.ncon:
                log_contacts(now)
        if not np.all(np.isfinite(d.qpos)) or d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:
            diverged = f"the simulation diverged at t = {now:.2f} s (non-finite accelerations)"
            K = k
            break
        record(k, now, ok)
        ok = True
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    rec = {key: val[:K] for key, val in rec.items()}
    qpos = qpos[:K]
    t = np.arange(K) * cfg.sample
    refs = [ref(float(x)) for x in t]
    P_ref = np.array([r[4] for r in refs])
    B_ref = np.array([r[0] for r in refs])
    W_ref = wrench_matrix(robot, P_ref, B_ref, np.array([r[3] for r in refs]))
    t_plan = closed_form_batch(W_ref, np.array([0.0, 0.0, pm * g]), lo, hi).t
    rp = McdprReplay(
        t=t,
        platform_ref=P_ref,
        platform=rec["platform"],
        platform_error=np.linalg.norm(rec["platform"] - P_ref, axis=1),
        bases_ref=B_ref,
        bases=rec["bases"],
        base_tilt=rec["tilt"],
        tensions=rec["tension"],
        tensions_plan=t_plan,
        tension_infeasible=rec["infeasible"],
        wheel_force=rec["wheel"],
        external=rec["external"],
        contacts=contacts,
        sim_time=step * cfg.timestep,
        wall_time=wall,
        cpu_time=cpu,
        steps=step,
        config=cfg,
        qpos=qpos,
        model=model,
        diverged=diverged,
    )
    rp.verdict = mcdpr_verdict(rp, robot)
    return rp


#: a footprint edge whose opposite wheels carry no more than this [N] is tipping: those wheels are off the ground.
LIFT_FORCE = 1e-3


def edge_margins(wheel_force: Array) -> Array:
    """Tipping margin of every footprint edge [N]: the ground force on the wheels off that edge, (K, p, c).

    Tipping about the edge of wheels o, o+1 (Rasheed 2019 eq. 5-6) lifts every other wheel; their summed normal
    force is the margin left before it does. (One wheel alone may unload on a flat floor — a four-wheel base rocks
    on a diagonal — without tipping.)"""
    c = wheel_force.shape[-1]
    return np.stack([np.delete(wheel_force, [o, (o + 1) % c], axis=-1).sum(axis=-1) for o in range(c)], axis=-1)


def mcdpr_verdict(rp: McdprReplay, robot: Any) -> Any:
    """Earliest failed check: a wheel lifting off (no ground force), cables unable to give the controller's wrench
    (a cable slack at t_min or saturated at t_max), the platform off its path beyond the tolerance, a contact."""
    from tmr.replay.report import Verdict

    fails: list[tuple[float, str, str]] = []
    margin = edge_margins(rp.wheel_force)  # (K, p, c)
    lift = margin <= LIFT_FORCE
    if lift.any():
        k = int(np.argmax(lift.any(axis=(1, 2))))
        j, o = (int(v) for v in np.argwhere(lift[k])[0])
        c = margin.shape[2]
        others = [w + 1 for w in range(c) if w not in (o, (o + 1) % c)]
        fails.append(
            (
                float(rp.t[k]),
                "wheel-lift",
                f"base {j + 1} tips about the edge of wheels {o + 1}-{(o + 1) % c + 1} at t = {rp.t[k]:.2f} s: "
                f"wheels {', '.join(map(str, others))} off the ground (tilt {math.degrees(rp.base_tilt[k, j]):.2f}°)",
            )
        )
    if rp.tension_infeasible.any():
        k = int(np.argmax(rp.tension_infeasible))
        t = rp.tensions[k]
        slack = [i + 1 for i in range(len(t)) if t[i] <= robot.t_min + 1e-6]
        sat = [i + 1 for i in range(len(t)) if t[i] >= robot.t_max - 1e-6]
        what = []
        if slack:
            what.append(f"cable {', '.join(map(str, slack))} slack ({robot.t_min:g} N)")
        if sat:
            what.append(f"cable {', '.join(map(str, sat))} at t_max {robot.t_max:g} N")
        fails.append(
            (
                float(rp.t[k]),
                "tension",
                f"no cable tensions in [{robot.t_min:g}, {robot.t_max:g}] N hold the platform at t = {rp.t[k]:.2f} s"
                + (f": {'; '.join(what)}" if what else ""),
            )
        )
    over = rp.platform_error > rp.config.tolerance
    if over.any():
        k = int(np.argmax(over))
        fails.append(
            (
                float(rp.t[k]),
                "platform",
                f"platform {rp.platform_error[k]:.3f} m off its path > tolerance {rp.config.tolerance:g} m at "
                f"t = {rp.t[k]:.2f} s (largest {rp.platform_error.max():.3f} m)",
            )
        )
    for kind, c in rp.contacts.items():
        if c["count"]:
            a, b = c["between"]
            fails.append((float(c["first_time"]), kind, f"{kind} contact ({a}, {b}) at t = {c['first_time']:.2f} s"))
    if rp.diverged:
        fails.append((float(rp.t[-1]) if len(rp.t) else 0.0, "diverged", rp.diverged))
    fails.sort(key=lambda f: f[0])
    return Verdict(ok=not fails, reason=fails[0][2] if fails else None, failures=tuple(fails))


def mcdpr_document(rp: McdprReplay, run: Any) -> dict[str, Any]:
    """``replay.json`` of a MoPICK replay (no timings)."""
    from dataclasses import asdict

    from tmr.replay.report import REPLAY_FORMAT

    v = rp.verdict
    m = rp.tensions.shape[1]
    return {
        "format": REPLAY_FORMAT,
        "kind": "mcdpr",
        "run": {"path": run.path.name, "scene": run.record["scene"]["name"], "plan_ok": run.plan["check"]["ok"]},
        "verdict": {
            "ok": v.ok,
            "reason": v.reason,
            "failures": [{"t": t, "check": k, "message": msg} for t, k, msg in v.failures],
        },
        "model": asdict(rp.config) | {"speed": SPEED, "external_period": EXTERNAL_PERIOD, "table_height": TABLE_HEIGHT},
        "sim_time": rp.sim_time,
        "steps": rp.steps,
        "platform": {
            "error_max": float(rp.platform_error.max()),
            "error_rms": float(np.sqrt(np.mean(rp.platform_error**2))),
        },
        "cables": [
            {
                "name": f"cable{k + 1}",
                "tension_min": float(rp.tensions[:, k].min()),
                "tension_max": float(rp.tensions[:, k].max()),
                "vs_tension_distribution_max": float(np.nanmax(np.abs(rp.tensions[:, k] - rp.tensions_plan[:, k])))
                if np.isfinite(rp.tensions_plan[:, k]).any()
                else None,
            }
            for k in range(m)
        ],
        "bases": [
            {
                "name": f"base{j + 1}",
                "wheel_force_min": float(rp.wheel_force[:, j].min()),
                "tipping_margin_min": float(edge_margins(rp.wheel_force)[:, j].min()),
                "two_wheel_samples": int((edge_margins(rp.wheel_force)[:, j] <= LIFT_FORCE).any(axis=1).sum()),
                "tilt_max_deg": float(np.degrees(rp.base_tilt[:, j].max())),
                "tracking_error_max": float(np.linalg.norm(rp.bases[:, j] - rp.bases_ref[:, j], axis=1).max()),
            }
            for j in range(rp.bases.shape[1])
        ],
        "tension_infeasible_samples": int(rp.tension_infeasible.sum()),
        "contacts": rp.contacts,
        "series": {
            "t": rp.t.tolist(),
            "platform_error": rp.platform_error.tolist(),
            "tensions": rp.tensions.tolist(),
            "tensions_distribution": [
                [None if not np.isfinite(v) else v for v in row] for row in rp.tensions_plan.tolist()
            ],
            "wheel_force_min": rp.wheel_force.min(axis=2).tolist(),
        },
    }


def mcdpr_figures(out: Path, rp: McdprReplay, run: Any) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tmr.views.plot import save_figure

    fig, ax = plt.subplots(3, 1, figsize=(8.0, 8.5), sharex=True)
    ax[0].plot(rp.t, 1000 * rp.platform_error, color="k")
    ax[0].axhline(1000 * rp.config.tolerance, color="r", ls=":")
    ax[0].set_ylabel("platform error [mm]")
    for k in range(rp.tensions.shape[1]):
        c = f"C{k}"
        ax[1].plot(rp.t, rp.tensions[:, k], color=c, label=f"cable {k + 1}")
        ax[1].plot(rp.t, rp.tensions_plan[:, k], color=c, ls="--", lw=0.9)
    ax[1].set_ylabel("tension [N]")
    ax[1].legend(fontsize=7, ncol=4)
    for j in range(rp.wheel_force.shape[1]):
        ax[2].plot(rp.t, rp.wheel_force[:, j].min(axis=1), label=f"base {j + 1}")
    ax[2].axhline(0.0, color="r", ls=":")
    ax[2].set_ylabel("smallest wheel force [N]")
    ax[2].set_xlabel("t [s]")
    ax[2].legend(fontsize=7, ncol=4)
    ax[0].set_title(f"MuJoCo replay: {run.label} (dashed: tmr.mcdpr.tension for the planned pose)")
    for a in ax:
        a.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, out / "mcdpr_replay.png")
    plt.close(fig)
    return ["mcdpr_replay.png"]


def write_mcdpr_outputs(out: Path, rp: McdprReplay, run: Any, plots: bool = True, gif: bool = False) -> list[str]:
    from tmr.io.outputs import atomic_write_text
    from tmr.replay.report import _dump, write_timing

    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "replay.json", _dump(mcdpr_document(rp, run)))
    write_timing(out, rp)
    names = ["replay.json", "timing.json"]
    if plots:
        names += mcdpr_figures(out, rp, run)
    if gif:
        from tmr.replay.gif import FPS, frames_mujoco, write_gif

        every = max(1, int(round(1.0 / (FPS * rp.config.sample))) * 5)  # 5x faster than real time (long plans)
        write_gif(frames_mujoco(rp.model, rp.qpos, run.record["scene"]["bounds"], every), out / "replay.gif")
        names.append("replay.gif")
    return sorted(names)


def mcdpr_summary(rp: McdprReplay, run: Any) -> str:
    v = rp.verdict
    lines = [f"tmr replay: {run.label}, {rp.sim_time:.1f} s simulated, {rp.steps} steps"]
    lines.append(
        f"  platform  error max {1000 * rp.platform_error.max():.1f} mm, "
        f"rms {1000 * float(np.sqrt(np.mean(rp.platform_error**2))):.1f} mm"
    )
    for k in range(rp.tensions.shape[1]):
        lines.append(f"  cable{k + 1}    tension {rp.tensions[:, k].min():.2f} .. {rp.tensions[:, k].max():.2f} N")
    for j in range(rp.wheel_force.shape[1]):
        lines.append(
            f"  base{j + 1}     tipping margin {edge_margins(rp.wheel_force)[:, j].min():.2f} N "
            f"(on two wheels in {int((edge_margins(rp.wheel_force)[:, j] <= LIFT_FORCE).any(axis=1).sum())} of "
            f"{len(rp.t)} samples), "
            f"tilt max {np.degrees(rp.base_tilt[:, j].max()):.2f}°"
        )
    lines.append(
        f"  real-time factor {rp.real_time_factor:.1f}x ({rp.wall_time:.2f} s wall; "
        f"{rp.cpu_real_time_factor:.1f}x of this process's CPU time)"
    )
    return "\n".join(lines) + ("" if v.ok else f"\nFAILED: {v.reason}")
