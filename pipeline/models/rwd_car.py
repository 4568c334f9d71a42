"""Kinematic (rear-axle referenced) car with the steering angle as a state.

States (x, y, theta, phi); inputs (v = rear-axle speed, omega_s = steering rate):
    x' = cos(theta) v,  y' = sin(theta) v,  theta' = tan(phi) v / L,  phi' = omega_s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .base import SteeredCar


@dataclass(frozen=True)
class RwdCar(SteeredCar):
    # a car's body reaches 3.3 m ahead of its rear axle, where a heading error of 0.05 rad already
    # moves it by 0.17 m, so cars keep more room than the unicycle
    robot_defaults: ClassVar[dict] = {
        "footprint": {"rectangle": {"length": 4.2, "width": 1.8, "rear_overhang": 0.9}},
        "margin": 0.3,
        "stabilizer": {"alpha": 0.1, "delta": 6.0, "gamma": 1.0, "end_strategy": "extend", "cusps": "split"},
        "turning_radius": ("factor", 1.25),
    }
    # the van: a long panel van (about a Mercedes Sprinter 314 with the standard wheelbase): 5.9 x 2.0 m
    # body, wheelbase 3.65 m, overhangs 1.1 m (rear) and 1.15 m (front), kerb-to-kerb turning circle
    # about 13.5 m (max_steer 0.65 rad: R = 4.80 m at the rear axle), slower steering than the car
    robot_presets: ClassVar[dict] = {
        "van": {"wheelbase": 3.65, "max_speed": 1.5, "max_steer": 0.65, "max_steer_rate": 0.8,
                "footprint": {"rectangle": {"length": 5.9, "width": 2.0, "rear_overhang": 1.1}}},
    }
    sweep_grid: ClassVar[dict | None] = {"alpha": [0.05, 0.1, 0.2], "delta": [2.0, 3.0, 4.0, 6.0]}
    plannable: ClassVar[bool] = True
    search_pad: ClassVar[float | None] = 0.05
    wheelbase: float = 2.5          # m, L
    max_speed: float = 1.5          # m/s, |v|
    max_steer: float = 0.6          # rad, |phi| (< pi/2)
    max_steer_rate: float = 1.0     # rad/s, |omega_s|

    def __post_init__(self):
        self._check_car("rwd_car", ("x", "y", "theta", "phi"))

    def g(self, x):
        x = np.asarray(x, dtype=float)
        th, phi = x[..., 2], x[..., 3]
        out = np.zeros(x.shape[:-1] + (4, 2))
        out[..., 0, 0] = np.cos(th)
        out[..., 1, 0] = np.sin(th)
        out[..., 2, 0] = np.tan(phi) / self.wheelbase
        out[..., 3, 1] = 1.0
        return out

    def rhs(self, x, u):
        """x' = g(x) u written out (the same values as the generic f + g u, without building g)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        th, phi, v = x[..., 2], x[..., 3], u[..., 0]
        out = np.empty(np.broadcast_shapes(x.shape[:-1], u.shape[:-1]) + (4,))
        out[..., 0] = np.cos(th) * v
        out[..., 1] = np.sin(th) * v
        out[..., 2] = (np.tan(phi) / self.wheelbase) * v
        out[..., 3] = u[..., 1]
        return out

    def dgu_dx(self, x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        th, phi, v = x[..., 2], x[..., 3], u[..., 0]
        shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        out = np.zeros(shape + (4, 4))
        out[..., 0, 2] = -np.sin(th) * v
        out[..., 1, 2] = np.cos(th) * v
        out[..., 2, 3] = v / (self.wheelbase * np.cos(phi) ** 2)
        return out
