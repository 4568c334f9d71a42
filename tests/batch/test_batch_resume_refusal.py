"""A refused ``--resume`` changes no byte of the store: a corrupt store is read whole and refused
before it is opened for writing, and a folder another batch is running in is refused before its
store is opened for writing."""

from __future__ import annotations

import hashlib
import shutil
import sqlite3
from pathlib import Path

import pytest
from click.testing import CliRunner
from nhstab.batch.config import load_batch_config
from nhstab.batch.runner import STORE_NAME, _only_batch_in, run_batch
from nhstab.batch.store import StoreError
from nhstab.cli.main import cli
from nhstab.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
ROOM = ROOT / "maps/ours/cluttered_room.yaml"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished batch (two short trials) whose store is padded with copies of its rows, so that the
    trials table spans many pages besides its index."""
    base = tmp_path_factory.mktemp("finished")
    cfg = base / "batch.yaml"
    cfg.write_text(f"name: r\nroot_seed: 5\ntrials: 2\nmaps:\n  - path: {ROOM}\ncontrollers: [open-loop]\n"
                   "run: {max_time_s: 1.0, tube: {kind: linear}}\n")
    out = base / "out"
    run_batch(load_batch_config(cfg), out, workers=1, progress=False)
    con = sqlite3.connect(out / STORE_NAME)
    with con:
        for k in range(40):
            con.execute("INSERT INTO trials SELECT id || ? , cell, trial, seed, spec, status, metrics, series, "
                        "timings, error, versions, finished_at FROM trials WHERE id NOT LIKE '%~%'", (f"~{k}",))
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.close()
    return cfg, out


def _copy(finished, tmp_path) -> tuple[Path, Path]:
    cfg, out = finished
    dst = tmp_path / "out"
    shutil.copytree(out, dst)
    return cfg, dst


def _flip_page(path: Path, page: int, size: int) -> None:
    data = bytearray(path.read_bytes())
    for i in range(page * size, min((page + 1) * size, len(data))):
        data[i] ^= 0xFF
    path.write_bytes(bytes(data))


def test_a_corrupt_store_is_refused_byte_identical_wherever_it_is_corrupt(finished, tmp_path):
    cfg, out = finished
    store = out / STORE_NAME
    header = store.read_bytes()[:100]
    size = int.from_bytes(header[16:18], "big")
    pages = store.stat().st_size // size
    assert pages >= 10
    config = load_batch_config(cfg)
    refused = 0
    for page in range(1, pages):           # every page but the header's
        case = tmp_path / f"p{page}"
        shutil.copytree(out, case)
        path = case / STORE_NAME
        _flip_page(path, page, size)
        before = _sha(path)
        try:
            run_batch(config, case, workers=1, resume=True, progress=False)
        except StoreError as exc:
            refused += 1
            assert exc.argument == "--resume" and "\n" not in str(exc)
            assert _sha(path) == before, f"page {page}: the refused resume changed the store"
            assert sorted(p.name for p in case.iterdir()) == sorted(p.name for p in out.iterdir())
        shutil.rmtree(case)
    assert refused >= pages // 2, f"only {refused} of {pages - 1} corrupt pages refused"


def test_the_command_line_refuses_a_corrupt_store_with_one_line_and_leaves_it_as_it_was(finished, tmp_path):
    cfg, out = _copy(finished, tmp_path)
    store = out / STORE_NAME
    data = bytearray(store.read_bytes())
    mid = len(data) // 2
    for i in range(mid - 2048, mid + 2048):           # 4 KiB in the middle
        data[i] ^= 0xFF
    store.write_bytes(bytes(data))
    before = _sha(store)
    for _ in range(2):                                 # every attempt
        res = CliRunner().invoke(cli, ["batch", str(cfg), "--out", str(out), "--resume", "--no-progress"])
        lines = [ln for ln in res.output.splitlines() if ln.startswith("nhstab:")]
        assert res.exit_code == 2 and len(lines) == 1 and "'--resume'" in lines[0], res.output
        assert "Traceback" not in res.output
        assert _sha(store) == before


def test_a_resume_refused_by_a_running_batch_writes_nothing_into_its_store(finished, tmp_path):
    """A store missing its maps gains them when resumed; a second resume while a batch runs in the folder
    is refused before that write."""
    cfg, out = _copy(finished, tmp_path)
    store = out / STORE_NAME
    con = sqlite3.connect(store)
    with con:
        con.execute("DELETE FROM maps")
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.close()
    before = _sha(store)
    with _only_batch_in(out):                          # the running batch
        with pytest.raises(InputError) as err:
            run_batch(load_batch_config(cfg), out, workers=1, resume=True, progress=False)
    assert err.value.argument == "--out" and "another process" in str(err.value)
    assert _sha(store) == before
    assert not any(p.name.endswith(("-wal", "-shm")) for p in out.iterdir())
    # once the folder is free, the resume runs and restores the maps
    run_batch(load_batch_config(cfg), out, workers=1, resume=True, progress=False)
    con = sqlite3.connect(store)
    assert con.execute("SELECT COUNT(*) FROM maps").fetchone()[0] == 1
    con.close()
