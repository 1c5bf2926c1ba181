"""Argument types shared by tmr's command lines (``argparse`` ``type=`` callables with messages a user can act on)."""

from __future__ import annotations

import argparse
import math


def positive_int(text: str) -> int:
    """An integer ≥ 1 (counts: robots, repeats, jobs, iterations)."""
    try:
        v = int(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from exc
    if v < 1:
        raise argparse.ArgumentTypeError(f"need at least 1, got {v}")
    return v


def positive_float(text: str) -> float:
    """A finite number > 0 (lengths, steps, tolerances)."""
    try:
        v = float(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from exc
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return v


def out_path(text: str) -> str:
    """An ``--out`` path: not empty, not blank, no NUL byte (an empty ``--out`` would write into the current
    directory). Only the text is judged here; whether the place can take the outputs is judged by
    :func:`tmr.outdir.check_out_dir` before any work."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a directory, got an empty path")
    if "\0" in text:
        raise argparse.ArgumentTypeError("must not contain a NUL byte")
    return text
