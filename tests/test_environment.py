"""Tests of tmr.world.environment: inflation, distance field vs exact distance, gradient, errors (map files:
test_maps)."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Point, Polygon, box

from tmr.errors import MapError, ParameterError
from tmr.world.environment import Environment, bilinear_interpolate
from tmr.world.scenario import builtin_scenarios, load_scenario

R = 0.5  # safety radius [m]


@pytest.fixture(scope="module")
def disc_env() -> Environment:
    """10 m x 10 m room, one disc of radius 1 m at (5, 5)."""
    return Environment.from_geometry(Point(5.0, 5.0).buffer(1.0, quad_segs=64), (0, 0, 10, 10), R, 0.05)


@pytest.fixture(scope="module")
def builtin_envs() -> dict[str, Environment]:
    return {name: load_scenario(name).environment for name in builtin_scenarios()}


# ---------------------------------------------------------------------------------------------------- exact
# queries
def test_exact_clearance_disc_and_walls(disc_env: Environment) -> None:
    pts = np.array([[8.0, 5.0], [5.0, 5.0], [5.0, 6.5], [2.0, 2.0], [0.2, 5.0], [-1.0, 5.0], [5.0, 1.0]])
    # disc grown to radius 1.5; walls grown inward to 0.5 from each side
    expected = np.array([min(3.0 - 1.5, 10 - 8.0 - R), -1.5, 0.0, min(math.hypot(3, 3) - 1.5, 2 - R), -0.3, -1.5, 0.5])
    got = disc_env.exact_clearance(pts)
    np.testing.assert_allclose(got, expected, atol=2e-3)  # the buffered circle is a 64-gon per quarter
    assert got[1] < 0 and got[5] < 0 and got[0] > 0


def test_queries_keep_leading_shape(disc_env: Environment) -> None:
    pts = np.random.default_rng(1).uniform(0.0, 10.0, size=(3, 4, 2))
    assert disc_env.exact_clearance(pts).shape == (3, 4)
    assert disc_env.clearance(pts).shape == (3, 4)
    d, g = disc_env.clearance_and_gradient(pts)
    assert d.shape == (3, 4) and g.shape == (3, 4, 2)
    assert disc_env.is_free(pts).shape == (3, 4)
    assert disc_env.segment_clearance(pts, np.array([1.0, 1.0])).shape == (3, 4)
    assert disc_env.exact_clearance([1.0, 1.0]).shape == ()


def test_bad_points_raise(disc_env: Environment) -> None:
    with pytest.raises(ParameterError, match="NaN"):
        disc_env.clearance([[1.0, np.nan]])
    with pytest.raises(ParameterError, match="shape"):
        disc_env.exact_clearance([1.0, 2.0, 3.0])


def test_is_free_with_margin(disc_env: Environment) -> None:
    pts = np.array([[8.0, 5.0], [6.6, 5.0], [5.0, 5.0], [0.55, 5.0]])  # clearances 1.5, 0.1, -1.5, 0.05
    np.testing.assert_array_equal(disc_env.is_free(pts), [True, True, False, True])
    np.testing.assert_array_equal(disc_env.is_free(pts, margin=0.08), [True, True, False, False])
    np.testing.assert_array_equal(disc_env.is_free(pts, margin=0.2), [True, False, False, False])
    np.testing.assert_array_equal(disc_env.is_free(pts, margin=-2.0), [True, True, True, True])
    np.testing.assert_array_equal(disc_env.is_free(pts, margin=0.08), disc_env.exact_clearance(pts) > 0.08)


def test_segment_clearance(disc_env: Environment) -> None:
    a = np.array([[2.0, 8.0], [2.0, 5.0], [5.0, 5.0], [2.0, 2.0], [1.0, 1.0], [7.0, 3.0]])
    b = np.array([[8.0, 8.0], [8.0, 5.0], [5.0, 5.0], [2.0, 2.0], [9.8, 1.0], [7.0, 7.0]])
    got = disc_env.segment_clearance(a, b)
    # y = 8 line: 3 - 1.5 = 1.5 from the disc, 2 - 0.5 = 1.5 from the top wall
    np.testing.assert_allclose(got[0], 1.5, atol=2e-3)
    # through the disc centre: deepest penetration = inflated radius 1.5 (sampled every 2.5 cm)
    np.testing.assert_allclose(got[1], -1.5, atol=2e-3)
    np.testing.assert_allclose(got[2], -1.5, atol=2e-3)  # zero length inside
    np.testing.assert_allclose(got[3], disc_env.exact_clearance([2.0, 2.0]), atol=1e-12)  # zero length free
    # ends at x = 9.8 > 10 - r: leaves the free space, 0.3 m deep into the grown right wall
    np.testing.assert_allclose(got[4], -0.3, atol=1e-9)
    np.testing.assert_allclose(got[5], 7.0 - 5.0 - 1.5, atol=2e-3)  # tangent-ish vertical segment at x = 7
    # the segment clearance is never above the clearance of its end points
    assert np.all(got <= np.minimum(disc_env.exact_clearance(a), disc_env.exact_clearance(b)) + 1e-12)


def test_segment_is_free_agrees_with_segment_clearance(builtin_envs: dict[str, Environment]) -> None:
    """The boolean test equals ``segment_clearance > margin`` on random segments (many of them blocked)."""
    rng = np.random.default_rng(3)
    for env in builtin_envs.values():
        xmin, ymin, xmax, ymax = env.bounds
        a = rng.uniform((xmin, ymin), (xmax, ymax), size=(400, 2))
        b = a + rng.normal(scale=3.0, size=(400, 2))
        b[:5] = a[:5]  # zero-length segments
        value = env.segment_clearance(a, b)
        for margin in (0.0, 0.03, 0.3, -0.1):
            got = env.segment_is_free(a, b, margin)
            assert got.dtype == bool and got.shape == (400,)
            np.testing.assert_array_equal(got, value > margin)
        per_segment = rng.uniform(0.0, 0.5, size=400)  # one margin per segment
        np.testing.assert_array_equal(env.segment_is_free(a, b, per_segment), value > per_segment)


def test_the_margin_test_is_the_nearest_distance_even_at_the_margin(builtin_envs: dict[str, Environment]) -> None:
    """``Environment._farther_than`` (only the boundary segments near each segment, stop 67) answers as the distance
    to the nearest boundary segment > the margin, also with each segment's margin its own distance, one rounding
    below or above it, or 0 (the envelopes' filter must not leave out the nearest segment at the margin)."""
    rng = np.random.default_rng(7)
    for env in builtin_envs.values():
        xmin, ymin, xmax, ymax = env.bounds
        a = rng.uniform((xmin, ymin), (xmax, ymax), size=(300, 2))
        b = a + rng.normal(scale=1.0, size=(300, 2))
        lines = shapely.linestrings(np.stack([a, b], axis=1))
        d = env._boundary_distance(lines)
        assert (d > 0.05).sum() > 100  # far from the boundary, not only on it
        for margin in (d, np.nextafter(d, 0.0), np.nextafter(d, np.inf), np.zeros_like(d), d + 0.1):
            np.testing.assert_array_equal(env._farther_than(lines, margin), d > margin)
        assert not env._farther_than(lines, d).any() and env._farther_than(lines, np.nextafter(d, 0.0))[d > 0].all()


def test_segment_is_free_on_and_from_the_boundary(builtin_envs: dict[str, Environment]) -> None:
    """Segments along the free space's boundary (``covers`` holds, clearance 0), from its vertices inward and
    outward, and across an obstacle with both ends free: the boolean test (the prepared boundary met or not, the
    start inside) still equals ``segment_clearance > margin``; and after pickling (the prepared boundary rebuilt)."""
    for env in builtin_envs.values():
        V = shapely.get_coordinates(shapely.boundary(env.free))
        a, b = V[:-1], V[1:]  # boundary edges (and the jumps between rings)
        inward = V + np.random.default_rng(4).normal(scale=0.4, size=V.shape)
        A = np.vstack([a, V, inward, a + 1e-9])
        B = np.vstack([b, inward, V, b + 1e-9])
        value = env.segment_clearance(A, B)
        for margin in (0.0, 0.03, 0.3):
            np.testing.assert_array_equal(env.segment_is_free(A, B, margin), value > margin)
        again = pickle.loads(pickle.dumps(env))
        np.testing.assert_array_equal(again.segment_is_free(A, B, 0.03), value > 0.03)


def test_thin_obstacle_crossing_is_negative() -> None:
    env = Environment.from_geometry(LineString([(5, 0), (5, 6)]), (0, 0, 10, 10), R, 0.05)
    # end points are free, the segment crosses the zero-thickness wall (a band 1 m wide once inflated)
    c = env.segment_clearance([2.0, 3.0], [8.0, 3.0])
    assert env.is_free([[2.0, 3.0], [8.0, 3.0]]).all()
    np.testing.assert_allclose(c, -0.5, atol=0.013)
    assert env.segment_clearance([2.0, 8.0], [8.0, 8.0]) > 0.0  # passes above the end of the wall


# ----------------------------------------------------------------------------------------------------- grid
# field
def test_bilinear_exact_on_linear_field() -> None:
    origin, h = (-1.0, 2.0), 0.1
    i, j = np.meshgrid(np.arange(30), np.arange(20), indexing="ij")
    x, y = origin[0] + h * i, origin[1] + h * j
    grid = np.stack([2.0 * x - 3.0 * y + 0.5, -x + 0.25 * y], axis=-1)
    pts = np.random.default_rng(3).uniform([-1.0, 2.0], [1.9, 3.9], size=(200, 2))
    got = bilinear_interpolate(grid, origin, h, pts)
    expected = np.stack([2 * pts[:, 0] - 3 * pts[:, 1] + 0.5, -pts[:, 0] + 0.25 * pts[:, 1]], axis=-1)
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # outside points are clamped onto the grid rectangle
    np.testing.assert_allclose(bilinear_interpolate(grid[..., 0], origin, h, [[-5.0, 2.0]]), [2.0 * -1.0 - 6 + 0.5])


def test_field_is_linear_near_a_wall() -> None:
    """Away from corners and other obstacles the field is the exact distance to the grown wall (linear)."""
    env = Environment.from_geometry(None, (0, 0, 10, 4), R, 0.05)
    x = np.linspace(1.0, 9.0, 50)
    pts = np.stack([x, np.full_like(x, 0.8)], axis=-1)  # 0.3 m above the grown bottom wall
    d, g = env.clearance_and_gradient(pts)
    np.testing.assert_allclose(d, 0.3, atol=1e-9)
    np.testing.assert_allclose(g, np.tile([0.0, 1.0], (50, 1)), atol=1e-9)
    # inside the wall (between the grown wall boundary and the room edge) the field is negative and linear too
    np.testing.assert_allclose(env.clearance([[5.0, 0.2]]), [-0.3], atol=1e-9)


def test_field_matches_exact_distance_builtin(builtin_envs: dict[str, Environment]) -> None:
    rng = np.random.default_rng(2021)
    for name, env in builtin_envs.items():
        xmin, ymin, xmax, ymax = env.bounds
        pts = rng.uniform([xmin, ymin], [xmax, ymax], size=(4000, 2))
        err = np.abs(env.clearance(pts) - env.exact_clearance(pts))
        assert err.max() <= env.resolution, f"scenario {name}: field error {err.max():.4f} m > one cell"
        assert np.percentile(err, 99) < 0.3 * env.resolution


def test_field_sign_matches_occupancy(builtin_envs: dict[str, Environment]) -> None:
    rng = np.random.default_rng(7)
    for env in builtin_envs.values():
        xmin, ymin, xmax, ymax = env.bounds
        pts = rng.uniform([xmin, ymin], [xmax, ymax], size=(4000, 2))
        exact = env.exact_clearance(pts)
        far = np.abs(exact) > env.resolution
        np.testing.assert_array_equal(env.clearance(pts)[far] > 0, exact[far] > 0)


def _fd_gradient(env: Environment, p: np.ndarray, step: float) -> np.ndarray:
    """Central finite differences of the exact clearance."""
    ex, ey = np.array([step, 0.0]), np.array([0.0, step])
    return np.stack(
        [
            (env.exact_clearance(p + ex) - env.exact_clearance(p - ex)) / (2 * step),
            (env.exact_clearance(p + ey) - env.exact_clearance(p - ey)) / (2 * step),
        ],
        axis=-1,
    )


def test_gradient_matches_finite_differences(builtin_envs: dict[str, Environment]) -> None:
    rng = np.random.default_rng(11)
    for name, env in builtin_envs.items():
        h = env.resolution
        xmin, ymin, xmax, ymax = env.bounds
        pts = rng.uniform([xmin, ymin], [xmax, ymax], size=(3000, 2))

        # keep points where the exact distance is smooth over a few cells: away from the medial axis, the
        # boundary (raster staircase) and the polygon vertices of the grown arcs
        g_small, g_big = _fd_gradient(env, pts, 1e-4), _fd_gradient(env, pts, 3 * h)
        smooth = (
            (np.abs(env.exact_clearance(pts)) > 3 * h)
            & (np.linalg.norm(g_big, axis=1) > 0.995)
            & (np.linalg.norm(g_small - g_big, axis=1) < 0.01)
        )
        assert smooth.sum() > 1000, name
        _, grad = env.clearance_and_gradient(pts[smooth])
        err = np.linalg.norm(grad - g_small[smooth], axis=1)
        assert np.percentile(err, 95) < 0.03, f"scenario {name}"
        assert err.max() < 0.15, f"scenario {name}"
        cos = np.sum(grad * g_small[smooth], axis=1) / np.linalg.norm(grad, axis=1)
        assert cos.min() > 0.99, f"scenario {name}"


def test_gradient_points_away_from_obstacle(disc_env: Environment) -> None:
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    u = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
    for radius in (0.8, 2.0):  # inside the disc (negative side) and outside
        _, g = disc_env.clearance_and_gradient(np.array([5.0, 5.0]) + radius * u)
        np.testing.assert_array_less(0.95, np.sum(g * u, axis=1))


def test_field_beyond_grid_decreases(disc_env: Environment) -> None:
    d, g = disc_env.clearance_and_gradient([[-3.0, 5.0], [5.0, 14.0], [-30.0, -30.0]])
    np.testing.assert_allclose(d[:2], [-3.5, -4.5], atol=0.03)
    np.testing.assert_allclose(g[0], [1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(g[1], [0.0, -1.0], atol=1e-9)
    assert d[2] < -40.0 and np.all(g[2] > 0.7)


def test_field_sees_free_slivers_thinner_than_a_cell() -> None:
    # inflated boxes leave a 2 cm wide free sliver at x in [4.5, 4.52] that contains no cell centre
    env = Environment.from_geometry([box(2, 0, 4, 4), box(5.02, 0, 8, 4)], (0, 0, 10, 4), R, 0.05)
    pts = np.array([[3.8, 2.0], [5.5, 2.0], [4.51, 2.0]])
    np.testing.assert_allclose(env.exact_clearance(pts), [-0.7, -0.98, 0.01], atol=1e-9)
    np.testing.assert_allclose(env.clearance(pts), env.exact_clearance(pts), atol=env.resolution)


def test_grid_layout_and_occupancy(disc_env: Environment) -> None:
    f = disc_env.distance_field
    x0, y0 = disc_env.grid_origin
    assert f.shape == disc_env.occupancy.shape == (208, 208)  # 10 m / 5 cm + 4 padding cells each side
    np.testing.assert_allclose((x0, y0), (-0.175, -0.175))
    np.testing.assert_array_equal(disc_env.occupancy, f < 0)
    assert disc_env.occupancy[:4].all() and disc_env.occupancy[:, -4:].all()  # padding outside the room


def test_large_room_field_is_fine_grained() -> None:
    env = Environment.from_geometry([box(3, 3, 5, 17), Point(12, 12).buffer(1.0)], (0, 0, 20, 20), R, 0.05)
    assert env.distance_field.shape == (408, 408)
    np.testing.assert_allclose(env.clearance([[10.0, 10.0]]), env.exact_clearance([[10.0, 10.0]]), atol=0.05)


def test_pickle_round_trip(disc_env: Environment) -> None:
    disc_env.clearance([1.0, 1.0])  # build the caches first
    env2 = pickle.loads(pickle.dumps(disc_env))
    pts = np.array([[2.0, 3.0], [5.0, 5.5]])
    np.testing.assert_allclose(env2.exact_clearance(pts), disc_env.exact_clearance(pts))
    np.testing.assert_allclose(env2.clearance(pts), disc_env.clearance(pts))


# ------------------------------------------------------------------------------------------------------------
# construction
def test_inflated_and_free_geometry(disc_env: Environment) -> None:
    assert disc_env.bounds == (0.0, 0.0, 10.0, 10.0)
    assert disc_env.free.area == pytest.approx(81.0 - math.pi * 1.5**2, rel=1e-3)
    assert disc_env.obstacles.area == pytest.approx(math.pi, rel=1e-3)
    assert disc_env.inflated.contains(Point(0.2, 0.2)) and disc_env.inflated.contains(Point(5, 6.2))
    assert not disc_env.inflated.intersects(Point(3.0, 3.0))


def test_obstacles_are_clipped_to_the_room() -> None:
    env = Environment.from_geometry([box(-5, -5, 1, 1), box(20, 20, 30, 30)], (0, 0, 10, 10))
    assert env.obstacles.area == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("obstacles", "bounds", "match"),
    [
        (None, (0, 0, 0.8, 10), "empty room"),
        (None, (0, 0, -1, 10), "empty room"),
        (None, (0, 0, 10), "bounds"),
        (None, (0, 0, float("nan"), 10), "finite"),
        (box(0, 0, 10, 10), (0, 0, 10, 10), "no free space"),
        (Polygon([(0, 0), (2, 2), (2, 0), (0, 2)]), (0, 0, 10, 10), "invalid geometry"),
        (["not a geometry"], (0, 0, 10, 10), "not a shapely geometry"),
    ],
)
def test_bad_geometry_raises(obstacles, bounds, match: str) -> None:
    with pytest.raises(MapError, match=match):
        Environment.from_geometry(obstacles, bounds)


def test_bad_parameters_raise() -> None:
    with pytest.raises(ParameterError, match="resolution"):
        Environment.from_geometry(None, (0, 0, 10, 10), resolution=0.0)
    with pytest.raises(ParameterError, match="safety_radius"):
        Environment.from_geometry(None, (0, 0, 10, 10), safety_radius=-0.1)
    with pytest.raises(ParameterError, match="coarser resolution"):
        Environment.from_geometry(None, (0, 0, 1000, 1000), resolution=0.01)


def test_free_region_numbers_the_connected_pieces() -> None:
    """A wall across the room splits the free space in two: points on either side get different indices, points
    on the same side the same one, points in an obstacle or outside the room −1."""
    env = Environment.from_geometry(box(4.9, 0.0, 5.1, 10.0), (0, 0, 10, 10), R, 0.05)
    pts = np.array([[2.0, 2.0], [2.0, 8.0], [8.0, 2.0], [8.0, 8.0], [5.0, 5.0], [12.0, 5.0]])
    region = env.free_region(pts)
    assert region.shape == (6,)
    assert region[0] == region[1] >= 0 and region[2] == region[3] >= 0 and region[0] != region[2]
    assert region[4] == -1 and region[5] == -1
    assert env.free_region(pts.reshape(2, 3, 2)).shape == (2, 3)


def test_visible_region_matches_segment_tests() -> None:
    """Points in the visible region are exactly those within the radius whose segment from the point is free (the
    textbook definition, tested point by point with ``segment_is_free``), on a cluttered room and round a disc."""
    from tmr.sweep.rooms import generate_room

    rng = np.random.default_rng(7)
    for env, p in (
        (generate_room(2845717476, "dense", "far").environment(), np.array([17.869, 10.493])),
        (Environment.from_geometry([Point(5.0, 5.0).buffer(1.0)], (0.0, 0.0, 10.0, 10.0)), np.array([2.0, 5.0])),
    ):
        region = env.visible_region(p, 5.6)
        q = p + rng.uniform(-6.0, 6.0, (6000, 2))
        d = np.linalg.norm(q - p, axis=1)
        free = env.segment_is_free(np.broadcast_to(p, q.shape), q) & (d <= 5.6)
        inside = shapely.contains_xy(region, q[:, 0], q[:, 1])
        # the disc is a circumscribed 64-gon: up to 0.12 % beyond the radius, a free segment may count as visible
        rim = (d > 5.6) & (d <= 5.6 / math.cos(math.pi / 64))
        near_edge = shapely.distance(shapely.boundary(region), shapely.points(q)) < 1e-6
        assert np.array_equal(inside[~near_edge & ~rim], free[~near_edge & ~rim])
        assert not np.any(free & ~inside & ~near_edge)
        assert free.sum() > 500 and (~free).sum() > 500
