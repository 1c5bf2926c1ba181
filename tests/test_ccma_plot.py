"""Tests of tmr.ccma.plot: the figures draw the mechanism bodies, agent paths and convergence curves."""

from __future__ import annotations

import io

import numpy as np
import pytest

from tmr.ccma.control import track
from tmr.ccma.energy import EnergyModel
from tmr.ccma.paths import make_path
from tmr.ccma.plot import body_segments, plot_convergence, plot_mechanism
from tmr.ccma.sim import end_effector_pose, reference_state
from tmr.ccma.system import load_system


@pytest.fixture(scope="module")
def tracked():
    m = EnergyModel(load_system("4dof-reduced"))
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    path = make_path("line", p0, r0, steps=3)
    return m, st, track(m, path.positions, path.rotations, keep_states=True)


def test_body_segments_join_the_joint_points(tracked):
    m, st, _ = tracked
    segs = body_segments(m, st)
    assert len(segs) == 7  # 3 posts, 3 arms, the end-effector triangle (closed)
    tri = [s for s in segs if len(s) == 4][0]
    np.testing.assert_allclose(tri[0], tri[-1])
    np.testing.assert_allclose(np.linalg.norm(tri[:3, :2], axis=1), 0.2, atol=1e-6)  # wrists at radius 0.2 m
    assert np.allclose(tri[:, 2], 0.5)


def test_mechanism_figure_has_3d_and_top_views(tracked):
    m, st, res = tracked
    fig = plot_mechanism(m, res, [st, res.states[-1]], "test")
    ax3, ax2 = fig.axes
    assert ax3.name == "3d"
    labels = [ln.get_label() for ln in ax2.get_lines()]
    assert {"agent_a", "agent_b", "agent_c", "end-effector"} <= set(labels)
    ee = [ln for ln in ax2.get_lines() if ln.get_label() == "end-effector"][0]
    np.testing.assert_allclose(ee.get_xdata(), res.ee_position[:, 0])
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    assert buf.getvalue()[:8] == b"\x89PNG\r\n\x1a\n"


def test_convergence_figure_plots_milliseconds_on_log_axis(tracked):
    _, _, res = tracked
    fig = plot_convergence({"step 1": res.histories[0]})
    ax = fig.axes[0]
    assert ax.get_yscale() == "log"
    np.testing.assert_allclose(ax.get_lines()[0].get_xdata(), 1e3 * res.histories[0][:, 0])


def test_joint_angle_panel_draws_turning_joints_and_lists_the_others():
    from tmr.ccma.angles import joint_angles, rotary_joints

    m = EnergyModel(load_system("4dof-reduced"))
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    path = make_path("vcircle", p0, r0, radius=0.05, step=0.01)
    res = track(m, path.positions, path.rotations, keep_states=True)
    names = [m.system.joints[k].name for k in rotary_joints(m)]
    a = joint_angles(m, res.states)
    fig = plot_mechanism(m, res, [st, res.states[-1]], "t", angles=a, joint_names=names)
    assert len(fig.axes) == 3
    ax = fig.axes[2]
    drawn = {ln.get_label(): ln for ln in ax.get_lines()}
    assert set(drawn) == {f"{j}_{leg}" for leg in "abc" for j in ("elbow", "wrist")}  # the mounts do not turn
    np.testing.assert_allclose(drawn["elbow_a"].get_ydata(), np.degrees(a[:, 0]))
    assert "agent_a.mount" in ax.texts[0].get_text()
    assert "largest range 15.6°" in ax.get_title()  # asin(0.3/L) − asin(0.2/L), L = √(0.4² + 0.2²)
