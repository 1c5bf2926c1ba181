"""Lexicographic QP per step with hard safety constraints (``--method qp``; math in ``formulations/qp.md``).

Each step solves a strict priority stack of QPs in x = [v, q̇]: the robot velocities v = [ṗ1, …, ṗN] (dim·N: 2N
planar, 3N for a spatial chain of drones) and the joint rates q̇, tied by q̇ = T v (:mod:`tmr.model.velocity`, T
banded; for a spatial chain q̇ are the singularity-free link coordinates of :class:`~tmr.model.velocity.VelocityMap3D`).
Rows on robots and tether points are local in v, joint-space rows (tether regulation, smoothness, energy, the joint
box) are simplest on q̇, and every task and limit declares which one it writes (``space``):

    level i:  min_x Σ_t w_t ‖J_t x − t_t‖² + ε‖x‖²
              s.t.  q̇ − T v = 0,   lb ≤ q̇ ≤ ub              (coupling; joint speed, acceleration, span: JointBox)
                    lower ≤ A x ≤ upper                       (every Limit: clearance, separation, robot speed, …)
                    F x = F x*                               (strict priority: the higher levels' optima are frozen)

F is an orthonormal basis, on v, of the higher levels' task rows (tasks of weight > 0 only) and F x* their optimal
values: a level's objective is strictly convex in its task value, so freezing it means no lower level can degrade a
higher one. The bounds of a lower level are widened just enough that x* meets them (``min(lower, A x*)``, …): every
frozen level is feasible by construction. A level holding a full-rank task (``Task.full_rank``) has a unique optimum,
and the levels below it are ``implied``. The returned joint rates are q̇ = T v* (exact).

**Optimistic first level.** Level 1 (leader tracking) usually reaches zero residual. So each step first solves level
2 with level 1's rows as equalities at their targets (``J_1 x = t_1``): if that QP is feasible its solution is exactly
the lexicographic one (level 1's optimum is then the zero residual), and one QP replaces two. Only if it is
infeasible (the limits hold the leader back) is level 1 solved on its own, as an objective: the leader lags instead of
breaking a hard limit, and the lag is reported. After a lagging step the next one starts with level 1 directly.

**Solvers.** With the default ``"osqp"`` each level is first solved from the previous step's active set by one KKT
solve, accepted only if the KKT conditions verify (:mod:`tmr.control.activeset`); otherwise one persistent
``osqp.OSQP`` workspace per level (fixed sparsity pattern, values updated each step) solves it and its answer is
polished the same way. Any qpsolvers backend (``"daqp"``, ``"proxqp"``, ``"clarabel"``, …, or ``"qpsolvers-osqp"``) is
reached through :func:`qpsolvers.solve_problem` with the same problem, and its answer polished from the rows it has
at their bounds. Every backend gets the condensed least squares P = Σ w JᵀJ + εI, q = −Σ w Jᵀt.

**Failures.** A level a backend does not solve (or solves outside the tolerances) goes to the next backend of
:data:`FALLBACK_SOLVERS`; an accepted answer that is not verified optimal gets a second opinion from the next backend
(the lower objective wins); if every backend fails, the freezes of the higher levels are relaxed by priority (lowest
first) to ``freeze_slack``; a level still unsolved is ``failed`` and the step keeps the higher levels' optimum. Each
step's status per level is in ``diagnostics["qp_level:<name>"]`` (:data:`LEVEL_STATUS`), counted in ``metrics.json``.
"""

from __future__ import annotations

import time
from collections.abc import Container, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from tmr.control.activeset import WarmActiveSet
from tmr.control.limits import JointBox, Limit
from tmr.control.qp_backends import FALLBACK_SOLVERS, _installed, _OsqpLevel, _QpsolversLevel, solvers
from tmr.control.tasks import StepContext, Task
from tmr.errors import InfeasibleStep, ParameterError
from tmr.model.chain import Chain
from tmr.model.velocity import robot_pattern, robot_pattern3d

if TYPE_CHECKING:
    pass

Array = NDArray[np.float64]


@dataclass
class Level:
    """One priority level: weighted tasks whose rows are stacked into a least-squares objective.

    Only tasks of weight > 0 take part (in the level's objective and in the freeze of its optimum below it).
    """

    tasks: Sequence[tuple[Task, float]]
    name: str = ""


def orthonormal_rows(J: Array, F: Array, rtol: float = 1e-9) -> Array:
    """Orthonormal rows spanning the part of the row space of ``J`` not already spanned by the orthonormal ``F``.

    QR of the projected rows; rows whose |R_kk| fall below ``rtol`` times the largest are dependent and dropped.
    """
    G = J - (J @ F.T) @ F if F.shape[0] else J
    if G.shape[0] == 0:
        return np.zeros((0, J.shape[1]))
    Q, R, _ = scipy.linalg.qr(G.T, mode="economic", pivoting=True, check_finite=False)  # columns of Q span G's rows
    d = np.abs(np.diag(R))
    keep = d > rtol * max(1.0, float(d.max()) if d.size else 0.0)
    rows = Q[:, keep].T
    if F.shape[0]:  # one re-orthogonalisation pass against F (QR of nearly dependent rows)
        rows = rows - (rows @ F.T) @ F
        rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    return rows


#: Per-step status of a level, in ``diagnostics["qp_level:<name>"]`` (the code, a float per step) and counted per
#: level in ``metrics.json`` (``qp_levels``). Codes are the indices in this tuple.
LEVEL_STATUS: tuple[str, ...] = ("solved", "relaxed", "implied", "failed", "skipped", "empty")
SOLVED, RELAXED, IMPLIED, FAILED, SKIPPED, EMPTY = range(len(LEVEL_STATUS))


class StepRecord(NamedTuple):
    """One step's QP as posed and as solved, kept when the step is in ``LexicographicQP.record_steps``.

    Everything is on x = [v, q̇] (robot velocities [m/s], then joint rates [rad/s, m/s]) so that an independent solver
    can re-solve the textbook lexicographic problem (``tests/test_qp_priority.py``).

    Attributes:
        k: step index.
        A: hard rows (m0, 2n): the coupling q̇ − T v = 0, the joint box on q̇, then every limit's rows.
        lower, upper: their bounds (m0,) with every limit (``relax=False``) [row units, ±inf allowed].
        lower_relaxed, upper_relaxed: the bounds without the comfort limits (acceleration), as the relaxed step.
        relaxed: whether this step was solved without the comfort limits.
        levels: per level, highest first, ``(J, t, w)`` of every task of weight w > 0 (J on x, t its target).
        x: the step's solution [v, T v] (q̇ = T v exactly, as returned).
        status: per level, the code of :data:`LEVEL_STATUS`.
    """

    k: int
    A: Array
    lower: Array
    upper: Array
    lower_relaxed: Array
    upper_relaxed: Array
    relaxed: bool
    levels: list[list[tuple[Array, Array, float]]]
    x: Array
    status: tuple[int, ...]


class _Objective(NamedTuple):
    """A level's least-squares rows on x = [v, q̇]: weighted (√w J, √w t), plain (J, t), full rank."""

    Jw: Array
    tw: Array
    J: Array
    t: Array
    full: bool


class LexicographicQP:
    """Strict-priority stack of QPs solved every step, in robot velocities (see the module docstring).

    Level i keeps the task values of every higher level j < i with rows ``F v = F v*``, where F is an orthonormal
    basis of the span of the higher levels' task rows (redundant rows, e.g. span differences next to the spans, are
    removed: OSQP converges poorly on inconsistent near-duplicate equalities), and v* the last accepted solution.
    Only tasks of weight > 0 take part in a level and in its freeze; a level without one is ``"empty"``. The levels
    below one holding a full-rank task, or below a freeze that fixes every robot velocity, are ``"implied"``.

    **Freezing is feasible by construction.** The inequality bounds of a lower level are those of the hard rows,
    widened just enough that v* meets them: ``min(lower, A x*) − widening ≤ A x ≤ max(upper, A x*) + widening``
    (x* = [v*, T v*]; equality rows stay exact). So v* itself is a feasible point of every frozen level, and a solver
    that calls one infeasible has failed. Each accepted solution is checked against the original bounds (within
    ``feasibility_tolerance``) and the frozen values (within ``lex_tolerance``).

    **Fallback.** A level is tried on the primary backend (``solver``), then on each of :data:`FALLBACK_SOLVERS`
    (``diagnostics["fallback_solves"]`` counts these solves); an accepted answer that its KKT polish does not verify
    optimal gets a second opinion from the next backend, and the lower objective wins. If every backend fails with the
    exact freeze, the freezes are relaxed by priority — the lowest frozen level first, up to all of them — to
    ``|F x − F x*| ≤ freeze_slack (1 + |F x*|)`` (status ``"relaxed"``); a level no attempt solves is ``"failed"`` and
    the step keeps the higher levels' optimum (lower levels ``"skipped"``). Each step's status per level is in
    ``diagnostics["qp_level:<name>"]`` (the index in :data:`LEVEL_STATUS`); a level 1 that no backend solves, even
    without the comfort limits, raises :class:`InfeasibleStep`.

    Args:
        chain: the chain: planar, or spatial (``Chain(spatial=True)``; its steps' ``velocity_map`` is then a
            :class:`~tmr.model.velocity.VelocityMap3D`, x = [v, link rates], n = 3N).
        levels: priority levels, highest first; each a :class:`Level` of (task, weight) pairs.
        limits: hard limits shared by every level.
        box: joint box bounds (speed, acceleration, span), imposed as rows ``lb ≤ T v ≤ ub``.
        solver: ``"osqp"`` (persistent workspace) or a qpsolvers backend name (see :func:`solvers`).
        regularization: ε added to every level's Hessian [dimensionless].
        feasibility_tolerance: largest violation of a hard row accepted from a solver [row units].
        lex_tolerance: largest relative change of a frozen higher-level task value accepted from a solver.
        widening: margin added round a higher optimum's row values in a lower level's bounds [row units].
        freeze_slack: relative half-width of a relaxed freeze (see above).
        optimistic: try each step first with level 1 met exactly (one QP instead of two; exact when feasible).
        warm_start: with ``"osqp"``, first solve each level from the previous step's active set by one KKT solve,
            verified by the KKT conditions (:mod:`tmr.control.activeset`); OSQP runs only when it fails.
        exact_miss: with ``"osqp"`` and ``warm_start``, solve a miss of the warm active set by DAQP first (an exact
            dual active-set solve, its answer verified by the same KKT conditions; a level DAQP finds infeasible, the
            verdict confirmed with P = I, goes straight to the fallbacks and the relaxed freeze), OSQP only if DAQP
            fails otherwise. Off: OSQP's coarse pass finds the new active set, as before (the same plan to 2·10⁻⁹ m
            on the 9,563-step narrow room measured, ``formulations/qp.md``).
        fallbacks: backends tried in order after the primary one (default :data:`FALLBACK_SOLVERS`, the installed
            ones other than the primary).

    Attributes:
        level_keys: the diagnostics key of each level's status, ``"qp_level:<name>"`` (``level<i>`` if unnamed).
        fallback_solvers: the backends tried after the primary one, in order.
        record_steps: a set of step indices (or None): those steps are kept as :class:`StepRecord` in ``records``.
        notes: one line per unusual solve of the plan so far (a backend that failed and why, a second opinion),
            at most ``max_notes``.
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
        widening: float = 0.0,
        freeze_slack: float = 1e-6,
        optimistic: bool = True,
        warm_start: bool = True,
        exact_miss: bool = True,
        fallbacks: Sequence[str] | None = None,
    ) -> None:
        if not levels or any(not level.tasks for level in levels):
            raise ParameterError("the QP stack needs at least one level, and every level at least one task")
        if solver != "osqp" and solver not in solvers():  # "osqp" is always there: no qpsolvers import
            raise ParameterError(f"unknown QP solver {solver!r}; available: {', '.join(solvers())}")
        for level in levels:
            for task, w in level.tasks:
                if not (np.isfinite(w) and w >= 0):
                    name = getattr(task, "name", task)
                    raise ParameterError(f"task {name!r}: weight must be finite and ≥ 0, got {w}")
        if not any(w > 0 for level in levels for _, w in level.tasks):
            raise ParameterError("every task of the QP stack has weight 0: nothing to optimise")
        self.chain, self.levels, self.limits, self.box = chain, list(levels), list(limits), box
        self.solver = solver
        self.eps, self.feas_tol, self.lex_tol = (
            float(regularization),
            float(feasibility_tolerance),
            float(lex_tolerance),
        )
        self.widen, self.slack = float(widening), float(freeze_slack)
        self.optimistic = bool(optimistic)
        self.warm_start = bool(warm_start)
        self.exact_miss = bool(exact_miss)
        primary = solver.removeprefix("qpsolvers-")
        names = FALLBACK_SOLVERS if fallbacks is None else tuple(fallbacks)
        available = _installed(names)
        self.fallback_solvers = tuple(s for s in names if s != primary and s in available)
        self._fallback = {s: _QpsolversLevel(s, self.eps) for s in self.fallback_solvers}
        self.level_keys = _level_keys(self.levels)
        self.record_steps: Container[int] | None = None
        self.records: dict[int, StepRecord] = {}
        self.notes: list[str] = []
        self.max_notes = 1000
        self._workspaces: dict[tuple[int, int, bool], _OsqpLevel | _QpsolversLevel] = {}
        self._declared: NDArray[np.bool_] | None = None
        self._lagging = False
        self.fallbacks = 0
        self._buffer = np.zeros((0, 0))
        self._zeros = np.zeros(0)
        self._rows_cache: dict[int, tuple] = {}
        self._spans: list[tuple[slice, slice, tuple[int, int], tuple[int]]] = []
        self._m0 = 0
        #: per level, its tasks of weight > 0 (set again by reset(): a plan starts with it)
        self._tasks = [[(task, w) for task, w in level.tasks if w > 0] for level in self.levels]

    def reset(self) -> None:
        self._workspaces = {}
        self._declared = None
        self._lagging = False
        self.fallbacks = 0
        self._rows_cache = {}
        self.records = {}
        self.notes = []
        self._tasks = [[(task, w) for task, w in level.tasks if w > 0] for level in self.levels]
        for level in self.levels:
            for task, _ in level.tasks:
                task.reset()
        for lim in self.limits:
            lim.reset()

    # ------------------------------------------------------------------ assembly
    def _objective(self, i: int, ctx: StepContext) -> _Objective | None:
        """Rows of a level on x = [v, q̇] from its tasks of weight > 0 (None if it has none).

        Tasks whose rows are constant return the same read-only array every step (selectors, identities); when every
        task of the level does, the stacked matrices of the previous step are reused and only the targets are rebuilt
        (a writable array may have been changed in place: it is always restacked).
        """
        tasks = self._tasks[i]
        if not tasks:
            return None
        parts = [task.compute(ctx) for task, _ in tasks]
        cached = self._rows_cache.get(i)
        if (
            cached is not None
            and len(cached[0]) == len(parts)
            and all(Jt is c and not Jt.flags.writeable for (Jt, _), c in zip(parts, cached[0], strict=True))
        ):
            _, J, Jw, sw, full = cached
        else:
            n = self.chain.dof
            m = sum(t.size for _, t in parts)
            J = np.zeros((m, 2 * n))
            sw = np.empty(m)
            full = False
            r = 0
            for (task, w), (Jt, t) in zip(tasks, parts, strict=True):
                k = t.size
                space = getattr(task, "space", "joint")  # duck-typed tasks write joint rates
                if space == "robot":
                    J[r : r + k, :n] = Jt
                elif space == "joint":
                    J[r : r + k, n:] = Jt
                else:
                    raise ParameterError(f"task {task.name!r}: unknown velocity coordinates {space!r}")
                sw[r : r + k] = np.sqrt(w)
                full = full or getattr(task, "full_rank", False)
                r += k
            Jw = sw[:, None] * J
            self._rows_cache[i] = ([Jt for Jt, _ in parts], J, Jw, sw, full)
        t = np.concatenate([t for _, t in parts])
        return _Objective(Jw, sw * t, J, t, full)

    def _get_objective(self, i: int, ctx: StepContext, objectives: dict) -> _Objective | None:
        """Level i's rows of this step, built on first use (skipped levels cost nothing)."""
        obj = objectives.get(i, objectives)
        if obj is objectives:
            obj = objectives[i] = self._objective(i, ctx)
        return obj

    def _workspace(self, i: int, n_frozen: int, relaxed: bool) -> _OsqpLevel | _QpsolversLevel:
        key = (i, n_frozen, relaxed)
        ws = self._workspaces.get(key)
        if ws is None:
            if self.solver == "osqp":
                ws = _OsqpLevel(self.eps, WarmActiveSet() if self.warm_start else None, self.exact_miss)
            else:
                ws = _QpsolversLevel(self.solver.removeprefix("qpsolvers-"), self.eps)
            self._workspaces[key] = ws
        return ws

    @property
    def exact_solves(self) -> int:
        """Misses of the warm active set that DAQP solved (``exact_miss``) so far."""
        return sum(getattr(ws, "exact_hits", 0) for ws in self._workspaces.values())

    @property
    def setups(self) -> int:
        """Number of solver workspace set-ups so far (OSQP: one per level, plus one per pattern growth)."""
        return sum(ws.setups for ws in self._workspaces.values())

    def _prepare(self, ctx: StepContext, rows: list) -> None:
        """Check the limits' row counts against their patterns; allocate the row buffer and the declared pattern."""
        n = self.chain.dof
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
        coupling = getattr(self.chain, "coupling_pattern", None)  # a chain with unknowns of its own (active winch)
        if coupling is None:
            coupling = robot_pattern3d if self.chain.spatial else robot_pattern
        declared[:n, :n] = coupling(np.eye(n, dtype=bool))
        declared[:n, n:] = np.eye(n, dtype=bool)
        declared[n : 2 * n, n:] = np.eye(n, dtype=bool)
        for (r, c, _, _), d in zip(self._spans, patterns, strict=True):
            declared[r, c] = d
        self._declared = declared

    def _rows(self, ctx: StepContext, rows: list) -> Array:
        """The hard rows on x = [v, q̇] of this step, written into the persistent buffer: a view (m0, 2n)."""
        n = self.chain.dof
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
        :class:`InfeasibleStep` is raised. ``diagnostics["qp_level:<name>"]`` is each level's status code
        (:data:`LEVEL_STATUS`), ``diagnostics["fallback_solves"]`` the solves by a fallback backend.
        """
        t0 = time.perf_counter()
        n = self.chain.dof
        fallbacks = self.fallbacks
        rows = [lim.compute(ctx) for lim in self.limits]
        if self._declared is None:
            self._prepare(ctx, rows)
        A0 = self._rows(ctx, rows)
        objectives: dict[int, _Objective | None] = {}  # built on first use: skipped levels cost nothing
        solves = [0, 0]  # QP solves, solver iterations
        result = None
        try:
            if self.optimistic and len(self.levels) > 1 and not self._lagging:
                result = self._solve_levels(ctx, A0, rows, objectives, relax=False, optimistic=True, solves=solves)
            if result is None:
                result = self._solve_levels(ctx, A0, rows, objectives, relax=False, optimistic=False, solves=solves)
            relaxed = 0.0
        except InfeasibleStep:  # without the comfort limits (with none, a second try on fresh workspaces)
            result = self._solve_levels(ctx, A0, rows, objectives, relax=True, optimistic=False, solves=solves)
            relaxed = 1.0
        assert result is not None
        x, lag, status = result
        self._lagging = lag > 1e-6
        diag = {
            "leader_residual": lag,
            "solver_iterations": float(solves[1]),
            "qp_solves": float(solves[0]),
            "fallback_solves": float(self.fallbacks - fallbacks),
            "relaxed": relaxed,
        }
        diag.update(zip(self.level_keys, map(float, status), strict=True))
        if self.record_steps is not None and ctx.k in self.record_steps:
            self.records[ctx.k] = self._record(ctx, A0, rows, x, bool(relaxed), status)
        diag["step_time"] = time.perf_counter() - t0
        # x = [v, T v] exactly (each accepted level is projected on the coupling q̇ = T v): the robots move as the
        # rows on v, which carry the safety limits and the leader, were solved
        return x[n:].copy(), diag

    def _bounds(self, ctx: StepContext, rows: list, relax: bool) -> tuple[Array, Array]:
        """Bounds of the hard rows (coupling, joint box, limits); ``relax`` drops the comfort limits (±inf)."""
        lb, ub = self.box.compute(ctx, relax=relax)
        zeros = self._zeros  # right-hand side of q̇ − T v = 0
        if not relax:
            lo0 = np.concatenate([zeros, lb, *[r.lower for r in rows]])
            return lo0, np.concatenate([zeros, ub, *[r.upper for r in rows]])
        pairs = [(r, lim.relaxable) for r, lim in zip(rows, self.limits, strict=True)]
        lo0 = np.concatenate([zeros, lb, *(np.full(r.lower.size, -np.inf) if d else r.lower for r, d in pairs)])
        up0 = np.concatenate([zeros, ub, *(np.full(r.upper.size, np.inf) if d else r.upper for r, d in pairs)])
        return lo0, up0

    def _below(self, status: list[int], i: int, code: int) -> None:
        """Mark the levels from i down with ``code`` (``"empty"`` for a level without a task of weight > 0)."""
        for j in range(i, len(self.levels)):
            status[j] = code if self._tasks[j] else EMPTY

    def _solve_levels(
        self,
        ctx: StepContext,
        A0: Array,
        rows: list,
        objectives: dict,
        relax: bool,
        optimistic: bool,
        solves: list[int],
    ) -> tuple[Array, float, list[int]] | None:
        """Solve the levels in order; each freezes an orthonormal basis F of its task rows' span: F x = F x*.

        ``optimistic``: start at level 2 with level 1's rows as equalities at their targets; returns None if that
        QP fails (the caller then solves level 1 on its own). Returns x = [v*, T v*], the leader residual and the
        status of every level.
        """
        nx = A0.shape[1]
        n = nx // 2
        lo0, up0 = self._bounds(ctx, rows, relax)
        status = [SKIPPED] * len(self.levels)
        if optimistic:
            first = self._get_objective(0, ctx, objectives)
            if first is None or first.full or first.J.shape[0] >= n:
                return None  # nothing to meet, or level 1 alone fixes every degree of freedom: solve it on its own
            F, y = first.J, first.t  # level 1 met exactly: J_1 x = t_1
            blocks = [F.shape[0]]
            status[0] = SOLVED
            start = 1
        else:
            F, y = np.zeros((0, nx)), np.zeros(0)
            blocks = []
            start = 0
        x: Array | None = None
        lag = 0.0
        last = len(self.levels) - 1
        for i in range(start, len(self.levels)):
            obj = self._get_objective(i, ctx, objectives)
            if obj is None:
                status[i] = EMPTY
                continue
            if x is not None and F.shape[0] >= n:
                self._below(status, i, IMPLIED)  # the higher levels fix every robot velocity (v determines q̇)
                break
            if x is None:
                lo, up = lo0, up0
            else:  # widened just enough that the higher optimum x* is feasible: the frozen level always has a solution
                r = A0 @ x
                ineq = lo0 < up0  # equality rows (q̇ = T v) stay exact: OSQP treats them apart
                lo = np.where(ineq, np.minimum(lo0, r) - self.widen, lo0)
                up = np.where(ineq, np.maximum(up0, r) + self.widen, up0)
            head = optimistic and i == start
            z, code, why = self._solve_level(i, ctx, A0, lo0, up0, lo, up, F, y, blocks, obj, solves, head)
            if z is None:
                if head:
                    return None
                if x is None:
                    raise InfeasibleStep(self._explain(ctx, why, A0, lo0, up0, relax))
                self._below(status, i, SKIPPED)
                status[i] = FAILED  # every backend failed, even relaxed: keep the higher levels' optimum
                break
            x = z
            status[i] = code
            if i == 0:
                lag = float(np.linalg.norm(obj.J @ x - obj.t))  # > 0 when the limits hold the leader back
            if i == last:
                break
            if obj.full:
                self._below(status, i + 1, IMPLIED)  # this level's optimum is unique
                break
            # the frozen basis lives on v (q̇ = T v): a row [a, b] on x = [v, q̇] acts as a + b T, so rows that are
            # equivalent through the coupling are recognised as dependent; F's rows are [F_v, 0]
            T = ctx.velocity_map.T
            if head:  # replace level 1's raw rows by an orthonormal basis before extending it
                F = self._on_x(orthonormal_rows(self._on_v(F, T), np.zeros((0, n))))
                blocks = [F.shape[0]]
            Fn = self._on_x(orthonormal_rows(self._on_v(obj.J, T), F[:, :n]))
            F = np.vstack([F, Fn])
            blocks.append(Fn.shape[0])
            y = F @ x  # the values of the accepted point (after a relaxed freeze: its own, within the slack)
        if x is None:  # pragma: no cover - level 1 is always solved or raises above
            raise InfeasibleStep(f"step {ctx.k}: no level was solved")
        return x, lag, status

    def _solve_level(
        self,
        i: int,
        ctx: StepContext,
        A0: Array,
        lo0: Array,
        up0: Array,
        lo: Array,
        up: Array,
        F: Array,
        y: Array,
        blocks: list[int],
        obj: _Objective,
        solves: list[int],
        head: bool,
    ) -> tuple[Array | None, int, str]:
        """One level (see the class docstring): the primary backend with the exact freeze; on failure the fallback
        backends, then the same with the freezes relaxed by priority. An accepted answer that its backend's KKT
        polish could not verify gets a second opinion from the next backend, and the lower objective wins.

        ``head`` (the optimistic first QP): a failure returns at once — solving level 1 on its own is the fallback.
        Returns the accepted solution, projected on q̇ = T v (or None), ``SOLVED`` or ``RELAXED``, and why the last
        attempt failed (a solver status).
        """
        m0, nF = A0.shape[0], F.shape[0]
        n = A0.shape[1] // 2
        self._buffer[m0 : m0 + nF] = F  # the frozen rows go below the hard rows: A is a view, never a copy
        A = self._buffer[: m0 + nF]
        # the usual case first, without the machinery below: the exact freeze, verified from the warm active set
        z, status, it = self._workspace(i, nF, False).solve(
            A, np.concatenate([lo, y]), np.concatenate([up, y]), obj.Jw, obj.tw, self._declared
        )
        solves[0] += 1
        solves[1] += it
        if status == "verified":
            z[n:] = ctx.velocity_map.T @ z[:n]  # onto the coupling q̇ = T v exactly: the motion the robots will make
            return z, SOLVED, status
        why = "not solved"
        best: tuple[Array, float] | None = None  # an accepted answer that is not verified optimal
        # attempt r relaxes the r lowest-priority frozen blocks (r = 0: the exact freeze)
        for r in range(1 if head or not nF else len(blocks) + 1):
            if r:
                s = np.zeros(nF)
                k = sum(blocks[len(blocks) - r :])
                s[nF - k :] = self.slack * (1.0 + np.abs(y[nF - k :]))
                lo_f, up_f = np.concatenate([lo, y - s]), np.concatenate([up, y + s])
            else:
                s = 0.0
                lo_f, up_f = np.concatenate([lo, y]), np.concatenate([up, y])
            backends = [(self.solver, self._workspace(i, nF, r > 0))]
            backends += [(b, self._fallback[b]) for b in self.fallback_solvers]
            for b, (name, ws) in enumerate(backends):
                if r or b:  # (the primary's exact attempt was solved above)
                    if head and b and best is None:
                        return None, FAILED, why  # optimistic QP: level 1 on its own is the fallback
                    z, status, it = ws.solve(A, lo_f, up_f, obj.Jw, obj.tw, self._declared)
                    solves[0] += 1
                    solves[1] += it
                    self.fallbacks += b > 0
                ok = z is not None and (
                    status == "verified"
                    or (status == "solved" and self._feasible(A0, lo0, up0, z) and self._kept(F, y, z, s))
                )
                if not ok:
                    why = f"{name}: {status if z is None or status != 'solved' else 'answer failed the checks'}"
                    if not head:  # (the optimistic QP failing is how a lagging leader shows: nothing unusual)
                        self._note(ctx, i, why)
                    continue
                z[n:] = ctx.velocity_map.T @ z[:n]
                code = RELAXED if r else SOLVED
                if status == "verified":
                    return z, code, status
                f = self._value(obj, z)
                if best is not None:  # the second opinion on an unverified answer: the lower objective wins
                    return (z, code, status) if f < best[1] else (best[0], code, "solved")
                best = (z, f)
                self._note(ctx, i, f"{name}: optimum not verified, asking the next backend")
            if best is not None:
                return best[0], RELAXED if r else SOLVED, "solved"
            if head:
                break
        return None, FAILED, why

    @staticmethod
    def _value(obj: _Objective, z: Array) -> float:
        """The level's objective ‖Jw z − tw‖² at z (without the ε regularisation)."""
        res = obj.Jw @ z - obj.tw
        return float(res @ res)

    def _note(self, ctx: StepContext, i: int, text: str) -> None:
        """Keep a line on an unusual solve (fallback, second opinion, relaxed freeze, failure) in ``notes``."""
        if len(self.notes) < self.max_notes:
            self.notes.append(f"step {ctx.k}: level {self.level_keys[i].removeprefix('qp_level:')}: {text}")

    def _record(
        self, ctx: StepContext, A0: Array, rows: list, x: Array, relaxed: bool, status: list[int]
    ) -> StepRecord:
        """This step's problem and solution (see :class:`StepRecord`); every level's rows are rebuilt."""
        n = self.chain.dof
        levels = []
        for level in self.levels:
            out = []
            for task, w in level.tasks:
                if w > 0:
                    Jt, t = task.compute(ctx)
                    J = np.zeros((t.size, 2 * n))
                    cols = slice(0, n) if getattr(task, "space", "joint") == "robot" else slice(n, 2 * n)
                    J[:, cols] = Jt
                    out.append((J, np.array(t, dtype=float), float(w)))
            levels.append(out)
        lo, up = self._bounds(ctx, rows, False)
        lo_r, up_r = self._bounds(ctx, rows, True)
        return StepRecord(ctx.k, A0.copy(), lo, up, lo_r, up_r, relaxed, levels, x.copy(), tuple(status))

    @staticmethod
    def _on_v(J: Array, T: Array) -> Array:
        """Rows on x = [v, q̇] as rows on v, through q̇ = T v."""
        n = T.shape[0]
        return J[:, :n] + J[:, n:] @ T

    @staticmethod
    def _on_x(Fv: Array) -> Array:
        """Rows on v as rows on x = [v, q̇] (zeros on q̇)."""
        return np.hstack([Fv, np.zeros_like(Fv)])

    def _kept(self, F: Array, y: Array, x: Array, slack: Array | float = 0.0) -> bool:
        """Whether x keeps the frozen task values of the higher levels (strict priority) to solver accuracy."""
        return bool(np.all(np.abs(F @ x - y) <= self.lex_tol * (1.0 + np.abs(y)) + slack))

    def _feasible(self, A: Array, lo: Array, up: Array, x: Array) -> bool:
        r = A @ x
        return bool(np.all(r >= lo - self.feas_tol) and np.all(r <= up + self.feas_tol))

    def _explain(self, ctx: StepContext, status: str, A0: Array, lo0: Array, up0: Array, relax: bool) -> str:
        """A message naming the step, the solver status and the limits the previous motion would violate."""
        n = self.chain.dof
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
        comfort = any(lim.relaxable for lim in self.limits)
        return (
            f"step {ctx.k} (t = {ctx.k * ctx.Ts:.2f} s): the hard constraints have no common solution "
            f"(solver status: {status}{', even without the acceleration bounds' if relax and comfort else ''}); "
            f"tightest: {names}. "
            + (
                "Relax the speed bounds or the clearance margin, or give the leader a path farther from the obstacles."
                if comfort
                else "The acceleration bounds are hard here: a slower leader (leader_speed, leader_accel) or a larger "
                "acceleration bound gives the limits room to brake; or relax the clearance margin."
            )
        )


def _level_keys(levels: Sequence[Level]) -> list[str]:
    """Diagnostics keys of the levels' status: ``"qp_level:<name>"`` (``level<i>`` if unnamed; unique)."""
    keys: list[str] = []
    for i, level in enumerate(levels):
        key = f"qp_level:{level.name or f'level{i + 1}'}"
        keys.append(key if key not in keys else f"{key}#{i + 1}")
    return keys
