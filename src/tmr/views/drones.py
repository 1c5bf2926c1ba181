"""Views of a tethered drone chain's plan (issue 32): figures, a 3-D perspective GIF and a plotly 3-D scene.

Every entry point takes the plan (:class:`tmr.control.plan3d.DronePlan`, or anything with its fields, e.g. a plan
rebuilt from a run directory) and the world (:class:`tmr.world.world3d.World3D`); nothing here plans or checks.

Tethers are drawn as the catenaries they are: each curve is rebuilt from its two ends and the recorded parameter
``a = H / (rho g)`` in closed form (:func:`tether_curves`; ``formulations/drones.md``, "Rebuilding a tether"), the same
curve as :func:`tmr.model.catenary3d.solve3d` gives (checked in the tests). Obstacles are drawn from their geometry
(:func:`obstacle_mesh`: boxes from their corners, convex prisms and meshes from coal's hull points, non-convex ones
from their triangles).

- figures (matplotlib on an Agg canvas, no ``pyplot``; PNG bytes are deterministic through
  :func:`tmr.views.plot.figure_bytes`): :func:`chain_poses_3d`, :func:`altitude`, :func:`tether_clearance`,
  :func:`tensions`, all four from :func:`figures`, written by :func:`save_figures`;
- :func:`write_gif_3d`: a perspective animation drawn with Pillow (fixed camera framing the room, painter's
  algorithm, one shared palette so the GIF stores only what changes between frames);
- :func:`write_html_3d`: a plotly 3-D scene (obstacle meshes, drones, catenaries) with a time slider, plotly.js
  embedded as in :mod:`tmr.views.htmlview`;
- :func:`write_drone_views`: the ``--gif`` / ``--html`` / ``--export`` files of a drone run, as
  :func:`tmr.views.flags.write_views` writes them for the ground systems (the bag: :func:`tmr.export.rosbag.
  write_drone_bag`).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.views.plot import _new_figure, _title, figure_bytes

__all__ = [
    "Camera",
    "ObstacleDrawing",
    "altitude",
    "build_figure_3d",
    "camera_for",
    "chain_poses_3d",
    "end_tensions",
    "figures",
    "frame_indices_3d",
    "gif_frames",
    "obstacle_label",
    "obstacle_mesh",
    "save_figures",
    "tensions",
    "tether_clearance",
    "tether_clearances",
    "tether_curves",
    "write_drone_views",
    "write_gif_3d",
    "write_html_3d",
]

Array = NDArray[np.float64]

#: Points per tether drawn along its catenary (ends included).
CURVE_POINTS = 24
#: Largest arc spacing [m] of the samples :func:`tether_clearances` measures.
CLEARANCE_SPACING = 0.1
#: Figure names :func:`figures` returns (file stems of :func:`save_figures`).
FIGURE_NAMES = ("chain_poses_3d", "altitude", "tether_clearance", "tensions")
TETHER_COLOR = "#5b2c83"
LEADER_COLOR = "#ff7f0e"
DRONE_COLOR = "#1f77b4"
OBSTACLE_COLOR = "#8c8c8c"
REFERENCE_COLOR = "#e377c2"


# ----------------------------------------------------------------------------------------------------------
# geometry
# ----------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ObstacleDrawing:
    """An obstacle's surface to draw: ``vertices`` (V, 3) [m], outward ``faces`` (F, 3) (vertex indices),
    ``normals`` (F, 3) unit outward, ``edges`` (E, 2, 3) [m] the feature edges (between faces meeting at an angle,
    so a box shows its 12 edges and not its triangles' diagonals), ``name``."""

    vertices: Array
    faces: NDArray[np.int64]
    normals: Array
    edges: Array
    name: str


def obstacle_mesh(ob: Any) -> ObstacleDrawing:
    """The surface of a :class:`tmr.world.world3d.Obstacle3D` (read only): a box from its corners ``lo``/``hi``,
    a non-convex prism or mesh from its ``triangles``, a convex one from the hull of coal's ``Convex`` points."""
    import trimesh

    if ob.triangles is not None:
        tri = np.asarray(ob.triangles, dtype=float)
        mesh = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=True)
    elif hasattr(ob.geometry, "points"):  # coal.Convex: the hull of its points
        mesh = trimesh.convex.convex_hull(np.asarray(ob.geometry.points(), dtype=float))
    else:  # a box: the corners are exact
        mesh = trimesh.creation.box(bounds=np.vstack([ob.lo, ob.hi]))
    sharp = mesh.face_adjacency_angles > math.radians(1.0)
    edges = np.asarray(mesh.vertices)[mesh.face_adjacency_edges[sharp]]
    return ObstacleDrawing(
        np.asarray(mesh.vertices, dtype=float),
        np.asarray(mesh.faces, dtype=np.int64),
        np.asarray(mesh.face_normals, dtype=float),
        edges.reshape(-1, 2, 3),
        str(ob.name),
    )


def obstacle_label(k: int, ob: Any) -> str:
    """What the HTML view calls obstacle ``k`` of a world: ``"obstacle #k"``, with the file's name for a mesh
    (``"obstacle #2 (mesh 'hangar.stl')"``). Never the world's source label (a scenario file's or run's path, as in
    ``ob.name``): the same plan draws the same bytes wherever its world was read from, and no path leaks out."""
    found = re.search(r"mesh '(.*)'\)?$", str(getattr(ob, "name", "")))
    label = f"obstacle #{k}"
    return f"{label} (mesh '{PurePath(found.group(1)).name}')" if found else label


def _ends(plan: Any) -> tuple[Array, Array]:
    """Lower-index end p and upper-index end q of every tether at every step, each (K+1, N, 3) [m]."""
    robots = np.asarray(plan.robots, dtype=float)
    base = np.broadcast_to(np.asarray(plan.base, dtype=float), (robots.shape[0], 1, 3))
    pts = np.concatenate([base, robots], axis=1)
    return pts[:, :-1], pts[:, 1:]


def _catenary_frame(p: Array, q: Array, a: Array) -> dict[str, Array]:
    """Closed-form catenary through p and q (..., 3) with parameter a (...) [m]: u, d, theta at p and q, length.

    In the vertical plane through the ends, x along the horizontal u from p: z = z0 + a (cosh((x - x0)/a) - 1)
    with x0 = d/2 - a asinh(h / (2 a sinh(d / (2a)))), h = q_z - p_z. Vertical (NaN a or d ~ 0): a straight line."""
    dxy = q[..., :2] - p[..., :2]
    d = np.hypot(dxy[..., 0], dxy[..., 1])
    h = q[..., 2] - p[..., 2]
    vertical = ~np.isfinite(a) | (d < 1e-9)
    aa = np.where(vertical, 1.0, a)
    dd = np.where(vertical, 1.0, d)
    u = np.where(vertical[..., None], 0.0, np.concatenate([dxy / dd[..., None], np.zeros_like(dd)[..., None]], axis=-1))
    with np.errstate(over="ignore", invalid="ignore"):
        x0 = 0.5 * dd - aa * np.arcsinh(h / (2.0 * aa * np.sinh(dd / (2.0 * aa))))
        th_p = -x0 / aa
        th_q = (dd - x0) / aa
        length = np.where(vertical, np.abs(h), aa * (np.sinh(th_q) - np.sinh(th_p)))
    return {"u": u, "d": d, "h": h, "a": aa, "x0": x0, "th_p": th_p, "th_q": th_q, "L": length, "vertical": vertical}


def tether_curves(plan: Any, samples: int = CURVE_POINTS, steps: Any = None) -> Array:
    """Every tether's catenary at the given steps (default all), sampled at equal arc length, ends included:
    (S, N, samples, 3) [m]. Tether j joins point j-1 and point j (point 0 the anchor); rebuilt from its two ends and
    the recorded ``plan.tether_a`` (NaN: vertical, a straight line)."""
    p, q = _ends(plan)
    a = np.asarray(plan.tether_a, dtype=float)
    if steps is not None:
        idx = np.asarray(steps, dtype=int)
        p, q, a = p[idx], q[idx], a[idx]
    c = _catenary_frame(p, q, a)
    frac = np.linspace(0.0, 1.0, int(samples))
    s = c["L"][..., None] * frac  # arc length from p
    aa = c["a"][..., None]
    with np.errstate(over="ignore", invalid="ignore"):
        th = np.arcsinh(np.sinh(c["th_p"])[..., None] + s / aa)
        x = c["x0"][..., None] + aa * th
        z = p[..., 2:3] + aa * (np.cosh(th) - np.cosh(c["th_p"])[..., None])
    curve = p[..., None, :] + x[..., None] * c["u"][..., None, :]
    curve[..., 2] = z
    straight = p[..., None, :] + frac[:, None] * (q - p)[..., None, :]
    out = np.where(c["vertical"][..., None, None], straight, curve)
    out[..., 0, :], out[..., -1, :] = p, q  # exactly through the ends
    return out


def end_tensions(plan: Any) -> tuple[Array, Array]:
    """Tension magnitude [N] at the p end (lower index) and q end of every tether, each (K+1, N):
    T = rho g a cosh(theta) at the end (= rho g (a + z - z0)); a vertical tether from the winch: T_w at the winch
    end and T_w ± rho g |h| at the other (an active winch: its recorded T_w of that step)."""
    p, q = _ends(plan)
    a = np.asarray(plan.tether_a, dtype=float)
    c = _catenary_frame(p, q, a)
    w = float(plan.tether.mass_per_length * plan.tether.g)
    recorded = getattr(plan, "winch_tension", None)
    tw: Any = float(plan.tether.winch_tension) if recorded is None else np.asarray(recorded, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        tp = w * c["a"] * np.cosh(c["th_p"])
        tq = w * c["a"] * np.cosh(c["th_q"])
    dh = np.abs(c["h"])
    lower = tw if plan.tether.winch_end == "lower" else tw - w * dh
    upper = lower + w * dh
    p_low = c["h"] >= 0.0
    vtp, vtq = np.where(p_low, lower, upper), np.where(p_low, upper, lower)
    return np.where(c["vertical"], vtp, tp), np.where(c["vertical"], vtq, tq)


def tether_clearances(plan: Any, world: Any, spacing: float = CLEARANCE_SPACING) -> tuple[Array, Array]:
    """Each tether curve's smallest distance [m] to the obstacles and the room's walls, floor and ceiling at every
    step, (K+1, N), and where on the curve it is, (K+1, N, 3) [m]: the distances (``World3D`` with radius 0, exact
    coal distances) of points at most ``spacing`` m apart along the curve (so the whole curve's minimum is at most
    spacing/2 less)."""
    p, q = _ends(plan)
    lengths = _catenary_frame(p, q, np.asarray(plan.tether_a, dtype=float))["L"]
    finite = lengths[np.isfinite(lengths)]
    longest = float(finite.max()) if finite.size else 1.0
    m = int(min(max(math.ceil(longest / spacing) + 1, 8), 801))
    curves = tether_curves(plan, m)
    w0 = world.with_safety_radius(0.0)
    dist = np.asarray(w0.clearance(curves.reshape(-1, 3)), dtype=float).reshape(curves.shape[:3])
    j = np.argmin(dist, axis=2)
    where = np.take_along_axis(curves, j[..., None, None], axis=2)[:, :, 0]
    return np.take_along_axis(dist, j[..., None], axis=2)[..., 0], where


# ----------------------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------------------
def _pose_steps(n_steps: int, poses: int) -> NDArray[np.int64]:
    """``poses`` step indices evenly spread from the first to the last step."""
    return np.unique(np.round(np.linspace(0, n_steps - 1, max(1, int(poses)))).astype(int))


def _drone_colors(n: int) -> list[str]:
    return [DRONE_COLOR] * (n - 1) + [LEADER_COLOR]


def chain_poses_3d(plan: Any, world: Any, poses: int = 5, route: Any = None) -> Any:
    """A 3-D perspective view of the chain at ``poses`` times (first to last): the obstacles as translucent
    surfaces with their edges, the floor and the room, every tether as its catenary, the drones as markers (size ~
    their radius), coloured by time; the leader's reference (dashed) and its trace, anchor (square) and goal
    (star). ``route``: the leader's free 3-D route, an (M, 3) array [m] or an object with ``path``, drawn wide and
    light."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    t = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    x0, y0, z0, x1, y1, z1 = (float(v) for v in world.bounds)
    fig = _new_figure(8.5, 7.0)
    ax = fig.add_axes((-0.04, 0.08, 0.9, 0.88), projection="3d")
    ax.set_proj_type("persp", focal_length=0.6)
    handles: list[Any] = []
    faces, edges = [], []
    for ob in world.obstacles:
        dr = obstacle_mesh(ob)
        faces.append(dr.vertices[dr.faces])
        edges.append(dr.edges)
    if faces:
        ax.add_collection3d(
            Poly3DCollection(np.concatenate(faces), facecolors=OBSTACLE_COLOR, edgecolors="none", alpha=0.22)
        )
        ax.add_collection3d(Line3DCollection(np.concatenate(edges), colors="#424242", linewidths=0.7))
        handles.append(Patch(facecolor=OBSTACLE_COLOR, alpha=0.4, edgecolor="#424242", label="obstacle"))
    floor = np.array([[[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]]])
    ax.add_collection3d(Poly3DCollection(floor, facecolors="#d9d9d9", edgecolors="#7f7f7f", alpha=0.35))
    if route is not None:
        rp = np.asarray(getattr(route, "path", route), dtype=float)
        ax.plot(rp[:, 0], rp[:, 1], rp[:, 2], color="#2ca02c", lw=5.0, alpha=0.3)
        handles.append(Line2D([], [], color="#2ca02c", lw=5.0, alpha=0.3, label="leader route"))
    ref = np.asarray(plan.reference, dtype=float)
    ax.plot(ref[:, 0], ref[:, 1], ref[:, 2], color=REFERENCE_COLOR, ls="--", lw=1.2)
    handles.append(Line2D([], [], color=REFERENCE_COLOR, ls="--", lw=1.2, label="leader reference"))
    for i in range(robots.shape[1]):
        ax.plot(robots[:, i, 0], robots[:, i, 1], robots[:, i, 2], color="#7f7f7f", lw=0.6, alpha=0.7)
    handles.append(Line2D([], [], color="#7f7f7f", lw=0.6, label="drone traces"))
    idx = _pose_steps(len(t), poses)
    cmap = colormaps["viridis"]
    norm = Normalize(vmin=float(t[0]), vmax=float(max(t[-1], t[0] + 1e-9)))
    curves = tether_curves(plan, CURVE_POINTS, idx)
    r = float(plan.safety_radius)
    # marker area in points²: a sphere of radius r seen at the view's mean scale (about 5 in across the room)
    size = (72.0 * 5.0 * 2.0 * r / max(x1 - x0, y1 - y0, z1 - z0)) ** 2
    for s, k in enumerate(idx):
        color = cmap(norm(t[k]))
        ax.add_collection3d(Line3DCollection(list(curves[s]), colors=[color], linewidths=1.6))
        ax.scatter(
            *robots[k].T, s=size, color=[color], alpha=0.35, edgecolors="black", linewidths=0.6, depthshade=False
        )
    handles.append(Line2D([], [], color=cmap(0.5), lw=1.6, label="tether (catenary)"))
    handles.append(
        Line2D([], [], ls="", marker="o", ms=9, mfc=cmap(0.5), alpha=0.5, mec="black", label=f"drone (r = {r:g} m)")
    )
    k = idx[-1]
    for i in range(robots.shape[1]):
        ax.text(*(robots[k, i] + [0.0, 0.0, 1.3 * r]), f"R{i + 1}", fontsize=8, ha="center")
    b, g = np.asarray(plan.base, dtype=float), np.asarray(plan.goal, dtype=float)
    ax.scatter(*b, marker="s", s=60, color="black", depthshade=False)
    ax.scatter(*g, marker="*", s=160, color=LEADER_COLOR, edgecolors="black", linewidths=0.6, depthshade=False)
    handles.append(Line2D([], [], marker="s", ms=7, color="black", ls="", label="anchor (winch)"))
    handles.append(Line2D([], [], marker="*", ms=11, color=LEADER_COLOR, mec="black", ls="", label="goal"))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_zlim(z0, z1)
    ax.set_box_aspect((x1 - x0, y1 - y0, z1 - z0), zoom=1.02)
    ax.view_init(elev=28.0, azim=-60.0)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(_title(plan, f"drone chain at {len(idx)} times"), y=1.0)
    cax = fig.add_axes((0.89, 0.2, 0.02, 0.6))
    from tmr.views.plot import _scalar_mappable

    cbar = fig.colorbar(_scalar_mappable(cmap, norm), cax=cax, ticks=np.round(t[idx], 2))
    cbar.set_label("time [s]")
    fig.legend(handles=handles, loc="lower center", ncols=4, fontsize=8, frameon=False)
    return fig


def altitude(plan: Any) -> Any:
    """Height z(t) [m] of each drone with its bounds: the floor + r and the ceiling − r (a drone's centre must keep
    its radius r from both)."""
    t = np.asarray(plan.t, dtype=float)
    robots = np.asarray(plan.robots, dtype=float)
    n = robots.shape[1]
    zmin, zmax = float(plan.bounds[2]), float(plan.bounds[5])
    r = float(plan.safety_radius)
    fig = _new_figure(8.5, 4.5)
    ax = fig.add_axes((0.09, 0.12, 0.68, 0.78))
    from matplotlib import colormaps

    for i in range(n):
        name = f"drone {i + 1}" + (" (leader)" if i == n - 1 else "")
        ax.plot(t, robots[:, i, 2], color=colormaps["tab10"](i % 10), lw=1.3, label=name)
    ax.axhline(zmin + r, color="#d62728", ls="--", lw=1.1, label=f"floor + r = {zmin + r:.3g} m")
    ax.axhline(zmax - r, color="#d62728", ls=":", lw=1.1, label=f"ceiling − r = {zmax - r:.3g} m")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("z [m]")
    ax.set_ylim(zmin, zmax)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_title(_title(plan, "drone altitudes"), y=1.0)
    return fig


def tether_clearance(plan: Any, world: Any) -> Any:
    """Each tether curve's smallest distance [m] to the obstacles, the floor and the walls over time
    (:func:`tether_clearances`) against the tether clearance c_t; the smallest one is marked and its place named."""
    from matplotlib import colormaps

    from tmr.errors import fmt_point

    t = np.asarray(plan.t, dtype=float)
    dist, where = tether_clearances(plan, world)
    n = dist.shape[1]
    ct = float(plan.tether.clearance)
    fig = _new_figure(8.5, 4.5)
    ax = fig.add_axes((0.09, 0.12, 0.68, 0.76))
    for j in range(n):
        ax.plot(t, dist[:, j], color=colormaps["tab10"](j % 10), lw=1.2, label=f"tether {j + 1}")
    ax.axhline(ct, color="#d62728", ls="--", lw=1.2, label=f"$c_t$ = {ct:g} m")
    k, j = np.unravel_index(int(np.argmin(dist)), dist.shape)
    ax.plot(t[k], dist[k, j], "o", ms=7, mfc="none", mec="black", label="smallest")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("curve clearance [m]")
    ax.set_ylim(bottom=min(0.0, float(dist.min()) - 0.05))
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_title(
        _title(
            plan,
            f"tether clearance (min {dist[k, j]:.3f} m, tether {j + 1} at t = {t[k]:.2f} s, {fmt_point(where[k, j])})",
        ),
        y=1.0,
        fontsize=9,
    )
    return fig


def tensions(plan: Any) -> Any:
    """Tension [N] the tethers pull each drone with over time — tether i at its upper-index end (solid) and tether
    i + 1 at its lower-index end (dashed), both ends of drone i — against the drone's spare thrust
    (:func:`end_tensions`)."""
    from matplotlib import colormaps

    t = np.asarray(plan.t, dtype=float)
    tp, tq = end_tensions(plan)
    n = tq.shape[1]
    spare = float(plan.tether.spare_thrust)
    fig = _new_figure(8.5, 4.5)
    ax = fig.add_axes((0.09, 0.12, 0.66, 0.78))
    for i in range(n):
        color = colormaps["tab10"](i % 10)
        ax.plot(t, tq[:, i], color=color, lw=1.2, label=f"drone {i + 1}: tether {i + 1}")
        if i + 1 < n:
            ax.plot(t, tp[:, i + 1], color=color, lw=1.0, ls="--", label=f"drone {i + 1}: tether {i + 2}")
    recorded = getattr(plan, "winch_tension", None)
    if recorded is not None:  # an active winch: each tether's commanded tension
        for j in range(n):
            ax.plot(t, np.asarray(recorded)[:, j], color=colormaps["tab10"](j % 10), lw=0.9, ls=":",
                    label=f"winch {j + 1} T_w (active)")  # fmt: skip
    ax.axhline(spare, color="#d62728", ls="--", lw=1.3, label=f"spare thrust {spare:.3g} N")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("tension at the drone [N]")
    ax.set_ylim(0.0, max(spare, float(np.nanmax(tq)), float(np.nanmax(tp[:, 1:], initial=0.0))) * 1.1)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_title(_title(plan, "tether tensions at the drones"), y=1.0)
    return fig


def figures(plan: Any, world: Any, route: Any = None) -> dict[str, Any]:
    """The four figures of a drone plan by name (:data:`FIGURE_NAMES`): matplotlib Figures."""
    return {
        "chain_poses_3d": chain_poses_3d(plan, world, route=route),
        "altitude": altitude(plan),
        "tether_clearance": tether_clearance(plan, world),
        "tensions": tensions(plan),
    }


def save_figures(plan: Any, world: Any, out: str | os.PathLike[str], route: Any = None, dpi: int = 120) -> list[Path]:
    """Write :func:`figures` as ``<name>.png`` into the directory ``out`` (atomic writes); return the paths."""
    from tmr.io.outputs import atomic_write_bytes

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return [
        atomic_write_bytes(out / f"{k}.png", figure_bytes(f, "png", dpi))
        for k, f in figures(plan, world, route).items()
    ]


# ----------------------------------------------------------------------------------------------------------
# the GIF: a pinhole camera and Pillow
# ----------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Camera:
    """A pinhole camera: ``eye`` (3,) [m], orthonormal ``right``, ``up``, ``forward`` axes, and the image map
    pixel = centre + scale · (x/depth, −y/depth) - offset, for an image ``size`` (width, height) [px]."""

    eye: Array
    right: Array
    up: Array
    forward: Array
    scale: float
    offset: Array
    size: tuple[int, int]

    def project(self, points: Any) -> tuple[Array, Array]:
        """Pixels (..., 2) and depths (...) [m] along the view axis of points (..., 3) [m]."""
        rel = np.asarray(points, dtype=float) - self.eye
        depth = rel @ self.forward
        dz = np.maximum(depth, 1e-6)
        uv = np.stack([rel @ self.right / dz, -(rel @ self.up) / dz], axis=-1)
        return self.scale * uv - self.offset, depth


def camera_for(
    bounds: Any, size: tuple[int, int] = (720, 540), azim: float = -60.0, elev: float = 32.0, top: int = 40
) -> Camera:
    """A fixed camera that frames the room ``bounds`` (xmin, ymin, zmin, xmax, ymax, zmax) [m]: looking at its centre
    from azimuth ``azim`` and elevation ``elev`` [deg], from 1.3 room diagonals away (a mild perspective), scaled so
    the room's eight corners fill the image below a ``top`` px title band."""
    b = np.asarray(bounds, dtype=float)
    lo, hi = b[:3], b[3:]
    centre = 0.5 * (lo + hi)
    diag = float(np.linalg.norm(hi - lo))
    az, el = math.radians(azim), math.radians(elev)
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    eye = centre + 1.3 * diag * direction
    forward = -direction
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    cam = Camera(eye, right, up, forward, 1.0, np.zeros(2), size)
    uv, _ = cam.project(corners)
    w, h = size
    margin = 16
    scale = min((w - 2 * margin) / np.ptp(uv[:, 0]), (h - top - 2 * margin) / np.ptp(uv[:, 1]))
    mid = 0.5 * (uv.min(axis=0) + uv.max(axis=0)) * scale
    offset = mid - np.array([0.5 * w, top + 0.5 * (h - top)])
    return Camera(eye, right, up, forward, float(scale), offset, size)


def frame_indices_3d(t: Any, fps: float = 10.0, max_frames: int = 150) -> NDArray[np.int64]:
    """Steps shown as frames: every round(1 / (fps Ts)) steps (real time at ``fps``), at most ``max_frames``, always
    ending with the last step."""
    t = np.asarray(t, dtype=float)
    k = t.size
    stride = max(1, int(round(1.0 / (fps * float(np.median(np.diff(t))))))) if k > 1 else 1
    stride = max(stride, math.ceil(k / max_frames))
    return np.unique(np.append(np.arange(0, k, stride), k - 1))


def _hex(c: str) -> tuple[int, int, int]:
    return int(c[1:3], 16), int(c[3:5], 16), int(c[5:7], 16)


#: Shades of the obstacle faces (Lambert, light from the upper left behind the camera), in a fixed set.
_SHADES = 12
_FACE_DARK, _FACE_LIGHT = np.array([110, 118, 128]), np.array([214, 220, 228])


def _palette() -> list[tuple[int, int, int]]:
    """Every colour the GIF uses (one palette for all frames, so frames store only their changes)."""
    greys = [(v, v, v) for v in range(0, 256, 17)]  # 16 greys: text anti-aliasing, floor, edges
    shades = [
        tuple(int(v) for v in _FACE_DARK + (_FACE_LIGHT - _FACE_DARK) * s / (_SHADES - 1)) for s in range(_SHADES)
    ]
    named = [
        _hex(c)
        for c in (
            TETHER_COLOR,
            LEADER_COLOR,
            DRONE_COLOR,
            REFERENCE_COLOR,
            "#0b3d66",
            "#8a4100",
            "#2ca02c",
            "#d62728",
            "#f4f4f4",
            "#e6e6e6",
            "#c8c8c8",
            "#ffffff",
        )
    ]
    return greys + shades + named  # type: ignore[return-value]


class _GifScene:
    """Static geometry projected once; :meth:`frame` draws one step."""

    def __init__(self, plan: Any, world: Any, size: tuple[int, int]) -> None:
        from PIL import Image, ImageDraw, ImageFont

        self.plan = plan
        self.cam = camera_for(world.bounds, size)
        self.font = ImageFont.load_default(size=13)
        self.small = ImageFont.load_default(size=11)
        x0, y0, z0, x1, y1, z1 = (float(v) for v in world.bounds)
        light = np.array([-0.4, -0.3, 0.85])
        light /= np.linalg.norm(light)
        # obstacle faces facing the camera (closed outward meshes: the others are hidden) and the sharp edges
        self.faces: list[tuple[float, list[tuple[float, float]], tuple[int, int, int]]] = []
        self.edges: list[tuple[float, list[tuple[float, float]]]] = []
        for ob in world.obstacles:
            dr = obstacle_mesh(ob)
            tri = dr.vertices[dr.faces]
            front = np.einsum("fi,fi->f", tri.mean(axis=1) - self.cam.eye, dr.normals) < 0.0
            uv, depth = self.cam.project(tri)
            lam = np.clip(0.35 + 0.65 * (dr.normals @ light), 0.0, 1.0)
            level = np.round(lam * (_SHADES - 1)).astype(int)
            for f in np.flatnonzero(front):
                col = tuple(int(v) for v in _FACE_DARK + (_FACE_LIGHT - _FACE_DARK) * level[f] / (_SHADES - 1))
                self.faces.append((float(depth[f].mean()), [tuple(p) for p in uv[f].tolist()], col))  # type: ignore[misc]
            euv, edepth = self.cam.project(dr.edges)
            for e in range(len(dr.edges)):
                self.edges.append((float(edepth[e].mean()) - 1e-3, [tuple(p) for p in euv[e].tolist()]))  # type: ignore[misc]
        # background: floor with a grid, the room's edges behind, title
        w, h = size
        bg = Image.new("RGB", size, (255, 255, 255))
        dr_ = ImageDraw.Draw(bg)
        floor, _ = self.cam.project(np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]]))
        dr_.polygon([tuple(p) for p in floor.tolist()], fill=_hex("#f4f4f4"), outline=(136, 136, 136))
        step = _grid_step(max(x1 - x0, y1 - y0))
        for x in np.arange(math.ceil(x0 / step) * step, x1 + 1e-9, step):
            ends, _ = self.cam.project(np.array([[x, y0, z0], [x, y1, z0]]))
            dr_.line([tuple(p) for p in ends.tolist()], fill=_hex("#e6e6e6"), width=1)
        for y in np.arange(math.ceil(y0 / step) * step, y1 + 1e-9, step):
            ends, _ = self.cam.project(np.array([[x0, y, z0], [x1, y, z0]]))
            dr_.line([tuple(p) for p in ends.tolist()], fill=_hex("#e6e6e6"), width=1)
        for a, b_ in _room_edges(world.bounds):
            ends, _ = self.cam.project(np.array([a, b_]))
            dr_.line([tuple(p) for p in ends.tolist()], fill=(204, 204, 204), width=1)
        title = _title(plan, "tethered drone chain")
        dr_.text((10, 8), title, fill=(0, 0, 0), font=self.font)
        dr_.text(
            (10, 24),
            f"grid {step:g} m; tethers drawn as catenaries; r = {float(plan.safety_radius):g} m",
            fill=(85, 85, 85),
            font=self.small,
        )
        self.background = bg
        self.r = float(plan.safety_radius)
        self.z0 = z0
        self.base = np.asarray(plan.base, dtype=float)
        self.goal = np.asarray(plan.goal, dtype=float)
        pal = Image.new("P", (1, 1))
        flat = [c for rgb in _palette() for c in rgb]
        pal.putpalette(flat + [0] * (768 - len(flat)))
        self.palette = pal

    def frame(self, k: int, curve: Array, trail: Array) -> Any:
        """Step ``k``'s image (palette mode): ``curve`` (N, M, 3) the tethers, ``trail`` (J, 3) the leader so far."""
        from PIL import Image, ImageDraw

        im = self.background.copy()
        d = ImageDraw.Draw(im)
        cam = self.cam
        robots = np.asarray(self.plan.robots[k], dtype=float)
        n = len(robots)
        # shadows on the floor (under everything that flies)
        ang = np.linspace(0.0, 2.0 * np.pi, 13)[:-1]
        for p in robots:
            ring = np.column_stack([p[0] + self.r * np.cos(ang), p[1] + self.r * np.sin(ang), np.full(12, self.z0)])
            uv, _ = cam.project(ring)
            d.polygon([tuple(v) for v in uv.tolist()], fill=(200, 200, 200))
        items: list[tuple[float, int, Any]] = []  # (depth, tie-break, draw)
        for depth, poly, col in self.faces:
            items.append((depth, 0, ("poly", poly, col)))
        for depth, seg in self.edges:
            items.append((depth, 1, ("line", seg, (68, 68, 68), 1)))
        uv, depth = cam.project(curve)
        for j in range(len(curve)):
            for s in range(curve.shape[1] - 1):
                seg = [tuple(uv[j, s]), tuple(uv[j, s + 1])]
                items.append((0.5 * float(depth[j, s] + depth[j, s + 1]), 2, ("line", seg, _hex(TETHER_COLOR), 3)))
        if len(trail) > 1:
            tuv, tdepth = cam.project(trail)
            for s in range(len(trail) - 1):
                seg = [tuple(tuv[s]), tuple(tuv[s + 1])]
                items.append((0.5 * float(tdepth[s] + tdepth[s + 1]), 2, ("line", seg, _hex("#2ca02c"), 2)))
        ruv, rdepth = cam.project(robots)
        for i in range(n):
            rad = max(3.0, cam.scale * self.r / max(float(rdepth[i]), 1e-6))
            face, edge = (LEADER_COLOR, "#8a4100") if i == n - 1 else (DRONE_COLOR, "#0b3d66")
            items.append((float(rdepth[i]), 3, ("disc", tuple(ruv[i]), rad, _hex(face), _hex(edge), f"R{i + 1}")))
        for p, kind in ((self.base, "anchor"), (self.goal, "goal")):
            puv, pdepth = cam.project(p)
            items.append((float(pdepth), 3, ("mark", tuple(puv), kind)))
        items.sort(key=lambda it: (-it[0], it[1]))
        for _, _, what in items:
            if what[0] == "poly":
                d.polygon(what[1], fill=what[2], outline=what[2])
            elif what[0] == "line":
                d.line(what[1], fill=what[2], width=what[3])
            elif what[0] == "disc":
                (x, y), rad = what[1], what[2]
                d.ellipse((x - rad, y - rad, x + rad, y + rad), fill=what[3], outline=what[4], width=2)
                d.text((x + rad + 2, y - rad - 2), what[5], fill=(0, 0, 0), font=self.small)
            else:
                (x, y), kind = what[1], what[2]
                if kind == "anchor":
                    d.rectangle((x - 5, y - 5, x + 5, y + 5), fill=(0, 0, 0))
                else:
                    d.regular_polygon((x, y, 9), 5, fill=_hex(LEADER_COLOR), outline=(0, 0, 0))
        t = np.asarray(self.plan.t, dtype=float)
        w, h = im.size
        d.text((w - 175, h - 22), f"t = {t[k]:6.2f} s / {t[-1]:.2f} s", fill=(0, 0, 0), font=self.font)
        return im.quantize(palette=self.palette, dither=Image.Dither.NONE)


def _grid_step(span: float) -> float:
    """A floor grid step [m] giving 5–20 lines over ``span`` [m]."""
    for step in (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0):
        if span / step <= 20:
            return step
    return 100.0


def _room_edges(bounds: Any) -> list[tuple[Array, Array]]:
    """The 12 edges of the room's box."""
    x0, y0, z0, x1, y1, z1 = (float(v) for v in bounds)
    c = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)])
    out = []
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(c[i] != c[j]) == 1:
                out.append((c[i], c[j]))
    return out


def gif_frames(
    plan: Any, world: Any, fps: float = 10.0, max_frames: int = 150, size: tuple[int, int] = (720, 540)
) -> Iterator[Any]:
    """The GIF's frames (Pillow images in palette mode) at :func:`frame_indices_3d`."""
    idx = frame_indices_3d(plan.t, fps, max_frames)
    scene = _GifScene(plan, world, size)
    curves = tether_curves(plan, CURVE_POINTS, idx)
    leader = np.asarray(plan.robots, dtype=float)[idx, -1]
    for s, k in enumerate(idx):
        yield scene.frame(int(k), curves[s], leader[: s + 1])


def write_gif_3d(
    plan: Any,
    world: Any,
    path: str | os.PathLike[str],
    fps: float = 10.0,
    max_frames: int = 150,
    size: tuple[int, int] = (720, 540),
    progress: bool = False,
) -> Path:
    """Write the 3-D perspective animation of the plan (≤ ``max_frames`` frames at ``fps``, ``size`` px) as a GIF at
    ``path`` (atomic: :func:`tmr.io.outputs.atomic_write_bytes`); the same plan gives the same bytes."""
    import io

    from tqdm import tqdm

    from tmr.io.outputs import atomic_write_bytes

    n = len(frame_indices_3d(plan.t, fps, max_frames))
    frames = list(
        tqdm(
            gif_frames(plan, world, fps, max_frames, size),
            total=n,
            desc="gif frames",
            unit="frame",
            leave=False,
            disable=not progress,
        )
    )
    buf = io.BytesIO()
    frames[0].save(buf, format="GIF", save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return atomic_write_bytes(path, buf.getvalue())


# ----------------------------------------------------------------------------------------------------------
# the HTML view (plotly)
# ----------------------------------------------------------------------------------------------------------
def _moving_traces(plan: Any, k: int, curve: Array, trail: Array) -> list[dict[str, Any]]:
    """Data of the moving traces at step k, in the order :func:`build_figure_3d` adds them: tethers, trail, drones."""
    out: list[dict[str, Any]] = []
    for j, c in enumerate(curve):
        out.append({"x": c[:, 0].tolist(), "y": c[:, 1].tolist(), "z": c[:, 2].tolist(), "name": f"tether {j + 1}"})
    out.append({"x": trail[:, 0].tolist(), "y": trail[:, 1].tolist(), "z": trail[:, 2].tolist()})
    p = np.asarray(plan.robots[k], dtype=float)
    text = [f"drone {i + 1}: ({x:.3f}, {y:.3f}, {z:.3f}) m" for i, (x, y, z) in enumerate(p)]
    out.append({"x": p[:, 0].tolist(), "y": p[:, 1].tolist(), "z": p[:, 2].tolist(), "text": text})
    return out


def build_figure_3d(plan: Any, world: Any, max_frames: int = 150) -> Any:
    """The plotly 3-D scene: obstacle meshes (translucent), floor, room edges, anchor, goal, leader reference; per
    frame the tethers (catenaries), the leader's trail and the drones; a time slider and play / pause buttons."""
    import plotly.graph_objects as go

    fig = go.Figure()
    for i, ob in enumerate(world.obstacles):
        dr = obstacle_mesh(ob)
        v, f = dr.vertices, dr.faces
        fig.add_trace(
            go.Mesh3d(
                x=v[:, 0],
                y=v[:, 1],
                z=v[:, 2],
                i=f[:, 0],
                j=f[:, 1],
                k=f[:, 2],
                color=OBSTACLE_COLOR,
                opacity=0.35,
                flatshading=True,
                name="obstacle",
                legendgroup="obstacle",
                showlegend=i == 0,
                hovertext=obstacle_label(i, ob),
                hoverinfo="text",
            )
        )
        e = dr.edges
        xs, ys, zs = (np.column_stack([e[:, 0, c], e[:, 1, c], np.full(len(e), np.nan)]).ravel() for c in range(3))
        fig.add_trace(
            go.Scatter3d(
                x=xs,
                y=ys,
                z=zs,
                mode="lines",
                line={"color": "#424242", "width": 2},
                showlegend=False,
                hoverinfo="skip",
                legendgroup="obstacle",
            )
        )
    x0, y0, z0, x1, y1, z1 = (float(v) for v in world.bounds)
    fig.add_trace(
        go.Mesh3d(
            x=[x0, x1, x1, x0],
            y=[y0, y0, y1, y1],
            z=[z0] * 4,
            i=[0, 0],
            j=[1, 2],
            k=[2, 3],
            color="#d9d9d9",
            opacity=0.4,
            name="floor",
            hoverinfo="skip",
        )
    )
    edges = _room_edges(world.bounds)
    xs, ys, zs = ([v for a, b in edges for v in (a[c], b[c], None)] for c in range(3))
    fig.add_trace(
        go.Scatter3d(
            x=xs, y=ys, z=zs, mode="lines", line={"color": "#bbbbbb", "width": 1}, name="room", hoverinfo="skip"
        )
    )
    ref = np.asarray(plan.reference, dtype=float)
    fig.add_trace(
        go.Scatter3d(
            x=ref[:, 0],
            y=ref[:, 1],
            z=ref[:, 2],
            mode="lines",
            name="leader reference",
            line={"color": REFERENCE_COLOR, "width": 3, "dash": "dash"},
            hoverinfo="skip",
        )
    )
    for name, p, sym, col in (("anchor", plan.base, "square", "black"), ("goal", plan.goal, "diamond", LEADER_COLOR)):
        p = np.asarray(p, dtype=float)
        fig.add_trace(
            go.Scatter3d(
                x=[p[0]],
                y=[p[1]],
                z=[p[2]],
                mode="markers+text",
                text=[name],
                name=name,
                marker={"symbol": sym, "size": 6, "color": col},
                hovertemplate=f"{name}: (%{{x:.3f}}, %{{y:.3f}}, %{{z:.3f}}) m<extra></extra>",
            )
        )
    n_static = len(fig.data)
    t = np.asarray(plan.t, dtype=float)
    idx = frame_indices_3d(t, 10.0, max_frames)
    curves = tether_curves(plan, CURVE_POINTS, idx)
    leader = np.asarray(plan.robots, dtype=float)[idx, -1]
    n = plan.robots.shape[1]
    first = _moving_traces(plan, int(idx[0]), curves[0], leader[:1])
    for j in range(n):
        fig.add_trace(
            go.Scatter3d(
                **first[j],
                mode="lines",
                line={"color": TETHER_COLOR, "width": 5},
                legendgroup="tether",
                showlegend=j == 0,
                hoverinfo="name",
            )
        )
    fig.add_trace(
        go.Scatter3d(
            **first[n], mode="lines", line={"color": "#17a589", "width": 3}, name="leader trail", hoverinfo="skip"
        )
    )
    r = float(plan.safety_radius)
    fig.add_trace(
        go.Scatter3d(
            **first[n + 1],
            mode="markers",
            hoverinfo="text",
            name=f"drone (r = {r:g} m)",
            marker={"size": 7, "color": _drone_colors(n), "line": {"color": "black", "width": 1}},
        )
    )
    fig.data[n_static]["name"] = "tether (catenary)"
    moving = list(range(n_static, len(fig.data)))
    frames = []
    for s, k in enumerate(idx):
        data = _moving_traces(plan, int(k), curves[s], leader[: s + 1])
        data[0]["name"] = "tether (catenary)"
        frames.append(
            go.Frame(
                data=[go.Scatter3d(**d_) for d_ in data],
                traces=moving,
                name=str(int(k)),
                layout={"title": {"text": f"{_title(plan, 'drone chain')} — t = {t[k]:.2f} s"}},
            )
        )
    fig.frames = frames
    slider = {
        "active": 0,
        "currentvalue": {"prefix": "t [s] = ", "visible": True},
        "pad": {"t": 30},
        "x": 0.2,
        "len": 0.8,
        "font": {"size": 9},
        "steps": [
            {
                "label": f"{t[k]:.2f}",
                "method": "animate",
                "args": [
                    [str(int(k))],
                    {"mode": "immediate", "frame": {"duration": 0, "redraw": True}, "transition": {"duration": 0}},
                ],
            }
            for k in idx
        ],
    }
    buttons = [
        {
            "label": "▶ play",
            "method": "animate",
            "args": [
                None,
                {"frame": {"duration": 100, "redraw": True}, "fromcurrent": True, "transition": {"duration": 0}},
            ],
        },
        {
            "label": "❚❚ pause",
            "method": "animate",
            "args": [
                [None],
                {"mode": "immediate", "frame": {"duration": 0, "redraw": False}, "transition": {"duration": 0}},
            ],
        },
    ]
    span = np.array([x1 - x0, y1 - y0, z1 - z0])
    ratio = span / span.max()
    fig.update_layout(
        title={"text": f"{_title(plan, 'drone chain')} — t = {t[idx[0]]:.2f} s"},
        scene={
            "xaxis": {"title": "x [m]", "range": [x0, x1]},
            "yaxis": {"title": "y [m]", "range": [y0, y1]},
            "zaxis": {"title": "z [m]", "range": [z0, z1]},
            "aspectmode": "manual",
            "aspectratio": {"x": ratio[0], "y": ratio[1], "z": ratio[2]},
            "camera": {"eye": {"x": -0.9, "y": -1.6, "z": 0.9}},
        },
        template="plotly_white",
        height=760,
        legend={"orientation": "h", "y": -0.05},
        updatemenus=[
            {
                "type": "buttons",
                "direction": "left",
                "x": 0.0,
                "y": 0.0,
                "xanchor": "left",
                "yanchor": "top",
                "buttons": buttons,
            }
        ],
        sliders=[slider],
    )
    return fig


def write_html_3d(plan: Any, world: Any, path: str | os.PathLike[str], max_frames: int = 150) -> Path:
    """Write the plotly 3-D scene (:func:`build_figure_3d`) as one self-contained HTML file (plotly.js embedded, as
    :func:`tmr.views.htmlview.write_html`; atomic write)."""
    from tmr.io.outputs import atomic_write_text

    fig = build_figure_3d(plan, world, max_frames=max_frames)
    html = fig.to_html(include_plotlyjs=True, full_html=True, auto_play=False, div_id="tmr-view")
    return atomic_write_text(path, html)


def write_drone_views(
    plan: Any,
    world: Any,
    out: str | os.PathLike[str],
    *,
    gif: bool = False,
    html: bool = False,
    export: str | None = None,
    progress: bool = False,
) -> list[str]:
    """Write the views a drone run asks for into the directory ``out`` under the ground views' names
    (:data:`tmr.views.flags.GIF_NAME`, ``HTML_NAME``, ``BAG_DIR``); ``export``: a bag storage (``"mcap"`` or
    ``"sqlite3"``) or None. Return the names written."""
    from tmr.views.flags import BAG_DIR, GIF_NAME, HTML_NAME

    out = Path(out)
    written: list[str] = []
    if export:
        from tmr.export.rosbag import write_drone_bag

        write_drone_bag(plan, world, out / BAG_DIR, storage=export, progress=progress)
        written.append(BAG_DIR)
    if html:
        write_html_3d(plan, world, out / HTML_NAME)
        written.append(HTML_NAME)
    if gif:
        write_gif_3d(plan, world, out / GIF_NAME, progress=progress)
        written.append(GIF_NAME)
    return written
