"""The parking study (``nhstab parking study``): the parking suite's plans under the feedback laws, with
their error tubes held to an independent Monte Carlo.

**Plans.** For each map of the parking suite (``maps/parking/``, the car of its ``robot:`` block) ONE
plan is made: the first plan of ``nhstab run example:NAME --seed PLAN_SEED`` (:func:`first_plan`: the run's
own first planning call, retried as the run retries it, with the run's options: by default the map
robot's margin 0.1 m, headroom 0.8, the gramian law with its schedule split at cusps). A map where no
plan is found is a row with the reason. On that fixed nominal, per controller (the gramian law of the
plan; TVLQR with Q = I, R = I, or with ``--tvlqr-q footprint`` Q from the car's outline) and noise
level (x0.5, x1, x2 of ``nhstab run``'s default initial error, sensor noise and process disturbance),
a **cell**:

1. **The tube**: :func:`nhstab.tubes.predict_tube` of the cell's law and noise against the known
   obstacles, probability p = 0.997, kind "auto" (the linear tube where it holds: no saturation, no
   interior stop; elsewhere the sampled tube of N rollouts with r = 2 left out, N = 2,097 the smallest
   with P[Bin(N, 1 - p) <= r] <= 1 - c at confidence c = 0.95), with its :func:`nhstab.tubes.verdict` (certified or not, where it is tightest, the margin
   it would need). A tube that is not certified gets the reason: where it is tightest, and whether
   the margin it needs is more than the start's or goal's own clearance (less 1 mm, as the run's cap):
   then no plan between them can be certified at that noise.
2. **Trials**: ``trials`` runs of the run loop on the cell's law
   (:func:`nhstab.batch.vector.simulate_shared`, bit-identical to ``nhstab run``'s tracking loop with
   the seeds of :func:`nhstab.batch.tube_study.trial_seeds` (trials, root_seed); no sensing or
   replanning). A trial **collides** when the footprint at its true pose overlaps a known obstacle at
   some sample (FCL, every sample: ``CollisionWorld.free_many``); otherwise it **succeeds** when its
   end state is within the run's goal tolerance (``RunOptions().tolerance``: 0.3 m, 0.2 rad, by
   :func:`nhstab.execution.runner.final_errors` against the map's goal), else it **misses** the goal;
   a trial whose loop diverges (a non-finite state or input) fails. Per cell: the success rate with its
   Wilson 95 % interval, collisions, missed goals and the median over trials of the smallest FCL
   clearance along the trial (``CollisionWorld.min_clearance_less``: exact).
3. **Tube check**: an independent Monte Carlo of M = mc_factor x N runs of the same loop, with seeds
   ``trial_seeds(M, root_seed + 1)`` (32-bit SeedSequence children: disjoint from the tube's rollouts,
   whose root seeds are 2^40 + i, and from the trials'), and per run and control sample the footprint's
   displacement D_k (:func:`nhstab.tubes.displacement`: the largest move of a hull vertex from
   its nominal place). Against the cell's reach_k:

   * **certificate coverage**: the fraction of the M runs whose own smallest FCL clearance over the
     samples is at least the tube's certified clearance (measured exactly where the bound c_k - D_k, c_k
     FCL's clearance at the nominal pose, does not already show it, up to :data:`MAX_MEASURED` poses a
     cell; runs left unmeasured beyond it are reported apart and can leave the check undetermined): the
     whole-run claim of the sampled tube's scenario bound, at least p;
   * **coverage per sample**: the fraction of (run, sample) pairs with D_k <= reach_k, pooled (reach_k
     claims the p-quantile at each sample, not all samples at once: the fraction of runs inside at
     every sample, 83-94 % on the suite, is also recorded, and is not a claim of the tube);
   * **conservatism**: reach_k / q_k with q_k the MC p-quantile of D_k (the order statistic
     X_(ceil(p M)), numpy's ``inverted_cdf``): its median, 95th percentile and maximum over the samples
     with q_k >= 1 mm, and its value at the tube's tightest sample (where its certificate is decided);
   * **below**: the samples where reach_k is below the lower end of the binomial 95 % confidence
     interval of q_k (the order statistics X_(l), X_(u) with l = the 2.5 % point and u - 1 the 97.5 %
     point of Bin(M, p)): below the quantile beyond the Monte Carlo's sampling error. The reach is the
     (r + 1)-th largest of N draws, so it is below the p-quantile at a sample with probability beta =
     P[Bin(N, 1 - p) <= r] (the certificate's 1 - confidence), by design: ``expected_if_correct`` is the
     count a correct tube gives on average. One tube's count scatters far more than a binomial one:
     its samples share their rollouts, so they are below together. The null is therefore the
     tube rebuilt from random subsets of N of the M runs (:func:`subsampled_reaches`,
     :data:`SUBSAMPLES` of them): the check fails when at most :data:`BELOW_LEVEL` of the rebuilt
     tubes are below at as large a fraction of the samples (``below.subsampled.p_value``).

   A cell's tube **passes** when the certificate coverage and the per-sample coverage are not below p
   beyond their Wilson intervals (upper end >= p), the conservatism at the tightest sample is at most
   1.25, and its fraction of samples below is not in the rebuilt tubes' tail (p-value above
   :data:`BELOW_LEVEL`). The 95th percentile of the conservatism is
   reported against 1.25 too (``p95_within``): the third largest of N = 2,097 draws sits near the
   0.9986-quantile on average, above p = 0.997 by the tail's shape. The M x S displacements (about 160 MB at M = 9,980 and
   S = 2,000) are freed after each cell.
4. **Targets** (``result["targets"]``): at x1, no collision in any cell whose tube is certified;
   success >= 98 % in every parallel slot of at least 1.0 x L1 and every bay, >= 90 % at 0.9 x L1 (the
   success targets at x1, per controller); every cell's tube passes.

The result is JSON-ready (:func:`run_parking_study`), with the per-sample curves for the figures
(:func:`tube_figure`, :func:`success_figure`) and the report (:func:`study_markdown`), whose every
number is read from the result. ``workers`` > 1 spreads the maps over processes (spawned, one BLAS
thread each); the result does not depend on it.
"""

from __future__ import annotations

import csv
import math
import os
import re
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import InputError, NumericalError, PipelineError
from ..examples import data_root
from ..execution.config import RunOptions
from ..execution.controllers import CONTROLLERS as KNOWN
from ..execution.controllers import build_law
from ..execution.outputs import nominal_cusps
from ..execution.runner import CompositeRun, final_errors
from ..limits import MAX_ROLLOUTS, MAX_SEED, MAX_STUDY_TRIALS, check_int
from ..maps import load_map, resolve_poses
from ..parking import read_suite_csv
from ..report import subplots
from ..robot import resolve_robot
from ..tubes.base import (
    DEFAULT_DISCARDS,
    REST_NOTE_S,
    displacement,
    hull_vertices,
    order_statistic_beta,
    pose_indices,
    rest_drift,
    rollouts_needed,
    verdict,
)
from ..tubes.predict import predict_tube
from .report import wilson
from .tube_study import CONTROLLERS, NOISE_LEVELS, PLAN_SEED, PROBABILITY, ROOT_SEED, trial_seeds
from .vector import simulate_shared

# the controllers, noise levels, seeds and probability are the tube study's (nhstab.batch.tube_study)
TRIALS = 50
MC_FACTOR = 10
CONFIDENCE = 0.95
#: a tube passes when its conservatism (reach / MC quantile) at the tightest sample and its 95th
#: percentile over the samples are at most this
CONSERVATISM_MAX = 1.25
#: samples whose MC quantile is below this [m] are left out of the conservatism ratios
QUANTILE_FLOOR_M = 1e-3
#: the two-sided level of the order-statistic interval of the MC quantile
QUANTILE_CI = 0.95
#: success targets at x1: parallel slots below this factor of L1 (0.9 x L1) need TARGET_TIGHT
TARGET_FULL, TARGET_TIGHT, FULL_FACTOR = 0.98, 0.90, 1.0
#: the MC displacements are reduced this many samples at a time (np.partition copies a block)
BLOCK = 128
#: poses of the Monte Carlo measured with FCL at most per cell for the certificate's coverage
MAX_MEASURED = 20_000_000
#: the noise level the collision and success targets are read at
TARGET_NOISE = 1.0
#: tubes rebuilt from subsets of the Monte Carlo runs for the 'below' check's null distribution
SUBSAMPLES = 1000
#: their seed (a numpy Generator's), fixed so that a study's checks repeat
SUBSAMPLE_SEED = 20261205
#: the 'below' check's level: it fails when at most this fraction of the rebuilt tubes are as often
#: below (with SUBSAMPLES = 1,000: none of them). The study tests 56 cells per noise level; at 0.1 %
#: each, a suite of correct tubes fails one of them with probability about 5 %
BELOW_LEVEL = 0.001


# ---- the suite and the plans -------------------------------------------------------------------------

def suite_rows(suite=None) -> list[dict]:
    """The parking suite's cases (maps/parking/suite.csv), in its order; with ``suite``, those of a folder
    written by ``nhstab parking suite --robot-config CAR --out FOLDER`` (its suite.csv; an InputError
    naming --suite when it is not such a folder)."""
    if suite is None:
        return read_suite_csv(data_root() / "parking" / "suite.csv")
    path = Path(suite) / "suite.csv"
    want = "a folder written by nhstab parking suite (with its suite.csv)"
    if not path.is_file():
        raise InputError("--suite", want, str(suite), detail="no suite.csv in it")
    try:
        rows = read_suite_csv(path)
    except (KeyError, ValueError, TypeError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError("--suite", want, str(suite), detail=f"suite.csv unreadable: {exc}") from None
    if not rows:
        raise InputError("--suite", want, str(suite), detail="suite.csv lists no case")
    for r in rows:
        if not re.fullmatch(r"[A-Za-z0-9_]{1,100}", str(r.get("name"))):
            raise InputError("--suite", want, str(suite), detail=f"suite.csv names {r.get('name')!r}, not a map name")
        if not (Path(suite) / f"{r['name']}.yaml").is_file():
            raise InputError("--suite", want, str(suite), detail=f"its map {r['name']}.yaml is missing")
    return rows


def map_ref(name: str, suite=None) -> str:
    """How ``nhstab run`` names a map of the study: ``example:NAME``, or the file in ``suite``."""
    return f"example:{name}" if suite is None else str(Path(suite) / f"{name}.yaml")


def check_maps(names, key: str = "maps", suite=None) -> list[dict]:
    """The suite rows of ``names`` (suite names, ``example:`` optional), in the order given; all when
    ``names`` is empty or None. An unknown or repeated name is an InputError naming ``key``. ``suite``:
    a folder of one's own car's suite (:func:`suite_rows`) instead of the bundled one."""
    rows = suite_rows(suite)
    if not names:
        return rows
    by_name = {r["name"]: r for r in rows}
    out, seen = [], set()
    for raw in names:
        name = raw[len("example:"):] if isinstance(raw, str) and raw.startswith("example:") else raw
        if name not in by_name:
            raise InputError(key, "maps of the parking suite (" + ", ".join(by_name) + ")", raw)
        if name in seen:
            raise InputError(key, "each map once", raw)
        seen.add(name)
        out.append(by_name[name])
    return out


def check_levels(levels, key: str = "noise") -> list[float]:
    out = []
    for v in levels:
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0.0 < v <= 100.0
        if not ok:
            raise InputError(key, "noise scales in (0, 100], e.g. 0.5,1,2", v)
        out.append(float(v))
    if not out:
        raise InputError(key, "at least one noise scale, e.g. 0.5,1,2", "nothing")
    if len(set(out)) != len(out):
        raise InputError(key, "each noise scale once", ",".join(f"{v:g}" for v in levels))
    return out


def check_controllers(names, key: str = "controllers") -> list[str]:
    out = list(names)
    if not out:
        raise InputError(key, "at least one of " + ", ".join(KNOWN), "nothing")
    for c in out:
        if c not in KNOWN:
            raise InputError(key, "controllers among " + ", ".join(KNOWN), c)
    if len(set(out)) != len(out):
        raise InputError(key, "each controller once", ",".join(out))
    return out


def first_plan(map_name: str, options=None, suite=None):
    """The first plan of ``nhstab run example:MAP`` with ``options`` (a RunOptions; default
    ``RunOptions(seed=PLAN_SEED)``): the map's robot, start and goal, the run's first planning call
    retried as ``CompositeRun.run`` retries it (a new seed, then a larger budget, at most
    ``replan.max_attempts`` calls). Returns (run, attempts, result, law, margin, tube); law None when
    no call found a plan (the attempts say why)."""
    opts = options if options is not None else RunOptions(seed=PLAN_SEED)
    m = load_map(map_ref(map_name, suite))
    robot = resolve_robot(opts.robot, m.robot)
    start, goal = resolve_poses(m, opts.start, opts.goal)
    run = CompositeRun(m, robot, start, goal, opts)
    attempts = []
    while True:
        attempt, result, law, margin, tube = run._plan_once(run._start_configuration, len(attempts))
        attempts.append(attempt)
        if law is not None or len(attempts) >= run.opts.replan.max_attempts:
            break
    return run, attempts, result, law, margin, tube


def cell_law(run, result, plan_law, controller: str):
    """The cell's feedback law: the plan's own for the run's controller, else ``controller`` with the
    run's options (TVLQR: Q = I, R = I unless the options say otherwise) along the same nominal."""
    if controller == run.opts.controller.kind:
        return plan_law
    copts = replace(run.opts.controller, kind=controller, gains="default")
    return build_law(result.nominal, copts, run.stab_defaults, None, robot=run.robot)


# ---- a cell's parts -------------------------------------------------------------------------------------

def tube_record(tube, v: dict, c_start: float, c_goal: float, noise=None) -> dict:
    """The cell's tube in JSON: its verdict (:func:`nhstab.tubes.verdict`: where it is tightest, the margin
    it would need, whether that is beyond the start's or goal's own clearance) and, for a tube that is not
    certified, the start's and goal's clearance, where the tightest sample lies, and how long the plan
    stands still before it (with ``noise``, the cell's NoiseOptions: the 1-sigma drift a per-second
    disturbance gives the car there, :func:`nhstab.tubes.base.rest_drift`; None per metre)."""
    rc = tube.info.get("rollout_clearance") or {}
    rec = {"kind": tube.kind, "rollouts": tube.certificate.get("rollouts"), "certified": tube.certified,
           "certified_clearance_m": tube.certified_clearance, "samples": int(len(tube.t)),
           "certificate_clearance": tube.certificate.get("clearance"),
           "grown_footprint_clearance_m": rc.get("grown_footprint_clearance_m"),
           "max_reach_m": float(tube.reach.max()), "saturation": tube.saturation["run_bound"],
           "why_this_kind": v.get("why_this_kind"), "tightest": v.get("tightest"),
           "needed_margin_m": v.get("needed_margin_m"), "needed_margin_note": v.get("needed_margin_note"),
           "failing_samples": v.get("failing_samples"), "failing_times_s": v.get("failing_times_s"),
           "beyond_start_or_goal": "beyond_start_or_goal" in v}
    if tube.certified is False:
        T = float(tube.t[-1])
        k = tube.certified_index
        where = "mid-run"
        if k is not None and k >= 0:
            if tube.t[k] <= 1.0:
                where = "start"
            elif tube.t[k] >= T - 1.0:
                where = "goal"
        rec["not_certified"] = {"start_clearance_m": c_start, "goal_clearance_m": c_goal,
                                "cap_m": min(c_start, c_goal) - 1e-3, "tightest_where": where, "plan_duration_s": T}
        rest = v.get("at_rest")
        if rest is not None:
            drift = rest_drift(noise, tube.state_names, rest["before_tightest_s"])
            rec["not_certified"]["at_rest"] = {**rest, "drift_position_m": None if drift is None else drift[0],
                                               "drift_heading_rad": None if drift is None else drift[1]}
    return rec


def trial_outcomes(run, law, seeds, noise) -> dict:
    """Trials of the run loop on ``law``: collisions at every sample (FCL), goal reached, the smallest
    clearance along each trial (see the module docstring)."""
    sim = simulate_shared(law, seeds, noise, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps, model=run.model)
    K, S = len(seeds), len(sim.t)
    idx = pose_indices(run.model)
    ok = sim.completed
    collided = np.zeros(K, dtype=bool)
    if ok.any():
        poses = sim.x[ok][:, :, idx].reshape(-1, 3)
        free = run.known.free_many(poses, run.fp, 0.0).reshape(int(ok.sum()), S)
        collided[ok] = ~free.all(axis=1)
    tol = run.opts.tolerance
    reached = np.zeros(K, dtype=bool)
    pos_err = np.full(K, np.nan)
    head_err = np.full(K, np.nan)
    min_clear = np.full(K, np.nan)
    for i in np.flatnonzero(ok):
        fe = final_errors(run.robot, sim.x_final[i], run.goal)
        pos_err[i], head_err[i] = fe["position_m"], fe["heading_rad"]
        reached[i] = fe["position_m"] <= tol.position_m and fe["heading_rad"] <= tol.heading_rad
        min_clear[i] = run.known.min_clearance_less(sim.x[i][:, idx], run.fp)[0]
    success = ok & ~collided & reached
    n_ok = int(success.sum())
    rate, lo, hi = wilson(n_ok, K)
    finite = np.isfinite(min_clear)
    return {"trials": K, "success": n_ok, "success_rate": rate, "wilson_lo": lo, "wilson_hi": hi,
            "collisions": int(collided.sum()), "missed_goal": int((ok & ~collided & ~reached).sum()),
            "diverged": int((~ok).sum()),
            "median_min_clearance_m": float(np.median(min_clear[finite])) if finite.any() else None,
            "min_min_clearance_m": float(np.min(min_clear[finite])) if finite.any() else None,
            "median_final_position_error_m": float(np.nanmedian(pos_err)) if ok.any() else None,
            "median_final_heading_error_rad": float(np.nanmedian(head_err)) if ok.any() else None,
            "per_trial": {"seed": [int(s) for s in seeds], "collided": collided.tolist(), "reached": reached.tolist(),
                          "completed": ok.tolist(), "min_clearance_m": [None if not np.isfinite(c) else float(c)
                                                                        for c in min_clear]}}


def mc_displacements(run, law, poses: np.ndarray, seeds, noise, nominal_clearance: np.ndarray | None = None,
                     certified_clearance: float | None = None) -> tuple[np.ndarray, dict]:
    """The footprint displacement (:func:`nhstab.tubes.displacement`) of M runs of the loop at
    every sample, as an (S, M) array (+inf for a run whose loop diverged), and a record: the runs that
    diverged, and with ``nominal_clearance`` (S,) and ``certified_clearance``, how many runs' own
    smallest FCL clearance over the samples is below the certified clearance. Exactly: at each sample,
    the poses whose lower bound c_k - D_k is below it are measured as the loop produces them, except
    those of runs already found below; at most :data:`MAX_MEASURED` poses in all, beyond which the runs
    left with an unmeasured pose are counted apart (``unmeasured_runs``: neither inside nor below, so
    the certificate's coverage lies between two bounds). ``poses`` (S, 3): the nominal poses at the
    samples (the tube's)."""
    idx = pose_indices(run.model)
    hull = hull_vertices(run.fp)
    S, M = len(poses), len(seeds)
    Dt = np.empty((S, M))
    check = nominal_clearance is not None and certified_clearance is not None
    found = {"count": 0, "below": np.zeros(M, dtype=bool), "unmeasured": np.zeros(M, dtype=bool)}

    def observe(rows, k, x, u=None):
        P = x[:, idx]
        D = displacement(hull, P, poses[k])
        Dt[k, rows] = D
        if check:
            runs = rows.start + np.arange(len(D))
            sel = np.flatnonzero((nominal_clearance[k] - D < certified_clearance) & ~found["below"][runs]
                                 & np.isfinite(P).all(axis=1))
            if not len(sel):
                return
            room = MAX_MEASURED - found["count"]
            if room < len(sel):
                found["unmeasured"][runs[sel[max(room, 0):]]] = True
                sel = sel[:max(room, 0)]
            if len(sel):
                c = run.known.clearance_many(P[sel], run.fp)
                found["count"] += len(sel)
                found["below"][runs[sel[c < certified_clearance]]] = True

    with np.errstate(over="ignore", invalid="ignore"):
        res = simulate_shared(law, seeds, noise, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps,
                              model=run.model, record=False, on_states=observe)
    if len(res.t) != S:
        raise NumericalError(f"the Monte Carlo's samples ({len(res.t)}) differ from the tube's ({S})")
    bad = ~res.completed
    if bad.any():
        Dt[:, bad] = np.inf
    rec = {"diverged": int(bad.sum())}
    if check:
        below = found["below"] | bad
        unmeasured = found["unmeasured"] & ~below
        rec.update(runs_below=int(below.sum()), measured=int(found["count"]),
                   unmeasured_runs=int(unmeasured.sum()), complete=not unmeasured.any())
    return Dt, rec


def quantile_indices(M: int, p: float, level: float = QUANTILE_CI) -> tuple[int, int, int]:
    """1-based order-statistic indices (j, l, u) for M draws: X_(j) the p-quantile (j = ceil(p M), numpy's
    ``inverted_cdf``) and [X_(l), X_(u)] its two-sided ``level`` confidence interval (l = the lower
    (1 - level)/2 point of Bin(M, p), u - 1 its upper point; l = 0: no lower end, u = M + 1: no upper)."""
    from scipy.stats import binom

    a = (1.0 - level) / 2.0
    j = max(1, min(M, math.ceil(p * M - 1e-9)))
    lo = int(binom.ppf(a, M, p))
    hi = int(binom.ppf(1.0 - a, M, p)) + 1
    return j, lo, hi


def below_chance(l: int, M: int, N: int, r: int = 0) -> float:
    """The chance that the (r + 1)-th largest of N independent draws is below the l-th smallest of M others
    (a correct sampled tube's chance of a 'below' at one sample): with U = F(X_(l)) ~ Beta(l, M - l + 1),
    E[P(Bin(N, 1 - U) <= r)] = sum_j C(N, j) B(l + N - j, M - l + 1 + j) / B(l, M - l + 1), j = 0..r
    (r = 0: E[U^N])."""
    from scipy.special import betaln, gammaln

    if l < 1:
        return 0.0
    base = betaln(l, M - l + 1)
    total = 0.0
    for j in range(int(r) + 1):
        log_choose = gammaln(N + 1) - gammaln(j + 1) - gammaln(N - j + 1)
        total += math.exp(log_choose + betaln(l + N - j, M - l + 1 + j) - base)
    return float(total)


def probability_beta(p: float, rollouts: int, discards: int = 0) -> float:
    """beta = P[Bin(N, 1 - p) <= r]: the chance that the (r + 1)-th largest of N draws is below the
    p-quantile (at one sample; r = 0: p^N)."""
    return order_statistic_beta(p, int(rollouts), int(discards))


def subsampled_reaches(Dt: np.ndarray, N: int, r: int, p: float, subsamples: int = SUBSAMPLES,
                       seed: int = SUBSAMPLE_SEED):
    """Tubes built as the sampled tube is, from the Monte Carlo's runs instead of fresh rollouts, each
    held to the runs it was not built from, as the cell's tube is held to the Monte Carlo: for each of
    ``subsamples`` random subsets of N of the M runs (without replacement), at every sample the
    subset's reach (its (r + 1)-th largest displacement) and the lower end of the p-quantile's interval
    (:func:`quantile_indices`) of the other M - N runs. Yields ((S,) reach, (S,) lower end).

    The subsets are the m-out-of-n bootstrap of the tube (m = N, n = M = mc_factor x N): the spread of
    what N rollouts of this loop give, with its correlation over time (a run that is far out at one
    sample tends to be far out at the next), which a per-sample binomial count ignores. Holding a
    subset to the rest rather than to all M runs keeps it out of its own yardstick (a subset light
    in the tail would otherwise lower the quantile it is compared with). Only each sample's K largest
    displacements are kept (K well above what a subset and the lower end draw from them); a sample
    where they do not suffice is computed in full."""
    S, M = Dt.shape
    N, r = int(N), int(r)
    if not 0 <= r < N < M:
        raise ValueError(f"need 0 <= discards < rollouts < runs, got {r}, {N}, {M}")
    _, lo, _ = quantile_indices(M - N, p)
    h = (M - N) - lo + 1 if lo >= 1 else None          # the lower end: the h-th largest of the other runs
    K = min(M, max(64, int(math.ceil(12 * (r + 1) * M / N)), 0 if h is None else int(math.ceil(2 * h * M / (M - N)))))
    top_i = np.empty((S, K), dtype=np.int64)
    top_v = np.empty((S, K))
    for a in range(0, S, BLOCK):
        block = Dt[a:a + BLOCK]
        idx = np.argpartition(-block, K - 1, axis=1)[:, :K] if K < M else np.tile(np.arange(M), (len(block), 1))
        vals = np.take_along_axis(block, idx, axis=1)
        order = np.argsort(-vals, axis=1, kind="stable")
        top_i[a:a + BLOCK] = np.take_along_axis(idx, order, axis=1)
        top_v[a:a + BLOCK] = np.take_along_axis(vals, order, axis=1)
    rng = np.random.default_rng(seed)
    rows = np.arange(S)
    mask = np.zeros(M, dtype=bool)
    for _ in range(int(subsamples)):
        chosen = rng.choice(M, size=N, replace=False)
        mask[:] = False
        mask[chosen] = True
        member = mask[top_i]
        count = np.cumsum(member, axis=1)
        reach = top_v[rows, np.argmax(count > r, axis=1)]
        short = count[:, -1] <= r
        if h is None:
            lower = np.zeros(S)
        else:
            other = np.cumsum(~member, axis=1)
            lower = top_v[rows, np.argmax(other >= h, axis=1)]
            short |= other[:, -1] < h
        for k in np.flatnonzero(short):
            reach[k] = np.partition(Dt[k, chosen], N - r - 1)[N - r - 1]
            if h is not None:
                rest = Dt[k, ~mask]
                lower[k] = np.partition(rest, lo - 1)[lo - 1]
        yield reach, lower


def tube_check(reach: np.ndarray, Dt: np.ndarray, p: float, t: np.ndarray, tightest: int | None = None,
               runs_below: int | None = None, rollouts: int | None = None, discards: int = 0,
               runs_unmeasured: int = 0, subsamples: int = SUBSAMPLES,
               nominal_clearance: np.ndarray | None = None) -> tuple[dict, dict]:
    """The tube check of one cell (see the module docstring): reach (S,) against the displacements
    Dt (S, M) of M Monte Carlo runs. ``runs_below``: the runs whose own smallest clearance is below the
    certified one; ``runs_unmeasured``: runs not known either way (:func:`mc_displacements`' cap), with
    which the certificate's coverage is a range and its check may be undetermined (None). Returns (JSON
    record, per-sample curves)."""
    S, M = Dt.shape
    reach = np.asarray(reach, dtype=float)
    inside = Dt <= reach[:, None]
    whole = inside.all(axis=0)
    per_sample = inside.mean(axis=1)
    del inside
    n_in = int(whole.sum())
    rate, lo, hi = wilson(n_in, M)
    j, l, u = quantile_indices(M, p)
    q, qlo, qhi = np.empty(S), np.full(S, 0.0), np.full(S, np.inf)
    kth = sorted({j - 1} | ({l - 1} if l >= 1 else set()) | ({u - 1} if u <= M else set()))
    for a in range(0, S, BLOCK):
        part = np.partition(Dt[a:a + BLOCK], kth, axis=1)
        q[a:a + BLOCK] = part[:, j - 1]
        if l >= 1:
            qlo[a:a + BLOCK] = part[:, l - 1]
        if u <= M:
            qhi[a:a + BLOCK] = part[:, u - 1]
        del part
    use = np.isfinite(q) & (q >= QUANTILE_FLOOR_M)
    ratio = np.full(S, np.nan)
    ratio[use] = reach[use] / q[use]
    below = reach < qlo
    kb = np.flatnonzero(below)
    rec = {"mc_runs": M, "quantile_order": j, "quantile_ci_orders": [l, u], "quantile_ci_level": QUANTILE_CI,
           "coverage": {"inside": n_in, "runs": M, "rate": rate, "wilson_lo": lo, "wilson_hi": hi},
           "coverage_min_per_sample": float(per_sample.min()),
           "coverage_min_per_sample_time_s": float(t[int(np.argmin(per_sample))]),
           "samples_ratio_used": int(use.sum())}
    if use.any():
        r = ratio[use]
        rec["conservatism"] = {"median": float(np.median(r)), "p95": float(np.percentile(r, 95)),
                               "max": float(r.max()), "min": float(r.min()),
                               "max_time_s": float(t[np.flatnonzero(use)[int(np.argmax(r))]])}
    else:
        rec["conservatism"] = {"median": None, "p95": None, "max": None, "min": None, "max_time_s": None}
    at = None
    if tightest is not None and tightest >= 0 and use[tightest]:
        at = float(ratio[tightest])
    rec["conservatism"]["at_tightest"] = at
    rec["conservatism"]["tightest_index"] = tightest
    rec["below"] = {"samples": int(below.sum()),
                    "times_s": [float(t[kb].min()), float(t[kb].max())] if len(kb) else None,
                    "largest_shortfall_m": float(np.max(qlo[kb] - reach[kb])) if len(kb) else None}
    if rollouts is not None:
        chance = below_chance(l, M, int(rollouts), discards)
        rec["below"]["chance_per_sample_if_correct"] = chance
        rec["below"]["expected_if_correct"] = chance * S
    if runs_below is not None:
        k_ok = M - int(runs_below) - int(runs_unmeasured)
        r2, lo2, hi2 = wilson(k_ok, M)
        rec["certificate_coverage"] = {"inside": k_ok, "runs": M, "rate": r2, "wilson_lo": lo2, "wilson_hi": hi2,
                                       "unmeasured": int(runs_unmeasured)}
        if runs_unmeasured:         # counted inside, the rate's upper end
            r4, lo4, hi4 = wilson(k_ok + int(runs_unmeasured), M)
            rec["certificate_coverage"].update(rate_if_unmeasured_inside=r4, wilson_hi_if_unmeasured_inside=hi4)
    pooled = int(round(float(per_sample.sum()) * M))
    r3, lo3, hi3 = wilson(pooled, S * M)
    rec["coverage_per_sample"] = {"inside": pooled, "samples": S * M, "rate": r3, "wilson_lo": lo3, "wilson_hi": hi3,
                                  "note": "pooled over runs and samples (correlated within a run: the interval is "
                                          "too narrow); reach_k claims the p-quantile at each sample"}
    cons = rec["conservatism"]
    beta = None if rollouts is None else float(probability_beta(p, rollouts, discards))
    fraction = float(below.mean())
    rec["below"]["fraction"] = fraction
    rec["below"]["beta"] = beta
    below_ok = None             # undetermined: no rebuilt tubes (no rollout count, or fewer runs than N + 1)
    if (int(subsamples) + 1) * BELOW_LEVEL < 1.0:
        raise ValueError(f"{subsamples} rebuilt tubes cannot resolve the level {BELOW_LEVEL:g}")
    if rollouts is not None and int(rollouts) < M:
        # the null: how often tubes of N of these same runs are below, sample by sample
        fr, tight, own = np.empty(int(subsamples)), np.empty(int(subsamples)), np.full(int(subsamples), np.nan)
        gap = None if nominal_clearance is None or not use.any() else np.asarray(nominal_clearance, dtype=float)
        for b, (rb, lb) in enumerate(subsampled_reaches(Dt, int(rollouts), int(discards), p, int(subsamples))):
            fr[b] = np.mean(rb < lb)
            tight[b] = rb[tightest] / q[tightest] if at is not None else np.nan
            if gap is not None:         # the rebuilt tube's own tightest sample (by its reach), as a tube picks it
                kb = int(np.argmin(np.where(use, gap - rb, np.inf)))
                own[b] = rb[kb] / q[kb]
        p_value = (1 + int(np.sum(fr >= fraction))) / (len(fr) + 1)
        below_ok = bool(p_value > BELOW_LEVEL)
        rec["below"]["subsampled"] = {
            "tubes": int(subsamples), "seed": SUBSAMPLE_SEED, "level": BELOW_LEVEL,
            "fraction_median": float(np.median(fr)), "fraction_p95": float(np.percentile(fr, 95)),
            "fraction_p99": float(np.percentile(fr, 99)), "fraction_mean": float(fr.mean()),
            "p_value": float(p_value),
            "conservatism_at_tightest_median": None if at is None else float(np.median(tight)),
            "conservatism_at_tightest_over_max": None if at is None else float(np.mean(tight > CONSERVATISM_MAX))}
        if gap is not None:
            k_own = int(np.argmin(np.where(use, gap - reach, np.inf)))
            rec["below"]["subsampled"]["own_tightest"] = {
                "rule": "argmin over the samples of nominal clearance - reach (samples with q >= 1 mm)",
                "median": float(np.median(own)), "p95": float(np.percentile(own, 95)),
                "over_max": float(np.mean(own > CONSERVATISM_MAX)),
                "cell_index": k_own, "cell": float(reach[k_own] / q[k_own])}
    cert_ok = True
    if "certificate_coverage" in rec:
        cc = rec["certificate_coverage"]
        cert_ok = bool(cc["wilson_hi"] >= p)
        if not cert_ok and cc["unmeasured"] and cc["wilson_hi_if_unmeasured_inside"] >= p:
            cert_ok = None          # the unmeasured runs decide it: undetermined
    passes = {"certificate_coverage": cert_ok,
              "coverage_per_sample": bool(hi3 >= p),
              "conservatism_at_tightest": bool(at is None or at <= CONSERVATISM_MAX),
              "below": below_ok}
    passes["all"] = all(v is True for v in passes.values())
    rec["conservatism"]["p95_within"] = bool(cons["p95"] is not None and cons["p95"] <= CONSERVATISM_MAX)
    rec["passes"] = passes
    curves = {"q": q, "q_lo": qlo, "q_hi": qhi, "coverage_t": per_sample, "ratio": ratio}
    return rec, curves


def failed_checks(passes: dict) -> list[str]:
    """The names of a tube check's failed parts; a part left undetermined (None) says so."""
    return [k if v is False else f"{k} undetermined" for k, v in passes.items() if k != "all" and v is not True]


# ---- a map ---------------------------------------------------------------------------------------------

def _say(progress, text: str) -> None:
    if progress is None:
        return
    if progress is True:
        print(text, file=sys.stderr, flush=True)
    else:
        progress(text)


def study_map(row: dict, settings: dict, progress=None) -> tuple[dict, dict]:
    """One map of the study: its plan and its cells. Returns (case record, curves by (controller, noise))."""
    opts = settings["options"]
    p, conf = settings["probability"], settings["confidence"]
    case = {k: row[k] for k in ("name", "car", "kind", "factor", "size_m", "reference_m")}
    case["map"] = case.pop("name")
    started = time.perf_counter()
    try:
        run, attempts, result, law0, margin, tube0 = first_plan(case["map"], opts, settings.get("suite"))
    except PipelineError as exc:
        case.update(plan={"found": False, "reason": " ".join(str(exc).split())}, plan_wall_s=time.perf_counter() - started,
                    cells=[])
        _say(progress, f"{case['map']}: no plan ({case['plan']['reason']})")
        return case, {}
    case["plan_wall_s"] = time.perf_counter() - started
    brief = []
    for a in attempts:
        b = {k: a.get(k) for k in ("seed", "margin", "status", "message", "latency_s")}
        for k in ("fit", "margin_auto", "gains_auto"):
            if isinstance(a.get(k), dict) and a[k].get("message"):
                b[f"{k}_message"] = a[k]["message"]
        brief.append(b)
    if law0 is None:
        last = attempts[-1]
        case.update(plan={"found": False, "reason": f"{last.get('status')}: {last.get('message')}", "attempts": brief},
                    cells=[])
        _say(progress, f"{case['map']}: no plan ({case['plan']['reason']})")
        return case, {}
    c_start = float(run.known.clearance(run.start[:3], run.fp))
    c_goal = float(run.known.clearance(run.goal[:3], run.fp))
    case["plan"] = {"found": True, "attempts": brief, "margin_m": margin,
                    "duration_s": float(law0.t_end - law0.t0), "length_m": result.metrics.get("length_m"),
                    "cusps": result.metrics.get("cusps"), "cusp_times_s": nominal_cusps(law0.nominal),
                    "min_clearance_m": result.metrics.get("min_clearance_m"),
                    "start_clearance_m": c_start, "goal_clearance_m": c_goal,
                    "tube_x1": None if tube0 is None else {"kind": tube0.kind, "certified": tube0.certified,
                                                           "certified_clearance_m": tube0.certified_clearance}}
    _say(progress, f"{case['map']}: plan {case['plan']['length_m']:.1f} m, {case['plan']['duration_s']:.1f} s, "
                   f"{case['plan']['cusps']} cusp(s), margin {margin:.3g} m ({case['plan_wall_s']:.1f} s)")
    trial_s = trial_seeds(settings["trials"], settings["root_seed"])
    cells, curves = [], {}
    for ctrl in settings["controllers"]:
        try:
            law = cell_law(run, result, law0, ctrl)
        except PipelineError as exc:
            for level in settings["noise_levels"]:
                cells.append({"controller": ctrl, "noise": level, "error": " ".join(str(exc).split())})
            continue
        for level in settings["noise_levels"]:
            cell_started = time.perf_counter()
            noise = replace(opts.noise, scale=level)
            cell = {"controller": ctrl, "noise": level, "wall_s": {}}
            t0 = time.perf_counter()
            reuse = (tube0 is not None and law is law0 and noise == run.opts.noise and opts.tube.kind == "auto"
                     and opts.tube.probability == p and opts.tube.confidence == conf
                     and opts.tube.discards == DEFAULT_DISCARDS)
            tube = None
            try:
                tube = tube0 if reuse else predict_tube(
                    law, noise, run.fp, run.known, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps,
                    model=run.model, probability=p, kind="auto", confidence=conf)
                vd = verdict(tube, run.known, run.fp, margin, cap=min(c_start, c_goal) - 1e-3)
                cell["tube"] = tube_record(tube, vd, c_start, c_goal, noise)
                cell["tube"]["from_plan"] = bool(reuse)
            except NumericalError as exc:
                cell["tube"] = {"error": " ".join(str(exc).split())}
                tube = None
            cell["wall_s"]["tube"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            cell["trials"] = trial_outcomes(run, law, trial_s, noise)
            cell["wall_s"]["trials"] = time.perf_counter() - t0
            cell["tube_check"] = None
            if tube is not None:
                t0 = time.perf_counter()
                M = settings["mc_factor"] * settings["rollouts"]
                c_nom = run.known.clearance_many(tube.poses, run.fp)
                Dt, mc = mc_displacements(run, law, tube.poses, trial_seeds(M, settings["root_seed"] + 1), noise,
                                          c_nom, tube.certified_clearance)
                rec, cur = tube_check(tube.reach, Dt, p, tube.t, tube.certified_index, mc.get("runs_below"),
                                      tube.certificate.get("rollouts") if tube.kind == "sampled" else None,
                                      tube.certificate.get("discards", 0) if tube.kind == "sampled" else 0,
                                      runs_unmeasured=mc.get("unmeasured_runs", 0), nominal_clearance=c_nom)
                del Dt
                rec["monte_carlo"] = mc
                cell["tube_check"] = rec
                cur.update(t=tube.t, reach=tube.reach, nominal_clearance=c_nom, tightest=tube.certified_index)
                curves[(ctrl, level)] = {k: (a.astype(np.float32) if isinstance(a, np.ndarray) else a)
                                         for k, a in cur.items()}
                cell["wall_s"]["monte_carlo"] = time.perf_counter() - t0
            cell["wall_s"]["total"] = time.perf_counter() - cell_started
            cells.append(cell)
            _say(progress, cell_line(case["map"], cell))
    case["cells"] = cells
    case["wall_s"] = time.perf_counter() - started
    return case, curves


def cell_line(map_name: str, cell: dict) -> str:
    """One progress line for a finished cell."""
    head = f"{map_name} {cell['controller']} x{cell['noise']:g}: "
    if "error" in cell:
        return head + "no law: " + cell["error"]
    tb, tr, tc = cell["tube"], cell["trials"], cell["tube_check"]
    text = head
    if "error" in tb:
        text += "no tube; "
    else:
        text += f"{tb['kind']} tube {tb['certified_clearance_m']:+.3f} m; "
    text += f"success {tr['success']}/{tr['trials']}, collisions {tr['collisions']}"
    if tc is not None:
        cons = tc["conservatism"]
        cc = tc.get("certificate_coverage")
        cert = "-" if cc is None else f"{100 * cc['rate']:.2f}%"
        text += (f"; cert. coverage {cert}, per sample "
                 f"{100 * tc['coverage_per_sample']['rate']:.2f}%, conservatism at tightest "
                 + ("-" if cons["at_tightest"] is None else f"{cons['at_tightest']:.2f}")
                 + ", p95 " + ("-" if cons["p95"] is None else f"{cons['p95']:.2f}")
                 + f", below {tc['below']['samples']}, " + ("passes" if tc["passes"]["all"] else
                                                            "FAILS (" + ", ".join(failed_checks(tc["passes"])) + ")"))
    return text + f" ({cell['wall_s']['total']:.1f} s)"


def _map_task(args):
    row, settings = args
    return study_map(row, settings, progress=True)


# ---- the study -----------------------------------------------------------------------------------------

def run_parking_study(trials: int = TRIALS, mc_factor: int = MC_FACTOR, maps=None, noise_levels=NOISE_LEVELS,
                      controllers=CONTROLLERS, root_seed: int = ROOT_SEED, plan_seed: int = PLAN_SEED,
                      options=None, probability: float = PROBABILITY, confidence: float = CONFIDENCE,
                      workers: int = 1, progress=None, suite=None) -> tuple[dict, dict]:
    """The parking study (see the module docstring); returns (JSON-ready result, curves by (map,
    controller, noise) for the figures). ``options``: the RunOptions of the plans (default
    ``RunOptions(seed=plan_seed)``; with options given, its seed is replaced by ``plan_seed``).
    ``progress``: called with one line per plan and per cell. ``suite``: the folder of a suite of one's
    own car (``nhstab parking suite --robot-config``) instead of the bundled suite."""
    trials = check_int("trials", trials, 1, MAX_STUDY_TRIALS, "a number of trials per cell")
    root_seed = check_int("root_seed", root_seed, 0, MAX_SEED - 1, "a seed")
    plan_seed = check_int("plan_seed", plan_seed, 0, MAX_SEED, "a seed")
    workers = check_int("workers", workers, 1, 64, "a number of worker processes")
    rows = check_maps(maps, "maps", suite)
    levels = check_levels(noise_levels)
    ctrls = check_controllers(controllers)
    N = rollouts_needed(probability, confidence, DEFAULT_DISCARDS)
    mc_factor = check_int("mc_factor", mc_factor, 1, max(1, MAX_ROLLOUTS // N),
                          f"a factor of the tube's {N} rollouts (at most {MAX_ROLLOUTS:,} Monte Carlo runs)")
    opts = replace(options, seed=plan_seed) if options is not None else RunOptions(seed=plan_seed)
    settings = {"options": opts, "trials": trials, "root_seed": root_seed, "controllers": ctrls,
                "noise_levels": levels, "probability": probability, "confidence": confidence,
                "rollouts": N, "mc_factor": mc_factor, "suite": None if suite is None else str(suite)}
    started = time.perf_counter()
    out = {"study": "parking", "probability": probability, "confidence": confidence, "rollouts": N,
           "discards": DEFAULT_DISCARDS, "mc_factor": mc_factor, "mc_runs": mc_factor * N, "trials": trials, "root_seed": root_seed,
           "mc_root_seed": root_seed + 1, "plan_seed": plan_seed, "controllers": ctrls, "noise_levels": levels,
           "process_per": opts.noise.process_per,
           "tolerance": {"position_m": opts.tolerance.position_m, "heading_rad": opts.tolerance.heading_rad},
           "planning": {"margin": opts.planning.margin, "fit": opts.planning.fit, "headroom": opts.headroom,
                        "planner": opts.planning.planner,
                        "time_limit_s": opts.planning.time_limit_s, "controller": opts.controller.kind,
                        "gains": opts.controller.gains,
                        **({"tvlqr_q": opts.controller.q} if opts.controller.q is not None else {})},
           "criteria": {"conservatism_max": CONSERVATISM_MAX, "quantile_floor_m": QUANTILE_FLOOR_M,
                        "quantile_ci": QUANTILE_CI, "target_full": TARGET_FULL, "target_tight": TARGET_TIGHT,
                        "full_factor": FULL_FACTOR, "target_noise": TARGET_NOISE},
           "workers": workers, "cases": []}
    if suite is not None:
        out["suite"] = str(suite)
    curves = {}
    if workers == 1 or len(rows) == 1:
        for row in rows:
            case, cur = study_map(row, settings, progress)
            out["cases"].append(case)
            curves.update({(case["map"],) + k: v for k, v in cur.items()})
    else:
        out["cases"], cur_all = _in_processes(rows, settings, workers, progress)
        curves.update(cur_all)
    out["wall_s"] = time.perf_counter() - started
    out["cpu_count"] = os.cpu_count()
    out["targets"] = targets(out)
    return out, curves


def spawned_pool(workers: int, tasks: int):
    """A ProcessPoolExecutor of min(workers, tasks) spawned processes, each started with one BLAS thread
    (the environment they start with; this process's is restored)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    saved = {v: os.environ.get(v) for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    for v in saved:
        os.environ[v] = "1"
    try:
        return ProcessPoolExecutor(max_workers=min(workers, tasks), mp_context=mp.get_context("spawn"))
    finally:
        for v, old in saved.items():
            if old is None:
                os.environ.pop(v, None)
            else:
                os.environ[v] = old


def stop_pool(pool) -> None:
    """Cancel what has not started and end the pool's processes (on an error or an interrupt)."""
    pool.shutdown(wait=False, cancel_futures=True)
    for p in list((getattr(pool, "_processes", None) or {}).values()):
        if p.is_alive():
            p.terminate()


def _in_processes(rows, settings, workers, progress):
    """The maps over ``workers`` spawned processes, one BLAS thread each; results in the suite's order."""
    from concurrent.futures import as_completed

    pool = spawned_pool(workers, len(rows))
    cases, curves = [None] * len(rows), {}
    try:
        futures = {pool.submit(_map_task, (row, settings)): i for i, row in enumerate(rows)}
        for fut in as_completed(futures):
            i = futures[fut]
            case, cur = fut.result()
            cases[i] = case
            curves.update({(case["map"],) + k: v for k, v in cur.items()})
            _say(progress, f"done {case['map']} ({sum(c is not None for c in cases)}/{len(rows)} maps)")
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)
    return cases, curves


# ---- targets -------------------------------------------------------------------------------------------

def target_success(case: dict) -> float:
    """The success target of a map: TARGET_TIGHT for a parallel slot under FULL_FACTOR x L1, else TARGET_FULL."""
    if case["kind"] == "parallel" and case["factor"] < FULL_FACTOR - 1e-9:
        return TARGET_TIGHT
    return TARGET_FULL


def targets(result: dict) -> dict:
    """The study's targets, each met or not, with the cells that miss it (read from the result)."""
    at = result["criteria"]["target_noise"]
    has_x1 = any(abs(v - at) < 1e-12 for v in result["noise_levels"])
    col = {"text": f"at x{at:g}, no collision in any cell whose tube is certified", "evaluated": has_x1,
           "checked": 0, "failing": []}
    suc = {"text": (f"at x{at:g}, success >= {100 * TARGET_FULL:g} % in every parallel slot of at least "
                    f"{FULL_FACTOR:g} x L1 and every bay, >= {100 * TARGET_TIGHT:g} % at 0.9 x L1"),
           "evaluated": has_x1, "checked": 0, "failing": []}
    tub = {"text": "every cell's tube passes its check", "evaluated": True, "checked": 0, "failing": []}
    for case in result["cases"]:
        if not case["plan"].get("found"):
            if has_x1:
                for ctrl in result["controllers"]:
                    suc["checked"] += 1
                    suc["failing"].append({"map": case["map"], "controller": ctrl, "noise": at, "success": 0,
                                           "trials": 0, "target": target_success(case), "reason": "no plan"})
            continue
        for c in case["cells"]:
            key = {"map": case["map"], "controller": c["controller"], "noise": c["noise"]}
            if "error" in c:
                tub["checked"] += 1
                tub["failing"].append({**key, "reason": "no law: " + c["error"]})
                continue
            tb, tr, tc = c["tube"], c["trials"], c["tube_check"]
            if abs(c["noise"] - at) < 1e-12:
                if tb.get("certified"):
                    col["checked"] += 1
                    if tr["collisions"]:
                        col["failing"].append({**key, "collisions": tr["collisions"], "trials": tr["trials"]})
                suc["checked"] += 1
                goal = target_success(case)
                if tr["success_rate"] < goal - 1e-12:
                    suc["failing"].append({**key, "success": tr["success"], "trials": tr["trials"], "target": goal,
                                           "collisions": tr["collisions"], "missed_goal": tr["missed_goal"],
                                           "diverged": tr["diverged"]})
            tub["checked"] += 1
            if tc is None:
                tub["failing"].append({**key, "reason": "no tube: " + tb.get("error", "")})
            elif not tc["passes"]["all"]:
                tub["failing"].append({**key, "reason": ", ".join(failed_checks(tc["passes"]))})
    for t in (col, suc, tub):
        t["met"] = bool(t["evaluated"] and not t["failing"])
    return {"no_collision_when_certified": col, "success": suc, "tubes_pass": tub}


# ---- the report ----------------------------------------------------------------------------------------

def size_text(case: dict) -> str:
    what = "slot" if case["kind"] == "parallel" else "aisle"
    ref = "L1" if case["kind"] == "parallel" else ("A90" if case["kind"] == "perpendicular" else "est.")
    return f"{what} {case['size_m']:.2f} m ({case['factor']:g} x {ref})"


def _f(v, fmt: str, none: str = "-") -> str:
    return none if v is None else format(v, fmt)


def _pct(v, digits: int = 1) -> str:
    return "-" if v is None else f"{100 * v:.{digits}f}%"


def not_certified_text(tb: dict) -> str:
    """Why a cell's tube is not certified, from its record."""
    nc = tb.get("not_certified") or {}
    t = tb.get("tightest") or {}
    parts = [f"certified clearance {tb['certified_clearance_m']:+.3f} m"]
    if t:
        x, y, th = t["pose"][:3]
        text = (f"tightest at t = {t['time_s']:.2f} s (at the {nc.get('tightest_where', '-')}"
                if nc.get("tightest_where") in ("start", "goal") else f"tightest at t = {t['time_s']:.2f} s (mid-run")
        text += (f"), pose ({x:.2f}, {y:.2f}, {th:.2f}), where the plan keeps {t['nominal_clearance_m']:.3f} m and ")
        if t.get("rollout_displacement_m") is not None:
            text += (f"a rollout moved {t['rollout_displacement_m']:.3f} m (its clearance "
                     f"{t['rollout_clearance_m']:+.3f} m; the tube's reach there {t['reach_m']:.3f} m)")
        else:
            text += f"the tube reaches {t['reach_m']:.3f} m"
        parts.append(text)
    if tb.get("needed_margin_m") is not None:
        a, b = tb["failing_times_s"]
        parts.append(f"{tb['failing_samples']} failing sample(s) over t = {a:.2f}-{b:.2f} s need a clearance of "
                     f"{tb['needed_margin_m']:.3f} m" + (f" ({tb['needed_margin_note']})" if tb.get("needed_margin_note")
                                                          else ""))
    if nc:
        own = (f"the start's ({nc['start_clearance_m']:.3f} m) or the goal's ({nc['goal_clearance_m']:.3f} m) own "
               "clearance")
        if tb.get("beyond_start_or_goal"):
            parts.append(f"more than {own}: no plan between them keeps it at this noise")
        elif tb.get("needed_margin_m") is not None:
            parts.append(f"not more than {own}: a plan keeping that margin there could certify it")
        rest = nc.get("at_rest") or {}
        if rest.get("drift_position_m") is not None and rest["before_tightest_s"] >= REST_NOTE_S:
            parts.append(f"the plan stands still {rest['before_tightest_s']:.1f} s before then, where the per-second "
                         f"disturbance drifts the car {rest['drift_position_m']:.3f} m and {rest['drift_heading_rad']:.3f} "
                         "rad (1 sigma) uncorrected")
    return "; ".join(parts)


def _conservatism_by_chance(result: dict):
    """(expected count, cells): the sum over the cells of the share of their rebuilt tubes over the
    conservatism limit at their own tightest samples, and how many cells have that reading; None
    when none has."""
    shares = [c["tube_check"]["below"]["subsampled"]["own_tightest"]["over_max"]
              for case in result["cases"] for c in case.get("cells", [])
              if ((((c.get("tube_check") or {}).get("below") or {}).get("subsampled") or {}).get("own_tightest"))]
    return (float(sum(shares)), len(shares)) if shares else None


def _conservatism_context(result: dict, failing: dict) -> str:
    """For a cell that fails on its conservatism at the tightest sample: what tubes rebuilt from the
    Monte Carlo's runs give there, and at their own tightest samples ('' when not recorded)."""
    if "conservatism_at_tightest" not in failing.get("reason", ""):
        return ""
    for case in result["cases"]:
        if case["map"] != failing["map"]:
            continue
        for c in case.get("cells", []):
            if c["controller"] != failing["controller"] or c["noise"] != failing["noise"]:
                continue
            tc = c.get("tube_check") or {}
            sub = (tc.get("below") or {}).get("subsampled") or {}
            if sub.get("conservatism_at_tightest_median") is None:
                return ""
            text = (f" ({tc['conservatism']['at_tightest']:.2f}; tubes rebuilt from the Monte Carlo's runs: median "
                    f"{sub['conservatism_at_tightest_median']:.2f} at this sample, "
                    f"{_pct(sub['conservatism_at_tightest_over_max'])} of them over {CONSERVATISM_MAX:g}")
            own = sub.get("own_tightest")
            if own:
                text += (f"; at their own tightest samples median {own['median']:.2f}, "
                         f"{_pct(own['over_max'])} over {CONSERVATISM_MAX:g}")
            return text + ")"
    return ""


def study_markdown(result: dict) -> str:
    """study.md: every number read from ``result``."""
    p = result["probability"]
    cr = result["criteria"]
    pl = result["planning"]
    lines = [
        "# The parking study: the suite's plans under the feedback laws, and their error tubes", "",
        "Produced by `nhstab parking study` (nhstab.batch.parking_study). Per map of the parking suite"
        + (f" in `{result['suite']}` (one's own car)" if result.get("suite") else "") + ", one plan: the "
        f"first plan of `nhstab run {map_ref('NAME', result.get('suite'))} --seed {result['plan_seed']}"
        + (" --fit" if pl.get("fit") else "") + "` (margin "
        + ("the map robot's" if pl["margin"] is None else str(pl["margin"]))
        + f", headroom {pl['headroom']:g}, {pl['planner']} with {pl['time_limit_s']:g} s"
        + ("; the gramian law's gains chosen per plan, `--gains auto`" if pl.get("gains") == "auto" else "")
        + ("; **TVLQR's Q from the car's outline**, `--tvlqr-q footprint` (e^T Q e: the mean squared move of "
           "its corners)" if pl.get("tvlqr_q") == "footprint" else "")
        + "). Per controller "
        f"and noise level (a cell): the {p:g}-tube (`predict_tube`, kind auto: linear where it holds, else sampled "
        f"with N = {result['rollouts']} rollouts, the {result.get('discards', 0)} most extreme left out, confidence "
        f"{result['confidence']:g}); {result['trials']} trials of "
        f"the run loop (seeds spawned from {result['root_seed']}): collision = the footprint overlaps a known "
        f"obstacle at some sample (FCL), success = no collision and the end within {result['tolerance']['position_m']:g} m "
        f"and {result['tolerance']['heading_rad']:g} rad of the goal (Wilson 95 %); and the tube check: "
        f"M = {result['mc_factor']} x N = {result['mc_runs']} further runs (seeds spawned from "
        f"{result['mc_root_seed']}) and their footprint displacement at every sample."
        + (" **The process disturbance acts per metre the car travels** (`--process-per metre`: its default "
           "intensities in unit / sqrt(m), none while the car stands), not per second as `nhstab run`'s default."
           if result.get("process_per") == "metre" else ""), "",
        f"Tube check: **cert.** = the fraction of runs whose own smallest FCL clearance over the samples is at least "
        f"the certified clearance (the sampled tube's whole-run claim; Wilson 95 %; runs whose clearance was not measured, "
        f"{MAX_MEASURED:,} poses a cell at most, are named apart and counted outside, and the check is undetermined when "
        f"they decide it); **per sample** = the fraction of "
        f"(run, sample) pairs whose displacement is within the reach (the reach's per-sample claim); 'all samples' = "
        f"runs within the reach at every sample at once (not a claim of the tube: recorded to show the difference); "
        f"**conservatism** = reach / MC {p:g}-quantile per sample (samples with quantile >= "
        f"{1000 * cr['quantile_floor_m']:g} mm): median, 95th percentile, max, at the tube's tightest sample; "
        f"**below** = samples whose reach is under the lower end of the quantile's {100 * cr['quantile_ci']:g} % "
        f"order-statistic interval (in brackets: the number a correct sampled tube of N rollouts shows on average, its "
        f"reach being the largest of N draws, below the quantile at a sample with probability beta = p^N). Pass: both "
        f"coverages' Wilson upper ends >= p, conservatism at the tightest sample <= {cr['conservatism_max']:g}, the "
        f"fraction of samples below <= beta.", ""]
    # plans
    lines += ["## Plans", "",
              "| map | car | size | plan | length [m] | duration [s] | cusps | margin [m] | nominal min clearance [m] "
              "| start / goal clearance [m] | planning wall [s] |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for case in result["cases"]:
        plan = case["plan"]
        if not plan.get("found"):
            lines.append(f"| {case['map']} | {case['car']} | {size_text(case)} | **no plan**: {plan['reason']} | - | - | - "
                         f"| - | - | - | {case['plan_wall_s']:.1f} |")
            continue
        lines.append(f"| {case['map']} | {case['car']} | {size_text(case)} | found | {plan['length_m']:.1f} | "
                     f"{plan['duration_s']:.1f} | {plan['cusps']} | {plan['margin_m']:g} | "
                     f"{plan['min_clearance_m']:.3f} | {plan['start_clearance_m']:.3f} / {plan['goal_clearance_m']:.3f} | "
                     f"{case['plan_wall_s']:.1f} |")
    lines.append("")
    for level in result["noise_levels"]:
        lines += [f"## Noise x{level:g}", "",
                  "| map | car | size | controller | tube (N) | certified clearance [m] | needed margin [m] | success "
                  "[Wilson 95 %] | collisions | missed goal | median min clearance [m] |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for case in result["cases"]:
            if not case["plan"].get("found"):
                continue
            for c in case["cells"]:
                if c["noise"] != level:
                    continue
                if "error" in c:
                    lines.append(f"| {case['map']} | {case['car']} | {size_text(case)} | {c['controller']} | no law: "
                                 f"{c['error']} | | | | | | |")
                    continue
                tb, tr = c["tube"], c["trials"]
                if "error" in tb:
                    kind, cert, need = "none", "no tube", "-"
                else:
                    kind = tb["kind"] + (f" ({tb['rollouts']})" if tb.get("rollouts") else "")
                    cert = f"{tb['certified_clearance_m']:+.3f}" + ("" if tb["certified"] else " **no**")
                    need = _f(tb.get("needed_margin_m"), ".3f")
                lines.append(
                    f"| {case['map']} | {case['car']} | {size_text(case)} | {c['controller']} | {kind} | {cert} | {need} | "
                    f"{tr['success']}/{tr['trials']} [{_pct(tr['wilson_lo'])}, {_pct(tr['wilson_hi'])}] | "
                    f"{tr['collisions']} | {tr['missed_goal']} | {_f(tr['median_min_clearance_m'], '.3f')} |")
        lines += ["", f"### Tube check, noise x{level:g}", "",
                  "| map | controller | tube | cert. [Wilson 95 %] | per sample | all samples | conservatism median / p95 / max "
                  "| at tightest | below [expected] | passes |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for case in result["cases"]:
            if not case["plan"].get("found"):
                continue
            for c in case["cells"]:
                if c["noise"] != level or "error" in c:
                    continue
                tc = c["tube_check"]
                if tc is None:
                    lines.append(f"| {case['map']} | {c['controller']} | none | - | - | - | - | - | - | - | **no** |")
                    continue
                cv, cons, bl = tc["coverage"], tc["conservatism"], tc["below"]
                cc, ps = tc.get("certificate_coverage"), tc["coverage_per_sample"]
                fails = failed_checks(tc["passes"])
                exp = bl.get("expected_if_correct")
                lines.append(
                    f"| {case['map']} | {c['controller']} | {c['tube']['kind']} | "
                    + (f"{_pct(cc['rate'], 2)} [{_pct(cc['wilson_lo'], 2)}, {_pct(cc['wilson_hi'], 2)}]" if cc else "-")
                    + (f" (+{cc['unmeasured']} runs unmeasured)" if cc and cc.get("unmeasured") else "")
                    + f" | {_pct(ps['rate'], 2)} | {_pct(cv['rate'], 1)} | {_f(cons['median'], '.2f')} / "
                    f"{_f(cons['p95'], '.2f')} / {_f(cons['max'], '.2f')} | {_f(cons['at_tightest'], '.2f')} | {bl['samples']}"
                    + (f" [{exp:.1f}]" if exp is not None else "") + " | "
                    + ("yes" if tc["passes"]["all"] else "**no** (" + ", ".join(fails) + ")") + " |")
        lines.append("")
    # not certified
    lines += ["## Cells whose plans cannot be certified", ""]
    any_nc = False
    for case in result["cases"]:
        for c in case.get("cells", []):
            tb = c.get("tube") or {}
            if "error" in c or "error" in tb:
                any_nc = True
                lines.append(f"- {case['map']}, {c['controller']}, x{c['noise']:g}: no tube ("
                             + (c.get("error") or tb.get("error")) + ")")
            elif tb.get("certified") is False:
                any_nc = True
                lines.append(f"- {case['map']}, {c['controller']}, x{c['noise']:g} ({tb['kind']} tube): "
                             + not_certified_text(tb))
    if not any_nc:
        lines.append("None.")
    lines.append("")
    # targets
    tg = result["targets"]
    lines += ["## Targets", ""]
    for key in ("no_collision_when_certified", "success", "tubes_pass"):
        t = tg[key]
        state = "not evaluated" if not t["evaluated"] else ("**met**" if t["met"] else "**NOT met**")
        lines.append(f"- {t['text']}: {state} ({t['checked']} cells checked, {len(t['failing'])} failing)")
        if key == "tubes_pass":
            chance = _conservatism_by_chance(result)
            if chance is not None:
                lines.append(f"  - by chance: tubes rebuilt from each cell's Monte Carlo runs, read at their own "
                             f"tightest samples, exceed the conservatism limit {CONSERVATISM_MAX:g} in {chance[0]:.1f} "
                             f"of these {chance[1]} cells on average (what tubes of N rollouts of these same loops give)")
        for f in t["failing"]:
            where = f"{f['map']}, {f['controller']}, x{f['noise']:g}"
            if key == "no_collision_when_certified":
                lines.append(f"  - {where}: {f['collisions']}/{f['trials']} trials collide")
            elif key == "success":
                if f.get("reason"):
                    lines.append(f"  - {where}: {f['reason']} (target {100 * f['target']:g} %)")
                else:
                    lines.append(f"  - {where}: {f['success']}/{f['trials']} (target {100 * f['target']:g} %; "
                                 f"{f['collisions']} collided, {f['missed_goal']} missed the goal, "
                                 f"{f['diverged']} diverged)")
            else:
                lines.append(f"  - {where}: {f['reason']}" + _conservatism_context(result, f))
    lines += ["", "## Cost", "",
              f"Whole study: {result['wall_s']:.0f} s wall with {result['workers']} worker(s) on {result['cpu_count']} "
              "core(s). Per map: planning and the cells (tube, trials, Monte Carlo), in seconds.", "",
              "| map | planning | cells | of which tubes | trials | Monte Carlo |", "|---|---|---|---|---|---|"]
    for case in result["cases"]:
        cells = [c for c in case.get("cells", []) if "wall_s" in c]
        tot = sum(c["wall_s"]["total"] for c in cells)
        lines.append(f"| {case['map']} | {case['plan_wall_s']:.1f} | {tot:.1f} | "
                     f"{sum(c['wall_s'].get('tube', 0.0) for c in cells):.1f} | "
                     f"{sum(c['wall_s'].get('trials', 0.0) for c in cells):.1f} | "
                     f"{sum(c['wall_s'].get('monte_carlo', 0.0) for c in cells):.1f} |")
    lines += ["", "Figures: `success.png` (success rate against slot or aisle size at each noise level); "
              "`tube_MAP.png` (each map: the tube's reach against the Monte Carlo quantile and its interval).", ""]
    return "\n".join(lines) + "\n"


# ---- figures -------------------------------------------------------------------------------------------

def tube_figure(curves: dict, result: dict, map_name: str):
    """Rows: controllers; columns: noise levels. The reach (tube) against the MC p-quantile of the
    displacement with its 95 % order-statistic interval; the tightest sample marked."""
    ctrls, levels = result["controllers"], result["noise_levels"]
    fig, axes = subplots(len(ctrls), len(levels), figsize=(max(6.0, 3.3 * len(levels)), 2.3 * len(ctrls) + 0.6),
                         squeeze=False,
                         sharex=True, layout="constrained")
    case = next(c for c in result["cases"] if c["map"] == map_name)
    cells = {(c["controller"], c["noise"]): c for c in case.get("cells", [])}
    for i, ctrl in enumerate(ctrls):
        for j, level in enumerate(levels):
            ax = axes[i, j]
            cur = curves.get((map_name, ctrl, level))
            if cur is None:
                ax.text(0.5, 0.5, "no tube", ha="center", va="center", transform=ax.transAxes)
                continue
            t = cur["t"]
            top = np.where(np.isfinite(cur["q_hi"]), cur["q_hi"], cur["q"])      # no upper end: up to the quantile
            ax.fill_between(t, cur["q_lo"], top, color="tab:orange", alpha=0.3, lw=0,
                            label="MC quantile 95 % interval")
            ax.plot(t, cur["q"], color="tab:orange", lw=0.9, label=f"MC {result['probability']:g}-quantile")
            ax.plot(t, cur["reach"], color="tab:blue", lw=1.0, label="tube reach")
            k = cur.get("tightest")
            if k is not None and k >= 0:
                ax.axvline(t[k], color="tab:red", lw=0.8, ls="--", label="tightest sample")
            c = cells.get((ctrl, level), {})
            tb = c.get("tube", {})
            ax.set_title(f"{ctrl}, x{level:g}: {tb.get('kind', '')}, "
                         + ("passes" if (c.get("tube_check") or {}).get("passes", {}).get("all") else "fails"),
                         fontsize=8)
            ax.grid(alpha=0.3)
            ax.set_ylim(bottom=0.0)
    axes[0, 0].legend(fontsize=6)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("displacement [m]", fontsize=8)
    fig.suptitle(f"{map_name}: footprint displacement, tube reach against {result['mc_runs']} Monte Carlo runs",
                 fontsize=9)
    return fig


def success_figure(result: dict):
    """Success rate (Wilson 95 % bars) against the size factor, per car and kind; one panel per noise level."""
    levels = result["noise_levels"]
    fig, axes = subplots(1, len(levels), figsize=(4.2 * len(levels), 3.4), squeeze=False, sharey=True,
                         layout="constrained")
    markers = {"gramian": "o", "tvlqr": "s", "open-loop": "^"}
    colors = {"parallel": "tab:blue", "perpendicular": "tab:green", "angled45": "tab:orange", "angled60": "tab:red"}
    styles = {"rwd_car": "-", "van": ":"}
    for j, level in enumerate(levels):
        ax = axes[0, j]
        for car in sorted({c["car"] for c in result["cases"]}):
            for kind in colors:
                for ctrl in result["controllers"]:
                    pts = []
                    for case in result["cases"]:
                        if case["car"] != car or case["kind"] != kind:
                            continue
                        cell = next((c for c in case.get("cells", []) if c["controller"] == ctrl
                                     and c["noise"] == level and "trials" in c), None)
                        if cell is None:
                            pts.append((case["factor"], 0.0, 0.0, 0.0))
                        else:
                            tr = cell["trials"]
                            pts.append((case["factor"], tr["success_rate"], tr["wilson_lo"], tr["wilson_hi"]))
                    if not pts:
                        continue
                    pts.sort()
                    f, r, lo, hi = (np.array(v) for v in zip(*pts))
                    ax.errorbar(f, 100 * r, yerr=[100 * np.maximum(r - lo, 0.0), 100 * np.maximum(hi - r, 0.0)], color=colors[kind],
                                ls=styles.get(car, "-"), marker=markers.get(ctrl, "x"), ms=3, lw=0.8, capsize=2,
                                label=f"{car} {kind} {ctrl}")
        ax.axhline(100 * TARGET_FULL, color="0.4", lw=0.6, ls="--")
        ax.axhline(100 * TARGET_TIGHT, color="0.6", lw=0.6, ls=":")
        ax.set_title(f"noise x{level:g}", fontsize=9)
        ax.set_xlabel("size factor (x L1, x A90, x estimate)")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("success [%]")
    axes[0, -1].legend(fontsize=5, ncol=2, loc="lower right")
    fig.suptitle(f"Parking study: success over {result['trials']} trials per cell", fontsize=9)
    return fig
