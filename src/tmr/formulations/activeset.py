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


class WarmActiveSet:
    """KKT solve of a QP from a guessed active set, with a few primal-dual corrections (see the module docstring).

    Args:
        tol: primal feasibility tolerance [row units], and the relative tolerance of the KKT residuals and of the
            multipliers' signs.
        rounds: largest number of KKT solves per call.
        dense_below: problems with fewer variables use dense LAPACK, larger ones SuperLU on the sparse KKT matrix.
    """

    def __init__(self, tol: float = 1e-9, rounds: int = 4, dense_below: int = 80) -> None:
        self.tol, self.rounds, self.dense_below = float(tol), int(rounds), int(dense_below)

    def _kkt(self, P: Array | sp.spmatrix, q: Array, A: Array, b: Array) -> tuple[Array, Array, Array] | None:
        """Solve ``[P Aᵀ; A 0][x; y] = [−q; b]``: x, y and the residual ``K z − rhs`` of the system at (x, y)."""
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
            else:
                As = sp.csr_matrix(A)
                K = sp.bmat([[sp.csr_matrix(P), As.T], [As, None]], format="csc")
                z = spla.splu(K).solve(rhs)
        except (np.linalg.LinAlgError, RuntimeError, ValueError):
            return None  # singular KKT matrix: dependent active rows or no curvature on their null space
        return z[:n], z[n:], K @ z - rhs

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
            if W.size > n:
                return None  # more active rows than unknowns: degenerate, multipliers not unique
            st = s[W]
            has_ineq = bool((st != 2).any())
            b = np.where(st == 1, up[W], lo[W]) if has_ineq else lo[W]  # equalities: lo = up
            sol = self._kkt(P, q, A[W], b)
            if sol is None:
                return None
            x, yW, res = sol
            # the KKT point itself: stationarity P x + q + A_Wᵀ y = 0 relative to q, and the active rows at their
            # bounds relative to b (never relative to y: an ill-conditioned system, e.g. nearly parallel active rows,
            # gives huge multipliers and fails here instead of passing garbage on; NaN compares false and fails too)
            if not np.max(np.abs(res[:n])) <= 10 * tol * qscale:
                return None
            if W.size and not np.max(np.abs(res[n:])) <= tol * (1.0 + float(np.max(np.abs(b)))):
                return None
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
