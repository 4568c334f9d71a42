"""Running a batch: every trial that the store does not have yet, on local worker processes or on a
Dask distributed cluster, each committed to the store the moment it finishes.

Trials are independent (their seeds are fixed by the config), so the order in which they finish
does not change any result: a batch run with 1 or N workers, locally or on Dask, interrupted and
resumed or not, stores the same records (up to wall-clock timings).

Interruption (Ctrl-C, SIGINT): the batch stops, the trials already stored stay stored, the running
ones are abandoned (never stored: an interrupted trial has no result) and :class:`KeyboardInterrupt`
propagates (``nhstab batch`` exits with 130); ``--resume`` runs every trial without a row. Local
workers ignore SIGINT, so a Ctrl-C at a terminal (which signals the whole process group) and a
SIGINT to the driving process alone behave the same: the driver stops the workers.

Before anything is created in ``--out``, the config, the scheduler address and the connection to
it are checked, so a refused request leaves nothing behind; a resumed batch must match the stored
config's fingerprint, which covers the content of every map file (base maps and images included).
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import sys
import tempfile
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from ..errors import InputError
from .config import BatchConfig
from .store import Store, versions
from .trial import run_trial

STORE_NAME = "trials.sqlite"


def _progress(total: int, initial: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="trial", disable=not enabled, file=sys.stderr,
                dynamic_ncols=True, smoothing=0.1)


def _worker_init():
    # one core per worker: no nested threading in numpy's BLAS
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    # Ctrl-C is the driver's business (it stops the workers); SIGTERM from the driver ends the
    # running trial through the normal exit path, so that the planner's child process is reaped
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_term)


def _exit_on_term(signum, frame):
    raise SystemExit(128 + signum)


def open_store(config: BatchConfig, out_dir: Path, resume: bool) -> Store:
    """The batch's store in ``out_dir``: a new one (complete with its config, fingerprint and
    versions before it appears under its name), or with ``resume`` the existing one, checked to be
    a batch store (read-only) and made from the same config and map contents before it is opened
    for writing."""
    path = Path(out_dir) / STORE_NAME
    exists = os.path.lexists(path)
    if exists and not resume:
        raise InputError("--out", "a folder without a batch store (or --resume to continue it)", str(out_dir))
    if resume and not exists:
        raise InputError("--resume", "an existing batch store in --out", str(path))
    if resume:
        with Store(path, argument="--resume") as ro:
            stored = ro.meta("fingerprint")
            stored_config = ro.meta("config", {}) or {}
        if stored != config.fingerprint():
            raise InputError("CONFIG", "the config the store was made with (to resume it)", str(config.source),
                             detail=_difference(stored_config, config))
        return Store(path, writable=True, argument="--resume")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{STORE_NAME}.", suffix=".new", dir=path.parent)
    os.close(fd)
    os.unlink(tmp)
    try:
        with Store(tmp, create=True) as store:
            store.set_meta("config", config.describe())
            store.set_meta("fingerprint", config.fingerprint())
            store.set_meta("versions", versions())
            store.set_meta("created", time.time())
            store.db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        _publish(tmp, path)
    except FileExistsError:
        raise InputError("--out", "a folder without a batch store (or --resume to continue it)", str(out_dir)) \
            from None
    finally:
        for leftover in (tmp, tmp + "-wal", tmp + "-shm"):
            if os.path.lexists(leftover):
                os.unlink(leftover)
    return Store(path, writable=True, argument="--out")


def _publish(tmp: str, path: Path) -> None:
    """Give the finished new store its name without replacing one that appeared meanwhile: a hard
    link (no-clobber), or where the file system has none, a rename after a last check."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise
    except OSError:
        if os.path.lexists(path):
            raise FileExistsError(str(path)) from None
        os.rename(tmp, path)


def _difference(stored: dict, config: BatchConfig) -> str:
    """Why a resumed config does not match the store, as precisely as the stored config allows."""
    now = config.describe()
    old_maps = {m.get("label"): m for m in stored.get("maps", []) if isinstance(m, dict)}
    for i, m in enumerate(now["maps"]):
        old = old_maps.get(m["label"])
        if old is not None and old.get("content_hash") != m["content_hash"]:
            if not old.get("content_hash"):
                return f"the store was made by an nhstab that did not record map contents (maps[{i}])"
            return (f"maps[{i}] ({m['path']}) has changed since the store was made: content hash "
                    f"{m['content_hash'][:12]}, the store's {old['content_hash'][:12]}")
    for key in ("root_seed", "trials", "robots", "controllers", "grid", "run"):
        if stored.get(key) != now.get(key) and key in stored:
            return f"its {key!r} differs"
    return "the trials it defines differ"


def run_batch(config: BatchConfig, out_dir, workers: int = 1, scheduler: str | None = None, resume: bool = False,
              progress: bool = True) -> dict:
    """Run every trial of ``config`` missing from the store in ``out_dir``. Returns counts.

    A KeyboardInterrupt stops the batch (see the module docstring) and propagates; the trials stored
    until then stay stored."""
    out_dir = Path(out_dir)
    client = None
    if scheduler is not None:
        client = connect_dask(scheduler)     # before the store is made: a refused request leaves nothing behind
    try:
        specs = config.trial_specs()
        with open_store(config, out_dir, resume) as store:
            done = store.done_ids()
            todo = [s for s in specs if s["id"] not in done]
            bar = _progress(len(specs), len(specs) - len(todo), progress)
            started = time.perf_counter()
            try:
                if client is not None:
                    _run_dask(todo, client, store, bar)
                elif workers <= 1:
                    with _interrupt_flag() as interrupted:
                        for spec in todo:
                            record = run_trial(spec)
                            if interrupted.is_set():     # a Ctrl-C the trial's code may have swallowed
                                raise KeyboardInterrupt
                            _store(store, record)
                            bar.update(1)
                else:
                    _run_local(todo, workers, store, bar)
            finally:
                bar.close()
            return {"trials": len(specs), "ran": len(todo), "already_stored": len(specs) - len(todo),
                    "stored": store.count(), "wall_s": time.perf_counter() - started}
    finally:
        if client is not None:
            client.close()


@contextlib.contextmanager
def _interrupt_flag():
    """While trials run in this process: SIGINT raises KeyboardInterrupt as usual and also sets the
    flag, so that a trial during which Ctrl-C was pressed is never stored, even if some library
    code on the way caught the exception."""
    flag = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def handler(signum, frame):
        flag.set()
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, previous)


def _store(store: Store, record: dict) -> None:
    """Commit a finished trial. An interrupted one is not a result: the batch stops (the user
    pressed Ctrl-C while it ran in this process) and the trial will run again on --resume."""
    if record.get("status") == "interrupted":
        raise KeyboardInterrupt
    store.add(record)


def _run_local(todo: list, workers: int, store: Store, bar) -> None:
    import multiprocessing as mp

    # fork keeps the already imported modules; the planner forks its own child per call
    ctx = mp.get_context("fork")
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init)
    try:
        pending = set()
        queue = iter(todo)
        for spec in queue:
            pending.add(pool.submit(run_trial, spec))
            if len(pending) >= 2 * workers:
                break
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                _store(store, fut.result())
                bar.update(1)
                nxt = next(queue, None)
                if nxt is not None:
                    pending.add(pool.submit(run_trial, nxt))
    except BaseException:
        _stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Abandon the running trials: cancel what is queued, end the workers (SIGTERM, then SIGKILL
    after a grace period) and wait for them, so that no worker outlives the batch."""
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None     # a second Ctrl-C waits
    try:
        _end_workers(pool)
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)


def _end_workers(pool: ProcessPoolExecutor) -> None:
    # the executor has no public way to end its workers before Python 3.14: its process table
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + 10.0
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(5.0)


def _dask_trial(spec: dict) -> dict:
    """run_trial in a Dask worker. Dask runs tasks in daemonic processes, which multiprocessing
    forbids to start children; the planner forks one child per call (to seed OMPL) and joins it
    before returning, so the flag is lifted for the task."""
    import multiprocessing

    multiprocessing.current_process()._config.pop("daemon", None)
    return run_trial(spec)


_SCHEMES = ("tcp", "tls", "inproc", "ucx", "ws", "wss")
_HOST = re.compile(r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+)")


def check_scheduler_address(address) -> str:
    """A Dask scheduler address ``[scheme://]host[:port]`` (scheme one of tcp, tls, inproc, ucx, ws,
    wss; port 1..65535), or an InputError naming ``--scheduler``. Checked before anything else."""
    expected = "a Dask scheduler address like tcp://10.0.0.5:8786 (scheme://host:port)"
    if not isinstance(address, str) or not address.strip():
        raise InputError("--scheduler", expected, address)
    text = address.strip()
    scheme, sep, rest = text.partition("://")
    if not sep:
        scheme, rest = "tcp", text
    if scheme not in _SCHEMES:
        raise InputError("--scheduler", expected, address, detail=f"unknown scheme {scheme!r}; one of "
                         + ", ".join(_SCHEMES))
    if scheme == "inproc":
        return text
    host, colon, port = rest.rpartition(":") if not rest.endswith("]") else (rest, "", "")
    if not colon:
        host, port = rest, ""
    if not _HOST.fullmatch(host or "") or (port and not (port.isdigit() and 1 <= int(port) <= 65535)) \
            or (colon and not port):
        raise InputError("--scheduler", expected, address)
    return text


def connect_dask(scheduler: str):
    """A connected ``distributed.Client``: the address checked, Dask's presence checked, the
    scheduler reached (one-line errors naming ``--scheduler`` for each)."""
    address = check_scheduler_address(scheduler)
    require_dask(address)
    from distributed import Client

    try:
        return Client(address, timeout="20s")
    except (OSError, ValueError, TypeError) as exc:
        raise InputError("--scheduler", "the address of a running Dask scheduler", scheduler,
                         detail=" ".join(str(exc).split())[:160]) from None


def require_dask(scheduler: str) -> None:
    """Refuse ``--scheduler`` in one line when Dask's distributed package is not installed (it is the
    optional extra ``nhstab[cluster]``)."""
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        raise InputError("--scheduler", "Dask distributed installed: pip install 'nhstab[cluster]'", scheduler,
                         detail="local batches need no Dask: drop --scheduler and use --workers")


def _run_dask(todo: list, client, store: Store, bar) -> None:
    from distributed import as_completed

    futures = client.map(_dask_trial, todo, key=[f"nhstab-{s['id']}" for s in todo], pure=False)
    try:
        for fut in as_completed(futures):
            _store(store, fut.result())
            bar.update(1)
            fut.release()
    except BaseException:
        client.cancel(futures)
        raise
