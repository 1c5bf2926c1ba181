"""A winched tether in MuJoCo: a chain of short rigid links whose common length follows the winch tension.

Model (``formulations/replay.md``): the tether is N links. Link k hangs from node k-1 on two hinges (about its
frame's z, then y) and a slide along its own axis; its length is s0 + slide. The N slides are tied equal by joint
equalities, so the cable keeps N equal segments and one length degree of freedom L = N s. A motor on a fixed
tendon over the N slides (the sum of the slides) is the winch: with the slides tied, the mean of the segment
tensions equals the motor force (Σ T_k = N F). The mass of the cable is lumped at the nodes (ρ s each; the last
node, held by the other end, ρ s / 2), and follows the paid-out length: :class:`TetherState` updates masses and the
capsules' collision sizes every step (``geom_size``, ``geom_pos``, ``geom_rbound``, ``geom_aabb``).

The winch law holds the cable's horizontal tension at T0 = torque / radius, the planner's catenary assumption
(Caruso 2021 §4.2.1, eq. 22): a lumped-mass chain with horizontal tension H has segment tension H / cos φ_k, so
the motor force is F = T0 · mean_k(1 / cos φ_k) (``winch="horizontal"``). ``winch="torque"`` instead holds the
tension at the winch end at T0 (a constant-torque pulley taken literally): F = T0 · mean_k(1/cos φ_k) / (1/cos φ_1).

Drone tethers (``params`` a :class:`tmr.model.catenary3d.DroneTetherParams`, ``formulations/drones.md``): the winch
keeps the tension *magnitude* T_w at the tether's lower end (``winch="lower"``, the planner's default) or upper end
(``winch="upper"``), whichever end that is at this instant, as the planner's model does. A hanging cable's tension
grows with height, T(z) = T_A + ρ g (z − z_A) (Irvine 1981), whatever its orientation (vertical included), so the
motor force is F = mean_k T_k = T_w + ρ g (mean_k z̄_k − z_w), z̄_k the segment midpoints, z_w the winch end's height.
The initial shape is :func:`tmr.model.catenary3d.solve3d`'s curve at equal arc length.

Units: m, kg, N, s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tmr.model.catenary import CatenaryParams, solve
from tmr.model.catenary3d import DroneTetherParams

Array = NDArray[np.float64]

#: capsule radius of the tether [m]: a thin cable; contacts are judged on it (``formulations/replay.md``).
TETHER_RADIUS = 0.002
#: hinge damping of the links [N m s/rad per kg m² of the node]: settles the cable's swinging (see replay.md).
HINGE_DAMPING = 0.002
#: rotational inertia given to each lumped node [kg m² per kg]: a small sphere, so no inertia matrix is singular.
NODE_INERTIA = 1e-4
#: stiff constraints (issue 17 measurement: default softness left the cable end 10 cm short, contacts 9 mm deep).
SOLREF = "0.004 1"
SOLIMP = "0.99 0.9999 0.0005 0.5 2"

#: winch laws: "horizontal" and "torque" for ground tethers (CatenaryParams), "lower" and "upper" (constant tension
#: magnitude T_w at that end) for drone tethers (DroneTetherParams).
WINCH_MODES = ("horizontal", "torque", "lower", "upper")
TetherParams = CatenaryParams | DroneTetherParams
#: node masses and capsules are resized when a segment's length changed by more than this [m] (0.2 mm: ≤ 0.2 % of a
#: 0.1 m segment's mass, below the cable's 2 mm radius for contacts).
RESIZE_STEP = 2e-4


def winch_tension(params: TetherParams) -> float:
    """The tension the winch law holds [N]: T0 (ground, horizontal or at the winch end) or T_w (drones)."""
    if isinstance(params, DroneTetherParams):
        return params.winch_tension
    return params.horizontal_tension


def catenary_nodes(p1: Array, p2: Array, n: int, params: TetherParams) -> tuple[Array, float]:
    """Nodes 0..n of the static catenary from p1 to p2 (world, [m]) at equal arc length, and its length [m].

    The cable hangs in the vertical plane through the two points (Caruso 2021 eq. 22; arc length from end 1
    S(x) = c (sinh((x - x_low)/c) - sinh(-x_low/c)), inverted in closed form).
    """
    p1, p2 = np.asarray(p1, float), np.asarray(p2, float)
    if isinstance(params, DroneTetherParams):  # the drone model: T_w at the winch end (tmr.model.catenary3d)
        from tmr.model.catenary3d import solve3d

        cat = solve3d(p1, p2, params)
        nodes = cat.points(n + 1)
        nodes[0], nodes[-1] = p1, p2
        return nodes, float(cat.length)
    d = p2[:2] - p1[:2]
    span = float(np.hypot(*d))
    if span < 1e-9:  # ends on one vertical: a straight segment
        nodes = p1 + np.linspace(0.0, 1.0, n + 1)[:, None] * (p2 - p1)
        return nodes, float(np.linalg.norm(p2 - p1))
    cat = solve(p1[2], p2[2], span, params)
    c, x_low = cat.c, float(cat.x_low)
    s = np.linspace(0.0, float(cat.length), n + 1)
    x = x_low + c * np.arcsinh(s / c + math.sinh(-x_low / c))
    z = float(cat.z_low) + c * (np.cosh((x - x_low) / c) - 1.0)
    u = d / span
    nodes = np.column_stack([p1[0] + x * u[0], p1[1] + x * u[1], z])
    nodes[0], nodes[-1] = p1, p2
    return nodes, float(cat.length)


def _frame(direction: Array) -> Array:
    """Rotation matrix whose x axis is ``direction``, y axis horizontal (z axis up-ish)."""
    x = direction / np.linalg.norm(direction)
    y = np.array([-x[1], x[0], 0.0])
    if np.linalg.norm(y) < 1e-9:
        y = np.array([0.0, 1.0, 0.0])
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    return np.column_stack([x, y, z])


def _quat(R: Array) -> Array:
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R).ravel())
    return q


def _f(v: float) -> str:
    return repr(float(v))


def _v(a: Array) -> str:
    return " ".join(_f(x) for x in a)


@dataclass(frozen=True)
class TetherSpec:
    """One tether to build.

    Attributes:
        name: prefix of its MuJoCo names.
        n_links: number of links N.
        root_body: body carrying the winch (the cable leaves it at ``root_local``, in that body's frame at qpos0).
        root_world: the exit point in world coordinates at qpos0 [m].
        end_body: body holding the other end ("world" for a fixed anchor).
        end_world: the other end in world coordinates at qpos0 [m].
        params: cable parameters (ground: T0, ρ, g; drones: T_w, ρ, g, winch end).
        contype, conaffinity: collision bits of the capsules.
        max_length: the longest the tether may be paid out [m] (0: 50 times the chord at qpos0, the slides' range).
        armature: added inertia of each hinge [kg m²] and slide [kg] (0 for the ground tethers; the light drone
            tethers need it: a 1.25 cm segment of a 15 g/m cable weighs 0.2 g next to a 1.5 kg drone, and MuJoCo's
            inertia matrix becomes singular; statics are unchanged).
    """

    name: str
    n_links: int
    root_body: str
    root_local: tuple[float, float, float]
    root_world: tuple[float, float, float]
    end_body: str
    end_world: tuple[float, float, float]
    params: TetherParams
    contype: int = 0
    conaffinity: int = 3
    max_length: float = 0.0
    armature: float = 0.0

    @property
    def chord(self) -> float:
        return float(np.linalg.norm(np.subtract(self.end_world, self.root_world)))

    @property
    def s0(self) -> float:
        """Link length at qpos0 (the straight chord split in N) [m]."""
        return self.chord / self.n_links


def tether_body_xml(spec: TetherSpec) -> str:
    """Nested ``<body>`` elements of the links, to place inside ``spec.root_body``."""
    n, s0 = spec.n_links, spec.s0
    d = np.subtract(spec.end_world, spec.root_world)
    q1 = _quat(_frame(d))
    m = spec.params.mass_per_length * s0
    r = TETHER_RADIUS
    geom_q = "0.7071067811865476 0 0.7071067811865476 0"
    damping = HINGE_DAMPING
    arm = f' armature="{_f(spec.armature)}"' if spec.armature > 0 else ""
    parts = []
    for k in range(1, n + 1):
        mk = m if k < n else 0.5 * m
        if k == 1:
            pos = np.asarray(spec.root_local) + s0 * d / np.linalg.norm(d)
            head = f'<body name="{spec.name}_l{k}" pos="{_v(pos)}" quat="{_v(q1)}">'
        else:
            head = f'<body name="{spec.name}_l{k}" pos="{_f(s0)} 0 0">'
        parts.append(
            head
            + f'<joint name="{spec.name}_z{k}" type="hinge" axis="0 0 1" pos="{_f(-s0)} 0 0" damping="{damping}"{arm}/>'
            + f'<joint name="{spec.name}_y{k}" type="hinge" axis="0 1 0" pos="{_f(-s0)} 0 0" damping="{damping}"{arm}/>'
            + f'<joint name="{spec.name}_s{k}" type="slide" axis="1 0 0" limited="true" '
            f'range="{_f(-0.95 * s0)} {_f(max(50.0 * s0, spec.max_length / n - s0))}"{arm}/>'
            + f'<inertial pos="0 0 0" mass="{_f(mk)}" diaginertia="{_v([NODE_INERTIA * mk] * 3)}"/>'
            + f'<geom name="{spec.name}_g{k}" type="capsule" size="{_f(r)} {_f(s0 / 2)}" pos="{_f(-s0 / 2)} 0 0" '
            f'quat="{geom_q}" contype="{spec.contype}" conaffinity="{spec.conaffinity}" rgba="0.95 0.6 0.1 1" '
            f'solref="{SOLREF}" solimp="{SOLIMP}" group="1"/>'
        )
        if k == 1:
            parts.append(f'<site name="{spec.name}_root" pos="{_f(-s0)} 0 0" size="0.004"/>')
    return "".join(parts) + "</body>" * n


def tether_extra_xml(spec: TetherSpec) -> dict[str, str]:
    """Equality, tendon, actuator and sensor elements of the tether (keys: equality, tendon, actuator, sensor)."""
    n = spec.n_links
    eq = [
        f'<connect name="{spec.name}_end" body1="{spec.name}_l{n}" '
        + (f'body2="{spec.end_body}" ' if spec.end_body != "world" else "")
        + f'anchor="0 0 0" solref="{SOLREF}" solimp="{SOLIMP}"/>'
    ]
    eq += [
        f'<joint name="{spec.name}_eq{k}" joint1="{spec.name}_s{k}" joint2="{spec.name}_s1" polycoef="0 1 0 0 0" '
        f'solref="{SOLREF}" solimp="{SOLIMP}"/>'
        for k in range(2, n + 1)
    ]
    joints = "".join(f'<joint joint="{spec.name}_s{k}" coef="1"/>' for k in range(1, n + 1))
    return {
        "equality": "".join(eq),
        "tendon": f'<fixed name="{spec.name}_len">{joints}</fixed>',
        "actuator": f'<motor name="{spec.name}_winch" tendon="{spec.name}_len" gear="1" ctrllimited="false"/>',
        "sensor": f'<force name="{spec.name}_rootforce" site="{spec.name}_root"/>',
    }


def initial_qpos(spec: TetherSpec, root_world: Array, end_world: Array) -> tuple[Array, Array, Array]:
    """(hinge z angles, hinge y angles, slides) that put the tether on its static catenary between the two ends
    (world [m]), for a root body whose frame is world-aligned (robots start at yaw 0)."""
    nodes, _ = catenary_nodes(root_world, end_world, spec.n_links, spec.params)
    seg = np.diff(nodes, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    d = np.subtract(spec.end_world, spec.root_world)
    R_prev = _frame(d)
    az, ay = np.zeros(spec.n_links), np.zeros(spec.n_links)
    for k in range(spec.n_links):
        R_k = _frame(seg[k])
        rel = R_prev.T @ R_k  # = Rz(a) Ry(b)
        az[k] = math.atan2(rel[1, 0], rel[0, 0])
        ay[k] = math.atan2(-rel[2, 0], math.hypot(rel[0, 0], rel[1, 0]))
        R_prev = R_k
    slides = np.full(spec.n_links, float(np.mean(lengths)) - spec.s0)
    return az, ay, slides


class TetherState:
    """Indices of one tether in a compiled model, and its per-step updates (winch force, masses, capsules)."""

    def __init__(self, model: object, spec: TetherSpec, winch: str = "horizontal") -> None:
        import mujoco

        if winch not in WINCH_MODES:
            raise ValueError(f"winch must be one of {WINCH_MODES}, got {winch!r}")
        if isinstance(spec.params, DroneTetherParams) != (winch in ("lower", "upper")):
            raise ValueError(f"winch {winch!r} does not go with {type(spec.params).__name__} (see WINCH_MODES)")
        self.spec = spec
        self.winch = winch
        m = model
        n = spec.n_links
        name = spec.name

        def jid(j: str) -> int:
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)

        self.body = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{name}_l{k}") for k in range(1, n + 1)])
        self.geom = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{name}_g{k}") for k in range(1, n + 1)])
        self.z_q = np.array([m.jnt_qposadr[jid(f"{name}_z{k}")] for k in range(1, n + 1)])
        self.y_q = np.array([m.jnt_qposadr[jid(f"{name}_y{k}")] for k in range(1, n + 1)])
        self.s_q = np.array([m.jnt_qposadr[jid(f"{name}_s{k}")] for k in range(1, n + 1)])
        self.s_dof = np.array([m.jnt_dofadr[jid(f"{name}_s{k}")] for k in range(1, n + 1)])
        self.z_dof = np.array([m.jnt_dofadr[jid(f"{name}_z{k}")] for k in range(1, n + 1)])
        self.y_dof = np.array([m.jnt_dofadr[jid(f"{name}_y{k}")] for k in range(1, n + 1)])
        self.site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"{name}_root")  # on link 1: frame of the sensor
        self.root_joint = jid(f"{name}_z1")  # its anchor is the exit point
        self.actuator = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{name}_winch")
        self.eq_end = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, f"{name}_end")
        sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, f"{name}_rootforce")
        self.sensor_adr = int(m.sensor_adr[sid])
        self.end_body = 0 if spec.end_body == "world" else mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, spec.end_body)
        self.s0 = spec.s0
        self.rho = spec.params.mass_per_length
        self.t0 = winch_tension(spec.params)
        self.weight = self.rho * spec.params.g  # ρ g [N/m]
        self._resized = -1.0  # segment length of the last resize [m]
        self._z = np.zeros(n + 1)  # node heights, reused every step (the drone winch law)
        self._n = float(n)
        self._xanchor_z = 3 * self.root_joint + 2  # flat index of the exit point's z in data.xanchor

    def set_initial(self, data: object, root_world: Array, end_world: Array) -> None:
        az, ay, sl = initial_qpos(self.spec, root_world, end_world)
        data.qpos[self.z_q] = az  # type: ignore[attr-defined]
        data.qpos[self.y_q] = ay  # type: ignore[attr-defined]
        data.qpos[self.s_q] = sl  # type: ignore[attr-defined]

    def nodes(self, data: object) -> Array:
        """(N+1, 3) node positions [m]: the exit point, then the link ends."""
        root = np.asarray(data.xanchor[self.root_joint])  # type: ignore[attr-defined]  # the exit point
        return np.vstack([root[None, :], np.asarray(data.xpos[self.body])])  # type: ignore[attr-defined]

    def segment_length(self, data: object) -> float:
        # the mean of the slides (the same sum and division as np.mean, without its Python overhead)
        return float(self.s0 + data.qpos[self.s_q].sum() / self._n)  # type: ignore[attr-defined]

    def length(self, data: object) -> float:
        """Paid-out length N s [m]."""
        return self.spec.n_links * self.segment_length(data)

    def winch_force(self, data: object) -> float:
        """Motor force on the tendon [N], negative = reeling in (see the module docstring)."""
        if self.winch in ("lower", "upper"):  # constant tension magnitude T_w at that end (drone model)
            z = self._z  # the nodes' heights, without building the (N+1, 3) nodes
            z[0] = data.xanchor.flat[self._xanchor_z]  # type: ignore[attr-defined]
            np.take(data.xpos[:, 2], self.body, out=z[1:])  # type: ignore[attr-defined]
            zw = min(z[0], z[-1]) if self.winch == "lower" else max(z[0], z[-1])
            zbar = (2.0 * float(z.sum()) - z[0] - z[-1]) / (2.0 * (len(z) - 1))  # mean segment midpoint
            return -(self.t0 + self.weight * (zbar - zw))
        seg = np.diff(self.nodes(data), axis=0)
        h2 = seg[:, 0] * seg[:, 0] + seg[:, 1] * seg[:, 1]
        s2 = h2 + seg[:, 2] * seg[:, 2]
        sec = np.sqrt(s2 / np.maximum(h2, 0.0025 * s2 + 1e-18))  # 1 / cos φ_k, capped at 20 (a near-vertical link)
        force = self.t0 * float(sec.mean())
        if self.winch == "torque":
            force /= float(sec[0])
        return -force

    def update(self, model: object, data: object) -> None:
        """Winch force, node masses and capsule sizes for the current paid-out length (masses and capsules only when
        a segment changed by more than :data:`RESIZE_STEP` since the last resize)."""
        s = self.segment_length(data)
        data.ctrl[self.actuator] = self.winch_force(data)  # type: ignore[attr-defined]
        if abs(s - self._resized) <= RESIZE_STEP:
            return
        self._resized = s
        m = self.rho * s
        masses = np.full(len(self.body), m)
        masses[-1] *= 0.5
        model.body_mass[self.body] = masses  # type: ignore[attr-defined]
        model.body_inertia[self.body] = (NODE_INERTIA * masses)[:, None]  # type: ignore[attr-defined]
        model.geom_size[self.geom, 1] = 0.5 * s  # type: ignore[attr-defined]
        model.geom_pos[self.geom, 0] = -0.5 * s  # type: ignore[attr-defined]
        model.geom_rbound[self.geom] = 0.5 * s + TETHER_RADIUS  # type: ignore[attr-defined]
        model.geom_aabb[self.geom, 5] = 0.5 * s + TETHER_RADIUS  # type: ignore[attr-defined]

    def root_force(self, data: object) -> Array:
        """Force the cable exerts on the winch's body at the exit point, world frame [N]: the interaction force of
        the first link (force sensor) plus the weight of the half segment next to the exit (lumped at node 0, carried
        by the winch)."""
        a = self.sensor_adr
        f_site = np.asarray(data.sensordata[a : a + 3])  # type: ignore[attr-defined]
        R = np.asarray(data.site_xmat[self.site]).reshape(3, 3)  # type: ignore[attr-defined]
        half = 0.5 * self.rho * self.segment_length(data) * self.spec.params.g
        return -(R @ f_site) - np.array([0.0, 0.0, half])  # the sensor gives the force on the link

    def root_tension(self, data: object) -> float:
        """Tension at the winch end [N]."""
        return float(np.linalg.norm(self.root_force(data)))

    def end_tension(self, data: object) -> float:
        """Tension at the far end [N] (force of the end's connect equality)."""
        import mujoco

        rows = (np.asarray(data.efc_type) == mujoco.mjtConstraint.mjCNSTR_EQUALITY) & (  # type: ignore[attr-defined]
            np.asarray(data.efc_id) == self.eq_end  # type: ignore[attr-defined]
        )
        return float(np.linalg.norm(np.asarray(data.efc_force)[rows]))  # type: ignore[attr-defined]


@dataclass(frozen=True)
class HangResult:
    """A tether hung between two fixed points and let settle (units: m, N).

    lowest: lowest node height; length: paid-out length N s; tension_winch / tension_far: end tensions;
    end_gap: distance between the last node and the far end (constraint error); speed: largest joint speed at the
    end (how still it is).
    """

    lowest: float
    length: float
    tension_winch: float
    tension_far: float
    end_gap: float
    speed: float


def hang(
    p1: tuple[float, float, float],
    p2: tuple[float, float, float],
    params: TetherParams,
    n_links: int = 16,
    timestep: float = 0.005,
    duration: float = 2.0,
    winch: str | None = None,
    floor: bool = False,
) -> HangResult:
    """Hang one winched tether between a fixed winch at ``p1`` and a fixed point ``p2`` (world [m]), start it on
    its static catenary, simulate ``duration`` seconds and measure it (the static check of ``replay.md``).
    ``winch``: the winch law (default: "horizontal" for ground tethers, ``params.winch_end`` for drone tethers)."""
    if winch is None:
        winch = params.winch_end if isinstance(params, DroneTetherParams) else "horizontal"
    import mujoco

    spec = TetherSpec("t1", n_links, "winch", (0.0, 0.0, 0.0), p1, "world", p2, params)
    ex = tether_extra_xml(spec)
    ground = '<geom type="plane" size="50 50 0.1" contype="1" conaffinity="0"/>' if floor else ""
    xml = (
        f'<mujoco><option timestep="{timestep!r}" integrator="implicitfast" gravity="0 0 {-params.g!r}"/>'
        f'<worldbody>{ground}<body name="winch" pos="{_v(np.asarray(p1))}">{tether_body_xml(spec)}</body>'
        f"</worldbody><equality>{ex['equality']}</equality><tendon>{ex['tendon']}</tendon>"
        f"<actuator>{ex['actuator']}</actuator><sensor>{ex['sensor']}</sensor></mujoco>"
    )
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    ts = TetherState(model, spec, winch)
    ts.set_initial(data, np.asarray(p1, float), np.asarray(p2, float))
    mujoco.mj_kinematics(model, data)
    for _ in range(int(round(duration / timestep))):
        ts.update(model, data)
        mujoco.mj_step(model, data)
    mujoco.mj_forward(model, data)
    nodes = ts.nodes(data)
    return HangResult(
        lowest=float(nodes[:, 2].min()),
        length=ts.length(data),
        tension_winch=ts.root_tension(data),
        tension_far=ts.end_tension(data),
        end_gap=float(np.linalg.norm(nodes[-1] - np.asarray(p2))),
        speed=float(np.abs(data.qvel).max()),
    )
