"""Formulations that turn the task stack into joint velocities: ``pinv`` (faithful baseline), ``qp``, ``horizon``."""
