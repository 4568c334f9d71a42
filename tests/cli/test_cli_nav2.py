"""``nhstab robot from-nav2`` and ``--robot-config`` with a Nav2 parameters file, from the command line."""
import math
from pathlib import Path

import yaml
from nhstab.nav2 import read_nav2_robot
from nhstab.robot import load_robot

from tests.clitools import invoke, one_line

DATA = Path(__file__).resolve().parents[1] / "data" / "nav2"
DIFF = DATA / "nav2_params.yaml"
CAR = DATA / "nav2_params_ackermann.yaml"


def test_from_nav2_writes_a_robot_file_with_the_planners_turning_radius(tmp_path):
    out = tmp_path / "car.yaml"
    res = invoke("robot", "from-nav2", CAR, "-o", out)
    assert res.exit_code == 0, res.output
    assert "nav2: model rwd_car, forward and reverse" in res.output
    assert "minimum_turning_radius 0.8 m" in res.output and f"wrote {out}" in res.output
    rob = load_robot(out)
    assert rob.model.name == "rwd_car" and abs(rob.min_turning_radius - 0.8) <= 1e-9
    assert rob.spec() == read_nav2_robot(CAR).robot.spec()
    text = out.read_text()
    assert text.startswith("# nhstab robot read from the Nav2 parameters file nav2_params_ackermann.yaml")


def test_from_nav2_prints_the_robot_yaml_and_takes_a_model_and_wheelbase(tmp_path):
    res = invoke("robot", "from-nav2", CAR, "--wheelbase", "0.5", "--margin", "0.1")
    assert res.exit_code == 0, res.output
    spec = yaml.safe_load(res.stdout)["robot"]
    assert spec["wheelbase"] == 0.5 and spec["margin"] == 0.1
    assert abs(0.5 / math.tan(spec["max_steer"]) - 0.8) <= 1e-9
    res = invoke("robot", "from-nav2", CAR, "--model", "unicycle")
    assert yaml.safe_load(res.stdout)["robot"]["model"] == "unicycle"
    assert "# model unicycle (given), where the planner suggests rwd_car" in res.stdout


def _dubin(tmp_path) -> Path:
    p = tmp_path / "dubin.yaml"
    p.write_text(CAR.read_text().replace('motion_model_for_search: "REEDS_SHEPP"', 'motion_model_for_search: "DUBIN"'))
    return p


def test_a_dubins_car_is_written_with_its_space(tmp_path):
    res = invoke("robot", "from-nav2", _dubin(tmp_path))
    assert res.exit_code == 0, res.output
    assert "# forward only: space dubins, which nhstab plan and run use unless --space" in res.stdout
    assert yaml.safe_load(res.stdout)["robot"]["space"] == "dubins"
    out = tmp_path / "car.yaml"
    assert invoke("robot", "from-nav2", _dubin(tmp_path), "-o", out).exit_code == 0
    assert load_robot(out).space == "dubins"
    assert yaml.safe_load(invoke("robot", "from-nav2", CAR).stdout)["robot"]["space"] == "reeds_shepp"


def _speeds(folder: Path):
    """The nominal's speed v [m/s] along a plan's trajectory.csv."""
    import numpy as np

    lines = (folder / "trajectory.csv").read_text().splitlines()
    col = lines[0].split(",").index("v [m/s]")
    return np.array([float(line.split(",")[col]) for line in lines[1:]])


def test_plan_uses_the_robots_space_and_space_overrides_it(tmp_path):
    """nhstab plan with the DUBIN car and no --space plans forward only (plan.json's path options say
    dubins; no cusp, no negative speed in trajectory.csv); --space reeds_shepp plans in that space."""
    import json

    args = ("plan", "example:depot", "--robot-config", f"nav2:{_dubin(tmp_path)}", "--start", "10,4.3,0", "--goal",
            "5,4.3,0", "--tube", "linear", "--no-figure")
    res = invoke(*args, "--out", tmp_path / "d")
    assert res.exit_code == 0, res.output
    plan = json.loads((tmp_path / "d" / "plan.json").read_text())
    assert plan["inputs"]["path_options"]["space"] == "dubins" and plan["metrics"]["cusps"] == 0
    assert plan["inputs"]["robot"]["space"] == "dubins"
    assert _speeds(tmp_path / "d").min() >= -1e-9
    res = invoke(*args, "--space", "reeds_shepp", "--out", tmp_path / "rs")
    assert res.exit_code == 0, res.output
    plan = json.loads((tmp_path / "rs" / "plan.json").read_text())
    assert plan["inputs"]["path_options"]["space"] == "reeds_shepp"
    assert _speeds(tmp_path / "rs").min() < 0


def test_run_uses_the_robots_space_unless_planning_space_is_given(tmp_path):
    args = ("run", "example:depot", "--robot-config", f"nav2:{_dubin(tmp_path)}", "--start", "10,4.3,0", "--goal",
            "5,4.3,0", "--print-config")
    res = invoke(*args)
    assert res.exit_code == 0, res.output
    doc = yaml.safe_load(res.stdout)
    assert doc["planning"]["space"] == "dubins" and doc["robot"]["space"] == "dubins"
    cfg = tmp_path / "run.yaml"
    cfg.write_text("planning: {space: reeds_shepp}\n")
    res = invoke(*args, "--config", cfg)
    assert res.exit_code == 0, res.output
    assert yaml.safe_load(res.stdout)["planning"]["space"] == "reeds_shepp"
    res = invoke("run", "example:depot", "--robot-config", CAR, "--start", "10,4.3,0", "--goal", "5,4.3,0",
                 "--print-config")
    assert yaml.safe_load(res.stdout)["planning"]["space"] == "reeds_shepp"


def test_bad_nav2_files_are_one_line_naming_the_key(tmp_path, monkeypatch):
    p = tmp_path / "bad.yaml"
    p.write_text(CAR.read_text().replace('"[ [0.55, 0.2], [0.55, -0.2], [-0.15, -0.2], [-0.15, 0.2] ]"',
                                         '"[ [0.55, 0.2], [0.55, -0.2], [-0.15, -0.2], [-0.15, 0.2] "'))
    one_line(invoke("robot", "from-nav2", p), 2, "bad.yaml: local_costmap.local_costmap.ros__parameters.footprint",
             "not closed")
    p.write_text(CAR.read_text().replace("minimum_turning_radius: 0.8", "minimum_turning_radius: -1"))
    one_line(invoke("robot", "from-nav2", p), 2, "planner_server.ros__parameters.GridBased.minimum_turning_radius")
    monkeypatch.chdir(tmp_path)          # a short path: a long one is shortened in the message
    one_line(invoke("robot", "from-nav2", "missing.yaml"), 2, "missing.yaml")
    one_line(invoke("robot", "from-nav2", CAR, "--wheelbase", "nan"), 2, "'--wheelbase'")
    one_line(invoke("robot", "from-nav2", CAR, "--margin", "-0.1"), 2, "'--margin'")


def test_robot_config_reads_a_nav2_file_with_or_without_the_prefix(tmp_path):
    for arg in (f"nav2:{DIFF}", str(DIFF)):
        res = invoke("map", "info", "example:tb3_sandbox", "--robot-config", arg)
        assert res.exit_code == 0, res.output
        assert "nav2: footprint disc r = 0.22 m" in res.stderr and "nav2: model unicycle" in res.stderr
    one_line(invoke("map", "info", "example:tb3_sandbox", "--robot-config", CAR, "--robot", "car_trailer"), 2,
             "--robot")
    res = invoke("map", "info", "example:tb3_sandbox", "--robot-config", CAR, "--robot", "unicycle")
    assert "model unicycle (given)" in res.stderr
    robot_file = tmp_path / "r.yaml"
    robot_file.write_text("robot: {model: unicycle}\n")
    one_line(invoke("map", "info", "example:tb3_sandbox", "--robot-config", f"nav2:{robot_file}"), 2,
             "ros__parameters")


def test_the_model_choices_are_the_readers():
    from nhstab.cli.robot import from_nav2
    from nhstab.nav2 import NAV2_MODELS

    option = next(p for p in from_nav2.params if p.name == "model")
    assert tuple(option.type.choices) == NAV2_MODELS


def test_robot_takes_a_nav2_file_too():
    res = invoke("map", "info", "example:tb3_sandbox", "--robot", f"nav2:{CAR}")
    assert res.exit_code == 0, res.output
    assert "nav2: model rwd_car" in res.stderr
    one_line(invoke("map", "info", "example:tb3_sandbox", "--robot", "nav2:missing.yaml"), 2, "missing.yaml")
