"""``nhstab run`` on the command line: outputs, exit codes, one-line errors, interruption."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from nhstab.cli.main import cli
from nhstab.execution import read_run_csv

from tests.clitools import invoke, one_line

ROOT = Path(__file__).resolve().parents[2]
ROOM = str(ROOT / "maps/ours/cluttered_room.yaml")


def _invoke(*args):
    return CliRunner().invoke(cli, ["run", *args])


@pytest.mark.parametrize("args,needle", [
    (["--noise", "-1"], "'--noise'"),
    (["--rate", "0"], "'--rate'"),
    (["--controller", "pid"], "'--controller'"),
    (["--sensor-std", "x=-0.1"], "'--sensor-std x'"),
    (["--sensor-std", "x:0.1"], "'--sensor-std'"),
    (["--process-std", "w=0.1"], "'--process-std w'"),
    (["--planner", "astar"], "'--planner'"),
    (["--time-limit", "0"], "'--time-limit'"),
    (["--start", "4.0,4.5,0"], "'--start'"),             # on the dining table
    (["--goal", "100,100,0"], "'--goal'"),                # out of bounds
    (["--gamma", "0.2"], "'--gamma'"),
    (["--window", "sideways"], "'--window'"),
    (["--robot", "tank"], "'--robot'"),
])
def test_bad_input_is_one_line_with_exit_code_2_and_writes_nothing(tmp_path, args, needle):
    out = tmp_path / "out"
    res = _invoke(ROOM, "--out", str(out), *args)
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("nhstab:")]
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in res.output
    assert not (out / "run.json").exists()


def test_a_bad_frozen_time_gain_bound_in_a_config_is_a_one_line_error(tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {ROOM}\ncontroller: {{window: frozen-time, max_gain: -1}}\n")
    res = _invoke("--config", str(cfg), "--out", str(tmp_path / "o"))
    assert res.exit_code == 2 and "controller.max_gain" in res.output


@pytest.mark.slow
def test_windows_on_a_real_map_frozen_time_reaches_the_goal_past_warns(tmp_path):
    """The cluttered room, seed 1: the causal frozen-time law reaches the goal (its verdict recomputed
    from trajectory.csv: the last pose within the goal tolerance, every pose clear of every real
    obstacle, FCL); the past window's run prints exactly one warning line."""
    import numpy as np
    from nhstab.collision import CollisionWorld
    from nhstab.maps import load_map
    from nhstab.robot import default_footprint

    out = tmp_path / "frozen"
    res = _invoke(ROOM, "--window", "frozen-time", "--seed", "1", "--out", str(out))
    assert res.exit_code == 0, res.output
    assert "nhstab: warning" not in res.output
    d = json.loads((out / "run.json").read_text())
    assert d["inputs"]["controller"]["window"] == "frozen-time" and d["status"] == "reached"
    log = read_run_csv(out / "trajectory.csv")
    m = load_map(ROOM)
    world = CollisionWorld.from_map(m, "all")
    poses = np.stack([log["x"], log["y"], log["theta"]], axis=1)
    assert world.free_many(poses, default_footprint("unicycle"), 0.0).all()
    goal = m.goal.as_array()
    assert np.hypot(*(poses[-1, :2] - goal[:2])) <= 0.3
    res = _invoke(ROOM, "--window", "past", "--seed", "1", "--out", str(tmp_path / "past"))
    warnings = [ln for ln in res.output.splitlines() if ln.startswith("nhstab: warning")]
    assert len(warnings) == 1 and "not stabilizing in general" in warnings[0]


def test_missing_map_and_bad_config_are_one_line_errors(tmp_path):
    res = _invoke("--out", str(tmp_path))
    assert res.exit_code == 2 and "MAP" in res.output
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {ROOM}\nmonitor: {{rate: 5}}\n")
    res = _invoke("--config", str(cfg), "--out", str(tmp_path / "o"))
    assert res.exit_code == 2 and "monitor.rate" in res.output


def test_config_file_gives_options_and_the_command_line_overrides(tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {ROOM}\nseed: 4\ncontroller: {{kind: open-loop}}\nnoise: {{scale: 0}}\n")
    out = tmp_path / "out"
    res = _invoke("--config", str(cfg), "--controller", "tvlqr", "--out", str(out))
    assert res.exit_code in (0, 4), res.output
    d = json.loads((out / "run.json").read_text())
    assert d["inputs"]["options"]["seed"] == 4
    assert d["inputs"]["controller"]["kind"] == "tvlqr"
    assert d["inputs"]["noise"]["scale"] == 0.0


@pytest.mark.slow
def test_run_writes_every_output_and_the_csv_has_units(tmp_path):
    out = tmp_path / "out"
    res = _invoke(ROOM, "--out", str(out), "--animate")
    assert res.exit_code == 0, res.output
    for name in ("run.json", "trajectory.csv", "run_map.png", "run_tracking.png", "run.gif"):
        assert (out / name).stat().st_size > 1000, name
    header = (out / "trajectory.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["t [s]", "plan_id", "mode"] and "x_nominal [m]" in header and "v [m/s]" in header
    d = json.loads((out / "run.json").read_text())
    for key in ("status", "seeds", "plans", "tracking", "final_error", "clearance", "control_effort", "timing"):
        assert key in d
    csv = read_run_csv(out / "trajectory.csv")
    assert len(csv["t"]) == d["tracking"]["samples"] + int((csv["mode"] != "track").sum())


def test_an_interrupted_run_keeps_what_was_computed_and_says_so(tmp_path, monkeypatch):
    """Ctrl-C during the run: the files written are complete and say "interrupted"; exit code 130;
    no temporary files are left."""
    from nhstab.execution import plant

    calls = {"n": 0}
    step = plant.Plant.step

    def interrupting(self, x, u):
        calls["n"] += 1
        if calls["n"] == 200:
            raise KeyboardInterrupt
        return step(self, x, u)

    monkeypatch.setattr(plant.Plant, "step", interrupting)
    out = tmp_path / "out"
    res = _invoke(ROOM, "--out", str(out))
    assert res.exit_code == 130, res.output
    d = json.loads((out / "run.json").read_text())
    assert d["status"] == "interrupted"
    csv = read_run_csv(out / "trajectory.csv")
    assert len(csv["t"]) == 200
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_without_out_plan_run_and_batch_write_into_out_of_the_current_folder(tmp_path):
    """No --out: plan, run and batch write into out/plan, out/run and out/batch of the current folder,
    which the repository's .gitignore ignores (so the committed results/ are never the default); a
    second batch into the same default folder is refused, naming --out."""
    assert "/out/" in (ROOT / ".gitignore").read_text().splitlines()
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {ROOM}\nseed: 4\ncontroller: {{kind: open-loop}}\nnoise: {{scale: 0}}\n")
    res = invoke("run", "--config", cfg, cwd=tmp_path)
    assert res.exit_code in (0, 4), res.output
    assert json.loads((tmp_path / "out" / "run" / "run.json").read_text())["inputs"]["options"]["seed"] == 4
    res = invoke("plan", ROOM, "--tube", "linear", "--no-figure", cwd=tmp_path)
    assert res.exit_code == 0, res.output
    assert (tmp_path / "out" / "plan" / "plan.json").is_file()
    batch = tmp_path / "batch.yaml"
    batch.write_text(f"name: t\nroot_seed: 1\ntrials: 1\nmaps: [{{path: {ROOM}}}]\ncontrollers: [open-loop]\n"
                     "run: {noise: {scale: 0}}\n")
    res = invoke("batch", batch, "--workers", 1, "--no-progress", cwd=tmp_path)
    assert res.exit_code == 0, res.output
    assert (tmp_path / "out" / "batch" / "trials.sqlite").is_file()
    one_line(invoke("batch", batch, "--workers", 1, "--no-progress", cwd=tmp_path), 2, "'--out'", "out/batch")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["batch", "plan", "run"]
