"""The frozen-time gramian law: a causal alternative to Remark 2's past window.

At each time t, Proposition 1's construction is applied to the linearisation *frozen* at t, the pair
(A(t), B(t)) held constant over a window of length delta:

    H_f(t) = int_0^delta exp(-w alpha s) exp(-A(t) s) B(t) B(t)^T exp(-A(t)^T s) ds,
    P_f(t) = H_f(t)^-1,        u = u0 - gamma B(t)^T P_f(t) (x - x0).

It needs x0(t), u0(t) at the current time only: no future nominal (the reason for Remark 2), and no
past one either. For a time-invariant pair it *is* Proposition 1 (the future window gramian of an LTI
system does not depend on t), so on the straight line at constant speed it has the future window's
closed-loop eigenvalues, and on any LTI system the 3 alpha guarantee.

Why it works, and when. For every fixed t the identity of NOTES.md item 1 holds with dP/dt = 0:

    0 = -w alpha P - P A - A^T P + P [B B^T - exp(-w alpha delta) e^{-A delta} B B^T e^{-A^T delta}] P,

so along the linearised closed loop e' = (A(t) - gamma B B^T P_f) e, with V = e^T P_f e,

    dV/dt <= -(w alpha - mu(t)) V,     mu(t) = lambda_max(P_f^-1/2 dP_f/dt P_f^-1/2),

for gamma >= 1/2. The law is therefore exponentially stabilizing wherever A and B vary slowly
enough that mu(t) < w alpha: the frozen-time (slowly varying systems) argument, made quantitative.
:meth:`GainSchedule.lyapunov_rates` computes the certified rate w alpha - mu(t) along any nominal.

Where it fails. The frozen pair of a drift-free robot at rest (a stop, a cusp where the speed passes
through zero, the start and the end of a plan) is not controllable (Brockett): H_f is singular there,
and near it H_f is nearly singular, the gains grow like 1/v (lateral position, unicycle) or 1/v^2
(cars), and P_f changes fast (mu large). So where the frozen gain norm would exceed ``max_gain`` (or
H_f is singular), the law *holds*: it carries the last admissible gramian along the nominal's
linearised flow, H(t) = Phi(t, s) H_f(s) Phi(t, s)^T (the construction of the ``frozen`` end
strategy), which keeps P continuous and makes V non-increasing there (dV/dt = -2 gamma |B^T P e|^2).
Holding needs only the nominal up to t, and is decided causally: where H_f is singular, where the
gain norm exceeds ``max_gain``, or where lambda_max(P_f) grows faster than exp(w alpha t) (its
logarithmic derivative, by a backward difference, above w alpha: the slow-variation condition in the
direction that matters at a stop, and blind to the rotations of the frame that leave the law
unchanged, so a circle at constant speed is never held). The one exception is a nominal that *starts*
inadmissible (a plan that starts from rest): there the first admissible gramian is carried back to the start, which
looks ahead by the time the nominal takes to get moving (``lookahead_s`` in the diagnostics). Where a
hold ends, P jumps back to the frozen P_f: V can jump up there by the factor lambda_max(P_held^-1 P_f)
(``resume_jump_max``), which the certified rate shows as a short, strongly negative stretch. After a
cusp that factor is large (hundreds: the held P belongs to the other direction of travel, and no
frozen P of one direction is a good Lyapunov matrix for the other), so the certificate does not carry
across cusps even where the closed loop converges.

Tried and set aside: instead of holding, regularizing, P = (H_f + eps I)^-1 with the smallest eps that
keeps the gain within ``max_gain`` (fully causal, continuous, no look-ahead; at rest B^T ignores the
null direction). On 12 trials at twice the default noise (depot and warehouse scenarios, seeds of root
4242, not those of results/causal) it reached the goal in 10 with max_gain 50 and 10 with max_gain 10 (one
collision), the hold in 12 (and the future window in 10).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError, SingularGramianError
from ..nominal import Nominal
from .elements import frozen_segments, interval_segments
from .windows import combine

#: default bound on the frozen law's gain norm before it holds; the same bound as the per-robot
#: stabilizer sweep's (``nhstab sweep``): a 50 Hz zero-order-hold loop stays inside dt ||B K|| < 2
#: and 2 cm of sensor noise stays near the robots' input limits
MAX_GAIN = 50.0
#: the frozen window is built from 2^DOUBLINGS equal pieces (each integrated by one DOP853 step with
#: PIECE_SUBSTEPS substeps), combined exactly by doubling
DOUBLINGS = 6
PIECE_SUBSTEPS = 2


def frozen_gramians(nominal: Nominal, cw: float, delta: float) -> np.ndarray:
    """H_f(t_k) at every grid point (N, n, n), with the weighting exp(-cw s).

    The window is 2^DOUBLINGS pieces of one frozen pair; (P, W) o (P, W) = (P^2, W + e^{-cw d} P W P^T)
    is exact, so only the shortest piece is integrated (8th order)."""
    A, B = nominal.model.linearize(nominal.x, nominal.u)
    seg = frozen_segments(A, B, delta / 2 ** DOUBLINGS, cw, PIECE_SUBSTEPS)
    for _ in range(DOUBLINGS):
        seg = combine(seg, seg, -cw)
    W = seg.W
    return 0.5 * (W + np.swapaxes(W, -1, -2))


def frozen_time_schedule(nominal: Nominal, cw: float, delta: float, gamma: np.ndarray, max_gain: float,
                         singular_rtol: float, singular_atol: float, substeps: int) -> tuple[np.ndarray, dict]:
    """The frozen-time law's H(t) on the nominal's grid, with holds where it is not admissible.

    Returns (H, info); info lists the hold intervals, their total time and the look-ahead at the start.
    """
    t = nominal.t
    n = nominal.model.n
    H = frozen_gramians(nominal, cw, delta)
    lam, V = np.linalg.eigh(H)
    thresholds = np.maximum(singular_atol, singular_rtol * np.abs(lam[:, -1]))
    singular = lam[:, 0] <= thresholds
    safe = np.where(singular[:, None], 1.0, lam)
    P = (V / safe[:, None, :]) @ np.swapaxes(V, -1, -2)
    B = nominal.model.g(nominal.x)
    norms = gamma * np.linalg.norm(np.swapaxes(B, -1, -2) @ P, ord=2, axis=(1, 2))
    rho = _growth(lam[:, 0], singular, t[1] - t[0])
    admissible = ~singular & (norms <= max_gain) & (rho <= cw)
    if not admissible.any():
        if singular.all():
            k = 0
            rank = int(np.sum(lam[k] > thresholds[k]))
            raise SingularGramianError(t[k], lam[k, 0], rank, n, thresholds[k], "frozen-time")
        raise InputError("max_gain", f"at least {float(norms[~singular].min()):.4g}, the smallest gain norm of the "
                         "frozen-time law along this nominal", max_gain)
    runs = _runs(~admissible)
    holds, lookahead, jumps = [], 0.0, []
    for i, j in runs:                                 # indices i..j (inclusive) are held
        if i > 0:                                     # carry forward from s = i - 1
            s = i - 1
            pieces = interval_segments(nominal, t[s:j], t[s + 1:j + 1] - t[s:j], 0.0, substeps).P
            F = np.linalg.inv(_cumulative(pieces))            # Phi(t_k, t_s) = Phi(t_s, t_k)^-1, k = s+1 .. j
        else:                                         # the start: carry back from s = j + 1
            s = j + 1                                 # exists: some point is admissible
            pieces = interval_segments(nominal, t[:s], t[1:s + 1] - t[:s], 0.0, substeps).P
            F = _cumulative(pieces, from_right=True)         # Phi(t_k, t_s), k = 0 .. j
            lookahead = float(t[s] - t[0])
        H[i:j + 1] = F @ H[s] @ np.swapaxes(F, -1, -2)
        holds.append([float(t[i]), float(t[j])])
        if i > 0 and j + 1 < len(t):
            # where the hold ends V = e^T P e can jump up by lambda_max(P_held^-1 P_f)
            L = np.linalg.cholesky(H[j])
            jumps.append(float(np.linalg.eigvalsh(L.T @ P[j + 1] @ L)[-1]))
    info = {"max_gain": float(max_gain), "hold_intervals_s": holds,
            "hold_time_s": float((~admissible).sum() * (t[1] - t[0])),
            "lookahead_s": lookahead,
            "resume_jump_max": max(jumps) if jumps else None,
            "frozen_singular_points": int(singular.sum())}
    return H, info


def _growth(lam_min_H: np.ndarray, singular: np.ndarray, h: float) -> np.ndarray:
    """rho_k = d/dt log lambda_max(P_f) = -d/dt log lambda_min(H_f) at each grid point, by the backward
    difference (causal; forward at the first point); inf where H_f or the previous point is singular."""
    rho = np.full(len(lam_min_H), np.inf)
    if len(lam_min_H) < 2:
        return np.where(singular, np.inf, 0.0)
    ok = ~singular
    log_l = np.log(np.where(ok, lam_min_H, 1.0))
    back = -(log_l[1:] - log_l[:-1]) / h
    pair = ok[1:] & ok[:-1]
    rho[1:] = np.where(pair, back, np.inf)
    rho[0] = rho[1] if ok[0] else np.inf
    return rho


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True as (first, last) index pairs."""
    if not mask.any():
        return []
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return list(zip(starts.tolist(), ends.tolist()))


def _cumulative(pieces: np.ndarray, from_right: bool = False) -> np.ndarray:
    """Running products of the pieces (a short sequential loop: holds are short). Forward:
    out[k] = pieces[0] ... pieces[k]; from the right: out[k] = pieces[k] ... pieces[-1]."""
    out = np.empty_like(pieces)
    acc = np.eye(pieces.shape[-1])
    order = range(len(pieces) - 1, -1, -1) if from_right else range(len(pieces))
    for k in order:
        acc = pieces[k] @ acc if from_right else acc @ pieces[k]
        out[k] = acc
    return out
