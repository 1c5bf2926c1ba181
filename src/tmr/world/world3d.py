"""The 3-D world of a drone chain: a room (floor, ceiling, four walls) holding boxes, extruded polygons (prisms) and
triangle meshes, with exact distances from ``coal`` (the maintained successor of hpp-fcl).

:class:`World3D` implements the :class:`tmr.world.World` protocol with points of shape (..., 3). Every distance is
a *clearance* [m]: the signed distance to the nearest obstacle or to the room's boundary, minus the robot radius
``safety_radius``; > 0 in the free space.

How each obstacle is queried (a point is a coal ``Sphere`` of radius 0, a segment a ``Capsule`` of radius 0):

- a box is a ``coal.Box``, a convex prism or convex mesh a ``coal.Convex`` (its hull): coal returns the *signed*
  distance (GJK outside, EPA inside; the sphere–box pair has a closed form) with the nearest points and normal;
- a non-convex prism or mesh is a ``coal.BVHModelOBBRSS`` of its triangles: coal returns the distance to the
  surface, and the sign (inside or not) comes from the generalized winding number of the closed triangle set
  (Jacobson 2013; the solid angles by Van Oosterom–Strackee 1983), computed here with numpy.

The room's boundary is exact in closed form: the clearance to the six faces is ``min(p - lo, hi - p) - r``, which
keeps decreasing by 1 m per metre outside the room. Overlapping obstacles: inside an overlap the clearance is the
deepest of the single obstacles' (the union's depth can be larger); outside, it is exact.

:func:`world3d_from_table` builds a World3D from a scenario's ``[world]`` table (keys ``bounds``, ``safety_radius``,
``obstacles``), refusing bad input with one-line :class:`tmr.errors.MapError` messages.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import coal
import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from shapely.geometry import Polygon

from tmr.errors import MapError

__all__ = ["Obstacle3D", "World3D", "aabb_gap", "box_obstacle", "mesh_obstacle", "prism_obstacle", "world3d_from_table"]

Bounds3 = tuple[float, float, float, float, float, float]


def _fmt(values: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in values) + ")"


@dataclass(frozen=True)
class Obstacle3D:
    """One obstacle as coal sees it.

    Attributes:
        geometry: the coal geometry, in world coordinates (identity placement).
        signed: True if coal's distance is already signed (Box, Convex); False for a triangle BVH, whose sign
            comes from the winding number of ``triangles``.
        triangles: (T, 3, 3) [m] the closed surface (only for a BVH obstacle, else None).
        lo, hi: (3,) [m] the axis-aligned bounding box.
        name: what the messages call it ("box #0", "mesh 'room.stl'").
    """

    geometry: Any
    signed: bool
    triangles: NDArray[np.float64] | None
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    name: str


def _vec3s(points: NDArray[np.float64]) -> Any:
    out = coal.StdVec_Vec3s()
    for p in np.asarray(points, dtype=float):
        out.append(np.array(p, dtype=float))
    return out


def _bvh(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> Any:
    model = coal.BVHModelOBBRSS()
    tris = coal.StdVec_Triangle()
    for f in faces:
        tris.append(coal.Triangle(int(f[0]), int(f[1]), int(f[2])))
    model.beginModel(len(faces), len(vertices))
    model.addSubModel(_vec3s(vertices), tris)
    model.endModel()
    return model


def box_obstacle(lo: ArrayLike, hi: ArrayLike, name: str = "box") -> Obstacle3D:
    """An axis-aligned box from its corners lo, hi (3,) [m] (hi > lo on every axis)."""
    lo_, hi_ = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    if lo_.shape != (3,) or hi_.shape != (3,) or not np.all(np.isfinite(np.r_[lo_, hi_])):
        raise MapError(f"{name}: corners must be 3 finite numbers each")
    if np.any(hi_ <= lo_):
        raise MapError(f"{name}: empty box from {_fmt(lo_)} to {_fmt(hi_)} (need max > min on x, y and z)")
    half = 0.5 * (hi_ - lo_)
    return Obstacle3D(_PlacedBox(coal.Box(*(2.0 * half)), 0.5 * (lo_ + hi_)), True, None, lo_, hi_, name)


@dataclass(frozen=True)
class _PlacedBox:
    """A coal.Box and its centre [m] (coal boxes are centred on their placement)."""

    box: Any
    centre: NDArray[np.float64]


def _closed_mesh_obstacle(mesh: Any, name: str) -> Obstacle3D:
    return _solid(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64), mesh.is_convex, name)


def _solid(vertices: NDArray[np.float64], faces: NDArray[np.int64], convex: bool, name: str) -> Obstacle3D:
    """A closed surface's obstacle: coal's convex hull if ``convex``, else a BVH of its triangles."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    if convex:
        hull = coal.Convex.convexHull(_vec3s(vertices), False, None)
        return Obstacle3D(hull, True, None, lo, hi, name)
    return Obstacle3D(_bvh(vertices, faces), False, vertices[faces], lo, hi, name)


def prism_obstacle(polygon: ArrayLike, z: ArrayLike, name: str = "prism") -> Obstacle3D:
    """The extrusion of a simple polygon [[x, y], ...] [m] (convex or not) between heights z = (z0, z1) [m]."""
    xy = np.asarray(polygon, dtype=float)
    zz = np.asarray(z, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 3 or not np.all(np.isfinite(xy)):
        raise MapError(f"{name}: the footprint must be at least 3 finite [x, y] points")
    if zz.shape != (2,) or not np.all(np.isfinite(zz)) or zz[1] <= zz[0]:
        shown = zz.tolist() if zz.ndim else z
        raise MapError(f"{name}: z must be 2 finite numbers [z0, z1] with z1 > z0, got {shown!r}")
    poly = Polygon(xy)
    if not poly.is_valid or poly.area <= 0.0:
        raise MapError(f"{name}: the footprint is not a simple polygon ({shapely.is_valid_reason(poly)})")
    poly = (
        shapely.orient_polygons(poly) if hasattr(shapely, "orient_polygons") else shapely.geometry.polygon.orient(poly)
    )
    ring = np.asarray(poly.exterior.coords)[:-1]
    n = len(ring)
    z0, z1 = float(zz[0]), float(zz[1])
    verts = [np.c_[ring, np.full(n, z0)], np.c_[ring, np.full(n, z1)]]
    faces: list[list[int]] = []
    for i in range(n):  # side walls, outward for the counter-clockwise ring
        j = (i + 1) % n
        faces += [[i, j, n + j], [i, n + j, n + i]]
    index = {tuple(np.round(p, 12)): k for k, p in enumerate(ring)}
    for tri in shapely.get_parts(shapely.constrained_delaunay_triangles(poly)):
        t = np.asarray(tri.exterior.coords)[:3]
        k = [index[tuple(np.round(p, 12))] for p in t]
        ccw = (t[1, 0] - t[0, 0]) * (t[2, 1] - t[0, 1]) - (t[1, 1] - t[0, 1]) * (t[2, 0] - t[0, 0]) > 0
        if not ccw:
            k = [k[0], k[2], k[1]]
        faces += [[n + k[0], n + k[1], n + k[2]], [k[0], k[2], k[1]]]  # top faces up, bottom faces down
    # a prism is convex exactly when its footprint is (no trimesh needed: 0.5 s to import)
    convex = bool(poly.convex_hull.area - poly.area <= 1e-12 * max(poly.area, 1.0))
    return _solid(np.vstack(verts), np.asarray(faces, dtype=np.int64), convex, name)


def mesh_obstacle(path: str | Path, name: str | None = None) -> Obstacle3D:
    """A closed triangle mesh read from an STL/OBJ/PLY file (coordinates in metres) with trimesh."""
    p = Path(path)
    label = name or f"mesh '{p.name}'"
    if p.is_dir():
        raise MapError(f"{label}: {p} is a directory, not a mesh file")
    if not p.is_file():
        raise MapError(f"{label}: no such file: {p}")
    import trimesh  # only meshes and non-convex prisms need it (0.14 s to import)

    try:
        mesh = trimesh.load(p, force="mesh")
    except Exception as exc:  # trimesh raises many types on corrupt files
        raise MapError(
            f"{label}: cannot read the mesh: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MapError(f"{label}: the file holds no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MapError(f"{label}: vertex coordinates contain NaN or inf")
    if not mesh.is_watertight:
        raise MapError(f"{label}: the mesh is not closed (watertight), so its inside is undefined")
    return _closed_mesh_obstacle(mesh, label)


def _winding_number(points: NDArray[np.float64], triangles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Generalized winding number of a closed triangle set at points (n, 3): ±1 inside, 0 outside."""
    out = np.empty(len(points))
    chunk = max(1, 2_000_000 // max(1, len(triangles)))
    for s in range(0, len(points), chunk):
        rel = triangles[None, :, :, :] - points[s : s + chunk, None, None, :]  # (n, T, 3, 3)
        a, b, c = rel[..., 0, :], rel[..., 1, :], rel[..., 2, :]
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        num = np.einsum("...i,...i", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("...i,...i", a, b) * lc + np.einsum("...i,...i", b, c) * la
        den += np.einsum("...i,...i", c, a) * lb
        out[s : s + chunk] = np.sum(np.arctan2(num, den), axis=1) / (2.0 * math.pi)
    return out


_REQUEST = coal.DistanceRequest()
_REQUEST.enable_signed_distance = True
_IDENTITY = coal.Transform3s()
_POINT = coal.Sphere(0.0)


def _placement(translation: NDArray[np.float64], rotation: NDArray[np.float64] | None = None) -> Any:
    t = coal.Transform3s()
    if rotation is not None:
        t.setRotation(rotation)
    t.setTranslation(translation)
    return t


def _query(shape: Any, place: Any, obstacle: Obstacle3D) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """coal distance from a query shape to an obstacle: (distance, nearest point on the shape, on the obstacle)."""
    res = coal.DistanceResult()
    geom = obstacle.geometry
    if isinstance(geom, _PlacedBox):
        d = coal.distance(shape, place, geom.box, _placement(geom.centre), _REQUEST, res)
    else:
        d = coal.distance(shape, place, geom, _IDENTITY, _REQUEST, res)
    return float(d), np.array(res.getNearestPoint1()), np.array(res.getNearestPoint2())


def _segment_shape(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[Any, Any]:
    """A radius-0 capsule spanning a–b and its placement (coal's capsule: axis z, the constructor takes the full
    length); a point if a == b."""
    v = b - a
    length = float(np.linalg.norm(v))
    if length < 1e-12:
        return _POINT, _placement(a)
    u = v / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, u)
    e1 /= np.linalg.norm(e1)
    rot = np.column_stack([e1, np.cross(u, e1), u])
    return coal.Capsule(0.0, length), _placement(0.5 * (a + b), rot)


def aabb_gap(
    lo_a: NDArray[np.float64], hi_a: NDArray[np.float64], lo_b: NDArray[np.float64], hi_b: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Distance [m] between axis-aligned boxes [lo_a, hi_a] and [lo_b, hi_b] (broadcast, last axis x y z; a point:
    lo = hi), 0 where they meet: the norm of the per-axis gaps (summed as ``np.linalg.norm`` sums them)."""
    gap = np.maximum(0.0, np.maximum(lo_a - hi_b, lo_b - hi_a))
    return np.sqrt(np.add.reduce(gap * gap, axis=-1))


class World3D:
    """A room with box, prism and mesh obstacles; implements :class:`tmr.world.World` with points (..., 3).

    Args:
        obstacles: :class:`Obstacle3D` items (:func:`box_obstacle`, :func:`prism_obstacle`, :func:`mesh_obstacle`).
        bounds: (xmin, ymin, zmin, xmax, ymax, zmax) [m]; the floor is z = zmin, the ceiling z = zmax.
        safety_radius: robot radius r [m] (≥ 0); the obstacles are grown by r and the room shrunk by r.

    :meth:`clearance` is exact here (there is no grid), so it equals :meth:`exact_clearance`; each query costs one
    coal call per obstacle whose bounding box could be nearer than the room's boundary (a Python loop).
    """

    def __init__(self, obstacles: Sequence[Obstacle3D], bounds: ArrayLike, safety_radius: float = 0.0) -> None:
        b = np.asarray(bounds, dtype=float)
        if b.shape != (6,) or not np.all(np.isfinite(b)):
            raise MapError(f"world: bounds must be 6 finite numbers [xmin ymin zmin xmax ymax zmax], got {bounds!r}")
        if np.any(b[3:] <= b[:3]):
            raise MapError(f"world: empty room: bounds {_fmt(b)} need max > min on x, y and z")
        r = float(safety_radius)
        if not math.isfinite(r) or r < 0.0:
            raise MapError(f"world: safety_radius must be a finite number >= 0 m, got {safety_radius!r}")
        self.obstacles: tuple[Obstacle3D, ...] = tuple(obstacles)
        self.bounds: Bounds3 = tuple(float(v) for v in b)  # type: ignore[assignment]
        self.safety_radius: float = r
        self._lo, self._hi = b[:3], b[3:]
        #: the obstacles' bounding boxes stacked (O, 3) each [m]: broad-phase tests of every obstacle at once
        self.aabb_lo = np.array([ob.lo for ob in self.obstacles], dtype=float).reshape(-1, 3)
        self.aabb_hi = np.array([ob.hi for ob in self.obstacles], dtype=float).reshape(-1, 3)
        #: which obstacles are axis-aligned boxes (O,) (closed-form distances), and per obstacle the coal shape and
        #: its placement for a query (the box and its centre; a hull or BVH in world coordinates, the identity)
        self.is_box = np.array([isinstance(ob.geometry, _PlacedBox) for ob in self.obstacles], dtype=bool)
        self.is_signed = np.array([ob.signed for ob in self.obstacles], dtype=bool)
        self.coal_targets: tuple[tuple[Any, Any], ...] = tuple(
            (ob.geometry.box, _placement(ob.geometry.centre))
            if isinstance(ob.geometry, _PlacedBox)
            else (ob.geometry, _IDENTITY)
            for ob in self.obstacles
        )

    def box_gaps(self, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> NDArray[np.float64]:
        """Distance [m] from every obstacle's bounding box to each box [lo, hi] (M, 3) (a point: lo = hi): (O, M),
        a lower bound of the distance to the obstacle itself (:func:`aabb_gap` for all obstacles at once)."""
        return aabb_gap(self.aabb_lo[:, None, :], self.aabb_hi[:, None, :], lo[None], hi[None])

    def __repr__(self) -> str:
        return f"World3D({len(self.obstacles)} obstacles, bounds={_fmt(self.bounds)}, r={self.safety_radius:.3f})"

    def with_safety_radius(self, safety_radius: float) -> World3D:
        """The same world with another robot radius [m] (``self`` if it is already that)."""
        if float(safety_radius) == self.safety_radius:
            return self
        return World3D(self.obstacles, self.bounds, safety_radius)

    # -- the room's boundary, in closed form ---------------------------------------------------------------------
    def _wall(self, p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Signed distance [m] of points (n, 3) to the six faces (> 0 inside the room) and its gradient."""
        gaps = np.concatenate([p - self._lo, self._hi - p], axis=1)  # (n, 6)
        k = np.argmin(gaps, axis=1)
        grad = np.zeros_like(p)
        grad[np.arange(len(p)), k % 3] = np.where(k < 3, 1.0, -1.0)
        return gaps[np.arange(len(p)), k], grad

    def _lower_bound(self, p: NDArray[np.float64], ob: Obstacle3D) -> NDArray[np.float64]:
        """Distance [m] of points (n, 3) to the obstacle's bounding box (a lower bound of the distance to it)."""
        return aabb_gap(ob.lo, ob.hi, p, p)

    def _signed(self, p: NDArray[np.float64], want_gradient: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Signed distance [m] (no robot radius) of points (n, 3) and its gradient (n, 3)."""
        dist, grad = self._wall(p)
        for ob in self.obstacles:
            cand = np.flatnonzero(self._lower_bound(p, ob) < dist)
            if len(cand) == 0:
                continue
            sign = np.ones(len(cand))
            if not ob.signed:
                assert ob.triangles is not None
                sign = np.where(np.abs(_winding_number(p[cand], ob.triangles)) > 0.5, -1.0, 1.0)
            for s, i in zip(sign, cand, strict=True):
                d, _, q = _query(_POINT, _placement(p[i]), ob)
                d = s * abs(d) if not ob.signed else d
                if d < dist[i]:
                    dist[i] = d
                    if want_gradient:
                        v = p[i] - q
                        n = float(np.linalg.norm(v))
                        grad[i] = (math.copysign(1.0, d) * v / n) if n > 1e-12 else grad[i]
        return dist, grad

    def _points(self, points: ArrayLike) -> tuple[NDArray[np.float64], tuple[int, ...]]:
        p = np.asarray(points, dtype=float)
        if p.shape[-1:] != (3,):
            raise MapError(f"world: points must have shape (..., 3), got {p.shape}")
        return p.reshape(-1, 3), p.shape[:-1]

    # -- the World protocol -----------------------------------------------------------------------------------
    def exact_clearance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Exact signed distance [m] of points (..., 3) to the grown obstacles and walls, shape (...)."""
        p, shape = self._points(points)
        return (self._signed(p, False)[0] - self.safety_radius).reshape(shape)

    def clearance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Clearance [m] of points (..., 3), shape (...): here the exact one (:meth:`exact_clearance`)."""
        return self.exact_clearance(points)

    def clearance_and_gradient(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`clearance` (...) and its gradient (..., 3): the unit vector from the nearest obstacle point
        (or away from the nearest wall), pointing to increasing clearance (outward when inside an obstacle)."""
        p, shape = self._points(points)
        d, g = self._signed(p, True)
        return (d - self.safety_radius).reshape(shape), g.reshape(*shape, 3)

    def segment_clearance(self, a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
        """Clearance [m] of the segments a–b (broadcast to (..., 3)), shape (...): the smallest exact clearance
        along a free segment (a capsule query per obstacle), ≤ 0 for a segment touching or crossing a grown
        obstacle or leaving the shrunk room."""
        A, B = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
        pa, shape = self._points(A)
        pb, _ = self._points(B)
        # the wall term is a minimum of affine functions: its smallest value on a segment is at an end
        wall = np.minimum(self._wall(pa)[0], self._wall(pb)[0])
        out = wall.copy()
        lo_seg, hi_seg = np.minimum(pa, pb), np.maximum(pa, pb)
        for ob in self.obstacles:
            gap = aabb_gap(ob.lo, ob.hi, lo_seg, hi_seg)
            cand = np.flatnonzero(gap < out)
            if len(cand) == 0:
                continue
            inside = np.zeros(len(cand), dtype=bool)
            if not ob.signed:  # an unsigned BVH distance misses a segment lying wholly inside: test its ends
                assert ob.triangles is not None
                w = _winding_number(np.vstack([pa[cand], pb[cand]]), ob.triangles)
                inside = (np.abs(w[: len(cand)]) > 0.5) | (np.abs(w[len(cand) :]) > 0.5)
            for k, i in enumerate(cand):
                shape_i, place = _segment_shape(pa[i], pb[i])
                d, _, _ = _query(shape_i, place, ob)
                if inside[k]:
                    d = -abs(d) if d > 0 else d
                out[i] = min(out[i], d)
        return (out - self.safety_radius).reshape(shape)

    def segment_is_free(self, a: ArrayLike, b: ArrayLike, margin: ArrayLike = 0.0) -> NDArray[np.bool_]:
        """Whether each segment a–b keeps a clearance > ``margin`` [m] (scalar or per segment), shape (...)."""
        return self.segment_clearance(a, b) > np.asarray(margin, dtype=float)

    def is_free(self, points: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
        """Whether ``exact_clearance(points) > margin`` [m], shape (...)."""
        return self.exact_clearance(points) > margin


# -- the scenario loader ----------------------------------------------------------------------------------------
_WORLD_KEYS = {"bounds", "safety_radius", "obstacles"}
_KINDS = ("box", "prism", "mesh")


def _numbers(value: Any, n: int | None, where: str, what: str) -> NDArray[np.float64]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise MapError(f"{where}: {what} must be numbers, got {value!r}") from None
    if arr.ndim != 1 or (n is not None and len(arr) != n):
        raise MapError(f"{where}: {what} must be {n} numbers, got {value!r}")
    if not np.all(np.isfinite(arr)):
        raise MapError(f"{where}: {what} contains NaN or inf")
    return arr


def world3d_from_table(table: Mapping[str, Any], base: str | Path = ".", where: str = "[world]") -> World3D:
    """A :class:`World3D` from a scenario's ``[world]`` table.

    Keys: ``bounds = [xmin, ymin, zmin, xmax, ymax, zmax]`` [m]; ``safety_radius`` [m] (default 0);
    ``[[world.obstacles]]`` each with exactly one of ``box = [xmin, ymin, zmin, xmax, ymax, zmax]``,
    ``prism = [[x, y], ...]`` with ``z = [z0, z1]``, ``mesh = "file.stl"`` (STL/OBJ/PLY in metres, relative to
    ``base``, the scenario file's folder). Unknown keys and bad values raise a one-line :class:`MapError`.
    """
    if not isinstance(table, Mapping):
        raise MapError(f"{where}: must be a table, got {type(table).__name__}")
    unknown = sorted(set(table) - _WORLD_KEYS)
    if unknown:
        raise MapError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(_WORLD_KEYS))})")
    if "bounds" not in table:
        raise MapError(f"{where}: missing 'bounds' = [xmin, ymin, zmin, xmax, ymax, zmax]")
    bounds = _numbers(table["bounds"], 6, where, "bounds")
    r = table.get("safety_radius", 0.0)
    if isinstance(r, bool) or not isinstance(r, int | float):
        raise MapError(f"{where}: safety_radius must be a number of metres, got {r!r}")
    items = table.get("obstacles", [])
    if not isinstance(items, list):
        raise MapError(f"{where}: obstacles must be a list of tables ([[world.obstacles]])")
    obstacles = []
    for k, item in enumerate(items):
        at = f"{where} obstacle #{k}"
        if not isinstance(item, Mapping):
            raise MapError(f"{at}: must be a table, got {type(item).__name__}")
        kinds = [kind for kind in _KINDS if kind in item]
        if len(kinds) != 1:
            raise MapError(f"{at}: needs exactly one of box, prism, mesh (got {', '.join(sorted(item)) or 'none'})")
        kind = kinds[0]
        allowed = {kind, "z"} if kind == "prism" else {kind}
        extra = sorted(set(item) - allowed)
        if extra:
            raise MapError(
                f"{at}: unknown key(s) {', '.join(extra)} for a {kind} (known: {', '.join(sorted(allowed))})"
            )
        if kind == "box":
            c = _numbers(item["box"], 6, at, "box")
            obstacles.append(box_obstacle(c[:3], c[3:], name=at))
        elif kind == "prism":
            if "z" not in item:
                raise MapError(f"{at}: a prism needs z = [z0, z1]")
            try:
                xy = np.asarray(item["prism"], dtype=float)
            except (TypeError, ValueError):
                raise MapError(f"{at}: prism must be a list of [x, y] points, got {item['prism']!r}") from None
            obstacles.append(prism_obstacle(xy, _numbers(item["z"], 2, at, "z"), name=at))
        else:
            f = item["mesh"]
            if not isinstance(f, str) or not f:
                raise MapError(f"{at}: mesh must be a file name, got {f!r}")
            obstacles.append(mesh_obstacle(Path(base) / f, name=f"{at} (mesh '{f}')"))
    return World3D(obstacles, bounds, float(r))
