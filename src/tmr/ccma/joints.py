"""Joints and mobile-agent actuators as constraint functions C(x, u) between rigid bodies.

Constraint-based linkage modelling (Coros 2013, Thomaszewski 2014; used by Kumar 2019 §II-A): a joint between bodies
A and B with world poses (p_A, R_A), (p_B, R_B) contributes residual rows that vanish exactly when the joint is
assembled. Anchors ``a`` and axes ``n`` are stored in the body frames (they are computed once from the world point
and axis of the description's reference configuration). Rows measuring orientation (differences of unit vectors,
dimensionless) are multiplied by a characteristic length ``ell`` [m] so that every row is a length [m] and the
constraint energy ½‖C‖² is in m².

Rows per joint type (redundant rows are harmless for the least-squares energy, they do not change its minimisers):

* point coincidence (3): ``p_A + R_A a_A − p_B − R_B a_B``
* revolute = point + axis alignment ``ell (R_A n_A − R_B n_B)`` (3 + 3)
* spherical = point (3)
* universal = point + perpendicularity ``ell (R_A n_A)·(R_B n_B)`` of the cross axes (3 + 1)
* prismatic = orientation lock + the anchor of B on the line through A's anchor along ``R_A n_A``:
  ``d − (d·n) n`` with ``d = p_B + R_B a_B − p_A − R_A a_A`` (6 + 3)
* fixed = point + orientation lock ``ell (R_A Q e_k − R_B e_k)``, k = 1, 2 with ``Q = R_A0ᵀ R_B0`` (3 + 6)

Mobile agent (Kumar 2019 §II-A): planar constraint ``p_z − h`` and ``ell (R e_z)_{x,y}`` (z, roll, pitch fixed),
motor constraints ``p_x − u_x``, ``p_y − u_y`` and the yaw motor ``ell ((R e_x)_x − cos ψ, (R e_x)_y − sin ψ)``, where
ψ is a control (complete actuation) or a held parameter (reduced actuation).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

__all__ = ["JOINT_TYPES", "Joint", "agent_rows", "joint_rows"]

#: Joint types of a description and the number of rows each contributes.
JOINT_TYPES = {"revolute": 6, "prismatic": 9, "spherical": 3, "universal": 4, "fixed": 9}

Pose = tuple[Any, Any]  # (p, R) CasADi expressions or numpy arrays


@dataclass(frozen=True)
class Joint:
    """A joint resolved into body frames.

    ``a`` / ``b`` are body indices (-1 = the world frame); ``anchor_a`` / ``anchor_b`` [m] and ``axis_a`` /
    ``axis_b`` (unit) are in the frames of A and B; ``q`` = R_A0ᵀ R_B0 is the locked relative rotation (prismatic,
    fixed). For a universal joint ``axis_a`` is the cross axis carried by A and ``axis_b`` the one carried by B.
    """

    name: str
    type: str
    a: int
    b: int
    anchor_a: np.ndarray
    anchor_b: np.ndarray
    axis_a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis_b: np.ndarray = field(default_factory=lambda: np.zeros(3))
    q: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def n_rows(self) -> int:
        return JOINT_TYPES[self.type]


def _point(pose_a: Pose, pose_b: Pose, j: Joint) -> Any:
    (pa, ra), (pb, rb) = pose_a, pose_b
    return pa + ra @ j.anchor_a - pb - rb @ j.anchor_b


def _lock(pose_a: Pose, pose_b: Pose, j: Joint, ell: float) -> Any:
    ra, rb = pose_a[1], pose_b[1]
    rq = ra @ j.q
    return ell * ca.vertcat(rq[:, 0] - rb[:, 0], rq[:, 1] - rb[:, 1])


def joint_rows(j: Joint, pose_a: Pose, pose_b: Pose, ell: float) -> Any:
    """Constraint rows [m] of joint ``j`` (CasADi column) for the world poses of its two bodies."""
    if j.type == "spherical":
        return _point(pose_a, pose_b, j)
    if j.type == "revolute":
        return ca.vertcat(_point(pose_a, pose_b, j), ell * (pose_a[1] @ j.axis_a - pose_b[1] @ j.axis_b))
    if j.type == "universal":
        return ca.vertcat(_point(pose_a, pose_b, j), ell * ca.dot(pose_a[1] @ j.axis_a, pose_b[1] @ j.axis_b))
    if j.type == "fixed":
        return ca.vertcat(_point(pose_a, pose_b, j), _lock(pose_a, pose_b, j, ell))
    if j.type == "prismatic":
        d = -_point(pose_a, pose_b, j)
        n = pose_a[1] @ j.axis_a
        return ca.vertcat(_lock(pose_a, pose_b, j, ell), d - ca.dot(d, n) * n)
    raise ValueError(f"unknown joint type {j.type!r}")


def agent_rows(pose: Pose, height: float, ux: Any, uy: Any, yaw: Any, ell: float) -> Any:
    """Planar + motor constraint rows [m] of an omnidirectional agent (7 rows).

    ``height`` [m] is the fixed z of the agent frame, ``ux``, ``uy`` [m] and ``yaw`` [rad] the commanded pose (yaw is
    a control for complete actuation, a held parameter for reduced actuation).
    """
    p, r = pose
    return ca.vertcat(
        p[2] - height,
        ell * r[0, 2],
        ell * r[1, 2],
        p[0] - ux,
        p[1] - uy,
        ell * (r[0, 0] - ca.cos(yaw)),
        ell * (r[1, 0] - ca.sin(yaw)),
    )
