"""Active winches against the constant winch tension (issue 34, ``formulations/drones.md``, "Active winch").

Scenario I (G's room and 1.8 m wall under a 2.6 m ceiling, 6.3 m tethers, ``[tether] winch = "active"``) and G,
each planned with ``--method qp`` with the active winch and with ``winch = "constant"`` (T_w = 2 N): the drones
needed (``--robots auto``: the fewest from the route's minimum that pass every check), the verdict and exit code of
the whole ``tmr plan`` process for the scenario's own count, and, per plan, the tensions used, the least tether
clearance, the largest pull on a drone, f1–f4 of the checker, the planning time (``plan.wall_time``: route,
loop and check, in this process) and the median time of a step of the loop (``diagnostics["step_time"]``), each the
median of ``--repeat`` runs. Writes ``benchmarks/results/active_winch.md``.

    PYTHONPATH=src python benchmarks/active_winch.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

from tmr.planner3d import plan_drones
from tmr.world.drones import load_drone_scenario

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "active_winch.md"


def _cli(scenario: str, robots: str, winch: str, *extra: str) -> tuple[int, str]:
    """Exit code and the verdict (or the ``--robots auto`` line) of a whole ``tmr plan`` process."""
    out_dir = f"/tmp/tmr_active_winch_{scenario}_{robots}_{winch}"
    cmd = [sys.executable, "-m", "tmr.plan", "--scenario", scenario, "--robots", robots, "--no-plots",
           "--set", f"winch={winch}", *extra, "--out", out_dir]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    lines = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.strip()]
    auto = next((ln for ln in lines if "--robots auto" in ln), "")
    verdict = next((ln for ln in lines if ln.startswith(("plan FAILED", "error"))), "every check passed")
    return r.returncode, auto or verdict


def _row(scenario: str, robots: int, winch: str, repeat: int, settle: float | None = None) -> list[str]:
    sc = load_drone_scenario(scenario)
    times, steps = [], []
    over: dict[str, object] = {"winch": winch} | ({} if settle is None else {"settle": settle})
    for _ in range(repeat):
        plan, m = plan_drones(sc, robots, overrides=over)
        times.append(plan.wall_time)
        steps.append(float(np.nanmedian(plan.diagnostics["step_time"])))
    w = m.winch or {}
    used = f"{w['min_tension_used']:.2f}–{w['max_tension_used']:.2f}" if w else f"{plan.tether.winch_tension:.2f}"
    verdict = "passed" if m.success else "FAILED: " + str(m.failure).split(";")[0][:110]
    f = " / ".join(f"{v:.4g}" for v in (m.f1, m.f2, m.f3, m.f4))
    label = winch + ("" if settle is None else f", settle {settle:g} s")
    return [scenario, str(robots), label, verdict, used, f"{m.max_drone_tension:.2f}", f"{m.min_tether_clearance:.3f}",
            f"{m.final_leader_error:.3f}", f, f"{m.duration:.2f}", f"{statistics.median(times):.2f}",
            f"{1e3 * statistics.median(steps):.2f}"]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per plan (median time)")
    args = ap.parse_args()
    out = ["# Active winch vs constant winch tension (drone chains)", "",
           f"`PYTHONPATH=src python benchmarks/active_winch.py --repeat {args.repeat}` (2 cores shared; times: "
           f"median of {args.repeat} in-process runs of `plan_drones`, route + loop + check).", "",
           "## Drones needed (`tmr plan --scenario S --robots auto --no-plots --set winch=W`)", "",
           "| scenario | winch | exit | --robots auto |", "|---|---|---|---|"]  # fmt: skip
    for scenario in ("I", "G"):
        for winch in ("active", "constant"):
            code, line = _cli(scenario, "auto", winch)
            out.append(f"| {scenario} | {winch} | {code} | {line.split('auto: ', 1)[-1]} |")
    out += ["", "## Verdicts of the whole process (`tmr plan --scenario S --robots N --no-plots --set winch=W`)", "",
            "| scenario | N | winch | exit | last line |", "|---|---|---|---|---|"]  # fmt: skip
    slow = ("--set", "settle=30")
    for scenario, n, extra in (("I", "2", ()), ("I", "2", slow), ("I", "3", ()), ("I", "3", slow), ("G", "3", ())):
        for winch in ("active", "constant"):
            code, line = _cli(scenario, n, winch, *extra)
            out.append(f"| {scenario} | {n} | {winch} {' '.join(extra)} | {code} | {line[:200]} |")
    out += ["", "## Plans side by side", "",
            "| scenario | N | winch | verdict | T_w used [N] | max pull on a drone [N] | min tether clearance [m] | "
            "leader to goal [m] | f1 / f2 / f3 / f4 | plan duration [s] | planning time [s] | median step [ms] |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for scenario, n, winch, settle in (("I", 2, "active", None), ("I", 2, "constant", None),
                                       ("I", 2, "constant", 30.0), ("I", 3, "constant", None),
                                       ("I", 3, "constant", 30.0),
                                       ("I", 4, "constant", None), ("G", 3, "active", None),
                                       ("G", 3, "constant", None)):  # fmt: skip
        out.append("| " + " | ".join(_row(scenario, n, winch, args.repeat, settle)) + " |")
    text = "\n".join(out) + "\n"
    OUT.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
