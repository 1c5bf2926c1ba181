"""Parameters of the tethered-chain planner, with the paper's values as defaults (Caruso 2021, DESIGN seed values).

Every field is in SI units. Values the paper leaves out are chosen here and documented in ``formulations/pinv.md``.
Scenario files override any field by name in their ``[params]`` table (see :func:`apply_overrides`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, TypeVar

from tmr.errors import ParameterError

T = TypeVar("T")


def _validate(obj: Any, positive: tuple[str, ...] = (), nonnegative: tuple[str, ...] = ()) -> None:
    """Every numeric field finite; the fields named in ``positive`` > 0 and in ``nonnegative`` ≥ 0."""
    cls = type(obj).__name__
    for f in fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, bool):
            continue
        if isinstance(v, (int, float)) and not math.isfinite(v):
            raise ParameterError(f"{cls}.{f.name} must be finite, got {v!r}")
    for name in positive:
        if getattr(obj, name) <= 0:
            raise ParameterError(f"{cls}.{name} must be > 0, got {getattr(obj, name)!r}")
    for name in nonnegative:
        if getattr(obj, name) < 0:
            raise ParameterError(f"{cls}.{name} must be ≥ 0, got {getattr(obj, name)!r}")


#: the ground winch's kinds (:attr:`ChainParams.winch`) and the fields an active one adds to the records
WINCHES = ("passive", "active")
WINCH_FIELDS = ("winch", "winch_tension_min", "winch_tension_max", "winch_tension_rate")
#: the ground robots' kinematics (:attr:`ChainParams.drive`, :mod:`tmr.model.diffdrive`) and the fields a
#: differential-drive plan adds to the records
DRIVES = ("omni", "diff")
DRIVE_FIELDS = ("drive", "robot_model")

#: What an active winch plans with unless given (issue 34's dynamic sag, ``formulations/catenary.md``, "Dynamic
#: sag"): the tether's lowest point stays ≥ 5 cm above the floor (checked on the static catenary; planned 1 cm
#: higher, the sag allowance), and a span approaches the reach of its tension at most at ρ_d (d_max(T) − margin − d)
#: per second, so the moving cable (which hangs lower than the static one while it is paid out) keeps that 5 cm in
#: the MuJoCo replay of A–E too (``benchmarks/dynamic_sag.py``). The passive winch keeps the paper's model (the
#: cable may reach the floor at d_max, no damper): the paper's scenarios and numbers stay its own.
ACTIVE_WINCH_DEFAULTS: dict[str, float] = {"ground_clearance": 0.05, "sag_allowance": 0.01, "span_approach_rate": 0.5}


def refuse_method_limits(method: str, chain_params: ChainParams, qp_params: QPParams) -> None:
    """What ``method`` refuses in the parameters, whatever the number of robots (ParameterError): ``"pinv"`` an
    active winch (the paper's constant tension) and the per-step QP's pay-out damper ``span_approach_rate``;
    ``"horizon"`` that damper unless the winch is active (the NLP keeps it through the tension,
    :func:`tmr.control.winch.least_tension_schedule`); ``"qp"`` nothing. ``tmr plan`` calls it before the route, the
    planner again before it plans."""
    if method == "pinv" and chain_params.active_winch:  # first: its damper is one of the active winch's defaults
        raise ParameterError(
            "an active winch (winch = 'active') is planned by --method qp and horizon only: the pinv baseline "
            "keeps the paper's constant tension"
        )
    if method not in ("pinv", "horizon") or qp_params.span_approach_rate is None:
        return
    if method == "horizon" and chain_params.active_winch:
        return
    who = "the pinv baseline" if method == "pinv" else "the horizon NLP"
    raise ParameterError(
        f"span_approach_rate is a limit of --method qp's per-step QP: {who} does not keep it (leave it unset"
        + ("; with winch = 'active' the horizon keeps it through the tension)" if method == "horizon" else ")")
    )


def with_winch_defaults(values: dict[str, Any]) -> tuple[dict[str, Any], tuple[str, ...]]:
    """``values`` (parameter overrides by field name) with :data:`ACTIVE_WINCH_DEFAULTS` filled in where not given,
    if they ask for ``winch = "active"``; and the names it filled in."""
    if str(values.get("winch", "passive")) != "active":
        return dict(values), ()
    filled = tuple(k for k in ACTIVE_WINCH_DEFAULTS if k not in values)
    return {**values, **{k: ACTIVE_WINCH_DEFAULTS[k] for k in filled}}, filled


@dataclass(frozen=True)
class ChainParams:
    """Physical chain parameters (Caruso 2021 §4 and §4.2.1).

    Attributes:
        safety_radius: robot safety bubble r [m]; obstacles are grown by it, two robots must stay ≥ 2r apart.
        exit_height: height H where a tether leaves a robot [m].
        base_height: height of the fixed tether anchor [m].
        pulley_torque: winch pulley resisting torque [N m].
        pulley_radius: winch pulley radius [m]; horizontal tension T0 = torque / radius.
        cable_mass_per_length: ρ [kg/m].
        ground_clearance: lowest allowed height of the cable [m] (checked on the static catenary).
        sag_allowance: with the active winch only (refused with the passive one), how much higher than
            ``ground_clearance`` the planner keeps the static catenary [m] (the checker holds it to
            ``ground_clearance``): room for the MuJoCo cable, which near a long span's reach
            hangs up to 2 mm below the static catenary (``formulations/catenary.md``, "Dynamic sag"). Default 0;
            0.01 m with the active winch (:data:`ACTIVE_WINCH_DEFAULTS`). Left out of the records while 0.
        winch: ``"passive"`` (the paper's winch: a constant horizontal tension T0) or ``"active"`` (Caruso 2021's
            future work: the pulley's torque, hence every tether's T0, is a decision of the per-step QP, within
            [winch_tension_min, winch_tension_max] and changing at most ``winch_tension_rate``; its nominal value,
            the one it returns to, is torque / radius). ``formulations/catenary.md``, "Active winch".
        winch_tension_min, winch_tension_max: the active winch's range of T0 [N] (pulley torque range / radius;
            documented choice: 5–40 N, i.e. 0.5–4 N m on the 0.1 m pulley).
        winch_tension_rate: how fast the active winch's T0 may change [N/s] (documented choice: 20 N/s).
        low_obstacle_clearance: height [m] a cable keeps above a low obstacle it passes over (a GeoJSON feature
            with a ``"height"``, :class:`tmr.world.environment.LowObstacle`): the catenary's height over the
            obstacle's footprint must be at least the obstacle's height plus this (checked by
            :func:`tmr.checks.metrics.evaluate`, kind ``low_obstacle``). Default 0.05 m. Left out of a plan's
            recorded parameters when the world has no low obstacle (their bytes unchanged).
        drive: ``"omni"`` (every robot omnidirectional, Caruso 2021) or ``"diff"`` (differential drive: heading
            state, no sideways motion of the axle, v/ω limits; :mod:`tmr.control.diffdrive`,
            ``formulations/diffdrive.md``).
        robot_model: with ``drive = "diff"``, a preset of :mod:`tmr.model.diffdrive` (``turtlebot3_burger``,
            ``turtlebot3_waffle_pi``, ``clearpath_jackal``) or a robot model TOML file; empty: the default preset.
            Both fields are left out of the records of an omnidirectional plan (their bytes unchanged).
    """

    safety_radius: float = 0.5
    exit_height: float = 0.43
    base_height: float = 0.43
    pulley_torque: float = 1.35
    pulley_radius: float = 0.1
    cable_mass_per_length: float = 0.15
    ground_clearance: float = 0.0
    sag_allowance: float = 0.0
    winch: str = "passive"
    winch_tension_min: float = 5.0
    winch_tension_max: float = 40.0
    winch_tension_rate: float = 20.0
    low_obstacle_clearance: float = 0.05
    drive: str = "omni"
    robot_model: str = ""

    def __post_init__(self) -> None:
        _validate(
            self,
            positive=(
                "safety_radius", "exit_height", "pulley_torque", "pulley_radius", "cable_mass_per_length",
                "winch_tension_min", "winch_tension_max", "winch_tension_rate",
            ),
            nonnegative=("low_obstacle_clearance", "sag_allowance"),
        )  # fmt: skip
        top = min(self.exit_height, self.base_height)
        if self.ground_clearance + self.sag_allowance >= top:
            raise ParameterError(
                f"ChainParams.ground_clearance ({self.ground_clearance:g} m) + sag_allowance "
                f"({self.sag_allowance:g} m) must be below the tether ends ({top:g} m): lower the clearance or the "
                "allowance"
            )
        if self.winch not in WINCHES:
            raise ParameterError(f"ChainParams.winch must be one of {', '.join(WINCHES)}, got {self.winch!r}")
        if self.drive not in DRIVES:
            raise ParameterError(f"ChainParams.drive must be one of {', '.join(DRIVES)}, got {self.drive!r}")
        if self.robot_model and self.drive != "diff":
            raise ParameterError(
                f"robot_model = {self.robot_model!r} is a differential-drive robot but drive = {self.drive!r}: give "
                "drive = 'diff' (--drive diff), or no robot model"
            )
        if self.active_winch:  # the range as a whole (a command line's --set checks each field on its own)
            if self.winch_tension_min > self.winch_tension_max:
                raise ParameterError(
                    f"ChainParams.winch_tension_min ({self.winch_tension_min} N) is above winch_tension_max "
                    f"({self.winch_tension_max} N)"
                )
            t0 = self.horizontal_tension
            if not self.winch_tension_min <= t0 <= self.winch_tension_max:
                raise ParameterError(
                    f"the active winch's nominal tension pulley_torque / pulley_radius = {t0:g} N is outside its range "
                    f"[{self.winch_tension_min:g}, {self.winch_tension_max:g}] N: widen the range or change the torque"
                )

    @property
    def active_winch(self) -> bool:
        """Whether the winches' tension is planned (``winch = "active"``)."""
        return self.winch == "active"

    @property
    def nominal_tension(self) -> float:
        """The tension an active winch returns to [N]: torque / radius (within its range, checked), T0 itself."""
        return self.horizontal_tension

    def record(self) -> dict[str, Any]:
        """The fields as a dict, without the active winch's four when the winch is passive, without a zero
        ``sag_allowance`` and without the drive's fields for omnidirectional robots (a passive omnidirectional plan's
        records keep the bytes they had before these existed)."""
        out = asdict(self)
        if not self.active_winch:
            for name in WINCH_FIELDS:
                out.pop(name)
        if not self.sag_allowance:
            out.pop("sag_allowance")
        if not self.diff_drive:  # an omnidirectional plan's records keep their bytes
            for name in DRIVE_FIELDS:
                out.pop(name)
        return out

    @property
    def diff_drive(self) -> bool:
        """Whether the robots are differential-drive (``drive = "diff"``)."""
        return self.drive == "diff"

    @property
    def horizontal_tension(self) -> float:
        """T0 = pulley torque / pulley radius [N] (Caruso 2021 §4.2.1: 13.5 N)."""
        return self.pulley_torque / self.pulley_radius


#: The most time steps a plan may have: 200,000 steps are 10,000 s (2.8 h) of motion at Ts = 0.05 s, ten times the
#: longest plan measured (a train-reference plan of Burgers in a 26.9 m narrow room, 19,037 steps). A time law that
#: needs more (a very slow robot model, a huge T_end) is refused up front instead of allocating arrays that long.
MAX_STEPS = 200_000


@dataclass(frozen=True)
class TimeParams:
    """Time law of the leader (Caruso 2021 §4.2): duration T_end [s] and sampling period Ts [s]."""

    T_end: float = 15.0
    Ts: float = 0.05

    def __post_init__(self) -> None:
        _validate(self)
        if self.T_end <= 0 or self.Ts <= 0 or self.Ts > self.T_end:
            raise ParameterError(f"need 0 < Ts ≤ T_end, got Ts={self.Ts}, T_end={self.T_end}")
        if round(self.T_end / self.Ts) > MAX_STEPS:
            raise ParameterError(
                f"T_end / Ts = {self.T_end / self.Ts:.6g} steps is above the planner's limit of {MAX_STEPS:,} steps "
                "(tmr.model.params.MAX_STEPS): a shorter motion (T_end; or a faster leader: leader_speed, a robot "
                "model's v_max; a shorter route) or a longer Ts"
            )

    @property
    def steps(self) -> int:
        """Number of integration steps K = T_end / Ts (300 for the paper)."""
        return int(round(self.T_end / self.Ts))


@dataclass(frozen=True)
class PathParams:
    """Leader path planning (Caruso 2021 §4.2 "Planner": RRT*).

    Attributes:
        path_clearance: margin [m] the leader's RRT* path keeps from the inflated obstacles. The default keeps the
            leader outside the obstacle task's danger zone (d_min + ε) where the map allows; if no path exists with
            it, the planner retries with half of it, then with ``path_clearance_min``.
        path_clearance_min: smallest margin tried [m].
        path_iterations: RRT* iterations (termination by count, so the path is a function of the seed).
        goal_tolerance: the plan fails if the leader ends farther than this from the goal [m].
        leader_speed: peak speed of the leader's time law along the route [m/s]; with ``leader_accel`` [m/s²] it
            sets the duration T_end from the route length unless T_end is given (``tmr.route.references``).
        route_gain: gain [1/s] of the followers' tracking of their route references (``RouteFollowers``).
        route_weight: weight of that task in the QP's tether level.
        route_settle: time [s] the route references hold still at their end, the leader on the goal, so that the
            followers come to rest on their stations before the plan ends (not added to a ``T_end`` the user set).
        catch_up: fastest rise [m/s] of a follower's trailing reference at a corner (``tmr.route.references.
            chain_reference``); None (the default): 1.2 m/s for omnidirectional robots
            (``tmr.route.references.CATCH_UP``), the wheels' straight-line speed for differential drive
            (``tmr.planner.diff_catch_up``).
    """

    path_clearance: float = 0.6
    path_clearance_min: float = 0.05
    path_iterations: int = 1000
    goal_tolerance: float = 0.1
    leader_speed: float = 0.8
    leader_accel: float = 0.5
    route_gain: float = 1.0
    route_weight: float = 10.0
    route_settle: float = 2.0
    catch_up: float | None = None

    def __post_init__(self) -> None:
        _validate(self)
        if self.catch_up is not None and not self.catch_up > 0:
            raise ParameterError(f"PathParams.catch_up must be > 0 m/s or None, got {self.catch_up!r}")
        if self.path_clearance < 0 or self.path_clearance_min < 0 or self.path_iterations < 1:
            raise ParameterError(f"need path_clearance ≥ 0, path_clearance_min ≥ 0, path_iterations ≥ 1; got {self}")
        if not 0.0 <= self.route_settle <= 60.0:
            raise ParameterError(f"need 0 ≤ route_settle ≤ 60 [s], got {self.route_settle}")
        if min(self.leader_speed, self.leader_accel, self.route_gain) <= 0 or self.route_weight < 0:
            raise ParameterError(
                "need leader_speed > 0 [m/s], leader_accel > 0 [m/s²], route_gain > 0 [1/s], route_weight ≥ 0; "
                f"got {self.leader_speed}, {self.leader_accel}, {self.route_gain}, {self.route_weight}"
            )

    def record(self) -> dict[str, Any]:
        """The fields as a dict, without ``catch_up`` while it is the default (the records keep their bytes)."""
        out = asdict(self)
        if self.catch_up is None:
            out.pop("catch_up")
        return out

    @property
    def clearances(self) -> tuple[float, ...]:
        """Margins tried in order [m]."""
        c = self.path_clearance
        return tuple(sorted({c, max(c / 2, self.path_clearance_min), min(c, self.path_clearance_min)}, reverse=True))


@dataclass(frozen=True)
class TaskParams:
    """Parameters of the tasks shared by every formulation (Caruso 2021 §4.1).

    Attributes:
        clik_gain: K of eq. 20 (scalar times identity) [1/s].
        samples_per_link: points per tether where clearance is sampled (critical point, clearance rows).
        span_target_fraction: target d_t of eq. 13 as a fraction of [d_lo, d_max]; 0.5 is the range midpoint of the
            joint-range criterion the paper cites (Siciliano 2009).
        gain_floor: G of eq. 23 [1/s].
        gain_edge: extra gain of each exponential of eq. 23 at its limit [1/s].
        gain_length: decay length 1/|b| of the exponentials of eq. 23 [m].
    """

    clik_gain: float = 5.0
    samples_per_link: int = 20
    span_target_fraction: float = 0.5
    gain_floor: float = 0.5
    gain_edge: float = 5.0
    gain_length: float = 0.2

    def __post_init__(self) -> None:
        _validate(self, positive=("clik_gain", "gain_length"))
        if self.samples_per_link < 1:
            raise ParameterError(f"samples_per_link must be ≥ 1, got {self.samples_per_link}")
        if not 0 <= self.span_target_fraction <= 1:
            raise ParameterError(f"span_target_fraction must be in [0, 1], got {self.span_target_fraction}")


@dataclass(frozen=True)
class PinvParams:
    """Parameters of the faithful task-priority CLIK baseline (Caruso 2021 §3, §4.1.3).

    Attributes:
        dls_damping: λ of the damped least-squares pseudoinverse J# = Jᵀ(JJᵀ + λI)⁻¹, λ ∈ ]0, 1[ (§3).
        d_min: activation distance of the obstacle task (eq. 17), measured from the inflated obstacles [m].
        k_v0: evasion speed constant, v0 = k_v0 / ‖d_c − x_c‖ [m²/s] (§4.1.3).
        hysteresis: ε of eq. 17 — the task is released at d_min + ε [m].
        min_evasion_distance: floor on ‖d_c − x_c‖ in v0 so the speed stays finite at contact [m] (not in the paper).
    """

    dls_damping: float = 0.01
    d_min: float = 0.5
    k_v0: float = 0.05
    hysteresis: float = 0.1
    min_evasion_distance: float = 0.05

    def __post_init__(self) -> None:
        _validate(self, positive=("d_min", "k_v0", "hysteresis", "min_evasion_distance"))
        if not 0 < self.dls_damping < 1:
            raise ParameterError(f"dls_damping λ must be in ]0, 1[ (Caruso 2021 §3), got {self.dls_damping}")


@dataclass(frozen=True)
class QPParams:
    """Parameters of the lexicographic QP (``formulations/qp.md``). Units: m, s, rad.

    Attributes:
        d_safe: clearance every robot and tether sample keeps from the inflated obstacles [m].
        clearance_rows_per_link: clearance rows per tether: 0 = every sample (safe default); k > 0 = the k lowest
            local minima of its clearance profile (fewer rows for long chains, see ``ObstacleClearance``).
        clearance_activation: samples farther than this from the obstacles give inactive rows [m].
        approach_rate: a distance to its limit (clearance, separation) may shrink at most at this rate times the
            remaining margin [1/s] (velocity damper), so the acceleration bound can always stop an approach.
        separation_margin: robots keep 2r + this from each other [m].
        separation_neighbours: separation rows per robot (its nearest robots; ≥ N−1 means every pair).
        robot_speed_max: Cartesian speed bound of every robot, per axis [m/s].
        joint_speed_max: |θ̇| bound [rad/s].
        span_speed_max: |ḋ| bound [m/s].
        accel_max: |q̇_k − q̇_{k−1}| ≤ accel_max · Ts [rad/s², m/s²].
        robot_accel_max: Cartesian acceleration bound of every robot, per axis [m/s²].
        span_margin: spans stay in [d_lo + margin, d_max − margin] [m].
        span_approach_rate: None (default: the span may reach d_max − margin in one step) or a rate ρ_d [1/s]: a
            tether is paid out towards its limit at most at ρ_d (d_max − margin − d) (a velocity damper, like
            ``approach_rate``): the cable slows down before it hangs at its limit, so it does not dip below its
            static catenary (the dynamic sag measured by ``tmr replay``; ``formulations/catenary.md``).
        uniformity_gain: rate at which adjacent span differences decay (level 2) [1/s].
        tether_smoothness: weight of ‖q̇ − q̇_{k−1}‖² inside level 2 (next to the tether regulation, weight 1): the
            tether level fixes N of the 2N − 2 joint velocities left by the leader, so smoothness must act there too.
        energy_weight: weight of ‖q̇‖² at level 3; smoothness_weight: weight of ‖q̇ − q̇_{k−1}‖² at level 3.
        solver: "osqp" (persistent workspace) or a qpsolvers backend.
    """

    d_safe: float = 0.05
    clearance_rows_per_link: int = 0
    clearance_activation: float = 1.5
    approach_rate: float = 2.0
    separation_margin: float = 0.02
    separation_neighbours: int = 2
    robot_speed_max: float = 2.5
    joint_speed_max: float = 3.0
    span_speed_max: float = 3.0
    accel_max: float = 20.0
    robot_accel_max: float = 6.0
    span_margin: float = 0.01
    span_approach_rate: float | None = None
    uniformity_gain: float = 1.0
    tether_smoothness: float = 100.0
    energy_weight: float = 1.0
    smoothness_weight: float = 10.0
    solver: str = "osqp"

    def __post_init__(self) -> None:
        _validate(
            self,
            positive=(
                "robot_speed_max",
                "joint_speed_max",
                "span_speed_max",
                "accel_max",
                "robot_accel_max",
                "approach_rate",
                "clearance_activation",
            ),
            nonnegative=(
                "d_safe",
                "separation_margin",
                "span_margin",
                "uniformity_gain",
                "energy_weight",
                "smoothness_weight",
                "tether_smoothness",
            ),
        )
        if self.clearance_rows_per_link < 0 or self.separation_neighbours < 1:
            raise ParameterError("need clearance_rows_per_link ≥ 0 and separation_neighbours ≥ 1")
        if self.span_approach_rate is not None and not self.span_approach_rate > 0:
            raise ParameterError(
                f"QPParams.span_approach_rate must be > 0 1/s or None, got {self.span_approach_rate!r}"
            )

    def record(self) -> dict[str, Any]:
        """The fields as a dict, without ``span_approach_rate`` while it is off (the records keep their bytes)."""
        out = asdict(self)
        if self.span_approach_rate is None:
            out.pop("span_approach_rate")
        return out


#: The longest a drone plan waits after its references stop [s] (``DroneParams.settle``).
MAX_SETTLE = 60.0


@dataclass(frozen=True)
class DroneParams:
    """Parameters of the drone-chain planner (``formulations/drones.md``; tether and drone physics are in
    :class:`tmr.model.catenary3d.DroneTetherParams`). Units: m, s. A drone scenario's ``[params]`` overrides them.

    Attributes:
        Ts: sampling period [s].
        leader_speed: cruise speed of the leader along the route [m/s] (below ``drone_speed_max`` so that the
            leader's CLIK has room to correct); leader_accel: its acceleration [m/s²] (the time law:
            :func:`tmr.route.route3d._cruise_law`).
        drone_speed_max: speed bound of every drone, per axis [m/s].
        drone_accel_max: acceleration bound of every drone, per axis [m/s²] (a hard limit: never dropped; where it
            and the safety limits have no common solution the plan slows down, then fails:
            :func:`tmr.control.run3d.run_drones`).
        drone_jerk_max: jerk bound of every drone, per axis [m/s³], or None (default): no jerk limit. Set:
            |(ṗ_k − ṗ_{k−1}) − (ṗ_{k−1} − ṗ_{k−2})| ≤ drone_jerk_max Ts² (a hard limit as the acceleration's). A
            quadrotor tilts its thrust to accelerate sideways (a_lat = g tan(tilt)) and turns it at most at its
            body-rate cap ω_max, so its acceleration changes at most at ≈ g ω_max near hover (≈ 59 m/s³ for the
            replay's 6 rad/s). Off by default: at 50 m/s³ F, G, H, I plan and the MuJoCo replay confirms H (which it
            does not without), but ``--robots auto`` plans 78 of the 90 reachable seeded worlds instead of 89; at
            25 and 40 the per-step dampers, met at full approach, ask for an acceleration change the jerk rows cannot
            give in one step and F, G, I (I at 40) no longer plan (``formulations/drones.md``, "Jerk").
        d_safe: clearance every drone keeps beyond its radius r from the obstacles, walls, floor and ceiling [m].
        separation_margin: drones keep 2r + this from each other [m].
        approach_rate: a distance to its limit may shrink at most at this rate times the remaining margin [1/s]
            (velocity damper, as ``QPParams.approach_rate``).
        tether_samples: points per tether where the curve's clearance is a row of the QP (interior points of the
            catenary, at equal arc length).
        clearance_activation: samples farther than this from their limit give inactive rows [m].
        length_margin: arc length ≤ tether_length − this [m]; tension_margin: end tension ≤ spare thrust − this [N].
        route_gain: gain of the followers' route references [1/s]; leader_gain: CLIK gain of the leader task [1/s].
        span_target_fraction: tether regulation pulls each chord towards this fraction of the route spacing [-].
        energy_weight: weight of ‖v‖² at the last level; smoothness_weight: weight of ‖v − v_{k−1}‖².
        goal_tolerance: the leader must end this close to the goal [m].
        settle: the most time added after the leader's reference reaches the goal [s] (≤ 60); the plan ends as soon
            as the leader is within half the goal tolerance and every drone at rest
            (:func:`tmr.control.run3d.run_drones`).
        grid: cell size of the 3-D route grid [m].
        solver: "osqp" or a qpsolvers backend.
    """

    Ts: float = 0.05
    leader_speed: float = 1.5
    leader_accel: float = 1.0
    drone_speed_max: float = 2.0
    drone_accel_max: float = 4.0
    drone_jerk_max: float | None = None
    d_safe: float = 0.02
    separation_margin: float = 0.05
    approach_rate: float = 2.0
    tether_samples: int = 8
    clearance_activation: float = 1.5
    length_margin: float = 0.05
    tension_margin: float = 0.05
    route_gain: float = 1.0
    leader_gain: float = 10.0
    span_target_fraction: float = 1.0
    energy_weight: float = 1.0
    smoothness_weight: float = 10.0
    goal_tolerance: float = 0.1
    settle: float = 8.0
    grid: float = 0.25
    solver: str = "osqp"

    def __post_init__(self) -> None:
        _validate(
            self,
            positive=(
                "Ts",
                "leader_speed",
                "leader_accel",
                "drone_speed_max",
                "drone_accel_max",
                "approach_rate",
                "clearance_activation",
                "goal_tolerance",
                "grid",
            ),
            nonnegative=(
                "d_safe",
                "separation_margin",
                "length_margin",
                "tension_margin",
                "route_gain",
                "leader_gain",
                "span_target_fraction",
                "energy_weight",
                "smoothness_weight",
                "settle",
            ),
        )
        if self.tether_samples < 1:
            raise ParameterError(f"DroneParams.tether_samples must be ≥ 1, got {self.tether_samples!r}")
        j = self.drone_jerk_max
        if j is not None and (isinstance(j, bool) or not isinstance(j, (int, float)) or not 0 < j < math.inf):
            raise ParameterError(f"DroneParams.drone_jerk_max must be a finite number > 0 or None, got {j!r}")
        if self.settle > MAX_SETTLE:
            raise ParameterError(f"DroneParams.settle must be ≤ {MAX_SETTLE:g} s, got {self.settle!r}")
        if self.leader_speed > self.drone_speed_max:
            raise ParameterError(
                f"DroneParams.leader_speed {self.leader_speed:g} m/s is above drone_speed_max "
                f"{self.drone_speed_max:g} m/s: no drone could follow its reference"
            )
        if self.leader_accel > self.drone_accel_max:
            raise ParameterError(
                f"DroneParams.leader_accel {self.leader_accel:g} m/s² is above drone_accel_max "
                f"{self.drone_accel_max:g} m/s²: no drone could follow its reference"
            )


#: Every parameter class, in the order the planner applies overrides (a name belongs to one of them).
PARAM_CLASSES: tuple[type, ...] = (ChainParams, TimeParams, PathParams, TaskParams, PinvParams, QPParams)


def convert_field(cls: type, name: str, value: Any) -> Any:
    """``value`` (a number, or its text from a command line or a file) as the type of field ``name`` of ``cls``:
    an int field takes only whole numbers (``2.5`` is refused, not truncated), a float field only finite numbers, a
    str field text; a field whose default is None also ``none``/``off`` (None). ParameterError naming the field
    otherwise."""
    default = getattr(cls(), name)
    kind = type(default)
    label = f"{cls.__name__}.{name}"
    if default is None and (value is None or (isinstance(value, str) and value.strip().lower() in ("none", "off"))):
        return None  # an optional limit (e.g. DroneParams.drone_jerk_max) switched off
    if kind is str:
        if not isinstance(value, str):
            raise ParameterError(f"{label} takes text, got {value!r}")
        return value
    if isinstance(value, bool):
        raise ParameterError(f"{label} takes a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{label} takes a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ParameterError(f"{label} must be finite, got {value!r}")
    if kind is int:
        if isinstance(value, str):
            try:
                return int(value.strip())
            except ValueError:
                pass
        if not number.is_integer():
            raise ParameterError(f"{label} takes a whole number, got {value!r}")
        return int(value) if isinstance(value, int) else int(number)
    return number


def apply_overrides(obj: T, overrides: dict[str, Any], *, strict: bool = False) -> tuple[T, dict[str, Any]]:
    """Return ``obj`` with the fields named in ``overrides`` replaced, and the overrides it did not use.

    With ``strict=True`` an unknown name raises ``ParameterError``. Types follow the field's default type
    (:func:`convert_field`: an int field refuses 2.5).
    """
    names = {f.name: f for f in fields(obj)}  # type: ignore[arg-type]
    used: dict[str, Any] = {}
    rest: dict[str, Any] = {}
    for key, value in overrides.items():
        if key in names:
            used[key] = convert_field(type(obj), key, value)
        else:
            rest[key] = value
    if strict and rest:
        raise ParameterError(f"unknown parameter(s) {sorted(rest)}")
    return replace(obj, **used), rest  # type: ignore[type-var]


def as_dict(*objs: Any) -> dict[str, Any]:
    """Flatten parameter dataclasses into one JSON-ready dict (for metrics.json)."""
    out: dict[str, Any] = {}
    for o in objs:
        out.update(o.record() if hasattr(o, "record") else asdict(o))
    return out
