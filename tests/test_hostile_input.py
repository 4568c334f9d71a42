"""Hostile and faulty input: every promise holds.

One regression test per class of failure found by trying nhstab as an adversarial user would. Each
checks the documented exit code, one line on stderr, no traceback, and that nothing already there is
lost or changed. (Ctrl-C during a batch is tested in test_batch.py; the fuzzers, with size and
nesting bombs under a deadline, are in test_fuzz_inputs.py.)
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sqlite3
from pathlib import Path

import nhstab
import numpy as np
import pytest
from clitools import invoke, one_line
from nhstab.errors import InputError
from nhstab.records import MANIFEST

ROOT = Path(__file__).resolve().parents[1]
D = ROOT / "maps/scenarios/depot_blocked_aisle.yaml"
M = ROOT / "maps/ours/cluttered_room.yaml"
NAV2 = ROOT / "maps/nav2"
STORE = ROOT / "tests/data/store_schema1.sqlite"
HUGE = str(10**400)






def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def tree(folder: Path) -> dict:
    """Every file under ``folder`` with its digest (what "nothing changed" compares)."""
    return {str(p.relative_to(folder)): digest(p) for p in sorted(folder.rglob("*")) if p.is_file()}


def ros_yaml(folder: Path, image: str, resolution="0.05", origin="[0, 0, 0]") -> Path:
    p = folder / "ros.yaml"
    p.write_text(f"image: {image}\nresolution: {resolution}\norigin: {origin}\nnegate: 0\n"
                 "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return p


# ---- one YAML loader for every reader ---------------------------------------------------------

def test_duplicate_keys_are_refused_naming_the_key_in_every_format(tmp_path):
    m = tmp_path / "dup.yaml"
    m.write_text("name: a\nbounds: [0, 0, 5, 5]\nname: b\n")
    one_line(invoke("map", "info", m), 2, "dup.yaml: name", "given once", "line 3")
    r = tmp_path / "run.yaml"
    r.write_text("seed: 1\nnoise:\n  scale: 1\n  scale: 2\n")
    out = tmp_path / "o"
    one_line(invoke("run", M, "--config", r, "--out", out), 2, "run.yaml: noise.scale")
    b = tmp_path / "batch.yaml"
    b.write_text(f"root_seed: 1\ntrials: 1\ntrials: 2\nmaps: [{{path: {M}}}]\n")
    one_line(invoke("batch", b, "--out", out), 2, "batch.yaml: trials")
    shutil.copy(NAV2 / "tb3_sandbox.pgm", tmp_path)
    ros = ros_yaml(tmp_path, "tb3_sandbox.pgm")
    ros.write_text(ros.read_text() + "negate: 1\n")
    one_line(invoke("map", "info", ros), 2, "ros.yaml: negate")
    assert not out.exists()


def test_nesting_and_alias_bombs_are_refused(tmp_path):
    deep = "[" * 3000 + "]" * 3000
    r = tmp_path / "run.yaml"
    r.write_text(f"seed: {deep}\n")
    one_line(invoke("run", M, "--config", r, "--out", tmp_path / "o"), 2, "run.yaml")
    b = tmp_path / "batch.yaml"
    b.write_text(f"root_seed: 1\ntrials: 1\nmaps: [{{path: {M}}}]\nrun: {{noise: {deep}}}\n")
    one_line(invoke("batch", b, "--out", tmp_path / "o"), 2, "batch.yaml")
    block = "seed:\n" + "".join("  " * i + "- \n" for i in range(300))
    r.write_text(block)
    one_line(invoke("run", M, "--config", r, "--out", tmp_path / "o"), 2, "nested at most 64")
    # the 531-byte billion laughs inside a map's robot block
    laughs = "name: bomb\nbounds: [0, 0, 10, 10]\nrobot:\n  model: unicycle\n  a: &a [x,x,x,x,x,x,x,x,x]\n"
    prev = "a"
    for n in "bcdefghi":
        laughs += f"  {n}: &{n} [" + ",".join(["*" + prev] * 9) + "]\n"
        prev = n
    assert len(laughs) < 600
    bomb = tmp_path / "laughs.yaml"
    bomb.write_text(laughs)
    one_line(invoke("map", "info", bomb), 2, "laughs.yaml: robot", "aliases expanded")
    assert not (tmp_path / "o").exists()


@pytest.mark.skipif(not Path("/dev/zero").exists() or not hasattr(os, "mkfifo"), reason="needs /dev/zero and FIFOs")
def test_devices_fifos_and_symlink_loops_are_refused_without_reading(tmp_path):
    one_line(invoke("map", "info", ros_yaml(tmp_path, "/dev/zero")), 2, "/dev/zero", "regular", "character device")
    os.mkfifo(tmp_path / "fifo.pgm")             # nothing ever writes to it: reading it would block forever
    one_line(invoke("map", "info", ros_yaml(tmp_path, "fifo.pgm")), 2, "fifo.pgm", "FIFO")
    os.symlink(tmp_path / "loop2.yaml", tmp_path / "loop1.yaml")
    os.symlink(tmp_path / "loop1.yaml", tmp_path / "loop2.yaml")
    (tmp_path / "uses.yaml").write_text("base: {format: nhstab, path: loop1.yaml}\n")
    one_line(invoke("map", "info", tmp_path / "uses.yaml"), 2, "uses.yaml: base.path", "ymlink loop")
    (tmp_path / "run.yaml").symlink_to(tmp_path / "run.yaml")
    one_line(invoke("run", M, "--config", tmp_path / "run.yaml", "--out", tmp_path / "o"), 2, "--config")


# ---- limits decided before allocation ----------------------------------------------------------

def test_absurd_grid_resolutions_and_coordinates_are_refused(tmp_path):
    shutil.copy(NAV2 / "tb3_sandbox.pgm", tmp_path)
    for res in ("1e300", "1.0e-300", "0"):
        one_line(invoke("map", "show", ros_yaml(tmp_path, "tb3_sandbox.pgm", res), "--out", tmp_path / "m.png"),
                 2, "resolution")
    one_line(invoke("map", "show", ros_yaml(tmp_path, "tb3_sandbox.pgm", origin="[1e200, 0, 0]"),
                    "--out", tmp_path / "m.png"), 2, "origin")
    one_line(invoke("map", "show", ROOT / "maps/movingai/64room_000.map", "--cell-size", "1e200",
                    "--out", tmp_path / "m.png"), 2, "'--cell-size'")
    svg = tmp_path / "far.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg"><path d="M 1e200 0 L 1e200 1 L 0 1 Z"/></svg>')
    one_line(invoke("map", "show", svg, "--out", tmp_path / "m.png"), 2, "far.svg", "1e+06 m")
    pgm = tmp_path / "wide.pgm"
    pgm.write_bytes(b"P5\n5000 5000\n255\n")     # the header alone: refused before the pixels are read
    one_line(invoke("map", "info", ros_yaml(tmp_path, "wide.pgm")), 2, "wide.pgm", "4096 x 4096")
    assert not (tmp_path / "m.png").exists()


def test_integers_of_any_size_give_one_line(tmp_path):
    out = tmp_path / "o"
    one_line(invoke("run", D, "--seed", HUGE, "--out", out), 2, "--seed", "2**128 - 1", "401 digits")
    one_line(invoke("plan", M, "--seed", str(2**64), "--out", out), 2, "--seed", "2**31 - 2")
    one_line(invoke("plan", D, "--seed", HUGE, "--out", out), 2, "--seed")
    r = tmp_path / "run.yaml"
    r.write_text(f"seed: {HUGE}\n")
    one_line(invoke("run", M, "--config", r, "--out", out), 2, "'seed'")
    b = tmp_path / "batch.yaml"
    b.write_text(f"root_seed: {HUGE}\ntrials: 2\nmaps: [{{path: {M}}}]\n")
    one_line(invoke("batch", b, "--out", out), 2, "root_seed")
    b.write_text(f"root_seed: 1\ntrials: 1000000000000\nmaps: [{{path: {M}}}]\n")
    one_line(invoke("batch", b, "--out", out), 2, "trials", "1,000,000")
    b.write_text(f"root_seed: 1\ntrials: 600000\nmaps: [{{path: {M}}}]\ncontrollers: [gramian, tvlqr]\n")
    one_line(invoke("batch", b, "--out", out), 2, "trials", "2 cells x 600000")
    assert not out.exists()
    # a seed below the limit is used as it is, through SeedSequence (no overflow anywhere)
    from nhstab.execution.seeds import planner_seed

    assert 0 <= planner_seed(2**128 - 1, 3) < 2**31 - 1


def test_rates_substeps_and_run_length_are_bounded_before_anything_runs(tmp_path):
    out = tmp_path / "o"
    one_line(invoke("run", D, "--rate", "1e7", "--out", out), 2, "--rate", "[1, 1000] Hz")
    one_line(invoke("run", D, "--rate", "0.1", "--out", out), 2, "--rate")
    r = tmp_path / "run.yaml"
    r.write_text("rate_hz: 1e7\n")
    line = one_line(invoke("run", D, "--config", r, "--out", out), 2, "rate_hz", "YAML 1.1 reads 1e7 as text")
    assert "write 1.0e+7" in line
    r.write_text("substeps: 1000000000\n")
    one_line(invoke("run", D, "--config", r, "--out", out), 2, "substeps", "[1, 100]")
    r.write_text("max_time_s: 100000\nrate_hz: 1000\n")
    one_line(invoke("run", D, "--config", r, "--out", out), 2, "max_time_s", "2,000,000 control periods")
    assert not out.exists()


def test_a_map_too_large_for_the_budget_is_refused_up_front(tmp_path):
    big = tmp_path / "huge.yaml"
    big.write_text("name: huge\nbounds: [-10000, -10000, 10000, 10000]\nobstacles:\n"
                   "  - box: {center: [5, 0], size: [1, 1]}\nstart: [0, 0, 0]\ngoal: [10, 0, 0]\n")
    one_line(invoke("plan", big, "--time-limit", "2", "--out", tmp_path / "p"), 2, "'map'", "28,284 m across",
             "planning budget of 2 s")
    one_line(invoke("run", big, "--time-limit", "2", "--out", tmp_path / "r"), 2, "'map'", "time limit")
    # with a budget that affords it, the same map is accepted (the refusal is about the budget)
    from nhstab.planning import check_map_budget

    check_map_budget(nhstab.load_map(big), 40.0)
    assert not (tmp_path / "p").exists() and not (tmp_path / "r").exists()


# ---- messages that name the user's key ---------------------------------------------------------

def test_messages_name_the_key_the_user_wrote(tmp_path):
    out = tmp_path / "o"
    r = tmp_path / "run.yaml"
    r.write_text("sensor: {fov_deg: 400}\n")
    one_line(invoke("run", M, "--config", r, "--out", out), 2, "'sensor.fov_deg'", "(0, 360]", "400")
    r.write_text("sensor: {fov_deg: 90, resolution_deg: 120}\n")
    one_line(invoke("run", M, "--config", r, "--out", out), 2, "'sensor.resolution_deg'")
    r.write_text("robot: heisenberg\n")
    one_line(invoke("run", M, "--config", r, "--out", out), 2, f"'robot (in {r})'", "heisenberg")
    one_line(invoke("plan", M, "--robot", "heisenberg", "--out", out), 2, "'--robot'", "heisenberg")
    b = tmp_path / "batch.yaml"
    b.write_text("root_seed: 1\ntrials: 1e3\nmaps: [{path: " + str(M) + "}]\n")
    one_line(invoke("batch", b, "--out", out), 2, "'trials'", "YAML 1.1 reads 1e3 as text")
    m = tmp_path / "m.yaml"
    m.write_text("bounds: [0, 0, 1e3, 10]\n")
    one_line(invoke("map", "info", m), 2, "m.yaml: bounds[2]", "YAML 1.1 reads 1e3 as text")
    assert not out.exists()


def test_start_equal_or_too_close_to_the_goal_says_so(tmp_path):
    out = tmp_path / "o"
    one_line(invoke("run", M, "--start", "1.8,1.8,0", "--goal", "1.8,1.8,0", "--out", out), 2,
             "'--goal'", "different from the start")
    one_line(invoke("plan", M, "--start", "1.8,1.8,0", "--goal", "1.8,1.8,0", "--out", out), 2,
             "'--goal'", "different from the start")
    one_line(invoke("run", M, "--start", "1.8,1.8,0", "--goal", "1.85,1.8,0", "--out", out), 2,
             "'--goal'", "shorter than the gain schedule's window delta = 2 s", "0.05 m apart",
             "robot.stabilizer.delta (the unicycle's default) would fit")
    assert not out.exists()


def test_bad_poses_problems_and_output_paths_on_the_command_line(tmp_path):
    one_line(invoke("run", M, "--start", "1,1", "--out", tmp_path / "o"), 2, "--start", "x,y,theta")
    one_line(invoke("map", "show", M, "--problems", "-5", "--out", tmp_path / "m.png"), 2, "--problems")
    one_line(invoke("map", "show", M, "--out", ""), 2, "--out")
    assert not (tmp_path / "o").exists() and not (tmp_path / "m.png").exists()


def test_default_output_names_are_sanitised(tmp_path):
    work = tmp_path / "a" / "b" / "c"
    work.mkdir(parents=True)
    evil = work / "evil.yaml"
    evil.write_text("name: ../../etc/passwd\nbounds: [0, 0, 5, 5]\n")
    res = invoke("map", "show", evil, cwd=work)
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in work.iterdir()) == ["etc_passwd.png", "evil.yaml"]
    assert [p.name for p in tmp_path.rglob("*.png")] == ["etc_passwd.png"]
    from nhstab.cli.map import safe_file_name

    assert safe_file_name("..") == "map" and safe_file_name("/", fallback="x") == "x"
    assert safe_file_name("a b/c\\d\x00e") == "a_b_c_d_e" and len(safe_file_name("x" * 500)) == 100


def test_a_batch_problem_outside_the_map_is_refused_before_any_trial(tmp_path):
    b = tmp_path / "batch.yaml"
    out = tmp_path / "o"
    b.write_text(f"root_seed: 1\ntrials: 2\nmaps: [{{path: {M}, problems: [{{start: [50, 50, 0], goal: [10, 7, 0]}}]}}]\n")
    one_line(invoke("batch", b, "--out", out), 2, "maps[0].problems[0].start", "inside the bounds")
    b.write_text(f"root_seed: 1\ntrials: 2\nmaps: [{{path: {M}, problems: [{{start: [1.8, 1.8, 0], goal: [4, 4.5, 0]}}]}}]\n")
    one_line(invoke("batch", b, "--out", out), 2, "maps[0].problems[0].goal", "planning margin")
    assert not out.exists()



def test_a_batch_with_margin_auto_checks_its_problems_at_the_first_plans_margin(tmp_path):
    """``planning: {margin: auto}`` in a batch config: its start/goal check uses the margin the first plan
    asks for (0.02 m; it crashed comparing a clearance with "auto"). A goal 0.042 m clear is accepted
    (refused at the fixed 0.1 m), one 0.002 m clear is refused naming it."""
    from nhstab.batch.config import load_batch_config

    b = tmp_path / "batch.yaml"
    text = "root_seed: 1\ntrials: 2\nmaps: [{{path: {m}, problems: [{{start: [1.8, 1.8, 0], goal: [{x}, 4.5, 0]}}]}}]\n{run}"
    b.write_text(text.format(m=M, x=5.67, run="run: {planning: {margin: auto}}\n"))
    assert len(load_batch_config(b).cells()) == 1
    b.write_text(text.format(m=M, x=5.67, run=""))
    with pytest.raises(InputError, match="planning margin 0.1 m"):
        load_batch_config(b)
    b.write_text(text.format(m=M, x=5.63, run="run: {planning: {margin: auto}}\n"))
    out = tmp_path / "o"
    one_line(invoke("batch", b, "--out", out), 2, "maps[0].problems[0].goal", "planning margin 0.02 m")
    assert not out.exists()

# ---- library calls -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def room():
    return nhstab.load_map(M)


@pytest.mark.parametrize("bad", [[1.0, 2.0], "1,2,3", None, [1, 2, 3, 4], [[1, 2, 3]], {"x": 1}, [1, np.nan, 0]])
def test_library_calls_with_bad_poses_raise_input_error(room, bad):
    model, fp = nhstab.make_model("unicycle"), nhstab.default_footprint("unicycle")
    goal = room.goal.as_array()
    calls = [lambda: nhstab.plan(room, nhstab.make_robot(model, footprint=fp), bad, goal), lambda: nhstab.plan(room, nhstab.make_robot(model, footprint=fp), goal, bad)]
    if bad is not None:                  # execute takes None as "the map's start"
        calls.append(lambda: nhstab.execute(room, nhstab.make_robot(model, footprint=fp), bad, goal, nhstab.RunOptions()))
    for call in calls:
        with pytest.raises(InputError, match="pose of three"):
            call()


def test_library_calls_with_wrong_types_raise_input_error(room):
    from nhstab.control.interpolant import GridInterpolant
    from nhstab.nominal import Nominal

    model, fp = nhstab.make_model("unicycle"), nhstab.default_footprint("unicycle")
    s, g = room.start.as_array(), room.goal.as_array()
    bad_t = np.array([0.0, 1.0, 1.0, 2.0])
    calls = [
        lambda: nhstab.load_map(12345), lambda: nhstab.load_map(None),
        lambda: nhstab.plan("room", nhstab.make_robot(model, footprint=fp), s, g), lambda: nhstab.plan(room, "unicycle", fp, s, g),
        lambda: nhstab.plan(room, model, "disc", s, g), lambda: nhstab.plan(room, nhstab.make_robot(model, footprint=fp), s, g, path_opts={}),
        lambda: nhstab.execute(room, nhstab.make_robot(model, footprint=fp), s, g, "fast"), lambda: nhstab.execute("room", nhstab.make_robot(model, footprint=fp), s, g),
        lambda: nhstab.compute_schedule("nominal"),
        lambda: Nominal(model, bad_t, np.zeros((4, 3)), np.ones((4, 2))),
        lambda: Nominal.from_samples(model, bad_t[::-1], np.zeros((4, 3)), np.ones((4, 2))),
        lambda: Nominal.from_inputs(model, lambda t: np.ones((np.size(t), 2)), np.zeros(3), bad_t),
        lambda: GridInterpolant(bad_t, np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((4, 2)), np.zeros((4, 2, 3))),
        lambda: nhstab.RunOptions(seed=10**400).validated(model.state_names, model.m),
        lambda: nhstab.PathOptions(seed=2**64).validated(),
    ]
    for call in calls:
        with pytest.raises(InputError):
            call()


# ---- stores: read-only unless writing, checked before anything is touched ----------------------

def _other_application_db(path: Path) -> Path:
    con = sqlite3.connect(path)
    con.execute("CREATE TABLE people (name TEXT)")
    con.execute("INSERT INTO people VALUES ('ada')")
    con.commit()
    con.close()
    return path


def _batch_yaml(tmp_path: Path, map_path: Path = M, trials: int = 1, extra: str = "") -> Path:
    f = tmp_path / "batch.yaml"
    f.write_text(f"name: t\nroot_seed: 11\ntrials: {trials}\nmaps:\n  - path: {map_path}\n"
                 f"controllers: [open-loop]\n{extra}")
    return f


def test_another_applications_database_is_left_byte_for_byte_unchanged(tmp_path):
    other = tmp_path / "app"
    other.mkdir()
    db = _other_application_db(other / "trials.sqlite")
    before = tree(other)
    one_line(invoke("batch", "report", db), 2, "STORE", "no 'meta' table", "people")
    one_line(invoke("batch", "replay", db, "x#0", "--out", tmp_path / "r"), 2, "STORE")
    one_line(invoke("batch", _batch_yaml(tmp_path), "--out", other, "--resume"), 2, "--resume")
    assert tree(other) == before                          # no byte changed, no -wal or -shm beside it
    assert not (tmp_path / "r").exists()


def test_a_read_only_store_is_read_without_writing(tmp_path):
    """The committed store (WAL mode): its report is written elsewhere, and the store's folder keeps
    exactly its bytes (no -wal/-shm files, even though WAL databases usually make them)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    shutil.copy(STORE, folder / "trials.sqlite")
    (folder / "trials.sqlite").chmod(0o444)
    folder.chmod(0o555)
    try:
        before = tree(folder)
        res = invoke("batch", "report", folder / "trials.sqlite", "--out", tmp_path / "rep")
        assert res.exit_code == 0, res.output
        assert tree(folder) == before
    finally:
        folder.chmod(0o755)
    assert (tmp_path / "rep" / "report.md").exists()


def test_corrupt_truncated_and_empty_stores_give_one_line(tmp_path):
    data = STORE.read_bytes()
    (tmp_path / "empty.sqlite").write_bytes(b"")
    (tmp_path / "trunc.sqlite").write_bytes(data[:5000])
    bad = bytearray(data)
    for i in range(8192, len(bad), 3000):
        bad[i] = (bad[i] + 77) % 256
    (tmp_path / "corrupt.sqlite").write_bytes(bytes(bad))
    (tmp_path / "text.sqlite").write_text("not a database at all\n")
    for name, needle in (("empty", "an empty file"), ("trunc", "malformed"), ("corrupt", "malformed"),
                         ("text", "not an SQLite database")):
        path = tmp_path / f"{name}.sqlite"
        before = digest(path)
        one_line(invoke("batch", "report", path, "--out", tmp_path / "rep"), 2, needle)
        one_line(invoke("batch", "replay", path, "a#0", "--out", tmp_path / "rp"), 2, "STORE")
        assert digest(path) == before
    folder = tmp_path / "b"
    folder.mkdir()
    (folder / "trials.sqlite").write_bytes(data[:5000])
    one_line(invoke("batch", _batch_yaml(tmp_path), "--out", folder, "--resume"), 2, "--resume", "malformed")
    assert not (tmp_path / "rep").exists() and not (tmp_path / "rp").exists()


def test_a_store_without_trials_has_no_report(tmp_path):
    from nhstab.batch.config import load_batch_config
    from nhstab.batch.runner import open_store

    open_store(load_batch_config(_batch_yaml(tmp_path)), tmp_path / "b", resume=False).close()
    one_line(invoke("batch", "report", tmp_path / "b"), 2, "at least one finished trial", "no trial is stored yet")
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["trials.sqlite"]


def test_a_malformed_scheduler_address_is_refused_before_the_store_exists(tmp_path):
    out = tmp_path / "b"
    for address in ("not a url", "tcp://", "http://host:8786", "tcp://host:99999", "host:port"):
        one_line(invoke("batch", _batch_yaml(tmp_path), "--out", out, "--scheduler", address), 2, "--scheduler")
    assert not out.exists()
    from nhstab.batch.runner import check_scheduler_address

    for ok in ("tcp://10.0.0.5:8786", "tls://sched.example.org:8786", "10.0.0.5:8786", "tcp://[::1]:8786",
               "inproc://10.0.0.5/1234/1"):
        assert check_scheduler_address(ok) == ok


# ---- the map content in the batch fingerprint --------------------------------------------------

def test_the_content_hash_covers_base_maps_and_images_not_names(tmp_path):
    from nhstab.maps import content_hash

    a = tmp_path / "a"
    (a / "scenarios").mkdir(parents=True)
    (a / "nav2").mkdir()
    shutil.copy(D, a / "scenarios")
    for f in ("depot.yaml", "depot.pgm"):
        shutil.copy(NAV2 / f, a / "nav2")
    scenario = a / "scenarios" / D.name
    h0 = content_hash(scenario)
    assert h0 == content_hash(D)                               # the same bytes elsewhere: the same hash
    m = nhstab.load_map(scenario)
    assert [Path(f["path"]).name for f in m.meta["files"]] == ["depot_blocked_aisle.yaml", "depot.yaml", "depot.pgm"]
    pgm = a / "nav2" / "depot.pgm"
    data = bytearray(pgm.read_bytes())
    data[-1] ^= 0xFF                                           # one pixel of the base map's image
    pgm.write_bytes(bytes(data))
    h1 = content_hash(scenario)
    assert h1 != h0
    (a / "nav2" / "depot.yaml").write_text((NAV2 / "depot.yaml").read_text() + "\n")
    assert content_hash(scenario) not in (h0, h1)            # the base map's YAML counts too


def test_resume_after_the_map_changed_is_refused(tmp_path):
    from nhstab.batch.config import load_batch_config
    from nhstab.batch.runner import run_batch
    from nhstab.batch.store import Store

    room = tmp_path / "room.yaml"
    shutil.copy(M, room)
    cfg = _batch_yaml(tmp_path, room, trials=2)
    out = tmp_path / "b"
    config = load_batch_config(cfg)
    with open_partial(config, out):
        pass
    with Store(out / "trials.sqlite") as s:
        stored = s.meta("config")
    assert stored["maps"][0]["content_hash"] == nhstab.load_map(room).meta["content_hash"]
    room.write_text(room.read_text().replace("radius: 0.7", "radius: 0.75"))
    before = tree(out)
    one_line(invoke("batch", cfg, "--out", out, "--resume"), 2, "CONFIG", "maps[0]", "has changed")
    assert tree(out) == before
    # a trial runs on the map the batch was configured with (its bundle: the files' bytes as they
    # were read), whatever happens to the files later; a trial given another map stops the batch
    from nhstab.batch.bundle import MapBundle
    from nhstab.batch.trial import MapChangedError, run_trial, trial_map

    spec = config.trial_specs()[0]
    assert trial_map(spec).meta["content_hash"] == stored["maps"][0]["content_hash"]
    with pytest.raises(MapChangedError):
        run_trial(spec, MapBundle.from_path(room))
    assert run_batch is not None


def open_partial(config, out):
    from nhstab.batch.runner import open_store

    return open_store(config, out, resume=False)


# ---- output folders never mix two runs ---------------------------------------------------------

def _run(out, *extra):
    return invoke("run", M, "--seed", "1", "--max-time", "3", "--out", out, *extra)


@pytest.mark.slow
def test_a_run_over_an_earlier_one_never_mixes_them(tmp_path, monkeypatch):
    out = tmp_path / "run"
    res = _run(out, "--animate")
    assert res.exit_code == 4, res.output                     # timed out after 3 s: a complete output
    first = tree(out)
    manifest = json.loads((out / MANIFEST).read_text())
    assert set(manifest["files"]) == set(first) - {MANIFEST} and "run.gif" in manifest["files"]
    for name, entry in manifest["files"].items():
        assert entry["sha256"] == first[name]

    # interrupted just after the new trajectory.csv is written: the earlier run stays whole
    from nhstab.execution import outputs

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "run_map_figure", interrupted)
    res = _run(out, "--noise", "2")
    assert res.exit_code == 130, res.output
    assert tree(out) == first
    assert not [p for p in out.iterdir() if p.name.startswith(".")]        # no staging folder left
    monkeypatch.undo()

    # a run without --animate: the earlier run.gif goes with the rest of that run
    res = _run(out, "--noise", "2")
    assert res.exit_code == 4, res.output
    second = tree(out)
    assert "run.gif" not in second and set(second) == {"run.json", "trajectory.csv", "run_map.png",
                                                       "run_tracking.png", MANIFEST}
    assert second["trajectory.csv"] != first["trajectory.csv"]
    assert set(json.loads((out / MANIFEST).read_text())["files"]) == set(second) - {MANIFEST}


def test_files_of_the_user_in_an_output_folder_are_kept(tmp_path):
    from nhstab.records import OutputFolder

    out = tmp_path / "o"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "run.gif").write_text("an older nhstab's run.gif (no manifest)")
    with OutputFolder(out, "run", owned=("run.json", "run.gif")) as o:
        o.write_text("run.json", "{}")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "notes.txt", "run.json"]
    with pytest.raises(RuntimeError):
        with OutputFolder(out, "run", owned=("run.json",)) as o:
            o.write_text("run.json", '{"new": 1}')
            raise RuntimeError("failed before the commit")
    assert (out / "run.json").read_text() == "{}" and (out / "notes.txt").read_text() == "mine"


@pytest.mark.slow
def test_a_report_leaves_no_figure_of_an_earlier_report(tmp_path):
    from nhstab.batch.config import load_batch_config
    from nhstab.batch.report import write_report
    from nhstab.batch.runner import run_batch

    two = load_batch_config(_batch_yaml(tmp_path, extra="grid:\n  noise: [0.5, 1.0]\n"))
    run_batch(two, tmp_path / "two", workers=1, progress=False)
    one = load_batch_config(_batch_yaml(tmp_path))
    run_batch(one, tmp_path / "one", workers=1, progress=False)
    report = tmp_path / "report"
    write_report(tmp_path / "two", report)
    assert (report / "figures" / "noise.png").exists()
    write_report(tmp_path / "one", report)
    figures = sorted(p.name for p in (report / "figures").iterdir())
    assert "noise.png" not in figures
    manifest = json.loads((report / MANIFEST).read_text())
    assert set(manifest["files"]) == {str(p.relative_to(report)) for p in report.rglob("*")
                                      if p.is_file() and p.name != MANIFEST}


# ---- one loader, and the documented limits are the code's ---------------------------------------

def test_every_yaml_read_goes_through_the_safe_loader():
    """No module but nhstab.safe_io parses YAML (writing it, yaml.safe_dump, is fine)."""
    offenders = []
    for folder in ("pipeline", "cli"):
        for path in (ROOT / folder).rglob("*.py"):
            if path.name == "safe_io.py":
                continue
            text = path.read_text()
            for needle in ("yaml.safe_load", "yaml.load(", "yaml.full_load", "yaml.unsafe_load", "yaml.compose"):
                if needle in text:
                    offenders.append(f"{path.relative_to(ROOT)}: {needle}")
    assert not offenders, offenders


def test_the_documented_limits_are_the_code_limits():
    """docs/reference/limits.md (the Limits table) states every bound of nhstab.limits."""
    from nhstab import limits
    from nhstab.clearance_field import ClearanceField
    from nhstab.control import StabilizerOptions
    from nhstab.planning import guide

    section = (ROOT / "docs" / "reference" / "limits.md").read_text()
    assert section.startswith("# Limits\n") and "| what | largest accepted | why |" in section
    assert limits.MAX_YAML_BYTES == 2**20 and "1 MiB, nested 64 levels, 2,000,000 values" in section
    assert limits.MAX_YAML_DEPTH == 64 and limits.MAX_YAML_NODES == 2_000_000
    assert limits.MAX_FILE_BYTES == 256 * 2**20 and "256 MiB" in section
    assert limits.MAX_GRID_CELLS == 4096**2 and "4096 x 4096 cells, cells of 0.1 mm to 1 km" in section
    assert (limits.MIN_CELL_M, limits.MAX_CELL_M) == (1e-4, 1e3)
    assert limits.MAX_COORD_M == 1e6 and "+-1,000 km" in section
    assert limits.MAX_WORLD_OBJECTS == 100_000 and "100,000 objects" in section
    assert limits.FCL_CHECK_S == 64e-6 and "64 us per FCL check" in section
    assert round(2.0 * 0.05 / limits.FCL_CHECK_S / 100) / 10 == 1.6 and "1.6 km across for the default 2 s" in section
    assert (limits.MIN_RATE_HZ, limits.MAX_RATE_HZ) == (1.0, 1000.0) and "1 to 1000 Hz" in section
    assert limits.MAX_SUBSTEPS == 100 and limits.MAX_CONTROL_PERIODS == 2_000_000 and "2,000,000 control periods" in section
    assert limits.MAX_SEED == 2**128 - 1 and limits.MAX_PLANNER_SEED == 2**31 - 2
    assert "0 to 2**128 - 1" in section and "0 to 2**31 - 2" in section
    assert limits.MAX_BATCH_TRIALS == 1_000_000 and "1,000,000 trials" in section
    assert limits.MAX_NOMINAL_SAMPLES == 2_000_000 and "2,000,000 samples of its time step (0.02 s: 11 hours)" in section
    assert round(limits.MAX_NOMINAL_SAMPLES * 0.02 / 3600) == 11
    assert limits.MAX_HEADING_RAD == 1e6 and "+-1,000,000 rad" in section
    assert limits.MAX_STUDY_TRIALS == 5_000 and "5,000 trials per cell" in section
    assert limits.MAX_ROLLOUTS == 100_000 and "| 100,000 rollouts (N >= ln(1 - confidence) / ln(p)) |" in section
    assert limits.MAX_WINDOW_SUBSTEPS == 1024 and StabilizerOptions().max_substep_fraction == 1 / 16
    assert limits.MAX_GAMMA == 1e4 and "| 1/2 to 10,000 |" in section
    assert limits.MAX_POLYGON_VERTICES == 10_000 and "| 10,000 vertices (a `line:` 5,001 points) |" in section
    from nhstab.maps.yaml_format import MAX_LINE_POINTS

    assert MAX_LINE_POINTS == 5_001 and "a robot's lengths (footprint, wheelbase, hitches, margin) | +-1,000 km" in section
    assert limits.MIN_TURNING_RADIUS_M == 1e-3 and "the map's diagonal; a car's smallest (wheelbase / tan(max_steer)) " \
        "at least 1 mm |" in section
    assert limits.MAX_PROBABILITY == 1 - 1e-9 and "| 1 - 1e-9 |" in section
    assert (limits.MAX_NOISE_SCALE, limits.MAX_NOISE_LEVEL) == (1e3, 1e6) and "| scale 1,000; levels 1,000 km" in section
    from nhstab.paper import GRID_HZ

    assert GRID_HZ == 500 and limits.MAX_PAPER_DELTA_S == 100 and "| `nhstab paper --delta` | 100 s |" in section
    assert "1/64 of the nominal's time step (0.3 ms at 0.02 s)" in section and "1,024 per time step" in section
    assert ClearanceField.MAX_CELLS == 4_000_000 and "4,000,000 cells" in section
    assert guide.MAX_CELLS == 400_000 and "400,000 guide cells" in section


@pytest.mark.parametrize("args,key", [
    ((M, "--turning-radius", "1e-12"), "'--turning-radius'"),   # the unicycle's speed: turn-rate limit x radius
    ((M, "--max-speed", "1e-12"), "'--max-speed'"),
    ((M, "--max-speed", "1e-4"), "'--max-speed'"),              # 1.3e5 s: 6.7 million samples of 0.02 s
    (("example:parking_lot", "--max-speed", "1e-9"), "'--max-speed'"),     # a car
])
def test_a_nominal_too_long_to_sample_is_refused_before_it_is_allocated(tmp_path, args, key):
    """A speed far too low for the map made a nominal of 1e13 s, and numpy was asked for petabytes
    (a MemoryError traceback); now one line names what set the speed."""
    out = tmp_path / "p"
    line = one_line(invoke("plan", *args, "--out", out), 2, key, "2,000,000 samples", "the nominal would last")
    assert "m/s" in line and not out.exists()


def test_a_car_with_a_trailer_at_a_crawl_is_refused_before_it_is_tracked(tmp_path):
    """The trailer's nominal is the rig driven step by step along its path: at 1e-6 m/s that loop ran
    for hours; the path's length at the tracker's speed is checked first."""
    out = tmp_path / "p"
    one_line(invoke("plan", "example:loading_dock", "--max-speed", "1e-6", "--out", out), 2, "'--max-speed'",
             "2,000,000 samples")
    assert not out.exists()


@pytest.mark.parametrize("where", ["--start", "--goal"])
def test_headings_beyond_a_million_radians_are_refused(tmp_path, where):
    """A heading of 1e308 has no angle left in it (the nominal came out with an infinite heading and
    numpy's overflow warning); 1e6 rad is still planned."""
    out = tmp_path / "p"
    one_line(invoke("plan", M, where, "1,1,1e308", "--out", out), 2, f"'{where}[2]'", "heading within +-1e+06 rad")
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {M}\n{where[2:]}: [1.0, 1.0, -1.0e+300]\n")
    one_line(invoke("run", "--config", cfg, "--out", out), 2, f"'{where[2:]}[2]'", "heading within")
    assert not out.exists()
    from nhstab.maps import load_map
    from nhstab.planning import plan
    from nhstab.robot import default_robot

    m = load_map(M)
    with pytest.raises(InputError, match=r"'start\[2\]' must be a heading"):
        plan(m, default_robot("unicycle"), [1.0, 1.0, 1e7], m.goal.as_array())


@pytest.mark.parametrize("args,key", [(("--trials", "1000000000000"), "'--trials'"), (("--trials", "1"), "'--trials'"),
                                      (("--seed", str(2**128)), "'--seed'"), (("--seed", "-1"), "'--seed'")])
def test_the_tube_study_bounds_its_trials_and_seed_before_it_starts(tmp_path, args, key):
    """--trials 1e12 ran (seeds for every trial, then every trial's series in memory) until killed;
    --seed beyond 2**128 - 1 was taken, where runs and batches refuse it."""
    out = tmp_path / "study"
    one_line(invoke("tubes", "study", *args, "--out", out), 2, key)
    assert not out.exists()


def test_gamma_beyond_its_bound_is_one_line_everywhere(tmp_path):
    """gamma 1e300 made infinite gains and a ValueError traceback from the paper's integrator; in a batch
    grid every trial failed by error. Now the command line, run configs and batch grids refuse it up front."""
    one_line(invoke("paper", "--out", tmp_path / "p", "--case", "hilare-circle", "--gamma", "1e300"), 2, "'--gamma'",
             "10000")
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {M}\ncontroller:\n  gamma: 1.0e+5\n")
    one_line(invoke("run", "--config", cfg, "--out", tmp_path / "r"), 2, "'controller.gamma'", "10000")
    b = tmp_path / "batch.yaml"
    b.write_text(f"name: g\nroot_seed: 1\ntrials: 1\nmaps:\n  - path: {M}\ncontrollers: [gramian]\n"
                 "grid:\n  gamma: [1.0, 1.0e+300]\n")
    one_line(invoke("batch", b, "--out", tmp_path / "b"), 2, "'grid.gamma[1]'", "10000")
    assert not any((tmp_path / d).exists() for d in ("p", "r", "b"))
