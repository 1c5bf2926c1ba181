"""Tests of tmr.ccma.sim: Newton forward kinematics against a closed form, an independent least-squares solver,
rigid rotations through re-anchoring, and the errors for non-assemblable commands."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from tmr.ccma.bodies import cayley, rotation_angle
from tmr.ccma.energy import EnergyModel
from tmr.ccma.errors import AssemblyError, ConvergenceError
from tmr.ccma.sim import agent_poses, end_effector_pose, newton, reference_state, simulate
from tmr.ccma.system import load_system

R_A, Z1, R_E, Z_E = 0.6, 0.3, 0.2, 0.5  # geometry of the shipped examples [m]


@pytest.fixture(scope="module")
def reduced() -> EnergyModel:
    return EnergyModel(load_system("4dof-reduced"))


@pytest.fixture(scope="module")
def complete() -> EnergyModel:
    return EnergyModel(load_system("4dof-complete"))


def test_reference_controls_give_the_reference_state(reduced):
    res = simulate(reduced, reduced.system.u0)
    assert res.iterations == 0 and res.energy < 1e-28
    np.testing.assert_allclose(agent_poses(reduced, res.state)[:, :2], reduced.system.u0.reshape(3, 2), atol=1e-15)


@pytest.mark.parametrize("delta", [-0.05, 0.02, 0.04])  # the arm reaches out to δ = 0.047 m
def test_radial_expansion_matches_closed_form(reduced, delta):
    """Agents moved radially by δ: by symmetry the platform stays centred and level and drops to
    z = z1 + sqrt(L² − (r_a + δ − r_e)²), L the arm length."""
    u = reduced.system.u0.reshape(3, 2) * (1.0 + delta / R_A)
    res = simulate(reduced, u.ravel(), tol=1e-12)
    p, r = end_effector_pose(reduced, res.state)
    arm = np.hypot(R_A - R_E, Z_E - Z1)
    z = Z1 + np.sqrt(arm**2 - (R_A + delta - R_E) ** 2)
    np.testing.assert_allclose(p, [0.0, 0.0, z], atol=2e-6)  # TOML coordinates are rounded to 1e-6 m
    assert rotation_angle(r, np.eye(3)) < 1e-5
    assert res.iterations <= 8


def test_newton_agrees_with_independent_least_squares(reduced):
    """An inconsistent command (residual > 0): Newton's minimiser of ½‖C‖² equals SciPy's trust-region least squares
    on C with finite-difference Jacobians."""
    rng = np.random.default_rng(5)
    u = reduced.system.u0 + 0.01 * rng.normal(size=6)
    st = reference_state(reduced)
    res = newton(reduced, st, u)
    assert res.converged and res.energy > 1e-8
    p = reduced.params(st.r_ref)
    ls = least_squares(lambda x: reduced.residuals(x, u, p), st.x, jac="3-point", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert 0.5 * ls.fun @ ls.fun == pytest.approx(res.energy, rel=1e-8)
    pos_ls, _ = reduced.world_poses(ls.x, st.r_ref)
    pos_n, _ = reduced.world_poses(res.state.x, res.state.r_ref)
    np.testing.assert_allclose(pos_n, pos_ls, atol=1e-7)


def test_newton_converges_quadratically(reduced):
    u = reduced.system.u0 + 0.01 * np.array([1, 0, 1, 0, 1, 0])  # rigid shift: exactly assemblable
    res = newton(reduced, reference_state(reduced), u)
    assert res.converged and res.iterations <= 4 and res.energy < 1e-28


def test_large_rotation_through_reanchoring(complete):
    """Complete actuation: rotating every agent about the vertical through the platform rotates the whole
    mechanism rigidly; 1.5 rad in warm-started increments crosses many re-anchorings."""
    s = complete.system
    st = reference_state(complete)
    xy = s.u0.reshape(3, 3)[:, :2]
    for psi in np.linspace(0.25, 1.5, 6):
        c, sn = np.cos(psi), np.sin(psi)
        u = np.column_stack([xy @ np.array([[c, sn], [-sn, c]]), s.u0.reshape(3, 3)[:, 2] + psi]).ravel()
        res = simulate(complete, u, st)
        st = res.state
    p, r = end_effector_pose(complete, st)
    np.testing.assert_allclose(p, [0, 0, Z_E], atol=1e-9)
    assert rotation_angle(r, cayley(np.array([0.0, 0.0, 2 * np.tan(0.75)]))) < 1e-9
    np.testing.assert_allclose(st.r_ref @ st.r_ref.transpose(0, 2, 1), np.tile(np.eye(3), (10, 1, 1)), atol=1e-12)


def test_non_assemblable_command_raises_a_clear_error(reduced):
    u = reduced.system.u0 * 2.0  # agents twice as far out as the arms reach
    with pytest.raises(
        AssemblyError, match=r"cannot assemble.*residual constraint energy .* m².*largest violation"
    ) as exc:
        simulate(reduced, u)
    assert exc.value.residual > 1e-3 and exc.value.worst.startswith(("elbow", "wrist", "agent"))
    with pytest.raises(AssemblyError, match="controls must be 6 finite numbers"):
        simulate(reduced, np.zeros(5))


def test_iteration_limit_raises_convergence_error(reduced):
    with pytest.raises(ConvergenceError, match="did not converge in 1 iterations"):
        simulate(reduced, reduced.system.u0 * 1.05, max_iter=1)
