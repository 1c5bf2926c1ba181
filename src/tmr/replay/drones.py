"""Physics replay of a drone-chain plan (``tmr plan`` on a ``kind = "drone"`` scenario) in MuJoCo.

The model (``formulations/replay.md``, "Drone chains"): the run's 3-D world (:func:`tmr.replay.world.world3d_xml`:
floor, walls and ceiling round the room, boxes, prisms, meshes); N quadrotors of the planner's mass and thrust limits
flown by a cascaded controller (:mod:`tmr.replay.quadrotor`) along the planned trajectories; N winched tethers
(:mod:`tmr.replay.tether`, the ground replay's segmented cable in 3-D): tether 1 leaves the ground winch at the run's
base point, tether j joins drone j-1 to drone j; the winch law holds the tension magnitude T_w at the end the planner
says (``winch_end``, the lower end by default).

:func:`replay_drones` steps the model over the plan and records, at every plan sample, the drones' positions and
tilts, each tether's lowest point, paid-out length and end tensions next to the static catenary of the same ends and
to the planner's catenary of the planned ends (:func:`tmr.model.catenary3d.solve3d`); at every physics step the rotor
thrusts (peak, mean, saturation) and every contact (tether-obstacle, tether-floor, drone-obstacle, drone-floor,
drone-drone). :func:`drone_verdict` judges it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.replay.errors import ReplayError
from tmr.replay.quadrotor import QuadrotorControl, QuadrotorSpec, quadrotor_actuator_xml, quadrotor_body_xml
from tmr.replay.tether import TetherSpec, TetherState, tether_body_xml, tether_extra_xml
from tmr.replay.timing import RealTimeFactors
from tmr.replay.world import DRONE_BITS, TETHER_BITS, world3d_xml

Array = NDArray[np.float64]

__all__ = [
    "DRONE_CONTACT_KINDS",
    "DroneChain",
    "DroneReplay",
    "DroneReplayConfig",
    "build_drone_model",
    "chain_of_run",
    "drone_verdict",
    "quad_spec",
    "replay_drones",
]

#: simulated time holding the start pose before the plan's first sample [s] (not recorded; the constraint forces
#: of the cables and the controller settle).
WARMUP = 0.5
DRONE_CONTACT_KINDS = ("drone-obstacle", "drone-floor", "drone-drone", "tether-obstacle", "tether-floor")
#: fewest links of a drone tether (fewer: a rigid rod, not a cable)
MIN_LINKS = 4
#: largest k_rate dt of the body-rate loop (explicit in the controller: beyond it the loop rings and diverges)
MAX_RATE_STEP = 0.5
#: geom kinds
_FLOOR, _OBSTACLE, _TETHER, _DRONE = 0, 1, 2, 3


@dataclass(frozen=True)
class DroneReplayConfig:
    """Choices of the drone replay (``formulations/replay.md`` gives the reasons). Units: m, kg, N, s, rad.

    Attributes:
        n_links: links per tether.
        timestep: physics step [s]; the controller runs every step (200 Hz at 5 ms).
        tolerance: tracking error beyond which the replay fails [m] (0.1: see replay.md).
        saturation_limit: largest fraction of the physics steps a drone may have a rotor clipped at 0 or f_max [-]
            (0.01).
        max_tilt: a drone tilted more than this has lost control (a crash) [rad] (60°).
        tether_density: ρ of the simulated tethers [kg/m]; None: the plan's. The controller's feed-forward keeps
            the plan's catenaries (what a plan with a wrong ρ would give the drones).
        settle: simulated time after the plan's last sample [s].
        armature: added inertia of the tether joints [kg m² on hinges, kg on slides] (:class:`TetherSpec`).
        smoothing: σ [s] of the Gaussian the drones' reference is smoothed with (:func:`_reference`); the tracking
            error is measured against the plan's own positions.
        saturation_run: longest unbroken run of physics steps with a rotor clipped a drone may have [s] (0.05).
        pull_tolerance: the measured tether pull on a drone may exceed the planner's spare thrust by this fraction
            [-] (0.05: the simulated tension's ripple; replay.md).
        reserve_window: longest unbroken time the collective thrust a drone needs may exceed the planner's
            (1 − reserve) 4 f_max [s] (0.1).
        accel_budget: largest acceleration the smoothing may remove from the plan's, |a_plan − a_ref| at a plan
            sample [m/s²] (15: above 2·4√3 ≈ 13.9, the most a plan within the planner's 4 m/s² per axis can lose, so
            only a plan the drones cannot follow as planned fails it; replay.md).
        clearance_fraction: a simulated tether nearer the floor or an obstacle than this fraction of the planner's
            tether clearance c_t fails [-] (0.5).
        length_tolerance: paid-out length beyond the planner's ``tether_length`` that fails [-] (0.01).
    """

    n_links: int = 16
    timestep: float = 0.005
    tolerance: float = 0.1
    saturation_limit: float = 0.01
    max_tilt: float = math.radians(60.0)
    tether_density: float | None = None
    settle: float = 0.0
    armature: float = 1e-4
    smoothing: float = 0.15
    saturation_run: float = 0.05
    pull_tolerance: float = 0.05
    reserve_window: float = 0.1
    accel_budget: float = 15.0
    clearance_fraction: float = 0.5
    length_tolerance: float = 0.01

    def __post_init__(self) -> None:
        from tmr.replay.chain import MAX_LINKS

        if not MIN_LINKS <= self.n_links <= MAX_LINKS:
            raise ReplayError(
                f"--links must be {MIN_LINKS} … {MAX_LINKS} links per drone tether (fewer make a rigid rod), "
                f"got {self.n_links}"
            )
        k_rate = QuadrotorSpec().rate_gain
        if k_rate * self.timestep > MAX_RATE_STEP:
            raise ReplayError(
                f"--timestep {self.timestep:g} s is too large for the drones' rate loop (k_rate dt = "
                f"{k_rate * self.timestep:g} > {MAX_RATE_STEP:g}): use at most {MAX_RATE_STEP / k_rate:g} s"
            )
        if self.tether_density is not None and not (math.isfinite(self.tether_density) and self.tether_density > 0):
            raise ReplayError(f"--tether-density must be a finite number > 0 kg/m, got {self.tether_density!r}")


@dataclass(frozen=True)
class DroneChain:
    """What the replay needs of a drone plan (a :class:`tmr.io.drones.DroneRun` gives it through :func:`chain_of_run`).

    Attributes:
        t: (K,) sample times [s], uniform step Ts.
        positions, velocities: (K, N, 3) planned drone positions [m] and the velocity of each step [m/s]
            (p_{k+1} = p_k + Ts v_k).
        base: (3,) the ground winch [m], or None for a chain without a ground tether (tether j joins drone j-1 and j).
        params: the plan's tether and drone parameters (:class:`tmr.model.catenary3d.DroneTetherParams`).
        world: the ``[world]`` table (None: an empty room of ``bounds``); world_dir: its mesh paths' folder.
        bounds: (6,) the room [m].
        label: how messages name the run.
        winch_tension: (K, J) an active winch's planned tension of every tether at every sample [N] (None: the
            constant ``params.winch_tension``); the replay's winches follow it, linear between samples.
    """

    t: Array
    positions: Array
    velocities: Array
    base: Array | None
    params: Any
    world: dict[str, Any] | None
    world_dir: Path
    bounds: Array
    label: str = "drone chain"
    winch_tension: Array | None = None

    @property
    def n(self) -> int:
        return int(self.positions.shape[1])

    def tether_ends(self) -> list[tuple[int, int]]:
        """(from, to) drone indices of every tether (from = -1: the ground winch)."""
        first = [(-1, 0)] if self.base is not None else []
        return first + [(i - 1, i) for i in range(1, self.n)]


def chain_of_run(run: Any) -> DroneChain:
    """The :class:`DroneChain` of a :class:`tmr.io.drones.DroneRun` (its world is validated first: RunDirError)."""
    run.world()  # a world that does not load is bad input (exit 2), before anything is built
    return DroneChain(
        t=np.asarray(run.t, dtype=float),
        positions=np.asarray(run.robots, dtype=float),
        velocities=np.asarray(run.velocities, dtype=float),
        base=np.asarray(run.base, dtype=float),
        params=run.tether_params(),
        world=run.world_table,
        world_dir=run.world_dir,
        bounds=np.asarray(run.bounds, dtype=float),
        label=run.label,
        winch_tension=None if run.winch_tension is None else np.asarray(run.winch_tension, dtype=float),
    )


@dataclass
class DroneModel:
    """A compiled drone-chain model: the MuJoCo model, tethers, index maps (precomputed for the hot loop)."""

    model: Any
    xml: str
    quad: QuadrotorSpec
    tethers: list[TetherState]
    ends: list[tuple[int, int]]
    body: NDArray[np.int64]  # (N,) drone body ids
    pos_q: NDArray[np.int64]  # (N, 3) qpos addresses of the positions
    lin_v: NDArray[np.int64]  # (N, 3) qvel addresses of the linear velocities (world frame)
    ang_v: NDArray[np.int64]  # (N, 3) qvel addresses of the angular velocities (body frame)
    rotors: NDArray[np.int64]  # (N, 4) actuator ids
    geom_kind: NDArray[np.int64]  # 0 floor, 1 obstacle/wall/ceiling, 2 tether, 3 drone, -1 other
    geom_owner: NDArray[np.int64]
    geom_names: list[str]


@dataclass
class DroneReplay(RealTimeFactors):
    """What a drone replay measured (per plan sample k; drones i, tethers j). Units: m, N, s, rad."""

    t: Array
    reference: Array  # (K, N, 3) planned positions
    actual: Array  # (K, N, 3)
    tracking_error: Array  # (K, N)
    tilt: Array  # (K, N) angle of the body z axis from the vertical
    rotor_max: Array  # (K, N) largest rotor thrust over the physics steps up to sample k
    rotor_peak: Array  # (N,) largest rotor thrust of the whole replay
    rotor_mean: Array  # (N,) mean rotor thrust (over rotors and physics steps)
    saturated_steps: NDArray[np.int64]  # (N,) physics steps with a rotor clipped at 0 or f_max
    first_saturation: list[float | None]  # (N,) time of the first clipped step
    rotor_limit: float  # f_max [N]
    ends: list[tuple[int, int]]
    lowest: Array  # (K, J) lowest node height (the ends included: see sag)
    lowest_catenary: Array  # (K, J) the static catenary's lowest point, same ends and ρ as simulated
    lowest_plan: Array  # (K, J) the planner's catenary at the planned ends (plan's ρ)
    length: Array  # (K, J) paid-out length
    length_catenary: Array
    tension_from: Array  # (K, J) tension at the tether's start (base or drone j-1)
    tension_to: Array  # (K, J) tension at drone j
    tension_from_catenary: Array
    tension_to_catenary: Array
    tension_from_plan: Array
    tension_to_plan: Array
    contacts: dict[str, dict[str, Any]]
    tether_contact_steps: NDArray[np.int64]  # (J,) physics steps with the tether touching an obstacle or the floor
    reference_deviation: Array  # (N,) largest distance of the smoothed reference from the plan at the samples
    nodes: list[Array]  # per sample, (J, n_links+1, 3)
    sim_time: float
    wall_time: float
    cpu_time: float
    steps: int
    diverged: str | None = None
    config: DroneReplayConfig = field(default_factory=DroneReplayConfig)
    gains: dict[str, Any] = field(default_factory=dict)
    qpos: list[Array] = field(default_factory=list)
    built: DroneModel | None = None
    saturation_run: Array = field(default_factory=lambda: np.zeros(0))  # (N,) longest unbroken clipped run [s]
    saturation_run_at: Array = field(default_factory=lambda: np.zeros(0))  # (N,) its start [s]
    reserve_run: Array = field(default_factory=lambda: np.zeros(0))  # (N,) longest run beyond the reserve [s]
    reserve_run_at: Array = field(default_factory=lambda: np.zeros(0))
    reserve_thrust: float = math.inf  # (1 − r_c) 4 f_max [N]
    spare_thrust: float = math.inf  # the planner's spare thrust [N]
    thrust_demand: Array = field(default_factory=lambda: np.zeros((0, 0)))  # (K, N) largest collective thrust asked
    pull: Array = field(default_factory=lambda: np.zeros((0, 0)))  # (K, N) largest tether tension at the drone
    accel_removed: Array = field(default_factory=lambda: np.zeros((0, 0)))  # (K_plan, N) |a_plan − a_ref| [m/s²]
    sag: Array = field(default_factory=lambda: np.zeros((0, 0)))  # (K, J) inner nodes' depth below the chord
    sag_plan: Array = field(default_factory=lambda: np.zeros((0, 0)))  # (K, J) the planner's catenary's, same way
    clearance: Array = field(default_factory=lambda: np.zeros((0, 0)))  # (K, J) distance to the world [m]
    tether_clearance: float = 0.0  # c_t [m]
    tether_length: float = math.inf  # the planner's tether_length [m]
    warnings: dict[str, int] = field(default_factory=dict)  # MuJoCo's warnings (name: count)
    warning_messages: list[str] = field(default_factory=list)  # their text (first 20), not printed

    @property
    def saturation_fraction(self) -> Array:
        """(N,) fraction of the physics steps with a rotor clipped."""
        return self.saturated_steps / max(self.steps, 1)


def _sim_params(chain: DroneChain, cfg: DroneReplayConfig) -> Any:
    """The simulated tethers' parameters: the plan's, with ``cfg.tether_density`` if given."""
    if cfg.tether_density is None:
        return chain.params
    return replace(chain.params, mass_per_length=float(cfg.tether_density))


def quad_spec(params: Any) -> QuadrotorSpec:
    """The quadrotor of the planner's parameters (mass, thrust-to-weight, g, radius)."""
    return QuadrotorSpec(
        mass=params.drone_mass, thrust_to_weight=params.thrust_to_weight, g=params.g, radius=params.drone_radius
    )


def build_drone_model(chain: DroneChain, cfg: DroneReplayConfig) -> DroneModel:
    """Compile the MuJoCo model of a drone chain (drones level at their first planned position)."""
    import mujoco

    params = _sim_params(chain, cfg)
    quad = quad_spec(chain.params)
    start = chain.positions[0]
    n = chain.n
    ends = chain.tether_ends()
    specs: list[TetherSpec] = []
    for j, (a, b) in enumerate(ends):
        root = tuple(float(v) for v in (chain.base if a < 0 else start[a]))  # type: ignore[index]
        specs.append(
            TetherSpec(
                name=f"t{j + 1}",
                n_links=cfg.n_links,
                root_body="winch" if a < 0 else f"d{a + 1}",
                root_local=(0.0, 0.0, 0.0),
                root_world=root,  # type: ignore[arg-type]
                end_body=f"d{b + 1}",
                end_world=tuple(float(v) for v in start[b]),  # type: ignore[arg-type]
                params=params,
                contype=TETHER_BITS[0],
                conaffinity=TETHER_BITS[1],
                max_length=1.5 * float(params.tether_length),
                armature=cfg.armature,
            )
        )
    inner = ["" for _ in range(n)]
    winch = ""
    for (a, _), spec in zip(ends, specs, strict=True):
        if a < 0:
            winch = tether_body_xml(spec)
        else:
            inner[a] += tether_body_xml(spec)
    dt, da = DRONE_BITS
    bodies = [quadrotor_body_xml(f"d{i + 1}", start[i], quad, dt, da, inner[i]) for i in range(n)]
    if chain.world is not None:
        assets, world, _ = world3d_xml(chain.world, chain.world_dir)
    else:
        assets, world, _ = world3d_xml({"bounds": chain.bounds.tolist()}, chain.world_dir)
    base = ""
    if chain.base is not None:
        bx, by, bz = (float(v) for v in chain.base)
        z0 = float(chain.bounds[2])
        base = (
            f'<body name="winch" pos="{bx!r} {by!r} {bz!r}"><site name="winch" size="0.05" rgba="0 0 0 1"/>'
            f'<geom type="cylinder" pos="0 0 {(z0 - bz) / 2!r}" size="0.06 {max((bz - z0) / 2, 1e-3)!r}" '
            f'contype="0" conaffinity="0" rgba="0.1 0.1 0.1 1"/>{winch}</body>'
        )
    extras = [tether_extra_xml(s) for s in specs]
    g = float(params.g)
    xml = (
        '<mujoco model="tmr-replay-drones"><compiler angle="radian"/>'
        f'<option timestep="{cfg.timestep!r}" integrator="implicitfast" gravity="0 0 {-g!r}"/>'
        '<visual><global offwidth="960" offheight="720"/><quality shadowsize="2048"/></visual>'
        f"<asset>{assets}</asset><worldbody>"
        '<light pos="0 0 20" dir="0 0 -1" directional="true" diffuse="0.7 0.7 0.7"/>'
        f"{world}{base}" + "".join(bodies) + "</worldbody>"
        "<equality>" + "".join(e["equality"] for e in extras) + "</equality>"
        "<tendon>" + "".join(e["tendon"] for e in extras) + "</tendon>"
        "<actuator>"
        + "".join(quadrotor_actuator_xml(f"d{i + 1}", quad) for i in range(n))
        + "".join(e["actuator"] for e in extras)
        + "</actuator>"
        "<sensor>" + "".join(e["sensor"] for e in extras) + "</sensor></mujoco>"
    )
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:
        raise ReplayError(f"MuJoCo could not compile the replay model: {exc}") from None
    tethers = [TetherState(model, s, str(params.winch_end)) for s in specs]
    body = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"d{i + 1}") for i in range(n)])
    jnt = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"d{i + 1}_free") for i in range(n)]
    qa = np.array([int(model.jnt_qposadr[j]) for j in jnt])
    va = np.array([int(model.jnt_dofadr[j]) for j in jnt])
    rotors = np.array(
        [[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"d{i + 1}_m{k}") for k in range(4)] for i in range(n)]
    )
    kinds = np.full(model.ngeom, -1)
    owner = np.full(model.ngeom, -1)
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, k) or "" for k in range(model.ngeom)]
    for k, nm in enumerate(names):
        if nm == "floor":
            kinds[k] = _FLOOR
        elif nm.startswith(("obs", "wall_")):
            kinds[k] = _OBSTACLE
        elif nm.startswith("t") and "_g" in nm:
            kinds[k], owner[k] = _TETHER, int(nm[1:].split("_")[0]) - 1
        elif nm.startswith("d") and nm.endswith("_body"):
            kinds[k], owner[k] = _DRONE, int(nm[1:].split("_")[0]) - 1
    return DroneModel(
        model=model,
        xml=xml,
        quad=quad,
        tethers=tethers,
        ends=ends,
        body=body,
        pos_q=qa[:, None] + np.arange(3),
        lin_v=va[:, None] + np.arange(3),
        ang_v=va[:, None] + 3 + np.arange(3),
        rotors=rotors,
        geom_kind=kinds,
        geom_owner=owner,
        geom_names=names,
    )


def _reference(chain: DroneChain, times: Array, smoothing: float) -> tuple[Array, Array, Array]:
    """Position, velocity, acceleration the drones are given at ``times`` (uniform steps): the cubic Hermite curve
    through the planned positions with, at each inner sample, the mean of the plan's velocities on the steps before
    and after it and zero velocity at both ends (the plan starts and ends at rest), convolved with a Gaussian of
    standard deviation ``smoothing`` [s] (zero phase, before the flight); the velocity is the curve's derivative
    convolved with the same Gaussian, padded consistently (the position held at its end values, the velocity zero,
    beyond both ends), so it is the derivative of the smoothed position; the acceleration is its derivative."""
    from scipy.interpolate import CubicHermiteSpline
    from scipy.ndimage import gaussian_filter1d

    v = chain.velocities
    knot_v = 0.5 * (np.concatenate([np.zeros_like(v[:1]), v[:-1]]) + v)
    knot_v[0] = 0.0
    knot_v[-1] = 0.0
    sp = CubicHermiteSpline(chain.t, chain.positions, knot_v, axis=0)
    tt = np.clip(times, chain.t[0], chain.t[-1])
    if smoothing <= 0 or times.size < 2:
        return sp(tt), sp(tt, 1), sp(tt, 2)
    dt = float(times[1] - times[0])
    sigma = smoothing / dt
    # the position padded with its end values (at rest before and after), so its velocity padded with zeros: the
    # convolutions then commute with the derivative (scipy's truncated derivative-of-Gaussian kernels do not sum
    # to zero, which would turn a position of 3 m into an acceleration of 0.13 m/s²). The acceleration is the
    # derivative of that velocity (second-order differences: the curve's own acceleration jumps at the samples,
    # which sampled and convolved would be off by ~1 %).
    p = gaussian_filter1d(sp(tt), sigma, axis=0, mode="nearest", truncate=4.0)
    v = gaussian_filter1d(np.where(times[:, None, None] > chain.t[-1], 0.0, sp(tt, 1)), sigma, axis=0,
                          mode="constant", truncate=4.0)  # fmt: skip
    a = np.gradient(v, dt, axis=0, edge_order=2) if times.size > 2 else np.zeros_like(v)
    return p, v, a


def _planned_catenaries(
    chain: DroneChain, ends: list[tuple[int, int]], n_sag: int = 65
) -> tuple[Array, Array, Array, Array, Array]:
    """Per plan sample, the planner's catenaries (plan's parameters, planned ends): the force they put on every
    drone (K, N, 3) [N], each tether's lowest point (K, J) [m], end tensions at its start and at its drone (K, J)
    [N] and its sag below the chord (:func:`_sag` of ``n_sag`` points) (K, J) [m]. A sample where no catenary
    exists (not in a checked plan) keeps the previous sample's values."""
    from tmr.errors import TetherSpanError
    from tmr.model.catenary3d import solve3d

    K, n = chain.positions.shape[:2]
    J = len(ends)
    force = np.zeros((K, n, 3))
    lowest, t_from, t_to = np.full((K, J), np.nan), np.full((K, J), np.nan), np.full((K, J), np.nan)
    sag = np.full((K, J), np.nan)
    warm: list[Any] = [None] * J
    for k in range(K):
        P = chain.positions[k]
        for j, (a, b) in enumerate(ends):
            p = chain.base if a < 0 else P[a]
            tw = None if chain.winch_tension is None else float(chain.winch_tension[k, j])
            try:
                cat = solve3d(p, P[b], chain.params, winch_tension=tw, warm=warm[j])
            except TetherSpanError:
                cat = warm[j]
                if cat is None:
                    continue
            warm[j] = cat
            force[k, b] += cat.force_q
            if a >= 0:
                force[k, a] += cat.force_p
            lowest[k, j], t_from[k, j], t_to[k, j] = float(cat.lowest[2]), cat.tension_p, cat.tension_q
            sag[k, j] = float(_sag(cat.points(n_sag)[None, None])[0, 0])
    return force, lowest, t_from, t_to, sag


def _contact_kind(k1: int, k2: int) -> str | None:
    pair = {k1, k2}
    if pair == {_TETHER, _FLOOR}:
        return "tether-floor"
    if pair == {_TETHER, _OBSTACLE}:
        return "tether-obstacle"
    if pair == {_DRONE, _OBSTACLE}:
        return "drone-obstacle"
    if pair == {_DRONE, _FLOOR}:
        return "drone-floor"
    if pair == {_DRONE}:
        return "drone-drone"
    return None


def _label(dm: Any, g: int) -> str:
    kind, owner = int(dm.geom_kind[g]), int(dm.geom_owner[g])
    if kind == _TETHER:
        return f"tether {owner + 1}"
    if kind == _DRONE:
        return f"drone {owner + 1}"
    name = dm.geom_names[g]
    if name.startswith("obs"):
        return f"obstacle #{name[3:].split('_')[0]}"
    return name.replace("wall_ceiling", "the ceiling").replace("wall_", "the wall ") or f"geom {g}"


def _count_tether_contacts(d: Any, dm: DroneModel, steps: NDArray[np.int64]) -> None:
    """Add 1 to ``steps[j]`` for every tether j in a penetrating contact with an obstacle or the floor this step."""
    n = d.ncon
    con = d.contact
    kinds = dm.geom_kind
    hit = set()
    for g1, g2, dist in zip(con.geom1[:n], con.geom2[:n], con.dist[:n], strict=True):
        if dist > 0:
            continue
        for a, b in ((g1, g2), (g2, g1)):
            if kinds[a] == _TETHER and kinds[b] in (_FLOOR, _OBSTACLE):
                hit.add(int(dm.geom_owner[a]))
    for j in hit:
        steps[j] += 1


def replay_drones(chain: DroneChain, cfg: DroneReplayConfig | None = None, progress: Any = None) -> DroneReplay:
    """Simulate a drone chain's plan in MuJoCo and measure it (module docstring).

    Args:
        chain: the plan (:func:`chain_of_run` of a run directory, or hand-made).
        cfg: replay choices.
        progress: optional callable(fraction) called every plan sample.

    Raises:
        ReplayError: the physics step does not divide the plan's sample time, the model does not compile.
    """
    import mujoco

    from tmr.errors import TetherSpanError
    from tmr.model.catenary3d import solve3d
    from tmr.replay.chain import _log_contacts

    cfg = cfg or DroneReplayConfig()
    t = chain.t
    Ts = float(t[1] - t[0]) if t.size > 1 else cfg.timestep
    sub = max(1, int(round(Ts / cfg.timestep)))
    if abs(sub * cfg.timestep - Ts) > 1e-9 * Ts:
        raise ReplayError(f"the physics step {cfg.timestep} s must divide the plan's sample time Ts = {Ts} s")
    dm = build_drone_model(chain, cfg)
    m = dm.model
    d = mujoco.MjData(m)
    n = chain.n
    ends = dm.ends
    J = len(ends)
    sim_params = _sim_params(chain, cfg)
    start = chain.positions[0]
    for (a, b), ts in zip(ends, dm.tethers, strict=True):
        root = chain.base if a < 0 else start[a]
        try:
            ts.set_initial(d, np.asarray(root, dtype=float), start[b])
        except TetherSpanError:  # no equilibrium (e.g. a heavier --tether-density): it starts straight (qpos0), and
            pass  # the winch pays out until the cable lies on something: the verdict tells
    mujoco.mj_kinematics(m, d)
    for ts in dm.tethers:
        ts.update(m, d)
    mujoco.mj_forward(m, d)

    n_settle = int(round(cfg.settle / Ts))
    K = t.size + n_settle
    times = t[0] + np.arange((K - 1) * sub + 1) * cfg.timestep
    p_ref, v_ref, a_ref = _reference(chain, times, cfg.smoothing)
    f_plan, low_plan, tf_plan, tt_plan, sag_plan = _planned_catenaries(chain, ends)
    # the feed-forward of every physics step: the planned catenary forces, linear between samples
    s_idx = np.minimum(np.arange(times.size) // sub, t.size - 1)
    frac = ((np.arange(times.size) % sub) / sub)[:, None, None]
    nxt = np.minimum(s_idx + 1, t.size - 1)
    f_ff = (1.0 - frac) * f_plan[s_idx] + frac * f_plan[nxt]
    tw_step = None  # an active winch: each winch's tension at every physics step, planned, linear between samples
    if chain.winch_tension is not None and J:
        tw_step = (1.0 - frac[:, :, 0]) * chain.winch_tension[s_idx] + frac[:, :, 0] * chain.winch_tension[nxt]
        for j, ts in enumerate(dm.tethers):
            ts.t0 = float(tw_step[0, j])
    ctl = QuadrotorControl(dm.quad, n)
    reserve_thrust = (1.0 - float(chain.params.control_reserve)) * 4.0 * dm.quad.rotor_max

    contacts: dict[str, dict[str, Any]] = {
        kind: {"count": 0, "first_time": None, "where": None, "between": None, "max_depth": 0.0}
        for kind in DRONE_CONTACT_KINDS
    }
    rec_actual = np.zeros((K, n, 3))
    rec_tilt = np.zeros((K, n))
    rec_rotor = np.zeros((K, n))
    rec_demand = np.zeros((K, n))
    rec_len = np.zeros((K, J))
    rec_tf = np.zeros((K, J))
    rec_tt = np.zeros((K, J))
    rec_nodes: list[Array] = []
    rec_qpos: list[Array] = []
    sat_steps = np.zeros(n, dtype=np.int64)
    teth_steps = np.zeros(J, dtype=np.int64)
    first_sat: list[float | None] = [None] * n
    # unbroken runs of physics steps: rotor clipped (saturation) and collective thrust beyond the reserve
    runs = {name: (np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64), np.full(n, np.nan)) for name in
            ("sat", "reserve")}  # fmt: skip
    rotor_sum = np.zeros(n)
    rotor_peak = np.zeros(n)
    P = np.zeros((n, 3))
    V = np.zeros((n, 3))
    W = np.zeros((n, 3))
    pq, lv, av, body, rot_ids = dm.pos_q, dm.lin_v, dm.ang_v, dm.body, dm.rotors
    rot_flat = rot_ids.reshape(-1)
    qpos, qvel, xmat, ctrl = d.qpos, d.qvel, d.xmat, d.ctrl
    zero3 = np.zeros((n, 3))

    R9 = np.zeros((n, 9))
    R = R9.reshape(n, 3, 3)  # a view: filled in place every step

    def control(p_r: Array, v_r: Array, a_r: Array, ff: Array) -> tuple[Array, NDArray[np.bool_]]:
        np.take(qpos, pq, out=P)
        np.take(qvel, lv, out=V)
        np.take(qvel, av, out=W)
        np.take(xmat, body, axis=0, out=R9)
        rot, sat = ctl.rotor_thrusts(P, V, R, W, p_r, v_r, a_r, ff)
        ctrl[rot_flat] = rot.reshape(-1)
        return rot, sat

    def track_run(name: str, flag: NDArray[np.bool_], now: float) -> None:
        cur, longest, at = runs[name]
        cur += flag
        cur[~flag] = 0
        better = cur > longest
        if better.any():
            longest[better] = cur[better]
            at[better] = now - (cur[better] - 1) * cfg.timestep  # the run's first step

    def record(k: int) -> None:
        np.take(qpos, pq, out=rec_actual[k])
        rec_tilt[k] = np.arccos(np.clip(xmat[body, 8], -1.0, 1.0))
        rec_nodes.append(np.stack([ts.nodes(d) for ts in dm.tethers]) if J else np.zeros((0, cfg.n_links + 1, 3)))
        rec_qpos.append(np.array(qpos))
        for j, ts in enumerate(dm.tethers):
            rec_len[k, j] = ts.length(d)
            rec_tf[k, j] = ts.root_tension(d)
            rec_tt[k, j] = ts.end_tension(d)

    def unstable() -> bool:
        return not np.all(np.isfinite(qpos)) or bool(d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)

    messages: list[str] = []
    old_warning = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda msg: messages.append(str(msg).strip()) if len(messages) < 20 else None)
    errstate = np.errstate(invalid="ignore", divide="ignore", over="ignore")  # a diverging model: the verdict tells
    errstate.__enter__()
    try:
        # warm-up at the start pose (t < 0, not recorded but checked: contacts logged, divergence caught): the
        # cables' constraint forces and the controller settle
        diverged = None
        n_warm = int(round(WARMUP / cfg.timestep))
        for i in range(n_warm):
            control(p_ref[0], zero3, zero3, f_ff[0])
            for ts in dm.tethers:
                ts.update(m, d)
            mujoco.mj_step(m, d)
            now = (i + 1 - n_warm) * cfg.timestep  # -WARMUP … 0
            if d.ncon:
                _log_contacts(d, dm, contacts, t[0] + now, kind_of=_contact_kind, label=_label)
            if unstable():
                diverged = f"the simulation diverged at t = {t[0] + now:.3f} s (warm-up)"
                break
        d.time = 0.0
        wall0, cpu0 = time.perf_counter(), time.process_time()
        record(0)
        step = 0
        for k in range(1 if diverged is None else K, K):
            row = rec_rotor[k]
            drow = rec_demand[k]
            for _ in range(sub):
                rot, sat = control(p_ref[step], v_ref[step], a_ref[step], f_ff[step])
                rmax = rot.max(axis=1)
                np.maximum(row, rmax, out=row)
                np.maximum(rotor_peak, rmax, out=rotor_peak)
                np.maximum(drow, ctl.demand, out=drow)
                rotor_sum += rot.sum(axis=1)
                now = float(times[step])
                track_run("sat", sat, now)
                track_run("reserve", ctl.demand > reserve_thrust, now)
                if sat.any():
                    sat_steps += sat
                    for i in np.flatnonzero(sat):
                        if first_sat[i] is None:
                            first_sat[i] = now
                if tw_step is not None:
                    for j, ts in enumerate(dm.tethers):
                        ts.t0 = tw_step[step, j]
                for ts in dm.tethers:
                    ts.update(m, d)
                mujoco.mj_step(m, d)
                step += 1
                if d.ncon:
                    _log_contacts(d, dm, contacts, times[step], kind_of=_contact_kind, label=_label)
                    _count_tether_contacts(d, dm, teth_steps)
            if unstable():
                diverged = f"the simulation diverged at t = {times[step]:.3f} s (non-finite accelerations)"
                break
            record(k)
            if progress is not None:
                progress(k / (K - 1))
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    finally:
        mujoco.set_mju_user_warning(old_warning)
        errstate.__exit__(None, None, None)
    warnings = {
        name: int(d.warning[int(w)].number)
        for name, w in mujoco.mjtWarning.__members__.items()
        if int(w) < len(d.warning) and d.warning[int(w)].number
    }
    K = len(rec_nodes)
    ext = np.minimum(np.arange(K), t.size - 1)  # the settle samples hold the last planned one
    ref_k = chain.positions[ext]  # the plan's own positions (not the smoothed reference)
    nodes = rec_nodes[:K]
    node_arr = np.stack(nodes) if K else np.zeros((0, J, cfg.n_links + 1, 3))  # (K, J, n+1, 3)
    low = node_arr[:, :, :, 2].min(axis=2) if J else np.zeros((K, 0))  # ends included (as the catenary's lowest)
    low_c, len_c, tf_c, tt_c = (np.full((K, J), np.nan) for _ in range(4))
    warm: list[Any] = [None] * J
    for k, nd in enumerate(nodes):
        for j, tn in enumerate(nd):
            if not np.all(np.isfinite(tn)):
                continue
            tw = None if chain.winch_tension is None else float(chain.winch_tension[ext[k], j])
            try:
                cat = solve3d(tn[0], tn[-1], sim_params, winch_tension=tw, warm=warm[j])
            except (TetherSpanError, ValueError):
                continue
            warm[j] = cat
            low_c[k, j], len_c[k, j] = float(cat.lowest[2]), cat.length
            tf_c[k, j], tt_c[k, j] = cat.tension_p, cat.tension_q
    # the tether pull on each drone: the largest tension at a drone end of its tethers
    pull = np.zeros((K, n))
    for j, (a, b) in enumerate(ends):
        pull[:, b] = np.fmax(pull[:, b], rec_tt[:K, j])
        if a >= 0:
            pull[:, a] = np.fmax(pull[:, a], rec_tf[:K, j])
    # the acceleration the smoothing removes from the plan's at its samples: (v_k − v_{k−1}) / Ts against a_ref
    v_pl = np.concatenate([np.zeros_like(chain.velocities[:1]), chain.velocities])
    a_plan = np.diff(v_pl, axis=0) / Ts if t.size > 1 else np.zeros_like(chain.positions)
    removed = np.linalg.norm(a_plan - a_ref[::sub][: t.size], axis=2)
    return DroneReplay(
        t=t[0] + np.arange(K) * Ts,
        reference=ref_k,
        actual=rec_actual[:K],
        tracking_error=np.linalg.norm(rec_actual[:K] - ref_k, axis=2),
        tilt=rec_tilt[:K],
        rotor_max=rec_rotor[:K],
        rotor_peak=rotor_peak,
        rotor_mean=rotor_sum / (4 * max(step, 1)),
        saturated_steps=sat_steps,
        first_saturation=first_sat,
        rotor_limit=dm.quad.rotor_max,
        ends=ends,
        lowest=low,
        lowest_catenary=low_c,
        lowest_plan=low_plan[ext],
        length=rec_len[:K],
        length_catenary=len_c,
        tension_from=rec_tf[:K],
        tension_to=rec_tt[:K],
        tension_from_catenary=tf_c,
        tension_to_catenary=tt_c,
        tension_from_plan=tf_plan[ext],
        tension_to_plan=tt_plan[ext],
        contacts=contacts,
        tether_contact_steps=teth_steps,
        reference_deviation=np.linalg.norm(p_ref[::sub][: t.size] - chain.positions, axis=2).max(axis=0),
        nodes=nodes,
        sim_time=float(step * cfg.timestep),
        wall_time=wall,
        cpu_time=cpu,
        steps=step,
        diverged=diverged,
        config=cfg,
        gains=ctl.gains(),
        qpos=rec_qpos[:K],
        built=dm,
        saturation_run=runs["sat"][1] * cfg.timestep,
        saturation_run_at=runs["sat"][2],
        reserve_run=runs["reserve"][1] * cfg.timestep,
        reserve_run_at=runs["reserve"][2],
        reserve_thrust=reserve_thrust,
        spare_thrust=float(chain.params.spare_thrust),
        thrust_demand=rec_demand[:K],
        pull=pull,
        accel_removed=removed,
        sag=_sag(node_arr),
        sag_plan=sag_plan[ext],
        clearance=_tether_clearance(chain, node_arr),
        tether_clearance=float(chain.params.clearance),
        tether_length=float(chain.params.tether_length),
        warnings=warnings,
        warning_messages=messages,
    )


def _sag(nodes: Array) -> Array:
    """(K, J) the largest depth of a tether's inner nodes below its chord (the straight line between its ends) [m]:
    the sag, 0 for a taut cable (``nodes`` (K, J, n+1, 3))."""
    if nodes.shape[0] == 0 or nodes.shape[1] == 0:
        return np.zeros(nodes.shape[:2])
    p0, p1 = nodes[:, :, :1], nodes[:, :, -1:]
    c = p1 - p0
    cc = np.maximum(np.einsum("kjai,kjai->kja", c, c), 1e-12)[..., None]
    s = np.clip(np.einsum("kjni,kjai->kjn", nodes - p0, c)[..., None] / cc, 0.0, 1.0)
    chord_z = p0[..., 2] + s[..., 0] * c[..., 2]
    return (chord_z - nodes[..., 2])[:, :, 1:-1].max(axis=2)


def _tether_clearance(chain: DroneChain, nodes: Array) -> Array:
    """(K, J) each simulated tether's least distance to the floor, walls, ceiling and obstacles [m] (its segments
    between recorded nodes against :class:`tmr.world.world3d.World3D` without the drones' safety radius, less the
    cable's radius); NaN for a sample with non-finite nodes."""
    from tmr.replay.tether import TETHER_RADIUS
    from tmr.world.world3d import world3d_from_table

    K, J = nodes.shape[:2]
    out = np.full((K, J), np.nan)
    if K == 0 or J == 0:
        return out
    table = dict(chain.world) if chain.world is not None else {"bounds": chain.bounds.tolist()}
    table["safety_radius"] = 0.0
    world = world3d_from_table(table, chain.world_dir)
    ok = np.all(np.isfinite(nodes), axis=(1, 2, 3))
    if ok.any():
        seg = world.segment_clearance(nodes[ok, :, :-1], nodes[ok, :, 1:])  # (k, J, n)
        out[ok] = seg.min(axis=2) - TETHER_RADIUS
    return out


def drone_verdict(rp: DroneReplay) -> Any:
    """The replay's :class:`tmr.replay.report.Verdict`: it fails at the earliest of a contact (any kind, the warm-up
    at the start pose included), a tracking error beyond the tolerance, a tether pulling a drone harder than the
    planner's spare thrust (+ ``pull_tolerance``), a drone asking for more collective thrust than the planner's
    (1 − reserve) 4 f_max for longer than ``reserve_window``, rotors clipped for an unbroken run longer than
    ``saturation_run`` or in more than ``saturation_limit`` of the physics steps, a plan the smoothing has to change
    by more than ``accel_budget``, a tether nearer the world than ``clearance_fraction`` c_t or paid out beyond
    ``tether_length``, a drone tilted beyond ``max_tilt`` (a crash) or a diverged simulation."""
    from tmr.replay.report import Verdict, _xyz, first_over

    cfg = rp.config
    fails: list[tuple[float, str, str]] = []
    for kind in DRONE_CONTACT_KINDS:
        c = rp.contacts[kind]
        if not c["count"]:
            continue
        t0 = float(c["first_time"])
        a, b = c["between"]
        when = f"t = {t0:.2f} s" + (" (warm-up, at the start pose)" if t0 < float(rp.t[0]) else "")
        msg = (
            f"{a} touches {b} at {when} at {_xyz(c['where'])} ({c['count']} physics steps in contact, "
            f"deepest {1000 * c['max_depth']:.1f} mm)"
        )
        if kind.startswith("tether"):
            j = int(a.split()[-1]) - 1
            k = int(np.argmin(np.abs(rp.t - t0)))
            msg += (
                f"; the planner's catenary had its lowest point at {rp.lowest_plan[k, j]:.3f} m, the simulated cable "
                f"{rp.lowest[k, j]:.3f} m"
            )
        fails.append((t0, kind, msg))
    if (at := first_over(rp.tracking_error > cfg.tolerance, rp.tracking_error)) is not None:
        k, i = at
        msg = (
            f"drone {i + 1} tracking error {rp.tracking_error[k, i]:.3f} m > tolerance {cfg.tolerance:g} m at "
            f"t = {rp.t[k]:.2f} s at {_xyz(rp.actual[k, i])} (largest {float(np.nanmax(rp.tracking_error)):.3f} m)"
        )
        fails.append((float(rp.t[k]), "tracking", msg))
    if rp.pull.size:
        if (at := first_over(rp.pull > rp.spare_thrust * (1.0 + cfg.pull_tolerance), rp.pull)) is not None:
            k, i = at
            msg = (
                f"a tether pulls drone {i + 1} with {rp.pull[k, i]:.2f} N at t = {rp.t[k]:.2f} s at "
                f"{_xyz(rp.actual[k, i])}, more than the planner's spare thrust {rp.spare_thrust:.2f} N "
                f"(+ {100 * cfg.pull_tolerance:g} %; largest {float(np.nanmax(rp.pull[:, i])):.2f} N)"
            )
            fails.append((float(rp.t[k]), "tether pull", msg))
    for i in np.flatnonzero(rp.reserve_run > cfg.reserve_window + 1e-9):
        t0 = float(rp.reserve_run_at[i])
        k = int(np.argmin(np.abs(rp.t - t0)))
        msg = (
            f"drone {int(i) + 1} needs more than the planner's (1 − reserve) thrust {rp.reserve_thrust:.2f} N for "
            f"{rp.reserve_run[i]:.3f} s (> {cfg.reserve_window:g} s) from t = {t0:.2f} s at {_xyz(rp.actual[k, i])} "
            f"(largest {float(np.nanmax(rp.thrust_demand[:, i])):.2f} N)"
        )
        fails.append((t0, "thrust reserve", msg))
    frac = rp.saturation_fraction
    long_run = rp.saturation_run > cfg.saturation_run + 1e-9
    for i in np.flatnonzero((frac > cfg.saturation_limit) | long_run):
        t0 = float(rp.saturation_run_at[i]) if long_run[i] else float(rp.first_saturation[i] or 0.0)
        k = int(np.argmin(np.abs(rp.t - t0)))
        msg = (
            f"drone {int(i) + 1} rotor thrust saturated for {1000 * rp.saturation_run[i]:.0f} ms on end from "
            f"t = {float(rp.saturation_run_at[i]):.2f} s (> {1000 * cfg.saturation_run:g} ms) and in "
            f"{100 * frac[i]:.1f} % of the physics steps (limit {100 * cfg.saturation_limit:g} %), first at "
            f"t = {float(rp.first_saturation[i] or 0.0):.2f} s at {_xyz(rp.actual[k, i])}; peak rotor thrust "
            f"{rp.rotor_peak[i]:.2f} N of {rp.rotor_limit:.2f} N"
        )
        fails.append((t0, "thrust saturation", msg))
    if rp.accel_removed.size:
        if (at := first_over(rp.accel_removed > cfg.accel_budget, rp.accel_removed)) is not None:
            k, i = at
            msg = (
                f"drone {i + 1}'s plan cannot be flown as planned: the smoothing (σ = {cfg.smoothing:g} s) removes "
                f"{rp.accel_removed[k, i]:.1f} m/s² of its acceleration at t = {rp.t[k]:.2f} s at "
                f"{_xyz(rp.reference[k, i])} (budget {cfg.accel_budget:g} m/s²; largest "
                f"{float(rp.accel_removed[:, i].max()):.1f} m/s²)"
            )
            fails.append((float(rp.t[k]), "reference", msg))
    if rp.clearance.size:
        near = rp.clearance < cfg.clearance_fraction * rp.tether_clearance
        if (at := first_over(near, near)) is not None:  # the first tether too near at that sample
            k, j = at
            msg = (
                f"tether {j + 1} passes {rp.clearance[k, j]:.3f} m from the floor or an obstacle at t = "
                f"{rp.t[k]:.2f} s, less than {cfg.clearance_fraction:g} of the planner's tether clearance "
                f"{rp.tether_clearance:.3f} m (least {float(np.nanmin(rp.clearance[:, j])):.3f} m)"
            )
            fails.append((float(rp.t[k]), "tether clearance", msg))
    if rp.length.size:
        if (at := first_over(rp.length > rp.tether_length * (1.0 + cfg.length_tolerance), rp.length)) is not None:
            k, j = at
            msg = (
                f"tether {j + 1} is paid out to {rp.length[k, j]:.3f} m at t = {rp.t[k]:.2f} s, more than the "
                f"{rp.tether_length:.3f} m the winch holds (+ {100 * cfg.length_tolerance:g} %)"
            )
            fails.append((float(rp.t[k]), "tether length", msg))
    if (at := first_over(rp.tilt > cfg.max_tilt, rp.tilt)) is not None:
        k, i = at
        msg = (
            f"drone {i + 1} crashed: tilted {math.degrees(rp.tilt[k, i]):.0f}° > {math.degrees(cfg.max_tilt):.0f}° "
            f"at t = {rp.t[k]:.2f} s at {_xyz(rp.actual[k, i])}"
        )
        fails.append((float(rp.t[k]), "crash", msg))
    if rp.diverged:
        t_div = float(rp.t[0]) - WARMUP if "(warm-up)" in rp.diverged else float(rp.t[-1])
        fails.append((t_div, "crash", f"crash: {rp.diverged}"))
    # the earliest first; at the same time a cause before its symptom (pull, then thrust, then a crash or contact,
    # then the tracking error they make)
    order = {"reference": -1, "tether pull": 0, "thrust reserve": 0.5, "thrust saturation": 1, "crash": 1.5,
             "tracking": 3}  # fmt: skip
    fails.sort(key=lambda f: (f[0], order.get(f[1], 2)))
    return Verdict(ok=not fails, reason=fails[0][2] if fails else None, failures=tuple(fails))
