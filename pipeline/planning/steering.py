"""Exact steering of chained-form systems with sinusoids (Murray & Sastry 1990/1993) and its use
for the Heisenberg system and the two kinematic cars.

Chained form (one chain, dimension 3 <= n <= 10)
-----------------------------------------------
    z1' = v1,   z2' = v2,   z3' = z2 v1,   ...,   zn' = z(n-1) v1.

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

Any dimension n: phase k's net motion of z_k is the Murray-Sastry formula
    dz_k = (a / 2w)^(k-2) b / (k-2)! * 2 pi / w,
and it also moves every z_j, j > k, by an amount that does not depend on the start state either
(every start-state term is an iterated integral of v1 alone over a period, (int v1)^m / m! = 0).
Phases are solved in order k = 3, ..., n, each for the error its predecessors left in z_k.

Every phase integrates in closed form, so :class:`SteeringPlan` evaluates states and inputs
exactly (round-off only) at any time. For n <= 4 the formulas are written out below; for n >= 5 the
states are exponential polynomials, finite sums of c t^p exp(i q w t) (:class:`_ExpPoly`): v1 and v2
are such sums, and the chain's products and integrals of them are again such sums, with the exact
antiderivative int_0^t tau^p e^(lam tau) dtau = e^(lam t) sum_(r<=p) (-1)^r p!/(p-r)! t^(p-r) / lam^(r+1)
- (-1)^p p! / lam^(p+1) (lam = i q w != 0; t^(p+1)/(p+1) for q = 0). The net motions of such a
phase are those sums at t = 2 pi / w, where every exp(i q w t) is exactly 1. Constant phases are
polynomials: z_k(t) = sum_(i=2..k) z_is (v1 t)^(k-i) / (k-i)! + v2 t (v1 t)^(k-2) / (k-1)!.
(tests/planning/test_trailer_steering.py checks both against DOP853 integration, and the formula above.)

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

Polynomial steering with v1 constant (:func:`steer_chained_polynomial`, any n >= 3)
-----------------------------------------------------------------------------------
v1 = c = (z1f - z1s) / T and v2 a polynomial of degree n - 2 in s = t / T, v2 = sum_j b_j s^j. Then
every z_k is a polynomial in s:
    z_k(s) = sum_(i=2..k) z_is (c T s)^(k-i) / (k-i)!  +  T (c T)^(k-2) sum_j b_j j! s^(j+k-1) / (j+k-1)!,
so the targets z_k(1) = z_kf (k = 2..n) are the linear system M b = r with
    M[k, j] = j! / (j + k - 1)!,   r_k = (z_kf - sum_(i=2..k) z_is (c T)^(k-i) / (k-i)!) / (T (c T)^(k-2)),
a Hilbert-like (n - 1) x (n - 1) matrix, nonsingular: it is the Gram-type matrix of the moments of
independent monomials (for n = 5 its condition number is about 2e4). It needs c != 0. As z1 = z1s + c t
moves uniformly, z_n is then a polynomial of degree 2n - 3 in z1 that matches z_n and its first
n - 2 derivatives with respect to z1 at both ends: the Hermite interpolant of the flat output. The
motion never reverses (v1 keeps its sign) and never oscillates more than that interpolant.

The cars' charts to and from this form, and car steering, are in :mod:`nhstab.planning.car_charts`;
the car with one trailer's in :mod:`nhstab.planning.trailer_charts`.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, require_finite, require_positive

__all__ = [
    "SteeringPlan", "SteeringPhase", "STEERING_MODES",
    "chained_rhs", "net_motion", "net_displacement", "steer_chained", "steer_chained_constant_v1", "steer_heisenberg",
    "steer_chained_polynomial", "MAX_CHAINED",
]

_TWO_PI = 2.0 * math.pi
#: the chained-form steering methods: the phased sinusoids of :func:`steer_chained` and the constant-v1
#: sinusoid of :func:`steer_chained_constant_v1`
STEERING_MODES = ("phased", "constant_v1", "polynomial")
#: the largest chained dimension the steering functions accept
MAX_CHAINED = 10
_SIZES = tuple(range(3, MAX_CHAINED + 1))


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
    z = _vector("z_start", z_start, _SIZES)
    n = z.shape[0]
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 3 <= int(k) <= n:
        raise InputError("k", f"an integer in 3..{n} (the chained dimension is {n})", k)
    return int(k), require_finite("a", a), require_finite("b", b), require_positive("w", w), z


def net_displacement(k: int, a: float, b: float, w: float, z_start) -> np.ndarray:
    """Change of the whole chained state over one period P = 2 pi / w of phase k.

    Phase k applies v1 = a sin(w t), v2 = b cos((k - 2) w t), t in [0, P], from ``z_start``
    (length n, 3 <= k <= n). For n <= 4, closed form, derived from the chained equations with
    c = cos(w t), s = sin(w t) (see :func:`_sin_phase` for the full time laws):

    * k = 3: z1 = z1s + (a/w)(1 - c), z2 = z2s + (b/w) s,
      z3 = z3s + z2s (a/w)(1 - c) + (a b / w)(t/2 - sin(2wt)/(4w))      -> dz3 = pi a b / w^2,
      z4 = z4s + z3s (a/w)(1 - c) + z2s (a/w)^2 (1 - c - s^2/2)
               + (a^2 b / w)(-t c/(2w) + s/(2w^2) - s^3/(6w^2))          -> dz4 = -pi a^2 b / w^3.
    * k = 4: z2 = z2s + (b/w) s c, z3 = z3s + z2s (a/w)(1 - c) + a b s^3 / (3 w^2)  -> dz3 = 0,
      z4 = ... + (a^2 b / (3 w^2)) int_0^t sin^4 = ... -> dz4 = (a^2 b/(3w^2)) (3 pi/(4 w))
      = pi a^2 b / (4 w^3).

    For n >= 5, the exponential-polynomial series of the phase (module docstring) at t = P:
    z_k moves by the Murray-Sastry amount and every z_j, j > k, by a^(j-2) b times a number that
    depends on w, j and k only.

    All start-state terms vanish over a full period, so the result does not depend on
    ``z_start`` (only its length n is used).
    """
    k, a, b, w, z = _check_phase_args(k, a, b, w, z_start)
    n = z.shape[0]
    d = np.zeros(n)
    if n >= 5:
        series = _sin_series(np.zeros(n), k, a, b, w, n)
        for j in range(k - 1, n):
            d[j] = series[j].at_period()
        return d
    if k == 3:
        d[2] = math.pi * a * b / w**2
        if n == 4:
            d[3] = -math.pi * a * a * b / w**3
    else:  # k == 4
        d[3] = math.pi * a * a * b / (4.0 * w**3)
    return d


def net_motion(k: int, a: float, b: float, w: float, z_start) -> float:
    """Change of z_k (1-based, 3 <= k <= n) over one period of v1 = a sin(w t), v2 = b cos((k-2) w t).

    Murray-Sastry closed form: dz_k = (a / (2 w))^(k-2) * b / (k-2)! * 2 pi / w, i.e.
    pi a b / w^2 for k = 3 and pi a^2 b / (4 w^3) for k = 4 (derivation in
    :func:`net_displacement`), whatever ``z_start``; ``z_start`` (length n) fixes the
    dimension, so k <= len(z_start).
    """
    k_checked = _check_phase_args(k, a, b, w, z_start)[0]
    if k_checked <= 4:
        return float(net_displacement(k, a, b, w, z_start)[k_checked - 1])
    return _net_coefficient(k_checked, float(w)) * float(a) ** (k_checked - 2) * float(b)


def _net_coefficient(k: int, w: float) -> float:
    """dz_k / (a^(k-2) b) over one period of phase k: (1 / (2 w))^(k-2) / (k-2)! * 2 pi / w."""
    return (0.5 / w) ** (k - 2) / math.factorial(k - 2) * _TWO_PI / w


# ---- exponential polynomials: exact phase laws of any dimension --------------------------------
class _ExpPoly:
    """f(t) = Re sum_(p, q) c[p, q] t^p exp(i q w t): the states of a chained-form phase whose inputs
    are trigonometric polynomials in w t (module docstring). Coefficients are complex; the real
    functions here carry conjugate pairs, and the real part removes the round-off between them."""

    __slots__ = ("w", "terms", "_arrays")

    def __init__(self, w: float, terms: dict):
        self.w, self.terms, self._arrays = float(w), terms, None

    @classmethod
    def constant(cls, w: float, value: float) -> "_ExpPoly":
        return cls(w, {(0, 0): complex(value)})

    def plus_constant(self, value: float) -> "_ExpPoly":
        terms = dict(self.terms)
        terms[(0, 0)] = terms.get((0, 0), 0j) + value
        return _ExpPoly(self.w, terms)

    def times(self, factor: dict) -> "_ExpPoly":
        """This times sum_(dq) f[dq] exp(i dq w t) (``factor``: {dq: f})."""
        out: dict = {}
        for (p, q), c in self.terms.items():
            for dq, f in factor.items():
                key = (p, q + dq)
                out[key] = out.get(key, 0j) + c * f
        return _ExpPoly(self.w, out)

    def integral(self) -> "_ExpPoly":
        """int_0^t of this, exactly (the antiderivative of the module docstring)."""
        out: dict = {}

        def add(key, value):
            out[key] = out.get(key, 0j) + value

        for (p, q), c in self.terms.items():
            if c == 0:
                continue
            if q == 0:
                add((p + 1, 0), c / (p + 1))
                continue
            lam = 1j * q * self.w
            falling = 1.0                                   # p! / (p - r)!
            for r in range(p + 1):
                add((p - r, q), c * (-1) ** r * falling / lam ** (r + 1))
                falling *= p - r
            add((0, 0), -c * (-1) ** p * math.factorial(p) / lam ** (p + 1))
        return _ExpPoly(self.w, out)

    def __call__(self, t) -> np.ndarray:
        if self._arrays is None:
            keys = list(self.terms)
            self._arrays = (np.array([p for p, _ in keys], dtype=float), np.array([q for _, q in keys], dtype=float),
                            np.array([self.terms[k] for k in keys], dtype=complex))
        p, q, c = self._arrays
        t = np.asarray(t, dtype=float)[..., None]
        return np.sum(c * t**p * np.exp((1j * self.w) * q * t), axis=-1).real

    def at_period(self) -> float:
        """The value at t = 2 pi / w (every exp(i q w t) is 1 there)."""
        P = _TWO_PI / self.w
        return float(sum((c * P**p for (p, q), c in self.terms.items()), 0j).real)


@functools.lru_cache(maxsize=256)
def _cached_series(zs: tuple, k: int, a: float, b: float, w: float, n: int) -> tuple:
    """:func:`_sin_series` kept for the phases evaluated again and again (an integrator's calls)."""
    return tuple(_sin_series(np.array(zs), k, a, b, w, n))


def _sin_series(zs: np.ndarray, k: int, a: float, b: float, w: float, n: int) -> list:
    """The states of phase k (v1 = a sin(w t), v2 = b cos((k-2) w t)) from ``zs`` as _ExpPoly series,
    the first ``n``: z1 = z1s + int v1, z2 = z2s + int v2, z_j = z_js + int z_(j-1) v1."""
    v1 = {1: a / 2j, -1: -a / 2j}
    m = k - 2
    one = _ExpPoly.constant(w, 1.0)
    z = [one.times(v1).integral().plus_constant(float(zs[0])),
         _ExpPoly(w, {(0, m): b / 2, (0, -m): b / 2}).integral().plus_constant(float(zs[1]))]
    for j in range(2, n):
        z.append(z[-1].times(v1).integral().plus_constant(float(zs[j])))
    return z


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
    elif n >= 5:        # z_k = sum_(i=2..k) z_is (v1 t)^(k-i) / (k-i)! + v2 t (v1 t)^(k-2) / (k-1)!
        r = v1 * t
        for k in range(4, n + 1):
            acc = v2 * t * r ** (k - 2) / math.factorial(k - 1)
            for i in range(2, k + 1):
                acc = acc + zs[i - 1] * r ** (k - i) / math.factorial(k - i)
            out[..., k - 1] = acc
    return out


def _sin_phase(zs: np.ndarray, k: int, a: float, b: float, w: float, t: np.ndarray,
               coords: int | None = None) -> np.ndarray:
    """States under v1 = a sin(w t), v2 = b cos((k-2) w t); formulas of :func:`net_displacement`;
    only the first ``coords`` (>= 3) of them if given. ``zs`` (n, ...) and a, b, w may also hold
    one phase per time (arrays shaped as t)."""
    n = zs.shape[0] if coords is None else coords
    if n >= 5 or k >= 5:        # exact exponential-polynomial series (module docstring)
        series = _cached_series(tuple(float(v) for v in np.asarray(zs, dtype=float)), int(k), float(a), float(b),
                                float(w), n)
        return np.stack([zj(t) for zj in series], axis=-1)
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
    """One phase of a plan. ``kind`` is "constant" (inputs v1, v2), "sinusoid" (k, a, b, w),
    "constant_v1" (v1 constant, v2(t) = v2 + v2_cos cos(w t) + v2_sin sin(w t)) or "polynomial"
    (v1 constant, v2 = sum_j v2_poly[j] (tau / (t1 - t0))^j)."""

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
    v2_poly: tuple = ()

    def inputs(self, tau: np.ndarray) -> np.ndarray:
        out = np.empty(tau.shape + (2,))
        if self.kind == "polynomial":
            out[..., 0] = self.v1
            out[..., 1] = np.polynomial.polynomial.polyval(tau / (self.t1 - self.t0), np.asarray(self.v2_poly))
        elif self.kind == "constant":
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
        if self.kind == "polynomial":
            return _polynomial_phase(self.z_start, self.v1, np.asarray(self.v2_poly), self.t1 - self.t0, tau, coords)
        if self.kind == "constant":
            return _constant_phase(self.z_start, self.v1, self.v2, tau, coords)
        if self.kind == "constant_v1":
            return _constant_v1_phase(self.z_start, self.v1, self.v2, self.v2_cos, self.v2_sin, self.w, tau, coords)
        return _sin_phase(self.z_start, self.k, self.a, self.b, self.w, tau, coords)


@dataclass(frozen=True)
class SteeringPlan:
    """A piecewise chained-form plan: ``mode`` "phased" (constant, then one sinusoid per higher
    coordinate), "constant_v1" or "polynomial" (one phase).

    ``phase_times`` holds the phase boundaries 0 = t_0 < t_1 < ... = T (n of them for "phased", 2 for
    "constant_v1" and "polynomial"). Inputs are right-continuous at the boundaries (the value of the later phase; at T
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
    """Murray-Sastry sinusoidal steering of the chained form (any dimension 3 <= n <= 10) from ``z0``
    to ``zf`` in time ``T``.

    Phases (see the module docstring): constant inputs for z1, z2, then for k = 3..n one period
    of v1 = a sin(w t), v2 = b cos((k-2) w t) with w = 2 pi / (phase length). Amplitude
    equations (closed form, :func:`net_motion`):
        phase z3: pi a b / w^2 = z3f - z3(after phase 1)    -> a b = c3 = dz3 w^2 / pi;
                  it moves z4 by -pi a^2 b / w^3 (n = 4), which phase z4 also corrects;
        phase z4: pi a^2 b / (4 w^3) = z4f - z4(after phase z3) -> a^2 b = c4 = 4 dz4 w^3 / pi;
        phase zk: (1 / 2w)^(k-2) / (k-2)! (2 pi / w) a^(k-2) b = dz_k  (any k); each phase's motion
                  of the later coordinates (:func:`net_displacement`) is added before they are solved.
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
        if k <= 4:
            c = dk * w**2 / math.pi if k == 3 else 4.0 * dk * w**3 / math.pi
        else:
            c = dk / _net_coefficient(k, w)
        a, b = _amplitudes(k, c, amplitude, balance)
        z_end = z + net_displacement(k, a, b, w, z)
        z_end[: k] = zf[: k]                # exact by construction; remove round-off
        phases.append(SteeringPhase("sinusoid", t0, t1, z.copy(), z_end, k=k, a=a, b=b, w=w))
        z = z_end
    return SteeringPlan(z0=z0, zf=zf, T=T, phase_times=times, phases=tuple(phases), amplitude=amplitude)


def _chained_pair(z0, zf, sizes=_SIZES) -> tuple[np.ndarray, np.ndarray]:
    z0 = _vector("z0", z0, sizes)
    zf = _vector("zf", zf, sizes)
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
    and the system is singular (z3, z4 cannot move). Dimension 3 or 4 (any dimension:
    :func:`steer_chained_polynomial`).
    """
    z0, zf = _chained_pair(z0, zf, (3, 4))
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


def _polynomial_coefficients(zs: np.ndarray, c: float, b: np.ndarray, T: float, n: int) -> list[np.ndarray]:
    """Coefficients in s = t / T (lowest degree first) of z_2 .. z_n under v1 = c, v2 = sum_j b_j s^j:
    z_k(s) = sum_(i=2..k) z_is (c T)^(k-i) s^(k-i) / (k-i)! + T (c T)^(k-2) sum_j b_j j! s^(j+k-1) / (j+k-1)!."""
    cT = c * T
    out = []
    for k in range(2, n + 1):
        coef = np.zeros(len(b) + k - 1)
        for i in range(2, k + 1):
            coef[k - i] += zs[i - 1] * cT ** (k - i) / math.factorial(k - i)
        for j, bj in enumerate(b):
            coef[j + k - 1] += T * cT ** (k - 2) * bj * math.factorial(j) / math.factorial(j + k - 1)
        out.append(coef)
    return out


def _polynomial_phase(zs: np.ndarray, c: float, b: np.ndarray, T: float, t: np.ndarray,
                      coords: int | None = None) -> np.ndarray:
    """States under v1 = c, v2 = sum_j b_j (t / T)^j (module docstring), by Horner's rule on the
    coefficients of :func:`_polynomial_coefficients`."""
    n = zs.shape[0] if coords is None else coords
    t = np.asarray(t, dtype=float)
    s = t / T
    out = np.empty(s.shape + (n,))
    out[..., 0] = zs[0] + c * t
    for k, coef in enumerate(_polynomial_coefficients(zs, c, b, T, n), start=2):
        out[..., k - 1] = np.polynomial.polynomial.polyval(s, coef)
    return out


def steer_chained_polynomial(z0, zf, T: float = 1.0) -> SteeringPlan:
    """Steer the chained form (any dimension 3 <= n <= 10) from ``z0`` to ``zf`` in time ``T`` with v1
    constant and v2 a polynomial of degree n - 2 in t / T (module docstring: the linear system and
    why it is the Hermite interpolant of the flat output z_n as a function of z1).

    v1 = c = (z1f - z1s) / T keeps its sign, so a vehicle driven this way never reverses within the
    piece. States and inputs are exact closed forms (polynomials); the end state equals ``zf`` up to
    round-off (set exactly in ``phases[0].z_end``). Refuses (:class:`InputError` on ``zf``) when
    z1f = z1s (c = 0: the higher coordinates cannot move).
    """
    z0, zf = _chained_pair(z0, zf)
    T = require_positive("T", T)
    n = z0.shape[0]
    if zf[0] == z0[0]:
        raise InputError("zf", "a z1 different from z0's (constant v1 = (z1f - z1s) / T must not vanish)", zf)
    c = (zf[0] - z0[0]) / T
    cT = c * T
    M = np.array([[math.factorial(j) / math.factorial(j + k - 1) for j in range(n - 1)] for k in range(2, n + 1)])
    rhs = np.empty(n - 1)
    for k in range(2, n + 1):
        free = sum(z0[i - 1] * cT ** (k - i) / math.factorial(k - i) for i in range(2, k + 1))
        rhs[k - 2] = (zf[k - 1] - free) / (T * cT ** (k - 2))
    b = np.linalg.solve(M, rhs)
    phase = SteeringPhase("polynomial", 0.0, T, z0.copy(), zf.copy(), v1=c, v2_poly=tuple(float(v) for v in b))
    return SteeringPlan(z0=z0, zf=zf, T=T, phase_times=np.array([0.0, T]), phases=(phase,), amplitude="none",
                        mode="polynomial")


def steer_heisenberg(x0, xf, T: float = 1.0, **kwargs) -> SteeringPlan:
    """Steer the Heisenberg system x1' = u1, x2' = u2, x3' = x2 u1 from x0 to xf in time T.

    It *is* the 3-dimensional chained form with z = x and v = u (z3' = z2 v1 is x3' = x2 u1), so
    the returned plan's ``states`` and ``inputs`` are directly in the model's coordinates.
    Keyword arguments go to :func:`steer_chained`.
    """
    x0 = _vector("x0", x0, (3,))
    xf = _vector("xf", xf, (3,))
    return steer_chained(x0, xf, T, **kwargs)
