"""Sensitivity grid of Caruso 2021 §5.1 (Fig. 9): k_v0 and d_min swept over nominal · [0.5, 2.0] (and the QP's
counterparts, see :data:`SWEEP_AXES`).

The paper writes the interval as ``k_v0 = k_v0* + [−50 %, +100 %]`` and ``d_min = d_min* + [−50 %, +100 %]`` with
k_v0* = 0.05 m²/s and d_min* = 0.5 m (the defaults of :class:`tmr.model.params.PinvParams`), i.e. k_v0 ∈ [0.025, 0.1]
m²/s
and d_min ∈ [0.25, 1.0] m.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.model.params import PinvParams, QPParams
from tmr.sweep.errors import MAX_RUNS, SweepError
from tmr.sweep.runs import RunResult, RunSpec

__all__ = ["SWEEP_AXES", "UNITS", "Grid", "SensitivityResult", "sensitivity_grid", "sensitivity_specs"]

Array = NDArray[np.float64]

#: Paper's ranges on its Fig. 9 grid (Caruso 2021 §5.1): f1 [J], f2 [m²], f3 [m²], f4 [m s⁻³ as printed].
PAPER_RANGES: dict[str, tuple[float, float]] = {
    "f1": (123.9412, 453.7501),
    "f2": (0.0021, 0.6446),
    "f3": (1.1405, 1.1407),
    "f4": (0.1559e8, 2.7352e8),
}


@dataclass(frozen=True)
class Grid:
    """A 2-D parameter grid: ``x`` values of parameter ``x_name`` (columns) × ``y`` values of ``y_name`` (rows)."""

    x_name: str
    x: tuple[float, ...]
    y_name: str
    y: tuple[float, ...]

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) = (len(y), len(x))."""
        return (len(self.y), len(self.x))

    def points(self) -> list[tuple[float, float]]:
        """(x, y) of every cell, row-major (y outer, x inner): task index i ↔ cell (i // nx, i % nx)."""
        return [(xv, yv) for yv in self.y for xv in self.x]


#: The two swept parameters (x, y) per method, with their units. ``pinv``: the paper's d_min (activation distance of
#: the obstacle task, eq. 17) and k_v0 (evasion speed constant). ``qp`` has no obstacle task — it reads neither — so
#: its counterparts are swept: ``d_safe``, the clearance its hard limit keeps (where avoidance acts), and
#: ``approach_rate``, the velocity damper's rate (how fast the chain may close on an obstacle).
SWEEP_AXES: dict[str, tuple[str, str]] = {"pinv": ("d_min", "k_v0"), "qp": ("d_safe", "approach_rate")}
SWEEP_AXES["horizon"] = SWEEP_AXES["qp"]  # warm-started from qp, same clearance limit

#: Units of the swept parameters (axis labels).
UNITS: dict[str, str] = {"d_min": "m", "k_v0": "m²/s", "d_safe": "m", "approach_rate": "1/s"}


def sensitivity_grid(
    n: int | Sequence[int] = 13,
    low: float = 0.5,
    high: float = 2.0,
    method: str = "pinv",
    nominal: dict[str, float] | None = None,
) -> Grid:
    """The Fig. 9 grid: the method's two parameters (:data:`SWEEP_AXES`) at nominal · linspace(low, high, n).

    For ``pinv``: d_min (x, columns) and k_v0 (y, rows), nominal 0.5 m and 0.05 m²/s (``PinvParams`` defaults), so
    d_min ∈ [0.25, 1.0] m and k_v0 ∈ [0.025, 0.1] m²/s as in Caruso 2021 §5.1.

    Args:
        n: points per axis (one int for both, or (n_x, n_y)); ≥ 2.
        low, high: factors on the nominal values (paper: 0.5 and 2.0).
        method: ``"pinv"``, ``"qp"`` or ``"horizon"``.
        nominal: nominal values by name (default: the parameter dataclasses' defaults).

    The values are rounded to 12 significant digits so they print and parse back exactly.
    """
    if method not in SWEEP_AXES:
        raise SweepError(f"no sensitivity axes for method {method!r}; available: {', '.join(SWEEP_AXES)}")
    nx, ny = (n, n) if isinstance(n, int) else tuple(n)
    if nx < 2 or ny < 2:
        raise SweepError(f"a sensitivity grid needs at least 2 points per axis, got {nx} × {ny}")
    if nx * ny > MAX_RUNS:
        raise SweepError(f"a {nx} × {ny} grid is {nx * ny:.3g} plans, more than {MAX_RUNS}; give a smaller --n")
    if not (math.isfinite(low) and math.isfinite(high) and 0 < low < high):
        raise SweepError(f"need 0 < low < high factors, got low={low}, high={high}")
    x_name, y_name = SWEEP_AXES[method]
    defaults = {**asdict(PinvParams()), **asdict(QPParams()), **(nominal or {})}
    x0, y0 = float(defaults[x_name]), float(defaults[y_name])
    if not (x0 > 0 and y0 > 0):
        raise SweepError(f"nominal {x_name} and {y_name} must be > 0, got {x0}, {y0}")

    def axis(nominal_value: float, count: int) -> tuple[float, ...]:
        return tuple(float(f"{v:.12g}") for v in nominal_value * np.linspace(low, high, count))

    return Grid(x_name, axis(x0, nx), y_name, axis(y0, ny))


def sensitivity_specs(
    grid: Grid, scenario: str, method: str, seed: int = 0, base: dict[str, Any] | None = None
) -> list[RunSpec]:
    """One :class:`RunSpec` per grid cell (row-major, see :meth:`Grid.points`); ``base`` overrides are shared."""
    base = dict(base or {})
    for name in (grid.x_name, grid.y_name):
        base.pop(name, None)
    shared = tuple(sorted(base.items()))
    return [
        RunSpec(scenario, method, seed, shared + ((grid.x_name, xv), (grid.y_name, yv))) for xv, yv in grid.points()
    ]


@dataclass(frozen=True)
class SensitivityResult:
    """Results of a sensitivity sweep on one scenario and method, cell (i, j) = (y[i], x[j])."""

    grid: Grid
    scenario: str
    method: str
    seed: int
    results: tuple[RunResult, ...]

    def field(self, name: str) -> Array:
        """(ny, nx) array of a :class:`RunResult` attribute (``"f1"``, ``"raw_f1"``, ``"min_robot_clearance"``…)."""
        if name.startswith("raw_f"):
            vals = [r.raw[int(name[-1]) - 1] for r in self.results]
        else:
            vals = [getattr(r, name) for r in self.results]
        return np.asarray(vals, dtype=float).reshape(self.grid.shape)

    @property
    def feasible(self) -> NDArray[np.bool_]:
        """(ny, nx) mask of the plans that succeeded."""
        return np.asarray([r.success for r in self.results]).reshape(self.grid.shape)

    def ranges(self) -> dict[str, tuple[float, float]]:
        """(min, max) of f1–f4 over the feasible cells (NaN if none), as in Caruso 2021 §5.1."""
        out = {}
        ok = self.feasible
        for k in ("f1", "f2", "f3", "f4"):
            v = self.field(k)[ok]
            out[k] = (float(v.min()), float(v.max())) if v.size else (math.nan, math.nan)
        return out
