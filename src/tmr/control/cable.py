"""The tether's height above low obstacles (a step, a cable tray): a hard limit of the per-step QP.

A low obstacle (``Environment.low_obstacles``: a bare footprint and a height h_o [m]) stops the robots, not the
tethers: a tether may pass over it if its catenary is high enough there. In plan view tether j is the chord from robot
j−1 (the anchor for j = 1) to robot j; in its vertical plane the cable hangs as the catenary of its horizontal tension
(:func:`tmr.model.catenary.height_at`). Per tether and low obstacle, one row on the **critical point** of the chord:

- if the chord comes within ``plan_margin`` of the footprint (shapely: the chord ∩ the footprint grown by it, the
  interval [s_a, s_b] of fractions), the lowest point of the cable over that interval: the catenary's vertex if it
  lies inside, else the interval's end nearest it (the catenary is convex). There the cable must be at least
  ``h_o + clearance`` high;
- otherwise the chord's nearest point to the footprint, at plan-view distance δ > ``plan_margin``. There the cable
  must be at least ``h_o + clearance − slope (δ − plan_margin)`` high: a cone, so a tether approaching a low obstacle
  must rise (a higher tension, a shorter span) before it gets over it, and one that cannot stops short of it.

The row (robot coordinates, with an active winch also Ṫ_j) is the velocity damper of g = z − need(δ) ≥ 0:

    Ts (∂z/∂d u_jᵀ (ṗ_j − ṗ_{j−1}) + ∂z/∂T0 Ṫ_j + slope ∇δᵀ ((1 − s) ṗ_{j−1} + s ṗ_j)) ≥ −min(rate Ts, 1) g,

the fraction s of the critical point held over the step (z is stationary there, or monotone at an interval end), the
slope term only outside ``plan_margin``. ∂z/∂d and ∂z/∂T0 are complex-step derivatives of the closed form
(:func:`tmr.model.catenary.height_sensitivities`). A cable already too low over an obstacle only must not get lower.
The independent check samples the catenary itself over the chord's crossing of the bare footprint
(:mod:`tmr.checks.metrics`, kind ``"low_obstacle"``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.control.limits import Limit, LimitRows, approach_bound, robot_link_pattern
from tmr.errors import ParameterError
from tmr.model import catenary
from tmr.model.chain import Chain
from tmr.model.params import ChainParams

Array = NDArray[np.float64]

__all__ = ["CableOverLowObstacles", "PLAN_MARGIN", "SLOPE"]

#: plan-view margin [m]: within it of a footprint the cable must clear the obstacle's top (lateral sway, the
#: footprint's edge), and the cone's slope [m of height per m of plan-view distance] outside it.
PLAN_MARGIN = 0.1
SLOPE = 0.5


class CableOverLowObstacles(Limit):
    """Every tether high enough over every low obstacle (hard; see the module docstring). N · n_low rows, row
    (j, o) = tether j over obstacle o; ``winch = True`` (set by :func:`tmr.control.winch.make_winch_qp`) adds the
    Ṫ_j column of an active winch."""

    name = "low_obstacle"
    space = "robot"

    def __init__(
        self,
        chain: Chain,
        low_obstacles: Any,
        params: ChainParams,
        clearance: float,
        approach_rate: float,
        plan_margin: float = PLAN_MARGIN,
        slope: float = SLOPE,
    ) -> None:
        import shapely

        if clearance < 0 or plan_margin < 0 or slope <= 0 or approach_rate <= 0:
            raise ParameterError(
                f"need clearance ≥ 0, plan_margin ≥ 0, slope > 0, approach_rate > 0; got {clearance}, {plan_margin}, "
                f"{slope}, {approach_rate}"
            )
        self.obstacles = tuple(low_obstacles)
        if not self.obstacles:
            raise ParameterError("CableOverLowObstacles needs at least one low obstacle")
        self.N, self.n_low = chain.n_robots, len(self.obstacles)
        self.params = params
        self.need = np.array([float(o.height) + float(clearance) for o in self.obstacles])
        self.margin, self.slope, self.rate = float(plan_margin), float(slope), float(approach_rate)
        self.footprints = [o.footprint for o in self.obstacles]
        self.grown = [shapely.buffer(f, self.margin) if self.margin > 0 else f for f in self.footprints]
        for g in (*self.footprints, *self.grown):
            shapely.prepare(g)
        self.links = np.repeat(np.arange(1, self.N + 1), self.n_low)
        self.heights1 = np.full(self.N, params.exit_height)
        self.heights1[0] = params.base_height
        self.weight = params.cable_mass_per_length * 9.81
        self.winch = False
        #: the last step's critical points (N, n_low): fraction s along the chord, plan-view distance δ [m] to the
        #: bare footprint, cable height z [m] and the required height [m] (diagnostics, tests)
        self.last: dict[str, Array] = {}

    def pattern(self, chain: Any) -> NDArray[np.bool_]:
        real = getattr(chain, "chain", chain)
        mask = robot_link_pattern(real, self.links)
        if not self.winch:
            return mask
        extra = np.zeros((mask.shape[0], self.N), dtype=bool)
        extra[np.arange(mask.shape[0]), self.links - 1] = True
        return np.hstack([mask, extra])

    def critical(self, P: Array, tension: Array) -> dict[str, Array]:
        """The critical point of every tether and low obstacle for anchor-and-robots ``P`` (N+1, 2) [m] and
        tensions ``tension`` (N,) [N]: fraction s, plan-view distance δ [m] and its gradient (N, n_low, 2), the
        required height [m] and the link directions u (N, 2), spans d (N,) [m]."""
        import shapely

        N, n_low = self.N, self.n_low
        a, b = P[:-1], P[1:]
        d = np.hypot(*(b - a).T)
        u = (b - a) / np.maximum(d, 1e-12)[:, None]
        s = np.zeros((N, n_low))
        delta = np.zeros((N, n_low))
        grad = np.zeros((N, n_low, 2))
        inside = np.zeros((N, n_low), dtype=bool)
        c = tension / self.weight
        dh = self.params.exit_height - self.heights1
        x_low = 0.5 * d - c * np.arcsinh(dh / (2 * c * np.sinh(np.maximum(d, 1e-12) / (2 * c))))
        s_low = np.clip(x_low / np.maximum(d, 1e-12), 0.0, 1.0)
        lines = shapely.linestrings(np.stack([a, b], axis=1))
        for o in range(n_low):
            hit = shapely.intersects(lines, self.grown[o])
            for j in range(N):
                if hit[j]:
                    piece = shapely.intersection(lines[j], self.grown[o])
                    pts = shapely.get_coordinates(piece)
                    along = (pts - a[j]) @ u[j] / max(d[j], 1e-12)
                    s[j, o] = float(np.clip(s_low[j], along.min(), along.max()))
                    inside[j, o] = True
                else:
                    near_line, _ = shapely.shortest_line(lines[j], self.footprints[o]).coords
                    s[j, o] = float(np.clip((np.asarray(near_line) - a[j]) @ u[j] / max(d[j], 1e-12), 0.0, 1.0))
            pts = a + s[:, o, None] * (b - a)
            points = shapely.points(pts)
            delta[:, o] = shapely.distance(points, self.footprints[o])
            out = ~inside[:, o] & (delta[:, o] > 0)
            for j in np.flatnonzero(out):
                _, q = shapely.shortest_line(points[j], self.footprints[o]).coords
                grad[j, o] = (pts[j] - np.asarray(q)) / delta[j, o]
        need = self.need[None, :] - np.where(inside, 0.0, self.slope * np.maximum(delta - self.margin, 0.0))
        return {"s": s, "delta": delta, "grad": grad, "inside": inside, "need": need, "u": u, "d": d}

    def compute(self, ctx: Any) -> LimitRows:
        base = ctx.base if self.winch else ctx
        P = base.points
        N, n_low, n = self.N, self.n_low, 2 * self.N
        T = ctx.winch_tension if self.winch else np.full(N, self.params.horizontal_tension)
        cr = self.critical(P, T)
        s, need = cr["s"], cr["need"]
        j_idx = np.repeat(np.arange(N), n_low)
        z, dz_dd, dz_dT = catenary.height_sensitivities(
            s.reshape(-1), self.heights1[j_idx], self.params.exit_height, cr["d"][j_idx], T[j_idx], self.weight
        )
        g = z - need.reshape(-1)
        Ts = ctx.Ts
        cols = n + (N if self.winch else 0)
        A = np.zeros((N * n_low, cols))
        u = cr["u"][j_idx]
        sf = s.reshape(-1)
        slope = np.where(cr["inside"].reshape(-1), 0.0, self.slope)[:, None] * cr["grad"].reshape(-1, 2)
        r = np.arange(N * n_low)
        # robot j: ∂z/∂d u + slope ∇δ s;  robot j−1 (not the anchor): −∂z/∂d u + slope ∇δ (1 − s)
        jc = 2 * j_idx
        A[r[:, None], jc[:, None] + np.arange(2)] = Ts * (dz_dd[:, None] * u + sf[:, None] * slope)
        lead = j_idx >= 1
        jp = 2 * (j_idx[lead] - 1)
        A[r[lead][:, None], jp[:, None] + np.arange(2)] = Ts * (
            -dz_dd[lead, None] * u[lead] + (1 - sf[lead])[:, None] * slope[lead]
        )
        if self.winch:
            A[r, n + j_idx] = Ts * dz_dT
        lower = approach_bound(g, 0.0, self.rate, Ts)
        lower[need.reshape(-1) <= 0.0] = -np.inf  # far from every low obstacle: the floor is the limit
        self.last = {"s": s, "delta": cr["delta"], "z": z.reshape(N, n_low), "need": need}
        return LimitRows(A, lower, np.full(N * n_low, np.inf))
