"""Random rooms put to the command line: what a plan of a room must satisfy, checked independently of the planner
(shapely distances, spans, separations), the expected verdict for N robots (:func:`decide_count`), and one
``python -m tmr.plan`` run per room in a subprocess (:func:`run_room`). The rooms come from
:mod:`tmr.sweep.rooms`; ``benchmarks/random_rooms.py`` runs them.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry.base import BaseGeometry

from tmr.sweep.rooms import (
    CLEARANCE_TOL,
    GEOMETRY_TOL,
    MIN_ROUTE_FOR_RATIO,
    SAFETY_RADIUS,
    Room,
    RoomError,
    _route_module,
    default_d_max,
    span_rows,
    write_geojson,
)

__all__ = ["RoomRun", "decide_count", "independent_check", "run_room", "trajectory_positions", "xy_arg"]


# ------------------------------------------------------------------------------------------------------------
# independent check of a plan
# ------------------------------------------------------------------------------------------------------------
def independent_check(
    positions: NDArray[np.float64],
    base: NDArray[np.float64],
    obstacles: list[BaseGeometry],
    bounds: tuple[float, float, float, float],
    d_max: float,
    safety_radius: float = SAFETY_RADIUS,
) -> dict[str, Any]:
    """Hard limits of a plan checked with shapely alone (no tmr.world.environment / tmr.checks.metrics query).

    Args:
        positions: (K+1, N, 2) robot centres [m], robot 1 next to the anchor, robot N the leader.
        base: tether anchor (2,) [m].
        obstacles: the room's raw (not grown) obstacles.
        bounds: the room (xmin, ymin, xmax, ymax) [m].
        d_max: longest allowed tether span [m].
        safety_radius: r [m].

    Returns a dict of minima over every step [m]: ``ind_robot_clearance`` (distance of a robot centre to the raw
    obstacles − r), ``ind_wall_clearance`` (to the room walls − r), ``ind_tether_clearance`` (distance of every
    straight tether chord anchor → robot 1 → … → robot N to the raw obstacles − r; the room is convex, so a
    chord is never closer to the walls than its ends), ``ind_max_span_ratio`` (span / d_max),
    ``ind_min_anchor_span`` (≥ r), ``ind_min_separation`` (every robot pair, ≥ 2r), and ``independent_ok``.

    Tolerance: 1 mm on the obstacle clearances (tmr grows obstacles by polygon buffers with 16 segments per
    quarter circle, whose chords lie up to r (1 − cos(π/64)) = 0.6 mm inside the true offset curve), 1e-6 on
    spans and separations.
    """
    P = np.asarray(positions, dtype=float)
    if P.ndim != 3 or P.shape[2] != 2 or P.shape[1] < 1:
        raise ValueError(f"positions must have shape (K+1, N, 2), got {P.shape}")
    r = float(safety_radius)
    n_t, n = P.shape[:2]
    anchor = np.broadcast_to(np.asarray(base, dtype=float)[:2], (n_t, 1, 2))
    nodes = np.concatenate([anchor, P], axis=1)  # (K+1, N+1, 2)
    geoms = [g for g in obstacles if not g.is_empty]
    obst = shapely.union_all(geoms) if geoms else None

    flat = P.reshape(-1, 2)
    if obst is not None:
        d_robot = shapely.distance(shapely.points(flat), obst) - r
        inside = shapely.contains_xy(obst, flat[:, 0], flat[:, 1])
        d_robot = np.where(inside, -r, d_robot)  # centre inside an obstacle: at least r too deep
        a = nodes[:, :-1].reshape(-1, 2)
        b = nodes[:, 1:].reshape(-1, 2)
        degenerate = np.all(a == b, axis=1)
        chords = np.empty(len(a), dtype=object)
        chords[degenerate] = shapely.points(a[degenerate])
        chords[~degenerate] = shapely.linestrings(np.stack([a[~degenerate], b[~degenerate]], axis=1))
        d_tether = shapely.distance(chords, obst) - r
        crosses = shapely.intersects(chords, obst)
        d_tether = np.where(crosses, np.minimum(d_tether, -r), d_tether)
        min_robot, min_tether = float(d_robot.min()), float(d_tether.min())
        worst_robot_step = int(np.argmin(d_robot.reshape(n_t, n).min(axis=1)))
        worst_tether_step = int(np.argmin(d_tether.reshape(n_t, n).min(axis=1)))
    else:
        min_robot = min_tether = math.inf
        worst_robot_step = worst_tether_step = -1
    xmin, ymin, xmax, ymax = bounds
    d_wall = np.minimum.reduce([flat[:, 0] - xmin, xmax - flat[:, 0], flat[:, 1] - ymin, ymax - flat[:, 1]]) - r

    spans = np.hypot(*(nodes[:, 1:] - nodes[:, :-1]).transpose(2, 0, 1))  # (K+1, N)
    max_ratio = float(spans.max() / d_max)
    min_anchor_span = float(spans[:, 0].min())
    if n > 1:
        diff = P[:, :, None, :] - P[:, None, :, :]
        dist = np.hypot(diff[..., 0], diff[..., 1])
        iu = np.triu_indices(n, k=1)
        min_sep = float(dist[:, iu[0], iu[1]].min())
    else:
        min_sep = math.inf
    checks = {
        "robot_clearance": min_robot >= -CLEARANCE_TOL,
        "wall_clearance": float(d_wall.min()) >= -CLEARANCE_TOL,
        "tether_clearance": min_tether >= -CLEARANCE_TOL,
        "span_max": max_ratio <= 1.0 + GEOMETRY_TOL,
        "span_min": min_anchor_span >= r - GEOMETRY_TOL,
        "separation": min_sep >= 2 * r - GEOMETRY_TOL,
    }
    return {
        "ind_robot_clearance": min_robot,
        "ind_robot_clearance_step": worst_robot_step,
        "ind_wall_clearance": float(d_wall.min()),
        "ind_tether_clearance": min_tether,
        "ind_tether_clearance_step": worst_tether_step,
        "ind_max_span_ratio": max_ratio,
        "ind_min_anchor_span": min_anchor_span,
        "ind_min_separation": min_sep,
        "ind_violations": ",".join(k for k, ok in checks.items() if not ok),
        "independent_ok": all(checks.values()),
    }


def decide_count(room: Room) -> dict[str, Any]:
    """Where the fewest robots lies for a room whose proven bound ``n_lower`` is below the plans' count ``n_min``
    (chords keeping 0.06 m): the problem's N_min (chords merely clear of the grown obstacles) is at least
    ``n_proven`` and at most ``n_clear``.

    * ``n_proven``: one more than the largest N < ``n_min`` proven too few by :func:`tmr.route.route.proven_too_few`
    (the
      proof as the command line runs it), else ``n_lower``;
    * ``n_clear``: the robots of the first chain :func:`tmr.route.route.clear_chain` finds for N = ``n_proven``,
      ``n_proven`` + 1, … < ``n_min`` that also passes :func:`independent_check` (shapely alone: chords clear of the
      raw obstacles grown by r, to 1 mm, spans ≤ d_max, robots 2r apart); None if none is found.

    N_min is decided when ``n_clear == n_proven``; a clear chain with fewer robots than a proof allows would show the
    proof wrong, and raises :class:`RoomError`. Returns ``{"room", "n_proven", "n_clear", "clear_margin"}``
    (``clear_margin``: that chain's least tether clearance by the independent check [m]). A picklable task for the
    sweep executors; seconds per room.
    """
    from tmr.route.route import clear_chain, proven_too_few

    out: dict[str, Any] = {"room": room.name, "n_proven": room.n_lower, "n_clear": None, "clear_margin": None}
    if room.n_min is None or room.n_lower is None or room.n_lower >= room.n_min:
        return out
    env, lim = room.environment(), span_rows(room.d_max)
    for n in range(room.n_min - 1, room.n_lower - 1, -1):
        if proven_too_few(env, room.base, room.goal, lim, n):
            out["n_proven"] = n + 1
            break
    for n in range(out["n_proven"], room.n_min):
        found = clear_chain(env, room.base, room.goal, lim, n)
        if found is None:
            continue
        chain = found[0]
        check = independent_check(chain[None, 1:], room.base, room.obstacles, room.bounds, room.d_max, SAFETY_RADIUS)
        if check["independent_ok"]:
            out["n_clear"], out["clear_margin"] = len(chain) - 1, check["ind_tether_clearance"]
            break
    if out["n_clear"] is not None and out["n_clear"] < out["n_proven"]:  # a clear chain below a proof: a wrong proof
        raise RoomError(
            f"{room.name}: a chain of {out['n_clear']} robots clear of the grown obstacles passes the independent "
            f"check, but {out['n_proven'] - 1} robots are proven too few"
        )
    return out


def trajectory_positions(doc: dict[str, Any], key: str = "robots") -> NDArray[np.float64]:
    """(K+1, N, 2) positions [m] from a ``tmr-trajectories/1`` document (``key``: "robots" raw, "filtered").

    The chain's points: for a differential-drive plan (``"drive": "diff"``) the tethers' exit points ``exit_x``,
    ``exit_y`` (``x``, ``y`` are there the axle centres, ``formulations/diffdrive.md``), which the safety disc of
    radius r is kept round; otherwise ``x``, ``y``."""
    entries = doc[key]
    xk, yk = ("exit_x", "exit_y") if doc.get("drive") == "diff" else ("x", "y")
    return np.stack([np.column_stack([e[xk], e[yk]]) for e in entries], axis=1).astype(float)


# ------------------------------------------------------------------------------------------------------------
# one run of the command line
# ------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RoomRun:
    """One benchmark task: a room, a method and a robot count (``"auto"`` or an int as a string).

    ``timeout`` [s] bounds the subprocess; ``keep_dir``: copy the room and outputs of runs that are not a clean
    success or refusal there; ``extra_args``: more ``tmr.plan`` flags.
    """

    room: Room
    method: str = "qp"
    robots: str = "auto"
    seed: int = 0
    timeout: float = 600.0
    keep_dir: str | None = None
    extra_args: tuple[str, ...] = ()


def _num(v: Any) -> float | None:
    if v is None:
        return None
    if isinstance(v, str):
        try:
            return float(v)
        except ValueError:
            return None
    return float(v)


def _leader_route_length(room: Room, start: NDArray[np.float64]) -> float | None:
    """Shortest free route [m] (tmr.route.route) from the leader's start to the goal, or None (no route module, no
    route)."""
    route_mod = _route_module()
    if route_mod is None:
        return None
    try:
        return float(
            route_mod.plan_route(room.environment(), start, room.goal, span_rows(room.d_max), fewest=False).length
        )
    except Exception:  # noqa: BLE001 - a start the route module refuses: no ratio
        return None


def xy_arg(p: NDArray[np.float64]) -> str:
    """``"X,Y"`` for the command line, each number in its shortest round-trip form (no numpy repr)."""
    return f"{float(p[0])!r},{float(p[1])!r}"


def run_room(spec: RoomRun) -> dict[str, Any]:
    """Run ``python -m tmr.plan --map ROOM.geojson ...`` in a subprocess; a flat dict of the outcome.

    Keys: the room summary (:meth:`Room.summary`), ``method``, ``robots`` (asked), ``exit_code`` (None on a
    timeout), ``wall_time`` (whole process [s]), ``stderr_last``, metrics read from ``metrics.json``
    (``success``, ``route_length_cli``, ``n_min_cli``, ``n_lower_cli``, ``robots_auto``, ``n_robots``,
    ``min_robot_clearance``,
    ``min_tether_clearance``, ``max_span_ratio``, ``final_leader_error``, ``d_max``), ``leader_length`` (path
    length of the leader [m]), ``leader_route_length`` (shortest free route from the leader's *start* to the goal,
    :func:`tmr.route.route.plan_route`: the leader starts along the route, not at the anchor), ``route_ratio``
    (leader_length / leader_route_length), and
    :func:`independent_check` of the raw trajectories (plus ``ind_filtered_*`` minima of the filtered ones); also
    ``references`` / ``references_note`` (trailing or train references, and why), ``n_steps``, ``duration`` (the motion
    [s]), ``f1``, ``f4`` (Caruso 2021 eq. 24, 27), ``violation_kinds`` and, for
    ``--drive diff``, the checker's ``max_lateral_velocity`` [m/s], ``peak_v``, ``v_max`` [m/s], ``peak_omega``,
    ``omega_max`` [rad/s] and ``turn_in_place_steps`` (summed over the robots).
    """
    room = spec.room
    out: dict[str, Any] = room.summary()
    out.update(method=spec.method, robots=str(spec.robots))
    with tempfile.TemporaryDirectory(prefix="tmr-room-") as tmp:
        tmpdir = Path(tmp)
        map_path = write_geojson(room, tmpdir / f"{room.name}.geojson")
        out_dir = tmpdir / "out"
        cmd = [
            sys.executable, "-m", "tmr.plan",
            "--map", str(map_path),
            f"--base={xy_arg(room.base)}",
            f"--goal={xy_arg(room.goal)}",
            "--robots", str(spec.robots),
            "--method", spec.method,
            "--no-plots",
            "--out", str(out_dir),
            "--seed", str(spec.seed),
            *spec.extra_args,
        ]  # fmt: skip
        env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=spec.timeout, env=env)
            code: int | None = proc.returncode
            stderr = proc.stderr
        except subprocess.TimeoutExpired as exc:
            code = None
            stderr = (exc.stderr.decode() if isinstance(exc.stderr, bytes) else exc.stderr) or ""
            stderr += f"\ntimeout after {spec.timeout:g} s"
        out["wall_time"] = time.perf_counter() - t0
        out["exit_code"] = code
        lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
        out["stderr_last"] = lines[-1] if lines else ""

        metrics: dict[str, Any] = {}
        mpath = out_dir / "metrics.json"
        if mpath.is_file():
            metrics = json.loads(mpath.read_text())
        out["success"] = metrics.get("success")
        out["failure"] = metrics.get("failure")
        out["n_robots"] = metrics.get("n_robots")
        out["route_length_cli"] = _num(metrics.get("route_length"))
        out["n_min_cli"] = metrics.get("n_min")
        out["n_lower_cli"] = metrics.get("n_lower")
        out["robots_auto"] = metrics.get("robots_auto")
        out["references"] = metrics.get("references")  # trail, or train when the trailing ones failed
        out["references_note"] = metrics.get("references_note")
        out["n_steps"] = metrics.get("n_steps")
        out["duration"] = _num(metrics.get("duration"))  # s, the motion
        out["f1"], out["f4"] = _num(metrics.get("f1")), _num(metrics.get("f4"))
        dd = metrics.get("diff_drive")
        if isinstance(dd, dict):  # --drive diff: what the checker measured from the recorded poses
            for key in ("max_lateral_velocity", "peak_v", "v_max", "peak_omega", "omega_max"):
                out[key] = _num(dd.get(key))
            out["turn_in_place_steps"] = int(sum(dd.get("turn_in_place_steps") or []))
        if isinstance(metrics.get("violation_steps"), dict):
            out["violation_kinds"] = ",".join(sorted(k for k, v in metrics["violation_steps"].items() if v))
        for key in ("min_robot_clearance", "min_tether_clearance", "max_span_ratio", "final_leader_error", "d_max"):
            out[key] = _num(metrics.get(key))
        tfile = out_dir / "timings.json"  # the planner's wall time is kept apart from the reproducible metrics
        timings = json.loads(tfile.read_text()) if tfile.is_file() else {}
        out["plan_wall_time"] = _num(timings.get("wall_time"))
        hz = metrics.get("horizon")
        if isinstance(hz, dict):  # --method horizon: what the NLP returned, against its qp warm start
            out["horizon_result"] = hz.get("result")
            out["horizon_stop"] = hz.get("stop")
            out["horizon_iterations"] = hz.get("iterations")
            coarse = hz.get("coarse")  # the coarse pass (long or large horizons): "accepted", "rejected" or "failed"
            out["horizon_coarse"] = coarse.get("result") if isinstance(coarse, dict) else None
            out["nlp_time"] = _num(timings.get("nlp_time"))
            out["qp_time"] = _num(timings.get("qp_time"))
            for k in ("f1", "f2", "f3", "f4"):
                out[f"horizon_{k}"] = _num(hz.get("terms", {}).get(k))
                out[f"qp_{k}"] = _num(hz.get("warm_start_terms", {}).get(k))

        tpath = out_dir / "trajectories.json"
        out["leader_length"] = out["leader_route_length"] = out["route_ratio"] = None
        if tpath.is_file():
            doc = json.loads(tpath.read_text())
            P = trajectory_positions(doc, "robots")
            d_max = out["d_max"] if out["d_max"] is not None else default_d_max()
            base = np.asarray(doc.get("base", room.base), dtype=float)
            out.update(independent_check(P, base, room.obstacles, room.bounds, d_max))
            out["knots"] = int(P.shape[0])
            leader = P[:, -1]
            out["leader_length"] = float(np.hypot(*np.diff(leader, axis=0).T).sum())
            out["leader_route_length"] = _leader_route_length(room, leader[0])
            if out["leader_route_length"] is not None and out["leader_route_length"] >= MIN_ROUTE_FOR_RATIO:
                out["route_ratio"] = out["leader_length"] / out["leader_route_length"]
            if "filtered" in doc:
                filt = independent_check(
                    trajectory_positions(doc, "filtered"), base, room.obstacles, room.bounds, d_max
                )
                for key in ("ind_robot_clearance", "ind_tether_clearance", "ind_max_span_ratio", "independent_ok"):
                    out[key.replace("ind_", "ind_filtered_") if key != "independent_ok" else "filtered_ok"] = filt[key]

        clean = (code == 0 and out.get("independent_ok") is True) or code == 2
        if spec.keep_dir and not clean:
            dest = Path(spec.keep_dir) / f"{room.name}-{spec.method}-{spec.robots}"
            shutil.rmtree(dest, ignore_errors=True)
            shutil.copytree(tmpdir, dest)
            (dest / "command.txt").write_text(" ".join(cmd[1:]) + "\n" + stderr)
    return out
