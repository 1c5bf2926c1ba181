"""The least winch tension schedule of a drone horizon plan (an active winch; ``formulations/horizon3d.md``,
"Active winch").

The horizon NLP (:mod:`tmr.control.horizon3d`) optimises the drones' positions under the ``qp`` plan's tension
schedule, held. With the positions chosen, every tether's tension is then chosen here, as the ground chain's horizon
does (:func:`tmr.control.winch.least_tension_schedule`):

1. per tether j and knot k the least tension T*_jk in [min(T_ref, T^qp_jk), T^qp_jk] at which the tether between its
   two (optimised) ends keeps the NLP's own tether limits (:class:`TetherRule`): a catenary exists on its stable
   branch (``catenary3d.solve3d``), its arc length ≤ L_max − length margin, its lowest point above the floor row,
   its whole curve c_t + d_safe from the obstacles (exact distances, :func:`tmr.control.horizon3d_field.
   exact_distance`, with the sampling margin), and with an upper winch the lower end's tension ≥ 0.05 N. A higher
   tension shortens the cable and lifts its sag, so the rule is taken as monotone and T* is found by bisection
   (the upper end of the final bracket, a tension that passed);
2. the rate-bounded least envelope T_k = max(T_ref, max_i (T*_i − rate Ts |k − i|)) (:func:`tmr.control.winch.
   rate_bounded_envelope`), capped by the held qp schedule (a minimum of two rate-bounded sequences is one);
3. the rule evaluated at the schedule itself (where the monotone assumption failed, T* is raised to the held tension
   and 2 repeats).

The result lies in [T_min, T_max] (between min(T_ref, T^qp) and T^qp), changes by at most rate Ts per step and is ≤
the held schedule at every knot; the pull on the drones (T_A = T, T_B = T + ρ g dh) is then no larger than under the
held one. The caller hands the plan at that schedule to the independent checker and keeps the held one if it fails.

Public API: :class:`TetherRule`, :func:`least_drone_tensions`, :func:`thrust_need`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.control.horizon3d_field import exact_distance
from tmr.control.winch import rate_bounded_envelope
from tmr.errors import ParameterError

Array = NDArray[np.float64]

__all__ = ["TetherRule", "least_drone_tensions", "thrust_need", "UPPER_END_MARGIN", "SAMPLE_SPACING", "TENSION_TOL"]

#: With an upper winch, the least tension the lower end keeps [N] (as :class:`tmr.control.drones.WinchUpperEnd`).
UPPER_END_MARGIN = 0.05
#: Arc spacing of the curve samples whose exact clearance the rule reads [m]; half of it is added as the sampling
#: margin (every point of the curve lies within half a spacing of a sample, :meth:`Catenary3D.points`).
SAMPLE_SPACING = 0.01
#: Width of the bisection's final bracket [N].
TENSION_TOL = 1e-3


@dataclass(frozen=True)
class TetherRule:
    """The limits a tether keeps at a tension, with the planner's clearances (the horizon NLP's tether rows, with the
    exact obstacle distance in place of its spline field).

    Attributes:
        world: the room and obstacles (:class:`tmr.world.world3d.World3D`; its radius is not used).
        tether: the :class:`tmr.model.catenary3d.DroneTetherParams` (ρ g, which end holds the winch).
        length_max: arc length ≤ this [m] (L_max − length margin).
        floor: (tether 1, every other tether): the lowest point of the curve at or above this height [m] (−inf:
            none).
        clearance: (tether 1, every other tether): the whole curve at least this far from the obstacles [m]
            (c_t + d_safe; tether 1's no more than its winch's own clearance allows).
        walls: the room's six faces count as obstacles too (else the floor row and the drones' bounds keep them).
        spacing: arc spacing of the clearance samples [m].
    """

    world: Any
    tether: Any
    length_max: float
    floor: tuple[float, float]
    clearance: tuple[float, float]
    walls: bool = False
    spacing: float = SAMPLE_SPACING

    @classmethod
    def of_problem(cls, world: Any, tether: Any, params: Any, base: Array, walls: bool = False) -> TetherRule:
        """The horizon NLP's tether rows (:class:`tmr.control.horizon3d`) for ``world``, ``tether`` and the planner's
        ``params`` (:class:`tmr.model.params.DroneParams`: ``d_safe``, ``length_margin``) with the ground winch at
        ``base`` (3,) [m]: length ≤ L_max − length margin; lowest point ≥ floor + c_t + d_safe (none if ``walls``:
        the faces are obstacles then); clearance c_t + d_safe, tether 1's no more than its winch's own clearance
        − 2 mm (+ d_safe) and its floor no higher than the winch's height above the floor − 2 mm (as the NLP and the
        checker)."""
        b = np.asarray(world.bounds, dtype=float)
        base = np.asarray(base, dtype=float)
        c_t, d_safe = float(tether.clearance), float(params.d_safe)
        base_clear = float(exact_distance(world, base[None], c_t + 1.0, walls=walls)[0])
        base_room = float(np.min(np.r_[base - b[:3], b[3:] - base]))
        floor0 = -math.inf if walls else float(b[2] + c_t + d_safe)
        return cls(
            world=world, tether=tether, length_max=float(tether.tether_length - params.length_margin),
            floor=(min(floor0, float(b[2]) + base_room - 0.002), floor0),
            clearance=(min(c_t, base_clear - 0.002) + d_safe, c_t + d_safe), walls=walls,
        )  # fmt: skip

    def holds(self, p: Array, q: Array, j: Array, tension: Array) -> NDArray[np.bool_]:
        """Whether tether ``j[m]`` between ``p[m]`` and ``q[m]`` (M, 3) [m] keeps every limit at ``tension[m]`` [N],
        (M,) bool; the clearance of all M curves is one distance query."""
        from tmr.model.catenary3d import solve3d

        M = len(j)
        ok = np.ones(M, dtype=bool)
        w = float(self.tether.weight_per_length)
        upper = self.tether.winch_end == "upper"
        pts: list[Array] = []
        owner: list[Array] = []
        need = np.zeros(M)
        for m in range(M):
            jj = min(int(j[m]), 1)  # tether 1, or any other
            if upper and float(tension[m]) - w * abs(float(q[m, 2] - p[m, 2])) < UPPER_END_MARGIN:
                ok[m] = False
                continue
            try:
                cat = solve3d(p[m], q[m], self.tether, winch_tension=float(tension[m]))
            except ParameterError:  # TetherSpanError: no catenary at this tension
                ok[m] = False
                continue
            if cat.length > self.length_max or cat.lowest[2] < self.floor[jj]:
                ok[m] = False
                continue
            n = max(2, int(math.ceil(cat.length / self.spacing)) + 1)
            pts.append(cat.points(n))
            owner.append(np.full(n, m))
            need[m] = self.clearance[jj] + cat.length / (2.0 * (n - 1))
        if pts:
            X, who = np.vstack(pts), np.concatenate(owner)
            cap = float(np.max(self.clearance)) + 1.0
            d = exact_distance(self.world, X, cap, walls=self.walls)
            low = np.full(M, np.inf)
            np.minimum.at(low, who, d)
            ok &= low >= need
        return ok


def _need(rule: TetherRule, ends: Array, lo: Array, hi: Array, tol: float) -> Array:
    """Per knot and tether (K+1, N) the least tension [N] in [lo, hi] at which the rule holds: ``lo`` where it holds
    there, else the upper end of a bisection bracket narrower than ``tol`` [N]; ``hi`` (the held tension, which the
    NLP kept the limits at) where the rule fails even at ``hi``."""
    K1, N = lo.shape
    kk, jj = np.meshgrid(np.arange(K1), np.arange(N), indexing="ij")
    kk, jj = kk.ravel(), jj.ravel()
    P, Q = ends[kk, jj], ends[kk, jj + 1]
    a, b = lo.ravel().copy(), hi.ravel().copy()
    out = a.copy()
    test = np.flatnonzero(b > a)
    bad = bad0 = test[~rule.holds(P[test], Q[test], jj[test], a[test])]
    while bad.size:  # invariant: the rule fails at a, is taken to hold at b
        mid = 0.5 * (a[bad] + b[bad])
        good = rule.holds(P[bad], Q[bad], jj[bad], mid)
        b[bad[good]] = mid[good]
        a[bad[~good]] = mid[~good]
        bad = bad[b[bad] - a[bad] > tol]
    out[bad0] = b[bad0]
    return out.reshape(K1, N)


def least_drone_tensions(
    rule: TetherRule, base: Array, robots: Array, held: Array, t_ref: float, rate: float, Ts: float,
    tol: float = TENSION_TOL, max_passes: int = 4,
) -> tuple[Array, dict[str, Any]]:  # fmt: skip
    """The least rate-bounded winch tensions (K+1, N) [N] for drone positions ``robots`` (K+1, N, 3) [m] already
    chosen under the ``held`` schedule (K+1, N) [N] (module docstring).

    Args:
        rule: the tether limits (:class:`TetherRule`).
        base: the ground winch (3,) [m]; tether j joins point j−1 and drone j (point 0 the winch).
        held: the schedule the positions were optimised under (the qp plan's), within range and rate.
        t_ref: the winch's nominal tension [N]: the schedule rests there where nothing needs more.
        rate: the winch's largest |dT/dt| [N/s]; Ts: the step [s].
        tol: bisection bracket [N]; max_passes: envelope passes at most (step 3 of the module docstring).

    Returns:
        (schedule, info): ``info`` has ``need`` (K+1, N) [N] the per-knot least tensions, ``passes`` and ``raised``
        (knots whose need was raised to the held tension because the rule failed above T*), ``unverified`` (tether
        knots where the rule fails even at the returned schedule; 0 when every knot was verified).
    """
    held = np.asarray(held, dtype=float)
    K1, N = held.shape
    ends = np.concatenate([np.broadcast_to(np.asarray(base, float), (K1, 1, 3)), np.asarray(robots, float)], axis=1)
    lo = np.minimum(float(t_ref), held)
    need = _need(rule, ends, lo, held, tol)
    step = float(rate) * float(Ts)
    kk, jj = np.meshgrid(np.arange(K1), np.arange(N), indexing="ij")
    kk, jj = kk.ravel(), jj.ravel()
    raised, passes = 0, 0
    while True:
        passes += 1
        sched = np.minimum(np.maximum(rate_bounded_envelope(need, step), lo), held)
        flat = sched.ravel()
        check = np.flatnonzero(flat > need.ravel())  # at need itself the rule was seen to hold
        fails = check[~rule.holds(ends[kk[check], jj[check]], ends[kk[check], jj[check] + 1], jj[check], flat[check])]
        if fails.size == 0 or passes == max_passes:
            break
        need.flat[fails] = held.flat[fails]  # non-monotone there: the held tension (the NLP's) instead
        raised += int(fails.size)
    return sched, dict(need=need, passes=passes, raised=raised, unverified=int(fails.size))


def thrust_need(base: Array, robots: Array, tether: Any, tensions: Array | None) -> tuple[Array, Array]:
    """The thrust every drone needs against its weight and its tethers, |m g e_z − F_q(j) − F_p(j+1)| (the quantity the
    checker bounds by the drone's available thrust), and the tethers' pull on it, |F_q(j) + F_p(j+1)|, each (K+1, N)
    [N], with the end forces of each tether's catenary (:func:`tmr.model.catenary3d.solve3d_batch`) at the winch
    tensions ``tensions`` (K+1, N) [N] (None: the constant ``tether.winch_tension``)."""
    from tmr.model.catenary3d import solve3d_batch

    robots = np.asarray(robots, float)
    K1, N = robots.shape[:2]
    ez = np.array([0.0, 0.0, 1.0])
    weight = float(tether.drone_mass) * float(tether.g)
    out, pulls = np.empty((K1, N)), np.empty((K1, N))
    theta = None
    for k in range(K1):
        pts = np.vstack([np.asarray(base, float)[None], robots[k]])
        cats = solve3d_batch(pts, tether, warm=theta, winch_tension=None if tensions is None else tensions[k])
        theta = cats.theta
        pull = np.array([cats[j].force_q for j in range(N)])
        pull[:-1] += np.array([cats[j].force_p for j in range(1, N)])
        out[k] = np.linalg.norm(weight * ez - pull, axis=1)
        pulls[k] = np.linalg.norm(pull, axis=1)
    return out, pulls
