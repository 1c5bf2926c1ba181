"""The tether's height above low obstacles (a step, a cable tray): a hard limit of the per-step QP.

A low obstacle (``Environment.low_obstacles``: a bare footprint and a height h_o [m]) stops the robots, not the
tethers: a tether may pass over it if its catenary is high enough there. In plan view tether j is the chord from robot
j−1 (the anchor for j = 1) to robot j; in its vertical plane the cable hangs as the catenary of its horizontal tension
(:func:`tmr.model.catenary.height_at`). Each tether is sampled at M fixed fractions s_i = i/(M+1) (material points of
the chord, as the clearance rows' samples), M = ⌈d_reach / plan_margin⌉ so that consecutive samples are at most
``plan_margin`` (0.1 m) apart on the longest span. Per sample and low obstacle, with δ the sample's plan-view distance
to the bare footprint, the cable's height z(s_i) must be at least

    need(δ) = h_o + clearance − slope · max(δ − plan_margin, 0)

(+ ``ROW_MARGIN``): the obstacle's top plus the clearance within ``plan_margin`` of the footprint, and a cone
outside it, so a tether approaching a low obstacle must rise (a higher tension, a shorter span) before it gets over it,
and one that cannot stops short of it. The row (robot coordinates; with an active winch also Ṫ_j) is the velocity
damper of g = z − need(δ) ≥ 0:

    Ts (∂z/∂d u_jᵀ (ṗ_j − ṗ_{j−1}) + ∂z/∂T0 Ṫ_j + slope [δ > plan_margin] ∇δᵀ ((1 − s) ṗ_{j−1} + s ṗ_j))
        ≥ −min(rate Ts, 1) max(g, 0),

active where need > 0. ∂z/∂d (the fraction held) and ∂z/∂T0 are complex-step derivatives of the closed form
(:func:`tmr.model.catenary.height_sensitivities`).

**Between samples.** A cable point over the bare footprint has both neighbouring samples within ``plan_margin`` of it
(δ is 1-Lipschitz), so both are held at h_o + clearance; the catenary between two points dips below their chord by at
most Δ²/(8c) ≤ 0.1²/(8 · 3.4 m) = 0.4 mm (c at the least tension of the active winch's range, 5 N), inside
``ROW_MARGIN``. The independent check samples the catenary itself every centimetre over the chord's crossing of the
bare footprint (:mod:`tmr.checks.metrics`, kind ``"low_obstacle"``).
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
#: height [m] the rows keep beyond the required one: the linearisation over a step (the critical point's fraction held,
#: z linear in d and T0) ends ~1e-6 m short of a row held at its bound; the checker has no tolerance.
ROW_MARGIN = 0.002


class CableOverLowObstacles(Limit):
    """Every tether high enough over every low obstacle (hard; see the module docstring). N · M · n_low rows: row
    (j, i, o) = sample i of tether j over obstacle o. ``winch = True`` (set by :func:`tmr.control.winch.make_winch_qp`)
    adds the Ṫ_j column of an active winch.

    Args:
        chain: the chain; env: its environment (``low_obstacles``, ``low_obstacle_distance``); params: the chain's
        parameters (heights, cable, T0); clearance: h_o + this [m] is the height to clear; approach_rate [1/s];
        reach: the longest span a tether may take [m] (sets M); plan_margin [m], slope [-]: the zone and the cone.
    """

    name = "low_obstacle"
    space = "robot"

    def __init__(
        self,
        chain: Chain,
        env: Any,
        params: ChainParams,
        clearance: float,
        approach_rate: float,
        reach: float,
        plan_margin: float = PLAN_MARGIN,
        slope: float = SLOPE,
    ) -> None:
        if clearance < 0 or plan_margin <= 0 or slope <= 0 or approach_rate <= 0 or not reach > 0:
            raise ParameterError(
                f"need clearance ≥ 0, plan_margin > 0, slope > 0, approach_rate > 0, reach > 0; got {clearance}, "
                f"{plan_margin}, {slope}, {approach_rate}, {reach}"
            )
        self.env = env
        obstacles = tuple(env.low_obstacles)
        if not obstacles:
            raise ParameterError("CableOverLowObstacles needs at least one low obstacle")
        self.N, self.n_low = chain.n_robots, len(obstacles)
        self.params = params
        self.need = np.array([float(o.height) + float(clearance) + ROW_MARGIN for o in obstacles])
        self.names = [str(o.name) for o in obstacles]
        self.heights = [float(o.height) for o in obstacles]
        self.clearance = float(clearance)
        self.margin, self.slope, self.rate = float(plan_margin), float(slope), float(approach_rate)
        self.M = int(np.ceil(reach / self.margin))
        self.s = np.arange(1, self.M + 1) / (self.M + 1)
        # rows in order (tether j, sample i, obstacle o)
        self.tether = np.repeat(np.arange(self.N), self.M * self.n_low)
        self.frac = np.tile(np.repeat(self.s, self.n_low), self.N)
        self.obst = np.tile(np.arange(self.n_low), self.N * self.M)
        self.h1 = np.where(self.tether == 0, params.base_height, params.exit_height)
        self.weight = params.cable_mass_per_length * 9.81
        self.winch = False
        #: the last step's rows: cable height z [m], required height [m], plan-view distance δ [m], (N, M, n_low)
        self.last: dict[str, Array] = {}

    def pattern(self, chain: Any) -> NDArray[np.bool_]:
        real = getattr(chain, "chain", chain)
        mask = robot_link_pattern(real, self.tether + 1)
        if not self.winch:
            return mask
        extra = np.zeros((mask.shape[0], self.N), dtype=bool)
        extra[np.arange(mask.shape[0]), self.tether] = True
        return np.hstack([mask, extra])

    def compute(self, ctx: Any) -> LimitRows:
        base = ctx.base if self.winch else ctx
        P = base.points
        N, M, n_low = self.N, self.M, self.n_low
        T = ctx.winch_tension if self.winch else np.full(N, self.params.horizontal_tension)
        a, b = P[:-1], P[1:]
        d = np.hypot(*(b - a).T)
        u = (b - a) / np.maximum(d, 1e-12)[:, None]
        pts = a[:, None, :] + self.s[None, :, None] * (b - a)[:, None, :]  # (N, M, 2)
        dist, grad = self.env.low_obstacle_distance(pts.reshape(-1, 2))  # (N M, n_low), (N M, n_low, 2)
        dist, grad = dist.reshape(-1), grad.reshape(-1, 2)  # row order (j, i, o)
        j = self.tether
        z, dz_dd, dz_dT = catenary.height_sensitivities(
            self.frac, self.h1, self.params.exit_height, d[j], T[j], self.weight
        )
        outside = dist > self.margin
        need = self.need[self.obst] - self.slope * np.maximum(dist - self.margin, 0.0)
        g = z - need
        Ts = ctx.Ts
        rows = N * M * n_low
        cols = 2 * N + (N if self.winch else 0)
        A = np.zeros((rows, cols))
        r = np.arange(rows)
        cone = np.where(outside, self.slope, 0.0)[:, None] * grad
        # robot j (1-based j+1): ∂z/∂d u + slope ∇δ s;  robot j−1 (not the anchor): −∂z/∂d u + slope ∇δ (1 − s)
        cj = 2 * j
        A[r[:, None], cj[:, None] + np.arange(2)] = Ts * (dz_dd[:, None] * u[j] + self.frac[:, None] * cone)
        lead = j >= 1
        cp = 2 * (j[lead] - 1)
        A[r[lead][:, None], cp[:, None] + np.arange(2)] = Ts * (
            -dz_dd[lead, None] * u[j[lead]] + (1.0 - self.frac[lead])[:, None] * cone[lead]
        )
        if self.winch:
            A[r, 2 * N + j] = Ts * dz_dT
        lower = approach_bound(g, 0.0, self.rate, Ts)
        lower[need <= 0.0] = -np.inf  # far from every low obstacle: the floor is the limit
        self.last = {
            "z": z.reshape(N, M, n_low), "need": need.reshape(N, M, n_low), "delta": dist.reshape(N, M, n_low),
            "tension": np.array(T, dtype=float),
        }  # fmt: skip
        return LimitRows(A, lower, np.full(rows, np.inf))

    def note(self, tolerance: float = 1e-3) -> str | None:
        """One line on the tether held lowest against a low obstacle at the last step computed (a row within
        ``tolerance`` [m] of its bound), or None: why a leader that stops short was held back."""
        if not self.last:
            return None
        g = self.last["z"] - self.last["need"]
        active = self.last["need"] > 0
        if not np.any(active & (g < tolerance)):
            return None
        j, i, o = np.unravel_index(np.argmin(np.where(active, g, np.inf)), g.shape)
        T = float(self.last["tension"][j])
        z, delta = float(self.last["z"][j, i, o]), float(self.last["delta"][j, i, o])
        where = "over" if delta <= self.margin else f"{delta:.2f} m from"
        if self.winch:
            top = T >= self.params.winch_tension_max - 1e-6
            at = f"at {T:.1f} N" + (", the top of the winch's range" if top else "")
        else:
            at = f"at the winch's constant {T:.1f} N (an active winch, --set winch=active, can lift it)"
        return (
            f"tether {j + 1} hangs {z:.3f} m high {where} the low obstacle '{self.names[o]}' ({self.heights[o]:.2f} m "
            f"high, to be cleared by {self.clearance:.2f} m) {at}"
        )
