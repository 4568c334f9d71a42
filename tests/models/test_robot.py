"""The robot description (nhstab.robot): one value for model, parameters, footprint, margin and
stabilizer defaults, written by users in YAML and honoured by every stage."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from nhstab.cli.main import cli
from nhstab.collision import CollisionWorld
from nhstab.errors import InputError, PipelineError
from nhstab.execution import RunOptions, execute, read_run_csv
from nhstab.maps import load_map
from nhstab.planning import PathOptions, plan
from nhstab.robot import (
    MODEL_DEFAULTS,
    RobotStabilizer,
    default_footprint,
    default_robot,
    load_robot,
    make_robot,
    robot_from_spec,
)

#: the user's car of the issue's example (a longer, wider car than the default rwd_car)
USER_CAR = {
    "model": "rwd_car", "wheelbase": 2.7, "max_steer": 0.7, "max_steer_rate": 0.6, "max_speed": 2.0,
    "footprint": {"polygon": [[-0.9, -0.95], [3.6, -0.95], [3.6, 0.95], [-0.9, 0.95]]},
    "margin": 0.1,
}

OPEN_MAP = """
name: open-yard
bounds: [0.0, 0.0, 40.0, 24.0]
obstacles:
  - box: {center: [20.0, 12.0], size: [4.0, 8.0]}
  - box: {center: [8.0, 20.0], size: [3.0, 3.0]}
start: [4.0, 5.0, 0.0]
goal: [34.0, 18.0, 0.0]
"""


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def _one_line(res, code=2, *needles):
    assert res.exit_code == code, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


# ---- the description ----------------------------------------------------------------------------

def test_the_issues_yaml_form_parses_and_round_trips():
    r = robot_from_spec(USER_CAR)
    assert r.model.wheelbase == 2.7 and r.model.max_steer == 0.7 and r.model.max_speed == 2.0
    assert r.margin == 0.1 and r.footprint.vertices.shape == (4, 2)
    assert r.min_turning_radius == pytest.approx(2.7 / math.tan(0.7), rel=1e-12)
    assert r.turning_radius == pytest.approx(1.25 * r.min_turning_radius, rel=1e-12)     # the default rule
    assert r.pose_columns == [0, 1, 2] and r.steering_column == 3
    again = robot_from_spec(r.spec())
    assert again.spec() == r.spec()
    assert np.allclose(again.footprint.vertices, r.footprint.vertices)


def test_builtin_robots_keep_the_old_defaults():
    """The values of the tables the description replaces (planning.DEFAULT_STABILIZER,
    execution.DEFAULT_MARGIN, geometry.DEFAULT_FOOTPRINTS, the turning-radius rule)."""
    u, c, f = default_robot("unicycle"), default_robot("rwd_car"), default_robot("fwd_car")
    assert (u.margin, c.margin, f.margin) == (0.1, 0.3, 0.2)
    assert u.stabilizer.as_dict() == {"alpha": 0.2, "delta": 2.0, "gamma": 1.0, "end_strategy": "frozen"}
    # the cars' schedules keep sliding along a final straight run's continuation (docs/theory/control-law.md, Ends of a trajectory), and
    # are split at cusps (docs/theory/control-law.md, Cusps: no window looks across a cusp)
    assert c.stabilizer.as_dict() == {"alpha": 0.1, "delta": 6.0, "gamma": 1.0, "end_strategy": "extend", "cusps": "split"}
    assert f.stabilizer.as_dict() == {"alpha": 0.2, "delta": 3.0, "gamma": 1.0, "end_strategy": "extend", "cusps": "split"}
    assert u.stabilizer == RobotStabilizer(alpha=0.2, delta=2.0, gamma=1.0, end_strategy="frozen")    # a typed value
    assert u.stabilizer.cusps is None and c.stabilizer.cusps == "split"
    typed = make_robot("rwd_car", stabilizer=RobotStabilizer(alpha=0.3, delta=4.0))     # the rest the rwd_car's
    assert typed.stabilizer == RobotStabilizer(alpha=0.3, delta=4.0, gamma=1.0, end_strategy="extend", cusps="split")
    assert u.turning_radius == 0.5 and c.turning_radius == pytest.approx(1.25 * 2.5 / math.tan(0.6))
    assert u.footprint.radius == 0.3
    assert np.allclose(c.footprint.vertices, [[-0.9, -0.9], [3.3, -0.9], [3.3, 0.9], [-0.9, 0.9]])
    assert set(MODEL_DEFAULTS) == {"unicycle", "rwd_car", "fwd_car", "heisenberg", "car_trailer"}


def test_repeated_polygon_vertices_are_cleaned_and_noted():
    spec = dict(USER_CAR, footprint={"polygon": [[-0.9, -0.95], [3.6, -0.95], [3.6, -0.95], [3.6, 0.95],
                                                 [-0.9, 0.95], [-0.9, -0.95]]})
    r = robot_from_spec(spec)
    assert len(r.footprint.vertices) == 4
    assert r.notes and "repeated" in r.notes[0]


@pytest.mark.parametrize("patch,key", [
    ({"wheelbase": -1.0}, "robot.wheelbase"),
    ({"wheelbase": float("nan")}, "robot.wheelbase"),
    ({"max_steer": 1.6}, "robot.max_steer"),
    ({"max_speed": "1e9"}, "robot.max_speed"),
    ({"wings": 2}, "robot.wings"),
    ({"max_turn_rate": 1.0}, "robot.max_turn_rate"),            # a unicycle parameter on a car
    ({"margin": -0.1}, "robot.margin"),
    ({"turning_radius": 1.0}, "robot.turning_radius"),          # below R_min = 2.7 / tan(0.7)
    ({"stabilizer": {"gamma": 0.3}}, "robot.stabilizer.gamma"),
    ({"stabilizer": {"beta": 1.0}}, "robot.stabilizer.beta"),
    ({"stabilizer": {"end_strategy": "sideways"}}, "robot.stabilizer.end_strategy"),
    ({"stabilizer": {"end_strategy": 1.0}}, "robot.stabilizer.end_strategy"),
    ({"footprint": {"polygon": [[0, 0], [1, 1], [1, 0], [0, 1]]}}, "robot.footprint.polygon"),   # a bow tie
    ({"footprint": {"polygon": [[0, 0], [1, 0], [1, 0]]}}, "robot.footprint.polygon"),
    ({"footprint": {"rectangle": {"length": 4.0}}}, "robot.footprint.rectangle.width"),
    ({"footprint": {"rectangle": {"length": 4.0, "width": 2.0, "rear_overhang": 5.0}}},
     "robot.footprint.rectangle.rear_overhang"),
    ({"footprint": {"radius": 0.5, "polygon": [[0, 0], [1, 0], [0, 1]]}}, "robot.footprint"),
    ({"model": "hovercraft"}, "robot.model"),
])
def test_bad_descriptions_name_the_key(patch, key):
    with pytest.raises(InputError) as exc:
        robot_from_spec({**USER_CAR, **patch})
    assert exc.value.argument == key


def test_the_1e9_string_gets_a_hint():
    with pytest.raises(InputError, match=r"write 1\.0e\+9"):
        robot_from_spec({**USER_CAR, "max_speed": "1e9"})


@pytest.mark.parametrize("text", ["1e9", "5E-3", "1.0e300", "-2e+4", "+.5e7", "3.e2"])
def test_the_hints_advice_is_a_number_to_yaml(text):
    """The text YAML 1.1 leaves a string, and the spelling the hint advises, which it reads as the
    same number (it needs a dot in the mantissa and a sign in the exponent)."""
    import yaml
    from nhstab.errors import number_hint

    assert isinstance(yaml.safe_load(f"x: {text}")["x"], str)
    fixed = number_hint(text).rpartition("write ")[2]
    assert yaml.safe_load(f"x: {fixed}")["x"] == float(text)


@settings(max_examples=150, deadline=None)
@given(st.recursive(st.none() | st.booleans() | st.floats(allow_nan=True) | st.integers() | st.text(max_size=6),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
                        st.sampled_from(["model", "footprint", "polygon", "radius", "rectangle", "length", "width",
                                         "margin", "wheelbase", "max_steer", "stabilizer", "alpha", "x"]),
                        inner, max_size=5), max_leaves=20))
def test_fuzzed_descriptions_raise_only_input_errors(spec):
    try:
        robot_from_spec(spec)
    except InputError:
        pass


# ---- the command line ---------------------------------------------------------------------------

BAD_FILES = {
    "unknown_key.yaml": ("robot: {model: rwd_car, wheelbase: 2.7, colour: red}\n", "robot.colour"),
    "nan.yaml": ("model: rwd_car\nwheelbase: .nan\n", "robot.wheelbase"),
    "polygon.yaml": ("model: rwd_car\nfootprint: {polygon: [[0, 0], [1, 0]]}\n", "robot.footprint.polygon"),
    "not_mapping.yaml": ("- rwd_car\n", "--robot-config"),
    "no_model.yaml": ("wheelbase: 2.7\n", "robot.model"),
    "syntax.yaml": ("model: [rwd_car\n", "--robot-config"),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
@pytest.mark.parametrize("command,extra", [(["plan"], ["--out", "OUT"]), (["map", "info"], []),
                                           (["map", "show"], ["--out", "OUT.png"]), (["run"], ["--out", "OUT"])])
def test_bad_robot_files_are_one_line_exit_2(tmp_path, name, command, extra):
    text, key = BAD_FILES[name]
    robot_file = _write(tmp_path, name, text)
    m = _write(tmp_path, "yard.yaml", OPEN_MAP)
    extra = [str(tmp_path / a) if a.startswith("OUT") else a for a in extra]
    res = CliRunner().invoke(cli, [*command, str(m), "--robot-config", str(robot_file), *extra])
    _one_line(res, 2, key)
    assert not (tmp_path / "OUT").exists() and not (tmp_path / "OUT.png").exists()


def test_map_robot_block_is_checked_strictly(tmp_path):
    m = _write(tmp_path, "yard.yaml", OPEN_MAP + "robot: {model: rwd_car, wheelbase: -2}\n")
    res = CliRunner().invoke(cli, ["map", "info", str(m)])
    _one_line(res, 2, "robot.wheelbase", "yard.yaml")


# ---- honoured end to end ------------------------------------------------------------------------

@pytest.mark.slow
def test_plan_uses_the_described_car(tmp_path):
    """`nhstab plan --robot-config`: plan.json records the car as given; the nominal steers within its
    limit and turns no tighter than its radius rule allows; the path is clear of the obstacles by its
    margin for *its* footprint, recomputed with FCL (and shapely) from trajectory.csv."""
    from shapely.affinity import rotate, translate
    from shapely.geometry import Polygon as SPoly
    from shapely.geometry import box

    robot_file = _write(tmp_path, "car.yaml", yaml.safe_dump({"robot": USER_CAR}))
    m_path = _write(tmp_path, "yard.yaml", OPEN_MAP)
    out = tmp_path / "plan"
    res = CliRunner().invoke(cli, ["plan", str(m_path), "--robot-config", str(robot_file), "--seed", "1",
                                   "--time-limit", "5", "--out", str(out)])
    assert res.exit_code == 0, res.output
    record = json.loads((out / "plan.json").read_text())
    used = record["inputs"]["robot"]
    assert used["wheelbase"] == 2.7 and used["max_steer"] == 0.7 and used["margin"] == 0.1
    assert used["footprint"]["polygon"] == USER_CAR["footprint"]["polygon"]
    assert record["inputs"]["path_options"]["margin"] == 0.1
    assert record["inputs"]["path_options"]["turning_radius"] == pytest.approx(1.25 * 2.7 / math.tan(0.7))
    data = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    x, y, th, phi = data[:, 1], data[:, 2], data[:, 3], data[:, 4]
    assert np.max(np.abs(phi)) <= 0.7 + 1e-9
    m = load_map(m_path)
    rob = load_robot(robot_file)
    world = CollisionWorld.from_map(m)
    poses = np.column_stack([x, y, th])
    c_min, _ = world.min_clearance(poses, rob.footprint)
    assert c_min >= 0.1 - 1e-6
    body = SPoly(USER_CAR["footprint"]["polygon"])
    obstacles = [box(18, 8, 22, 16), box(6.5, 18.5, 9.5, 21.5)]
    for k in range(0, len(poses), 10):
        placed = translate(rotate(body, poses[k, 2], origin=(0, 0), use_radians=True), poses[k, 0], poses[k, 1])
        assert min(placed.distance(o) for o in obstacles) >= 0.1 - 1e-6


@pytest.mark.slow
def test_execute_uses_the_described_car_in_the_plant(tmp_path):
    """The plant integrates the described car: theta' = tan(phi) v / L with L = 2.7 m (not 2.5),
    checked from trajectory.csv by finite differences; the run options' robot is what execute() uses
    when no robot is passed."""
    m = load_map(_write(tmp_path, "yard.yaml", OPEN_MAP))
    opts = RunOptions(robot=USER_CAR, seed=3, noise=RunOptions().noise.__class__(scale=0.0))
    result = execute(m, opts=opts)
    assert result.robot.model.wheelbase == 2.7 and result.robot.footprint.vertices.shape == (4, 2)
    assert result.status == "reached", result.message
    from nhstab.execution import write_run

    write_run(result, tmp_path / "run", figures=False)
    lg = read_run_csv(tmp_path / "run" / "trajectory.csv")
    run_json = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run_json["inputs"]["robot"]["wheelbase"] == 2.7
    assert run_json["inputs"]["options"]["robot"]["model"] == "rwd_car"
    t, th, phi, v = lg["t"], lg["theta"], lg["phi"], lg["v"]
    follow = lg["mode"] == "track"
    k = np.flatnonzero(follow[:-1] & follow[1:] & (np.abs(v[:-1]) > 0.5))
    dth = (th[k + 1] - th[k]) / (t[k + 1] - t[k])
    # over one 20 ms hold the input is constant and phi moves little: the midpoint rule is good to ~1e-3
    pred_27 = np.tan(0.5 * (phi[k] + phi[k + 1])) * v[k] / 2.7
    pred_25 = np.tan(0.5 * (phi[k] + phi[k + 1])) * v[k] / 2.5
    turning = np.abs(pred_27) > 0.05
    assert turning.sum() > 20
    assert np.median(np.abs(dth[turning] - pred_27[turning])) < 2e-3
    assert np.median(np.abs(dth[turning] - pred_25[turning])) > 5 * np.median(np.abs(dth[turning] - pred_27[turning]))


@pytest.mark.slow
def test_map_robot_block_is_used_by_plan(tmp_path):
    spec = yaml.safe_dump({"robot": USER_CAR}, default_flow_style=False)
    m_path = _write(tmp_path, "yard.yaml", OPEN_MAP + spec)
    out = tmp_path / "plan"
    res = CliRunner().invoke(cli, ["plan", str(m_path), "--seed", "1", "--time-limit", "5", "--out", str(out)])
    assert res.exit_code == 0, res.output
    used = json.loads((out / "plan.json").read_text())["inputs"]["robot"]
    assert used["wheelbase"] == 2.7 and used["source"] == "map"
    # --robot NAME takes the model's built-in robot instead
    res = CliRunner().invoke(cli, ["plan", str(m_path), "--robot", "rwd_car", "--seed", "1", "--time-limit", "5",
                                   "--out", str(tmp_path / "p2")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "p2" / "plan.json").read_text())["inputs"]["robot"]["wheelbase"] == 2.5


def test_map_polygons_with_repeated_vertices_are_cleaned_and_noted(tmp_path):
    text = OPEN_MAP.replace("obstacles:\n", "obstacles:\n  - polygon: [[30, 2], [32, 2], [32, 2], [32, 4], [30, 4], "
                                            "[30, 4], [30, 2]]\n", 1)
    m_path = _write(tmp_path, "yard.yaml", text)
    m = load_map(m_path)
    assert any("repeated" in n for n in m.meta["notes"])
    res = CliRunner().invoke(cli, ["map", "info", str(m_path)])
    assert res.exit_code == 0 and "note" in res.output and "repeated" in res.output


@pytest.mark.parametrize("bad", [(1.0, 2.0), "1,2,3", None, (1.0, float("nan"), 0.0), np.zeros((2, 3))])
def test_library_poses_of_the_wrong_shape_name_the_argument(tmp_path, bad):
    m = load_map(_write(tmp_path, "yard.yaml", OPEN_MAP))
    with pytest.raises(InputError) as exc:
        plan(m, default_robot("unicycle"), bad, m.goal.as_array(), PathOptions(time_limit_s=0.5))
    assert exc.value.argument == "start"
    if bad is None:            # execute: None means the map's goal
        return
    with pytest.raises(InputError) as exc:
        execute(m, default_robot("unicycle"), m.start.as_array(), bad)
    assert exc.value.argument == "goal"


def test_make_robot_and_footprints():
    r = make_robot("unicycle", max_speed=0.5, footprint={"radius": 0.4}, margin=0.05)
    assert r.model.max_speed == 0.5 and r.footprint.radius == 0.4 and r.margin == 0.05
    assert default_footprint("rwd_car").label.startswith("rectangle 4.2 x 1.8")
    with pytest.raises(PipelineError):
        default_footprint("hovercraft")


def test_the_adding_a_model_guide_example_runs(tmp_path):
    """docs/guide/robots.md's worked example: a model defined in one class and one registry entry is
    taken by make_robot (with its robot_defaults), gets its own default noise (noise_defaults) and is
    stabilized along its own nominal."""
    import re
    import subprocess
    import sys
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "guide" / "robots.md").read_text()
    code = re.search(r"## Adding a model.*?```python\n(.*?)```", text, re.S).group(1)
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    name_line, noise_line, gain_line = res.stdout.strip().splitlines()
    assert name_line == "chained disc r=0.2 m 0.1 0.0"
    assert noise_line == "sensor noise [0.01, 0.01, 0.01]"          # the model's own noise_defaults
    assert gain_line.startswith("max gain norm ") and 0.0 < float(gain_line.split()[-1]) < 1e3


def test_per_model_knowledge_is_read_from_the_model_classes():
    """The built-in robots, the models the planner plans for and the search's pads are each model
    class's own (robot_defaults, plannable, search_pad), in the registry's order."""
    from nhstab.models import MODELS
    from nhstab.planning import MARGIN_PAD, PLANNABLE

    assert MODEL_DEFAULTS == {name: cls.robot_defaults for name, cls in MODELS.items()}
    assert PLANNABLE == ("unicycle", "rwd_car", "fwd_car", "car_trailer")
    assert MARGIN_PAD == {"unicycle": 0.02, "rwd_car": 0.05, "fwd_car": 0.05}
    for name in MODELS:
        robot = default_robot(name)
        assert robot.margin == MODELS[name].robot_defaults["margin"]


def test_noise_grid_and_van_are_read_from_the_model_classes():
    """The default noise (execution.config.DEFAULT_NOISE), the sweep's grid and the parking suite's van
    are the model classes' own (noise_defaults, sweep_grid, robot_presets); the models agree on the
    noise of the states they share."""
    from nhstab.execution.config import DEFAULT_NOISE, default_noise
    from nhstab.models import MODELS
    from nhstab.parking import SUITE_MARGIN, cars
    from nhstab.planning.sweep import GRID

    for kind in ("initial", "sensor", "process"):
        for cls in MODELS.values():
            for state, level in cls.noise_defaults[kind].items():
                assert DEFAULT_NOISE[kind][state] == level, (cls.__name__, kind, state)
    assert DEFAULT_NOISE == default_noise()
    assert DEFAULT_NOISE["sensor"]["phi"] == 0.005 and DEFAULT_NOISE["initial"]["theta8"] == 0.05
    assert GRID == {name: cls.sweep_grid for name, cls in MODELS.items() if cls.sweep_grid is not None}
    assert list(GRID) == ["unicycle", "rwd_car", "fwd_car"]
    van = cars()["van"]
    assert van == {"model": "rwd_car", "name": "van", **MODELS["rwd_car"].robot_presets["van"], "margin": SUITE_MARGIN}
    assert robot_from_spec(van).min_turning_radius == pytest.approx(3.65 / math.tan(0.65), rel=1e-15)


@pytest.mark.parametrize("name", ["unicycle", "rwd_car", "fwd_car", "heisenberg", "car_trailer"])
def test_the_minimum_turning_radius_has_one_owner(name):
    """Robot, planner and parking geometry all read the model's min_turning_radius: L / tan(max_steer)
    for the cars, 0 for models that turn in place, the trailer's own closed form for car_trailer."""
    from nhstab.planning import min_turning_radius

    r = default_robot(name)
    assert r.min_turning_radius == r.model.min_turning_radius == min_turning_radius(r.model)
    if name in ("rwd_car", "fwd_car"):
        assert r.min_turning_radius == r.model.wheelbase / math.tan(r.model.max_steer)
    elif name in ("unicycle", "heisenberg"):
        assert r.min_turning_radius == 0.0
    else:
        r0, d = r.model.wheelbase / math.tan(r.model.max_steer), r.model.hitch_lengths[0]   # one trailer:
        assert r.min_turning_radius == pytest.approx(math.sqrt(r0 * r0 - d * d), rel=1e-12)    # R1^2 = R0^2 - d^2
