"""Figures of a tracked CCMA path: mechanism in 3D and top view, joint angles, and BFGS convergence (Kumar 2019
Fig. 5, 11)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the 3d projection)

from tmr.ccma.control import TrackResult
from tmr.ccma.energy import EnergyModel
from tmr.ccma.sim import State, agent_poses

__all__ = ["body_segments", "plot_convergence", "plot_mechanism"]

_AGENT_HALF = 0.06  # half side of the drawn agent footprint [m]


def body_segments(model: EnergyModel, state: State) -> list[np.ndarray]:
    """World polylines (k, 3) [m] of every passive body through its joint points (closed for ≥ 3 points)."""
    pos, rot = model.world_poses(state.x, state.r_ref)
    agent_bodies = {a.body for a in model.system.agents}
    out = []
    for i, pts in enumerate(model.system.body_points):
        if i in agent_bodies or len(pts) < 2:
            continue
        w = pos[i] + pts @ rot[i].T
        out.append(np.vstack([w, w[:1]]) if len(w) >= 3 else w)
    return out


def _draw_agents(ax: Axes, agents: np.ndarray, colour: str, z: float | None) -> None:
    sq = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]], float) * _AGENT_HALF
    for x, y, yaw in agents:
        c, s = np.cos(yaw), np.sin(yaw)
        pts = sq @ np.array([[c, s], [-s, c]]) + [x, y]
        if z is None:
            ax.plot(pts[:, 0], pts[:, 1], color=colour, lw=1.0)
            ax.plot([x, x + 1.5 * _AGENT_HALF * c], [y, y + 1.5 * _AGENT_HALF * s], color=colour, lw=1.0)
        else:
            ax.plot(pts[:, 0], pts[:, 1], np.full(len(pts), z), color=colour, lw=1.0)


def plot_mechanism(
    model: EnergyModel,
    result: TrackResult,
    states: Sequence[State],
    title: str = "",
    *,
    angles: np.ndarray | None = None,
    joint_names: Sequence[str] = (),
) -> Figure:
    """3D view (mechanism at the given states, end-effector path) and top view (agent and end-effector paths); with
    ``angles`` (K, J) [rad] of the joints ``joint_names`` (:func:`tmr.ccma.angles.joint_angles`) a third panel plots
    every joint that turns against the step (joints that stay within 1e-6 rad are listed, not drawn)."""
    panels = 3 if angles is not None else 2
    fig = Figure(figsize=(6 * panels, 5.5))
    ax3 = fig.add_subplot(1, panels, 1, projection="3d")
    ax2 = fig.add_subplot(1, panels, 2)
    cmap = colormaps["viridis"]
    ee = result.ee_position
    n_ag = result.agents.shape[1]
    for k, st in enumerate(states):
        colour = cmap(k / max(1, len(states) - 1))
        ag = agent_poses(model, st)
        for seg in body_segments(model, st):
            ax3.plot(seg[:, 0], seg[:, 1], seg[:, 2], color=colour, lw=1.6)
            ax2.plot(seg[:, 0], seg[:, 1], color=colour, lw=0.8, alpha=0.6)
        _draw_agents(ax3, ag, colour, z=min(a.height for a in model.system.agents))
        _draw_agents(ax2, ag, colour, z=None)
    ax3.plot(ee[:, 0], ee[:, 1], ee[:, 2], color="crimson", lw=1.2, label="end-effector")
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    pts = np.vstack([seg for st in states for seg in body_segments(model, st)] + [ee])
    lo, hi = pts.min(axis=0) - 0.1, pts.max(axis=0) + 0.1
    lo[2] = 0.0
    ax3.set_xlim(lo[0], hi[0])
    ax3.set_ylim(lo[1], hi[1])
    ax3.set_zlim(lo[2], hi[2])
    ax3.set_box_aspect(tuple(hi - lo))  # equal scale on the three axes
    ax3.set_title("mechanism (start → end, viridis)")
    for j in range(n_ag):
        ax2.plot(result.agents[:, j, 0], result.agents[:, j, 1], lw=1.4, label=model.system.agents[j].name)
    ax2.plot(ee[:, 0], ee[:, 1], color="crimson", lw=1.4, label="end-effector")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("y [m]")
    ax2.set_title("top view: agent and end-effector paths")
    ax2.legend(fontsize=8, loc="best")
    ax2.grid(True, lw=0.3)
    if angles is not None:
        _plot_angles(fig.add_subplot(1, panels, 3), np.asarray(angles, float), list(joint_names))
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def _plot_angles(ax: Axes, angles: np.ndarray, names: list[str]) -> None:
    steps = np.arange(1, len(angles) + 1)
    still = []
    for c, name in enumerate(names):
        a = angles[:, c]
        if a.size and np.ptp(a) > 1e-6:
            ax.plot(steps, np.degrees(a), lw=1.3, label=name)
        else:
            still.append(name)
    ax.set_xlabel("step")
    ax.set_ylabel("joint angle from the reference [deg]")
    span = float(np.ptp(angles, axis=0).max()) if angles.size else 0.0
    ax.set_title(f"joint angles (largest range {np.degrees(span):.1f}°)")
    if len(names) > len(still):
        ax.legend(fontsize=7, loc="best", ncol=2)
    if still:
        text = "not turning: " + ", ".join(still)
        ax.text(0.01, 0.01, text if len(text) < 90 else text[:87] + "…", transform=ax.transAxes, fontsize=7)
    ax.grid(True, lw=0.3)


def plot_convergence(curves: Mapping[str, np.ndarray], title: str = "") -> Figure:
    """Objective O [m²] against wall time [ms] of BFGS solves (Kumar 2019 Fig. 5); ``curves`` maps a label to a
    (k, 2) array of (time [s], O)."""
    fig = Figure(figsize=(6.5, 4.2))
    ax = fig.add_subplot(1, 1, 1)
    for label, h in curves.items():
        h = np.asarray(h, float)
        ax.semilogy(1e3 * h[:, 0], np.maximum(h[:, 1], 1e-30), marker=".", ms=4, lw=1.2, label=label)
    ax.set_xlabel("time [ms]")
    ax.set_ylabel("objective O(u) [m²]")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title or "BFGS convergence of one IK step")
    fig.tight_layout()
    return fig
