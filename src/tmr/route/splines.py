"""Piecewise-cubic interpolants for the leader's time law (:func:`tmr.route.path.time_law`).

Two textbook interpolants in Hermite form (de Boor, *A Practical Guide to Splines*, 2001, ch. IV):

* :class:`NotAKnotSpline`: the C² cubic spline through vector-valued points with the not-a-knot end conditions
  (the third derivative is continuous at the second and the second-to-last knot). Its knot slopes solve one
  tridiagonal system; it is the same function as scipy's ``make_interp_spline(x, y, k=3)`` and
  ``CubicSpline(x, y)`` (``tests/test_splines.py`` checks both to 1e-10).
* :class:`HermiteSpline`: the C¹ piecewise cubic with given values and slopes at the knots (scipy's
  ``CubicHermiteSpline``).

They live here, not in ``scipy.interpolate``, for one reason: importing ``scipy.interpolate`` takes 0.3–0.45 s
(it loads scipy.special, scipy.optimize and scipy.stats), a third of a whole ``tmr.plan`` run
(``benchmarks/results/end_to_end.md``), and the time law is on every run's path. Evaluation is vectorised
(``searchsorted`` and Horner), so the leader's arc-length tables cost no more than with scipy.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ParameterError

Array = NDArray[np.float64]

__all__ = ["HermiteSpline", "NotAKnotSpline"]


class HermiteSpline:
    """Piecewise cubic with values ``y`` and slopes ``dydx`` at the strictly increasing knots ``x``.

    On [x_i, x_{i+1}], with t = x − x_i and h = x_{i+1} − x_i:
    p(x) = y_i + m_i t + c_i t² + d_i t³, c_i = (3 δ_i − 2 m_i − m_{i+1}) / h, d_i = (m_i + m_{i+1} − 2 δ_i) / h²,
    δ_i = (y_{i+1} − y_i) / h. Outside [x_0, x_{n−1}] the end pieces extend (as scipy's ``extrapolate=True``).

    Args:
        x: (n,) knots, n ≥ 2, strictly increasing.
        y: (n,) or (n, d) values at the knots.
        dydx: slopes at the knots, same shape as ``y``.
    """

    def __init__(self, x: ArrayLike, y: ArrayLike, dydx: ArrayLike) -> None:
        self.x = np.asarray(x, dtype=float)
        y_arr = np.asarray(y, dtype=float)
        m = np.asarray(dydx, dtype=float)
        if self.x.ndim != 1 or self.x.size < 2 or y_arr.shape[:1] != self.x.shape or m.shape != y_arr.shape:
            raise ParameterError(
                f"knots {self.x.shape}, values {y_arr.shape} and slopes {m.shape} must share a first axis of n >= 2"
            )
        h = np.diff(self.x)
        if not np.all(h > 0.0):
            raise ParameterError("spline knots must be strictly increasing")
        self._scalar = y_arr.ndim == 1
        y2 = y_arr.reshape(len(self.x), -1)
        m2 = m.reshape(len(self.x), -1)
        hc = h[:, None]
        delta = np.diff(y2, axis=0) / hc
        # coefficients of t^0 .. t^3 on each interval, shape (4, n - 1, d)
        self._c = np.stack(
            [
                y2[:-1],
                m2[:-1],
                (3.0 * delta - 2.0 * m2[:-1] - m2[1:]) / hc,
                (m2[:-1] + m2[1:] - 2.0 * delta) / (hc * hc),
            ]
        )

    def __call__(self, u: ArrayLike, nu: int = 0) -> Array:
        """Value (``nu`` = 0) or derivative of order ``nu`` ∈ {1, 2} at ``u``; shape ``u.shape`` (+ (d,))."""
        u_arr = np.asarray(u, dtype=float)
        flat = u_arr.ravel()
        i = np.clip(np.searchsorted(self.x, flat, side="right") - 1, 0, len(self.x) - 2)
        t = (flat - self.x[i])[:, None]
        c0, c1, c2, c3 = self._c[:, i]
        if nu == 0:
            out = c0 + t * (c1 + t * (c2 + t * c3))
        elif nu == 1:
            out = c1 + t * (2.0 * c2 + t * (3.0 * c3))
        elif nu == 2:
            out = 2.0 * c2 + t * (6.0 * c3)
        else:
            raise ParameterError(f"derivative order must be 0, 1 or 2, got {nu!r}")
        return out.reshape(u_arr.shape) if self._scalar else out.reshape(*u_arr.shape, -1)


class NotAKnotSpline(HermiteSpline):
    """C² cubic interpolating spline through ``y`` at the knots ``x`` with not-a-knot end conditions.

    The slopes m solve, for the interior knots (continuity of the second derivative),
    h_i m_{i−1} + 2 (h_{i−1} + h_i) m_i + h_{i−1} m_{i+1} = 3 (h_i δ_{i−1} + h_{i−1} δ_i),
    and at the ends (continuity of the third derivative at x_1 and x_{n−2}; de Boor 2001, eq. IV.(10)–(11))
    h_1 m_0 + (h_0 + h_1) m_1 = ((h_0 + 2 (h_0 + h_1)) h_1 δ_0 + h_0² δ_1) / (h_0 + h_1) and its mirror image.

    Args:
        x: (n,) strictly increasing knots, n ≥ 4 (the not-a-knot conditions need two interior knots).
        y: (n,) or (n, d) values.
    """

    def __init__(self, x: ArrayLike, y: ArrayLike) -> None:
        from scipy.linalg import solve_banded  # scipy.linalg is already loaded by the QP (no import cost)

        xs = np.asarray(x, dtype=float)
        y_arr = np.asarray(y, dtype=float)
        n = xs.size
        if xs.ndim != 1 or n < 4 or y_arr.shape[:1] != xs.shape:
            raise ParameterError(f"a not-a-knot cubic needs n >= 4 knots and values of matching length, got {n}")
        h = np.diff(xs)
        if not np.all(h > 0.0):
            raise ParameterError("spline knots must be strictly increasing")
        y2 = y_arr.reshape(n, -1)
        delta = np.diff(y2, axis=0) / h[:, None]
        ab = np.zeros((3, n))  # banded storage: ab[0, 1:] super-, ab[1] main, ab[2, :-1] sub-diagonal
        rhs = np.empty_like(y2)
        ab[1, 1:-1] = 2.0 * (h[:-1] + h[1:])
        ab[0, 2:] = h[:-1]
        ab[2, :-2] = h[1:]
        rhs[1:-1] = 3.0 * (h[1:, None] * delta[:-1] + h[:-1, None] * delta[1:])
        s0, s1 = h[0] + h[1], h[-1] + h[-2]
        ab[1, 0], ab[0, 1] = h[1], s0
        rhs[0] = ((h[0] + 2.0 * s0) * h[1] * delta[0] + h[0] ** 2 * delta[1]) / s0
        ab[2, -2], ab[1, -1] = s1, h[-2]
        rhs[-1] = (h[-1] ** 2 * delta[-2] + (2.0 * s1 + h[-1]) * h[-2] * delta[-1]) / s1
        slopes = solve_banded((1, 1), ab, rhs, overwrite_ab=True, overwrite_b=True, check_finite=False)
        super().__init__(xs, y_arr, slopes.reshape(y_arr.shape))
