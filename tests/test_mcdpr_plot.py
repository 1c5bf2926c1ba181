"""Tests of tmr.mcdpr.plot: the figures are written, non-trivial and of the expected size."""

from __future__ import annotations

import matplotlib.image as mpimg
import numpy as np
import pytest

from tmr.mcdpr.planner import PlannerParams, plan
from tmr.mcdpr.plot import plot_mu, plot_tensions, plot_topview
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.scene import load_scene


@pytest.fixture(scope="module")
def small_plan():
    import dataclasses

    r = mopick()
    s = dataclasses.replace(load_scene("fig2"), tasks=load_scene("fig2").tasks[:2], intermediate=1)
    env = s.environment(r)
    return r, s, env, plan(r, s, PlannerParams(), env)


def test_figures(small_plan, tmp_path) -> None:
    r, s, env, res = small_plan
    for path, size in [
        (plot_topview(r, s, env, res, tmp_path / "top.png"), (825, 1100)),
        (plot_mu(res, tmp_path / "mu.png"), (440, 1210)),
        (plot_tensions(r, res, tmp_path / "t.png"), (440, 1210)),
    ]:
        img = mpimg.imread(path)
        assert img.shape[:2] == size
        assert np.std(img[..., :3]) > 0.05  # not a blank canvas
