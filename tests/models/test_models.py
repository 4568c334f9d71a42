"""Contract tests run over every registered model."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from nhstab.errors import InputError, PipelineError, UnknownModelError
from nhstab.models import MODELS, make_model
from reference import central_jacobian

MODEL_NAMES = sorted(MODELS)
angle = st.floats(-3.0, 3.0, allow_nan=False)
coord = st.floats(-20.0, 20.0, allow_nan=False)
steer = st.floats(-1.2, 1.2, allow_nan=False)       # |phi| < pi/2 for the rwd car's tan
speed = st.floats(-3.0, 3.0, allow_nan=False)


def _state(name, vals, extra=(0.3,)):
    m = make_model(name)
    if name == "heisenberg":
        return np.array(vals[:3])
    if name == "unicycle":
        return np.array([vals[0], vals[1], vals[2]])
    if name == "fwd_car":
        return np.array([vals[0], vals[1], vals[3], vals[2]])   # (x, y, phi, theta)
    if name == "rwd_car":
        return np.array([vals[0], vals[1], vals[2], vals[3]])   # (x, y, theta, phi)
    if name == "car_trailer":                                   # (x, y, theta, phi, theta1, ..., thetaN)
        return np.array([vals[0], vals[1], vals[2], vals[3], *extra[: m.n - 4]])
    raise AssertionError(m)




@pytest.mark.parametrize("name", MODEL_NAMES)
@settings(max_examples=60, deadline=None)
@given(vals=st.tuples(coord, coord, angle, steer), u=st.tuples(speed, speed),
       extra=st.lists(angle, min_size=8, max_size=8))
def test_jacobians_match_central_differences(name, vals, u, extra):
    m = make_model(name)
    x = _state(name, vals, extra)
    u = np.array(u)
    # d(g(x) u)/dx and df/dx against central differences; tolerance: eps^2 truncation + roundoff
    num_gu = central_jacobian(lambda z: m.g(z) @ u, x)
    np.testing.assert_allclose(m.dgu_dx(x, u), num_gu, rtol=1e-6, atol=1e-7)
    num_f = central_jacobian(m.f, x)
    np.testing.assert_allclose(m.dfdx(x), num_f, atol=1e-9)
    A, B = m.linearize(x, u)
    np.testing.assert_allclose(A, m.dfdx(x) + m.dgu_dx(x, u))
    np.testing.assert_allclose(B, m.g(x))


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_shapes_names_and_vectorisation(name, rng):
    m = make_model(name)
    assert len(m.state_names) == m.n and len(m.input_names) == m.m
    x = rng.uniform(-1, 1, (7, 5, m.n))
    u = rng.uniform(-1, 1, (7, 5, m.m))
    assert m.g(x).shape == (7, 5, m.n, m.m)
    assert m.dgu_dx(x, u).shape == (7, 5, m.n, m.n)
    assert m.rhs(x, u).shape == (7, 5, m.n)
    # batched evaluation equals point-by-point evaluation
    for i, j in [(0, 0), (3, 4), (6, 2)]:
        np.testing.assert_allclose(m.rhs(x, u)[i, j], m.rhs(x[i, j], u[i, j]), rtol=1e-14)
        np.testing.assert_allclose(m.dgu_dx(x, u)[i, j], m.dgu_dx(x[i, j], u[i, j]), rtol=1e-14)
    lim = m.input_limits()
    assert lim.shape == (m.m, 2) and np.all(lim[:, 0] < lim[:, 1])
    assert m.state_limits().shape == (m.n, 2)


def test_paper_equations():
    """Spot values straight from the paper's equations (10), (11), (12)."""
    h = make_model("heisenberg")
    np.testing.assert_allclose(h.rhs(np.array([1.0, 2.0, 3.0]), np.array([0.5, -1.0])), [0.5, -1.0, 1.0])
    uni = make_model("unicycle")
    np.testing.assert_allclose(uni.rhs(np.array([0, 0, np.pi / 2]), np.array([2.0, 0.3])), [0, 2.0, 0.3], atol=1e-15)
    car = make_model("fwd_car", wheelbase=2.0)
    x = np.array([0.0, 0.0, 0.3, 0.7])          # phi = 0.3, theta = 0.7
    np.testing.assert_allclose(car.rhs(x, np.array([1.5, 0.2])),
                               [np.cos(0.3) * np.cos(0.7) * 1.5, np.cos(0.3) * np.sin(0.7) * 1.5, 0.2,
                                np.sin(0.3) * 1.5 / 2.0])
    # NOTES item 3: the corrected Jacobian row 4 = (0, 0, cos x3 u1 / L, 0)
    np.testing.assert_allclose(car.dgu_dx(x, np.array([1.5, 0.2]))[3], [0, 0, np.cos(0.3) * 1.5 / 2.0, 0])
    rwd = make_model("rwd_car", wheelbase=2.5)
    np.testing.assert_allclose(rwd.rhs(np.array([0, 0, 0, 0.4]), np.array([1.0, 0.1]))[2], np.tan(0.4) / 2.5)


def test_state_error_wraps_angles():
    uni = make_model("unicycle")
    e = uni.state_error(np.array([1.0, 0.0, np.pi - 0.1]), np.array([0.0, 0.0, -np.pi + 0.1]))
    np.testing.assert_allclose(e, [1.0, 0.0, -0.2], atol=1e-12)


def test_registry_errors():
    with pytest.raises(UnknownModelError, match="'model' must be one of") as exc:
        make_model("tricycle")
    assert isinstance(exc.value, ValueError) and isinstance(exc.value, PipelineError)
    with pytest.raises(InputError, match="fwd_car.wheelbase"):
        make_model("fwd_car", wheelbase=-1.0)
    with pytest.raises(InputError, match="fwd_car.wheelbase"):
        make_model("fwd_car", wheelbase=float("nan"))
    with pytest.raises(InputError, match="heisenberg parameter"):
        make_model("heisenberg", wheelbase=1.0)
    with pytest.raises(InputError, match="rwd_car.max_steer"):
        make_model("rwd_car", max_steer=2.0)
