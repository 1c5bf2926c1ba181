"""End-effector target paths as sequences of small increments (Kumar 2019 §III-D: 1 mm / 0.01 rad steps).

Every path starts at the reference end-effector pose (p0, R0) and returns positions (K, 3) [m] and rotations
(K, 3, 3); the first target is the first increment (not the start). Rotations are composed as
R(s) = Rz(ψ(s)) · R0 · Π_k Rot(a_k, θ_k(s)) — yaw about the world vertical on the left, tilts about the body-frame
``tilt_axes`` of the description on the right — so a target stays on the reachable set of a mechanism that keeps those
body axes' constraints (e.g. a level platform: no tilt axes).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tmr.ccma.bodies import rot_axis, rot_z
from tmr.ccma.errors import CcmaError

__all__ = ["PATHS", "Path", "make_path"]

PATHS = ("circle", "line", "yaw", "combined")


class Path(NamedTuple):
    """Targets: ``positions`` (K, 3) [m], ``rotations`` (K, 3, 3)."""

    positions: np.ndarray
    rotations: np.ndarray


def _rotations(r0: np.ndarray, yaw: np.ndarray, tilts: np.ndarray, axes: np.ndarray) -> np.ndarray:
    out = np.empty((yaw.size, 3, 3))
    for i in range(yaw.size):
        r = rot_z(yaw[i]) @ r0
        for a, th in zip(axes, tilts[i], strict=True):
            r = r @ rot_axis(a, th)
        out[i] = r
    return out


def make_path(
    kind: str,
    p0: np.ndarray,
    r0: np.ndarray,
    tilt_axes: np.ndarray | None = None,
    *,
    step: float = 1e-3,
    rot_step: float = 0.01,
    radius: float = 0.05,
    steps: int = 20,
) -> Path:
    """Target path of the given kind.

    * ``circle``: horizontal circle of ``radius`` [m] through p0 (centre p0 − radius·e_x), arc steps ≈ ``step`` [m].
    * ``line``: ``steps`` increments of ``step`` [m] along +x.
    * ``yaw``: ``steps`` increments of ``rot_step`` [rad] about the world vertical.
    * ``combined``: ``steps`` simultaneous increments of ``step`` in x, y and z and ``rot_step`` in yaw and every tilt
      (the combined perturbation of Kumar 2019 Fig. 5).
    """
    if kind not in PATHS:
        raise CcmaError(f"unknown path {kind!r}; choose one of {', '.join(PATHS)}")
    for name, v in (("step", step), ("rot_step", rot_step), ("radius", radius)):
        if not (math.isfinite(v) and v > 0):
            raise CcmaError(f"{name} must be a positive number, got {v}")
    if steps < 1:
        raise CcmaError(f"steps must be at least 1, got {steps}")
    axes = np.zeros((0, 3)) if tilt_axes is None else np.asarray(tilt_axes, float).reshape(-1, 3)
    p0 = np.asarray(p0, float)
    if kind == "circle":
        k = max(8, math.ceil(2 * math.pi * radius / step))
        s = 2 * math.pi * np.arange(1, k + 1) / k
        pos = p0 + radius * np.column_stack([np.cos(s) - 1.0, np.sin(s), np.zeros(k)])
        yaw, tilts = np.zeros(k), np.zeros((k, len(axes)))
    else:
        i = np.arange(1, steps + 1, dtype=float)
        d = {"line": (1, 0, 0), "yaw": (0, 0, 0), "combined": (1, 1, 1)}[kind]
        pos = p0 + step * i[:, None] * np.asarray(d, float)
        yaw = rot_step * i if kind in ("yaw", "combined") else np.zeros(steps)
        tilts = rot_step * i[:, None] * np.ones(len(axes)) if kind == "combined" else np.zeros((steps, len(axes)))
    return Path(pos, _rotations(np.asarray(r0, float), yaw, tilts, axes))
