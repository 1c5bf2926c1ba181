"""Figures of a replay (matplotlib, Agg): tether heights and tensions against the catenary, tracking errors,
planned and simulated paths over the map. Every figure is written with :func:`tmr.views.plot.save_figure`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = [
    "chain_figures",
    "drone_figures",
    "plot_drone_paths",
    "plot_drone_tensions",
    "plot_heights",
    "plot_rotor_thrust",
    "plot_tensions",
    "plot_topview",
    "plot_tracking",
]

_COLORS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive"]


def _fig(rows: int = 1, height: float = 3.6) -> tuple[Any, Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(rows, 1, figsize=(8.0, height * rows), sharex=True, squeeze=False)
    return fig, ax[:, 0]


def plot_heights(rp: Any, title: str) -> Any:
    """Lowest point of every tether over time (solid) and the static catenary of the same ends (dashed) [m]."""
    fig, (ax,) = _fig()
    for j in range(rp.lowest.shape[1]):
        c = _COLORS[j % len(_COLORS)]
        ax.plot(rp.t, rp.lowest[:, j], color=c, lw=1.8, label=f"tether {j + 1}, MuJoCo")
        ax.plot(rp.t, rp.lowest_catenary[:, j], color=c, lw=1.2, ls="--", label=f"tether {j + 1}, catenary")
    ax.axhline(0.0, color="k", lw=1.0)
    ax.fill_between(rp.t, -1.0, 0.0, color="0.85")
    lo = min(float(rp.lowest.min()), float(rp.lowest_catenary.min()))
    ax.set_ylim(min(-0.02, lo - 0.02), float(max(rp.lowest.max(), rp.lowest_catenary.max())) + 0.03)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("lowest point of the tether [m]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="lower left")
    fig.tight_layout()
    return fig


def plot_tensions(rp: Any, title: str) -> Any:
    """Tension at the winch end and at the far end of every tether (solid) and the catenary's (dashed) [N]."""
    fig, axes = _fig(2, 3.0)
    for j in range(rp.tension_winch.shape[1]):
        c = _COLORS[j % len(_COLORS)]
        axes[0].plot(rp.t, rp.tension_winch[:, j], color=c, lw=1.5, label=f"tether {j + 1}")
        axes[0].plot(rp.t, rp.tension_winch_catenary[:, j], color=c, lw=1.0, ls="--")
        axes[1].plot(rp.t, rp.tension_far[:, j], color=c, lw=1.5, label=f"tether {j + 1}")
        axes[1].plot(rp.t, rp.tension_far_catenary[:, j], color=c, lw=1.0, ls="--")
    axes[0].set_ylabel("winch end [N]")
    axes[1].set_ylabel("far end [N]")
    axes[1].set_xlabel("t [s]")
    axes[0].set_title(title + " (dashed: catenary)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return fig


def plot_tracking(rp: Any, title: str) -> Any:
    """Distance between each robot and its tracked reference [m], with the tolerance."""
    fig, (ax,) = _fig()
    for i in range(rp.tracking_error.shape[1]):
        ax.plot(rp.t, 1000 * rp.tracking_error[:, i], color=_COLORS[i % len(_COLORS)], label=f"robot {i + 1}")
    ax.axhline(1000 * rp.config.tolerance, color="r", ls=":", label="tolerance")
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tracking error [mm]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_topview(rp: Any, run: Any, title: str) -> Any:
    """The map (obstacles filled, grown obstacles dashed), planned paths (thin) and simulated paths (thick), the
    tethers' horizontal projection every 1 s, and the first contact of each kind (x)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 7.0))
    for poly in run.obstacles:
        x, y = poly.exterior.xy
        ax.fill(x, y, color="0.55", zorder=1)
    if getattr(run, "low_obstacles", ()):  # a tether may pass over them: lighter, hatched, with their height
        from tmr.views.plot import draw_low_obstacles

        draw_low_obstacles(ax, run.low_obstacles, zorder=1.2)
    for poly in run.grown:
        x, y = poly.exterior.xy
        ax.plot(x, y, color="0.5", ls="--", lw=0.7, zorder=1)
    xmin, ymin, xmax, ymax = run.bounds
    ax.plot([xmin, xmax, xmax, xmin, xmin], [ymin, ymin, ymax, ymax, ymin], color="k", lw=1.2)
    ax.plot(*run.anchor, "ks", ms=8, label="anchor")
    n = rp.actual.shape[1]
    for i in range(n):
        c = _COLORS[i % len(_COLORS)]
        ax.plot(rp.reference[:, i, 0], rp.reference[:, i, 1], color=c, lw=0.8, ls="--")
        ax.plot(rp.actual[:, i, 0], rp.actual[:, i, 1], color=c, lw=2.0, alpha=0.8, label=f"robot {i + 1}")
    Ts = float(rp.t[1] - rp.t[0]) if rp.t.size > 1 else 1.0
    every = max(1, int(round(1.0 / Ts)))
    for k in range(0, len(rp.nodes), every):
        for nd in rp.nodes[k]:
            ax.plot(nd[:, 0], nd[:, 1], color="tab:orange", lw=0.6, alpha=0.5)
    for kind, c in rp.contacts.items():
        if c["count"]:
            ax.plot(c["where"][0], c["where"][1], "rx", ms=12, mew=2.5)
            ax.annotate(kind, c["where"][:2], color="r", fontsize=8, xytext=(5, 5), textcoords="offset points")
    ax.set_aspect("equal")
    ax.set_xlim(xmin - 0.3, xmax + 0.3)
    ax.set_ylim(ymin - 0.3, ymax + 0.3)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title + "\nplanned (dashed) and simulated paths, tethers every 1 s")
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return fig


def _save(out: Path, figs: dict[str, Any]) -> list[str]:
    """Write every figure of ``figs`` (name: figure) into ``out`` and close it; return the names."""
    import matplotlib.pyplot as plt

    from tmr.views.plot import save_figure

    for name, fig in figs.items():
        save_figure(fig, out / name)
        plt.close(fig)
    return list(figs)


def chain_figures(out: Path, rp: Any, run: Any) -> list[str]:
    """Write the four PNG figures of a chain replay into ``out``; return their names."""
    label = f"MuJoCo replay: {run.label}"
    figs = {
        "tether_heights.png": plot_heights(rp, label),
        "tensions.png": plot_tensions(rp, label),
        "tracking.png": plot_tracking(rp, label),
        "topview.png": plot_topview(rp, run, label),
    }
    return _save(out, figs)


def plot_drone_tensions(rp: Any, title: str) -> Any:
    """Tension at each drone tether's start (base or drone j-1) and at drone j (solid), the static catenary of the
    simulated ends (dashed) and the planner's catenary of the planned ends (dotted) [N]."""
    fig, axes = _fig(2, 3.0)
    for j in range(rp.tension_from.shape[1]):
        c = _COLORS[j % len(_COLORS)]
        for ax, x, xc, xp in (
            (axes[0], rp.tension_from, rp.tension_from_catenary, rp.tension_from_plan),
            (axes[1], rp.tension_to, rp.tension_to_catenary, rp.tension_to_plan),
        ):
            ax.plot(rp.t, x[:, j], color=c, lw=1.5, label=f"tether {j + 1}")
            ax.plot(rp.t, xc[:, j], color=c, lw=1.0, ls="--")
            ax.plot(rp.t, xp[:, j], color=c, lw=1.0, ls=":")
    axes[0].set_ylabel("start end [N]")
    axes[1].set_ylabel("drone end [N]")
    axes[1].set_xlabel("t [s]")
    axes[0].set_title(title + " (dashed: catenary of the simulated ends, dotted: plan)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return fig


def plot_rotor_thrust(rp: Any, title: str) -> Any:
    """Largest rotor thrust of each drone per plan sample with the rotor limit f_max and the planner's budget
    (1 − reserve) f_max [N], and each drone's tilt [deg]."""
    import numpy as np

    fig, axes = _fig(2, 3.0)
    for i in range(rp.rotor_max.shape[1]):
        c = _COLORS[i % len(_COLORS)]
        axes[0].plot(rp.t[1:], rp.rotor_max[1:, i], color=c, lw=1.3, label=f"drone {i + 1}")
        axes[1].plot(rp.t, np.degrees(rp.tilt[:, i]), color=c, lw=1.3, label=f"drone {i + 1}")
    axes[0].axhline(rp.rotor_limit, color="r", ls=":", label="rotor limit f_max")
    reserve = rp.reserve_thrust / 4.0  # (1 − r_c) f_max: the planner's budget per rotor
    if np.isfinite(reserve):
        axes[0].axhline(reserve, color="darkorange", ls="--", label="(1 − reserve) f_max (planner)")
    axes[1].axhline(np.degrees(rp.config.max_tilt), color="r", ls=":", label="crash")
    axes[0].set_ylabel("largest rotor thrust [N]")
    axes[1].set_ylabel("tilt [deg]")
    axes[1].set_xlabel("t [s]")
    axes[0].set_title(title)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return fig


def _boxes(world: Any) -> list[tuple[Any, Any]]:
    """(lo, hi) axis-aligned boxes of a ``[world]`` table's obstacles (prisms and meshes by their bounding boxes)."""
    import numpy as np

    out = []
    for item in (world or {}).get("obstacles") or []:
        if "box" in item:
            c = np.asarray(item["box"], dtype=float)
            out.append((c[:3], c[3:]))
        elif "prism" in item:
            xy = np.asarray(item["prism"], dtype=float)
            z = np.asarray(item["z"], dtype=float)
            out.append((np.r_[xy.min(axis=0), z[0]], np.r_[xy.max(axis=0), z[1]]))
    return out


def plot_drone_paths(rp: Any, run: Any, title: str) -> Any:
    """Top (x-y) and side (x-z) views: the obstacles (boxes; prisms by their bounding boxes; meshes not drawn),
    planned (dashed) and simulated (solid) drone paths, the tethers every 1 s, the first contact of each kind (x)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    fig, axes = plt.subplots(1, 2, figsize=(12.0, 5.5))
    b = [float(v) for v in run.bounds]
    for ax, (u, w) in zip(axes, ((0, 1), (0, 2)), strict=True):
        for lo, hi in _boxes(run.world_table):
            ax.add_patch(Rectangle((lo[u], lo[w]), hi[u] - lo[u], hi[w] - lo[w], color="0.6", alpha=0.6, lw=0))
        ax.plot([b[u], b[u + 3], b[u + 3], b[u], b[u]], [b[w], b[w], b[w + 3], b[w + 3], b[w]], color="k", lw=1.0)
        ax.plot(run.base[u], run.base[w], "ks", ms=7, label="winch")
        for i in range(rp.actual.shape[1]):
            c = _COLORS[i % len(_COLORS)]
            ax.plot(rp.reference[:, i, u], rp.reference[:, i, w], color=c, lw=0.8, ls="--")
            ax.plot(rp.actual[:, i, u], rp.actual[:, i, w], color=c, lw=2.0, alpha=0.8, label=f"drone {i + 1}")
        Ts = float(rp.t[1] - rp.t[0]) if rp.t.size > 1 else 1.0
        for k in range(0, len(rp.nodes), max(1, int(round(1.0 / Ts)))):
            for nd in rp.nodes[k]:
                ax.plot(nd[:, u], nd[:, w], color="tab:orange", lw=0.6, alpha=0.6)
        for kind, c in rp.contacts.items():
            if c["count"]:
                ax.plot(c["where"][u], c["where"][w], "rx", ms=12, mew=2.5)
                ax.annotate(kind, (c["where"][u], c["where"][w]), color="r", fontsize=8)
        ax.set_aspect("equal")
        ax.set_xlabel("xyz"[u] + " [m]")
        ax.set_ylabel("xyz"[w] + " [m]")
        ax.grid(alpha=0.3)
    axes[0].set_title("top view")
    axes[1].set_title("side view")
    axes[0].legend(fontsize=7, loc="upper right")
    fig.suptitle(title + ": planned (dashed) and simulated paths, tethers every 1 s", fontsize=10)
    fig.tight_layout()
    return fig


def drone_figures(out: Path, rp: Any, run: Any) -> list[str]:
    """Write the five PNG figures of a drone replay into ``out``; return their names."""
    label = f"MuJoCo replay: {run.label}"
    figs = {
        "tether_heights.png": plot_heights(rp, label),
        "tensions.png": plot_drone_tensions(rp, label),
        "tracking.png": plot_tracking(rp, label),
        "rotor_thrust.png": plot_rotor_thrust(rp, label),
        "topview.png": plot_drone_paths(rp, run, label),
    }
    return _save(out, figs)
