"""Coarse knots for long horizons: the NLP on every M-th knot first, interpolated to every knot (issue 33).

A horizon of K + 1 knots (the ``qp`` plan's steps, T_s = 0.05 s) is an NLP of 2 N (K + 1) variables whose IPOPT
iterations cost in proportion to K and whose iteration counts grow with it (walls rooms, 720–900 knots: 130–430
iterations of ≈ 0.2 s). The same NLP on every M-th knot (steps of M T_s, the leader's reference and the warm start
sampled there; every knot of the first and last M steps, where the chain starts from and comes to rest) has about M
times fewer variables and rows. Its optimum is interpolated to every knot by a quadratic spline
through the coarse knots (positions; a cubic spline overshoots between knots: f4 12.7 against 0.72 on a walls room
with 8 robots), and accepted as the plan if *every* row of the whole NLP holds at every knot and it is no worse than
the warm start in each term — rows failing at a few knots first re-solved by windows of the whole NLP around them,
each on its own model (``HorizonOptions.coarse_repair``), and where tethers still graze obstacles' corners between
coarse knots the coarse NLP solved again on a grid cut finer there (:func:`refine`,
``HorizonOptions.coarse_refine``) — otherwise :func:`tmr.control.horizon.plan_horizon` solves the whole NLP as
before (``formulations/horizon.md``, "Coarse knots").
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import make_interp_spline

from tmr.control.horizon_model import held

Array = NDArray[np.float64]


def stride(
    K: int, coarse_knots: int | None, coarse_from: int, *, from_size: int | None = None, N: int | None = None
) -> int:
    """Knot stride M of the coarse pass for a horizon of K + 1 knots and N robots: ⌈K / coarse_knots⌉ if
    K + 1 ≥ ``coarse_from`` or N (K + 1) ≥ ``from_size`` (knots × robots; None: no such rule), else 1 (no coarse
    pass). N is needed with ``from_size``."""
    if from_size is not None and N is None:
        raise ValueError("stride: from_size (knots × robots) needs the robots N")
    big = K + 1 >= coarse_from or (from_size is not None and N is not None and N * (K + 1) >= from_size)
    if coarse_knots is None or not big:
        return 1
    return max(1, math.ceil(K / int(coarse_knots)))


def coarse_indices(K: int, M: int, ends: int = 0) -> NDArray[np.int_]:
    """Fine knots of the coarse ones: every M-th knot and K last — a last step shorter than M/2 merged into the one
    before (steps between M/2 and 3M/2: no tiny step where the chain comes to rest) — and every knot of the first and
    the last ``ends`` steps (where the chain starts from and comes to rest; 0: none)."""
    if M <= 1:
        return np.arange(K + 1)
    grid = np.arange(0, K + 1, M)
    if grid[-1] != K:
        if K - grid[-1] < M / 2 and grid.size > 1:
            grid[-1] = K
        else:
            grid = np.append(grid, K)
    e = np.arange(min(int(ends), K) + 1)
    return np.unique(np.concatenate([e, grid, K - e]))


def refine(grid: NDArray[np.int_], knots: list[int] | NDArray[np.int_], parts: int, pad: int = 1) -> NDArray[np.int_]:
    """The coarse ``grid`` (fine knots, sorted, from 0 to K) with each of its steps that holds one of the fine
    ``knots`` — and ``pad`` steps either side of it — cut into ``parts`` steps as equal as the fine knots allow (a
    step shorter than ``parts`` fine steps: at every fine knot). The grid where rows failed between its knots."""
    grid = np.asarray(grid, dtype=np.intp)
    j = np.clip(np.searchsorted(grid, np.asarray(knots, dtype=np.intp), side="right") - 1, 0, grid.size - 2)
    steps = np.unique(np.clip((j[:, None] + np.arange(-pad, pad + 1)[None, :]).ravel(), 0, grid.size - 2))
    a, b = grid[steps], grid[steps + 1]
    cuts = np.rint(a[:, None] + (b - a)[:, None] * np.arange(1, parts)[None, :] / parts).astype(np.intp)
    return np.unique(np.concatenate([grid, cuts.ravel()]))


def coarse_problem(
    problem: Any,
    warm: Any,
    M: int,
    rate_scale: float,
    margin: float = 0.0,
    ends: int = 0,
    grid: NDArray[np.int_] | None = None,
) -> tuple[Any, Any]:
    """The problem and the warm start on every M-th knot (:func:`coarse_indices`; or on the fine knots ``grid``, e.g.
    :func:`refine`'s): the leader's reference sampled at those knots, the warm start's joints there, the rate bounds
    (speeds and accelerations of joints and robots, ``QPParams``) scaled by ``rate_scale`` ≤ 1 and the robots'
    separation margin raised by ``margin`` [m] — margins for the interpolation between knots (the clearance's is the
    caller's ``d_safe``)."""
    tr = problem.trajectory
    K = tr.t.size - 1
    idx = coarse_indices(K, M, ends) if grid is None else np.asarray(grid, dtype=np.intp)
    tc = np.asarray(tr.t, dtype=float)[idx]  # a non-uniform grid: the NLP's rates and cost take each step's length
    traj = tr._replace(t=tc, x=tr.x[idx], xd=tr.xd[idx], xdd=tr.xdd[idx])
    qp = problem.qp_params
    scaled = {
        f.name: getattr(qp, f.name) * rate_scale
        for f in dataclasses.fields(qp)
        if f.name in ("span_speed_max", "joint_speed_max", "accel_max", "robot_speed_max", "robot_accel_max")
    }
    scaled["separation_margin"] = qp.separation_margin + margin
    pc = dataclasses.replace(problem, trajectory=traj, qp_params=dataclasses.replace(qp, **scaled))
    Qc = held(np.asarray(warm.q, dtype=float), K)[idx]
    wc = dataclasses.replace(
        warm,
        t=tc,
        q=Qc,
        qdot=np.vstack([np.diff(Qc, axis=0) / np.diff(tc)[:, None], np.zeros((1, Qc.shape[1]))]),
        robots=np.asarray(warm.robots, dtype=float)[np.minimum(idx, len(warm.robots) - 1)],
        reference=tr.x[idx],
        spans=Qc[:, 1::2],
        diagnostics={},
    )
    return pc, wc


def interpolate(robots: Array, t_fine: Array, M: int, ends: int = 0, grid: NDArray[np.int_] | None = None) -> Array:
    """Robot positions (K+1, N, 2) [m] at the fine knots ``t_fine`` from the coarse plan's ``robots`` (Kc+1, N, 2) at
    :func:`coarse_indices` (or at the fine knots ``grid``): a quadratic interpolating spline in time per coordinate
    (C¹; its accelerations are the coarse differences' to first order)."""
    idx = coarse_indices(t_fine.size - 1, M, ends) if grid is None else np.asarray(grid, dtype=np.intp)
    k = min(2, idx.size - 1)
    return np.asarray(make_interp_spline(t_fine[idx], robots, k=k, axis=0)(t_fine), dtype=float)
