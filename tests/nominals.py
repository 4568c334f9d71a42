"""Nominal trajectories the tests share: closed-form inputs on the paper's models."""
import numpy as np
from nhstab.models import make_model
from nhstab.nominal import Nominal


def hilare_sinusoid(t_end=2 * np.pi, hz=500.0):
    t = np.linspace(0.0, t_end, int(round(t_end * hz)) + 1)
    return Nominal.from_inputs(make_model("unicycle"), lambda s: np.stack([np.sin(s), np.cos(s)], -1), np.zeros(3), t)


def fwd_car_parking(t_end=2 * np.pi, hz=500.0):
    t = np.linspace(0.0, t_end, int(round(t_end * hz)) + 1)
    return Nominal.from_inputs(make_model("fwd_car", wheelbase=1.0),
                               lambda s: np.stack([np.sin(s), np.cos(2 * s)], -1), np.zeros(4), t)


def heisenberg_line(t_end=10.0, hz=200.0):
    t = np.linspace(0.0, t_end, int(round(t_end * hz)) + 1)
    return Nominal.from_functions(make_model("heisenberg"), lambda s: np.stack([0 * s, s, 0 * s], -1),
                                  lambda s: np.stack([0 * s, 1 + 0 * s], -1), t)
