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


def _steps(path):
    return np.linalg.norm(np.diff(np.vstack([P0, path.positions]), axis=0), axis=1)


def test_vertical_circle_rises_first_and_closes():
    path = make_path("vcircle", P0, np.eye(3), radius=0.05, step=1e-3)
    k = len(path.positions)
    assert k == int(np.ceil(2 * np.pi * 0.05 / 1e-3))
    centre = P0 + [0, 0, 0.05]
    np.testing.assert_allclose(np.linalg.norm(path.positions - centre, axis=1), 0.05, rtol=1e-12)
    np.testing.assert_allclose(path.positions[:, 1], P0[1])  # in the x–z plane
    assert path.positions[0, 2] > P0[2] and path.positions[:, 2].max() == pytest.approx(P0[2] + 0.1, abs=5e-6)
    np.testing.assert_allclose(path.positions[-1], P0, atol=1e-15)
    assert 0.99e-3 < _steps(path).min() and _steps(path).max() <= 1e-3


def test_figure_eight_lies_on_its_implicit_surfaces():
    """x = r sin s, y = r sin s cos s, z = r sin² s  ⇒  z = x²/r and y² = x²(1 − x²/r²); steps of equal length."""
    r = 0.08
    path = make_path("figure8", P0, np.eye(3), radius=r, step=2e-3)
    x, y, z = (path.positions - P0).T
    np.testing.assert_allclose(z, x**2 / r, atol=1e-12)
    np.testing.assert_allclose(y**2, x**2 * (1 - x**2 / r**2), atol=1e-12)
    assert np.ptp(x) == pytest.approx(2 * r, rel=1e-3) and np.ptp(z) == pytest.approx(r, rel=1e-3)
    steps = _steps(path)
    assert steps.max() <= 2e-3 and steps.min() > 0.99 * steps.max()
    np.testing.assert_allclose(path.positions[-1], P0, atol=1e-15)
    assert (x > 0).any() and (x < 0).any()  # both lobes


@pytest.mark.parametrize(("kind", "col"), [("tilt", 0), ("roll", 1)])
def test_tilt_and_roll_sweep_one_axis(kind, col):
    axes = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    path = make_path(kind, P0, rot_z(0.3), axes, amplitude=0.2, rot_step=0.01)
    k = len(path.positions)
    assert k == int(np.ceil(2 * np.pi * 0.2 / 0.01))
    np.testing.assert_allclose(path.positions, np.tile(P0, (k, 1)))
    theta = 0.2 * np.sin(2 * np.pi * np.arange(1, k + 1) / k)
    theta[-1] = 0.0
    for i in (0, k // 4, k // 2, k - 1):
        expected = rot_z(0.3) @ rot_axis(axes[col], theta[i])
        assert rotation_angle(path.rotations[i], expected) < 1e-14
    angles = [rotation_angle(a, b) for a, b in zip(path.rotations[:-1], path.rotations[1:], strict=True)]
    assert max(angles) <= 0.01 + 1e-12


def test_step_cap_is_checked_before_allocating(monkeypatch):
    """A path of 6e12 targets is refused from its count alone: nothing is allocated (np.arange would fail)."""
    import tmr.ccma.paths as paths

    paths._unit_length("figure8")  # the figure-eight's unit length is computed once (a fixed 65536-segment polyline)

    def boom(*a, **k):
        raise AssertionError("allocated")

    monkeypatch.setattr(paths.np, "arange", boom)
    monkeypatch.setattr(paths.np, "linspace", boom)
    for kind, kw in (("vcircle", {"radius": 1e9}), ("figure8", {"step": 1e-12}), ("line", {"steps": 10**12})):
        with pytest.raises(CcmaError, match="more than the cap of 100000"):
            make_path(kind, P0, np.eye(3), **kw)
    with pytest.raises(CcmaError, match="more than the cap of 10"):
        make_path("tilt", P0, np.eye(3), [[1, 0, 0]], max_steps=10)


def test_tilt_needs_the_axis():
    with pytest.raises(CcmaError, match="0 tilt axis"):
        make_path("tilt", P0, np.eye(3))
    with pytest.raises(CcmaError, match="1 tilt axis"):
        make_path("roll", P0, np.eye(3), [[1, 0, 0]])
