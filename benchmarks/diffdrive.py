"""Differential-drive robots (issue 35, ``formulations/diffdrive.md``) on scenarios A–E with every preset.

Each scenario is planned with ``--method qp`` for the omnidirectional robots of Caruso 2021 (the reference) and with
``drive = "diff"`` for each robot preset of ``src/tmr/model/robot_models.toml``; per plan: the verdict, the steps and
the duration of the motion, and what the checker (:mod:`tmr.checks.diffdrive`) measured from the recorded poses — the
largest lateral velocity of an axle centre, the peak v, ω, v̇, ω̇ against their bounds, the steps a robot turns in
place — with the leader's largest and final tracking errors, the least robot clearance and the planning time
(``plan.wall_time``: route, loop and checks, in this process; median of ``--repeat`` runs). Writes
``benchmarks/results/diffdrive.md`` and its CSV twin.

    PYTHONPATH=src python benchmarks/diffdrive.py [--repeat 1] [--scenarios ABCDE]
"""

from __future__ import annotations

import argparse
import csv
import statistics
from pathlib import Path

from tmr.model.diffdrive import preset_names
from tmr.planner import build_problem, solve
from tmr.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "diffdrive.md"

COLUMNS = (
    "scenario", "robots", "success", "steps", "duration_s", "max_lateral_m_s", "peak_v", "v_max", "peak_omega",
    "omega_max", "peak_v_dot", "a_max", "peak_omega_dot", "alpha_max", "turn_in_place_steps", "max_tracking_error_m",
    "final_leader_error_m", "min_robot_clearance_m", "wall_s",
)  # fmt: skip


def _row(scenario: str, model: str | None, repeat: int) -> dict[str, object]:
    walls = []
    for _ in range(repeat):
        over = {} if model is None else {"drive": "diff", "robot_model": model}
        problem = build_problem(load_scenario(scenario), overrides=over)
        plan, m = solve(problem, "qp")
        walls.append(plan.wall_time)
    d = m.diff_drive or {}
    return {
        "scenario": scenario,
        "robots": model or "omni",
        "success": plan.success,
        "steps": m.n_steps,
        "duration_s": m.duration,
        "max_lateral_m_s": d.get("max_lateral_velocity", ""),
        "peak_v": d.get("peak_v", ""),
        "v_max": d.get("v_max", ""),
        "peak_omega": d.get("peak_omega", ""),
        "omega_max": d.get("omega_max", ""),
        "peak_v_dot": d.get("peak_linear_acceleration", ""),
        "a_max": d.get("a_max", ""),
        "peak_omega_dot": d.get("peak_angular_acceleration", ""),
        "alpha_max": d.get("alpha_max", ""),
        "turn_in_place_steps": sum(d["turn_in_place_steps"]) if d else "",
        "max_tracking_error_m": m.max_tracking_error,
        "final_leader_error_m": m.final_leader_error,
        "min_robot_clearance_m": m.min_robot_clearance,
        "wall_s": statistics.median(walls),
    }


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1e-3 and v != 0 else f"{v:.4g}"
    return str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--scenarios", default="ABCDE")
    args = ap.parse_args()
    rows = []
    for s in args.scenarios:
        for model in (None, *preset_names()):
            rows.append(_row(s, model, args.repeat))
            print(" ".join(_fmt(rows[-1][c]) for c in COLUMNS), flush=True)
    with OUT.with_suffix(".csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    lines = [
        "# Differential-drive robots on A–E (`benchmarks/diffdrive.py`)",
        "",
        '`--method qp`; `omni` is Caruso 2021\'s omnidirectional chain, the others `drive = "diff"` with that preset',
        "(`formulations/diffdrive.md`). Lateral velocity, v, ω and their rates are the checker's, from the recorded",
        "poses; v̇ and ω̇ from rest. Wall: route, loop and checks in one process, median of "
        f"{args.repeat} run(s), 2-core machine.",
        "",
        "| " + " | ".join(COLUMNS) + " |",
        "|" + "---|" * len(COLUMNS),
    ]
    lines += ["| " + " | ".join(_fmt(r[c]) for c in COLUMNS) + " |" for r in rows]
    lines += [
        "",
        "The same robots on the seeded random rooms, planned with omni and diff on the same inputs "
        "(success, time ratio,",
        "failures): `diffdrive_rooms.md` (`benchmarks/random_rooms.py --drive diff`).",
    ]
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
