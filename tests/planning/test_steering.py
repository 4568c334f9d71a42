"""Sinusoidal steering of chained-form systems, the Heisenberg system and the two cars.

Every end-point claim is checked independently by integrating the dynamics with scipy's DOP853
under the plan's inputs, phase by phase (the inputs jump at the phase boundaries).
"""

import functools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from nhstab.errors import InputError, PipelineError
from nhstab.models import make_model
from nhstab.planning.car_charts import (
    CarSteering,
    car_inputs_from_chained,
    chained_inputs_from_car,
    from_chained,
    steer_car,
    to_chained,
)
from nhstab.planning.steering import (
    SteeringPlan,
    chained_rhs,
    net_displacement,
    net_motion,
    steer_chained,
    steer_chained_constant_v1,
    steer_heisenberg,
)
from scipy.integrate import solve_ivp

RTOL, ATOL = 1e-11, 1e-12
fl = functools.partial(st.floats, allow_nan=False, allow_infinity=False, allow_subnormal=False)
coord = fl(-2.0, 2.0)
horizon = fl(0.5, 8.0)


def integrate_end(fun, y0, boundaries):
    y = np.array(y0, dtype=float)
    for t0, t1 in zip(boundaries[:-1], boundaries[1:]):
        sol = solve_ivp(fun, (t0, t1), y, method="DOP853", rtol=RTOL, atol=ATOL)
        assert sol.success
        y = sol.y[:, -1]
    return y


def integrate_on_grid(fun, y0, boundaries, grid):
    """States at every grid time (grid includes all boundaries), integrating phase by phase."""
    out = np.empty((grid.size, len(y0)))
    y = np.array(y0, dtype=float)
    for t0, t1 in zip(boundaries[:-1], boundaries[1:]):
        mask = (grid >= t0) & (grid <= t1)
        sol = solve_ivp(fun, (t0, t1), y, method="DOP853", rtol=RTOL, atol=ATOL, t_eval=grid[mask])
        assert sol.success
        out[mask] = sol.y.T
        y = sol.y[:, -1]
    return out


# ---------------------------------------------------------------------------------------------
# (a) chained form and Heisenberg: exact end points
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [3, 4])
@settings(max_examples=50, deadline=None)
@given(data=st.data(), T=horizon)
def test_steer_chained_reaches_goal(n, data, T):
    z0 = np.array(data.draw(st.lists(coord, min_size=n, max_size=n)))
    zf = np.array(data.draw(st.lists(coord, min_size=n, max_size=n)))
    plan = steer_chained(z0, zf, T)
    assert isinstance(plan, SteeringPlan) and plan.T == T and plan.n == n
    assert plan.phase_times.shape == (n,) and plan.phase_times[0] == 0.0 and plan.phase_times[-1] == T
    np.testing.assert_allclose(plan.states(np.array([0.0]))[0], z0, atol=1e-12)
    closed = plan.states(np.array([T]))[0]
    np.testing.assert_allclose(closed, zf, atol=1e-9)
    numeric = integrate_end(lambda t, z: chained_rhs(z, plan.inputs(t)), z0, plan.phase_times)
    np.testing.assert_allclose(numeric, zf, atol=1e-6)
    np.testing.assert_allclose(numeric, closed, atol=1e-6)


@settings(max_examples=50, deadline=None)
@given(x0=st.lists(coord, min_size=3, max_size=3), xf=st.lists(coord, min_size=3, max_size=3), T=horizon)
def test_steer_heisenberg_reaches_goal(x0, xf, T):
    model = make_model("heisenberg")
    plan = steer_heisenberg(x0, xf, T)
    np.testing.assert_allclose(plan.states(np.array([T]))[0], xf, atol=1e-9)
    # integrate the *model* (not the chained form) under the plan's inputs
    numeric = integrate_end(lambda t, x: model.rhs(x, plan.inputs(t)), x0, plan.phase_times)
    np.testing.assert_allclose(numeric, xf, atol=1e-6)


@pytest.mark.parametrize("n", [3, 4])
def test_plan_states_follow_the_integrated_trajectory(n, rng):
    z0, zf = rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)
    for kwargs in ({}, {"amplitude": 0.7}, {"balance": 3.0, "phase_fractions": [1, 2, 3][: n - 1]}):
        plan = steer_chained(z0, zf, 3.0, **kwargs)
        grid = plan.grid(40)
        numeric = integrate_on_grid(lambda t, z: chained_rhs(z, plan.inputs(t)), z0, plan.phase_times, grid)
        np.testing.assert_allclose(plan.states(grid), numeric, atol=1e-8)
        np.testing.assert_allclose(plan.states(np.array([plan.T]))[0], zf, atol=1e-9)


def test_plan_phase_structure():
    plan = steer_chained([0, 0, 0, 0], [1.0, 0.2, -0.3, 0.5], 6.0)
    kinds = [(p.kind, p.k) for p in plan.phases]
    assert kinds == [("constant", 0), ("sinusoid", 3), ("sinusoid", 4)]
    np.testing.assert_allclose(plan.phase_times, [0, 2, 4, 6])
    u = plan.inputs(np.array([0.5, 2.0 + 1e-9, 4.0]))
    np.testing.assert_allclose(u[0], [0.5, 0.1])                       # constant phase
    assert abs(u[1, 0]) < 1e-8 and abs(u[1, 1] - plan.phases[1].b) < 1e-8   # sin/cos at phase start
    assert u[2, 0] == 0.0 and u[2, 1] == pytest.approx(plan.phases[2].b)
    # balanced amplitudes: a = |b|
    for ph in plan.phases[1:]:
        assert ph.a == pytest.approx(abs(ph.b)) and ph.a >= 0
    # already at the goal: the sinusoidal phases are idle
    idle = steer_chained([1, 2, 3], [1, 2, 3], 1.0)
    assert all(p.a == 0.0 and p.b == 0.0 for p in idle.phases[1:])
    with pytest.raises(InputError):
        plan.states(np.array([6.5]))


# ---------------------------------------------------------------------------------------------
# (b) the closed-form net motion of one sinusoidal period
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("k", [3, 4])
@pytest.mark.parametrize("a,b,w", [(1.0, 2.0, 1.3), (-0.5, 0.7, 3.0), (2.0, -1.0, 0.5), (0.3, 0.3, 2 * math.pi)])
def test_net_motion_matches_integration(k, a, b, w, rng):
    for n in (3, 4) if k == 3 else (4,):
        zs = rng.uniform(-1, 1, n)
        fun = lambda t, z: chained_rhs(z, [a * math.sin(w * t), b * math.cos((k - 2) * w * t)])  # noqa: E731
        ze = solve_ivp(fun, (0.0, 2 * math.pi / w), zs, method="DOP853", rtol=1e-12, atol=1e-13).y[:, -1]
        assert net_motion(k, a, b, w, zs) == pytest.approx(ze[k - 1] - zs[k - 1], abs=1e-9)
        np.testing.assert_allclose(net_displacement(k, a, b, w, zs), ze - zs, atol=1e-9)
        # the Murray-Sastry formula (a / 2w)^(k-2) b / (k-2)! * 2 pi / w
        ms = (a / (2 * w)) ** (k - 2) * b / math.factorial(k - 2) * 2 * math.pi / w
        assert net_motion(k, a, b, w, zs) == pytest.approx(ms, rel=1e-12)


def test_net_motion_n3_special_case():
    # v1 = a sin wt, v2 = b cos wt from z2(0) = 0: dz3 = pi a b / w^2
    assert net_motion(3, 1.5, 2.0, 2.0, [0, 0, 0]) == pytest.approx(math.pi * 3.0 / 4.0)


# ---------------------------------------------------------------------------------------------
# (b') constant-v1 steering: v1 = (z1f - z1s) / T, v2 = b0 + b1 cos(w t) + b2 sin(w t)
# ---------------------------------------------------------------------------------------------
@st.composite
def constant_v1_pairs(draw, n):
    """Random chained pairs whose z1 moves by at least 0.25 (c = dz1 / T != 0), either way."""
    z0 = np.array(draw(st.lists(coord, min_size=n, max_size=n)))
    zf = np.array(draw(st.lists(coord, min_size=n, max_size=n)))
    zf[0] = z0[0] + draw(st.sampled_from([-1.0, 1.0])) * draw(fl(0.25, 4.0))
    return z0, zf


@pytest.mark.parametrize("n", [3, 4])
@settings(max_examples=100, deadline=None)
@given(data=st.data(), T=horizon)
def test_constant_v1_reaches_goal_without_reversing(n, data, T):
    z0, zf = data.draw(constant_v1_pairs(n))
    plan = steer_chained_constant_v1(z0, zf, T)
    assert plan.mode == "constant_v1" and plan.T == T and len(plan.phases) == 1
    np.testing.assert_array_equal(plan.phase_times, [0.0, T])
    np.testing.assert_allclose(plan.states(np.array([0.0]))[0], z0, atol=1e-12)
    np.testing.assert_allclose(plan.states(np.array([T]))[0], zf, atol=1e-9)
    # v1 is the constant (z1f - z1s) / T on the whole horizon: one sign, never zero
    v1 = plan.inputs(plan.grid(200))[:, 0]
    assert np.all(v1 == (zf[0] - z0[0]) / T) and np.all(np.sign(v1) == np.sign(zf[0] - z0[0]))
    if n == 3:
        assert plan.phases[0].v2_cos == 0.0          # v2 = b0 + b2 sin(w t)
    numeric = integrate_end(lambda t, z: chained_rhs(z, plan.inputs(t)), z0, plan.phase_times)
    np.testing.assert_allclose(numeric, zf, atol=1e-6)


@pytest.mark.parametrize("n", [3, 4])
def test_constant_v1_states_follow_the_integrated_trajectory(n, rng):
    """The closed-form states agree with DOP853 (rtol 1e-12) under the same inputs along the way."""
    for _ in range(5):
        z0, zf = rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)
        T = rng.uniform(0.5, 8.0)
        plan = steer_chained_constant_v1(z0, zf, T)
        grid = np.linspace(0.0, T, 101)
        sol = solve_ivp(lambda t, z: chained_rhs(z, plan.inputs(t)), (0.0, T), z0, method="DOP853", rtol=1e-12,
                        atol=1e-13, t_eval=grid)
        assert sol.success
        np.testing.assert_allclose(plan.states(grid), sol.y.T, atol=1e-9)
        np.testing.assert_allclose(plan.states(grid, coords=3), sol.y.T[:, :3], atol=1e-9)


def test_constant_v1_coefficients_solve_the_linear_system(rng):
    """(b0, b1, b2) solve M b = e with M of the module docstring, det M = -c^3 T^6 / (8 pi^3)."""
    for _ in range(10):
        z0, zf = rng.uniform(-2, 2, 4), rng.uniform(-2, 2, 4)
        T = rng.uniform(0.5, 8.0)
        w, c = 2 * math.pi / T, (zf[0] - z0[0]) / T
        M = np.array([[T, 0.0, 0.0],
                      [c * T**2 / 2, 0.0, c * T / w],
                      [c**2 * T**3 / 6, c**2 * T / w**2, c**2 * T**2 / (2 * w)]])
        e = np.array([zf[1] - z0[1], zf[2] - z0[2] - c * T * z0[1],
                      zf[3] - z0[3] - c * T * z0[2] - c**2 * T**2 * z0[1] / 2])
        assert np.linalg.det(M) == pytest.approx(-c**3 * T**6 / (8 * math.pi**3), rel=1e-9)
        ph = steer_chained_constant_v1(z0, zf, T).phases[0]
        assert ph.v1 == pytest.approx(c, rel=1e-15)
        np.testing.assert_allclose([ph.v2, ph.v2_cos, ph.v2_sin], np.linalg.solve(M, e), rtol=1e-9, atol=1e-9)


def test_constant_v1_time_scaling_keeps_the_path():
    """A longer T traces the same states at the same fraction of T, with inputs divided by T."""
    z0, zf = np.array([0.0, 0.3, -0.2, 0.1]), np.array([1.5, -0.1, 0.25, 0.4])
    p1, p3 = steer_chained_constant_v1(z0, zf, 1.0), steer_chained_constant_v1(z0, zf, 3.0)
    tau = np.linspace(0.0, 1.0, 57)
    np.testing.assert_allclose(p3.states(3.0 * tau), p1.states(tau), atol=1e-12)
    np.testing.assert_allclose(3.0 * p3.inputs(3.0 * tau), p1.inputs(tau), atol=1e-12)


# ---------------------------------------------------------------------------------------------
# (c) car <-> chained coordinates
# ---------------------------------------------------------------------------------------------
def _car_state(name, px, py, th, phi):
    return np.array([px, py, th, phi]) if name == "rwd_car" else np.array([px, py, phi, th])


@pytest.mark.parametrize("name", ["rwd_car", "fwd_car"])
@settings(max_examples=50, deadline=None)
@given(px=st.floats(-10, 10), py=st.floats(-10, 10), th=st.floats(-1.4, 1.4), phi=st.floats(-1.4, 1.4),
       v=st.floats(-2, 2), om=st.floats(-2, 2))
def test_chained_coordinates_round_trip(name, px, py, th, phi, v, om):
    model = make_model(name, wheelbase=1.7)
    x = _car_state(name, px, py, th, phi)
    z = to_chained(model, x)
    np.testing.assert_allclose(from_chained(model, z), x, atol=1e-12)
    np.testing.assert_allclose(to_chained(model, from_chained(model, z)), z, rtol=1e-9, atol=1e-10)
    # input maps are inverse to each other ...
    u = np.array([v, om])
    vc = chained_inputs_from_car(model, x, u)
    np.testing.assert_allclose(car_inputs_from_chained(model, z, vc), u, rtol=1e-9, atol=1e-10)
    # ... and realise the chained dynamics: d/dt to_chained(x) = chained_rhs(z, v)
    eps = 1e-6
    dz = (to_chained(model, x + eps * model.rhs(x, u)) - to_chained(model, x - eps * model.rhs(x, u))) / (2 * eps)
    np.testing.assert_allclose(dz, chained_rhs(z, vc), rtol=1e-5, atol=1e-5 * (1 + np.abs(dz).max()))


@pytest.mark.parametrize("name", ["rwd_car", "fwd_car"])
def test_converted_inputs_reproduce_the_chained_trajectory(name, rng):
    """Integrating the model from from_chained(z0) under car_inputs_from_chained reproduces
    from_chained of the chained trajectory to 1e-8 on a grid."""
    model = make_model(name)
    z0 = np.array([0.0, 0.1, 0.2, 0.0])
    zf = np.array([1.0, -0.1, -0.1, 0.4])
    plan = steer_chained(z0, zf, 6.0)
    grid = plan.grid(50)
    fun = lambda t, x: model.rhs(x, car_inputs_from_chained(model, plan.states(t), plan.inputs(t)))  # noqa: E731
    numeric = integrate_on_grid(fun, from_chained(model, z0), plan.phase_times, grid)
    np.testing.assert_allclose(numeric, from_chained(model, plan.states(grid)), atol=1e-8)


def test_chained_rhs_vectorised():
    z = np.arange(24.0).reshape(2, 3, 4)
    v = np.array([2.0, -1.0])
    out = chained_rhs(z, v)
    assert out.shape == (2, 3, 4)
    np.testing.assert_allclose(out[..., 0], 2.0)
    np.testing.assert_allclose(out[..., 1], -1.0)
    np.testing.assert_allclose(out[..., 2:], 2.0 * z[..., 1:3])


# ---------------------------------------------------------------------------------------------
# (a) cars: whole chain of conversions, checked by integrating the car model
# ---------------------------------------------------------------------------------------------
@st.composite
def pose_pairs(draw):
    p0 = np.array([draw(fl(-5, 5)), draw(fl(-5, 5))])
    th0 = draw(fl(-math.pi, math.pi))
    # no move at all, or at least a nanometre: between them (moves such as 1e-158 m, whose squares
    # underflow) the steering is exact, but the independent check's DOP853 fails on its error norm (0 / 0)
    r, ang = draw(st.one_of(st.just(0.0), fl(1e-9, 2.0))), draw(fl(-math.pi, math.pi))
    pf = p0 + r * np.array([math.cos(ang), math.sin(ang)])
    thf = th0 + draw(fl(-0.8, 0.8))
    phi0, phif = draw(fl(-0.3, 0.3)), draw(fl(-0.3, 0.3))
    return (p0[0], p0[1], th0, phi0), (pf[0], pf[1], thf, phif)


@pytest.mark.parametrize("name", ["rwd_car", "fwd_car"])
@settings(max_examples=50, deadline=None)
@given(pair=pose_pairs(), T=fl(2.0, 20.0))
@pytest.mark.slow
def test_steer_car_reaches_goal(name, pair, T):
    model = make_model(name)
    x0, xf = _car_state(name, *pair[0]), _car_state(name, *pair[1])
    res = steer_car(model, x0, xf, T, points_per_phase=100)
    assert isinstance(res, CarSteering)
    assert res.x.shape == (3 * 100 + 1, 4) and res.u.shape == (3 * 100 + 1, 2) and res.t[-1] == T
    np.testing.assert_array_equal(res.x[0], x0)
    assert np.abs(res.final_error).max() < 1e-9
    assert res.max_abs_local_theta < 1.2
    # independent check: integrate the car model from x0 under the returned model inputs
    x_end = integrate_end(lambda t, x: model.rhs(x, res.inputs_at(t)), x0, res.phase_times)
    assert np.abs(model.state_error(x_end, xf)).max() < 1e-6
    # the gridded inputs are the continuous ones
    np.testing.assert_allclose(res.inputs_at(res.t), res.u, atol=1e-12)
    # steering angle continuous: |dphi| <= max|omega_s| dt on the output grid
    phi = res.x[:, 3] if name == "rwd_car" else res.x[:, 2]
    dt = np.diff(res.t)
    assert np.all(np.abs(np.diff(phi)) <= res.max_abs_omega_s * dt * 1.01 + 1e-12)
    assert res.max_abs_phi == pytest.approx(np.abs(phi).max())
    assert res.max_speed == pytest.approx(np.abs(res.u[:, 0]).max())
    # heading continuous too (no 2 pi jumps from the frame change)
    th = res.x[:, 2] if name == "rwd_car" else res.x[:, 3]
    assert np.abs(np.diff(th)).max() < 0.1


@pytest.mark.parametrize("name", ["rwd_car", "fwd_car"])
def test_steer_car_auto_time_respects_rate_limits(name):
    model = make_model(name)
    x0 = _car_state(name, 1.0, -2.0, 3.0, 0.1)
    xf = _car_state(name, 0.2, -1.0, -2.9, -0.2)   # heading across the +-pi cut
    res = steer_car(model, x0, xf)
    assert res.max_speed <= model.max_speed and res.max_abs_omega_s <= model.max_steer_rate
    assert res.within_limits["speed"] and res.within_limits["steer_rate"]
    phi = res.x[:, 3] if name == "rwd_car" else res.x[:, 2]
    assert np.all(np.abs(np.diff(phi)) <= model.max_steer_rate * np.diff(res.t) + 1e-12)
    x_end = integrate_end(lambda t, x: model.rhs(x, res.inputs_at(t)), x0, res.phase_times)
    assert np.abs(model.state_error(x_end, xf)).max() < 1e-6
    np.testing.assert_allclose(res.states_at(res.t), res.x, atol=1e-12)


@st.composite
def ahead_or_behind_pairs(draw):
    """Car pose pairs whose goal lies within 0.5 rad of the start's heading line, ahead or behind."""
    p0 = np.array([draw(fl(-5, 5)), draw(fl(-5, 5))])
    th0 = draw(fl(-math.pi, math.pi))
    back = draw(st.booleans())
    r, ang = draw(fl(0.3, 2.0)), th0 + draw(fl(-0.5, 0.5)) + (math.pi if back else 0.0)
    pf = p0 + r * np.array([math.cos(ang), math.sin(ang)])
    thf = th0 + draw(fl(-0.6, 0.6))
    phi0, phif = draw(fl(-0.3, 0.3)), draw(fl(-0.3, 0.3))
    return (p0[0], p0[1], th0, phi0), (pf[0], pf[1], thf, phif), -1.0 if back else 1.0


@pytest.mark.parametrize("name", ["rwd_car", "fwd_car"])
@settings(max_examples=50, deadline=None)
@given(pair=ahead_or_behind_pairs())
def test_steer_car_constant_v1_reaches_goal_in_one_direction(name, pair):
    model = make_model(name)
    x0, xf = _car_state(name, *pair[0]), _car_state(name, *pair[1])
    res = steer_car(model, x0, xf, mode="constant_v1", points_per_phase=300)
    assert res.plan.mode == "constant_v1" and res.phase_times.tolist() == [0.0, res.T]
    np.testing.assert_array_equal(res.x[0], x0)
    assert np.abs(res.final_error).max() < 1e-9
    # the car moves one way only: the sign of the goal's side
    assert np.all(np.sign(res.u[:, 0]) == pair[2])
    # time scaling to the limits, as in the phased mode
    assert res.max_speed <= model.max_speed and res.max_abs_omega_s <= model.max_steer_rate
    x_end = integrate_end(lambda t, x: model.rhs(x, res.inputs_at(t)), x0, res.phase_times)
    assert np.abs(model.state_error(x_end, xf)).max() < 1e-6
    np.testing.assert_allclose(res.inputs_at(res.t), res.u, atol=1e-12)
    np.testing.assert_allclose(res.states_at(res.t), res.x, atol=1e-12)


def test_steer_car_frames():
    model = make_model("rwd_car")
    x0, xf = np.array([0.0, 0.0, 1.5, 0.0]), np.array([1.0, 2.0, 1.7, 0.0])   # near theta = pi/2 globally
    with pytest.raises(InputError):
        steer_car(model, x0, xf, 5.0, frame="world")          # the world chart is singular there
    for frame in ("auto", "mean", "start", "goal", 1.6):
        res = steer_car(model, x0, xf, 5.0, frame=frame)
        assert np.abs(res.final_error).max() < 1e-9
    assert steer_car(model, x0, xf, 5.0, frame="mean").frame["heading"] == pytest.approx(1.6)


# ---------------------------------------------------------------------------------------------
# (d) errors
# ---------------------------------------------------------------------------------------------
def test_refuses_large_heading_change():
    model = make_model("rwd_car")
    with pytest.raises(InputError) as err:
        steer_car(model, [0, 0, 0, 0], [1, 0, 2.6, 0], 5.0)
    assert err.value.argument == "xf"
    # end points inside the chart but the steered path leaves it: the detail reports max |phi|
    with pytest.raises(InputError, match=r"max \|phi\|"):
        steer_car(model, [0, 0, 0, 0], [0, 3, 1.1, 0], 5.0, frame="start")


def test_check_limits():
    model = make_model("rwd_car")
    with pytest.raises(InputError, match="limit"):
        steer_car(model, [0, 0, 0, 0], [0.0, 2.0, 0.0, 0.0], 0.5, check_limits=True)


@pytest.mark.parametrize("call,argument", [
    (lambda: steer_chained([0, 0, 0], [1, 1, 1], 0.0), "T"),
    (lambda: steer_chained([0, 0, 0], [1, 1, 1], -1.0), "T"),
    (lambda: steer_chained([0, 0, 0], [1, 1, 1], float("nan")), "T"),
    (lambda: steer_chained([0, 0], [1, 1], 1.0), "z0"),
    (lambda: steer_chained([0] * 11, [1] * 11, 1.0), "z0"),          # dimensions 3 .. 10
    (lambda: steer_chained_constant_v1([0, 0, 0, 0, 0], [1, 1, 1, 1, 1], 1.0), "z0"),   # 3 or 4
    (lambda: steer_chained([0, 0, 0], [1, 1, 1, 1], 1.0), "zf"),
    (lambda: steer_chained([0, 0, float("nan")], [1, 1, 1], 1.0), "z0"),
    (lambda: steer_chained([0, 0, 0], [1, 1, np.inf], 1.0), "zf"),
    (lambda: steer_chained([0, 0, 0], [1, 1, 1], 1.0, amplitude="big"), "amplitude"),
    (lambda: steer_chained([0, 0, 0], [1, 1, 1], 1.0, amplitude=-1.0), "amplitude"),
    (lambda: steer_chained([0, 0, 0], [1, 1, 1], 1.0, balance=0.0), "balance"),
    (lambda: steer_chained([0, 0, 0], [1, 1, 1], 1.0, phase_fractions=[1.0, -1.0]), "phase_fractions"),
    (lambda: steer_chained([0, 0, 0], [1, 1, 1], 1.0, phase_fractions=[1.0]), "phase_fractions"),
    (lambda: steer_heisenberg([0, 0, 0, 0], [1, 1, 1, 1], 1.0), "x0"),
    (lambda: net_motion(4, 1.0, 1.0, 1.0, [0, 0, 0]), "k"),
    (lambda: net_motion(2, 1.0, 1.0, 1.0, [0, 0, 0, 0]), "k"),
    (lambda: net_motion(3, 1.0, 1.0, 0.0, [0, 0, 0]), "w"),
    (lambda: net_motion(3, float("nan"), 1.0, 1.0, [0, 0, 0]), "a"),
    (lambda: chained_rhs([0.0, 0.0, 0.0], [1.0]), "v"),
    (lambda: chained_rhs([0.0], [1.0, 1.0]), "z"),
    (lambda: to_chained(make_model("rwd_car"), [0, 0, 1.6, 0]), "x"),
    (lambda: to_chained(make_model("fwd_car"), [0, 0, 0, 1.6]), "x"),
    (lambda: to_chained(make_model("fwd_car"), [0, 0, 0]), "x"),
    (lambda: to_chained(make_model("heisenberg"), [0, 0, 0, 0]), "model"),
    (lambda: from_chained(make_model("rwd_car"), [0, 0, np.nan, 0]), "z"),
    (lambda: car_inputs_from_chained(make_model("rwd_car"), [0, 0, 0, 0], [1, 2, 3]), "v"),
    (lambda: steer_car(make_model("heisenberg"), [0, 0, 0], [1, 1, 1], 1.0), "model"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0], [1, 1, 1, 0], 1.0), "x0"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [1, 1, 0, np.nan], 1.0), "xf"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [1, 1, 0, 0], 0.0), "T"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [1, 1, 0, 0], 1.0, frame="north"), "frame"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [1, 1, 0, 0], 1.0, points_per_phase=1),
     "points_per_phase"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [1, 1, 0, 0], 1.0, theta_limit=1.6), "theta_limit"),
    (lambda: steer_car(make_model("fwd_car"), [0, 0, 1.6, 0], [1, 1, 0, 0], 1.0), "x0"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [1, 1, 0, 0], 1.0, mode="sideways"), "mode"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [1, 1, 0, 0], 1.0, mode="constant_v1",
                       phase_fractions=[1, 1, 1]), "phase_fractions"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [1, 1, 0, 0], 1.0, mode="constant_v1", amplitude=0.5),
     "amplitude"),
    (lambda: steer_car(make_model("rwd_car"), [0, 0, 0, 0], [0, 1, 0, 0], 1.0, mode="constant_v1", frame="start"),
     "xf"),
    (lambda: steer_chained_constant_v1([0, 0, 0], [0, 1, 1], 1.0), "zf"),
    (lambda: steer_chained_constant_v1([0, 0, 0], [1, 1, 1, 1], 1.0), "zf"),
    (lambda: steer_chained_constant_v1([0, 0, 0], [1, 1, 1], 0.0), "T"),
    (lambda: steer_chained_constant_v1([0, 0], [1, 1], 1.0), "z0"),
])
def test_bad_input(call, argument):
    with pytest.raises(InputError) as err:
        call()
    assert err.value.argument == argument
    assert isinstance(err.value, PipelineError) and isinstance(err.value, ValueError)
