"""Physics replay (MuJoCo) of the built-in plans: static tether accuracy, A–D (qp, horizon), the 15 s rrt plan, MoPICK,
and the drone chains F, G, H.

    python benchmarks/replay.py [--repeats 3] [--skip-mcdpr] [--drones-only]

The drone rows (a tether between two hovering drones against ``tmr.model.catenary3d``, F, G, H, and plans made for a
tether 3× too light replayed with the true density) go to ``benchmarks/results/replay_drones.md`` and
``replay_drones.csv``; ``--drones-only`` runs only those.

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


def _e(x: float, sign: str) -> str:
    """x in 1.0e-03 form, or "–" when there is none (NaN)."""
    return "–" if x != x else format(x, sign + ".1e")


def drone_static_rows() -> list[dict]:
    """Two drones holding station, one tether between them (5 s), against tmr.model.catenary3d's catenary (the winch
    at the lower end, and one case at the upper end)."""
    from tmr.model.catenary3d import DroneTetherParams, solve3d
    from tmr.replay.drones import DroneChain, DroneReplayConfig, drone_verdict, replay_drones

    rows = []
    lower = (((0, 0, 2), (3, 0, 3)), ((0, 0, 2), (8, 0, 2.5)), ((0, 0, 2), (0.3, 0, 5)), ((0, 0, 3), (10, 0, 3.5)))
    cases = [(p1, p2, "lower") for p1, p2 in lower] + [((0, 0, 2), (8, 0, 2.5), "upper")]
    for p1, p2, winch_end in cases:
        params = DroneTetherParams(winch_end=winch_end)
        k = 101
        pos = np.broadcast_to(np.array([p1, p2], dtype=float), (k, 2, 3)).copy()
        chain = DroneChain(
            np.arange(k) * 0.05, pos, np.zeros_like(pos), None, params, None, Path("."),
            np.array([-5.0, -5.0, 0.0, 20.0, 5.0, 6.0]), "hover",
        )  # fmt: skip
        rp = replay_drones(chain, DroneReplayConfig())
        c = solve3d(p1, p2, params)
        sag = min(p1[2], p2[2]) - float(c.lowest[2])
        last = rp.t >= rp.t[-1] - 2.0  # means over the last 2 s (the light cable keeps a small swing)
        low = rp.lowest[last, 0]
        rows.append(
            {
                "ends": f"{p1} – {p2}" + (", winch upper" if winch_end == "upper" else ""),
                "lowest_m": float(low.mean()),
                "lowest_cat_m": float(c.lowest[2]),
                "lowest_err_sag": (low.mean() - c.lowest[2]) / sag if sag > 1e-9 else float("nan"),
                "lowest_swing_sag": (low.max() - low.min()) / sag if sag > 1e-9 else float("nan"),
                "t_from_err": (rp.tension_from[last, 0].mean() - c.tension_p) / c.tension_p,
                "t_to_err": (rp.tension_to[last, 0].mean() - c.tension_q) / c.tension_q,
                "track_mm": 1000 * float(rp.tracking_error[-1].max()),
                "verdict": "OK" if drone_verdict(rp).ok else "FAIL",
                "rtf": rp.real_time_factor,
            }
        )
    return rows


def drone_row(run_dir: Path, repeats: int, density: float | None = None) -> dict:
    from tmr.io.rundir import load_run
    from tmr.replay.drones import DroneReplayConfig, chain_of_run, drone_verdict, replay_drones

    run = load_run(run_dir)
    chain = chain_of_run(run)
    reps = [replay_drones(chain, DroneReplayConfig(tether_density=density)) for _ in range(repeats)]
    rp = reps[0]
    v = drone_verdict(rp)
    return {
        "run": run.label + (f", rho {chain.params.mass_per_length:g} replayed at {density:g}" if density else ""),
        "drones": run.n_robots,
        "plan_s": float(run.t[-1]),
        "plan_ok": run.record["success"],
        "verdict": "OK" if v.ok else "FAIL",
        "reason": v.reason or "",
        "track_max_mm": 1000 * float(rp.tracking_error.max()),
        "track_rms_mm": 1000 * float(np.sqrt(np.mean(rp.tracking_error**2))),
        "tilt_deg": float(np.degrees(rp.tilt.max())),
        "rotor_peak": float(rp.rotor_peak.max()),
        "rotor_mean": float(rp.rotor_mean.mean()),
        "rotor_limit": rp.rotor_limit,
        "saturation_pct": 100 * float(rp.saturation_fraction.max()),
        "saturation_run_ms": 1000 * float(rp.saturation_run.max()),
        "pull_max_n": float(np.nanmax(rp.pull)),
        "spare_thrust_n": rp.spare_thrust,
        "demand_max_n": float(np.nanmax(rp.thrust_demand)),
        "reserve_thrust_n": rp.reserve_thrust,
        "clearance_min_m": float(np.nanmin(rp.clearance)),
        "clearance_plan_m": rp.tether_clearance,
        "accel_removed_max": float(np.nanmax(rp.accel_removed)),
        "min_tether_m": float(rp.lowest.min()),
        "plan_then_m": float(rp.lowest_plan.flat[int(np.argmin(rp.lowest))]),
        "low_vs_plan_mm": 1000 * float(np.nanmax(np.abs(rp.lowest - rp.lowest_plan))),
        "t_vs_plan_n": float(
            max(
                np.nanmax(np.abs(rp.tension_from - rp.tension_from_plan)),
                np.nanmax(np.abs(rp.tension_to - rp.tension_to_plan)),
            )
        ),
        "contacts": ", ".join(f"{k} {c['count']}" for k, c in rp.contacts.items() if c["count"]) or "none",
        "sim_s": rp.sim_time,
        "rtf": statistics.median(r.real_time_factor for r in reps),
        "rtf_cpu": statistics.median(r.cpu_real_time_factor for r in reps),
    }


def drone_section(repeats: int) -> tuple[list[str], list[dict]]:
    lines = [
        "## Drone chains: a tether between two hovering drones vs `tmr.model.catenary3d`",
        "",
        "Two drones of the planner's defaults hold station under the cascaded controller (5 s), one tether between"
        " them (16 links, winch at the lower end holding T_w = 2 N); relative errors of the simulated cable against"
        " `solve3d` of the same planned ends, means over the last 2 s: lowest point / sag (none when the vertex lies"
        " beyond the lower end) and its swing (max − min) / sag, tension at the lower and the upper end.",
        "",
        "| ends [m] | lowest [m] (catenary) | lowest / sag | swing / sag | T lower | T upper | tracking [mm] | verdict "
        "| RTF |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in drone_static_rows():
        lines.append(
            f"| {r['ends']} | {r['lowest_m']:.4f} ({r['lowest_cat_m']:.4f}) | {_e(r['lowest_err_sag'], '+')} | "
            f"{_e(r['lowest_swing_sag'], '')} | {r['t_from_err']:+.1e} | {r['t_to_err']:+.1e} | {r['track_mm']:.2f} | "
            f"{r['verdict']} | {r['rtf']:.0f}× |"
        )
    rows = []
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for s in "FGHI":
            run_dir, code = plan(tmp, s, "qp")
            rows.append(drone_row(run_dir, repeats) if code == 0 else {"run": s, "verdict": f"no plan ({code})"})
            print(rows[-1], flush=True)
        for s in "FGH":  # planned for a tether 3x too light, replayed with the true density
            out = tmp / f"{s}_light"
            cmd = [sys.executable, "-m", "tmr.plan", "--scenario", s, "--set", "mass_per_length=0.005"]
            code = subprocess.run([*cmd, "--out", str(out), "--no-plots"], capture_output=True).returncode
            rows.append(drone_row(out, 1, 0.015) if code == 0 else {"run": s, "verdict": f"no plan ({code})"})
            print(rows[-1], flush=True)
    lines += [
        "",
        "## Drone chains: F, G, H, I (qp)",
        "",
        "Tracking: distance of each drone to the plan's positions (the drones fly a reference smoothed with σ = 0.15"
        " s). Rotor thrust: the largest of any rotor, the mean of all, against f_max; saturation: the largest share"
        " of physics steps a drone had a rotor at 0 or f_max, and the longest unbroken run (fails > 50 ms). Pull: the"
        " largest tether tension on a drone against the planner's spare thrust; thrust asked: the largest collective"
        " thrust the controller asked for against (1 − reserve) 4 f_max. Smoothing: the largest acceleration the"
        " reference's smoothing removed from the plan's (fails > 15 m/s²). Lowest tether point over the run and the"
        " planner's catenary at that moment; least tether distance to the world against c_t (fails < c_t / 2); |Δ|"
        " columns: the largest gap to the planner's catenary of the planned ends.",
        "",
        "| run | N | plan [s] | replay | tracking max / rms [mm] | tilt max [°] | rotor peak / mean / f_max [N] | "
        "saturation [%] / longest [ms] | pull / spare [N] | thrust asked / reserve [N] | smoothing [m/s²] | "
        "lowest tether [m] (plan) | least tether distance / c_t [m] | max abs lowest vs plan [mm] | "
        "max abs tension vs plan [N] | contacts | RTF wall / CPU | first reason |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "track_max_mm" not in r:
            lines.append(f"| {r['run']} | | | {r['verdict']} |" + " |" * 14)
            continue
        lines.append(
            f"| {r['run']} | {r['drones']} | {r['plan_s']:.1f} | {r['verdict']} | {r['track_max_mm']:.1f} / "
            f"{r['track_rms_mm']:.1f} | {r['tilt_deg']:.1f} | {r['rotor_peak']:.2f} / {r['rotor_mean']:.2f} / "
            f"{r['rotor_limit']:.2f} | {r['saturation_pct']:.2f} / {r['saturation_run_ms']:.0f} | "
            f"{r['pull_max_n']:.2f} / {r['spare_thrust_n']:.2f} | "
            f"{r['demand_max_n']:.1f} / {r['reserve_thrust_n']:.1f} | "
            f"{r['accel_removed_max']:.1f} | {r['min_tether_m']:.3f} ({r['plan_then_m']:.3f}) | "
            f"{r['clearance_min_m']:.3f} / {r['clearance_plan_m']:.2f} | {r['low_vs_plan_mm']:.1f} | "
            f"{r['t_vs_plan_n']:.3f} | {r['contacts']} | {r['rtf']:.1f}× / "
            f"{r['rtf_cpu']:.1f}× | {r['reason']} |"
        )
    return lines, rows


def write_drones(repeats: int) -> list[str]:
    lines, rows = drone_section(repeats)
    head = [
        "# Physics replay (MuJoCo): drone chains",
        "",
        "`python benchmarks/replay.py --drones-only` — " + versions(["mujoco", "numpy", "scipy"])
        + f"; {source_version()}. Model: [`formulations/replay.md`](../../formulations/replay.md), \"Drone"
        f" chains\". RTF = simulated time / wall time (CPU time) of the simulation loop, median of {repeats} replays"
        " (1 for the light-tether rows); the machine's 2 cores are shared with other jobs.",
        "",
    ]  # fmt: skip
    (RESULTS / "replay_drones.md").write_text("\n".join(head + lines) + "\n")
    with (RESULTS / "replay_drones.csv").open("w", newline="") as fh:
        keys = sorted({k for r in rows for k in r})
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    print("\n".join(lines))
    return lines


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-mcdpr", action="store_true")
    ap.add_argument("--drones-only", action="store_true", help="only the drone rows (replay_drones.md)")
    args = ap.parse_args()
    RESULTS.mkdir(exist_ok=True)
    if args.drones_only:
        write_drones(args.repeats)
        return
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
    lines += ["", *write_drones(args.repeats)]
    (RESULTS / "replay.md").write_text("\n".join(lines) + "\n")
    with (RESULTS / "replay.csv").open("w", newline="") as fh:
        keys = sorted({k for r in rows for k in r})
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
