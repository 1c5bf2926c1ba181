"""tmr.views.plotpool: figures rendered by worker processes are byte-identical to those rendered in the caller."""

from __future__ import annotations

import pytest
from shapely.geometry import Point

from tests.test_plot import make_env, synthetic_plan
from tmr.checks.metrics import filter_trajectories
from tmr.views import plot
from tmr.views.plotpool import FigurePool


def test_pool_renders_the_same_bytes_as_the_caller():
    plan = synthetic_plan()
    env = make_env([Point(5.0, 5.0).buffer(1.0)], (0.0, 0.0, 10.0, 10.0), 0.5)
    filtered = filter_trajectories(plan.robots, 0.05)
    figures = {
        "chain_poses.png": ("plot_chain_poses", (plan, env), {"every": 3.0}),
        "trajectories.png": ("plot_trajectories", (plan, filtered), {}),
        "distance_errors.pdf": ("plot_distance_errors", (plan,), {}),
        "speeds.png": ("plot_speeds", (plan, filtered), {}),
    }
    with FigurePool(2) as pool:
        pooled = pool.render(figures)
    assert list(pooled) == list(figures)
    for name, (function, args, kwargs) in figures.items():
        fmt = name.rsplit(".", 1)[1]
        assert pooled[name] == plot.figure_bytes(getattr(plot, function)(*args, **kwargs), fmt), name
    assert pooled["chain_poses.png"].startswith(b"\x89PNG") and pooled["distance_errors.pdf"].startswith(b"%PDF")


def test_pool_raises_the_plotting_error():
    with FigurePool(1) as pool, pytest.raises(TypeError):
        pool.render({"x.png": ("plot_speeds", (), {})})  # a missing argument, raised in the worker


def test_dead_workers_fall_back_to_rendering_here():
    """If the workers die (killed, out of memory), the command line renders the figures itself."""
    import os
    import signal
    import time

    from tmr.plan import _pooled

    pool = FigurePool(1)
    try:
        for _ in range(100):  # the worker exists once started
            procs = list(pool._pool._processes.values())
            if procs:
                break
            time.sleep(0.01)
        for p in procs:
            os.kill(p.pid, signal.SIGKILL)
        plan = synthetic_plan()
        assert _pooled(pool, {"s.png": ("plot_speeds", (plan,), {})}) is None
    finally:
        pool.close()
    assert _pooled(None, {}) is None
