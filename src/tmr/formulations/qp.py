"""Lexicographic QP per step with hard safety constraints (``--method qp``; math in ``formulations/qp.md``).

Each step solves one QP per priority level in the joint velocities q̇ (2N planar):

    level i:  min_q̇ Σ_t w_t ‖J_t q̇ − v_t‖² + ε‖q̇‖²
              s.t.  lb ≤ q̇ ≤ ub                               (joint speed, acceleration, tether span: JointBox)
                    lower ≤ A q̇ ≤ upper                       (every Limit: clearance, separation, robot speed, …)
                    J_j q̇ = y_j*          for every level j < i  (strict priority: higher optima are frozen)

where y_j* = J_j q̇_j* is the optimal task value of level j. The objective of a level is strictly convex in its task
value y = J q̇, so the set of level-j optima is exactly {q̇ feasible : J_j q̇ = y_j*}: freezing y_j* means no lower
level can degrade a higher one. The equalities use an orthonormal basis of the higher levels' task rows (no
redundant rows), and a level is skipped once the levels above fix every degree of freedom. Level 1 (leader
tracking) is an objective, never a constraint, so when the hard constraints forbid following the reference the
leader lags instead of breaking them; the lag is reported.

Solvers: the default ``"osqp"`` keeps one persistent ``osqp.OSQP`` workspace per level with a fixed sparsity pattern
and only updates its values each step; any qpsolvers backend (``"daqp"``, ``"proxqp"``, ``"clarabel"``, …, or
``"qpsolvers-osqp"``) is reached through :func:`qpsolvers.solve_qp` with the same matrices.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import osqp
import qpsolvers
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray

from tmr.chain import Chain
from tmr.errors import InfeasibleStep, ParameterError
from tmr.limits import JointBox, Limit
from tmr.tasks import StepContext, Task

Array = NDArray[np.float64]

#: OSQP settings (polishing is off: osqp 1.1 prints a line on stdout for every polish that finds no active set,
#: even with verbose=False).
OSQP_SETTINGS = dict(eps_abs=1e-8, eps_rel=1e-8, polishing=False, max_iter=20000, verbose=False, warm_starting=True)
#: OSQP's infinity: bounds beyond it are clipped.
OSQP_INFTY = 1e30


def solvers() -> list[str]:
    """Names accepted by ``solver=``: ``"osqp"`` (persistent workspace) and every installed qpsolvers backend."""
    return ["osqp", *(f"qpsolvers-{s}" if s == "osqp" else s for s in qpsolvers.available_solvers)]


@dataclass
class Level:
    """One priority level: weighted tasks whose rows are stacked into a least-squares objective."""

    tasks: Sequence[tuple[Task, float]]
    name: str = ""


class _Pattern:
    """A fixed sparsity pattern and the map from a dense matrix to its CSC data vector."""

    def __init__(self, mask: NDArray[np.bool_]) -> None:
        csc = sp.csc_matrix(mask.astype(float))
        csc.sort_indices()
        self.shape = mask.shape
        self.indptr, self.indices = csc.indptr.copy(), csc.indices.copy()
        cols = np.repeat(np.arange(mask.shape[1]), np.diff(self.indptr))
        self.flat = self.indices * mask.shape[1] + cols

    def data(self, dense: Array) -> Array:
        return dense.ravel()[self.flat]

    def matrix(self, dense: Array) -> sp.csc_matrix:
        data = self.data(dense)
        data = np.where(data == 0.0, 1e-30, data)  # keep every pattern entry stored at setup
        return sp.csc_matrix((data, self.indices, self.indptr), shape=self.shape)


class _OsqpLevel:
    """Persistent OSQP workspace of one level.

    The sparsity patterns of P (upper triangle) and A are taken from the first step's matrices together with the
    declared patterns (``A_mask``); the workspace is set up once and only its values are updated afterwards. If a
    later step has a nonzero outside the pattern (a task whose Jacobian pattern changed) or a different number of
    rows, the workspace is set up again with the union of the patterns.
    """

    def __init__(self, A_mask: NDArray[np.bool_]) -> None:
        self.A_mask = A_mask
        self.solver: osqp.OSQP | None = None
        self.setups = 0

    def _fits(self, P: Array, A: Array) -> bool:
        return (
            self.solver is not None
            and A.shape == self.A_pat.shape
            and not np.any(np.triu(P)[~self.P_mask])
            and not np.any(A[~self.A_full])
        )

    def solve(self, P: Array, q: Array, A: Array, lo: Array, up: Array, n_eq: int = 0) -> tuple[Array | None, str, int]:
        lo = np.maximum(lo, -OSQP_INFTY)
        up = np.minimum(up, OSQP_INFTY)
        if not self._fits(P, A):
            n = P.shape[0]
            P_mask = (np.triu(P) != 0) | np.eye(n, dtype=bool)
            A_full = np.zeros(A.shape, dtype=bool)
            rows = min(self.A_mask.shape[0], A.shape[0])
            A_full[:rows] = self.A_mask[:rows]
            A_full |= A != 0
            if self.solver is not None:  # grow, never shrink, the pattern
                P_mask |= self.P_mask
                if self.A_full.shape == A.shape:
                    A_full |= self.A_full
            self.P_mask, self.A_full = P_mask, A_full
            self.P_pat, self.A_pat = _Pattern(P_mask), _Pattern(A_full)
            self.solver = osqp.OSQP()
            self.solver.setup(self.P_pat.matrix(P), q, self.A_pat.matrix(A), lo, up, **OSQP_SETTINGS)
            self.solver.update(Px=self.P_pat.data(P), Ax=self.A_pat.data(A))
            self.setups += 1
        else:
            self.solver.update(q=q, l=lo, u=up, Px=self.P_pat.data(P), Ax=self.A_pat.data(A))
        res = self.solver.solve(raise_error=False)  # the status is checked by the caller
        status = str(res.info.status)
        x = res.x if res.x is not None and np.all(np.isfinite(res.x)) else None
        return x, status, int(res.info.iter)


class _QpsolversLevel:
    """One level solved by a qpsolvers backend with the same matrices (a fresh problem each call)."""

    #: tolerances passed to the backends whose defaults are too loose for strict priority
    OPTIONS: dict[str, dict[str, float]] = {
        "osqp": {"eps_abs": 1e-8, "eps_rel": 1e-8, "max_iter": 20000, "polishing": False},
        "proxqp": {"eps_abs": 1e-9, "eps_rel": 0.0},
    }

    def __init__(self, solver: str) -> None:
        self.solver = solver
        self.options = self.OPTIONS.get(solver, {})
        self.setups = 0

    def solve(self, P: Array, q: Array, A: Array, lo: Array, up: Array, n_eq: int = 0) -> tuple[Array | None, str, int]:
        m = A.shape[0] - n_eq
        Ai, li, ui = A[:m], lo[:m], up[:m]
        has_u, has_l = np.isfinite(ui), np.isfinite(li)
        G = np.vstack([Ai[has_u], -Ai[has_l]])
        h = np.concatenate([ui[has_u], -li[has_l]])
        Aeq = A[m:] if n_eq else None
        beq = lo[m:] if n_eq else None
        if self.solver in qpsolvers.sparse_solvers and self.solver not in qpsolvers.dense_solvers:
            P, G = sp.csc_matrix(P), sp.csc_matrix(G)
            Aeq = sp.csc_matrix(Aeq) if Aeq is not None else None
        try:
            x = qpsolvers.solve_qp(P, q, G, h, Aeq, beq, solver=self.solver, **self.options)
        except Exception as exc:  # a backend error is a failed solve, reported by the caller
            return None, f"{self.solver} error: {exc}", 0
        if x is None or not np.all(np.isfinite(x)):
            return None, "infeasible or failed", 0
        return np.asarray(x, dtype=float), "solved", 0


def orthonormal_rows(J: Array, F: Array, rtol: float = 1e-9) -> Array:
    """Orthonormal rows spanning the part of the row space of ``J`` not already spanned by the orthonormal ``F``.

    QR of the projected rows; rows whose |R_kk| fall below ``rtol`` times the largest are dependent and dropped.
    """
    G = J - (J @ F.T) @ F if F.shape[0] else J
    if G.shape[0] == 0:
        return np.zeros((0, J.shape[1]))
    Q, R, _ = scipy.linalg.qr(G.T, mode="economic", pivoting=True)  # columns of Q span the row space of G
    d = np.abs(np.diag(R))
    keep = d > rtol * max(1.0, float(d.max()) if d.size else 0.0)
    rows = Q[:, keep].T
    if F.shape[0]:  # one re-orthogonalisation pass against F (QR of nearly dependent rows)
        rows = rows - (rows @ F.T) @ F
        rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    return rows


class LexicographicQP:
    """Strict-priority stack of QPs solved every step (see the module docstring).

    Level i keeps the task values of every higher level j < i with equality rows ``F q̇ = F q̇*_{i−1}``, where F is an
    orthonormal basis of the span of the higher levels' task rows (redundant rows, e.g. span differences next to the
    spans, are removed: OSQP converges poorly on inconsistent near-duplicate equalities). The last level freezes
    nothing, and a level is skipped once the higher ones fix every degree of freedom.

    Args:
        chain: the chain.
        levels: priority levels, highest first; each a :class:`Level` of (task, weight) pairs.
        limits: hard limits shared by every level.
        box: joint box bounds (speed, acceleration, span).
        solver: ``"osqp"`` (persistent workspace) or a qpsolvers backend name (see :func:`solvers`).
        regularization: ε added to every level's Hessian [dimensionless].
        feasibility_tolerance: largest violation of a hard row accepted from a solver [row units].
        lex_tolerance: largest relative change of a frozen higher-level task value accepted from a solver.
    """

    name = "qp"

    def __init__(
        self,
        chain: Chain,
        levels: Sequence[Level],
        limits: Sequence[Limit],
        box: JointBox,
        *,
        solver: str = "osqp",
        regularization: float = 1e-9,
        feasibility_tolerance: float = 1e-5,
        lex_tolerance: float = 1e-6,
    ) -> None:
        if not levels or any(not level.tasks for level in levels):
            raise ParameterError("the QP stack needs at least one level, and every level at least one task")
        if solver not in solvers():
            raise ParameterError(f"unknown QP solver {solver!r}; available: {', '.join(solvers())}")
        self.chain, self.levels, self.limits, self.box = chain, list(levels), list(limits), box
        self.solver = solver
        self.eps, self.feas_tol, self.lex_tol = (
            float(regularization),
            float(feasibility_tolerance),
            float(lex_tolerance),
        )
        self.widen = 0.1 * self.feas_tol / max(1, len(self.levels))
        self._workspaces: list[_OsqpLevel | _QpsolversLevel] | None = None

    def reset(self) -> None:
        self._workspaces = None
        for level in self.levels:
            for task, _ in level.tasks:
                task.reset()
        for lim in self.limits:
            lim.reset()

    # ------------------------------------------------------------------ assembly
    def _objective(self, level: Level, ctx: StepContext) -> tuple[Array, Array, Array, Array]:
        """(P, q, J, v) of a level: P = Σ w JᵀJ + εI, q = −Σ w Jᵀv; J, v stack the task rows."""
        n = self.chain.dof
        P = self.eps * np.eye(n)
        c = np.zeros(n)
        Js, vs = [], []
        for task, w in level.tasks:
            J, v = task.compute(ctx)
            P += w * (J.T @ J)
            c -= w * (J.T @ v)
            Js.append(J)
            vs.append(v)
        return P, c, np.vstack(Js), np.concatenate(vs)

    def _build_workspaces(self, hard_mask: NDArray[np.bool_]) -> None:
        n = self.chain.dof
        base_mask = np.vstack([np.eye(n, dtype=bool), hard_mask])  # box rows, then the limits' declared patterns
        ws: list[_OsqpLevel | _QpsolversLevel] = []
        for _ in self.levels:
            if self.solver == "osqp":
                ws.append(_OsqpLevel(base_mask))
            else:
                ws.append(_QpsolversLevel(self.solver.removeprefix("qpsolvers-")))
        self._workspaces = ws

    # ------------------------------------------------------------------ one step
    def step(self, ctx: StepContext) -> tuple[Array, dict[str, float]]:
        """Joint velocities for the step in ``ctx`` (strict priority over the levels) and diagnostics.

        If the limits have no common solution, the step is solved again without the relaxable (comfort) limits —
        the acceleration bounds — and ``diagnostics["relaxed"]`` is 1; if the safety limits alone have no solution,
        :class:`InfeasibleStep` is raised.
        """
        t0 = time.perf_counter()
        n = self.chain.dof
        rows = [lim.compute(ctx) for lim in self.limits]
        H = np.vstack([r.A for r in rows]) if rows else np.zeros((0, n))
        if self._workspaces is None:
            hard_mask = (
                np.vstack([lim.pattern(self.chain) for lim in self.limits]) if self.limits else np.zeros((0, n), bool)
            )
            if hard_mask.shape != H.shape or np.any(H[~hard_mask] != 0):
                raise ParameterError("limit rows do not match their declared sparsity patterns")
            self._build_workspaces(hard_mask)
        objectives: dict[int, tuple[Array, Array, Array, Array]] = {}  # built on first use: skipped levels cost nothing
        try:
            x, lag, iters = self._solve_levels(ctx, H, rows, objectives, relax=False)
            relaxed = 0.0
        except InfeasibleStep:
            x, lag, iters = self._solve_levels(ctx, H, rows, objectives, relax=True)
            relaxed = 1.0
        diag = {
            "leader_residual": lag,
            "solver_iterations": float(iters),
            "relaxed": relaxed,
            "step_time": time.perf_counter() - t0,
        }
        return x, diag

    def _solve_levels(
        self, ctx: StepContext, H: Array, rows: list, objectives: dict, relax: bool
    ) -> tuple[Array, float, int]:
        """Solve the levels in order; each freezes an orthonormal basis F of its task rows' span: F q̇ = F q̇*."""
        assert self._workspaces is not None
        n = self.chain.dof
        lb, ub = self.box.compute(ctx, relax=relax)
        drop = [relax and lim.relaxable for lim in self.limits]
        h_lo = np.concatenate(
            [np.full(r.lower.size, -np.inf) if d else r.lower for r, d in zip(rows, drop, strict=True)]
        )
        h_up = np.concatenate(
            [np.full(r.upper.size, np.inf) if d else r.upper for r, d in zip(rows, drop, strict=True)]
        )
        A0 = np.vstack([np.eye(n), H])
        lo0, up0 = np.concatenate([lb, h_lo]), np.concatenate([ub, h_up])
        F = np.zeros((0, n))
        y = np.zeros(0)
        x: Array | None = None
        iters = 0
        lag = 0.0
        last = len(self.levels) - 1
        for i, level in enumerate(self.levels):
            if F.shape[0] >= n:
                break  # the higher levels fix every degree of freedom
            if i not in objectives:
                objectives[i] = self._objective(level, ctx)
            P, c, J, v = objectives[i]
            # lower levels start from the higher optimum, which sits on active rows up to the solver accuracy: a
            # small widening (growing with the level, as violations may accumulate) keeps that optimum feasible
            widen = self.widen * i
            A = np.vstack([A0, F])
            lo = np.concatenate([lo0 - widen, y])
            up = np.concatenate([up0 + widen, y])
            z, status, it = self._workspaces[i].solve(P, c, A, lo, up, n_eq=F.shape[0])
            iters += it
            if z is None or not self._feasible(A0, lo0, up0, z) or not self._kept(F, y, z):
                if i == 0:
                    raise InfeasibleStep(self._explain(ctx, status, lb, ub, rows, relax))
                break  # a lower level failed numerically: keep the higher levels' optimum (strict priority holds)
            x = z
            if i == 0:
                lag = float(np.linalg.norm(J @ x - v))  # > 0 when the limits hold the leader back
            if i < last:
                Fn = orthonormal_rows(J, F)
                F, y = np.vstack([F, Fn]), np.concatenate([y, Fn @ x])
        assert x is not None
        return x, lag, iters

    def _kept(self, F: Array, y: Array, x: Array) -> bool:
        """Whether x keeps the frozen task values of the higher levels (strict priority) to solver accuracy."""
        return bool(np.all(np.abs(F @ x - y) <= self.lex_tol * (1.0 + np.abs(y))))

    def _feasible(self, A: Array, lo: Array, up: Array, x: Array) -> bool:
        r = A @ x
        return bool(np.all(r >= lo - self.feas_tol) and np.all(r <= up + self.feas_tol))

    def _explain(self, ctx: StepContext, status: str, lb: Array, ub: Array, rows: list, relax: bool) -> str:
        """A message naming the step, the solver status and the limits that cannot be met by the closest motion."""
        x = np.clip(ctx.qdot_prev, lb, ub)
        worst = []
        for lim, r in zip(self.limits, rows, strict=True):
            if relax and lim.relaxable:
                continue
            val = r.A @ x
            gap = np.maximum(r.lower - val, val - r.upper)
            if gap.size and np.max(gap) > self.feas_tol:
                worst.append(f"{lim.name} (rows violated by up to {np.max(gap):.3g})")
        names = ", ".join(worst) or "the joint box bounds together with the limits"
        return (
            f"step {ctx.k} (t = {ctx.k * ctx.Ts:.2f} s): the hard constraints have no common solution "
            f"(solver status: {status}{', even without the acceleration bounds' if relax else ''}); tightest: {names}. "
            "Relax the speed bounds or the clearance margin, or give the leader a path farther from the obstacles."
        )
