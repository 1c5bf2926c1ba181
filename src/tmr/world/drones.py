"""Drone scenarios: a 3-D world, the ground winch (base), the leader's goal, the team size and the tether.

A drone scenario is a TOML file with ``kind = "drone"`` (format in ``scenarios/README.md``, model in
``formulations/drones.md``)::

    name = "window"            # default: the file name without suffix
    kind = "drone"             # required: the ground chain is the default kind
    description = "..."        # optional
    robots = 3                 # N >= 1 drones, or "auto" (the fewest the route needs); default 3
    base = [1.0, 5.0, 0.3]     # the anchor: the ground winch [m]
    goal = [9.0, 5.0, 2.0]     # the leader's goal [m]
    [world]                    # tmr.world.world3d.world3d_from_table: bounds, safety_radius (drone radius r), obstacles
    [tether]                   # optional overrides of tmr.model.catenary3d.DroneTetherParams (not drone_radius)
    [params]                   # optional overrides of tmr.model.params.DroneParams

What is checked (one-line errors, exit 2): unknown keys at every level, the ``[tether]`` and ``[params]`` names and
values (their classes' own checks); the goal must be free for a drone (clearance > 0 from the obstacles and the room
grown by r) and farther than r from the base; the base is the ground winch, not a drone: it must lie in the room, at
least c_t above the floor and c_t from every obstacle and wall (the tether leaves it, and the whole tether keeps c_t),
but it may be nearer than r to the floor.

The built-in drone scenarios F, G and H live in ``scenarios/`` beside the ground ones; :func:`builtin_drone_scenarios`
lists them, :func:`tmr.world.scenario.builtin_scenarios` keeps listing only the ground ones.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from tmr.errors import MapError, ParameterError, ScenarioError, fmt_point
from tmr.model.catenary3d import DroneTetherParams
from tmr.model.params import DroneParams, convert_field
from tmr.world.scenario import all_builtins, file_kind, read_scenario_toml, resolve_scenario, scenario_kind
from tmr.world.world3d import World3D, world3d_from_table

if sys.version_info >= (3, 11):
    pass
else:  # pragma: no cover - python 3.10
    pass

__all__ = ["DroneScenario", "builtin_drone_scenarios", "load_drone_scenario", "scenario_kind"]

_TOP_KEYS = {"name", "kind", "description", "robots", "base", "goal", "world", "tether", "params"}
_TETHER_KEYS = {f.name for f in dataclasses.fields(DroneTetherParams)} - {"drone_radius"}
_PARAM_KEYS = {f.name for f in dataclasses.fields(DroneParams)}


@dataclass
class DroneScenario:
    """A drone-chain planning problem (units: m, N).

    Attributes:
        name, description: as in the file.
        n_robots: N >= 1 drones, or ``"auto"``: the fewest the route needs (the planner decides).
        base: the anchor, the ground winch (3,) [m]. goal: the leader's goal (3,) [m].
        world: the room and obstacles, ``safety_radius`` = the drone radius r.
        world_table: the parsed ``[world]`` table (JSON-able; mesh paths as written in the file).
        tether: the tether and drone parameters with the ``[tether]`` overrides; ``drone_radius`` = r.
        params: the ``[params]`` overrides of :class:`tmr.model.params.DroneParams` (names and values checked).
        source: the file, or None. text: the file's text ("" if built in memory).
    """

    name: str
    description: str
    n_robots: int | Literal["auto"]
    base: NDArray[np.float64]
    goal: NDArray[np.float64]
    world: World3D
    world_table: dict[str, Any]
    tether: DroneTetherParams
    params: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None
    text: str = ""

    def __post_init__(self) -> None:
        label = self._label()
        n = self.n_robots
        if isinstance(n, float) and n.is_integer():
            n = int(n)
        if n != "auto" and (isinstance(n, bool | np.bool_) or not isinstance(n, int | np.integer) or n < 1):
            raise ParameterError(f'{label}: robots must be an integer >= 1 or "auto", got {self.n_robots!r}')
        self.n_robots = n if n == "auto" else int(n)  # type: ignore[assignment]
        self.base = _point3(self.base, "base", label)
        self.goal = _point3(self.goal, "goal", label)
        if not isinstance(self.params, dict):
            raise ParameterError(f"{label}: [params] must be a table of name = value")
        unknown = sorted(set(self.params) - _PARAM_KEYS)
        if unknown:
            raise ParameterError(f"{label}: unknown [params] {unknown}; known: {sorted(_PARAM_KEYS)}")
        try:  # the field's type, as --set converts it ("a" for a number is refused, 2.5 for an int too)
            self.params = {k: convert_field(DroneParams, k, v) for k, v in self.params.items()}
        except ParameterError as exc:
            raise ParameterError(f"{label}: [params]: {exc}") from None
        self.drone_params()  # the values: DroneParams' own checks
        if self.tether.drone_radius != self.world.safety_radius:
            self.tether = dataclasses.replace(self.tether, drone_radius=self.world.safety_radius)
        self._check_points()

    def _label(self) -> str:
        return f"scenario {self.name!r}" + (f" ({self.source})" if self.source is not None else "")

    def drone_params(self) -> DroneParams:
        """:class:`DroneParams` with this scenario's ``[params]`` overrides (ParameterError for a bad value)."""
        try:
            return DroneParams(**self.params)
        except TypeError as exc:  # a wrong type a dataclass rejects before its checks
            raise ParameterError(f"{self._label()}: [params]: {exc}") from None

    def _check_points(self) -> None:
        label = self._label()
        lo, hi = np.asarray(self.world.bounds[:3]), np.asarray(self.world.bounds[3:])
        c_t = self.tether.clearance
        for nm, p in (("base", self.base), ("goal", self.goal)):
            if np.any(p < lo) or np.any(p > hi):
                raise ScenarioError(
                    f"{label}: the {nm} {fmt_point(p)} is outside the room {fmt_point(self.world.bounds)}"
                )
        # the winch: the tether leaves it, so it keeps the tether's clearance c_t (from obstacles, walls and floor)
        bare = float(self.world.with_safety_radius(0.0).exact_clearance(self.base))
        if not bare >= c_t:
            raise ScenarioError(
                f"{label}: the base (ground winch) {fmt_point(self.base)} is {bare:.3f} m from the nearest obstacle, "
                f"wall or the floor, less than the tether clearance c_t {c_t:.3f} m; move it away"
            )
        goal_clear = float(self.world.exact_clearance(self.goal))
        if not goal_clear > 0.0:
            raise ScenarioError(
                f"{label}: the goal {fmt_point(self.goal)} is not free for a drone: clearance {goal_clear:.3f} m to "
                f"the obstacles, walls, floor and ceiling grown by the drone radius {self.world.safety_radius:.3f} m "
                "(must be > 0); move it away from the obstacles"
            )
        gap = float(np.linalg.norm(self.goal - self.base))
        if gap <= self.world.safety_radius:
            raise ScenarioError(
                f"{label}: the goal {fmt_point(self.goal)} is {gap:.3f} m from the base, within the drone radius "
                f"{self.world.safety_radius:.3f} m: no drone can stand there"
            )


def _point3(value: Any, what: str, label: str) -> NDArray[np.float64]:
    if isinstance(value, list | tuple) and any(isinstance(v, bool | np.bool_) for v in value):
        raise ParameterError(f"{label}: {what} must be [x, y, z] in metres, got {value!r} (true/false is not a number)")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{label}: {what} must be [x, y, z] in metres, got {value!r}") from None
    if arr.shape != (3,):
        raise ParameterError(f"{label}: {what} must be [x, y, z] in metres, got {value!r}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{label}: {what} contains NaN or inf: {arr.tolist()}")
    return arr


def builtin_drone_scenarios() -> list[str]:
    """Names of the built-in drone scenarios (``["F", "G", "H"]``): the ``kind = "drone"`` files in ``scenarios/``."""
    return sorted(name for name, p in all_builtins().items() if file_kind(p) == "drone")


def load_drone_scenario(name_or_path: str | Path) -> DroneScenario:
    """Load a built-in drone scenario by name ("F", "G", "H", case-insensitive) or a ``kind = "drone"`` TOML file.

    Raises:
        ScenarioError: unknown name, missing or malformed file, not a drone file, unknown or missing keys, base or
            goal not where they may be (module doc).
        MapError: a bad ``[world]`` table or mesh file.
        ParameterError: bad ``robots``, ``[tether]`` or ``[params]`` values, NaN/inf coordinates.
    """
    path = resolve_scenario(name_or_path)
    text, doc = read_scenario_toml(path)
    label = f"scenario file {path}"
    kind = doc.get("kind", "ground")
    if kind != "drone":
        raise ScenarioError(
            f'{label} is not a drone scenario (kind = {kind!r}, need kind = "drone"); ground scenarios load with '
            "tmr.world.scenario.load_scenario"
        )
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise ScenarioError(f"{label}: unknown keys {unknown}; allowed: {sorted(_TOP_KEYS)}")
    for key in ("base", "goal", "world"):
        if key not in doc:
            raise ScenarioError(f"{label}: missing required key {key!r}")
    name, description = doc.get("name", path.stem), doc.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise ScenarioError(f"{label}: name and description must be strings")
    world_table = doc["world"]
    if not isinstance(world_table, dict):
        raise MapError(f"{label}: [world] must be a table with bounds, safety_radius, obstacles")
    world = world3d_from_table(world_table, base=path.parent, where=f"{label} [world]")
    tether_table = doc.get("tether", {})
    if not isinstance(tether_table, dict):
        raise ScenarioError(f"{label}: [tether] must be a table of name = value")
    if "drone_radius" in tether_table:
        raise ScenarioError(f"{label}: [tether] drone_radius: the drone radius is [world] safety_radius")
    unknown = sorted(set(tether_table) - _TETHER_KEYS)
    if unknown:
        raise ScenarioError(f"{label}: unknown keys in [tether] {unknown}; allowed: {sorted(_TETHER_KEYS)}")
    for key, val in tether_table.items():
        if isinstance(val, float) and not math.isfinite(val):
            raise ParameterError(f"{label}: tether.{key} = {val} is not a finite number")
    tether = DroneTetherParams(**tether_table, drone_radius=world.safety_radius)
    params = doc.get("params", {})
    return DroneScenario(
        name=name,
        description=description,
        n_robots=doc.get("robots", 3),
        base=doc["base"],
        goal=doc["goal"],
        world=world,
        world_table=world_table,
        tether=tether,
        params=dict(params) if isinstance(params, dict) else params,
        source=path,
        text=text,
    )
