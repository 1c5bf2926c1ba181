"""Tasks of the tethered chain: each one returns cost rows ``J q̇ ≈ v`` for the current step.

The same task objects feed every formulation: the pseudoinverse baseline stacks them by priority (Caruso 2021 eq. 5),
the QP formulations use their rows as least-squares objectives. A task reads everything it needs from a
:class:`StepContext`, which computes the chain geometry and the distance-field samples once per step.

Write your own task by subclassing :class:`Task` and returning :class:`TaskRows` from :meth:`Task.compute`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ParameterError
from tmr.model.chain import Chain
from tmr.model.velocity import VelocityMap

Array = NDArray[np.float64]


#: Velocity coordinates a task's or a limit's rows are written in (``space`` attribute): ``"joint"`` — joint rates
#: q̇ (2N planar); ``"robot"`` — robot velocities v = [ṗ1, …, ṗN] (2N, see :mod:`tmr.model.velocity`).
SPACES = ("joint", "robot")


class TaskRows(NamedTuple):
    """Cost rows of a task: ``J x ≈ v`` with x the task's velocity coordinates (its ``space``: q̇ or robot
    velocities); ``J`` is (m, 2N) and ``v`` (m,) in task units per second."""

    J: Array
    v: Array


class StepContext:
    """Per-step state shared by tasks and constraints: joint vector, chain geometry, reference, distance samples.

    Args:
        chain: the planar chain.
        env: environment with ``clearance_and_gradient(points)`` (signed distance to inflated obstacles [m]).
        reference: leader reference positions ``(K+1, 2)`` [m] and velocities ``(K+1, 2)`` [m/s].
        Ts: sampling period [s].
        samples_per_link: points per tether where clearance is sampled (fractions k/m, k = 1..m; s = 1 is the robot).
        span_limits: ``(N, 2)`` array of [d_lo, d_max] per tether [m].

    With low obstacles (``env.low_obstacles``, :class:`tmr.world.environment.LowObstacle`), the samples inside a
    tether (fraction < 1) read the field of ``env.tether_environment`` (a tether may pass over a low obstacle; its
    height there is a row of the active-winch QP), the samples at s = 1 (the robots) the field of ``env``.
    ``sample_clearance_all``/``sample_gradient_all`` are every sample against ``env`` itself, the low obstacles
    included (the pinv baseline's obstacle task reads them: it treats a low obstacle as tall for the tethers too,
    conservative); without low obstacles they are the same arrays as ``sample_clearance``/``sample_gradient``.
    """

    def __init__(
        self,
        chain: Chain,
        env: object,
        reference: Array,
        reference_velocity: Array,
        Ts: float,
        samples_per_link: int,
        span_limits: ArrayLike,
    ) -> None:
        self.chain = chain
        self.env = env
        self.reference = np.asarray(reference, dtype=float)
        self.reference_velocity = np.asarray(reference_velocity, dtype=float)
        self.Ts = float(Ts)
        m = int(samples_per_link)
        n_links = chain.n_robots
        self.sample_links = np.repeat(np.arange(1, n_links + 1), m)
        self.sample_fractions = np.tile(np.arange(1, m + 1) / m, n_links)
        # low obstacles: tether interiors see the world without them, robots (s = 1) the whole world
        self._tether_env = env.tether_environment if getattr(env, "low_obstacles", ()) else None  # type: ignore[attr-defined]
        self._robot_samples = self.sample_fractions >= 1.0
        self.span_limits = np.broadcast_to(np.asarray(span_limits, dtype=float), (n_links, 2)).copy()
        self.k = 0
        self.q = np.zeros(chain.dof)
        self.qdot_prev = np.zeros(chain.dof)

    def update(self, k: int, q: Array, qdot_prev: Array) -> None:
        """Recompute the per-step quantities at step ``k`` for joint vector ``q``."""
        self.k = k
        self.q = q
        self.qdot_prev = qdot_prev
        if self.chain.spatial:
            self.points, self._u = self.chain.points(q), None
        else:
            self._u, self.points = self.chain._planar_geometry(np.asarray(q, dtype=float))
        self.x_e = self.points[-1]
        self.x_d = self.reference[k]
        self.xd_d = self.reference_velocity[k]
        P = self.points
        li = self.sample_links
        self.sample_points = P[li - 1] + self.sample_fractions[:, None] * (P[li] - P[li - 1])
        if self._tether_env is None:
            self.sample_clearance, self.sample_gradient = self.env.clearance_and_gradient(self.sample_points)
            self.sample_clearance_all, self.sample_gradient_all = self.sample_clearance, self.sample_gradient
        else:
            rob = self._robot_samples
            d_all, g_all = self.env.clearance_and_gradient(self.sample_points)  # type: ignore[attr-defined]
            d, g = self._tether_env.clearance_and_gradient(self.sample_points)
            d[rob], g[rob] = d_all[rob], g_all[rob]
            self.sample_clearance, self.sample_gradient = d, g
            self.sample_clearance_all, self.sample_gradient_all = d_all, g_all
        self._J_e: Array | None = None
        self._J_r: Array | None = None
        self._vmap: VelocityMap | None = None
        self._spans: Array | None = None

    @property
    def J_e(self) -> Array:
        """Leader Jacobian (2, n), Caruso 2021 eq. 9 (cached for the step)."""
        if self._J_e is None:
            self._J_e = self.chain.end_effector_jacobian(self.q)
        return self._J_e

    @property
    def robot_jacobians(self) -> Array:
        """Jacobians of every robot (N, 2, n), Caruso 2021 eq. 10–12 (cached for the step)."""
        if self._J_r is None:
            self._J_r = self.chain.robot_jacobians(self.q)
            self._J_e = self._J_r[-1]
        return self._J_r

    @property
    def velocity_map(self) -> VelocityMap:
        """Maps between joint rates and robot velocities at this step (planar chains; cached for the step)."""
        if self._vmap is None:
            self._vmap = VelocityMap(self.points, self.spans, self._u)
        return self._vmap

    def rows_in(self, space: str, A: Array, source: str) -> Array:
        """Rows ``A`` written in velocity coordinates ``source`` expressed in ``space`` ("joint" or "robot")."""
        if source == space:
            return A
        if source == "joint":
            return self.velocity_map.to_robot(A)
        if source == "robot":
            return VelocityMap.to_joint(A, self.robot_jacobians)
        raise ParameterError(f"unknown velocity coordinates {source!r}; use one of {SPACES}")

    @staticmethod
    def robot_columns(i: int) -> slice:
        """Columns of robot ``i`` (1-based) in rows on robot velocities: ``A[:, ctx.robot_columns(i)]``."""
        return slice(2 * (i - 1), 2 * i)

    def robot_position(self, i: int) -> Array:
        """Position of robot ``i`` (1-based; 0 is the anchor) [m]."""
        return self.points[i]

    def robot_jacobian(self, i: int) -> Array:
        """Jacobian (2, n) of robot ``i`` (1-based), Caruso 2021 eq. 10–12."""
        return self.robot_jacobians[i - 1]

    @property
    def spans(self) -> Array:
        """Tether spans d_i [m] (the prismatic joints; cached for the step)."""
        if self._spans is None:
            self._spans = self.q[self.chain.prismatic_index]
        return self._spans


class Task(ABC):
    """A task: desired velocity ``v`` of a quantity with Jacobian ``J`` (cost rows).

    ``space`` names the velocity coordinates of ``J``: ``"joint"`` (q̇, the default) or ``"robot"`` (robot
    velocities); every formulation converts the rows to its own coordinates (:meth:`StepContext.rows_in`).
    ``full_rank = True`` declares that the rows always have rank 2N (e.g. all joint rates): a priority level holding
    such a task has a unique optimum, so the lexicographic QP skips the levels below it. A task whose ``J`` never
    changes may return the same read-only array every step (``J.flags.writeable = False``): formulations then reuse
    what they built from it.
    """

    name: str = "task"
    space: str = "joint"
    full_rank: bool = False

    @abstractmethod
    def compute(self, ctx: StepContext) -> TaskRows:
        """Cost rows for the step described by ``ctx``."""

    def reset(self) -> None:  # noqa: B027 - optional hook, stateless tasks need nothing
        """Forget any internal state (called before a new plan)."""


class LeaderTracking(Task):
    """Primary task: the leader tracks the reference with the CLIK law (Caruso 2021 eq. 19–20).

    ``v = ẋ_d + K e`` with ``e = x_d − x_e``. Its rows are written on robot velocities (they select the leader's
    velocity); in joint rates they are the leader Jacobian J_e of eq. 9.

    Args:
        gain: K [1/s] (scalar gain times identity).
    """

    name = "leader"
    space = "robot"

    def __init__(self, gain: float) -> None:
        if not np.isfinite(gain) or gain <= 0:
            raise ParameterError(f"CLIK gain must be a positive finite number [1/s], got {gain!r}")
        self.gain = float(gain)
        self._S: Array | None = None

    def compute(self, ctx: StepContext) -> TaskRows:
        n = 2 * ctx.chain.n_robots
        if self._S is None or self._S.shape[1] != n:
            self._S = np.zeros((2, n))
            self._S[:, n - 2 :] = np.eye(2)
            self._S.flags.writeable = False  # constant rows (formulations may reuse what they built from them)
        return TaskRows(self._S, ctx.xd_d + self.gain * (ctx.x_d - ctx.x_e))


def joint_limit_gain_coefficients(d_lo: float, d_max: float, edge: float, length: float) -> tuple[float, ...]:
    """Coefficients ``(a1, b1, a2, b2)`` of Caruso 2021 eq. 23 so each exponential equals ``edge`` at its limit.

    ``a1 e^{b1 d}`` grows towards d_max (b1 = 1/length > 0), ``a2 e^{b2 d}`` towards d_lo (b2 = −1/length).
    """
    b1 = 1.0 / length
    return (edge * np.exp(-b1 * d_max), b1, edge * np.exp(b1 * d_lo), -b1)


class TetherRegulation(Task):
    """Joint-limit avoidance on the tether spans (Caruso 2021 eq. 13 and eq. 23).

    Rows select the prismatic joints; ``v_i = K_ii(d_i) (d_t,i − d_i)`` with the gain of eq. 23
    ``K_ii(d) = a1 e^{b1 d} + a2 e^{b2 d} + G`` growing near both limits. Used as the gradient-projection term
    ``q̇_opt = Jᵀ v`` by the pseudoinverse baseline (eq. 7, 13) and as a least-squares task by the QP.

    Args:
        chain: the chain (for the joint layout).
        span_limits: (N, 2) [d_lo, d_max] per tether [m].
        target_fraction: common target d_t = d_lo + f (d_max − d_lo) of every tether, on the range shared by all
            tethers (largest d_lo, smallest d_max); 0.5 is the midpoint of eq. 13's joint range.
        gain_floor: G [1/s]; gain_edge: value of each exponential at its limit [1/s]; gain_length: 1/|b| [m];
        max_gain: cap on K_ii [1/s] (not in the paper: beyond a limit the exponentials grow without bound and an
            explicit Euler step with K_ii·Ts > 2 diverges; the planner sets it to 1/Ts).
    """

    name = "tether"

    def __init__(
        self,
        chain: Chain,
        span_limits: ArrayLike,
        target_fraction: float = 0.5,
        gain_floor: float = 0.5,
        gain_edge: float = 5.0,
        gain_length: float = 0.2,
        max_gain: float = 20.0,
    ) -> None:
        lim = np.broadcast_to(np.asarray(span_limits, dtype=float), (chain.n_robots, 2))
        if np.any(lim[:, 0] >= lim[:, 1]):
            raise ParameterError(f"every tether needs d_lo < d_max, got {lim.tolist()}")
        self.limits = lim.copy()
        # one target for every tether (uniform spans, the f2 objective), inside every tether's range
        lo, hi = lim[:, 0].max(), lim[:, 1].min()
        self.target = np.full(chain.n_robots, lo + target_fraction * (hi - lo))
        coeffs = np.array([joint_limit_gain_coefficients(lo, hi, gain_edge, gain_length) for lo, hi in lim])  # (N, 4)
        self.a1, self.b1, self.a2, self.b2 = coeffs.T
        self._a, self._b = np.vstack([self.a1, self.a2]), np.vstack([self.b1, self.b2])  # (2, N)
        self.G = float(gain_floor)
        self.max_gain = float(max_gain)
        self.S = np.zeros((chain.n_robots, chain.dof))
        self.S[np.arange(chain.n_robots), chain.prismatic_index] = 1.0
        self.S.flags.writeable = False  # constant rows

    def gain(self, d: Array) -> Array:
        """K_ii(d) of Caruso 2021 eq. 23 [1/s], capped at ``max_gain``."""
        # both exponentials at once, exponents clipped below overflow (beyond a limit the gain is capped anyway)
        k = np.einsum("ij,ij->j", self._a, np.exp(np.minimum(self._b * d, 700.0)))
        return np.minimum(k + self.G, self.max_gain)

    def compute(self, ctx: StepContext) -> TaskRows:
        d = ctx.spans
        return TaskRows(self.S, self.gain(d) * (self.target - d))


class ObstacleEvasion(Task):
    """Obstacle avoidance at the critical point of the whole chain (Caruso 2021 eq. 14–18).

    The critical point x_c is the sample point of the tethers closest to the inflated obstacles, except the samples
    within ``end_radius`` of the fixed anchor (no joint moves them away from it) or of the leader (its clearance is
    its path's, which the primary task follows). When its clearance drops below ``d_min`` the task activates and asks
    the point to move along the distance gradient n_c at ``v0 = k_v0 / ‖d_c − x_c‖``: one row ``J_n = n_cᵀ J_c``
    (eq. 18) with ``J_c`` the point Jacobian with the paper's zero columns (eq. 15, fixed distance along the link).
    It is released only when every point is beyond ``d_min + ε`` (hysteresis of eq. 17).

    Args:
        d_min: activation distance [m]; k_v0: evasion constant [m²/s]; hysteresis: ε [m];
        min_distance: floor on the distance in v0 [m];
        end_radius: exclusion radius around the anchor and the leader [m].
    """

    name = "obstacle"

    def __init__(
        self,
        d_min: float,
        k_v0: float,
        hysteresis: float,
        min_distance: float = 0.05,
        end_radius: float = 0.5,
    ) -> None:
        self.d_min, self.k_v0, self.eps, self.floor = (
            float(d_min),
            float(k_v0),
            float(hysteresis),
            float(min_distance),
        )
        self.end_radius = float(end_radius)
        self.active = False
        self.critical_index = -1
        self.critical_clearance = np.inf

    def reset(self) -> None:
        self.active = False
        self.critical_index = -1
        self.critical_clearance = np.inf

    def update(self, ctx: StepContext) -> bool:
        """Find the critical point and update the two-state activation (eq. 17). Returns whether active.

        Reads ``ctx.sample_clearance_all``: a low obstacle counts as tall for the tethers too (the pinv baseline has
        no cable-height row; conservative)."""
        d = ctx.sample_clearance_all.copy()
        # samples within one safety radius of the fixed anchor or of the leader are not candidates: no joint can move
        # them away from the anchor, and the leader's clearance is its path's (the primary task)
        along = ctx.sample_fractions * np.abs(ctx.spans)[ctx.sample_links - 1]
        last = ctx.sample_links == ctx.chain.n_robots
        near_anchor = (ctx.sample_links == 1) & (along < self.end_radius)
        near_leader = last & (np.abs(ctx.spans[-1]) - along < self.end_radius)
        d[near_anchor | near_leader] = np.inf
        i = int(np.argmin(d))
        self.critical_index, self.critical_clearance = i, float(d[i])
        if self.active:
            self.active = bool(np.any(d < self.d_min + self.eps))
        else:
            self.active = bool(d[i] < self.d_min)
        return self.active

    def compute(self, ctx: StepContext) -> TaskRows:
        i = self.critical_index
        g = ctx.sample_gradient_all[i]
        norm = float(np.hypot(g[0], g[1]))
        n_c = g / norm if norm > 1e-12 else np.zeros(2)
        J_c = ctx.chain.point_jacobians(
            ctx.q, ctx.sample_links[i : i + 1], ctx.sample_fractions[i : i + 1], fixed="distance"
        )[0]
        v0 = self.k_v0 / max(self.critical_clearance, self.floor)
        return TaskRows((n_c @ J_c)[None, :], np.array([v0]))


class SpanUniformity(Task):
    """Equal tether spans (the spirit of Caruso 2021 eq. 25, f2): differences of adjacent spans decay at ``gain``.

    Rows ``ḋ_i − ḋ_{i+1} ≈ −gain (d_i − d_{i+1})``, i = 1..N−1 [m/s]; no rows for a single robot.
    """

    name = "uniformity"

    def __init__(self, chain: Chain, gain: float = 1.0) -> None:
        N = chain.n_robots
        self.gain = float(gain)
        self.D = np.zeros((max(N - 1, 0), chain.dof))
        rows = np.arange(N - 1)
        self.D[rows, chain.prismatic_index[:-1]] = 1.0
        self.D[rows, chain.prismatic_index[1:]] = -1.0
        self.D.flags.writeable = False  # constant rows

    def compute(self, ctx: StepContext) -> TaskRows:
        return TaskRows(self.D, -self.gain * (self.D @ ctx.q))


class _EveryJointRate(Task):
    """A task on every joint rate: rows ``q̇ ≈ target`` (the identity, full rank, constant)."""

    full_rank = True

    def __init__(self, chain: Chain) -> None:
        self.I = np.eye(chain.dof)
        self.I.flags.writeable = False  # constant rows


class Damping(_EveryJointRate):
    """Minimum joint velocity (the energy f1 of Caruso 2021 eq. 24): rows ``q̇ ≈ 0``."""

    name = "energy"

    def compute(self, ctx: StepContext) -> TaskRows:
        return TaskRows(self.I, np.zeros(ctx.chain.dof))


class Smoothness(_EveryJointRate):
    """Small joint acceleration (the jerk-like f4 of Caruso 2021 eq. 27): rows ``q̇_k ≈ q̇_{k−1}``."""

    name = "smoothness"

    def compute(self, ctx: StepContext) -> TaskRows:
        return TaskRows(self.I, ctx.qdot_prev)


class RouteFollowers(Task):
    """Followers track their route references (``formulations/route.md``): rows select robots 1..N−1.

    ``v_i = ṗ_ref,i + gain (p_ref,i − p_i)`` [m/s] with the references of :class:`tmr.route.references.ChainReference`
    (robot i trails the leader along the route and stops at its station). Written on robot velocities.

    Args:
        positions: (K+1, N, 2) references of every robot [m] (the leader's column is ignored).
        velocities: (K+1, N, 2) their time derivatives [m/s].
        gain: tracking gain [1/s].
    """

    name = "route"
    space = "robot"

    def __init__(self, positions: ArrayLike, velocities: ArrayLike, gain: float = 1.0) -> None:
        P = np.asarray(positions, dtype=float)
        V = np.asarray(velocities, dtype=float)
        if P.ndim != 3 or P.shape[2] != 2 or V.shape != P.shape or not np.all(np.isfinite(P)):
            raise ParameterError(f"route references must be finite (K+1, N, 2) arrays, got {P.shape} and {V.shape}")
        if not np.isfinite(gain) or gain <= 0:
            raise ParameterError(f"route tracking gain must be a positive finite number [1/s], got {gain!r}")
        self.P, self.V, self.gain = P, V, float(gain)
        N = P.shape[1]
        self.S = np.zeros((2 * (N - 1), 2 * N))
        self.S[:, : 2 * (N - 1)] = np.eye(2 * (N - 1))
        self.S.flags.writeable = False  # constant rows

    def compute(self, ctx: StepContext) -> TaskRows:
        k = min(ctx.k, len(self.P) - 1)
        ref, vel = self.P[k, :-1], self.V[k, :-1]
        here = ctx.points[1:-1]
        return TaskRows(self.S, (vel + self.gain * (ref - here)).ravel())
