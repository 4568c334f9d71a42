"""Why a car with a trailer found no plan: the rig's likely cause (its bodies, its swept path), checked
on the trailer suite's 90 degree turn, narrowed, with a door in its corridor, and on the command line."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from clitools import invoke
from nhstab import trailer_suite as T
from nhstab.collision import CollisionWorld
from nhstab.maps import load_map
from nhstab.parking import Box
from nhstab.planning.guide import MAX_CELLS
from nhstab.planning.trailer import rig_likely_cause, swept_path
from nhstab.robot import robot_from_spec
from nhstab.trailer_suite import rig_geometry

#: the door's thickness [m], and where it stands in the corridor of the suite's turn at 1.2 x S
DOOR_T, DOOR_Y = 0.3, 6.8


def _turn(tmp_path, factor: float, door: float | None = None):
    """The suite's turn at ``factor`` x S, with a door ``door`` m wide across its corridor (centred on the
    goal's line) between the crossing and the goal's trailer; returns (map file, case)."""
    case = T.turn_case(factor)
    extra = []
    if door is not None:
        x0 = min(b.cx + b.length / 2 for b in case.obstacles if b.label == "inner corner block")
        x1 = min(b.cx - b.length / 2 for b in case.obstacles if b.label == "wall along the corridor")
        xm = case.goal[0]
        assert x0 < xm - door / 2 and xm + door / 2 < x1 and case.aisle_m < DOOR_Y < case.goal[1] - 5.0
        extra = [Box((x0 + xm - door / 2) / 2, DOOR_Y, xm - door / 2 - x0, DOOR_T, 0.0, "door, left"),
                 Box((xm + door / 2 + x1) / 2, DOOR_Y, x1 - xm - door / 2, DOOR_T, 0.0, "door, right")]
        extra = [b for b in extra if b.length > 0]
    case = dataclasses.replace(case, name=f"turn{factor:g}_door{door}", obstacles=list(case.obstacles) + extra)
    path = tmp_path / f"{case.name}.yaml"
    path.write_text(T.case_yaml(case))
    return path, case


def _cause(path, margin: float, pad: float = 0.005) -> dict:
    m = load_map(path)
    robot = robot_from_spec(m.robot, source="map")
    world = CollisionWorld.from_map(m, "known")

    def state(pose):
        c = robot.configuration(pose, "pose")
        return np.array([c[0], c[1], c[2], 0.0, c[3]])

    field = world.clearance_field()      # passage's cell: the field's, pooled to at most MAX_CELLS
    cell = field.r * math.ceil(math.sqrt(field.lower_bound.size / MAX_CELLS))
    return rig_likely_cause(world, robot, state(m.start.as_array()), state(m.goal.as_array()), margin,
                            robot.turning_radius, 2.0, pad), cell


def test_the_rigs_swept_path_is_the_suites_estimate_and_a_discs_annulus():
    """At the tightest turn and wider ones, the swept path of the rig equals the trailer suite's estimate
    (RigGeometry, itself checked against the model's steady turn measured with shapely); with disc bodies
    it is the closed form: R0 + r0 - max(R1 - r1, 0) for car disc r0 and trailer disc r1."""
    spec = T.rig_spec()
    robot, g = robot_from_spec(spec), rig_geometry(spec)
    r_min = g.steady_turn()[1]
    assert robot.model.min_turning_radius == pytest.approx(r_min, rel=1e-12)
    for r1 in (r_min, 2 * r_min, 5 * r_min):
        sweep, r_in, r_out = swept_path(robot, r1)
        assert (r_in, r_out) == pytest.approx(g.swept_radii(r1), rel=1e-12) and sweep == pytest.approx(r_out - r_in)
    discs = robot_from_spec({**{k: v for k, v in spec.items() if k not in ("footprint", "trailer_footprint")},
                             "footprint": {"radius": 1.0}, "trailer_footprint": {"radius": 0.7}})
    d = spec["hitch_lengths"][0]
    for r1 in (0.5, 3.0):
        r0 = math.hypot(r1, d)
        assert swept_path(discs, r1)[0] == pytest.approx(max(r0 + 1.0, r1 + 0.7) - min(max(r0 - 1.0, 0.0),
                                                                                          max(r1 - 0.7, 0.0)))


def test_a_turn_without_room_for_the_swept_path_names_it_a_wider_one_the_radius_or_budget(tmp_path):
    """The suite's turn at 0.75 x S: the roomiest place between start and goal is the crossing of aisle and
    corridor, where the largest free disc has the diameter 2 sqrt(2) / (1 + sqrt(2)) w (w the width: the
    disc touches both outer walls and the inner corner), 0.88 S, less than the rig's tightest turn sweeps;
    at 1.2 x S it is 1.41 S, room for it, so the likely cause is the turning radius or the budget. The
    measured diameter is the closed form's to a few cells of the passage's grid."""
    for factor, cause in ((0.75, "swept_path"), (1.2, "turning_radius_or_budget")):
        path, case = _turn(tmp_path, factor)
        why, cell = _cause(path, 0.05)
        assert why["cause"] == cause, why["text"]
        assert why["swept_path_m"] == pytest.approx(case.swept_m, rel=1e-12)
        corner = 2 * math.sqrt(2) / (1 + math.sqrt(2)) * case.aisle_m
        assert why["roomiest_width_m"] == pytest.approx(corner, abs=3 * cell)
        assert f"{case.swept_m:.2f} m" in why["text"] and f"{why['roomiest_width_m']:.2f} m across" in why["text"]


@pytest.mark.parametrize("door, margin, cause", [(1.6, 0.05, "footprint"), (2.0, 0.3, "margin"),
                                                 (0.0, 0.05, "blocked")])
def test_no_plan_through_a_door_says_the_rigs_body_or_margin(tmp_path, door, margin, cause):
    """nhstab plan on the turn at 1.2 x S with a door in its corridor: no way for the rig's 1.8 m bodies
    (a 1.6 m door: the footprint; a closed one: the obstacles) or only with a smaller margin (a 2 m door
    keeps each body 0.1 m off its sides: --margin below 0.1 m less the lattice's pad); exit code 3, the
    likely cause on the last line. The way's width is the door's, to a cell."""
    path, case = _turn(tmp_path, 1.2, door)
    res = invoke("plan", path, "--margin", margin, "--time-limit", "1", "--no-figure", "--out", tmp_path / "p")
    assert res.exit_code == 3, res.output
    last = res.stderr.strip().splitlines()[-1]
    assert last.startswith({"footprint": "likely cause: the footprint", "margin": "likely cause: the margin",
                            "blocked": "likely cause: the known obstacles"}[cause]), last
    why, cell = _cause(path, margin)
    assert why["cause"] == cause and why["text"] == last
    if cause != "blocked":
        assert why["way_width_m"] == pytest.approx(door, abs=cell) and abs(why["narrowest_at"][1] - DOOR_Y) < DOOR_T
    if cause == "margin":
        below = float(re.search(r"--margin below ([0-9.]+) m", last).group(1))
        assert below == pytest.approx((door - case.width_m) / 2 - 0.005, abs=cell)


def test_run_without_a_first_plan_for_the_rig_says_why(tmp_path):
    """nhstab run with the rig and a closed door: no first plan (exit code 3), the likely cause printed
    once and kept in run.json with the failed attempt."""
    import json

    path, _ = _turn(tmp_path, 1.2, 0.0)
    res = invoke("run", path, "--time-limit", "0.2", "--out", tmp_path / "r")
    assert res.exit_code == 3, res.output
    causes = [ln for ln in res.stdout.splitlines() if ln.startswith("likely cause")]
    assert len(causes) == 1 and causes[0].startswith("likely cause: the known obstacles: no way from start to goal")
    run = json.loads((tmp_path / "r" / "run.json").read_text())
    assert run["plans"][0]["attempts"][-1]["likely_cause"]["cause"] == "blocked"


def test_a_closed_dock_bay_is_named_enclosed():
    """The suite's 1.1 W bay off the 1.2 S aisle, whose goal `nhstab trailer reach` finds closed at the maps'
    margin: plan() at that margin finds no path, the lattice's stop-and-steer rung at the goal expands every
    configuration it reaches (`lattice_enclosed`), and the likely cause names the goal as enclosed, with the
    margin the search kept; the same bay's roomier neighbour off the 2 S aisle plans (the cause is the space)."""
    from nhstab.planning import PathOptions, plan

    m = load_map("example:trailer_dock_bay110_aisle120")
    robot = robot_from_spec(m.robot, source="map")
    res = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(time_limit_s=4.0, seed=0))
    assert res.status == "no_path"
    enclosed = res.metrics["lattice_enclosed"]
    assert enclosed["end"] == "goal" and enclosed["expansions"] > 0
    assert enclosed["margin_m"] == pytest.approx(robot.margin + 0.005)
    cause = res.metrics["likely_cause"]
    assert cause["cause"] == "enclosed" and cause["enclosed_end"] == "goal"
    assert re.match(r"likely cause: the goal is enclosed: .* \(\d+ expansions, keeping 0\.055 m\) without a way to "
                    r"the start", cause["text"])
    m2 = load_map("example:trailer_dock_bay110_aisle200")
    ok = plan(m2, robot_from_spec(m2.robot, source="map"), m2.start.as_array(), m2.goal.as_array(),
              PathOptions(time_limit_s=10.0, seed=0))
    assert ok.status == "ok", ok.message
