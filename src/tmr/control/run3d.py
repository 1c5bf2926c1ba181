"""The drone chain's planning loop: references + formulation → :class:`~tmr.control.plan3d.DronePlan`
(``formulations/drones.md``, "Per-step QP (3-D)").

Each step k the formulation returns the drones' velocities v_k (``qp``) or joint rates q̇_k (``pinv``) from the state
at t_k, and the state integrates by explicit Euler (Caruso 2021 eq. 21): ``p_{k+1} = p_k + Ts v_k`` or
``q_{k+1} = q_k + Ts q̇_k`` with the drones from the forward kinematics. Every tether's catenary parameter a is
recorded per step (NaN for a vertical tether). A step without a solution (:class:`~tmr.errors.InfeasibleStep`, or a
tether span that no catenary holds) ends the run: the plan is returned up to that step, failed, with the reason; so
does a leader that the hard limits held back from the goal (farther than the goal tolerance at the end).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.control.drones import DronePinv, DroneQP, DroneReferencesLike
from tmr.control.plan3d import DronePlan
from tmr.errors import InfeasibleStep, ParameterError, TetherSpanError, fmt_point
from tmr.model.catenary3d import DroneTetherParams
from tmr.model.params import DroneParams
from tmr.world.world3d import World3D

Array = NDArray[np.float64]

__all__ = ["run_drones", "LineReferences", "line_references", "slowed_references", "REST_SPEED"]

#: A drone is at rest when no velocity component exceeds this [m/s], or a_max Ts / 2 or j_max Ts² / 2 if less (the
#: plan's end: see :func:`run_drones`): stopping from it within one step stays within half the acceleration and jerk
#: bounds.
REST_SPEED = 0.05
#: A step where the hard limits have no common solution: go back this long [s], ...
BACK_S = 1.0
#: ... take this long of the references [s] at half speed (twice the time), then go on; at most SLOW_DOWNS times.
SLOW_S = 3.0
SLOW_DOWNS = 3
#: The speed of the slowed references changes from full to half (and back) over this long [s], smoothly.
RAMP_S = 1.0
#: After the references stop, a leader farther than the goal tolerance that got less than STALL_GAIN [m] closer over
#: the last STALL_S [s] has stalled: the plan ends there (failed: held back), without waiting for the whole settle.
STALL_S = 1.0
STALL_GAIN = 0.01


def _grow(x: Array, n: int, fill: float = 0.0) -> Array:
    """``x`` with its first axis extended to ``n`` (new entries ``fill``)."""
    if x.shape[0] >= n:
        return x
    return np.concatenate([x, np.full((n - x.shape[0], *x.shape[1:]), fill)])


def slowed_references(
    ref: DroneReferencesLike, k0: int, steps: int, ramp: int = 20, base: ArrayLike | None = None
) -> LineReferences:
    """``ref`` re-timed: the same paths, but from sample ``k0`` the next ``steps`` samples' worth of motion at half
    speed, then the rest as before. The speed factor falls from 1 to 1/2 over ``ramp`` samples by a smoothstep,
    holds, and rises back the same way, so the references' accelerations stay of the order of the original ones
    (no jump at the seams). With the factor ρ_j (original samples per new sample) the new sample j sits at the
    original time τ_j = k0 + Σ_{i ≤ j} ρ_i; positions are interpolated linearly between the original samples and
    velocities are the original ones at τ_j times ρ_j (Ts unchanged). ``base`` [m]: the anchor (``ref.base`` if it
    has one)."""
    t = np.asarray(ref.t, dtype=float)
    K = len(t) - 1
    Ts = float(t[1] - t[0]) if K > 0 else 0.0
    R = max(int(ramp), 1)
    u = np.arange(1, R + 1) / R
    down = 1.0 - 0.5 * (3.0 * u**2 - 2.0 * u**3)  # 1 → 1/2
    hold = max(0, int(math.ceil((steps - 2.0 * down.sum()) / 0.5)))
    rates = np.concatenate([down, np.full(hold, 0.5), down[::-1][1:], [1.0]])  # 1/2 → 1 mirrors the fall
    tau = np.concatenate([np.arange(k0 + 1, dtype=float), k0 + np.cumsum(rates)])
    rate = np.concatenate([np.ones(k0 + 1), rates])
    if tau[-1] < K:  # then the rest at full speed
        extra = np.arange(1, int(math.ceil(K - tau[-1])) + 1, dtype=float)
        tau, rate = np.concatenate([tau, tau[-1] + extra]), np.concatenate([rate, np.ones(extra.size)])
    keep = np.concatenate([[True], tau[:-1] < K])  # up to the first sample at or beyond the end
    tau, rate = np.minimum(tau[keep], K), rate[keep]
    i = np.minimum(np.floor(tau).astype(int), max(K - 1, 0))
    w = tau - i

    def at(x: ArrayLike) -> Array:
        x = np.asarray(x, dtype=float)
        if K == 0:
            return np.repeat(x[:1], len(tau), axis=0)
        ww = w.reshape(-1, *([1] * (x.ndim - 1)))
        return (1.0 - ww) * x[i] + ww * x[i + 1]

    r = np.where(tau < K, rate, 1.0).reshape(-1, 1)
    anchor = base if base is not None else getattr(ref, "base", None)
    return LineReferences(
        base=np.asarray(anchor if anchor is not None else np.full(3, np.nan), dtype=float),
        t=Ts * np.arange(len(tau)),
        x=at(ref.x),
        xd=at(ref.xd) * r,
        positions=at(ref.positions),
        velocities=at(ref.velocities) * r[:, :, None],
        start_positions=np.asarray(getattr(ref, "start_positions", np.asarray(ref.positions)[0]), dtype=float),
    )


@dataclass
class LineReferences:
    """References along a straight segment (tests and hand-made worlds; the route planner gives real ones).

    Attributes: base (3,) [m]; t (K+1,) [s]; x, xd the leader's (K+1, 3) [m, m/s]; positions, velocities of every
    drone (K+1, N, 3) [m, m/s]; start_positions (N, 3) [m]."""

    base: Array
    t: Array
    x: Array
    xd: Array
    positions: Array
    velocities: Array
    start_positions: Array


def line_references(
    base: ArrayLike,
    start: ArrayLike,
    goal: ArrayLike,
    n: int,
    *,
    Ts: float = 0.05,
    speed: float = 1.0,
    settle: float = 2.0,
) -> LineReferences:
    """Drone i (1..N) at ``(i/N)`` of the way from ``base`` to the leader's point, the leader moving at ``speed``
    [m/s] from ``start`` to ``goal`` (trapezoid-free: constant speed, then ``settle`` s at the goal)."""
    b, s, g = (np.asarray(v, dtype=float) for v in (base, start, goal))
    T = float(np.linalg.norm(g - s)) / float(speed)
    K = int(np.ceil((T + settle) / Ts))
    t = np.arange(K + 1) * Ts
    frac = np.clip(t / T, 0.0, 1.0) if T > 0 else np.ones_like(t)
    x = s + frac[:, None] * (g - s)
    xd = np.where((t < T)[:, None], (g - s) / max(T, 1e-12), 0.0)
    w = np.arange(1, n + 1) / n
    pos = b + w[None, :, None] * (x[:, None, :] - b)
    vel = w[None, :, None] * xd[:, None, :]
    return LineReferences(b, t, x, xd, pos, vel, pos[0].copy())


def run_drones(
    world: World3D,
    references: DroneReferencesLike,
    formulation: DroneQP | DronePinv,
    start: ArrayLike,
    *,
    tether: DroneTetherParams,
    params: DroneParams,
    scenario: str = "",
    goal: ArrayLike | None = None,
) -> DronePlan:
    """Integrate ``formulation`` (:func:`~tmr.control.drones.make_drone_qp` or ``make_drone_pinv``, built for the
    same world, tether, parameters and references) along the references from the drones at ``start`` (N, 3) [m].

    The plan ends at the references' last sample, or earlier — at the first step after the references have stopped
    moving where the leader is within half the goal tolerance of ``goal`` and every drone at rest (no velocity
    component above :data:`REST_SPEED` [m/s], or a_max Ts / 2): the references' settling time
    (``DroneParams.settle``) is the most the plan waits for the chain to come to rest, not a fixed tail. It fails
    when the leader stalls (less than :data:`STALL_GAIN` closer over :data:`STALL_S`, farther than the goal
    tolerance), or when the settling time is over with the leader off the goal or a drone too fast to stop within one
    step; a step without a solution first slows the references down (:func:`slowed_references`, at most
    :data:`SLOW_DOWNS` times).

    ``diagnostics``: per step (K+1,) ``step_time`` [s] (the whole step: catenaries, world queries, rows and the
    QP), ``qp_step_time`` [s] (the QP's part: its rows and solves; ``qp`` only), ``leader_residual`` [m/s] (the
    leader task's residual: > 0 when a limit holds the leader back), the formulation's own (``qp_level:<name>``
    status codes of :data:`tmr.control.qp.LEVEL_STATUS`, ...), ``slowed_down`` (where the references were slowed,
    if they were) and under ``"timings"`` the loop's wall time. The plan is not checked (``success`` is True if
    every step was computed and the leader ended within the goal tolerance; the independent checker decides the
    rest).
    """
    ctx = formulation.context
    chain = ctx.chain
    N = chain.n_robots
    P = np.asarray(start, dtype=float).reshape(N, 3)
    ref = references
    K = len(ref.t) - 1
    Ts = params.Ts
    if K > 0 and abs(float(ref.t[1] - ref.t[0]) - Ts) > 1e-9:
        raise ParameterError(f"the references are sampled every {ref.t[1] - ref.t[0]:.4f} s, the plan every {Ts} s")
    joints = formulation.integrates == "joints"
    q = chain.q_from_positions(P) if joints else None
    robots = np.zeros((K + 1, N, 3))
    vel = np.zeros((K + 1, N, 3))
    qs = np.zeros((K + 1, chain.dof)) if joints else None
    a = np.full((K + 1, N), np.nan)
    winch = bool(getattr(ctx, "winch_active", False))  # an active winch: the tensions integrate too
    tw = np.full((K + 1, N), np.nan)
    tw_rate = np.zeros((K + 1, N))
    T_w = np.full(N, float(tether.winch_tension))
    T_rate = np.zeros(N)
    diag: dict[str, Any] = {}
    failure: str | None = None
    formulation.reset()
    v_prev = np.zeros(3 * N)
    v_prev2 = np.zeros(3 * N)  # from rest: no acceleration before the start either (the jerk rows)
    t_start = time.perf_counter()
    last = K
    slowed: list[str] = []

    def end_of_motion(r: DroneReferencesLike) -> int:
        """The references' last change: after it the plan may end early, once the chain rests at the goal."""
        moving = np.flatnonzero(np.any(np.diff(np.asarray(r.positions), axis=0) != 0.0, axis=(1, 2)))
        return int(moving[-1]) + 1 if len(moving) else 0

    k_end = end_of_motion(ref)
    g_end = np.asarray(ref.x[-1] if goal is None else goal, dtype=float)
    near = 0.5 * params.goal_tolerance
    stall = int(round(STALL_S / Ts))
    # at rest: stopping from it within one step stays within half the acceleration and jerk bounds (the stop's jerk
    # is v_{k−2} − 2 v_{k−1} per Ts², then v_{k−1} per Ts² as the acceleration returns to 0)
    jerk_step = math.inf if params.drone_jerk_max is None else params.drone_jerk_max * Ts**2
    rest_speed = min(REST_SPEED, 0.5 * params.drone_accel_max * Ts, 0.5 * jerk_step)
    failed_at: list[int] = []
    ended = ""
    k = 0
    while True:
        t0 = time.perf_counter()
        robots[k] = P
        try:
            if winch:
                tw[k] = T_w
                ctx.update(k, P, v_prev, q, winch_tension=T_w, winch_rate_prev=T_rate, v_prev2=v_prev2)
            else:
                ctx.update(k, P, v_prev, q, v_prev2=v_prev2)
        except TetherSpanError as exc:
            failure = f"step {k} (t = {k * Ts:.2f} s): {exc}"
            last = k - 1
            break
        if qs is not None:
            qs[k] = q
        a[k] = ctx.tethers.a  # NaN: vertical
        if k >= k_end:  # the references are at rest: the plan ends once the chain rests at the goal, or stalls
            gap = float(np.linalg.norm(P[-1] - g_end))
            if (
                gap <= near
                and float(np.max(np.abs(v_prev), initial=0.0)) <= rest_speed
                and float(np.max(np.abs(v_prev2 - 2.0 * v_prev), initial=0.0)) <= 0.5 * jerk_step
            ):
                last, ended = k, "rest"
                break
            kb = k - stall
            if (
                kb >= k_end
                and gap > params.goal_tolerance
                and float(np.linalg.norm(robots[kb, -1] - g_end)) - gap < STALL_GAIN
            ):
                last, ended = k, "stall"  # held back: another second brought the leader less than STALL_GAIN closer
                break
        if k == K:
            last, ended = k, "time"
            break
        try:
            out, d = formulation.step(ctx)
        except InfeasibleStep as exc:
            if len(slowed) < SLOW_DOWNS and k > 0 and not joints:
                # the hard limits conflict at this speed (a damper asks a drone to brake harder than a_max):
                # go back BACK_S (twice as far each time the same step fails again) and take the next SLOW_S of
                # the references at half speed, then go on
                again = sum(1 for kf in failed_at if kf == k)
                failed_at.append(k)
                k0 = max(0, k - int(round(BACK_S * 2**again / Ts)))
                ref = slowed_references(ref, k0, int(round(SLOW_S / Ts)), ramp=int(round(RAMP_S / Ts)), base=chain.base)
                slowed.append(f"t = {k * Ts:.2f} s")
                ctx.references = ref
                K, k_end = len(ref.t) - 1, end_of_motion(ref)
                robots, vel, a = _grow(robots, K + 1), _grow(vel, K + 1), _grow(a, K + 1, np.nan)
                tw, tw_rate = _grow(tw, K + 1, np.nan), _grow(tw_rate, K + 1)
                T_w = tw[k0].copy()
                T_rate = tw_rate[k0 - 1].copy() if k0 > 0 else np.zeros(N)
                diag = {key: _grow(val, K + 1, np.nan) for key, val in diag.items()}
                k, P = k0, robots[k0].copy()
                v_prev = vel[k0 - 1].reshape(-1).copy() if k0 > 0 else np.zeros(3 * N)
                v_prev2 = vel[k0 - 2].reshape(-1).copy() if k0 > 1 else np.zeros(3 * N)
                formulation.reset()
                continue
            failure = str(exc) + (f" (after slowing down at {', '.join(slowed)})" if slowed else "")
            last = k
            break
        if joints:
            assert q is not None
            q = q + Ts * out
            P_next = chain.robots(q)
            v = ((P_next - P) / Ts).reshape(-1)
        elif winch:  # x = [v, Ṫ]
            v, T_rate = out[: 3 * N], out[3 * N :]
            tw_rate[k] = T_rate
            P_next = P + Ts * v.reshape(N, 3)
            T_w = np.clip(T_w + Ts * T_rate, tether.winch_tension_min, tether.winch_tension_max)  # rounding only
        else:
            v = out
            P_next = P + Ts * v.reshape(N, 3)
        vel[k] = v.reshape(N, 3)
        if "step_time" in d:  # the formulation's own (the QP: its rows and solves), apart from the whole step
            d["qp_step_time"] = d["step_time"]
        d["step_time"] = time.perf_counter() - t0
        lead = ctx.xd_d + params.leader_gain * (ctx.x_d - P[-1])
        d.setdefault("leader_residual", float(np.linalg.norm(v[-3:] - lead)))
        for key, val in d.items():
            diag.setdefault(key, np.full(K + 1, np.nan))[k] = val
        P, v_prev, v_prev2 = P_next, v, v_prev
        k += 1
    n = max(last, 0) + 1
    short = float(np.linalg.norm(robots[n - 1, -1] - g_end))
    moving = np.abs(vel[n - 2]).max(axis=1) if n > 1 else np.zeros(N)  # each drone's largest velocity component
    stop = min(params.drone_accel_max * Ts, jerk_step)  # the most a stop within one step may shed
    if n > 2 and math.isfinite(jerk_step):  # with a jerk bound the stop's jerk counts too: |v_{n-3} - 2 v_{n-2}| is
        # at most j_max Ts² (the checker's), scaled here so that "moving > stop" says exactly that
        moving = np.maximum(moving, np.abs(vel[n - 3] - 2.0 * vel[n - 2]).max(axis=1) * (stop / jerk_step))
    if failure is None and ended == "stall":
        failure = (
            f"the leader stalled {short:.3f} m from the goal {fmt_point(g_end)} (tolerance {params.goal_tolerance:g} m)"
            f" at {fmt_point(robots[n - 1, -1])}, t = {(n - 1) * Ts:.2f} s: the hard limits held it back (it came "
            f"less than {STALL_GAIN * 100:g} cm closer in the last {STALL_S:g} s)"
        )
    elif (
        failure is None and ended == "time" and (short > params.goal_tolerance or moving.max(initial=0.0) > stop)
    ):  # off the goal, or too fast to stop within one step (the checker counts the stop)
        i = int(np.argmax(moving))
        where = (
            f"the leader is {short:.3f} m from the goal {fmt_point(g_end)} (tolerance {params.goal_tolerance:g} m)"
            if short > params.goal_tolerance
            else f"drone {i + 1} still moves at {moving[i]:.3f} m/s"
        )
        failure = (
            f"the chain did not come to rest at the goal within the settling time ({params.settle:g} s after the "
            f"references stop, t = {(n - 1) * Ts:.2f} s): {where}; a longer --set settle=... may let it"
        )
    wall = time.perf_counter() - t_start
    diagnostics: dict[str, Any] = {key: val[:n] for key, val in diag.items()}
    diagnostics["timings"] = {"loop": wall}
    if slowed:
        diagnostics["slowed_down"] = slowed
    plan_params = {"planner": asdict(params), "tether": tether.as_dict()}
    return DronePlan(
        method=formulation.name,
        scenario=scenario,
        t=np.asarray(ref.t[:n], dtype=float),
        robots=robots[:n],
        velocities=np.vstack([vel[: n - 1], np.zeros((1, N, 3))]) if n else vel[:0],
        base=chain.base.copy(),
        goal=np.asarray(ref.x[-1] if goal is None else goal, dtype=float),
        reference=np.asarray(ref.x[:n], dtype=float),
        tether_a=a[:n],
        tether=tether,
        safety_radius=world.safety_radius,
        bounds=np.asarray(world.bounds, dtype=float),
        success=failure is None,
        failure=failure,
        diagnostics=diagnostics,
        wall_time=wall,
        params=plan_params,
        q=None if qs is None else qs[:n],
        winch_tension=tw[:n] if winch else None,
    )
