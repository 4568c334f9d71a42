"""Stabilizers: the gramian gain schedule of Proposition 1 (P_c), Remark 2 (P_r, for study) and the
frozen-time law (a causal alternative)."""

from .gramian import (
                      END_STRATEGIES,
                      GAIN_BOUND,
                      GUARANTEES,
                      PAST_WINDOW_WARNING,
                      WINDOWS,
                      GainSchedule,
                      StabilizerOptions,
                      compute_schedule,
)

__all__ = ["GainSchedule", "StabilizerOptions", "compute_schedule", "WINDOWS", "END_STRATEGIES", "GUARANTEES",
           "PAST_WINDOW_WARNING", "GAIN_BOUND"]
