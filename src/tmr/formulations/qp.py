"""Lexicographic QP per step with hard safety constraints (``--method qp``; math in ``formulations/qp.md``).

Each step solves a strict priority stack of QPs in x = [v, q̇]: the robot velocities v = [ṗ1, …, ṗN] (2N, planar)
and the joint rates q̇, tied by q̇ = T v (:mod:`tmr.velocity`, T banded). Rows on robots and tether points are local
in v, joint-space rows (tether regulation, smoothness, energy, the joint box) are simplest on q̇, and every task and
limit declares which one it writes (``space``):

    level i:  min_x Σ_t w_t ‖J_t x − t_t‖² + ε‖x‖²
              s.t.  q̇ − T v = 0,   lb ≤ q̇ ≤ ub              (coupling; joint speed, acceleration, span: JointBox)
                    lower ≤ A x ≤ upper                       (every Limit: clearance, separation, robot speed, …)
                    F x = F x*                               (strict priority: the higher levels' optima are frozen)

F is an orthonormal basis, on v, of the higher levels' task rows and F x* their optimal values: a level's objective
is strictly convex in its task value, so freezing it means no lower level can degrade a higher one. A level holding a
full-rank task (``Task.full_rank``) has a unique optimum, and the levels below it are skipped. The returned joint
rates are q̇ = T v* (exact).

**Optimistic first level.** Level 1 (leader tracking) usually reaches zero residual. So each step first solves level
2 with level 1's rows as equalities at their targets (``J_1 x = t_1``): if that QP is feasible its solution is exactly
the lexicographic one (level 1's optimum is then the zero residual), and one QP replaces two. Only if it is
infeasible (the limits hold the leader back) is level 1 solved on its own, as an objective: the leader lags instead of
breaking a hard limit, and the lag is reported. After a lagging step the next one starts with level 1 directly.

**Solvers.** With the default ``"osqp"`` each level is first solved from the previous step's active set by one KKT
solve, accepted only if the KKT conditions verify (:mod:`tmr.formulations.activeset`); otherwise one persistent
``osqp.OSQP`` workspace per level (fixed sparsity pattern, values updated each step) solves it, and DAQP settles a
level OSQP leaves at its iteration limit. Any qpsolvers backend (``"daqp"``, ``"proxqp"``, ``"clarabel"``, …, or
``"qpsolvers-osqp"``) is reached through :func:`qpsolvers.solve_qp` with the same problem. Every backend gets the
condensed least squares P = Σ w JᵀJ + εI, q = −Σ w Jᵀt.
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
from tmr.formulations.activeset import WarmActiveSet, active_set
from tmr.limits import JointBox, Limit
from tmr.tasks import StepContext, Task
from tmr.velocity import robot_pattern

Array = NDArray[np.float64]

#: OSQP settings (polishing is off: osqp 1.1 prints a line on stdout for every polish that finds no active set,
#: even with verbose=False).
OSQP_SETTINGS = dict(eps_abs=1e-8, eps_rel=1e-8, polishing=False, max_iter=20000, verbose=False, warm_starting=True)
#: Backend that settles a level OSQP leaves unsolved (iteration limit): dense active set, exact.
FALLBACK_SOLVER = "daqp"
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
    """A fixed sparsity pattern of a dense (m, n) block and the map from the block to its CSC data vector."""

    def __init__(self, mask: NDArray[np.bool_]) -> None:
        csc = sp.csc_matrix(mask.astype(float))
        csc.sort_indices()
        self.shape = mask.shape
        self.indptr, self.indices = csc.indptr.copy(), csc.indices.copy()
        cols = np.repeat(np.arange(mask.shape[1]), np.diff(self.indptr))
        self.flat = self.indices * mask.shape[1] + cols
        self.mask = mask

    def data(self, dense: Array) -> Array:
        return dense.ravel()[self.flat]

    def matrix(self, dense: Array) -> sp.csc_matrix:
        data = self.data(dense)
        data = np.where(data == 0.0, 1e-30, data)  # keep every pattern entry stored at setup
        return sp.csc_matrix((data, self.indices, self.indptr), shape=self.shape)


class _OsqpLevel:
    """Persistent OSQP workspace of one level (see the module docstring for the problem it holds).

    C (dense, (m, n)) stacks the hard and frozen rows on v, then the level's m_r weighted task rows Jw with targets
    tw (given as ``lo = up`` of those rows). Condensed form: ``P = JwᵀJw + εI`` (upper triangle), ``q = −Jwᵀ tw``,
    ``A`` = the hard and frozen rows. The sparsity of A is the declared pattern of the hard rows together with the
    nonzeros of the first step, that of P the nonzeros of the first step; the workspace is set up once and only its
    values are updated afterwards. A later step with a nonzero outside the pattern (a pair of robots that was never
    close before, a task whose rows changed shape) sets it up again with the union of the patterns — it never
    shrinks. For long chains (``n > sparse_above``) JwᵀJw is formed with scipy.sparse (it is banded).
    """

    sparse_above = 80

    def __init__(self, eps: float, warm: WarmActiveSet | None = None) -> None:
        self.eps = float(eps)
        self.solver: osqp.OSQP | None = None
        self.setups = 0
        self.warm = warm
        self.guess: NDArray[np.int8] | None = None
        self.warm_hits = 0
        self._P: Array | sp.csr_matrix | None = None
        self._P_of: Array | None = None
        self.A_pat: _Pattern | None = None
        self.J_pat: _Pattern | None = None
        self.P_pat: _Pattern | None = None

    def _hessian(self, Jw: Array, tw: Array) -> tuple[Array | sp.csr_matrix, Array]:
        """P = JwᵀJw + εI (scipy.sparse for long chains: it is banded) and q = −Jwᵀ tw."""
        if Jw is not self._P_of:  # the same rows as last step (constant task rows): the same P
            n = Jw.shape[1]
            if n > self.sparse_above:
                Js = sp.csr_matrix(Jw)
                P = (Js.T @ Js + sp.identity(n, format="csr") * self.eps).tocsr()
            else:
                P = Jw.T @ Jw
                P.flat[:: n + 1] += self.eps
            self._P, self._P_of = P, Jw
        return self._P, -(tw @ Jw)

    def _setup(
        self, P: Array, q: Array, A: Array, Jw: Array, lo: Array, up: Array, declared: NDArray[np.bool_] | None
    ) -> None:
        n = A.shape[1]
        A_mask, J_mask = A != 0, Jw != 0
        if declared is not None:
            A_mask[: declared.shape[0]] |= declared
        if self.A_pat is not None and self.A_pat.shape == A.shape and self.J_pat.shape == Jw.shape:
            A_mask |= self.A_pat.mask  # grow, never shrink
            J_mask |= self.J_pat.mask
        Ji = J_mask.astype(float)
        P_mask = np.triu(Ji.T @ Ji != 0) | np.eye(n, dtype=bool)  # the structure of JwᵀJw covers every P
        self.A_pat, self.J_pat, self.P_pat = _Pattern(A_mask), _Pattern(J_mask), _Pattern(P_mask)
        self.Ax, self.Px, self.Jx = self.A_pat.data(A), self.P_pat.data(P), self.J_pat.data(Jw)
        self.solver = osqp.OSQP()
        self.solver.setup(self.P_pat.matrix(P), q, self.A_pat.matrix(A), lo, up, **OSQP_SETTINGS)
        self.solver.update(Px=self.Px, Ax=self.Ax)
        self.core = getattr(self.solver, "_solver", None)  # the extension object: no per-call Python overhead
        self.setups += 1

    @staticmethod
    def _gather(pat: _Pattern, dense: Array, out: Array) -> bool:
        """Copy the pattern entries of ``dense`` into ``out``; False if ``dense`` has a nonzero outside the pattern."""
        np.take(dense.ravel(), pat.flat, out=out)
        return np.count_nonzero(dense) == np.count_nonzero(out)

    def solve(
        self, A: Array, lo: Array, up: Array, Jw: Array, tw: Array, declared: NDArray[np.bool_] | None = None
    ) -> tuple[Array | None, str, int]:
        """Minimise ‖Jw x − tw‖² + ε‖x‖² subject to lo ≤ A x ≤ up (equalities where lo = up)."""
        m = A.shape[0]
        P, q = self._hessian(Jw, tw)
        if self.warm is not None:  # the previous step's active set, verified by the KKT conditions
            guess = self.guess if self.guess is not None and self.guess.size == m else np.zeros(m, np.int8)
            res = self.warm.solve(P, q, A, lo, up, guess)
            if res is not None:
                self.guess = res.active
                self.warm_hits += 1
                return res.x, "verified", 0
        lo = np.maximum(lo, -OSQP_INFTY)
        up = np.minimum(up, OSQP_INFTY)
        if sp.issparse(P):
            P = P.toarray()
        fits = self.A_pat is not None and self.A_pat.shape == A.shape and self.J_pat.shape == Jw.shape
        fits = fits and self._gather(self.A_pat, A, self.Ax) and self._gather(self.J_pat, Jw, self.Jx)
        if fits:
            np.take(P.ravel(), self.P_pat.flat, out=self.Px)
        if not fits:
            self._setup(P, q, A, Jw, lo, up, declared)
        elif self.core is not None:
            self.core.update_data_vec(q=q, l=lo, u=up)
            self.core.update_data_mat(P_x=self.Px, P_i=None, A_x=self.Ax, A_i=None)
        else:  # pragma: no cover - an osqp without the extension attribute
            self.solver.update(q=q, l=lo, u=up, Px=self.Px, Ax=self.Ax)
        if self.core is not None:
            self.core.solve()
            info = self.core.info
            x, y = self.core.solution.x, self.core.solution.y
        else:  # pragma: no cover
            res = self.solver.solve(raise_error=False)
            info, x, y = res.info, res.x, res.y
        x = np.array(x) if x is not None and np.all(np.isfinite(x)) else None
        if x is not None and y is not None and str(info.status) == "solved":
            self.guess = active_set(np.asarray(y), lo, up, tol=1e-7)
        return x, str(info.status), int(info.iter)


class _QpsolversLevel:
    """One level solved by a qpsolvers backend, condensed (``P = Σ w JᵀJ + εI``), a fresh problem each call."""

    #: tolerances passed to the backends whose defaults are too loose for strict priority
    OPTIONS: dict[str, dict[str, float]] = {
        "osqp": {"eps_abs": 1e-8, "eps_rel": 1e-8, "max_iter": 20000, "polishing": False},
        "proxqp": {"eps_abs": 1e-9, "eps_rel": 0.0},
    }

    def __init__(self, solver: str, eps: float) -> None:
        self.solver = solver
        self.eps = float(eps)
        self.options = self.OPTIONS.get(solver, {})
        self.setups = 0

    def solve(
        self, A: Array, lo: Array, up: Array, Jw: Array, tw: Array, declared: NDArray[np.bool_] | None = None
    ) -> tuple[Array | None, str, int]:
        n = A.shape[1]
        P = Jw.T @ Jw + self.eps * np.eye(n)
        q = -Jw.T @ tw
        Ai, li, ui = A, lo, up
        eq = li == ui
        has_u = ~eq & np.isfinite(ui) & (ui < OSQP_INFTY)
        has_l = ~eq & np.isfinite(li) & (li > -OSQP_INFTY)
        G = np.vstack([Ai[has_u], -Ai[has_l]])
        h = np.concatenate([ui[has_u], -li[has_l]])
        Aeq = Ai[eq] if eq.any() else None
        beq = li[eq] if eq.any() else None
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
    """Strict-priority stack of QPs solved every step, in robot velocities (see the module docstring).

    Level i keeps the task values of every higher level j < i with equality rows ``F v = F v*_{i−1}``, where F is an
    orthonormal basis of the span of the higher levels' task rows (redundant rows, e.g. span differences next to the
    spans, are removed: OSQP converges poorly on inconsistent near-duplicate equalities). The last level freezes
    nothing, and the levels below one holding a full-rank task are skipped.

    Args:
        chain: the chain (planar).
        levels: priority levels, highest first; each a :class:`Level` of (task, weight) pairs.
        limits: hard limits shared by every level.
        box: joint box bounds (speed, acceleration, span), imposed as rows ``lb ≤ T v ≤ ub``.
        solver: ``"osqp"`` (persistent workspace) or a qpsolvers backend name (see :func:`solvers`).
        regularization: ε added to every level's Hessian [dimensionless].
        feasibility_tolerance: largest violation of a hard row accepted from a solver [row units].
        lex_tolerance: largest relative change of a frozen higher-level task value accepted from a solver.
        optimistic: try each step first with level 1 met exactly (one QP instead of two; exact when feasible).
        warm_start: with ``"osqp"``, first solve each level from the previous step's active set by one KKT solve,
            verified by the KKT conditions (:mod:`tmr.formulations.activeset`); OSQP runs only when it fails.
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
        optimistic: bool = True,
        warm_start: bool = True,
    ) -> None:
        if not levels or any(not level.tasks for level in levels):
            raise ParameterError("the QP stack needs at least one level, and every level at least one task")
        if solver not in solvers():
            raise ParameterError(f"unknown QP solver {solver!r}; available: {', '.join(solvers())}")
        if chain.spatial:
            raise ParameterError("the lexicographic QP plans planar chains (robot-velocity coordinates)")
        self.chain, self.levels, self.limits, self.box = chain, list(levels), list(limits), box
        self.solver = solver
        self.eps, self.feas_tol, self.lex_tol = (
            float(regularization),
            float(feasibility_tolerance),
            float(lex_tolerance),
        )
        self.optimistic = bool(optimistic)
        self.warm_start = bool(warm_start)
        self.widen = 0.1 * self.feas_tol / max(1, len(self.levels))
        self._workspaces: dict[tuple[int, int], _OsqpLevel | _QpsolversLevel] = {}
        self._declared: NDArray[np.bool_] | None = None
        self._lagging = False
        self._fallback = _QpsolversLevel(FALLBACK_SOLVER, self.eps)
        self.fallbacks = 0
        self._buffer = np.zeros((0, 0))
        self._zeros = np.zeros(0)
        self._rows_cache: dict[int, tuple] = {}
        self._spans: list[tuple[slice, slice, tuple[int, int], tuple[int]]] = []
        self._m0 = 0

    def reset(self) -> None:
        self._workspaces = {}
        self._declared = None
        self._lagging = False
        self.fallbacks = 0
        self._rows_cache = {}
        for level in self.levels:
            for task, _ in level.tasks:
                task.reset()
        for lim in self.limits:
            lim.reset()

    # ------------------------------------------------------------------ assembly
    def _objective(self, level: Level, ctx: StepContext) -> tuple[Array, Array, Array, Array, bool]:
        """Rows of a level on x = [v, q̇]: weighted (√w J, √w t), plain (J, t), and whether it is full rank.

        Tasks whose rows are constant return the same read-only array every step (selectors, identities); when every
        task of the level does, the stacked matrices of the previous step are reused and only the targets are rebuilt
        (a writable array may have been changed in place: it is always restacked).
        """
        parts = [task.compute(ctx) for task, _ in level.tasks]
        cached = self._rows_cache.get(id(level))
        if cached is not None and all(
            Jt is c and not Jt.flags.writeable for (Jt, _), c in zip(parts, cached[0], strict=True)
        ):
            _, J, Jw, sw, full = cached
        else:
            n = 2 * self.chain.n_robots
            m = sum(t.size for _, t in parts)
            J = np.zeros((m, 2 * n))
            sw = np.empty(m)
            full = False
            r = 0
            for (task, w), (Jt, t) in zip(level.tasks, parts, strict=True):
                k = t.size
                space = getattr(task, "space", "joint")  # duck-typed tasks write joint rates
                if space == "robot":
                    J[r : r + k, :n] = Jt
                elif space == "joint":
                    J[r : r + k, n:] = Jt
                else:
                    raise ParameterError(f"task {task.name!r}: unknown velocity coordinates {space!r}")
                sw[r : r + k] = np.sqrt(w)
                full = full or (getattr(task, "full_rank", False) and w > 0)
                r += k
            Jw = sw[:, None] * J
            self._rows_cache[id(level)] = ([Jt for Jt, _ in parts], J, Jw, sw, full)
        t = np.concatenate([t for _, t in parts])
        return Jw, sw * t, J, t, full

    def _workspace(self, i: int, n_frozen: int) -> _OsqpLevel | _QpsolversLevel:
        key = (i, n_frozen)
        ws = self._workspaces.get(key)
        if ws is None:
            if self.solver == "osqp":
                ws = _OsqpLevel(self.eps, WarmActiveSet() if self.warm_start else None)
            else:
                ws = _QpsolversLevel(self.solver.removeprefix("qpsolvers-"), self.eps)
            self._workspaces[key] = ws
        return ws

    @property
    def setups(self) -> int:
        """Number of solver workspace set-ups so far (OSQP: one per level, plus one per pattern growth)."""
        return sum(ws.setups for ws in self._workspaces.values())

    def _prepare(self, ctx: StepContext, rows: list) -> None:
        """Check the limits' row counts against their patterns; allocate the row buffer and the declared pattern."""
        n = 2 * self.chain.n_robots
        patterns = [lim.pattern(self.chain) for lim in self.limits]
        for lim, r, d in zip(self.limits, rows, patterns, strict=True):
            if r.A.shape != d.shape:
                raise ParameterError(
                    f"limit {lim.name!r} returned rows of shape {r.A.shape}, its pattern declares {d.shape}"
                )
            if lim.space not in ("robot", "joint"):
                raise ParameterError(f"limit {lim.name!r}: unknown velocity coordinates {lim.space!r}")
        self._spans = []
        start = 2 * n
        for lim, d in zip(self.limits, patterns, strict=True):
            cols = slice(0, n) if lim.space == "robot" else slice(n, 2 * n)
            self._spans.append((slice(start, start + d.shape[0]), cols, (d.shape[0], n), (d.shape[0],)))
            start += d.shape[0]
        self._m0 = start
        # rows: [T, −I] (q̇ = T v), [0, I] (joint box), the limits, then room for the frozen rows of the levels
        self._buffer = np.zeros((start + n, 2 * n))
        self._zeros = np.zeros(n)
        self._buffer[:n, n:] = -np.eye(n)
        self._buffer[n : 2 * n, n:] = np.eye(n)
        declared = np.zeros((start, 2 * n), dtype=bool)
        declared[:n, :n] = robot_pattern(np.eye(n, dtype=bool))
        declared[:n, n:] = np.eye(n, dtype=bool)
        declared[n : 2 * n, n:] = np.eye(n, dtype=bool)
        for (r, c, _, _), d in zip(self._spans, patterns, strict=True):
            declared[r, c] = d
        self._declared = declared

    def _rows(self, ctx: StepContext, rows: list) -> Array:
        """The hard rows on x = [v, q̇] of this step, written into the persistent buffer: a view (m0, 2n)."""
        n = 2 * self.chain.n_robots
        B = self._buffer
        B[:n, :n] = ctx.velocity_map.T
        for (r, c, shape, bounds), lr, lim in zip(self._spans, rows, self.limits, strict=True):
            if lr.A.shape != shape or lr.lower.shape != bounds or lr.upper.shape != bounds:
                raise ParameterError(
                    f"limit {lim.name!r} returned rows of shape {lr.A.shape} (bounds {lr.lower.shape}, "
                    f"{lr.upper.shape}); its pattern declares {shape[0]} rows of {shape[1]} columns"
                )
            B[r, c] = lr.A
        return B[: self._m0]

    # ------------------------------------------------------------------ one step
    def step(self, ctx: StepContext) -> tuple[Array, dict[str, float]]:
        """Joint velocities for the step in ``ctx`` (strict priority over the levels) and diagnostics.

        If the limits have no common solution, the step is solved again without the relaxable (comfort) limits —
        the acceleration bounds — and ``diagnostics["relaxed"]`` is 1; if the safety limits alone have no solution,
        :class:`InfeasibleStep` is raised.
        """
        t0 = time.perf_counter()
        n = 2 * self.chain.n_robots
        fallbacks = self.fallbacks
        rows = [lim.compute(ctx) for lim in self.limits]
        if self._declared is None:
            self._prepare(ctx, rows)
        A0 = self._rows(ctx, rows)
        objectives: dict[int, tuple] = {}  # built on first use: skipped levels cost nothing
        solves = [0]
        result = None
        try:
            if self.optimistic and len(self.levels) > 1 and not self._lagging:
                result = self._solve_levels(ctx, A0, rows, objectives, relax=False, optimistic=True, solves=solves)
            if result is None:
                result = self._solve_levels(ctx, A0, rows, objectives, relax=False, optimistic=False, solves=solves)
            relaxed = 0.0
        except InfeasibleStep:
            result = self._solve_levels(ctx, A0, rows, objectives, relax=True, optimistic=False, solves=solves)
            relaxed = 1.0
        assert result is not None
        x, lag, iters = result
        self._lagging = lag > 1e-6
        diag = {
            "leader_residual": lag,
            "solver_iterations": float(iters),
            "qp_solves": float(solves[0]),
            "fallback_solves": float(self.fallbacks - fallbacks),
            "relaxed": relaxed,
            "step_time": time.perf_counter() - t0,
        }
        # q̇ = T v exactly (the solver meets the coupling rows q̇ = T v only to its tolerance): the robots move as
        # the rows on v, which carry the safety limits and the leader, were solved
        return ctx.velocity_map.joint_rates(x[:n]), diag

    def _solve_levels(
        self,
        ctx: StepContext,
        A0: Array,
        rows: list,
        objectives: dict,
        relax: bool,
        optimistic: bool,
        solves: list[int],
    ) -> tuple[Array, float, int] | None:
        """Solve the levels in order; each freezes an orthonormal basis F of its task rows' span: F x = F x*.

        ``optimistic``: start at level 2 with level 1's rows as equalities at their targets; returns None if that
        QP fails (the caller then solves level 1 on its own).
        """
        nx = A0.shape[1]
        lb, ub = self.box.compute(ctx, relax=relax)
        zeros = self._zeros  # right-hand side of q̇ − T v = 0
        # with relax, the relaxable (comfort) limits are dropped: their rows get infinite bounds
        pairs = [(r, relax and lim.relaxable) for r, lim in zip(rows, self.limits, strict=True)]
        lo0 = np.concatenate([zeros, lb, *(np.full(r.lower.size, -np.inf) if d else r.lower for r, d in pairs)])
        up0 = np.concatenate([zeros, ub, *(np.full(r.upper.size, np.inf) if d else r.upper for r, d in pairs)])
        n = nx // 2
        if optimistic:
            if 0 not in objectives:
                objectives[0] = self._objective(self.levels[0], ctx)
            if objectives[0][4] or objectives[0][2].shape[0] >= n:
                return None  # level 1 alone fixes every degree of freedom: nothing to gain, solve it on its own
            F, y = objectives[0][2], objectives[0][3]  # level 1 met exactly: J_1 x = t_1
            start = 1
        else:
            F, y = np.zeros((0, nx)), np.zeros(0)
            start = 0
        x: Array | None = None
        iters = 0
        lag = 0.0
        last = len(self.levels) - 1
        for i in range(start, len(self.levels)):
            if i > start and F.shape[0] >= n:
                break  # the higher levels fix every degree of freedom (x has 2N of them: v determines q̇)
            if i not in objectives:
                objectives[i] = self._objective(self.levels[i], ctx)
            Jw, tw, J, t, full = objectives[i]
            # lower levels start from the higher optimum, which sits on active rows up to the solver accuracy: a
            # small widening (growing with the level, as violations may accumulate) keeps that optimum feasible
            m0, nF = A0.shape[0], F.shape[0]
            self._buffer[m0 : m0 + nF] = F  # the frozen rows go below the hard rows: A is a view, never a copy
            A = self._buffer[: m0 + nF]
            if i == start:  # no optimum of an earlier solve to keep feasible
                lo, up = np.concatenate([lo0, y]), np.concatenate([up0, y])
            else:
                widen = self.widen * i * (lo0 < up0)  # equalities (q̇ = T v) stay exact: OSQP treats them apart
                lo, up = np.concatenate([lo0 - widen, y]), np.concatenate([up0 + widen, y])
            z, status, it = self._workspace(i, nF).solve(A, lo, up, Jw, tw, self._declared)
            solves[0] += 1
            iters += it
            if self.solver == "osqp" and status not in ("verified", "solved", "primal infeasible"):
                # OSQP stopped without an answer (iteration limit on an ill-conditioned level): an active-set method
                # settles it exactly
                z, status, _ = self._fallback.solve(A, lo, up, Jw, tw)
                self.fallbacks += 1
            # a KKT-verified solution meets every row to 1e-9 already; a solver's answer is checked here
            ok = z is not None and (status == "verified" or (self._feasible(A0, lo0, up0, z) and self._kept(F, y, z)))
            if not ok:
                if i == start and optimistic:
                    return None
                if i == 0:
                    raise InfeasibleStep(self._explain(ctx, status, A0, lo0, up0, relax))
                break  # a lower level failed numerically: keep the higher levels' optimum (strict priority holds)
            x = z
            if i == 0:
                lag = float(np.linalg.norm(J @ x - t))  # > 0 when the limits hold the leader back
            if i == last or full:
                break  # nothing below, or this level's optimum is unique
            # the frozen basis lives on v (q̇ = T v): a row [a, b] on x = [v, q̇] acts as a + b T, so rows that are
            # equivalent through the coupling are recognised as dependent; F's rows are [F_v, 0]
            T = ctx.velocity_map.T
            if i == start and optimistic:  # replace level 1's raw rows by an orthonormal basis before extending it
                F = self._on_x(orthonormal_rows(self._on_v(F, T), np.zeros((0, n))))
                y = F @ x
            Fn = self._on_x(orthonormal_rows(self._on_v(J, T), F[:, :n]))
            F, y = np.vstack([F, Fn]), np.concatenate([y, Fn @ x])
        if x is None:  # pragma: no cover - level 1 is always solved or raises above
            raise InfeasibleStep(f"step {ctx.k}: no level was solved")
        return x, lag, iters

    @staticmethod
    def _on_v(J: Array, T: Array) -> Array:
        """Rows on x = [v, q̇] as rows on v, through q̇ = T v."""
        n = T.shape[0]
        return J[:, :n] + J[:, n:] @ T

    @staticmethod
    def _on_x(Fv: Array) -> Array:
        """Rows on v as rows on x = [v, q̇] (zeros on q̇)."""
        return np.hstack([Fv, np.zeros_like(Fv)])

    def _kept(self, F: Array, y: Array, x: Array) -> bool:
        """Whether x keeps the frozen task values of the higher levels (strict priority) to solver accuracy."""
        return bool(np.all(np.abs(F @ x - y) <= self.lex_tol * (1.0 + np.abs(y))))

    def _feasible(self, A: Array, lo: Array, up: Array, x: Array) -> bool:
        r = A @ x
        return bool(np.all(r >= lo - self.feas_tol) and np.all(r <= up + self.feas_tol))

    def _explain(self, ctx: StepContext, status: str, A0: Array, lo0: Array, up0: Array, relax: bool) -> str:
        """A message naming the step, the solver status and the limits the previous motion would violate."""
        n = 2 * self.chain.n_robots
        x = np.concatenate([ctx.velocity_map.robot_velocities(ctx.qdot_prev), ctx.qdot_prev])
        r = A0 @ x
        gap = np.maximum(lo0 - r, r - up0)
        worst = []
        if np.max(gap[n : 2 * n], initial=0.0) > self.feas_tol:
            worst.append(f"joint box (rows violated by up to {np.max(gap[n : 2 * n]):.3g})")
        start = 2 * n
        for lim in self.limits:
            m = lim.pattern(self.chain).shape[0]
            g = gap[start : start + m]
            start += m
            if relax and lim.relaxable:
                continue
            if g.size and np.max(g) > self.feas_tol:
                worst.append(f"{lim.name} (rows violated by up to {np.max(g):.3g})")
        names = ", ".join(worst) or "the joint box bounds together with the limits"
        return (
            f"step {ctx.k} (t = {ctx.k * ctx.Ts:.2f} s): the hard constraints have no common solution "
            f"(solver status: {status}{', even without the acceleration bounds' if relax else ''}); tightest: {names}. "
            "Relax the speed bounds or the clearance margin, or give the leader a path farther from the obstacles."
        )
