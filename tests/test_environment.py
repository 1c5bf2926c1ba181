"""Tests of tmr.environment: inflation, distance field vs exact distance, gradient, map loaders, errors."""

from __future__ import annotations

import json
import math
import pickle
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import LineString, Point, Polygon, box

from tmr.environment import Environment, bilinear_interpolate, parse_map_yaml, read_pgm
from tmr.errors import MapError, ParameterError
from tmr.scenario import builtin_scenarios, load_scenario

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


# ------------------------------------------------------------------------------------------------------ ROS
# maps
def _write_pgm_p5(path: Path, img: np.ndarray, maxval: int = 255, comment: bool = True) -> None:
    h, w = img.shape
    header = b"P5\n" + (b"# CREATOR: test\n" if comment else b"") + f"{w} {h}\n{maxval}\n".encode()
    dtype = ">u2" if maxval > 255 else "u1"
    path.write_bytes(header + img.astype(dtype).tobytes())


def _ros_image() -> np.ndarray:
    """40 x 60 pixels (2 m x 3 m at 5 cm): white (free), a black 10 x 10 block, a grey (unknown) strip."""
    img = np.full((40, 60), 254, dtype=np.int64)
    img[5:15, 20:30] = 0  # occupied: rows 5..14 from the top, columns 20..29
    img[30:40, 50:60] = 205  # unknown (trinary grey)
    return img


def _check_ros_env(env: Environment) -> None:
    # origin (-1, -0.5): the image covers x in [-1, 2], y in [-0.5, 1.5]
    assert env.bounds == pytest.approx((-1.0, -0.5, 2.0, 1.5))
    # occupied block: x in [-1 + 20*0.05, -1 + 30*0.05] = [0, 0.5], y from 1.5 - 15*0.05 = 0.75 to 1.25
    assert env.obstacles.area == pytest.approx(0.25 + 0.25, rel=1e-9)  # block + unknown strip (0.5 m x 0.5 m)
    assert env.obstacles.covers(box(0.0, 0.75, 0.5, 1.25))
    assert env.obstacles.covers(box(1.5, -0.5, 2.0, 0.0))  # unknown cells are obstacles
    # nearest: the grown corner of the block at (0.5, 0.75)
    np.testing.assert_allclose(env.exact_clearance([[1.0, 0.4]]), [math.hypot(0.5, 0.35) - R], atol=1e-3)


def test_ros_map_p5(tmp_path: Path) -> None:
    _write_pgm_p5(tmp_path / "map.pgm", _ros_image())
    (tmp_path / "map.yaml").write_text(
        "# map_saver output\nimage: map.pgm\nresolution: 0.050000\norigin: [-1.0, -0.5, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n"
    )
    env = Environment.from_file(tmp_path / "map.yaml")
    _check_ros_env(env)
    assert env.source == tmp_path / "map.yaml"


def test_ros_map_p2_negate_block_list(tmp_path: Path) -> None:
    img = 255 - _ros_image()  # negated image: 255 - v
    h, w = img.shape
    rows = "\n".join(" ".join(str(v) for v in row) for row in img)
    (tmp_path / "m.pgm").write_text(f"P2\n# ascii\n{w} {h}\n255\n{rows}\n")
    (tmp_path / "m.yaml").write_text(
        'image: "m.pgm"   # quoted\nresolution: 0.05\norigin:\n  - -1.0\n  - -0.5\n  - 0.0\nnegate: 1\n'
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    _check_ros_env(Environment.from_file(tmp_path / "m.yaml"))


def test_ros_map_16bit_and_png(tmp_path: Path) -> None:
    import matplotlib.image as mpimg

    img = _ros_image()
    _write_pgm_p5(tmp_path / "m16.pgm", img * 257, maxval=65535, comment=False)
    yaml = "resolution: 0.05\norigin: [-1.0, -0.5, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    (tmp_path / "m16.yaml").write_text("image: m16.pgm\n" + yaml)
    _check_ros_env(Environment.from_file(tmp_path / "m16.yaml"))
    mpimg.imsave(tmp_path / "m.png", img / 255.0, cmap="gray", vmin=0.0, vmax=1.0)
    (tmp_path / "mp.yaml").write_text("image: m.png\n" + yaml)
    _check_ros_env(Environment.from_file(tmp_path / "mp.yaml"))


def test_ros_map_yaw_rotates(tmp_path: Path) -> None:
    _write_pgm_p5(tmp_path / "map.pgm", _ros_image())
    (tmp_path / "map.yaml").write_text(f"image: map.pgm\nresolution: 0.05\norigin: [0.0, 0.0, {math.pi / 2}]\n")
    env = Environment.from_file(tmp_path / "map.yaml")
    # rotated by +90 deg about the origin: the 3 m x 2 m image covers x in [-2, 0], y in [0, 3]
    assert env.bounds == pytest.approx((-2.0, 0.0, 0.0, 3.0), abs=1e-9)
    # the block (image x in [1, 1.5], y in [1.25, 1.75]) maps to x in [-1.75, -1.25], y in [1, 1.5]
    assert env.obstacles.buffer(1e-9).covers(box(-1.75, 1.0, -1.25, 1.5))


def test_parse_map_yaml() -> None:
    meta = parse_map_yaml(
        "---\nimage: 'my map.pgm'  # comment\nresolution: 0.025\norigin: [ -10, -10.5, 0.0 ]\nnegate: false\n"
        "mode: scale\n"
    )
    assert meta == {
        "image": "my map.pgm",
        "resolution": 0.025,
        "origin": [-10, -10.5, 0.0],
        "negate": False,
        "mode": "scale",
    }


def test_read_pgm_values(tmp_path: Path) -> None:
    img = np.arange(12).reshape(3, 4) * 20
    _write_pgm_p5(tmp_path / "a.pgm", img)
    pixels, maxval = read_pgm(tmp_path / "a.pgm")
    assert maxval == 255
    np.testing.assert_array_equal(pixels, img)


@pytest.mark.parametrize(
    ("yaml", "image", "match"),
    [
        ("this is: not: [valid\n", None, "line 1"),
        ("just garbage without colon\n", None, "expected 'key: value'"),
        ("image: map.pgm\nresolution: 0.05\n", b"P5\n2 2\n255\n\x00\x00\x00\x00", "origin"),
        (
            "image: map.pgm\nresolution: -0.05\norigin: [0, 0, 0]\n",
            b"P5\n2 2\n255\n\x00\x00\x00\x00",
            "resolution",
        ),
        (
            "image: map.pgm\nresolution: abc\norigin: [0, 0, 0]\n",
            b"P5\n2 2\n255\n\x00\x00\x00\x00",
            "resolution",
        ),
        ("image: other.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", None, "other.pgm not found"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", b"P6\n2 2\n255\n" + bytes(12), "not a PGM"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", b"P5\nxx 2\n255\n", "bad PGM header"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", b"P5\n20 20\n255\n\x00\x00", "truncated"),
        (
            "image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.9\n",
            b"P5\n2 2\n255\n" + bytes(4),
            "free_thresh",
        ),
        (
            "image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fancy\n",
            b"P5\n2 2\n255\n" + bytes(4),
            "mode",
        ),
        ("resolution: 0.05\norigin: [0, 0, 0]\nresolution: 0.1\n", None, "duplicate key"),
        ("", None, "empty map yaml"),
    ],
)
def test_ros_map_errors(tmp_path: Path, yaml: str, image: bytes | None, match: str) -> None:
    (tmp_path / "map.yaml").write_text(yaml)
    if image is not None:
        (tmp_path / "map.pgm").write_bytes(image)
    with pytest.raises(MapError, match=match) as info:
        Environment.from_file(tmp_path / "map.yaml")
    assert "map." in str(info.value)  # names the file


def test_all_black_map_has_no_free_space(tmp_path: Path) -> None:
    _write_pgm_p5(tmp_path / "map.pgm", np.zeros((40, 40)))
    (tmp_path / "map.yaml").write_text("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(MapError, match="no free space"):
        Environment.from_file(tmp_path / "map.yaml")


# -------------------------------------------------------------------------------------------------- GeoJSON
# / WKT
def test_geojson_loader(tmp_path: Path) -> None:
    doc = {
        "type": "FeatureCollection",
        "bounds": [0, 0, 10, 8],
        "features": [
            {
                "type": "Feature",
                "properties": {"name": "block"},
                "geometry": {"type": "Polygon", "coordinates": [[[1, 1], [3, 1], [3, 2], [1, 2], [1, 1]]]},
            },
            {
                "type": "Feature",
                "properties": {"radius": 0.5},
                "geometry": {"type": "Point", "coordinates": [6, 4]},
            },
            {
                "type": "Feature",
                "properties": {"width": 0.2},
                "geometry": {"type": "LineString", "coordinates": [[8, 0], [8, 3]]},
            },
            {
                "type": "Feature",
                "properties": {},
                "geometry": {"type": "MultiPolygon", "coordinates": [[[[1, 6], [2, 6], [2, 7], [1, 6]]]]},
            },
            {"type": "Feature", "properties": {}, "geometry": None},
        ],
    }
    (tmp_path / "m.geojson").write_text(json.dumps(doc))
    env = Environment.from_file(tmp_path / "m.geojson")
    assert env.bounds == (0.0, 0.0, 10.0, 8.0)
    assert env.obstacles.area == pytest.approx(2.0 + math.pi * 0.25 + 0.6 + 0.5, rel=1e-3)
    np.testing.assert_allclose(env.exact_clearance([[6.0, 6.0]]), [2.0 - 1.0], atol=1e-3)
    np.testing.assert_allclose(env.exact_clearance([[9.0, 1.5]]), [0.9 - R], atol=1e-9)
    # explicit bounds win over the file's
    assert Environment.from_file(tmp_path / "m.geojson", bounds=(0, 0, 12, 9)).bounds == (0.0, 0.0, 12.0, 9.0)
    # a bare geometry needs explicit bounds
    (tmp_path / "g.json").write_text(json.dumps(doc["features"][0]["geometry"]))
    with pytest.raises(MapError, match="no room bounds"):
        Environment.from_file(tmp_path / "g.json")
    assert Environment.from_file(tmp_path / "g.json", bounds=(0, 0, 5, 5)).obstacles.area == pytest.approx(2.0)


def test_wkt_loader(tmp_path: Path) -> None:
    (tmp_path / "a.wkt").write_text(
        "# two obstacles\n# bounds: 0 0 10 10\nPOLYGON ((1 1, 3 1, 3 3, 1 3, 1 1))\nLINESTRING (5 0, 5 6)\n"
    )
    env = Environment.from_file(tmp_path / "a.wkt")
    assert env.bounds == (0.0, 0.0, 10.0, 10.0)
    assert env.obstacles.area == pytest.approx(4.0)
    np.testing.assert_allclose(env.exact_clearance([[5.0, 7.0]]), [0.5], atol=2e-3)  # above the grown line end
    (tmp_path / "b.wkt").write_text("GEOMETRYCOLLECTION (\n  POLYGON ((1 1, 3 1, 3 3, 1 3, 1 1)),\n  POINT (7 7))\n")
    env = Environment.from_file(tmp_path / "b.wkt", bounds=(0, 0, 10, 10))
    assert env.exact_clearance([7.0, 7.0]) == pytest.approx(-R, abs=1e-3)  # 64-gon disc
    with pytest.raises(MapError, match="no room bounds"):
        Environment.from_file(tmp_path / "b.wkt")


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [
        ("bad.geojson", "{not json", "not valid JSON"),
        (
            "bad.geojson",
            '{"type": "FeatureCollection", "bounds": [0, 0, 5, 5], "features": [{"type": "Feature", '
            '"properties": {"name": "bow"}, "geometry": {"type": "Polygon", "coordinates": '
            "[[[0, 0], [2, 2], [2, 0], [0, 2], [0, 0]]]}}]}",
            r"invalid geometry.*Self-intersection",
        ),
        (
            "bad.geojson",
            '{"type": "FeatureCollection", "bounds": [0, 0, 5, 5], "features": [{"type": "Feature", '
            '"properties": {"radius": -1}, "geometry": {"type": "Point", "coordinates": [1, 1]}}]}',
            "radius",
        ),
        ("bad.geojson", '{"type": "FeatureCollection", "bounds": [0, 0, 5], "features": []}', "bounds"),
        ("bad.geojson", '{"type": "Topology"}', "unsupported geometry type"),
        ("bad.geojson", "[1, 2]", "not a GeoJSON object"),
        ("bad.wkt", "# bounds: 0 0 10 10\nPOLYGON ((1 1, 3 1, 3 3\n", "not valid WKT"),
        ("bad.wkt", "# bounds: 0 0 10 10\nPOLYGON ((0 0, 2 2, 2 0, 0 2, 0 0))\n", "invalid geometry"),
        ("map.txt", "whatever", "unknown map format"),
        ("map.pgm", "P5", "yaml"),
    ],
)
def test_vector_map_errors(tmp_path: Path, name: str, text: str, match: str) -> None:
    (tmp_path / name).write_text(text)
    with pytest.raises(MapError, match=match) as info:
        Environment.from_file(tmp_path / name)
    assert name in str(info.value)


def test_missing_map_file(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="not found") as info:
        Environment.from_file(tmp_path / "nope.yaml")
    assert "nope.yaml" in str(info.value)
