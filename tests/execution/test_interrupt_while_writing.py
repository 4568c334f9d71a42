"""Ctrl-C once a run (or a plan) has ended, while its result is assembled or its files are written:
the files are completed and describe the run as it ended; the command exits 130 and says so. The
SIGINT is a real signal sent from inside the code that runs at that moment (the command line's
handler is installed, as for a user's Ctrl-C)."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import pytest
from click.testing import CliRunner
from nhstab.cli.main import cli

ROOT = Path(__file__).resolve().parents[2]
ROOM = str(ROOT / "maps/ours/cluttered_room.yaml")
QUICK = ["--noise", "0", "--tube", "linear", "--max-time", "2"]


def _interrupting(fn, calls: dict):
    """fn, sending this process a SIGINT on its first call (before it does its work)."""

    def wrapped(*args, **kwargs):
        calls["n"] = calls.get("n", 0) + 1
        if calls["n"] == 1:
            os.kill(os.getpid(), signal.SIGINT)
        return fn(*args, **kwargs)

    return wrapped


@pytest.fixture
def real_sigint():
    """The default SIGINT handler, as in a terminal (the command line installs its own over it)."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


@pytest.mark.parametrize("where", ["csv", "figure", "result"])
def test_ctrl_c_after_the_run_keeps_its_files(tmp_path, monkeypatch, real_sigint, where):
    from nhstab.execution import outputs, runner

    calls: dict = {}
    if where == "csv":            # writing trajectory.csv
        monkeypatch.setattr(outputs, "trajectory_csv", _interrupting(outputs.trajectory_csv, calls))
    elif where == "figure":       # drawing run_tracking.png, after run_map.png was staged
        monkeypatch.setattr(outputs, "run_tracking_figure", _interrupting(outputs.run_tracking_figure, calls))
    else:                         # assembling the result, after the simulation loop
        monkeypatch.setattr(runner.RunLog, "arrays", _interrupting(runner.RunLog.arrays, calls))
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["run", ROOM, "--out", str(out), *QUICK])
    assert calls["n"] >= 1
    assert res.exit_code == 130, res.output
    assert "interrupted after the run ended" in res.output and "aborted" not in res.output
    for name in ("run.json", "trajectory.csv", "run_map.png", "run_tracking.png", "nhstab-manifest.json"):
        assert (out / name).stat().st_size > 0, name
    d = json.loads((out / "run.json").read_text())
    assert d["status"] == "timed_out"          # the run as it ended (2 s of simulated time), not "interrupted"
    manifest = json.loads((out / "nhstab-manifest.json").read_text())
    assert {"run.json", "trajectory.csv", "run_map.png", "run_tracking.png"} <= set(manifest["files"])


def test_ctrl_c_while_a_plan_is_written_keeps_its_files(tmp_path, monkeypatch, real_sigint):
    from nhstab.execution import outputs

    calls: dict = {}
    monkeypatch.setattr(outputs, "write_trajectory", _interrupting(outputs.write_trajectory, calls))
    out = tmp_path / "p"
    res = CliRunner().invoke(cli, ["plan", ROOM, "--out", str(out), "--tube", "linear", "--no-figure"])
    assert calls["n"] == 2
    assert res.exit_code == 130, res.output
    assert "interrupted after planning" in res.output
    for name in ("trajectory.csv", "trajectory.npz", "plan.json", "nhstab-manifest.json"):
        assert (out / name).stat().st_size > 0, name


def test_ctrl_c_during_the_simulation_still_ends_the_run_as_interrupted(tmp_path, monkeypatch, real_sigint):
    """The hold is only for what comes after the simulation: a SIGINT while the robot moves stops it."""
    from nhstab.execution import plant

    calls = {"n": 0}
    step = plant.Plant.step

    def stepping(self, x, u):
        calls["n"] += 1
        if calls["n"] == 30:
            os.kill(os.getpid(), signal.SIGINT)
        return step(self, x, u)

    monkeypatch.setattr(plant.Plant, "step", stepping)
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["run", ROOM, "--out", str(out), *QUICK])
    assert res.exit_code == 130, res.output
    assert json.loads((out / "run.json").read_text())["status"] == "interrupted"
    assert "interrupted after the run ended" not in res.output
