"""Exact steering of chained-form systems with sinusoids (Murray & Sastry 1990/1993) and its use
for the Heisenberg system and the two kinematic cars.

Chained form (one chain, dimension n = 3 or 4)
----------------------------------------------
    z1' = v1,   z2' = v2,   z3' = z2 v1,   z4' = z3 v1.

Steering algorithm (:func:`steer_chained`), total time T split into n - 1 phases (equal lengths
unless ``phase_fractions`` is given):

1. *Constant phase* of length T1: v1 = (z1f - z1)/T1, v2 = (z2f - z2)/T1. z1 and z2 reach their
   targets; z3, z4 drift by the closed-form amounts of :func:`_constant_phase`.
2. *Sinusoidal phase for z_k*, k = 3, ..., n, one period P = 2 pi / w of
       v1 = a sin(w t),   v2 = b cos((k - 2) w t)          (t measured from the phase start).
   Its net motion over the period (derived in :func:`net_displacement`, independent of the start
   state) is
       k = 3:  dz1 = dz2 = 0,  dz3 = pi a b / w^2,         dz4 = -pi a^2 b / w^3,
       k = 4:  dz1 = dz2 = dz3 = 0,                        dz4 = pi a^2 b / (4 w^3),
   i.e. the Murray-Sastry formula dz_k = (a / 2w)^(k-2) b / (k-2)! * 2 pi / w, plus the drift
   the z3 phase induces in z4. Phase k = 3 is solved first for the z3 error left by phase 1; its
   z4 drift is added to the z4 error before phase k = 4 is solved.

Amplitude choice. The phase-k equation fixes only a^(k-2) b = c_k (c_3 = dz3 w^2 / pi,
c_4 = 4 dz4 w^3 / pi). ``amplitude="balanced"`` (default) takes a = beta |b| >= 0 with
sign(b) = sign(c_k), so |b| = (|c_k| / beta^(k-2))^(1/(k-1)) (``balance`` beta = 1 by default:
|a| = |b|); a positive number fixes a and gives b = c_k / a^(k-2).

Every phase integrates in closed form, so :class:`SteeringPlan` evaluates states and inputs
exactly (round-off only) at any time.

Constant-v1 steering (:func:`steer_chained_constant_v1`)
--------------------------------------------------------
In the phased algorithm v1 = a sin(w t) changes sign, so a car drives back and forth in every
phase. This mode keeps v1 constant over the whole time T and puts the correction into v2 alone
(Murray & Sastry also steer with u1 constant and a sinusoid/polynomial series in u2):
    v1 = c = (z1f - z1s) / T,   v2 = b0 + b1 cos(w t) + b2 sin(w t),   w = 2 pi / T.
With S = sin(w t) and C = 1 - cos(w t) the chained equations integrate in closed form
(:func:`_constant_v1_phase`):
    z1 = z1s + c t,
    z2 = z2s + b0 t + (b1 S + b2 C) / w,
    z3 = z3s + c (z2s t + b0 t^2/2 + b1 C / w^2 + b2 (t - S/w) / w),
    z4 = z4s + c (z3s t + c (z2s t^2/2 + b0 t^3/6 + b1 (t - S/w) / w^2 + b2 (t^2/2 - C/w^2) / w)).
At t = T (S = C = 0, w T = 2 pi) the targets are linear in b = (b0, b1, b2):
    [ T          0          0           ] [b0]   [e2 = z2f - z2s                              ]
    [ c T^2/2    0          c T/w       ] [b1] = [e3 = z3f - z3s - c T z2s                    ]
    [ c^2 T^3/6  c^2 T/w^2  c^2 T^2/(2w)] [b2]   [e4 = z4f - z4s - c T z3s - c^2 T^2 z2s / 2 ]
whose determinant is T (0 * c^2 T^2/(2w) - (c T/w)(c^2 T/w^2)) = -c^3 T^3 / w^3
= -c^3 T^6 / (8 pi^3): nonsingular exactly when c != 0, i.e. when z1 has to move. It is triangular
after swapping columns 2 and 3, so
    b0 = e2 / T,   b2 = (w / T) (e3 / c - b0 T^2/2),   b1 = (w^2 / T) (e4 / c^2 - b0 T^3/6 - b2 T^2/(2w)).
For n = 3 the z4 row drops out: b1 = 0 and v2 = b0 + b2 sin(w t) (2 x 2 determinant c T^2 / w).
Time scaling: with tau = t / T the states depend on (c T, b T) only and the solution has b ~ 1/T,
so a longer T traces the same path with inputs divided by T (as the phased plans do).

Cars in chained form (valid for |theta| < pi/2 and |phi| < pi/2)
---------------------------------------------------------------
Both cars move their rear-axle midpoint with body speed s along the heading and turn with
theta' = tan(phi) s / L: the rear-wheel-drive car has s = v, the front-wheel-drive car of eq. (12)
has s = cos(phi) u1 (x' = cos(phi) cos(theta) u1 = cos(theta) s, theta' = sin(phi) u1 / L =
tan(phi) s / L). Hence the same chained coordinates serve both:
    z1 = x,  z2 = tan(phi) / (L cos^3 theta),  z3 = tan(theta),  z4 = y,
    v1 = cos(theta) s,  v2 = z2'.
Check: z1' = cos(theta) s = v1; z4' = sin(theta) s = tan(theta) v1 = z3 v1;
z3' = theta' / cos^2 theta = tan(phi) s / (L cos^2 theta) = z2 v1.
Differentiating z2:
    z2' = phi' / (L cos^2 phi cos^3 theta) + 3 tan(phi) sin(theta) theta' / (L cos^4 theta)
        = omega_s / (L cos^2 phi cos^3 theta) + 3 z2^2 z3 v1 / (1 + z3^2)
(using tan(phi) = L z2 cos^3 theta and s = v1 / cos theta), so the model inputs are
    s = v1 / cos(theta) = v1 sqrt(1 + z3^2),
    omega_s = L cos^2(phi) cos^3(theta) (v2 - 3 z2^2 z3 v1 / (1 + z3^2)),
with v = s (rwd_car) or u1 = s / cos(phi) (fwd_car), and the inverse state map
theta = arctan z3, phi = arctan(L z2 cos^3 theta).

Local frames. The chart is singular at theta = +-pi/2, so :func:`steer_car` expresses both poses
in a frame (origin, heading alpha), steers there, checks that |theta - alpha| stays below
``theta_limit`` (default 1.2 rad) along the whole steered path, and maps the path back.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import InputError, require_finite, require_positive
from ..geometry import wrap_angle

__all__ = [
    "SteeringPlan", "SteeringPhase", "CarSteering", "STEERING_MODES",
    "chained_rhs", "net_motion", "net_displacement", "steer_chained", "steer_chained_constant_v1", "steer_heisenberg",
    "to_chained", "from_chained", "car_inputs_from_chained", "chained_inputs_from_car", "steer_car",
]

_TWO_PI = 2.0 * math.pi
#: the chained-form steering methods: the phased sinusoids of :func:`steer_chained` and the constant-v1
#: sinusoid of :func:`steer_chained_constant_v1`
STEERING_MODES = ("phased", "constant_v1")


# ---------------------------------------------------------------------------------------------
# validation helpers
# ---------------------------------------------------------------------------------------------
def _vector(name: str, value, sizes: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, f"a vector of length {' or '.join(map(str, sizes))}", value) from None
    if arr.ndim != 1 or arr.shape[0] not in sizes:
        raise InputError(name, f"a vector of length {' or '.join(map(str, sizes))}",
                         f"shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(name, "finite values", value)
    return arr.copy()


def _array(name: str, value, last: int | None = None, min_last: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, "a numeric array", value) from None
    if arr.ndim == 0:
        raise InputError(name, "an array with a last axis", f"shape {arr.shape}")
    if last is not None and arr.shape[-1] != last:
        raise InputError(name, f"an array with last axis of length {last}", f"shape {arr.shape}")
    if min_last is not None and arr.shape[-1] < min_last:
        raise InputError(name, f"an array with last axis of length >= {min_last}", f"shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(name, "finite values", "non-finite entries")
    return arr




# ---------------------------------------------------------------------------------------------
# chained form
# ---------------------------------------------------------------------------------------------
def chained_rhs(z, v):
    """z' of the one-chain form z1' = v1, z2' = v2, z_k' = z_(k-1) v1 (k >= 3); vectorised.

    ``z`` has shape (..., n) with n >= 2, ``v`` shape (..., 2); the result has the broadcast shape
    (..., n).
    """
    z = _array("z", z, min_last=2)
    v = _array("v", v, last=2)
    shape = np.broadcast_shapes(z.shape[:-1], v.shape[:-1]) + (z.shape[-1],)
    out = np.empty(shape)
    out[..., 0] = v[..., 0]
    out[..., 1] = v[..., 1]
    out[..., 2:] = z[..., 1:-1] * v[..., 0:1]
    return out


def _check_phase_args(k, a, b, w, z_start):
    z = _vector("z_start", z_start, (3, 4))
    n = z.shape[0]
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 3 <= int(k) <= n:
        raise InputError("k", f"an integer in 3..{n} (the chained dimension is {n})", k)
    return int(k), require_finite("a", a), require_finite("b", b), require_positive("w", w), z


def net_displacement(k: int, a: float, b: float, w: float, z_start) -> np.ndarray:
    """Change of the whole chained state over one period P = 2 pi / w of phase k.

    Phase k applies v1 = a sin(w t), v2 = b cos((k - 2) w t), t in [0, P], from ``z_start``
    (length n = 3 or 4, 3 <= k <= n). Closed form, derived from the chained equations with
    c = cos(w t), s = sin(w t) (see :func:`_sin_phase` for the full time laws):

    * k = 3: z1 = z1s + (a/w)(1 - c), z2 = z2s + (b/w) s,
      z3 = z3s + z2s (a/w)(1 - c) + (a b / w)(t/2 - sin(2wt)/(4w))      -> dz3 = pi a b / w^2,
      z4 = z4s + z3s (a/w)(1 - c) + z2s (a/w)^2 (1 - c - s^2/2)
               + (a^2 b / w)(-t c/(2w) + s/(2w^2) - s^3/(6w^2))          -> dz4 = -pi a^2 b / w^3.
    * k = 4: z2 = z2s + (b/w) s c, z3 = z3s + z2s (a/w)(1 - c) + a b s^3 / (3 w^2)  -> dz3 = 0,
      z4 = ... + (a^2 b / (3 w^2)) int_0^t sin^4 = ... -> dz4 = (a^2 b/(3w^2)) (3 pi/(4 w))
      = pi a^2 b / (4 w^3).

    All start-state terms vanish over a full period, so the result does not depend on
    ``z_start`` (only its length n is used).
    """
    k, a, b, w, z = _check_phase_args(k, a, b, w, z_start)
    n = z.shape[0]
    d = np.zeros(n)
    if k == 3:
        d[2] = math.pi * a * b / w**2
        if n == 4:
            d[3] = -math.pi * a * a * b / w**3
    else:  # k == 4
        d[3] = math.pi * a * a * b / (4.0 * w**3)
    return d


def net_motion(k: int, a: float, b: float, w: float, z_start) -> float:
    """Change of z_k (1-based, k = 3 or 4) over one period of v1 = a sin(w t), v2 = b cos((k-2) w t).

    Murray-Sastry closed form: dz_k = (a / (2 w))^(k-2) * b / (k-2)! * 2 pi / w, i.e.
    pi a b / w^2 for k = 3 and pi a^2 b / (4 w^3) for k = 4 (derivation in
    :func:`net_displacement`), whatever ``z_start``; ``z_start`` (length 3 or 4) fixes the
    dimension, so k <= len(z_start).
    """
    k_checked = _check_phase_args(k, a, b, w, z_start)[0]
    return float(net_displacement(k, a, b, w, z_start)[k_checked - 1])


# ---- closed-form phase laws ---------------------------------------------------------------------
def _constant_phase(zs: np.ndarray, v1: float, v2: float, t: np.ndarray, coords: int | None = None) -> np.ndarray:
    """States under constant inputs: z2 = z2s + v2 t, z3 = z3s + v1 (z2s t + v2 t^2/2),
    z4 = z4s + v1 (z3s t + v1 (z2s t^2/2 + v2 t^3/6)); only the first ``coords`` (>= 3) of them
    if given. ``zs`` (n, ...) and the inputs may also hold one phase per time (arrays shaped as t)."""
    n = zs.shape[0] if coords is None else coords
    out = np.empty(t.shape + (n,))
    out[..., 0] = zs[0] + v1 * t
    out[..., 1] = zs[1] + v2 * t
    out[..., 2] = zs[2] + v1 * (zs[1] * t + 0.5 * v2 * t**2)
    if n == 4:
        out[..., 3] = zs[3] + v1 * (zs[2] * t + v1 * (0.5 * zs[1] * t**2 + v2 * t**3 / 6.0))
    return out


def _sin_phase(zs: np.ndarray, k: int, a: float, b: float, w: float, t: np.ndarray,
               coords: int | None = None) -> np.ndarray:
    """States under v1 = a sin(w t), v2 = b cos((k-2) w t); formulas of :func:`net_displacement`;
    only the first ``coords`` (>= 3) of them if given. ``zs`` (n, ...) and a, b, w may also hold
    one phase per time (arrays shaped as t)."""
    n = zs.shape[0] if coords is None else coords
    c, s = np.cos(w * t), np.sin(w * t)
    one_c = 1.0 - c
    out = np.empty(t.shape + (n,))
    out[..., 0] = zs[0] + (a / w) * one_c
    if k == 3:
        out[..., 1] = zs[1] + (b / w) * s
        out[..., 2] = zs[2] + zs[1] * (a / w) * one_c + (a * b / w) * (0.5 * t - np.sin(2 * w * t) / (4 * w))
        if n == 4:
            out[..., 3] = (zs[3] + zs[2] * (a / w) * one_c + zs[1] * (a / w) ** 2 * (one_c - 0.5 * s * s)
                           + (a * a * b / w) * (-t * c / (2 * w) + s / (2 * w * w) - s**3 / (6 * w * w)))
    else:  # k == 4 (a 4-dimensional chain)
        out[..., 1] = zs[1] + (b / w) * s * c
        out[..., 2] = zs[2] + zs[1] * (a / w) * one_c + a * b * s**3 / (3 * w * w)
        if n == 4:
            sin4 = 0.375 * t - np.sin(2 * w * t) / (4 * w) + np.sin(4 * w * t) / (32 * w)  # int_0^t sin^4(w tau)
            out[..., 3] = (zs[3] + zs[2] * (a / w) * one_c + zs[1] * (a / w) ** 2 * (one_c - 0.5 * s * s)
                           + (a * a * b / (3 * w * w)) * sin4)
    return out


def _constant_v1_phase(zs: np.ndarray, c, b0, b1, b2, w, t: np.ndarray, coords: int | None = None) -> np.ndarray:
    """States under v1 = c, v2 = b0 + b1 cos(w t) + b2 sin(w t) (closed forms in the module docstring);
    only the first ``coords`` (>= 3) of them if given. The parameters may be arrays broadcasting with
    ``t`` (and ``zs`` of shape (n, ...) likewise)."""
    n = zs.shape[0] if coords is None else coords
    wt = w * t
    S, C = np.sin(wt), 1.0 - np.cos(wt)
    ramp = t - S / w                                        # int_0^t C
    out = np.empty(np.shape(t) + (n,))
    out[..., 0] = zs[0] + c * t
    out[..., 1] = zs[1] + b0 * t + (b1 * S + b2 * C) / w
    out[..., 2] = zs[2] + c * (zs[1] * t + 0.5 * b0 * t * t + b1 * C / (w * w) + b2 * ramp / w)
    if n == 4:
        out[..., 3] = zs[3] + c * (zs[2] * t + c * (0.5 * zs[1] * t * t + b0 * t**3 / 6.0 + b1 * ramp / (w * w)
                                                    + b2 * (0.5 * t * t - C / (w * w)) / w))
    return out


@dataclass(frozen=True)
class SteeringPhase:
    """One phase of a plan. ``kind`` is "constant" (inputs v1, v2), "sinusoid" (k, a, b, w) or
    "constant_v1" (v1 constant, v2(t) = v2 + v2_cos cos(w t) + v2_sin sin(w t))."""

    kind: str
    t0: float
    t1: float
    z_start: np.ndarray
    z_end: np.ndarray
    k: int = 0
    v1: float = 0.0
    v2: float = 0.0
    a: float = 0.0
    b: float = 0.0
    w: float = 0.0
    v2_cos: float = 0.0
    v2_sin: float = 0.0

    def inputs(self, tau: np.ndarray) -> np.ndarray:
        out = np.empty(tau.shape + (2,))
        if self.kind == "constant":
            out[..., 0] = self.v1
            out[..., 1] = self.v2
        elif self.kind == "constant_v1":
            out[..., 0] = self.v1
            out[..., 1] = self.v2 + self.v2_cos * np.cos(self.w * tau) + self.v2_sin * np.sin(self.w * tau)
        else:
            out[..., 0] = self.a * np.sin(self.w * tau)
            out[..., 1] = self.b * np.cos((self.k - 2) * self.w * tau)
        return out

    def states(self, tau: np.ndarray, coords: int | None = None) -> np.ndarray:
        if self.kind == "constant":
            return _constant_phase(self.z_start, self.v1, self.v2, tau, coords)
        if self.kind == "constant_v1":
            return _constant_v1_phase(self.z_start, self.v1, self.v2, self.v2_cos, self.v2_sin, self.w, tau, coords)
        return _sin_phase(self.z_start, self.k, self.a, self.b, self.w, tau, coords)


@dataclass(frozen=True)
class SteeringPlan:
    """A piecewise chained-form plan: ``mode`` "phased" (constant, then one sinusoid per higher
    coordinate) or "constant_v1" (one phase).

    ``phase_times`` holds the phase boundaries 0 = t_0 < t_1 < ... = T (n of them for "phased", 2 for
    "constant_v1"). Inputs are right-continuous at the boundaries (the value of the later phase; at T
    the last phase's).
    """

    z0: np.ndarray
    zf: np.ndarray
    T: float
    phase_times: np.ndarray
    phases: tuple[SteeringPhase, ...]
    amplitude: str | float = "balanced"
    mode: str = "phased"

    @property
    def n(self) -> int:
        return int(self.z0.shape[0])

    def _locate(self, t) -> tuple[np.ndarray, np.ndarray]:
        if isinstance(t, (float, int, np.floating, np.integer)) and not isinstance(t, bool):
            tf = float(t)   # fast path for ODE right-hand sides
            if not -1e-9 * max(self.T, 1.0) <= tf <= self.T * (1 + 1e-9) + 1e-9:
                raise InputError("t", f"times in [0, {self.T:g}]", tf)
            tf = min(max(tf, 0.0), self.T)
            return np.array(tf), np.array(bisect.bisect_right(self.phase_times[1:-1].tolist(), tf))
        t = np.asarray(t, dtype=float)
        if not np.all(np.isfinite(t)):
            raise InputError("t", "finite times", "non-finite entries")
        tol = 1e-9 * max(self.T, 1.0)
        if t.size and (t.min() < -tol or t.max() > self.T + tol):
            raise InputError("t", f"times in [0, {self.T:g}]", f"[{t.min():g}, {t.max():g}]")
        t = np.clip(t, 0.0, self.T)
        idx = np.searchsorted(self.phase_times[1:-1], t, side="right")
        return t, idx

    def _parts(self, idx: np.ndarray) -> list[tuple[SteeringPhase, slice | np.ndarray]]:
        """(phase, its times) for every phase holding some of the times with phase indices ``idx``:
        slices when the times are in order (a grid), boolean masks otherwise."""
        if idx.ndim == 1 and np.all(idx[1:] >= idx[:-1]):
            cuts = np.searchsorted(idx, np.arange(len(self.phases) + 1)).tolist()
            return [(ph, slice(a, b)) for ph, a, b in zip(self.phases, cuts[:-1], cuts[1:]) if b > a]
        masks = [(ph, idx == i) for i, ph in enumerate(self.phases)]
        return [(ph, m) for ph, m in masks if np.any(m)]

    def inputs(self, t) -> np.ndarray:
        """Chained inputs (v1, v2) at times t, shape t.shape + (2,)."""
        t, idx = self._locate(t)
        if idx.ndim == 0:
            ph = self.phases[int(idx)]
            return ph.inputs(t - ph.t0)
        out = np.empty(t.shape + (2,))
        for ph, sel in self._parts(idx):
            out[sel] = ph.inputs(t[sel] - ph.t0)
        return out

    def states(self, t, coords: int | None = None) -> np.ndarray:
        """Chained states at times t (exact closed form), shape t.shape + (n,); with ``coords``
        (3 <= coords <= n) only the first ``coords`` coordinates, shape t.shape + (coords,)."""
        t, idx = self._locate(t)
        if idx.ndim == 0:
            ph = self.phases[int(idx)]
            return ph.states(t - ph.t0, coords)
        out = np.empty(t.shape + (self.n if coords is None else coords,))
        for ph, sel in self._parts(idx):
            out[sel] = ph.states(t[sel] - ph.t0, coords)
        return out

    def grid(self, points_per_phase: int = 200) -> np.ndarray:
        """Time grid with ``points_per_phase`` points per phase (starting at its start) plus T."""
        ppp = _count("points_per_phase", points_per_phase)
        parts = [np.linspace(t0, t1, ppp, endpoint=False)
                 for t0, t1 in zip(self.phase_times[:-1], self.phase_times[1:])]
        return np.concatenate(parts + [np.array([self.T])])


def _count(name: str, value, minimum: int = 2) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise InputError(name, f"an integer >= {minimum}", value)
    return int(value)


def _amplitudes(k: int, c: float, amplitude, balance: float) -> tuple[float, float]:
    """Solve a^(k-2) b = c for (a, b) under the amplitude rule.

    "balanced": a = balance |b| >= 0, so balance^(k-2) |b|^(k-1) = |c| and sign(b) = sign(c).
    A number: a fixed, b = c / a^(k-2).
    """
    if amplitude == "balanced":
        bmag = (abs(c) / balance ** (k - 2)) ** (1.0 / (k - 1))
        return balance * bmag, (math.copysign(bmag, c) if c != 0.0 else 0.0)
    a = float(amplitude)
    return a, c / a ** (k - 2)


def steer_chained(z0, zf, T: float = 1.0, *, amplitude="balanced", balance: float = 1.0,
                  phase_fractions=None) -> SteeringPlan:
    """Murray-Sastry sinusoidal steering of the chained form from ``z0`` to ``zf`` in time ``T``.

    Phases (see the module docstring): constant inputs for z1, z2, then for k = 3..n one period
    of v1 = a sin(w t), v2 = b cos((k-2) w t) with w = 2 pi / (phase length). Amplitude
    equations (closed form, :func:`net_motion`):
        phase z3: pi a b / w^2 = z3f - z3(after phase 1)    -> a b = c3 = dz3 w^2 / pi;
                  it moves z4 by -pi a^2 b / w^3 (n = 4), which phase z4 also corrects;
        phase z4: pi a^2 b / (4 w^3) = z4f - z4(after phase z3) -> a^2 b = c4 = 4 dz4 w^3 / pi.
    ``amplitude``: "balanced" (a = ``balance`` * |b| >= 0, i.e. |a| = |b| for balance = 1) or a
    positive number fixing a. The chained form is invariant under z -> (z1/l, l z2, z3, z4/l),
    (v1, v2) -> (v1/l, l v2); balanced amplitudes in those scaled coordinates are balance = l^2
    in the original ones (:func:`steer_car` uses l = wheelbase, making the plan scale-aware).
    ``phase_fractions``: n - 1 positive weights of the phase lengths (default equal).
    A correction below 8 machine epsilons of the coordinate's size is treated as zero (idle phase).
    """
    z0, zf = _chained_pair(z0, zf)
    T = require_positive("T", T)
    balance = require_positive("balance", balance)
    if not (isinstance(amplitude, str) and amplitude == "balanced"):
        if isinstance(amplitude, str):
            raise InputError("amplitude", "'balanced' or a positive number", amplitude)
        amplitude = require_positive("amplitude", amplitude)
    n = z0.shape[0]
    if phase_fractions is None:
        frac = np.full(n - 1, 1.0 / (n - 1))
    else:
        frac = _vector("phase_fractions", phase_fractions, (n - 1,))
        if np.any(frac <= 0):
            raise InputError("phase_fractions", "positive weights", phase_fractions)
        frac = frac / frac.sum()
    times = np.concatenate([[0.0], np.cumsum(frac) * T])
    times[-1] = T

    phases: list[SteeringPhase] = []
    # phase 1: constant inputs
    t0, t1 = times[0], times[1]
    d1 = t1 - t0
    v1, v2 = (zf[0] - z0[0]) / d1, (zf[1] - z0[1]) / d1
    z_end = _constant_phase(z0, v1, v2, np.array(d1))
    z_end[0], z_end[1] = zf[0], zf[1]        # remove round-off in the steered coordinates
    phases.append(SteeringPhase("constant", t0, t1, z0.copy(), z_end, v1=v1, v2=v2))
    z = z_end
    # phases k = 3..n
    for k in range(3, n + 1):
        t0, t1 = times[k - 2], times[k - 1]
        w = _TWO_PI / (t1 - t0)
        dk = zf[k - 1] - z[k - 1]
        if abs(dk) <= 8.0 * np.finfo(float).eps * max(1.0, abs(zf[k - 1]), abs(z[k - 1])):
            dk = 0.0        # round-off sized correction: idle phase instead of (dk)^(1/(k-1)) motions
        c = dk * w**2 / math.pi if k == 3 else 4.0 * dk * w**3 / math.pi
        a, b = _amplitudes(k, c, amplitude, balance)
        z_end = z + net_displacement(k, a, b, w, z)
        z_end[: k] = zf[: k]                # exact by construction; remove round-off
        phases.append(SteeringPhase("sinusoid", t0, t1, z.copy(), z_end, k=k, a=a, b=b, w=w))
        z = z_end
    return SteeringPlan(z0=z0, zf=zf, T=T, phase_times=times, phases=tuple(phases), amplitude=amplitude)


def _chained_pair(z0, zf) -> tuple[np.ndarray, np.ndarray]:
    z0 = _vector("z0", z0, (3, 4))
    zf = _vector("zf", zf, (3, 4))
    if zf.shape != z0.shape:
        raise InputError("zf", f"a vector of the same length as z0 ({z0.shape[0]})", f"length {zf.shape[0]}")
    return z0, zf


def steer_chained_constant_v1(z0, zf, T: float = 1.0) -> SteeringPlan:
    """Steer the chained form from ``z0`` to ``zf`` in time ``T`` with v1 constant.

    One phase of v1 = c = (z1f - z1s) / T and v2 = b0 + b1 cos(w t) + b2 sin(w t), w = 2 pi / T, with
    (b0, b1, b2) the solution of the 3 x 3 linear system of the module docstring (determinant
    -c^3 T^6 / (8 pi^3); for n = 3, b1 = 0 and the 2 x 2 system in (b0, b2)). v1 never changes sign:
    its sign is the direction z1 moves. States and inputs are exact closed forms
    (:func:`_constant_v1_phase`), the end state equals ``zf`` up to round-off (set exactly in the
    plan's ``phases[0].z_end``). Refuses (:class:`InputError` on ``zf``) when z1f = z1s: then c = 0
    and the system is singular (z3, z4 cannot move).
    """
    z0, zf = _chained_pair(z0, zf)
    T = require_positive("T", T)
    n = z0.shape[0]
    if zf[0] == z0[0]:
        raise InputError("zf", "a z1 different from z0's (constant v1 = (z1f - z1s) / T must not vanish)", zf)
    w = _TWO_PI / T
    c = (zf[0] - z0[0]) / T
    e2 = zf[1] - z0[1]
    e3 = zf[2] - z0[2] - c * T * z0[1]
    b0 = e2 / T
    b2 = (w / T) * (e3 / c - 0.5 * b0 * T * T)
    b1 = 0.0
    if n == 4:
        e4 = zf[3] - z0[3] - c * T * z0[2] - 0.5 * (c * T) ** 2 * z0[1]
        b1 = (w * w / T) * (e4 / (c * c) - b0 * T**3 / 6.0 - b2 * T * T / (2.0 * w))
    phase = SteeringPhase("constant_v1", 0.0, T, z0.copy(), zf.copy(), v1=c, v2=b0, v2_cos=b1, v2_sin=b2, w=w)
    return SteeringPlan(z0=z0, zf=zf, T=T, phase_times=np.array([0.0, T]), phases=(phase,),
                        amplitude="none", mode="constant_v1")


def steer_heisenberg(x0, xf, T: float = 1.0, **kwargs) -> SteeringPlan:
    """Steer the Heisenberg system x1' = u1, x2' = u2, x3' = x2 u1 from x0 to xf in time T.

    It *is* the 3-dimensional chained form with z = x and v = u (z3' = z2 v1 is x3' = x2 u1), so
    the returned plan's ``states`` and ``inputs`` are directly in the model's coordinates.
    Keyword arguments go to :func:`steer_chained`.
    """
    x0 = _vector("x0", x0, (3,))
    xf = _vector("xf", xf, (3,))
    return steer_chained(x0, xf, T, **kwargs)


# ---------------------------------------------------------------------------------------------
# cars <-> chained form
# ---------------------------------------------------------------------------------------------
def _car_kind(model) -> tuple[str, float]:
    name = getattr(model, "name", None)
    if name not in ("rwd_car", "fwd_car"):
        raise InputError("model", "a rwd_car or fwd_car model", name if name is not None else model)
    L = require_positive(f"{name}.wheelbase", getattr(model, "wheelbase", None))
    return name, L


def _theta_phi(name: str, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (x[..., 2], x[..., 3]) if name == "rwd_car" else (x[..., 3], x[..., 2])


def to_chained(model, x) -> np.ndarray:
    """Model state(s) (..., 4) in model order to chained coordinates (..., 4):
    z = (x, tan(phi) / (L cos^3 theta), tan(theta), y). Needs |theta| < pi/2, |phi| < pi/2."""
    name, L = _car_kind(model)
    x = _array("x", x, last=4)
    th, phi = _theta_phi(name, x)
    if np.any(np.abs(th) >= 0.5 * np.pi):
        raise InputError("x", "heading |theta| < pi/2 (the chained chart)", f"max |theta| {np.abs(th).max():.6g}")
    if np.any(np.abs(phi) >= 0.5 * np.pi):
        raise InputError("x", "steering angle |phi| < pi/2", f"max |phi| {np.abs(phi).max():.6g}")
    ct = np.cos(th)
    z = np.empty(x.shape)
    z[..., 0] = x[..., 0]
    z[..., 1] = np.tan(phi) / (L * ct**3)
    z[..., 2] = np.tan(th)
    z[..., 3] = x[..., 1]
    return z


def from_chained(model, z) -> np.ndarray:
    """Chained coordinates (..., 4) to model state(s) in model order:
    theta = arctan z3, phi = arctan(L z2 cos^3 theta) (inverse of :func:`to_chained`)."""
    name, L = _car_kind(model)
    z = _array("z", z, last=4)
    th = np.arctan(z[..., 2])
    phi = np.arctan(L * z[..., 1] * np.cos(th) ** 3)
    x = np.empty(z.shape)
    x[..., 0] = z[..., 0]
    x[..., 1] = z[..., 3]
    if name == "rwd_car":
        x[..., 2], x[..., 3] = th, phi
    else:
        x[..., 2], x[..., 3] = phi, th
    return x


def car_inputs_from_chained(model, z, v) -> np.ndarray:
    """Model inputs (..., 2) that realise chained inputs v = (v1, v2) at chained state z.

    Body speed s = v1 sqrt(1 + z3^2) (= v1 / cos theta);
    omega_s = L cos^2(phi) cos^3(theta) (v2 - 3 z2^2 z3 v1 / (1 + z3^2));
    first input v = s (rwd_car) or u1 = s / cos(phi) (fwd_car, whose body speed is cos(phi) u1).
    """
    name, L = _car_kind(model)
    return _car_inputs(name, L, _array("z", z, last=4), _array("v", v, last=2))


def _car_inputs(name: str, L: float, z: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`car_inputs_from_chained` without validation; uses only z2 and z3 of ``z``."""
    z2, z3 = z[..., 1], z[..., 2]
    v1, v2 = v[..., 0], v[..., 1]
    q = 1.0 + z3 * z3
    ct = 1.0 / np.sqrt(q)                        # cos theta (theta in (-pi/2, pi/2))
    cphi2 = 1.0 / (1.0 + (L * z2 * ct**3) ** 2)  # cos^2 phi
    s = v1 * np.sqrt(q)
    omega = L * cphi2 * ct**3 * (v2 - 3.0 * z2 * z2 * z3 * v1 / q)
    first = s if name == "rwd_car" else s / np.sqrt(cphi2)
    return np.stack(np.broadcast_arrays(first, omega), axis=-1)


def chained_inputs_from_car(model, x, u) -> np.ndarray:
    """Inverse input map: model state x and inputs u (model order) to chained inputs (v1, v2).

    v1 = cos(theta) s with s = v (rwd) or cos(phi) u1 (fwd);
    v2 = omega_s / (L cos^2 phi cos^3 theta) + 3 z2^2 z3 v1 / (1 + z3^2).
    """
    name, L = _car_kind(model)
    z = to_chained(model, x)
    x = np.asarray(x, dtype=float)
    u = _array("u", u, last=2)
    th, phi = _theta_phi(name, x)
    s = u[..., 0] if name == "rwd_car" else np.cos(phi) * u[..., 0]
    v1 = np.cos(th) * s
    z2, z3 = z[..., 1], z[..., 2]
    v2 = u[..., 1] / (L * np.cos(phi) ** 2 * np.cos(th) ** 3) + 3.0 * z2 * z2 * z3 * v1 / (1.0 + z3 * z3)
    return np.stack(np.broadcast_arrays(v1, v2), axis=-1)


# ---------------------------------------------------------------------------------------------
# car steering in a local frame
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CarSteering:
    """Result of :func:`steer_car`.

    ``t`` (N,), model states ``x`` (N, 4) and inputs ``u`` (N, 2) in model order on the grid
    (``points_per_phase`` per phase + the end point; inputs right-continuous at phase boundaries);
    maxima over the grid; ``final_error`` = model.state_error(x(T), xf) (angles wrapped);
    ``frame`` = {"name", "origin", "heading"} of the chart; ``max_abs_local_theta`` the largest
    |theta - heading| along the path; ``plan`` the chained plan in the local frame. ``states_at`` /
    ``inputs_at`` evaluate the exact trajectory at any t in [0, T].
    """

    model: object
    x0: np.ndarray
    xf: np.ndarray
    T: float
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    phase_times: np.ndarray
    max_abs_phi: float
    max_abs_omega_s: float
    max_speed: float
    max_abs_local_theta: float
    final_error: np.ndarray
    frame: dict
    plan: SteeringPlan
    within_limits: dict = field(default_factory=dict)
    _to_world: Callable = field(default=None, repr=False)

    @property
    def final_error_norm(self) -> float:
        return float(np.linalg.norm(self.final_error))

    def states_at(self, t) -> np.ndarray:
        """Model states (model order, world frame) at times t, shape t.shape + (4,)."""
        return self._to_world(from_chained(self.model, self.plan.states(t)))

    def inputs_at(self, t) -> np.ndarray:
        """Model inputs at times t, shape t.shape + (2,) (frame-independent)."""
        name, L = _car_kind(self.model)
        return _car_inputs(name, L, self.plan.states(t), self.plan.inputs(t))


def _pose_parts(name: str, x: np.ndarray):
    th, phi = _theta_phi(name, x)
    return x[..., 0], x[..., 1], th, phi


def _assemble(name: str, px, py, th, phi) -> np.ndarray:
    cols = (px, py, th, phi) if name == "rwd_car" else (px, py, phi, th)
    return np.stack(np.broadcast_arrays(*cols), axis=-1)


def _frames(frame, x0, xf, name):
    _, _, th0, _ = _pose_parts(name, x0)
    _, _, thf, _ = _pose_parts(name, xf)
    origin = np.array([x0[0], x0[1]])
    mean = float(th0 + 0.5 * wrap_angle(thf - th0))
    options = {"mean": mean, "start": float(th0), "goal": float(thf)}
    if isinstance(frame, str):
        if frame == "auto":
            return [(key, origin, val) for key, val in options.items()]
        if frame in options:
            return [(frame, origin, options[frame])]
        if frame == "world":
            return [("world", np.zeros(2), 0.0)]
        raise InputError("frame", "'auto', 'mean', 'start', 'goal', 'world' or a heading in radians", frame)
    return [("heading", origin, require_finite("frame", frame))]


def steer_car(model, x0, xf, T: float | None = None, frame="auto", *, mode: str = "phased",
              points_per_phase: int = 200, theta_limit: float = 1.2, amplitude="balanced",
              balance: float | None = None, phase_fractions=None, check_limits: bool = False) -> CarSteering:
    """Exactly steer a ``rwd_car`` or ``fwd_car`` from model state x0 to xf through the chained form.

    The poses are expressed in a local frame (origin = x0's position, heading alpha): ``frame``
    "mean" (alpha = mean of the two headings), "start", "goal", "world" (alpha = 0, world origin), a
    number (alpha itself), or "auto" (try mean, start and goal; keep the frame whose steered path
    has the smallest max |theta - alpha|). In the frame the chained plan (``mode``) is computed and
    mapped back (the heading is offset so x(0) = x0 exactly; xf's heading is met modulo 2 pi).
    Refuses with :class:`InputError` if |theta - alpha| reaches ``theta_limit`` (rad, < pi/2)
    anywhere on the grid of the best frame (detail gives max |theta - alpha| and max |phi|).

    ``T``: total time; ``None`` picks the shortest T at which max |speed| and max |omega_s| meet
    the model's limits (inputs scale as 1/T along the same geometric path). ``check_limits``:
    raise InputError if the steering angle, speed or steering rate limit is exceeded.
    ``mode``: "phased" (:func:`steer_chained`, the car drives back and forth in its sinusoidal
    phases) or "constant_v1" (:func:`steer_chained_constant_v1`: v1 = cos(theta) s keeps one sign, so
    the car never reverses within the piece; refused with InputError on ``xf`` when the goal does not
    advance along the frame's axis). ``amplitude``/``balance``/``phase_fractions`` go to
    :func:`steer_chained` (phased mode only); ``balance`` defaults to L^2, i.e. |a| = |b| in the
    dimensionless chained coordinates (x/L, tan(phi)/cos^3 theta, tan theta, y/L).
    """
    name, L = _car_kind(model)
    if mode not in STEERING_MODES:
        raise InputError("mode", "one of " + ", ".join(STEERING_MODES), mode)
    if mode == "constant_v1":
        for key, value in (("amplitude", None if amplitude == "balanced" else amplitude), ("balance", balance),
                           ("phase_fractions", phase_fractions)):
            if value is not None:
                raise InputError(key, "left at its default: it applies to mode 'phased' only", value)
    x0 = _vector("x0", x0, (4,))
    xf = _vector("xf", xf, (4,))
    if T is not None:
        T = require_positive("T", T)
    ppp = _count("points_per_phase", points_per_phase)
    theta_limit = require_positive("theta_limit", theta_limit)
    balance = L * L if balance is None else require_positive("balance", balance)
    if theta_limit >= 0.5 * np.pi:
        raise InputError("theta_limit", "below pi/2 rad", theta_limit)
    for label, xx in (("x0", x0), ("xf", xf)):
        if abs(_theta_phi(name, xx)[1]) >= 0.5 * np.pi:
            raise InputError(label, "a steering angle |phi| < pi/2", xx)

    def chained(z0, zf, T):
        if mode == "constant_v1":
            return steer_chained_constant_v1(z0, zf, T)
        return steer_chained(z0, zf, T, amplitude=amplitude, balance=balance, phase_fractions=phase_fractions)

    best = None
    refusals = []
    tried = []
    for fname, origin, alpha in _frames(frame, x0, xf, name):
        if any(alpha == a and np.array_equal(origin, o) for o, a in tried):
            continue        # the same chart as an earlier frame (e.g. a straight piece): same plan
        tried.append((origin, alpha))
        ca, sa = math.cos(alpha), math.sin(alpha)

        def to_local(x, origin=origin, ca=ca, sa=sa, alpha=alpha):
            px, py, th, phi = _pose_parts(name, x)
            dx, dy = px - origin[0], py - origin[1]
            return _assemble(name, ca * dx + sa * dy, -sa * dx + ca * dy, wrap_angle(th - alpha), phi)

        l0, lf = to_local(x0), to_local(xf)
        ends = max(abs(_theta_phi(name, l0)[0]), abs(_theta_phi(name, lf)[0]))
        if ends >= theta_limit:
            refusals.append(f"{fname}: endpoint |theta - alpha| = {ends:.3f}")
            continue
        z0l, zfl = to_chained(model, l0), to_chained(model, lf)
        if mode == "constant_v1" and zfl[0] == z0l[0]:
            refusals.append(f"{fname}: the goal does not advance along the frame's axis (v1 would be 0)")
            continue
        plan = chained(z0l, zfl, 1.0 if T is None else T)
        dense = plan.grid(max(ppp, 2000) if T is None else ppp)
        zl = plan.states(dense, coords=3)          # z4 (= y) plays no part in the chart or the inputs
        th_local = np.arctan(zl[:, 2])
        max_th = float(np.abs(th_local).max())
        if max_th >= theta_limit:
            phi_max = float(np.abs(np.arctan(L * zl[:, 1] * np.cos(th_local) ** 3)).max())
            refusals.append(f"{fname}: max |theta - alpha| = {max_th:.3f} along the path, max |phi| = {phi_max:.3f}")
            continue
        if best is None or max_th < best[0]:
            best = (max_th, fname, origin, alpha, plan, l0, dense, zl)
    if best is None:
        raise InputError("xf", f"a goal reachable within the chained chart (|theta - alpha| < {theta_limit:g} rad)",
                         xf, detail="; ".join(refusals) or "no frame")
    max_th, fname, origin, alpha, plan, l0, dense, zl = best

    if T is None:   # time scaling: same path, inputs divided by T
        uu = _car_inputs(name, L, zl, plan.inputs(dense))
        T = max(float(np.abs(uu[:, 0]).max()) / model.max_speed,
                float(np.abs(uu[:, 1]).max()) / model.max_steer_rate) * 1.001
        if T <= 0.0:
            T = 1.0   # x0 == xf: nothing to do
        plan = chained(plan.z0, plan.zf, T)

    th_l0 = float(_theta_phi(name, l0)[0])
    th0 = float(_theta_phi(name, x0)[0])
    ca, sa = math.cos(alpha), math.sin(alpha)

    def to_world(xl):
        px, py, th, phi = _pose_parts(name, xl)
        return _assemble(name, origin[0] + ca * px - sa * py, origin[1] + sa * px + ca * py,
                         th0 + (th - th_l0), phi)

    t = plan.grid(ppp)
    z = plan.states(t)
    u = car_inputs_from_chained(model, z, plan.inputs(t))
    x = to_world(from_chained(model, z))
    x[0] = x0       # exact start (differs by round-off only)
    phi = _theta_phi(name, x)[1]
    res_max_phi = float(np.abs(phi).max())
    res_max_speed = float(np.abs(u[:, 0]).max())
    res_max_omega = float(np.abs(u[:, 1]).max())
    within = {"steer": res_max_phi <= model.max_steer, "speed": res_max_speed <= model.max_speed,
              "steer_rate": res_max_omega <= model.max_steer_rate}
    if check_limits and not all(within.values()):
        raise InputError("xf", "reachable within the model's limits",
                         xf, detail=f"max |phi| {res_max_phi:.3f} (limit {model.max_steer:g}), max speed "
                         f"{res_max_speed:.3f} (limit {model.max_speed:g}), max |omega_s| {res_max_omega:.3f} "
                         f"(limit {model.max_steer_rate:g})")
    return CarSteering(
        model=model, x0=x0, xf=xf, T=float(T), t=t, x=x, u=u, phase_times=plan.phase_times.copy(),
        max_abs_phi=res_max_phi, max_abs_omega_s=res_max_omega, max_speed=res_max_speed,
        max_abs_local_theta=float(np.abs(np.arctan(z[:, 2])).max()),
        final_error=model.state_error(x[-1], xf),
        frame={"name": fname, "origin": origin.copy(), "heading": float(alpha)},
        plan=plan, within_limits=within, _to_world=to_world)
