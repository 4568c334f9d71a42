"""Running a batch: every trial that the store does not have yet, on local worker processes or on a
Dask distributed cluster, each committed to the store the moment it finishes.

Trials are independent (their seeds are fixed by the config), so the order in which they finish
does not change any result: a batch run with 1 or N workers, locally or on Dask, interrupted and
resumed or not, stores the same records (up to wall-clock timings).
"""

from __future__ import annotations

import os
import sys
import time
import warnings
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


def open_store(config: BatchConfig, out_dir: Path, resume: bool) -> Store:
    path = Path(out_dir) / STORE_NAME
    if path.exists() and not resume:
        raise InputError("--out", "a folder without a batch store (or --resume to continue it)", str(out_dir))
    if resume and not path.exists():
        raise InputError("--resume", "an existing batch store in --out", str(path))
    store = Store(path, create=True)
    stored = store.meta("fingerprint")
    if stored is None:
        store.set_meta("config", config.describe())
        store.set_meta("fingerprint", config.fingerprint())
        store.set_meta("versions", versions())
        store.set_meta("created", time.time())
    elif stored != config.fingerprint():
        store.close()
        raise InputError("CONFIG", "the config the store was made with (to resume it)", str(config.source),
                         detail="the trials it defines differ")
    return store


def run_batch(config: BatchConfig, out_dir, workers: int = 1, scheduler: str | None = None, resume: bool = False,
              progress: bool = True) -> dict:
    """Run every trial of ``config`` missing from the store in ``out_dir``. Returns counts."""
    out_dir = Path(out_dir)
    if scheduler:
        require_dask(scheduler)          # before the store is made: a refused request leaves nothing behind
    if "past" in config.windows():       # once here; the trials do not repeat it
        from ..control import PAST_WINDOW_WARNING
        from ..errors import NotStabilizingWarning

        warnings.warn(PAST_WINDOW_WARNING, NotStabilizingWarning, stacklevel=2)
    specs = config.trial_specs()
    with open_store(config, out_dir, resume) as store:
        done = store.done_ids()
        todo = [s for s in specs if s["id"] not in done]
        bar = _progress(len(specs), len(specs) - len(todo), progress)
        started = time.perf_counter()
        try:
            if scheduler:
                _run_dask(todo, scheduler, store, bar)
            elif workers <= 1:
                for spec in todo:
                    store.add(run_trial(spec))
                    bar.update(1)
            else:
                _run_local(todo, workers, store, bar)
        finally:
            bar.close()
        return {"trials": len(specs), "ran": len(todo), "already_stored": len(specs) - len(todo),
                "stored": store.count(), "wall_s": time.perf_counter() - started}


def _run_local(todo: list, workers: int, store: Store, bar) -> None:
    import multiprocessing as mp

    # fork keeps the already imported modules; the planner forks its own child per call
    ctx = mp.get_context("fork")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init) as pool:
        pending = set()
        queue = iter(todo)
        for spec in queue:
            pending.add(pool.submit(run_trial, spec))
            if len(pending) >= 2 * workers:
                break
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                store.add(fut.result())
                bar.update(1)
                nxt = next(queue, None)
                if nxt is not None:
                    pending.add(pool.submit(run_trial, nxt))


def _dask_trial(spec: dict) -> dict:
    """run_trial in a Dask worker. Dask runs tasks in daemonic processes, which multiprocessing
    forbids to start children; the planner forks one child per call (to seed OMPL) and joins it
    before returning, so the flag is lifted for the task."""
    import multiprocessing

    multiprocessing.current_process()._config.pop("daemon", None)
    return run_trial(spec)


def require_dask(scheduler: str) -> None:
    """Refuse ``--scheduler`` in one line when Dask's distributed package is not installed (it is the
    optional extra ``nhstab[cluster]``)."""
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        raise InputError("--scheduler", "Dask distributed installed: pip install 'nhstab[cluster]'", scheduler,
                         detail="local batches need no Dask: drop --scheduler and use --workers")


def _run_dask(todo: list, scheduler: str, store: Store, bar) -> None:
    from distributed import Client, as_completed

    try:
        client = Client(scheduler, timeout="20s")
    except OSError as exc:
        raise InputError("--scheduler", "the address of a running Dask scheduler", scheduler,
                         detail=" ".join(str(exc).split())[:160]) from None
    try:
        futures = client.map(_dask_trial, todo, key=[f"nhstab-{s['id']}" for s in todo], pure=False)
        for fut in as_completed(futures):
            store.add(fut.result())
            bar.update(1)
            fut.release()
    finally:
        client.close()
