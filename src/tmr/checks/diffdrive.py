"""Checks of a differential-drive plan from its recorded poses alone (independent of the planner's QP rows; math in
``formulations/diffdrive.md``).

From the axle centres c_k (K+1, N, 2) [m], the continuous headings θ_k (K+1, N) [rad], the exit points p_k the chain
recorded and the robot model (recorded in the plan's parameters, ``robot_model_params``), per step k and robot:

- ω_k = (θ_{k+1} − θ_k) / Ts, lateral_k = Δc·e_⊥(θ_m) / Ts and v_k = Δc·e(θ_m) / (Ts sinc(Δθ / 2)) with θ_m the mid
  heading (:func:`tmr.model.diffdrive.step_velocities`: any unicycle arc has lateral_k = 0; a sideways slip does not);
- the accelerations (v_k − v_{k−1}) / Ts and (ω_k − ω_{k−1}) / Ts, from rest (v_{−1} = ω_{−1} = 0);
- the exit point's offset |p_k − c_k − b e(θ_k)|.

Violation kinds (:data:`DIFF_KINDS`, reported by :func:`tmr.checks.metrics.evaluate` for a plan with headings): a
lateral velocity above :data:`LATERAL_TOLERANCE`, |v| > v_max, |ω| > ω_max, a wheel rim |v ± ω L/2| > v_max (with
a track L), |v̇| > a_max, |ω̇| > α_max (each beyond a relative :data:`RELATIVE_TOLERANCE`), an exit point off its pose
by more than :data:`EXIT_TOLERANCE`. A step's violation is reported at its sample k.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tmr.model.diffdrive import MODEL_FIELDS, exit_point, step_velocities

__all__ = [
    "DIFF_KINDS",
    "EXIT_TOLERANCE",
    "HEADING_TOLERANCE_DEG",
    "LATERAL_TOLERANCE",
    "RELATIVE_TOLERANCE",
    "diff_drive_check",
    "heading_error",
]


def heading_error(theta: float, goal: float) -> float:
    """|θ − Θ| wrapped to [0, π] [rad]: the turn left between a heading θ and a goal heading Θ [rad]."""
    return abs(math.remainder(float(theta) - float(goal), 2.0 * math.pi))


#: Violation kinds of a differential-drive plan, in report order.
DIFF_KINDS = (
    "lateral_velocity",
    "linear_speed",
    "angular_speed",
    "wheel_speed",
    "linear_acceleration",
    "angular_acceleration",
    "exit_point",
)
#: Largest lateral velocity of an axle centre accepted [m/s] (rounding of the recorded poses: ~1e-14).
LATERAL_TOLERANCE = 1e-9
#: Relative slack on the v, ω and acceleration bounds (rounding of v, ω recovered from poses).
RELATIVE_TOLERANCE = 1e-9
#: Largest distance [m] of a recorded exit point from c + b e(θ).
EXIT_TOLERANCE = 1e-9
#: Largest accepted error of the leader's final heading against a goal heading (``--goal X,Y,THETA``) [deg].
HEADING_TOLERANCE_DEG = 1.0
#: A robot turns in place where |v| < 1e-3 m/s and |ω| > 0.05 rad/s (as :data:`tmr.control.diffdrive.TURN_IN_PLACE`).
TURN_IN_PLACE = (1e-3, 0.05)


def _model(plan: Any) -> dict[str, float] | None:
    rec = (getattr(plan, "params", None) or {}).get("robot_model_params")
    if not isinstance(rec, dict) or any(k not in rec for k in MODEL_FIELDS):
        return None
    out = {k: float(rec[k]) for k in MODEL_FIELDS}
    if rec.get("track") is not None:  # the wheels' rim speeds |v ± ω L/2| ≤ v_max are checked too
        out["track"] = float(rec["track"])
    return out


def diff_drive_check(plan: Any, Ts: float) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
    """Per sample (K+1,) bool masks of :data:`DIFF_KINDS` and a summary dict (JSON-ready) of a plan with recorded
    poses (``plan.axle``, ``plan.heading``, ``plan.robots`` the exit points) and a robot model in
    ``plan.params["robot_model_params"]``; None for a plan without headings (omnidirectional). Ts [s]."""
    heading = getattr(plan, "heading", None)
    axle = getattr(plan, "axle", None)
    if heading is None or axle is None:
        return None
    model = _model(plan)
    if model is None:
        raise ValueError("a plan with headings needs its robot model in params['robot_model_params']")
    th = np.asarray(heading, dtype=float)
    c = np.asarray(axle, dtype=float)
    p = np.asarray(plan.robots, dtype=float)
    K1, N = th.shape
    masks = {kind: np.zeros(K1, dtype=bool) for kind in DIFF_KINDS}
    exit_err = np.linalg.norm(p - exit_point(c, th, model["exit_offset"]), axis=-1)
    masks["exit_point"] = (exit_err > EXIT_TOLERANCE).any(axis=1)
    summary: dict[str, Any] = {"max_exit_point_error": float(exit_err.max()) if exit_err.size else 0.0}
    goal_heading = (getattr(plan, "params", None) or {}).get("goal_heading")
    if goal_heading is not None:  # --goal X,Y,THETA: the leader's final heading against THETA (plan.check judges it)
        summary.update(
            goal_heading=float(goal_heading),
            final_heading_error=heading_error(th[-1, -1], goal_heading),
            heading_tolerance_deg=HEADING_TOLERANCE_DEG,
        )
    if K1 < 2 or not math.isfinite(Ts) or Ts <= 0:
        summary.update(max_lateral_velocity=0.0, peak_v=0.0, peak_omega=0.0)
        return masks, summary
    v, w, lat = step_velocities(c, th, Ts)
    zero = np.zeros((1, N))
    dv = np.diff(np.vstack([zero, v]), axis=0) / Ts
    dw = np.diff(np.vstack([zero, w]), axis=0) / Ts
    slack = 1.0 + RELATIVE_TOLERANCE
    steps = {
        "lateral_velocity": np.abs(lat) > LATERAL_TOLERANCE,
        "linear_speed": np.abs(v) > model["v_max"] * slack,
        "angular_speed": np.abs(w) > model["omega_max"] * slack,
        "wheel_speed": np.abs(v) + np.abs(w) * 0.5 * model.get("track", 0.0) > model["v_max"] * slack,
        "linear_acceleration": np.abs(dv) > model["a_max"] * slack,
        "angular_acceleration": np.abs(dw) > model["alpha_max"] * slack,
    }
    for kind, bad in steps.items():
        masks[kind][:-1] = bad.any(axis=1)
    turning = (np.abs(v) < TURN_IN_PLACE[0]) & (np.abs(w) > TURN_IN_PLACE[1])
    summary.update(
        max_lateral_velocity=float(np.abs(lat).max()),
        peak_v=float(np.abs(v).max()),
        peak_omega=float(np.abs(w).max()),
        peak_wheel_rim_speed=float((np.abs(v) + np.abs(w) * 0.5 * model.get("track", 0.0)).max()),
        peak_linear_acceleration=float(np.abs(dv).max()),
        peak_angular_acceleration=float(np.abs(dw).max()),
        turn_in_place_steps=[int(n) for n in turning.sum(axis=0)],
        v_max=model["v_max"],
        omega_max=model["omega_max"],
        a_max=model["a_max"],
        alpha_max=model["alpha_max"],
    )
    return masks, summary
