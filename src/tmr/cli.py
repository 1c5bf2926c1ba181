"""The ``tmr`` command: one entry point for every tool, ``tmr <command> [options]``.

``tmr plan`` (= ``python -m tmr.plan``), ``tmr mcdpr plan`` (= ``python -m tmr.mcdpr plan``), ``tmr ccma run``
(= ``python -m tmr.ccma run``), ``tmr sweep`` (= ``python -m tmr.sweep``), ``tmr export`` (= ``python -m
tmr.export``) and ``tmr replay`` (= ``python -m tmr.replay``): the arguments after the command go to that tool
unchanged (with ``prog="tmr <command>"``, the name its messages use), and its exit code is returned (0 success,
1 plan failed or check failed, 2 bad input, 130 interrupted). A tool's module is imported only when its command
runs, so ``tmr --help`` is fast.
"""

from __future__ import annotations

import difflib
import importlib
import sys
from collections.abc import Callable

__all__ = ["COMMANDS", "main"]

#: command -> (module with ``main(argv) -> int``, one-line description)
COMMANDS: dict[str, tuple[str, str]] = {
    "plan": ("tmr.plan", "plan a chain of tethered robots to a goal (Caruso 2021)"),
    "mcdpr": ("tmr.mcdpr.__main__", "MoPICK mobile cable-driven parallel robot (Rasheed 2019): tmr mcdpr plan ..."),
    "ccma": ("tmr.ccma.__main__", "agents moving a passive linkage (Kumar 2019): tmr ccma run ... / tmr ccma list"),
    "sweep": ("tmr.sweep.cli", "parameter sweeps: tmr sweep sensitivity|moga|bench ..."),
    "export": ("tmr.export.__main__", "export a run directory (ROS 2 bag in MCAP storage, ...)"),
    "replay": ("tmr.replay.__main__", "replay a run directory in MuJoCo"),
}


def _usage() -> str:
    width = max(map(len, COMMANDS))
    lines = [
        "usage: tmr <command> [options]    (tmr <command> --help for a command's options)",
        "",
        "Motion planning for teams of mobile robots joined by tethers, cables or passive linkages.",
        "",
        "commands:",
    ]
    lines += [f"  {name:{width}s}  {what}" for name, (_, what) in COMMANDS.items()]
    lines += [
        "",
        "Every command takes --out, --quiet/--verbose, --debug (tracebacks) and --version; those that draw figures",
        "--no-plots, those that draw a progress bar --no-progress, those with random choices (plan, mcdpr plan,",
        "sweep) --seed, those whose output is a motion (plan, mcdpr plan, ccma run) --gif, --html and --export.",
        "Exit codes: 0 success, 1 no plan / a check failed, 2 bad input, 130 interrupted.",
    ]
    return "\n".join(lines)


def _load(name: str) -> Callable[..., int] | None:
    module_name = COMMANDS[name][0]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and module_name.startswith(exc.name):  # the tool itself is not there
            return None
        raise
    return module.main


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``tmr`` console script; returns the exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:  # a refusal is one line
        print(f"tmr: error: a command is required: {', '.join(COMMANDS)} (see tmr --help)", file=sys.stderr)
        return 2
    if args[0] in ("-h", "--help"):
        try:
            print(_usage())
        except BrokenPipeError:  # e.g. tmr --help | head -3
            pass
        return 0
    if args[0] == "--version":
        from importlib.metadata import PackageNotFoundError, version

        try:
            print(f"tmr {version('tmr')}")
        except PackageNotFoundError:  # pragma: no cover - a source tree without installation
            print("tmr (not installed)")
        return 0
    name = args[0]
    if name not in COMMANDS:
        close = difflib.get_close_matches(name, list(COMMANDS), n=1)
        hint = f"; did you mean '{close[0]}'?" if close else f"; commands: {', '.join(COMMANDS)}"
        print(f"tmr: error: unknown command {name!r}{hint}", file=sys.stderr)
        return 2
    try:
        entry = _load(name)  # the command's imports: a Ctrl-C here is one line and 130 too
        if entry is None:
            print(f"tmr: error: 'tmr {name}' is not available in this version of tmr", file=sys.stderr)
            return 2
        return int(entry(args[1:], prog=f"tmr {name}"))  # the tool's messages name it as it was called
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except KeyboardInterrupt:  # a tool without tmr.io.console.run
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
