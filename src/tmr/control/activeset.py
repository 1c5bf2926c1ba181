"""Warm active set: solve a QP exactly from a guess of its active constraints, verified by the KKT conditions.

Consecutive control steps solve nearly the same QP, and most of the time the same constraints are active (often only
the equalities). Given a guess W of the active rows (each at its lower or upper bound), the equality-constrained QP

    min ½ xᵀPx + qᵀx   s.t.  A_W x = b_W

is one linear solve of its KKT system ``[P A_Wᵀ; A_W 0] [x; y_W] = [−q; b_W]`` (LAPACK for small problems, SuperLU
through scipy.sparse for large ones). Its solution is the QP's optimum exactly when the KKT conditions hold, and each
is checked on the computed point: stationarity ``P x + q + A_Wᵀ y_W = 0`` and the active rows at their bounds (an
ill-conditioned solve fails here), every row within its bounds (primal feasibility), and every multiplier of the
right sign (y ≥ 0 at an upper bound, y ≤ 0 at a lower bound; free on equalities), with tolerances scaled by the
problem data. If they do not hold, the violated rows are added to W and the rows with wrong-sign multipliers
dropped, for a few rounds (a primal-dual active-set update); a guess with more active rows than unknowns, or a
singular or inaccurate solve, is declined. Then the caller falls back to a general solver (OSQP) and takes its active
set as the next guess. It is OSQP's own "solution
polishing" applied across steps: the guess comes from the previous step instead of from ADMM iterates.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray
from scipy.linalg.lapack import dgesv

Array = NDArray[np.float64]


class ActiveSetResult(NamedTuple):
    """x: primal solution; active: the verified active set (+1 upper, −1 lower, 2 equality, 0 inactive); rounds: KKT
    solves used; y_active: the multipliers of the active rows (in row order); ``y``: of every row (0 on inactive)."""

    x: Array
    active: NDArray[np.int8]
    rounds: int
    y_active: Array

    @property
    def y(self) -> Array:
        y = np.zeros(self.active.size)
        y[np.flatnonzero(self.active)] = self.y_active
        return y


def active_set(y: Array, lo: Array, up: Array, tol: float = 1e-9) -> NDArray[np.int8]:
    """Active set from row multipliers: +1 at the upper bound (y > 0), −1 at the lower (y < 0), 2 equality, 0 free."""
    s = np.where(y > tol, 1, np.where(y < -tol, -1, 0)).astype(np.int8)
    s[lo == up] = 2
    return s


def _sparse_kkt(P: Array | sp.spmatrix, A: Array, d: float) -> sp.csc_matrix:
    """``[P, Aᵀ; A, −d I]`` in CSC, assembled from coordinates in one conversion (``sp.bmat`` converts every block)."""
    n, k = P.shape[0], A.shape[0]
    Pc = P.tocoo() if sp.issparse(P) else sp.coo_matrix(P)
    ar, ac = np.nonzero(A)
    av = A[ar, ac]
    diag = np.arange(n, n + k)
    rows = np.concatenate([Pc.row, ac, ar + n, diag])
    cols = np.concatenate([Pc.col, ar + n, ac, diag])
    data = np.concatenate([Pc.data, av, av, np.full(k, -d)])
    return sp.csc_matrix((data, (rows, cols)), shape=(n + k, n + k))


class WarmActiveSet:
    """KKT solve of a QP from a guessed active set, with a few primal-dual corrections (see the module docstring).

    Args:
        tol: primal feasibility tolerance [row units], and the relative tolerance of the KKT residuals and of the
            multipliers' signs.
        rounds: largest number of KKT solves per call.
        dense_below: problems with fewer variables use dense LAPACK, larger ones SuperLU on the sparse KKT matrix.
        independence_rtol: a row of a degenerate guess within this distance of the span of the kept rows (unit rows,
            projected off the equalities) is dropped from the KKT system.
        huge: a KKT solution with an entry beyond this is declined (a nearly singular system).
        kkt_reg, refinements: regularisation δ and refinement steps of the sparse KKT solve (see ``_kkt``).
    """

    def __init__(
        self,
        tol: float = 1e-9,
        rounds: int = 4,
        dense_below: int = 80,
        independence_rtol: float = 1e-8,
        huge: float = 1e100,
        kkt_reg: float = 1e-10,
        refinements: int = 3,
    ) -> None:
        self.tol, self.rounds, self.dense_below = float(tol), int(rounds), int(dense_below)
        self.independence_rtol, self.huge = float(independence_rtol), float(huge)
        self.kkt_reg, self.refinements = float(kkt_reg), int(refinements)

    def _kkt(self, P: Array | sp.spmatrix, q: Array, A: Array, b: Array) -> tuple[Array, Array, Array] | None:
        """Solve ``[P Aᵀ; A 0][x; y] = [−q; b]``: x, y and the residual ``K z − rhs`` of the system at (x, y).

        None if the KKT matrix is singular (dependent active rows, or no curvature on their null space), or so
        nearly singular that the solution has entries beyond ``huge`` (or non-finite ones): such a vector is never
        multiplied out (it would overflow), and a finite but inaccurate one fails the residual checks of the caller.
        Large problems factor ``[P, Aᵀ; A, −δI]`` (δ = ``kkt_reg``; quasi-definite, so never singular when P is
        positive definite, as the QP's P = Σ w JᵀJ + εI is: SuperLU prints BLAS errors on stderr when it meets an
        exactly singular matrix) and refine the solution against the exact system (up to ``refinements`` steps, as
        OSQP's polish does); dependent active rows then fail the residual checks, or are consistent and harmless.
        """
        n, k = P.shape[0], A.shape[0]
        rhs = np.concatenate([-q, b])
        try:
            if n < self.dense_below:
                P = P.toarray() if sp.issparse(P) else P
                K = np.zeros((n + k, n + k))
                K[:n, :n] = P
                K[:n, n:] = A.T
                K[n:, :n] = A
                _, _, z, info = dgesv(K, rhs)  # LAPACK without the wrapper overhead; K and rhs are kept
                if info != 0:
                    return None
            else:  # quasi-definite regularisation + iterative refinement: SuperLU never sees a singular matrix
                d = self.kkt_reg
                Kd = _sparse_kkt(P, A, d)
                lu = spla.splu(Kd)
                z = lu.solve(rhs)
                small = 1e-3 * self.tol * (1.0 + np.abs(rhs).max())
                for i in range(self.refinements + 1):
                    if not np.abs(z).max() <= self.huge:
                        return None
                    res = Kd @ z - rhs
                    res[n:] += d * z[n:]  # the residual of the exact system K z = rhs
                    if i == self.refinements or np.abs(res).max() <= small:
                        return z[:n], z[n:], res
                    z -= lu.solve(res)
        except (np.linalg.LinAlgError, RuntimeError, ValueError):
            return None  # exactly singular KKT matrix
        if not np.abs(z).max() <= self.huge:
            return None  # nearly singular: a tiny pivot gave huge, infinite or NaN values (NaN compares false)
        return z[:n], z[n:], K @ z - rhs

    @staticmethod
    def _independent(A: Array, st: NDArray[np.int8], rtol: float) -> NDArray[np.bool_]:
        """Which of the active rows ``A`` (kinds ``st``) to keep: every equality, and among the inequalities a
        subset that is linearly independent of them and of each other (pivoted QR of the unit rows projected off the
        equalities; a row within ``rtol`` of the span of the kept ones is dropped).

        At a degenerate vertex (several nearly parallel clearance rows touching at one point, a speed bound on a
        frozen velocity) more rows are at their bounds than the KKT system can take; the dropped ones are checked
        as ordinary rows afterwards.
        """
        keep = st == 2
        ineq = np.flatnonzero(~keep)
        B = A[ineq]
        norm = np.linalg.norm(B, axis=1)
        ok = norm > 0
        ineq, B = ineq[ok], B[ok] / norm[ok, None]
        if not ineq.size:
            return keep
        E = A[keep]
        if E.shape[0]:
            Q, _ = np.linalg.qr(E.T)
            B = B - (B @ Q) @ Q.T
        _, R, piv = scipy.linalg.qr(B.T, mode="economic", pivoting=True)
        d = np.abs(R.diagonal())
        rank = min(int(np.count_nonzero(d > rtol)), A.shape[1] - E.shape[0])
        keep[ineq[piv[:rank]]] = True
        return keep

    def solve(
        self, P: Array | sp.spmatrix, q: Array, A: Array, lo: Array, up: Array, guess: NDArray[np.int8]
    ) -> ActiveSetResult | None:
        """The optimum of ``min ½xᵀPx + qᵀx s.t. lo ≤ Ax ≤ up`` if the guess (corrected a few times) verifies.

        ``P`` may be dense or scipy.sparse; ``A`` is dense. Returns None when the guess does not verify.
        """
        s = guess.copy()
        s[lo == up] = 2
        tol = self.tol
        n = q.size
        qscale = 1.0 + float(np.max(np.abs(q), initial=0.0))  # problem data, never the (maybe garbage) multipliers
        for r in range(1, self.rounds + 1):
            W = np.flatnonzero(s)
            st = s[W]
            has_ineq = bool((st != 2).any())
            sol = self._verified_kkt(P, q, A, lo, up, W, st, has_ineq, qscale) if W.size <= n else None
            if sol is None and has_ineq:  # degenerate guess: keep an independent subset of its rows
                keep = self._independent(A[W], st, self.independence_rtol)
                if not keep.all():
                    s[W[~keep]] = 0  # dropped: checked as ordinary rows below, re-added if violated
                    W, st = W[keep], st[keep]
                    has_ineq = bool((st != 2).any())
                    sol = self._verified_kkt(P, q, A, lo, up, W, st, has_ineq, qscale)
            if sol is None:
                return None
            x, yW = sol
            Ax = A @ x
            viol = np.maximum(lo - Ax, Ax - up)  # every row within its bounds
            feasible = not viol.size or viol.max() <= tol
            wrong = None
            if has_ineq:  # multipliers of the active inequalities must have the sign of their bound
                ytol = tol * qscale
                wrong = ((st == 1) & (yW < -ytol)) | ((st == -1) & (yW > ytol))
                if not wrong.any():
                    wrong = None
            if feasible and wrong is None:
                return ActiveSetResult(x, s, r, yW)
            if wrong is not None:
                s[W[wrong]] = 0
            if not feasible:
                free = s != 2
                s[(Ax < lo - tol) & free] = -1
                s[(Ax > up + tol) & free] = 1
        return None

    def certify(
        self, P: Array | sp.spmatrix, q: Array, A: Array, lo: Array, up: Array, x: Array, y: Array
    ) -> ActiveSetResult | None:
        """A solver's own answer ``x`` with row multipliers ``y`` (positive at an upper bound, negative at a lower one,
        the convention of :func:`active_set`) as a verified optimum: the KKT conditions :meth:`solve` checks on its
        KKT point, with the same tolerances — stationarity ``P x + q + Aᵀy = 0`` relative to q, every row within its
        bounds, and every row with a multiplier beyond the sign tolerance at the bound that multiplier's sign names.
        No solve: the proof for an active-set solver (DAQP) that stopped at a vertex with exact multipliers, where a
        multiplier of 10⁻¹² on a weakly active row would make the set from :func:`active_set` fail to verify.
        None if a condition fails."""
        tol = self.tol
        qscale = 1.0 + float(np.max(np.abs(q), initial=0.0))
        s = active_set(y, lo, up, tol * qscale)
        rows = s != 0
        y = np.where(rows, y, 0.0)  # only rows at a bound carry a multiplier (a tiny one elsewhere proves nothing)
        if not np.abs(P @ x + q + A.T @ y).max(initial=0.0) <= 10 * tol * qscale:
            return None
        Ax = A @ x
        if Ax.size and not np.maximum(lo - Ax, Ax - up).max() <= tol:
            return None
        at = np.where(s == 1, up, lo)
        b = at[rows]
        if b.size and not (np.all(np.isfinite(b)) and np.abs(Ax[rows] - b).max() <= tol * (1.0 + np.abs(b).max())):
            return None  # a multiplier on a row away from the bound it names (or naming a bound the row lacks)
        return ActiveSetResult(x, s, 0, y[rows])

    def _verified_kkt(
        self,
        P: Array | sp.spmatrix,
        q: Array,
        A: Array,
        lo: Array,
        up: Array,
        W: NDArray[np.intp],
        st: NDArray[np.int8],
        has_ineq: bool,
        qscale: float,
    ) -> tuple[Array, Array] | None:
        """x and the multipliers of the rows W (kinds ``st``) at their bounds, if the KKT solve is accurate."""
        b = np.where(st == 1, up[W], lo[W]) if has_ineq else lo[W]  # equalities: lo = up
        sol = self._kkt(P, q, A[W], b)
        if sol is None:
            return None
        x, yW, res = sol
        # the KKT point itself: stationarity P x + q + A_Wᵀ y = 0 relative to q, and the active rows at their bounds
        # relative to b (never relative to y: an ill-conditioned system, e.g. nearly parallel active rows, gives huge
        # multipliers and fails here instead of passing garbage on)
        n = q.size
        if not np.abs(res[:n]).max() <= 10 * self.tol * qscale:
            return None
        if W.size and not np.abs(res[n:]).max() <= self.tol * (1.0 + np.abs(b).max()):
            return None
        return x, yW
