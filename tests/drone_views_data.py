"""Small hand-made drone plans for the 3-D views and export tests: positions chosen here, each tether's ``a`` from
:func:`tmr.model.catenary3d.solve3d` (the planner's model), so every curve is the true equilibrium."""

from __future__ import annotations

import numpy as np

from tmr.control.plan3d import DronePlan
from tmr.model.catenary3d import DroneTetherParams, solve3d
from tmr.world.world3d import World3D, box_obstacle, prism_obstacle

BOUNDS = (0.0, 0.0, 0.0, 10.0, 8.0, 4.0)


def small_world(r: float = 0.3) -> World3D:
    """A box, a convex prism (triangle) and a non-convex prism (an L) in a 10 × 8 × 4 m room."""
    return World3D(
        [
            box_obstacle([4.0, 0.0, 0.0], [4.5, 3.0, 2.5], "box #0"),
            prism_obstacle([[1.0, 6.0], [2.0, 6.0], [1.5, 7.0]], [0.0, 1.5], "prism #1"),
            prism_obstacle([[7.0, 5.0], [9.0, 5.0], [9.0, 5.5], [7.5, 5.5], [7.5, 7.0], [7.0, 7.0]], [0.0, 3.0], "L"),
        ],
        BOUNDS,
        r,
    )


def hand_plan(n: int = 3, steps: int = 41, Ts: float = 0.05, vertical_at: int | None = None) -> DronePlan:
    """``n`` drones flying along +x at rising height, in a line behind the leader; tether a from solve3d. With
    ``vertical_at`` = k, drone 1 is straight above the anchor at step k (a vertical tether, a = NaN)."""
    tether = DroneTetherParams()
    base = np.array([1.0, 4.0, 0.3])
    t = Ts * np.arange(steps)
    s = np.linspace(0.0, 1.0, steps)
    robots = np.empty((steps, n, 3))
    for i in range(n):
        frac = (i + 1) / n
        robots[:, i, 0] = 1.0 + frac * (1.5 + 5.0 * s)
        robots[:, i, 1] = 4.0 + 0.6 * frac * np.sin(2.0 * np.pi * s)
        robots[:, i, 2] = 1.2 + 0.8 * frac + 0.6 * s
    if vertical_at is not None:
        robots[vertical_at, 0, :2] = base[:2]
    a = np.full((steps, n), np.nan)
    for k in range(steps):
        pts = np.vstack([base, robots[k]])
        for j in range(n):
            a[k, j] = (
                np.nan if (solve3d(pts[j], pts[j + 1], tether).a is None) else solve3d(pts[j], pts[j + 1], tether).a
            )
    vel = np.zeros_like(robots)
    vel[:-1] = np.diff(robots, axis=0) / Ts
    return DronePlan(
        method="qp", scenario="hand", t=t, robots=robots, velocities=vel, base=base, goal=robots[-1, -1].copy(),
        reference=robots[:, -1].copy(), tether_a=a, tether=tether, safety_radius=0.3, bounds=np.array(BOUNDS),
        success=True, failure=None,
    )  # fmt: skip
