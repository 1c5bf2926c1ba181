"""Tipping moments of the mobile bases about their footprint edges (Rasheed 2019 eq. 5-6).

For base j with footprint contact points C_o (anticlockwise), edge direction e_o = (C_{o+1} − C_o)/‖·‖, weight
w_g = (0, 0, −M g) at the centre of gravity G, and cable k of that base pulling its exit point towards the platform
with tension t_k along −u_k, the moment about edge o is (Rasheed 2019 eq. 5)

    m_o = e_oᵀ((G − C_o) × w_g) + Σ_k e_oᵀ((C_o − P) × u_k) t_k  =  a_o + Σ_k B_ok t_k,

and static equilibrium needs m_o ≤ 0 for every edge (eq. 6). These are linear inequalities B t ≤ −a in the
tensions. With one cable per base each inequality involves a single tension, so it is a pose-dependent bound on
that tension (:func:`tension_bounds`); several cables per base couple them (:func:`constraint_rows`, general path).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.mcdpr.errors import ParameterError
from tmr.mcdpr.robot import Robot
from tmr.mcdpr.wrench import wrench_matrix

__all__ = ["Tipping", "constraint_rows", "tension_bounds", "tipping"]


class Tipping(NamedTuple):
    """Tipping moments m = a + B t about every footprint edge of every base (Rasheed 2019 eq. 5).

    a: (..., p, c) moment of the base weight [N·m] (< 0 when the CoG projects inside the footprint).
    B: (..., p, c, m) moment per newton of cable tension [N·m/N] (zero for cables of other bases).
    W: (..., 3, m) the wrench matrix of the same pose (eq. 3).
    """

    a: NDArray[np.float64]
    B: NDArray[np.float64]
    W: NDArray[np.float64]

    def moments(self, t: ArrayLike) -> NDArray[np.float64]:
        """m_o = a_o + Σ_k B_ok t_k [N·m], shape (..., p, c), for tensions t (..., m) [N]."""
        return self.a + np.einsum("...pcm,...m->...pc", self.B, np.asarray(t, float))


def _rot(heading: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    return np.cos(heading), np.sin(heading)


def tipping(robot: Robot, platform: ArrayLike, bases: ArrayLike, heading: ArrayLike | None = None) -> Tipping:
    """Tipping-moment coefficients of every base edge for a batch of poses (Rasheed 2019 eq. 5).

    ``platform`` (..., 3) [m], ``bases`` (..., p, 2) [m], ``heading`` (..., p) [rad] (default 0) orients each
    footprint. Returns :class:`Tipping` with a (..., p, c), B (..., p, c, m), W (..., 3, m).
    """
    b = np.asarray(bases, dtype=float)
    P = np.asarray(platform, dtype=float)
    if P.shape[-1:] != (3,) or b.ndim < 2:
        raise ParameterError(f"platform must be (..., 3) and bases (..., p, 2), got {P.shape} and {b.shape}")
    lead = np.broadcast_shapes(P.shape[:-1], b.shape[:-2])
    b = np.broadcast_to(b, (*lead, *b.shape[-2:]))
    P = np.broadcast_to(P, (*lead, 3))
    W = wrench_matrix(robot, P, b, heading)
    shape = b.shape[:-1]  # (..., p)
    th = np.zeros(shape) if heading is None else np.broadcast_to(np.asarray(heading, float), shape)
    c, s = _rot(th)
    fp = robot.footprint  # (c, 2)
    # contact points in the world, (..., p, c, 3) with z = 0
    cx = b[..., None, 0] + c[..., None] * fp[:, 0] - s[..., None] * fp[:, 1]
    cy = b[..., None, 1] + s[..., None] * fp[:, 0] + c[..., None] * fp[:, 1]
    C = np.stack([cx, cy, np.zeros_like(cx)], axis=-1)
    E = np.roll(C, -1, axis=-2) - C
    E /= np.linalg.norm(E, axis=-1, keepdims=True)
    gx = b[..., 0] + c * robot.cog[0] - s * robot.cog[1]
    gy = b[..., 1] + s * robot.cog[0] + c * robot.cog[1]
    G = np.stack([gx, gy, np.full_like(gx, robot.cog[2])], axis=-1)  # (..., p, 3)
    wg = np.array([0.0, 0.0, -robot.base_mass * robot.gravity])
    a = np.einsum("...i,...i->...", E, np.cross(G[..., None, :] - C, wg))
    # cable part: e_oᵀ((C_o − P) × u_k) for the cables k of base j
    U = np.swapaxes(W, -1, -2)  # (..., m, 3)
    m = robot.n_cables
    B = np.zeros((*a.shape, m))
    for k, j in enumerate(robot.cable_base):
        r = C[..., j, :, :] - P[..., None, :]  # (..., c, 3)
        B[..., j, :, k] = np.einsum("...ci,...ci->...c", E[..., j, :, :], np.cross(r, U[..., k, None, :]))
    return Tipping(a, B, W)


def tension_bounds(robot: Robot, tip: Tipping) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-cable tension bounds tightened by the tipping conditions, (lo, hi) each (..., m) [N].

    Only for one cable per base: the inequality a_o + b_o t_k ≤ 0 (Rasheed 2019 eq. 6) is t_k ≤ −a_o/b_o for
    b_o > 0 and t_k ≥ −a_o/b_o for b_o < 0 (and infeasible for b_o = 0 < a_o, which cannot happen when the CoG
    projects inside the footprint since then a_o < 0). The result is intersected with [t_min, t_max]; lo > hi
    marks an empty interval (no tension keeps that base standing).
    """
    if not robot.one_cable_per_base:
        raise ParameterError("tension_bounds needs one cable per base; use constraint_rows for coupled tipping")
    cb = np.asarray(robot.cable_base)
    a = tip.a[..., cb, :]  # (..., m, c): the edges of the base of cable k
    b = np.stack([tip.B[..., j, :, k] for k, j in enumerate(robot.cable_base)], axis=-2)  # (..., m, c)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = -a / b
    hi = np.minimum(robot.t_max, np.min(np.where(b > 0, ratio, np.inf), axis=-1))
    lo = np.maximum(robot.t_min, np.max(np.where(b < 0, ratio, -np.inf), axis=-1))
    bad = np.any((b == 0) & (a > 0), axis=-1)
    lo = np.where(bad, np.inf, lo)
    return lo, hi


def constraint_rows(robot: Robot, tip: Tipping) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """All tension constraints as rows A t ≤ b: the box t_min ≤ t ≤ t_max (eq. 4) and B t ≤ −a (eq. 6).

    Returns A (..., 2m + p·c, m) and b (..., 2m + p·c). Works for any number of cables per base.
    """
    m = robot.n_cables
    lead = tip.a.shape[:-2]
    eye = np.eye(m)
    Abox = np.broadcast_to(np.concatenate([eye, -eye]), (*lead, 2 * m, m))
    bbox = np.broadcast_to(np.concatenate([np.full(m, robot.t_max), np.full(m, -robot.t_min)]), (*lead, 2 * m))
    Atip = tip.B.reshape(*lead, -1, m)
    btip = -tip.a.reshape(*lead, -1)
    return np.concatenate([Abox, Atip], axis=-2), np.concatenate([bbox, btip], axis=-1)
