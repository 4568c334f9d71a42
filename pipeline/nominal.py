"""Nominal trajectories x0(t), u0(t): sampled on a time grid, evaluable at any time in the span.

A :class:`Nominal` always carries samples on a strictly increasing grid (``t``, ``x``, ``u``,
time-major). Between samples it is evaluated either from the functions it was built from (closed
forms, or the dense output of an accurate integration) or, for sampled data, by a cubic Hermite
interpolant of x0 whose node slopes are the model's own x' = f(x0) + g(x0) u0, and linear
interpolation of u0.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicHermiteSpline

from .errors import InputError, NumericalError, TrajectoryError
from .models import Model

ArrayFn = Callable[[np.ndarray], np.ndarray]


def _as_float_array(name: str, value, ndim: int) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TrajectoryError(name, f"a numeric array with {ndim} dimension(s)", type(value).__name__) from None
    if arr.ndim != ndim:
        raise TrajectoryError(name, f"an array with {ndim} dimension(s)", f"shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        where = np.argwhere(bad)[0]
        raise TrajectoryError(name, "finite everywhere", f"{arr[tuple(where)]} at index {tuple(int(i) for i in where)}")
    return arr


def _check_grid(model: Model, t: np.ndarray, x: np.ndarray, u: np.ndarray) -> None:
    """Samples on a strictly increasing grid, with the model's state and input sizes."""
    N = t.shape[0]
    if N < 2:
        raise TrajectoryError("t", "at least 2 samples", N)
    if x.shape != (N, model.n):
        raise TrajectoryError("x", f"shape ({N}, {model.n}) to match t and the {model.name} state", f"shape {x.shape}")
    if u.shape != (N, model.m):
        raise TrajectoryError("u", f"shape ({N}, {model.m}) to match t and the {model.name} inputs", f"shape {u.shape}")
    _check_increasing(t)


def _check_increasing(t: np.ndarray) -> None:
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise TrajectoryError("t", "strictly increasing", f"t[{k}] = {t[k]} then t[{k + 1}] = {t[k + 1]}")


class Nominal:
    """A nominal trajectory of a model. Build it with one of the ``from_*`` constructors.

    ``tail`` (optional, None by default) is a feasible continuation of the motion past the end, a
    :class:`Nominal` starting where this one ends: not a part of the plan (nothing follows it), but
    the future windows of the gramian law look into it, so that every window inside the plan is a
    whole one (:func:`nhstab.control.compute_schedule`; the paper's nominals are defined for all t).
    A planner sets it where the plan ends in motion (a car with a trailer reversing into a dock).
    """

    def __init__(self, model: Model, t: np.ndarray, x: np.ndarray, u: np.ndarray,
                 x_func: ArrayFn | None = None, u_func: ArrayFn | None = None, source: str = "samples"):
        if not isinstance(model, Model):
            raise InputError("model", "a robot model (nhstab.make_model(name))", type(model).__name__)
        if x_func is None or u_func is None:       # sampled data: the grid must be usable
            t, x, u = _as_float_array("t", t, 1), _as_float_array("x", x, 2), _as_float_array("u", u, 2)
            _check_grid(model, t, x, u)
        self.model = model
        self.t = t
        self.x = x
        self.u = u
        self.source = source
        if x_func is None:
            x_func = CubicHermiteSpline(t, x, model.rhs(x, u), axis=0)
        if u_func is None:
            u_func = _LinearInterpolant(t, u)
        self._x_func = x_func
        self._u_func = u_func
        self.tail: Nominal | None = None

    # ---- constructors --------------------------------------------------------------------------
    @classmethod
    def from_samples(cls, model: Model, t, x, u) -> "Nominal":
        """Validated samples: ``t`` (N,), ``x`` (N, n), ``u`` (N, m), finite, t strictly increasing.

        Angle states are unwrapped so the nominal is continuous.
        """
        t = _as_float_array("t", t, 1)
        x = _as_float_array("x", x, 2)
        u = _as_float_array("u", u, 2)
        _check_grid(model, t, x, u)
        if model.angle_states:
            x = x.copy()
            idx = list(model.angle_states)
            x[:, idx] = np.unwrap(x[:, idx], axis=0)
        return cls(model, t, x, u, source="samples")

    @classmethod
    def from_functions(cls, model: Model, x_func: ArrayFn, u_func: ArrayFn, t) -> "Nominal":
        """A nominal given in closed form: ``x_func(t)`` -> (len(t), n), ``u_func(t)`` -> (len(t), m)."""
        t = _as_float_array("t", t, 1)
        nom = cls.from_samples(model, t, _call("x_func", x_func, t, model.n), _call("u_func", u_func, t, model.m))
        nom._x_func, nom._u_func, nom.source = x_func, u_func, "functions"
        return nom

    @classmethod
    def from_inputs(cls, model: Model, u_func: ArrayFn, x_init, t, rtol: float = 1e-12, atol: float = 1e-13) -> "Nominal":
        """Integrate the model from ``x_init`` under the open-loop input ``u_func``.

        DOP853 with tight tolerances; between samples x0 comes from the integrator's dense output, so
        integrating the model along the nominal reproduces it to about ``rtol``.
        """
        t = _as_float_array("t", t, 1)
        if t.shape[0] < 2:
            raise TrajectoryError("t", "at least 2 samples", t.shape[0])
        _check_increasing(t)
        x_init = _as_float_array("x_init", x_init, 1)
        if x_init.shape != (model.n,):
            raise TrajectoryError("x_init", f"a vector of length {model.n}", f"shape {x_init.shape}")
        _call("u_func", u_func, t[:2], model.m)

        def rhs(tt, xx):
            return model.rhs(xx, u_func(np.array([tt]))[0])

        sol = solve_ivp(rhs, (t[0], t[-1]), x_init, method="DOP853", t_eval=t, dense_output=True,
                        rtol=rtol, atol=atol)
        if not sol.success:
            raise NumericalError(f"integrating the nominal failed: {sol.message}")
        dense = sol.sol

        def x_func(tau):
            return np.asarray(dense(np.asarray(tau, dtype=float))).T

        nom = cls.from_samples(model, t, sol.y.T, _call("u_func", u_func, t, model.m))
        nom._x_func, nom._u_func, nom.source = x_func, u_func, "integrated"
        return nom

    # ---- evaluation -----------------------------------------------------------------------------
    @property
    def t0(self) -> float:
        return float(self.t[0])

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def at(self, tau) -> tuple[np.ndarray, np.ndarray]:
        """(x0(tau), u0(tau)) for times ``tau`` (any shape, clipped to the span)."""
        tau = np.clip(np.asarray(tau, dtype=float), self.t[0], self.t[-1])
        flat = tau.reshape(-1)
        x = np.asarray(self._x_func(flat), dtype=float).reshape(flat.shape + (self.model.n,))
        u = np.asarray(self._u_func(flat), dtype=float).reshape(flat.shape + (self.model.m,))
        return x.reshape(tau.shape + (self.model.n,)), u.reshape(tau.shape + (self.model.m,))

    def is_uniform(self, rtol: float = 1e-9) -> bool:
        dt = np.diff(self.t)
        return bool(np.all(np.abs(dt - dt.mean()) <= rtol * max(dt.mean(), 1e-300) + 1e-12 * abs(self.t[-1])))

    def resampled(self, n_points: int) -> "Nominal":
        """The same nominal on a uniform grid of ``n_points`` over the same span."""
        t = np.linspace(self.t[0], self.t[-1], int(n_points))
        x, u = self.at(t)
        # keep evaluating the original functions or interpolants, not a re-interpolation of them
        return Nominal(self.model, t, x, u, x_func=self._x_func, u_func=self._u_func, source=self.source)

    def feasibility_residual(self, rtol: float = 1e-10, atol: float = 1e-12) -> float:
        """max |x(t_k) - x0(t_k)| over the grid when the model is integrated from x0(t0) under u0,
        independently of how x0 was made.

        Computed by multiple shooting, vectorised over the grid: every interval [t_k, t_k+1] is
        integrated from x0(t_k) under u0 with steps of the 8th-order Dormand-Prince tableau (scipy's
        DOP853 coefficients), all intervals at once, u0 evaluated at every stage time in one call. An
        interval whose end changes by more than atol + rtol |x| when its step is halved (u0 jumps
        inside it, e.g. where a path's curvature does) is split into pieces, recursively, as an
        adaptive integrator would refine its step there. The local defects d_k = x(t_k+1; x0(t_k)) -
        x0(t_k+1) then give the deviation of one integration from the start, e_k+1 = Phi_k e_k + d_k,
        with Phi_k the pieces' transition matrices (second order in the piece's length, plenty for a
        correction to e, whose size is the residual itself), composed by a parallel prefix scan."""
        model = self.model
        n = model.n
        t = self.t
        shoot = _Shooting(model, self._u_func, rtol, atol)
        t0, t1, x_start, x_end = t[:-1], t[1:], self.x[:-1], self.x[1:]
        node = np.arange(1, len(t))            # the grid node each piece ends at (-1: an inner point)
        pieces = []                             # (t0, t1, X - x0(t1), node) of the pieces that converged
        for depth in range(shoot.MAX_DEPTH + 1):
            X, bad = shoot.interval(t0, t1, x_start, last=depth == shoot.MAX_DEPTH)
            good = ~bad
            pieces.append((t0[good], t1[good], X[good] - x_end[good], node[good]))
            if not bad.any():
                break
            # split each such interval into SPLIT pieces, each starting from x0 at its start
            q = shoot.SPLIT
            frac = np.arange(1, q) / q
            inner = (t0[bad, None] + (t1[bad] - t0[bad])[:, None] * frac[None, :]).reshape(-1)
            x_in = np.asarray(self._x_func(inner), dtype=float).reshape(-1, q - 1, n)
            tt = np.concatenate([t0[bad, None], inner.reshape(-1, q - 1), t1[bad, None]], axis=1)
            xs = np.concatenate([x_start[bad, None], x_in, x_end[bad, None]], axis=1)
            nodes = np.concatenate([np.full((len(tt), q - 1), -1), node[bad, None]], axis=1)
            t0, t1 = tt[:, :-1].reshape(-1), tt[:, 1:].reshape(-1)
            x_start, x_end = xs[:, :-1].reshape(-1, n), xs[:, 1:].reshape(-1, n)
            node = nodes.reshape(-1)
        a, b, defect, node = (np.concatenate([p[i] for p in pieces]) for i in range(4))
        order = np.argsort(a, kind="stable")
        a, b, defect, node = a[order], b[order], defect[order], node[order]
        if not np.all(np.isfinite(defect)):
            raise NumericalError("checking feasibility failed: the integration is not finite")
        # transition matrices of the pieces: exp(h A) to second order, A at the piece's middle
        mid = 0.5 * (a + b)
        x_mid, u_mid = self.at(mid)
        hA = (b - a)[:, None, None] * model.linearize(x_mid, u_mid)[0]
        Phi = np.eye(n) + hA + 0.5 * (hA @ hA)
        # e after piece k: the composition (Phi, d)_k o ... o (Phi, d)_0 applied to 0 (Hillis-Steele scan)
        P, D = Phi, defect
        shift = 1
        while shift < len(D):
            D = np.concatenate([D[:shift], np.einsum("kij,kj->ki", P[shift:], D[:-shift]) + D[shift:]])
            P = np.concatenate([P[:shift], P[shift:] @ P[:-shift]])
            shift *= 2
        at_nodes = D[node >= 0]
        return float(np.max(np.abs(at_nodes))) if len(at_nodes) else 0.0


class _Shooting:
    """Many intervals integrated at once by DOP853 steps."""

    #: steps per interval, against twice as many for the error estimate
    SUBSTEPS = 1
    #: an interval that does not converge is split into this many pieces, at most MAX_DEPTH times
    SPLIT = 16
    MAX_DEPTH = 12

    def __init__(self, model: Model, u_func: ArrayFn, rtol: float, atol: float):
        from scipy.integrate import DOP853

        self.model, self.u_func, self.rtol, self.atol = model, u_func, rtol, atol
        self.stages = DOP853.n_stages
        self.A = np.asarray(DOP853.A, dtype=float)[: self.stages, : self.stages]
        self.B = np.asarray(DOP853.B, dtype=float)
        self.C = np.asarray(DOP853.C, dtype=float)[: self.stages]

    def steps(self, t0, t1, x0, substeps: int):
        model, K = self.model, len(t0)
        h = (t1 - t0) / substeps
        offsets = (np.arange(substeps)[:, None] + self.C[None, :]).reshape(-1)
        taus = t0[:, None] + h[:, None] * offsets[None, :]
        u_all = np.asarray(self.u_func(taus.reshape(-1)), dtype=float).reshape(K, -1, model.m)
        X = x0.copy()
        kx = np.empty((self.stages, K, model.n))
        hh = h[:, None]
        for j in range(substeps):
            for i in range(self.stages):
                Xi = X + hh * np.tensordot(self.A[i, :i], kx[:i], axes=1) if i else X
                kx[i] = model.rhs(Xi, u_all[:, j * self.stages + i])
            X = X + hh * np.tensordot(self.B, kx, axes=1)
        return X

    def interval(self, t0, t1, x0, last: bool = False):
        """(X, bad): the state at the end of each interval, and where halving the step changed it by
        more than the tolerance (never on the ``last`` refinement)."""
        X1 = self.steps(t0, t1, x0, self.SUBSTEPS)
        X2 = self.steps(t0, t1, x0, 2 * self.SUBSTEPS)
        err = np.max(np.abs(X2 - X1) - self.rtol * np.abs(X2), axis=1)
        return X2, (err > self.atol) & (not last)


class _LinearInterpolant:
    """Piecewise-linear u0(t) through the samples (no overshoot between samples)."""

    def __init__(self, t: np.ndarray, u: np.ndarray):
        self.t = t.copy()
        self.u = u.copy()

    def __call__(self, tau) -> np.ndarray:
        tau = np.asarray(tau, dtype=float)
        return np.stack([np.interp(tau, self.t, self.u[:, j]) for j in range(self.u.shape[1])], axis=-1)


def _call(name: str, fn, t: np.ndarray, width: int) -> np.ndarray:
    if not callable(fn):
        raise InputError(name, "a callable of time", type(fn).__name__)
    out = np.asarray(fn(t), dtype=float)
    if out.shape != (t.shape[0], width):
        raise TrajectoryError(name, f"to return shape ({t.shape[0]}, {width}) for {t.shape[0]} times", f"shape {out.shape}")
    if not np.all(np.isfinite(out)):
        raise TrajectoryError(name, "to return finite values", "NaN or inf")
    return out
