"""Sampled error tubes: the closed loop as it actually runs, with a finite-sample certificate.

The linear tube (:mod:`nhstab.tubes`) is exact for the closed loop linearised along the nominal. It
stops holding where that model is wrong: where the inputs reach their limits with non-negligible
probability (the law is clipped, the linear model does not know it) and at stops and cusps, where the
robot is at rest and its error dynamics are the most nonlinear. That is where a parking maneuver's
clearance is small. There, :func:`sampled_tube` runs **N rollouts of the run loop itself** (the
saturating law, the plant's RK4 steps under zero-order hold, the sensor, process and initial noise:
:func:`nhstab.batch.vector.simulate_shared`, each rollout bit-identical to ``nhstab run``'s tracking
loop for its seed) and reports what they did.

**The region.** At control sample k, rollout i's footprint is the nominal footprint moved rigidly by
the pose error: a footprint point b (robot frame) moves by |(R(theta_i) - R(theta_0)) b + (p_i - p_0)|.
That is convex in b, so over the footprint it is largest at a vertex of the footprint's convex hull
(for a disc about the reference point, which a turn does not move: |p_i - p_0|). Call it D_k^i, the
rollout's **displacement**; the rollout's footprint lies inside the nominal footprint grown by D_k^i.
The tube's **reach** is reach_k = max_i D_k^i, and its certified clearance is

    c_cert = min_k [ c_k - reach_k ],   c_k = FCL's clearance of the footprint at the nominal pose k,

the clearance of the footprint grown by the reach: the same construction as the linear tube, with
the reach measured instead of bounded.

**The certificate (scenario bound).** Let g = min_k (c_k - D_k) for a run of this loop: a lower bound
of the run's own clearance at every control sample. min_i g^i = min_k (c_k - max_i D_k^i) = c_cert
(the minima commute). For N independent rollouts of a continuous distribution, the probability mass
of g below the smallest of N samples is Beta(1, N) distributed, so P[P(g < c_cert) > 1 - p] = p^N.
With **N >= ln(beta) / ln(p)** rollouts that is at most beta: with confidence 1 - beta, a run keeps a
clearance of at least c_cert at every control sample with probability at least p. The same argument
at one sample k says that reach_k bounds the p-quantile of the displacement D_k with confidence
1 - beta. This is a statement about **the whole run**, stronger than the linear tube's per-sample
one, and it needs no linearisation, no Gaussian assumption and nothing about saturation: only that
the rollouts are independent runs of the loop that will run (same law, plant, rate, noise model).
It is not a statement about model error (a real robot that is not the model).

**Discarded rollouts.** The largest of N draws overshoots the p-quantile by a margin that shrinks
slowly with N and scatters widely from sample to sample (for a Rayleigh-like displacement at p =
0.997 and N = 998, by 12 % at the median and 26 % in one sample of ten). With r rollouts left out
(``discards``, default :data:`~nhstab.tubes.base.DEFAULT_DISCARDS`), the reach at sample k is the
(r + 1)-th largest D_k^i and the certified clearance the (r + 1)-th smallest of the rollouts' own
clearances g^i (the certificate: the smallest FCL clearance of each rollout's footprint over its
control samples, :func:`rollout_clearance`). The (r + 1)-th largest of N draws lies below the
p-quantile exactly when at most r draws exceed it, with probability P[Binomial(N, 1 - p) <= r]; N is
the smallest with that at most beta (the scenario approach with discarded samples, Campi and
Garatti 2011): N = 998, 1,580, 2,097, 2,583 for r = 0, 1, 2, 3 at p = 0.997 and confidence 0.95. The
statements above hold as they are, with the (r + 1)-th order statistics in place of the extremes;
the tube is closer to the quantile it claims, at the cost of more rollouts. Where the rollouts are
too many to keep, the certified clearance falls back to the grown footprint's with the largest
displacement (a lower bound of the statistic).

Rollout i's root seed is :data:`ROLLOUT_SEED_BASE` + i (numpy SeedSequence streams as a run's), recorded
with the tube, so a rollout can be replayed with ``nhstab run --seed`` on the same plan.
"""

from __future__ import annotations

import math

import numpy as np

from ..batch.vector import simulate_shared
from ..errors import InputError, NumericalError
from ..execution.controllers import FeedbackLaw
from ..geometry import Footprint, wrap_angle
from ..limits import MAX_ROLLOUTS
from ..nominal import Nominal
from .base import (
    DEFAULT_CONFIDENCE,
    DEFAULT_DISCARDS,
    Tube,
    certified_clearance,
    check_discards,
    hull_vertices,
    order_statistic_beta,
    pose_indices,
    rollouts_needed,
    run_schedule,
)

#: rollout i of a sampled tube uses the root seed ROLLOUT_SEED_BASE + i (apart from the small seeds
#: that runs and batches usually take, so that a run is not one of its own plan's rollouts)
ROLLOUT_SEED_BASE = 1 << 40


#: a linear tube is trusted when its run saturation bound is at most this (the same 1 % as --gains auto)
LINEAR_MAX_SATURATION = 0.01


#: the rollouts' poses and displacements are kept for the exact certificate (:func:`rollout_clearance`)
#: up to this much memory (a 30 s car plan's 998 rollouts take 46 MB); beyond, the certificate is the
#: grown footprint's (nominal clearance minus reach), a lower bound of it
EXACT_MEMORY_BYTES = 512 * 1024 * 1024


#: exact clearances measured at most while finding the rollouts' smallest clearance (beyond, the certified
#: clearance is the lower bound of the poses not measured); where it is a contact, the search goes on
#: through the poses that may touch while it has measured fewer than EXACT_CONTACT_EVALUATIONS (the
#: samples in contact and the margin they need)
EXACT_MAX_EVALUATIONS = 200_000


EXACT_CONTACT_EVALUATIONS = 20_000


#: samples of the rollouts reduced together (a block of (samples, rollouts, states) floats)
BLOCK_SAMPLES = 64


def interior_stops(nominal, pose_idx, speed_tol: float = 1e-6) -> list[tuple[float, float]]:
    """Intervals (t_from, t_to) where the nominal's reference point is at rest strictly inside the plan
    (not the leading or trailing rest): cusps, and cars steering in place. At rest: translational speed
    below ``speed_tol`` times the largest speed along the nominal."""
    ix, iy, _ = pose_idx
    xd = nominal.model.rhs(nominal.x, nominal.u)
    speed = np.hypot(xd[:, ix], xd[:, iy])
    top = float(speed.max()) if len(speed) else 0.0
    if top <= 0.0:
        return []
    rest = speed <= speed_tol * top
    moving = np.flatnonzero(~rest)
    first, last = int(moving[0]), int(moving[-1])
    out, k = [], first
    t = nominal.t
    while k <= last:
        if rest[k]:
            j = k
            while j + 1 <= last and rest[j + 1]:
                j += 1
            out.append((float(t[k]), float(t[j])))
            k = j + 1
        else:
            k += 1
    return out


def cusp_stops(nominal, pose_idx) -> list[tuple[float, float]]:
    """The interior stops (:func:`interior_stops`) where the motion reverses: the direction of travel
    (the velocity along the heading) before the stop and after it differ in sign."""
    ix, iy, ith = pose_idx
    xd = nominal.model.rhs(nominal.x, nominal.u)
    along = xd[:, ix] * np.cos(nominal.x[:, ith]) + xd[:, iy] * np.sin(nominal.x[:, ith])
    t = nominal.t
    out = []
    for a, b in interior_stops(nominal, pose_idx):
        before = along[(t < a) & (np.abs(along) > 0)]
        after = along[(t > b) & (np.abs(along) > 0)]
        if len(before) and len(after) and np.sign(before[-1]) != np.sign(after[0]):
            out.append((a, b))
    return out


def remaining_law(law, tau: float):
    """The feedback law ``law`` from time ``tau`` of its plan on, as a law of its own starting at 0 (the
    same grid values of x0, u0 and K from the first grid time at or after tau; None if fewer than three
    grid points are left). For the error tube of the rest of a maneuver."""

    t = law.t
    i = int(np.searchsorted(t, float(tau) - 1e-9 * max(1.0, abs(float(tau)))))
    if i > len(t) - 3:
        return None
    nom = law.nominal
    ts = t[i:] - t[i]
    sub = Nominal(nom.model, ts, nom.x[i:], nom.u[i:])
    return FeedbackLaw(law.kind, sub, ts, law.K[i:], None, dict(law.info))


def linear_validity(tube, nominal) -> tuple[bool, str]:
    """Whether the linear tube holds for this nominal: (valid, why). It does where the inputs do not
    saturate (run bound at most :data:`LINEAR_MAX_SATURATION`) and the nominal has no interior stop."""
    reasons = []
    bound = tube.saturation["run_bound"]
    if bound > LINEAR_MAX_SATURATION:
        reasons.append(f"inputs may saturate (linear bound {bound:.2g} > {LINEAR_MAX_SATURATION:g})")
    stops = interior_stops(nominal, tube.info["pose_indices"])
    if stops:
        reasons.append(f"{len(stops)} interior stop{'s' if len(stops) > 1 else ''} (cusps or steering in place), "
                       f"the first at t = {stops[0][0]:.2f} s")
    if reasons:
        return False, "; ".join(reasons)
    return True, (f"inputs do not saturate (linear bound {bound:.2g} <= {LINEAR_MAX_SATURATION:g}) and the nominal "
                  "has no interior stop")


def sampled_tube(law, noise, footprint: Footprint, world=None, *, rate_hz: float = 50.0, substeps: int = 4,
                 model=None, probability: float = 0.997, confidence: float = DEFAULT_CONFIDENCE,
                 rollouts: int | None = None, seed_base: int = ROLLOUT_SEED_BASE, t_end: float | None = None,
                 keep_displacements: bool = False, keep_states: bool = False, x_start=None, why: str = "",
                 discards: int = DEFAULT_DISCARDS, robot=None):
    """The sampled error tube of ``law`` (a FeedbackLaw) under ``noise`` (a NoiseOptions): N rollouts of
    the run loop (N = :func:`rollouts_needed` (probability, confidence, discards) unless ``rollouts`` is
    given), the per-sample reach (the (r + 1)-th largest footprint displacement of the rollouts, r =
    ``discards``; r = 0: the largest), and with ``world`` the certified clearance (see the module
    docstring). ``model``: the real robot (its input limits clip
    the law; default the nominal's). Returns a :class:`nhstab.tubes.Tube` of kind "sampled", whose
    mean and cov are the rollouts' sample mean and covariance of the tracking error, position_radius
    and heading_spread the largest position and heading errors, and ``saturation`` the fraction of
    rollouts whose inputs reached a limit. ``keep_displacements``: also return every rollout's
    displacement per sample, (N, S), in ``tube.info["displacements"]``; ``keep_states``: every rollout's true
    states (N, S, n) in ``tube.info["states"]`` (for studies and tests). ``x_start``: the mean of the
    initial state (default the nominal's start): the rest of a maneuver from a measured state.

    ``robot``: a :class:`nhstab.robot.Robot` of several bodies (a car and its trailers): every body is
    displaced and measured (:func:`rollout_clearance` over every body's pose; a rollout's clearance is
    the smallest over its bodies and samples), ``footprint`` is the car's, the reach at a sample the
    largest of the bodies' reaches (``info["body_reach"]``: per body), and a rollout whose hitch angle
    passes the model's jackknife limit at a sample is counted (``certificate["jackknifes"]``): the tube
    is certified only when at most r rollouts jackknife. A one-body robot is the same as None.

    Raises :class:`NumericalError` when a rollout diverges (a non-finite state or input): the loop
    cannot be certified."""

    model = model or law.nominal.model
    r = check_discards(discards)
    if rollouts is None:
        N = rollouts_needed(probability, confidence, r)
    else:
        if not (isinstance(rollouts, (int, np.integer)) and not isinstance(rollouts, bool)
                and 1 <= rollouts <= MAX_ROLLOUTS):
            raise InputError("rollouts", f"an integer in [1, {MAX_ROLLOUTS:,}]", rollouts)
        N = int(rollouts)
        rollouts_needed(probability, 0.5)        # checks the probability
        if r >= N:
            raise InputError("discards", f"fewer discarded rollouts than the {N} rollouts", r)
    beta = order_statistic_beta(probability, N, r)
    idx = pose_indices(model)
    n, m = model.n, model.m
    T = 1.0 / float(rate_hz)
    sched = run_schedule(law, T, t_end)
    S = len(sched.t)
    nominal_poses = sched.x0[:, idx]
    hull = hull_vertices(footprint)
    multi = robot is not None and len(robot.footprints) > 1
    if multi:
        fps = tuple(robot.footprints)
        B = len(fps)
        hulls = [hull_vertices(f) for f in fps]
        body_nominal = robot.body_poses(sched.x0)                 # (S, B, 3)
        body_c, body_s = np.cos(body_nominal[..., 2]), np.sin(body_nominal[..., 2])
        jack_limit = float(getattr(model, "jackknife_limit", math.inf))
    else:
        B = 1
    angles = list(model.angle_states)
    lim = model.input_limits()
    acc = {"reach": np.zeros(S), "pos": np.zeros(S), "head": np.zeros(S), "sum": np.zeros((S, n)),
           "sq": np.zeros((S, n, n)), "u_sum": np.zeros((S - 1, m)), "u_sq": np.zeros((S - 1, m)),
           "u_at": np.zeros((S - 1, m)), "sat_any": np.zeros(N, dtype=bool)}
    if r:
        acc["top"] = np.zeros((S, r + 1))       # each sample's r + 1 largest displacements so far
    if multi:
        acc["body_top"] = np.zeros((B, S, r + 1))   # per body: each sample's r + 1 largest displacements
        acc["jack"] = np.zeros(N, dtype=bool)
    exact = world is not None and B * N * S * 8 * 4 <= EXACT_MEMORY_BYTES
    D_all = np.empty((S, N)) if keep_displacements or (exact and not multi) else None   # time-major
    X_all = np.empty((N, S, n)) if keep_states else None
    P_all = np.empty((S, N, 3)) if exact and not multi else None
    # a robot of several bodies: body-major rows (body b, sample k) = row b * S + k
    DB_all = np.empty((B * S, N)) if multi and exact else None
    PB_all = np.empty((B * S, N, 3)) if multi and exact else None
    ix, iy, ith = idx
    nom_c, nom_s = np.cos(nominal_poses[:, 2]), np.sin(nominal_poses[:, 2])

    # the rollouts' states are gathered in blocks of samples and reduced block by block: numpy's
    # operations then run over (block, rollouts) arrays instead of one sample's rollouts at a time
    block = {"k": [], "x": None, "u": None, "rows": None}

    def flush() -> None:
        ks = np.array(block["k"])
        if not len(ks):
            return
        b, rows = len(ks), block["rows"]
        X = block["x"][:, :b]                   # (n, b, Kc): each state's plane contiguous
        E = X - sched.x0[ks].T[:, :, None]
        for a in angles:
            if np.abs(E[a]).max() >= math.pi:
                E[a] = wrap_angle(E[a])
        dx, dy = E[ix], E[iy]
        r2 = dx * dx
        r2 += dy * dy
        if multi:
            D = _bodies_displacement(X, ks, rows)
        elif hull is None:
            D = np.sqrt(r2)
        else:
            dc = np.cos(X[ith])
            dc -= nom_c[ks][:, None]
            ds = np.sin(X[ith])
            ds -= nom_s[ks][:, None]
            D = np.sqrt(_displacement2(hull, dx, dy, dc, ds))     # (b, Kc)
        acc["reach"][ks] = np.maximum(acc["reach"][ks], D.max(axis=1))
        if r:
            both = np.concatenate([acc["top"][ks], D], axis=1)
            acc["top"][ks] = np.partition(both, both.shape[1] - r - 1, axis=1)[:, -(r + 1):]
        acc["pos"][ks] = np.maximum(acc["pos"][ks], np.sqrt(r2.max(axis=1)))
        acc["head"][ks] = np.maximum(acc["head"][ks], np.abs(E[ith]).max(axis=1))
        acc["sum"][ks] += E.sum(axis=2).T
        Eb = np.moveaxis(E, 0, 1)               # (b, n, Kc)
        acc["sq"][ks] += Eb @ np.swapaxes(Eb, 1, 2)
        if D_all is not None:
            D_all[ks[0]:ks[-1] + 1, rows] = D
        if X_all is not None:
            X_all[rows, ks[0]:ks[-1] + 1] = np.moveaxis(X, 0, 2).swapaxes(0, 1)
        if P_all is not None:
            Pb = P_all[ks[0]:ks[-1] + 1, rows]
            Pb[..., 0], Pb[..., 1], Pb[..., 2] = X[ix], X[iy], X[ith]
        ctrl = ks < S - 1
        if ctrl.any():
            c = int(ctrl.sum())                 # the control samples come first in a block
            Ub = block["u"][:c]
            kc = ks[:c]
            acc["u_sum"][kc] += Ub.sum(axis=1)
            acc["u_sq"][kc] += (Ub * Ub).sum(axis=1)
            at = (Ub <= lim[:, 0]) | (Ub >= lim[:, 1])
            acc["u_at"][kc] += at.sum(axis=1)
            acc["sat_any"][rows] |= at.any(axis=(0, 2))
        block["k"] = []

    def _bodies_displacement(X: np.ndarray, ks: np.ndarray, rows: slice) -> np.ndarray:
        """Every body's displacement at the block's samples (per body into the accumulators and the
        body-major arrays), and the largest over the bodies (b, Kc)."""
        BP = robot.body_poses(np.moveaxis(X, 0, -1))             # (b, Kc, B, 3)
        hitch = model.hitch_angles(np.moveaxis(X, 0, -1))        # (b, Kc, trailers)
        acc["jack"][rows] |= (np.abs(hitch) > jack_limit).any(axis=(0, 2))
        out = None
        for j in range(B):
            P = BP[:, :, j]
            dx = P[..., 0] - body_nominal[ks, j, 0][:, None]
            dy = P[..., 1] - body_nominal[ks, j, 1][:, None]
            if hulls[j] is None:
                Dj = np.hypot(dx, dy)
            else:
                dc = np.cos(P[..., 2]) - body_c[ks, j][:, None]
                ds = np.sin(P[..., 2]) - body_s[ks, j][:, None]
                Dj = np.sqrt(_displacement2(hulls[j], dx, dy, dc, ds))
            both = np.concatenate([acc["body_top"][j, ks], Dj], axis=1)
            acc["body_top"][j, ks] = np.partition(both, both.shape[1] - r - 1, axis=1)[:, -(r + 1):]
            if DB_all is not None:
                lo = j * S + ks[0]
                DB_all[lo:lo + len(ks), rows] = Dj
                PB_all[lo:lo + len(ks), rows] = P
            out = Dj if out is None else np.maximum(out, Dj)
        return out

    def observe(rows: slice, k: int, x: np.ndarray, u: np.ndarray | None = None) -> None:
        if block["rows"] != rows or block["x"] is None or block["x"].shape[2] != x.shape[0]:
            flush()
            block.update(rows=rows, x=np.empty((n, BLOCK_SAMPLES, x.shape[0])),
                         u=np.empty((BLOCK_SAMPLES, x.shape[0], m)))
        j = len(block["k"])
        block["x"][:, j] = x.T
        if u is not None:
            block["u"][j] = u
        block["k"].append(k)
        if j + 1 == BLOCK_SAMPLES or k == S - 1:
            flush()

    seeds = [int(seed_base) + i for i in range(N)]
    with np.errstate(over="ignore", invalid="ignore"):
        extra = {} if x_start is None else {"x_start": np.asarray(x_start, dtype=float)}
        res = simulate_shared(law, seeds, noise, rate_hz=rate_hz, substeps=substeps, model=model,
                              t_end=t_end, record=False, on_states=observe, **extra)
        flush()
    if len(res.t) != S:
        raise NumericalError(f"the rollouts' samples ({len(res.t)}) differ from the tube's schedule ({S})")
    failed = ~res.completed
    if failed.any():
        i = int(np.flatnonzero(failed)[0])
        raise NumericalError(f"{int(failed.sum())} of {N} rollouts of the closed loop diverged (a non-finite state or "
                             f"input), the first at t = {res.t_fail[i]:.2f} s (seed {seeds[i]}): no tube")
    mean = acc["sum"] / N
    cov = acc["sq"] / N - np.einsum("ki,kj->kij", mean, mean)
    if N > 1:
        cov *= N / (N - 1.0)
    cov = 0.5 * (cov + np.transpose(cov, (0, 2, 1)))
    u_mean = acc["u_sum"] / N
    u_std = np.sqrt(np.maximum(acc["u_sq"] / N - u_mean ** 2, 0.0))
    per_step = acc["u_at"] / N
    hits = int(acc["sat_any"].sum())
    saturation = {"observed_fraction": hits / N, "rollouts_saturated": hits,
                  "upper_bound": _clopper_pearson_upper(hits, N, confidence),
                  "max_per_sample": float(per_step.max(initial=0.0)),
                  "expected_fraction": float(np.minimum(per_step.sum(axis=1), 1.0).mean()) if S > 1 else 0.0}
    # the fields the linear tube's consumers read, with the sampled meaning
    saturation.update(run_bound=saturation["observed_fraction"], union_bound=None,
                      max_step=saturation["max_per_sample"], expected_fraction_bound=saturation["expected_fraction"])
    largest = acc["reach"]
    reach = acc["top"].min(axis=1) if r else largest
    cert, k_cert, c_there, evals = (None, None, None, 0)
    exact_info = None
    if multi:
        body_reach = acc["body_top"].min(axis=2)               # (B, S): each body's (r + 1)-th largest
        reach = body_reach.max(axis=0)
    if multi and world is not None and exact:
        exact_info = rollout_clearance(world, fps, PB_all, DB_all, body_nominal.transpose(1, 0, 2).reshape(-1, 3),
                                       discards=r)
        cert, k_cert, c_there, evals = (exact_info["clearance_m"], exact_info["sample"],
                                        exact_info["nominal_clearance_m"], exact_info["evaluations"])
    elif multi and world is not None:
        # the largest displacement of each body bounds every rollout's clearance from below
        per = [certified_clearance(world, fps[j], body_nominal[:, j], acc["body_top"][j].max(axis=1)) for j in range(B)]
        cert, k_cert, c_there, evals = min(per, key=lambda v: v[0])
        evals = sum(v[3] for v in per)
    elif world is not None and exact:
        exact_info = rollout_clearance(world, footprint, P_all, D_all, nominal_poses, discards=r)
        cert, k_cert, c_there, evals = (exact_info["clearance_m"], exact_info["sample"],
                                        exact_info["nominal_clearance_m"], exact_info["evaluations"])
    elif world is not None:
        # with discards the rollouts left out differ from sample to sample: the largest displacement bounds all
        cert, k_cert, c_there, evals = certified_clearance(world, footprint, nominal_poses, largest)
    outside = "none below it" if r == 0 else f"at most {r} below it"
    certificate = {"kind": "sampled", "rollouts": N, "discards": r, "probability": float(probability),
                   "confidence": float(1.0 - beta), "beta": float(beta),
                   "seeds": {"first": seeds[0], "last": seeds[-1],
                             "streams": "rollout i: root seed first + i; numpy SeedSequence([root, stream, 0]), "
                                        "streams initial=0, sensor=1, process=2 (as nhstab run)"},
                   "clearance": (("the smallest FCL clearance of any rollout's footprint at any control sample" if r == 0
                                  else f"the {_ordinal(r + 1)} smallest of the rollouts' own smallest FCL clearances "
                                  f"over the control samples (the {r} smallest left out)")
                                 if exact else "min over samples of FCL clearance at the nominal pose minus the largest "
                                 "displacement of any rollout (the rollouts were too many to keep)"),
                   "statement": (f"with confidence {1.0 - beta:.4g} (N = {N} rollouts of the run loop, {outside}), a "
                                 f"run keeps the certified clearance at every control sample with probability >= "
                                 f"{probability:g}; reach_k bounds the {probability:g}-quantile of the footprint's "
                                 f"displacement at each sample with the same confidence")}
    if why:
        certificate["why"] = why
    if multi:
        jack = int(acc["jack"].sum())
        certificate.update(bodies=B, jackknifes=jack, jackknife_limit_rad=jack_limit,
                           clearance_bodies="the smallest over the car and its trailers")
        certificate["statement"] += (f"; every body measured; {jack} of {N} rollouts jackknifed (a hitch angle "
                                     f"beyond {jack_limit:g} rad), the tube is certified only if at most {r} did")
    info = {"pose_indices": idx, "period_s": T, "kind": "sampled", "rollouts": N, "hull": hull,
            "model": "the run loop itself: saturating law, RK4 plant under zero-order hold, the noise model "
                     "(nhstab.batch.vector.simulate_shared)"}
    if exact_info is not None:
        info["rollout_clearance"] = exact_info
    if r:
        info["largest_displacement"] = largest
    if multi:
        info["body_reach"] = body_reach
    if keep_displacements:
        info["displacements"] = D_all.T
    if X_all is not None:
        info["states"] = X_all
    return Tube(probability, sched.t, nominal_poses, mean, cov, acc["pos"], acc["head"], reach, u_mean, u_std,
                per_step, saturation, cert, k_cert, c_there, evals, tuple(model.state_names),
                footprint.bounding_radius, info, kind="sampled", certificate=certificate)


def _displacement2(hull: np.ndarray, dx: np.ndarray, dy: np.ndarray, dc: np.ndarray, ds: np.ndarray) -> np.ndarray:
    """The squared displacement of a footprint moved by (dx, dy) with its heading's cosine and sine changed
    by (dc, ds): |(R - R0) b + dp|^2 at each hull vertex b, the largest."""
    D2, tx, ty = None, np.empty_like(dx), np.empty_like(dx)
    for bx, by in hull:
        np.multiply(dc, bx, out=tx)
        tx -= ds * by
        tx += dx
        np.multiply(ds, bx, out=ty)
        ty += dc * by
        ty += dy
        tx *= tx
        ty *= ty
        tx += ty
        D2 = tx.copy() if D2 is None else np.maximum(D2, tx, out=D2)
    return D2


def rollout_clearance(world, fp: Footprint, poses: np.ndarray, D: np.ndarray, nominal: np.ndarray,
                      discards: int = 0) -> dict:
    """The smallest FCL clearance of the footprint at any rollout pose, poses (S, N, 3) (sample-major), exactly,
    with where it is, without measuring most poses: a branch and bound on the lower bounds c_k - D[k, i] (the
    nominal pose's clearance c_k, measured at every sample, minus the rollout's displacement there: the
    footprint moved by at most D lies within the nominal one grown by D). Poses are measured in
    increasing order of their bound, in batches, until no bound is below the best found (at most
    :data:`EXACT_MAX_EVALUATIONS`). Where the best is negative, the samples where a measured pose is in
    contact, and the nominal clearance each would need for its worst measured rollout to clear
    (``needed_clearance_m``: at least that; ``complete`` says whether every pose that may touch was
    measured, which the search does not wait for).

    This is the certificate's statistic: for rollout i, g_i = min_k clearance(pose[i, k]) (its own
    clearance over the run); the smallest g_i over the N rollouts bounds the p-quantile of g with the
    scenario bound's confidence. It is at least min_k (c_k - reach_k) (the grown footprint's).

    ``discards`` r > 0: the (r + 1)-th smallest g_i instead (:func:`_rollout_clearance_discarding`).

    A robot of several bodies: ``fp`` a tuple of B footprints, and the rows of ``poses``, ``D`` and
    ``nominal`` body-major, B blocks of S samples (row b * S + k: body b at sample k); g_i is then the
    smallest over every body and sample, and the result's ``sample`` and ``body`` say where."""
    S, N = D.shape
    if discards or isinstance(fp, tuple):
        return _rollout_clearance_discarding(world, fp, poses, D, nominal, int(discards))
    c = world.clearance_many(nominal, fp)                              # (S,) exact
    lb = c[:, None] - D
    order = np.argsort(lb, axis=None)
    flat_lb = lb.ravel()[order]
    best, best_at = math.inf, -1
    measured = np.full(N * S, np.nan)
    pos = 0
    batch = 256
    evaluations = 0
    while pos < len(order) and evaluations < EXACT_MAX_EVALUATIONS:
        # no pose left can beat the best (nor, where the best is a contact, touch: while the extra budget
        # for the contacts lasts; a penetration depth is not bounded by the displacement)
        if flat_lb[pos] >= best and (best >= 0.0 or flat_lb[pos] >= 0.0 or evaluations >= EXACT_CONTACT_EVALUATIONS):
            break
        take = order[pos:pos + batch]
        pts = poses.reshape(-1, 3)[take]
        vals = world.clearance_many(pts, fp)
        measured[take] = vals
        evaluations += len(take)
        j = int(np.argmin(vals))
        if vals[j] < best:
            best, best_at = float(vals[j]), int(take[j])
        pos += len(take)
        batch = min(4 * batch, 16384)
    bounded = pos < len(order) and flat_lb[pos] < best and best >= 0.0
    if bounded:                            # the budget ran out: the certificate is the bound, not a pose's value
        best_bound = float(flat_lb[pos])
    if best_at < 0:                        # nothing measured: every bound already at or above c's minimum
        k = int(np.argmin(c))
        i = int(np.argmin(lb[k]))
        best_at = k * N + i
        best = float(world.clearance_many(poses[k, i][None], fp)[0])
        evaluations += 1
    k, i = divmod(best_at, N)
    out = {"clearance_m": best_bound if bounded else best, "rollout": int(i), "sample": int(k),
           "nominal_clearance_m": float(c[k]), "displacement_m": float(D[k, i]), "evaluations": int(evaluations),
           "grown_footprint_clearance_m": float(np.min(c - D.max(axis=1))), "exact": not bounded}
    if best < 0:
        neg = measured.reshape(S, N)
        with np.errstate(invalid="ignore"):
            worst = np.where(neg < 0, neg, np.inf).min(axis=1)       # NaN (not measured) compares False
        bad = np.flatnonzero(np.isfinite(worst))
        complete = pos >= len(order) or flat_lb[min(pos, len(order) - 1)] >= 0.0
        out.update(failing_samples=int(len(bad)), failing_times_index=[int(bad.min()), int(bad.max())],
                   needed_clearance_m=float(np.max(c[bad] - worst[bad])), complete=bool(complete),
                   failing_index=bad, failing_need_m=c[bad] - worst[bad], failing_worst_m=worst[bad])
    return out


def _rollout_clearance_discarding(world, fp: Footprint, poses: np.ndarray, D: np.ndarray, nominal: np.ndarray,
                                  r: int) -> dict:
    """:func:`rollout_clearance` with r rollouts left out: the (r + 1)-th smallest of the rollouts' own
    clearances g_i = min_k clearance(pose[k, i]), by the same branch and bound. Poses are measured in
    increasing order of their bound c_k - D[k, i]; each measured pose lowers its rollout's g_i (an upper
    estimate until all its poses below it are measured); the search stops when no pose left has a bound
    below the (r + 1)-th smallest estimate, which is then exact: a pose not measured cannot lower any
    g_i below it. The failing samples (where the result is a contact) leave out the r rollouts with the
    smallest clearances, as the certificate does. ``fp`` a tuple of B footprints: the rows are B
    body-major blocks (see :func:`rollout_clearance`)."""
    S, N = D.shape
    fps = fp if isinstance(fp, tuple) else (fp,)
    B = len(fps)
    if S % B:
        raise InputError("poses", f"{B} blocks of rows, one per body", S)
    Sb = S // B                                # samples per body

    def measure(pts: np.ndarray, rows_of: np.ndarray) -> np.ndarray:
        if B == 1:
            return world.clearance_many(pts, fps[0])
        body = rows_of // Sb
        out = np.empty(len(pts))
        for j in np.unique(body):
            sel = body == j
            out[sel] = world.clearance_many(pts[sel], fps[j])
        return out

    c = measure(nominal, np.arange(S))
    lb = c[:, None] - D
    order = np.argsort(lb, axis=None)
    flat_lb = lb.ravel()[order]
    g = np.full(N, math.inf)
    measured = np.full(N * S, np.nan)
    pos, batch, evaluations = 0, 256, 0

    def threshold() -> float:
        return float(np.partition(g, r)[r])

    thr = math.inf
    while pos < len(order) and evaluations < EXACT_MAX_EVALUATIONS:
        thr = threshold()
        if flat_lb[pos] >= thr and (thr >= 0.0 or flat_lb[pos] >= 0.0 or evaluations >= EXACT_CONTACT_EVALUATIONS):
            break
        take = order[pos:pos + batch]
        vals = measure(poses.reshape(-1, 3)[take], take // N)
        measured[take] = vals
        np.minimum.at(g, take % N, vals)
        evaluations += len(take)
        pos += len(take)
        batch = min(4 * batch, 16384)
    thr = threshold()
    bounded = pos < len(order) and flat_lb[pos] < thr and thr >= 0.0
    value = min(thr, float(flat_lb[pos])) if bounded else thr
    if not math.isfinite(value):           # fewer than r + 1 rollouts measured: the bound of the rest
        value, bounded = float(flat_lb[min(pos, len(order) - 1)]), True
    grid = measured.reshape(S, N)
    i = int(np.argpartition(g, r)[r])
    col = grid[:, i]
    k = int(np.nanargmin(col)) if np.isfinite(col).any() else int(np.argmin(lb[:, i]))
    top = np.partition(D, N - 1 - r, axis=1)[:, N - 1 - r]
    out = {"clearance_m": value, "rollout": i, "sample": k % Sb, "nominal_clearance_m": float(c[k]),
           "displacement_m": float(D[k, i]), "evaluations": int(evaluations), "discards": r,
           "grown_footprint_clearance_m": float(np.min(c - top)), "exact": not bounded}
    if B > 1:
        out["body"] = int(k // Sb)
    if value < 0:
        left_out = np.argpartition(g, r)[:r]
        kept = grid.copy()
        kept[:, left_out] = np.nan
        with np.errstate(invalid="ignore"):
            worst = np.where(kept < 0, kept, np.inf).min(axis=1)
        bad = np.flatnonzero(np.isfinite(worst))
        if len(bad):
            complete = pos >= len(order) or flat_lb[min(pos, len(order) - 1)] >= 0.0
            need = c[bad] - worst[bad]
            if B > 1:               # per sample: the most any body needs, and the worst clearance
                k_of = bad % Sb
                samples = np.unique(k_of)
                need_s = np.full(Sb, -np.inf)
                worst_s = np.full(Sb, np.inf)
                np.maximum.at(need_s, k_of, need)
                np.minimum.at(worst_s, k_of, worst[bad])
                bad, need, worst_bad = samples, need_s[samples], worst_s[samples]
            else:
                worst_bad = worst[bad]
            out.update(failing_samples=int(len(bad)), failing_times_index=[int(bad.min()), int(bad.max())],
                       needed_clearance_m=float(np.max(need)), complete=bool(complete),
                       failing_index=bad, failing_need_m=need, failing_worst_m=worst_bad)
    return out


def _ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"


def _clopper_pearson_upper(k: int, n: int, confidence: float) -> float:
    """One-sided Clopper-Pearson upper bound on a proportion after k successes in n trials."""
    if k >= n:
        return 1.0
    from scipy.stats import beta as beta_dist

    return float(beta_dist.ppf(confidence, k + 1, n - k))
