"""Constrained collaborative mobile agents (CCMA, Kumar 2019): constraint-based simulation and sensitivity-based
kinematic control of omnidirectional mobile agents joined by a passive kinematic chain.

    from tmr.ccma import EnergyModel, load_system, reference_state, end_effector_pose, Target, solve_ik, simulate

    model = EnergyModel(load_system("4dof-reduced"))        # or build_system(dict) / a TOML path
    state = reference_state(model)
    p0, r0 = end_effector_pose(model, state)
    ik = solve_ik(model, state, model.system.u0, Target(p0 + [0.001, 0.0, 0.0], r0))
    sim = simulate(model, ik.u, state)                       # forward kinematics of the controls found

Modules: :mod:`~tmr.ccma.bodies` (pose parameterisation), :mod:`~tmr.ccma.joints` (constraint rows),
:mod:`~tmr.ccma.system` (declarative description), :mod:`~tmr.ccma.energy` (E = ½‖C‖² and its derivatives),
:mod:`~tmr.ccma.sim` (Newton forward kinematics), :mod:`~tmr.ccma.control` (sensitivity IK with BFGS),
:mod:`~tmr.ccma.paths`, :mod:`~tmr.ccma.angles` (joint angles), :mod:`~tmr.ccma.reach` (reach bound checked before
control), :mod:`~tmr.ccma.plot`; CLI ``python -m tmr.ccma``. Math: ``formulations/ccma.md``.
"""

from __future__ import annotations

from tmr.ccma.angles import joint_angles
from tmr.ccma.control import IKResult, Target, TrackResult, conditioning, objective, sensitivity, solve_ik, track
from tmr.ccma.energy import EnergyModel
from tmr.ccma.errors import AssemblyError, CcmaError, ConvergenceError, DescriptionError
from tmr.ccma.paths import make_path
from tmr.ccma.reach import ReachVerdict, check_reach
from tmr.ccma.sim import SimResult, State, agent_poses, end_effector_pose, reference_state, simulate
from tmr.ccma.system import System, build_system, example_names, load_description, load_system

__all__ = [
    "AssemblyError",
    "CcmaError",
    "ConvergenceError",
    "DescriptionError",
    "EnergyModel",
    "IKResult",
    "ReachVerdict",
    "SimResult",
    "State",
    "System",
    "Target",
    "TrackResult",
    "agent_poses",
    "build_system",
    "check_reach",
    "conditioning",
    "end_effector_pose",
    "example_names",
    "joint_angles",
    "load_description",
    "load_system",
    "make_path",
    "objective",
    "reference_state",
    "sensitivity",
    "simulate",
    "solve_ik",
    "track",
]
