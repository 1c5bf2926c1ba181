"""Output files of a drone-chain plan (``formulations/drones.md``, "Outputs (3-D)") and their reader.

``tmr plan`` on a ``kind = "drone"`` scenario writes, into its :class:`tmr.io.outdir.Stage` directory (through
:func:`write_drone_outputs`):

* ``trajectories.json`` — per drone ``t, x, y, z`` (and the velocities ``vx, vy, vz`` the plan holds on each step),
  the leader's reference, and per tether ``{t, a}`` with the catenary parameter a = H / (ρ g) [m] at each step
  (``null`` for a vertical tether): any reader rebuilds each curve from its two ends and a.
* ``trajectories.csv`` — one row per step: ``t``, then ``robot<i>_x, _y, _z``, then ``tether<j>_a`` (empty: vertical).
* ``metrics.json`` — :class:`tmr.checks.drones.DroneMetrics` without its per-step series (plus the glue's extras).
* ``run.json`` — ``kind = "drone"``: the world (the scenario's ``[world]`` table, its mesh paths made relative to the
  run directory; the scenario file's name and text), ``safety_radius``, ``tether_clearance``, ``rho``, ``g``,
  ``tension_max``, ``tether_length_max``, ``winch_end``, ``winch_tension``, every tether parameter, the planner
  parameters and a summary of the check.
* ``timings.json`` — wall times (not reproducible, so kept apart and listed without a hash in the manifest).
* ``world_meshes/`` (:data:`DRONE_MESH_DIR`, only for a world with meshes) — a byte copy of every mesh file of the
  world, ``world_meshes/<file name>`` (``world_meshes/obstacle<k>/<file name>`` when two different files share a
  name): the run directory is self-contained (moved or copied, ``tmr export`` and :meth:`DroneRun.check` still
  read its world), and run.json holds no absolute path.

Every file goes through the atomic writers of :mod:`tmr.io.outputs`; the same plan gives the same bytes (fixed key
order, floats in shortest round-trip form). :func:`load_drone_run` (registered for ``kind = "drone"`` with
:func:`tmr.io.rundir.register_kind`) reads a run directory back into a :class:`DroneRun`, which rebuilds the
:class:`tmr.control.plan3d.DronePlan`.
"""

from __future__ import annotations

import csv
import io as _io
import math
import os
import statistics
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.errors import ParameterError
from tmr.io.rundir import RUN_FORMAT, RunDirError, _dump, _read_json, _safe, _version, register_kind

__all__ = [
    "DRONE_MESH_DIR",
    "DRONE_OUTPUT_NAMES",
    "DRONE_TRAJECTORY_FORMAT",
    "DRONE_VOLATILE_NAMES",
    "DroneRun",
    "drone_run_dict",
    "drone_trajectories_dict",
    "load_drone_run",
    "world_meshes",
    "write_drone_outputs",
    "write_drone_trajectories_csv",
    "write_drone_trajectories_json",
]

Array = NDArray[np.float64]

#: ``format`` of a drone plan's ``trajectories.json``.
DRONE_TRAJECTORY_FORMAT = "tmr-drone-trajectories/1"
#: The directory of the run that holds a copy of the world's mesh files (written only for a world with meshes).
DRONE_MESH_DIR = "world_meshes"
#: Every entry :func:`write_drone_outputs` may write (the glue's ``Stage(owned=...)`` adds its figures).
DRONE_OUTPUT_NAMES = (
    "trajectories.json",
    "trajectories.csv",
    "metrics.json",
    "run.json",
    "timings.json",
    DRONE_MESH_DIR,
)
#: Files whose bytes change from run to run (``Stage(volatile=...)``).
DRONE_VOLATILE_NAMES = ("timings.json",)


def _list(values: Any) -> list[Any]:
    """Floats as a JSON list, non-finite values (a vertical tether's NaN) as null."""
    return [v if math.isfinite(v) else None for v in np.asarray(values, dtype=float).reshape(-1).tolist()]


def drone_trajectories_dict(plan: Any) -> dict[str, Any]:
    """The ``trajectories.json`` document of a :class:`tmr.control.plan3d.DronePlan` (format
    :data:`DRONE_TRAJECTORY_FORMAT`; key order as written)::

        {"format", "scenario", "method", "success", "failure", "Ts" [s], "n_robots", "leader": "robot<N>",
         "base": [x, y, z], "goal": [x, y, z],                               # anchor (ground winch), leader goal [m]
         "robots": [{"name": "robot1", "t": [s], "x": [m], "y": [m], "z": [m], "vx", "vy", "vz": [m/s]}, ...],
         "reference": {"t": [s], "x", "y", "z": [m]},                        # the leader's reference x_d(t)
         "tethers": [{"name": "tether1", "from": "base", "to": "robot1", "t": [s], "a": [m or null]}, ...]}

    Tether j joins ``from`` (the anchor for j = 1, else robot j-1) to robot j; ``a`` is null for a vertical tether.
    With an active winch (``plan.winch_tension`` recorded) each tether also has ``"T_w"`` [N], its winch tension at
    every step (``a`` is the catenary at that tension).
    """
    t = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    vel = np.asarray(plan.velocities, dtype=float)
    ref = np.asarray(plan.reference, dtype=float)
    a = np.asarray(plan.tether_a, dtype=float)
    n = robots.shape[1]
    tl = _list(t)
    tw = getattr(plan, "winch_tension", None)
    tw = None if tw is None else np.asarray(tw, dtype=float).reshape(t.size, n)
    return {
        "format": DRONE_TRAJECTORY_FORMAT,
        "scenario": str(plan.scenario),
        "method": str(plan.method),
        "success": bool(plan.success),
        "failure": None if plan.failure is None else str(plan.failure),
        "Ts": float(t[1] - t[0]) if t.size > 1 else None,
        "n_robots": int(n),
        "leader": f"robot{n}",
        "base": _list(plan.base),
        "goal": _list(plan.goal),
        "robots": [
            {
                "name": f"robot{i + 1}",
                "t": tl,
                **{c: _list(robots[:, i, m]) for m, c in enumerate("xyz")},
                **{f"v{c}": _list(vel[:, i, m]) for m, c in enumerate("xyz")},
            }
            for i in range(n)
        ],
        "reference": {"t": tl, **{c: _list(ref[:, m]) for m, c in enumerate("xyz")}},
        "tethers": [
            {
                "name": f"tether{j + 1}",
                "from": "base" if j == 0 else f"robot{j}",
                "to": f"robot{j + 1}",
                "t": tl,
                "a": _list(a[:, j]),
                **({} if tw is None else {"T_w": _list(tw[:, j])}),
            }
            for j in range(n)
        ],  # fmt: skip
    }


def write_drone_trajectories_json(plan: Any, path: str | os.PathLike[str]) -> Path:
    """Write :func:`drone_trajectories_dict` as compact JSON (atomic, deterministic)."""
    from tmr.io.outputs import _dumps, atomic_write_text

    return atomic_write_text(path, _dumps(drone_trajectories_dict(plan), indent=None))


def write_drone_trajectories_csv(plan: Any, path: str | os.PathLike[str]) -> Path:
    """Write the trajectories as CSV (atomic, deterministic): ``t`` [s], ``robot<i>_x, _y, _z`` [m] for i = 1..N, then
    ``tether<j>_a`` [m] (empty for a vertical tether), then with an active winch ``tether<j>_T_w`` [N]; floats in
    shortest round-trip form, ``\\n`` line ends."""
    from tmr.io.outputs import atomic_write_text

    t = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    a = np.asarray(plan.tether_a, dtype=float)
    n = robots.shape[1]
    header = ["t"] + [f"robot{i + 1}_{c}" for i in range(n) for c in "xyz"] + [f"tether{j + 1}_a" for j in range(n)]
    table = np.concatenate([t[:, None], robots.reshape(t.size, 3 * n), a.reshape(t.size, n)], axis=1)
    tw = getattr(plan, "winch_tension", None)
    if tw is not None:  # an active winch: every tether's tension [N]
        header += [f"tether{j + 1}_T_w" for j in range(n)]
        table = np.concatenate([table, np.asarray(tw, dtype=float).reshape(t.size, n)], axis=1)
    buf = _io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([[repr(v) if math.isfinite(v) else "" for v in row] for row in table.tolist()])
    return atomic_write_text(path, buf.getvalue())


def _info(scenario_info: Any, key: str) -> Any:
    if scenario_info is None:
        return None
    if isinstance(scenario_info, Mapping):
        return scenario_info.get(key)
    return getattr(scenario_info, key, None)


def _mesh_base(scenario_info: Any) -> Path:
    """The folder the scenario's mesh paths are relative to: its file's folder (the current directory if unknown)."""
    source = _info(scenario_info, "source")
    return Path(source).parent if source is not None else Path(".")


def world_meshes(world_table: Any, base: str | os.PathLike[str]) -> tuple[Any, list[tuple[Path, str]]]:
    """The ``[world]`` table with every ``mesh`` path replaced by its copy in the run directory, and the copies to
    make as (source file, path relative to the run directory) pairs, in table order (module doc: the names).

    Args:
        world_table: the scenario's ``[world]`` table (returned as it is when it has no mesh or is not a table).
        base: the folder the table's mesh paths are relative to (the scenario file's).
    """
    if not isinstance(world_table, Mapping) or not isinstance(world_table.get("obstacles"), list):
        return world_table, []
    items = world_table["obstacles"]
    is_mesh = [isinstance(it, Mapping) and isinstance(it.get("mesh"), str) for it in items]
    meshes = {k: items[k]["mesh"] for k in range(len(items)) if is_mesh[k]}
    if not meshes:
        return world_table, []
    sources = {k: Path(base) / f for k, f in meshes.items()}
    files = {k: os.path.normcase(os.path.abspath(p)) for k, p in sources.items()}
    by_name: dict[str, set[str]] = {}
    for k, p in sources.items():
        by_name.setdefault(p.name, set()).add(files[k])
    dest: dict[str, str] = {}  # one copy per source file
    copies: list[tuple[Path, str]] = []
    obstacles = list(items)
    for k, p in sources.items():
        if files[k] not in dest:
            shared = len(by_name[p.name]) > 1
            dest[files[k]] = f"{DRONE_MESH_DIR}/obstacle{k}/{p.name}" if shared else f"{DRONE_MESH_DIR}/{p.name}"
            copies.append((p, dest[files[k]]))
        obstacles[k] = {**items[k], "mesh": dest[files[k]]}
    return {**world_table, "obstacles": obstacles}, copies


def drone_run_dict(plan: Any, metrics: Any = None, scenario_info: Any = None) -> dict[str, Any]:
    """The ``run.json`` document of a drone plan (format :data:`tmr.io.rundir.RUN_FORMAT`, ``kind = "drone"``).

    Args:
        plan: a :class:`tmr.control.plan3d.DronePlan`.
        metrics: its :class:`tmr.checks.drones.DroneMetrics` (for the summary), or None.
        scenario_info: the scenario (a ``DroneScenario`` or a dict) for ``name``, ``description``, ``world_table``
            (the parsed ``[world]`` table), ``source`` (the scenario file: its folder holds the mesh files) and
            ``text`` (the file's content); None records no world. Mesh paths are recorded as their copies in the
            run directory (:func:`world_meshes`; :func:`write_drone_outputs` makes the copies).
    """
    teth = plan.tether
    t = np.asarray(plan.t, dtype=float)
    source = _info(scenario_info, "source")
    world, _ = world_meshes(_info(scenario_info, "world_table"), _mesh_base(scenario_info))
    m = metrics.to_dict(per_step=False) if hasattr(metrics, "to_dict") else dict(metrics or {})
    summary_keys = ("success", "failure", "min_drone_clearance", "min_altitude_margin", "min_separation",
                    "min_tether_clearance", "max_tether_length", "max_drone_tension", "peak_speed",
                    "peak_acceleration", "final_leader_error", "binding_limit")  # fmt: skip
    diag = getattr(plan, "diagnostics", None) or {}
    p = dict(getattr(plan, "params", None) or {})
    return _safe(
        {
            "format": RUN_FORMAT,
            "kind": "drone",
            "tmr_version": _version(),
            "scenario": str(plan.scenario),
            "description": _info(scenario_info, "description"),
            "method": str(plan.method),
            "success": bool(plan.success),
            "failure": None if plan.failure is None else str(plan.failure),
            "planner_failure": diag.get("planner_failure"),
            "n_robots": int(np.asarray(plan.robots).shape[1]),
            "Ts": float(t[1] - t[0]) if t.size > 1 else None,
            "T_end": float(t[-1]),
            "n_samples": int(t.size),
            "anchor": np.asarray(plan.base, dtype=float).tolist(),
            "goal": np.asarray(plan.goal, dtype=float).tolist(),
            "bounds": np.asarray(plan.bounds, dtype=float).tolist(),
            "safety_radius": float(plan.safety_radius),
            "tether_clearance": teth.clearance,
            "rho": teth.mass_per_length,
            "g": teth.g,
            "tension_max": teth.spare_thrust,
            "tether_length_max": teth.tether_length,
            "winch_end": teth.winch_end,
            "winch_tension": teth.winch_tension,
            "tether": teth.as_dict() if hasattr(teth, "as_dict") else asdict(teth),
            **_winch_record(teth),
            "world": world,
            "scenario_file": None if source is None else Path(source).name,
            "scenario_text": _info(scenario_info, "text"),
            "summary": {k: m[k] for k in summary_keys if k in m},
            "params": {k: p[k] for k in sorted(p)},
            "files": {"trajectories": "trajectories.json", "metrics": "metrics.json"},
        }
    )


def write_drone_outputs(
    stage_dir: str | os.PathLike[str],
    plan: Any,
    metrics: Any,
    scenario_info: Any = None,
    *,
    extra: Mapping[str, Any] | None = None,
) -> list[str]:
    """Write trajectories.json, trajectories.csv, metrics.json, run.json and timings.json of a checked drone plan into
    ``stage_dir`` (a :class:`tmr.io.outdir.Stage`'s directory; stage it with ``owned`` including
    :data:`DRONE_OUTPUT_NAMES` and ``volatile`` :data:`DRONE_VOLATILE_NAMES`), and for a world with meshes a copy
    of its mesh files in :data:`DRONE_MESH_DIR`; return the names written, sorted.

    Raises:
        MapError: a mesh file of the world cannot be read (one line).

    ``extra`` (route, N_min, auto-count note: JSON-able) is added to metrics.json; keys ending in ``_time`` go to
    timings.json with the plan's ``wall_time``, the check's time and the median per-step time."""
    from tmr.errors import MapError
    from tmr.io.outputs import atomic_write_bytes, atomic_write_text, write_metrics_json

    out = Path(stage_dir)
    out.mkdir(parents=True, exist_ok=True)
    _, copies = world_meshes(_info(scenario_info, "world_table"), _mesh_base(scenario_info))
    for src, rel in copies:
        try:
            data = src.read_bytes()
        except OSError as exc:
            raise MapError(f"cannot copy the world's mesh {src} into the run ({exc.strerror or exc})") from None
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(out / rel, data)
    write_drone_trajectories_json(plan, out / "trajectories.json")
    write_drone_trajectories_csv(plan, out / "trajectories.csv")
    values = metrics.to_dict(per_step=False) if hasattr(metrics, "to_dict") else dict(metrics)
    ex = dict(extra or {})
    timings: dict[str, Any] = {"wall_time": float(getattr(plan, "wall_time", math.nan))}
    check_time = getattr(metrics, "check_time", None)
    if check_time is not None:
        timings["check_time"] = float(check_time)
    steps = np.asarray((getattr(plan, "diagnostics", None) or {}).get("step_time", []), dtype=float)
    steps = steps[np.isfinite(steps)]
    if steps.size:
        timings["step_time_median"] = float(statistics.median(steps.tolist()))
        timings["step_time_max"] = float(steps.max())
    timings |= {k: ex.pop(k) for k in sorted(ex) if k.endswith("_time")}
    write_metrics_json(values | ex, out / "metrics.json")
    atomic_write_text(out / "run.json", _dump(drone_run_dict(plan, metrics, scenario_info)))
    write_metrics_json(timings, out / "timings.json")
    return sorted(n for n in DRONE_OUTPUT_NAMES if n != DRONE_MESH_DIR or copies)


# ----------------------------------------------------------------------------------------------------------
# reader
# ----------------------------------------------------------------------------------------------------------
def _winch_record(teth: Any) -> dict[str, Any]:
    """run.json's active-winch fields: ``winch`` ("active"), ``winch_tension_range`` [T_min, T_max] [N],
    ``winch_tension_rate`` [N/s]; none for a constant-tension winch (its run.json keeps its bytes)."""
    if not getattr(teth, "active", False):
        return {}
    return {
        "winch": teth.winch,
        "winch_tension_range": [teth.winch_tension_min, teth.winch_tension_max],
        "winch_tension_rate": teth.winch_tension_rate,
    }


@dataclass(frozen=True)
class DroneRun:
    """A drone-chain run directory, read back (units: m, s, N).

    Attributes:
        path: the directory; record: ``run.json``; metrics: ``metrics.json`` (None if absent).
        t: (K+1,) [s]; robots, velocities: (K+1, N, 3) [m], [m/s]; reference: (K+1, 3) [m];
        tether_a: (K+1, N) [m], NaN for a vertical tether; base, goal: (3,) [m]; bounds: (6,) [m].
        winch_tension: (K+1, N) [N], an active winch's recorded tensions (None: constant).
    """

    path: Path
    record: dict[str, Any]
    t: Array
    robots: Array
    velocities: Array
    reference: Array
    tether_a: Array
    base: Array
    goal: Array
    bounds: Array
    metrics: dict[str, Any] | None = field(default=None)
    winch_tension: Array | None = field(default=None)

    kind = "drone"

    @property
    def n_robots(self) -> int:
        return int(self.robots.shape[1])

    @property
    def label(self) -> str:
        return f"scenario {self.record['scenario']}, {self.record['method']} (drones)"

    @property
    def safety_radius(self) -> float:
        return float(self.record["safety_radius"])

    @property
    def world_table(self) -> dict[str, Any] | None:
        """The scenario's ``[world]`` table as recorded (None if the run recorded none)."""
        return self.record.get("world")

    @property
    def world_dir(self) -> Path:
        """The folder the table's mesh paths are relative to: the run directory (its :data:`DRONE_MESH_DIR` holds
        the copies), or the absolute ``world_dir`` an older run recorded."""
        d = self.record.get("world_dir")
        return Path(d) if isinstance(d, str) and d and Path(d).is_absolute() else self.path

    def world(self) -> Any:
        """The run's :class:`tmr.world.world3d.World3D`, rebuilt from the recorded ``[world]`` table (RunDirError if
        the run recorded none or it no longer loads, e.g. a mesh file moved)."""
        from tmr.errors import TmrError
        from tmr.world.world3d import world3d_from_table

        if self.world_table is None:
            raise RunDirError(f"{self.path}: run.json records no world; re-run the planner")
        try:
            return world3d_from_table(self.world_table, self.world_dir, where=f"{self.path / 'run.json'} [world]")
        except TmrError as exc:
            raise RunDirError(f"{self.path}: the run's world does not load: {exc}") from None

    def tether_params(self) -> Any:
        """The plan's :class:`tmr.model.catenary3d.DroneTetherParams`."""
        from tmr.model.catenary3d import DroneTetherParams

        try:
            return DroneTetherParams(**self.record["tether"])
        except (TypeError, ValueError, KeyError, ParameterError) as exc:
            raise RunDirError(
                f"{self.path}: run.json tether parameters are malformed ({exc}); re-run the planner"
            ) from None

    def plan(self) -> Any:
        """The :class:`tmr.control.plan3d.DronePlan` the files hold (no diagnostics but the planner's own failure,
        no wall time, no joints)."""
        from tmr.control.plan3d import DronePlan

        rec = self.record
        return DronePlan(
            method=str(rec["method"]),
            scenario=str(rec["scenario"]),
            t=self.t.copy(),
            robots=self.robots.copy(),
            velocities=self.velocities.copy(),
            base=self.base.copy(),
            goal=self.goal.copy(),
            reference=self.reference.copy(),
            tether_a=self.tether_a.copy(),
            winch_tension=None if self.winch_tension is None else self.winch_tension.copy(),
            tether=self.tether_params(),
            safety_radius=self.safety_radius,
            bounds=self.bounds.copy(),
            success=bool(rec["success"]),
            failure=rec.get("failure"),
            diagnostics={"planner_failure": rec.get("planner_failure")},
            params=dict(rec.get("params") or {}),
        )

    def check(self, **kwargs: Any) -> Any:
        """Re-run :func:`tmr.checks.drones.check_drone_plan` on the recorded plan and world (the per-step series of
        the views); the recorded verdict is left as it is unless ``update_plan=True``."""
        from tmr.checks.drones import check_drone_plan

        if self.world_table is None:
            raise RunDirError(f"{self.path}: run.json records no world; re-run the planner")
        kwargs.setdefault("update_plan", False)
        return check_drone_plan(self.plan(), self.world_table, base_dir=self.world_dir, **kwargs)

    def motion(self, rate: float = 10.0, trajectory: str = "raw") -> Any:
        """The 2-D views' Motion does not exist for a 3-D run: :class:`RunDirError` (one line)."""
        raise RunDirError(f"{self.path} is a 3-D drone run: the planar replay and export do not read it")


def _array(doc: Any, where: str, what: str) -> Array:
    try:
        return np.array([np.nan if v is None else v for v in doc], dtype=float)
    except (TypeError, ValueError):
        raise RunDirError(f"{where}: trajectories.json {what} is not numeric; re-run the planner") from None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


#: Planner limits the checker reads from run.json's ``params`` (flat or under ``"planner"``).
_CHECKED_PARAMS = ("drone_speed_max", "drone_accel_max", "drone_jerk_max", "goal_tolerance")


def _validate_record(rec: dict[str, Any], where: str) -> None:
    """One-line :class:`RunDirError` for a run.json field of the wrong type (a corrupt or hand-edited file), so that
    no reader meets a ValueError later (module doc: the fields)."""

    def bad(key: str, what: str) -> RunDirError:
        shown = repr(rec[key])
        shown = shown if len(shown) <= 40 else shown[:37] + "..."
        return RunDirError(f"{where}: run.json {key} must be {what}, got {shown}; it is corrupt, re-run the planner")

    for key in ("scenario", "method"):
        if not isinstance(rec[key], str):
            raise bad(key, "a string")
    n = rec["n_robots"]
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise bad("n_robots", "a whole number >= 1")
    for key, size in (("anchor", 3), ("goal", 3), ("bounds", 6)):
        v = rec[key]
        if not isinstance(v, list) or len(v) != size or not all(_is_number(x) for x in v):
            raise bad(key, f"{size} finite numbers")
    b = rec["bounds"]
    if any(b[i + 3] <= b[i] for i in range(3)):
        raise bad("bounds", "xmin ymin zmin xmax ymax zmax with max > min")
    if not _is_number(rec["safety_radius"]) or rec["safety_radius"] < 0:
        raise bad("safety_radius", "a number of metres >= 0")
    if not isinstance(rec["tether"], Mapping):
        raise bad("tether", "a table of the tether parameters")
    if "success" in rec and not isinstance(rec["success"], bool):
        raise bad("success", "true or false")
    for key in ("failure", "planner_failure", "world_dir"):
        if rec.get(key) is not None and not isinstance(rec[key], str):
            raise bad(key, "a string or null")
    for key in ("world", "params"):
        if rec.get(key) is not None and not isinstance(rec[key], Mapping):
            raise bad(key, "a table or null")
    params = rec.get("params") or {}
    planner = params.get("planner")
    if planner is not None and not isinstance(planner, Mapping):
        raise RunDirError(f"{where}: run.json params.planner must be a table; it is corrupt, re-run the planner")
    for table, prefix in ((params, "params"), (planner or {}, "params.planner")):
        for name in _CHECKED_PARAMS:
            v = table.get(name)
            if v is not None and not (_is_number(v) and v > 0):
                raise RunDirError(
                    f"{where}: run.json {prefix}.{name} must be a positive number, got {v!r:.40}; it is corrupt, "
                    "re-run the planner"
                )


def load_drone_run(path: Path, rec: dict[str, Any], where: str) -> DroneRun:
    """Read a drone run directory whose ``run.json`` is ``rec`` (``kind = "drone"``): :class:`DroneRun`.

    Raises:
        RunDirError: a run.json field missing or of the wrong type, a missing or malformed trajectories.json, tether
            parameters that do not make a :class:`tmr.model.catenary3d.DroneTetherParams` (one line, says to re-run
            the planner).
    """
    for key in ("scenario", "method", "n_robots", "anchor", "goal", "bounds", "safety_radius", "tether"):
        if key not in rec:
            raise RunDirError(f"{where}: run.json lacks {key!r}; it is corrupt, re-run the planner")
    _validate_record(rec, where)
    traj = _read_json(Path(path) / "trajectories.json", where)
    if traj.get("format") != DRONE_TRAJECTORY_FORMAT:
        raise RunDirError(f"{where}: trajectories.json has format {traj.get('format')!r}; re-run the planner")
    n = int(rec["n_robots"])
    try:
        entries, tethers, ref = traj["robots"], traj["tethers"], traj["reference"]
        t = _array(entries[0]["t"], where, "t")
        robots = np.stack([np.column_stack([_array(e[c], where, c) for c in "xyz"]) for e in entries], axis=1)
        vel = np.stack([np.column_stack([_array(e[f"v{c}"], where, c) for c in "xyz"]) for e in entries], axis=1)
        reference = np.column_stack([_array(ref[c], where, "reference") for c in "xyz"])
        a = np.column_stack([_array(e["a"], where, "tether a") for e in tethers])
        has_tw = any("T_w" in e for e in tethers)
        tw = np.column_stack([_array(e["T_w"], where, "tether T_w") for e in tethers]) if has_tw else None
    except (KeyError, IndexError, TypeError, ValueError):
        raise RunDirError(f"{where}: trajectories.json is malformed; re-run the planner") from None
    k = t.size
    if robots.shape != (k, n, 3) or vel.shape != (k, n, 3) or reference.shape != (k, 3) or a.shape != (k, n):
        raise RunDirError(f"{where}: trajectories.json arrays do not match {n} drones x {k} samples; re-run it")
    if tw is not None and tw.shape != (k, n):
        raise RunDirError(f"{where}: trajectories.json winch tensions do not match {n} drones x {k} samples")
    metrics_path = Path(path) / "metrics.json"
    metrics = _read_json(metrics_path, where) if metrics_path.is_file() else None
    run = DroneRun(
        path=Path(path),
        record=rec,
        t=t,
        robots=robots,
        velocities=vel,
        reference=reference,
        tether_a=a,
        base=_array(rec["anchor"], where, "anchor"),
        goal=_array(rec["goal"], where, "goal"),
        bounds=_array(rec["bounds"], where, "bounds"),
        metrics=metrics,
        winch_tension=tw,
    )
    run.tether_params()  # RunDirError now, not when a view asks for it
    return run


register_kind("drone", load_drone_run)
