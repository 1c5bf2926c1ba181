"""Tests of tmr.mcdpr.clearance: distances to the exact circles, rectangles and walls (analytic references)."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.mcdpr.clearance import point_clearance, segment_clearance
from tmr.mcdpr.scene import scene_from_dict

SCENE = scene_from_dict(
    {
        "bounds": [0, 0, 6, 4],
        "tasks": [[2, 2, 0.8], [3, 2, 0.8]],
        "bases": [[1, 1], [3, 1], [3, 3], [1, 3]],
        "tables": [{"center": [4.5, 1.0], "size": [1.0, 0.5]}],
        "obstacles": [{"center": [2.0, 3.0], "radius": 0.3}],
    }
)
R = 0.25


def test_point_clearance_analytic() -> None:
    pts = np.array([[2.0, 2.1], [4.5, 2.0], [0.5, 0.5], [5.9, 3.5], [2.0, 3.0]])
    ref = np.array(
        [
            min(0.9 - 0.3, 2.1),  # below the disc: 0.6 to the circle
            min(2.0 - 1.25, 4.0 - 2.0, 6.0 - 4.5),  # above the table's top edge y = 1.25; walls
            0.5,  # the corner walls
            min(6.0 - 5.9, 4.0 - 3.5),
            -0.3,  # at the disc centre
        ]
    )
    np.testing.assert_allclose(point_clearance(SCENE, R, pts), ref - R, atol=1e-12)


def test_disc_is_exact_not_its_polygon() -> None:
    # a point at 0.3 + R + 0.0002 m from the disc centre, in the direction between two polygon vertices: the
    # inscribed polygon would give more clearance than the circle; we use the circle
    ang = np.pi / 64  # half-way between vertices of the 64-gon
    p = np.array([2.0, 3.0]) + (0.3 + R + 2e-4) * np.array([np.cos(ang), np.sin(ang)])
    assert point_clearance(SCENE, R, p) == pytest.approx(2e-4, abs=1e-12)
    assert SCENE.discs.tolist() == [[2.0, 3.0, 0.3]]


def test_segment_clearance_is_the_minimum_along_the_segment() -> None:
    rng = np.random.default_rng(3)
    a = rng.uniform([0, 0], [6, 4], (200, 2))
    b = a + rng.normal(0, 0.8, (200, 2))
    got = segment_clearance(SCENE, R, a, b)
    s = np.linspace(0, 1, 2001)
    dense = point_clearance(SCENE, R, a[:, None] + s[None, :, None] * (b - a)[:, None]).min(axis=1)
    assert np.all(got <= dense + 1e-9)
    assert np.all(got >= dense - np.hypot(*(b - a).T) / 2000 - 1e-9)  # at most one sample step below
