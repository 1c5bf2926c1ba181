"""The smooth obstacle distance of the drone chain's whole-horizon NLP (``--method horizon`` on a drone scenario; math
in ``formulations/horizon3d.md``): a cubic tensor B-spline over a 3-D grid of the world's exact signed distance, and
the catenary sample points of a tether as closed-form functions of its two ends and one unknown per tether.

Both are written for casadi (the NLP's expressions) and checked against the exact code they stand for
(:mod:`tmr.world.world3d` through coal, :mod:`tmr.model.catenary3d`) in ``tests/test_horizon3d.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from tmr.world.world3d import World3D

Array = NDArray[np.float64]

__all__ = ["EPS_SPAN", "DistanceField3D", "distance_field3d", "exact_distance", "catenary_samples", "theta_warm"]

#: Horizontal span added in quadrature in the NLP's catenary, d = sqrt(dx² + dy² + EPS_SPAN²) [m]: keeps a vertical
#: tether (d = 0: a drone straight above the winch) differentiable. The sample points move by at most about this.
EPS_SPAN = 1e-3


def exact_distance(world: World3D, points: Array, cap: float, walls: bool = False) -> Array:
    """Exact signed distance [m] of points (M, 3) to the raw obstacles (no drone radius) — and, with ``walls``, to the
    room's six faces (positive inside the room) — negative inside an obstacle, capped at ``cap`` [m]: obstacles whose
    bounding box is farther than ``cap`` are not queried (their distance is ≥ cap). Boxes in closed form, other
    obstacles by coal (:func:`tmr.control.drones.point_nearest_k`)."""
    from tmr.control.drones import point_nearest_k

    P = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.full(P.shape[0], float(cap))
    if walls:
        lo, hi = np.asarray(world.bounds[:3], float), np.asarray(world.bounds[3:], float)
        out = np.minimum(out, np.minimum((P - lo).min(axis=1), (hi - P).min(axis=1)))
    if world.obstacles:
        w0 = world.with_safety_radius(0.0)
        c = point_nearest_k(w0, P, 1, cap=cap)[0][:, 0]
        out = np.minimum(out, c)
    return out


@dataclass
class DistanceField3D:
    """A cubic tensor B-spline D̃(p) of the exact signed distance D(p) (:func:`exact_distance`) [m].

    Attributes:
        function: casadi ``f(p (3, 1)) -> D̃`` (``f.map(M)`` on (3, M)).
        origin: the grid's first node (3,) [m]; h: its cell [m]; shape: nodes per axis.
        valid_lo, valid_hi: the box where the spline is complete (every point has its 4³ control points) [m].
        error: measured bound on the overestimate D̃ − D [m] (max over ``error_points`` points, times
            ``error_factor``, at least 1 mm) — the margin the NLP rows add.
        measured: the largest overestimate actually measured [m]; error_points: how many points were measured.
        cap: the field is min(D, cap) [m]: farther than this every row is inactive.
        build_time: seconds to sample the grid and measure the error.
    """

    function: ca.Function
    origin: Array
    h: float
    shape: tuple[int, int, int]
    valid_lo: Array
    valid_hi: Array
    error: float
    measured: float
    error_points: int
    cap: float
    build_time: float

    def __call__(self, points: Array) -> Array:
        """D̃ at points (M, 3) [m], numerically (the casadi function, mapped)."""
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        if P.shape[0] == 0:
            return np.zeros(0)
        return np.asarray(self.function.map(P.shape[0])(P.T), dtype=float).ravel()


def distance_field3d(
    world: World3D,
    lo: Array,
    hi: Array,
    *,
    h: float = 0.1,
    cap: float = 1.0,
    max_nodes: int = 1_500_000,
    probe: Array | None = None,
    band: float = 0.2,
    error_points: int = 100_000,
    error_factor: float = 1.5,
    seed: int = 0,
    walls: bool = False,
) -> DistanceField3D:
    """The spline field over the box [lo, hi] (3,) [m] (grown by two cells so the spline is complete on it) of the
    distance to the obstacles (and to the room's faces with ``walls``).

    The control points are the exact distance at the grid nodes (nothing is fitted: the quasi-interpolant of
    ``tmr.control.horizon_spline.distance_spline`` in 3-D). The cell ``h`` [m] grows if the box would need more than
    ``max_nodes`` nodes. The overestimate D̃ − D is measured at ``error_points`` points — half uniform in the box, half
    the ``probe`` points (e.g. the warm start's drones and tether samples) moved by random offsets of up to 0.5 m —
    among those where the spline reads at least ``band`` [m] (the smallest bound of any clearance row: a point that
    reads less fails its row whatever its error) and the cap does not bind; the rows use
    ``error`` = max(measured × ``error_factor``, 1 mm). This is a measurement, not a proof: the plan is verified
    afterwards by the independent checker (exact distances along the whole curve)."""
    import time

    t0 = time.perf_counter()
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    ext = hi - lo
    h = float(h)
    while np.prod(np.ceil(ext / h) + 5) > max_nodes:
        h *= 1.1
    origin = lo - 2.0 * h
    shape = tuple(int(v) for v in np.ceil((hi + 2.0 * h - origin) / h) + 1)
    axes = [origin[i] + h * np.arange(shape[i]) for i in range(3)]
    G = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    D = exact_distance(world, G, cap, walls).reshape(shape)
    knots = [(origin[i] + h * (np.arange(shape[i] + 4) - 2.0)).tolist() for i in range(3)]
    spline = ca.Function.bspline("clearance3d_spline", knots, D.ravel(order="F").tolist(), [3, 3, 3], 1, {})
    p = ca.MX.sym("p", 3, 1)
    fn = ca.Function("clearance3d", [p], [spline(p)], {"never_inline": True})
    valid_lo, valid_hi = origin + h, origin + h * (np.asarray(shape) - 2)
    field = DistanceField3D(fn, origin, h, shape, valid_lo, valid_hi, 0.0, 0.0, 0, float(cap), 0.0)
    rng = np.random.default_rng(seed)
    pts = [rng.uniform(lo, hi, size=(error_points // 2, 3))]
    if probe is not None and len(probe):
        probe = np.asarray(probe, float).reshape(-1, 3)
        pick = probe[rng.integers(0, probe.shape[0], size=error_points - error_points // 2)]
        pts.append(pick + rng.uniform(-0.5, 0.5, size=pick.shape))
    Q = np.clip(np.vstack(pts), lo, hi)
    exact = exact_distance(world, Q, cap, walls)
    approx = field(Q)
    over = approx - exact
    near = (exact < cap - 2.0 * h) & (approx >= band)  # where the cap does not bind and a row could pass
    measured = float(np.max(over[near], initial=0.0))
    field.measured, field.error_points = measured, int(Q.shape[0])
    field.error = max(measured * float(error_factor), 1e-3)
    field.build_time = time.perf_counter() - t0
    return field


def catenary_samples(
    A: Any, B: Any, theta: Any, sigma: Any, m: Any, eps: float = EPS_SPAN
) -> tuple[Any, Any, Any, Any, Any]:
    """Points of the catenary hanging from its lower end A to its upper end B, at arc fractions ``sigma`` from A.

    Closed form in (A, B, θ_A) (``tmr.model.catenary3d``'s ``_plane``): with dh = z_B − z_A ≥ 0, d the horizontal
    span (with :data:`EPS_SPAN` in quadrature), m = T_A/(ρ g) [m], k = 1 + dh/m, a = m / cosh θ_A,
    sinh θ_B = sqrt(k² sinh² θ_A + k² − 1), arc length L = a (sinh θ_B − sinh θ_A), the point at fraction σ has
    θ = asinh(sinh θ_A + σ (sinh θ_B − sinh θ_A)) and lies x = a (θ − θ_A) along the horizontal unit vector A → B,
    z = a (cosh θ − cosh θ_A) above A. θ_A solves the span equation R = asinh(sinh θ_B) − θ_A − d cosh θ_A / m = 0
    (Caruso 2021 §4.2.1 in 3-D; ``formulations/drones.md``): the NLP keeps R = 0 as an equality row.

    Works on casadi MX/SX or numpy arrays (elementwise; A, B as (3, M) or three rows; ``lib.fmax`` guards the square
    root where dh < 0, outside the model). Returns (X (3 rows), R, L, a,
    sinh θ_B)."""
    lib = ca if any(isinstance(v, (ca.MX, ca.SX, ca.DM)) for v in (A, B, theta)) else np
    Ax, Ay, Az = A[0], A[1], A[2]
    dx, dy, dh = B[0] - Ax, B[1] - Ay, B[2] - Az
    d = lib.sqrt(dx * dx + dy * dy + eps * eps)
    k = 1.0 + dh / m
    sh, ch = lib.sinh(theta), lib.cosh(theta)
    # sinh θ_B; the floor only acts off the model's domain (B below A at an iterate that violates its lower-end row)
    sb = lib.sqrt(lib.fmax(k * k * sh * sh + k * k - 1.0, 1e-12))
    a = m / ch
    R = lib.asinh(sb) - theta - d * ch / m
    L = a * (sb - sh)
    th = lib.asinh(sh + sigma * (sb - sh))
    x = a * (th - theta)
    z = a * (lib.cosh(th) - ch)
    X = (Ax + x * dx / d, Ay + x * dy / d, Az + z)
    return X, R, L, a, sb


def theta_warm(d: float, dh: float, m: float, guess: float | None = None) -> float:
    """θ_A of the shallow catenary of span ``d`` (with :data:`EPS_SPAN`) and height ``dh`` ≥ 0 [m] at m [m]
    (:func:`tmr.model.catenary3d._solve_theta`): the NLP's initial value of its auxiliary variable."""
    from tmr.model.catenary3d import _solve_theta

    return float(_solve_theta(math.sqrt(d * d + EPS_SPAN**2), dh, m, guess))
