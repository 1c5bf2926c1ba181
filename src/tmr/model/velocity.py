"""Two velocity coordinates of a chain: joint rates q̇ and robot velocities v, and the maps between them (planar:
:class:`VelocityMap`; spatial, tethered drones: :class:`VelocityMap3D` with singularity-free link coordinates).

Joint rates ``q̇ = [θ̇1, ḋ1, …, θ̇N, ḋN]`` are the manipulator's coordinates (Caruso 2021 §3). Robot velocities
``v = [ṗ1, …, ṗN]`` (2N, m/s, the Cartesian velocity of every robot) are an equivalent set for a planar chain with
nonzero spans: ``v = J_R q̇`` with ``J_R`` the stacked robot Jacobians (eq. 10–12), and the inverse is local. With
link j from robot j−1 to robot j, direction ``u_j = (cos φ_j, sin φ_j)`` (φ_j = θ1 + … + θj), normal
``n_j = (−sin φ_j, cos φ_j)`` and span d_j, the relative velocity ``w_j = ṗ_j − ṗ_{j−1}`` (ṗ_0 = 0, the anchor)
gives

    ḋ_j = u_jᵀ w_j,      φ̇_j = n_jᵀ w_j / d_j,      θ̇_j = φ̇_j − φ̇_{j−1}  (φ̇_0 = 0).

So ``q̇ = T v`` with T banded (θ̇_j involves robots j−2 … j, ḋ_j robots j−1, j), and a row ``a`` on q̇ becomes the row
``a T`` on v, with at most six nonzeros per joint entry. Rows on robot or tether points are local in v (a point at
fraction s of link j moves with ``(1 − s) ṗ_{j−1} + s ṗ_j``), whereas in q̇ they are dense up to their link (eq. 15).
This is why the lexicographic QP (``tmr.control.qp``) works in v: every row is banded, the QP is sparse, and
OSQP's factorisation cost grows linearly with N instead of quadratically.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tmr.errors import ParameterError

Array = NDArray[np.float64]

#: Entries of a converted row below this fraction of the row's largest entry are rounding noise and set to zero,
#: so that a row that is local in the target coordinates keeps its exact sparsity.
NOISE = 1e-13
_PERP = np.array([-1.0, 1.0])


class VelocityMap:
    """The maps between joint rates q̇ (2N) and robot velocities v (2N) at one configuration of a planar chain.

    Args:
        points: base and robots, ``(N+1, 2)`` [m].
        spans: signed spans d_j, ``(N,)`` [m] (the prismatic joints; they must be nonzero).
        directions: the unit link directions u_j ``(N, 2)`` if already known (then ``points`` is not read).
    """

    def __init__(self, points: Array, spans: Array, directions: Array | None = None) -> None:
        d = np.asarray(spans, dtype=float)
        if np.min(np.abs(d), initial=np.inf) < 1e-9:
            raise ParameterError(f"robot-velocity coordinates need nonzero spans, got {d}")
        if directions is None:
            P = np.asarray(points, dtype=float)
            if P.ndim != 2 or P.shape[1] != 2 or d.shape != (P.shape[0] - 1,):
                raise ParameterError("robot-velocity coordinates need a planar chain: points (N+1, 2) and spans (N,)")
            u = np.diff(P, axis=0) / d[:, None]  # (N, 2) link directions (signed spans: P_j − P_{j−1} = d_j u_j)
        else:
            u = directions
        self.n_robots = d.size
        self.d = d
        self.u = u
        self.nrm = u[:, ::-1] * _PERP  # (−u_y, u_x)
        self._T: Array | None = None

    # ------------------------------------------------------------------ vectors
    def joint_rates(self, v: Array) -> Array:
        """q̇ = T v: joint rates [rad/s, m/s] of robot velocities ``v`` (2N,) [m/s]."""
        if self._T is not None and self.n_robots <= 16:
            return self._T @ np.asarray(v, dtype=float)
        V = np.asarray(v, dtype=float).reshape(self.n_robots, 2)
        w = V.copy()
        w[1:] -= V[:-1]
        phid = np.einsum("ij,ij->i", self.nrm, w) / self.d
        qd = np.empty(2 * self.n_robots)
        qd[0::2] = phid
        qd[2::2] -= phid[:-1]
        qd[1::2] = np.einsum("ij,ij->i", self.u, w)
        return qd

    def robot_velocities(self, qdot: Array) -> Array:
        """v = J_R q̇: robot velocities (2N,) [m/s] of joint rates ``qdot`` (eq. 10–12, in closed form)."""
        qd = np.asarray(qdot, dtype=float)
        phid = np.cumsum(qd[0::2])
        w = qd[1::2, None] * self.u + (self.d * phid)[:, None] * self.nrm
        return np.cumsum(w, axis=0).reshape(-1)

    # ------------------------------------------------------------------ rows
    def to_robot(self, A: Array) -> Array:
        """Rows ``A`` on q̇, (m, 2N), as rows on v: ``A T`` (m, 2N); exact zeros stay zero, rounding noise is removed."""
        A = np.asarray(A, dtype=float)
        N = self.n_robots
        At, Ad = A[:, 0::2], A[:, 1::2]  # (m, N): columns of θ_j and d_j
        a = At.copy()
        a[:, :-1] -= At[:, 1:]  # coefficient of φ̇_j: A_θj − A_θ(j+1)
        a /= self.d
        W = a[:, :, None] * self.nrm[None] + Ad[:, :, None] * self.u[None]  # (m, N, 2): coefficient of w_j
        B = W.copy()
        B[:, :-1] -= W[:, 1:]  # coefficient of ṗ_j: W_j − W_(j+1)
        B = B.reshape(A.shape[0], 2 * N)
        return _denoise(B)

    @property
    def T(self) -> Array:
        """The matrix T of ``q̇ = T v``, (2N, 2N), banded (computed once per map)."""
        if self._T is None:
            N = self.n_robots
            idx = _t_scatter(N)
            a = self.nrm / self.d[:, None]  # φ̇_j = a_jᵀ (ṗ_j − ṗ_{j−1})
            # ḋ_j = u_jᵀ (ṗ_j − ṗ_{j−1});  θ̇_j = φ̇_j − φ̇_{j−1} = a_jᵀ ṗ_j − (a_j + a_{j−1})ᵀ ṗ_{j−1} + a_{j−1}ᵀ ṗ_{j−2}
            vals = np.concatenate([self.u, -self.u[1:], a, -a[1:] - a[:-1], a[1:-1]], axis=None)
            T = np.zeros(4 * N * N)
            T[idx] = vals
            self._T = T.reshape(2 * N, 2 * N)
        return self._T

    @staticmethod
    def to_joint(B: Array, robot_jacobians: Array) -> Array:
        """Rows ``B`` on v, (m, 2N), as rows on q̇: ``B J_R`` with ``J_R`` the stacked robot Jacobians (N, 2, n)."""
        J = np.asarray(robot_jacobians, dtype=float)
        return np.asarray(B, dtype=float) @ J.reshape(-1, J.shape[-1])


_T_SCATTER: dict[int, NDArray[np.intp]] = {}


def _t_scatter(N: int) -> NDArray[np.intp]:
    """Flat indices into T (2N, 2N) of the values stacked by :attr:`VelocityMap.T` (cached per N)."""
    idx = _T_SCATTER.get(N)
    if idx is None:
        j = np.arange(N)
        xy = np.arange(2)

        def block(rows: NDArray[np.intp], robots: NDArray[np.intp]) -> NDArray[np.intp]:
            return ((rows * 2 * N)[:, None] + 2 * robots[:, None] + xy).ravel()

        idx = np.concatenate(
            [
                block(2 * j + 1, j),  # ḋ_j on robot j
                block(2 * j[1:] + 1, j[1:] - 1),  # ḋ_j on robot j−1
                block(2 * j, j),  # θ̇_j on robot j
                block(2 * j[1:], j[1:] - 1),  # θ̇_j on robot j−1
                block(2 * j[2:], j[2:] - 2),  # θ̇_j on robot j−2
            ]
        )
        _T_SCATTER[N] = idx
    return idx


def _denoise(B: Array) -> Array:
    if B.size:
        scale = np.max(np.abs(B), axis=1, keepdims=True)
        B[np.abs(B) <= NOISE * scale] = 0.0
    return B


def robot_pattern(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Sparsity in v of rows whose sparsity in q̇ is ``mask`` (m, 2N): the structural pattern of ``mask`` times T."""
    m, n = mask.shape
    N = n // 2
    t, d = mask[:, 0::2], mask[:, 1::2]
    a = t.copy()
    a[:, :-1] |= t[:, 1:]
    w = a | d  # coefficient of w_j (both of its components)
    b = w.copy()
    b[:, :-1] |= w[:, 1:]
    return np.repeat(b, 2, axis=1).reshape(m, 2 * N)


class VelocityMap3D:
    """The maps between robot velocities v (3N) and singularity-free link coordinates q̇ (3N) of a spatial chain.

    Link j joins robot j−1 and robot j (robot 0 the fixed anchor) with direction u_j and length d_j > 0. Its rates are
    ``q̇_j = [ω_j1, ω_j2, ḋ_j]``: the angular rates of u_j about the orthonormal pair (e1_j, e2_j) ⟂ u_j and the
    length rate, with w_j = ṗ_j − ṗ_{j−1}:

        ω_j1 = e1_jᵀ w_j / d_j,   ω_j2 = e2_jᵀ w_j / d_j,   ḋ_j = u_jᵀ w_j;
        w_j = d_j (ω_j1 e1_j + ω_j2 e2_j) + ḋ_j u_j.

    The pair is built at each configuration from the coordinate axis least aligned with u_j (e1 = that axis made
    ⟂ u_j, e2 = u_j × e1), so the map is defined and well conditioned for every nonzero link — a vertical tether
    included — unlike the chain's D–H angles (α, β), whose yaw is singular when a link is vertical (gimbal lock).
    T (q̇ = T v) is block bidiagonal: link j's three rows touch robots j−1 and j only. Same methods as
    :class:`VelocityMap`.

    Args:
        points: anchor and robots, ``(N+1, 3)`` [m]; consecutive points must differ.
    """

    def __init__(self, points: Array) -> None:
        P = np.asarray(points, dtype=float)
        if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] < 2:
            raise ParameterError(f"a spatial velocity map needs points (N+1, 3), got shape {P.shape}")
        # a few numpy calls on small arrays (this runs at every step of a drone plan): no np.diff / np.cross /
        # np.linalg.norm wrappers, their arithmetic written out (same results bit for bit)
        diff = P[1:] - P[:-1]
        d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        if d.min() < 1e-9:
            raise ParameterError(f"link coordinates need every link longer than 0, got lengths {d}")
        u = diff / d[:, None]
        N = d.size
        rows = np.arange(N)
        k = np.abs(u).argmin(axis=1)  # the axis least aligned with u_j
        # e1 = a − (aᵀu) u with a the unit axis k: aᵀu is u_k exactly (the other terms are ±0)
        e1 = _EYE3[k] - u[rows, k][:, None] * u
        e1 /= np.sqrt(np.add.reduce(e1 * e1, axis=1))[:, None]
        e2 = u[:, _NEXT] * e1[:, _PREV] - u[:, _PREV] * e1[:, _NEXT]  # u × e1
        self.n_robots = N
        self.d = d
        self.u = u
        self.e1, self.e2 = e1, e2
        #: per link, the rows (3, 3) mapping w_j to q̇_j: [e1/d; e2/d; u]
        self.R = np.stack([e1 / d[:, None], e2 / d[:, None], u], axis=1)
        self._T: Array | None = None

    def joint_rates(self, v: Array) -> Array:
        """q̇ = T v: link rates [rad/s, rad/s, m/s per link] of robot velocities ``v`` (3N,) [m/s]."""
        V = np.asarray(v, dtype=float).reshape(self.n_robots, 3)
        w = V.copy()
        w[1:] -= V[:-1]
        return np.einsum("jkl,jl->jk", self.R, w).reshape(-1)

    def robot_velocities(self, qdot: Array) -> Array:
        """v (3N,) [m/s] of link rates ``qdot`` (3N,): w_j = d_j (ω1 e1 + ω2 e2) + ḋ u, ṗ_j = Σ_{i≤j} w_i."""
        Q = np.asarray(qdot, dtype=float).reshape(self.n_robots, 3)
        w = (self.d * Q[:, 0])[:, None] * self.e1 + (self.d * Q[:, 1])[:, None] * self.e2 + Q[:, 2:3] * self.u
        return np.cumsum(w, axis=0).reshape(-1)

    def to_robot(self, A: Array) -> Array:
        """Rows ``A`` on q̇, (m, 3N), as rows on v: ``A T`` (m, 3N); rounding noise is removed."""
        A = np.asarray(A, dtype=float)
        N = self.n_robots
        W = np.einsum("mjk,jkl->mjl", A.reshape(A.shape[0], N, 3), self.R)  # coefficient of w_j
        B = W.copy()
        B[:, :-1] -= W[:, 1:]  # coefficient of ṗ_j: W_j − W_(j+1)
        return _denoise(B.reshape(A.shape[0], 3 * N))

    @property
    def T(self) -> Array:
        """The matrix T of ``q̇ = T v``, (3N, 3N), block bidiagonal (computed once per map)."""
        if self._T is None:
            N = self.n_robots
            T = np.zeros(9 * N * N)
            T[_t3_scatter(N)] = np.concatenate([self.R, -self.R[1:]], axis=None)
            self._T = T.reshape(3 * N, 3 * N)
        return self._T

    @staticmethod
    def to_joint(B: Array, robot_jacobians: Array) -> Array:
        """Rows ``B`` on v, (m, 3N), as rows on q̇ through the robots' Jacobians (N, 3, n) in those coordinates."""
        J = np.asarray(robot_jacobians, dtype=float)
        return np.asarray(B, dtype=float) @ J.reshape(-1, J.shape[-1])


_EYE3 = np.eye(3)
_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])
_T3_SCATTER: dict[int, NDArray[np.intp]] = {}


def _t3_scatter(N: int) -> NDArray[np.intp]:
    """Flat indices into T (3N, 3N) of :attr:`VelocityMap3D.T`'s values: the blocks R_j at (j, j), then −R_j at
    (j, j−1) for j ≥ 1, each block row-major (cached per N)."""
    idx = _T3_SCATTER.get(N)
    if idx is None:
        j = np.arange(N)
        r, c = np.arange(3)[:, None], np.arange(3)[None, :]

        def block(rows: NDArray[np.intp], cols: NDArray[np.intp]) -> NDArray[np.intp]:
            return ((3 * rows[:, None, None] + r) * 3 * N + 3 * cols[:, None, None] + c).ravel()

        idx = _T3_SCATTER[N] = np.concatenate([block(j, j), block(j[1:], j[1:] - 1)])
    return idx


def robot_pattern3d(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Sparsity in v of rows whose sparsity in the link rates of :class:`VelocityMap3D` is ``mask`` (m, 3N)."""
    m, n = mask.shape
    N = n // 3
    w = mask.reshape(m, N, 3).any(axis=2)  # coefficient of w_j (all three components)
    b = w.copy()
    b[:, :-1] |= w[:, 1:]
    return np.repeat(b, 3, axis=1).reshape(m, 3 * N)
