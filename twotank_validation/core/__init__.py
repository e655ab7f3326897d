"""The validation math: datum, LTI systems, LFT models, per-bin solvers, validate, statistics.

ROS-free: imports numpy, scipy and cvxpy (and numba for the fast path's kernel, on first use).
"""
