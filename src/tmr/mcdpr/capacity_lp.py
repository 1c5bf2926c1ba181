"""Available wrench set and capacity margin, general path: one support-function LP per facet normal (cvxpy).

For tension constraints A t ≤ b of any form (box eq. 4 and tipping eq. 6, possibly coupling several cables of one
base), the AWS {W t : A t ≤ b} (Rasheed 2019 eq. 7) is the linear image of a polytope. Each of its facets is spanned
by images W d of edge directions d of the tension polytope, and every edge direction is the null vector of m − 1
constraint rows. :func:`candidate_normals` builds all such normals c = W d_1 × W d_2; the support
h(c) = max {cᵀ W t : A t ≤ b} is one LP (:class:`SupportLP`, DPP with cvxpy Parameters, compiled once, solved with
HiGHS). μ = min over RWS vertices and normals of h(c) − cᵀ f (eq. 8). For one cable per base the candidate normals are
exactly the zonotope normals of :mod:`tmr.mcdpr.capacity`, so both paths agree; with coupled rows some candidates
may be supporting planes that are not facets, which leaves μ exact when it is ≥ 0 and keeps its sign otherwise.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.mcdpr.errors import McdprError, ParameterError
from tmr.mcdpr.robot import Robot
from tmr.mcdpr.tipping import constraint_rows, tipping

__all__ = ["SupportLP", "candidate_normals", "capacity_lp", "capacity_margin_lp"]

_DECIMALS = 10


def _unique_directions(X: NDArray[np.float64], tol: float = 1e-10) -> NDArray[np.float64]:
    """Unit rows of X, zero rows dropped, one per direction up to sign (first non-zero entry positive)."""
    n = np.linalg.norm(X, axis=1)
    X = X[n > tol] / n[n > tol, None]
    if len(X) == 0:
        return X
    lead = np.argmax(np.abs(X) > 1e-9, axis=1)
    X = X * np.sign(X[np.arange(len(X)), lead])[:, None]
    _, idx = np.unique(np.round(X, _DECIMALS), axis=0, return_index=True)
    return X[np.sort(idx)]


def candidate_normals(W: ArrayLike, A: ArrayLike) -> NDArray[np.float64]:
    """Unit normals (K, 3), in ± pairs, containing every facet normal of {W t : A t ≤ b} for W (3, m), A (r, m)."""
    W = np.asarray(W, dtype=float)
    A = np.asarray(A, dtype=float)
    m = W.shape[1]
    rows = _unique_directions(A)
    edges = []
    for combo in combinations(range(len(rows)), m - 1):
        _, s, vt = np.linalg.svd(rows[list(combo)])
        if s[-1] > 1e-9 * s[0]:
            edges.append(vt[-1])
    if not edges:
        raise ParameterError("the tension constraints have no edge directions (fewer than m−1 independent rows)")
    images = _unique_directions(np.array(edges) @ W.T)
    pairs = np.array(list(combinations(range(len(images)), 2)))
    if len(pairs) == 0:
        raise ParameterError("the wrench matrix maps the tension polytope to a segment: no facets in 3D")
    normals = _unique_directions(np.cross(images[pairs[:, 0]], images[pairs[:, 1]]))
    return np.stack([normals, -normals], axis=1).reshape(-1, 3)


class SupportLP:
    """max gᵀ t s.t. A t ≤ b, with g, A, b cvxpy Parameters (DPP: compiled once, re-solved with new values).

    ``m`` cables, ``r`` constraint rows. ``solver`` defaults to HiGHS (simplex: vertex solutions, ~1e-12 accurate).
    """

    def __init__(self, m: int, r: int, solver: str = "HIGHS") -> None:
        import cvxpy as cp  # lazily: a 1-5 s import most runs do not need

        self.t = cp.Variable(m)
        self.g = cp.Parameter(m)
        self.A = cp.Parameter((r, m))
        self.b = cp.Parameter(r)
        self.problem = cp.Problem(cp.Maximize(self.g @ self.t), [self.A @ self.t <= self.b])
        if not self.problem.is_dpp():  # pragma: no cover - structural guarantee
            raise McdprError("support LP is not DPP")
        self.solver = solver

    def support(self, g: ArrayLike, A: ArrayLike, b: ArrayLike) -> tuple[float, NDArray[np.float64] | None]:
        """(max gᵀ t, argmax t) [N]; (−inf, None) if the constraints are infeasible."""
        import cvxpy as cp  # lazily: a 1-5 s import most runs do not need

        self.g.value = np.asarray(g, dtype=float)
        self.A.value = np.asarray(A, dtype=float)
        self.b.value = np.asarray(b, dtype=float)
        self.problem.solve(solver=self.solver)
        if self.problem.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
            return -np.inf, None
        if self.problem.status != cp.OPTIMAL:
            raise McdprError(f"support LP failed with status {self.problem.status}")
        t = np.asarray(self.t.value, dtype=float)
        return float(self.g.value @ t), t


_LP_CACHE: dict[tuple[int, int, str], SupportLP] = {}


def _support_lp(m: int, r: int, solver: str) -> SupportLP:
    key = (m, r, solver)
    if key not in _LP_CACHE:
        _LP_CACHE[key] = SupportLP(m, r, solver)
    return _LP_CACHE[key]


def capacity_margin_lp(
    W: ArrayLike, A: ArrayLike, b: ArrayLike, rws: ArrayLike, solver: str = "HIGHS"
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """μ [N] of one pose (Rasheed 2019 eq. 8) from support LPs; also the normals (K, 3) and supports h (K,) [N].

    ``W`` (3, m), constraints ``A`` (r, m) t ≤ ``b`` (r,), ``rws`` (V, 3). An empty tension polytope gives −inf.
    """
    W = np.asarray(W, dtype=float)
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    N = candidate_normals(W, A)
    lp = _support_lp(W.shape[1], A.shape[0], solver)
    h = np.empty(len(N))
    for i, c in enumerate(N):
        h[i], t = lp.support(W.T @ c, A, b)
        if t is None:
            return -np.inf, N, np.full(len(N), -np.inf)
        h[i] = float(c @ (W @ t))
    F = np.asarray(rws, dtype=float)
    return float(np.min(h[:, None] - N @ F.T)), N, h


def capacity_lp(
    robot: Robot, platform: ArrayLike, bases: ArrayLike, heading: ArrayLike | None, rws: ArrayLike
) -> NDArray[np.float64]:
    """μ (B,) [N] for a batch of poses through the LP path; works for coupled tipping constraints (eq. 5-8)."""
    P = np.atleast_2d(np.asarray(platform, dtype=float))
    Bs = np.asarray(bases, dtype=float).reshape(-1, robot.n_bases, 2)
    n = max(len(P), len(Bs))
    P = np.broadcast_to(P, (n, 3))
    Bs = np.broadcast_to(Bs, (n, robot.n_bases, 2))
    H = None
    if heading is not None:
        H = np.broadcast_to(np.asarray(heading, float).reshape(-1, robot.n_bases), Bs.shape[:-1])
    mu = np.empty(n)
    for i in range(n):
        tip = tipping(robot, P[i], Bs[i], None if H is None else H[i])
        A, b = constraint_rows(robot, tip)
        mu[i] = capacity_margin_lp(tip.W, A, b, rws)[0]
    return mu
