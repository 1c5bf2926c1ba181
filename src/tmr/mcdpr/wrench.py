"""Cable unit vectors and the wrench matrix W of a point-mass platform (Rasheed 2019 eq. 1-3), batched.

Shapes: a batch of B poses (any leading shape ``...``): platform position ``platform`` (..., 3) [m], base positions
``bases`` (..., p, 2) [m] in the ground plane x0y0, base headings ``heading`` (..., p) [rad] (only needed when an
exit point is off the base axis).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.mcdpr.errors import ParameterError
from tmr.mcdpr.robot import Robot

__all__ = ["exit_points", "wrench_matrix"]


def exit_points(robot: Robot, bases: ArrayLike, heading: ArrayLike | None = None) -> NDArray[np.float64]:
    """World coordinates of the cable exit points A_k, shape (..., m, 3) [m].

    ``bases`` (..., p, 2) [m]; ``heading`` (..., p) [rad] rotates the base frame about z (default 0).
    """
    b = np.asarray(bases, dtype=float)
    if b.ndim < 2 or b.shape[-2:] != (robot.n_bases, 2):
        raise ParameterError(f"bases must have shape (..., {robot.n_bases}, 2), got {b.shape}")
    cb = np.asarray(robot.cable_base)
    local = robot.exit_points
    pos = b[..., cb, :]  # (..., m, 2)
    if robot.axial_exits:
        xy = pos
    else:
        th = np.zeros(b.shape[:-1]) if heading is None else np.broadcast_to(np.asarray(heading, float), b.shape[:-1])
        c, s = np.cos(th[..., cb]), np.sin(th[..., cb])
        xy = pos + np.stack([c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1]], axis=-1)
    z = np.broadcast_to(local[:, 2], xy.shape[:-1])
    return np.concatenate([xy, z[..., None]], axis=-1)


def wrench_matrix(
    robot: Robot, platform: ArrayLike, bases: ArrayLike, heading: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Wrench matrix W = [u_1 … u_m], shape (..., 3, m) (Rasheed 2019 eq. 3).

    u_k = (A_k − P)/‖A_k − P‖ is the unit vector of cable k from the platform point P to its exit point A_k
    (Rasheed 2019 eq. 1), so the cables apply the force W t to the platform for tensions t [N] (eq. 2).
    ``platform`` (..., 3) [m] broadcasts against ``bases`` (..., p, 2). Raises ParameterError when P coincides with
    an exit point.
    """
    A = exit_points(robot, bases, heading)
    P = np.asarray(platform, dtype=float)
    if P.shape[-1:] != (3,):
        raise ParameterError(f"platform must have shape (..., 3), got {P.shape}")
    d = A - P[..., None, :]
    n = np.sqrt(np.einsum("...i,...i->...", d, d))
    if np.any(n <= 1e-12):
        raise ParameterError("the platform coincides with a cable exit point: the cable direction is undefined")
    return np.swapaxes(d / n[..., None], -1, -2)
