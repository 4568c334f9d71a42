"""Front-wheel-drive car of the paper, equation (12).

States (x1, x2, x3 = steering angle phi, x4 = heading theta); inputs (u1 = driving speed of the front
wheels, u2 = steering rate):
    x1' = cos(x3) cos(x4) u1,  x2' = cos(x3) sin(x4) u1,  x3' = u2,  x4' = sin(x3) u1 / L.
The Jacobian d(g u)/dx is derived from these equations; the A(t) printed in the paper has slips
(docs/theory/control-law.md, The FWD car).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .base import SteeredCar


@dataclass(frozen=True)
class FwdCar(SteeredCar):
    robot_defaults: ClassVar[dict] = {
        "footprint": {"rectangle": {"length": 1.6, "width": 0.8, "rear_overhang": 0.3}},
        "margin": 0.2,
        "stabilizer": {"alpha": 0.2, "delta": 3.0, "gamma": 1.0, "end_strategy": "extend", "cusps": "split"},
        "turning_radius": ("factor", 1.25),
    }
    front_wheel_drive: ClassVar[bool] = True
    sweep_grid: ClassVar[dict | None] = {"alpha": [0.05, 0.1, 0.2], "delta": [2.0, 3.0, 4.0, 6.0]}
    plannable: ClassVar[bool] = True
    search_pad: ClassVar[float | None] = 0.05
    wheelbase: float = 1.0          # m, L
    max_speed: float = 1.0          # m/s, |u1|
    max_steer: float = 0.6          # rad, |x3| (< pi/2)
    max_steer_rate: float = 1.0     # rad/s, |u2|

    def __post_init__(self):
        self._check_car("fwd_car", ("x", "y", "phi", "theta"))

    def g(self, x):
        x = np.asarray(x, dtype=float)
        phi, th = x[..., 2], x[..., 3]
        out = np.zeros(x.shape[:-1] + (4, 2))
        out[..., 0, 0] = np.cos(phi) * np.cos(th)
        out[..., 1, 0] = np.cos(phi) * np.sin(th)
        out[..., 3, 0] = np.sin(phi) / self.wheelbase
        out[..., 2, 1] = 1.0
        return out

    def rhs(self, x, u):
        """x' = g(x) u written out (the same values as the generic f + g u, without building g)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        phi, th, u1 = x[..., 2], x[..., 3], u[..., 0]
        out = np.empty(np.broadcast_shapes(x.shape[:-1], u.shape[:-1]) + (4,))
        cphi = np.cos(phi)
        out[..., 0] = (cphi * np.cos(th)) * u1
        out[..., 1] = (cphi * np.sin(th)) * u1
        out[..., 2] = u[..., 1]
        out[..., 3] = (np.sin(phi) / self.wheelbase) * u1
        return out

    def dgu_dx(self, x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        phi, th, u1 = x[..., 2], x[..., 3], u[..., 0]
        shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        out = np.zeros(shape + (4, 4))
        out[..., 0, 2] = -np.sin(phi) * np.cos(th) * u1
        out[..., 0, 3] = -np.cos(phi) * np.sin(th) * u1
        out[..., 1, 2] = -np.sin(phi) * np.sin(th) * u1
        out[..., 1, 3] = np.cos(phi) * np.cos(th) * u1
        out[..., 3, 2] = np.cos(phi) * u1 / self.wheelbase
        return out
