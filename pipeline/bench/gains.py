"""``nhstab bench gains``: the gain schedule's cost against the naive per-point quadrature."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import quad_vec, solve_ivp

from ..control import StabilizerOptions, compute_schedule
from ..models import make_model
from ..nominal import Nominal
from .common import _best, machine


def hilare_sinusoid(n_points: int) -> Nominal:
    """The paper's Hilare sinusoid nominal, u0 = (sin t, cos t) over 2 pi s, on n_points."""
    model = make_model("unicycle")
    t = np.linspace(0.0, 2.0 * math.pi, int(n_points))
    return Nominal.from_inputs(model, lambda tt: np.stack([np.sin(tt), np.cos(tt)], axis=-1), np.zeros(3), t)


def naive_schedule_P(nominal: Nominal, opts: StabilizerOptions) -> np.ndarray:
    """The naive way, as a baseline: for every grid point, integrate Phi(t, .) over its window with
    an adaptive ODE solver and the weighted gramian integrand with adaptive quadrature, then invert.
    Interior (whole future windows) only; the window end is clipped to the trajectory."""
    model = nominal.model
    n = model.n
    cw = opts.weight * opts.alpha
    out = np.empty((len(nominal.t), n, n))
    for i, t in enumerate(nominal.t):
        a = min(t, nominal.t_end - opts.delta)

        def phi_rhs(tau, z):
            x0, u0 = nominal.at(np.array([tau]))
            A, _ = model.linearize(x0[0], u0[0])
            return -(z.reshape(n, n) @ A).ravel()      # d/dtau Phi(t, tau) = -Phi(t, tau) A(tau)

        lo, hi = a, a + opts.delta
        fwd = solve_ivp(phi_rhs, (t, hi), np.eye(n).ravel(), method="DOP853", rtol=1e-11, atol=1e-13,
                        dense_output=True) if hi > t else None
        bwd = solve_ivp(phi_rhs, (t, lo), np.eye(n).ravel(), method="DOP853", rtol=1e-11, atol=1e-13,
                        dense_output=True) if lo < t else None

        def integrand(tau):
            sol = fwd if tau >= t else bwd
            X = sol.sol(tau).reshape(n, n)
            x0, u0 = nominal.at(np.array([tau]))
            XB = X @ model.g(x0[0])
            return math.exp(cw * (t - tau)) * (XB @ XB.T)

        H, _ = quad_vec(integrand, lo, hi, epsrel=1e-11, epsabs=1e-14)
        out[i] = np.linalg.inv(0.5 * (H + H.T))
    return out


def bench_gains(sizes=(1_000, 10_000, 100_000), naive_size: int = 1_000) -> dict:
    """Gain schedule on the Hilare sinusoid: linear growth and speed-up over the naive method."""
    opts = StabilizerOptions(alpha=0.1, delta=1.0, gamma=1.0)
    rows = []
    schedule_1k = None
    for N in sizes:
        nom = hilare_sinusoid(N)
        repeats = 7 if N <= 1_000 else (5 if N <= 10_000 else 3)
        compute_schedule(nom, opts)                  # warm-up
        best, median, sched = _best(lambda: compute_schedule(nom, opts), repeats)
        if N == naive_size:
            schedule_1k = sched
        rows.append({"grid_points": N, "best_s": best, "median_s": median, "repeats": repeats,
                     "us_per_point": best / N * 1e6})
    per_point = [r["us_per_point"] for r in rows]
    nom = hilare_sinusoid(naive_size)
    if schedule_1k is None:
        schedule_1k = compute_schedule(nom, opts)
    naive_best, _, P_naive = _best(lambda: naive_schedule_P(nom, opts), 1)
    interior = schedule_1k.t <= nom.t_end - opts.delta
    rel = (np.linalg.norm(schedule_1k.P[interior] - P_naive[interior], ord=2, axis=(1, 2))
           / np.linalg.norm(P_naive[interior], ord=2, axis=(1, 2)))
    fast_1k = next(r["best_s"] for r in rows if r["grid_points"] == naive_size)
    ratio = max(per_point) / min(per_point)
    speedup = naive_best / fast_1k
    return {
        "benchmark": "gains",
        "case": "hilare-sinusoid, alpha=0.1, delta=1, gamma=1, future window, 6-alpha weighting",
        "machine": machine(),
        "schedule": rows,
        "per_point_time_ratio": ratio,
        "naive": {"grid_points": naive_size, "seconds": naive_best,
                  "method": "per grid point: adaptive DOP853 for Phi plus adaptive quad_vec of the integrand"},
        "speedup_vs_naive": speedup,
        "max_relative_P_difference_vs_naive": float(rel.max()),
        "targets": {"per_point_time_ratio_max": 1.5, "speedup_vs_naive_min": 50.0},
        "met": {"linear": bool(ratio <= 1.5), "speedup": bool(speedup >= 50.0)},
    }


def summary_lines(g: dict) -> list[str]:
    """Rows of the benchmark summary table (benchmark | measure | value | target | met)."""
    lines = []
    lines.append(f"| gains | time per point, max/min over N = "
                 f"{', '.join(str(r['grid_points']) for r in g['schedule'])} | {g['per_point_time_ratio']:.2f} | "
                 f"<= {g['targets']['per_point_time_ratio_max']} | {'yes' if g['met']['linear'] else 'NO'} |")
    lines.append(f"| gains | speed-up vs naive at N = {g['naive']['grid_points']} | {g['speedup_vs_naive']:.0f}x | "
                 f">= {g['targets']['speedup_vs_naive_min']:.0f}x | {'yes' if g['met']['speedup'] else 'NO'} |")
    for r in g["schedule"]:
        lines.append(f"| gains | N = {r['grid_points']}: best of {r['repeats']} | {r['best_s'] * 1e3:.1f} ms "
                     f"({r['us_per_point']:.1f} us/point) | - | - |")
    return lines
