"""Stabilizers: the gramian gain schedule of Proposition 1 (P_c) and Remark 2 (P_r)."""

from .gramian import END_STRATEGIES, WINDOWS, GainSchedule, StabilizerOptions, compute_schedule

__all__ = ["GainSchedule", "StabilizerOptions", "compute_schedule", "WINDOWS", "END_STRATEGIES"]
