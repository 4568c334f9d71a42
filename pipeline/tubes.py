"""Error tubes: how far the stabilized robot strays from its nominal, and the clearance that leaves.

For a nominal and its feedback law (a :class:`nhstab.execution.FeedbackLaw`: gramian, TVLQR or open
loop), the control rate with zero-order hold, the plant's substeps and the noise model of ``nhstab run``
(initial error, sensor noise, process disturbance, impulses), :func:`predict_tube`

1. propagates the mean m_k and covariance S_k of the tracking error at every control sample through
   the closed loop linearised along the nominal, exactly discretised at the control rate
   (:mod:`nhstab.control.tube`, linear in the number of samples), with the probability that an input
   saturates (an upper bound for the whole run);
2. turns the pose part of (m_k, S_k) into the region the footprint may occupy at probability p, and
3. measures with FCL (:class:`nhstab.collision.CollisionWorld`) the **certified clearance**: the
   smallest clearance of that region to the obstacles along the nominal.

**The region (conservative).** Let q = 1 - (1 - p)/2. At sample k, with S_xy the position block of S_k,
s_th^2 the heading variance and (m_xy, m_th) the mean error:

* position: the error lies in the ellipse (d - m_xy)^T S_xy^-1 (d - m_xy) <= chi2_2(q) with
  probability q (chi2_2(q) = -2 ln(1 - q), the 2-dof quantile). The ellipse lies in the disc of radius
  **r_k = |m_xy| + sqrt(chi2_2(q) lambda_max(S_xy))** about the nominal position;
* heading: |d_th| <= **s_k = |m_th| + z s_th** with probability q, z the two-sided normal quantile
  of q (Phi(z) = 1 - (1 - q)/2);
* both hold with probability >= 1 - 2 (1 - q) = p (Bonferroni; no independence assumed);
* then every point b of the footprint (body frame; rho = max |b|, the farthest point from the
  reference point, e.g. the rwd car's front corner 3.42 m ahead of its rear axle) moves by at most
  |d_xy| + 2 |b| sin(|d_th|/2) <= **reach_k = r_k + 2 rho sin(min(s_k, pi)/2)**: the footprint lies in
  the footprint at the nominal pose grown by a disc of radius reach_k.

The certified clearance is min_k [c_k - reach_k], with c_k the signed FCL clearance of the footprint at
the nominal pose k: the clearance of the grown footprint, exactly. It is certified per control sample
(the run checks collisions at its control samples), with probability >= p at each sample, under the
linear-Gaussian model; it is not a probability for the whole run. Only the samples where the
conservative distance field cannot show c_k - reach_k above the best value so far are measured
with FCL (usually a small fraction of them), so the minimum is exact at a fraction of the cost.

Also here: the ``--margin auto`` loop (:func:`plan_with_auto_margin`) and the ``--gains auto`` choice
(:func:`choose_gains`), which use the planner and the feedback laws (imported when called).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import ndtri

from .control.interpolant import hermite_weights
from .control.tube import CovariancePropagation, propagate, saturation
from .errors import InputError, NumericalError
from .limits import check_probability
from .geometry import Footprint

#: the default probability of the tube
DEFAULT_PROBABILITY = 0.997
#: ``--margin auto``: the first margin tried [m], the rounds at most, and the room added to a deficit [m]
AUTO_MARGIN_START = 0.02
AUTO_MARGIN_ROUNDS = 5
AUTO_MARGIN_SLACK = 0.01
#: ``--gains auto``: the grid, as factors of the robot's default alpha and delta, and gamma values
AUTO_GAINS_ALPHA = (0.5, 1.0, 2.0)
AUTO_GAINS_DELTA = (0.5, 1.0, 2.0)
AUTO_GAINS_GAMMA = (0.5, 1.0, 2.0)
#: a linear tube's line mentions saturation above this bound
LINEAR_SATURATION_NOTE = 0.01
#: ``--gains auto`` admits settings whose run saturation bound is below this
AUTO_GAINS_MAX_SATURATION = 0.01
CONSTRUCTION = ("per control sample, probability >= p under the linear-Gaussian model: position in the 2-dof "
                "chi-square ellipse at q = 1 - (1 - p)/2, enclosed in a disc of radius r = |m_xy| + "
                "sqrt(chi2_2(q) lambda_max(S_xy)); heading within s = |m_th| + z_q s_th (two-sided, q); "
                "Bonferroni: both with probability >= p; footprint grown by reach = r + 2 rho sin(s/2), rho = "
                "the farthest footprint point from the reference point; certified clearance = min over samples "
                "of FCL clearance at the nominal pose minus reach")
SAMPLED_CONSTRUCTION = ("N rollouts of the run loop (saturating law, plant, zero-order hold, noise model); per control "
                        "sample, reach = the largest displacement of any footprint point over the rollouts (at a vertex "
                        "of the footprint's convex hull: |(R(theta) - R(theta0)) b + p - p0|); certified clearance = "
                        "min over samples of FCL clearance at the nominal pose minus reach; scenario bound: with "
                        "N >= ln(beta) / ln(p), a run keeps it at every sample with probability >= p, with confidence "
                        "1 - beta")


def pose_indices(model) -> list[int]:
    names = list(model.state_names)
    return [names.index("x"), names.index("y"), names.index("theta")]


# ---- the run's sample schedule --------------------------------------------------------------------------

@dataclass
class SampleSchedule:
    """What the run loop uses at its samples t_k = k T (k = 0 .. S - 1, the last the end sample):
    x0 (S, n), u_ff (S - 1, m) the mean of u0 over each hold interval, K (S - 1, m, n), jumps (S - 1, n)
    the impulses added after each step."""

    t: np.ndarray
    x0: np.ndarray
    u_ff: np.ndarray
    K: np.ndarray
    jumps: np.ndarray
    period: float


def run_schedule(law, period: float, t_stop: float | None = None, impulses=()) -> SampleSchedule:
    """The samples of the run loop following ``law`` from tau = 0: steps at tau = k T while
    tau < t_stop - 1e-9 (default: the nominal's end), then the end sample; the reference and gains
    by the law's interpolant, the feedforward as the exact mean of the piecewise-linear u0 over
    [tau, tau + T] (held at its end values outside the span), impulses (time, jump) applied after the
    step whose period contains them (as the run does)."""
    interp = law.interp
    T = float(period)
    t_stop = law.t_end if t_stop is None else float(t_stop)
    steps = int(math.ceil((t_stop - 1e-9) / T)) if t_stop > 1e-9 else 0
    while steps > 0 and (steps - 1) * T >= t_stop - 1e-9:
        steps -= 1
    while steps * T < t_stop - 1e-9:
        steps += 1
    taus = T * np.arange(steps + 1)
    k, a = interp.locate_many(taus)
    # the grid's samples stacked steps last (rows x, h x', u, the integral of u from the start, K), so that
    # each sample time gathers its interval's two ends in one operation each, and every operation after
    # runs along the samples; the schedule's arrays are views of these in the (samples, ...) layout
    x, u, h = interp.x, interp.u, interp.h
    G, n = x.shape
    m = u.shape[1]
    table = np.empty((2 * n + 2 * m + m * n, G))
    table[:n], table[n:2 * n], table[2 * n:2 * n + m] = x.T, interp.xd.T, u.T
    ut = table[2 * n:2 * n + m]
    cum = table[2 * n + m:2 * (n + m)]
    cum[:, 0] = 0.0
    np.cumsum(0.5 * h * (ut[:, 1:] + ut[:, :-1]), axis=1, out=cum[:, 1:])
    table[2 * (n + m):] = interp.K.reshape(G, -1).T
    lo, hi = np.take(table, k, axis=1), np.take(table, k + 1, axis=1)
    h00, h10, h01, h11 = hermite_weights(a)      # x0: the grid interpolant's cubic Hermite
    x0 = h00 * lo[:n] + h10 * lo[n:2 * n] + h01 * hi[:n] + h11 * hi[n:2 * n]
    # the feedforward: the mean of the piecewise-linear u0 over each hold interval, from its integral
    ul, uh = lo[2 * n:2 * n + m], hi[2 * n:2 * n + m]
    U = lo[2 * n + m:2 * (n + m)] + (h * a) * (ul + (0.5 * a) * (uh - ul))
    before, after = taus < interp.t[0], taus > interp.t[-1]       # held at the end values outside the span
    if before.any():
        U[:, before] += u[0][:, None] * (taus[before] - interp.t[0])
    if after.any():
        U[:, after] += u[-1][:, None] * (taus[after] - interp.t[-1])
    u_ff = np.diff(U, axis=1)
    u_ff /= T
    ak = a[:-1]
    K = (1.0 - ak) * lo[2 * (n + m):, :-1] + ak * hi[2 * (n + m):, :-1]
    x0, u_ff, K = x0.T, u_ff.T, K.reshape(interp.K.shape[1:] + (steps,)).transpose(2, 0, 1)
    jumps = np.zeros((steps, n))
    for time_s, jump in impulses:
        k = max(0, int(math.floor((float(time_s) + 1e-12) / T)))
        while k > 0 and float(time_s) < k * T - 1e-12:       # the first step with time < (k + 1) T - 1e-12
            k -= 1
        while float(time_s) >= (k + 1) * T - 1e-12:
            k += 1
        if k < steps:
            jumps[k] += np.asarray(jump, dtype=float)
    return SampleSchedule(taus, x0, u_ff, K, jumps, T)


# ---- the tube ---------------------------------------------------------------------------------------------

@dataclass
class Tube:
    """A predicted error tube along one nominal; per-sample arrays (index k, time t[k]) and a summary."""

    probability: float
    t: np.ndarray                      # (S,) sample times from the nominal's start
    poses: np.ndarray                  # (S, 3) nominal poses at the samples
    mean: np.ndarray                   # (S, n) mean tracking error
    cov: np.ndarray                    # (S, n, n) its covariance
    position_radius: np.ndarray        # (S,) r_k [m]
    heading_spread: np.ndarray         # (S,) s_k [rad]
    reach: np.ndarray                  # (S,) reach_k [m]
    u_mean: np.ndarray                 # (S - 1, m)
    u_std: np.ndarray                  # (S - 1, m)
    saturation_per_step: np.ndarray    # (S - 1, m)
    saturation: dict
    certified_clearance: float | None  # None without a world
    certified_index: int | None
    nominal_clearance_there: float | None
    clearance_evaluations: int
    state_names: tuple
    footprint_reach: float             # rho
    info: dict = field(default_factory=dict)
    #: "linear" (the linear-Gaussian model) or "sampled" (rollouts of the run loop, nhstab.sampled_tube)
    kind: str = "linear"
    #: what the certified clearance means: kind, probability, for a sampled tube N and the confidence
    certificate: dict = field(default_factory=dict)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.einsum("kii->ki", self.cov), 0.0))

    def state_quantile(self) -> float:
        """chi2_n(p): the squared Mahalanobis radius of the full-state p-ellipsoid."""
        from scipy.stats import chi2

        return float(chi2.ppf(self.probability, len(self.state_names)))

    def inside(self, e: np.ndarray, pose_idx=None) -> tuple[np.ndarray, np.ndarray]:
        """For errors e (..., S, n) at the samples: (inside the full-state p-ellipsoid, inside the
        pose region the spatial tube is built from). The linear tube's pose region: the position
        ellipse at q and the heading band at q. The sampled tube's: the footprint displaced by at most
        the reach (its ellipsoid uses the rollouts' sample covariance: a diagnostic, not its region)."""
        e = np.asarray(e, dtype=float)
        d = e - self.mean
        cov = self.cov + 1e-300 * np.eye(self.cov.shape[-1])
        sol = np.linalg.solve(cov, d[..., None])[..., 0] if d.ndim == 2 else \
            np.einsum("kij,...kj->...ki", np.linalg.inv(cov), d)
        d2 = np.einsum("...i,...i->...", d, sol)
        state = d2 <= self.state_quantile()
        ix, iy, ith = pose_idx if pose_idx is not None else self.info["pose_indices"]
        if self.kind == "sampled":
            from .sampled_tube import displacement

            moved = self.poses + e[..., [ix, iy, ith]]
            return state, displacement(self.info.get("hull"), moved, self.poses) <= self.reach
        q = 1.0 - (1.0 - self.probability) / 2.0
        Sxy = self.cov[:, [ix, iy]][:, :, [ix, iy]]
        dxy = d[..., [ix, iy]]
        Sinv = np.linalg.inv(Sxy + 1e-300 * np.eye(2))
        pos = np.einsum("...ki,kij,...kj->...k", dxy, Sinv, dxy) <= -2.0 * math.log(1.0 - q)
        z = float(ndtri(1.0 - (1.0 - q) / 2.0))
        head = np.abs(d[..., ith]) <= z * np.sqrt(self.cov[:, ith, ith])
        return state, pos & head

    @property
    def certified(self) -> bool | None:
        """Whether the certified clearance is non-negative (None without a world)."""
        return None if self.certified_clearance is None else bool(self.certified_clearance >= 0.0)

    def summary(self) -> dict:
        """The ``tube`` record of plan.json and run.json."""
        std = self.std
        k_r = int(np.argmax(self.position_radius))
        sat = self.saturation
        out = {"kind": self.kind, "probability": self.probability,
               "max_position_radius_m": float(self.position_radius.max()),
               "max_heading_spread_rad": float(self.heading_spread.max()),
               "certified_clearance_m": self.certified_clearance, "certified": self.certified,
               "saturation_probability": sat["run_bound"],
               "max_position_radius_time_s": float(self.t[k_r]),
               "max_reach_m": float(self.reach.max()), "mean_reach_m": float(self.reach.mean()),
               "final_reach_m": float(self.reach[-1]),
               "footprint_reach_m": self.footprint_reach,
               "max_std_by_state": dict(zip(self.state_names, std.max(axis=0).tolist())),
               "final_std_by_state": dict(zip(self.state_names, std[-1].tolist())),
               "samples": len(self.t), "period_s": self.info.get("period_s"),
               "certificate": dict(self.certificate)}
        if self.kind == "sampled":
            out["saturation"] = {"observed_fraction": sat["observed_fraction"],
                                 "rollouts_saturated": sat["rollouts_saturated"],
                                 "upper_bound": sat["upper_bound"],
                                 "max_per_sample": sat["max_per_sample"], "expected_fraction": sat["expected_fraction"],
                                 "note": "saturation_probability is the fraction of the tube's rollouts whose inputs "
                                         "reached a limit at some sample (upper_bound: its one-sided Clopper-Pearson "
                                         "bound at the certificate's confidence)"}
            out["construction"] = SAMPLED_CONSTRUCTION
        else:
            out["saturation"] = {"run_bound": sat["run_bound"], "union_bound": sat["union_bound"],
                                 "max_per_sample": sat["max_step"],
                                 "expected_fraction_bound": sat["expected_fraction_bound"],
                                 "note": "saturation_probability is an upper bound (linear-Gaussian model) of the "
                                         "probability that some input reaches a limit at some sample: excursions "
                                         "counted once (see nhstab.control.tube)"}
            out["construction"] = CONSTRUCTION
        if "verdict" in self.info:
            out["verdict"] = self.info["verdict"]
        if self.certified_index is not None:
            k = self.certified_index
            out.update({"certified_clearance_time_s": float(self.t[k]),
                        "certified_clearance_pose": self.poses[k].tolist(),
                        "nominal_clearance_there_m": self.nominal_clearance_there,
                        "reach_there_m": float(self.reach[k]),
                        "clearance_evaluations": self.clearance_evaluations})
        return out


def initial_covariance(noise, state_names) -> np.ndarray:
    """diag(sigma0^2) for a gaussian initial error, diag(sigma0^2 / 3) for a uniform one."""
    s0 = noise.vector("initial", state_names)
    return np.diag(s0 ** 2 if noise.distribution == "gaussian" else s0 ** 2 / 3.0)


def predict_tube(law, noise, footprint: Footprint, world=None, *, rate_hz: float = 50.0, substeps: int = 4,
                 model=None, probability: float = DEFAULT_PROBABILITY, initial_cov: np.ndarray | None = None,
                 t_end: float | None = None, impulses: bool = True, kind: str = "auto",
                 confidence: float | None = None) -> Tube:
    """The error tube of ``law`` (a FeedbackLaw) under ``noise`` (a NoiseOptions), see the module
    docstring. ``world``: the CollisionWorld of the obstacles to certify against (None: no certified
    clearance). ``model``: the real robot (input limits for the saturation probability; default the
    nominal's, which for a plan with headroom is the derated one). ``initial_cov``: the initial error's
    covariance, diagonal (default: the noise's initial error; a replan starts from a measured state, whose
    error is the sensor noise). ``impulses``: include the noise's impulses (times from the start).

    ``kind``: "linear" (the linear-Gaussian tube), "sampled" (rollouts of the run loop,
    :func:`nhstab.sampled_tube.sampled_tube`, with ``confidence``), or "auto" (default): the linear tube
    where it holds (:func:`nhstab.sampled_tube.linear_validity`: no input saturation to speak of and no
    interior stop), the sampled one elsewhere; the tube's ``certificate`` says which and why. With a
    world the tube carries its :func:`verdict` (without the plan's margin; call it again with it)."""
    from .sampled_tube import DEFAULT_CONFIDENCE, TUBE_KINDS, linear_validity, sampled_tube

    check_probability("probability", probability)
    if kind not in TUBE_KINDS:
        raise InputError("tube", "one of " + ", ".join(TUBE_KINDS), kind)
    confidence = DEFAULT_CONFIDENCE if confidence is None else confidence
    nominal_model = law.nominal.model
    model = model or nominal_model
    names = model.state_names
    lin, why = None, "asked for"
    if kind != "sampled":
        try:
            lin = _linear_tube(law, noise, footprint, None, rate_hz, substeps, model, probability, initial_cov,
                               t_end, impulses)
        except NumericalError:
            if kind == "linear":
                raise
            why = "the linearised closed loop diverges"
        if lin is not None:
            valid, why = linear_validity(lin, law.nominal)
            lin.certificate = {"kind": "linear", "probability": float(probability), "valid": valid, "why": why,
                               "statement": f"per control sample, probability >= {probability:g} under the closed loop "
                                            "linearised along the nominal (Gaussian noise, no input saturation)"}
            if kind == "linear" or valid:
                if world is not None:
                    (lin.certified_clearance, lin.certified_index, lin.nominal_clearance_there,
                     lin.clearance_evaluations) = certified_clearance(world, footprint, lin.poses, lin.reach)
                    verdict(lin, world, footprint)
                return lin
    sample_noise = noise
    if initial_cov is not None:
        S0 = np.asarray(initial_cov, dtype=float)
        if S0.shape != (model.n, model.n) or np.any(S0 != np.diag(np.diag(S0))) or np.any(np.diag(S0) < 0):
            raise InputError("initial_cov", "a diagonal covariance of the robot's states (the sampled tube draws "
                             "independent initial errors)", S0.shape)
        scale = float(noise.scale)
        raw = np.sqrt(np.diag(S0)) / scale if scale > 0 else np.zeros(model.n)
        sample_noise = replace(noise, distribution="gaussian", initial={s: float(v) for s, v in zip(names, raw)})
    if not impulses:
        sample_noise = replace(sample_noise, impulses=())
    tube = sampled_tube(law, sample_noise, footprint, world, rate_hz=rate_hz, substeps=substeps, model=model,
                        probability=probability, confidence=confidence, t_end=t_end, why=why)
    if world is not None:
        verdict(tube, world, footprint)
    return tube


def _linear_tube(law, noise, footprint, world, rate_hz, substeps, model, probability, initial_cov, t_end,
                 impulses) -> Tube:
    names = model.state_names
    T = 1.0 / float(rate_hz)
    sched = run_schedule(law, T, t_end, noise.impulse_list(names) if impulses else ())
    S0 = initial_covariance(noise, names) if initial_cov is None else np.asarray(initial_cov, dtype=float)
    prop = propagate(model, sched.t, sched.x0, sched.u_ff, sched.K, T, substeps, S0,
                     noise.vector("sensor", names), noise.vector("process", names) * math.sqrt(T), sched.jumps)
    sat = saturation(prop, sched.K, model.input_limits())
    return _spatial(prop, sched, sat, model, footprint, world, probability)


def _spatial(prop: CovariancePropagation, sched: SampleSchedule, sat: dict, model, fp: Footprint, world,
             probability: float) -> Tube:
    idx = pose_indices(model)
    ix, iy, ith = idx
    q = 1.0 - (1.0 - probability) / 2.0
    chi2_2 = -2.0 * math.log(1.0 - q)
    z = float(ndtri(1.0 - (1.0 - q) / 2.0))
    # the larger eigenvalue of the symmetric 2 x 2 position block, in closed form
    a, b, c = prop.cov[:, ix, ix], prop.cov[:, ix, iy], prop.cov[:, iy, iy]
    lam_max = 0.5 * (a + c) + np.hypot(0.5 * (a - c), b)
    r = np.hypot(prop.mean[:, ix], prop.mean[:, iy]) + np.sqrt(chi2_2 * np.maximum(lam_max, 0.0))
    s = np.abs(prop.mean[:, ith]) + z * np.sqrt(np.maximum(prop.cov[:, ith, ith], 0.0))
    rho = fp.bounding_radius
    reach = r + 2.0 * rho * np.sin(np.minimum(s, math.pi) / 2.0)
    poses = sched.x0[:, idx]
    cert, k_cert, c_there, evals = (None, None, None, 0)
    if world is not None:
        cert, k_cert, c_there, evals = certified_clearance(world, fp, poses, reach)
    info = {"pose_indices": idx, "period_s": sched.period, "q": q, "chi2_2": chi2_2, "z": z,
            "model": "closed loop linearised along the nominal, exact ZOH discretisation at the control rate"}
    return Tube(probability, sched.t, poses, prop.mean, prop.cov, r, s, reach, prop.u_mean, prop.u_std,
                sat["per_step"], sat, cert, k_cert, c_there, evals, tuple(model.state_names), rho, info)


def certified_clearance(world, fp: Footprint, poses: np.ndarray, reach: np.ndarray):
    """min_k [clearance(fp at poses[k]) - reach[k]], exactly, with its index, the clearance there and
    the number of poses whose clearance was measured (:meth:`CollisionWorld.min_clearance_less`: a branch
    and bound on lower bounds from the distance field and the objects' boxes, measuring only the poses
    whose bound does not pass the best value found)."""
    poses = np.asarray(poses, dtype=float)
    if not len(poses):
        return math.inf, -1, math.nan, 0
    return world.min_clearance_less(poses, fp, np.asarray(reach, dtype=float))


def tube_needs(tube, world, fp: Footprint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples where the tube is not clear (idx), the nominal clearance each would need, and its
    deficit (negative): for a sampled tube with its rollouts measured (``info["rollout_clearance"]``),
    the nominal clearance there minus the worst rollout's, and that rollout's clearance; otherwise the
    tube's reach at the samples whose grown footprint is not clear, and the grown footprint's clearance."""
    rc = tube.info.get("rollout_clearance")
    if rc is not None:
        if "failing_index" not in rc:
            return np.zeros(0, dtype=int), np.zeros(0), np.zeros(0)
        return (np.asarray(rc["failing_index"], dtype=int), np.asarray(rc["failing_need_m"], dtype=float),
                np.asarray(rc["failing_worst_m"], dtype=float))
    idx, gap = failing_samples(world, fp, tube.poses, tube.reach)
    return idx, tube.reach[idx], gap


def failing_samples(world, fp: Footprint, poses: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples whose grown footprint is not clear (c_k < reach_k), and their c_k - reach_k. Samples
    the distance field shows clear are not measured."""
    from .clearance_field import disc_cover

    field = world.clearance_field()
    cand = np.arange(len(poses))
    if field is not None:
        bound = field.cover_bound(poses, disc_cover(fp))
        cand = np.flatnonzero(bound < reach)
    gap = np.array([world.clearance(poses[k], fp) - reach[k] for k in cand])
    bad = gap < 0.0
    return cand[bad], gap[bad]


def plan_with_auto_margin(plan_at, tube_of, world, fp: Footprint, *, cap: float,
                          start: float = AUTO_MARGIN_START, rounds: int = AUTO_MARGIN_ROUNDS,
                          slack: float = AUTO_MARGIN_SLACK):
    """``--margin auto``: plan at a small margin, predict the tube, and while its certified clearance is
    negative replan with the margin the failing samples need, a few rounds at most.

    ``plan_at(margin)`` -> (PlanResult, FeedbackLaw or None); ``tube_of(law)`` -> a :class:`Tube` with a
    certified clearance against ``world`` (or None if the linearised loop diverges); ``cap``: the
    largest margin the request allows (the start's and goal's clearance, less 1 mm).

    After each plan, the samples whose grown footprint is not clear (:func:`failing_samples`) are split:
    those whose reach exceeds cap - slack cannot be certified by any margin the request allows (a tube
    wider than the start's or goal's own clearance, typically right at them); the others are fixable,
    and the next margin is max(m + slack, their largest reach + slack), so that a nominal keeping it
    certifies them if the tube stays as wide. A margin that finds no plan is bisected with the largest
    margin that found one. The loop stops when no fixable sample fails, when the margin cannot grow, or
    after ``rounds`` plans. The plan kept: the smallest margin with no fixable failure, else the one
    whose fixable samples come closest to clear. Returns (result, law, tube, record) (the failed first
    result and law None if no round found a plan; the first plan with tube None, not certified, if its
    linearised loop diverges); ``record`` says what happened."""
    history, cands, last = [], [], None
    record = {"mode": "auto", "rounds": history, "start_margin_m": min(start, cap), "cap_m": cap,
              "max_rounds": rounds, "slack_m": slack}
    margin = min(start, cap)
    ok_margin, fail_margin = None, None
    for i in range(rounds):
        result, law = plan_at(margin)
        entry = {"round": i, "margin_m": margin, "status": result.status}
        last = result
        history.append(entry)
        if law is None:
            entry["message"] = result.message
            if ok_margin is None:
                break
            fail_margin = margin if fail_margin is None else min(fail_margin, margin)
            if fail_margin - ok_margin < 2 * slack:
                entry["stopped"] = f"no plan at margin {fail_margin:.3g} m"
                break
            margin = 0.5 * (ok_margin + fail_margin)
            continue
        tube = tube_of(law)
        if tube is None:
            entry["stopped"] = "no tube: the linearised closed loop diverges"
            if not cands:               # the plan stands, its margin not chosen by a tube
                record.update(margin_m=margin, certified=False, certified_clearance_m=None,
                              message=f"margin auto: NOT certified: no tube at margin {margin:.3g} m (the "
                                      "linearised closed loop diverges under the law); kept that plan")
                return result, law, None, record
            break
        idx, need, gap = tube_needs(tube, world, fp) if tube.certified_clearance < 0 else \
            (np.zeros(0, dtype=int), np.zeros(0), np.zeros(0))
        pinned = need + slack > cap
        fix_gap = float(gap[~pinned].min()) if np.any(~pinned) else 0.0
        entry.update(certified_clearance_m=tube.certified_clearance,
                     nominal_min_clearance_m=result.metrics.get("min_clearance_m"),
                     max_reach_m=float(tube.reach.max()), failing_samples=int(len(idx)),
                     failing_beyond_cap=int(pinned.sum()), fixable_clearance_m=fix_gap)
        if pinned.any():
            entry["beyond_cap_times_s"] = [float(tube.t[idx[pinned]].min()), float(tube.t[idx[pinned]].max())]
            entry["beyond_cap_max_reach_m"] = float(need[pinned].max())
        cands.append(((1, -margin) if fix_gap >= 0.0 else (0, fix_gap), margin, result, law, tube, entry))
        if fix_gap >= 0.0 or i == rounds - 1:
            break
        ok_margin = margin if ok_margin is None else max(ok_margin, margin)
        nxt = min(cap, max(margin + slack, float(need[~pinned].max()) + slack))
        if fail_margin is not None and nxt >= fail_margin:
            if fail_margin - margin < 2 * slack:
                entry["stopped"] = f"no plan at margin {fail_margin:.3g} m"
                break
            nxt = 0.5 * (margin + fail_margin)
        if nxt <= margin + 1e-9:
            entry["stopped"] = f"the margin cannot grow past {cap:.3g} m (the start's or goal's clearance)"
            break
        margin = nxt
    if not cands:
        record.update(margin_m=None, certified=False,
                      message="margin auto: " + (history[-1].get("stopped")
                                                 or f"no plan at margin {history[-1]['margin_m']:.3g} m"))
        return last, None, None, record
    _, margin, result, law, tube, chosen = max(cands, key=lambda c: c[0])
    ok = tube.certified_clearance >= 0.0
    trail = ", ".join(f"{h['margin_m']:.3g} m -> " + (f"{h['certified_clearance_m']:+.3f} m" if "certified_clearance_m" in h
                                                       else h["status"]) for h in history)
    if ok:
        text = (f"margin auto: certified at margin {margin:.3g} m (tube clearance {tube.certified_clearance:+.3f} m "
                f"at p = {tube.probability:g}) after {len(history)} round(s): {trail}")
    elif chosen["fixable_clearance_m"] >= 0.0:
        a, b = chosen["beyond_cap_times_s"]
        text = (f"margin auto: margin {margin:.3g} m certifies every sample it can; NOT certified at "
                f"{chosen['failing_beyond_cap']} sample(s) in t = {a:.2f}-{b:.2f} s, where the tube reaches "
                f"{chosen['beyond_cap_max_reach_m']:.3f} m but the start's or goal's clearance allows a margin of "
                f"{cap:.3g} m at most (tube clearance {tube.certified_clearance:+.3f} m); rounds: {trail}")
    else:
        why = next((h["stopped"] for h in reversed(history) if "stopped" in h), f"{len(history)} rounds used")
        text = (f"margin auto: NOT certified ({why}); kept margin {margin:.3g} m, the closest to clear: tube clearance "
                f"{tube.certified_clearance:+.3f} m at t = {tube.t[tube.certified_index]:.2f} s; rounds: {trail}")
    record.update(margin_m=margin, certified=ok, certified_clearance_m=tube.certified_clearance,
                  certified_where_possible=bool(chosen["fixable_clearance_m"] >= 0.0), message=text)
    return result, law, tube, record


#: ``--fit``: the plans tried at most after the first (a margin that certifies, then other maneuvers)
FIT_TRIES = 4


def fit_plan(plan_at, tube_of, world, fp: Footprint, *, margin: float, cap: float, first, tries: int = FIT_TRIES,
             slack: float = AUTO_MARGIN_SLACK):
    """``--fit``: when the first plan's tube is not certified clear, change the plan until one is, cheapest
    first, and keep the best found.

    1. **The margin the tube needs**, where the room allows: a plan at the tube verdict's needed margin
       (the largest reach among the samples whose grown footprint is not clear) plus ``slack``, if that
       is below ``cap`` (the start's and goal's own clearance); a margin that finds no plan is halved
       towards the last that did, once.
    2. **Another maneuver**: plans with other seeds (``plan_at(margin, k)`` for k = 1, 2, ...) at the
       largest margin that found a plan, a different path through the same space (the car planner also
       falls back to its full steering range where its reserved lock finds nothing).

    Each try is judged by its own tube. Two other remedies were measured and are not tried: slowing the
    nominal near obstacles and before cusps (process noise grows per second while a car corrects a
    lateral error per metre driven: on twelve parking plans, 0.5 m/s there raised the gramian law's
    collisions from 2.9 % to 18.3 % of rollouts) and other gain settings (gamma 2, delta 3 s or alpha x 3
    were worse on the same plans, or singular). ``plan_at(margin, k)`` -> (PlanResult, FeedbackLaw or None);
    ``tube_of(law)`` -> a Tube with its verdict, or None; ``first`` = (result, law, tube) at ``margin``.
    Returns (result, law, tube, margin, record); the record lists every try."""
    result, law, tube = first
    rows = [{"try": "the plan", "margin_m": margin, "seed_offset": 0, "status": result.status,
             "certified_clearance_m": None if tube is None else tube.certified_clearance}]
    record = {"tries": rows, "max_tries": tries}
    if law is None or tube is None or tube.certified is not False:
        record.update(chosen=0, certified=None if tube is None else tube.certified,
                      message="fit: nothing to do" + ("" if tube is None or tube.certified is None
                                                       else " (the plan's tube is certified clear)"))
        return result, law, tube, margin, record
    cands = [(tube.certified_clearance, 0, result, law, tube, margin)]
    ok_margin = margin

    def attempt(label, mg, k):
        r, lw = plan_at(mg, k)
        tb = tube_of(lw) if lw is not None else None
        rows.append({"try": label, "margin_m": mg, "seed_offset": k, "status": r.status,
                     "certified_clearance_m": None if tb is None else tb.certified_clearance})
        if tb is not None and tb.certified_clearance is not None:
            cands.append((tb.certified_clearance, len(rows) - 1, r, lw, tb, mg))
        return lw is not None, tb is not None and tb.certified is True

    v = tube.info.get("verdict") or verdict(tube, world, fp, margin)
    need = v.get("needed_margin_m")
    left = tries
    if need is not None and left > 0:
        want = min(need + slack, cap)
        if want > margin + 1e-9:
            found, done = attempt(f"margin {want:.3g} m (the tube's need)", want, 0)
            left -= 1
            if found:
                ok_margin = want
            elif left > 0 and want - margin > 2 * slack:
                half = 0.5 * (margin + want)
                found, done = attempt(f"margin {half:.3g} m (halfway)", half, 0)
                left -= 1
                ok_margin = half if found else ok_margin
            if done:
                left = 0
    k = 1
    while left > 0 and not any(c[4].certified for c in cands):
        _, done = attempt(f"another maneuver (seed + {k}) at margin {ok_margin:.3g} m", ok_margin, k)
        left -= 1
        k += 1
    best = max(cands, key=lambda c: (c[4].certified is True, c[0]))
    clearance, i, result, law, tube, mg = best
    record.update(chosen=i, certified=bool(tube.certified), margin_m=mg)
    trail = "; ".join(f"{r['try']}: " + (f"{r['certified_clearance_m']:+.3f} m" if r["certified_clearance_m"] is not None
                                         else r["status"]) for r in rows)
    record["message"] = (f"fit: {'certified' if tube.certified else 'NOT certified'} after {len(rows)} plan(s), "
                         f"kept {rows[i]['try']} (tube clearance {clearance:+.3f} m); {trail}")
    return result, law, tube, mg, record


def choose_gains(nominal, defaults: dict, tube_of, window: str = "future", *,
                 alphas=AUTO_GAINS_ALPHA, deltas=AUTO_GAINS_DELTA, gammas=AUTO_GAINS_GAMMA,
                 max_saturation: float = AUTO_GAINS_MAX_SATURATION):
    """``--gains auto``: the gramian law's (alpha, delta, gamma) for this nominal from a small grid
    (alpha and delta as factors of the robot's defaults, gamma as given), minimising the tube's mean
    reach over the samples subject to a run saturation bound below ``max_saturation``. Settings whose
    window does not fit the nominal or whose gramian is singular are skipped. ``tube_of(law)`` -> Tube
    (no world needed). Returns (law, record); if no setting meets the saturation bound, the one with
    the smallest bound, and the record says so."""
    from .errors import PipelineError
    from .execution.controllers import ControllerOptions, build_law

    rows, best, fallback = [], None, None
    for fa in alphas:
        for fd in deltas:
            for g in gammas:
                a, d = float(defaults["alpha"]) * fa, float(defaults["delta"]) * fd
                row = {"alpha": a, "delta": d, "gamma": float(g)}
                try:
                    law = build_law(nominal, ControllerOptions(kind="gramian", window=window, alpha=a, delta=d,
                                                               gamma=float(g)), defaults)
                    tube = tube_of(law)
                except PipelineError as exc:
                    row["skipped"] = " ".join(str(exc).split())[:160]
                    rows.append(row)
                    continue
                row.update(mean_reach_m=float(tube.reach.mean()), max_reach_m=float(tube.reach.max()),
                           saturation_probability=tube.saturation["run_bound"],
                           max_gain_norm=law.info.get("max_gain_norm"))
                rows.append(row)
                key = (row["mean_reach_m"], row["saturation_probability"])
                if row["saturation_probability"] < max_saturation and (best is None or key < best[0]):
                    best = (key, row, law)
                if fallback is None or row["saturation_probability"] < fallback[0]:
                    fallback = (row["saturation_probability"], row, law)
    default_row = next((r for r in rows if r["alpha"] == float(defaults["alpha"]) and r["delta"] == float(defaults["delta"])
                        and r["gamma"] == float(defaults["gamma"])), None)
    if best is None and fallback is None:
        raise InputError("--gains", "a gain grid with at least one usable setting for this nominal", "auto",
                         detail="every setting was skipped: " + (rows[-1].get("skipped", "") if rows else ""))
    chosen = best if best is not None else fallback
    row, law = chosen[1], chosen[2]
    met = best is not None
    text = (f"gains auto: alpha {row['alpha']:g}, delta {row['delta']:g} s, gamma {row['gamma']:g}: mean reach "
            f"{row['mean_reach_m']:.3f} m, saturation bound {row['saturation_probability']:.3g}")
    if default_row is not None and "mean_reach_m" in default_row:
        text += (f" (defaults alpha {default_row['alpha']:g}, delta {default_row['delta']:g}, gamma "
                 f"{default_row['gamma']:g}: {default_row['mean_reach_m']:.3f} m, "
                 f"{default_row['saturation_probability']:.3g})")
    if not met:
        text += f"; NO setting has a saturation bound below {max_saturation:g}: kept the smallest"
    record = {"mode": "auto", "chosen": {k: row[k] for k in ("alpha", "delta", "gamma")}, "objective": "mean reach",
              "max_saturation": max_saturation, "met": met, "default": default_row, "grid": rows, "message": text}
    return law, record


def certified_text(tube) -> str:
    """The tube's certified clearance for a message, or that it was not certified (no world: e.g. a robot
    of several bodies, whose tube is certified for no body)."""
    if tube.certified_clearance is None:
        return "clearance not certified (a robot of several bodies)"
    word = "certified clear by" if tube.certified_clearance >= 0 else "NOT certified: tube clearance"
    return f"{word} {tube.certified_clearance:+.3f} m"


def verdict(tube, world, fp: Footprint, margin: float | None = None, cap: float | None = None) -> dict:
    """What a user needs to act on a tube: certified or not, at which probability, by which kind of tube,
    where it is tightest (time, pose, the nominal's clearance and the tube's reach there), and where it
    is not certified, the margin that would certify it if the tube stayed as wide (the largest reach
    among the samples whose grown footprint is not clear; for a sampled tube with its rollouts kept, the
    nominal clearance each failing sample would need for its worst rollout to clear), and whether that
    is more than ``cap`` (the start's or goal's own clearance: no plan keeps it). Stored as
    ``tube.info["verdict"]`` (and in the ``tube`` record of plan.json and run.json)."""
    out = {"kind": tube.kind, "probability": tube.probability, "certified": tube.certified,
           "certified_clearance_m": tube.certified_clearance}
    if tube.kind == "sampled":
        out.update(rollouts=tube.certificate["rollouts"], confidence=tube.certificate["confidence"],
                   saturated_fraction=tube.saturation["observed_fraction"])
    else:
        out.update(saturation_bound=tube.saturation["run_bound"], linear_valid=tube.certificate.get("valid"))
    if tube.certificate.get("why"):
        out["why_this_kind"] = tube.certificate["why"]
    if margin is not None:
        out["margin_m"] = float(margin)
    rc = tube.info.get("rollout_clearance")
    if tube.certified_clearance is not None and tube.certified_index is not None and tube.certified_index >= 0:
        k = tube.certified_index
        out["tightest"] = {"time_s": float(tube.t[k]), "pose": [float(v) for v in tube.poses[k]],
                           "nominal_clearance_m": tube.nominal_clearance_there, "reach_m": float(tube.reach[k])}
        if rc is not None:
            out["tightest"].update(rollout_clearance_m=rc["clearance_m"], rollout_displacement_m=rc["displacement_m"])
        if tube.certified_clearance < 0 and rc is not None:
            a, b = rc["failing_times_index"]
            out.update(failing_samples=rc["failing_samples"], failing_times_s=[float(tube.t[a]), float(tube.t[b])],
                       needed_margin_m=rc["needed_clearance_m"])
            if not rc.get("complete", True):
                out["needed_margin_note"] = "a lower bound: not every pose that may touch was measured"
        elif tube.certified_clearance < 0 and world is not None:
            idx, gap = failing_samples(world, fp, tube.poses, tube.reach)
            if len(idx):
                out["failing_samples"] = int(len(idx))
                out["failing_times_s"] = [float(tube.t[idx].min()), float(tube.t[idx].max())]
                out["needed_margin_m"] = float(tube.reach[idx].max())
        if cap is not None and "needed_margin_m" in out and out["needed_margin_m"] > cap:
            out["beyond_start_or_goal"] = {"clearance_m": float(cap), "note": "the margin it needs is more than the "
                                           "start's or goal's own clearance: no plan between them keeps it"}
    tube.info["verdict"] = out
    return out


def tube_line(tube, noise_scale: float | None = None, prefix: str = "tube") -> str:
    """One line for a user: certified or not, at which probability, which tube, where it is tightest and
    what would certify it (from :func:`verdict`, which must have run)."""
    v = tube.info.get("verdict") or {}
    if tube.kind == "sampled":
        how = (f"sampled: {tube.certificate['rollouts']} rollouts of the run loop, confidence "
               f"{tube.certificate['confidence']:.3g}, the whole run")
    else:
        how = "linear, per sample"
    head = f"{prefix} (p = {tube.probability:g}, {how}" + (f", noise x{noise_scale:g}" if noise_scale is not None else "") + ")"
    if tube.certified_clearance is None:
        return (f"{head}: clearance not certified (a robot of several bodies); reach up to "
                f"{float(tube.reach.max()):.2f} m")
    text = f"{head}: {certified_text(tube)}"
    t = v.get("tightest")
    if t:
        x, y, th = t["pose"][:3]
        text += (f"; tightest at t = {t['time_s']:.2f} s, pose ({x:.2f}, {y:.2f}, {th:.2f} rad), where the plan keeps "
                 f"{t['nominal_clearance_m']:.3f} m and " + (
                     f"a rollout moved {t['rollout_displacement_m']:.3f} m" if "rollout_displacement_m" in t
                     else f"the tube reaches {t['reach_m']:.3f} m"))
    if tube.certified is False:
        if "needed_margin_m" in v:
            a, b = v["failing_times_s"]
            text += (f"; a margin of {v['needed_margin_m']:.2f} m over t = {a:.1f}-{b:.1f} s would certify it "
                     + (f"(planned with {v['margin_m']:.2f} m)" if "margin_m" in v else "(if the tube stayed as wide)"))
            if "beyond_start_or_goal" in v:
                text += (f", more than the start's or goal's own clearance ({v['beyond_start_or_goal']['clearance_m']:.2f} m): "
                         "no plan between them keeps it at this noise")
    if tube.kind == "sampled":
        frac = tube.saturation["observed_fraction"]
        if frac > 0:
            text += f"; inputs reach a limit in {100.0 * frac:.0f} % of rollouts"
    elif tube.saturation["run_bound"] > LINEAR_SATURATION_NOTE:
        text += f"; inputs may saturate (probability <= {tube.saturation['run_bound']:.2g})"
    return text


#: the refusal of ``margin: auto`` for a robot of several bodies (a car with trailers)
SEVERAL_BODIES = ("a margin in metres for a robot of several bodies (the error tube's clearance is certified "
                  "for one footprint; margin auto is for one-body robots)")


def plan_and_tube(m, robot, start, goal, path_options, timing_options, *, margin="auto",
                  gains: str = "default", noise=None, probability: float = DEFAULT_PROBABILITY,
                  rate_hz: float = 50.0, substeps: int = 4, world=None, plan_robot=None, tube_kind: str = "auto",
                  confidence: float | None = None, fit: bool = False):
    """``nhstab plan`` with its tube: plan (``margin`` a number, or "auto" for
    :func:`plan_with_auto_margin`), the gramian law with the robot's default parameters (``gains``
    "auto": :func:`choose_gains`), and the error tube under ``noise`` (a NoiseOptions; default: the run's
    default noise) at ``rate_hz``, certified against the map's known obstacles. ``robot`` is the real
    robot (a :class:`~nhstab.robot.Robot`: its limits, footprint, stabilizer defaults), ``plan_robot``
    the one the nominal is planned for (derated for headroom; default ``robot``). ``tube_kind`` and
    ``confidence``: the tube's kind and its certificate's confidence (:func:`predict_tube`); the tube
    carries its :func:`verdict`. ``fit``: an uncertified plan is changed by :func:`fit_plan` (record in
    ``extra["fit"]``).

    Returns (result, law, tube, extra) with extra = {"tube_model": ..., "margin_auto": ..., "gains_auto": ...,
    "tube_error": ...} (the records that apply); law and tube are None when no plan was found, the tube alone
    (with "tube_error" saying why) when the linearised loop diverges under the law."""
    from dataclasses import replace

    from .collision import CollisionWorld
    from .execution.config import NoiseOptions
    from .execution.controllers import ControllerOptions, build_law
    from .planning import plan

    if gains not in ("default", "auto"):
        raise InputError("--gains", "default or auto", gains)
    plan_robot = plan_robot or robot
    model, fp = plan_robot.model, robot.footprint
    noise = NoiseOptions() if noise is None else noise
    noise.validated(model.state_names)
    several = len(robot.footprints) > 1           # a car with trailers: no certified clearance
    if several and margin == "auto":
        raise InputError("--margin", SEVERAL_BODIES, margin)
    world = world or CollisionWorld.from_map(m, "known")
    defaults = dict(robot.stabilizer)
    extra = {"tube_model": {"noise": noise.describe(model.state_names), "rate_hz": rate_hz, "substeps": substeps,
                            "input_limits": robot.model.input_limits()[:, 1].tolist(),
                            "controller": "gramian, future window",
                            "initial_error": "the noise's initial error about the nominal's start"}}
    path_options = path_options.for_robot(plan_robot)

    def tube_of(law, certify=True):
        try:
            tube = predict_tube(law, noise, fp, world if certify and not several else None, rate_hz=rate_hz,
                                substeps=substeps, model=robot.model, probability=probability,
                                kind=tube_kind if certify else "linear", confidence=confidence)
        except NumericalError as exc:
            if not certify:
                raise                       # choose_gains skips the setting
            extra["tube_error"] = str(exc)  # the plan stands; its tube could not be predicted
            return None
        if certify:
            verdict(tube, None if several else world, fp, state["margin"],
                    cap=None if several else min(world.clearance(np.asarray(p, dtype=float)[:3], fp) for p in (start, goal)))
        return tube

    state = {"margin": None}

    def plan_at(mg, k=0):
        state["margin"] = mg
        opts = replace(path_options, margin=mg, seed=(path_options.seed + k) % (2**31 - 1))
        result = plan(m, plan_robot, start, goal, opts, timing_options, world=world)
        if not result.ok:
            return result, None
        if gains == "auto":
            law, record = choose_gains(result.nominal, defaults, lambda lw: tube_of(lw, certify=False))
            extra["gains_auto"] = record
        else:
            law = build_law(result.nominal, ControllerOptions(kind="gramian"), defaults, result.schedule)
        return result, law

    clear = [world.clearance(np.asarray(p, dtype=float)[:3], fp) for p in (start, goal)]
    if margin == "auto":
        result, law, tube, record = plan_with_auto_margin(plan_at, tube_of, world, fp, cap=min(clear) - 1e-3)
        extra["margin_auto"] = record
        used = record["margin_m"]
    else:
        result, law = plan_at(margin)
        tube, used = (tube_of(law) if law is not None else None), margin
    if fit and law is not None and tube is not None and tube.certified is False:
        result, law, tube, used, record = fit_plan(plan_at, tube_of, world, fp, margin=used, cap=min(clear) - 1e-3,
                                                   first=(result, law, tube))
        extra["fit"] = record
        if margin == "auto":
            extra["margin_auto"]["margin_m"] = used
        else:
            extra["fit_margin_m"] = used
        state["margin"] = used
    return result, law, tube, extra