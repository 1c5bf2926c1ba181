"""Exceptions of the mobile cable-driven parallel robot package (Rasheed 2019)."""

from __future__ import annotations

from tmr.errors import ParameterError, ScenarioError, TmrError

__all__ = ["InfeasibleWrench", "McdprError", "NoPlanFound", "ParameterError", "ScenarioError", "TaskRefused"]


class McdprError(TmrError):
    """Base class of the errors raised on purpose by :mod:`tmr.mcdpr`."""


class InfeasibleWrench(McdprError):
    """No cable tensions within the (tipping-tightened) bounds produce the requested wrench (Rasheed 2019 eq. 2, 7).

    The message names the wrench and the reason (empty tension interval, solver status); move the bases closer to
    the platform, lower the payload or widen the tension bounds.
    """


class TaskRefused(McdprError):
    """The task is refused before any search (CLI exit 2): the start pose already violates a limit, or no placement
    of the bases can ever hold the platform (proven, e.g. weight above the sum of the cable limits).

    ``constraint`` names the limit (``"tension"``, ``"tipping"``, ``"capacity"``), ``value`` says by how much [N]."""

    def __init__(self, message: str, constraint: str = "", value: float = float("nan")) -> None:
        super().__init__(message)
        self.constraint = constraint
        self.value = value


class NoPlanFound(McdprError):
    """The search found no plan at its resolution (CLI exit 1).

    ``kind``: ``"no-placement"`` (a task point or a platform position on the path has no base placement with
    μ ≥ the margin among the candidates; ``best_mu`` is the best found [N]) or ``"not-connectable"`` (placements
    exist but no certified motion joins them; ``where`` the last platform position reached [m])."""

    def __init__(self, message: str, kind: str, where: tuple[float, ...] = (), best_mu: float = float("nan")) -> None:
        super().__init__(message)
        self.kind = kind
        self.where = where
        self.best_mu = best_mu
