"""The associative window aggregation against a naive left fold."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from nhstab.control.windows import Segments, combine, exclusive_prefix, scan, sliding


def _segments(K, n, seed):
    rng = np.random.default_rng(seed)
    P = np.eye(n) + 0.1 * rng.standard_normal((K, n, n))
    G = rng.standard_normal((K, n, n))
    return Segments(P, G @ np.swapaxes(G, -1, -2), rng.uniform(0.001, 0.05, K))


def _fold(seg, i, j, c):
    n = seg.n
    acc = Segments(np.eye(n), np.zeros((n, n)), np.array(0.0))
    for k in range(i, j):
        acc = combine(acc, seg[k], c)
    return acc


def _close(a, b, tol=1e-12):
    scale = max(np.abs(b.W).max(), 1e-300)
    return (np.abs(a.W - b.W).max() <= tol * scale and np.abs(a.P - b.P).max() <= tol * np.abs(b.P).max()
            and abs(float(a.d) - float(b.d)) <= 1e-12)


@settings(max_examples=40, deadline=None)
@given(K=st.integers(1, 400), frac=st.floats(0, 1), n=st.integers(1, 4), seed=st.integers(0, 2**31),
       c=st.sampled_from([-0.6, 0.0, 0.6]))
def test_sliding_equals_fold(K, frac, n, seed, c):
    seg = _segments(K, n, seed)
    m = int(round(frac * K))
    R = sliding(seg, m, c)
    assert R.shape == (K - m + 1,)
    for k in sorted({0, (K - m) // 2, K - m}):
        assert _close(R[k], _fold(seg, k, k + m, c))


@settings(max_examples=25, deadline=None)
@given(K=st.integers(1, 3000), seed=st.integers(0, 2**31))
def test_scans_equal_fold(K, seed):
    seg = _segments(K, 3, seed)
    fwd, rev = scan(seg, -0.5), scan(seg, -0.5, reverse=True)
    ex = exclusive_prefix(seg, -0.5)
    for j in sorted({0, K // 3, K - 1}):
        assert _close(fwd[j], _fold(seg, 0, j + 1, -0.5), 1e-11)
        assert _close(rev[j], _fold(seg, j, K, -0.5), 1e-11)
        assert _close(ex[j], _fold(seg, 0, j, -0.5), 1e-11)


def test_combination_is_associative():
    a, b, c_ = (_segments(5, 3, s) for s in (1, 2, 3))
    left = combine(combine(a, b, 0.4), c_, 0.4)
    right = combine(a, combine(b, c_, 0.4), 0.4)
    np.testing.assert_allclose(left.W, right.W, rtol=1e-13)
    np.testing.assert_allclose(left.P, right.P, rtol=1e-13)
