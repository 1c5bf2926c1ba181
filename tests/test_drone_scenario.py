"""Drone scenarios (tmr.world.drones): loading, refusals, and the built-in F, G, H designs."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.errors import MapError, ParameterError, ScenarioError
from tmr.model.catenary3d import solve3d
from tmr.world.drones import DroneScenario, builtin_drone_scenarios, load_drone_scenario, scenario_kind
from tmr.world.scenario import SCENARIO_DIR, builtin_scenarios, load_scenario

HEAD = 'kind = "drone"\nrobots = 2\nbase = [1.0, 5.0, 0.3]\ngoal = [9.0, 5.0, 2.0]\n'
WORLD = "[world]\nbounds = [0.0, 0.0, 0.0, 10.0, 10.0, 4.0]\nsafety_radius = 0.3\n"
BOX = "[[world.obstacles]]\nbox = [4.0, 4.0, 0.0, 6.0, 6.0, 3.0]\n"


def _write(tmp_path, text: str, name: str = "s.toml"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_builtin_lists_are_split_by_kind():
    assert builtin_drone_scenarios() == ["F", "G", "H", "I"]
    assert builtin_scenarios() == ["A", "B", "C", "D", "E", "J"]
    assert [scenario_kind(n) for n in ("A", "f", "H")] == ["ground", "drone", "drone"]


@pytest.mark.parametrize("name", ["F", "G", "H"])
def test_builtin_drone_scenarios_load(name):
    sc = load_drone_scenario(name.lower())
    assert isinstance(sc, DroneScenario) and sc.name == name
    assert sc.source == SCENARIO_DIR / f"{name}.toml" and sc.text.startswith('name = "')
    assert sc.tether.drone_radius == sc.world.safety_radius == 0.3
    assert float(sc.world.exact_clearance(sc.goal)) > 0.0
    assert sc.world_table["bounds"] == list(sc.world.bounds)


def test_h_is_the_neptune_arena():
    sc = load_drone_scenario("H")
    assert sc.world.bounds == (0.0, 0.0, 0.0, 30.0, 30.0, 8.0)
    assert len(sc.world.obstacles) == 9 and sc.n_robots == 5
    assert sc.tether.tether_length == 9.0
    # 4 tethers of 9 m cannot even span the straight line from corner to corner
    assert np.linalg.norm(sc.goal - sc.base) > 4 * 9.0


def test_ground_loader_refuses_a_drone_file_and_vice_versa():
    with pytest.raises(ScenarioError, match="load_drone_scenario"):
        load_scenario("F")
    with pytest.raises(ScenarioError, match="load_drone_scenario"):
        load_scenario(SCENARIO_DIR / "G.toml")
    with pytest.raises(ScenarioError, match="not a drone scenario"):
        load_drone_scenario("A")


def test_ground_file_with_kind_ground_still_loads(tmp_path):
    text = (SCENARIO_DIR / "A.toml").read_text().replace('name = "A"', 'name = "A"\nkind = "ground"')
    p = _write(tmp_path, text, "A2.toml")
    (tmp_path / "A.geojson").write_text((SCENARIO_DIR / "A.geojson").read_text())
    assert load_scenario(p).n_robots == 3
    bad = _write(tmp_path, text.replace('kind = "ground"', 'kind = "boat"'), "A3.toml")
    with pytest.raises(ScenarioError, match="kind"):
        load_scenario(bad)
    with pytest.raises(ScenarioError, match="kind"):
        scenario_kind(bad)


def test_minimal_file_and_auto(tmp_path):
    sc = load_drone_scenario(_write(tmp_path, HEAD.replace("robots = 2", 'robots = "auto"') + WORLD + BOX))
    assert sc.n_robots == "auto" and sc.name == "s" and len(sc.world.obstacles) == 1
    sc2 = load_drone_scenario(_write(tmp_path, HEAD + "[tether]\ntether_length = 7.5\n[params]\ngrid = 0.5\n" + WORLD))
    assert sc2.tether.tether_length == 7.5 and sc2.drone_params().grid == 0.5


@pytest.mark.parametrize(
    ("extra", "error", "match"),
    [
        ("colour = 1\n", ScenarioError, "unknown keys"),
        ("[tether]\nlength = 3\n", ScenarioError, r"unknown keys in \[tether\]"),
        ("[tether]\ndrone_radius = 0.2\n", ScenarioError, "safety_radius"),
        ("[tether]\ntether_length = -1.0\n", ParameterError, "tether_length"),
        ("[params]\nspeed = 3\n", ParameterError, r"unknown \[params\]"),
        ("[params]\nTs = 0.0\n", ParameterError, "Ts"),
        ('[params]\nTs = "a"\n', ParameterError, r"\[params\]: DroneParams.Ts takes a number, got 'a'$"),
        ("[params]\ntether_samples = 2.5\n", ParameterError, "DroneParams.tether_samples takes a whole number"),
        ("[params]\nsolver = 3\n", ParameterError, "DroneParams.solver takes text"),
    ],
)
def test_bad_keys_and_values_refused(tmp_path, extra, error, match):
    text = HEAD + (extra if not extra.startswith("[") else "") + WORLD + (extra if extra.startswith("[") else "")
    with pytest.raises(error, match=match):
        load_drone_scenario(_write(tmp_path, text))


@pytest.mark.parametrize(
    ("base", "goal", "match"),
    [
        ("[1.0, 5.0, 0.1]", "[9.0, 5.0, 2.0]", "tether clearance"),  # the winch 0.1 m above the floor < c_t
        ("[5.0, 5.0, 1.0]", "[9.0, 5.0, 2.0]", "tether clearance"),  # the winch inside the box
        ("[1.0, 5.0, 0.3]", "[5.0, 5.0, 3.1]", "not free for a drone"),  # 0.1 m above the box: < r
        ("[1.0, 5.0, 0.3]", "[9.0, 5.0, 3.8]", "not free for a drone"),  # 0.2 m under the ceiling
        ("[1.0, 5.0, 0.3]", "[11.0, 5.0, 2.0]", "outside the room"),
    ],
)
def test_base_and_goal_checked(tmp_path, base, goal, match):
    text = HEAD.replace("[1.0, 5.0, 0.3]", base).replace("[9.0, 5.0, 2.0]", goal) + WORLD + BOX
    with pytest.raises(ScenarioError, match=match):
        load_drone_scenario(_write(tmp_path, text))


def test_params_take_their_fields_types(tmp_path):
    params = '[params]\nTs = 1\ntether_samples = 6.0\nsolver = "osqp"\n'
    sc = load_drone_scenario(_write(tmp_path, HEAD + WORLD + params))
    assert sc.params == {"Ts": 1.0, "tether_samples": 6, "solver": "osqp"}
    assert type(sc.params["Ts"]) is float and type(sc.params["tether_samples"]) is int


@pytest.mark.parametrize("point", ["[true, 5.0, 0.3]", "[1.0, false, 0.3]"])
def test_booleans_are_not_coordinates(tmp_path, point):
    with pytest.raises(ParameterError, match="base must be"):
        load_drone_scenario(_write(tmp_path, HEAD.replace("[1.0, 5.0, 0.3]", point) + WORLD))


def test_a_world_table_without_kind_points_at_the_drone_kind(tmp_path):
    p = _write(tmp_path, HEAD.replace('kind = "drone"\n', "") + WORLD)
    with pytest.raises(ScenarioError, match=r'a \[world\] table is a drone scenario: add kind = "drone"') as exc:
        load_scenario(p)
    assert "\n" not in str(exc.value)


def test_base_may_be_nearer_than_r_to_the_floor(tmp_path):
    # a winch, not a drone: 0.25 m above the floor (< r = 0.3, >= c_t = 0.2) is fine
    sc = load_drone_scenario(_write(tmp_path, HEAD.replace("[1.0, 5.0, 0.3]", "[1.0, 5.0, 0.25]") + WORLD))
    assert sc.base[2] == 0.25


def test_bad_world_and_robots(tmp_path):
    with pytest.raises(MapError):
        load_drone_scenario(_write(tmp_path, HEAD + "[world]\nbounds = [0, 0, 0, 1, 1]\n"))
    with pytest.raises(ParameterError, match="robots"):
        load_drone_scenario(_write(tmp_path, HEAD.replace("robots = 2", "robots = 0") + WORLD))
    with pytest.raises(ScenarioError, match="missing required key 'world'"):
        load_drone_scenario(_write(tmp_path, HEAD))
    with pytest.raises(ScenarioError, match="not found"):
        load_drone_scenario(tmp_path / "nope.toml")


def test_g_sag_binds_over_the_low_wall():
    """G: a level tether over the wall whose chord clears it by more than c_t while the catenary does not; higher,
    the catenary clears it, with little to spare under the ceiling."""
    sc = load_drone_scenario("G")
    bare = sc.world.with_safety_radius(0.0)
    c_t = sc.tether.clearance

    def clearances(z: float) -> tuple[float, float]:
        p, q = np.array([4.5, 3.0, z]), np.array([9.5, 3.0, z])
        cat = solve3d(p, q, sc.tether)
        return float(bare.segment_clearance(p, q)), float(bare.exact_clearance(cat.points(400)).min())

    chord, curve = clearances(2.10)
    assert chord > c_t + 0.05 and curve < c_t  # the chord would clear, the sag does not
    chord, curve = clearances(2.25)  # valid but tight: 0.015 m to spare; the chord has 0.25 m
    assert c_t < curve < c_t + 0.05 and chord > c_t + 0.2 and float(sc.world.exact_clearance([4.5, 3.0, 2.25])) > 0.3
