"""A MoPICK plan (Rasheed 2019) as a :class:`tmr.views.motion.Motion`: what the viewers and exporters draw."""

from __future__ import annotations

from typing import Any

import numpy as np

from tmr.views.motion import Lines, Motion, Track, _room_parts, sample_stamps

__all__ = ["mcdpr_motion"]


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
