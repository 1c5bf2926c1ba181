"""Differential-drive robots on wheels in the MuJoCo chain replay (``formulations/replay.md``, "Wheeled robots").

A wheeled robot is a chassis body on slides x, y, z and a yaw hinge (no roll or pitch: the chassis cannot tip, it
rests on its wheels and casters under gravity), with

- two driven wheels (radius r_w, ``track`` L apart, hinge joints on the axle; the tyre collides as a sphere of
  radius r_w: one contact point in the wheel's mid-plane, a thin wheel), each a MuJoCo
  ``velocity`` actuator whose ``ctrlrange`` is the wheel-speed limit
  w_max = (v_max + ω_max L / 2) / r_w [rad/s] — the fastest wheel a command inside the plan's (v, ω) box needs;
- two passive casters (spheres ahead of and behind the axle, frictionless contacts: ``condim="1"``);
- Coulomb friction μ = 1 between the wheels and the floor (``condim="3"``, MuJoCo's default pyramidal cone, the
  floor's contact softness): a wheel grips sideways, so the chassis moves sideways only as far as the soft contact
  creeps or the tether's pull beats the friction (measured: the lateral slip speed);
- on each wheel hinge the reflected rotor inertia of a gear motor, ``armature`` = (M / 2) r_w² (without it the light
  wheel spins up against the soft contact faster than the ground can roll it, and the wheels skid);
- the tether attached at the exit point, b ahead of the axle, at the exit height.

The drive (:class:`WheelDriver`): the reference pose (c_r, θ_r) and command (v_r, ω_r) of every physics step, the
unicycle tracking law of Kanayama et al. 1990 ("A stable tracking control method for an autonomous mobile robot",
ICRA) with the error in the robot's frame, e_x = e(θ)·(c_r − c), e_y = e_⊥(θ)·(c_r − c), e_θ = wrap(θ_r − θ):

    v = v_r cos e_θ + K_x e_x
    ω = ω_r + v_r K_y e_y + |v_r| K_θ sin e_θ + K_h sin e_θ

(|v_r| in the heading term keeps the law stable when reversing; K_h, not in Kanayama's law, turns the heading back
when v_r ≈ 0, where the other terms vanish), then inverse kinematics w_R,L = (v ± ω L / 2) / r_w [rad/s], both scaled
down by the same factor when one exceeds w_max (the turn's curvature is kept). The velocity servo of each wheel
applies the torque k_w (w_cmd − w) [N m], k_w = ((M / 2) r_w² + armature) / τ_w; no torque limit (the floor's
friction bounds the traction).

References: a diff-drive plan (``trajectories.json`` x, y, theta, v, omega: the exact arcs of the held cmd_vel,
:func:`tmr.model.diffdrive.unicycle_step`), or an omnidirectional plan replayed on wheels (the robot is asked to follow
the omni plan's pose: its exit point on the planned position and its heading at 0, the yaw the omni replay holds; the
axle reference c_r = p − b e(0), v_r = e(0)·ṗ, ω_r = 0, and the plan demands the lateral speed e_⊥(0)·ṗ, which no
unicycle can give).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.model.diffdrive import RobotModel, exit_point, load_robot_model
from tmr.replay.errors import ReplayError

Array = NDArray[np.float64]

__all__ = [
    "WheelConfig",
    "WheelDriver",
    "WheelReference",
    "WheelSetup",
    "wheel_config",
    "wheel_reference",
]


#: Largest demanded lateral (sideways) speed of the axle that a plan may ask of a differential drive [m/s]
#: (diff-drive plans: ≤ 4e-14 m/s, ``formulations/diffdrive.md``).
LATERAL_DEMAND_TOL = 1e-3
#: The wheels' and casters' contact softness: the floor's (the stiffest MuJoCo allows at the 5 ms step), so the
#: contact's solref/solimp are not mixed with MuJoCo's softer defaults.
_CONTACT = 'solref="0.01 1" solimp="0.99 0.9999 0.0005 0.5 2"'
#: A wheel's measured speed may exceed w_max by this fraction (the velocity servo's overshoot) before the replay fails.
WHEEL_SPEED_SLACK = 0.01


@dataclass(frozen=True)
class WheelConfig:
    """The wheeled robots of a replay. Units: m, kg, s, rad.

    Attributes:
        model: the robot model (v_max, ω_max, b, footprint radius).
        wheel_radius: r_w [m].
        track: L, distance between the two driven wheels [m].
        plan_drive: "diff" (the plan is a diff-drive plan) or "omni" (an omni plan replayed on wheels).
        k_x: longitudinal gain K_x [1/s].
        k_y: lateral gain K_y [1/m²].
        k_theta: heading gain K_θ [1/m] (2 √K_y: critically damped lateral error at constant v_r).
        k_h: heading gain K_h at rest [1/s].
        servo_time: time constant τ_w of a wheel's velocity servo [s]; k_w = (M / 2) r_w² / τ_w [N m s/rad].
        friction: wheel-floor sliding friction μ.
        wheel_mass: mass of one wheel as a fraction of the robot mass.
        heading_tolerance: heading error beyond which the replay fails [rad].
        armature_share: the reflected rotor inertia of a wheel's motor as a multiple of (M / 2) r_w² (:meth:`armature`).
    """

    model: RobotModel
    wheel_radius: float
    track: float
    plan_drive: str = "diff"
    k_x: float = 4.0
    k_y: float = 25.0
    k_theta: float = 10.0
    k_h: float = 4.0
    servo_time: float = 0.005
    friction: float = 1.0
    wheel_mass: float = 0.02
    heading_tolerance: float = 0.1
    armature_share: float = 1.0

    @property
    def wheel_limit(self) -> float:
        """w_max = v_max / r_w [rad/s]: a wheel's rim is as fast as the robot driving straight (the planner keeps
        |v ± ω L/2| ≤ v_max when the robot model has a track)."""
        return self.model.v_max / self.wheel_radius

    def armature(self, robot_mass: float) -> float:
        """The rotor inertia a gear motor reflects onto each wheel's hinge [kg m²], taken equal to the robot's share
        (M / 2) r_w² (a geared motor's reflected inertia is of that order; without it the light wheel spins up
        against MuJoCo's soft contact faster than the ground can roll it, and skids)."""
        return self.armature_share * 0.5 * robot_mass * self.wheel_radius**2

    def servo_gain(self, robot_mass: float) -> float:
        """k_w = ((M / 2) r_w² + armature) / τ_w [N m s/rad], each wheel's velocity servo for a robot of
        ``robot_mass`` [kg]."""
        return (0.5 * robot_mass * self.wheel_radius**2 + self.armature(robot_mass)) / self.servo_time

    def record(self) -> dict[str, Any]:
        """JSON-ready description (replay.json ``wheels.config``)."""
        return {
            "robot_model": self.model.record(),
            "plan_drive": self.plan_drive,
            "wheel_radius": self.wheel_radius,
            "track": self.track,
            "wheel_limit": self.wheel_limit,
            "k_x": self.k_x,
            "k_y": self.k_y,
            "k_theta": self.k_theta,
            "k_h": self.k_h,
            "servo_time": self.servo_time,
            "friction": self.friction,
            "wheel_mass_fraction": self.wheel_mass,
            "heading_tolerance": self.heading_tolerance,
            "armature": self.armature_share,
            "lateral_demand_tolerance": LATERAL_DEMAND_TOL,
            "wheel_speed_slack": WHEEL_SPEED_SLACK,
        }


def wheel_config(
    run: Any,
    robot_model: str | None = None,
    wheel_radius: float | None = None,
    track: float | None = None,
) -> WheelConfig:
    """The :class:`WheelConfig` of a run: a diff-drive run's own recorded robot model (``robot_model`` must be None
    or its name), or for an omni run the model ``robot_model`` (a preset or TOML file; default the Burger). Wheel
    radius and track: the robot model's (``wheel_radius``, ``track``) unless given [m]. Raises :class:`ReplayError`."""
    params = run.record.get("params") or {}
    if params.get("drive") == "diff":
        rec = dict(params.get("robot_model_params") or {})
        try:
            model = RobotModel(**rec)
        except TypeError:
            raise ReplayError(
                "the diff-drive run records no usable robot model (run.json params.robot_model_params)"
            ) from None
        if robot_model is not None and robot_model != model.name:
            raise ReplayError(
                f"the run was planned for robot model {model.name!r}; replay it on that model (no --robot-model)"
            )
        plan_drive = "diff"
    else:
        model = load_robot_model(robot_model or "turtlebot3_burger")
        plan_drive = "omni"
    r = wheel_radius if wheel_radius is not None else model.wheel_radius
    L = track if track is not None else model.track
    if r is None or L is None:
        raise ReplayError(
            f"no wheel geometry for robot model {model.name!r}: give --wheel-radius and --wheel-track (or "
            "wheel_radius and track in its TOML file)"
        )
    return WheelConfig(model=model, wheel_radius=float(r), track=float(L), plan_drive=plan_drive)


@dataclass
class WheelReference:
    """The reference of every physics step s (S) and robot i (N). Units: m, rad, m/s, rad/s."""

    axle: Array  # (S, N, 2) c_r
    theta: Array  # (S, N) θ_r (continuous)
    v: Array  # (S, N) v_r
    omega: Array  # (S, N) ω_r
    exit: Array  # (S, N, 2) p_r = c_r + b e(θ_r): what the tethers' planned ends follow
    lateral: Array  # (S, N) the lateral axle speed the plan demands (0 for a diff-drive plan)


def _diff_samples(run: Any) -> tuple[Array, Array, Array, Array]:
    """(axle (K, N, 2), theta (K, N), v (K, N), omega (K, N)) of a diff-drive run's trajectories.json."""
    try:
        doc = json.loads((run.path / "trajectories.json").read_text(encoding="utf-8"))
        rows = doc["robots"]
        axle = np.stack([np.column_stack([r["x"], r["y"]]) for r in rows], axis=1).astype(float)
        theta, v, omega = (np.array([r[k] for r in rows], dtype=float).T for k in ("theta", "v", "omega"))
    except (OSError, KeyError, TypeError, ValueError) as exc:
        raise ReplayError(f"the diff-drive run's trajectories.json lacks x, y, theta, v, omega ({exc})") from None
    if not (np.all(np.isfinite(axle)) and np.all(np.isfinite(theta)) and np.all(np.isfinite(v))):
        raise ReplayError("the diff-drive run's trajectories.json has non-finite poses")
    return axle, theta, v, omega


def wheel_reference(run: Any, wc: WheelConfig, t: Array, times: Array, traj: Array) -> WheelReference:
    """The reference at the physics steps ``times`` [s] of a plan sampled at ``t`` [s] (module docstring); ``traj``
    (K, N, 2): the planned exit points an omni plan's robots track (filtered or raw)."""
    b = wc.model.exit_offset
    if wc.plan_drive == "diff":
        axle, theta, v, omega = _diff_samples(run)
        Ts = float(run.record["Ts"])
        k = np.clip(np.floor((times - t[0]) / Ts + 1e-9).astype(int), 0, t.size - 1)
        s = np.clip(times - t[k], 0.0, Ts)
        vk, wk = v[k], omega[k]
        last = k == t.size - 1  # after the last sample: at rest
        vk[last], wk[last] = 0.0, 0.0
        # the exact arc of the held command (tmr.model.diffdrive.unicycle_step, with a time per physics step)
        dth = wk * s[:, None]
        mid = theta[k] + 0.5 * dth
        chord = vk * s[:, None] * np.sinc(dth / (2.0 * np.pi))
        c = axle[k] + chord[..., None] * np.stack([np.cos(mid), np.sin(mid)], axis=-1)
        th = theta[k] + dth
        lateral = np.zeros_like(th)
        return WheelReference(c, th, vk, wk, exit_point(c, th, b), lateral)
    from tmr.replay.chain import _reference

    p, pd, _ = _reference(t, traj, times)
    th = np.zeros(p.shape[:2])
    c = p - np.array([b, 0.0])
    return WheelReference(c, th, pd[..., 0].copy(), np.zeros_like(th), p, pd[..., 1].copy())


@dataclass
class WheelSetup:
    """What the model builder needs: the config, the robot mass [kg], the start poses (axle (N, 2) [m], heading (N,)
    [rad])."""

    config: WheelConfig
    robot_mass: float
    start_axle: Array
    start_theta: Array
    reference: WheelReference | None = None

    def body_xml(self, i: int, H: float, height: float, tether_xml: str) -> str:
        """The ``<body>`` of robot i (0-based): chassis on slides x, y, z and a yaw hinge at the axle centre (frame
        world-aligned at qpos0; its parts turned by the start heading), wheels, casters, footprint, mast; the
        tether's first link inside it (``tether_xml``, root at the exit point)."""
        wc = self.config
        m = wc.model
        n = i + 1
        cx, cy = (float(v) for v in self.start_axle[i])
        th0 = float(self.start_theta[i])
        b, rf, rw, L = m.exit_offset, m.radius, wc.wheel_radius, wc.track
        M = self.robot_mass
        mw = wc.wheel_mass * M
        izz = 0.5 * M * rf * rf
        rc = 0.5 * rw  # caster radius
        arm = wc.armature(M)
        xc = 0.7 * rf  # casters ahead of and behind the axle
        z0 = rw  # footprint cylinder starts at the wheel axle's height
        hz = max(0.5 * (height - z0), 0.02)
        ex, ey = b * math.cos(th0), b * math.sin(th0)
        rt, ra = 8, 10  # ROBOT_BITS: obstacles and robots
        # the tyre: a sphere of radius r_w (one contact point in the wheel's mid-plane, a thin wheel; a cylinder's
        # two rim contacts fight each other and the wheel skids), drawn as a cylinder that does not collide
        wheel_geom = (
            f'type="sphere" size="{rw!r}" mass="{mw!r}" contype="0" conaffinity="1" condim="3" '
            f'friction="{wc.friction!r} 0.005 0.0001" rgba="0 0 0 0" {_CONTACT}/><geom type="cylinder" '
            f'size="{rw!r} {0.25 * rw!r}" euler="1.5707963267948966 0 0" contype="0" conaffinity="0" mass="0" '
            'rgba="0.1 0.1 0.1 1"'
        )
        caster = (
            f'type="sphere" size="{rc!r}" contype="0" conaffinity="1" condim="1" priority="1" '
            f'rgba="0.5 0.5 0.5 1" {_CONTACT}'
        )
        return (
            f'<body name="r{n}" pos="{cx!r} {cy!r} 0">'
            f'<joint name="r{n}_x" type="slide" axis="1 0 0"/>'
            f'<joint name="r{n}_y" type="slide" axis="0 1 0"/>'
            f'<joint name="r{n}_z" type="slide" axis="0 0 1"/>'
            f'<joint name="r{n}_yaw" type="hinge" axis="0 0 1"/>'
            f'<inertial pos="0 0 {rw!r}" mass="{M!r}" diaginertia="{izz!r} {izz!r} {izz!r}"/>'
            f'<geom name="r{n}_body" type="cylinder" size="{rf!r} {hz!r}" pos="0 0 {z0 + hz!r}" '
            f'contype="{rt}" conaffinity="{ra}" rgba="0.15 0.35 0.75 0.55" solref="0.01 1" '
            f'solimp="0.99 0.9999 0.0005 0.5 2" mass="0"/>'
            f'<geom type="cylinder" size="0.02 {H / 2!r}" pos="{ex!r} {ey!r} {H / 2!r}" contype="0" conaffinity="0" '
            f'rgba="0.2 0.2 0.2 1" mass="0"/>'
            f'<body name="r{n}_base" euler="0 0 {th0!r}">'
            f'<geom name="r{n}_caster_f" {caster} pos="{xc!r} 0 {rc!r}" mass="0"/>'
            f'<geom name="r{n}_caster_b" {caster} pos="{-xc!r} 0 {rc!r}" mass="0"/>'
            f'<body name="r{n}_wl" pos="0 {L / 2!r} {rw!r}">'
            f'<joint name="r{n}_wl" type="hinge" axis="0 1 0" armature="{arm!r}"/>'
            f'<geom name="r{n}_wl" {wheel_geom}/></body>'
            f'<body name="r{n}_wr" pos="0 {-L / 2!r} {rw!r}">'
            f'<joint name="r{n}_wr" type="hinge" axis="0 1 0" armature="{arm!r}"/>'
            f'<geom name="r{n}_wr" {wheel_geom}/></body>'
            "</body>" + tether_xml + "</body>"
        )

    def actuator_xml(self, i: int) -> str:
        """The two wheels' velocity servos of robot i (0-based), ctrlrange ± w_max."""
        n = i + 1
        kw = self.config.servo_gain(self.robot_mass)
        w = self.config.wheel_limit
        return "".join(
            f'<velocity name="r{n}_a{s}" joint="r{n}_w{s}" kv="{kw!r}" ctrllimited="true" ctrlrange="{-w!r} {w!r}"/>'
            for s in ("l", "r")
        )


@dataclass
class WheelDriver:
    """The wheel commands of every physics step and what they did (see the module docstring)."""

    setup: WheelSetup
    model: Any
    q_pose: NDArray[np.int64]  # (N, 3) qpos addresses x, y, yaw
    v_pose: NDArray[np.int64]  # (N, 2) dof addresses x, y
    q_wheel_vel: NDArray[np.int64]  # (N, 2) dof addresses of the left, right wheel
    act: NDArray[np.int64]  # (N, 2) actuator ids left, right
    peak_wheel: Array = field(default_factory=lambda: np.zeros(0))  # (N,) largest |wheel speed| measured [rad/s]
    peak_wheel_at: Array = field(default_factory=lambda: np.zeros(0))  # (N,) when [s]
    peak_cmd: Array = field(default_factory=lambda: np.zeros(0))  # (N,) largest |wheel command| before the limit
    saturated_steps: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    peak_slip: Array = field(default_factory=lambda: np.zeros(0))  # (N,) largest |lateral axle speed| [m/s]
    peak_slip_at: Array = field(default_factory=lambda: np.zeros(0))
    steps: int = 0

    @classmethod
    def build(cls, setup: WheelSetup, model: Any) -> WheelDriver:
        import mujoco

        def jnt(name: str) -> int:
            return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)

        n = setup.start_axle.shape[0]
        q = np.array([[model.jnt_qposadr[jnt(f"r{i + 1}_{a}")] for a in ("x", "y", "yaw")] for i in range(n)])
        v = np.array([[model.jnt_dofadr[jnt(f"r{i + 1}_{a}")] for a in ("x", "y")] for i in range(n)])
        w = np.array([[model.jnt_dofadr[jnt(f"r{i + 1}_w{s}")] for s in ("l", "r")] for i in range(n)])
        aid = mujoco.mjtObj.mjOBJ_ACTUATOR
        act = np.array([[mujoco.mj_name2id(model, aid, f"r{i + 1}_a{s}") for s in ("l", "r")] for i in range(n)])
        z = np.zeros(n)
        return cls(
            setup, model, q, v, w, act, z.copy(), z.copy(), z.copy(), np.zeros(n, dtype=np.int64), z.copy(), z.copy()
        )

    def pose(self, d: Any) -> tuple[Array, Array]:
        """(axle (N, 2) [m], heading (N,) [rad]) of the simulated chassis."""
        qp = d.qpos[self.q_pose]
        return self.setup.start_axle + qp[:, :2], self.setup.start_theta + qp[:, 2]

    def exit(self, d: Any) -> Array:
        """(N, 2) the simulated exit points [m]."""
        c, th = self.pose(d)
        return exit_point(c, th, self.setup.config.model.exit_offset)

    def hold(self, d: Any) -> None:
        """Wheels commanded to stand still (warm-up)."""
        d.ctrl[self.act] = 0.0

    def command(self, d: Any, s: int) -> None:
        """Set the wheel commands of physics step ``s`` from the tracking law (module docstring)."""
        wc = self.setup.config
        ref = self.setup.reference
        assert ref is not None
        c, th = self.pose(d)
        dc = ref.axle[s] - c
        cs, sn = np.cos(th), np.sin(th)
        ex = cs * dc[:, 0] + sn * dc[:, 1]
        ey = -sn * dc[:, 0] + cs * dc[:, 1]
        et = np.angle(np.exp(1j * (ref.theta[s] - th)))
        vr, wr = ref.v[s], ref.omega[s]
        v = vr * np.cos(et) + wc.k_x * ex
        w = wr + vr * wc.k_y * ey + np.abs(vr) * wc.k_theta * np.sin(et) + wc.k_h * np.sin(et)
        half = 0.5 * wc.track
        wheels = np.column_stack([v - w * half, v + w * half]) / wc.wheel_radius  # left, right [rad/s]
        peak = np.abs(wheels).max(axis=1)
        lim = wc.wheel_limit
        self.peak_cmd = np.maximum(self.peak_cmd, peak)
        over = peak > lim
        self.saturated_steps += over
        scale = np.where(over, lim / np.maximum(peak, 1e-300), 1.0)
        d.ctrl[self.act] = wheels * scale[:, None]

    def measure(self, d: Any, now: float) -> None:
        """After a physics step: the wheels' speeds and the chassis' lateral speed."""
        _, th = self.pose(d)
        w = np.abs(d.qvel[self.q_wheel_vel]).max(axis=1)
        faster = w > self.peak_wheel
        self.peak_wheel = np.where(faster, w, self.peak_wheel)
        self.peak_wheel_at = np.where(faster, now, self.peak_wheel_at)
        vel = d.qvel[self.v_pose]
        lat = np.abs(-np.sin(th) * vel[:, 0] + np.cos(th) * vel[:, 1])
        more = lat > self.peak_slip
        self.peak_slip = np.where(more, lat, self.peak_slip)
        self.peak_slip_at = np.where(more, now, self.peak_slip_at)
        self.steps += 1


@dataclass
class WheelReport:
    """What the wheels did (robots i = 0..N-1, samples k). Units: m, rad, rad/s, m/s, s."""

    config: WheelConfig
    axle: Array  # (K, N, 2) simulated axle centres
    theta: Array  # (K, N) simulated headings
    axle_reference: Array  # (K, N, 2)
    theta_reference: Array  # (K, N)
    axle_error: Array  # (K, N) |c − c_r|
    heading_error: Array  # (K, N) |wrap(θ − θ_r)|
    lateral_demand: Array  # (K, N) |lateral axle speed| the plan demands
    peak_wheel: Array  # (N,)
    peak_wheel_at: Array  # (N,)
    peak_cmd: Array  # (N,)
    saturated_time: Array  # (N,) physics time with a clipped wheel command [s]
    peak_slip: Array  # (N,)
    peak_slip_at: Array  # (N,)

    def failures(self, t: Array, tolerance: float) -> list[tuple[float, str, str]]:
        """The wheeled robots' failed checks as (time [s], check, message), for the verdict
        (:func:`tmr.replay.report.chain_verdict`): the plan demands sideways motion (lateral axle speed >
        :data:`LATERAL_DEMAND_TOL`), the axle off its reference by more than ``tolerance`` [m], the heading by more
        than ``config.heading_tolerance``, a wheel faster than its limit by more than :data:`WHEEL_SPEED_SLACK`. Each
        check names its first robot and time (``t``: (K,) sample times [s])."""
        from tmr.replay.report import first_over

        out: list[tuple[float, str, str]] = []
        lat = self.lateral_demand
        if (at := first_over(lat > LATERAL_DEMAND_TOL, lat)) is not None:
            k, i = at
            kk = int(np.argmax(lat[:, i]))
            out.append(
                (
                    float(t[k]),
                    "sideways",
                    f"robot {i + 1} is asked to move sideways at {lat[k, i]:.3f} m/s at t = {t[k]:.2f} s (largest "
                    f"{lat[kk, i]:.3f} m/s at t = {t[kk]:.2f} s): a differential drive cannot (the plan is "
                    f"{self.config.plan_drive}, replayed on {self.config.model.name} wheels)",
                )
            )
        e = self.axle_error
        if (at := first_over(e > tolerance, e)) is not None:
            k, i = at
            out.append(
                (
                    float(t[k]),
                    "axle-tracking",
                    f"robot {i + 1} axle tracking error {e[k, i]:.3f} m > tolerance {tolerance:g} m at "
                    f"t = {t[k]:.2f} s (largest {float(e.max()):.3f} m)",
                )
            )
        h = self.heading_error
        tol_h = self.config.heading_tolerance
        if (at := first_over(h > tol_h, h)) is not None:
            k, i = at
            out.append(
                (
                    float(t[k]),
                    "heading",
                    f"robot {i + 1} heading error {h[k, i]:.3f} rad > tolerance {tol_h:g} rad at t = {t[k]:.2f} s "
                    f"(largest {float(h.max()):.3f} rad)",
                )
            )
        lim = self.config.wheel_limit
        for i in np.flatnonzero(self.peak_wheel > lim * (1 + WHEEL_SPEED_SLACK)):
            out.append(
                (
                    float(self.peak_wheel_at[i]),
                    "wheel-speed",
                    f"robot {i + 1} wheel speed {self.peak_wheel[i]:.2f} rad/s > limit {lim:.2f} rad/s at "
                    f"t = {self.peak_wheel_at[i]:.2f} s (the wheels are driven past their limit)",
                )
            )
        return out

    def document(self, t: Array) -> dict[str, Any]:
        """The ``wheels`` section of ``replay.json`` (units: m, rad, rad/s, m/s, s)."""
        robots = []
        for i in range(self.axle_error.shape[1]):
            ka = int(np.argmax(self.axle_error[:, i]))
            kh = int(np.argmax(self.heading_error[:, i]))
            kl = int(np.argmax(self.lateral_demand[:, i]))
            robots.append(
                {
                    "name": f"robot{i + 1}",
                    "axle_error_max": float(self.axle_error[ka, i]),
                    "axle_error_max_at": float(t[ka]),
                    "axle_error_rms": float(np.sqrt(np.mean(self.axle_error[:, i] ** 2))),
                    "heading_error_max": float(self.heading_error[kh, i]),
                    "heading_error_max_at": float(t[kh]),
                    "wheel_speed_peak": float(self.peak_wheel[i]),
                    "wheel_speed_peak_at": float(self.peak_wheel_at[i]),
                    "wheel_command_peak": float(self.peak_cmd[i]),
                    "wheel_limit": self.config.wheel_limit,
                    "saturated_time": float(self.saturated_time[i]),
                    "lateral_slip_peak": float(self.peak_slip[i]),
                    "lateral_slip_peak_at": float(self.peak_slip_at[i]),
                    "lateral_demand_max": float(self.lateral_demand[kl, i]),
                    "lateral_demand_max_at": float(t[kl]),
                }
            )
        return {
            "config": self.config.record(),
            "robots": robots,
            "series": {
                "axle": self.axle,
                "theta": self.theta,
                "axle_error": self.axle_error,
                "heading_error": self.heading_error,
            },
        }

    def summary(self) -> list[str]:
        """Console lines, one per robot."""
        lim = self.config.wheel_limit
        lines = []
        for i in range(self.axle_error.shape[1]):
            lines.append(
                f"  robot{i + 1}   wheels: axle error max {1000 * self.axle_error[:, i].max():.2f} mm, heading error "
                f"max {math.degrees(self.heading_error[:, i].max()):.2f} deg; wheel speed peak "
                f"{self.peak_wheel[i]:.2f} of {lim:.2f} rad/s (commanded {self.peak_cmd[i]:.2f}, clipped "
                f"{self.saturated_time[i]:.2f} s); lateral slip max {1000 * self.peak_slip[i]:.2f} mm/s; "
                f"sideways demand max {self.lateral_demand[:, i].max():.3f} m/s"
            )
        return lines
