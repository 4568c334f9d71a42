"""The composite controller's parts: plant, feedback laws, noise, config, determinism."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from nhstab.control import StabilizerOptions, compute_schedule
from nhstab.errors import InputError
from nhstab.execution import ControllerOptions, Plant, RunOptions, build_law, execute, summary, tvlqr_gains
from nhstab.execution.config import NoiseOptions, load_run_config, merge
from nhstab.execution.outputs import nominal_cusps
from nhstab.execution.seeds import planner_seed
from nhstab.maps.base import Map, Pose, box_polygon
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nhstab.robot import default_footprint, make_robot
from scipy.integrate import solve_ivp
from scipy.linalg import solve_continuous_are


@pytest.mark.parametrize("name,u", [("unicycle", [1.0, 2.0]), ("rwd_car", [1.5, 0.8]), ("fwd_car", [1.0, -0.9]),
                                    ("heisenberg", [0.7, -1.1])])
def test_plant_step_matches_an_adaptive_solve(name, u):
    """One 20 ms hold with 4 RK4 substeps agrees with DOP853 at rtol 1e-12 to 1e-10 (state units)."""
    model = make_model(name)
    x = np.array({"unicycle": [1.0, 2.0, 0.3], "rwd_car": [0.0, 0.0, 0.2, 0.1], "fwd_car": [0.0, 0.0, -0.2, 0.4],
                  "heisenberg": [0.1, 0.2, 0.3]}[name])
    u = np.array(u)
    got = Plant(model, 0.02, 4).step(x, u)
    ref = solve_ivp(lambda t, z: model.rhs(z, u), (0.0, 0.02), x, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
    assert np.max(np.abs(got - ref)) < 1e-10


def test_plant_is_vectorised_over_trials_and_stops_at_the_steering_limit():
    model = make_model("rwd_car")
    plant = Plant(model, 0.02, 4)
    xs = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, 2.0, 0.5, -0.2]])
    us = np.array([[1.0, 0.5], [-1.0, 0.3]])
    both = plant.step(xs, us)
    for i in range(2):
        assert np.array_equal(both[i], plant.step(xs[i], us[i]))
    x = np.array([0.0, 0.0, 0.0, 0.59])
    for _ in range(10):
        x = plant.step(x, np.array([1.0, 1.0]))
    assert x[3] == pytest.approx(model.max_steer, abs=1e-15)


def _straight(model, duration=40.0, n=2001):
    t = np.linspace(0.0, duration, n)
    return Nominal.from_inputs(model, lambda tt: np.stack([np.ones_like(tt), 0 * tt], -1), np.zeros(model.n), t)


def test_tvlqr_converges_to_the_algebraic_riccati_solution_and_ends_at_Q():
    """On a time-invariant nominal (straight line at 1 m/s), far from the end S(t) is the ARE's
    solution (scipy.linalg.solve_continuous_are), and K(T) = R^-1 B^T Q."""
    model = make_model("unicycle")
    nom = _straight(model)
    q, r = np.array([2.0, 1.0, 0.5]), np.array([1.0, 0.3])
    K = tvlqr_gains(nom, q, r)
    A, B = model.linearize(nom.x[0], nom.u[0])
    S = solve_continuous_are(A, B, np.diag(q), np.diag(r))
    assert np.max(np.abs(K[0] - np.diag(1 / r) @ B.T @ S)) < 1e-9
    assert np.max(np.abs(K[-1] - np.diag(1 / r) @ B.T @ np.diag(q))) < 1e-12


def test_tvlqr_matches_an_adaptive_riccati_solve_on_a_curved_nominal():
    """The Hilare sinusoid: RK4 on the grid against DOP853 on the continuous nominal, to 1e-6."""
    model = make_model("unicycle")
    t = np.linspace(0.0, 2 * math.pi, 1001)
    nom = Nominal.from_inputs(model, lambda tt: np.stack([np.sin(tt), np.cos(tt)], -1), np.zeros(3), t)
    K = tvlqr_gains(nom, np.ones(3), np.ones(2))

    def rhs(tau, s):
        x0, u0 = nom.at(np.array([tau]))
        A, B = model.linearize(x0[0], u0[0])
        S = s.reshape(3, 3)
        return -(A.T @ S + S @ A - S @ B @ B.T @ S + np.eye(3)).ravel()

    sol = solve_ivp(rhs, (t[-1], 0.0), np.eye(3).ravel(), method="DOP853", rtol=1e-11, atol=1e-13, dense_output=True)
    for k in (0, 300, 700):
        S = sol.sol(t[k]).reshape(3, 3)
        assert np.max(np.abs(K[k] - model.g(nom.x[k]).T @ S)) < 1e-6


def test_gramian_law_is_the_schedule_and_open_loop_has_no_feedback():
    model = make_model("unicycle")
    nom = _straight(model, 12.0, 601)
    opts = ControllerOptions(kind="gramian", alpha=0.2, delta=2.0, gamma=1.0)
    law = build_law(nom, opts, {"alpha": 0.1, "delta": 1.0, "gamma": 1.0})
    sched = compute_schedule(nom, StabilizerOptions(alpha=0.2, delta=2.0, gamma=1.0))
    x = np.array([3.1, 0.2, 0.1])
    u, x0, e = law.control(3.05, x.copy())
    assert np.allclose(u, sched.control(3.05, x), atol=1e-9)
    ol = build_law(nom, ControllerOptions(kind="open-loop"), {})
    u_ol, _, _ = ol.control(3.05, x.copy())
    assert np.allclose(u_ol, nom.at(3.05)[1], atol=1e-12)


def test_mean_input_is_the_exact_average_of_the_piecewise_linear_input():
    model = make_model("unicycle")
    t = np.linspace(0.0, 1.0, 11)
    u = np.stack([t ** 2, np.sin(5 * t)], -1)
    nom = Nominal.from_samples(model, t, np.zeros((11, 3)), u)
    law = build_law(nom, ControllerOptions(kind="open-loop"), {})
    fine = np.linspace(0.23, 0.47, 200001)
    ref = np.trapezoid(np.stack([np.interp(fine, t, u[:, i]) for i in range(2)], -1), fine, axis=0) / 0.24
    assert np.allclose(law.mean_input(0.23, 0.47), ref, atol=1e-9)
    # held at the end value past the span
    assert np.allclose(law.mean_input(1.0, 1.2), u[-1], atol=1e-12)


def test_cusps_ignore_short_back_and_forth_motion():
    model = make_model("unicycle")
    t = np.linspace(0.0, 10.0, 1001)
    v = np.where(t < 4, 1.0, np.where(t < 4.2, -1.0, np.where(t < 6, 1.0, -1.0)))
    nom = Nominal.from_samples(model, t, np.zeros((len(t), 3)), np.stack([v, 0 * v], -1))
    cusps = nominal_cusps(nom)      # 4 -> 4.2 s is 0.2 m backwards: not a cusp; 6 s is
    assert len(cusps) == 1 and cusps[0] == pytest.approx(6.0, abs=0.02)


# ---- options and config ---------------------------------------------------------------------------------------

def test_noise_levels_by_state_name_are_validated():
    names = ("x", "y", "theta")
    NoiseOptions(sensor={"x": 0.1}).validated(names)
    with pytest.raises(InputError, match="noise.sensor.z"):
        NoiseOptions(sensor={"z": 0.1}).validated(names)
    with pytest.raises(InputError, match="noise.process.x"):
        NoiseOptions(process={"x": -0.1}).validated(names)
    assert np.allclose(NoiseOptions(scale=2.0, sensor={"x": 0.1}).vector("sensor", names), [0.2, 0.04, 0.02])


@pytest.mark.parametrize("text,key", [
    ("controler: {kind: gramian}\n", "controler"),
    ("controller: {kind: pid}\n", "controller"),
    ("controller: {alpha: -1}\n", "controller.alpha"),
    ("rate_hz: 0\n", "rate_hz"),
    ("noise: {sensor: {x: -0.1}}\n", "noise.sensor.x"),
    ("noise: {sensor: {x: 0.1, q: 1}}\n", "noise.sensor.q"),
    ("noise: {process: {per: hour}}\n", "noise.process.per"),
    ("noise: {process: {per: [metre]}}\n", "noise.process.per"),
    ("noise: {process: {per: null}}\n", "got 'null'"),
    ("sensor: {range_m: 0}\n", "sensor.range_m"),
    ("sensor: {fov: 90}\n", "sensor.fov"),
    ("replan: {max_attempts: 0}\n", "replan.max_attempts"),
    ("start: [1, 2]\n", "start"),
    ("seed: -3\n", "seed"),
    ("saturate: 1\n", "saturate"),
])
def test_a_bad_run_config_names_the_key(tmp_path, text, key):
    f = tmp_path / "run.yaml"
    f.write_text(text)
    with pytest.raises(InputError) as err:
        _, opts = load_run_config(f)
        opts.validated(("x", "y", "theta"), 2)
    assert key in str(err.value) and "\n" not in str(err.value)


def test_run_config_round_trip_and_command_line_override(tmp_path):
    f = tmp_path / "run.yaml"
    f.write_text("map: maps/x.yaml\nseed: 7\ncontroller: {kind: tvlqr, q: [1, 2, 3]}\n"
                 "noise: {scale: 0.5, initial: {distribution: uniform, x: 0.2}, impulses: [{time: 2.0, y: 0.3}],\n"
                 "        process: {per: metre, y: 0.03}}\n"
                 "sensor: {fov_deg: 180}\n")
    extra, opts = load_run_config(f)
    assert extra["map"] == tmp_path / "maps/x.yaml"
    assert opts.seed == 7 and opts.controller.kind == "tvlqr" and opts.controller.q == (1, 2, 3)
    assert opts.noise.distribution == "uniform" and opts.noise.impulses == ((2.0, {"y": 0.3}),)
    assert opts.noise.process_per == "metre" and opts.noise.process == {"y": 0.03}
    assert NoiseOptions().process_per == "second"
    assert opts.sensor.fov_rad == pytest.approx(math.pi)
    merged = merge(opts, seed=9, controller__kind="gramian", planning__margin=None)
    assert merged.seed == 9 and merged.controller.kind == "gramian" and merged.controller.q == (1, 2, 3)


def test_planner_seeds_differ_per_call_and_are_reproducible():
    seeds = [planner_seed(3, i) for i in range(5)]
    assert len(set(seeds)) == 5 and seeds == [planner_seed(3, i) for i in range(5)]
    assert all(0 <= s < 2**31 for s in seeds)


# ---- runs on a small open map ---------------------------------------------------------------------------------

def _open_map(unknown=()):
    return Map("open", (0.0, 0.0, 20.0, 10.0), obstacles=(box_polygon(10.0, 8.5, 4.0, 1.0),),
               unknown_obstacles=tuple(unknown), start=Pose(2.0, 5.0, 0.0), goal=Pose(17.0, 5.0, 0.0))


def _run(m, **kw):
    model, fp = make_model("unicycle"), default_footprint("unicycle")
    return execute(m, make_robot(model, footprint=fp), m.start.as_array(), m.goal.as_array(), RunOptions(**kw))


def test_noiseless_run_tracks_the_nominal_to_integration_accuracy():
    """No noise and no initial error: the closed loop reproduces the nominal (ZOH with the mean input
    over each hold interval) to millimetres, and reaches the goal."""
    r = _run(_open_map(), noise=NoiseOptions(scale=0.0))
    assert r.status == "reached"
    s = summary(r)
    assert s["tracking"]["max_position_error_m"] < 2e-3
    assert s["final_error"]["position_m"] < 2e-3


def test_the_feedback_corrects_an_initial_error():
    r = _run(_open_map(), noise=NoiseOptions(initial={"x": 0.3, "y": 0.3, "theta": 0.2}, sensor={"x": 0, "y": 0,
                                                                                                   "theta": 0},
                                             process={"x": 0, "y": 0, "theta": 0}), seed=5)
    e = np.linalg.norm(make_model("unicycle").state_error(r.log["x"], r.log["x0"]), axis=1)
    assert r.status == "reached"
    assert e[0] > 0.1 and e[-2] < 0.1 * e[0]


def test_measured_noise_has_the_configured_spread():
    r = _run(_open_map(), noise=NoiseOptions(sensor={"x": 0.05, "y": 0.01, "theta": 0.02}), seed=2)
    n = r.log["y"] - r.log["x"]
    sd = n.std(axis=0)
    # sample std of ~1000 draws: within 10% (about 4 standard errors)
    assert np.allclose(sd, [0.05, 0.01, 0.02], rtol=0.1)


@pytest.mark.slow
def test_same_seed_same_run_json_except_timing(tmp_path):
    from nhstab.execution import write_run

    m = _open_map(unknown=(box_polygon(9.0, 5.0, 0.6, 3.0),))
    texts = []
    for k in range(2):
        r = _run(m, seed=11)
        write_run(r, tmp_path / str(k), figures=False)
        d = json.loads((tmp_path / str(k) / "run.json").read_text())
        timing = d.pop("timing")
        texts.append(json.dumps(d, sort_keys=True))
        assert r.status == "reached" and len(r.plans) >= 2
        # the latency ends with the feedback law; the tube's time, after it, is recorded beside it
        for rec, t in zip(r.plans, timing["plans"]):
            assert t["attempt_latencies_s"] == [a["latency_s"] for a in rec.attempts]
            assert t["attempt_tube_s"][-1] > 0 and rec.tube is not None
        assert "tube_s" not in json.dumps(d["plans"])
    assert texts[0] == texts[1]
    assert (tmp_path / "0" / "trajectory.csv").read_bytes() == (tmp_path / "1" / "trajectory.csv").read_bytes()
    r3 = _run(m, seed=12)
    assert not np.array_equal(r3.log["y"][:50], r.log["y"][:50])


def test_a_start_in_collision_is_bad_input_and_an_unreachable_goal_is_a_status():
    m = _open_map()
    with pytest.raises(InputError, match="start"):
        execute(m, make_robot(make_model("unicycle"), footprint=default_footprint("unicycle")), np.array([10.0, 8.5, 0.0]),
                m.goal.as_array(), RunOptions())
    walled = replace(m, obstacles=m.obstacles + (box_polygon(12.0, 5.0, 0.5, 10.0),))
    r = execute(walled, make_robot(make_model("unicycle"), footprint=default_footprint("unicycle")), m.start.as_array(),
                np.array([17.0, 5.0, 0.0]), RunOptions(planning=replace(RunOptions().planning, time_limit_s=0.3)))
    assert r.status == "no_plan" and "no collision-free path" in r.message


def test_a_zero_margin_is_a_valid_request():
    """planning.margin = 0 plans (it used to be mistaken for a start in contact)."""
    r = _run(_open_map(), noise=NoiseOptions(scale=0.0), planning=replace(RunOptions().planning, margin=0.0))
    assert r.status == "reached" and r.plans[0].margin == 0.0


def test_the_first_plan_is_retried_with_new_seeds_then_a_larger_budget(monkeypatch):
    """The planner fails twice: the run retries the first plan (new seed each time, the third attempt
    with budget_growth times the budget) and then reaches the goal; the attempts are recorded."""
    import nhstab.execution.runner as runner
    from nhstab.execution.config import PlanningOptions, ReplanOptions
    from nhstab.planning import PlanResult

    real, calls = runner.plan, []

    def flaky(m, robot, start, goal, path_opts, *args, **kw):
        calls.append(path_opts)
        if len(calls) <= 2:
            return PlanResult("no_path", "no collision-free path found (injected)", None)
        return real(m, robot, start, goal, path_opts, *args, **kw)

    monkeypatch.setattr(runner, "plan", flaky)
    r = _run(_open_map(), seed=4, planning=PlanningOptions(time_limit_s=0.5), replan=ReplanOptions(budget_growth=3.0))
    assert r.status == "reached"
    first = r.plans[0]
    assert [a["status"] for a in first.attempts] == ["no_path", "no_path", "ok"]
    assert [c.time_limit_s for c in calls[:3]] == [0.5, 0.5, 1.5]
    assert len({c.seed for c in calls[:3]}) == 3
    assert r.seeds["planner_calls"][:3] == [c.seed for c in calls[:3]]


def test_no_first_plan_after_every_attempt(monkeypatch):
    import nhstab.execution.runner as runner
    from nhstab.planning import PlanResult

    monkeypatch.setattr(runner, "plan", lambda *a, **k: PlanResult("no_path", "none (injected)", None))
    r = _run(_open_map(), seed=1)
    assert r.status == "no_plan" and len(r.plans[0].attempts) == 3
    assert "3 attempts" in r.message
