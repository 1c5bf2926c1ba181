"""Tests of tmr.mcdpr.planner: greedy stage 1 (batched = brute force), smoothing, stage 2, the whole plan."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.mcdpr.capacity import capacity, required_wrench_set
from tmr.mcdpr.planner import (
    MOVES,
    PlannerParams,
    _candidates,
    _clamped_bspline,
    _min_pair_distance,
    base_search,
    check,
    path_headings,
    plan,
    platform_search,
)
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.scene import load_scene

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
    np.testing.assert_allclose(mu, capacity(R, P, S, H, RWS).mu, atol=1e-12)


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
    np.testing.assert_allclose(res.mu, capacity(R, res.platform, res.bases, res.headings, RWS).mu)


def test_check_reports_violations(fig2_plan) -> None:
    import copy

    bad = copy.deepcopy(fig2_plan)
    bad.mu[5] = -1.0
    bad.bases[10, 0] = [2.0, 2.0]  # on top of table 1
    bad.tensions[3] = np.nan
    chk = check(R, ENV, bad)
    assert not chk.ok and chk.nonpositive == (5,) and not chk.collision_free and not chk.tension_ok


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
