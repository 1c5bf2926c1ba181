"""Checks of a plan: the performance metrics (Caruso 2021 eq. 24–27), the within-limits trajectory filter and its low-
pass.
"""
