"""Forward kinematics of a CCMA: minimise the constraint energy over the state by Newton with line search.

Kumar 2019 §III-A, eq. 2: for given controls u, x*(u) = argminₓ E(x, u), E = ½‖C(x, u)‖². Each iteration solves
(∇ₓ²E + μI) Δx = −∇ₓE with the exact CasADi Hessian (μ = 0 unless the Cholesky factorisation fails, then μ grows
from 1e-10·max diag until it succeeds — far from a solution with non-zero residual the Hessian may be indefinite),
followed by Armijo backtracking on E (a full step that halves the gradient is also accepted when E only changes at
rounding level, as happens at a non-zero residual). The solve is warm-started from the previous state and starts by
re-anchoring every body's rotation (:func:`tmr.ccma.bodies.reanchor`). Converged when ‖∇ₓE‖∞ ≤ ``gtol``·s² [m]
(or E ≤ 1e-30·s² m²), where s = max(1, largest coordinate of the state and controls in metres)
(:func:`problem_size`), because the rounding floor of ∇ₓE grows with the square of the coordinates; or when no
descent is possible and the Newton decrement ½∇ₓEᵀ(∇ₓ²E)⁻¹∇ₓE is below the rounding level of E (:func:`e_noise`),
i.e. E sits at its rounding floor. A mechanism 1000× larger therefore converges as the shipped ones do.

The residual energy E(x*, u) measures how far the commanded agents are from an assemblable configuration;
:func:`simulate` raises :class:`AssemblyError` (naming the worst constraint) when it exceeds ``tol``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from tmr.ccma.bodies import REANCHOR_LIMIT, reanchor
from tmr.ccma.energy import EnergyModel
from tmr.ccma.errors import AssemblyError, ConvergenceError

__all__ = [
    "ASSEMBLY_TOL",
    "SimResult",
    "State",
    "agent_poses",
    "end_effector_pose",
    "newton",
    "reference_state",
    "simulate",
    "worst_constraint",
]

#: Default residual-energy tolerance of an assembled mechanism [m²] (‖C‖ ≤ ~1.4 µm).
ASSEMBLY_TOL = 1e-12


@dataclass
class State:
    """Body states ``x`` (6 n,: position [m] + Cayley vector per body) and reference rotations ``r_ref`` (n, 3, 3)."""

    x: np.ndarray
    r_ref: np.ndarray

    def copy(self) -> State:
        return State(self.x.copy(), self.r_ref.copy())


class SimResult(NamedTuple):
    """Outcome of one forward simulation: ``energy`` = residual E(x*, u) [m²], ``grad_norm`` = ‖∇ₓE‖∞ [m],
    ``hessian`` = ∇ₓ²E at the returned state (reused by the sensitivity analysis)."""

    state: State
    energy: float
    grad_norm: float
    iterations: int
    converged: bool
    hessian: np.ndarray


def reference_state(model: EnergyModel) -> State:
    """The description's reference configuration (assembled for ``model.system.u0``)."""
    return State(model.system.x0.copy(), model.system.r_ref0.copy())


def problem_size(x: np.ndarray, u: np.ndarray) -> float:
    """Size of the coordinates [m] (≥ 1): rounding errors of C, E and ∇ₓE grow with it (1, 2 and 2 powers)."""
    pos = np.abs(x.reshape(-1, 6)[:, :3])
    return max(1.0, float(np.max(pos)) if pos.size else 0.0, float(np.max(np.abs(u))) if u.size else 0.0)


def e_noise(e: float, size: float) -> float:
    """Rounding level [m²] of E = ½‖C‖² at coordinates of ``size`` [m] (C is known to ~1e-16·size per row)."""
    return 1e-10 * e + 1e-14 * size * float(np.sqrt(2.0 * e)) + (1e-15 * size) ** 2


def newton(
    model: EnergyModel,
    state: State,
    u: np.ndarray,
    *,
    gtol: float = 1e-13,
    max_iter: int = 60,
) -> SimResult:
    """Minimise E(·, u) from ``state`` (not modified) by damped Newton with Armijo line search (Kumar 2019 eq. 2)."""
    st = state.copy()
    x = st.x
    reanchor(x, st.r_ref)
    p = model.params(st.r_ref)
    u = np.asarray(u, dtype=float)
    eye = np.eye(x.size)
    size = problem_size(x, u)
    gtol_eff = gtol * size**2
    e, g, h = model.egh(x, u, p)
    for it in range(max_iter + 1):
        gnorm = float(np.max(np.abs(g)))
        if gnorm <= gtol_eff or e <= 1e-30 * size**2:
            return SimResult(st, e, gnorm, it, True, h)
        if it == max_iter:
            break
        mu = 0.0
        while True:
            try:
                factor = cho_factor(h + mu * eye if mu else h, check_finite=False)
                break
            except np.linalg.LinAlgError:
                mu = max(10.0 * mu, 1e-10 * float(np.max(np.abs(np.diag(h)))) + 1e-300)
        dx = -cho_solve(factor, g, check_finite=False)
        slope = float(g @ dx)
        t = 1.0
        while True:  # Armijo backtracking; the full step is evaluated with egh and reused by the next iteration
            x_new = x + t * dx
            if t == 1.0:
                e_new, g_new, h_new = model.egh(x_new, u, p)
                # at the rounding floor of E (residual > 0) a full step that shrinks the gradient is accepted even if
                # E rises by a few ulps; Armijo alone would backtrack into noise forever
                # (rounding of C is ~1e-16 m per row and metre of coordinates, so E = ½‖C‖² is known to about
                # ‖C‖·size·1e-14 m²)
                if e_new <= e + e_noise(e, size) and np.max(np.abs(g_new)) < 0.5 * gnorm:
                    break
            else:
                e_new = model.energy(x_new, u, p)
            if e_new <= e + 1e-4 * t * slope or t < 1e-12:
                break
            t *= 0.5
        if t < 1e-12 and e_new >= e:  # no descent along the Newton direction
            if 0.0 <= -0.5 * slope <= e_noise(e, size):  # predicted decrease below the rounding of E: at the floor
                return SimResult(st, e, gnorm, it, True, h)
            break  # stalled away from a minimum
        x[:] = x_new
        if reanchor(x, st.r_ref, REANCHOR_LIMIT):
            p = model.params(st.r_ref)
            e, g, h = model.egh(x, u, p)
        elif t == 1.0:
            e, g, h = e_new, g_new, h_new
        else:
            e, g, h = model.egh(x, u, p)
    return SimResult(st, e, gnorm, it, False, h)


def worst_constraint(model: EnergyModel, state: State, u: np.ndarray) -> tuple[str, float]:
    """Label and size [m] of the most violated constraint row at ``state``."""
    c = np.abs(model.residuals(state.x, np.asarray(u, float), model.params(state.r_ref)))
    k = int(np.argmax(c))
    return model.labels[k], float(c[k])


def simulate(
    model: EnergyModel,
    u: np.ndarray,
    state: State | None = None,
    *,
    tol: float = ASSEMBLY_TOL,
    gtol: float = 1e-13,
    max_iter: int = 60,
) -> SimResult:
    """Forward kinematics x*(u), warm-started from ``state`` (default: the reference configuration).

    Raises :class:`ConvergenceError` if Newton does not converge (uses up ``max_iter`` iterations, or its line search
    stalls before), and :class:`AssemblyError` if it converges with a residual energy above ``tol`` [m²]: the agents
    are commanded to poses the chain cannot reach.
    """
    u = np.asarray(u, dtype=float)
    if u.shape != (model.nu,) or not np.all(np.isfinite(u)):
        raise AssemblyError(f"controls must be {model.nu} finite numbers ({', '.join(model.system.control_names)})")
    res = newton(model, state if state is not None else reference_state(model), u, gtol=gtol, max_iter=max_iter)
    if not res.converged and res.iterations >= max_iter:
        raise ConvergenceError(
            f"{model.system.name}: Newton did not converge in {max_iter} iterations (‖∇E‖∞ = {res.grad_norm:.3g} m, "
            f"residual energy {res.energy:.3g} m²); allow more iterations, warm-start closer, or check for a "
            f"singular configuration"
        )
    if not res.converged:  # the line search found no descent before the iteration limit
        raise ConvergenceError(
            f"{model.system.name}: Newton stalled after {res.iterations} iterations: the line search found no "
            f"descent (‖∇E‖∞ = {res.grad_norm:.3g} m, residual energy {res.energy:.3g} m²); the state is not a "
            f"minimiser of the constraint energy. Warm-start closer or check for a singular configuration"
        )
    if res.energy > tol:
        name, size = worst_constraint(model, res.state, u)
        raise AssemblyError(
            f"{model.system.name}: the chain cannot assemble for these controls: residual constraint energy "
            f"{res.energy:.3g} m² > {tol:.3g} m²; largest violation {size:.3g} m at {name!r}. Move the agents back "
            f"inside the workspace (or use tmr.ccma.control.solve_ik to find consistent controls)",
            residual=res.energy,
            worst=name,
        )
    return res


def end_effector_pose(model: EnergyModel, state: State) -> tuple[np.ndarray, np.ndarray]:
    """End-effector point [m] and rotation matrix in the world frame."""
    return model.ee(state.x, model.params(state.r_ref))


def agent_poses(model: EnergyModel, state: State) -> np.ndarray:
    """(n_agents, 3) array of agent x [m], y [m], yaw [rad] in the world frame."""
    pos, rot = model.world_poses(state.x, state.r_ref)
    idx = [a.body for a in model.system.agents]
    return np.column_stack([pos[idx, 0], pos[idx, 1], np.arctan2(rot[idx, 1, 0], rot[idx, 0, 0])])
