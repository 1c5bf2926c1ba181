"""tmr.views.htmlview: the self-contained plotly view (offline, frames, slider, equal aspect, data = the plan)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tests.motion_data import mopick_plan, scenario_a
from tmr.mcdpr.motion import mcdpr_motion
from tmr.views.animate import frame_indices
from tmr.views.htmlview import build_figure, write_html
from tmr.views.motion import chain_motion


@pytest.fixture(scope="module")
def chain():
    plan, env, cp = scenario_a()
    m = chain_motion(plan, env, cp)
    return plan, m, build_figure(m)


def test_frames_slider_and_equal_aspect(chain):
    plan, m, fig = chain
    idx = frame_indices(m, fps=10.0, max_frames=200)
    assert [f.name for f in fig.frames] == [str(int(k)) for k in idx]
    steps = fig.layout.sliders[0].steps
    assert len(steps) == len(idx) and steps[-1].label == f"{plan.t[-1]:.2f}"
    assert fig.layout.yaxis.scaleanchor == "x" and fig.layout.yaxis.scaleratio == 1
    assert fig.layout.xaxis.title.text == "x [m]" and fig.layout.yaxis.title.text == "y [m]"
    assert [b.label for b in fig.layout.updatemenus[0].buttons] == ["▶ play", "❚❚ pause"]
    names = {t.name for t in fig.data if t.showlegend is not False}
    assert {"obstacle", "grown by robot radius", "anchor", "goal", "tether", "leader trail"} <= names


def test_frame_data_is_the_plan(chain):
    """Each frame's robot discs are centred on the plan's positions; tether hover gives its catenary sag."""
    plan, m, fig = chain
    n = plan.robots.shape[1]
    for fr in (fig.frames[0], fig.frames[len(fig.frames) // 2], fig.frames[-1]):
        k = int(fr.name)
        discs = fr.data[-n:]  # the bodies come last, robot 1..N
        for i, d in enumerate(discs):
            xs, ys = np.array(d.x[:-1]), np.array(d.y[:-1])  # the closing point repeats the first
            assert abs(xs.mean() - plan.robots[k, i, 0]) <= 1e-9 and abs(ys.mean() - plan.robots[k, i, 1]) <= 1e-9
            r = np.hypot(xs - xs.mean(), ys - ys.mean())
            assert np.allclose(r, plan.safety_radius, atol=1e-9)
        for i, ln in enumerate(m.lines):
            text = fr.data[i].text[0]
            got = float(re.search(r"sag ([0-9.]+) m", text).group(1))
            assert got == pytest.approx(ln.sag[k], abs=5e-4)
        trail = fr.data[len(m.lines)]
        shown = [int(f.name) for f in fig.frames if int(f.name) <= k]
        assert list(trail.x) == plan.robots[shown, n - 1, 0].tolist()  # through the shown samples, ends at k


def test_mopick_side_view_shows_heights():
    """MoPICK and CCMA get a side view (x–z, equal scale): the platform's height is its z, cables end on it."""
    robot, scene, res = mopick_plan(n=5)
    m = mcdpr_motion(robot, scene, res)
    fig = build_figure(m)
    assert fig.layout.yaxis2.scaleanchor == "x2" and fig.layout.xaxis2.matches == "x"
    fr = fig.frames[-1]
    side = [d for d, i in zip(fr.data, fr.traces, strict=True) if fig.data[i].yaxis == "y2"]
    assert len(side) == 4 + 1 + 5  # cables, trail, bodies
    assert list(side[-1].x) == [res.platform[-1, 0]] and list(side[-1].y) == [res.platform[-1, 2]]
    assert list(side[0].y) == [1.2, res.platform[-1, 2]]  # cable 1: exit 1.2 m up, to the platform
    assert "yaxis2" not in build_figure(chain_motion(*scenario_a())).layout.to_plotly_json()  # chain: top view only


def test_offline_file_same_bytes(tmp_path):
    robot, scene, res = mopick_plan(n=5)
    m = mcdpr_motion(robot, scene, res)
    a = write_html(m, tmp_path / "a.html")
    b = write_html(m, tmp_path / "b.html")
    html = a.read_text(encoding="utf-8")
    assert a.read_bytes() == b.read_bytes()
    assert "plotly.js v" in html or "plotly.js" in html
    assert not re.search(r"<script[^>]+src=\"https?://", html)  # no network needed
    assert "sample 1" in html and len(html) > 3_000_000  # plotly.js itself is embedded
