"""Differential drives on wheels in the MuJoCo replay (issue 35), and the MoPICK bases' lateral motion.

    python benchmarks/replay_wheels.py [--out DIR]

1. Plans A–E with ``--drive diff --robot-model turtlebot3_burger`` and A, D with the Waffle Pi and the Jackal
   (``python -m tmr.plan --no-plots``), replays each on wheels (``python -m tmr.replay``), and replays the omni plans
   of A and D on Burger and Jackal wheels (``--drive diff --robot-model M``). Per replay: verdict, exit-point and axle
   errors, heading error, peak wheel speed against w_max, clipped time, lateral slip, the plan's sideways demand, the
   lowest tether point, the first failed check.
2. MoPICK (``python -m tmr.mcdpr plan``, the default scene): the bases' lateral motion relative to their headings in
   the plan's samples, in the replay's reference (:class:`tmr.replay.mcdpr._Reference`, smoothed and timed) and in the
   simulated bases (``tmr.replay.mcdpr.replay_mcdpr``: a planar drive force, no wheel constraint).

Writes ``benchmarks/results/replay_wheels.md``. Units: m, s, rad/s, mm, deg.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PY = [sys.executable, "-m"]
DIFF = [("A", "turtlebot3_burger"), ("B", "turtlebot3_burger"), ("C", "turtlebot3_burger")]
DIFF += [("D", "turtlebot3_burger"), ("E", "turtlebot3_burger")]
DIFF += [(s, m) for m in ("turtlebot3_waffle_pi", "clearpath_jackal") for s in ("A", "D")]
OMNI = [(s, m) for s in ("A", "D") for m in ("turtlebot3_burger", "clearpath_jackal")]


def _run(args: list[str]) -> int:
    return subprocess.run([*PY, *args], cwd=ROOT, capture_output=True, text=True).returncode


def _row(doc: dict, code: int) -> str:
    w = doc["wheels"]
    c, R = w["config"], w["robots"]
    v = doc["verdict"]
    return (
        f"| {doc['run']['scenario']} {c['plan_drive']} | {c['robot_model']['name']} | {code} | {doc['sim_time']:.2f} | "
        f"{1000 * max(r['tracking_error_max'] for r in doc['robots']):.2f} | "
        f"{1000 * max(r['axle_error_max'] for r in R):.2f} | "
        f"{math.degrees(max(r['heading_error_max'] for r in R)):.2f} | "
        f"{max(r['wheel_speed_peak'] for r in R):.2f} / {c['wheel_limit']:.2f} | "
        f"{max(r['saturated_time'] for r in R):.2f} | {1000 * max(r['lateral_slip_peak'] for r in R):.2f} | "
        f"{max(r['lateral_demand_max'] for r in R):.3f} | {min(t['lowest_min'] for t in doc['tethers']):.4f} | "
        f"{'' if v['ok'] else v['failures'][0]['check']} |"
    )


def chains(tmp: Path) -> list[str]:
    lines = [
        "| plan | replayed on | exit | sim [s] | exit-point err max [mm] | axle err max [mm] | heading err max [deg] "
        "| wheel speed peak / w_max [rad/s] | clipped [s] | lateral slip max [mm/s] | sideways demand max [m/s] "
        "| lowest tether [m] | first failure |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s, m in DIFF:
        run = tmp / f"{s}_{m}"
        assert (
            _run(["tmr.plan", "--scenario", s, "--drive", "diff", "--robot-model", m, "--out", str(run), "--no-plots"])
            == 0
        )
        code = _run(["tmr.replay", str(run), "--no-plots"])
        lines.append(_row(json.loads((run / "replay" / "replay.json").read_text()), code))
        print(lines[-1], flush=True)
    for s in ("A", "D"):
        run = tmp / f"omni_{s}"
        assert _run(["tmr.plan", "--scenario", s, "--out", str(run), "--no-plots"]) == 0
        for s2, m in OMNI:
            if s2 != s:
                continue
            out = tmp / f"omni_{s}_{m}"
            code = _run(
                ["tmr.replay", str(run), "--drive", "diff", "--robot-model", m, "--out", str(out), "--no-plots"]
            )
            lines.append(_row(json.loads((out / "replay.json").read_text()), code))
            print(lines[-1], flush=True)
    return lines


def mopick(tmp: Path) -> list[str]:
    sys.path.insert(0, str(ROOT / "src"))
    import mujoco

    from tmr.io.rundir import load_run
    from tmr.replay.mcdpr import McdprConfig, _Reference, replay_mcdpr

    out = tmp / "mopick"
    assert _run(["tmr.mcdpr", "plan", "--out", str(out), "--no-plots"]) == 0
    run = load_run(out)
    b, h = np.asarray(run.bases, float), np.unwrap(np.asarray(run.headings, float), axis=0)
    db = np.diff(b, axis=0)
    lat_plan = np.abs(-np.sin(h[1:]) * db[..., 0] + np.cos(h[1:]) * db[..., 1])  # the heading during step k
    path = np.linalg.norm(db, axis=2).sum(axis=0)
    ref = _Reference(run.bases, run.headings, run.platform, run.segment)
    ts = np.arange(0.0, ref.T, 0.005)
    lat_r, spd_r = [], []
    for t in ts:
        _, bv, _, hh, *_ = ref(t)
        lat_r.append(np.abs(-np.sin(hh) * bv[:, 0] + np.cos(hh) * bv[:, 1]))
        spd_r.append(np.linalg.norm(bv, axis=1))
    lat_r, spd_r = np.array(lat_r), np.array(spd_r)
    rp = replay_mcdpr(run, McdprConfig())
    m = rp.model
    Q = np.array(rp.qpos)
    dt = float(np.diff(rp.t).mean())
    lat_s, spd_s = [], []
    for j in range(m.njnt):
        if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE:
            continue
        a = m.jnt_qposadr[j]
        qw, qx, qy, qz = (Q[:, a + k] for k in range(3, 7))
        yaw = np.unwrap(np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz)))
        v = np.diff(Q[:, a : a + 2], axis=0) / dt
        ym = 0.5 * (yaw[1:] + yaw[:-1])
        lat_s.append(np.abs(-np.sin(ym) * v[:, 0] + np.cos(ym) * v[:, 1]))
        spd_s.append(np.linalg.norm(v, axis=1))
    lat_s, spd_s = np.array(lat_s).T, np.array(spd_s).T
    lines = [
        f"MoPICK default scene, replay verdict ok = {rp.verdict.ok}.",
        "",
        "| base | plan: max lateral step [m] | plan: path [m] | reference: max lateral [m/s] "
        "| reference: ∫lateral / ∫speed | replay: max lateral [m/s] | replay: max speed [m/s] "
        "| replay: ∫lateral / ∫speed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for j in range(b.shape[1]):
        lines.append(
            f"| {j + 1} | {lat_plan[:, j].max():.1e} | {path[j]:.3f} | {lat_r[:, j].max():.4f} | "
            f"{lat_r[:, j].sum() / spd_r[:, j].sum():.4f} | {lat_s[:, j].max():.4f} | {spd_s[:, j].max():.4f} | "
            f"{lat_s[:, j].sum() / spd_s[:, j].sum():.4f} |"
        )
    print("\n".join(lines), flush=True)
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="keep the run directories here (default: a temporary directory)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as td:
        tmp = args.out or Path(td)
        tmp.mkdir(parents=True, exist_ok=True)
        text = ["# Differential drives on wheels in the MuJoCo replay", "", "`python benchmarks/replay_wheels.py`", ""]
        text += chains(tmp) + ["", "## MoPICK: lateral motion of the bases", ""] + mopick(tmp)
    res = ROOT / "benchmarks" / "results" / "replay_wheels.md"
    res.write_text("\n".join(text) + "\n", encoding="utf-8")
    print(f"wrote {res}")


if __name__ == "__main__":
    main()
