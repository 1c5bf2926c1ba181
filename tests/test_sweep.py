"""tmr.sweep: grids, the task function, executors (serial, process pool, Dask LocalCluster) giving identical results,
failure handling, NSGA-II tuning, reports and the ``python -m tmr.sweep`` CLI (determinism, bad input)."""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tmr.errors import InfeasibleStep, TmrError
from tmr.planner import build_problem, solve
from tmr.sweep import (
    LocalExecutor,
    RunSpec,
    SerialExecutor,
    SweepError,
    evaluate_run,
    sensitivity_grid,
    sensitivity_specs,
)
from tmr.sweep import runs as runs_mod
from tmr.sweep.bench import bench_markdown, bench_specs
from tmr.sweep.cli import main
from tmr.sweep.grid import SensitivityResult
from tmr.sweep.moga import Variable, choose, pareto_indices, run_moga
from tmr.sweep.report import csv_text, heatmap_figure, sensitivity_markdown
from tmr.world.scenario import load_scenario

#: a short plan: 6 s of the leader's time law (120 steps), a cheap RRT*
FAST = {"T_end": 6.0, "path_iterations": 200}
FAST_ARGS = ["--set", "T_end=6", "--set", "path_iterations=200", "--no-progress"]

#: A 9 m × 6 m room, 2 robots, one column just below the straight base–goal line: on the 2 × 2 corner grid of the
#: sweep, pinv clears it with the large k_v0 and lets a tether touch it with the small one.
TINY_MAP = """{"type": "FeatureCollection", "name": "tiny", "bounds": [0, 0, 9, 6],
 "features": [{"type": "Feature", "properties": {"name": "column", "radius": 0.4},
               "geometry": {"type": "Point", "coordinates": [4.5, 2.2]}}]}
"""
TINY_TOML = """name = "tiny"
robots = 2
base = [1.0, 3.0]
goal = [7.5, 3.0]
[map]
file = "tiny.geojson"
bounds = [0.0, 0.0, 9.0, 6.0]
safety_radius = 0.5
resolution = 0.05
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> str:
    d = tmp_path_factory.mktemp("scenario")
    (d / "tiny.geojson").write_text(TINY_MAP)
    (d / "tiny.toml").write_text(TINY_TOML)
    return str(d / "tiny.toml")


def _rows(results):
    return [r.row() for r in results]


def _same(a, b):
    """Rows equal, NaN == NaN."""
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        assert ra.keys() == rb.keys()
        for k in ra:
            va, vb = ra[k], rb[k]
            if isinstance(va, float) and math.isnan(va):
                assert isinstance(vb, float) and math.isnan(vb), k
            else:
                assert va == vb, k


# ------------------------------------------------------------------------------------------------------------------
# grid
# ------------------------------------------------------------------------------------------------------------------
def test_default_grid_is_the_papers_interval():
    g = sensitivity_grid()
    assert g.x_name == "d_min" and g.y_name == "k_v0"
    assert g.x[0] == 0.25 and g.x[-1] == 1.0  # d_min* = 0.5 m · [0.5, 2]
    assert g.y[0] == 0.025 and g.y[-1] == 0.1  # k_v0* = 0.05 m²/s · [0.5, 2]
    assert 0.5 in g.x and 0.05 in g.y  # odd n keeps the nominal point (factor 1 = 0.5 + 0.5 · 1.5 / 1.5 · …)
    assert np.allclose(np.diff(g.x), g.x[1] - g.x[0])
    assert g.shape == (13, 13)


def test_qp_grid_sweeps_its_own_counterparts():
    g = sensitivity_grid(3, method="qp")
    assert (g.x_name, g.y_name) == ("d_safe", "approach_rate")
    assert g.x == (0.025, 0.0625, 0.1) and g.y == (1.0, 2.5, 4.0)  # QPParams defaults 0.05 m, 2 1/s · [0.5, 2]


def test_grid_points_are_row_major_and_specs_carry_them():
    g = sensitivity_grid((3, 2))
    assert g.shape == (2, 3)
    pts = g.points()
    assert pts[:3] == [(g.x[0], g.y[0]), (g.x[1], g.y[0]), (g.x[2], g.y[0])]
    specs = sensitivity_specs(g, "C", "pinv", seed=4, base={"T_end": 2.0, "d_min": 9.0})
    assert len(specs) == 6
    for (x, y), s in zip(pts, specs, strict=True):
        assert s.seed == 4 and s.override("d_min") == x and s.override("k_v0") == y and s.override("T_end") == 2.0
        assert [k for k, _ in s.overrides].count("d_min") == 1  # the grid value wins over the base


@pytest.mark.parametrize(
    "kwargs",
    [{"n": 1}, {"n": (4, 1)}, {"low": 2.0, "high": 0.5}, {"low": 0.0}, {"nominal": {"k_v0": -1}}, {"method": "lp"}],
)
def test_bad_grid_raises(kwargs):
    with pytest.raises(SweepError):
        sensitivity_grid(**kwargs)


# ------------------------------------------------------------------------------------------------------------------
# the task
# ------------------------------------------------------------------------------------------------------------------
def test_cached_problem_gives_the_same_plan_as_a_fresh_build():
    over = {**FAST, "k_v0": 0.08, "d_min": 0.7, "clik_gain": 4.0}
    spec = RunSpec("C", "pinv", 3, tuple(sorted(over.items())))
    evaluate_run(RunSpec("C", "pinv", 3, tuple(sorted(FAST.items()))))  # fill the cache with the nominal controller
    r = evaluate_run(spec)
    plan, m = solve(build_problem(load_scenario("C"), seed=3, overrides=over, route="rrt"), "pinv")  # sweeps: rrt
    assert r.raw == tuple(m.fitness_raw)
    assert r.success == m.success and r.min_tether_clearance == m.min_tether_clearance
    spans = plan.spans - plan.spans.mean(axis=1, keepdims=True)
    assert r.distance_error_min == spans.min() and r.distance_error_max == spans.max()


def test_failed_plan_scores_inf_with_positive_violation():
    # scenario D with the paper's nominal gains: pinv lets a tether cross the plane (see formulations/pinv.md)
    r = evaluate_run(RunSpec("D", "pinv", 0, (("T_end", 6.0), ("path_iterations", 300))))
    if r.success:
        pytest.skip("this short run happens to succeed")
    assert r.fitness == (math.inf,) * 4
    assert all(math.isfinite(v) for v in r.raw)
    expected = max(-r.min_robot_clearance, -r.min_tether_clearance)
    assert r.violation == pytest.approx(max(expected, 1e-3))
    assert r.row()["f1"] == math.inf and "plan_time" not in r.row() and "plan_time" in r.row(timing=True)


def test_infeasible_step_outside_the_loop_is_a_failed_result(monkeypatch):
    def boom(problem, method):
        raise InfeasibleStep("no solution at step 7")

    monkeypatch.setattr(runs_mod, "solve", boom)
    r = evaluate_run(RunSpec("C", "horizon", 0, tuple(sorted(FAST.items()))))
    assert not r.success and "no solution at step 7" in r.failure
    assert r.fitness == (math.inf,) * 4 and r.violation > 0 and math.isnan(r.min_robot_clearance)


def test_unknown_method_raises():
    with pytest.raises(SweepError):
        evaluate_run(RunSpec("C", "simplex"))


# ------------------------------------------------------------------------------------------------------------------
# executors
# ------------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny_specs(tiny):
    return sensitivity_specs(sensitivity_grid(2), tiny, "pinv", seed=0, base=FAST)


@pytest.fixture(scope="module")
def serial_results(tiny_specs):
    res = SerialExecutor().map(evaluate_run, tiny_specs)
    assert 0 < sum(r.success for r in res) < len(res)  # both outcomes are compared below
    return res


def test_process_pool_matches_serial_in_task_order(tiny_specs, serial_results):
    ex = LocalExecutor(jobs=2, progress=False)
    try:
        res = ex.map(evaluate_run, tiny_specs[::-1])[::-1]  # reversed submission: order must follow the items
    finally:
        ex.close()
    assert [r.spec for r in res] == tiny_specs
    _same(_rows(res), _rows(serial_results))


@pytest.fixture(scope="module")
def dask_cluster():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0", silence_logs=50
    )
    yield cluster
    cluster.close()


def test_dask_local_cluster_matches_local(dask_cluster, tiny_specs, serial_results):
    from tmr.sweep import DaskExecutor

    ex = DaskExecutor(dask_cluster.scheduler_address, progress=False)
    try:
        res = ex.map(evaluate_run, tiny_specs)
    finally:
        ex.close()
    _same(_rows(res), _rows(serial_results))


def test_cli_on_dask_writes_the_same_bytes_as_local(dask_cluster, tiny, tmp_path, capsys):
    args = ["sensitivity", "--scenario", tiny, "--methods", "pinv", "--n", "2", "--seed", "0", *FAST_ARGS]
    assert main([*args, "--out", str(tmp_path / "local"), "--jobs", "2"]) == 0  # process pool
    assert main([*args, "--out", str(tmp_path / "dask"), "--scheduler", dask_cluster.scheduler_address]) == 0
    local = sorted(p.name for p in (tmp_path / "local").iterdir())
    assert local == sorted(p.name for p in (tmp_path / "dask").iterdir())
    assert local == [
        ".tmr-outputs.json",
        "sensitivity_tiny.md",
        "sensitivity_tiny_pinv.csv",
        "sensitivity_tiny_pinv.png",
        "sensitivity_tiny_pinv_raw.png",
    ]
    for name in local:
        assert (tmp_path / "local" / name).read_bytes() == (tmp_path / "dask" / name).read_bytes(), name


def test_unreachable_scheduler_is_exit_2(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["bench", "--scenarios", "C", "--methods", "pinv", "--scheduler", "tcp://127.0.0.1:9",
                 "--connect-timeout", "1", "--out", str(out), *FAST_ARGS])  # fmt: skip
    assert code == 2 and "scheduler" in capsys.readouterr().err and not out.exists()


# ------------------------------------------------------------------------------------------------------------------
# reports
# ------------------------------------------------------------------------------------------------------------------
def test_heatmap_blacks_out_exactly_the_failed_cells(tiny_specs, serial_results):
    res = SensitivityResult(sensitivity_grid(2), "tiny", "pinv", 1, tuple(serial_results))
    fig = heatmap_figure(res)
    for ax in fig.axes[:4]:  # the four heatmaps (colourbars are appended after them)
        mesh = ax.collections[0]
        arr = np.ma.asarray(mesh.get_array()).reshape(res.grid.shape)
        assert np.array_equal(np.ma.getmaskarray(arr), ~res.feasible)
        assert tuple(mesh.cmap.get_bad()) == (0.0, 0.0, 0.0, 1.0)
    md = sensitivity_markdown([res], "cmd")
    assert "| paper (D) | pinv |" in md and f"{int(res.feasible.sum())}/4" in md


def test_csv_text_round_trips_floats():
    rows = [{"a": 0.1 + 0.2, "b": math.inf, "c": None}, {"a": 1e-300, "d": "x"}]
    text = csv_text(rows)
    assert text.splitlines()[0] == "a,b,c,d"
    assert float(text.splitlines()[1].split(",")[0]) == 0.1 + 0.2 and ",inf," in text


def test_bench_rows_and_table(serial_results):
    specs = bench_specs(["C", "A"], ["pinv", "qp"], seed=2, repeats=3, overrides={"T_end": 2.0})
    assert [(s.scenario, s.method) for s in specs] == [("C", "pinv"), ("C", "qp"), ("A", "pinv"), ("A", "qp")]
    assert all(s.repeats == 3 and s.override("T_end") == 2.0 for s in specs)
    table = bench_markdown(serial_results)
    assert table.count("\n") == 2 + len(serial_results) and "dist err max [m]" in table


# ------------------------------------------------------------------------------------------------------------------
# MOGA
# ------------------------------------------------------------------------------------------------------------------
def test_pareto_indices_match_brute_force():
    rng = np.random.default_rng(0)
    F = rng.random((60, 3))
    F[[3, 17]] = np.inf  # failed plans are never on the front
    F[40] = F[41]  # a duplicate is kept once
    front = pareto_indices(F)
    brute = [
        i
        for i in range(len(F))
        if np.all(np.isfinite(F[i]))
        and not any(np.all(F[j] <= F[i]) and np.any(F[j] < F[i]) for j in range(len(F)) if np.all(np.isfinite(F[j])))
    ]
    brute = [i for i in brute if not (i == 41 and 40 in brute)]
    assert sorted(front) == sorted(brute)
    assert list(F[list(front), 0]) == sorted(F[list(front), 0])
    assert 3 not in front and 17 not in front


def test_choose_picks_the_balanced_point():
    F = np.array([[0.0, 10.0], [10.0, 0.0], [4.0, 4.0], [np.inf, np.inf]])
    assert choose(F, pareto_indices(F)) == 2
    assert choose(F, ()) == -1


def test_moga_is_deterministic_and_failures_are_infeasible(tiny):
    kw = dict(
        variables=(Variable("k_v0", 0.025, 0.1), Variable("d_min", 0.25, 1.0)),
        pop_size=4,
        n_gen=2,
        seed=1,
        base=FAST,
    )
    a = run_moga(tiny, "pinv", **kw)
    b = run_moga(tiny, "pinv", **kw)
    assert a.X.shape == (8, 2) and list(a.generation) == [1] * 4 + [2] * 4
    assert np.array_equal(a.X, b.X) and np.array_equal(a.F, b.F)
    assert np.all((a.X >= [0.025, 0.25]) & (a.X <= [0.1, 1.0]))
    failed = np.array([not r.success for r in a.results])
    assert np.all(np.isinf(a.F[failed])) and np.all(np.isfinite(a.F[~failed]))
    assert all(r.violation > 0 for r, f in zip(a.results, failed, strict=True) if f)
    assert set(a.pareto) <= set(np.flatnonzero(~failed))
    assert a.pareto and a.chosen in a.pareto
    assert a.chosen_params() == {"k_v0": a.X[a.chosen, 0], "d_min": a.X[a.chosen, 1]}
    # every feasible plan is dominated by (or equal to) a front point
    F = a.F
    for i in np.flatnonzero(~failed):
        assert any(np.all(F[j] <= F[i]) for j in a.pareto)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"variables": (Variable("k_v0", 0.1, 0.05),)},
        {"variables": (Variable("no_such_gain", 0.0, 1.0),)},
        {"variables": (Variable("k_v0", -1.0, 0.1),)},  # PinvParams rejects k_v0 ≤ 0
        {"pop_size": 1},
    ],
)
def test_moga_bad_input(kwargs):
    with pytest.raises(TmrError):
        run_moga("C", "pinv", **kwargs)


# ------------------------------------------------------------------------------------------------------------------
# CLI
# ------------------------------------------------------------------------------------------------------------------
def _cli(args, capsys):
    try:
        code = main(args)
    except SystemExit as exc:
        code = int(exc.code)
    out, err = capsys.readouterr()
    return code, out, err


def test_same_seed_same_bytes_moga(tiny, tmp_path, capsys):
    args = ["moga", "--scenario", tiny, "--pop", "4", "--gen", "2", "--seed", "1", "--jobs", "1", *FAST_ARGS,
            "--var", "k_v0=0.025:0.1", "--var", "d_min=0.25:1"]  # fmt: skip
    for d in ("a", "b"):
        assert _cli([*args, "--out", str(tmp_path / d)], capsys)[0] == 0
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == [".tmr-outputs.json", "moga_tiny_pinv.csv", "moga_tiny_pinv.md", "moga_tiny_pinv.png"]
    for n in names:
        assert (tmp_path / "a" / n).read_bytes() == (tmp_path / "b" / n).read_bytes(), n
    md = (tmp_path / "a" / "moga_tiny_pinv.md").read_text()
    assert "--var k_v0=0.025:0.1" in md and "## Chosen parameter set" in md and "**yes**" in md


def test_bench_cli_writes_scores_and_timings(tmp_path, capsys):
    out = tmp_path / "b"
    code, stdout, _ = _cli(["bench", "--scenarios", "C", "--methods", "pinv", "--jobs", "1", "--out", str(out),
                            *FAST_ARGS], capsys)  # fmt: skip
    assert code == 0 and "bench.md" in stdout
    assert sorted(p.name for p in out.iterdir()) == [".tmr-outputs.json", "bench.csv", "bench.md", "bench_timing.csv"]
    assert "plan_time" not in (out / "bench.csv").read_text()
    assert float((out / "bench_timing.csv").read_text().splitlines()[1].split(",")[2]) > 0


@pytest.mark.parametrize(
    "args, message",
    [
        (["sensitivity", "--scenario", "Z"], "scenario"),
        (["sensitivity", "--scenario", "C", "--set", "no_such=1"], "unknown parameter"),
        (["sensitivity", "--scenario", "C", "--set", "d_min=-1"], "d_min"),
        (["sensitivity", "--scenario", "C", "--n", "1"], "at least 2"),
        (["sensitivity", "--scenario", "C", "--n", "2", "2", "2"], "--n"),
        (["moga", "--scenario", "C", "--var", "k_v0=0.2:0.1"], "low < high"),
        (["moga", "--scenario", "C", "--var", "k_v0=a:b"], "NAME=LOW:HIGH"),
        (["bench", "--methods", "simplex"], "invalid choice"),
        (["sensitivity", "--jobs", "0"], "--jobs: must be ≥ 1, got 0"),
        (["moga", "--scenario", "C", "--var", "samples_per_link=5:20"], "samples_per_link is not a real number"),
        (["bench", "--set", "path_iterations=2.5"], "takes a whole number"),
        (["bench", "--seed", "-1"], "--seed: must be in 0"),
        (["bench", "--connect-timeout", "nan"], "--connect-timeout: must be a finite number > 0"),
    ],
)
def test_bad_input_exit_2_and_no_files(tmp_path, capsys, args, message):
    out = tmp_path / "out"
    code, _, err = _cli([*args, "--out", str(out), "--no-progress"], capsys)
    assert code == 2
    assert message in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []  # no temporary directory left either


def test_out_is_a_file_exit_2(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("keep")
    code, _, err = _cli(["bench", "--scenarios", "C", "--out", str(f), "--no-progress"], capsys)
    assert code == 2 and "not a directory" in err and f.read_text() == "keep"


def test_run_error_writes_nothing(tmp_path, capsys, monkeypatch):
    """An error inside a run (after validation) leaves no partial output."""

    def boom(spec):
        raise SweepError("worker crashed")

    import tmr.sweep.cli as cli

    monkeypatch.setattr(runs_mod, "evaluate_run", boom)
    out = tmp_path / "out"
    code = cli.main(["sensitivity", "--scenario", "C", "--n", "2", "--out", str(out), *FAST_ARGS], SerialExecutor())
    assert code == 2 and not out.exists() and [p.name for p in tmp_path.iterdir()] == []
    assert "worker crashed" in capsys.readouterr().err


def test_outputs_land_next_to_existing_files(tmp_path, capsys):
    out = tmp_path / "res"
    out.mkdir()
    (out / "other.md").write_text("x")
    assert _cli(["bench", "--scenarios", "C", "--methods", "pinv", "--jobs", "1", "--no-plots", "--out", str(out),
                 *FAST_ARGS], capsys)[0] == 0  # fmt: skip
    assert (out / "other.md").read_text() == "x" and (out / "bench.md").exists()
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())


def test_module_entry_point_help():
    res = subprocess.run([sys.executable, "-m", "tmr.sweep", "sensitivity", "--help"], capture_output=True, text=True)
    assert res.returncode == 0 and "--scheduler" in res.stdout and "d_min" in res.stdout


def _fail_first(args: tuple[int, str]) -> int:
    import time

    i, folder = args
    if i == 0:
        raise ValueError("task 0 is broken")
    time.sleep(0.2)
    Path(folder, f"ran_{i}").touch()
    return i


def test_a_failing_task_stops_the_pool_without_running_the_rest(tmp_path):
    from tmr.sweep.executor import LocalExecutor

    ex = LocalExecutor(jobs=2, progress=False)
    with pytest.raises(ValueError, match="task 0 is broken"):
        ex.map(_fail_first, [(i, str(tmp_path)) for i in range(40)])
    ex.close()  # waits for nothing left: the queued tasks were cancelled
    assert len(list(tmp_path.glob("ran_*"))) < 20  # without the cancel every one of the 39 tasks would have run
    assert ex.map(abs, [-1, 2]) == [1, 2]  # the executor is usable again (a fresh pool)
    ex.close()


def test_help_is_plain_text_and_every_option_explained():
    """No RST markup in --help, and every option of every sub-command has a help text."""
    from tmr.sweep.cli import build_parser

    parser = build_parser()
    assert "``" not in parser.format_help()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sp in sub.choices.items():
        assert "``" not in sp.format_help(), name
        missing = [a.option_strings for a in sp._actions if a.option_strings and not a.help]
        assert missing == [], (name, missing)


def test_moga_reused_out_keeps_no_stale_figure(tiny, tmp_path, capsys):
    out = tmp_path / "m"
    args = ["moga", "--scenario", tiny, "--pop", "4", "--gen", "1", "--jobs", "1", "--quiet",
            *FAST_ARGS, "--out", str(out)]  # fmt: skip
    assert _cli(args, capsys)[0] == 0 and (out / "moga_tiny_pinv.png").is_file()  # an older sweep, with its figure
    (out / "notes.txt").write_text("mine")
    code, stdout, err = _cli([*args, "--no-plots"], capsys)
    assert code == 0 and stdout == "" and err == ""
    names = sorted(p.name for p in out.iterdir())
    assert names == [".tmr-outputs.json", "moga_tiny_pinv.csv", "moga_tiny_pinv.md", "notes.txt"]
