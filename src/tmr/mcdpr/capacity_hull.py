"""Independent check of the AWS and capacity margin: vertex enumeration + convex hull (scipy/Qhull).

The tension polytope {t : A t ≤ b} (Rasheed 2019 eq. 4, 6) is enumerated vertex by vertex (every choice of m active
rows, vectorised), its vertices are mapped through W (eq. 2) and Qhull builds the convex hull, i.e. the AWS (eq. 7)
in H-representation. μ (eq. 8) is the smallest signed distance of an RWS vertex to a hull facet. Shares no code with
the hyperplane-shifting and LP paths, which is the point; O(C(r, m)) so only for checks and benchmarks.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull

__all__ = ["box_rows", "capacity_margin_hull", "polytope_vertices"]


def box_rows(lo: ArrayLike, hi: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rows A t ≤ b of the box lo ≤ t ≤ hi (m,) [N]."""
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    eye = np.eye(len(lo))
    return np.concatenate([eye, -eye]), np.concatenate([hi, -lo])


def polytope_vertices(A: ArrayLike, b: ArrayLike, tol: float = 1e-9) -> NDArray[np.float64]:
    """Vertices (k, m) of {t : A t ≤ b} by solving every m×m subsystem of active rows; duplicates removed."""
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    m = A.shape[1]
    idx = np.array(list(combinations(range(len(A)), m)))
    As = A[idx]
    bs = b[idx]
    det = np.linalg.det(As)
    ok = np.abs(det) > 1e-12
    V = np.linalg.solve(As[ok], bs[ok][..., None])[..., 0]
    scale = 1.0 + np.abs(b).max()
    feas = np.all(V @ A.T <= b + tol * scale, axis=1)
    V = V[feas]
    if len(V) == 0:
        return V
    _, keep = np.unique(np.round(V / scale, 9), axis=0, return_index=True)
    return V[np.sort(keep)]


def capacity_margin_hull(W: ArrayLike, A: ArrayLike, b: ArrayLike, rws: ArrayLike) -> float:
    """μ [N] of one pose via vertex enumeration and Qhull; −inf for an empty tension polytope.

    Raises scipy's QhullError when the AWS is flat (W of rank < 3).
    """
    V = polytope_vertices(A, b)
    if len(V) == 0:
        return -np.inf
    pts = V @ np.asarray(W, dtype=float).T
    hull = ConvexHull(pts)
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]
    F = np.asarray(rws, dtype=float)
    return float(np.min(-offsets[:, None] - normals @ F.T))
