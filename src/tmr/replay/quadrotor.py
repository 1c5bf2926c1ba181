"""A quadrotor of tmr's own for the drone-chain replay: its MJCF and a cascaded controller with a rotor mixer.

The model (``formulations/replay.md``, "Drone chains"): a free rigid body of the planner's mass m_d
(``DroneTetherParams.drone_mass``) with 4 rotors in an X at ``arm`` from the centre. Each rotor is a MuJoCo
``motor`` on a site, ``gear = 0 0 1 0 0 ±c``: its control f [N] pushes along the body's z axis and twists the body
about z by ±c f (the drag torque; c = 0.0201 m as in the mujoco_menagerie Skydio X2, used as a reference for the form
only). Each rotor's thrust is limited to [0, f_max] with 4 f_max = τ m_d g (``thrust_to_weight``): the full thrust,
**not** the planner's budget. The planner keeps a control reserve r_c (``control_reserve``, 25 %) and lets a tether
pull a drone with at most (1 − r_c) 4 f_max − m_d g = ``DroneTetherParams.spare_thrust``; the replay checks that
budget on its own (:func:`tmr.replay.drones.drone_verdict`: the measured tether pull and the collective thrust the
controller asks for against (1 − r_c) 4 f_max), and the clipping at f_max is the saturation check.

Controller, vectorised over the drones and run every physics step — position → attitude → body rate → mixer, the
usual cascade of multirotor autopilots (PX4's, on the attitude of Lee, Leok & McClamroch 2010):

* position: f = m_d (a_ref + k_p (p_ref − p) + k_v (v_ref − v) + g e_z) − F_ff, with F_ff the force the planner's
  catenaries put on the drone at the planned positions (feed-forward only: the measured cable force is not used);
  collective thrust T = f · R e_z;
* attitude: desired body z b3 = f / |f|, yaw 0; e_R = ½ vee(R_dᵀR − RᵀR_d); desired body rates
  ω_d = −k_att e_R, clipped to ``rate_max`` per axis;
* body rate: τ = J k_rate (ω_d − ω) + ω × Jω;
* mixer: the rotor thrusts f_rotor = M⁻¹ [T, τ] (M from the rotor positions and ±c). When one falls outside
  [0, f_max], the collective thrust is kept (itself clipped to [0, 4 f_max]), the roll and pitch torques are scaled
  down by the largest factor that fits, then the yaw torque in the room left (yaw has the least authority; PX4's
  mixer desaturates the same way): a **saturation**, counted per drone and physics step.

Gains: position ω_p = 2π·1 rad/s, ζ = 1 → k_p = ω_p² = 39.5 s⁻², k_v = 2ζω_p = 12.6 s⁻¹; attitude
k_att = 15 s⁻¹ (ω_d per radian of error), rate_max = 6 rad/s; body rate k_rate = 50 s⁻¹ (k_rate dt = 0.25 at the
5 ms step). Attitude and rate loops together are a second-order loop of ω_n = √(k_att k_rate) = 27 rad/s,
ζ = ½√(k_rate/k_att) = 0.91, 4.4× faster than the position loop. Measured on scenario F (``formulations/replay.md``):
ω_p = 2π·1.5 with k_att = 10, k_rate = 40 oscillated (the position loop as fast as the attitude loop) and lost
drone 2.

Units: m, kg, N, s, rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["QuadrotorSpec", "QuadrotorControl", "quadrotor_body_xml", "quadrotor_actuator_xml"]

#: rotor drag torque per newton of thrust [m] (the Skydio X2's motor gear, mujoco_menagerie)
YAW_COEFFICIENT = 0.0201


@dataclass(frozen=True)
class QuadrotorSpec:
    """A quadrotor and its controller's gains.

    Attributes:
        mass: m_d [kg] (the planner's ``drone_mass``).
        thrust_to_weight: τ, total maximal thrust over weight [-] (the planner's).
        g: gravity [m/s²].
        radius: radius of the collision sphere [m] (the planner's ``drone_radius`` = safety radius r).
        arm: distance of each rotor from the centre [m] (0.18: a 0.36 m motor-to-motor diagonal, F450 class).
        inertia: principal moments of inertia [kg m²] (assumption for a 1.5 kg quadrotor of that size: body and
            battery plus 4 motors at the arm).
        yaw_coefficient: c [m], drag torque per thrust.
        pos_frequency, pos_damping: ω_p/2π [Hz], ζ of the position loop.
        att_gain: k_att [1/s], desired body rate per radian of attitude error.
        rate_max: largest commanded body rate [rad/s].
        rate_gain: k_rate [1/s], angular acceleration per rad/s of body-rate error.
    """

    mass: float = 1.5
    thrust_to_weight: float = 2.0
    g: float = 9.81
    radius: float = 0.3
    arm: float = 0.18
    inertia: tuple[float, float, float] = (0.015, 0.015, 0.027)
    yaw_coefficient: float = YAW_COEFFICIENT
    pos_frequency: float = 1.0
    pos_damping: float = 1.0
    att_gain: float = 15.0
    rate_max: float = 6.0
    rate_gain: float = 50.0

    @property
    def rotor_max(self) -> float:
        """f_max [N]: the largest thrust of one rotor, τ m g / 4."""
        return self.thrust_to_weight * self.mass * self.g / 4.0

    @property
    def rotor_positions(self) -> Array:
        """(4, 3) rotor sites in the body frame [m]: front-left, front-right, back-right, back-left (an X)."""
        a = self.arm / math.sqrt(2.0)
        return np.array([[a, a, 0.0], [a, -a, 0.0], [-a, -a, 0.0], [-a, a, 0.0]])

    @property
    def spin(self) -> Array:
        """(4,) ±1: the sign of each rotor's drag torque about z (diagonal pairs spin the same way)."""
        return np.array([1.0, -1.0, 1.0, -1.0])

    def mixer(self) -> Array:
        """M (4×4): [T, τ_x, τ_y, τ_z] = M f for rotor thrusts f [N]."""
        r = self.rotor_positions
        return np.vstack([np.ones(4), r[:, 1], -r[:, 0], self.yaw_coefficient * self.spin])


def quadrotor_body_xml(name: str, pos: Array, spec: QuadrotorSpec, contype: int, conaffinity: int, inner: str) -> str:
    """``<body>`` of one quadrotor at ``pos`` [m] (level), with a free joint, its inertia, a collision sphere of
    ``spec.radius``, visual arms and rotors, the 4 thrust sites ``{name}_rotor{k}``; ``inner`` is XML placed inside
    (the tethers the drone carries)."""
    ix, iy, iz = spec.inertia
    parts = [
        f'<body name="{name}" pos="{" ".join(repr(float(v)) for v in pos)}">',
        f'<freejoint name="{name}_free"/>',
        f'<inertial pos="0 0 0" mass="{spec.mass!r}" diaginertia="{ix!r} {iy!r} {iz!r}"/>',
        f'<geom name="{name}_body" type="sphere" size="{spec.radius!r}" contype="{contype}" '
        f'conaffinity="{conaffinity}" rgba="0.15 0.35 0.75 0.18" group="1" solref="0.01 1" '
        f'solimp="0.99 0.9999 0.0005 0.5 2"/>',
        '<geom type="box" size="0.08 0.06 0.03" contype="0" conaffinity="0" mass="0" rgba="0.2 0.2 0.25 1"/>',
    ]
    for k, r in enumerate(spec.rotor_positions):
        p = " ".join(repr(float(v)) for v in r)
        parts.append(
            f'<geom type="capsule" fromto="0 0 0 {p}" size="0.01" contype="0" conaffinity="0" mass="0" '
            f'rgba="0.3 0.3 0.3 1"/>'
            f'<geom type="cylinder" pos="{p}" size="0.06 0.005" contype="0" conaffinity="0" mass="0" '
            f'rgba="0.9 0.9 0.95 0.6"/>'
            f'<site name="{name}_rotor{k}" pos="{p}" size="0.01"/>'
        )
    parts.append(inner + "</body>")
    return "".join(parts)


def quadrotor_actuator_xml(name: str, spec: QuadrotorSpec) -> str:
    """The 4 rotor motors of a quadrotor: thrust along the site's z in [0, f_max], drag torque ±c per newton."""
    fmax = spec.rotor_max
    return "".join(
        f'<motor name="{name}_m{k}" site="{name}_rotor{k}" gear="0 0 1 0 0 {float(s) * spec.yaw_coefficient!r}" '
        f'ctrllimited="true" ctrlrange="0 {fmax!r}"/>'
        for k, s in enumerate(spec.spin)
    )


class QuadrotorControl:
    """The cascaded controller of N quadrotors (module docstring), with preallocated work arrays.

    :meth:`rotor_thrusts` takes the drones' states and references (arrays (N, 3)) and returns the clipped rotor
    thrusts (N, 4) [N] (a view of an internal array, overwritten by the next call) and the (N,) saturation flags.
    """

    def __init__(self, spec: QuadrotorSpec, n: int) -> None:
        self.spec = spec
        self.n = n
        wp = 2 * math.pi * spec.pos_frequency
        self.kp = wp * wp
        self.kv = 2 * spec.pos_damping * wp
        self.J = np.asarray(spec.inertia, dtype=float)
        self.minv = np.linalg.inv(spec.mixer())
        self.fmax = spec.rotor_max
        # work arrays, reused every call (no allocation of (N, 3) or (N, 3, 3) arrays per physics step)
        self._f = np.zeros((n, 3))
        self._b1 = np.zeros((n, 3))
        self._b2 = np.zeros((n, 3))
        self._b3 = np.zeros((n, 3))
        self._Rd = np.zeros((n, 3, 3))
        self._E = np.zeros((n, 3, 3))
        self._eR = np.zeros((n, 3))
        self._tau = np.zeros((n, 3))
        self._Jw = np.zeros((n, 3))
        self._norm = np.zeros((n, 1))
        self._thrust = np.zeros(n)
        #: (N,) the collective thrust the last call asked for, before clipping [N]
        self.demand = np.zeros(n)
        self._u0 = np.zeros((n, 4))
        self._du = np.zeros((n, 4))
        self._rotors = np.zeros((n, 4))

    def gains(self) -> dict[str, float]:
        """The gains, for replay.json: k_p [s⁻²], k_v, k_att, k_rate [s⁻¹], rate_max [rad/s]."""
        s = self.spec
        return {"kp": self.kp, "kv": self.kv, "k_att": s.att_gain, "k_rate": s.rate_gain, "rate_max": s.rate_max}

    def rotor_thrusts(
        self, p: Array, v: Array, R: Array, w: Array, p_ref: Array, v_ref: Array, a_ref: Array, f_ff: Array
    ) -> tuple[Array, NDArray[np.bool_]]:
        """Rotor thrusts (N, 4) in [0, f_max] [N] (a view of an internal array, overwritten by the next call) and the
        saturation flags (N,).

        Args:
            p, v: positions [m] and velocities [m/s] (world), (N, 3).
            R: body orientations, (N, 3, 3) (columns: body axes in world).
            w: angular velocities in the body frame [rad/s], (N, 3).
            p_ref, v_ref, a_ref: the reference [m, m/s, m/s²], (N, 3).
            f_ff: feed-forward force to cancel [N] (the planned tether pull on each drone), (N, 3).
        """
        s = self.spec
        f, b1, b2, b3, Rd, E, eR, tau, Jw, nrm = (
            self._f, self._b1, self._b2, self._b3, self._Rd, self._E, self._eR, self._tau, self._Jw, self._norm
        )  # fmt: skip
        np.subtract(p_ref, p, out=f)
        f *= self.kp
        np.subtract(v_ref, v, out=b1)  # b1 as scratch
        b1 *= self.kv
        f += b1
        f += a_ref
        f[:, 2] += s.g
        f *= s.mass
        f -= f_ff
        np.sqrt(np.einsum("ij,ij->i", f, f)[:, None], out=nrm)
        np.divide(f, nrm, out=b3)
        # b2 = b3 × e_x / |.| (yaw 0), b1 = b2 × b3
        b2[:, 0] = 0.0
        b2[:, 1] = b3[:, 2]
        np.negative(b3[:, 1], out=b2[:, 2])
        np.sqrt(np.einsum("ij,ij->i", b2, b2)[:, None], out=nrm)
        b2 /= nrm
        _cross(b2, b3, b1)
        Rd[:, :, 0], Rd[:, :, 1], Rd[:, :, 2] = b1, b2, b3
        np.matmul(Rd.transpose(0, 2, 1), R, out=E)  # e_R = ½ vee(E − Eᵀ), E = R_dᵀR
        np.subtract(E[:, 2, 1], E[:, 1, 2], out=eR[:, 0])
        np.subtract(E[:, 0, 2], E[:, 2, 0], out=eR[:, 1])
        np.subtract(E[:, 1, 0], E[:, 0, 1], out=eR[:, 2])
        eR *= -0.5 * s.att_gain  # ω_d = −k_att e_R, clipped
        np.clip(eR, -s.rate_max, s.rate_max, out=eR)
        eR -= w
        eR *= s.rate_gain
        np.multiply(eR, self.J, out=tau)
        np.multiply(w, self.J, out=Jw)
        _cross(w, Jw, b1)
        tau += b1  # τ = J k_rate (ω_d − ω) + ω × Jω
        thrust = self._thrust
        np.einsum("ij,ij->i", f, R[:, :, 2], out=thrust)
        self.demand[:] = thrust
        sat = (thrust < 0.0) | (thrust > 4.0 * self.fmax)
        np.clip(thrust, 0.0, 4.0 * self.fmax, out=thrust)
        u0, du, rot = self._u0, self._du, self._rotors
        np.multiply(thrust[:, None], self.minv[:, 0], out=u0)
        # roll and pitch first, then yaw in the room left (yaw has the least authority: c f against arm f)
        np.matmul(tau[:, :2], self.minv[:, 1:3].T, out=du)
        lam = _fit(u0, du, self.fmax)
        sat |= lam < 1.0
        du *= lam[:, None]
        u0 += du
        np.multiply(tau[:, 2:3], self.minv[:, 3], out=du)
        lam = _fit(u0, du, self.fmax)
        sat |= lam < 1.0
        np.multiply(du, lam[:, None], out=rot)
        rot += u0
        np.clip(rot, 0.0, self.fmax, out=rot)
        return rot, sat


def _cross(a: Array, b: Array, out: Array) -> None:
    """out = a × b row by row, (N, 3) (numpy's cross costs more in its axis handling than in the arithmetic)."""
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def _fit(u0: Array, du: Array, fmax: float) -> Array:
    """(N,) the largest λ in [0, 1] with u0 + λ du inside [0, f_max] for every rotor (u0 inside)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(du > 0.0, (fmax - u0) / du, np.where(du < 0.0, -u0 / du, np.inf))
    return np.clip(room.min(axis=1), 0.0, 1.0)
