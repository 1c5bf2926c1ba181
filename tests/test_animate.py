"""tmr.views.animate: the GIF of a plan (frames, timing, size, what a frame shows)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image, ImageSequence

from tests.motion_data import mopick_plan, scenario_a
from tmr.mcdpr.motion import mcdpr_motion
from tmr.views.animate import _Scene, frame_indices, render_frame, write_gif
from tmr.views.motion import Motion, Track, chain_motion


def _motion(k: int, ts: float = 0.05, timed: bool = True) -> Motion:
    xyz = np.zeros((k, 3))
    xyz[:, 0] = np.linspace(0, 1, k)
    return Motion("chain", "m", np.arange(k) * ts, (Track("a", xyz, "robot"),), (), (), (), (0, 0, 1, 1), timed=timed)


def test_frame_indices_play_in_real_time_and_end_on_the_last_sample():
    idx = frame_indices(_motion(123, ts=0.05), fps=10)  # 1 frame per 0.1 s of plan time
    assert idx[0] == 0 and idx[-1] == 122 and np.all(np.diff(idx[:-1]) == 2)
    assert np.array_equal(frame_indices(_motion(10, ts=0.5), fps=10), np.arange(10))  # slower plans: every sample
    capped = frame_indices(_motion(1000, ts=0.01), fps=10, max_frames=50)
    assert len(capped) <= 51 and capped[-1] == 999
    assert np.array_equal(frame_indices(_motion(7, timed=False)), np.arange(7))


@pytest.fixture(scope="module")
def gif_a(tmp_path_factory):
    plan, env, cp = scenario_a()
    m = chain_motion(plan, env, cp)
    path = write_gif(m, tmp_path_factory.mktemp("gif") / "motion.gif")
    return plan, m, path


def test_scenario_a_gif_frames_timing_size(gif_a):
    plan, m, path = gif_a
    im = Image.open(path)
    frames = [f.convert("RGB") for f in ImageSequence.Iterator(im)]
    assert im.format == "GIF" and len(frames) == len(frame_indices(m)) and im.info["duration"] == 100
    assert im.info.get("loop") == 0  # loops forever
    assert path.stat().st_size <= 3_000_000  # the limit for scenario A
    assert (path.stat().st_mode & 0o777) == 0o644
    assert not np.array_equal(np.asarray(frames[0]), np.asarray(frames[-1]))  # it moves


def test_the_leader_disc_is_where_the_plan_puts_it(gif_a):
    """In the last frame, the pixel half a radius beyond the leader's centre (away from its tether) has the
    leader's face colour (orange, alpha 0.45 over white); in the first frame the leader is elsewhere."""
    plan, m, path = gif_a
    sc = _Scene(m)
    frames = [np.asarray(f.convert("RGB")).astype(int) for f in ImageSequence.Iterator(Image.open(path))]
    n = plan.robots.shape[1]

    def pixel(k: int) -> tuple[int, int]:
        p, q = plan.robots[k, n - 1], plan.robots[k, n - 2]
        u = (p - q) / np.linalg.norm(p - q)
        x, y = sc.ax.transData.transform(p + 0.5 * plan.safety_radius * u)
        return int(round(x)), int(round(sc.fig.bbox.height - y))

    face = np.array([255, 127, 14]) * 0.45 + 255 * 0.55
    x, y = pixel(len(plan.t) - 1)
    assert np.max(np.abs(frames[-1][y, x] - face)) <= 30
    assert np.max(np.abs(frames[0][y, x] - face)) > 30


def test_mopick_gif_same_bytes_and_a_frame(tmp_path):
    robot, scene, res = mopick_plan(n=6)
    m = mcdpr_motion(robot, scene, res)
    im = Image.open(write_gif(m, tmp_path / "m.gif"))
    assert im.n_frames == 6  # untimed: every sample
    assert write_gif(m, tmp_path / "again.gif").read_bytes() == (tmp_path / "m.gif").read_bytes()
    png = render_frame(m, 3, tmp_path / "f.png")
    assert Image.open(png).size[0] == 512


def test_mopick_and_ccma_get_a_side_view():
    robot, scene, res = mopick_plan(n=4)
    sc = _Scene(mcdpr_motion(robot, scene, res))
    sc.update(3)
    assert sc.axz is not None and sc.axz.get_ylabel() == "z [m]"
    assert sc.axz.get_aspect() == 1.0  # equal scale
    assert list(sc.side_dots[-1].get_xdata()) == [res.platform[3, 0]]  # the platform, last track
    assert list(sc.side_dots[-1].get_ydata()) == [res.platform[3, 2]]
    plan, env, cp = scenario_a()
    assert _Scene(chain_motion(plan, env, cp)).axz is None  # the chain moves on the floor: top view only
