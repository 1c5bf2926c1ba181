"""Command line: ``python -m tmr.sweep sensitivity|moga|bench …``.

* ``sensitivity`` — Caruso 2021 §5.1 / Fig. 9: f1–f4 over a k_v0 × d_min grid (nominal · [0.5, 2.0]) for each
  ``--methods``; writes ``sensitivity_<S>.md``, ``sensitivity_<S>_<method>.csv``, ``sensitivity_<S>_<method>.png``
  (failed cells black) and ``sensitivity_<S>_<method>_raw.png`` (values of the recorded motion, failed cells ×).
* ``moga`` — NSGA-II over the controller parameters (Caruso 2021 §4.2.2); writes ``moga_<S>_<method>.md`` (Pareto
  front + chosen set), ``.csv`` (every evaluation) and ``.png`` (pairwise objective plots).
* ``bench`` — scenarios × methods; writes ``bench.md``, ``bench.csv`` (scores) and ``bench_timing.csv``.

Runs locally on every core by default (``--jobs N``; ``--jobs 1`` = in this process) or on a Dask cluster with
``--scheduler tcp://host:port``. Same arguments and seed → the same bytes in every file except ``bench_timing.csv``,
whichever the executor. Inputs are validated first; files are written to a temporary directory and moved into
``--out`` only when all are complete.

A re-used ``--out`` keeps no output of an older run of the same command (the files of :func:`owned_names` that this
run did not write are deleted; other files are left alone). Messages go through :mod:`logging` (``--quiet``,
``--verbose``, ``--debug``: :mod:`tmr.io.console`); the progress bar is drawn on a terminal only, not with ``--quiet``
or ``--no-progress``.

Exit codes: 0 done; 2 bad input or a run error (nothing written); 130 interrupted (Ctrl-C; nothing written).
"""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tmr.io.cli_args import ArgumentParser, add_common, param, path_arg, positive_float
from tmr.io.cli_args import count as _positive
from tmr.io.console import LOG, progress_enabled
from tmr.io.console import run as run_cli
from tmr.planner import METHODS
from tmr.sweep.errors import SweepError

__all__ = ["build_parser", "main"]


def _var(text: str) -> Any:
    from tmr.sweep.moga import Variable

    key, sep, rng = text.partition("=")
    lo, sep2, hi = rng.partition(":")
    try:
        low, high = float(lo), float(hi)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected NAME=LOW:HIGH, got {text!r}") from exc
    if not sep or not sep2 or not key:
        raise argparse.ArgumentTypeError(f"expected NAME=LOW:HIGH, got {text!r}")
    return Variable(key, low, high)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``python -m tmr.sweep``; ``prog``: the name it shows (``tmr sweep`` through the dispatcher)."""
    p = ArgumentParser(
        prog=prog or "python -m tmr.sweep",
        description="Parameter sweeps of the tethered-chain planner (Caruso 2021 §5.1, §4.2.2): a sensitivity grid, "
        "NSGA-II tuning (moga) and a scenarios x methods table (bench), on every core or a Dask cluster.",
    )
    sub = p.add_subparsers(dest="command", required=True)
    common = ArgumentParser(add_help=False)
    common.add_argument(
        "--set",
        type=param,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="fixed parameter override by its field name in tmr.model.params (repeatable)",
    )
    common.add_argument("--jobs", type=_positive, help="local worker processes (default: all cores; 1 = serial)")
    common.add_argument("--scheduler", help="Dask scheduler address tcp://host:port (instead of local processes)")
    common.add_argument(
        "--connect-timeout",
        type=positive_float,
        default=10.0,
        help="seconds to wait for the Dask scheduler (default 10)",
    )
    add_common(common, out="runs/sweep", seed_help="seed of the leader's RRT* and of NSGA-II", views=False)

    s = sub.add_parser("sensitivity", parents=[common], help="k_v0 × d_min grid (Caruso 2021 §5.1, Fig. 9)")
    s.add_argument("--scenario", type=path_arg, default="D", help="scenario (default D, the paper's plane case study)")
    s.add_argument(
        "--methods",
        nargs="+",
        default=["pinv", "qp"],
        choices=list(METHODS),
        help="pinv sweeps d_min × k_v0; qp and horizon sweep d_safe × approach_rate (default: pinv qp)",
    )
    s.add_argument(
        "--n", type=_positive, nargs="+", default=[13], help="grid points per axis, or two: columns rows (default 13)"
    )
    s.add_argument("--low", type=positive_float, default=0.5, help="lowest factor on the nominal values (default 0.5)")
    s.add_argument(
        "--high", type=positive_float, default=2.0, help="highest factor on the nominal values (default 2.0)"
    )

    m = sub.add_parser("moga", parents=[common], help="NSGA-II tuning of the controller parameters (§4.2.2)")
    m.add_argument(
        "--scenario", type=path_arg, default="D", help="scenario to tune on (default D, the paper's plane case study)"
    )
    m.add_argument(
        "--method", default="pinv", choices=["pinv", "qp"], help="formulation whose parameters are tuned (default pinv)"
    )
    m.add_argument("--pop", type=_positive, default=16, help="population size (default 16)")
    m.add_argument("--gen", type=_positive, default=6, help="generations (default 6)")
    m.add_argument(
        "--var", type=_var, action="append", metavar="NAME=LOW:HIGH", help="decision variable (default: the method's)"
    )

    b = sub.add_parser("bench", parents=[common], help="scenarios × methods table")
    b.add_argument(
        "--scenarios", type=path_arg, nargs="+", default=["A", "B", "C", "D"], help="scenarios (default A B C D)"
    )
    b.add_argument(
        "--methods", nargs="+", default=list(METHODS), choices=list(METHODS), help="formulations (default: all)"
    )
    b.add_argument("--repeats", type=_positive, default=1, help="plans per cell for the timing median (default 1)")
    b.add_argument("--robots", type=_positive, help="number of robots N (default: the scenario's)")
    return p


def canonical_command(args: argparse.Namespace) -> str:
    """The command line without the executor options (``--jobs``, ``--scheduler``, ``--out``, progress/plots), so
    reports do not depend on where the sweep ran."""
    parts = ["python", "-m", "tmr.sweep", args.command]
    skip = {"command", "jobs", "scheduler", "connect_timeout", "out", "no_progress", "no_plots"}
    skip |= {"quiet", "verbose", "debug"}
    for key, val in vars(args).items():
        if key in skip or val is None or val == []:
            continue
        flag = "--" + key.replace("_", "-")
        if key == "set":
            for k, v in val:
                parts += [flag, f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"]
        elif key == "var":
            for v in val:
                parts += [flag, f"{v.name}={v.low:g}:{v.high:g}"]
        elif isinstance(val, list):
            parts += [flag, *map(str, val)]
        elif isinstance(val, float):
            parts += [flag, f"{val:g}"]
        else:
            parts += [flag, str(val)]
    return shlex.join(parts)


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in Path(name).stem)


def _sensitivity(args: argparse.Namespace, executor: Any) -> dict[str, Callable[[Path], Any]]:
    from tmr.sweep.grid import SensitivityResult, sensitivity_grid, sensitivity_specs
    from tmr.sweep.report import csv_text, heatmap_figure, sensitivity_markdown
    from tmr.sweep.runs import evaluate_run

    if len(args.n) > 2:
        raise SweepError(f"--n takes one or two integers, got {args.n}")
    n = args.n[0] if len(args.n) == 1 else tuple(args.n)
    grids = {method: sensitivity_grid(n, args.low, args.high, method) for method in args.methods}
    results = []
    for method, grid in grids.items():
        specs = sensitivity_specs(grid, args.scenario, method, args.seed, dict(args.set))
        res = executor.map(evaluate_run, specs, desc=f"sensitivity {args.scenario} {method}")
        results.append(SensitivityResult(grid, args.scenario, method, args.seed, tuple(res)))
    tag = _safe(args.scenario)
    files: dict[str, Callable[[Path], Any]] = {
        f"sensitivity_{tag}.md": lambda p: p.write_text(sensitivity_markdown(results, canonical_command(args)))
    }
    for r in results:
        files[f"sensitivity_{tag}_{r.method}.csv"] = lambda p, r=r: p.write_text(csv_text([x.row() for x in r.results]))
        if not args.no_plots:
            files[f"sensitivity_{tag}_{r.method}.png"] = lambda p, r=r: _save(heatmap_figure(r), p)
            files[f"sensitivity_{tag}_{r.method}_raw.png"] = lambda p, r=r: _save(heatmap_figure(r, raw=True), p)
    return files


def _moga(args: argparse.Namespace, executor: Any) -> dict[str, Callable[[Path], Any]]:
    from tmr.sweep.moga import run_moga
    from tmr.sweep.report import csv_text, moga_figure, moga_markdown, moga_rows

    res = run_moga(
        args.scenario,
        args.method,
        variables=args.var,
        pop_size=args.pop,
        n_gen=args.gen,
        seed=args.seed,
        base=dict(args.set),
        executor=executor,
    )
    stem = f"moga_{_safe(args.scenario)}_{args.method}"
    files: dict[str, Callable[[Path], Any]] = {
        f"{stem}.md": lambda p: p.write_text(moga_markdown(res, canonical_command(args))),
        f"{stem}.csv": lambda p: p.write_text(csv_text(moga_rows(res))),
    }
    if not args.no_plots:
        files[f"{stem}.png"] = lambda p: _save(moga_figure(res), p)
    return files


def _bench(args: argparse.Namespace, executor: Any) -> dict[str, Callable[[Path], Any]]:
    from tmr.sweep.bench import bench_markdown, bench_specs
    from tmr.sweep.report import csv_text
    from tmr.sweep.runs import evaluate_run

    specs = bench_specs(args.scenarios, args.methods, args.seed, args.repeats, args.robots, dict(args.set))
    res = executor.map(evaluate_run, specs, desc="bench")
    cmd = canonical_command(args)
    md = f"# Formulations on scenarios {', '.join(args.scenarios)}\n\n`{cmd}`\n\n" + bench_markdown(res, timing=False)
    return {
        "bench.md": lambda p: p.write_text(md),
        "bench.csv": lambda p: p.write_text(csv_text([r.row() for r in res])),
        "bench_timing.csv": lambda p: p.write_text(
            csv_text(
                [
                    {
                        "scenario": r.spec.scenario,
                        "method": r.spec.method,
                        "plan_time": r.plan_time,
                        "ms_per_step": r.ms_per_step,
                    }
                    for r in res
                ]
            )  # fmt: skip
        ),
    }


def _save(fig: Any, path: Path) -> None:
    from tmr.views.plot import save_figure

    save_figure(fig, path)


def _validate(args: argparse.Namespace) -> None:
    from tmr.sweep.runs import check_overrides
    from tmr.world.scenario import load_scenario

    for name in getattr(args, "scenarios", None) or [args.scenario]:
        load_scenario(name)
    check_overrides(dict(args.set))
    if getattr(args, "var", None):
        from dataclasses import fields

        from tmr.model.params import PARAM_CLASSES

        kinds = {f.name: (cls, type(getattr(cls(), f.name))) for cls in PARAM_CLASSES for f in fields(cls)}
        for v in args.var:
            check_overrides({v.name: v.low, **dict(args.set)})
            cls, kind = kinds[v.name]
            if kind is not float:  # NSGA-II proposes real numbers: an int field would refuse them mid-run
                raise SweepError(f"--var {v.name}: {cls.__name__}.{v.name} is not a real number; vary a float field")
    from tmr.io.outdir import check_out

    check_out(Path(args.out), owned_names(args))


def owned_names(args: argparse.Namespace) -> list[str]:
    """Every file the command of ``args`` can write into ``--out`` (for the stale-output cleanup)."""
    if args.command == "sensitivity":
        tag = _safe(args.scenario)
        names = [f"sensitivity_{tag}.md"]
        for method in METHODS:
            stem = f"sensitivity_{tag}_{method}"
            names += [f"{stem}.csv", f"{stem}.png", f"{stem}_raw.png"]
        return names
    if args.command == "moga":
        stem = f"moga_{_safe(args.scenario)}_{args.method}"
        return [f"{stem}.md", f"{stem}.csv", f"{stem}.png"]
    return ["bench.md", "bench.csv", "bench_timing.csv"]


def write_outputs(out: Path, files: dict[str, Callable[[Path], Any]], owned: Any = None) -> list[str]:
    """Write every file (``files``: name → writer of that path) into a staging directory, then publish them into
    ``out`` in one step (:mod:`tmr.io.outdir`); files of ``owned`` names an older sweep wrote there and this one did
    not are removed."""
    from tmr.io.outdir import Stage

    with Stage(out, sorted(set(owned or ()) | set(files)), volatile=[n for n in files if "timing" in n]) as stage:
        for name, writer in files.items():
            writer(stage.path / name)
        return stage.publish()


def main(argv: list[str] | None = None, executor: Any = None, prog: str | None = None) -> int:
    """Entry point; ``executor`` (an object with ``map``) overrides ``--jobs``/``--scheduler`` (for tests); ``prog``:
    the name messages use (``tmr sweep`` through the dispatcher)."""
    args = build_parser(prog).parse_args(argv)
    return run_cli(lambda a: _main(a, executor), args)


def _main(args: argparse.Namespace, executor: Any = None) -> int:
    from tmr.sweep.executor import make_executor

    own = executor is None
    _validate(args)
    if own:
        progress = progress_enabled()  # a terminal, not --quiet, not --no-progress
        executor = make_executor(args.jobs, args.scheduler, progress=progress, timeout=args.connect_timeout)
    try:
        run = {"sensitivity": _sensitivity, "moga": _moga, "bench": _bench}[args.command]
        files = run(args, executor)
        names = write_outputs(Path(args.out), files, owned_names(args))
    finally:
        if own and executor is not None:
            executor.close()
    LOG.info("tmr sweep %s: wrote %s to %s", args.command, ", ".join(names), args.out)
    return 0
