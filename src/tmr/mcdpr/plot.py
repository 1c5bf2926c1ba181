"""Figures of an MCDPR plan: top view like Rasheed 2019 Fig. 4, capacity margin and tension profiles (matplotlib)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import shapely  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402
from matplotlib.patches import Polygon as MplPolygon

from tmr.mcdpr.planner import Plan  # noqa: E402
from tmr.mcdpr.robot import Robot  # noqa: E402
from tmr.mcdpr.scene import Scene  # noqa: E402
from tmr.world.environment import Environment  # noqa: E402

__all__ = ["plot_mu", "plot_tensions", "plot_topview", "plot_workspace"]

_COLORS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive"]


def _polys(ax: plt.Axes, geom: shapely.Geometry, **kw: object) -> None:
    for g in shapely.get_parts(geom):
        if g.geom_type == "Polygon" and not g.is_empty:
            ax.add_patch(MplPolygon(np.asarray(g.exterior.coords), closed=True, **kw))


def plot_topview(robot: Robot, scene: Scene, env: Environment, result: Plan, path: str | Path) -> Path:
    """Top view: tables/obstacles and their inflated safe regions, base paths, platform path, way-points, and the
    cables at the way-points (Rasheed 2019 Fig. 2, 4). Writes a PNG to ``path``."""
    fig, ax = plt.subplots(figsize=(10, 7.5))
    x0, y0, x1, y1 = scene.bounds
    grown = shapely.union_all([g.buffer(robot.base_radius) for g in (*scene.tables, *scene.obstacles)])
    _polys(ax, grown, facecolor="0.9", edgecolor="0.7", lw=0.8, ls="--")
    for t in scene.tables:
        _polys(ax, t, facecolor="tan", edgecolor="saddlebrown", lw=1.0)
    if len(scene.discs) == len(scene.obstacles):
        for cx, cy, r in scene.discs:  # the exact circles
            ax.add_patch(Circle((cx, cy), r, facecolor="dimgray", edgecolor="black", lw=1.0))
    else:
        for o in scene.obstacles:
            _polys(ax, o, facecolor="dimgray", edgecolor="black", lw=1.0)
    ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], "k-", lw=1.5)
    for j in range(robot.n_bases):
        c = _COLORS[j % len(_COLORS)]
        ax.plot(result.bases[:, j, 0], result.bases[:, j, 1], "-", color=c, lw=1.6, label=f"base {j + 1}")
        for st in result.stage1:
            ax.plot(st["iterates"][:, j, 0], st["iterates"][:, j, 1], ".", color=c, ms=3, alpha=0.6)
        ax.add_patch(Circle(result.bases[0, j], robot.base_radius, fill=False, color=c, lw=1.0, ls=":"))
        ax.add_patch(Circle(result.bases[-1, j], robot.base_radius, fill=False, color=c, lw=1.5))
        ax.plot(*result.bases[0, j], "o", mfc="white", mec=c, ms=6)
        ax.plot(*result.bases[-1, j], "s", color=c, ms=6)
    ax.plot(result.platform[:, 0], result.platform[:, 1], "k-", lw=1.4, label="platform")
    ax.plot([], [], "o", mfc="white", mec="k", ms=6, label="start (dotted: base footprint)")
    ax.plot([], [], "s", color="k", ms=6, label="end (solid: base footprint)")
    if result.stage1:
        ax.plot([], [], ".", color="0.4", ms=4, label="stage-1 iterates")
    ends = np.flatnonzero(np.diff(np.r_[result.segment, -1]) != 0)
    for r in np.r_[0, ends]:
        for j, k in enumerate(robot.cable_base):
            ax.plot(
                [result.platform[r, 0], result.bases[r, k, 0]],
                [result.platform[r, 1], result.bases[r, k, 1]],
                "-",
                color=_COLORS[j % len(_COLORS)],
                lw=0.6,
                alpha=0.7,
            )
    ax.plot(
        [], [], "-", color="0.5", lw=0.6, label="cables at the " + ("way-points" if result.stage1 else "task points")
    )
    w = result.waypoints
    ax.plot(w[:, 0], w[:, 1], "k*", ms=11, label="way-points" if result.stage1 else "task points")
    for i, p in enumerate(w):
        ax.annotate(f"P{i + 1}", p[:2], textcoords="offset points", xytext=(6, 6), fontsize=10)
    bad = result.mu <= 0
    if bad.any():
        ax.plot(result.platform[bad, 0], result.platform[bad, 1], "rx", ms=4, label="μ ≤ 0")
    ax.set_xlim(x0 - 0.2, x1 + 0.2)
    ax.set_ylim(y0 - 0.2, y1 + 0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    title = f"{robot.name} plan ({result.planner}), scene {scene.name}: min μ = {np.min(result.mu):.3f} N"
    if result.mu_lower is not None and len(result.mu_lower):
        title += f", ≥ {np.min(result.mu_lower):.3f} N guaranteed between samples"
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", fontsize=7, ncol=3, framealpha=0.85)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_mu(result: Plan, path: str | Path) -> Path:
    """Capacity margin μ [N] along the plan (Rasheed 2019 eq. 8) and its stage-1 histories (cf. Fig. 3e)."""
    if not result.stage1:
        fig, a1 = plt.subplots(figsize=(11, 4))
        a2 = None
    else:
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(result.mu))
    a1.plot(x, result.mu, "k.-", lw=1.0, ms=3, label="μ at the samples")
    if result.mu_lower is not None and len(result.mu_lower):
        low = result.mu_lower
        xs = np.repeat(x, 2)[1:-1]
        a1.plot(xs, np.repeat(low, 2), "-", color="tab:green", lw=1.0, label="guaranteed lower bound between samples")
        a1.fill_between(xs, np.repeat(low, 2), 0.0, color="tab:green", alpha=0.15, lw=0)
    a1.axhline(0.0, color="r", lw=0.8, ls="--")
    for s in np.flatnonzero(np.diff(result.segment)):
        a1.axvline(s + 0.5, color="0.7", lw=0.8)
    a1.set_xlabel("sample along the plan (in-place turns and straight drives)")
    a1.set_ylabel("capacity margin μ [N]")
    a1.set_title("μ along the plan" + (" (stage 2)" if result.stage1 else ""))
    a1.legend(fontsize=8, loc="lower right")
    if a2 is None:
        fig.tight_layout()
        path = Path(path)
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path
    for i, st in enumerate(result.stage1):
        a2.plot(st["mu"], "o-", ms=3, label=f"P{i + 1}→P{i + 2}")
    a2.axhline(0.0, color="r", lw=0.8, ls="--")
    a2.set_xlabel("stage-1 iteration k")
    a2.set_ylabel("μ [N]")
    a2.set_title("stage-1 greedy search")
    a2.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_tensions(robot: Robot, result: Plan, path: str | Path) -> Path:
    """Minimum 2-norm cable tensions [N] along the plan with the tipping-tightened upper bounds (dashed)."""
    fig, ax = plt.subplots(figsize=(11, 4))
    for k in range(robot.n_cables):
        c = _COLORS[k % len(_COLORS)]
        ax.plot(result.tensions[:, k], "-", color=c, lw=1.2, label=f"t{k + 1}")
        ax.plot(result.hi[:, k], "--", color=c, lw=0.7, alpha=0.7)
    ax.axhline(robot.t_max, color="k", lw=0.8, ls=":", label="t_max")
    ax.set_xlabel("sample along the plan")
    ax.set_ylabel("tension [N]")
    ax.set_title("tensions holding the platform weight (solid) and tipping-tightened bounds (dashed)")
    ax.legend(fontsize=8, ncol=5)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_workspace(robot: Robot, scene: Scene, ws: object, bases: np.ndarray, path: str | Path) -> Path:
    """Map of the capacity margin μ [N] over platform positions at one height with the bases parked, the
    wrench-feasible workspace (μ > 0) outlined, tables/obstacles and the bases (Rasheed 2019 eq. 8)."""
    from matplotlib.colors import TwoSlopeNorm

    fig, ax = plt.subplots(figsize=(10, 7.5))
    mu = np.where(np.isfinite(ws.mu), ws.mu, np.nan)
    lo = float(np.nanmin(mu)) if np.isfinite(np.nanmin(mu)) else -1.0
    hi = float(np.nanmax(mu))
    span = max(hi, 1.0)  # negative margins are clipped at −max μ (far outside the workspace they dive)
    norm = TwoSlopeNorm(vcenter=0.0, vmin=max(min(lo, -1e-3), -span), vmax=max(hi, 1e-3))
    x0, y0, x1, y1 = scene.bounds
    im = ax.imshow(
        mu,
        origin="lower",
        extent=(ws.x[0] - ws.cell / 2, ws.x[-1] + ws.cell / 2, ws.y[0] - ws.cell / 2, ws.y[-1] + ws.cell / 2),
        cmap="RdYlGn",
        norm=norm,
        interpolation="nearest",
    )
    fig.colorbar(im, ax=ax, label="capacity margin μ [N]", shrink=0.8, extend="min" if lo < -span else "neither")
    if np.nanmax(mu) > 0 > np.nanmin(mu):
        ax.contour(ws.x, ws.y, mu, levels=[0.0], colors="k", linewidths=1.5)
    for t in scene.tables:
        _polys(ax, t, facecolor="none", edgecolor="saddlebrown", lw=1.2, hatch="//")
    for cx, cy, r in scene.discs:
        ax.add_patch(Circle((cx, cy), r, facecolor="none", edgecolor="black", lw=1.0, hatch="xx"))
    for j in range(robot.n_bases):
        c = _COLORS[j % len(_COLORS)]
        ax.add_patch(Circle(bases[j], robot.base_radius, facecolor="white", edgecolor=c, lw=2.0))
        ax.annotate(f"{j + 1}", bases[j], ha="center", va="center", fontsize=9, color=c)
    ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], "k-", lw=1.5)
    ax.plot([], [], "k-", lw=1.5, label="μ = 0: border of the wrench-feasible workspace")
    ax.plot([], [], "o", mfc="white", mec="k", ms=9, label="parked bases")
    ax.set_xlim(x0 - 0.2, x1 + 0.2)
    ax.set_ylim(y0 - 0.2, y1 + 0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(
        f"{robot.name}, scene {scene.name}: wrench-feasible workspace at z = {ws.z:g} m "
        f"(area {ws.area:.2f} m², max μ {hi:.2f} N)",
        fontsize=10,
    )
    ax.legend(loc="upper left", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
