"""Tests of tmr.ccma.control: the sensitivity gradient (Kumar 2019 eq. 6–9) against finite differences, IK solutions
checked by independent forward simulation, and actuation / agent-count changes made in the description only."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from tmr.ccma.bodies import reanchor, rot_axis, rot_z, rotation_angle
from tmr.ccma.control import Target, gauss_newton_hessian, objective, reached, sensitivity, solve_ik, track
from tmr.ccma.energy import EnergyModel
from tmr.ccma.paths import make_path
from tmr.ccma.sim import end_effector_pose, newton, reference_state, simulate
from tmr.ccma.system import build_system, load_description, load_system

from .conftest import add_fourth_leg


@pytest.fixture(scope="module")
def models() -> dict[str, EnergyModel]:
    return {n: EnergyModel(load_system(n)) for n in ("4dof-reduced", "4dof-complete", "6dof-reduced")}


def _fd_objective(model, state, u, target, h=1e-4):
    """Central differences of O(u); Newton is converged to ‖∇E‖∞ ≤ 1e-15 m so the evaluation noise stays far below
    the O(h²) truncation error."""

    def o(v):
        return objective(model, state, v, target, gtol=1e-15)[0]

    return np.array([(o(u + h * e) - o(u - h * e)) / (2 * h) for e in np.eye(u.size)])


@pytest.mark.parametrize("name", ["4dof-reduced", "4dof-complete", "6dof-reduced"])
def test_sensitivity_gradient_matches_finite_differences(models, name):
    """dO/du by the adjoint sensitivity vs central differences of O(u) (each a full Newton solve). The command is
    off the assemblable set for the 4-dof systems, so the residual-energy term (eq. 8–9) is exercised."""
    m = models[name]
    rng = np.random.default_rng(2)
    st = reference_state(m)
    u = m.system.u0 + 0.004 * rng.normal(size=m.nu)
    target = Target(np.array([0.01, -0.005, 0.49]), rot_z(0.03))
    o, grad, sim, f = objective(m, st, u, target, gtol=1e-15)
    assert sim.converged and o == pytest.approx(f + sim.energy)
    if name != "6dof-reduced":
        assert sim.energy > 1e-9  # really off the assemblable set
    fd = _fd_objective(m, st, u, target)
    assert np.max(np.abs(grad - fd)) < 1e-5 * np.max(np.abs(fd))


def test_state_sensitivity_matches_finite_differences(models):
    m = models["6dof-reduced"]
    u = m.system.u0 + 0.003
    st = newton(m, reference_state(m), u).state
    reanchor(st.x, st.r_ref)  # w = 0: newton() re-anchors first, so its results share these coordinates
    dxdu = sensitivity(m, st, u)
    h = 1e-6
    for k in range(m.nu):
        e = np.eye(m.nu)[k]
        xp = newton(m, st, u + h * e).state
        xm = newton(m, st, u - h * e).state
        # same reference rotations (no re-anchoring for tiny steps), so states compare directly
        np.testing.assert_allclose(xp.r_ref, st.r_ref, atol=1e-15)
        np.testing.assert_allclose(dxdu[:, k], (xp.x - xm.x) / (2 * h), atol=1e-6 * np.abs(dxdu).max())


@pytest.mark.parametrize("name", ["4dof-reduced", "4dof-complete", "6dof-reduced"])
def test_ik_controls_reach_the_target_in_an_independent_forward_simulation(models, name):
    m = models[name]
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    tilt = rot_axis(np.array([1.0, 0.0, 0.0]), 0.02) if name == "6dof-reduced" else np.eye(3)
    target = Target(p0 + [0.004, -0.003, 0.002], rot_z(0.02) @ r0 @ tilt)
    res = solve_ik(m, st, m.system.u0, target)
    assert res.objective < 1e-16 and res.residual < 1e-16
    # forward simulation of the returned controls from the reference configuration
    sim = simulate(m, res.u, reference_state(m), tol=1e-16)
    p, r = end_effector_pose(m, sim.state)
    assert np.linalg.norm(p - target.position) < 1e-8
    assert rotation_angle(r, target.rotation) < 1e-7
    assert res.history.shape[1] == 2 and np.all(np.diff(res.history[:, 0]) >= 0)
    assert res.history[-1, 1] < 1e-3 * res.history[0, 1]


def test_gauss_newton_hessian_matches_the_hessian_of_the_objective_at_a_solution(models):
    """At a solution (f = 0) the Gauss–Newton tracking term plus the exact residual-energy term is the exact ∇²O;
    compare with central differences of the sensitivity gradient."""
    m = models["4dof-reduced"]
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    target = Target(p0 + [0.003, 0.001, -0.002], rot_z(0.01) @ r0)
    res = solve_ik(m, st, m.system.u0, target, gtol=1e-12)
    o, grad, sim, _ = objective(m, res.state, res.u, target, gtol=1e-15)
    b = gauss_newton_hessian(m, sim, res.u, target)
    h = 1e-5
    fd = np.column_stack(
        [
            (
                objective(m, res.state, res.u + h * e, target, gtol=1e-15)[1]
                - objective(m, res.state, res.u - h * e, target, gtol=1e-15)[1]
            )
            / (2 * h)
            for e in np.eye(m.nu)
        ]
    )
    np.testing.assert_allclose(b, fd, atol=1e-5 * np.abs(fd).max())
    assert np.linalg.eigvalsh(b)[0] > 1e-3  # the residual energy makes O strictly convex in the 2 extra controls


def test_cold_start_with_gauss_newton_needs_few_iterations():
    desc = load_description("4dof-reduced")  # the symmetric chain with complete actuation (Kumar 2019 Fig. 3(a)/(b))
    for a in desc["agents"]:
        a["actuation"] = "complete"
    m = EnergyModel(build_system(desc))
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    target = Target(p0 + [0.001, 0.001, 0.001], rot_z(0.01) @ r0)
    gn = solve_ik(m, st, m.system.u0, target)
    ident = solve_ik(m, st, m.system.u0, target, hess_inv0=np.eye(m.nu))
    assert gn.objective < 1e-16 and ident.objective < 1e-16
    assert gn.iterations <= 8 < ident.iterations


def test_actuation_swap_and_extra_agent_need_no_code_change():
    base = load_description("4dof-reduced")
    complete = copy.deepcopy(base)
    for a in complete["agents"]:
        a["actuation"] = "complete"
    four = add_fourth_leg(base)
    for desc, nu in ((complete, 9), (four, 8)):
        m = EnergyModel(build_system(desc))
        assert m.nu == nu
        st = reference_state(m)
        p0, r0 = end_effector_pose(m, st)
        path = make_path("combined", p0, r0, m.system.tilt_axes, steps=3)
        res = track(m, path.positions, path.rotations, state=st)
        assert reached(res).all(), (desc["agents"][-1], res.position_error, res.residual)
        assert res.u.shape == (3, nu)


def test_unreachable_target_is_reported_not_faked(models):
    m = models["4dof-reduced"]
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    # the arms (0.447 m) cannot lift the platform above z1 + 0.447 = 0.747 m
    res = track(m, np.array([p0 + [0, 0, 0.3]]), r0[None])
    assert not reached(res).any()
    assert res.position_error[0] > 1e-3


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        ({"position": [np.nan, 0.0, 0.5]}, "target position must be 3 finite numbers"),
        ({"position": [0.0, 0.5]}, "target position must be 3 finite numbers"),
        ({"rotation": np.full((3, 3), np.nan)}, "target rotation must be a finite 3×3 matrix"),
        ({"rotation": 2.0 * np.eye(3)}, "not a rotation matrix"),
        ({"u0": np.full(6, np.inf)}, "u0 must be 6 finite numbers"),
        ({"u0": np.zeros(5)}, "u0 must be 6 finite numbers"),
    ],
)
def test_solve_ik_rejects_bad_inputs(models, bad, match):
    from tmr.ccma.errors import CcmaError

    m = models["4dof-reduced"]
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    target = Target(bad.get("position", p0), bad.get("rotation", r0))
    with pytest.raises(CcmaError, match=match):
        solve_ik(m, st, bad.get("u0", m.system.u0), target)


def _fd_task_jacobian(model, state, u, directions, h=1e-5):
    """(12, k) central differences of r = (p_EE, ℓ_R/√2 · R_EE) along control directions (m, k), through independent
    forward simulations."""

    def r(v):
        st = simulate(model, v, state, tol=1e-10).state
        p, rot = end_effector_pose(model, st)
        return np.concatenate([p, model.system.rotation_scale / np.sqrt(2.0) * rot.ravel()])

    return np.column_stack([(r(u + h * e) - r(u - h * e)) / (2 * h) for e in directions.T])


def _fd_assemblable_directions(model, state, u, d, h=1e-4):
    """The d directions of least curvature of the residual energy E(x*(u), u), from central second differences of
    independent forward simulations (no CasADi second derivatives)."""

    def e(v):
        return simulate(model, v, state, tol=1.0).energy

    m = u.size
    hess = np.zeros((m, m))
    eye = np.eye(m)
    for i in range(m):
        for j in range(m):
            a, b = h * eye[i], h * eye[j]
            hess[i, j] = (e(u + a + b) - e(u + a - b) - e(u - a + b) + e(u - a - b)) / (4 * h * h)
    return np.linalg.eigh(0.5 * (hess + hess.T))[1][:, :d]


@pytest.mark.parametrize(("name", "dz"), [("4dof-reduced", 0.0), ("6dof-reduced", 0.0), ("4dof-reduced", -0.18)])
def test_conditioning_matches_finite_differences_of_the_forward_kinematics(models, name, dz):
    from tmr.ccma.control import conditioning, task_dof

    m = models[name]
    st = reference_state(m)
    u = m.system.u0.copy()
    if dz:
        p0, r0 = end_effector_pose(m, st)
        res = track(m, p0 + np.outer(np.linspace(0, dz, 10)[1:], [0, 0, 1]), np.tile(r0, (9, 1, 1)), keep_states=True)
        st, u = res.states[-1], res.u[-1]
    sim = newton(m, st, u)
    low, cond = conditioning(m, sim.state, sim.hessian, u)
    d = task_dof(m)
    assert d == (4 if name.startswith("4dof") else 6)
    t = _fd_assemblable_directions(m, sim.state, u, d)
    sv = np.linalg.svd(_fd_task_jacobian(m, sim.state, u, t), compute_uv=False)
    assert low == pytest.approx(sv[d - 1], rel=1e-4)
    assert cond == pytest.approx(sv[0] / sv[d - 1], rel=1e-4)


def test_missed_step_near_a_fold_is_solved_in_sub_steps(models):
    """Platform lowered towards the elbow height (arms horizontal, 0.3 m): at 5 mm above it one 3 mm step overshoots
    the cusp of O(u) when solved directly (max_substeps=1: missed), and is reached in two sub-steps."""
    m = models["4dof-reduced"]
    p0, r0 = end_effector_pose(m, reference_state(m))
    zs = np.concatenate([np.linspace(0.5, 0.32, 25), [0.31, 0.305]])
    pos = np.column_stack([np.zeros_like(zs), np.zeros_like(zs), zs])
    rots = np.tile(r0, (len(zs), 1, 1))
    lead = track(m, pos, rots, keep_states=True)
    assert reached(lead).all() and lead.condition[-1] > 100  # near-singular: the next step is damped
    last = (np.array([[0.0, 0.0, 0.302]]), r0[None])
    direct = track(m, *last, state=lead.states[-1], u0=lead.u[-1], max_substeps=1)
    assert not reached(direct).any() and direct.substeps[0] == 1
    sub = track(m, *last, state=lead.states[-1], u0=lead.u[-1])
    assert reached(sub).all() and sub.substeps[0] == 2
