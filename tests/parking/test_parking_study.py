"""``nhstab parking study`` (nhstab.batch.parking_study): its numbers recomputed independently from the run
loop and FCL, its tube check against brute-force numpy, its report against its JSON, and its refusals."""

import math

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab.batch.parking_study import below_chance, probability_beta
from nhstab.cli.main import cli
from nhstab.records import read_json
from scipy.integrate import quad
from scipy.stats import beta as beta_dist
from scipy.stats import binom

#: every test reads the study run once by the module fixtures
pytestmark = pytest.mark.slow

MAP = "parallel_rwd_car_140"
TRIALS = 20
MC_FACTOR = 1
ROOT_SEED = 2026


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    res = CliRunner().invoke(cli, ["parking", "study", "--out", str(out), "--maps", MAP, "--controllers", "gramian",
                                   "--noise", "1", "--trials", str(TRIALS), "--mc-factor", str(MC_FACTOR),
                                   "--root-seed", str(ROOT_SEED), "--no-fit", "--figures", MAP])
    assert res.exit_code == 0, res.output
    assert not (out / "study.json").exists()                  # the record is gzip-compressed, in one form
    result = read_json(out / "study.json.gz")
    return out, result


@pytest.fixture(scope="module")
def recomputed():
    """The same cell, recomputed here from the plan, simulate_shared (recording every state) and FCL."""
    from nhstab.batch.parking_study import first_plan
    from nhstab.batch.tube_study import trial_seeds
    from nhstab.batch.vector import simulate_shared
    from nhstab.execution.config import NoiseOptions
    from nhstab.execution.runner import final_errors
    from nhstab.tubes.base import displacement, hull_vertices, pose_indices, rollouts_needed
    from nhstab.tubes.predict import predict_tube

    run, _, result, law, _, _ = first_plan(MAP)
    noise = NoiseOptions(scale=1.0)
    # the tube from scratch (the study takes the plan's own: they must be the same)
    tube = predict_tube(law, noise, run.fp, run.known, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps,
                        model=run.model, probability=0.997, kind="auto", confidence=0.95)
    idx = pose_indices(run.model)
    sim = simulate_shared(law, trial_seeds(TRIALS, ROOT_SEED), noise, model=run.model)
    assert sim.completed.all()
    collided, reached = [], []
    for i in range(TRIALS):
        poses = sim.x[i][:, idx]
        collided.append(any(not run.known.is_free(p, run.fp, 0.0) for p in poses))
        fe = final_errors(run.robot, sim.x[i, -1], run.goal)
        reached.append(fe["position_m"] <= 0.3 and fe["heading_rad"] <= 0.2)
    collided, reached = np.array(collided), np.array(reached)
    M = MC_FACTOR * rollouts_needed(0.997, 0.95, tube.certificate["discards"])
    mc = simulate_shared(law, trial_seeds(M, ROOT_SEED + 1), noise, model=run.model)
    poses = mc.x[:, :, idx]
    D = displacement(hull_vertices(run.fp), poses, tube.poses[None])           # (M, S)
    return {"tube": tube, "collided": collided, "reached": reached, "D": D, "poses": poses, "M": M,
            "length_m": result.metrics["length_m"], "run": run, "law": law, "noise": noise}


def _cell(result):
    (case,) = result["cases"]
    assert case["map"] == MAP and case["plan"]["found"]
    (cell,) = case["cells"]
    return case, cell


def test_trials_match_an_independent_recount(study, recomputed):
    _, result = study
    case, cell = _cell(result)
    assert case["plan"]["length_m"] == pytest.approx(recomputed["length_m"], abs=1e-9)   # the same plan
    tr = cell["trials"]
    col, hit = recomputed["collided"], recomputed["reached"]
    assert tr["trials"] == TRIALS
    assert tr["collisions"] == int(col.sum())
    assert tr["success"] == int((~col & hit).sum())
    assert tr["missed_goal"] == int((~col & ~hit).sum())
    assert tr["per_trial"]["collided"] == col.tolist()
    rate, lo, hi = tr["success_rate"], tr["wilson_lo"], tr["wilson_hi"]
    assert lo <= rate <= hi and rate == tr["success"] / TRIALS


def test_tube_and_its_check_match_brute_force(study, recomputed):
    _, result = study
    _, cell = _cell(result)
    tube, D, M = recomputed["tube"], recomputed["D"], recomputed["M"]
    tb, tc = cell["tube"], cell["tube_check"]
    # the study's tube (the plan's own, reused) is the one predict_tube makes for the cell
    assert tb["kind"] == tube.kind and tb["certified_clearance_m"] == pytest.approx(tube.certified_clearance, abs=1e-12)
    assert tb["max_reach_m"] == pytest.approx(float(tube.reach.max()), abs=1e-12)
    reach, p = tube.reach, 0.997
    assert tc["mc_runs"] == M
    inside = D <= reach[None]
    assert tc["coverage"]["inside"] == int(inside.all(axis=1).sum())
    assert tc["coverage_min_per_sample"] == pytest.approx(inside.mean(axis=0).min(), abs=1e-12)
    q = np.quantile(D, p, axis=0, method="inverted_cdf")
    use = q >= 1e-3
    ratio = reach[use] / q[use]
    cons = tc["conservatism"]
    assert cons["median"] == pytest.approx(np.median(ratio), rel=1e-12)
    assert cons["p95"] == pytest.approx(np.percentile(ratio, 95), rel=1e-12)
    assert cons["max"] == pytest.approx(ratio.max(), rel=1e-12)
    k = tube.certified_index
    assert cons["at_tightest"] == pytest.approx(reach[k] / q[k], rel=1e-12)
    # below: under the order statistic X_(l), l the 2.5 % point of Bin(M, p)
    lower = np.sort(D, axis=0)[int(binom.ppf(0.025, M, p)) - 1]
    assert tc["below"]["samples"] == int(np.sum(reach < lower))
    # the certificate's coverage: each run's own smallest FCL clearance against the certified clearance
    # (measured where the bound c_k - D_k does not already clear it)
    world, fp = _world()
    c_nom = world.clearance_many(tube.poses, fp)
    i, k2 = np.nonzero(c_nom[None] - D < tube.certified_clearance)
    c = world.clearance_many(recomputed["poses"][i, k2], fp)
    below = np.unique(i[c < tube.certified_clearance])
    assert tc["certificate_coverage"]["inside"] == M - len(below)
    passes = tc["passes"]
    assert tc["coverage_per_sample"]["inside"] == int(inside.sum())
    assert passes["certificate_coverage"] == (tc["certificate_coverage"]["wilson_hi"] >= p)
    assert passes["coverage_per_sample"] == (tc["coverage_per_sample"]["wilson_hi"] >= p)
    assert passes["conservatism_at_tightest"] == (cons["at_tightest"] <= 1.25)
    beta = binom.cdf(tube.certificate["discards"], tube.certificate["rollouts"], 1.0 - p)   # 3rd largest of N below q
    assert tc["below"]["beta"] == pytest.approx(beta)
    # with as many Monte Carlo runs as rollouts (--mc-factor 1) no tube can be rebuilt from runs it is
    # held against: 'below' is undetermined, and the cell does not pass
    assert "subsampled" not in tc["below"] and passes["below"] is None and passes["all"] is False


def _world():
    from nhstab.collision import CollisionWorld
    from nhstab.maps import load_map
    from nhstab.robot import resolve_robot

    m = load_map(f"example:{MAP}")
    return CollisionWorld.from_map(m, "known"), resolve_robot(None, m.robot).footprint


def test_tube_check_on_synthetic_draws_is_the_brute_force_one():
    from nhstab.batch.parking_study import tube_check

    rng = np.random.default_rng(3)
    S, M, p = 40, 3000, 0.997
    Dt = np.abs(rng.standard_normal((S, M))) * np.linspace(0.05, 0.3, S)[:, None]
    q = np.quantile(Dt, p, axis=1, method="inverted_cdf")
    reach = q * np.where(np.arange(S) % 7 == 0, 0.9, 1.1)          # a few samples well below their quantile
    t = 0.02 * np.arange(S)
    rec, cur = tube_check(reach, Dt, p, t, tightest=5, rollouts=998)
    assert np.array_equal(cur["q"], q)
    lo = np.sort(Dt, axis=1)[:, int(binom.ppf(0.025, M, p)) - 1]
    hi = np.sort(Dt, axis=1)[:, int(binom.ppf(0.975, M, p))]
    assert np.array_equal(cur["q_lo"], lo) and np.array_equal(cur["q_hi"], hi)
    assert np.all(lo <= q) and np.all(q <= hi)
    assert rec["below"]["samples"] == int(np.sum(reach < lo)) > 0
    assert rec["coverage"]["inside"] == int(np.all(Dt <= reach[:, None], axis=0).sum())
    assert rec["coverage_per_sample"]["inside"] == int(np.sum(Dt <= reach[:, None]))
    assert rec["conservatism"]["at_tightest"] == pytest.approx(1.1)
    # 6 of 40 independent samples below: more than any of 1,000 tubes of 998 of these runs
    assert rec["below"]["subsampled"]["p_value"] <= 0.001
    assert not rec["passes"]["below"] and not rec["passes"]["all"]


def test_subsampled_reaches_are_the_order_statistics_of_their_subsets():
    """The rebuilt tubes of the 'below' check: for each subset of N runs (drawn as the check draws them),
    the (r + 1)-th largest displacement at every sample, and the lower end of the p-quantile's interval
    of the other runs, also where a subset has few of a sample's largest runs (the full computation
    there)."""
    from nhstab.batch.parking_study import SUBSAMPLE_SEED, quantile_indices, subsampled_reaches

    rng = np.random.default_rng(5)
    S, N, r, p = 30, 200, 2, 0.997
    M = 10 * N
    Dt = rng.gamma(2.0, 1.0, (S, M)) * np.linspace(0.1, 1.0, S)[:, None]
    Dt[3, :] = 0.0              # ties: a sample where nothing moves
    Dt[7, 5] = np.inf           # a diverged run
    got = list(subsampled_reaches(Dt, N, r, p, subsamples=25))
    draw = np.random.default_rng(SUBSAMPLE_SEED)
    lo = quantile_indices(M - N, p)[1]
    for reach, lower in got:
        chosen = draw.choice(M, size=N, replace=False)
        rest = np.setdiff1d(np.arange(M), chosen)
        assert np.array_equal(reach, np.sort(Dt[:, chosen], axis=1)[:, N - r - 1])
        assert np.array_equal(lower, np.sort(Dt[:, rest], axis=1)[:, lo - 1])
    # a subset with none of a sample's largest runs: taken in full
    Dt2 = np.zeros((2, M))
    Dt2[0] = np.arange(M)
    only, lower = next(subsampled_reaches(Dt2, N, 0, p, subsamples=1))
    chosen = np.random.default_rng(SUBSAMPLE_SEED).choice(M, size=N, replace=False)
    rest = np.setdiff1d(np.arange(M), chosen)
    assert only[0] == chosen.max() and only[1] == 0.0
    assert lower[0] == np.sort(rest)[lo - 1] and lower[1] == 0.0


def test_the_below_check_holds_correct_tubes_at_its_level_and_fails_a_short_one():
    """Tubes whose samples move together (one scale per run, as a run's early error carries on): a
    correct tube (the third largest of N fresh runs) fails 'below' about as rarely as its level says,
    though its fraction of samples below scatters far beyond a binomial count; a tube that bounds a
    lower quantile than it claims fails."""
    from nhstab.batch.parking_study import tube_check

    rng = np.random.default_rng(11)
    S, N, r, p = 60, 2097, 2, 0.997
    M = 10 * N
    shape = np.linspace(0.05, 0.4, S)[:, None]

    def runs(n):
        a = np.abs(rng.standard_normal(n))
        return shape * (0.7 * a[None, :] + 0.3 * np.abs(rng.standard_normal((S, n))))

    fails, fractions, t = 0, [], 0.1 * np.arange(S)
    for _ in range(20):
        Dt, fresh = runs(M), runs(N)
        reach = np.sort(fresh, axis=1)[:, N - r - 1]
        rec, _ = tube_check(reach, Dt, p, t, tightest=S - 1, rollouts=N, discards=r)
        fails += not rec["passes"]["below"]
        fractions.append(rec["below"]["fraction"])
        # a tube at the 0.99-quantile of its runs, claimed as the 0.997 one
        short, _ = tube_check(np.quantile(fresh, 0.99, axis=1), Dt, p, t, tightest=S - 1, rollouts=N, discards=r)
        assert not short["passes"]["below"]
    # level 0.1 %: 20 correct tubes fail at most once (P[Bin(20, 0.001) >= 2] < 0.02 %)
    assert fails <= 1
    # ... while their fractions below scatter: some tube is below at several times its mean
    assert max(fractions) > 3 * np.mean(fractions) > 0


def test_the_certificate_check_with_runs_left_unmeasured_is_a_range(recomputed, monkeypatch):
    """Under a cap on the poses measured, the runs found below the certified clearance are truly below
    (by brute force over every pose whose bound does not clear it), every truly-below run is found or
    left unmeasured, and the coverage's two ends bracket the exact one."""
    import nhstab.batch.parking_study as PS
    from nhstab.batch.tube_study import trial_seeds

    tube, D, M, poses = recomputed["tube"], recomputed["D"], recomputed["M"], recomputed["poses"]
    run, law, noise = recomputed["run"], recomputed["law"], recomputed["noise"]
    cert = tube.certified_clearance
    world, fp = _world()
    c_nom = world.clearance_many(tube.poses, fp)
    i, k = np.nonzero(c_nom[None] - D < cert)
    below_true = set(np.unique(i[world.clearance_many(poses[i, k], fp) < cert]).tolist())
    assert len(i) > 200                         # enough candidate poses for a cap to bite
    monkeypatch.setattr(PS, "MAX_MEASURED", len(i) // 3)
    Dt, rec = PS.mc_displacements(run, law, tube.poses, trial_seeds(M, ROOT_SEED + 1), noise, c_nom, cert)
    np.testing.assert_allclose(Dt, D.T, rtol=0, atol=1e-12)     # the displacements do not depend on the cap
    assert rec["measured"] == len(i) // 3 and not rec["complete"] and rec["unmeasured_runs"] > 0
    # the exact count lies between the found and the found plus the unmeasured
    assert rec["runs_below"] <= len(below_true) <= rec["runs_below"] + rec["unmeasured_runs"]
    # without the cap: the exact count, complete
    monkeypatch.setattr(PS, "MAX_MEASURED", len(i))
    _, full = PS.mc_displacements(run, law, tube.poses, trial_seeds(M, ROOT_SEED + 1), noise, c_nom, cert)
    assert full["complete"] and full["unmeasured_runs"] == 0 and full["runs_below"] == len(below_true)
    assert full["measured"] <= len(i)           # a run found below is not measured further


@pytest.mark.parametrize("below, unmeasured, verdict", [(0, 0, True), (0, 40, None), (40, 1, False)])
def test_the_certificate_check_is_undetermined_when_unmeasured_runs_decide_it(below, unmeasured, verdict):
    from nhstab.batch.parking_study import failed_checks, tube_check
    from nhstab.batch.report import wilson

    rng = np.random.default_rng(5)
    S, M, p = 10, 4000, 0.997
    Dt = np.abs(rng.standard_normal((S, M))) * 0.1
    reach = 1.5 * np.quantile(Dt, p, axis=1, method="inverted_cdf")
    rec, _ = tube_check(reach, Dt, p, 0.02 * np.arange(S), tightest=2, runs_below=below, rollouts=2097,
                        discards=2, runs_unmeasured=unmeasured)
    cc = rec["certificate_coverage"]
    assert cc["inside"] == M - below - unmeasured and cc["unmeasured"] == unmeasured
    assert cc["wilson_hi"] == pytest.approx(wilson(M - below - unmeasured, M)[2])
    assert rec["passes"]["certificate_coverage"] is verdict
    assert rec["passes"]["all"] == (verdict is True and all(v for key, v in rec["passes"].items()
                                                            if key not in ("all", "certificate_coverage")))
    if verdict is None:
        assert cc["wilson_hi_if_unmeasured_inside"] == pytest.approx(wilson(M - below, M)[2])
        assert "certificate_coverage undetermined" in failed_checks(rec["passes"])
    if verdict is False:
        assert "certificate_coverage" in failed_checks(rec["passes"])


def test_quantile_interval_covers_at_its_level():
    """The order-statistic interval [X_(l), X_(u)] holds the true p-quantile in at least 95 % of repeats."""
    from nhstab.batch.parking_study import quantile_indices

    rng = np.random.default_rng(11)
    M, p, R = 2000, 0.997, 4000
    j, l, u = quantile_indices(M, p)
    assert j == math.ceil(p * M)
    # uniform draws: the true quantile is p; only the l-th and u-th order statistics matter
    draws = np.sort(rng.random((R, M)), axis=1)
    held = (draws[:, l - 1] <= p) & (p <= draws[:, u - 1])
    assert held.mean() >= 0.95 - 3 * math.sqrt(0.05 * 0.95 / R)


def test_report_numbers_are_the_json_numbers(study):
    out, result = study
    md = (out / "study.md").read_text()
    case, cell = _cell(result)
    tb, tr, tc = cell["tube"], cell["trials"], cell["tube_check"]
    row = next(ln for ln in md.splitlines() if ln.startswith(f"| {MAP} |") and "| gramian | sampled (" in ln
               or ln.startswith(f"| {MAP} |") and "| gramian | linear" in ln)
    assert f"{tr['success']}/{tr['trials']} [{100 * tr['wilson_lo']:.1f}%, {100 * tr['wilson_hi']:.1f}%]" in row
    assert f"| {tr['collisions']} | {tr['missed_goal']} |" in row
    assert f"{tb['certified_clearance_m']:+.3f}" in row
    check = next(ln for ln in md.splitlines() if ln.startswith(f"| {MAP} | gramian | {tb['kind']} | "))
    cons = tc["conservatism"]
    assert f"{100 * tc['coverage_per_sample']['rate']:.2f}%" in check
    assert f"{100 * tc['certificate_coverage']['rate']:.2f}%" in check
    assert f"{cons['median']:.2f} / {cons['p95']:.2f} / {cons['max']:.2f}" in check
    assert f"| {tc['below']['samples']} [" in check
    assert ("| yes |" in check) == tc["passes"]["all"]
    # the targets section states what the JSON's targets say
    for key, text in (("success", "success >="), ("tubes_pass", "tube passes")):
        t = result["targets"][key]
        line = next(ln for ln in md.splitlines() if ln.startswith("- ") and text in ln)
        assert ("**met**" in line) == t["met"] and f"{t['checked']} cells checked, {len(t['failing'])} failing" in line
    assert (out / "success.png").stat().st_size > 0 and (out / f"tube_{MAP}.png").stat().st_size > 0


@pytest.mark.parametrize("args,needle", [
    (["--trials", "0"], "--trials"),
    (["--mc-factor", "0"], "--mc-factor"),
    (["--noise", "-1"], "--noise"),
    (["--noise", "1,lots"], "--noise"),
    (["--maps", "moon_base"], "--maps"),
    (["--controllers", "gramian,pid"], "--controllers"),
    (["--root-seed", "-3"], "--root-seed"),
    (["--workers", "0"], "--workers"),
    (["--process-per", "hour"], "--process-per"),
    (["--gains", "best"], "--gains"),
])
def test_bad_options_are_refused_in_one_line(tmp_path, args, needle):
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["parking", "study", "--out", str(out), *args])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], res.stderr
    assert "Traceback" not in res.output
    assert not out.exists()


@pytest.mark.parametrize("r", [0, 2])
def test_below_chance_is_the_order_statistics_integral(r):
    """A correct tube's chance of a 'below' at one sample: the (r + 1)-th largest of N uniform draws below
    the l-th of M others, E[P(Bin(N, 1 - U) <= r)], U ~ Beta(l, M - l + 1): the closed-form sum against a
    numerical integral, and against a seeded simulation of the two order statistics (3.5 standard errors)."""
    M, N, l = 5000, 700, 4975
    integral = quad(lambda u: binom.cdf(r, N, 1.0 - u) * beta_dist.pdf(u, l, M - l + 1), 0.98, 1.0, limit=200,
                    points=[l / (M + 1)])[0]
    got = below_chance(l, M, N, r)
    assert got == pytest.approx(integral, rel=1e-6)
    rng = np.random.default_rng(7)
    K = 4000
    y = np.sort(rng.random((K, M)), axis=1)[:, l - 1]
    x = np.sort(rng.random((K, N)), axis=1)[:, N - 1 - r]
    freq = float(np.mean(x < y))
    assert abs(freq - got) <= 3.5 * np.sqrt(got * (1 - got) / K) + 1e-3
    assert probability_beta(0.997, 2097, 2) == pytest.approx(binom.cdf(2, 2097, 0.003), rel=1e-12)
    assert probability_beta(0.997, 998, 0) == pytest.approx(0.997 ** 998, rel=1e-12)


def test_rebuilt_tubes_read_at_their_own_tightest_samples():
    """With the nominal's clearance, each rebuilt tube is also read where its own reach comes closest to
    the obstacles (argmin of clearance - reach over the samples with a quantile of at least 1 mm), as
    a tube picks its tightest sample; a failing cell's line in study.md quotes both readings."""
    from nhstab.batch.parking_study import (
        QUANTILE_FLOOR_M,
        SUBSAMPLES,
        _conservatism_context,
        quantile_indices,
        subsampled_reaches,
        tube_check,
    )

    rng = np.random.default_rng(8)
    S, N, r, p = 50, 300, 2, 0.997
    M = 10 * N
    Dt = np.abs(rng.standard_normal((S, M))) * np.linspace(0.02, 0.3, S)[:, None]
    Dt[0] = 0.0                                     # a sample whose quantile is under the floor
    c_nom = np.linspace(1.0, 0.5, S)
    c_nom[0] = -5.0                                 # ... is never picked, however tight
    reach = np.sort(Dt[:, :N], axis=1)[:, N - r - 1] * 1.3
    rec, _ = tube_check(reach, Dt, p, 0.1 * np.arange(S), tightest=S - 1, rollouts=N, discards=r,
                        nominal_clearance=c_nom)
    q = np.sort(Dt, axis=1)[:, quantile_indices(M, p)[0] - 1]
    use = q >= QUANTILE_FLOOR_M
    own = []
    for rb, _ in subsampled_reaches(Dt, N, r, p, SUBSAMPLES):
        k = int(np.argmin(np.where(use, c_nom - rb, np.inf)))
        assert k != 0
        own.append(rb[k] / q[k])
    got = rec["below"]["subsampled"]["own_tightest"]
    assert got["median"] == pytest.approx(np.median(own), rel=1e-12)
    assert got["over_max"] == pytest.approx(np.mean(np.array(own) > 1.25))
    k_cell = int(np.argmin(np.where(use, c_nom - reach, np.inf)))
    assert got["cell_index"] == k_cell and got["cell"] == pytest.approx(reach[k_cell] / q[k_cell])
    # the line of a cell failing on its conservatism
    result = {"cases": [{"map": "m", "cells": [{"controller": "gramian", "noise": 1.0, "tube_check": rec}]}]}
    line = _conservatism_context(result, {"map": "m", "controller": "gramian", "noise": 1.0,
                                          "reason": "conservatism_at_tightest"})
    assert f"median {rec['below']['subsampled']['conservatism_at_tightest_median']:.2f} at this sample" in line
    assert f"at their own tightest samples median {got['median']:.2f}" in line
    assert _conservatism_context(result, {"map": "m", "controller": "gramian", "noise": 1.0, "reason": "below"}) == ""
    from nhstab.batch.parking_study import _conservatism_by_chance

    twice = {"cases": result["cases"] + [{"map": "n", "cells": [{"controller": "tvlqr", "noise": 1.0, "tube_check": rec}]}]}
    assert _conservatism_by_chance(twice) == (pytest.approx(2 * got["over_max"]), 2)
    assert _conservatism_by_chance({"cases": [{"map": "n", "cells": [{"controller": "tvlqr", "noise": 1.0,
                                                                    "tube_check": None}]}]}) is None
