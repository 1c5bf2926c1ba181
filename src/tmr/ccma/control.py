"""Kinematic control (inverse kinematics) of a CCMA by sensitivity analysis and BFGS (Kumar 2019 §III-B, §III-C).

For a target end-effector pose (p_t, R_t) find the controls u minimising (Kumar 2019 eq. 7)

    O(u) = f(x*(u)) + E(x*(u), u),   f(x) = ‖p_EE(x) − p_t‖² + ℓ_R² · ½‖R_EE(x) − R_t‖_F²   [m²]

where x*(u) is the forward simulation (:func:`tmr.ccma.sim.newton`) and E the residual constraint energy, which keeps
the controls on the assemblable set. At x*(u) the energy gradient vanishes, ∇ₓE(x*(u), u) = 0 (eq. 5);
differentiating this identity gives the sensitivity (eq. 6)

    dx*/du = −(∇ₓ²E)⁻¹ ∂²E/∂x∂u,

so (eq. 4, 8, 9) dO/du = ∇ₓf · dx*/du + ∂E/∂u, because dE/du = ∂E/∂u + ∇ₓE · dx*/du and ∇ₓE = 0.
:func:`objective` evaluates it in adjoint form, λ = (∇ₓ²E)⁻¹ ∇ₓf, dO/du = ∂E/∂u − (∂²E/∂x∂u)ᵀ λ (one solve instead
of m); :func:`sensitivity` returns the full dx*/du. The controls are updated by SciPy's BFGS (the exact Hessian of O
would need third derivatives of E), started from the inverse of the Gauss–Newton estimate of ∇²O
(:func:`gauss_newton_hessian`) and warm-started along a path with the previous step's controls and state.
:func:`track` follows a sequence of small target increments (e.g. 1 mm / 0.01 rad, as in Kumar 2019 §III-D).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import OptimizeResult, minimize

from tmr.ccma.bodies import rotation_angle
from tmr.ccma.energy import EnergyModel
from tmr.ccma.errors import CcmaError, ConvergenceError
from tmr.ccma.sim import ASSEMBLY_TOL, SimResult, State, agent_poses, end_effector_pose, newton

__all__ = [
    "CONDITION_LIMIT",
    "IKResult",
    "Objective",
    "Target",
    "gauss_newton_hessian",
    "reached",
    "TrackResult",
    "conditioning",
    "objective",
    "sensitivity",
    "solve_ik",
    "track",
]


#: Condition number of the end-effector sensitivity above which a configuration is called near-singular and the next
#: IK step is damped (see :func:`conditioning`).
CONDITION_LIMIT = 100.0


class Target(NamedTuple):
    """End-effector target: position [m] and rotation matrix."""

    position: np.ndarray
    rotation: np.ndarray


def _check_ik_inputs(model: EnergyModel, state: State, u0: np.ndarray, target: Target) -> tuple[np.ndarray, Target]:
    """``u0`` and ``target`` as float arrays, or :class:`CcmaError` naming the bad input (shape, NaN/inf, not a
    rotation)."""
    try:
        u = np.asarray(u0, dtype=float)
        pos = np.asarray(target.position, dtype=float)
        rot = np.asarray(target.rotation, dtype=float)
    except (TypeError, ValueError) as exc:
        raise CcmaError(f"solve_ik: controls and target must be numeric arrays: {exc}") from exc
    if u.shape != (model.nu,) or not np.all(np.isfinite(u)):
        raise CcmaError(
            f"solve_ik: u0 must be {model.nu} finite numbers ({', '.join(model.system.control_names)}), got {u0!r}"
        )
    if pos.shape != (3,) or not np.all(np.isfinite(pos)):
        raise CcmaError(f"solve_ik: target position must be 3 finite numbers [m], got {target.position!r}")
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
        raise CcmaError(f"solve_ik: target rotation must be a finite 3×3 matrix, got shape {rot.shape}")
    if np.max(np.abs(rot.T @ rot - np.eye(3))) > 1e-6 or np.linalg.det(rot) < 0:
        raise CcmaError("solve_ik: target rotation is not a rotation matrix (RᵀR ≠ I or det R < 0)")
    x = np.asarray(state.x)
    if x.shape != (model.nx,) or not np.all(np.isfinite(x)):
        raise CcmaError(f"solve_ik: state.x must be {model.nx} finite numbers, got shape {x.shape}")
    return u, Target(pos, rot)


def _solve_h(h: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    try:
        return cho_solve(cho_factor(h, check_finite=False), rhs, check_finite=False)
    except np.linalg.LinAlgError:  # indefinite at a compromise with large residual: least squares
        return np.linalg.lstsq(h, rhs, rcond=None)[0]


def _positive_definite(h: np.ndarray | None) -> np.ndarray | None:
    """Symmetric positive-definite copy of a BFGS inverse-Hessian estimate (eigenvalues clipped to ≥ 1e-12 × the
    largest), or None if there is none; rounding in BFGS updates can leave tiny negative eigenvalues."""
    if h is None:
        return None
    h = 0.5 * (h + h.T)
    lam, v = np.linalg.eigh(h)
    if not np.all(np.isfinite(lam)) or lam[-1] <= 0:
        return None
    h = (v * np.maximum(lam, 1e-12 * lam[-1])) @ v.T
    return 0.5 * (h + h.T)  # exactly symmetric: SciPy checks with issymmetric


def sensitivity(model: EnergyModel, state: State, u: np.ndarray) -> np.ndarray:
    """dx*/du = −(∇ₓ²E)⁻¹ ∂²E/∂x∂u at a converged state (Kumar 2019 eq. 6); shape (6 n, m), in the coordinates of
    ``state`` (positions [m], Cayley vectors about ``state.r_ref``)."""
    p = model.params(state.r_ref)
    u = np.asarray(u, float)
    _, _, h = model.egh(state.x, u, p)
    _, _, _, exu = model.ik(state.x, u, p, np.zeros(12))
    return -_solve_h(h, exu)


def task_dof(model: EnergyModel) -> int:
    """Number of end-effector coordinates the system controls: x, y, z, yaw and one per tilt axis (at most 6 and at
    most the number of controls)."""
    return min(6, 4 + len(model.system.tilt_axes), model.nu)


def conditioning(model: EnergyModel, state: State, hessian: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """Smallest singular value σ_d [m per unit control] and condition number σ_1/σ_d of the end-effector sensitivity
    restricted to the assemblable control directions, at a converged state (Kumar 2019 eq. 6 for dx*/du).

    J = ∂r/∂x · dx*/du, where r stacks the end-effector point [m] and ℓ_R/√2 · R_EE (a rotation rate ω changes it by
    ℓ_R |ω|), is (12, m) in metres. An over-constrained system (more controls than end-effector dof) also has control
    directions that squeeze the chain — the residual energy rises along them and the end-effector only moves through
    the compromise. So J is restricted to the d = :func:`task_dof` directions T of least curvature of the residual
    energy, d²E(x*(u), u)/du² = ∂²E/∂u² − (∂²E/∂x∂u)ᵀ (∇ₓ²E)⁻¹ ∂²E/∂x∂u (zero along the assemblable set), and the
    singular values of J T are the rates at which the agents drive the end-effector. Near a singular configuration
    the condition number grows without bound: at a fold (a leg's link passing the horizontal) σ_1 → ∞, the
    end-effector's height moves without the agents moving; at a stretched leg σ_d → 0. ``hessian`` is ∇ₓ²E at
    ``state``.
    """
    return _condition(_sensitivity_parts(model, state, hessian, u), task_dof(model))


class _Parts(NamedTuple):
    """At a converged state: ju = ∂r/∂x · dx*/du (12, m) [m], the residual-energy curvature d²E/du² (m, m) [m²]."""

    ju: np.ndarray
    curvature: np.ndarray


def _sensitivity_parts(model: EnergyModel, state: State, hessian: np.ndarray, u: np.ndarray) -> _Parts:
    """ju and d²E(x*(u), u)/du² = ∂²E/∂u² − (∂²E/∂x∂u)ᵀ (∇ₓ²E)⁻¹ ∂²E/∂x∂u; neither depends on the target (∂r/∂x
    does not), so one evaluation serves the conditioning of a reached state and the Gauss–Newton start of the next
    step."""
    p = model.params(state.r_ref)
    u = np.asarray(u, float)
    t = model.target_vector(np.zeros(3), np.eye(3))
    _, _, _, exu = model.ik(state.x, u, p, t)
    jr, euu = model.gn(state.x, u, p, t)
    dxdu = -_solve_h(hessian, exu)
    curvature = euu + exu.T @ dxdu
    return _Parts(jr @ dxdu, 0.5 * (curvature + curvature.T))


def _condition(parts: _Parts, d: int) -> tuple[float, float]:
    """(σ_d, σ_1/σ_d) of ju on the d least-curvature control directions (see :func:`conditioning`)."""
    _, vec = np.linalg.eigh(parts.curvature)
    sv = np.linalg.svd(parts.ju @ vec[:, :d], compute_uv=False)
    low = float(sv[d - 1])
    return low, float(sv[0] / low) if low > 0 else float("inf")


def gauss_newton_hessian(model: EnergyModel, sim: SimResult, u: np.ndarray, target: Target) -> np.ndarray:
    """Estimate of ∇²O(u) [m² per unit control²] at a converged forward simulation.

    Residual-energy part, exact by the implicit function theorem: d²E(x*(u), u)/du² = ∂²E/∂u² − (∂²E/∂x∂u)ᵀ
    (∇ₓ²E)⁻¹ ∂²E/∂x∂u. Tracking part, Gauss–Newton: 2 (∂r/∂x · dx*/du)ᵀ (∂r/∂x · dx*/du) with f = ‖r‖² (the term
    with d²x*/du², which needs third derivatives of E, is dropped; it vanishes with f at the solution).
    """
    return _gn_from(_sensitivity_parts(model, sim.state, sim.hessian, u))


def _gn_from(parts: _Parts) -> np.ndarray:
    b = 2.0 * parts.ju.T @ parts.ju + parts.curvature
    return 0.5 * (b + b.T)


def objective(
    model: EnergyModel, state: State, u: np.ndarray, target: Target, **newton_kw: float
) -> tuple[float, np.ndarray, SimResult, float]:
    """O(u) [m²], dO/du (Kumar 2019 eq. 7–9), the forward simulation warm-started from ``state`` and f [m²]."""
    u = np.asarray(u, dtype=float)
    sim = newton(model, state, u, **newton_kw)  # type: ignore[arg-type]
    p = model.params(sim.state.r_ref)
    t = model.target_vector(target.position, target.rotation)
    f, fx, eu, exu = model.ik(sim.state.x, u, p, t)
    lam = _solve_h(sim.hessian, fx)
    grad = eu - exu.T @ lam
    return f + sim.energy, grad, sim, f


@dataclass
class Objective:
    """O(u) and dO/du as a callable for :func:`scipy.optimize.minimize`, with warm starts and bookkeeping.

    Every evaluation warm-starts Newton from the state of the best point evaluated so far (the BFGS iterate), so a
    rejected line-search trial never moves the warm start. An evaluation whose forward simulation did not converge
    (``SimResult.converged`` false: iteration limit or stalled line search) is returned to BFGS but never becomes the
    best point or the warm start, since its sensitivity gradient assumes ∇ₓE = 0; ``unconverged`` counts them.
    """

    model: EnergyModel
    state: State
    target: Target
    gtol_newton: float = 1e-13
    evaluations: int = 0
    newton_iterations: int = 0
    unconverged: int = 0
    best: float = float("inf")
    best_sim: SimResult | None = None
    best_f: float = float("nan")
    best_u: np.ndarray | None = None
    history: list[tuple[float, float]] = field(default_factory=list)
    t0: float = field(default_factory=time.perf_counter)

    last: tuple[np.ndarray, float, np.ndarray] | None = None

    def __call__(self, u: np.ndarray) -> tuple[float, np.ndarray]:
        if self.last is not None and np.array_equal(self.last[0], u):  # SciPy re-evaluates the start point
            return self.last[1], self.last[2].copy()
        o, g, sim, f = objective(self.model, self.state, u, self.target, gtol=self.gtol_newton)
        self.last = (np.array(u, dtype=float), o, g.copy())
        self.evaluations += 1
        self.newton_iterations += sim.iterations
        if not sim.converged:
            self.unconverged += 1
        elif o < self.best:  # the controls returned are the best evaluated, with their own state
            self.best, self.best_sim, self.best_f, self.best_u = o, sim, f, np.array(u, dtype=float)
            self.state = sim.state
        return o, g

    def callback(self, intermediate_result: OptimizeResult) -> None:
        self.history.append((time.perf_counter() - self.t0, float(intermediate_result.fun)))


class IKResult(NamedTuple):
    """One inverse-kinematics solve. ``objective`` = O [m²], ``tracking`` = f [m²], ``residual`` = E [m²];
    ``history`` (k, 2): wall time since the start [s] and O after each BFGS iteration (Kumar 2019 Fig. 5)."""

    u: np.ndarray
    state: State
    objective: float
    tracking: float
    residual: float
    iterations: int
    evaluations: int
    newton_iterations: int
    hess_inv: np.ndarray
    history: np.ndarray
    time: float
    message: str
    hessian: np.ndarray | None = None
    start_condition: tuple[float, float] | None = None
    damped: bool = False


def solve_ik(
    model: EnergyModel,
    state: State,
    u0: np.ndarray,
    target: Target,
    *,
    hess_inv0: np.ndarray | None = None,
    gtol: float = 1e-9,
    max_iter: int = 200,
    damping: float = 0.0,
    condition_limit: float | None = None,
) -> IKResult:
    """Controls reaching ``target`` from the warm start (``state``, ``u0``) by BFGS on O(u) (Kumar 2019 §III-B/C).

    ``gtol`` [m] is the BFGS tolerance on ‖dO/du‖∞; ``hess_inv0`` an initial inverse-Hessian estimate (default: the
    inverse of :func:`gauss_newton_hessian` at ``u0``; or pass the previous step's ``hess_inv`` along a path).
    ``damping`` λ [m²] ≥ 0 is added to the diagonal of the Gauss–Newton estimate before it is inverted (damped least
    squares: the first BFGS step shrinks in the directions the end-effector barely moves; :func:`track` sets it near
    singular configurations). It changes only the start of BFGS, not the minimiser. With ``condition_limit`` and the
    Gauss–Newton start, the conditioning of the start configuration (:func:`conditioning`, returned as
    ``start_condition``) decides the damping: above the limit, λ = 2 (σ_1 / ``condition_limit``)² (``damped``).
    Raises :class:`CcmaError` if ``u0`` is not ``model.nu`` finite numbers, the target position not 3 finite numbers
    or the target rotation not a rotation matrix.
    """
    u0, target = _check_ik_inputs(model, state, u0, target)
    obj = Objective(model, state, target)
    o0, _ = obj(u0)
    obj.history.append((time.perf_counter() - obj.t0, o0))
    if obj.best_sim is None:  # Newton did not converge at u0 (or O(u0) is not finite): nothing to start from
        raise ConvergenceError(
            f"{model.system.name}: the forward simulation at u0 did not converge (objective {o0:.3g} m²); start "
            f"from controls close to assemblable ones (e.g. the previous solution) and a state close to them"
        )
    start = None
    if hess_inv0 is None:
        parts = _sensitivity_parts(model, obj.best_sim.state, obj.best_sim.hessian, u0)
        b = _gn_from(parts)
        if condition_limit is not None:
            start = _condition(parts, task_dof(model))
            if start[1] > condition_limit:
                damping = max(damping, 2.0 * (start[0] * start[1] / condition_limit) ** 2)
        if damping > 0:
            b = b + damping * np.eye(b.shape[0])
        hess_inv0 = _positive_definite(np.linalg.inv(_positive_definite(b)))
    else:
        hess_inv0 = _positive_definite(hess_inv0)
    res = minimize(
        obj,
        u0,
        jac=True,
        method="BFGS",
        callback=obj.callback,
        options={"gtol": gtol, "maxiter": max_iter, "hess_inv0": hess_inv0},
    )
    elapsed = time.perf_counter() - obj.t0
    sim, u = obj.best_sim, obj.best_u
    assert sim is not None and u is not None
    return IKResult(
        u=u,
        state=sim.state,
        objective=obj.best,
        tracking=obj.best_f,
        residual=sim.energy,
        iterations=int(res.nit),
        evaluations=obj.evaluations,
        newton_iterations=obj.newton_iterations,
        hess_inv=np.asarray(res.hess_inv),
        history=np.array(obj.history),
        time=elapsed,
        message=str(res.message),
        hessian=sim.hessian,
        start_condition=start,
        damped=damping > 0,
    )


class TrackResult(NamedTuple):
    """A tracked end-effector path (K targets). Arrays: ``u`` (K, m) controls; ``agents`` (K, n_agents, 3) agent
    x, y [m], yaw [rad]; ``ee_position`` (K, 3) [m], ``ee_rotation`` (K, 3, 3) reached; ``position_error`` [m] and
    ``rotation_error`` [rad] (K,); ``residual`` (K,) [m²]; ``iterations``, ``evaluations``, ``newton_iterations``
    (K,) per step; ``step_time`` (K,) [s]; ``histories`` per-step BFGS convergence (time [s], O [m²]); ``condition``
    (K,) condition number of the end-effector sensitivity at the reached state and ``sigma_min`` (K,) its smallest
    task singular value [m] (:func:`conditioning`); ``damped`` (K,) whether the step was solved with damping because
    the previous state was near-singular (condition > ``condition_limit``); ``substeps`` (K,) how many sub-steps
    the target was finally solved in (1: directly; see :func:`track`)."""

    u: np.ndarray
    agents: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    residual: np.ndarray
    iterations: np.ndarray
    evaluations: np.ndarray
    newton_iterations: np.ndarray
    step_time: np.ndarray
    histories: list[np.ndarray]
    states: list[State]
    condition: np.ndarray
    sigma_min: np.ndarray
    damped: np.ndarray
    substeps: np.ndarray


def track(
    model: EnergyModel,
    positions: np.ndarray,
    rotations: np.ndarray,
    *,
    state: State | None = None,
    u0: np.ndarray | None = None,
    gtol: float = 1e-9,
    keep_states: bool = False,
    init: str = "gauss-newton",
    condition_limit: float = CONDITION_LIMIT,
    max_substeps: int = 16,
    progress: bool = False,
) -> TrackResult:
    """Follow the targets (positions (K, 3) [m], rotations (K, 3, 3)) one IK solve per target, warm-starting each
    from the previous solution's controls and state. BFGS starts every step from the Gauss–Newton estimate
    (``init="gauss-newton"``, :func:`gauss_newton_hessian`) or, after the first step, from the previous step's
    inverse-Hessian estimate (``init="warm"``).

    After every step the conditioning of the end-effector sensitivity is recorded (:func:`conditioning`, computed
    by the next step's Gauss–Newton start, which needs the same quantities); when it exceeds ``condition_limit`` the
    next step is damped: λ = 2 (σ_1 / ``condition_limit``)² [m²] is added to the Gauss–Newton estimate that starts
    BFGS (:func:`solve_ik`), which bounds that estimate's condition number (``init="warm"``: recorded, no damping).

    A target that is missed (position error > 1e-5 m, rotation error > 1e-4 rad or residual energy > the assembly
    tolerance) is solved again from the previous solution in 2, 4, … ``max_substeps`` equal sub-steps (positions
    linear, rotations by spherical interpolation) until one division reaches it; otherwise the direct solve is kept
    (and the following targets are not subdivided until one is reached again).
    Near a singular configuration the objective has a cusp (e.g. a leg's link passing the horizontal: the height of
    the end-effector grows like the square root of an agent's travel), where one BFGS line search can overshoot to the
    far side; smaller increments stay on the branch (Kumar 2019 §III-D recommends small steps for the same reason).
    Iterations and evaluations of a subdivided target add up all its solves; ``step_time`` is the wall time of the
    whole step (every solve and the conditioning). ``progress``: a tqdm bar of the steps on stderr, shown once the
    run has taken 2 s."""
    if init not in ("gauss-newton", "warm"):
        raise ValueError(f"init must be 'gauss-newton' or 'warm', got {init!r}")
    from tmr.ccma.sim import reference_state

    st = state if state is not None else reference_state(model)
    u = np.asarray(u0 if u0 is not None else model.system.u0, float).copy()
    k = len(positions)
    na = len(model.system.agents)
    out_u = np.zeros((k, model.nu))
    agents = np.zeros((k, na, 3))
    pe = np.zeros((k, 3))
    re = np.zeros((k, 3, 3))
    perr, rerr, resid = np.zeros(k), np.zeros(k), np.zeros(k)
    its, evals, nits = np.zeros(k, int), np.zeros(k, int), np.zeros(k, int)
    times = np.zeros(k)
    hist: list[np.ndarray] = []
    states: list[State] = []
    cond, smin, damped, subs = np.zeros(k), np.zeros(k), np.zeros(k, bool), np.ones(k, int)
    hinv = None
    lim = condition_limit if init == "gauss-newton" else None
    prev = Target(*end_effector_pose(model, st))
    ok_prev = True
    last: IKResult | None = None
    from tqdm import tqdm

    bar = tqdm(total=k, desc="ccma steps", unit="step", leave=False, delay=2.0, disable=not progress)
    for i in range(k):
        target = Target(positions[i], rotations[i])
        t_step = time.perf_counter()
        r = solve_ik(model, st, u, target, hess_inv0=hinv, gtol=gtol, condition_limit=lim)
        damped[i] = r.damped
        if i > 0:  # the conditioning of the previous step's state, found by this step's Gauss–Newton start
            assert last is not None and last.hessian is not None
            start = r.start_condition or conditioning(model, last.state, last.hessian, last.u)
            smin[i - 1], cond[i - 1] = start
        spent = (r.iterations, r.evaluations, r.newton_iterations)
        n = 2 if ok_prev else max_substeps + 1
        while not _step_reached(model, r, target) and n <= max_substeps:
            sub = _subdivided(model, st, u, prev, target, n, gtol, lim)
            spent = tuple(a + b for a, b in zip(spent, sub[1][:3], strict=True))  # type: ignore[assignment]
            if _step_reached(model, sub[0], target):
                r, subs[i] = sub[0], n
                break
            n *= 2
        prev, ok_prev, last = target, _step_reached(model, r, target), r
        st, u = r.state, r.u
        hinv = r.hess_inv if init == "warm" else None
        if i == k - 1:
            assert r.hessian is not None
            smin[i], cond[i] = conditioning(model, st, r.hessian, u)
        out_u[i] = u
        agents[i] = agent_poses(model, st)
        pe[i], re[i] = end_effector_pose(model, st)
        perr[i] = np.linalg.norm(pe[i] - positions[i])
        rerr[i] = rotation_angle(re[i], rotations[i])
        resid[i] = r.residual
        its[i], evals[i], nits[i] = spent
        times[i] = time.perf_counter() - t_step  # IK solve(s) + the conditioning: the whole cost of the step
        hist.append(r.history)
        if keep_states:
            states.append(st.copy())
        bar.update()
    bar.close()
    return TrackResult(
        out_u, agents, pe, re, perr, rerr, resid, its, evals, nits, times, hist, states, cond, smin, damped, subs
    )


def _step_reached(model: EnergyModel, r: IKResult, target: Target) -> bool:
    """The tolerances of :func:`reached` for one IK result."""
    p, rot = end_effector_pose(model, r.state)
    return bool(
        np.linalg.norm(p - target.position) <= 1e-5
        and rotation_angle(rot, target.rotation) <= 1e-4
        and r.residual <= ASSEMBLY_TOL
    )


def _subdivided(
    model: EnergyModel, st: State, u: np.ndarray, start: Target, target: Target, n: int, gtol: float, lim: float | None
) -> tuple[IKResult, tuple[int, int, int, float]]:
    """Solve ``target`` from (``st``, ``u``) in ``n`` equal sub-steps from ``start``; the last result and the summed
    iterations, evaluations, Newton iterations and time [s]."""
    from scipy.spatial.transform import Rotation, Slerp

    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([start.rotation, target.rotation])))
    total = (0, 0, 0, 0.0)
    r = None
    for s in np.arange(1, n + 1) / n:
        sub = Target(start.position + s * (target.position - start.position), slerp([s]).as_matrix()[0])
        r = solve_ik(model, st, u, sub, gtol=gtol, condition_limit=lim)
        st, u = r.state, r.u
        total = (total[0] + r.iterations, total[1] + r.evaluations, total[2] + r.newton_iterations, total[3] + r.time)
    assert r is not None
    return r, total


def reached(
    result: TrackResult, position_tol: float = 1e-5, rotation_tol: float = 1e-4, residual_tol: float = ASSEMBLY_TOL
) -> np.ndarray:
    """Boolean (K,): the step reached its target within the tolerances [m], [rad] with residual energy ≤ tol [m²]."""
    return (
        (result.position_error <= position_tol)
        & (result.rotation_error <= rotation_tol)
        & (result.residual <= residual_tol)
    )
