"""Tests of tmr.mcdpr.scene: the shipped Fig. 2-like scene, way-point placement, validation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import shapely

from tmr.errors import ScenarioError
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.scene import builtin_scenes, load_scene, scene_from_dict, waypoints

R = mopick()


def test_fig2_scene_loads_and_is_valid() -> None:
    assert "fig2" in builtin_scenes()
    s = load_scene("fig2")
    env = s.validate(R)
    assert len(s.tables) == 3 and len(s.obstacles) == 4
    assert env.safety_radius == R.base_radius
    assert env.is_free(s.bases).all()


def test_intermediate_waypoints_maximise_obstacle_distance() -> None:
    s = load_scene("fig2")
    w = waypoints(s)
    assert len(w) == len(s.tasks) + (len(s.tasks) - 1) * s.intermediate
    np.testing.assert_array_equal(w[:: s.intermediate + 1], s.tasks)
    raw = shapely.union_all(list(s.tables) + list(s.obstacles))
    a, b = s.tasks[0], s.tasks[1]
    n = np.array([-(b - a)[1], (b - a)[0]]) / np.linalg.norm((b - a)[:2])
    base = a + (b - a) / (s.intermediate + 1)
    best = shapely.distance(raw, shapely.Point(w[1][:2]))
    for off in np.linspace(-s.lateral, s.lateral, 301):  # finer than the placement grid: within one grid step
        q = base[:2] + off * n
        assert shapely.distance(raw, shapely.Point(q)) <= best + 2 * s.lateral / 60 + 1e-9
    assert w[1][2] == pytest.approx(base[2])


def test_no_intermediate_points() -> None:
    s = dataclasses.replace(load_scene("fig2"), intermediate=0)
    np.testing.assert_array_equal(waypoints(s), s.tasks)


@pytest.mark.parametrize(
    "change, match",
    [
        ({"bases": [[2.0, 2.0], [3.1, 1.0], [3.1, 3.0], [0.9, 3.0]]}, "inside an obstacle"),
        ({"bases": [[0.9, 1.0], [1.0, 1.1], [3.1, 3.0], [0.9, 3.0]]}, "closer than"),
        ({"tasks": [[2.0, 2.0, 1.5], [5.0, 5.2, 0.8]]}, "task heights"),
        ({"tasks": [[2.0, 2.0, 0.8]]}, "at least 2"),
        ({"tasks": [[2.0, 2.0, 0.8], [12.0, 2.0, 0.8]]}, "outside the room"),
        ({"headings": [0.0]}, "headings"),
    ],
)
def test_invalid_scenes(change, match) -> None:
    from importlib import resources

    from tmr.mcdpr.scene import tomllib

    data = tomllib.loads(resources.files("tmr.mcdpr").joinpath("scenes").joinpath("fig2.toml").read_text())
    data.update(change)
    with pytest.raises(ScenarioError, match=match):
        scene_from_dict(data).validate(R)


def test_bad_files(tmp_path) -> None:
    with pytest.raises(ScenarioError, match="no scene"):
        load_scene(tmp_path / "missing.toml")
    p = tmp_path / "bad.toml"
    p.write_text("bounds = [0, 0, 1]\n")
    with pytest.raises(ScenarioError, match="bounds"):
        load_scene(p)
    p.write_text("bounds = [0, 0, 5, 5]\ncolour = 1\n")
    with pytest.raises(ScenarioError, match="unknown keys"):
        load_scene(p)
    p.write_text("bounds = [0, 0, 5, 5\n")
    with pytest.raises(ScenarioError, match="invalid TOML"):
        load_scene(p)
