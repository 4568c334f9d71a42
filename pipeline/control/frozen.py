"""The frozen-time gramian law: a causal alternative to Remark 2's past window.

At each time t, Proposition 1's construction is applied to the linearisation *frozen* at t, the pair
(A(t), B(t)) held constant over a window of length delta:

    H_f(t) = int_0^delta exp(-w alpha s) exp(-A(t) s) B(t) B(t)^T exp(-A(t)^T s) ds,
    P_f(t) = H_f(t)^-1,        u = u0 - gamma B(t)^T P_f(t) (x - x0).

It needs x0(t), u0(t) at the current time only: no future nominal (the reason for Remark 2), and no
past one either. For a time-invariant pair it *is* Proposition 1 (the future window gramian of an LTI
system does not depend on t), so on the straight line at constant speed it has the future window's
closed-loop eigenvalues, and on any LTI system the 3 alpha guarantee.

Why it works, and when. For every fixed t the corrected dP_c/dt identity (docs/theory/control-law.md,
Weighting) holds with dP/dt = 0:

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
A hold begins causally: where H_f is singular, where the gain norm exceeds ``max_gain``, or where
lambda_max(P_f) grows faster than exp(w alpha t) (its logarithmic derivative, by a backward
difference, above w alpha: the stop coming; blind to the rotations of the frame that leave the law
unchanged, so a circle at constant speed is never held).

Leaving a stop. The frozen pair assumes the current speed for a whole window; where the robot speeds
up out of a stop or a cusp, P_f falls fast (the same logarithmic derivative below -w alpha) and that
assumption fails the other way: the frozen lateral gain (~ 1/v) of the low speed turns the robot hard
to remove, within a window of motion at that low speed, a lateral error that the coming motion
removes anyway or that a short move cannot remove at all, and the heading error stays. (On a
straight line through a cusp, from 0.1 m of lateral error, the heading error peaks at 0.39 rad there,
``tests/control/test_frozen_time.py``.) So a hold ends only where the law is admissible *and* P_f no
longer falls faster than exp(-w alpha t): once the robot is up to speed. Every stop is then treated
like the start of a plan: up to the stop (the hold's least controllable point) the last admissible
gramian is carried forward; from the stop on, the first admissible gramian after the hold is carried
back, H(t) = Phi(t, s) H_f(s) Phi(t, s)^T with s after t. The gains leaving a stop are those of the
motion it leads into, in its direction (after a cusp the carried-forward gramian belongs to the other
direction of travel, and carried into the new one it turns the robot the wrong way). The cost is
a look-ahead at each stop, by the time the nominal takes to get up to speed (about 1.4 s for the
unicycle's default 0.5 m/s^2 to 0.8 m/s; ``lookahead_s`` in the diagnostics for the start): the law
is causal except that, at a stop, it needs the motion it is about to start, as any reference
generator knows it. A hold that runs to the end of the nominal (the final stop, where there is no
motion after) is carried forward throughout; at rest the held law then drives the error towards the
line H_held n (n the direction it cannot act on, the unicycle's lateral one), which makes V non-
increasing but can leave a small heading error per lateral error at the goal. Where a hold hands
over (at the stop, and from a hold without a stop, such as a sharp turn, back to P_f), V = e^T P e
can jump up by the factor lambda_max(P_before^-1 P_after) (``resume_jump_max``), which the certified
rate shows as a short, strongly negative stretch; at a cusp the jump can be tens (no P of one direction
of travel is a good Lyapunov matrix for the other), so the certificate does not carry across cusps
even where the closed loop converges.

Not used for leaving a stop: holding on through the acceleration with the gramian from before the
stop (across a cusp it turns the robot the wrong way); and at the final stop, the frozen pair's
pseudo-inverse on the directions it still controls (P = sum f(lambda_i) v_i v_i^T with f faded below
the gain bound), which trades smaller along-track errors for larger heading errors at the goal, since
a run ends when its nominal does and the robot is never at rest long enough for it to act.

Not used instead of holding: regularizing, P = (H_f + eps I)^-1 with the smallest eps that keeps the
gain within ``max_gain`` (fully causal, continuous, no look-ahead; at rest B^T ignores the null
direction). Under twice the default noise it reaches the goal less often than the hold.
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
    # a hold ends only where the law is admissible and P_f no longer falls fast (up to speed again)
    N = len(t)
    held = ~admissible
    for k in range(1, N):
        if held[k - 1] and not held[k] and rho[k] < -cw:
            held[k] = True
    if held.all():                                    # never up to speed: resume where admissible
        held = ~admissible
    holds, lookahead, jumps = [], 0.0, []
    for i, j in _runs(held):                          # indices i..j (inclusive) are held
        # from the stop on (the run's least controllable point), the gramian of the first admissible
        # point after the run is carried back; before it, the last admissible one is carried forward.
        # A run at the start is carried back throughout, one at the end forward throughout.
        if i == 0:
            m = 0
        elif j == N - 1:
            m = N
        else:
            m = i + int(np.argmin(np.where(singular[i:j + 1], -np.inf, lam[i:j + 1, 0])))
        if m > i:                                     # carry forward from s = i - 1, to k = i .. last
            s, last = i - 1, min(m - 1, j)
            pieces = interval_segments(nominal, t[s:last], t[s + 1:last + 1] - t[s:last], 0.0, substeps).P
            F = np.linalg.inv(_cumulative(pieces))            # Phi(t_k, t_s) = Phi(t_s, t_k)^-1
            H[i:last + 1] = F @ H[s] @ np.swapaxes(F, -1, -2)
        if m <= j:                                    # carry back from s = j + 1 (admissible), to k = m .. j
            s = j + 1
            pieces = interval_segments(nominal, t[m:s], t[m + 1:s + 1] - t[m:s], 0.0, substeps).P
            F = _cumulative(pieces, from_right=True)         # Phi(t_k, t_s)
            H[m:j + 1] = F @ H[s] @ np.swapaxes(F, -1, -2)
            if i == 0:
                lookahead = float(t[s] - t[0])
            else:
                # where the carried-back gramian takes over, V = e^T P e can jump up by lambda_max(H_before P_after)
                L = np.linalg.cholesky(H[m - 1])
                jumps.append(float(np.linalg.eigvalsh(L.T @ np.linalg.inv(H[m]) @ L)[-1]))
        holds.append([float(t[i]), float(t[j])])
    info = {"max_gain": float(max_gain), "hold_intervals_s": holds,
            "hold_time_s": float(held.sum() * (t[1] - t[0])),
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
