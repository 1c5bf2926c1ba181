"""The planning loop: reference trajectory + task stack + formulation → :class:`Plan` (Caruso 2021 §4.2, eq. 21).

Each step k the formulation returns q̇_k from the state at t_k, and the joints integrate with explicit Euler
``q_{k+1} = q_k + Ts q̇_k`` (the discretised eq. 21). The robots' positions are the forward kinematics of q (eq. 2).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from tmr.control.tasks import StepContext
from tmr.errors import InfeasibleStep, ParameterError
from tmr.model.chain import Chain

Array = NDArray[np.float64]


@dataclass
class Plan:
    """Result of a plan; arrays are indexed by step k = 0..K (truncated if the run stopped early).

    Attributes:
        method: formulation name ("pinv", "qp", "horizon").
        scenario: scenario name.
        t: times [s], (K+1,).
        q: joint positions, (K+1, n); q[k] at t[k].
        qdot: joint velocities, (K+1, n); qdot[k] applies on [t_k, t_k+1]; qdot[K] = 0.
        robots: robot positions, (K+1, N, 2) [m].
        base: tether anchor (2,) [m].
        reference: leader reference x_d(t), (K+1, 2) [m].
        spans: tether spans (prismatic joints), (K+1, N) [m].
        span_limits: (N, 2) [d_lo, d_max] per tether [m].
        safety_radius: robot safety radius [m].
        success: whether every step was computed and every hard constraint holds (set by the checker).
        failure: reason the plan failed, or None.
        diagnostics: per-step arrays (e.g. "obstacle_active", "critical_clearance").
        wall_time: planning time of the loop [s].
        params: parameters used.
        goal: leader goal (2,) [m].
        winch_tension: with an active winch, every tether's planned horizontal tension T0 per state (K+1, N) [N];
            None for the paper's constant-tension winch.
        axle, heading, drive_v, drive_omega: differential-drive robots only (else None; :mod:`tmr.control.diffdrive`):
            axle centres (K+1, N, 2) [m], headings θ (K+1, N) [rad, continuous], forward speed v and yaw rate ω
            (K+1, N) [m/s, rad/s] held over [t_k, t_k+1] (0 at K). ``robots`` are then the tethers' exit points
            c + b e(θ).
    """

    method: str
    scenario: str
    t: Array
    q: Array
    qdot: Array
    robots: Array
    base: Array
    reference: Array
    spans: Array
    span_limits: Array
    safety_radius: float
    success: bool
    failure: str | None
    diagnostics: dict[str, Array] = field(default_factory=dict)
    wall_time: float = 0.0
    params: dict[str, Any] = field(default_factory=dict)
    goal: Array | None = None
    winch_tension: Array | None = None
    axle: Array | None = None
    heading: Array | None = None
    drive_v: Array | None = None
    drive_omega: Array | None = None

    @property
    def Ts(self) -> float:
        """Sampling period [s]."""
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else 0.0

    @property
    def n_robots(self) -> int:
        return int(self.robots.shape[1])


class Formulation(Protocol):
    """A per-step formulation: ``step(ctx) -> (q̇, diagnostics)``."""

    name: str

    def reset(self) -> None: ...

    def step(self, ctx: StepContext) -> tuple[Array, dict[str, float]]: ...


def run(
    chain: Chain,
    env: object,
    trajectory: Any,
    formulation: Formulation,
    q0: Array,
    *,
    span_limits: Array,
    safety_radius: float,
    samples_per_link: int,
    scenario: str = "",
    params: dict[str, Any] | None = None,
    goal: Array | None = None,
    progress: bool = False,
) -> Plan:
    """Integrate the formulation along the leader trajectory (Caruso 2021 eq. 21, Euler with step Ts).

    Args:
        chain: planar chain; q0: initial joints (the leader must start on the reference).
        env: environment (distance field queries); trajectory: :class:`tmr.route.path.Trajectory` (t, x, xd).
        formulation: object with ``reset()`` and ``step(ctx)``.
        span_limits: (N, 2) [d_lo, d_max]; safety_radius [m]; samples_per_link: clearance samples per tether.
        progress: a tqdm bar of the steps on stderr, shown only once the run has taken 2 s (the caller decides
            whether a bar is wanted at all, e.g. :func:`tmr.io.console.progress_enabled`).

    The run stops early only if the formulation raises :class:`InfeasibleStep` (no motion satisfies its hard
    constraints) or returns non-finite velocities (numerical divergence); the plan is then marked failed, with the
    reason, and holds the steps done so far. Constraint checks are done afterwards on the recorded states
    (:func:`tmr.planner.check`).
    """
    q = chain.check_q(q0).copy()
    t = np.asarray(trajectory.t, dtype=float)
    K = t.size - 1
    if K < 1:
        raise ParameterError("the trajectory needs at least two samples")
    Ts = float(t[1] - t[0])
    ctx = StepContext(chain, env, trajectory.x, trajectory.xd, Ts, samples_per_link, span_limits)
    Q = np.zeros((K + 1, chain.dof))
    Qd = np.zeros((K + 1, chain.dof))
    diag: dict[str, Array] = {}
    failure: str | None = None
    formulation.reset()
    qdot_prev = np.zeros(chain.dof)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=K, desc=f"{formulation.name} steps", unit="step", leave=False, delay=2.0, mininterval=0.5)
    start = time.perf_counter()
    k_done = K
    for k in range(K + 1):
        Q[k] = q
        if bar is not None:
            bar.update(1 if k else 0)
        if k == K:
            break
        ctx.update(k, q, qdot_prev)
        try:
            qdot, d = formulation.step(ctx)
        except InfeasibleStep as exc:
            failure = f"{formulation.name}: {exc}"
            k_done = k
            break
        for key, val in d.items():
            diag.setdefault(key, np.full(K + 1, np.nan))[k] = val
        if not np.all(np.isfinite(qdot)):
            failure = f"{formulation.name}: non-finite joint velocity at step {k} (t = {t[k]:.2f} s)"
            k_done = k
            break
        Qd[k] = qdot
        q = q + Ts * qdot
        qdot_prev = qdot
    wall = time.perf_counter() - start
    if bar is not None:
        bar.close()
    n = k_done + 1
    Q, Qd = Q[:n], Qd[:n]
    robots = np.stack([chain.robots(qk) for qk in Q])
    return Plan(
        method=formulation.name,
        scenario=scenario,
        t=t[:n].copy(),
        q=Q,
        qdot=Qd,
        robots=robots,
        base=chain.base.copy(),
        reference=np.asarray(trajectory.x, dtype=float)[:n].copy(),
        spans=Q[:, chain.prismatic_index].copy(),
        span_limits=np.asarray(span_limits, dtype=float).copy(),
        safety_radius=float(safety_radius),
        success=failure is None,
        failure=failure,
        diagnostics={key: val[:n] for key, val in diag.items()},
        wall_time=wall,
        params=dict(params or {}),
        goal=None if goal is None else np.asarray(goal, dtype=float).copy(),
    )
