"""The gain schedule against closed forms, identities and a brute-force reference."""

import numpy as np
import pytest
from nhstab.control import StabilizerOptions, compute_schedule
from nhstab.errors import InputError, NotStabilizingWarning, PipelineError, SingularGramianError, TrajectoryError
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nominals import fwd_car_parking, heisenberg_line, hilare_sinusoid
from reference import reference_H, transition, window_gramian


def heisenberg_line_H(t, alpha, delta, weight=6.0):
    """Closed form of H_c(t, t+delta) on x0 = (0, t, 0), u0 = (0, 1) (docs/theory/control-law.md, conventions).

    A = 0, Phi = I, B(tau) = [[1,0],[0,1],[tau,0]]; with c = w alpha and s = tau - t:
    I_k = int_0^delta s^k exp(-c s) ds, H11 = H22 = I0, H13 = t I0 + I1, H33 = t^2 I0 + 2 t I1 + I2,
    det H = I0 (I0 I2 - I1^2), independent of t.
    """
    c = weight * alpha
    E = np.exp(-c * delta)
    I0 = (1 - E) / c
    I1 = (1 - E * (1 + c * delta)) / c**2
    I2 = (2 - E * (c**2 * delta**2 + 2 * c * delta + 2)) / c**3
    t = np.asarray(t, dtype=float)
    H = np.zeros(t.shape + (3, 3))
    H[..., 0, 0] = H[..., 1, 1] = I0
    H[..., 0, 2] = H[..., 2, 0] = t * I0 + I1
    H[..., 2, 2] = t**2 * I0 + 2 * t * I1 + I2
    return H, I0 * (I0 * I2 - I1**2)


def rel(a, b):
    return np.linalg.norm(a - b, axis=(-2, -1)) / np.linalg.norm(b, axis=(-2, -1))


@pytest.mark.parametrize("alpha,delta", [(1.0, 1.0), (0.3, 0.7), (2.0, 1.37)])
def test_heisenberg_line_closed_form(alpha, delta):
    nom = heisenberg_line(10.0, hz=200.0)
    s = compute_schedule(nom, StabilizerOptions(alpha=alpha, delta=delta))
    interior = s.t <= 10.0 - delta
    Hc, det = heisenberg_line_H(s.t[interior], alpha, delta)
    # tolerance 1e-8 relative (measured ~1e-12): entrywise on the nonzero entries, and in norm
    assert rel(s.H[interior], Hc).max() < 1e-8
    nz = np.abs(Hc) > 0
    assert np.max(np.abs(s.H[interior][nz] - Hc[nz]) / np.abs(Hc[nz])) < 1e-8
    assert np.max(np.abs(s.H[interior][~nz])) < 1e-12
    # det H_c(t, t + delta) is the same at every t and equals the closed form
    dets = np.linalg.det(s.H[interior])
    assert np.max(np.abs(dets / det - 1)) < 1e-8


@pytest.mark.parametrize("alpha,delta", [(1.0, 1.0), (0.3, 0.7)])
def test_extend_end_is_the_closed_form_on_the_whole_line(alpha, delta):
    """end_strategy="extend": the Heisenberg line continued under u0 = (0, 1) held is the same line, so
    every grid point's window, those that run off the end included, is the closed form's."""
    nom = heisenberg_line(5.0, hz=200.0)
    s = compute_schedule(nom, StabilizerOptions(alpha=alpha, delta=delta, end_strategy="extend"))
    assert s.diagnostics["end"].startswith("extend")
    Hc, _ = heisenberg_line_H(s.t, alpha, delta)
    assert rel(s.H, Hc).max() < 1e-8
    with pytest.warns(NotStabilizingWarning):
        p = compute_schedule(nom, StabilizerOptions(alpha=alpha, delta=delta, window="past", end_strategy="extend"))
    assert p.diagnostics["end"].startswith("extend")
    # the past window [t - delta, t] of the line is the future window of the line started delta earlier,
    # carried to t (Phi = I: A = 0); weights exp(w alpha (t - tau)) = exp(w alpha delta) exp(w alpha (t - delta - tau))
    Hp, _ = heisenberg_line_H(s.t - delta, alpha, delta)
    import math
    # carry H_c(t - delta, t) to t: Phi = I, weight shift exp(w alpha delta)
    assert rel(p.H, math.exp(6.0 * alpha * delta) * Hp).max() < 1e-8


def _car_nominal(segments, dt=0.05):
    """A rwd_car nominal driving ``segments`` (direction, steering, length) exactly (closed forms)."""
    from types import SimpleNamespace

    from nhstab.planning import TimingOptions
    from nhstab.planning.cars import exact_nominal

    path = SimpleNamespace(info={"segments": segments}, samples=np.zeros((2, 3)))
    return exact_nominal(make_model("rwd_car"), path, TimingOptions(dt=dt))[0]


def test_extend_end_equals_the_sliding_window_of_the_longer_run():
    """A car that reverses a straight run into its goal: with "extend" the schedule at every grid point
    equals the ordinary sliding future window of the same nominal with that run 10.5 m longer (built
    independently, in closed form, on the same grid), to 1e-10; and the largest gain stays that of the
    sliding part, where "frozen" lets it grow at the end (the parking suite's tight bays)."""
    pre = [(1, 0.0, 2.0), (1, 0.5, 2.0), (-1, -0.5, 2.0)]
    short = _car_nominal(pre + [(-1, 0.0, 3.0)])
    longer = _car_nominal(pre + [(-1, 0.0, 3.0 + 10.5)])
    h = short.t[1] - short.t[0]
    grid = h * np.arange(len(short.t) + 200)
    longer = Nominal.from_functions(short.model, longer._x_func, longer._u_func, grid)
    opts = StabilizerOptions(alpha=0.1, delta=6.0)
    ext = compute_schedule(short, opts, end_strategy="extend")
    ref = compute_schedule(longer, opts)
    N = len(short.t)
    assert ref.diagnostics["sliding_window_until_s"] >= short.t[-1]
    assert rel(ext.H, ref.H[:N]).max() < 1e-10
    assert rel(ext.P, ref.P[:N]).max() < 1e-8
    frozen = compute_schedule(short, opts)
    sliding = frozen.t <= frozen.diagnostics["sliding_window_until_s"]
    g_frozen = np.linalg.norm(frozen.K, ord=2, axis=(1, 2))
    g_ext = np.linalg.norm(ext.K, ord=2, axis=(1, 2))
    assert np.allclose(g_ext[sliding], g_frozen[sliding], rtol=1e-9)
    assert g_ext.max() <= 1.2 * g_frozen[sliding].max() and g_frozen.max() > 3 * g_frozen[sliding].max()


def test_extend_drives_on_under_the_last_real_move_where_the_robot_ends_at_rest():
    """A car that ends steering in place (every car nominal that ends on an arc steers its wheels
    straight at the end, and the input held there would steer past max_steer): "extend" continues
    under its last real move, the reverse at full speed, with the steering rate zeroed, i.e. along the
    straight it ends on. Every window then equals, to 1e-10, the sliding future window of the same
    nominal with a reverse straight appended in closed form. The frozen end it replaces
    carries the window of T - delta along the flow, which counts the control already spent before t:
    over the last window its gain fell to a fraction of the sliding part's (on the parking suite the
    tracking error then grew in the last reverse arc until the car touched the curb or missed the goal)."""
    opts = StabilizerOptions(alpha=0.1, delta=6.0)
    segments = [(1, 0.0, 2.0), (1, 0.5, 4.0), (-1, -0.5, 3.0)]
    steering = _car_nominal(segments)                                  # ends steering back to 0 in place
    assert abs(steering.u[-1, 0]) < 1e-12 and abs(steering.u[-1, 1]) > 0
    s = compute_schedule(steering, opts, end_strategy="extend")
    assert "last real move" in s.diagnostics["end"] and "steers in place" in s.diagnostics["end"]
    # the reference: the same nominal, then the reverse straight in closed form (wheels straight, the
    # arc's speed), on the same grid
    T, xT = steering.t[-1], steering.x[-1]
    v = steering.u[np.flatnonzero(np.abs(steering.u[:, 0]) > 0)[-1], 0]
    assert abs(xT[3]) < 1e-12 and v < 0

    def x_func(tau):
        tau = np.asarray(tau, dtype=float)
        d = v * np.maximum(tau - T, 0.0)[..., None]
        straight = xT + d * np.array([np.cos(xT[2]), np.sin(xT[2]), 0.0, 0.0])
        return np.where((tau <= T)[..., None], steering._x_func(np.minimum(tau, T)), straight)

    def u_func(tau):
        tau = np.asarray(tau, dtype=float)
        return np.where((tau <= T)[..., None], steering._u_func(np.minimum(tau, T)), np.array([v, 0.0]))

    h = steering.t[1] - steering.t[0]
    grid = h * np.arange(len(steering.t) + 200)
    ref = compute_schedule(Nominal.from_functions(steering.model, x_func, u_func, grid), opts)
    N = len(steering.t)
    assert ref.diagnostics["sliding_window_until_s"] >= steering.t[-1]
    assert rel(s.H, ref.H[:N]).max() < 1e-10
    frozen = compute_schedule(steering, opts)
    assert frozen.diagnostics["end"] == "frozen"
    sliding = frozen.t <= frozen.diagnostics["sliding_window_until_s"]
    g_frozen = np.linalg.norm(frozen.K, ord=2, axis=(1, 2))
    g_ext = np.linalg.norm(s.K, ord=2, axis=(1, 2))
    moving_end = (~sliding) & (np.abs(steering.u[:, 0]) > 0)           # the end region while the car drives
    # the frozen end's gain falls to under a quarter of the continued window's while the car still drives
    # (0.14 here), where the extended schedule's stays within the sliding part's range
    assert (g_frozen[moving_end] / g_ext[moving_end]).min() < 0.25
    assert g_ext.max() <= 1.2 * g_frozen[sliding].max()


def test_extend_continues_a_robot_that_ends_standing_still_and_refuses_one_that_never_moves():
    """A unicycle that drives, turns and ends at rest (last input zero) continues under its last real
    move; a car that only steers in place never moves, so there is nothing to continue (the frozen
    end, and the schedule would be singular anyway)."""
    from nhstab.control.gramian import _held_inputs

    t = np.linspace(0.0, 2 * np.pi, 252)          # the unicycle drives and turns, and ends at rest
    still = Nominal.from_inputs(make_model("unicycle"), lambda s: np.stack([np.sin(s), 1 - np.cos(s)], -1),
                                np.zeros(3), t)
    assert np.allclose(still.u[-1], 0.0, atol=1e-12)
    s = compute_schedule(still, StabilizerOptions(alpha=0.1, delta=1.0, end_strategy="extend"))
    assert "last real move" in s.diagnostics["end"] and "stands still" in s.diagnostics["end"]
    (u, _), = _held_inputs(still, True)
    speed = np.linalg.norm(still.model.rhs(still.x, still.u), axis=1)
    assert np.linalg.norm(still.model.rhs(still.x[-1], u)) >= 0.5 * speed.max() - 1e-12
    car = make_model("rwd_car")
    tt = np.linspace(0.0, 1.0, 51)
    in_place = Nominal.from_inputs(car, lambda s: np.stack([0 * s, 0.3 + 0 * s], -1), np.zeros(4), tt)
    why = _held_inputs(in_place, True)
    assert isinstance(why, str) and why.startswith("frozen") and "never moves" in why


def test_long_trajectory_keeps_accuracy():
    """2000 s Heisenberg line: H33 ~ t^2 ~ 4e6, nothing re-anchored by hand; still 1e-8 relative.
    (Its H has condition number ~t^4, past what double precision can invert meaningfully, so this
    test checks H and switches the singularity check off.)"""
    nom = heisenberg_line(2000.0, hz=20.0)
    s = compute_schedule(nom, StabilizerOptions(alpha=1.0, delta=1.0, singular_rtol=1e-300))
    interior = s.t <= 1999.0
    Hc, det = heisenberg_line_H(s.t[interior], 1.0, 1.0)
    assert rel(s.H[interior], Hc).max() < 1e-8
    late = s.t[interior] > 1900
    assert np.max(np.abs(np.linalg.det(s.H[interior][late]) / det - 1)) < 1e-6   # det of a matrix with entries ~4e6
    assert np.all(np.isfinite(s.K)) and np.all(np.isfinite(s.P))


def test_circle_gramian_spectrum_is_time_invariant_over_1200_s():
    """On the circle u0 = (1, 1) the linearisation is the same in the body frame at every t, so the
    eigenvalues of H_c(t, t+delta) are constant: a check at t = 0 and t ~ 1200 s."""
    model = make_model("unicycle")
    T = 1201.0
    t = np.linspace(0.0, T, int(T * 50) + 1)
    nom = Nominal.from_functions(model, lambda s: np.stack([np.sin(s), 1 - np.cos(s), s], -1),
                                 lambda s: np.stack([1 + 0 * s, 1 + 0 * s], -1), t)
    s = compute_schedule(nom, StabilizerOptions(alpha=0.1, delta=1.0))
    interior = s.t <= T - 1.0
    lam = s.H_eigenvalues[interior]
    assert np.max(np.abs(lam / lam[0] - 1)) < 1e-9
    # and against the brute-force reference at a late time
    k = int(np.flatnonzero(interior)[-1]) - 7
    H_ref = window_gramian(nom, s.t[k], s.t[k], s.t[k] + 1.0, 0.6)
    assert rel(s.H[k], H_ref) < 1e-9


def _fd(P, h):
    """4th-order central difference of P along axis 0, for interior indices 2..N-3."""
    return (-P[4:] + 8 * P[3:-1] - 8 * P[1:-3] + P[:-4]) / (12 * h)


def _lyap_terms(nom, s, idx, cw):
    A, B = nom.model.linearize(nom.x[idx], nom.u[idx])
    P = s.P[idx]
    return P, A, B, -cw * P - P @ A - np.swapaxes(A, -1, -2) @ P


def test_corrected_dPc_identity_hilare_sinusoid():
    """The weighted Riccati equation (docs/theory/control-law.md, weighting): dP_c/dt = -6a P - P A - A^T P + P [B B^T - e^{-6 a d} Phi B_d B_d^T Phi^T] P,
    with Phi = Phi(t, t+delta), B_d = B(t+delta); against finite differences of P_c (rel < 1e-5)."""
    alpha, delta = 0.1, 1.0
    nom = hilare_sinusoid(2 * np.pi + delta, hz=1000.0)
    s = compute_schedule(nom, StabilizerOptions(alpha=alpha, delta=delta))
    h = s.h
    dP = _fd(s.P, h)
    cw = 6 * alpha
    worst_corrected, worst_printed = 0.0, np.inf
    last = int(np.flatnonzero(s.t <= s.t[-1] - delta)[-1])
    for i in np.linspace(3, last - 3, 15).astype(int):
        P, A, B, lin = _lyap_terms(nom, s, i, cw)
        t_end = s.t[i] + delta
        Phi = transition(nom, s.t[i], t_end)                # Phi(t, t + delta), independent
        Bd = nom.model.g(nom.at(t_end)[0])
        BB = Phi @ Bd @ Bd.T @ Phi.T
        corrected = lin + P @ (B @ B.T - np.exp(-cw * delta) * BB) @ P
        printed = lin + P @ (B @ B.T - np.exp(-4 * alpha * delta) * BB) @ P   # the paper's exp(-4 alpha delta)
        worst_corrected = max(worst_corrected, rel(dP[i - 2], corrected))
        worst_printed = min(worst_printed, rel(dP[i - 2], printed))
    assert worst_corrected < 1e-5
    assert worst_printed > 1e-3     # the printed constant is visibly wrong


def test_past_window_identity_and_frozen_end_identity():
    """Past window: dP_r/dt = -6a P - PA - A^T P - P [B B^T - e^{6 a d} Phi(t,t-d) B B^T Phi^T] P.
    Frozen end (H(s) carried along the flow past s = T - delta): dP/dt = -PA - A^T P exactly."""
    alpha, delta = 0.1, 1.0
    nom = hilare_sinusoid(2 * np.pi, hz=1000.0)
    cw = 6 * alpha
    with pytest.warns(NotStabilizingWarning):
        past = compute_schedule(nom, StabilizerOptions(alpha=alpha, delta=delta, window="past"))
    dP = _fd(past.P, past.h)
    first = int(np.flatnonzero(past.t >= delta)[0])
    for i in np.linspace(first + 3, len(nom.t) - 4, 8).astype(int):
        P, A, B, lin = _lyap_terms(nom, past, i, cw)
        t_start = nom.t[i] - delta
        Phi = transition(nom, nom.t[i], t_start)
        Bd = nom.model.g(nom.at(t_start)[0])
        expected = lin - P @ (B @ B.T - np.exp(cw * delta) * Phi @ Bd @ Bd.T @ Phi.T) @ P
        assert rel(dP[i - 2], expected) < 1e-5
    fut = compute_schedule(nom, StabilizerOptions(alpha=alpha, delta=delta))
    dP = _fd(fut.P, fut.h)
    boundary = int(np.flatnonzero(fut.t <= fut.t[-1] - delta)[-1])
    for i in np.linspace(boundary + 4, len(nom.t) - 4, 6).astype(int):
        P, A, B, lin = _lyap_terms(nom, fut, i, 0.0)
        assert rel(dP[i - 2], lin) < 1e-5


@pytest.mark.slow
@pytest.mark.parametrize("make", [hilare_sinusoid, fwd_car_parking], ids=["unicycle", "fwd_car"])
def test_fast_schedule_matches_brute_force_on_whole_grid(make):
    nom = make(2 * np.pi, hz=40.0)             # 252 points, the reference integrates each window
    opts = StabilizerOptions(alpha=0.1, delta=1.0)
    s = compute_schedule(nom, opts)
    P_ref = np.linalg.inv(reference_H(nom, s.t, opts))
    assert rel(s.P, P_ref).max() < 1e-6


def test_past_window_matches_brute_force():
    nom = fwd_car_parking(2 * np.pi, hz=100.0)
    opts = StabilizerOptions(alpha=0.1, delta=1.0, window="past")
    with pytest.warns(NotStabilizingWarning):
        s = compute_schedule(nom, opts)
    idx = np.r_[0:len(s.t):29, len(s.t) - 1, 99, 100, 101, len(s.t) - 101]
    P_ref = np.linalg.inv(reference_H(nom, s.t[idx], opts))
    assert rel(s.P[idx], P_ref).max() < 1e-6


def test_grid_not_commensurate_with_delta():
    """delta / h not an integer: the window's fractional last piece is integrated too."""
    nom = hilare_sinusoid(2 * np.pi, hz=37.3)
    opts = StabilizerOptions(alpha=0.2, delta=0.8137)
    s = compute_schedule(nom, opts)
    assert s.diagnostics["window_fraction_s"] > 0
    idx = np.r_[0:len(s.t):11, len(s.t) - 1]
    assert rel(s.P[idx], np.linalg.inv(reference_H(nom, s.t[idx], opts))).max() < 1e-6


def test_end_of_trajectory_gains_finite_and_bounded():
    end = "frozen"
    nom = hilare_sinusoid(2 * np.pi, hz=500.0)
    s = compute_schedule(nom, StabilizerOptions(alpha=0.1, delta=1.0, end_strategy=end))
    assert np.all(np.isfinite(s.K))
    interior = s.t <= s.t[-1] - 1.0
    norms = np.linalg.norm(s.K, ord=2, axis=(1, 2))
    # the end region's gains stay within a small factor of the interior's
    assert norms[~interior].max() < 3 * norms[interior].max()
    if end == "frozen":
        # continuous where the window stops sliding: the step there is like any other step
        k = int(np.flatnonzero(interior)[-1])
        steps = np.linalg.norm(np.diff(s.P, axis=0), axis=(1, 2))
        assert steps[k] < 3 * np.median(steps[k - 20:k])


def test_point_trajectory_is_refused_with_time_and_rank():
    model = make_model("heisenberg")
    t = np.linspace(0, 8, 801)
    nom = Nominal.from_samples(model, t, np.zeros((801, 3)), np.zeros((801, 2)))
    with pytest.raises(SingularGramianError) as exc:
        compute_schedule(nom, StabilizerOptions(alpha=1.0, delta=1.0))
    assert exc.value.rank == 2 and exc.value.n == 3
    assert exc.value.time == 0.0 and abs(exc.value.min_eigenvalue) < 1e-12
    assert "t = 0 s" in str(exc.value) and "rank 2 of 3" in str(exc.value)


def test_robot_that_stops_is_refused_at_the_stop():
    """A unicycle that drives, stops for 3 s (> delta), then drives: singular inside the stop."""
    model = make_model("unicycle")
    t = np.linspace(0, 10, 1001)
    v = np.where((t > 4) & (t < 7), 0.0, 1.0)
    x = np.stack([np.cumsum(v) * 0.01, 0 * t, 0 * t], -1)
    u = np.stack([v, 0 * t], -1)
    with pytest.raises(SingularGramianError) as exc:
        compute_schedule(Nominal.from_samples(model, t, x, u), StabilizerOptions(alpha=0.1, delta=1.0))
    assert 3.9 < exc.value.time < 7.0
    assert exc.value.rank < 3


@pytest.mark.parametrize("kwargs,argument", [
    ({"gamma": 0.49}, "gamma"), ({"gamma": float("nan")}, "gamma"), ({"gamma": lambda t: 0.4 + 0 * t}, "gamma"),
    ({"alpha": 0.0}, "alpha"), ({"alpha": -1.0}, "alpha"), ({"delta": 0.0}, "delta"), ({"delta": -2.0}, "delta"),
    ({"delta": 100.0}, "delta"), ({"window": "sideways"}, "window"), ({"end_strategy": "extrapolate"}, "end_strategy"),
    ({"alpha": "fast"}, "alpha"),
])
def test_bad_options_name_the_argument(kwargs, argument):
    nom = hilare_sinusoid(2 * np.pi, hz=50.0)
    with pytest.raises(InputError) as exc:
        compute_schedule(nom, StabilizerOptions(**kwargs))
    assert isinstance(exc.value, PipelineError) and isinstance(exc.value, ValueError)
    assert exc.value.argument == argument and f"'{argument}'" in str(exc.value)


def test_gamma_function_is_applied():
    nom = hilare_sinusoid(2 * np.pi, hz=50.0)
    s1 = compute_schedule(nom, StabilizerOptions())
    s2 = compute_schedule(nom, StabilizerOptions(gamma=lambda t: 1.0 + 0.5 * np.sin(t) ** 2))
    np.testing.assert_allclose(s2.K, (1.0 + 0.5 * np.sin(s1.t) ** 2)[:, None, None] * s1.K, rtol=1e-12)


@pytest.mark.parametrize("field,value,argument", [
    ("x", np.nan, "x"), ("u", np.inf, "u"), ("t", np.nan, "t"),
])
def test_non_finite_trajectory_refused(field, value, argument):
    model = make_model("unicycle")
    data = {"t": np.linspace(0, 5, 51), "x": np.zeros((51, 3)), "u": np.ones((51, 2))}
    data[field] = data[field].copy()
    data[field][17] = value
    with pytest.raises(TrajectoryError) as exc:
        Nominal.from_samples(model, data["t"], data["x"], data["u"])
    assert exc.value.argument == argument and "index" in str(exc.value)


def test_mismatched_shapes_refused():
    model = make_model("unicycle")
    t = np.linspace(0, 5, 51)
    with pytest.raises(TrajectoryError, match="'x' must be shape \\(51, 3\\)"):
        Nominal.from_samples(model, t, np.zeros((51, 4)), np.zeros((51, 2)))
    with pytest.raises(TrajectoryError, match="'u' must be shape"):
        Nominal.from_samples(model, t, np.zeros((51, 3)), np.zeros((50, 2)))
    with pytest.raises(TrajectoryError, match="'t' must be strictly increasing"):
        Nominal.from_samples(model, t[::-1], np.zeros((51, 3)), np.zeros((51, 2)))


# ---- the 3 alpha guarantee and the removed past-window uses (Remark 2) ------------------------

def test_rate_bound_is_3_alpha_and_the_printed_rate_is_reported_beside_it():
    nom = hilare_sinusoid(2 * np.pi + 1.0, hz=200.0)
    for alpha, weight in ((0.1, 6.0), (0.3, 6.0), (0.2, 4.0)):
        d = compute_schedule(nom, StabilizerOptions(alpha=alpha, delta=1.0, weight=weight)).diagnostics
        assert d["rate_bound"] == pytest.approx(0.5 * weight * alpha, rel=1e-15)
        assert d["rate_bound_printed"] == pytest.approx(2 * alpha * d["p_m"] / d["p_M"], rel=1e-12)
        assert d["rate_bound_printed"] < d["rate_bound"]
        assert "3 alpha" in d["guarantee"]


def test_certified_lyapunov_rate_of_the_future_window_is_at_least_6_alpha():
    """Item 8 checked numerically, independently of the identity's algebra: along the schedule,
    r = -lambda_max(P^-1/2 (A^T P + P A + dP/dt - 2 gamma P B B^T P) P^-1/2) >= 6 alpha while the window
    slides, and >= 0 (V non-increasing) in the frozen end, to the accuracy of the difference quotient of P
    (measured: 1.6e-4 relative at h = 2 ms; the tolerance is 1e-3)."""
    alpha, delta = 0.1, 1.0
    nom = hilare_sinusoid(2 * np.pi + delta, hz=500.0)
    for gamma in (0.5, 1.0, 3.0):
        s = compute_schedule(nom, StabilizerOptions(alpha=alpha, delta=delta, gamma=gamma))
        r = s.lyapunov_rates()
        sliding = s.t[1:] <= s.t[-1] - delta + 1e-9
        assert r[sliding].min() >= 6 * alpha * (1 - 1e-3)
        assert r[~sliding].min() >= -1e-3 * 6 * alpha


def test_error_bound_holds_along_the_closed_loop_and_is_refused_for_the_past_window():
    """The noiseless closed loop from small initial errors in random directions (the linear regime:
    ||e(0)|| ~ 1e-6) stays below the 3 alpha bound at every sample, and V exp(6 alpha t) does not grow
    (to 1e-4 per sample: K is linear between grid points, an O(h^2) departure from the law)."""
    from nhstab.simulation import simulate_tracking

    nom = hilare_sinusoid(2 * np.pi + 1.0, hz=500.0)
    s = compute_schedule(nom, StabilizerOptions(alpha=0.1, delta=1.0))
    rng = np.random.default_rng(17)
    for e0 in 1e-6 * rng.standard_normal((2, 3)):
        run = simulate_tracking(s, nom.x[0] + e0, 2 * np.pi, rtol=1e-7, atol=1e-20, n_out=800)
        bound = s.error_bound(e0, run.t)
        assert np.all(run.error_norm <= bound * (1 + 1e-6))
        V = np.einsum("ti,tij,tj->t", run.e, s.P_at(run.t), run.e)
        W = V * np.exp(0.6 * run.t)                 # V exp(6 alpha t)
        assert np.all(np.diff(W) <= 1e-4 * W[:-1])
    with pytest.warns(NotStabilizingWarning):
        past = compute_schedule(nom, StabilizerOptions(alpha=0.1, delta=1.0, window="past"))
    assert past.diagnostics["rate_bound"] is None and past.diagnostics["rate_bound_printed"] is None
    with pytest.raises(InputError, match="no guarantee"):
        past.error_bound(np.ones(3), np.array([1.0]))


def test_the_past_window_warns_and_its_lyapunov_function_grows_on_a_line():
    model = make_model("unicycle")
    t = np.linspace(0.0, 6.0, 601)
    nom = Nominal.from_functions(model, lambda s: np.stack([s, 0 * s, 0 * s], -1),
                                 lambda s: np.stack([1 + 0 * s, 0 * s], -1), t)
    with pytest.warns(NotStabilizingWarning, match="not stabilizing in general"):
        s = compute_schedule(nom, StabilizerOptions(alpha=0.1, delta=1.0, window="past"))
    whole = s.t[:-1] >= 1.0
    assert s.lyapunov_rates()[whole].max() < 0       # V = e^T P_r e grows in some direction everywhere


def test_the_switch_end_strategy_is_refused_with_the_reason():
    with pytest.raises(InputError) as err:
        StabilizerOptions(end_strategy="switch").validated()
    assert "'end_strategy'" in str(err.value) and "not stabilizing" in str(err.value)
