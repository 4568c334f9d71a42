"""TVLQR with Q from the robot's outline (``controller.q: footprint``): the weights against closed forms
and an independent computation of how far the corners move, the time-varying Riccati solve, and the
options that ask for it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from nhstab.batch import trailer_study as TS
from nhstab.errors import InputError
from nhstab.execution import ControllerOptions, build_law, tvlqr_gains
from nhstab.execution.config import load_run_config
from nhstab.execution.controllers import FOOTPRINT_FLOOR, footprint_weights
from nhstab.geometry import Footprint
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nhstab.robot import make_robot, robot_from_spec


def _corners(robot, x) -> np.ndarray:
    """Every body's corners (the outline's vertices; a disc's centre) in the world at state x, placed
    by hand from the body poses: p + R(theta) c."""
    out = []
    for (px, py, th), fp in zip(robot.body_poses(np.asarray(x, dtype=float)), robot.footprints):
        v = np.zeros((1, 2)) if fp.vertices is None else fp.vertices
        c, s = math.cos(th), math.sin(th)
        out.append(np.stack([px + c * v[:, 0] - s * v[:, 1], py + s * v[:, 0] + c * v[:, 1]], axis=1))
    return out


def _mean_square_move(robot, x, e) -> float:
    """The mean over bodies of the mean squared distance its corners move from x to x + e."""
    a, b = _corners(robot, x), _corners(robot, np.asarray(x) + e)
    return float(np.mean([np.mean(np.sum((q - p) ** 2, axis=1)) for p, q in zip(a, b)]))


@pytest.mark.parametrize("spec,x", [
    ({"model": "rwd_car", "footprint": {"rectangle": {"length": 4.5, "width": 1.9, "rear_overhang": 1.0}}},
     [3.0, -2.0, 0.7, 0.2]),
    ({"model": "car_trailer"}, [1.0, 2.0, -2.5, 0.3, -2.1]),
    ({"model": "car_trailer", "hitch_lengths": [2.5, 3.0]}, [0.0, 0.0, 1.0, -0.2, 0.6, 0.9]),
])
def test_the_weights_are_the_mean_squared_move_of_the_corners(spec, x):
    """e^T Q e against the corners placed by hand at x and x + e, for small errors e in random
    directions (second-order terms: relative 1e-4 at |e| = 1e-5); the steering angle moves no corner
    and weighs the floor exactly; Q is symmetric and positive semidefinite."""
    robot = robot_from_spec(spec)
    Q = footprint_weights(robot, np.array([x]))[0]
    rng = np.random.default_rng(7)
    iphi = robot.model.state_names.index("phi")
    for _ in range(20):
        e = rng.standard_normal(robot.model.n)
        e[iphi] = 0.0
        e *= 1e-5 / np.linalg.norm(e)
        assert e @ Q @ e == pytest.approx(_mean_square_move(robot, x, e), rel=1e-4)
    assert Q[iphi, iphi] == FOOTPRINT_FLOOR
    assert np.all(Q[iphi, np.arange(robot.model.n) != iphi] == 0.0)
    assert np.array_equal(Q, Q.T)
    assert np.linalg.eigvalsh(Q).min() > -1e-9


def test_a_rectangle_at_heading_zero_has_the_closed_form():
    """One body at heading 0, corners c = (a, b): a corner moves by (dx - b dtheta, dy + a dtheta), so
    Q = [[1, 0, -mean b], [0, 1, mean a], [-mean b, mean a, mean(a^2 + b^2)]] (to 1e-8: the
    derivatives are central differences), and phi weighs the floor."""
    fp = Footprint.rectangle(4.0, 1.8, rear_overhang=0.8)
    robot = make_robot("rwd_car", footprint=fp)
    Q = footprint_weights(robot, np.zeros((1, 4)))[0]
    a, b = fp.vertices[:, 0], fp.vertices[:, 1]
    want = np.array([[1.0, 0.0, -b.mean(), 0.0], [0.0, 1.0, a.mean(), 0.0],
                     [-b.mean(), a.mean(), np.mean(a ** 2 + b ** 2), 0.0], [0.0, 0.0, 0.0, FOOTPRINT_FLOOR]])
    assert np.max(np.abs(Q - want)) < 1e-8


def test_a_disc_weighs_its_centre_and_the_heading_only_the_floor():
    robot = make_robot("unicycle", footprint=Footprint.disc(0.4))
    Q = footprint_weights(robot, np.array([[1.0, 2.0, 0.3], [0.0, 0.0, -2.0]]))
    assert np.max(np.abs(Q - np.diag([1.0, 1.0, FOOTPRINT_FLOOR]))) < 1e-8


def test_a_time_varying_Q_that_is_constant_is_the_diagonal_solve():
    """tvlqr_gains with Q given at every grid point and midpoint equals the diagonal form (1e-12)."""
    model = make_model("unicycle")
    t = np.linspace(0.0, 2 * math.pi, 501)
    nom = Nominal.from_inputs(model, lambda tt: np.stack([np.sin(tt), np.cos(tt)], -1), np.zeros(3), t)
    q, r = np.array([2.0, 1.0, 0.5]), np.ones(2)
    Qg = np.broadcast_to(np.diag(q), (len(t), 3, 3))
    assert np.max(np.abs(tvlqr_gains(nom, Qg, r, Q_mid=Qg[1:]) - tvlqr_gains(nom, q, r))) < 1e-12


def test_the_footprint_law_uses_the_robots_outline_and_needs_one():
    """build_law with q: footprint solves the Riccati equation with the outline's Q(t): the gains equal
    tvlqr_gains on footprint_weights at the grid and the midpoints; without a robot it is refused."""
    robot = make_robot("rwd_car")
    model = robot.model
    t = np.linspace(0.0, 8.0, 401)
    nom = Nominal.from_inputs(model, lambda tt: np.stack([np.ones_like(tt), 0.3 * np.cos(tt)], -1),
                              np.zeros(model.n), t)
    law = build_law(nom, ControllerOptions(kind="tvlqr", q="footprint"), {}, robot=robot)
    mid, _ = nom.at(0.5 * (t[1:] + t[:-1]))
    want = tvlqr_gains(nom, footprint_weights(robot, nom.x), np.ones(2), Q_mid=footprint_weights(robot, mid))
    assert np.array_equal(law.K, want)
    ident = build_law(nom, ControllerOptions(kind="tvlqr"), {}, robot=robot)
    assert not np.allclose(law.K, ident.K)
    with pytest.raises(InputError, match="controller.q"):
        build_law(nom, ControllerOptions(kind="tvlqr", q="footprint"), {})


def test_the_config_takes_footprint_and_refuses_other_words(tmp_path):
    good = tmp_path / "good.yaml"
    good.write_text("controller: {kind: tvlqr, q: footprint}\n")
    _, opts = load_run_config(good)
    assert opts.controller.q == "footprint"
    assert opts.controller.validated(4, 2).describe(4, 2, {})["Q"].startswith("footprint")
    with pytest.raises(InputError, match=r"'controller.q' must be 4 positive finite numbers \(a diagonal\) or "
                                         r"'footprint'; got 'footprnt'"):
        ControllerOptions(kind="tvlqr", q="footprnt").validated(4, 2)


def test_the_trailer_sweep_takes_tvlqr_q():
    base = {"cases": ["trailer_turn_150"], "noise": [1.0], "trials": 2}
    settings = TS.check_sweep_config({**base, "tvlqr_q": ["identity", "footprint"]})
    labels = [TS.law_label(law) for law in TS.laws(settings, {"alpha": 0.02, "delta": 15.0, "gamma": 2.0,
                                                              "end_strategy": "frozen"})]
    assert labels == ["tvlqr", "tvlqr q=footprint", "gramian a=0.02 d=15 g=2 frozen"]
    assert TS.check_sweep_config(base)["tvlqr_q"] == ["identity"]
    with pytest.raises(InputError, match=r"'tvlqr_q\[1\]' must be one of identity, footprint"):
        TS.check_sweep_config({**base, "tvlqr_q": ["identity", "diag"]})
    with pytest.raises(InputError, match="'tvlqr_q' must be each value once"):
        TS.check_sweep_config({**base, "tvlqr_q": ["footprint", "footprint"]})


def test_nhstab_run_takes_tvlqr_q_with_the_tvlqr_controller_only():
    """--tvlqr-q footprint sets controller.q (the effective config says so); with another controller it is
    refused in one line, exit code 2, nothing run."""
    from click.testing import CliRunner
    from nhstab.cli.main import cli

    res = CliRunner().invoke(cli, ["run", "example:parallel_rwd_car_100", "--controller", "tvlqr", "--tvlqr-q",
                                   "footprint", "--print-config"])
    assert res.exit_code == 0, res.output
    assert "  kind: tvlqr\n" in res.output and "  q: footprint\n" in res.output
    res = CliRunner().invoke(cli, ["run", "example:parallel_rwd_car_100", "--tvlqr-q", "footprint", "--print-config"])
    assert res.exit_code == 2 and "'--tvlqr-q' must be given with the tvlqr controller" in res.output
    assert "Traceback" not in res.output
