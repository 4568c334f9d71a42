"""Running a batch: every trial that the store does not have yet, on local worker processes or on a
Dask distributed cluster, each committed to the store the moment it finishes.

Trials are independent (their seeds are fixed by the config), so the order in which they finish
does not change any result: a batch run with 1 or N workers, locally or on Dask, interrupted and
resumed or not, stores the same records (up to wall-clock timings).

Interruption (Ctrl-C, SIGINT): the batch stops, the trials already stored stay stored, the running
ones are abandoned (never stored: an interrupted trial has no result) and :class:`KeyboardInterrupt`
propagates (``nhstab batch`` exits with 130); ``--resume`` runs every trial without a row. Local
workers ignore SIGINT, so a Ctrl-C at a terminal (which signals the whole process group) and a
SIGINT to the driving process alone behave the same: the driver stops the workers. SIGTERM and
SIGHUP stop the batch the same way (:class:`BatchSignal`, a KeyboardInterrupt); a worker they reach
directly ends at once with its children. A worker whose driver is gone (killed with SIGKILL) ends
too (:func:`_die_with`), so no process of a batch outlives it.

Before anything is created in ``--out``, the config, the scheduler address and the connection to
it are checked, so a refused request leaves nothing behind; a resumed batch must match the stored
config's fingerprint, which covers the content of every map file (base maps and images included).

What a trial needs travels with it, as data: its spec (robot description, run options, seed,
poses) and its map as a :class:`~nhstab.batch.bundle.MapBundle` (the bytes of every file the map
is built from). No worker reads a path of the submitting machine. On Dask, each map's packed bundle
is scattered once per batch to every worker (``broadcast=True``) and passed to the map's trials as
a shared future; local workers receive the bundles when they start. Every worker loads a map once
(cached by bundle id) from a private copy of its files. The store keeps the bundles (its ``maps``
table), so replays need the store alone. The bytes each invocation ships (bundles and copies,
pickled specs sent, pickled records received) are returned in the counts and appended to the
store's meta ``runs``.

A trial that fails by error (an exception, not an outcome such as a collision) is stored with its
message and does not stop the batch; the counts say how many of this run's trials did, with the
first message (``nhstab batch`` prints them, and exits 1 when every trial errored). Problems of
the cluster itself are not trial errors: a worker without nhstab (or with another version) stops
the batch with one line naming ``--scheduler``; a trial whose worker died (Dask's ``KilledWorker``)
is stored as an error.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import re
import signal
import sys
import tempfile
import threading
import time
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, fields
from pathlib import Path

from .. import __version__
from ..collision import defer_interrupt
from ..control import PAST_WINDOW_WARNING
from ..errors import InputError, NotStabilizingWarning
from .bundle import MapChangedError
from .config import BatchConfig
from .store import Store, versions
from .trial import provide_bundles, run_trial, withdraw_bundles

STORE_NAME = "trials.sqlite"


def _progress(total: int, initial: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="trial", disable=not enabled, file=sys.stderr,
                dynamic_ncols=True, smoothing=0.1)


def _worker_init(bundles: dict | None = None, driver: int | None = None):
    if bundles:
        provide_bundles(bundles)
    # one core per worker: no nested threading in numpy's BLAS
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    # Ctrl-C is the driver's business (it stops the workers). SIGTERM (from the driver, or sent to
    # the whole process group) and SIGHUP end the worker at once, with its own children: the pool's
    # loop would catch an exception raised by the handler and wait for the next trial for ever
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_exit)
    if hasattr(signal, "SIGHUP") and signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN:     # not under nohup
        signal.signal(signal.SIGHUP, _worker_exit)
    if driver is not None:
        _die_with(driver)


def _worker_exit(signum, frame):
    """End this worker now: its children first (a planner's forked search), then the process, without
    going back to the pool's loop."""
    import multiprocessing as mp

    children = mp.active_children()
    for child in children:
        with contextlib.suppress(Exception):
            child.terminate()
    for child in children:
        with contextlib.suppress(Exception):
            child.join(1.0)
            if child.is_alive():
                child.kill()
    os._exit(128 + signum)


#: how often a worker without PR_SET_PDEATHSIG checks that its driver is alive [s]
PARENT_POLL_S = 0.5


def _die_with(driver: int) -> None:
    """End this worker (as SIGTERM does) when the driving process ``driver`` is gone, however it ended
    (SIGKILL included): on Linux the kernel sends SIGTERM when the parent dies (prctl
    PR_SET_PDEATHSIG; the pool forks its workers from the thread that runs the batch, which lives as
    long as the batch); elsewhere a daemon thread checks every PARENT_POLL_S that the parent is still
    ``driver``. A driver already gone when this runs ends the worker at once."""
    armed = False
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(1, int(signal.SIGTERM), 0, 0, 0) == 0         # PR_SET_PDEATHSIG = 1
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != driver:
        _worker_exit(signal.SIGTERM, None)
    if not armed:
        threading.Thread(target=_watch_driver, args=(driver,), name="nhstab-driver-watch", daemon=True).start()


def _watch_driver(driver: int) -> None:
    while os.getppid() == driver:
        time.sleep(PARENT_POLL_S)
    os.kill(os.getpid(), signal.SIGTERM)


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
            ro.verify()                 # every page and row read: a corrupt store is refused unchanged
            stored = ro.meta("fingerprint")
            stored_config = ro.meta("config", {}) or {}
        if stored != config.fingerprint():
            raise InputError("CONFIG", "the config the store was made with (to resume it)", str(config.source),
                             detail=_difference(stored_config, config))
        store = Store(path, writable=True, argument="--resume")
        try:
            for bundle in config.bundles().values():     # a store of schema 1 gains its maps
                store.add_map(bundle)
        except BaseException:
            store.close()
            raise
        return store
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
            for bundle in config.bundles().values():
                store.add_map(bundle)
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


@dataclass(frozen=True)
class BatchSummary:
    """What one :func:`run_batch` call did: the counts of this invocation and of the whole store.

    Attributes
    ----------
    trials : int
        The trials of the config (cells x trials per cell).
    ran : int
        The trials this call ran (those missing from the store).
    already_stored : int
        The trials the store held before this call (``trials - ran``).
    stored : int
        The trials in the store after this call.
    wall_s : float
        Wall-clock time [s] this call spent running trials.
    outcomes : dict
        ``{status: count}`` of this call's trials (e.g. ``"reached"``, ``"collision"``, ``"error"``).
    errors : int
        This call's trials that failed by error (an exception, not an outcome).
    first_error : tuple of (str, str) or None
        The first of them: its trial id and message.
    stored_errors : int
        The trials stored with an error in the whole store.
    transfer : dict
        The bytes this call shipped: ``bundle_bytes`` (per map), ``bundle_copies``,
        ``bundles_sent_bytes``, ``specs_sent_bytes``, ``records_received_bytes``, ``trials``,
        ``spec_bytes_per_trial`` and ``record_bytes_per_trial`` (None when no trial ran).
    """

    trials: int
    ran: int
    already_stored: int
    stored: int
    wall_s: float
    outcomes: dict
    errors: int
    first_error: tuple[str, str] | None
    stored_errors: int
    transfer: dict

    def as_dict(self) -> dict:
        """The summary as a plain dict with the attribute names as keys, in their order (JSON-ready
        but for ``first_error``, a tuple)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def run_batch(config: BatchConfig, out_dir: str | os.PathLike, workers: int = 1, scheduler: str | None = None,
              resume: bool = False, progress: bool = True, retry_errors: bool = False) -> BatchSummary:
    """Run every trial of ``config`` missing from the store in ``out_dir``.

    Each trial is committed to ``out_dir/trials.sqlite`` the moment it finishes; see the module
    docstring for interruption, resumption and what travels to the workers.

    Parameters
    ----------
    config : BatchConfig
        The batch (:func:`nhstab.load_batch_config`).
    out_dir : str or path-like
        The batch folder; it holds the store ``trials.sqlite``.
    workers : int
        Local worker processes (1: the trials run in this process).
    scheduler : str, optional
        Address of a Dask distributed scheduler (e.g. ``"tcp://10.0.0.5:8786"``); ``workers`` is then
        not used.
    resume : bool
        Continue the batch stored in ``out_dir`` (its config must match ``config``): run each missing
        trial once.
    progress : bool
        Show a progress bar on stderr.
    retry_errors : bool
        With ``resume``: remove the trials stored with an error and run them again.

    Returns
    -------
    BatchSummary
        The counts of this call and of the store (``.as_dict()``: a plain dict).

    Raises
    ------
    InputError
        For a bad request: ``retry_errors`` without ``resume``, an ``out_dir`` that already holds a
        store (without ``resume``) or another running batch, a stored batch that does not match
        ``config``, an unreachable scheduler.
    KeyboardInterrupt
        On Ctrl-C (or :class:`BatchSignal` on SIGTERM and SIGHUP): the batch stops; the trials stored
        until then stay stored.
    """
    out_dir = Path(out_dir)
    client = None
    if retry_errors and not resume:
        raise InputError("--retry-errors", "used with --resume (it reruns the errors of a stored batch)", "alone")
    if scheduler is not None:
        client = connect_dask(scheduler)     # before the store is made: a refused request leaves nothing behind
    if "past" in config.windows():       # once here; the trials do not repeat it

        warnings.warn(PAST_WINDOW_WARNING, NotStabilizingWarning, stacklevel=2)
    try:
        if client is not None:
            check_workers(client, scheduler)
        specs = config.trial_specs()
        with contextlib.ExitStack() as held:
            # a resumed store is locked before it is opened for writing (nothing is written by a refused
            # second resume); a new one once it exists under its name
            early = resume and os.path.isdir(out_dir)
            if early:
                held.enter_context(_only_batch_in(out_dir))
            store = held.enter_context(open_store(config, out_dir, resume))
            if not early:
                held.enter_context(_only_batch_in(out_dir))
            if retry_errors:
                store.remove_errors()
            done = store.done_ids()
            todo = [s for s in specs if s["id"] not in done]
            bar = _progress(len(specs), len(specs) - len(todo), progress)
            tally = _Tally(config.bundles())
            started = time.perf_counter()
            try:
                with _stop_signals() as stopping:
                    if client is not None:
                        _run_dask(todo, client, store, bar, config.bundles(), tally)
                    elif workers <= 1:
                        _run_serial(todo, store, bar, config.bundles(), tally, stopping)
                    else:
                        _run_local(todo, workers, store, bar, config.bundles(), tally)
            finally:
                bar.close()
                wall = time.perf_counter() - started
                _record_run(store, tally, "dask" if client is not None else "local",
                            scheduler if client is not None else workers, wall)
            errors = store.errors()
            return BatchSummary(trials=len(specs), ran=len(todo), already_stored=len(specs) - len(todo),
                                stored=store.count(), wall_s=wall, outcomes=dict(tally.outcomes), errors=tally.errors,
                                first_error=tally.first_error, stored_errors=len(errors), transfer=tally.transfer())
    finally:
        if client is not None:
            client.close()


@contextlib.contextmanager
def _only_batch_in(out_dir: Path):
    """While a batch runs, an exclusive lock on its folder (flock: the system releases it when the
    process ends, however it ends), so that a second ``nhstab batch --resume`` on the same folder is
    refused instead of running the same missing trials again beside the first (the store kept one
    copy of each, but the work was done twice and each reported trials the other had stored)."""
    import fcntl

    fd = os.open(out_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError("--out", "a batch folder no other nhstab batch is running in", str(out_dir),
                             detail="another process is running this batch; --resume once it has ended") from None
        _LOCK_FDS.add(fd)
        yield
    finally:
        _LOCK_FDS.discard(fd)
        os.close(fd)


#: the folder locks this process holds (:func:`_only_batch_in`)
_LOCK_FDS: set[int] = set()


def _drop_locks_in_child() -> None:
    """A forked process (a local worker) closes its copies of the folder locks: the lock is the
    batch's, and a worker outliving its batch (its parent killed alone) must not keep --resume out."""
    for fd in _LOCK_FDS:
        with contextlib.suppress(OSError):
            os.close(fd)
    _LOCK_FDS.clear()


os.register_at_fork(after_in_child=_drop_locks_in_child)


class _Tally:
    """What this run stored: outcomes, errors (the first with its trial id), and the bytes shipped:
    each map's packed bundle and how many copies were sent, and every trial's pickled spec (sent)
    and record (received), the objects the executor serialises with pickle."""

    def __init__(self, bundles: dict):
        self.outcomes: dict = {}
        self.errors = 0
        self.first_error: tuple[str, str] | None = None
        self.bundle_bytes = {key: len(b.packed) for key, b in bundles.items()}
        self.bundle_copies = 0
        self.bundles_sent = 0
        self.sent = 0
        self.received = 0
        self.trials = 0

    def spec(self, spec: dict) -> None:
        self.sent += len(pickle.dumps(spec, protocol=pickle.HIGHEST_PROTOCOL))

    def record(self, record: dict) -> None:
        self.trials += 1
        self.received += len(pickle.dumps(record, protocol=pickle.HIGHEST_PROTOCOL))
        status = record.get("status")
        self.outcomes[status] = self.outcomes.get(status, 0) + 1
        if status == "error":
            self.errors += 1
            if self.first_error is None:
                self.first_error = (record["id"], record.get("error") or "")

    def transfer(self) -> dict:
        n = max(self.trials, 1)
        return {"bundle_bytes": dict(self.bundle_bytes), "bundle_copies": self.bundle_copies,
                "bundles_sent_bytes": self.bundles_sent, "specs_sent_bytes": self.sent, "records_received_bytes": self.received, "trials": self.trials,
                "spec_bytes_per_trial": self.sent / n if self.trials else None,
                "record_bytes_per_trial": self.received / n if self.trials else None}


def _record_run(store: Store, tally: _Tally, executor: str, where, wall: float) -> None:
    """Append this invocation to the store's meta ``runs`` (executor, workers or scheduler, trials
    stored, wall time, bytes shipped)."""
    try:
        runs = store.meta("runs", []) or []
        if not isinstance(runs, list):
            runs = []
        runs.append({"executor": executor, "workers": where if executor == "local" else None,
                     "scheduler": where if executor == "dask" else None, "stored": tally.trials,
                     "errors": tally.errors, "wall_s": wall, "finished": time.time(), "transfer": tally.transfer()})
        store.set_meta("runs", runs)
    except Exception:        # bookkeeping must never cost the stored trials (e.g. during Ctrl-C)
        pass


def _run_serial(todo: list, store: Store, bar, bundles: dict, tally: _Tally, stopping=None) -> None:
    provide_bundles(bundles)
    try:
        for spec in todo:
            record = run_trial(spec)
            if stopping is not None and stopping.is_set():     # a signal the trial's code may have swallowed
                raise stopping.exception()
            _store(store, record, tally)
            bar.update(1)
    finally:
        withdraw_bundles(bundles)


class BatchSignal(KeyboardInterrupt):
    """SIGTERM or SIGHUP stopped the batch: handled as Ctrl-C is (the running trials are abandoned and
    the workers ended); ``signum`` says which (``nhstab batch`` exits with 128 + signum)."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        super().__init__(signal.Signals(self.signum).name)


#: the signals that stop a batch (each ends every worker before the batch returns)
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class _Stopping(threading.Event):
    """Set by the first stop signal; ``signum`` is that signal's."""

    signum: int = signal.SIGINT

    def exception(self) -> KeyboardInterrupt:
        return KeyboardInterrupt() if self.signum == signal.SIGINT else BatchSignal(self.signum)


@contextlib.contextmanager
def _stop_signals():
    """While the batch runs: the first SIGINT raises KeyboardInterrupt, the first SIGTERM or SIGHUP
    :class:`BatchSignal`, in the driving process, so that the batch stops its workers on its way out
    (a process killed by the signal's default action would leave them running); the flag is set too,
    so that a trial during which one arrived is never stored even if library code on the way caught
    the exception. Later signals wait (the batch is already stopping; ``timeout`` sends SIGTERM to
    the process and then to its group). A signal the process ignores (SIGHUP under nohup, SIGINT in a
    background job) stays ignored. Outside the main thread nothing is installed."""
    flag = _Stopping()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def handler(signum, frame):
        if flag.is_set():
            return
        flag.signum = signum
        flag.set()
        if signum != signal.SIGINT:
            raise BatchSignal(signum)
        if not defer_interrupt(frame):       # inside an FCL callback: raised when FCL returns
            raise KeyboardInterrupt

    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS
                if signal.getsignal(sig) is not signal.SIG_IGN}
    try:
        try:
            yield flag
        except KeyboardInterrupt as exc:
            if flag.is_set() and flag.signum != signal.SIGINT and not isinstance(exc, BatchSignal):
                raise BatchSignal(flag.signum) from exc     # the signal, whatever the trial turned it into
            raise
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _store(store: Store, record: dict, tally: _Tally) -> None:
    """Commit a finished trial. An interrupted one is not a result: the batch stops (the user
    pressed Ctrl-C while it ran in this process) and the trial will run again on --resume."""
    if record.get("status") == "interrupted":
        raise KeyboardInterrupt
    if store.add(record):
        tally.record(record)


def _run_local(todo: list, workers: int, store: Store, bar, bundles: dict, tally: _Tally) -> None:
    import multiprocessing as mp

    # fork keeps the already imported modules (and the maps the config loaded); the workers get the
    # bundles as their initializer's argument, so that any start method gives them the same maps
    ctx = mp.get_context("fork")
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                               initargs=(bundles, os.getpid()))
    try:
        pending = set()
        queue = iter(todo)

        def submit(spec):
            tally.spec(spec)
            pending.add(pool.submit(run_trial, spec))

        for spec in queue:
            submit(spec)
            if len(pending) >= 2 * workers:
                break
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                _store(store, fut.result(), tally)
                bar.update(1)
                nxt = next(queue, None)
                if nxt is not None:
                    submit(nxt)
    except BaseException:
        _stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Abandon the running trials: cancel what is queued, end the workers (SIGTERM, then SIGKILL
    after a grace period) and wait for them, so that no worker outlives the batch."""
    main = threading.current_thread() is threading.main_thread()
    # a second Ctrl-C (or SIGTERM, SIGHUP) waits for the workers' end
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in STOP_SIGNALS} if main else {}
    try:
        _end_workers(pool)
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _end_workers(pool: ProcessPoolExecutor) -> None:
    # the executor has no public way to end its workers before Python 3.14: its process table, and
    # the manager thread with its result queue (shutdown(wait=False) drops the references)
    procs = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    results = getattr(pool, "_result_queue", None)
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
    _release_manager(manager, results)


def _release_manager(manager, results) -> None:
    """A worker ended while it wrote a record larger than a pipe's buffer leaves the executor's manager
    thread reading the rest of it for ever (this process holds the pipe's write end too), and the
    interpreter joins that thread at exit: the batch hung after its "interrupted" line. With the
    workers gone, closing this process's write end turns the read into end-of-file; the manager then
    finds the pool broken and ends."""
    if manager is None or not manager.is_alive():
        return
    writer = getattr(results, "_writer", None)
    if writer is not None:
        with contextlib.suppress(OSError):
            writer.close()
    manager.join(10.0)


def _dask_trial(spec: dict, bundle: bytes, version: str) -> dict:
    """run_trial in a Dask worker, with the map's packed bundle (a scattered future, resolved by Dask
    to the bytes held by this worker) and the submitting nhstab's version, which this worker's must
    equal. Dask runs tasks in daemonic processes, which multiprocessing forbids to start children;
    the planner may fork one child per call (``isolate``) and joins it before returning, so the flag
    is lifted for the task."""
    import multiprocessing


    if version != __version__:
        raise WorkerMismatch(version, __version__)
    multiprocessing.current_process()._config.pop("daemon", None)
    return run_trial(spec, bundle)


class WorkerMismatch(Exception):
    """A Dask worker runs another nhstab than the submitting machine."""

    def __init__(self, wanted: str, found: str):
        super().__init__(wanted, found)
        self.wanted, self.found = wanted, found

    def __str__(self) -> str:
        return f"a worker runs nhstab {self.found}, this machine {self.wanted}"


def _worker_versions() -> dict:
    return {**versions(), "nhstab": __version__}


def check_workers(client, scheduler: str) -> dict:
    """The workers connected now, each checked to run this nhstab version (one line naming
    ``--scheduler`` otherwise: install ``nhstab[cluster]`` of the same version on every worker).
    Returns their versions by address. A cluster without workers yet (e.g. an adaptive one) is
    not refused: its trials wait for workers, each checked when it runs one."""
    expected = f"Dask workers with nhstab {__version__} installed (the version of this machine)"
    try:
        found = client.run(_worker_versions)
    except Exception as exc:          # e.g. ModuleNotFoundError: nhstab is not installed there
        raise InputError("--scheduler", expected, scheduler,
                         detail=f"a worker could not run nhstab: {type(exc).__name__}: {_one_line(exc)}"[:240]) \
            from None
    wrong = {addr: v.get("nhstab") for addr, v in found.items() if v.get("nhstab") != __version__}
    if wrong:
        addr, v = next(iter(wrong.items()))
        raise InputError("--scheduler", expected, scheduler,
                         detail=f"{len(wrong)} of {len(found)} workers run another: {addr} has nhstab {v}")
    return found


def _one_line(exc) -> str:
    return " ".join(str(exc).split())


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


def _run_dask(todo: list, client, store: Store, bar, bundles: dict, tally: _Tally) -> None:
    """Each map's packed bundle scattered once to every worker, then every trial with its map's
    future; records stored as they come back (see the module docstring)."""
    from distributed import as_completed


    if not todo:
        return
    needed = sorted({s["cell_spec"]["map_bundle"] for s in todo})
    shared = {}
    for key in needed:
        shared[key] = client.scatter(bundles[key].packed, broadcast=True, hash=False)
    tally.bundle_copies = len(client.nthreads())          # one copy per worker connected now
    tally.bundles_sent = tally.bundle_copies * sum(tally.bundle_bytes[key] for key in needed)
    for spec in todo:
        tally.spec(spec)
    by_key = {f"nhstab-{s['id']}": s for s in todo}
    futures = client.map(_dask_trial, todo, [shared[s["cell_spec"]["map_bundle"]] for s in todo],
                         [__version__] * len(todo), key=list(by_key), pure=False)
    try:
        for fut in as_completed(futures):
            try:
                record = fut.result()
            except (KeyboardInterrupt, MapChangedError):
                raise
            except WorkerMismatch as exc:
                raise InputError("--scheduler", f"Dask workers with nhstab {exc.wanted} installed (the version of "
                                 "this machine)", str(exc)) from None
            except Exception as exc:
                if type(exc).__name__ != "KilledWorker":
                    raise InputError("--scheduler", "Dask workers that can run nhstab trials", type(exc).__name__,
                                     detail=_one_line(exc)[:240]) from None
                record = _lost_trial(by_key[fut.key], exc)
            _store(store, record, tally)
            bar.update(1)
            fut.release()
    except BaseException:
        client.cancel(futures)
        raise
    finally:
        for f in shared.values():
            f.release()


def _lost_trial(spec: dict, exc) -> dict:
    """The record of a trial whose worker died running it (Dask gave up on it: ``KilledWorker``):
    an error, the crash being what the trial did."""
    return {"id": spec["id"], "cell": spec["cell"], "trial": spec["trial"], "seed": spec["seed"], "spec": spec,
            "versions": versions(), "status": "error", "metrics": None, "series": None,
            "error": f"{type(exc).__name__}: the worker running it died ({_one_line(exc)[:160]})",
            "timings": {}, "finished_at": time.time()}
