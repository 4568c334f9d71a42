"""The planner's result: a nominal trajectory with its path, gain schedule and metrics, or why there is none."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from ..control import GainSchedule
from ..nominal import Nominal
from .geometric import GeometricPath


@dataclass
class PlanResult:
    """status: "ok", or why there is no usable plan: "no_path" (the planner found none in its budget),
    "infeasible" (the car's local planner could not follow the path), "not_clear" (the nominal does not
    keep the margin), "not_stabilizable" (singular gramian)."""

    status: str
    message: str
    path: GeometricPath | None
    nominal: Nominal | None = None
    schedule: GainSchedule | None = None
    metrics: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def schedule_metrics(robot, stab_opts, schedule: GainSchedule, started: float) -> dict:
    """The plan metrics of a nominal's gain schedule (plan.json's stabilizer entries): the robot, the
    stabilizer, the gramian's smallest eigenvalue and when, the largest gain norm, the bounds p_m and p_M
    of P, the rate bound (as derived and as printed in the paper), and the time spent since ``started``
    (a ``time.perf_counter()`` reading)."""
    d = schedule.diagnostics
    return {"robot": robot.name, "stabilizer": stab_opts.describe(), "h_min_eigenvalue": d["h_min_eigenvalue"],
            "h_min_eigenvalue_time_s": d["h_min_eigenvalue_time_s"], "max_gain_norm": d["max_gain_norm"],
            "p_m": d["p_m"], "p_M": d["p_M"], "rate_bound": d["rate_bound"],
            "rate_bound_printed": d["rate_bound_printed"], "time_to_nominal_s": time.perf_counter() - started}
