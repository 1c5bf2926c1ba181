"""The lexicographic QP of a chain of differential-drive robots (``--drive diff``; math in
``formulations/diffdrive.md``).

Caruso 2021's chain model drives each robot's tether exit point p_i. A differential-drive robot carries a heading θ_i
and its exit point lies b ahead of the axle centre c_i (p = c + b e(θ)), so (:mod:`tmr.model.diffdrive`)

    ṗ_i = v_i e(θ_i) + b ω_i e_⊥(θ_i),   i.e.   v_i = e(θ_i)·ṗ_i,   ω_i = e_⊥(θ_i)·ṗ_i / b   (b ≠ 0).

The QP keeps its unknowns (the exit points' velocities v = [ṗ_1, …, ṗ_N] and the joint rates, tied by q̇ = T v) and
every task and limit of the omnidirectional QP; (v_i, ω_i) are linear in ṗ_i at the step's heading, so the robots'
limits are two more sets of hard rows on robot velocities:

- :class:`DiffDriveSpeed` (hard): ``|e_i·ṗ_i| ≤ v_max``, ``|e_⊥i·ṗ_i| / b ≤ ω_max``, and with a wheel track L each
  wheel's rim speed ``|v_i ± ω_i L/2| ≤ v_max``;
- :class:`DiffDriveAcceleration` (comfort, like :class:`~tmr.control.limits.RobotAcceleration`):
  ``|v_i − v_i,k−1| ≤ a_max Ts``, ``|ω_i − ω_i,k−1| ≤ α_max Ts``;
- and in the joint box (:class:`~tmr.control.limits.JointBox`, built by :func:`tmr.planner.make_qp`) every span meets
  its band along a braking curve at :func:`span_brake` (:func:`~tmr.control.limits.braking_rate`), so that the robots
  can stop it there within their acceleration bounds.

The non-holonomic constraint (no sideways motion of the axle centre) is not a row but the integration:
:class:`DiffDriveQP` reads (v_i, ω_i) off the QP's ṗ_i, holds them over the step and moves every pose along the exact
unicycle arc (:func:`tmr.model.diffdrive.unicycle_step`), so the recorded axle centres never slip sideways whatever
the solver's tolerance; the exit points follow as c + b e(θ) and the chain's joints are recomputed from them (spans =
distances, angles = directions, continuous): the plan loop :func:`tmr.control.clik.run` receives the joint rates
that reach exactly those joints (they differ from the QP's by O(Ts²) per step: the arc against the straight step).
With b ≠ 0 eliminating (v, ω) is exact; the alternative, x = [ṗ, v, ω] with equality rows ṗ_i − v_i e_i − b ω_i
e_⊥i = 0, has the same feasible set with 2N more unknowns and 2N more equality rows per level.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.control.limits import Limit, LimitRows
from tmr.control.tasks import StepContext
from tmr.errors import ParameterError
from tmr.model.chain import Chain
from tmr.model.diffdrive import RobotModel, exit_point, unicycle_step

Array = NDArray[np.float64]

__all__ = [
    "DiffDriveAcceleration",
    "DiffDriveContext",
    "DiffDriveQP",
    "DiffDriveSpeed",
    "GoalHeading",
    "SPAN_BRAKE_FRACTION",
    "TURN_IN_PLACE",
    "WHEEL_RESERVE",
    "rest_to_rest",
    "span_brake",
]

#: A robot turns in place at a step where |v| < TURN_IN_PLACE[0] [m/s] and |ω| > TURN_IN_PLACE[1] [rad/s].
TURN_IN_PLACE = (1e-3, 0.05)
#: The share of a wheel's speed the plan leaves to the robot's tracking feedback: the rim rows keep
#: |v ± ω L/2| ≤ (1 − WHEEL_RESERVE) v_max (the checker holds the plan to v_max itself). Planned to the full v_max, the
#: wheeled MuJoCo replays of D and E (Burger) saturated their wheels while correcting and fell behind (62 mm on E).
WHEEL_RESERVE = 0.1
#: The share of a_max the span band's braking curve counts on (:func:`span_brake`): a span rate ḋ_i = u_i·(ṗ_i −
#: ṗ_i−1) falls at a_max only when robot i drives along its tether (at a_max cos φ at an angle φ to it).
SPAN_BRAKE_FRACTION = 0.5


def span_brake(model: RobotModel) -> float:
    """The deceleration [m/s²] of a span rate that the span band's braking curve counts on
    (:class:`~tmr.control.limits.JointBox` ``span_brake``, :func:`~tmr.control.limits.braking_rate`):
    :data:`SPAN_BRAKE_FRACTION` of a_max. Without it a span ran into d_max at 0.133 m/s and the robot had to stop
    within one step (2.66 m/s² > a_max = 2.5 m/s²): the comfort limit was dropped for that step."""
    return SPAN_BRAKE_FRACTION * model.a_max


class DiffDriveContext:
    """The step seen by the QP of differential-drive robots: ``base`` the :class:`StepContext`, ``heading`` (N,)
    [rad] every robot's θ_k, ``v_prev`` (N,) [m/s] and ``omega_prev`` (N,) [rad/s] the speeds held over the previous
    step (0 at the start: the robots start at rest); every other attribute is the base's."""

    def __init__(self, base: StepContext, heading: Array, v_prev: Array, omega_prev: Array) -> None:
        self.base = base
        self.heading = heading
        self.v_prev = v_prev
        self.omega_prev = omega_prev

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)


class _DiffRows(Limit):
    """Rows (2N, 2N) on robot velocities: per robot i, ``e(θ_i)·ṗ_i`` (= v_i) and ``e_⊥(θ_i)·ṗ_i / b`` (= ω_i)."""

    space = "robot"

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self._A: Array | None = None

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        N = chain.n_robots
        return np.kron(np.eye(N, dtype=bool), np.ones((2, 2), dtype=bool))

    def rows(self, heading: Array) -> Array:
        N = heading.size
        if self._A is None or self._A.shape[0] != 2 * N:
            self._A = np.zeros((2 * N, 2 * N))
        c, s = np.cos(heading), np.sin(heading)
        i = np.arange(N)
        b = self.model.exit_offset
        A = self._A
        A[2 * i, 2 * i], A[2 * i, 2 * i + 1] = c, s  # v_i = e_i·ṗ_i
        A[2 * i + 1, 2 * i], A[2 * i + 1, 2 * i + 1] = -s / b, c / b  # ω_i = e_⊥i·ṗ_i / b
        return A

    def reset(self) -> None:
        self._A = None


class DiffDriveSpeed(_DiffRows):
    """|v_i| ≤ v_max [m/s] and |ω_i| ≤ ω_max [rad/s] for every robot (hard); with a wheel track L (the robot model's
    ``track``) also each wheel's rim speed |v_i ± ω_i L/2| ≤ (1 − :data:`WHEEL_RESERVE`) v_max (2 more rows per
    robot)."""

    name = "diff_speed"

    def pattern(self, chain: Chain) -> NDArray[np.bool_]:
        base = super().pattern(chain)
        return np.vstack([base, base]) if self.model.track else base

    def compute(self, ctx: Any) -> LimitRows:
        N = ctx.heading.size
        m = self.model
        A = self.rows(ctx.heading)
        rows = 4 * N if m.track else 2 * N
        if self._up is None or self._up.size != rows:  # the bounds and the stacked rows: allocated once per N
            up = np.tile([m.v_max, m.omega_max], N)
            if m.track:
                up = np.concatenate([up, np.full(2 * N, (1.0 - WHEEL_RESERVE) * m.v_max)])
                self._stack = np.empty((rows, 2 * N))
            self._up, self._lo = up, -up
        if not m.track:
            return LimitRows(A, self._lo, self._up)
        h = 0.5 * m.track
        S = self._stack
        S[: 2 * N] = A
        W = S[2 * N :]
        np.add(A[0::2], h * A[1::2], out=W[0::2])  # right wheel's rim speed v + ω L/2
        np.subtract(A[0::2], h * A[1::2], out=W[1::2])  # left wheel's v − ω L/2
        return LimitRows(S, self._lo, self._up)

    def __init__(self, model: RobotModel) -> None:
        super().__init__(model)
        self.reset()

    def reset(self) -> None:
        super().reset()
        self._up: Array | None = None
        self._lo: Array | None = None
        self._stack: Array | None = None


class DiffDriveAcceleration(_DiffRows):
    """|v_i − v_i,k−1| ≤ a_max Ts and |ω_i − ω_i,k−1| ≤ α_max Ts (a comfort limit: dropped for a step only if the
    safety limits need it, as :class:`~tmr.control.limits.RobotAcceleration`; the checker then reports it)."""

    name = "diff_acceleration"
    relaxable = True

    def compute(self, ctx: Any) -> LimitRows:
        prev = np.column_stack([ctx.v_prev, ctx.omega_prev]).reshape(-1)
        step = np.tile([self.model.a_max * ctx.Ts, self.model.alpha_max * ctx.Ts], ctx.heading.size)
        return LimitRows(self.rows(ctx.heading), prev - step, prev + step)


def rest_to_rest(distance: float, v_lim: float, a_lim: float) -> tuple[float, Any]:
    """The time-optimal rest-to-rest profile over ``distance`` ≥ 0 with speed ≤ ``v_lim`` and acceleration ≤ ``a_lim``
    (trapezoid, or triangle when ``v_lim`` is not reached; units of the distance: m or rad). Returns its duration [s]
    and ``f(t) -> (s, ṡ)`` (clamped to [0, duration])."""
    if distance <= 0.0:
        return 0.0, lambda t: (0.0, 0.0)
    ta = v_lim / a_lim
    if a_lim * ta * ta >= distance:  # triangle: the peak speed stays below v_lim
        ta = math.sqrt(distance / a_lim)
        T = 2.0 * ta
    else:
        T = distance / v_lim + ta
    vp = a_lim * ta

    def f(t: float) -> tuple[float, float]:
        t = min(max(t, 0.0), T)
        if t < ta:
            return 0.5 * a_lim * t * t, a_lim * t
        if t > T - ta:
            r = T - t
            return distance - 0.5 * a_lim * r * r, a_lim * r
        return 0.5 * a_lim * ta * ta + vp * (t - ta), vp

    return T, f


class GoalHeading:
    """The leader's final manoeuvre to a goal heading Θ [rad] (``--goal X,Y,THETA``, ``formulations/diffdrive.md``).

    The leader's exit point reaches the goal G along the route at state ``k_arrive`` with some heading θ_a and axle
    c_a = G − b e(θ_a). The goal pose is the exit point at G with heading Θ, i.e. the axle at c_f = G − b e(Θ). From
    the state at ``k_arrive`` (measured, not predicted) the manoeuvre is turn in place → straight drive → turn in place:

    1. turn about c_a from θ_a to φ, the direction of d = c_f − c_a (forwards only: driving backwards, the heading's
       internal dynamics would amplify its errors by up to e^(|d|/b));
    2. drive the axle by |d| (≤ 2b) along e(φ);
    3. turn about c_f from φ to Θ* (Θ + 2πn nearest φ).

    Each piece is a rest-to-rest profile (:func:`rest_to_rest`) at ``v_lim``, ``a_lim`` [m/s, m/s²] or ``omega_lim``,
    ``alpha_lim`` [rad/s, rad/s²]. Its exit point p = c + b e(θ), ṗ = ċ + b θ̇ e_⊥(θ) (:meth:`at`) ends exactly at
    G. :class:`DiffDriveQP` makes it the leader task's reference from ``k_arrive`` on: x_d = p(τ) (in the last turn and
    after it c_k + b e(θ_ref(τ)), about the leader's own axle c_k, so the CLIK corrects the heading, not the axle) and
    ẋ_d the exit-point velocity whose (v, ω) at the leader's heading are :meth:`step_commands`. :meth:`budget` is the
    longest manoeuvre (two half turns and a 2b drive) [s]: the planner holds the reference that long after the route.
    """

    def __init__(
        self,
        theta: float,
        goal: Array,
        k_arrive: int,
        b: float,
        v_lim: float,
        a_lim: float,
        omega_lim: float,
        alpha_lim: float,
    ) -> None:
        self.theta, self.goal, self.k_arrive, self.b = float(theta), np.asarray(goal, dtype=float), int(k_arrive), b
        self.v_lim, self.a_lim, self.omega_lim, self.alpha_lim = v_lim, a_lim, omega_lim, alpha_lim
        self._pieces: list[tuple[str, float, Array, float, float, Any]] | None = None
        self.final_turn_start = math.inf  # τ [s] at which the last turn starts (set by start)
        self.reference: dict[int, Array] = {}  # state k → the leader's reference exit point used [m]

    def budget(self) -> float:
        """The longest manoeuvre [s]: two turns of π and a drive of 2b."""
        t_turn = rest_to_rest(math.pi, self.omega_lim, self.alpha_lim)[0]
        return 2.0 * t_turn + rest_to_rest(2.0 * abs(self.b), self.v_lim, self.a_lim)[0]

    def start(self, axle: Array, theta: float) -> None:
        """Plan the three pieces from the leader's axle centre ``axle`` (2,) [m] and heading ``theta`` [rad] at
        ``k_arrive``."""
        b = self.b
        c_f = self.goal - b * np.array([math.cos(self.theta), math.sin(self.theta)])
        d = c_f - axle
        dist = float(np.hypot(*d))

        def near(angle: float, to: float) -> float:  # angle + 2πn nearest ``to``
            return angle + 2.0 * math.pi * round((to - angle) / (2.0 * math.pi))

        # forwards only (reversing would amplify heading errors); no drive when the axle already stands at c_f
        phi = theta if dist <= 1e-12 else near(math.atan2(d[1], d[0]), theta)
        theta_f = near(self.theta, phi)
        pieces = []
        t0 = 0.0
        for kind, start, dist_or_turn in (
            ("turn", np.array([*axle, theta]), phi - theta),
            ("drive", np.array([*axle, phi]), dist),
            ("turn", np.array([*c_f, phi]), theta_f - phi),
        ):
            lim = (self.omega_lim, self.alpha_lim) if kind == "turn" else (self.v_lim, self.a_lim)
            T, f = rest_to_rest(abs(dist_or_turn), *lim)
            pieces.append((kind, t0, start, math.copysign(1.0, dist_or_turn), T, f))
            t0 += T
        self._pieces = pieces
        self.final_turn_start = pieces[-1][1]
        self.end_pose = (c_f, theta_f)

    def pose(self, tau: float) -> tuple[Array, float, Array, float]:
        """The reference axle centre (2,) [m], heading [rad] and their rates (2,) [m/s], [rad/s] at ``tau`` [s] after
        ``k_arrive`` (the end pose once the manoeuvre is over)."""
        assert self._pieces is not None, "start() first"
        for kind, t0, start, sgn, T, f in self._pieces:
            if tau < t0 + T or t0 == self._pieces[-1][1]:
                s, sd = f(tau - t0)
                c, th = start[:2].copy(), float(start[2])
                if kind == "turn":
                    return c, th + sgn * s, np.zeros(2), sgn * sd
                e = np.array([math.cos(th), math.sin(th)])
                return c + sgn * s * e, th, sgn * sd * e, 0.0
        raise AssertionError("unreachable")

    def at(self, tau: float) -> tuple[Array, Array]:
        """The reference exit point (2,) [m] and its velocity (2,) [m/s] at ``tau`` [s] after ``k_arrive``."""
        c, th, cdot, thdot = self.pose(tau)
        e, en = np.array([math.cos(th), math.sin(th)]), np.array([-math.sin(th), math.cos(th)])
        return c + self.b * e, cdot + self.b * thdot * en

    def step_commands(self, tau: float, Ts: float) -> tuple[float, float]:
        """(v [m/s], ω [rad/s]) that, held over [tau, tau + Ts] (:func:`tmr.model.diffdrive.unicycle_step`), move the
        reference pose at ``tau`` exactly to the one at ``tau + Ts`` (:func:`tmr.model.diffdrive.step_velocities`; a
        step across two pieces is not one arc: its residual is O(a Ts³), both pieces at rest there)."""
        from tmr.model.diffdrive import step_velocities

        c0, th0, _, _ = self.pose(tau)
        c1, th1, _, _ = self.pose(tau + Ts)
        v, w, _ = step_velocities(np.array([c0, c1]), np.array([th0, th1]), Ts)
        return float(v[0]), float(w[0])


class DiffDriveQP:
    """The per-step formulation of differential-drive robots (module docstring): the lexicographic QP ``qp`` (built
    with :class:`DiffDriveSpeed` and :class:`DiffDriveAcceleration` among its limits), the robots' poses, and the
    exact unicycle integration. ``heading0`` (N,) [rad] are the initial headings.

    ``step`` returns the joint rates that move the chain's exit points to c_{k+1} + b e(θ_{k+1}); :meth:`poses`
    gives the recorded axle centres, headings, v and ω.
    """

    name = "qp"

    def __init__(
        self, qp: Any, chain: Chain, model: RobotModel, heading0: Array, goal_heading: GoalHeading | None = None
    ) -> None:
        self.goal_heading = goal_heading
        if chain.spatial:
            raise ParameterError("differential drive is a ground robot's kinematics: not for a spatial chain")
        self.qp, self.chain, self.model = qp, chain, model
        if hasattr(qp, "tensions"):  # an active winch's QP (tmr.control.winch.GroundWinchQP): its tensions per state
            self.tensions = qp.tensions
        self.heading0 = np.asarray(heading0, dtype=float).copy()
        if self.heading0.shape != (chain.n_robots,):
            raise ParameterError(
                f"heading0 must have one heading per robot ({chain.n_robots}), got {self.heading0.shape}"
            )
        self.reset_state()

    @property
    def level_keys(self) -> list[str]:
        return self.qp.level_keys

    @property
    def limits(self) -> list[Limit]:
        return _limits(self.qp)

    def reset_state(self) -> None:
        N = self.chain.n_robots
        self._axle: Array | None = None
        self._theta = self.heading0.copy()
        self._v, self._w = np.zeros(N), np.zeros(N)
        self._hist: list[tuple[Array, Array, Array, Array]] = []
        if self.goal_heading is not None:
            self.goal_heading.reference.clear()

    def reset(self) -> None:
        self.qp.reset()
        self.reset_state()

    def step(self, ctx: StepContext) -> tuple[Array, dict[str, float]]:
        m = self.model
        b, Ts = m.exit_offset, ctx.Ts
        if self._axle is None:  # the chain's start places the exit points: the axles are b behind them
            self._axle = ctx.points[1:] - b * np.column_stack([np.cos(self._theta), np.sin(self._theta)])
        gh = self.goal_heading
        if gh is not None and ctx.k >= gh.k_arrive:  # the final manoeuvre to the goal heading replaces x_d, ẋ_d
            if ctx.k == gh.k_arrive:
                gh.start(self._axle[-1], float(self._theta[-1]))
            tau = (ctx.k - gh.k_arrive) * Ts
            # x_d the manoeuvre's exit point; ẋ_d the exit-point velocity whose (v, ω) at the leader's heading θ_k
            # are the step's exact arc commands (the tangent ṗ would leave the O(Ts² b ω²) chord error of every step
            # to the CLIK, and its lag turns the heading by lag / b)
            v_ff, w_ff = gh.step_commands(tau, Ts)
            th = float(self._theta[-1])
            if tau < gh.final_turn_start:
                ctx.x_d = gh.at(tau)[0]
            else:  # the last turn and the hold: about the leader's own axle, so the CLIK corrects the heading itself
                th_ref = gh.pose(tau)[1]
                ctx.x_d = self._axle[-1] + b * np.array([math.cos(th_ref), math.sin(th_ref)])
            e, e_n = np.array([math.cos(th), math.sin(th)]), np.array([-math.sin(th), math.cos(th)])
            ctx.xd_d = v_ff * e + b * w_ff * e_n
            gh.reference[ctx.k] = ctx.x_d
        dctx = DiffDriveContext(ctx, self._theta, self._v, self._w)
        qdot, diag = self.qp.step(dctx)
        pdot = ctx.velocity_map.robot_velocities(qdot).reshape(-1, 2)
        c, s = np.cos(self._theta), np.sin(self._theta)
        v = c * pdot[:, 0] + s * pdot[:, 1]
        w = (-s * pdot[:, 0] + c * pdot[:, 1]) / b
        # the solver meets its rows to ~1e-5: the commands are put inside the bounds it was given (the acceleration's
        # too unless the step dropped them), so the poses keep them exactly
        v_lo, v_hi = np.full_like(v, -m.v_max), np.full_like(v, m.v_max)
        w_lo, w_hi = np.full_like(w, -m.omega_max), np.full_like(w, m.omega_max)
        if not diag.get("relaxed", 0.0):
            v_lo, v_hi = np.maximum(v_lo, self._v - m.a_max * Ts), np.minimum(v_hi, self._v + m.a_max * Ts)
            w_lo, w_hi = np.maximum(w_lo, self._w - m.alpha_max * Ts), np.minimum(w_hi, self._w + m.alpha_max * Ts)
        v_c, w_c = np.clip(v, v_lo, v_hi), np.clip(w, w_lo, w_hi)
        diag["diff_clip"] = float(max(np.max(np.abs(v_c - v)), b * np.max(np.abs(w_c - w))))
        diag["turning_in_place"] = float(
            np.count_nonzero((np.abs(v_c) < TURN_IN_PLACE[0]) & (np.abs(w_c) > TURN_IN_PLACE[1]))
        )
        self._hist.append((self._axle, self._theta, v_c, w_c))
        axle, theta = unicycle_step(self._axle, self._theta, v_c, w_c, Ts)
        qdot_eff = self._joint_step(ctx, exit_point(axle, theta, b)) / Ts
        self._axle, self._theta, self._v, self._w = axle, theta, v_c, w_c
        return qdot_eff, diag

    def _joint_step(self, ctx: StepContext, p_new: Array) -> Array:
        """q_{k+1} − q_k that places the robots at ``p_new`` (N, 2): per link the change of its direction (continuous,
        the angle between the old and the new direction) and of its (signed) span."""
        P_old = ctx.points
        P_new = np.vstack([P_old[:1], p_new])
        d_old = ctx.spans
        D_old, D_new = np.diff(P_old, axis=0), np.diff(P_new, axis=0)
        d_new = np.sign(d_old) * np.linalg.norm(D_new, axis=1)
        cross = D_old[:, 0] * D_new[:, 1] - D_old[:, 1] * D_new[:, 0]
        dot = np.einsum("ij,ij->i", D_old, D_new)
        dphi = np.arctan2(cross, dot)  # the turn of link j's direction u_j (signed spans turn u and D alike)
        dq = np.empty(self.chain.dof)
        dq[self.chain.revolute_index] = dphi - np.r_[0.0, dphi[:-1]]  # θ_j = φ_j − φ_{j−1}
        dq[self.chain.prismatic_index] = d_new - d_old
        return dq

    def poses(self, n_states: int) -> tuple[Array, Array, Array, Array]:
        """Axle centres (n, N, 2) [m], headings (n, N) [rad, continuous], v (n, N) [m/s] and ω (n, N) [rad/s] at
        states 0..n−1: (v, ω) of state k are held over [t_k, t_k+1] (0 after the last step, like ``Plan.qdot``)."""
        if self._axle is None:
            raise ParameterError("no step was planned: the poses are not known")
        rows = [*self._hist, (self._axle, self._theta, np.zeros_like(self._v), np.zeros_like(self._w))]
        if len(rows) < n_states:
            raise ParameterError(f"{len(rows)} poses recorded, {n_states} asked")
        rows = rows[:n_states]
        return tuple(np.array([r[i] for r in rows]) for i in range(4))  # type: ignore[return-value]


def _limits(qp: Any) -> list[Limit]:
    """The limits of a :class:`~tmr.control.qp.LexicographicQP`, or of the one inside an active winch's QP."""
    return list(getattr(qp, "limits", None) or getattr(qp.qp, "limits", []))


def make_diffdrive_qp(
    qp: Any, chain: Chain, model: RobotModel, heading0: Array, goal_heading: GoalHeading | None = None
) -> DiffDriveQP:
    """``qp`` (a :class:`~tmr.control.qp.LexicographicQP`, or an active winch's
    :class:`~tmr.control.winch.GroundWinchQP`, whose limits already hold :class:`DiffDriveSpeed` and
    :class:`DiffDriveAcceleration`, padded with the tension columns there) wrapped as the differential-drive
    formulation; ``goal_heading`` the leader's final manoeuvre (:class:`GoalHeading`) or None. With an active winch
    the winch's QP receives the :class:`DiffDriveContext` as its step context, so
    the padded v/ω rows read the headings from it."""
    names = {lim.name for lim in _limits(qp)}
    if not {DiffDriveSpeed.name, DiffDriveAcceleration.name} <= names:
        raise ParameterError("the differential-drive QP needs the diff_speed and diff_acceleration limits")
    return DiffDriveQP(qp, chain, model, heading0, goal_heading)
