"""Physics replay (MuJoCo) of the built-in plans: static tether accuracy, A–D (qp, horizon), the 15 s rrt plan, MoPICK.

    python benchmarks/replay.py [--repeats 3] [--skip-mcdpr]

Writes ``benchmarks/results/replay.md`` and ``replay.csv`` and the tether-height figures of scenarios A and D (qp),
``replay_A_qp_heights.png`` and ``replay_D_qp_heights.png`` (the README shows D's and quotes its numbers).
Plans are made with the command line (``python -m tmr.plan ... --no-plots``, ``python -m tmr.mcdpr plan``) into a
temporary directory and replayed through :mod:`tmr.replay`. The real-time factor is simulated time / wall time of
the simulation loop (model building and figures excluded), the median over ``--repeats`` replays of the same run.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def static_rows() -> list[dict]:
    from tmr.model.catenary import CatenaryParams, max_span, solve
    from tmr.replay.tether import hang

    P = CatenaryParams()
    rows = []
    for n in (8, 16, 32):
        for span in (1.0, 2.0, 3.0, 4.0, 5.0, max_span()):
            t0 = time.perf_counter()
            r = hang((0.0, 0.0, 0.43), (span, 0.0, 0.43), P, n_links=n)
            wall = time.perf_counter() - t0
            c = solve(0.43, 0.43, span, P)
            rows.append(
                {
                    "links": n,
                    "span": span,
                    "lowest_err_sag": (r.lowest - c.z_min) / (0.43 - c.z_min),
                    "length_err": (r.length - c.length) / c.length,
                    "t_winch_err": (r.tension_winch - c.tension_1) / c.tension_1,
                    "t_far_err": (r.tension_far - c.tension_2) / c.tension_2,
                    "rtf": 2.0 / wall,
                }
            )
    return rows


def plan(tmp: Path, scenario: str, method: str, route: str = "shortest") -> tuple[Path, int]:
    out = tmp / f"{scenario}_{method}_{route}"
    cmd = [sys.executable, "-m", "tmr.plan", "--scenario", scenario, "--method", method, "--route", route]
    code = subprocess.run([*cmd, "--out", str(out), "--no-plots"], capture_output=True, text=True).returncode
    return out, code


def chain_row(run_dir: Path, repeats: int, figure: Path | None = None) -> dict:
    from tmr.io.rundir import load_run
    from tmr.replay.chain import replay_chain
    from tmr.replay.report import chain_verdict

    run = load_run(run_dir)
    reps = [replay_chain(run) for _ in range(repeats)]
    rp = reps[0]
    v = chain_verdict(rp, run)
    if figure is not None:
        import matplotlib.pyplot as plt

        from tmr.replay.figures import plot_heights
        from tmr.views.plot import save_figure

        fig = plot_heights(rp, f"MuJoCo replay: {run.label} — lowest point of each tether")
        save_figure(fig, figure)
        plt.close(fig)
    k_low = np.unravel_index(np.argmin(rp.lowest), rp.lowest.shape)
    return {
        "run": run.label,
        "robots": run.n_robots,
        "plan_s": float(run.t[-1]),
        "plan_ok": run.record["success"],
        "verdict": "OK" if v.ok else "FAIL",
        "reason": v.reason or "",
        "track_max_mm": 1000 * float(rp.tracking_error.max()),
        "track_rms_mm": 1000 * float(np.sqrt(np.mean(rp.tracking_error**2))),
        "min_tether_m": float(rp.lowest.min()),
        "min_tether_t_s": float(rp.t[k_low[0]]),
        "catenary_then_m": float(rp.lowest_catenary[k_low]),
        "low_err_mm": 1000 * float(np.abs(rp.lowest - rp.lowest_catenary).max()),
        "t_err_n": float(
            max(
                np.abs(rp.tension_winch - rp.tension_winch_catenary).max(),
                np.abs(rp.tension_far - rp.tension_far_catenary).max(),
            )
        ),
        "contacts": ", ".join(f"{k} {c['count']}" for k, c in rp.contacts.items() if c["count"]) or "none",
        "sim_s": rp.sim_time,
        "rtf": statistics.median(r.real_time_factor for r in reps),
        "rtf_cpu": statistics.median(r.cpu_real_time_factor for r in reps),
    }


def mcdpr_row(tmp: Path) -> dict:
    from tmr.io.rundir import load_run
    from tmr.replay.mcdpr import edge_margins, replay_mcdpr

    out = tmp / "mcdpr"
    subprocess.run([sys.executable, "-m", "tmr.mcdpr", "plan", "--out", str(out), "--no-plots"], check=False)
    run = load_run(out)
    rp = replay_mcdpr(run)
    v = rp.verdict
    margin = edge_margins(rp.wheel_force)
    return {
        "run": run.label,
        "plan_ok": run.plan["check"]["ok"],
        "verdict": "OK" if v.ok else "FAIL",
        "reason": v.reason or "",
        "platform_max_mm": 1000 * float(rp.platform_error.max()),
        "platform_rms_mm": 1000 * float(np.sqrt(np.mean(rp.platform_error**2))),
        "tension_range": f"{rp.tensions.min():.2f}–{rp.tensions.max():.2f}",
        "tension_vs_dist": float(np.nanmax(np.abs(rp.tensions - rp.tensions_plan))),
        "tipping_margin": ", ".join(f"{margin[:, j].min():.2f}" for j in range(margin.shape[1])),
        "two_wheels": ", ".join(str(int((margin[:, j] <= 1e-3).any(axis=1).sum())) for j in range(margin.shape[1])),
        "tilt_deg": float(np.degrees(rp.base_tilt.max())),
        "samples": len(rp.t),
        "contacts": ", ".join(f"{k} {c['count']}" for k, c in rp.contacts.items() if c["count"]) or "none",
        "sim_s": rp.sim_time,
        "rtf": rp.real_time_factor,
        "rtf_cpu": rp.cpu_real_time_factor,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-mcdpr", action="store_true")
    args = ap.parse_args()
    RESULTS.mkdir(exist_ok=True)
    lines = [
        "# Physics replay (MuJoCo)",
        "",
        "`python benchmarks/replay.py` — " + versions(["mujoco", "numpy", "scipy"]) + f"; tmr {source_version()}.",
        "Model and choices: [`formulations/replay.md`](../../formulations/replay.md). Real-time factor (RTF) ="
        f" simulated time / wall time of the simulation loop (median of {args.repeats} replays), and simulated time /"
        " CPU time of the process in that loop (the machine's 2 cores are shared with other jobs: the wall figure"
        " depends on their load, the CPU figure is what one free core would give).",
        "",
        "## Static tether between two fixed ends (`tmr.replay.tether.hang`, 2 s settled) vs `tmr.model.catenary`",
        "",
        "Relative errors: lowest point / sag (H − z_min), paid-out length, tension at the winch and at the far end.",
        "",
        "| links | span [m] | lowest / sag | length | T winch | T far | RTF |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in static_rows():
        lines.append(
            f"| {r['links']} | {r['span']:.3f} | {r['lowest_err_sag']:+.1e} | {r['length_err']:+.1e} | "
            f"{r['t_winch_err']:+.1e} | {r['t_far_err']:+.1e} | {r['rtf']:.0f}× |"
        )
    rows = []
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        jobs = [(s, m, "shortest") for s in "ABCD" for m in ("qp", "horizon")] + [("A", "qp", "rrt")]
        for s, m, route in jobs:
            run_dir, code = plan(tmp, s, m, route)
            if not (run_dir / "run.json").is_file():
                rows.append({"run": f"scenario {s}, {m}, {route}", "verdict": f"no plan (exit {code})"})
                continue
            fig = RESULTS / f"replay_{s}_qp_heights.png" if (m, route) == ("qp", "shortest") and s in "AD" else None
            row = chain_row(run_dir, args.repeats, fig)
            row["run"] += f", route {route}"
            rows.append(row)
            print(row, flush=True)
        mrow = None if args.skip_mcdpr else mcdpr_row(tmp)
    lines += [
        "",
        "## Tethered chain: built-in scenarios",
        "",
        "Tracking: distance of each robot to its (filtered) planned trajectory. Lowest tether point: the lowest node"
        " of any tether over the run, next to the static catenary of the same ends at that moment; |Δ| columns: the"
        " largest gap to the catenary over the run (lowest point, end tensions).",
        "",
        "| run | N | plan [s] | plan ok | replay | tracking max / rms [mm] | lowest tether [m] at t (catenary) | "
        "max abs lowest-point error [mm] | max abs tension error [N] | contacts (physics steps) | RTF wall / CPU | "
        "first reason |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "track_max_mm" not in r:
            lines.append(f"| {r['run']} | | | | {r['verdict']} | | | | | | | |")
            continue
        lines.append(
            f"| {r['run']} | {r['robots']} | {r['plan_s']:.1f} | {r['plan_ok']} | {r['verdict']} | "
            f"{r['track_max_mm']:.2f} / {r['track_rms_mm']:.2f} | "
            f"{r['min_tether_m']:.3f} at {r['min_tether_t_s']:.1f} s ({r['catenary_then_m']:.3f}) | "
            f"{r['low_err_mm']:.2f} | {r['t_err_n']:.2f} | {r['contacts']} | {r['rtf']:.1f}× / {r['rtf_cpu']:.1f}× | "
            f"{r['reason']} |"
        )
    if mrow is not None:
        lines += [
            "",
            "## MoPICK (Rasheed 2019), scene fig2",
            "",
            "| run | plan ok | replay | platform error max / rms [mm] | cable tensions [N] | max abs tension − "
            "tmr.mcdpr.tension [N] | tipping margin per base [N] | samples on two wheels per base | max tilt [°] | "
            "contacts | simulated [s] | RTF wall / CPU | first reason |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
            f"| {mrow['run']} | {mrow['plan_ok']} | {mrow['verdict']} | {mrow['platform_max_mm']:.1f} / "
            f"{mrow['platform_rms_mm']:.1f} | {mrow['tension_range']} | {mrow['tension_vs_dist']:.2f} | "
            f"{mrow['tipping_margin']} | {mrow['two_wheels']} (of {mrow['samples']}) | {mrow['tilt_deg']:.2f} | "
            f"{mrow['contacts']} | {mrow['sim_s']:.0f} | {mrow['rtf']:.1f}× / {mrow['rtf_cpu']:.1f}× | "
            f"{mrow['reason']} |",
        ]
    (RESULTS / "replay.md").write_text("\n".join(lines) + "\n")
    with (RESULTS / "replay.csv").open("w", newline="") as fh:
        keys = sorted({k for r in rows for k in r})
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
