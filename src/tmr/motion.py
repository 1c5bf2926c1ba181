"""A plan as timed 3D geometry, the one input of every viewer and exporter (GIF, HTML, ROS 2 bag).

:class:`Motion` holds what moves (robots, bases, platform, agents, end-effector as :class:`Track`; tethers, cables
and links as :class:`Lines`) sampled at the plan's time stamps, and what stays (obstacles, room, anchor, goal, task
points). Three builders turn a plan of each system into one:

* :func:`chain_motion` — a tethered chain (Caruso 2021): robots at the tether exit height H, tethers as catenaries
  (Caruso 2021 eq. 22, :func:`tmr.catenary.solve`) hanging between the anchor / robot exits, so their sag is real;
* :func:`mcdpr_motion` — a MoPICK plan (Rasheed 2019): bases, point-mass platform, straight cables from each base's
  exit point A_k (Rasheed 2019 Fig. 1b) to the platform;
* :func:`ccma_motion` — a CCMA run (Kumar 2019): agents, passive links, end-effector.

MoPICK and CCMA plans are sequences of samples without a time law; they are stamped at a constant ``rate`` [Hz]
(the stamps then say "sample k", not a physical time; the exporters say so).

Readers only: nothing here plans or checks anything, and nothing in the planners imports this module.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.errors import ParameterError

__all__ = [
    "Lines",
    "Motion",
    "Track",
    "catenary_polylines",
    "ccma_motion",
    "ccma_track_motion",
    "chain_motion",
    "mcdpr_motion",
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
        obstacles: raw obstacle polygons (shapely) in the room.
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
    :mod:`tmr.rundir` records them in, so a motion rebuilt from a run directory is the same), and the room."""
    import shapely

    bounds = tuple(float(v) for v in env.bounds)
    parts = []
    for geom in (getattr(env, "obstacles", None), getattr(env, "inflated", None)):
        polys: list[Any] = []
        if geom is not None and not geom.is_empty:
            for part in shapely.get_parts(geom):
                polys.extend(_polygons(part))
        parts.append(tuple(polys))
    return parts[0], parts[1], bounds  # type: ignore[return-value]


def catenary_polylines(
    start: Array, end: Array, h_start: float, h_end: float, params: Any, n: int = CATENARY_POINTS
) -> tuple[Array, Array]:
    """Tethers hanging between ``start`` and ``end`` (K, 2) [m] at heights ``h_start``, ``h_end`` [m]: points
    (K, n, 3) along the catenary of Caruso 2021 eq. 22 (:func:`tmr.catenary.solve` with ``params``, a
    :class:`tmr.catenary.CatenaryParams`) and the sag (K,) [m]. A span below 1 µm is drawn as a straight line
    (sag 0)."""
    from tmr import catenary

    start = np.asarray(start, dtype=float)
    end = np.asarray(end, dtype=float)
    span = np.linalg.norm(end - start, axis=1)
    ok = span > 1e-6
    s = np.linspace(0.0, 1.0, n)
    xy = start[:, None, :] + (end - start)[:, None, :] * s[None, :, None]
    z = np.broadcast_to(h_start + (h_end - h_start) * s, (span.size, n)).copy()
    sag = np.zeros(span.size)
    if np.any(ok):
        cat = catenary.solve(h_start, h_end, span[ok], params)
        _, zc = catenary.shape(cat, n)
        z[ok] = zc
        sag[ok] = np.asarray(cat.sag, dtype=float)
    return np.concatenate([xy, z[..., None]], axis=2), sag


def chain_motion(plan: Any, env: Any, chain_params: Any = None, title: str | None = None) -> Motion:
    """Motion of a tethered-chain plan (:class:`tmr.clik.Plan`) in ``env`` (:class:`tmr.environment.Environment`).

    The tether parameters come from ``chain_params`` (:class:`tmr.params.ChainParams`), else from the plan's
    recorded ``params`` (the fields of ``ChainParams``), else the defaults (Caruso 2021 §4.2.1). See
    :func:`tethered_chain`.
    """
    from tmr.catenary import CatenaryParams
    from tmr.params import ChainParams

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
    )


def _known_view(env: Any) -> tuple[float, float, float, float] | None:
    """The known free area of an occupancy map (``env.known_free``, :mod:`tmr.maps`), else None."""
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
) -> Motion:
    """Motion of a tethered chain: ``robots`` (K, N, 2) [m] at stamps ``t`` (K,) [s], robot N the leader.

    Robots stand at the tether exit height H (``cat.end_height``), the anchor at ``cat.base_height``; tether i hangs
    from robot i−1 (the anchor for i = 1) to robot i as the catenary of ``cat`` (a
    :class:`tmr.catenary.CatenaryParams`: T0, ρ, g; Caruso 2021 §4.2.1, eq. 22). Robot disc radius ``radius`` [m].
    """
    t = np.asarray(t, dtype=float)
    robots = np.asarray(robots, dtype=float)
    k, n = robots.shape[:2]
    base = np.asarray(anchor, dtype=float)[:2]
    h = float(cat.end_height)
    tracks = []
    for i in range(n):
        xyz = np.column_stack([robots[:, i], np.full(k, h)])
        tracks.append(Track(f"robot{i + 1}", xyz, "leader" if i == n - 1 else "robot", radius=radius))
    lines = []
    prev, h_prev = np.broadcast_to(base, (k, 2)), float(cat.base_height)
    for i in range(n):
        pts, sag = catenary_polylines(prev, robots[:, i], h_prev, h, cat)
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
            f"robot disc = safety radius {radius:g} m; tethers hang as catenaries (T0 = {cat.horizontal_tension:g} N, "
            f"rho = {cat.mass_per_length:g} kg/m)",
        ),
    )


def sample_stamps(n: int, rate: float) -> Array:
    """Stamps k / rate [s] of ``n`` samples of a plan without a time law."""
    if not (np.isfinite(rate) and rate > 0):
        raise ParameterError(f"rate must be a finite number > 0 Hz, got {rate!r}")
    return np.arange(n, dtype=float) / float(rate)


def mcdpr_motion(robot: Any, scene: Any, result: Any, rate: float = 10.0, title: str | None = None) -> Motion:
    """Motion of a MoPICK plan (:class:`tmr.mcdpr.planner.Plan`) for ``robot`` in ``scene``.

    Bases on the floor (radius r_mb, heading = the plan's), the point-mass platform, and cable k as the straight
    segment from its exit point A_k (``robot.exit_points[k]`` in the frame of base ``robot.cable_base[k]``, rotated
    by the base heading) to the platform (Rasheed 2019 sec. 2: massless straight cables). Samples stamped k / rate.
    """
    bases = np.asarray(result.bases, dtype=float)
    heads = np.asarray(result.headings, dtype=float)
    plat = np.asarray(result.platform, dtype=float)
    k, p = bases.shape[:2]
    tracks = [
        Track(
            f"base{j + 1}", np.column_stack([bases[:, j], np.zeros(k)]), "base", float(robot.base_radius), heads[:, j]
        )
        for j in range(p)
    ]
    tracks.append(Track("platform", plat, "platform", radius=0.08))
    lines = []
    for c, (b, a) in enumerate(zip(robot.cable_base, np.asarray(robot.exit_points, dtype=float), strict=True)):
        cs, sn = np.cos(heads[:, b]), np.sin(heads[:, b])
        exit_xyz = np.column_stack([bases[:, b, 0] + cs * a[0] - sn * a[1], bases[:, b, 1] + sn * a[0] + cs * a[1]])
        exit_xyz = np.column_stack([exit_xyz, np.full(k, a[2])])
        lines.append(Lines(f"cable{c + 1}", np.stack([exit_xyz, plat], axis=1), "cable"))
    env = scene.environment(robot)
    obs, inf, bounds = _room_parts(env)
    points = {f"task{i + 1}": np.asarray(tp, dtype=float) for i, tp in enumerate(np.asarray(scene.tasks))}
    return Motion(
        system="mcdpr",
        title=title or f"MoPICK scene {scene.name}: {p} bases, {len(lines)} cables",
        t=sample_stamps(k, rate),
        tracks=tuple(tracks),
        lines=tuple(lines),
        obstacles=obs,
        inflated=inf,
        bounds=bounds,
        points=points,
        timed=False,
        trail="platform",
        notes=(f"samples stamped at {rate:g} Hz (the plan has no time law)",),
    )


def ccma_motion(
    name: str,
    agent_names: list[str],
    agents: Array,
    agent_height: float,
    ee: Array,
    links: list[Array],
    bounds: tuple[float, float, float, float] | None = None,
    rate: float = 10.0,
    title: str | None = None,
) -> Motion:
    """Motion of a CCMA run (Kumar 2019): ``agents`` (K, n_a, 3) x, y [m], yaw [rad] at ``agent_height`` [m];
    ``ee`` (K, 3) end-effector [m]; ``links`` one (K, M, 3) polyline per passive body through its joint points
    (:func:`tmr.ccma.plot.body_segments`). No room: ``bounds`` default to the motion's extent. Stamped k / rate."""
    agents = np.asarray(agents, dtype=float)
    ee = np.asarray(ee, dtype=float)
    k = agents.shape[0]
    tracks = [
        Track(nm, np.column_stack([agents[:, j, :2], np.full(k, agent_height)]), "agent", 0.06, agents[:, j, 2])
        for j, nm in enumerate(agent_names)
    ]
    tracks.append(Track("end_effector", ee, "end_effector", radius=0.0))
    lines = tuple(Lines(f"link{i + 1}", np.asarray(seg, dtype=float), "link") for i, seg in enumerate(links))
    if bounds is None:
        allp = np.vstack(
            [agents[..., :2].reshape(-1, 2), ee[:, :2]] + [ln.points[..., :2].reshape(-1, 2) for ln in lines]
        )
        lo, hi = allp.min(axis=0) - 0.15, allp.max(axis=0) + 0.15
        bounds = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    return Motion(
        system="ccma",
        title=title or f"CCMA {name}: {len(agent_names)} agents",
        t=sample_stamps(k, rate),
        tracks=tuple(tracks),
        lines=lines,
        obstacles=(),
        inflated=(),
        bounds=bounds,
        timed=False,
        trail="end_effector",
        notes=(f"steps stamped at {rate:g} Hz (the run has no time law)",),
    )


def ccma_track_motion(model: Any, result: Any, path_name: str = "", rate: float = 10.0) -> Motion:
    """:func:`ccma_motion` of a tracked path (:func:`tmr.ccma.control.track` with ``keep_states=True``) of the
    CCMA ``model`` (:class:`tmr.ccma.energy.EnergyModel`): links from every step's state
    (:func:`tmr.ccma.plot.body_segments`)."""
    from tmr.ccma.plot import body_segments

    if not result.states:
        raise ParameterError("the tracked path has no states (track(..., keep_states=True))")
    frames = [body_segments(model, st) for st in result.states]
    links = [np.stack([f[i] for f in frames]) for i in range(len(frames[0]))]
    sysm = model.system
    return ccma_motion(
        sysm.name,
        [a.name for a in sysm.agents],
        result.agents,
        min(a.height for a in sysm.agents),
        result.ee_position,
        links,
        rate=rate,
        title=f"CCMA {sysm.name}: {path_name} path" if path_name else None,
    )
