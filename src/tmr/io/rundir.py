"""The run directory record: ``run.json``, everything a reader needs to rebuild a plan's world.

``python -m tmr.plan`` writes trajectories and metrics; ``run.json`` (written next to them by the same command) adds
the scenario (anchor, goal, robot radius, number of robots), the map (room bounds, raw obstacles and obstacles grown
by the robot radius as polygons, coordinates written exactly), and every physical parameter the plan used (tether
exit and anchor heights, winch torque and pulley radius, horizontal tension T0 = torque / radius, mass per length,
g, catenary parameter c = T0 / (ρ g), every tether's span limits [d_lo, d_max]; Caruso 2021 §4.2.1, eq. 22), the
sampling period Ts and the method. ``python -m tmr.mcdpr plan`` writes one too (robot, scene, external wrench).

Readers (``tmr.replay``, ``tmr.export``) call :func:`load_run`, which returns a typed :class:`ChainRun` or
:class:`tmr.mcdpr.rundir.McdprRun` with the trajectories as numpy arrays, or raises :class:`RunDirError` with a
one-line message for a missing, older or corrupt directory. It dispatches on the run's ``kind`` through a small
registry (:func:`register_kind`): each system writes and reads its own section (``tmr.mcdpr.rundir``), and this
shared module never imports a system package.

The file is deterministic: same plan, same bytes (key order fixed, floats in shortest round-trip form, no
timings).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import import_module
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.errors import TmrError

__all__ = [
    "KIND_MODULES",
    "RUN_FORMAT",
    "ChainRun",
    "RunDirError",
    "chain_run_dict",
    "load_run",
    "polygons_from_json",
    "polygons_to_json",
    "register_kind",
    "run_loader",
    "write_chain_run",
]

#: Value of the ``format`` key of ``run.json``; bump the number when a field changes meaning or disappears.
RUN_FORMAT = "tmr-run/1"

Array = NDArray[np.float64]


class RunDirError(TmrError):
    """A run directory cannot be read: missing, written by an older tmr, or corrupt (one-line message)."""


# ----------------------------------------------------------------------------------------------------------
# geometry <-> JSON
# ----------------------------------------------------------------------------------------------------------
def _ring(coords: Any) -> list[list[float]]:
    return [[float(x), float(y)] for x, y, *_ in coords]


def _known_free(env: Any) -> dict[str, list[float]]:
    """``{"known_free": [xmin, ymin, xmax, ymax]}`` for an occupancy map, else {} (other runs' bytes unchanged)."""
    known = getattr(env, "known_free", None)
    return {} if known is None else {"known_free": [float(v) for v in known]}


def _low_obstacles(env: Any) -> dict[str, list[dict[str, Any]]]:
    """``{"low_obstacles": [{"name", "height" [m], "polygons"}, ...]}`` for a world with low obstacles
    (:class:`tmr.world.environment.LowObstacle`; ``obstacles`` then holds the tall ones only), else {} (other runs'
    bytes unchanged)."""
    lows = getattr(env, "low_obstacles", ())
    if not lows:
        return {}
    return {
        "low_obstacles": [
            {"name": str(o.name), "height": float(o.height), "polygons": polygons_to_json(o.footprint)} for o in lows
        ]
    }


def low_obstacles_from_json(items: Any, where: str = "run.json") -> list[Any]:
    """:class:`tmr.world.environment.LowObstacle` s from run.json's ``map.low_obstacles``; RunDirError if malformed."""
    import shapely

    from tmr.errors import TmrError
    from tmr.world.environment import LowObstacle

    out = []
    try:
        for it in items:
            polys = polygons_from_json(it["polygons"], where)
            fp = polys[0] if len(polys) == 1 else shapely.MultiPolygon(polys)
            out.append(LowObstacle(str(it["name"]), fp, float(it["height"])))
    except (TypeError, KeyError, ValueError, TmrError) as exc:
        raise RunDirError(f"{where}: malformed low obstacles ({exc}); re-run the planner") from None
    return out


def polygons_to_json(geom: Any) -> list[dict[str, Any]]:
    """Polygons of a shapely geometry as ``[{"exterior": [[x, y], ...], "holes": [[[x, y], ...], ...]}, ...]``.

    Coordinates are copied exactly (JSON floats round-trip); lines and points (zero-area obstacles) are skipped.
    """
    import shapely

    if geom is None or geom.is_empty:
        return []
    out = []
    for part in shapely.get_parts(geom):
        if part.geom_type == "Polygon":
            out.append({"exterior": _ring(part.exterior.coords), "holes": [_ring(r.coords) for r in part.interiors]})
        elif part.geom_type in ("MultiPolygon", "GeometryCollection"):
            out.extend(polygons_to_json(part))
    return out


def polygons_from_json(items: Any, where: str = "run.json") -> list[Any]:
    """shapely Polygons from :func:`polygons_to_json`'s list; RunDirError if the list is malformed."""
    from shapely.geometry import Polygon

    try:
        polys = [Polygon(it["exterior"], it.get("holes", [])) for it in items]
    except (TypeError, KeyError, ValueError, AttributeError) as exc:
        raise RunDirError(f"{where}: malformed obstacle polygons ({exc}); re-run the planner") from None
    return polys


# ----------------------------------------------------------------------------------------------------------
# writers
# ----------------------------------------------------------------------------------------------------------
def _safe(x: Any) -> Any:
    """JSON-ready copy: numpy -> Python, non-finite floats -> "inf"/"-inf"/"nan" strings."""
    if isinstance(x, dict):
        return {str(k): _safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return _safe(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(x, Path):
        return str(x)
    return x


def _version() -> str:
    from tmr import __version__

    return str(__version__)


def _dump(doc: dict[str, Any]) -> str:
    """Readable JSON: one key a line, [x, y] pairs and lists of numbers on one line (``tmr.io.outputs``'s layout)."""
    from tmr.io.outputs import _dumps_readable

    return _dumps_readable(_safe(doc)) + "\n"


def chain_run_dict(plan: Any, env: Any, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``run.json`` document of a tethered-chain plan (format :data:`RUN_FORMAT`, ``kind = "chain"``).

    Args:
        plan: a :class:`tmr.control.clik.Plan` (its ``params`` are ``Problem.params_dict()``: every parameter used).
        env: the plan's :class:`tmr.world.environment.Environment`.
        extra: what ``metrics.json`` records beyond the metrics (route, n_min, ...); copied under ``"route"``.
    """
    from tmr.model.catenary import CatenaryParams

    p = dict(plan.params or {})
    chain_keys = ("exit_height", "base_height", "pulley_torque", "pulley_radius", "cable_mass_per_length")
    missing = [k for k in chain_keys + ("Ts",) if k not in p]
    if missing:
        raise RunDirError(f"plan.params lacks {missing}: cannot record the run")
    cat = CatenaryParams.from_pulley(
        p["pulley_torque"],
        p["pulley_radius"],
        mass_per_length=p["cable_mass_per_length"],
        end_height=p["exit_height"],
        base_height=p["base_height"],
        ground_clearance=p.get("ground_clearance", 0.0),
    )
    limits = np.asarray(plan.span_limits, dtype=float)
    robots = np.asarray(plan.robots)
    tether = {
        "exit_height": cat.end_height,
        "anchor_height": cat.base_height,
        "winch_torque": p["pulley_torque"],
        "pulley_radius": p["pulley_radius"],
        "horizontal_tension": cat.horizontal_tension,
        "mass_per_length": cat.mass_per_length,
        "g": cat.g,
        "catenary_c": cat.c,
        "ground_clearance": cat.ground_clearance,
        "d_lo": limits[:, 0].tolist(),
        "d_max": limits[:, 1].tolist(),
    }
    if p.get("winch") == "active":  # the tension is planned (trajectories.json "tethers"); d_max is T_max's reach
        tether.update({k: p[k] for k in ("winch", "winch_tension_min", "winch_tension_max", "winch_tension_rate")})
    if p.get("sag_allowance"):  # the planner's d_max keeps the cable this much above ground_clearance
        tether["sag_allowance"] = p["sag_allowance"]
    ex = dict(extra or {})
    return {
        "format": RUN_FORMAT,
        "kind": "chain",
        "tmr_version": _version(),
        "scenario": str(plan.scenario),
        "method": str(plan.method),
        "success": bool(plan.success),
        "failure": None if plan.failure is None else str(plan.failure),
        "n_robots": int(robots.shape[1]),
        "Ts": float(p["Ts"]),
        "T_end": float(np.asarray(plan.t)[-1]),
        "n_samples": int(robots.shape[0]),
        "anchor": np.asarray(plan.base, dtype=float)[:2].tolist(),
        "goal": None if plan.goal is None else np.asarray(plan.goal, dtype=float)[:2].tolist(),
        "robot_radius": float(plan.safety_radius),
        "map": {
            "bounds": [float(v) for v in env.bounds],
            "safety_radius": float(env.safety_radius),
            "resolution": float(env.resolution),
            "source": None if env.source is None else Path(env.source).name,
            "obstacles": polygons_to_json(getattr(env, "tall_obstacles", env.obstacles)),
            "grown": polygons_to_json(env.inflated),
            **_known_free(env),
            **_low_obstacles(env),
        },
        "tether": tether,
        "route": {
            k: ex[k]
            for k in sorted(ex)
            if k in ("route", "route_length", "n_min", "n_lower", "n_lower_by", "n_route", "robots_auto")
        },
        "params": {k: p[k] for k in sorted(p)},
        "files": {"trajectories": "trajectories.json", "metrics": "metrics.json"},
    }


def write_chain_run(path: str | os.PathLike[str], plan: Any, env: Any, extra: dict[str, Any] | None = None) -> Path:
    """Write :func:`chain_run_dict` to ``path`` (atomic, deterministic bytes)."""
    from tmr.io.outputs import atomic_write_text

    return atomic_write_text(path, _dump(chain_run_dict(plan, env, extra)))


# ----------------------------------------------------------------------------------------------------------
# loader
# ----------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ChainRun:
    """A tethered-chain run directory, read back (units: m, s, N, kg).

    Attributes:
        path: the directory.
        record: ``run.json`` as a dict (see :func:`chain_run_dict` for the keys).
        t: (K+1,) sample times [s].
        robots: (K+1, N, 2) raw planned positions [m], robot 1 next to the anchor, robot N the leader.
        filtered: (K+1, N, 2) low-passed positions the robots track [m] (= ``robots`` if the file has none).
        anchor: (2,) tether anchor [m]; goal: (2,) or None.
        obstacles, grown: raw obstacle polygons and obstacles grown by the robot radius (shapely Polygons); the
            raw ones are the tall obstacles, the grown ones include the low obstacles (the robots avoid them).
        low_obstacles: :class:`tmr.world.environment.LowObstacle` s (bare footprint, height [m]); empty for most maps.
    """

    path: Path
    record: dict[str, Any]
    t: Array
    robots: Array
    filtered: Array
    anchor: Array
    goal: Array | None
    obstacles: list[Any] = field(default_factory=list)
    grown: list[Any] = field(default_factory=list)
    #: with an active winch, every tether's planned horizontal tension per sample (K+1, N) [N]; None: constant T0
    winch_tension: Array | None = None
    low_obstacles: list[Any] = field(default_factory=list)
    #: a differential-drive run (``"drive": "diff"`` in trajectories.json): ``axle`` (K+1, N, 2) [m], ``theta``
    #: [rad], ``v`` [m/s], ``omega`` [rad/s] (K+1, N) each; None for an omnidirectional run
    diff_drive: dict[str, Array] | None = None

    kind = "chain"

    @property
    def n_robots(self) -> int:
        return int(self.robots.shape[1])

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        b = self.record["map"]["bounds"]
        return (float(b[0]), float(b[1]), float(b[2]), float(b[3]))

    @property
    def known_free(self) -> tuple[float, float, float, float] | None:
        """Bounding box of an occupancy map's known free cells [m] (``tmr.world.maps``), or None for other maps."""
        b = self.record["map"].get("known_free")
        return None if b is None else (float(b[0]), float(b[1]), float(b[2]), float(b[3]))

    @property
    def robot_radius(self) -> float:
        return float(self.record["robot_radius"])

    @property
    def tether(self) -> dict[str, Any]:
        return dict(self.record["tether"])

    @property
    def label(self) -> str:
        return f"scenario {self.record['scenario']}, {self.record['method']}"

    def environment(self) -> Any:
        """The plan's :class:`tmr.world.environment.Environment`, rebuilt from the raw polygons (same grown
        obstacles)."""
        from tmr.world.environment import Environment

        m = self.record["map"]
        return Environment(
            self.obstacles, m["bounds"], m["safety_radius"], m["resolution"], low_obstacles=self.low_obstacles
        )

    def catenary_params(self) -> Any:
        """:class:`tmr.model.catenary.CatenaryParams` of the plan's tethers."""
        from tmr.model.catenary import CatenaryParams

        t = self.record["tether"]
        return CatenaryParams(
            horizontal_tension=t["horizontal_tension"],
            mass_per_length=t["mass_per_length"],
            g=t["g"],
            end_height=t["exit_height"],
            base_height=t["anchor_height"],
            ground_clearance=t["ground_clearance"],
        )

    def motion(self, rate: float = 10.0, trajectory: str = "raw") -> Any:
        """The :class:`tmr.views.motion.Motion` of the run: ``trajectory`` ``"raw"`` (the checked plan) or
        ``"filtered"`` (the low-passed positions the robots track); ``rate`` is unused (the plan has a time law)."""
        from tmr.views.motion import DiffDrive, tethered_chain

        rec = self.record
        dd = self.diff_drive
        if dd is not None and trajectory == "filtered":
            raise RunDirError(
                f"--trajectory filtered: {self.path} is a differential-drive plan, which is not filtered (its robots "
                "execute cmd_vel/robotK.csv, whose poses are the checked plan): use --trajectory raw"
            )
        robots = self.filtered if trajectory == "filtered" else self.robots
        verdict = "" if rec.get("success", True) else " — FAILED"
        what = "filtered trajectory" if trajectory == "filtered" else f"{self.n_robots} tethered robots"
        return tethered_chain(
            t=self.t,
            robots=robots,
            anchor=self.anchor,
            goal=self.goal,
            radius=self.robot_radius,
            cat=self.catenary_params(),
            obstacles=tuple(self.obstacles),
            inflated=tuple(self.grown),
            bounds=self.bounds,
            title=f"Scenario {rec['scenario']}, {rec['method']}: {what}{verdict}",
            view=self.known_free,
            low_obstacles=tuple(self.low_obstacles),
            tension=self.winch_tension,  # the planned tension per sample (filtered positions too: same stamps)
            diff_drive=None if dd is None else DiffDrive(dd["axle"], dd["theta"], dd["v"], dd["omega"]),
        )


def _read_json(path: Path, where: str) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RunDirError(f"{where}: cannot read {path.name} ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RunDirError(f"{where}: {path.name} is not valid JSON ({exc}); re-run the planner") from None
    except RecursionError:  # [[[[... nested deeper than the parser's stack
        raise RunDirError(f"{where}: {path.name} is nested too deeply to be a tmr file; re-run the planner") from None
    if not isinstance(doc, dict):
        raise RunDirError(f"{where}: {path.name} is not a JSON object; re-run the planner")
    return doc


def _floats(value: Any, where: str, what: str) -> Array:
    try:
        arr = np.array([np.nan if v is None else v for v in value] if isinstance(value, list) else value, dtype=float)
    except (TypeError, ValueError):
        raise RunDirError(f"{where}: {what} is not numeric; re-run the planner") from None
    return arr


def _positions(entries: Any, n: int, k: int, where: str, what: str) -> Array:
    try:  # a differential-drive run: x, y are the axle centres, the chain's points are the tethers' exit points
        keys = ("exit_x", "exit_y") if entries and "exit_x" in entries[0] else ("x", "y")
        out = np.stack([np.column_stack([e[keys[0]], e[keys[1]]]) for e in entries], axis=1).astype(float)
    except (TypeError, KeyError, ValueError):
        raise RunDirError(f"{where}: trajectories.json {what} are malformed; re-run tmr.plan") from None
    if out.shape != (k, n, 2) or not np.all(np.isfinite(out)):
        raise RunDirError(f"{where}: trajectories.json {what} have shape {out.shape}, expected ({k}, {n}, 2)")
    return out


def _load_chain(path: Path, rec: dict[str, Any], where: str) -> ChainRun:
    for key in ("map", "tether", "anchor", "robot_radius", "Ts", "n_robots", "scenario", "method"):
        if key not in rec:
            raise RunDirError(f"{where}: run.json lacks {key!r}; it is corrupt, re-run tmr.plan")
    traj = _read_json(path / "trajectories.json", where)
    if traj.get("format") != "tmr-trajectories/1":
        raise RunDirError(f"{where}: trajectories.json has format {traj.get('format')!r}; re-run tmr.plan")
    n = int(rec["n_robots"])
    try:
        t = np.asarray(traj["robots"][0]["t"], dtype=float)
    except (KeyError, IndexError, TypeError, ValueError):
        raise RunDirError(f"{where}: trajectories.json has no robot samples; re-run tmr.plan") from None
    robots = _positions(traj.get("robots"), n, t.size, where, "robots")
    filtered = _positions(traj["filtered"], n, t.size, where, "filtered") if "filtered" in traj else robots
    m = rec["map"]
    goal = rec.get("goal")
    tension = None
    if rec["tether"].get("winch") == "active" and "tethers" not in traj:
        raise RunDirError(f"{where}: an active winch's run without its planned tensions (trajectories.json 'tethers')")
    if "tethers" in traj:
        try:
            tension = np.array([np.asarray(e["horizontal_tension"], dtype=float) for e in traj["tethers"]]).T
        except (KeyError, TypeError, ValueError):
            raise RunDirError(f"{where}: trajectories.json has unreadable tether tensions; re-run tmr.plan") from None
        if tension.shape != (t.size, n) or not np.all(np.isfinite(tension)) or np.any(tension <= 0):
            raise RunDirError(f"{where}: trajectories.json's tether tensions are not ({t.size}, {n}) finite > 0 N")
    diff = _diff_drive(traj.get("robots"), n, t.size, where) if traj.get("drive") == "diff" else None
    return ChainRun(
        path=path,
        record=rec,
        t=t,
        robots=robots,
        filtered=filtered,
        anchor=_floats(rec["anchor"], where, "anchor"),
        goal=None if goal is None else _floats(goal, where, "goal"),
        obstacles=polygons_from_json(m.get("obstacles", []), where),
        grown=polygons_from_json(m.get("grown", []), where),
        winch_tension=tension,
        low_obstacles=low_obstacles_from_json(m.get("low_obstacles", []), where),
        diff_drive=diff,
    )


def _diff_drive(entries: Any, n: int, k: int, where: str) -> dict[str, Array]:
    """A differential-drive run's ``axle`` (k, n, 2) [m], ``theta`` [rad], ``v`` [m/s], ``omega`` [rad/s] (k, n) from
    trajectories.json's robot entries (keys ``x``, ``y``, ``theta``, ``v``, ``omega``)."""
    try:
        cols = {key: np.array([e[key] for e in entries], dtype=float).T for key in ("x", "y", "theta", "v", "omega")}
    except (TypeError, KeyError, ValueError):
        raise RunDirError(f"{where}: trajectories.json's robot poses are malformed; re-run tmr.plan") from None
    for key, arr in cols.items():
        if arr.shape != (k, n) or not np.all(np.isfinite(arr)):
            raise RunDirError(f"{where}: trajectories.json's robot {key} have shape {arr.shape}, expected ({k}, {n})")
    return {"axle": np.stack([cols["x"], cols["y"]], axis=-1), **{key: cols[key] for key in ("theta", "v", "omega")}}


# ----------------------------------------------------------------------------------------------------------
# kinds: each system reads its own run.json section
# ----------------------------------------------------------------------------------------------------------
#: ``loader(path, record, where) -> run``: reads the rest of a run directory whose ``run.json`` (``record``, already
#: checked for :data:`RUN_FORMAT`) has that ``kind``; the run has ``kind``, ``label`` and ``motion(rate, trajectory)``.
RunLoader = Callable[[Path, dict[str, Any], str], Any]

_LOADERS: dict[str, RunLoader] = {}
#: Module that registers a system's kind when imported: imported on the first read of that kind, so this shared
#: module never imports a system package (data flows one way: the systems know the run files, not the reverse).
KIND_MODULES: dict[str, str] = {"mcdpr": "tmr.mcdpr.rundir", "drone": "tmr.io.drones"}


def register_kind(kind: str, loader: RunLoader) -> None:
    """Make :func:`load_run` read ``run.json`` files of ``kind`` with ``loader`` (a system's own reader)."""
    _LOADERS[kind] = loader


def run_loader(kind: str) -> RunLoader | None:
    """The loader registered for ``kind`` (importing its system's module of :data:`KIND_MODULES` first), or None."""
    if kind not in _LOADERS and kind in KIND_MODULES:
        import_module(KIND_MODULES[kind])
    return _LOADERS.get(kind)


def load_run(path: str | os.PathLike[str]) -> Any:
    """Read a ``tmr.plan`` or ``tmr.mcdpr plan`` output directory: a :class:`ChainRun`, a
    :class:`tmr.mcdpr.rundir.McdprRun`, or the run of any kind registered with :func:`register_kind`.

    Raises:
        RunDirError: the directory does not exist, has no ``run.json`` (written by an older tmr), has a
            ``run.json`` of another format version, or its files are corrupt. The message is one line and says
            what to do.
    """
    p = Path(path)
    where = str(path)
    if not p.exists():
        raise RunDirError(f"{where} does not exist: give the --out directory of tmr.plan or tmr.mcdpr plan")
    if not p.is_dir():
        raise RunDirError(f"{where} is not a directory: give the --out directory of tmr.plan or tmr.mcdpr plan")
    from tmr.io.outdir import is_complete

    if not is_complete(p):
        raise RunDirError(f"{where} was being written when its run was stopped (its files may mix two runs); rerun it")
    if not (p / "run.json").is_file():
        hint = "re-run tmr.mcdpr plan" if (p / "plan.json").is_file() else "re-run tmr.plan"
        if not any((p / n).is_file() for n in ("trajectories.json", "plan.json")):
            raise RunDirError(f"{where} has no run.json and is not a tmr run directory (no trajectories.json)")
        raise RunDirError(f"{where} has no run.json: it was written by an older tmr; {hint}")
    rec = _read_json(p / "run.json", where)
    fmt = rec.get("format")
    if fmt != RUN_FORMAT:
        raise RunDirError(f"{where}/run.json has format {fmt!r}, this tmr reads {RUN_FORMAT!r}; re-run the planner")
    kind = rec.get("kind")
    loader = run_loader(kind) if isinstance(kind, str) else None
    if loader is None:
        raise RunDirError(f"{where}/run.json has unknown kind {kind!r}; re-run the planner")
    return loader(p, rec, where)


register_kind("chain", _load_chain)
