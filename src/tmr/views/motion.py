"""A plan as timed 3D geometry, the one input of every viewer and exporter (GIF, HTML, ROS 2 bag).

:class:`Motion` holds what moves (robots, bases, platform, agents, end-effector as :class:`Track`; tethers, cables
and links as :class:`Lines`) sampled at the plan's time stamps, and what stays (obstacles, room, anchor, goal, task
points). Each system turns its own plan into one:

* :func:`chain_motion` — a tethered chain (Caruso 2021): robots at the tether exit height H, tethers as catenaries
  (Caruso 2021 eq. 22, :func:`tmr.model.catenary.solve`) hanging between the anchor / robot exits, so their sag is real;
* :func:`tmr.mcdpr.motion.mcdpr_motion` — a MoPICK plan (Rasheed 2019): bases, point-mass platform, straight
  cables from each base's exit point A_k (Rasheed 2019 Fig. 1b) to the platform;
* :func:`tmr.ccma.motion.ccma_motion` — a CCMA run (Kumar 2019): agents, passive links, end-effector.

MoPICK and CCMA plans are sequences of samples without a time law; they are stamped at a constant ``rate`` [Hz]
(the stamps then say "sample k", not a physical time; the exporters say so).

Readers only: nothing here plans or checks anything, and nothing in the planners imports this module. A shared
module: it never imports a system package (the systems' builders live in them and import this one).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.errors import ParameterError

__all__ = [
    "DiffDrive",
    "Lines",
    "Motion",
    "Track",
    "catenary_polylines",
    "chain_motion",
    "tethered_chain",
]

Array = NDArray[np.float64]

#: Points per tether drawn along its catenary (ends included).
CATENARY_POINTS = 16
#: Height given to extruded obstacles in 3D views and markers [m].
OBSTACLE_HEIGHT = 1.0


@dataclass(frozen=True)
class Track:
    """A moving body: ``xyz`` (K, 3) positions [m] at the motion's stamps, ``yaw`` (K,) [rad] or None, ``radius``
    its drawn disc radius [m] (0 for a point), ``role`` one of robot, leader, base, platform, agent, end_effector."""

    name: str
    xyz: Array
    role: str
    radius: float = 0.0
    yaw: Array | None = None


@dataclass(frozen=True)
class DiffDrive:
    """The differential-drive state of a chain's robots (``--drive diff``, :mod:`tmr.model.diffdrive`) at the
    motion's stamps: ``axle`` (K, N, 2) the axle centres [m], ``theta`` (K, N) the headings [rad, continuous], ``v``
    (K, N) the forward speeds [m/s] and ``omega`` (K, N) the yaw rates [rad/s] commanded over [t_k, t_k+1] (0 at the
    last sample). Robot i is the track ``robot<i+1>``."""

    axle: Array
    theta: Array
    v: Array
    omega: Array


@dataclass(frozen=True)
class Lines:
    """A moving polyline (tether, cable or link): ``points`` (K, M, 3) [m]; ``sag`` (K,) its largest vertical
    distance below the chord [m] (catenary tethers), else None."""

    name: str
    points: Array
    kind: str
    sag: Array | None = None


@dataclass(frozen=True)
class Motion:
    """A plan as timed geometry.

    Attributes:
        system: "chain", "mcdpr" or "ccma".
        title: one line naming the plan (scenario, method, verdict).
        t: (K,) stamps [s], increasing.
        tracks: moving bodies, each sampled at ``t``.
        lines: moving polylines, each sampled at ``t``.
        obstacles: raw obstacle polygons (shapely) in the room (the tall ones).
        low_obstacles: :class:`tmr.world.environment.LowObstacle` s (``name``, ``footprint``, ``height`` [m]): the
            robots avoid them, a tether may pass over them; drawn lighter and hatched with their height.
        inflated: obstacles grown by the safety radius (shapely polygons), drawn as outlines; may be empty.
        bounds: room (xmin, ymin, xmax, ymax) [m].
        view: the part of the room the views frame (xmin, ymin, xmax, ymax) [m], or None for the whole room: the
            known free area of an occupancy map, often a small arena in a large unknown image (the plan and the
            fixed points are framed too).
        points: fixed named points (anchor, goal, task points), each (3,) [m].
        timed: False when ``t`` only counts samples (no time law in the plan).
        trail: name of the track whose trail the views draw (the leader), or None.
        notes: facts a viewer should state (e.g. the sag's scale).
    """

    system: str
    title: str
    t: Array
    tracks: tuple[Track, ...]
    lines: tuple[Lines, ...]
    obstacles: tuple[Any, ...]
    inflated: tuple[Any, ...]
    bounds: tuple[float, float, float, float]
    points: dict[str, Array] = field(default_factory=dict)
    view: tuple[float, float, float, float] | None = None
    timed: bool = True
    trail: str | None = None
    notes: tuple[str, ...] = ()
    low_obstacles: tuple[Any, ...] = ()
    #: a differential-drive chain's axle poses and commands (the ROS 2 bag's ``cmd_vel`` / ``odom``), else None
    diff_drive: DiffDrive | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ParameterError("Motion.t must be a non-empty, finite, strictly increasing (K,) array of stamps [s]")
        k = t.size
        for tr in self.tracks:
            if np.shape(tr.xyz) != (k, 3) or not np.all(np.isfinite(tr.xyz)):
                raise ParameterError(f"track {tr.name}: xyz must be finite with shape ({k}, 3), got {np.shape(tr.xyz)}")
        for ln in self.lines:
            shp = np.shape(ln.points)
            if len(shp) != 3 or shp[0] != k or shp[2] != 3 or shp[1] < 2 or not np.all(np.isfinite(ln.points)):
                raise ParameterError(f"line {ln.name}: points must be finite with shape ({k}, M >= 2, 3), got {shp}")
        dd = self.diff_drive
        if dd is not None:
            n = sum(1 for tr in self.tracks if tr.role in ("robot", "leader"))
            shapes = {"axle": (k, n, 2), "theta": (k, n), "v": (k, n), "omega": (k, n)}
            for key, shape in shapes.items():
                arr = getattr(dd, key)
                if np.shape(arr) != shape or not np.all(np.isfinite(arr)):
                    raise ParameterError(f"diff_drive.{key} must be finite with shape {shape}, got {np.shape(arr)}")

    def inflated_in_room(self) -> tuple[Any, ...]:
        """The grown obstacles cut to the room (the walls grown by r reach r beyond it), as polygons to draw."""
        from shapely.geometry import box

        room = box(*self.bounds)
        return tuple(q for p in self.inflated for q in _polygons(p.intersection(room)))

    @property
    def n_samples(self) -> int:
        return int(np.asarray(self.t).size)

    def track(self, name: str) -> Track:
        for tr in self.tracks:
            if tr.name == name:
                return tr
        raise KeyError(name)

    def extent(self, pad: float = 0.3) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) [m] framing the room, everything that moves and the fixed points."""
        pts = [np.asarray(tr.xyz)[:, :2] for tr in self.tracks] + [
            np.asarray(ln.points)[..., :2].reshape(-1, 2) for ln in self.lines
        ]
        pts += [np.asarray(p)[None, :2] for p in self.points.values()]
        x0, y0, x1, y1 = self.bounds if self.view is None else self.view
        allp = np.vstack(pts + [np.array([[x0, y0], [x1, y1]])])
        lo, hi = allp.min(axis=0) - pad, allp.max(axis=0) + pad
        if self.view is not None:  # a map's known area: never beyond the room
            b = self.bounds
            lo, hi = np.maximum(lo, [b[0] - pad, b[1] - pad]), np.minimum(hi, [b[2] + pad, b[3] + pad])
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _polygons(geom: Any) -> tuple[Any, ...]:
    if geom is None or geom.is_empty:
        return ()
    if geom.geom_type == "Polygon":
        return (geom,)
    if geom.geom_type in ("MultiPolygon", "GeometryCollection"):
        return tuple(p for g in geom.geoms for p in _polygons(g))
    return ()


def _room_parts(env: Any) -> tuple[tuple[Any, ...], tuple[Any, ...], tuple[float, float, float, float]]:
    """Raw and grown obstacle polygons of ``env`` in the order ``shapely.get_parts`` gives them (the order
    :mod:`tmr.io.rundir` records them in, so a motion rebuilt from a run directory is the same), and the room."""
    import shapely

    bounds = tuple(float(v) for v in env.bounds)
    parts = []
    for geom in (getattr(env, "tall_obstacles", getattr(env, "obstacles", None)), getattr(env, "inflated", None)):
        polys: list[Any] = []
        if geom is not None and not geom.is_empty:
            for part in shapely.get_parts(geom):
                polys.extend(_polygons(part))
        parts.append(tuple(polys))
    return parts[0], parts[1], bounds  # type: ignore[return-value]


def catenary_polylines(
    start: Array,
    end: Array,
    h_start: float,
    h_end: float,
    params: Any,
    n: int = CATENARY_POINTS,
    tension: Array | None = None,
) -> tuple[Array, Array]:
    """Tethers hanging between ``start`` and ``end`` (K, 2) [m] at heights ``h_start``, ``h_end`` [m]: points
    (K, n, 3) along the catenary of Caruso 2021 eq. 22 (:func:`tmr.model.catenary.solve` with ``params``, a
    :class:`tmr.model.catenary.CatenaryParams`) and the sag (K,) [m]. A span below 1 µm is drawn as a straight line
    (sag 0). ``tension`` (K,) [N]: an active winch's horizontal tension per sample, in place of ``params``' T0."""
    from tmr.model import catenary

    start = np.asarray(start, dtype=float)
    end = np.asarray(end, dtype=float)
    span = np.linalg.norm(end - start, axis=1)
    ok = span > 1e-6
    s = np.linspace(0.0, 1.0, n)
    xy = start[:, None, :] + (end - start)[:, None, :] * s[None, :, None]
    z = np.broadcast_to(h_start + (h_end - h_start) * s, (span.size, n)).copy()
    sag = np.zeros(span.size)
    tension = None if tension is None else np.asarray(tension, dtype=float)
    if np.any(ok):
        cat = catenary.solve(h_start, h_end, span[ok], params, tension=None if tension is None else tension[ok])
        _, zc = catenary.shape(cat, n)
        z[ok] = zc
        sag[ok] = np.asarray(cat.sag, dtype=float)
    return np.concatenate([xy, z[..., None]], axis=2), sag


def chain_motion(plan: Any, env: Any, chain_params: Any = None, title: str | None = None) -> Motion:
    """Motion of a tethered-chain plan (:class:`tmr.control.clik.Plan`) in ``env``
    (:class:`tmr.world.environment.Environment`).

    The tether parameters come from ``chain_params`` (:class:`tmr.model.params.ChainParams`), else from the plan's
    recorded ``params`` (the fields of ``ChainParams``), else the defaults (Caruso 2021 §4.2.1). See
    :func:`tethered_chain`.
    """
    from tmr.model.catenary import CatenaryParams
    from tmr.model.params import ChainParams

    if chain_params is None:
        names = {f for f in ChainParams.__dataclass_fields__}
        chain_params = ChainParams(**{k: v for k, v in (getattr(plan, "params", None) or {}).items() if k in names})
    cp = chain_params
    cat = CatenaryParams(
        horizontal_tension=cp.horizontal_tension,
        mass_per_length=cp.cable_mass_per_length,
        end_height=cp.exit_height,
        base_height=cp.base_height,
        ground_clearance=cp.ground_clearance,
    )
    obs, inf, bounds = _room_parts(env)
    n = int(np.asarray(plan.robots).shape[1])
    heading = getattr(plan, "heading", None)  # None for an omnidirectional plan
    verdict = "" if plan.success else " — FAILED"
    return tethered_chain(
        t=plan.t,
        robots=plan.robots,
        anchor=plan.base,
        goal=getattr(plan, "goal", None),
        radius=float(plan.safety_radius),
        cat=cat,
        obstacles=obs,
        inflated=inf,
        bounds=bounds,
        title=title or f"Scenario {plan.scenario}, {plan.method}: {n} tethered robots{verdict}",
        view=_known_view(env),
        low_obstacles=tuple(getattr(env, "low_obstacles", ())),
        tension=getattr(plan, "winch_tension", None),
        diff_drive=None
        if heading is None
        else DiffDrive(*(np.asarray(a, dtype=float) for a in (plan.axle, heading, plan.drive_v, plan.drive_omega))),
    )


def _known_view(env: Any) -> tuple[float, float, float, float] | None:
    """The known free area of an occupancy map (``env.known_free``, :mod:`tmr.world.maps`), else None."""
    known = getattr(env, "known_free", None)
    return None if known is None else (float(known[0]), float(known[1]), float(known[2]), float(known[3]))


def tethered_chain(
    t: Array,
    robots: Array,
    anchor: Array,
    goal: Array | None,
    radius: float,
    cat: Any,
    obstacles: tuple[Any, ...],
    inflated: tuple[Any, ...],
    bounds: tuple[float, float, float, float],
    title: str,
    view: tuple[float, float, float, float] | None = None,
    low_obstacles: tuple[Any, ...] = (),
    tension: Array | None = None,
    diff_drive: DiffDrive | None = None,
) -> Motion:
    """Motion of a tethered chain: ``robots`` (K, N, 2) [m] at stamps ``t`` (K,) [s], robot N the leader.

    ``diff_drive``: a differential-drive chain's axle poses and commands (``robots`` are then the tethers' exit
    points); each robot's track then carries its heading as ``yaw`` [rad].

    Robots stand at the tether exit height H (``cat.end_height``), the anchor at ``cat.base_height``; tether i hangs
    from robot i−1 (the anchor for i = 1) to robot i as the catenary of ``cat`` (a
    :class:`tmr.model.catenary.CatenaryParams`: T0, ρ, g; Caruso 2021 §4.2.1, eq. 22), or with an active winch at
    its planned horizontal tension ``tension`` (K, N) [N]. Robot disc radius ``radius`` [m].
    """
    t = np.asarray(t, dtype=float)
    robots = np.asarray(robots, dtype=float)
    k, n = robots.shape[:2]
    base = np.asarray(anchor, dtype=float)[:2]
    h = float(cat.end_height)
    tracks = []
    for i in range(n):
        xyz = np.column_stack([robots[:, i], np.full(k, h)])
        yaw = None if diff_drive is None else np.asarray(diff_drive.theta, dtype=float)[:, i]
        tracks.append(Track(f"robot{i + 1}", xyz, "leader" if i == n - 1 else "robot", radius=radius, yaw=yaw))
    lines = []
    prev, h_prev = np.broadcast_to(base, (k, 2)), float(cat.base_height)
    T = None if tension is None else np.asarray(tension, dtype=float).reshape(k, n)
    for i in range(n):
        pts, sag = catenary_polylines(prev, robots[:, i], h_prev, h, cat, tension=None if T is None else T[:, i])
        lines.append(Lines(f"tether{i + 1}", pts, "tether", sag=sag))
        prev, h_prev = robots[:, i], h
    points = {"anchor": np.array([base[0], base[1], float(cat.base_height)])}
    if goal is not None:
        points["goal"] = np.array([float(goal[0]), float(goal[1]), 0.0])
    return Motion(
        system="chain",
        title=title,
        t=t,
        tracks=tuple(tracks),
        lines=tuple(lines),
        obstacles=tuple(obstacles),
        inflated=tuple(inflated),
        bounds=bounds,
        points=points,
        view=view,
        trail=f"robot{n}",
        notes=(
            f"robot disc = safety radius {radius:g} m; tethers hang as catenaries ("
            + (
                f"T0 = {cat.horizontal_tension:g} N"
                if T is None
                else f"T0 = {T.min():.3g}–{T.max():.3g} N planned by the active winch"
            )
            + f", rho = {cat.mass_per_length:g} kg/m)",
        ),
        low_obstacles=tuple(low_obstacles),
        diff_drive=diff_drive,
    )


def sample_stamps(n: int, rate: float) -> Array:
    """Stamps k / rate [s] of ``n`` samples of a plan without a time law."""
    if not (np.isfinite(rate) and rate > 0):
        raise ParameterError(f"rate must be a finite number > 0 Hz, got {rate!r}")
    return np.arange(n, dtype=float) / float(rate)
