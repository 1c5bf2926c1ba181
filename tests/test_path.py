"""Tests of tmr.route.path: RRT* leader path (OMPL) and the B-spline / minimum-jerk time law (Caruso 2021 §4.2)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

import tmr.route.path as path_module
from tmr.errors import ParameterError, PathError
from tmr.route.path import Trajectory, leader_trajectory, path_length, plan_leader_path, time_law
from tmr.world.environment import Environment

BOUNDS = (0.0, 0.0, 10.0, 10.0)
DISC_CENTRES = [(5.0, 5.0), (3.0, 3.0), (7.0, 7.0), (3.0, 7.0), (7.0, 3.0)]


def make_env(obstacles, bounds=BOUNDS):
    return Environment.from_geometry(obstacles, bounds, safety_radius=0.5, resolution=0.05)


@pytest.fixture(scope="module")
def discs_env():
    return make_env([shapely.Point(c).buffer(0.6) for c in DISC_CENTRES])


@pytest.fixture(scope="module")
def discs_path(discs_env):
    return plan_leader_path(discs_env, (1.0, 5.0), (9.0, 5.2), seed=0, iterations=400)


@pytest.fixture(scope="module")
def square_env():
    return make_env([shapely.box(3.0, 3.0, 7.0, 7.0)])


# ------------------------------------------------------------------------------------------------------------
# plan_leader_path


def test_path_endpoints_exact_and_segments_free(discs_env, discs_path):
    W = discs_path
    assert W.ndim == 2 and W.shape[1] == 2 and len(W) >= 3  # the straight line is blocked by the middle disc
    assert np.array_equal(W[0], [1.0, 5.0]) and np.array_equal(W[-1], [9.0, 5.2])
    assert np.all(discs_env.segment_clearance(W[:-1], W[1:]) > 0.1)  # exact, with the default extra margin
    assert np.all(discs_env.is_free(W, margin=0.1))
    # detour round the middle disc (inflated radius 1.1 m): longer than the straight line, far from a wander
    straight = np.hypot(8.0, 0.2)
    assert straight < path_length(W) < 1.15 * straight


def test_raw_rrt_path_is_free_and_not_shorter_than_simplified(discs_env, discs_path):
    raw = plan_leader_path(discs_env, (1.0, 5.0), (9.0, 5.2), seed=0, iterations=400, simplify=False)
    assert np.array_equal(raw[0], [1.0, 5.0]) and np.array_equal(raw[-1], [9.0, 5.2])
    assert np.all(discs_env.segment_clearance(raw[:-1], raw[1:]) > 0.1)
    assert path_length(discs_path) <= path_length(raw) + 1e-12


def test_same_seed_same_bytes_other_seed_still_valid(discs_env, discs_path):
    again = plan_leader_path(discs_env, (1.0, 5.0), (9.0, 5.2), seed=0, iterations=400)
    assert again.tobytes() == discs_path.tobytes()
    other = plan_leader_path(discs_env, (1.0, 5.0), (9.0, 5.2), seed=7, iterations=400)  # may differ, must be valid
    assert np.all(discs_env.segment_clearance(other[:-1], other[1:]) > 0.1)
    third = plan_leader_path(discs_env, (1.0, 5.0), (9.0, 5.2), seed=0, iterations=400)  # after another seed
    assert third.tobytes() == discs_path.tobytes()


def test_deterministic_under_threads(discs_env, discs_path):
    from concurrent.futures import ThreadPoolExecutor

    def plan(seed):
        return plan_leader_path(discs_env, (1.0, 5.0), (9.0, 5.2), seed=seed, iterations=400)

    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(plan, [0, 7, 0]))
    assert results[0].tobytes() == discs_path.tobytes() and results[2].tobytes() == discs_path.tobytes()
    assert results[1].tobytes() == plan(7).tobytes()


def test_straight_line_when_free(square_env):
    W = plan_leader_path(square_env, (1.0, 1.0), (9.0, 1.5))
    assert np.array_equal(W, [[1.0, 1.0], [9.0, 1.5]])


def test_start_equal_goal_gives_two_equal_points(square_env):
    W = plan_leader_path(square_env, (1.0, 1.0), (1.0, 1.0))
    assert W.shape == (2, 2) and np.array_equal(W[0], W[1])


def test_clearance_margin_lowered_near_a_close_start(square_env):
    # start 0.04 m from the inflated square (< clearance 0.1): the margin drops to 0.02 m instead of failing
    W = plan_leader_path(square_env, (2.46, 5.0), (8.0, 5.0), iterations=300, clearance=0.1)
    assert np.array_equal(W[0], [2.46, 5.0])
    assert np.all(square_env.segment_clearance(W[:-1], W[1:]) > 0.02)


def test_start_inside_obstacle_raises(square_env):
    with pytest.raises(PathError, match=r"start \(5, 5\) is inside .*clearance -2\.500 m"):
        plan_leader_path(square_env, (5.0, 5.0), (9.0, 9.0))
    with pytest.raises(PathError, match=r"goal .* inside"):
        plan_leader_path(square_env, (1.0, 1.0), (2.7, 5.0))
    with pytest.raises(PathError, match="outside the room"):
        plan_leader_path(square_env, (1.0, 1.0), (11.0, 5.0))


def test_ompl_log_level_restored(discs_env):
    from ompl import util as ou

    before = ou.getLogLevel()
    plan_leader_path(discs_env, (1.0, 5.0), (9.0, 5.2), seed=3, iterations=300)
    assert ou.getLogLevel() == before
    with pytest.raises(PathError):  # also after a failure
        plan_leader_path(discs_env, (1.0, 5.0), (9.0, 5.2), seed=3, iterations=5)
    assert ou.getLogLevel() == before


def test_goal_enclosed_by_ring_raises():
    ring = shapely.Point(5.0, 5.0).buffer(3.0).difference(shapely.Point(5.0, 5.0).buffer(2.0))
    env = make_env([ring])
    with pytest.raises(PathError, match=r"no collision-free path.*200 iterations.*more iterations.*different goal"):
        plan_leader_path(env, (0.8, 0.8), (5.0, 5.0), iterations=200)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"start": (np.nan, 1.0)},
        {"goal": (1.0, 2.0, 3.0)},
        {"iterations": 0},
        {"iterations": 2.5},
        {"seed": -1},
        {"clearance": -0.1},
        {"clearance": float("inf")},
        {"range": 0.0},
    ],
)
def test_plan_parameter_errors(square_env, kwargs):
    args = {"start": (1.0, 1.0), "goal": (9.0, 9.0)} | kwargs
    start, goal = args.pop("start"), args.pop("goal")
    with pytest.raises(ParameterError):
        plan_leader_path(square_env, start, goal, **args)


# ------------------------------------------------------------------------------------------------------------
# time_law


def test_time_law_samples_endpoints_and_rest(discs_path):
    tr = time_law(discs_path)
    assert isinstance(tr, Trajectory)
    assert tr.t.shape == (301,) and tr.x.shape == tr.xd.shape == tr.xdd.shape == (301, 2)
    assert tr.t[0] == 0.0 and tr.t[-1] == 15.0
    np.testing.assert_allclose(np.diff(tr.t), 0.05, rtol=0, atol=1e-12)
    assert np.array_equal(tr.x[0], [1.0, 5.0]) and np.array_equal(tr.x[-1], [9.0, 5.2])
    assert np.array_equal(tr.waypoints, discs_path)
    for k in (0, -1):  # minimum-jerk law: at rest at both ends
        np.testing.assert_allclose(tr.xd[k], 0.0, atol=1e-12)
        np.testing.assert_allclose(tr.xdd[k], 0.0, atol=1e-12)
    assert np.all(np.isfinite(tr.xd)) and np.all(np.isfinite(tr.xdd))


def test_time_law_derivatives_match_finite_differences(discs_path):
    tr = time_law(discs_path)
    h = 0.05
    # The same trajectory sampled 10x finer: same positions at common times, and an estimate of the jerk bound
    # J = sup |d3x/dt3| (piecewise continuous: the cubic spline's third derivative jumps at its knots).
    fine = time_law(discs_path, Ts=h / 10)
    np.testing.assert_allclose(fine.x[::10], tr.x, atol=1e-12)
    jerk = np.max(np.linalg.norm(np.diff(fine.xdd, axis=0), axis=1)) / (h / 10)
    # Central difference of x (Taylor, integral remainder): |(x(t+h) - x(t-h)) / 2h - xd(t)| <= h^2 J / 6.
    # The bound is tight here (the largest error is at the smooth ends); 20 % covers the estimate of J.
    fd_v = (tr.x[2:] - tr.x[:-2]) / (2 * h)
    err_v = np.max(np.linalg.norm(fd_v - tr.xd[1:-1], axis=1))
    assert err_v <= 1.2 * h**2 / 6 * jerk + 1e-12
    assert err_v < 1e-3 * np.max(np.linalg.norm(tr.xd, axis=1))
    # Central difference of xd: xdd is only Lipschitz (constant J), so |error| <= h J / 2.
    fd_a = (tr.xd[2:] - tr.xd[:-2]) / (2 * h)
    err_a = np.max(np.linalg.norm(fd_a - tr.xdd[1:-1], axis=1))
    assert err_a <= 1.2 * h / 2 * jerk + 1e-12
    assert err_a < 1e-2 * np.max(np.linalg.norm(tr.xdd, axis=1))
    # arc-length parametrisation: speed = s_dot of the minimum-jerk law, L = length of the fine polyline
    L = np.sum(np.linalg.norm(np.diff(fine.x, axis=0), axis=1))
    tau = tr.t / 15.0
    np.testing.assert_allclose(np.linalg.norm(tr.xd, axis=1), 30 * L / 15.0 * tau**2 * (1 - tau) ** 2, atol=1e-5)


def test_time_law_straight_line_is_minimum_jerk():
    tr = time_law([[0.0, 0.0], [3.0, 4.0]], T_end=10.0, Ts=0.1)
    assert tr.x.shape == (101, 2)
    u = np.array([0.6, 0.8])
    tau = tr.t / 10.0
    s = 5.0 * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
    np.testing.assert_allclose(tr.x, s[:, None] * u, atol=1e-12)
    np.testing.assert_allclose(tr.xd, (5.0 / 10.0 * 30 * tau**2 * (1 - tau) ** 2)[:, None] * u, atol=1e-12)
    sdd = 5.0 / 100.0 * 60 * tau * (1 - tau) * (1 - 2 * tau)
    np.testing.assert_allclose(tr.xdd, sdd[:, None] * u, atol=1e-12)
    assert np.linalg.norm(tr.xd[50]) == pytest.approx(1.875 * 5.0 / 10.0, abs=1e-12)  # peak speed 15/8 L/T


@settings(max_examples=25, deadline=None)
@given(
    steps=st.lists(
        st.tuples(st.floats(0.2, 2.0), st.floats(-1.0, 1.0)),  # (dx, dy) per segment: no reversal
        min_size=1,
        max_size=8,
    ),
    T_end=st.sampled_from([5.0, 15.0]),
)
def test_time_law_properties_random_polylines(steps, T_end):
    wp = np.vstack([[0.0, 0.0], np.cumsum(np.array(steps), axis=0)])
    tr = time_law(wp, T_end=T_end, Ts=0.05)
    assert len(tr.t) == round(T_end / 0.05) + 1
    assert np.array_equal(tr.x[0], wp[0]) and np.array_equal(tr.x[-1], wp[-1])
    np.testing.assert_allclose(tr.xd[[0, -1]], 0.0, atol=1e-12)
    np.testing.assert_allclose(tr.xdd[[0, -1]], 0.0, atol=1e-12)
    # arc length parametrisation: |xd| / (30 tau^2 (1 - tau)^2 / T) is the same length L at every sample
    tau = tr.t[1:-1] / T_end
    L = np.linalg.norm(tr.xd[1:-1], axis=1) / (30 * tau**2 * (1 - tau) ** 2 / T_end)
    np.testing.assert_allclose(L, L[0], rtol=1e-9)
    assert L[0] >= np.linalg.norm(wp[-1] - wp[0]) - 1e-9  # no shorter than the straight line
    # the tangential acceleration is s_ddot: xdd . xd / |xd| = L 60 tau (1 - tau)(1 - 2 tau) / T^2
    v = np.linalg.norm(tr.xd[1:-1], axis=1)
    at = np.sum(tr.xdd[1:-1] * tr.xd[1:-1], axis=1) / v
    np.testing.assert_allclose(at, L[0] * 60 * tau * (1 - tau) * (1 - 2 * tau) / T_end**2, atol=1e-9)


@pytest.mark.parametrize(
    "steps",
    [
        [(1.0, 0.0), (0.75, 1.0), (0.25, -0.75), (1.0, 0.0), (1.3125, 0.875)],  # found by hypothesis in a CI run
        [(0.5, 0.0), (0.203125, -0.75), (1.5, 0.0), (1.8125, 1.0)],  # every turn < 90°, a short segment
    ],
)
def test_a_spline_that_loops_round_a_sharp_turn_is_refined_not_refused(steps):
    """The interpolating spline through these polylines (x always increasing: no reversal) loops round a sharp turn
    next to a short segment — a cusp of the spline, not of the waypoints. Midpoints are inserted round it until the
    spline is regular: the trajectory passes through every waypoint, its tangent never turns by 90° between samples
    and its speed is positive inside the motion."""
    wp = np.vstack([[0.0, 0.0], np.cumsum(np.array(steps), axis=0)])
    with pytest.raises(ParameterError, match="cusp"):
        path_module._ArcLengthSpline(path_module._ensure_four(wp))  # the spline through the waypoints alone
    tr = time_law(wp, T_end=5.0, Ts=0.01)
    assert np.array_equal(tr.x[0], wp[0]) and np.array_equal(tr.x[-1], wp[-1])
    speed = np.linalg.norm(tr.xd[1:-1], axis=1)
    assert np.all(speed > 0)
    assert np.all(np.sum(tr.xd[1:-2] * tr.xd[2:-1], axis=1) > 0)  # no turn of 90° or more between samples
    d = np.min(np.linalg.norm(tr.x[:, None, :] - wp[None, :, :], axis=2), axis=0)
    assert d.max() < 0.05  # every waypoint is passed within one sample's travel (≤ 0.05 m at Ts = 0.01 s here)


def test_waypoints_that_retrace_their_path_are_still_refused():
    """A true reversal (the polyline turns back along itself) keeps its cusp however densely it is refined."""
    with pytest.raises(ParameterError, match="turn back on themselves"):
        time_law([[0.0, 0.0], [1.0, 0.0], [0.5, 0.0]], T_end=5.0)


@pytest.mark.parametrize("wp", [[[1.0, 2.0], [1.0, 2.0]], [[1.0, 2.0], [1.0, 2.0], [1.0, 2.0 + 1e-12]]])
def test_time_law_zero_length_is_constant(wp):
    tr = time_law(wp)
    assert tr.x.shape == (301, 2)
    assert np.all(tr.x == [1.0, 2.0]) and np.all(tr.xd == 0.0) and np.all(tr.xdd == 0.0)


def test_time_law_duplicate_waypoints_are_merged():
    a = time_law([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [2.0, 0.5], [4.0, 1.0]])
    b = time_law([[0.0, 0.0], [1.0, 1.0], [2.0, 0.5], [4.0, 1.0]])
    np.testing.assert_allclose(a.x, b.x, atol=1e-12)
    assert np.all(np.isfinite(a.xdd))


@pytest.mark.parametrize(
    "wp",
    [
        [(1.0, 2.4), (7.6, 2.4), (7.6, 9.0)],  # tight 90 degree corner round the inflated square
        [(1.0, 1.0), (2.4, 2.4), (2.4, 7.6), (9.0, 9.0)],  # zig-zag along the side
        [(1.0, 2.4), (7.6, 2.4), (7.65, 7.6), (9.0, 7.6)],  # S-bend
    ],
)
def test_time_law_spline_kept_free_on_corner_map(square_env, wp):
    wp = np.array(wp)
    dense_t = 0.005
    # the plain spline (no env) cuts into the 0.05 m margin: the check is needed
    free_spline = time_law(wp, Ts=dense_t)
    assert np.min(square_env.exact_clearance(free_spline.x)) < 0.05
    tr = time_law(wp, env=square_env, clearance=0.05)
    assert np.min(square_env.exact_clearance(tr.x)) >= 0.05
    dense = time_law(wp, Ts=dense_t, env=square_env, clearance=0.05)  # same spline, sampled every ~1 cm or less
    np.testing.assert_allclose(dense.x[::10], tr.x, atol=1e-12)
    assert np.min(square_env.segment_clearance(dense.x[:-1], dense.x[1:])) >= 0.05 - 1e-6
    assert np.array_equal(tr.x[0], wp[0]) and np.array_equal(tr.x[-1], wp[-1])
    again = time_law(wp, env=square_env, clearance=0.05)
    assert again.x.tobytes() == tr.x.tobytes()  # refinement is deterministic


def test_time_law_polyline_too_close_raises(square_env):
    with pytest.raises(PathError, match="clearance 0.100 m < the required 0.2"):
        time_law([(1.0, 2.4), (7.6, 2.4)], env=square_env, clearance=0.2)


@pytest.mark.parametrize(
    "args",
    [
        {"waypoints": [[0.0, 0.0]]},
        {"waypoints": [[0.0, 0.0], [np.nan, 1.0]]},
        {"waypoints": [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]},
        {"waypoints": [0.0, 1.0]},
        {"Ts": 0.0},
        {"Ts": -0.05},
        {"Ts": 0.07},  # 15 / 0.07 is not an integer number of steps
        {"Ts": 20.0},
        {"T_end": 0.0},
        {"T_end": float("nan")},
        {"clearance": -1.0},
        {"waypoints": [[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]]},  # reversal: cusp of the spline
    ],
)
def test_time_law_parameter_errors(args):
    kwargs = {"waypoints": [[0.0, 0.0], [1.0, 1.0]]} | args
    with pytest.raises(ParameterError):
        time_law(**kwargs)


# ------------------------------------------------------------------------------------------------------------
# leader_trajectory


def test_leader_trajectory_combines_planner_and_time_law(discs_env, discs_path):
    tr = leader_trajectory(discs_env, (1.0, 5.0), (9.0, 5.2), seed=0, iterations=400)
    assert np.array_equal(tr.waypoints, discs_path)
    assert tr.t.shape == (301,)
    assert np.array_equal(tr.x[0], [1.0, 5.0]) and np.array_equal(tr.x[-1], [9.0, 5.2])
    assert np.min(discs_env.segment_clearance(tr.x[:-1], tr.x[1:])) >= 0.05 - 1e-6
    again = leader_trajectory(discs_env, (1.0, 5.0), (9.0, 5.2), seed=0, iterations=400)
    assert again.x.tobytes() == tr.x.tobytes() and again.xdd.tobytes() == tr.xdd.tobytes()
