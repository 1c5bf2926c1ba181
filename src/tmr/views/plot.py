"""Figures of a tethered-chain plan (Caruso 2021 §5, Figs. 5–8).

Every function builds a :class:`matplotlib.figure.Figure` directly on an Agg canvas (no ``pyplot``, so no
global figure state and no GUI backend) and returns it; :func:`save_figure` writes it atomically. Plans and
environments are read through their fields only (see :mod:`tmr.checks.metrics`).
"""

from __future__ import annotations

import io as _io
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, PathPatch, Rectangle
from matplotlib.path import Path as MplPath

from tmr.checks.metrics import distance_errors, plan_goal, sample_time, span_limits
from tmr.io.outputs import atomic_write_bytes

__all__ = [
    "figure_bytes",
    "plot_chain_poses",
    "plot_distance_errors",
    "plot_speeds",
    "plot_drive",
    "plot_trajectories",
    "save_figure",
]

RAW_COLOR = "#1f77b4"  # blue: planner output
FILTERED_COLOR = "#d62728"  # red: filtered (as in Caruso 2021 Figs. 6 and 8)
OBSTACLE_FACE = "#9e9e9e"
INFLATED_EDGE = "#555555"
#: Low obstacles (a tether may pass over them): a lighter hatched fill, labelled with their height.
LOW_OBSTACLE_FACE = "#e0d5b8"
LOW_OBSTACLE_EDGE = "#8d6e63"
LOW_OBSTACLE_HATCH = "////"
TIME_CMAP = "viridis"
#: Height [in] of one legend row at font size 8.
LEGEND_ROW = 0.19


def _new_figure(width: float, height: float) -> Figure:
    """A figure on an Agg canvas, laid out by hand (:func:`_grid`): matplotlib's constrained layout measured
    every tick label twice and took 60 % of the rendering time (1.1 s of the four figures' 1.8 s)."""
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def _grid(
    fig: Figure,
    rows: int,
    cols: int,
    *,
    left: float = 0.8,
    right: float = 0.2,
    top: float = 0.65,
    bottom: float = 0.55,
    hgap: float = 0.5,
    wgap: float = 0.85,
    sharex: bool = True,
) -> np.ndarray:
    """(rows, cols) axes with fixed margins and gaps in inches (room for tick labels, axis labels and titles)."""
    w, h = fig.get_size_inches()
    ax_w = (w - left - right - (cols - 1) * wgap) / cols
    ax_h = (h - top - bottom - (rows - 1) * hgap) / rows
    gridspec = {
        "left": left / w,
        "right": 1.0 - right / w,
        "top": 1.0 - top / h,
        "bottom": bottom / h,
        "wspace": wgap / ax_w,
        "hspace": hgap / ax_h,
    }
    return fig.subplots(rows, cols, sharex=sharex, squeeze=False, gridspec_kw=gridspec)


def _suptitle(fig: Figure, text: str) -> None:
    fig.suptitle(text, y=1.0 - 0.1 / fig.get_size_inches()[1], va="top")


def _title(plan: Any, what: str) -> str:
    status = "" if plan.success else f" — FAILED: {plan.failure}" if plan.failure else " — FAILED"
    return f"Scenario {plan.scenario}, {plan.method}: {what}{status}"


# ----------------------------------------------------------------------------------------------------------
# shapely -> matplotlib
# ----------------------------------------------------------------------------------------------------------
def _polygons(geom: Any) -> list[Any]:
    """All polygons in a shapely geometry (Polygon, MultiPolygon, GeometryCollection); other types ignored."""
    if geom is None or geom.is_empty:
        return []
    kind = geom.geom_type
    if kind == "Polygon":
        return [geom]
    if kind in ("MultiPolygon", "GeometryCollection"):
        return [p for g in geom.geoms for p in _polygons(g)]
    return []


def _polygon_path(poly: Any) -> MplPath:
    """Compound matplotlib path of a polygon with its holes (even-odd fill)."""
    rings = [np.asarray(poly.exterior.coords)[:, :2]] + [np.asarray(h.coords)[:, :2] for h in poly.interiors]
    verts = np.concatenate(rings)
    codes = np.concatenate(
        [[MplPath.MOVETO] + [MplPath.LINETO] * (len(r) - 2) + [MplPath.CLOSEPOLY] for r in rings]
    ).astype(MplPath.code_type)
    return MplPath(verts, codes)


def _boundary_segments(geom: Any) -> list[np.ndarray]:
    """Coordinates of every linear piece of the boundary of a (multi)polygon."""
    out = []
    for poly in _polygons(geom):
        out.append(np.asarray(poly.exterior.coords)[:, :2])
        out.extend(np.asarray(h.coords)[:, :2] for h in poly.interiors)
    return out


def draw_low_obstacles(ax: Any, low_obstacles: Any, zorder: float = 1.5) -> list[Any]:
    """Low obstacles (:class:`tmr.world.environment.LowObstacle`: ``footprint``, ``height`` [m]) as a lighter hatched
    fill, each labelled with its height ("0.2 m") at a point inside it; returns the legend handle ("low obstacle"),
    none if there are none."""
    lows = list(low_obstacles or ())
    if not lows:
        return []
    for low in lows:
        polys = _polygons(low.footprint)
        if not polys:
            continue
        ax.add_patch(
            PathPatch(
                MplPath.make_compound_path(*[_polygon_path(p) for p in polys]),
                facecolor=LOW_OBSTACLE_FACE,
                edgecolor=LOW_OBSTACLE_EDGE,
                hatch=LOW_OBSTACLE_HATCH,
                lw=0.8,
                zorder=zorder,
            )
        )
        at = low.footprint.representative_point()
        ax.annotate(
            f"{low.height:.2f} m",
            (at.x, at.y),
            ha="center",
            va="center",
            fontsize=7,
            color="#4e342e",
            zorder=zorder + 0.1,
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    label = "low obstacle (tethers may pass over)"
    return [
        Rectangle(
            (0, 0),
            1,
            1,
            facecolor=LOW_OBSTACLE_FACE,
            edgecolor=LOW_OBSTACLE_EDGE,
            hatch=LOW_OBSTACLE_HATCH,
            label=label,
        )
    ]


def _draw_environment(ax: Any, env: Any) -> list[Any]:
    """Raw obstacles filled (the tall ones; low obstacles lighter and hatched, :func:`draw_low_obstacles`), inflated
    obstacles dashed outline, room bounds; returns legend handles."""
    from shapely.geometry import box  # local: shapely is only needed when an environment is drawn

    handles: list[Any] = []
    bounds = tuple(float(v) for v in env.bounds)
    room = box(*bounds)
    obstacles = getattr(env, "tall_obstacles", getattr(env, "obstacles", None))
    polys = _polygons(obstacles.intersection(room)) if obstacles is not None else []
    if polys:
        patch = PathPatch(
            MplPath.make_compound_path(*[_polygon_path(p) for p in polys]),
            facecolor=OBSTACLE_FACE,
            edgecolor="#424242",
            lw=0.8,
            zorder=1,
        )
        ax.add_patch(patch)
        handles.append(Rectangle((0, 0), 1, 1, facecolor=OBSTACLE_FACE, edgecolor="#424242", label="obstacle"))
    handles += draw_low_obstacles(ax, getattr(env, "low_obstacles", ()))
    inflated = getattr(env, "inflated", None)
    if inflated is not None:
        segs = _boundary_segments(inflated.intersection(room))
        if segs:
            ax.add_collection(
                LineCollection(segs, colors=INFLATED_EDGE, linestyles=(0, (4, 3)), linewidths=0.9, zorder=2)
            )
            r = getattr(env, "safety_radius", None)
            label = "inflated obstacle" + (f" (+{r:g} m)" if r is not None else "")
            handles.append(Line2D([], [], color=INFLATED_EDGE, ls=(0, (4, 3)), lw=0.9, label=label))
    x0, y0, x1, y1 = bounds
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, edgecolor="black", lw=1.6, zorder=3))
    return handles


# ----------------------------------------------------------------------------------------------------------
# Fig. 5
# ----------------------------------------------------------------------------------------------------------
def view_bounds(env: Any, points: np.ndarray, margin: float = 0.5) -> tuple[float, float, float, float]:
    """The part of the map a figure frames (xmin, ymin, xmax, ymax) [m].

    The whole room, except for an occupancy-grid map (``env.known_free`` set by :func:`tmr.world.maps.load_map`), whose
    image is often mostly unknown (a TurtleBot3 map: a 4 m arena in a 20 m x 20 m image): then the known free area
    and ``points`` (robots, base, goal; (..., 2) [m]) with ``margin`` [m] round them, within the room.
    """
    room = tuple(float(v) for v in env.bounds)
    known = getattr(env, "known_free", None)
    if known is None:
        return room  # type: ignore[return-value]
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    lo = np.minimum(np.array(known[:2], dtype=float), pts.min(axis=0) if pts.size else np.inf) - margin
    hi = np.maximum(np.array(known[2:], dtype=float), pts.max(axis=0) if pts.size else -np.inf) + margin
    return (max(lo[0], room[0]), max(lo[1], room[1]), min(hi[0], room[2]), min(hi[1], room[3]))


def _pose_indices(t: np.ndarray, every: float) -> np.ndarray:
    """Sample indices closest to t0, t0 + every, ..., plus the last sample."""
    if t.size == 0:
        return np.zeros(0, dtype=int)
    targets = np.arange(t[0], t[-1] + 1e-9, every) if every > 0 else np.array([t[0]])
    idx = np.clip(np.searchsorted(t, targets - 1e-9), 0, t.size - 1)
    return np.unique(np.append(idx, t.size - 1))


def plot_chain_poses(
    plan: Any, env: Any, every: float = 3.0, goal: np.ndarray | None = None, route: Any = None
) -> Figure:
    """Caruso 2021 Fig. 5: poses of the chain (base → robot 1 → … → robot N) every ``every`` seconds over the
    map.

    Draws the raw obstacles (filled), the inflated obstacles (dashed outline), the room, the leader reference
    path, the robots' traces (thin), and at each pose time the tether polylines and the robots as circles of
    the safety radius, coloured by time (colour bar in s). Base = black square, goal = star (``goal``, else
    ``plan.goal``, else the reference's end). With a :class:`tmr.route.route.Route`, its shortest route (wide, light)
    and its stations (diamonds) are drawn under the chain. A differential-drive plan (``plan.axle`` set) also draws
    each robot's footprint round its axle (dotted) and its heading, a bar from the axle to the tether's exit point.
    """
    t = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    base = np.asarray(plan.base, dtype=float)[:2]
    ref = np.asarray(plan.reference, dtype=float)[:, :2]
    goal_xy = plan_goal(plan, goal)
    r = float(plan.safety_radius)
    axle = getattr(plan, "axle", None)  # differential drive (tmr.control.diffdrive): axle centres, footprint radius
    footprint = 0.0
    if axle is not None:
        axle = np.asarray(axle, dtype=float)
        footprint = float(((getattr(plan, "params", None) or {}).get("robot_model_params") or {}).get("radius", 0.0))

    x0, y0, x1, y1 = view_bounds(env, np.vstack([robots.reshape(-1, 2), base[None], np.reshape(goal_xy, (1, 2))]))
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    width = 7.5
    fig = _new_figure(width, min(max(width * aspect * 0.92 + 0.9, 3.5), 11.0))
    ax = fig.add_subplot()  # placed at the end, when the legend's height is known
    handles = _draw_environment(ax, env)

    if route is not None:
        rp = np.asarray(route.points, dtype=float)
        ax.plot(rp[:, 0], rp[:, 1], color="#2ca02c", lw=5.0, alpha=0.25, solid_capstyle="round", zorder=3)
        handles.append(
            Line2D(
                [],
                [],
                color="#2ca02c",
                lw=5.0,
                alpha=0.25,
                label=f"route ({route.length:.1f} m, {route.margin:.2f} m clear)",
            )
        )
        st = np.asarray(route.stations, dtype=float)
        ax.plot(st[:, 0], st[:, 1], "D", ms=5, mfc="none", mec="#2ca02c", mew=1.2, zorder=4)
        handles.append(
            Line2D([], [], ls="", marker="D", ms=5, mfc="none", mec="#2ca02c", label=f"{len(route.stations)} stations")
        )
    ax.plot(ref[:, 0], ref[:, 1], color="#e377c2", ls="--", lw=1.3, zorder=4)
    handles.append(Line2D([], [], color="#e377c2", ls="--", lw=1.3, label="leader reference"))
    for i in range(robots.shape[1]):
        ax.plot(robots[:, i, 0], robots[:, i, 1], color="#7f7f7f", lw=0.6, alpha=0.7, zorder=4)
    handles.append(Line2D([], [], color="#7f7f7f", lw=0.6, label="robot traces"))

    idx = _pose_indices(t, every)
    cmap = colormaps[TIME_CMAP]
    norm = Normalize(vmin=float(t[0]), vmax=float(max(t[-1], t[0] + 1e-9)))
    pts = np.concatenate([np.broadcast_to(base, (robots.shape[0], 1, 2)), robots], axis=1)
    for k in idx:
        color = cmap(norm(t[k]))
        ax.plot(pts[k, :, 0], pts[k, :, 1], color=color, lw=1.6, zorder=5)
        circles = PatchCollection(
            [Circle((float(x), float(y)), r) for x, y in robots[k]],
            facecolors=[(*color[:3], 0.12)],
            edgecolors=[color],
            linewidths=1.1,
            zorder=6,
        )
        ax.add_collection(circles)
        ax.plot(robots[k, :, 0], robots[k, :, 1], "o", ms=2.5, color=color, zorder=7)
        if axle is not None:  # differential drive: the footprint round the axle and the heading to the tether's exit
            ax.add_collection(
                PatchCollection(
                    [Circle((float(x), float(y)), footprint) for x, y in axle[k]],
                    facecolors="none",
                    edgecolors=[color],
                    linewidths=0.8,
                    linestyles=":",
                    zorder=6,
                )
            )
            for (ax_x, ax_y), (ex, ey) in zip(axle[k], robots[k], strict=True):
                ax.plot([ax_x, ex], [ax_y, ey], color=color, lw=2.0, solid_capstyle="butt", zorder=7)
    if axle is not None:
        handles.append(
            Line2D(
                [],
                [],
                color=cmap(0.5),
                lw=2.0,
                ls="-",
                label=f"heading (r_f {footprint:g} m)",
            )
        )
    handles.append(
        Line2D(
            [],
            [],
            color=cmap(0.5),
            lw=1.6,
            marker="o",
            mfc="none",
            ms=9,
            label=f"chain pose (robot r = {r:g} m)",
        )
    )
    k_last = idx[-1] if idx.size else robots.shape[0] - 1
    for i in range(robots.shape[1]):  # name the robots at the last pose
        ax.text(
            robots[k_last, i, 0],
            robots[k_last, i, 1] + 1.08 * r,
            f"R{i + 1}",
            fontsize=8,
            ha="center",
            va="bottom",
            zorder=9,
        )

    ax.plot(*base, marker="s", ms=9, color="black", ls="none", zorder=8)
    ax.plot(*goal_xy, marker="*", ms=15, color="#ff7f0e", mec="black", mew=0.6, ls="none", zorder=8)
    handles.append(Line2D([], [], marker="s", ms=8, color="black", ls="none", label="base (tether anchor)"))
    handles.append(Line2D([], [], marker="*", ms=12, color="#ff7f0e", mec="black", ls="none", label="goal"))

    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(_title(plan, f"chain poses every {every:g} s"), y=1.0)  # y given: no tick-box search
    ax.grid(True, lw=0.3, alpha=0.5)
    # fixed layout [in]: legend rows at the bottom, then the x label; colour bar and its label on the right
    w, h = fig.get_size_inches()
    legend_h = 0.2 * math.ceil(len(handles) / 4) + 0.15
    left, right, top, bottom = 0.7, 1.15, 0.45, legend_h + 0.55
    box_w, box_h = w - left - right, h - top - bottom
    ax.set_position((left / w, bottom / h, box_w / w, box_h / h))
    # equal scales filling the box: the shorter side of the view widens about its centre
    pad = 0.03 * max(x1 - x0, y1 - y0)
    half_x, half_y = 0.5 * (x1 - x0) + pad, 0.5 * (y1 - y0) + pad
    half_x, half_y = max(half_x, half_y * box_w / box_h), max(half_y, half_x * box_h / box_w)
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    ax.set_xlim(cx - half_x, cx + half_x)
    ax.set_ylim(cy - half_y, cy + half_y)
    ax.set_aspect("equal")
    cax = fig.add_axes(((w - right + 0.15) / w, bottom / h, 0.2 / w, box_h / h))
    cbar = fig.colorbar(_scalar_mappable(cmap, norm), cax=cax, ticks=np.round(t[idx], 2) if idx.size < 12 else None)
    cbar.set_label("time [s]")
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 0.05 / h), ncols=4, fontsize=8, frameon=False)
    return fig


def _scalar_mappable(cmap: Any, norm: Normalize) -> Any:
    from matplotlib.cm import ScalarMappable

    sm = ScalarMappable(norm=norm, cmap=cmap)
    sm.set_array([])
    return sm


# ----------------------------------------------------------------------------------------------------------
# Fig. 6
# ----------------------------------------------------------------------------------------------------------
def plot_trajectories(plan: Any, filtered: np.ndarray | None = None) -> Figure:
    """Caruso 2021 Fig. 6: x(t) and y(t) of each robot, raw (blue) vs filtered (red). One row per robot
    (robot N = leader), columns x and y; 1 line per axis without ``filtered``, 2 with it."""
    t = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    n = robots.shape[1]
    fig = _new_figure(9.0, 1.9 * n + 0.9)
    axes = _grid(fig, n, 2)
    for i in range(n):
        name = f"robot {i + 1}" + (" (leader)" if i == n - 1 else "")
        for c, coord in enumerate("xy"):
            ax = axes[i, c]
            label = "planner output" if getattr(plan, "heading", None) is None else "tether exit point (planned)"
            ax.plot(t, robots[:, i, c], color=RAW_COLOR, lw=1.8, label=label)
            if filtered is not None:
                ax.plot(t, np.asarray(filtered)[:, i, c], color=FILTERED_COLOR, lw=1.0, label="filtered")
            ax.set_ylabel(f"{coord} [m]")
            ax.set_title(f"{name}: {coord}(t)", fontsize=10, y=1.0)
            ax.grid(True, lw=0.3, alpha=0.5)
    for c in range(2):
        axes[-1, c].set_xlabel("time [s]")
    axes[0, 1].legend(loc="best", fontsize=8)
    _suptitle(fig, _title(plan, "robot trajectories"))
    return fig


# ----------------------------------------------------------------------------------------------------------
# Fig. 7
# ----------------------------------------------------------------------------------------------------------
def _shade_obstacle_active(ax: Any, plan: Any, t: np.ndarray) -> bool:
    """Shade the time intervals where the obstacle-avoidance task is active (diagnostics
    "obstacle_active")."""
    active = (getattr(plan, "diagnostics", None) or {}).get("obstacle_active")
    if active is None:
        return False
    active = np.asarray(active, dtype=bool)
    if active.shape != t.shape or not active.any():
        return False
    Ts = sample_time(t, default=0.0)
    edges = np.diff(np.concatenate([[0], active.astype(np.int8), [0]]))
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        ax.axvspan(t[a], t[b - 1] + Ts, color="#ffbb78", alpha=0.35, lw=0, zorder=0)
    return True


def plot_distance_errors(plan: Any) -> Figure:
    """Caruso 2021 Fig. 7: distance errors span_i(t) − mean_j span_j(t) per tether (top) and the spans against
    d_max and d_lo (bottom). Intervals where the obstacle-avoidance task is active
    (``plan.diagnostics["obstacle_active"]``, if present) are shaded. Top axis: N lines; bottom axis: N span
    lines + 2 limit lines for a shared limit (2 N for per-tether limits, in the tethers' colours, with two legend
    entries for all of them). The figure grows with N so that each legend fits beside its axis."""
    t = np.asarray(plan.t, dtype=float)
    spans = np.asarray(plan.spans, dtype=float)
    err = distance_errors(plan)
    n = spans.shape[1]
    d_lo, d_max = span_limits(plan)
    colors = [colormaps["tab10"](i % 10) for i in range(n)]

    # legends outside, on the right: each axis tall enough for its legend (N tether entries + 2 or 3)
    fig = _new_figure(9.5, max(6.0, 2.0 * (LEGEND_ROW * (n + 3) + 0.2) + 1.7))
    ax_e, ax_s = _grid(fig, 2, 1, right=1.95)[:, 0]
    for i in range(n):
        ax_e.plot(t, err[:, i], color=colors[i], lw=1.2, label=f"tether {i + 1}")
        ax_s.plot(t, spans[:, i], color=colors[i], lw=1.2, label=f"tether {i + 1}")
    shaded = _shade_obstacle_active(ax_e, plan, t)
    _shade_obstacle_active(ax_s, plan, t)
    ax_e.axhline(0.0, color="black", lw=0.6, zorder=0)
    ax_e.set_ylabel("span − mean span [m]")
    ax_e.set_title(f"distance errors (max |e| = {np.abs(err).max():.3g} m)", fontsize=10, y=1.0)
    handles, _ = ax_e.get_legend_handles_labels()
    if shaded:
        handles.append(Rectangle((0, 0), 1, 1, color="#ffbb78", alpha=0.35, label="obstacle avoidance active"))
    ax_e.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)

    shared = np.allclose(d_max, d_max[0]) and np.allclose(d_lo, d_lo[0])
    if shared:
        ax_s.axhline(d_max[0], color="#d62728", ls="--", lw=1.2, label=f"$d_{{max}}$ = {d_max[0]:.3g} m")
        ax_s.axhline(d_lo[0], color="#2ca02c", ls="--", lw=1.2, label=f"$d_{{lo}}$ = {d_lo[0]:.3g} m")
    else:  # per-tether limits in the tether's colour; two legend entries for all of them
        for i in range(n):
            ax_s.axhline(d_max[i], color=colors[i], ls="--", lw=1.0)
            ax_s.axhline(d_lo[i], color=colors[i], ls=":", lw=1.0)
    handles, _ = ax_s.get_legend_handles_labels()
    if not shared:
        handles.append(Line2D([], [], color="0.35", ls="--", lw=1.0, label="$d_{max}$ (tether colours)"))
        handles.append(Line2D([], [], color="0.35", ls=":", lw=1.0, label="$d_{lo}$ (tether colours)"))
    ax_s.set_ylabel("horizontal span [m]")
    ax_s.set_xlabel("time [s]")
    ax_s.set_title("tether spans and limits", fontsize=10, y=1.0)
    ax_s.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    for ax in (ax_e, ax_s):
        ax.grid(True, lw=0.3, alpha=0.5)
    _suptitle(fig, _title(plan, "tether distance errors"))
    return fig


# ----------------------------------------------------------------------------------------------------------
# Fig. 8
# ----------------------------------------------------------------------------------------------------------
def _speeds(robots: np.ndarray, Ts: float) -> np.ndarray:
    """Speeds (K+1, N) [m/s] by central differences (one-sided at the ends)."""
    if robots.shape[0] < 2:
        return np.zeros(robots.shape[:2])
    return np.linalg.norm(np.gradient(robots, Ts, axis=0), axis=-1)


def plot_speeds(plan: Any, filtered: np.ndarray | None = None) -> Figure:
    """Caruso 2021 Fig. 8: normalised speed v_i(t) / v_n of each robot, raw (blue) vs filtered (red).

    v_n is the nominal speed: the mean speed of the leader over the plan = length of its (raw) path / duration
    (the paper's "mean speed the end-effector must have to track the entire trajectory in the simulation
    time"). Speeds by central finite differences of the positions. One row per robot; 1 or 2 lines per axis.
    """
    t = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    n = robots.shape[1]
    Ts = sample_time(t, default=1.0)
    duration = float(t[-1] - t[0]) if t.size > 1 else 0.0
    path_len = float(np.linalg.norm(np.diff(robots[:, -1, :], axis=0), axis=-1).sum())
    v_n = path_len / duration if duration > 0 and path_len > 0 else 1.0
    raw = _speeds(robots, Ts) / v_n
    filt = _speeds(np.asarray(filtered, dtype=float), Ts) / v_n if filtered is not None else None

    fig = _new_figure(8.5, 1.9 * n + 1.0)
    axes = _grid(fig, n, 1)[:, 0]
    for i, ax in enumerate(axes):
        ax.plot(t, raw[:, i], color=RAW_COLOR, lw=1.1, label="planner output")
        if filt is not None:
            ax.plot(t, filt[:, i], color=FILTERED_COLOR, lw=1.3, label="filtered")
        ax.set_ylabel(r"$v / v_n$ [-]")
        ax.set_title(f"robot {i + 1}" + (" (leader)" if i == n - 1 else ""), fontsize=10, y=1.0)
        ax.grid(True, lw=0.3, alpha=0.5)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    _suptitle(fig, _title(plan, f"normalised robot speeds ($v_n$ = {v_n:.3g} m/s)"))
    return fig


def plot_drive(plan: Any) -> Figure:
    """A differential-drive plan's commands (``cmd_vel/robotK.csv``): per robot, the forward speed v(t) [m/s] with
    each wheel's rim speed v ± ω L/2 (with a track L) against ±v_max (left), and the yaw rate ω(t) [rad/s] against
    ±ω_max (right); the rims are planned within (1 − WHEEL_RESERVE) v_max; turn-in-place steps shaded
    (``formulations/diffdrive.md``)."""
    from tmr.checks.diffdrive import TURN_IN_PLACE
    from tmr.control.diffdrive import WHEEL_RESERVE

    t = np.asarray(plan.t, dtype=float)
    v = np.asarray(plan.drive_v, dtype=float)
    w = np.asarray(plan.drive_omega, dtype=float)
    m = dict((plan.params or {}).get("robot_model_params") or {})
    n = v.shape[1]
    fig = _new_figure(9.0, 1.9 * n + 0.9)
    axes = _grid(fig, n, 2)
    for i in range(n):
        name = f"robot {i + 1}" + (" (leader)" if i == n - 1 else "")
        av, aw = axes[i, 0], axes[i, 1]
        av.plot(t, v[:, i], color=RAW_COLOR, lw=1.5, label="v")
        if m.get("track"):
            half = 0.5 * m["track"] * w[:, i]
            rim = (1.0 - WHEEL_RESERVE) * m["v_max"]
            av.axhline(rim, color="0.4", ls=":", lw=0.9, label="planned rim bound")
            av.axhline(-rim, color="0.4", ls=":", lw=0.9)
            av.plot(t, v[:, i] + half, color="C2", lw=0.8, alpha=0.8, label="right wheel rim")
            av.plot(t, v[:, i] - half, color="C1", lw=0.8, alpha=0.8, label="left wheel rim")
        aw.plot(t, w[:, i], color=RAW_COLOR, lw=1.5, label="ω")
        for ax, key in ((av, "v_max"), (aw, "omega_max")):
            if key in m:
                ax.axhline(m[key], color="0.4", ls="--", lw=0.9, label="limit")
                ax.axhline(-m[key], color="0.4", ls="--", lw=0.9)
            ax.grid(True, lw=0.3, alpha=0.5)
        turning = (np.abs(v[:, i]) < TURN_IN_PLACE[0]) & (np.abs(w[:, i]) > TURN_IN_PLACE[1])
        if turning.any():
            aw.fill_between(t, 0, 1, where=turning, color="0.85", transform=aw.get_xaxis_transform(),
                            label="turn in place")  # fmt: skip
        av.set_ylabel("v [m/s]")
        aw.set_ylabel("ω [rad/s]")
        av.set_title(f"{name}: forward speed", fontsize=10, y=1.0)
        aw.set_title(f"{name}: yaw rate", fontsize=10, y=1.0)
    for c in range(2):
        axes[-1, c].set_xlabel("time [s]")
        axes[0, c].legend(loc="best", fontsize=8)
    _suptitle(fig, _title(plan, f"differential drive commands ({(plan.params or {}).get('robot_model', '')})"))
    return fig


def plot_winch(plan: Any) -> Figure:
    """An active winch's plan: every tether's planned horizontal tension T0(t) [N] within the pulley's range (top),
    and how much of its reach each span uses, d / d_max(T0) (bottom; 1 = the cable's lowest point on the ground
    clearance), d_max from the closed-form catenary at that tension (:func:`tmr.model.catenary.max_span`)."""
    from dataclasses import replace as _replace

    from tmr.model import catenary

    T = np.asarray(plan.winch_tension, dtype=float)
    t = np.asarray(plan.t, dtype=float)
    p = dict(plan.params or {})
    cat = catenary.CatenaryParams(
        mass_per_length=p["cable_mass_per_length"], end_height=p["exit_height"], base_height=p["base_height"],
        ground_clearance=p.get("ground_clearance", 0.0),
    )  # fmt: skip
    spans = np.abs(np.asarray(plan.spans, dtype=float))
    n = T.shape[1]
    ratio = np.empty_like(T)
    for j in range(n):
        h1 = cat.base_height if j == 0 else cat.end_height
        reach = {v: catenary.max_span(h1, cat.end_height, _replace(cat, horizontal_tension=v)) for v in set(T[:, j])}
        ratio[:, j] = spans[:, j] / np.array([reach[v] for v in T[:, j]])
    fig = _new_figure(8.5, 6.0)
    top, bottom = _grid(fig, 2, 1)[:, 0]
    colors = [f"C{j % 10}" for j in range(n)]
    for j in range(n):
        top.plot(t, T[:, j], color=colors[j], lw=1.3, label=f"tether {j + 1}")
        bottom.plot(t, ratio[:, j], color=colors[j], lw=1.3, label=f"tether {j + 1}")
    for key, label in (("winch_tension_min", "range"), ("winch_tension_max", None)):
        if key in p:
            top.axhline(p[key], color="0.4", ls="--", lw=0.9, label=label)
    if "pulley_torque" in p:
        top.axhline(p["pulley_torque"] / p["pulley_radius"], color="0.4", ls=":", lw=0.9, label="nominal")
    bottom.axhline(1.0, color="tab:red", ls="--", lw=0.9, label="cable on the ground clearance")
    top.set_ylabel("horizontal tension $T_0$ [N]")
    bottom.set_ylabel("$d / d_{max}(T_0)$ [-]")
    bottom.set_xlabel("time [s]")
    for ax in (top, bottom):
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.legend(loc="best", fontsize=8, ncol=2)
    _suptitle(fig, _title(plan, "active winch: planned tension and the span it allows"))
    return fig


# ----------------------------------------------------------------------------------------------------------
# saving
# ----------------------------------------------------------------------------------------------------------
_DETERMINISTIC_METADATA = {"pdf": {"CreationDate": None, "ModDate": None}, "svg": {"Date": None}}


def figure_bytes(fig: Figure, fmt: str = "png", dpi: int = 120) -> bytes:
    """``fig`` rendered in format ``fmt`` (png, pdf, svg, ...). Dates are left out of PDF/SVG metadata so the same
    figure gives the same bytes."""
    fmt = fmt.lower()
    buf = _io.BytesIO()
    # PNG: zlib level 1 encodes 4-5× faster than matplotlib's default 6 for files ~13 % larger
    extra = {"pil_kwargs": {"compress_level": 1}} if fmt == "png" else {}
    fig.savefig(buf, format=fmt, dpi=dpi, metadata=_DETERMINISTIC_METADATA.get(fmt), **extra)
    return buf.getvalue()


def save_figure(fig: Figure, path: str | os.PathLike[str], dpi: int = 120) -> Path:
    """Render ``fig`` (:func:`figure_bytes`, format from the suffix; default png) and write it atomically."""
    path = Path(path)
    return atomic_write_bytes(path, figure_bytes(fig, path.suffix.lstrip(".") or "png", dpi))
