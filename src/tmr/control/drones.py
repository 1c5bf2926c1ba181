"""Tasks and hard limits of a tethered drone chain, and its two formulations (``formulations/drones.md``, sections
"Per-step QP (3-D)" and "pinv (3-D)").

The QP works in the drones' velocities v = [ṗ1, …, ṗN] (3N, m/s): every row on a drone or a tether point is local in
v (no gimbal lock at vertical tethers), and :class:`~tmr.model.velocity.VelocityMap3D` gives the singularity-free
link coordinates the lexicographic QP couples to v. Each tether hangs as the catenary of
:mod:`tmr.model.catenary3d`; its sample points, arc length and end tensions move with its two ends through the
Jacobians of :func:`~tmr.model.catenary3d.sensitivities`, so a limit on the curve is a linear row in the ends'
velocities. Every limit is linearised at the current positions and kept over one step with the velocity damper of
the ground chain (:func:`tmr.control.limits.approach_bound`): a margin g ≥ 0 may shrink at most by
``min(rate Ts, 1) g`` in one step.

:func:`make_drone_qp` stacks, as the ground planner does (``tmr.planner.make_qp``): level 1 the leader's reference,
level 2 the tethers' regulation with the followers' route references (and a little smoothness), level 3 energy and
smoothness; hard limits every level keeps: drone clearance, the room (floor, ceiling, walls), separation, tether
curve clearance, arc length, drone-end tension, speed, acceleration and jerk.
:func:`make_drone_pinv` is Caruso 2021's CLIK (eq. 5) on the 3N-joint ``Chain(spatial=True)``: leader task, then a
soft obstacle task at the critical point, tether regulation in the null space (gradient projection, eq. 7).
"""

from __future__ import annotations

import math
import threading
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from tmr.control.limits import Limit, LimitRows, RobotSeparation, _infinite, approach_bound
from tmr.control.pinv import dls_inverse, null_space_projector
from tmr.control.qp import Level, LexicographicQP
from tmr.control.tasks import Task, TaskRows
from tmr.control.winch import (
    WINCH_GAIN,
    WINCH_WEIGHT,
    PaddedLimit,
    PaddedTask,
    WinchChain,
    WinchReturn,
    WinchVelocityMap,
)
from tmr.errors import ParameterError
from tmr.model.catenary3d import (
    Catenary3D,
    DroneTetherParams,
    TetherCatenaries,
    TetherSensitivities,
    sensitivities_batch,
    solve3d_batch,
)
from tmr.model.chain import Chain
from tmr.model.params import DroneParams
from tmr.model.velocity import VelocityMap3D
from tmr.world.world3d import World3D

Array = NDArray[np.float64]

__all__ = [
    "DroneReferencesLike",
    "DroneStepContext",
    "DroneLeader",
    "DroneFollowers",
    "TetherChords",
    "DroneEnergy",
    "DroneSmoothness",
    "DroneClearance",
    "RoomBounds",
    "DroneSeparation",
    "TetherClearance",
    "TetherLength",
    "TetherTension",
    "DroneSpeed",
    "DroneAcceleration",
    "DroneJerk",
    "DroneQP",
    "DronePinv",
    "make_drone_qp",
    "make_drone_pinv",
    "WinchVelocityMap",
    "WinchChain",
    "WinchTensionRange",
    "WinchRate",
    "WinchReturn",
]


class DroneReferencesLike(Protocol):
    """What the formulations read of the references (``tmr.route.route3d.DroneReferences`` has it): times t (K+1,)
    [s], the leader's x (K+1, 3) [m] and xd (K+1, 3) [m/s], every drone's positions (K+1, N, 3) [m] and velocities
    (K+1, N, 3) [m/s] along the route."""

    t: Array
    x: Array
    xd: Array
    positions: Array
    velocities: Array


class _FreeBox:
    """The QP's box on the link rates: none (every drone limit is a row on v); kept for the QP's interface."""

    def __init__(self, n: int) -> None:
        self.lo, self.hi = np.full(n, -np.inf), np.full(n, np.inf)

    def compute(self, ctx: Any, relax: bool = False) -> tuple[Array, Array]:
        return self.lo, self.hi


def _cross(x: Array, y: Array) -> Array:
    """Row-wise cross product x × y of (M, 3) arrays: np.cross's arithmetic (x1 y2 − x2 y1, …, bit for bit) in four
    numpy calls instead of ~20 (np.cross moves axes and checks shapes: ~15 µs on a few rows)."""
    return x[:, _NEXT] * y[:, _PREV] - x[:, _PREV] * y[:, _NEXT]


_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])
_AXES = np.eye(3)


def _segment_frames(a: Array, b: Array) -> tuple[Array, Array, Array]:
    """Per segment a–b (M, 3): the rotation (M, 3, 3) whose z axis is along it, its midpoint (M, 3) and half length
    (M,) — the placement of coal's capsule (axis z) — all at once in numpy."""
    v = b - a
    length = np.sqrt(np.einsum("ij,ij->i", v, v))
    u = np.where((length > 0.0)[:, None], v / np.maximum(length, 1e-300)[:, None], _AXES[2])  # a point: any axis
    helper = np.where((np.abs(u[:, 0]) < 0.9)[:, None], _AXES[0], _AXES[1])
    e1 = _cross(helper, u)
    e1 /= np.maximum(np.sqrt(np.add.reduce(e1 * e1, axis=1)), 1e-300)[:, None]  # np.linalg.norm's sum
    R = np.stack([e1, _cross(u, e1), u], axis=2)
    return R, 0.5 * (a + b), 0.5 * length


def segment_box_distance(a: Array, b: Array, lo: Array, hi: Array) -> tuple[Array, Array]:
    """Exact distance [m] from the segments a–b (M, 3) to the axis-aligned box [lo, hi] (3,) — or, per segment, to
    its own box (M, 3) each — and the parameter t ∈ [0, 1] of the segment's nearest point (M,), vectorised. Along a
    segment the squared distance is piecewise quadratic in t, with breakpoints where a coordinate crosses a face: on
    each of the (≤ 7) pieces the minimiser is the clipped stationary point of its quadratic; the smallest over the
    pieces is the minimum (the distance is convex in t). 0 for a segment touching or crossing the box (its depth is
    not computed here)."""
    lo3, hi3 = (lo, hi) if np.ndim(lo) == 1 else (lo[:, None, :], hi[:, None, :])  # against the (M, 7, 3) pieces
    v = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = np.concatenate([(lo - a) / v, (hi - a) / v], axis=1)  # (M, 6); ±inf/nan where v_k = 0
    cross = np.where(np.isfinite(cross), np.clip(cross, 0.0, 1.0), 0.0)
    knots = np.sort(np.concatenate([np.zeros((a.shape[0], 1)), cross, np.ones((a.shape[0], 1))], axis=1), axis=1)
    t0, t1 = knots[:, :-1], knots[:, 1:]  # (M, 7) pieces
    x_mid = a[:, None, :] + (0.5 * (t0 + t1))[..., None] * v[:, None, :]  # (M, 7, 3)
    below, above = x_mid < lo3, x_mid > hi3
    bound = np.where(below, lo3, np.where(above, hi3, 0.0))
    active = below | above
    off = np.where(active, a[:, None, :] - bound, 0.0)  # x_k(t) − bound_k = off_k + t v_k on the active axes
    vv = np.where(active, v[:, None, :], 0.0)
    den = np.einsum("mpk,mpk->mp", vv, vv)
    num = -np.einsum("mpk,mpk->mp", off, vv)
    with np.errstate(divide="ignore", invalid="ignore"):
        ts = np.where(den > 0.0, num / den, t0)
    ts = np.clip(ts, t0, t1)
    X = a[:, None, :] + ts[..., None] * v[:, None, :]
    gap = X - np.clip(X, lo3, hi3)
    dist = np.sqrt(np.einsum("mpk,mpk->mp", gap, gap))
    best = np.argmin(dist, axis=1)
    rows = np.arange(a.shape[0])
    return dist[rows, best], ts[rows, best]


#: the inward normals of the room's six faces (x = xmin, y = ymin, z = zmin, x = xmax, y = ymax, z = zmax)
_WALL_NORMALS = np.vstack([np.eye(3), -np.eye(3)])


def segment_nearest_k(
    world: World3D, a: Array, b: Array, k: int, cap: float = np.inf, walls: bool = True, within: float | None = None
) -> tuple[Array, Array, Array, NDArray[np.int64]]:
    """The ``k`` nearest obstacles of each segment a–b (M, 3), one by one: per segment and slot (M, k), sorted by
    clearance, the clearance [m] of the segment from that obstacle (the room's six walls each count as one when
    ``walls``), the unit gradient (M, k, 3) of that clearance at the segment's point nearest it (from the obstacle's
    nearest point towards it; away from the wall) and that point's parameter t ∈ [0, 1] along a → b. Boxes in closed
    form (:func:`segment_box_distance`), other obstacles (and a segment touching a box) by a capsule query of radius 0
    (coal, as :meth:`World3D.segment_clearance`, with the capsules' placements computed at once); a wall's term is
    affine along a segment, so its minimum is at an end. A point is the segment a = b. Obstacles whose bounding box
    is farther than ``cap`` [m] (beyond the world's safety radius) from a segment are not queried; a slot with no
    obstacle left has clearance +inf, gradient 0 and t = 0. Also returns, as the fourth value, how many obstacles
    each segment has within a clearance ``within`` [m] (default ``cap``) (M,): more than ``k`` means the farthest of
    them got no slot.

    The work is per (segment, obstacle) candidate pair of the broad phase, not per obstacle: every box pair in one
    call of :func:`segment_box_distance`, every other pair in one loop of coal queries (~2 µs each; their nearest
    points turned into gradients at once after it), written into one (M, walls + obstacles) table sorted once."""

    M = a.shape[0]
    k = int(k)
    W = 6 if walls else 0
    n_obs = len(world.obstacles)
    ncol = max(W + n_obs, k)  # walls, then one column per obstacle (+inf if not queried), then empty slots
    C = np.full((M, ncol), np.inf)
    G = np.zeros((M, ncol, 3))
    T = np.zeros((M, ncol))
    if walls:  # the six faces of the room, each an obstacle of its own (x = xmin, y = ymin, z = zmin, then the max)
        lo_room, hi_room = world._lo, world._hi
        ga = np.concatenate([a - lo_room, hi_room - a], axis=1)  # (M, 6)
        gb = np.concatenate([b - lo_room, hi_room - b], axis=1)
        np.minimum(ga, gb, out=C[:, :6])
        T[:, :6] = gb < ga
        G[:, :6] = _WALL_NORMALS
    if n_obs:
        near = world.box_gaps(np.minimum(a, b), np.maximum(a, b)) < cap + world.safety_radius  # (O, M)
        co, cs = np.nonzero(near)  # the candidate pairs (obstacle, segment)
        if world.is_box.any():  # boxes in numpy (exact), all pairs at once; coal only for a segment touching one
            box = world.is_box[co]
            bo, bs = co[box], cs[box]
            lo, hi = world.aabb_lo[bo], world.aabb_hi[bo]
            ab, bb = a[bs], b[bs]
            dist, tb = segment_box_distance(ab, bb, lo, hi)
            closer = dist > 1e-9
            X = ab[closer] + tb[closer, None] * (bb[closer] - ab[closer])
            cols = W + bo[closer]
            C[bs[closer], cols], T[bs[closer], cols] = dist[closer], tb[closer]
            G[bs[closer], cols] = (X - np.clip(X, lo[closer], hi[closer])) / dist[closer, None]
            box[np.flatnonzero(box)[~closer]] = False  # the touching pairs: to coal
            co, cs = co[~box], cs[~box]
        if co.size:
            _segment_coal_pairs(world, a, b, co, cs, C[:, W:], G[:, W:], T[:, W:])
    count = np.count_nonzero(C <= (cap if within is None else within) + world.safety_radius, axis=1)
    order = np.argsort(C, axis=1, kind="stable")[:, :k] if ncol > 1 else np.zeros((M, 1), dtype=np.intp)
    flat = order + _row_offsets(M, ncol)  # flat indices of the sorted slots (one take each, not 2-D fancy indexing)
    return C.take(flat) - world.safety_radius, G.reshape(-1, 3)[flat], T.take(flat), count


def _row_offsets(M: int, ncol: int) -> NDArray[np.intp]:
    """(M, 1) offsets i·ncol of the rows of an (M, ncol) table in its flat form (cached: the shapes are per plan)."""
    key = (M, ncol)
    out = _ROW_OFFSETS.get(key)
    if out is None:
        out = _ROW_OFFSETS[key] = (np.arange(M) * ncol)[:, None]
    return out


_ROW_OFFSETS: dict[tuple[int, int], NDArray[np.intp]] = {}
_COAL_SCRATCH = threading.local()


def _coal_scratch() -> list[Any]:
    """coal objects reused by every query of this thread (their values are set before each; constructing them costs
    ~1 µs a query): the segments' capsule, placement and result, then the points' placement (a translation only, never
    rotated) and result."""
    objs = getattr(_COAL_SCRATCH, "objs", None)
    if objs is None:
        import coal

        objs = _COAL_SCRATCH.objs = [
            coal.Capsule(0.0, 1.0),
            coal.Transform3s(),
            coal.DistanceResult(),
            coal.Transform3s(),
            coal.DistanceResult(),
        ]
    return objs


def _segment_coal_pairs(
    world: World3D, a: Array, b: Array, co: NDArray[np.intp], cs: NDArray[np.intp], C: Array, G: Array, T: Array
) -> None:
    """coal's radius-0 capsule queries of the pairs (obstacle ``co``, segment ``cs``) of :func:`segment_nearest_k`,
    written into its tables (columns per obstacle): C[cs, co] the clearance [m] (negative inside), G the unit
    gradient (from the obstacle's nearest point towards the segment's; touching: away from the bounding box's
    centre), T the nearest point's parameter along a → b. The queries alone in the loop (coal: ~2 µs each); their
    results are turned into rows at once after it."""
    import coal

    from tmr.world.world3d import _REQUEST, _winding_number

    capsule, place, res = _coal_scratch()[:3]
    ca, cb = a[cs], b[cs]
    R, mid, half = _segment_frames(ca, cb)
    targets = world.coal_targets
    d_l: list[float] = []
    p1_l: list[Array] = []
    p2_l: list[Array] = []
    for Ri, mi, hl, o in zip(R, mid, np.maximum(half, 1e-12).tolist(), co.tolist(), strict=True):
        capsule.halfLength = hl
        place.setRotation(Ri)
        place.setTranslation(mi)
        res.clear()
        shape2, place2 = targets[o]
        d_l.append(coal.distance(capsule, place, shape2, place2, _REQUEST, res))
        p1_l.append(res.getNearestPoint1())
        p2_l.append(res.getNearestPoint2())
    d = np.array(d_l)
    p1, p2 = np.array(p1_l), np.array(p2_l)
    if not world.is_signed.all():  # a triangle BVH: its sign from the winding number of the segment's ends
        inside = np.zeros(co.size, dtype=bool)
        for o in np.unique(co[~world.is_signed[co]]).tolist():
            tri = world.obstacles[o].triangles
            assert tri is not None
            sel = co == o
            w = _winding_number(np.vstack([ca[sel], cb[sel]]), tri)
            n_sel = int(np.count_nonzero(sel))
            inside[sel] = (np.abs(w[:n_sel]) > 0.5) | (np.abs(w[n_sel:]) > 0.5)
        d = np.where(inside & (d > 0.0), -np.abs(d), d)
    v = p1 - p2
    nv = np.sqrt(np.einsum("ij,ij->i", v, v))
    grad = np.copysign(1.0, d)[:, None] * v / np.maximum(nv, 1e-300)[:, None]
    touching = ~(nv > 1e-12)
    if touching.any():  # away from the bounding box's centre
        off = 0.5 * (ca + cb) - 0.5 * (world.aabb_lo[co] + world.aabb_hi[co])
        off /= np.maximum(np.sqrt(np.add.reduce(off * off, axis=1)), 1e-12)[:, None]
        grad[touching] = off[touching]
    along = np.einsum("ij,ij->i", p1 - mid, R[:, :, 2]) / np.maximum(2.0 * half, 1e-300)
    C[cs, co] = d
    G[cs, co] = grad
    T[cs, co] = np.where(half > 1e-12, np.clip(0.5 + along, 0.0, 1.0), 0.0)


def point_nearest_k(world: World3D, points: Array, k: int, cap: float = np.inf) -> tuple[Array, Array, Array]:
    """:func:`segment_nearest_k` for points (M, 3) and the obstacles only (no walls), cheaper: per point and slot
    (M, k), sorted, the clearance [m] from that obstacle (World3D's radius subtracted; negative inside), its unit
    gradient (M, k, 3) and how many obstacles are within ``cap`` [m] (M,). Boxes in closed form (inside: the depth to
    the nearest face), other obstacles by coal's point query (as :meth:`World3D.clearance`); per (point, obstacle)
    candidate pair of the broad phase: every box pair at once, every other pair in one loop of coal queries."""
    import coal

    from tmr.world.world3d import _POINT, _REQUEST, _winding_number

    M = points.shape[0]
    k = int(k)
    ncol = max(k, len(world.obstacles))
    C = np.full((M, ncol), np.inf)
    G = np.zeros((M, ncol, 3))
    r = world.safety_radius
    co, cs = np.nonzero(world.box_gaps(points, points) < cap + r)  # candidate pairs (obstacle, point)
    if world.is_box.any():
        box = world.is_box[co]
        bo, bs = co[box], cs[box]
        lo, hi = world.aabb_lo[bo], world.aabb_hi[bo]
        p = points[bs]
        off = p - np.clip(p, lo, hi)
        d = np.sqrt(np.einsum("ij,ij->i", off, off))
        g = off / np.maximum(d, 1e-300)[:, None]
        inside = d <= 0.0
        if inside.any():  # the depth to the nearest face, the gradient along its outward normal
            faces = np.concatenate([p[inside] - lo[inside], hi[inside] - p[inside]], axis=1)
            f = np.argmin(faces, axis=1)
            d[inside] = -faces[np.arange(len(f)), f]
            g[inside] = -_WALL_NORMALS[f]
        C[bs, bo], G[bs, bo] = d, g
        co, cs = co[~box], cs[~box]
    if co.size:
        place, res = _coal_scratch()[3:]  # a translation only (the segments' placement is rotated)
        targets = world.coal_targets
        d_l: list[float] = []
        q_l: list[Array] = []
        p = points[cs]
        for pi, o in zip(p, co.tolist(), strict=True):  # the queries alone in the loop
            place.setTranslation(pi)
            res.clear()
            shape2, place2 = targets[o]
            d_l.append(coal.distance(_POINT, place, shape2, place2, _REQUEST, res))
            q_l.append(res.getNearestPoint2())
        d = np.array(d_l)
        if not world.is_signed.all():  # a triangle BVH: its sign from the winding number
            sign = np.ones(co.size)
            for o in np.unique(co[~world.is_signed[co]]).tolist():
                sel = co == o
                tri = world.obstacles[o].triangles
                assert tri is not None
                sign[sel] = np.where(np.abs(_winding_number(p[sel], tri)) > 0.5, -1.0, 1.0)
            d = np.where(world.is_signed[co], d, sign * np.abs(d))
        v = p - np.array(q_l)
        nv = np.sqrt((v[:, None, :] @ v[:, :, None])[:, 0, 0])  # a dot product per row, as np.linalg.norm(v_i)
        g = np.copysign(1.0, d)[:, None] * v / np.maximum(nv, 1e-300)[:, None]
        g[~(nv > 1e-12)] = 0.0
        C[cs, co], G[cs, co] = d, g
    count = np.count_nonzero(C <= cap + r, axis=1)
    order = np.argsort(C, axis=1, kind="stable")[:, :k]
    flat = order + _row_offsets(M, ncol)
    return C.take(flat) - r, G.reshape(-1, 3)[flat], count


def segment_nearest(world: World3D, a: Array, b: Array, cap: float = np.inf) -> tuple[Array, Array, Array]:
    """Clearance [m] of the segments a–b (M, 3) in ``world`` (its walls included), the unit gradient (M, 3) of the
    clearance at the segment's nearest point and that point's parameter t ∈ [0, 1] along a → b (M,): the nearest
    slot of :func:`segment_nearest_k`. Obstacles farther than ``cap`` [m] are not queried (the walls always are)."""
    c, g, t, _ = segment_nearest_k(world, a, b, 1, cap)
    return c[:, 0], g[:, 0], t[:, 0]


class DroneStepContext:
    """Per-step state of the drone chain shared by tasks and limits (computed once per step by :meth:`update`).

    Attributes (after ``update``): k, points (N+1, 3) (anchor then drones) [m], v_prev (3N,) the previous step's
    velocities [m/s], v_prev2 (3N,) the ones of the step before it [m/s] (the jerk rows), velocity_map
    (:class:`VelocityMap3D`), qdot_prev = T v_prev (link rates), tethers (the N tethers' catenaries as arrays,
    :class:`~tmr.model.catenary3d.TetherCatenaries`, tether j from point j−1 to point j), catenaries (the same
    as one :class:`Catenary3D` per tether, built on first use), sens (their stacked
    :class:`~tmr.model.catenary3d.TetherSensitivities` at the interior fractions i/(m+1), i = 1..m),
    drone_clearance (N,) [m] and drone_gradient (N, 3) (the world grown by the drone radius), sample_points
    (N, m, 3); each tether as the polyline through its ends and samples, per piece (N, m+1): segment_clearance [m],
    segment_gradient (N, m+1, 3), segment_t (the nearest point's parameter on the piece), in the world with radius 0
    (the bare obstacles and walls); the same per piece and per obstacle for the ``nearest`` nearest obstacles
    (:func:`segment_nearest_k`, each wall one obstacle): piece_clearance (N, m+1, k) [m] (+inf: no obstacle within
    the cap), piece_gradient (N, m+1, k, 3), piece_t (N, m+1, k); chord_deviation (N,) [m] the bound on how far each
    tether's arc departs from its chord over one piece, min(δ²/(8a), δ/2) with δ = L/(m+1) (0 for a vertical tether);
    and per drone and obstacle (no walls: :class:`RoomBounds` has them) drone_obstacle_clearance (N, k_d) [m] and
    drone_obstacle_gradient (N, k_d, 3); uncovered: how many (piece or drone, obstacle) pairs within the cap got no
    slot this step (0 when ``nearest`` covers them all). x_d, xd_d the leader's reference; ref_positions,
    ref_velocities (N, 3). q: the 3N joints (``pinv`` only, else None).

    Args:
        chain: ``Chain(n, base, spatial=True)``.
        world: the world with ``safety_radius`` = the drone radius r.
        tether: tether and drone parameters.
        references: the route references (:class:`DroneReferencesLike`).
        Ts: sampling period [s]; samples: interior tether samples m per tether.
        cap: tether pieces farther than this [m] from an obstacle's bounding box skip the exact query (their rows
            are inactive: use the limits' activation distance).
        nearest: obstacles (walls included) per tether piece with a row of their own; drone_nearest: obstacles per
            drone (walls excluded), within ``drone_cap`` [m].
    """

    def __init__(
        self,
        chain: Chain,
        world: World3D,
        tether: DroneTetherParams,
        references: DroneReferencesLike,
        Ts: float,
        samples: int,
        cap: float = np.inf,
        nearest: int = 1,
        drone_nearest: int = 1,
        drone_cap: float = np.inf,
    ) -> None:
        if not chain.spatial:
            raise ParameterError("a drone chain is a spatial chain: Chain(n, base, spatial=True)")
        self.chain = chain
        self.world = world
        self.bare = world.with_safety_radius(0.0)
        self.tether = tether
        self.references = references
        self.Ts = float(Ts)
        self.fractions = np.arange(1, int(samples) + 1) / (int(samples) + 1)
        #: tether pieces farther than this from every obstacle are not queried exactly [m] (their rows are inactive)
        self.cap = float(cap)
        self.nearest, self.drone_nearest, self.drone_cap = int(nearest), int(drone_nearest), float(drone_cap)
        self.k = 0
        self.q: Array | None = None
        self.tethers: TetherCatenaries | None = None
        #: an active winch (``tether.winch = "active"``, the QP only): the tensions are unknowns of the step
        self.winch_active = bool(getattr(tether, "active", False))
        self.winch_tension: Array | None = None
        self.winch_rate_prev: Array | None = None

    def update(
        self,
        k: int,
        positions: Array,
        v_prev: Array,
        q: Array | None = None,
        winch_tension: Array | None = None,
        winch_rate_prev: Array | None = None,
        v_prev2: Array | None = None,
    ) -> None:
        """The quantities of step ``k`` with the drones at ``positions`` (N, 3) [m] after velocities ``v_prev`` (3N,),
        and before them ``v_prev2`` (3N,) [m/s] (default ``v_prev``: no acceleration in the previous step; the loop
        passes 0 at the start, from rest).

        With an active winch, ``winch_tension`` (N,) [N] is every tether's tension now (default: the tether's
        ``winch_tension``) and ``winch_rate_prev`` (N,) [N/s] its previous rate: the tethers are solved at those
        tensions, their sensitivities include d/dT_w, and ``velocity_map`` is the coupling of the QP's unknowns
        [v, Ṫ] (:class:`WinchVelocityMap`).

        Raises:
            TetherSpanError: a tether has no catenary (its span is too long for the winch tension).
        """
        N = self.chain.n_robots
        self.k = int(k)
        self.q = q
        P = np.vstack([self.chain.base[None, :], np.asarray(positions, dtype=float).reshape(N, 3)])
        self.points = P
        self.v_prev = np.asarray(v_prev, dtype=float).reshape(-1)
        self.v_prev2 = self.v_prev if v_prev2 is None else np.asarray(v_prev2, dtype=float).reshape(-1)
        warm = self.tethers.theta if self.tethers is not None and len(self.tethers) == N else None
        if self.winch_active:
            tw = np.full(N, self.tether.winch_tension) if winch_tension is None else winch_tension
            self.winch_tension = np.asarray(tw, dtype=float).reshape(N).copy()
            rate = np.zeros(N) if winch_rate_prev is None else winch_rate_prev
            self.winch_rate_prev = np.asarray(rate, dtype=float).reshape(N).copy()
            self.velocity_map = WinchVelocityMap(VelocityMap3D(P))
            self.qdot_prev = self.velocity_map.T @ np.concatenate([self.v_prev, self.winch_rate_prev])
            self.tethers = solve3d_batch(P, self.tether, warm, winch_tension=self.winch_tension)
            self.sens = sensitivities_batch(self.tethers, self.fractions, self.tether, winch=True)
        else:
            self.velocity_map = VelocityMap3D(P)
            self.qdot_prev = self.velocity_map.T @ self.v_prev
            self.tethers = solve3d_batch(P, self.tether, warm)
            self.sens: TetherSensitivities = sensitivities_batch(self.tethers, self.fractions, self.tether)
        samples = self.sens.points  # (N, m, 3)
        m = self.fractions.size
        self._drone_nearest_obstacle: tuple[Array, Array] | None = None  # pinv's, on first use this step
        kd = self.drone_nearest
        cd, gd, nd = point_nearest_k(self.world, P[1:], kd, self.drone_cap)
        self.drone_obstacle_clearance, self.drone_obstacle_gradient = cd, gd
        # each tether as the polyline p, X_1..X_m, q: its m+1 pieces, each with its points nearest its k nearest
        # obstacles (walls included), one per obstacle
        kt = self.nearest
        poly = np.concatenate([P[:-1, None, :], samples, P[1:, None, :]], axis=1)  # (N, m+2, 3)
        ends = poly[:, :-1].reshape(-1, 3), poly[:, 1:].reshape(-1, 3)
        c, g, t, nt = segment_nearest_k(self.bare, *ends, kt, self.cap)
        self.piece_clearance = c.reshape(N, m + 1, kt)
        self.piece_gradient = g.reshape(N, m + 1, kt, 3)
        self.piece_t = t.reshape(N, m + 1, kt)
        self.segment_clearance = self.piece_clearance[..., 0]
        self.segment_gradient = self.piece_gradient[..., 0, :]
        self.segment_t = self.piece_t[..., 0]
        self.uncovered = int(np.maximum(nt - kt, 0).sum() + np.maximum(nd - kd, 0).sum())
        delta = self.tethers.length / (m + 1)
        a = np.where(self.tethers.vertical, np.inf, self.tethers.a)
        self.chord_deviation = np.minimum(delta**2 / (8.0 * a), 0.5 * delta)
        self.sample_points = samples
        ref = self.references
        kk = min(self.k, len(ref.t) - 1)
        self.x_d, self.xd_d = ref.x[kk], ref.xd[kk]
        self.ref_positions, self.ref_velocities = ref.positions[kk], ref.velocities[kk]

    @property
    def catenaries(self) -> list[Catenary3D]:
        """One :class:`Catenary3D` per tether (tether j from point j−1 to point j), built on first use this step."""
        return [] if self.tethers is None else list(self.tethers)

    @property
    def drone_clearance(self) -> Array:
        """Clearance of every drone (N,) [m] in the world grown by r (walls included), computed on first use."""
        return self._drone_world()[0]

    @property
    def drone_gradient(self) -> Array:
        """Unit gradient (N, 3) of :attr:`drone_clearance`."""
        return self._drone_world()[1]

    def _drone_world(self) -> tuple[Array, Array]:
        if self._drone_nearest_obstacle is None:  # only pinv reads it: the QP has its per-obstacle rows
            self._drone_nearest_obstacle = self.world.clearance_and_gradient(self.points[1:])
        return self._drone_nearest_obstacle

    @property
    def robot_jacobians(self) -> Array:
        """Joint-space Jacobians of every drone (N, 3, 3N) (``pinv``: needs ``q``)."""
        if self.q is None:
            raise ParameterError("the drones' joint Jacobians need the joint vector q (pinv)")
        return self.chain.robot_jacobians(self.q)


# ---------------------------------------------------------------------------------------------------------- tasks
class _DroneTask(Task):
    space = "robot"


class DroneLeader(_DroneTask):
    """Leader tracking in 3-D (Caruso 2021 eq. 20 on v): ``ṗ_N = ẋ_d + K (x_d − p_N)`` (3 rows) [m/s]."""

    name = "leader"

    def __init__(self, n_robots: int, gain: float) -> None:
        self.gain = float(gain)
        J = np.zeros((3, 3 * n_robots))
        J[:, -3:] = np.eye(3)
        J.flags.writeable = False
        self.J = J

    def compute(self, ctx: DroneStepContext) -> TaskRows:  # type: ignore[override]
        return TaskRows(self.J, ctx.xd_d + self.gain * (ctx.x_d - ctx.points[-1]))


class DroneFollowers(_DroneTask):
    """Followers' route references: ``ṗ_i = ṗ_ref,i + K (p_ref,i − p_i)`` for drones 1..N−1 (3(N−1) rows) [m/s], so
    that the chain follows the route (and does not wind round a pillar the route does not)."""

    name = "followers"

    def __init__(self, n_robots: int, gain: float) -> None:
        self.gain = float(gain)
        J = np.eye(3 * n_robots)[: 3 * (n_robots - 1)].copy()
        J.flags.writeable = False
        self.J = J

    def compute(self, ctx: DroneStepContext) -> TaskRows:  # type: ignore[override]
        P, R, V = ctx.points[1:-1], ctx.ref_positions[:-1], ctx.ref_velocities[:-1]
        return TaskRows(self.J, (V + self.gain * (R - P)).reshape(-1))


class TetherChords(_DroneTask):
    """Tether regulation: each chord length c_j = |p_j − p_{j−1}| towards ``fraction`` × the references' spacing,
    ``u_jᵀ(ṗ_j − ṗ_{j−1}) = K (c*_j − c_j)`` (N rows) [m/s] — the drone counterpart of the ground chain's span
    regulation (Caruso 2021 eq. 13, 23)."""

    name = "tethers"

    def __init__(self, n_robots: int, gain: float, fraction: float) -> None:
        self.gain, self.fraction = float(gain), float(fraction)

    def compute(self, ctx: DroneStepContext) -> TaskRows:  # type: ignore[override]
        vm = ctx.velocity_map
        N = vm.n_robots
        J = np.zeros((N, N, 3))
        j = np.arange(N)
        J[j, j] = vm.u
        J[j[1:], j[1:] - 1] = -vm.u[1:]
        ref = np.vstack([ctx.chain.base[None, :], ctx.ref_positions])
        target = self.fraction * np.linalg.norm(np.diff(ref, axis=0), axis=1)
        return TaskRows(J.reshape(N, 3 * N), self.gain * (target - vm.d))


class DroneEnergy(_DroneTask):
    """Energy: ``v ≈ 0`` (3N rows)."""

    name = "energy"

    def __init__(self, n_robots: int) -> None:
        self.J = np.eye(3 * n_robots)
        self.J.flags.writeable = False
        self.zero = np.zeros(3 * n_robots)

    def compute(self, ctx: DroneStepContext) -> TaskRows:  # type: ignore[override]
        return TaskRows(self.J, self.zero)


class DroneSmoothness(DroneEnergy):
    """Smoothness: ``v ≈ v_{k−1}`` (3N rows)."""

    name = "smoothness"

    def compute(self, ctx: DroneStepContext) -> TaskRows:  # type: ignore[override]
        return TaskRows(self.J, ctx.v_prev)


# --------------------------------------------------------------------------------------------------------- limits
_BLOCK_SCATTER: dict[tuple[int, int, int, int], NDArray[np.intp]] = {}


def _block_scatter(N: int, per: int, width: int, pad: int) -> NDArray[np.intp]:
    """Flat indices into a row-major (N·per, 3N + pad) table of N blocks (per, width): block j at rows j·per… and
    columns 3j… (cached: the shapes are fixed for a plan). With pad = 3 and width = 6 a tether's rows on its two
    ends, point j−1 (the anchor's columns in front) and drone j; with pad = 0 and width = 3 a drone's own rows."""
    key = (N, per, width, pad)
    idx = _BLOCK_SCATTER.get(key)
    if idx is None:
        j, r, c = np.ix_(np.arange(N), np.arange(per), np.arange(width))
        idx = _BLOCK_SCATTER[key] = ((j * per + r) * (3 * N + pad) + 3 * j + c).ravel()
    return idx


def _row_norms(x: Array) -> Array:
    """Euclidean norm of each row of x (M, 3): np.linalg.norm(x, axis=1)'s arithmetic without its wrapper."""
    return np.sqrt(np.add.reduce(x * x, axis=1))


def _minus_infinite(m: int) -> Array:
    """A read-only vector of m −infinities (shared: lower bounds that never bind)."""
    v = _MINUS_INF.get(m)
    if v is None:
        v = _MINUS_INF[m] = np.full(m, -np.inf)
        v.flags.writeable = False
    return v


_MINUS_INF: dict[int, Array] = {}


def _robot_pattern(N: int, rows_robots: list[list[int]]) -> NDArray[np.bool_]:
    """(m, 3N) mask: row r may touch the 0-based drones in ``rows_robots[r]`` (3 columns each)."""
    mask = np.zeros((len(rows_robots), N, 3), dtype=bool)
    for r, robots in enumerate(rows_robots):
        mask[r, robots] = True
    return mask.reshape(len(rows_robots), 3 * N)


class _DroneLimit(Limit):
    space = "robot"


class DroneClearance(_DroneLimit):
    """Every drone at least ``d_safe`` beyond its radius r from every obstacle (the room's walls, floor and ceiling
    are :class:`RoomBounds`' rows): one row per drone and obstacle for its ``nearest`` nearest obstacles, each with
    the exact clearance d to that obstacle and its gradient, ``Ts ∇dᵀ ṗ_i ≥ −min(rate Ts, 1)(d − d_safe)`` (N·k
    rows; an obstacle farther than ``activation`` gives an inactive row). One row per obstacle, not one for the
    nearest: where two obstacles meet (a window's jamb and sill) the nearest one alternates between steps, and the
    obstacle without a row could be approached without limit for that step. As
    :class:`tmr.control.limits.ObstacleClearance` on the ground: the distance to a convex obstacle is convex, so its
    linearisation is conservative."""

    name = "drone_clearance"

    def __init__(self, n_robots: int, d_safe: float, approach_rate: float, activation: float, nearest: int = 1) -> None:
        self.N, self.d_safe, self.rate, self.activation = n_robots, float(d_safe), float(approach_rate), activation
        self.nearest = int(nearest)

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return _robot_pattern(self.N, [[i] for i in range(self.N) for _ in range(self.nearest)])

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        N, k = self.N, self.nearest
        A = np.zeros((N * k, 3 * N))
        A.reshape(-1)[_block_scatter(N, k, 3, 0)] = (ctx.Ts * ctx.drone_obstacle_gradient).reshape(-1)
        d = ctx.drone_obstacle_clearance.reshape(-1)
        lower = approach_bound(d, self.d_safe, self.rate, ctx.Ts)
        lower[~(d <= self.activation)] = -np.inf
        return LimitRows(A, lower, _infinite(N * k))


class RoomBounds(_DroneLimit):
    """Every drone inside the room shrunk by r + d_safe, per axis (altitude between floor and ceiling included):
    ``lo ≤ p + Ts ṗ ≤ hi`` with the velocity damper on both sides (3N rows, exact: the walls are planes)."""

    name = "room"

    def __init__(self, n_robots: int, bounds: Any, margin: float, approach_rate: float) -> None:
        b = np.asarray(bounds, dtype=float)
        self.N, self.lo, self.hi, self.rate = n_robots, b[:3] + margin, b[3:] - margin, float(approach_rate)
        self.eye = np.eye(3 * n_robots)
        self._A: tuple[float, Array] | None = None  # (Ts, Ts I): the rows are constant for a plan

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return np.eye(3 * self.N, dtype=bool)

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        P = ctx.points[1:]
        low = approach_bound((P - self.lo).reshape(-1), 0.0, self.rate, ctx.Ts)
        high = -approach_bound((self.hi - P).reshape(-1), 0.0, self.rate, ctx.Ts)
        if self._A is None or self._A[0] != ctx.Ts:
            self._A = (ctx.Ts, ctx.Ts * self.eye)
            self._A[1].flags.writeable = False
        return LimitRows(self._A[1], low, high)


class DroneSeparation(RobotSeparation):
    """Drones at least 2r + margin apart, every pair (:class:`tmr.control.limits.RobotSeparation` in 3-D)."""

    name = "separation"

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        N = chain.n_robots
        i = np.repeat(np.arange(N), self.k)
        robot = np.repeat(np.arange(N), 3)[None, :]
        return np.abs(robot - i[:, None]) <= self.k


class _TetherRows(_DroneLimit):
    """Rows on tether j's two ends: point j−1 (a drone for j ≥ 2, the fixed anchor for j = 1) and drone j; with an
    active winch (``winch = True``) also on tether j's tension rate Ṫ_j (column 3N + j)."""

    winch: bool = False

    def _with_winch(self, N: int, per: int, A: Array, DT: Array) -> Array:
        """A (N·per, 3N) with the winch columns appended: tether j's rows get DT[j] (per,) in column 3N + j (the
        row's derivative w.r.t. T_w, times Ts); A itself without an active winch."""
        if not self.winch:
            return A
        out = np.zeros((N * per, 4 * N))
        out[:, : 3 * N] = A
        out[np.arange(N * per), 3 * N + np.repeat(np.arange(N), per)] = DT.reshape(-1)
        return out

    def _winch_mask(self, N: int, per: int, mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        if not self.winch:
            return mask
        extra = np.zeros((N * per, N), dtype=bool)
        extra[np.arange(N * per), np.repeat(np.arange(N), per)] = True
        return np.hstack([mask, extra])

    @staticmethod
    def _scatter(N: int, per: int, D: Array) -> Array:
        """A (N·per, 3N) from per-row gradients D (N, per, 6) w.r.t. the tether's p end (D[..., :3]) and q end
        (D[..., 3:]): tether j's rows touch point j−1 and drone j, six adjacent columns, written by one scatter
        into a table with the anchor's three columns in front (dropped: the anchor does not move)."""
        A = np.zeros((N * per, 3 * N + 3))
        A.reshape(-1)[_block_scatter(N, per, 6, 3)] = D.reshape(-1)
        return A[:, 3:]

    def _mask(self, N: int, per: int) -> NDArray[np.bool_]:
        return _robot_pattern(N, [[j - 1, j] if j else [j] for j in range(N) for _ in range(per)])


class TetherClearance(_TetherRows):
    """The whole tether curve at least c_t (+ ``margin``) from every obstacle, the floor and the walls.

    Each catenary is sampled at the m interior arc fractions i/(m+1) and seen as the polyline through its ends and the
    samples; each of its m+1 pieces gives one row per obstacle for its ``nearest`` nearest obstacles (each wall of the
    room is one), at the piece's point nearest that obstacle, X = (1−t) X_i + t X_{i+1} with clearance c and unit
    gradient n (World3D with radius 0, coal capsule queries):
    ``Ts nᵀ (∂X/∂p ṗ + ∂X/∂q q̇) ≥ −min(rate Ts, 1)(c − c_t − margin − e_j)`` (N·(m+1)·k rows; the anchor end of
    tether 1 is fixed). ∂X_i/∂(p, q) come from implicit differentiation of the catenary
    (:func:`~tmr.model.catenary3d.sensitivities`): the sag's motion is in the row, not only the chord's. A piece of
    arc length δ = L_j/(m+1) departs from its chord by at most e_j = min(δ²/(8a_j), δ/2) (the catenary's curvature is
    at most 1/a, and an arc of curvature ≤ κ stays within (1 − cos(κδ/2))/κ ≤ κδ²/8 of its chord): adding it per
    tether keeps the curve, not only the polyline, c_t + margin away. One row per (piece, obstacle) and not one for
    the piece's nearest obstacle: where two obstacles meet (a window's jamb and sill) the nearest one alternates
    between steps and the other, without a row, could be approached without limit for that step. With ``nearest``
    slots a piece near more than ``nearest`` obstacles (walls counted) leaves the farthest without a row
    (``DroneStepContext.uncovered`` counts them; :func:`make_drone_qp` sizes the slots so that it stays 0 on the
    worlds it was measured on).
    """

    name = "tether_clearance"

    def __init__(
        self, n_robots: int, samples: int, c_t: float, margin: float, rate: float, activation: float, nearest: int = 1
    ) -> None:
        self.N, self.m, self.nearest = n_robots, int(samples), int(nearest)
        self.c_min, self.rate, self.activation = float(c_t) + float(margin), float(rate), float(activation)
        f = np.arange(1, self.m + 1) / (self.m + 1)
        self._ends = (np.r_[1.0, np.zeros(self.m), 0.0], np.r_[0.0, np.zeros(self.m), 1.0])  # p, q weights
        self.fractions = f
        # ∂X/∂(p, q) (N, m+2, 3, 6) of the polyline's points: the ends (I and 0) fixed, the samples' set per step
        self._J = np.zeros((n_robots, self.m + 2, 3, 6))
        self._J[:, 0, :, :3] = np.eye(3)
        self._J[:, -1, :, 3:] = np.eye(3)

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        per = (self.m + 1) * self.nearest
        return self._winch_mask(self.N, per, self._mask(self.N, per))

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        N, m, k = self.N, self.m, self.nearest
        J = self._J  # [∂X/∂p | ∂X/∂q] per point: its rows' sums are those of two (3, 3) products, bit for bit
        J[:, 1:-1, :, :3], J[:, 1:-1, :, 3:] = ctx.sens.dpoints_dp, ctx.sens.dpoints_dq
        # n ᵀ ∂X/∂(p, q) with X = (1 − t) X_i + t X_{i+1}: (N, m+1, k, 6), one per piece and obstacle
        t = ctx.piece_t[..., None]
        g1 = t * ctx.piece_gradient  # (N, m+1, k, 3)
        g0 = ctx.piece_gradient - g1
        D = g0 @ J[:, :-1] + g1 @ J[:, 1:]
        A = self._scatter(N, (m + 1) * k, (ctx.Ts * D).reshape(N, (m + 1) * k, 6))
        c = ctx.piece_clearance.reshape(N, -1)
        need = self.c_min + ctx.chord_deviation[:, None]  # (N, 1): c_t + margin + the arc's departure from its chord
        lower = -np.minimum(self.rate * ctx.Ts, 1.0) * np.maximum(c - need, 0.0)
        lower[~(c <= self.activation + ctx.chord_deviation[:, None])] = -np.inf
        if self.winch:  # nᵀ dX/dT_w, X = (1 − t) X_i + t X_{i+1}; the ends do not move with T_w
            dXT = np.zeros((N, m + 2, 3))
            dXT[:, 1:-1] = ctx.sens.dpoints_dtw
            DT = np.einsum("jpkc,jpc->jpk", g0, dXT[:, :-1]) + np.einsum("jpkc,jpc->jpk", g1, dXT[:, 1:])
            A = self._with_winch(N, (m + 1) * k, A, ctx.Ts * DT)
        return LimitRows(A, lower.reshape(-1), _infinite(c.size))


class TetherLength(_TetherRows):
    """Arc length L_j ≤ L_max − margin: ``Ts (∇_p L ṗ + ∇_q L q̇) ≤ min(rate Ts, 1)(L_max − margin − L) − e_j``
    (N rows), with e_j the second-order growth the linear row misses: moving one end across the chord c_j by Δ (the
    relative displacement of the ends in one step) lengthens the chord by |Δ|²/(2 c_j), the arc by
    |∇_q L| |Δ|²/(2 c_j); with the previous step's relative velocity w and the acceleration bound a_max per axis,
    |Δ| ≤ Ts (|w| + 2√3 a_max Ts). Without it a chain held at full stretch, its drones sliding across their tethers,
    crept past the limit by ~0.5 mm per step (window-0-1 of ``tmr.sweep.rooms3d``: 7.025 m > L_max 7.02 m)."""

    name = "tether_length"

    def __init__(self, n_robots: int, L_max: float, rate: float, a_max: float = 0.0) -> None:
        self.N, self.L_max, self.rate, self.a_max = n_robots, float(L_max), float(rate), float(a_max)

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return self._winch_mask(self.N, 1, self._mask(self.N, 1))

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        S = ctx.sens
        V = ctx.v_prev.reshape(-1, 3)
        rel = V.copy()  # the ends' relative velocities (the anchor does not move)
        rel[1:] -= V[:-1]
        w = _row_norms(rel)
        step = ctx.Ts * (w + 2.0 * math.sqrt(3.0) * self.a_max * ctx.Ts)
        chord = np.maximum(ctx.velocity_map.d, 1e-9)
        growth = _row_norms(S.dlength_dq) * step**2 / (2.0 * chord)
        upper = -approach_bound(self.L_max - S.length, 0.0, self.rate, ctx.Ts) - growth
        D = np.concatenate([S.dlength_dp, S.dlength_dq], axis=1)  # (N, 6)
        A = self._scatter(self.N, 1, ctx.Ts * D)
        if self.winch:
            A = self._with_winch(self.N, 1, A, ctx.Ts * S.dlength_dtw)
        return LimitRows(A, _minus_infinite(self.N), upper)


class TetherTension(_TetherRows):
    """Tension at every drone end ≤ spare thrust − margin (the winch's end of tether 1 is the ground station: no row
    there, its tension is the constant-ish winch side): 2 rows per tether (p end, q end; the p end of tether 1 has a
    zero row), ``Ts ∇T · (ṗ, q̇) ≤ min(rate Ts, 1)(T_max − T)``."""

    name = "tether_tension"

    def __init__(self, n_robots: int, T_max: float, rate: float) -> None:
        self.N, self.T_max, self.rate = n_robots, float(T_max), float(rate)

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return self._winch_mask(self.N, 2, self._mask(self.N, 2))

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        S = ctx.sens
        # (N, 2, 6): per tether its p end's and q end's tension, each w.r.t. (p, q)
        D = np.concatenate([S.dtension_p_dp, S.dtension_p_dq, S.dtension_q_dp, S.dtension_q_dq], axis=1)
        D = (ctx.Ts * D).reshape(self.N, 2, 6)
        D[0, 0] = 0.0  # tether 1's p end is the ground winch, not a drone
        T = np.column_stack([S.tension_p, S.tension_q])
        upper = -approach_bound(self.T_max - T, 0.0, self.rate, ctx.Ts).reshape(-1)
        upper[0] = np.inf
        A = self._scatter(self.N, 2, D)
        if self.winch:  # both end tensions move by dT/dT_w (= 1: T_B = T_A + ρ g h); no row at the ground winch
            DT = ctx.Ts * np.repeat(S.dtension_dtw, 2).reshape(self.N, 2)
            DT[0, 0] = 0.0
            A = self._with_winch(self.N, 2, A, DT)
        return LimitRows(A, _minus_infinite(2 * self.N), upper)


def end_forces(tethers: Any, sens: Any, winch: bool = False) -> tuple[Array, Array, Array, Array]:
    """The forces of every tether on its two ends and their Jacobians (no per-step object churn: arrays only).

    With H the horizontal tension, u the horizontal unit vector p → q, V_P, V_Q the vertical pulls (the cable's
    weight between them: V_Q − V_P = ρ g L) the cable pulls its p end with F_p = H u + V_P e_z and its q end with
    F_q = −H u − V_Q e_z (the checker's forms, :func:`tmr.checks.drones.check_drone_plan`). From the end tensions
    and the length, T_P² = H² + V_P², T_Q² = H² + V_Q²:

        V_P = ((T_Q² − T_P²) / (ρ g L) − ρ g L) / 2,   V_Q = V_P + ρ g L,   H = √(T_P² − V_P²),

    so their derivatives follow from the sensitivities of T_P, T_Q and L (:func:`tmr.model.catenary3d.
    sensitivities_batch`), and du = (I − u uᵀ)(dq − dp)_xy / d.

    Returns F_p, F_q (N, 3) [N] and their Jacobians (N, 3, 6) w.r.t. (p, q) [N/m], or (N, 3, 7) with the winch
    tension T_w last [N/N] when ``winch``.
    """
    w = float(tethers.weight_per_length)
    N = tethers.p.shape[0]
    L, TP, TQ = sens.length, sens.tension_p, sens.tension_q
    cols = 7 if winch else 6
    dTP = np.zeros((N, cols))
    dTQ = np.zeros((N, cols))
    dL = np.zeros((N, cols))
    dTP[:, :3], dTP[:, 3:6] = sens.dtension_p_dp, sens.dtension_p_dq
    dTQ[:, :3], dTQ[:, 3:6] = sens.dtension_q_dp, sens.dtension_q_dq
    dL[:, :3], dL[:, 3:6] = sens.dlength_dp, sens.dlength_dq
    if winch:
        dTP[:, 6] = dTQ[:, 6] = sens.dtension_dtw
        dL[:, 6] = sens.dlength_dtw
    wL = w * L
    S = TQ * TQ - TP * TP
    VP = 0.5 * (S / wL - wL)
    VQ = VP + wL
    H = np.sqrt(np.maximum(TP * TP - VP * VP, 0.0))
    dS = 2.0 * (TQ[:, None] * dTQ - TP[:, None] * dTP)
    dVP = 0.5 * (dS / wL[:, None] - (S / (wL * L))[:, None] * dL - w * dL)
    dVQ = dVP + w * dL
    curved = (H > 1e-9) & ~np.asarray(tethers.vertical, dtype=bool)
    safe_H = np.where(curved, H, 1.0)
    dH = np.where(curved[:, None], (TP[:, None] * dTP - VP[:, None] * dVP) / safe_H[:, None], 0.0)
    u = np.zeros((N, 3))
    u[:, :2] = (tethers.q - tethers.p)[:, :2]
    d = np.hypot(u[:, 0], u[:, 1])
    u[:, :2] /= np.where(d > 0, d, 1.0)[:, None]
    # du/d(p, q): (I − u uᵀ)/d on the horizontal components, minus for p, plus for q
    P = np.zeros((N, 3, 3))
    P[:, :2, :2] = np.eye(2)[None] - u[:, :2, None] * u[:, None, :2]
    P /= np.where(d > 0, d, np.inf)[:, None, None]
    du = np.zeros((N, 3, cols))
    du[:, :, :3], du[:, :, 3:6] = -P, P
    ez = np.array([0.0, 0.0, 1.0])
    Hc = np.where(curved, H, 0.0)
    F_p = Hc[:, None] * u + VP[:, None] * ez
    F_q = -Hc[:, None] * u - VQ[:, None] * ez
    dHu = u[:, :, None] * dH[:, None, :] + Hc[:, None, None] * du
    # a vertical tether (H = 0) still pulls sideways once its ends move apart: near vertical d = a (θ_Q − θ_P) with
    # T_Q/T_P → e^(θ_Q − θ_P), so H u = ρ g (q − p)_xy / |ln(T_Q/T_P)| (a pendulum's stiffness)
    flat = ~curved
    if flat.any():
        log = np.abs(np.log(np.maximum(TQ[flat], 1e-300) / np.maximum(TP[flat], 1e-300)))
        k = np.where(log > 1e-12, w / np.where(log > 1e-12, log, 1.0), 0.0)
        stiff = np.zeros((int(flat.sum()), 3, cols))
        stiff[:, 0, 0] = stiff[:, 1, 1] = -k
        stiff[:, 0, 3] = stiff[:, 1, 4] = k
        dHu[flat] = stiff
    J_p = dHu + ez[None, :, None] * dVP[:, None, :]
    J_q = -dHu - ez[None, :, None] * dVQ[:, None, :]
    return F_p, F_q, J_p, J_q


class DroneThrust(_TetherRows):
    """The thrust each drone needs against all its tethers and its weight within what it has beyond its control
    reserve (hard): drone i carries tether i's q end and, but the leader, tether i+1's p end, so with the pull
    F_i = F_q(i) + F_p(i+1) (:func:`end_forces`) it needs ‖m g e_z − F_i‖ ≤ (1 − reserve) (T/W) m g − margin, the
    checker's row (``tension`` kind). Linearised: ``Ts n̂ᵀ(−dF_i) ≤ min(rate Ts, 1)(available − margin − need)`` with
    n̂ the unit needed thrust (N rows on the drones i−1, i, i+1, and with an active winch on Ṫ_i, Ṫ_{i+1}). The
    per-end rows of :class:`TetherTension` bound one tether at a time; two tethers of a middle drone pulling
    sideways and down can need more than either alone."""

    name = "drone_thrust"

    def __init__(self, n_robots: int, available: float, weight: float, rate: float) -> None:
        self.N, self.available, self.weight, self.rate = n_robots, float(available), float(weight), float(rate)

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        N = self.N
        mask = _robot_pattern(N, [[k for k in (i - 1, i, i + 1) if 0 <= k < N] for i in range(N)])
        if not self.winch:
            return mask
        extra = np.zeros((N, N), dtype=bool)
        for i in range(N):
            extra[i, i] = True
            if i + 1 < N:
                extra[i, i + 1] = True
        return np.hstack([mask, extra])

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        N, Ts = self.N, ctx.Ts
        F_p, F_q, J_p, J_q = end_forces(ctx.tethers, ctx.sens, self.winch)
        pull = F_q.copy()
        pull[:-1] += F_p[1:]
        need_vec = self.weight * np.array([0.0, 0.0, 1.0]) - pull
        need = np.linalg.norm(need_vec, axis=1)
        nh = need_vec / np.maximum(need, 1e-12)[:, None]
        A = np.zeros((N, 4 * N if self.winch else 3 * N))
        # row i: −n̂_iᵀ dF_q(tether i) (p = drone i−1, the anchor for i = 0; q = drone i; T_i) and −n̂_iᵀ dF_p(tether
        # i+1) (p = drone i, q = drone i+1; T_{i+1})
        g_q = -Ts * np.einsum("ij,ijk->ik", nh, J_q)  # (N, 6|7)
        rows, c3 = np.arange(N), 3 * np.arange(N)[:, None] + np.arange(3)
        A[rows[1:, None], c3[:-1]] += g_q[1:, :3]
        A[rows[:, None], c3] += g_q[:, 3:6]
        if N > 1:
            g_p = -Ts * np.einsum("ij,ijk->ik", nh[:-1], J_p[1:])  # (N−1, 6|7)
            A[rows[:-1, None], c3[:-1]] += g_p[:, :3]
            A[rows[:-1, None], c3[1:]] += g_p[:, 3:6]
        if self.winch:
            A[rows, 3 * N + rows] += g_q[:, 6]
            if N > 1:
                A[rows[:-1], 3 * N + rows[1:]] += g_p[:, 6]
        upper = -approach_bound(self.available - need, 0.0, self.rate, Ts)
        upper[need < self.available - THRUST_ACTIVATION] = np.inf  # far below the limit: an inactive row
        return LimitRows(A, _minus_infinite(N), upper)


#: :class:`DroneThrust`'s rows are active only within this much [N] of the available thrust (a step of the drones
#: changes the need by a few tenths of a newton at most: speed and acceleration bounds).
THRUST_ACTIVATION = 2.0


class DroneSpeed(_DroneLimit):
    """|ṗ_i,axis| ≤ v_max per axis [m/s] (3N rows). With a jerk bound ``j_max`` [m/s³] the bound looks ahead: an
    axis accelerating by Δ = ṗ_k − ṗ_{k−1} keeps gaining speed while its acceleration is brought back to 0 at most
    J = j_max Ts² a step, by S(Δ) = Σ_{i≥1} max(Δ − iJ, 0); the row is ṗ_k + S(ṗ_k − ṗ_{k−1}) ≤ v_max (and its mirror
    below), which, being increasing in ṗ_k, is the box ṗ_k ≤ ṗ_{k−1} + Δ*(v_max − ṗ_{k−1}) with Δ* the largest Δ
    with Δ + S(Δ) ≤ v_max − ṗ_{k−1} (:func:`_jerk_reach`). Without it a drone reaching v_max at full acceleration
    could not stop accelerating within one step of jerk: the next step would have no solution. From a state inside
    it, reducing Δ by J keeps it inside (recursively feasible)."""

    name = "drone_speed"

    def __init__(self, n_robots: int, v_max: float, j_max: float = math.inf) -> None:
        v = np.full(3 * n_robots, float(v_max))
        self.N, self.rows = n_robots, LimitRows(np.eye(3 * n_robots), -v, v)
        self.v_max, self.j_max = float(v_max), float(j_max)

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return np.eye(3 * self.N, dtype=bool)

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        if not math.isfinite(self.j_max):
            return self.rows
        J = self.j_max * ctx.Ts**2
        v = ctx.v_prev
        hi = np.minimum(v + _jerk_reach(self.v_max - v, J), self.v_max)
        lo = np.maximum(v - _jerk_reach(self.v_max + v, J), -self.v_max)
        return LimitRows(self.rows.A, np.minimum(lo, v), np.maximum(hi, v))


def _jerk_reach(room: Array, J: float) -> Array:
    """The largest velocity step Δ [m/s] with Δ + S(Δ) ≤ ``room`` [m/s] (:class:`DroneSpeed`): S grows by (Δ − iJ)
    for every i ≥ 1 with iJ < Δ, so on [nJ, (n+1)J] Δ + S(Δ) = (n+1)Δ − J n(n+1)/2, which is J n(n+1)/2 at Δ = nJ;
    with n the largest such that J n(n+1)/2 ≤ room, Δ = (room + J n(n+1)/2)/(n+1). ``room`` < 0 (never, inside the
    speed bound): Δ = room."""
    r = np.maximum(room, 0.0)
    n = np.floor(0.5 * (np.sqrt(1.0 + 8.0 * r / J) - 1.0))
    n = np.where(J * (n + 1.0) * (n + 2.0) / 2.0 <= r, n + 1.0, n)  # rounding of the square root
    n = np.where(J * n * (n + 1.0) / 2.0 > r, n - 1.0, n)
    return np.where(room < 0.0, room, (r + J * n * (n + 1.0) / 2.0) / (n + 1.0))


class DroneAcceleration(DroneSpeed):
    """|ṗ_i − ṗ_i,k−1| ≤ a_max Ts per axis (3N rows). A hard limit (issue 32 lists it with the others; the checker
    enforces it): it is never dropped (unlike the ground chain's comfort limit); where it and the safety limits have
    no common solution the loop slows the references down and retries, and the plan fails only if that does not
    help (:func:`tmr.control.run3d.run_drones`)."""

    name = "drone_acceleration"
    relaxable = False

    def __init__(self, n_robots: int, a_max: float) -> None:
        super().__init__(n_robots, 1.0)
        self.a_max = float(a_max)

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        dv = self.a_max * ctx.Ts
        return LimitRows(self.rows.A, ctx.v_prev - dv, ctx.v_prev + dv)


class DroneJerk(DroneSpeed):
    """|(ṗ_i − ṗ_i,k−1) − (ṗ_i,k−1 − ṗ_i,k−2)| ≤ j_max Ts² per axis (3N rows): the acceleration changes by at most
    j_max Ts [m/s²] a step. A hard limit as :class:`DroneAcceleration` (slow down and retry where it conflicts). A
    quadrotor accelerates sideways by tilting its thrust and turns it at a finite body rate: an acceleration that
    flips in one step it cannot follow (``formulations/drones.md``, "Jerk"). Always compatible with the acceleration
    rows (the previous step's acceleration is within them) and with the jerk-aware speed rows (:class:`DroneSpeed`)."""

    name = "drone_jerk"
    relaxable = False

    def __init__(self, n_robots: int, j_max: float) -> None:
        super().__init__(n_robots, 1.0)
        self.j_max = float(j_max)

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        dj = self.j_max * ctx.Ts**2
        centre = 2.0 * ctx.v_prev - ctx.v_prev2
        return LimitRows(self.rows.A, centre - dj, centre + dj)


# ---------------------------------------------------------------------------------------------------- active winch
class WinchTensionRange(_DroneLimit):
    """Every winch's tension within the pulley's torque range after the step: T_min ≤ T + Ts Ṫ ≤ T_max (N rows on
    Ṫ, exact: T integrates linearly). A tension outside the range (never, from a valid start) may not move further
    out: the bounds are widened to include Ṫ = 0."""

    name = "winch_tension"

    def __init__(self, n_robots: int, t_min: float, t_max: float) -> None:
        self.N, self.t_min, self.t_max = n_robots, float(t_min), float(t_max)
        self._A: tuple[float, Array] | None = None

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return np.hstack([np.zeros((self.N, 3 * self.N), dtype=bool), np.eye(self.N, dtype=bool)])

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        if self._A is None or self._A[0] != ctx.Ts:
            A = np.hstack([np.zeros((self.N, 3 * self.N)), ctx.Ts * np.eye(self.N)])
            A.flags.writeable = False
            self._A = (ctx.Ts, A)
        T = ctx.winch_tension
        assert T is not None
        return LimitRows(self._A[1], np.minimum(self.t_min - T, 0.0), np.maximum(self.t_max - T, 0.0))


class WinchRate(_DroneLimit):
    """Every winch's tension rate |Ṫ_j| ≤ ``rate`` [N/s] (N rows on Ṫ): how fast the pulley's torque can change."""

    name = "winch_rate"

    def __init__(self, n_robots: int, rate: float) -> None:
        N = n_robots
        A = np.hstack([np.zeros((N, 3 * N)), np.eye(N)])
        A.flags.writeable = False
        r = np.full(N, float(rate))
        self.N, self.rows = N, LimitRows(A, -r, r)

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return self.rows.A != 0.0

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        return self.rows


class WinchUpperEnd(_DroneLimit):
    """With the winch at the upper end of each tether (``winch_end = "upper"``), the lower end's tension T_A = T_w −
    ρ g dh must stay positive, or no catenary hangs there (``catenary3d.solve3d`` refuses it): per tether

        T_w + Ts Ṫ − ρ g (dh + Ts ḋh) ≥ margin,   dh = |z_q − z_p|, ḋh = sgn(z_q − z_p) (ż_q − ż_p)

    (N rows on [v, Ṫ]; the anchor of tether 1 does not move). ``margin`` [N]: 0.05 N. A tension already below it only
    must not fall further."""

    name = "winch_upper_end"

    def __init__(self, n_robots: int, weight_per_length: float, margin: float = 0.05) -> None:
        self.N, self.w, self.margin = n_robots, float(weight_per_length), float(margin)
        self._A = np.zeros((n_robots, 4 * n_robots))

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        N = self.N
        mask = np.zeros((N, 4 * N), dtype=bool)
        for j in range(N):
            mask[j, 3 * j + 2] = True
            if j:
                mask[j, 3 * (j - 1) + 2] = True
            mask[j, 3 * N + j] = True
        return mask

    def compute(self, ctx: DroneStepContext) -> LimitRows:  # type: ignore[override]
        N, Ts, w = self.N, ctx.Ts, self.w
        z = ctx.points[:, 2]
        dz = z[1:] - z[:-1]  # z_q − z_p per tether
        sgn = np.where(dz >= 0.0, 1.0, -1.0)
        A = self._A
        A[:] = 0.0
        rows = np.arange(N)
        A[rows, 3 * rows + 2] = -Ts * w * sgn  # q end: drone j
        A[rows[1:], 3 * (rows[1:] - 1) + 2] = Ts * w * sgn[1:]  # p end: drone j−1 (tether 1's is the anchor)
        A[rows, 3 * N + rows] = Ts
        T = ctx.winch_tension
        assert T is not None
        slack = T - w * np.abs(dz) - self.margin
        return LimitRows(A, np.minimum(-slack, 0.0), np.full(N, np.inf))


# --------------------------------------------------------------------------------------------------- formulations
def _anchor(references: Any, base: Any | None) -> Array:
    """The anchor: ``base`` if given, else ``references.base``."""
    b = base if base is not None else getattr(references, "base", None)
    if b is None:
        raise ParameterError("the drone chain needs its anchor: pass base=(x, y, z) or references with a .base")
    return np.asarray(b, dtype=float)


class DroneQP:
    """The lexicographic QP on the drones' velocities (:func:`make_drone_qp`); ``step`` returns v (3N,) [m/s], or
    with an active winch [v, Ṫ] (3N + N,) [m/s, N/s]."""

    name = "qp"
    integrates = "robots"

    def __init__(self, qp: LexicographicQP, context: DroneStepContext) -> None:
        self.qp, self.context = qp, context

    def reset(self) -> None:
        self.qp.reset()

    def step(self, ctx: DroneStepContext) -> tuple[Array, dict[str, float]]:
        qdot, diag = self.qp.step(ctx)  # type: ignore[arg-type]
        diag["uncovered_obstacles"] = float(ctx.uncovered)
        return ctx.velocity_map.robot_velocities(qdot), diag

    @property
    def level_keys(self) -> list[str]:
        return self.qp.level_keys


def make_drone_qp(
    world: World3D,
    tether: DroneTetherParams,
    params: DroneParams,
    n: int,
    references: DroneReferencesLike,
    base: Any | None = None,
    nearest: int | None = None,
    drone_nearest: int | None = None,
) -> DroneQP:
    """The drone chain's lexicographic QP (``formulations/drones.md``, "Per-step QP (3-D)").

    Args:
        world: the world, ``safety_radius`` = the drone radius r [m].
        tether: tether and drone parameters (c_t, L_max, spare thrust).
        params: planner parameters (gains, margins, limits, ``tether_samples``).
        n: number of drones N.
        references: the route references (leader and every drone).
        base: the anchor (ground winch) (3,) [m]; default: ``references.base``.
        nearest: obstacles (each wall one) per tether piece with a row of their own (``TetherClearance``); default
            min(6, obstacles + 6).
        drone_nearest: obstacles per drone with a row of their own (``DroneClearance``; walls are ``RoomBounds``);
            default min(5, obstacles).

    The default slots cover every obstacle within the activation distance on the measured worlds (window worlds of
    ``tmr.sweep.rooms3d`` and F, G, H: at most 6 per tether piece, walls included, and 5 per drone);
    ``diagnostics["uncovered_obstacles"]`` counts, per step, the (piece or drone, obstacle) pairs within it left
    without a row.
    """
    chain = Chain(int(n), _anchor(references, base), spatial=True)
    n_obstacles = len(world.obstacles)
    nearest = min(6, n_obstacles + 6) if nearest is None else int(nearest)
    drone_nearest = min(5, max(n_obstacles, 1)) if drone_nearest is None else int(drone_nearest)
    p = params
    act = p.clearance_activation
    ctx = DroneStepContext(
        chain, world, tether, references, p.Ts, p.tether_samples, cap=act + tether.clearance,
        nearest=nearest, drone_nearest=drone_nearest, drone_cap=act,
    )  # fmt: skip
    N = chain.n_robots
    tether_level: list[tuple[Task, float]] = [(TetherChords(N, p.route_gain, p.span_target_fraction), 1.0)]
    if N > 1:
        tether_level.append((DroneFollowers(N, p.route_gain), 1.0))
    levels = [
        Level([(DroneLeader(N, p.leader_gain), 1.0)], "leader"),
        Level(tether_level, "tethers"),
        Level([(DroneEnergy(N), p.energy_weight), (DroneSmoothness(N), p.smoothness_weight)], "energy"),
    ]
    r = world.safety_radius
    limits: list[Limit] = [
        DroneClearance(N, p.d_safe, p.approach_rate, act, drone_nearest),
        RoomBounds(N, world.bounds, r + p.d_safe, p.approach_rate),
        TetherClearance(
            N, p.tether_samples, tether.clearance, p.d_safe, p.approach_rate, act + tether.clearance, nearest
        ),
        TetherLength(N, tether.tether_length - p.length_margin, p.approach_rate, p.drone_accel_max),
        TetherTension(N, tether.spare_thrust - p.tension_margin, p.approach_rate),
        DroneThrust(N, tether.available_thrust - p.tension_margin, tether.drone_weight, p.approach_rate),
        DroneSpeed(N, p.drone_speed_max, math.inf if p.drone_jerk_max is None else p.drone_jerk_max),
        DroneAcceleration(N, p.drone_accel_max),
    ]
    if p.drone_jerk_max is not None:  # off by default (DroneParams.drone_jerk_max)
        limits.append(DroneJerk(N, p.drone_jerk_max))
    if N > 1:
        limits.append(
            DroneSeparation(
                chain, r, p.separation_margin, neighbours=N - 1, activation=2 * r + 3.0, approach_rate=p.approach_rate
            )  # fmt: skip
        )
    if ctx.winch_active:  # x = [v, Ṫ]: every row gets the winch columns ("Active winch" in formulations/drones.md)
        return _winch_qp(chain, levels, limits, tether, p, ctx)
    qp = LexicographicQP(chain, levels, limits, _FreeBox(chain.dof), solver=p.solver)  # type: ignore[arg-type]
    return DroneQP(qp, ctx)


def _winch_qp(
    chain: Chain, levels: list[Level], limits: list[Limit], tether: DroneTetherParams, p: DroneParams,
    ctx: DroneStepContext,
) -> DroneQP:  # fmt: skip
    """:func:`make_drone_qp`'s QP with an active winch: the same levels and limits on x = [v, Ṫ] (drone-only rows
    padded with zero Ṫ columns, the tether rows with their d/dT_w columns), the winch's range and rate as hard rows,
    and :class:`WinchReturn` in the lowest level."""
    N = chain.n_robots
    t_ref = min(max(tether.winch_tension, tether.winch_tension_min), tether.winch_tension_max)
    new_levels = []
    for i, level in enumerate(levels):
        tasks: list[tuple[Task, float]] = [(PaddedTask(t, of_base=False), w) for t, w in level.tasks]
        if i == len(levels) - 1:
            tasks.append((WinchReturn(chain, t_ref, WINCH_GAIN, space="robot"), WINCH_WEIGHT))
        new_levels.append(Level(tasks, level.name))
    new_limits: list[Limit] = []
    for lim in limits:
        if isinstance(lim, _TetherRows):
            lim.winch = True
            new_limits.append(lim)
        else:
            new_limits.append(PaddedLimit(lim, of_base=False))
    new_limits += [
        WinchTensionRange(N, tether.winch_tension_min, tether.winch_tension_max),
        WinchRate(N, tether.winch_tension_rate),
    ]
    if tether.winch_end == "upper":  # the lower end keeps a positive tension (a catenary exists)
        new_limits.append(WinchUpperEnd(N, tether.weight_per_length))
    wchain = WinchChain(chain)
    qp = LexicographicQP(wchain, new_levels, new_limits, _FreeBox(wchain.dof), solver=p.solver)  # type: ignore[arg-type]
    return DroneQP(qp, ctx)


class DronePinv:
    """Caruso 2021's CLIK (eq. 5) on the 3N-joint ``Chain(spatial=True)`` (:func:`make_drone_pinv`); ``step``
    returns the joint rates q̇ (3N,), integrated by the loop.

    Tasks by priority: the leader (eq. 20, J_e), then — only while the critical point (the drone or tether sample
    nearest its limit) is within ``danger`` of it — a soft obstacle task pushing that point away along the clearance
    gradient (eq. 14–18: ``∇cᵀ J_c q̇ = k_o (danger − (c − c_min))``); tether regulation (chord lengths towards
    the references' spacing, on the prismatic joints) by the gradient projection method in the null space of both
    (eq. 7). J_c of a tether sample is ∂X/∂p J_{j−1} + ∂X/∂q J_j (catenary sensitivities times the drones' joint
    Jacobians). Soft: nothing stops a limit from being crossed (the paper's baseline).
    """

    name = "pinv"
    integrates = "joints"

    def __init__(self, context: DroneStepContext, params: DroneParams, tether: DroneTetherParams) -> None:
        self.context, self.p, self.tether = context, params, tether
        self.danger = params.clearance_activation
        self.damping = 1e-4

    def reset(self) -> None:
        pass

    def step(self, ctx: DroneStepContext) -> tuple[Array, dict[str, float]]:
        chain, p = ctx.chain, self.p
        JR = ctx.robot_jacobians  # (N, 3, 3N)
        N = chain.n_robots
        J_e = JR[-1]
        v_e = ctx.xd_d + p.leader_gain * (ctx.x_d - ctx.points[-1])
        qdot = dls_inverse(J_e, self.damping) @ v_e
        P = null_space_projector(J_e)
        rows = [J_e]
        # critical point: a drone (clearance beyond d_safe) or a tether sample (beyond c_t)
        margins = np.concatenate(
            [ctx.drone_clearance - p.d_safe, ctx.segment_clearance.reshape(-1) - self.tether.clearance]
        )
        i = int(np.argmin(margins))
        active = margins[i] < self.danger
        if active:
            if i < N:
                g, Jc = ctx.drone_gradient[i], JR[i]
            else:  # the nearest point of piece s of tether j: X = (1 − t) X_s + t X_{s+1} (X_0 = p, X_{m+1} = q)
                j, s = divmod(i - N, ctx.fractions.size + 1)
                t = ctx.segment_t[j, s]
                sens = ctx.sens[j]
                eye, zero = np.eye(3), np.zeros((3, 3))
                Dp = [eye, *sens.dpoints_dp, zero]
                Dq = [zero, *sens.dpoints_dq, eye]
                dXdp = (1.0 - t) * Dp[s] + t * Dp[s + 1]
                dXdq = (1.0 - t) * Dq[s] + t * Dq[s + 1]
                Jc = dXdq @ JR[j]
                if j > 0:
                    Jc = Jc + dXdp @ JR[j - 1]
                g = ctx.segment_gradient[j, s]
            Jo = (g @ Jc)[None, :]
            vo = np.array([p.leader_gain * (self.danger - margins[i])])
            qdot = qdot + P @ (dls_inverse(Jo, self.damping) @ (vo - Jo @ qdot))
            rows.append(Jo)
            P = null_space_projector(np.vstack(rows))
        ref = np.vstack([chain.base[None, :], ctx.ref_positions])
        target = p.span_target_fraction * np.linalg.norm(np.diff(ref, axis=0), axis=1)
        opt = np.zeros(chain.dof)
        opt[chain.prismatic_index] = p.route_gain * (target - np.linalg.norm(np.diff(ctx.points, axis=0), axis=1))
        qdot = qdot + P @ opt
        return qdot, {"obstacle_active": float(active), "critical_clearance": float(margins[i])}


def make_drone_pinv(
    world: World3D,
    tether: DroneTetherParams,
    params: DroneParams,
    n: int,
    references: DroneReferencesLike,
    base: Any | None = None,
) -> DronePinv:
    """Caruso 2021's CLIK on the spatial chain (``formulations/drones.md``, "pinv (3-D)"); arguments as
    :func:`make_drone_qp`."""
    chain = Chain(int(n), _anchor(references, base), spatial=True)
    cap = params.clearance_activation + tether.clearance  # the soft task acts within the danger distance only
    ctx = DroneStepContext(chain, world, tether, references, params.Ts, params.tether_samples, cap=cap)
    return DronePinv(ctx, params, tether)
