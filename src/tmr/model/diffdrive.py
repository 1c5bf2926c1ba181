"""Differential-drive ground robots: the robot models (presets and a user's TOML file) and the unicycle kinematics
of a robot whose tether leaves at an exit point offset from its wheel axle (math in ``formulations/diffdrive.md``).

A robot's pose is its axle centre c = (x, y) [m] and heading θ [rad]; it moves as a unicycle

    ẋ = v cos θ,   ẏ = v sin θ,   θ̇ = ω,        |v| ≤ v_max, |ω| ≤ ω_max, |v̇| ≤ a_max, |ω̇| ≤ α_max,

so the axle centre never moves sideways: e_⊥(θ)·ċ = 0 with e(θ) = (cos θ, sin θ), e_⊥ = (−sin θ, cos θ). The tether
leaves at the exit point p = c + b e(θ), b [m] ahead of the axle: that point is what Caruso 2021's chain model calls
the robot's position. Its velocity is

    ṗ = v e(θ) + b ω e_⊥(θ) = R(θ) [v, b ω]ᵀ,

a bijection between (v, ω) and ṗ for b ≠ 0: the exit point is fully actuated (the classic "point offset" of
unicycle control), and v = e·ṗ, ω = e_⊥·ṗ / b are linear in ṗ at a given heading.

Over one sampling period with (v, ω) held (a real robot executing one ``cmd_vel``), the pose follows an exact arc
(:func:`unicycle_step`); its chord is along the mid heading θ_k + ω Ts / 2, so the recorded poses satisfy
``(c_{k+1} − c_k)·e_⊥((θ_k + θ_{k+1}) / 2) = 0`` exactly, and :func:`step_velocities` recovers (v, ω) and that
lateral velocity from two poses alone (the checker, :mod:`tmr.checks.diffdrive`).
"""

from __future__ import annotations

import math
import sys
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ParameterError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

Array = NDArray[np.float64]

__all__ = [
    "DRIVES",
    "MODEL_FIELDS",
    "PRESET_ALIASES",
    "RobotModel",
    "WHEEL_FIELDS",
    "canonical_model_name",
    "exit_jacobian",
    "exit_point",
    "exit_velocity",
    "load_robot_model",
    "model_for",
    "preset_names",
    "step_velocities",
    "unicycle_step",
]

#: Kinematics of a ground robot: ``omni`` (every robot omnidirectional, Caruso 2021) or ``diff`` (differential drive).
DRIVES = ("omni", "diff")
#: The numeric fields of a robot model file (all required, SI units).
MODEL_FIELDS = ("radius", "v_max", "omega_max", "a_max", "alpha_max", "exit_offset")
#: The optional fields of a robot model: its wheels (radius r_w and track L [m]); with a track the planner also keeps
#: each wheel's rim speed |v ± ω L/2| ≤ v_max (``formulations/diffdrive.md``, "Wheel speeds").
WHEEL_FIELDS = ("wheel_radius", "track")
#: The least exit offset b [m] a model may give (b = 0 leaves the exit point no sideways motion at all; the presets
#: have 0.08–0.15 m).
MIN_EXIT_OFFSET = 1e-3
#: The preset used by ``--drive diff`` without ``--robot-model``.
DEFAULT_MODEL = "turtlebot3_burger"
#: Short names of the presets (``--robot-model burger``): alias → preset name.
PRESET_ALIASES = {"burger": "turtlebot3_burger", "waffle_pi": "turtlebot3_waffle_pi", "jackal": "clearpath_jackal"}


@dataclass(frozen=True)
class RobotModel:
    """A differential-drive robot (see the module docstring).

    Attributes:
        name: preset name or the file's ``name`` (else its stem).
        radius: footprint radius r_f round the axle centre [m].
        v_max: forward speed bound |v| [m/s].
        omega_max: yaw rate bound |ω| [rad/s].
        a_max: forward acceleration bound |v̇| [m/s²].
        alpha_max: yaw acceleration bound |ω̇| [rad/s²].
        exit_offset: b [m], the tether's exit point ahead of the axle centre along the heading (> 0).
        wheel_radius: r_w [m] of the two driven wheels, or None (the MuJoCo replay needs it).
        track: L [m], the distance between the driven wheels, or None. With a track each wheel's rim speed
            |v ± ω L/2| is kept ≤ v_max (v_max being the straight-line speed, the wheels' own limit): turning while
            driving slows the robot down, as on the real one.
    """

    name: str
    radius: float
    v_max: float
    omega_max: float
    a_max: float
    alpha_max: float
    exit_offset: float
    wheel_radius: float | None = None
    track: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ParameterError(f"a robot model's name must be non-empty text, got {self.name!r}")
        for f in MODEL_FIELDS + WHEEL_FIELDS:
            v = getattr(self, f)
            if f in WHEEL_FIELDS and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ParameterError(f"robot model {self.name!r}: {f} must be a finite number > 0, got {v!r}")
        if self.exit_offset < MIN_EXIT_OFFSET:
            raise ParameterError(
                f"robot model {self.name!r}: exit_offset = {self.exit_offset:g} m is below {MIN_EXIT_OFFSET:g} m: the "
                f"exit point then moves sideways at most b ω_max = {self.exit_offset * self.omega_max:.3g} m/s and "
                "the heading turns by its sideways error / b (formulations/diffdrive.md); measure b from the axle"
            )

    def record(self) -> dict[str, Any]:
        """The model as a JSON-ready dict (recorded in a diff-drive plan's parameters; wheels only if given)."""
        return {k: v for k, v in asdict(self).items() if not (k in WHEEL_FIELDS and v is None)}

    @property
    def lateral_max(self) -> float:
        """The most the exit point can move sideways, b ω_max [m/s]."""
        return self.exit_offset * self.omega_max


def _presets() -> dict[str, dict[str, Any]]:
    text = resources.files("tmr.model").joinpath("robot_models.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def preset_names() -> list[str]:
    """The names of the built-in presets (``src/tmr/model/robot_models.toml``)."""
    return sorted(_presets())


def canonical_model_name(name_or_file: str) -> str:
    """The preset name of an alias (:data:`PRESET_ALIASES`, ``burger`` → ``turtlebot3_burger``); anything else (a
    preset name, a file) unchanged, stripped of surrounding blanks."""
    key = str(name_or_file).strip()
    return PRESET_ALIASES.get(key, key)


def _from_table(name: str, table: dict[str, Any], where: str) -> RobotModel:
    unknown = sorted(set(table) - set(MODEL_FIELDS) - set(WHEEL_FIELDS) - {"name"})
    missing = [f for f in MODEL_FIELDS if f not in table]
    if unknown or missing:
        parts = ([f"unknown keys {unknown}"] if unknown else []) + ([f"missing {missing}"] if missing else [])
        raise ParameterError(f"{where}: {'; '.join(parts)}; a robot model has {', '.join(MODEL_FIELDS)} (SI units)")
    wheels = {f: table[f] for f in WHEEL_FIELDS if f in table}
    given = table.get("name", name)
    if not isinstance(given, str):
        raise ParameterError(f"{where}: name must be non-empty text, got {given!r}")
    return RobotModel(given, *(table[f] for f in MODEL_FIELDS), **wheels)


def load_robot_model(name_or_file: str) -> RobotModel:
    """A preset by name (:func:`preset_names`, or a short name of :data:`PRESET_ALIASES`), or a TOML file with
    ``radius``, ``v_max``, ``omega_max``, ``a_max``, ``alpha_max``, ``exit_offset`` (and an optional ``name``). Raises
    :class:`ParameterError` (exit 2 on the command line) for an unknown name or a bad file."""
    presets = _presets()
    key = canonical_model_name(name_or_file)
    if key in presets:
        return _from_table(key, presets[key], f"preset {key!r}")
    path = Path(key)
    if path.suffix.lower() != ".toml" and not path.exists():
        raise ParameterError(
            f"unknown robot model {key!r}: the presets are {', '.join(sorted(presets))} (short names "
            f"{', '.join(sorted(PRESET_ALIASES))}), or give a .toml file with "
            f"{', '.join(MODEL_FIELDS)}"
        )
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ParameterError(f"robot model file {key!r} not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ParameterError(f"robot model file {key!r} cannot be read: {exc}") from None
    return _from_table(path.stem, table, f"robot model file {key!r}")


def model_for(robot_model: str, safety_radius: float) -> RobotModel:
    """The robot model named by ``ChainParams.robot_model`` (empty: :data:`DEFAULT_MODEL`), refused
    (:class:`ParameterError`) if its footprint leaves the safety disc of radius ``safety_radius`` [m] round the exit
    point (b + r_f > r): the planner keeps that disc clear of obstacles and other robots, so the footprint is clear
    when it lies inside."""
    model = load_robot_model(robot_model or DEFAULT_MODEL)
    reach = model.exit_offset + model.radius
    if reach > safety_radius + 1e-12:
        raise ParameterError(
            f"robot model {model.name!r}: its footprint (radius {model.radius:g} m round the axle, "
            f"{model.exit_offset:g} m behind the tether's exit point) leaves the safety disc r = {safety_radius:g} m "
            f"round the exit point that the planner keeps clear: use --robot-radius {reach:g} or more, or a smaller "
            "exit_offset"
        )
    return model


# ----------------------------------------------------------------------------------------------------------
# kinematics
# ----------------------------------------------------------------------------------------------------------
def _e(theta: ArrayLike) -> tuple[Array, Array]:
    th = np.asarray(theta, dtype=float)
    c, s = np.cos(th), np.sin(th)
    return np.stack([c, s], axis=-1), np.stack([-s, c], axis=-1)


def exit_point(axle: ArrayLike, theta: ArrayLike, b: float) -> Array:
    """p = c + b e(θ) [m]: the tether's exit point of robots at axle centres ``axle`` (..., 2) [m], headings
    ``theta`` (...) [rad]."""
    e, _ = _e(theta)
    return np.asarray(axle, dtype=float) + float(b) * e


def exit_velocity(theta: ArrayLike, v: ArrayLike, omega: ArrayLike, b: float) -> Array:
    """ṗ = v e(θ) + b ω e_⊥(θ) [m/s] (the derivative of :func:`exit_point` along the unicycle)."""
    e, n = _e(theta)
    return np.asarray(v, dtype=float)[..., None] * e + float(b) * np.asarray(omega, dtype=float)[..., None] * n


def exit_jacobian(theta: float, b: float) -> Array:
    """∂ṗ/∂(v, ω) = [e(θ), b e_⊥(θ)] (2, 2): invertible iff b ≠ 0 (det = b)."""
    e, n = _e(theta)
    return np.column_stack([e, float(b) * n])


def _sinc_half(dth: Array) -> Array:
    """sin(δ/2) / (δ/2), 1 at δ = 0 (np.sinc is sin(πx)/(πx))."""
    return np.sinc(np.asarray(dth, dtype=float) / (2.0 * np.pi))


def unicycle_step(axle: ArrayLike, theta: ArrayLike, v: ArrayLike, omega: ArrayLike, Ts: float) -> tuple[Array, Array]:
    """The exact pose after holding (v [m/s], ω [rad/s]) for ``Ts`` [s] from (``axle`` [m], ``theta`` [rad]):
    θ⁺ = θ + ω Ts, c⁺ = c + v Ts sinc(ω Ts / 2) e(θ + ω Ts / 2) (the arc's chord; a straight segment for ω = 0)."""
    th = np.asarray(theta, dtype=float)
    dth = np.asarray(omega, dtype=float) * float(Ts)
    e, _ = _e(th + 0.5 * dth)
    chord = np.asarray(v, dtype=float) * float(Ts) * _sinc_half(dth)
    return np.asarray(axle, dtype=float) + chord[..., None] * e, th + dth


def step_velocities(axle: ArrayLike, theta: ArrayLike, Ts: float) -> tuple[Array, Array, Array]:
    """From recorded poses alone: per step k (K, ...) the forward speed v [m/s], the yaw rate ω [rad/s] and the
    lateral velocity [m/s] of the axle centre, for states ``axle`` (K+1, ..., 2) and continuous (unwrapped) headings
    ``theta`` (K+1, ...) sampled every ``Ts`` [s].

    ω = Δθ / Ts; with the chord Δc split along the mid heading θ_m = θ_k + Δθ / 2, lateral = Δc·e_⊥(θ_m) / Ts (zero for
    any unicycle arc) and v = Δc·e(θ_m) / (Ts sinc(Δθ / 2)) (the inverse of :func:`unicycle_step`).
    """
    c = np.asarray(axle, dtype=float)
    th = np.asarray(theta, dtype=float)
    dc = np.diff(c, axis=0)
    dth = np.diff(th, axis=0)
    e, n = _e(th[:-1] + 0.5 * dth)
    Ts = float(Ts)
    lateral = np.einsum("...i,...i->...", dc, n) / Ts
    v = np.einsum("...i,...i->...", dc, e) / (Ts * _sinc_half(dth))
    return v, dth / Ts, lateral
