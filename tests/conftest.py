import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from nhstab.models import make_model  # noqa: E402
from nhstab.nominal import Nominal  # noqa: E402


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


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)
