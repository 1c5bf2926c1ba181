"""Whole-horizon trajectory optimisation of the chain (``--method horizon``; math in ``formulations/horizon.md``).

One nonlinear program over every knot of the plan instead of one QP per step (Caruso 2021 fitness eq. 24–27 as the
objective, the hard limits of ``formulations/qp.md`` as constraints)::

    min_{q_0..q_K}  w1 f1 + w2 f2 + w4 f4  (+ w3 f3 when the leader has a tolerance)
    s.t.  q_0 = start
          x_N(q_k) = x_d(t_k)                              leader on its time-parametrised reference, k = 1..K
          c(p_{k,j,s}) ≥ d_safe                            robots and tether samples clear of the inflated obstacles
          d_lo + m ≤ d_{k,i} ≤ d_max − m                   tether spans (catenary) = prismatic joints q[1::2]
          ‖x_i(q_k) − x_j(q_k)‖² ≥ (2r + m_s)²              robot–robot separation, every pair
          |q̇_k| ≤ (ω_max, v_d,max),  |q̈_k| ≤ a_max          joint speed and acceleration (q̇_{−1} = q̇_K = 0)
          |ẋ_{i,k}|, |ẍ_{i,k}| ≤ v_rob, a_rob per axis      robot Cartesian speed and acceleration

with q̇_k = (q_{k+1} − q_k)/Ts, q̈_k = (q̇_k − q̇_{k−1})/Ts. The clearance c is a cubic tensor B-spline whose control points
are the environment's signed-distance grid (:func:`distance_spline`). The NLP is written with whole-horizon matrix
expressions (all knots at once, casadi MX) and solved by IPOPT from the ``qp`` plan.

Clearance rows are **generated lazily**: a transcription holds the rows of the samples closer than ``activation`` to
the obstacles along the warm start (every row of every other group is always there); after each solve the clearance of
every sample at every knot is evaluated, and if one that was left out is violated, the samples within ``activation`` at
the new solution are added and IPOPT restarts primal–dual warm. The final point is a KKT point of the relaxed problem
that satisfies every row of the full one, hence a KKT point of the full problem (the rows left out are inactive, with
zero multipliers).

**Never worse than the warm start.** The warm start (a plan of the same problem, required: the planner passes its
``qp`` plan; this module never imports :mod:`tmr.planner`) is IPOPT's initial point and the last fallback. If IPOPT
stops without a solution (both attempts of a round), the time limit is reached, rows left out stay violated after
``max_rounds``, or the optimum costs more than the warm start, :func:`plan_horizon` returns the cheapest IPOPT iterate
that satisfies every row of every group (casadi ``iteration_callback``; the leader projected on its reference) or else
the warm start itself if it satisfies them; only if none does it raise :class:`HorizonInfeasible`.
``diagnostics["horizon_result"]`` is ``"optimal"``, ``"best_feasible_iterate"`` or ``"warm_start"`` and
``diagnostics["horizon_note"]`` says why in one line.

Public API: :func:`plan_horizon` (→ :class:`tmr.control.clik.Plan`), :data:`DEFAULT_TIME_LIMIT`,
:class:`HorizonOptions`,
:class:`HorizonInfeasible` (:class:`Violation`), :func:`distance_spline`, :func:`samples_needed`,
:func:`objective_terms`, :func:`objective`.
"""

from __future__ import annotations

import contextlib
import heapq
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, NamedTuple

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from tmr.control.clik import Plan
from tmr.errors import InfeasibleStep, ParameterError

Array = NDArray[np.float64]

__all__ = [
    "DEFAULT_TIME_LIMIT",
    "GROUPS",
    "HorizonInfeasible",
    "HorizonOptions",
    "Violation",
    "distance_spline",
    "objective",
    "objective_terms",
    "plan_horizon",
    "samples_needed",
]

#: Constraint groups of the NLP, in report order.
GROUPS: tuple[str, ...] = (
    "leader",
    "clearance",
    "span",
    "separation",
    "joint_speed",
    "joint_accel",
    "robot_speed",
    "robot_accel",
)

#: Wall-clock limit [s] of a whole :func:`plan_horizon` call used by the command line (``--time-limit``); the library
#: default is no limit (``time_limit=None``). Successful runs on A–D take 2.5–4.5 s.
DEFAULT_TIME_LIMIT: float = 60.0

_SUCCESS = ("Solve_Succeeded",)
_ACCEPTABLE = ("Solved_To_Acceptable_Level",)
_WALL_TIME = "Maximum_WallTime_Exceeded"
_POOL_SIZE = 64  # iterates kept for the fallback (the cheapest ones; 64 × 9 k doubles ≈ 4.6 MB on A–D)
_POOL_SCREEN = 1e-3  # kept only if no transcribed row is violated by more than this (the leader is projected after)


# ----------------------------------------------------------------------------------------------------------------
# options, errors
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class HorizonOptions:
    """Options of :func:`plan_horizon` (each one is also a keyword of it). Units: m, s, rad.

    Attributes:
        w_energy: weight w1 of f1 = Σ q̇ᵀq̇ (Caruso 2021 eq. 24).
        w_uniformity: weight w2 of f2 = Σ_k Σ_{i<j} (d_i − d_j)² (eq. 25).
        w_smoothness: weight w4 of f4 = Σ q̈ᵀq̈ (eq. 27).
        w_tracking: weight w3 of f3 = Σ ‖x_e − x_d‖² (eq. 26), used only with ``leader_tolerance > 0``.
        leader_tolerance: 0 (default): the leader is *on* its reference at every knot (2 equality rows per knot);
            ε > 0: ‖x_e,k − x_d,k‖² ≤ ε² [m] and w3 f3 joins the cost.
        samples_per_link: clearance samples per tether at s = i/S, i = 1..S (s = 1 is the robot); ``None``: the
            smallest S for which the sagitta bound keeps the whole tether clear (:func:`samples_needed`; 15 for the
            default limits).
        field_error: bound on how much the spline field may *over*estimate the exact clearance [m] (measured ≤ 9 mm
            on A–D), used by :func:`samples_needed`.
        d_safe: clearance the samples keep [m]; ``None``: ``QPParams.d_safe`` (0.05 m).
        activation: clearance rows only for samples closer than this to the obstacles [m] along the warm start (or a
            previous round's solution): the lazy rows, see the module docstring. Every other group is always complete.
        max_rounds: transcriptions at most (a round adds the clearance rows that were left out and came out violated).
        max_iter, tol, acceptable_tol, acceptable_iter, constr_viol_tol, mu_strategy, mu_init, hessian,
            linear_solver, nlp_scaling, min_hessian_perturbation: IPOPT options (choices and measurements in
            ``formulations/horizon.md``).
        accept_acceptable: also accept IPOPT's ``Solved_To_Acceptable_Level`` (KKT error below ``acceptable_tol`` for
            ``acceptable_iter`` iterations, constraint violation below ``constr_viol_tol``); the status is recorded.
        retry: if IPOPT stops without a solution, solve the round once more from the same start with ``retry_ipopt``
            merged into the options and least-squares multipliers of the leader rows (another path to the optimum;
            the fallbacks of :func:`plan_horizon` are used only if both attempts fail).
        warm_start_leader_error: with the equality leader, the warm start *as given* (not projected on the reference)
            is still a fallback if its leader stays within this distance [m] of the reference at every knot and every
            other row holds (a ``qp`` plan lags its reference by ≤ 4.6 mm on A–D: CLIK).
        expand: expand the MX graph to SX (default False: measured 3× slower, the B-spline is one call node per point).
        scale_objective: divide the cost by its warm-start value, so IPOPT sees O(1) (without: 35–80 % more
            iterations on A–D).
        ipopt: extra IPOPT options, merged last.
    """

    w_energy: float = 1.0
    w_uniformity: float = 1.0
    w_smoothness: float = 1.0
    w_tracking: float = 1.0e4
    leader_tolerance: float = 0.0
    samples_per_link: int | None = None
    field_error: float = 0.015
    d_safe: float | None = None
    activation: float = 0.3
    max_rounds: int = 4
    max_iter: int = 200
    tol: float = 1e-6
    acceptable_tol: float = 1e-4
    acceptable_iter: int = 10
    constr_viol_tol: float = 1e-6
    mu_strategy: str = "adaptive"
    mu_init: float = 1e-3
    hessian: str = "exact"
    linear_solver: str = "mumps"
    nlp_scaling: str = "none"
    min_hessian_perturbation: float = 1e-3
    accept_acceptable: bool = True
    retry: bool = True
    retry_ipopt: dict[str, Any] = field(default_factory=lambda: {"min_hessian_perturbation": 1e-2})
    warm_start_leader_error: float = 0.01
    expand: bool = False
    scale_objective: bool = True
    ipopt: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in (
            "w_energy",
            "w_uniformity",
            "w_smoothness",
            "w_tracking",
            "leader_tolerance",
            "field_error",
            "warm_start_leader_error",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ParameterError(f"HorizonOptions.{name} must be a finite number ≥ 0, got {v!r}")
        if self.samples_per_link is not None and int(self.samples_per_link) < 1:
            raise ParameterError(f"samples_per_link must be ≥ 1, got {self.samples_per_link}")
        if not self.activation > 0:
            raise ParameterError(f"activation must be > 0 m, got {self.activation}")
        if self.max_rounds < 1 or self.max_iter < 1:
            raise ParameterError("max_rounds and max_iter must be ≥ 1")
        if self.hessian not in ("exact", "limited-memory"):
            raise ParameterError(f"hessian must be 'exact' or 'limited-memory', got {self.hessian!r}")


class Violation(NamedTuple):
    """The worst violated row of one constraint group at one knot."""

    group: str  #: one of :data:`GROUPS`
    knot: int  #: k (time t_k = k Ts)
    t: float  #: t_k [s]
    item: str  #: which row: "robot 2", "tether 3 at s = 0.47", "robots 1–2", "joint 4 (d2)", "robot 1 x", ...
    amount: float  #: how far beyond its bound (> 0), in ``unit``
    unit: str


class HorizonInfeasible(InfeasibleStep):
    """The whole-horizon NLP has no (found) solution that satisfies its hard constraints.

    Raised when the fixed start violates a hard constraint, or when IPOPT stops without a solution (infeasible problem
    detected, iteration limit, restoration failure, time limit, …) and neither an iterate nor the warm start satisfies
    every row. ``violations`` lists, per constraint group and knot, the worst violated row at the last iterate;
    ``status`` is IPOPT's return status (``"start_infeasible"``, or ``"time_limit"`` if IPOPT never ran);
    ``diagnostics`` its statistics.
    """

    def __init__(
        self, message: str, violations: list[Violation], status: str = "", diagnostics: dict[str, Any] | None = None
    ) -> None:
        super().__init__(message)
        self.violations = list(violations)
        self.status = status
        self.diagnostics = dict(diagnostics or {})

    @property
    def groups(self) -> list[str]:
        """Violated constraint groups, in :data:`GROUPS` order."""
        seen = {v.group for v in self.violations}
        return [g for g in GROUPS if g in seen]


# ----------------------------------------------------------------------------------------------------------------
# building blocks
# ----------------------------------------------------------------------------------------------------------------
def distance_spline(env: Any) -> ca.Function:
    """Smooth signed distance to the inflated obstacles, ``f(p (2, 1)) -> c`` [m] (casadi; ``f.map(M)`` for batches).

    A cubic tensor B-spline whose control points are the samples of the environment's signed distance field
    (``env._grid``, cell h = ``env.resolution``) on uniform knots centred on the samples: nothing is fitted, so it is
    built instantly. This quasi-interpolant reproduces bilinear functions; elsewhere it is a local weighted mean of the
    samples (weights ≥ 0, second moment 2h²/3), so it lies *below* the field at the field's kinks in free space (the
    distance to a union is a minimum of distances: concave there) and above it by at most κh²/3 where the field is
    smooth with curvature κ ≤ 1/r (1.7 mm for h = 5 cm, r = 0.5 m). Measured against the exact (shapely) clearance
    within 0.5 m of the obstacles of A–D: overestimate ≤ 9 mm (99.9 % ≤ 2.7 mm).

    It is wrapped with ``never_inline`` so that an SX-expanded NLP keeps it as a call node (the B-spline node has no SX
    form).
    """
    fld, origin, _ = env._grid
    d = np.asarray(fld[..., 0], dtype=float)
    nx, ny = d.shape
    h = float(env.resolution)
    kx = (origin[0] + h * (np.arange(nx + 4) - 2.0)).tolist()
    ky = (origin[1] + h * (np.arange(ny + 4) - 2.0)).tolist()
    spline = ca.Function.bspline("clearance_spline", [kx, ky], d.ravel(order="F").tolist(), [3, 3], 1, {})
    p = ca.MX.sym("p", 2, 1)
    return ca.Function("clearance", [p], [spline(p)], {"never_inline": True})


def samples_needed(span_max: float, r: float, d_safe: float, field_error: float) -> int:
    """Clearance samples per tether so that the straight tether between two samples stays out of the obstacles.

    Every obstacle is grown by the safety radius r, and along a unit-speed line the squared distance to any closed set
    has second derivative ≤ 2, so a chord of length δ whose end points are ≥ r + c from the raw obstacles stays
    ≥ √((r + c)² − δ²/4) from them (the sagitta of a circle of radius r + c). The samples keep ``d_safe`` in a field
    that overestimates the clearance by at most ``field_error`` = e, so c = d_safe − e, and the chord keeps a clearance
    ≥ 0 if δ ≤ 2√((r + c)² − r²). Samples at s = i/S along a span ≤ ``span_max``: S = ⌈span_max / δ⌉.
    """
    c = d_safe - field_error
    if c <= 0:
        raise ParameterError(f"d_safe = {d_safe} m must exceed the field error budget {field_error} m")
    delta = 2.0 * math.sqrt((r + c) ** 2 - r**2)
    return max(1, math.ceil(span_max / delta - 1e-9))


def objective_terms(q: Array, Ts: float, reference: Array | None = None, base: Array | None = None) -> dict[str, float]:
    """f1, f2, f4 (and f3 when ``reference`` and ``base`` are given) of a joint trajectory ``q`` (K+1, 2N).

    q̇_k = (q_{k+1} − q_k)/Ts for k < K, q̇_K = 0, q̈_k = (q̇_k − q̇_{k−1})/Ts: exactly
    :func:`tmr.checks.metrics.fitness` of a
    plan with these joints (Caruso 2021 eq. 24–27).
    """
    q = np.asarray(q, dtype=float)
    qd = np.vstack([np.diff(q, axis=0) / Ts, np.zeros((1, q.shape[1]))])
    d = q[:, 1::2]
    i, j = np.triu_indices(d.shape[1], k=1)
    out = {
        "f1": float(np.sum(qd * qd)),
        "f2": float(np.sum((d[:, i] - d[:, j]) ** 2)),
        "f4": float(np.sum((np.diff(qd, axis=0) / Ts) ** 2)),
    }
    if reference is not None and base is not None:
        phi = np.cumsum(q[:, 0::2], axis=1)
        xe = np.asarray(base, float)[:2] + np.stack([np.sum(d * np.cos(phi), 1), np.sum(d * np.sin(phi), 1)], 1)
        e = xe[1:] - np.asarray(reference, float)[1:, :2]
        out["f3"] = float(np.sum(e * e))
    return out


def objective(q: Array, problem: Any, **options: Any) -> float:
    """The NLP's cost w1 f1 + w2 f2 + w4 f4 (+ w3 f3 with a leader tolerance) of joints ``q`` (K+1, 2N)."""
    opts = _options(options)
    tr = problem.trajectory
    terms = objective_terms(q, float(tr.t[1] - tr.t[0]), tr.x, problem.chain.base)
    return _weighted(terms, opts)


def _weighted(terms: dict[str, float], opts: HorizonOptions) -> float:
    J = opts.w_energy * terms["f1"] + opts.w_uniformity * terms["f2"] + opts.w_smoothness * terms["f4"]
    if opts.leader_tolerance > 0:
        J += opts.w_tracking * terms["f3"]
    return float(J)


def _options(options: dict[str, Any]) -> HorizonOptions:
    names = {f.name for f in fields(HorizonOptions)}
    unknown = set(options) - names
    if unknown:
        raise ParameterError(f"unknown horizon option(s) {sorted(unknown)}; available: {', '.join(sorted(names))}")
    return replace(HorizonOptions(), **options)


# ----------------------------------------------------------------------------------------------------------------
# the model: numbers and whole-horizon expressions
# ----------------------------------------------------------------------------------------------------------------
class _Setup:
    """Numbers of the problem: limits, samples, reference (SI units)."""

    def __init__(self, problem: Any, opts: HorizonOptions) -> None:
        chain = problem.chain
        if chain.spatial:
            raise ParameterError("the horizon formulation is planar only (2N joints)")
        qp = problem.qp_params
        self.opts = opts
        self.N, self.n = chain.n_robots, chain.dof
        self.base = chain.base[:2].astype(float)
        self.t = np.asarray(problem.trajectory.t, dtype=float)
        self.K = self.t.size - 1
        if self.K < 2:
            raise ParameterError("the horizon needs at least 2 steps (K ≥ 2)")
        self.Ts = float(self.t[1] - self.t[0])
        self.ref = np.asarray(problem.trajectory.x, dtype=float)[:, :2]
        self.q0 = chain.check_q(problem.q0).astype(float)
        self.limits = np.broadcast_to(np.asarray(problem.span_limits, float), (self.N, 2)).copy()
        self.r = float(problem.chain_params.safety_radius)
        self.d_safe = float(qp.d_safe if opts.d_safe is None else opts.d_safe)
        self.span_lo = self.limits[:, 0] + float(qp.span_margin)
        self.span_hi = self.limits[:, 1] - float(qp.span_margin)
        self.sep_min = 2 * self.r + float(qp.separation_margin)
        self.vmax = np.where(chain.is_prismatic, qp.span_speed_max, qp.joint_speed_max).astype(float)
        self.amax = float(qp.accel_max)
        self.v_rob, self.a_rob = float(qp.robot_speed_max), float(qp.robot_accel_max)
        if opts.samples_per_link is None:
            self.S = samples_needed(float(self.limits[:, 1].max()), self.r, self.d_safe, opts.field_error)
        else:
            self.S = int(opts.samples_per_link)
        S = self.S
        self.s = np.arange(1, S + 1) / S
        Ls = np.zeros((self.N * S, self.N + 1))  # sample = Ls @ [base; robots], rows: tether major, sample minor
        for j in range(self.N):
            Ls[j * S : (j + 1) * S, j] = 1 - self.s
            Ls[j * S : (j + 1) * S, j + 1] = self.s
        self.Ls = Ls
        self.sample_labels = [
            f"robot {j + 1}" if i == S - 1 else f"tether {j + 1} at s = {self.s[i]:.2f}"
            for j in range(self.N)
            for i in range(S)
        ]
        self.pairs = [(int(i), int(j)) for i, j in zip(*np.triu_indices(self.N, k=1), strict=True)]

    def robots(self, Q: Array) -> Array:
        """(K+1, N, 2) robot positions of joints Q (K+1, n) (Caruso 2021 eq. 2, planar closed form)."""
        Q = np.atleast_2d(Q)
        phi = np.cumsum(Q[:, 0::2], axis=1)
        u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        return self.base + np.cumsum(Q[:, 1::2, None] * u, axis=1)


class _Rows(NamedTuple):
    """One constraint group over the whole horizon: ``lo ≤ expr ≤ hi`` entrywise, expr (rows, cols) in knots."""

    expr: Any  # MX (rows, cols); None for clearance (built from points)
    lo: Array  # (rows,)
    hi: Array  # (rows,)
    knots: NDArray[np.int_]  # (cols,) knot of every column
    items: list[str]  # (rows,) labels
    unit: str


class _Model:
    """Whole-horizon symbolic model (casadi MX, every knot at once) and the full numeric evaluation of every row."""

    def __init__(self, su: _Setup, clr: ca.Function) -> None:
        opts = su.opts
        N, n, K, Ts = su.N, su.n, su.K, su.Ts
        self.su, self.clr = su, clr
        x = ca.MX.sym("q", n * (K + 1))  # x = [q_0; q_1; ...; q_K]
        Q = ca.reshape(x, n, K + 1)  # column k = q_k
        D = Q[1::2, :]
        tril = ca.DM(np.tril(np.ones((N, N))))
        Phi = ca.mtimes(tril, Q[0::2, :])  # absolute headings
        X = su.base[0] + ca.mtimes(tril, D * ca.cos(Phi))  # (N, K+1) robot x
        Y = su.base[1] + ca.mtimes(tril, D * ca.sin(Phi))
        Qd = (Q[:, 1:] - Q[:, :-1]) / Ts  # q̇_0 .. q̇_{K−1}; q̇_K = 0
        zn = ca.DM.zeros(n, 1)
        Qdd = (ca.horzcat(Qd, zn) - ca.horzcat(zn, Qd)) / Ts  # q̈_0 (from rest) .. q̈_K (to rest)
        ex = X[N - 1, 1:] - su.ref[1:, 0].reshape(1, -1)
        ey = Y[N - 1, 1:] - su.ref[1:, 1].reshape(1, -1)
        f1 = ca.sumsqr(Qd)
        f2 = sum((ca.sumsqr(D[i, :] - D[j, :]) for i, j in su.pairs), ca.MX(0))
        f3 = ca.sumsqr(ex) + ca.sumsqr(ey)
        f4 = ca.sumsqr(Qdd[:, 1:])  # eq. 27: k = 1..K
        J = opts.w_energy * f1 + opts.w_uniformity * f2 + opts.w_smoothness * f4
        if opts.leader_tolerance > 0:
            J = J + opts.w_tracking * f3
        self.x, self.J = x, J
        self.terms = ca.Function("terms", [x], [f1, f2, f3, f4])
        self.grad = ca.Function("grad", [x], [ca.gradient(J, x)])

        k1 = np.arange(1, K + 1)
        rows: dict[str, _Rows] = {}
        if opts.leader_tolerance > 0:
            rows["leader"] = _Rows(
                ex * ex + ey * ey,
                np.array([-np.inf]),
                np.array([opts.leader_tolerance**2]),
                k1,
                [f"robot {N} (distance² to the reference)"],
                "m²",
            )
        else:
            rows["leader"] = _Rows(
                ca.vertcat(ex, ey), np.zeros(2), np.zeros(2), k1, [f"robot {N} x", f"robot {N} y"], "m"
            )
        # clearance sample points (N S, K+1), index in vec order = m + N S k
        Ls = ca.DM(su.Ls)
        ones = ca.DM.ones(1, K + 1)
        self.Px = ca.vec(ca.mtimes(Ls, ca.vertcat(su.base[0] * ones, X)))
        self.Py = ca.vec(ca.mtimes(Ls, ca.vertcat(su.base[1] * ones, Y)))
        M = N * su.S
        rows["clearance"] = _Rows(
            None, np.full(M, su.d_safe), np.full(M, np.inf), np.arange(K + 1), su.sample_labels, "m"
        )
        if su.pairs:
            sep = ca.vertcat(*[(X[i, :] - X[j, :]) ** 2 + (Y[i, :] - Y[j, :]) ** 2 for i, j in su.pairs])
            rows["separation"] = _Rows(
                sep,
                np.full(len(su.pairs), su.sep_min**2),
                np.full(len(su.pairs), np.inf),
                np.arange(K + 1),
                [f"robots {i + 1}–{j + 1} (distance²)" for i, j in su.pairs],
                "m²",
            )
        jl = [f"joint {i + 1} ({'d' if i % 2 else 'θ'}{i // 2 + 1})" for i in range(n)]
        rows["joint_speed"] = _Rows(Qd, -su.vmax, su.vmax, np.arange(K), jl, "rad/s | m/s")
        rows["joint_accel"] = _Rows(
            Qdd, np.full(n, -su.amax), np.full(n, su.amax), np.arange(K + 1), jl, "rad/s² | m/s²"
        )
        Vx, Vy = (X[:, 1:] - X[:, :-1]) / Ts, (Y[:, 1:] - Y[:, :-1]) / Ts
        rl = [f"robot {i + 1} {a}" for a in "xy" for i in range(N)]
        rows["robot_speed"] = _Rows(
            ca.vertcat(Vx, Vy), np.full(2 * N, -su.v_rob), np.full(2 * N, su.v_rob), np.arange(K), rl, "m/s"
        )
        zN = ca.DM.zeros(N, 1)
        Ax = (ca.horzcat(Vx, zN) - ca.horzcat(zN, Vx)) / Ts
        Ay = (ca.horzcat(Vy, zN) - ca.horzcat(zN, Vy)) / Ts
        rows["robot_accel"] = _Rows(
            ca.vertcat(Ax, Ay), np.full(2 * N, -su.a_rob), np.full(2 * N, su.a_rob), np.arange(K + 1), rl, "m/s²"
        )
        self.rows = rows
        # numeric evaluation of every row of every group (the clearance of all samples through one mapped call)
        names = [g for g in rows if g != "clearance"]
        self._names = names
        self._full = ca.Function("rows", [x], [rows[g].expr for g in names] + [ca.horzcat(self.Px, self.Py).T])
        self._clr_all = clr.map(M * (K + 1))

    def values(self, xv: Array) -> dict[str, Array]:
        """Every row of every group at ``xv``: name → (rows, cols) array (clearance: (N S, K+1))."""
        out = self._full(xv)
        vals = {g: np.asarray(v, dtype=float) for g, v in zip(self._names, out[:-1], strict=True)}
        M = self.su.N * self.su.S
        vals["clearance"] = np.asarray(self._clr_all(out[-1]), dtype=float).reshape(self.su.K + 1, M).T
        return vals

    def fixed_columns(self, name: str) -> NDArray[np.bool_]:
        """Columns of a group that depend only on the fixed start q_0 (never rows of the NLP)."""
        knots = self.rows[name].knots
        if name in ("clearance", "separation"):
            return knots == 0
        return np.zeros(knots.size, dtype=bool)

    def violation(self, name: str, v: Array) -> Array:
        """How far each entry of group ``name`` (values ``v`` (rows, cols)) is beyond its bounds (≤ 0: satisfied)."""
        r = self.rows[name]
        return np.maximum(r.lo[:, None] - v, v - r.hi[:, None])

    def near(self, name: str, v: Array) -> NDArray[np.bool_]:
        """Entries that are rows of the next transcription: every entry, except clearance samples farther than
        ``activation`` from the obstacles (lazy rows)."""
        if name == "clearance":
            m = (v < self.su.opts.activation) | (self.violation(name, v) > 0)
        else:
            m = np.ones(v.shape, dtype=bool)
        m[:, self.fixed_columns(name)] = False
        return m


class _Transcription:
    """The NLP of one round: the selected rows of every group, their bounds and labels, and the IPOPT solver."""

    def __init__(self, model: _Model, masks: dict[str, NDArray[np.bool_]]) -> None:
        su = model.su
        self.opts = su.opts
        K, n = su.K, su.n
        g: list[Any] = []
        lbg: list[Array] = []
        ubg: list[Array] = []
        self.index: dict[str, NDArray[np.int_]] = {}  # flat (column-major) entries of each group's (rows, cols)
        self.offset: dict[str, int] = {}
        start = 0
        for name in GROUPS:
            if name not in model.rows or name == "span":
                continue
            r = model.rows[name]
            mask = masks[name]
            idx = np.flatnonzero(mask.ravel(order="F"))
            self.index[name], self.offset[name] = idx, start
            if idx.size == 0:
                continue
            rows = mask.shape[0]
            if name == "clearance":
                il = idx.tolist()
                P = ca.horzcat(model.Px[il], model.Py[il]).T
                g.append(ca.vec(model.clr.map(idx.size)(P)))
            else:
                g.append(ca.vec(r.expr)[idx.tolist()])
            lbg.append(r.lo[idx % rows])
            ubg.append(r.hi[idx % rows])
            start += idx.size
        self.size = start
        self.g = ca.vertcat(*g) if g else ca.MX(0, 1)
        self.lbg = np.concatenate(lbg) if lbg else np.zeros(0)
        self.ubg = np.concatenate(ubg) if ubg else np.zeros(0)
        lbx = np.full((K + 1, n), -np.inf)
        ubx = np.full((K + 1, n), np.inf)
        lbx[:, 1::2], ubx[:, 1::2] = su.span_lo, su.span_hi
        lbx[0], ubx[0] = su.q0, su.q0  # q_0 fixed: IPOPT removes it (fixed_variable_treatment make_parameter)
        self.lbx, self.ubx = lbx.ravel(), ubx.ravel()
        self.nlp = {"x": model.x, "f": model.J, "g": self.g}

    def solver(self, obj_scale: float, extra: dict[str, Any], callback: ca.Callback | None = None) -> ca.Function:
        """IPOPT on this transcription, cost divided by ``obj_scale``, with ``extra`` IPOPT options and an optional
        casadi ``iteration_callback`` (called with x, f, g, … of every iterate; it must outlive the solver)."""
        nlp = dict(self.nlp, f=self.nlp["f"] / obj_scale)
        opts = _solver_opts(self.opts, extra)
        if callback is not None:
            opts["iteration_callback"] = callback
        return ca.nlpsol("horizon", "ipopt", nlp, opts)

    def carry_multipliers(self, old: _Transcription, lam_g: Array) -> Array:
        """Constraint multipliers of the previous round mapped onto this round's rows (new rows start at 0)."""
        out = np.zeros(self.size)
        for name, idx in self.index.items():
            oidx = old.index.get(name)
            if oidx is None or idx.size == 0 or oidx.size == 0:
                continue
            pos = np.minimum(np.searchsorted(oidx, idx), oidx.size - 1)
            same = oidx[pos] == idx
            out[self.offset[name] + np.flatnonzero(same)] = lam_g[old.offset[name] + pos[same]]
        return out


def _leader_multipliers(model: _Model, tr: _Transcription, xv: Array, obj_scale: float) -> Array:
    """Least-squares multipliers of the leader equality rows at ``xv`` (the others 0): per knot k ≥ 1,
    λ_k = −(J_k J_kᵀ)⁻¹ J_k ∇_{q_k} f, so the first Hessian already carries the curvature of the leader constraint."""
    su = model.su
    Q = xv.reshape(su.K + 1, su.n)
    grad = np.asarray(model.grad(xv), dtype=float).reshape(su.K + 1, su.n)[1:] / obj_scale
    Je = _leader_jacobians(su, Q[1:])
    lam = -np.linalg.solve(Je @ np.swapaxes(Je, 1, 2), (Je @ grad[..., None]))[..., 0]  # (K, 2)
    out = np.zeros(tr.size)
    idx = tr.index["leader"]  # flat entries of the (2, K) leader block, column-major: row + 2 col
    out[tr.offset["leader"] : tr.offset["leader"] + idx.size] = lam.ravel()[idx]
    return out


def _solver_opts(opts: HorizonOptions, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    ip: dict[str, Any] = {
        "print_level": 0,
        "sb": "yes",
        "print_timing_statistics": "no",
        "max_iter": int(opts.max_iter),
        "tol": float(opts.tol),
        "acceptable_tol": float(opts.acceptable_tol),
        "acceptable_iter": int(opts.acceptable_iter),
        "constr_viol_tol": float(opts.constr_viol_tol),
        "mu_strategy": opts.mu_strategy,
        "mu_init": float(opts.mu_init),
        "linear_solver": opts.linear_solver,
        "hessian_approximation": opts.hessian,
        "nlp_scaling_method": opts.nlp_scaling,
        "min_hessian_perturbation": float(opts.min_hessian_perturbation),
        "acceptable_constr_viol_tol": float(opts.constr_viol_tol),
        "warm_start_init_point": "yes",
        "warm_start_bound_push": 1e-6,
        "warm_start_bound_frac": 1e-6,
        "warm_start_slack_bound_push": 1e-6,
        "warm_start_slack_bound_frac": 1e-6,
        "warm_start_mult_bound_push": 1e-6,
    }
    ip.update(extra or {})
    ip.update(opts.ipopt)
    return {"ipopt": ip, "print_time": False, "expand": bool(opts.expand), "error_on_fail": False}


# ----------------------------------------------------------------------------------------------------------------
# violations
# ----------------------------------------------------------------------------------------------------------------
def _violations(model: _Model, vals: dict[str, Array], Q: Array, tol: float) -> list[Violation]:
    """Worst violated row per (group, knot), over every row of every group (fixed start columns excluded)."""
    su = model.su
    out: dict[tuple[str, int], Violation] = {}

    def put(name: str, k: int, item: str, amount: float, unit: str) -> None:
        key = (name, k)
        if key not in out or amount > out[key].amount:
            out[key] = Violation(name, k, float(su.t[k]), item, float(amount), unit)

    for name, r in model.rows.items():
        a = model.violation(name, vals[name])
        a[:, model.fixed_columns(name)] = 0.0
        for i, c in zip(*np.nonzero(a > tol), strict=True):
            put(name, int(r.knots[c]), r.items[i], a[i, c], r.unit)
    d = Q[:, 1::2]
    a = np.maximum(su.span_lo - d, d - su.span_hi)
    a[0] = 0.0
    for k, i in zip(*np.nonzero(a > tol), strict=True):
        put("span", int(k), f"tether {i + 1}", a[k, i], "m")
    order = {g: i for i, g in enumerate(GROUPS)}
    return sorted(out.values(), key=lambda v: (order[v.group], v.knot))


def _describe(violations: list[Violation], worst: int = 3) -> str:
    """One line per violated group: how many knots, the time span, the worst rows."""
    parts = []
    for name in GROUPS:
        vs = [v for v in violations if v.group == name]
        if not vs:
            continue
        top = sorted(vs, key=lambda v: -v.amount)[:worst]
        w = "; ".join(f"{v.item} at knot {v.knot} (t = {v.t:.2f} s) by {v.amount:.3g} {v.unit}" for v in top)
        k0, k1 = min(v.knot for v in vs), max(v.knot for v in vs)
        t0, t1 = min(v.t for v in vs), max(v.t for v in vs)
        where = f"k = {k0} (t = {t0:.2f} s)" if k0 == k1 else f"k = {k0}–{k1} (t = {t0:.2f}–{t1:.2f} s)"
        parts.append(f"{name}: {len(vs)} knot(s), {where}, worst: {w}")
    return " | ".join(parts)


def _check_start(su: _Setup, env: Any) -> list[Violation]:
    """Hard constraints the fixed start q_0 violates (then no trajectory can satisfy the rows of knot 1)."""
    out = []
    d = su.q0[1::2]
    for i in range(su.N):
        lo, hi = su.limits[i]
        if d[i] > hi:
            out.append(
                Violation(
                    "span",
                    0,
                    0.0,
                    f"tether {i + 1}: start span {d[i]:.3f} m > d_max = {hi:.3f} m",
                    float(d[i] - hi),
                    "m",
                )
            )
        elif d[i] < lo:
            out.append(
                Violation(
                    "span",
                    0,
                    0.0,
                    f"tether {i + 1}: start span {d[i]:.3f} m < d_lo = {lo:.3f} m",
                    float(lo - d[i]),
                    "m",
                )
            )
    R = su.robots(su.q0)[0]
    c = np.asarray(env.exact_clearance(R), dtype=float)
    for i in np.flatnonzero(c < 0):
        out.append(Violation("clearance", 0, 0.0, f"robot {i + 1} starts inside an obstacle", float(-c[i]), "m"))
    for i, j in su.pairs:
        gap = 2 * su.r - float(np.linalg.norm(R[i] - R[j]))
        if gap > 0:
            out.append(Violation("separation", 0, 0.0, f"robots {i + 1}–{j + 1} start closer than 2r", gap, "m"))
    e = float(np.linalg.norm(R[-1] - su.ref[0]))
    if e > max(su.opts.leader_tolerance, 1e-6):
        out.append(Violation("leader", 0, 0.0, f"robot {su.N} starts off the reference", e, "m"))
    return out


# ----------------------------------------------------------------------------------------------------------------
# warm start
# ----------------------------------------------------------------------------------------------------------------
def _leader_jacobians(su: _Setup, Q: Array) -> Array:
    """(M, 2, n) Jacobians of the leader position at joints Q (M, n) (Caruso 2021 eq. 9, planar)."""
    phi = np.cumsum(Q[:, 0::2], axis=1)
    u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    P = np.cumsum(Q[:, 1::2, None] * u, axis=1)
    rel = P[:, -1:, :] - np.concatenate([np.zeros((Q.shape[0], 1, 2)), P[:, :-1]], axis=1)
    J = np.zeros((Q.shape[0], 2, su.n))
    J[:, 0, 0::2], J[:, 1, 0::2] = -rel[..., 1], rel[..., 0]
    J[:, :, 1::2] = np.swapaxes(u, 1, 2)
    return J


def _project_leader(su: _Setup, Q: Array) -> Array:
    """A copy of joints Q (K+1, n) with the leader on its reference at every knot k ≥ 1: per knot, up to five
    Gauss–Newton steps of minimum joint change q ← q + J_eᵀ(J_e J_eᵀ)⁻¹(x_d − x_N(q)) (to 10⁻¹² m)."""
    Q = np.array(Q, dtype=float)
    for _ in range(5):
        e = su.ref[1:] - su.robots(Q[1:])[:, -1]
        if np.max(np.abs(e)) < 1e-12:
            break
        Je = _leader_jacobians(su, Q[1:])
        JJt = Je @ np.swapaxes(Je, 1, 2) + 1e-12 * np.eye(2)
        Q[1:] += np.einsum("kji,kj->ki", Je, np.linalg.solve(JJt, e[..., None])[..., 0])
    return Q


def _warm_start(su: _Setup, warm: Plan) -> tuple[Array, Array, dict[str, Any]]:
    """Joints (K+1, n) to start IPOPT from (the warm start's, q_0 = start, leader projected on x_d with the equality
    leader) and the warm start's joints as given (padded with its last configuration if it stopped early)."""
    info: dict[str, Any] = {}
    Q = np.asarray(warm.q, dtype=float)
    if Q.ndim != 2 or Q.shape[1] != su.n or Q.shape[0] < 1:
        raise ParameterError(f"warm start q must have shape (K+1, {su.n}), got {Q.shape}")
    info["warm_start_method"] = str(warm.method)
    info["warm_start_success"] = bool(warm.success)
    info["warm_start_steps"] = int(Q.shape[0] - 1)
    if Q.shape[0] < su.K + 1:  # a plan that stopped early: hold its last configuration
        Q = np.vstack([Q, np.repeat(Q[-1:], su.K + 1 - Q.shape[0], axis=0)])
    raw = Q[: su.K + 1].copy()
    info["objective_warm_start_raw"] = _weighted(objective_terms(raw, su.Ts, su.ref, su.base), su.opts)
    Q = raw.copy()
    Q[0] = su.q0
    if su.opts.leader_tolerance == 0:  # leader exactly on x_d, so IPOPT starts on the equality rows
        Q = _project_leader(su, Q)
    return Q, raw, info


# ----------------------------------------------------------------------------------------------------------------
# fallbacks: the warm start and the best feasible iterate
# ----------------------------------------------------------------------------------------------------------------
class _Candidate(NamedTuple):
    """A trajectory that satisfies every hard-constraint row: what :func:`plan_horizon` may return."""

    Q: Array  #: (K+1, n) joints
    J: float  #: weighted objective w1 f1 + w2 f2 + w4 f4 (+ w3 f3)
    result: str  #: "optimal", "best_feasible_iterate" or "warm_start"
    detail: str  #: where it comes from, for the note


def _cost(su: _Setup, Q: Array) -> float:
    return _weighted(objective_terms(Q, su.Ts, su.ref, su.base), su.opts)


def _warm_candidate(model: _Model, warm: Plan, Qw: Array, raw: Array, tol: float) -> tuple[_Candidate | None, str]:
    """The warm start as a fallback if it satisfies the hard constraints (else ``None`` and why not).

    Only a successful plan (``warm.success``: for the planner's ``qp`` plan, verified by :func:`tmr.planner.check`
    with exact clearances of robots and tether segments) is a fallback, and every row must hold at ``tol`` except that
    a clearance sample may read up to ``field_error`` [m] below ``d_safe`` in the spline field (the warm start kept
    d_safe in its own formulation's distance field; the two fields differ by up to the spline's error budget). Tried in
    order: (1) the warm start as given, if it starts at q_0 and every row holds at ``tol`` (the fallback is then the
    warm start itself, cost included); (2) the warm start with its leader projected on the reference (IPOPT's initial
    point); (3) with the equality leader, the warm start as given with its leader within ``warm_start_leader_error``
    [m] of the reference at every knot (a ``qp`` plan lags its reference by a few mm: CLIK).
    """
    su = model.su
    if not warm.success:
        return None, f"the {warm.method} plan failed ({warm.failure or 'no reason given'})"
    name = f"the warm-start {warm.method} plan"
    slack = float(su.opts.field_error)

    def blocking(viol: list[Violation]) -> list[Violation]:
        return [v for v in viol if not (v.group == "clearance" and v.amount <= slack)]

    def dip(viol: list[Violation]) -> str:
        a = max((v.amount for v in viol if v.group == "clearance"), default=0.0)
        return f"; clearance up to {1e3 * a:.2f} mm below d_safe in the spline field" if a > 0 else ""

    at_start = bool(np.allclose(raw[0], su.q0, rtol=0.0, atol=1e-9))
    viol_raw = _violations(model, model.values(raw.ravel()), raw, tol)
    if at_start and not viol_raw:
        return _Candidate(raw, _cost(su, raw), "warm_start", name), ""
    viol = _violations(model, model.values(Qw.ravel()), Qw, tol)
    if not blocking(viol):
        detail = f"{name}, leader projected on the reference" if su.opts.leader_tolerance == 0 else name
        return _Candidate(Qw, _cost(su, Qw), "warm_start", detail + dip(viol)), ""
    why = f"the {warm.method} plan violates {_describe(blocking(viol), worst=1)}"
    if su.opts.leader_tolerance == 0 and at_start:
        err = float(np.max(np.linalg.norm(su.robots(raw[1:])[:, -1] - su.ref[1:], axis=1)))
        rest = blocking([v for v in viol_raw if v.group != "leader"])
        if not rest and err <= su.opts.warm_start_leader_error:
            detail = f"{name} as given, leader within {1e3 * err:.1f} mm of the reference" + dip(viol_raw)
            return _Candidate(raw, _cost(su, raw), "warm_start", detail), ""
        groups = [g for g in GROUPS if any(v.group == g for v in rest)]
        why += f" (as given: leader up to {err:.3g} m off the reference"
        why += f", and {', '.join(groups)} violated)" if rest else ")"
    return None, why


class _Pool:
    """The ``keep`` lowest-cost IPOPT iterates (over every solve) that nearly satisfy the transcribed rows.

    An iterate is kept if its scaled cost is below ``f_limit`` (the feasible warm start's) and no transcribed row or
    bound is violated by more than ``screen`` (the leader rows are projected afterwards). Only copies are made during
    the solve; :meth:`best` runs the full check (every row of every group, the clearance of every sample) afterwards,
    and only when a fallback is needed, so a successful solve pays nothing but the copies.
    """

    def __init__(self, keep: int, screen: float, f_limit: float) -> None:
        self.keep, self.screen, self.f_limit = keep, screen, f_limit
        self._heap: list[tuple[float, int, Array, str]] = []  # (−f, seq, x, where): the costliest kept on top
        self._seq = 0

    def offer(self, f: float, viol: float, x: Array, where: str) -> None:
        if not (f < self.f_limit and viol <= self.screen):
            return
        if len(self._heap) >= self.keep and -self._heap[0][0] <= f:
            return
        item = (-f, self._seq, np.array(x, dtype=float), where)
        self._seq += 1
        if len(self._heap) < self.keep:
            heapq.heappush(self._heap, item)
        else:
            heapq.heapreplace(self._heap, item)

    def __len__(self) -> int:
        return len(self._heap)

    def best(self, model: _Model, tol: float, J_limit: float) -> _Candidate | None:
        """The lowest-cost kept iterate that satisfies every row at ``tol`` (leader projected on the reference with
        the equality leader) and costs less than ``J_limit``; ``None`` if there is none."""
        su = model.su
        best: _Candidate | None = None
        for _, _, x, where in sorted(self._heap, key=lambda item: (-item[0], item[1])):
            Q = x.reshape(su.K + 1, su.n)
            if su.opts.leader_tolerance == 0:
                Q = _project_leader(su, Q)
            if _violations(model, model.values(Q.ravel()), Q, tol):
                continue
            J = _cost(su, Q)
            if J < J_limit and (best is None or J < best.J):
                best = _Candidate(Q, J, "best_feasible_iterate", f"its best feasible iterate ({where})")
                break  # ascending cost: the next ones cost more (up to the tiny change of the projection)
        return best


_LOG = logging.getLogger("tmr")

#: Set while an NLP runs when Ctrl-C arrives: IPOPT stops at its next iteration, then KeyboardInterrupt is raised.
_INTERRUPT = threading.Event()


@contextlib.contextmanager
def _ctrl_c_stops_ipopt() -> Iterator[None]:
    """Ctrl-C during IPOPT: casadi catches the KeyboardInterrupt raised inside the iteration callback and IPOPT goes
    on (or its caller retries), so the first Ctrl-C was lost. Here SIGINT only sets :data:`_INTERRUPT`; the callback
    then asks IPOPT to stop, and KeyboardInterrupt is raised once the solver has returned."""
    _INTERRUPT.clear()
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        yield  # a worker that ignores Ctrl-C (tmr.sweep: the parent stops it) keeps ignoring it
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: _INTERRUPT.set())
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if _INTERRUPT.is_set():
        raise KeyboardInterrupt


class _IterationCallback(ca.Callback):
    """IPOPT's per-iteration hook (casadi ``iteration_callback``): advances the progress bar and offers the iterate
    to the pool. Stops IPOPT (returns 1) only after Ctrl-C (:func:`_ctrl_c_stops_ipopt`)."""

    def __init__(self, tr: _Transcription, pool: _Pool, bar: Any, label: str) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng = int(tr.lbx.size), int(tr.size)
        self.tr, self.pool, self.bar, self.label = tr, pool, bar, label
        self.iteration = 0
        self._names = list(ca.nlpsol_out())
        self.construct("horizon_iteration", {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return str(ca.nlpsol_out(i))

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg: list[Any]) -> list[Any]:
        a = dict(zip(self._names, arg, strict=True))
        x = np.asarray(a["x"], dtype=float).ravel()
        g = np.asarray(a["g"], dtype=float).ravel()
        f = float(a["f"])
        tr = self.tr
        viol = max(
            float(np.max(tr.lbg - g, initial=0.0)),
            float(np.max(g - tr.ubg, initial=0.0)),
            float(np.max(tr.lbx - x, initial=0.0)),
            float(np.max(x - tr.ubx, initial=0.0)),
        )
        self.pool.offer(f, viol, x, f"{self.label}, iteration {self.iteration}")
        self.iteration += 1
        self.bar.update(1)
        self.bar.set_postfix_str(f"cost/warm {f:.3g}, row violation {viol:.1e}", refresh=False)
        return [1 if _INTERRUPT.is_set() else 0]


def _time_limit(time_limit: float | None) -> float:
    if time_limit is None:
        return math.inf
    if isinstance(time_limit, bool) or not isinstance(time_limit, (int, float)) or not time_limit > 0:
        raise ParameterError(f"time_limit must be a number of seconds > 0 (or None: no limit), got {time_limit!r}")
    return float(time_limit)


# ----------------------------------------------------------------------------------------------------------------
# the planner
# ----------------------------------------------------------------------------------------------------------------
def plan_horizon(
    problem: Any,
    warm_start: Plan | None,
    *,
    time_limit: float | None = None,
    progress: bool = False,
    **options: Any,
) -> Plan:
    """Plan the whole horizon at once: one NLP over q_0..q_K solved by IPOPT (``formulations/horizon.md``).

    Never worse than its warm start: the plan returned is IPOPT's optimum if it satisfies every hard-constraint row
    and costs no more than the warm start; otherwise (IPOPT stopped without a solution, the time limit was reached,
    rows left out stayed violated, or the optimum costs more) the cheapest IPOPT iterate that satisfies every row, or
    else the warm start itself if it does (see :func:`_warm_candidate`). ``diagnostics["horizon_result"]`` says which.

    Args:
        problem: a :class:`tmr.planner.Problem` (chain, environment, leader trajectory, limits, parameters); only its
            attributes are used (this module does not import the planner).
        warm_start: a plan of the same problem whose joints ``q`` start IPOPT, required — the planner passes its
            ``qp`` plan (``tmr.planner.solve(problem, "qp")[0]``); it is also the fallback if it satisfies the hard
            constraints (``warm_start.success`` and every row).
        time_limit: wall-clock limit [s] for the whole call (``None``: none; the CLI uses
            :data:`DEFAULT_TIME_LIMIT` = 60 s): each IPOPT solve gets the remaining budget as ``max_wall_time`` and no
            round or retry starts once it is spent; the overrun is at most one transcription (0.2–0.3 s on A–D), one
            IPOPT iteration and the fallback check. A run that does not reach it gives the same plan as without.
        progress: show a tqdm bar of the IPOPT iterations on stderr (only if stderr is a terminal).
        **options: fields of :class:`HorizonOptions` (weights, leader tolerance, samples, IPOPT options, …).

    Returns:
        A :class:`tmr.control.clik.Plan`, ``method="horizon"``: ``q`` the trajectory, ``qdot[k] = (q[k+1] − q[k])/Ts``,
        ``qdot[K] = 0``, ``robots`` its forward kinematics, ``success=True``; ``diagnostics`` holds
        ``horizon_result`` ("optimal", "best_feasible_iterate" or "warm_start"), ``horizon_note`` (one line: what
        IPOPT did and what was returned), ``horizon_stop`` ("converged", "ipopt_failed", "time_limit",
        "rows_left_out"), IPOPT's status and iterations, the objective returned and at the warm start, f1–f4, the
        largest row violation, the row counts, the rounds and the time split (warm-start preparation, transcription,
        solve); ``wall_time`` is the total. Run :func:`tmr.planner.check` on it for the exact (shapely) verification.

    Raises:
        ParameterError: no warm start, a warm start of the wrong shape, a bad option or time limit.
        HorizonInfeasible: the start violates a hard constraint, or neither IPOPT's optimum, nor an iterate, nor the
            warm start satisfies them; the message names the violated constraint groups with knots, times and
            amounts (also in ``.violations``).
    """
    start_time = time.perf_counter()
    if warm_start is None:
        raise ParameterError(
            "plan_horizon needs a warm start: a Plan of the same problem, e.g. the qp plan "
            "tmr.planner.solve(problem, 'qp')[0] (tmr.planner.solve(problem, 'horizon') computes and passes it)"
        )
    limit = _time_limit(time_limit)
    deadline = start_time + limit
    opts = _options(options)
    su = _Setup(problem, opts)
    env = problem.env
    bad = _check_start(su, env)
    if bad:
        raise HorizonInfeasible(
            "horizon NLP: the start configuration violates hard constraints, so no trajectory satisfies them: "
            + _describe(bad),
            bad,
            status="start_infeasible",
        )
    tol = max(10 * opts.constr_viol_tol, 1e-6)  # a row "holds" if violated by at most this (its unit)
    t0 = time.perf_counter()
    Qw, Qraw, info = _warm_start(su, warm_start)
    warm_time = time.perf_counter() - t0
    t0 = time.perf_counter()
    model = _Model(su, distance_spline(env))
    xv = Qw.ravel()
    vals = model.values(xv)
    masks = {name: model.near(name, vals[name]) for name in model.rows}
    J_warm = _cost(su, Qw)
    obj_scale = max(J_warm, 1e-6) if opts.scale_objective else 1.0
    trans_time, solve_time = time.perf_counter() - t0, 0.0
    t0 = time.perf_counter()
    warm_c, warm_why = _warm_candidate(model, warm_start, Qw, Qraw, tol)
    viol = _violations(model, vals, Qw, tol)  # at the current point (the last iterate once IPOPT ran)
    info["warm_start_time"] = warm_time + time.perf_counter() - t0
    pool = _Pool(_POOL_SIZE, _POOL_SCREEN, (warm_c.J if warm_c else math.inf) / obj_scale)
    rounds: list[dict[str, Any]] = []
    tr: _Transcription | None = None
    lam: tuple[Array, Array] | None = None
    stats: dict[str, Any] = {}
    status = ""
    stop = ""  # why the rounds ended: converged, ipopt_failed, time_limit, rows_left_out
    attempts = [("primary", {}, False)]
    if opts.retry:
        attempts.append(("retry", dict(opts.retry_ipopt), opts.leader_tolerance == 0))
    bar = tqdm(  # no total: IPOPT's iterations are counted, its rounds named ("horizon NLP, round 1 (primary solve)")
        desc="horizon NLP",
        unit="IPOPT iteration",
        bar_format="{desc}: {n_fmt} IPOPT iterations [{elapsed}{postfix}]",
        file=sys.stderr,
        leave=False,
        disable=not (progress and _is_terminal(sys.stderr)),
    )
    try:
        for rnd in range(1, opts.max_rounds + 1):
            if time.perf_counter() >= deadline:
                stop = "time_limit"
                break
            t1 = time.perf_counter()
            prev, tr = tr, _Transcription(model, masks)
            trans_time += time.perf_counter() - t1
            x_start, lam_start = xv, lam
            ok = False
            for label, extra, ls_duals in attempts:
                remaining = deadline - time.perf_counter()
                if remaining <= 0:
                    stop = "time_limit"
                    break
                if math.isfinite(limit):
                    extra = dict(extra, max_wall_time=float(remaining))
                bar.set_description_str(f"horizon NLP, round {rnd} ({label} solve)")
                t2 = time.perf_counter()
                callback = _IterationCallback(tr, pool, bar, f"round {rnd} {label}")
                solver = tr.solver(obj_scale, extra, callback)
                kwargs: dict[str, Any] = dict(x0=x_start, lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg)
                if prev is not None and lam_start is not None:  # primal–dual warm start from the previous round
                    kwargs.update(lam_x0=lam_start[0], lam_g0=tr.carry_multipliers(prev, lam_start[1]))
                elif ls_duals:
                    kwargs.update(lam_g0=_leader_multipliers(model, tr, x_start, obj_scale))
                t3 = time.perf_counter()
                _LOG.debug("horizon NLP round %d %s: IPOPT on %d rows", rnd, label, tr.size)
                with _ctrl_c_stops_ipopt():
                    sol = solver(**kwargs)
                t4 = time.perf_counter()
                trans_time += t3 - t2
                solve_time += t4 - t3
                stats = solver.stats()
                status = str(stats.get("return_status", ""))
                xv = np.asarray(sol["x"], dtype=float).ravel()
                lam = (np.asarray(sol["lam_x"], dtype=float).ravel(), np.asarray(sol["lam_g"], dtype=float).ravel())
                vals = model.values(xv)
                viol = _violations(model, vals, xv.reshape(su.K + 1, su.n), tol=tol)
                rounds.append(
                    dict(
                        round=rnd,
                        attempt=label,
                        status=status,
                        iterations=int(stats.get("iter_count", -1)),
                        rows=int(tr.size),
                        clearance_rows=int(tr.index["clearance"].size),
                        violated=len(viol),
                        transcription_time=(t2 - t1 if label == "primary" else 0.0) + t3 - t2,
                        solve_time=t4 - t3,
                        t_wall={k[7:]: round(float(v), 4) for k, v in stats.items() if k.startswith("t_wall_nlp")},
                    )
                )
                ok = status in _SUCCESS or (opts.accept_acceptable and status in _ACCEPTABLE)
                if ok:
                    break
                if status == _WALL_TIME:
                    stop = "time_limit"
                    break
            if stop:
                break
            if not ok:
                stop = "ipopt_failed"
                break
            if not viol:
                stop = "converged"
                break
            masks = {name: masks[name] | model.near(name, vals[name]) for name in model.rows}
        else:
            stop = "rows_left_out"
    finally:
        bar.close()

    # what happened, in words; then the choice: optimum, best feasible iterate, warm start
    last = rounds[-1]["round"] if rounds else 0
    tried = " and ".join(f"{r['attempt']}: {r['status']!r} after {r['iterations']} iterations"
                         for r in rounds if r["round"] == last)  # fmt: skip
    iterations = int(sum(r["iterations"] for r in rounds))
    if stop == "converged":
        what = f"IPOPT solved the NLP ({status}, {iterations} iterations in {last} round(s))"
    elif stop == "ipopt_failed":
        what = f"IPOPT stopped without a solution in round {last} ({tried})"
    elif stop == "time_limit":
        where = (
            f"in round {last} ({tried})"
            if rounds and rounds[-1]["status"] == _WALL_TIME
            else (f"after round {last} ({tried})" if rounds else "before IPOPT started")
        )
        what = f"time limit of {limit:g} s reached {where}"
    else:
        what = f"rows left out of the NLP were still violated after {opts.max_rounds} rounds of constraint generation"
    final: _Candidate | None = None
    if stop == "converged":
        Q = xv.reshape(su.K + 1, su.n)
        final = _Candidate(Q, _cost(su, Q), "optimal", "the optimum")
    if final is not None and (warm_c is None or final.J <= warm_c.J):
        chosen: _Candidate | None = final
    else:
        if final is not None:
            what = f"IPOPT's optimum ({status}, objective {final.J:.6g}) costs more than the warm start"
        chosen = pool.best(model, tol, warm_c.J if warm_c else math.inf) or warm_c
    if chosen is None:
        warm_note = f"; the warm start is no fallback: {warm_why}"
        diag = _diagnostics(model, tr, stats, xv, vals, rounds, info, J_warm, trans_time, solve_time, start_time)
        diag.update(horizon_stop=stop, time_limit=time_limit, time_limit_hit=stop == "time_limit")
        if stop == "rows_left_out":
            message = (
                f"horizon NLP: rows left out of the NLP are still violated after {opts.max_rounds} rounds of "
                "constraint generation (raise max_rounds or activation): " + _describe(viol)
            )
        else:
            lead = {"ipopt_failed": f"IPOPT found no solution in round {last} ({tried})"}.get(stop, what)
            at = "no iterate satisfies the hard constraints; violated constraints at its last iterate: "
            if not rounds:
                at = "violated constraints at the initial point (the warm start, leader projected): "
            message = f"horizon NLP: {lead}; {at}" + (
                _describe(viol) if viol else "none above tolerance (not converged: raise max_iter)"
            )
        raise HorizonInfeasible(message + warm_note, viol, status=status or stop, diagnostics=diag)

    Q = chosen.Q
    xv = Q.ravel()
    vals = model.values(xv)
    diag = _diagnostics(model, tr, stats, xv, vals, rounds, info, J_warm, trans_time, solve_time, start_time)
    versus = f"warm start {warm_c.J:.6g}" if warm_c else f"warm start {J_warm:.6g}, outside the NLP's own rows"
    returned = {"optimal": "returned the optimum"}.get(chosen.result, f"returned {chosen.detail}")
    diag.update(
        horizon_result=chosen.result,
        horizon_note=f"{what}; {returned} (objective {chosen.J:.6g} vs {versus})",
        horizon_stop=stop,
        time_limit=time_limit,
        time_limit_hit=stop == "time_limit",
        objective_warm_start_fallback=warm_c.J if warm_c else math.inf,
        warm_start_fallback=warm_c.detail if warm_c else f"none: {warm_why}",
        iterates_kept=len(pool),
    )
    return Plan(
        method="horizon",
        scenario=problem.scenario.name,
        t=su.t.copy(),
        q=Q,
        qdot=np.vstack([np.diff(Q, axis=0) / su.Ts, np.zeros((1, su.n))]),
        robots=su.robots(Q),
        base=problem.chain.base.copy(),
        reference=su.ref.copy(),
        spans=Q[:, 1::2].copy(),
        span_limits=su.limits.copy(),
        safety_radius=su.r,
        success=True,
        failure=None,
        diagnostics=diag,
        wall_time=time.perf_counter() - start_time,
        params=dict(problem.params_dict(), **{f"horizon_{k}": v for k, v in asdict(opts).items()}),
        goal=np.asarray(problem.scenario.goal, float).copy(),
    )


def _is_terminal(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _diagnostics(
    model: _Model,
    tr: _Transcription | None,
    stats: dict[str, Any],
    xv: Array,
    vals: dict[str, Array],
    rounds: list[dict[str, Any]],
    info: dict[str, Any],
    J_warm: float,
    trans_time: float,
    solve_time: float,
    start_time: float,
) -> dict[str, Any]:
    su = model.su
    f1, f2, f3, f4 = (float(v) for v in model.terms(xv))
    worst = 0.0
    for name in model.rows:
        a = model.violation(name, vals[name])
        a[:, model.fixed_columns(name)] = -np.inf
        worst = max(worst, float(a.max(initial=-np.inf)))
    clr = vals["clearance"].copy()
    return {
        "ipopt_status": str(stats.get("return_status", "")),
        "ipopt_success": bool(stats.get("success", False)),
        "ipopt_iterations": int(sum(r["iterations"] for r in rounds)),
        "objective": _weighted({"f1": f1, "f2": f2, "f3": f3, "f4": f4}, su.opts),
        "objective_warm_start": float(J_warm),
        "objective_warm_start_raw": float(info.get("objective_warm_start_raw", math.nan)),
        "f1": f1,
        "f2": f2,
        "f3": f3,
        "f4": f4,
        "constraint_violation": max(worst, 0.0),
        "variables": int(model.x.shape[0]),
        "rows": int(tr.size) if tr is not None else 0,
        "rows_full": int(sum(vals[g].shape[0] * np.count_nonzero(~model.fixed_columns(g)) for g in model.rows)),
        "clearance_rows": int(tr.index["clearance"].size) if tr is not None else 0,
        "samples_per_link": int(su.S),
        "rounds": len({r["round"] for r in rounds}),
        "round_log": rounds,
        "warm_start_method": info.get("warm_start_method", ""),
        "warm_start_success": info.get("warm_start_success"),
        "warm_start_time": float(info.get("warm_start_time", 0.0)),
        "transcription_time": float(trans_time),
        "solve_time": float(solve_time),
        "total_time": time.perf_counter() - start_time,
        "min_field_clearance": clr[:, :].min(axis=0),  # (K+1,) per knot, spline field [m]
    }
