"""Error tubes in use: plan.json / run.json records, --margin auto, --gains auto, the batch report's
coverage, the study and the benchmark (each checked against an independent computation)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from clitools import only_line
from nhstab.batch.report import cell_table, wilson
from nhstab.cli.main import cli
from nhstab.collision import CollisionWorld
from nhstab.errors import InputError
from nhstab.execution import ControllerOptions, RunOptions, execute, summary
from nhstab.execution.config import NoiseOptions, PlanningOptions, options_from_mapping
from nhstab.maps import load_map
from nhstab.planning import PathOptions, TimingOptions
from nhstab.records import read_json
from nhstab.robot import default_robot
from nhstab.tubes.fit import plan_and_tube


@pytest.fixture(scope="module")
def room():
    return load_map("example:cluttered_room")


def test_margin_auto_certifies_the_plan_it_keeps(room):
    """plan_and_tube(margin="auto") on the cluttered room: the kept margin is below the unicycle's
    hand-set 0.1 m, and the certified clearance, recomputed by measuring every sample with FCL,
    is >= 0 and equals the reported one (1e-12)."""
    robot = default_robot("unicycle")
    fp = robot.footprint
    result, law, tube, extra = plan_and_tube(room, robot, room.start.as_array(), room.goal.as_array(),
                                             PathOptions(turning_radius=0.5, seed=1), TimingOptions(),
                                             margin="auto", noise=NoiseOptions(scale=1.0))
    rec = extra["margin_auto"]
    assert rec["certified"] and rec["margin_m"] < 0.1, rec["message"]
    world = CollisionWorld.from_map(room, "known")
    brute = min(world.clearance(p, fp) - r for p, r in zip(tube.poses, tube.reach))
    if tube.kind == "linear":
        assert brute >= 0.0
        assert tube.certified_clearance == pytest.approx(brute, abs=1e-12)
    else:           # the rollouts' own clearance (tests/tubes/test_sampled_tube.py), at least the grown footprint's
        grown = tube.info["rollout_clearance"]["grown_footprint_clearance_m"]
        assert grown == pytest.approx(brute, abs=1e-12) and tube.certified_clearance >= max(grown, 0.0)
    # the plan keeps the chosen margin (the planner's own re-check)
    assert result.metrics["min_clearance_m"] >= rec["margin_m"] - 1e-9


def test_plan_cli_writes_the_tube(tmp_path, room):
    res = CliRunner().invoke(cli, ["plan", "example:cluttered_room", "--seed", "1", "--margin", "auto",
                                   "--headroom", "0.8", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "margin auto: certified at margin" in res.output and "certified clear by" in res.output
    doc = json.loads((tmp_path / "plan.json").read_text())
    tube = doc["tube"]
    # the tube line names its kind, and plan.json records it with its certificate and verdict
    assert f"tube (p = 0.997, {tube['kind']}" in res.output
    assert tube["certificate"]["kind"] == tube["kind"] and tube["verdict"]["certified"] is True
    assert tube["verdict"]["tightest"]["time_s"] == tube["certified_clearance_time_s"]
    for key in ("probability", "max_position_radius_m", "max_heading_spread_rad", "certified_clearance_m",
                "saturation_probability"):
        assert key in tube
    assert tube["probability"] == 0.997 and tube["certified_clearance_m"] >= 0
    assert doc["margin_auto"]["certified"] and doc["inputs"]["path_options"]["margin"] == doc["margin_auto"]["margin_m"]
    arrays = np.load(tmp_path / "tube.npz")
    assert arrays["reach"].max() == pytest.approx(tube["max_reach_m"])
    assert (tmp_path / "plan.png").stat().st_size > 10_000


@pytest.mark.parametrize("margin", ["0.1", "auto"])
def test_plan_cli_writes_the_plan_when_its_tube_diverges(tmp_path, margin):
    """A robot whose gains destabilise the sampled loop (the unicycle with alpha 20: gains of 2e6): the
    plan is still written (trajectory, plan.json with tube_error; no tube.npz), one line on stderr says
    why, exit code 1; with --margin auto the plan is kept at the first margin, not certified."""
    robot = tmp_path / "robot.yaml"
    robot.write_text("model: unicycle\nstabilizer: {alpha: 20, delta: 2.0, gamma: 1.0}\n")
    out = tmp_path / "o"
    res = CliRunner().invoke(cli, ["plan", "example:cluttered_room", "--robot-config", str(robot), "--seed", "1",
                                   "--margin", margin, "--tube", "linear", "--no-figure", "--out", str(out)])
    only_line(res, 1, "no tube", "diverges")
    doc = json.loads((out / "plan.json").read_text())
    assert "tube" not in doc and "diverges" in doc["tube_error"]
    assert (out / "trajectory.csv").exists() and not (out / "tube.npz").exists()
    if margin == "auto":
        rec = doc["margin_auto"]
        assert not rec["certified"] and rec["margin_m"] == 0.02 and "no tube" in rec["message"]
        assert doc["inputs"]["path_options"]["margin"] == 0.02


@pytest.mark.slow
def test_where_the_linearised_loop_diverges_the_sampled_tube_shows_the_saturated_loop(tmp_path):
    """The same robot with the default tube (auto): the linearised loop diverges, but the loop that runs
    clips its inputs and stays bounded; the sampled tube says what it does, and why it was used."""
    robot = tmp_path / "robot.yaml"
    robot.write_text("model: unicycle\nstabilizer: {alpha: 20, delta: 2.0, gamma: 1.0}\n")
    out = tmp_path / "o"
    res = CliRunner().invoke(cli, ["plan", "example:cluttered_room", "--robot-config", str(robot), "--seed", "1",
                                   "--no-figure", "--out", str(out)])
    assert res.exit_code == 0, res.output
    tube = json.loads((out / "plan.json").read_text())["tube"]
    assert tube["kind"] == "sampled" and "diverges" in tube["certificate"]["why"]
    assert tube["saturation_probability"] == 1.0            # every rollout chatters at its limits
    assert math.isfinite(tube["max_reach_m"]) and (out / "tube.npz").exists()


def test_a_large_noise_is_a_large_tube_not_a_divergent_one(room):
    """The covariance grows as the square of the noise: at x1000 (the largest scale,
    nhstab.limits.MAX_NOISE_SCALE) the tube is 1000 times wider (1e-9), where an absolute bound on the
    covariance used to call the loop divergent."""
    robot = default_robot("unicycle")
    args = (room, robot, room.start.as_array(), room.goal.as_array(), PathOptions(turning_radius=0.5, seed=1),
            TimingOptions())
    one = plan_and_tube(*args, margin=0.1, noise=NoiseOptions(scale=1.0, impulses=()), tube_kind="linear")[2]
    big = plan_and_tube(*args, margin=0.1, noise=NoiseOptions(scale=1e3, impulses=()), tube_kind="linear")[2]
    np.testing.assert_allclose(big.cov, 1e6 * one.cov, rtol=1e-9, atol=0)
    assert big.certified_clearance < -10.0


@pytest.mark.parametrize("args,needles", [
    (["--margin", "wide"], ["'--margin'", "auto", "wide"]),
    (["--margin", "-1"], ["'--margin'"]),
    (["--gains", "best"], ["'--gains'", "best"]),
    (["--probability", "1.5"], ["'--probability'"]),
    (["--headroom", "0"], ["'--headroom'"]),
])
def test_plan_cli_refuses_bad_tube_options(tmp_path, args, needles):
    only_line(CliRunner().invoke(cli, ["plan", "example:cluttered_room", "--out", str(tmp_path / "o"), *args]), 2,
              *needles)
    assert not (tmp_path / "o").exists()


def test_run_config_margin_and_gains_are_checked():
    opts = options_from_mapping({"planning": {"margin": "auto"}, "controller": {"gains": "auto"}})
    assert opts.validated(("x", "y", "theta"), 2).planning.margin == "auto"
    with pytest.raises(InputError, match="planning.margin"):
        options_from_mapping({"planning": {"margin": "wide"}}).validated(("x", "y", "theta"), 2)
    with pytest.raises(InputError, match="controller.gains"):
        options_from_mapping({"controller": {"gains": "best"}}).validated(("x", "y", "theta"), 2)
    with pytest.raises(InputError, match="controller.gains"):
        options_from_mapping({"controller": {"kind": "tvlqr", "gains": "auto"}}).validated(("x", "y", "theta"), 2)


@pytest.fixture(scope="module")
def auto_run(room):
    opts = RunOptions(seed=3, planning=PlanningOptions(margin="auto"), controller=ControllerOptions(gains="auto"))
    return execute(room, default_robot("unicycle"), room.start.as_array(), room.goal.as_array(), opts)


def test_run_with_margin_and_gains_auto_records_what_it_chose(auto_run):
    """Every plan of the run has a tube and the records of both choices; the margin of each plan is the
    one its auto record kept; the gains the law uses are the ones the gains record chose; run.json's
    top-level tube is the first plan's, with the observed coverage of this run's own samples."""
    s = summary(auto_run)
    assert s["tube"] == s["plans"][0]["tube"] and "observed" in s["tube"]
    obs = s["tube"]["observed"]
    # one run's coverage is not a property of the tube (the study measures coverage over 200 trials per
    # cell); this seed draws an initial error near the tail whose correction saturates the inputs, the
    # regime where the linear prediction is known to be optimistic (docs/guide/tubes.md). It must be a
    # fraction, recomputed exactly from the log below.
    assert 0.0 <= obs["inside_tube"] <= 1.0 and obs["samples"] > 100
    for rec, entry in zip(auto_run.plans, s["plans"]):
        if rec.law is None:
            continue
        attempt = rec.attempts[-1]
        assert rec.margin == attempt["margin_auto"]["margin_m"] == entry["margin_m"]
        chosen = attempt["gains_auto"]["chosen"]
        opts = rec.law.schedule.options
        assert (opts.alpha, opts.delta, opts.gamma) == (chosen["alpha"], chosen["delta"], chosen["gamma"])
        assert entry["tube"]["saturation_probability"] <= 1.0
    assert s["clearance"]["margin_m"] == auto_run.plans[0].margin
    # the observed coverage, recomputed from the log
    tube = auto_run.plans[0].tube
    lg = auto_run.log
    sel = np.flatnonzero((lg["plan_id"] == 0) & (lg["mode"] == 0))
    e = np.zeros((len(tube.t), 3))
    k = np.rint(lg["t"][sel] / 0.02).astype(int)
    e[k] = auto_run.model.state_error(lg["x"][sel], lg["x0"][sel])
    assert obs["inside_tube"] == pytest.approx(tube.inside(e)[1][k].mean(), abs=1e-12)


def test_run_cli_margin_auto_writes_tube_and_says_so(tmp_path):
    res = CliRunner().invoke(cli, ["run", "example:cluttered_room", "--margin", "auto", "--seed", "1",
                                   "--max-time", "3", "--out", str(tmp_path)])
    assert res.exit_code in (0, 4), res.output
    assert "plan 0: margin auto:" in res.output and "plan 0 tube" in res.output
    doc = json.loads((tmp_path / "run.json").read_text())
    assert doc["tube"]["probability"] == 0.997 and doc["inputs"]["options"]["planning"]["margin"] == "auto"
    only_line(CliRunner().invoke(cli, ["run", "example:cluttered_room", "--margin", "x", "--out",
                                       str(tmp_path / "o")]), 2, "'--margin'")


def test_batch_report_coverage_pools_samples_with_wilson():
    """Two trials with 100 and 300 tube samples, 99 % and 100 % inside: pooled 399/400, Wilson."""
    def trial(k, n, inside):
        return {"id": f"c#{k}", "cell": "c", "trial": k, "status": "reached", "spec": {"cell_spec": {
            "map": "m", "robot": "unicycle", "controller": "gramian", "alpha": None, "delta": None, "gamma": None,
            "noise": 1.0}}, "metrics": {"robot": "unicycle", "tube_samples": n, "tube_inside": inside,
                                        "tube_inside_state": inside, "tube_probability": 0.997,
                                        "tube_certified_clearance_m": 0.01, "tube_saturation_probability": 0.0}}
    row = cell_table([trial(0, 100, 0.99), trial(1, 300, 1.0)])[0]
    rate, lo, hi = wilson(399, 400)
    assert row["tube_samples"] == 400
    assert (row["tube_inside_rate"], row["tube_inside_lo"], row["tube_inside_hi"]) == (rate, lo, hi)
    assert row["tube_inside_min_trial"] == 0.99


def test_tube_study_machinery_on_one_case(tmp_path):
    """The study on one case with 30 trials: every cell has coverages, std ratios with bootstrap
    intervals, saturation and collision counts; the files are written."""
    from nhstab.batch.tube_study import write_study

    files = write_study(tmp_path, trials=30, root_seed=5, gains=False, cases=(("unicycle", "cluttered_room"),))
    doc = read_json(tmp_path / "study.json.gz")
    cells = doc["cases"][0]["cells"]
    assert len(cells) == 6 and {c["controller"] for c in cells} == {"gramian", "tvlqr"}
    for c in cells:
        assert 0.9 < c["coverage_tube"]["rate"] <= 1.0 and c["completed"] == 30
        for name, (lo, hi) in c["std_ratio_bootstrap95"].items():
            assert lo <= c["std_ratio"][name] <= hi
    assert (tmp_path / "study.md").read_text().startswith("# Error tubes")
    assert len(files) == 5


@pytest.mark.slow
def test_bench_tube_agrees_with_its_baseline():
    from nhstab.bench.tube import bench_tube

    b = bench_tube(scenarios=("cluttered_room",), repeats=3, cases=None, auto_repeats=1)
    row = b["rows"][0]
    assert b["met"]["baseline_agrees"] and row["samples"] > 100
    # the target's ratio: the median over the pairs (a plan, then its tube) of their ratio, from the times kept
    assert row["tube_over_plan"] == pytest.approx(
        float(np.median(np.array(row["tube_times_s"]) / np.array(row["plan_times_s"]))), rel=1e-12)
    assert row["tube_over_plan_best"] == pytest.approx(min(row["tube_times_s"]) / min(row["plan_times_s"]))
    # every part of the tube timed on its own (no timing asserted: the machine is shared)
    parts = b["rows"][0]["parts_best_s"]
    assert set(parts) == {"schedule", "plant_derivatives", "covariance", "saturation", "spatial",
                          "certified_clearance"} and all(v >= 0.0 for v in parts.values())


def test_monitor_with_margin_auto_asks_a_new_obstacle_to_clear_the_tube(room):
    """A small disc seen after planning, beside the nominal at 30 % of it, at a gap inside the tube's
    reach there but outside a fixed 0.02 m margin: with margin auto the monitor finds the conflict,
    with the fixed 0.02 m margin it does not."""
    from nhstab.execution.runner import CompositeRun, PlanRecord
    from nhstab.maps.base import Circle

    found, gap = {}, None
    for margin in ("auto", 0.02):
        run = CompositeRun(room, default_robot("unicycle"), room.start.as_array(), room.goal.as_array(),
                           RunOptions(seed=0, planning=PlanningOptions(margin=margin)))
        attempt, result, law, used, tube = run._plan_once(run.start[:3])
        rec = PlanRecord(0, "initial", 0.0, 0.0, run.start[:3], attempt["seed"], used, [attempt], result, law,
                         tube=tube)
        k = int(0.3 * len(law.nominal.t))
        x, y, th = law.nominal.x[k][:3]
        if gap is None:
            reach = float(np.interp(law.nominal.t[k] - law.nominal.t[0], tube.t, tube.reach))
            assert reach > 0.04          # room for a gap between the fixed margin and the tube's reach
            gap = 0.5 * (reach + 0.02)
        centre = (x - np.sin(th) * (0.3 + gap + 0.05), y + np.cos(th) * (0.3 + gap + 0.05))
        shape = Circle(centre, 0.05)
        run.discovered = [{"index": 0, "time_s": 0.0, "pose": [x, y, th]}]
        run.discovered_world = CollisionWorld([shape], walls=False)
        run.discovered_discs = [(np.asarray(centre), 0.05)]
        found[margin] = run._conflict(rec, 0.0)
    assert found["auto"] is not None and found["auto"]["tube_reach"]
    assert found["auto"]["clearance_m"] < found["auto"]["margin_m"]
    assert found[0.02] is None


def test_batch_report_tube_figure_mixes_robots():
    """Cells of a unicycle (3 states) and a car (4 states) in one figure (a regression)."""
    from nhstab.batch.report import tube_figure

    def trial(cell, names, k):
        n = len(names)
        return {"id": f"{cell}#{k}", "cell": cell, "trial": k, "status": "reached",
                "spec": {"cell_spec": {"map": cell, "robot": None, "controller": "gramian", "alpha": None,
                                       "delta": None, "gamma": None, "noise": 1.0}},
                "metrics": {}, "series": {"dt_s": 0.2, "state_names": names, "error_by_state": [[0.01] * n] * 5,
                                          "tube_mean": [[0.0] * n] * 5, "tube_std": [[0.02] * n] * 5}}

    trials = [trial("a", ["x", "y", "theta"], k) for k in range(3)] + \
        [trial("b", ["x", "y", "theta", "phi"], k) for k in range(3)]
    rows = [{"cell": c, "map": c, "controller": "gramian", "alpha": None, "delta": None, "gamma": None, "noise": 1.0}
            for c in ("a", "b")]
    fig = tube_figure(trials, rows)
    assert fig is not None and sum(ax.get_visible() for ax in fig.axes) == 7


def test_tubes_redraw_draws_the_recorded_plans_and_leaves_the_others(tmp_path):
    """``nhstab tubes redraw``: the committed study's warehouse case planned again is the plan and tube
    study.json.gz records (to 1e-9), so its plan figure is drawn and study.md is rendered from the record; the
    same case recorded 1 m longer (in an uncompressed study.json, as an earlier nhstab wrote it) is left, with a
    line naming the figure, the length and the file, and not drawn."""
    from pathlib import Path

    from nhstab.batch.tube_study import study_markdown
    from nhstab.records import read_json, record_file, write_json_gz
    from PIL import Image

    root = Path(__file__).resolve().parents[2]
    doc = read_json(record_file(root / "results/tubes", "study.json"))
    doc["cases"] = [c for c in doc["cases"] if c["map"] == "warehouse_aisle_a2"]
    doc.pop("gains")
    wrong = json.loads(json.dumps(doc))
    wrong["cases"][0]["plan"]["length_m"] += 1.0
    name = "plan_rwd_car_warehouse_aisle_a2.png"
    write_json_gz(tmp_path / "same" / "study.json.gz", doc, indent=2)                 # as nhstab tubes study writes
    (tmp_path / "wrong").mkdir()
    (tmp_path / "wrong" / "study.json").write_text(json.dumps(wrong))                 # uncompressed: read too
    res = CliRunner().invoke(cli, ["tubes", "redraw", str(tmp_path / "same")])
    assert res.exit_code == 0, res.output
    with Image.open(tmp_path / "same" / name) as img, Image.open(root / "results/tubes" / name) as committed:
        assert img.size == committed.size
    assert (tmp_path / "same" / "study.md").read_text() == study_markdown(doc)
    res = CliRunner().invoke(cli, ["tubes", "redraw", str(tmp_path / "wrong")])
    assert res.exit_code == 1, res.output
    left = [ln for ln in res.stderr.splitlines() if " left: " in ln]
    assert len(left) == 1 and left[0].startswith(name) and "length_m" in left[0] and "(study.json: " in left[0]
    assert not (tmp_path / "wrong" / name).exists() and (tmp_path / "wrong" / "study.md").exists()
