"""Tests of tmr.mcdpr.robot: the MoPICK description, TOML loading and validation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.mcdpr.robot import Robot, load_robot, mopick


def test_mopick_values_from_the_paper() -> None:
    r = mopick()
    assert r.n_bases == 4 and r.n_cables == 4 and r.one_cable_per_base and r.axial_exits
    assert r.base_radius == 0.25
    np.testing.assert_array_equal(r.exit_points[:, 2], 1.2)
    assert (r.t_min, r.t_max) == (0.0, 15.0)
    d = Robot()  # the dataclass defaults are the shipped TOML
    for f in dataclasses.fields(Robot):
        assert np.array_equal(getattr(r, f.name), getattr(d, f.name)), f.name


def test_toml_roundtrip(tmp_path) -> None:
    p = tmp_path / "r.toml"
    p.write_text(
        'name = "two"\nn_bases = 2\ncable_base = [0, 0, 1]\nexit_points = [[0.1, 0, 1], [-0.1, 0, 1], [0, 0, 1]]\n'
    )
    r = load_robot(p)
    assert r.name == "two" and r.cable_base == (0, 0, 1) and not r.one_cable_per_base and not r.axial_exits


@pytest.mark.parametrize(
    "changes, match",
    [
        ({"cog": [0.5, 0.0, 0.3]}, "inside the footprint"),
        ({"footprint": [[0.2, 0], [0, -0.2], [-0.2, 0], [0, 0.2]]}, "anticlockwise"),
        ({"t_max": 0.0}, "t_max"),
        ({"cable_base": (0, 1, 2, 7)}, "cable_base"),
        ({"base_mass": -1.0}, "base_mass"),
        ({"exit_points": [[0, 0, 1.2]]}, "exit_points"),
        ({"footprint": [[0.2, 0], [0, 0.2], [-0.2, 0], [0, -0.2], [0.2, 0]]}, "coincide"),  # was NaN tipping rows
        ({"footprint": [[0.2, 0], [0, 0.2], [0, 0.2], [-0.2, 0], [0, -0.2]]}, "coincide"),
        ({"base_mass": "heavy"}, "base_mass must be a number"),
        ({"n_bases": 4.0}, "n_bases must be an integer"),
        ({"cable_base": ("a", "b", "c", "d")}, "cable_base entry"),
    ],
)
def test_invalid_robot(changes, match) -> None:
    with pytest.raises(ParameterError, match=match):
        mopick().replace(**changes)


def test_unknown_key(tmp_path) -> None:
    p = tmp_path / "r.toml"
    p.write_text("wheels = 3\n")
    with pytest.raises(ParameterError, match="unknown robot keys"):
        load_robot(p)
