"""MoPICK in MuJoCo: a pose with capacity margin μ > 0 holds its platform; an 8 kg platform (μ < 0) does not."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo's first import: offscreen rendering for --gif
pytest.importorskip("mujoco")

from tmr.mcdpr.capacity import capacity, required_wrench_set  # noqa: E402
from tmr.mcdpr.planner import PlannerParams  # noqa: E402
from tmr.mcdpr.robot import mopick  # noqa: E402
from tmr.mcdpr.rundir import McdprRun, mcdpr_run_dict  # noqa: E402
from tmr.mcdpr.scene import load_scene  # noqa: E402
from tmr.replay.mcdpr import McdprConfig, edge_margins, replay_mcdpr  # noqa: E402


def static_run(platform: list[float]) -> McdprRun:
    """The fig2 scene's start: bases at their initial positions, the platform held at ``platform`` [m]."""
    robot, scene = mopick(), load_scene("fig2")
    return McdprRun(
        path=Path("static"),
        record=mcdpr_run_dict(robot, scene, PlannerParams()),
        plan={"check": {"ok": True}},
        bases=scene.bases[None].copy(),
        headings=scene.headings[None].copy(),
        platform=np.array([platform]),
        tensions=np.full((1, 4), np.nan),
        mu=np.array([np.nan]),
        segment=np.zeros(1, dtype=np.int64),
    )


def mu(robot, run: McdprRun) -> float:
    rws = required_wrench_set(robot, load_scene("fig2").external)
    return float(capacity(robot, run.platform[0], run.bases[0], run.headings[0], rws).mu)


def test_positive_margin_holds_the_platform() -> None:
    run = static_run([2.0, 2.0, 0.8])
    robot = mopick()
    assert mu(robot, run) > 0.5  # clearly positive
    rp = replay_mcdpr(run, McdprConfig(settle=3.0))
    assert rp.verdict.ok, rp.verdict.reason
    assert rp.platform_error.max() < 0.02
    assert np.all(rp.tensions > robot.t_min) and np.all(rp.tensions < robot.t_max)  # no cable slack or saturated
    assert edge_margins(rp.wheel_force).min() > 1.0  # every base on its wheels
    # at t = 0 (weight only) the winches pull what tmr.mcdpr.tension distributes for the platform's weight
    assert rp.tensions[0] == pytest.approx(rp.tensions_plan[0], abs=1e-2)
    # later, with an external force on: the distribution of weight minus that force, after the loop has settled
    from tmr.mcdpr.tension import closed_form_batch
    from tmr.mcdpr.wrench import wrench_matrix

    W = wrench_matrix(robot, rp.platform, rp.bases)
    f = np.array([0.0, 0.0, robot.platform_mass * robot.gravity]) - rp.external
    expected = closed_form_batch(W, f, np.zeros(4), np.full(4, robot.t_max)).t
    settled = (rp.t % 2.0) > 1.5  # the external force switches corner every 2 s
    assert np.abs(rp.tensions - expected)[settled].max() < 0.05


def test_eight_kilogram_platform_is_not_held(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # a tipped-over base makes MuJoCo write MUJOCO_LOG.TXT into the working directory
    run = static_run([2.0, 2.0, 0.8])
    heavy = mopick().replace(platform_mass=8.0)
    assert mu(heavy, run) < 0
    rp = replay_mcdpr(run, McdprConfig(settle=1.5), robot=heavy)
    assert not rp.verdict.ok
    checks = {c for _, c, _ in rp.verdict.failures}
    assert {"tension", "wheel-lift", "platform"} <= checks  # 78 N cannot be held by 4 x 15 N: it sinks, bases tip
    assert rp.verdict.failures[0][1] in ("tension", "wheel-lift")
    assert rp.platform_error.max() > 0.1
    assert np.isclose(rp.tensions.max(), heavy.t_max, atol=1e-6)  # the winches saturate
    assert edge_margins(rp.wheel_force).min() <= 1e-3  # a base is off two of its wheels
