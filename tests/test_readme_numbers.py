"""Every measured figure README.md quotes matches its source: a committed benchmark result, a committed artifact or
a quantity the code computes cheaply.

One entry of ``QUOTES`` per quoted figure: a regular expression (on the README with its whitespace collapsed to
single spaces, so a phrase may wrap) whose groups capture the figures, and the source that gives them, in the same
unit, one value per group. A number matches when the README shows the source rounded to the README's own precision
("0.98" matches 0.9824, "31" matches 31.4, "3·10⁻²" matches 0.0319); ``cmp=">="`` / ``"<="`` mark a README bound
("to 1e-3 or better": the source must not exceed it). A string source (a commit, a message) must match exactly.
Every pattern must occur in the README, and every occurrence must match, so a change on either side fails here.
No benchmark is run: results are read from ``benchmarks/results``.
"""

from __future__ import annotations

import csv
import math
import re
import statistics
from collections.abc import Callable, Iterable
from functools import cache
from pathlib import Path
from typing import Any, NamedTuple

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
README = ROOT / "README.md"

SUPERSCRIPT = str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹⁻", "0123456789-")


# -- sources -----------------------------------------------------------------------------------------------------------


@cache
def rows(name: str) -> tuple[dict[str, str], ...]:
    """The rows of ``benchmarks/results/<name>`` (a CSV) as dicts of strings."""
    with (RESULTS / name).open(newline="", encoding="utf-8") as fh:
        return tuple(csv.DictReader(fh))


def row(name: str, **where: str) -> dict[str, str]:
    """The one row of a results CSV whose columns have the given values."""
    found = [r for r in rows(name) if all(r[k] == v for k, v in where.items())]
    assert len(found) == 1, f"{name}: {len(found)} rows match {where}"
    return found[0]


def cell(name: str, column: str, **where: str) -> float:
    """One number of a results CSV."""
    return float(row(name, **where)[column])


@cache
def text(name: str) -> str:
    """A results Markdown file with its whitespace collapsed to single spaces."""
    return " ".join((RESULTS / name).read_text(encoding="utf-8").split())


def md(name: str, pattern: str) -> tuple[Any, ...]:
    """The groups of the first match of ``pattern`` in a results Markdown file, numbers as floats."""
    m = re.search(pattern, text(name))
    assert m, f"{name} has no match for {pattern!r}"
    return tuple(parse(g)[0] if re.fullmatch(r"[-−\d.,]+", g) else g for g in m.groups())


@cache
def table(name: str, header: str) -> tuple[dict[str, str], ...]:
    """The rows of the Markdown table of a results file whose header line starts with ``header``, as dicts."""
    lines = (RESULTS / name).read_text(encoding="utf-8").splitlines()
    start = next((i for i, ln in enumerate(lines) if ln.startswith(header)), None)
    assert start is not None, f"{name} has no table starting {header!r}"

    def cells(line: str) -> list[str]:
        return [c.strip() for c in line.strip().strip("|").split("|")]

    keys, body = cells(lines[start]), []
    keys = [k if k not in keys[:i] else f"{k} ({keys[:i].count(k) + 1})" for i, k in enumerate(keys)]  # "plots" twice
    for ln in lines[start + 2 :]:
        if not ln.startswith("|"):
            break
        body.append(dict(zip(keys, cells(ln), strict=False)))
    return tuple(body)


@cache
def gif(name: str) -> tuple[int, float]:
    """Frames and size [MB, 10⁶ bytes] of a committed GIF, read with Pillow."""
    from PIL import Image

    path = RESULTS / name
    with Image.open(path) as im:
        return im.n_frames, path.stat().st_size / 1e6


@cache
def route_e() -> Any:
    """The shortest free route of built-in scenario E (tmr.route.route.plan_route, as tests/test_scenario.py builds
    it)."""
    from tmr import load_scenario
    from tmr.model.catenary import max_span
    from tmr.route.route import plan_route

    sc = load_scenario("E")
    return plan_route(sc.environment, sc.base, sc.goal, [[0.5, max_span()], [1.0, max_span()]])


def d_max() -> float:
    from tmr.model.catenary import max_span

    return max_span()


def steps_rrt() -> int:
    """Samples per robot of a ``--route rrt`` plan: T_end / Ts + 1."""
    from tmr.model.params import TimeParams

    p = TimeParams()
    return round(p.T_end / p.Ts) + 1


def chord_clearance() -> float:
    from tmr.route.route import CHORD_CLEARANCE

    return CHORD_CLEARANCE


def replay(run: str, column: str) -> float:
    return cell("replay.csv", column, run=run)


def formulations(method: str, column: str) -> list[float]:
    return [cell("formulations.csv", column, scenario=s, method=method) for s in "ABCD"]


def horizon_ratio(column: str) -> list[float]:
    """horizon / qp of a fitness on A–D (benchmarks/results/formulations.csv)."""
    return [h / q for h, q in zip(formulations("horizon", column), formulations("qp", column), strict=True)]


def step_ratio() -> list[float]:
    return [
        h / q for h, q in zip(formulations("horizon", "ms_per_step"), formulations("qp", "ms_per_step"), strict=True)
    ]


def qp_step(n: int, solver: str, column: str) -> float:
    return cell("qp_step.csv", column, n_robots=str(n), method="qp" if solver != "–" else "pinv", solver=solver)


def end_to_end(scenario: str, method: str, plots: str = "no") -> float:
    return md("end_to_end.md", rf"\| {scenario} \| {method} \| {plots} \| \d \| ([\d.]+) \|")[0]


def breakdown(phase: str) -> float:
    """A phase [s] of the breakdown of A ``qp --no-plots`` in end_to_end.md."""
    found = [
        r
        for r in table("end_to_end.md", "| scenario | method | plots | startup |")
        if (r["scenario"], r["method"], r["plots"]) == ("A", "qp", "no")
    ]
    return float(found[0][phase])


def ccma(mode: str | None = None) -> list[dict[str, str]]:
    return [r for r in rows("ccma.csv") if mode is None or r["mode"] == mode]


def ccma_max(column: str, mode: str | None = None) -> float:
    return max(float(r[column]) for r in ccma(mode))


def mopick_replay() -> dict[str, str]:
    """The MoPICK row of replay.md."""
    (found,) = table("replay.md", "| run | plan ok | replay | platform error")
    return found


def sensitivity_first_tether_failure() -> tuple[int, int, float]:
    """D / pinv sweep: cells whose first tether collision is at the most common time, cells, that time [s]."""
    times = [
        float(re.search(r"tether_clearance violated .*?first at t = ([\d.]+) s", r["failure"]).group(1))
        for r in rows("sensitivity_D_pinv.csv")
    ]
    t = statistics.mode(times)
    return times.count(t), len(times), t


def static_tether_error(links: str) -> float:
    """Largest relative error of the MuJoCo tether against tmr.model.catenary over the spans of replay.md."""
    table = re.findall(
        rf"\| {links} \| [\d.]+ \| ([-+.\de]+) \| ([-+.\de]+) \| ([-+.\de]+) \| ([-+.\de]+) \|", text("replay.md")
    )
    assert len(table) == 6, "replay.md lost its static tether table"
    return max(abs(float(v)) for r in table for v in r)


# -- the quoted figures ------------------------------------------------------------------------------------------------


class Quote(NamedTuple):
    pattern: str  # regular expression on the README (whitespace collapsed), one group per figure
    source: Callable[[], Any]  # the figure(s) from the source, in the README's unit; a tuple for several groups
    cmp: str = "="  # "=": the README shows the source rounded; "<=" / ">=": README value <= / >= source


D_QP = "scenario D, qp, route shortest"
RR = "random_rooms.md"

DR = "drones.md"

QUOTES = [
    # the GIF at the top and its description under "ROS 2 bags, animations and interactive views"
    Quote(r"Scenario A: (\d+) frames, ([\d.]+) MB", lambda: gif("A_qp_motion.gif")),
    Quote(
        r"Scenario A: (\d+) frames, ([\d.]+) MB",
        lambda: (
            md("views.md", r"(\d+) frames at 10 fps")[0],
            cell("views.csv", "size_MB", scenario="A", output="gif"),
        ),
    ),
    Quote(r"behind it in (\S+) s, then hold 2 s", lambda: cell("views.csv", "plan_s", scenario="A", output="gif") - 2),
    Quote(
        r"settle on their stations \((\S+) s, shown in real time\)",
        lambda: cell("views.csv", "plan_s", scenario="A", output="gif"),
    ),
    # active winches (benchmarks/results/active_winch.md)
    Quote(
        r"at the constant 2 N two are held back (\S+) m short",
        lambda: md(
            "active_winch.md",
            r"\| I \| 2 \| constant --set settle=30 \| 1 \| plan FAILED: the leader stalled ([\d.]+) m",
        ),
    ),
    # tethered drone chains in 3-D (benchmarks/results/drones.md, its targets table)
    Quote(
        r"`--robots auto` planned (\d+) of the (\d+) reachable goals",
        lambda: md(DR, r"`auto` plans ≥ 95% of the reachable goals \(passing the check\) \| (\d+)/(\d+)"),
    ),
    Quote(
        r"every drone count below the proven bound was refused \((\d+)/(\d+), before any motion is planned\)",
        lambda: md(DR, r"every N below the proven bound refused, in < 1 s \(in-process\) \| (\d+)/(\d+)"),
    ),
    Quote(
        r"the unreachable goals were refused in (\S+) s median",
        lambda: md(
            DR,
            r"unreachable goals refused \(no route, or too few for the straight line\), in < 1 s \(in-process\) \| "
            r"\d+/\d+ \(\d+ %\); median ([\d.]+) s",
        ),
    ),
    Quote(
        r"the independent check found (\d+) violated limits in the (\d+) plans made",
        lambda: md(
            DR,
            r"0 violations by the independent check \(hard limits broken, in every plan computed\) \| "
            r"(\d+) in (\d+) plans",
        ),
    ),
    Quote(
        r"A whole step \(catenaries, world queries, rows and the QP\) took (\S+) ms median for 8\s+drones \(the QP "
        r"(\S+) ms of it\)",
        lambda: md(DR, r"per-step QP time for 8 drones ≤ 2 ms median \| ([\d.]+) ms .*?of which the QP ([\d.]+) ms"),
    ),
    Quote(
        r"H with 5 drones (\S+) s for the whole process",
        lambda: md(DR, r"H arena, 5 drones, whole process < 2 s \| ([\d.]+) s"),
    ),
    # what it does, the command line
    Quote(r"clears the floor \((\S+) m with the paper's data", d_max),
    Quote(
        r"a goal 4 m away behind a 16 m wall \(a (\d+) m route, (\d+) robots\)",
        lambda: (route_e().length, route_e().n_min),
    ),
    Quote(r'--scenario E --robots 3`: "(the goal needs at least [^"]*)"', lambda: route_e().refusal(3)),
    Quote(
        r"the (\d+) refusals of the random rooms took (\S+) s median and (\S+) s at most",
        lambda: md(RR, r"N proven below N_min: (\d+)/\d+ refused, .*? median ([\d.]+) s, max ([\d.]+) s"),
    ),
    Quote(r"K \+ 1 samples per robot \(K = T_end / Ts; (\d+) with `--route rrt`\)", steps_rrt),
    # physics replay
    Quote(r"near d_max \(t ≈ (\d+) s\)", lambda: replay(D_QP, "min_tether_t_s")),
    Quote(
        r"dips to (\d+) mm above the floor where the static catenary says (\d+) mm",
        lambda: (1000 * replay(D_QP, "min_tether_m"), 1000 * replay(D_QP, "catenary_then_m")),
    ),
    Quote(r"The replay passes \(no contact, tracking within (\S+) mm\)", lambda: replay(D_QP, "track_max_mm")),
    Quote(r"matches `tmr.model.catenary` to (\S+) or better", lambda: static_tether_error("16"), ">="),
    Quote(
        r"replays with the platform within (\S+) mm of its path",
        lambda: float(mopick_replay()["platform error max / rms [mm]"].split(" / ")[0]),
    ),
    Quote(
        r"every base on its four wheels \(tipping margin ≥ (\S+) N\)",
        lambda: min(float(v) for v in mopick_replay()["tipping margin per base [N]"].split(", ")),
    ),
    Quote(r"the plan's span reaches … m > d_max (\S+) m", d_max),
    # formulations
    Quote(
        r"Per step: (\S+) ms for 3 robots \((\S+)× `pinv` in the same run\), (\S+) ms for 100 robots",
        lambda: (
            qp_step(3, "osqp", "ms_per_step"),
            qp_step(3, "osqp", "ratio_loop"),
            qp_step(100, "osqp", "ms_per_step"),
        ),
    ),
    Quote(r"nonlinear program over all (\d+) knots", steps_rrt),
    Quote(
        r"f1 up to (\S+)× and f4 up to (\d+)× lower than `qp` on A–D\) in (\S+)–(\S+) s per scenario",
        lambda: (
            1 / min(horizon_ratio("f1")),
            1 / min(horizon_ratio("f4")),
            min(end_to_end(s, "horizon") for s in "ABCD"),
            max(end_to_end(s, "horizon") for s in "ABCD"),
        ),
    ),
    # results
    Quote(
        r"The route \(light green, (\S+) m, kept (\S+) m clear of the grown obstacles\)",
        lambda: (route_e().length, route_e().margin),
    ),
    Quote(r"on the shortest possible tether route, (\S+) m,", lambda: route_e().lower_length),
    Quote(r'touching the grown obstacles \("(the goal needs at least [^"]*)"\)', lambda: route_e().refusal(3)),
    Quote(
        r"per step \((\S+)–(\S+) ms, the loop included\)",
        lambda: (
            min(formulations("pinv", "ms_per_step") + formulations("qp", "ms_per_step")),
            max(formulations("pinv", "ms_per_step") + formulations("qp", "ms_per_step")),
        ),
    ),
    Quote(
        r"\(f2 (\S+)–(\S+) of `qp`'s, f4 (\d+)–(\d+) %\)",
        lambda: (
            max(horizon_ratio("f2")),
            min(horizon_ratio("f2")),
            100 * min(horizon_ratio("f4")),
            100 * max(horizon_ratio("f4")),
        ),
    ),
    Quote(r"at (\S+)–(\S+)× the time per step", lambda: (min(step_ratio()), max(step_ratio()))),
    # random rooms
    Quote(
        r"On (\d+) rooms \((\S+) runs of `qp`, (\d+) workers, (\d+) min, load average (\S+)–(\S+), commit (\w+)\)",
        lambda: (
            md(RR, r"(\d+) rooms \(`tmr.sweep.rooms.room_set")[0],
            *md(RR, r"(\d+) runs [\d.]+ s\)"),
            md(RR, r"(\d+) local worker processes")[0],
            md(RR, r"total (\d+) s")[0] / 60,
            *md(RR, r"load average ([\d.]+) at the start, ([\d.]+) at the end"),
            md(RR, r"tmr commit (\w+)\.")[0],
        ),
    ),
    Quote(
        r"`qp` planned (\d+) of the (\d+) rooms whose goal is connected \((\d+) %; target (\d+) %\)",
        lambda: (*md(RR, r"\| (\d+)/(\d+) \((\d+) %\) \| yes"), md(RR, r"plans ≥ (\d+) % of the rooms")[0]),
    ),
    Quote(r"every one of the (\d+) plans written passed", lambda: md(RR, r"hard limit .*? \| (\d+)/\d+ \| yes")[0]),
    Quote(r"the median run that wrote a plan took (\S+) s", lambda: md(RR, r"\| ([\d.]+) s \(exit 0 only")[0]),
    Quote(
        r"planned all (\d+) and (\d+) reachable rooms, with 5 robots (\d+) of (\d+), with 8 robots (\d+) of (\d+)\.",
        lambda: (
            *md(RR, r"\| qp \| 2 \| \d+ \| \d+ \| (\d+)/"),
            *md(RR, r"\| qp \| 3 \| \d+ \| \d+ \| (\d+)/"),
            *md(RR, r"\| qp \| 5 \| \d+ \| \d+ \| (\d+)/(\d+)"),
            *md(RR, r"\| qp \| 8 \| \d+ \| \d+ \| (\d+)/(\d+)"),
        ),
    ),
    Quote(
        r"Every one of the (\d+) runs with N proven below N_min was refused \(exit 2, (\S+) s median, whole process "
        r"under load, the slowest (\S+) s\)",
        lambda: md(RR, r"N proven below N_min: (\d+)/\d+ refused, .*? median ([\d.]+) s, max ([\d.]+) s"),
    ),
    Quote(r"In (\d+) runs a chain of N robots exists", lambda: md(RR, r"\| (\d+)/\d+ \(those chains'")[0]),
    Quote(r"nearer them than the (\S+) m the plans keep", chord_clearance),
    Quote(
        r"a tether passes (\S+) m from them where (\S+) m is needed",
        lambda: (md(RR, r"least tether clearance ([\d.]+)–")[0], chord_clearance()),
    ),
    Quote(
        r"known exactly in (\d+) of the (\d+) rooms with a route", lambda: md(RR, r"so in (\d+) of the (\d+) in all")
    ),
    # sensitivity
    Quote(
        r"nominal·\[0.5, 2\] \((\d+) × (\d+) plans\)",
        lambda: md("sensitivity_D.md", r"D / pinv: .*?\((\d+) values\) × .*?\((\d+) values\)"),
    ),
    Quote(
        r"the baseline fails in every cell \(in (\d+) of the (\d+) a tether enters a grown obstacle at t = (\S+) s",
        sensitivity_first_tether_failure,
    ),
    Quote(
        r"the baseline fails in (every) cell .*? `qp` in (none)",
        lambda: (
            "every" if md("sensitivity_D.md", r"\| D \| pinv \| d_min, k_v0 \| (\d+)/")[0] == 0 else "some",
            "none"
            if md("sensitivity_D.md", r"\| D \| qp \| d_safe, approach_rate \| (\d+/\d+) \|")[0] == "169/169"
            else "some",
        ),
    ),
    # MoPICK
    Quote(
        r"the search plan keeps μ ≥ (\S+) N at its samples and ≥ (\S+) N guaranteed between them",
        lambda: (
            cell("mcdpr_planner.csv", "search_mu_min", scene="fig2"),
            cell("mcdpr_planner.csv", "search_mu_between", scene="fig2"),
        ),
    ),
    Quote(
        r"the greedy plan μ ≥ (\S+) N at its samples only",
        lambda: cell("mcdpr_planner.csv", "greedy_mu_min", scene="fig2"),
    ),
    Quote(
        r"the paper's MATLAB run took (\S+) \+ (\S+) min",
        lambda: md("mcdpr.md", r"([\d.]+) min \(bases\) \+ ([\d.]+) min"),
    ),
    Quote(r"On (\d+) generated scenes", lambda: len(rows("mcdpr_planner.csv"))),
    Quote(
        r"each in at most (\S+) s of CPU on a 2-core machine",
        lambda: max(float(r["search_cpu_s"]) for r in rows("mcdpr_planner.csv")),
    ),
    Quote(
        r"\(μ in (\S+) µs per pose, batched\)",
        lambda: cell("mcdpr.csv", "us_per_pose", group="capacity margin μ", method="numpy batched (zonotope)"),
    ),
    # CCMA
    Quote(
        r"python -m tmr.ccma list # (\d+) examples", lambda: len(list((ROOT / "src/tmr/ccma/examples").glob("*.toml")))
    ),
    Quote(
        r"along a vertical circle: every arm bends by (\S+)°",
        lambda: math.degrees(cell("ccma.csv", "joint_range", example="4dof-reduced", path="vcircle", mode="vm")),
    ),
    Quote(
        r"end-effector errors ≤ (\S+) m and (\S+) rad and residual energy ≤ (\S+) m², the joints turning by up to "
        r"(\S+) rad",
        lambda: (ccma_max("max_pos_err"), ccma_max("max_rot_err"), ccma_max("max_residual"), ccma_max("joint_range")),
    ),
    Quote(
        r"takes at most (\S+) ms median and (\S+) ms at worst with `--compile`",
        lambda: (ccma_max("warm_ms", "compiled"), ccma_max("warm_max_ms", "compiled")),
    ),
    Quote(
        r"interpreted, the medians are (\S+)–(\S+) ms \((\d+) of (\d+) example × path rows above 5 ms",
        lambda: (
            min(float(r["warm_ms"]) for r in ccma("vm")),
            ccma_max("warm_ms", "vm"),
            sum(float(r["warm_ms"]) > 5 for r in ccma("vm")),
            len(ccma("vm")),
        ),
    ),
    Quote(r"and the worst step (\S+) ms \(", lambda: ccma_max("warm_max_ms", "vm")),
    # speed
    Quote(
        r"load [\d.]+–[\d.]+\): 3 robots (\d+) µs per step including building the matrices \(DAQP alone (\d+) µs\), "
        r"30 robots no step above (\S+) ms \(DAQP (\S+) ms\), 100 robots (\S+) ms per step \(DAQP (\S+) ms\)",
        lambda: (
            1000 * qp_step(3, "osqp", "step_ms"),
            1000 * qp_step(3, "daqp", "step_ms"),
            qp_step(30, "osqp", "step_max_ms"),
            qp_step(30, "daqp", "step_max_ms"),
            qp_step(100, "osqp", "step_ms"),
            qp_step(100, "daqp", "step_ms"),
        ),
    ),
    Quote(
        r"\(\[`qp_step.md`\]\(benchmarks/results/qp_step.md\), load (\S+)–(\S+)\)",
        lambda: md("qp_step.md", r"load average \(1/5/15 min\) ([\d.]+)/.*? at the start, ([\d.]+)/"),
    ),
    Quote(
        r"\(\[`end_to_end.md`\]\(benchmarks/results/end_to_end.md\), commit (\w+), load (\S+)–(\S+);",
        lambda: (
            md("end_to_end.md", r"tmr commit (\w+)\.")[0],
            *md("end_to_end.md", r"Load average \(1/5/15 min\) ([\d.]+)/.*? at the start, ([\d.]+)/"),
        ),
    ),
    Quote(
        r"scenario A `qp --no-plots` takes (\S+) s wall \(median of 5\), of which (\S+) s is starting Python and "
        r"importing .*? and (\S+) s the control loop",
        lambda: (end_to_end("A", "qp"), breakdown("startup") + breakdown("imports"), breakdown("loop")),
    ),
    Quote(r"plots add (\S+) s\.", lambda: md("end_to_end.md", r"plots add to A `qp`: ([\d.]+) s wall")[0]),
    Quote(
        r"`horizon` takes (\S+) s on A and (\S+), (\S+) and (\S+) s on B, C and D",
        lambda: tuple(end_to_end(s, "horizon") for s in "ABCD"),
    ),
    Quote(r"`import tmr` \((\d+) ms\)", lambda: md("end_to_end.md", r"`tmr` ([\d.]+) ms cumulative")[0]),
    Quote(
        r"default 60 s\): F −(\d+) % f4, G −(\d+) % f4, H −(\d+) % f4",
        lambda: tuple(drone_horizon_f4_cut(s) for s in "FGH"),
    ),
    Quote(
        r"What is left in `horizon` is IPOPT's (\d+)–(\d+) iterations",
        lambda: (min(horizon_iterations()), max(horizon_iterations())),
    ),
    Quote(
        r"now evaluated once per iterate, (\d+)× faster again",
        lambda: md("horizon_spline.md", r"\| 28,195 \|(?: [\d.]+ \|){5} ([\d.]+)× \|")[0],
    ),
    Quote(
        r"E with 6 robots: optimal in (\S+) s, whole process",
        lambda: cell("horizon_rooms.csv", "wall_time", room="scenario E", horizon_result="optimal"),
    ),
    Quote(
        r"the slowest (\S+) s\);",
        lambda: max(optimal_times()),
    ),
    Quote(
        r"\[`horizon_rooms_216.md`\]\(benchmarks/results/horizon_rooms_216.md\)\) (\d+) of (\d+) plans are optimal and"
        r" under 10 s and\s+every plan is no worse than `qp`; the misses are mostly long horizons \(a median of"
        r" ([\d,]+) knots, against ([\d,]+)\)",
        lambda: all_rooms(),
    ),
    Quote(
        r"Run again at commit (\w+) \(\[`horizon_rooms_216_misses.md`\]\(benchmarks/results/"
        r"horizon_rooms_216_misses.md\)\) on a machine ([\d.]+)× slower than the table's \(by its reference runs\),"
        r" (\d+) misses gave (\d+) optimal plans, (\d+) of them under 10 s \((\d+) at the table's speed\)",
        lambda: rooms_misses(),
    ),
    Quote(
        r"Run again in full at commit (\w+) \(\[`horizon_rooms_216_(\w+).md`\]\(benchmarks/results/"
        r"horizon_rooms_216_(\w+).md\)\) on a machine ([\d.]+)× slower than the table's \(by the (\d+) runs with the"
        r" same result and IPOPT iterations in both\), (\d+) of (\d+) plans are optimal, (\d+) of them under 10 s"
        r" there \((\d+) at the table's speed\), and every plan is no worse than `qp`",
        lambda: rooms_rerun("5173c34"),
    ),
    Quote(
        r"the remaining gap of the first sample \(one narrow room, ([\d,]+)\s+knots of train references with its"
        r" `qp` plan in\s+([\d.]+) s,",
        lambda: (statistics.median(qp_only_knots()), statistics.median(qp_only_times())),
    ),
    Quote(
        r"\(`--seed 1`,\s+\[`horizon_rooms_seed1.md`\]\(benchmarks/results/horizon_rooms_seed1.md\)\) (\d+) of (\d+)"
        r" plans are optimal, all under 10 s,",
        lambda: second_sample(),
    ),
    Quote(
        r"on (\d+) generated drone worlds \(`--robots auto`\), (\d+) optimal, the median in ([\d.]+) s, whole"
        r" process",
        lambda: drone_worlds_optimal(),
    ),
    Quote(
        r"(\d+)× faster to build than casadi's symbolic Hessian and (\d+)× faster to evaluate",
        lambda: md(
            "horizon_hessian.md",
            r"\| 150917237:walls:corner:8 \| [\d,]+ \| \d+ \| exact \|(?: [\d.,]+ \|){3} ([\d.]+)× \|"
            r"(?: [\d.]+ \|){2} ([\d.]+)× \|",
        ),
    ),
]


#: the horizon's optimum, or the coarse pass's optimum interpolated with every row holding where the polish's optimum
#: costs more (its documented equivalent: formulations/horizon.md, "Coarse knots")
OPTIMAL = ("optimal", "coarse_optimal")


def optimal_times() -> list[float]:
    """Whole-process times [s] of the runs of horizon_rooms.csv whose horizon plan is optimal (all under 10 s, as the
    README says)."""
    times = [float(r["wall_time"]) for r in rows("horizon_rooms.csv") if r["horizon_result"] in OPTIMAL]
    assert max(times) < 10, "the README says every optimal run takes under 10 s"
    return times


def second_sample() -> tuple[int, int]:
    """Optimal horizon plans and plans of horizon_rooms_seed1.csv (a second sample of rooms); every plan under 10 s,
    whole process, as the README says."""
    planned = [r for r in rows("horizon_rooms_seed1.csv") if r["horizon_result"]]
    assert all(float(r["wall_time"]) < 10 for r in planned), "the README says every plan takes under 10 s"
    return sum(r["horizon_result"] in OPTIMAL for r in planned), len(planned)


def all_rooms() -> tuple[int, int, float, float]:
    """horizon_rooms_216.csv (every room of benchmarks/random_rooms.py): plans optimal and under 10 s, plans, and the
    median knots of the other plans and of those; every plan no worse than qp in each term, as the README says."""
    planned = [r for r in rows("horizon_rooms_216.csv") if r["horizon_result"]]
    no_worse_than_qp(planned)
    good = [r for r in planned if r["horizon_result"] in OPTIMAL and float(r["wall_time"]) < 10]
    bad = [r for r in planned if r not in good]
    knots = [statistics.median(float(r["knots"]) for r in rs) for rs in (bad, good)]
    return len(good), len(planned), knots[0], knots[1]


def rooms_misses() -> tuple[str, float, int, int, int, int]:
    """horizon_rooms_216_misses.csv (``benchmarks/horizon.py --misses horizon_rooms_216``): the commit measured (its
    Markdown's header; src/ unchanged from it), this machine's time against the table's (the median ratio over the
    reference runs that took the same IPOPT iterations), the misses' count, those now optimal (or the coarse
    optimum), those of them under 10 s, and those under 10 s with the times divided by that ratio. Its misses are
    exactly the table's, the runs of horizon_rooms_216.csv not optimal within 10 s (the runs the README counts the
    other way), and its "then" columns are the table's."""
    rs = rows("horizon_rooms_216_misses.csv")
    ref = [r for r in rs if r["kind"] == "reference"]
    factor = statistics.median(
        float(r["time_now"]) / float(r["time_then"]) for r in ref if r["iterations_now"] == r["iterations_then"]
    )
    miss = [r for r in rs if r["kind"] == "miss"]
    table = [r for r in rows("horizon_rooms_216.csv") if r["horizon_result"]]
    met = {(r["room"], r["robots"]) for r in table if r["horizon_result"] in OPTIMAL and float(r["wall_time"]) < 10}
    bad = {(r["room"], r["robots"]) for r in table} - met
    assert {(r["room"], r["robots"]) for r in miss} == bad and len(miss) == len(bad)
    by_run = {(r["room"], r["robots"]): r for r in table}
    for r in rs:
        t = by_run[r["room"], r["robots"]]
        then = (t["horizon_result"], float(t["wall_time"]), t["horizon_iterations"])
        assert (r["result_then"], float(r["time_then"]), r["iterations_then"]) == then, r["room"]
    now = [r for r in miss if r["result_now"] in OPTIMAL]
    commit = re.search(r"tmr commit (\w+)( \+ uncommitted)?", text("horizon_rooms_216_misses.md"))
    assert commit and not commit.group(2), "the misses table names no commit, or src/ had uncommitted changes"
    return (commit.group(1), factor, len(miss), len(now), *under_10_s([float(r["time_now"]) for r in now], factor))


def rooms_rerun(commit: str) -> tuple[str, str, str, float, int, int, int, int, int]:
    """horizon_rooms_216_COMMIT.csv (the rooms command run again in full at ``commit``): the commit in its file name
    and its Markdown's header (no uncommitted changes in src/ when it ran), this machine's time against
    horizon_rooms_216.csv's (the median ratio over the runs with the same result and IPOPT iterations in both) and how
    many those are, the optimal plans (or the coarse optimum), the plans, those optimal and under 10 s, and those with
    the times divided by that ratio. The same runs planned as the table's, each no worse than qp in every term and
    passing the independent check."""
    stem = f"horizon_rooms_216_{commit}"
    measured = re.search(r"tmr commit (\w+)( \+ uncommitted)?", text(f"{stem}.md"))
    assert measured and measured.group(1) == commit and not measured.group(2), "another commit, or src/ changed"
    new = {(r["room"], r["robots"]): r for r in rows(f"{stem}.csv") if r["horizon_result"]}
    table = {(r["room"], r["robots"]): r for r in rows("horizon_rooms_216.csv") if r["horizon_result"]}
    assert new.keys() == table.keys()
    no_worse_than_qp(new.values())
    for r in new.values():
        assert r["independent_ok"] == "True", r["room"]
    same = [
        float(new[k]["wall_time"]) / float(t["wall_time"])
        for k, t in table.items()
        if (t["horizon_result"], t["horizon_iterations"]) == (new[k]["horizon_result"], new[k]["horizon_iterations"])
    ]
    factor = statistics.median(same)
    optimal = [float(r["wall_time"]) for r in new.values() if r["horizon_result"] in OPTIMAL]
    return (commit, commit, commit, factor, len(same), len(optimal), len(new), *under_10_s(optimal, factor))


def no_worse_than_qp(planned: Iterable[dict[str, str]]) -> None:
    """Every planned row of a rooms table is no worse than its qp plan in each of f1–f4, as the README says."""
    for r in planned:
        assert all(float(r[f"horizon_{k}"]) <= float(r[f"qp_{k}"]) for k in ("f1", "f2", "f3", "f4")), r["room"]


def under_10_s(times: list[float], factor: float) -> tuple[int, int]:
    """How many of ``times`` [s] are under 10 s, and how many with each divided by ``factor`` (this machine's time
    against the table's: the count at the table's speed)."""
    return sum(t < 10 for t in times), sum(t / factor < 10 for t in times)


def qp_only_knots() -> list[float]:
    """The knots of the runs of horizon_rooms.csv that returned the qp plan."""
    return [float(r["knots"]) for r in rows("horizon_rooms.csv") if r["horizon_result"] == "warm_start"]


def qp_only_times() -> list[float]:
    """The qp time [s] of the runs of horizon_rooms.csv that returned the qp plan."""
    return [float(r["qp_time"]) for r in rows("horizon_rooms.csv") if r["horizon_result"] == "warm_start"]


def drone_worlds_optimal() -> tuple[float, float, float]:
    """Worlds, optimal horizon plans and the median whole-process time of those [s] (horizon_drone_worlds.csv)."""
    rs = rows("horizon_drone_worlds.csv")
    times = [float(r["process_s"]) for r in rs if r["result"] == "optimal"]
    return float(len(rs)), float(len(times)), statistics.median(times)


def drone_horizon_f4_cut(scenario: str) -> float:
    """How much lower f4 of the drone ``horizon`` plan is than the ``qp`` plan's [%] (horizon_drones.csv)."""
    return 100 * (
        1
        - cell("horizon_drones.csv", "f4", scenario=scenario, method="horizon")
        / cell("horizon_drones.csv", "f4", scenario=scenario, method="qp")
    )


def horizon_iterations() -> list[float]:
    """IPOPT iterations per scenario, from the cold wall-time table of horizon.md."""
    its = [float(r["IPOPT iter."]) for r in table("horizon.md", "| scenario | horizon wall [s] |")]
    assert len(its) == 4, "horizon.md lost its wall-time table"
    return its


# -- comparison --------------------------------------------------------------------------------------------------------


def parse(s: str) -> tuple[float, float]:
    """A number as the README writes it, and half a unit of its last digit: "1,080", "−0.15", "3·10⁻²", "1e-3"."""
    s = s.replace("−", "-").replace(",", "")
    m = re.fullmatch(r"(-?\d+(?:\.(\d+))?)(?:·10(\S+)|e(-?\d+))?", s)
    assert m, f"not a number: {s!r}"
    mant, dec, sup, exp = m.groups()
    e = int(sup.translate(SUPERSCRIPT)) if sup else int(exp) if exp else 0
    return float(mant) * 10.0**e, 0.5 * 10.0 ** (e - len(dec or ""))


def agrees(quoted: str, value: Any, cmp: str) -> bool:
    if value is None or isinstance(value, str):
        return value is None or quoted == value
    x, half = parse(quoted)
    if cmp == ">=":
        return x >= value
    if cmp == "<=":
        return x <= value
    return abs(x - float(value)) <= half * (1 + 1e-9) + 1e-12


@pytest.fixture(scope="module")
def readme() -> str:
    return " ".join(README.read_text(encoding="utf-8").split())


@pytest.mark.parametrize("quote", QUOTES, ids=[q.pattern[:60] for q in QUOTES])
def test_quoted_figure_matches_its_source(readme: str, quote: Quote) -> None:
    matches = list(re.finditer(quote.pattern, readme))
    assert matches, f"README no longer has the phrase {quote.pattern!r}: update QUOTES with the README"
    value = quote.source()
    values = value if isinstance(value, (tuple, list)) else (value,)
    for m in matches:
        assert len(m.groups()) == len(values), f"{quote.pattern!r}: {len(m.groups())} groups, {len(values)} values"
        for quoted, v in zip(m.groups(), values, strict=True):
            assert agrees(quoted, v, quote.cmp), f"README quotes {quoted} in “{m.group(0)}”, the source says {v!r}"


def test_results_table_is_the_benchmark_table() -> None:
    """The f1–f4 table under "Results" is the headline table of benchmarks/results/formulations.md, row for row."""

    def table(path: Path, after: str) -> list[str]:
        lines = path.read_text(encoding="utf-8").split(after, 1)[1].splitlines()
        start = next(i for i, ln in enumerate(lines) if ln.startswith("| scenario | method |"))
        return [ln.strip() for ln in lines[start + 2 :] if ln.startswith("|")][:12] if lines else []

    ours = table(README, "Scenarios A–D in the paper's setting")
    theirs = table(RESULTS / "formulations.md", "## Headline table")
    assert len(theirs) == 12 and ours == theirs


@pytest.mark.parametrize(
    ("quoted", "value", "ok"),
    [
        ("0.98", 0.9824, True),
        ("0.73", 0.9824, False),
        ("31", 31.4, True),
        ("31", 29.2, False),
        ("1,080", 1080, True),
        ("3·10⁻²", 0.0319, True),
        ("2·10⁻⁴", 0.00052, False),
        ("−0.150", -0.15, True),
        ("8", 8.53, False),
    ],
)
def test_rounding_rule(quoted: str, value: float, ok: bool) -> None:
    assert agrees(quoted, value, "=") is ok
