"""Faithful task-priority pseudoinverse CLIK baseline (Caruso 2021 §3–4.2).

Per step (eq. 5–6, Chiaverini 1997 / Baerlocher 1998 singularity-robust form):

    q̇ = Σ_i P^A_{i−1} J_i^# v_i + P^A_t q̇_opt,     P^A_i = I − J^{A†}_i J^A_i,   J^A_i = [J_1; …; J_i]

with J^# the damped least-squares inverse Jᵀ(JJᵀ + λI)⁻¹ (§3) and the two-state task manager of §4.2:
    state 1 (every point beyond the danger distance): tasks = [leader (eq. 20)], q̇_opt = tether regulation (eq. 13, 23);
    state 2 (obstacle task active, eq. 17):           tasks = [leader, obstacle (eq. 18)], q̇_opt = tether regulation.
The joint-limit term enters through the gradient projection method (eq. 7) in the null space of all active tasks, so
the obstacle task outranks it whenever it is active. See ``formulations/pinv.md``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tmr.control.tasks import LeaderTracking, ObstacleEvasion, StepContext, Task, TetherRegulation

Array = NDArray[np.float64]


def dls_inverse(J: Array, damping: float) -> Array:
    """Damped least-squares inverse ``J^# = Jᵀ (J Jᵀ + λ I)⁻¹`` (Caruso 2021 §3), shape (n, m)."""
    m = J.shape[0]
    return np.linalg.solve(J @ J.T + damping * np.eye(m), J).T


def null_space_projector(JA: Array) -> Array:
    """Orthogonal projector ``I − J^{A†} J^A`` onto the null space of the augmented Jacobian (eq. 5–6)."""
    n = JA.shape[1]
    return np.eye(n) - np.linalg.pinv(JA, rcond=1e-10) @ JA


class PinvController:
    """Task-priority CLIK controller with the paper's two-state manager.

    Args:
        leader: primary task (eq. 20).
        tether: joint-limit / tether regulation used as q̇_opt (eq. 7, 13, 23).
        obstacle: obstacle evasion at the critical point (eq. 14–18), or None to disable.
        damping: λ of the DLS inverse.
        extra: further tasks appended after the obstacle task, in priority order (user-defined).
    """

    name = "pinv"

    def __init__(
        self,
        leader: LeaderTracking,
        tether: TetherRegulation,
        obstacle: ObstacleEvasion | None,
        damping: float,
        extra: tuple[Task, ...] = (),
    ) -> None:
        self.leader, self.tether, self.obstacle = leader, tether, obstacle
        self.damping = float(damping)
        self.extra = tuple(extra)

    def reset(self) -> None:
        for t in (self.leader, self.tether, self.obstacle, *self.extra):
            if t is not None:
                t.reset()

    def step(self, ctx: StepContext) -> tuple[Array, dict[str, float]]:
        """Joint velocities for the step in ``ctx`` and per-step diagnostics."""
        tasks: list[Task] = [self.leader]
        active = False
        if self.obstacle is not None:
            active = self.obstacle.update(ctx)
            if active:
                tasks.append(self.obstacle)
        tasks.extend(self.extra)
        n = ctx.chain.dof
        qdot = np.zeros(n)
        P = np.eye(n)
        rows: list[Array] = []
        for task in tasks:
            J, v = task.compute(ctx)
            J = ctx.rows_in("joint", J, getattr(task, "space", "joint"))
            qdot += P @ (dls_inverse(J, self.damping) @ v)
            rows.append(J)
            P = null_space_projector(np.vstack(rows))
        J_t, v_t = self.tether.compute(ctx)
        J_t = ctx.rows_in("joint", J_t, getattr(self.tether, "space", "joint"))
        qdot += P @ (J_t.T @ v_t)  # GPM: q̇_opt = K φ̂ on the prismatic joints (eq. 7, 13)
        diag = {
            "obstacle_active": float(active),
            "critical_clearance": self.obstacle.critical_clearance if self.obstacle is not None else np.inf,
        }
        return qdot, diag
