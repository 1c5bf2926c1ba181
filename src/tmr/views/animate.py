"""Animated GIF of a :class:`tmr.views.motion.Motion`: the plan seen from above, frame by frame.

Drawn on a matplotlib Agg canvas (no ``pyplot``) and encoded with matplotlib's ``PillowWriter``: raw obstacles
(filled), obstacles grown by the safety radius (dashed), the room, the anchor / goal / task points, the tethers,
cables and links (tethers shaded by their catenary sag, Caruso 2021 eq. 22, with a colour bar), robots and bases
as discs of their radius, the leader's (platform's, end-effector's) trail so far, and the time stamp. MoPICK and
CCMA plans move in height too: under the top view, a side view (x–z, same scale) shows the cables, links, bodies
and the trail by height.

Frames are taken every ``stride`` samples so that the GIF plays at ``fps`` frames per second in real time when
the plan has a time law (one frame per ``1 / fps`` s of plan time); the last sample is always the last frame.
Deterministic: the same motion gives the same bytes.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from tmr.views.motion import Motion

__all__ = ["frame_indices", "render_frame", "write_gif"]

_ROLE_STYLE = {  # face, edge
    "robot": ("#1f77b4", "#0b3d66"),
    "leader": ("#ff7f0e", "#8a4100"),
    "base": ("#7f7f7f", "#333333"),
    "platform": ("#d62728", "#6b0f10"),
    "agent": ("#9467bd", "#4a2a66"),
    "end_effector": ("#dc143c", "#6b0f10"),
}
_LINE_COLOR = {"cable": "#d62728", "link": "#2ca02c"}
_SAG_CMAP = "plasma_r"
_TRAIL = "#17a589"


def frame_indices(motion: Motion, fps: float = 10.0, max_frames: int = 200) -> np.ndarray:
    """Sample indices shown as frames: every ``stride`` samples, stride = round(1 / (fps Ts)) for a timed motion
    (so the GIF plays in real time at ``fps``), at most ``max_frames`` frames, always ending with the last sample."""
    k = motion.n_samples
    stride = 1
    if motion.timed and k > 1:
        ts = float(np.median(np.diff(motion.t)))
        stride = max(1, int(round(1.0 / (fps * ts))))
    stride = max(stride, int(np.ceil(k / max_frames)))
    idx = np.arange(0, k, stride)
    return np.unique(np.append(idx, k - 1))


def _stamp(motion: Motion, k: int) -> str:
    if motion.timed:
        return f"t = {motion.t[k]:6.2f} s / {motion.t[-1]:.2f} s"
    return f"sample {k + 1} / {motion.n_samples}"


class _Scene:
    """The figure, its static layer and the artists updated per frame."""

    def __init__(self, motion: Motion, width: float = 6.4, dpi: int = 80) -> None:
        from matplotlib import colormaps
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.collections import LineCollection
        from matplotlib.colors import Normalize
        from matplotlib.figure import Figure
        from matplotlib.lines import Line2D
        from matplotlib.patches import Circle, PathPatch, Rectangle
        from matplotlib.path import Path as MplPath

        from tmr.views.plot import _boundary_segments, _polygon_path  # shapely → matplotlib helpers

        self.m = motion
        x0, y0, x1, y1 = motion.extent(pad=0.3)
        aspect = (y1 - y0) / max(x1 - x0, 1e-9)
        # MoPICK and CCMA move in height too: a side view (x–z, same x scale) under the top view
        self.side = motion.system in ("mcdpr", "ccma")
        z0, z1 = 0.0, 1.0
        if self.side:
            zs = [np.asarray(tr.xyz)[:, 2] for tr in motion.tracks] + [
                np.asarray(ln.points)[..., 2].ravel() for ln in motion.lines
            ]
            zall = np.concatenate(zs)
            z0, z1 = min(0.0, float(zall.min())) - 0.1, float(zall.max()) + 0.15
        zaspect = (z1 - z0) / max(x1 - x0, 1e-9) if self.side else 0.0
        height = 0.8 * width * (aspect + zaspect) + 1.3 + (0.5 if self.side else 0.0)
        self.fig = Figure(figsize=(width, min(max(height, 3.5), 9.5)), dpi=dpi, layout="constrained")
        FigureCanvasAgg(self.fig)
        if self.side:
            ax, axz = self.fig.subplots(2, 1, sharex=True, height_ratios=[y1 - y0, max(z1 - z0, 0.25 * (y1 - y0))])
        else:
            ax, axz = self.fig.add_subplot(), None
        self.ax = ax
        self.axz = axz
        handles: list[Any] = []
        if motion.obstacles:
            path = MplPath.make_compound_path(*[_polygon_path(p) for p in motion.obstacles])
            ax.add_patch(PathPatch(path, facecolor="#9e9e9e", edgecolor="#424242", lw=0.8, zorder=1))
            handles.append(Rectangle((0, 0), 1, 1, facecolor="#9e9e9e", edgecolor="#424242", label="obstacle"))
        from tmr.views.plot import draw_low_obstacles

        handles += draw_low_obstacles(ax, motion.low_obstacles)
        if motion.inflated_in_room():
            segs = [s for p in motion.inflated_in_room() for s in _boundary_segments(p)]
            ax.add_collection(LineCollection(segs, colors="#555555", linestyles=(0, (4, 3)), linewidths=0.8, zorder=2))
            handles.append(Line2D([], [], color="#555555", ls=(0, (4, 3)), lw=0.8, label="grown by robot radius"))
        if motion.system != "ccma":
            bx0, by0, bx1, by1 = motion.bounds
            ax.add_patch(Rectangle((bx0, by0), bx1 - bx0, by1 - by0, fill=False, edgecolor="black", lw=1.4, zorder=3))
        for name, p in motion.points.items():
            if name == "anchor":
                ax.plot(p[0], p[1], "s", ms=8, color="black", zorder=8)
                handles.append(Line2D([], [], marker="s", ms=7, color="black", ls="", label="anchor"))
            elif name == "goal":
                ax.plot(p[0], p[1], "*", ms=14, color="#ff7f0e", mec="black", mew=0.6, zorder=8)
                handles.append(Line2D([], [], marker="*", ms=11, color="#ff7f0e", mec="black", ls="", label="goal"))
            else:
                ax.plot(p[0], p[1], "X", ms=8, color="#2ca02c", mec="black", mew=0.5, zorder=8)
                ax.annotate(name, (p[0], p[1]), xytext=(4, 4), textcoords="offset points", fontsize=7, zorder=9)
        if any(n.startswith("task") for n in motion.points):
            handles.append(Line2D([], [], marker="X", ms=7, color="#2ca02c", mec="black", ls="", label="task point"))

        # moving lines: tethers shaded by sag, others plain
        self.tethers = [ln for ln in motion.lines if ln.sag is not None]
        self.plain = [ln for ln in motion.lines if ln.sag is None]
        self.norm = None
        if self.tethers:
            smax = max(float(np.max(ln.sag)) for ln in self.tethers)
            self.norm = Normalize(0.0, max(smax, 1e-3))
            from matplotlib.colors import ListedColormap

            # the light end of the map left out: a slack tether stays visible on white
            self.cmap = ListedColormap(colormaps[_SAG_CMAP](np.linspace(0.25, 1.0, 256)), name="sag")
            self.tether_lc = LineCollection([], linewidths=2.6, zorder=5, capstyle="round")
            ax.add_collection(self.tether_lc)
            from matplotlib.cm import ScalarMappable

            sm = ScalarMappable(norm=self.norm, cmap=self.cmap)
            cbar = self.fig.colorbar(sm, ax=ax, shrink=0.8, pad=0.02)
            cbar.set_label("tether sag [m] (catenary)")
            handles.append(Line2D([], [], color=self.cmap(0.6), lw=2.6, label="tether (shade = sag)"))
        self.plain_lc = LineCollection(
            [], colors=[_LINE_COLOR.get(ln.kind, "#2ca02c") for ln in self.plain], linewidths=1.6, zorder=5
        )
        ax.add_collection(self.plain_lc)
        for kind in sorted({ln.kind for ln in self.plain}):
            handles.append(Line2D([], [], color=_LINE_COLOR.get(kind, "#2ca02c"), lw=1.6, label=kind))

        # trail of the leader / platform / end-effector
        self.trail = motion.track(motion.trail) if motion.trail else None
        if self.trail is not None:
            (self.trail_line,) = ax.plot([], [], color=_TRAIL, lw=1.8, zorder=4.5)
            handles.append(
                Line2D(
                    [],
                    [],
                    color=_TRAIL,
                    lw=1.8,
                    label=f"{'leader' if self.trail.role == 'leader' else self.trail.name} trail",
                )
            )

        # bodies: discs of their radius (or dots), with a heading tick when they have a yaw
        self.discs: list[tuple[Any, Any, Any]] = []
        seen: set[str] = set()
        for tr in motion.tracks:
            face, edge = _ROLE_STYLE.get(tr.role, ("#1f77b4", "#0b3d66"))
            if tr.radius > 0:
                disc = Circle((0, 0), tr.radius, facecolor=face, edgecolor=edge, alpha=0.45, lw=1.2, zorder=6)
                ax.add_patch(disc)
            else:
                (disc,) = ax.plot([], [], "o", ms=6, color=face, mec=edge, zorder=7)
            tick = ax.plot([], [], color=edge, lw=1.2, zorder=7)[0] if tr.yaw is not None else None
            label = ax.text(0, 0, "", fontsize=7, ha="center", va="bottom", zorder=9)
            self.discs.append((disc, tick, label))
            if tr.role not in seen:
                seen.add(tr.role)
                r_txt = f" (r = {tr.radius:g} m)" if tr.radius > 0 else ""
                handles.append(
                    Line2D([], [], marker="o", ms=9, ls="", mfc=face, mec=edge, alpha=0.7, label=f"{tr.role}{r_txt}")
                )
        self.clock = ax.text(
            0.02,
            0.98,
            "",
            transform=ax.transAxes,
            ha="left",
            va="top",
            fontsize=10,
            family="monospace",
            zorder=10,
            bbox={"boxstyle": "round,pad=0.25", "facecolor": "white", "alpha": 0.85, "edgecolor": "#999999"},
        )
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.set_title(motion.title, fontsize=10)
        if axz is not None:
            self._side_view(axz, x0, x1, z0, z1)
            ax.set_xlabel("")
        self.fig.legend(handles=handles, loc="outside lower center", ncols=4, fontsize=7, frameon=False)
        self.update(0)
        self.fig.canvas.draw()  # lay out once (constrained), then keep that layout for every frame (fast, steady)
        self.fig.set_layout_engine("none")

    def _side_view(self, axz: Any, x0: float, x1: float, z0: float, z1: float) -> None:
        """Side view: the floor, fixed points, and per frame the lines, bodies and trail projected on x–z."""
        from matplotlib.collections import LineCollection

        m = self.m
        axz.axhline(0.0, color="black", lw=1.2, zorder=1)
        for p in m.points.values():
            axz.plot(p[0], p[2], "X", ms=7, color="#2ca02c", mec="black", mew=0.5, zorder=8)
        self.side_lc = LineCollection(
            [], colors=[_LINE_COLOR.get(ln.kind, "#5b2c83") for ln in m.lines], linewidths=1.6, zorder=5
        )
        axz.add_collection(self.side_lc)
        self.side_dots = [
            axz.plot(
                [], [], "o", ms=6, color=_ROLE_STYLE.get(tr.role, ("#1f77b4", ""))[0], mec="black", mew=0.4, zorder=7
            )[0]
            for tr in m.tracks
        ]
        (self.side_trail,) = axz.plot([], [], color=_TRAIL, lw=1.6, zorder=4.5)
        axz.set_xlim(x0, x1)
        axz.set_ylim(z0, z1)
        axz.set_aspect("equal")
        axz.set_xlabel("x [m]")
        axz.set_ylabel("z [m]")
        axz.grid(True, lw=0.3, alpha=0.5)
        axz.set_title("side view (x–z)", fontsize=8)

    def animated(self) -> list[Any]:
        """The artists that change from frame to frame."""
        out: list[Any] = [self.plain_lc, self.clock]
        if self.axz is not None:
            out += [self.side_lc, self.side_trail, *self.side_dots]
        if self.tethers:
            out.append(self.tether_lc)
        if self.trail is not None:
            out.append(self.trail_line)
        for disc, tick, label in self.discs:
            out += [disc, label] + ([tick] if tick is not None else [])
        return out

    def update(self, k: int) -> None:
        m = self.m
        if self.tethers:
            self.tether_lc.set_segments([ln.points[k, :, :2] for ln in self.tethers])
            self.tether_lc.set_color([self.cmap(self.norm(float(ln.sag[k]))) for ln in self.tethers])
        self.plain_lc.set_segments([ln.points[k, :, :2] for ln in self.plain])
        if self.trail is not None:
            self.trail_line.set_data(self.trail.xyz[: k + 1, 0], self.trail.xyz[: k + 1, 1])
        for tr, (disc, tick, label) in zip(m.tracks, self.discs, strict=True):
            x, y = float(tr.xyz[k, 0]), float(tr.xyz[k, 1])
            if tr.radius > 0:
                disc.center = (x, y)
            else:
                disc.set_data([x], [y])
            if tick is not None:
                rr = max(tr.radius, 0.06) * 1.4
                tick.set_data([x, x + rr * np.cos(tr.yaw[k])], [y, y + rr * np.sin(tr.yaw[k])])
            if tr.role in ("robot", "leader", "base"):
                label.set_position((x, y + 1.05 * tr.radius))
                label.set_text(tr.name.replace("robot", "R").replace("base", "B"))
        self.clock.set_text(_stamp(m, k))
        if self.axz is not None:
            self.side_lc.set_segments([ln.points[k][:, [0, 2]] for ln in m.lines])
            for tr, dot in zip(m.tracks, self.side_dots, strict=True):
                dot.set_data([tr.xyz[k, 0]], [tr.xyz[k, 2]])
            if self.trail is not None:
                self.side_trail.set_data(self.trail.xyz[: k + 1, 0], self.trail.xyz[: k + 1, 2])

    def frames(self, indices: np.ndarray) -> Any:
        """RGBA images of the given samples: the static layer is drawn once, then only the moving artists are
        drawn over a copy of it (blitting), frame after frame."""
        from PIL import Image

        canvas = self.fig.canvas
        moving = self.animated()
        for a in moving:
            a.set_animated(True)  # left out of the full draw below
        canvas.draw()
        background = canvas.copy_from_bbox(self.fig.bbox)
        for k in indices:
            canvas.restore_region(background)
            self.update(int(k))
            for a in moving:
                a.axes.draw_artist(a)
            buf = canvas.buffer_rgba()
            yield Image.frombuffer("RGBA", (buf.shape[1], buf.shape[0]), bytes(buf), "raw", "RGBA", 0, 1)


def render_frame(motion: Motion, k: int, path: str | os.PathLike[str], dpi: int = 80) -> Path:
    """One frame (sample ``k``) as a PNG, for a quick look."""
    from tmr.views.plot import save_figure

    sc = _Scene(motion, dpi=dpi)
    sc.update(k)
    return save_figure(sc.fig, path, dpi=dpi)


def write_gif(
    motion: Motion,
    path: str | os.PathLike[str],
    fps: float = 10.0,
    dpi: int = 80,
    max_frames: int = 200,
    progress: bool = False,
) -> Path:
    """Write the animation of ``motion`` as a GIF at ``path`` (atomic: :func:`tmr.io.outputs.atomic_write_bytes`);
    return the path. ``fps`` frames per second; ``dpi`` sets the size (6.4 in wide → 512 px at 80 dpi); ``progress``: a
    tqdm bar over the frames on stderr."""
    import io

    from tmr.io.outputs import atomic_write_bytes

    sc = _Scene(motion, dpi=dpi)
    from tqdm import tqdm

    idx = frame_indices(motion, fps, max_frames)
    logging.getLogger("tmr").debug("GIF: drawing %d frames", len(idx))
    frames = tqdm(sc.frames(idx), total=len(idx), desc="gif frames", unit="frame", leave=False, disable=not progress)
    images = [im.convert("RGB") for im in frames]
    buf = io.BytesIO()  # saved as matplotlib's PillowWriter saves its frames, with the frames drawn by blitting
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return atomic_write_bytes(path, buf.getvalue())
