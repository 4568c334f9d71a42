"""The robot of a Nav2 parameters file (nhstab.nav2): footprints, padding, Smac kinematics, speeds.

The fixtures are tests/data/nav2/*.yaml (nav2_bringup's layout); every other case is derived from
them here. Footprint areas are checked against shapely, turning radii against the Smac planner's
minimum_turning_radius to 1e-9 m.
"""
import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
import shapely
import yaml
from nhstab.errors import InputError
from nhstab.nav2 import is_nav2_params, parse_footprint_string, read_nav2_robot
from nhstab.robot import load_robot, robot_from_spec

DATA = Path(__file__).resolve().parents[1] / "data" / "nav2"
DIFF = DATA / "nav2_params.yaml"
CAR = DATA / "nav2_params_ackermann.yaml"
LOCAL = "local_costmap.local_costmap.ros__parameters"
GLOBAL = "global_costmap.global_costmap.ros__parameters"
PLANNER = "planner_server.ros__parameters.GridBased"


def _load(path):
    return yaml.safe_load(path.read_text())


def _write(tmp_path, doc, name="params.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


def _costmaps(doc):
    return [doc[c][c]["ros__parameters"] for c in ("local_costmap", "global_costmap")]


def _with_footprint(tmp_path, footprint, padding=0.0):
    doc = _load(CAR)
    for cm in _costmaps(doc):
        cm["footprint"] = footprint
        cm["footprint_padding"] = padding
    return _write(tmp_path, doc)


# ---- footprint strings --------------------------------------------------------------------------
@pytest.mark.parametrize("text", [
    "[[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3], [-0.5, 0.3]]",
    "[ [0.5,0.3],[0.5,-0.3] , [-0.5,-0.3],[-0.5,0.3] ]",
    "[[0.5 0.3] [0.5 -0.3] [-0.5 -0.3] [-0.5 0.3]]",          # blanks separate values, as in Nav2's parseVVF
    "[[5e-1, 3.0E-1],\n [.5, -.3], [-0.5, -0.3], [-5.0e-1, +0.3]]",
])
def test_footprint_strings_in_nav2s_spellings_give_the_same_points(text):
    assert parse_footprint_string(text, "k") == [[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3], [-0.5, 0.3]]


@pytest.mark.parametrize("text", ["", "[]", "  [] "])
def test_an_empty_footprint_string_means_no_footprint(text):
    assert parse_footprint_string(text, "k") == []


@pytest.mark.parametrize("text, detail", [
    ("[[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3]", "not closed"),
    ("[[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3]]]", "after the closing bracket"),
    ("][[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3]]", "no '['"),
    ("[ ]", "0 point(s)"),
    ("[[0.5, 0.3, 0.1], [0.5, -0.3], [-0.5, -0.3]]", "3 number(s)"),
    ("[[0.5], [0.5, -0.3], [-0.5, -0.3]]", "1 number(s)"),
    ("[[nan, 0.3], [0.5, -0.3], [-0.5, -0.3]]", "not a number"),
    ("[[inf, 0.3], [0.5, -0.3], [-0.5, -0.3]]", "not a number"),
    ("[[1e400, 0.3], [0.5, -0.3], [-0.5, -0.3]]", "not a finite number"),
    ("[0.5, 0.3, 0.5, -0.3]", "outside a [x, y] point"),
    ("[[[0.5, 0.3]]]", "third level"),
    ("[[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3]] [[1, 1]]", "after the closing bracket"),
    ("[[0.5, 0.3], [0.5, -0.3]]", "2 point(s)"),
    ("[[0.5x, 0.3], [0.5, -0.3], [-0.5, -0.3]]", "after a number"),
    ("__import__('os').getcwd()", "not a number"),
    ("[[0.5, 0.3], [0.5; -0.3], [-0.5, -0.3]]", "after a number"),
])
def test_malformed_footprint_strings_are_refused_naming_the_key(text, detail):
    with pytest.raises(InputError) as err:
        parse_footprint_string(text, "f.yaml: a.b.footprint")
    assert err.value.argument == "f.yaml: a.b.footprint"
    assert detail in str(err.value)


@pytest.mark.parametrize("text, detail", [
    ("[[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3], [-0.5, 0.3]] x", "after the closing bracket"),
    ("[[0.5, 0.3], [-0.5, -0.3], [0.5, -0.3], [-0.5, 0.3]]", "intersects itself"),    # a bow tie
    ("[[0, 0], [1, 1], [2, 2]]", "area"),                                            # on a line
    ("[[0.5, .nan], [0.5, -0.3], [-0.5, -0.3]]", "not a number"),
])
def test_a_bad_footprint_in_the_file_names_its_key_path(tmp_path, text, detail):
    with pytest.raises(InputError) as err:
        read_nav2_robot(_with_footprint(tmp_path, text))
    assert err.value.argument == f"params.yaml: {LOCAL}.footprint"
    assert detail in str(err.value)


def test_a_closed_ring_is_the_same_footprint_as_the_open_one(tmp_path):
    open_ = read_nav2_robot(_with_footprint(tmp_path, "[[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3], [-0.5, 0.3]]"))
    closed = read_nav2_robot(_with_footprint(tmp_path, "[[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3], [-0.5, 0.3], "
                                                       "[0.5, 0.3]]"))
    assert np.array_equal(open_.robot.footprint.vertices, closed.robot.footprint.vertices)
    assert len(closed.robot.footprint.vertices) == 4


def test_a_footprint_as_a_yaml_list_is_read_like_the_string(tmp_path):
    pts = [[0.5, 0.3], [0.5, -0.3], [-0.5, -0.3], [-0.5, 0.3]]
    a = read_nav2_robot(_with_footprint(tmp_path, pts)).robot.footprint
    b = read_nav2_robot(_with_footprint(tmp_path, json.dumps(pts))).robot.footprint
    assert np.array_equal(a.vertices, b.vertices)
    with pytest.raises(InputError) as err:
        read_nav2_robot(_with_footprint(tmp_path, [[0.5, 0.3], [0.5, "x"], [-0.5, -0.3]]))
    assert err.value.argument == f"params.yaml: {LOCAL}.footprint[1][1]"


# ---- padding, radius and the two costmaps -------------------------------------------------------
@pytest.mark.parametrize("pad", [0.0, 0.02, 0.1])
def test_padding_grows_a_centred_rectangle_by_the_padding_on_every_side(tmp_path, pad):
    fp = read_nav2_robot(_with_footprint(tmp_path, "[[0.4, 0.25], [0.4, -0.25], [-0.3, -0.25], [-0.3, 0.25]]",
                                         pad)).robot.footprint
    poly = shapely.Polygon(fp.vertices)
    assert poly.area == pytest.approx((0.7 + 2 * pad) * (0.5 + 2 * pad), abs=1e-12)
    assert poly.bounds == pytest.approx((-0.3 - pad, -0.25 - pad, 0.4 + pad, 0.25 + pad), abs=1e-12)


def test_the_fixtures_footprint_is_its_string_padded_by_002(tmp_path):
    fp = read_nav2_robot(CAR).robot.footprint
    assert shapely.Polygon(fp.vertices).bounds == pytest.approx((-0.17, -0.22, 0.57, 0.22), abs=1e-12)


@pytest.mark.parametrize("pad, given", [(0.01, False), (0.0, True), (0.05, True)])
def test_robot_radius_gives_a_disc_of_radius_plus_padding(tmp_path, pad, given):
    doc = _load(DIFF)
    for cm in _costmaps(doc):
        cm.pop("footprint_padding", None)
        if given:
            cm["footprint_padding"] = pad
    fp = read_nav2_robot(_write(tmp_path, doc)).robot.footprint
    assert fp.vertices is None and fp.radius == pytest.approx(0.22 + pad, abs=1e-15)


def test_a_footprint_wins_over_robot_radius_and_an_empty_one_does_not(tmp_path):
    doc = _load(DIFF)
    for cm in _costmaps(doc):
        cm["footprint"] = "[[0.2, 0.2], [0.2, -0.2], [-0.2, -0.2], [-0.2, 0.2]]"
        cm["footprint_padding"] = 0.0
    assert read_nav2_robot(_write(tmp_path, doc)).robot.footprint.vertices is not None
    for cm in _costmaps(doc):
        cm["footprint"] = "[]"
    assert read_nav2_robot(_write(tmp_path, doc)).robot.footprint.radius == 0.22


def test_costmaps_that_describe_different_robots_are_refused(tmp_path):
    doc = _load(DIFF)
    _costmaps(doc)[1]["robot_radius"] = 0.3
    with pytest.raises(InputError) as err:
        read_nav2_robot(_write(tmp_path, doc))
    assert err.value.argument == f"params.yaml: {GLOBAL}.robot_radius"
    assert LOCAL in str(err.value) and "different robots" in str(err.value)
    doc = _load(CAR)
    _costmaps(doc)[1]["footprint_padding"] = 0.03            # same string, other padding
    with pytest.raises(InputError, match="global_costmap"):
        read_nav2_robot(_write(tmp_path, doc))


def test_one_costmap_is_enough_and_none_is_refused(tmp_path):
    doc = _load(DIFF)
    del doc["local_costmap"]
    assert read_nav2_robot(_write(tmp_path, doc)).robot.footprint.radius == pytest.approx(0.23)
    del doc["global_costmap"]
    with pytest.raises(InputError, match="footprint or robot_radius"):
        read_nav2_robot(_write(tmp_path, doc))


@pytest.mark.parametrize("key, value", [("robot_radius", -0.2), ("robot_radius", 0.0), ("robot_radius", ".nan"),
                                        ("robot_radius", "'0.2'"), ("footprint_padding", -0.01),
                                        ("footprint_padding", ".inf"), ("robot_radius", True)])
def test_bad_radius_and_padding_values_name_their_key(tmp_path, key, value):
    doc = _load(DIFF)
    text = yaml.safe_dump(doc, sort_keys=False).replace("robot_radius: 0.22", f"robot_radius: 0.22\n      {key}: "
                                                         f"{value}" if key != "robot_radius" else f"{key}: {value}", 1)
    p = tmp_path / "params.yaml"
    p.write_text(text)
    with pytest.raises(InputError) as err:
        read_nav2_robot(p)
    assert err.value.argument == f"params.yaml: {LOCAL}.{key}"


# ---- kinematics ---------------------------------------------------------------------------------
def _hybrid(tmp_path, **block):
    doc = _load(CAR)
    gb = doc["planner_server"]["ros__parameters"]["GridBased"]
    for k, v in block.items():
        if v is None:
            gb.pop(k, None)
        else:
            gb[k] = v
    return _write(tmp_path, doc)


@pytest.mark.parametrize("radius", [0.4, 0.8, 2.35, 5.0, 12.3])
def test_the_cars_minimum_turning_radius_is_the_smac_planners(tmp_path, radius):
    got = read_nav2_robot(_hybrid(tmp_path, minimum_turning_radius=radius))
    rob = got.robot
    assert rob.model.name == "rwd_car"
    assert abs(rob.min_turning_radius - radius) <= 1e-9
    assert abs(rob.model.wheelbase / math.tan(rob.model.max_steer) - radius) <= 1e-9
    assert rob.model.max_steer == 0.6                     # the model's, kept
    for wheelbase in (0.3, 1.0, 2.7):                     # a given wheelbase sets max_steer instead
        rob = read_nav2_robot(_hybrid(tmp_path, minimum_turning_radius=radius), wheelbase=wheelbase).robot
        assert rob.model.wheelbase == wheelbase and abs(rob.min_turning_radius - radius) <= 1e-9
        assert 0 < rob.model.max_steer < math.pi / 2


@pytest.mark.parametrize("motion, space", [("DUBIN", "dubins"), ("REEDS_SHEPP", "reeds_shepp"), (None, "dubins")])
def test_the_motion_model_gives_the_planning_space(tmp_path, motion, space):
    got = read_nav2_robot(_hybrid(tmp_path, motion_model_for_search=motion))
    assert got.robot.model.name == "rwd_car" and got.space == space
    assert got.robot.space == space and got.robot.spec()["space"] == space      # the robot carries it
    assert robot_from_spec(got.robot.spec()).space == space                     # and its YAML keeps it
    assert any(("Nav2 default" in line) == (motion is None) for line in got.lines if "SmacPlannerHybrid" in line)


def test_nav2s_default_turning_radius_when_none_is_given(tmp_path):
    got = read_nav2_robot(_hybrid(tmp_path, minimum_turning_radius=None))
    assert abs(got.robot.min_turning_radius - 0.4) <= 1e-9


@pytest.mark.parametrize("motion", ["STATE_LATTICE", "dubin", "2D", "OMNI", 3])
def test_motion_models_the_hybrid_planner_does_not_take_are_refused(tmp_path, motion):
    with pytest.raises(InputError) as err:
        read_nav2_robot(_hybrid(tmp_path, motion_model_for_search=motion))
    assert err.value.argument == f"params.yaml: {PLANNER}.motion_model_for_search"


@pytest.mark.parametrize("radius", [-0.5, ".nan", "fast"])
def test_a_bad_turning_radius_names_its_key(tmp_path, radius):
    p = _hybrid(tmp_path)
    p.write_text(p.read_text().replace("minimum_turning_radius: 0.8", f"minimum_turning_radius: {radius}"))
    with pytest.raises(InputError) as err:
        read_nav2_robot(p)
    assert err.value.argument == f"params.yaml: {PLANNER}.minimum_turning_radius"


def test_radius_zero_and_non_smac_planners_give_a_unicycle(tmp_path):
    got = read_nav2_robot(_hybrid(tmp_path, minimum_turning_radius=0.0))
    assert got.robot.model.name == "unicycle" and got.space is None
    for plugin in ("nav2_navfn_planner/NavfnPlanner", "nav2_smac_planner/SmacPlanner2D",
                   "nav2_theta_star_planner/ThetaStarPlanner"):
        got = read_nav2_robot(_hybrid(tmp_path, plugin=plugin))
        assert got.robot.model.name == "unicycle" and got.robot.min_turning_radius == 0.0
    doc = _load(CAR)
    del doc["planner_server"]
    assert read_nav2_robot(_write(tmp_path, doc)).robot.model.name == "unicycle"


def test_the_plugin_class_is_read_with_either_separator(tmp_path):
    got = read_nav2_robot(_hybrid(tmp_path, plugin="nav2_smac_planner::SmacPlannerHybrid"))
    assert got.robot.model.name == "rwd_car"


def test_a_given_model_overrides_the_planners(tmp_path):
    uni = read_nav2_robot(CAR, model="unicycle").robot
    assert uni.model.name == "unicycle" and uni.turning_radius == pytest.approx(0.8)
    fwd = read_nav2_robot(CAR, model="fwd_car").robot
    assert fwd.model.name == "fwd_car" and abs(fwd.min_turning_radius - 0.8) <= 1e-9
    with pytest.raises(InputError, match="minimum turning radius"):
        read_nav2_robot(DIFF, model="rwd_car")               # NavFn: no radius for a car
    with pytest.raises(InputError):
        read_nav2_robot(CAR, model="car_trailer")


def _lattice(tmp_path, motion="ackermann", radius=0.9, reverse=None, write=True):
    if write:
        (tmp_path / "prims.json").write_text(json.dumps(
            {"version": 1.0, "lattice_metadata": {"motion_model": motion, "turning_radius": radius,
                                                  "grid_resolution": 0.05, "num_of_headings": 16},
             "primitives": []}))
    block = {"plugin": "nav2_smac_planner/SmacPlannerLattice", "lattice_filepath": "prims.json",
             "motion_model_for_search": None, "minimum_turning_radius": None}
    if reverse is not None:
        block["allow_reverse_expansion"] = reverse
    return _hybrid(tmp_path, **block)


def test_a_state_lattice_is_read_from_its_lattice_file(tmp_path):
    got = read_nav2_robot(_lattice(tmp_path, radius=0.9))
    assert got.robot.model.name == "rwd_car" and got.space == "dubins"
    assert abs(got.robot.min_turning_radius - 0.9) <= 1e-9
    assert read_nav2_robot(_lattice(tmp_path, reverse=True)).space == "reeds_shepp"
    assert read_nav2_robot(_lattice(tmp_path, motion="diff")).robot.model.name == "unicycle"
    with pytest.raises(InputError) as err:
        read_nav2_robot(_lattice(tmp_path, motion="holonomic"))
    assert err.value.argument == f"params.yaml: {PLANNER}.lattice_filepath: lattice_metadata.motion_model"
    (tmp_path / "prims.json").write_text('{"lattice_metadata": {"motion_model": "ackermann"}}')
    with pytest.raises(InputError) as err:
        read_nav2_robot(_lattice(tmp_path, write=False))
    assert err.value.argument == f"params.yaml: {PLANNER}.lattice_filepath"
    (tmp_path / "prims.json").unlink()
    with pytest.raises(InputError) as err:
        read_nav2_robot(_lattice(tmp_path, write=False))
    assert err.value.argument == f"params.yaml: {PLANNER}.lattice_filepath"


def test_two_planners_that_disagree_are_refused(tmp_path):
    doc = _load(CAR)
    ps = doc["planner_server"]["ros__parameters"]
    ps["planner_plugins"] = ["GridBased", "Tight"]
    ps["Tight"] = {**copy.deepcopy(ps["GridBased"]), "minimum_turning_radius": 0.5}
    with pytest.raises(InputError) as err:
        read_nav2_robot(_write(tmp_path, doc))
    assert err.value.argument == "params.yaml: planner_server.ros__parameters.Tight.minimum_turning_radius"


# ---- speeds -------------------------------------------------------------------------------------
def test_the_speed_limits_are_the_smallest_given():
    diff = read_nav2_robot(DIFF).robot
    assert diff.model.max_speed == 0.26 and diff.model.max_turn_rate == 1.0
    car = read_nav2_robot(CAR).robot
    assert car.model.max_speed == 0.5                     # RPP's 0.5 under the smoother's 0.6


def test_mppi_limits_are_read(tmp_path):
    doc = _load(DIFF)
    doc["controller_server"]["ros__parameters"]["FollowPath"] = {
        "plugin": "nav2_mppi_controller::MPPIController", "vx_max": 0.2, "wz_max": 0.7}
    rob = read_nav2_robot(_write(tmp_path, doc)).robot
    assert rob.model.max_speed == 0.2 and rob.model.max_turn_rate == 0.7


@pytest.mark.parametrize("where, value", [("dwb", -0.26), ("dwb", ".nan"), ("smoother", "[0.26, 0.0]"),
                                          ("smoother", "[0.0, 0.0, 1.0]")])
def test_bad_speed_limits_name_their_key(tmp_path, where, value):
    text = DIFF.read_text()
    if where == "dwb":
        text = text.replace("max_vel_x: 0.26", f"max_vel_x: {value}")
        key = "controller_server.ros__parameters.FollowPath.max_vel_x"
    else:
        text = text.replace("max_velocity: [0.26, 0.0, 1.0]", f"max_velocity: {value}")
        key = "velocity_smoother.ros__parameters.max_velocity"
    p = tmp_path / "params.yaml"
    p.write_text(text)
    with pytest.raises(InputError) as err:
        read_nav2_robot(p)
    assert err.value.argument.startswith(f"params.yaml: {key}")


# ---- the file -----------------------------------------------------------------------------------
def test_a_robot_file_is_not_a_nav2_file(tmp_path):
    assert is_nav2_params(_load(DIFF)) and is_nav2_params(_load(CAR))
    assert not is_nav2_params({"robot": {"model": "unicycle"}}) and not is_nav2_params({"model": "rwd_car"})
    p = _write(tmp_path, {"robot": {"model": "unicycle"}})
    with pytest.raises(InputError, match="ros__parameters"):
        read_nav2_robot(p)


def test_the_one_level_layout_is_read_too(tmp_path):
    doc = _load(DIFF)
    for c in ("local_costmap", "global_costmap"):
        doc[c] = doc[c][c]
    assert read_nav2_robot(_write(tmp_path, doc)).robot.footprint.radius == pytest.approx(0.23)


def test_the_robots_spec_round_trips_through_an_nhstab_robot_file(tmp_path):
    for f in (DIFF, CAR):
        rob = read_nav2_robot(f).robot
        again = robot_from_spec(rob.spec())
        assert again.spec() == rob.spec()
        p = _write(tmp_path, {"robot": rob.spec()}, "robot.yaml")
        assert load_robot(p).spec() == rob.spec()


def test_a_lattice_file_nhstab_cannot_open_is_not_needed_for_a_given_unicycle(tmp_path):
    p = _lattice(tmp_path, write=False)
    p.write_text(p.read_text().replace("lattice_filepath: prims.json",
                                       "lattice_filepath: $(find-pkg-share nav2_smac_planner)/prims.json"))
    with pytest.raises(InputError):
        read_nav2_robot(p)
    got = read_nav2_robot(p, model="unicycle")
    assert got.robot.model.name == "unicycle" and any("lattice file not read" in line for line in got.lines)


def test_the_reference_page_names_every_key_the_reader_reads():
    from nhstab.nav2 import NAV2_KEYS

    text = (Path(__file__).resolve().parents[2] / "docs" / "reference" / "nav2.md").read_text()
    assert [k for k in NAV2_KEYS if f"`{k}`" not in text] == []


# ---- the robot's planning space at work -----------------------------------------------------------
def _dubin_car(tmp_path):
    return read_nav2_robot(_hybrid(tmp_path, motion_model_for_search="DUBIN")).robot


def test_a_dubin_robot_plans_forward_only_in_its_own_space_unless_the_options_say_otherwise(tmp_path):
    """The Nav2 car with the DUBIN motion model, on the bundled depot (0.05 m cells), to a goal 5 m behind
    its start with the same heading: with no space in the options it plans in its own, dubins: no
    reverse interval in the path, v >= 0 along the nominal, no cusp, and no shorter than OMPL's
    shortest Dubins path between the two poses (5 m + 2 pi R at R = 1 m: turn, drive back, turn). The
    options' reeds_shepp overrides it: the path reverses and is shorter than any forward-only one."""
    import nhstab
    from nhstab.planning import path_length

    rob = _dubin_car(tmp_path)
    assert rob.space == "dubins" and rob.turning_radius == pytest.approx(1.0)      # 1.25 x R = 0.8 m
    m = nhstab.load_map("example:depot")
    start, goal = [10.0, 4.3, 0.0], [5.0, 4.3, 0.0]
    dubins_lower = path_length(nhstab.PathOptions(space="dubins", turning_radius=rob.turning_radius), start, goal)
    assert dubins_lower == pytest.approx(5.0 + 2 * math.pi * rob.turning_radius, abs=1e-9)
    fwd = nhstab.plan(m, rob, start, goal, nhstab.PathOptions(seed=0))
    assert fwd.ok, fwd.message
    assert fwd.path.options.space == "dubins" and set(fwd.path.direction) == {1.0}
    assert fwd.metrics["cusps"] == 0 and fwd.nominal.u[:, 0].min() >= -1e-9
    assert fwd.metrics["length_m"] >= dubins_lower - 1e-6
    both = nhstab.plan(m, rob, start, goal, nhstab.PathOptions(seed=0, space="reeds_shepp"))
    assert both.ok, both.message
    assert both.path.options.space == "reeds_shepp" and -1.0 in set(both.path.direction)
    assert both.nominal.u[:, 0].min() < 0 and both.metrics["length_m"] < dubins_lower


def test_a_robot_space_is_checked_and_the_default_robot_has_none(tmp_path):
    from nhstab.robot import default_robot, make_robot

    assert default_robot("rwd_car").space is None and "space" not in default_robot("rwd_car").spec()
    assert default_robot("rwd_car").planning_space == "reeds_shepp"
    assert make_robot("unicycle", space="dubins").planning_space == "dubins"
    with pytest.raises(InputError) as err:
        robot_from_spec({"model": "rwd_car", "space": "hilbert"})
    assert err.value.argument == "robot.space"
    with pytest.raises(InputError, match="reeds_shepp") as err:
        robot_from_spec({"model": "car_trailer", "space": "dubins"})
    assert err.value.argument == "robot.space"
