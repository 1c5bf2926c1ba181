"""Animated GIF of a replay, rendered offscreen by MuJoCo from the simulated states (Pillow writes the GIF).

MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when it is first imported: :func:`select_backend` sets
``egl`` (GPU or Mesa's EGL, headless) unless the user chose one (``MUJOCO_GL=osmesa`` for software rendering);
when no OpenGL context can be made, :func:`render_gif` draws the same simulated states with matplotlib instead
and says so.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

__all__ = ["render_drone_gif", "render_gif", "select_backend"]

#: frames per second of the GIF, and its size [px]
FPS = 10
WIDTH, HEIGHT = 640, 480
#: radius the tethers are drawn with [m] (the simulated cable is 2 mm thick)
VISUAL_TETHER_RADIUS = 0.02


def select_backend() -> None:
    """Set ``MUJOCO_GL=egl`` before MuJoCo is imported, unless the user set it."""
    os.environ.setdefault("MUJOCO_GL", "egl")


def frames_mujoco(model: Any, states: list[Any], bounds: Any, every: int, prepare: Any = None) -> list[Any]:
    """Offscreen MuJoCo frames of every ``every``-th state (qpos) over a room ``bounds`` (x0, y0, x1, y1) [m];
    ``prepare(model, data)`` runs before each frame (e.g. to resize the tether capsules)."""
    import mujoco
    from PIL import Image

    d = mujoco.MjData(model)
    xmin, ymin, xmax, ymax = bounds
    cam = mujoco.MjvCamera()
    cam.lookat[:] = [(xmin + xmax) / 2, (ymin + ymax) / 2, 0.0]
    cam.distance = 1.25 * max(xmax - xmin, ymax - ymin)
    cam.elevation = -62.0
    cam.azimuth = 90.0
    frames = []
    with mujoco.Renderer(model, HEIGHT, WIDTH) as renderer:
        for k in range(0, len(states), every):
            d.qpos[:] = states[k]
            mujoco.mj_kinematics(model, d)
            if prepare is not None:
                prepare(model, d)
            mujoco.mj_forward(model, d)
            renderer.update_scene(d, camera=cam)
            frames.append(Image.fromarray(renderer.render()))
    return frames


def _frames_mujoco(rp: Any, run: Any, every: int) -> list[Any]:
    cm = rp.built
    m = cm.model
    radius = m.geom_size[:, 0].copy()
    for ts in cm.tethers:  # drawn thicker than the 2 mm cable so that it shows at this scale
        m.geom_size[ts.geom, 0] = VISUAL_TETHER_RADIUS

    def prepare(model: Any, data: Any) -> None:
        for ts in cm.tethers:
            ts.update(model, data)  # capsule sizes of this sample

    try:
        return frames_mujoco(m, rp.qpos, run.bounds, every, prepare)
    finally:
        m.geom_size[:, 0] = radius


def write_gif(frames: list[Any], path: Path) -> None:
    """Frames (PIL images) to an animated GIF at :data:`FPS`, written atomically."""
    import io

    from tmr.io.outputs import atomic_write_bytes

    buf = io.BytesIO()
    frames[0].save(buf, format="GIF", save_all=True, append_images=frames[1:], duration=int(1000 / FPS), loop=0)
    atomic_write_bytes(path, buf.getvalue())


def _frame(fig: Any) -> Any:
    """A matplotlib figure as an RGB PIL image (rendered to PNG in memory); the figure is closed."""
    import io

    import matplotlib.pyplot as plt
    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return Image.open(io.BytesIO(buf.getvalue())).convert("RGB")


def _frames_matplotlib(rp: Any, run: Any, every: int) -> list[Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = []
    xmin, ymin, xmax, ymax = run.bounds
    for k in range(0, len(rp.nodes), every):
        fig, ax = plt.subplots(figsize=(WIDTH / 100, HEIGHT / 100), dpi=100)
        for poly in run.obstacles:
            ax.fill(*poly.exterior.xy, color="0.55")
        if getattr(run, "low_obstacles", ()):  # a tether may pass over them: lighter, hatched, with their height
            from tmr.views.plot import draw_low_obstacles

            draw_low_obstacles(ax, run.low_obstacles)
        for nd in rp.nodes[k]:
            ax.plot(nd[:, 0], nd[:, 1], color="tab:orange", lw=1.5)
        for i, p in enumerate(rp.actual[k]):
            ax.add_patch(plt.Circle(p, run.robot_radius, color="tab:blue", alpha=0.5))
            ax.annotate(str(i + 1), p, ha="center", va="center", fontsize=8)
        ax.plot(*run.anchor, "ks")
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_aspect("equal")
        ax.set_title(f"t = {rp.t[k]:.2f} s (top view of the simulated states)", fontsize=9)
        frames.append(_frame(fig))
    return frames


def render_gif(rp: Any, run: Any, path: Path) -> str:
    """Write ``path`` (GIF, :data:`FPS` frames per second of simulated time); return the renderer used
    ("mujoco-egl", "mujoco-osmesa" or "matplotlib")."""
    Ts = float(rp.t[1] - rp.t[0]) if rp.t.size > 1 else 0.1
    every = max(1, int(round(1.0 / (FPS * Ts))))
    used = "matplotlib"
    try:
        frames = _frames_mujoco(rp, run, every)
        used = f"mujoco-{os.environ.get('MUJOCO_GL', 'default')}"
    except Exception:  # noqa: BLE001 - no OpenGL context on this machine: draw the same states with matplotlib
        frames = _frames_matplotlib(rp, run, every)
    write_gif(frames, path)
    return used


def _drone_frames_matplotlib(rp: Any, run: Any, every: int) -> list[Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tmr.replay.figures import _boxes

    frames = []
    b = [float(v) for v in run.bounds]
    for k in range(0, len(rp.nodes), every):
        fig, axes = plt.subplots(1, 2, figsize=(WIDTH / 100, HEIGHT / 100), dpi=100)
        for ax, (u, w) in zip(axes, ((0, 1), (0, 2)), strict=True):
            for lo, hi in _boxes(run.world_table):
                ax.fill([lo[u], hi[u], hi[u], lo[u]], [lo[w], lo[w], hi[w], hi[w]], color="0.6")
            for nd in rp.nodes[k]:
                ax.plot(nd[:, u], nd[:, w], color="tab:orange", lw=1.5)
            ax.plot(rp.actual[k, :, u], rp.actual[k, :, w], "o", color="tab:blue")
            ax.set_xlim(b[u], b[u + 3])
            ax.set_ylim(b[w], b[w + 3])
            ax.set_aspect("equal")
        fig.suptitle(f"t = {rp.t[k]:.2f} s (top and side views of the simulated states)", fontsize=9)
        frames.append(_frame(fig))
    return frames


#: the model arrays a tether's update() writes (:meth:`tmr.replay.tether.TetherState.update`) and the GIF's visual
#: radius changes
_TETHER_MODEL_FIELDS = ("geom_size", "geom_pos", "geom_rbound", "geom_aabb", "body_mass", "body_inertia")


def render_drone_gif(rp: Any, run: Any, path: Path) -> str:
    """Write ``path`` for a drone replay (:class:`tmr.replay.drones.DroneReplay`), :data:`FPS` frames per second of
    simulated time, rendered by MuJoCo offscreen (matplotlib top and side views when no OpenGL context can be made);
    return the renderer used."""
    Ts = float(rp.t[1] - rp.t[0]) if rp.t.size > 1 else 0.1
    every = max(1, int(round(1.0 / (FPS * Ts))))
    b = [float(v) for v in run.bounds]
    used = "matplotlib"
    try:
        dm = rp.built
        m = dm.model
        # everything the rendering changes (the visual radius here, the tethers' update() per frame), restored after
        saved = {name: getattr(m, name).copy() for name in _TETHER_MODEL_FIELDS}
        resized = [ts._resized for ts in dm.tethers]
        for ts in dm.tethers:
            m.geom_size[ts.geom, 0] = VISUAL_TETHER_RADIUS

        def prepare(model: Any, data: Any) -> None:
            for ts in dm.tethers:
                ts.update(model, data)

        try:
            frames = frames_mujoco(m, rp.qpos, (b[0], b[1], b[3], b[4]), every, prepare)
        finally:
            for name, value in saved.items():
                getattr(m, name)[...] = value
            for ts, r in zip(dm.tethers, resized, strict=True):
                ts._resized = r
        used = f"mujoco-{os.environ.get('MUJOCO_GL', 'default')}"
    except Exception:  # noqa: BLE001 - no OpenGL context on this machine: draw the same states with matplotlib
        frames = _drone_frames_matplotlib(rp, run, every)
    write_gif(frames, path)
    return used
