"""``nhstab trailer train``: the feedback laws on a rig of several trailers, which nhstab does not plan for."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab.batch import train_study as TR
from nhstab.cli.main import cli
from nhstab.errors import InputError
from nhstab.records import read_json
from nhstab.robot import robot_from_spec


def test_the_train_nominal_is_the_models_motion_and_its_reverse():
    """The S-curve of a dolly and a trailer: the reversed nominal is the forward motion backwards in time
    under the negated inputs, and it is a motion of the model: its samples' central differences equal the
    model's right-hand side (to 1e-3: the difference's own error at the 0.01 s grid, largest where the speed
    ramp has a corner, h / 2 x the jump of the acceleration, 0.27 m/s^2, in x). Integrating it again
    open loop would not do as a check: backing up, the trailers' headings diverge from any error."""
    robot = robot_from_spec({"model": "car_trailer", "hitch_lengths": [1.5, 3.0]})
    model = robot.model
    fwd, back = TR.s_curve(model)
    assert np.array_equal(back.x, fwd.x[::-1]) and np.array_equal(back.u, -fwd.u[::-1])
    for nom in (fwd, back):
        h = nom.t[1] - nom.t[0]
        dx = (nom.x[2:] - nom.x[:-2]) / (2 * h)
        assert np.max(np.abs(dx - model.rhs(nom.x[1:-1], nom.u[1:-1]))) < 1e-3
    assert np.abs(robot.model.hitch_angles(fwd.x)).max() <= TR.FEASIBLE_FRACTION * robot.model.jackknife_limit


def test_the_train_study_refuses_rigs_it_cannot_drive_and_bad_values(tmp_path):
    with pytest.raises(InputError, match=r"'--hitch-lengths' must be a rig whose S-curve keeps the steering and hitch "
                                         r"angles within 0.8 of their limits; got \[12.0, 12.0\] \(steering"):
        TR.train_study((12.0, 12.0), trials=1)
    for bad in ((), (1.0,) * 9, (float("nan"),), (0.1,), ("a",)):
        with pytest.raises(InputError, match="'--hitch-lengths' must be 1 to 8 hitch lengths"):
            TR.train_study(bad, trials=1)
    with pytest.raises(InputError, match="'--noise'"):
        TR.train_study((3.0,), trials=1, noise=float("inf"))
    with pytest.raises(InputError, match="'--steer-rate' must be a steering-rate amplitude in"):
        TR.train_study((3.0,), trials=1, steer_rate=0.0)
    res = CliRunner().invoke(cli, ["trailer", "train", "--hitch-lengths", "1.5,x", "--out", "/tmp/never"])
    assert res.exit_code == 2 and "'--hitch-lengths' must be numbers separated by commas" in res.output
    # the planner refuses two trailers in one line that points here
    cfg = tmp_path / "two.yaml"
    cfg.write_text("robot: {model: car_trailer, hitch_lengths: [1.5, 3.0]}\n")
    res = CliRunner().invoke(cli, ["plan", "example:tugger_aisle", "--robot-config", str(cfg), "--out",
                                   str(cfg.parent / "out")])
    assert res.exit_code == 2 and "got '2 trailers'" in res.output and "nhstab trailer train" in res.output
    assert "Traceback" not in res.output


@pytest.mark.slow
@pytest.mark.parametrize("folder", ["train", "train_gentle"])
def test_the_committed_train_study_is_what_the_command_computes(folder):
    """results/trailer/train and train_gentle (nhstab trailer train [--steer-rate 0.02]): the two-trailer
    rig computed again here with the record's settings, every count and error is the same (the laws and
    the loop are deterministic for the seeds); a dolly and a trailer backing up jackknife under every law
    in some trial, one trailer under TVLQR in none."""
    rec = read_json(Path(__file__).parents[1] / "results" / "trailer" / folder / "train.json.gz")
    again = TR.train_study(rec["rigs"][0]["hitch_lengths_m"], rec["trials"], rec["noise"], rec["process_per"],
                           rec["root_seed"], reference=False,            # the two-trailer rig: half the time
                           steer_rate=rec["nominal"]["steer_rate_amplitude_rad_s"])
    (rig,) = again["rigs"]
    assert rig == rec["rigs"][0]
    two, one = ({(c["direction"], c["law"]): c for c in rig["cells"]} for rig in rec["rigs"])
    assert all(two[("reversed", law)]["jackknifes"] > 0 for law, _ in TR.LAWS)
    assert one[("reversed", "tvlqr")]["jackknifes"] == 0
