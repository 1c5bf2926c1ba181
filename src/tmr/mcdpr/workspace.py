"""Wrench-feasible workspace of an MCDPR with its bases parked: the capacity margin μ over a grid of platform
positions at one height (Rasheed 2019 eq. 7-8; the wrench-feasible workspace of cable robots, CASPR's
"wrench closure/feasible workspace" for a point-mass platform).

A platform position belongs to the wrench-feasible workspace when μ > 0: every wrench of the required set (platform
weight ± the external box) is produced by tensions within [t_min, t_max] and the tipping limits of the parked bases
(eq. 5-6). The map is one batched :func:`tmr.mcdpr.capacity.capacity` call.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.mcdpr.capacity import capacity
from tmr.mcdpr.errors import ParameterError
from tmr.mcdpr.robot import Robot

__all__ = ["Workspace", "workspace"]


class Workspace(NamedTuple):
    """μ map: x (nx,), y (ny,) grid coordinates [m]; mu (ny, nx) capacity margin [N]; z platform height [m]; cell
    [m]; area of the wrench-feasible part (μ > 0) [m²]."""

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    mu: NDArray[np.float64]
    z: float
    cell: float
    area: float


def workspace(
    robot: Robot,
    bases: ArrayLike,
    headings: ArrayLike | None,
    rws: ArrayLike,
    bounds: tuple[float, float, float, float],
    z: float,
    cell: float = 0.05,
) -> Workspace:
    """μ [N] on a grid of platform positions (cell ``cell`` m, cell centres inside ``bounds`` = (xmin, ymin, xmax,
    ymax) [m]) at height ``z`` [m] with the bases at ``bases`` (p, 2) [m], headings (p,) [rad]."""
    x0, y0, x1, y1 = (float(v) for v in bounds)
    if not (cell > 0 and np.isfinite(cell)):
        raise ParameterError(f"cell must be positive, got {cell}")
    ztop = float(robot.exit_points[:, 2].min())
    if not 0 < z < ztop:
        raise ParameterError(f"the platform height must be in (0, {ztop:g}) m (below the cable exits), got {z}")
    nx, ny = int(np.floor((x1 - x0) / cell)), int(np.floor((y1 - y0) / cell))
    if nx < 1 or ny < 1 or nx * ny > 4_000_000:
        raise ParameterError(
            f"a {nx:.3g} x {ny:.3g} grid is empty or too large (more than 4e6 cells); choose another cell size"
        )
    x = x0 + cell * (np.arange(nx) + 0.5)
    y = y0 + cell * (np.arange(ny) + 0.5)
    X, Y = np.meshgrid(x, y)
    P = np.stack([X, Y, np.full_like(X, z)], axis=-1)
    B = np.asarray(bases, dtype=float)
    mu = np.empty(X.shape)
    rows = max(1, 20_000 // nx)
    for r in range(0, ny, rows):  # bounded memory
        mu[r : r + rows] = capacity(robot, P[r : r + rows], B, headings, rws).mu
    return Workspace(x, y, mu, float(z), float(cell), float(np.sum(mu > 0) * cell * cell))
