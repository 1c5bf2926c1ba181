"""The drone chain's global route in 3-D: the leader's shortest free route, a proven lower bound on any chain's
length, the fewest drones, the refusals, and references for every drone along the route (``formulations/drones.md``,
section "Route (3-D)").

1. **Route.** A lattice of spacing h over the room (h = ``grid``, raised so the lattice keeps at most
   ``MAX_NODES`` nodes); a node is free for a drone if its exact clearance (obstacles and room grown by r) exceeds
   ``ROUTE_MARGIN``. Dijkstra (``scipy.sparse.csgraph``) on the 26-connected lattice with Euclidean edge lengths from
   the node nearest the base whose straight segment from the base keeps the tether clearance c_t, to the node nearest
   the goal seen from it; then the node path is shortened greedily (from each point, the farthest later point whose
   segment keeps clearance > ``ROUTE_MARGIN``, tested exactly with ``World3D.segment_is_free``).
2. **Lower bound.** Every chain that reaches the goal carries a continuous tether curve from the base to the goal
   whose points keep c_t from the obstacles and the floor (the tether limit) and lie in the room: a set F_t. Each
   lattice cube that meets F_t has its 8 corners within √3 h of a point of F_t, so it lies in the union U of the cubes
   whose corners all pass the test "obstacle distance > c_t − √3 h, height above the floor > c_t − √3 h, distance
   to the walls and ceiling > −√3 h". On the corners, Φ = the 26-connected lattice distance to the goal's cube
   (Dijkstra), extended to U linearly on the Kuhn (Freudenthal) simplices of each cube: a continuous piecewise linear
   function whose gradient norm on U is at most Λ, the largest over the simplices of U (computed). Along any curve
   γ ⊂ F_t ⊂ U from the base to a point g' within tol = ``goal_tolerance`` of the goal (where the leader succeeds),
   Φ(base) − Φ(g') ≤ Λ · length(γ) and Φ(g') ≤ Φ_ball (the largest corner value of the cubes meeting the ball, or
   Φ(goal) + Λ·tol when the ball keeps c_t), so

       length(γ) ≥ max(|goal − base| − tol, (Φ(base) − Φ_ball) / Λ, 0) =: ``lower_bound_length``,

   and since every tether's arc is ≤ L_max, N ≥ ``min_robots`` = ⌈lower_bound_length / L_max⌉. If the goal is not in
   the component of U holding the base, no chain reaches it: :class:`NoRouteError` (proven). If U joins them but no
   drone route is found, ``_boxes_disconnected`` tries an exact proof on the box obstacles (the cells of the grid of
   their faces grown by c, no lattice resolution: a window lower than 2c is closed however it lies), then, only when
   the world holds other obstacles, ``_cells_disconnected`` a lattice proof, on a finer lattice (h < c/√3, any plane
   wall) when the route's is too coarse.
3. **References.** :func:`drone_references`: the leader follows the route with a smooth trapezoid in arc length
   (:func:`_cruise_law`); drone j moves along the same route from its start arc to j/N of the route's length, in step
   with the leader's progress, so the chain lies along the route and winds round only what the route winds round.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from tmr.errors import ParameterError, TetherSpanError, TmrError, fmt_point
from tmr.model.catenary3d import DroneTetherParams, solve3d
from tmr.route.geodesic import NoRouteError, TooFewRobotsError
from tmr.world.world3d import Obstacle3D, World3D, _PlacedBox, aabb_gap, box_obstacle

Array = NDArray[np.float64]

__all__ = [
    "KAPPA",
    "MAX_NODES",
    "PROOF_MAX_NODES",
    "PROOF_SPACING",
    "ROUTE_MARGIN",
    "DroneReferences",
    "NoRouteError",
    "Route3D",
    "StartError",
    "TooFewRobotsError",
    "check_drone_count",
    "chain_violations",
    "drone_references",
    "plan_route3d",
]

#: Clearance [m] the route keeps beyond the drone radius r (above the QP's d_safe = 0.02 m).
ROUTE_MARGIN = 0.05
#: Most lattice nodes of a route search; a finer ``grid`` is coarsened to keep the search under 1 s on 2 cores.
MAX_NODES = 100_000
#: The no-route proof's second lattice: spacing PROOF_SPACING · c [m] (< c/√3: any plane wall, however thin and
#: wherever it cuts the lattice, separates the nodes passing the proof's test), at most PROOF_MAX_NODES nodes.
PROOF_SPACING = 0.95 / math.sqrt(3.0)
PROOF_MAX_NODES = 400_000
#: Worst over-estimate of the 26-connected lattice metric over the Euclidean one: a displacement with sorted
#: components a ≥ b ≥ c costs a + (√2 − 1) b + (√3 − √2) c, at most KAPPA times its length.
KAPPA = math.sqrt(1.0 + (math.sqrt(2.0) - 1.0) ** 2 + (math.sqrt(3.0) - math.sqrt(2.0)) ** 2)

_STEPS = np.array([d for d in itertools.product((-1, 0, 1), repeat=3) if d > (0, 0, 0)])  # 13 half-neighbourhood
_PERMS = list(itertools.permutations(range(3)))


class StartError(TmrError):
    """No start placement along the route keeps every limit (the drones, their spacing and every tether)."""


@dataclass
class Route3D:
    """The leader's route and what it proves (units: m).

    Attributes:
        path: (M, 3) the route, base first, goal last (a free polyline: segments after the first keep clearance
            > ``ROUTE_MARGIN`` beyond r; the first, from the ground winch, keeps the tether clearance c_t).
        length: its length [m] (an upper bound on the shortest free route's).
        lower_bound_length: a proven lower bound on the length of any chain's tether curve from base to goal [m].
        min_robots: ⌈lower_bound_length / L_max⌉, the proven fewest drones.
        base, goal: (3,) [m]. grid: the lattice spacing used [m]. tether: the tether parameters.
        euclidean: |goal − base| [m]. grid_bound: (Φ(base) − Φ(goal)) / Λ [m]. lipschitz: Λ [-].
        diagnostics: timings [s], node counts, the route's gap over the bound.
    """

    path: Array
    length: float
    lower_bound_length: float
    min_robots: int
    base: Array
    goal: Array
    grid: float
    tether: DroneTetherParams
    euclidean: float
    grid_bound: float
    lipschitz: float
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def arcs(self) -> Array:
        """Cumulative arc length [m] at each route point, (M,)."""
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.path, axis=0), axis=1))])

    def point_at(self, s: ArrayLike) -> Array:
        """Route points at arc lengths ``s`` [m] (clipped to [0, length]), shape ``s.shape + (3,)``."""
        return _point_at(self.path, self.arcs, s)


def _point_at(path: Array, arcs: Array, s: ArrayLike) -> Array:
    s_ = np.clip(np.asarray(s, dtype=float), 0.0, arcs[-1])
    return np.stack([np.interp(s_, arcs, path[:, k]) for k in range(3)], axis=-1)


def _tangent_at(path: Array, arcs: Array, s: ArrayLike) -> Array:
    """Unit tangent of the polyline at arc lengths s (the segment's; the last segment's at the end)."""
    seg = np.diff(path, axis=0)
    lens = np.linalg.norm(seg, axis=1)
    unit = seg / np.maximum(lens, 1e-12)[:, None]
    i = np.clip(np.searchsorted(arcs, np.asarray(s, dtype=float), side="right") - 1, 0, len(seg) - 1)
    return unit[i]


# ----------------------------------------------------------------------------------------------------------------
# the lattice
# ----------------------------------------------------------------------------------------------------------------
@dataclass
class _Lattice:
    origin: Array
    h: float
    shape: tuple[int, int, int]

    @property
    def n(self) -> int:
        return int(np.prod(self.shape))

    def nodes(self) -> Array:
        ii = np.indices(self.shape).reshape(3, -1).T
        return self.origin + self.h * ii

    def cell(self, p: Array) -> NDArray[np.int64]:
        """Index (3,) of the lattice cube holding p (its lowest corner)."""
        c = np.floor((np.asarray(p) - self.origin) / self.h).astype(np.int64)
        return np.clip(c, 0, np.array(self.shape) - 2)

    def flat(self, ijk: NDArray[np.int64]) -> NDArray[np.int64]:
        return np.ravel_multi_index(tuple(np.asarray(ijk).T), self.shape)


def _lattice(bounds: Array, grid: float, max_nodes: int = MAX_NODES) -> _Lattice:
    lo, hi = bounds[:3], bounds[3:]
    h = max(float(grid), float((np.prod(hi - lo) / max_nodes) ** (1.0 / 3.0)))
    for _ in range(50):  # one cube beyond the room on each side, at most max_nodes nodes
        shape = tuple(int(math.ceil((hi[k] - lo[k]) / h)) + 3 for k in range(3))
        if np.prod(shape) <= max_nodes:
            break
        h *= 1.05
    return _Lattice(lo - h, h, shape)  # type: ignore[arg-type]


def _graph(lat: _Lattice, ok: NDArray[np.bool_]) -> Any:
    """The 26-connected lattice graph on the nodes ``ok`` (flat (n,)), edge weights the Euclidean lengths [m]: a
    symmetric CSR matrix built row by row (each row's columns ascending, as ``coo_matrix.tocsr`` leaves them)."""
    shape = np.array(lat.shape)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    dirs = np.array(sorted((d for d in itertools.product((-1, 0, 1), repeat=3) if any(d)), key=lambda d: d @ strides))
    offs = dirs @ strides  # ascending: the columns of a row in order
    weights = np.array([lat.h * float(np.linalg.norm(d)) for d in dirs])
    padded = np.zeros(shape + 2, dtype=bool)  # a border of False: no neighbour off the lattice
    padded[1:-1, 1:-1, 1:-1] = ok.reshape(lat.shape)
    pflat = padded.reshape(-1)
    pstrides = np.array([(shape[1] + 2) * (shape[2] + 2), shape[2] + 2, 1])
    rows = np.flatnonzero(ok).astype(np.int32)
    prow = (np.stack(np.unravel_index(rows, lat.shape), axis=1) + 1) @ pstrides  # the same nodes in ``padded``
    valid = np.empty((len(rows), len(dirs)), dtype=bool)
    for k, po in enumerate(dirs @ pstrides):
        valid[:, k] = pflat[prow + po]
    counts = valid.sum(axis=1)
    indptr = np.zeros(lat.n + 1, dtype=np.int32)
    indptr[rows + 1] = counts
    np.cumsum(indptr, out=indptr)
    cols = np.repeat(rows, counts) + np.broadcast_to(offs.astype(np.int32), valid.shape)[valid]
    data = np.broadcast_to(weights, valid.shape)[valid]
    return csr_matrix((data, cols, indptr), shape=(lat.n, lat.n))


def _obstacle_distance(world: World3D, pts: Array, cap: float) -> Array:
    """Signed distance [m] of points (n, 3) to the obstacles only (no room, no radius), exact where below ``cap``,
    else ``cap`` (a value ≥ cap means "at least cap")."""
    out = np.full(len(pts), cap)
    lo, hi = np.asarray(world.bounds[:3]), np.asarray(world.bounds[3:])
    span = float(np.max(hi - lo)) + 10.0 * cap + 10.0
    for ob in world.obstacles:  # one at a time: inside an overlap, the deepest single depth
        gap = aabb_gap(ob.lo, ob.hi, pts, pts)
        near = np.flatnonzero(gap < cap)
        if not len(near):
            continue
        if isinstance(ob.geometry, _PlacedBox):  # the box's signed distance in closed form (as coal's sphere-box)
            p = pts[near]
            inside = np.minimum(np.min(p - ob.lo, axis=1), np.min(ob.hi - p, axis=1))
            d = np.where(inside > 0.0, -inside, gap[near])
        else:
            footprint = _vertical_prism(ob)
            if footprint is not None:
                d = _prism_distance(footprint, float(ob.lo[2]), float(ob.hi[2]), pts[near])
            else:
                alone = World3D([ob], np.r_[lo - span, hi + span], 0.0)  # the walls far away: this obstacle only
                d = alone.exact_clearance(pts[near])
        out[near] = np.minimum(out[near], d)
    return out


def _vertical_prism(ob: Obstacle3D) -> Any:
    """The footprint (a shapely Polygon) of a convex obstacle that is a vertical prism (every hull point at its
    lowest or highest z, the same xy at both), else None."""
    if ob.triangles is not None or not hasattr(ob.geometry, "points"):
        return None
    pts = np.asarray(ob.geometry.points(), dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 6:
        return None
    low, high = np.isclose(pts[:, 2], ob.lo[2], atol=1e-12), np.isclose(pts[:, 2], ob.hi[2], atol=1e-12)
    if not np.all(low | high):
        return None
    a, b = np.unique(np.round(pts[low, :2], 12), axis=0), np.unique(np.round(pts[high, :2], 12), axis=0)
    if a.shape != b.shape or not np.array_equal(a, b):
        return None
    return shapely.MultiPoint(a).convex_hull


def _prism_distance(footprint: Any, z0: float, z1: float, pts: Array) -> Array:
    """Signed distance [m] of points (n, 3) to the vertical prism footprint × [z0, z1] (< 0 inside): outside,
    √(d_xy² + d_z²) with d_xy the planar distance to the footprint (shapely) and d_z to [z0, z1]; inside, minus the
    smallest of the depth in plan (the distance to the footprint's boundary) and to the two caps."""
    xy = shapely.points(pts[:, :2])
    dxy = shapely.distance(footprint, xy)
    dz = np.maximum(0.0, np.maximum(z0 - pts[:, 2], pts[:, 2] - z1))
    out = np.sqrt(dxy**2 + dz**2)
    inside = (dxy == 0.0) & (dz == 0.0)
    if inside.any():
        depth = shapely.distance(footprint.exterior, xy[inside])
        p = pts[inside]
        out[inside] = -np.minimum(depth, np.minimum(p[:, 2] - z0, z1 - p[:, 2]))
    return out


def _components26(mask: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Labels (flat) of the 26-connected components of a 3-D mask (0 outside it): ``scipy.ndimage.label`` with the
    full 3 × 3 × 3 structure, the same components as the 26-connected lattice graph (imported here: only the
    no-route proofs need it)."""
    from scipy import ndimage

    labels, _ = ndimage.label(mask, structure=np.ones((3, 3, 3), dtype=bool))
    return np.asarray(labels).reshape(-1)


def _cells_disconnected(world: World3D, lat: _Lattice, nodes: Array, b: Array, g: Array, c: float) -> bool:
    """A proof that no curve keeping ``c`` [m] from the obstacles and the room's walls, floor and ceiling joins ``b``
    to ``g`` (True), or none (False).

    The lattice's cubes (side h, one per node) cover the room; a curve passes through a 26-connected sequence of
    them, and every cube it meets holds a curve point p within ρ = h√3/2 of the cube's node q. Such a p lies in the
    room shrunk by c (a box R'), so the projection q' of q on R' is at most as far from p as q is (R' is convex):
    |q − q'| ≤ ρ and, the distance to the obstacles being 1-Lipschitz, d(q') ≥ c − ρ. The nodes passing both tests
    hold every cube such a curve meets; if the cubes of b and g are in different 26-connected components of them,
    no such curve exists. Unlike the bound's enlarged space (slack √3 h on each distance alone), the projection sees
    an obstacle and a wall together: a wall across the room, touching its walls, blocks the proof's space too."""
    if c <= 0.0:
        return False
    rho = 0.5 * math.sqrt(3.0) * lat.h
    bounds = np.asarray(world.bounds, dtype=float)
    lo, hi = bounds[:3] + c, bounds[3:] - c
    if np.any(lo > hi):
        return False
    q = np.clip(nodes, lo, hi)
    near = np.linalg.norm(nodes - q, axis=1) <= rho
    ok = near.copy()
    ok[near] = _obstacle_distance(world, q[near], cap=c + 0.01) >= c - rho
    top = np.array(lat.shape) - 1

    def node(p: Array) -> int:  # the node whose cube (centred on it) holds p
        return int(lat.flat(np.clip(np.rint((p - lat.origin) / lat.h).astype(np.int64), 0, top)))

    nb, ng = node(b), node(g)
    if not (ok[nb] and ok[ng]):
        return not ok[ng] if ok[nb] else False  # b's own cube always holds b: a failed test there proves nothing
    labels = _components26(ok.reshape(lat.shape))
    return bool(labels[nb] != labels[ng])


def _boxes_disconnected(world: World3D, b: Array, g: Array, c: float) -> bool:
    """An exact proof, at no lattice resolution, that no curve keeping ``c`` [m] from the obstacles and the room's
    walls, floor and ceiling joins ``b`` to ``g`` (True), or none (False). Needs b and g ≥ c (+ 1 µm) from everything.

    Only the axis-aligned boxes are used; the other obstacles are left out, which only enlarges the free set (so a
    separation found without them holds with them). Every point within distance < c of a box B lies outside F_c, the
    set of points ≥ c from everything; so do the points of these closed boxes, each inside B's open c-neighbourhood
    (c' = c − ε, ε = 1 µm): B grown by c' along one axis (3 face slabs), by c'/√2 along two axes (3 edge bars) and by
    c'/√3 along all three (the corner block). Let S = the room shrunk by c, less those boxes: F_c ⊂ S. The box faces
    and the shrunk room's cut S into the cells of a rectilinear grid; each cell's interior lies inside one removed
    box or meets none. S is relatively open in the shrunk room, so a point p of S has a neighbourhood in S, every
    cell whose closure holds p is free, and those cells are 26-neighbours on the grid: a curve in S passes through a
    26-connected sequence of free cells. If the cells holding b and g are in different 26-connected components, no
    curve in S, hence in F_c, joins them. Exact for walls and openings (a window lower than 2c is closed however the
    wall lies); it misses only the rounded parts of the c-neighbourhoods beyond the edge and corner blocks (points
    farther than c/√3 from a box), which a narrow diagonal pinch between two boxes' edges may need."""
    if c <= 0.0:
        return False
    bounds = np.asarray(world.bounds, dtype=float)
    lo_r, hi_r = bounds[:3] + c, bounds[3:] - c
    if np.any(lo_r >= hi_r):
        return False
    cc = c - 1e-6
    grow = []  # (lo, hi) of the removed boxes
    for ob in world.obstacles:
        if not isinstance(ob.geometry, _PlacedBox):
            continue
        for k in range(3):  # the face slabs
            d = np.zeros(3)
            d[k] = cc
            grow.append((ob.lo - d, ob.hi + d))
        e = cc / math.sqrt(2.0)
        for k in range(3):  # the edge bars, along axis k
            d = np.full(3, e)
            d[k] = 0.0
            grow.append((ob.lo - d, ob.hi + d))
        grow.append((ob.lo - cc / math.sqrt(3.0), ob.hi + cc / math.sqrt(3.0)))
    if not grow:
        return False
    los = np.array([x[0] for x in grow])
    his = np.array([x[1] for x in grow])
    axes = [np.unique(np.clip(np.r_[lo_r[k], hi_r[k], los[:, k], his[:, k]], lo_r[k], hi_r[k])) for k in range(3)]
    shape = tuple(len(a) - 1 for a in axes)
    free = np.ones(shape, dtype=bool)
    for blo, bhi in zip(los, his, strict=True):
        i0 = [int(np.searchsorted(axes[k], blo[k], side="left")) for k in range(3)]
        i1 = [int(np.searchsorted(axes[k], bhi[k], side="right")) - 1 for k in range(3)]
        if all(i1[k] > i0[k] for k in range(3)):  # the cells between the box's own coordinates
            free[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]] = False

    def cell(p: Array) -> int:  # a cell whose closure holds p (p in the shrunk room)
        ijk = [int(np.clip(np.searchsorted(axes[k], p[k], side="right") - 1, 0, shape[k] - 1)) for k in range(3)]
        return int(np.ravel_multi_index(tuple(ijk), shape))

    if np.any(b < lo_r) or np.any(b > hi_r) or np.any(g < lo_r) or np.any(g > hi_r):
        return False
    nb, ng = cell(b), cell(g)
    flat = free.reshape(-1)
    if not (flat[nb] and flat[ng]):
        return False
    labels = _components26(free)
    return bool(labels[nb] != labels[ng])


def _wall_distance(bounds: Array, pts: Array) -> tuple[Array, Array]:
    """(distance to the floor, distance to the four walls and the ceiling) [m], > 0 inside the room."""
    lo, hi = bounds[:3], bounds[3:]
    floor = pts[:, 2] - lo[2]
    side = np.min(np.concatenate([pts[:, :2] - lo[:2], hi - pts], axis=1), axis=1)
    return floor, side


# ----------------------------------------------------------------------------------------------------------------
# the lower bound: a piecewise linear potential on the Kuhn simplices
# ----------------------------------------------------------------------------------------------------------------
def _lipschitz(phi: Array, lat: _Lattice) -> tuple[float, NDArray[np.bool_]]:
    """Largest gradient norm Λ [-] of the Kuhn-simplex interpolant of ``phi`` (flat, inf outside) over the cubes
    whose 8 corners are finite, and the mask of those cubes (shape - 1)."""
    P = phi.reshape(lat.shape)
    nx, ny, nz = (s - 1 for s in lat.shape)

    def corner(o: tuple[int, int, int]) -> Array:
        return P[o[0] : o[0] + nx, o[1] : o[1] + ny, o[2] : o[2] + nz]

    corners = {o: corner(o) for o in itertools.product((0, 1), repeat=3)}
    good = np.ones((nx, ny, nz), dtype=bool)
    for v in corners.values():
        good &= np.isfinite(v)
    if not good.any():
        return 1.0, good
    lam = 0.0
    for perm in _PERMS:
        v = [0, 0, 0]
        prev = corners[(0, 0, 0)][good]
        g2 = np.zeros_like(prev)
        for axis in perm:
            v[axis] = 1
            cur = corners[(v[0], v[1], v[2])][good]
            g2 += (cur - prev) ** 2
            prev = cur
        lam = max(lam, float(np.sqrt(g2.max())) / lat.h)
    return max(lam, 1e-12), good


def _interp(phi: Array, lat: _Lattice, p: Array) -> float:
    """The Kuhn-simplex interpolant of ``phi`` at p (inf if a corner of its simplex is inf)."""
    c = lat.cell(p)
    f = np.clip((p - (lat.origin + lat.h * c)) / lat.h, 0.0, 1.0)
    order = np.argsort(-f, kind="stable")
    v = c.copy()
    val = float(phi[lat.flat(v)])
    for axis in order:
        nxt = v.copy()
        nxt[axis] += 1
        val += f[axis] * (float(phi[lat.flat(nxt)]) - float(phi[lat.flat(v)]))
        v = nxt
    return val


def _ball_max(phi: Array, lat: _Lattice, g: Array, tol: float) -> float:
    """An upper bound of the Kuhn-simplex interpolant of ``phi`` on U ∩ B(g, tol): the largest finite value at the
    corners of the cubes meeting the box [g − tol, g + tol] (on a cube of U the interpolant is a convex combination
    of its corners, all finite)."""
    top = np.array(lat.shape) - 2
    lo = np.clip(np.floor((g - tol - lat.origin) / lat.h).astype(np.int64), 0, top)
    hi = np.clip(np.floor((g + tol - lat.origin) / lat.h).astype(np.int64), 0, top) + 1
    ii = np.indices(tuple(hi - lo + 1)).reshape(3, -1).T + lo
    vals = phi[lat.flat(ii)]
    vals = vals[np.isfinite(vals)]
    return float(vals.max()) if len(vals) else math.inf


# ----------------------------------------------------------------------------------------------------------------
# the route
# ----------------------------------------------------------------------------------------------------------------
def _attach(
    world: World3D, lat: _Lattice, free: NDArray[np.bool_], p: Array, radius: float, what: str, margin: float = 0.0
) -> int:
    """The free node nearest p whose segment from p keeps clearance > ``margin`` in ``world`` with safety radius
    ``radius``. None found: :class:`NoRouteError` with ``proven = False`` (a lattice verdict, exit 1)."""
    c = lat.cell(p)
    w = world.with_safety_radius(radius)
    for reach in (2, 4, 8):
        lo = np.maximum(c - reach + 1, 0)
        hi = np.minimum(c + reach + 1, np.array(lat.shape) - 1)
        ii = np.indices(tuple(hi - lo + 1)).reshape(3, -1).T + lo
        flat = lat.flat(ii)
        ok = free[flat]
        if not ok.any():
            continue
        flat, ii = flat[ok], ii[ok]
        pts = lat.origin + lat.h * ii
        order = np.argsort(np.linalg.norm(pts - p, axis=1), kind="stable")[:64]
        seen = w.segment_is_free(np.broadcast_to(p, (len(order), 3)), pts[order], margin)
        if seen.any():
            return int(flat[order[int(np.argmax(seen))]])
    err = NoRouteError(
        f"no free lattice node for a drone reachable from the {what} {fmt_point(p)} on a {lat.h:.3f} m lattice "
        "(not proven: a finer grid may find one)"
    )
    err.proven = False
    raise err


def _shorten(world: World3D, path: Array, margin: float) -> Array:
    """Greedy shortcut: from each kept point the farthest later point whose segment keeps clearance > margin."""
    out = [path[0]]
    i = 0
    while i < len(path) - 1:
        cand = np.arange(len(path) - 1, i, -1)
        ok = world.segment_is_free(np.broadcast_to(path[i], (len(cand), 3)), path[cand], margin)
        j = int(cand[int(np.argmax(ok))]) if ok.any() else i + 1
        out.append(path[j])
        i = j
    return np.asarray(out)


def plan_route3d(
    world: World3D,
    base: ArrayLike,
    goal: ArrayLike,
    tether: DroneTetherParams,
    *,
    grid: float = 0.25,
    goal_tolerance: float = 0.1,
) -> Route3D:
    """The leader's shortest free route from the ground winch ``base`` to ``goal`` and the proven lower bound.

    Args:
        world: the room and obstacles; ``world.safety_radius`` is the drone radius r [m].
        base: the anchor (3,) [m] (the loader checks it keeps c_t from obstacles, walls and floor).
        goal: the leader's goal (3,) [m] (free for a drone).
        tether: tether parameters (c_t = ``clearance``, L_max = ``tether_length``).
        grid: lattice spacing h [m] (> 0); raised to keep at most ``MAX_NODES`` nodes.
        goal_tolerance: the leader succeeds anywhere within this distance of ``goal`` [m] (``DroneParams.
            goal_tolerance``): the bound is on curves from the base to that ball (module doc).

    Raises:
        NoRouteError: no chain can reach the goal (proven, exit 2: the goal is outside the component of U holding the
            base, module doc), or none was found for a drone at this lattice (``proven = False``, exit 1).
        ParameterError: bad points or grid.
    """
    t0 = time.perf_counter()
    b = np.asarray(base, dtype=float).reshape(-1)
    g = np.asarray(goal, dtype=float).reshape(-1)
    if b.shape != (3,) or g.shape != (3,) or not np.all(np.isfinite(np.r_[b, g])):
        raise ParameterError(f"base and goal must be finite 3-D points, got {base!r} and {goal!r}")
    if not (isinstance(grid, int | float) and math.isfinite(grid) and grid > 0):
        raise ParameterError(f"the route grid must be a number > 0 m, got {grid!r}")
    tol = goal_tolerance
    if isinstance(tol, bool) or not (isinstance(tol, int | float) and math.isfinite(tol) and tol >= 0):
        raise ParameterError(f"the goal tolerance must be a number >= 0 m, got {goal_tolerance!r}")
    tol = float(tol)
    bounds = np.asarray(world.bounds, dtype=float)
    r, c_t = world.safety_radius, tether.clearance
    lat = _lattice(bounds, grid)
    h = lat.h
    nodes = lat.nodes()
    slack = math.sqrt(3.0) * h
    cap = max(r + ROUTE_MARGIN, c_t) + 0.01  # the tests below need no more
    obst = _obstacle_distance(world, nodes, cap=cap)
    floor, side = _wall_distance(bounds, nodes)
    t_field = time.perf_counter()

    # the lower bound (and the proof of no route) on U. Boxes standing on the floor are extended below it (they then
    # lie in obstacles ∪ {z < zmin}, so a point c_t from both is c_t from them): a node on the floor under a box is
    # then inside it, not on its surface
    zmin = bounds[2]
    if any(isinstance(ob.geometry, _PlacedBox) and ob.lo[2] <= zmin for ob in world.obstacles):
        deep = [
            box_obstacle(np.r_[ob.lo[:2], zmin - 10.0], ob.hi, ob.name)
            if isinstance(ob.geometry, _PlacedBox) and ob.lo[2] <= zmin
            else ob
            for ob in world.obstacles
        ]
        obst_u = _obstacle_distance(World3D(deep, bounds, 0.0), nodes, cap=cap)
    else:
        obst_u = obst
    in_u = (obst_u > c_t - slack) & (floor > c_t - slack) & (side > -slack)
    gu = _graph(lat, in_u)
    goal_node = int(lat.flat(lat.cell(g)))
    phi = dijkstra(gu, directed=True, indices=goal_node)  # gu holds both directions
    phi[~in_u] = np.inf
    lam, _ = _lipschitz(phi, lat)
    phi_b, phi_g = _interp(phi, lat, b), _interp(phi, lat, g)
    # the leader succeeds anywhere in the ball B(g, tol): if the ball keeps c_t from everything (bare clearance of g
    # >= c_t + tol) it lies in F_t, so a curve reaching it extends to g inside F_t, and the proofs about g hold for it
    bare_g = float(world.with_safety_radius(0.0).exact_clearance(g[None, :])[0])
    ball_in_ft = bare_g - tol >= c_t
    if not math.isfinite(phi_b):
        err = NoRouteError(
            f"the goal {fmt_point(g)} cannot be reached from the base {fmt_point(b)}: no curve keeping the tether "
            f"clearance {c_t:.3f} m from the obstacles and the floor joins them"
        )
        err.proven = ball_in_ft
        raise err
    euclid = float(np.linalg.norm(g - b))
    # a curve ending at g' in the ball: Φ(base) − Φ(g') ≤ Λ·length, with Φ(g') ≤ the largest corner value of the
    # cubes meeting the ball, or ≤ Φ(g) + Λ·tol when the segment g'–g lies in U (the ball in F_t)
    grid_bound = max(0.0, (phi_b - _ball_max(phi, lat, g, tol)) / lam)
    if ball_in_ft:
        grid_bound = max(grid_bound, (phi_b - phi_g) / lam - tol)
    lower = max(euclid - tol, grid_bound, 0.0)
    t_bound = time.perf_counter()

    # the leader's route on the drones' free nodes
    free = (np.minimum(obst, side) - r > ROUTE_MARGIN) & (floor - r > ROUTE_MARGIN)  # a subset of U
    start = _attach(world, lat, free, b, c_t, "base", margin=-1e-9)  # the winch may sit exactly c_t from the floor
    end = _attach(world, lat, free, g, r, "goal")
    keep = np.flatnonzero(free)
    local = np.full(lat.n, -1)
    local[keep] = np.arange(len(keep))
    gr = gu[keep][:, keep]  # U's graph restricted to the drones' free nodes
    dist_l, pred_l = dijkstra(gr, directed=True, indices=int(local[start]), return_predecessors=True)
    dist = np.full(lat.n, np.inf)
    dist[keep] = dist_l
    pred = np.full(lat.n, -9999)
    pred[keep] = np.where(pred_l >= 0, keep[np.maximum(pred_l, 0)], -9999)
    if not math.isfinite(dist[end]):
        c = min(c_t, r, float(world.with_safety_radius(0.0).exact_clearance(b[None, :])[0]) - 0.002)
        # the exact proof on the boxes first (milliseconds); the lattice proofs only for the other obstacles (with
        # boxes alone they could only add a pinch between two boxes' edges or corners, at 0.6-1.2 s)
        lattice_proofs = not all(isinstance(ob.geometry, _PlacedBox) for ob in world.obstacles)
        proven = bare_g - tol >= c and (
            _boxes_disconnected(world, b, g, c) or (lattice_proofs and _cells_disconnected(world, lat, nodes, b, g, c))
        )
        if not proven and lattice_proofs and bare_g - tol >= c and c > 0.0 and h >= PROOF_SPACING * c:
            # the lattice may straddle a thin wall (ρ = h√3/2 against c): once more on a lattice fine enough to see
            # any plane wall, h < c/√3 (formulations/drones.md), within PROOF_MAX_NODES
            fine = _lattice(bounds, PROOF_SPACING * c, max_nodes=PROOF_MAX_NODES)
            if fine.h < h:
                proven = _cells_disconnected(world, fine, fine.nodes(), b, g, c)
        if proven:
            raise NoRouteError(
                f"the goal {fmt_point(g)} cannot be reached from the base {fmt_point(b)}: no curve keeping "
                f"{c:.3f} m from the obstacles, the walls, the floor and the ceiling joins them (the tethers keep "
                f"c_t = {c_t:.3f} m, the drones r = {r:.3f} m)"
            )
        err = NoRouteError(
            f"no free route for a drone (radius {r:.3f} m) from the base {fmt_point(b)} to the goal {fmt_point(g)} "
            f"on a {h:.3f} m lattice"
        )
        err.proven = False
        raise err
    chain = [end]
    while chain[-1] != start:
        chain.append(int(pred[chain[-1]]))
    node_path = nodes[np.asarray(chain[::-1])]
    path = np.vstack([b, node_path, g])
    path = np.vstack([path[:2], _shorten(world, path[1:], ROUTE_MARGIN)])  # the winch leg stays as attached
    keep = np.r_[True, np.linalg.norm(np.diff(path, axis=0), axis=1) > 1e-9]
    path = path[keep]
    length = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    if lower > length + 1e-9:  # the route is a free curve the bound covers: a bound above it is a bug in the proof
        raise AssertionError(
            f"internal error: the proven lower bound {lower:.6f} m exceeds the route found, {length:.6f} m "
            f"(straight {euclid:.6f} m, grid {grid_bound:.6f} m, Λ = {lam:.6f}, h = {h:.4f} m)"
        )
    n_min = max(1, int(math.ceil(lower / tether.tether_length - 1e-9)))
    t_end = time.perf_counter()
    return Route3D(
        path=path,
        length=length,
        lower_bound_length=lower,
        min_robots=n_min,
        base=b,
        goal=g,
        grid=h,
        tether=tether,
        euclidean=euclid,
        grid_bound=grid_bound,
        lipschitz=lam,
        diagnostics={
            "nodes": lat.n,
            "free_nodes": int(free.sum()),
            "bound_nodes": int(in_u.sum()),
            "grid_length": float(dist[end]),
            "gap": length / lower - 1.0 if lower > 0 else 0.0,
            "time_field": t_field - t0,
            "time_bound": t_bound - t_field,
            "time_route": t_end - t_bound,
            "time": t_end - t0,
        },
    )


def check_drone_count(route: Route3D, n: int) -> None:
    """Refuse ``n`` drones below the proven fewest: :class:`TooFewRobotsError` (proven, exit 2) with the numbers."""
    if n < route.min_robots:
        L = route.tether.tether_length
        raise TooFewRobotsError(
            f"{n} drone{'s' if n != 1 else ''} cannot reach the goal {fmt_point(route.goal)}: any chain's tethers run "
            f"at least {route.lower_bound_length:.3f} m from the base {fmt_point(route.base)}, more than {n} x "
            f"{L:.3f} m of tether; the fewest is {route.min_robots}",
            route.min_robots,
            proven=True,
        )


# ----------------------------------------------------------------------------------------------------------------
# references
# ----------------------------------------------------------------------------------------------------------------
@dataclass
class DroneReferences:
    """References of every drone along the route (units: m, s).

    Attributes:
        t: times (K+1,) [s], step Ts.
        x, xd: the leader's reference position and velocity (K+1, 3).
        positions, velocities: every drone's reference (K+1, N, 3), drone N the leader (``positions[:, -1] == x``).
        arcs: each drone's arc length along the route (K+1, N) [m].
        start_positions: (N, 3) a start keeping every limit (:func:`chain_violations` is empty for it).
        final_positions: (N, 3) where the references end (drone j at j/N of the route, the leader at the goal).
        route: the route.
        diagnostics: ``final_violations`` (list of messages for the end placement; the per-step planner may need to
            move off the route to keep the tether limits there), ``start_arcs``.
    """

    t: Array
    x: Array
    xd: Array
    positions: Array
    velocities: Array
    arcs: Array
    start_positions: Array
    final_positions: Array
    route: Route3D
    diagnostics: dict[str, Any] = field(default_factory=dict)


def chain_violations(
    world: World3D,
    base: Array,
    positions: Array,
    tether: DroneTetherParams,
    *,
    d_safe: float = 0.02,
    separation_margin: float = 0.05,
    samples: int = 64,
) -> list[str]:
    """Every limit a chain placement violates, one message each (empty: valid): drone clearance > d_safe beyond r,
    drones ≥ 2r + margin apart, every tether's catenary (``solve3d``) solvable, arc ≤ L_max, drone-end tensions ≤
    spare thrust, the whole curve ≥ c_t from the obstacles (``samples`` points at arc spacing Δ and the bound
    (d_k + d_{k+1} − Δ)/2 between neighbours) and the floor (the catenary's lowest point, exactly), inside the room."""
    out: list[str] = []
    P = np.asarray(positions, dtype=float)
    r = world.safety_radius
    clear = world.exact_clearance(P)
    for j, (p, c) in enumerate(zip(P, clear, strict=True)):
        if not c > d_safe:
            out.append(f"drone {j + 1} at {fmt_point(p)} has clearance {c:.3f} m beyond its radius (< {d_safe:.3f})")
    for i in range(len(P)):
        for j in range(i + 1, len(P)):
            gap = float(np.linalg.norm(P[i] - P[j]))
            if gap < 2 * r + separation_margin:
                out.append(f"drones {i + 1} and {j + 1} are {gap:.3f} m apart (< {2 * r + separation_margin:.3f})")
    ends = np.vstack([base, P])
    for j in range(len(P)):
        try:
            cat = solve3d(ends[j], ends[j + 1], tether)
        except (TetherSpanError, ParameterError) as exc:
            out.append(f"tether {j + 1}: {exc}")
            continue
        if cat.length > tether.tether_length:
            out.append(f"tether {j + 1} is {cat.length:.3f} m long (> L_max {tether.tether_length:.3f} m)")
        for t_end, is_drone in ((cat.tension_p, j > 0), (cat.tension_q, True)):
            if is_drone and t_end > tether.spare_thrust:
                out.append(f"tether {j + 1} pulls a drone with {t_end:.3f} N (> {tether.spare_thrust:.3f} N)")
        pts = cat.points(samples)
        spacing = cat.length / (samples - 1)
        obst = _obstacle_distance(world, pts, cap=tether.clearance + spacing + 1.0)
        # between samples k and k+1 (arc spacing Δ) the 1-Lipschitz obstacle distance is at least
        # max(d_k − s, d_{k+1} − (Δ − s)) ≥ (d_k + d_{k+1} − Δ)/2 (never below min(d_k, d_{k+1}) − Δ/2)
        pair = np.minimum(np.minimum(obst[:-1], obst[1:]), 0.5 * (obst[:-1] + obst[1:] - spacing))
        i = int(np.argmin(pair))
        at = pts[i] if obst[i] <= obst[i + 1] else pts[i + 1]
        worst = float(pair[i])
        # the floor exactly: the lowest point of the catenary (the vertex, or the lower end); a base exactly c_t above
        # the floor keeps c_t. The walls and the ceiling: a catenary is a segment in plan and convex in height, so
        # its end samples are its extremes there
        floor_gap = float(cat.lowest[2] - world.bounds[2])
        if floor_gap < worst:
            worst, at = floor_gap, cat.lowest
        _, side = _wall_distance(np.asarray(world.bounds, dtype=float), pts)
        if worst < tether.clearance or side.min() < 0.0:
            out.append(
                f"tether {j + 1} passes {max(worst, 0.0):.3f} m from an obstacle or the floor at "
                f"{fmt_point(at)} (< c_t {tether.clearance:.3f} m)"
            )
    return out


def _cruise_law(ds: float, speed: float, accel: float, Ts: float) -> tuple[Array, Array, int]:
    """The leader's progress along ``ds`` [m] of route: a smooth trapezoid, sampled every ``Ts`` [s].

    The speed rises from rest to the cruise speed V over a ramp of T_r = 1.5 V / ``accel`` s with the smoothstep
    v = V (3τ² − 2τ³), τ = t / T_r (acceleration 6 V τ (1 − τ) / T_r: continuous, zero at both ends of the ramp, peak
    1.5 V / T_r = ``accel``), cruises at V, and falls back to rest by the mirror ramp; each ramp covers V T_r / 2, so
    the travel time is ds / V + T_r. V = ``speed`` if the route is long enough for both ramps (ds ≥ V T_r), otherwise
    V = √(ds · accel / 1.5) (no cruise). Against the quintic minimum-jerk law over the whole route (peak speed
    1.875 ds / T, mean speed about half the peak), a long route takes ≈ 1.9× fewer steps at the same peak speed.

    Returns the fraction φ_k ∈ [0, 1] of ``ds`` covered and its rate φ̇_k [1/s] at t_k = k Ts for k = 0..K, and K
    (the last sample is the first at or after the end of the move: φ = 1, φ̇ = 0 there).
    """
    if ds <= 0.0:
        return np.ones(1), np.zeros(1), 0
    V = min(float(speed), math.sqrt(ds * accel / 1.5))
    Tr = 1.5 * V / accel
    Tc = max(0.0, ds / V - Tr)
    T = 2.0 * Tr + Tc
    K = int(math.ceil(T / Ts - 1e-9))
    t = Ts * np.arange(K + 1)

    def ramp(tt: Array) -> tuple[Array, Array]:  # distance [m] and speed [m/s] of the rising ramp at tt ∈ [0, T_r]
        tau = np.clip(tt / Tr, 0.0, 1.0)
        return V * Tr * (tau**3 - 0.5 * tau**4), V * (3.0 * tau**2 - 2.0 * tau**3)

    s_up, v_up = ramp(t)
    s_dn, v_dn = ramp(T - t)
    half = V * Tr / 2.0
    s = np.where(t <= Tr, s_up, np.where(t < Tr + Tc, half + V * (t - Tr), ds - s_dn))
    v = np.where(t <= Tr, v_up, np.where(t < Tr + Tc, V, v_dn))
    s[-1], v[-1] = ds, 0.0
    return np.clip(s / ds, 0.0, 1.0), np.where(t < T, v, 0.0) / ds, K


def drone_references(
    route: Route3D,
    n: int,
    *,
    Ts: float = 0.05,
    speed: float = 1.0,
    accel: float = 1.0,
    settle: float = 2.0,
    world: World3D,
    d_safe: float = 0.02,
    separation_margin: float = 0.05,
) -> DroneReferences:
    """References for ``n`` drones along ``route`` and a verified start.

    Start: drone 1 at the first route point free for a drone (beyond the winch leg), drone j + 1 a spacing
    2r + margin + 0.1 m further along the route; if a limit fails (:func:`chain_violations`) the whole placement slides
    along the route in 0.1 m steps (up to a third of the route). The leader then follows the route from its start arc
    to the goal with a smooth trapezoid (:func:`_cruise_law`: cruise ≤ ``speed`` [m/s], acceleration ≤ ``accel``
    [m/s²]), then holds for ``settle`` [s]; drone j moves along the route from its start arc to j/N of the route's
    length in proportion to the leader's progress (its share of the leader's arc length).

    Raises:
        StartError: no valid start found (one line with the first violation).
        ParameterError: n < 1 or bad times.
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ParameterError(f"the number of drones must be an integer >= 1, got {n!r}")
    for nm, v in (("Ts", Ts), ("speed", speed), ("accel", accel)):
        if not (math.isfinite(v) and v > 0):
            raise ParameterError(f"{nm} must be a number > 0, got {v!r}")
    if not (math.isfinite(settle) and settle >= 0):
        raise ParameterError(f"settle must be a number >= 0 s, got {settle!r}")
    tether = route.tether
    path, arcs = route.path, route.arcs
    L = float(arcs[-1])
    r = world.safety_radius
    spacing = 2.0 * r + separation_margin + 0.1
    s_first = float(arcs[1]) if len(arcs) > 2 else 0.0  # the end of the winch leg: the first point free for a drone
    first_error = ""
    start_arcs = None
    for shift in np.arange(0.0, max(L / 3.0, 0.1), 0.1):
        sa = s_first + shift + spacing * np.arange(n)
        if sa[-1] > L:
            break
        P = _point_at(path, arcs, sa)
        bad = chain_violations(world, route.base, P, tether, d_safe=d_safe, separation_margin=separation_margin)
        if not bad:
            start_arcs = sa
            break
        first_error = first_error or bad[0]
    if start_arcs is None:
        raise StartError(
            f"no start for {n} drones along the route from {fmt_point(route.base)}: "
            + (first_error or f"the route ({L:.3f} m) is too short for {n} drones {spacing:.3f} m apart")
        )
    end_arcs = L * np.arange(1, n + 1) / n
    ds = L - start_arcs[-1]
    phi, dphi, K = _cruise_law(ds, speed, accel, Ts)
    Ks = int(math.ceil(settle / Ts - 1e-9))
    t = Ts * np.arange(K + Ks + 1)
    phi = np.concatenate([phi, np.ones(Ks)])
    dphi = np.concatenate([dphi, np.zeros(Ks)])
    T = K * Ts
    S = start_arcs[None, :] + (end_arcs - start_arcs)[None, :] * phi[:, None]  # (K+1, N)
    Sd = (end_arcs - start_arcs)[None, :] * dphi[:, None]
    pos = _point_at(path, arcs, S)
    vel = _tangent_at(path, arcs, S) * Sd[..., None]
    final = _point_at(path, arcs, end_arcs)
    return DroneReferences(
        t=t,
        x=pos[:, -1].copy(),
        xd=vel[:, -1].copy(),
        positions=pos,
        velocities=vel,
        arcs=S,
        start_positions=_point_at(path, arcs, start_arcs),
        final_positions=final,
        route=route,
        diagnostics={
            "start_arcs": start_arcs.tolist(),
            "final_violations": chain_violations(
                world, route.base, final, tether, d_safe=d_safe, separation_margin=separation_margin
            ),
            "travel_time": T,
        },
    )
