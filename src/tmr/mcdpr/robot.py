"""Robot description of a mobile cable-driven parallel robot (MCDPR), loadable from TOML (Rasheed 2019 sec. 2).

``p`` mobile bases carry ``m`` cables (``cable_base[k]`` = index of the base carrying cable k). Each cable leaves its
base at an exit point fixed in the base frame; MoPICK has one cable per base with the exit point on the base's
vertical axis 1.2 m above the ground, so turning a base in place does not change its cable (Rasheed 2019 sec. 2).
The platform is a point mass (n = 3 dof). Each base stands on wheel contact points (its footprint, anticlockwise
seen from above) and has a mass and a centre of gravity, which enter the tipping moments (Rasheed 2019 eq. 5).
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from shapely.geometry import Point, Polygon

from tmr.mcdpr.errors import ParameterError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - python 3.10
    import tomli as tomllib

__all__ = ["Robot", "load_robot", "mopick"]


def _arr(value: Any, shape: tuple[int | None, ...], name: str) -> NDArray[np.float64]:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be numeric, got {value!r}") from exc
    if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape, strict=True)):
        raise ParameterError(f"{name} must have shape {shape} (None = any), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be finite, got {a.tolist()}")
    a.setflags(write=False)
    return a


def _scalar(value: Any, name: str) -> float:
    if isinstance(value, (bool, np.bool_)):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a number, got {value!r}") from exc


def _integer(value: Any, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ParameterError(f"{name} must be an integer, got {value!r}")
    return int(value)


@dataclass(frozen=True, eq=False)
class Robot:
    """An MCDPR: bases, cables, footprints, masses and tension bounds (SI units).

    Attributes:
        name: label.
        n_bases: number of mobile bases p.
        cable_base: (m,) index of the base carrying each cable.
        exit_points: (m, 3) cable exit point A_k in the frame of its base [m] (Rasheed 2019 Fig. 1b).
        base_radius: r_mb, radius of the cylindrical base [m]; obstacles are inflated by it.
        footprint: (c, 2) wheel contact points C_o in the base frame, anticlockwise [m] (Rasheed 2019 eq. 5).
        base_mass: mass of one base [kg].
        cog: (3,) centre of gravity of a base in its frame [m]; its ground projection must lie inside the footprint.
        platform_mass: mass of the point-mass platform [kg].
        t_min, t_max: cable tension bounds [N] (Rasheed 2019 eq. 4).
        gravity: g [m/s²].
    """

    name: str = "MoPICK"
    n_bases: int = 4
    cable_base: tuple[int, ...] = (0, 1, 2, 3)
    exit_points: NDArray[np.float64] = field(default_factory=lambda: np.tile([0.0, 0.0, 1.2], (4, 1)))
    base_radius: float = 0.25
    footprint: NDArray[np.float64] = field(
        default_factory=lambda: np.array([[0.2, 0.0], [0.0, 0.2], [-0.2, 0.0], [0.0, -0.2]])
    )
    base_mass: float = 8.0
    cog: NDArray[np.float64] = field(default_factory=lambda: np.array([0.0, 0.0, 0.3]))
    platform_mass: float = 0.5
    t_min: float = 0.0
    t_max: float = 15.0
    gravity: float = 9.81

    def __post_init__(self) -> None:
        if not isinstance(self.name, str):
            raise ParameterError(f"name must be a string, got {self.name!r}")
        object.__setattr__(self, "n_bases", _integer(self.n_bases, "n_bases"))
        try:
            cb = tuple(_integer(b, "cable_base entry") for b in self.cable_base)
        except TypeError as exc:
            raise ParameterError(f"cable_base must be a list of base indices, got {self.cable_base!r}") from exc
        m = len(cb)
        if self.n_bases < 1 or m < 1:
            raise ParameterError(f"need at least one base and one cable, got p={self.n_bases}, m={m}")
        if any(b < 0 or b >= self.n_bases for b in cb):
            raise ParameterError(f"cable_base entries must be in 0..{self.n_bases - 1}, got {cb}")
        object.__setattr__(self, "cable_base", cb)
        object.__setattr__(self, "exit_points", _arr(self.exit_points, (m, 3), "exit_points [m]"))
        fp = _arr(self.footprint, (None, 2), "footprint [m]")
        if len(fp) < 3:
            raise ParameterError(f"footprint needs at least 3 contact points, got {len(fp)}")
        gap = np.linalg.norm(np.roll(fp, -1, axis=0) - fp, axis=1)
        if np.any(gap <= 1e-9):
            k = int(np.argmax(gap <= 1e-9))
            raise ParameterError(
                f"footprint contact points {k} and {(k + 1) % len(fp)} coincide ({fp[k].tolist()}): list every "
                "contact point once (do not repeat the first point at the end)"
            )
        poly = Polygon(fp)
        if not poly.is_valid or poly.area <= 0.0 or not poly.exterior.is_ccw:
            raise ParameterError("footprint must be a simple polygon listed anticlockwise (seen from above)")
        object.__setattr__(self, "footprint", fp)
        cog = _arr(self.cog, (3,), "cog [m]")
        if not poly.contains(Point(cog[:2])):
            raise ParameterError(f"the centre of gravity {cog[:2].tolist()} must project inside the footprint")
        object.__setattr__(self, "cog", cog)
        for name in ("base_radius", "base_mass", "gravity"):
            v = _scalar(getattr(self, name), name)
            if not np.isfinite(v) or v <= 0.0:
                raise ParameterError(f"{name} must be positive and finite, got {v}")
            object.__setattr__(self, name, v)
        for name in ("platform_mass", "t_min", "t_max"):
            v = _scalar(getattr(self, name), name)
            if not np.isfinite(v) or v < 0.0:
                raise ParameterError(f"{name} must be non-negative and finite, got {v}")
            object.__setattr__(self, name, v)
        if self.t_max <= self.t_min:
            raise ParameterError(f"t_max ({self.t_max} N) must exceed t_min ({self.t_min} N)")

    @property
    def n_cables(self) -> int:
        """Number of cables m."""
        return len(self.cable_base)

    @property
    def one_cable_per_base(self) -> bool:
        """True when every base carries exactly one cable (tipping = per-cable bound, fast capacity path)."""
        return sorted(self.cable_base) == list(range(self.n_bases))

    @property
    def axial_exits(self) -> bool:
        """True when every exit point is on its base's vertical axis (base heading does not change W)."""
        return bool(np.all(self.exit_points[:, :2] == 0.0))

    def replace(self, **changes: Any) -> Robot:
        """Copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


def load_robot(path: str | Path) -> Robot:
    """Robot from a TOML file with the field names of :class:`Robot` (those left out keep their defaults); unknown
    keys, an empty file, a directory or a file that is not UTF-8 text raise ParameterError."""
    from tmr.files import read_text

    path = Path(path)
    text = read_text(path, "robot TOML", ParameterError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"{path}: cannot read robot TOML: {exc}") from exc
    if not data:  # else every field at its default: the shipped robot planned as if it were this file's
        raise ParameterError(
            f"{path}: the robot file is empty; give the fields of tmr.mcdpr.Robot (the shipped mopick.toml is an "
            "example), or leave out --robot for the shipped MoPICK"
        )
    return robot_from_dict(data, str(path))


def robot_from_dict(data: dict[str, Any], where: str = "robot") -> Robot:
    """Robot from a mapping (the parsed TOML)."""
    known = {f.name for f in dataclasses.fields(Robot)}
    unknown = set(data) - known
    if unknown:
        raise ParameterError(f"{where}: unknown robot keys {sorted(unknown)}; known: {sorted(known)}")
    kwargs = dict(data)
    if "cable_base" in kwargs:
        if not isinstance(kwargs["cable_base"], (list, tuple)):
            raise ParameterError(f"{where}: cable_base must be a list of base indices, got {kwargs['cable_base']!r}")
        kwargs["cable_base"] = tuple(kwargs["cable_base"])
    try:
        return Robot(**kwargs)
    except ParameterError as exc:
        raise ParameterError(f"{where}: {exc}") from exc
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{where}: invalid robot description: {exc}") from exc


def mopick() -> Robot:
    """The MoPICK robot shipped as ``tmr/mcdpr/mopick.toml`` (Rasheed 2019 values + documented assumptions)."""
    text = resources.files("tmr.mcdpr").joinpath("mopick.toml").read_text()
    return robot_from_dict(tomllib.loads(text), "mopick.toml")
