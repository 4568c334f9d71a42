"""The sampled error tube: its finite-sample certificate against a closed form, its rollouts against the
run loop, its region against shapely, and when it is used instead of the linear tube."""

from __future__ import annotations

import math

import numpy as np
import pytest
from nhstab.errors import InputError, NumericalError
from nhstab.execution import ControllerOptions, RunOptions, build_law, execute
from nhstab.execution.config import NoiseOptions
from nhstab.geometry import Footprint
from nhstab.maps.base import Map, Pose, box_polygon
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nhstab.robot import default_footprint, make_robot
from nhstab.tubes.base import DEFAULT_DISCARDS, displacement, hull_vertices, rollouts_needed
from nhstab.tubes.predict import predict_tube
from nhstab.tubes.sampled import interior_stops, linear_validity, sampled_tube
from scipy.optimize import brentq
from scipy.stats import binom, norm

ZERO = {"x": 0.0, "y": 0.0, "theta": 0.0}


@pytest.mark.parametrize("p,conf", [(0.997, 0.99), (0.997, 0.95), (0.9, 0.9), (0.5, 0.75), (0.9999, 0.999)])
def test_rollouts_needed_is_the_smallest_scenario_count(p, conf):
    N = rollouts_needed(p, conf)
    assert p ** N <= 1.0 - conf < p ** (N - 1)
    assert N == math.ceil(math.log(1.0 - conf) / math.log(p) - 1e-12)


@pytest.mark.parametrize("bad", [0.0, 1.0, -0.1, float("nan"), "0.9"])
def test_rollouts_needed_refuses_what_is_not_a_probability(bad):
    with pytest.raises(InputError):
        rollouts_needed(bad, 0.99)
    with pytest.raises(InputError):
        rollouts_needed(0.9, bad)


def test_rollouts_needed_refuses_counts_beyond_the_limit():
    with pytest.raises(InputError, match="rollouts"):
        rollouts_needed(0.999999, 0.999999)


def test_displacement_bounds_every_point_of_the_moved_footprint_and_is_attained():
    """The displaced footprint lies in the nominal footprint grown by the displacement (shapely), and the
    displacement is the largest point displacement over a dense sampling of the footprint (attained at a
    hull vertex), for convex and non-convex footprints; a disc's is its centre's."""
    from shapely import affinity
    from shapely.geometry import Polygon

    rng = np.random.default_rng(5)
    shapes = [Footprint.rectangle(4.2, 1.8, 0.9).vertices,
              np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 0.4], [0.0, 1.0]]),     # non-convex
              np.array([[-0.5, -0.3], [1.5, -0.2], [0.3, 0.9]])]
    for v in shapes:
        fp = Footprint.polygon(v)
        hull = hull_vertices(fp)
        poly = Polygon(fp.vertices)
        # dense points of the footprint: its boundary and interior grid
        ts = np.linspace(0, 1, 50)[:, None]
        edges = np.concatenate([a + ts * (b - a) for a, b in zip(fp.vertices, np.roll(fp.vertices, -1, axis=0))])
        for _ in range(40):
            p0 = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi)])
            p1 = p0 + np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), rng.normal(0, 0.2)])
            d = float(displacement(hull, p1[None], p0[None])[0])

            def place(pts, p):
                c, s = math.cos(p[2]), math.sin(p[2])
                return pts @ np.array([[c, s], [-s, c]]) + p[:2]

            moved = np.linalg.norm(place(edges, p1) - place(edges, p0), axis=1)
            assert moved.max() <= d + 1e-12
            assert moved.max() >= d - 1e-9          # attained at a vertex, which the sampling contains
            nominal = affinity.translate(affinity.rotate(poly, p0[2], origin=(0, 0), use_radians=True), *p0[:2])
            shifted = affinity.translate(affinity.rotate(poly, p1[2], origin=(0, 0), use_radians=True), *p1[:2])
            # (shapely draws the buffer's arcs as chords: 64 per quarter sit within 1e-4 d of the arc)
            assert nominal.buffer(d * (1 + 1e-4) + 1e-9, quad_segs=64).covers(shifted)
    disc = Footprint.disc(0.3)
    p0, p1 = np.array([1.0, 2.0, 0.1]), np.array([1.3, 2.4, 2.0])
    assert displacement(hull_vertices(disc), p1[None], p0[None])[0] == pytest.approx(0.5, abs=1e-15)


def _lagging_line(duration=4.0, v0=0.5, vmax=0.6):
    """A unicycle on a straight line at v0 with its speed limit just above it, a gramian law along it."""
    model = make_model("unicycle", max_speed=vmax)
    t = np.arange(0.0, duration + 1e-9, 0.02)
    x = np.column_stack([v0 * t, np.zeros_like(t), np.zeros_like(t)])
    u = np.column_stack([np.full_like(t, v0), np.zeros_like(t)])
    nom = Nominal.from_samples(model, t, x, u)
    return model, build_law(nom, ControllerOptions(kind="gramian", alpha=0.2, delta=1.0, gamma=1.0), {})


def test_certificate_against_the_closed_form_of_a_saturated_loop():
    """A unicycle set back 1 m (an impulse after the first step) behind a nominal that drives at 0.5 m/s,
    with a speed limit of 0.6 m/s and process noise along x only: the law asks for more than the limit at
    every later sample, so the loop runs saturated, and its error is the closed form
    e_k = -1 + 0.1 T (k - 1) + sigma sqrt(T) (w_0 + ... + w_(k-1)), a Gaussian. The footprint (a disc)
    moves by |e_k|, whose p-quantile q_k is known exactly.

    * The linear tube, which does not know the clipping, predicts the lag away: its reach at the end is
      under half of q.
    * The sampled tube at p = 0.9 needs N = 22 rollouts for confidence 0.9 (0.9^22 = 0.098). 400
      independent sampled tubes (8,800 rollouts, grouped by 22) put their reach below the true quantile
      in a fraction of them that is Binomial(400, 0.9^22): the scenario bound holds and is exact for a
      continuous law (checked within 3.3 standard deviations at three samples).
    * All 8,800 rollouts' empirical 0.9-quantile matches the closed form."""
    model, law = _lagging_line()
    sigma = 0.02
    noise = NoiseOptions(initial=dict(ZERO), sensor=dict(ZERO), process={"x": sigma, "y": 0.0, "theta": 0.0},
                         impulses=((0.0, {"x": -1.0}),))
    fp = Footprint.disc(0.3)
    p, T = 0.9, 0.02
    N = rollouts_needed(p, 0.9)
    assert N == 22
    groups = 400
    tube = sampled_tube(law, noise, fp, model=model, probability=p, rollouts=N * groups, keep_displacements=True)
    D = tube.info["displacements"]
    S = D.shape[1]
    assert S == 201
    # saturated at every step after the first, in every rollout
    assert np.all(tube.saturation_per_step[1:, 0] == 1.0)
    k = np.arange(S)
    mu = np.where(k >= 1, -1.0 + 0.1 * T * (k - 1), 0.0)
    sd = sigma * np.sqrt(T * k)

    def q_abs(m, s):                 # the p-quantile of |X|, X ~ N(m, s^2)
        return brentq(lambda q: norm.cdf((q - m) / s) - norm.cdf((-q - m) / s) - p, 0.0, abs(m) + 10 * s)

    picks = [50, 120, S - 1]
    q = np.array([q_abs(mu[j], sd[j]) for j in picks])
    # the error itself follows the closed form (mean and spread of all rollouts)
    assert np.allclose(tube.mean[picks, 0], mu[picks], atol=4 * sd[picks] / math.sqrt(N * groups))
    assert np.allclose(np.sqrt(tube.cov[picks, 0, 0]), sd[picks], rtol=0.05)
    emp = np.quantile(D[:, picks], p, axis=0)
    assert np.allclose(emp, q, atol=0.02 * q.max())
    # the scenario certificate: P(max of N below the p-quantile) = p^N exactly
    reach = D.reshape(groups, N, S).max(axis=1)[:, picks]
    misses = (reach < q).sum(axis=0)
    lo, hi = binom.ppf([0.0005, 0.9995], groups, p ** N)
    assert np.all((misses >= lo) & (misses <= hi)), (misses, lo, hi)
    assert abs(tube.certificate["confidence"] - (1.0 - p ** (N * groups))) < 1e-12
    # with r = 2 rollouts left out: the third largest of N2 below the p-quantile with P[Bin(N2, 1 - p) <= 2]
    N2 = rollouts_needed(p, 0.9, 2)
    assert binom.cdf(2, N2, 1 - p) <= 0.1 < binom.cdf(2, N2 - 1, 1 - p)
    g2 = (N * groups) // N2
    third = np.sort(D[:g2 * N2].reshape(g2, N2, S), axis=1)[:, -3][:, picks]
    misses = (third < q).sum(axis=0)
    lo, hi = binom.ppf([0.0005, 0.9995], g2, binom.cdf(2, N2, 1 - p))
    assert np.all((misses >= lo) & (misses <= hi)), (misses, lo, hi)
    # the linear tube misses the lag it cannot see
    lin = predict_tube(law, noise, fp, model=model, probability=p, kind="linear")
    assert lin.reach[-1] < 0.5 * q[-1]
    assert lin.saturation["run_bound"] > 0.99


def test_a_diverging_rollout_is_an_error_not_a_tube(monkeypatch):
    """Noise beyond its bounds (nhstab.limits.MAX_NOISE_LEVEL) is refused before anything runs; the guard
    behind them, for a closed loop that diverges anyway, is exercised with that check switched off."""
    monkeypatch.setattr(NoiseOptions, "validated", lambda self, state_names: self)
    model, law = _lagging_line()
    noise = NoiseOptions(initial=dict(ZERO), sensor=dict(ZERO), process=dict(ZERO),
                         impulses=((1.0, {"x": 1e308}), (1.0, {"x": 1e308})))
    with pytest.raises(NumericalError, match="rollouts of the closed loop diverged"):
        sampled_tube(law, noise, Footprint.disc(0.3), model=model, rollouts=3)


def _open_map():
    return Map("open", (0.0, 0.0, 20.0, 10.0), obstacles=(box_polygon(10.0, 8.5, 4.0, 1.0),),
               start=Pose(2.0, 5.0, 0.0), goal=Pose(17.0, 5.0, 0.0))


def test_rollouts_are_the_run_loop_bit_for_bit():
    """A rollout of the sampled tube with a run's seed is that run (nothing to discover, no replan): the
    same true states at every control sample, bit for bit, and so the same displacements."""
    m = _open_map()
    seed = 4
    r = execute(m, make_robot(make_model("unicycle"), footprint=default_footprint("unicycle")), m.start.as_array(), m.goal.as_array(),
                RunOptions(seed=seed))
    assert r.status in ("reached", "missed_goal") and len(r.plans) == 1
    o = r.options
    tube = sampled_tube(r.plans[0].law, o.noise, r.footprint, model=r.model, rollouts=3, seed_base=seed - 1,
                        keep_states=True, keep_displacements=True)
    X = tube.info["states"][1]
    assert X.shape == r.log["x"].shape
    assert np.array_equal(X, r.log["x"])
    other = tube.info["states"][0]
    assert not np.array_equal(other, r.log["x"])


def _car_along_a_wall():
    """The rwd_car driving 8 s at 1 m/s along a wall 0.3 m thick whose near side is 1.5 m from its path,
    under the gramian law: (robot, model, law, known world)."""
    from nhstab.collision import CollisionWorld
    from nhstab.robot import default_robot

    robot = default_robot("rwd_car")
    model = robot.model
    t = np.arange(0.0, 8.0 + 1e-9, 0.02)
    nom = Nominal.from_samples(model, t, np.column_stack([3.0 + 1.0 * t, 0 * t + 2.0, 0 * t, 0 * t]),
                               np.column_stack([1.0 + 0 * t, 0 * t]))
    law = build_law(nom, ControllerOptions(kind="gramian"), robot.stabilizer.as_dict())
    m = Map("wall", (0.0, 0.0, 18.0, 6.0), obstacles=(box_polygon(9.0, 3.65, 14.0, 0.3),))
    world = CollisionWorld.from_map(m, "known")
    return robot, model, law, world


@pytest.mark.parametrize("discards", [0, 2])
@pytest.mark.parametrize("scale", [1.0, 4.0])
def test_the_certified_clearance_is_the_rollouts_smallest_clearance(scale, discards):
    """The sampled tube's certified clearance is the (r + 1)-th smallest of the rollouts' own smallest FCL
    clearances (r = 0: the smallest of any rollout at any control sample), found by branch and bound: equal
    to measuring every rollout pose (a car along a wall, 60 rollouts, at the default noise (clear) and four
    times it (touching)); its reach the (r + 1)-th largest displacement at each sample; with the needed
    clearance of each failing sample the nominal's minus its worst rollout's, the r rollouts left out."""
    robot, model, law, world = _car_along_a_wall()
    tube = sampled_tube(law, NoiseOptions(scale=scale), robot.footprint, world, model=model, rollouts=60,
                        keep_states=True, keep_displacements=True, discards=discards)
    assert tube.certificate["discards"] == discards
    X = tube.info["states"][:, :, :3]
    c = world.clearance_many(X.reshape(-1, 3), robot.footprint).reshape(X.shape[:2])
    g = c.min(axis=1)                                  # each rollout's own smallest clearance
    kept = np.sort(np.argsort(g, kind="stable")[discards:])
    assert tube.certified_clearance == pytest.approx(np.sort(g)[discards], abs=1e-12)
    D = tube.info["displacements"]
    assert np.array_equal(tube.reach, np.sort(D, axis=0)[-1 - discards])
    rc = tube.info["rollout_clearance"]
    assert rc["rollout"] == np.argsort(g, kind="stable")[discards] and c[rc["rollout"], rc["sample"]] == g[rc["rollout"]]
    c = c[kept]
    grown = world.clearance_many(tube.poses, robot.footprint) - tube.reach
    assert rc["grown_footprint_clearance_m"] == pytest.approx(grown.min(), abs=1e-12)
    if grown.min() >= 0:             # (a penetration depth is not bounded by the displacement)
        assert tube.certified_clearance >= grown.min()
    if c.min() < 0:
        bad = np.flatnonzero((c < 0).any(axis=0))
        assert np.array_equal(rc["failing_index"], bad)
        need = world.clearance_many(tube.poses[bad], robot.footprint) - c[:, bad].min(axis=0)
        assert np.allclose(rc["failing_need_m"], need, atol=1e-12)
    assert (c.min() < 0) == (scale > 1.0)


def test_auto_keeps_the_linear_tube_where_it_holds_and_samples_elsewhere():
    """A unicycle's straight line at low noise: no stop, no saturation: the linear tube, valid. The lagging
    line: saturated: the sampled tube, and the certificate says why."""
    model = make_model("unicycle")
    t = np.arange(0.0, 6.0 + 1e-9, 0.02)
    nom = Nominal.from_samples(model, t, np.column_stack([0.4 * t, 0 * t, 0 * t]),
                               np.column_stack([0.4 + 0 * t, 0 * t]))
    law = build_law(nom, ControllerOptions(kind="gramian", alpha=0.2, delta=1.0), {})
    tube = predict_tube(law, NoiseOptions(scale=0.2), Footprint.disc(0.3), model=model)
    assert tube.kind == "linear" and tube.certificate["valid"] is True
    assert interior_stops(nom, [0, 1, 2]) == []
    model2, law2 = _lagging_line()
    noise = NoiseOptions(initial=dict(ZERO), sensor=dict(ZERO), process={"x": 0.02}, impulses=((0.0, {"x": -1.0}),))
    lin = predict_tube(law2, noise, Footprint.disc(0.3), model=model2, kind="linear")
    valid, why = linear_validity(lin, law2.nominal)
    assert not valid and "saturate" in why
    auto = predict_tube(law2, noise, Footprint.disc(0.3), model=model2, probability=0.9, confidence=0.9)
    assert auto.kind == "sampled" and auto.certificate["rollouts"] == rollouts_needed(0.9, 0.9, DEFAULT_DISCARDS) and "saturate" in auto.certificate["why"]
    assert auto.summary()["kind"] == "sampled"


def test_interior_stops_are_the_rests_between_motions():
    model = make_model("unicycle")
    t = np.arange(0.0, 6.0 + 1e-9, 0.02)
    v = np.where(t < 1.0, 0.0, np.where(t < 3.0, 0.5, np.where(t < 3.5, 0.0, np.where(t < 5.5, -0.5, 0.0))))
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * 0.02)])
    nom = Nominal.from_samples(model, t, np.column_stack([x, 0 * t, 0 * t]), np.column_stack([v, 0 * t]))
    stops = interior_stops(nom, [0, 1, 2])
    assert len(stops) == 1
    a, b = stops[0]
    assert a == pytest.approx(3.0, abs=0.021) and b == pytest.approx(3.48, abs=0.021)


def test_a_negative_clearance_without_measured_failing_samples_takes_them_from_the_reach():
    """The exact certificate names the failing samples when it measured a rollout pose inside an obstacle.
    When its negative clearance comes from its lower bound alone (the measurements cut short, as on a loop
    that diverges) it names none; the verdict then takes the samples where the reach meets an obstacle
    (failing_samples), and does not fail. Here: the car along a wall at four times the default noise, its
    certificate's failing samples removed."""
    from nhstab.tubes.base import failing_samples, verdict

    robot, model, law, world = _car_along_a_wall()
    tube = sampled_tube(law, NoiseOptions(scale=4.0), robot.footprint, world, model=model, rollouts=60)
    assert tube.certified_clearance < 0
    rc = tube.info["rollout_clearance"]
    for k in ("failing_samples", "failing_times_index", "needed_clearance_m", "failing_index", "failing_need_m",
              "failing_worst_m"):
        rc.pop(k, None)
    v = verdict(tube, world, robot.footprint, 0.1)
    idx, _ = failing_samples(world, robot.footprint, tube.poses, tube.reach)
    assert len(idx) > 0 and v["failing_samples"] == len(idx)
    assert v["failing_times_s"] == [float(tube.t[idx].min()), float(tube.t[idx].max())]
    assert v["needed_margin_m"] == pytest.approx(float(tube.reach[idx].max()), abs=1e-12)
