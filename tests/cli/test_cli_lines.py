"""What the commands print and default to: every line with a quantity to act on, one set of defaults."""

import json
import re

import numpy as np
import pytest
from clitools import invoke
from nhstab.cli.gains import DEFAULTS_HELP
from nhstab.execution import RunOptions
from nhstab.geometry import Footprint
from nhstab.limits import DEFAULT_HEADROOM
from nhstab.models import make_model
from nhstab.parking import suite
from nhstab.robot import MODEL_DEFAULTS
from nhstab.trajectory_io import write_trajectory
from nominals import heisenberg_line, hilare_sinusoid

ROOM = "example:cluttered_room"


def test_parking_table_has_a_header_and_one_row_per_case():
    res = invoke("parking", "table")
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    assert lines[0].split() == ["map", "car", "kind", "measure", "size", "[m]", "factor", "reference", "reference",
                                "[m]"]
    cases = suite()
    assert len(lines) == 1 + len(cases)
    for line, c in zip(lines[1:], cases):
        assert line.startswith(c.name + " ")
        assert f"{c.size_m:.3f}" in line and f"{c.reference_m:.3f}" in line


def test_plan_and_run_plan_with_the_same_headroom():
    assert RunOptions().headroom == DEFAULT_HEADROOM
    res = invoke("plan", "--help")
    assert f"default: nhstab run's, {DEFAULT_HEADROOM:g}" in " ".join(res.stdout.split())


def test_default_plan_prints_no_saturation_note_and_a_larger_headroom_prints_an_actionable_one(tmp_path):
    res = invoke("plan", ROOM, "--out", tmp_path / "a", "--no-figure")
    assert res.exit_code == 0, res.output
    assert "note:" not in res.stdout
    plan = json.loads((tmp_path / "a" / "plan.json").read_text())
    assert plan["headroom"] == DEFAULT_HEADROOM
    res = invoke("plan", ROOM, "--out", tmp_path / "b", "--no-figure", "--headroom", "1")
    assert res.exit_code == 0, res.output
    notes = [ln for ln in res.stdout.splitlines() if ln.startswith("note:")]
    assert len(notes) == 1 and "--headroom 1" in notes[0] and "--headroom 0.8 (the default)" in notes[0]
    frac = float(re.search(r"reach a limit in (\d+) %", notes[0]).group(1))
    assert frac > 1
    # nhstab run's first plan is the default plan's: the same nominal
    full = json.loads((tmp_path / "b" / "plan.json").read_text())
    assert full["metrics"]["duration_s"] < plan["metrics"]["duration_s"]


def test_gains_help_shows_each_models_defaults():
    text = " ".join(invoke("gains", "--help").stdout.split())
    assert DEFAULTS_HELP in text
    for name, spec in MODEL_DEFAULTS.items():
        st = spec["stabilizer"]
        part = re.search(rf"(?:^|; ){name} ([^;]*)", DEFAULTS_HELP).group(1)
        assert f"alpha {st['alpha']:g}" in part and f"delta {st['delta']:g}" in part, name
        for key in ("end_strategy", "cusps"):
            default = {"end_strategy": "frozen", "cusps": "across"}[key]
            if st.get(key, default) != default:
                assert f"{key.replace('_', '-')} {st[key]}" in part, (name, key)
        assert (f"gamma {st['gamma']:g}" in part) == (st["gamma"] != 1.0), name


@pytest.mark.parametrize("model, nominal", [("unicycle", lambda: hilare_sinusoid(2 * np.pi, hz=50)),
                                            ("heisenberg", lambda: heisenberg_line(6.0, hz=50))])
def test_gains_defaults_are_the_models_and_the_file_has_a_and_b(tmp_path, model, nominal):
    nom = nominal()
    traj = write_trajectory(tmp_path / "n.csv", nom)
    res = invoke("gains", traj, "--model", model, "--out", tmp_path / "g")
    assert res.exit_code == 0, res.output
    st = MODEL_DEFAULTS[model]["stabilizer"]
    diag = json.loads((tmp_path / "g" / "gains.json").read_text())
    assert diag["stabilizer"]["alpha"] == st["alpha"] and diag["stabilizer"]["delta"] == st["delta"]
    assert diag["rate_bound"] == pytest.approx(3 * st["alpha"], rel=1e-12)
    assert res.stdout.splitlines()[0].startswith(f"{model}: alpha {st['alpha']:g}, delta {st['delta']:g} s")
    data = np.load(tmp_path / "g" / "gains.npz")
    x0, u0, A, B = data["x0"], data["u0"], data["A"], data["B"]
    n, m = x0.shape[1], u0.shape[1]
    assert A.shape == (len(x0), n, n) and B.shape == (len(x0), n, m)
    # against finite differences of the model's vector field f(x) + g(x) u0
    mdl = make_model(model)
    for k in (0, len(x0) // 3, len(x0) - 1):
        h = 1e-6
        fd = np.column_stack([(mdl.rhs(x0[k] + h * e, u0[k]) - mdl.rhs(x0[k] - h * e, u0[k])) / (2 * h)
                              for e in np.eye(n)])
        np.testing.assert_allclose(A[k], fd, atol=1e-6)
        fdu = np.column_stack([(mdl.rhs(x0[k], u0[k] + h * e) - mdl.rhs(x0[k], u0[k] - h * e)) / (2 * h)
                               for e in np.eye(m)])
        np.testing.assert_allclose(B[k], fdu, atol=1e-6)
    # an option given overrides the model's default
    res = invoke("gains", traj, "--model", model, "--alpha", "0.3", "--out", tmp_path / "g")
    assert json.loads((tmp_path / "g" / "gains.json").read_text())["rate_bound"] == pytest.approx(0.9)


GAP_MAP = ("bounds: [0, 0, 20, 10]\nobstacles:\n"
           "  - box: {center: [10, 2.25], size: [0.4, 4.5]}\n  - box: {center: [10, 7.75], size: [0.4, 4.5]}\n"
           "start: [3, 5, 0]\ngoal: [17, 5, 0]\nrobot: {model: unicycle}\n")
#: the gap in the wall is 1.0 m wide: the unicycle's disc (radius 0.3 m) keeps at most 0.2 m from it
GAP_ROOM = 0.5 - 0.3


def test_the_widest_way_through_a_gap_keeps_half_the_gap_less_the_radius(tmp_path, monkeypatch):
    from nhstab import load_map
    from nhstab.collision import CollisionWorld
    from nhstab.planning.guide import likely_cause, passage
    from nhstab.robot import default_robot

    (tmp_path / "gap.yaml").write_text(GAP_MAP)
    m = load_map(tmp_path / "gap.yaml")
    world, fp = CollisionWorld.from_map(m, "known"), default_robot("unicycle").footprint
    start, goal = np.array([3.0, 5.0, 0.0]), np.array([17.0, 5.0, 0.0])
    info = passage(world, fp, start, goal)
    cell = world.clearance_field().r
    assert info["connected"] and info["margin_m"] == pytest.approx(GAP_ROOM, abs=0.5 * cell)
    assert abs(info["at"][0] - 10.0) <= 0.2 + cell and abs(info["at"][1] - 5.0) <= cell
    why = likely_cause(world, fp, start, goal, 0.25, 0.5, 2.0, "unicycle", pad=0.02)
    assert why["cause"] == "margin" and why["fits_below_m"] == pytest.approx(GAP_ROOM - 0.02, abs=0.5 * cell)
    assert likely_cause(world, fp, start, goal, 0.1, 0.5, 2.0, "unicycle", pad=0.02)["cause"] == \
        "turning_radius_or_budget"
    # a raster pooled to fewer cells (as a large map's is) finds the same gap, to about a pooled cell
    import nhstab.planning.guide as guide

    monkeypatch.setattr(guide, "MAX_CELLS", 20_000)
    coarse = passage(world, fp, start, goal)
    pooled = cell * np.ceil(np.sqrt(world.clearance_field().lower_bound.size / 20_000))
    assert pooled > 2 * cell and coarse["margin_m"] == pytest.approx(GAP_ROOM, abs=pooled)
    wide = Footprint.disc(0.6)
    assert likely_cause(world, wide, start, goal, 0.0, 0.5, 2.0, "unicycle")["cause"] in ("footprint", "blocked")


def test_run_without_a_first_plan_says_each_attempt_and_the_margin_that_fits(tmp_path):
    (tmp_path / "gap.yaml").write_text(GAP_MAP)
    res = invoke("run", tmp_path / "gap.yaml", "--margin", "0.25", "--time-limit", "0.2", "--out", tmp_path / "r")
    assert res.exit_code == 3, res.output
    progress = [ln for ln in res.stderr.splitlines() if ln.startswith("first plan, attempt")]
    assert [p.split(":")[0] for p in progress] == [f"first plan, attempt {k} of 3" for k in (1, 2)]
    assert progress[0].endswith("attempt 2 with a budget of 0.2 s ...") and "likely cause: the margin" in progress[0]
    assert progress[1].endswith("attempt 3 with a budget of 0.8 s ...") and "likely cause" not in progress[1]
    causes = [ln for ln in res.stdout.splitlines() if ln.startswith("likely cause: the margin")]
    assert len(causes) == 1
    below = float(re.search(r"--margin below ([0-9.]+) m", causes[0]).group(1))
    assert below == pytest.approx(GAP_ROOM - 0.02, abs=0.03)
    run = json.loads((tmp_path / "r" / "run.json").read_text())
    assert run["plans"][0]["attempts"][-1]["likely_cause"]["cause"] == "margin"


def test_saturation_and_negative_clearance_lines_say_what_they_mean():
    from types import SimpleNamespace

    from nhstab.tubes.base import certified_text, saturation_text

    assert "<=" not in saturation_text(1.0) and "no information" in saturation_text(1.0)
    assert "--tube sampled" in saturation_text(0.999)
    assert saturation_text(0.123) == "inputs may saturate (probability at most 12 %)"
    text = certified_text(SimpleNamespace(certified_clearance=-0.0134), explain=True)
    assert text.startswith("NOT certified: tube clearance -0.013 m") and "overlap a known obstacle by 0.013 m" in text
    assert certified_text(SimpleNamespace(certified_clearance=-0.0134)) == "NOT certified: tube clearance -0.013 m"
    assert certified_text(SimpleNamespace(certified_clearance=0.2)) == "certified clear by +0.200 m"


@pytest.mark.slow
def test_run_says_the_closest_it_came_to_an_obstacle(tmp_path):
    res = invoke("run", ROOM, "--out", tmp_path / "r")
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "r" / "run.json").read_text())["clearance"]
    line = next(ln for ln in res.stdout.splitlines() if "obstacle(s) discovered" in ln)
    assert f"closest {doc['min_executed_m']:.3f} m to an obstacle at t = {doc['time_s']:.1f} s (margin 0.1 m)" in line
    assert "first plan, attempt" not in res.stderr
