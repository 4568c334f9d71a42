"""The nonholonomic integrator whose control Lie algebra is the Heisenberg algebra (paper eq. 10).

x1' = u1, x2' = u2, x3' = x2 u1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .base import Model


@dataclass(frozen=True)
class Heisenberg(Model):
    robot_defaults: ClassVar[dict] = {
        "footprint": {"radius": 0.1},
        "margin": 0.1,
        "stabilizer": {"alpha": 1.0, "delta": 1.0, "gamma": 1.0, "end_strategy": "frozen"},
        "turning_radius": ("fixed", 0.5),
    }
    def __post_init__(self):
        object.__setattr__(self, "name", "heisenberg")
        object.__setattr__(self, "state_names", ("x1", "x2", "x3"))
        object.__setattr__(self, "input_names", ("u1", "u2"))
        object.__setattr__(self, "state_units", ("", "", ""))
        object.__setattr__(self, "input_units", ("1/s", "1/s"))

    def g(self, x):
        x = np.asarray(x, dtype=float)
        out = np.zeros(x.shape[:-1] + (3, 2))
        out[..., 0, 0] = 1.0
        out[..., 1, 1] = 1.0
        out[..., 2, 0] = x[..., 1]
        return out

    def rhs(self, x, u):
        """x' = g(x) u written out (the same values as the generic f + g u, without building g)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        out = np.empty(np.broadcast_shapes(x.shape[:-1], u.shape[:-1]) + (3,))
        out[..., 0] = u[..., 0]
        out[..., 1] = u[..., 1]
        out[..., 2] = x[..., 1] * u[..., 0]
        return out

    def dgu_dx(self, x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        out = np.zeros(shape + (3, 3))
        out[..., 2, 1] = u[..., 0]
        return out
