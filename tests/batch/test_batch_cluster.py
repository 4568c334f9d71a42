"""Batches whose trials carry their map: a real Dask cluster started elsewhere, the store
alone for reports and replays, map bundles as hostile input, errors said at the end of a batch.

The cluster test starts ``dask scheduler`` and two ``dask worker`` processes in a folder of their
own (not the batch's, as on other machines), so a trial that needed a path of the submitting
machine would fail there; the LocalCluster of test_batch.py inherits the working folder and could
not show it.
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import time
import zlib
from pathlib import Path

import nhstab
import numpy as np
import pytest
from clitools import invoke, one_line
from nhstab.batch.bundle import BundleError, MapBundle
from nhstab.batch.config import load_batch_config
from nhstab.batch.runner import run_batch
from nhstab.batch.store import Store
from nhstab.errors import InputError
from storetools import records

ROOT = Path(__file__).resolve().parents[2]
OLD_STORE = ROOT / "tests/data/store_schema1.sqlite"      # made before stores kept maps (schema 1)


# ---- a map with a base map and an image, and a batch that names it relative to its config --------

def make_room(maps: Path) -> Path:
    """maps/nav2/room.yaml + room.pgm (a ROS map: a 6 m x 4 m room with a wall from the top), and
    maps/scen/room_detour.yaml (an nhstab scenario on that base map, with an unknown box). Returns
    the scenario."""
    (maps / "nav2").mkdir(parents=True)
    (maps / "scen").mkdir(parents=True)
    w, h = 120, 80
    img = np.full((h, w), 254, np.uint8)
    img[:2, :] = img[-2:, :] = 0
    img[:, :2] = img[:, -2:] = 0
    img[0:50, 58:62] = 0
    (maps / "nav2" / "room.pgm").write_bytes(b"P5\n%d %d\n255\n" % (w, h) + img.tobytes())
    (maps / "nav2" / "room.yaml").write_text("image: room.pgm\nmode: trinary\nresolution: 0.05\n"
                                             "origin: [0.0, 0.0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
                                             "free_thresh: 0.25\n")
    scen = maps / "scen" / "room_detour.yaml"
    scen.write_text("name: room-detour\nbase:\n  format: ros\n  path: ../nav2/room.yaml\nunknown_obstacles:\n"
                    "  - box: {center: [4.5, 0.9], size: [0.3, 0.3]}\nstart: [1.0, 2.5, 0.0]\n"
                    "goal: [5.0, 2.5, 0.0]\nrobot: {model: unicycle}\n")
    return scen


def make_batch(folder: Path, trials: int = 2, controllers=("gramian", "open-loop")) -> Path:
    """folder/maps/... (make_room) and folder/cfg/batch.yaml naming the scenario relative to itself."""
    make_room(folder / "maps")
    cfg = folder / "cfg" / "batch.yaml"
    cfg.parent.mkdir(parents=True)
    cfg.write_text(f"name: room\nroot_seed: 5\ntrials: {trials}\nmaps:\n  - path: ../maps/scen/room_detour.yaml\n"
                   f"controllers: [{', '.join(controllers)}]\n")
    return cfg








# ---- a real cluster: scheduler and workers as processes of their own --------------------------------

def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask_command() -> list[str]:
    script = Path(sys.executable).parent / "dask"
    return [str(script)] if script.exists() else [sys.executable, "-m", "dask"]


def _stop(proc: subprocess.Popen) -> None:
    """End a process started here with its own session, and everything it started (SIGTERM, then
    SIGKILL after a grace period)."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    with contextlib.suppress(ProcessLookupError):      # the nanny's worker process, if it lingers
        os.killpg(proc.pid, signal.SIGKILL)


@contextlib.contextmanager
def dask_cluster(folder: Path, workers: int = 2):
    """``dask scheduler`` and ``workers`` x ``dask worker --nworkers 1 --nthreads 1`` on loopback,
    started in ``folder``; yields the scheduler address once every worker has registered; stops
    them all afterwards, also on failure."""
    pytest.importorskip("distributed")
    from distributed import Client

    folder.mkdir(parents=True, exist_ok=True)
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    procs = []
    logs = []
    try:
        log = open(folder / "scheduler.log", "w")
        logs.append(log)
        procs.append(subprocess.Popen(_dask_command() + ["scheduler", "--host", "127.0.0.1", "--port", str(port),
                                                         "--no-dashboard"],
                                      cwd=folder, env=env, stdout=log, stderr=subprocess.STDOUT,
                                      start_new_session=True))
        for i in range(workers):
            log = open(folder / f"worker{i}.log", "w")
            logs.append(log)
            procs.append(subprocess.Popen(_dask_command() + ["worker", address, "--nworkers", "1", "--nthreads", "1",
                                                             "--no-dashboard", "--host", "127.0.0.1",
                                                             "--local-directory", str(folder / f"w{i}")],
                                          cwd=folder, env=env, stdout=log, stderr=subprocess.STDOUT,
                                          start_new_session=True))
        client = Client(address, timeout="60s")
        try:
            client.wait_for_workers(workers, timeout=120)
        finally:
            client.close()
        yield address
    finally:
        for proc in reversed(procs):          # workers first, then the scheduler
            _stop(proc)
        for log in logs:
            log.close()
        time.sleep(0.5)
        for proc in procs:                                # nothing of the cluster outlives the test
            assert not _running_in_group(proc.pid), (proc.args, _running_in_group(proc.pid))


def _running_in_group(pgid: int) -> list[int]:
    """Processes of group ``pgid`` that still run (zombies, which only wait to be reaped by init,
    do not count). Linux: from /proc; elsewhere: the group's existence."""
    if not Path("/proc/self/stat").exists():
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return []
        return [pgid]
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[0] != "Z" and int(fields[2]) == pgid:
            out.append(int(stat.parent.name))
    return out


@pytest.mark.slow
def test_a_batch_on_a_dask_cluster_started_elsewhere_equals_a_local_run_and_its_store_suffices(tmp_path):
    """The batch names its map relative to its config and is run from its own folder; the
    scheduler and workers run in another one. The store equals a local run's trial for trial.
    Then the map files are moved away: report and replay work from the store alone."""
    batch = tmp_path / "batch"
    cfg = make_batch(batch)
    scenario = batch / "maps" / "scen" / "room_detour.yaml"
    run_batch(load_batch_config(cfg), tmp_path / "local", workers=1, progress=False)
    local = records(tmp_path / "local" / "trials.sqlite")
    assert len(local) == 4

    with dask_cluster(tmp_path / "cluster") as address:
        res = subprocess.run([sys.executable, "-m", "nhstab.cli.main", "batch", "cfg/batch.yaml", "--out", "out",
                              "--scheduler", address, "--no-progress"],
                             cwd=batch, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr
    assert "ran 4 trials" in res.stdout and "error" not in res.stdout, res.stdout
    db = batch / "out" / "trials.sqlite"
    assert records(db) == local                     # status, metrics, series and seed of every trial
    with Store(db) as s:
        trials = s.trials()
        ids = s.map_ids()
        bundle = s.map_bundle(ids[0])
        runs = s.meta("runs")
    assert all(t["status"] != "error" for t in trials)
    assert {t["versions"]["nhstab"] for t in trials} == {nhstab.__version__}
    # the store holds the map: the bytes of its three files, the content hash the batch recorded
    assert len(ids) == 1 and {t["spec"]["cell_spec"]["map_bundle"] for t in trials} == {ids[0]}
    assert bundle.content_hash == nhstab.maps.content_hash(scenario)
    assert sorted(bundle.files) == ["nav2/room.pgm", "nav2/room.yaml", "scen/room_detour.yaml"]
    assert bundle.files["nav2/room.pgm"] == (batch / "maps" / "nav2" / "room.pgm").read_bytes()
    # what crossed the network: the bundle once per worker, small specs and records per trial
    t = runs[-1]["transfer"]
    assert runs[-1]["executor"] == "dask" and t["bundle_copies"] == 2 and t["trials"] == 4
    assert t["bundles_sent_bytes"] == 2 * len(bundle.packed)
    assert 0 < t["spec_bytes_per_trial"] < 4000 and 0 < t["record_bytes_per_trial"]
    assert "shipped: map bundles" in res.stderr
    # nothing of the map reached the workers' folder as a file
    assert not [p for p in (tmp_path / "cluster").rglob("*") if p.name.startswith("room")]

    # ---- the map files are gone: the store alone ----------------------------------------------------
    away = tmp_path / "elsewhere"
    shutil.move(batch / "maps", away)
    rep = invoke("batch", "report", batch / "out", "--out", tmp_path / "rep")
    assert rep.exit_code == 0, rep.output
    rows = list(csv.DictReader((tmp_path / "rep" / "trials.csv").open()))
    assert {r["id"]: r["status"] for r in rows} == {x["id"]: x["status"] for x in trials}
    assert "on the Dask cluster at " + address in (tmp_path / "rep" / "report.md").read_text()

    rec = trials[0]
    rp = tmp_path / "replay"
    out = invoke("batch", "replay", batch / "out", rec["id"], "--out", rp)
    assert out.exit_code in (0, 4), out.output
    d = json.loads((rp / "run.json").read_text())
    assert d["status"] == rec["status"]
    assert d["clearance"]["min_executed_m"] == rec["metrics"]["min_clearance_m"]
    assert d["tracking"]["max_error_norm"] == rec["metrics"]["max_error_norm"]
    for rel in bundle.files:                        # the replay's folder holds the map: it runs anywhere
        assert (rp / "map" / rel).read_bytes() == (away / rel).read_bytes()
    again = invoke("run", "--config", rp / "run_config.yaml", "--out", tmp_path / "again", cwd=tmp_path)
    assert again.exit_code in (0, 4), again.output
    assert json.loads((tmp_path / "again" / "run.json").read_text())["clearance"]["min_executed_m"] == \
        rec["metrics"]["min_clearance_m"]


# ---- local workers: the same path (the map from its bundle, never from the files) ------------------

@pytest.fixture(scope="module")
def small_batch(tmp_path_factory):
    """A 2-trial batch (open loop) on the room scenario, run on one worker from its folder (so that
    its trials record the map path relative to it): its folder, config and store."""
    folder = tmp_path_factory.mktemp("small")
    cfg = make_batch(folder, trials=2, controllers=("open-loop",))
    old = os.getcwd()
    os.chdir(folder)
    try:
        run_batch(load_batch_config("cfg/batch.yaml"), folder / "out", workers=1, progress=False)
    finally:
        os.chdir(old)
    return folder, cfg, folder / "out" / "trials.sqlite"


def test_local_workers_run_from_the_bundle_after_the_map_files_are_gone(small_batch, tmp_path):
    folder, _, db = small_batch
    copy = tmp_path / "b"
    shutil.copytree(folder / "maps", copy / "maps")
    shutil.copytree(folder / "cfg", copy / "cfg")
    config = load_batch_config(copy / "cfg" / "batch.yaml")
    shutil.rmtree(copy / "maps")                    # after the config is read: the trials need no file
    from nhstab.batch import bundle as bundle_module

    bundle_module._LOADED.clear()                   # nor a map this process loaded: only the bundle
    counts = run_batch(config, copy / "two", workers=2, progress=False)
    assert counts.errors == 0 and counts.outcomes and counts.transfer["bundle_copies"] == 0
    assert records(copy / "two" / "trials.sqlite") == records(db)


def test_a_map_bundle_travels_and_loads_the_same_map(tmp_path):
    scen = make_room(tmp_path / "a" / "maps")
    b = MapBundle.from_path(scen)
    assert sorted(b.files) == ["nav2/room.pgm", "nav2/room.yaml", "scen/room_detour.yaml"]
    assert b.entry == "scen/room_detour.yaml" and b.content_hash == nhstab.maps.content_hash(scen)
    u = MapBundle.unpack(b.packed)
    assert u == b and u.id == b.id
    # the same files elsewhere: the same bundle id and content hash (names of folders above do not count)
    shutil.copytree(tmp_path / "a" / "maps", tmp_path / "x" / "y" / "maps")
    b2 = MapBundle.from_path(tmp_path / "x" / "y" / "maps" / "scen" / "room_detour.yaml")
    assert b2.id == b.id and b2.content_hash == b.content_hash
    # the map from the bundle is the map from the files, with the submitting machine's names
    m0 = nhstab.load_map(scen)
    m = u.load()
    assert m.name == m0.name and m.bounds == m0.bounds and m.source == str(scen)
    assert m.meta == m0.meta
    assert np.array_equal(m.grids[0].occupied, m0.grids[0].occupied) and m.grids[0].origin == m0.grids[0].origin
    assert [o.vertices.tolist() for o in m.unknown_obstacles] == [o.vertices.tolist() for o in m0.unknown_obstacles]
    assert (m.start, m.goal, m.robot) == (m0.start, m0.goal, m0.robot)


def _same_map(a, b) -> bool:
    def shapes(m, key):
        return [getattr(o, "vertices", None).tolist() if hasattr(o, "vertices") else (o.center, o.radius)
                for o in getattr(m, key)]

    return (a.name == b.name and a.bounds == b.bounds and a.meta == b.meta and a.robot == b.robot
            and (a.start, a.goal) == (b.start, b.goal) and a.problems == b.problems
            and shapes(a, "obstacles") == shapes(b, "obstacles")
            and shapes(a, "unknown_obstacles") == shapes(b, "unknown_obstacles")
            and len(a.grids) == len(b.grids)
            and all(np.array_equal(g.occupied, h.occupied) and g.origin == h.origin and g.resolution == h.resolution
                    for g, h in zip(a.grids, b.grids)))


def test_every_bundled_map_travels_in_every_format(tmp_path):
    """ROS map_server, Moving AI (with its .scen), Bench-MR SVG (with polygon_scenarios.csv), nhstab
    YAML with base maps of each kind: from the bundle, the same map as from the files."""
    from nhstab.examples import list_examples

    formats = set()
    for ex in list_examples():
        b = MapBundle.from_path(ex.path)
        formats.update(Path(f).suffix for f in b.files)
        assert _same_map(MapBundle.unpack(b.packed).load(), nhstab.load_map(ex.path)), ex.name
    assert {".yaml", ".pgm", ".map", ".scen", ".svg", ".csv"} <= formats
    # a Moving AI map at another cell size: another map from the same bundle
    ex = next(e for e in list_examples() if e.path.suffix == ".map")
    b = MapBundle.from_path(ex.path, cell_size=0.5)
    assert _same_map(b.load(0.5), nhstab.load_map(ex.path, cell_size=0.5))
    assert b.load(0.5).bounds != b.load().bounds


def test_a_map_that_reaches_outside_its_files_cannot_travel_and_is_refused(tmp_path):
    scen = make_room(tmp_path / "maps")
    text = scen.read_text().replace("../nav2/room.yaml", str(tmp_path / "maps" / "nav2" / "room.yaml"))
    scen.write_text(text)                           # the base map by an absolute path
    ros = tmp_path / "maps" / "nav2" / "room.yaml"
    ros.write_text(ros.read_text().replace("image: room.pgm", f"image: {tmp_path / 'maps' / 'nav2' / 'room.pgm'}"))
    nhstab.load_map(scen)                           # loads here ...
    cfg = tmp_path / "batch.yaml"
    cfg.write_text(f"name: r\nroot_seed: 1\ntrials: 1\nmaps:\n  - path: {scen}\ncontrollers: [open-loop]\n")
    with pytest.raises(InputError) as err:          # ... but a batch could not run it on another machine
        load_batch_config(cfg)
    msg = str(err.value)
    assert "maps[0].path" in msg and "travel" in msg and "\n" not in msg


def test_hostile_map_bundles_are_refused_in_one_line_and_write_nothing(tmp_path, monkeypatch):
    good = MapBundle.from_path(make_room(tmp_path / "maps"))
    raw = zlib.decompress(good.packed)
    n = int.from_bytes(raw[:4], "big")
    head = json.loads(raw[4:4 + n])

    def repack(h, payload=raw[4 + n:]):
        text = json.dumps(h).encode()
        return zlib.compress(len(text).to_bytes(4, "big") + text + payload)

    def bad(data, needle):
        with pytest.raises(BundleError) as err:
            MapBundle.unpack(data, source="test bundle")
        assert needle in str(err.value) and "\n" not in str(err.value), str(err.value)

    bad(b"not zlib", "zlib")
    bad(good.packed[:-10], "")
    bad(good.packed + b"x", "nothing after")
    bad("text", "bytes")
    for path, needle in (("../escape.yaml", "no '..'"), ("/etc/passwd", "not absolute"), ("a/./b", "no '..'"),
                         ("a\\b", "relative"), ("", "relative")):
        h = json.loads(json.dumps(head))
        h["files"][0]["path"] = path
        bad(repack(h), needle)
    h = json.loads(json.dumps(head))
    h["files"][1]["path"] = h["files"][0]["path"]
    bad(repack(h), "each file once")
    h = json.loads(json.dumps(head))
    h["files"][0]["sha256"] = "0" * 64
    bad(repack(h), "corrupt")
    h = json.loads(json.dumps(head))
    h["files"] = [dict(h["files"][0], path=f"f{i}") for i in range(65)]
    bad(repack(h), "1 to 64 files")
    h = json.loads(json.dumps(head))
    h["version"] = 99
    bad(repack(h), "another version")
    bad(repack(head, raw[4 + n:] + b"extra"), "no bytes after the files")
    # a bomb: refused while decompressing, at the limit, not after
    import nhstab.batch.bundle

    monkeypatch.setattr(nhstab.batch.bundle, "MAX_BUNDLE_BYTES", 1 << 20)     # where the bundle reads it
    bad(zlib.compress(b"\0" * (8 << 20)), "at most")
    # random damage (seeded): a BundleError or, rarely, an intact bundle, never anything else
    rng = np.random.default_rng(1616)
    for _ in range(200):
        data = bytearray(good.packed)
        for i in rng.integers(0, len(data), size=rng.integers(1, 4)):
            data[i] ^= int(rng.integers(1, 256))
        try:
            MapBundle.unpack(bytes(data))
        except BundleError:
            pass


# ---- old stores (schema 1: no maps) ---------------------------------------------------------------

def _as_schema_1(db: Path) -> None:
    con = sqlite3.connect(db)
    con.execute("DROP TABLE maps")
    con.execute("UPDATE meta SET value = '1' WHERE key = 'schema'")
    con.commit()
    con.close()


def test_an_old_store_is_reported_replayed_from_the_files_or_refused_in_one_line_and_upgraded(small_batch,
                                                                                            tmp_path):
    folder, cfg, db = small_batch
    old = tmp_path / "old"
    old.mkdir()
    shutil.copy(db, old / "trials.sqlite")
    _as_schema_1(old / "trials.sqlite")
    with Store(old / "trials.sqlite") as s:
        assert s.schema == 1 and s.map_ids() == [] and s.count() == 2
        rec = s.trials()[0]
    assert invoke("batch", "report", old, "--out", tmp_path / "rep").exit_code == 0
    assert rec["spec"]["cell_spec"]["map_path"] == "cfg/../maps/scen/room_detour.yaml"
    # the map files at the recorded path, with the recorded content: the replay uses them
    res = invoke("batch", "replay", old, rec["id"], "--out", tmp_path / "r1", cwd=folder)
    assert res.exit_code in (0, 4), res.output
    assert json.loads((tmp_path / "r1" / "run.json").read_text())["clearance"]["min_executed_m"] == \
        rec["metrics"]["min_clearance_m"]
    # no files there: one line naming what is missing
    one_line(invoke("batch", "replay", old, rec["id"], "--out", tmp_path / "r2", cwd=tmp_path), 2,
             "STORE", "schema 1", "room_detour.yaml", "not a file here")
    # other files there: refused, naming both content hashes
    moved = tmp_path / "moved"
    shutil.copytree(folder / "maps", moved / "maps")
    (moved / "cfg").mkdir()
    scen = moved / "maps" / "scen" / "room_detour.yaml"
    scen.write_text(scen.read_text().replace("size: [0.3, 0.3]", "size: [0.3, 0.4]"))
    one_line(invoke("batch", "replay", old, rec["id"], "--out", tmp_path / "r3", cwd=moved), 2,
             "STORE", "schema 1", "has changed since the batch")
    assert not (tmp_path / "r2").exists() and not (tmp_path / "r3").exists()
    # the resume upgrades it: its maps table made and filled, the trials kept
    counts = run_batch(load_batch_config(cfg), old, resume=True, progress=False)
    assert counts.ran == 0
    with Store(old / "trials.sqlite") as s:
        assert s.schema == 2 and len(s.map_ids()) == 1 and s.count() == 2


def test_the_committed_old_store_replay_names_what_is_missing(tmp_path):
    """tests/data/store_schema1.sqlite (the robustness batch's store as an early version wrote it) was
    made before stores kept maps or content hashes (its report:
    test_hostile_input.py::test_a_read_only_store_is_read_without_writing). Made schema 1 here as well."""
    old = tmp_path / "old.sqlite"
    shutil.copy(OLD_STORE, old)
    with Store(old) as s:
        regenerated = s.schema >= 2
    if regenerated:
        _as_schema_1(old)
    one_line(invoke("batch", "replay", old, "map=depot-blocked-aisle|problem=0|robot=default|controller="
                    "gramian|noise=0.5#0", "--out", tmp_path / "r", cwd=tmp_path), 2,
             "schema 1", "depot_blocked_aisle.yaml", "not a file here")


def test_a_stored_map_that_is_not_intact_is_refused_in_one_line(small_batch, tmp_path):
    _, _, db = small_batch
    shutil.copy(db, tmp_path / "trials.sqlite")
    con = sqlite3.connect(tmp_path / "trials.sqlite")
    packed = bytearray(con.execute("SELECT packed FROM maps").fetchone()[0])
    packed[len(packed) // 2] ^= 0x55
    con.execute("UPDATE maps SET packed = ?", (bytes(packed),))
    con.commit()
    trial = con.execute("SELECT id FROM trials").fetchone()[0]
    con.close()
    one_line(invoke("batch", "replay", tmp_path, trial, "--out", tmp_path / "r"), 2, "STORE", "maps are intact")
    assert invoke("batch", "report", tmp_path, "--out", tmp_path / "rep").exit_code == 0     # the report needs no map


# ---- errors, said at the end ------------------------------------------------------------------------

def test_a_batch_whose_trials_all_error_exits_non_zero_with_one_line(tmp_path, monkeypatch):
    import nhstab.batch.trial

    cfg = make_batch(tmp_path, trials=2, controllers=("open-loop",))

    def broken(m, robot, start, goal, opts):
        raise RuntimeError(f"the solver gave up (seed {opts.seed})")

    monkeypatch.setattr(nhstab.batch.trial, "execute", broken)     # where a trial calls it
    res = invoke("batch", cfg, "--out", tmp_path / "b", "--workers", "1", "--no-progress")
    line = one_line(res, 1, "all 2 trials failed by error", "RuntimeError: the solver gave up",
                    "map=room-detour|problem=0|robot=default|controller=open-loop|noise=1#0")
    assert line.startswith("nhstab: failed:")
    assert "error 2" in res.stdout
    md = (tmp_path / "b" / "report.md").read_text()
    assert "## Errors" in md and "(0 with an outcome, 2 failed by error" in md
    assert md.count("RuntimeError: the solver gave up") == 2          # one row per message (two seeds)

    # some errors, some outcomes: said, exit 0, and the report keeps them apart from the rates
    monkeypatch.undo()
    from nhstab.execution import execute as real_execute

    first_seed = load_batch_config(cfg).seeds()[0]

    def sometimes(m, robot, start, goal, opts):
        if opts.seed == first_seed:
            raise RuntimeError("only the first seed fails")
        return real_execute(m, robot, start, goal, opts)

    monkeypatch.setattr(nhstab.batch.trial, "execute", sometimes)
    res = invoke("batch", cfg, "--out", tmp_path / "c", "--workers", "1", "--no-progress")
    one_line(res, 0, "warning: 1 of 2 trials failed by error", "only the first seed fails", "--retry-errors")
    md = (tmp_path / "c" / "report.md").read_text()
    assert "(1 with an outcome, 1 failed by error" in md and "| 2 (1 errors) |" in md
    # fixed: --resume --retry-errors runs the error again, and only it
    monkeypatch.undo()
    res = invoke("batch", cfg, "--out", tmp_path / "c", "--resume", "--retry-errors", "--workers", "1",
                 "--no-progress")
    assert res.exit_code == 0 and "ran 1 trials" in res.stdout, res.output
    with Store(tmp_path / "c" / "trials.sqlite") as s:
        assert s.errors() == [] and s.count() == 2
    one_line(invoke("batch", cfg, "--out", tmp_path / "d", "--retry-errors"), 2, "--retry-errors", "--resume")


@pytest.mark.slow
def test_a_trial_that_kills_its_dask_worker_is_stored_as_an_error(tmp_path, monkeypatch):
    """Dask gives up on a task whose worker died (KilledWorker): the trial is stored as an error
    (what it did), the batch goes on and says so."""
    pytest.importorskip("distributed")
    import dask
    from distributed import LocalCluster
    from nhstab.batch import runner

    cfg = make_batch(tmp_path, trials=1, controllers=("open-loop",))

    def crash(spec, bundle, version):          # defined here: shipped by value to the worker
        os._exit(3)

    monkeypatch.setattr(runner, "_dask_trial", crash)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                          host="127.0.0.1") as cluster:
            counts = run_batch(load_batch_config(cfg), tmp_path / "b", scheduler=cluster.scheduler_address,
                               progress=False)
    assert counts.errors == counts.ran == 1 and counts.outcomes == {"error": 1}
    assert counts.first_error[1].startswith("KilledWorker: the worker running it died")
    with Store(tmp_path / "b" / "trials.sqlite") as s:
        assert [t["status"] for t in s.trials()] == ["error"]


def test_a_worker_with_another_nhstab_is_refused_naming_the_scheduler(tmp_path, monkeypatch):
    """Checked before the store exists for the workers connected at the start; and by every trial
    for a worker that joins later (the batch stops, its trial not stored)."""
    pytest.importorskip("distributed")
    from distributed import LocalCluster
    from nhstab.batch import runner

    cfg = make_batch(tmp_path, trials=1, controllers=("open-loop",))
    config = load_batch_config(cfg)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                      host="127.0.0.1") as cluster:
        with monkeypatch.context() as mp:
            mp.setattr(runner, "_worker_versions", lambda: {"nhstab": "0.0.1"})     # shipped by value
            with pytest.raises(InputError) as err:
                run_batch(config, tmp_path / "b", scheduler=cluster.scheduler_address, progress=False)
        assert "--scheduler" in str(err.value) and "nhstab 0.0.1" in str(err.value)
        assert not (tmp_path / "b").exists()            # refused before the store is made
        # a worker the start-up check did not see: this machine says 9.9.9, the worker its own
        monkeypatch.setattr(runner, "check_workers", lambda client, scheduler: {})
        monkeypatch.setattr(runner, "__version__", "9.9.9")       # the version the batch compares
        with pytest.raises(InputError) as err:
            run_batch(config, tmp_path / "c", scheduler=cluster.scheduler_address, progress=False)
    assert "--scheduler" in str(err.value) and "nhstab 9.9.9" in str(err.value)
    assert f"a worker runs nhstab {nhstab._version.__version__}" in str(err.value)
    with Store(tmp_path / "c" / "trials.sqlite") as s:
        assert s.count() == 0
