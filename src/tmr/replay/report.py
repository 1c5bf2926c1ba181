"""Verdict and outputs of a chain replay: ``replay.json`` (deterministic), ``timing.json`` and the figures.

The verdict lists every failed check with the time it first failed and takes the earliest as the reason:
a contact robot-obstacle, robot-robot, tether-obstacle or tether-floor, a tracking error beyond the tolerance,
or a diverged simulation. ``replay.json`` holds no timings (same run, same bytes); the wall time and real-time
factor go to ``timing.json``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tmr.replay.chain import CONTACT_KINDS, WARMUP, ChainReplay
from tmr.replay.tether import TETHER_RADIUS

__all__ = ["REPLAY_FORMAT", "Verdict", "chain_document", "chain_verdict", "write_chain_outputs"]

REPLAY_FORMAT = "tmr-replay/1"


@dataclass(frozen=True)
class Verdict:
    """ok: the replay confirms the plan; reason: the earliest failed check (None if ok); failures: every failed
    check as (time [s], kind, message), earliest first."""

    ok: bool
    reason: str | None
    failures: tuple[tuple[float, str, str], ...]


def _xyz(p: Any) -> str:
    return "(" + ", ".join(f"{float(v):.2f}" for v in p) + ") m"


def first_over(mask: Any, score: Any) -> tuple[int, int] | None:
    """Where a check first fails: the first sample k with any entry of ``mask`` (K, M) set, and the entry i of the
    largest ``score[k]`` (the one the message names); None if none is set."""
    if not mask.any():
        return None
    k = int(np.argmax(mask.any(axis=1)))
    return k, int(np.argmax(score[k]))


def chain_verdict(rp: ChainReplay, run: Any) -> Verdict:
    """Check the replay against the plan's promises (no contact, no floor touch, tracking within tolerance)."""
    fails: list[tuple[float, str, str]] = []
    d_max = np.asarray(run.record["tether"]["d_max"], dtype=float)
    for kind in CONTACT_KINDS:
        c = rp.contacts[kind]
        if not c["count"]:
            continue
        t0 = float(c["first_time"])
        a, b = c["between"]
        who = f"{a} touches {b}"  # the tether or robot first
        if kind == "tether-floor":
            j = int(a.split()[-1]) - 1
            k = int(np.argmin(np.abs(rp.t - t0)))
            extra = f"; span {rp.span[k, j]:.3f} m, static catenary lowest point {rp.lowest_catenary[k, j]:.3f} m"
            planned = _planned_spans(rp, run)[:, j]
            kp = int(np.argmax(planned))
            if planned[kp] > d_max[j]:
                extra += (
                    f"; the plan's span reaches {planned[kp]:.3f} m > d_max {d_max[j]:.3f} m (by "
                    f"{planned[kp] - d_max[j]:.3f} m) at t = {rp.t[kp]:.2f} s"
                )
            msg = f"tether {j + 1} touches the floor at t = {t0:.2f} s at {_xyz(c['where'])}{extra}"
        else:
            msg = f"{who} at t = {t0:.2f} s at {_xyz(c['where'])} ({c['count']} physics steps in contact, "
            msg += f"deepest {1000 * c['max_depth']:.1f} mm)"
        fails.append((t0, kind, msg))
    gap = getattr(rp, "low_gap", None)
    if gap is not None and (at := first_over(gap < 0.0, -gap)) is not None:  # a cable into a low obstacle
        k, j = at
        fails.append(
            (
                float(rp.t[k]),
                "tether-obstacle",
                f"tether {j + 1} hangs {-gap[k, j]:.3f} m into a low obstacle at t = {rp.t[k]:.2f} s",
            )
        )
    tol = rp.config.tolerance
    if (at := first_over(rp.tracking_error > tol, rp.tracking_error)) is not None:
        k, i = at
        e = float(rp.tracking_error.max())
        msg = (
            f"robot {i + 1} tracking error {rp.tracking_error[k, i]:.3f} m > tolerance {tol:g} m at "
            f"t = {rp.t[k]:.2f} s (largest {e:.3f} m)"
        )
        fails.append((float(rp.t[k]), "tracking", msg))
    if rp.diverged:
        fails.append((float(rp.t[-1]), "diverged", rp.diverged))
    if getattr(rp, "wheels", None) is not None:  # differential-drive robots on wheels (tmr.replay.wheels)
        fails += rp.wheels.failures(rp.t, tol)
    fails.sort(key=lambda f: f[0])
    return Verdict(ok=not fails, reason=fails[0][2] if fails else None, failures=tuple(fails))


def _planned_spans(rp: ChainReplay, run: Any) -> np.ndarray:
    """(K, N) horizontal spans of the tracked plan [m] (tether j from robot j-1, or the anchor, to robot j)."""
    ref = rp.reference
    prev = np.concatenate([np.broadcast_to(run.anchor, (ref.shape[0], 1, 2)), ref[:, :-1]], axis=1)
    return np.linalg.norm(ref - prev, axis=2)


def _f(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return [_f(v) for v in x.tolist()]
    if isinstance(x, (list, tuple)):
        return [_f(v) for v in x]
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


def _head(kind: str, run: Any, verdict: Verdict) -> dict[str, Any]:
    """The first keys of a ``replay.json`` (chain and drone replays): format, kind, the run replayed, the verdict."""
    return {
        "format": REPLAY_FORMAT,
        "kind": kind,
        "run": {
            "path": run.path.name,
            "scenario": run.record["scenario"],
            "method": run.record["method"],
            "plan_success": run.record["success"],
        },
        "verdict": {
            "ok": verdict.ok,
            "reason": verdict.reason,
            "failures": [{"t": t, "check": k, "message": m} for t, k, m in verdict.failures],
        },
    }


def chain_document(rp: ChainReplay, run: Any, verdict: Verdict) -> dict[str, Any]:
    """The ``replay.json`` document (format :data:`REPLAY_FORMAT`; no timings)."""
    cfg = rp.config
    robots = []
    for i in range(rp.actual.shape[1]):
        e = rp.tracking_error[:, i]
        k = int(np.argmax(e))
        robots.append(
            {
                "name": f"robot{i + 1}",
                "tracking_error_max": float(e.max()),
                "tracking_error_rms": float(np.sqrt(np.mean(e**2))),
                "max_at": float(rp.t[k]),
            }
        )
    tethers = []
    for j in range(rp.lowest.shape[1]):
        k = int(np.argmin(rp.lowest[:, j]))
        tethers.append(
            {
                "name": f"tether{j + 1}",
                "winch_on": f"robot{j + 1}",
                "held_by": "anchor" if j == 0 else f"robot{j}",
                "lowest_min": float(rp.lowest[k, j]),
                "lowest_min_at": float(rp.t[k]),
                "lowest_catenary_then": float(rp.lowest_catenary[k, j]),
                "lowest_error_max": float(np.abs(rp.lowest[:, j] - rp.lowest_catenary[:, j]).max()),
                "span_max": float(rp.span[:, j].max()),
                "d_max": float(run.record["tether"]["d_max"][j]),
                "length_error_max": float(np.abs(rp.length[:, j] - rp.length_catenary[:, j]).max()),
                "tension_winch_max": float(rp.tension_winch[:, j].max()),
                "tension_winch_error_max": float(
                    np.abs(rp.tension_winch[:, j] - rp.tension_winch_catenary[:, j]).max()
                ),
                "tension_far_max": float(rp.tension_far[:, j].max()),
                "tension_far_error_max": float(np.abs(rp.tension_far[:, j] - rp.tension_far_catenary[:, j]).max()),
            }
        )
        gap = getattr(rp, "low_gap", None)
        if gap is not None:  # a world with low obstacles: the least height of the cable above one it hangs over
            kg = int(np.argmin(gap[:, j]))
            finite = bool(np.isfinite(gap[kg, j]))
            tethers[-1]["low_obstacle_gap_min"] = float(gap[kg, j]) if finite else None
            tethers[-1]["low_obstacle_gap_at"] = float(rp.t[kg]) if finite else None
    model = asdict(cfg) | {
        "kp": cfg.kp,
        "kv": cfg.kv,
        "tether_radius": TETHER_RADIUS,
        "warmup": WARMUP,
        "integrator": "implicitfast",
    }
    wheels = {} if getattr(rp, "wheels", None) is None else {"wheels": rp.wheels.document(rp.t)}
    return _head("chain", run, verdict) | {
        "model": model,
        "sim_time": rp.sim_time,
        "steps": rp.steps,
        "robots": robots,
        "tethers": tethers,
        **wheels,
        "contacts": rp.contacts,
        "series": {
            "t": rp.t,
            "lowest": rp.lowest,
            "lowest_catenary": rp.lowest_catenary,
            "span": rp.span,
            "length": rp.length,
            "length_catenary": rp.length_catenary,
            "tension_winch": rp.tension_winch,
            "tension_winch_catenary": rp.tension_winch_catenary,
            "tension_far": rp.tension_far,
            "tension_far_catenary": rp.tension_far_catenary,
            "tracking_error": rp.tracking_error,
            "actual": rp.actual,
        },
    }


def _dump(doc: dict[str, Any]) -> str:
    from tmr.io.outputs import _dumps_readable

    return _dumps_readable(_f_tree(doc)) + "\n"


def _f_tree(x: Any) -> Any:
    """JSON-ready: dicts and lists (and the dicts inside lists) walked, arrays to lists, non-finite floats to null."""
    if isinstance(x, dict):
        return {str(k): _f_tree(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_f_tree(v) for v in x]
    return _f(x) if not isinstance(x, (str, bool, type(None), int)) else x


def write_timing(out: Path, rp: Any) -> None:
    """``timing.json``: wall, CPU and simulated time [s] of a chain or MoPICK replay and its real-time factors (kept
    apart from ``replay.json``, which is the same bytes for the same plan)."""
    from tmr.io.outputs import atomic_write_text

    timing = {
        "wall_time": rp.wall_time,
        "cpu_time": rp.cpu_time,
        "sim_time": rp.sim_time,
        "real_time_factor": rp.real_time_factor,
        "cpu_real_time_factor": rp.cpu_real_time_factor,
    }
    atomic_write_text(out / "timing.json", _dump(timing))


def write_chain_outputs(out: Path, rp: ChainReplay, run: Any, verdict: Verdict, plots: bool = True) -> list[str]:
    """Write ``replay.json``, ``timing.json`` and the figures into ``out``; return the file names."""
    from tmr.io.outputs import atomic_write_text

    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "replay.json", _dump(chain_document(rp, run, verdict)))
    write_timing(out, rp)
    names = ["replay.json", "timing.json"]
    if plots:
        from tmr.replay import figures

        names += figures.chain_figures(out, rp, run)
    return sorted(names)


# ----------------------------------------------------------------------------------------------------------
# drone chains (tmr.replay.drones)
# ----------------------------------------------------------------------------------------------------------
def _nanmax(x: np.ndarray) -> float | None:
    return float(np.nanmax(x)) if x.size and np.isfinite(x).any() else None


def _nanmin(x: np.ndarray) -> float | None:
    return float(np.nanmin(x)) if x.size and np.isfinite(x).any() else None


def drone_document(rp: Any, run: Any, verdict: Verdict) -> dict[str, Any]:
    """The ``replay.json`` document of a drone-chain replay (:class:`tmr.replay.drones.DroneReplay`; format
    :data:`REPLAY_FORMAT`, ``kind = "drone"``; no timings). Units: m, N, s; angles in degrees."""
    from tmr.replay.drones import WARMUP

    cfg = rp.config
    built = rp.built
    quad = built.quad if built is not None else None
    drones = []
    for i in range(rp.actual.shape[1]):
        e = rp.tracking_error[:, i]
        k = int(np.argmax(e))
        drones.append(
            {
                "name": f"drone{i + 1}",
                "tracking_error_max": float(e.max()),
                "tracking_error_rms": float(np.sqrt(np.mean(e**2))),
                "max_at": float(rp.t[k]),
                "tilt_max_deg": math.degrees(float(rp.tilt[:, i].max())),
                "rotor_thrust_peak": float(rp.rotor_peak[i]),
                "rotor_thrust_mean": float(rp.rotor_mean[i]),
                "rotor_thrust_limit": float(rp.rotor_limit),
                "saturated_fraction": float(rp.saturation_fraction[i]),
                "first_saturation": rp.first_saturation[i],
                "reference_deviation_max": float(rp.reference_deviation[i]),
                "accel_removed_max": _nanmax(rp.accel_removed[:, i]) if rp.accel_removed.size else None,
                "saturation_run_max": float(rp.saturation_run[i]),
                "saturation_run_at": float(rp.saturation_run_at[i]),
                "thrust_demand_max": _nanmax(rp.thrust_demand[:, i]),
                "reserve_thrust": float(rp.reserve_thrust),
                "reserve_run_max": float(rp.reserve_run[i]),
                "reserve_run_at": float(rp.reserve_run_at[i]),
                "tether_pull_max": _nanmax(rp.pull[:, i]),
                "spare_thrust": float(rp.spare_thrust),
            }
        )
    tethers = []
    for j, (a, b) in enumerate(rp.ends):
        k = int(np.argmin(rp.lowest[:, j]))

        def err(x: np.ndarray, y: np.ndarray) -> float | None:
            d = np.abs(x - y)
            return float(np.nanmax(d)) if np.isfinite(d).any() else None

        tethers.append(
            {
                "name": f"tether{j + 1}",
                "from": "base" if a < 0 else f"drone{a + 1}",
                "to": f"drone{b + 1}",
                "lowest_min": float(rp.lowest[k, j]),
                "lowest_min_at": float(rp.t[k]),
                "lowest_plan_then": float(rp.lowest_plan[k, j]),
                "lowest_catenary_then": float(rp.lowest_catenary[k, j]),
                "lowest_error_max": err(rp.lowest[:, j], rp.lowest_catenary[:, j]),
                "lowest_plan_error_max": err(rp.lowest[:, j], rp.lowest_plan[:, j]),
                "length_max": float(rp.length[:, j].max()),
                "length_error_max": err(rp.length[:, j], rp.length_catenary[:, j]),
                "tension_from_max": float(rp.tension_from[:, j].max()),
                "tension_from_error_max": err(rp.tension_from[:, j], rp.tension_from_catenary[:, j]),
                "tension_from_plan_error_max": err(rp.tension_from[:, j], rp.tension_from_plan[:, j]),
                "tension_to_max": float(rp.tension_to[:, j].max()),
                "tension_to_error_max": err(rp.tension_to[:, j], rp.tension_to_catenary[:, j]),
                "tension_to_plan_error_max": err(rp.tension_to[:, j], rp.tension_to_plan[:, j]),
                "contact_steps": int(rp.tether_contact_steps[j]),
                "sag_max": _nanmax(rp.sag[:, j]),
                "sag_plan_max": _nanmax(rp.sag_plan[:, j]),
                "sag_plan_error_max": err(rp.sag[:, j], rp.sag_plan[:, j]),
                "clearance_min": _nanmin(rp.clearance[:, j]),
                "clearance_plan": float(rp.tether_clearance),
                "tether_length": float(rp.tether_length),
            }
        )
    params = run.tether_params() if hasattr(run, "tether_params") else None
    model = asdict(cfg) | {
        "max_tilt_deg": math.degrees(cfg.max_tilt),
        "tether_radius": TETHER_RADIUS,
        "warmup": WARMUP,
        "integrator": "implicitfast",
        "quadrotor": asdict(quad) if quad is not None else None,
        "rotor_thrust_limit": float(rp.rotor_limit),
        "gains": rp.gains,
        "tether_density_plan": None if params is None else params.mass_per_length,
        "winch_tension": None if params is None else params.winch_tension,
        "winch_end": None if params is None else params.winch_end,
    }
    return _head("drone", run, verdict) | {
        "model": model,
        "sim_time": rp.sim_time,
        "steps": rp.steps,
        "drones": drones,
        "tethers": tethers,
        "contacts": rp.contacts,
        "mujoco_warnings": {"counts": rp.warnings, "messages": rp.warning_messages},
        "series": {
            "t": rp.t,
            "actual": rp.actual,
            "reference": rp.reference,
            "tracking_error": rp.tracking_error,
            "tilt": rp.tilt,
            "rotor_max": rp.rotor_max,
            "lowest": rp.lowest,
            "lowest_catenary": rp.lowest_catenary,
            "lowest_plan": rp.lowest_plan,
            "length": rp.length,
            "length_catenary": rp.length_catenary,
            "tension_from": rp.tension_from,
            "tension_from_catenary": rp.tension_from_catenary,
            "tension_from_plan": rp.tension_from_plan,
            "tension_to": rp.tension_to,
            "tension_to_catenary": rp.tension_to_catenary,
            "tension_to_plan": rp.tension_to_plan,
            "sag": rp.sag,
            "sag_plan": rp.sag_plan,
            "clearance": rp.clearance,
            "tether_pull": rp.pull,
            "thrust_demand": rp.thrust_demand,
        },
    }


def write_drone_outputs(out: Path, rp: Any, run: Any, verdict: Verdict, plots: bool = True) -> list[str]:
    """Write ``replay.json``, ``timing.json`` and the figures of a drone replay into ``out``; return the names."""
    from tmr.io.outputs import atomic_write_text

    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "replay.json", _dump(drone_document(rp, run, verdict)))
    write_timing(out, rp)
    names = ["replay.json", "timing.json"]
    if plots:
        from tmr.replay import figures

        names += figures.drone_figures(out, rp, run)
    return sorted(names)
