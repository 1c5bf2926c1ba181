"""Seeded 3-D worlds for the tethered-drone benchmark (``benchmarks/drones.py``, issue 32).

Each world is a drone scenario in the format of ``tmr plan --scenario X.toml`` (``kind = "drone"``): a room
10–30 m × 10–30 m, 4–8 m high, with box and vertical-prism obstacles, the ground winch ``base`` (z =
:data:`BASE_Z`), the leader's ``goal``, and a ``[tether]`` table whose ``tether_length`` (6–14 m, against the
default 20 m of :class:`tmr.model.catenary3d.DroneTetherParams`) makes the number of drones matter: corner-to-corner
routes of 12–45 m need 1–8 drones. Everything comes from ``numpy.random.default_rng([seed, index])``, so world
``index`` of seed ``seed`` is the same dict and the same TOML bytes on every machine, whatever other worlds are made.

Families (``index % 4``, so every family holds a quarter of any run of consecutive indices):

* ``pillars`` — 4–16 pillars of mixed heights (boxes and octagonal prisms; half reach the ceiling, the others stop
  1–H−1 m high, so some routes go over them), base near one corner, goal near the opposite one;
* ``window`` — a wall across the room, floor to ceiling, with one rectangular window 1.5–3 m wide and 1.2–2 m high
  (sill 0.5 m … H − 0.5 m), plus 0–3 pillars; base on one side, goal on the other. In every
  :data:`CLOSED_EVERY`-th of them (``index // 4 ≡ 4 mod 5``) the window is 0.3–0.5 m high, less than a drone's
  diameter 2r = 0.6 m: the goal is unreachable (a refusal test);
* ``low_wall`` — a wall across the room 1 m … H − 2 m high to pass over (the tethers' sag must clear its top), plus
  0–2 pillars, goal low behind it; in every :data:`CLOSED_EVERY`-th of them the wall stops 0.3–0.5 m below the ceiling
  (unreachable);
* ``warehouse`` — rows of shelves (boxes 0.8–1.2 m deep, 2 m … H − 1 m high, or to the ceiling in 40 % of the
  warehouses) along x with aisles 1.6–3 m wide, cross-aisles ≥ 2.5 m at both ends and sometimes one in the middle;
  base at an aisle's end, goal in another aisle.

Every coordinate is rounded to the millimetre before any check, so the TOML text describes exactly the world that
was checked. Base and goal are checked with :func:`tmr.world.world3d.world3d_from_table` (the scenario loader's
world) at the drone radius r = :data:`DRONE_RADIUS`: the goal keeps a clearance ≥ :data:`GOAL_CLEARANCE` from the
obstacles, walls, floor and ceiling grown by r, the base (a winch at z = 0.4 m, 0.1 m above a drone's radius from
the floor) ≥ :data:`BASE_CLEARANCE`; pillars and walls keep :data:`BASE_KEEP` (horizontally) from both (shelves:
base and goal are in the middle of an aisle ≥ 1.6 m wide).

Reachability is known by construction (:attr:`DroneWorld.reachable`) and verified independently of coal and of the
route planner by :func:`voxel_reachable`: a flood fill of the voxels whose centres are farther than r from every
obstacle (exact box and prism distances in numpy/shapely) and inside the room shrunk by r.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy import ndimage
from shapely.geometry import Polygon

from tmr.world.world3d import World3D, world3d_from_table

__all__ = [
    "BASE_CLEARANCE",
    "BASE_Z",
    "CLOSABLE",
    "CLOSED_EVERY",
    "DRONE_RADIUS",
    "FAMILIES",
    "GOAL_CLEARANCE",
    "DroneWorld",
    "drone_world",
    "drone_worlds",
    "scenario_toml",
    "voxel_reachable",
]

FAMILIES = ("pillars", "window", "low_wall", "warehouse")
DRONE_RADIUS = 0.3  # m, r: DroneTetherParams.drone_radius, the world's safety_radius
BASE_Z = 0.4  # m, height of the ground winch (the anchor)
BASE_CLEARANCE = 0.1  # m, clearance of the base beyond r (the floor is 0.1 m below a drone sphere there)
GOAL_CLEARANCE = 0.3  # m, clearance of the goal beyond r
BASE_KEEP = 2.0  # m, no obstacle footprint within this horizontal distance of the base or the goal
PILLAR_GAP = 1.2  # m, footprints of two pillars keep this gap (2r and two tether clearances)
ROOM_SIDE = (10.0, 30.0)  # m
ROOM_HEIGHT = (4.0, 8.0)  # m
TETHER_LENGTH = (6.0, 14.0)  # m, [tether] tether_length, one per world
CLOSABLE = ("window", "low_wall")
CLOSED_EVERY = 5  # every 5th window and low-wall world (index // 4 = 4, 9, 14, ...) has its passage closed
VOXEL = 0.2  # m, cell of voxel_reachable


def _r(v: float) -> float:
    """Round to the millimetre (a plain float, so the TOML text is exact)."""
    return float(round(float(v), 3)) + 0.0


@dataclass(frozen=True)
class DroneWorld:
    """One generated world.

    Attributes:
        seed, index: what made it (``default_rng([seed, index])``).
        family: one of :data:`FAMILIES`.
        name: ``"<family>-<seed>-<index>"`` (also the scenario's ``name``).
        scenario: the scenario as a TOML-able dict (keys name, kind, description, robots, base, goal, world, tether).
        reachable: whether the goal is reachable by a drone of radius r from the base (by construction).
        notes: what the generator chose (room, passage sizes, tether length), for the tables.
    """

    seed: int
    index: int
    family: str
    name: str
    scenario: dict[str, Any]
    reachable: bool
    notes: dict[str, Any] = field(default_factory=dict)

    @property
    def toml(self) -> str:
        """The scenario's TOML text (:func:`scenario_toml`)."""
        return scenario_toml(self.scenario)

    @property
    def base(self) -> NDArray[np.float64]:
        """The anchor (ground winch) (3,) [m]."""
        return np.asarray(self.scenario["base"], dtype=float)

    @property
    def goal(self) -> NDArray[np.float64]:
        """The leader's goal (3,) [m]."""
        return np.asarray(self.scenario["goal"], dtype=float)

    @property
    def tether_length(self) -> float:
        """The world's L_max [m] (``[tether] tether_length``)."""
        return float(self.scenario["tether"]["tether_length"])

    def world(self) -> World3D:
        """The :class:`World3D` the scenario loader builds from the ``[world]`` table (r = the drone radius)."""
        return world3d_from_table(self.scenario["world"])

    def write(self, folder: str | Path) -> Path:
        """Write ``<folder>/<name>.toml`` [UTF-8, LF] and return its path."""
        path = Path(folder) / f"{self.name}.toml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(self.toml.encode("utf-8"))
        return path


# -- TOML ------------------------------------------------------------------------------------------------------
def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        f = float(v)
        if not math.isfinite(f):
            raise ValueError(f"TOML has no {f!r} here")
        return repr(f)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, Sequence):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def _scalars(table: Mapping[str, Any]) -> list[str]:
    return [f"{k} = {_value(v)}" for k, v in table.items() if not isinstance(v, Mapping) and not _is_tables(v)]


def _is_tables(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(isinstance(x, Mapping) for x in v)


def scenario_toml(scenario: Mapping[str, Any]) -> str:
    """The TOML text of a drone scenario dict: top-level keys, then ``[world]`` with its ``[[world.obstacles]]``,
    then the other tables (``[tether]``, ``[params]``). Floats are written with ``repr`` (exact round trip through
    ``tomllib``). Only what scenarios hold: numbers, strings, booleans, lists of them, tables, lists of tables."""
    lines = _scalars(scenario)
    for key, sub in scenario.items():
        if not isinstance(sub, Mapping):
            continue
        lines += ["", f"[{key}]", *_scalars(sub)]
        for k, v in sub.items():
            if _is_tables(v):
                for item in v:
                    lines += ["", f"[[{key}.{k}]]", *_scalars(item)]
    return "\n".join(lines) + "\n"


# -- obstacles ---------------------------------------------------------------------------------------------------
def _box(lo: Sequence[float], hi: Sequence[float]) -> dict[str, Any]:
    return {"box": [_r(v) for v in (*lo, *hi)]}


def _octagon(cx: float, cy: float, radius: float) -> list[list[float]]:
    angles = np.arange(8) * (math.pi / 4) + math.pi / 8
    return [[_r(cx + radius * math.cos(a)), _r(cy + radius * math.sin(a))] for a in angles]


def _footprint(ob: Mapping[str, Any]) -> Polygon:
    if "box" in ob:
        b = ob["box"]
        return shapely.box(b[0], b[1], b[3], b[4])
    return Polygon(ob["prism"])


def _z_range(ob: Mapping[str, Any]) -> tuple[float, float]:
    if "box" in ob:
        return float(ob["box"][2]), float(ob["box"][5])
    return float(ob["z"][0]), float(ob["z"][1])


def _pillars(
    rng: np.random.Generator,
    count: int,
    size: tuple[float, float, float],
    keep_clear: Sequence[NDArray[np.float64]],
    others: list[dict[str, Any]],
    region: tuple[float, float, float, float],
) -> list[dict[str, Any]]:
    """Up to ``count`` pillars of mixed heights in ``region`` (x0, y0, x1, y1), footprints ≥ PILLAR_GAP from each
    other and from ``others``, ≥ BASE_KEEP from every point of ``keep_clear``; half of them reach the ceiling."""
    w, d, h = size
    out: list[dict[str, Any]] = []
    placed = [_footprint(o) for o in others]
    for _ in range(40 * count):
        if len(out) == count:
            break
        cx, cy = rng.uniform(region[0], region[2]), rng.uniform(region[1], region[3])
        top = h if rng.random() < 0.5 else _r(rng.uniform(1.0, h - 1.0))
        if rng.random() < 0.5:
            sx, sy = rng.uniform(0.4, 1.4, size=2)
            ob = _box((cx - sx / 2, cy - sy / 2, 0.0), (cx + sx / 2, cy + sy / 2, top))
        else:
            ob = {"prism": _octagon(cx, cy, rng.uniform(0.25, 0.8)), "z": [0.0, _r(top)]}
        fp = _footprint(ob)
        lo_x, lo_y, hi_x, hi_y = fp.bounds
        if lo_x < 0.0 or lo_y < 0.0 or hi_x > w or hi_y > d:
            continue
        if any(fp.distance(shapely.Point(p[0], p[1])) < BASE_KEEP for p in keep_clear):
            continue
        if any(fp.distance(q) < PILLAR_GAP for q in placed):
            continue
        out.append(ob)
        placed.append(fp)
    return out


# -- families ----------------------------------------------------------------------------------------------------
def _room(rng: np.random.Generator) -> tuple[float, float, float]:
    w, d = (_r(v) for v in rng.uniform(*ROOM_SIDE, size=2))
    h = _r(rng.uniform(*ROOM_HEIGHT))
    return w, d, h


def _goal_z(rng: np.random.Generator, h: float, lo: float = 1.0, hi: float | None = None) -> float:
    return _r(rng.uniform(lo, (h - 1.0) if hi is None else min(hi, h - 1.0)))


def _family_pillars(rng: np.random.Generator, closed: bool) -> tuple[tuple[float, float, float], dict[str, Any]]:
    w, d, h = _room(rng)
    base = np.array([_r(rng.uniform(1.0, 3.0)), _r(rng.uniform(1.0, 3.0)), BASE_Z])
    goal = np.array([_r(w - rng.uniform(1.0, 3.0)), _r(d - rng.uniform(1.0, 3.0)), _goal_z(rng, h)])
    count = int(np.clip(round(w * d / rng.uniform(25.0, 60.0)), 4, 16))
    obstacles = _pillars(rng, count, (w, d, h), [base, goal], [], (1.0, 1.0, w - 1.0, d - 1.0))
    return (w, d, h), {"base": base, "goal": goal, "obstacles": obstacles, "reachable": True, "pillars": count}


def _cross_wall(
    rng: np.random.Generator, w: float, d: float
) -> tuple[float, float, NDArray[np.float64], NDArray[np.float64]]:
    """x and thickness of a wall across the room (y = 0 … d), and a base before it and a goal's (x, y) after it."""
    xw = _r(rng.uniform(0.35 * w, 0.65 * w))
    t = _r(rng.uniform(0.2, 0.4))
    base = np.array([_r(rng.uniform(1.0, xw - BASE_KEEP - 0.5)), _r(rng.uniform(1.0, d - 1.0)), BASE_Z])
    goal_xy = np.array([_r(rng.uniform(xw + t + BASE_KEEP + 0.5, w - 1.0)), _r(rng.uniform(1.0, d - 1.0))])
    return xw, t, base, goal_xy


def _family_window(rng: np.random.Generator, closed: bool) -> tuple[tuple[float, float, float], dict[str, Any]]:
    w, d, h = _room(rng)
    xw, t, base, goal_xy = _cross_wall(rng, w, d)
    width = _r(rng.uniform(1.5, 3.0))
    height = _r(rng.uniform(0.3, 0.5) if closed else rng.uniform(1.2, 2.0))
    sill = _r(rng.uniform(0.5, h - height - 0.5))
    y0 = _r(rng.uniform(0.5, d - width - 0.5))
    y1 = _r(y0 + width)
    x0, x1 = xw, _r(xw + t)
    wall = [
        _box((x0, 0.0, 0.0), (x1, d, sill)),
        _box((x0, 0.0, _r(sill + height)), (x1, d, h)),
        _box((x0, 0.0, sill), (x1, y0, _r(sill + height))),
        _box((x0, y1, sill), (x1, d, _r(sill + height))),
    ]
    goal = np.array([goal_xy[0], goal_xy[1], _goal_z(rng, h)])
    extra = _pillars(rng, int(rng.integers(0, 4)), (w, d, h), [base, goal], wall, (1.0, 1.0, w - 1.0, d - 1.0))
    window = {"window": [x0, y0, sill, x1, y1, _r(sill + height)], "closed": closed}
    return (w, d, h), {"base": base, "goal": goal, "obstacles": wall + extra, "reachable": not closed, **window}


def _family_low_wall(rng: np.random.Generator, closed: bool) -> tuple[tuple[float, float, float], dict[str, Any]]:
    w, d, h = _room(rng)
    xw, t, base, goal_xy = _cross_wall(rng, w, d)
    top = _r(h - rng.uniform(0.3, 0.5) if closed else rng.uniform(1.0, h - 2.0))
    wall = [_box((xw, 0.0, 0.0), (_r(xw + t), d, top))]
    goal = np.array([goal_xy[0], goal_xy[1], _goal_z(rng, h, 0.8, 2.5)])
    extra = _pillars(rng, int(rng.integers(0, 3)), (w, d, h), [base, goal], wall, (1.0, 1.0, w - 1.0, d - 1.0))
    info = {"wall_top": top, "closed": closed}
    return (w, d, h), {"base": base, "goal": goal, "obstacles": wall + extra, "reachable": not closed, **info}


def _family_warehouse(rng: np.random.Generator, closed: bool) -> tuple[tuple[float, float, float], dict[str, Any]]:
    w, d, h = _room(rng)
    to_ceiling = rng.random() < 0.4
    shelf_h = h if to_ceiling else _r(rng.uniform(2.0, h - 1.0))
    depth, aisle = _r(rng.uniform(0.8, 1.2)), _r(rng.uniform(1.6, 3.0))
    end = _r(rng.uniform(2.5, 3.5))  # cross-aisles at both ends
    middle = rng.random() < 0.5 and w - 2 * end > 8.0
    gap = (_r(w / 2 - 1.0), _r(w / 2 + 1.0)) if middle else None
    rows: list[float] = []
    y = _r(aisle)
    while y + depth <= d - aisle:
        rows.append(y)
        y = _r(y + depth + aisle)
    shelves = []
    for y0 in rows:
        spans = [(end, gap[0]), (gap[1], w - end)] if gap else [(end, w - end)]
        for xa, xb in spans:
            shelves.append(_box((xa, y0, 0.0), (xb, _r(y0 + depth), shelf_h)))
    # aisles: the free bands between rows (and before the first / after the last)
    edges = [0.0, *[v for y0 in rows for v in (y0, y0 + depth)], d]
    aisles = [(edges[i], edges[i + 1]) for i in range(0, len(edges), 2)]
    a0 = aisles[0]
    a1 = aisles[-1] if len(aisles) > 1 else aisles[0]
    if len(aisles) > 2:
        a1 = aisles[int(rng.integers(len(aisles) // 2, len(aisles)))]
    base = np.array([_r(rng.uniform(0.8, end - 0.8)), _r((a0[0] + a0[1]) / 2), BASE_Z])
    goal = np.array([_r(rng.uniform(0.3 * w, 0.7 * w)), _r((a1[0] + a1[1]) / 2), _goal_z(rng, h, 1.0, shelf_h)])
    info = {"shelf_height": shelf_h, "aisle": aisle, "rows": len(rows), "cross_aisle": bool(middle)}
    return (w, d, h), {"base": base, "goal": goal, "obstacles": shelves, "reachable": True, **info}


_MAKERS = {
    "pillars": _family_pillars,
    "window": _family_window,
    "low_wall": _family_low_wall,
    "warehouse": _family_warehouse,
}

_DESCRIPTIONS = {
    "pillars": "pillars of mixed heights, corner to corner",
    "window": "through a window in a wall",
    "low_wall": "over a low wall",
    "warehouse": "between warehouse shelves",
}


def _free_enough(table: Mapping[str, Any], base: NDArray[np.float64], goal: NDArray[np.float64]) -> bool:
    world = world3d_from_table(table)
    c = world.clearance(np.vstack([base, goal]))
    return bool(c[0] >= BASE_CLEARANCE - 1e-9 and c[1] >= GOAL_CLEARANCE - 1e-9)


def drone_world(seed: int, index: int) -> DroneWorld:
    """World ``index`` (≥ 0) of seed ``seed``: family ``FAMILIES[index % 4]``, drawn from
    ``default_rng([seed, index])`` (retried with the same generator until base and goal are free enough)."""
    if index < 0 or seed < 0:
        raise ValueError(f"seed and index must be >= 0, got seed={seed}, index={index}")
    family = FAMILIES[index % len(FAMILIES)]
    rng = np.random.default_rng([seed, index])
    closed = family in CLOSABLE and (index // len(FAMILIES)) % CLOSED_EVERY == CLOSED_EVERY - 1
    for _ in range(100):
        (w, d, h), spec = _MAKERS[family](rng, closed)
        table = {"bounds": [0.0, 0.0, 0.0, w, d, h], "safety_radius": DRONE_RADIUS, "obstacles": spec["obstacles"]}
        base, goal = spec["base"], spec["goal"]
        if _free_enough(table, base, goal):
            break
    else:  # pragma: no cover - the families leave room for base and goal by construction
        raise RuntimeError(f"world {index} of seed {seed}: no free base/goal after 100 draws")
    tether_length = _r(rng.uniform(*TETHER_LENGTH))
    name = f"{family}-{seed}-{index}"
    scenario: dict[str, Any] = {
        "name": name,
        "kind": "drone",
        "description": f"generated world {index} (seed {seed}): {_DESCRIPTIONS[family]}, {w:g} x {d:g} x {h:g} m",
        "robots": 3,
        "base": [float(v) for v in base],
        "goal": [float(v) for v in goal],
        "world": table,
        "tether": {"tether_length": tether_length},
    }
    notes = {k: v for k, v in spec.items() if k not in ("base", "goal", "obstacles", "reachable")}
    notes.update(room=[w, d, h], tether_length=tether_length, obstacles=len(table["obstacles"]))
    return DroneWorld(seed, index, family, name, scenario, bool(spec["reachable"]), notes)


def drone_worlds(n: int = 100, seed: int = 0) -> list[DroneWorld]:
    """Worlds 0 … n−1 of ``seed`` (each family ⌈n/4⌉ or ⌊n/4⌋ times)."""
    return [drone_world(seed, i) for i in range(n)]


# -- independent reachability ------------------------------------------------------------------------------------
def _obstacle_distance(
    ob: Mapping[str, Any], xy: NDArray[np.float64], shape2: tuple[int, int], z: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Exact distance [m] of the voxel centres to one box or vertical prism, (nx, ny, nz): the obstacle is a
    footprint × a z range, so the distance is sqrt(d_xy² + d_z²) with d_xy the planar distance to the footprint
    (shapely; 0 inside) and d_z the distance to the z range (0 inside); 0 inside the obstacle."""
    dxy = shapely.distance(_footprint(ob), shapely.points(xy)).reshape(shape2)
    z0, z1 = _z_range(ob)
    dz = np.maximum(0.0, np.maximum(z0 - z, z - z1))
    return np.sqrt(dxy[:, :, None] ** 2 + dz[None, None, :] ** 2)


def voxel_reachable(
    table: Mapping[str, Any],
    base: Sequence[float],
    goal: Sequence[float],
    radius: float = DRONE_RADIUS,
    cell: float = VOXEL,
) -> bool:
    """Whether ``goal`` is reachable from ``base`` for a sphere of ``radius`` [m] in the world ``table`` (boxes and
    prisms only): a 6-connected flood fill (``scipy.ndimage.label``) of the voxels of side ``cell`` [m] whose
    centres are farther than ``radius`` from every obstacle and from the room's faces. Base and goal join the voxel
    nearest to them among the free ones within one cell. Independent of coal and of the route planner; a
    resolution-limited verdict (a passage narrower than ``cell`` beyond 2r may be missed), used to cross-check the
    generator's construction, whose passages are ≥ 0.6 m wider than 2r or ≥ 0.1 m narrower."""
    b = np.asarray(table["bounds"], dtype=float)
    axes = [np.arange(b[i] + cell / 2, b[i + 3], cell) for i in range(3)]
    gx, gy = np.meshgrid(axes[0], axes[1], indexing="ij")
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    wall_xy = np.minimum.reduce([gx - b[0], gy - b[1], b[3] - gx, b[4] - gy])
    wall_z = np.minimum(axes[2] - b[2], b[5] - axes[2])
    dist = np.minimum(wall_xy[:, :, None], wall_z[None, None, :])
    for ob in table.get("obstacles", []):
        dist = np.minimum(dist, _obstacle_distance(ob, xy, gx.shape, axes[2]))
    free = dist > radius
    labels, _ = ndimage.label(free)

    def label_of(p: Sequence[float]) -> int:
        idx = [int(np.clip(round((p[i] - b[i]) / cell - 0.5), 0, len(axes[i]) - 1)) for i in range(3)]
        best, best_d = 0, math.inf
        for off in np.ndindex(3, 3, 3):
            j = [idx[i] + off[i] - 1 for i in range(3)]
            if any(j[i] < 0 or j[i] >= len(axes[i]) for i in range(3)):
                continue
            if labels[j[0], j[1], j[2]] == 0:
                continue
            dd = sum((axes[i][j[i]] - p[i]) ** 2 for i in range(3))
            if dd < best_d:
                best, best_d = int(labels[j[0], j[1], j[2]]), dd
        return best

    lb, lg = label_of(base), label_of(goal)
    return lb != 0 and lb == lg
