"""Rigid-body pose parameterisation: position + Cayley (Gibbs) vector about a per-body reference rotation.

Each body has a 6-dof state block ``x_i = (p_i, w_i)``: ``p_i`` the world position of the body frame [m] and ``w_i``
the Cayley vector (dimensionless, ``w = 2 tan(θ/2) a`` for a rotation θ about the unit axis ``a``) of the rotation
relative to a reference rotation ``R_ref,i`` kept outside the state::

    R_i = R_ref,i · cay(w_i),   cay(w) = I + 4 / (4 + |w|²) · ([w]× + [w]×² / 2)

The Cayley map is rational (no 0/0 at ``w = 0`` unlike the exponential map's ``sin θ / θ``, so CasADi's exact
derivatives are finite everywhere) and is singular only at θ = π. :func:`reanchor` folds ``cay(w_i)`` into
``R_ref,i`` and resets ``w_i = 0`` before every solve (and whenever ``|w_i|`` grows past :data:`REANCHOR_LIMIT`
during one), so in use θ stays far below π: the parameterisation has no singularity along any motion. This is the
"incremental rotation" device of constraint-based linkage simulators (Coros 2013, Thomaszewski 2014).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

__all__ = [
    "REANCHOR_LIMIT",
    "cayley",
    "cayley_sx",
    "reanchor",
    "rot_axis",
    "rot_rpy",
    "rot_z",
    "rotation_angle",
]

#: Re-anchor a body when its Cayley vector exceeds this norm (|w| = 0.5 ↔ θ ≈ 0.49 rad).
REANCHOR_LIMIT = 0.5


def cayley(w: np.ndarray) -> np.ndarray:
    """Rotation matrices of Cayley vectors ``w`` with shape (..., 3) → (..., 3, 3) (numpy, vectorised)."""
    w = np.asarray(w, dtype=float)
    k = np.zeros(w.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2] = -w[..., 2], w[..., 1]
    k[..., 1, 0], k[..., 1, 2] = w[..., 2], -w[..., 0]
    k[..., 2, 0], k[..., 2, 1] = -w[..., 1], w[..., 0]
    s = 4.0 / (4.0 + np.sum(w * w, axis=-1))[..., None, None]
    return np.eye(3) + s * (k + 0.5 * k @ k)


def cayley_sx(w: Any) -> Any:
    """Rotation matrix (3×3 CasADi expression) of a symbolic Cayley vector ``w`` (3×1)."""
    k = ca.skew(w)
    return ca.SX.eye(3) + (4.0 / (4.0 + ca.dot(w, w))) * (k + 0.5 * k @ k)


def _orthonormalise(r: np.ndarray) -> np.ndarray:
    """Nearest rotation matrices (polar decomposition by SVD) of a stack (..., 3, 3)."""
    u, _, vt = np.linalg.svd(r)
    return u @ vt


def reanchor(x: np.ndarray, r_ref: np.ndarray, limit: float = 0.0) -> bool:
    """Fold ``cay(w_i)`` into ``r_ref[i]`` and zero ``w_i`` for every body with ``|w_i| > limit`` (in place).

    ``x`` is the stacked state (6 n,), ``r_ref`` the reference rotations (n, 3, 3). The world pose of every body is
    unchanged. Returns whether anything was re-anchored.
    """
    w = x.reshape(-1, 6)[:, 3:]
    sel = np.linalg.norm(w, axis=1) > limit
    if not np.any(sel):
        return False
    r_ref[sel] = _orthonormalise(r_ref[sel] @ cayley(w[sel]))
    w[sel] = 0.0
    return True


def rot_z(psi: float) -> np.ndarray:
    """Rotation about the world z axis by ``psi`` [rad]."""
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_axis(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation about the unit vector ``axis`` by ``angle`` [rad] (Rodrigues)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * k @ k


def rot_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (fixed-axis roll–pitch–yaw, radians)."""
    return rot_z(yaw) @ rot_axis(np.array([0.0, 1.0, 0.0]), pitch) @ rot_axis(np.array([1.0, 0.0, 0.0]), roll)


def rotation_angle(r_a: np.ndarray, r_b: np.ndarray) -> float:
    """Angle [rad] of the relative rotation ``r_aᵀ r_b``, from ‖R_a − R_b‖_F = 2√2 sin(θ/2) (accurate near 0,
    unlike the arccos of the trace)."""
    s = np.linalg.norm(np.asarray(r_a) - np.asarray(r_b)) / (2.0 * np.sqrt(2.0))
    return float(2.0 * np.arcsin(np.clip(s, 0.0, 1.0)))
