"""Independent check of a tethered drone chain's plan (``formulations/drones.md``, "Independent check (3-D)").

Written without the planner's code and without its collision library: the world is rebuilt here from the scenario's
``[world]`` table (boxes as numpy arrays, prism footprints as shapely polygons, meshes with trimesh), every tether is
rebuilt in closed form from its two ends and the recorded catenary parameter ``a``, and every distance is an exact
formula of this module. At every step of the plan it checks:

* the plan record: finite positions, the radius and room it was made with are the world's;
* each tether's model: the rebuilt catenary passes through both ends, holds the winch tension T_w at the winch end
  (the recorded ``a`` is the equilibrium) and is the stable (shallow) equilibrium. The through-the-ends test holds
  for every a > 0 (the closed form solves z(d) = z_Q for the vertex), so it only measures rounding; it is the winch
  tension test that pins a; with an active winch (``tether.winch = "active"``) T_w is the plan's recorded tension of
  that tether at that step (``plan.winch_tension``), and the ``winch`` kind checks it: recorded, finite, within
  [T_min, T_max] and changing by at most ``winch_tension_rate`` per second;
* drone clearance >= r from every obstacle and the side walls; altitude within [zmin + r, zmax - r];
* drones >= 2 r apart;
* every tether's whole curve >= c_t from every obstacle, the floor, the ceiling and the walls (tether 1 no closer
  than the winch itself when the winch is nearer than c_t, e.g. on the floor), by sampling the curve with certified
  bounds between samples (below);
* arc length <= L_max; the tension at every drone end <= the drone's spare thrust;
* speed, acceleration and jerk per axis (finite differences of the positions) within the planner's bounds;
* the leader ends at the goal within the tolerance.

Curve sampling. The signed distance D to a union of closed sets is 1-Lipschitz, so on a piece of curve of arc length
delta between samples with distances d0 and d1 every point is at least ``(d0 + d1 - delta) / 2`` from the obstacles.
Each curve is sampled every <= 0.5 m, then every piece whose bound comes within 5 cm of its limit and below the
curve's least sample so far (only there can the least distance lie) is split (4 ways) until it is <= 2 cm long, and
while no sample of the curve is below its limit, a piece whose bound is below it is split further until <= 2 mm: a
violation is reported only if the certified bound is below the limit (the sampled value is given in the message), so
the verdict is exact to within 1 mm of arc, and the least distance reported near a limit is within 1 cm of the
curve's. Two shortcuts keep those answers (``formulations/drones.md``, "Fast path"): an obstacle is measured only from
the tethers whose bounding box (:func:`curve_boxes`) may be nearer to it than a room face (then a room face is nearer
at every point, and the sample's distance and what it names are unchanged); and each piece gets a second lower bound,
the least room distance over it (exact: a wall's distance is monotone along the curve, the floor's convex, least at an
end or the vertex) with the obstacles' own 1-Lipschitz bound, which decides the 2 mm refinement and is the certified
one, and a piece is split towards 2 cm only if it, less the limit, is <= the least margin found so far over the ranked
tethers (every ancestor of a sample with the plan's least margin passes: its bound is <= that sample's distance), so
the plan's least margin and where it is are those of the full sampling; a tether far from it keeps fewer samples (its
per-step least sample is then only an upper bound).

Units: metres, seconds, newtons. Steps k = 0..K index ``plan.t``; drone i (1..N) is ``plan.robots[:, i-1]``;
tether j (1..N) joins point j-1 (point 0 the anchor) and drone j.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.checks.metrics import json_safe
from tmr.errors import MapError, fmt_point

__all__ = [
    "DRONE_VIOLATION_KINDS",
    "CheckWorld",
    "DroneMetrics",
    "TetherCurves",
    "box_signed_distance",
    "check_drone_plan",
    "check_world",
    "curve_points",
    "prism_signed_distance",
    "tether_curves",
]

Array = NDArray[np.float64]

#: Violation kinds, in report order.
DRONE_VIOLATION_KINDS: tuple[str, ...] = (
    "planner",
    "record",
    "tether_model",
    "drone_clearance",
    "altitude",
    "separation",
    "tether_clearance",
    "tether_length",
    "tension",
    "speed",
    "acceleration",
    "jerk",
    "goal",
)
#: With an active winch (``tether.winch = "active"``) one kind more: the recorded tensions within the pulley's range
#: [T_min, T_max] and their rate within ``winch_tension_rate`` (a constant-tension plan's metrics keep their keys).
WINCH_KIND = "winch"
#: The limits whose margins are compared to name the binding one (each as a fraction of its limit).
LIMIT_KINDS: tuple[str, ...] = (
    "drone_clearance",
    "altitude",
    "separation",
    "tether_clearance",
    "tether_length",
    "tension",
    "speed",
    "acceleration",
    "jerk",
)

COARSE = 0.5  # first arc spacing of the curve samples [m]
DENSE = 0.02  # arc spacing near a limit [m] (within BAND of it)
FINE = 0.002  # arc spacing where the certified bound and the samples disagree about a limit [m]
BAND = 0.05  # pieces whose bound is within this of the limit are sampled DENSE [m]
EXACT_RANGE = 1.0  # distances are exact up to limit + this; farther, a lower bound (bounding boxes) [m]
MODEL_TOL = 1e-6  # through-the-ends residual [m], relative winch tension error [-], vertical tether span [m]
_ROOM_FACES = ("the wall x = xmin", "the wall y = ymin", "the floor", "the wall x = xmax", "the wall y = ymax",
               "the ceiling")  # fmt: skip


# ----------------------------------------------------------------------------------------------------------
# exact distances
# ----------------------------------------------------------------------------------------------------------
def box_signed_distance(points: Array, boxes: Array) -> Array:
    """Signed distance [m] from points (P, 3) to axis-aligned boxes (B, 6) = (xmin, ymin, zmin, xmax, ymax, zmax):
    (P, B), negative inside (minus the depth to the nearest face). Closed form: with c the centre, e the half
    extents and q = |p - c| - e, D = |max(q, 0)| + min(max_k q_k, 0)."""
    p = np.asarray(points, dtype=float).reshape(-1, 1, 3)
    b = np.asarray(boxes, dtype=float).reshape(1, -1, 6)
    c = 0.5 * (b[..., :3] + b[..., 3:])
    e = 0.5 * (b[..., 3:] - b[..., :3])
    q = np.abs(p - c) - e
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


def prism_signed_distance(points: Array, footprint: Any, z0: float, z1: float) -> Array:
    """Signed distance [m] from points (P, 3) to the vertical prism ``footprint`` (a shapely Polygon) x [z0, z1]:
    (P,). The prism is the product of the footprint F and the interval I, so with the signed 2-D distance s_F
    (shapely: distance to the boundary, negative inside) and s_I = max(z0 - z, z - z1),
    D = |(max(s_F, 0), max(s_I, 0))| + min(max(s_F, s_I), 0) (exact for a product of two sets)."""
    import shapely

    p = np.asarray(points, dtype=float).reshape(-1, 3)
    if p.shape[0] == 0:
        return np.zeros(0)
    pts = shapely.points(p[:, 0], p[:, 1])
    s_f = shapely.distance(footprint.boundary, pts)
    inside = shapely.contains_xy(footprint, p[:, 0], p[:, 1])
    s_f = np.where(inside, -s_f, s_f)
    s_i = np.maximum(z0 - p[:, 2], p[:, 2] - z1)
    return np.hypot(np.maximum(s_f, 0.0), np.maximum(s_i, 0.0)) + np.minimum(np.maximum(s_f, s_i), 0.0)


def _winding_number(points: Array, tri: Array) -> Array:
    """Generalized winding number of a closed triangle soup ``tri`` (T, 3, 3) at points (P, 3) (Jacobson et al. 2013;
    solid angle of a triangle: Van Oosterom & Strackee 1983): 1 inside, 0 outside."""
    out = np.empty(len(points))
    step = max(1, 1_000_000 // max(1, len(tri)))
    for s in range(0, len(points), step):
        r = tri[None] - points[s : s + step, None, None, :]
        a, b, c = r[..., 0, :], r[..., 1, :], r[..., 2, :]
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.einsum("...i,...i", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("...i,...i", a, b) * lc + np.einsum("...i,...i", b, c) * la
        den += np.einsum("...i,...i", c, a) * lb
        out[s : s + step] = np.arctan2(det, den).sum(axis=-1) / (2.0 * np.pi)
    return out


def mesh_signed_distance(points: Array, mesh: Any) -> Array:
    """Signed distance [m] from points (P, 3) to a closed trimesh mesh: (P,), negative inside.

    Unsigned distance: ``trimesh.triangles.closest_point`` on the triangles whose centroid lies within the point's
    nearest-vertex distance (an upper bound on the distance, scipy ``cKDTree``) plus the largest centroid-to-vertex
    radius, i.e. every triangle that can be the nearest. Sign: where the nearest point is inside its triangle's face,
    the side of that face (outward normals; a mesh of negative volume is turned inside out); on an edge or a vertex,
    outside if outside the convex hull (scipy ``ConvexHull``), else the generalized winding number."""
    import itertools

    import trimesh
    from scipy.spatial import ConvexHull, cKDTree

    p = np.asarray(points, dtype=float).reshape(-1, 3)
    if p.shape[0] == 0:
        return np.zeros(0)
    tri = np.asarray(mesh.triangles, dtype=float)
    cen = tri.mean(axis=1)
    reach = float(np.linalg.norm(tri - cen[:, None], axis=-1).max())
    ub, _ = cKDTree(np.asarray(mesh.vertices, dtype=float)).query(p)
    lists = cKDTree(cen).query_ball_point(p, ub + reach * (1 + 1e-12) + 1e-12, return_sorted=False)
    counts = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
    it = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64, count=int(counts.sum()))
    ip = np.repeat(np.arange(p.shape[0]), counts)
    cp = trimesh.triangles.closest_point(tri[it], p[ip])
    dist = np.linalg.norm(cp - p[ip], axis=1)
    order = np.lexsort((dist, ip))
    first = order[np.r_[True, ip[order][1:] != ip[order][:-1]]]  # each point's nearest pair
    near_t, near_c, out = it[first], cp[first], dist[first]
    normals = np.cross(tri[near_t, 1] - tri[near_t, 0], tri[near_t, 2] - tri[near_t, 0])
    if float(getattr(mesh, "volume", 1.0)) < 0.0:
        normals = -normals
    bary = trimesh.triangles.points_to_barycentric(tri[near_t], near_c)
    on_face = np.all(bary > 1e-9, axis=1)
    side = np.einsum("ij,ij->i", normals, p - near_c)
    inside = on_face & (side < 0.0)
    rest = np.nonzero(~on_face & (out > 0.0))[0]
    if rest.size:  # outside the convex hull is outside; the winding number for the others
        hull = ConvexHull(np.asarray(mesh.vertices, dtype=float)).equations  # outward normal, offset
        rest = rest[(p[rest] @ hull[:, :3].T + hull[:, 3]).max(axis=1) <= 0.0]
    if rest.size:
        inside[rest] = _winding_number(p[rest], tri) > 0.5
    return np.where(inside, -out, out)


@dataclass(frozen=True)
class CheckWorld:
    """The checker's own world (from a ``[world]`` table by :func:`check_world`).

    Attributes:
        bounds: room (xmin, ymin, zmin, xmax, ymax, zmax) [m]; floor z = zmin, ceiling z = zmax.
        safety_radius: drone radius r [m].
        obstacles: one entry per obstacle in table order: ``("box", (6,) array)``, ``("prism", (Polygon, z0, z1))``
            or ``("mesh", trimesh.Trimesh)``.
        names: a label per obstacle (``obstacle #k`` as in the table; meshes with their file).
    """

    bounds: Array
    safety_radius: float
    obstacles: tuple[tuple[str, Any], ...] = ()
    names: tuple[str, ...] = ()

    def _aabb(self, k: int) -> Array:
        kind, data = self.obstacles[k]
        if kind == "box":
            return np.asarray(data, dtype=float)
        if kind == "prism":
            poly, z0, z1 = data
            x0, y0, x1, y1 = poly.bounds
            return np.array([x0, y0, z0, x1, y1, z1])
        lo, hi = np.asarray(data.bounds, dtype=float)
        return np.concatenate([lo, hi])

    def aabbs(self) -> Array:
        """Every obstacle's axis-aligned bounding box (B, 6) = (xmin, ymin, zmin, xmax, ymax, zmax) [m]."""
        return np.array([self._aabb(k) for k in range(len(self.obstacles))]).reshape(-1, 6)

    def obstacle_distance(
        self, points: Array, cutoff: float = math.inf, mask: NDArray[np.bool_] | None = None
    ) -> tuple[Array, NDArray[np.int64]]:
        """Signed distance to the nearest obstacle (P,) [m] (+inf without obstacles) and its index (-1 if none).

        Exact where it is below ``cutoff`` [m]; a point farther than ``cutoff`` from a prism's or mesh's bounding box
        gets the box distance, a lower bound (>= cutoff). ``mask`` (P, B) bool: only obstacle k is measured from
        point p where ``mask[p, k]`` (default: every one)."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        best = np.full(p.shape[0], np.inf)
        which = np.full(p.shape[0], -1, dtype=np.int64)
        for k, (kind, data) in enumerate(self.obstacles):
            sel = slice(None) if mask is None else np.flatnonzero(mask[:, k])
            ps = p[sel]
            if ps.shape[0] == 0:
                continue
            best_s = best[sel]
            if kind == "box":
                dist = box_signed_distance(ps, data)[:, 0]
            else:
                dist = box_signed_distance(ps, self._aabb(k))[:, 0]
                near = np.nonzero(dist < np.minimum(cutoff, best_s))[0]  # only there can the exact value matter
                if near.size:
                    if kind == "prism":
                        dist[near] = prism_signed_distance(ps[near], *data)
                    else:
                        dist[near] = mesh_signed_distance(ps[near], data)
            closer = dist < best_s
            best[sel] = np.where(closer, dist, best_s)
            which[sel] = np.where(closer, k, which[sel])
        return best, which

    def room_distance(self, points: Array) -> tuple[Array, NDArray[np.int64]]:
        """Distance to the nearest room face (P,) [m] (negative outside the room) and the face (index into
        x = xmin, y = ymin, floor, x = xmax, y = ymax, ceiling)."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        faces = np.concatenate([p - self.bounds[:3], self.bounds[3:] - p], axis=1)
        i = np.argmin(faces, axis=1)
        return faces[np.arange(p.shape[0]), i], i

    def distance(
        self, points: Array, cutoff: float = math.inf, mask: NDArray[np.bool_] | None = None
    ) -> tuple[Array, NDArray[np.int64]]:
        """Distance to the nearest obstacle or room face (P,) [m] and what it is: obstacle index k >= 0, or
        -1 - face for a room face (see :meth:`room_distance`). ``mask`` as in :meth:`obstacle_distance`: the answer
        is the same as without it if every obstacle left out at a point is farther from it than a room face."""
        d_o, k_o = self.obstacle_distance(points, cutoff, mask)
        d_r, f_r = self.room_distance(points)
        room = d_r < d_o
        return np.where(room, d_r, d_o), np.where(room, -1 - f_r, k_o)

    def label(self, what: int) -> str:
        """What :meth:`distance`'s index names: ``"obstacle #2"``, ``"the floor"``, ..."""
        return self.names[what] if what >= 0 else _ROOM_FACES[-1 - what]


def _numbers(value: Any, n: int, where: str) -> Array:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise MapError(f"{where} must be {n} numbers, got {value!r}") from None
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise MapError(f"{where} must be {n} finite numbers, got {value!r}")
    return arr


def check_world(table: Any, base_dir: str | Path = ".") -> CheckWorld:
    """The checker's world from a scenario's ``[world]`` table (``bounds``, ``safety_radius``, ``obstacles`` with
    ``box`` | ``prism`` + ``z`` | ``mesh``; mesh files relative to ``base_dir``), or from a scenario object with
    ``world_table`` and ``source`` (meshes beside its file); a :class:`CheckWorld` is returned as it is. Raises a
    one-line :class:`MapError` on a malformed table."""
    if isinstance(table, CheckWorld):
        return table
    if hasattr(table, "world_table"):  # a DroneScenario: its [world] table, meshes beside its file
        source = getattr(table, "source", None)
        base_dir = Path(source).parent if source is not None else base_dir
        table = table.world_table
    if not isinstance(table, Mapping) or "bounds" not in table:
        raise MapError("the checker needs the scenario's [world] table with 'bounds'")
    bounds = _numbers(table["bounds"], 6, "[world] bounds")
    if np.any(bounds[3:] <= bounds[:3]):
        raise MapError(f"[world] bounds must be xmin ymin zmin xmax ymax zmax with max > min, got {bounds.tolist()}")
    r = float(table.get("safety_radius", 0.0))
    obstacles: list[tuple[str, Any]] = []
    names: list[str] = []
    for k, item in enumerate(table.get("obstacles", []) or []):
        at = f"obstacle #{k}"
        if not isinstance(item, Mapping):
            raise MapError(f"[world] {at} must be a table")
        if "box" in item:
            box = _numbers(item["box"], 6, f"[world] {at} box")
            if np.any(box[3:] <= box[:3]):
                raise MapError(f"[world] {at} box must have max > min, got {box.tolist()}")
            obstacles.append(("box", box))
        elif "prism" in item:
            import shapely
            from shapely.geometry import Polygon

            z = _numbers(item.get("z"), 2, f"[world] {at} z")
            poly = Polygon(np.asarray(item["prism"], dtype=float))
            if not poly.is_valid or poly.area <= 0.0 or z[1] <= z[0]:
                raise MapError(f"[world] {at}: the prism needs a simple footprint and z1 > z0")
            shapely.prepare(poly)
            obstacles.append(("prism", (poly, float(z[0]), float(z[1]))))
        elif "mesh" in item:
            import trimesh

            path = Path(base_dir) / str(item["mesh"])
            try:
                mesh = trimesh.load(path, force="mesh")
            except Exception as exc:  # trimesh raises many types on missing or corrupt files
                raise MapError(f"[world] {at}: cannot read the mesh {path} ({type(exc).__name__})") from None
            obstacles.append(("mesh", mesh))
            at = f"{at} (mesh '{Path(str(item['mesh'])).name}')"  # the file's name: the same in the run's copy
        else:
            raise MapError(f"[world] {at} needs one of box, prism, mesh")
        names.append(at)
    return CheckWorld(bounds=bounds, safety_radius=r, obstacles=tuple(obstacles), names=tuple(names))


# ----------------------------------------------------------------------------------------------------------
# tethers rebuilt from their ends and a
# ----------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TetherCurves:
    """Every tether of a plan rebuilt in closed form; arrays (K+1, N) unless said (tether j = column j - 1).

    In the vertical plane through the ends P (point j-1) and Q (drone j), x from P along u, the catenary is
    z(x) = z_P + a (cosh θ - cosh θ_P), θ = θ_P + x / a, with (from z(d) = z_Q; Irvine 1981 §1.2)
    u_ = d / (2a), v_ = asinh(h / (2 a sinh u_)), θ_P = v_ - u_, θ_Q = v_ + u_ (i.e. the vertex at
    x0 = d/2 - a v_ from P). Arc length L = a (sinh θ_Q - sinh θ_P); tension T = ρ g a cosh θ.

    Attributes:
        p, q: ends (K+1, N, 3) [m]; u: horizontal unit vector P -> Q (K+1, N, 3); d, h: span, z_Q - z_P [m].
        a: recorded parameter [m] (NaN: vertical); vertical: bool mask.
        sinh_p, cosh_p, sinh_q, cosh_q: at the ends (vertical: 0/1, unused).
        length: arc length [m]; tension_p, tension_q: tension at each end [N].
        winch_at_p: bool, the winch end; winch_error: tension at the winch end - T_w [N].
        end_residual: largest |z(x) - z_end| of the vertex form at both ends [m]: rounding only (the vertex is
            solved from both ends, so every a > 0 passes through them; ``winch_error`` is what pins a).
        stable: the shallow (stable) equilibrium: dT/da > 0 at fixed ends.
        valid: a is a positive finite number (or NaN with d <= MODEL_TOL).
    """

    p: Array
    q: Array
    u: Array
    d: Array
    h: Array
    a: Array
    vertical: NDArray[np.bool_]
    sinh_p: Array
    cosh_p: Array
    sinh_q: Array
    cosh_q: Array
    length: Array
    tension_p: Array
    tension_q: Array
    winch_at_p: NDArray[np.bool_]
    winch_error: Array
    end_residual: Array
    stable: NDArray[np.bool_]
    valid: NDArray[np.bool_]


def _thetas(a: Array, d: Array, h: Array) -> tuple[Array, Array]:
    """θ_P, θ_Q of the catenary with parameter a through P = (0, 0), Q = (d, h) (a, d > 0)."""
    u = d / (2.0 * a)
    v = np.arcsinh(h / (2.0 * a * np.sinh(u)))
    return v - u, v + u


def tether_curves(
    base: Array, robots: Array, tether_a: Array, tether: Any, winch_tension: Array | None = None
) -> TetherCurves:
    """Rebuild every tether (closed form, :class:`TetherCurves`) from the anchor ``base`` (3,), the drones ``robots``
    (K+1, N, 3) [m], the recorded ``tether_a`` (K+1, N) [m] (NaN: vertical) and the tether's physics ``tether``
    (``mass_per_length``, ``g``, ``winch_tension``, ``winch_end``; a DroneTetherParams). ``winch_tension``: an
    active winch's recorded tension of every tether at every step (K+1, N) [N], in place of the constant one."""
    robots = np.asarray(robots, dtype=float)
    n_k, n = robots.shape[:2]
    pts = np.concatenate([np.broadcast_to(np.asarray(base, dtype=float), (n_k, 1, 3)), robots], axis=1)
    p, q = pts[:, :-1], pts[:, 1:]
    dxy = q[..., :2] - p[..., :2]
    d = np.hypot(dxy[..., 0], dxy[..., 1])
    h = q[..., 2] - p[..., 2]
    a = np.asarray(tether_a, dtype=float).reshape(n_k, n)
    w = float(tether.mass_per_length) * float(tether.g)
    tw = float(tether.winch_tension) if winch_tension is None else np.asarray(winch_tension, float).reshape(n_k, n)
    vertical = np.isnan(a)
    valid = np.where(vertical, d <= MODEL_TOL, np.isfinite(a) & (a > 0.0))
    curved = ~vertical & valid & (d > 0.0)
    safe_a = np.where(curved, a, 1.0)
    safe_d = np.where(curved, d, 1.0)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        th_p, th_q = _thetas(safe_a, safe_d, np.where(curved, h, 0.0))
        u = np.zeros_like(p)
        u[..., 0] = np.where(d > 0, dxy[..., 0] / np.where(d > 0, d, 1.0), 1.0)
        u[..., 1] = np.where(d > 0, dxy[..., 1] / np.where(d > 0, d, 1.0), 0.0)
        sp, cp, sq, cq = np.sinh(th_p), np.cosh(th_p), np.sinh(th_q), np.cosh(th_q)
        length = np.where(curved, safe_a * (sq - sp), np.hypot(d, h))
        t_p_c, t_q_c = w * safe_a * cp, w * safe_a * cq
        # the vertex form z(x) = z0 + a (cosh((x - x0)/a) - 1) evaluated at both ends
        x0 = -safe_a * th_p
        z0 = p[..., 2] - safe_a * (cp - 1.0)
        z_at_p = z0 + safe_a * (np.cosh((0.0 - x0) / safe_a) - 1.0)
        z_at_q = z0 + safe_a * (np.cosh((safe_d - x0) / safe_a) - 1.0)
        resid = np.maximum(np.abs(z_at_p - p[..., 2]), np.abs(z_at_q - q[..., 2]))
        # stability: the tension at the lower end grows with a at fixed ends (module doc of the check)
        eps = 1e-6

        def t_lower(aa: Array) -> Array:
            tp, tq = _thetas(aa, safe_d, np.where(curved, h, 0.0))
            return aa * np.cosh(np.where(h >= 0.0, tp, tq))

        stable = (t_lower(safe_a * (1 + eps)) - t_lower(safe_a * (1 - eps))) > 0.0
    lower_is_p = h >= 0.0
    winch_lower = tether.winch_end == "lower"
    winch_at_p = np.where(h == 0.0, True, lower_is_p if winch_lower else ~lower_is_p)
    # vertical: the lower end holds T_w (winch below) or T_w - w |h| (winch above); tension grows by w |h| upwards
    t_low = tw if winch_lower else tw - w * np.abs(h)
    t_p_v = np.where(lower_is_p, t_low, t_low + w * np.abs(h))
    t_q_v = np.where(lower_is_p, t_low + w * np.abs(h), t_low)
    tension_p = np.where(curved, t_p_c, t_p_v)
    tension_q = np.where(curved, t_q_c, t_q_v)
    winch_error = np.where(winch_at_p, tension_p, tension_q) - tw
    ok_num = np.isfinite(length) & np.isfinite(tension_p) & np.isfinite(tension_q)
    return TetherCurves(
        p=p, q=q, u=u, d=d, h=h, a=a, vertical=vertical,
        sinh_p=np.where(curved, sp, 0.0), cosh_p=np.where(curved, cp, 1.0),
        sinh_q=np.where(curved, sq, 0.0), cosh_q=np.where(curved, cq, 1.0),
        length=length, tension_p=tension_p, tension_q=tension_q, winch_at_p=winch_at_p,
        winch_error=np.where(valid & ok_num, winch_error, np.inf),
        end_residual=np.where(curved, resid, 0.0), stable=np.where(curved, stable, True), valid=valid & ok_num,
    )  # fmt: skip


def curve_points(curves: TetherCurves, index: NDArray[np.int64], s: Array) -> Array:
    """Points (M, 3) [m] at arc length ``s`` (M,) from P of the tethers with flat index ``index`` (M,) into the
    (K+1, N) arrays: sinh θ = sinh θ_P + s / a, x = a (asinh(sinh θ) - θ_P), and (cancellation-free)
    z - z_P = a (cosh θ - cosh θ_P) = s (2 sinh θ_P + s / a) / (cosh θ + cosh θ_P); a vertical tether is straight."""
    p = curves.p.reshape(-1, 3)[index]
    q = curves.q.reshape(-1, 3)[index]
    u = curves.u.reshape(-1, 3)[index]
    a = curves.a.reshape(-1)[index]
    vert = curves.vertical.reshape(-1)[index] | ~np.isfinite(a)
    length = curves.length.reshape(-1)[index]
    sp = curves.sinh_p.reshape(-1)[index]
    cp = curves.cosh_p.reshape(-1)[index]
    aa = np.where(vert, 1.0, a)
    sh = sp + s / aa
    x = aa * (np.arcsinh(sh) - np.arcsinh(sp))
    dz = s * (2.0 * sp + s / aa) / (np.sqrt(1.0 + sh * sh) + cp)
    out = p + x[:, None] * u
    out[:, 2] = p[:, 2] + dz
    frac = np.where(length > 0, s / np.where(length > 0, length, 1.0), 0.0)
    straight = p + frac[:, None] * (q - p)
    return np.where(vert[:, None], straight, out)


def curve_boxes(curves: TetherCurves) -> Array:
    """An axis-aligned box (N_c, 6) [m] around every point :func:`curve_points` gives on each tether (flat index
    into the (K+1, N) arrays), or the whole space (±inf) where there is no closed-form bound.

    A catenary lies in the vertical plane through its ends, its horizontal coordinate x = a (θ - θ_P) running from
    0 to d as θ goes from θ_P to θ_Q: its horizontal extent is that of the chord. Its height z - z_P =
    a (cosh θ - cosh θ_P) is convex in θ, so it is highest at an end and lowest at an end or, when θ_P < 0 < θ_Q,
    at the vertex θ = 0: z_P + a (1 - cosh θ_P). A vertical (or null-a) tether is its chord. The box is padded by
    1 mm + 1e-9 of the numbers' size, far more than the rounding of the closed forms. Tethers that are not a valid
    curve with d > 0 (``curve_points`` still samples them) get the whole space."""
    p = curves.p.reshape(-1, 3)
    q = curves.q.reshape(-1, 3)
    a = curves.a.reshape(-1)
    sp, cp, sq = curves.sinh_p.reshape(-1), curves.cosh_p.reshape(-1), curves.sinh_q.reshape(-1)
    length = curves.length.reshape(-1)
    straight = curves.vertical.reshape(-1) | ~np.isfinite(a)
    curved = ~straight & curves.valid.reshape(-1) & (curves.d.reshape(-1) > 0.0)
    lo, hi = np.minimum(p, q), np.maximum(p, q)
    with np.errstate(invalid="ignore", over="ignore"):
        vertex = np.where(curved & (sp < 0.0) & (sq > 0.0), p[:, 2] + np.where(curved, a, 0.0) * (1.0 - cp), np.inf)
        lo[:, 2] = np.minimum(lo[:, 2], vertex)
        size = np.abs(np.concatenate([lo, hi], axis=1)).max(axis=1) + np.where(
            curved, length * (1.0 + np.abs(sp) + np.abs(sq)), 0.0
        )
        pad = 1e-3 + 1e-9 * size
        box = np.concatenate([lo - pad[:, None], hi + pad[:, None]], axis=1)
    known = (straight | curved) & np.isfinite(box).all(axis=1)
    return np.where(known[:, None], box, np.array([-np.inf] * 3 + [np.inf] * 3))


def _candidates(world: CheckWorld, boxes: Array) -> tuple[NDArray[np.bool_], Array]:
    """Which obstacles may be nearer than a room face to the points of the boxes ``boxes`` (N_c, 6) [m]: (N_c, B)
    bool, and the least distance [m] from each box to an obstacle left out (+inf if none).

    Every point p of box c is within U_c = min over the six room faces of the face's greatest distance over the
    box of a room face (the room distance is the least face distance). If the box and obstacle k's bounding box
    are disjoint, at a distance g > 0, then p is outside that bounding box and its distance to obstacle k (exact,
    or the bounding box's own as :meth:`CheckWorld.obstacle_distance` may give) is >= g; so when g > U_c a room
    face is strictly nearer than obstacle k at every point of the box, and leaving k out changes neither the
    distance :meth:`CheckWorld.distance` gives nor what it names."""
    obs = world.aabbs()
    if obs.shape[0] == 0:
        return np.zeros((boxes.shape[0], 0), dtype=bool), np.full(boxes.shape[0], np.inf)
    b = world.bounds
    with np.errstate(invalid="ignore"):
        u = np.minimum((boxes[:, 3:] - b[:3]).min(axis=1), (b[3:] - boxes[:, :3]).min(axis=1))  # (N_c,)
        gap = np.maximum(np.maximum(boxes[:, None, :3] - obs[None, :, 3:], obs[None, :, :3] - boxes[:, None, 3:]), 0.0)
        g = np.sqrt((gap * gap).sum(axis=-1))  # (N_c, B)
        far = (g > 0.0) & (g > u[:, None])
    return ~far, np.where(far, g, np.inf).min(axis=1)


def _curve_clearance(
    world: CheckWorld, curves: TetherCurves, limit: Array, tol: float, ranked: NDArray[np.bool_] | None = None
) -> tuple[Array, Array, Array, NDArray[np.int64], int]:
    """Per tether (K+1, N): the least sampled distance [m], the arc length where it is [m], the certified lower
    bound on the whole curve's distance [m], the nearest thing's index (:meth:`CheckWorld.distance`); and the number
    of points sampled. ``ranked`` (K+1, N) bool: the tethers whose least margin (least sample - limit) is reported
    (default: all); pieces that cannot hold a sample below the least margin of these so far are not refined
    (module doc, "Curve sampling")."""
    length = curves.length.reshape(-1)
    lim = limit.reshape(-1)
    n_c = length.size
    rank = np.ones(n_c, dtype=bool) if ranked is None else np.asarray(ranked, dtype=bool).reshape(-1)
    ok = np.isfinite(length)
    counts = np.maximum(1, np.ceil(np.where(ok, length, 0.0) / COARSE)).astype(np.int64)
    cid = np.repeat(np.arange(n_c), counts + 1)
    start = np.cumsum(counts + 1) - (counts + 1)
    frac = (np.arange(cid.size) - start[cid]) / counts[cid]
    s = np.where(ok[cid], frac * np.where(ok, length, 0.0)[cid], 0.0)
    cutoff = float(np.max(lim)) + EXACT_RANGE
    # the obstacles that may be a curve's nearest thing, and a lower bound on the distance to the others
    cand, g_out = _candidates(world, curve_boxes(curves))
    # the lowest point of a curve that has one inside (θ_P < 0 < θ_Q): its arc length and its height above the floor
    curved = ~curves.vertical.reshape(-1) & np.isfinite(curves.a.reshape(-1)) & curves.valid.reshape(-1)
    curved &= curves.d.reshape(-1) > 0.0
    sp, cp = curves.sinh_p.reshape(-1), curves.cosh_p.reshape(-1)
    aa = np.where(curved, curves.a.reshape(-1), 0.0)
    has_v = curved & (sp < 0.0) & (curves.sinh_q.reshape(-1) > 0.0)
    s_v = np.where(has_v, -aa * sp, np.nan)
    floor_v = np.where(has_v, curves.p.reshape(-1, 3)[:, 2] - aa * sp * sp / (1.0 + cp) - world.bounds[2], np.inf)

    def measure(c: NDArray[np.int64], ss: Array) -> tuple[Array, NDArray[np.int64], Array, Array]:
        """Distance [m] and nearest thing (as :meth:`CheckWorld.distance`) at arc ``ss`` of curves ``c``, the room
        faces' distance and a lower bound on the obstacles' [m]."""
        pts = curve_points(curves, c, ss)
        d_o, k_o = world.obstacle_distance(pts, cutoff, cand[c])
        d_r, f_r = world.room_distance(pts)
        room = d_r < d_o
        return np.where(room, d_r, d_o), np.where(room, -1 - f_r, k_o), d_r, np.minimum(d_o, g_out[c])

    dist, what, room_d, obst_d = measure(cid, s)
    best = np.full(n_c, np.inf)
    best_s = np.zeros(n_c)
    best_what = np.full(n_c, -1, dtype=np.int64)

    def keep_min(c: NDArray[np.int64], ss: Array, dd: Array, ww: NDArray[np.int64]) -> None:
        """Each curve's least sample of this batch (``c`` is sorted: the samples of a curve are contiguous; ties:
        the first) replaces its best if lower."""
        head = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
        low = np.fmin.reduceat(dd, head)  # NaN only if every sample of the curve is NaN (then no update)
        at = np.flatnonzero(dd == np.repeat(low, np.diff(np.r_[head, c.size])))
        at = at[np.r_[True, c[at][1:] != c[at][:-1]]] if at.size else at  # the first least sample per curve
        c, ss, dd, ww = c[at], ss[at], dd[at], ww[at]
        better = dd < best[c]
        best[c[better]], best_s[c[better]], best_what[c[better]] = dd[better], ss[better], ww[better]

    keep_min(cid, s, dist, what)
    n_samples = int(cid.size)
    first, second = np.r_[cid[1:] == cid[:-1], False], np.r_[False, cid[1:] == cid[:-1]]  # a piece's two ends
    seg_c, s0, s1 = cid[first], s[first], s[second]
    d0, d1, r0, r1, o0, o1 = dist[first], dist[second], room_d[first], room_d[second], obst_d[first], obst_d[second]
    lower = np.full(n_c, np.inf)
    while seg_c.size:
        delta = s1 - s0
        lb = 0.5 * (d0 + d1 - delta)
        sl = lim[seg_c]
        # the piece's least room distance (exact: each face's distance is monotone or, the floor's, convex along
        # the curve) and the obstacles' 1-Lipschitz bound: no point of the piece is nearer than the lesser
        vc = s_v[seg_c]
        room_lo = np.minimum(np.minimum(r0, r1), np.where((vc >= s0) & (vc <= s1), floor_v[seg_c], np.inf))
        lb2 = np.maximum(lb, np.minimum(room_lo, 0.5 * (o0 + o1 - delta)) - 1e-9)
        undecided = (lb2 < sl - tol) & (np.minimum(d0, d1) >= sl - tol) & (best[seg_c] >= sl - tol)
        m_rank = np.min(np.where(rank & np.isfinite(best), best - lim, np.inf))  # the least reported margin so far
        # dense near the limit, only where the curve's least distance may lie (a piece with lb >= the least sample
        # cannot hold a lower one) and the plan's least margin may (lb2 - limit <= the least so far); finer where
        # the verdict is still open
        dense = (lb < sl + BAND) & (lb < best[seg_c]) & (lb2 - sl <= m_rank) & (delta > DENSE)
        need = dense | (undecided & (delta > FINE))
        done = ~need
        np.minimum.at(lower, seg_c[done], lb2[done])
        if not need.any():
            break
        c, a0, a1 = seg_c[need], s0[need], s1[need]
        mids = a0[:, None] + (a1 - a0)[:, None] * np.array([0.25, 0.5, 0.75])[None]
        mc = np.repeat(c, 3)
        md, mw, mr, mo = measure(mc, mids.reshape(-1))
        n_samples += int(mc.size)
        keep_min(mc, mids.reshape(-1), md, mw)
        seg_c = np.repeat(c, 4)
        grid = [np.column_stack([e0[need], m.reshape(-1, 3), e1[need]]) for e0, m, e1 in
                ((s0, mids, s1), (d0, md, d1), (r0, mr, r1), (o0, mo, o1))]  # fmt: skip
        s0, d0, r0, o0 = (g[:, :-1].reshape(-1) for g in grid)
        s1, d1, r1, o1 = (g[:, 1:].reshape(-1) for g in grid)
    lower = np.minimum(lower, best)  # a curve of one point (zero length) has no piece
    shape = curves.length.shape
    return best.reshape(shape), best_s.reshape(shape), lower.reshape(shape), best_what.reshape(shape), n_samples


# ----------------------------------------------------------------------------------------------------------
# metrics
# ----------------------------------------------------------------------------------------------------------
@dataclass
class DroneMetrics:
    """The check of one drone-chain plan. Lengths in m, times in s, forces in N; steps are sample indices k.

    ``f1..f4`` follow Caruso 2021 eq. 24–27 in robot coordinates (the QP's space; the pinv's joints are not in every
    plan), summed over k with v_k = (p_{k+1} - p_k) / Ts the velocity held on [t_k, t_k+1]:
    f1 = Σ_k Σ_i |v_ik|² (energy) [m²/s²]; f2 = Σ_k Σ_{i<j} (c_i - c_j)² with c_i the chord |p_i - p_{i-1}| of
    tether i (span uniformity; the chord is the spatial chain's prismatic joint) [m²]; f3 = Σ_{k>=1} |x_e,k - x_d,k|²
    (leader tracking) [m²]; f4 = Σ_k Σ_i |(v_ik - v_i,k-1) / Ts|² (smoothness) [m²/s⁴]. They are +inf when the plan
    fails (``fitness_raw`` keeps the values); ``leader_path_length`` is the leader's travelled distance.
    ``binding``: per limit, its least margin (limit side minus value, in the limit's unit; negative: violated), where
    (step, t, what, point) and the margin as a fraction of the limit; ``binding_limit`` is the limit with the least
    fraction. ``per_step``: series (K+1,) or (K+1, N) for the views.

    The summary fields do not share one convention; each, over every step k (and drone/tether/pair/axis):

    * ``min_drone_clearance`` [m]: a MARGIN — least (distance from a drone's centre to the nearest obstacle or side
      wall) − r; ≥ 0 passes (``per_step["drone_clearance"]`` likewise).
    * ``min_altitude_margin`` [m]: a MARGIN — least min(z − (zmin + r), (zmax − r) − z); ≥ 0 passes.
    * ``min_separation`` [m]: a RAW DISTANCE — least centre-to-centre distance of two drones (+inf for one drone);
      passes if ≥ 2r (``per_step["separation"]`` likewise).
    * ``min_tether_clearance`` [m]: a RAW DISTANCE — least distance of any tether's curve to an obstacle, the floor,
      the ceiling or a wall (vertical tethers included; NaN if no tether could be rebuilt); compared with
      ``tether_clearance_limit`` c_t (tether 1 with min(c_t, the winch's own clearance − 2 mm)).
    * ``max_tether_length`` [m]: a RAW VALUE — longest arc length; passes if ≤ ``tether_length_max``.
    * ``max_drone_tension`` [N]: a RAW VALUE — largest tension at a drone end (the end Q at drone j of every tether j,
      and the end P of tethers 2..N; not the anchor's end); passes if ≤ ``tension_max`` (the spare thrust).
    * ``peak_speed`` [m/s], ``peak_acceleration`` [m/s²]: PER AXIS — the largest |component| of the finite-difference
      velocity (p_{k+1} − p_k)/Ts and acceleration (p_{k+1} − 2p_k + p_{k−1})/Ts² over x, y, z (not the norm),
      as the per-axis limits ``speed_max``, ``accel_max`` are; 0 for a plan too short to difference. ``peak_jerk``
      [m/s³] likewise, the third difference (p_{k+1} − 3p_k + 3p_{k−1} − p_{k−2})/Ts³ against ``jerk_max``.
    * ``final_leader_error`` [m]: |leader's last position − goal| (Euclidean); passes if ≤ ``goal_tolerance``.
      ``max_tracking_error`` [m]: largest |leader − its reference| (Euclidean), not a limit.
    * ``max_end_residual`` [m]: largest miss of a rebuilt catenary at its ends — rounding only, it holds for every
      a > 0; ``max_winch_tension_error`` [N]: largest |tension at the winch end − T_w|, what pins the recorded a.
    * ``winch`` (an active winch only, else None and left out of ``to_dict``): the range ``tension_min``,
      ``tension_max`` [N] and ``tension_rate`` [N/s], and the ``min_tension_used``, ``max_tension_used`` [N] and
      ``max_rate_used`` [N/s] of the recorded tensions (what the ``winch`` kind checks against them).
    """

    scenario: str
    method: str
    success: bool
    failure: str | None
    failures: list[str]
    n_robots: int
    n_steps: int
    Ts: float
    duration: float
    f1: float
    f2: float
    f3: float
    f4: float
    fitness_raw: list[float]
    leader_path_length: float
    final_leader_error: float
    goal_tolerance: float
    max_tracking_error: float
    safety_radius: float
    tether_clearance_limit: float
    tether_length_max: float
    tension_max: float
    speed_max: float
    accel_max: float
    jerk_max: float | None
    min_drone_clearance: float
    min_altitude_margin: float
    min_separation: float
    min_tether_clearance: float
    max_tether_length: float
    max_drone_tension: float
    peak_speed: float
    peak_acceleration: float
    peak_jerk: float
    max_end_residual: float
    max_winch_tension_error: float
    binding_limit: str | None
    binding: dict[str, dict[str, Any]] = field(default_factory=dict)
    violation_steps: dict[str, list[int]] = field(default_factory=dict)
    first_violation: dict[str, int | None] = field(default_factory=dict)
    n_violation_steps: int = 0
    tolerance: float = 1e-6
    curve_samples: int = 0
    check_time: float = math.nan
    per_step: dict[str, Any] = field(default_factory=dict)
    winch: dict[str, Any] | None = None

    def to_dict(self, per_step: bool = True) -> dict[str, Any]:
        """JSON-safe dict in field order (non-finite floats as ``"inf"``/``"nan"`` strings); ``check_time`` left out
        (timings are not reproducible), ``per_step`` only if asked; ``winch`` only with an active winch."""
        d = asdict(self)
        d.pop("check_time")
        if d["winch"] is None:
            d.pop("winch")
        if not per_step:
            d.pop("per_step")
        return json_safe(d)


def _lookup(params: Any, name: str) -> Any:
    """``name`` in planner parameters: a ``DroneParams``, a flat dict, or the plan record's nested
    ``{"planner": {...}, "tether": {...}}`` (what :func:`tmr.control.run3d.run_drones` stores in ``plan.params``)."""
    if params is None:
        return None
    if not isinstance(params, Mapping):
        return getattr(params, name, None)
    if params.get(name) is not None:
        return params[name]
    nested = params.get("planner")
    if isinstance(nested, Mapping):
        return nested.get(name)
    return getattr(nested, name, None) if nested is not None else None


def _param(plan: Any, params: Any, name: str, default: float) -> float:
    """A planner limit: from ``params``, else ``plan.params`` (flat or under ``"planner"``), else ``default``."""
    for source in (params, getattr(plan, "params", None)):
        v = _lookup(source, name)
        if v is not None:
            return float(v)
    return default


def _m(value: float, limit: float) -> str:
    """``value`` [m] to the millimetre, or to 0.1 mm when that would print the limit it breaks."""
    text = f"{value:.3f}"
    return f"{value:.4f}" if text == f"{limit:.3f}" else text


def _t(t: Array, k: int) -> str:
    return f"t = {float(t[k]):.2f} s"


def check_drone_plan(
    plan: Any,
    world: Any,
    *,
    base_dir: str | Path = ".",
    params: Any = None,
    tolerance: float = 1e-6,
    update_plan: bool = True,
    rest_ends: bool = True,
) -> DroneMetrics:
    """Check every hard limit of a drone plan at every step, independently of the planner (module doc).

    Args:
        plan: a :class:`tmr.control.plan3d.DronePlan` (read by its fields: ``t``, ``robots``, ``base``, ``goal``,
            ``reference``, ``tether_a``, ``tether``, ``safety_radius``, ``bounds``, ``failure``, ``params``).
        world: the scenario's ``[world]`` table, the scenario itself (``world_table``, ``source``) or a
            :class:`CheckWorld` (:func:`check_world`).
        base_dir: folder the table's mesh files are relative to (the scenario file's folder).
        params: the planner parameters (a ``DroneParams`` or a dict) for ``drone_speed_max``, ``drone_accel_max``,
            ``drone_jerk_max``, ``goal_tolerance``; default: ``plan.params`` (flat, or the planner's record
            ``{"planner": {...}}``), then 2 m/s, 4 m/s², no jerk limit, 0.1 m.
        tolerance: slack [m] before a length limit counts as broken; speeds get 2 tol / Ts, accelerations 4 tol / Ts²,
            jerks 8 tol / Ts³.
        update_plan: set ``plan.success`` / ``plan.failure`` from the check (the planner's own failure, kept in
            ``plan.diagnostics["planner_failure"]``, stays first).
        rest_ends: the plan starts and ends at rest, as tmr's do: the acceleration (and jerk) from rest to the first
            step's velocity and from the last step's velocity to rest are checked too (False: only between steps, for
            trajectories cut out of a longer motion). The final stop is not checked on a plan the planner failed
            (``plan.failure`` / ``planner_failure``): it was cut off where the planner stopped.

    Returns:
        :class:`DroneMetrics`; ``failures`` has one line per violated limit kind (its first step).
    """
    start = time.perf_counter()
    w = check_world(world, base_dir)
    tol = float(tolerance)
    teth = plan.tether
    r = float(w.safety_radius)
    c_t = float(teth.clearance)
    l_max = float(teth.tether_length)
    f_max = float(teth.spare_thrust)
    v_max = _param(plan, params, "drone_speed_max", 2.0)
    a_max = _param(plan, params, "drone_accel_max", 4.0)
    j_max = _param(plan, params, "drone_jerk_max", math.inf)  # None / absent: no jerk limit (the default)
    goal_tol = _param(plan, params, "goal_tolerance", 0.1)
    t = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    n_k, n = robots.shape[:2]
    base = np.asarray(plan.base, dtype=float)
    goal = np.asarray(plan.goal, dtype=float)
    Ts = float((t[-1] - t[0]) / (n_k - 1)) if n_k > 1 else math.nan
    diag = plan.diagnostics if isinstance(getattr(plan, "diagnostics", None), dict) else {}
    planner_failure = diag["planner_failure"] if "planner_failure" in diag else plan.failure

    steps: dict[str, NDArray[np.bool_]] = {kind: np.zeros(n_k, dtype=bool) for kind in DRONE_VIOLATION_KINDS}
    reasons: dict[str, str] = {}
    binding: dict[str, dict[str, Any]] = {}

    def violate(kind: str, mask: NDArray[np.bool_], message: Any) -> None:
        """Record the steps of ``mask`` (K+1,) and the message of the first (a callable of k)."""
        steps[kind] |= mask
        if mask.any() and kind not in reasons:
            reasons[kind] = message(int(np.argmax(mask)))

    def bind(kind: str, margin: Array, limit: float, where: Any) -> None:
        """Least ``margin`` (any shape, axis 0 = step) of a limit and where (``where(flat index) -> (k, what, pt)``)."""
        if margin.size == 0 or not np.isfinite(margin).any():
            return
        i = int(np.nanargmin(margin))
        k, what, pt = where(i)
        m = float(margin.flat[i])
        binding[kind] = {
            "margin": m, "fraction": m / limit if limit > 0 else math.inf, "step": int(k), "t": float(t[k]),
            "what": what, "at": None if pt is None else [float(v) for v in pt],
        }  # fmt: skip

    if planner_failure:
        steps["planner"][-1] = True
        reasons["planner"] = str(planner_failure)

    # -- record ----------------------------------------------------------------------------------------------
    finite = np.isfinite(robots).all(axis=(1, 2))
    violate("record", ~finite, lambda k: f"drone positions are not finite at {_t(t, k)}")
    mismatch = []
    if abs(float(plan.safety_radius) - r) > tol or abs(float(teth.drone_radius) - r) > tol:
        mismatch.append(f"drone radius {float(plan.safety_radius):.3f} m (tether params {teth.drone_radius:.3f} m)")
    if np.asarray(plan.bounds).shape != (6,) or np.max(np.abs(np.asarray(plan.bounds, float) - w.bounds)) > tol:
        mismatch.append(f"room {np.asarray(plan.bounds).tolist()}")
    if mismatch:
        steps["record"][0] = True
        reasons.setdefault("record", f"the plan was made with {' and '.join(mismatch)}, not the world's "
                           f"(r = {r:.3f} m, room {w.bounds.tolist()})")  # fmt: skip
    robots = np.where(np.isfinite(robots), robots, 0.0)

    # -- tethers rebuilt --------------------------------------------------------------------------------------
    active = bool(getattr(teth, "active", False))
    kinds = DRONE_VIOLATION_KINDS + ((WINCH_KIND,) if active else ())
    if active:
        steps[WINCH_KIND] = np.zeros(n_k, dtype=bool)
        tw_rec = getattr(plan, "winch_tension", None)
        tw_arr = None if tw_rec is None else np.asarray(tw_rec, dtype=float)
        if tw_arr is None or tw_arr.shape != (n_k, n) or not np.isfinite(tw_arr).all():
            steps[WINCH_KIND][0] = True
            reasons[WINCH_KIND] = (
                "the plan has an active winch but records no finite winch tension of every tether at every step "
                f"({n_k} x {n}; got {None if tw_arr is None else tw_arr.shape})"
            )
            tw_arr = np.full((n_k, n), float(teth.winch_tension))
        tw: Any = tw_arr
        cur = tether_curves(base, robots, plan.tether_a, teth, winch_tension=tw_arr)
    else:
        tw = float(teth.winch_tension)
        cur = tether_curves(base, robots, plan.tether_a, teth)
    tw_tol = MODEL_TOL * np.maximum(tw, 1.0)
    bad_model = ~cur.valid | (cur.end_residual > MODEL_TOL) | (np.abs(cur.winch_error) > tw_tol) | ~cur.stable

    def model_msg(k: int) -> str:
        j = int(np.argmax(bad_model[k]))
        a = cur.a[k, j]
        head = f"tether {j + 1} at {_t(t, k)}"
        if not cur.valid[k, j]:
            if np.isnan(a):
                return f"{head} is recorded vertical (a null) but its ends are {cur.d[k, j]:.3f} m apart horizontally"
            return f"{head} has a = {a!r}, not a positive number"
        if cur.end_residual[k, j] > MODEL_TOL:
            return f"{head}: the catenary of a = {a:.6g} m misses its ends by {cur.end_residual[k, j]:.2e} m"
        tw_kj = float(tw[k, j]) if active else tw
        if abs(cur.winch_error[k, j]) > MODEL_TOL * max(tw_kj, 1.0):
            t_w = tw_kj + cur.winch_error[k, j]
            return f"{head}: a = {a:.6g} m gives {t_w:.4f} N at the winch end, not the winch tension {tw_kj:.4f} N"
        return f"{head}: a = {a:.6g} m is the unstable (deep-sag) equilibrium"

    violate("tether_model", bad_model.any(axis=1), model_msg)

    # -- active winch: the recorded tensions within the pulley's range, their rate bounded --------------------------
    winch_summary: dict[str, Any] | None = None
    if active:
        t_lo, t_hi = float(teth.winch_tension_min), float(teth.winch_tension_max)
        rate_max = float(teth.winch_tension_rate)
        slack = MODEL_TOL * max(t_hi, 1.0)
        out_lo, out_hi = tw_arr < t_lo - slack, tw_arr > t_hi + slack
        rate = np.abs(np.diff(tw_arr, axis=0)) / Ts if n_k > 1 else np.zeros((0, n))
        fast = np.zeros((n_k, n), dtype=bool)
        fast[:-1] = rate > rate_max + 2.0 * slack / Ts

        def winch_msg(k: int) -> str:
            j = int(np.argmax(out_lo[k] | out_hi[k] | fast[k]))
            if out_lo[k, j] or out_hi[k, j]:
                return (f"winch of tether {j + 1} at {tw_arr[k, j]:.4f} N at {_t(t, k)}, outside its range "
                        f"[{t_lo:g}, {t_hi:g}] N")  # fmt: skip
            return (f"winch of tether {j + 1} changes by {rate[k, j]:.4f} N/s at {_t(t, k)}, faster than its "
                    f"{rate_max:g} N/s")  # fmt: skip

        violate(WINCH_KIND, (out_lo | out_hi | fast).any(axis=1), winch_msg)
        winch_summary = {
            "mode": "active", "tension_min": t_lo, "tension_max": t_hi, "tension_rate": rate_max,
            "min_tension_used": float(tw_arr.min()), "max_tension_used": float(tw_arr.max()),
            "max_rate_used": float(rate.max()) if rate.size else 0.0,
        }  # fmt: skip

    # -- drones -----------------------------------------------------------------------------------------------
    flat = robots.reshape(-1, 3)
    d_obs, k_obs = w.obstacle_distance(flat, r + EXACT_RANGE)
    walls = np.concatenate([flat[:, :2] - w.bounds[:2], w.bounds[3:5] - flat[:, :2]], axis=1)  # faces 0, 1, 3, 4
    wall_i = np.argmin(walls, axis=1)
    d_wall = walls[np.arange(flat.shape[0]), wall_i]
    use_wall = d_wall < d_obs
    drone_d = np.where(use_wall, d_wall, d_obs).reshape(n_k, n)
    drone_what = np.where(use_wall, -1 - np.array([0, 1, 3, 4])[wall_i], k_obs).reshape(n_k, n)
    clear = drone_d - r

    def drone_msg(k: int) -> str:
        i = int(np.argmin(clear[k]))
        return (f"drone {i + 1} at {fmt_point(robots[k, i])} is {drone_d[k, i]:.3f} m from {w.label(drone_what[k, i])} "
                f"at {_t(t, k)}, less than its radius r {r:.3f} m")  # fmt: skip

    violate("drone_clearance", (clear < -tol).any(axis=1), drone_msg)
    bind("drone_clearance", clear, r, lambda i: (i // n, f"drone {i % n + 1}", robots.reshape(-1, 3)[i]))

    above = robots[..., 2] - w.bounds[2] - r
    below = w.bounds[5] - robots[..., 2] - r
    alt = np.minimum(above, below)

    def alt_msg(k: int) -> str:
        i = int(np.argmin(alt[k]))
        if above[k, i] <= below[k, i]:
            return (f"drone {i + 1} at {fmt_point(robots[k, i])} is {above[k, i] + r:.3f} m above the floor at "
                    f"{_t(t, k)}, less than its radius r {r:.3f} m")  # fmt: skip
        return (f"drone {i + 1} at {fmt_point(robots[k, i])} is {below[k, i] + r:.3f} m below the ceiling at "
                f"{_t(t, k)}, less than its radius r {r:.3f} m")  # fmt: skip

    violate("altitude", (alt < -tol).any(axis=1), alt_msg)
    bind("altitude", alt, r, lambda i: (i // n, f"drone {i % n + 1}", robots.reshape(-1, 3)[i]))

    ii, jj = np.triu_indices(n, k=1)
    sep = np.linalg.norm(robots[:, ii] - robots[:, jj], axis=-1) if ii.size else np.zeros((n_k, 0))

    def sep_msg(k: int) -> str:
        m = int(np.argmin(sep[k]))
        return (f"drones {ii[m] + 1} and {jj[m] + 1} are {sep[k, m]:.3f} m apart at {_t(t, k)}, less than "
                f"2r = {2 * r:.3f} m")  # fmt: skip

    if sep.size:
        violate("separation", (sep < 2 * r - tol).any(axis=1), sep_msg)
        npair = sep.shape[1]
        bind("separation", sep - 2 * r, 2 * r,
             lambda i: (i // npair, f"drones {ii[i % npair] + 1} and {jj[i % npair] + 1}", None))  # fmt: skip

    # -- tether curves ----------------------------------------------------------------------------------------
    base_clear = float(w.distance(base[None])[0][0])
    if base_clear < -tol:
        steps["record"][0] = True
        reasons.setdefault("record", f"the anchor {fmt_point(base)} is {-base_clear:.3f} m inside an obstacle or "
                           "outside the room")  # fmt: skip
    limit = np.full((n_k, n), c_t)
    # no closer than the winch itself (a winch on the floor), less the sampling resolution: a curve that starts
    # exactly at its limit can be certified only to within FINE of it
    limit[:, 0] = min(c_t, base_clear - FINE)
    t_min, t_s, t_lb, t_what, n_samples = _curve_clearance(w, cur, limit, tol, cur.valid)
    bad_curve = (t_lb < limit - tol) & cur.valid
    t_point = lambda k, j: curve_points(cur, np.array([k * n + j]), np.array([t_s[k, j]]))[0]  # noqa: E731

    def curve_msg(k: int) -> str:
        j = int(np.argmax(np.where(bad_curve[k], limit[k] - t_lb[k], -np.inf)))
        value = t_min[k, j] if t_min[k, j] < limit[k, j] - tol else t_lb[k, j]
        lim_txt = f"c_t {c_t:.3f} m" if limit[k, j] == c_t else f"the winch's own clearance {limit[k, j]:.3f} m"
        where = f"{w.label(t_what[k, j])} at {fmt_point(t_point(k, j))}"
        return f"tether {j + 1} curve {_m(value, limit[k, j])} m from {where} at {_t(t, k)}, less than {lim_txt}"

    violate("tether_clearance", bad_curve.any(axis=1), curve_msg)
    margin_c = np.where(cur.valid, t_min - limit, np.nan)
    bind("tether_clearance", margin_c, c_t, lambda i: (i // n, f"tether {i % n + 1}", t_point(i // n, i % n)))
    if "tether_clearance" in binding:  # does the sag bind? the chord's clearance at that step, for comparison
        b = binding["tether_clearance"]
        k, j = b["step"], int(b["what"].split()[1]) - 1
        ends = np.array([cur.p[k, j], cur.q[k, j]])
        chord = ends[0] + np.linspace(0.0, 1.0, max(2, int(np.ceil(np.linalg.norm(ends[1] - ends[0]) / 0.005)) + 1))[
            :, None] * (ends[1] - ends[0])  # fmt: skip
        b["chord_clearance"] = float(w.distance(chord)[0].min())
        b["curve_clearance"] = float(t_min[k, j])

    over_len = cur.length - l_max
    violate("tether_length", (over_len > tol).any(axis=1),
            lambda k: (f"tether {int(np.argmax(over_len[k])) + 1} is {cur.length[k, int(np.argmax(over_len[k]))]:.3f} "
                       f"m long at {_t(t, k)}, more than L_max {l_max:.3f} m"))  # fmt: skip
    bind("tether_length", -over_len, l_max, lambda i: (i // n, f"tether {i % n + 1}", None))

    # tension at every drone end: Q is drone j; P is drone j-1 for j >= 2
    tens = np.stack([np.where(np.arange(n) >= 1, cur.tension_p, -np.inf), cur.tension_q], axis=-1)  # (K+1, N, 2)
    over_t = tens - f_max

    def tension_msg(k: int) -> str:
        j, e = np.unravel_index(int(np.argmax(over_t[k])), over_t[k].shape)
        drone = j + 1 if e == 1 else j
        return (f"tether {j + 1} pulls drone {drone} with {tens[k, j, e]:.3f} N at {_t(t, k)}, more than its spare "
                f"thrust {f_max:.3f} N")  # fmt: skip

    # the thrust a drone needs against ALL its tethers (a middle drone carries two): |m g e_z - F_q(j) - F_p(j+1)|
    # <= (1 - reserve) T/W m g, with the end forces of the rebuilt curves (H = rho g a along the tangent: on P
    # +H (u + sinh(theta_P) e_z), on Q -H (u + sinh(theta_Q) e_z); a vertical tether pulls its ends towards each other)
    ez = np.array([0.0, 0.0, 1.0])
    curved = ~cur.vertical & cur.valid
    H = np.where(curved, float(teth.mass_per_length) * float(teth.g) * np.where(curved, cur.a, 0.0), 0.0)
    up = np.where(cur.h >= 0.0, 1.0, -1.0)  # +1: P is the lower end
    f_p = np.where(curved[..., None], H[..., None] * (cur.u + cur.sinh_p[..., None] * ez),
                   (up * cur.tension_p)[..., None] * ez)  # fmt: skip
    f_q = np.where(curved[..., None], -H[..., None] * (cur.u + cur.sinh_q[..., None] * ez),
                   (-up * cur.tension_q)[..., None] * ez)  # fmt: skip
    pull = f_q.copy()  # (K+1, N, 3): on drone j, tether j's Q end plus tether j+1's P end
    pull[:, :-1] += f_p[:, 1:]
    weight = float(teth.drone_mass) * float(teth.g)
    available = (1.0 - float(teth.control_reserve)) * float(teth.thrust_to_weight) * weight
    need = np.linalg.norm(weight * ez - pull, axis=-1)  # (K+1, N) [N]
    over_need = np.where(np.isfinite(need), need - available, -np.inf)

    def thrust_msg(k: int) -> str:
        if (over_t[k] > tol).any():
            return tension_msg(k)
        i = int(np.argmax(over_need[k]))
        return (f"drone {i + 1} needs {need[k, i]:.3f} N of thrust against its tethers and its weight at {_t(t, k)}, "
                f"more than the {available:.3f} N it has beyond its control reserve")  # fmt: skip

    violate("tension", (over_t > tol).any(axis=(1, 2)) | (over_need > tol).any(axis=1), thrust_msg)
    bind("tension", -over_t, f_max,
         lambda i: (i // (2 * n), f"tether {(i // 2) % n + 1} at drone {(i // 2) % n + i % 2}", None))  # fmt: skip

    # -- speed, acceleration -------------------------------------------------------------------------------------
    axes = "xyz"
    if n_k > 1:
        vel = np.diff(robots, axis=0) / Ts  # (K, N, 3) held on [t_k, t_k+1]
        over_v = np.abs(vel) - v_max
        mask_v = np.zeros(n_k, dtype=bool)
        mask_v[:-1] = (over_v > 2 * tol / Ts).any(axis=(1, 2))

        def speed_msg(k: int) -> str:
            i, ax = np.unravel_index(int(np.argmax(over_v[k])), over_v[k].shape)
            return (f"drone {i + 1} moves at {abs(vel[k, i, ax]):.3f} m/s along {axes[ax]} at {_t(t, k)}, more than "
                    f"{v_max:.3f} m/s")  # fmt: skip

        violate("speed", mask_v, speed_msg)
        bind("speed", -over_v, v_max, lambda i: (i // (3 * n), f"drone {(i // 3) % n + 1} along {axes[i % 3]}", None))
        # the chain starts and ends at rest: the velocity is 0 before t_0 and after t_K, so the first step's start
        # and the last step's stop are accelerations too
        # a plan the planner itself failed was cut off where it stopped: its last state is not a stop at rest
        rest_end = rest_ends and not planner_failure
        before = np.zeros((1, n, 3)) if rest_ends else vel[:1]
        after = np.zeros((1, n, 3)) if rest_end else vel[-1:]
        acc = np.diff(np.concatenate([before, vel, after]), axis=0) / Ts  # (K+1, N, 3) at steps 0..K
        over_a = np.abs(acc) - a_max
        mask_a = (over_a > 4 * tol / Ts**2).any(axis=(1, 2))

        def acc_msg(k: int) -> str:
            i, ax = np.unravel_index(int(np.argmax(over_a[k])), over_a[k].shape)
            what = " (stopping: the plan ends there, at rest)" if k == n_k - 1 else ""
            return (f"drone {i + 1} accelerates at {abs(acc[k, i, ax]):.3f} m/s² along {axes[ax]} at "
                    f"{_t(t, k)}{what}, more than {a_max:.3f} m/s²")  # fmt: skip

        violate("acceleration", mask_a, acc_msg)
        bind("acceleration", -over_a, a_max,
             lambda i: (i // (3 * n), f"drone {(i // 3) % n + 1} along {axes[i % 3]}", None))  # fmt: skip
        # jerk: the change of that acceleration per step; at rest ends the acceleration is 0 before the start and
        # after the stop too (hovering), so the start's and the stop's jerks count (the last two at step K)
        # (K+2, N, 3): steps 0..K, then K again; a jerk next to an end that is no rest (acc[0] or acc[K] then 0 by
        # construction, not a real acceleration) is 0
        jerk = np.zeros((n_k + 1, n, 3))
        jerk[1:n_k] = np.diff(acc, axis=0) / Ts
        if rest_ends:
            jerk[0] = acc[0] / Ts
        else:
            jerk[1] = 0.0
        if rest_end:
            jerk[n_k] = -acc[-1] / Ts
        else:
            jerk[n_k - 1] = 0.0
        over_j = np.abs(jerk) - j_max
        mask_j = np.zeros(n_k, dtype=bool)
        bad_j = (over_j > 8 * tol / Ts**3).any(axis=(1, 2))
        mask_j |= bad_j[:n_k]
        mask_j[-1] |= bool(bad_j[n_k:].any())

        def jerk_msg(k: int) -> str:
            kk = k if k < n_k - 1 or over_j[k].max() >= over_j[k + 1].max() else k + 1
            i, ax = np.unravel_index(int(np.argmax(over_j[kk])), over_j[kk].shape)
            what = " (stopping: the plan ends there, at rest)" if k == n_k - 1 else ""
            return (f"drone {i + 1}'s acceleration changes at {abs(jerk[kk, i, ax]):.3f} m/s³ along {axes[ax]} at "
                    f"{_t(t, k)}{what}, more than {j_max:.3f} m/s³")  # fmt: skip

        if math.isfinite(j_max):  # a jerk limit was planned with (DroneParams.drone_jerk_max)
            violate("jerk", mask_j, jerk_msg)
            bind("jerk", -over_j, j_max,
                 lambda i: (min(i // (3 * n), n_k - 1), f"drone {(i // 3) % n + 1} along {axes[i % 3]}",
                            None))  # fmt: skip
    else:
        vel = np.zeros((0, n, 3))
        over_v = np.zeros((0, n, 3))
        acc = np.zeros((0, n, 3))
        over_a = np.zeros((0, n, 3))
        jerk = np.zeros((0, n, 3))

    # -- goal -----------------------------------------------------------------------------------------------------
    final_err = float(np.linalg.norm(robots[-1, -1] - goal))
    if final_err > goal_tol + tol:
        steps["goal"][-1] = True
        reasons["goal"] = (f"the leader ends at {fmt_point(robots[-1, -1])}, {final_err:.3f} m from the goal "
                           f"{fmt_point(goal)}, more than the tolerance {goal_tol:.3f} m")  # fmt: skip

    # -- fitness ------------------------------------------------------------------------------------------------
    pts = np.concatenate([np.broadcast_to(base, (n_k, 1, 3)), robots], axis=1)
    chords = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    ci, cj = np.triu_indices(n, k=1)
    reference = np.asarray(plan.reference, dtype=float).reshape(n_k, 3)
    track = np.linalg.norm(robots[:, -1] - reference, axis=-1)
    raw = [
        float(np.sum(vel * vel)),
        float(np.sum((chords[:, ci] - chords[:, cj]) ** 2)),
        float(np.sum(track[1:] ** 2)),
        float(np.sum(acc * acc)),
    ]
    failures = [reasons[k] for k in kinds if k in reasons]
    success = not failures
    fit = raw if success else [math.inf] * 4
    any_step = np.logical_or.reduce([steps[k] for k in kinds])
    fractions = {k: binding[k]["fraction"] for k in LIMIT_KINDS if k in binding}
    binding_limit = min(fractions, key=lambda k: fractions[k]) if fractions else None
    metrics = DroneMetrics(
        scenario=str(plan.scenario),
        method=str(plan.method),
        success=success,
        failure="; ".join(failures) if failures else None,
        failures=failures,
        n_robots=int(n),
        n_steps=int(n_k - 1),
        Ts=Ts,
        duration=float(t[-1] - t[0]),
        f1=fit[0],
        f2=fit[1],
        f3=fit[2],
        f4=fit[3],
        fitness_raw=raw,
        leader_path_length=float(np.linalg.norm(np.diff(robots[:, -1], axis=0), axis=-1).sum()),
        final_leader_error=final_err,
        goal_tolerance=goal_tol,
        max_tracking_error=float(track.max()),
        safety_radius=r,
        tether_clearance_limit=c_t,
        tether_length_max=l_max,
        tension_max=f_max,
        speed_max=v_max,
        accel_max=a_max,
        jerk_max=j_max if math.isfinite(j_max) else None,
        min_drone_clearance=float(clear.min()),
        min_altitude_margin=float(alt.min()),
        min_separation=float(sep.min()) if sep.size else math.inf,
        min_tether_clearance=float(np.nanmin(np.where(cur.valid, t_min, np.nan))) if cur.valid.any() else math.nan,
        max_tether_length=float(np.nanmax(cur.length)),
        max_drone_tension=float(np.max(tens)),
        peak_speed=float(np.abs(vel).max()) if vel.size else 0.0,
        peak_acceleration=float(np.abs(acc).max()) if acc.size else 0.0,
        peak_jerk=float(np.abs(jerk).max()) if jerk.size else 0.0,
        max_end_residual=float(cur.end_residual.max()),
        max_winch_tension_error=float(np.abs(cur.winch_error).max()),
        binding_limit=binding_limit,
        binding=binding,
        violation_steps={k: np.flatnonzero(steps[k]).tolist() for k in kinds},
        first_violation={k: (int(np.argmax(steps[k])) if steps[k].any() else None) for k in kinds},
        n_violation_steps=int(np.count_nonzero(any_step)),
        tolerance=tol,
        per_step={
            "drone_clearance": clear.min(axis=1),
            "altitude_margin": alt.min(axis=1),
            "separation": sep.min(axis=1) if sep.size else np.full(n_k, math.inf),
            "tether_clearance": t_min,  # least sample: within 1 cm of the curve's only near the plan's least margin
            "tether_length": cur.length,
            "tension_p": cur.tension_p,
            "tension_q": cur.tension_q,
        },
        winch=winch_summary,
    )
    metrics.curve_samples = n_samples
    metrics.check_time = time.perf_counter() - start
    if update_plan:
        if isinstance(getattr(plan, "diagnostics", None), dict):
            plan.diagnostics.setdefault("planner_failure", planner_failure)
        plan.success = metrics.success
        plan.failure = metrics.failure
    return metrics
