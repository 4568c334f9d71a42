"""Runs that act on their error tubes: the verdict line before the robot moves, --require-certified,
and the cusp checks (the rest of the maneuver's tube from the measured state, a replan where it is not
clear)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab.cli.main import cli
from nhstab.collision import CollisionWorld
from nhstab.errors import InputError
from nhstab.execution import RunOptions, execute
from nhstab.execution.config import TubeOptions, options_from_mapping
from nhstab.maps import load_map
from nhstab.maps.base import Map, Pose, box_polygon
from nhstab.models import make_model
from nhstab.robot import default_footprint, make_robot
from nhstab.tubes.sampled import remaining_law, sampled_tube


@pytest.mark.slow
def test_require_certified_refuses_an_uncertified_plan_and_says_why(tmp_path):
    """A parallel slot of 1.0 x L1 at the map's 0.1 m margin: the plan's tube is not certified, so with
    --require-certified the robot never moves: exit code 5, run.json says not_certified with the plan, its
    tube and verdict, and the log holds no sample (nothing that looks like a run)."""
    out = tmp_path / "o"
    res = CliRunner().invoke(cli, ["run", "example:parallel_rwd_car_100", "--require-certified",
                                                   "--out", str(out)])
    assert res.exit_code == 5, res.output + res.stderr
    assert "NOT certified" in res.stderr and "would certify it" in res.stderr
    doc = json.loads((out / "run.json").read_text())
    assert doc["status"] == "not_certified" and "require_certified" in doc["message"]
    plan = doc["plans"][0]
    assert plan["tube"]["certified"] is False and plan["tube"]["verdict"]["needed_margin_m"] > 0.1
    assert plan["tube_line"].startswith("plan 0 tube") and "NOT certified" in plan["tube_line"]
    assert doc["tracking"]["samples"] == 0 and doc["collision"] is None
    lines = (out / "trajectory.csv").read_text().strip().splitlines()
    assert len(lines) == 1                       # the header alone


def _open_map():
    return Map("open", (0.0, 0.0, 20.0, 10.0), obstacles=(box_polygon(10.0, 8.5, 4.0, 1.0),),
               start=Pose(2.0, 5.0, 0.0), goal=Pose(17.0, 5.0, 0.0))


def test_require_certified_lets_a_certified_plan_run():
    m = _open_map()
    lines = []
    r = execute(m, make_robot(make_model("unicycle"), footprint=default_footprint("unicycle")), m.start.as_array(), m.goal.as_array(),
                RunOptions(seed=2, tube=TubeOptions(require_certified=True)), notify=lines.append)
    assert r.status == "reached" and r.plans[0].tube.certified
    assert len(lines) == 1 and "certified clear by" in lines[0]


def test_tube_options_are_checked_and_read_from_configs():
    opts = options_from_mapping({"tube": {"kind": "sampled", "probability": 0.99, "confidence": 0.9,
                                          "require_certified": True}, "replan": {"at_cusps": False}})
    opts.validated(("x", "y", "theta"), 2)
    assert opts.tube.require_certified and opts.tube.kind == "sampled" and not opts.replan.at_cusps
    for bad, key in (({"tube": {"kind": "wide"}}, "tube.kind"), ({"tube": {"confidence": 1.0}}, "tube.confidence"),
                     ({"tube": {"require_certified": "yes"}}, "tube.require_certified"),
                     ({"tube": {"probability": 0.999999, "confidence": 0.999999}}, "tube.confidence"),
                     ({"replan": {"at_cusps": 1}}, "replan.at_cusps")):
        with pytest.raises(InputError, match=key.replace(".", r"\.")):
            options_from_mapping(bad).validated(("x", "y", "theta"), 2)


@pytest.mark.parametrize("flags,needle", [(["--confidence", "1.5"], "'--confidence'"),
                                          (["--probability", "0"], "'--probability'"),
                                          (["--tube", "wide"], "--tube")])
def test_run_refuses_bad_tube_flags_by_their_names(tmp_path, flags, needle):
    res = CliRunner().invoke(cli, ["run", "example:parallel_rwd_car_100", "--out", str(tmp_path / "o"), *flags])
    assert res.exit_code == 2 and needle in res.output and "Traceback" not in res.output
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", ["parallel_rwd_car_120", "perpendicular_rwd_car_aisle160"])
@pytest.mark.slow
def test_cusp_replanning_triggers_exactly_where_the_rest_is_not_certified(name):
    """At every cusp the run predicts the rest of the maneuver's tube from the measured state. Recomputed
    here independently (the rest of the plan's law from the measured state, the rollouts starting at it
    with the sensor noise's spread), the certified clearance is the one the run found, and the run
    replanned at exactly the cusps where it is negative (up to replan.max_cusp_replans), and followed a
    replan only if its tube is certified. (On the 1.2 x L1 slot the rest is not certified at the cusp; on
    the 1.6 x A90 aisle every rest is certified.)"""
    m = load_map(f"maps/parking/{name}.yaml")
    r = execute(m, opts=RunOptions(seed=0))
    assert r.status == "reached", r.message
    checks = [(rec, c) for rec in r.plans for c in rec.cusp_checks]
    assert checks
    world = CollisionWorld.from_map(m, "known")
    o = r.options
    names = r.model.state_names
    sens = o.noise.vector("sensor", names)
    start_noise = dataclasses.replace(o.noise, distribution="gaussian", impulses=(),
                                      initial={s: float(v) for s, v in zip(names, sens)})
    for rec, c in checks:
        k = int(np.flatnonzero(np.isclose(r.log["t"], c["time_s"]))[0])
        y = r.log["y"][k]
        assert np.array_equal(np.asarray(c["measured_state"]), y)
        rest = sampled_tube(remaining_law(rec.law, c["plan_time_s"]), start_noise, r.footprint, world,
                            model=r.model, probability=o.tube.probability, confidence=o.tube.confidence, x_start=y)
        assert rest.certified_clearance == pytest.approx(c["certified_clearance_m"], abs=1e-12)
        capped = "max_cusp_replans" in c.get("why_not", "")
        assert bool(c.get("replanned", False)) == (rest.certified_clearance < 0 and not capped)
        if c.get("adopted"):
            assert c["new_certified_clearance_m"] >= 0.0
    if name.startswith("parallel"):
        assert any(c.get("replanned") for _, c in checks)
        adopted = [c for _, c in checks if c.get("adopted")]
        assert len(r.plans) == 1 + len(adopted)
        for rec in r.plans[1:]:
            assert rec.trigger == "cusp" and rec.tube is not None
    else:
        assert all(c["certified"] for _, c in checks) and len(r.plans) == 1


# ---- the time a plan stands still, and what a per-second disturbance does there ----------------------

def test_standing_steps_and_the_drift_at_rest_in_closed_form():
    """A pose that does not move between samples stands (a turn through +-pi by a hair is motion); a
    per-second disturbance of intensity s drifts a robot standing t seconds by s sqrt(t) (1 sigma), the
    position's the larger of x's and y's; per metre travelled it does not act at rest (None)."""
    from nhstab.execution.config import NoiseOptions
    from nhstab.tubes.base import rest_drift, standing_steps

    poses = np.array([[0, 0, 0], [0, 0, 0], [0.1, 0, 0], [0.1, 0, 0], [0.1, 0, np.pi - 1e-4],
                      [0.1, 0, -np.pi + 1e-4], [0.1, 0, -np.pi + 1e-4]], dtype=float)
    assert standing_steps(poses).tolist() == [True, False, True, False, False, True]
    assert standing_steps(poses[:1]).shape == (0,)
    names = ("x", "y", "theta", "phi")
    noise = NoiseOptions(scale=2.0, process={"x": 0.01, "y": 0.03, "theta": 0.005})
    pos, head = rest_drift(noise, names, 16.0)
    assert pos == pytest.approx(2.0 * 0.03 * 4.0, rel=1e-12) and head == pytest.approx(2.0 * 0.005 * 4.0, rel=1e-12)
    assert rest_drift(dataclasses.replace(noise, process_per="metre"), names, 16.0) is None
    assert rest_drift(noise, ("x", "y"), 16.0) is None and rest_drift(None, names, 16.0) is None


@pytest.mark.parametrize("per", ["second", "metre"])
def test_an_uncertified_tube_says_how_long_the_plan_stands_before_its_tightest_point(per):
    """The van in the 0.9 x L1 parallel slot (it steers in place at its cusps): the verdict's time at rest is
    the nominal's, measured independently from the model's speed (nhstab.tubes.sampled.interior_stops,
    to within a control period per stop), and the line a user reads names the drift a per-second
    disturbance gives there (0.02 m/sqrt(s) sqrt(t)); per metre it does not."""
    from nhstab.tubes.sampled import interior_stops

    m = load_map("example:parallel_van_090")
    lines = []
    from nhstab.execution.config import NoiseOptions
    from nhstab.maps import resolve_poses
    from nhstab.robot import resolve_robot

    robot = resolve_robot(None, m.robot)
    start, goal = resolve_poses(m, None, None)
    r = execute(m, robot, start, goal, RunOptions(seed=0, noise=NoiseOptions(process_per=per),
                                                  tube=TubeOptions(require_certified=True)), notify=lines.append)
    assert r.status == "not_certified"
    plan = r.plans[0]
    v = plan.tube.info["verdict"]
    nominal = plan.law.nominal
    T = 1.0 / r.options.rate_hz
    t_tight = v["tightest"]["time_s"]
    # the nominal's own grid: a step stands where the model's speed is zero at both of its ends
    xd = nominal.model.rhs(nominal.x, nominal.u)
    speed = np.hypot(xd[:, 0], xd[:, 1])
    rest = speed <= 1e-6 * speed.max()
    step_rest = rest[:-1] & rest[1:] & (nominal.t[1:] <= t_tight)
    independent = float(np.diff(nominal.t)[step_rest].sum())
    stops = [s for s in interior_stops(nominal, (0, 1, 2)) if s[0] < t_tight]
    assert len(stops) >= 2
    assert abs(v["at_rest"]["before_tightest_s"] - independent) <= (len(stops) + 2) * T + 1e-9
    assert v["at_rest"]["before_tightest_s"] <= v["at_rest"]["total_s"] <= v["at_rest"]["duration_s"]
    tube_lines = [ln for ln in lines if ln.startswith("plan 0 tube")]
    assert len(tube_lines) == 1, lines
    line = tube_lines[0]
    if per == "second":
        sigma = 0.02 * np.sqrt(v["at_rest"]["before_tightest_s"])
        assert f"stands still for {v['at_rest']['before_tightest_s']:.1f} s" in line
        assert f"drifts the robot by {sigma:.3f} m" in line
    else:
        assert "stands still" not in line and "per metre travelled" in line
