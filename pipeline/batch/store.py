"""The batch store: one SQLite database per batch (WAL mode), one row per finished trial.

Every trial is committed on its own transaction as soon as it finishes, so a batch killed at any
moment (even with SIGKILL) loses at most the trials that were running; ``--resume`` then runs
exactly the trials that have no row. Rows are written by the process that drives the batch (the
workers return their records), so there is one writer. A trial that was interrupted (Ctrl-C) is
never stored: it has no result.

Opening is careful, because the path comes from the user: the file must be an SQLite database
whose tables are a batch store's (checked on a read-only connection, before anything is written),
and a store is opened read-only unless it is being written (a report or a replay never changes a
byte of it, nor creates files beside it). A file of another application, a truncated or corrupt
database, or an empty one is refused with one line (:class:`StoreError`, exit code 2).

Tables:
    meta(key TEXT PRIMARY KEY, value TEXT)          -- the batch config (JSON), versions, created,
                                                       schema version
    trials(id TEXT PRIMARY KEY, cell TEXT, trial INTEGER, seed INTEGER, spec TEXT, status TEXT,
           metrics TEXT, series TEXT, timings TEXT, error TEXT, versions TEXT, finished_at REAL)
``spec``, ``metrics``, ``series``, ``timings`` and ``versions`` hold JSON.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
import urllib.parse
from pathlib import Path

from ..errors import InputError
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
_COLUMNS = {"meta": ("key", "value"),
            "trials": ("id", "cell", "trial", "seed", "spec", "status", "metrics", "series", "timings", "error",
                       "versions", "finished_at")}
_SQLITE_MAGIC = b"SQLite format 3\x00"
#: statuses that are results; "interrupted" is not one (the trial did not finish)
NOT_A_RESULT = ("interrupted",)


class StoreError(InputError):
    """A path given as a batch store is not one (missing, another application's database, corrupt)."""


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
    """A batch's SQLite database. Use as a context manager or call :meth:`close`.

    ``Store(path)`` opens an existing store read-only; ``writable=True`` opens it for writing (after
    the same checks); ``create=True`` makes a new store if ``path`` does not exist, and otherwise
    opens the existing one for writing (after the checks). ``argument`` names the path in errors.
    """

    def __init__(self, path, create: bool = False, writable: bool | None = None, argument: str = "STORE"):
        self.path = Path(path)
        self.argument = argument
        self.writable = create if writable is None else bool(writable)
        self.db = None
        new = create and not os.path.lexists(self.path)
        if not new:
            check_store_file(self.path, argument)
        try:
            if self.writable:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.db = sqlite3.connect(self.path, timeout=60.0)
                self.db.execute("PRAGMA journal_mode=WAL")
                self.db.execute("PRAGMA synchronous=NORMAL")
                if new:
                    self.db.executescript(_SCHEMA)
                    with self.db:
                        self.db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES ('schema', ?)",
                                        (json.dumps(SCHEMA_VERSION),))
            else:
                self.db = _connect_read_only(self.path)
        except sqlite3.Error as exc:
            self.close()
            raise self._error(exc) from None

    def _error(self, exc) -> StoreError:
        return StoreError(self.argument, "a readable, intact batch store (trials.sqlite)", str(self.path),
                          detail=f"SQLite: {' '.join(str(exc).split())}")

    def _query(self, sql: str, args=()):
        try:
            return self.db.execute(sql, args).fetchall()
        except sqlite3.DatabaseError as exc:
            raise self._error(exc) from None

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.db is not None:
            self.db.close()
            self.db = None

    # ---- meta -----------------------------------------------------------------------------------
    def set_meta(self, key: str, value) -> None:
        if not self.writable:
            raise RuntimeError("the store was opened read-only")
        with self.db:
            self.db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)",
                            (key, json.dumps(to_jsonable(value), sort_keys=True)))

    def meta(self, key: str, default=None):
        rows = self._query("SELECT value FROM meta WHERE key = ?", (key,))
        if not rows:
            return default
        try:
            return json.loads(rows[0][0])
        except (TypeError, ValueError) as exc:
            raise self._error(f"meta {key!r} is not JSON ({exc})") from None

    # ---- trials ---------------------------------------------------------------------------------
    def done_ids(self) -> set[str]:
        return {r[0] for r in self._query("SELECT id FROM trials")}

    def add(self, record: dict) -> bool:
        """Commit one finished trial. Returns False (and writes nothing) if its id is already stored,
        so that a trial is never recorded twice. A trial whose status is not a result (interrupted)
        is refused: it must run again."""
        if record.get("status") in NOT_A_RESULT:
            raise ValueError(f"trial {record.get('id')} has status {record['status']!r}: not a result to store")
        if not self.writable:
            raise RuntimeError("the store was opened read-only")
        row = (record["id"], record["cell"], int(record["trial"]), int(record["seed"]),
               _dump(record["spec"]), record["status"], _dump(record.get("metrics")), _dump(record.get("series")),
               _dump(record.get("timings")), record.get("error"), _dump(record.get("versions")),
               float(record.get("finished_at", time.time())))
        try:
            with self.db:
                cur = self.db.execute("INSERT OR IGNORE INTO trials VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", row)
        except sqlite3.DatabaseError as exc:
            raise self._error(exc) from None
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
        rows = self._query(q, args)
        keys = ("id", "cell", "trial", "seed", "spec", "status", "metrics", "series", "timings", "error", "versions",
                "finished_at")
        out = []
        for r in rows:
            d = dict(zip(keys, r))
            for k in ("spec", "metrics", "series", "timings", "versions"):
                try:
                    d[k] = json.loads(d[k]) if d[k] is not None else None
                except (TypeError, ValueError) as exc:
                    raise self._error(f"trial {d['id']!r}: {k} is not JSON ({exc})") from None
            out.append(d)
        return out

    def trial(self, trial_id: str) -> dict | None:
        found = self.trials(trial_id=trial_id)
        return found[0] if found else None

    def count(self) -> int:
        return int(self._query("SELECT COUNT(*) FROM trials")[0][0])


def _uri(path: Path, **params) -> str:
    return "file:" + urllib.parse.quote(str(path.resolve())) + "?" + urllib.parse.urlencode(params)


def _connect_read_only(path: Path) -> sqlite3.Connection:
    """A read-only connection that writes nothing: no byte of the database changes, and no side file
    is created. A WAL database without a -wal file has no writer and is opened immutable (SQLite
    would otherwise create -wal and -shm files beside it)."""
    with open(path, "rb") as fh:
        header = fh.read(20)
    wal = len(header) >= 20 and header[18:20] == b"\x02\x02"
    live = os.path.exists(str(path) + "-wal")
    params = {"mode": "ro"}
    if wal and not live:
        params["immutable"] = "1"
    return sqlite3.connect(_uri(path, **params), uri=True, timeout=60.0)


def check_store_file(path: Path, argument: str = "STORE") -> None:
    """Refuse, with a :class:`StoreError` naming ``argument``, anything but a batch store: a missing
    path, a directory, a file that is not an SQLite database (or is empty, truncated or corrupt), a
    database without the store's tables and columns. Reads only: a read-only connection that
    writes nothing (see :func:`_connect_read_only`)."""
    expected = "a batch store (trials.sqlite) made by nhstab batch"
    if not path.is_file():
        raise StoreError(argument, expected, str(path), detail="no such file" if not path.exists() else "not a file")
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(_SQLITE_MAGIC))
    except OSError as exc:
        raise StoreError(argument, expected, str(path), detail=" ".join(str(exc.strerror or exc).split())) from None
    if head != _SQLITE_MAGIC:
        raise StoreError(argument, expected, str(path),
                         detail="an empty file" if not head else "not an SQLite database")
    try:
        con = _connect_read_only(path)
        try:
            tables = {name for (name,) in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            for table, columns in _COLUMNS.items():
                if table not in tables:
                    raise StoreError(argument, expected, str(path),
                                     detail=f"it has no {table!r} table"
                                     + (f" (its tables: {', '.join(sorted(tables))})" if tables else " (no tables)"))
                have = {row[1] for row in con.execute(f"PRAGMA table_info({table})")}
                missing = [c for c in columns if c not in have]
                if missing:
                    raise StoreError(argument, expected, str(path),
                                     detail=f"its {table!r} table lacks {', '.join(missing)}")
            row = con.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
            if row is not None and row[0] != json.dumps(SCHEMA_VERSION):
                raise StoreError(argument, f"a batch store of schema {SCHEMA_VERSION}", str(path),
                                 detail=f"schema {row[0]}: made by another version of nhstab")
            con.execute("SELECT COUNT(*) FROM trials").fetchone()
        finally:
            con.close()
    except sqlite3.DatabaseError as exc:
        raise StoreError(argument, expected, str(path), detail=f"SQLite: {' '.join(str(exc).split())}") from None


def _dump(value) -> str | None:
    return None if value is None else json.dumps(to_jsonable(value), sort_keys=True)
