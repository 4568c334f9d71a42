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
                                                       schema version, runs (one entry per
                                                       invocation: executor, workers, bytes shipped)
    trials(id TEXT PRIMARY KEY, cell TEXT, trial INTEGER, seed INTEGER, spec TEXT, status TEXT,
           metrics TEXT, series TEXT, timings TEXT, error TEXT, versions TEXT, finished_at REAL)
    maps(id TEXT PRIMARY KEY, content_hash TEXT, entry TEXT, source TEXT, bytes INTEGER,
         packed BLOB)                               -- schema 2: every map of the batch as data
``spec``, ``metrics``, ``series``, ``timings`` and ``versions`` hold JSON; ``maps.packed`` is a
packed :class:`~nhstab.batch.bundle.MapBundle` (the bytes of every file the map is built from,
compressed; ``bytes`` is their size unpacked), keyed by the bundle id that each trial's
``spec.cell_spec.map_bundle`` names, so that ``nhstab batch replay`` needs the store alone.

Schemas: 2 (this version: with ``maps``) and 1 (stores made before maps were stored) are read; a
store of schema 1 has no map to replay from (a replay then needs the map files at the path the
trial records, with the same content), and is upgraded to schema 2 (its ``maps`` table made and
filled) when a batch resumes it.
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
from .bundle import BundleError, MapBundle

SCHEMA_VERSION = 2
#: the schemas this version reads (1: before the maps table)
READABLE_SCHEMAS = (1, 2)

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
_MAPS_SCHEMA = """
CREATE TABLE IF NOT EXISTS maps (
    id TEXT PRIMARY KEY,
    content_hash TEXT NOT NULL,
    entry TEXT NOT NULL,
    source TEXT,
    bytes INTEGER NOT NULL,
    packed BLOB NOT NULL
);
"""
_COLUMNS = {"meta": ("key", "value"),
            "trials": ("id", "cell", "trial", "seed", "spec", "status", "metrics", "series", "timings", "error",
                       "versions", "finished_at"),
            "maps": ("id", "content_hash", "entry", "source", "bytes", "packed")}
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
                    self.db.executescript(_SCHEMA + _MAPS_SCHEMA)
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

    def verify(self) -> None:
        """Read the whole store and refuse it (:class:`StoreError`) unless it is intact: SQLite's
        integrity check of every page, then every row of every table read and every JSON value
        parsed. Reads only; a store about to be written (``--resume``) is verified first, so that a
        corrupt one is refused before a byte of it changes."""
        rows = self._query("PRAGMA integrity_check")
        problems = [str(r[0]) for r in rows if r and r[0] != "ok"]
        if problems:
            more = f" (and {len(problems) - 1} more problems)" if len(problems) > 1 else ""
            raise self._error(f"database disk image is malformed: {problems[0]}{more}")
        json_columns = {"meta": ("value",), "trials": ("spec", "metrics", "series", "timings", "versions")}
        tables = ("meta", "trials") + (("maps",) if self.schema >= 2 else ())
        for table in tables:
            columns = _COLUMNS[table]
            try:
                for row in self.db.execute(f"SELECT {', '.join(columns)} FROM {table}"):
                    record = dict(zip(columns, row))
                    for column in json_columns.get(table, ()):
                        if record[column] is not None:
                            try:
                                json.loads(record[column])
                            except (TypeError, ValueError) as exc:
                                raise self._error(f"{table} row {row[0]!r}: {column} is not JSON ({exc})") from None
            except sqlite3.DatabaseError as exc:
                raise self._error(exc) from None

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

    def errors(self) -> list[tuple[str, str]]:
        """(id, error) of every trial stored with status "error", by cell and trial."""
        return [(r[0], r[1] or "") for r in
                self._query("SELECT id, error FROM trials WHERE status = 'error' ORDER BY cell, trial")]

    def remove_errors(self) -> int:
        """Delete the trials stored with status "error" (to run them again); returns how many."""
        if not self.writable:
            raise RuntimeError("the store was opened read-only")
        try:
            with self.db:
                return self.db.execute("DELETE FROM trials WHERE status = 'error'").rowcount
        except sqlite3.DatabaseError as exc:
            raise self._error(exc) from None

    # ---- maps -----------------------------------------------------------------------------------
    @property
    def schema(self) -> int:
        """The store's schema (1 for stores made before the schema was recorded)."""
        return int(self.meta("schema", 1))

    def add_map(self, bundle) -> bool:
        """Keep a map (a :class:`~nhstab.batch.bundle.MapBundle`) in the store, once per bundle id;
        a store of schema 1 is upgraded to schema 2 first."""
        if not self.writable:
            raise RuntimeError("the store was opened read-only")
        try:
            if self.schema < SCHEMA_VERSION:
                self.db.executescript(_MAPS_SCHEMA)
                self.set_meta("schema", SCHEMA_VERSION)
            with self.db:
                cur = self.db.execute("INSERT OR IGNORE INTO maps VALUES (?, ?, ?, ?, ?, ?)",
                                      (bundle.id, bundle.content_hash, bundle.entry, bundle.source, bundle.nbytes,
                                       sqlite3.Binary(bundle.packed)))
        except sqlite3.DatabaseError as exc:
            raise self._error(exc) from None
        return cur.rowcount == 1

    def map_ids(self) -> list[str]:
        if self.schema < 2:
            return []
        return [r[0] for r in self._query("SELECT id FROM maps ORDER BY id")]

    def map_bundle(self, bundle_id: str | None = None, content_hash: str | None = None):
        """The map stored under ``bundle_id`` (or, for trials that name none, the one map with
        ``content_hash``), unpacked and checked; None if the store has no such map (or, schema 1,
        none at all). A stored map that is not intact raises :class:`StoreError`."""
        if self.schema < 2:
            return None
        bundle_id = bundle_id if isinstance(bundle_id, str) else None       # a spec is data from the file
        content_hash = content_hash if isinstance(content_hash, str) else None
        if bundle_id is not None:
            rows = self._query("SELECT id, content_hash, packed FROM maps WHERE id = ?", (bundle_id,))
        elif content_hash:
            rows = self._query("SELECT id, content_hash, packed FROM maps WHERE content_hash = ?", (content_hash,))
        else:
            return None
        if len(rows) != 1:
            return None
        key, digest, packed = rows[0]
        try:
            bundle = MapBundle.unpack(packed, source=f"{self.argument} {self.path}: maps[{key}]")
        except BundleError as exc:
            raise StoreError(self.argument, "a batch store whose maps are intact", str(self.path),
                             detail=str(exc)) from None
        if bundle.id != key or bundle.content_hash != digest:
            raise StoreError(self.argument, "a batch store whose maps are intact", str(self.path),
                             detail=f"map {key} holds another map ({bundle.id})")
        return bundle


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
            schema = json.dumps(1)
            for table, columns in _COLUMNS.items():
                if table == "maps":
                    row = con.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
                    schema = row[0] if row is not None else json.dumps(1)       # none recorded: schema 1
                    if schema not in [json.dumps(v) for v in READABLE_SCHEMAS]:
                        raise StoreError(argument, "a batch store of schema "
                                         + " or ".join(str(v) for v in READABLE_SCHEMAS), str(path),
                                         detail=f"schema {schema}: made by another version of nhstab")
                    if schema == json.dumps(1):
                        continue                    # schema 1: made before maps were stored
                if table not in tables:
                    raise StoreError(argument, expected, str(path),
                                     detail=f"it has no {table!r} table"
                                     + (f" (its tables: {', '.join(sorted(tables))})" if tables else " (no tables)"))
                have = {row[1] for row in con.execute(f"PRAGMA table_info({table})")}
                missing = [c for c in columns if c not in have]
                if missing:
                    raise StoreError(argument, expected, str(path),
                                     detail=f"its {table!r} table lacks {', '.join(missing)}")
            con.execute("SELECT COUNT(*) FROM trials").fetchone()
        finally:
            con.close()
    except sqlite3.DatabaseError as exc:
        raise StoreError(argument, expected, str(path), detail=f"SQLite: {' '.join(str(exc).split())}") from None


def _dump(value) -> str | None:
    return None if value is None else json.dumps(to_jsonable(value), sort_keys=True)
