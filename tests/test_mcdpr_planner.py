"""Tests of tmr.mcdpr.planner: greedy stage 1 (batched = brute force), smoothing, stage 2, the whole plan."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.mcdpr.capacity import capacity, required_wrench_set
from tmr.mcdpr.capacity_hull import box_rows, capacity_margin_hull
from tmr.mcdpr.planner import (
    MOVES,
    PlannerParams,
    _candidates,
    _clamped_bspline,
    _min_pair_distance,
    _path_ok,
    base_search,
    check,
    path_headings,
    plan,
    platform_search,
    samples_needed,
)
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.scene import load_scene, scene_from_dict
from tmr.mcdpr.tipping import constraint_rows, tipping
from tmr.mcdpr.wrench import wrench_matrix

R = mopick()
SCENE = load_scene("fig2")
ENV = SCENE.environment(R)
RWS = required_wrench_set(R, SCENE.external)
PARAMS = PlannerParams()


@pytest.fixture(scope="module")
def fig2_plan():
    return plan(R, SCENE, PARAMS, ENV)


def test_first_greedy_step_is_the_brute_force_best() -> None:
    target = np.array([3.9, 3.2, 0.8])
    xy, th = SCENE.bases.astype(float), SCENE.headings.astype(float)
    path, heads, mus, _ = base_search(R, ENV, target, xy, th, RWS, PlannerParams(max_iter=1))
    cand, chead, valid = _candidates(ENV, xy, th, PARAMS)
    best = -np.inf
    for combo in np.ndindex(*(len(MOVES),) * 4):  # one capacity call per combination, no batching
        if not all(valid[j, c] for j, c in enumerate(combo)):
            continue
        b = np.array([cand[j, c] for j, c in enumerate(combo)])
        if min(np.linalg.norm(b[i] - b[k]) for i in range(4) for k in range(i + 1, 4)) < 2 * R.base_radius:
            continue
        h = np.array([chead[j, c] for j, c in enumerate(combo)])
        best = max(best, float(capacity(R, target, b, h, RWS).mu))
    assert mus[1] == pytest.approx(best, abs=1e-12)
    assert mus[1] > mus[0]


def test_candidates_are_differential_drive_moves() -> None:
    xy = np.array([[1.0, 1.0], [3.0, 1.0], [3.0, 3.0], [1.0, 3.0]])
    th = np.array([0.0, np.pi / 2, 0.3, -2.0])
    cand, chead, valid = _candidates(ENV, xy, th, PARAMS)
    d = cand - xy[:, None]
    L = np.linalg.norm(d, axis=-1)
    np.testing.assert_array_equal(L[:, 0], 0.0)
    assert np.all(L[:, 1:][valid[:, 1:]] <= PARAMS.d_base + 1e-12)
    for j in range(4):  # never sideways: every move is along the new heading (forward or backward)
        for k in range(1, 7):
            if valid[j, k] and L[j, k] > 0:
                cross = np.cos(chead[j, k]) * d[j, k, 1] - np.sin(chead[j, k]) * d[j, k, 0]
                assert abs(cross) < 1e-12


def test_step_shrinks_near_an_obstacle() -> None:
    # a base 0.1 m from the inflated table of P1, heading into it: full step blocked, a shorter one allowed
    xy = np.array([[2.0, 1.25], [3.1, 1.0], [3.1, 3.0], [0.9, 3.0]])
    th = np.array([np.pi / 2, 0.0, 0.0, 0.0])
    cand, _, valid = _candidates(ENV, xy, th, PARAMS)
    assert valid[0, 1]
    assert 0 < np.linalg.norm(cand[0, 1] - xy[0]) < PARAMS.d_base
    assert ENV.is_free(cand[0, 1][None]).all()


def test_bspline_keeps_end_points_and_convex_hull() -> None:
    ctrl = np.array([[[0.0, 0.0]], [[1.0, 0.0]], [[1.0, 1.0]], [[2.0, 1.0]], [[2.0, 2.0]]])
    S = _clamped_bspline(ctrl, 50)
    np.testing.assert_allclose(S[0], ctrl[0], atol=1e-14)
    np.testing.assert_allclose(S[-1], ctrl[-1], atol=1e-14)
    assert S[..., 0].min() >= -1e-12 and S[..., 0].max() <= 2 + 1e-12


def test_path_headings_forward_and_backward() -> None:
    S = np.array([[[0.0, 0.0]], [[0.1, 0.1]], [[0.2, 0.2]], [[0.1, 0.1]], [[0.1, 0.1]]])
    H = path_headings(S, np.array([0.0]))
    np.testing.assert_allclose(H[1:, 0], np.pi / 4, atol=1e-12)  # turns to the tangent, then reverses along it


def test_platform_search_reaches_the_goal_with_bounded_steps() -> None:
    n = 40
    S = np.repeat(SCENE.bases[None].astype(float), n, axis=0)
    H = np.zeros((n, 4))
    start, goal = np.array([2.0, 2.0, 0.8]), np.array([2.6, 2.3, 0.9])
    P, mu = platform_search(R, start, goal, S, H, RWS, PARAMS)
    np.testing.assert_allclose(P[-1], goal, atol=1e-12)
    assert np.all(np.linalg.norm(np.diff(P[:, :2], axis=0), axis=1) <= PARAMS.d_platform + 1e-12)
    for r in (0, 13, n - 1):  # μ against the independent hull method (general box + tipping rows)
        A, b = constraint_rows(R, tipping(R, P[r], S[r], H[r]))
        W = wrench_matrix(R, P[r], S[r], H[r])
        assert mu[r] == pytest.approx(capacity_margin_hull(W, A, b, RWS), abs=1e-8)


def test_platform_search_refuses_too_few_samples() -> None:
    # 1.5 m at d_MP = 0.05 m needs 31 samples: with 20 the old search stopped short and the platform jumped
    start, goal = np.array([2.0, 2.0, 0.8]), np.array([3.5, 2.0, 0.8])
    assert samples_needed(start, goal, PARAMS.d_platform) == 31
    S = np.repeat(SCENE.bases[None].astype(float), 20, axis=0)
    with pytest.raises(ParameterError, match="at least 31"):
        platform_search(R, start, goal, S, np.zeros((20, 4)), RWS, PARAMS)
    S = np.repeat(SCENE.bases[None].astype(float), 31, axis=0)
    P, _ = platform_search(R, start, goal, S, np.zeros((31, 4)), RWS, PARAMS)
    np.testing.assert_allclose(P[-1], goal, atol=1e-12)


def _arrivals(res) -> tuple[float, float]:
    """Largest way-point miss [m] and largest platform step (horizontal or vertical) [m] of a plan."""
    ends = np.flatnonzero(np.diff(np.r_[res.segment, -1]) != 0)
    miss = np.linalg.norm(res.platform[ends] - res.waypoints[1:], axis=1).max()
    miss = max(miss, float(np.linalg.norm(res.platform[0] - res.waypoints[0])))
    d = np.diff(res.platform, axis=0)
    return float(miss), float(np.maximum(np.hypot(d[:, 0], d[:, 1]), np.abs(d[:, 2])).max())


def test_few_samples_still_reach_every_waypoint_without_jumps() -> None:
    # upsample = 1 gives far fewer base samples than the platform needs at d_MP; the segments are resampled densely
    scene = scene_from_dict(
        {
            "name": "room",
            "bounds": [0, 0, 8, 8],
            "tasks": [[2, 2, 0.8], [3.2, 3.0, 0.8], [2.2, 3.4, 0.5]],
            "bases": [[1, 1], [3, 1], [3, 3], [1, 3]],
            "intermediate": 0,
        }
    )
    params = PlannerParams(upsample=1, max_iter=20)
    res = plan(R, scene, params)
    miss, step = _arrivals(res)
    assert miss <= 1e-9 and step <= params.d_platform + 1e-12
    chk = check(R, scene.environment(R), res)
    assert chk.waypoints_ok and chk.steps_ok


def test_check_reports_missed_waypoints_and_jumps(fig2_plan) -> None:
    import copy

    bad = copy.deepcopy(fig2_plan)
    later = bad.segment >= 2
    bad.platform[later, 0] += 0.3  # from segment 2 on the platform is 0.3 m off: a jump and missed way-points
    chk = check(R, ENV, bad)
    assert not chk.ok and not chk.waypoints_ok and not chk.steps_ok
    assert any("misses" in m and "by 0.3 m" in m for m in chk.messages)
    assert any("jumps" in m for m in chk.messages)


def test_whole_plan_guarantees(fig2_plan) -> None:
    res = fig2_plan
    chk = check(R, ENV, res)
    assert chk.ok, chk.messages
    assert chk.mu_min > 0 and chk.max_tension <= R.t_max
    np.testing.assert_array_equal(res.bases[0], SCENE.bases)
    # the platform passes through every way-point, at the end of its segment
    ends = np.flatnonzero(np.diff(np.r_[res.segment, -1]) != 0)
    np.testing.assert_allclose(res.platform[ends], res.waypoints[1:], atol=1e-12)
    for st in res.stage1:  # greedy: μ never decreases along the iterations (plateau moves only while μ <= 0)
        dmu = np.diff(st["mu"])
        assert np.all(dmu >= -PARAMS.tol)
        assert np.all((dmu > PARAMS.tol) | (st["mu"][:-1] <= 0))
        assert st["mu"][-1] > 0
    assert chk.waypoints_ok and chk.steps_ok
    for r in (0, len(res.mu) // 2, len(res.mu) - 1):  # against the independent hull method
        A, b = constraint_rows(R, tipping(R, res.platform[r], res.bases[r], res.headings[r]))
        W = wrench_matrix(R, res.platform[r], res.bases[r], res.headings[r])
        assert res.mu[r] == pytest.approx(capacity_margin_hull(W, A, b, RWS), abs=1e-8)
        t = res.tensions[r]
        np.testing.assert_allclose(W @ t, [0, 0, R.platform_mass * R.gravity], atol=1e-9)
        assert np.all(A @ t <= b + 1e-9)


def test_check_reports_violations(fig2_plan) -> None:
    import copy

    bad = copy.deepcopy(fig2_plan)
    bad.bases[10, 0] = [2.0, 2.0]  # on top of table 1
    bad.tensions[3] = np.nan
    chk = check(R, ENV, bad)
    assert not chk.ok and not chk.collision_free and not chk.tension_ok


def test_check_recomputes_mu_and_bounds(fig2_plan) -> None:
    import copy

    # a stored μ alone does not make a sample bad ...
    bad = copy.deepcopy(fig2_plan)
    bad.mu[5] = -1.0
    chk = check(R, ENV, bad)
    assert chk.nonpositive == () and chk.mu_min == pytest.approx(float(np.min(fig2_plan.mu)))
    assert any("stored capacity margin differs" in m for m in chk.messages)
    # ... and a pose with μ <= 0 is found although the stored μ and bounds say all is fine
    bad = copy.deepcopy(fig2_plan)
    bad.platform[5, :2] = [9.5, 6.5]  # far outside the bases: the weight cannot be held
    bad.hi[:] = 1e3
    chk = check(R, ENV, bad)
    assert 5 in chk.nonpositive and chk.mu_min < 0 and not chk.ok
    # tensions beyond the recomputed tipping bound are caught even when the stored bound allows them
    bad = copy.deepcopy(fig2_plan)
    cap = capacity(R, bad.platform[7], bad.bases[7], bad.headings[7], RWS)
    A, b = box_rows(cap.lo, cap.hi)
    bad.tensions[7] = cap.hi + 1.0
    bad.hi[7] = cap.hi + 2.0
    chk = check(R, ENV, bad)
    assert not chk.tension_ok


def test_path_ok_checks_bases_between_samples() -> None:
    # two bases swap places: 1 m apart at both samples, but they meet half way
    S = np.array([[[6.0, 3.0], [7.0, 3.0], [6.0, 6.0], [8.0, 6.0]], [[7.0, 3.0], [6.0, 3.0], [6.0, 6.0], [8.0, 6.0]]])
    assert np.linalg.norm(S[:, 0] - S[:, 1], axis=-1).min() >= 2 * R.base_radius
    assert not _path_ok(R, ENV, S)
    assert _path_ok(R, ENV, S[:1])


def _robot_and_scene(p: int):
    rob = R.replace(n_bases=p, cable_base=tuple(range(p)), exit_points=[[0.0, 0.0, 1.2]] * p)
    ang = 2 * np.pi * np.arange(p) / p + np.pi / 4
    bases = np.column_stack([2.5 + 1.3 * np.cos(ang), 2.5 + 1.3 * np.sin(ang)])
    scene = scene_from_dict(
        {"name": f"p{p}", "bounds": [0, 0, 6, 6], "tasks": [[2.5, 2.5, 0.8], [3.0, 2.8, 0.8]], "bases": bases.tolist()}
    )
    return rob, scene


@pytest.mark.parametrize("p", [3, 5])
def test_plan_with_other_numbers_of_cables(p) -> None:
    rob, scene = _robot_and_scene(p)
    res = plan(rob, scene, PlannerParams(max_iter=3))
    assert res.tensions.shape == (len(res.mu), p)
    chk = check(rob, scene.environment(rob), res)
    assert chk.ok, chk.messages
    f = np.array([0.0, 0.0, rob.platform_mass * rob.gravity])
    W = wrench_matrix(rob, res.platform, res.bases, res.headings)
    np.testing.assert_allclose(np.einsum("tij,tj->ti", W, res.tensions), np.broadcast_to(f, (len(W), 3)), atol=1e-6)


def test_plan_rejects_several_cables_per_base() -> None:
    rob = R.replace(n_bases=4, cable_base=(0, 0, 1, 2, 3), exit_points=[[0.0, 0.0, 1.2]] * 5)
    with pytest.raises(ParameterError, match="one cable per base"):
        plan(rob, SCENE)


def test_min_pair_distance_during_simultaneous_straight_moves() -> None:
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 2, (4, 2))
    XY = xy + rng.normal(0, 0.8, (50, 4, 2))
    iu = np.triu_indices(4, 1)
    s = np.linspace(0, 1, 20001)[:, None, None, None]
    traj = xy[None, None] + s * (XY[None] - xy[None, None])  # (S, 50, 4, 2)
    dense = np.linalg.norm(traj[:, :, iu[0]] - traj[:, :, iu[1]], axis=-1).min(axis=(0, 2))
    exact = _min_pair_distance(xy, XY, iu)
    assert np.all(exact <= dense + 1e-12)
    np.testing.assert_allclose(exact, dense, atol=1e-4)
