"""Exceptions of the CCMA simulator (Kumar 2019). Every message says what is wrong and what to change."""

from __future__ import annotations

from typing import Any

from tmr.errors import TmrError

__all__ = ["AssemblyError", "CcmaError", "ConvergenceError", "DescriptionError", "ReachError"]


class CcmaError(TmrError):
    """Base class of the errors raised by :mod:`tmr.ccma`."""


class DescriptionError(CcmaError, ValueError):
    """A system description (TOML or Python dict) is inconsistent: unknown body, zero axis, free body, ..."""


class AssemblyError(CcmaError):
    """The mechanism cannot assemble for the given controls: the constraint energy stays above the tolerance.

    Attributes: ``residual`` (the residual constraint energy [m²]) and ``worst`` (name of the constraint with the
    largest violation).
    """

    def __init__(self, message: str, residual: float = float("nan"), worst: str = "") -> None:
        super().__init__(message)
        self.residual = residual
        self.worst = worst


class ConvergenceError(CcmaError):
    """Newton's method on the constraint energy did not converge (the chain may be at a singular configuration)."""


class ReachError(CcmaError):
    """A target of the path is proven out of the linkage's reach before any IK step (:func:`tmr.ccma.reach.check_reach`:
    beyond a leg's span, or past the singular configuration its tracking cannot cross); the command line exits 2 and
    writes nothing. ``verdict``: the :class:`tmr.ccma.reach.ReachVerdict` (which target, leg, by how much)."""

    def __init__(self, message: str, verdict: Any = None) -> None:
        super().__init__(message)
        self.verdict = verdict
