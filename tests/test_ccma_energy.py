"""Tests of tmr.ccma.energy: exact CasADi derivatives against finite differences, and the compiled model."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from tmr.ccma.energy import EnergyModel, _Evaluator
from tmr.ccma.system import build_system, load_system

RNG = np.random.default_rng(11)


@pytest.fixture(scope="module")
def model() -> EnergyModel:
    return EnergyModel(load_system("5dof-reduced"))


def _perturbed(model):
    s = model.system
    x = s.x0 + 0.02 * RNG.normal(size=s.x0.size)
    u = s.u0 + 0.01 * RNG.normal(size=s.u0.size)
    return x, u, model.params(s.r_ref0)


def test_energy_is_half_squared_residual(model):
    x, u, p = _perturbed(model)
    c = model.residuals(x, u, p)
    assert c.size == model.system.n_constraints == len(model.labels)
    assert model.energy(x, u, p) == pytest.approx(0.5 * c @ c, rel=1e-13)
    assert model.energy(model.system.x0, model.system.u0, p) < 1e-28


def test_gradient_hessian_and_mixed_derivative_match_finite_differences(model):
    x, u, p = _perturbed(model)
    e, g, h = model.egh(x, u, p)
    step = 1e-6
    g_fd = np.array(
        [(model.energy(x + step * ei, u, p) - model.energy(x - step * ei, u, p)) / (2 * step) for ei in np.eye(x.size)]
    )
    np.testing.assert_allclose(g, g_fd, atol=1e-8 * max(1.0, np.abs(g).max()))
    h_fd = np.column_stack(
        [(model.egh(x + step * ei, u, p)[1] - model.egh(x - step * ei, u, p)[1]) / (2 * step) for ei in np.eye(x.size)]
    )
    np.testing.assert_allclose(h, h_fd, atol=1e-6 * np.abs(h).max())
    np.testing.assert_allclose(h, h.T, atol=1e-14)
    t = model.target_vector(np.array([0.01, 0.0, 0.52]), np.eye(3))
    f, fx, eu, exu = model.ik(x, u, p, t)
    exu_fd = np.column_stack(
        [(model.egh(x, u + step * ei, p)[1] - model.egh(x, u - step * ei, p)[1]) / (2 * step) for ei in np.eye(u.size)]
    )
    np.testing.assert_allclose(exu, exu_fd, atol=1e-7 * np.abs(exu).max())
    eu_fd = np.array(
        [(model.energy(x, u + step * ei, p) - model.energy(x, u - step * ei, p)) / (2 * step) for ei in np.eye(u.size)]
    )
    np.testing.assert_allclose(eu, eu_fd, atol=1e-9)
    f_fd = np.array(
        [
            (model.ik(x + step * ei, u, p, t)[0] - model.ik(x - step * ei, u, p, t)[0]) / (2 * step)
            for ei in np.eye(x.size)
        ]
    )
    np.testing.assert_allclose(fx, f_fd, atol=1e-9)


def test_tracking_term_measures_position_and_rotation(model):
    s = model.system
    p = model.params(s.r_ref0)
    pe, re = model.ee(s.x0, p)
    np.testing.assert_allclose(pe, [0, 0, 0.5], atol=1e-15)
    from tmr.ccma.bodies import rot_z

    # 3 mm position error and 0.02 rad yaw error: f = 0.003² + ℓ_R² · 2(1 − cos 0.02)
    f = model.ik(s.x0, s.u0, p, model.target_vector(pe + [0.003, 0, 0], rot_z(0.02)))[0]
    assert f == pytest.approx(0.003**2 + 0.1**2 * 2 * (1 - np.cos(0.02)), rel=1e-12)


def test_world_poses_and_mobility(model):
    s = model.system
    pos, rot = model.world_poses(s.x0, s.r_ref0)
    np.testing.assert_allclose(pos, s.x0.reshape(-1, 6)[:, :3])
    np.testing.assert_allclose(rot, s.r_ref0, atol=1e-15)
    mob = model.mobility()
    assert mob.free_modes == [] and mob.eigenvalues[0] > 1e-5


@pytest.mark.skipif(shutil.which(os.environ.get("CC", "cc")) is None, reason="no C compiler")
def test_compiled_model_matches_interpreted(tmp_path):
    """A one-agent pendulum (tiny, compiles in about a second) evaluated by the C library and by CasADi's VM."""
    desc = {
        "name": "pendulum",
        "bodies": [{"name": "rod"}],
        "joints": [{"type": "revolute", "bodies": ["world", "rod"], "point": [0, 0, 1.0], "axis": [0, 1, 0]}],
        "agents": [
            {
                "name": "cart",
                "position": [0.0, 0.0],
                "height": 0.2,
                "attach": "rod",
                "actuation": "complete",
                "point": [0.0, 0.0, 0.2],
            }
        ],
        "end_effector": {"body": "rod"},
    }
    # the rod hangs from a world pivot and is bolted to the cart: over-constrained, but a valid energy
    ref = EnergyModel(build_system(desc), check=False)
    fast = EnergyModel(build_system(desc), compile=True, cache_dir=tmp_path, check=False)
    assert fast.compiled and list(tmp_path.glob("ccma_*.so"))
    x = ref.system.x0 + 0.05 * RNG.normal(size=ref.system.x0.size)
    u = ref.system.u0 + 0.05
    p = ref.params(ref.system.r_ref0)
    t = ref.target_vector(np.array([0.1, -0.2, 0.9]), np.eye(3))
    inputs = {
        "egh": (x, u, p),
        "energy": (x, u, p),
        "ik": (x, u, p, t),
        "gn": (x, u, p, t),
        "ee": (x, p),
        "residuals": (x, u, p),
        "poses": (x, p),
    }
    evaluators = {k for k, v in vars(ref).items() if isinstance(v, _Evaluator)}
    assert set(inputs) == evaluators and len(evaluators) == 7  # every compiled function of EnergyModel
    for name, args in inputs.items():
        a_out, b_out = getattr(ref, name)(*args), getattr(fast, name)(*args)
        a_out = a_out if isinstance(a_out, tuple) else (a_out,)
        b_out = b_out if isinstance(b_out, tuple) else (b_out,)
        assert len(a_out) == len(b_out), name
        for a, b in zip(a_out, b_out, strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15, err_msg=name)
    # the second build loads the cached library
    again = EnergyModel(build_system(desc), compile=True, cache_dir=tmp_path, check=False)
    assert again.energy(x, u, p) == fast.energy(x, u, p)
