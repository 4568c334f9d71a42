"""The guided search on the bundled maps: exact, clear by the margin (FCL, recomputed on a fresh world),
stabilizable; the same seed gives the same plan, in-process and in a fresh process."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from nhstab.collision import CollisionWorld, interpolate_poses
from nhstab.examples import data_root
from nhstab.geometry import Footprint
from nhstab.maps import load_map
from nhstab.maps.base import Map, box_polygon
from nhstab.models import make_model
from nhstab.planning import PathOptions, default_turning_radius, plan, pose_columns
from nhstab.planning.geometric import plan_path
from nhstab.planning.guide import Guide, inscribed_disc
from nhstab.planning.problems import random_problems
from nhstab.robot import default_footprint, make_robot

MAPS = data_root()
MARGIN = 0.05


def _fresh_min_clearance(m, fp, poses):
    """The nominal's smallest clearance, interpolated every 5 cm, on a world built anew (FCL decides it)."""
    world = CollisionWorld.from_map(m)
    dense, _ = interpolate_poses(poses, 0.05, 0.05)
    return world.min_clearance(dense, fp)[0]


def _check(m, robot, start, goal, seed, world):
    model, fp = make_model(robot), default_footprint(robot)
    opts = PathOptions(turning_radius=default_turning_radius(model), time_limit_s=10.0, seed=seed, margin=MARGIN)
    r = plan(m, make_robot(model, footprint=fp), start, goal, opts, world=world)
    assert r.ok, r.message
    assert r.path.status == "exact"
    assert r.schedule is not None and r.metrics["h_min_eigenvalue"] > 0        # stabilizable
    poses = r.nominal.x[:, pose_columns(model)]
    assert _fresh_min_clearance(m, fp, poses) >= MARGIN - 1e-9
    np.testing.assert_allclose(poses[0], start, atol=1e-6)
    np.testing.assert_allclose(poses[-1, :2], goal[:2], atol=0.02)     # the nominal integrates the path
    return r


@pytest.fixture(scope="module")
def newyork():
    m = load_map(MAPS / "bench-mr" / "moving_ai_scenarios" / "NewYork_1_512.map", cell_size=0.25)
    return m, CollisionWorld.from_map(m)


def test_guided_unicycle_across_newyork(newyork):
    """A 180 m Moving AI problem (the longest bucket) at 0.25 m cells: the guide sets the subgoals, no
    OMPL search is needed, and the path is not much longer than the guide's grid shortest path."""
    m, world = newyork
    p = m.problems[-2]
    r = _check(m, "unicycle", p.start.as_array(), p.goal.as_array(), 1, world)
    info = r.path.info
    assert info["planner_used"] == "guided"
    assert r.path.length < 1.15 * p.reference_length
    guide = Guide(world.clearance_field(), default_footprint("unicycle"), 0.07, p.start.as_array(), p.goal.as_array())
    assert guide.ok and r.path.length < 1.15 * guide.shortest_length()


def test_guided_rwd_car_across_newyork_at_half_metre_cells():
    m = load_map(MAPS / "bench-mr" / "moving_ai_scenarios" / "NewYork_1_512.map", cell_size=0.5)
    world = CollisionWorld.from_map(m)
    p = m.problems[-2]
    r = _check(m, "rwd_car", p.start.as_array(), p.goal.as_array(), 0, world)
    assert r.path.info["planner_used"] == "guided"


@pytest.mark.parametrize("robot", ["unicycle", "rwd_car"])
def test_guided_on_the_depot(robot):
    """Ends in the open (the car's ends with less than CarOptions.open_clearance_m = 0.75 m go through
    its unparking maneuvers first, whose searches between nearby poses do not use the guide)."""
    m = load_map(MAPS / "nav2" / "depot.yaml")
    world = CollisionWorld.from_map(m)
    fp = default_footprint(robot)
    used = set()
    clearance = 0.5 if robot == "unicycle" else 1.0
    for k, (s, g) in enumerate(random_problems(world, fp, 3, seed=7, clearance=clearance, min_distance=8.0)):
        used.add(_check(m, robot, s, g, k, world).path.info["planner_used"])
    assert "guided" in used


def test_guided_rwd_car_in_the_warehouse_same_seed_same_plan():
    m = load_map(MAPS / "ours" / "warehouse_corridor.yaml")
    world = CollisionWorld.from_map(m)
    s, g = m.start.as_array(), m.goal.as_array()
    r1 = _check(m, "rwd_car", s, g, 3, world)
    _check(m, "rwd_car", s, g, 4, world)
    r2 = _check(m, "rwd_car", s, g, 3, world)
    np.testing.assert_array_equal(r1.path.waypoints, r2.path.waypoints)


def test_inscribed_disc_of_a_car():
    c, r = inscribed_disc(Footprint.rectangle(4.2, 1.8, rear_overhang=0.9))
    np.testing.assert_allclose(c, [1.2, 0.0])
    assert r == pytest.approx(0.9)


def test_guide_reports_no_path_and_the_planner_falls_back():
    """A wall that closes the map: the guide has no path; the planner searches unguided and fails with a
    status (not an exception)."""
    m = Map("closed", (0, 0, 20, 10), obstacles=(box_polygon(10, 5, 1.0, 10.0),))
    world = CollisionWorld.from_map(m)
    g = plan_path(world, Footprint.disc(0.3), (2, 5, 0), (18, 5, 0), PathOptions(turning_radius=1.0, time_limit_s=0.3, margin=0.1))
    assert g.status == "failed"
    assert g.info["guide"]["failure"] == "the grid has no path for the inscribed disc"


_CHILD = """
import json, sys
from nhstab.collision import CollisionWorld
from nhstab.geometry import Footprint
from nhstab.maps.base import Map, box_polygon
from nhstab.planning.geometric import PathOptions, plan_path
m = Map("wall", (0, 0, 20, 12), obstacles=(box_polygon(10, 4, 1.0, 8.0),))
g = plan_path(CollisionWorld.from_map(m), Footprint.rectangle(1.0, 0.6, rear_overhang=0.2), (2, 3, 0), (18, 3, 0),
              PathOptions(turning_radius=1.0, time_limit_s=5.0, seed=11, margin=0.2, guide=False))
print(json.dumps(g.waypoints.tolist()))
"""


def test_same_seed_same_plan_in_process_and_in_a_fresh_process():
    """OMPL is reseeded in-process for every call: the plan equals the one a fresh interpreter makes,
    after other seeds ran in this process."""
    m = Map("wall", (0, 0, 20, 12), obstacles=(box_polygon(10, 4, 1.0, 8.0),))
    world = CollisionWorld.from_map(m)
    fp = Footprint.rectangle(1.0, 0.6, rear_overhang=0.2)
    opts = PathOptions(turning_radius=1.0, time_limit_s=5.0, seed=11, margin=0.2, guide=False)
    for other in (3, 12):
        plan_path(world, fp, (2, 3, 0), (18, 3, 0), PathOptions(**{**opts.__dict__, "seed": other}))
    here = plan_path(world, fp, (2, 3, 0), (18, 3, 0), opts)
    out = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, check=True)
    fresh = np.array(json.loads(out.stdout.strip().splitlines()[-1]))
    assert here.info["ompl_calls"] == 1 and len(here.waypoints) > 2
    np.testing.assert_array_equal(here.waypoints, fresh)
    assert "leaked" not in out.stderr
    assert math.isfinite(here.length)
