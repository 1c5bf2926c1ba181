"""Run directories → :class:`tmr.views.motion.Motion`: what ``python -m tmr.export`` reads.

* a ``tmr.plan`` directory (``run.json`` kind ``chain`` + ``trajectories.json``, :func:`tmr.io.rundir.load_run`): the
  robots, the anchor, the goal, the recorded obstacle polygons (raw and grown) and the tether parameters, so the
  catenaries are those the plan was checked with;
* a ``tmr.mcdpr plan`` directory (``run.json`` kind ``mcdpr`` + ``plan.json``): robot, scene, sampled bases,
  headings and platform;
* a ``tmr.ccma run`` directory (``trajectory.json``): the agents and the end-effector as recorded, and the links
  rebuilt by the forward kinematics of the recorded controls (:func:`tmr.ccma.sim.simulate`, warm-started step after
  step as the run did); the rebuilt agents and end-effector must match the recorded ones to 1e-6 m, else the run is
  refused (it was made from another description).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tmr.errors import TmrError
from tmr.views.motion import Motion

__all__ = ["ExportError", "load_motion"]

#: Largest allowed gap between a rebuilt CCMA pose and the recorded one [m].
CCMA_MATCH_TOL = 1e-6


class ExportError(TmrError):
    """A run directory cannot be exported (one-line message)."""


def _ccma(path: Path, rate: float, description: str | None) -> Motion:
    from tmr.ccma.energy import EnergyModel
    from tmr.ccma.motion import ccma_motion
    from tmr.ccma.plot import body_segments
    from tmr.ccma.sim import agent_poses, end_effector_pose, reference_state, simulate
    from tmr.ccma.system import build_system, load_description

    where = str(path)
    try:
        doc = json.loads((path / "trajectory.json").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ExportError(f"{where}: cannot read trajectory.json ({exc}); re-run tmr.ccma run") from None
    if not isinstance(doc, dict) or doc.get("format") != "tmr-ccma-trajectory/1":
        raise ExportError(f"{where}: trajectory.json is not a tmr.ccma run (format tmr-ccma-trajectory/1)")
    try:
        u = np.asarray(doc["controls"], dtype=float)
        agents = np.asarray(doc["agent_poses"], dtype=float)
        ee = np.asarray(doc["ee_position"], dtype=float)
        names = [a["name"] for a in doc["agents"]]
        system = str(doc["system"])
    except (KeyError, TypeError, ValueError):
        raise ExportError(f"{where}: trajectory.json lacks controls/agent poses; re-run tmr.ccma run") from None
    try:
        desc = load_description(description or system)
    except TmrError as exc:
        raise ExportError(
            f"{where}: the run's system {system!r} is not a shipped example ({exc}); give its --description FILE"
        ) from None
    try:
        built = build_system(desc)
    except TmrError as exc:
        raise ExportError(f"{description or system}: {exc}") from None
    model = EnergyModel(built)
    if model.system.name != system or [a.name for a in model.system.agents] != names or u.shape[1:] != (model.nu,):
        raise ExportError(f"{where}: the description does not describe the run's system {system!r}")
    st = reference_state(model)
    links: list[list[np.ndarray]] = []
    for k in range(len(u)):
        st = simulate(model, u[k], st).state
        a_k = agent_poses(model, st)
        e_k, _ = end_effector_pose(model, st)
        gap = max(float(np.max(np.abs(a_k[:, :2] - agents[k, :, :2]))), float(np.max(np.abs(e_k - ee[k]))))
        if gap > CCMA_MATCH_TOL:
            raise ExportError(
                f"{where}: step {k + 1} rebuilt from the recorded controls lies {gap:.3g} m from the recorded pose "
                f"(> {CCMA_MATCH_TOL:g} m); the run was made from another description"
            )
        links.append(body_segments(model, st))
    per_link = [np.stack([frame[i] for frame in links]) for i in range(len(links[0]))] if links else []
    height = min(a.height for a in model.system.agents)
    # positions exported are the recorded ones (bit for bit); the rebuilt state only supplies the links
    return ccma_motion(
        system, names, agents, height, ee, per_link, rate=rate, title=f"CCMA {system}: {doc.get('path', '')} path"
    )


def load_motion(
    path: str | Path, rate: float = 10.0, trajectory: str = "raw", description: str | None = None
) -> Motion:
    """The :class:`Motion` of a run directory of ``tmr.plan``, ``tmr.mcdpr plan`` or ``tmr.ccma run``.

    ``rate`` [Hz] stamps the samples of MoPICK / CCMA runs (they have no time law); ``trajectory`` ``"raw"`` (the
    checked plan, default) or ``"filtered"`` (the low-passed positions the robots track) for chain runs;
    ``description`` the CCMA system file of a run not made from a shipped example.
    """
    from tmr.io.outdir import is_complete
    from tmr.io.rundir import load_run

    p = Path(path)
    if p.is_dir() and not (p / "run.json").exists() and (p / "trajectory.json").is_file():
        if not is_complete(p):  # a CCMA run has no run.json: load_run's check does not see it
            raise ExportError(f"{p} was being written when its run was stopped (its files may mix two runs); rerun it")
        return _ccma(p, rate, description)
    return load_run(p).motion(rate=rate, trajectory=trajectory)  # each kind builds its own Motion (and load_run
    # refuses a run directory whose publication was stopped part-way)
