"""The batch store: one SQLite database per batch (WAL mode), one row per finished trial.

Every trial is committed on its own transaction as soon as it finishes, so a batch killed at any
moment (even with SIGKILL) loses at most the trials that were running; ``--resume`` then runs
exactly the trials that have no row. Rows are written by the process that drives the batch (the
workers return their records), so there is one writer.

Tables:
    meta(key TEXT PRIMARY KEY, value TEXT)          -- the batch config (JSON), versions, created
    trials(id TEXT PRIMARY KEY, cell TEXT, trial INTEGER, seed INTEGER, spec TEXT, status TEXT,
           metrics TEXT, series TEXT, timings TEXT, error TEXT, versions TEXT, finished_at REAL)
``spec``, ``metrics``, ``series``, ``timings`` and ``versions`` hold JSON.
"""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path

from ..records import to_jsonable

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS trials (
    id TEXT PRIMARY KEY,
    cell TEXT NOT NULL,
    trial INTEGER NOT NULL,
    seed INTEGER NOT NULL,
    spec TEXT NOT NULL,
    status TEXT NOT NULL,
    metrics TEXT,
    series TEXT,
    timings TEXT,
    error TEXT,
    versions TEXT,
    finished_at REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS trials_cell ON trials(cell);
"""


def versions() -> dict:
    """Versions of nhstab and the libraries a trial's result depends on."""
    import platform
    from importlib import metadata

    out = {"python": platform.python_version()}
    for dist in ("nhstab", "numpy", "scipy", "ompl", "python-fcl", "matplotlib"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


class Store:
    """A batch's SQLite database. Use as a context manager or call :meth:`close`."""

    def __init__(self, path, create: bool = False):
        self.path = Path(path)
        if not create and not self.path.is_file():
            from ..errors import InputError

            raise InputError("STORE", "an existing batch database (trials.sqlite)", str(self.path))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(self.path, timeout=60.0)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=NORMAL")
        self.db.executescript(_SCHEMA)
        self.db.commit()

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.db.close()

    # ---- meta -----------------------------------------------------------------------------------
    def set_meta(self, key: str, value) -> None:
        with self.db:
            self.db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)",
                            (key, json.dumps(to_jsonable(value), sort_keys=True)))

    def meta(self, key: str, default=None):
        row = self.db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return default if row is None else json.loads(row[0])

    # ---- trials ---------------------------------------------------------------------------------
    def done_ids(self) -> set[str]:
        return {r[0] for r in self.db.execute("SELECT id FROM trials")}

    def add(self, record: dict) -> bool:
        """Commit one finished trial. Returns False (and writes nothing) if its id is already stored,
        so that a trial is never recorded twice."""
        row = (record["id"], record["cell"], int(record["trial"]), int(record["seed"]),
               _dump(record["spec"]), record["status"], _dump(record.get("metrics")), _dump(record.get("series")),
               _dump(record.get("timings")), record.get("error"), _dump(record.get("versions")),
               float(record.get("finished_at", time.time())))
        with self.db:
            cur = self.db.execute("INSERT OR IGNORE INTO trials VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", row)
        return cur.rowcount == 1

    def trials(self, cell: str | None = None, trial_id: str | None = None) -> list[dict]:
        """Stored trials (all, one cell's, or the one with ``trial_id``), ordered by cell and trial."""
        where, args = [], []
        if cell is not None:
            where.append("cell = ?")
            args.append(cell)
        if trial_id is not None:
            where.append("id = ?")
            args.append(trial_id)
        q = ("SELECT id, cell, trial, seed, spec, status, metrics, series, timings, error, versions, finished_at "
             "FROM trials" + (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY cell, trial")
        rows = self.db.execute(q, args)
        keys = ("id", "cell", "trial", "seed", "spec", "status", "metrics", "series", "timings", "error", "versions",
                "finished_at")
        out = []
        for r in rows:
            d = dict(zip(keys, r))
            for k in ("spec", "metrics", "series", "timings", "versions"):
                d[k] = json.loads(d[k]) if d[k] is not None else None
            out.append(d)
        return out

    def trial(self, trial_id: str) -> dict | None:
        found = self.trials(trial_id=trial_id)
        return found[0] if found else None

    def count(self) -> int:
        return int(self.db.execute("SELECT COUNT(*) FROM trials").fetchone()[0])


def _dump(value) -> str | None:
    return None if value is None else json.dumps(to_jsonable(value), sort_keys=True)
