"""The causal frozen-time law (nhstab.control.frozen): closed forms, the hold, where it fails."""

from __future__ import annotations

import numpy as np
import pytest
from nhstab.control import StabilizerOptions, compute_schedule
from nhstab.control.frozen import frozen_gramians
from nhstab.errors import InputError, SingularGramianError
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nhstab.paper import remark2_eigenvalues
from nhstab.simulation import simulate_tracking
from nominals import heisenberg_line, hilare_sinusoid
from scipy.linalg import expm


def _van_loan(A, B, c, delta):
    """Independent: int_0^delta exp(-c s) e^{-A s} B B^T e^{-A^T s} ds from one matrix exponential
    (Van Loan 1978): with At = A + c/2 I, expm([[At, B B^T], [0, -At^T]] delta) = [[*, G], [0, F]] and
    the integral is F^T G."""
    n = A.shape[0]
    At = A + 0.5 * c * np.eye(n)
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:], M[n:, n:] = At, B @ B.T, -At.T
    E = expm(M * delta)
    return E[n:, n:].T @ E[:n, n:]


class _Frozen:
    """A stand-in nominal whose linearisation at every sample is a given pair (A_k, B_k)."""

    def __init__(self, A, B):
        self.A, self.B = A, B
        self.x = np.zeros((len(A), 1))
        self.u = np.zeros((len(A), 1))
        outer = self

        class M:
            def linearize(self, x, u):
                return outer.A, outer.B

        self.model = M()


@pytest.mark.parametrize("c,delta", [(0.6, 1.0), (1.2, 2.0), (0.3, 6.0)])
def test_frozen_gramian_matches_van_loan(rng, c, delta):
    """Random pairs, general and nilpotent like the robots' (speeds up to 1.5 m/s): 1e-10 relative."""
    K = 12
    A = rng.standard_normal((K, 4, 4)) * 0.5
    A[6:] = np.triu(A[6:], 1) * 3.0
    B = rng.standard_normal((K, 4, 2))
    W = frozen_gramians(_Frozen(A, B), c, delta)
    for k in range(K):
        ref = _van_loan(A[k], B[k], c, delta)
        assert np.abs(W[k] - ref).max() <= 1e-10 * np.abs(ref).max()


def _line(v=1.0, T=8.0, hz=100.0):
    model = make_model("unicycle")
    t = np.linspace(0.0, T, int(T * hz) + 1)
    return Nominal.from_functions(model, lambda s: np.stack([v * s, 0 * s, 0 * s], -1),
                                  lambda s: np.stack([v + 0 * s, 0 * s], -1), t)


@pytest.mark.parametrize("v", [1.0, -0.5])
def test_on_a_straight_line_it_is_proposition_1(v):
    """Time-invariant nominal: the frozen-time P equals the future window's wherever that window is
    whole, and the closed loop has the closed-form eigenvalues of the double integrator."""
    nom = _line(v)
    opts = dict(alpha=0.2, delta=2.0, gamma=1.0)
    fut = compute_schedule(nom, StabilizerOptions(**opts))
    fro = compute_schedule(nom, StabilizerOptions(**opts, window="frozen-time"))
    whole = fut.t <= fut.t[-1] - 2.0
    assert np.abs(fro.P[whole] - fut.P[whole]).max() <= 1e-9 * np.abs(fut.P).max()
    assert fro.diagnostics["frozen_time"]["hold_intervals_s"] == []
    A, B = nom.model.linearize(nom.x[0], nom.u[0])
    ev = np.linalg.eigvals(A - B @ fro.K[0])
    ref = remark2_eigenvalues(0.2, 2.0, 1.0, "frozen-time", v=v)
    assert np.allclose(np.sort_complex(ev), np.sort_complex(ref), atol=1e-8)
    # the certified rate on an LTI nominal is the full 6 alpha everywhere (no end region)
    assert fro.lyapunov_rates().min() >= 6 * 0.2 * (1 - 1e-6)


def _stop_and_go(hz=50.0):
    """A unicycle on a line: from rest, accelerate at 0.5 m/s^2 to 0.8 m/s, cruise, brake to rest,
    and turn a little on the way (a piecewise-linear u0, as the planner makes)."""
    model = make_model("unicycle")
    T = 12.0
    t = np.linspace(0.0, T, int(T * hz) + 1)

    def u(s):
        s = np.asarray(s, dtype=float)
        v = np.clip(np.minimum(0.5 * s, 0.5 * (T - s)), 0.0, 0.8)
        return np.stack([v, 0.1 * np.sin(0.5 * s)], -1)

    return Nominal.from_inputs(model, u, np.zeros(3), t)


def test_holds_at_the_start_and_the_stop_with_the_documented_properties():
    nom = _stop_and_go(hz=200.0)
    s = compute_schedule(nom, StabilizerOptions(alpha=0.2, delta=2.0, window="frozen-time"))
    ft = s.diagnostics["frozen_time"]
    holds = ft["hold_intervals_s"]
    # from rest: held from t = 0 (the look-ahead, at most until the nominal is up to speed at 1.6 s);
    # braking to rest: held to the end
    assert holds[0][0] == 0.0 and ft["lookahead_s"] == pytest.approx(holds[0][1] + s.h)
    assert ft["lookahead_s"] <= 1.6
    assert holds[-1][1] == pytest.approx(s.t[-1])
    assert np.all(np.isfinite(s.K)) and s.diagnostics["max_gain_norm"] < 200
    # inside a hold H is carried along the flow: dP/dt = -P A - A^T P (central differences, 1e-4)
    A, _ = nom.model.linearize(nom.x, nom.u)
    a, b = holds[-1]
    idx = np.flatnonzero((s.t > a + 3 * s.h) & (s.t < b - 3 * s.h))
    dP = (s.P[idx + 1] - s.P[idx - 1]) / (2 * s.h)
    lin = -(s.P[idx] @ A[idx] + np.swapaxes(A[idx], 1, 2) @ s.P[idx])
    assert np.abs(dP - lin).max() <= 1e-4 * np.abs(s.P[idx]).max()
    # ... and continuous where the hold begins (the step there is like its neighbours')
    k = int(np.searchsorted(s.t, a))
    steps = np.linalg.norm(np.diff(s.P, axis=0), axis=(1, 2))
    assert steps[k - 1] < 3 * np.median(steps[k - 40:k - 1])
    # the certified rate: 6 alpha on the cruise, about 0 (V non-increasing) in the final hold
    r = s.lyapunov_rates()
    cruise = (s.t[:-1] > 3.0) & (s.t[:-1] < 6.0)
    assert r[cruise].min() > 0
    assert r[idx].min() > -1e-3


def _cusp(hz=50.0):
    """A unicycle on a line: reverse from rest to -0.8 m/s and brake to rest at t = 6 s (a cusp), then
    forward to 0.8 m/s and brake to rest at t = 12 s (0.5 m/s^2 throughout)."""
    model = make_model("unicycle")
    T1, T = 6.0, 12.0
    t = np.linspace(0.0, T, int(T * hz) + 1)

    def u(s):
        s = np.asarray(s, dtype=float)
        back = -np.clip(np.minimum(0.5 * s, 0.5 * (T1 - s)), 0.0, 0.8)
        fwd = np.clip(np.minimum(0.5 * (s - T1), 0.5 * (T - s)), 0.0, 0.8)
        return np.stack([np.where(s < T1, back, fwd), 0.0 * s], -1)

    return Nominal.from_inputs(model, u, np.zeros(3), t), T1


def test_leaving_a_cusp_it_does_not_trade_heading_for_lateral_error():
    """Speeding up out of a cusp, the frozen pair of the low speed has a lateral gain ~ 1/v: resumed
    there (before the fix: gain norm 47 at 0.07 m/s, against 5.3 on the cruise) it turned the robot
    0.39 rad to remove 0.1 m of lateral error. The hold now lasts until the robot is up to speed and
    carries back the gramian of the motion it leads into: the gains leaving the cusp stay within 3 times
    the cruise's and the heading error within 1.5 rad per metre of lateral error (0.09 rad measured)."""
    nom, T1 = _cusp()
    s = compute_schedule(nom, StabilizerOptions(alpha=0.2, delta=2.0, window="frozen-time"))
    ft = s.diagnostics["frozen_time"]
    assert any(a < T1 < b for a, b in ft["hold_intervals_s"])
    norms = np.linalg.norm(s.K, ord=2, axis=(1, 2))
    leaving = (s.t > T1) & (s.t < T1 + 1.6)
    cruise = (s.t > T1 + 2.0) & (s.t < T1 + 3.0)
    assert norms[leaving].max() <= 3.0 * norms[cruise].max()
    # after the cusp the law steers like the forward motion's: the lateral gain on the turn rate has
    # the forward sign (omega = -K e: positive lateral error, negative turn) wherever it acts
    lateral_gain = s.K[:, 1, 1]
    assert np.all(lateral_gain[leaving] >= -1e-9) and lateral_gain[cruise].min() > 0
    ts = T1 - 1.0
    run = simulate_tracking(s, nom.at(ts)[0] + np.array([0.0, 0.1, 0.0]), t_start=ts, rtol=1e-8, atol=1e-12,
                            n_out=600)
    assert run.status == "completed"
    e = run.e
    after = (run.t > T1) & (run.t < T1 + 3.0)
    assert np.abs(e[after, 2]).max() <= 0.15
    assert np.linalg.norm(e[-1]) <= 1e-3


def test_it_converges_from_the_paper_error_on_a_stop_and_go_line():
    nom = _stop_and_go(hz=50.0)
    s = compute_schedule(nom, StabilizerOptions(alpha=0.2, delta=2.0, window="frozen-time"))
    e0 = np.array([-0.1, 0.2, 0.1])
    run = simulate_tracking(s, nom.x[0] + e0, rtol=1e-6, atol=1e-10, n_out=400)
    assert run.status == "completed"
    assert run.error_norm[-1] < 0.1 * run.error_norm[0]


def test_certified_bound_holds_on_the_hilare_circle():
    """The circle at constant speed: never held (the frame rotates, lambda_max(P) does not grow), and
    the certified bound from lyapunov_rates holds at every sample from a small initial error."""
    model = make_model("unicycle")
    t = np.linspace(0.0, 2 * np.pi + 1, int((2 * np.pi + 1) * 200) + 1)
    nom = Nominal.from_inputs(model, lambda s: np.ones((np.shape(s)[0], 2)), np.zeros(3), t)
    s = compute_schedule(nom, StabilizerOptions(alpha=0.1, delta=1.0, window="frozen-time"))
    assert s.diagnostics["frozen_time"]["hold_intervals_s"] == []
    e0 = 1e-6 * np.array([-0.1, 0.2, 0.1])
    run = simulate_tracking(s, nom.x[0] + e0, 2 * np.pi, rtol=1e-7, atol=1e-20, n_out=500)
    assert np.all(run.error_norm <= s.error_bound(e0, run.t) * (1 + 1e-6))
    assert run.error_norm[-1] < 1e-3 * run.error_norm[0]


def test_where_it_fails_it_says_so():
    # the Heisenberg line: A = 0 and rank B = 2 at every instant, so no frozen pair is controllable
    with pytest.raises(SingularGramianError, match="frozen-time"):
        compute_schedule(heisenberg_line(4.0, 100.0), StabilizerOptions(alpha=1.0, delta=1.0, window="frozen-time"))
    # a gain bound below what the law needs anywhere
    with pytest.raises(InputError) as err:
        compute_schedule(_line(), StabilizerOptions(alpha=0.2, delta=2.0, window="frozen-time", max_gain=0.5))
    assert "'max_gain'" in str(err.value)
    # the sinusoid's stops at t = 0, pi, 2 pi are held
    s = compute_schedule(hilare_sinusoid(2 * np.pi, 200.0),
                         StabilizerOptions(alpha=0.1, delta=1.0, window="frozen-time"))
    holds = s.diagnostics["frozen_time"]["hold_intervals_s"]
    assert any(a <= np.pi <= b for a, b in holds)


def test_a_frozen_time_law_runs_in_the_vectorised_engine_like_in_the_loop():
    """The law is K on the nominal's grid, so the shared-nominal engine takes it unchanged: its
    trials are bit-identical to the run loop's (the loop of tests/batch/test_batch_vector.py)."""
    from nhstab.batch.vector import simulate_shared
    from nhstab.bench import hilare_sinusoid as bench_sinusoid
    from nhstab.execution import ControllerOptions, build_law
    from nhstab.execution.config import NoiseOptions
    from test_batch_vector import _assert_trial_is, reference_loop

    law = build_law(bench_sinusoid(315), ControllerOptions(kind="gramian", window="frozen-time", alpha=0.1,
                                                           delta=1.0, gamma=1.0), {})
    assert law.schedule.options.window == "frozen-time"
    noise = NoiseOptions()
    res = simulate_shared(law, [0, 5], noise)
    for i, seed in enumerate([0, 5]):
        status, log = reference_loop(law, seed, noise)
        _assert_trial_is(res, i, status, log)
