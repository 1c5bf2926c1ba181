"""Tests of tmr.ccma.paths: increments, circle geometry and input checks."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.ccma.bodies import rot_axis, rot_z, rotation_angle
from tmr.ccma.errors import CcmaError
from tmr.ccma.paths import make_path

P0 = np.array([0.1, -0.2, 0.5])


def test_circle_closes_with_steps_of_the_requested_length():
    path = make_path("circle", P0, np.eye(3), radius=0.05, step=1e-3)
    k = len(path.positions)
    assert k == int(np.ceil(2 * np.pi * 0.05 / 1e-3))
    np.testing.assert_allclose(path.positions[-1], P0, atol=1e-15)
    centre = P0 - [0.05, 0, 0]
    np.testing.assert_allclose(np.linalg.norm(path.positions - centre, axis=1), 0.05, rtol=1e-12)
    steps = np.linalg.norm(np.diff(np.vstack([P0, path.positions]), axis=0), axis=1)
    assert steps.max() <= 1e-3 and steps.min() > 0.99e-3
    np.testing.assert_allclose(path.rotations, np.tile(np.eye(3), (k, 1, 1)))


def test_combined_increments_translation_yaw_and_tilt():
    axis = np.array([0.0, 1.0, 0.0])
    path = make_path("combined", P0, rot_z(0.2), axis[None], steps=4, step=2e-3, rot_step=0.01)
    np.testing.assert_allclose(path.positions[-1], P0 + 8e-3)
    expected = rot_z(0.04) @ rot_z(0.2) @ rot_axis(axis, 0.04)
    assert rotation_angle(path.rotations[-1], expected) < 1e-14
    # consecutive targets differ by one increment: 0.01 rad yaw and 0.01 rad tilt
    assert 0.01 < rotation_angle(path.rotations[0], path.rotations[1]) < 0.02


def test_line_and_yaw():
    line = make_path("line", P0, np.eye(3), steps=3)
    np.testing.assert_allclose(line.positions, P0 + np.outer([1, 2, 3], [1e-3, 0, 0]))
    yaw = make_path("yaw", P0, np.eye(3), steps=2, rot_step=0.05)
    assert rotation_angle(yaw.rotations[1], rot_z(0.1)) < 1e-15
    np.testing.assert_allclose(yaw.positions, np.tile(P0, (2, 1)))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"kind": "spiral"}, "unknown path"),
        ({"step": 0.0}, "step"),
        ({"radius": float("nan")}, "radius"),
        ({"steps": 0}, "steps"),
    ],
)
def test_bad_arguments(kwargs, message):
    args = {"kind": "circle"} | kwargs
    kind = args.pop("kind")
    with pytest.raises(CcmaError, match=message):
        make_path(kind, P0, np.eye(3), **args)
