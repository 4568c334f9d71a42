"""Closed-loop simulation of a robot stabilized to its nominal trajectory.

:func:`simulate_tracking` integrates x' = f(x) + g(x) u with the continuous-time law
u = u0(t) - K(t) (x - x0(t)) (gains linearly interpolated between schedule grid points) with an
adaptive integrator. It integrates the error e = x - x0 itself,

    e' = f(x0 + e) + g(x0 + e) (u0 - K e) - [f(x0) + g(x0) u0],

so that the error keeps its relative accuracy as it decays (x - x0 computed by subtraction would hit
a floor near 1e-15 |x|); x = x0 + e. For a feasible nominal this is exactly the plant. The default is Radau (implicit, 5th order) with the exact closed-loop Jacobian,
because the gramian gains can be very large where H is nearly singular (the FWD car reaches
||K|| ~ 1e5), which makes the closed loop stiff: an explicit method would need steps well below
1 / ||K||. DOP853 is available for non-stiff checks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from .control import GainSchedule
from .errors import InputError, NumericalError

METHODS = ("Radau", "BDF", "DOP853", "LSODA")


@dataclass
class TrackingResult:
    """Time-major samples of one closed-loop run."""

    t: np.ndarray          # (T,)
    x: np.ndarray          # (T, n) actual state
    x_nominal: np.ndarray  # (T, n)
    u: np.ndarray          # (T, m) applied input
    u_nominal: np.ndarray  # (T, m)
    e: np.ndarray          # (T, n) x - x0, angles wrapped
    v: np.ndarray          # (T, m) u - u0
    status: str            # "completed" | "diverged"
    message: str = ""
    info: dict = field(default_factory=dict)

    @property
    def error_norm(self) -> np.ndarray:
        return np.linalg.norm(self.e, axis=1)


def simulate_tracking(schedule: GainSchedule, x_init, t_end: float | None = None, *, method: str = "Radau",
                      rtol: float = 1e-10, atol: float = 1e-20, n_out: int = 2001,
                      divergence_norm: float | None = None, t_start: float | None = None) -> TrackingResult:
    """Integrate the closed loop from ``x_init`` at ``t_start`` (default: the schedule's start) until
    ``t_end``.

    The run stops early with status "diverged" when ||x - x0|| exceeds ``divergence_norm``
    (default: max(10, 100 ||e(0)||)).
    """
    nom = schedule.nominal
    model = nom.model
    x_init = np.asarray(x_init, dtype=float)
    if x_init.shape != (model.n,) or not np.all(np.isfinite(x_init)):
        raise InputError("x_init", f"a finite vector of length {model.n}", x_init.tolist())
    t0 = float(schedule.t[0]) if t_start is None else float(t_start)
    if not (schedule.t[0] - 1e-9 <= t0 < schedule.t[-1]):
        raise InputError("t_start", f"in [{schedule.t[0]:.6g}, {schedule.t[-1]:.6g}) s (the schedule's span)", t_start)
    t_end = float(schedule.t[-1]) if t_end is None else float(t_end)
    if not (t0 < t_end <= schedule.t[-1] + 1e-9):
        raise InputError("t_end", f"in ({t0:.6g}, {schedule.t[-1]:.6g}] s (the schedule's span)", t_end)
    if method not in METHODS:
        raise InputError("method", "one of " + ", ".join(METHODS), method)
    e0 = model.state_error(x_init, nom.at(t0)[0])
    limit = float(divergence_norm) if divergence_norm is not None else max(10.0, 100.0 * float(np.linalg.norm(e0)))

    evaluate = schedule.evaluator()

    def rhs(t, e):
        x0, u0, K = evaluate(t)
        return model.rhs(x0 + e, u0 - K @ e) - model.rhs(x0, u0)

    def jac(t, e):
        x0, u0, K = evaluate(t)
        x = x0 + e
        return model.dfdx(x) + model.dgu_dx(x, u0 - K @ e) - model.g(x) @ K

    def diverged(t, e):
        return limit - float(np.linalg.norm(e))

    diverged.terminal = True
    diverged.direction = -1

    t_eval = np.linspace(t0, t_end, int(n_out))
    kwargs = {"jac": jac} if method in ("Radau", "BDF", "LSODA") else {}
    started = time.perf_counter()
    sol = solve_ivp(rhs, (t0, t_end), e0, method=method, t_eval=t_eval, rtol=rtol, atol=atol,
                    events=diverged, dense_output=True, **kwargs)
    wall = time.perf_counter() - started
    t = sol.t
    e = sol.y.T
    status, message = "completed", "reached t_end"
    if sol.status == -1:
        # the integrator broke down (step size underflow): the closed loop ran away
        if sol.sol is None:
            raise NumericalError(f"closed-loop integration failed at the first step: {sol.message}")
        t_fail = float(sol.sol.t_max)
        e_last = sol.sol(t_fail)
        e_fail = float(np.linalg.norm(e_last))
        status = "diverged" if e_fail > np.linalg.norm(e0) else "failed"
        message = (f"the integrator broke down at t = {t_fail:.4g} s with ||x - x0|| = {e_fail:.3g} "
                   f"({sol.message})")
        keep = t < t_fail
        t = np.append(t[keep], t_fail)
        e = np.vstack([e[keep], e_last])
    elif sol.status == 1 and len(sol.t_events[0]):
        status = "diverged"
        message = f"||x - x0|| reached {limit:.3g} at t = {sol.t_events[0][0]:.4g} s"
        t = np.append(t, sol.t_events[0][0])
        e = np.vstack([e, sol.y_events[0][0]])
    x0, u0 = nom.at(t)
    x = x0 + e
    e = model.state_error(x, x0)     # report angle errors wrapped
    K = schedule.gain_at(t)
    v = -np.einsum("tij,tj->ti", K, e)
    info = {"method": method, "rtol": rtol, "atol": atol, "nfev": int(sol.nfev), "njev": int(sol.njev),
            "wall_time_s": wall, "divergence_norm": limit}
    return TrackingResult(t=t, x=x, x_nominal=x0, u=u0 + v, u_nominal=u0, e=e, v=v, status=status,
                          message=message, info=info)


def fit_decay_rate(t: np.ndarray, err_norm: np.ndarray, t_from: float | None = None) -> float:
    """Least-squares exponential decay rate r of ||e|| ~ C exp(-r t) over t >= t_from
    (default: the second half of the run). Positive means decaying."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(err_norm, dtype=float)
    if t_from is None:
        t_from = t[0] + 0.5 * (t[-1] - t[0])
    sel = (t >= t_from) & (y > 0)
    if sel.sum() < 2:
        return float("nan")
    slope = np.polyfit(t[sel], np.log(y[sel]), 1)[0]
    return float(-slope)
