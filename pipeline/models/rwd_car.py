"""Kinematic (rear-axle referenced) car with the steering angle as a state.

States (x, y, theta, phi); inputs (v = rear-axle speed, omega_s = steering rate):
    x' = cos(theta) v,  y' = sin(theta) v,  theta' = tan(phi) v / L,  phi' = omega_s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import SteeredCar


@dataclass(frozen=True)
class RwdCar(SteeredCar):
    wheelbase: float = 2.5          # m, L
    max_speed: float = 1.5          # m/s, |v|
    max_steer: float = 0.6          # rad, |phi| (< pi/2)
    max_steer_rate: float = 1.0     # rad/s, |omega_s|

    def __post_init__(self):
        self._check_car("rwd_car")
        object.__setattr__(self, "name", "rwd_car")
        object.__setattr__(self, "state_names", ("x", "y", "theta", "phi"))
        object.__setattr__(self, "input_names", ("v", "omega_s"))
        object.__setattr__(self, "angle_states", (2, 3))
        object.__setattr__(self, "state_units", ("m", "m", "rad", "rad"))
        object.__setattr__(self, "input_units", ("m/s", "rad/s"))

    @property
    def min_turning_radius(self) -> float:
        return self.wheelbase / np.tan(self.max_steer)

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
