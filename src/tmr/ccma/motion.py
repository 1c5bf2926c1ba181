"""A CCMA run (Kumar 2019) as a :class:`tmr.views.motion.Motion`: what the viewers and exporters draw."""

from __future__ import annotations

from typing import Any

import numpy as np

from tmr.errors import ParameterError
from tmr.views.motion import Array, Lines, Motion, Track, sample_stamps

__all__ = ["ccma_motion", "ccma_track_motion"]


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
