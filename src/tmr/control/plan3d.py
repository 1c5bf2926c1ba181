"""The plan of a tethered drone chain (Caruso 2021's chain in 3-D): what every 3-D formulation returns and what the
checker, the outputs and the views read (``formulations/drones.md``).

Arrays are indexed by step k = 0..K (truncated if the run stopped early). Tether j (j = 1..N) joins point j-1 and
point j of the chain, point 0 being the anchor (the ground winch at ``base``) and point j robot j; each hangs as the
catenary of :mod:`tmr.model.catenary3d` through its two ends, in the vertical plane through them, with parameter
``a = H / (rho g)`` recorded per step in ``tether_a`` (NaN for a vertical tether, which hangs straight). From the two
ends and ``a`` any reader rebuilds the curve (``formulations/drones.md``, "Rebuilding a tether").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.model.catenary3d import DroneTetherParams

Array = NDArray[np.float64]

__all__ = ["DronePlan"]


@dataclass
class DronePlan:
    """A drone chain's plan, K + 1 states.

    Attributes:
        method: formulation name (``"pinv"``, ``"qp"``).
        scenario: scenario name.
        t: times [s], (K+1,).
        robots: drone positions, (K+1, N, 3) [m]; robot N is the leader.
        velocities: drone velocities, (K+1, N, 3) [m/s]; ``velocities[k]`` applies on [t_k, t_k+1] (explicit
            Euler, Caruso 2021 eq. 21 in robot coordinates); the last row is 0.
        base: the anchor (ground winch) (3,) [m].
        goal: the leader's goal (3,) [m].
        reference: the leader's reference x_d(t), (K+1, 3) [m].
        tether_a: catenary parameter a = H/(rho g) of each tether at each step, (K+1, N) [m]; NaN: vertical.
        tether: the tether and drone parameters the plan was made with (rho, g, T_w, which end, L_max, c_t, spare
            thrust, drone radius).
        safety_radius: drone radius r [m] (the world's obstacles are grown by it for the drones' clearance).
        bounds: the room (xmin, ymin, zmin, xmax, ymax, zmax) [m]; the floor is z = zmin.
        success: every step computed and every hard limit holds (set by the checker).
        failure: why the plan failed, or None.
        diagnostics: per-step arrays (K+1,) (e.g. ``"step_time"``, ``"leader_residual"``, ``"qp_level:<name>"``)
            and, under ``"timings"``, the parts of the wall time [s].
        wall_time: planning time [s].
        params: the parameters used (JSON-able).
        q: the 3N joints of the chain seen as a manipulator (``Chain(spatial=True)``), (K+1, 3N), when the
            formulation integrates joints (``pinv``); None otherwise.
        winch_tension: with an active winch (``tether.winch = "active"``), every tether's winch tension T_w at
            every step, (K+1, N) [N] (``tether_a`` is the catenary at that tension); None: every winch at the
            constant ``tether.winch_tension``.
    """

    method: str
    scenario: str
    t: Array
    robots: Array
    velocities: Array
    base: Array
    goal: Array
    reference: Array
    tether_a: Array
    tether: DroneTetherParams
    safety_radius: float
    bounds: Array
    success: bool
    failure: str | None
    diagnostics: dict[str, Any] = field(default_factory=dict)
    wall_time: float = 0.0
    params: dict[str, Any] = field(default_factory=dict)
    q: Array | None = None
    winch_tension: Array | None = None

    @property
    def Ts(self) -> float:
        """Sampling period [s]."""
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else 0.0

    @property
    def n_robots(self) -> int:
        """Number of drones N."""
        return int(self.robots.shape[1])

    def points(self, k: int) -> Array:
        """The chain's points at step k: the anchor then every drone, (N+1, 3) [m]."""
        return np.vstack([self.base[None, :], self.robots[k]])
