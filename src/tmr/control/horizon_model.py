"""The transcription of the whole-horizon NLP (``--method horizon``; math in ``formulations/horizon.md``): its
options and errors, the objective and the distance spline, the problem's numbers and its CasADi expressions over the
whole horizon, IPOPT's options and the warm start projected onto the leader's path. Solved by
:func:`tmr.control.horizon.plan_horizon`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, NamedTuple

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from tmr.control.clik import Plan
from tmr.errors import InfeasibleStep, ParameterError

Array = NDArray[np.float64]


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
