"""Available wrench set and capacity margin, fast exact path: zonotope hyperplane shifting (Rasheed 2019 eq. 7-8).

With one cable per base the tipping conditions (eq. 6) are per-cable bounds (:func:`tmr.mcdpr.tipping.tension_bounds`),
so the available wrench set (AWS, eq. 7) is the zonotope A = {W t : lo ≤ t ≤ hi}. For n = 3 its facet normals are the
cross products c = w_i × w_k of every pair of columns, and the support in direction c is
h(c) = Σ_l max(cᵀw_l · hi_l, cᵀw_l · lo_l) (hyperplane shifting, Bouchard/Gosselin; Guay 2014). The capacity margin is
μ = min over required-wrench vertices f_d and facets (c_l, h_l) of the signed distance h_l − c_lᵀ f_d (eq. 8): μ > 0
iff every vertex of the required wrench set (RWS) lies strictly inside the AWS. Everything is vectorised over a batch
of poses. See ``formulations/capacity.md``.
"""

from __future__ import annotations

from itertools import combinations, product
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.mcdpr.errors import ParameterError
from tmr.mcdpr.robot import Robot
from tmr.mcdpr.tipping import tension_bounds, tipping

__all__ = [
    "Capacity",
    "aws_hrep",
    "capacity",
    "capacity_margin",
    "required_wrench_set",
]

#: Column pairs whose cross product is shorter than this are parallel (no facet of their own).
PARALLEL_TOL = 1e-12


def required_wrench_set(
    robot: Robot, external: ArrayLike = (0.0, 0.0, 0.0), external_lo: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Vertices (V, 3) [N] of the required wrench set: what the cables must apply to hold the platform.

    Static equilibrium W t + w_p + w_e = 0 (Rasheed 2019 eq. 2) with platform weight w_p = (0, 0, −m_p g) and an
    external wrench w_e in the box [external_lo, external] (default symmetric ±external) gives the required cable
    wrench f = −w_p − w_e. Duplicate vertices (zero-width box sides) are removed; the order is deterministic.
    """
    hi = np.asarray(external, dtype=float)
    lo = -hi if external_lo is None else np.asarray(external_lo, dtype=float)
    if hi.shape != (3,) or lo.shape != (3,) or np.any(lo > hi) or not np.all(np.isfinite(np.r_[lo, hi])):
        raise ParameterError(f"external wrench box must be 3 finite bounds with lo <= hi, got lo={lo}, hi={hi}")
    corners = np.array(list(product(*zip(lo, hi, strict=True))))
    base = np.array([0.0, 0.0, robot.platform_mass * robot.gravity])
    return np.unique(base - corners, axis=0)


def aws_hrep(W: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """H-representation {f : N f ≤ h} of the zonotope {W t : lo ≤ t ≤ hi} (Rasheed 2019 eq. 7), batched.

    ``W`` (..., 3, m), ``lo``/``hi`` (..., m) [N]. Returns unit normals N (..., 2·C(m,2), 3) and offsets h (..., K)
    [N]; rows of parallel column pairs get N = 0, h = +inf (no constraint). Rows come in ± pairs: row 2i is
    w_a × w_b, row 2i+1 its opposite, for the i-th pair (a, b) of ``itertools.combinations(range(m), 2)``.
    """
    W = np.asarray(W, dtype=float)
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    m = W.shape[-1]
    if W.shape[-2] != 3 or m < 2:
        raise ParameterError(f"W must have shape (..., 3, m) with m >= 2, got {W.shape}")
    ia, ib = np.array(list(combinations(range(m), 2))).T
    c = np.cross(np.swapaxes(W[..., :, ia], -1, -2), np.swapaxes(W[..., :, ib], -1, -2))  # (..., P, 3)
    norm = np.linalg.norm(c, axis=-1, keepdims=True)
    ok = norm[..., 0] > PARALLEL_TOL
    c = np.where(ok[..., None], c / np.where(ok[..., None], norm, 1.0), 0.0)
    proj = c @ W  # (..., P, m): cᵀ w_l
    hp = np.sum(np.maximum(proj * hi[..., None, :], proj * lo[..., None, :]), axis=-1)
    hm = -np.sum(np.minimum(proj * hi[..., None, :], proj * lo[..., None, :]), axis=-1)
    hp = np.where(ok, hp, np.inf)
    hm = np.where(ok, hm, np.inf)
    N = np.stack([c, -c], axis=-2).reshape(*c.shape[:-2], -1, 3)
    h = np.stack([hp, hm], axis=-1).reshape(*hp.shape[:-1], -1)
    return N, h


def capacity_margin(W: ArrayLike, lo: ArrayLike, hi: ArrayLike, rws: ArrayLike) -> NDArray[np.float64]:
    """Capacity margin μ [N] (Rasheed 2019 eq. 8) of the zonotope AWS {W t : lo ≤ t ≤ hi}, batched over poses.

    ``rws`` (V, 3) or (..., V, 3) vertices of the required wrench set. μ = min_{d,l} (h_l − N_l f_d): positive iff
    all vertices are strictly inside, negative when one is outside. An empty tension box (lo > hi) gives −inf, and so
    do poses whose columns are all parallel (no column pair spans a facet: the AWS is a segment, no interior in 3D).
    """
    N, h = aws_hrep(W, lo, hi)
    F = np.asarray(rws, dtype=float)
    s = h[..., :, None] - N @ np.swapaxes(F, -1, -2)
    mu = np.min(s, axis=(-2, -1))
    empty = np.any(np.asarray(lo) > np.asarray(hi), axis=-1)
    flat = ~np.any(np.isfinite(h), axis=-1)
    return np.where(empty | flat, -np.inf, mu)


class Capacity(NamedTuple):
    """Capacity margin of a batch of poses and what it was computed from.

    mu: (...) capacity margin [N] (Rasheed 2019 eq. 8). W: (..., 3, m) wrench matrices (eq. 3).
    lo, hi: (..., m) tension bounds tightened by tipping (eq. 4, 6) [N].
    """

    mu: NDArray[np.float64]
    W: NDArray[np.float64]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]


def capacity(
    robot: Robot, platform: ArrayLike, bases: ArrayLike, heading: ArrayLike | None, rws: ArrayLike
) -> Capacity:
    """μ for a batch of poses of a one-cable-per-base robot: W, tipping-tightened bounds, hyperplane shifting.

    ``platform`` (..., 3) [m], ``bases`` (..., p, 2) [m], ``heading`` (..., p) [rad] or None, ``rws`` (V, 3) [N]
    from :func:`required_wrench_set`. For coupled tipping constraints use :mod:`tmr.mcdpr.capacity_lp`.
    """
    if not robot.one_cable_per_base:
        raise ParameterError(
            f"{robot.name}: the fast capacity path needs one cable per base; "
            "use tmr.mcdpr.capacity_lp for coupled tipping"
        )
    tip = tipping(robot, platform, bases, heading)
    lo, hi = tension_bounds(robot, tip)
    return Capacity(capacity_margin(tip.W, lo, hi, rws), tip.W, lo, hi)
