"""The static world of a replay: floor, walls and obstacles extruded from the plan's polygons into convex prisms.

MuJoCo collides meshes through their convex hulls, so every obstacle polygon is split into convex pieces first:
a convex polygon (its area equals its hull's to 1e-9 relative) is one piece; any other polygon is cut into the
triangles of its constrained Delaunay triangulation (``shapely.constrained_delaunay_triangles``), each a convex
prism. Grid maps arrive here as the polygons of their occupied cells (``tmr.world.environment``). Prisms reach from the
floor to :data:`OBSTACLE_HEIGHT`, above every tether exit, so a tether can only pass round them. A low obstacle
(run.json's ``map.low_obstacles``, :class:`tmr.world.environment.LowObstacle`) is extruded to its own height, geoms
named ``obs_low{o}_{k}`` (obstacles for the contact report), so a tether passing over it touches it only if it sags
that low (:func:`tmr.replay.chain.build_chain_model`).

Collision bits (``contype``/``conaffinity``, a pair collides if either's type meets the other's affinity):
floor 1/0, obstacles and walls 2/0, tether links 0/3 (floor and obstacles), robots 8/10 (obstacles and robots),
drones 8/11 (floor, obstacles and drones).

Drone worlds (:func:`world3d_xml`, the scenario's 3-D ``[world]`` table, ``formulations/drones.md``): boxes are box
geoms; a prism's footprint is split into the same convex pieces, each extruded between its z0 and z1; a mesh file is a
MuJoCo mesh geom, which MuJoCo collides through its **convex hull** (a non-convex mesh is conservative: a cable
in one of its concavities is reported as a contact); the room is the floor plane at zmin, four walls and a ceiling
outside the bounds.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["OBSTACLE_HEIGHT", "convex_pieces", "world3d_xml", "world_xml"]

#: height of the extruded obstacles and walls [m] (documented choice: above the 0.43 m tether exits).
OBSTACLE_HEIGHT = 1.0
#: wall thickness outside the room bounds [m].
WALL_THICKNESS = 0.2

FLOOR_BITS = (1, 0)
OBSTACLE_BITS = (2, 0)
TETHER_BITS = (0, 3)
ROBOT_BITS = (8, 10)
DRONE_BITS = (8, 11)
_SOFT = 'solref="0.01 1" solimp="0.99 0.9999 0.0005 0.5 2"'


def convex_pieces(polygons: list[Any]) -> list[np.ndarray]:
    """Convex pieces of the polygons, each an (k, 2) array of its vertices [m] (no repeated closing vertex)."""
    import shapely

    pieces: list[np.ndarray] = []
    for poly in polygons:
        if poly.is_empty or poly.area <= 0.0:
            continue
        hull = poly.convex_hull
        if not poly.interiors and abs(hull.area - poly.area) <= 1e-9 * max(hull.area, 1e-12):
            pieces.append(np.asarray(poly.exterior.coords)[:-1, :2])
            continue
        for tri in shapely.get_parts(shapely.constrained_delaunay_triangles(poly)):
            if tri.area > 1e-12:
                pieces.append(np.asarray(tri.exterior.coords)[:-1, :2])
    return pieces


def _fmt(values: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


def world_xml(
    polygons: list[Any],
    bounds: tuple[float, float, float, float],
    height: float = OBSTACLE_HEIGHT,
    *,
    prefix: str = "obs",
    floor_and_walls: bool = True,
) -> tuple[str, str, list[str]]:
    """(asset XML, worldbody XML, obstacle geom names) of the floor, the four walls round ``bounds`` (unless
    ``floor_and_walls`` is False) and the obstacles extruded to ``height`` [m], named ``{prefix}{k}``."""
    xmin, ymin, xmax, ymax = bounds
    cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
    hx, hy = 0.5 * (xmax - xmin), 0.5 * (ymax - ymin)
    w = WALL_THICKNESS
    ft, fa = FLOOR_BITS
    ot, oa = OBSTACLE_BITS
    assets = []
    body = [
        f'<geom name="floor" type="plane" pos="{cx!r} {cy!r} 0" size="{hx + 2 * w!r} {hy + 2 * w!r} 0.1" '
        f'contype="{ft}" conaffinity="{fa}" rgba="0.85 0.85 0.82 1" solref="0.01 1" solimp="0.99 0.9999 0.0005 0.5 2"/>'
    ]
    names = []
    walls = [
        ("wall_s", cx, ymin - w / 2, hx + w, w / 2),
        ("wall_n", cx, ymax + w / 2, hx + w, w / 2),
        ("wall_w", xmin - w / 2, cy, w / 2, hy + w),
        ("wall_e", xmax + w / 2, cy, w / 2, hy + w),
    ]
    if not floor_and_walls:
        body, walls = [], []
    for name, x, y, sx, sy in walls:
        body.append(
            f'<geom name="{name}" type="box" pos="{x!r} {y!r} {height / 2!r}" size="{sx!r} {sy!r} {height / 2!r}" '
            f'contype="{ot}" conaffinity="{oa}" rgba="0.6 0.6 0.62 0.3" group="2"/>'
        )
        names.append(name)
    for k, piece in enumerate(convex_pieces(polygons)):
        k_ = len(piece)
        verts = np.vstack([np.column_stack([piece, np.zeros(k_)]), np.column_stack([piece, np.full(k_, height)])])
        assets.append(f'<mesh name="{prefix}{k}" vertex="{_fmt(verts)}"/>')
        body.append(
            f'<geom name="{prefix}{k}" type="mesh" mesh="{prefix}{k}" contype="{ot}" conaffinity="{oa}" '
            f'rgba="0.45 0.47 0.5 1" solref="0.01 1" solimp="0.99 0.9999 0.0005 0.5 2"/>'
        )
        names.append(f"{prefix}{k}")
    return "".join(assets), "".join(body), names


def _prism_pieces(piece: np.ndarray, z0: float, z1: float) -> np.ndarray:
    k_ = len(piece)
    return np.vstack([np.column_stack([piece, np.full(k_, z0)]), np.column_stack([piece, np.full(k_, z1)])])


def world3d_xml(table: Any, base: Any, *, prefix: str = "obs") -> tuple[str, str, list[str]]:
    """(asset XML, worldbody XML, obstacle and wall geom names) of a drone world's ``[world]`` table (validated
    before by :func:`tmr.world.world3d.world3d_from_table`; mesh paths relative to ``base``): floor plane at zmin,
    four walls and a ceiling 0.2 m thick outside the bounds, and every obstacle (module docstring). Units: m."""
    from pathlib import Path

    from shapely.geometry import Polygon

    xmin, ymin, zmin, xmax, ymax, zmax = (float(v) for v in table["bounds"])
    cx, cy, cz = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax), 0.5 * (zmin + zmax)
    hx, hy, hz = 0.5 * (xmax - xmin), 0.5 * (ymax - ymin), 0.5 * (zmax - zmin)
    w = WALL_THICKNESS
    ft, fa = FLOOR_BITS
    ot, oa = OBSTACLE_BITS
    assets: list[str] = []
    body = [
        f'<geom name="floor" type="plane" pos="{cx!r} {cy!r} {zmin!r}" size="{hx + 2 * w!r} {hy + 2 * w!r} 0.1" '
        f'contype="{ft}" conaffinity="{fa}" rgba="0.85 0.85 0.82 1" {_SOFT}/>'
    ]
    names: list[str] = []
    walls = [
        ("wall_s", (cx, ymin - w / 2, cz), (hx + w, w / 2, hz)),
        ("wall_n", (cx, ymax + w / 2, cz), (hx + w, w / 2, hz)),
        ("wall_w", (xmin - w / 2, cy, cz), (w / 2, hy + w, hz)),
        ("wall_e", (xmax + w / 2, cy, cz), (w / 2, hy + w, hz)),
        ("wall_ceiling", (cx, cy, zmax + w / 2), (hx + w, hy + w, w / 2)),
    ]
    for name, pos, size in walls:
        body.append(
            f'<geom name="{name}" type="box" pos="{_fmt(np.array(pos))}" size="{_fmt(np.array(size))}" '
            f'contype="{ot}" conaffinity="{oa}" rgba="0.6 0.6 0.62 0.15" group="2" {_SOFT}/>'
        )
        names.append(name)
    geom = f'contype="{ot}" conaffinity="{oa}" rgba="0.45 0.47 0.5 1" {_SOFT}'
    for k, item in enumerate(table.get("obstacles") or []):
        if "box" in item:
            c = np.asarray(item["box"], dtype=float)
            body.append(
                f'<geom name="{prefix}{k}" type="box" pos="{_fmt(0.5 * (c[:3] + c[3:]))}" '
                f'size="{_fmt(0.5 * (c[3:] - c[:3]))}" {geom}/>'
            )
            names.append(f"{prefix}{k}")
        elif "prism" in item:
            z0, z1 = (float(v) for v in item["z"])
            for i, piece in enumerate(convex_pieces([Polygon(np.asarray(item["prism"], dtype=float))])):
                name = f"{prefix}{k}_{i}"
                assets.append(f'<mesh name="{name}" vertex="{_fmt(_prism_pieces(piece, z0, z1))}"/>')
                body.append(f'<geom name="{name}" type="mesh" mesh="{name}" {geom}/>')
                names.append(name)
        else:
            import trimesh

            mesh = trimesh.load(Path(base) / item["mesh"], force="mesh")
            name = f"{prefix}{k}"
            assets.append(
                f'<mesh name="{name}" vertex="{_fmt(np.asarray(mesh.vertices))}" '
                f'face="{" ".join(str(int(i)) for i in np.ravel(mesh.faces))}"/>'
            )
            body.append(f'<geom name="{name}" type="mesh" mesh="{name}" {geom}/>')
            names.append(name)
    return "".join(assets), "".join(body), names
