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
from tmr.ccma.system import build_system, load_description, load_system

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


@pytest.mark.parametrize("delta", [0.04, -0.05])
def test_newton_converges_quadratically_in_the_tail(reduced, delta):
    """Radial expansion bends every leg (nonlinear in the state, unlike a rigid shift that Newton solves in one step).
    ‖∇E‖ after k iterations is read from runs stopped at max_iter = k. The sequence need not be monotone (the line
    search decreases E, not ‖∇E‖), but once ‖∇E‖ ≤ 5e-5 m every step squares it: g_{k+1} ≤ C g_k²."""
    u = (reduced.system.u0.reshape(3, 2) * (1.0 + delta / R_A)).ravel()
    res = newton(reduced, reference_state(reduced), u)
    assert res.converged and 4 <= res.iterations <= 10 and res.energy < 1e-16  # TOML rounding: E ~ 4e-18
    g = [newton(reduced, reference_state(reduced), u, max_iter=k).grad_norm for k in range(res.iterations + 1)]
    tail = [(a, b) for a, b in zip(g, g[1:], strict=False) if a <= 5e-5 and b > 1e-15]  # above the rounding floor
    assert len(tail) >= 2
    for a, b in tail:
        assert b <= 1e4 * a * a, g


def test_newton_converges_on_a_large_mechanism():
    """The 4dof-reduced example scaled 1000× (coordinates ~600 m), commanded off the assemblable set: the rounding
    floor of ∇E is ~1e-11 m, above an absolute tolerance of 1e-13, so Newton must use a size-relative one."""
    s = 1000.0
    d = load_description("4dof-reduced")
    d["length_scale"] *= s
    d["end_effector"]["point"] = [s * v for v in d["end_effector"]["point"]]
    for b in d["bodies"]:
        if "position" in b:
            b["position"] = [s * v for v in b["position"]]
    for j in d["joints"]:
        j["point"] = [s * v for v in j["point"]]
    for a in d["agents"]:
        a["position"], a["height"] = [s * v for v in a["position"]], s * a["height"]
    big = EnergyModel(build_system(d))
    u = big.system.u0 + s * 0.01 * np.random.default_rng(5).normal(size=6)
    res = newton(big, reference_state(big), u)
    assert res.converged and res.iterations <= 8
    small = EnergyModel(load_system("4dof-reduced"))
    assert res.energy == pytest.approx(s * s * newton(small, reference_state(small), u / s).energy, rel=1e-6)


class _NoDescent:
    """An EnergyModel whose gradient points uphill: Newton's line search stalls at once (before max_iter)."""

    def __init__(self, model: EnergyModel) -> None:
        self._m = model

    def __getattr__(self, name):
        return getattr(self._m, name)

    def egh(self, x, u, p):
        e, g, h = self._m.egh(x, u, p)
        return e, -g, h


def test_stalled_newton_is_not_accepted(reduced):
    """A command 1e-7 m off the reference: E ≈ 1e-14 m² is below the assembly tolerance, but the stalled Newton
    has not found the minimiser, so simulate must not return it (and IK must not start from it)."""
    from tmr.ccma.control import Target, solve_ik

    bad = _NoDescent(reduced)
    u = reduced.system.u0 * (1.0 + 1e-7 / R_A)
    res = newton(bad, reference_state(reduced), u)
    assert not res.converged and res.iterations < 60 and res.energy < 1e-12
    with pytest.raises(ConvergenceError, match="stalled"):
        simulate(bad, u)
    p0, r0 = end_effector_pose(reduced, reference_state(reduced))
    with pytest.raises(ConvergenceError, match="did not converge"):
        solve_ik(bad, reference_state(reduced), u, Target(p0, r0))


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
