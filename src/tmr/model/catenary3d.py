"""Catenary model of a drone tether between two 3-D ends at different heights (Caruso 2021 §4.2.1 in 3-D).

The tether hangs in the vertical plane through its two ends. In that plane, with ``x`` the horizontal distance from
the *lower* end A towards the upper end B and ``z`` the height, the shape is the catenary (Irvine 1981, §1.2)

    z(x) = z0 + a (cosh((x - x0) / a) - 1),      a = H / (rho g),

and the tension at a point is ``T = H cosh((x - x0)/a) = rho g (a + z - z0)``: it grows with height, so
``T_B - T_A = rho g h`` with ``h = z_B - z_A``.

Which end is given. Caruso 2021 §4.2.1 models each winch as a pulley with a constant resisting torque T_r, i.e. a
constant tension T_w = T_r / r where the cable leaves the pulley. Here the winch sits by default at the LOWER end
of each tether (``winch_end="lower"``): the first tether's winch is the ground station (tethered multirotors reel
their tether at the ground), and for a drone-to-drone tether the spool is carried by the lower drone, so the upper
drone carries only cable. With the winch tension at the lower end, the upper end's tension is
``T_w + rho g h`` in closed form, whatever the span: the pull the upper drone must hold is known before the shape
is solved. ``winch_end="upper"`` is supported too (then ``T_A = T_w - rho g h`` must stay > 0). On level ends both
choices coincide. Unlike the ground model (``tmr.model.catenary``, where the winch fixes the *horizontal* tension
T0), the winch here fixes the tension *magnitude* at its end, and H follows from the geometry: on a near-vertical
tether H -> 0 while the tension stays T_w.

Solution. With theta = (x - x0)/a, theta_A = -x0/a at A and theta_B = theta_A + d/a at B, the two end tensions give
``a cosh(theta_A) = m = T_A/(rho g)`` and ``a cosh(theta_B) = m + h``. For a trial theta_A,
``a = m / cosh(theta_A)`` and ``sinh(theta_B) = sqrt(k^2 sinh^2(theta_A) + k^2 - 1)``, k = 1 + h/m, so the span is a
function ``d(theta_A)`` of one variable; ``brentq`` finds the root of ``d(theta_A) - d`` in a bracket found on a grid.
At a given end tension there are generally two equilibria (a shallow and a deep sag); the solver returns the shallow
one, the branch joined continuously to the taut limit (theta_A -> +inf). Only that one is stable under a
constant-tension winch: with Pi(L) = rho g \\int z ds + T_w L, dPi/dL = T_w - T_A(L), and on the shallow branch the end
tension falls as the paid-out length L grows (a perturbation is pulled back), on the deep branch it rises. If the
span exceeds the largest span the tension can hold (the maximum of d(theta_A)), ``TetherSpanError`` is raised.

Everything in SI units: metres, newtons, kilograms; z is the height above the floor (z = 0).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, fields

import numpy as np
from numpy.typing import ArrayLike

from tmr.errors import ParameterError, TetherSpanError, fmt_point
from tmr.model.catenary import G0
from tmr.model.params import _validate

__all__ = [
    "DroneTetherParams",
    "Catenary3D",
    "CatenarySensitivity",
    "solve3d",
    "solve3d_batch",
    "TetherCatenaries",
    "sensitivities",
    "sensitivities_batch",
    "TetherSensitivities",
    "theta_lower",
    "tether_limits",
    "VERTICAL_SPAN",
    "WINCH_MODES",
    "WINCH_FIELDS",
]

#: ``DroneTetherParams.winch``: every winch at the constant tension ``winch_tension``, or its tension a decision
WINCH_MODES = ("constant", "active")
#: the active winch's fields (left out of the records of a constant-tension plan: :meth:`DroneTetherParams.as_dict`)
WINCH_FIELDS = ("winch", "winch_tension_min", "winch_tension_max", "winch_tension_rate")

VERTICAL_SPAN = 1e-9  # horizontal spans below this [m] are a vertical tether (no catenary, a = None)

_GRID = np.linspace(-40.0, 40.0, 4001)  # trial theta_A values for the bracket (cosh(40) ~ 1.2e17 stays finite)


@dataclass(frozen=True)
class DroneTetherParams:
    """A light drone tether and a small quadrotor (defaults with their reasoning).

    Attributes:
        mass_per_length: rho [kg/m], default 0.015: a thin power/data micro-tether; tethers sold for small
            multirotors weigh on the order of 10-30 g/m (vs the ground robots' 0.15 kg/m, Caruso 2021).
        g: gravitational acceleration [m/s^2], 9.81.
        winch_tension: T_w [N], the constant tension the winch keeps at its end (Caruso 2021's constant pulley
            torque / pulley radius), default 2.0 N: about 14 % of the default drone's weight, and with
            rho g = 0.147 N/m a level span of up to 1.3255 T_w / (rho g) = 18.0 m.
        winch_end: ``"lower"`` (default) or ``"upper"``: the end of each tether where the winch acts (module doc).
        tether_length: longest cable a winch can pay out [m], default 20.0 m.
        clearance: c_t [m], the whole curve must stay at least this far from every obstacle and the floor,
            default 0.2 m.
        drone_mass: [kg], default 1.5 kg (a small quadrotor of the F450 / 5-inch-long-range class with battery).
        thrust_to_weight: total maximal thrust / weight [-], default 2.0 (the usual minimum for a controllable
            multirotor).
        control_reserve: fraction of the maximal thrust kept for attitude control and gusts [-], default 0.25.
        drone_radius: radius of the sphere enclosing the drone with its propellers [m], default 0.3 m.
        winch: ``"constant"`` (default: every winch keeps ``winch_tension``, Caruso 2021) or ``"active"``: each
            winch's pulley torque is controlled, so its tension T_w is a decision of the per-step QP within
            [``winch_tension_min``, ``winch_tension_max``], changing by at most ``winch_tension_rate`` per second,
            starting at ``winch_tension`` (``formulations/drones.md``, "Active winch"). Caruso 2021 §6 proposes it
            "to increase or decrease the tension acting on the cable … to overcome low height obstacles".
        winch_tension_min: T_min [N], default 0.5 N (an active winch; a quarter of the default T_w).
        winch_tension_max: T_max [N], default 6.0 N (an active winch; below the default spare thrust 7.36 N, so
            a drone holds the upper end of a tether rising ~9 m at T_max).
        winch_tension_rate: largest |dT_w/dt| [N/s], default 2.0 N/s (an active winch).

    Raises:
        ParameterError: a value is not a finite real number or is out of range.
    """

    mass_per_length: float = 0.015
    g: float = G0
    winch_tension: float = 2.0
    winch_end: str = "lower"
    tether_length: float = 20.0
    clearance: float = 0.2
    drone_mass: float = 1.5
    thrust_to_weight: float = 2.0
    control_reserve: float = 0.25
    drone_radius: float = 0.3
    winch: str = "constant"
    winch_tension_min: float = 0.5
    winch_tension_max: float = 6.0
    winch_tension_rate: float = 2.0

    def __post_init__(self) -> None:
        if self.winch_end not in ("lower", "upper"):
            raise ParameterError(f"DroneTetherParams.winch_end must be 'lower' or 'upper', got {self.winch_end!r}")
        if self.winch not in WINCH_MODES:
            raise ParameterError(f"DroneTetherParams.winch must be 'constant' or 'active', got {self.winch!r}")
        for f in fields(self):
            if f.name in ("winch_end", "winch"):
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ParameterError(f"DroneTetherParams.{f.name} must be a real number, got {value!r}")
            object.__setattr__(self, f.name, float(value))
        _validate(  # finite, and the ranges: the parameter classes' one check (tmr.model.params)
            self,
            positive=("mass_per_length", "g", "winch_tension", "tether_length", "drone_mass", "thrust_to_weight",
                      "winch_tension_min", "winch_tension_max", "winch_tension_rate"),
            nonnegative=("clearance", "drone_radius"),
        )  # fmt: skip
        if not 0.0 <= self.control_reserve < 1.0:
            raise ParameterError(f"DroneTetherParams.control_reserve must be in [0, 1), got {self.control_reserve!r}")
        if self.active and not self.winch_tension_min <= self.winch_tension <= self.winch_tension_max:
            raise ParameterError(
                "an active winch needs winch_tension_min <= winch_tension <= winch_tension_max, got "
                f"{self.winch_tension_min:g} <= {self.winch_tension:g} <= {self.winch_tension_max:g} N"
            )

    @property
    def active(self) -> bool:
        """Whether the winch tension is a decision of the planner (``winch = "active"``)."""
        return self.winch == "active"

    def as_dict(self) -> dict[str, object]:
        """The fields as a dict (``dataclasses.asdict``), without the active winch's four when ``winch`` is
        ``"constant"``: a constant-tension plan's records keep the bytes they had before the active winch."""
        out = asdict(self)
        if not self.active:
            for name in WINCH_FIELDS:
                out.pop(name)
        return out

    @property
    def weight_per_length(self) -> float:
        """rho g [N/m]."""
        return self.mass_per_length * self.g

    @property
    def drone_weight(self) -> float:
        """m g of a drone [N]."""
        return self.drone_mass * self.g

    @property
    def available_thrust(self) -> float:
        """Thrust a drone may use beyond its control reserve [N]: (1 − reserve) T/W m g (defaults: 22.07 N); it must
        hold |m g e_z − F| for the pull F of all its tethers (:class:`tmr.control.drones.DroneThrust`)."""
        return (1.0 - self.control_reserve) * self.thrust_to_weight * self.drone_weight

    @property
    def spare_thrust(self) -> float:
        """Thrust left to pull a tether while hovering [N]: (1 - reserve) * T/W * m g - m g (defaults: 7.36 N).

        Used as the bound on the tension magnitude at a drone end; conservative, since the thrust needed is
        |m g e_z - F| <= m g + |F| for the tether force F on the drone."""
        weight = self.drone_mass * self.g
        return max(0.0, (1.0 - self.control_reserve) * self.thrust_to_weight * weight - weight)


@dataclass(frozen=True)
class Catenary3D:
    """A tether hanging between ``p`` and ``q`` (3-D, z up, metres; forces in newtons).

    Attributes:
        p, q: the two ends, shape (3,) [m].
        u: horizontal unit vector from p towards q (``(1, 0, 0)`` for a vertical tether) [-].
        d: horizontal span |(q - p)_xy| [m]. h: height difference q_z - p_z [m].
        a: catenary parameter H / (rho g) [m], ``None`` for a vertical tether (d < ``VERTICAL_SPAN``).
        x0: horizontal position of the vertex along ``u`` from p [m] (may lie outside [0, d]); ``None`` if vertical.
        z0: height of the vertex [m]; ``None`` if vertical.
        horizontal_tension: H [N] (0 for a vertical tether).
        length: arc length L [m].
        lowest: lowest point of the cable itself, shape (3,) [m] (the vertex, or the lower end when the vertex lies
            outside the span).
        tension_p, tension_q: tension magnitude at p and at q [N].
        force_p, force_q: force of the cable on the end p / q, shape (3,) [N]; force_p + force_q = -rho g L e_z.
        weight_per_length: rho g [N/m].
    """

    p: np.ndarray
    q: np.ndarray
    u: np.ndarray
    d: float
    h: float
    a: float | None
    x0: float | None
    z0: float | None
    horizontal_tension: float
    length: float
    lowest: np.ndarray
    tension_p: float
    tension_q: float
    force_p: np.ndarray
    force_q: np.ndarray
    weight_per_length: float

    def points(self, k: int = 64) -> np.ndarray:
        """``k`` >= 2 points of the curve, equally spaced in arc length from p to q, shape (k, 3) [m].

        Consecutive points are L/(k-1) apart along the cable, so every point of the cable lies within L/(2(k-1)) of a
        sample: a clearance check on the samples with that margin added holds for the whole curve."""
        if int(k) < 2:
            raise ParameterError(f"a tether needs at least 2 sample points, got {k!r}")
        s = np.linspace(0.0, self.length, int(k))  # arc length from p
        if self.a is None:
            return self.p + np.outer(s * np.sign(self.h), [0.0, 0.0, 1.0])
        a = self.a
        theta_p = (0.0 - self.x0) / a
        theta = np.arcsinh(np.sinh(theta_p) + s / a)  # ds = a cosh(theta) dtheta
        x = self.x0 + a * theta
        z = self.z0 + a * (np.cosh(theta) - 1.0)
        return np.column_stack((self.p[0] + x * self.u[0], self.p[1] + x * self.u[1], z))


def _as_point(name: str, value: ArrayLike) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a 3-D point, got {value!r}") from exc
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} must be a finite 3-D point (x, y, z), got {value!r}")
    return arr


def _span(theta_a: np.ndarray | float, m: float, k: float) -> np.ndarray | float:
    """d(theta_A) / m: horizontal span over m for a lower-end angle parameter theta_A (k = 1 + h/m)."""
    sh = np.sinh(theta_a)
    theta_b = np.arcsinh(np.sqrt(k * k * sh * sh + (k * k - 1.0)))
    return (theta_b - theta_a) / np.cosh(theta_a)


def _newton_theta(d: float, h: float, m: float, guess: float) -> float | None:
    """theta_A by Newton's method on ``m span(theta_A) = d`` from ``guess`` (a warm start: the previous step's value),
    or None when it does not converge to the shallow branch (then the bracket method decides).

    The shallow branch is where the span falls as theta_A grows (beyond the maximum of d(theta_A)): a root with
    d span / d theta_A < 0 is on it, and the span has a single maximum, so that root is the one the bracket finds.
    """
    k = 1.0 + h / m
    target = d / m
    t = float(guess)
    kk = k * k
    for _ in range(30):
        if not -40.0 <= t <= 40.0:
            return None
        sh, ch = math.sinh(t), math.cosh(t)
        r2 = kk * sh * sh + (kk - 1.0)
        if r2 <= 0.0:
            return None
        sb = math.sqrt(r2)
        tb = math.asinh(sb)
        f = (tb - t) / ch - target
        # d/dt [(theta_B - t)/cosh t] with d theta_B/dt = k^2 sh ch / (sb sqrt(1 + sb^2))
        dtb = kk * sh * ch / (sb * math.sqrt(1.0 + r2)) if sb > 0.0 else 0.0
        df = ((dtb - 1.0) - (tb - t) * math.tanh(t)) / ch
        if not df < 0.0:
            return None
        step = f / df
        t -= step
        if abs(step) <= 1e-14 * max(1.0, abs(t)):
            sh = math.sinh(t)
            span = (math.asinh(math.sqrt(kk * sh * sh + (kk - 1.0))) - t) / math.cosh(t)
            return t if abs(span - target) <= 1e-12 * max(1.0, target) else None
    return None


def _solve_theta(d: float, h: float, m: float, guess: float | None = None) -> float:
    """theta_A of the shallow (stable) catenary through A=(0,0), B=(d,h), h >= 0, with a cosh(theta_A) = m.

    ``guess``: a warm start (Newton, :func:`_newton_theta`); the grid-bracketed root is the fallback."""
    if guess is not None and math.isfinite(guess):
        t = _newton_theta(d, h, m, guess)
        if t is not None:
            return t
    k = 1.0 + h / m
    target = d / m
    vals = _span(_GRID, m, k)
    j = int(np.argmax(vals))
    if guess is None:
        # a cold start without scipy.optimize (its import costs ~0.2 s of a start-up or a refusal): Newton from the
        # middle of the shallow branch's grid bracket (the last angle beyond the maximum whose span reaches the
        # target, and the next); the root it returns is on the shallow branch, so it is the bracket method's
        beyond = np.nonzero(vals[j + 1 :] >= target)[0]
        i = j + 1 + int(beyond[-1]) if beyond.size else len(_GRID)
        if i + 1 < len(_GRID):
            t = _newton_theta(d, h, m, 0.5 * (float(_GRID[i]) + float(_GRID[i + 1])))
            if t is not None:
                return t
    lo, hi = _GRID[max(j - 1, 0)], _GRID[min(j + 1, len(_GRID) - 1)]
    from scipy.optimize import brentq, minimize_scalar  # here: a warm-started solve never needs them

    res = minimize_scalar(lambda t: -_span(t, m, k), bounds=(lo, hi), method="bounded", options={"xatol": 1e-13})
    theta_star, d_max = (float(res.x), -float(res.fun)) if -res.fun >= vals[j] else (float(_GRID[j]), float(vals[j]))
    if target > d_max:
        raise TetherSpanError(
            f"a span of {d:.3f} m at a height difference of {h:.3f} m is longer than the {d_max * m:.3f} m the "
            f"tether can hold at an end tension of {m:.3f} m of cable weight; raise the winch tension or close the span"
        )
    above = np.nonzero((_GRID > theta_star) & (vals >= target))[0]
    if above.size:
        i = int(above[-1])
        if i + 1 >= len(_GRID):  # a span shorter than the grid resolves: nearer vertical than d(40) m
            return float(_GRID[-1])
        lo, hi = float(_GRID[i]), float(_GRID[i + 1])
    else:
        lo, hi = theta_star, float(_GRID[np.searchsorted(_GRID, theta_star, side="right")])
    if _span(lo, m, k) == target:
        return lo
    return float(brentq(lambda t: _span(t, m, k) - target, lo, hi, xtol=1e-15, rtol=4 * np.finfo(float).eps))


def solve3d(
    p: ArrayLike,
    q: ArrayLike,
    params: DroneTetherParams | None = None,
    *,
    winch_tension: float | None = None,
    warm: Catenary3D | None = None,
) -> Catenary3D:
    """The tether between ``p`` and ``q`` [m] with the winch keeping ``winch_tension`` [N] (default
    ``params.winch_tension``) at ``params.winch_end``. Ties (level ends) put the winch at p.

    ``warm``: the same tether a moment ago (e.g. the previous step's): its theta_A starts a Newton iteration
    (a few microseconds instead of the grid bracket's ~0.25 ms); the result is the same shallow branch, and the
    bracket method runs whenever Newton does not converge onto it.

    Raises:
        ParameterError: p or q is not a finite 3-D point, they coincide, or the tension is not finite and > 0.
        TetherSpanError: no catenary exists (span too long for the tension, or with the winch at the upper end its
            tension does not even carry the weight of a vertical cable).
    """
    prm = params if params is not None else DroneTetherParams()
    p_ = _as_point("tether end p", p)
    q_ = _as_point("tether end q", q)
    tw = prm.winch_tension if winch_tension is None else winch_tension
    if (
        isinstance(tw, bool)
        or not isinstance(tw, (int, float, np.integer, np.floating))
        or not (math.isfinite(tw) and tw > 0)
    ):
        raise ParameterError(f"the winch tension must be a finite number > 0 N, got {tw!r}")
    w = prm.weight_per_length
    dxy = q_[:2] - p_[:2]
    d = float(np.hypot(dxy[0], dxy[1]))
    h = float(q_[2] - p_[2])
    if d < VERTICAL_SPAN and abs(h) < VERTICAL_SPAN:
        raise ParameterError(f"the tether's two ends coincide at {fmt_point(p_)}")
    p_lower = h >= 0.0  # A = p, B = q
    dh = abs(h)
    t_a = float(tw) if prm.winch_end == "lower" else float(tw) - w * dh  # tension at the lower end A
    if t_a <= 0.0:
        raise TetherSpanError(
            f"a winch tension of {float(tw):.3f} N at the upper end cannot carry {dh:.3f} m of tether "
            f"({w * dh:.3f} N); raise the winch tension above that"
        )
    t_b = t_a + w * dh
    t_p, t_q = (t_a, t_b) if p_lower else (t_b, t_a)
    ez = np.array([0.0, 0.0, 1.0])
    if d < VERTICAL_SPAN:
        up = ez if p_lower else -ez  # from p towards q
        return Catenary3D(
            p=p_, q=q_, u=np.array([1.0, 0.0, 0.0]), d=d, h=h, a=None, x0=None, z0=None, horizontal_tension=0.0,
            length=dh, lowest=(p_ if p_lower else q_).copy(), tension_p=t_p, tension_q=t_q,
            force_p=t_p * up, force_q=-t_q * up, weight_per_length=w,
        )  # fmt: skip
    m = t_a / w
    theta_a = _solve_theta(d, dh, m, None if warm is None else theta_lower(warm))
    return _catenary(p_, q_, d, h, m, theta_a, t_p, t_q, w)


def _shape(d: float, h: float, m: float, theta_a: float, z_a: float) -> tuple[float, ...]:
    """The scalars of a non-vertical tether from its solved theta_A (span d, height difference h = z_q - z_p [m],
    m = T_A/(rho g) [m], z_a the lower end's height [m]): (a, x0 from p, z0, length, sinh theta_A, sinh theta_B,
    theta_B) in the units of :class:`Catenary3D` (the closed forms of the module doc)."""
    a = m / math.cosh(theta_a)
    k = 1.0 + abs(h) / m
    sh_a = math.sinh(theta_a)
    sh_b = math.sqrt(k * k * sh_a * sh_a + (k * k - 1.0))
    theta_b = math.asinh(sh_b)
    z0 = z_a - m + a  # z_A = z0 + a (cosh(theta_A) - 1) and a cosh(theta_A) = m
    x0_a = -a * theta_a  # vertex from A along A -> B
    x0 = x0_a if h >= 0.0 else d - x0_a
    return a, x0, z0, a * (sh_b - sh_a), sh_a, sh_b, theta_b


def _catenary(
    p_: np.ndarray, q_: np.ndarray, d: float, h: float, m: float, theta_a: float, t_p: float, t_q: float, w: float
) -> Catenary3D:
    """The :class:`Catenary3D` of a non-vertical tether from its solved theta_A (arguments as in :func:`_shape`;
    t_p, t_q the end tensions [N], w = rho g [N/m])."""
    ez = np.array([0.0, 0.0, 1.0])
    dxy = q_[:2] - p_[:2]
    u = np.array([dxy[0] / d, dxy[1] / d, 0.0])
    p_lower = h >= 0.0  # A = p, B = q
    a, x0, z0, length, sh_a, sh_b, theta_b = _shape(d, h, m, theta_a, min(p_[2], q_[2]))
    H = w * a
    if theta_a <= 0.0 <= theta_b:  # vertex within the span
        lowest = np.array([p_[0] + x0 * u[0], p_[1] + x0 * u[1], z0])
    else:
        lowest = (p_ if p_lower else q_).copy()
    # force of the cable on A pulls towards B along the tangent: (H, H sinh(theta_A)); on B: -(H, H sinh(theta_B))
    if p_lower:
        f_p = H * u + H * sh_a * ez
        f_q = -H * u - H * sh_b * ez
    else:  # p = B and q = A: the cable pulls p towards q (+u) and down, q towards p (-u)
        f_p = H * u - H * sh_b * ez
        f_q = -H * u + H * sh_a * ez
    return Catenary3D(
        p=p_, q=q_, u=u, d=d, h=h, a=a, x0=x0, z0=z0, horizontal_tension=H, length=length, lowest=lowest,
        tension_p=t_p, tension_q=t_q, force_p=f_p, force_q=f_q, weight_per_length=w,
    )  # fmt: skip


def theta_lower(cat: Catenary3D) -> float | None:
    """theta_A = (x_A - x0)/a at the lower end A of ``cat`` (None for a vertical tether): the one unknown that
    :func:`solve3d` solves for, e.g. to warm-start the next solve of the same tether."""
    if cat.a is None or cat.x0 is None:
        return None
    x0_a = cat.x0 if cat.h >= 0.0 else cat.d - cat.x0  # vertex from A along A -> B
    return -x0_a / cat.a


class TetherCatenaries:
    """N tethers of a chain solved at once (:func:`solve3d_batch`), stacked (tether j from ``points[j]`` to
    ``points[j + 1]``).

    Attributes:
        p, q: the ends, (N, 3) [m]. u: horizontal unit vectors p -> q, (N, 3) ((1, 0, 0) for a vertical tether).
        d, h: horizontal spans and height differences q_z - p_z, (N,) [m].
        a, x0, z0: catenary parameter, vertex position along u from p and vertex height, (N,) [m]; NaN if vertical.
        theta: theta_A at the lower end, (N,) [-], the value :func:`theta_lower` gives for each tether (NaN if
            vertical): the warm start of the next :func:`solve3d_batch` and the unknown :func:`sensitivities_batch`
            differentiates.
        length: arc lengths (N,) [m]. tension_p, tension_q: end tensions (N,) [N]. vertical: (N,) bool.
        weight_per_length: rho g [N/m].

    ``cats[j]`` (and iterating) gives tether j's :class:`Catenary3D`, equal to what :func:`solve3d` returns for it,
    built on first use: the per-step loop reads only the arrays.
    """

    def __init__(
        self,
        p: np.ndarray,
        q: np.ndarray,
        table: np.ndarray,
        vertical: np.ndarray,
        weight_per_length: float | np.ndarray,
        cats: list[Catenary3D | tuple[float, ...]],
    ) -> None:
        """``table``: (N, 11) columns d, h, a, x0, z0, theta, length, tension_p, tension_q, u_x, u_y (the
        attributes); ``cats``: per tether its :class:`Catenary3D`, or the arguments (d, h, m, theta_A, T_p, T_q)
        that build it (:func:`_catenary`)."""
        self.p, self.q, self.vertical, self.weight_per_length = p, q, vertical, weight_per_length
        self.d, self.h, self.a, self.x0, self.z0, self.theta, self.length, self.tension_p, self.tension_q = table[
            :, :9
        ].T
        self.u = np.zeros((len(table), 3))
        self.u[:, :2] = table[:, 9:]
        self._cats = cats

    def __len__(self) -> int:
        return len(self._cats)

    def __getitem__(self, j: int) -> Catenary3D:
        cat = self._cats[j]
        if isinstance(cat, tuple):
            cat = self._cats[j] = _catenary(self.p[j], self.q[j], *cat, float(self.weight_per_length))
        return cat

    def __iter__(self) -> Iterator[Catenary3D]:
        return (self[j] for j in range(len(self)))


def _winch_tensions(winch_tension: ArrayLike | None, n: int, prm: DroneTetherParams) -> list[float]:
    """The n tethers' winch tensions [N]: ``params.winch_tension`` each (None) or an (n,) array of finite values
    > 0 (ParameterError otherwise)."""
    if winch_tension is None:
        return [float(prm.winch_tension)] * n
    try:
        tw = np.asarray(winch_tension, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"the winch tensions must be {n} numbers > 0 N, got {winch_tension!r}") from exc
    if tw.shape != (n,) or not (np.isfinite(tw).all() and (tw > 0).all()):
        raise ParameterError(f"the winch tensions must be {n} finite numbers > 0 N, got {winch_tension!r}")
    return tw.tolist()


def solve3d_batch(
    points: ArrayLike,
    params: DroneTetherParams | None = None,
    warm: ArrayLike | None = None,
    *,
    winch_tension: ArrayLike | None = None,
) -> TetherCatenaries:
    """The N tethers between consecutive ``points`` (N+1, 3) [m] at once: tether j is ``solve3d(points[j],
    points[j + 1], params, winch_tension=T_j)`` (the winch tension T_j [N] at ``params.winch_end``:
    ``winch_tension[j]`` of an (N,) array, an active winch's, or ``params.winch_tension`` for every tether).

    ``warm``: (N,) theta_A of the same tethers a moment ago (the previous result's ``theta``; NaN: none), each the
    warm start :func:`solve3d` takes from ``warm=``. The spans and heights are computed for all tethers in one numpy
    pass and only the one-variable solve runs per tether (the scalar Newton of :func:`solve3d`, a few microseconds;
    a numpy Newton over the tethers costs more in call overhead at chain sizes and rounds differently); a vertical
    tether, or one whose winch cannot carry it, goes through :func:`solve3d` itself. The result equals
    :func:`solve3d`'s per tether, to the bit.

    Raises:
        ParameterError: ``points`` is not an (N+1, 3) array of finite points with N >= 1, or two consecutive coincide.
        TetherSpanError: a tether has no catenary (the first such tether's :func:`solve3d` message).
    """
    prm = params if params is not None else DroneTetherParams()
    try:
        P = np.array(points, dtype=float)  # its own copy: the result keeps views of it
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"the tether ends must be an (N+1, 3) array of points, got {points!r}") from exc
    if P.ndim != 2 or P.shape[0] < 2 or P.shape[1] != 3:
        raise ParameterError(f"the tether ends must be an (N+1, 3) array of points, got shape {P.shape}")
    N = P.shape[0] - 1
    if not np.isfinite(P).all():
        for j in range(N):  # solve3d names the offending end
            solve3d(P[j], P[j + 1], prm)
    D = P[1:] - P[:-1]
    d_all, h_all = np.hypot(D[:, 0], D[:, 1]), D[:, 2]
    guesses = [None] * N if warm is None else np.asarray(warm, dtype=float).reshape(N).tolist()
    tws = _winch_tensions(winch_tension, N, prm)
    w, lower = prm.weight_per_length, prm.winch_end == "lower"
    nan = math.nan
    rows: list[tuple[float, ...]] = []
    cats: list[Catenary3D | tuple[float, ...]] = []
    z = P[:, 2].tolist()
    for j, (d, h, dx, dy, guess, tw) in enumerate(
        zip(d_all.tolist(), h_all.tolist(), *D[:, :2].T.tolist(), guesses, tws, strict=True)
    ):
        dh = abs(h)
        t_a = tw if lower else tw - w * dh  # tension at the lower end A, as in solve3d
        if d < VERTICAL_SPAN or t_a <= 0.0:
            cat = solve3d(P[j], P[j + 1], prm, winch_tension=tw)  # vertical: a straight line; else its error
            cats.append(cat)
            rows.append((cat.d, cat.h, nan, nan, nan, nan, cat.length, cat.tension_p, cat.tension_q, 1.0, 0.0))
            continue
        t_b = t_a + w * dh
        t_p, t_q = (t_a, t_b) if h >= 0.0 else (t_b, t_a)
        m = t_a / w
        theta_a = _solve_theta(d, dh, m, guess if guess is None or math.isfinite(guess) else None)
        a, x0, z0, length, *_ = _shape(d, h, m, theta_a, min(z[j], z[j + 1]))
        cats.append((d, h, m, theta_a, t_p, t_q))
        theta = -(x0 if h >= 0.0 else d - x0) / a  # theta_lower's value (the warm start of solve3d)
        rows.append((d, h, a, x0, z0, theta, length, t_p, t_q, dx / d, dy / d))
    vertical = np.array([isinstance(c, Catenary3D) for c in cats], dtype=bool)
    return TetherCatenaries(P[:-1], P[1:], np.array(rows), vertical, w, cats)


@dataclass(frozen=True)
class CatenarySensitivity:
    """How a tether's sample points, arc length and end tensions move with its two ends (:func:`sensitivities`).

    Attributes:
        fractions: arc fractions sigma of the samples, (k,) [-] (sigma = 0 at p, 1 at q).
        points: the samples, at arc length sigma L from p, (k, 3) [m].
        dpoints_dp, dpoints_dq: their Jacobians w.r.t. p and q, (k, 3, 3) [m/m]:
            dX_i = dpoints_dp[i] dp + dpoints_dq[i] dq.
        length: arc length L [m]; dlength_dp, dlength_dq: its gradients (3,) [m/m].
        tension_p, tension_q: end tensions [N]; dtension_p_dp, dtension_p_dq, dtension_q_dp, dtension_q_dq: their
            gradients (3,) [N/m].
        dpoints_dtw, dlength_dtw, dtension_dtw: (``winch=True`` only, else None) the derivatives of the samples
            (k, 3) [m/N], of L [m/N] and of both end tensions [N/N = 1: T_B = T_A + rho g h] w.r.t. the winch
            tension T_w (an active winch, issue 34).
    """

    fractions: np.ndarray
    points: np.ndarray
    dpoints_dp: np.ndarray
    dpoints_dq: np.ndarray
    length: float
    dlength_dp: np.ndarray
    dlength_dq: np.ndarray
    tension_p: float
    tension_q: float
    dtension_p_dp: np.ndarray
    dtension_p_dq: np.ndarray
    dtension_q_dp: np.ndarray
    dtension_q_dq: np.ndarray
    dpoints_dtw: np.ndarray | None = None
    dlength_dtw: float | None = None
    dtension_dtw: float | None = None


_CSTEP = 1e-30  # complex-step size: derivatives of the closed-form parts exact to rounding (Squire & Trapp 1998)
_CSTEP4 = 1j * _CSTEP * np.eye(4)  # row i: the complex step along the i-th of (theta_A, d, h, T_w)
_EYE2, _EYE3, _EZ = np.eye(2), np.eye(3), np.array([0.0, 0.0, 1.0])


def _plane(theta: complex, d: complex, dh: complex, tw: float, w: float, upper: bool, sig: np.ndarray) -> tuple:
    """The catenary in its plane from the lower end A = (0, 0) with B = (d, dh): the residual of the span equation
    R = a (theta_B - theta_A) - d, the arc length L, and the samples (x, z) relative to A at arc fractions ``sig``
    from A. Closed form in (theta_A, d, dh): complex arguments give derivatives by the complex step."""
    m = tw / w - dh if upper else tw / w  # a cosh(theta_A) = T_A / (rho g)
    k = 1.0 + dh / m
    kk = k * k
    ch = np.cosh(theta)
    sh = np.sinh(theta)
    a = m / ch
    sb = np.sqrt(kk * sh * sh + (kk - 1.0))
    span = sb - sh
    L = a * span
    R = a * (np.arcsinh(sb) - theta) - d
    th = np.arcsinh(sh + sig * span)  # ds = a cosh(theta) dtheta: s = a (sinh th - sinh theta_A)
    return R, L, a * (th - theta), a * (np.cosh(th) - ch)


@dataclass(frozen=True)
class TetherSensitivities:
    """:class:`CatenarySensitivity` of M tethers at once, stacked: points (M, k, 3), dpoints_dp/dq (M, k, 3, 3),
    length (M,), dlength_dp/dq (M, 3), tension_p/q (M,), dtension_p_dp … dtension_q_dq (M, 3) (same units)."""

    fractions: np.ndarray
    points: np.ndarray
    dpoints_dp: np.ndarray
    dpoints_dq: np.ndarray
    length: np.ndarray
    dlength_dp: np.ndarray
    dlength_dq: np.ndarray
    tension_p: np.ndarray
    tension_q: np.ndarray
    dtension_p_dp: np.ndarray
    dtension_p_dq: np.ndarray
    dtension_q_dp: np.ndarray
    dtension_q_dq: np.ndarray
    dpoints_dtw: np.ndarray | None = None
    dlength_dtw: np.ndarray | None = None
    dtension_dtw: np.ndarray | None = None

    def __getitem__(self, i: int) -> CatenarySensitivity:
        """Tether i's :class:`CatenarySensitivity`."""
        return CatenarySensitivity(
            self.fractions,
            *(None if (v := getattr(self, f.name)) is None else v[i] for f in fields(self) if f.name != "fractions"),
        )


def sensitivities(
    cat: Catenary3D, fractions: ArrayLike, params: DroneTetherParams | None = None, *, winch: bool = False
) -> CatenarySensitivity:
    """Sample points of ``cat`` at fixed arc fractions, its arc length and end tensions, with their Jacobians w.r.t.
    both ends (3x3 per point, 3-vectors for L and the tensions).

    Implicit differentiation of the catenary equations: with A the lower end, B the upper one, d the horizontal span
    and h = z_B - z_A >= 0, the shape is fixed by the one unknown theta_A solving R(theta_A, d, h) = 0 (the span
    equation of :func:`solve3d`); the implicit function theorem gives d theta_A / d(d, h) = -R_(d,h) / R_theta, and
    every output y(theta_A, d, h) (closed form) changes by y_(d,h) + y_theta d theta_A / d(d, h). The partials of
    the closed forms come from the complex step (exact to rounding). In 3-D a point at (x, z) in the plane is
    X = A + x u + z e_z with u the horizontal unit vector A -> B; d d = u.(dB - dA)_xy, d h = dB_z - dA_z and
    d u = (I - u u^T)(dB - dA)_xy / d, so dX/dB is the 3x3 block below and dX/dA = I - dX/dB (translation).
    A vertical tether (straight) moves as X = p + sigma (q - p). At level ends (h = 0) the lower end swaps and the
    Jacobians are one-sided (the tension at each end has a kink there). ``winch``: also w.r.t. the winch tension
    (:class:`CatenarySensitivity`'s ``*_dtw``).
    """
    return sensitivities_batch([cat], fractions, params, winch=winch)[0]


def _stack(cats: Sequence[Catenary3D]) -> TetherCatenaries:
    """Tethers solved one by one (:func:`solve3d`) gathered into a :class:`TetherCatenaries`."""
    M = len(cats)
    table = np.array(
        [
            (c.d, c.h, *((math.nan,) * 4 if c.a is None else (c.a, c.x0, c.z0, theta_lower(c))), c.length,
             c.tension_p, c.tension_q, c.u[0], c.u[1])
            for c in cats
        ],
        dtype=float,
    ).reshape(M, 11)  # fmt: skip
    w = np.array([c.weight_per_length for c in cats])
    vertical = np.array([c.a is None for c in cats], dtype=bool)
    p, q = np.array([c.p for c in cats]).reshape(M, 3), np.array([c.q for c in cats]).reshape(M, 3)
    return TetherCatenaries(p, q, table, vertical, w, list(cats))


def sensitivities_batch(
    cats: Sequence[Catenary3D] | TetherCatenaries,
    fractions: ArrayLike,
    params: DroneTetherParams | None = None,
    *,
    winch: bool = False,
) -> TetherSensitivities:
    """:func:`sensitivities` of several tethers at once (vectorised over the tethers: one numpy pass for a chain).

    ``cats``: the tethers, as :class:`Catenary3D` objects or as the arrays :func:`solve3d_batch` returns (read as
    they are: no per-tether gathering); each tether's own winch tension is read from its end tensions, so tethers
    solved with different tensions (an active winch each) are differentiated at their own. ``winch``: also the
    derivatives w.r.t. the winch tension T_w (``dpoints_dtw``, ``dlength_dtw``, ``dtension_dtw``; the same implicit
    differentiation with T_w as a fourth argument of the span equation: d theta_A / d T_w = -R_T / R_theta)."""
    prm = params if params is not None else DroneTetherParams()
    sig = np.asarray(fractions, dtype=float).reshape(-1)
    C = cats if isinstance(cats, TetherCatenaries) else _stack(cats)
    M, k = len(C), sig.size
    up = prm.winch_end == "upper"
    ez = _EZ
    w = np.full(M, C.weight_per_length)
    p, q = C.p, C.q
    p_lower = C.h >= 0.0
    vertical = C.vertical
    lw = p_lower | vertical  # p is the end A (a vertical tether: p, whatever its height)
    straight = bool(vertical.any())  # vertical tethers: X = p + sigma (q - p), dX/dq = sigma I (the JB below)
    cv = np.flatnonzero(~vertical) if straight else None
    if winch:  # a vertical tether: straight whatever T_w (zeros)
        dX_dT, dL_dT = np.zeros((M, k, 3)), np.zeros(M)
    if straight:
        X = p[:, None, :] + sig[None, :, None] * (q - p)[:, None, :]
        JB = np.zeros((M, k, 3, 3))
        JB[:] = sig[None, :, None, None] * _EYE3
        dL_dB = np.tile(ez, (M, 1))
    if not vertical.all():
        sel = slice(None) if cv is None else cv  # all tethers (the usual case: no copies) or the non-vertical
        theta, d, wv, hv, low = C.theta[sel], C.d[sel], w[sel], np.abs(C.h[sel]), p_lower[sel]
        t_a = np.where(low, C.tension_p[sel], C.tension_q[sel])
        tw = t_a + wv * hv if up else t_a  # the winch's T_w
        sig_a = np.where(low[:, None], sig, 1.0 - sig)  # fractions from A
        # axis 1: perturbation of theta_A, d, h (imaginary parts, Z[:, i, j] = (theta_A, d, h)_j + i eps delta_ij);
        # axis 2: the samples
        # with ``winch``, a 4th row perturbs T_w (the active winch's tension, an unknown of its own)
        if winch:
            Z = np.array((theta, d, hv, tw)).T[:, None, :] + _CSTEP4
            T = Z[..., 3:4]
        else:  # T_w real: the common per-step case stays as cheap as it was
            Z, T = np.array((theta, d, hv)).T[:, None, :] + _CSTEP4[:3, :3], tw[:, None, None]
        R, L, xs, zs = _plane(Z[..., 0:1], Z[..., 1:2], Z[..., 2:3], T, wv[:, None, None], up,
                              sig_a[:, None, :])  # fmt: skip
        Ri = R.imag[:, :, 0] / _CSTEP  # (C, 3 or 4): dR/d(theta_A, d, h[, T_w])
        dt = -Ri[:, 1:] / Ri[:, :1]  # (C, 2 or 3): d theta_A / d(d, h[, T_w]), implicit function theorem
        # the samples' x (k), z (k) and L (1) with their partials (imaginary parts, axis 1) and their total
        # derivatives along d and h [and T_w] (axis 1 of G)
        Y = np.concatenate((xs, zs, L), axis=2)  # (C, 3 or 4, 2k+1)
        Yi = Y.imag / _CSTEP
        G = Yi[:, 1:] + Yi[:, :1] * dt[:, :, None]  # (C, 2 or 3, 2k+1)
        if winch:  # T_w moves the curve in its plane only: dX/dT_w = x_T u + z_T e_z (A and u stay)
            x_dt, z_dt, L_dt = G[:, 2, :k], G[:, 2, k:-1], G[:, 2, -1]
        x, z = xs[:, 0].real, zs[:, 0].real  # (C, k)
        x_dd, z_dd, L_dd = G[:, 0, :k], G[:, 0, k:-1], G[:, 0, -1]
        x_dh, z_dh, L_dh = G[:, 1, :k], G[:, 1, k:-1], G[:, 1, -1]
        A = np.where(low[:, None], p[sel], q[sel])
        u = np.where(low[:, None], C.u[sel], -C.u[sel])  # horizontal A -> B
        u2 = u[:, :2]
        Xc = A[:, None, :] + x[..., None] * u[:, None, :] + z[..., None] * ez
        uu = u2[:, :, None] * u2[:, None, :]  # (C, 2, 2)
        J = np.empty((len(theta), k, 3, 3))
        J[:, :, :2, :2] = x_dd[..., None, None] * uu[:, None] + (x / d[:, None])[..., None, None] * (
            _EYE2 - uu[:, None]
        )
        J[:, :, :2, 2] = x_dh[..., None] * u2[:, None, :]
        J[:, :, 2, :2] = z_dd[..., None] * u2[:, None, :]
        J[:, :, 2, 2] = z_dh
        dLc = np.concatenate((L_dd[:, None] * u2, L_dh[:, None]), axis=1)
        if straight:
            X[cv], JB[cv], dL_dB[cv] = Xc, J, dLc
        else:
            X, JB, dL_dB = Xc, J, dLc
        if winch:
            dX_dT[sel] = x_dt[..., None] * u[:, None, :] + z_dt[..., None] * ez
            dL_dT[sel] = L_dt
    # vertical tethers: B is q when p is lower (X = p + sigma (q - p) has dX/dq = sigma I = the JB set above)
    JA = _EYE3 - JB
    lowv = lw[:, None, None, None]
    Jp = np.where(lowv, JA, JB)
    Jq = np.where(lowv, JB, JA)
    if straight:
        dL_dB = np.where((~p_lower & vertical)[:, None], -dL_dB, dL_dB)  # vertical: dL/dq = sign(h) e_z
    dL_dp = np.where(lw[:, None], -dL_dB, dL_dB)
    # end tensions: T_A = T_w (lower winch) or T_w - w h; T_B = T_A + w h; h = z_B - z_A
    dta = (-w if up else 0.0 * w)[:, None] * ez
    dtb = dta + w[:, None] * ez
    pl = p_lower[:, None]
    tp_p = np.where(pl, -dta, dtb)
    tq_q = np.where(pl, dtb, -dta)
    return TetherSensitivities(
        fractions=sig, points=X, dpoints_dp=Jp, dpoints_dq=Jq, length=C.length.copy(),
        dlength_dp=dL_dp, dlength_dq=-dL_dp, tension_p=C.tension_p.copy(), tension_q=C.tension_q.copy(),
        dtension_p_dp=tp_p, dtension_p_dq=-tp_p, dtension_q_dp=-tq_q, dtension_q_dq=tq_q,
        **({} if not winch else dict(dpoints_dtw=dX_dT, dlength_dtw=dL_dT, dtension_dtw=np.ones(M))),
    )  # fmt: skip


def tether_limits(
    cat: Catenary3D,
    params: DroneTetherParams | None = None,
    *,
    drone_ends: tuple[bool, bool] = (True, True),
    distance: Callable[[np.ndarray], np.ndarray] | None = None,
    samples: int = 128,
) -> list[str]:
    """The limits ``cat`` violates, one message each (empty list: every limit holds).

    Limits: arc length <= ``tether_length``; tension at each drone end (``drone_ends`` for p, q) <= the drone's
    ``spare_thrust``; the whole curve (``samples`` points, with the sampling margin L/(2(samples-1)) added) at least
    ``clearance`` above the floor z = 0 and, if ``distance`` is given (points (K, 3) -> distances (K,) [m] to the
    nearest obstacle), from every obstacle.
    """
    prm = params if params is not None else DroneTetherParams()
    out: list[str] = []
    if cat.length > prm.tether_length:
        out.append(f"tether of {cat.length:.3f} m is longer than the {prm.tether_length:.3f} m the winch holds")
    for is_drone, name, end, t in (
        (drone_ends[0], "p", cat.p, cat.tension_p),
        (drone_ends[1], "q", cat.q, cat.tension_q),
    ):
        if is_drone and t > prm.spare_thrust:
            out.append(
                f"tether pulls the drone at {fmt_point(end)} (end {name}) with {t:.3f} N, more than its spare "
                f"thrust {prm.spare_thrust:.3f} N"
            )
    pts = cat.points(samples)
    margin = cat.length / (2.0 * (samples - 1))
    if cat.lowest[2] < prm.clearance:
        out.append(
            f"tether's lowest point {fmt_point(cat.lowest)} is less than the clearance {prm.clearance:.3f} m above "
            "the floor"
        )
    if distance is not None:
        dist = np.asarray(distance(pts), dtype=float).reshape(-1)
        i = int(np.argmin(dist))
        if dist[i] - margin < prm.clearance:
            out.append(
                f"tether passes {max(dist[i] - margin, 0.0):.3f} m from an obstacle at {fmt_point(pts[i])}, less "
                f"than the clearance {prm.clearance:.3f} m"
            )
    return out
