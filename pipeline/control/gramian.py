"""The gain schedule of Proposition 1 (future window), Remark 2 (past window, for study) and the
frozen-time law (a causal alternative).

Convention (the 6-alpha weighting: docs/theory/control-law.md, Weighting; the constant ``weight`` = w = 6
is a parameter):

    H_c(t, t + delta) = int_t^{t+delta} exp(w alpha (t - tau)) Phi(t, tau) B B^T Phi(t, tau)^T dtau
    P_c(t) = H_c(t, t + delta)^-1,        u = u0 - gamma(t) B(t)^T P_c(t) (x - x0)

The guarantee (docs/theory/control-law.md, The guarantee). With the corrected identity for dP_c/dt,
V = e^T P_c e along the linearised closed loop e' = (A - gamma B B^T P_c) e satisfies

    dV/dt = -w alpha V + (1 - 2 gamma) |B^T P_c e|^2 - exp(-w alpha delta) |B(t+delta)^T Phi(t,t+delta)^T P_c e|^2
          <= -w alpha V          (gamma >= 1/2),

so ||e(t)|| <= sqrt(e(0)^T P_c(0) e(0) / lambda_min(P_c(t))) exp(-(w/2) alpha t) <= sqrt(p_M/p_m) ||e(0)||
exp(-3 alpha t): the guaranteed local rate is 3 alpha (``rate_bound``), not the 2 alpha p_m/p_M printed
in the paper (kept as ``rate_bound_printed``, which it always exceeds). :meth:`GainSchedule.error_bound`
evaluates the time-varying bound; it holds while the window slides (t <= T - delta); in the frozen end
region V is non-increasing only.

``window="past"`` (Remark 2, kept for study) uses [t - delta, t] with the same weighting:
P_r(t) = [int_{t-delta}^t exp(w alpha (t - tau)) Phi(t, tau) B B^T Phi(t, tau)^T dtau]^-1. (The paper
writes H_c(t, t - delta); read literally, with the limits reversed, that integral is negative definite.)
The law with P_r is **not stabilizing in general** (docs/theory/control-law.md, Remark 2): on the
unicycle's straight line the past window flips the sign of the lateral position gain and the closed
loop has an eigenvalue with positive real part for every alpha, delta and gamma (``nhstab paper
--case remark2-line-past``). The 3 alpha argument does not apply to it, and no rate bound is reported
for it; computing it issues a :class:`NotStabilizingWarning`.

``window="frozen-time"`` is the causal alternative (:mod:`nhstab.control.frozen`): Proposition 1 on
the pair (A(t), B(t)) frozen at the current time, with a hold where that pair is not (or barely)
controllable. It has the 3 alpha guarantee on LTI nominals and a certified rate w alpha - mu(t) where
A and B vary slowly (:meth:`GainSchedule.lyapunov_rates`).

The ends of a finite trajectory. A future window needs t + delta <= T and a past one t - delta >= t0.
Where a window would run off the trajectory the ``end_strategy="frozen"`` (the default) stops sliding
it at the boundary time s (s = T - delta for the future window, s = t0 + delta for the past one) and
carries that last whole window's gramian along the nominal's linearised flow:

    H(t) = Phi(t, s) H(s) Phi(t, s)^T,   so   dP/dt = -P A - A^T P   there.

P is continuous at s, as far from singular as the last whole window (Phi spans at most delta), and
along the linearised closed loop V = e^T P e obeys dV/dt = -2 gamma |B^T P e|^2 <= 0: the error keeps
being driven down wherever the remaining motion can act on it. (Carrying the exponential weighting on
past s would make P, and with it the gains, shrink by up to exp(w alpha delta) by the end.) There is no
``"switch"`` strategy (P_r for the last delta seconds of a future-window schedule): it would use the
past window, which is not stabilizing, and make the gains jump.

``end_strategy="extend"`` keeps the window sliding: past the end it runs along the nominal's
continuation under its last input held (before the start, under its first input held, for a past
window), x' = f(x) + g(x) u0(T) from x0(T), integrated to 1e-12 (DOP853). The windows are then the
paper's own, on the continued trajectory. Where the robot is at rest at the end (its last input is
zero, or it only steers: every car nominal that ends on an arc steers its wheels straight in place
before it stops, and holding that input would steer past the limit), the continuation drives on as
the robot last really moved: the input of the last grid point where the pose moved at least half as
fast as anywhere on the nominal, with the inputs that act only on limited states (the steering rate)
zeroed, so the car drives on at its final steering angle (``_held_inputs``). Why: the frozen end
carries the window [s, s + delta] to t > s, H(t) = Phi(t, s) H(s) Phi(t, s)^T, which still counts the
control spent in [s, t] as if it were to come; over the last window the gains fall (on the parking
suite's last reverse arc into a slot to a tenth of the sliding part's), the tracking error grows
under the process noise while the car reverses towards the curb, and the car touched it or missed
the goal (``tests/parking/test_parking_runs.py`` fails with the frozen end). Along the continuation the window
sees the motion the car is in, and the gains stay those of the sliding part. Where no continuation is
usable (the robot never moves, the continuation leaves the model's state limits within delta, or its
window gramian is singular), the end falls back to "frozen"; ``diagnostics["end"]`` says which end
was used, under which input, and why.

Computation: per-interval pieces are integrated to 8th order (``elements``), then every window is an
associative combination of pieces (``windows``): linear in the number of grid points, with no
subtraction and nothing spanning more than one window, so long trajectories lose no accuracy.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError, NotStabilizingWarning, NumericalError, SingularGramianError, require_positive
from ..limits import MAX_GAMMA, MAX_WINDOW_SUBSTEPS
from ..nominal import Nominal
from .elements import interval_segments, to_end_anchored
from .frozen import MAX_GAIN, frozen_time_schedule
from .interpolant import GridInterpolant
from .windows import Segments, combine, exclusive_prefix, scan, sliding, transposed

WINDOWS = ("future", "past", "frozen-time")
END_STRATEGIES = ("frozen", "extend")
#: how a future-window schedule meets a cusp: "across" (one schedule, windows run across cusps) or
#: "split" (one schedule per cusp-free segment, :func:`_split_schedule`)
CUSP_HANDLING = ("across", "split")

#: the one-line warning for the past window (the command line prints it as is)
PAST_WINDOW_WARNING = (
    "the past window (Remark 2) is not stabilizing in general: it flips the sign of the lateral position "
    "gain, so on a straight line at constant speed the closed loop has an eigenvalue with positive real part "
    "for every alpha, delta and gamma (see docs/theory/control-law.md, Remark 2, and `nhstab paper --case "
    "remark2-line-past`); use it for study only, and --window frozen-time for a causal law that works")
#: the largest gain norm max ||K|| the stabilizer defaults are chosen for (``nhstab sweep`` picks, per
#: robot, the gains within it); a plan whose schedule exceeds it is flagged in its metrics
GAIN_BOUND = 50.0

#: what the reported rate_bound means, per window
GUARANTEES = {
    "future": "3 alpha (w alpha / 2): V = e^T P_c e decays at least as exp(-w alpha t) along the linearised closed "
              "loop while the window slides; ||e(t)|| <= sqrt(e0^T P_c(0) e0 / lambda_min(P_c(t))) exp(-3 alpha t) "
              "(see docs/theory/control-law.md, The guarantee)",
    "past": "none: the past-window law is not stabilizing in general (see docs/theory/control-law.md, Remark 2)",
    "frozen-time": "none uniform: V = e^T P e decays at the certified rate w alpha - mu(t) where A, B vary slowly "
                   "(GainSchedule.lyapunov_rates; nhstab gains reports their min and mean); exactly 3 alpha on "
                   "time-invariant nominals",
}


@dataclass(frozen=True)
class StabilizerOptions:
    """Parameters of the gramian stabilizer.

    alpha: the rate parameter (> 0); delta: window length in s (> 0); gamma: gain factor, a number or
    a function of time (array in, array out), >= 1/2 everywhere; weight: the weighting constant w of
    exp(w alpha (t - tau)) (6 in the paper's Proposition 1); window: "future" (P_c), "past" (P_r, not
    stabilizing in general: for study) or "frozen-time" (the causal law of :mod:`nhstab.control.frozen`);
    end_strategy: "frozen" or "extend" (see the module docstring); cusps: "across" (one schedule whose
    windows run across the nominal's cusps) or "split" (future window: one schedule per cusp-free
    segment, :func:`_split_schedule`; the cars' default); max_gain: the frozen-time law holds its last
    admissible gramian where its gain norm would exceed this; singular_rtol / singular_atol:
    H(t) counts as singular where its smallest eigenvalue is <= max(atol, rtol * lambda_max(H(t))),
    i.e. where it cannot be told from singular in double precision.
    """

    alpha: float = 0.1
    delta: float = 1.0
    gamma: float | Callable[[np.ndarray], np.ndarray] = 1.0
    weight: float = 6.0
    window: str = "future"
    end_strategy: str = "frozen"
    cusps: str = "across"
    singular_rtol: float = 1e-11
    singular_atol: float = 1e-300
    max_substep_fraction: float = 1.0 / 16.0
    max_gain: float = MAX_GAIN

    def validated(self) -> "StabilizerOptions":
        require_positive("alpha", self.alpha)
        require_positive("delta", self.delta)
        require_positive("weight", self.weight)
        require_positive("singular_rtol", self.singular_rtol)
        require_positive("max_substep_fraction", self.max_substep_fraction)
        require_positive("max_gain", self.max_gain)
        if self.window not in WINDOWS:
            raise InputError("window", "one of " + ", ".join(WINDOWS), self.window)
        if self.end_strategy == "switch":
            raise InputError("end_strategy", "frozen or extend (there is no 'switch': it would use the past window P_r, "
                             "which is not stabilizing in general; see docs/theory/control-law.md)", self.end_strategy)
        if self.end_strategy not in END_STRATEGIES:
            raise InputError("end_strategy", "one of " + ", ".join(END_STRATEGIES), self.end_strategy)
        if self.cusps not in CUSP_HANDLING:
            raise InputError("cusps", "one of " + ", ".join(CUSP_HANDLING), self.cusps)
        if not callable(self.gamma):
            try:
                g = float(self.gamma)
            except (TypeError, ValueError):
                raise InputError("gamma", "a number >= 1/2 or a function of time", self.gamma) from None
            if not math.isfinite(g) or not 0.5 <= g <= MAX_GAMMA:
                raise InputError("gamma", f"a number in [1/2 (Proposition 1), {MAX_GAMMA:g}]", self.gamma)
        return self

    def check_step(self, h: float) -> None:
        """The window against a nominal's time step ``h`` [s]: a window of delta is integrated in steps
        of at most delta x max_substep_fraction, and at most MAX_WINDOW_SUBSTEPS of them per time step,
        so delta must be at least h / (max_substep_fraction x MAX_WINDOW_SUBSTEPS)."""
        delta = float(self.delta)
        if h / (self.max_substep_fraction * delta) > MAX_WINDOW_SUBSTEPS:
            shortest = h / (self.max_substep_fraction * MAX_WINDOW_SUBSTEPS)
            raise InputError("delta", f"at least {shortest:.3g} s for this nominal's time step {h:.3g} s", self.delta,
                             detail=f"a window of delta is integrated in steps of at most delta x "
                                    f"{self.max_substep_fraction:g}, and at most {MAX_WINDOW_SUBSTEPS} per time step")

    def gamma_on(self, t: np.ndarray) -> np.ndarray:
        if callable(self.gamma):
            try:
                g = np.broadcast_to(np.asarray(self.gamma(t), dtype=float), t.shape).copy()
            except (TypeError, ValueError) as exc:
                raise InputError("gamma", "a function returning one number per time", str(exc)) from None
            if not np.all(np.isfinite(g)):
                raise InputError("gamma", "finite and bounded at every time", "NaN or inf")
            if g.max() > MAX_GAMMA:
                k = int(np.argmax(g))
                raise InputError("gamma", f"a function <= {MAX_GAMMA:g} at every time", f"{g[k]:.6g} at t = {t[k]:.6g} s")
            if g.min() < 0.5:
                k = int(np.argmin(g))
                raise InputError("gamma", "a function >= 1/2 at every time (Proposition 1)",
                                 f"{g[k]:.6g} at t = {t[k]:.6g} s")
            return g
        return np.full(t.shape, float(self.gamma))

    def describe(self) -> dict:
        d = {"alpha": float(self.alpha), "delta": float(self.delta),
             "gamma": "function" if callable(self.gamma) else float(self.gamma),
             "weight": float(self.weight), "window": self.window, "end_strategy": self.end_strategy,
             "weighting": f"exp({self.weight:g} alpha (t - tau))"}
        if self.cusps != "across":
            d["cusps"] = self.cusps
        if self.window == "frozen-time":
            d["max_gain"] = float(self.max_gain)
        return d


@dataclass
class GainSchedule:
    """P(t), K(t) = gamma(t) B(t)^T P(t) on a uniform grid, with diagnostics. Linear in between."""

    t: np.ndarray                 # (N,)
    H: np.ndarray                 # (N, n, n) the window gramian H(t) (future: H_c(t, t + delta))
    P: np.ndarray                 # (N, n, n) P = H^-1
    K: np.ndarray                 # (N, m, n)
    H_eigenvalues: np.ndarray     # (N, n), ascending, eigenvalues of the window gramian H(t)
    gamma: np.ndarray             # (N,)
    options: StabilizerOptions
    nominal: Nominal
    diagnostics: dict = field(default_factory=dict)

    @property
    def h(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def interpolant(self) -> GridInterpolant:
        """The schedule's one interpolator: x0 cubic Hermite, u0 the nominal's own function, K linear
        (see :mod:`nhstab.control.interpolant`)."""
        cached = self.__dict__.get("_interpolant")
        if cached is None:
            nom = self.nominal
            cached = GridInterpolant(self.t, nom.x, nom.model.rhs(nom.x, nom.u), nom.u, self.K, u_func=nom._u_func)
            self.__dict__["_interpolant"] = cached
        return cached

    def gain_at(self, tau):
        """K(tau), linearly interpolated between grid points; shape (..., m, n)."""
        return self.interpolant.gain_many(tau)

    def P_at(self, tau):
        """P(tau), linearly interpolated between grid points; shape (..., n, n)."""
        return self.interpolant.linear_many(self.P, tau)

    def diagnose(self, t_from: float | None = None, t_to: float | None = None, lyapunov: bool = True) -> dict:
        """Diagnostics over the grid points in [t_from, t_to] (default: the whole schedule); the
        Lyapunov rates only with ``lyapunov`` (a plan's schedule leaves them out of its ``diagnostics``:
        they take about a fifth of the schedule's time on a car's nominal, and nothing in planning or
        control reads them; ``nhstab gains`` and ``nhstab paper`` ask for them).

        p_m, p_M: extreme eigenvalues of P. rate_bound: the guaranteed local rate, 3 alpha (w alpha / 2)
        for the future window (docs/theory/control-law.md, The guarantee; see :meth:`error_bound` for its
        time-varying factor), None for the past window (no guarantee) and the frozen-time law (see
        lyapunov_rate_*).
        rate_bound_printed: the paper's printed 2 alpha p_m / p_M (future window only), always below
        rate_bound. lyapunov_rate_min / _mean: the certified decay rate of V = e^T P e along the
        linearised closed loop (:meth:`lyapunov_rates`; half of it is the rate of ||e||). Also the
        smallest eigenvalue of H and its time, and the largest gain norm.
        """
        lo = -np.inf if t_from is None else t_from - 1e-9 * self.h
        hi = np.inf if t_to is None else t_to + 1e-9 * self.h
        sel = np.flatnonzero((self.t >= lo) & (self.t <= hi))
        if sel.size == 0:
            raise InputError("t_from/t_to", f"a span containing grid points of [{self.t[0]:.6g}, {self.t[-1]:.6g}] s",
                             (t_from, t_to))
        lam = self.H_eigenvalues[sel]
        p_m = float(np.min(1.0 / lam[:, -1]))
        p_M = float(np.max(1.0 / lam[:, 0]))
        k_min = int(np.argmin(lam[:, 0]))
        k_gain, max_gain = _largest_norm(self.K[sel])
        alpha, window = float(self.options.alpha), self.options.window
        intervals = sel[:-1] if sel.size > 1 else np.clip(sel, 0, len(self.t) - 2)   # grid intervals in the span
        rates = self.lyapunov_rates()[intervals] if lyapunov else None
        out = {
            "p_m": p_m, "p_M": p_M,
            "rate_bound": 0.5 * float(self.options.weight) * alpha if window == "future" else None,
            "rate_bound_printed": 2.0 * alpha * p_m / p_M if window == "future" else None,
            "guarantee": GUARANTEES[window],
            "h_min_eigenvalue": float(lam[k_min, 0]), "h_min_eigenvalue_time_s": float(self.t[sel][k_min]),
            "h_max_eigenvalue": float(lam[:, -1].max()),
            "max_gain_norm": max_gain, "max_gain_norm_time_s": float(self.t[sel][k_gain]),
        }
        if lyapunov:
            out.update(lyapunov_rate_min=float(np.min(rates)), lyapunov_rate_mean=float(np.mean(rates)))
        return out

    def lyapunov_rates(self) -> np.ndarray:
        """The certified decay rate r_k of V = e^T P e on each grid interval (N - 1,), for the
        linearised closed loop e' = (A - gamma B B^T P) e with P linear between grid points (as the law
        interpolates it): dV/dt <= -r V with

            r = -lambda_max(P^-1/2 (A^T P + P A + dP/dt - 2 gamma P B B^T P) P^-1/2),

        dP/dt the interval's difference quotient, averaged over the interval's two ends (accurate to
        O(h^2)). For the future window r >= w alpha while the window slides (docs/theory/control-law.md,
        The guarantee) and r = 0 in the frozen end region; for the frozen-time law r = w alpha - mu(t)
        (:mod:`.frozen`); for the past window r is negative on a straight line (its V is no Lyapunov
        function)."""
        cached = self.__dict__.get("_lyapunov_rates")
        if cached is not None:
            return cached
        nom = self.nominal
        A, B = nom.model.linearize(nom.x, nom.u)
        dP = np.diff(self.P, axis=0) / self.h
        # per grid point, once: the part of M without dP/dt, and P^-1/2 as the inverse Cholesky factor
        P = self.P
        PB = P @ B
        Q = np.swapaxes(A, -1, -2) @ P + P @ A - 2.0 * self.gamma[:, None, None] * (PB @ transposed(PB))
        Li = np.linalg.inv(np.linalg.cholesky(P))
        LiT = np.swapaxes(Li, -1, -2)

        def rate(idx):
            S = Li[idx] @ (Q[idx] + dP) @ LiT[idx]
            return -np.linalg.eigvalsh(0.5 * (S + np.swapaxes(S, -1, -2)))[:, -1]

        r = 0.5 * (rate(slice(None, -1)) + rate(slice(1, None)))
        self.__dict__["_lyapunov_rates"] = r
        return r

    def error_bound(self, e0, t, t_start: float | None = None) -> np.ndarray:
        """The guaranteed bound on ||e(t)|| of the linearised closed loop started with error e0 at
        t_start (default: the schedule's start), at the times t >= t_start:

            ||e(t)|| <= sqrt(e0^T P(t_start) e0 / lambda_min(P(t))) exp(-(1/2) int_{t_start}^t r)

        with int r from :meth:`guaranteed_decay`. With w = 6 this is the 3 alpha bound of the future
        window. The past window has no guarantee: refused.
        """
        t = np.asarray(t, dtype=float)
        until = self.diagnostics.get("guarantee_until_s")
        if until is not None and np.any(t > until + 1e-9 * self.h):
            raise InputError("t", f"times up to {until:.6g} s, the end of the first cusp (a schedule split at "
                             "cusps has no guarantee across one)", float(np.max(t)))
        exponent = self.guaranteed_decay(t, t_start)
        t_start = float(self.t[0]) if t_start is None else float(t_start)
        e0 = np.asarray(e0, dtype=float)
        V0 = float(e0 @ self.P_at(t_start) @ e0)
        return np.sqrt(V0 / self.p_min_at(t)) * np.exp(-0.5 * exponent)

    def guaranteed_decay(self, t, t_start: float | None = None) -> np.ndarray:
        """int_{t_start}^t r: V(t) <= V(t_start) exp(-that) along the linearised closed loop.

        Future window: r = w alpha while the window slides and 0 after it stops
        (docs/theory/control-law.md, The guarantee). Frozen-time law: r from :meth:`lyapunov_rates` (a
        numerical certificate, P linear between grid points). Past window: refused (no guarantee:
        docs/theory/control-law.md, Remark 2)."""
        window = self.options.window
        if window == "past":
            raise InputError("window", "future or frozen-time (the past window has no guarantee: it is not "
                             "stabilizing in general; see docs/theory/control-law.md, Remark 2)", window)
        t = np.asarray(t, dtype=float)
        t_start = float(self.t[0]) if t_start is None else float(t_start)
        if window == "future":
            until = self.diagnostics.get("sliding_window_until_s", float(self.t[-1]))
            return float(self.options.weight) * float(self.options.alpha) * (
                np.minimum(t, until) - min(t_start, until)).clip(0.0)
        cum = np.concatenate([[0.0], np.cumsum(self.lyapunov_rates() * self.h)])     # int_{t_0}^{t_k} r
        return np.interp(t, self.t, cum) - np.interp(t_start, self.t, cum)          # r constant per interval

    def p_min_at(self, t) -> np.ndarray:
        """A lower bound of lambda_min(P(t)) for P linear between grid points: exact at grid points,
        the smaller end's value between them (lambda_min is concave)."""
        t = np.asarray(t, dtype=float)
        lam_P = 1.0 / self.H_eigenvalues[:, -1]
        k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2)
        on_grid = np.isclose(t, self.t[k], rtol=0.0, atol=1e-9 * self.h)
        return np.where(on_grid, lam_P[k], np.minimum(lam_P[k], lam_P[k + 1]))

    def evaluator(self) -> GridInterpolant:
        """A fast scalar-time evaluator: ``evaluator()(tau)`` -> (x0, u0, K) (the interpolant)."""
        return self.interpolant

    def control(self, tau: float, x: np.ndarray) -> np.ndarray:
        """u = u0(tau) - K(tau) e, e = x - x0(tau) (angles wrapped)."""
        x0, u0 = self.nominal.at(tau)
        e = self.nominal.model.state_error(x, x0)
        return u0 - self.gain_at(tau) @ e


def _largest_norm(K: np.ndarray) -> tuple[int, float]:
    """The (first) index and the value of the largest spectral norm among matrices K (N, m, n): the
    same as the argmax of ``np.linalg.norm(K, ord=2, axis=(1, 2))``, with an SVD only for the matrices
    that can hold it: ||K||_2 <= ||K||_F, and ||K||_2 >= ||K||_F / sqrt(rank), so a matrix whose
    Frobenius norm is below the largest one's / sqrt(min(m, n)) is not the largest (a relative
    allowance of 1e-9 covers rounding)."""
    fro = np.sqrt(np.einsum("kij,kij->k", K, K))
    top = fro.max()
    keep = np.flatnonzero(fro >= top / math.sqrt(min(K.shape[1:])) * (1.0 - 1e-9)) if np.isfinite(top) \
        else np.arange(len(K))          # a non-finite gain: every matrix goes to the SVD, as before
    norms = np.linalg.norm(K[keep], ord=2, axis=(1, 2))
    k = int(np.argmax(norms))
    return int(keep[k]), float(norms[k])


def compute_schedule(nominal: Nominal, options: StabilizerOptions | None = None, **overrides) -> GainSchedule:
    """Gain schedule of the gramian stabilizer along ``nominal``.

    Raises :class:`SingularGramianError` (naming the time and the smallest eigenvalue) where the
    window gramian is singular, and :class:`InputError` for bad options or a trajectory shorter
    than delta.

    A nominal with a ``tail`` (:class:`~nhstab.nominal.Nominal`: a feasible continuation past its
    end) and a future window: the schedule is computed on the nominal continued by its tail over
    delta, on the same grid step, and kept on the nominal's own grid, so that every window inside it
    is whole and the end strategy never applies there.
    """
    if not isinstance(nominal, Nominal):
        raise InputError("nominal", "a Nominal (nhstab.Nominal.from_samples, or a plan's nominal)",
                         type(nominal).__name__)
    if options is None:
        options = StabilizerOptions()
    if not isinstance(options, StabilizerOptions):
        raise InputError("options", "a StabilizerOptions or None", type(options).__name__)
    if overrides:
        options = StabilizerOptions(**{**options.__dict__, **overrides})
    opts = options.validated()
    if opts.window == "past":
        warnings.warn(PAST_WINDOW_WARNING, NotStabilizingWarning, stacklevel=2)
    if opts.cusps == "split" and opts.window == "future":
        nom = nominal if nominal.is_uniform() else nominal.resampled(len(nominal.t))
        stops = cusp_stop_indices(nom)
        if stops:
            return _split_schedule(nominal, nom, stops, opts)
    tail = getattr(nominal, "tail", None)
    if tail is not None and opts.window == "future":
        return _with_tail(nominal, tail, opts)
    nom = nominal if nominal.is_uniform() else nominal.resampled(len(nominal.t))
    model = nom.model
    n = model.n
    t = nom.t
    N = len(t)
    T = nom.duration
    h = T / (N - 1)
    delta = float(opts.delta)
    future = opts.window == "future"
    frozen_time = opts.window == "frozen-time"
    if delta > T * (1.0 + 1e-12) and not frozen_time:
        raise InputError("delta", f"at most the trajectory duration {T:.6g} s", delta)
    if not frozen_time:                   # the frozen-time window is not a stretch of the nominal
        delta = min(delta, T)
    cw = float(opts.weight) * float(opts.alpha)
    w = int(math.floor(delta / h + 1e-9))
    phi = delta - w * h
    if phi <= 1e-9 * h:
        phi = 0.0
    n_full = min(N, int(math.floor((T - delta) / h + 1e-9)) + 1)   # points with t + delta <= T
    i_min = N - n_full                                              # first point with t - delta >= t0
    replace(opts, delta=delta).check_step(h)
    substeps = max(1, int(math.ceil(h / (opts.max_substep_fraction * delta) - 1e-9)))

    gamma = opts.gamma_on(t)
    frozen_info = None
    end = "none: every window fits" if n_full == N else opts.end_strategy
    if frozen_time:
        end = "none: the frozen-time window is not a stretch of the nominal"
        H, frozen_info = frozen_time_schedule(nom, cw, delta, gamma, float(opts.max_gain), float(opts.singular_rtol),
                                              float(opts.singular_atol), substeps)
    else:
        E = interval_segments(nom, t[:-1], h, cw, substeps)             # K = N - 1 start-anchored pieces
        H = np.empty((N, n, n))
        if future:
            H[:n_full] = _future_windows(nom, E, w, phi, n_full, cw, substeps).W
            if n_full < N:
                extended = None
                if opts.end_strategy == "extend":
                    extended, end = _extended_windows(nom, E, w, phi, cw, substeps, opts, future=True, first=n_full)
                if extended is not None:
                    H[n_full:] = extended
                else:
                    H[n_full:] = _frozen_end(nom, E, n_full, delta, cw, substeps)
        else:
            # past windows for i = i_min .. N-1, computed in reversed order
            H[i_min:] = _past_windows(nom, E, w, phi, n_full, cw, substeps).W[::-1]
            if i_min > 0:
                extended = None
                if opts.end_strategy == "extend":
                    extended, end = _extended_windows(nom, E, w, phi, cw, substeps, opts, future=False)
                if extended is not None:
                    H[:i_min] = extended[:i_min]
                else:
                    H[:i_min] = _frozen_start(nom, E, w, phi, i_min, cw, substeps)

    H = 0.5 * (H + np.swapaxes(H, -1, -2))
    if not np.all(np.isfinite(H)):
        k = int(np.argmax(~np.all(np.isfinite(H), axis=(1, 2))))
        raise NumericalError(f"the window gramian is not finite at t = {t[k]:.6g} s")
    lam, V = np.linalg.eigh(H)
    thresholds = np.maximum(float(opts.singular_atol), float(opts.singular_rtol) * np.abs(lam[:, -1]))
    bad = lam[:, 0] <= thresholds
    if bad.any():
        k = int(np.argmax(bad))
        rank = int(np.sum(lam[k] > thresholds[k]))
        raise SingularGramianError(t[k], lam[k, 0], rank, n, thresholds[k], opts.window)
    P = (V / lam[:, None, :]) @ transposed(V)
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    B = model.g(nom.x)
    K = gamma[:, None, None] * (np.swapaxes(B, -1, -2) @ P)

    schedule = GainSchedule(t=t.copy(), H=H, P=P, K=K, H_eigenvalues=lam, gamma=gamma, options=opts, nominal=nom)
    schedule.diagnostics = {
        **opts.describe(),
        "model": model.name,
        "grid_points": N, "grid_step_s": h, "duration_s": T,
        "window_intervals": w, "window_fraction_s": phi, "substeps": substeps,
        "sliding_window_until_s": float(t[n_full - 1]) if future else None,
        "sliding_window_from_s": float(t[i_min]) if opts.window == "past" else None,
        "end": end,
    }
    if frozen_info is not None:
        schedule.diagnostics["frozen_time"] = frozen_info
    schedule.diagnostics.update(schedule.diagnose(lyapunov=False))
    return schedule


def cusp_stop_indices(nominal: Nominal, rel_eps: float = 1e-9) -> list[tuple[int, int]]:
    """The nominal's cusp stops as grid index ranges (first, last point at rest): the points between two
    moving points whose directions of travel (the velocity along the heading) have opposite signs. For
    models with a planar pose (x, y, theta); none for others."""
    names = list(nominal.model.state_names)
    if not all(k in names for k in ("x", "y", "theta")):
        return []
    ix, iy, ith = names.index("x"), names.index("y"), names.index("theta")
    xd = nominal.model.rhs(nominal.x, nominal.u)
    along = xd[:, ix] * np.cos(nominal.x[:, ith]) + xd[:, iy] * np.sin(nominal.x[:, ith])
    scale = float(np.abs(along).max()) if len(along) else 0.0
    moving = np.flatnonzero(np.abs(along) > rel_eps * max(scale, 1e-300))
    if scale <= 0.0 or moving.size < 2:
        return []
    flips = np.flatnonzero(np.diff(np.sign(along[moving])) != 0)
    return [(int(moving[f]) + 1, int(moving[f + 1]) - 1) for f in flips]


def _split_schedule(nominal: Nominal, nom: Nominal, stops: list, opts: StabilizerOptions) -> GainSchedule:
    """Proposition 1 on each cusp-free segment of the nominal (``cusps="split"``).

    With one schedule for the whole plan, the future window looks across a cusp: it holds motion in both
    directions at several steering angles, so a small back-and-forth of the speed is the cheapest way
    the gramian finds to remove a lateral or heading error, and the law puts large speed gains on those
    errors (17 on the lateral error at a parallel slot's cusp, where its gain on the error along the path
    is about 1): under process noise the car surges along its path while it stops at the cusp, next to
    the parked cars. Here the nominal is cut at its cusps: each segment ends with its cusp stop and gets
    the paper's own schedule, P = H_c(t, t + delta)^-1, K = gamma B^T P, with whole windows that never
    cross a cusp: past its end a segment continues by the motion it is in (the ``extend`` end's
    continuation, driving on under the last real input with the steering rate zeroed, as the segment's
    tail, so that segments shorter than delta work too). The stop (the robot at rest, steering in place)
    belongs to the segment that ends in it, with P held at its value where the robot stopped: along the
    stop A(t) = 0, so this is the frozen end (H carried along the flow, Phi = I) and V = e^T P e does
    not increase there. The last segment ends with ``end_strategy``. The 3 alpha guarantee holds
    within each segment; none is claimed across a cusp (V can jump where the next segment's P takes
    over): ``diagnostics["guarantee_until_s"]`` is the first cusp."""
    import dataclasses as _dc

    h = float(nom.t[1] - nom.t[0])
    N, n, m = len(nom.t), nom.model.n, nom.model.m
    bounds = [0] + [b for _, b in stops] + [N - 1]
    H, P = np.empty((N, n, n)), np.empty((N, n, n))
    K, lam, gamma = np.empty((N, m, n)), np.empty((N, n)), np.empty(N)
    segments = []
    single = _dc.replace(opts, cusps="across")
    for k in range(len(bounds) - 1):
        i0, i1 = bounds[k], bounds[k + 1]
        last = k == len(bounds) - 2
        seg = Nominal.from_functions(nom.model, nom._x_func, nom._u_func, nom.t[i0:i1 + 1])
        seg_opts = _dc.replace(single, end_strategy="frozen")
        own_tail = getattr(nominal, "tail", None) if last else None
        if own_tail is not None:                       # the plan's own continuation past its end
            seg.tail, end = own_tail, "the plan's tail"
        elif last and opts.end_strategy == "frozen":
            seg_opts = _dc.replace(seg_opts, delta=min(float(opts.delta), float(seg.t[-1] - seg.t[0])))
            end = f"frozen (delta {seg_opts.delta:.4g} s)"
        else:                                          # into the cusp, or the plan's end with extend
            cont = _continuation(seg, float(opts.delta) + 2.0 * h, True)
            if isinstance(cont, str):          # no continuation: the segment's own windows, shortened to fit
                seg_opts = _dc.replace(seg_opts, delta=min(float(opts.delta), float(seg.t[-1] - seg.t[0])))
                end = f"no continuation ({cont}); delta {seg_opts.delta:.4g} s"
            else:
                t_rel, dense, u_held, what = cont
                T = float(seg.t[-1])
                seg.tail = Nominal.from_functions(
                    seg.model, lambda tau, dense=dense, T=T: np.asarray(dense(np.asarray(tau, float) - T)).T,
                    lambda tau, u_held=u_held: np.broadcast_to(u_held, np.shape(tau) + (len(u_held),)).copy(),
                    T + np.concatenate([[0.0], t_rel]))
                end = f"extend ({what})"
        sch = compute_schedule(seg, seg_opts)
        Hs, Ps, Ks, ls = sch.H.copy(), sch.P.copy(), sch.K.copy(), sch.H_eigenvalues.copy()
        if not last:                                   # the cusp stop: P held from where the robot stopped
            a = stops[k][0] - i0
            Hs[a:], Ps[a:], ls[a:] = Hs[a - 1], Ps[a - 1], ls[a - 1]
            B = nom.model.g(nom.x[i0 + a:i1 + 1])
            Ks[a:] = sch.gamma[a:, None, None] * (np.swapaxes(B, -1, -2) @ Ps[a - 1])
        lo = i0 if k == 0 else i0 + 1                  # the shared point belongs to the earlier segment
        sl = slice(lo - i0, None)
        H[lo:i1 + 1], P[lo:i1 + 1], K[lo:i1 + 1] = Hs[sl], Ps[sl], Ks[sl]
        lam[lo:i1 + 1], gamma[lo:i1 + 1] = ls[sl], sch.gamma[sl]
        segments.append({"t0_s": float(nom.t[i0]), "t1_s": float(nom.t[i1]),
                         "stop_s": None if last else [float(nom.t[stops[k][0]]), float(nom.t[stops[k][1]])],
                         "end": end,
                         "max_gain_norm": float(sch.diagnostics["max_gain_norm"])})
    schedule = GainSchedule(t=nom.t.copy(), H=H, P=P, K=K, H_eigenvalues=lam, gamma=gamma, options=opts, nominal=nom)
    first_cusp = float(nom.t[stops[0][0]])
    schedule.diagnostics = {
        **opts.describe(), "model": nom.model.name, "grid_points": N, "grid_step_s": h,
        "duration_s": float(nom.t[-1] - nom.t[0]), "sliding_window_until_s": first_cusp,
        "sliding_window_from_s": None, "end": segments[-1]["end"],
        "segments": segments, "guarantee_until_s": float(nom.t[stops[0][1]]),
        "cusps_note": "one schedule per cusp-free segment: the 3 alpha guarantee within each, none across a cusp"}
    schedule.diagnostics.update(schedule.diagnose(lyapunov=False))
    return schedule


def _with_tail(nominal: Nominal, tail: Nominal, opts: StabilizerOptions) -> GainSchedule:
    """The future-window schedule of ``nominal`` computed on it continued by ``tail`` (over delta, or
    all of the tail if shorter), restricted to the nominal's grid."""
    nom = nominal if nominal.is_uniform() else nominal.resampled(len(nominal.t))
    h = float(nom.t[1] - nom.t[0])
    T = float(nom.t[-1])
    extra = int(math.ceil(min(float(opts.delta), float(tail.t[-1] - tail.t[0])) / h - 1e-9))
    if extra < 1:
        return compute_schedule(nom, opts)
    t_ext = np.concatenate([nom.t, T + h * np.arange(1, extra + 1)])
    t_ext[-1] = min(t_ext[-1], T + float(tail.t[-1] - tail.t[0]))
    shift = float(tail.t[0]) - T

    def x_func(tau):
        tau = np.asarray(tau, dtype=float)
        return np.where((tau <= T)[..., None], nom.at(np.minimum(tau, T))[0], tail.at(np.maximum(tau, T) + shift)[0])

    def u_func(tau):
        tau = np.asarray(tau, dtype=float)
        return np.where((tau <= T)[..., None], nom.at(np.minimum(tau, T))[1], tail.at(np.maximum(tau, T) + shift)[1])

    joined = Nominal.from_functions(nom.model, x_func, u_func, t_ext)
    full = compute_schedule(joined, opts)
    N = len(nom.t)
    schedule = GainSchedule(t=nom.t.copy(), H=full.H[:N], P=full.P[:N], K=full.K[:N],
                            H_eigenvalues=full.H_eigenvalues[:N], gamma=full.gamma[:N], options=opts, nominal=nom)
    tail_s = float(t_ext[-1] - T)
    schedule.diagnostics = {**full.diagnostics, "grid_points": N, "duration_s": T,
                            "tail_s": tail_s, **schedule.diagnose(lyapunov=False)}
    if tail_s >= float(opts.delta) - 1e-9 * h:
        # the joined nominal's end strategy acted past T only, on windows that are not kept
        schedule.diagnostics["end"] = (f"none: every window fits (the nominal's own continuation covers "
                                       f"delta = {float(opts.delta):g} s past its end)")
        schedule.diagnostics["sliding_window_until_s"] = T
    return schedule


# ---- the window families -------------------------------------------------------------------------

def _future_windows(nom: Nominal, E: Segments, w: int, phi: float, count: int, cw: float, substeps: int,
                    first: int = 0) -> Segments:
    """Start-anchored windows [t_i, t_i + delta] for i = first .. first + count - 1."""
    R = sliding(E[first:] if first else E, w, -cw)[:count]
    if phi > 0.0:
        frac = interval_segments(nom, nom.t[first + w:first + w + count], phi, cw, substeps)
        R = combine(R, frac, -cw)
    return R


def _past_windows(nom: Nominal, E: Segments, w: int, phi: float, count: int, cw: float, substeps: int) -> Segments:
    """End-anchored windows [t_i - delta, t_i] for i = N-1, N-2, ..., N-count (reversed order)."""
    N = len(nom.t)
    Er = to_end_anchored(E, cw)[::-1]
    R = sliding(Er, w, cw)[:count]                   # R[k] is the window ending at t_{N-1-k}
    if phi > 0.0:
        ends = nom.t[N - 1 - np.arange(count) - w]   # t_{i-w}
        frac = to_end_anchored(interval_segments(nom, ends - phi, phi, cw, substeps), cw)
        R = combine(R, frac, cw)
    return R


def _held_inputs(nom: Nominal, future: bool):
    """The inputs the continuation may hold past the end (``future``) or before the start, in order of
    preference: a list of (input, what it is), or a reason why there is none.

    The input there, if it moves the robot's pose (and then the same with the steering rate zeroed,
    in case holding it would steer past the limit). Where the robot is at rest there (its input is
    zero, or it only drives states with limits, as a car steering its wheels straight in place before
    it stops), the continuation drives on as the robot last really moved: the input of the last
    (first) grid point where the pose moved at least half as fast as anywhere on the nominal, with the
    inputs that act only on limited states (the steering rate) set to zero, so that the car drives on
    at its final steering angle."""
    model = nom.model
    i = -1 if future else 0
    x_end, u_end = nom.x[i], nom.u[i]
    lim = model.state_limits()
    limited = np.all(np.isfinite(lim), axis=1)                       # e.g. a car's steering angle
    acts = np.abs(np.asarray(model.g(x_end))) > 1e-12                # (n, m): which input drives which state
    steering_only = acts.any(axis=0) & ~np.any(acts & ~limited[:, None], axis=0)
    scale = max(float(np.max(np.abs(nom.u))), 1e-300)
    nonzero = np.abs(u_end) > 1e-9 * scale
    end = "last" if future else "first"
    if np.any(nonzero & ~steering_only):
        out = [(u_end, f"its {end} input")]
        if np.any(nonzero & steering_only):
            out.append((np.where(steering_only, 0.0, u_end), f"its {end} input with the steering rate zeroed"))
        return out
    speed = np.linalg.norm(model.rhs(nom.x, nom.u)[:, ~limited], axis=1)
    moving = np.flatnonzero(speed >= 0.5 * speed.max()) if speed.max() > 0 else np.array([], dtype=int)
    if not moving.size:
        return f"frozen: the nominal's {end} input is zero and it never moves (the robot stands still)"
    j = int(moving[-1] if future else moving[0])
    u = np.where(steering_only, 0.0, nom.u[j])
    at_rest = "steers in place" if np.any(nonzero) else "stands still"
    return [(u, f"its {end} real move (the robot {at_rest} at its {'end' if future else 'start'}; the input "
                f"at t = {nom.t[j]:.6g} s with the steering rate zeroed)")]


def _continuation(nom: Nominal, length: float, future: bool):
    """The nominal continued past its end (``future``) or before its start under the first usable
    input of :func:`_held_inputs` held, on the nominal's grid step, at least ``length`` long: (times,
    dense states, input, what was held) or a reason why it is unusable (the robot never moves, or
    every continuation leaves the model's state limits)."""
    from scipy.integrate import solve_ivp

    model = nom.model
    h = float(nom.t[1] - nom.t[0])
    k = int(math.ceil(length / h - 1e-9))
    x_end = nom.x[-1] if future else nom.x[0]
    held = _held_inputs(nom, future)
    if isinstance(held, str):
        return held
    sign = 1.0 if future else -1.0
    t_rel = sign * h * np.arange(1, k + 1)
    lim = model.state_limits()
    why = None
    for u_end, what in held:
        sol = solve_ivp(lambda _, x: model.rhs(x, u_end), (0.0, t_rel[-1]), x_end, method="DOP853",
                        t_eval=t_rel, dense_output=True, rtol=1e-12, atol=1e-13)
        if not sol.success or not np.all(np.isfinite(sol.y)):
            why = why or "frozen: the continuation under the held input could not be integrated"
            continue
        out = (sol.y.T < lim[:, 0] - 1e-9) | (sol.y.T > lim[:, 1] + 1e-9)
        if np.any(out):
            j = int(np.argmax(np.any(out, axis=1)))
            why = why or (f"frozen: the continuation under the held input leaves the state limits after "
                          f"{abs(t_rel[j]):.3g} s (shorter than delta)")
            continue
        return t_rel, sol.sol, u_end, what
    return why


def _extended_windows(nom: Nominal, E: Segments, w: int, phi: float, cw: float, substeps: int,
                      opts: StabilizerOptions, future: bool, first: int = 0):
    """The window gramians at the grid points of ``nom`` (future windows: from index ``first`` on, the
    ones that run off its end; past windows: every point), the windows that run off its end (or start)
    continued along :func:`_continuation`; (H (N - first, n, n), what was done) or (None, why not)."""
    N = len(nom.t)
    h = float(nom.t[1] - nom.t[0])
    cont = _continuation(nom, (w + 1) * h, future)
    if isinstance(cont, str):
        return None, cont
    t_rel, dense, u_held, what = cont
    model = nom.model
    k = len(t_rel)
    T_edge = float(nom.t[-1] if future else nom.t[0])
    t_all = np.concatenate([nom.t, T_edge + t_rel]) if future else np.concatenate([T_edge + t_rel[::-1], nom.t])

    def x_func(tau):
        tau = np.asarray(tau, dtype=float)
        out = np.empty(tau.shape + (model.n,))
        inside = (tau <= T_edge) if future else (tau >= T_edge)
        if inside.any():
            out[inside] = nom.at(tau[inside])[0]
        if (~inside).any():
            out[~inside] = np.asarray(dense(tau[~inside] - T_edge)).T
        return out

    def u_func(tau):
        tau = np.asarray(tau, dtype=float)
        out = np.empty(tau.shape + (model.m,))
        inside = (tau <= T_edge) if future else (tau >= T_edge)
        if inside.any():
            out[inside] = nom.at(tau[inside])[1]
        out[~inside] = u_held
        return out

    ext = Nominal(model, t_all, x_func(t_all), u_func(t_all), x_func=x_func, u_func=u_func, source="continued")
    if future:
        tail = interval_segments(ext, t_all[N - 1:-1], h, cw, substeps)
        E_all = Segments(np.concatenate([E.P, tail.P]), np.concatenate([E.W, tail.W]), np.concatenate([E.d, tail.d]))
        H = _future_windows(ext, E_all, w, phi, N - first, cw, substeps, first).W
    else:
        head = interval_segments(ext, t_all[:k], h, cw, substeps)
        E_all = Segments(np.concatenate([head.P, E.P]), np.concatenate([head.W, E.W]), np.concatenate([head.d, E.d]))
        H = _past_windows(ext, E_all, w, phi, N, cw, substeps).W[::-1]
    H = 0.5 * (H + np.swapaxes(H, -1, -2))
    lam = np.linalg.eigvalsh(H)
    if not np.all(np.isfinite(lam)) or np.any(lam[:, 0] <= np.maximum(float(opts.singular_atol),
                                                                      float(opts.singular_rtol) * np.abs(lam[:, -1]))):
        return None, "frozen: the window along the continuation is singular"
    where = "past its end" if future else "before its start"
    return H, f"extend: the nominal continued {k * h:.6g} s {where} under {what} held"


def _carry(G: np.ndarray, Phi_back: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Carry a gramian G given at time a along the linearised flow to times t:
    scale * Phi(t, a) G Phi(t, a)^T, given Phi_back = Phi(a, t)."""
    F = np.linalg.inv(Phi_back)
    return scale * (F @ G @ transposed(F))


def _frozen_end(nom: Nominal, E: Segments, n_full: int, delta: float, cw: float, substeps: int) -> np.ndarray:
    """H_c(s, T), s = T - delta, carried to each t_i > s (i = n_full .. N-1)."""
    t = nom.t
    a = t[-1] - delta
    j0 = n_full - 1                                   # t_j0 <= a < t_{j0+1}
    piece = interval_segments(nom, np.array([a]), np.array([t[j0 + 1] - a]), cw, substeps)
    chain = Segments(np.concatenate([piece.P, E.P[j0 + 1:]]), np.concatenate([piece.W, E.W[j0 + 1:]]),
                     np.concatenate([piece.d, E.d[j0 + 1:]]))
    pref = scan(chain, -cw)                            # pref[q]: from a to t_{j0+1+q}
    return _carry(pref.W[-1], pref.P)


def _frozen_start(nom: Nominal, E: Segments, w: int, phi: float, i_min: int, cw: float, substeps: int) -> np.ndarray:
    """The past window at s = t0 + delta carried back to each t_i < s (i = 0 .. i_min-1).

    H_r(s) = exp(cw delta) Phi(s, t0) H_c(t0, s) Phi(s, t0)^T, so H(t) = exp(cw delta) Phi(t, t0) H_c(t0, s) Phi(t, t0)^T.
    """
    G = _future_windows(nom, E, w, phi, 1, cw, substeps).W[0]
    if i_min > 1:
        Phi_back = exclusive_prefix(E[: i_min - 1], -cw).P     # Phi(t0, t_i), i = 0 .. i_min-1
    else:
        Phi_back = np.eye(E.n)[None]
    return _carry(G, Phi_back, math.exp(cw * (w * (nom.t[1] - nom.t[0]) + phi)))
