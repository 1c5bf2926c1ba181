"""Capacity margin guaranteed along a motion, not only at its samples: a Lipschitz-type lower bound of μ between
samples and adaptive resampling until the bound is positive everywhere (Rasheed 2019 eq. 5-8; our addition).

The executed motion between two consecutive samples q0, q1 (platform P, base positions b_j, headings θ_j) is the
straight interpolation of every coordinate (a differential-drive base either turns in place or drives straight
along its heading; the planner only produces such pieces). Any pose q' of the piece is within the half
displacements ε_P = ‖ΔP‖/2, ε_b = ‖Δb_j‖/2, ε_θ = |Δθ_j|/2 of the nearer sample q. With ψ(q) = min over required
wrench vertices f and all unit directions c of h_q(c) − cᵀf (h_q the support function of the AWS zonotope,
Rasheed 2019 eq. 7), ψ = μ of eq. 8 whenever μ ≥ 0, and μ(q') ≥ ψ(q'). For a cable k of base j:

* cable direction u_k = v/‖v‖, v = A_k − P: ‖Δv‖ ≤ ε_v = ε_b + ε_P (+ ρ_A ε_θ for an exit point off the base axis),
  ‖Δu_k‖ ≤ δu_k = 2 sin(asin(ε_v/‖v‖)/2) (2 when ε_v ≥ ‖v‖);
* tipping bound (eq. 5-6): hi_k = 1/φ_k, φ_k = max(1/t_max, max_o b_o⁺/|a_o|), a_o < 0 the weight moment about edge
  o (independent of the pose), b_o = e_oᵀ((C_o − P) × u_k): |Δb_o| ≤ ε_θ(‖r_o‖ + ε_r) + ε_r + ‖r_o‖ δu_k with
  r_o = C_o − P, ε_r = ε_b + ρ_o ε_θ + ε_P (ρ_o = ‖C_o‖ in the base frame), so |Δφ_k| ≤ Δφ_k = max_o |Δb_o|/|a_o|
  and hi_k' ≥ 1/(φ_k + Δφ_k) = hi_k − hi_k² Δφ_k/(1 + hi_k Δφ_k); the lower bound lo_k = t_min does not move
  (a_o < 0 for a centre of gravity inside the footprint);
* support function (monotone in hi): h_q'(c) ≥ h_q(c) − Σ_k (hi_k δu_k + hi_k² Δφ_k/(1 + hi_k Δφ_k)) =: h_q(c) − Δ
  for every unit c.

Hence μ(q') ≥ μ(q) − Δ(q) on the half piece next to q, and the guaranteed lower bound of the piece is
min(μ0 − Δ0, μ1 − Δ1) (only when μ0, μ1 ≥ 0 and the tension boxes stay non-empty; else −inf). A piece whose bound
is ≤ 0 is bisected (the midpoint is a real pose of the motion) until the bound is positive, a sample has μ ≤ 0
(a real violation), or the piece is shorter than ``min_piece``. See ``formulations/mcdpr_planner.md``.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from tmr.mcdpr.capacity import capacity
from tmr.mcdpr.robot import Robot
from tmr.mcdpr.tipping import tipping

__all__ = ["Certified", "SampleStats", "certify", "interval_bounds", "sample_stats", "wrap"]


def wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles wrapped to [−π, π) [rad]."""
    return np.mod(np.asarray(a, float) + np.pi, 2 * np.pi) - np.pi


class SampleStats(NamedTuple):
    """What the bound needs at each sample (T samples, m cables, p bases, c footprint edges).

    mu (T,) capacity margin [N]; lo, hi (T, m) tipping-tightened tension bounds [N]; vnorm (T, m) exit point to
    platform distance ‖A_k − P‖ [m]; rnorm (T, m, c) distance from the platform to the contact points C_o of the
    cable's base [m]."""

    mu: NDArray[np.float64]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    vnorm: NDArray[np.float64]
    rnorm: NDArray[np.float64]


def sample_stats(
    robot: Robot, P: NDArray[np.float64], B: NDArray[np.float64], H: NDArray[np.float64], rws: NDArray[np.float64]
) -> SampleStats:
    """μ and the per-cable quantities of :class:`SampleStats` at poses P (T, 3), B (T, p, 2), H (T, p)."""
    cap = capacity(robot, P, B, H, rws)
    cb = np.asarray(robot.cable_base)
    c, s = np.cos(H[:, cb]), np.sin(H[:, cb])  # (T, m)
    ex = robot.exit_points
    Bc = B[:, cb]  # (T, m, 2): the base of each cable
    axy = Bc + np.stack([c * ex[:, 0] - s * ex[:, 1], s * ex[:, 0] + c * ex[:, 1]], axis=-1)
    v = np.concatenate([axy, np.broadcast_to(ex[:, 2], axy.shape[:-1])[..., None]], axis=-1) - P[:, None, :]
    fp = robot.footprint
    cx = Bc[..., None, 0] + c[..., None] * fp[:, 0] - s[..., None] * fp[:, 1]
    cy = Bc[..., None, 1] + s[..., None] * fp[:, 0] + c[..., None] * fp[:, 1]
    r = np.stack([cx - P[:, None, None, 0], cy - P[:, None, None, 1], -np.broadcast_to(P[:, None, None, 2], cx.shape)])
    return SampleStats(cap.mu, cap.lo, cap.hi, np.linalg.norm(v, axis=-1), np.sqrt(np.sum(r**2, axis=0)))


@functools.lru_cache(maxsize=32)
def _weight_moments(robot: Robot) -> NDArray[np.float64]:
    """|a_o| (c,) [N·m]: moment of the base weight about each footprint edge (pose-independent, Rasheed 2019 eq. 5)."""
    tip = tipping(robot, np.array([0.0, 0.0, 1.0]), np.zeros((robot.n_bases, 2)) + [[10.0, 0.0]], None)
    return np.abs(tip.a[0])


def half_bound(
    robot: Robot, st: SampleStats, eps_p: NDArray[np.float64], eps_b: NDArray[np.float64], eps_t: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Guaranteed lower bound μ − Δ [N] over all poses within the displacements of the samples of ``st``.

    eps_p (T,) platform [m], eps_b (T, p) base positions [m], eps_t (T, p) headings [rad]; −inf where μ < 0 or a
    tension box could empty."""
    cb = np.asarray(robot.cable_base)
    eb, et = eps_b[:, cb], eps_t[:, cb]  # (T, m)
    rho_a = np.hypot(robot.exit_points[:, 0], robot.exit_points[:, 1])
    ev = eb + eps_p[:, None] + rho_a * et
    x = ev / st.vnorm
    du = np.where(x < 1.0, 2.0 * np.sin(0.5 * np.arcsin(np.minimum(x, 1.0))), 2.0)
    rho_o = np.hypot(robot.footprint[:, 0], robot.footprint[:, 1])  # (c,)
    er = eb[..., None] + rho_o * et[..., None] + eps_p[:, None, None]  # (T, m, c)
    db = et[..., None] * (st.rnorm + er) + er + st.rnorm * du[..., None]
    a = _weight_moments(robot)  # (c,): the same for every base
    dphi = np.max(db / a, axis=-1)  # (T, m)
    hi = np.where(np.isfinite(st.hi), st.hi, 0.0)
    dhi = hi * hi * dphi / (1.0 + hi * dphi)  # hi − 1/(φ + Δφ): only a smaller bound can shrink the AWS
    delta = np.sum(hi * du + dhi, axis=-1)
    ok = (st.mu >= 0) & np.all(hi - dhi >= st.lo, axis=-1)
    return np.where(ok, st.mu - delta, -np.inf)


def interval_bounds(
    robot: Robot, st: SampleStats, P: NDArray[np.float64], B: NDArray[np.float64], H: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Guaranteed lower bound of μ [N] on each of the T − 1 straight pieces between consecutive samples."""
    if len(P) < 2:
        return np.zeros(0)
    ep = 0.5 * np.linalg.norm(np.diff(P, axis=0), axis=-1)  # (T-1,)
    eb = 0.5 * np.linalg.norm(np.diff(B, axis=0), axis=-1)  # (T-1, p)
    et = 0.5 * np.abs(wrap(np.diff(H, axis=0)))
    sl0 = SampleStats(*(f[:-1] for f in st))
    sl1 = SampleStats(*(f[1:] for f in st))
    return np.minimum(half_bound(robot, sl0, ep, eb, et), half_bound(robot, sl1, ep, eb, et))


class Certified(NamedTuple):
    """Result of :func:`certify`. P, B, H the refined samples (original samples kept, midpoints inserted);
    origin (T',) index of the original piece each sample starts (the original samples have integer u); u (T',)
    parameter: original sample i at u = i; mu (T',) [N]; lower (T'−1,) guaranteed lower bound of μ per piece [N];
    ok: every piece's bound > 0; fail: index (into the refined samples) of the first piece that could not be
    certified, or −1; violated: a sample with μ ≤ 0 was found (a real violation, not only an unproven piece)."""

    P: NDArray[np.float64]
    B: NDArray[np.float64]
    H: NDArray[np.float64]
    u: NDArray[np.float64]
    mu: NDArray[np.float64]
    lower: NDArray[np.float64]
    hi: NDArray[np.float64]
    ok: bool
    fail: int
    violated: bool


def certify(
    robot: Robot,
    P: NDArray[np.float64],
    B: NDArray[np.float64],
    H: NDArray[np.float64],
    rws: NDArray[np.float64],
    min_piece: float = 1e-3,
    max_samples: int = 200_000,
    frac: float = 0.5,
    skip: NDArray[np.bool_] | None = None,
) -> Certified:
    """Bisect the pieces of the motion (P (T, 3), B (T, p, 2), H (T, p)) until μ's lower bound on every piece is at
    least ``frac`` × the smaller μ of its two end samples (so > 0: certified, and not much below the samples).

    ``min_piece`` [m or rad]: pieces whose largest displacement is below it are not split further (they stay
    uncertified if their bound is ≤ 0). Pieces with an end sample at μ ≤ 0 are not split (a real violation).
    ``skip`` (T − 1,) marks pieces that are not motions (the junctions of several motions certified in one batch):
    their bound is +inf and they are never split."""
    P = np.asarray(P, float)
    B = np.asarray(B, float)
    H = np.asarray(H, float)
    u = np.arange(len(P), dtype=float)
    st = sample_stats(robot, P, B, H, rws)
    skip = np.zeros(max(len(P) - 1, 0), bool) if skip is None else np.asarray(skip, bool).copy()
    while True:
        low = np.where(skip, np.inf, interval_bounds(robot, st, P, B, H))
        size = np.maximum(
            np.linalg.norm(np.diff(P, axis=0), axis=-1),
            np.maximum(np.linalg.norm(np.diff(B, axis=0), axis=-1), np.abs(wrap(np.diff(H, axis=0)))).max(axis=-1),
        )
        ends_ok = (st.mu[:-1] > 0) & (st.mu[1:] > 0)
        target = frac * np.minimum(st.mu[:-1], st.mu[1:])
        split = np.flatnonzero(~(low >= target) & ends_ok & (size > min_piece))
        if not len(split) or len(P) + len(split) > max_samples:
            break
        Pm = 0.5 * (P[split] + P[split + 1])
        Bm = 0.5 * (B[split] + B[split + 1])
        Hm = wrap(H[split] + 0.5 * wrap(H[split + 1] - H[split]))
        stm = sample_stats(robot, Pm, Bm, Hm, rws)
        at = split + 1
        P = np.insert(P, at, Pm, axis=0)
        B = np.insert(B, at, Bm, axis=0)
        H = np.insert(H, at, Hm, axis=0)
        u = np.insert(u, at, 0.5 * (u[split] + u[split + 1]))
        skip = np.insert(skip, at, False)
        st = SampleStats(*(np.insert(a, at, b, axis=0) for a, b in zip(st, stm, strict=True)))
    bad = np.flatnonzero(~(low > 0))
    return Certified(
        P=P,
        B=B,
        H=H,
        u=u,
        mu=st.mu,
        lower=low,
        hi=st.hi,
        ok=not len(bad),
        fail=int(bad[0]) if len(bad) else -1,
        violated=bool(np.any(~(st.mu > 0))),
    )
