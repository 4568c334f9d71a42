"""The planner's result: a nominal trajectory with its path, gain schedule and metrics, or why there is none."""

from __future__ import annotations

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
