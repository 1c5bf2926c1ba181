"""The tethered chain's model: the chain as a redundant serial manipulator (D–H, forward kinematics, Jacobians), the
catenary tether, the span limits, the velocity coordinates and the planner's parameters.
"""
