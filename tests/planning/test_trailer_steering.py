"""Chained forms of any dimension (the exact phase laws, the Murray-Sastry net motion, polynomial
steering) and the car with one trailer in chained form.

Every end point is checked twice: in chained coordinates by the plan's own closed form, and by an
independent DOP853 integration (of the chained equations, and of the car_trailer model itself under
the mapped inputs), phase by phase since the inputs jump at phase boundaries.
"""

import functools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from nhstab.errors import InputError
from nhstab.models import make_model
from nhstab.planning.steering import chained_rhs, net_displacement, net_motion, steer_chained, steer_chained_polynomial
from nhstab.planning.trailer_charts import chained_inputs, from_chained, inputs_from_chained, steer_trailer, to_chained
from scipy.integrate import solve_ivp

RTOL, ATOL = 1e-12, 1e-12
fl = functools.partial(st.floats, allow_nan=False, allow_infinity=False, allow_subnormal=False)
TRAILER = make_model("car_trailer")


def integrate_end(fun, y0, boundaries, rtol=RTOL, atol=ATOL):
    y = np.array(y0, dtype=float)
    for t0, t1 in zip(boundaries[:-1], boundaries[1:]):
        sol = solve_ivp(fun, (t0, t1), y, method="DOP853", rtol=rtol, atol=atol)
        assert sol.success
        y = sol.y[:, -1]
    return y


def chained_end(plan):
    """The chained form integrated under the plan's inputs (evaluated strictly inside each phase)."""
    def fun(t, z):
        return chained_rhs(z, plan.inputs(float(t)))
    return integrate_end(fun, plan.z0, plan.phase_times)


# ---------------------------------------------------------------------------------------------
# chained forms of any dimension
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n,k", [(5, 3), (5, 4), (5, 5), (6, 6), (7, 4)])
def test_net_displacement_matches_integration_and_murray_sastry(n, k):
    """One period of phase k: the exponential-polynomial closed form against DOP853, and z_k's motion
    against Murray-Sastry's (a / 2w)^(k-2) b / (k-2)! 2 pi / w."""
    a, b, w = 0.8, -1.1, 1.7
    z0 = np.linspace(0.3, -0.4, n)
    P = 2 * math.pi / w

    def fun(t, z):
        return chained_rhs(z, np.array([a * math.sin(w * t), b * math.cos((k - 2) * w * t)]))

    end = integrate_end(fun, z0, [0.0, P])
    np.testing.assert_allclose(end - z0, net_displacement(k, a, b, w, z0), atol=1e-10)
    ms = (a / (2 * w)) ** (k - 2) * b / math.factorial(k - 2) * 2 * math.pi / w
    assert net_motion(k, a, b, w, z0) == pytest.approx(ms, rel=1e-12)
    assert net_displacement(k, a, b, w, z0)[k - 1] == pytest.approx(ms, rel=1e-9)


@pytest.mark.parametrize("n", [5, 6])
def test_phase_states_follow_integration(n, rng):
    """The closed-form states of every phase of a plan, at many times, against DOP853 on a grid."""
    z0, zf = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    plan = steer_chained(z0, zf, 4.0)
    grid = plan.grid(40)

    def fun(t, z):
        return chained_rhs(z, plan.inputs(float(t)))

    y = plan.z0.copy()
    for t0, t1 in zip(plan.phase_times[:-1], plan.phase_times[1:]):
        sel = (grid >= t0) & (grid <= t1)
        sol = solve_ivp(fun, (t0, t1), y, method="DOP853", rtol=RTOL, atol=ATOL, t_eval=grid[sel])
        np.testing.assert_allclose(plan.states(grid[sel]), sol.y.T, atol=1e-9)
        y = sol.y[:, -1]


@settings(max_examples=40, deadline=None)
@given(data=st.data(), T=fl(0.5, 6.0))
@pytest.mark.slow
def test_steer_chained_five_reaches_goal(data, T):
    """Murray-Sastry phased sinusoids, n = 5: the plan ends at the target to 1e-6, in its closed form
    and by integrating the chained equations."""
    z0 = np.array(data.draw(st.lists(fl(-1.5, 1.5), min_size=5, max_size=5)))
    zf = np.array(data.draw(st.lists(fl(-1.5, 1.5), min_size=5, max_size=5)))
    plan = steer_chained(z0, zf, T)
    assert len(plan.phases) == 4 and [p.k for p in plan.phases[1:]] == [3, 4, 5]
    np.testing.assert_allclose(plan.states(T), zf, atol=1e-6)
    np.testing.assert_allclose(chained_end(plan), zf, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(data=st.data(), T=fl(0.5, 6.0), n=st.sampled_from([3, 4, 5, 6]))
def test_polynomial_steering_reaches_goal_without_reversing(data, T, n):
    z0 = np.array(data.draw(st.lists(fl(-1.5, 1.5), min_size=n, max_size=n)))
    zf = np.array(data.draw(st.lists(fl(-1.5, 1.5), min_size=n, max_size=n)))
    assume(abs(zf[0] - z0[0]) > 0.2)
    plan = steer_chained_polynomial(z0, zf, T)
    v1 = plan.inputs(plan.grid(50))[:, 0]
    assert np.all(np.sign(v1) == np.sign(zf[0] - z0[0]))
    np.testing.assert_allclose(plan.states(T), zf, atol=1e-6)
    np.testing.assert_allclose(chained_end(plan), zf, atol=1e-6)


def test_polynomial_steering_is_the_hermite_interpolant():
    """With v1 constant, z_n as a function of z1 is the polynomial of degree 2n - 3 matching z_n and
    its first n - 2 derivatives at both ends: check against numpy's Hermite fit for n = 5."""
    z0, zf = np.array([0.0, 0.3, -0.2, 0.1, 0.0]), np.array([2.0, -0.1, 0.4, 0.3, 0.5])
    plan = steer_chained_polynomial(z0, zf, 3.0)
    t = np.linspace(0, 3.0, 41)
    z = plan.states(t)
    coef = np.polynomial.polynomial.polyfit(z[:, 0], z[:, 4], 7)
    np.testing.assert_allclose(np.polynomial.polynomial.polyval(z[:, 0], coef), z[:, 4], atol=1e-10)
    # d z5 / d z1 = z4, d z4 / d z1 = z3 along the motion (chained form with v1 constant)
    d1 = np.polynomial.polynomial.polyder(coef)
    np.testing.assert_allclose(np.polynomial.polynomial.polyval(z[:, 0], d1), z[:, 3], atol=1e-8)


def test_bad_chained_input():
    with pytest.raises(InputError) as err:
        steer_chained_polynomial([0, 0, 0, 0, 0], [0, 1, 1, 1, 1], 1.0)
    assert err.value.argument == "zf"
    with pytest.raises(InputError) as err:
        net_motion(6, 1.0, 1.0, 1.0, [0, 0, 0, 0, 0])
    assert err.value.argument == "k"


# ---------------------------------------------------------------------------------------------
# the car with one trailer in chained form
# ---------------------------------------------------------------------------------------------
state = st.tuples(fl(-5, 5), fl(-5, 5), fl(-1.0, 1.0), fl(-0.6, 0.6), fl(-1.0, 1.0))


@settings(max_examples=60, deadline=None)
@given(s=state)
def test_chart_round_trips(s):
    x = np.array(s)
    assume(abs(x[2] - x[4]) < 1.3)
    np.testing.assert_allclose(from_chained(TRAILER, to_chained(TRAILER, x)), x, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(s=state, u=st.tuples(fl(-2, 2), fl(-2, 2)))
def test_chart_carries_the_model_to_the_chained_form(s, u):
    """d(to_chained)/dx (central differences) times the model's x' equals the chained z' under the
    mapped inputs; and the input maps invert each other."""
    x, u = np.array(s), np.array(u)
    assume(abs(x[2] - x[4]) < 1.3)
    eps = 1e-6
    J = np.stack([(to_chained(TRAILER, x + eps * e) - to_chained(TRAILER, x - eps * e)) / (2 * eps)
                  for e in np.eye(5)], axis=1)
    v = chained_inputs(TRAILER, x, u)
    z = to_chained(TRAILER, x)
    np.testing.assert_allclose(J @ TRAILER.rhs(x, u), chained_rhs(z, v), rtol=1e-6, atol=1e-6 * (1 + np.abs(z).max()))
    np.testing.assert_allclose(inputs_from_chained(TRAILER, z, v), u, rtol=1e-9, atol=1e-9)


pair = st.tuples(fl(2.0, 8.0), fl(-2.0, 2.0), fl(-0.4, 0.4), fl(-0.3, 0.3), fl(-0.4, 0.4))


@pytest.mark.slow
@pytest.mark.parametrize("mode,examples", [("phased", 6), ("polynomial", 15)])
def test_trailer_steering_reaches_goal_in_both_coordinates(mode, examples):
    """(Sinusoidal steering is the "phased" mode; each example integrates the model through four
    phases, so there are few of them.)"""

    @settings(max_examples=examples, deadline=None)
    @given(p=pair, reverse=st.booleans())
    def check(p, reverse):
        _reaches_goal(p, mode, reverse)

    check()


def _reaches_goal(p, mode, reverse):
    """n = 5: the steered trailer ends at the target to 1e-6 in chained coordinates (the plan's closed
    form, and DOP853 on the chained equations) and in the model's (DOP853 on the car_trailer model
    under the mapped inputs, independently of the chart's state map)."""
    dx, dy, th, phi, dth = p
    x0 = np.array([0.0, 0.0, 0.1, 0.0, 0.0])
    xf = np.array([-dx if reverse else dx, dy, th + dth, phi, th])
    try:
        steering = steer_trailer(TRAILER, x0, xf, T=4.0, mode=mode)
    except InputError:
        assume(False)
    plan = steering.plan
    np.testing.assert_allclose(plan.states(plan.T), plan.zf, atol=1e-6)
    np.testing.assert_allclose(chained_end(plan), plan.zf, atol=1e-6)

    def model_rhs(t, x):
        return TRAILER.rhs(x, steering.inputs_at(np.array([t]))[0])

    end = integrate_end(model_rhs, x0, plan.phase_times, rtol=1e-10, atol=1e-11)
    np.testing.assert_allclose(TRAILER.state_error(end, xf), 0.0, atol=1e-6)


def test_trailer_steering_time_scaling_meets_the_limits():
    x0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    xf = np.array([6.0, 1.0, 0.3, 0.0, 0.3])
    s = steer_trailer(TRAILER, x0, xf)               # T None: the shortest time within the limits
    assert s.max_speed <= TRAILER.max_speed + 1e-9 and s.max_abs_omega_s <= TRAILER.max_steer_rate + 1e-9
    assert max(s.max_speed / TRAILER.max_speed, s.max_abs_omega_s / TRAILER.max_steer_rate) > 0.99
    np.testing.assert_allclose(s.final_error, 0.0, atol=1e-9)


def test_trailer_chart_refuses():
    with pytest.raises(InputError) as err:
        to_chained(TRAILER, [0, 0, 1.7, 0, 0.0])             # hitch angle beyond pi/2
    assert err.value.argument == "x"
    with pytest.raises(InputError) as err:
        steer_trailer(make_model("car_trailer", hitch_lengths=[2, 2]), np.zeros(6), np.ones(6))
    assert err.value.argument == "model"
    with pytest.raises(InputError) as err:
        steer_trailer(TRAILER, np.zeros(5), np.zeros(5), mode="sideways")
    assert err.value.argument == "mode"
