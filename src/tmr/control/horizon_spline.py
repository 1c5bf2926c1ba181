"""The clearance spline of the whole-horizon NLP (``formulations/horizon.md``, "One spline evaluation an
iterate"): a cubic tensor B-spline on the environment's signed-distance samples, as casadi's B-spline node
(:func:`distance_spline`: the rows when casadi differentiates them, and every numeric check) and as
:class:`ClearanceSpline`, the same spline with its first and second derivatives from one vectorised pass: the NLP's
clearance rows, Jacobian and Hessian (:class:`SplineRows`).

Why not scipy's ``NdBSpline``: it evaluates one derivative order per call, so value, gradient and Hessian take five
calls plus casadi's value; ``benchmarks/horizon_spline.py`` measures both. Tested against both
(``tests/test_horizon_spline.py``).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def spline_tables(env: Any) -> tuple[list[float], list[float], Array]:
    """Knots (x, y) and control points (nx, ny) of the clearance B-spline: the environment's signed-distance samples
    (``env._grid``, cell h = ``env.resolution``) on uniform knots centred on them (see :func:`distance_spline`)."""
    fld, origin, _ = env._grid
    d = np.asarray(fld[..., 0], dtype=float)
    nx, ny = d.shape
    h = float(env.resolution)
    kx = (origin[0] + h * (np.arange(nx + 4) - 2.0)).tolist()
    ky = (origin[1] + h * (np.arange(ny + 4) - 2.0)).tolist()
    return kx, ky, d


def distance_spline(env: Any) -> ca.Function:
    """Smooth signed distance to the inflated obstacles, ``f(p (2, 1)) -> c`` [m] (casadi; ``f.map(M)`` for batches).

    A cubic tensor B-spline whose control points are the samples of the environment's signed distance field
    (``env._grid``, cell h = ``env.resolution``) on uniform knots centred on the samples: nothing is fitted, so it is
    built instantly. This quasi-interpolant reproduces bilinear functions; elsewhere it is a local weighted mean of the
    samples (weights ≥ 0, second moment 2h²/3), so it lies *below* the field at the field's kinks in free space (the
    distance to a union is a minimum of distances: concave there) and above it by at most κh²/3 where the field is
    smooth with curvature κ ≤ 1/r (1.7 mm for h = 5 cm, r = 0.5 m). Measured against the exact (shapely) clearance
    within 0.5 m of the obstacles of A–D: overestimate ≤ 9 mm (99.9 % ≤ 2.7 mm).

    It is wrapped with ``never_inline`` so that an SX-expanded NLP keeps it as a call node (the B-spline node has no SX
    form). In the NLP the same spline is evaluated by :class:`ClearanceSpline` (see
    :class:`tmr.control.horizon_model._Transcription`).
    """
    kx, ky, d = spline_tables(env)
    spline = ca.Function.bspline("clearance_spline", [kx, ky], d.ravel(order="F").tolist(), [3, 3], 1, {})
    p = ca.MX.sym("p", 2, 1)
    return ca.Function("clearance", [p], [spline(p)], {"never_inline": True})


def _cubic_basis(u: Array) -> tuple[Array, Array, Array]:
    """The four uniform cubic B-spline pieces at local coordinates ``u`` (n,) and their first and second derivatives
    in u, each (n, 4), for the control points j−3 … j of cell j (de Boor 1978, uniform knots)."""
    u2 = u * u
    u3 = u2 * u
    v = 1.0 - u
    B = np.stack([v * v * v, 3.0 * u3 - 6.0 * u2 + 4.0, -3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0, u3], axis=-1) / 6.0
    dB = np.stack([-v * v, 3.0 * u2 - 4.0 * u, -3.0 * u2 + 2.0 * u + 1.0, u2], axis=-1) / 2.0
    ddB = np.stack([v, 3.0 * u - 2.0, -3.0 * u + 1.0, u], axis=-1)
    return B, dB, ddB


_THIRD = np.array([-1.0, 3.0, -3.0, 1.0])  # d³/du³ of the four pieces of :func:`_cubic_basis`


class ClearanceSpline:
    """The spline of :func:`distance_spline` with its derivatives, evaluated in numpy.

    ``evaluate(P (2, n))`` returns (c, ∂c/∂x, ∂c/∂y, ∂²c/∂x², ∂²c/∂x∂y, ∂²c/∂y²), each (n,) [m, 1, 1/m], from one
    gather of each point's 4 × 4 control points. Its values are casadi's B-spline's (to rounding): the polynomial
    piece of the nearest valid cell extends over the outer three cells of the knot box (de Boor's rule at the ends),
    and outside the knot box [t_0, t_last]² everything is 0. Its derivatives are those of these values (scipy's
    ``NdBSpline``'s); casadi's own automatic ones differ in the outer cells (0 in [t_0, t_1) for the gradient, in
    [t_0, t_2) for the Hessian), a band more than two cells outside the environment's bounds.
    """

    def __init__(self, env: Any) -> None:
        kx, ky, d = spline_tables(env)
        self.coef = np.ascontiguousarray(d)
        self.nx, self.ny = d.shape
        self.h = float(env.resolution)
        self.x0, self.y0 = kx[0], ky[0]  # first knots [m]
        self.box = np.array([[kx[0], kx[-1]], [ky[0], ky[-1]]])  # [[x_lo, x_hi], [y_lo, y_hi]] [m]
        a = np.arange(4)
        self._offsets = (a[:, None] * self.ny + a[None, :]).ravel()  # the 4 × 4 patch in the flat coefficients

    def evaluate(self, P: Array, third: bool = False) -> tuple[Array, ...]:
        """Value, gradient and Hessian entries of the spline at the points ``P`` (2, n) [m] (see the class); with
        ``third`` the third derivatives (c_xxx, c_xxy, c_xyy, c_yyy) [1/m²] instead."""
        P = np.asarray(P, dtype=float)
        h = self.h
        sx = (P[0] - self.x0) / h
        sy = (P[1] - self.y0) / h
        inside = (P[0] >= self.box[0, 0]) & (P[0] <= self.box[0, 1]) & (P[1] >= self.box[1, 0])
        inside &= P[1] <= self.box[1, 1]
        # cell j spans knots j … j+1; the valid ones are 3 … n−1 (the others extend their nearest valid neighbour)
        jx = np.clip(np.floor(np.where(inside, sx, 3.0)), 3, self.nx - 1).astype(np.intp)
        jy = np.clip(np.floor(np.where(inside, sy, 3.0)), 3, self.ny - 1).astype(np.intp)
        Bx, dBx, ddBx = _cubic_basis(sx - jx)
        By, dBy, ddBy = _cubic_basis(sy - jy)
        first = (jx - 3) * self.ny + (jy - 3)
        patch = self.coef.ravel()[first[:, None] + self._offsets].reshape(-1, 4, 4)
        t0 = np.einsum("nab,nb->na", patch, By)
        t1 = np.einsum("nab,nb->na", patch, dBy)
        t2 = np.einsum("nab,nb->na", patch, ddBy)
        if third:  # the third derivative of each cubic piece in u is constant
            d3 = np.broadcast_to(_THIRD, Bx.shape)
            t3 = np.einsum("nab,nb->na", patch, d3)
            h3 = h * h * h
            out = tuple(np.einsum("na,na->n", a, b) / h3 for a, b in ((d3, t0), (ddBx, t1), (dBx, t2), (Bx, t3)))
        else:
            out = (
                np.einsum("na,na->n", Bx, t0),
                np.einsum("na,na->n", dBx, t0) / h,
                np.einsum("na,na->n", Bx, t1) / h,
                np.einsum("na,na->n", ddBx, t0) / (h * h),
                np.einsum("na,na->n", dBx, t1) / (h * h),
                np.einsum("na,na->n", Bx, t2) / (h * h),
            )
        if not inside.all():
            for o in out:
                o[~inside] = 0.0
        return out


def _diagonal_sparsity(n: int) -> ca.Sparsity:
    """Jacobian pattern of n values (1, n) of point i in the points (2, n): entries (i, 2i) and (i, 2i + 1)."""
    i = np.arange(n)
    return ca.Sparsity.triplet(n, 2 * n, np.repeat(i, 2).tolist(), np.arange(2 * n).tolist())


class _SplineNode(ca.Callback):
    """A casadi node of :class:`ClearanceSpline` at n points, reading from and writing to casadi's own buffers (no
    conversion): ``P (2, n) ->`` the outputs of :meth:`ClearanceSpline.evaluate` (``third``: the third derivatives),
    each (1, n). The last evaluation is kept and reused while the points are the same."""

    def __init__(self, name: str, spline: ClearanceSpline, n: int, third: bool = False) -> None:
        ca.Callback.__init__(self)
        self.spline, self.n, self.third = spline, int(n), third
        self._last: tuple[Array, tuple[Array, ...]] | None = None
        self.evaluations = 0  # how many times the spline was evaluated (not served from the last evaluation)
        self.construct(name, {})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 4 if self.third else 6

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(2, self.n)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(1, self.n)

    def has_jac_sparsity(self, oind: int, iind: int) -> bool:
        return True

    def get_jac_sparsity(self, oind: int, iind: int, symmetric: bool) -> ca.Sparsity:
        return _diagonal_sparsity(self.n)

    def has_eval_buffer(self) -> bool:
        return True

    def eval_buffer(self, arg: list[Any], res: list[Any]) -> int:
        pts = np.frombuffer(arg[0], dtype=float).reshape(self.n, 2).T  # column-major (2, n)
        if self._last is None or not np.array_equal(self._last[0], pts):
            self._last = (pts.copy(), self.spline.evaluate(pts, third=self.third))
            self.evaluations += 1
        for buf, value in zip(res, self._last[1], strict=True):
            if buf is not None:  # None: that output is not needed by the caller
                np.frombuffer(buf, dtype=float)[:] = value
        return 0


class SplineRows(_SplineNode):
    """casadi node ``P (2, n) -> (c, c_x, c_y, c_xx, c_xy, c_yy)``, each (1, n): the clearance spline and its
    derivatives at n points (:meth:`ClearanceSpline.evaluate`). IPOPT evaluates the rows, their Jacobian and the
    Lagrangian's Hessian at the same iterate one after the other: the spline is evaluated once for the three. The
    NLP's Jacobian and Hessian are assembled from its outputs (:class:`tmr.control.horizon_model._Transcription`);
    casadi's reverse mode (which it asks for to build the multipliers' gradient) is exact, with the third derivatives
    from a second node."""

    def __init__(self, spline: ClearanceSpline, n: int) -> None:
        super().__init__(f"clearance_rows_{n}", spline, n)
        self._reverse: list[Any] = []  # the reverse-mode nodes must outlive the functions that call them

    def has_reverse(self, nadj: int) -> bool:
        return nadj == 1

    def get_reverse(self, nadj: int, name: str, inames: list[str], onames: list[str], opts: dict) -> ca.Function:
        n = self.n
        P = ca.MX.sym("P", 2, n)
        outs = [ca.MX.sym(f"o{i}", 1, n) for i in range(6)]
        seeds = [ca.MX.sym(f"s{i}", 1, n) for i in range(6)]
        third = _SplineNode(f"clearance_third_{n}", self.spline, n, third=True)
        self._reverse.append(third)
        _, cx, cy, cxx, cxy, cyy = outs
        cxxx, cxxy, cxyy, cyyy = third(P)
        a, ax, ay, axx, axy, ayy = seeds
        gx = a * cx + ax * cxx + ay * cxy + axx * cxxx + axy * cxxy + ayy * cxyy
        gy = a * cy + ax * cxy + ay * cyy + axx * cxxy + axy * cxyy + ayy * cyyy
        return ca.Function(name, [P, *outs, *seeds], [ca.vertcat(gx, gy)], inames, onames, opts)
