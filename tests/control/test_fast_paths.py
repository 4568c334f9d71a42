"""The faster paths (a replan within 0.5 s) give the answers of the plain computations they
replace: the exact car nominal evaluated at many times at once equals its pieces' own closed forms bit
for bit; the gain schedule's largest gain norm is the largest SVD norm; the gramian pieces do not depend
on how many intervals are integrated at once."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from nhstab.control import elements
from nhstab.control.gramian import StabilizerOptions, _largest_norm, compute_schedule
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nhstab.planning import TimingOptions
from nhstab.planning.cars import exact_nominal


def _pieces_at(joined, t):
    """The reference: every time evaluated by its own piece's states_at / inputs_at, one piece at a time
    (what the table evaluation replaces)."""
    j = np.clip(np.searchsorted(joined.starts, t, side="right") - 1, 0, len(joined.pieces) - 1)
    local = np.clip(t - joined.starts[j], 0.0, joined.lengths[j])
    x = np.empty((len(t), joined.model.n))
    u = np.empty((len(t), joined.model.m))
    for q in np.unique(j):
        k = np.flatnonzero(j == q)
        x[k] = joined.pieces[q].states_at(local[k])
        u[k] = joined.pieces[q].inputs_at(local[k])
    return x, u


segment = st.tuples(st.sampled_from([1, -1]), st.sampled_from([0.0, 0.3, -0.3, 0.55, -0.55, 1e-13]),
                    st.floats(0.01, 8.0))


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(["rwd_car", "fwd_car"]), st.lists(segment, min_size=1, max_size=8),
       st.floats(-math.pi, math.pi), st.integers(0, 2**31 - 1))
def test_table_evaluation_equals_the_pieces_closed_forms(name, segs, heading, seed):
    model = make_model(name)
    start = np.array([3.0, -2.0, heading])
    path = SimpleNamespace(info={"segments": segs}, samples=np.array([start, start]))
    nominal, _ = exact_nominal(model, path, TimingOptions(dt=0.02))
    joined = nominal._x_func.__self__
    rng = np.random.default_rng(seed)
    t = np.concatenate([nominal.t, rng.uniform(-0.1, nominal.duration + 0.1, 500), joined.starts])
    x_ref, u_ref = _pieces_at(joined, t)
    assert np.array_equal(joined.states(t), x_ref)
    assert np.array_equal(joined.inputs(t), u_ref)
    assert np.array_equal(nominal.x, _pieces_at(joined, nominal.t)[0])


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 300), st.sampled_from([(2, 4), (2, 3), (3, 3), (1, 4)]), st.integers(0, 2**31 - 1),
       st.booleans())
def test_largest_norm_is_the_svd_argmax(count, shape, seed, ties):
    rng = np.random.default_rng(seed)
    K = rng.standard_normal((count,) + shape) * rng.uniform(0.1, 10.0, (count, 1, 1))
    if ties and count > 2:
        K[count // 2] = K[-1] = K[0] * 3.0            # the largest, three times: the first one counts
    norms = np.linalg.norm(K, ord=2, axis=(1, 2))
    k, value = _largest_norm(K)
    assert k == int(np.argmax(norms)) and value == float(norms.max())


def test_gramian_pieces_do_not_depend_on_the_chunk(monkeypatch):
    model = make_model("rwd_car")
    t = np.linspace(0.0, 30.0, 1501)

    def xf(tt):
        tt = np.asarray(tt, dtype=float)
        return np.stack([30 * np.cos(0.05 * tt), 30 * np.sin(0.05 * tt), 0.05 * tt + np.pi / 2,
                         0.3 * np.sin(0.2 * tt)], axis=-1)

    def uf(tt):
        tt = np.asarray(tt, dtype=float)
        return np.stack([1.5 * np.ones_like(tt), 0.06 * np.cos(0.2 * tt)], axis=-1)

    nom = Nominal.from_functions(model, xf, uf, t)
    opts = StabilizerOptions(alpha=0.1, delta=6.0)
    ref = compute_schedule(nom, opts)
    for chunk in (1, 7, 100000):
        monkeypatch.setattr(elements, "CHUNK", chunk)
        other = compute_schedule(nom, opts)
        assert np.array_equal(other.K, ref.K) and np.array_equal(other.H, ref.H)



def _rates_reference(s):
    """GainSchedule.lyapunov_rates as first written: everything recomputed at both ends of every
    interval, dP/dt added inside the product."""
    nom = s.nominal
    A, B = nom.model.linearize(nom.x, nom.u)
    dP = np.diff(s.P, axis=0) / s.h

    def rate(idx):
        P, Ak, Bk = s.P[idx], A[idx], B[idx]
        PB = P @ Bk
        M = np.swapaxes(Ak, -1, -2) @ P + P @ Ak + dP - 2.0 * s.gamma[idx, None, None] * (PB @ np.swapaxes(PB, -1, -2))
        Li = np.linalg.inv(np.linalg.cholesky(P))
        S = Li @ M @ np.swapaxes(Li, -1, -2)
        return -np.linalg.eigvalsh(0.5 * (S + np.swapaxes(S, -1, -2)))[:, -1]

    k = np.arange(len(s.t) - 1)
    return 0.5 * (rate(k) + rate(k + 1))


@pytest.mark.parametrize("window", ["future", "frozen-time"])
def test_lyapunov_rates_equal_the_plain_computation(window):
    """The rates computed once per grid point equal the per-interval computation to rounding (1e-9 of
    the largest |r|; the two orders of the same sums)."""
    model = make_model("rwd_car")
    t = np.linspace(0.0, 20.0, 1001)

    def xf(tt):
        tt = np.asarray(tt, dtype=float)
        return np.stack([10 * np.cos(0.1 * tt), 10 * np.sin(0.1 * tt), 0.1 * tt + np.pi / 2,
                         0.3 * np.sin(0.2 * tt)], axis=-1)

    def uf(tt):
        tt = np.asarray(tt, dtype=float)
        return np.stack([1.0 * np.ones_like(tt), 0.06 * np.cos(0.2 * tt)], axis=-1)

    s = compute_schedule(Nominal.from_functions(model, xf, uf, t), StabilizerOptions(alpha=0.2, delta=3.0, window=window))
    ref = _rates_reference(s)
    got = s.lyapunov_rates()
    assert got.shape == ref.shape
    assert np.max(np.abs(got - ref)) <= 1e-9 * np.max(np.abs(ref))
