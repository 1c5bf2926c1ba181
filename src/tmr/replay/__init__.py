"""Physics replay of plans in MuJoCo (``python -m tmr.replay RUN_DIR``).

Rebuilds a plan's world from its run directory (:mod:`tmr.io.rundir`) — floor, extruded obstacles, robots on
force-limited actuators, winched tethers discretised into links (:mod:`tmr.replay.tether`); for drone chains the 3-D
world and quadrotors flown by a cascaded controller (:mod:`tmr.replay.drones`, :mod:`tmr.replay.quadrotor`); for
MoPICK the bases on wheels, the cables and the platform — steps it over the plan and reports whether the physics
confirms it.
Nothing in the planners imports this package; MuJoCo is imported only inside the functions that use it.
The model and every choice: ``formulations/replay.md``.
"""

from tmr.replay.errors import ReplayError

__all__ = ["ReplayError"]
