"""How fast a replay ran: the real-time factors every replay result (chain, MoPICK, drone chain) reports."""

from __future__ import annotations

import math


class RealTimeFactors:
    """Mixin of a replay result with ``sim_time``, ``wall_time`` and ``cpu_time`` [s] of its simulation loop."""

    sim_time: float
    wall_time: float
    cpu_time: float

    @property
    def real_time_factor(self) -> float:
        """Simulated time / wall time of the simulation loop."""
        return self.sim_time / self.wall_time if self.wall_time > 0 else math.inf

    @property
    def cpu_real_time_factor(self) -> float:
        """Simulated time / CPU time of this process in the loop (what the machine's load does not change)."""
        return self.sim_time / self.cpu_time if self.cpu_time > 0 else math.inf
