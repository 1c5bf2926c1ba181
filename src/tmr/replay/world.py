"""The static world of a replay: floor, walls and obstacles extruded from the plan's polygons into convex prisms.

MuJoCo collides meshes through their convex hulls, so every obstacle polygon is split into convex pieces first:
a convex polygon (its area equals its hull's to 1e-9 relative) is one piece; any other polygon is cut into the
triangles of its constrained Delaunay triangulation (``shapely.constrained_delaunay_triangles``), each a convex
prism. Grid maps arrive here as the polygons of their occupied cells (``tmr.world.environment``). Prisms reach from the
floor to :data:`OBSTACLE_HEIGHT`, above every tether exit, so a tether can only pass round them.

Collision bits (``contype``/``conaffinity``, a pair collides if either's type meets the other's affinity):
floor 1/0, obstacles and walls 2/0, tether links 0/3 (floor and obstacles), robots 8/10 (obstacles and robots).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["OBSTACLE_HEIGHT", "convex_pieces", "world_xml"]

#: height of the extruded obstacles and walls [m] (documented choice: above the 0.43 m tether exits).
OBSTACLE_HEIGHT = 1.0
#: wall thickness outside the room bounds [m].
WALL_THICKNESS = 0.2

FLOOR_BITS = (1, 0)
OBSTACLE_BITS = (2, 0)
TETHER_BITS = (0, 3)
ROBOT_BITS = (8, 10)


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
