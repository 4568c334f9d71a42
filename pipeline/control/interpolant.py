"""The one interpolator of a gain schedule and its nominal on a uniform time grid.

On the grid t_k = t_0 + k h (k = 0..N-1), at fraction a in [0, 1] of interval k:

* x0: the cubic Hermite interpolant through the samples x_k with the model's own slopes
  x'_k = f(x_k) + g(x_k) u_k (4th-order accurate),
      x0 = h00(a) x_k + h10(a) h x'_k + h01(a) x_{k+1} + h11(a) h x'_{k+1},
      h00 = 2a^3 - 3a^2 + 1, h10 = a^3 - 2a^2 + a, h01 = 3a^2 - 2a^3, h11 = a^3 - a^2;
* u0: linear between the samples, or the nominal's own function when one is given (closed forms);
* K (and any other per-sample matrix, e.g. P): linear between the samples.

Times outside [t_0, t_{N-1}] are clamped to the span. The scalar methods (``locate``, ``state``,
``input``, ``gain``) are for the per-step control loop (plain Python arithmetic, no array
allocation for the index); the ``*_many`` methods evaluate arrays of times at once.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..errors import InputError


class GridInterpolant:
    """x0 (cubic Hermite), u0 (linear or a given function) and K (linear) on a uniform grid."""

    def __init__(self, t: np.ndarray, x: np.ndarray, xdot: np.ndarray, u: np.ndarray, K: np.ndarray,
                 u_func: Callable | None = None):
        self.t = np.asarray(t, dtype=float)
        if self.t.ndim != 1 or len(self.t) < 2 or not np.all(np.diff(self.t) > 0):
            raise InputError("t", "a strictly increasing grid of at least 2 times", f"shape {self.t.shape}")
        self.t0 = float(self.t[0])
        self.t_end = float(self.t[-1])
        self.h = float(self.t[1] - self.t[0])
        self.last = len(self.t) - 2
        self.x = x
        self.xd = xdot * self.h            # slopes scaled to the unit interval
        self.u = u
        self.K = K
        self.u_func = u_func

    # -- one time (the control loop) -------------------------------------------------------------
    def locate(self, tau: float) -> tuple[int, float]:
        """(k, a): the grid interval of ``tau`` (clamped to the span) and the fraction within it."""
        s = (min(max(float(tau), self.t0), self.t_end) - self.t0) / self.h
        k = min(int(s), self.last)
        return k, s - k

    def state(self, k: int, a: float) -> np.ndarray:
        a2 = a * a
        a3 = a2 * a
        return ((2 * a3 - 3 * a2 + 1) * self.x[k] + (a3 - 2 * a2 + a) * self.xd[k]
                + (3 * a2 - 2 * a3) * self.x[k + 1] + (a3 - a2) * self.xd[k + 1])

    def input(self, k: int, a: float) -> np.ndarray:
        if self.u_func is not None:
            return np.asarray(self.u_func(np.array([self.t0 + (k + a) * self.h])), dtype=float)[0]
        return (1.0 - a) * self.u[k] + a * self.u[k + 1]

    def gain(self, k: int, a: float) -> np.ndarray:
        return (1.0 - a) * self.K[k] + a * self.K[k + 1]

    def __call__(self, tau: float):
        """(x0(tau), u0(tau), K(tau))."""
        k, a = self.locate(tau)
        return self.state(k, a), self.input(k, a), self.gain(k, a)

    # -- many times ------------------------------------------------------------------------------
    def locate_many(self, tau) -> tuple[np.ndarray, np.ndarray]:
        s = np.clip((np.asarray(tau, dtype=float) - self.t0) / self.h, 0.0, self.last + 1.0)
        k = np.minimum(np.floor(s).astype(int), self.last)
        return k, s - k

    def linear_many(self, values: np.ndarray, tau) -> np.ndarray:
        """Any per-sample array ``values`` (N, ...) linearly interpolated at times ``tau``: (..., ...)."""
        k, a = self.locate_many(tau)
        a = a.reshape(a.shape + (1,) * (values.ndim - 1))
        return (1.0 - a) * values[k] + a * values[k + 1]

    def gain_many(self, tau) -> np.ndarray:
        return self.linear_many(self.K, tau)

    def state_many(self, tau) -> np.ndarray:
        k, a = self.locate_many(tau)
        h00, h10, h01, h11 = hermite_weights(a[..., None])
        return h00 * self.x[k] + h10 * self.xd[k] + h01 * self.x[k + 1] + h11 * self.xd[k + 1]


def hermite_weights(a):
    """The cubic Hermite basis (h00, h10, h01, h11) at fractions ``a`` of an interval (the module
    docstring's), for arrays: :meth:`GridInterpolant.state_many` and the tube's sample schedule."""
    a2 = a * a
    a3 = a2 * a
    return 2 * a3 - 3 * a2 + 1, a3 - 2 * a2 + a, 3 * a2 - 2 * a3, a3 - a2
