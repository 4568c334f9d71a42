"""The plant between control samples: x' = f(x) + g(x) u with u held (zero-order hold).

Classical RK4 with ``substeps`` steps per hold interval, vectorised over leading axes of ``x`` (many
trials at once). The built-in robots have their own step, written per state so that what the stages
share is computed once: with u held, the cars' steering angle is the same at stages 2 and 3 (so are
its tangent or cosine and sine, and the heading rate: the same arithmetic as the generic step on the
model's ``rhs``, bit-identical, tested); the unicycle's heading advances by the same angle at every
stage, so its cosines and sines follow by rotations (agreeing with the generic step to 1e-14). At 50 Hz with 4 substeps the local error is below 1e-11 m for the built-in robots at
their speed limits (tests/execution/test_execution.py compares with an adaptive DOP853 solve). States with
limits (the cars' steering angle) stop at them, like a mechanical end stop.

:meth:`Plant.stack_stepper` is the same step for many states stored state-major, (n, K), as the
batch engine keeps them: bit-identical to :meth:`Plant.step` on each state (numpy's float64 sin, cos
and tan give the same value for an element whatever the array's size, layout or stride; tested),
with each function evaluated once per hold interval for all substeps and RK4 stages of all states.
"""

from __future__ import annotations

import numpy as np

from ..models import Model
from ..models.fwd_car import FwdCar
from ..models.rwd_car import RwdCar
from ..models.unicycle import Unicycle

try:
    from numpy._core.umath import clip as _clip  # np.clip's ufunc, without its Python wrapper
except ImportError:                                       # numpy 1.x
    from numpy.core.umath import clip as _clip


class Plant:
    def __init__(self, model: Model, period: float, substeps: int = 4):
        self.model = model
        self.h = float(period) / int(substeps)
        self.substeps = int(substeps)
        lim = model.state_limits()
        self._limited = bool(np.any(np.isfinite(lim)))
        self._lo, self._hi = lim[:, 0], lim[:, 1]

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The state one hold interval later, from x (..., n) under the constant input u (..., m)."""
        fast = _STEPS.get(type(self.model))
        if fast is not None:
            return fast(self, np.asarray(x, dtype=float), np.asarray(u, dtype=float))
        return self.generic_step(x, u)

    def stack_stepper(self, count: int):
        """A step for ``count`` states stored state-major, ``step(x, u, out)``: x (n, count) and u
        (m, count) in (column i is state i and its input), the states one hold interval later written
        to ``out`` (n, count, not overlapping x), which is returned. Bit-identical to :meth:`step` on
        each column. For the built-in robots it keeps its work arrays between calls and evaluates
        each function once per hold interval for all substeps and stages at once (what a stage needs
        is known before the stage: the steering angles from the input alone, then the headings), the
        same arithmetic as :meth:`step` in the same order per element, in a few dozen array
        operations per step instead of a few hundred; other models use :meth:`step`."""
        kind = _STACKS.get(type(self.model))
        if kind is None:
            def step(x, u, out):
                out[...] = self.step(x.T, u.T).T
                return out
            return step
        return kind(self, int(count))

    def generic_step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """RK4 on the model's ``rhs`` (any model)."""
        rhs, h = self.model.rhs, self.h
        for _ in range(self.substeps):
            k1 = rhs(x, u)
            k2 = rhs(x + 0.5 * h * k1, u)
            k3 = rhs(x + 0.5 * h * k2, u)
            k4 = rhs(x + h * k3, u)
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            if self._limited:
                x = np.clip(x, self._lo, self._hi)
        return x


def _unicycle_step(plant: Plant, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """RK4 of x' = (cos(theta) v, sin(theta) v, omega) under the held input. theta's rate is omega at
    every stage, so the stages' headings are theta, theta + a, theta + a and theta + 2a with a = omega h
    / 2, and the next substep starts at theta + 2a: their cosines and sines follow from cos, sin of
    theta and of a by rotations, two evaluations of each per hold interval instead of twelve. The
    rotations round differently from direct evaluation, by about 1e-16 per substep (the generic step
    on ``rhs`` agrees to 1e-14, tested); theta itself advances by the RK4 sum exactly as before."""
    hh, w6 = 0.5 * plant.h, plant.h / 6.0
    px, py, th = x[..., 0], x[..., 1], x[..., 2]
    v, w = u[..., 0], u[..., 1]
    a = hh * w
    ca, sa = np.cos(a), np.sin(a)
    c, s = np.cos(th), np.sin(th)
    for _ in range(plant.substeps):
        c2, s2 = c * ca - s * sa, s * ca + c * sa
        c4, s4 = c2 * ca - s2 * sa, s2 * ca + c2 * sa
        px = px + w6 * v * (c + 4.0 * c2 + c4)
        py = py + w6 * v * (s + 4.0 * s2 + s4)
        th = th + w6 * (w + 2.0 * w + 2.0 * w + w)
        c, s = c4, s4
    return np.stack(np.broadcast_arrays(px, py, th), axis=-1)


def _rwd_car_step(plant: Plant, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """k1 .. k4 of x' = (cos(theta) v, sin(theta) v, tan(phi) v / L, omega_s): phi is the same at
    stages 2 and 3, so their tangent and heading rate are shared (k3 theta = k2 theta)."""
    h, hh, w6 = plant.h, 0.5 * plant.h, plant.h / 6.0
    L = plant.model.wheelbase
    lo, hi = plant._lo[3], plant._hi[3]
    px, py, th, phi = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
    v, ws = u[..., 0], u[..., 1]
    for _ in range(plant.substeps):
        k1x, k1y, k1t = np.cos(th) * v, np.sin(th) * v, (np.tan(phi) / L) * v
        th2, phi2 = th + hh * k1t, phi + hh * ws
        k2x, k2y, k2t = np.cos(th2) * v, np.sin(th2) * v, (np.tan(phi2) / L) * v
        th3 = th + hh * k2t
        k3x, k3y = np.cos(th3) * v, np.sin(th3) * v
        th4, phi4 = th + h * k2t, phi + h * ws
        k4x, k4y, k4t = np.cos(th4) * v, np.sin(th4) * v, (np.tan(phi4) / L) * v
        px = px + w6 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
        py = py + w6 * (k1y + 2.0 * k2y + 2.0 * k3y + k4y)
        th = th + w6 * (k1t + 2.0 * k2t + 2.0 * k2t + k4t)
        phi = np.clip(phi + w6 * (ws + 2.0 * ws + 2.0 * ws + ws), lo, hi)
    return np.stack(np.broadcast_arrays(px, py, th, phi), axis=-1)


def _fwd_car_step(plant: Plant, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """k1 .. k4 of x' = (cos(phi) cos(theta) u1, cos(phi) sin(theta) u1, u2, sin(phi) u1 / L): phi
    is the same at stages 2 and 3, so its cosine and sine and the heading rate are shared."""
    h, hh, w6 = plant.h, 0.5 * plant.h, plant.h / 6.0
    L = plant.model.wheelbase
    lo, hi = plant._lo[2], plant._hi[2]
    px, py, phi, th = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
    u1, u2 = u[..., 0], u[..., 1]
    for _ in range(plant.substeps):
        c1 = np.cos(phi)
        k1x, k1y, k1t = (c1 * np.cos(th)) * u1, (c1 * np.sin(th)) * u1, (np.sin(phi) / L) * u1
        phi2, th2 = phi + hh * u2, th + hh * k1t
        c2 = np.cos(phi2)
        k2x, k2y, k2t = (c2 * np.cos(th2)) * u1, (c2 * np.sin(th2)) * u1, (np.sin(phi2) / L) * u1
        th3 = th + hh * k2t
        k3x, k3y = (c2 * np.cos(th3)) * u1, (c2 * np.sin(th3)) * u1
        phi4, th4 = phi + h * u2, th + h * k2t
        c4 = np.cos(phi4)
        k4x, k4y, k4t = (c4 * np.cos(th4)) * u1, (c4 * np.sin(th4)) * u1, (np.sin(phi4) / L) * u1
        px = px + w6 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
        py = py + w6 * (k1y + 2.0 * k2y + 2.0 * k3y + k4y)
        phi = np.clip(phi + w6 * (u2 + 2.0 * u2 + 2.0 * u2 + u2), lo, hi)
        th = th + w6 * (k1t + 2.0 * k2t + 2.0 * k2t + k4t)
    return np.stack(np.broadcast_arrays(px, py, phi, th), axis=-1)


class _StackStep:
    """Work arrays for a stack of K states, state-major (a state's or a quantity's K values in one
    contiguous row). Substep j's values are row j of a (J, K) array and a stage's values one (J, K)
    block of a (stages, J, K) array, so that one call of a ufunc covers every substep and stage that
    needs it."""

    def __init__(self, plant: Plant, count: int):
        self.J, self.K = plant.substeps, count
        self.h, self.hh, self.w6 = plant.h, 0.5 * plant.h, plant.h / 6.0

    def _chain(self, rows: np.ndarray, start: np.ndarray, inc: np.ndarray, last: np.ndarray) -> None:
        """rows[j + 1] = rows[j] + inc[j] from rows[0] = start (not stored); the last sum into ``last``."""
        J = self.J
        prev = start
        for j in range(J - 1):
            np.add(prev, inc[j], out=rows[j + 1])
            prev = rows[j + 1]
        np.add(prev, inc[J - 1], out=last)

    def _steering(self, phi0: np.ndarray, rate: np.ndarray, last: np.ndarray) -> None:
        """The steering angle phi_j of every substep into P[0] (phi_0 = phi0), phi_j + hh rate and
        phi_j + h rate into P[1] and P[2]: phi + w6 (rate + 2.0 rate + 2.0 rate + rate), clipped to
        the end stops, at every substep; the value after the last into ``last``."""
        P, a24, w2, dphi = self.P, self.a24, self.w2, self.dphi
        np.multiply(self.HH, rate, out=a24)         # hh rate, h rate
        np.multiply(2.0, rate, out=w2)
        np.add(rate, w2, out=dphi)
        np.add(dphi, w2, out=dphi)
        np.add(dphi, rate, out=dphi)
        np.multiply(self.w6, dphi, out=dphi)
        phi = self.phis
        np.copyto(phi[0], phi0)
        for j in range(self.J):
            nxt = phi[j + 1] if j + 1 < self.J else last
            np.add(phi[j], dphi, out=nxt)
            _clip(nxt, self.lo, self.hi, out=nxt)
        np.add(P[0], a24[:, None, :], out=P[1:])

    def _heading(self, KT: np.ndarray, th0: np.ndarray, last: np.ndarray) -> None:
        """From the heading rates KT = (k1t, k2t, k4t) of every substep: the headings th_j (th_0 =
        th0) and the stages' th2 = th + hh k1t, th3 = th + hh k2t, th4 = th + h k2t into TH; th +
        w6 (k1t + 2.0 k2t + 2.0 k2t + k4t) at every substep, the value after the last into ``last``."""
        TH, dth, t2 = self.TH, self.dth, self.t2
        np.multiply(2.0, KT[1], out=t2)
        np.add(KT[0], t2, out=dth)
        np.add(dth, t2, out=dth)
        np.add(dth, KT[2], out=dth)
        np.multiply(self.w6, dth, out=dth)
        th = TH[0]
        np.copyto(th[0], th0)
        self._chain(th, th[0], dth, last)
        np.multiply(self.hh, KT[:2], out=TH[1:3])
        np.add(th, TH[1:3], out=TH[1:3])
        np.multiply(self.h, KT[1], out=TH[3])
        np.add(th, TH[3], out=TH[3])

    def _position(self, k: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
        """px + w6 (k1x + 2.0 k2x + 2.0 k3x + k4x), py likewise, at every substep from k = (k.x,
        k.y) (2, stages, J, K); x's and out's first two rows are the positions."""
        D, tmp = self.D, self.tmp
        np.multiply(2.0, k[:, 1:3], out=tmp)
        np.add(k[:, 0], tmp[:, 0], out=D)
        np.add(D, tmp[:, 1], out=D)
        np.add(D, k[:, 3], out=D)
        np.multiply(self.w6, D, out=D)
        self._chain(self.XY, x[:2], D.transpose(1, 0, 2), out[:2])

    def _car_arrays(self, plant: Plant, count: int, phi_index: int) -> None:
        J, K = self.J, count
        self.L = plant.model.wheelbase
        self.lo, self.hi = plant._lo[phi_index], plant._hi[phi_index]
        self.HH = np.array([[self.hh], [self.h]])
        vec = np.empty((4, K))
        self.a24, self.w2, self.dphi = vec[0:2], vec[2], vec[3]
        self.P = np.empty((3, J, K))           # phi_j, phi_j + hh rate, phi_j + h rate
        self.phis = self.P[0]
        self.KT = np.empty((3, J, K))          # the heading rates k1t, k2t, k4t
        self.dth = np.empty((J, K))
        self.t2 = np.empty((J, K))
        self.TH = np.empty((4, J, K))          # th_j, th2, th3, th4
        self.CS = np.empty((2, 4, J, K))       # the position rates (x, y) at the four stages
        self.tmp = np.empty((2, 2, J, K))
        self.D = np.empty((2, J, K))
        self.XY = np.empty((J, 2, K))


class _RwdCarStack(_StackStep):
    """:func:`_rwd_car_step` for a stack: the steering angles of all substeps first, their tangents
    (one call) and heading rates k1t, k2t, k4t; the headings th_j and th2, th3, th4 from those; the
    cosines and sines of all 4 J headings (one call each); the position increments. Each chain (phi,
    th, px, py) is summed substep by substep in the step's order."""

    def __init__(self, plant: Plant, count: int):
        super().__init__(plant, count)
        self._car_arrays(plant, count, 3)

    def __call__(self, x: np.ndarray, u: np.ndarray, out: np.ndarray) -> np.ndarray:
        KT, CS = self.KT, self.CS
        v = u[0]
        self._steering(x[3], u[1], out[3])
        np.tan(self.P, out=KT)                      # (tan(phi) / L) v
        np.divide(KT, self.L, out=KT)
        np.multiply(KT, v, out=KT)
        self._heading(KT, x[2], out[2])
        np.cos(self.TH, out=CS[0])                  # cos(th) v, sin(th) v
        np.sin(self.TH, out=CS[1])
        np.multiply(CS, v, out=CS)
        self._position(CS, x, out)
        return out


class _FwdCarStack(_StackStep):
    """:func:`_fwd_car_step` for a stack, as :class:`_RwdCarStack`, with the steering angles'
    cosines (c1, c2, c2, c4 at the four stages) and sines (the heading rates)."""

    def __init__(self, plant: Plant, count: int):
        super().__init__(plant, count)
        self._car_arrays(plant, count, 2)
        self.CP = np.empty((4, self.J, count))

    def __call__(self, x: np.ndarray, u: np.ndarray, out: np.ndarray) -> np.ndarray:
        P, CP, KT, CS = self.P, self.CP, self.KT, self.CS
        u1 = u[0]
        self._steering(x[2], u[1], out[2])
        np.cos(P[:2], out=CP[:2])
        np.copyto(CP[2], CP[1])
        np.cos(P[2], out=CP[3])
        np.sin(P, out=KT)                           # (sin(phi) / L) u1
        np.divide(KT, self.L, out=KT)
        np.multiply(KT, u1, out=KT)
        self._heading(KT, x[3], out[3])
        np.cos(self.TH, out=CS[0])                  # (c cos(th)) u1, (c sin(th)) u1
        np.sin(self.TH, out=CS[1])
        np.multiply(CP, CS, out=CS)
        np.multiply(CS, u1, out=CS)
        self._position(CS, x, out)
        return out


class _UnicycleStack(_StackStep):
    """:func:`_unicycle_step` for a stack: the cosines and sines of a = h/2 omega and theta in one
    call each, the chain of 2 J rotations (c, s) -> (c ca - s sa, s ca + c sa) in three operations
    each, then all position increments at once."""

    def __init__(self, plant: Plant, count: int):
        super().__init__(plant, count)
        J, K = self.J, count
        self.A = np.empty((2, K))              # a, theta
        self.Q = np.empty((2, 2, K))           # (cos, sin) of (a, theta)
        self.csa = self.Q[:, 0][:, None, :]    # (ca, sa)
        self.R = np.empty((2 * J + 1, 2, K))   # (c, s) after r rotations: c_j = R[2j], c2_j = R[2j+1]
        self.M = np.empty((2, 2, K))
        self.T = np.empty((J, 2, K))
        vec = np.empty((3, K))
        self.w6v, self.w2, self.dth = vec
        self.XY = np.empty((J, 2, K))
        self.TH = np.empty((J, K))

    def __call__(self, x: np.ndarray, u: np.ndarray, out: np.ndarray) -> np.ndarray:
        J, w6 = self.J, self.w6
        A, Q, R, M, T, csa = self.A, self.Q, self.R, self.M, self.T, self.csa
        v, w = u[0], u[1]
        np.multiply(self.hh, w, out=A[0])
        np.copyto(A[1], x[2])
        np.cos(A, out=Q[0])
        np.sin(A, out=Q[1])
        np.copyto(R[0], Q[:, 1])                    # (c, s)
        for r in range(2 * J):
            np.multiply(csa, R[r], out=M)           # ((c ca, s ca), (c sa, s sa))
            np.subtract(M[0, 0], M[1, 1], out=R[r + 1, 0])
            np.add(M[0, 1], M[1, 0], out=R[r + 1, 1])
        w6v, w2, dth = self.w6v, self.w2, self.dth
        np.multiply(w6, v, out=w6v)
        # px + w6 * v * (c + 4.0 * c2 + c4), py likewise with the sines
        np.multiply(4.0, R[1::2], out=T)
        np.add(R[0:2 * J:2], T, out=T)
        np.add(T, R[2::2], out=T)
        np.multiply(w6v, T, out=T)
        self._chain(self.XY, x[:2], T, out[:2])
        # th + w6 * (w + 2.0 * w + 2.0 * w + w): the same every substep
        np.multiply(2.0, w, out=w2)
        np.add(w, w2, out=dth)
        np.add(dth, w2, out=dth)
        np.add(dth, w, out=dth)
        np.multiply(w6, dth, out=dth)
        self._chain(self.TH, x[2], (dth,) * J, out[2])
        return out


def _steps() -> tuple[dict, dict]:
    return ({Unicycle: _unicycle_step, RwdCar: _rwd_car_step, FwdCar: _fwd_car_step},
            {Unicycle: _UnicycleStack, RwdCar: _RwdCarStack, FwdCar: _FwdCarStack})


_STEPS, _STACKS = _steps()
