"""Shared command-line argument types."""

from __future__ import annotations

import argparse
import re

import pytest

from tmr import cli
from tmr.errors import fmt_point
from tmr.io.cli_args import SEED_MAX, bounds, count, param, point, points, positive_float, seed


def test_positive_float():
    assert positive_float("0.25") == 0.25
    for bad in ("0", "-1", "nan", "inf", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            positive_float(bad)


# ---- one validator per parameter type ------------------------------------------------------------------------


def test_count_refuses_fractions_instead_of_truncating():
    assert count("7") == 7 and count("3") == 3
    for bad in ("2.5", "1e3", "0", "-1", "-2", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError):
            count(bad)


def test_seed_range_is_what_every_rng_accepts():
    import numpy as np

    from tmr.route.path import _as_int

    assert seed("0") == 0 and seed(str(SEED_MAX)) == SEED_MAX
    for bad in ("-1", "1e308", "2.5", str(SEED_MAX + 1), "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            seed(bad)
    assert _as_int(SEED_MAX, "seed", 0, 2**32 - 2) == SEED_MAX  # the RRT*'s own check (OMPL seeded with seed + 1)
    np.random.default_rng(SEED_MAX)  # MoPICK's search and NSGA-II


def test_points_and_bounds():
    assert point(" -2.5, 1") == (-2.5, 1.0)
    assert points("1,2;3,4;").tolist() == [[1, 2], [3, 4]]
    assert bounds("0,0,10,5") == (0, 0, 10, 5)
    for fn, bad in ((point, "inf,0"), (point, "1,2,3"), (points, ";"), (points, "1,nan"), (bounds, "0,0,0,5")):
        with pytest.raises(argparse.ArgumentTypeError):
            fn(bad)


def test_param_is_typed_by_its_tmr_params_field():
    assert param("path_iterations=200") == ("path_iterations", 200)
    assert isinstance(param("path_iterations=200")[1], int)
    assert param("d_min = 0.6") == ("d_min", 0.6) and param("solver=daqp") == ("solver", "daqp")
    cases = {
        "path_iterations=2.5": "takes a whole number",
        "d_min=nan": "finite",
        "d_min=abc": "takes a number",
        "d_min=-1": "must be > 0",
        "no_such=1": "no_such=1: unknown parameter 'no_such'",  # echoed as typed, not as 1.0
        "d_mni=1": "did you mean d_min?",
        "d_min": "expected NAME=VALUE",
    }
    for text, words in cases.items():
        with pytest.raises(argparse.ArgumentTypeError, match=re.escape(words)):
            param(text)


def test_int_fields_refuse_fractions_in_every_path():
    from tmr.errors import ParameterError
    from tmr.model.params import PathParams, apply_overrides

    assert apply_overrides(PathParams(), {"path_iterations": 2.0})[0].path_iterations == 2
    with pytest.raises(ParameterError, match="whole number"):
        apply_overrides(PathParams(), {"path_iterations": 2.5})  # a scenario's [params] or the API


def test_fmt_point_rounds_to_the_millimetre():
    assert fmt_point([3.6750000000000003, 1.725]) == "(3.675, 1.725)"
    assert fmt_point((2.0, -0.0001, 0.5)) == "(2, 0, 0.5)"


# ---- one-line errors naming the command as it was called ---------------------------------------------------------


def _call(argv: list[str], capsys) -> tuple[int, str, str]:
    code = cli.main(argv)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["plan", "--robots", "0"], "tmr plan: error: --robots: must be a whole number ≥ 1 or 'auto', got '0'"),
        (["plan", "--robot-radius", "nan"], "tmr plan: error: --robot-radius: must be a finite number > 0"),
        (["plan", "--goal", "inf,0"], "tmr plan: error: --goal: expected X,Y in metres (finite numbers)"),
        (["plan", "--set", "d_min=nan"], "tmr plan: error: --set: d_min=nan: PinvParams.d_min must be finite"),
        (["plan", "--time-limit", "-5"], "tmr plan: error: --time-limit: must be a finite number > 0"),
        (["plan", "--seed", "1e308"], "tmr plan: error: --seed: expected a whole number in 0 … 4294967294"),
        (["plan", "--seed", "-1"], "tmr plan: error: --seed: must be in 0 … 4294967294, got -1"),
        (["plan", "--seed", "-1", "--route", "rrt"], "tmr plan: error: --seed: must be in 0 … 4294967294"),
        (["plan", "--set", "path_iterations=2.5"], "tmr plan: error: --set: path_iterations=2.5: PathParams."),
        (["plan", "--filter-cutoff", "0"], "tmr plan: error: --filter-cutoff: must be a finite number > 0"),
        (["plan", "-q", "-v"], "tmr plan: error: --verbose: not allowed with argument -q/--quiet"),
        (["mcdpr", "plan", "--seed", "-1"], "tmr mcdpr plan: error: --seed: must be in 0"),
        (["mcdpr", "workspace", "--cell", "0"], "tmr mcdpr workspace: error: --cell: must be a finite number > 0"),
        (["mcdpr"], "tmr mcdpr: error: the following arguments are required: command (see tmr mcdpr --help)"),
        (["ccma", "run", "--steps", "2.5"], "tmr ccma run: error: --steps: expected a whole number ≥ 1"),
        (["sweep", "bench", "--seed", "x"], "tmr sweep bench: error: --seed: expected a whole number"),
        (["sweep", "bench", "--set", "no_such=1"], "tmr sweep bench: error: --set: no_such=1: unknown parameter"),
        (["export", "run", "--rate", "inf"], "tmr export: error: --rate: must be a finite number > 0"),
        (["replay", "run", "--links", "0"], "tmr replay: error: --links: must be ≥ 1, got 0"),
    ],
)
def test_usage_error_is_one_line_naming_the_command(argv, line, capsys):
    code, out, err = _call(argv, capsys)
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and err.startswith(line), err


def test_python_m_form_names_itself(capsys):
    from tmr.mcdpr.__main__ import main as mcdpr_main
    from tmr.plan import main as plan_main

    with pytest.raises(SystemExit) as exc:
        plan_main(["--robots", "0"])
    assert exc.value.code == 2 and capsys.readouterr().err.startswith("python -m tmr.plan: error: --robots:")
    with pytest.raises(SystemExit):
        mcdpr_main(["plan", "--max-iter", "0"])
    assert capsys.readouterr().err.startswith("python -m tmr.mcdpr plan: error: --max-iter: must be ≥ 1")


@pytest.mark.parametrize(
    "argv",
    [["plan"], ["mcdpr"], ["mcdpr", "plan"], ["mcdpr", "workspace"], ["ccma", "run"], ["ccma", "list"], ["sweep"]]
    + [["sweep", "moga"], ["export"], ["replay"]],
)
def test_every_command_prints_its_version(argv, capsys):
    from importlib.metadata import version

    code, out, _ = _call([*argv, "--version"], capsys)
    assert code == 0 and out.strip() == f"tmr {' '.join(argv)} {version('tmr')}"


# ---- the common flags, where they mean something -----------------------------------------------------------------


def _parsers():
    from tmr.ccma.__main__ import build_parser as ccma
    from tmr.export.__main__ import build_parser as export
    from tmr.mcdpr.__main__ import build_parser as mcdpr
    from tmr.plan import build_parser as plan
    from tmr.replay.__main__ import build_parser as replay
    from tmr.sweep.cli import build_parser as sweep

    def sub(parser, name):
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        return action.choices[name]

    yield "plan", plan()
    yield "mcdpr plan", sub(mcdpr(), "plan")
    yield "mcdpr workspace", sub(mcdpr(), "workspace")
    yield "ccma run", sub(ccma(), "run")
    for name in ("sensitivity", "moga", "bench"):
        yield f"sweep {name}", sub(sweep(), name)
    yield "export", export()
    yield "replay", replay()


#: Which command takes which shared flag (what ``tmr --help`` and the README say).
EXPECTED = {
    "--seed": {"plan", "mcdpr plan", "sweep sensitivity", "sweep moga", "sweep bench"},
    "--no-plots": {"plan", "mcdpr plan", "mcdpr workspace", "ccma run", "sweep sensitivity", "sweep moga"}
    | {"sweep bench", "replay"},
    "--no-progress": {"plan", "mcdpr plan", "ccma run", "sweep sensitivity", "sweep moga", "sweep bench", "export"}
    | {"replay"},
    "--html": {"plan", "mcdpr plan", "ccma run"},
    "--export": {"plan", "mcdpr plan", "ccma run"},
}


def test_shared_flags_are_where_they_mean_something():
    parsers = dict(_parsers())
    for name, parser in parsers.items():
        flags = {s for a in parser._actions for s in a.option_strings}
        assert {"--out", "--quiet", "--verbose", "--debug", "--version"} <= flags, name
        for flag, where in EXPECTED.items():
            assert (flag in flags) == (name in where), (flag, name)
    usage = cli._usage()
    assert "--no-progress" in usage and "--version" in usage and "(plan, mcdpr plan,\nsweep) --seed" in usage


def test_seed_is_one_type_everywhere():
    for name, parser in _parsers():
        for action in parser._actions:
            if "--seed" in action.option_strings:
                assert action.type is seed, name


def test_no_progress_turns_every_bar_off():
    from tmr.io import console
    from tmr.plan import build_parser

    class Terminal:
        def isatty(self):
            return True

    build_parser().parse_args(["--no-progress"])
    assert console.progress_enabled(Terminal()) is False
    build_parser().parse_args([])
    assert console.progress_enabled(Terminal()) is True
