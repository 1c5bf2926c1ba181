"""Tension distribution: cable tensions t with W t = f inside the (tipping-tightened) bounds (Rasheed 2019 eq. 2, 4, 6).

* :func:`closed_form` — m = n + 1 (MoPICK: 4 cables, 3 dof): t = W⁺f + λ n with n spanning the null space of W; the
  bounds give an interval of λ and the minimum 2-norm solution clamps λ = 0 into it (t_p = W⁺f ⊥ n). Batched numpy.
  Needs W of full rank (rank-deficient poses are reported infeasible; use :class:`TensionProblem` there).
* :class:`TensionProblem` — cvxpy, any m and any constraint rows A t ≤ b: minimum 2-norm (QP), minimum max tension
  (LP) or minimum 1-norm (LP). DPP with Parameters: compiled once, re-solved per pose.
* :func:`wrench_feasible` — the feasibility LP (is f in the AWS of eq. 7?).
* :func:`min_norm_qp` — minimum 2-norm tensions, a dense active-set QP through qpsolvers (DAQP): any m.
* :func:`min_max_lp` — minimum largest tension, min s s.t. t_k ≤ s, W t = f, lo ≤ t ≤ hi (scipy linprog, HiGHS).
* :func:`distribute` — one of these (``"closed-form"``, ``"qp"``, ``"lp"``) over a batch of poses, NaN where
  infeasible; the choice CASPR users know (closed form, quadratic programming, linear programming).

Infeasible wrenches raise :class:`~tmr.mcdpr.errors.InfeasibleWrench`. See ``formulations/tension.md``.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.mcdpr.errors import InfeasibleWrench, McdprError, ParameterError

__all__ = [
    "METHODS",
    "ClosedForm",
    "TensionProblem",
    "closed_form",
    "closed_form_batch",
    "distribute",
    "min_max_lp",
    "min_norm_qp",
    "wrench_feasible",
]

Objective = Literal["2norm", "maxnorm", "1norm"]


class ClosedForm(NamedTuple):
    """Null-space tension distribution for m = n + 1 (batched shapes ``...``).

    t: (..., m) minimum 2-norm tensions in the bounds [N] (NaN where infeasible). feasible: (...) bool.
    lam_lo, lam_hi: (...) interval of the null-space coordinate λ allowed by the bounds [N].
    particular: (..., m) W⁺ f [N]. null: (..., m) unit null vector of W.
    """

    t: NDArray[np.float64]
    feasible: NDArray[np.bool_]
    lam_lo: NDArray[np.float64]
    lam_hi: NDArray[np.float64]
    particular: NDArray[np.float64]
    null: NDArray[np.float64]


def closed_form_batch(W: ArrayLike, f: ArrayLike, lo: ArrayLike, hi: ArrayLike, tol: float = 1e-9) -> ClosedForm:
    """Closed-form tension distribution along the null space of W (m = n + 1), batched over poses.

    ``W`` (..., n, n+1), ``f`` (..., n) [N], ``lo``/``hi`` (..., m) [N]. W t = f has the solutions
    t = W⁺f + λ n (n = unit null vector); lo ≤ t ≤ hi gives λ ∈ [λ_lo, λ_hi] and the minimum-norm feasible tension is
    λ* = clip(0, λ_lo, λ_hi). The closed form needs W of full rank n (a one-dimensional null space): a pose is
    reported infeasible when the interval is empty, when f is not in the range of W (residual > tol·(1 + ‖f‖)) and
    whenever W is rank-deficient (smallest singular value ≤ 1e-12), even if some tensions would produce f there —
    fall back to :class:`TensionProblem` or :func:`wrench_feasible` for such poses.
    """
    W = np.asarray(W, dtype=float)
    f = np.asarray(f, dtype=float)
    n, m = W.shape[-2:]
    if m != n + 1:
        raise ParameterError(f"closed form needs m = n + 1 cables, got W of shape {W.shape}")
    U, s, Vt = np.linalg.svd(W)
    null = Vt[..., -1, :]
    pinv = np.linalg.pinv(W)
    tp = np.einsum("...ij,...j->...i", pinv, f)
    resid = np.linalg.norm(np.einsum("...ij,...j->...i", W, tp) - f, axis=-1)
    lo = np.broadcast_to(np.asarray(lo, dtype=float), tp.shape)
    hi = np.broadcast_to(np.asarray(hi, dtype=float), tp.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = (lo - tp) / null
        r2 = (hi - tp) / null
    pos = null > 1e-14
    neg = null < -1e-14
    zero = ~(pos | neg)
    lam_lo = np.max(np.where(pos, r1, np.where(neg, r2, -np.inf)), axis=-1)
    lam_hi = np.min(np.where(pos, r2, np.where(neg, r1, np.inf)), axis=-1)
    zero_ok = np.all(~zero | ((tp >= lo - tol) & (tp <= hi + tol)), axis=-1)
    scale = 1.0 + np.linalg.norm(f, axis=-1)
    feasible = (lam_lo <= lam_hi + tol) & zero_ok & (resid <= tol * scale) & (s[..., -1] > 1e-12)
    lam = np.clip(0.0, lam_lo, np.maximum(lam_lo, lam_hi))
    t = tp + lam[..., None] * null
    t = np.where(feasible[..., None], np.clip(t, lo, hi), np.nan)
    return ClosedForm(t, feasible, lam_lo, lam_hi, tp, null)


def closed_form(W: ArrayLike, f: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> NDArray[np.float64]:
    """Minimum 2-norm tensions (m,) [N] of one pose by the null-space closed form; raises InfeasibleWrench."""
    res = closed_form_batch(W, f, lo, hi)
    s = np.linalg.svd(np.asarray(W, dtype=float), compute_uv=False)
    if s[-1] <= 1e-12:
        raise InfeasibleWrench(
            f"W is rank-deficient (rank {int(np.sum(s > 1e-12))} < {len(s)}): the null-space closed form needs full "
            "rank; use TensionProblem (QP/LP) for this pose"
        )
    if not bool(res.feasible):
        raise InfeasibleWrench(
            f"wrench f = {np.round(np.asarray(f, float), 6).tolist()} N cannot be produced with tensions in "
            f"[{np.round(np.asarray(lo, float), 4).tolist()}, {np.round(np.asarray(hi, float), 4).tolist()}] N: the "
            f"null-space interval is [{float(res.lam_lo):.6g}, {float(res.lam_hi):.6g}]"
        )
    return res.t


class TensionProblem:
    """cvxpy tension distribution W t = f, A t ≤ b with a chosen objective (DPP; compiled on first solve).

    ``n`` wrench dimension, ``m`` cables, ``r`` constraint rows (e.g. from :func:`tmr.mcdpr.tipping.constraint_rows`).
    ``objective``: ``"2norm"`` min ‖t‖₂² (QP), ``"maxnorm"`` min max_k t_k (LP), ``"1norm"`` min Σ|t_k| (LP).
    """

    def __init__(self, n: int, m: int, r: int, objective: Objective = "2norm", solver: str | None = None) -> None:
        import cvxpy as cp  # lazily: a 1-5 s import most runs do not need

        self.t = cp.Variable(m)
        self.W = cp.Parameter((n, m))
        self.f = cp.Parameter(n)
        self.A = cp.Parameter((r, m))
        self.b = cp.Parameter(r)
        cons = [self.W @ self.t == self.f, self.A @ self.t <= self.b]
        if objective == "2norm":
            obj = cp.Minimize(cp.sum_squares(self.t))
            default = "CLARABEL"
        elif objective == "maxnorm":
            obj = cp.Minimize(cp.max(self.t))
            default = "HIGHS"
        elif objective == "1norm":
            obj = cp.Minimize(cp.norm1(self.t))
            default = "HIGHS"
        else:
            raise ParameterError(f"objective must be '2norm', 'maxnorm' or '1norm', got {objective!r}")
        self.objective = objective
        self.solver = solver or default
        self.problem = cp.Problem(obj, cons)
        if not self.problem.is_dpp():  # pragma: no cover - structural guarantee
            raise McdprError("tension problem is not DPP")

    def solve(self, W: ArrayLike, f: ArrayLike, A: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
        """Tensions (m,) [N]; raises InfeasibleWrench when no tension satisfies W t = f and A t ≤ b."""
        import cvxpy as cp  # lazily: a 1-5 s import most runs do not need

        self.W.value = np.asarray(W, dtype=float)
        self.f.value = np.asarray(f, dtype=float)
        self.A.value = np.asarray(A, dtype=float)
        self.b.value = np.asarray(b, dtype=float)
        try:
            self.problem.solve(solver=self.solver)
        except cp.error.SolverError as exc:
            raise InfeasibleWrench(f"tension solver {self.solver} failed: {exc}") from exc
        if self.problem.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
            raise InfeasibleWrench(
                f"wrench f = {np.round(self.f.value, 6).tolist()} N is outside the available wrench set: no tensions "
                f"satisfy W t = f within the bounds and tipping limits ({self.objective}, {self.solver})"
            )
        if self.problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            raise InfeasibleWrench(f"tension solver {self.solver} returned status {self.problem.status}")
        return np.asarray(self.t.value, dtype=float)


def wrench_feasible(W: ArrayLike, f: ArrayLike, A: ArrayLike, b: ArrayLike) -> bool:
    """Feasibility LP: is there t with W t = f and A t ≤ b? (f in the AWS, Rasheed 2019 eq. 7)."""
    W = np.asarray(W, dtype=float)
    A = np.asarray(A, dtype=float)
    key = (W.shape[0], W.shape[1], A.shape[0])
    prob = _FEAS.get(key)
    if prob is None:
        prob = _FEAS[key] = TensionProblem(*key, objective="1norm")
    try:
        prob.solve(W, f, A, b)
    except InfeasibleWrench:
        return False
    return True


_FEAS: dict[tuple[int, int, int], TensionProblem] = {}


#: Tension-distribution methods of :func:`distribute`.
METHODS = ("closed-form", "qp", "lp")


def min_norm_qp(W: ArrayLike, f: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> NDArray[np.float64]:
    """Minimum 2-norm tensions (m,) [N]: min ½‖t‖² s.t. W t = f, lo ≤ t ≤ hi (Rasheed 2019 eq. 2, 4, 6), solved by
    qpsolvers with the dense active-set solver DAQP; raises InfeasibleWrench when no tension fits."""
    import qpsolvers

    W = np.asarray(W, dtype=float)
    m = W.shape[1]
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    if np.any(lo > hi):
        raise InfeasibleWrench(f"empty tension box: lo {np.round(lo, 4).tolist()} > hi {np.round(hi, 4).tolist()} N")
    t = qpsolvers.solve_qp(np.eye(m), np.zeros(m), A=W, b=np.asarray(f, dtype=float), lb=lo, ub=hi, solver="daqp")
    if t is None:
        raise InfeasibleWrench(
            f"wrench f = {np.round(np.asarray(f, float), 6).tolist()} N cannot be produced with tensions in "
            f"[{np.round(lo, 4).tolist()}, {np.round(hi, 4).tolist()}] N (QP infeasible, DAQP)"
        )
    return np.clip(np.asarray(t, dtype=float), lo, hi)


def min_max_lp(W: ArrayLike, f: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> NDArray[np.float64]:
    """Tensions (m,) [N] minimising the largest tension: min s s.t. t_k − s ≤ 0, W t = f, lo ≤ t ≤ hi (scipy
    ``linprog``, HiGHS); among the minimisers HiGHS returns a vertex. Raises InfeasibleWrench when infeasible."""
    from scipy.optimize import linprog

    W = np.asarray(W, dtype=float)
    n, m = W.shape
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    if np.any(lo > hi):
        raise InfeasibleWrench(f"empty tension box: lo {np.round(lo, 4).tolist()} > hi {np.round(hi, 4).tolist()} N")
    c = np.r_[np.zeros(m), 1.0]
    A_ub = np.hstack([np.eye(m), -np.ones((m, 1))])
    A_eq = np.hstack([W, np.zeros((n, 1))])
    bounds = [(float(a), float(b)) for a, b in zip(lo, hi, strict=True)] + [(None, None)]
    res = linprog(c, A_ub=A_ub, b_ub=np.zeros(m), A_eq=A_eq, b_eq=np.asarray(f, float), bounds=bounds, method="highs")
    if res.status != 0:
        raise InfeasibleWrench(
            f"wrench f = {np.round(np.asarray(f, float), 6).tolist()} N cannot be produced with tensions in "
            f"[{np.round(lo, 4).tolist()}, {np.round(hi, 4).tolist()}] N (min-max LP: {res.message})"
        )
    return np.clip(res.x[:m], lo, hi)


def distribute(method: str, W: ArrayLike, f: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> NDArray[np.float64]:
    """Tensions (T, m) [N] for a batch of poses W (T, n, m), bounds lo/hi (T, m) and one wrench f (n,) by
    ``method`` (:data:`METHODS`): ``"closed-form"`` (null space, m = n + 1, minimum 2-norm; poses it rejects fall
    back to the QP), ``"qp"`` (:func:`min_norm_qp`) or ``"lp"`` (:func:`min_max_lp`). NaN rows where infeasible."""
    if method not in METHODS:
        raise ParameterError(f"tension method must be one of {', '.join(METHODS)}, got {method!r}")
    W = np.asarray(W, dtype=float)
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    T, n, m = W.shape
    t = np.full((T, m), np.nan)
    if method == "closed-form" and m == n + 1:
        t = closed_form_batch(W, f, lo, hi).t
    solve = min_max_lp if method == "lp" else min_norm_qp
    for i in np.flatnonzero(~np.all(np.isfinite(t), axis=1)):
        try:
            t[i] = solve(W[i], f, lo[i], hi[i])
        except InfeasibleWrench:
            t[i] = np.nan
    return t
