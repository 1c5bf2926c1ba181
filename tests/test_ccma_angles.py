"""Tests of tmr.ccma.angles: joint angles against closed-form leg geometry, and zero for rigid slides."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.ccma.angles import joint_angles, joint_ranges, rotary_joints
from tmr.ccma.bodies import rot_z
from tmr.ccma.control import track
from tmr.ccma.energy import EnergyModel
from tmr.ccma.sim import end_effector_pose, reference_state
from tmr.ccma.system import load_system

ARM = np.hypot(0.4, 0.2)  # arm of the shipped legs: elbow (r 0.6, z 0.3) to wrist (r 0.2, z 0.5) [m]


@pytest.fixture(scope="module")
def reduced() -> EnergyModel:
    return EnergyModel(load_system("4dof-reduced"))


def _track(model, positions, rotations):
    return track(model, np.asarray(positions), np.asarray(rotations), keep_states=True)


def test_reference_has_zero_angles_and_fixed_joints_are_left_out(reduced):
    names = [reduced.system.joints[k].name for k in rotary_joints(reduced)]
    assert names == [f"{j}_{leg}" for leg in "abc" for j in ("elbow", "wrist")] + [f"agent_{x}.mount" for x in "abc"]
    np.testing.assert_allclose(joint_angles(reduced, [reference_state(reduced)]), 0.0, atol=1e-12)
    complete = EnergyModel(load_system("4dof-complete"))
    assert all(complete.system.joints[k].type != "fixed" for k in rotary_joints(complete))
    assert len(rotary_joints(complete)) == 6  # bolted mounts have no angle


@pytest.mark.parametrize("dz", [-0.1, 0.05, 0.2])
def test_lifting_the_platform_turns_elbow_and_wrist_by_the_arm_elevation(reduced, dz):
    """A level platform raised by dz: every arm's elevation goes from asin(0.2/L) to asin((0.2 + dz)/L); the elbow
    turns by that difference and the wrist back by the same (the platform stays level)."""
    st = reference_state(reduced)
    p0, r0 = end_effector_pose(reduced, st)
    zs = np.linspace(0, dz, 6)[1:]
    res = _track(reduced, p0 + np.outer(zs, [0, 0, 1]), np.tile(r0, (5, 1, 1)))
    a = joint_angles(reduced, res.states)
    expected = np.arcsin((0.2 + zs) / ARM) - np.arcsin(0.2 / ARM)
    for leg in range(3):
        elbow, wrist = a[:, 2 * leg], a[:, 2 * leg + 1]
        np.testing.assert_allclose(np.abs(elbow), np.abs(expected), atol=2e-6)
        np.testing.assert_allclose(wrist, -elbow, atol=1e-9)
        assert np.all(np.sign(elbow) == np.sign(dz))
    np.testing.assert_allclose(a[:, 6:], 0.0, atol=1e-9)  # the posts do not turn on their agents


def test_yawing_the_platform_turns_every_post_on_its_agent(reduced):
    """Reduced actuation: the agents keep their heading, so a platform yaw ψ turns each post by ψ about the vertical
    mount axis, and the legs stay unbent."""
    st = reference_state(reduced)
    p0, r0 = end_effector_pose(reduced, st)
    psi = np.array([0.05, 0.1, 0.15])
    res = _track(reduced, np.tile(p0, (3, 1)), np.array([rot_z(v) @ r0 for v in psi]))
    a = joint_angles(reduced, res.states)
    np.testing.assert_allclose(a[:, 6:], np.tile(psi[:, None], (1, 3)), atol=1e-8)
    np.testing.assert_allclose(a[:, :6], 0.0, atol=1e-8)


def test_a_horizontal_slide_leaves_every_angle_at_zero(reduced):
    st = reference_state(reduced)
    p0, r0 = end_effector_pose(reduced, st)
    res = _track(reduced, p0 + np.outer([0.01, 0.02], [1, 1, 0]), np.tile(r0, (2, 1, 1)))
    assert max(r.span for r in joint_ranges(reduced, joint_angles(reduced, res.states))) < 1e-12


def test_universal_joint_angle_is_the_total_rotation():
    """6-dof example raised by 0.05 m: the universal elbow turns about its tangential axis only, so its total angle
    equals the arm's change of elevation."""
    m = EnergyModel(load_system("6dof-reduced"))
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    res = _track(m, [p0 + [0, 0, 0.05]], [r0])
    a = joint_angles(m, res.states)[0]
    names = [m.system.joints[k].name for k in rotary_joints(m)]
    expected = np.arcsin(0.25 / ARM) - np.arcsin(0.2 / ARM)
    assert a[names.index("elbow_a")] == pytest.approx(expected, abs=2e-6)
    assert a[names.index("elbow_a")] >= 0


def test_ranges():
    m = EnergyModel(load_system("4dof-reduced"))
    a = np.zeros((3, len(rotary_joints(m))))
    a[:, 0] = [0.1, -0.2, 0.3]
    r = joint_ranges(m, a)
    assert (r[0].name, r[0].low, r[0].high) == ("elbow_a", -0.2, 0.3) and r[0].span == pytest.approx(0.5)
    assert joint_ranges(m, np.zeros((0, len(a[0]))))[0].span == 0.0
