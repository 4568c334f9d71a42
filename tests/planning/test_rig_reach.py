"""nhstab.planning.rig_reach: the exhaustive grid search of where the car with a trailer can get to, and
`nhstab trailer reach`."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from nhstab.collision import CollisionWorld
from nhstab.errors import InputError
from nhstab.maps import load_map
from nhstab.planning.rig_reach import reach_text, rest_state, rig_reach
from nhstab.robot import robot_from_spec

from tests.clitools import invoke, one_line

RIG = {"model": "car_trailer", "name": "rig", "wheelbase": 2.5, "hitch_lengths": [3.0], "max_speed": 1.5,
       "max_steer": 0.6, "max_steer_rate": 1.0, "jackknife_limit": 1.0,
       "footprint": {"rectangle": {"length": 4.2, "width": 1.8, "rear_overhang": 0.9}},
       "trailer_footprint": {"rectangle": {"length": 2.5, "width": 1.8, "rear_overhang": 1.0}}, "margin": 0.05}


def _corridor(tmp_path, goal_x: float, second_chamber: bool):
    """The rig heading +x in a chamber closed by walls at x = 5.30 and 14.50. Straight along x it spans
    [X - 4, X + 3.3] (X its car's rear axle), so with a 0.05 m margin X = 10.05 + 0.2 k is free for
    k = -3 .. 5 (0.15 m to a wall at both ends) and not for k = -4 or 6 (overlapping). Beyond the wall
    14.50 .. 15.00 the map is open up to its edge, or with ``second_chamber`` closed by a wall at 30.0."""
    walls = [{"box": {"center": [5.05, 0.0], "size": [0.5, 8.0], "yaw": 0.0}},
             {"box": {"center": [14.75, 0.0], "size": [0.5, 8.0], "yaw": 0.0}}]
    if second_chamber:
        walls.append({"box": {"center": [30.25, 0.0], "size": [0.5, 8.0], "yaw": 0.0}})
    data = {"name": "corridor", "bounds": [0.0, -4.0, 32.0, 4.0], "obstacles": walls,
            "start": [10.05, 0.0, 0.0], "goal": [goal_x, 0.0, 0.0], "robot": RIG}
    path = tmp_path / "corridor.yaml"
    path.write_text(yaml.safe_dump(data))
    m = load_map(str(path))
    robot = robot_from_spec(m.robot, source="map")
    world = CollisionWorld.from_map(m, "known")
    ends = [rest_state(robot.model, robot.configuration(p.as_array(), k)) for p, k in ((m.start, "start"),
                                                                                     (m.goal, "goal"))]
    return path, world, robot, ends


def test_a_closed_chamber_reaches_exactly_the_cells_the_geometry_allows(tmp_path):
    # straight moves only (one steering level): the start's chamber holds 9 positions, the goal is beyond
    # a wall, so the start's end closes with exactly those 9 cells and its trailer axle at most 1.0 m away.
    # (The end with the smaller frontier grows first, the start on a tie: the goal, mid-way in its longer
    # chamber, has as many ways on as the start until the start's run out.)
    _, world, robot, (xs, xg) = _corridor(tmp_path, 23.0, second_chamber=True)
    r = rig_reach(world, robot, xs, xg, 0.05, steer_levels=1, budget_s=60.0)
    assert r["verdict"] == "disconnected" and r["closed_end"] == "start"
    assert r["start"]["cells"] == 9
    assert r["start"]["farthest_m"] == pytest.approx(1.0, abs=1e-9)
    assert r["start"]["closest_m"] == pytest.approx(23.0 - 11.05, abs=1e-9)   # k = 5 is the nearest
    # the goal at its chamber's left end can only go right: it grows alone and closes first, with the
    # 38 positions 19.2 + 0.2 k (k = 0 .. 37) that keep 0.05 m from the walls at 15.0 and 30.0
    r = rig_reach(world, robot, xs, rest_state(robot.model, [19.2, 0.0, 0.0, 0.0]), 0.05, steer_levels=1)
    assert r["verdict"] == "disconnected" and r["closed_end"] == "goal"
    assert r["goal"]["cells"] == 38 and r["goal"]["farthest_m"] == pytest.approx(7.4, abs=1e-9)


def test_ends_in_one_chamber_meet_after_the_distance_between_them(tmp_path):
    _, world, robot, (xs, xg) = _corridor(tmp_path, 11.05, second_chamber=False)
    r = rig_reach(world, robot, xs, xg, 0.05, steer_levels=1, budget_s=60.0)
    assert r["verdict"] == "connected"
    assert r["travel_m"] == pytest.approx(1.0, abs=1e-9)
    # and with steering the same ends are still joined
    assert rig_reach(world, robot, xs, xg, 0.05, budget_s=60.0)["verdict"] == "connected"


def test_a_larger_margin_closes_the_chamber_tighter(tmp_path):
    # 0.15 m to each wall at k = -3 and 5: a margin of 0.2 m takes those two positions away
    _, world, robot, (xs, xg) = _corridor(tmp_path, 23.0, second_chamber=True)
    r = rig_reach(world, robot, xs, xg, 0.2, steer_levels=1, budget_s=60.0)
    assert r["verdict"] == "disconnected" and r["start"]["cells"] == 7


def test_no_budget_is_undecided_and_bad_grids_name_their_key(tmp_path):
    _, world, robot, (xs, xg) = _corridor(tmp_path, 19.2, second_chamber=True)
    r = rig_reach(world, robot, xs, xg, 0.05, budget_s=0.0)
    assert r["verdict"] == "undecided" and r["stopped"] == "budget"
    r = rig_reach(world, robot, xs, xg, 0.05, max_cells=50)        # memory's guard: a cap on the cells
    assert r["verdict"] == "undecided" and r["stopped"] == "cells"
    assert 50 <= r["start"]["cells"] + r["goal"]["cells"] and "cap of 50 cells" in reach_text(r)
    for key, value in (("cell_m", 0.0), ("angle_rad", math.nan), ("steer_levels", 2.5), ("step_m", -1.0),
                       ("max_cells", 0)):
        with pytest.raises(InputError) as exc:
            rig_reach(world, robot, xs, xg, 0.05, **{key: value})
        assert key in str(exc.value)
    with pytest.raises(InputError, match="start"):
        rig_reach(world, robot, xs[:3], xg, 0.05)
    with pytest.raises(InputError, match="goal"):          # the rig overlapping the wall at 14.5 .. 15.0
        rig_reach(world, robot, xs, rest_state(robot.model, [12.0, 0.0, 0.0, 0.0]), 0.05)


def test_the_suites_narrowest_bay_off_its_narrowest_aisle_is_closed_at_the_goal():
    # the 1.1 W bay off the 1.2 S aisle: the rig driving out of the bay meets the aisle's far wall before
    # its trailer has left the bay; every configuration reachable from the docked rig stays in the bay
    m = load_map("example:trailer_dock_bay110_aisle120")
    robot = robot_from_spec(m.robot, source="map")
    world = CollisionWorld.from_map(m, "known")
    xs = rest_state(robot.model, robot.configuration(m.start.as_array(), "start"))
    xg = rest_state(robot.model, robot.configuration(m.goal.as_array(), "goal"))
    r = rig_reach(world, robot, xs, xg, robot.margin, budget_s=120.0)
    assert r["verdict"] == "disconnected" and r["closed_end"] == "goal"
    # the trailer's axle moves at most the bay's depth less the trailer: it never gets into the aisle
    trailer_axle_goal_y = robot.body_poses(xg)[-1, 1]
    assert r["goal"]["farthest_m"] < trailer_axle_goal_y
    assert np.isfinite(r["goal"]["closest_m"])


def test_cli_reach_writes_its_table_and_refuses_bad_arguments(tmp_path):
    path, *_ = _corridor(tmp_path, 23.0, second_chamber=True)
    out = tmp_path / "out"
    res = invoke("trailer", "reach", path, "--steer-levels", "1", "--budget", "30", "--out", out)
    assert res.exit_code == 0, res.output
    assert "disconnected (start closed)" in (out / "reach.md").read_text()
    one_line(invoke("trailer", "reach", path, "--step", "0"), 2, "--step")
    # the library's ranges, named by the options; the angle in degrees
    one_line(invoke("trailer", "reach", path, "--cell", "100"), 2, "--cell", "[0.001, 10] m")
    one_line(invoke("trailer", "reach", path, "--angle", "1000"), 2, "--angle", "57.2958] deg")
    one_line(invoke("trailer", "reach", path, "--budget", "1e300"), 2, "--budget")
    one_line(invoke("trailer", "reach", path, "--steer-levels", "0"), 2, "--steer-levels")
    one_line(invoke("trailer", "reach", "example:parking_lot"), 2, "car_trailer")


def test_a_dolly_and_a_trailer_are_searched_as_the_model_has_them(tmp_path):
    # two trailers: the cells are the last trailer's axle, its heading and both hitch angles; straight
    # moves in open space join ends 1.0 m apart (within a cell: at most one more move)
    rig = {**RIG, "hitch_lengths": [1.5, 3.0],
           "trailer_footprint": [{"rectangle": {"length": 1.2, "width": 1.8, "rear_overhang": 0.6}},
                                 {"rectangle": {"length": 2.5, "width": 1.8, "rear_overhang": 1.0}}]}
    data = {"name": "dolly", "bounds": [0.0, -10.0, 40.0, 10.0], "obstacles": [],
            "start": [12.05, 0.0, 0.0], "goal": [13.05, 0.0, 0.0], "robot": rig}
    path = tmp_path / "dolly.yaml"
    path.write_text(yaml.safe_dump(data))
    m = load_map(str(path))
    robot = robot_from_spec(m.robot, source="map")
    assert robot.trailers == 2
    world = CollisionWorld.from_map(m, "known")
    xs, xg = (rest_state(robot.model, robot.configuration(p.as_array(), k)) for p, k in ((m.start, "start"),
                                                                                         (m.goal, "goal")))
    assert xs.shape == (robot.model.n,) == (6,)
    r = rig_reach(world, robot, xs, xg, 0.05, steer_levels=1, budget_s=60.0)
    assert r["verdict"] == "connected" and 1.0 - 1e-9 <= r["travel_m"] <= 1.2 + 1e-9
    # a wall across the way closes the start's end
    data["obstacles"] = [{"box": {"center": [12.55 + 3.3 + 0.3, 0.0], "size": [0.2, 8.0], "yaw": 0.0}}]
    data["goal"] = [26.0, 0.0, 0.0]
    path.write_text(yaml.safe_dump(data))
    m = load_map(str(path))
    xg = rest_state(robot.model, robot.configuration(m.goal.as_array(), "goal"))
    r = rig_reach(CollisionWorld.from_map(m, "known"), robot, xs, xg, 0.05, steer_levels=1, budget_s=60.0)
    assert r["verdict"] == "disconnected"
