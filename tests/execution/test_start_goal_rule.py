"""One rule for a start or goal, for every model and every way of giving it (command line, run config,
batch config, ``plan()``, ``execute()``): the pose x, y, theta (a car_trailer may add its trailer
headings), or the model's full state in its state order with the steering angle phi = 0. Nothing
given is dropped: any other phi, or any other length, is a one-line error naming where it was given."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab.cli.main import cli
from nhstab.errors import InputError
from nhstab.robot import default_robot

ROOT = Path(__file__).resolve().parents[2]
ROOM = str(ROOT / "maps/ours/cluttered_room.yaml")


@pytest.mark.parametrize("model", ["unicycle", "rwd_car", "fwd_car", "car_trailer"])
def test_a_full_state_with_phi_zero_gives_its_own_configuration(model):
    rob = default_robot(model)
    names = list(rob.model.state_names)
    x = np.arange(1.0, rob.model.n + 1.0) / 10.0
    if "phi" in names:
        x[names.index("phi")] = 0.0
    conf = rob.configuration(x, "start")
    assert conf.tolist() == x[rob.configuration_columns].tolist()
    # and the configuration itself passes through unchanged
    assert rob.configuration(conf, "start").tolist() == conf.tolist()


@pytest.mark.parametrize("model,phi", [("rwd_car", 0.05), ("fwd_car", -0.2), ("car_trailer", 0.4),
                                       ("rwd_car", 2.0), ("car_trailer", -7.0)])
def test_a_full_state_with_another_phi_is_refused_naming_where_and_phi(model, phi):
    rob = default_robot(model)
    names = list(rob.model.state_names)
    x = np.array([2.0, 3.0] + [0.1] * (rob.model.n - 2))
    x[names.index("phi")] = phi
    with pytest.raises(InputError) as err:
        rob.configuration(x, "goal (in a.yaml)")
    text = str(err.value)
    assert err.value.argument == "goal (in a.yaml)" and "\n" not in text
    assert f"phi = {phi:g} rad" in text and ",".join(names) in text
    beyond = abs(phi) > rob.model.max_steer
    assert ("beyond the steering limits" in text) == beyond


@pytest.mark.parametrize("model,length", [("unicycle", 4), ("rwd_car", 5), ("fwd_car", 2), ("car_trailer", 6)])
def test_any_other_length_is_refused(model, length):
    with pytest.raises(InputError) as err:
        default_robot(model).configuration(np.ones(length), "--goal")
    assert err.value.argument == "--goal"


def test_plan_refuses_a_steered_start_and_honours_a_full_state_in_the_model_order():
    """plan(): a fwd_car's full state is (x, y, phi, theta): with phi = 0 the nominal starts at exactly
    that state; with phi != 0 the plan is refused (before the search) instead of starting at phi = 0."""
    from nhstab.maps import load_map
    from nhstab.planning import PathOptions, plan

    m = load_map(ROOM)
    rob = default_robot("fwd_car")
    start, goal = np.array([1.8, 1.8, 0.0, 0.4]), np.array([10.2, 7.2, 0.0, 1.5708])
    res = plan(m, rob, start, goal, PathOptions(time_limit_s=2.0, seed=3))
    assert res.ok, res.message
    assert np.allclose(res.nominal.x[0], start, atol=1e-9)
    assert np.allclose(res.nominal.x[-1][[0, 1, 3]], goal[[0, 1, 3]], atol=1e-6) and res.nominal.x[-1][2] == 0.0
    with pytest.raises(InputError) as err:
        plan(m, rob, np.array([1.8, 1.8, 0.3, 0.4]), goal, PathOptions(time_limit_s=2.0, seed=3))
    assert err.value.argument == "start" and "phi = 0.3 rad" in str(err.value)


def test_execute_refuses_a_steered_goal_before_anything_runs():
    from nhstab.execution import execute
    from nhstab.maps import load_map

    with pytest.raises(InputError) as err:
        execute(load_map(ROOM), default_robot("rwd_car"), (1.8, 1.8, 0.0), (10.2, 7.2, 1.5708, -0.1))
    assert err.value.argument == "goal" and "phi = -0.1 rad" in str(err.value)


def _one_error_line(res, needle):
    lines = [ln for ln in res.output.splitlines() if ln.startswith("nhstab:")]
    assert res.exit_code == 2 and len(lines) == 1 and needle in lines[0], res.output
    assert "Traceback" not in res.output
    return lines[0]


def test_cli_plan_refuses_a_steered_goal_and_writes_nothing(tmp_path):
    out = tmp_path / "p"
    res = CliRunner().invoke(cli, ["plan", ROOM, "--robot", "rwd_car", "--goal", "10.2,7.2,1.5708,0.25",
                                   "--out", str(out), "--no-figure"])
    line = _one_error_line(res, "'--goal'")
    assert "phi = 0.25 rad" in line
    assert not out.exists() or not list(out.iterdir())


def test_cli_run_refuses_a_steered_start_from_its_config_naming_the_file(tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {ROOM}\nrobot: fwd_car\nstart: [1.8, 1.8, -0.9, 0.0]\n")
    out = tmp_path / "o"
    res = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--out", str(out)])
    line = _one_error_line(res, f"'start (in {cfg})'")
    assert "beyond the steering limits" in line
    assert not out.exists() or not list(out.iterdir())


def test_cli_run_with_full_state_ends_writes_every_figure_and_records_the_configuration(tmp_path):
    """A car's full-state start and goal (phi = 0) run to the end and the figures are drawn: the run
    records the configurations it planned between."""
    out = tmp_path / "o"
    res = CliRunner().invoke(cli, ["run", ROOM, "--robot", "fwd_car", "--start", "1.8,1.8,0,0.2",
                                   "--goal", "10.2,7.2,0,1.5708", "--max-time", "2", "--noise", "0",
                                   "--tube", "linear", "--out", str(out)])
    assert res.exit_code in (0, 4), res.output
    assert "Traceback" not in res.output
    for name in ("run.json", "trajectory.csv", "run_map.png", "run_tracking.png"):
        assert (out / name).stat().st_size > 1000, name
    d = json.loads((out / "run.json").read_text())
    assert d["inputs"]["start"] == pytest.approx([1.8, 1.8, 0.2])
    assert d["inputs"]["goal"] == pytest.approx([10.2, 7.2, 1.5708])
    assert d["initial_state"] == pytest.approx([1.8, 1.8, 0.0, 0.2])      # noiseless: the state given


def test_batch_config_refuses_a_steered_problem_naming_the_key(tmp_path):
    from nhstab.batch.config import load_batch_config

    cfg = tmp_path / "b.yaml"
    cfg.write_text(f"name: b\nroot_seed: 1\ntrials: 1\nmaps:\n  - path: {ROOM}\n    problems:\n"
                   "      - {start: [1.8, 1.8, 0.0, 0.3], goal: [10.2, 7.2, 1.5708]}\n"
                   "robots: [rwd_car]\n")
    with pytest.raises(InputError) as err:
        load_batch_config(cfg)
    assert err.value.argument == "maps[0].problems[0].start" and "phi = 0.3 rad" in str(err.value)


def test_map_show_follows_the_same_rule(tmp_path):
    png = tmp_path / "m.png"
    res = CliRunner().invoke(cli, ["map", "show", ROOM, "--robot", "rwd_car", "--start", "1.8,1.8,0,-0.3",
                                   "--out", str(png)])
    assert "phi = -0.3 rad" in _one_error_line(res, "'--start'")
    assert not png.exists()
    res = CliRunner().invoke(cli, ["map", "show", ROOM, "--robot", "fwd_car", "--start", "1.8,1.8,0,0.3",
                                   "--out", str(png)])
    assert res.exit_code == 0, res.output
    assert png.stat().st_size > 1000
