"""Error tubes, part 1: the mean and covariance of the tracking error of the sampled closed loop,
linearised along the nominal, and the probability that an input saturates.

The loop is ``nhstab run``'s (:mod:`nhstab.execution.runner`; :func:`nhstab.batch.vector.simulate_shared`
reproduces it). At the control samples t_k = k T, k = 0 .. S - 1 (the last one is the end sample,
where no input is applied):

    y_k     = x_k + n_k,                       n_k ~ N(0, R),  R = diag(sensor std^2)
    u_k     = u_ff,k - K_k (y_k - x0_k)        (then clipped to the input limits)
    x_{k+1} = F(x_k, u_k) + w_k + j_k,         w_k ~ N(0, Q),  Q = diag(process std^2) T

where u_ff,k is the mean of u0 over the hold interval, F the plant over one hold interval (``substeps``
classical RK4 steps with the input held: :class:`nhstab.execution.Plant`), w_k the Wiener increments of
the process disturbance and j_k the impulses of that period. The initial error e_0 = x_0 - x0_0 has mean
0 and covariance diag(sigma0^2) (gaussian) or diag(sigma0^2 / 3) (uniform of half-width sigma0).

**Linearisation, exactly discretised.** About (x0_k, u_ff,k), with e_k = x_k - x0_k,

    e_{k+1} = Phi_k e_k + Gamma_k (u_k - u_ff,k) + d_k + w_k + j_k,

Phi_k = dF/dx and Gamma_k = dF/du at (x0_k, u_ff,k): the exact derivatives of the plant's hold-interval
map, i.e. RK4 applied to the variational equations dPhi/dt = A Phi, dGamma/dt = A Gamma + B along the
plant's own stages (A = df/dx + d(g u)/dx, B = g: Proposition 1's linearisation). They equal the
transition matrix over one hold interval and the ZOH input matrix of the continuous linearisation to
RK4's accuracy (about 1e-11 at 50 Hz; tested against closed forms). d_k = F(x0_k, u_ff,k) - x0_{k+1} is
the feedforward's deterministic miss (u0 varies inside the interval, u_ff is held; about 1e-7 m).
With u_k - u_ff,k = -K_k (e_k + n_k) (unsaturated), A_k = Phi_k - Gamma_k K_k and G_k = Gamma_k K_k:

    mean:        m_{k+1} = A_k m_k + d_k + j_k,                          m_0 = 0
    covariance:  S_{k+1} = A_k S_k A_k^T + G_k R G_k^T + Q,              S_0 = Sigma_0

Measurement noise enters through the feedback (G_k R G_k^T), process noise directly. The recursions are
linear in (S_k, m_k), so each is one unit lower block-bidiagonal linear system in the values at all
samples, solved by forward substitution in compiled code (LAPACK's banded triangular solve): the plain
recursion's arithmetic, in linear time, without a Python-level step (:func:`_banded_scan`; for more
than ``BANDED_MAX_STATES`` states, whose packed Kronecker blocks grow as n^4, a blocked scan of
vectorised prefix products, :func:`_block_scan`). :func:`propagate_loop` is the plain recursion (both
tested equal to it to 1e-13).

**Saturation.** Under the same model u_k is Gaussian with mean u_ff,k - K_k m_k and covariance
K_k (S_k + R) K_k^T. Per sample and input the probability of a value beyond a limit is exact (for the
linear model). For the whole run :func:`saturation` gives an **upper bound** (not an estimate) of the
probability that any input reaches a limit at any sample: the event "some sample saturates" is
contained in "sample 0 saturates, or some sample saturates while the previous one did not" (per input
and side), so

    P(any) <= sum_{j, side} [ P(E_0) + sum_{k >= 1} P(E_k and not E_{k-1}) ],

each term a bivariate normal probability of (u_{k-1,j}, u_{k,j}) with their exact cross-covariance
K_k (A_{k-1} S_{k-1} - G_{k-1} R) K_{k-1}^T. Unlike the plain union bound sum_k P(E_k), this counts an
excursion once, not once per sample it lasts. It is clipped to 1. The pairs are computed where they
matter: the smallest P(E_k) (in all at most 1 % of the largest per-sample probability, a lower bound of
the true one, or 1e-4, whichever is larger) stand for their terms themselves, so the bound is looser
than the full sum by at most 1 % of itself or 1e-4 (tested): it is compared with 1 % (``--gains auto``)
and reported to two digits. Below 1e-4 in all it is the plain union bound.

What the linear model leaves out (say so where it is used): the clipping itself (it describes the loop
as long as nothing saturates), the cars' steering end stop, the wrapping of angles (errors are small),
and the curvature of the dynamics (errors grow with the noise; results/tubes/ measures where).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dtbtrs
from scipy.special import ndtr, owens_t

from ..control.windows import transposed
from ..errors import InputError, NumericalError
from ..geometry import cos_sin, wrap_angle
from ..models import Model
from ..models.rwd_car import RwdCar
from ..models.unicycle import Unicycle


@dataclass
class CovariancePropagation:
    """The tracking error's first two moments at the samples t_k (k = 0 .. S - 1), and the inputs'.

    mean (S, n), cov (S, n, n): of e_k = x_k - x0_k. u_mean (S - 1, m), u_var (S - 1, m): of the
    unclipped input u_k (its covariance: :attr:`u_cov`). A (S - 1, n, n), G (S - 1, n, n): A_k and G_k = Gamma_k K_k. drift (S - 1, n):
    d_k. Phi, Gamma: the plant's hold-interval derivatives.
    """

    t: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    u_mean: np.ndarray
    u_var: np.ndarray
    A: np.ndarray
    G: np.ndarray
    Phi: np.ndarray
    Gamma: np.ndarray
    drift: np.ndarray
    R: np.ndarray                 # (n,) sensor variances
    Q: np.ndarray                 # (n,) process variances per period
    K: np.ndarray                 # (S - 1, m, n) the gains

    @property
    def std(self) -> np.ndarray:
        """(S, n) standard deviation of each state's error."""
        return np.sqrt(np.maximum(np.einsum("kii->ki", self.cov), 0.0))

    @property
    def u_std(self) -> np.ndarray:
        return np.sqrt(np.maximum(self.u_var, 0.0))

    @property
    def u_cov(self) -> np.ndarray:
        """(S - 1, m, m) covariance of the unclipped inputs: K_k (S_k + R) K_k^T."""
        K = self.K
        return K @ (self.cov[:-1] + np.diag(self.R)[None]) @ transposed(K)


def plant_derivatives(model: Model, x: np.ndarray, u: np.ndarray, period: float, substeps: int):
    """The plant's hold-interval map F (``substeps`` RK4 steps, input held) from states x (K, n) under
    inputs u (K, m), and its exact derivatives: (F (K, n), dF/dx (K, n, n), dF/du (K, n, m)).

    RK4 on the variational equations with the stages of RK4 on the state: the derivative of the
    discrete map itself (no state clipping: the end stops are outside the linear model). The state's
    stages use the model's ``rhs``, as the plant does; one batched product per stage carries both
    derivatives. The unicycle's and the rwd car's maps and derivatives are in closed form
    (:func:`_unicycle_derivatives`, :func:`_rwd_car_derivatives`); subclasses of them take the general
    way, in case they change the dynamics."""
    F, Phi, Gamma = _derivatives(model, x, u, period, substeps)
    return F, Phi.transpose(2, 0, 1), Gamma.transpose(2, 0, 1)


def _derivatives(model: Model, x: np.ndarray, u: np.ndarray, period: float, substeps: int):
    """:func:`plant_derivatives` with the derivatives laid out steps last, (n, n, K) and (n, m, K), as
    :func:`propagate` uses them: each entry's values over the steps contiguous, so that every operation
    on them is one long array operation."""
    if type(model) is Unicycle:
        return _unicycle_derivatives(np.asarray(x, dtype=float), np.asarray(u, dtype=float), period, substeps)
    if type(model) is RwdCar:
        return _rwd_car_derivatives(np.asarray(x, dtype=float), np.asarray(u, dtype=float), period, substeps,
                                    float(model.wheelbase))
    F, Phi, Gamma = _variational_derivatives(model, x, u, period, substeps)
    return F, np.ascontiguousarray(Phi.transpose(1, 2, 0)), np.ascontiguousarray(Gamma.transpose(1, 2, 0))


def _variational_derivatives(model: Model, x: np.ndarray, u: np.ndarray, period: float, substeps: int):
    """:func:`plant_derivatives` for any model: RK4 on the state and the variational equations."""
    x = np.array(x, dtype=float)
    u = np.asarray(u, dtype=float)
    K, n = x.shape
    m = u.shape[1]
    h = float(period) / int(substeps)
    # W = [dx/dx_0 | dx/du] (K, n, n + m): dW/dt = A W + [0 | B], one product per stage for both
    W = np.zeros((K, n, n + m))
    W[:, :, :n] = np.eye(n)

    def stage(xs, Ws):
        A, B = model.linearize(xs, u)
        dW = A @ Ws
        dW[:, :, n:] += B
        return model.rhs(xs, u), dW

    for _ in range(int(substeps)):
        f1, d1 = stage(x, W)
        f2, d2 = stage(x + (0.5 * h) * f1, W + (0.5 * h) * d1)
        f3, d3 = stage(x + (0.5 * h) * f2, W + (0.5 * h) * d2)
        f4, d4 = stage(x + h * f3, W + h * d3)
        x = x + (h / 6.0) * (f1 + 2.0 * f2 + 2.0 * f3 + f4)
        d2 += d3
        d2 *= 2.0
        d2 += d1
        d2 += d4
        d2 *= h / 6.0
        W += d2
    return x, W[:, :, :n], W[:, :, n:]


def _unicycle_derivatives(x: np.ndarray, u: np.ndarray, period: float, substeps: int):
    """The unicycle's hold-interval map and its exact derivatives in closed form. Its heading rate is
    omega at every stage, so RK4's stages see the headings theta + omega tau_j, tau_j = j h / 2
    (j = 0 .. 2 substeps), with weights 1, 4, 2, 4, .., 4, 1 (h / 6 each), and

        F_x = x + (h/6) v sum_j w_j cos(theta_j),   F_y = y + (h/6) v sum_j w_j sin(theta_j),
        F_theta = theta + T omega,

    whose derivatives are sums of the same terms (d/dtheta rotates F - x, d/domega weighs each term by
    tau_j). F is computed as the plant computes it (:func:`nhstab.execution.plant._unicycle_step`,
    the same rotations in the same order) but from cosines and sines of theta and omega h / 2 by
    :func:`nhstab.geometry.cos_sin`: it equals the plant's step to rounding (1e-14 m at tens of metres), the derivatives
    the variational RK4's (tested)."""
    h = float(period) / int(substeps)
    hh, w6 = 0.5 * h, h / 6.0
    px, py, th = x[:, 0], x[:, 1], x[:, 2]
    v, w = u[:, 0], u[:, 1]
    N = len(px)
    cs = cos_sin(np.concatenate([th, hh * w]))
    c, ca = cs[0][:N], cs[0][N:]
    s, sa = cs[1][:N], cs[1][N:]
    wv = w6 * v
    turn = w6 * (w + 2.0 * w + 2.0 * w + w)
    sc = np.zeros(N)                # sum_j w_j cos(theta_j), and with tau_j: tc
    ss = np.zeros(N)
    tc = np.zeros(N)
    ts = np.zeros(N)
    for k in range(int(substeps)):
        c2, s2 = c * ca - s * sa, s * ca + c * sa
        c4, s4 = c2 * ca - s2 * sa, s2 * ca + c2 * sa
        sum_c, sum_s = c + 4.0 * c2 + c4, s + 4.0 * s2 + s4
        px = px + wv * sum_c
        py = py + wv * sum_s
        th = th + turn
        sc += sum_c
        ss += sum_s
        t0 = k * h
        tc += t0 * c + 4.0 * (t0 + hh) * c2 + (t0 + h) * c4
        ts += t0 * s + 4.0 * (t0 + hh) * s2 + (t0 + h) * s4
        c, s = c4, s4
    K = len(px)
    F = np.stack([px, py, th], axis=1)
    Phi = np.zeros((3, 3, K))                   # steps last (see _derivatives)
    Phi[0, 0] = Phi[1, 1] = Phi[2, 2] = 1.0
    Phi[0, 2] = -w6 * v * ss
    Phi[1, 2] = w6 * v * sc
    Gamma = np.zeros((3, 2, K))
    Gamma[0, 0] = w6 * sc
    Gamma[1, 0] = w6 * ss
    Gamma[0, 1] = -w6 * v * ts
    Gamma[1, 1] = w6 * v * tc
    Gamma[2, 1] = int(substeps) * h
    return F, Phi, Gamma


def _rwd_car_derivatives(x: np.ndarray, u: np.ndarray, period: float, substeps: int, L: float):
    """The rwd car's hold-interval map and its exact derivatives, substep by substep in closed form.

    With the input (v, omega_s) held, RK4's stages see phi, phi + h omega_s / 2 (twice) and
    phi + h omega_s, and the headings theta, theta + (h/2) k1_theta, theta + (h/2) k2_theta and
    theta + h k2_theta (k_theta = tan(phi_stage) v / L), as the plant computes them
    (:func:`nhstab.execution.plant._rwd_car_step`, without its steering end stop, which is outside the
    linear model). Each substep's Jacobian follows from these by the chain rule (d tan(phi) / d phi =
    1 + tan(phi)^2), and the substeps' Jacobians are composed. All substeps' stages are arrays
    (substeps, stage, K): three tangents per substep (stages 2 and 3 share theirs), the headings'
    cosines and sines at once by :func:`nhstab.geometry.cos_sin`, the stage sums that the entries share
    formed once (the stages 3 and 4 enter each heading derivative together), and the composition runs
    over the derivatives' entries that are not constant (one long array operation per entry, not one per
    sample). The map equals the plant's step to rounding (1e-14 m at tens of metres: the cosines and the order of the sums
    differ) and the derivatives the variational RK4's (tested)."""
    h = float(period) / int(substeps)
    hh, w6 = 0.5 * h, h / 6.0
    S, K = int(substeps), len(x)
    px, py, th, phi = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    v, ws = u[:, 0], u[:, 1]
    # the steering at each substep as the plant advances it, and its stages' tangents (stages 1, 2 = 3, 4)
    tn = np.empty((S, 3, K))
    step_phi = w6 * (ws + 2.0 * ws + 2.0 * ws + ws)
    half_w, full_w = hh * ws, h * ws
    for s in range(S):
        tn[s, 0] = phi
        np.add(phi, half_w, out=tn[s, 1])
        np.add(phi, full_w, out=tn[s, 2])
        phi = phi + step_phi
    np.tan(tn, out=tn)
    tn /= L                                                   # tan(phi_stage) / L
    kt = tn * v                                               # the heading rates
    TH = np.empty((S, 4, K))                                  # the stages' headings
    for s in range(S):
        k1, k2, k4 = kt[s]
        TH[s, 0] = th
        TH[s, 1] = th + hh * k1
        TH[s, 2] = th + hh * k2
        TH[s, 3] = th + h * k2
        th = th + w6 * (k1 + 2.0 * k2 + 2.0 * k2 + k4)
    C, Sn = cos_sin(TH)
    C34, S34 = C[:, 2] + C[:, 3], Sn[:, 2] + Sn[:, 3]
    sum_c = C[:, 0] + 2.0 * C[:, 1] + C[:, 2] + C34           # sum over the stages with RK4's weights
    sum_s = Sn[:, 0] + 2.0 * Sn[:, 1] + Sn[:, 2] + S34
    wv = w6 * v
    px = px + wv * sum_c.sum(axis=0)
    py = py + wv * sum_s.sum(axis=0)
    # every substep's Jacobian entries at once (arrays (S, K)); J = I + these (+ h at d phi / d omega_s).
    # The stages' headings move with phi by (h/2) v q1, (h/2) v q2, h v q2 (stages 2, 3, 4; q the
    # derivative of tan(phi) / L at the stage), with v by (h/2) t1, (h/2) t2, h t2, and with omega_s by
    # 0, (h/2)^2 v q2, h (h/2) v q2: weighted by RK4's 2, 2, 1, stages 3 and 4 enter as one sum.
    q = 1.0 / L + L * (tn * tn)
    q1, q2, q4 = q[:, 0], q[:, 1], q[:, 2]
    t1, t2, t4 = tn[:, 0], tn[:, 1], tn[:, 2]
    whv, wh = wv * h * v, wv * h
    J02, J12 = -wv * sum_s, wv * sum_c
    J03 = -whv * (Sn[:, 1] * q1 + S34 * q2)
    J13 = whv * (C[:, 1] * q1 + C34 * q2)
    J04 = w6 * sum_c - wh * (Sn[:, 1] * t1 + S34 * t2)
    J14 = w6 * sum_s + wh * (C[:, 1] * t1 + C34 * t2)
    g = (whv * hh) * q2
    J05, J15 = -g * S34, g * C34
    J23 = wv * (q1 + 4.0 * q2 + q4)
    J24 = w6 * (t1 + 4.0 * t2 + t4)
    J25 = wv * (4.0 * hh * q2 + h * q4)
    # compose the substeps, W <- J[:, :4] W + [0 | J[:, 4:]], W = d(x, y, theta, phi) / d(x_0, u) with its
    # known zeros: rows x and y are [1 0 a2 a3 a4 a5] and [0 1 b2 b3 b4 b5], theta [0 0 1 c3 c4 c5],
    # phi [0 0 0 1 0 e5] (e5 = the time so far)
    zero = np.zeros(K)
    a2 = a3 = a4 = a5 = b2 = b3 = b4 = b5 = c3 = c4 = c5 = zero
    e5 = 0.0
    for s in range(S):
        a2, a3, a4, a5 = (a2 + J02[s], (a3 + J02[s] * c3) + J03[s], (a4 + J02[s] * c4) + J04[s],
                          ((a5 + J02[s] * c5) + J03[s] * e5) + J05[s])
        b2, b3, b4, b5 = (b2 + J12[s], (b3 + J12[s] * c3) + J13[s], (b4 + J12[s] * c4) + J14[s],
                          ((b5 + J12[s] * c5) + J13[s] * e5) + J15[s])
        c3, c4, c5 = c3 + J23[s], c4 + J24[s], (c5 + J23[s] * e5) + J25[s]
        e5 = e5 + h
    Phi = np.zeros((4, 4, K))                   # steps last (see _derivatives)
    Gamma = np.zeros((4, 2, K))
    Phi[0, 0] = Phi[1, 1] = Phi[2, 2] = Phi[3, 3] = 1.0
    Phi[0, 2], Phi[0, 3], Phi[1, 2], Phi[1, 3], Phi[2, 3] = a2, a3, b2, b3, c3
    Gamma[0, 0], Gamma[0, 1], Gamma[1, 0], Gamma[1, 1] = a4, a5, b4, b5
    Gamma[2, 0], Gamma[2, 1], Gamma[3, 1] = c4, c5, e5
    return np.stack([px, py, th, phi], axis=1), Phi, Gamma


#: state dimensions up to which the recursions are solved as banded systems (:func:`_banded_scan`; its
#: matrices have n^2 (n + 1)^2 / 4 entries per step against the blocked scan's n^3 products: measured
#: faster for n <= 4, slower for n = 5)
BANDED_MAX_STATES = 4
#: steps per banded solve (bounds the band's memory: 2 d^2 numbers per step, d = n (n + 1) / 2)
BANDED_CHUNK = 512


@functools.lru_cache(maxsize=16)
def _packed_pairs(n: int):
    """The d = n (n + 1) / 2 index pairs (i, j), i <= j, of a symmetric matrix's packed vector: the
    diagonal first, then the pairs above it."""
    iu, ju = np.triu_indices(n, 1)
    I, J = np.concatenate([np.arange(n), iu]), np.concatenate([np.arange(n), ju])
    I.flags.writeable = J.flags.writeable = False          # shared by every call (cached)
    return I, J


def _band_block_view(band: np.ndarray, d: int, s: int) -> np.ndarray:
    """The view V (d, d, s) of LAPACK lower band storage (``band`` ((s + 1) d, 2 d), row c = column c of
    the matrix, entry r = row c + r) at the subdiagonal blocks of a block-bidiagonal matrix with d x d
    blocks: V[i, j, k] = L[(k + 1) d + i, k d + j] = band[k d + j, d + i - j]."""
    kd = 2 * d - 1
    item = band.itemsize
    return np.lib.stride_tricks.as_strided(band.ravel()[d:], shape=(d, d, s),
                                           strides=(item, item * kd, item * d * (kd + 1)), writeable=True)


def _forward_substitution(band: np.ndarray, x: np.ndarray) -> None:
    """Solve L y = x in place (x ((s + 1), d), C order) for the unit lower banded L in ``band``."""
    rhs = x.reshape(-1, 1)
    sol, info = dtbtrs(band.T, rhs, uplo="L", trans="N", diag="U", overwrite_b=1)
    if info != 0:                                  # only for an illegal argument: a bug here, not bad input
        raise NumericalError(f"LAPACK dtbtrs failed (info {info})")
    if not np.shares_memory(sol, rhs):
        x[:] = sol.reshape(x.shape)


def _banded_scan(A: np.ndarray, M: np.ndarray, b: np.ndarray, S0: np.ndarray, m0: np.ndarray):
    """:func:`_block_scan`'s recursions as two unit lower block-bidiagonal linear systems, solved by forward
    substitution in compiled code (LAPACK's banded triangular solve, ``dtbtrs``): the same arithmetic as
    the plain recursion, step by step, up to the order of the sums.

    The covariance in packed form s_k = (S_k[i, j], i <= j) (d entries): s_{k+1} = T_k s_k + m_k with
    T_k[(i, j), (p, q)] = A_ip A_jq + A_iq A_jp (p < q) or A_ip A_jp (p = q) (the packed A_k (x) A_k); the
    mean: m_{k+1} = A_k m_k + b_k. Unknowns in time order make each system's matrix I minus the T_k one
    block below the diagonal, a band of width 2 d - 1; it is solved ``BANDED_CHUNK`` steps at a time,
    each chunk from the last value of the one before. M may come packed ((N, d), as s_k), and A as a
    view of an (n, n, N) array, the layout the band is filled from (then not copied). Returns the packed
    covariances (N + 1, d) (:func:`_unpack` makes them matrices) and the means (N + 1, n)."""
    N, n = A.shape[0], A.shape[1]
    I, J = _packed_pairs(n)
    d = len(I)
    xs = np.empty((N + 1, d))
    xs[0] = S0[I, J]
    xs[1:] = M if M.ndim == 2 else M[:, I, J]
    xm = np.empty((N + 1, n))
    xm[0] = m0
    xm[1:] = b
    As = np.ascontiguousarray(A.transpose(1, 2, 0))       # (n, n, N): the steps last, for long array ops
    nAs = np.negative(As)
    c = min(BANDED_CHUNK, N)
    band_s = np.zeros(((c + 1) * d, 2 * d))
    band_m = np.zeros(((c + 1) * n, 2 * n))
    rI, rJ = I[:, None], J[:, None]
    cI, cJ = I[None, :], J[None, :]
    oI, oJ = I[None, n:], J[None, n:]
    for a in range(0, N, c):
        s = min(c, N - a)
        ac, nac = As[:, :, a:a + s], nAs[:, :, a:a + s]
        bs = band_s[:(s + 1) * d]                          # unit diagonal: never read (diag='U')
        V = _band_block_view(bs, d, s)
        np.multiply(nac[rI, cI], ac[rJ, cJ], out=V)        # -A_ip A_jq
        V[:, n:] -= ac[rI, oJ] * ac[rJ, oI]                # - A_iq A_jp for the pairs p < q
        _forward_substitution(bs, xs[a:a + s + 1])
        bm = band_m[:(s + 1) * n]
        np.copyto(_band_block_view(bm, n, s), nac)
        _forward_substitution(bm, xm[a:a + s + 1])
    return xs, xm


def _unpack(xs: np.ndarray, n: int) -> np.ndarray:
    """Packed symmetric matrices (K, d) (:func:`_packed_pairs`' order) as (K, n, n)."""
    return xs[:, _unpacking(n)].reshape(len(xs), n, n)


@functools.lru_cache(maxsize=16)
def _unpacking(n: int) -> np.ndarray:
    """For each entry (i, j) of an n x n symmetric matrix, row by row, its place in the packed vector."""
    I, J = _packed_pairs(n)
    where = np.empty((n, n), dtype=np.intp)
    where[I, J] = where[J, I] = np.arange(len(I))
    where = where.ravel()
    where.flags.writeable = False
    return where


def _block_scan(A: np.ndarray, M: np.ndarray, b: np.ndarray, S0: np.ndarray, m0: np.ndarray):
    """S_{k+1} = A_k S_k A_k^T + M_k and m_{k+1} = A_k m_k + b_k for k = 0 .. N-1, all N + 1 values.

    Blocks of L ~ sqrt(N) steps: within every block (vectorised across blocks) the prefix maps from the
    block's start, P_j = A_{j-1} .. A_0, C_j (covariance from zero), c_j (mean from zero); then the block
    starts in one pass; then every value as P_j S_start P_j^T + C_j. Affine maps compose without
    subtraction, and no product spans more than one block."""
    N, n = A.shape[0], A.shape[1]
    L = max(1, int(math.ceil(math.sqrt(N))))
    B = -(-N // L)
    pad = B * L - N
    if pad:
        A = np.concatenate([A, np.broadcast_to(np.eye(n), (pad, n, n))])
        M = np.concatenate([M, np.zeros((pad, n, n))])
        b = np.concatenate([b, np.zeros((pad, n))])
    A = A.reshape(B, L, n, n)
    M = M.reshape(B, L, n, n)
    b = b.reshape(B, L, n)
    P = np.empty((B, L + 1, n, n))
    C = np.empty((B, L + 1, n, n))
    c = np.empty((B, L + 1, n))
    P[:, 0] = np.eye(n)
    C[:, 0] = 0.0
    c[:, 0] = 0.0
    for j in range(L):
        Aj = A[:, j]
        P[:, j + 1] = Aj @ P[:, j]
        C[:, j + 1] = Aj @ C[:, j] @ np.swapaxes(Aj, -1, -2) + M[:, j]
        c[:, j + 1] = np.einsum("bij,bj->bi", Aj, c[:, j]) + b[:, j]
    starts_S = np.empty((B + 1, n, n))
    starts_m = np.empty((B + 1, n))
    starts_S[0], starts_m[0] = S0, m0
    for i in range(B):
        starts_S[i + 1] = P[i, L] @ starts_S[i] @ P[i, L].T + C[i, L]
        starts_m[i + 1] = P[i, L] @ starts_m[i] + c[i, L]
    Pj = P[:, :L]
    S = Pj @ starts_S[:B, None] @ transposed(Pj) + C[:, :L]
    mvec = np.einsum("blij,bj->bli", Pj, starts_m[:B]) + c[:, :L]
    # padded steps are the identity map, so the value after step N is the one at index N
    S = np.concatenate([S.reshape(B * L, n, n), starts_S[B:]])[:N + 1]
    mvec = np.concatenate([mvec.reshape(B * L, n), starts_m[B:]])[:N + 1]
    return 0.5 * (S + np.swapaxes(S, -1, -2)), mvec


#: the error covariance counts as unbounded (the sampled loop diverges) beyond this many times the
#: largest variance the noise injects (or 1, whichever is larger)
DIVERGENCE_RATIO = 1e12


def propagate(model: Model, t: np.ndarray, x0: np.ndarray, u_ff: np.ndarray, K: np.ndarray, period: float,
              substeps: int, initial_cov: np.ndarray, sensor_std: np.ndarray, process_std: np.ndarray,
              jumps: np.ndarray | None = None, loop: bool = False) -> CovariancePropagation:
    """Mean and covariance of the tracking error at the samples (see the module docstring).

    t (S,), x0 (S, n): the reference at the samples; u_ff (S - 1, m), K (S - 1, m, n): the feedforward
    and the gains of each control step; period T and substeps of the plant; initial_cov (n, n);
    sensor_std (n,); process_std (n,) per period (the intensity times sqrt(T)), or (S - 1, n) per step (a
    disturbance per metre travelled: the intensity times sqrt of the nominal's move in the step); jumps
    (S - 1, n): the impulses added after each step (default none). ``loop`` uses the plain per-step
    recursion."""
    x0 = np.asarray(x0, dtype=float)
    S, n = x0.shape
    if S < 2:
        raise InputError("x0", "at least two samples (one control step)", S)
    u_ff = np.asarray(u_ff, dtype=float)
    K = np.asarray(K, dtype=float)
    # the derivatives, gains and closed-loop matrices laid out steps last ((rows, columns, steps)): every
    # operation on them below is a few long array operations, not a batch of small matrix products
    F, Phi, Gamma = _derivatives(model, x0[:-1], u_ff, period, substeps)
    drift = F - x0[1:]
    if model.angle_states:
        idx = list(model.angle_states)
        turn = drift[:, idx]
        if not np.abs(turn).max() < math.pi:           # wrap (only where needed: the miss is ~1e-7)
            drift[:, idx] = wrap_angle(turn)
    if jumps is not None:
        drift = drift + np.asarray(jumps, dtype=float)
    Kt = np.ascontiguousarray(K.transpose(1, 2, 0))                  # (m, n, N)
    m = Kt.shape[0]
    G = Gamma[:, 0, None, :] * Kt[0]                                 # G_k = Gamma_k K_k, (n, n, N)
    for b in range(1, m):
        G += Gamma[:, b, None, :] * Kt[b]
    A = Phi - G
    R = np.asarray(sensor_std, dtype=float) ** 2
    Q = np.asarray(process_std, dtype=float) ** 2
    S0 = np.asarray(initial_cov, dtype=float)
    m0 = np.zeros(n)
    I, J = _packed_pairs(n)
    At, Gt = A.transpose(2, 0, 1), G.transpose(2, 0, 1)              # (N, n, n) views
    with np.errstate(over="ignore", invalid="ignore"):
        if not loop and n <= BANDED_MAX_STATES:
            # M_k = G_k R G_k^T + Q packed: M[(i, j)] = sum_b R_b G_ib G_jb, the diagonal first
            GG = G[I] * G[J]
            GG *= R[:, None]
            M = GG.sum(axis=1)
            M[:n] += Q[:, None] if Q.ndim == 1 else Q.T
            xs, mean = _banded_scan(At, M.T, drift, S0, m0)
        else:
            M = (Gt * R) @ transposed(Gt)
            diag = np.arange(n)
            M[:, diag, diag] += Q
            cov, mean = (_loop if loop else _block_scan)(At, M, drift, S0, m0)
            xs = cov[:, I, J]
    # unbounded: not finite, or DIVERGENCE_RATIO times the largest variance the noise injects (at least 1):
    # a large noise makes a large covariance, not a divergent one
    level = max(1.0, float(np.abs(S0).max(initial=0.0)), float(R.max(initial=0.0)), float(Q.max(initial=0.0)))
    if not math.isfinite(level):
        raise NumericalError("the noise's variances overflow: its levels (standard deviations) must stay below "
                             "about 1e150")
    limit = DIVERGENCE_RATIO * level
    if not (np.abs(xs).max() <= limit and np.abs(mean).max() < math.inf):      # also NaN
        bad = ~(np.all(np.isfinite(xs), axis=1) & np.all(np.isfinite(mean), axis=1))
        k = int(np.argmax(bad | (np.abs(xs).max(axis=1) > limit)))
        raise NumericalError(f"the linearised closed loop diverges: the error covariance is unbounded from "
                             f"t = {float(np.asarray(t)[k]):.3g} s (the gains destabilise the sampled loop)")
    if not loop and n <= BANDED_MAX_STATES:
        cov = _unpack(xs, n)
    # the inputs' means u_ff - K m and variances diag(K (S + R) K^T) = sum over the packed pairs (i, j) of
    # K_i K_j S_ij (twice off the diagonal) + sum_b K_b^2 R_b, steps last
    u_mean = u_ff.T - (Kt * mean[:-1].T).sum(axis=1)                  # (m, N)
    xw = xs[:-1].T * np.where(I == J, 1.0, 2.0)[:, None]              # (d, N)
    KK = Kt[:, I] * Kt[:, J]
    KK *= xw
    u_var = KK.sum(axis=1)
    KR = Kt * Kt
    KR *= R[:, None]
    u_var += KR.sum(axis=1)
    return CovariancePropagation(np.asarray(t, dtype=float), mean, cov, u_mean.T, u_var.T, At, Gt,
                                 Phi.transpose(2, 0, 1), Gamma.transpose(2, 0, 1), drift, R, Q, K)


def _loop(A, M, b, S0, m0):
    N, n = A.shape[0], A.shape[1]
    cov = np.empty((N + 1, n, n))
    mean = np.empty((N + 1, n))
    cov[0], mean[0] = S0, m0
    for k in range(N):
        cov[k + 1] = A[k] @ cov[k] @ A[k].T + M[k]
        mean[k + 1] = A[k] @ mean[k] + b[k]
    return 0.5 * (cov + np.swapaxes(cov, -1, -2)), mean


def propagate_loop(*args, **kwargs) -> CovariancePropagation:
    """:func:`propagate` with the plain per-step recursion (the reference the blocked scan is tested
    against)."""
    return propagate(*args, **kwargs, loop=True)


# ---- saturation ---------------------------------------------------------------------------------------

def bivariate_normal_cdf(h, k, rho) -> np.ndarray:
    """P(Z1 <= h, Z2 <= k) for standard normals with correlation rho, vectorised (Owen's T:
    Phi2 = (Phi(h) + Phi(k))/2 - T(h, a_h) - T(k, a_k) - beta; tested against scipy's
    multivariate_normal). Infinite h or k are allowed."""
    h, k, rho = np.broadcast_arrays(np.asarray(h, dtype=float), np.asarray(k, dtype=float),
                                    np.asarray(rho, dtype=float))
    rho = np.clip(rho, -1.0 + 1e-15, 1.0 - 1e-15)
    out = np.empty(h.shape)
    inf_h, inf_k = ~np.isfinite(h), ~np.isfinite(k)
    # infinite limits reduce to one-dimensional probabilities
    out[inf_h] = np.where(h[inf_h] > 0, ndtr(k[inf_h]), 0.0)
    sel = inf_k & ~inf_h
    out[sel] = np.where(k[sel] > 0, ndtr(h[sel]), 0.0)
    fin = ~(inf_h | inf_k)
    hh, kk, r = h[fin], k[fin], rho[fin]
    # exact zeros make a_h or a_k 0/0; a shift of 1e-300 changes the result by far less than rounding
    hh = np.where(hh == 0.0, 1e-300, hh)
    kk = np.where(kk == 0.0, 1e-300, kk)
    s = np.sqrt((1.0 - r) * (1.0 + r))
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        a_h = (kk - r * hh) / (hh * s)
        a_k = (hh - r * kk) / (kk * s)
    beta = np.where(hh * kk > 0, 0.0, 0.5)
    val = 0.5 * (ndtr(hh) + ndtr(kk)) - owens_t(hh, a_h) - owens_t(kk, a_k) - beta
    out[fin] = np.clip(val, 0.0, np.minimum(ndtr(hh), ndtr(kk)))
    return out


#: the saturation bound may be looser than the full computation by at most this fraction of itself ...
SATURATION_SLACK_REL = 1e-2
#: ... or by this much, whichever is larger
SATURATION_SLACK_ABS = 1e-4


def saturation(prop: CovariancePropagation, K: np.ndarray, limits: np.ndarray) -> dict:
    """Probabilities that the (unclipped) inputs of the linear model reach the limits (m, 2).

    Returns per-sample arrays ``per_step`` (S - 1, m): P(u_kj beyond one of its limits); and the scalars
    ``run_bound`` (the upper bound of the module docstring on P(some input saturates at some sample)),
    ``union_bound`` (sum over samples and inputs of the per-sample probabilities, clipped to 1: the
    plain bound, for comparison), ``max_step`` and ``expected_fraction_bound`` (the mean over samples
    of sum_j P(u_kj beyond), an upper bound of the expected fraction of samples with an input at a limit:
    compare run.json's control_effort.saturated_fraction)."""
    lim = np.asarray(limits, dtype=float)
    # steps last: (input, sample) arrays, whose operations run along the samples
    mu, sd = prop.u_mean.T, prop.u_std.T
    steps = mu.shape[1]
    Z = np.empty((2,) + mu.shape)                 # the standardised distances to the upper and lower limits
    np.subtract(lim[:, 1:2], mu, out=Z[0])
    np.subtract(mu, lim[:, 0:1], out=Z[1])
    if np.all(sd > 0):
        Z /= sd
    else:                                         # a deterministic input: beyond its limit or not
        with np.errstate(divide="ignore", invalid="ignore"):
            Z = np.where(sd > 0, Z / sd, np.where(Z <= 0, -np.inf, np.inf))
    P = ndtr(-Z)                                  # P(u > hi), P(u < lo)
    per_step = P[0] + P[1]                        # (m, steps)
    # P(beyond at k, not at k-1) = P(beyond at k) - P(beyond at both), per input and side, with the
    # pair's bivariate probability; for the smallest P(beyond at k) the pair is not computed and
    # P(beyond at k) itself bounds the term: those terms add at most `slack` in all, where slack is
    # SATURATION_SLACK_REL times a lower bound of the true probability (the largest per-sample one; the
    # bound is at or above the true probability) or SATURATION_SLACK_ABS, whichever is larger
    run = float(np.sum(per_step[:, 0])) if steps else 0.0
    if steps > 1:
        later = P[:, :, 1:]                       # (2, m, steps - 1)
        slack = max(SATURATION_SLACK_REL * max(float(later.max()), float(per_step[:, 0].max())),
                    SATURATION_SLACK_ABS)
        total = float(later.sum())
        if total <= slack:                        # every term left out: no pair is computed
            live = None
            run += total
        else:                                     # the smallest terms that add up to at most slack are left
            small = np.sort(later[later <= slack])     # out (a term above slack never is)
            cut = int(np.searchsorted(np.cumsum(small), slack, side="right"))
            # ties with the first live value stay live: the terms left out add at most small[:cut].sum() <= slack
            live = later >= small[cut] if cut < small.size else later > slack
            run += float(later[~live].sum())
        if live is not None and live.any():
            ks = np.flatnonzero((live[0] | live[1]).any(axis=0))  # the steps k - 1 (0-based over 1 ..) with a live pair
            # cross-covariance of consecutive inputs, its diagonal: K_k (A_{k-1} S_{k-1} - G_{k-1} R) K_{k-1}^T
            C = prop.A[ks] @ prop.cov[ks] - prop.G[ks] * prop.R[None, None, :]
            diag = np.sum((K[ks + 1] @ C) * K[ks], axis=-1).T            # (m, len(ks))
            s1, s0 = sd[:, ks + 1], sd[:, ks]
            with np.errstate(divide="ignore", invalid="ignore"):
                rho = np.where((s1 > 0) & (s0 > 0), diag / (s1 * s0), 0.0)
            np.clip(rho, -1.0, 1.0, out=rho)
            rho[np.isnan(rho)] = 0.0
            lv = live[:, :, ks]                         # (2, m, len(ks)): both sides in one evaluation
            zk, zp = Z[:, :, ks + 1][lv], Z[:, :, ks][lv]
            both = bivariate_normal_cdf(-zk, -zp, np.broadcast_to(rho, lv.shape)[lv])
            run += float(np.sum(np.clip(later[:, :, ks][lv] - both, 0.0, None)))
    return {"per_step": per_step.T, "run_bound": min(1.0, run), "union_bound": min(1.0, float(per_step.sum())),
            "max_step": float(per_step.max(initial=0.0)),
            "expected_fraction_bound": float(np.minimum(per_step.sum(axis=0), 1.0).mean()) if steps else 0.0}
