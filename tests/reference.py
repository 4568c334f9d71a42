"""Brute-force references for the gain schedule: one adaptive integration per grid point.

Independent of the library's window aggregation and of its fixed-step integrator: for each time t it
integrates X(tau) = Phi(t, tau) (X' = -X A(tau), X(t) = I) and the weighted gramian integrand with
scipy's adaptive DOP853 at tight tolerances, forwards to the window's end and backwards to its
start. Slow by design (this is what the fast schedule is measured against).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


def window_gramian(nominal, t: float, a: float, b: float, cw: float, rtol=1e-12, atol=1e-15):
    """int_a^b exp(cw (t - tau)) Phi(t, tau) B B^T Phi(t, tau)^T dtau, with a <= t <= b."""
    model = nominal.model
    n = model.n

    def rhs(tau, y):
        X = y[: n * n].reshape(n, n)
        x0, u0 = nominal.at(np.array([tau]))
        A, B = model.linearize(x0[0], u0[0])
        XB = X @ B
        return np.concatenate([(-X @ A).ravel(), (np.exp(cw * (t - tau)) * (XB @ XB.T)).ravel()])

    y0 = np.concatenate([np.eye(n).ravel(), np.zeros(n * n)])
    H = np.zeros((n, n))
    if b > t:
        sol = solve_ivp(rhs, (t, b), y0, method="DOP853", rtol=rtol, atol=atol)
        H += sol.y[n * n:, -1].reshape(n, n)
    if a < t:
        sol = solve_ivp(rhs, (t, a), y0, method="DOP853", rtol=rtol, atol=atol)
        H -= sol.y[n * n:, -1].reshape(n, n)
    return 0.5 * (H + H.T)


def transition(nominal, t: float, s: float, rtol=1e-12, atol=1e-15):
    """Phi(t, s) by integrating Z' = A Z from s to t."""
    model = nominal.model
    n = model.n

    def rhs(tau, z):
        x0, u0 = nominal.at(np.array([tau]))
        A, _ = model.linearize(x0[0], u0[0])
        return (A @ z.reshape(n, n)).ravel()

    if t == s:
        return np.eye(n)
    sol = solve_ivp(rhs, (s, t), np.eye(n).ravel(), method="DOP853", rtol=rtol, atol=atol)
    return sol.y[:, -1].reshape(n, n)


def reference_H(nominal, times, opts):
    """H(t) at each time with the window and end conventions the library documents: whole windows
    where they fit; past the boundary s, "frozen" carries H(s) along the flow,
    H(t) = Phi(t, s) H(s) Phi(t, s)^T."""
    t0, T = nominal.t0, nominal.t_end
    delta = opts.delta
    cw = opts.weight * opts.alpha
    out = []
    for t in times:
        fits_future = t + delta <= T + 1e-12
        fits_past = t - delta >= t0 - 1e-12
        if opts.window == "future" and fits_future:
            out.append(window_gramian(nominal, t, t, t + delta, cw))
        elif opts.window == "past" and fits_past:
            out.append(window_gramian(nominal, t, t - delta, t, cw))
        else:   # frozen
            s = T - delta if opts.window == "future" else t0 + delta
            Hs = window_gramian(nominal, s, s, s + delta, cw) if opts.window == "future" \
                else window_gramian(nominal, s, s - delta, s, cw)
            Phi = transition(nominal, t, s)
            out.append(Phi @ Hs @ Phi.T)
    return np.array(out)


def central_jacobian(fun, x, eps=1e-6):
    """The Jacobian of ``fun`` at ``x`` by central differences (step ``eps``), columns stacked last."""
    cols = []
    for j in range(x.size):
        d = np.zeros_like(x)
        d[j] = eps
        cols.append((fun(x + d) - fun(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)
