"""Error tubes: how far the stabilized robot strays from its nominal, and the clearance that leaves.

For a nominal and its feedback law (a :class:`nhstab.execution.FeedbackLaw`: gramian, TVLQR or open
loop), the control rate with zero-order hold, the plant's substeps and the noise model of ``nhstab run``
(initial error, sensor noise, process disturbance, impulses), :func:`predict_tube`

1. propagates the mean m_k and covariance S_k of the tracking error at every control sample through
   the closed loop linearised along the nominal, exactly discretised at the control rate
   (:mod:`nhstab.tubes.covariance`, linear in the number of samples), with the probability that an input
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

import numpy as np
from scipy.special import ndtri

from ..execution.config import distance_factor, position_states
from ..geometry import Footprint
from .base import SampleSchedule, Tube, certified_clearance, initial_covariance, pose_indices, run_schedule
from .covariance import CovariancePropagation, propagate, saturation


def process_step_stds(noise, names, x0: np.ndarray, period: float) -> np.ndarray:
    """The process increment's std per state: (n,) per second; per metre (S - 1, n), the intensity times
    sqrt of the distance the nominal ``x0`` (S, n) moves in each step (the linearisation's: the rollouts'
    own moves differ from it by the tracking error's)."""
    std = noise.process_step_std(names, period)
    if not noise.per_metre:
        return std
    ix, iy = position_states(names)
    d = np.diff(np.asarray(x0, dtype=float)[:, [ix, iy]], axis=0)
    return distance_factor(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])[:, None] * std[None, :]


def _linear_tube(law, noise, footprint, world, rate_hz, substeps, model, probability, initial_cov, t_end,
                 impulses) -> Tube:
    names = model.state_names
    T = 1.0 / float(rate_hz)
    sched = run_schedule(law, T, t_end, noise.impulse_list(names) if impulses else ())
    S0 = initial_covariance(noise, names) if initial_cov is None else np.asarray(initial_cov, dtype=float)
    prop = propagate(model, sched.t, sched.x0, sched.u_ff, sched.K, T, substeps, S0,
                     noise.vector("sensor", names), process_step_stds(noise, names, sched.x0, T), sched.jumps)
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
