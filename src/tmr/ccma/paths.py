"""End-effector target paths as sequences of small increments (Kumar 2019 §III-D: 1 mm / 0.01 rad steps).

Every path starts at the reference end-effector pose (p0, R0) and returns positions (K, 3) [m] and rotations
(K, 3, 3); the first target is the first increment (not the start). Rotations are composed as
R(s) = Rz(ψ(s)) · R0 · Π_k Rot(a_k, θ_k(s)) — yaw about the world vertical on the left, tilts about the body-frame
``tilt_axes`` of the description on the right — so a target stays on the reachable set of a mechanism that keeps those
body axes' constraints (e.g. a level platform: no tilt axes).

Paths that move the linkage (the joints bend): ``vcircle`` (vertical circle), ``figure8`` (a figure-eight that also
rises and falls), ``tilt`` / ``roll`` (sweeps about the first / second tilt axis). Paths that only slide a level
4-dof mechanism across the floor (every joint angle stays 0): ``circle`` (horizontal), ``line``. The number of targets
is checked against :data:`MAX_STEPS` before any array is allocated.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

from tmr.ccma.bodies import rot_axis, rot_z
from tmr.ccma.errors import CcmaError

__all__ = ["MAX_STEPS", "PATHS", "Path", "make_path", "path_steps"]

PATHS = ("vcircle", "figure8", "tilt", "roll", "circle", "line", "yaw", "combined")
#: Largest number of targets a path may have (one IK solve each, ~5 ms: about 8 minutes).
MAX_STEPS = 100_000
#: Length of the unit figure-eight (radius 1 m), by a 2^16-segment polyline of :func:`_figure8_unit`.
_N_LENGTH = 1 << 16


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


def _figure8_unit(s: np.ndarray) -> np.ndarray:
    """Figure-eight of unit size, s ∈ [0, 2π]: x = sin s, y = ½ sin 2s (a lemniscate of Gerono in plan), z = sin² s
    (both lobes rise to 1 m and come back down), starting and ending at the origin."""
    return np.column_stack([np.sin(s), 0.5 * np.sin(2 * s), np.sin(s) ** 2])


def _vcircle_unit(s: np.ndarray) -> np.ndarray:
    """Vertical circle of unit radius in the x–z plane through the origin, centre (0, 0, 1): up first."""
    return np.column_stack([np.sin(s), np.zeros_like(s), 1.0 - np.cos(s)])


def _hcircle_unit(s: np.ndarray) -> np.ndarray:
    """Horizontal circle of unit radius through the origin, centre (−1, 0, 0)."""
    return np.column_stack([np.cos(s) - 1.0, np.sin(s), np.zeros_like(s)])


_CURVES = {"circle": _hcircle_unit, "vcircle": _vcircle_unit, "figure8": _figure8_unit}


@functools.cache
def _unit_length(kind: str) -> float:
    """Length [m] of the closed curve of unit radius."""
    if kind in ("circle", "vcircle"):
        return 2.0 * math.pi
    pts = _CURVES[kind](np.linspace(0.0, 2.0 * math.pi, _N_LENGTH + 1))
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def _sweep_count(amplitude: float, rot_step: float) -> int:
    """Targets of one sinusoidal period θ = A sin s whose largest increment A·2π/K is ≤ ``rot_step``."""
    return max(8, math.ceil(2.0 * math.pi * amplitude / rot_step))


def path_steps(kind: str, *, step: float, rot_step: float, radius: float, amplitude: float, steps: int) -> int:
    """Number of targets the path would have (computed without building it), for the :data:`MAX_STEPS` check."""
    if kind in _CURVES:
        return max(8, math.ceil(_unit_length(kind) * radius / step))
    if kind in ("tilt", "roll"):
        return _sweep_count(amplitude, rot_step)
    return steps


def _resample(kind: str, radius: float, k: int) -> np.ndarray:
    """k points at equal arc length along the closed curve (the last one back at the start), relative to the start."""
    n = max(_N_LENGTH, 16 * k)
    s = np.linspace(0.0, 2.0 * math.pi, n + 1)
    pts = _CURVES[kind](s)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    s_k = np.interp(arc[-1] * np.arange(1, k + 1) / k, arc, s)
    s_k[-1] = 2.0 * math.pi
    out = radius * _CURVES[kind](s_k)
    out[-1] = 0.0  # closed exactly
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
    amplitude: float = 0.2,
    max_steps: int = MAX_STEPS,
) -> Path:
    """Target path of the given kind.

    * ``vcircle``: vertical circle of ``radius`` [m] in the x–z plane through p0 (centre p0 + radius·e_z, rising
      first), arc steps ≈ ``step`` [m].
    * ``figure8``: p0 + radius·(sin s, ½ sin 2s, sin² s), s ∈ [0, 2π]: a figure-eight in plan whose two lobes rise
      to ``radius`` above p0; arc steps ≈ ``step``.
    * ``tilt`` / ``roll``: one period of θ = ``amplitude``·sin s [rad] about the first / second tilt axis of the
      description (largest increment ≤ ``rot_step``), position held at p0.
    * ``circle``: horizontal circle of ``radius`` [m] through p0 (centre p0 − radius·e_x), arc steps ≈ ``step``.
    * ``line``: ``steps`` increments of ``step`` [m] along +x.
    * ``yaw``: ``steps`` increments of ``rot_step`` [rad] about the world vertical.
    * ``combined``: ``steps`` simultaneous increments of ``step`` in x, y and z and ``rot_step`` in yaw and every tilt
      (the combined perturbation of Kumar 2019 Fig. 5).

    Raises :class:`CcmaError` for an unknown kind, a non-positive or non-finite size, a tilt/roll sweep about an axis
    the description does not have, or more than ``max_steps`` targets (checked before anything is allocated).
    """
    if kind not in PATHS:
        raise CcmaError(f"unknown path {kind!r}; choose one of {', '.join(PATHS)}")
    for name, v in (("step", step), ("rot_step", rot_step), ("radius", radius), ("amplitude", amplitude)):
        if not (math.isfinite(v) and v > 0):
            raise CcmaError(f"{name} must be a positive number, got {v}")
    if steps < 1:
        raise CcmaError(f"steps must be at least 1, got {steps}")
    axes = np.zeros((0, 3)) if tilt_axes is None else np.asarray(tilt_axes, float).reshape(-1, 3)
    if kind in ("tilt", "roll"):
        need = 1 if kind == "tilt" else 2
        if len(axes) < need:
            which = "first" if need == 1 else "second"
            raise CcmaError(
                f"path {kind!r} sweeps the end-effector about its {which} tilt axis, but the system has "
                f"{len(axes)} tilt axis(es) (its end-effector stays {'level' if not len(axes) else 'on one tilt'}); "
                f"use a 5-dof or 6-dof example, or path vcircle / figure8"
            )
    k = path_steps(kind, step=step, rot_step=rot_step, radius=radius, amplitude=amplitude, steps=steps)
    if k > max_steps:
        raise CcmaError(
            f"path {kind!r} would have {k:.3g} targets, more than the cap of {max_steps}; use a larger step "
            f"(--step / --rot-step) or a smaller size (--radius / --amplitude / --steps)"
        )
    p0 = np.asarray(p0, float)
    yaw, tilts = np.zeros(k), np.zeros((k, len(axes)))
    if kind in _CURVES:
        pos = p0 + _resample(kind, radius, k)
    elif kind in ("tilt", "roll"):
        pos = np.tile(p0, (k, 1))
        th = amplitude * np.sin(2.0 * math.pi * np.arange(1, k + 1) / k)
        th[-1] = 0.0
        tilts[:, 0 if kind == "tilt" else 1] = th
    else:
        i = np.arange(1, steps + 1, dtype=float)
        d = {"line": (1, 0, 0), "yaw": (0, 0, 0), "combined": (1, 1, 1)}[kind]
        pos = p0 + step * i[:, None] * np.asarray(d, float)
        if kind in ("yaw", "combined"):
            yaw = rot_step * i
        if kind == "combined":
            tilts = rot_step * i[:, None] * np.ones(len(axes))
    return Path(pos, _rotations(np.asarray(r0, float), yaw, tilts, axes))
