"""tmr.world.world3d: the 3-D world (coal distances) against exact formulas worked out independently here — the
Euclidean distance to an axis-aligned box, the planar polygon distance (shapely) combined with the z range for a
prism, the floor and ceiling — plus its gradient (finite differences), its segments (dense sampling), a mesh file
equal to a box, and the loader's refusals."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import trimesh
from shapely.geometry import Polygon

from tmr.errors import MapError
from tmr.world import World
from tmr.world.world3d import World3D, box_obstacle, mesh_obstacle, prism_obstacle, world3d_from_table

R = 0.1
BOUNDS = (0.0, 0.0, 0.0, 6.0, 4.0, 3.0)
BOX = (np.array([1.0, 1.0, 0.5]), np.array([2.0, 2.5, 1.5]))
# a non-convex (L-shaped) footprint, extruded from z = 0.5 to 2.0
L_XY = [[3.5, 0.5], [5.0, 0.5], [5.0, 1.2], [4.2, 1.2], [4.2, 3.0], [3.5, 3.0]]
L_Z = (0.5, 2.0)


def box_sd(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Signed Euclidean distance to an axis-aligned box (negative inside): the textbook formula."""
    q = np.maximum(lo - p, p - hi)
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


def prism_sd(p: np.ndarray, xy, z) -> np.ndarray:
    """Signed distance to the extrusion of a polygon: the 2-D signed distance (shapely) and the z gap combined like
    the box formula (the prism is the product of the polygon and the z interval)."""
    poly = Polygon(xy)
    pts = shapely.points(p[:, 0], p[:, 1])
    d2 = shapely.distance(poly.exterior, pts) * np.where(shapely.contains(poly, pts), -1.0, 1.0)
    dz = np.maximum(z[0] - p[:, 2], p[:, 2] - z[1])
    q = np.c_[d2, dz]
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


def room_sd(p: np.ndarray) -> np.ndarray:
    b = np.asarray(BOUNDS)
    return np.minimum((p - b[:3]).min(axis=-1), (b[3:] - p).min(axis=-1))


def expected(p: np.ndarray) -> np.ndarray:
    return np.minimum.reduce([room_sd(p), box_sd(p, *BOX), prism_sd(p, L_XY, L_Z)]) - R


@pytest.fixture(scope="module")
def world() -> World3D:
    return World3D([box_obstacle(*BOX), prism_obstacle(L_XY, L_Z)], BOUNDS, R)


def sample(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(BOUNDS[:3], BOUNDS[3:], size=(n, 3))


def test_world3d_is_a_world(world):
    assert isinstance(world, World)
    assert world.bounds == BOUNDS and world.safety_radius == R
    assert world.with_safety_radius(R) is world


def test_exact_clearance_matches_the_box_prism_and_room_formulas(world):
    p = sample(400, 1)
    got = world.exact_clearance(p)
    np.testing.assert_allclose(got, expected(p), atol=1e-7)
    # both signs are exercised: points inside each obstacle and free ones
    assert np.any(box_sd(p, *BOX) < 0) and np.any(prism_sd(p, L_XY, L_Z) < 0) and np.any(got > 0)
    assert world.exact_clearance(p.reshape(20, 20, 3)).shape == (20, 20)
    np.testing.assert_array_equal(world.clearance(p), got)


def test_points_near_the_floor_ceiling_and_in_the_prism_notch(world):
    pts = np.array(
        [
            [0.5, 3.5, 0.05],  # 0.05 m above the floor
            [0.5, 3.5, 2.9],  # 0.1 m under the ceiling
            [4.6, 2.0, 1.0],  # in the L's notch, 0.4 m from the wall x = 4.2 and 0.8 m from y = 1.2
            [4.0, 2.0, 1.0],  # inside the L's upright, 0.2 m from x = 4.2
            [1.5, 1.75, 1.6],  # 0.1 m above the box's top
            [-0.5, 2.0, 1.0],  # outside the room, 0.5 m beyond the wall x = 0
        ]
    )
    np.testing.assert_allclose(
        world.exact_clearance(pts), [0.05 - R, 0.1 - R, 0.4 - R, -0.2 - R, 0.1 - R, -0.5 - R], atol=1e-9
    )
    np.testing.assert_allclose(world.exact_clearance(pts), expected(pts), atol=1e-9)


def test_gradient_is_the_unit_normal_and_the_derivative_of_the_clearance(world):
    p = sample(150, 2)
    d, g = world.clearance_and_gradient(p)
    np.testing.assert_allclose(d, world.exact_clearance(p))
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-9)
    h = 1e-5
    fd = np.stack(
        [(world.clearance(p + h * e) - world.clearance(p - h * e)) / (2 * h) for e in np.eye(3)],
        axis=1,
    )
    # away from the medial surfaces (where the nearest feature switches) the gradient is the derivative
    agree = np.linalg.norm(fd - g, axis=1) < 1e-4
    assert agree.mean() > 0.9
    # 0.2 m left of the box (0.8 m from the wall), the gradient is -x; inside the box near its top face, +z
    _, g0 = world.clearance_and_gradient(np.array([[0.8, 1.75, 1.0], [1.5, 1.75, 1.4]]))
    np.testing.assert_allclose(g0, [[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-9)


def test_segment_clearance_is_the_smallest_clearance_along_the_segment(world):
    rng = np.random.default_rng(3)
    a = sample(120, 4)
    b = np.clip(a + rng.normal(scale=1.0, size=a.shape), BOUNDS[:3], BOUNDS[3:])
    got = world.segment_clearance(a, b)
    t = np.linspace(0.0, 1.0, 201)
    dense = expected((a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]).reshape(-1, 3)).reshape(len(a), -1)
    lowest = dense.min(axis=1)
    free = lowest > 0
    assert free.sum() > 20 and (~free).sum() > 10
    # free segments: the exact minimum (sampling overestimates it by at most the step's worth)
    step = np.linalg.norm(b - a, axis=1) / 200
    assert np.all(got[free] <= lowest[free] + 1e-7) and np.all(got[free] >= lowest[free] - step[free])
    assert np.all(got[~free] <= 1e-7)  # touching or crossing a grown obstacle: <= 0
    # a segment lying wholly inside the non-convex prism is not free; a zero-length one is its point
    assert world.segment_clearance([3.7, 2.0, 1.0], [3.8, 2.5, 1.5]) < 0
    assert world.segment_clearance([0.5, 3.5, 1.0], [0.5, 3.5, 1.0]) == pytest.approx(
        expected(np.array([[0.5, 3.5, 1.0]]))[0]
    )
    for margin in (0.0, 0.2):
        np.testing.assert_array_equal(world.segment_is_free(a, b, margin), got > margin)
    np.testing.assert_array_equal(world.is_free(a, 0.1), world.exact_clearance(a) > 0.1)


def test_with_safety_radius_shifts_every_clearance(world):
    p = sample(50, 5)
    wider = world.with_safety_radius(R + 0.2)
    np.testing.assert_allclose(wider.exact_clearance(p), world.exact_clearance(p) - 0.2, atol=1e-12)


def test_a_mesh_file_gives_the_distances_of_its_box(tmp_path):
    lo, hi = BOX
    mesh = trimesh.creation.box(bounds=np.array([lo, hi]))
    mesh.export(tmp_path / "block.stl")
    # a non-convex mesh too (a box with a notch cut: the L prism, written as a mesh), so the BVH path is tested
    ell = trimesh.Trimesh(*_prism_mesh(L_XY, L_Z))
    ell.export(tmp_path / "ell.ply")
    from_files = World3D([mesh_obstacle(tmp_path / "block.stl"), mesh_obstacle(tmp_path / "ell.ply")], BOUNDS, R)
    p = sample(300, 6)
    # STL stores float32 coordinates: agreement to 1e-6 m
    np.testing.assert_allclose(from_files.exact_clearance(p), expected(p), atol=1e-6)
    a, b = p[:60], p[60:120]
    shapes = World3D([box_obstacle(*BOX), prism_obstacle(L_XY, L_Z)], BOUNDS, R)
    np.testing.assert_array_equal(from_files.segment_clearance(a, b) > 0, shapes.segment_clearance(a, b) > 0)


def _prism_mesh(xy, z):
    """The L prism as a closed mesh built here independently: the footprint's triangles (shapely) and the walls."""
    poly = shapely.geometry.polygon.orient(Polygon(xy))
    ring = np.asarray(poly.exterior.coords)[:-1]
    n = len(ring)
    verts = np.vstack([np.c_[ring, np.full(n, z[0])], np.c_[ring, np.full(n, z[1])]])
    faces = [[i, (i + 1) % n, n + (i + 1) % n] for i in range(n)] + [[i, n + (i + 1) % n, n + i] for i in range(n)]
    for tri in shapely.get_parts(shapely.constrained_delaunay_triangles(poly)):
        k = [int(np.argmin(np.linalg.norm(ring - c, axis=1))) for c in np.asarray(tri.exterior.coords)[:3]]
        t = ring[k]
        if (t[1, 0] - t[0, 0]) * (t[2, 1] - t[0, 1]) - (t[1, 1] - t[0, 1]) * (t[2, 0] - t[0, 0]) < 0:
            k = [k[0], k[2], k[1]]
        faces += [[n + k[0], n + k[1], n + k[2]], [k[0], k[2], k[1]]]
    return verts, np.asarray(faces)


def test_the_loader_builds_the_world_from_a_scenario_table(tmp_path):
    trimesh.creation.box(bounds=np.array(BOX)).export(tmp_path / "block.obj")
    table = {
        "bounds": list(BOUNDS),
        "safety_radius": R,
        "obstacles": [{"mesh": "block.obj"}, {"prism": L_XY, "z": list(L_Z)}],
    }
    w = world3d_from_table(table, base=tmp_path)
    p = sample(100, 7)
    np.testing.assert_allclose(w.exact_clearance(p), expected(p), atol=1e-7)
    w2 = world3d_from_table({"bounds": list(BOUNDS), "safety_radius": R, "obstacles": [{"box": [*BOX[0], *BOX[1]]}]})
    np.testing.assert_allclose(w2.exact_clearance(p), np.minimum(room_sd(p), box_sd(p, *BOX)) - R, atol=1e-9)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"bounds": [0, 0, 0, 1, 1, 1], "gravity": 9.8}, "unknown key(s) gravity"),
        ({"safety_radius": 0.1}, "missing 'bounds'"),
        ({"bounds": [0, 0, 1, 1, 1]}, "bounds must be 6 numbers"),
        ({"bounds": [0, 0, 0, 1, float("nan"), 1]}, "bounds contains NaN or inf"),
        ({"bounds": [0, 0, 2, 1, 1, 1]}, "empty room"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "safety_radius": -0.1}, "safety_radius must be a finite number >= 0"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"box": [0, 0, 0, 1, 1]}]}, "box must be 6 numbers"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"box": [0.5, 0, 0, 0.2, 1, 1]}]}, "empty box"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"box": [0, 0, 0, 1, 1, "x"]}]}, "box must be numbers"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"sphere": 1}]}, "needs exactly one of box, prism, mesh"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"box": [0, 0, 0, 1, 1, 1], "z": [0, 1]}]}, "unknown key(s) z"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"prism": [[0, 0], [1, 0], [0, 1]]}]}, "needs z = [z0, z1]"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"prism": [[0, 0], [1, 0], [0, 1]], "z": [1, 0]}]}, "z1 > z0"),
        (
            {"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"prism": [[0, 0], [1, 1], [1, 0], [0, 1]], "z": [0, 1]}]},
            "not a simple polygon",
        ),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"mesh": "absent.stl"}]}, "no such file"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"mesh": "meshes"}]}, "is a directory"),
        (  # plain numbers, not numpy's repr
            {"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"prism": [[0, 0], [1, 0], [0, 1]], "z": [1.5, 0]}]},
            "got [1.5, 0.0]",
        ),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"mesh": "corrupt.stl"}]}, "mesh 'corrupt.stl'"),
        ({"bounds": [0, 0, 0, 1, 1, 1], "obstacles": [{"mesh": "open.stl"}]}, "not closed"),
    ],
)
def test_the_loader_refuses_bad_tables_with_one_line(tmp_path, table, message):
    (tmp_path / "corrupt.stl").write_bytes(b"solid x\nfacet normal nonsense\n")
    open_mesh = trimesh.creation.box(extents=[1, 1, 1])
    open_mesh.update_faces(np.arange(len(open_mesh.faces) - 2))  # two triangles missing
    open_mesh.export(tmp_path / "open.stl")
    (tmp_path / "meshes").mkdir()
    with pytest.raises(MapError) as err:
        world3d_from_table(table, base=tmp_path)
    text = str(err.value)
    assert message in text and "\n" not in text
