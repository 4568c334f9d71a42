"""Differential drive (Hilare, paper eq. 11): x' = cos(theta) v, y' = sin(theta) v, theta' = omega."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .base import POSE_NOISE, Model, positive_param


@dataclass(frozen=True)
class Unicycle(Model):
    robot_defaults: ClassVar[dict] = {
        "footprint": {"radius": 0.3},
        "margin": 0.1,
        "stabilizer": {"alpha": 0.2, "delta": 2.0, "gamma": 1.0, "end_strategy": "frozen"},
        "turning_radius": ("fixed", 0.5),
    }
    noise_defaults: ClassVar[dict] = POSE_NOISE
    sweep_grid: ClassVar[dict | None] = {"alpha": [0.1, 0.2, 0.5, 1.0], "delta": [0.5, 1.0, 2.0]}
    plannable: ClassVar[bool] = True
    search_pad: ClassVar[float | None] = 0.02
    max_speed: float = 1.0          # m/s, |v|
    max_turn_rate: float = 2.0      # rad/s, |omega|

    def __post_init__(self):
        positive_param("max_speed", self.max_speed, "unicycle")
        positive_param("max_turn_rate", self.max_turn_rate, "unicycle")
        object.__setattr__(self, "name", "unicycle")
        object.__setattr__(self, "state_names", ("x", "y", "theta"))
        object.__setattr__(self, "input_names", ("v", "omega"))
        object.__setattr__(self, "angle_states", (2,))
        object.__setattr__(self, "state_units", ("m", "m", "rad"))
        object.__setattr__(self, "input_units", ("m/s", "rad/s"))

    def g(self, x):
        x = np.asarray(x, dtype=float)
        th = x[..., 2]
        out = np.zeros(x.shape[:-1] + (3, 2))
        out[..., 0, 0] = np.cos(th)
        out[..., 1, 0] = np.sin(th)
        out[..., 2, 1] = 1.0
        return out

    def rhs(self, x, u):
        """x' = g(x) u written out (the same values as the generic f + g u, without building g)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        th, v = x[..., 2], u[..., 0]
        out = np.empty(np.broadcast_shapes(x.shape[:-1], u.shape[:-1]) + (3,))
        out[..., 0] = np.cos(th) * v
        out[..., 1] = np.sin(th) * v
        out[..., 2] = u[..., 1]
        return out

    def dgu_dx(self, x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        th = x[..., 2]
        v = u[..., 0]
        shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        out = np.zeros(shape + (3, 3))
        out[..., 0, 2] = -np.sin(th) * v
        out[..., 1, 2] = np.cos(th) * v
        return out

    def params(self) -> dict:
        return {"max_speed": self.max_speed, "max_turn_rate": self.max_turn_rate}

    def input_limits(self) -> np.ndarray:
        return np.array([[-self.max_speed, self.max_speed], [-self.max_turn_rate, self.max_turn_rate]])
