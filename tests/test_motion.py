"""tmr.views.motion: plans as timed geometry (tethers as catenaries, MoPICK cables, CCMA links)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.motion_data import mopick_plan, scenario_a
from tmr.errors import ParameterError
from tmr.mcdpr.motion import mcdpr_motion
from tmr.model.catenary import CatenaryParams
from tmr.views.motion import Motion, Track, catenary_polylines, chain_motion, sample_stamps


def test_chain_motion_robots_tethers_points():
    plan, env, cp = scenario_a()
    m = chain_motion(plan, env, cp)
    k, n = plan.robots.shape[:2]
    assert m.system == "chain" and m.timed and m.n_samples == k and np.array_equal(m.t, plan.t)
    assert [tr.name for tr in m.tracks] == [f"robot{i + 1}" for i in range(n)]
    assert [tr.role for tr in m.tracks] == ["robot"] * (n - 1) + ["leader"] and m.trail == f"robot{n}"
    for i, tr in enumerate(m.tracks):
        assert np.array_equal(tr.xyz[:, :2], plan.robots[:, i]) and np.all(tr.xyz[:, 2] == cp.exit_height)
        assert tr.radius == plan.safety_radius == 0.5
    assert [ln.name for ln in m.lines] == [f"tether{i + 1}" for i in range(n)]
    ends = np.concatenate([np.broadcast_to(plan.base[:2], (k, 1, 2)), plan.robots], axis=1)
    for i, ln in enumerate(m.lines):
        assert np.array_equal(ln.points[:, 0, :2], ends[:, i]) and np.array_equal(ln.points[:, -1, :2], ends[:, i + 1])
    assert np.array_equal(m.points["anchor"][:2], plan.base[:2]) and np.array_equal(m.points["goal"][:2], plan.goal)
    assert len(m.obstacles) == 5
    x0, y0, x1, y1 = m.bounds
    for p in m.inflated_in_room():
        bx0, by0, bx1, by1 = p.bounds
        assert bx0 >= x0 - 1e-12 and by0 >= y0 - 1e-12 and bx1 <= x1 + 1e-12 and by1 <= y1 + 1e-12


def test_chain_motion_reads_the_plans_own_parameters():
    """Without chain_params the tether heights and winch come from plan.params (what the plan used)."""
    plan, env, cp = scenario_a()
    a, b = chain_motion(plan, env, cp), chain_motion(plan, env)
    for la, lb in zip(a.lines, b.lines, strict=True):
        assert np.array_equal(la.points, lb.points) and np.array_equal(la.sag, lb.sag)


def test_catenary_polylines_level_textbook_sag_and_zero_span():
    """Level ends at h: sag = c (cosh(s / 2c) − 1), c = T0 / (ρ g); a zero span is a straight line."""
    cat = CatenaryParams(horizontal_tension=13.5, mass_per_length=0.15, end_height=0.43, base_height=0.43)
    c = 13.5 / (0.15 * 9.81)
    start = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    end = np.array([[3.0, 4.0], [1.0, 1.0], [2.0, 7.0]])
    pts, sag = catenary_polylines(start, end, 0.43, 0.43, cat, n=21)
    assert pts.shape == (3, 21, 3)
    for j, s in ((0, 5.0), (2, 5.0)):
        assert sag[j] == pytest.approx(c * (math.cosh(s / (2 * c)) - 1.0), abs=1e-12)
        assert pts[j, 10, 2] == pytest.approx(0.43 - sag[j], abs=1e-12)  # mid-span is the lowest point
    assert sag[1] == 0.0 and np.all(pts[1, :, 2] == 0.43) and np.all(pts[1, :, :2] == 1.0)


def test_mcdpr_motion_cables_leave_the_rotated_exit_point():
    """Cable k starts at base position + R(heading) A_k[:2], height A_k[2] (Rasheed 2019 Fig. 1b)."""
    import dataclasses

    robot, scene, res = mopick_plan(n=5)
    offset = np.array([[0.1, 0.05, 1.2], [0.0, 0.0, 1.2], [-0.1, 0.0, 1.1], [0.0, 0.2, 1.2]])
    robot = dataclasses.replace(robot, exit_points=offset)
    m = mcdpr_motion(robot, scene, res, rate=2.0)
    assert m.system == "mcdpr" and not m.timed and np.allclose(m.t, np.arange(5) / 2.0)
    assert [tr.name for tr in m.tracks] == ["base1", "base2", "base3", "base4", "platform"]
    for j in range(5):
        for c in range(4):
            th = res.headings[j, c]
            a = offset[c]
            want = [
                res.bases[j, c, 0] + math.cos(th) * a[0] - math.sin(th) * a[1],
                res.bases[j, c, 1] + math.sin(th) * a[0] + math.cos(th) * a[1],
                a[2],
            ]
            assert np.allclose(m.lines[c].points[j, 0], want, atol=1e-12, rtol=0)
            assert np.array_equal(m.lines[c].points[j, 1], res.platform[j])
    assert set(m.points) == {"task1", "task2", "task3"}
    assert np.array_equal(m.track("base2").yaw, res.headings[:, 1])


def test_motion_refuses_inconsistent_samples():
    t = np.array([0.0, 0.1, 0.2])
    ok = Track("a", np.zeros((3, 3)), "robot")
    with pytest.raises(ParameterError, match="strictly increasing"):
        Motion("chain", "x", np.array([0.0, 0.0, 0.1]), (ok,), (), (), (), (0, 0, 1, 1))
    with pytest.raises(ParameterError, match="track b"):
        Motion("chain", "x", t, (ok, Track("b", np.zeros((2, 3)), "robot")), (), (), (), (0, 0, 1, 1))
    with pytest.raises(ParameterError, match="track c"):
        Motion("chain", "x", t, (Track("c", np.full((3, 3), np.nan), "robot"),), (), (), (), (0, 0, 1, 1))
    with pytest.raises(ParameterError, match="rate"):
        sample_stamps(3, 0.0)
    m = Motion("chain", "x", t, (ok,), (), (), (), (0, 0, 1, 1), points={"goal": np.array([5.0, -2.0, 0.0])})
    assert m.extent(pad=0.0) == (0.0, -2.0, 5.0, 1.0)


def test_views_frame_an_occupancy_maps_known_area_not_the_whole_image():
    """A ROS map is often a small arena in a large unknown image: with ``env.known_free`` set (tmr.world.maps) the views
    frame the known area and the plan, not the 20 m room; other maps frame the room as before."""
    plan, env, cp = scenario_a()
    whole = chain_motion(plan, env, cp)
    assert whole.view is None and whole.extent(pad=0.0) == tuple(float(v) for v in env.bounds)
    env.known_free = (2.0, 3.0, 6.0, 7.0)  # as tmr.world.maps sets it for an occupancy map
    try:
        framed = chain_motion(plan, env, cp)
    finally:
        env.known_free = None
    lo = np.minimum(plan.robots.reshape(-1, 2).min(0), [2.0, 3.0])
    hi = np.maximum(plan.robots.reshape(-1, 2).max(0), [6.0, 7.0])
    x0, y0, x1, y1 = framed.extent(pad=0.0)
    assert framed.view == (2.0, 3.0, 6.0, 7.0)
    assert x0 <= lo[0] and y0 <= lo[1] and x1 >= hi[0] and y1 >= hi[1]  # the plan and the known area are in view
    assert (x1 - x0) * (y1 - y0) < 0.9 * (env.bounds[2] - env.bounds[0]) * (env.bounds[3] - env.bounds[1])
