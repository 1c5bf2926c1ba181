"""tmr.views.drones: the curves drawn are the model's catenaries, the distances are exact, the files deterministic."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from tests.drone_views_data import BOUNDS, hand_plan, small_world
from tmr.model.catenary3d import solve3d
from tmr.views import drones as D
from tmr.views.plot import figure_bytes

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def plan():
    return hand_plan(3, vertical_at=5)


@pytest.fixture(scope="module")
def world():
    return small_world()


def test_tether_curves_are_solve3d_catenaries_through_both_ends(plan):
    curves = D.tether_curves(plan, 17)
    assert curves.shape == (len(plan.t), 3, 17, 3)
    assert np.isnan(plan.tether_a[5, 0])  # drone 1 straight above the anchor: a vertical tether
    for k in range(len(plan.t)):
        pts = plan.points(k)
        for j in range(3):
            ref = solve3d(pts[j], pts[j + 1], plan.tether).points(17)
            assert np.max(np.abs(curves[k, j] - ref)) < 1e-9, (k, j)
            assert np.array_equal(curves[k, j, 0], pts[j]) and np.array_equal(curves[k, j, -1], pts[j + 1])
    sub = D.tether_curves(plan, 9, steps=[3, 0])
    assert np.array_equal(sub, D.tether_curves(plan, 9)[[3, 0]])


def test_tether_curve_sags_below_its_chord(plan):
    c = D.tether_curves(plan, 33)[10, 1]  # tether 2 at step 10: not vertical
    chord_z = np.linspace(c[0, 2], c[-1, 2], 33)
    assert np.all(c[1:-1, 2] < chord_z[1:-1])  # not the chord: the catenary hangs below it


def test_end_tensions_match_solve3d(plan):
    tp, tq = D.end_tensions(plan)
    for k in (0, 5, 17, 40):
        pts = plan.points(k)
        for j in range(3):
            cat = solve3d(pts[j], pts[j + 1], plan.tether)
            assert tp[k, j] == pytest.approx(cat.tension_p, rel=1e-9)
            assert tq[k, j] == pytest.approx(cat.tension_q, rel=1e-9)
    # winch at the lower end: T_w there (the recorded a is the equilibrium)
    assert np.allclose(np.minimum(tp, tq), plan.tether.winch_tension, rtol=1e-9)


def _box_distance(p, lo, hi):
    """Exact signed distance of points (n, 3) to an axis-aligned box, < 0 inside (numpy, independent of coal)."""
    outside = np.linalg.norm(np.maximum(0.0, np.maximum(lo - p, p - hi)), axis=1)
    depth = np.minimum(p - lo, hi - p).min(axis=1)
    return np.where(depth > 0.0, -depth, outside)


def test_tether_clearance_against_exact_box_distance():
    """One drone's tether over (and at first through) a low box: the curve's clearance (sampled every 0.1 m with
    World3D) lies within 0.05 m above the exact minimum (a dense numpy signed point–box / floor / wall distance)."""
    from tmr.world.world3d import World3D, box_obstacle

    plan = hand_plan(1, steps=6)
    lo, hi = np.array([1.8, 3.0, 0.0]), np.array([2.2, 5.0, 0.9])
    world = World3D([box_obstacle(lo, hi)], BOUNDS, 0.3)
    dist, where = D.tether_clearances(plan, world)
    dense = D.tether_curves(plan, 4001)
    b = np.asarray(BOUNDS)
    for k in range(6):
        c = dense[k, 0]
        walls = np.minimum(c - b[:3], b[3:] - c).min(axis=1)
        exact = float(np.minimum(_box_distance(c, lo, hi), walls).min())
        assert exact - 1e-9 <= dist[k, 0] <= exact + 0.05 + 1e-9
        assert world.with_safety_radius(0.0).clearance(where[k, 0]) == pytest.approx(dist[k, 0])


def test_obstacle_meshes(world):
    box, tri, ell = (D.obstacle_mesh(ob) for ob in world.obstacles)
    assert {tuple(v) for v in box.vertices} == {(x, y, z) for x in (4.0, 4.5) for y in (0.0, 3.0) for z in (0.0, 2.5)}
    assert len(box.edges) == 12 and len(tri.edges) == 9 and len(ell.edges) == 18  # no triangle diagonals
    import trimesh

    for dr, volume in ((box, 0.5 * 3.0 * 2.5), (tri, 0.5 * 1.5), (ell, (2.0 * 0.5 + 0.5 * 1.5) * 3.0)):
        mesh = trimesh.Trimesh(dr.vertices, dr.faces)
        assert mesh.is_watertight and mesh.volume == pytest.approx(volume)  # closed and outward (positive volume)
        assert np.allclose(dr.normals, mesh.face_normals)


def test_figures(plan, world, tmp_path):
    figs = D.figures(plan, world)
    assert tuple(figs) == D.FIGURE_NAMES
    poses = figs["chain_poses_3d"]
    ax3 = poses.axes[0]
    assert ax3.name == "3d" and ax3.get_zlabel() == "z [m]"
    assert ax3.get_xlim() == pytest.approx((0.0, 10.0)) and ax3.get_zlim() == pytest.approx((0.0, 4.0))
    alt = figs["altitude"].axes[0]
    assert len(alt.lines) == 3 + 2
    assert alt.lines[0].get_ydata() == pytest.approx(plan.robots[:, 0, 2])
    assert alt.lines[3].get_ydata()[0] == pytest.approx(0.3)  # floor + r
    assert alt.lines[4].get_ydata()[0] == pytest.approx(3.7)  # ceiling - r
    clr = figs["tether_clearance"].axes[0]
    dist, _ = D.tether_clearances(plan, world)
    assert clr.lines[1].get_ydata() == pytest.approx(dist[:, 1])
    assert clr.lines[3].get_ydata()[0] == pytest.approx(plan.tether.clearance)
    ten = figs["tensions"].axes[0]
    assert len(ten.lines) == 3 + 2 + 1  # drone i: tether i (3), tether i + 1 (2), spare thrust
    assert ten.lines[-1].get_ydata()[0] == pytest.approx(plan.tether.spare_thrust)
    for name, fig in figs.items():
        data = figure_bytes(fig)
        assert data.startswith(PNG_SIGNATURE) and data == figure_bytes(fig), name
    assert figure_bytes(D.chain_poses_3d(plan, world)) == figure_bytes(poses)  # rebuilt: same bytes
    paths = D.save_figures(plan, world, tmp_path / "figs")
    assert sorted(p.name for p in paths) == sorted(f"{n}.png" for n in D.FIGURE_NAMES)


def test_camera_frames_the_room():
    cam = D.camera_for(BOUNDS, (720, 540), top=40)
    corners = np.array([[x, y, z] for x in (0, 10) for y in (0, 8) for z in (0, 4)], dtype=float)
    uv, depth = cam.project(corners)
    assert np.all(depth > 0)
    assert uv[:, 0].min() >= 15.9 and uv[:, 0].max() <= 720 - 15.9
    assert uv[:, 1].min() >= 40 + 15.9 and uv[:, 1].max() <= 540 - 15.9
    # the room fills the image in width or in height (16 px margins, a 40 px title band)
    assert math.isclose(np.ptp(uv[:, 0]), 720 - 32, rel_tol=1e-9) or math.isclose(
        np.ptp(uv[:, 1]), 540 - 72, rel_tol=1e-9
    )
    # perspective: a 1 m segment across the view looks shorter the farther it is, as scale / depth
    for c in corners:
        (p0, p1), (d0, _) = cam.project(np.array([c, c + cam.right]))
        assert np.linalg.norm(p1 - p0) == pytest.approx(cam.scale / d0)
    near, far = np.argmin(depth), np.argmax(depth)
    assert depth[near] < 0.8 * depth[far]


def test_gif(plan, world, tmp_path):
    a = D.write_gif_3d(plan, world, tmp_path / "a.gif")
    b = D.write_gif_3d(plan, world, tmp_path / "b.gif")
    assert a.read_bytes() == b.read_bytes()
    idx = D.frame_indices_3d(plan.t, 10.0, 150)
    assert idx[0] == 0 and idx[-1] == len(plan.t) - 1 and np.all(np.diff(idx) == 2)  # Ts 0.05 s at 10 fps
    with Image.open(a) as im:
        assert im.size == (720, 540) and im.n_frames == len(idx)
        im.seek(10)
        mid = np.asarray(im.convert("RGB"))
    # the leader is drawn where the camera sees it, in its colour (mid-way: the goal, also orange, is elsewhere)
    cam = D.camera_for(world.bounds, (720, 540))
    (u, v), _ = cam.project(plan.robots[idx[10], -1])
    (gu, gv), _ = cam.project(plan.goal)
    assert math.hypot(u - gu, v - gv) > 50
    assert tuple(mid[int(round(v)) + 3, int(round(u))]) == D._hex(D.LEADER_COLOR)
    (u1, v1), _ = cam.project(plan.robots[idx[10], 0])
    assert tuple(mid[int(round(v1)) + 3, int(round(u1))]) == D._hex(D.DRONE_COLOR)
    assert len(D.frame_indices_3d(np.arange(0.0, 60.0, 0.05), 10.0, 150)) <= 151


def test_html(plan, world, tmp_path):
    fig = D.build_figure_3d(plan, world)
    idx = D.frame_indices_3d(plan.t)
    assert [f.name for f in fig.frames] == [str(int(k)) for k in idx]
    assert sum(tr.type == "mesh3d" for tr in fig.data) == len(world.obstacles) + 1  # + the floor
    k = int(idx[3])
    tether2 = fig.frames[3].data[1]
    pts = plan.points(k)
    ref = solve3d(pts[1], pts[2], plan.tether).points(D.CURVE_POINTS)
    assert np.allclose(np.column_stack([tether2.x, tether2.y, tether2.z]), ref, atol=1e-9)
    drones = fig.frames[3].data[-1]
    assert np.allclose(np.column_stack([drones.x, drones.y, drones.z]), plan.robots[k])
    path = D.write_html_3d(plan, world, tmp_path / "m.html")
    html = path.read_text(encoding="utf-8")
    assert 'id="tmr-view"' in html and "plotly.js" in html and len(html) > 3_000_000  # plotly.js itself is embedded


def test_write_drone_views(plan, world, tmp_path):
    names = D.write_drone_views(plan, world, tmp_path, gif=True, html=True, export="mcap")
    assert names == ["ros2_bag", "motion.html", "motion.gif"]
    assert (tmp_path / "ros2_bag" / "ros2_bag.mcap").is_file()
    assert D.write_drone_views(plan, world, tmp_path / "none") == []


def test_html_bytes_do_not_depend_on_where_the_world_was_read(plan, tmp_path):
    """The hover text names "obstacle #k" (and a mesh's file name), not the world's source label: the plan-time
    world (a scenario file's path) and the export-time one (the run's run.json, its meshes copied) draw the same
    bytes, and no install path leaks into motion.html."""
    import trimesh

    from tmr.world.world3d import world3d_from_table

    for folder in ("scenario", "run/world_meshes"):
        (tmp_path / folder).mkdir(parents=True)
        trimesh.creation.box(bounds=[[6.0, 1.0, 0.0], [7.0, 2.0, 1.0]]).export(tmp_path / folder / "crate.stl")
    table = {
        "bounds": list(BOUNDS),
        "safety_radius": 0.3,
        "obstacles": [{"box": [4.0, 0.0, 0.0, 4.5, 3.0, 2.5]}, {"prism": [[1, 6], [2, 6], [1.5, 7]], "z": [0, 1.5]}],
    }
    plan_time = world3d_from_table(
        {**table, "obstacles": [*table["obstacles"], {"mesh": "crate.stl"}]},
        tmp_path / "scenario",
        where=f"scenario file {tmp_path / 'scenario' / 'X.toml'} [world]",
    )
    export_time = world3d_from_table(
        {**table, "obstacles": [*table["obstacles"], {"mesh": "world_meshes/crate.stl"}]},
        tmp_path / "run",
        where="runs/X/run.json [world]",
    )
    a = D.write_html_3d(plan, plan_time, tmp_path / "a.html").read_bytes()
    b = D.write_html_3d(plan, export_time, tmp_path / "b.html").read_bytes()
    assert a == b
    assert str(tmp_path).encode() not in a and b"run.json" not in a and b"scenario file" not in a
    assert [D.obstacle_label(k, ob) for k, ob in enumerate(export_time.obstacles)] == [
        "obstacle #0", "obstacle #1", "obstacle #2 (mesh 'crate.stl')",
    ]  # fmt: skip
