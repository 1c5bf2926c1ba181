"""What every tmr command line shares: its parser, its argument types and its common flags.

* :class:`ArgumentParser`: a usage error is ONE line on stderr, ``PROG: error: --flag: message``, exit 2, with
  ``PROG`` the command as the user called it (``tmr plan`` through the ``tmr`` dispatcher, ``python -m tmr.plan``
  run that way; ``tmr mcdpr plan`` for a sub-command); ``--version`` prints the version.
* One ``type=`` callable per kind of value, so a value means the same and is refused with the same words in every
  command: :func:`count` (≥ 1), :func:`seed` (``0 … SEED_MAX``), :func:`positive_float`, :func:`finite_float`,
  :func:`point` (``X,Y``), :func:`points` (``X1,Y1;X2,Y2;…``), :func:`bounds`, :func:`param` (``NAME=VALUE``
  checked against the field of :mod:`tmr.model.params` it names) and :func:`out_path` (``--out``). Their messages do not
  repeat the flag: the parser prefixes it.
* :func:`add_common`: the flags every command takes where they mean something (``--out --seed --no-plots
  --no-progress --gif --html --export --quiet --verbose --debug``).
"""

from __future__ import annotations

import argparse
import math
import re
from typing import Any, NoReturn

import numpy as np

__all__ = [
    "SEED_MAX",
    "ArgumentParser",
    "add_common",
    "bounds",
    "count",
    "finite_float",
    "out_path",
    "param",
    "path_arg",
    "point",
    "points",
    "positive_float",
    "seed",
]

#: The largest seed: RRT* seeds OMPL with ``seed + 1`` (OMPL rejects 0; its seeds are 32-bit), numpy's
#: ``default_rng`` (MoPICK's search, NSGA-II) takes any integer ≥ 0. So every command takes 0 … 2**32 − 2.
SEED_MAX = 2**32 - 2


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("tmr")
    except PackageNotFoundError:  # pragma: no cover - a source tree without installation
        return "(not installed)"


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose errors are one line (``PROG: error: --flag: message``, exit 2; no usage
    block) and which takes ``--version`` (when it has ``--help``). Sub-parsers are of this class too."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.add_help:
            self.add_argument("--version", action="version", version=f"%(prog)s {_version()}", help="print the version")

    def error(self, message: str) -> NoReturn:
        # argparse says "argument -q/--quiet: ..."; name the long flag alone, as the user would type it
        match = re.match(r"argument (\S+): ", message)
        if match:
            names = match.group(1).split("/")
            message = f"{next((n for n in names if n.startswith('--')), names[-1])}: {message[match.end() :]}"
        hint = f" (see {self.prog} --help)" if message.startswith(("unrecognized", "the following")) else ""
        message = _one_line(message)  # a value with a line break (--set $'a\nb=1') still makes one line
        self.exit(2, f"{self.prog}: error: {message}{hint}\n")

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        ns, rest = super().parse_known_args(args, namespace)
        from tmr.io.console import set_progress

        set_progress(not getattr(ns, "no_progress", False))  # --no-progress: tmr.io.console.progress_enabled
        return ns, rest


def _one_line(text: str) -> str:
    """``text`` with its line breaks written as ``\\n`` / ``\\r``: an error is one line whatever the user typed."""
    return text.replace("\r", "\\r").replace("\n", "\\n")


def _number(text: str, what: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None


def _integer(text: str, what: str) -> int:
    """``text`` as an integer; ``2.5`` or ``1e308`` are refused with ``what`` (not truncated)."""
    try:
        return int(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None


def count(text: str) -> int:
    """A whole number ≥ 1 (counts: robots, repeats, jobs, iterations, links, generations)."""
    v = _integer(text, "a whole number ≥ 1")
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be ≥ 1, got {v}")
    return v


def seed(text: str) -> int:
    """A seed: a whole number in ``0 … SEED_MAX`` (what both OMPL's RRT* and numpy's generators accept)."""
    v = _integer(text, f"a whole number in 0 … {SEED_MAX}")
    if not 0 <= v <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"must be in 0 … {SEED_MAX}, got {v}")
    return v


def positive_float(text: str) -> float:
    """A finite number > 0 (lengths, steps, tolerances, times, rates)."""
    v = _number(text, "a positive number")
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return v


def finite_float(text: str) -> float:
    """A finite number (no NaN, no inf)."""
    v = _number(text, "a number")
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return v


def _floats(text: str, n: int | None, what: str) -> list[float]:
    parts = [p for p in text.replace(" ", "").split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if (n is not None and len(vals) != n) or not all(math.isfinite(v) for v in vals):
        raise argparse.ArgumentTypeError(f"expected {what} (finite numbers), got {text!r}")
    return vals


def point(text: str) -> tuple[float, float]:
    """``X,Y`` [m]: two finite numbers."""
    x, y = _floats(text, 2, "X,Y in metres")
    return x, y


def goal_pose(text: str) -> tuple[float, ...]:
    """``X,Y`` [m] or ``X,Y,THETA``: THETA the leader's final heading in degrees (counter-clockwise from +x; a
    ``deg`` suffix is allowed, a ``rad`` suffix gives radians). Returns (x, y) or (x, y, theta [rad])."""
    parts = text.replace(" ", "").split(",")
    if len(parts) > 3:
        raise argparse.ArgumentTypeError(
            f"expected X,Y or X,Y,THETA (metres, THETA in degrees or with a rad suffix), got {text!r}"
        )
    if len(parts) != 3:
        return point(text)
    theta, scale = parts[2].lower(), math.pi / 180.0
    if theta.endswith("deg"):
        theta = theta[:-3]
    elif theta.endswith("rad"):
        theta, scale = theta[:-3], 1.0
    try:
        x, y, th = _floats(",".join([*parts[:2], theta]), 3, "")
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"expected X,Y or X,Y,THETA (finite; metres, THETA in degrees or with a rad suffix), got {text!r}"
        ) from None
    return x, y, th * scale


def points(text: str) -> np.ndarray:
    """``X1,Y1;X2,Y2;…`` [m]: one or more points, as an (n, 2) array."""
    pts = [_floats(p, 2, "X1,Y1;X2,Y2;… in metres") for p in text.split(";") if p.strip()]
    if not pts:
        raise argparse.ArgumentTypeError(f"expected X1,Y1;X2,Y2;… in metres, got {text!r}")
    return np.array(pts, dtype=float)


def bounds(text: str) -> tuple[float, float, float, float]:
    """``XMIN,YMIN,XMAX,YMAX`` [m]: a rectangle of positive size."""
    x0, y0, x1, y1 = _floats(text, 4, "XMIN,YMIN,XMAX,YMAX in metres")
    if not (x0 < x1 and y0 < y1):
        raise argparse.ArgumentTypeError(f"need XMIN < XMAX and YMIN < YMAX, got {text!r}")
    return x0, y0, x1, y1


def param(text: str) -> tuple[str, Any]:
    """``NAME=VALUE``: NAME a field of the parameter classes of :mod:`tmr.model.params`, VALUE of that field's type
    (an int field refuses ``2.5``, a float field ``nan``) and within its range; returns ``(NAME, typed value)``."""
    import difflib
    from dataclasses import fields

    from tmr.errors import ParameterError
    from tmr.model.params import PARAM_CLASSES, DroneParams, convert_field

    key, sep, value = (part.strip() for part in text.partition("="))
    if not sep or not key or not value:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, e.g. d_min=0.6, got {text!r}")
    from tmr.model.catenary3d import DroneTetherParams

    drone_classes: tuple[type, ...] = (DroneParams, DroneTetherParams)
    # every class with that field: a name both systems use (the winch's ``winch``, ``winch_tension_min``, …) is taken
    # if either accepts the value; the planner of the scenario's kind then checks it with its own (tmr.planner,
    # tmr.planner3d refuse the other system's names)
    owners = [cls for cls in PARAM_CLASSES + drone_classes if key in {f.name for f in fields(cls)}]
    if not owners:
        known = {f.name for cls in PARAM_CLASSES + drone_classes for f in fields(cls)}
        close = difflib.get_close_matches(key, sorted(known), n=3)
        hint = f"; did you mean {' or '.join(close)}?" if close else ""
        names = ", ".join(c.__name__ for c in PARAM_CLASSES + drone_classes)
        raise argparse.ArgumentTypeError(
            f"{key}={value}: unknown parameter {key!r}{hint} (the names are the fields of {names} in tmr.model.params)"
        )
    first: ParameterError | None = None
    for cls in owners:
        try:
            typed = convert_field(cls, key, value)
            # the field's own range (e.g. d_min > 0), the other fields at their defaults; a robot model is a
            # differential-drive robot's (drive = "diff", which another --set or --drive gives); T_end and Ts are
            # judged together (their step count, MAX_STEPS) where both are known, by the planner's precheck
            cls(**({key: typed} | _companions(cls, key, typed)))
            if key == "robot_model":
                typed = _robot_model_name(typed)
        except ParameterError as exc:
            first = first or exc
            continue
        return key, typed
    raise argparse.ArgumentTypeError(f"{key}={value}: {first}") from None


def _companions(cls: type, key: str, typed: Any) -> dict[str, Any]:
    """The other fields a field of ``cls`` is judged with on its own in ``--set`` (:func:`param`): a robot model with
    ``drive = "diff"``; ``T_end`` or ``Ts`` with the other equal to it (one step: the step count of the pair is judged
    when both are known)."""
    if key == "robot_model":
        return {"drive": "diff"}
    if cls.__name__ == "TimeParams" and key in ("T_end", "Ts") and typed > 0:
        return {"T_end": typed, "Ts": typed}
    return {}


def _robot_model_name(text: str) -> str:
    """The preset's full name (``burger`` → ``turtlebot3_burger``, as the records keep it) or the file as given, once
    the model loads (:func:`tmr.model.diffdrive.load_robot_model`; ParameterError otherwise)."""
    from tmr.model.diffdrive import canonical_model_name, load_robot_model

    load_robot_model(text)
    return canonical_model_name(text)


def robot_model_arg(text: str) -> str:
    """``--robot-model NAME|FILE``: a preset (or its short name) or a robot model TOML file that loads
    (:func:`tmr.model.diffdrive.load_robot_model`); returns the preset's full name (``burger`` →
    ``turtlebot3_burger``, as the records keep it) or the file as given."""
    from tmr.errors import ParameterError

    if not text.strip():
        raise argparse.ArgumentTypeError("must name a robot model preset or a .toml file, got an empty value")
    try:
        return _robot_model_name(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def path_arg(text: str) -> str:
    """A file or directory the user names (``--scenario``, ``--map``, ``--scene``, a run directory, ...): not empty,
    not blank, no NUL byte. An empty value would otherwise mean the default (``--map ''`` planned scenario A) or the
    current directory; whether the file exists and can be read is judged by its reader (:mod:`tmr.files`)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a file, got an empty value")
    if "\0" in text:
        raise argparse.ArgumentTypeError("must not contain a NUL byte")
    return text


def out_path(text: str) -> str:
    """An ``--out`` path: not empty, not blank, no NUL byte (an empty ``--out`` would write into the current
    directory). Only the text is judged here; whether the place can take the outputs is judged by
    :func:`tmr.io.outdir.check_out` before any work."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a directory, got an empty path")
    if "\0" in text:
        raise argparse.ArgumentTypeError("must not contain a NUL byte")
    return text


def add_common(
    parser: argparse.ArgumentParser,
    *,
    out: str | None,
    out_help: str | None = None,
    seed_help: str | None = None,
    plots: bool = True,
    progress: bool = True,
    views: bool = True,
) -> None:
    """Add the flags shared by tmr's commands to ``parser``, those that mean something for it:

    ``--out`` (default ``out``; ``out_help`` replaces the help text), ``--seed`` (if its help ``seed_help`` is
    given), ``--no-plots`` (``plots``), ``--no-progress`` (``progress``: the command draws a progress bar),
    ``--gif --html --export`` (``views``: the command's output is a motion, :mod:`tmr.views.flags`) and ``--quiet
    --verbose --debug`` (always, :func:`tmr.io.console.add_manners`)."""
    from tmr.io.console import add_manners

    g = parser.add_argument_group("output")
    default = f" (default {out})" if out else ""
    g.add_argument("--out", type=out_path, default=out, help=out_help or f"output directory{default}")
    if seed_help:
        g.add_argument("--seed", type=seed, default=0, metavar="S", help=f"{seed_help} (0 … 2**32−2, default 0)")
    if plots:
        g.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    if progress:
        g.add_argument("--no-progress", action="store_true", help="no progress bar (drawn on a terminal only)")
    if views:
        from tmr.views.flags import add_view_args

        add_view_args(parser)  # --gif, --html, --export FORMAT
    add_manners(parser)
