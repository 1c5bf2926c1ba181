"""Performance metrics of a tethered-chain plan (Caruso 2021 §4.2.2, eq. 24–27, and §5, Figs. 5–8).

Everything here reads a plan through the fields of :class:`tmr.control.clik.Plan` only (duck typing): ``t`` (K+1,)
[s], ``q``/``qdot`` (K+1, n), ``robots`` (K+1, N, 2) [m], ``base`` (2,) [m], ``reference`` (K+1, 2) [m],
``spans`` (K+1, N) [m], ``span_limits`` ((d_lo, d_max) or (N, 2)) [m], ``safety_radius`` [m], ``success``,
``failure``, ``wall_time`` [s], and optionally ``goal`` (2,) [m] and ``diagnostics`` (per-step arrays; the lexicographic
QP's level status ``qp_level:<name>`` and ``fallback_solves`` are counted).
The environment is read through ``exact_clearance(points (..., 2))`` and ``segment_clearance(a, b)`` (signed
distances to the inflated obstacles, metres: > 0 free, < 0 inside), as :class:`tmr.world.environment.Environment`
provides.

**Low obstacles** (``env.low_obstacles``, :class:`tmr.world.environment.LowObstacle`): the robots are checked against
the whole environment, the tethers' plan-view chords against ``env.tether_environment`` (the room without the low
obstacles), and every chord that crosses a low obstacle's bare footprint is checked in the vertical plane
(:func:`low_obstacle_margins`): the closed-form catenary (:func:`tmr.model.catenary.solve`) at that step's
horizontal tension must stay ``low_obstacle_clearance`` above the obstacle's height over the whole crossing (kind
``low_obstacle``; none of the planner's rows is reused). A plan with an active winch records its tensions
``winch_tension`` (K+1, N) [N]; then the span check ``span_max`` asks the catenary of that step's tension for its
lowest point (≥ ``ground_clearance``) instead of the constant d_max. Without low obstacles and winch tensions
nothing of the above runs and metrics.json keeps its keys.

Indexing: step ``k`` is the sample at ``t[k]``; a plan with K+1 samples has K steps. Robot N (last) is the
leader (the manipulator's end-effector x_e); tether j joins point j-1 to robot j, point 0 being the base.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, NamedTuple

import numpy as np

from tmr.checks.diffdrive import DIFF_KINDS, diff_drive_check
from tmr.checks.lowpass import butter_lowpass, filtfilt
from tmr.errors import ParameterError

__all__ = [
    "QP_LEVEL_STATUS",
    "VIOLATION_KINDS",
    "Clearances",
    "Metrics",
    "chain_points",
    "clearances",
    "distance_errors",
    "evaluate",
    "filter_trajectories",
    "filter_within_limits",
    "fitness",
    "json_safe",
    "limit_breaks",
    "low_obstacle_margins",
    "plan_goal",
    "qp_level_counts",
    "robot_separations",
    "robot_speeds",
    "sample_time",
    "span_limits",
]

#: Status of a level of the lexicographic QP at a step, by code: ``plan.diagnostics["qp_level:<name>"]`` holds the
#: code per step (the same tuple as :data:`tmr.control.qp.LEVEL_STATUS`, not imported here: metrics read plans).
QP_LEVEL_STATUS: tuple[str, ...] = ("solved", "relaxed", "implied", "failed", "skipped", "empty")
#: Prefix of those diagnostics keys.
QP_LEVEL_PREFIX = "qp_level:"

#: Names of the violation kinds reported by :func:`evaluate`, in report order.
VIOLATION_KINDS: tuple[str, ...] = (
    "robot_clearance",
    "tether_clearance",
    "span_max",
    "span_min",
    "separation",
)
#: Violation kind of a cable lower than a low obstacle's height plus ``low_obstacle_clearance`` over its footprint;
#: reported after :data:`VIOLATION_KINDS` only for a world with low obstacles.
LOW_OBSTACLE_KIND = "low_obstacle"
#: Largest spacing [m] of the catenary samples over a low obstacle's footprint (the crossing's ends are samples too).
LOW_OBSTACLE_STEP = 0.01
#: Default height [m] a cable keeps above a low obstacle (``ChainParams.low_obstacle_clearance``; not imported here:
#: metrics read plans).
LOW_OBSTACLE_CLEARANCE = 0.05


# ----------------------------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------------------------
def sample_time(t: np.ndarray, default: float = math.nan) -> float:
    """Sample time Ts [s] of a time vector ``t`` (K+1,): (t[K] − t[0]) / K (exact for a uniform grid, the mean
    step otherwise), or ``default`` if t has fewer than 2 samples."""
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return float(default)
    return float((t[-1] - t[0]) / (t.size - 1))


def _plan_ts(plan: Any, Ts: float | None) -> float:
    if Ts is None:
        params = getattr(plan, "params", None) or {}
        Ts = sample_time(plan.t, default=float(params.get("Ts", math.nan)))
    Ts = float(Ts)
    if not math.isfinite(Ts) or Ts <= 0.0:
        raise ParameterError(
            f"sample time Ts must be a positive finite number of seconds, got {Ts!r}; pass Ts explicitly "
            "or give the plan at least two time samples"
        )
    return Ts


def span_limits(plan: Any) -> tuple[np.ndarray, np.ndarray]:
    """Per-tether span limits ``(d_lo (N,), d_max (N,))`` [m] from ``plan.span_limits``.

    ``plan.span_limits`` is either one pair ``(d_lo, d_max)`` shared by all tethers or an (N, 2) array.
    """
    n = np.asarray(plan.robots).shape[1]
    lim = np.asarray(plan.span_limits, dtype=float)
    if lim.shape == (2,):
        lim = np.broadcast_to(lim, (n, 2))
    if lim.shape != (n, 2):
        raise ParameterError(
            f"plan.span_limits must be (d_lo, d_max) or an ({n}, 2) array for {n} tethers, got shape {lim.shape}"
        )
    return lim[:, 0].copy(), lim[:, 1].copy()


def plan_goal(plan: Any, goal: Any = None) -> np.ndarray:
    """Leader goal (2,) [m]: ``goal`` if given, else ``plan.goal`` if set, else the end of
    ``plan.reference``."""
    if goal is None:
        goal = getattr(plan, "goal", None)
    if goal is None:
        goal = np.asarray(plan.reference, dtype=float)[-1]
    return np.asarray(goal, dtype=float)[:2].copy()


def chain_points(plan: Any, robots: np.ndarray | None = None) -> np.ndarray:
    """Polyline of the chain at every sample: base then robots 1..N, shape (K+1, N+1, 2) [m]; the robots at
    ``robots`` (K+1, N, 2) [m] if given (e.g. filtered positions), else at ``plan.robots``."""
    robots = np.asarray(plan.robots if robots is None else robots, dtype=float)
    base = np.broadcast_to(np.asarray(plan.base, dtype=float)[:2], (robots.shape[0], 1, 2))
    return np.concatenate([base, robots], axis=1)


def robot_speeds(robots: np.ndarray, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Robot speeds and accelerations by finite differences of positions.

    Args:
        robots: (K+1, N, 2) positions [m].
        Ts: sample time [s].

    Returns:
        ``(speed (K, N) [m/s], accel (K-1, N) [m/s^2])``: speed[k] = ‖p[k+1] − p[k]‖/Ts (the velocity held on
        [t_k, t_k+1]), accel[k] = ‖v[k+1] − v[k]‖/Ts with v the forward-difference velocity vectors.
    """
    robots = np.asarray(robots, dtype=float)
    vel = np.diff(robots, axis=0) / Ts
    acc = np.diff(vel, axis=0) / Ts
    return np.linalg.norm(vel, axis=-1), np.linalg.norm(acc, axis=-1)


def robot_separations(robots: np.ndarray) -> np.ndarray:
    """Distances between every pair of robots i < j at every sample, shape (K+1, N(N-1)/2) [m]."""
    robots = np.asarray(robots, dtype=float)
    i, j = np.triu_indices(robots.shape[1], k=1)
    return np.linalg.norm(robots[:, i, :] - robots[:, j, :], axis=-1)


def distance_errors(plan: Any) -> np.ndarray:
    """Distance errors of Caruso 2021 Fig. 7: span_i(t) − mean_j span_j(t), shape (K+1, N) [m]."""
    spans = np.asarray(plan.spans, dtype=float)
    return spans - spans.mean(axis=1, keepdims=True)


# ----------------------------------------------------------------------------------------------------------
# fitness functions
# ----------------------------------------------------------------------------------------------------------
def fitness(plan: Any, Ts: float | None = None, *, penalize: bool = True) -> tuple[float, float, float, float]:
    """Fitness functions f1..f4 of Caruso 2021 eq. 24–27 (all to be minimised).

    With samples k = 0..K at t = k Ts:

    - ``f1 = Σ_{k=0..K} q̇_kᵀ q̇_k`` (eq. 24, "energy" of the equivalent manipulator's motors). Mixed units:
      rad²/s² for the revolute joints plus m²/s² for the prismatic ones (the paper quotes it in J).
    - ``f2 = Σ_{k=0..K} Σ_{i<j} (d_i − d_j)²`` [m²] with d_i the horizontal span of tether i (= the prismatic
      joint q_2i). Eq. 25 is written for N = 3 as (d1−d2)² + (d2−d3)² + (d3−d1)², which is exactly the sum
      over all pairs i < j; the all-pairs sum is the generalisation to N tethers (N = 1: f2 = 0; N = 2: one
      pair).
    - ``f3 = Σ_{k=1..K} ‖x_e,k − x_d,k‖²`` [m²] (eq. 26), x_e = position of the last robot (leader),
      x_d = ``plan.reference``.
    - ``f4 = Σ_{k=1..K} q̈_kᵀ q̈_k`` with ``q̈_k = (q̇_k − q̇_{k−1}) / Ts`` (eq. 27; mixed units rad²/s⁴ +
      m²/s⁴).

    Blind penalty (Caruso 2021 §4.2.2): if ``plan.success`` is False every f_i is ``+inf`` (unless
    ``penalize=False``, which gives the values of the recorded motion, e.g. to compare failed baselines).

    Args:
        plan: a :class:`tmr.control.clik.Plan` (fields ``qdot``, ``spans``, ``robots``, ``reference``, ``t``,
            ``success``).
        Ts: sample time [s]; default: from ``plan.t`` (see :func:`sample_time`).

    Returns:
        ``(f1, f2, f3, f4)`` as Python floats.
    """
    if penalize and not plan.success:
        return (math.inf, math.inf, math.inf, math.inf)
    Ts = _plan_ts(plan, Ts)
    qdot = np.asarray(plan.qdot, dtype=float)
    f1 = float(np.sum(qdot * qdot))
    spans = np.asarray(plan.spans, dtype=float)
    i, j = np.triu_indices(spans.shape[1], k=1)
    f2 = float(np.sum((spans[:, i] - spans[:, j]) ** 2))
    err = np.asarray(plan.robots, dtype=float)[1:, -1, :] - np.asarray(plan.reference, dtype=float)[1:, :2]
    f3 = float(np.sum(err * err))
    qddot = np.diff(qdot, axis=0) / Ts
    f4 = float(np.sum(qddot * qddot))
    return (f1, f2, f3, f4)


# ----------------------------------------------------------------------------------------------------------
# clearances
# ----------------------------------------------------------------------------------------------------------
class Clearances(NamedTuple):
    """Exact signed clearances to the inflated obstacles [m] (> 0 free, < 0 inside)."""

    robots: np.ndarray  #: (K+1, N) clearance of robot i's centre at sample k
    tethers: np.ndarray  #: (K+1, N) clearance of tether segment j (point j-1 → robot j, point 0 = base)


def clearances(plan: Any, env: Any) -> Clearances:
    """Exact clearance of every robot and every tether segment at every sample.

    One vectorised call to ``env.exact_clearance`` for all (K+1)·N robot centres and one to
    ``env.segment_clearance`` for all (K+1)·N tether segments. Tethers are taken as straight segments in the
    horizontal plane (their top view, as in Caruso 2021 Fig. 5). Distances are to the *inflated* obstacles, so
    the robot body (radius = safety radius) touches a raw obstacle when its clearance is 0.

    Returns:
        :class:`Clearances` with ``robots`` and ``tethers`` arrays of shape (K+1, N) [m].
    """
    return _chain_clearances(chain_points(plan), env)


def _chain_clearances(pts: np.ndarray, env: Any) -> Clearances:
    """:class:`Clearances` of chain polylines ``pts`` (K+1, N+1, 2) [m] (base first): robots against ``env``, tether
    chords against ``env.tether_environment`` (without the low obstacles a tether may pass over; ``env`` itself when
    it has none or no such attribute)."""
    robot_c = np.asarray(env.exact_clearance(pts[:, 1:, :]), dtype=float).reshape(pts.shape[0], -1)
    tenv = getattr(env, "tether_environment", env)
    tether_c = np.asarray(tenv.segment_clearance(pts[:, :-1, :], pts[:, 1:, :]), dtype=float).reshape(pts.shape[0], -1)
    return Clearances(robots=robot_c, tethers=tether_c)


def _violation_masks(
    clr: Clearances,
    spans: np.ndarray,
    sep: np.ndarray,
    limits: tuple[np.ndarray, np.ndarray],
    r: float,
    tol: float,
    span_high: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Per sample (K+1,) bool, for each of :data:`VIOLATION_KINDS`: whether that hard limit is broken beyond ``tol``
    [m] (clearances < −tol, spans outside [d_lo − tol, d_max + tol], separations < 2 r − tol). ``span_high`` (K+1, N)
    bool, if given, replaces the d_max test (:func:`_winch_span_high`)."""
    d_lo, d_max = limits
    high = (spans > d_max + tol) if span_high is None else span_high
    return {
        "robot_clearance": (clr.robots < -tol).any(axis=1),
        "tether_clearance": (clr.tethers < -tol).any(axis=1),
        "span_max": high.any(axis=1),
        "span_min": (spans < d_lo - tol).any(axis=1),
        "separation": (sep < 2.0 * r - tol).any(axis=1) if sep.size else np.zeros(spans.shape[0], dtype=bool),
    }


# ----------------------------------------------------------------------------------------------------------
# the cable in the vertical plane: active winch tensions, low obstacles
# ----------------------------------------------------------------------------------------------------------
def _winch_tension(plan: Any, shape: tuple[int, int]) -> np.ndarray | None:
    """``plan.winch_tension`` (K+1, N) [N] of an active-winch plan, or None (constant tension T0)."""
    wt = getattr(plan, "winch_tension", None)
    if wt is None:
        return None
    wt = np.asarray(wt, dtype=float)
    if wt.shape != shape or not np.all(np.isfinite(wt)) or np.any(wt <= 0.0):
        raise ParameterError(
            f"plan.winch_tension must be positive finite horizontal tensions [N] of shape {shape}, got shape {wt.shape}"
        )
    return wt


def _tether_params(plan: Any) -> dict[str, float]:
    """Tether parameters from the plan's recorded ``params`` (defaults: Caruso 2021 §4.2.1, ChainParams'):
    ``T0`` [N], ``rho`` [kg/m], ``H`` exit height, ``Hb`` anchor height, ``ground`` clearance, ``low`` clearance [m]."""
    p = getattr(plan, "params", None) or {}
    return {
        "T0": float(p.get("pulley_torque", 1.35)) / float(p.get("pulley_radius", 0.1)),
        "rho": float(p.get("cable_mass_per_length", 0.15)),
        "H": float(p.get("exit_height", 0.43)),
        "Hb": float(p.get("base_height", 0.43)),
        "ground": float(p.get("ground_clearance", 0.0)),
        "low": float(p.get("low_obstacle_clearance", LOW_OBSTACLE_CLEARANCE)),
    }


def _catenary_params(tp: dict[str, float], tension: float) -> Any:
    from tmr.model.catenary import CatenaryParams

    return CatenaryParams(
        horizontal_tension=float(tension),
        mass_per_length=tp["rho"],
        end_height=tp["H"],
        base_height=tp["Hb"],
        ground_clearance=tp["ground"],
    )


def _winch_span_high(plan: Any, spans: np.ndarray, tension: np.ndarray, tol: float) -> np.ndarray:
    """(K+1, N) bool: the span of tether j at step k is too long for that step's winch tension ``tension[k, j]`` [N]:
    the catenary's lowest point (:func:`tmr.model.catenary.lowest_height`, h1 = anchor height for tether 1, else the
    exit height; h2 = the exit height) lies below ``ground_clearance`` − ``tol``. Replaces span ≤ d_max (d_max is the
    span where that happens at the constant tension T0)."""
    from tmr.model.catenary import lowest_height

    tp = _tether_params(plan)
    h1 = np.where(np.arange(spans.shape[1]) == 0, tp["Hb"], tp["H"])
    h1 = np.broadcast_to(h1, spans.shape)
    low = lowest_height(h1, tp["H"], np.maximum(spans, 0.0), _catenary_params(tp, tp["T0"]), tension=tension)
    return np.asarray(low) < tp["ground"] - tol


#: An active winch's checks: its tension within [winch_tension_min, winch_tension_max] at every sample, and changing
#: by at most winch_tension_rate · Ts from one sample to the next (reported at the later sample).
WINCH_KINDS = ("winch_range", "winch_rate")


def _winch_masks(plan: Any, tension: np.ndarray, Ts: float, tol: float) -> dict[str, np.ndarray]:
    """Per sample (K+1,), whether the winch tensions ``tension`` (K+1, N) [N] leave the recorded range or change
    faster than the recorded rate (``plan.params``: ``winch_tension_min``, ``winch_tension_max`` [N],
    ``winch_tension_rate`` [N/s], as every active-winch plan of tmr records them), with ``tol`` [N] of slack. A bound
    the plan does not record is not judged."""
    p = getattr(plan, "params", None) or {}
    lo = float(p.get("winch_tension_min", -np.inf))
    hi = float(p.get("winch_tension_max", np.inf))
    rate = float(p.get("winch_tension_rate", np.inf))
    out_range = ((tension < lo - tol) | (tension > hi + tol)).any(axis=1)
    jump = np.zeros(tension.shape[0], dtype=bool)
    if tension.shape[0] > 1:
        jump[1:] = (np.abs(np.diff(tension, axis=0)) > rate * Ts + tol).any(axis=1)
    return {"winch_range": out_range, "winch_rate": jump}


def _winch_reach(plan: Any, tension: np.ndarray) -> np.ndarray:
    """(K+1, N) d_max [m] of every tether at every step's winch tension ``tension`` [N]
    (:func:`tmr.model.catenary.max_span`, one solve per distinct tension and end height)."""
    from tmr.model.catenary import max_span

    tp = _tether_params(plan)
    out = np.empty(tension.shape)
    for j in range(tension.shape[1]):
        h1 = tp["Hb"] if j == 0 else tp["H"]
        values, where = np.unique(tension[:, j], return_inverse=True)
        out[:, j] = np.array([max_span(h1, tp["H"], _catenary_params(tp, T)) for T in values])[where]
    return out


def low_obstacle_margins(plan: Any, env: Any, robots: np.ndarray | None = None) -> np.ndarray:
    """Height margin [m] of every tether over the low obstacles it crosses, shape (K+1, N): min over the obstacles
    o whose bare footprint the plan-view chord of tether j at step k meets of min_s (z(s) − height_o −
    ``low_obstacle_clearance``), +inf where the chord crosses none.

    z(s) is the closed-form catenary (:func:`tmr.model.catenary.solve`; end 1 at point j−1 at the anchor height for
    tether 1, else the exit height; end 2 at robot j at the exit height) with that step's horizontal tension:
    ``plan.winch_tension[k, j]`` for an active-winch plan, else T0 = pulley torque / pulley radius (the plan's
    ``params``). s runs over the crossing (shapely intersection of the chord with the footprint), sampled at most
    :data:`LOW_OBSTACLE_STEP` apart, both ends of every crossing piece included. ``robots`` (K+1, N, 2) [m]
    replaces ``plan.robots`` (e.g. filtered positions).
    """
    import shapely

    from tmr.model.catenary import solve

    pts = chain_points(plan, robots)
    n_s, n = pts.shape[0], pts.shape[1] - 1
    out = np.full((n_s, n), np.inf)
    lows = getattr(env, "low_obstacles", ())
    if not lows:
        return out
    tp = _tether_params(plan)
    tension = _winch_tension(plan, (n_s, n))
    A = pts[:, :-1].reshape(-1, 2)
    B = pts[:, 1:].reshape(-1, 2)
    span = np.hypot(*(B - A).T)
    lines = shapely.linestrings(np.stack([A, B], axis=1))
    for low in lows:
        fp = low.footprint
        hit = np.flatnonzero(shapely.intersects(lines, fp))
        for m, cross in zip(hit.tolist(), shapely.intersection(lines[hit], fp), strict=True):
            k, j = divmod(m, n)
            d = span[m]
            u = (B[m] - A[m]) / d if d > 0 else np.zeros(2)
            s_all: list[np.ndarray] = []
            for part in shapely.get_parts(cross):
                s_part = (shapely.get_coordinates(part) - A[m]) @ u
                lo, hi = float(s_part.min()), float(s_part.max())
                s_all.append(np.linspace(lo, hi, max(2, math.ceil((hi - lo) / LOW_OBSTACLE_STEP) + 1)))
            s = np.clip(np.concatenate(s_all), 0.0, d)
            h1 = tp["Hb"] if j == 0 else tp["H"]
            if d <= 0.0:  # robot on the anchor/its neighbour: the cable hangs at its ends
                z = np.array([min(h1, tp["H"])])
            else:
                T = tp["T0"] if tension is None else tension[k, j]
                cat = solve(h1, tp["H"], d, _catenary_params(tp, T))
                z = cat.z_low + cat.c * 2.0 * np.sinh(0.5 * (s - cat.x_low) / cat.c) ** 2
            out[k, j] = min(out[k, j], float(z.min()) - low.height - tp["low"])
    return out


# ----------------------------------------------------------------------------------------------------------
# Metrics
# ----------------------------------------------------------------------------------------------------------
def json_safe(value: Any) -> Any:
    """Convert ``value`` to plain JSON types, recursively.

    numpy scalars/arrays become Python floats/ints/bools/lists; tuples become lists; non-finite floats become
    the strings ``"inf"``, ``"-inf"`` and ``"nan"`` (JSON has no infinity; ``float("inf")`` parses the string
    back, and a string keeps "infinitely bad" distinct from ``null`` = "not available").
    """
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return v
    return value


@dataclass
class Metrics:
    """Summary of one plan. Lengths in m, times in s, speeds in m/s, accelerations in m/s²; steps are sample
    indices k (time t[k]). Values that cannot be computed (e.g. separation with one robot) are ``inf`` for
    minima and 0 for maxima over an empty set; see :func:`evaluate`."""

    scenario: str
    method: str
    success: bool
    failure: str | None
    n_robots: int
    n_steps: int  #: K (number of steps actually done; samples = K + 1)
    Ts: float  #: sample time [s]
    duration: float  #: t[K] − t[0] [s]
    # Caruso 2021 eq. 24–27 (+inf on failure)
    f1: float
    f2: float
    f3: float
    f4: float
    #: eq. 24–27 of the recorded motion without the failure penalty (to compare failed plans)
    fitness_raw: list[float]
    # clearances to the inflated obstacles [m]
    min_robot_clearance: float
    min_robot_clearance_step: int | None
    min_tether_clearance: float
    min_tether_clearance_step: int | None
    # tether spans [m]
    max_span: float
    d_max: float  #: limit of the tether that reaches the largest span / d_max (all equal for a shared limit)
    max_span_ratio: float  #: max over k, i of span_i / d_max_i (an active winch: d_max of step k's tension)
    min_span: float
    d_lo: float  #: limit of the tether that comes closest to (or furthest below) its d_lo
    # robots
    min_separation: float  #: min over all pairs i < j and all samples of the robot–robot distance [m]
    separation_limit: float  #: 2 × safety radius [m]
    peak_speed: float  #: max over robots and steps [m/s]
    peak_speed_per_robot: list[float]
    peak_acceleration: float  #: [m/s²]
    peak_acceleration_per_robot: list[float]
    final_speed: float  #: max over robots of the speed over the last step [m/s] (≈ 0: the plan ends at rest)
    # distance errors of Fig. 7 (span_i − mean span) [m]
    max_abs_distance_error: float
    max_abs_distance_error_per_tether: list[float]
    # tracking of the leader reference [m]
    final_leader_error: float  #: ‖x_e(T) − goal‖
    max_tracking_error: float  #: max_k ‖x_e,k − x_d,k‖
    rms_tracking_error: float
    # violations (with tolerance ``tolerance``)
    tolerance: float
    n_violation_steps: int  #: number of samples with at least one violation of any kind
    violation_steps: dict[str, list[int]] = field(default_factory=dict)  #: kind -> samples with that violation
    first_violation: dict[str, int | None] = field(default_factory=dict)  #: kind -> first sample or None
    # timing
    wall_time: float = math.nan  #: planner wall time [s]
    ms_per_step: float = math.nan  #: wall_time / K [ms]
    # lexicographic QP (``--method qp``; empty for the other methods), see :func:`qp_level_counts`
    #: per level name, the number of steps at which it was solved / relaxed / implied / failed / skipped / empty
    qp_levels: dict[str, dict[str, int]] = field(default_factory=dict)
    qp_fallback_solves: int = 0  #: level solves done by a fallback backend (the primary failed or was not verified)
    #: low obstacles only (None otherwise, and then not written): the worst height margin [m] of a cable over a low
    #: obstacle, min over steps, tethers and obstacles of z − height − low_obstacle_clearance (+inf: no chord
    #: crosses one), see :func:`low_obstacle_margins`; and its sample k
    low_obstacle_margin: float | None = None
    low_obstacle_margin_step: int | None = None
    #: differential drive only (None otherwise, and then not written): what the checker measured from the recorded
    #: poses (:func:`tmr.checks.diffdrive.diff_drive_check`): lateral velocity, peak v, ω and accelerations, steps
    #: turning in place per robot
    diff_drive: dict[str, Any] | None = None

    @property
    def fitness(self) -> tuple[float, float, float, float]:
        """(f1, f2, f3, f4)."""
        return (self.f1, self.f2, self.f3, self.f4)

    @property
    def violation_free(self) -> bool:
        """True if no sample violates anything."""
        return self.n_violation_steps == 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict in field order. Non-finite floats are written as the strings ``"inf"``, ``"-inf"``,
        ``"nan"`` (see :func:`json_safe`); ``None`` (e.g. no failure, no violation of a kind) becomes
        ``null``."""
        out = asdict(self)
        if out["low_obstacle_margin"] is None:  # no low obstacle: its metrics.json keeps the keys it always had
            for key in _OPTIONAL_FIELDS:
                del out[key]
        if out["diff_drive"] is None:  # an omnidirectional plan: its metrics.json keeps its keys
            del out["diff_drive"]
        return json_safe(out)


#: Metrics fields left out of :meth:`Metrics.to_dict` when None (the world has no low obstacle).
_OPTIONAL_FIELDS = ("low_obstacle_margin", "low_obstacle_margin_step")


def qp_level_counts(diagnostics: dict[str, Any]) -> dict[str, dict[str, int]]:
    """Per QP level, how many steps ended in each status of :data:`QP_LEVEL_STATUS`.

    Reads the per-step codes ``diagnostics["qp_level:<name>"]`` (NaN where no step was done) that
    :class:`tmr.control.qp.LexicographicQP` writes: ``solved`` (its optimum with every higher level kept
    exactly), ``relaxed`` (solved with a higher level's freeze loosened by the documented slack), ``implied`` (not
    solved: the higher levels leave it no freedom), ``failed`` (no backend solved it: the step keeps the higher
    levels' optimum), ``skipped`` (below a failed level), ``empty`` (no task of weight > 0). Levels in stack order.
    """
    out: dict[str, dict[str, int]] = {}
    for key, values in diagnostics.items():
        if not key.startswith(QP_LEVEL_PREFIX):
            continue
        v = np.asarray(values, dtype=float)
        v = v[np.isfinite(v)]
        counts = {name: int(np.count_nonzero(v == c)) for c, name in enumerate(QP_LEVEL_STATUS)}
        out[key[len(QP_LEVEL_PREFIX) :]] = counts
    return out


def _argmin_step(values: np.ndarray) -> tuple[float, int | None]:
    """(min over all entries, sample index k of the min) of a (K+1, M) array; (inf, None) if empty."""
    if values.size == 0:
        return math.inf, None
    flat = int(np.argmin(values))
    return float(values.flat[flat]), int(np.unravel_index(flat, values.shape)[0])


def evaluate(
    plan: Any,
    env: Any,
    *,
    Ts: float | None = None,
    goal: np.ndarray | None = None,
    tolerance: float = 1e-6,
) -> Metrics:
    """Evaluate a plan: fitness (Caruso 2021 eq. 24–27), clearances, span limits, separations, speeds, errors.

    Args:
        plan: a :class:`tmr.control.clik.Plan` (possibly truncated if it failed).
        env: environment with ``exact_clearance`` and ``segment_clearance`` (see :func:`clearances`).
        Ts: sample time [s]; default: from ``plan.t`` (see :func:`sample_time`).
        goal: leader goal (2,) [m] for ``final_leader_error``; default: ``plan.goal`` if the plan has one,
            else the last reference point ``plan.reference[-1]`` (the reference trajectory ends at the goal).
        tolerance: slack [m] before a sample counts as a violation (clearance < −tol, span > d_max + tol,
            span < d_lo − tol, separation < 2 r − tol).

    Violation kinds (:data:`VIOLATION_KINDS`): ``robot_clearance`` (a robot centre inside the inflated
    obstacles), ``tether_clearance`` (a tether segment crosses them), ``span_max`` (span above d_max: the
    catenary would touch the ground), ``span_min`` (span below d_lo), ``separation`` (two robots closer than
    twice the safety radius). With low obstacles (``env.low_obstacles``) the tether chords are checked against
    ``env.tether_environment`` and kind ``low_obstacle`` (:data:`LOW_OBSTACLE_KIND`) is added: a cable crossing a
    low obstacle's footprint lower than its height plus ``low_obstacle_clearance`` (:func:`low_obstacle_margins`,
    beyond ``tolerance``). With ``plan.winch_tension`` (K+1, N) [N] set, ``span_max`` is the catenary's lowest point
    at that step's tension below ``ground_clearance`` (:func:`_winch_span_high`).
    """
    t = np.asarray(plan.t, dtype=float)
    if Ts is None and t.size < 2 and "Ts" not in (getattr(plan, "params", None) or {}):
        Ts = math.nan  # a plan that stopped at its first sample: nothing is differentiated
    else:
        Ts = _plan_ts(plan, Ts)
    robots = np.asarray(plan.robots, dtype=float)
    spans = np.asarray(plan.spans, dtype=float)
    reference = np.asarray(plan.reference, dtype=float)[:, :2]
    n_samples, n_robots = robots.shape[:2]
    n_steps = n_samples - 1
    tol = float(tolerance)
    r = float(plan.safety_radius)

    f1, f2, f3, f4 = fitness(plan, Ts)
    raw = list(fitness(plan, Ts, penalize=False)) if t.size >= 2 else [math.nan] * 4

    # clearances
    clr = clearances(plan, env)
    min_rc, min_rc_k = _argmin_step(clr.robots)
    min_tc, min_tc_k = _argmin_step(clr.tethers)

    # spans
    d_lo, d_max = span_limits(plan)
    reach = d_max  # an active winch: the reach of each step's tension, d_max(T_k) (max_span_ratio and d_max)
    tension_now = _winch_tension(plan, spans.shape)
    if tension_now is not None:
        reach = _winch_reach(plan, tension_now)
    ratio = spans / reach
    k_hi, i_hi = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    k_lo, i_lo = np.unravel_index(int(np.argmin(spans - d_lo)), spans.shape)

    # separations
    sep = robot_separations(robots)
    min_sep = float(sep.min()) if sep.size else math.inf

    # speeds / accelerations
    speed, acc = robot_speeds(robots, Ts)
    peak_speed_i = speed.max(axis=0) if speed.shape[0] else np.zeros(n_robots)
    peak_acc_i = acc.max(axis=0) if acc.shape[0] else np.zeros(n_robots)

    # distance errors, tracking
    derr = np.abs(distance_errors(plan)).max(axis=0)
    track = np.linalg.norm(robots[:, -1, :] - reference, axis=-1)
    goal_xy = plan_goal(plan, goal)
    final_err = float(np.linalg.norm(robots[-1, -1, :] - goal_xy))

    # violations, per sample
    tension = _winch_tension(plan, spans.shape)
    high = None if tension is None else _winch_span_high(plan, spans, tension, tol)
    masks = _violation_masks(clr, spans, sep, (d_lo, d_max), r, tol, high)
    kinds = VIOLATION_KINDS
    low_margin: float | None = None
    low_step: int | None = None
    if getattr(env, "low_obstacles", ()):
        margins = low_obstacle_margins(plan, env)
        low_margin, low_step = _argmin_step(margins)
        if not math.isfinite(low_margin):
            low_step = None
        masks[LOW_OBSTACLE_KIND] = (margins < -tol).any(axis=1)
        kinds = (*VIOLATION_KINDS, LOW_OBSTACLE_KIND)
    if tension is not None:  # an active winch: its tension within the pulley's range, changing within its rate
        masks.update(_winch_masks(plan, tension, Ts, tol))
        kinds = (*kinds, *WINCH_KINDS)
    diff = diff_drive_check(plan, Ts)
    diff_summary: dict[str, Any] | None = None
    if diff is not None:  # differential drive: the recorded poses (tmr.checks.diffdrive)
        masks.update(diff[0])
        diff_summary = diff[1]
        kinds = (*kinds, *DIFF_KINDS)
    steps = {kind: np.flatnonzero(masks[kind]).tolist() for kind in kinds}
    first = {kind: (steps[kind][0] if steps[kind] else None) for kind in kinds}
    any_violation = np.logical_or.reduce([masks[kind] for kind in kinds])

    wall = float(getattr(plan, "wall_time", math.nan))
    diagnostics = getattr(plan, "diagnostics", None) or {}
    fallbacks = np.asarray(diagnostics.get("fallback_solves", []), dtype=float)
    return Metrics(
        scenario=str(plan.scenario),
        method=str(plan.method),
        success=bool(plan.success),
        failure=None if plan.failure is None else str(plan.failure),
        n_robots=int(n_robots),
        n_steps=int(n_steps),
        Ts=Ts,
        duration=float(t[-1] - t[0]),
        f1=f1,
        f2=f2,
        f3=f3,
        f4=f4,
        fitness_raw=raw,
        min_robot_clearance=min_rc,
        min_robot_clearance_step=min_rc_k,
        min_tether_clearance=min_tc,
        min_tether_clearance_step=min_tc_k,
        max_span=float(spans.max()),
        d_max=float(np.broadcast_to(reach, spans.shape)[k_hi, i_hi]),
        max_span_ratio=float(ratio[k_hi, i_hi]),
        min_span=float(spans.min()),
        d_lo=float(d_lo[i_lo]),
        min_separation=min_sep,
        separation_limit=2.0 * r,
        peak_speed=float(peak_speed_i.max()),
        final_speed=float(speed[-1].max()) if speed.shape[0] else 0.0,
        peak_speed_per_robot=[float(v) for v in peak_speed_i],
        peak_acceleration=float(peak_acc_i.max()),
        peak_acceleration_per_robot=[float(v) for v in peak_acc_i],
        max_abs_distance_error=float(derr.max()),
        max_abs_distance_error_per_tether=[float(v) for v in derr],
        final_leader_error=final_err,
        max_tracking_error=float(track.max()),
        rms_tracking_error=float(np.sqrt(np.mean(track * track))),
        tolerance=tol,
        n_violation_steps=int(np.count_nonzero(any_violation)),
        violation_steps=steps,
        first_violation=first,
        wall_time=wall,
        ms_per_step=1000.0 * wall / n_steps if n_steps > 0 else math.nan,
        qp_levels=qp_level_counts(diagnostics),
        qp_fallback_solves=int(np.nansum(fallbacks)) if fallbacks.size else 0,
        low_obstacle_margin=low_margin,
        low_obstacle_margin_step=low_step,
        diff_drive=diff_summary,
    )


# ----------------------------------------------------------------------------------------------------------
# post-filtering (Caruso 2021 §5: "the trajectories have been smoothed by filtering")
# ----------------------------------------------------------------------------------------------------------
def filter_trajectories(robots: np.ndarray, Ts: float, cutoff_hz: float = 1.0, order: int = 2) -> np.ndarray:
    """Zero-phase low-pass filter of the robot trajectories, removing the spikes that task switching produces.

    Butterworth low-pass (:func:`tmr.checks.lowpass.butter_lowpass`, the numbers of ``scipy.signal.butter``) applied
    forward and backward (:func:`tmr.checks.lowpass.filtfilt`, as ``scipy.signal.filtfilt``) along time, so there is
    no phase lag. The series is extended by odd reflection about each end point (which continues a straight
    line exactly) over about four cut-off periods, so the start-up transient dies out in the padding: a straight
    line comes back unchanged (< 1e-6 m) and the end points of a smooth trajectory stay put. The pad length is
    capped at K samples for short series (guard for filtfilt); series with fewer than 3 samples are returned
    unchanged. The filter does not know the hard limits: :func:`filter_within_limits` restores them.

    Args:
        robots: (K+1, N, 2) positions [m] (any array with time on axis 0 works).
        Ts: sample time [s].
        cutoff_hz: −3 dB cut-off frequency [Hz]; must be below the Nyquist frequency 1/(2 Ts).
        order: Butterworth order (the forward-backward pass doubles the effective order).

    Returns:
        A filtered copy; ``robots`` is not modified.
    """
    x = np.array(robots, dtype=float, copy=True)
    Ts = float(Ts)
    if not (math.isfinite(Ts) and Ts > 0.0):
        raise ParameterError(f"sample time Ts must be a positive number of seconds, got {Ts!r}")
    nyquist = 0.5 / Ts
    if not (0.0 < cutoff_hz < nyquist):
        raise ParameterError(
            f"cutoff_hz={cutoff_hz!r} Hz must be in ]0, {nyquist:g}[ (the Nyquist frequency for Ts={Ts:g} s)"
        )
    if int(order) < 1:
        raise ParameterError(f"filter order must be >= 1, got {order!r}")
    if x.shape[0] < 3:
        return x
    b, a = butter_lowpass(int(order), cutoff_hz, fs=1.0 / Ts)
    # pad over ~4 periods of the cut-off so the start-up transient dies out inside the padding
    padlen = min(max(3 * max(len(a), len(b)), math.ceil(4.0 / (cutoff_hz * Ts))), x.shape[0] - 1)
    return filtfilt(b, a, x, padlen=padlen)


def limit_breaks(plan: Any, robots: np.ndarray, env: Any, tolerance: float = 1e-6) -> np.ndarray:
    """Samples (K+1,) bool at which positions ``robots`` (K+1, N, 2) [m] of ``plan``'s chain break a hard limit:
    a robot or tether inside the inflated obstacles, a span outside [d_lo, d_max], two robots closer than 2 r, a
    cable too low over a low obstacle — the violation kinds of :func:`evaluate`, with its ``tolerance`` [m]."""
    pts = chain_points(plan, robots)
    spans = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    tension = _winch_tension(plan, spans.shape)
    masks = _violation_masks(
        _chain_clearances(pts, env),
        spans,
        robot_separations(pts[:, 1:]),
        span_limits(plan),
        float(plan.safety_radius),
        tolerance,
        None if tension is None else _winch_span_high(plan, spans, tension, tolerance),
    )
    if getattr(env, "low_obstacles", ()):
        masks[LOW_OBSTACLE_KIND] = (low_obstacle_margins(plan, env, pts[:, 1:]) < -tolerance).any(axis=1)
    return np.logical_or.reduce(list(masks.values()))


#: Hold times [s] round the samples where the filtered trajectories break a limit, tried in turn by
#: :func:`filter_within_limits` (the raw plan is kept for ± hold, then blends into the filtered one over 1 / cut-off).
FILTER_HOLDS = (0.0, 0.5, 1.0, 2.0, 4.0)


def filter_within_limits(
    plan: Any, env: Any, Ts: float, cutoff_hz: float = 1.0, order: int = 2
) -> tuple[np.ndarray, str | None]:
    """:func:`filter_trajectories`, then the raw plan restored wherever the filtered trajectories break a hard limit.

    Robot nodes track the filtered trajectories (Caruso 2021 §5.2), so they must keep the limits the plan keeps; the
    low-pass can pull a robot that turns close round an obstacle a few centimetres into it. Around every sample that
    breaks a limit (:func:`limit_breaks`) the output is the raw plan for ± hold, blending back into the filtered
    trajectories over 1 / ``cutoff_hz`` seconds with a raised-cosine weight; holds of :data:`FILTER_HOLDS` are tried
    in turn, then the raw plan itself (which the checker passed). A failed plan (``plan.success`` False) is only
    filtered, and the note says so.

    Returns:
        (filtered positions (K+1, N, 2) [m], a note saying where and how the filter was held, or None if untouched).
    """
    raw = np.asarray(plan.robots, dtype=float)
    filtered = filter_trajectories(raw, Ts, cutoff_hz=cutoff_hz, order=order)
    if not plan.success:  # a limit broken, the goal missed or the run stopped: no checked plan to fall back on
        return filtered, "not checked against the hard limits: the plan itself failed"
    bad = limit_breaks(plan, filtered, env)
    if not bad.any():
        return filtered, None
    t = np.asarray(plan.t, dtype=float)
    first = float(t[np.argmax(bad)])
    ramp = max(1.0, 1.0 / (cutoff_hz * Ts))  # samples
    k = np.arange(raw.shape[0])
    marked = bad.copy()
    broke = f"the filtered trajectories broke a hard limit at {int(bad.sum())} sample(s) from t = {first:.2f} s"
    for hold in FILTER_HOLDS:
        idx = np.flatnonzero(marked)
        # distance [samples] of every sample to the nearest marked one
        pos = np.searchsorted(idx, k)
        right, left = idx[np.minimum(pos, len(idx) - 1)], idx[np.maximum(pos - 1, 0)]
        dist = np.minimum(np.abs(k - right), np.abs(k - left))
        beyond = np.clip((dist - hold / Ts) / ramp, 0.0, 1.0)
        w = 0.5 * (1.0 + np.cos(np.pi * beyond))  # 1 held (raw), 0 filtered
        out = w[:, None, None] * raw + (1.0 - w[:, None, None]) * filtered
        still = limit_breaks(plan, out, env)
        if not still.any():
            return out, f"{broke}; there the raw plan is kept (± {hold:g} s, blending over {ramp * Ts:.2g} s)"
        marked |= still
    return raw.copy(), f"{broke} and no local hold removed it: the 'filtered' trajectories are the raw plan"
