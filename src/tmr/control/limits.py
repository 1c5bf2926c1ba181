"""Hard limits of the chain: each one returns inequality rows ``lower ≤ A x ≤ upper`` for the current step.

Limits are linearised at q_k and valid over one sampling period Ts: a quantity g must satisfy
``g(q_k) + Ts ġ ≥ g_min`` with ġ linear in the velocities x. A limit writes its rows in the velocity coordinates
named by its ``space``: ``"joint"`` (joint rates q̇, the default, natural for joint quantities) or ``"robot"``
(robot velocities v = [ṗ1, …, ṗN], :mod:`tmr.model.velocity`), where every row on a robot or a tether point is local —
the built-in limits use it. Every limit declares a **fixed number of rows and a sparsity pattern** in its space
(:meth:`Limit.pattern`), so a QP solver can keep one workspace for the whole plan and only update values.

Write your own by subclassing :class:`Limit` (see ``KeepInPolygon`` for a small example).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.control.tasks import StepContext
from tmr.errors import ParameterError
from tmr.model.chain import Chain

Array = NDArray[np.float64]


class LimitRows(NamedTuple):
    """Inequality rows ``lower ≤ A q̇ ≤ upper``; ``A`` is (m, n), bounds (m,) (±inf allowed)."""

    A: Array
    lower: Array
    upper: Array


def link_pattern(chain: Chain, links: ArrayLike) -> NDArray[np.bool_]:
    """Sparsity in q̇ of the Jacobian rows of points on ``links`` (1-based): the joints of links 1..j (eq. 15)."""
    li = np.asarray(links, dtype=int).reshape(-1)
    return chain.joint_link[None, :] <= li[:, None]


def robot_link_pattern(chain: Chain, links: ArrayLike) -> NDArray[np.bool_]:
    """Sparsity in robot velocities of rows on points of ``links`` (1-based): robots j−1 (not the anchor) and j."""
    li = np.asarray(links, dtype=int).reshape(-1)
    robot = np.repeat(np.arange(1, chain.n_robots + 1), 2)[None, :]
    return (robot == li[:, None]) | (robot == li[:, None] - 1)


_INF: dict[int, Array] = {}


def _infinite(m: int) -> Array:
    """A read-only vector of m infinities (shared: bounds that never bind)."""
    v = _INF.get(m)
    if v is None:
        v = np.full(m, np.inf)
        v.flags.writeable = False
        _INF[m] = v
    return v


def approach_bound(g: Array, g_min: float, rate: float, Ts: float) -> Array:
    """Lower bound on the change ``Ts ġ`` of a distance g ≥ g_min over one step (velocity damper).

    ``ġ ≥ −rate (g − g_min)``: the distance may shrink at most exponentially towards g_min with time constant
    1/rate [s], so that bounded accelerations can always stop the approach; ``rate ≥ 1/Ts`` gives the plain one-step
    constraint ``g + Ts ġ ≥ g_min``. A distance already below g_min must not shrink (ġ ≥ 0).
    """
    return -np.minimum(rate * Ts, 1.0) * np.maximum(g - g_min, 0.0)


def braking_rate(gap: Array, decel: float, Ts: float) -> Array:
    """The largest rate v ≥ 0 at which a distance ``gap`` ≥ 0 to a limit may shrink so that a rate falling by at most
    ``decel`` Ts per step still stops at the limit (a discrete braking curve; ``formulations/diffdrive.md``).

    v is the largest with Ts (v + (v − decel Ts) + (v − 2 decel Ts) + …, its positive terms) ≤ gap: with h = decel
    Ts² and m = ⌊(√(1 + 8 gap / h) − 1) / 2⌋ (the steps after this one), v = gap / ((m + 1) Ts) + m decel Ts / 2.
    Continuous, increasing, ≤ gap / Ts (m = 0: the plain one-step bound), ≈ √(2 decel gap) far from the limit; and
    recursively feasible: after a step at v ≤ braking_rate(g), braking_rate(g − Ts v) ≥ v − decel Ts. A negative gap
    counts as 0 (the rate must not shrink it further).
    """
    g = np.maximum(np.asarray(gap, dtype=float), 0.0)
    h = decel * Ts * Ts
    m = np.floor(0.5 * (np.sqrt(1.0 + 8.0 * g / h) - 1.0))
    return g / ((m + 1.0) * Ts) + 0.5 * m * decel * Ts


class Limit(ABC):
    """A hard limit: ``lower ≤ A q̇ ≤ upper`` rows with a fixed pattern.

    ``relaxable = True`` marks a comfort limit (e.g. an acceleration bound) that a formulation may drop for a step
    when the limits have no common solution, so that the safety limits can still be met.
    """

    name: str = "limit"
    relaxable: bool = False
    space: str = "joint"

    @abstractmethod
    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        """(m, 2N) boolean mask of the entries of ``A`` that may be nonzero, in the limit's ``space``.

        A QP keeps it as the initial sparsity of its workspace; an entry outside it makes the workspace grow (a new
        factorisation), so a declared pattern saves time but is not a promise the solver relies on.
        """

    @abstractmethod
    def compute(self, ctx: StepContext) -> LimitRows:
        """Rows for the step described by ``ctx``; ``A`` must be zero outside :meth:`pattern`."""

    def reset(self) -> None:  # noqa: B027 - optional hook
        """Forget any internal state (called before a new plan)."""


class ObstacleClearance(Limit):
    """Every robot and every tether stays out of the inflated obstacles (hard, Caruso 2021 objectives 2–3).

    Along each tether the distance field is sampled at ``ctx.sample_fractions`` (``samples_per_link`` points, robots
    are the end samples s = 1); every sample closer than ``activation`` becomes a row
    ``Ts ∇d(p)ᵀ ṗ ≥ −min(rate Ts, 1)(d(p) − d_safe)`` (a velocity damper, see :func:`approach_bound`; it keeps
    d(p) + Ts ḋ ≥ d_safe) with ṗ = (1 − s) ṗ_{j−1} + s ṗ_j the velocity of the point at fraction s of link j (it
    slides with the tether length; in joint rates ṗ = J_p q̇, eq. 15). Rows are on robot velocities. Linearising the
    distance to a convex obstacle is conservative (the distance is convex).

    With ``per_link > 0`` only that many samples per tether get rows: the lowest local minima of its clearance
    profile (fewer rows for long chains). Then a sample on a slope of the profile has no row and a second obstacle
    can reach it within one step (seen on dense clutter): the default, every sample, is the safe choice.

    Between samples spaced δ a straight tether can cut into a convex obstacle corner by at most δ²/(8ρ), where ρ ≥ r
    (inflation rounds every convex corner with the safety radius r); ``d_safe`` should cover it plus the distance-field
    interpolation error (see ``formulations/qp.md``). A sample already closer than ``d_safe`` (e.g. next to an anchor
    placed near a wall) only has to not get closer: ``∇dᵀ J q̇ ≥ 0``. ``approach_rate`` [1/s] bounds how fast a
    sample may approach ``d_safe``.

    Args:
        chain: the chain.
        samples_per_link: clearance samples per tether (``StepContext``'s).
        d_safe: clearance kept from the inflated obstacles [m].
        per_link: rows per tether; 0 = every sample (default).
        activation: samples farther than this [m] give inactive rows (lower bound −inf).
    """

    name = "clearance"
    space = "robot"

    def __init__(
        self,
        chain: Chain,
        samples_per_link: int,
        d_safe: float = 0.05,
        per_link: int = 0,
        activation: float = 1.5,
        approach_rate: float = 2.0,
    ) -> None:
        if d_safe < 0 or per_link < 0 or samples_per_link < 1 or activation <= d_safe or approach_rate <= 0:
            raise ParameterError(
                "need d_safe ≥ 0, per_link ≥ 0, samples_per_link ≥ 1, activation > d_safe, approach_rate > 0; got "
                f"{d_safe}, {per_link}, {samples_per_link}, {activation}, {approach_rate}"
            )
        self.samples = int(samples_per_link)
        self.per_link = self.samples if per_link == 0 else min(int(per_link), self.samples)
        self.d_safe, self.activation = float(d_safe), float(activation)
        self.rate = float(approach_rate)
        self.links = np.repeat(np.arange(1, chain.n_robots + 1), self.per_link)
        self._scatter: tuple | None = None

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return robot_link_pattern(chain, self.links)

    def select(self, ctx: StepContext) -> tuple[Array, Array]:
        """Indices (into the samples) of the rows' points, (N·per_link,): every sample, or the lowest local minima."""
        N, c = ctx.chain.n_robots, self.per_link
        d = ctx.sample_clearance.reshape(N, -1)
        m = d.shape[1]
        if m != self.samples:
            raise ParameterError(f"the step samples {m} points per tether, this limit was built for {self.samples}")
        if c == m:
            return np.arange(N * m), m
        # local minima along each link (ends count as minima if lower than their only neighbour)
        left = np.concatenate([np.full((N, 1), np.inf), d[:, :-1]], axis=1)
        right = np.concatenate([d[:, 1:], np.full((N, 1), np.inf)], axis=1)
        score = np.where((d <= left) & (d <= right), d, np.inf)
        order = np.argsort(score, axis=1, kind="stable")[:, :c]
        chosen = np.take_along_axis(score, order, axis=1)
        # links with fewer minima than rows repeat their lowest one (the row is then duplicated, harmless)
        fallback = np.broadcast_to(order[:, :1], order.shape)
        order = np.where(np.isfinite(chosen), order, fallback)
        return (order + (np.arange(N) * m)[:, None]).reshape(-1), m

    def compute(self, ctx: StepContext) -> LimitRows:
        links, s, d, g = ctx.sample_links, ctx.sample_fractions, ctx.sample_clearance, ctx.sample_gradient
        idx = None
        if self.per_link != self.samples or d.size != links.size or d.size != self.samples * ctx.chain.n_robots:
            idx, _ = self.select(ctx)
            links, s, d, g = links[idx], s[idx], d[idx], g[idx]
        M = d.size
        n = 2 * ctx.chain.n_robots
        if idx is None:  # every sample: the scatter of the rows into A is fixed, built once
            key = (M, n, ctx.Ts)
            if self._scatter is None or self._scatter[0] != key:
                self._scatter = (key, *self._scatter_map(links, s, ctx.Ts, n))
            _, flat, w, pick = self._scatter
        else:
            flat, w, pick = self._scatter_map(links, s, ctx.Ts, n)
        A = np.zeros(M * n)
        A[flat] = (w[:, None] * g[pick]).ravel()  # Ts (1 − s) ∇d on robot j−1, Ts s ∇d on robot j
        lower = approach_bound(d, self.d_safe, self.rate, ctx.Ts)
        lower[d > self.activation] = -np.inf
        return LimitRows(A.reshape(M, n), lower, _infinite(M))

    @staticmethod
    def _scatter_map(
        links: NDArray[np.intp], s: Array, Ts: float, n: int
    ) -> tuple[NDArray[np.intp], Array, NDArray[np.intp]]:
        """Flat indices into A (M, n) of each row's two robot blocks, their weights and the sample of each."""
        r = np.arange(links.size)
        lead = links >= 2  # link 1 starts at the fixed anchor: no robot j−1
        rows = np.concatenate([r[lead], r])
        robot = np.concatenate([links[lead] - 2, links - 1])  # 0-based robots j−1 and j
        weight = Ts * np.concatenate([1.0 - s[lead], s])
        flat = ((rows * n + 2 * robot)[:, None] + np.arange(2)).ravel()
        return flat, weight, rows


class RobotSeparation(Limit):
    """Robots keep at least ``2 r + margin`` from each other, for every pair (hard).

    For each robot the ``neighbours`` nearest other robots give rows
    ``Ts n_ijᵀ (ṗ_i − ṗ_j) ≥ −min(rate Ts, 1)(‖p_i − p_j‖ − 2r − margin)`` (n_ij the unit vector from j to i; a
    velocity damper as in :class:`ObstacleClearance`), on robot velocities. With ``neighbours ≥ N − 1`` every pair
    is a row. The declared pattern of robot i's rows covers the robots within ``neighbours`` of it along the chain;
    a pair outside it (the chain folded back) grows the QP's pattern. Pairs farther than ``activation`` [m] give
    inactive rows.
    """

    name = "separation"
    space = "robot"

    def __init__(
        self,
        chain: Chain,
        safety_radius: float,
        margin: float = 0.02,
        neighbours: int = 2,
        activation: float = 3.0,
        approach_rate: float = 2.0,
    ) -> None:
        self.min_distance = 2 * float(safety_radius) + float(margin)
        self.rate = float(approach_rate)
        self.k = max(1, min(int(neighbours), chain.n_robots - 1))
        self.activation = float(activation)
        self.rows = chain.n_robots * self.k if chain.n_robots > 1 else 0
        self._D = np.zeros((0, 0))

    @staticmethod
    def _all_pairs(N: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Robot i's rows are its pairs with every other robot j (N·(N−1) rows, j in increasing order)."""
        i = np.repeat(np.arange(N), N - 1)
        j = np.array([jj for ii in range(N) for jj in range(N) if jj != ii], dtype=np.intp)
        return i, j

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        N = chain.n_robots
        i = np.repeat(np.arange(N), self.k)
        robot = np.repeat(np.arange(N), 2)[None, :]
        return np.abs(robot - i[:, None]) <= self.k

    def compute(self, ctx: StepContext) -> LimitRows:
        n = ctx.chain.dof
        if self.rows == 0:
            return LimitRows(np.zeros((0, n)), np.zeros(0), np.zeros(0))
        P = ctx.points[1:]
        D = self._differences(P)  # (rows, N): row r is robot i minus robot j
        diff = D @ P
        dij = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        nij = diff / dij[:, None]
        A = (D[:, :, None] * (ctx.Ts * nij)[:, None, :]).reshape(D.shape[0], -1)
        lower = approach_bound(dij, self.min_distance, self.rate, ctx.Ts)
        lower[dij > self.activation] = -np.inf
        return LimitRows(A, lower, _infinite(dij.size))

    def _differences(self, P: Array) -> Array:
        """The pair matrix of this step: every pair (fixed, built once) or each robot's k nearest (re-sorted)."""
        N = P.shape[0]
        if self.k == N - 1:
            if self._D.shape != (N * (N - 1), N):
                i, j = self._all_pairs(N)
                self._D = np.zeros((i.size, N))
                self._D[np.arange(i.size), i] = 1.0
                self._D[np.arange(i.size), j] = -1.0
            return self._D
        dist = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=-1)
        np.fill_diagonal(dist, np.inf)
        j = np.argsort(dist, axis=1, kind="stable")[:, : self.k].reshape(-1)  # the k nearest of each robot
        i = np.repeat(np.arange(N), self.k)
        D = np.zeros((i.size, N))
        D[np.arange(i.size), i] = 1.0
        D[np.arange(i.size), j] = -1.0
        return D


class _RobotVelocityRows(Limit):
    """Rows on the Cartesian velocity of every robot, x and y: the identity on robot velocities (``J_i q̇``)."""

    space = "robot"

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        return np.eye(2 * chain.n_robots, dtype=bool)


class RobotSpeed(_RobotVelocityRows):
    """Cartesian speed of every robot, per axis: ``|(J_i q̇)_x|, |(J_i q̇)_y| ≤ v_max`` [m/s] (hard)."""

    name = "robot_speed"

    def __init__(self, chain: Chain, v_max: float) -> None:
        if not v_max > 0:
            raise ParameterError(f"v_max must be > 0 m/s, got {v_max}")
        self.v_max = float(v_max)
        self._rows: LimitRows | None = None

    def compute(self, ctx: StepContext) -> LimitRows:
        n = 2 * ctx.chain.n_robots
        if self._rows is None or self._rows.A.shape[0] != n:  # constant rows: built once
            v = np.full(n, self.v_max)
            self._rows = LimitRows(np.eye(n), -v, v)
        return self._rows


class RobotAcceleration(_RobotVelocityRows):
    """Cartesian acceleration of every robot, per axis: ``|J_i (q̇ − q̇_{k−1})| ≤ a_max Ts`` [m/s²] (hard).

    ``J_i(q_k) q̇_{k−1}`` stands for the robot's previous velocity (the change of J over one step is second order).
    Rows on robot velocities: ``|ṗ_i − J_i q̇_{k−1}| ≤ a_max Ts``.
    """

    name = "robot_acceleration"
    relaxable = True

    def __init__(self, chain: Chain, a_max: float) -> None:
        if not a_max > 0:
            raise ParameterError(f"a_max must be > 0 m/s², got {a_max}")
        self.a_max = float(a_max)
        self._eye: Array | None = None

    def compute(self, ctx: StepContext) -> LimitRows:
        v_prev = ctx.velocity_map.robot_velocities(ctx.qdot_prev)
        dv = self.a_max * ctx.Ts
        if self._eye is None or self._eye.shape[0] != v_prev.size:
            self._eye = np.eye(v_prev.size)
        return LimitRows(self._eye, v_prev - dv, v_prev + dv)


class JointBox:
    """Box bounds on q̇ (solver bounds): joint speeds, the acceleration bound and the tether span limits.

    ``lb ≤ q̇ ≤ ub`` with, per joint, the tightest of
      - speed: ``|θ̇| ≤ omega_max`` [rad/s], ``|ḋ| ≤ v_span_max`` [m/s];
      - acceleration: ``|q̇ − q̇_{k−1}| ≤ a_max Ts`` (a_max in rad/s² and m/s²);
      - span (hard, catenary): ``d_lo + margin ≤ d + Ts ḋ ≤ d_max − margin``; with ``span_rate`` ρ_d [1/s] also
        ``ḋ ≤ ρ_d (d_max − margin − d)`` (a tether slows down as it is paid out towards its limit); with
        ``span_brake`` b_d [m/s²] (differential drive) also ``|ḋ| ≤ braking_rate(gap, b_d, Ts)`` towards either end
        of the band (:func:`braking_rate`): a span reaches its bound at a rate that falls by at most b_d Ts per step,
        so robots whose acceleration is bounded can stop it there (without it a span may run into its bound at full
        speed and must stop within one step).
    A span already outside its band is only asked not to get worse; where the acceleration bound cannot reach the span
    band, the span band wins (the box is never empty).
    """

    def __init__(
        self,
        chain: Chain,
        span_limits: ArrayLike,
        omega_max: float,
        v_span_max: float,
        a_max: float,
        span_margin: float = 0.01,
        span_rate: float | None = None,
        span_brake: float | None = None,
    ) -> None:
        self.chain = chain
        self.span_rate = None if span_rate is None else float(span_rate)
        if span_brake is not None and not span_brake > 0:
            raise ParameterError(f"span_brake must be > 0 (a deceleration [m/s²]) or None, got {span_brake}")
        self.span_brake = None if span_brake is None else float(span_brake)
        self.limits = np.broadcast_to(np.asarray(span_limits, float), (chain.n_robots, 2)).copy()
        self.vmax = np.where(chain.is_prismatic, v_span_max, omega_max).astype(float)
        self.a_max = float(a_max)
        self.margin = float(span_margin)
        self._q_lo = np.full(chain.dof, -np.inf)  # span band per joint (revolute joints: unbounded)
        self._q_hi = np.full(chain.dof, np.inf)
        self._q_lo[chain.prismatic_index] = self.limits[:, 0] + self.margin
        self._q_hi[chain.prismatic_index] = self.limits[:, 1] - self.margin

    def compute(self, ctx: StepContext, relax: bool = False) -> tuple[Array, Array]:
        """Bounds (lb, ub) on q̇; ``relax=True`` drops the acceleration bound (speed and span bounds stay)."""
        Ts = ctx.Ts
        if relax:
            lb, ub = -self.vmax, self.vmax.copy()
        else:
            da = self.a_max * Ts
            lb = np.maximum(-self.vmax, ctx.qdot_prev - da)
            ub = np.minimum(self.vmax, ctx.qdot_prev + da)
        # span band on every joint at once (±inf on the revolute ones): d_lo + m ≤ d + Ts ḋ ≤ d_max − m; a span already
        # outside only must not get worse
        q = ctx.q
        band_lo = (np.minimum(self._q_lo, q) - q) / Ts
        band_hi = (np.maximum(self._q_hi, q) - q) / Ts
        if self.span_rate is not None:  # paid out towards d_max at most at ρ_d (d_max − m − d)
            band_hi = np.minimum(band_hi, self.span_rate * (np.maximum(self._q_hi, q) - q))
        if self.span_brake is not None:  # either end of the band reached at a rate the robots can brake
            p = self.chain.prismatic_index
            band_hi[p] = np.minimum(band_hi[p], braking_rate(self._q_hi[p] - q[p], self.span_brake, Ts))
            band_lo[p] = np.maximum(band_lo[p], -braking_rate(q[p] - self._q_lo[p], self.span_brake, Ts))
        lo, hi = np.maximum(lb, band_lo), np.minimum(ub, band_hi)
        empty = lo > hi
        if empty.any():  # speed/acceleration and the span band do not meet: the span band (the safety limit) wins
            edge = np.where(lb > band_hi, band_hi, band_lo)
            lo, hi = np.where(empty, edge, lo), np.where(empty, edge, hi)
        return lo, hi


class KeepInPolygon(Limit):
    """Keep one robot inside a convex polygon (an example of a user-defined limit).

    Each edge with outward normal a and offset b (aᵀx ≤ b inside) gives ``Ts aᵀ ṗ_i ≤ b − margin − aᵀ p_i`` on robot
    velocities (``ṗ_i = J_i q̇`` in joint rates).

    Args:
        chain: the chain; robot: 1-based index of the robot; polygon: (M, 2) vertices of a convex polygon [m].
    """

    name = "keep_in_polygon"
    space = "robot"

    def __init__(self, chain: Chain, robot: int, polygon: ArrayLike, margin: float = 0.0) -> None:
        V = np.asarray(polygon, dtype=float)
        if V.ndim != 2 or V.shape[0] < 3 or V.shape[1] != 2 or not np.all(np.isfinite(V)):
            raise ParameterError("polygon must be (M ≥ 3, 2) finite vertices")
        if not 1 <= robot <= chain.n_robots:
            raise ParameterError(f"robot must be in 1..{chain.n_robots}, got {robot}")
        area2 = np.sum(V[:, 0] * np.roll(V[:, 1], -1) - np.roll(V[:, 0], -1) * V[:, 1])
        if area2 < 0:
            V = V[::-1]  # counter-clockwise
        E = np.roll(V, -1, axis=0) - V
        self.normals = np.column_stack([E[:, 1], -E[:, 0]]) / np.linalg.norm(E, axis=1)[:, None]
        self.offsets = np.einsum("ij,ij->i", self.normals, V)
        self.robot, self.margin = int(robot), float(margin)

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        mask = np.zeros((self.normals.shape[0], 2 * chain.n_robots), dtype=bool)
        mask[:, StepContext.robot_columns(self.robot)] = True
        return mask

    def compute(self, ctx: StepContext) -> LimitRows:
        p = ctx.points[self.robot]
        A = np.zeros((self.normals.shape[0], 2 * ctx.chain.n_robots))
        A[:, ctx.robot_columns(self.robot)] = ctx.Ts * self.normals
        upper = np.maximum(self.offsets - self.margin - self.normals @ p, 0.0)  # outside: do not get worse
        return LimitRows(A, np.full(A.shape[0], -np.inf), upper)
