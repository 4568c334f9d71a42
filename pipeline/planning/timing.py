"""Time-parameterisation: a geometric path with cusps -> a nominal trajectory x0(t), u0(t).

Each cusp-free run of the path gets a trapezoidal speed profile (acceleration limit, speed limit)
that starts and ends at rest, so the robot stops for an instant at every cusp and at the ends and
never dwells: every window of the stabilizer contains motion. The nominal inputs follow from the
path's curvature kappa = dtheta/dsigma: v = d * sigma', omega = kappa * sigma' (d = +1 forward,
-1 reverse). x0 is the model's exact solution under u0 from the start (so the nominal is feasible by
construction): with kappa constant on each sample interval the unicycle moves along an arc,
integrated in closed form (vectorised); its distance from the geometric path is reported as
``path_deviation_m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..limits import nominal_grid
from ..models import Model
from ..nominal import Nominal
from .geometric import GeometricPath


@dataclass(frozen=True)
class TimingOptions:
    """max_speed [m/s] (None: the model's), max_accel [m/s^2], dt [s]: the nominal's grid step
    (50 Hz by default, the controller's default rate)."""

    max_speed: float | None = None
    max_accel: float = 0.5
    dt: float = 0.02

    def validated(self) -> "TimingOptions":
        for key in ("max_accel", "dt"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v > 0):
                raise InputError(key, "a positive finite number", v)
        if self.max_speed is not None and not (math.isfinite(self.max_speed) and self.max_speed > 0):
            raise InputError("max_speed", "a positive finite number", self.max_speed)
        return self


@dataclass
class _Run:
    t0: float        # start time of the run
    length: float    # arc length of the run
    v_peak: float
    accel: float
    direction: float
    sigma0: float    # arc length of the path at the run's start

    @property
    def t_acc(self) -> float:
        return self.v_peak / self.accel

    @property
    def duration(self) -> float:
        cruise = self.length / self.v_peak - self.t_acc      # time at v_peak
        return 2 * self.t_acc + max(cruise, 0.0)

    def time_at(self, s: np.ndarray) -> np.ndarray:
        """The run-local times at which the run has advanced s (0 <= s <= length): ``progress`` inverted."""
        a, vp, ta, T, L = self.accel, self.v_peak, self.t_acc, self.duration, self.length
        s = np.clip(np.asarray(s, dtype=float), 0.0, L)
        s_acc = 0.5 * a * ta * ta
        return np.where(s < s_acc, np.sqrt(2.0 * s / a),
                        np.where(s < L - s_acc, ta + (s - s_acc) / vp, T - np.sqrt(np.maximum(2.0 * (L - s) / a, 0.0))))

    def progress(self, tau: np.ndarray):
        """(sigma advanced, sigma') at run-local times tau in [0, duration]."""
        a, vp, ta, T = self.accel, self.v_peak, self.t_acc, self.duration
        tau = np.clip(tau, 0.0, T)
        s_acc = 0.5 * a * ta * ta
        s = np.where(tau < ta, 0.5 * a * tau * tau,
                     np.where(tau < T - ta, s_acc + vp * (tau - ta), self.length - 0.5 * a * (T - tau) ** 2))
        v = np.where(tau < ta, a * tau, np.where(tau < T - ta, vp, a * (T - tau)))
        return np.minimum(s, self.length), np.maximum(v, 0.0)


class PathTiming:
    """sigma(t), sigma'(t), direction and curvature along a timed path (vectorised in t)."""

    def __init__(self, path: GeometricPath, max_speed: float, max_accel: float):
        self.path = path
        sigma, direction = path.sigma, path.direction
        d_theta = np.diff(path.samples[:, 2])
        d_sigma = np.diff(sigma)
        with np.errstate(invalid="ignore", divide="ignore"):
            kappa = np.where(d_sigma > 1e-12, d_theta / d_sigma, 0.0)
        # A reverse interval's heading changes along sigma as kappa: theta' = kappa sigma' either way.
        self.kappa = kappa
        self.sigma = sigma
        self.runs: list[_Run] = []
        change = np.flatnonzero(direction[1:] != direction[:-1]) + 1        # interval index where a run starts
        bounds = np.concatenate([[0], change, [len(direction)]])
        t = 0.0
        for i0, i1 in zip(bounds[:-1], bounds[1:]):
            length = float(sigma[i1] - sigma[i0])
            if length <= 1e-12:
                continue
            v_peak = min(max_speed, math.sqrt(max_accel * length))
            run = _Run(t, length, v_peak, max_accel, float(direction[i0]), float(sigma[i0]))
            self.runs.append(run)
            t += run.duration
        self.duration = t

    def evaluate(self, t):
        """(sigma, sigma', direction, kappa) at times t."""
        t = np.asarray(t, dtype=float)
        starts = np.array([r.t0 for r in self.runs])
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.runs) - 1)
        sigma = np.empty_like(t)
        speed = np.empty_like(t)
        direction = np.empty_like(t)
        for j, run in enumerate(self.runs):
            sel = k == j
            if sel.any():
                s, v = run.progress(t[sel] - run.t0)
                sigma[sel] = run.sigma0 + s
                speed[sel] = v
                direction[sel] = run.direction
        idx = np.clip(np.searchsorted(self.sigma, sigma, side="right") - 1, 0, len(self.kappa) - 1)
        return sigma, speed, direction, self.kappa[idx]

    def breaks(self) -> np.ndarray:
        """The times at which u0 = (d sigma', kappa sigma') is not smooth: each run's start and end and
        the ends of its speed ramps (sigma' has a kink), and the times the path's curvature changes
        (omega jumps). A hint for integrators (:meth:`nhstab.nominal.Nominal.feasibility_residual`)."""
        kap, sig = self.kappa, self.sigma
        scale = max(1.0, float(np.max(np.abs(kap)))) if len(kap) else 1.0
        changes = sig[np.flatnonzero(np.abs(np.diff(kap)) > 1e-9 * scale) + 1]
        out = []
        for run in self.runs:
            out.append([run.t0, run.t0 + run.t_acc, run.t0 + run.duration - run.t_acc, run.t0 + run.duration])
            inside = changes[(changes > run.sigma0) & (changes < run.sigma0 + run.length)]
            out.append(run.t0 + run.time_at(inside - run.sigma0))
        return np.unique(np.concatenate(out)) if out else np.zeros(0)

    def pose(self, sigma):
        """Geometric path pose at arc lengths sigma (linear between dense samples)."""
        sig = self.sigma
        return np.stack([np.interp(sigma, sig, self.path.samples[:, j]) for j in range(3)], axis=-1)

    def exact_poses(self, start):
        """Poses at the sample arc lengths of the unicycle driven by u0 from ``start`` (exact arcs)."""
        d_sigma = np.diff(self.sigma)
        theta = start[2] + np.concatenate([[0.0], np.cumsum(self.kappa * d_sigma)])
        step = self.path.direction * d_sigma * np.sinc(self.kappa * d_sigma / (2 * np.pi))
        mid = theta[:-1] + 0.5 * self.kappa * d_sigma
        x = start[0] + np.concatenate([[0.0], np.cumsum(step * np.cos(mid))])
        y = start[1] + np.concatenate([[0.0], np.cumsum(step * np.sin(mid))])
        self._exact = np.column_stack([x, y, theta])
        return self._exact

    def exact_at(self, sigma):
        """The exact unicycle pose at arc lengths sigma (arc from the sample before)."""
        sigma = np.asarray(sigma, dtype=float)
        k = np.clip(np.searchsorted(self.sigma, sigma, side="right") - 1, 0, len(self.kappa) - 1)
        base = self._exact[k]
        ds = sigma - self.sigma[k]
        kap = self.kappa[k]
        step = self.path.direction[k] * ds * np.sinc(kap * ds / (2 * np.pi))
        mid = base[..., 2] + 0.5 * kap * ds
        return np.stack([base[..., 0] + step * np.cos(mid), base[..., 1] + step * np.sin(mid),
                         base[..., 2] + kap * ds], axis=-1)


def unicycle_nominal(model: Model, path: GeometricPath, opts: TimingOptions) -> tuple[Nominal, dict]:
    """The unicycle's nominal along a Reeds-Shepp path: (v, omega) = (d sigma', kappa sigma')."""
    opts = opts.validated()
    if model.name != "unicycle":
        raise InputError("model", "unicycle for this time-parameterisation", model.name)
    turn_limit = float(model.input_limits()[1, 1])
    kmax = 1.0 / path.options.turning_radius
    v_cap, v_turn = opts.max_speed or float(model.input_limits()[0, 1]), turn_limit / max(kmax, 1e-9)
    v_lim = min(v_cap, v_turn)
    timing = PathTiming(path, v_lim, opts.max_accel)

    def u_func(t):
        _, speed, direction, kappa = timing.evaluate(t)
        return np.stack([direction * speed, kappa * speed], axis=-1)

    key, value, why = (("turning_radius", path.options.turning_radius, " (the turn-rate limit times the turning "
                        "radius)") if v_turn < v_cap else ("max_speed", v_lim, ""))
    n = nominal_grid(timing.duration, opts.dt, key, value, v_lim, why)
    t = np.linspace(0.0, timing.duration, n)
    timing.exact_poses(path.samples[0])

    def x_func(tt):
        return timing.exact_at(timing.evaluate(tt)[0])

    nominal = Nominal.from_functions(model, x_func, u_func, t)
    nominal.u_breaks = timing.breaks()
    sigma, _, _, _ = timing.evaluate(t)
    geo = timing.pose(sigma)
    deviation = float(np.max(np.hypot(nominal.x[:, 0] - geo[:, 0], nominal.x[:, 1] - geo[:, 1])))
    return nominal, {"path_deviation_m": deviation, "duration_s": timing.duration, "speed_limit_mps": v_lim,
                     "runs": len(timing.runs), "dt_s": float(t[1] - t[0])}
