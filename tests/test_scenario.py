"""Tests of tmr.world.scenario: built-in scenarios A-D (Caruso 2021 §5), TOML loading, validation errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely

from tmr.errors import MapError, ParameterError, ScenarioError
from tmr.world.environment import Environment
from tmr.world.scenario import SCENARIO_DIR, Scenario, builtin_scenarios, load_scenario, scenario_from_map

D_MAX = 5.6  # m, tether max horizontal span (tmr.model.catenary.max_span() with the paper's parameters)

# Hand-made final chains (robots 1 and 2; robot 3 = leader at the goal) showing that every built-in goal can
# be reached by three straight tethers of at most D_MAX that go round the obstacles.
FINAL_CHAINS = {
    "A": [[3.3, 3.7], [5.8, 3.4]],
    "B": [[10.3, 7.9], [13.9, 5.5]],
    "C": [[3.4, 3.6], [6.6, 6.4]],
    "D": [[2.5, 9.3], [2.5, 4.7]],
}

TABLE = {  # bounds, base, goal (see tmr/scenarios/README.md)
    "A": ((0, 0, 10, 10), (1.0, 5.0), (6.7, 5.0)),
    "B": ((0, 0, 15.5, 10), (6.0, 7.5), (11.6, 3.5)),
    "C": ((0, 0, 10, 10), (4.0, 1.0), (9.0, 9.0)),
    "D": ((0, 0, 16, 14), (6.8, 10.5), (6.8, 3.5)),
}


@pytest.fixture(scope="module")
def scenarios() -> dict[str, Scenario]:
    return {name: load_scenario(name) for name in builtin_scenarios()}


def test_builtin_names() -> None:
    assert builtin_scenarios() == ["A", "B", "C", "D", "E", "J"]


def test_scenario_e_needs_more_than_three_robots(scenarios: dict[str, Scenario]) -> None:
    """E (tmr's): the straight line is 4 m, the route over the wall's end about 30.4 m, so 3 robots are refused."""
    from tmr.route.route import plan_route

    sc = scenarios["E"]
    route = plan_route(sc.environment, sc.base, sc.goal, [[0.5, D_MAX], [1.0, D_MAX]])
    assert np.linalg.norm(sc.goal - sc.base) == pytest.approx(4.0)
    assert 30.3 < route.length < 30.5 and 29.7 < route.lower_length < route.length and route.n_lower == 6
    assert route.n_min <= sc.n_robots and route.refusal(3).startswith("the goal needs at least 6 robots")


@pytest.mark.parametrize("name", ["A", "B", "C", "D"])
def test_builtin_scenario_values(scenarios: dict[str, Scenario], name: str) -> None:
    sc = scenarios[name]
    bounds, base, goal = TABLE[name]
    assert sc.name == name and sc.n_robots == 3 and sc.start is None and sc.params == {}
    assert sc.environment.bounds == tuple(float(v) for v in bounds)
    np.testing.assert_allclose(sc.base, base)
    np.testing.assert_allclose(sc.goal, goal)
    assert sc.environment.safety_radius == 0.5 and sc.environment.resolution == 0.05
    assert sc.source == SCENARIO_DIR / f"{name}.toml"
    assert sc.description
    # base and goal free with a margin, both exactly and on the field
    env = sc.environment
    pts = np.array([sc.base, sc.goal])
    assert np.all(env.exact_clearance(pts) >= 0.5 - 1e-9)
    assert np.all(env.clearance(pts) >= 0.45)
    # the straight line base -> goal is blocked: the leader has to go round something
    assert env.segment_clearance(sc.base, sc.goal) < 0.0


@pytest.mark.parametrize("name", ["A", "B", "C", "D"])
def test_builtin_final_chain_exists(scenarios: dict[str, Scenario], name: str) -> None:
    sc = scenarios[name]
    chain = np.array([sc.base, *FINAL_CHAINS[name], sc.goal])
    spans = np.linalg.norm(np.diff(chain, axis=0), axis=1)
    assert np.all(spans <= D_MAX - 0.5), spans
    assert np.all(spans >= 1.5), spans  # robots well apart
    assert np.all(sc.environment.exact_clearance(chain) > 0.3)
    assert np.all(sc.environment.segment_clearance(chain[:-1], chain[1:]) > 0.3)


def test_builtin_maps_carry_the_same_bounds(scenarios: dict[str, Scenario]) -> None:
    for name, sc in scenarios.items():
        doc = json.loads((SCENARIO_DIR / f"{name}.geojson").read_text())
        assert tuple(float(v) for v in doc["bounds"]) == sc.environment.bounds


def test_case_insensitive_and_path(scenarios: dict[str, Scenario]) -> None:
    sc = load_scenario("c")
    assert sc.name == "C"
    np.testing.assert_allclose(sc.goal, scenarios["C"].goal)
    sc2 = load_scenario(SCENARIO_DIR / "C.toml")
    np.testing.assert_allclose(sc2.base, scenarios["C"].base)
    sc3 = load_scenario(str(SCENARIO_DIR / "C.toml"))
    assert sc3.environment.free.equals(scenarios["C"].environment.free)


def test_scenario_a_goal_behind_middle_column(scenarios: dict[str, Scenario]) -> None:
    sc = scenarios["A"]
    columns = list(shapely.get_parts(sc.environment.obstacles))
    assert len(columns) == 5
    radii = [np.sqrt(c.area / np.pi) for c in columns]
    np.testing.assert_allclose(radii, 0.45, rtol=1e-3)
    middle = min(columns, key=lambda c: c.centroid.distance(shapely.Point(5, 5)))
    m = np.array([middle.centroid.x, middle.centroid.y])
    # the middle column lies between base and goal
    assert np.linalg.norm(sc.goal - sc.base) > np.linalg.norm(m - sc.base)
    line = shapely.LineString([sc.base, sc.goal])
    assert line.intersects(middle)


def test_scenario_b_goal_at_corridor_end_outside_room(scenarios: dict[str, Scenario]) -> None:
    env = scenarios["B"].environment
    goal = scenarios["B"].goal
    assert goal[0] > 10.0  # outside the 10 m x 10 m room, in the corridor
    # corridor free width >= 1.4 m everywhere along the hairpin: the centre line is at least 0.7 m from
    # obstacles
    th = np.linspace(np.pi / 2, -np.pi / 3, 31)  # (the last 30 degrees approach the dead end)
    centre = np.stack([11.5 + 2.0 * np.cos(th), 5.5 + 2.0 * np.sin(th)], axis=-1)
    np.testing.assert_allclose(env.exact_clearance(centre), 1.0, atol=2e-3)  # 3 m wide, grown by 0.5 m
    # high curvature: the corridor turns by 180 degrees with a 2 m centre-line radius; dead end just after the
    # goal
    assert env.is_free(goal) and not env.is_free([goal[0] - 0.6, goal[1]])


def test_scenario_c_goal_in_top_right_corner(scenarios: dict[str, Scenario]) -> None:
    sc = scenarios["C"]
    xmin, ymin, xmax, ymax = sc.environment.bounds
    np.testing.assert_allclose([xmax - sc.goal[0], ymax - sc.goal[1]], [1.0, 1.0])
    features = json.loads((SCENARIO_DIR / "C.geojson").read_text())["features"]
    assert len(features) == 5
    for feat in features:  # 0.2 m thick rectangular walls
        wall = shapely.geometry.shape(feat["geometry"])
        x0, y0, x1, y1 = wall.bounds
        assert wall.area == pytest.approx((x1 - x0) * (y1 - y0))
        assert min(x1 - x0, y1 - y0) == pytest.approx(0.2)


def test_scenario_d_cessna_dimensions(scenarios: dict[str, Scenario]) -> None:
    sc = scenarios["D"]
    plane = sc.environment.obstacles
    assert plane.geom_type == "Polygon"  # fuselage, wing and tailplane in one piece
    x0, y0, x1, y1 = plane.bounds
    assert x1 - x0 == pytest.approx(8.28, abs=1e-6)  # length (nose +x)
    assert y1 - y0 == pytest.approx(11.0, abs=1e-6)  # wingspan
    # base and goal on opposite sides of the fuselage axis (y = 7), between the wing and the tailplane
    assert (sc.base[1] - 7.0) * (sc.goal[1] - 7.0) < 0
    assert x0 < sc.base[0] < x1 and x0 < sc.goal[0] < x1
    # horizontal tailplane span 3.4 m: the plane's width at 0.5 m in front of the tail
    tail_cut = plane.intersection(shapely.box(x0 + 0.4, 0, x0 + 0.6, 14))
    assert tail_cut.bounds[3] - tail_cut.bounds[1] == pytest.approx(3.4, abs=1e-6)
    # the wing chord is about 1.5 m
    wing_cut = plane.intersection(shapely.box(0, 3.99, 16, 4.01))
    assert 1.1 <= wing_cut.bounds[2] - wing_cut.bounds[0] <= 1.7


# --------------------------------------------------------------------------------------------------- errors
def _write_toml(tmp_path: Path, body: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(body)
    return path


MAP_A = (SCENARIO_DIR / "A.geojson").as_posix()


def test_start_inside_obstacle_raises(tmp_path: Path) -> None:
    path = _write_toml(
        tmp_path,
        f'name = "bad"\nrobots = 3\nbase = [1.0, 5.0]\ngoal = [6.7, 5.0]\n'
        f'start = [[2.0, 5.0], [3.0, 5.0], [5.0, 5.2]]\n[map]\nfile = "{MAP_A}"\nbounds = [0, 0, 10, 10]\n',
    )
    with pytest.raises(ScenarioError, match=r"'bad'.*start of robot 3 \(5, 5.2\).*clearance -0\.7") as info:
        load_scenario(path)
    assert str(path) in str(info.value)


def test_start_loads_when_free(tmp_path: Path) -> None:
    path = _write_toml(
        tmp_path,
        f"base = [1.0, 5.0]\ngoal = [6.7, 5.0]\nstart = [[2.0, 5.0], [3.0, 5.0], [3.8, 4.4]]\n"
        f'[map]\nfile = "{MAP_A}"\n[params]\nk_v0 = 0.05\nd_min = 0.5\n',
    )
    sc = load_scenario(path)
    assert sc.name == "s" and sc.n_robots == 3 and sc.description == ""  # defaults
    assert sc.start is not None and sc.start.shape == (3, 2)
    assert sc.params == {"k_v0": 0.05, "d_min": 0.5}
    assert sc.environment.bounds == (0.0, 0.0, 10.0, 10.0)  # from the GeoJSON "bounds" member


@pytest.mark.parametrize(
    ("body", "error", "match", "tail"),
    [
        ("robots = 0\nbase = [1.0, 5.0]\ngoal = [6.7, 5.0]\n", ParameterError, "robots must be >= 1", ""),
        ("robots = 2.5\nbase = [1.0, 5.0]\ngoal = [6.7, 5.0]\n", ParameterError, "integer", ""),
        ("robots = true\nbase = [1.0, 5.0]\ngoal = [6.7, 5.0]\n", ParameterError, "integer", ""),
        ("base = [nan, 5.0]\ngoal = [6.7, 5.0]\n", ParameterError, "base contains NaN", ""),
        ("base = [1.0, 5.0]\ngoal = [inf, 5.0]\n", ParameterError, "goal contains NaN or inf", ""),
        ("base = [1.0, 5.0, 2.0]\ngoal = [6.7, 5.0]\n", ParameterError, r"base must be \[x, y\]", ""),
        (
            "base = [1.0, 5.0]\ngoal = [5.0, 5.0]\n",
            ScenarioError,
            r"goal \(5, 5\) m is not in free space",
            "",
        ),
        ("base = [0.2, 5.0]\ngoal = [6.7, 5.0]\n", ScenarioError, r"base \(0.2, 5\).*clearance -0.300", ""),
        ("base = [1.0, 5.0]\ngoal = [60.0, 5.0]\n", ScenarioError, "goal", ""),
        (
            "base = [1.0, 5.0]\ngoal = [6.7, 5.0]\nstart = [[2.0, 5.0]]\n",
            ParameterError,
            "one \\[x, y\\] per robot",
            "",
        ),
        ("goal = [6.7, 5.0]\n", ScenarioError, "missing required key 'base'", ""),
        ("base = [1.0, 5.0]\ngoal = [6.7, 5.0]\ngaol = 1\n", ScenarioError, "unknown keys \\['gaol'\\]", ""),
        ("base = [1.0, 5.0]\ngoal = [6.7, 5.0]\n", ParameterError, "params.k = nan", "[params]\nk = nan\n"),
    ],
)
def test_bad_scenario_files(tmp_path: Path, body: str, error: type[Exception], match: str, tail: str) -> None:
    path = _write_toml(tmp_path, body + f'[map]\nfile = "{MAP_A}"\n' + tail)
    with pytest.raises(error, match=match):
        load_scenario(path)


def test_bad_toml_and_map(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(_write_toml(tmp_path, "base = [1.0, \n"))
    with pytest.raises(ScenarioError, match="missing required key 'map'"):
        load_scenario(_write_toml(tmp_path, "base = [1.0, 5.0]\ngoal = [2.0, 5.0]\n"))
    with pytest.raises(MapError, match="map file not found"):
        load_scenario(_write_toml(tmp_path, 'base = [1, 5]\ngoal = [2, 5]\n[map]\nfile = "nowhere.geojson"\n'))
    with pytest.raises(ScenarioError, match="unknown keys in \\[map\\]"):
        load_scenario(_write_toml(tmp_path, f'base = [1, 5]\ngoal = [2, 5]\n[map]\nfile = "{MAP_A}"\nres = 1\n'))
    with pytest.raises(ParameterError, match="map.resolution"):
        load_scenario(
            _write_toml(tmp_path, f'base = [1, 5]\ngoal = [2, 5]\n[map]\nfile = "{MAP_A}"\nresolution = nan\n')
        )


def test_unknown_builtin_lists_available() -> None:
    with pytest.raises(ScenarioError, match="unknown scenario 'Z'.*A, B, C, D, E"):
        load_scenario("Z")  # F is a drone scenario now (tests/test_drone_scenario.py)
    with pytest.raises(ScenarioError, match="not found"):
        load_scenario("no/such/file.toml")


def test_scenario_from_map(tmp_path: Path) -> None:
    sc = scenario_from_map(SCENARIO_DIR / "D.geojson", base=(6.8, 10.5), goal=[6.8, 3.5])
    assert sc.name == "D" and sc.n_robots == 3 and sc.environment.bounds == (0.0, 0.0, 16.0, 14.0)
    np.testing.assert_allclose(sc.goal, [6.8, 3.5])
    (tmp_path / "room.wkt").write_text("POLYGON ((4 0, 4.2 0, 4.2 10, 4 10, 4 0))\n")  # wall splitting the room
    sc = scenario_from_map(tmp_path / "room.wkt", (1, 1), (3, 9), n_robots=1, bounds=(0, 0, 10, 10))
    assert sc.n_robots == 1
    with pytest.raises(ScenarioError, match="no free route from the base"):
        scenario_from_map(tmp_path / "room.wkt", (1, 1), (8, 8), bounds=(0, 0, 10, 10))
    with pytest.raises(ParameterError, match="robots must be >= 1"):
        scenario_from_map(SCENARIO_DIR / "A.geojson", (1, 5), (6.7, 5), n_robots=0)
    with pytest.raises(ScenarioError, match="start of robot 1"):
        scenario_from_map(SCENARIO_DIR / "A.geojson", (1, 5), (6.7, 5), start=[[5, 5]], n_robots=1)
    with pytest.raises(MapError, match="no room bounds"):
        scenario_from_map(tmp_path / "room.wkt", (1, 1), (3, 9))


def test_direct_construction_validates() -> None:
    env = Environment.from_geometry(None, (0, 0, 10, 10))
    sc = Scenario("x", "", env, np.array([1.0, 1.0]), np.array([9.0, 9.0]), None, np.int64(2))
    assert sc.n_robots == 2 and isinstance(sc.n_robots, int)
    with pytest.raises(ParameterError, match="robots must be >= 1"):
        Scenario("x", "", env, np.array([1.0, 1.0]), np.array([9.0, 9.0]), None, -1)


def test_one_robot_radius_from_the_caller_or_the_file(tmp_path):
    """load_scenario grows the obstacles by the caller's r (base and goal checked with it); a file's [params]
    safety_radius is the chain's and the map's r at once."""
    sc = load_scenario("A", safety_radius=0.3)
    assert sc.environment.safety_radius == 0.3
    assert sc.environment.obstacles.equals(load_scenario("A").environment.obstacles)
    assert sc.environment.free.area > load_scenario("A").environment.free.area  # less grown, more free space
    (tmp_path / "room.geojson").write_text('{"type": "FeatureCollection", "bounds": [0, 0, 8, 6], "features": []}')
    (tmp_path / "room.toml").write_text(
        'base = [1, 3]\ngoal = [7, 3]\n[map]\nfile = "room.geojson"\nsafety_radius = 0.5\n'
        "[params]\nsafety_radius = 0.2\n"
    )
    sc = load_scenario(tmp_path / "room.toml")
    assert sc.environment.safety_radius == 0.2 and sc.params["safety_radius"] == 0.2
    sc = load_scenario(tmp_path / "room.toml", safety_radius=0.25)
    assert sc.environment.safety_radius == 0.25 and sc.params["safety_radius"] == 0.25
