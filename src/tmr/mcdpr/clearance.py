"""Exact clearance of MoPICK bases against the scene's true shapes: rectangles (tables), exact circles (disc
obstacles, not their inscribed polygons) and the room walls (Rasheed 2019 sec. 4; the base is a disc of radius r_mb).

A base centre is free when its distance to every table and wall is > r_mb and to every disc centre > r_o + r_mb.
For a straight drive the same holds with the segment's distance (shapely for the rectangles, closed-form
point-segment distance for the circles, the end points for the convex room).
"""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray

from tmr.mcdpr.scene import Scene

__all__ = ["point_clearance", "segment_clearance"]


def _walls(scene: Scene, pts: NDArray[np.float64]) -> NDArray[np.float64]:
    x0, y0, x1, y1 = scene.bounds
    return np.minimum.reduce([pts[..., 0] - x0, x1 - pts[..., 0], pts[..., 1] - y0, y1 - pts[..., 1]])


def point_clearance(scene: Scene, radius: float, points: ArrayLike) -> NDArray[np.float64]:
    """Clearance [m] of base discs of ``radius`` [m] centred at points (..., 2): distance to the nearest table,
    exact circle or wall minus the radius (> 0 free). Shape (...)."""
    pts = np.asarray(points, dtype=float)
    flat = pts.reshape(-1, 2)
    d = _walls(scene, flat)
    if len(scene.tables) and len(flat):
        geo = shapely.points(flat)
        for t in scene.tables:
            d = np.minimum(d, shapely.distance(geo, t))
    for cx, cy, r in scene.discs:
        d = np.minimum(d, np.hypot(flat[:, 0] - cx, flat[:, 1] - cy) - r)
    return (d - radius).reshape(pts.shape[:-1])


def segment_clearance(scene: Scene, radius: float, a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Clearance [m] of a base disc of ``radius`` [m] driving straight from a to b (both (..., 2)): the smallest
    distance of the segment to a table, an exact circle or a wall, minus the radius (> 0: the whole drive is
    free). Shape (...)."""
    A, B = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    shape = A.shape[:-1]
    fa, fb = A.reshape(-1, 2), B.reshape(-1, 2)
    d = np.minimum(_walls(scene, fa), _walls(scene, fb))  # the room is convex: the end points are the worst
    if len(scene.tables) and len(fa):
        same = np.all(fa == fb, axis=1)
        geo = np.where(same, shapely.points(fa), shapely.linestrings(np.stack([fa, fb], axis=1)))
        for t in scene.tables:
            d = np.minimum(d, shapely.distance(geo, t))
    v = fb - fa
    vv = np.einsum("ni,ni->n", v, v)
    for cx, cy, r in scene.discs:
        w = np.array([cx, cy]) - fa
        s = np.clip(np.einsum("ni,ni->n", w, v) / np.where(vv > 0, vv, 1.0), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(w - s[:, None] * v, axis=1) - r)
    return (d - radius).reshape(shape)
