"""Scenarios: an environment, the tether anchor (base), the leader's goal and the team size.

The four built-in scenarios A-D reproduce the settings of Caruso 2021 §5 (three omnidirectional robots
tethered in a chain to a fixed base): A square room with five disc columns, goal behind the middle one; B a
curved high-curvature corridor leaving the room, goal at its end; C a small maze, goal in the top-right
corner; D a hangar with a Cessna C-172, the leader goes round the plane to the opposite side. They are data
files in ``tmr/scenarios/`` (TOML + GeoJSON, format in ``tmr/scenarios/README.md``); any TOML file of the same
format loads with :func:`load_scenario`.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ParameterError, ScenarioError
from tmr.world.environment import DEFAULT_RESOLUTION, DEFAULT_SAFETY_RADIUS, Environment
from tmr.world.maps import load_environment

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - python 3.10
    import tomli as tomllib

__all__ = [
    "SCENARIO_DIR",
    "Scenario",
    "all_builtins",
    "builtin_scenarios",
    "file_kind",
    "load_scenario",
    "read_scenario_toml",
    "resolve_scenario",
    "scenario_from_map",
    "scenario_kind",
]

SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"

_TOP_KEYS = {"name", "kind", "description", "robots", "base", "goal", "start", "map", "params", "drive", "robot_model"}
#: Top-level keys that are parameters (``ChainParams.drive``, ``robot_model``): merged into ``params``.
_PARAM_KEYS = ("drive", "robot_model")
_MAP_KEYS = {"file", "bounds", "safety_radius", "resolution"}


@dataclass
class Scenario:
    """A planning problem: environment, base (tether anchor), leader goal, optional start, team size.

    ``base`` and ``goal`` are (2,) [m]; ``start`` is (N, 2) [m], robot 1..N with robot N the leader, or None
    when the planner chooses the initial chain; ``params`` holds optional overrides of chain/controller
    parameters (the TOML ``[params]`` table). Validated on construction: N >= 1 integer, finite coordinates
    (ParameterError); base, goal and start points in free space (exact clearance > 0) and in one connected
    free region (ScenarioError).
    """

    name: str
    description: str
    environment: Environment
    base: NDArray[np.float64]
    goal: NDArray[np.float64]
    start: NDArray[np.float64] | None
    n_robots: int
    params: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None
    #: the leader's final heading [rad] (differential drive only), or None: a scenario file's ``goal = [x, y,
    #: theta]`` gives it in degrees (``goal`` is then the (2,) position)
    goal_heading: float | None = None

    def __post_init__(self) -> None:
        label = self._label()
        if np.shape(self.goal) == (3,):  # [x, y, theta]: theta in degrees
            goal = list(self.goal)
            if self.goal_heading is not None:
                raise ParameterError(f"{label}: the goal heading is given twice (goal = [x, y, theta], goal_heading)")
            theta = _finite_array(goal[2:], "goal heading (degrees)", label)[0]
            self.goal, self.goal_heading = list(goal[:2]), math.radians(float(theta))
        if self.goal_heading is not None:
            if isinstance(self.goal_heading, bool) or not math.isfinite(float(self.goal_heading)):
                raise ParameterError(f"{label}: the goal heading must be a finite angle, got {self.goal_heading!r}")
            self.goal_heading = float(self.goal_heading)
        if isinstance(self.n_robots, bool | np.bool_) or not isinstance(self.n_robots, int | np.integer):
            raise ParameterError(f"{label}: robots must be an integer >= 1, got {self.n_robots!r}")
        if self.n_robots < 1:
            raise ParameterError(f"{label}: robots must be >= 1 (number of tethered robots), got {self.n_robots}")
        self.n_robots = int(self.n_robots)
        self.base = _point(self.base, "base", label)
        self.goal = _point(self.goal, "goal", label)
        if self.start is not None:
            start = _finite_array(self.start, "start", label)
            if start.shape != (self.n_robots, 2):
                raise ParameterError(
                    f"{label}: start must list one [x, y] per robot, shape ({self.n_robots}, 2); got shape "
                    f"{start.shape}"
                )
            self.start = start
        _check_params(self.params, label)
        self._check_free()

    def _label(self) -> str:
        return f"scenario {self.name!r}" + (f" ({self.source})" if self.source is not None else "")

    def _check_free(self) -> None:
        env = self.environment
        label = self._label()
        names = ["base", "goal"]
        pts = [self.base, self.goal]
        if self.start is not None:
            names += [f"start of robot {k + 1}" for k in range(self.n_robots)]
            pts += list(self.start)
        P = np.array(pts)
        clear = env.exact_clearance(P)
        xmin, ymin, xmax, ymax = env.bounds
        for nm, p, c in zip(names, P, clear, strict=True):
            if not (xmin <= p[0] <= xmax and ymin <= p[1] <= ymax):
                raise ScenarioError(f"{label}: {nm} ({p[0]:.6g}, {p[1]:.6g}) m is outside the room {env.bounds}")
            known = getattr(env, "known_free", None)
            if (
                not c > 0.0
                and known is not None
                and not (known[0] <= p[0] <= known[2] and known[1] <= p[1] <= known[3])
            ):
                raise ScenarioError(
                    f"{label}: {nm} ({p[0]:g}, {p[1]:g}) m is outside the map's known free area (x {known[0]:.6g} .. "
                    f"{known[2]:.6g} m, y {known[1]:.6g} .. {known[3]:.6g} m; unknown and occupied cells are obstacles)"
                )
            if not c > 0.0:
                raise ScenarioError(
                    f"{label}: {nm} ({p[0]:g}, {p[1]:g}) m is not in free space: clearance {c:.3f} m to the "
                    f"obstacles and walls grown by the safety radius {env.safety_radius:g} m (must be > 0); "
                    f"move it away from the obstacles"
                )
        # every point must lie in the same connected piece of free space as the base
        r = float(env.safety_radius)
        gap = float(np.linalg.norm(P[1] - P[0]))
        if gap < r:  # the leader's disc would cover the anchor: no robot can stand at the goal
            raise ScenarioError(
                f"{label}: the goal ({P[1][0]:g}, {P[1][1]:g}) m is {gap:.3g} m from the base (the tether anchor), "
                f"within the robot radius {r:g} m: no robot can stand there; move the goal away from the anchor"
            )
        region = env.free_region(P)
        for nm, p, reg in zip(names[1:], P[1:], region[1:], strict=True):
            if reg != region[0]:
                raise ScenarioError(
                    f"{label}: no free route from the base to the {nm} ({p[0]:g}, {p[1]:g}) m: they lie in "
                    f"different connected regions of free space (the obstacles grown by {env.safety_radius:g} m "
                    "separate them)"
                )


def _finite_array(value: Any, what: str, label: str) -> NDArray[np.float64]:
    def texts(v: Any) -> bool:  # a TOML string or boolean is not a number, though numpy would convert "90" or true
        return isinstance(v, str | bool) or (isinstance(v, list | tuple) and any(texts(u) for u in v))

    if texts(value):
        raise ParameterError(f"{label}: {what} must be numbers, got {value!r}")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{label}: {what} must be numbers [m], got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{label}: {what} contains NaN or inf: {arr.tolist()}")
    return arr


def _point(value: Any, what: str, label: str) -> NDArray[np.float64]:
    arr = _finite_array(value, what, label)
    if arr.shape != (2,):
        form = "[x, y] in metres, or [x, y, theta] (theta in degrees)" if what == "goal" else "[x, y] in metres"
        raise ParameterError(f"{label}: {what} must be {form}, got {np.asarray(value).tolist()!r}")
    return arr


def _check_params(params: Any, label: str, prefix: str = "params") -> None:
    if not isinstance(params, dict):
        raise ParameterError(f"{label}: {prefix} must be a table of name = value, got {type(params).__name__}")
    for key, val in params.items():
        _check_param_value(val, f"{prefix}.{key}", label)


def _check_param_value(val: Any, name: str, label: str) -> None:
    if isinstance(val, dict):
        _check_params(val, label, name)
    elif isinstance(val, list | tuple):
        for k, v in enumerate(val):
            _check_param_value(v, f"{name}[{k}]", label)
    elif isinstance(val, float) and not math.isfinite(val):
        raise ParameterError(f"{label}: {name} = {val} is not a finite number")


def builtin_scenarios() -> list[str]:
    """Names of the built-in ground scenarios (``["A", "B", "C", "D", "E", "J"]``): the TOML files in ``scenarios/``
    without ``kind = "drone"`` (those are :func:`tmr.world.drones.builtin_drone_scenarios`)."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml") if file_kind(p) == "ground")


def file_kind(path: Path) -> str:
    """The ``kind`` of a scenario TOML file: ``"ground"`` (the default) or ``"drone"``; ``"ground"`` for a file that
    does not parse (its loader reports why)."""
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return "ground"
    kind = doc.get("kind", "ground")
    return kind if isinstance(kind, str) else "ground"


def all_builtins() -> dict[str, Path]:
    """Every built-in scenario, ground and drone: its name → its TOML file in ``scenarios/``."""
    return {p.stem: p for p in sorted(SCENARIO_DIR.glob("*.toml"))}


def resolve_scenario(name_or_path: str | Path) -> Path:
    """A built-in name (case-insensitive, ground or drone) or a path -> the file (ScenarioError if none)."""
    if isinstance(name_or_path, str) and not any(sep in name_or_path for sep in "/\\") and "." not in name_or_path:
        match = [p for n, p in all_builtins().items() if n.lower() == name_or_path.strip().lower()]
        if match:
            return match[0]
        if not Path(name_or_path).exists():
            raise ScenarioError(
                f"unknown scenario {name_or_path!r}: built-in scenarios are {', '.join(all_builtins())}; or give "
                "the path of a scenario .toml file"
            )
    path = Path(name_or_path)
    if not path.exists():
        raise ScenarioError(f"{path}: scenario file not found (built-in scenarios are {', '.join(all_builtins())})")
    return path  # a directory or an unreadable file: tmr.files.read_text says which, in one line


def read_scenario_toml(path: Path) -> tuple[str, dict[str, Any]]:
    """The text of a scenario file and its TOML table (ScenarioError, one line, for unreadable text or invalid TOML)."""
    from tmr.files import read_text

    text = read_text(path, "scenario TOML", ScenarioError)
    try:
        return text, tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None


def scenario_kind(name_or_path: str | Path) -> Literal["ground", "drone"]:
    """``"drone"`` for a scenario with ``kind = "drone"``, ``"ground"`` for the others (the default kind). Reads the
    file only: ``tmr plan`` asks it of every scenario before it loads one (no 3-D geometry imported for a ground run).

    Raises ScenarioError for an unknown name, a missing or unreadable file, invalid TOML or another kind."""
    path = resolve_scenario(name_or_path)
    _, doc = read_scenario_toml(path)
    kind = doc.get("kind", "ground")
    if kind not in ("ground", "drone"):
        raise ScenarioError(f'scenario file {path}: kind must be "ground" (the default) or "drone", got {kind!r}')
    return kind  # type: ignore[no-any-return]


def load_scenario(name_or_path: str | Path, safety_radius: float | None = None) -> Scenario:
    """Load a built-in scenario by name ("A".."D", case-insensitive) or a scenario TOML file by path.

    ``safety_radius`` [m]: the robot radius r to grow the obstacles by, instead of the file's (``[params]``
    ``safety_radius``, else ``[map] safety_radius``, else 0.5 m); base, goal and start are checked with it.

    Raises ScenarioError for an unknown name, a missing or malformed TOML, missing keys or points not in free
    space; ParameterError for N < 1 robots or NaN/inf numbers; MapError for a bad map file.
    """
    if isinstance(name_or_path, str) and not any(sep in name_or_path for sep in "/\\") and "." not in name_or_path:
        builtins = builtin_scenarios()
        everything = sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))  # a drone name: refused by _load_toml
        match = [b for b in everything if b.lower() == name_or_path.strip().lower()]
        if match:
            return _load_toml(SCENARIO_DIR / f"{match[0]}.toml", safety_radius)
        if not Path(name_or_path).exists():
            raise ScenarioError(
                f"unknown scenario {name_or_path!r}: built-in scenarios are {', '.join(builtins)}; "
                f"or give the path of a scenario .toml file"
            )
    path = Path(name_or_path)
    if not path.exists():
        raise ScenarioError(
            f"{path}: scenario file not found (built-in scenarios are {', '.join(builtin_scenarios())})"
        )
    return _load_toml(path, safety_radius)


def _load_toml(path: Path, safety_radius: float | None = None) -> Scenario:
    from tmr.files import read_text

    text = read_text(path, "scenario TOML", ScenarioError)  # a directory, random bytes: one line, exit 2
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    label = f"scenario file {path}"
    kind = doc.get("kind", "ground")
    if kind == "drone":
        raise ScenarioError(
            f'{label} is a drone scenario (kind = "drone"): load it with tmr.world.drones.load_drone_scenario'
        )
    if kind != "ground":
        raise ScenarioError(f'{label}: kind must be "ground" (the default) or "drone", got {kind!r}')
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        hint = ' (a [world] table is a drone scenario: add kind = "drone")' if "world" in unknown else ""
        raise ScenarioError(f"{label}: unknown keys {sorted(unknown)}; allowed: {sorted(_TOP_KEYS)}{hint}")
    for key in ("base", "goal", "map"):
        if key not in doc:
            raise ScenarioError(f"{label}: missing required key {key!r}")
    name = doc.get("name", path.stem)
    description = doc.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise ScenarioError(f"{label}: name and description must be strings")
    robots = doc.get("robots", 3)
    if isinstance(robots, float) and robots.is_integer():
        robots = int(robots)

    m = doc["map"]
    if not isinstance(m, dict):
        raise ScenarioError(f"{label}: [map] must be a table with file, bounds, safety_radius, resolution")
    unknown = set(m) - _MAP_KEYS
    if unknown:
        raise ScenarioError(f"{label}: unknown keys in [map] {sorted(unknown)}; allowed: {sorted(_MAP_KEYS)}")
    if not isinstance(m.get("file"), str):
        raise ScenarioError(f'{label}: [map] needs file = "<map file relative to the TOML>"')
    map_path = Path(m["file"])
    if not map_path.is_absolute():
        map_path = path.parent / map_path
    params = doc.get("params", {})
    if isinstance(params, dict):
        params = _drive_params(doc, params, path, label)
    if safety_radius is None and isinstance(params, dict) and "safety_radius" in params:
        safety_radius = _number(params["safety_radius"], "params.safety_radius", label)  # one r: the chain's
    if safety_radius is None:
        safety_radius = _number(m.get("safety_radius", DEFAULT_SAFETY_RADIUS), "map.safety_radius", label)
    env = load_environment(
        map_path,
        bounds=m.get("bounds"),
        safety_radius=safety_radius,
        resolution=_number(m.get("resolution", DEFAULT_RESOLUTION), "map.resolution", label),
    )
    return Scenario(
        name=name,
        description=description,
        environment=env,
        base=doc["base"],
        goal=doc["goal"],
        start=doc.get("start"),
        n_robots=robots,
        params=(dict(params) | ({"safety_radius": env.safety_radius} if "safety_radius" in params else {}))
        if isinstance(params, dict)
        else params,
        source=path,
    )


def _drive_params(doc: dict[str, Any], params: dict[str, Any], path: Path, label: str) -> dict[str, Any]:
    """``params`` with the top-level ``drive`` and ``robot_model`` keys merged in (refused if ``[params]`` gives them
    too; a robot model without a drive implies ``drive = "diff"``, as ``--robot-model`` does), and a relative robot
    model file (``*.toml``) made relative to the scenario file, like its map. Unchanged when the scenario has neither
    (its parameters keep their bytes)."""
    top = {k: doc[k] for k in _PARAM_KEYS if k in doc}
    twice = sorted(set(top) & set(params))
    if twice:
        raise ScenarioError(f"{label}: {', '.join(twice)} given at the top and in [params]: give one")
    out = dict(params) | top if top else params
    if "robot_model" in out and "drive" not in out:  # a robot model is a differential drive's, as --robot-model
        out = dict(out) | {"drive": "diff"}
    model = out.get("robot_model")
    if isinstance(model, str) and model.lower().endswith(".toml") and not Path(model).is_absolute():
        out = dict(out) | {"robot_model": str(path.parent / model)}
    return out


def _number(value: Any, what: str, label: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ParameterError(f"{label}: {what} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ParameterError(f"{label}: {what} = {value} is not a finite number")
    return float(value)


def scenario_from_map(
    map_path: str | Path,
    base: ArrayLike,
    goal: ArrayLike,
    start: ArrayLike | None = None,
    n_robots: int = 3,
    *,
    bounds: tuple[float, float, float, float] | None = None,
    safety_radius: float = DEFAULT_SAFETY_RADIUS,
    resolution: float = DEFAULT_RESOLUTION,
    name: str | None = None,
) -> Scenario:
    """Scenario from a map file plus base and goal [m] (the ``--map --base --goal`` command-line use).

    ``map_path``: any format of :func:`tmr.world.maps.load_map`; ``bounds`` is needed for GeoJSON/WKT files that
    do not carry their own. Validated like a scenario file (ScenarioError / ParameterError / MapError).
    """
    p = Path(map_path)
    env = load_environment(p, bounds=bounds, safety_radius=safety_radius, resolution=resolution)
    return Scenario(
        name=name if name is not None else p.stem,
        description=f"map {p.name}",
        environment=env,
        base=base,  # type: ignore[arg-type]  # converted and validated in Scenario.__post_init__
        goal=goal,  # type: ignore[arg-type]
        start=start,  # type: ignore[arg-type]
        n_robots=n_robots,
        source=p,
    )
