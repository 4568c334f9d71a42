"""Per-interval pieces of the gramian, integrated to high order.

For an interval [s, s + l] of the nominal, :func:`interval_segments` returns, anchored at s,

    P = Phi(s, s + l)                         (transition matrix, backwards across the interval)
    W = int_s^{s+l} exp(c (s - tau)) Phi(s, tau) B(tau) B(tau)^T Phi(s, tau)^T dtau

by integrating X(tau) = Phi(s, tau), X' = -X A(tau), X(s) = I, together with W' = exp(c (s - tau))
X B B^T X^T, with one fixed step (or a few substeps) of the 8th-order Dormand-Prince tableau (the
coefficients of scipy's DOP853), vectorised over all intervals at once. A and B come from the model's
Jacobians along the nominal, evaluated at the stage times.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import DOP853

from ..nominal import Nominal
from .windows import Segments, transposed

_A = np.asarray(DOP853.A, dtype=float)[: DOP853.n_stages, : DOP853.n_stages]
_B = np.asarray(DOP853.B, dtype=float)
_C = np.asarray(DOP853.C, dtype=float)[: DOP853.n_stages]
_STAGES = DOP853.n_stages
# the strictly lower triangle of the tableau, row by row: row i holds a_i0 .. a_i(i-1)
_A_LOWER = np.concatenate([_A[i, :i] for i in range(_STAGES)])
_PAIR_START = np.concatenate([[0], np.cumsum(np.arange(_STAGES))]).astype(int)
#: intervals integrated at once: bounds the memory of the stage arrays, and keeps them in the CPU's
#: cache (the twelve stages reuse them; 512 intervals of a 4-state model are about 1 MB). Every
#: interval is integrated on its own, so the result does not depend on the chunk.
CHUNK = 512


def interval_segments(nominal: Nominal, starts: np.ndarray, length: float | np.ndarray,
                      c: float, substeps: int = 1) -> Segments:
    """Start-anchored segments for the intervals [starts[k], starts[k] + length[k]]."""
    starts = np.asarray(starts, dtype=float)
    lengths = np.broadcast_to(np.asarray(length, dtype=float), starts.shape)
    n = nominal.model.n
    K = starts.shape[0]
    P = np.empty((K, n, n))
    W = np.empty((K, n, n))
    for lo in range(0, K, CHUNK):
        hi = min(K, lo + CHUNK)
        P[lo:hi], W[lo:hi] = _integrate(nominal, starts[lo:hi], lengths[lo:hi], c, substeps)
    return Segments(P, W, lengths.copy())


def _integrate(nominal: Nominal, s0: np.ndarray, lengths: np.ndarray, c: float, substeps: int):
    h = lengths / substeps
    # all stage times of all substeps, evaluated in one call to the model
    offsets = (np.arange(substeps)[:, None] + _C[None, :]).reshape(-1)          # (substeps * stages,)
    taus = s0[:, None] + h[:, None] * offsets[None, :]                            # (K, S)
    x0, u0 = nominal.at(taus)
    A_all, B_all = nominal.model.linearize(x0, u0)
    return _dop853(A_all, B_all, np.exp(c * (s0[:, None] - taus)), h, substeps)


def frozen_segments(A: np.ndarray, B: np.ndarray, length: float, c: float, substeps: int = 1) -> Segments:
    """Start-anchored segments of the *frozen* pairs (A[k], B[k]) held constant over [0, length]:
    P = exp(-A length), W = int_0^length exp(-c s) exp(-A s) B B^T exp(-A^T s) ds (same integrator)."""
    K = A.shape[0]
    lengths = np.full(K, float(length))
    S = substeps * _STAGES
    h = lengths / substeps
    offsets = (np.arange(substeps)[:, None] + _C[None, :]).reshape(-1)
    weights = np.exp(-c * h[:, None] * offsets[None, :])
    P, W = _dop853(np.broadcast_to(A[:, None], (K, S) + A.shape[1:]),
                   np.broadcast_to(B[:, None], (K, S) + B.shape[1:]), weights, h, substeps)
    return Segments(P, W, lengths)


def _dop853(A_all: np.ndarray, B_all: np.ndarray, weights: np.ndarray, h: np.ndarray, substeps: int):
    """X' = -X A, W' = weight X B B^T X^T from X = I, W = 0; A_all, B_all, weights at every stage time
    of every substep, shape (K, substeps * stages, ...)."""
    K, n = A_all.shape[0], A_all.shape[-1]
    X = np.broadcast_to(np.eye(n), (K, n, n)).copy()
    W = np.zeros((K, n, n))
    hA = h[:, None] * _A_LOWER[None, :]                                          # (K, pairs)
    kX = np.empty((_STAGES, K, n, n))
    for j in range(substeps):
        dW = np.zeros((K, n, n))
        for i in range(_STAGES):
            if i:
                # X_i = X + h sum_q a_iq k_q, all q at once
                coef = hA[:, _PAIR_START[i]:_PAIR_START[i] + i]                   # (K, i)
                Xi = X + np.einsum("kq,qkab->kab", coef, kX[:i])
            else:
                Xi = X
            col = j * _STAGES + i
            kX[i] = -(Xi @ A_all[:, col])
            if _B[i] != 0.0:
                XB = Xi @ B_all[:, col]
                dW += (_B[i] * weights[:, col])[:, None, None] * (XB @ transposed(XB))
        X = X + h[:, None, None] * np.tensordot(_B, kX, axes=1)
        W = W + h[:, None, None] * dW
    W = 0.5 * (W + np.swapaxes(W, -1, -2))
    return X, W


def to_end_anchored(seg: Segments, c: float) -> Segments:
    """Convert start-anchored segments (weight exp(c (s - tau))) into end-anchored ones:
    P = Phi(end, start) and W with weight exp(c (end - tau)). Used for past windows."""
    F = np.linalg.inv(seg.P)
    scale = np.exp(c * seg.d)[:, None, None]
    W = scale * (F @ seg.W @ transposed(F))
    return Segments(F, 0.5 * (W + np.swapaxes(W, -1, -2)), seg.d.copy())
