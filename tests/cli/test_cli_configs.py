"""The bundled run and batch configs (example:NAME), the effective configs (--print-config), --trials."""

import json
import sqlite3
from pathlib import Path

import pytest
import yaml
from clitools import invoke, one_line
from nhstab.batch.config import load_batch_config
from nhstab.execution.config import DEFAULT_NOISE, load_run_config
from nhstab.maps.bundled import config_catalog
from nhstab.robot import default_robot

ROOT = Path(__file__).resolve().parents[2]


def test_bundled_configs_load_by_name_and_are_no_maps():
    from nhstab.examples import list_configs, list_examples

    batch, run = config_catalog("batch"), config_catalog("run")
    assert {"depot_robustness", "scenarios_auto_margin"} <= set(batch) and "warehouse_replan" in run
    assert not (set(batch) | set(run)) & {e.name for e in list_examples()}
    extra, _ = load_run_config("example:warehouse_replan")
    assert extra["map_given"] == "example:warehouse_aisle_a2"
    listed = {c.name: c for c in list_configs()}
    assert set(listed) == set(batch) | set(run) and all(c.description for c in listed.values())
    res = invoke("examples")
    assert "Batch configs: nhstab batch example:NAME" in res.stdout and "  warehouse_replan " in res.stdout


@pytest.mark.parametrize("name, committed", [("depot_robustness", "results/robustness/batch.yaml"),
                                             ("scenarios_auto_margin", "results/tubes/auto_margin/batch.yaml")])
def test_bundled_batch_configs_define_the_committed_batches(name, committed):
    """The shipped configs name their maps as example:NAME; they define the same trials (the store's
    fingerprint: options, seeds, problems and every map file's content) as the repository's own."""
    shipped = load_batch_config(f"example:{name}")
    assert all(m.given.startswith("example:") for m in shipped.maps)
    assert shipped.fingerprint() == load_batch_config(ROOT / committed).fingerprint()


def test_an_unknown_config_name_lists_the_bundled_ones():
    one_line(invoke("batch", "example:nope", "--print-config"), 2, "'CONFIG'", "depot_robustness", "example:nope")
    one_line(invoke("run", "--config", "example:depot_robustness", "--print-config"), 2, "'--config'",
             "warehouse_replan")


def test_run_print_config_fills_every_default_and_runs_as_printed(tmp_path):
    res = invoke("run", "example:parking_lot", "--alpha", "0.3", "--noise", "2", "--print-config")
    assert res.exit_code == 0, res.output
    doc = yaml.safe_load(res.stdout)
    rob = default_robot("rwd_car")
    assert doc["map"] == "example:parking_lot" and doc["robot"]["model"] == "rwd_car"
    assert doc["planning"]["margin"] == rob.margin and doc["planning"]["turning_radius"] == rob.turning_radius
    assert doc["controller"]["alpha"] == 0.3 and doc["controller"]["delta"] == rob.stabilizer.delta
    assert doc["noise"]["scale"] == 2.0
    assert doc["noise"]["sensor"] == {s: DEFAULT_NOISE["sensor"].get(s, 0.0) for s in rob.state_names}
    for section in ("controller", "noise", "sensor", "monitor", "planning", "replan", "tolerance", "tube"):
        assert isinstance(doc[section], dict) and doc[section], section
    assert not (tmp_path / "o").exists()
    (tmp_path / "eff.yaml").write_text(res.stdout)
    again = invoke("run", "--config", tmp_path / "eff.yaml", "--print-config")
    assert again.exit_code == 0 and again.stdout == res.stdout
    # a bundled run config prints too, its map by name
    res = invoke("run", "--config", "example:warehouse_replan", "--print-config")
    assert res.exit_code == 0 and yaml.safe_load(res.stdout)["map"] == "example:warehouse_aisle_a2"


def test_an_angle_given_in_degrees_and_radians_is_refused(tmp_path):
    (tmp_path / "c.yaml").write_text("map: example:cluttered_room\nsensor: {fov_deg: 90, fov_rad: 1.0}\n")
    one_line(invoke("run", "--config", tmp_path / "c.yaml", "--print-config"), 2, "'sensor.fov_rad'", "fov_deg")


def test_batch_print_config_with_trials_prints_what_runs(tmp_path):
    res = invoke("batch", "example:depot_robustness", "--trials", "2", "--print-config")
    assert res.exit_code == 0, res.output
    assert res.stdout.startswith("# the effective batch config: 9 cells x 2 trials = 18 trials")
    doc = yaml.safe_load(res.stdout)
    assert doc["trials"] == 2 and doc["maps"][0]["path"] == "example:depot_blocked_aisle"
    assert doc["maps"][0]["problems"] == [{"start": [3.0, 4.3, 0.0], "goal": [28.6, 4.3, 0.0]}]
    assert doc["grid"]["noise"] == [0.5, 1.0, 2.0] and doc["run"]["planning"]["time_limit_s"] == 2.0
    (tmp_path / "b.yaml").write_text(res.stdout)
    again = invoke("batch", tmp_path / "b.yaml", "--print-config")
    assert again.exit_code == 0 and again.stdout == res.stdout
    one_line(invoke("batch", "example:depot_robustness", "--trials", "0", "--print-config"), 2, "'--trials'")


def test_batch_trials_override_runs_the_first_trials_of_the_full_batch(tmp_path):
    cfg = tmp_path / "b.yaml"
    cfg.write_text("root_seed: 7\ntrials: 5\nmaps: [{path: 'example:cluttered_room'}]\nrun: {noise: {scale: 0}}\n")
    res = invoke("batch", cfg, "--out", tmp_path / "o", "--trials", "1", "--workers", "1", "--no-progress")
    assert res.exit_code == 0, res.output
    assert "1 cells x 1 trials = 1 trials" in res.stderr
    db = sqlite3.connect(tmp_path / "o" / "trials.sqlite")
    try:
        rows = db.execute("SELECT id, trial, seed FROM trials").fetchall()
    finally:
        db.close()
    assert len(rows) == 1 and rows[0][0].endswith("#0") and rows[0][1] == 0
    assert rows[0][2] == load_batch_config(cfg).seeds()[0]


def test_plan_print_config_fills_every_default_as_the_plan_uses_it(tmp_path):
    args = ("plan", "example:cluttered_room", "--headroom", "0.9", "--noise", "2", "--seed", "3")
    res = invoke(*args, "--print-config", "--out", tmp_path / "p")
    assert res.exit_code == 0, res.output
    assert res.stdout.startswith("# the effective plan configuration") and not (tmp_path / "p").exists()
    doc = yaml.safe_load(res.stdout)
    rob = default_robot("unicycle")
    assert doc["map"] == "example:cluttered_room" and doc["robot"]["model"] == "unicycle"
    assert doc["headroom"] == 0.9 and doc["max_speed"] == pytest.approx(0.9 * rob.model.max_speed, rel=1e-12)
    assert doc["controller"]["gains"] == "default" and doc["controller"]["alpha"] == rob.stabilizer.alpha
    assert doc["noise"]["sensor"] == {s: DEFAULT_NOISE["sensor"].get(s, 0.0) for s in rob.state_names}
    # the plan made with the same flags records the same options (plan.json: inputs, headroom, tube model)
    res = invoke(*args, "--no-figure", "--out", tmp_path / "p")
    assert res.exit_code == 0, res.output
    rec = json.loads((tmp_path / "p" / "plan.json").read_text())
    used = rec["inputs"]["path_options"]
    assert {k: used[k] for k in ("planner", "space", "time_limit_s", "seed", "margin", "turning_radius", "guide")} \
        == {k: v for k, v in doc["planning"].items() if k != "fit"}
    assert rec["inputs"]["start"] == doc["start"] and rec["inputs"]["goal"] == doc["goal"]
    assert rec["headroom"] == doc["headroom"] and rec["tube_model"]["rate_hz"] == doc["rate_hz"]
    noise = rec["tube_model"]["noise"]
    assert noise["scale"] == doc["noise"]["scale"] == 2.0
    assert doc["noise"]["process"]["per"] == noise["process_per"] == "second"
    for kind in ("sensor", "process"):
        levels = {s: v for s, v in doc["noise"][kind].items() if s != "per"}
        assert {s: v * 2.0 for s, v in levels.items()} == pytest.approx(noise[f"{kind}_by_state"])


def test_plan_print_config_checks_what_the_plan_checks():
    one_line(invoke("plan", "example:cluttered_room", "--turning-radius", "-1", "--print-config"), 2,
             "'--turning-radius'")
    one_line(invoke("plan", "example:cluttered_room", "--goal", "100,100,0", "--print-config"), 2, "'--goal'")
    one_line(invoke("plan", "example:loading_dock", "--margin", "auto", "--print-config"), 2, "'--margin'")
