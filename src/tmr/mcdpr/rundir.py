"""The MoPICK section of the run directory record: ``run.json`` of ``kind = "mcdpr"`` (written by
``python -m tmr.mcdpr plan``) and its reader, registered with :func:`tmr.io.rundir.register_kind` so that
:func:`tmr.io.rundir.load_run` reads it (robot, scene, external wrench box and planner parameters in ``run.json``;
the sampled bases, platform and tensions in ``plan.json``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.io.rundir import (
    RUN_FORMAT,
    RunDirError,
    _dump,
    _floats,
    _read_json,
    _version,
    polygons_from_json,
    polygons_to_json,
    register_kind,
)

__all__ = ["McdprRun", "load_mcdpr_run", "mcdpr_run_dict", "write_mcdpr_run"]

Array = NDArray[np.float64]


def mcdpr_run_dict(robot: Any, scene: Any, params: Any) -> dict[str, Any]:
    """The ``run.json`` document of a MoPICK plan (``kind = "mcdpr"``): robot, scene geometry, external wrench box,
    planner parameters. The sampled bases/platform/tensions stay in ``plan.json`` (read by :func:`load_run`)."""
    import dataclasses

    rob = {f.name: getattr(robot, f.name) for f in dataclasses.fields(robot)}
    return {
        "format": RUN_FORMAT,
        "kind": "mcdpr",
        "tmr_version": _version(),
        "robot": rob,
        "scene": {
            "name": scene.name,
            "bounds": [float(v) for v in scene.bounds],
            "tables": [polygons_to_json(t) for t in scene.tables],
            "obstacles": [polygons_to_json(o) for o in scene.obstacles],
            "tasks": scene.tasks,
            "bases": scene.bases,
            "headings": scene.headings,
            "external": scene.external,
            "intermediate": scene.intermediate,
            "lateral": scene.lateral,
        },
        "params": dataclasses.asdict(params),
        "files": {"plan": "plan.json", "bases": "bases.csv", "platform": "platform.csv"},
    }


def write_mcdpr_run(path: str | os.PathLike[str], robot: Any, scene: Any, params: Any) -> Path:
    """Write :func:`mcdpr_run_dict` to ``path`` (atomic, deterministic bytes)."""
    from tmr.io.outputs import atomic_write_text

    return atomic_write_text(path, _dump(mcdpr_run_dict(robot, scene, params)))


@dataclass(frozen=True)
class McdprRun:
    """A MoPICK run directory, read back (units: m, rad, N).

    Attributes:
        path: the directory; record: ``run.json``; plan: ``plan.json``.
        bases: (T, p, 2) base positions [m]; headings: (T, p) [rad]; platform: (T, 3) [m];
        tensions: (T, m) planned cable tensions [N] (NaN where the plan has none); mu: (T,) capacity margin [N];
        segment: (T,) way-point segment of each sample.
    """

    path: Path
    record: dict[str, Any]
    plan: dict[str, Any]
    bases: Array
    headings: Array
    platform: Array
    tensions: Array
    mu: Array
    segment: NDArray[np.int64]

    kind = "mcdpr"

    def motion(self, rate: float = 10.0, trajectory: str = "raw") -> Any:
        """The :class:`tmr.views.motion.Motion` of the plan, samples stamped k / ``rate`` [Hz] (no time law);
        ``trajectory`` is unused (a MoPICK plan has one)."""
        from tmr.mcdpr.motion import mcdpr_motion

        return mcdpr_motion(self.robot(), self.scene(), self, rate=rate)

    @property
    def label(self) -> str:
        return f"MoPICK scene {self.record['scene']['name']}"

    def robot(self) -> Any:
        """The :class:`tmr.mcdpr.robot.Robot` of the plan."""
        from tmr.mcdpr.robot import robot_from_dict

        return robot_from_dict(dict(self.record["robot"]), f"{self.path}/run.json")

    def scene(self) -> Any:
        """The :class:`tmr.mcdpr.scene.Scene` of the plan, rebuilt from the recorded polygons."""
        from tmr.mcdpr.scene import Scene

        s = self.record["scene"]
        where = f"{self.path}/run.json"
        return Scene(
            name=s["name"],
            bounds=tuple(s["bounds"]),
            tables=tuple(polygons_from_json(t, where)[0] for t in s["tables"]),
            obstacles=tuple(polygons_from_json(o, where)[0] for o in s["obstacles"]),
            tasks=np.asarray(s["tasks"], dtype=float),
            bases=np.asarray(s["bases"], dtype=float),
            headings=np.asarray(s["headings"], dtype=float),
            external=np.asarray(s["external"], dtype=float),
            intermediate=int(s["intermediate"]),
            lateral=float(s["lateral"]),
        )


def load_mcdpr_run(path: Path, rec: dict[str, Any], where: str) -> McdprRun:
    for key in ("robot", "scene"):
        if key not in rec:
            raise RunDirError(f"{where}: run.json lacks {key!r}; it is corrupt, re-run tmr.mcdpr plan")
    plan = _read_json(path / "plan.json", where)
    if plan.get("format") != "tmr-mcdpr-plan/1" or "samples" not in plan:
        raise RunDirError(f"{where}: plan.json has format {plan.get('format')!r}; re-run tmr.mcdpr plan")
    s = plan["samples"]
    try:
        bases = _floats(s["bases"], where, "bases")
        out = McdprRun(
            path=path,
            record=rec,
            plan=plan,
            bases=bases,
            headings=_floats(s["headings"], where, "headings"),
            platform=_floats(s["platform"], where, "platform"),
            tensions=np.array([[np.nan if v is None else v for v in row] for row in s["tensions"]], dtype=float),
            mu=_floats(s["mu"], where, "mu"),
            segment=np.asarray(s["segment"], dtype=np.int64),
        )
    except (KeyError, TypeError, ValueError):
        raise RunDirError(f"{where}: plan.json samples are malformed; re-run tmr.mcdpr plan") from None
    if bases.ndim != 3 or bases.shape[2] != 2 or out.platform.shape != (bases.shape[0], 3):
        raise RunDirError(f"{where}: plan.json samples have inconsistent shapes; re-run tmr.mcdpr plan")
    return out


register_kind("mcdpr", load_mcdpr_run)
