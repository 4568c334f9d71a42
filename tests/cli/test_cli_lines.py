"""What the commands print and default to: every line with a quantity to act on, one set of defaults."""

import json
import re

import numpy as np
import pytest
from clitools import invoke
from nhstab.cli.gains import DEFAULTS_HELP
from nhstab.execution import RunOptions
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
        assert st["gamma"] == 1.0


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
