"""Lexicographic QP per step with hard safety constraints (``--method qp``; math in ``formulations/qp.md``).

Each step solves a strict priority stack of QPs in x = [v, q̇]: the robot velocities v = [ṗ1, …, ṗN] (2N, planar)
and the joint rates q̇, tied by q̇ = T v (:mod:`tmr.model.velocity`, T banded). Rows on robots and tether points are local
in v, joint-space rows (tether regulation, smoothness, energy, the joint box) are simplest on q̇, and every task and
limit declares which one it writes (``space``):

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

import importlib.util
import signal
import time
import warnings
from collections.abc import Container, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import osqp
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray

from tmr.control.activeset import WarmActiveSet, active_set
from tmr.control.limits import JointBox, Limit
from tmr.control.tasks import StepContext, Task
from tmr.errors import InfeasibleStep, ParameterError
from tmr.model.chain import Chain
from tmr.model.velocity import robot_pattern

if TYPE_CHECKING:
    import qpsolvers

Array = NDArray[np.float64]

#: OSQP settings (polishing is off: osqp 1.1 prints a line on stdout for every polish that finds no active set,
#: even with verbose=False).
OSQP_SETTINGS = dict(eps_abs=1e-8, eps_rel=1e-8, polishing=False, max_iter=20000, verbose=False, warm_starting=True)
#: First OSQP pass of a level whose warm active set failed: loose tolerances and few iterations, enough to find the
#: active set the KKT polish (:mod:`tmr.control.activeset`) then solves exactly. Only if that polish does not
#: verify does OSQP continue (warm) to :data:`OSQP_SETTINGS`; a hard step thus costs a few hundred ADMM iterations
#: instead of thousands at 1e-8 (issue 14: the 30-robot band had steps of 11 000 iterations, 50–300 ms).
OSQP_COARSE = dict(eps_abs=1e-5, eps_rel=1e-5, max_iter=400)
#: Backends that take over a level, in this order, when the primary one fails (no answer, or one that fails the checks).
FALLBACK_SOLVERS: tuple[str, ...] = ("daqp", "clarabel")
#: OSQP's infinity: bounds beyond it are clipped.
OSQP_INFTY = 1e30


def _ctrl_c_again(status: str) -> None:
    """OSQP (and SCS, through qpsolvers) install their own SIGINT handler while they iterate: a Ctrl-C then stops
    the solve with the status ``"interrupted"`` and never reaches Python, so the run went on with a failed step (about
    one Ctrl-C in 12 was lost during the QP loop). Deliver that Ctrl-C again, to Python's handler, restored by the
    solver on return: KeyboardInterrupt by default; a process that ignores SIGINT (a sweep worker) goes on."""
    if "interrupt" in status.lower():
        signal.raise_signal(signal.SIGINT)


#: Python module of each default fallback backend: whether it is installed is asked without importing qpsolvers
#: (which imports every backend it finds: 50-60 ms of a run that, as nearly every run, never falls back).
_BACKEND_MODULES = {"daqp": "daqp", "clarabel": "clarabel"}


def _installed(names: Sequence[str]) -> set[str]:
    """Which of the qpsolvers backends ``names`` are installed. For the default fallbacks this asks only whether
    their module can be found (qpsolvers itself tries to import it): a broken install of one shows up as that
    backend's error when a level falls back to it."""
    if all(n in _BACKEND_MODULES for n in names):
        return {n for n in names if importlib.util.find_spec(_BACKEND_MODULES[n]) is not None}
    import qpsolvers

    return set(qpsolvers.available_solvers)


def solvers() -> list[str]:
    """Names accepted by ``solver=``: ``"osqp"`` (persistent workspace) and every installed qpsolvers backend."""
    import qpsolvers

    return ["osqp", *(f"qpsolvers-{s}" if s == "osqp" else s for s in qpsolvers.available_solvers)]


@dataclass
class Level:
    """One priority level: weighted tasks whose rows are stacked into a least-squares objective.

    Only tasks of weight > 0 take part (in the level's objective and in the freeze of its optimum below it).
    """

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

    def _run(self) -> tuple[Any, Array | None, Array | None]:
        """One OSQP solve with the current data and settings: (info, x, y)."""
        if self.core is not None:
            self.core.solve()
            info = self.core.info
            _ctrl_c_again(str(info.status))
            return info, self.core.solution.x, self.core.solution.y
        res = self.solver.solve(raise_error=False)  # pragma: no cover - an osqp without the extension attribute
        _ctrl_c_again(str(res.info.status))  # pragma: no cover
        return res.info, res.x, res.y  # pragma: no cover

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
        coarse_iters = 0
        if self.warm is not None:  # a coarse pass for the active set, polished exactly if the KKT conditions verify
            self.solver.update_settings(**OSQP_COARSE)
            info, x, y = self._run()
            coarse_iters = int(info.iter)
            self.solver.update_settings(**{k: OSQP_SETTINGS[k] for k in OSQP_COARSE})
            if x is not None and y is not None and np.all(np.isfinite(y)):
                res = self.warm.solve(P, q, A, lo, up, active_set(np.asarray(y), lo, up, tol=1e-7))
                if res is not None:
                    self.guess = res.active
                    return res.x, "verified", coarse_iters
        info, x, y = self._run()  # warm started from the coarse pass: on to the full tolerances
        x = np.array(x) if x is not None and np.all(np.isfinite(x)) else None
        status, iters = str(info.status), coarse_iters + int(info.iter)
        if x is not None and y is not None and status == "solved":
            self.guess = active_set(np.asarray(y), lo, up, tol=1e-7)
            if self.warm is not None:  # polish: the exact optimum on OSQP's active set, if it verifies
                res = self.warm.solve(P, q, A, lo, up, self.guess)
                if res is not None:
                    self.guess = res.active
                    return res.x, "verified", iters
        return x, status, iters


class _QpsolversLevel:
    """One level solved by a qpsolvers backend, condensed (``P = Σ w JᵀJ + εI``), a fresh problem each call."""

    #: tolerances passed to the backends whose defaults are too loose for strict priority
    OPTIONS: dict[str, dict[str, float]] = {
        "osqp": {"eps_abs": 1e-8, "eps_rel": 1e-8, "max_iter": 20000, "polishing": False},
        "proxqp": {"eps_abs": 1e-9, "eps_rel": 0.0},
    }

    #: rows within this distance (relative to 1 + |bound|) of a bound are the polishing guess of the active set
    POLISH_ROWS = 1e-7
    #: backends that never warn on a failed solve (no warnings filter needed: it costs a few µs per call)
    SILENT = frozenset({"daqp"})
    #: backends whose own multipliers may prove an answer optimal (:meth:`_certified`): an active-set method stops on
    #: a vertex with exact multipliers; interior-point (Clarabel), ADMM (OSQP) and augmented-Lagrangian (proxqp)
    #: answers sit near the bounds with spread multipliers and can pass the test while off by 1e-5: they are polished
    CERTIFY = frozenset({"daqp"})

    def __init__(self, solver: str, eps: float, polish: bool = True) -> None:
        self.solver = solver
        self.eps = float(eps)
        self.options = self.OPTIONS.get(solver, {})
        self.setups = 0
        self.polish = WarmActiveSet() if polish else None

    def solve(
        self, A: Array, lo: Array, up: Array, Jw: Array, tw: Array, declared: NDArray[np.bool_] | None = None
    ) -> tuple[Array | None, str, int]:
        import qpsolvers  # only when a level falls back (or a qpsolvers backend was chosen)

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
        problem = qpsolvers.Problem(P, q, G if G.shape[0] else None, h if h.size else None, Aeq, beq)
        try:
            if self.solver in self.SILENT:
                sol = qpsolvers.solve_problem(problem, solver=self.solver, **self.options)
            else:
                with warnings.catch_warnings():  # the caller reports the status (Clarabel warns on every failure)
                    warnings.simplefilter("ignore")
                    sol = qpsolvers.solve_problem(problem, solver=self.solver, **self.options)
        except Exception as exc:  # a backend error is a failed solve, reported by the caller
            return None, f"{self.solver} error: {exc}", 0
        x = sol.x
        if not sol.found or x is None or not np.all(np.isfinite(x)):
            extras = getattr(sol, "extras", None) or {}
            why = extras.get("status", extras.get("info", None))
            why = getattr(why, "status", why)
            _ctrl_c_again(str(why))  # OSQP and SCS stop on Ctrl-C with the status "interrupted"
            return None, f"{self.solver}: {why if why is not None else 'infeasible or failed'}", 0
        x = np.array(x, dtype=float)
        if self.polish is None:
            return x, "solved", 0
        if self.solver in self.CERTIFY and self._certified(P, q, x, sol, G, h, Aeq, beq):
            return x, "verified", 0
        # polish: the exact optimum on the rows the answer has at their bounds, if it verifies
        r = A @ x
        at_up = r >= up - self.POLISH_ROWS * (1.0 + np.abs(np.where(np.isfinite(up), up, 0.0)))
        at_lo = r <= lo + self.POLISH_ROWS * (1.0 + np.abs(np.where(np.isfinite(lo), lo, 0.0)))
        guess = np.where(at_up, 1, np.where(at_lo, -1, 0)).astype(np.int8)
        res = self.polish.solve(P, q, A, lo, up, guess)
        if res is not None:
            return res.x, "verified", 0
        return x, "solved", 0

    def _certified(
        self,
        P: Array | sp.spmatrix,
        q: Array,
        x: Array,
        sol: qpsolvers.Solution,
        G: Array | sp.spmatrix,
        h: Array,
        Aeq: Array | sp.spmatrix | None,
        beq: Array | None,
    ) -> bool:
        """Whether the backend's own multipliers prove x optimal (``G x ≤ h``, ``Aeq x = beq``): stationarity
        ``P x + q + Gᵀz + Aeqᵀy = 0`` relative to q, every row within its bound, z ≥ 0 and z = 0 off the bound — the
        KKT conditions :class:`WarmActiveSet` verifies, with its tolerances. No solve: the usual proof for an
        active-set backend (DAQP) that stopped exactly."""
        z, y = getattr(sol, "z", None), getattr(sol, "y", None)
        if (h.size and (z is None or np.size(z) != h.size)) or (
            beq is not None and (y is None or np.size(y) != beq.size)
        ):
            return False
        tol = self.polish.tol
        qscale = 1.0 + float(np.abs(q).max(initial=0.0))
        grad = P @ x + q
        if h.size:
            z = np.asarray(z, dtype=float).ravel()
            slack = h - G @ x  # ≥ 0 inside
            if not slack.min() >= -tol or not z.min() >= -tol * qscale:
                return False
            if not np.abs(z[slack > tol * (1.0 + np.abs(h))]).max(initial=0.0) <= tol * qscale:
                return False  # a multiplier on a row away from its bound
            grad = grad + G.T @ z
        if beq is not None:
            if not np.abs(Aeq @ x - beq).max() <= tol * (1.0 + np.abs(beq).max()):
                return False
            grad = grad + Aeq.T @ np.asarray(y, dtype=float).ravel()
        return bool(np.abs(grad).max() <= 10 * tol * qscale)


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
        chain: the chain (planar).
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
        fallbacks: Sequence[str] | None = None,
    ) -> None:
        if not levels or any(not level.tasks for level in levels):
            raise ParameterError("the QP stack needs at least one level, and every level at least one task")
        if solver != "osqp" and solver not in solvers():  # "osqp" is always there: no qpsolvers import
            raise ParameterError(f"unknown QP solver {solver!r}; available: {', '.join(solvers())}")
        if chain.spatial:
            raise ParameterError("the lexicographic QP plans planar chains (robot-velocity coordinates)")
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
            n = 2 * self.chain.n_robots
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
        :class:`InfeasibleStep` is raised. ``diagnostics["qp_level:<name>"]`` is each level's status code
        (:data:`LEVEL_STATUS`), ``diagnostics["fallback_solves"]`` the solves by a fallback backend.
        """
        t0 = time.perf_counter()
        n = 2 * self.chain.n_robots
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
        except InfeasibleStep:
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
        n = 2 * self.chain.n_robots
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


def _level_keys(levels: Sequence[Level]) -> list[str]:
    """Diagnostics keys of the levels' status: ``"qp_level:<name>"`` (``level<i>`` if unnamed; unique)."""
    keys: list[str] = []
    for i, level in enumerate(levels):
        key = f"qp_level:{level.name or f'level{i + 1}'}"
        keys.append(key if key not in keys else f"{key}#{i + 1}")
    return keys
