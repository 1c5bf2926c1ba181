"""Exceptions of the mobile cable-driven parallel robot package (Rasheed 2019)."""

from __future__ import annotations

from tmr.errors import ParameterError, ScenarioError, TmrError

__all__ = ["InfeasibleWrench", "McdprError", "ParameterError", "ScenarioError"]


class McdprError(TmrError):
    """Base class of the errors raised on purpose by :mod:`tmr.mcdpr`."""


class InfeasibleWrench(McdprError):
    """No cable tensions within the (tipping-tightened) bounds produce the requested wrench (Rasheed 2019 eq. 2, 7).

    The message names the wrench and the reason (empty tension interval, solver status); move the bases closer to
    the platform, lower the payload or widen the tension bounds.
    """
