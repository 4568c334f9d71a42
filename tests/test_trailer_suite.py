"""The trailer suite: the swept-path estimate against the model's own steady turn measured with shapely,
the generated maps against their stated geometry, the commands that make and measure them, and the
sweep config's errors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab import trailer_suite as T
from nhstab.batch import trailer_study as TS
from nhstab.cli.main import cli
from nhstab.errors import InputError
from nhstab.examples import list_examples
from nhstab.maps import load_map
from nhstab.records import read_json
from nhstab.robot import robot_from_spec

shapely = pytest.importorskip("shapely")
from shapely.geometry import Point  # noqa: E402
from shapely.geometry import Polygon as SPolygon  # noqa: E402
from shapely.ops import unary_union  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FOLDER = ROOT / "maps" / "trailer" / "suite"


def _rig(spec: dict):
    """(L, d, (a0, b0, w0), (a1, b1, w1)) of a rig description, read directly (not through RigGeometry)."""
    def rect(r):
        r = r["rectangle"]
        return r["length"] - r["rear_overhang"], r["rear_overhang"], r["width"]
    return spec["wheelbase"], spec["hitch_lengths"][0], rect(spec["footprint"]), rect(spec["trailer_footprint"])


def _bodies(spec: dict, pose, theta1=None) -> list:
    """The car's and the trailer's shapely rectangles with the car's rear axle at ``pose`` (trailer straight
    behind unless ``theta1`` is given), by hand: the trailer's axle d behind the hitch along theta1."""
    L, d, (a0, b0, w0), (a1, b1, w1) = _rig(spec)
    x, y, th = pose
    th1 = th if theta1 is None else theta1
    out = []
    for (px, py, h), (a, b, w) in (((x, y, th), (a0, b0, w0)),
                                   ((x - d * math.cos(th1), y - d * math.sin(th1), th1), (a1, b1, w1))):
        local = np.array([[-b, -w / 2], [a, -w / 2], [a, w / 2], [-b, w / 2]])
        c, s = math.cos(h), math.sin(h)
        out.append(SPolygon(local @ np.array([[c, s], [-s, c]]) + [px, py]))
    return out


# ---- the swept-path estimate ------------------------------------------------------------------------------

def test_the_default_rig_sweeps_4_44_m_at_its_physical_minimum_turn():
    g = T.rig_geometry()
    L, d = 2.5, 3.0
    r0 = L / math.tan(0.6)                         # the steering limit binds: atan(d / R1) = 0.963 < 1.0 rad
    r1 = math.sqrt(r0 ** 2 - d ** 2)
    assert g.steady_turn()[:2] == pytest.approx((r0, r1), abs=1e-12)
    assert r1 == pytest.approx(robot_from_spec(T.rig_spec()).model.min_turning_radius, abs=1e-12)
    # the car's outer front corner (3.3 m ahead of its axle) and the trailer's inner side at its axle
    assert g.swept_radii() == pytest.approx((r1 - 0.9, math.hypot(r0 + 0.9, 3.3)), abs=1e-12)
    assert round(g.swept_path(), 2) == 4.44
    assert g.width == 1.8 and g.length == pytest.approx(7.3)


def _steady_turn_sweep(spec: dict, steps: int = 1440):
    """Integrate the model (RK4) on its tightest steady turn for a full circle from the steady hitch
    angle, and measure the union of the bodies with shapely: (r_in, r_out, largest hitch-angle drift)."""
    robot = robot_from_spec(spec)
    model = robot.model
    L, d = spec["wheelbase"], spec["hitch_lengths"][0]
    r1 = model.min_turning_radius                  # the model's own smallest steady turn of the trailer's axle
    r0 = math.hypot(r1, d)
    phi = math.atan(L / r0)
    x = np.array([0.0, 0.0, 0.0, phi, -math.atan2(d, r1)])
    T_circle = 2 * math.pi * r0                    # v = 1 m/s
    dt = T_circle / steps
    u = np.array([1.0, 0.0])
    states = [x]
    for _ in range(steps):
        k1 = model.rhs(x, u)
        k2 = model.rhs(x + dt / 2 * k1, u)
        k3 = model.rhs(x + dt / 2 * k2, u)
        k4 = model.rhs(x + dt * k3, u)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        states.append(x)
    states = np.array(states)
    poses = robot.body_poses(states)
    polys = [SPolygon(fp.outline_at(poses[k, b])) for k in range(len(states)) for b, fp in enumerate(robot.footprints)]
    swept = unary_union(polys)
    centre = poses[:-1, 0, :2].mean(axis=0)        # the car's axle, sampled evenly over one circle
    ring = np.vstack([np.asarray(p.exterior.coords) for p in polys])
    r_out = float(np.hypot(*(ring - centre).T).max())
    r_in = float(Point(centre).distance(swept))
    drift = float(np.abs(model.hitch_angles(states) - model.hitch_angles(states[0])).max())
    return r_in, r_out, drift


@pytest.mark.parametrize("rig", ["default", "jackknife_binds", "long_trailer"])
def test_swept_path_formula_equals_the_models_steady_turn_measured_with_shapely(rig):
    spec = T.rig_spec()
    if rig == "jackknife_binds":       # atan(d / R1) <= 0.8 binds before the steering limit
        spec = {**spec, "jackknife_limit": 0.8}
    elif rig == "long_trailer":         # the trailer's rear corner reaches out farther than the car's front
        spec = {**spec, "hitch_lengths": [4.0],
                "trailer_footprint": {"rectangle": {"length": 8.5, "width": 2.2, "rear_overhang": 6.0}}}
    g = T.rig_geometry(spec)
    r_in, r_out, drift = _steady_turn_sweep(spec)
    assert drift < 1e-9                                   # the steady turn is steady: the hitch angle stays
    # every body keeps its distance to the centre on a steady turn, so the sampled union meets both radii
    assert (r_in, r_out) == pytest.approx(g.swept_radii(), abs=1e-6)
    assert r_out - r_in == pytest.approx(g.swept_path(), abs=2e-6)
    if rig == "jackknife_binds":
        assert g.steady_turn()[2] == pytest.approx(0.8, abs=1e-12)
    if rig == "long_trailer":
        r0, r1, _ = g.steady_turn()
        assert g.swept_radii()[1] == pytest.approx(math.hypot(r1 + 1.1, 6.0), abs=1e-12)
        assert math.hypot(r1 + 1.1, 6.0) > math.hypot(r0 + 0.9, 3.3)


def test_a_rig_the_suite_cannot_size_is_refused():
    with pytest.raises(InputError, match="trailer_footprint"):
        T.rig_geometry({**T.rig_spec(), "trailer_footprint": {"radius": 1.0}})
    with pytest.raises(InputError, match="car_trailer with one trailer"):
        T.rig_geometry({**T.rig_spec(), "hitch_lengths": [3.0, 2.0]})
    with pytest.raises(InputError, match="car_trailer"):
        T.rig_geometry({"model": "rwd_car"})


# ---- the generated maps ----------------------------------------------------------------------------------

def test_committed_folder_is_what_the_command_writes(tmp_path):
    assert T.write_suite(FOLDER, check=True) == {"differ": [], "missing": [], "extra": []}
    res = CliRunner().invoke(cli, ["trailer", "suite", "--check", "--out", str(FOLDER)])
    assert res.exit_code == 0 and "up to date" in res.output
    out = tmp_path / "suite"
    res = CliRunner().invoke(cli, ["trailer", "suite", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in FOLDER.iterdir())
    (out / "trailer_turn_150.yaml").write_text("name: changed\n")
    res = CliRunner().invoke(cli, ["trailer", "suite", "--check", "--out", str(out)])
    assert res.exit_code == 1 and "trailer_turn_150.yaml" in res.output


def test_the_suite_covers_the_factors_and_its_maps_are_examples():
    rows = TS.suite_rows()
    docks = {(r["bay_factor"], r["aisle_factor"]) for r in rows if r["kind"] == "dock"}
    assert docks == {(b, a) for b in (1.1, 1.2, 1.3, 1.5) for a in (1.2, 1.5, 2.0)}
    assert sorted(r["aisle_factor"] for r in rows if r["kind"] == "turn") == [1.2, 1.5, 2.0]
    names = {e.name for e in list_examples()}
    assert {r["name"] for r in rows} <= names


def _obstacles(m):
    return [SPolygon(o.vertices) for o in m.obstacles]


@pytest.mark.parametrize("name", [r["name"] for r in TS.suite_rows()])
def test_case_geometry(name):
    """Bay and aisle equal their factors times W and S (1e-9 m, measured between the obstacles with
    shapely), and no obstacle comes within the margin of the start's or the goal's rig."""
    m = load_map(FOLDER / f"{name}.yaml")
    row = {r["name"]: r for r in T.read_suite_csv(FOLDER / "suite.csv")}[name]
    spec = m.robot
    L, d, (a0, b0, w0), (a1, b1, w1) = _rig(spec)
    W = max(w0, w1)
    r0 = L / math.tan(spec["max_steer"])
    r1 = math.sqrt(r0 ** 2 - d ** 2)
    S = math.hypot(r0 + w0 / 2, max(a0, b0)) - (r1 - w1 / 2)      # the default rig's case (module docstring)
    assert row["swept_m"] == pytest.approx(S, abs=1e-9) and row["width_m"] == W
    obstacles = _obstacles(m)
    labels = [line.split("#")[-1].strip() for line in (FOLDER / f"{name}.yaml").read_text().splitlines()
              if line.startswith("  - box:")]
    by = dict(zip(range(len(labels)), labels))
    if row["kind"] == "dock":
        left = unary_union([p for k, p in enumerate(obstacles) if by[k].startswith("parked at door -1")])
        right = unary_union([p for k, p in enumerate(obstacles) if by[k].startswith("parked at door +1")])
        assert left.distance(right) == pytest.approx(row["bay_factor"] * W, abs=1e-9)
        parked = unary_union([p for k, p in enumerate(obstacles) if by[k].startswith("parked")])
        across = next(p for k, p in enumerate(obstacles) if by[k] == "wall across the aisle")
        assert parked.distance(across) == pytest.approx(row["aisle_factor"] * S, abs=1e-9)
        # the goal sits in the free bay, centred between the neighbours, trailer to the dock wall
        goal_rig = unary_union(_bodies(spec, m.goal.as_array()))
        assert goal_rig.distance(left) == pytest.approx(goal_rig.distance(right), abs=1e-9)
        assert m.goal.theta == pytest.approx(-math.pi / 2)
    else:
        aisle_wall = next(p for k, p in enumerate(obstacles) if by[k] == "wall along the aisle")
        corridor_wall = next(p for k, p in enumerate(obstacles) if by[k] == "wall along the corridor")
        block = next(p for k, p in enumerate(obstacles) if by[k] == "inner corner block")
        assert aisle_wall.distance(block) == pytest.approx(row["aisle_factor"] * S, abs=1e-9)
        assert corridor_wall.distance(block) == pytest.approx(row["aisle_factor"] * S, abs=1e-9)
        assert m.goal.theta == pytest.approx(math.pi / 2) and m.start.theta == 0.0
    x0, y0, x1, y1 = m.bounds
    inside = SPolygon([(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
    for pose in (m.start.as_array(), m.goal.as_array()):
        for body in _bodies(spec, pose):
            assert inside.contains(body)
            assert min(body.distance(o) for o in obstacles) > spec["margin"]


# ---- the commands ------------------------------------------------------------------------------------------

def test_table_and_figure_commands_on_one_case(tmp_path):
    case = "trailer_turn_120"
    res = CliRunner().invoke(cli, ["trailer", "table", "--cases", case, "--seeds", "1", "--budget", "1",
                                   "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "table.json").read_text())
    (row,) = data["rows"]
    assert row["name"] == case and row["seeds"] == 1 and len(row["trials"]) == 1
    t = row["trials"][0]
    assert row["planned"] == int(t["ok_within_budget"])
    assert f"| {case} | turn |" in res.output and f"{row['planned']}/1" in res.output
    if not t["ok_within_budget"]:
        assert "## Why plans failed" in (tmp_path / "table.md").read_text()
    if t["status"] == "no_path":            # the search found nothing: the record says why, likely
        assert t["likely_cause"].startswith("likely cause: ") and t["likely_cause"] in (tmp_path / "table.md").read_text()
    png = tmp_path / "fig.png"
    res = CliRunner().invoke(cli, ["trailer", "figure", case, "--budget", "1", "--out", str(png)])
    assert res.exit_code in (0, 4), res.output
    if res.exit_code == 4 and "(no_path:" in res.output:
        assert res.output.splitlines()[-1].startswith("likely cause: ")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_table_says_whether_a_plan_can_exist_where_none_was_found(tmp_path):
    # the 1.1 W bay off the 1.2 S aisle plans with no budget, and its goal is closed (nhstab trailer reach):
    # the table says so; with --reach-budget 0 it does not ask
    case = "trailer_dock_bay110_aisle120"
    res = CliRunner().invoke(cli, ["trailer", "table", "--cases", case, "--seeds", "1", "--budget", "0.5",
                                   "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    (row,) = json.loads((tmp_path / "table.json").read_text())["rows"]
    assert row["planned"] == 0
    assert row["reach"]["verdict"] == "disconnected" and row["reach"]["closed_end"] == "goal"
    text = (tmp_path / "table.md").read_text()
    assert "## Can any plan exist where none was found?" in text and row["reach"]["text"] in text
    res = CliRunner().invoke(cli, ["trailer", "table", "--cases", case, "--seeds", "1", "--budget", "0.5",
                                   "--reach-budget", "0", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "reach" not in json.loads((tmp_path / "table.json").read_text())["rows"][0]


def test_commands_refuse_bad_input_naming_the_option():
    for args, key in ((["table", "--cases", "nope"], "--cases[0]"), (["figure", "nope"], "CASE"),
                      (["table", "--seeds", "0"], "--seeds"), (["table", "--budget", "0"], "--budget"),
                      (["table", "--reach-budget", "-1"], "--reach-budget"),
                      # refused before any plan (the reach search's own range), not after the table's plans
                      (["table", "--reach-budget", "1e300"], "--reach-budget"),
                      (["figure", "trailer_turn_120", "--budget", "-1"], "--budget"),
                      (["figure", "trailer_turn_120", "--seed", "-1"], "--seed")):
        res = CliRunner().invoke(cli, ["trailer", *args])
        assert res.exit_code == 2 and f"'{key}'" in res.output, res.output
    # the library refuses it before planning too (a plan would take seconds; this returns at once)
    for bad in (1e300, -1.0, math.nan):
        with pytest.raises(InputError) as err:
            TS.plan_table(["trailer_turn_120"], 1, 10.0, progress=lambda s: pytest.fail("planned: " + s),
                          reach_budget_s=bad)
        assert err.value.argument == "reach_budget"


# ---- the sweep config -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("config, key", [
    ({"trails": 5}, "trails"),
    ({"cases": ["trailer_turn_120", "nope"]}, "cases[1]"),
    ({"cases": ["trailer_turn_120", "trailer_turn_120"]}, "cases[1]"),
    ({"trials": 0}, "trials"),
    ({"noise": [1.0, 0.0]}, "noise[1]"),
    ({"noise": []}, "noise"),
    ({"tvlqr": "yes"}, "tvlqr"),
    ({"tube": 1}, "tube"),
    ({"process_per": "hour"}, "process_per"),
    ({"time_limit_s": 0}, "time_limit_s"),
    ({"gramian": {"alpha": [0.05, -1]}}, "gramian.alpha[1]"),
    ({"gramian": {"delta": ["ten"]}}, "gramian.delta[0]"),
    ({"gramian": {"gamma": [0.2]}}, "gramian.gamma[0]"),
    ({"gramian": {"end_strategy": ["frozen", "switch"]}}, "gramian.end_strategy[1]"),
    ({"gramian": {"window": ["future"]}}, "gramian.window"),
    ({"gramian": [0.1]}, "gramian"),
    ({"trials": 5000, "gramian": {"alpha": [0.01, 0.02, 0.05, 0.1, 0.2], "delta": [2.0, 5.0, 10.0, 15.0, 20.0]}},
     "trials"),
])
def test_sweep_config_errors_name_the_key(config, key):
    with pytest.raises(InputError) as err:
        TS.check_sweep_config(config)
    assert err.value.argument == key


def test_sweep_config_defaults_and_laws():
    s = TS.check_sweep_config({"gramian": {"alpha": [0.02, 0.05], "end_strategy": ["frozen", "extend"]}})
    assert s["cases"] == [r["name"] for r in TS.suite_rows()] and s["noise"] == [0.5, 1.0, 2.0] and s["trials"] == 50
    assert s["process_per"] == "second" and TS.check_sweep_config({"process_per": "metre"})["process_per"] == "metre"
    defaults = robot_from_spec(T.rig_spec()).stabilizer.as_dict()
    laws = TS.laws(s, defaults)
    assert laws[0] == {"controller": "tvlqr"} and len(laws) == 1 + 2 * 2
    assert {(w["alpha"], w["delta"], w["gamma"], w["end_strategy"]) for w in laws[1:]} == {
        (a, defaults["delta"], defaults["gamma"], e) for a in (0.02, 0.05) for e in ("frozen", "extend")}


def test_sweep_command_refuses_a_bad_config_naming_the_key(tmp_path):
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text("trials: 2\ngramian:\n  delta: [10, -1]\n")
    res = CliRunner().invoke(cli, ["trailer", "sweep", str(cfg), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and "gramian.delta[1]" in res.output
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_sweep_trials_are_judged_as_shapely_and_the_hitch_angles_say():
    """A sweep cell on the bundled loading dock (which plans with today's planner): each trial's outcome
    recomputed from its states by hand (hitch angle theta - theta1 against the limit, both bodies against
    the obstacles with shapely, the trailer's axle and heading at the end against the goal's)."""
    from dataclasses import replace

    from nhstab.batch.parking_study import first_plan
    from nhstab.batch.tube_study import trial_seeds
    from nhstab.batch.vector import simulate_shared
    from nhstab.execution import RunOptions

    run, _, result, law0, _, _ = first_plan("loading_dock", RunOptions(seed=0))
    assert law0 is not None
    law = TS.build_sweep_law(run, result, {"controller": "gramian", "alpha": 0.05, "delta": 10.0, "gamma": 1.0,
                                           "end_strategy": "extend"})
    assert law.schedule.options.end_strategy == "extend"
    seeds = trial_seeds(4, 2026)
    noise = replace(run.opts.noise, scale=2.0)
    out = TS.trial_outcomes(run, law, seeds, noise)
    sim = simulate_shared(law, seeds, noise, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps, model=run.model)
    m = load_map("example:loading_dock")
    obstacles = unary_union([SPolygon(o.vertices) if hasattr(o, "vertices") else Point(o.center).buffer(o.radius, 64)
                             for o in m.obstacles])
    spec = {**T.rig_spec(), "margin": 0.3}
    d = spec["hitch_lengths"][0]
    g = m.goal.as_array()
    goal_axle = g[:2] - d * np.array([math.cos(g[2]), math.sin(g[2])])
    want = []
    for i in range(len(seeds)):
        x = sim.x[i]
        outcome = None
        for k in range(len(x)):
            hitch = math.remainder(x[k, 2] - x[k, 4], 2 * math.pi)
            if abs(hitch) > 1.0:
                outcome = "jackknife"
                break
            if any(b.intersects(obstacles) for b in _bodies(spec, x[k, :3], x[k, 4])):
                outcome = "collision"
                break
        if outcome is None:
            xf = sim.x_final[i]
            axle = xf[:2] - d * np.array([math.cos(xf[4]), math.sin(xf[4])])
            ok = np.hypot(*(axle - goal_axle)) <= 0.3 and abs(math.remainder(xf[4] - g[2], 2 * math.pi)) <= 0.2
            outcome = "docked" if ok else "missed"
        want.append(outcome)
    assert out["per_trial"]["outcome"] == want
    assert sum(out[k] for k in ("docked", "jackknife", "collision", "missed", "diverged")) == len(seeds)


@pytest.mark.slow
def test_a_plan_record_and_figure_on_a_map_that_plans_today(tmp_path):
    """The table's record and the figure of a plan, on the bundled loading dock (the suite's cases need
    a search that turns tighter): the clearance is every body's, checked here with shapely."""
    fig, rec = TS.case_figure("loading_dock", 0, 10.0)
    assert rec["status"] == "ok"
    fig.savefig(tmp_path / "dock.png")
    assert (tmp_path / "dock.png").read_bytes()[:4] == b"\x89PNG"
    rec, m, robot, res = TS.plan_case("loading_dock", 0, 10.0)
    assert rec["status"] == "ok" and rec["ok_within_budget"] == (rec["time_s"] <= 10.0)
    v = res.nominal.u[:, 0]
    s = np.sign(v[np.abs(v) > 1e-9])
    assert rec["cusps"] == int(np.count_nonzero(np.diff(s))) and (v < 0).any()     # the trailer backs into the dock
    x = res.nominal.x
    hitch = np.abs(np.remainder(x[:, 2] - x[:, 4] + np.pi, 2 * np.pi) - np.pi)
    assert rec["max_abs_hitch_rad"] == pytest.approx(hitch.max(), abs=1e-12)
    assert hitch.max() <= 1.0
    obstacles = unary_union([SPolygon(o.vertices) if hasattr(o, "vertices") else Point(o.center).buffer(o.radius, 256)
                             for o in m.obstacles])
    spec = T.rig_spec()
    by_hand = min(b.distance(obstacles) for k in range(0, len(x), 5) for b in _bodies(spec, x[k, :3], x[k, 4]))
    assert rec["min_clearance_m"] <= by_hand + 1e-3 and rec["min_clearance_m"] >= 0.3 - 1e-6   # the map's margin


def _sweep(tmp_path, config: str) -> tuple[dict, str]:
    """`nhstab trailer sweep` on the config text, into tmp_path/out: (sweep.json.gz, sweep.md)."""
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(config)
    res = CliRunner().invoke(cli, ["trailer", "sweep", str(cfg), "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    return read_json(tmp_path / "out" / "sweep.json.gz"), (tmp_path / "out" / "sweep.md").read_text()


@pytest.mark.slow
def test_sweep_command_writes_its_report_whether_or_not_the_case_plans(tmp_path):
    data, md = _sweep(tmp_path, "cases: [trailer_dock_bay150_aisle200]\ntrials: 1\nnoise: [1.0]\ntvlqr: false\n"
                                "tube: true\ngramian: {end_strategy: [frozen]}\n")
    (case,) = data["cases"]
    assert data["cases_planned"] == int(case["plan"]["found"])
    if case["plan"]["found"]:
        (cell,) = case["cells"]
        assert cell["end_strategy"] == "frozen" and cell["trials"] == 1
        assert sum(cell[k] for k in ("docked", "jackknife", "collision", "missed", "diverged")) == 1
        # the cell's tube: the rig's sampled tube, certified exactly when its clearance is >= 0 and at most the
        # discarded rollouts jackknifed; listed among the certified cells of the report when it is
        tube = cell["tube"]
        assert tube["kind"] == "sampled" and tube["rollouts"] == 2097 and tube["discards"] == 2
        assert tube["certified"] == (tube["certified_clearance_m"] >= 0 and tube["jackknifes"] <= tube["discards"])
        assert "## Cells whose tube is certified" in md
        assert (f"- trailer_dock_bay150_aisle200, {TS.law_label(cell)}, x1: docked" in md) == tube["certified"]
    else:
        assert case["cells"] == [] and case["plan"]["reason"] in md and "no case planned" in md


@pytest.mark.slow
def test_a_setting_with_the_same_gains_is_run_once_and_says_so(tmp_path):
    """On a trailer plan the nominal carries its own continuation past its end, so the frozen and extend end
    strategies give the same gains bit for bit: the sweep runs that law once, the second setting's cells say
    whose they are, and they equal the trials of that law built and simulated here on its own. A setting with
    other gains (another alpha) is run."""
    data, md = _sweep(tmp_path, "cases: [trailer_turn_150]\ntrials: 3\nnoise: [1.0]\ntvlqr: false\n"
                                "gramian: {alpha: [0.05, 0.1], delta: [10.0], gamma: [1.0], end_strategy: [frozen, extend]}\n")
    (case,) = data["cases"]
    assert case["plan"]["found"]
    by = {TS.law_label(c): c for c in case["cells"]}
    assert set(by) == {f"gramian a={a} d=10 g=1 {e}" for a in ("0.05", "0.1") for e in ("frozen", "extend")}
    for a in ("0.05", "0.1"):
        frozen, extend = by[f"gramian a={a} d=10 g=1 frozen"], by[f"gramian a={a} d=10 g=1 extend"]
        assert "same_gains_as" not in frozen and extend["same_gains_as"] == TS.law_label(frozen)
        assert "per_trial" not in extend and extend["end_strategy"] == "extend"
        assert all(extend[k] == frozen[k] for k in ("docked", "jackknife", "collision", "missed", "diverged"))
        assert f"- trailer_turn_150: gramian a={a} d=10 g=1 extend = gramian a={a} d=10 g=1 frozen" in md
    assert "same_gains_as" not in by["gramian a=0.1 d=10 g=1 frozen"]      # other gains: run
    # the extend law on its own: its gains equal the frozen law's, and its trials are the cell's
    from dataclasses import replace

    from nhstab.batch.parking_study import first_plan
    from nhstab.batch.tube_study import trial_seeds
    from nhstab.execution import RunOptions
    from nhstab.execution.config import PlanningOptions

    run, _, result, _, _, _ = first_plan("trailer_turn_150", RunOptions(seed=0, planning=PlanningOptions(time_limit_s=2.0)))
    laws = {e: TS.build_sweep_law(run, result, {"controller": "gramian", "alpha": 0.05, "delta": 10.0, "gamma": 1.0,
                                                "end_strategy": e}) for e in ("frozen", "extend")}
    assert TS.same_gains(laws["frozen"], laws["extend"])
    assert laws["extend"].schedule.diagnostics["end"].startswith("none: every window fits")
    other = TS.build_sweep_law(run, result, {"controller": "gramian", "alpha": 0.1, "delta": 10.0, "gamma": 1.0,
                                             "end_strategy": "frozen"})
    assert not TS.same_gains(laws["frozen"], other)
    out = TS.trial_outcomes(run, laws["extend"], trial_seeds(3, 2026), replace(run.opts.noise, scale=1.0))
    assert out["per_trial"] == by["gramian a=0.05 d=10 g=1 frozen"]["per_trial"]
    assert all(out[k] == by["gramian a=0.05 d=10 g=1 extend"][k] for k in ("docked", "jackknife", "collision"))


@pytest.mark.slow
def test_the_sweep_runs_tvlqr_with_q_from_the_outline(tmp_path):
    """tvlqr_q [identity, footprint]: two TVLQR cells, labelled apart; the footprint cell's trials are those
    of TVLQR built here with q: footprint on the rig's own outline (the Riccati solve on footprint_weights),
    and its gains are not the identity's."""
    data, md = _sweep(tmp_path, "cases: [trailer_turn_150]\ntrials: 3\nnoise: [1.0]\ntvlqr_q: [identity, footprint]\n"
                                "gramian: {end_strategy: [frozen]}\n")
    (case,) = data["cases"]
    assert case["plan"]["found"]
    by = {TS.law_label(c): c for c in case["cells"]}
    assert set(by) == {"tvlqr", "tvlqr q=footprint", "gramian a=0.02 d=15 g=2 frozen"}
    assert "| tvlqr q=footprint | x1 |" in md and "Against TVLQR with Q from the rig's outline" in md
    from dataclasses import replace

    from nhstab.batch.parking_study import first_plan
    from nhstab.batch.tube_study import trial_seeds
    from nhstab.execution import ControllerOptions, RunOptions, build_law
    from nhstab.execution.config import PlanningOptions

    run, _, result, _, _, _ = first_plan("trailer_turn_150", RunOptions(seed=0, planning=PlanningOptions(time_limit_s=2.0)))
    law = build_law(result.nominal, ControllerOptions(kind="tvlqr", q="footprint"), {}, robot=run.robot)
    assert not TS.same_gains(law, TS.build_sweep_law(run, result, {"controller": "tvlqr"}))
    out = TS.trial_outcomes(run, law, trial_seeds(3, 2026), replace(run.opts.noise, scale=1.0))
    assert out["per_trial"] == by["tvlqr q=footprint"]["per_trial"]


@pytest.mark.parametrize("name", ["batch_x1_footprint", "batch_x1_per_metre_footprint"])
def test_the_committed_footprint_batches_cover_the_suite_and_their_totals_recompute(name):
    """Each committed batch with TVLQR's two Q: every case of the suite is a row; every case that planned has
    the three laws at x1 with 50 trials; the totals and both verdicts recompute from the cells; the config
    beside it is the one it records."""
    root = Path(__file__).parents[1] / "results" / "trailer" / "suite"
    data = read_json(root / name / "sweep.json.gz")
    assert TS.load_sweep_config(root / f"{name}.yaml") == data["settings"]
    assert [c["case"] for c in data["cases"]] == [r["name"] for r in TS.suite_rows()]
    labels = {"tvlqr", "tvlqr q=footprint", "gramian a=0.02 d=15 g=2 frozen"}
    totals = {}
    for case in data["cases"]:
        if not case["plan"]["found"]:
            assert case["cells"] == []
            continue
        assert {TS.law_label(c) for c in case["cells"]} == labels
        for c in case["cells"]:
            assert c["noise"] == 1.0 and c["trials"] == 50
            t = totals.setdefault(TS.law_label(c), dict.fromkeys(("docked", "jackknife", "collision"), 0))
            for k in t:
                t[k] += c[k]
    assert data["cases_planned"] == sum(1 for c in data["cases"] if c["plan"]["found"])
    for row in data["totals"]:
        assert {k: row[k] for k in ("docked", "jackknife", "collision")} == totals[row["law"]]
    for ref, key in (("tvlqr", "matches_or_beats_tvlqr"), ("tvlqr q=footprint", "matches_or_beats_tvlqr_footprint")):
        g = totals["gramian a=0.02 d=15 g=2 frozen"]
        want = g["jackknife"] <= totals[ref]["jackknife"] and g["collision"] <= totals[ref]["collision"]
        assert data[key] == {"gramian a=0.02 d=15 g=2 frozen": want}

