"""Nominal trajectories x0(t), u0(t): sampled on a time grid, evaluable at any time in the span.

A :class:`Nominal` always carries samples on a strictly increasing grid (``t``, ``x``, ``u``,
time-major). Between samples it is evaluated either from the functions it was built from (closed
forms, or the dense output of an accurate integration) or, for sampled data, by a cubic Hermite
interpolant of x0 whose node slopes are the model's own x' = f(x0) + g(x0) u0, and linear
interpolation of u0.
"""

from __future__ import annotations

import math
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
        #: times where u0 may jump or kink, if the maker knows them (a hint for the feasibility check)
        self.u_breaks: np.ndarray | None = None

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
        out = Nominal(self.model, t, x, u, x_func=self._x_func, u_func=self._u_func, source=self.source)
        out.u_breaks = self.u_breaks
        return out

    def feasibility_residual(self, rtol: float = 1e-10, atol: float = 1e-12) -> float:
        """max ``|x(t_k) - x0(t_k)|`` over the grid when the model is integrated from x0(t0) under u0,
        independently of how x0 was made.

        Computed by multiple shooting, vectorised over the grid: every interval [t_k, t_k+1] is
        integrated from x0(t_k) under u0 by one step of the 8th-order Dormand-Prince tableau (scipy's
        DOP853 coefficients), all intervals at once, u0 evaluated at every stage time in one call. An
        interval whose embedded error estimate (DOP853's, as scipy's adaptive solver uses it) exceeds
        ``atol + rtol |x|`` (u0 jumps inside it, e.g. where a path's curvature does) is split into pieces,
        recursively, as an adaptive integrator would refine its step there; where the nominal's maker
        knows the times u0 jumps or kinks (``u_breaks``, e.g. a unicycle nominal's curvature changes),
        the intervals are cut there first, so that each piece is smooth (the end stages are taken a
        hair inside a piece, so each side of a jump uses its own values). The local defects
        d_k = x(t_k+1; x0(t_k)) - x0(t_k+1) then give the deviation of one integration from the start, e_k+1 = Phi_k e_k + d_k,
        with Phi_k the pieces' transition matrices (second order in the piece's length, plenty for a
        correction to e, whose size is the residual itself), composed by a parallel prefix scan."""
        model = self.model
        n = model.n
        t = self.t
        shoot = _Shooting(model, self._u_func, rtol, atol)
        t0, t1, x_start, x_end = t[:-1], t[1:], self.x[:-1], self.x[1:]
        node = np.arange(1, len(t))            # the grid node each piece ends at (-1: an inner point)
        if self.u_breaks is not None and len(self.u_breaks):
            t0, t1, x_start, x_end, node = _split_pieces(t, self.x, np.asarray(self.u_breaks, dtype=float),
                                                         self._x_func)
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
        # e after piece k: the composition (Phi, d)_k o ... o (Phi, d)_0 applied to 0
        D = affine_scan(Phi, defect)
        at_nodes = D[node >= 0]
        return float(np.max(np.abs(at_nodes))) if len(at_nodes) else 0.0


def _split_pieces(t: np.ndarray, x: np.ndarray, breaks: np.ndarray, x_func: ArrayFn):
    """The grid's intervals cut at the breaks strictly inside them (those within 1e-6 of an
    interval's length from a node are left out): (t0, t1, x_start, x_end, node) per piece, x0 at a
    break from ``x_func``, node = the grid index a piece ends at, -1 at a break."""
    k = np.clip(np.searchsorted(t, breaks, side="right") - 1, 0, len(t) - 2)
    room = 1e-6 * (t[k + 1] - t[k])
    b = np.unique(breaks[(breaks > t[k] + room) & (breaks < t[k + 1] - room)])
    if not len(b):
        return t[:-1], t[1:], x[:-1], x[1:], np.arange(1, len(t))
    pts = np.concatenate([t, b])
    xs = np.concatenate([x, np.asarray(x_func(b), dtype=float).reshape(len(b), x.shape[1])])
    idx = np.concatenate([np.arange(len(t)), np.full(len(b), -1)])
    order = np.argsort(pts, kind="stable")
    pts, xs, idx = pts[order], xs[order], idx[order]
    return pts[:-1], pts[1:], xs[:-1], xs[1:], idx[1:]


def affine_scan(P: np.ndarray, D: np.ndarray) -> np.ndarray:
    """e_k = P_k e_k-1 + D_k from e_-1 = 0, for every k: (N, n, n) and (N, n) -> (N, n).

    A two-level scan: the sequence is cut into about sqrt(N) blocks of about sqrt(N) steps; the steps
    run in order within every block at once (each block from 0, with its running transition product),
    then the blocks' end values are chained in order, and every block is corrected by its running
    product applied to the value it starts from. About 2 sqrt(N) vectorised steps and O(N n^3) work
    (a Hillis-Steele scan takes log2(N) passes over all N matrices, O(N log N n^3) work)."""
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    N, n = D.shape
    if N == 0:
        return D.copy()
    B = max(1, int(math.ceil(math.sqrt(N))))
    nb = -(-N // B)
    pad = nb * B - N
    if pad:            # identity steps with no defect: they leave e unchanged
        P = np.concatenate([P, np.broadcast_to(np.eye(n), (pad, n, n))])
        D = np.concatenate([D, np.zeros((pad, n))])
    Pb, Db = P.reshape(nb, B, n, n), D.reshape(nb, B, n)
    E, M = np.empty_like(Db), np.empty_like(Pb)        # within-block values from 0, running products
    e, Mk = np.zeros((nb, n)), np.broadcast_to(np.eye(n), (nb, n, n))
    for k in range(B):
        e = np.einsum("bij,bj->bi", Pb[:, k], e) + Db[:, k]
        Mk = Pb[:, k] @ Mk
        E[:, k], M[:, k] = e, Mk
    start = np.zeros((nb, n))                           # e just before each block
    for b in range(1, nb):
        start[b] = M[b - 1, -1] @ start[b - 1] + E[b - 1, -1]
    return (E + np.einsum("bkij,bj->bki", M, start)).reshape(-1, n)[:N]


class _Shooting:
    """Many intervals integrated at once, one DOP853 step each, checked by DOP853's own embedded
    error estimate (the 5th- and 3rd-order estimators combined as scipy's ``solve_ivp`` does, per
    component): 13 right-hand sides and 12 input evaluations per interval."""

    #: an interval that does not converge is split into this many pieces, at most MAX_DEPTH times
    SPLIT = 16
    MAX_DEPTH = 12
    #: the estimate must be within this fraction of atol + rtol |x|: the step-halving check this
    #: replaces kept the two-half-step result, about 2^8 = 256 times more accurate than the difference
    #: it tested, and this keeps that accuracy (residuals of exact nominals stay at the 1e-9 level)
    SAFETY = 1.0 / 256

    def __init__(self, model: Model, u_func: ArrayFn, rtol: float, atol: float):
        from scipy.integrate import DOP853

        self.model, self.u_func, self.rtol, self.atol = model, u_func, rtol, atol
        self.stages = DOP853.n_stages
        self.A = np.asarray(DOP853.A, dtype=float)[: self.stages, : self.stages]
        self.B = np.asarray(DOP853.B, dtype=float)
        self.C = np.asarray(DOP853.C, dtype=float)[: self.stages]
        self.E3 = np.asarray(DOP853.E3, dtype=float)
        self.E5 = np.asarray(DOP853.E5, dtype=float)
        assert self.C[-1] == 1.0 and len(self.E5) == self.stages + 1     # the last stage is at t + h

    def step(self, t0, t1, x0):
        """(X, err): one DOP853 step over every interval, and its error estimate (per component)."""
        model, K, s = self.model, len(t0), self.stages
        h = t1 - t0
        taus = t0[:, None] + h[:, None] * self.C[None, :]
        # the end stages a hair inside the interval: where u0 jumps at an end (a grid node or a break
        # the interval was cut at), each side integrates with its own one-sided values
        hair = np.minimum(1e-12 * np.maximum(1.0, np.abs(t1)), 0.25 * h)[:, None]
        taus = np.clip(taus, t0[:, None] + hair, t1[:, None] - hair)
        u_all = np.asarray(self.u_func(taus.reshape(-1)), dtype=float).reshape(K, s, model.m)
        kx = np.empty((s + 1, K, model.n))
        hh = h[:, None]
        for i in range(s):
            Xi = x0 + hh * np.tensordot(self.A[i, :i], kx[:i], axes=1) if i else x0
            kx[i] = model.rhs(Xi, u_all[:, i])
        X = x0 + hh * np.tensordot(self.B, kx[:s], axes=1)
        kx[s] = model.rhs(X, u_all[:, s - 1])             # f at (t + h, X): the stage the estimators use
        err5 = np.abs(np.tensordot(self.E5, kx, axes=1))
        err3 = np.abs(np.tensordot(self.E3, kx, axes=1))
        denom = np.hypot(err5, 0.1 * err3)
        with np.errstate(invalid="ignore", divide="ignore"):
            err = np.abs(hh) * err5 * np.where(denom > 0, err5 / denom, 1.0)
        return X, err

    def interval(self, t0, t1, x0, last: bool = False):
        """(X, bad): the state at the end of each interval, and where the step's error estimate
        exceeds SAFETY (atol + rtol |X|) in some component (never on the ``last`` refinement)."""
        X, err = self.step(t0, t1, x0)
        bad = np.max(err / self.SAFETY - self.rtol * np.abs(X), axis=1) > self.atol
        return X, bad & (not last)


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
