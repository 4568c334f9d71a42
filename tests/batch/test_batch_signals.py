"""No process of a local batch outlives it, whatever signal ends it: SIGINT, SIGTERM or SIGHUP to the
driving process alone or to its whole process group (as a terminal, ``timeout`` or a job system
send them), and SIGKILL to the driver alone (the workers notice that their parent is gone)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ROOM = ROOT / "maps/ours/cluttered_room.yaml"

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")


def _stat(pid: int) -> tuple[str, int] | None:
    """(state, parent pid) of a process, or None when it does not exist."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return fields[0], int(fields[1])


def _children(pid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            st = _stat(int(d.name))
            if st is not None and st[1] == pid:
                out.append(int(d.name))
    return out


def _descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        for child in _children(todo.pop()):
            out.append(child)
            todo.append(child)
    return out


def _alive(pid: int) -> bool:
    st = _stat(pid)
    return st is not None and st[0] != "Z"       # a zombie has ended (its parent has not reaped it yet)


@pytest.mark.parametrize("target,signame", [
    ("group", "SIGINT"), ("group", "SIGTERM"), ("group", "SIGHUP"),
    ("driver", "SIGINT"), ("driver", "SIGTERM"), ("driver", "SIGHUP"), ("driver", "SIGKILL"),
    ("timeout", "SIGTERM"),          # what `timeout` does: the driver first, then its process group
])
@pytest.mark.slow
def test_no_worker_outlives_a_signalled_batch(tmp_path, target, signame):
    sig = getattr(signal, signame)
    cfg = tmp_path / "batch.yaml"
    cfg.write_text(f"name: s\nroot_seed: 3\ntrials: 6\nmaps:\n  - path: {ROOM}\ncontrollers: [gramian]\n")
    log = open(tmp_path / "log.txt", "w")
    proc = subprocess.Popen([sys.executable, "-m", "nhstab.cli.main", "batch", str(cfg), "--out",
                             str(tmp_path / "out"), "--workers", "2", "--no-progress"],
                            start_new_session=True, stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 60
        while len(_children(proc.pid)) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        time.sleep(1.0)                                # the workers are running their first trials
        workers = _descendants(proc.pid)
        assert len(workers) >= 2, (tmp_path / "log.txt").read_text()
        if target in ("driver", "timeout"):
            os.kill(proc.pid, sig)
        if target in ("group", "timeout"):
            os.killpg(proc.pid, sig)
        code = proc.wait(timeout=30)
        deadline = time.monotonic() + 5.0
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        survivors = [w for w in workers if _alive(w)]
        assert not survivors, f"{signame} to the {target}: workers {survivors} outlived the batch"
        text = (tmp_path / "log.txt").read_text()
        if sig == signal.SIGKILL:
            assert code == -signal.SIGKILL
        else:
            assert code == 128 + sig, text
            assert "Traceback" not in text and "--resume" in text.splitlines()[-1], text
    finally:
        log.close()
        for pid in [proc.pid, *workers]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        proc.wait(timeout=10)


@pytest.mark.slow
def test_a_batch_started_under_nohup_keeps_running_through_sighup(tmp_path):
    """SIGHUP ignored when the batch starts (nohup) stays ignored, in the driver and in its workers: the
    batch completes and stores every trial."""
    cfg = tmp_path / "batch.yaml"
    cfg.write_text(f"name: h\nroot_seed: 3\ntrials: 4\nmaps:\n  - path: {ROOM}\ncontrollers: [open-loop]\n"
                   "run: {max_time_s: 3.0, tube: {kind: linear}}\n")
    log = open(tmp_path / "log.txt", "w")

    def nohup():
        signal.signal(signal.SIGHUP, signal.SIG_IGN)

    proc = subprocess.Popen([sys.executable, "-m", "nhstab.cli.main", "batch", str(cfg), "--out",
                             str(tmp_path / "out"), "--workers", "2", "--no-progress"],
                            start_new_session=True, stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path,
                            preexec_fn=nohup)
    try:
        deadline = time.monotonic() + 60
        while len(_children(proc.pid)) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        assert len(_children(proc.pid)) >= 2
        os.killpg(proc.pid, signal.SIGHUP)
        assert proc.wait(timeout=120) == 0, (tmp_path / "log.txt").read_text()
    finally:
        log.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    from nhstab.batch.store import Store

    with Store(tmp_path / "out" / "trials.sqlite") as store:
        assert store.count() == 4
