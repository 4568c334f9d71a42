"""The parking suite of one's own car (``nhstab parking suite --robot-config``) and its study
(``nhstab parking study --suite``): the same layouts as the bundled suite, sized from the car given,
checked against the bundled suite's geometry and the closed forms, and refused clearly when the car or
the folder will not do."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from nhstab import parking as P
from nhstab.cli.main import cli
from nhstab.errors import InputError
from nhstab.maps import load_map
from nhstab.records import read_json

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "maps" / "parking"

#: a compact hatchback, about 3.9 x 1.7 m (not a car of the bundled suite)
COMPACT = {"model": "rwd_car", "name": "compact", "wheelbase": 2.45, "max_speed": 1.5, "max_steer": 0.62,
           "max_steer_rate": 1.0, "footprint": {"rectangle": {"length": 3.9, "width": 1.7, "rear_overhang": 0.65}}}


def _write(tmp_path, spec, name="car.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(spec))
    return path


def test_the_bundled_rwd_car_under_another_name_gives_the_bundled_maps(tmp_path):
    """The built-in rwd_car's own description, renamed: every map's obstacles, bounds, start and goal are the
    bundled suite's (the same generator), its robot block the description given, and suite.csv's sizes the
    bundled ones."""
    spec = dict(P.cars()["rwd_car"], name="mine")
    cfg = _write(tmp_path, spec)
    out = tmp_path / "suite"
    res = CliRunner().invoke(cli, ["parking", "suite", "--robot-config", str(cfg), "--out", str(out)])
    assert res.exit_code == 0, res.output + res.stderr
    own = {r["name"]: r for r in P.read_suite_csv(out / "suite.csv")}
    bundled = {r["name"]: r for r in P.read_suite_csv(BUNDLED / "suite.csv") if r["car"] == "rwd_car"}
    assert sorted(n.replace("_mine_", "_rwd_car_") for n in own) == sorted(bundled)
    for name, row in own.items():
        ref = bundled[name.replace("_mine_", "_rwd_car_")]
        assert row["car"] == "mine" and row["kind"] == ref["kind"] and row["factor"] == ref["factor"]
        assert row["size_m"] == pytest.approx(ref["size_m"], abs=1e-9)
        a, b = load_map(str(out / f"{name}.yaml")), load_map(str(BUNDLED / f"{ref['name']}.yaml"))
        assert a.bounds == b.bounds and a.start == b.start and a.goal == b.goal
        assert len(a.obstacles) == len(b.obstacles)
        for oa, ob in zip(a.obstacles, b.obstacles):
            assert np.array_equal(np.asarray(oa.vertices), np.asarray(ob.vertices))
        assert a.robot == spec
        head = (out / f"{name}.yaml").read_text().splitlines()[0]
        assert f"--robot-config {cfg}" in head and f"--out {out}" in head
    src = (out / "SOURCE.md").read_text()
    assert "| `mine` |" in src and f"nhstab parking suite --robot-config {cfg} --out {out}" in src


def test_a_car_of_its_own_is_sized_by_the_closed_forms(tmp_path):
    """A compact car (none of the bundled suite's): its slots are factor x L1, with L1 = b + sqrt(2 R w +
    (L + f)^2) from its description read directly, to 1e-9 m; the margin is the suite's 0.1 m unless the
    description states its own; --check says the folder is what the command writes."""
    cfg = _write(tmp_path, COMPACT)
    out = tmp_path / "suite"
    assert CliRunner().invoke(cli, ["parking", "suite", "--robot-config", str(cfg), "--out", str(out)]).exit_code == 0
    rect = COMPACT["footprint"]["rectangle"]
    L, w, b = COMPACT["wheelbase"], rect["width"], rect["rear_overhang"]
    f, R = rect["length"] - b - L, COMPACT["wheelbase"] / math.tan(COMPACT["max_steer"])
    L1 = b + math.sqrt(2 * R * w + (L + f) ** 2)
    rows = P.read_suite_csv(out / "suite.csv")
    parallel = [r for r in rows if r["kind"] == "parallel"]
    assert [r["factor"] for r in parallel] == list(P.PARALLEL_FACTORS)
    for r in parallel:
        assert r["reference_m"] == pytest.approx(L1, abs=1e-9) and r["size_m"] == pytest.approx(r["factor"] * L1, abs=1e-9)
    assert len(rows) == len(P.suite()) // 2
    assert load_map(str(out / "parallel_compact_090.yaml")).robot["margin"] == P.SUITE_MARGIN
    res = CliRunner().invoke(cli, ["parking", "suite", "--robot-config", str(cfg), "--out", str(out), "--check"])
    assert res.exit_code == 0 and "up to date" in res.output
    (out / "parallel_compact_100.yaml").write_text("name: x\n")
    res = CliRunner().invoke(cli, ["parking", "suite", "--robot-config", str(cfg), "--out", str(out), "--check"])
    assert res.exit_code == 1 and "differ: parallel_compact_100.yaml" in res.output
    cfg2 = _write(tmp_path, {**COMPACT, "margin": 0.25}, "careful.yaml")
    specs = P.own_car(yaml.safe_load(cfg2.read_text()), "--robot-config", "careful")
    assert list(specs) == ["careful"] and specs["careful"]["margin"] == 0.25


@pytest.mark.parametrize("spec,name,needle", [
    ([1, 2], None, "a robot description"),
    ({**COMPACT, "model": "unicycle"}, None, "rwd_car"),
    ({**COMPACT, "model": "fwd_car"}, None, "rwd_car"),
    ({**COMPACT, "footprint": {"disc": {"radius": 1.0}}}, None, "rectangle"),
    ({**COMPACT, "wheelbase": -2.0}, None, "wheelbase"),
    ({k: v for k, v in COMPACT.items() if k != "name"}, None, "name"),
    (COMPACT, "my car", "--name"),
    (COMPACT, "9lives", "--name"),
    ({**COMPACT, "name": "a" * 41}, None, "name"),
])
def test_cars_that_will_not_do_are_refused_by_name(spec, name, needle):
    with pytest.raises(InputError, match=needle):
        P.own_car(spec, "--robot-config car.yaml", name)


@pytest.mark.parametrize("args,needle", [
    (["--robot-config", "{cfg}"], "--out"),
    (["--name", "x", "--out", "{out}"], "--name"),
    (["--robot-config", "{cfg}", "--name", "two words", "--out", "{out}"], "--name"),
    (["--robot-config", "{missing}", "--out", "{out}"], "--robot-config"),
])
def test_the_suite_command_refuses_in_one_line_and_writes_nothing(tmp_path, args, needle):
    cfg, out = _write(tmp_path, COMPACT), tmp_path / "out"
    args = [a.format(cfg=cfg, out=out, missing=tmp_path / "nope.yaml") for a in args]
    res = CliRunner().invoke(cli, ["parking", "suite", *args])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in res.output
    assert not out.exists()
    assert P.write_suite(BUNDLED, check=True) == {"differ": [], "missing": [], "extra": []}


def test_the_study_of_ones_own_suite(tmp_path):
    """nhstab parking study --suite: the maps of the folder, planned from their files (study.json.gz records the
    folder; study.md names `nhstab run FOLDER/NAME.yaml`), written into FOLDER/study by default."""
    cfg = _write(tmp_path, COMPACT)
    suite = tmp_path / "suite"
    assert CliRunner().invoke(cli, ["parking", "suite", "--robot-config", str(cfg), "--out", str(suite)]).exit_code == 0
    res = CliRunner().invoke(cli, ["parking", "study", "--suite", str(suite), "--maps", "parallel_compact_140",
                                   "--noise", "1", "--controllers", "tvlqr", "--trials", "3", "--mc-factor", "1",
                                   "--workers", "1"])
    assert res.exit_code == 0, res.output + res.stderr
    doc = read_json(suite / "study" / "study.json.gz")
    assert doc["suite"] == str(suite) and [c["map"] for c in doc["cases"]] == ["parallel_compact_140"]
    case = doc["cases"][0]
    assert case["car"] == "compact" and case["plan"]["found"] and case["cells"][0]["trials"]["trials"] == 3
    md = (suite / "study" / "study.md").read_text()
    assert f"`nhstab run {suite}/NAME.yaml --seed 0 --fit`" in md
    assert (suite / "study" / "tube_parallel_compact_140.png").exists() is False


@pytest.mark.parametrize("make,needle", [
    (lambda d: d.mkdir(), "no suite.csv"),
    (lambda d: (d.mkdir(), (d / "suite.csv").write_text("name,car\nx,y\n")), "suite.csv unreadable"),
])
def test_the_study_refuses_a_folder_that_is_not_a_suite(tmp_path, make, needle):
    d = tmp_path / "notasuite"
    make(d)
    res = CliRunner().invoke(cli, ["parking", "study", "--suite", str(d), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--suite" in lines[0] and needle in lines[0]
    assert not (tmp_path / "o").exists()
