"""The controllers of the chain: its tasks (cost rows) and hard limits (inequality rows), the CLIK loop, and the
formulations that turn them into joint velocities: ``pinv`` (faithful baseline), ``qp`` (+ the warm active set),
``horizon``.
"""
