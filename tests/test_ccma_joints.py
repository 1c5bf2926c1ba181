"""Tests of tmr.ccma.joints: each joint type leaves exactly its degrees of freedom, and its residual vanishes
along the motions the joint allows (rotations about the axis, slides along it)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from tmr.ccma.bodies import cayley_sx, rot_axis
from tmr.ccma.joints import JOINT_TYPES, Joint, agent_rows, joint_rows

POINT = np.array([0.3, -0.2, 0.5])
AXIS = np.array([1.0, 2.0, 2.0]) / 3.0
AXIS2 = np.cross(AXIS, [0.0, 0.0, 1.0]) / np.linalg.norm(np.cross(AXIS, [0.0, 0.0, 1.0]))
P_A, R_A = np.array([0.1, 0.0, 0.2]), rot_axis(np.array([0.0, 1.0, 1.0]), 0.4)
P_B, R_B = np.array([0.5, 0.1, 0.4]), rot_axis(np.array([1.0, 0.0, 1.0]), -0.7)
DOF = {"revolute": 1, "prismatic": 1, "spherical": 3, "universal": 2, "fixed": 0}


def _joint(kind: str) -> Joint:
    return Joint(
        name=kind,
        type=kind,
        a=0,
        b=1,
        anchor_a=R_A.T @ (POINT - P_A),
        anchor_b=R_B.T @ (POINT - P_B),
        axis_a=R_A.T @ AXIS,
        axis_b=R_B.T @ (AXIS2 if kind == "universal" else AXIS),
        q=R_A.T @ R_B,
    )


def _residual_fn(kind: str):
    """C(x_B) with body A fixed at its pose and body B at (p, R_B cay(w))."""
    xb = ca.SX.sym("xb", 6)
    pose_b = (xb[:3], ca.DM(R_B) @ cayley_sx(xb[3:]))
    c = joint_rows(_joint(kind), (ca.DM(P_A), ca.DM(R_A)), pose_b, 0.1)
    return ca.Function("c", [xb], [c, ca.jacobian(c, xb)])


@pytest.mark.parametrize("kind", sorted(JOINT_TYPES))
def test_rows_vanish_at_reference_and_leave_the_joint_dof(kind):
    fn = _residual_fn(kind)
    c, jac = (np.asarray(v) for v in fn(np.concatenate([P_B, np.zeros(3)])))
    assert c.shape == (JOINT_TYPES[kind], 1)
    np.testing.assert_allclose(c, 0.0, atol=1e-15)
    sv = np.linalg.svd(jac, compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * sv[0]))
    assert 6 - rank == DOF[kind]


def _move_b(rot: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """State of B after rotating it by ``rot`` about POINT and translating by ``shift`` (world)."""
    p = POINT + rot @ (P_B - POINT) + shift
    r = rot @ R_B
    # Cayley vector of R_Bᵀ r: w = 2 tan(θ/2) a
    rel = R_B.T @ r
    angle = np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1))
    if angle < 1e-12:
        return np.concatenate([p, np.zeros(3)])
    a = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]]) / (2 * np.sin(angle))
    return np.concatenate([p, 2 * np.tan(angle / 2) * a])


@pytest.mark.parametrize(
    ("kind", "rot", "shift", "allowed"),
    [
        ("revolute", rot_axis(AXIS, 1.1), np.zeros(3), True),
        ("revolute", rot_axis(AXIS2, 0.2), np.zeros(3), False),
        ("prismatic", np.eye(3), 0.37 * AXIS, True),
        ("prismatic", np.eye(3), 0.1 * AXIS2, False),
        ("prismatic", rot_axis(AXIS, 0.3), np.zeros(3), False),
        ("spherical", rot_axis(np.array([0.3, -1.0, 0.2]), 1.3), np.zeros(3), True),
        ("spherical", np.eye(3), 0.01 * AXIS, False),
        ("universal", rot_axis(AXIS, 0.8), np.zeros(3), True),
        ("universal", rot_axis(AXIS2, -0.6), np.zeros(3), True),
        ("universal", rot_axis(np.cross(AXIS, AXIS2), 0.3), np.zeros(3), False),
        ("fixed", rot_axis(AXIS, 0.05), np.zeros(3), False),
    ],
)
def test_allowed_and_forbidden_finite_motions(kind, rot, shift, allowed):
    c = np.asarray(_residual_fn(kind)(_move_b(rot, shift))[0]).ravel()
    if allowed:
        assert np.max(np.abs(c)) < 1e-12
    else:
        assert np.max(np.abs(c)) > 1e-3


def test_agent_rows_fix_height_tilt_and_commanded_pose():
    x = ca.SX.sym("x", 6)
    u = ca.SX.sym("u", 3)
    pose = (x[:3], rot_axis(np.array([0.0, 0.0, 1.0]), 0.0) @ cayley_sx(x[3:]))
    fn = ca.Function("a", [x, u], [agent_rows(pose, 0.1, u[0], u[1], u[2], 0.1)])
    yaw = 0.7
    w = np.array([0.0, 0.0, 2 * np.tan(yaw / 2)])
    np.testing.assert_allclose(np.asarray(fn(np.r_[0.4, -0.3, 0.1, w], [0.4, -0.3, yaw])), 0.0, atol=1e-15)
    # a wrong height, a tilt, an x offset and a yaw offset each show up
    for dx in ([0, 0, 0.01, 0, 0, 0], [0, 0, 0, 0.02, 0, 0], [0.01, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0.05]):
        assert np.max(np.abs(np.asarray(fn(np.r_[0.4, -0.3, 0.1, w] + dx, [0.4, -0.3, yaw])))) > 1e-3
