"""Tests of tmr.views.plot: Figs. 5–8 of Caruso 2021 built on a synthetic 3-robot plan around a disc."""

from __future__ import annotations

import os
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.collections import PatchCollection
from matplotlib.figure import Figure
from shapely.geometry import Point

from tmr.checks.metrics import filter_trajectories
from tmr.control.clik import Plan
from tmr.views.plot import plot_chain_poses, plot_distance_errors, plot_speeds, plot_trajectories, save_figure
from tmr.world.environment import Environment

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
BOUNDS = (0.0, 0.0, 10.0, 10.0)


def make_env(obstacles, bounds, safety_radius=0.5):
    return Environment.from_geometry(obstacles, bounds, safety_radius=safety_radius, resolution=0.05)


def synthetic_plan(T: float = 15.0, Ts: float = 0.05, N: int = 3) -> Plan:
    """Leader goes from near the base round a disc at (5, 5) (along a radius-2.2 arc) to (7.2, 5); robot j
    follows the same path at arc length j/N of the leader's; robots 1..N-1 get a few task-switching spikes."""
    base = np.array([1.0, 5.0])
    phi = np.radians(np.linspace(-150.0, 0.0, 400))
    arc = np.stack([5.0 + 2.2 * np.cos(phi), 5.0 + 2.2 * np.sin(phi)], axis=-1)
    path = np.concatenate([np.linspace(base, arc[0], 100, endpoint=False), arc])
    s_path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=-1))])
    t = np.arange(round(T / Ts) + 1) * Ts
    u = t / T
    s_leader = 3.3 + (s_path[-1] - 3.3) * (10 * u**3 - 15 * u**4 + 6 * u**5)
    robots = np.empty((t.size, N, 2))
    for j in range(N):
        s_j = s_leader * (j + 1) / N
        robots[:, j, 0] = np.interp(s_j, s_path, path[:, 0])
        robots[:, j, 1] = np.interp(s_j, s_path, path[:, 1])
    rng = np.random.default_rng(1)
    for k in (90, 91, 180, 230):
        robots[k, : N - 1] += rng.normal(0.0, 0.06, size=(N - 1, 2))
    pts = np.concatenate([np.broadcast_to(base, (t.size, 1, 2)), robots], axis=1)
    links = np.diff(pts, axis=1)
    spans = np.linalg.norm(links, axis=-1)
    q = np.empty((t.size, 2 * N))
    q[:, 0::2] = np.arctan2(links[..., 1], links[..., 0])
    q[:, 1::2] = spans
    qdot = np.zeros_like(q)
    qdot[:-1] = np.diff(q, axis=0) / Ts
    active = np.zeros(t.size, dtype=bool)
    active[85:120] = True
    active[175:240] = True
    return Plan(
        method="qp",
        scenario="synthetic",
        t=t,
        q=q,
        qdot=qdot,
        robots=robots,
        base=base,
        reference=robots[:, -1].copy(),
        spans=spans,
        span_limits=np.tile([1.0, 5.63], (N, 1)),
        safety_radius=0.5,
        success=True,
        failure=None,
        diagnostics={"obstacle_active": active},
        wall_time=1.2,
        params={},
        goal=robots[-1, -1].copy(),
    )


@pytest.fixture(scope="module")
def plan():
    return synthetic_plan()


@pytest.fixture(scope="module")
def env():
    return make_env([Point(5.0, 5.0).buffer(1.0)], BOUNDS, 0.5)


@pytest.fixture(scope="module")
def filtered(plan):
    return filter_trajectories(plan.robots, 0.05)


def test_chain_poses(plan, env, tmp_path):
    fig = plot_chain_poses(plan, env, every=3.0)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 2  # map + colour bar
    ax = fig.axes[0]
    n_poses = 6  # t = 0, 3, 6, 9, 12, 15 s
    # reference + 3 robot traces + (chain polyline + robot markers) per pose + base + goal
    assert len(ax.lines) == 1 + 3 + 2 * n_poses + 2
    polylines = [ln for ln in ax.lines if len(ln.get_xdata()) == 4]  # base + 3 robots
    assert len(polylines) == n_poses
    np.testing.assert_allclose(polylines[1].get_xydata(), np.vstack([plan.base, plan.robots[60]]))  # t = 3 s
    circles = [c for c in ax.collections if isinstance(c, PatchCollection)]  # robots, radius = safety radius
    assert len(circles) == n_poses and all(len(c.get_paths()) == 3 for c in circles)
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
    assert "synthetic" in ax.get_title() and "qp" in ax.get_title()
    assert ax.get_aspect() == 1.0
    out = save_figure(fig, tmp_path / "fig5.png")
    data = out.read_bytes()
    assert data.startswith(PNG_SIGNATURE) and len(data) > 10_000


def test_chain_poses_every(plan, env):
    ax = plot_chain_poses(plan, env, every=5.0).axes[0]
    assert len(ax.lines) == 1 + 3 + 2 * 4 + 2  # t = 0, 5, 10, 15


def test_trajectories(plan, filtered):
    fig = plot_trajectories(plan, filtered)
    assert len(fig.axes) == 6
    assert all(len(ax.lines) == 2 for ax in fig.axes)
    assert fig.axes[0].get_ylabel() == "x [m]" and fig.axes[-1].get_xlabel() == "time [s]"
    np.testing.assert_array_equal(fig.axes[3].lines[1].get_ydata(), filtered[:, 1, 1])
    assert all(len(ax.lines) == 1 for ax in plot_trajectories(plan).axes)


def test_distance_errors(plan):
    fig = plot_distance_errors(plan)
    ax_e, ax_s = fig.axes
    assert len(ax_e.lines) == 3 + 1  # 3 tethers + zero line
    assert len(ax_s.lines) == 3 + 2  # 3 spans + d_max + d_lo
    err = plan.spans - plan.spans.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(ax_e.lines[0].get_ydata(), err[:, 0])
    assert "[m]" in ax_e.get_ylabel() and "[m]" in ax_s.get_ylabel()


def test_speeds(plan, filtered, tmp_path):
    fig = plot_speeds(plan, filtered)
    assert len(fig.axes) == 3 and all(len(ax.lines) == 2 for ax in fig.axes)
    leader = fig.axes[2].lines[0].get_ydata()
    assert np.mean(leader) == pytest.approx(1.0, rel=0.05)  # normalised by the leader's mean speed
    a = save_figure(fig, tmp_path / "a.png").read_bytes()
    b = save_figure(fig, tmp_path / "b.png").read_bytes()
    assert a == b and a.startswith(PNG_SIGNATURE)
    assert sorted(os.listdir(tmp_path)) == ["a.png", "b.png"]


def test_view_bounds_frames_the_known_area_of_an_occupancy_map(tmp_path):
    """A map_saver map that is mostly unknown is framed on its known free area and the plan, not the whole image;
    a geometric room is framed whole."""
    from tests.test_maps import _turtlebot3_world
    from tmr.views.plot import view_bounds
    from tmr.world.maps import load_environment

    env = load_environment(_turtlebot3_world(tmp_path), safety_radius=0.15)
    pts = np.array([[-2.0, 0.0], [1.5, 2.5]])
    x0, y0, x1, y1 = view_bounds(env, pts)
    # the arena's known free cells span x in [-2.85, 1.85], y in [-1.85, 2.85]; margin 0.5 m
    assert (x0, y0, x1, y1) == pytest.approx((-3.35, -2.35, 2.35, 3.35))
    assert (x1 - x0) * (y1 - y0) < 0.1 * 20 * 20
    # a point outside the known area widens the frame, within the room
    assert view_bounds(env, np.array([[-9.9, 9.9]]))[0] == pytest.approx(-10.0)
    room = make_env([], (0, 0, 10, 8))
    assert view_bounds(room, pts) == (0.0, 0.0, 10.0, 8.0)


@pytest.mark.parametrize("n", [3, 6, 12])
def test_distance_error_legends_fit_in_the_figure(n):
    """Every legend entry is drawn inside the figure, whatever the number of tethers (per-tether limits)."""
    t = np.linspace(0.0, 5.0, 51)
    spans = 1.0 + 0.1 * np.arange(n)[None, :] + 0.2 * np.sin(t)[:, None]
    limits = np.stack([np.full(n, 0.5), 5.0 + 0.1 * np.arange(n)], axis=1)  # d_max differs per tether
    robots = np.stack([np.cumsum(spans, axis=1), np.zeros_like(spans)], axis=-1)  # along x from the base
    plan = SimpleNamespace(
        t=t, spans=spans, span_limits=limits, robots=robots, base=np.zeros(2), safety_radius=0.5, diagnostics={}
    )
    plan.__dict__.update(scenario="S", method="qp", success=True, failure=None)
    fig = plot_distance_errors(plan)
    fig.canvas.draw()
    width, height = fig.bbox.width, fig.bbox.height
    for ax in fig.axes:
        box = ax.get_legend().get_window_extent()
        assert box.x0 >= 0 and box.y0 >= 0 and box.x1 <= width + 1 and box.y1 <= height + 1, (n, box)
