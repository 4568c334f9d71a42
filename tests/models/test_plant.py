"""The robots' own RK4 steps and right-hand sides against the generic ones."""

import numpy as np
import pytest
from nhstab.execution.plant import Plant
from nhstab.models import make_model
from nhstab.models.base import Model

ROBOTS = ["unicycle", "rwd_car", "fwd_car", "heisenberg"]


@pytest.mark.parametrize("name", ROBOTS)
def test_rhs_written_out_equals_f_plus_g_u(name):
    """Each model's rhs is the generic f(x) + g(x) u, bit for bit, for stacks and single states."""
    model = make_model(name)
    rng = np.random.default_rng(3)
    x, u = 3 * rng.standard_normal((500, model.n)), 2 * rng.standard_normal((500, model.m))
    np.testing.assert_array_equal(model.rhs(x, u), Model.rhs(model, x, u))
    np.testing.assert_array_equal(model.rhs(x[7], u[7]), Model.rhs(model, x[7], u[7]))


@pytest.mark.parametrize("name", ["unicycle", "rwd_car", "fwd_car"])
def test_specialised_step_agrees_with_generic_rk4(name):
    """The cars' steps are the generic RK4 on rhs, bit for bit (shared values only computed once); the
    unicycle's rotations agree to 1e-14 (relative to the state's size), for stacks and single states,
    and with the steering angle at its end stop."""
    model = make_model(name)
    plant = Plant(model, 0.02, 4)
    rng = np.random.default_rng(11)
    lim = model.state_limits()
    x = np.clip(5 * rng.standard_normal((2000, model.n)), lim[:, 0], lim[:, 1])
    u = np.clip(2 * rng.standard_normal((2000, model.m)), *model.input_limits().T)
    fast, ref = plant.step(x, u), plant.generic_step(x, u)
    if name == "unicycle":
        np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-14 * max(1.0, np.abs(x).max()))
    else:
        np.testing.assert_array_equal(fast, ref)
    np.testing.assert_allclose(plant.step(x[5], u[5]), ref[5], rtol=0, atol=1e-13)
