"""Planar environments: obstacles, inflation by the robot safety radius and clearance queries.

The world is an axis-aligned rectangular room ``bounds = (xmin, ymin, xmax, ymax)`` [m]; everything outside it
is an obstacle (the walls). Obstacles are shapely geometries. A robot is a disc of radius ``safety_radius`` r
[m], so every obstacle is grown by r and the walls are grown inward by r (Caruso 2021 §5: "the obstacles are
grown in size accordingly"). The **free space** is what is left of the room; the **clearance** of a point is
its signed distance [m] to the inflated obstacles: > 0 free, 0 on the boundary, < 0 inside (minus the distance
to the free space).

Two kinds of query:

* grid queries (fast, vectorised, differentiable): :meth:`Environment.clearance` and
  :meth:`Environment.clearance_and_gradient` look up a signed distance field sampled on a grid of cell size
  ``resolution`` (bilinear interpolation). The field is built once with scipy's Euclidean distance transform
  (feature transform to the boundary cells) refined with the exact distance to the nearest boundary segments,
  and its gradient with ``np.gradient``. This is the "distance field and its gradient" the controller of
  Caruso 2021 §4.2 (Figure 4) consumes for the obstacle-avoidance task (eq. 16-18).
* exact queries (shapely/GEOS): :meth:`Environment.exact_clearance`, :meth:`Environment.segment_clearance` and
  :meth:`Environment.is_free`, used for validity checks (path planner, metrics).

**Low obstacles** (a step, a cable tray: :class:`LowObstacle`, a footprint and a height [m]) are obstacles for the
robots -- every query above includes them exactly like the tall ones, a robot cannot drive over them -- but a tether
may pass over them. :attr:`Environment.tether_environment` is the same room without them (the world of the tethers'
plan-view chords); :meth:`Environment.low_obstacle_distance` measures the plan-view distance to each bare footprint.
Whether a cable actually clears a low obstacle is a question of its height there (the per-step QP and the checker
of :mod:`tmr.checks.metrics` answer it with the catenary).

Map files (ROS ``map_server``/Nav2, GeoJSON, WKT) are turned into geometry by :mod:`tmr.world.maps`
(:func:`tmr.world.maps.load_environment`); occupancy-grid maps are **polygonised** there (occupied and unknown cells
become unions of boxes), so every query works the same for every map source.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from shapely.geometry import box
from shapely.geometry.base import BaseGeometry

from tmr.errors import MapError, ParameterError

__all__ = [
    "DEFAULT_RESOLUTION",
    "DEFAULT_SAFETY_RADIUS",
    "Bounds",
    "Environment",
    "LowObstacle",
    "bilinear_interpolate",
    "check_bounds",
    "check_geometry",
    "refuse_low_obstacles",
]

Bounds = tuple[float, float, float, float]

DEFAULT_SAFETY_RADIUS = 0.5  # m, Caruso 2021 §5 (obstacles grown by the robot size)
DEFAULT_RESOLUTION = 0.05  # m, cell of the distance field
QUAD_SEGS = 16  # segments per quarter circle when buffering (chord error r(1 - cos(pi/64)) = 0.06 % of r)
# grid cells added around the room (all occupied) so that the field is defined just outside the walls
_PAD_CELLS = 4
# refuse grids bigger than this (e.g. 200 m x 200 m at 5 cm); building the field needs ~60 bytes per cell
_MAX_CELLS = 16_000_000


# ------------------------------------------------------------------------------------------------------------
# small helpers
# ------------------------------------------------------------------------------------------------------------
def _as_points(points: ArrayLike, what: str = "points") -> NDArray[np.float64]:
    """``points`` as a float array of shape (..., 2); ParameterError on a wrong shape or NaN/inf."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim == 0 or pts.shape[-1] != 2:
        raise ParameterError(f"{what} must have shape (..., 2) (x, y in metres), got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ParameterError(f"{what} contain NaN or inf: {pts[~np.isfinite(pts).all(axis=-1)][:3].tolist()} ...")
    return pts


def check_bounds(bounds: Any, where: str) -> Bounds:
    try:
        values = [float(v) for v in bounds]
    except (TypeError, ValueError):
        raise MapError(
            f"{where}: bounds must be 4 numbers [xmin, ymin, xmax, ymax] in metres, got {bounds!r}"
        ) from None
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise MapError(f"{where}: bounds must be 4 finite numbers [xmin, ymin, xmax, ymax] in metres, got {bounds!r}")
    xmin, ymin, xmax, ymax = values
    if not (xmax > xmin and ymax > ymin):
        raise MapError(f"{where}: empty room: bounds {tuple(values)} need xmax > xmin and ymax > ymin")
    return (xmin, ymin, xmax, ymax)


def _check_positive(value: Any, name: str, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ParameterError(f"{name} must be a finite {'non-negative' if allow_zero else 'positive'} number, got {v}")
    return v


def _polygonal_parts(geom: BaseGeometry) -> BaseGeometry:
    """Keep only the polygons of ``geom`` (set operations may leave stray zero-area lines or points)."""
    parts = [g for g in shapely.get_parts(geom) if isinstance(g, shapely.Polygon) and not g.is_empty]
    if not parts:
        return shapely.Polygon()
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def bilinear_interpolate(
    values: ArrayLike, origin: tuple[float, float], resolution: float, points: ArrayLike
) -> NDArray[np.float64]:
    """Bilinear interpolation of grid samples at arbitrary points, vectorised (no Python loop over points).

    ``values[i, j, ...]`` is the sample at ``(origin[0] + i * resolution, origin[1] + j * resolution)`` (the
    first axis is x). ``points`` has shape (..., 2); the result has shape ``points.shape[:-1] +
    values.shape[2:]``. Points outside the sampled rectangle are clamped onto it (the value of the nearest
    border point is returned). The interpolation is exact for fields linear in x and y.
    """
    vals = np.asarray(values, dtype=float)
    pts = np.asarray(points, dtype=float)
    if vals.ndim < 2 or vals.shape[0] < 1 or vals.shape[1] < 1:
        raise ParameterError(f"values must be a grid of shape (nx, ny, ...), got shape {vals.shape}")
    nx, ny = vals.shape[:2]
    fx = np.clip((pts[..., 0] - origin[0]) / resolution, 0.0, nx - 1)
    fy = np.clip((pts[..., 1] - origin[1]) / resolution, 0.0, ny - 1)
    ix = np.minimum(np.floor(fx).astype(np.intp), max(nx - 2, 0))
    iy = np.minimum(np.floor(fy).astype(np.intp), max(ny - 2, 0))
    tx = fx - ix
    ty = fy - iy
    ix1 = np.minimum(ix + 1, nx - 1)
    iy1 = np.minimum(iy + 1, ny - 1)
    extra = (np.newaxis,) * (vals.ndim - 2)
    tx = tx[(..., *extra)]
    ty = ty[(..., *extra)]
    return (
        vals[ix, iy] * (1.0 - tx) * (1.0 - ty)
        + vals[ix1, iy] * tx * (1.0 - ty)
        + vals[ix, iy1] * (1.0 - tx) * ty
        + vals[ix1, iy1] * tx * ty
    )


# ------------------------------------------------------------------------------------------------------------
# Environment
# ------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LowObstacle:
    """An obstacle the robots must avoid but a tether may pass over (a step, a cable tray).

    ``name``: a label (the GeoJSON feature's ``name``); ``footprint``: its bare plan-view footprint (shapely Polygon or
    MultiPolygon, not grown by the robot radius) [m]; ``height``: its top above the floor [m] (> 0; heights below the
    tethers' exit height 0.43 m are the interesting case). A map gives one with a GeoJSON feature carrying a numeric
    ``"height"`` property (:mod:`tmr.world.maps`). A cable is never higher than its higher end, so a low obstacle at
    or above the exit height minus ``low_obstacle_clearance`` can never be passed over: every crossing fails the
    checker (make it tall instead).
    """

    name: str
    footprint: BaseGeometry
    height: float

    def __post_init__(self) -> None:
        h = self.height
        if isinstance(h, bool) or not isinstance(h, int | float | np.floating) or not math.isfinite(h) or h <= 0:
            raise ParameterError(f"low obstacle {self.name!r}: height must be a positive number of metres, got {h!r}")
        object.__setattr__(self, "height", float(h))
        g = self.footprint
        if not isinstance(g, shapely.Polygon | shapely.MultiPolygon) or g.is_empty or g.area <= 0.0:
            raise MapError(
                f"low obstacle {self.name!r}: the footprint must be a polygon with an area (a polygon, a point with a "
                f"'radius' or a line with a 'width'), got {getattr(g, 'geom_type', type(g).__name__)}"
            )
        check_geometry(g, f"low obstacle {self.name!r}")


class Environment:
    """A rectangular room with obstacles, inflated by the robot safety radius, with clearance queries.

    Build it with :meth:`from_geometry`, or from a map file with :func:`tmr.world.maps.load_environment`. Attributes
    (read-only by convention):

    * ``bounds`` (xmin, ymin, xmax, ymax) [m] -- the room; outside is wall.
    * ``safety_radius`` r [m] -- robot radius; obstacles are grown by r and the walls inward by r.
    * ``resolution`` [m] -- cell size of the signed distance field.
    * ``obstacles`` -- raw obstacles (shapely, union, clipped to the room), the low obstacles' footprints included.
    * ``tall_obstacles`` -- the raw obstacles without the low ones (``obstacles`` when there are none).
    * ``low_obstacles`` -- the :class:`LowObstacle` s (bare footprints and heights): obstacles for the robots (in
      ``obstacles``, ``inflated``, ``free`` and every clearance query), not for the tethers
      (:attr:`tether_environment`, :meth:`low_obstacle_distance`).
    * ``inflated`` -- obstacles grown by r plus the walls grown by r (a frame covering the room box grown by
      r); everything outside the room is an obstacle too.
    * ``free`` -- the free space (Polygon or MultiPolygon), the complement of ``inflated`` in the room;
      prepared.
    * ``source`` -- the map file it was loaded from, or None.
    * ``known_free`` -- for an occupancy-grid map, the bounding box (xmin, ymin, xmax, ymax) [m] of its known free
      cells (figures are framed on it); None otherwise.

    The signed distance field is built lazily on the first grid query and cached; the exact queries use a
    prepared polygon and an STR-tree of the free-space boundary segments (also cached).
    """

    def __init__(
        self,
        obstacles: BaseGeometry | Iterable[BaseGeometry] | None,
        bounds: Sequence[float],
        safety_radius: float = DEFAULT_SAFETY_RADIUS,
        resolution: float = DEFAULT_RESOLUTION,
        *,
        source: str | Path | None = None,
        low_obstacles: Iterable[LowObstacle] = (),
    ) -> None:
        where = str(source) if source is not None else "environment"
        self.source: Path | None = Path(source) if source is not None else None
        self.known_free: Bounds | None = None
        self.bounds: Bounds = check_bounds(bounds, where)
        self.safety_radius: float = _check_positive(safety_radius, "safety_radius [m]", allow_zero=True)
        self.resolution: float = _check_positive(resolution, "resolution [m]")
        xmin, ymin, xmax, ymax = self.bounds
        r = self.safety_radius

        cells = [(hi - lo) / self.resolution for lo, hi in ((xmin, xmax), (ymin, ymax))]  # inf for a 1e308 m room
        ncells = math.prod(self._grid_shape()) if all(map(math.isfinite, cells)) else math.inf
        if ncells > _MAX_CELLS:
            raise ParameterError(
                f"{where}: a {xmax - xmin:g} m x {ymax - ymin:g} m room at resolution {self.resolution:g} m "
                f"needs {f'{ncells:,}' if math.isfinite(ncells) else 'over 1e308'} grid cells (limit "
                f"{_MAX_CELLS:,}); use a coarser resolution"
            )

        self.room = box(xmin, ymin, xmax, ymax)
        raw = _union_obstacles(obstacles, where)
        self.low_obstacles: tuple[LowObstacle, ...] = tuple(low_obstacles)
        for k, low in enumerate(self.low_obstacles):
            if not isinstance(low, LowObstacle):
                raise MapError(f"{where}: low obstacle #{k} is not a LowObstacle: {type(low).__name__}")
        tall = raw.intersection(self.room) if not raw.is_empty else raw
        self.tall_obstacles: BaseGeometry = tall
        if self.low_obstacles:
            both = shapely.union_all([raw, *(low.footprint for low in self.low_obstacles)])
            self.obstacles: BaseGeometry = both.intersection(self.room)
        else:
            self.obstacles = tall

        if xmax - xmin <= 2 * r or ymax - ymin <= 2 * r:
            width = f"{2 * r:g} m" if math.isfinite(2 * r) else f"2 × {r:g} m"  # 2r overflows for r ≥ 9e307
            raise MapError(
                f"{where}: empty room: the room {xmax - xmin:g} m x {ymax - ymin:g} m leaves no free space "
                f"for a robot of safety radius {r:g} m (needs more than {width} each way)"
            )
        inner = box(xmin + r, ymin + r, xmax - r, ymax - r)
        grown = self.obstacles.buffer(r, quad_segs=QUAD_SEGS) if not self.obstacles.is_empty else self.obstacles
        free = _polygonal_parts(inner.difference(grown) if not grown.is_empty else inner)
        if free.is_empty or free.area <= 0.0:
            raise MapError(
                f"{where}: no free space: the obstacles grown by the safety radius {r:g} m cover the "
                f"whole room {self.bounds}"
            )
        shapely.prepare(free)
        self.free: BaseGeometry = free
        self.inflated: BaseGeometry = box(xmin - r, ymin - r, xmax + r, ymax + r).difference(free)

    # --------------------------------------------------------------------------------------------------------
    # constructors
    @classmethod
    def from_geometry(
        cls,
        obstacles: BaseGeometry | Iterable[BaseGeometry] | None,
        bounds: Sequence[float],
        safety_radius: float = DEFAULT_SAFETY_RADIUS,
        resolution: float = DEFAULT_RESOLUTION,
        *,
        low_obstacles: Iterable[LowObstacle] = (),
    ) -> Environment:
        """Environment from shapely obstacles (one geometry, a list of them, or None for an empty room).

        Polygons are solid obstacles; lines and points are zero-thickness obstacles (they still block a band
        of width 2 r once inflated). ``bounds`` = (xmin, ymin, xmax, ymax) [m]; ``safety_radius`` [m];
        ``resolution`` [m] cell of the distance field; ``low_obstacles``: :class:`LowObstacle` s (obstacles for the
        robots, not for the tethers). Invalid geometry raises MapError.
        """
        return cls(obstacles, bounds, safety_radius, resolution, low_obstacles=low_obstacles)

    def with_safety_radius(self, safety_radius: float) -> Environment:
        """The same room and obstacles with the obstacles grown by another robot radius ``safety_radius`` [m]
        (``self`` when it is already that radius)."""
        if float(safety_radius) == self.safety_radius:
            return self
        env = Environment(
            self.tall_obstacles,
            self.bounds,
            safety_radius,
            self.resolution,
            source=self.source,
            low_obstacles=self.low_obstacles,
        )
        env.known_free = self.known_free
        return env

    # --------------------------------------------------------------------------------------------------------
    # low obstacles
    @cached_property
    def tether_environment(self) -> Environment:
        """The world of the tethers' plan-view chords: the same room, safety radius and resolution without the low
        obstacles (a tether may pass over them; whether the cable's height clears one is checked on the catenary).
        ``self`` when there are no low obstacles, so nothing changes for a world without them. Cached."""
        if not self.low_obstacles:
            return self
        env = Environment(self.tall_obstacles, self.bounds, self.safety_radius, self.resolution, source=self.source)
        env.known_free = self.known_free
        return env

    def low_obstacle_distance(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Exact plan-view signed distance [m] of points (M, 2) to each low obstacle's bare footprint, and its gradient.

        Returns ``dist`` (M, n_low): > 0 outside footprint o, the distance to it; < 0 inside, minus the distance to
        its boundary (shapely/GEOS, exact on the polygon); and ``grad`` (M, n_low, 2), dimensionless: the unit vector
        away from the footprint (outside: from the nearest footprint point to the point; inside: from the point to
        the nearest boundary point, the way out), the gradient of ``dist`` wherever it is differentiable. On the
        boundary itself (distance 0) the direction from the footprint's centroid. ``n_low`` may be 0.
        """
        pts = _as_points(points).reshape(-1, 2)
        m, n = len(pts), len(self.low_obstacles)
        dist = np.zeros((m, n))
        grad = np.zeros((m, n, 2))
        if m == 0 or n == 0:
            return dist, grad
        geoms = shapely.points(pts)
        for o, low in enumerate(self.low_obstacles):
            fp = low.footprint
            inside = shapely.contains_xy(fp, pts[:, 0], pts[:, 1])
            target = np.where(inside, shapely.boundary(fp), fp)
            line = shapely.shortest_line(geoms, target)
            ends = shapely.get_coordinates(line).reshape(m, 2, 2)  # [point, nearest point of the target]
            vec = ends[:, 0] - ends[:, 1]
            d = np.hypot(vec[:, 0], vec[:, 1])
            vec = np.where(inside[:, None], -vec, vec)
            flat = d <= 1e-12
            if flat.any():  # on the boundary: away from the centroid
                c = np.asarray(fp.centroid.coords[0])
                vec[flat] = pts[flat] - c
            norm = np.hypot(vec[:, 0], vec[:, 1])
            grad[:, o] = vec / np.where(norm > 0, norm, 1.0)[:, None]
            grad[norm <= 0, o] = (1.0, 0.0)
            dist[:, o] = np.where(inside, -d, d)
        return dist, grad

    # --------------------------------------------------------------------------------------------------------
    # pickling
    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        for key in ("_grid", "_tree", "_boundary", "tether_environment"):  # cached heavy objects; rebuilt on demand
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state.setdefault("low_obstacles", ())  # pickled before low obstacles existed
        state.setdefault("tall_obstacles", state["obstacles"])
        self.__dict__.update(state)
        shapely.prepare(self.free)

    def __repr__(self) -> str:
        src = f", source={str(self.source)!r}" if self.source is not None else ""
        low = self.low_obstacles
        lows = f", low_obstacles={len(low)} (heights {', '.join(f'{o.height:g}' for o in low)} m)" if low else ""
        return (
            f"Environment(bounds={self.bounds}, safety_radius={self.safety_radius:g}, "
            f"resolution={self.resolution:g}, obstacle_area={self.obstacles.area:.3f} m^2{lows}{src})"
        )

    # --------------------------------------------------------------------------------------------------------
    # grid field
    def _grid_shape(self) -> tuple[int, int]:
        """Number of grid cells (nx, ny): the room plus _PAD_CELLS on every side."""
        xmin, ymin, xmax, ymax = self.bounds
        return (
            math.ceil((xmax - xmin) / self.resolution - 1e-9) + 2 * _PAD_CELLS,
            math.ceil((ymax - ymin) / self.resolution - 1e-9) + 2 * _PAD_CELLS,
        )

    @cached_property
    def _grid(self) -> tuple[NDArray[np.float64], tuple[float, float], NDArray[np.bool_]]:
        """(field (nx, ny, 3) = [signed distance, d/dx, d/dy], centre of cell (0, 0), occupancy (nx, ny))."""
        xmin, ymin, _, _ = self.bounds
        res = self.resolution
        nx, ny = self._grid_shape()
        x0 = xmin - (_PAD_CELLS - 0.5) * res
        y0 = ymin - (_PAD_CELLS - 0.5) * res
        xs = x0 + res * np.arange(nx)
        ys = y0 + res * np.arange(ny)
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        free = shapely.contains_xy(self.free, X, Y)
        if not free.any():
            raise MapError(
                f"{self.source or 'environment'}: the free space is narrower than one grid cell "
                f"({res:g} m); use a finer resolution"
            )
        sdf = np.where(free, 1.0, -1.0) * self._unsigned_field(free, x0, y0)
        gx, gy = np.gradient(sdf, res)
        field = np.stack([sdf, gx, gy], axis=-1)
        field.setflags(write=False)
        return field, (float(x0), float(y0)), ~free

    def _unsigned_field(self, free: NDArray[np.bool_], x0: float, y0: float) -> NDArray[np.float64]:
        """Distance [m] of every cell centre to the free-space boundary (EDT feature transform + exact).

        1. boundary band = cells with a 4-neighbour on the other side of the boundary, and the cells the
           boundary passes through;
        2. for each band cell, the nearest boundary segment (STR-tree, exact);
        3. ``distance_transform_edt(..., return_indices=True)`` gives every cell its nearest band cell;
        4. the cell's distance is the exact distance to the segments of that band cell and of its 8
           neighbours.

        Compared with the plain raster EDT (distances between cell centres, free minus occupied) this removes
        the staircase error: on the built-in scenarios the 99th percentile of the field error drops from 0.45
        to 0.05-0.2 cell and the 95th percentile of the gradient error from 0.09 to 0.01. It is not exact
        everywhere: where the segment nearest a cell belongs to none of those nine band cells (along the short
        chords of a grown obstacle's rounded corner), the distance is to a farther segment. On two 20 m random
        rooms (0.05 m cells) free cells within 0.1 m of the boundary read up to 0.021 m too far, farther ones up
        to 0.033 m; the QP's ``d_safe`` (0.05 m) absorbs this, and every plan is checked with exact distances.
        """
        res = self.resolution
        nx, ny = free.shape
        band = np.zeros_like(free)
        band[1:] |= free[1:] != free[:-1]
        band[:-1] |= free[:-1] != free[1:]
        band[:, 1:] |= free[:, 1:] != free[:, :-1]
        band[:, :-1] |= free[:, :-1] != free[:, 1:]
        # plus the cells the boundary passes through (sampled every half cell), so that free pockets or
        # slivers thinner than a cell, invisible to the occupancy raster, still attract the nearby distances
        tree, segments = self._tree
        seg = shapely.get_coordinates(segments).reshape(-1, 2, 2)
        n = np.ceil(np.hypot(*(seg[:, 1] - seg[:, 0]).T) / (0.5 * res)).astype(np.intp) + 1
        sid = np.repeat(np.arange(len(seg)), n)
        t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n - 1, n)
        samples = seg[sid, 0] + t[:, None] * (seg[sid, 1] - seg[sid, 0])
        si = np.clip(np.rint((samples[:, 0] - x0) / res).astype(np.intp), 0, nx - 1)
        sj = np.clip(np.rint((samples[:, 1] - y0) / res).astype(np.intp), 0, ny - 1)
        band[si, sj] = True
        bi, bj = np.nonzero(band)
        centres = shapely.points(x0 + res * bi, y0 + res * bj)
        hit_idx, hit_seg = tree.query_nearest(centres, all_matches=False)
        seg_of = np.empty(len(bi), dtype=np.intp)
        seg_of[hit_idx] = hit_seg
        ax, ay = seg[seg_of, 0, 0], seg[seg_of, 0, 1]  # per band cell: its nearest segment A + t (B - A)
        ux, uy = seg[seg_of, 1, 0] - ax, seg[seg_of, 1, 1] - ay
        uu = np.maximum(ux * ux + uy * uy, 1e-300)
        label = np.full(free.shape, -1, dtype=np.intp)
        label[bi, bj] = np.arange(len(bi))
        from scipy import ndimage  # only when a distance field is built (a refusal never needs one)

        near = ndimage.distance_transform_edt(~band, return_distances=False, return_indices=True)
        out = np.empty(free.shape)
        step = max(1, 2_000_000 // (9 * ny))  # rows per slab: bounds the temporaries to a few tens of MB
        for r0 in range(0, nx, step):
            ni, nj = near[0, r0 : r0 + step], near[1, r0 : r0 + step]
            px = (x0 + res * np.arange(r0, r0 + ni.shape[0]))[:, None]
            py = (y0 + res * np.arange(ny))[None, :]
            best = np.full(ni.shape, np.inf)
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    k = label[np.clip(ni + di, 0, nx - 1), np.clip(nj + dj, 0, ny - 1)]
                    ok = k >= 0
                    k = np.where(ok, k, 0)
                    dx, dy = px - ax[k], py - ay[k]
                    t = np.clip((dx * ux[k] + dy * uy[k]) / uu[k], 0.0, 1.0)
                    d = np.hypot(dx - t * ux[k], dy - t * uy[k])
                    best = np.where(ok & (d < best), d, best)
            out[r0 : r0 + step] = best
        return out

    @property
    def distance_field(self) -> NDArray[np.float64]:
        """Signed distance field [m], shape (nx, ny); [i, j] is at the cell centre (x0 + i h, y0 + j h)."""
        return self._grid[0][..., 0]

    @property
    def occupancy(self) -> NDArray[np.bool_]:
        """Occupied cells (inflated obstacles and walls), shape (nx, ny), indexed like the field."""
        return self._grid[2]

    @property
    def grid_origin(self) -> tuple[float, float]:
        """Centre (x0, y0) [m] of grid cell (0, 0)."""
        return self._grid[1]

    def _lookup(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        pts = _as_points(points)
        field, origin, _ = self._grid
        nx, ny = field.shape[:2]
        res = self.resolution
        lo = np.array(origin)
        hi = lo + res * np.array([nx - 1, ny - 1])
        clamped = np.clip(pts, lo, hi)
        vals = bilinear_interpolate(field, origin, res, clamped)
        d = vals[..., 0]
        grad = vals[..., 1:]
        off = pts - clamped
        out = np.hypot(off[..., 0], off[..., 1])
        if np.any(out > 0):
            # beyond the grid (deep in the walls): keep decreasing linearly with the distance to the grid, and
            # differentiate that term in the clamped coordinates
            d = d - out
            unit = off / np.where(out > 0, out, 1.0)[..., None]
            grad = np.where(off != 0.0, -unit, grad)
        return d, grad

    def clearance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Clearance [m] of points (..., 2), shape (...): bilinear lookup of the signed distance field.

        > 0 free, < 0 inside an inflated obstacle or wall. Agrees with :meth:`exact_clearance` to within about
        half a grid cell (the bilinear interpolation error at kinks of the distance: medial axis, corners).
        Points beyond the grid are clamped onto it and lose one metre of clearance per metre outside.
        """
        return self._lookup(points)[0]

    def clearance_and_gradient(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Clearance [m] (shape (...)) and its gradient (shape (..., 2), dimensionless) at points (..., 2).

        The gradient is the bilinear interpolation of the central-difference gradient of the field
        (``np.gradient``); it has unit length away from the medial axis and points away from the nearest
        obstacle -- the direction of the distance gradient used by the obstacle-avoidance task (Caruso 2021
        eq. 16-18). It is shorter than one near the medial axis, where the nearest obstacle changes.
        """
        return self._lookup(points)

    # --------------------------------------------------------------------------------------------------------
    # exact
    @cached_property
    def _tree(self) -> tuple[shapely.STRtree, NDArray[np.object_]]:
        """STR-tree over the straight segments of the free-space boundary (exact nearest distances)."""
        boundary = shapely.get_parts(shapely.boundary(self.free))
        coords, index = shapely.get_coordinates(boundary, return_index=True)
        same = index[1:] == index[:-1]
        segments = shapely.linestrings(np.stack([coords[:-1][same], coords[1:][same]], axis=1))
        return shapely.STRtree(segments), segments

    @cached_property
    def _boundary(self) -> BaseGeometry:
        """The free space's boundary (walls and obstacles grown by r), prepared: a segment that does not meet it and
        starts inside the free space lies inside (:meth:`segment_is_free`)."""
        boundary = shapely.boundary(self.free)
        shapely.prepare(boundary)
        return boundary

    def _boundary_distance(self, geoms: NDArray[np.object_]) -> NDArray[np.float64]:
        tree, _ = self._tree
        dist = np.empty(len(geoms))
        if len(geoms) == 0:
            return dist
        (idx, _), d = tree.query_nearest(geoms, return_distance=True, all_matches=False)
        dist[idx] = d
        return dist

    def exact_clearance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Exact signed distance [m] of points (..., 2) to the inflated obstacles and walls; shape (...).

        Distance to the boundary of the free space (nearest boundary segment, STR-tree, vectorised), positive
        inside the free space and negative outside it (``shapely.contains_xy``). Buffered arcs are polygons
        with 16 segments per quarter circle, so round obstacles are exact to 0.06 % of their inflated radius.
        """
        pts = _as_points(points)
        flat = pts.reshape(-1, 2)
        d = self._boundary_distance(shapely.points(flat))
        inside = shapely.contains_xy(self.free, flat[:, 0], flat[:, 1])
        return np.where(inside, d, -d).reshape(pts.shape[:-1])

    def segment_clearance(self, a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
        """Clearance [m] of the straight segments a-b (a, b broadcast to (..., 2)); shape (...).

        Definition: if the segment lies in the free space (closure included), its exact distance to the
        inflated obstacles, i.e. the minimum clearance over the segment (>= 0). Otherwise the segment touches
        or crosses an inflated obstacle and the result is ``min(0, min_k exact_clearance(p_k))`` over points
        p_k spaced at most ``resolution / 2`` along it (end points included): <= 0, minus (approximately, from
        below) the deepest penetration. So ``segment_clearance > m`` (m >= 0) is an exact test that the whole
        segment keeps a clearance above m. Zero-length segments give the point clearance.
        """
        pa = _as_points(a, "a")
        pb = _as_points(b, "b")
        pa, pb = np.broadcast_arrays(pa, pb)
        shape = pa.shape[:-1]
        A = pa.reshape(-1, 2)
        B = pb.reshape(-1, 2)
        out = np.empty(len(A))
        degenerate = np.all(A == B, axis=1)
        if degenerate.any():
            out[degenerate] = self.exact_clearance(A[degenerate])
        seg = ~degenerate
        if seg.any():
            lines = shapely.linestrings(np.stack([A[seg], B[seg]], axis=1))
            dist = self._boundary_distance(lines)
            covered = shapely.covers(self.free, lines)
            res = np.where(covered, dist, 0.0)
            if not covered.all():
                res[~covered] = self._penetration(A[seg][~covered], B[seg][~covered])
            out[seg] = res
        return out.reshape(shape)

    def segment_is_free(self, a: ArrayLike, b: ArrayLike, margin: ArrayLike = 0.0) -> NDArray[np.bool_]:
        """Whether each straight segment a-b keeps a clearance > ``margin`` [m] from the inflated obstacles and
        walls: ``segment_clearance(a, b) > margin`` without measuring how deep a blocked segment goes when
        ``margin`` ≥ 0 (exact, and much cheaper for long blocked segments); shape (...). ``margin`` is a scalar
        or one value per segment (broadcast with the segments' shape). A segment that meets the free space's
        boundary is not free (its clearance is 0), decided by GEOS's robust ``intersects``, not by a distance."""
        pa, pb = np.broadcast_arrays(_as_points(a, "a"), _as_points(b, "b"))
        shape = pa.shape[:-1]
        m = np.asarray(margin, dtype=float)
        if not np.all(np.isfinite(m)):
            raise ParameterError(f"margin must be finite, got {margin}")
        if np.any(m < 0.0):
            return np.asarray(self.segment_clearance(a, b)) > m
        M = np.broadcast_to(m, shape).reshape(-1)
        A, B = pa.reshape(-1, 2), pb.reshape(-1, 2)
        out = np.zeros(len(A), dtype=bool)
        degenerate = np.all(A == B, axis=1)
        if degenerate.any():
            out[degenerate] = self.exact_clearance(A[degenerate]) > M[degenerate]
        seg = np.flatnonzero(~degenerate)
        if len(seg):
            # clear of the boundary and started inside: inside (the test the free space's ``covers`` makes, less
            # the segments that touch the boundary, whose clearance 0 is not > margin). On the 1.8 million segments
            # of a 34 m route's placement (long_walls-corner-1883971893, 8 robots) the test takes 0.77 s against
            # covers' 1.31 s (the whole of these 21,415 calls 2.40 → 2.08 s); the STR-tree of boundary segments
            # (``_tree``) queried with ``intersects`` took 3.1 s, prepared ``dwithin`` for the whole test 6.2 s
            lines = shapely.linestrings(np.stack([A[seg], B[seg]], axis=1))
            inside = ~shapely.intersects(self._boundary, lines)
            inside &= shapely.contains_xy(self.free, A[seg, 0], A[seg, 1])
            if inside.any():
                out[seg[inside]] = self._farther_than(lines[inside], M[seg[inside]])
        return out.reshape(shape)

    def _farther_than(self, lines: NDArray[np.object_], margin: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether each geometry's distance to the free space's boundary is > its ``margin`` [m] (≥ 0): the same
        answer as :meth:`_boundary_distance` > ``margin``, from only the boundary segments whose envelope meets the
        geometry's envelope grown by the margin (a segment within the margin has a point there; grown by 1 nm more,
        so that no rounding of the box leaves such a point out: more candidates, the same answer), each distance
        GEOS's. ``benchmarks/segment_margin.py``: on the 7,133 tests of a train search (``narrow-far-2856891376``,
        8 robots; 420,467 segments) 0.46× the time of the nearest segment of each (``STRtree.query_nearest``)."""
        tree, segments = self._tree
        lo = shapely.bounds(lines)
        grow = margin + 1e-9
        boxes = shapely.box(lo[:, 0] - grow, lo[:, 1] - grow, lo[:, 2] + grow, lo[:, 3] + grow)
        i, j = tree.query(boxes)
        near = shapely.distance(lines[i], segments[j]) <= margin[i]
        out = np.ones(len(lines), dtype=bool)
        out[i[near]] = False
        return out

    def visible_region(self, point: ArrayLike, radius: float) -> BaseGeometry:
        """The points q of the free space within ``radius`` [m] of ``point`` whose segment point–q lies in the free
        space (``point``'s visibility polygon cut to a disc), as a shapely geometry. It contains every such point;
        the disc is a circumscribed 64-gon, so points up to 0.12 % beyond the radius may be in it too.

        The disc (a 64-gon circumscribing the circle) ∩ the free space, minus the shadow of every free-space boundary
        segment near the point: the quadrilateral behind the segment as seen from the point, closed at twice the
        radius (through the bisector too, so it covers the disc). A segment from the point crosses the boundary iff
        its far end is in a shadow. ``point`` must be in the free space.
        """
        p = _as_points(point, "point").reshape(2)
        r = _check_positive(radius, "radius [m]")
        disc = shapely.Point(p).buffer(r / math.cos(math.pi / 64) * (1 + 1e-12), quad_segs=16)
        tree, segments = self._tree
        c = shapely.get_coordinates(segments[tree.query(disc)]).reshape(-1, 2, 2)
        du, dv = c[:, 0] - p, c[:, 1] - p
        nu, nv = np.linalg.norm(du, axis=1), np.linalg.norm(dv, axis=1)
        cross = du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0]
        keep = np.abs(cross) > 1e-9 * nu * nv  # a segment in line with the point casts no shadow
        c, du, dv = c[keep], du[keep] / nu[keep, None], dv[keep] / nv[keep, None]
        mid = du + dv
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        far = 2.0 * r
        rings = np.stack([c[:, 0], c[:, 1], p + far * dv, p + far * mid, p + far * du, c[:, 0]], axis=1)
        shadows = shapely.union_all(shapely.make_valid(shapely.polygons(rings)))
        return shapely.difference(shapely.intersection(self.free, disc), shadows)

    def _penetration(self, A: NDArray[np.float64], B: NDArray[np.float64]) -> NDArray[np.float64]:
        """min(0, min exact clearance over points spaced <= resolution/2 along each segment A-B)."""
        h = 0.5 * self.resolution
        length = np.hypot(*(B - A).T)
        n = np.maximum(2, np.ceil(length / h).astype(np.intp) + 1)
        starts = np.concatenate([[0], np.cumsum(n)[:-1]])
        seg_id = np.repeat(np.arange(len(A)), n)
        t = (np.arange(n.sum()) - starts[seg_id]) / (n[seg_id] - 1)
        pts = A[seg_id] + t[:, None] * (B - A)[seg_id]
        d = self.exact_clearance(pts)
        return np.minimum(np.minimum.reduceat(d, starts), 0.0)

    def free_region(self, points: ArrayLike) -> NDArray[np.intp]:
        """Index of the connected piece of the free space each point lies in (the order of
        ``shapely.get_parts(free)``), −1 outside it; shape (...). Two points are joined by a free path iff they get
        the same index ≥ 0."""
        pts = _as_points(points)
        flat = pts.reshape(-1, 2)
        region = np.full(len(flat), -1, dtype=np.intp)
        for k, part in enumerate(shapely.get_parts(self.free)):
            region[shapely.contains_xy(part, flat[:, 0], flat[:, 1])] = k
        return region.reshape(pts.shape[:-1])

    def is_free(self, points: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
        """True where ``exact_clearance(points) > margin`` [m]; shape (...). Fast path for margin >= 0."""
        pts = _as_points(points)
        margin = float(margin)
        if not math.isfinite(margin):
            raise ParameterError(f"margin must be finite, got {margin}")
        if margin < 0.0:
            return self.exact_clearance(pts) > margin
        flat = pts.reshape(-1, 2)
        inside = shapely.contains_xy(self.free, flat[:, 0], flat[:, 1])
        if margin > 0.0 and inside.any():
            tree, _ = self._tree
            idx = np.flatnonzero(inside)
            hits = tree.query(shapely.points(flat[idx]), predicate="dwithin", distance=margin)
            inside[idx[np.unique(hits[0])]] = False
        return inside.reshape(pts.shape[:-1])


def refuse_low_obstacles(env: Any, what: str, why: str) -> None:
    """ParameterError (the command line: one line, exit 2) when ``env`` has low obstacles and ``what`` (e.g.
    ``"--method horizon"``) cannot plan over them; ``why`` says why and what to use instead."""
    lows = getattr(env, "low_obstacles", ())
    if lows:
        names = ", ".join(f"{o.name} ({o.height:g} m)" for o in lows)
        raise ParameterError(f"{what} cannot plan over low obstacles (the map has {len(lows)}: {names}): {why}")


def refuse_impassable_low_obstacles(env: Any, highest_end: float, clearance: float) -> None:
    """ParameterError (the command line: one line, exit 2) when a low obstacle of ``env`` is too high for any cable:
    a catenary is nowhere higher than its higher end, so a tether whose ends are at most ``highest_end`` [m] cannot
    clear an obstacle of height h by ``clearance`` [m] if h + clearance ≥ highest_end. Without this refusal the route
    would let tethers over it (``tether_environment``) and every plan would be held back in front of it."""
    for o in getattr(env, "low_obstacles", ()):
        if o.height + clearance >= highest_end:
            raise ParameterError(
                f"the low obstacle {o.name!r} is {o.height:g} m high: with the {clearance:g} m clearance no tether "
                f"(its ends at most {highest_end:g} m high) can pass over it; give it no 'height' (a tall obstacle), "
                "or raise exit_height / base_height"
            )


# ------------------------------------------------------------------------------------------------------------
# geometry input
# ------------------------------------------------------------------------------------------------------------
def _union_obstacles(obstacles: BaseGeometry | Iterable[BaseGeometry] | None, where: str) -> BaseGeometry:
    if obstacles is None:
        return shapely.GeometryCollection()
    geoms = [obstacles] if isinstance(obstacles, BaseGeometry) else list(obstacles)
    for k, g in enumerate(geoms):
        if not isinstance(g, BaseGeometry):
            raise MapError(f"{where}: obstacle #{k} is not a shapely geometry: {type(g).__name__}")
        check_geometry(g, f"{where}: obstacle #{k}")
    if not geoms:
        return shapely.GeometryCollection()
    return shapely.union_all(geoms)


def check_geometry(g: BaseGeometry, what: str) -> None:
    if g.is_empty:
        return
    coords = shapely.get_coordinates(g)
    if not np.all(np.isfinite(coords)):
        raise MapError(f"{what}: coordinates contain NaN or inf")
    if not shapely.is_valid(g):
        raise MapError(
            f"{what}: invalid geometry ({shapely.is_valid_reason(g)}); fix the polygon "
            f"(no self-intersections, closed rings, holes inside the shell), e.g. with shapely.make_valid"
        )
