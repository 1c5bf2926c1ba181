"""The seeded 3-D benchmark worlds (tmr.sweep.rooms3d): determinism, free base and goal, families, TOML round trip,
reachability by construction vs an independent voxel flood fill."""

from __future__ import annotations

import math
import sys
from collections import Counter

import numpy as np
import pytest

from tmr.sweep.rooms3d import (
    BASE_CLEARANCE,
    BASE_Z,
    CLOSABLE,
    DRONE_RADIUS,
    FAMILIES,
    GOAL_CLEARANCE,
    drone_world,
    drone_worlds,
    scenario_toml,
    voxel_reachable,
)
from tmr.world.world3d import world3d_from_table

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - python 3.10
    import tomli as tomllib


@pytest.fixture(scope="module")
def worlds():
    return drone_worlds(100, seed=0)


def test_same_seed_and_index_same_world_whatever_else_is_made():
    a = drone_world(7, 13)
    drone_worlds(5, seed=7)  # other worlds of the seed drawn in between change nothing
    b = drone_world(7, 13)
    assert a.toml == b.toml and a.scenario == b.scenario
    assert drone_worlds(14, seed=7)[13].toml == a.toml
    assert drone_world(8, 13).toml != a.toml  # another seed, another world
    assert drone_world(7, 17).toml != a.toml  # same family (13 % 4 == 17 % 4), another world


def test_families_sizes_and_tethers(worlds):
    assert Counter(w.family for w in worlds) == {f: 25 for f in FAMILIES}
    for w in worlds:
        assert w.family == FAMILIES[w.index % 4] and w.name == f"{w.family}-0-{w.index}"
        x0, y0, z0, x1, y1, z1 = w.scenario["world"]["bounds"]
        assert (x0, y0, z0) == (0.0, 0.0, 0.0)
        assert 10.0 <= x1 <= 30.0 and 10.0 <= y1 <= 30.0 and 4.0 <= z1 <= 8.0
        assert 6.0 <= w.tether_length <= 14.0
        assert w.scenario["kind"] == "drone" and w.scenario["world"]["safety_radius"] == DRONE_RADIUS
        assert len(w.scenario["world"]["obstacles"]) >= 1
    # the tether length varies, so that the number of drones a straight flight needs does too
    needs = Counter(math.ceil(float(np.linalg.norm(w.goal - w.base)) / w.tether_length) for w in worlds)
    assert len(needs) >= 4
    # unreachable goals: only behind a closed window or a wall up to the ceiling, every 5th of those families
    closed = [w for w in worlds if not w.reachable]
    assert {w.family for w in closed} == set(CLOSABLE) and len(closed) == 10


def test_base_and_goal_free_for_a_drone(worlds):
    for w in worlds:
        world = world3d_from_table(w.scenario["world"])
        assert world.safety_radius == DRONE_RADIUS
        c_base, c_goal = world.clearance(np.vstack([w.base, w.goal]))
        assert w.base[2] == BASE_Z
        assert c_base >= BASE_CLEARANCE - 1e-9, w.name
        assert c_goal >= GOAL_CLEARANCE - 1e-9, w.name


def test_toml_round_trip(worlds, tmp_path):
    for w in worlds:
        loaded = tomllib.loads(w.toml)
        assert loaded == w.scenario, w.name
        assert set(loaded) == {"name", "kind", "description", "robots", "base", "goal", "world", "tether"}
        assert len(world3d_from_table(loaded["world"]).obstacles) == len(w.scenario["world"]["obstacles"])
    path = worlds[3].write(tmp_path)
    assert path.name == "warehouse-0-3.toml" and path.read_bytes() == worlds[3].toml.encode()


def test_scenario_toml_escapes_and_tables():
    text = scenario_toml({"name": 'a "b" \\ c', "n": 3, "ok": True, "t": {"x": [1.5, 2.0]}, "u": {"k": 1}})
    assert tomllib.loads(text) == {"name": 'a "b" \\ c', "n": 3, "ok": True, "t": {"x": [1.5, 2.0]}, "u": {"k": 1}}
    with pytest.raises(ValueError):
        scenario_toml({"x": math.nan})


def _wall_with_window(height: float) -> dict:
    """A 10 × 10 × 4 m room cut by a wall at x = 5 with a 2 m wide window of the given height, sill 1 m."""
    top = 1.0 + height
    return {
        "bounds": [0.0, 0.0, 0.0, 10.0, 10.0, 4.0],
        "obstacles": [
            {"box": [4.9, 0.0, 0.0, 5.1, 10.0, 1.0]},
            {"box": [4.9, 0.0, top, 5.1, 10.0, 4.0]},
            {"box": [4.9, 0.0, 1.0, 5.1, 4.0, top]},
            {"prism": [[4.9, 6.0], [5.1, 6.0], [5.1, 10.0], [4.9, 10.0]], "z": [1.0, top]},
        ],
    }


def test_voxel_reachable_against_hand_made_windows():
    base, goal = (2.0, 5.0, 0.4), (8.0, 5.0, 2.0)
    assert voxel_reachable(_wall_with_window(1.0), base, goal)
    assert not voxel_reachable(_wall_with_window(0.5), base, goal)  # 0.5 m < 2r = 0.6 m
    assert voxel_reachable(_wall_with_window(0.5), base, goal, radius=0.15)
    assert voxel_reachable(_wall_with_window(0.5), base, (2.0, 8.0, 3.0))  # same side of the wall


def test_reachable_by_construction_agrees_with_the_voxel_flood_fill(worlds):
    # the first world of each family and the first closed window and low wall (indices 17, 18)
    for w in [*worlds[:4], worlds[17], worlds[18]]:
        assert voxel_reachable(w.scenario["world"], w.base, w.goal) == w.reachable, w.name
    assert not worlds[17].reachable and not worlds[18].reachable


@pytest.mark.slow
def test_reachable_by_construction_agrees_with_the_voxel_flood_fill_everywhere(worlds):
    for w in worlds:
        assert voxel_reachable(w.scenario["world"], w.base, w.goal) == w.reachable, w.name


def test_the_drone_scenario_loader_reads_the_generated_files(worlds, tmp_path):
    drones = pytest.importorskip("tmr.world.drones")  # piece A of issue 32 (the scenario loader)
    for w in worlds[:8]:
        sc = drones.load_drone_scenario(w.write(tmp_path))
        assert sc.name == w.name
        assert np.array_equal(sc.base, w.base) and np.array_equal(sc.goal, w.goal)
        assert sc.tether.tether_length == w.tether_length and sc.tether.drone_radius == DRONE_RADIUS
        assert len(sc.world.obstacles) == len(w.scenario["world"]["obstacles"])
