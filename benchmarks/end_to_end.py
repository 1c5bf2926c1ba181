"""Whole-command time of ``python -m tmr.plan``: scenarios A–D × ``pinv`` / ``qp`` / ``horizon``, with a breakdown.

    python benchmarks/end_to_end.py [--scenarios A B C D] [--methods pinv qp horizon] [--repeats 5]
                                    [--breakdown-repeats 3] [--plots-for A:qp] [--out benchmarks/results]

A benchmark, not a test (issue 14: "the user waits for the whole command"). Three measurements, every one in fresh
Python processes, interleaved (repeat r of every command before repeat r + 1) so that a change in the machine's load
spreads over all of them:

* **whole process** — ``python -m tmr.plan --scenario S --method M --no-plots --out DIR --quiet`` as a user runs it,
  timed from the parent: wall time (median, min, max over ``--repeats``) and the CPU time of the child
  (``resource.getrusage(RUSAGE_CHILDREN)``, user + system; far less sensitive to other processes than the wall time),
  and its exit code (0 plan passed every check, 1 plan failed: a timing of a failed plan is still a timing). The
  commands of ``--plots-for`` are also run with plots (``plots add`` = their median minus the ``--no-plots`` one).
* **breakdown** — the same command in a child that first imports every module a real run of it ends with in
  ``sys.modules`` (found by a probe run, imported in the same order: ``imports``), then runs ``tmr.plan.main`` itself
  with thin timers wrapped round the functions it calls: ``inputs`` (scenario and map), ``route`` (the shortest route
  and the refusal check), ``path`` (the anchor's RRT*, ``--route rrt`` only), ``start`` (start placement),
  ``refs`` (route references and the leader's time law), ``loop`` (the control loop, ``tmr.control.clik.run``),
  ``horizon`` (the whole-horizon NLP), ``checks`` (the exact checks and metrics), ``filter`` (the zero-phase filter),
  ``writing`` (JSON, CSV, run.json), ``plots`` (importing ``tmr.views.plot`` and drawing and saving the figures);
  ``other``
  is what ``main`` spent outside those. ``startup`` is ``python -c pass``. Medians over ``--breakdown-repeats``.
* **import tmr** — ``python -X importtime -c "import tmr"``: the cumulative time of the ``tmr`` entry, and the wall
  time of ``python -c "import tmr"``.

Writes ``end_to_end.md`` and ``end_to_end.csv`` under ``--out``; the load average (1/5/15 min) at the start and the
end goes into the note: the development machine is shared, so absolute times are inflated by other work and ratios
measured in the same run are the reliable figures.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parent / "results"
PACKAGES = ("numpy", "scipy", "shapely", "osqp", "qpsolvers", "ompl", "casadi", "matplotlib")

#: Phases of the breakdown, in the order of a run.
PHASES = ("inputs", "route", "path", "start", "refs", "loop", "horizon", "checks", "filter", "writing", "plots")
#: Targets of issue 14 on 2 cores [s].
TARGET_QP_A = 0.8
TARGET_HORIZON = 3.0
TARGET_PLOTS = 0.5
TARGET_IMPORT = 0.3


# ------------------------------------------------------------------------------------------------------- children
def method_flags(method: str) -> list[str]:
    """``qp`` → ``--method qp``; ``qp+rrt`` → ``--method qp --route rrt`` (the paper's RRT* leader)."""
    name, _, route = method.partition("+")
    return ["--method", name, *(["--route", route] if route else [])]


def command(scenario: str, method: str, plots: bool, out: Path) -> list[str]:
    """The user's command line."""
    cmd = [sys.executable, "-m", "tmr.plan", "--scenario", scenario, *method_flags(method), "--out", str(out)]
    return [*cmd, "--quiet"] if plots else [*cmd, "--quiet", "--no-plots"]


def timed_run(cmd: list[str]) -> dict[str, float]:
    """Wall and CPU time [s] of one child process, and its exit code."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr.strip()[-500:]}")
    return {"wall": wall, "cpu": cpu, "code": float(proc.returncode)}


_PROBE = """
import json, runpy, sys
sys.argv = ["tmr.plan", *json.loads(sys.argv[1])]
try:
    runpy.run_module("tmr.plan", run_name="__main__")
except SystemExit:
    pass
print(json.dumps(list(sys.modules)))
"""


def probe_modules(args: list[str]) -> list[str]:
    """Every module a run of ``tmr.plan ARGS`` has in ``sys.modules`` when it ends, in import order."""
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(args)], capture_output=True, text=True, check=True
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def _wrap(module: Any, name: str, phase: str, acc: dict[str, float]) -> None:
    """Replace ``module.name`` by a wrapper adding its time to ``acc[phase]`` (outermost call only)."""
    fn = getattr(module, name)
    depth = [0]

    def timed(*args: Any, **kwargs: Any) -> Any:
        depth[0] += 1
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                acc[phase] = acc.get(phase, 0.0) + time.perf_counter() - t0

    setattr(module, name, timed)


def child(spec: dict[str, Any]) -> dict[str, float]:
    """One breakdown run (in its own process): imports, then ``tmr.plan.main`` with timers round its steps."""
    import importlib

    acc: dict[str, float] = {}
    t0 = time.perf_counter()
    for name in spec["modules"]:
        if name not in sys.modules and not name.startswith("__"):
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - a module only importable as a side effect of another: skipped
                pass
    acc["imports"] = time.perf_counter() - t0

    import tmr.checks.metrics as metrics_mod
    import tmr.plan as plan_mod
    import tmr.planner as planner_mod

    _wrap(plan_mod, "load_inputs", "inputs", acc)
    _wrap(plan_mod, "precheck", "route", acc)
    _wrap(planner_mod, "_anchor_path", "path", acc)
    _wrap(planner_mod, "_rrt_trajectory", "path", acc)  # the leader's own RRT* (a given start) + its time law
    _wrap(planner_mod, "_start_from_path", "start", acc)
    _wrap(planner_mod, "start_placement", "start", acc)
    _wrap(planner_mod, "chain_reference", "refs", acc)
    _wrap(planner_mod, "_trajectory_along", "refs", acc)
    _wrap(planner_mod, "plan", "loop", acc)
    _wrap(planner_mod, "check", "checks", acc)
    if "tmr.control.horizon" in sys.modules:  # a horizon run (its modules were imported above)
        _wrap(sys.modules["tmr.control.horizon"], "plan_horizon", "horizon", acc)
    _wrap(metrics_mod, "filter_trajectories", "filter", acc)
    _wrap(plan_mod, "write_outputs", "writing", acc)
    plots_import = 0.0
    if spec["plots"]:
        t1 = time.perf_counter()
        import tmr.views.plot as plot_mod  # matplotlib: counted in plots

        plots_import = time.perf_counter() - t1
        for name in ("plot_chain_poses", "plot_trajectories", "plot_distance_errors", "plot_speeds", "save_figure"):
            _wrap(plot_mod, name, "plots", acc)
    t2 = time.perf_counter()
    code = plan_mod.main(spec["args"])
    main_time = time.perf_counter() - t2
    draw = acc.get("plots", 0.0)
    if spec["plots"]:
        acc["writing"] -= draw  # the figures are drawn inside write_outputs
        acc["plots"] = plots_import + draw
    acc["other"] = max(0.0, main_time - sum(acc.get(p, 0.0) for p in PHASES) + plots_import)
    acc["code"] = float(code)
    return acc


def breakdown_run(args: list[str], modules: list[str], plots: bool) -> dict[str, float]:
    spec = {"args": args, "modules": modules, "plots": plots}
    out = subprocess.run(
        [sys.executable, __file__, "--child", json.dumps(spec)], capture_output=True, text=True, check=False
    )
    if out.returncode != 0:
        raise SystemExit(f"breakdown child failed ({' '.join(args)}): {out.stderr.strip()[-800:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def import_tmr_time() -> tuple[float, float]:
    """(cumulative µs→s of the ``tmr`` entry of ``-X importtime``, wall time of ``python -c 'import tmr'``)."""
    out = subprocess.run([sys.executable, "-X", "importtime", "-c", "import tmr"], capture_output=True, text=True)
    cum = 0.0
    for line in out.stderr.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[2].strip() == "tmr":
            cum = float(parts[1]) * 1e-6
    wall = timed_run([sys.executable, "-c", "import tmr"])["wall"]
    return cum, wall


# ------------------------------------------------------------------------------------------------------- report
def verdict(ok: bool) -> str:
    return "met" if ok else "not met"


def stats(values: list[float]) -> tuple[float, float, float]:
    return statistics.median(values), min(values), max(values)


def markdown(rows: list[dict[str, Any]], breakdown: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    buf.write(
        "| scenario | method | plots | exit | wall median [s] | min | max | CPU median [s] | runs |\n"
        "|---|---|---|---|---|---|---|---|---|\n"
    )
    for r in rows:
        buf.write(
            f"| {r['scenario']} | {r['method']} | {'yes' if r['plots'] else 'no'} | {r['exit']} | "
            f"{r['wall_median']:.3f} | {r['wall_min']:.3f} | {r['wall_max']:.3f} | {r['cpu_median']:.3f} | "
            f"{r['runs']} |\n"
        )
    buf.write("\nBreakdown [s] (medians; `–`: the phase does not occur):\n\n")
    cols = ["startup", "imports", *PHASES, "other", "sum"]
    buf.write("| scenario | method | plots | " + " | ".join(cols) + " |\n")
    buf.write("|---|---|---|" + "---|" * len(cols) + "\n")
    for b in breakdown:
        cells = [("–" if b.get(c) is None else f"{b[c]:.3f}") for c in cols]
        buf.write(
            f"| {b['scenario']} | {b['method']} | {'yes' if b['plots'] else 'no'} | " + " | ".join(cells) + " |\n"
        )
    return buf.getvalue()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["A", "B", "C", "D"])
    ap.add_argument("--methods", nargs="+", default=["pinv", "qp", "horizon"], choices=["pinv", "qp", "horizon"])
    ap.add_argument("--repeats", type=int, default=5, help="whole-process runs per command (median, min, max)")
    ap.add_argument("--breakdown-repeats", type=int, default=3, help="breakdown runs per command (median)")
    ap.add_argument("--plots-for", nargs="*", default=["A:qp"], metavar="S:M", help="commands also timed with plots")
    ap.add_argument(
        "--rrt-for", nargs="*", default=["A:qp"], metavar="S:M", help="commands also timed with --route rrt"
    )
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    if args.repeats < 1 or args.breakdown_repeats < 1:
        raise SystemExit("--repeats and --breakdown-repeats must be ≥ 1")
    plots_for = {tuple(s.split(":")) for s in args.plots_for}
    combos = [(s, m, False) for s in args.scenarios for m in args.methods]
    combos += [(s, m, True) for s, m in sorted(plots_for)]
    combos += [(s, f"{m}+rrt", False) for s, m in sorted({tuple(x.split(":")) for x in args.rrt_for})]

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from provenance import source_version, versions

    t_start = time.perf_counter()
    load_start = os.getloadavg()
    work = Path(tempfile.mkdtemp(prefix="tmr-e2e-"))
    walls: dict[tuple, list[dict[str, float]]] = {c: [] for c in combos}
    startup: list[float] = []
    imports: list[tuple[float, float]] = []
    for r in range(args.repeats):
        startup.append(timed_run([sys.executable, "-c", "pass"])["wall"])
        imports.append(import_tmr_time())
        for c in combos:
            s, m, plots = c
            walls[c].append(timed_run(command(s, m, plots, work / f"{s}_{m}_{int(plots)}")))
            print(
                f"repeat {r + 1}/{args.repeats} {s} {m}{' plots' if plots else ''}: {walls[c][-1]['wall']:.2f} s",
                file=sys.stderr,
            )
    modules = {}
    for s, m, _ in combos:
        if (s, m) not in modules:
            base = ["--scenario", s, *method_flags(m), "--no-plots", "--quiet", "--out", str(work / f"probe_{s}_{m}")]
            modules[(s, m)] = probe_modules(base)
    parts: dict[tuple, list[dict[str, float]]] = {c: [] for c in combos}
    for _ in range(args.breakdown_repeats):
        for c in combos:
            s, m, plots = c
            argv = ["--scenario", s, *method_flags(m), "--quiet", "--out", str(work / f"bd_{s}_{m}_{int(plots)}")]
            parts[c].append(breakdown_run(argv if plots else [*argv, "--no-plots"], modules[(s, m)], plots))
    load_end = os.getloadavg()

    rows, breakdown = [], []
    for c in combos:
        s, m, plots = c
        w = stats([x["wall"] for x in walls[c]])
        codes = sorted({int(x["code"]) for x in walls[c]})
        rows.append(
            dict(
                scenario=s,
                method=m,
                plots=plots,
                exit="/".join(map(str, codes)),
                wall_median=w[0],
                wall_min=w[1],
                wall_max=w[2],
                cpu_median=statistics.median(x["cpu"] for x in walls[c]),
                runs=len(walls[c]),
            )
        )
        b: dict[str, Any] = {"scenario": s, "method": m, "plots": plots, "startup": statistics.median(startup)}
        for key in ("imports", *PHASES):
            vals = [p[key] for p in parts[c] if key in p]
            b[key] = statistics.median(vals) if vals else None
        b["other"] = statistics.median(p["other"] for p in parts[c])
        b["sum"] = b["startup"] + b["imports"] + sum(b[k] or 0.0 for k in PHASES) + b["other"]
        breakdown.append(b)

    write(
        args.out,
        rows,
        breakdown,
        startup,
        imports,
        load_start,
        load_end,
        time.perf_counter() - t_start,
        versions(PACKAGES),
        source_version(),
        args,
    )


def write(out: Path, rows, breakdown, startup, imports, load_start, load_end, total, vers, source, args) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "end_to_end.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        cols = ["scenario", "method", "plots", "exit", "wall_median", "wall_min", "wall_max", "cpu_median", "runs"]
        w.writerow([*cols, "startup", "imports", *PHASES, "other"])
        for r, b in zip(rows, breakdown, strict=True):
            w.writerow(
                [r[k] for k in cols]
                + ["" if b.get(k) is None else f"{b[k]:.4f}" for k in ("startup", "imports", *PHASES, "other")]
            )

    def find(s: str, m: str, plots: bool) -> dict[str, Any] | None:
        return next((r for r in rows if (r["scenario"], r["method"], r["plots"]) == (s, m, plots)), None)

    lines = []
    a_qp = find("A", "qp", False)
    if a_qp:
        ok = a_qp["wall_median"] < TARGET_QP_A
        lines.append(
            f"- scenario A `qp --no-plots`: {a_qp['wall_median']:.2f} s wall median, {a_qp['cpu_median']:.2f} s "
            f"CPU (target < {TARGET_QP_A} s: **{'met' if ok else 'not met'}**)."
        )
    for r in rows:
        if r["method"] == "horizon" and not r["plots"]:
            ok = r["wall_median"] < TARGET_HORIZON
            lines.append(
                f"- {r['scenario']} `horizon`: {r['wall_median']:.2f} s wall median, {r['cpu_median']:.2f} s "
                f"CPU (target < {TARGET_HORIZON} s: **{'met' if ok else 'not met'}**)."
            )
    for r in rows:
        if r["plots"]:
            base = find(r["scenario"], r["method"], False)
            if base:
                add = r["wall_median"] - base["wall_median"]
                add_cpu = r["cpu_median"] - base["cpu_median"]
                lines.append(
                    f"- plots add to {r['scenario']} `{r['method']}`: {add:.2f} s wall, {add_cpu:.2f} s CPU "
                    f"(target < {TARGET_PLOTS} s: **{'met' if add < TARGET_PLOTS else 'not met'}**)."
                )
    cum = statistics.median(c for c, _ in imports)
    wall = statistics.median(w for _, w in imports)
    lines.append(
        f'- `python -X importtime -c "import tmr"`: `tmr` {cum * 1e3:.1f} ms cumulative (median of '
        f'{len(imports)}); `python -c "import tmr"` {wall:.3f} s wall, of which interpreter start '
        f"{statistics.median(startup):.3f} s (target < {TARGET_IMPORT} s: **{verdict(cum < TARGET_IMPORT)}**)."
    )

    cmdline = "python benchmarks/end_to_end.py " + " ".join(
        [
            f"--scenarios {' '.join(args.scenarios)}",
            f"--methods {' '.join(args.methods)}",
            f"--repeats {args.repeats}",
            f"--breakdown-repeats {args.breakdown_repeats}",
            f"--plots-for {' '.join(args.plots_for)}",
            f"--rrt-for {' '.join(args.rrt_for)}",
        ]
    )
    md = f"""# End-to-end time of `python -m tmr.plan`

`{cmdline}` — {time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}, machine `{platform.machine()}`, nproc
{os.cpu_count()}, Python {platform.python_version()}; {vers}; {source}. Total run time {total:.0f} s.
Load average (1/5/15 min) {"/".join(f"{x:.1f}" for x in load_start)} at the start,
{"/".join(f"{x:.1f}" for x in load_end)} at the end: the machine is shared, a load above 2 on its 2 cores means the
wall times are inflated by other processes (the CPU column much less so).

Whole process: `python -m tmr.plan --scenario S --method M [--no-plots] --out DIR --quiet`, timed from the parent,
{args.repeats} runs each, interleaved. *exit* 0 = the plan passed every check, 1 = it failed one (its time is still
the time the user waits). Breakdown: see the script's docstring (imports = every module the run ends with, imported
first; the phases are timers round the functions `tmr.plan.main` calls).

{chr(10).join(lines)}

{markdown(rows, breakdown)}
"""
    (out / "end_to_end.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
