"""Deterministic outputs of the sweeps: CSV rows, Markdown tables, Fig. 9-style heatmaps (Caruso 2021 §5.1).

CSV floats are written with ``repr`` (shortest round-trip), so the same results give the same bytes; figures go
through :func:`tmr.views.plot.save_figure` (no dates in the metadata).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from tmr.sweep.grid import PAPER_RANGES, UNITS, SensitivityResult

__all__ = ["csv_text", "fmt", "heatmap_figure", "markdown_table", "sensitivity_markdown"]


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return repr(v)
    if v is None:
        return ""
    return str(v)


def csv_text(rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None) -> str:
    """CSV of ``rows`` (``\\n`` line ends); columns: the union of the keys in first-seen order unless given."""
    if columns is None:
        seen: dict[str, None] = {}
        for r in rows:
            seen.update(dict.fromkeys(r))
        columns = list(seen)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in columns])
    return buf.getvalue()


def fmt(v: Any, spec: str = ".4g") -> str:
    """A number for a Markdown cell: ``spec`` format, ``∞`` for +inf, ``–`` for NaN/None."""
    if v is None:
        return "–"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, float, np.floating, np.integer)):
        v = float(v)
        if math.isnan(v):
            return "–"
        if math.isinf(v):
            return "∞" if v > 0 else "−∞"
        return format(v, spec)
    return str(v)


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A GitHub Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def sensitivity_markdown(res: Sequence[SensitivityResult], command: str) -> str:
    """Markdown report of sensitivity sweeps: ranges of f1–f4 over the feasible cells next to the paper's, the
    feasible fraction, and the feasibility map of each sweep (``■`` failed, ``·`` succeeded)."""
    out = io.StringIO()
    out.write("# Sensitivity of f1–f4 to k_v0 and d_min (Caruso 2021 §5.1, Fig. 9)\n\n")
    out.write(f"`{command}`\n\n")
    for r in res:
        g = r.grid
        out.write(
            f"- {r.scenario} / {r.method}: {g.x_name} ∈ [{g.x[0]:g}, {g.x[-1]:g}] {UNITS.get(g.x_name, '')} "
            f"({len(g.x)} values) × {g.y_name} ∈ [{g.y[0]:g}, {g.y[-1]:g}] {UNITS.get(g.y_name, '')} "
            f"({len(g.y)} values); seed {r.seed}.\n"
        )
    out.write(
        "\nRanges are over the feasible cells (a failed plan scores +∞, the paper's blind penalty); f1, f4 in mixed "
        "joint units (rad²/s² + m²/s², rad²/s⁴ + m²/s⁴), f2, f3 in m². `qp` reads neither d_min nor k_v0 (it has no "
        "obstacle task): its grid sweeps its counterparts d_safe (clearance kept by the hard limit) and "
        "approach_rate (velocity-damper rate) over the same factors.\n\n"
    )
    header = ["scenario", "method", "swept", "feasible", "f1 range", "f2 range [m²]", "f3 range [m²]", "f4 range"]
    rows = [
        [
            "paper (D)",
            "pinv",
            "d_min, k_v0",
            "–",
            *(f"[{fmt(PAPER_RANGES[k][0])}, {fmt(PAPER_RANGES[k][1])}]" for k in ("f1", "f2", "f3", "f4")),
        ]
    ]
    for r in res:
        rng = r.ranges()
        rows.append(
            [
                r.scenario,
                r.method,
                f"{r.grid.x_name}, {r.grid.y_name}",
                f"{int(r.feasible.sum())}/{r.feasible.size}",
                *(f"[{fmt(rng[k][0])}, {fmt(rng[k][1])}]" for k in ("f1", "f2", "f3", "f4")),
            ]
        )
    out.write(markdown_table(header, rows))
    for r in res:
        g = r.grid
        out.write(f"\n## {r.scenario} / {r.method}: feasibility (■ failed, · succeeded)\n\n")
        head = [f"{g.y_name} \\ {g.x_name}"] + [f"{v:g}" for v in g.x]
        ok = r.feasible
        body = [[f"{g.y[i]:g}"] + ["·" if ok[i, j] else "■" for j in range(len(g.x))] for i in range(len(g.y))]
        out.write(markdown_table(head, body))
        reasons: dict[str, int] = {}
        for x in r.results:
            if not x.success and x.failure:
                kinds = sorted({part.split(" violated")[0].strip() for part in x.failure.split(";")})
                key = ", ".join(kinds)
                reasons[key] = reasons.get(key, 0) + 1
        if reasons:
            out.write("\nFailures: " + "; ".join(f"{k} ({n})" for k, n in sorted(reasons.items())) + ".\n")
        raw = {k: r.field(f"raw_{k}") for k in ("f1", "f2", "f3", "f4")}
        out.write(
            "Raw values of the recorded motion over all cells (failed included): "
            + ", ".join(f"{k} ∈ [{fmt(np.nanmin(v))}, {fmt(np.nanmax(v))}]" for k, v in raw.items())
            + ".\n"
        )
    return out.getvalue()


def _edges(v: Sequence[float]) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    mid = 0.5 * (v[1:] + v[:-1])
    return np.r_[v[0] - (mid[0] - v[0]), mid, v[-1] + (v[-1] - mid[-1])]


def heatmap_figure(res: SensitivityResult, raw: bool = False) -> Any:
    """Fig. 9 of Caruso 2021: one heatmap per fitness f1–f4 over (d_min, k_v0), failed cells in black.

    With ``raw=True`` the colours are the values of the recorded motion for every cell (failed ones too) and
    failed cells are marked with ``×`` instead of being blacked out.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import colors
    from matplotlib.figure import Figure

    g = res.grid
    ok = res.feasible
    fig = Figure(figsize=(10, 8), layout="constrained")
    axes = fig.subplots(2, 2)
    xe, ye = _edges(g.x), _edges(g.y)
    units = {"f1": "", "f2": " [m²]", "f3": " [m²]", "f4": ""}
    for ax, k in zip(axes.flat, ("f1", "f2", "f3", "f4"), strict=True):
        vals = res.field(f"raw_{k}" if raw else k)
        masked = np.ma.masked_invalid(np.where(ok | raw, vals, np.nan))
        cmap = matplotlib.colormaps["viridis"].with_extremes(bad="black")
        data = masked.compressed()
        norm: Any = None
        if data.size and data.min() > 0 and data.max() / data.min() > 20:
            norm = colors.LogNorm(vmin=data.min(), vmax=data.max())
        mesh = ax.pcolormesh(xe, ye, masked, cmap=cmap, norm=norm, shading="flat")
        if data.size:
            fig.colorbar(mesh, ax=ax)
        else:
            ax.text(0.5, 0.5, "no feasible cell", color="white", ha="center", va="center", transform=ax.transAxes)
        if raw and not ok.all():
            yy, xx = np.nonzero(~ok)
            ax.scatter(np.asarray(g.x)[xx], np.asarray(g.y)[yy], marker="x", s=12, c="white", linewidths=0.8)
        ax.set_xlabel(f"{g.x_name} [{UNITS.get(g.x_name, '')}]")
        ax.set_ylabel(f"{g.y_name} [{UNITS.get(g.y_name, '')}]")
        ax.set_title(f"{k}{units[k]}")
    what = "raw values (× = failed)" if raw else "black = failed (f = +∞)"
    fig.suptitle(f"Sensitivity, scenario {res.scenario}, {res.method}: {what}")
    return fig


def moga_markdown(res: Any, command: str) -> str:
    """Markdown report of a :class:`tmr.sweep.moga.MogaResult`: settings, Pareto front table, chosen set."""
    F = res.F
    feasible = int(np.all(np.isfinite(F), axis=1).sum())
    names = [v.name for v in res.variables]
    out = io.StringIO()
    out.write(f"# MOGA tuning (NSGA-II), scenario {res.scenario}, {res.method} (Caruso 2021 §4.2.2)\n\n")
    out.write(f"`{command}`\n\n")
    out.write(
        f"NSGA-II (pymoo), population {res.pop_size}, {res.n_gen} generations, seed {res.seed}: "
        f"{len(res.results)} plans, {feasible} feasible. Objectives f1–f4 (eq. 24–27), minimised; a failed plan is "
        "infeasible (constraint = its violation in m). Pareto front = non-dominated feasible plans over every "
        "generation; chosen = the front point nearest the ideal point with each objective normalised over the "
        "front.\n\n"
    )
    out.write("Decision variables: " + ", ".join(f"{v.name} ∈ [{v.low:g}, {v.high:g}]" for v in res.variables))
    out.write(".\n\n## Pareto front\n\n")
    header = ["#", "gen", *names, "f1", "f2 [m²]", "f3 [m²]", "f4", "chosen"]
    rows = []
    for n, i in enumerate(res.pareto, start=1):
        rows.append(
            [
                str(n),
                str(int(res.generation[i])),
                *(fmt(x, ".4g") for x in res.X[i]),
                *(fmt(f, ".4g") for f in F[i]),
                "**yes**" if i == res.chosen else "",
            ]
        )
    out.write(markdown_table(header, rows) if rows else "No feasible plan: no front.\n")
    out.write("\n## Chosen parameter set\n\n")
    if res.chosen >= 0:
        out.write(markdown_table(["parameter", "value"], [[k, f"{v:.6g}"] for k, v in res.chosen_params().items()]))
        out.write("\nf1–f4 = " + ", ".join(fmt(f, ".6g") for f in F[res.chosen]) + "\n")
    else:
        out.write("none (no feasible plan)\n")
    viol = np.array([r.violation for r in res.results], dtype=float)
    if viol.size and not feasible:
        i = int(np.nanargmin(viol))
        out.write(
            f"\nLeast-violating plan (evaluation {i}, generation {int(res.generation[i])}): violation "
            f"{viol[i]:.3f} m ({res.results[i].failure}) with "
            + ", ".join(f"{n} = {x:.4g}" for n, x in zip(names, res.X[i], strict=True))
            + ".\nBest violation per generation [m]: "
            + ", ".join(f"{np.nanmin(viol[res.generation == g]):.3f}" for g in range(1, res.n_gen + 1))
            + ".\n"
        )
    return out.getvalue()


def moga_rows(res: Any) -> list[dict[str, Any]]:
    """One CSV row per evaluation: generation, variables, scores, Pareto membership, chosen flag."""
    front = set(res.pareto)
    rows = []
    for i, r in enumerate(res.results):
        row: dict[str, Any] = {"index": i, "generation": int(res.generation[i])}
        row.update(r.row())
        row["pareto"] = i in front
        row["chosen"] = i == res.chosen
        rows.append(row)
    return rows


def moga_figure(res: Any) -> Any:
    """Pairwise objective scatter plots: feasible plans grey, Pareto front red, chosen set a black star."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    F = res.F
    ok = np.all(np.isfinite(F), axis=1)
    front = np.asarray(res.pareto, dtype=int)
    fig = Figure(figsize=(12, 7), layout="constrained")
    axes = fig.subplots(2, 3)
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    for ax, (a, b) in zip(axes.flat, pairs, strict=True):
        ax.scatter(F[ok, a], F[ok, b], s=10, c="0.7", label="feasible")
        if front.size:
            ax.scatter(F[front, a], F[front, b], s=18, c="tab:red", label="Pareto front")
        if res.chosen >= 0:
            ax.scatter(F[res.chosen, a], F[res.chosen, b], s=120, marker="*", c="k", label="chosen")
        for axis, k in ((ax.xaxis, a), (ax.yaxis, b)):
            v = F[ok, k]
            if v.size and v.min() > 0 and v.max() / v.min() > 20:
                (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
        ax.set_xlabel(f"f{a + 1}")
        ax.set_ylabel(f"f{b + 1}")
    axes.flat[0].legend(fontsize=8)
    n_fail = int((~ok).sum())
    fig.suptitle(
        f"NSGA-II on scenario {res.scenario}, {res.method}: {len(F)} plans ({n_fail} failed, not shown), "
        f"{len(res.pareto)} on the front"
    )
    return fig
