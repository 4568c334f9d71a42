"""Planning the car with a trailer: exact, feasible, jackknife-free nominals that reverse into the dock,
checked independently (the model integrated under u0, every body against the map with shapely);
the gain schedule's tail; bad requests."""

import dataclasses
import math

import numpy as np
import pytest
import shapely.geometry as sg
from nhstab.batch.vector import simulate_shared
from nhstab.collision import CollisionWorld
from nhstab.control import StabilizerOptions, compute_schedule
from nhstab.errors import InputError
from nhstab.execution.config import NoiseOptions
from nhstab.execution.controllers import FeedbackLaw
from nhstab.maps import load_map
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nhstab.planning import PathOptions, plan
from nhstab.planning.trailer import REEDS_SHEPP_SHARE, TrailerRig
from nhstab.planning.trailer_charts import steer_trailer
from nhstab.robot import default_robot, make_robot
from shapes import shapely_obstacles

DOCK = "maps/trailer/loading_dock.yaml"


def _bodies(robot, x):
    """Every body's polygon at state x, computed here from the columns and the hitch length (not with
    nhstab's body_poses)."""
    d = robot.model.hitch_lengths[0]
    car = (x[0], x[1], x[2])
    trailer = (x[0] - d * math.cos(x[4]), x[1] - d * math.sin(x[4]), x[4])
    return [sg.Polygon(fp.outline_at(p)) for fp, p in zip(robot.footprints, (car, trailer))]


@pytest.fixture(scope="module")
def dock_plan():
    m = load_map(DOCK)
    robot = default_robot("car_trailer")
    result = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(seed=3, time_limit_s=2.0))
    return m, robot, result


def test_dock_plan_is_exact_feasible_and_clear(dock_plan):
    m, robot, res = dock_plan
    assert res.ok, res.message
    nom, model = res.nominal, robot.model
    # starts at the start and ends at the goal (trailer in line, wheels straight)
    np.testing.assert_allclose(nom.x[0], [*m.start.as_array(), 0.0, m.start.theta], atol=1e-9)
    np.testing.assert_allclose(model.state_error(nom.x[-1], [*m.goal.as_array(), 0.0, m.goal.theta]), 0.0, atol=1e-6)
    # the model integrated under u0 reproduces x0 (multiple shooting, independently of how x0 was made)
    assert nom.feasibility_residual() < 1e-5
    # jackknife-free with room, steering within its limit
    assert np.abs(model.hitch_angles(nom.x)).max() <= 0.8 * model.jackknife_limit + 1e-9
    assert np.abs(nom.x[:, 3]).max() <= model.max_steer + 1e-9
    assert np.all(np.abs(nom.u[:, 0]) <= model.max_speed + 1e-9)
    # it reverses into the dock: the last part of the motion is in reverse, with at least one cusp
    assert res.metrics["cusps"] >= 1 and nom.u[-5:, 0].max() < 0
    # every body keeps the margin from every obstacle (shapely, at every sample)
    obstacles = shapely_obstacles(m)
    margin = robot.margin
    worst = min(min(poly.distance(obstacles) for poly in _bodies(robot, x)) for x in nom.x[::5])
    assert worst >= margin - 0.03          # samples every 0.1 s; the planner's own check runs every 5 cm
    assert res.metrics["min_clearance_m"] >= margin
    # the open yard is not tight for the Reeds-Shepp radius: its paths run first, with their share of the limit
    assert not res.metrics["tight_space"] and res.metrics["search_order"][0] == "reeds_shepp"
    assert res.metrics["search_budget_s"]["reeds_shepp"] <= REEDS_SHEPP_SHARE * 2.0 + 1e-9
    assert sum(res.metrics["search_budget_s"].values()) <= 2.0 + 1e-9


def test_goal_trailer_heading_is_met(tmp_path):
    """A goal with the trailer at an angle to the car (a configuration x, y, theta, theta1)."""
    text = ("bounds: [0, 0, 60, 40]\nobstacles:\n  - box: {center: [30, 38], size: [60, 4]}\n"
            "start: [10, 10, 0.0]\ngoal: [40, 22, 1.2]\n")
    p = tmp_path / "open.yaml"
    p.write_text(text)
    m = load_map(p)
    robot = default_robot("car_trailer")
    goal = np.array([40.0, 22.0, 1.2, 1.0])            # hitch angle 0.2 rad
    res = plan(m, robot, m.start.as_array(), goal, PathOptions(seed=1, time_limit_s=2.0))
    assert res.ok, res.message
    end = res.nominal.x[-1]
    assert end[4] == pytest.approx(1.0, abs=1e-6) and end[2] == pytest.approx(1.2, abs=1e-6)
    np.testing.assert_allclose(end[:2], goal[:2], atol=1e-6)


def test_bad_requests():
    m = load_map(DOCK)
    robot = default_robot("car_trailer")
    with pytest.raises(InputError) as err:          # beyond the jackknife limit
        plan(m, robot, [12.0, 5.0, 0.0, 1.2], m.goal.as_array())
    assert err.value.argument == "start" and "jackknife" in str(err.value)
    with pytest.raises(InputError) as err:
        plan(m, make_robot("car_trailer", hitch_lengths=[2.0, 2.0]), [12, 5, 0], m.goal.as_array())
    assert err.value.argument == "robot"
    with pytest.raises(InputError) as err:
        plan(m, robot, [12.0, 5.0, 0.0], m.goal.as_array(), PathOptions(turning_radius=1.0))
    assert err.value.argument == "turning_radius"


def test_rig_checks_the_car_where_the_path_turns():
    """The geometric search places the car by the turn of each segment: the same trailer pose is free
    on a straight and blocked on an arc when an obstacle stands where the turning car would be."""
    robot = default_robot("car_trailer")
    from nhstab.maps.base import Polygon
    opts = PathOptions().for_robot(robot)
    world = CollisionWorld([Polygon(np.array([[6.5, 1.4], [8.5, 1.4], [8.5, 3.0], [6.5, 3.0]]))],
                           bounds=(-20, -20, 40, 40))
    rig = TrailerRig(world, robot, 0.1, opts)
    pose = np.array([[0.0, 0.0, 0.0]])
    straight, left = rig.car_poses(pose, [0.0]), rig.car_poses(pose, [1.0])
    assert straight[0, 2] == 0.0 and left[0, 2] == pytest.approx(math.atan(3.0 / opts.turning_radius))
    assert rig.connect((0.0, 0.0, 0.0), (10.0, 0.0, 0.0))           # straight: the car passes below the box
    R = opts.turning_radius
    assert not rig.connect((0.0, 0.0, 0.0), (R * math.sin(1.0), R * (1 - math.cos(1.0)), 1.0))


def test_tail_keeps_the_reversing_gramian_law(rng):
    """On a straight reverse the frozen end strategy lets the error grow over the last window (the
    linearised flow is unstable in reverse); with the nominal's tail every window inside the plan is
    whole. 16 trials with the default noise, the same seeds."""
    m = make_model("car_trailer")
    v, L, delta = 0.72, 30.0, 10.0
    piece = steer_trailer(m, np.zeros(5), np.array([-(L + v * 20.0), 0, 0, 0, 0.0]), T=(L + v * 20.0) / v)
    t = np.linspace(0.0, L / v, int(round(L / v / 0.02)) + 1)
    nom = Nominal.from_functions(m, piece.states_at, piece.inputs_at, t)
    opts = StabilizerOptions(alpha=0.05, delta=delta)
    frozen = compute_schedule(nom, opts)
    nom.tail = Nominal.from_functions(m, lambda s: piece.states_at(s + t[-1]), lambda s: piece.inputs_at(s + t[-1]),
                                      np.linspace(0.0, 20.0, 1001))
    tailed = compute_schedule(nom, opts)
    assert tailed.diagnostics["tail_s"] == pytest.approx(delta, abs=0.02)
    np.testing.assert_allclose(tailed.K[0], frozen.K[0], rtol=1e-6, atol=1e-9)   # the same where windows are whole
    # the tail covers delta: every window on the plan's grid is whole, and the end strategy does not act there
    assert tailed.diagnostics["end"].startswith("none: every window fits")
    assert tailed.diagnostics["sliding_window_until_s"] == t[-1]
    extended = compute_schedule(nom, dataclasses.replace(opts, end_strategy="extend"))
    assert np.array_equal(extended.K, tailed.K)
    seeds = list(range(16))
    finals = {}
    for name, sch in (("frozen", frozen), ("tail", tailed)):
        law = FeedbackLaw("gramian", nom, sch.t, sch.K, sch)
        finals[name] = np.median(simulate_shared(law, seeds, NoiseOptions(), model=m, record=False).final_error_norm)
    assert finals["tail"] < 0.4 and finals["frozen"] > 2.0 * finals["tail"]


@pytest.mark.parametrize("radius,within", [(10.0, False), (14.0, True), (20.0, True)])
def test_pieces_between_straight_rigs_need_wide_arcs(radius, within):
    """Why the search does not join poses where the rig stands straight with the polynomial steering:
    an 8 m piece along an arc keeps within 0.9 of the steering limit only from a radius of about 14 m."""
    m = make_model("car_trailer")
    d = m.hitch_lengths[0]

    def straight(x1, y1, th):
        return np.array([x1 + d * math.cos(th), y1 + d * math.sin(th), th, 0.0, th])

    th = 8.0 / radius
    piece = steer_trailer(m, straight(0.0, 0.0, 0.0), straight(radius * math.sin(th), radius * (1 - math.cos(th)), th),
                          T=10.0, frame=0.5 * th)
    assert (piece.max_abs_phi <= 0.9 * m.max_steer) == within
