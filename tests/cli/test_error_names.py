"""Bad input names the key or option the user wrote, says what was expected and what was given, in
one line with exit code 2: model parameters' ranges, the gain schedule's window, the YAML 1.1
number hint, a batch's values checked before any trial runs, and command-line options named as
options (tables of bad inputs, each asserting the key in the message)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from nhstab.cli.main import cli
from nhstab.errors import InputError, user_keys
from nhstab.maps.base import MapError

ROOT = Path(__file__).resolve().parents[2]
ROOM = str(ROOT / "maps/ours/cluttered_room.yaml")
HINT = "YAML 1.1 reads"


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _one_line(res, *needles, code: int = 2) -> str:
    """The command's one error line, checked for the exit code, no traceback and every needle."""
    assert res.exit_code == code, res.output
    assert "Traceback" not in res.output, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("nhstab:")]
    assert len(lines) == 1, res.output
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def _write(path: Path, data) -> Path:
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data), encoding="utf-8")
    return path


def _small_map(tmp_path: Path, robot: dict | None = None, name: str = "small.yaml", **extra) -> Path:
    doc = {"bounds": [0, 0, 12, 9], "start": [1.5, 1.5, 0.0], "goal": [10.0, 7.0, 0.0], **extra}
    if robot is not None:
        doc["robot"] = robot
    return _write(tmp_path / name, doc)


# ---- the mechanism ---------------------------------------------------------------------------------
def test_user_keys_renames_the_key_and_keeps_the_rest():
    with pytest.raises(MapError) as err:
        with user_keys({"delta": "grid.delta[2]"}):
            raise MapError("delta", "a positive number", "1e-3", detail="why")
    e = err.value
    assert (e.argument, e.expected, e.got) == ("grid.delta[2]", "a positive number", "1e-3")
    assert e.detail.startswith("why") and HINT in e.detail and str(e).startswith("'grid.delta[2]' must be")
    # keys below the one given follow it; options take the rest after a space; the innermost block wins
    with pytest.raises(InputError, match=r"^'--initial-error x' must"):
        with user_keys({"noise.initial": "--initial-error"}):
            raise InputError("noise.initial.x", "a number >= 0", -1)
    with pytest.raises(InputError, match=r"^'run\.controller\.delta\[0\]' must"):
        with user_keys({"controller": "run.controller"}), user_keys({"gamma": "controller.gamma"}):
            raise InputError("controller.delta[0]", "x", 1)
    with pytest.raises(InputError, match=r"^'--headroom' must .* got 1e-05"):
        with user_keys({"max_speed": ("--headroom", 1e-5)}):
            raise InputError("max_speed", "large enough", 1e-5 * 1.5)
    with pytest.raises(InputError, match=r"^'alpha' must"):     # a key not named stays as it is
        with user_keys({"delta": "--delta", "alpha": None}):
            raise InputError("alpha", "x", 1)


@pytest.mark.parametrize("got", ["2e3", ["1", "5E-3"], {"x": "1e+2"}, ("0.1", "-3e2")])
def test_every_input_error_on_number_looking_text_carries_the_yaml_hint(got):
    assert HINT in str(InputError("k", "a number", got))
    assert HINT not in str(InputError("k", "a number", "abc")) and HINT not in str(InputError("k", "x", 3.0))


# ---- model parameters: ranges, under their own names --------------------------------------------------
ANGLES = [("fwd_car", "max_steer"), ("rwd_car", "max_steer"), ("car_trailer", "max_steer"),
          ("car_trailer", "jackknife_limit")]


@pytest.mark.parametrize("model,key", ANGLES)
@pytest.mark.parametrize("value", [math.pi / 2, 1.6, 3.0, 500.0])
def test_angle_limits_of_every_model_are_below_a_right_angle_under_their_own_names(model, key, value, tmp_path):
    from nhstab.models import make_model
    from nhstab.robot import make_robot

    with pytest.raises(InputError) as err:
        make_model(model, **{key: value})
    assert err.value.argument == f"{model}.{key}" and "below pi/2" in str(err.value)
    with pytest.raises(InputError) as err:
        make_robot(model, **{key: value})
    assert err.value.argument == f"robot.{key}" and "below pi/2" in str(err.value)
    # a robot file, a map's robot block, a batch's robots
    robot = {"model": model, key: value}
    rfile = _write(tmp_path / "car.yaml", robot)
    _one_line(_invoke("plan", ROOM, "--robot-config", rfile, "--out", tmp_path / "p"), f"'car.yaml: robot.{key}'",
              "below pi/2")
    mfile = _small_map(tmp_path, robot)
    _one_line(_invoke("plan", mfile, "--out", tmp_path / "p"), f"{mfile}: robot.{key}'", "below pi/2")
    batch = _write(tmp_path / "b.yaml", {"root_seed": 1, "trials": 1, "maps": [{"path": ROOM}], "robots": [robot]})
    _one_line(_invoke("batch", batch, "--out", tmp_path / "b"), f"'robots[0].{key}'", "below pi/2")
    assert not (tmp_path / "p").exists() and not (tmp_path / "b").exists()


def test_a_fwd_car_steering_limit_inside_its_range_is_planned_with_a_positive_radius():
    from nhstab.robot import make_robot

    car = make_robot("fwd_car", max_steer=1.4, wheelbase=1.0)
    assert car.min_turning_radius == pytest.approx(1.0 / math.tan(1.4)) and car.turning_radius > 0


def test_gains_names_model_parameters_as_the_param_option(tmp_path):
    import numpy as np

    t = np.linspace(0.0, 4.0, 201)
    rows = np.column_stack([t, 0.5 * t, np.zeros_like(t), 0.3 * np.ones_like(t), np.zeros_like(t), 0.5 * np.ones_like(t),
                            np.zeros_like(t)])
    traj = tmp_path / "fwd.csv"
    traj.write_text("t,x,y,phi,theta,v,omega_s\n" + "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows) + "\n")
    base = ["gains", traj, "--model", "fwd_car", "--out", tmp_path / "g"]
    _one_line(_invoke(*base, "--param", "max_steer=1.7"), "'--param max_steer'", "below pi/2")
    _one_line(_invoke(*base, "--param", "wheelbase=-2"), "'--param wheelbase'", "positive")
    _one_line(_invoke(*base, "--param", "tyres=4"), "'--param'", "tyres")
    _one_line(_invoke(*base, "--gamma", "2.0e4"), "'--gamma'", "10000")


def test_a_robot_too_slow_for_the_map_is_named_by_its_files_key_and_value(tmp_path):
    rfile = _write(tmp_path / "slow.yaml", {"model": "unicycle", "max_speed": 3.0e-9})
    for cmd in (("plan", ROOM, "--no-figure"), ("run", ROOM)):
        _one_line(_invoke(*cmd, "--robot-config", rfile, "--out", tmp_path / "o"), "'slow.yaml: robot.max_speed'",
                  "got 3e-09", "2,000,000 samples")
    assert not (tmp_path / "o").exists()


# ---- the robot's stabilizer: its window named where it was written --------------------------------------
@pytest.mark.parametrize("delta", [1e-9, 2e-5])
def test_a_robot_files_window_too_short_for_the_time_step_names_that_key(tmp_path, delta):
    rfile = _write(tmp_path / "bot.yaml", {"model": "unicycle", "stabilizer": {"delta": delta}})
    for cmd in (("plan", ROOM, "--no-figure"), ("run", ROOM)):
        line = _one_line(_invoke(*cmd, "--robot-config", rfile, "--out", tmp_path / "o"),
                         "'bot.yaml: robot.stabilizer.delta'", "at least", "time step")
        assert "'goal'" not in line and "smaller" not in line
    mfile = _small_map(tmp_path, {"model": "unicycle", "stabilizer": {"delta": delta}})
    _one_line(_invoke("run", mfile, "--out", tmp_path / "o"), f"{mfile}: robot.stabilizer.delta'", "at least")
    # the same window given on the command line or in a run config is named there
    _one_line(_invoke("run", ROOM, "--delta", delta, "--out", tmp_path / "o"), "'--delta'", "at least")
    cfg = _write(tmp_path / "run.yaml", {"map": ROOM, "controller": {"delta": delta}})
    _one_line(_invoke("run", "--config", cfg, "--out", tmp_path / "o"), "'controller.delta'", "at least")
    assert not (tmp_path / "o").exists()


def test_a_window_longer_than_the_nominal_is_the_goals_and_names_the_window_to_shorten(tmp_path):
    rfile = _write(tmp_path / "bot.yaml", {"model": "unicycle", "stabilizer": {"delta": 400.0}})
    _one_line(_invoke("plan", ROOM, "--robot-config", rfile, "--no-figure", "--out", tmp_path / "o"),
              "cluttered_room.yaml: goal' must be far enough", "a smaller bot.yaml: robot.stabilizer.delta would fit")


@pytest.mark.parametrize("stab,key,needle", [({"gamma": 3.0e+4}, "gamma", "10000"),
                                              ({"gamma": 1.0e+200}, "gamma", "10000"),
                                              ({"alpha": -1.0}, "alpha", "> 0")])
def test_a_robots_stabilizer_is_checked_by_the_laws_own_rules_where_it_is_written(tmp_path, stab, key, needle):
    from nhstab.robot import robot_from_spec

    with pytest.raises(InputError) as err:
        robot_from_spec({"model": "rwd_car", "stabilizer": stab}, where="robots[3]")
    assert err.value.argument == f"robots[3].stabilizer.{key}" and needle in str(err.value)
    rfile = _write(tmp_path / "bot.yaml", {"model": "unicycle", "stabilizer": stab})
    _one_line(_invoke("run", ROOM, "--robot-config", rfile, "--out", tmp_path / "o"),
              f"'bot.yaml: robot.stabilizer.{key}'", needle)


# ---- the YAML 1.1 number hint in every file the tool reads ---------------------------------------------
@pytest.mark.parametrize("kind,text,key", [
    ("robot", "model: unicycle\nmax_speed: 2e0\n", "'bot.yaml: robot.max_speed'"),
    ("robot", "model: rwd_car\nstabilizer: {delta: 5e0}\n", "'bot.yaml: robot.stabilizer.delta'"),
    ("robot", "model: car_trailer\nhitch_lengths: 3e0\n", "'bot.yaml: robot.hitch_lengths'"),
    ("robot", "model: unicycle\nfootprint: {radius: 3e-1}\n", "'bot.yaml: robot.footprint.radius'"),
    ("map", "bounds: [0, 0, 12, 9]\nstart: [1.5, 1.5, 0]\ngoal: [10, 7, 0]\nrobot: {model: unicycle, margin: 1e-1}\n",
     ": robot.margin'"),
    ("map", "bounds: [0, 0, 12, 9]\nstart: [1.5, 1.5, 0]\ngoal: [10, 7, 0]\nrobot: {model: rwd_car, wheelbase: 2e0}\n",
     ": robot.wheelbase'"),
    ("map", "bounds: [0, 0, 12, 9]\nobstacles: [{circle: {center: [6, 4], radius: 5e-1}}]\n",
     ": obstacles[0].circle.radius'"),
    ("run", f"map: {ROOM}\nmax_time_s: 6e1\n", "'max_time_s'"),
    ("run", f"map: {ROOM}\nrobot: {{model: unicycle, max_turn_rate: 2e0}}\n", "'robot.max_turn_rate'"),
    ("run", f"map: {ROOM}\ngoal: [1.0e+1, 7e0, 0]\n", "'goal[1]'"),
    ("batch", f"root_seed: 1\ntrials: 1\nmaps: [{{path: {ROOM}}}]\ngrid: {{noise: [1e0]}}\n", "'grid.noise[0]'"),
    ("batch", f"root_seed: 1\ntrials: 1\nmaps: [{{path: {ROOM}}}]\nrobot: {{model: unicycle, max_speed: 1e9}}\n",
     "'robot.max_speed'"),
    ("batch", f"root_seed: 1\ntrials: 1\nmaps: [{{path: {ROOM}}}]\nrun: {{monitor: {{horizon_s: 8e0}}}}\n",
     "'run.monitor.horizon_s'"),
])
def test_number_looking_text_gets_the_hint_in_every_yaml(tmp_path, kind, text, key):
    f = _write(tmp_path / {"robot": "bot.yaml", "map": "m.yaml", "run": "run.yaml", "batch": "b.yaml"}[kind], text)
    args = {"robot": ("plan", ROOM, "--robot-config", f), "map": ("plan", f, "--start", "1,1,0", "--goal", "2,2,0"),
            "run": ("run", "--config", f), "batch": ("batch", f)}[kind]
    _one_line(_invoke(*args, "--out", tmp_path / "o"), key, HINT)
    assert not (tmp_path / "o").exists()


# ---- a batch's values, checked before any trial runs ------------------------------------------------
def _batch(tmp_path, maps=None, **extra) -> Path:
    return _write(tmp_path / "batch.yaml", {"root_seed": 7, "trials": 3, "maps": maps or [{"path": ROOM}], **extra})


@pytest.mark.parametrize("maps,extra,key,needle", [
    (None, {"grid": {"delta": [2.0, 5.0e-13]}}, "'grid.delta[1]'", "time step"),
    (None, {"grid": {"alpha": [0.2], "delta": [1.0e-6]}}, "'grid.delta[0]'", "time step"),
    (None, {"run": {"controller": {"delta": 1.0e-7}}}, "'run.controller.delta'", "time step"),
    (None, {"run": {"rate_hz": 1, "controller": {"delta": 2.0e-3}}}, "'run.controller.delta'", "time step"),
    (None, {"robots": ["unicycle", {"model": "unicycle", "name": "u", "stabilizer": {"gamma": 5.0e+4}}]},
     "'robots[1].stabilizer.gamma'", "10000"),
    (None, {"robot": {"model": "unicycle", "stabilizer": {"delta": 1.0e-9}}}, "'robot.stabilizer.delta'", "time step"),
    (None, {"run": {"controller": {"gamma": 2.0e+4}}}, "'run.controller.gamma'", "10000"),
    (None, {"controllers": ["tvlqr"], "run": {"controller": {"gains": "auto"}}}, "'run.controller.gains'", "tvlqr"),
    ([{"path": "example:loading_dock"}], {"run": {"planning": {"margin": "auto"}}}, "'run.planning.margin'",
     "several bodies"),
    ([{"path": "example:parking_lot"}], {"run": {"planning": {"turning_radius": 0.5}}},
     "'run.planning.turning_radius'", "minimum turning radius"),
    ([{"path": "example:parking_lot"}], {"robots": [{"model": "rwd_car", "turning_radius": 9.0}],
                                          "run": {"planning": {"space": "dubins", "turning_radius": 0.5}}},
     "'run.planning.turning_radius'", "minimum turning radius"),
])
def test_a_batch_refuses_what_every_trial_would_before_any_runs(tmp_path, maps, extra, key, needle):
    out = tmp_path / "out"
    _one_line(_invoke("batch", _batch(tmp_path, maps, **extra), "--out", out, "--no-progress"), key, needle)
    assert not out.exists()


def test_a_batch_names_a_maps_own_robot_block_by_its_file(tmp_path):
    mfile = _small_map(tmp_path, {"model": "unicycle", "stabilizer": {"delta": 1.0e-9}})
    out = tmp_path / "out"
    _one_line(_invoke("batch", _batch(tmp_path, [{"path": str(mfile)}]), "--out", out), f"{mfile}: robot.stabilizer.delta'",
              "time step")
    assert not out.exists()


# ---- keys the user wrote, in the command line and in config files ------------------------------------
@pytest.mark.parametrize("args,key", [
    (("plan", ROOM, "--headroom", "1e-8"), "'--headroom'"),
    (("plan", "example:parking_lot", "--headroom", "1e-9"), "'--headroom'"),
    (("plan", "example:parking_lot", "--turning-radius", "1.0"), "'--turning-radius'"),
    (("plan", ROOM, "--max-speed", "1e-11"), "'--max-speed'"),
    (("plan", ROOM, "--space", "hilbert"), "'--space'"),
    (("plan", ROOM, "--start", "4.0,4.5,0"), "'--start'"),          # on the dining table
    (("plan", ROOM, "--goal", "50,4,0"), "'--goal'"),               # out of bounds
    (("plan", "example:x-not-a-map"), "'MAP'"),
    (("run", ROOM, "--gamma", "12000"), "'--gamma'"),
    (("run", ROOM, "--gamma", "0.3"), "'--gamma'"),
    (("run", ROOM, "--delta", "1e-4"), "'--delta'"),
    (("run", ROOM, "--alpha", "-2"), "'--alpha'"),
    (("run", ROOM, "--noise", "-3"), "'--noise'"),
    (("run", ROOM, "--max-time", "-1"), "'--max-time'"),
    (("run", ROOM, "--initial-error", "theta=-1"), "'--initial-error theta'"),
    (("run", ROOM, "--planner", "dijkstra"), "'--planner'"),
    (("run", ROOM, "--time-limit", "-1"), "'--time-limit'"),
    (("run", ROOM, "--goal", "4.0,4.5,0"), "'--goal'"),
    (("run", "example:loading_dock", "--margin", "auto"), "'--margin'"),
    (("paper", "--case", "hilare-circle", "--delta", "-1"), "'--delta'"),
    (("paper", "--case", "hilare-circle", "--gamma", "2e4"), "'--gamma'"),
    (("map", "show", ROOM, "--goal", "30,2,0"), "'--goal'"),
])
def test_command_line_errors_name_the_option(tmp_path, args, key):
    out = tmp_path / "o"
    line = _one_line(_invoke(*args, "--out", out), key)
    assert not out.exists(), line


@pytest.mark.parametrize("kind,doc,key,absent", [
    ("batch", {"maps": [{"path": ROOM, "problems": [{"start": [1.5, 1.5, 0, 0], "goal": [10, 7, 0]}]}]},
     "'maps[0].problems[0].start'", "'pose'"),
    ("batch", {"maps": [{"path": ROOM, "problems": [{"start": [1.5, 1.5, 0], "goal": [10, 7, 0, 0.2, 0.1]}]}]},
     "'maps[0].problems[0].goal'", "'pose'"),
    ("batch", {"maps": [{"path": "example:nowhere"}]}, "'maps[0].path'", "'example'"),
    ("batch", {"maps": [{"path": ROOM}, {"path": "example:nowhere"}]}, "'maps[1].path'", "'example'"),
    ("batch", {"maps": [{"path": ROOM, "problems": {"first": 1, "count": 2}}]}, "'maps[0].problems'", "map's 0"),
    ("batch", {"maps": [{"path": "example:parking1", "problems": {"first": 3, "count": 4}}]}, "'maps[0].problems'",
     "within the map's"),
    ("run", {"map": "example:nowhere"}, "'map'", "'example'"),
    ("run", {"map": ROOM, "start": [4.0, 4.5, 0]}, "'start'", "cluttered_room.yaml: start'"),
    ("run", {"map": ROOM, "headroom": 1.0e-9}, "'headroom'", "max_speed'"),
    ("run", {"map": ROOM, "robot": {"model": "unicycle", "max_speed": 2.0e-9}}, "'robot.max_speed'", "got 1.6e-09"),
])
def test_config_errors_name_the_key_path(tmp_path, kind, doc, key, absent):
    if kind == "batch":
        f = _write(tmp_path / "b.yaml", {"root_seed": 1, "trials": 1, **doc})
        args = ("batch", f)
    else:
        f = _write(tmp_path / "run.yaml", doc)
        args = ("run", "--config", f)
    line = _one_line(_invoke(*args, "--out", tmp_path / "o"), key)
    assert absent not in line
    assert not (tmp_path / "o").exists()
