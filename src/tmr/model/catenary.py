"""Catenary model of a slack tether hanging between two robots (Caruso 2021 §4.2.1, eq. 22).

Each robot's winch exerts a constant tension, so the *horizontal* tension ``T0`` of every tether is known
and the cable takes the shape of a catenary with parameter ``c = T0 / (rho g)`` (Caruso 2021 eq. 22). In a
vertical plane through the two exit points, with end 1 at ``(0, h1)`` and end 2 at ``(span, h2)`` (heights
above the floor, metres):

    z(x) = z_low + c (cosh((x - x_low) / c) - 1)

The vertex ``(x_low, z_low)`` follows in closed form from the two end heights (``formulations/catenary.md``):

    x_low = span/2 - c asinh(dh / (2 c sinh(span / (2 c)))),   dh = h2 - h1.

The cable is inextensible; its length is whatever the winches pay out for the given span. The planner needs
the largest span ``d_max`` that keeps the lowest point of the cable above the floor (``max_span``), which is
the upper limit of the prismatic joints of the chain (Caruso 2021 §4.1, eq. 23).

Everything is in SI units: metres, newtons, kilograms. ``solve`` and ``lowest_height`` broadcast over numpy
arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from tmr.errors import ParameterError

__all__ = [
    "G0",
    "CatenaryParams",
    "Catenary",
    "solve",
    "shape",
    "lowest_height",
    "max_span",
    "max_span_level",
    "max_span_slope",
    "height_at",
    "height_sensitivities",
    "tether_max_spans",
]

G0 = 9.81  # standard gravitational acceleration used by Caruso 2021 [m/s^2]


@dataclass(frozen=True)
class CatenaryParams:
    """Physical parameters of a tether (defaults: Caruso 2021 §4.2.1).

    Attributes:
        horizontal_tension: T0 [N], horizontal tension imposed by the winch. Default 13.5 N = pulley resisting
            torque 1.35 N m / pulley radius 0.1 m.
        mass_per_length: rho [kg/m], linear mass of the cable ("specific weight" in the paper), default
            0.15 kg/m.
        g: gravitational acceleration [m/s^2], default 9.81.
        end_height: H [m], height above the floor where the tether leaves each robot, default 0.43 m.
        base_height: height of the fixed anchor of the first tether [m], default 0.43 m.
        ground_clearance: the lowest point of a cable must stay at or above this height [m], default 0
            (touching the floor is the limit, as in the paper).

    Raises:
        ParameterError: a value is not a finite real number, T0, rho, g or a height is <= 0, the clearance is
            < 0, or the clearance is not below both heights.
    """

    horizontal_tension: float = 13.5
    mass_per_length: float = 0.15
    g: float = G0
    end_height: float = 0.43
    base_height: float = 0.43
    ground_clearance: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ParameterError(
                    f"CatenaryParams.{f.name} must be a real number, got {value!r} ({type(value).__name__})"
                )
            value = float(value)
            if not math.isfinite(value):
                raise ParameterError(f"CatenaryParams.{f.name} must be finite, got {value!r}")
            object.__setattr__(self, f.name, value)
        units = {
            "horizontal_tension": "N",
            "mass_per_length": "kg/m",
            "g": "m/s^2",
            "end_height": "m",
            "base_height": "m",
        }
        for name, unit in units.items():
            value = getattr(self, name)
            if value <= 0.0:
                raise ParameterError(f"CatenaryParams.{name} must be > 0 {unit}, got {value!r}")
        if self.ground_clearance < 0.0:
            raise ParameterError(f"CatenaryParams.ground_clearance must be >= 0 m, got {self.ground_clearance!r}")
        lowest_end = min(self.end_height, self.base_height)
        if self.ground_clearance >= lowest_end:
            raise ParameterError(
                f"CatenaryParams.ground_clearance ({self.ground_clearance} m) must be below the end heights "
                f"(end_height={self.end_height} m, base_height={self.base_height} m), otherwise no cable can "
                "hang between the robots; lower the clearance or raise the exit heights"
            )

    @classmethod
    def from_pulley(cls, torque: float = 1.35, radius: float = 0.1, **kwargs: float) -> CatenaryParams:
        """Parameters with T0 = pulley resisting torque [N m] / pulley radius [m] (Caruso 2021 §4.2.1).

        The remaining fields are passed through ``kwargs``.
        """
        for name, value in (("torque", torque), ("radius", radius)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ParameterError(f"pulley {name} must be a finite number > 0, got {value!r}")
        return cls(horizontal_tension=torque / radius, **kwargs)

    @property
    def weight_per_length(self) -> float:
        """w = rho g, weight of one metre of cable [N/m]."""
        return self.mass_per_length * self.g

    @property
    def c(self) -> float:
        """Catenary parameter c = T0 / (rho g) [m] (Caruso 2021 eq. 22), radius of curvature at the vertex."""
        return self.horizontal_tension / (self.mass_per_length * self.g)


class Catenary(NamedTuple):
    """Shape and forces of a cable hanging between end 1 at (0, h1) and end 2 at (span, h2).

    Every field is a float, or an ndarray of the broadcast shape of ``solve``'s inputs. Horizontal positions
    are measured from end 1 towards end 2 along the span; heights are above the floor.

    Fields:
        c: catenary parameter T0 / (rho g) [m].
        span: horizontal distance between the ends [m].
        h1, h2: heights of end 1 and end 2 [m].
        x_low: horizontal position of the vertex of the catenary [m]; may lie outside [0, span] (then the
            cable rises monotonically from its lower end).
        z_low: height of the vertex [m] (below the cable when the vertex lies outside the span).
        x_min, z_min: lowest point of the cable itself over [0, span] [m] (the vertex, or the lower end).
        sag: largest vertical distance between the chord joining the ends and the cable [m] (mid-span sag for
            level ends).
        length: cable length between the ends [m].
        horizontal_tension: T0 [N], the same all along the cable.
        tension_1, tension_2: magnitude of the cable tension at end 1 and end 2 [N], T0 cosh((x - x_low)/c).
        vertical_1, vertical_2: vertical component of the force the cable exerts on end 1 / end 2, positive
            downwards [N]; vertical_1 + vertical_2 = rho g length. Negative when the vertex lies beyond that
            end (the cable pulls it up).
        slope_1, slope_2: dz/dx of the cable at end 1 and end 2 [-].
    """

    c: float | np.ndarray
    span: float | np.ndarray
    h1: float | np.ndarray
    h2: float | np.ndarray
    x_low: float | np.ndarray
    z_low: float | np.ndarray
    x_min: float | np.ndarray
    z_min: float | np.ndarray
    sag: float | np.ndarray
    length: float | np.ndarray
    horizontal_tension: float | np.ndarray
    tension_1: float | np.ndarray
    tension_2: float | np.ndarray
    vertical_1: float | np.ndarray
    vertical_2: float | np.ndarray
    slope_1: float | np.ndarray
    slope_2: float | np.ndarray


_DEFAULT_PARAMS = CatenaryParams()


def _as_finite(name: str, value: ArrayLike) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a real number or array of real numbers, got {value!r}") from exc
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} must be finite, got {value!r}")
    return arr


def _out(arr: np.ndarray) -> float | np.ndarray:
    """0-d arrays become Python floats, others stay arrays."""
    return float(arr) if arr.ndim == 0 else arr


def _cosh_m1(u: np.ndarray) -> np.ndarray:
    """cosh(u) - 1 without cancellation for small u."""
    return 2.0 * np.sinh(0.5 * u) ** 2


def _vertex(h1: np.ndarray, h2: np.ndarray, span: np.ndarray, c: float) -> np.ndarray:
    """x_low = span/2 - c asinh((h2 - h1) / (2 c sinh(span / 2c))), valid for span > 0."""
    return 0.5 * span - c * np.arcsinh((h2 - h1) / (2.0 * c * np.sinh(span / (2.0 * c))))


def _tension_and_c(params: CatenaryParams, tension: ArrayLike | None) -> tuple[Any, Any]:
    """(T0, c) of ``params``, or of a horizontal tension ``tension`` [N] per element (an active winch), c = T0/(ρ g)
    elementwise by the same arithmetic as :attr:`CatenaryParams.c`."""
    if tension is None:
        return params.horizontal_tension, params.c
    t0 = _as_finite("tension", tension)
    if np.any(t0 <= 0.0):
        raise ParameterError(f"tension must be > 0 N, got {tension!r}")
    return t0, t0 / (params.mass_per_length * params.g)


def solve(
    h1: ArrayLike,
    h2: ArrayLike,
    span: ArrayLike,
    params: CatenaryParams = _DEFAULT_PARAMS,
    *,
    tension: ArrayLike | None = None,
) -> Catenary:
    """Closed-form catenary of an inextensible cable with known horizontal tension (Caruso 2021 eq. 22).

    Args:
        h1: height of end 1 above the floor [m].
        h2: height of end 2 above the floor [m].
        span: horizontal distance from end 1 to end 2 [m], > 0.
        params: cable parameters (T0, rho, g).
        tension: a horizontal tension per element [N] in place of ``params``' T0 (an active winch's plan).

    The inputs broadcast with numpy rules; the fields of the result have the broadcast shape (floats for scalar
    inputs; ``c`` and ``horizontal_tension`` are arrays only with an array ``tension``).

    Returns:
        Catenary: vertex, lowest point, sag, length, end tensions and their vertical components.

    Raises:
        ParameterError: a non-finite input or a span <= 0 (a zero span is a vertical cable, not a catenary).
    """
    h1a = _as_finite("h1", h1)
    h2a = _as_finite("h2", h2)
    sa = _as_finite("span", span)
    if np.any(sa <= 0.0):
        raise ParameterError(f"span must be > 0 m for a catenary, got {span!r}")
    t0, c = _tension_and_c(params, tension)
    h1a, h2a, sa = np.broadcast_arrays(h1a, h2a, sa)
    if tension is not None:
        h1a, h2a, sa, t0, c = np.broadcast_arrays(h1a, h2a, sa, t0, c)
    dh = h2a - h1a

    x_low = _vertex(h1a, h2a, sa, c)
    u1 = -x_low / c  # (0 - x_low) / c
    u2 = (sa - x_low) / c
    z_low = h1a - c * _cosh_m1(u1)

    inside = (x_low >= 0.0) & (x_low <= sa)
    lower_is_1 = h1a <= h2a
    x_min = np.where(inside, x_low, np.where(lower_is_1, 0.0, sa))
    z_min = np.where(inside, z_low, np.minimum(h1a, h2a))

    # sag: the chord-minus-cable distance is largest where the cable slope equals the chord slope dh/span
    x_star = x_low + c * np.arcsinh(dh / sa)
    z_star = z_low + c * _cosh_m1((x_star - x_low) / c)
    sag = h1a + dh * x_star / sa - z_star

    # L = c (sinh(u2) - sinh(u1)) = sqrt(dh^2 + (2 c sinh(span / 2c))^2), the second form avoids cancellation
    length = np.hypot(dh, 2.0 * c * np.sinh(sa / (2.0 * c)))

    slope_1 = np.sinh(u1)
    slope_2 = np.sinh(u2)
    return Catenary(
        c=c if tension is None else _out(c),
        span=_out(sa),
        h1=_out(h1a),
        h2=_out(h2a),
        x_low=_out(x_low),
        z_low=_out(z_low),
        x_min=_out(x_min),
        z_min=_out(z_min),
        sag=_out(sag),
        length=_out(length),
        horizontal_tension=t0 if tension is None else _out(t0),
        tension_1=_out(t0 * np.cosh(u1)),
        tension_2=_out(t0 * np.cosh(u2)),
        vertical_1=_out(-t0 * slope_1),
        vertical_2=_out(t0 * slope_2),
        slope_1=_out(slope_1),
        slope_2=_out(slope_2),
    )


def shape(cat: Catenary, n: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Points of the cable curve, evenly spaced in x from end 1 to end 2.

    Args:
        cat: result of ``solve`` (scalar or broadcast).
        n: number of points (>= 2), both ends included.

    Returns:
        (x, z): horizontal positions from end 1 and heights [m], each of shape ``cat.span.shape + (n,)``.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ParameterError(f"shape needs an integer number of points n >= 2, got {n!r}")
    t = np.linspace(0.0, 1.0, int(n))
    span = np.asarray(cat.span, dtype=float)[..., None]
    x_low = np.asarray(cat.x_low, dtype=float)[..., None]
    z_low = np.asarray(cat.z_low, dtype=float)[..., None]
    x = span * t
    c = cat.c if np.ndim(cat.c) == 0 else np.asarray(cat.c, dtype=float)[..., None]  # a tension per element
    z = z_low + c * _cosh_m1((x - x_low) / c)
    x, z = np.broadcast_arrays(x, z)
    return np.array(x), np.array(z)


def lowest_height(
    h1: ArrayLike,
    h2: ArrayLike,
    span: ArrayLike,
    params: CatenaryParams = _DEFAULT_PARAMS,
    *,
    tension: ArrayLike | None = None,
) -> float | np.ndarray:
    """Height of the lowest point of the cable over [0, span] [m] (vectorised, broadcasts like ``solve``, its
    ``tension`` too).

    A span of 0 gives min(h1, h2). Non-increasing in the span: constant while the vertex lies beyond the lower
    end, strictly decreasing once it enters the span.

    Raises:
        ParameterError: non-finite input or negative span.
    """
    h1a = _as_finite("h1", h1)
    h2a = _as_finite("h2", h2)
    sa = _as_finite("span", span)
    if np.any(sa < 0.0):
        raise ParameterError(f"span must be >= 0 m, got {span!r}")
    _, c = _tension_and_c(params, tension)
    h1a, h2a, sa = np.broadcast_arrays(h1a, h2a, sa)
    if tension is not None:
        h1a, h2a, sa, c = np.broadcast_arrays(h1a, h2a, sa, c)
    zero = sa == 0.0
    s_safe = np.where(zero, 1.0, sa)
    x_low = _vertex(h1a, h2a, s_safe, c)
    z_low = h1a - c * _cosh_m1(x_low / c)
    inside = (x_low >= 0.0) & (x_low <= s_safe) & ~zero
    return _out(np.where(inside, z_low, np.minimum(h1a, h2a)))


def _height_or_default(name: str, value: float | None, default: float) -> float:
    if value is None:
        return default
    arr = _as_finite(name, value)
    if arr.ndim != 0:
        raise ParameterError(f"{name} must be a scalar height [m], got an array of shape {arr.shape}")
    return float(arr)


def max_span_level(h: float | None = None, params: CatenaryParams = _DEFAULT_PARAMS) -> float:
    """Closed-form largest span for two ends at the same height h [m] (Caruso 2021 eq. 22 solved for x).

    d_max = 2 c acosh(1 + (h - clearance) / c). ``h`` defaults to ``params.end_height``.
    """
    hh = _height_or_default("h", h, params.end_height)
    drop = hh - params.ground_clearance
    if drop < 0.0:
        raise ParameterError(
            f"end height {hh} m is below the ground clearance {params.ground_clearance} m: no span keeps the "
            "cable above it"
        )
    c = params.c
    return float(2.0 * c * np.arccosh(1.0 + drop / c))


def max_span(
    h1: float | None = None,
    h2: float | None = None,
    params: CatenaryParams = _DEFAULT_PARAMS,
    *,
    xtol: float = 1e-12,
) -> float:
    """Largest horizontal span [m] keeping the lowest point of the cable >= ``params.ground_clearance``.

    This is d_max of Caruso 2021 §4.2.1 (upper limit of the prismatic joints). Solved with
    ``scipy.optimize.brentq`` on ``lowest_height(h1, h2, span) - clearance``; for equal heights it equals
    ``max_span_level``.

    Args:
        h1: height of end 1 [m], default ``params.end_height`` (pass ``params.base_height`` for the base
            tether).
        h2: height of end 2 [m], default ``params.end_height``.
        params: cable parameters.
        xtol: absolute tolerance on the span [m].

    Returns:
        d_max [m]. With the defaults (H = 0.43 m, T0 = 13.5 N, 0.15 kg/m, g = 9.81) it is 5.596 m; the paper
        states 5.84 m (see formulations/catenary.md).

    Raises:
        ParameterError: an end below the clearance.
    """
    a = _height_or_default("h1", h1, params.end_height)
    b = _height_or_default("h2", h2, params.end_height)
    clr = params.ground_clearance
    lo_end, hi_end = min(a, b), max(a, b)
    if lo_end < clr:
        raise ParameterError(
            f"end height {lo_end} m is below the ground clearance {clr} m: no span keeps the cable above it; "
            "raise the end or lower CatenaryParams.ground_clearance"
        )
    c = params.c
    if lo_end == clr:
        # the cable rises from its lower end until the vertex reaches it: h_hi - h_lo = c (cosh(d/c) - 1)
        return float(c * np.arccosh(1.0 + (hi_end - lo_end) / c))

    if a == b:  # the vertex is mid-span: closed form (and no scipy.optimize import, ~0.1 s, for a CLI refusal)
        return max_span_level(a, params)

    def f(s: float) -> float:
        return float(lowest_height(a, b, s, params)) - clr

    # upper bracket: with both ends at h_hi the lowest point is higher than with one end lowered
    # (formulations/catenary.md)
    # (a little more so that rounding at equal heights cannot leave f(hi) at +1e-17)
    hi = 1.001 * max_span_level(hi_end, params) + 1e-9
    for _ in range(60):
        if f(hi) <= 0.0:
            break
        hi *= 2.0
    else:  # pragma: no cover - lowest_height -> -inf as span -> inf, so this cannot happen for finite inputs
        raise ParameterError(f"could not bracket the maximum span for h1={a}, h2={b}")
    from scipy.optimize import brentq  # imported here: scipy.optimize costs ~0.1 s to import

    return float(brentq(f, 0.0, hi, xtol=xtol, rtol=4.0 * np.finfo(float).eps))


def max_span_slope(
    h1: float | None = None, h2: float | None = None, params: CatenaryParams = _DEFAULT_PARAMS
) -> tuple[float, float]:
    """d_max [m] (:func:`max_span`) and its derivative with respect to the horizontal tension, ∂d_max/∂T0 [m/N].

    The active winch's span limit ``d ≤ d_max(T0)`` is linearised with it (``formulations/catenary.md``, "Active
    winch"). For level ends d_max = 2c acosh(1 + δ/c) with c = T0/w, δ = h − clearance, so

        ∂d_max/∂T0 = (2 acosh(1 + δ/c) − 2δ / (c √((1 + δ/c)² − 1))) / w,

    positive: a taut cable spans farther. For ends at different heights d_max has no closed form: the slope is a
    central difference of :func:`max_span` (solved to 1e-12 m) with a step of 1e-4 T0 (relative error ~1e-7).
    """
    a = _height_or_default("h1", h1, params.end_height)
    b = _height_or_default("h2", h2, params.end_height)
    d = max_span(a, b, params)
    w = params.weight_per_length
    c = params.c
    if a == b:
        r = 1.0 + (a - params.ground_clearance) / c
        root = math.sqrt(r * r - 1.0)
        if root == 0.0:  # an end on the clearance: no span at any tension
            return d, 0.0
        return d, (2.0 * math.acosh(r) - 2.0 * (r - 1.0) / root) / w
    h = 1e-4 * params.horizontal_tension
    up = max_span(a, b, replace(params, horizontal_tension=params.horizontal_tension + h))
    down = max_span(a, b, replace(params, horizontal_tension=params.horizontal_tension - h))
    return d, (up - down) / (2.0 * h)


def tension_for_span(
    span: float, h1: float | None, h2: float | None, params: CatenaryParams, t_min: float, t_max: float
) -> float | None:
    """The least horizontal tension T0 in [t_min, t_max] [N] whose d_max is ≥ ``span`` [m] (the other fields from
    ``params``), or None if even t_max is too slack. d_max grows with T0, so it is a bracketed root
    (``scipy.optimize.brentq``, 1e-9 N)."""
    a = _height_or_default("h1", h1, params.end_height)
    b = _height_or_default("h2", h2, params.end_height)

    def reach(t: float) -> float:
        return max_span(a, b, replace(params, horizontal_tension=t)) - span

    if reach(t_min) >= 0.0:
        return float(t_min)
    if reach(t_max) < 0.0:
        return None
    from scipy.optimize import brentq

    t = float(brentq(reach, t_min, t_max, xtol=1e-9))
    return t if reach(t) >= 0.0 else min(t + 1e-9, t_max)


def height_at(s: ArrayLike, h1: ArrayLike, h2: ArrayLike, span: ArrayLike, c: ArrayLike) -> np.ndarray:
    """Height [m] of the cable at the fraction ``s`` of its span (x = s · span from end 1), for catenary parameter
    ``c`` = T0 / (ρ g) [m]: z(x) = h1 + c (cosh((x − x_low)/c) − cosh(x_low/c)), written as
    h1 + 2c sinh(x / 2c) sinh((x − 2 x_low) / 2c) (no cancellation). Broadcasts, and takes complex inputs: the
    complex-step derivatives of :func:`height_sensitivities` evaluate it off the real axis."""
    s, h1, h2, span, c = (np.asarray(v) for v in (s, h1, h2, span, c))
    x = s * span
    x_low = 0.5 * span - c * np.arcsinh((h2 - h1) / (2.0 * c * np.sinh(span / (2.0 * c))))
    return h1 + 2.0 * c * np.sinh(x / (2.0 * c)) * np.sinh((x - 2.0 * x_low) / (2.0 * c))


def height_sensitivities(
    s: ArrayLike, h1: ArrayLike, h2: ArrayLike, span: ArrayLike, tension: ArrayLike, weight: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cable's height z [m] at fraction ``s`` of its span (:func:`height_at`), ∂z/∂span [m/m] (the fraction
    held) and ∂z/∂T0 [m/N], for horizontal tension ``tension`` [N] and weight per length ``weight`` = ρ g [N/m].

    The derivatives are complex-step derivatives of the closed form (Im f(x + i h) / h, h = 1e-30: exact to rounding,
    no difference of two values); ∂z/∂T0 = ∂z/∂c / (ρ g).
    """
    h = 1e-30
    c = np.asarray(tension, dtype=float) / weight
    span = np.asarray(span, dtype=float)
    z = height_at(s, h1, h2, span, c)
    dz_dspan = height_at(s, h1, h2, span + 1j * h, c).imag / h
    dz_dc = height_at(s, h1, h2, span, c + 1j * h).imag / h
    return np.real(z), dz_dspan, dz_dc / weight


def tether_max_spans(n_tethers: int, params: CatenaryParams = _DEFAULT_PARAMS) -> np.ndarray:
    """d_max [m] of every tether of a chain: tether 1 hangs from the base anchor (``base_height``) to robot 1,
    tether j > 1 between robots j-1 and j (both at ``end_height``).

    Returns:
        ndarray (n_tethers,).
    """
    if isinstance(n_tethers, bool) or not isinstance(n_tethers, (int, np.integer)) or n_tethers < 1:
        raise ParameterError(f"n_tethers must be an integer >= 1, got {n_tethers!r}")
    first = max_span(params.base_height, params.end_height, params)
    rest = max_span(params.end_height, params.end_height, params)
    out = np.full(int(n_tethers), rest)
    out[0] = first
    return out
