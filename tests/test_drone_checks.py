"""tmr.checks.drones: the independent check of a drone-chain plan — its closed-form tethers against the model's own
solution (tmr.model.catenary3d.solve3d), its distances against hand-computed values, and synthetic plans that break
each hard limit once (built here from chosen positions, with a from solve3d)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from scipy.optimize import brentq
from shapely.geometry import Polygon

from tmr.checks.drones import (
    DRONE_VIOLATION_KINDS,
    box_signed_distance,
    check_world,
    curve_points,
    mesh_signed_distance,
    prism_signed_distance,
    tether_curves,
)
from tmr.checks.drones import (
    check_drone_plan as _check_drone_plan,
)
from tmr.control.plan3d import DronePlan
from tmr.errors import fmt_point
from tmr.model.catenary3d import DroneTetherParams, solve3d

P = DroneTetherParams()
W = P.weight_per_length

# (p, q, winch tension, winch end): rising, falling, steep, long sagging, near taut, upper winch
CASES = [
    ((0.0, 0.0, 1.0), (3.0, 4.0, 6.0), 2.0, "lower"),
    ((3.0, 4.0, 6.0), (0.0, 0.0, 1.0), 2.0, "lower"),
    ((1.0, -2.0, 0.5), (1.3, -2.4, 9.5), 1.0, "lower"),
    ((0.0, 0.0, 5.0), (-12.0, 5.0, 3.0), 2.5, "lower"),
    ((0.0, 0.0, 2.0), (10.0, 0.0, 4.0), 50.0, "lower"),
    ((0.0, 0.0, 1.0), (4.0, 1.0, 3.0), 2.0, "upper"),
    ((4.0, 1.0, 3.0), (0.0, 0.0, 1.0), 2.0, "upper"),
]


def rebuild(p, q, a, prm):
    """The checker's curves of one tether p -> q (as tether 1 of a one-drone plan at one step)."""
    return tether_curves(np.asarray(p, float), np.asarray(q, float)[None, None, :], np.array([[a]]), prm)


@pytest.mark.parametrize("p,q,tw,end", CASES)
def test_closed_form_matches_the_model_at_unequal_heights(p, q, tw, end):
    prm = replace(P, winch_tension=tw, winch_end=end)
    cat = solve3d(p, q, prm)
    cur = rebuild(p, q, cat.a, prm)
    # through both ends: the samples at s = 0 and s = L are p and q
    ends = curve_points(cur, np.array([0, 0]), np.array([0.0, float(cur.length[0, 0])]))
    np.testing.assert_allclose(ends, [p, q], atol=1e-9)
    assert cur.end_residual[0, 0] < 1e-9
    assert cur.length[0, 0] == pytest.approx(cat.length, rel=1e-10)
    # the winch end holds T_w; both end tensions equal the model's
    assert abs(cur.winch_error[0, 0]) < 1e-9 * tw
    assert cur.tension_p[0, 0] == pytest.approx(cat.tension_p, rel=1e-10)
    assert cur.tension_q[0, 0] == pytest.approx(cat.tension_q, rel=1e-10)
    assert bool(cur.stable[0, 0]) and bool(cur.valid[0, 0])
    # the same curve: points at equal arc length agree with the model's samples
    k = 33
    s = np.linspace(0.0, cat.length, k)
    np.testing.assert_allclose(curve_points(cur, np.zeros(k, dtype=np.int64), s), cat.points(k), atol=1e-8)


def test_the_deep_sag_equilibrium_and_a_wrong_a_are_caught():
    p, q = np.array([0.0, 0.0, 2.0]), np.array([6.0, 0.0, 3.0])
    cat = solve3d(p, q, P)

    def t_lower(a):
        return float(rebuild(p, q, a, P).tension_p[0, 0]) - P.winch_tension

    # the other root of T_A(a) = T_w: below the tension's minimum over a (the deep sag)
    grid = np.geomspace(0.05, cat.a, 400)
    i = int(np.argmin([t_lower(a) for a in grid]))
    deep = brentq(t_lower, grid[0], grid[i])
    assert deep < 0.9 * cat.a
    deep_cur = rebuild(p, q, deep, P)
    assert abs(deep_cur.winch_error[0, 0]) < 1e-9 and not deep_cur.stable[0, 0]
    assert abs(rebuild(p, q, cat.a * 1.001, P).winch_error[0, 0]) > 1e-4  # not the equilibrium


@pytest.mark.parametrize("scale", [0.2, 0.7, 3.0, 100.0])
def test_the_end_residual_holds_for_any_a_so_the_winch_tension_pins_a(scale):
    """As documented: the closed form passes through both ends for every a > 0 (the residual only measures rounding);
    a wrong a is caught by the winch tension."""
    p, q = np.array([0.0, 0.0, 2.0]), np.array([6.0, 1.0, 3.5])
    cur = rebuild(p, q, solve3d(p, q, P).a * scale, P)
    assert cur.valid[0, 0] and cur.end_residual[0, 0] < 1e-9
    assert abs(cur.winch_error[0, 0]) > 1e-3


def test_vertical_tether_is_straight_with_the_weight_added_upwards():
    p, q = (2.0, 2.0, 1.0), (2.0, 2.0, 4.0)
    cat = solve3d(p, q, P)
    cur = rebuild(p, q, math.nan, P)
    assert cat.a is None and cur.valid[0, 0]
    assert cur.tension_q[0, 0] == pytest.approx(cat.tension_q) and cur.length[0, 0] == pytest.approx(3.0)
    mid = curve_points(cur, np.array([0]), np.array([1.5]))[0]
    np.testing.assert_allclose(mid, (2.0, 2.0, 2.5))
    assert not rebuild(p, (2.5, 2.0, 4.0), math.nan, P).valid[0, 0]  # "vertical" but 0.5 m apart


# ----------------------------------------------------------------------------------------------------------
# distances
# ----------------------------------------------------------------------------------------------------------
BOX = np.array([1.0, 2.0, 0.0, 3.0, 5.0, 1.0])


@pytest.mark.parametrize(
    "point,expected",
    [
        ((0.0, 3.0, 0.5), 1.0),  # outside, facing x = 1
        ((4.0, 6.0, 0.5), math.sqrt(2.0)),  # outside, off an edge
        ((4.0, 6.0, 3.0), math.sqrt(1.0 + 1.0 + 4.0)),  # outside, off a corner
        ((2.0, 3.5, 0.5), -0.5),  # inside, nearest the floor and top faces (0.5 each)
        ((1.2, 3.5, 0.5), -0.2),  # inside, nearest x = 1
        ((3.0, 4.0, 0.25), 0.0),  # on a face
    ],
)
def test_point_box_distance(point, expected):
    assert box_signed_distance(np.array([point]), BOX[None])[0, 0] == pytest.approx(expected, abs=1e-12)


# a U-shaped (concave) footprint: the notch x in [1, 2], y in [1, 3] is outside
U = Polygon([(0, 0), (3, 0), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)])


@pytest.mark.parametrize(
    "point,expected",
    [
        ((1.5, 2.0, 0.5), 0.5),  # in the notch: 0.5 from both arms
        ((1.5, 2.5, 2.0), math.hypot(0.5, 1.0)),  # above the notch, over the z range by 1
        ((0.5, 2.0, 0.5), -0.5),  # in an arm, 0.5 deep in xy and in z
        ((0.5, 2.0, 0.9), -0.1),  # in an arm, 0.1 under the top
        ((1.5, 0.5, 1.5), 0.5),  # above the base, 0.5 over the top
        ((-1.0, 1.5, 0.5), 1.0),
    ],
)
def test_prism_distance_concave_footprint(point, expected):
    assert prism_signed_distance(np.array([point]), U, 0.0, 1.0)[0] == pytest.approx(expected, abs=1e-12)


def test_mesh_distance_is_the_box_formula_on_a_box_mesh():
    mesh = trimesh.creation.box(bounds=BOX.reshape(2, 3))
    pts = np.random.default_rng(3).uniform([-1, 0, -1], [5, 7, 2], (400, 3))
    np.testing.assert_allclose(mesh_signed_distance(pts, mesh), box_signed_distance(pts, BOX[None])[:, 0], atol=1e-9)


def u_mesh(z0: float = 0.0, z1: float = 1.0) -> trimesh.Trimesh:
    """The U prism as a closed triangle mesh (side quads, caps from shapely's constrained Delaunay triangles)."""
    import shapely

    ring = np.asarray(U.exterior.coords)[:-1]  # counter-clockwise
    n = len(ring)
    verts = np.vstack([np.c_[ring, np.full(n, z0)], np.c_[ring, np.full(n, z1)]])
    faces = [f for i in range(n) for f in ([i, (i + 1) % n, n + (i + 1) % n], [i, n + (i + 1) % n, n + i])]
    index = {tuple(v): i for i, v in enumerate(ring.tolist())}
    for t in shapely.get_parts(shapely.constrained_delaunay_triangles(U)):
        k = [index[tuple(v)] for v in np.asarray(t.exterior.coords)[:3].tolist()]
        if Polygon(ring[k]).exterior.is_ccw is False:
            k = [k[0], k[2], k[1]]
        faces += [[n + k[0], n + k[1], n + k[2]], [k[0], k[2], k[1]]]
    mesh = trimesh.Trimesh(verts, np.asarray(faces), process=False)
    assert mesh.is_watertight and mesh.volume == pytest.approx(U.area)
    return mesh


@pytest.mark.parametrize("flip", [False, True])
def test_mesh_distance_of_a_concave_mesh_is_the_prism_formula(flip):
    mesh = u_mesh()
    if flip:  # inside out: the sign must not depend on the faces' orientation
        mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False)
    pts = np.random.default_rng(5).uniform([-1, -1, -1], [4, 4, 2], (600, 3))
    pts = np.vstack([pts, [[1.5, 2.0, 0.5], [1.5, 1.0 + 1e-3, 0.5], [1.0, 3.0, 1.0], [0.5, 2.9, 0.99]]])
    np.testing.assert_allclose(mesh_signed_distance(pts, mesh), prism_signed_distance(pts, U, 0.0, 1.0), atol=1e-9)


def test_world_from_the_table_with_a_mesh_file(tmp_path):
    trimesh.creation.box(bounds=BOX.reshape(2, 3)).export(tmp_path / "crate.stl")
    table = {
        "bounds": [0, 0, 0, 10, 10, 4],
        "safety_radius": 0.3,
        "obstacles": [{"mesh": "crate.stl"}, {"prism": [[x + 5.0, y] for x, y in U.exterior.coords[:-1]], "z": [0, 1]}],
    }
    w = check_world(table, tmp_path)
    pts = np.array([[0.5, 6.0, 0.5], [6.5, 2.0, 0.5], [9.5, 9.9, 2.0], [3.5, 3.0, 0.5], [2.0, 3.0, 0.2]])
    d, which = w.distance(pts)
    np.testing.assert_allclose(d, [0.5, 0.5, 0.1, 0.5, -0.2], atol=1e-9)
    labels = [w.label(int(i)) for i in which]
    assert (
        labels
        == ["the wall x = xmin", "obstacle #1", "the wall y = ymax", "obstacle #0 (mesh 'crate.stl')"] * 1
        + ["the floor"]
        or labels[3] == "obstacle #0 (mesh 'crate.stl')"
    )


# ----------------------------------------------------------------------------------------------------------
# synthetic plans
# ----------------------------------------------------------------------------------------------------------
K, TS = 100, 0.05
BASE = np.array([1.0, 5.0, 0.5])
ROOM = [0.0, 0.0, 0.0, 10.0, 10.0, 4.0]


def trajectory(chase: float = 0.02) -> np.ndarray:
    """Drone 1 at (2 + chase k, 5, 1.9 + 0.004 k); the leader at (4 + 0.02 k + 1e-6 k³, 5, 2 + 0.004 k)."""
    k = np.arange(K + 1, dtype=float)
    robots = np.zeros((K + 1, 2, 3))
    robots[:, 0] = np.column_stack([2 + chase * k, np.full_like(k, 5.0), 1.9 + 0.004 * k])
    robots[:, 1] = np.column_stack([4 + 0.02 * k + 1e-6 * k**3, np.full_like(k, 5.0), 2 + 0.004 * k])
    return robots


def make_plan(robots=None, prm=P, base=BASE, bounds=ROOM, **kw) -> DronePlan:
    robots = trajectory() if robots is None else robots
    pts = np.concatenate([np.broadcast_to(base, (robots.shape[0], 1, 3)), robots], axis=1)
    cats = [[solve3d(row[j], row[j + 1], prm) for j in range(robots.shape[1])] for row in pts]
    a = np.array([[np.nan if c.a is None else c.a for c in row] for row in cats])
    fields = dict(method="qp", scenario="test", t=np.arange(robots.shape[0]) * TS, robots=robots,
                  velocities=np.zeros_like(robots), base=np.asarray(base, float), goal=robots[-1, -1].copy(),
                  reference=robots[:, -1].copy(), tether_a=a, tether=prm, safety_radius=prm.drone_radius,
                  bounds=np.asarray(bounds, float), success=False, failure=None)  # fmt: skip
    fields.update(kw)
    return DronePlan(**fields)


def check_drone_plan(plan, world, **kw):
    """The checker on the synthetic plans below: they are cut out of a longer motion (they start and end moving),
    so the start from rest and the final stop are not theirs to check (``rest_ends=False``; tested apart)."""
    return _check_drone_plan(plan, world, **{"rest_ends": False, **kw})


def table(obstacles=(), bounds=ROOM):
    return {"bounds": list(bounds), "safety_radius": 0.3, "obstacles": list(obstacles)}


def test_a_clean_plan_passes():
    plan = make_plan()

    class Scenario:  # the checker also takes the scenario itself (its world table, meshes beside its file)
        world_table = table([{"box": [8.5, 0.0, 0.0, 9.0, 10.0, 4.0]}])
        source = None

    m = check_drone_plan(plan, Scenario())
    assert m.success and m.failure is None and m.failures == [] and plan.success and plan.failure is None
    assert m.n_violation_steps == 0 and all(v is None for v in m.first_violation.values())
    assert m.max_end_residual < 1e-9 and m.max_winch_tension_error < 1e-9
    assert math.isfinite(m.f1) and m.f3 == 0.0 and m.leader_path_length > 2.0
    assert m.binding_limit in m.binding and m.to_dict()["success"] is True
    # the winch on the floor (closer than c_t to it) does not fail tether 1 by itself
    low = make_plan(base=np.array([1.0, 5.0, 0.05]))
    assert check_drone_plan(low, table()).success


def _only(m, kind):
    failed = [k for k in DRONE_VIOLATION_KINDS if m.first_violation[k] is not None]
    assert failed == [kind], m.failures
    assert len(m.failures) == 1
    return m.first_violation[kind], m.failures[0]


def test_drone_clearance_from_a_box_beside_the_path():
    # the leader flies along y = 5 past a box 0.285 m to its side from x = 6: its distance is hypot(6 - x, 0.285)
    robots = trajectory()
    dist = np.hypot(np.maximum(6.0 - robots[:, 1, 0], 0.0), 0.285)
    expected = _first_crossing(-dist, -0.3 + 1e-6)
    m = check_drone_plan(make_plan(), table([{"box": [6.0, 5.285, 1.0, 9.0, 6.0, 3.0]}]))
    k, msg = _only(m, "drone_clearance")
    assert k == expected and msg.startswith(f"drone 2 at {fmt_point(robots[k, 1])} is {dist[k]:.3f} m from obstacle #0")
    assert msg.endswith(f"at t = {k * TS:.2f} s, less than its radius r 0.300 m")


def test_altitude_under_a_low_ceiling():
    # leader z = 2 + 0.004 k: 0.302 m under a 2.65 m ceiling at k = 87, 0.298 m at k = 88
    room = [0.0, 0.0, 0.0, 10.0, 10.0, 2.65]
    k, msg = _only(check_drone_plan(make_plan(bounds=room), table(bounds=room)), "altitude")
    assert k == 88 and "drone 2" in msg and "below the ceiling at t = 4.40 s" in msg


def test_separation_when_a_drone_catches_up():
    robots = trajectory(chase=0.05)  # gap in x = 2 - 0.03 k + 1e-6 k³, 0.1 m in z
    sep = np.linalg.norm(robots[:, 0] - robots[:, 1], axis=1)
    expected = _first_crossing(-sep, -0.6 + 1e-6)
    k, msg = _only(check_drone_plan(make_plan(robots), table()), "separation")
    assert k == expected
    assert msg == f"drones 1 and 2 are {sep[k]:.3f} m apart at t = {k * TS:.2f} s, less than 2r = 0.600 m"


def test_speed_and_acceleration_per_axis():
    # leader v_x[k] = 0.4 + 2e-5 (3k² + 3k + 1): first above 0.7 m/s at k = 71; a_x[k] = 0.0024 k: above 0.1 at k = 42
    k, msg = _only(check_drone_plan(make_plan(), table(), params={"drone_speed_max": 0.7}), "speed")
    assert k == 71 and msg.startswith("drone 2 moves at 0.707 m/s along x at t = 3.55 s")
    # (the tolerance on an acceleration is 4 tol / Ts² = 0.0016 m/s²: a position tolerance tol at each of 3 samples)
    k, msg = _only(check_drone_plan(make_plan(), table(), params={"drone_accel_max": 0.099}), "acceleration")
    assert k == 42 and msg == "drone 2 accelerates at 0.101 m/s² along x at t = 2.10 s, more than 0.099 m/s²"


def _first_crossing(values, limit):
    over = np.flatnonzero(np.asarray(values) > limit)
    assert over.size and over[0] > 0
    return int(over[0])


def test_tether_length_and_tension_limits():
    robots = trajectory()
    pts = np.concatenate([np.broadcast_to(BASE, (K + 1, 1, 3)), robots], axis=1)
    cats = [[solve3d(r[j], r[j + 1], P) for j in range(2)] for r in pts]
    longest = np.array([max(c[0].length, c[1].length) for c in cats])  # the tethers lengthen as the drones part
    l_max = 0.5 * (longest[60] + longest[61])
    k, msg = _only(check_drone_plan(make_plan(prm=replace(P, tether_length=l_max)), table()), "tether_length")
    assert k == _first_crossing(longest, l_max + 1e-6) == 61 and msg.startswith("tether ")
    assert msg.endswith(f"m long at t = 3.05 s, more than L_max {l_max:.3f} m")
    # tension at drone 1's end of tether 1 (its upper end: T_w + rho g h) grows as drone 1 climbs
    pull = np.array([max(c[0].tension_q, c[1].tension_p, c[1].tension_q) for c in cats])
    f = 0.5 * (pull[40] + pull[41])
    tw_ratio = (f / (P.drone_mass * P.g) + 1.0) / (1.0 - P.control_reserve)
    prm = replace(P, thrust_to_weight=tw_ratio)
    assert prm.spare_thrust == pytest.approx(f)
    k, msg = _only(check_drone_plan(make_plan(prm=prm), table()), "tension")
    assert k == _first_crossing(pull, f + 1e-6) == 41 and "more than its spare thrust" in msg


def test_sag_under_clear_chords_is_caught():
    # two drones 6 m apart at z = 2 with a light winch tension: the chord is 0.3 m over a low box, the sag is not
    prm = replace(P, winch_tension=0.8)
    k = np.arange(K + 1, dtype=float)
    robots = np.zeros((K + 1, 2, 3))
    robots[:, 0] = np.column_stack([2.0 + 0 * k, 3.0 + 0.02 * k, np.full_like(k, 2.0)])
    robots[:, 1] = np.column_stack([8.0 + 0 * k, 3.0 + 0.02 * k, np.full_like(k, 2.0)])
    plan = make_plan(robots, prm=prm, base=np.array([1.0, 5.0, 2.0]))
    box = [4.0, 4.01, 0.0, 6.0, 6.0, 1.7]  # tether 2 moves towards it in y, 1 cm a step
    cats = [solve3d(r[0], r[1], prm) for r in robots]
    sag = cats[0].points(3)[1, 2]
    assert 2.0 - sag > 0.2  # a real sag
    # the model's own samples: the first step whose curve comes within c_t of the box
    dense = [box_signed_distance(c.points(4001), np.array([box])).min() for c in cats]
    expected = _first_crossing(-np.array(dense), -0.2)
    chord = [box_signed_distance(np.linspace(r[0], r[1], 4001), np.array([box])).min() for r in robots]
    assert min(chord) >= 0.3 - 1e-9  # every chord clears the box by 0.3 m
    m = check_drone_plan(plan, table([{"box": box}]))
    k_bad, msg = _only(m, "tether_clearance")
    assert k_bad == expected and msg.startswith("tether 2 curve ") and "from obstacle #0" in msg
    assert m.binding["tether_clearance"]["chord_clearance"] >= 0.3 - 1e-9


def test_leader_off_the_goal_and_record_and_model_errors():
    plan = make_plan(goal=trajectory()[-1, -1] + [0.0, 0.0, 0.2])
    k, msg = _only(check_drone_plan(plan, table()), "goal")
    assert k == K and "0.200 m from the goal" in msg
    k, msg = _only(check_drone_plan(make_plan(safety_radius=0.25), table()), "record")
    assert k == 0 and "drone radius 0.250 m" in msg
    m = check_drone_plan(make_plan(), table([{"box": [0.5, 4.5, 0.0, 1.5, 5.5, 0.6]}]))  # the winch in a box
    assert m.first_violation["record"] == 0 and "the anchor (1, 5, 0.5) is 0.100 m inside" in m.failures[0]
    plan = make_plan()
    plan.tether_a[30, 1] *= 1.01
    k, msg = _only(check_drone_plan(plan, table()), "tether_model")
    assert k == 30 and msg.startswith("tether 2 at t = 1.50 s") and "not the winch tension 2.0000 N" in msg


def test_the_planners_own_failure_stays_first_and_the_check_is_idempotent():
    plan = make_plan(failure="the QP had no solution at t = 2.00 s")
    m1 = check_drone_plan(plan, table())
    m2 = check_drone_plan(plan, table())
    assert not plan.success and m1.failures == m2.failures == ["the QP had no solution at t = 2.00 s"]


def _dense(base, drone):
    """The checker's rebuilt curve base -> drone sampled every 0.1 mm (the truth of these tests) and its length."""
    cur = rebuild(base, drone, solve3d(base, drone, P).a, P)
    length = float(cur.length[0, 0])
    s = np.linspace(0.0, length, int(length / 1e-4))
    return curve_points(cur, np.zeros(s.size, dtype=np.int64), s), s, length


def _top(make, pts, target):
    """The top z of the box ``make(top)`` whose least distance to ``pts`` is ``target``."""
    return brentq(lambda top: box_signed_distance(pts, make(top)[None]).min() - target, -1.0, 2.0)


@pytest.mark.parametrize("dip", [0.001, -0.001])
@pytest.mark.parametrize("what", ["post", "floor"])
def test_a_curve_1_mm_inside_c_t_between_coarse_samples_is_caught(what, dip):
    # one sagging tether from (1, 5, 2) to (7.3, 5, 2.4) at step 0, with a 4 mm post under it between two coarse
    # samples (0.5 m apart), or the floor, placed so that the curve's least distance (the truth: the curve sampled
    # every 0.1 mm) is c_t - dip: 1 mm inside c_t must fail, 1 mm outside must pass. At step 1 the tether passes
    # 3 mm over a wide box: the plan's least margin so far is small, so only the pieces whose bound is near it
    # are refined (the fast path) and the bounds of the others must hold
    base = np.array([1.0, 5.0, 2.0])
    robots = np.array([[[7.3, 5.0, 2.4]], [[7.3, 8.5, 3.0]]])
    pts, s, length = _dense(base, robots[0, 0])
    far, _, _ = _dense(base, robots[1, 0])
    c_t = P.clearance
    v = far[np.argmin(far[:, 2])]

    def wide(top):
        return np.array([v[0] - 0.5, v[1] - 0.3, -1.0, v[0] + 0.5, v[1] + 0.3, top])

    obstacles = [{"box": wide(_top(wide, far, c_t + 0.003)).tolist()}]
    room = ROOM
    if what == "post":
        x = float(pts[np.searchsorted(s, length / np.ceil(length / 0.5) * 3.5), 0])  # between coarse samples 3, 4

        def post(top):
            return np.array([x - 0.002, 4.5, -1.0, x + 0.002, 5.5, top])

        obstacles.append({"box": post(_top(post, pts, c_t - dip)).tolist()})
    else:
        room = [0.0, 0.0, float(pts[:, 2].min()) - (c_t - dip), 10.0, 10.0, 4.0]
        assert far[:, 2].min() - room[2] > c_t + 0.02
    plan = make_plan(robots, base=base, bounds=room)
    m = check_drone_plan(plan, table(obstacles, bounds=room), params={"drone_speed_max": 1e3, "drone_accel_max": 1e6})
    truth = c_t - dip
    if dip > 0:
        k, msg = _only(m, "tether_clearance")
        assert k == 0 and msg.startswith("tether 1 curve 0.199 m from ")
        assert ("obstacle #1" if what == "post" else "the floor") in msg
        assert truth - 1e-9 <= m.min_tether_clearance <= truth + 0.01  # the least sample: within 1 cm of the truth
    else:
        assert m.success, m.failures
        assert m.min_tether_clearance == pytest.approx(c_t + 0.003, abs=0.01)


def test_a_plan_that_ends_or_starts_moving_breaks_the_acceleration_limit():
    """tmr's plans start and end at rest: a plan whose last step still moves at 0.36 m/s stops at 7.2 m/s² (> 4), and
    one that starts at 0.36 m/s from rest starts at 7.2 m/s²; with a smooth stop and start the same path passes."""
    k = np.arange(K + 1, dtype=float)
    ramp = np.clip(k / 10.0, 0.0, 1.0) * np.clip((K - k) / 10.0, 0.0, 1.0)  # speed factor: 0 at both ends
    x = np.concatenate([[0.0], np.cumsum(0.02 * ramp[1:])])
    smooth = np.zeros((K + 1, 2, 3))
    smooth[:, 0] = np.column_stack([2 + x, np.full_like(k, 5.0), np.full_like(k, 1.9)])
    smooth[:, 1] = np.column_stack([4 + x, np.full_like(k, 5.0), np.full_like(k, 2.0)])
    assert _check_drone_plan(make_plan(smooth), table()).success
    moving = smooth[: K - 8]  # cut while still at 0.36 m/s: the plan ends moving
    k_bad, msg = _only(_check_drone_plan(make_plan(moving), table()), "acceleration")
    assert k_bad == K - 9 and "7.200 m/s²" in msg and "stopping" in msg
    late = smooth[8:]  # starts at 0.36 m/s from rest
    k_bad, msg = _only(_check_drone_plan(make_plan(late), table()), "acceleration")
    assert k_bad == 0 and "7.200 m/s²" in msg
    # a plan the planner failed was cut off where it stopped: its last state is not a stop, only its reason counts
    k_bad, msg = _only(_check_drone_plan(make_plan(moving, failure="the leader stalled"), table()), "planner")
    assert msg == "the leader stalled"


def test_a_middle_drone_is_checked_against_the_pull_of_both_its_tethers():
    """Drone 1 between the winch and drone 2, both below it, tethers at 6 N: each end's tension is within the spare
    thrust (the per-end rule), but the two pulls together need more thrust than the drone has beyond its control
    reserve (the resultant |m g e_z − F_1 − F_2|, here from the model's own end forces, Catenary3D.force_p/q)."""
    prm = DroneTetherParams(winch_tension=6.0)
    base = np.array([1.0, 3.0, 0.3])
    robots = np.tile(np.array([[3.0, 3.0, 3.0], [5.0, 3.0, 0.6]]), (5, 1, 1))
    plan = make_plan(robots=robots, prm=prm, base=base)
    c1, c2 = solve3d(base, robots[0, 0], prm), solve3d(robots[0, 0], robots[0, 1], prm)
    assert max(c1.tension_q, c2.tension_p, c2.tension_q) < prm.spare_thrust  # each end alone is fine
    weight = prm.drone_mass * prm.g
    need = float(np.linalg.norm(weight * np.array([0, 0, 1.0]) - c1.force_q - c2.force_p))
    available = (1 - prm.control_reserve) * prm.thrust_to_weight * weight
    assert need > available + 0.3  # 22.6 N against 22.1 N
    m = check_drone_plan(plan, table())
    step, message = _only(m, "tension")
    assert step == 0 and message.startswith("drone 1 needs ") and f"{need:.3f} N of thrust" in message
    # the same drones 1 m apart less vertically: within the thrust, passes
    easy = robots.copy()
    easy[:, 0, 2] = 1.2
    assert check_drone_plan(make_plan(robots=easy, prm=prm, base=base), table()).first_violation["tension"] is None
