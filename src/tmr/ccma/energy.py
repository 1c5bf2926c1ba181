"""Constraint energy E(x, u) = ½‖C(x, u)‖² and its exact derivatives, compiled once with CasADi (Kumar 2019 eq. 2).

:class:`EnergyModel` builds the stacked constraint vector C of a :class:`~tmr.ccma.system.System` symbolically
(joints and agent constraints from :mod:`tmr.ccma.joints`, bodies parameterised as in :mod:`tmr.ccma.bodies`) and
compiles, once, the CasADi functions reused at every Newton and BFGS step:

* ``egh(x, u, p) → (E, ∇ₓE, ∇ₓ²E)`` — Newton on the energy (Kumar 2019 §III-A),
* ``energy(x, u, p) → E`` — line search,
* ``ik(x, u, p, t) → (f, ∇ₓf, ∂E/∂u, ∂²E/∂x∂u)`` — with the Hessian of the last Newton iteration, everything
  the sensitivity gradient needs (Kumar 2019 eq. 4–9), where f is the end-effector tracking term,
* ``gn(x, u, p, t) → (∂r/∂x, ∂²E/∂u²)`` with f = ‖r‖² — the Gauss–Newton estimate of ∇²O that starts BFGS,
* ``ee(x, p) → (p_EE, R_EE)`` and ``residuals(x, u, p) → C``.

Symbols: x ∈ R^{6n} body states (positions [m], Cayley vectors [-]); u ∈ R^m controls (agent x, y [m], yaw [rad]);
p = (R_ref,i column-major for every body, held yaw of reduced agents [rad]); t = (target position [m], target rotation
column-major). Tracking term (Kumar 2019 eq. 3 with a rotation part):
f = ‖p_EE − p_t‖² + ℓ_R² · ½‖R_EE − R_t‖_F², and ½‖R − R_t‖_F² = 2(1 − cos θ) ≈ θ² for a rotation error θ, so
ℓ_R [m] converts radians to metres (ℓ_R = 0.1 m: 0.01 rad weighs like 1 mm).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from tmr.ccma.bodies import cayley_sx
from tmr.ccma.errors import DescriptionError
from tmr.ccma.joints import agent_rows, joint_rows
from tmr.ccma.system import System

__all__ = ["EnergyModel", "Mobility", "default_cache_dir"]

#: Relative eigenvalue threshold below which the reference Hessian is called singular.
_RANK_TOL = 1e-9


class _Evaluator:
    """Fast numeric evaluation of a CasADi function through its zero-copy buffer interface.

    Inputs are copied into preallocated float arrays and the (dense) outputs are written by CasADi into preallocated
    arrays; a call returns copies (scalars as float, column vectors as 1-D arrays, matrices as 2-D arrays).
    """

    def __init__(self, fn: ca.Function) -> None:
        self.fn = fn
        self._in = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self._shape = [fn.size_out(j) for j in range(fn.n_out())]
        self._out = [np.zeros(r * c) for r, c in self._shape]
        self._buf, self._eval = fn.buffer()
        for i, a in enumerate(self._in):
            self._buf.set_arg(i, memoryview(a))
        for j, a in enumerate(self._out):
            self._buf.set_res(j, memoryview(a))

    def __call__(self, *args: np.ndarray) -> Any:
        for dst, src in zip(self._in, args, strict=True):
            dst[:] = np.ravel(src)
        self._eval()
        res = []
        for (r, c), a in zip(self._shape, self._out, strict=True):
            if r * c == 1:
                res.append(float(a[0]))
            elif c == 1:
                res.append(a.copy())
            else:
                res.append(a.reshape(c, r).T.copy())  # CasADi stores column-major
        return res[0] if len(res) == 1 else tuple(res)


def default_cache_dir() -> Path:
    """Directory of compiled CCMA models: ``$TMR_CACHE_DIR/ccma`` or ``~/.cache/tmr/ccma``."""
    root = os.environ.get("TMR_CACHE_DIR")
    return Path(root) / "ccma" if root else Path.home() / ".cache" / "tmr" / "ccma"


def _compile(funcs: list[ca.Function], cache_dir: str | os.PathLike[str] | None) -> list[ca.Function]:
    """Generate C for ``funcs``, compile it (cached by content hash) and load the shared library."""
    cg = ca.CodeGenerator("ccma_model.c", {"with_header": False})
    for fn in funcs:
        cg.add(fn)
    with tempfile.TemporaryDirectory() as tmp:
        cg.generate(tmp + os.sep)
        source = Path(tmp, "ccma_model.c").read_text()
        key = hashlib.sha256(source.encode()).hexdigest()[:20]
        out_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        lib = out_dir / f"ccma_{key}.so"
        if not lib.is_file():
            out_dir.mkdir(parents=True, exist_ok=True)
            cc = os.environ.get("CC", "cc")
            if shutil.which(cc) is None:
                raise DescriptionError(f"compile=True needs a C compiler ({cc!r} not found); use compile=False")
            tmp_lib = Path(tmp, lib.name)
            cmd = [cc, "-O1", "-shared", "-fPIC", str(Path(tmp, "ccma_model.c")), "-o", str(tmp_lib), "-lm"]
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                raise DescriptionError(f"compiling the CCMA model failed: {proc.stderr.strip()[:500]}")
            fd, staged = tempfile.mkstemp(dir=out_dir, prefix=f".{lib.name}.", suffix=".tmp")
            os.close(fd)
            shutil.copyfile(tmp_lib, staged)
            os.replace(staged, lib)  # atomic: concurrent builders never see a partial library
    return [ca.external(fn.name(), str(lib)) for fn in funcs]


class Mobility(NamedTuple):
    """Reference-configuration check: Hessian eigenvalues, and the bodies moving in each free mode (if any)."""

    eigenvalues: np.ndarray
    free_modes: list[list[str]]


class EnergyModel:
    """Compiled constraint energy of a system; see the module docstring.

    ``compile=True`` generates C code for the functions, compiles it once with the system C compiler (``$CC``, default
    ``cc``) into a shared library cached under ``cache_dir`` (default ``$TMR_CACHE_DIR`` or ``~/.cache/tmr/ccma``,
    keyed by a hash of the code) and loads it: the same derivatives, ~30× faster than CasADi's SX virtual machine.

    Constructing the model checks that the reference configuration is assembled (C(x0, u0) = 0) and that the state is
    fully determined by the controls (∇ₓ²E positive definite there, i.e. no passive body or joint left free); otherwise
    :class:`DescriptionError` names the free bodies.
    """

    def __init__(
        self,
        system: System,
        *,
        compile: bool = False,
        cache_dir: str | os.PathLike[str] | None = None,
        check: bool = True,
    ) -> None:
        self.system = system
        n = system.n_bodies
        self.nx = 6 * n
        self.nu = system.n_controls
        x = ca.SX.sym("x", self.nx)
        u = ca.SX.sym("u", self.nu)
        p = ca.SX.sym("p", 9 * n + system.held_yaw.size)
        t = ca.SX.sym("t", 12)
        poses = []
        for i in range(n):
            r_ref = ca.reshape(p[9 * i : 9 * i + 9], 3, 3)
            poses.append((x[6 * i : 6 * i + 3], r_ref @ cayley_sx(x[6 * i + 3 : 6 * i + 6])))
        world = (ca.SX.zeros(3), ca.SX.eye(3))
        ell = system.length_scale
        rows = [
            joint_rows(j, poses[j.a] if j.a >= 0 else world, poses[j.b] if j.b >= 0 else world, ell)
            for j in system.joints
        ]
        for a in system.agents:
            yaw = u[a.controls[2]] if a.actuation == "complete" else p[9 * n + a.yaw_param]
            rows.append(agent_rows(poses[a.body], a.height, u[a.controls[0]], u[a.controls[1]], yaw, ell))
        c = ca.vertcat(*rows)
        e = 0.5 * ca.dot(c, c)
        h, g = ca.hessian(e, x)
        pe_body, re = poses[system.ee_body]
        pe = pe_body + re @ system.ee_offset
        pt, rt = t[:3], ca.reshape(t[3:], 3, 3)
        f = ca.sumsqr(pe - pt) + system.rotation_scale**2 * 0.5 * ca.sumsqr(re - rt)
        exu = ca.jacobian(g, u)
        eu = ca.gradient(e, u)
        fx = ca.gradient(f, x)
        r_track = ca.vertcat(pe - pt, system.rotation_scale * np.sqrt(0.5) * ca.reshape(re - rt, 9, 1))  # f = ‖r‖²
        euu = ca.hessian(e, u)[0]
        all_poses = ca.horzcat(*[ca.vertcat(q, ca.reshape(r, 9, 1)) for q, r in poses])
        funcs = [
            ca.Function("ccma_egh", [x, u, p], [e, g, h]),
            ca.Function("ccma_energy", [x, u, p], [e]),
            ca.Function("ccma_ik", [x, u, p, t], [f, fx, eu, exu]),
            ca.Function("ccma_gn", [x, u, p, t], [ca.jacobian(r_track, x), euu]),
            ca.Function("ccma_ee", [x, p], [pe, re]),
            ca.Function("ccma_residuals", [x, u, p], [c]),
            ca.Function("ccma_poses", [x, p], [all_poses]),
        ]
        funcs = [ca.Function(fn.name(), fn.sx_in(), [ca.densify(o) for o in fn.call(fn.sx_in())]) for fn in funcs]
        self.compiled = False
        if compile:
            funcs = _compile(funcs, cache_dir)
            self.compiled = True
        self.egh, self.energy, self.ik, self.gn, self.ee, self.residuals, self.poses = (_Evaluator(fn) for fn in funcs)
        self.labels = system.constraint_labels
        if check:
            self.check_reference()

    # -------------------------------------------------------------------------------------------- parameters
    def params(self, r_ref: np.ndarray) -> np.ndarray:
        """Parameter vector p from reference rotations (n, 3, 3) and the system's held yaws."""
        return np.concatenate([r_ref.transpose(0, 2, 1).reshape(-1), self.system.held_yaw])

    @staticmethod
    def target_vector(position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """t = (p_t, R_t column-major) for ``ik``."""
        return np.concatenate([np.asarray(position, float), np.asarray(rotation, float).T.reshape(-1)])

    def world_poses(self, x: np.ndarray, r_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World positions (n, 3) [m] and rotations (n, 3, 3) of every body."""
        m = self.poses(x, self.params(r_ref))
        return m[:3].T.copy(), m[3:].T.reshape(-1, 3, 3).transpose(0, 2, 1).copy()

    # -------------------------------------------------------------------------------------------- checks
    def mobility(self) -> Mobility:
        """Eigenvalues of ∇ₓ²E at the reference state and the bodies moving in its (near-)null modes."""
        s = self.system
        _, _, h = self.egh(s.x0, s.u0, self.params(s.r_ref0))
        lam, vec = np.linalg.eigh(h)
        free = []
        for k in np.flatnonzero(lam <= _RANK_TOL * max(1.0, lam[-1])):
            v = np.abs(vec[:, k]).reshape(-1, 6).max(axis=1)
            free.append([s.body_names[i] for i in np.flatnonzero(v > 0.1 * v.max())])
        return Mobility(lam, free)

    def check_reference(self) -> None:
        """Raise :class:`DescriptionError` if the reference configuration is not assembled or not determined."""
        s = self.system
        c = self.residuals(s.x0, s.u0, self.params(s.r_ref0))
        if c.size and np.max(np.abs(c)) > 1e-9:
            k = int(np.argmax(np.abs(c)))
            raise DescriptionError(
                f"{s.name}: reference configuration not assembled at {self.labels[k]} ({c[k]:.3g} m)"
            )
        mob = self.mobility()
        if mob.free_modes:
            modes = "; ".join(", ".join(b) for b in mob.free_modes)
            raise DescriptionError(
                f"{s.name}: {len(mob.free_modes)} state direction(s) are not fixed by the joints and the agents' "
                f"controls (free bodies: {modes}); add joints or actuation, or remove the free dof"
            )
