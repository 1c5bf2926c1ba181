"""A chain of tethered mobile robots seen as a redundant serial manipulator (Caruso 2021 §3–4).

Each robot is a revolute joint (planar) or a two-axis spherical joint (spatial, tethered drones) and each tether is a
prismatic joint whose length is the distance between two consecutive robots. Link ``j`` (``j = 1..N``) runs from robot
``j-1`` to robot ``j``; robot 0 is the fixed base (the tether anchor).

Joint vector layout
    planar  (2N): ``q = [θ1, d1, θ2, d2, ..., θN, dN]`` — θ relative heading of link j [rad], d tether span [m].
    spatial (3N): ``q = [α1, β1, d1, ..., αN, βN, dN]`` — two revolute angles of each spherical joint [rad], d [m].

The Denavit–Hartenberg model (:meth:`Chain.dh_table`, :meth:`Chain.frames`) follows Caruso 2021 eq. 1–2 and Table 1;
the planar hot path uses the equivalent closed form (tested equal to the D–H products) because it is ~20× faster.
Point Jacobians follow eq. 10–12 and 15: a point on link ``j`` has zero columns for every joint after that link.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ParameterError

Array = NDArray[np.float64]
Fixed = Literal["fraction", "distance"]


def dh_transform(theta: Array, d: Array, a: Array, alpha: Array) -> Array:
    """Homogeneous transforms ``T_i^{i-1}`` of Caruso 2021 eq. 1, vectorised over joints.

    Args:
        theta, d, a, alpha: arrays of equal shape ``(n,)`` — joint angle [rad], offset [m], length [m], twist [rad].

    Returns:
        ``(n, 4, 4)`` array of transforms.
    """
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2], T[..., 0, 3] = ct, -st * ca, st * sa, a * ct
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st, ct * ca, -ct * sa, a * st
    T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa, ca, d
    T[..., 3, 3] = 1.0
    return T


class Chain:
    """Kinematics of ``n_robots`` tethered robots anchored at ``base``.

    Args:
        n_robots: number of robots N ≥ 1 (the last one is the leader / end-effector).
        base: anchor position, ``(x, y)`` planar or ``(x, y, z)`` spatial [m].
        spatial: ``False`` for ground robots (2N joints), ``True`` for tethered drones (3N joints).
    """

    def __init__(self, n_robots: int, base: ArrayLike = (0.0, 0.0), spatial: bool = False) -> None:
        if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)) or n_robots < 1:
            raise ParameterError(f"the chain needs at least one robot (an integer ≥ 1), got n_robots={n_robots!r}")
        self.n_robots = int(n_robots)
        self.spatial = bool(spatial)
        self.dim = 3 if spatial else 2
        self.joints_per_robot = 3 if spatial else 2
        self.dof = self.joints_per_robot * self.n_robots
        b = np.asarray(base, dtype=float).reshape(-1)
        if b.size == 2 and self.spatial:
            b = np.append(b, 0.0)
        if b.size != self.dim or not np.all(np.isfinite(b)):
            raise ParameterError(f"base must be {self.dim} finite coordinates, got {base!r}")
        self.base = b
        jpr = self.joints_per_robot
        self.prismatic_index = np.arange(jpr - 1, self.dof, jpr)
        self.revolute_index = np.setdiff1d(np.arange(self.dof), self.prismatic_index)
        self.is_prismatic = np.zeros(self.dof, dtype=bool)
        self.is_prismatic[self.prismatic_index] = True
        # link number (1-based) each joint belongs to: joints of robot j move link j
        self.joint_link = np.repeat(np.arange(1, self.n_robots + 1), jpr)
        n = self.n_robots
        if self.spatial:
            # per robot: yaw (α=π/2), pitch (α=−π/2, θ offset −π/2), tether (prismatic, θ offset −π/2, α=π/2);
            # the yaw of robots 2..N has a θ offset π/2 so that q = 0 is a straight horizontal chain along +x
            # and every yaw axis is vertical when the tethers are horizontal (derivation in formulations/pinv.md).
            self._dh_alpha = np.tile([np.pi / 2, -np.pi / 2, np.pi / 2], n)
            self._dh_offset = np.tile([np.pi / 2, -np.pi / 2, -np.pi / 2], n)
            self._dh_offset[0] = 0.0
        else:
            # Caruso 2021 Table 1: odd rows revolute α=π/2, even rows prismatic α=−π/2, first θ offset π/2
            self._dh_alpha = np.tile([np.pi / 2, -np.pi / 2], n)
            self._dh_offset = np.zeros(self.dof)
            self._dh_offset[0] = np.pi / 2
        self._tril = np.tril(np.ones((n, n)))  # cumulative-sum operator over links

    # ------------------------------------------------------------------ validation
    def check_q(self, q: ArrayLike) -> Array:
        """Return ``q`` as a float array of shape ``(dof,)``; ``ParameterError`` if wrong size or not finite."""
        qa = np.asarray(q, dtype=float)
        if qa.shape != (self.dof,):
            raise ParameterError(
                f"joint vector must have shape ({self.dof},) for {self.n_robots} robots, got {qa.shape}"
            )
        if not np.all(np.isfinite(qa)):
            raise ParameterError(f"joint vector contains NaN or inf: {qa}")
        return qa

    # ------------------------------------------------------------------ D–H model (eq. 1–2)
    def dh_table(self, q: ArrayLike) -> Array:
        """D–H parameters ``[θ, d, a, α]`` per joint (rows), Caruso 2021 Table 1 (planar)."""
        qa = np.asarray(q, dtype=float)
        theta = np.where(self.is_prismatic, 0.0, qa) + self._dh_offset
        d = np.where(self.is_prismatic, qa, 0.0)
        return np.column_stack([theta, d, np.zeros(self.dof), self._dh_alpha])

    def frames(self, q: ArrayLike) -> Array:
        """World frames ``T_i^0`` for ``i = 0..dof`` (Caruso 2021 eq. 2 products), shape ``(dof+1, 4, 4)``.

        Frame 0 is at the base with z vertical; frame ``i`` is after joint ``i``.
        """
        tab = self.dh_table(q)
        Ts = dh_transform(tab[:, 0], tab[:, 1], tab[:, 2], tab[:, 3])
        out = np.empty((self.dof + 1, 4, 4))
        out[0] = np.eye(4)
        out[0, : self.dim, 3] = self.base
        for i in range(self.dof):
            out[i + 1] = out[i] @ Ts[i]
        return out

    # ------------------------------------------------------------------ forward kinematics
    def _planar_geometry(self, q: Array) -> tuple[Array, Array]:
        """Unit link directions ``u`` (N,2) and chain points ``P`` (N+1,2) for a planar chain."""
        phi = np.cumsum(q[0::2])
        u = np.column_stack([np.cos(phi), np.sin(phi)])
        P = np.empty((self.n_robots + 1, 2))
        P[0] = self.base
        np.cumsum(q[1::2, None] * u, axis=0, out=P[1:])
        P[1:] += self.base
        return u, P

    def points(self, q: ArrayLike) -> Array:
        """Base followed by every robot, shape ``(N+1, dim)`` [m] (Caruso 2021 eq. 2 for k = 0..N)."""
        qa = np.asarray(q, dtype=float)
        if not self.spatial:
            return self._planar_geometry(qa)[1]
        F = self.frames(qa)
        return F[np.r_[0, self.prismatic_index + 1], : self.dim, 3]

    def robots(self, q: ArrayLike) -> Array:
        """Robot positions ``x_k``, k = 1..N, shape ``(N, dim)`` [m] (Caruso 2021 eq. 2)."""
        return self.points(q)[1:]

    def end_effector(self, q: ArrayLike) -> Array:
        """Leader position (robot N) [m]."""
        return self.points(q)[-1]

    def spans(self, q: ArrayLike) -> Array:
        """Horizontal distance between consecutive robots (tether spans), shape ``(N,)`` [m]."""
        P = self.points(q)
        return np.linalg.norm(np.diff(P[:, :2], axis=0), axis=1)

    def link_points(self, q: ArrayLike, links: ArrayLike, s: ArrayLike) -> Array:
        """Points at fraction ``s ∈ [0, 1]`` along links ``links`` (1-based), shape ``(M, dim)`` [m]."""
        P = self.points(q)
        li = np.asarray(links, dtype=int).reshape(-1)
        sa = np.broadcast_to(np.asarray(s, dtype=float), li.shape)
        return P[li - 1] + sa[:, None] * (P[li] - P[li - 1])

    # ------------------------------------------------------------------ Jacobians (eq. 10–12, 15)
    def point_jacobians(self, q: ArrayLike, links: ArrayLike, s: ArrayLike, fixed: Fixed = "fraction") -> Array:
        """Jacobians of points on links, shape ``(M, dim, dof)`` (Caruso 2021 eq. 10–12, 15).

        Args:
            q: joint vector.
            links: link index per point, 1-based (link j joins robot j-1 and robot j).
            s: fraction along the link per point, in [0, 1] (s = 1 is robot j).
            fixed: what stays fixed when the tether of the point's own link changes length.
                ``"fraction"`` — the point is at a fixed fraction s of the tether, so it moves with ``d_j`` (column
                ``s·u_j``); ``"distance"`` — the point is at a fixed distance from the link's start, as a point on a
                rigid manipulator link, so the column of ``d_j`` is zero: exactly Caruso 2021 eq. 15.

        Columns of joints of later links are zero (eq. 15).
        """
        qa = np.asarray(q, dtype=float)
        li = np.asarray(links, dtype=int).reshape(-1)
        sa = np.broadcast_to(np.asarray(s, dtype=float), li.shape)
        if li.size and (li.min() < 1 or li.max() > self.n_robots):
            raise ParameterError(f"link indices must be in 1..{self.n_robots}, got {li}")
        if self.spatial:
            return self._spatial_point_jacobians(qa, li, sa, fixed)
        u, P = self._planar_geometry(qa)
        pts = P[li - 1] + (sa * qa[2 * li - 1])[:, None] * u[li - 1]
        M, n = li.size, self.n_robots
        J = np.zeros((M, 2, self.dof))
        link_no = np.arange(1, n + 1)
        on_or_before = link_no[None, :] <= li[:, None]  # (M, N): joint i moves the point
        rel = pts[:, None, :] - P[None, :-1, :]  # p - p_{i-1}
        # revolute about vertical axis: z × (p - o) = (-(p-o)_y, (p-o)_x)
        J[:, 0, 0::2] = -rel[..., 1] * on_or_before
        J[:, 1, 0::2] = rel[..., 0] * on_or_before
        before = link_no[None, :] < li[:, None]
        w = before.astype(float)
        if fixed == "fraction":
            w = w + (link_no[None, :] == li[:, None]) * sa[:, None]
        elif fixed != "distance":
            raise ParameterError(f"fixed must be 'fraction' or 'distance', got {fixed!r}")
        J[:, 0, 1::2] = w * u[None, :, 0]
        J[:, 1, 1::2] = w * u[None, :, 1]
        return J

    def _spatial_point_jacobians(self, q: Array, li: Array, sa: Array, fixed: Fixed) -> Array:
        F = self.frames(q)
        z = F[:-1, :3, 2]  # axis of joint i is z of frame i-1
        o = F[:-1, :3, 3]
        ends = F[self.prismatic_index + 1, :3, 3]
        starts = np.vstack([self.base, ends[:-1]])
        pts = starts[li - 1] + sa[:, None] * (ends[li - 1] - starts[li - 1])
        jl = self.joint_link  # (dof,)
        J = np.zeros((li.size, 3, self.dof))
        rev = ~self.is_prismatic
        moves = jl[None, :] <= li[:, None]
        cross = np.cross(z[None, :, :], pts[:, None, :] - o[None, :, :])  # (M, dof, 3)
        Jr = np.where((moves & rev[None, :])[..., None], cross, 0.0)
        pw = (jl[None, :] < li[:, None]).astype(float)
        if fixed == "fraction":
            pw = pw + (jl[None, :] == li[:, None]) * sa[:, None]
        elif fixed != "distance":
            raise ParameterError(f"fixed must be 'fraction' or 'distance', got {fixed!r}")
        Jp = (pw * self.is_prismatic[None, :])[..., None] * z[None, :, :]
        J[:] = np.swapaxes(Jr + Jp, 1, 2)
        return J

    def robot_jacobians(self, q: ArrayLike) -> Array:
        """Jacobians of every robot position, shape ``(N, dim, dof)`` (eq. 10–12 with p = x_k)."""
        links = np.arange(1, self.n_robots + 1)
        return self.point_jacobians(q, links, np.ones(self.n_robots))

    def end_effector_jacobian(self, q: ArrayLike) -> Array:
        """Leader Jacobian ``J_e``, shape ``(dim, dof)`` (Caruso 2021 eq. 9)."""
        return self.point_jacobians(q, [self.n_robots], [1.0])[0]

    # ------------------------------------------------------------------ inverse of the placement
    def q_from_positions(self, positions: ArrayLike) -> Array:
        """Joint vector placing the robots at ``positions`` (N, dim) [m]: the inverse of :meth:`robots`.

        Planar: ``[θ_j, d_j]``. Spatial: per robot j, in the frame R at the end of link j−1 (frame 3(j−1) of
        :meth:`frames`), the D–H model moves the tether along ``(cos β cos θ, cos β sin θ, sin β)`` with θ = α + the
        yaw offset; so d_j = |p_j − p_{j−1}|, β_j = asin(z) and α_j = atan2(y, x) − offset of Rᵀ u_j (a vertical link
        in that frame leaves α free: 0). Angles in (−π, π].

        Raises ``ParameterError`` when two consecutive points coincide (zero span: heading undefined).
        """
        P = np.asarray(positions, dtype=float)
        if P.shape != (self.n_robots, self.dim) or not np.all(np.isfinite(P)):
            raise ParameterError(f"positions must be finite, shape ({self.n_robots}, {self.dim}); got {P.shape}")
        full = np.vstack([self.base, P])
        diff = np.diff(full, axis=0)
        d = np.linalg.norm(diff, axis=1)
        if np.any(d < 1e-9):
            k = int(np.argmin(d)) + 1
            raise ParameterError(f"robot {k} coincides with the previous point of the chain: spans must be > 0")
        if self.spatial:
            q = np.zeros(self.dof)
            frame = np.eye(3)  # rotation of frame 0 (the base)
            tab_alpha, offset = self._dh_alpha, self._dh_offset
            for j in range(self.n_robots):
                local = frame.T @ (diff[j] / d[j])
                beta = float(np.arcsin(np.clip(local[2], -1.0, 1.0)))
                yaw = float(np.arctan2(local[1], local[0])) if np.hypot(local[0], local[1]) > 1e-12 else offset[3 * j]
                alpha = (yaw - offset[3 * j] + np.pi) % (2 * np.pi) - np.pi
                q[3 * j : 3 * j + 3] = alpha, beta, d[j]
                i = np.arange(3 * j, 3 * j + 3)
                theta = np.where(self.is_prismatic[i], 0.0, q[i]) + offset[i]
                for R in dh_transform(theta, np.zeros(3), np.zeros(3), tab_alpha[i])[:, :3, :3]:
                    frame = frame @ R
            return q
        phi = np.unwrap(np.arctan2(diff[:, 1], diff[:, 0]))
        theta = np.diff(np.r_[0.0, phi])
        theta = (theta + np.pi) % (2 * np.pi) - np.pi
        q = np.empty(self.dof)
        q[0::2], q[1::2] = theta, d
        return q
