"""Per-tether span limits [d_lo, d_max] of the chain (Caruso 2021 §4.2.1), shared by the route and the planner."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tmr.errors import ParameterError
from tmr.model import catenary
from tmr.model.params import ChainParams

Array = NDArray[np.float64]

__all__ = ["catenary_params", "span_limits"]


def catenary_params(params: ChainParams, tension: float | None = None) -> catenary.CatenaryParams:
    """The planner's :class:`~tmr.model.catenary.CatenaryParams` of the tethers at horizontal tension ``tension`` [N]
    (default: the winch's T0 = torque / radius): the cable kept ``ground_clearance + sag_allowance`` above the floor
    (the checker, :mod:`tmr.checks.metrics`, holds it to ``ground_clearance`` alone)."""
    return catenary.CatenaryParams(
        horizontal_tension=params.horizontal_tension if tension is None else float(tension),
        mass_per_length=params.cable_mass_per_length,
        end_height=params.exit_height,
        base_height=params.base_height,
        ground_clearance=params.ground_clearance + params.sag_allowance,
    )


def span_limits(n_robots: int, params: ChainParams) -> Array:
    """Per-tether [d_lo, d_max] [m]: d_lo from the safety bubbles (r for the anchor link, 2r between robots),
    d_max the catenary limit of Caruso 2021 §4.2.1 (lowest point of the cable above the floor).

    With an active winch d_max is the reach at the winch's highest tension (``winch_tension_max``): the route and the
    joint box get the farthest a tether can span, and the per-step QP keeps each span within d_max of its planned
    tension (:class:`tmr.control.winch.WinchSpan`)."""
    cat = catenary_params(params, params.winch_tension_max if params.active_winch else None)
    lim = np.empty((n_robots, 2))
    lim[:, 0] = 2 * params.safety_radius
    lim[0, 0] = params.safety_radius
    lim[0, 1] = catenary.max_span(params.base_height, params.exit_height, cat)
    if n_robots > 1:
        lim[1:, 1] = catenary.max_span(params.exit_height, params.exit_height, cat)
    if np.any(lim[:, 0] >= lim[:, 1]):
        raise ParameterError(
            f"the catenary limit d_max = {lim[:, 1].min():.2f} m is below the minimum span {lim[:, 0].max():.2f} m "
            "from the safety bubbles: increase the tension or the exit height"
        )
    return lim
