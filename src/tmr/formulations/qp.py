"""Lexicographic QP per step with hard safety constraints (``--method qp``; math in ``formulations/qp.md``).

Each step solves one QP per priority level in the joint velocities q̇ (2N planar):

    level i:  min_q̇ Σ_t w_t ‖J_t q̇ − v_t‖² + ε‖q̇‖²
              s.t.  lb ≤ q̇ ≤ ub                               (joint speed, acceleration, tether span: JointBox)
                    lower ≤ A q̇ ≤ upper                       (every Limit: clearance, separation, robot speed, …)
                    J_j q̇ = y_j*          for every level j < i  (strict priority: higher optima are frozen)

where y_j* = J_j q̇_j* is the optimal task value of level j. The objective of a level is strictly convex in its task
value y = J q̇, so the set of level-j optima is exactly {q̇ feasible : J_j q̇ = y_j*}: freezing y_j* means no lower
level can degrade a higher one. The equalities are eliminated by solving level i in the null space of the higher
levels' rows, q̇ = q̇_{i−1}* + Z z. Level 1 (leader tracking) is an objective, never a constraint, so when the
hard constraints forbid following the reference the leader lags instead of breaking them; the lag is reported.

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
    """Persistent OSQP workspace of one level; rebuilt only if the level's dimension changes (rank change)."""

    def __init__(self, A_mask: NDArray[np.bool_]) -> None:
        self.A_mask = A_mask
        self.solver: osqp.OSQP | None = None
        self.shape: tuple[int, int] = (-1, -1)

    def solve(self, P: Array, q: Array, A: Array, lo: Array, up: Array) -> tuple[Array | None, str, int]:
        k = P.shape[0]
        if self.solver is None or self.shape != A.shape:
            mask = self.A_mask if self.A_mask.shape == A.shape else np.ones(A.shape, dtype=bool)
            self.P_pat, self.A_pat = _Pattern(np.triu(np.ones((k, k), dtype=bool))), _Pattern(mask)
            self.solver = osqp.OSQP()
            self.solver.setup(self.P_pat.matrix(P), q, self.A_pat.matrix(A), lo, up, **OSQP_SETTINGS)
            self.solver.update(Px=self.P_pat.data(P), Ax=self.A_pat.data(A))
            self.shape = A.shape
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

    def solve(self, P: Array, q: Array, A: Array, lo: Array, up: Array) -> tuple[Array | None, str, int]:
        has_u, has_l = np.isfinite(up), np.isfinite(lo)
        G = np.vstack([A[has_u], -A[has_l]])
        h = np.concatenate([up[has_u], -lo[has_l]])
        if self.solver in qpsolvers.sparse_solvers and self.solver not in qpsolvers.dense_solvers:
            P, G = sp.csc_matrix(P), sp.csc_matrix(G)
        try:
            x = qpsolvers.solve_qp(P, q, G, h, solver=self.solver, **self.options)
        except Exception as exc:  # a backend error is a failed solve, reported by the caller
            return None, f"{self.solver} error: {exc}", 0
        if x is None or not np.all(np.isfinite(x)):
            return None, "infeasible or failed", 0
        return np.asarray(x, dtype=float), "solved", 0


def null_space(M: Array, rtol: float = 1e-9) -> Array:
    """Orthonormal basis (columns) of the null space of ``M`` (SVD with a relative rank tolerance)."""
    k = M.shape[1]
    if M.shape[0] == 0:
        return np.eye(k)
    _, S, Vt = np.linalg.svd(M, full_matrices=True)
    rank = int(np.count_nonzero(S > rtol * max(1.0, S[0] if S.size else 0.0)))
    return Vt[rank:].T


class LexicographicQP:
    """Strict-priority stack of QPs solved every step (see the module docstring).

    Level i is solved in the null space of every higher level's task rows: ``q̇ = x_{i−1} + Z_{i−1} z`` with
    ``J_j Z_{i−1} = 0`` for all j < i, so the higher levels' task values are kept exactly (strict priority) and each
    QP has only inequality rows, which OSQP solves quickly.

    Args:
        chain: the chain.
        levels: priority levels, highest first; each a :class:`Level` of (task, weight) pairs.
        limits: hard limits shared by every level.
        box: joint box bounds (speed, acceleration, span).
        solver: ``"osqp"`` (persistent workspace) or a qpsolvers backend name (see :func:`solvers`).
        regularization: ε added to every level's Hessian [dimensionless].
        feasibility_tolerance: largest violation of a hard row accepted from a solver [row units].
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
    ) -> None:
        if not levels or any(not level.tasks for level in levels):
            raise ParameterError("the QP stack needs at least one level, and every level at least one task")
        if solver not in solvers():
            raise ParameterError(f"unknown QP solver {solver!r}; available: {', '.join(solvers())}")
        self.chain, self.levels, self.limits, self.box = chain, list(levels), list(limits), box
        self.solver = solver
        self.eps, self.feas_tol = float(regularization), float(feasibility_tolerance)
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
        first = np.vstack([np.eye(n, dtype=bool), hard_mask])  # level 1 keeps the sparse pattern of the rows
        ws: list[_OsqpLevel | _QpsolversLevel] = []
        for i in range(len(self.levels)):
            if self.solver == "osqp":
                ws.append(_OsqpLevel(first if i == 0 else np.ones((first.shape[0], 0), dtype=bool)))
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
        objectives = [self._objective(level, ctx) for level in self.levels]
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
        self, ctx: StepContext, H: Array, rows: list, objectives: list, relax: bool
    ) -> tuple[Array, float, int]:
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
        x = np.zeros(n)
        Z = np.eye(n)
        iters = 0
        lag = 0.0
        for i, (P, c, J, v) in enumerate(objectives):
            k = Z.shape[1]
            if k == 0:
                break  # the higher levels use every degree of freedom
            Az = A0 if i == 0 else A0 @ Z
            base = A0 @ x
            # lower levels start from the higher optimum, which sits on active rows up to the solver accuracy: a
            # small widening keeps z = 0 feasible so the solver is not asked for more accuracy than it delivered
            widen = self.widen * i  # level i may inherit level i−1's widening: widen cumulatively
            z, status, it = self._workspaces[i].solve(
                Z.T @ P @ Z, Z.T @ (P @ x + c), Az, lo0 - base - widen, up0 - base + widen
            )
            iters += it
            cand = x + Z @ z if z is not None else None
            if cand is None or not self._feasible(A0, lo0, up0, cand):
                if i == 0:
                    raise InfeasibleStep(self._explain(ctx, status, lb, ub, rows, relax))
                break  # a lower level failed numerically: keep the higher levels' optimum (strict priority holds)
            x = cand
            if i == 0:
                lag = float(np.linalg.norm(J @ x - v))  # > 0 when the limits hold the leader back
            Z = Z @ null_space(J @ Z)
        return x, lag, iters

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
