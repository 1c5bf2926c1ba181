"""Formulation benchmark through the sweep executors: scenarios × methods → one :class:`RunResult` each.

The scores (f1–f4, clearances, spans, separation, peak speed/acceleration, distance-error bounds of Caruso 2021
Fig. 7) are deterministic; the timing fields (median loop time over ``repeats``) are wall-clock measurements — run
with ``--jobs 1`` for timings not disturbed by concurrent plans.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from tmr.sweep.report import fmt, markdown_table
from tmr.sweep.runs import RunResult, RunSpec

__all__ = ["BENCH_COLUMNS", "bench_markdown", "bench_specs"]

#: (RunResult attribute, Markdown header, format) of the benchmark table.
BENCH_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("f1", "f1", ".4g"),
    ("f2", "f2 [m²]", ".4g"),
    ("f3", "f3 [m²]", ".3g"),
    ("f4", "f4", ".4g"),
    ("min_robot_clearance", "min robot clr [m]", "+.3f"),
    ("min_tether_clearance", "min tether clr [m]", "+.3f"),
    ("max_span_ratio", "max span / d_max", ".3f"),
    ("min_separation", "min robot–robot [m]", ".3f"),
    ("peak_speed", "peak speed [m/s]", ".2f"),
    ("peak_acceleration", "peak acc [m/s²]", ".1f"),
    ("distance_error_min", "dist err min [m]", "+.3f"),
    ("distance_error_max", "dist err max [m]", "+.3f"),
)


def bench_specs(
    scenarios: Sequence[str],
    methods: Sequence[str],
    seed: int = 0,
    repeats: int = 1,
    n_robots: int | None = None,
    overrides: dict[str, Any] | None = None,
) -> list[RunSpec]:
    """Scenario-major list of runs (scenario outer, method inner), all with the same ``overrides``."""
    shared = tuple(sorted((overrides or {}).items()))
    return [RunSpec(s, m, seed, shared, n_robots, repeats) for s in scenarios for m in methods]


def bench_markdown(results: Sequence[RunResult], timing: bool = True) -> str:
    """Markdown table of a benchmark; f1–f4 of failed plans are the raw values in brackets (the paper scores +∞)."""
    header = list(BENCH_HEADER)
    if timing:
        header += ["plan [ms/step]", "plan [s]"]
    rows = []
    for r in results:
        cells = bench_cells(r)
        if timing:
            cells += [fmt(r.ms_per_step, ".3f"), fmt(r.plan_time, ".2f")]
        rows.append(cells)
    return markdown_table(header, rows)


#: Header of the score columns of :func:`bench_cells`.
BENCH_HEADER = ("scenario", "method", "success", *(h for _, h, _ in BENCH_COLUMNS))


def bench_cells(r: RunResult) -> list[str]:
    """Scenario, method, success and the :data:`BENCH_COLUMNS` of one run, formatted; f1–f4 of a failed plan are the
    raw values of its recorded motion in brackets (the paper scores a failure +∞)."""
    cells = [r.spec.scenario, r.spec.method, fmt(r.success)]
    for key, _, spec in BENCH_COLUMNS:
        if key in ("f1", "f2", "f3", "f4") and not r.success:
            cells.append(f"({fmt(r.raw[int(key[1]) - 1], spec)})")
        else:
            cells.append(fmt(getattr(r, key), spec))
    return cells
