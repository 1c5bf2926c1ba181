"""Planning scene of an MCDPR task: room, tables, cylindrical obstacles, task and way-points (Rasheed 2019 sec. 4).

Obstacles (tables as rectangles, obstacles as discs; shapely) are inflated by the base radius r_mb (the "safe region
around obstacles" of Rasheed 2019 Fig. 2) through :class:`tmr.world.environment.Environment`, so a base is a point that
must
stay in the free space. The platform passes over the tables (it flies above them), the bases must not. Way-points are
the task points (above tables: pick/place) plus intermediate points between consecutive task points, each shifted
sideways to maximise its distance to the nearest (raw) obstacle (Rasheed 2019 sec. 4).

A scene is a TOML file (see ``tmr/mcdpr/scenes/fig2.toml``)::

    name = "fig2"
    bounds = [xmin, ymin, xmax, ymax]          # room [m]
    tasks = [[x, y, z], ...]                   # task points of the platform [m], in order
    bases = [[x, y], ...]                      # initial base positions [m] (p rows)
    headings = [...]                           # initial base headings [rad] (optional, default 0)
    external = [fx, fy, fz]                    # half-widths of the external wrench box [N] (optional)
    intermediate = 1                           # intermediate way-points per pair of task points (optional)
    lateral = 1.5                              # max sideways shift of an intermediate point [m] (optional)
    [[tables]]   center = [x, y]  size = [lx, ly]  angle = 0.0   # [m], [m], [deg]
    [[obstacles]] center = [x, y]  radius = r                      # [m]
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely import affinity
from shapely.geometry import Point, box
from shapely.geometry.base import BaseGeometry

from tmr.errors import TmrError
from tmr.mcdpr.errors import ScenarioError
from tmr.mcdpr.robot import Robot
from tmr.world.environment import Environment

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - python 3.10
    import tomli as tomllib

__all__ = ["Scene", "builtin_scenes", "load_scene", "waypoints"]

_KEYS = {"name", "bounds", "tasks", "bases", "headings", "external", "intermediate", "lateral", "tables", "obstacles"}


@dataclass(frozen=True)
class Scene:
    """An MCDPR task scene (SI units). Build with :func:`load_scene` or directly.

    tables, obstacles: raw shapely polygons (tables are rectangles, obstacles discs). tasks: (k, 3) task points [m].
    bases: (p, 2) initial base positions [m]. headings: (p,) [rad]. external: (3,) external wrench half-widths [N].
    discs: (k, 3) the obstacles' exact circles (x, y, radius) [m] (the polygons of ``obstacles`` are inscribed in
    them; the search planner checks the bases against the exact circles).
    """

    name: str
    bounds: tuple[float, float, float, float]
    tables: tuple[BaseGeometry, ...]
    obstacles: tuple[BaseGeometry, ...]
    tasks: NDArray[np.float64]
    bases: NDArray[np.float64]
    headings: NDArray[np.float64]
    external: NDArray[np.float64] = field(default_factory=lambda: np.ones(3))
    intermediate: int = 1
    lateral: float = 1.5
    discs: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))

    def environment(self, robot: Robot) -> Environment:
        """Room with tables and obstacles inflated by the base radius (bases become points)."""
        return Environment.from_geometry(
            list(self.tables) + list(self.obstacles), self.bounds, safety_radius=robot.base_radius, resolution=0.05
        )

    def validate(self, robot: Robot, env: Environment | None = None) -> Environment:
        """Check sizes, the start (bases in free space, apart, below the exit height); return the environment."""
        if self.bases.shape != (robot.n_bases, 2):
            raise ScenarioError(f"scene {self.name}: needs {robot.n_bases} base positions, got {self.bases.shape[0]}")
        if self.headings.shape != (robot.n_bases,):
            raise ScenarioError(f"scene {self.name}: needs {robot.n_bases} headings, got {self.headings.shape}")
        if len(self.tasks) < 2:
            raise ScenarioError(f"scene {self.name}: needs at least 2 task points, got {len(self.tasks)}")
        ztop = float(robot.exit_points[:, 2].min())
        if np.any(self.tasks[:, 2] >= ztop) or np.any(self.tasks[:, 2] <= 0):
            raise ScenarioError(f"scene {self.name}: task heights must be in (0, {ztop}) m (below the cable exits)")
        x0, y0, x1, y1 = self.bounds
        t = self.tasks
        if np.any((t[:, 0] <= x0) | (t[:, 0] >= x1) | (t[:, 1] <= y0) | (t[:, 1] >= y1)):
            raise ScenarioError(f"scene {self.name}: a task point is outside the room {self.bounds}")
        try:
            env = env or self.environment(robot)
        except TmrError as exc:
            raise ScenarioError(f"scene {self.name}: {exc}") from exc
        bad = np.flatnonzero(~env.is_free(self.bases))
        if len(bad):
            raise ScenarioError(
                f"scene {self.name}: base(s) {bad.tolist()} start inside an obstacle inflated by the base radius "
                f"{robot.base_radius} m or outside the room"
            )
        d = np.linalg.norm(self.bases[:, None] - self.bases[None], axis=-1) + np.eye(len(self.bases)) * 1e9
        if d.min() < 2 * robot.base_radius:
            raise ScenarioError(f"scene {self.name}: two bases start closer than 2 r_mb = {2 * robot.base_radius} m")
        return env


def _arr(data: Any, key: str, shape: tuple[int | None, ...], where: str, default: Any = None) -> NDArray[np.float64]:
    if not isinstance(data, dict):
        raise ScenarioError(f"{where}: expected a table with key {key!r}, got {type(data).__name__} {data!r}")
    if key not in data and default is None:
        raise ScenarioError(f"{where}: missing key {key!r}")
    value = data.get(key, default)
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"{where}: {key} must be numeric, got {value!r}") from exc
    if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape, strict=True)):
        raise ScenarioError(f"{where}: {key} must have shape {shape} (None = any), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ScenarioError(f"{where}: {key} must be finite, got {value!r}")
    return a


def _num(data: dict[str, Any], key: str, default: float, where: str) -> float:
    """A finite number data[key] (default when absent); ScenarioError otherwise."""
    value = data.get(key, default)
    if isinstance(value, bool):
        raise ScenarioError(f"{where}: {key} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"{where}: {key} must be a number, got {value!r}") from exc
    if not np.isfinite(v):
        raise ScenarioError(f"{where}: {key} must be finite, got {value!r}")
    return v


def _tables(data: dict[str, Any], key: str, where: str) -> list[dict[str, Any]]:
    value = data.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise ScenarioError(f"{where}: {key} must be an array of tables ([[{key}]] entries), got {value!r}")
    return value


def scene_from_dict(data: dict[str, Any], where: str = "scene") -> Scene:
    """Scene from a parsed TOML mapping (see the module docstring for the keys)."""
    unknown = set(data) - _KEYS
    if unknown:
        raise ScenarioError(f"{where}: unknown keys {sorted(unknown)}; known: {sorted(_KEYS)}")
    bounds = tuple(_arr(data, "bounds", (4,), where))
    if bounds[2] <= bounds[0] or bounds[3] <= bounds[1]:
        raise ScenarioError(f"{where}: bounds must be xmin < xmax, ymin < ymax, got {bounds}")
    tables = []
    for i, t in enumerate(_tables(data, "tables", where)):
        w = f"{where} table {i}"
        c = _arr(t, "center", (2,), w)
        s = _arr(t, "size", (2,), w)
        if np.any(s <= 0):
            raise ScenarioError(f"{w}: size must be positive")
        rect = box(c[0] - s[0] / 2, c[1] - s[1] / 2, c[0] + s[0] / 2, c[1] + s[1] / 2)
        tables.append(affinity.rotate(rect, _num(t, "angle", 0.0, w), origin=(c[0], c[1])))
    obstacles, discs = [], []
    for i, o in enumerate(_tables(data, "obstacles", where)):
        w = f"{where} obstacle {i}"
        c = _arr(o, "center", (2,), w)
        r = _num(o, "radius", 0.0, w)
        if not r > 0:
            raise ScenarioError(f"{w}: radius must be positive, got {r}")
        obstacles.append(Point(c).buffer(r, quad_segs=16))
        discs.append([c[0], c[1], r])
    bases = _arr(data, "bases", (None, 2), where)
    headings = _arr(data, "headings", (len(bases),), where, default=np.zeros(len(bases)))
    external = _arr(data, "external", (3,), where, default=[1.0, 1.0, 1.0])
    if np.any(external < 0):
        raise ScenarioError(f"{where}: external must be 3 non-negative numbers [N], got {external.tolist()}")
    inter = data.get("intermediate", 1)
    if isinstance(inter, bool) or not isinstance(inter, int) or inter < 0:
        raise ScenarioError(f"{where}: intermediate must be a non-negative integer, got {inter!r}")
    lateral = _num(data, "lateral", 1.5, where)
    if lateral < 0:
        raise ScenarioError(f"{where}: lateral (max sideways shift of a way-point) must be >= 0 m, got {lateral}")
    name = data.get("name", Path(where).stem)
    if not isinstance(name, str):
        raise ScenarioError(f"{where}: name must be a string, got {name!r}")
    return Scene(
        name=name,
        bounds=bounds,  # type: ignore[arg-type]
        tables=tuple(tables),
        obstacles=tuple(obstacles),
        tasks=_arr(data, "tasks", (None, 3), where),
        bases=bases,
        headings=headings,
        external=external,
        intermediate=inter,
        lateral=lateral,
        discs=np.array(discs, dtype=float).reshape(-1, 3),
    )


def builtin_scenes() -> list[str]:
    """Names of the scenes shipped in ``tmr/mcdpr/scenes``."""
    files = resources.files("tmr.mcdpr").joinpath("scenes").iterdir()
    return sorted(f.name[:-5] for f in files if f.name.endswith(".toml"))


def load_scene(name_or_path: str | Path) -> Scene:
    """A shipped scene by name (``fig2``) or a scene TOML file; raises ScenarioError on bad input."""
    text: str
    where = str(name_or_path)
    if str(name_or_path) in builtin_scenes():
        text = resources.files("tmr.mcdpr").joinpath("scenes").joinpath(f"{name_or_path}.toml").read_text()
    else:
        path = Path(name_or_path)
        if not path.exists():
            raise ScenarioError(f"no scene {where!r}: not a built-in ({', '.join(builtin_scenes())}) nor a file")
        from tmr.files import read_text

        text = read_text(path, "scene TOML", ScenarioError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{where}: invalid TOML: {exc}") from exc
    return scene_from_dict(data, where)


def waypoints(scene: Scene, n_offsets: int = 61) -> NDArray[np.float64]:
    """Way-points (l, 3) [m]: task points with ``scene.intermediate`` points between each consecutive pair.

    Intermediate point k of the pair (a, b) starts at a + (b − a)·k/(n+1) and is shifted along the unit normal of
    a→b by the offset in [−lateral, lateral] (``n_offsets`` samples, vectorised shapely distance) that maximises its
    distance to the nearest raw obstacle or table while staying in the room; ties go to the smallest |offset|.
    Heights are interpolated linearly (Rasheed 2019 sec. 4).
    """
    raw = shapely.union_all(list(scene.tables) + list(scene.obstacles))
    x0, y0, x1, y1 = scene.bounds
    pts = [scene.tasks[0]]
    offsets = np.linspace(-scene.lateral, scene.lateral, n_offsets)
    order = np.argsort(np.abs(offsets), kind="stable")
    offsets = offsets[order]
    for a, b in zip(scene.tasks[:-1], scene.tasks[1:], strict=True):
        d = b[:2] - a[:2]
        L = np.linalg.norm(d)
        nrm = np.array([-d[1], d[0]]) / L if L > 0 else np.zeros(2)
        for k in range(1, scene.intermediate + 1):
            s = k / (scene.intermediate + 1)
            base = a + (b - a) * s
            cand = base[:2] + offsets[:, None] * nrm
            if raw.is_empty:
                dist = np.zeros(len(cand))
            else:
                dist = shapely.distance(raw, shapely.points(cand))
            wall = np.minimum.reduce([cand[:, 0] - x0, x1 - cand[:, 0], cand[:, 1] - y0, y1 - cand[:, 1]])
            dist = np.where(wall > 0, np.minimum(dist, wall), -np.inf)
            best = int(np.argmax(np.round(dist, 9)))
            pts.append(np.array([cand[best, 0], cand[best, 1], base[2]]))
        pts.append(b)
    return np.array(pts)
