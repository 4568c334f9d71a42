"""A map as data: :class:`MapBundle`, the bytes of every file a map is built from, so that a batch's
trials carry their map to wherever they run, and a store keeps what a replay needs.

Why the files and not the loaded :class:`~nhstab.maps.Map`: the same bytes serve the workers and the
store, and a store may come from anyone, so it holds plain bytes and JSON (never a pickle, whose
loading runs code). A bundle is made on the submitting machine from the files
:func:`nhstab.maps.load_map` reads (the map file, its base maps, images and scenario lists; the
same set and order as :func:`nhstab.maps.content_hash`), each read once more and checked against
the digest recorded while the map loaded, so the bundle holds exactly the bytes the batch was
configured with.

Map loaders resolve base maps and images relative to the file that names them, so a bundle keeps
the files' layout: each file's path relative to the deepest folder that holds them all. Where a
bundle is used (every trial, locally or on a Dask worker, and ``nhstab batch replay``), its files
are written into a private temporary folder with that layout, loaded from there with
:func:`~nhstab.maps.load_map`, and the folder is removed; the map is checked to have the bundle's
content hash and to have read nothing outside the folder. A map that reaches outside its own
files (an absolute path to a base map or an image, or a symlink that changes the layout) cannot
travel and is refused when the batch config is read. The loaded map keeps the names of the
submitting machine (``Map.source`` and the paths in ``Map.meta``), as labels; no file is ever read
there. Each process keeps the maps it loaded, keyed by bundle id and load options (the few most
recent), so a worker unpacks and loads a map once per batch, not once per trial.

The packed form (:meth:`MapBundle.pack`, what crosses the network and what the store keeps) is
zlib-compressed: a 4-byte big-endian header length, the header (UTF-8 JSON: format, version,
entry file, content hash, the files with their sizes and SHA-256, and the submitting machine's path
of the map and of the folder, as labels), then the files' bytes in header order. Unpacking checks
everything before anything is written (sizes bounded by :data:`nhstab.limits.MAX_BUNDLE_BYTES`
*before* decompressing further, safe relative paths, every file's digest) and raises
:class:`BundleError` naming the source.
"""

from __future__ import annotations

import collections
import hashlib
import json
import os
import re
import shutil
import tempfile
import threading
import zlib
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path, PurePosixPath

from ..errors import InputError
from ..examples import resolve_map_path
from ..limits import MAX_BUNDLE_BYTES, MAX_BUNDLE_FILES
from ..maps import load_map
from ..safe_io import not_recorded, read_bytes

FORMAT = "nhstab map bundle"
VERSION = 1
_HEX64 = re.compile(r"[0-9a-f]{64}")
_MAX_HEADER = 1 << 20
#: how many loaded maps a process keeps (a batch has a few; a long-lived Dask worker serves many)
CACHE_SIZE = 8


class MapChangedError(InputError):
    """A trial's map is not the one its batch was configured with (its files changed since, or a
    bundle holds another map). Not recorded as a trial's error: the batch stops, since its trials
    would mix two maps."""


class BundleError(InputError):
    """A map bundle that is not intact (bad format, sizes, digests, unsafe paths), or a map whose
    files cannot travel as one (it reads a file outside them)."""


@dataclass(frozen=True)
class MapBundle:
    """Every file of one map, by path relative to the folder that holds them all."""

    entry: str                     # the map file (what load_map opens), relative, POSIX separators
    files: dict = field(repr=False)     # {relative path: bytes}, in the order the loader read them
    content_hash: str = ""         # nhstab.maps.content_hash of the map
    source: str = ""               # the map's path as given on the machine that made the bundle (a label)
    root: str = ""                 # the folder the relative paths start from, there (a label)

    # ---- identity --------------------------------------------------------------------------------
    @cached_property
    def id(self) -> str:
        """What the bundle is, independent of where it came from: the entry and every file's path
        and SHA-256 (32 hex digits). Moving the folder keeps it; renaming a file changes it."""
        doc = {"entry": self.entry, "files": sorted((p, _sha(b)) for p, b in self.files.items())}
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:32]

    @property
    def nbytes(self) -> int:
        """The files' bytes, unpacked."""
        return sum(len(b) for b in self.files.values())

    # ---- made from the files -----------------------------------------------------------------------
    @classmethod
    def from_path(cls, path, **options) -> "MapBundle":
        """The bundle of the map at ``path`` (``load_map`` options as for that format). Loads the map
        to learn its files, then reads each once more; a file that changed in between raises
        :class:`~nhstab.batch.trial.MapChangedError`."""
        given = resolve_map_path(path)
        m = load_map(given, **options)
        records = m.meta["files"]
        entry_abs = Path(os.path.abspath(given)).resolve()
        paths = [Path(r["path"]) for r in records]
        if entry_abs not in paths:            # pragma: no cover - load_map reads the map file first
            raise BundleError(str(given), "a map file that its loader reads", str(entry_abs))
        try:
            root = Path(os.path.commonpath([str(p.parent) for p in paths]))
        except ValueError:                    # Windows: files on different drives
            raise BundleError(str(given), "a map whose files can travel together (on one drive)",
                              ", ".join(sorted({p.anchor for p in paths}))) from None
        files: dict = {}
        with not_recorded():
            for rec in records:
                p = Path(rec["path"])
                rel = p.relative_to(root).as_posix()
                if rel in files:
                    continue
                data = read_bytes(p, what="map file")
                if _sha(data) != rec["sha256"]:
                    raise MapChangedError(str(given), "map files that do not change while they are read",
                                          f"{p} changed")
                files[rel] = data
        return cls(entry_abs.relative_to(root).as_posix(), files, m.meta["content_hash"], str(given), str(root))

    # ---- packed: what travels and what the store keeps ------------------------------------------------
    def header(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "entry": self.entry, "content_hash": self.content_hash,
                "source": self.source, "root": self.root,
                "files": [{"path": p, "bytes": len(b), "sha256": _sha(b)} for p, b in self.files.items()]}

    @cached_property
    def packed(self) -> bytes:
        """The packed form (see the module docstring): what travels and what the store keeps."""
        head = json.dumps(self.header(), sort_keys=True).encode()
        return zlib.compress(len(head).to_bytes(4, "big") + head + b"".join(self.files.values()), 6)

    @classmethod
    def unpack(cls, data, source: str = "map bundle") -> "MapBundle":
        """The bundle packed in ``data``, checked (see the module docstring); :class:`BundleError`
        naming ``source`` otherwise."""
        def bad(expected, got=None, detail=""):
            return BundleError(source, expected, got, detail=detail)

        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise bad("a packed map bundle (bytes)", type(data).__name__)
        try:
            z = zlib.decompressobj()
            raw = z.decompress(bytes(data), MAX_BUNDLE_BYTES + _MAX_HEADER + 5)
            if z.unconsumed_tail:
                raise bad(f"a map bundle of at most {MAX_BUNDLE_BYTES:,} bytes unpacked", "more")
            if not z.eof:
                raise bad("a complete zlib stream", detail="truncated")
            if z.unused_data:
                raise bad("nothing after the zlib stream", f"{len(z.unused_data)} more bytes")
        except zlib.error as exc:
            raise bad("a zlib-compressed map bundle", detail=str(exc)) from None
        if len(raw) < 4:
            raise bad("a map bundle header", detail="too short")
        n = int.from_bytes(raw[:4], "big")
        if n > _MAX_HEADER or 4 + n > len(raw):
            raise bad("a map bundle header of its stated length", n)
        try:
            head = json.loads(raw[4:4 + n].decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            raise bad("a JSON map bundle header", detail=" ".join(str(exc).split())[:120]) from None
        if not isinstance(head, dict) or head.get("format") != FORMAT:
            raise bad(f"a header of format {FORMAT!r}", head.get("format") if isinstance(head, dict) else None)
        if head.get("version") != VERSION:
            raise bad(f"a map bundle of version {VERSION}", head.get("version"),
                      detail="made by another version of nhstab")
        entries = head.get("files")
        if not isinstance(entries, list) or not 1 <= len(entries) <= MAX_BUNDLE_FILES:
            raise bad(f"a list of 1 to {MAX_BUNDLE_FILES} files", type(entries).__name__ if not isinstance(entries, list)
                      else f"{len(entries)} files")
        files: dict = {}
        pos = 4 + n
        for i, e in enumerate(entries):
            if not (isinstance(e, dict) and isinstance(e.get("bytes"), int) and not isinstance(e["bytes"], bool)
                    and e["bytes"] >= 0 and isinstance(e.get("sha256"), str) and _HEX64.fullmatch(e["sha256"])):
                raise bad(f"files[{i}] with path, bytes and sha256", str(e)[:80])
            rel = _safe_relative(e.get("path"), f"{source}: files[{i}].path")
            if rel in files:
                raise bad("each file once", rel)
            chunk = raw[pos:pos + e["bytes"]]
            pos += e["bytes"]
            if len(chunk) != e["bytes"]:
                raise bad(f"{e['bytes']} bytes of {rel}", f"{len(chunk)}", detail="truncated")
            if _sha(chunk) != e["sha256"]:
                raise bad(f"the bytes of {rel} with their recorded SHA-256", detail="corrupt")
            files[rel] = chunk
        if pos != len(raw):
            raise bad("no bytes after the files", f"{len(raw) - pos} more")
        entry = head.get("entry")
        if entry not in files:
            raise bad("an entry that is one of its files", entry)
        ch = head.get("content_hash")
        if not (isinstance(ch, str) and _HEX64.fullmatch(ch)):
            raise bad("a content hash (64 hex digits)", ch)
        labels = [head.get(k, "") for k in ("source", "root")]
        if not all(isinstance(v, str) for v in labels):
            raise bad("source and root as text", labels)
        return cls(entry, files, ch, labels[0], labels[1])

    # ---- used: the map, loaded from a private copy ---------------------------------------------------
    def write_into(self, folder) -> Path:
        """Write the files into ``folder`` with their layout; returns the entry's path there."""
        folder = Path(folder)
        for rel, data in self.files.items():
            target = folder.joinpath(*_safe_relative(rel, "map bundle").split("/"))
            target.parent.mkdir(parents=True, exist_ok=True)
            with open(target, "xb") as fh:
                fh.write(data)
        return folder.joinpath(*self.entry.split("/"))

    def load(self, cell_size=None, argument: str = "map bundle"):
        """The map, loaded from a private copy of the files (cached per process by bundle id and
        options; see the module docstring). Raises :class:`BundleError` (naming ``argument``) if the
        map reads a file that is not in the bundle or its content hash is not the bundle's."""
        options = {"cell_size": cell_size} if cell_size else {}
        key = (self.id, tuple(sorted(options.items())))
        with _LOCK:
            if key in _LOADED:
                _LOADED.move_to_end(key)
                return _LOADED[key]
        m = self._load_fresh(options, argument)
        with _LOCK:
            _LOADED[key] = m
            while len(_LOADED) > CACHE_SIZE:
                _LOADED.popitem(last=False)
        return m

    def _load_fresh(self, options: dict, argument: str):
        tmp = Path(tempfile.mkdtemp(prefix="nhstab-map-")).resolve()
        try:
            m = load_map(self.write_into(tmp), **options)
            outside = [f["path"] for f in m.meta["files"] if not _inside(Path(f["path"]), tmp)]
            if outside:
                first = self._label(outside[0], tmp)
                raise BundleError(argument, "a map whose files all travel with it (base maps and images named "
                                  "by relative paths, inside the map's folders)", self.source or self.entry,
                                  detail=f"it also reads {first}, which is not one of its files: an absolute path "
                                         "or a symlink?")
            if m.meta["content_hash"] != self.content_hash:
                raise BundleError(argument, f"a map with the bundle's content hash {self.content_hash[:12]}",
                                  m.meta["content_hash"][:12],
                                  detail="its files do not give the same map when copied (a symlink that changes "
                                         "the layout?)")
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return replace(m, source=self.source or m.source, meta=_relabel(m.meta, str(tmp), self.root))

    def _label(self, path: str, tmp: Path) -> str:
        return _relabel(path, str(tmp), self.root)


_LOADED: "collections.OrderedDict" = collections.OrderedDict()
_LOCK = threading.Lock()


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.resolve().relative_to(folder)
        return True
    except ValueError:
        return False


def _safe_relative(value, where: str) -> str:
    """A relative POSIX path without '..', '.', empty or absolute parts, NUL or backslashes."""
    if not isinstance(value, str) or not value or len(value) > 4096:
        raise BundleError(where, "a relative file path", value)
    parts = PurePosixPath(value).parts
    if (PurePosixPath(value).is_absolute() or not parts or any(p in ("..", ".", "") for p in parts)
            or "\x00" in value or "\\" in value or PurePosixPath(*parts).as_posix() != value):
        raise BundleError(where, "a relative file path inside the bundle (no '..', not absolute)", value)
    return value


def _relabel(value, tmp: str, root: str):
    """Paths under the private folder ``tmp`` named as they were on the submitting machine."""
    if isinstance(value, str):
        if value == tmp or value.startswith(tmp + os.sep):
            rest = value[len(tmp):].lstrip(os.sep)
            return os.path.join(root, rest) if root else rest
        return value
    if isinstance(value, dict):
        return {k: _relabel(v, tmp, root) for k, v in value.items()}
    if isinstance(value, list):
        return [_relabel(v, tmp, root) for v in value]
    if isinstance(value, tuple):
        return tuple(_relabel(v, tmp, root) for v in value)
    return value


def loaded(bundle_id: str, cell_size=None):
    """The map of bundle ``bundle_id`` if this process has it loaded, else None."""
    key = (bundle_id, tuple(sorted(({"cell_size": cell_size} if cell_size else {}).items())))
    with _LOCK:
        return _LOADED.get(key)
