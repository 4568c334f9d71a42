"""The error tube's common parts: the run loop's sample schedule, the :class:`Tube` record, its
certified clearance, verdict and one-line report, and the footprint displacement both tubes measure."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri

from ..clearance_field import disc_cover
from ..control.interpolant import hermite_weights
from ..errors import InputError
from ..geometry import Footprint
from ..limits import MAX_ROLLOUTS, check_probability

#: the default probability of the tube
DEFAULT_PROBABILITY = 0.997

#: a nominal's pose that moves less than this between samples (m, rad) stands (:func:`standing_steps`)
STANDING_TOL = 1e-7

#: the time standing before the tightest point from which an uncertified tube's line names its drift [s]
REST_NOTE_S = 2.0


#: a linear tube's line mentions saturation above this bound
LINEAR_SATURATION_NOTE = 0.01


CONSTRUCTION = ("per control sample, probability >= p under the linear-Gaussian model: position in the 2-dof "
                "chi-square ellipse at q = 1 - (1 - p)/2, enclosed in a disc of radius r = |m_xy| + "
                "sqrt(chi2_2(q) lambda_max(S_xy)); heading within s = |m_th| + z_q s_th (two-sided, q); "
                "Bonferroni: both with probability >= p; footprint grown by reach = r + 2 rho sin(s/2), rho = "
                "the farthest footprint point from the reference point; certified clearance = min over samples "
                "of FCL clearance at the nominal pose minus reach")


SAMPLED_CONSTRUCTION = ("N rollouts of the run loop (saturating law, plant, zero-order hold, noise model), r of them "
                        "left out; per control sample, reach = the (r + 1)-th largest displacement of any footprint "
                        "point over the rollouts (at a vertex of the footprint's convex hull: |(R(theta) - R(theta0)) b "
                        "+ p - p0|); certified clearance = the (r + 1)-th smallest of the rollouts' own smallest FCL "
                        "clearances; scenario bound with discarded samples: with P[Binomial(N, 1 - p) <= r] <= beta, a "
                        "run keeps it at every sample with probability >= p, with confidence 1 - beta")


def pose_indices(model) -> list[int]:
    names = list(model.state_names)
    return [names.index("x"), names.index("y"), names.index("theta")]


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
    #: "linear" (the linear-Gaussian model) or "sampled" (rollouts of the run loop, nhstab.tubes.sampled)
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
        """Whether the certified clearance is non-negative (None without a world), and for a rig's
        sampled tube, whether at most the discarded rollouts jackknifed."""
        if self.certified_clearance is None:
            return None
        return bool(self.certified_clearance >= 0.0) and not self.jackknifes_beyond

    @property
    def jackknifes_beyond(self) -> bool:
        """A rig's sampled tube: more rollouts jackknifed than the certificate leaves out."""
        return self.certificate.get("jackknifes", 0) > self.certificate.get("discards", 0)

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
                                         "counted once (see nhstab.tubes.covariance)"}
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
    field = world.clearance_field()
    cand = np.arange(len(poses))
    if field is not None:
        bound = field.cover_bound(poses, disc_cover(fp))
        cand = np.flatnonzero(bound < reach)
    gap = np.array([world.clearance(poses[k], fp) - reach[k] for k in cand])
    bad = gap < 0.0
    return cand[bad], gap[bad]


def certified_text(tube, explain: bool = False) -> str:
    """The tube's certified clearance for a message, or that it was not certified (no world: e.g. a robot
    of several bodies, whose tube is certified for no body); with ``explain``, a negative clearance
    says in words what it means (for a line a user reads; a figure's title keeps the short form)."""
    if tube.certified_clearance is None:
        return "clearance not certified (a robot of several bodies)"
    c = tube.certified_clearance
    cert = getattr(tube, "certificate", None) or {}
    if cert.get("jackknifes", 0) > cert.get("discards", 0):
        return (f"NOT certified: {cert['jackknifes']} of {cert['rollouts']:,} rollouts jackknife (a hitch angle beyond "
                f"{cert['jackknife_limit_rad']:g} rad; at most {cert.get('discards', 0)} may); tube clearance {c:+.3f} m")
    if c >= 0:
        return f"certified clear by {c:+.3f} m"
    text = f"NOT certified: tube clearance {c:+.3f} m"
    if explain:
        text += f" (at this probability the robot's footprint may overlap a known obstacle by {-c:.3f} m)"
    return text


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
            if "body" in rc:
                out["tightest"]["body"] = "car" if rc["body"] == 0 else f"trailer {rc['body']}"
        # the exact certificate names the failing samples when it measured a rollout pose inside an
        # obstacle; a negative clearance from its lower bound alone (the rollouts' measurements cut short)
        # names none, and the samples where the reach meets an obstacle are used instead
        if tube.certified_clearance < 0 and rc is not None and "failing_times_index" in rc:
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
        if tube.certified_clearance < 0:
            still = standing_steps(tube.poses)
            dt = np.diff(tube.t)
            out["at_rest"] = {"before_tightest_s": float(dt[:k][still[:k]].sum()), "total_s": float(dt[still].sum()),
                              "duration_s": float(tube.t[-1] - tube.t[0])}
    if tube.certificate.get("bodies"):
        out.update(bodies=tube.certificate["bodies"], jackknifes=tube.certificate["jackknifes"])
    tube.info["verdict"] = out
    return out


def standing_steps(poses: np.ndarray, tol: float = STANDING_TOL) -> np.ndarray:
    """Per step k -> k + 1 of a nominal's poses (S, 3): whether its pose stays put (position and heading
    within ``tol``): the robot stands (a car steering in place, a stop at a cusp)."""
    poses = np.asarray(poses, dtype=float)
    if len(poses) < 2:
        return np.zeros(0, dtype=bool)
    d = np.diff(poses[:, :3], axis=0)
    d[:, 2] = np.abs(np.angle(np.exp(1j * d[:, 2])))
    return (np.hypot(d[:, 0], d[:, 1]) <= tol) & (d[:, 2] <= tol)


def rest_drift(noise, state_names, seconds: float) -> tuple[float, float] | None:
    """The 1-sigma drift a per-second process disturbance (``noise``, a NoiseOptions) gives a robot
    standing for ``seconds``: (position [m]: the larger of x's and y's, heading [rad]); None when it acts
    per metre travelled (not at rest) or the robot has no x, y, theta."""
    if noise is None or noise.per_metre or not {"x", "y", "theta"} <= set(state_names):
        return None
    lv = dict(zip(state_names, noise.vector("process", list(state_names))))
    root = math.sqrt(max(seconds, 0.0))
    return max(lv["x"], lv["y"]) * root, lv["theta"] * root


def tube_line(tube, noise_scale: float | None = None, prefix: str = "tube", noise=None) -> str:
    """One line for a user: certified or not, at which probability, which tube, where it is tightest and
    what would certify it (from :func:`verdict`, which must have run). ``noise`` (the tube's
    NoiseOptions): when its process disturbance acts per metre travelled the line says so; where a tube
    is not certified and the plan stands still for at least :data:`REST_NOTE_S` before its tightest
    point under a per-second disturbance, the line says how far that moves the robot there
    (:func:`rest_drift`)."""
    v = tube.info.get("verdict") or {}
    per_metre = noise is not None and noise.per_metre
    if tube.kind == "sampled":
        r = tube.certificate.get("discards", 0)
        how = (f"sampled: {tube.certificate['rollouts']:,} rollouts of the run loop"
               + (f", the {r} most extreme left out" if r else "")
               + f", confidence {tube.certificate['confidence']:.3g}, the whole run")
    else:
        how = "linear, per sample"
    head = (f"{prefix} (p = {tube.probability:g}, {how}"
            + (f", noise x{noise_scale:g}" if noise_scale is not None else "")
            + (", process disturbance per metre travelled" if per_metre else "") + ")")
    if tube.certified_clearance is None:
        return (f"{head}: clearance not certified (a robot of several bodies); reach up to "
                f"{float(tube.reach.max()):.2f} m")
    text = f"{head}: {certified_text(tube, explain=True)}"
    t = v.get("tightest")
    if t:
        x, y, th = t["pose"][:3]
        body = f" ({t['body']})" if "body" in t else ""
        text += (f"; tightest at t = {t['time_s']:.2f} s{body}, pose ({x:.2f}, {y:.2f}, {th:.2f} rad), where the plan keeps "
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
        rest = v.get("at_rest")
        drift = rest_drift(noise, tube.state_names, rest["before_tightest_s"]) if rest else None
        if drift is not None and rest["before_tightest_s"] >= REST_NOTE_S:
            text += (f"; before then the plan stands still for {rest['before_tightest_s']:.1f} s (steering in place, "
                     f"stops at cusps), where a per-second process disturbance drifts the robot by {drift[0]:.3f} m "
                     f"and {drift[1]:.3f} rad (1 sigma), which no feedback corrects while it stands (per metre "
                     "travelled, --process-per metre, it does not act at rest)")
    if tube.kind == "sampled":
        frac = tube.saturation["observed_fraction"]
        if frac > 0:
            text += f"; inputs reach a limit in {100.0 * frac:.0f} % of rollouts"
    elif tube.saturation["run_bound"] > LINEAR_SATURATION_NOTE:
        text += "; " + saturation_text(tube.saturation["run_bound"])
    return text


def saturation_text(bound: float) -> str:
    """The linear tube's bound on the probability that the inputs saturate, for a user: a percentage,
    or where the bound is (about) 1, that it says nothing and what measures it."""
    if bound >= 0.995:
        return ("inputs may saturate (the linear bound on how often is 1, no information: --tube sampled "
                "measures it)")
    return f"inputs may saturate (probability at most {100.0 * bound:.2g} %)"


def hull_vertices(fp: Footprint) -> np.ndarray | None:
    """The footprint's convex hull vertices (k, 2) in its frame; None for a disc (centred on the
    reference point: a turn does not move it)."""
    if fp.radius is not None:
        return None
    v = np.asarray(fp.vertices, dtype=float)
    if len(v) <= 3:
        return v
    from scipy.spatial import ConvexHull

    try:
        return v[ConvexHull(v).vertices]
    except Exception:               # degenerate (collinear) outline: every vertex is a candidate
        return v


def displacement(hull: np.ndarray | None, poses: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """How far the footprint's farthest-moving point moves from its nominal place: poses (..., 3)
    against the nominal pose(s) (..., 3) (broadcast). max over the hull's vertices b of
    |(R(theta) - R(theta0)) b + (p - p0)|; |p - p0| for a disc (hull None)."""
    dx = poses[..., 0] - nominal[..., 0]
    dy = poses[..., 1] - nominal[..., 1]
    if hull is None:
        return np.hypot(dx, dy)
    dc = np.cos(poses[..., 2]) - np.cos(nominal[..., 2])
    ds = np.sin(poses[..., 2]) - np.sin(nominal[..., 2])
    out = None
    for bx, by in hull:
        d = np.hypot(dx + dc * bx - ds * by, dy + ds * bx + dc * by)
        out = d if out is None else np.maximum(out, d, out=out)
    return out


#: the default confidence 1 - beta of the sampled tube's certificate
DEFAULT_CONFIDENCE = 0.95


#: tube kinds: "auto" chooses linear where it holds and sampled elsewhere
TUBE_KINDS = ("auto", "linear", "sampled")


#: the sampled tube's default number of discarded rollouts r: its reach at a sample is the (r + 1)-th largest
#: displacement of the N rollouts, and its certified clearance the (r + 1)-th smallest rollout clearance
#: (the scenario bound with discarded samples); r = 0 is the plain largest of N
DEFAULT_DISCARDS = 2


#: the most discarded rollouts a sampled tube may ask for
MAX_DISCARDS = 1000


def check_discards(discards, key: str = "discards") -> int:
    """``discards`` as an int in [0, MAX_DISCARDS], else an InputError naming ``key``."""
    if isinstance(discards, bool) or not isinstance(discards, (int, np.integer)) or not 0 <= discards <= MAX_DISCARDS:
        raise InputError(key, f"an integer in [0, {MAX_DISCARDS}]", discards)
    return int(discards)


def order_statistic_beta(probability: float, rollouts: int, discards: int = 0) -> float:
    """beta = P[Binomial(N, 1 - p) <= r]: the chance that fewer than r + 1 of N independent draws exceed the
    p-quantile, i.e. that the (r + 1)-th largest of N lies below it (r = 0: p^N)."""
    from scipy.stats import binom

    if discards == 0:
        return float(probability) ** int(rollouts)
    return float(binom.cdf(int(discards), int(rollouts), 1.0 - float(probability)))


def rollouts_needed(probability: float, confidence: float = DEFAULT_CONFIDENCE, discards: int = 0) -> int:
    """The smallest N with P[Binomial(N, 1 - p) <= r] <= 1 - confidence (r = ``discards``; for r = 0,
    p^N <= 1 - confidence): N rollouts of which at most r lie outside the reported region bound its
    p-quantile with that confidence (the scenario bound with discarded samples; see
    :mod:`nhstab.tubes.sampled`)."""
    check_probability("probability", probability)
    if not (isinstance(confidence, (int, float)) and 0.0 < confidence < 1.0):
        raise InputError("confidence", "a number in (0, 1)", confidence)
    r = check_discards(discards)
    n = math.log1p(-confidence) / math.log(probability)
    if not math.isfinite(n) or n > MAX_ROLLOUTS:
        raise InputError("confidence", f"a probability and confidence needing at most {MAX_ROLLOUTS:,} rollouts "
                         f"(N >= ln(1 - confidence) / ln(p))", confidence,
                         detail=f"p = {probability:.10g} at confidence {confidence:.10g} needs {n:.4g}")
    # ceil with a guard: p^N may round a hair above the target at an exact integer
    N = max(1, math.ceil(n - 1e-9))
    while probability ** N > 1.0 - confidence:
        N += 1
    if r == 0:
        return N
    # P[Bin(N, q) <= r] falls as N grows: a doubling search, then bisection
    lo, hi = N, N
    while order_statistic_beta(probability, hi, r) > 1.0 - confidence:
        lo, hi = hi, 2 * hi
        if hi > 4 * MAX_ROLLOUTS:
            break
    while lo < hi:
        mid = (lo + hi) // 2
        if order_statistic_beta(probability, mid, r) <= 1.0 - confidence:
            hi = mid
        else:
            lo = mid + 1
    if hi > MAX_ROLLOUTS:
        raise InputError("discards", f"a number of discarded rollouts needing at most {MAX_ROLLOUTS:,} rollouts", r,
                         detail=f"p = {probability:.10g} at confidence {confidence:.10g} needs {hi:,}")
    return hi
