"""The QP backends of the lexicographic QP (``--method qp``; math in ``formulations/qp.md``): one priority level
solved by a persistent OSQP workspace (:class:`_OsqpLevel`, warm-started, with the warm active set of
:mod:`tmr.control.activeset`) or by a qpsolvers backend (:class:`_QpsolversLevel`, the fallbacks), their settings
and the installed solvers. Used by :class:`tmr.control.qp.LexicographicQP`.
"""

from __future__ import annotations

import importlib.util
import signal
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import osqp
import scipy.sparse as sp
from numpy.typing import NDArray

from tmr.control.activeset import ActiveSetResult, WarmActiveSet, active_set

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
#: DAQP's singularity tolerance for the pivots of its working set (its default 3.7·10⁻¹¹ is too coarse here): a
#: level's P = JᵀJ + εI has eigenvalues down to ε = 10⁻⁹ (fewer task rows than variables), which DAQP's default
#: treats as singular, calling feasible levels infeasible (exit flag −1): 28 of the 40 first such verdicts on
#: narrow-far-4253401181 with 8 robots (HiGHS found a point for each), 60 of 1,500 random levels of that shape (a
#: reviewer's test); with 10⁻¹⁴ none, and DAQP's answer is certified optimal on 1,499 of those 1,500 instead of 1,421.
DAQP_SING_TOL = 1e-14
#: What :meth:`_OsqpLevel._exact` returns when DAQP proves a level infeasible (its exit flag −1).
DAQP_INFEASIBLE = "infeasible"
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
    #: levels with at most this many variables (x = [v, q̇]: 4 per planar robot) solve a miss of the warm active set
    #: by DAQP first (:meth:`_exact`): measured up to N = 100 (benchmarks/qp_step.py: no slower than OSQP's coarse
    #: pass there); larger ones go straight to OSQP (dense DAQP costs O(n³) a solve: 20 ms a step at N = 100 when it
    #: solves every step)
    exact_above = 400

    def __init__(self, eps: float, warm: WarmActiveSet | None = None, exact_miss: bool = True) -> None:
        self.eps = float(eps)
        self.exact_miss = exact_miss and importlib.util.find_spec("daqp") is not None
        self.exact_hits = 0
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

    def _exact(self, P: Array, q: Array, A: Array, lo: Array, up: Array) -> ActiveSetResult | str | None:
        """A miss of the warm active set solved by DAQP (dense, dual active-set: exact at a vertex, no iteration
        count to tune), warm-started from the previous step's active set; its answer is verified by the KKT conditions
        (:meth:`WarmActiveSet.certify`, the tolerances of a hit). An answer that does not verify (on ill-conditioned
        levels DAQP's vertex can miss a row by 10⁻⁹–10⁻⁵ where the tolerance is 10⁻⁹) is polished: the exact KKT solve
        on DAQP's active set (:meth:`WarmActiveSet.solve`, as OSQP's answers are). Measured on narrow-far-4253401181
        with 8 robots: 149 of the 173 misses that did not verify did after the polish, instead of going to OSQP,
        which reached its iteration cap on 189 of 225 (1.8 s of 7.9); the same plan, byte for byte, in 6.6 s.
        :data:`DAQP_INFEASIBLE` if DAQP finds the level
        infeasible twice — with the level's P (singularity tolerance :data:`DAQP_SING_TOL`) and again with P = I, f = 0,
        which only asks whether a point exists — so that OSQP does not spend its 20 000 iterations failing to
        converge; None if DAQP fails otherwise or its answer does not verify (OSQP takes over)."""
        import daqp

        m = A.shape[0]
        sense = np.zeros(m, np.int32)
        guess = self.guess if self.guess is not None and self.guess.size == m else None
        if guess is not None:  # DAQP's sense bits: 1 active, 2 at the lower bound (a warm start only)
            sense[guess == 1] = 1
            sense[guess == -1] = 3
        sense[lo == up] = 5  # equality (active, immutable)
        x, _, flag, info = daqp.solve(P, q, A, up, lo, sense, sing_tol=DAQP_SING_TOL)
        if flag == -1:  # confirmed on the same rows with H = I, f = 0: a question of feasibility alone
            n = A.shape[1]
            if daqp.solve(np.eye(n), np.zeros(n), A, up, lo, np.where(lo == up, 5, 0).astype(np.int32))[2] == -1:
                return DAQP_INFEASIBLE
            return None
        if flag < 1 or not np.all(np.isfinite(x)):
            return None
        lam = np.asarray(info["lam"])
        res = self.warm.certify(P, q, A, lo, up, np.asarray(x), lam)
        if res is None:  # DAQP's active set, solved exactly (the tolerance certify classes the multipliers with)
            tol = self.warm.tol * (1.0 + float(np.max(np.abs(q), initial=0.0)))
            res = self.warm.solve(P, q, A, lo, up, active_set(lam, lo, up, tol))
        return res

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
        if self.warm is not None and self.exact_miss and A.shape[1] <= self.exact_above:
            res = self._exact(P, q, A, lo, up)
            if isinstance(res, str):  # DAQP_INFEASIBLE
                return None, "primal infeasible (daqp)", 0
            if res is not None:
                self.guess = res.active
                self.exact_hits += 1
                return res.x, "verified", 0
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
        "daqp": {"sing_tol": DAQP_SING_TOL},
    }

    #: rows within this distance (relative to 1 + |bound|) of a bound are the polishing guess of the active set
    POLISH_ROWS = 1e-7
    #: backends that never warn on a failed solve (no warnings filter needed: it costs a few µs per call)
    SILENT = frozenset({"daqp"})
    #: backends whose own multipliers may prove an answer optimal (:meth:`WarmActiveSet.certify`): an active-set method
    #: stops on a vertex with exact multipliers; interior-point (Clarabel), ADMM (OSQP) and augmented-Lagrangian
    #: (proxqp) answers sit near the bounds with spread multipliers and can pass the test while off by 1e-5: they are
    #: polished
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
        if self.solver in self.CERTIFY:
            y = self._row_multipliers(sol, has_u, has_l, eq)
            if y is not None and self.polish.certify(P, q, A, lo, up, x, y) is not None:
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

    @staticmethod
    def _row_multipliers(
        sol: qpsolvers.Solution, has_u: NDArray[np.bool_], has_l: NDArray[np.bool_], eq: NDArray[np.bool_]
    ) -> Array | None:
        """The backend's multipliers of ``G x ≤ h`` (the rows with an upper bound, then the negated rows with a lower
        one) and of ``Aeq x = beq`` as one multiplier per row of A, positive at the upper bound and negative at the
        lower (:func:`tmr.control.activeset.active_set`'s convention), for :meth:`WarmActiveSet.certify` — the KKT
        conditions a warm hit and the DAQP miss path are verified by. None if the backend gave none."""
        z, y = getattr(sol, "z", None), getattr(sol, "y", None)
        nu, nl, ne = int(has_u.sum()), int(has_l.sum()), int(eq.sum())
        if (nu + nl and (z is None or np.size(z) != nu + nl)) or (ne and (y is None or np.size(y) != ne)):
            return None
        out = np.zeros(eq.size)
        if nu + nl:
            z = np.asarray(z, dtype=float).ravel()
            out[has_u] += z[:nu]
            out[has_l] -= z[nu:]
        if ne:
            out[eq] = np.asarray(y, dtype=float).ravel()
        return out
