"""Plain result records and atomic file writing. Imports nothing heavy."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from . import __version__
from .errors import InputError
from .limits import MAX_FILE_BYTES


def to_jsonable(obj):
    """Convert numpy scalars/arrays and non-finite floats to JSON-safe values (NaN/inf -> None)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def _atomic_write(path: Path, write) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.chmod(tmp, 0o666 & ~_UMASK)           # mkstemp makes 0600; give the file the usual mode
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


def write_json(path, obj) -> Path:
    text = json.dumps(to_jsonable(obj), indent=2, sort_keys=False) + "\n"
    return _atomic_write(Path(path), lambda fh: fh.write(text.encode()))


def write_text(path, text: str) -> Path:
    return _atomic_write(Path(path), lambda fh: fh.write(text.encode()))


#: the suffix of a gzip-compressed record (``study.json.gz``; see :func:`write_json_gz`)
GZ = ".gz"


def write_json_gz(path, obj, indent: int | None = None) -> Path:
    """Write ``obj`` as JSON compressed with gzip, for the large records that commands leave in
    ``results/`` (a study's or sweep's cells compress six- to twenty-fold). ``path`` ends in
    ``.json.gz``; ``zcat``, Python's :mod:`gzip` and :func:`read_json` read it. The JSON text is
    ``json.dumps(obj, indent=indent)`` (compact, without spaces, when ``indent`` is None) plus a newline,
    every number as :func:`write_json` writes it; the gzip header holds no time stamp or file name, so
    one record always gives the same bytes. An uncompressed copy of the record (``path`` without
    ``.gz``) is removed once the new file is in place, so that a folder holds one form of each record."""
    import gzip

    path = Path(path)
    if not path.name.endswith(".json" + GZ):
        raise ValueError(f"a gzip-compressed JSON record is named *.json.gz: {path}")
    separators = (",", ":") if indent is None else None
    data = (json.dumps(to_jsonable(obj), indent=indent, separators=separators) + "\n").encode()

    def write(fh):
        with gzip.GzipFile(filename="", mode="wb", fileobj=fh, compresslevel=9, mtime=0) as gz:
            gz.write(data)

    written = _atomic_write(path, write)
    plain = path.with_name(path.name[:-len(GZ)])
    if plain.is_file() or plain.is_symlink():
        plain.unlink()
    return written


def record_file(folder, name: str) -> Path:
    """Where the record ``name`` (e.g. ``"study.json"``) of ``folder`` is: ``name.gz`` (what the
    commands write, :func:`write_json_gz`) when it exists, else ``name`` (a record written
    uncompressed) when that exists, else ``name.gz``."""
    folder = Path(folder)
    gz, plain = folder / (name + GZ), folder / name
    return plain if not gz.exists() and plain.exists() else gz


def read_json(path):
    """The JSON value in ``path``, gzip-compressed (a name ending in ``.gz``, as :func:`write_json_gz`
    writes) or plain. Raises OSError (unreadable; gzip.BadGzipFile: not gzip) or ValueError (a gzip
    stream cut short, damaged or expanding past :data:`~nhstab.limits.MAX_FILE_BYTES`, text that is
    not UTF-8 or not JSON)."""
    path = Path(path)
    if path.name.endswith(GZ):
        import gzip
        import zlib

        try:
            with gzip.open(path, "rb") as fh:
                data = fh.read(MAX_FILE_BYTES + 1)                 # a bound on what it expands to
        except (EOFError, zlib.error) as exc:                     # cut short, or damaged
            raise ValueError(f"not a whole gzip stream: {exc}") from None
        if len(data) > MAX_FILE_BYTES:
            raise ValueError(f"it expands to more than {MAX_FILE_BYTES} bytes")
        return json.loads(data.decode("utf-8"))
    return json.loads(path.read_text(encoding="utf-8"))


def write_generated(out, files: dict[str, str], check: bool = False, pattern: str = "*.yaml") -> dict:
    """Write the generated ``files`` (name -> text) into the folder ``out``, file by file and atomically,
    or with ``check`` only compare: returns {"written": [...], "folder": ...} or {"differ": [...],
    "missing": [...], "extra": [...]} (files matching ``pattern`` in ``out`` that are not generated)."""
    out = Path(out)
    if check:
        differ = [n for n, t in files.items() if (out / n).is_file() and (out / n).read_text(encoding="utf-8") != t]
        missing = [n for n in files if not (out / n).is_file()]
        extra = sorted(p.name for p in out.glob(pattern) if p.name not in files) if out.is_dir() else []
        return {"differ": differ, "missing": missing, "extra": extra}
    for name, text in files.items():
        write_text(out / name, text)
    return {"written": sorted(files), "folder": str(out)}


def write_npz(path, **arrays) -> Path:
    """An NPZ file (what ``numpy.savez_compressed`` writes, read by ``numpy.load``) compressed at zlib
    level 1: float arrays hardly compress further at numpy's level 6 (a 9,000-sample tube.npz: 1.379
    MB against 1.374 MB), which took twice as long."""
    import zipfile

    def write(fh):
        with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as z:
            for name, value in arrays.items():
                with z.open(f"{name}.npy", "w", force_zip64=True) as entry:
                    np.lib.format.write_array(entry, np.asanyarray(value), allow_pickle=False)

    return _atomic_write(Path(path), write)


def save_figure(fig, path, dpi: int = 110, fast_palette: bool = False) -> Path:
    """Save a matplotlib figure atomically as PNG (figures from :func:`nhstab.report.subplots` are not
    registered with pyplot, so there is nothing to close). The image is stored with a palette of at
    most 256 colours, without dithering: plots of lines, shades and text lose nothing visible, and
    the files are under half the size of full-colour PNGs. The palette is median cut's (about 0.1 s
    at 900 x 900 pixels), or with ``fast_palette`` PIL's fast octree (about 10 ms), for figures of
    flat fills, lines and text such as the plan figure (on it every channel within 16 levels of the
    drawing, about one level on average; the octree bands smooth colour maps, median cut much less).
    An Agg figure is drawn once and its pixels go straight to the palette step (no PNG encoded by
    matplotlib and decoded again). The PNG is deflated at zlib's level 9 (PIL's ``optimize``): the
    same pixels in fewer bytes than at PIL's default level, for a little more time per figure."""
    image = _figure_pixels(fig, dpi)
    from PIL import Image

    method = Image.Quantize.FASTOCTREE if fast_palette else Image.Quantize.MEDIANCUT
    image = image.quantize(colors=256, method=method, dither=Image.Dither.NONE)
    return _atomic_write(Path(path), lambda fh: image.save(fh, format="PNG", optimize=True))


def _figure_pixels(fig, dpi: int):
    """The figure drawn at ``dpi`` as an RGB PIL image (the alpha channel dropped, as a PNG of it
    converted to RGB would)."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    canvas = fig.canvas
    if not isinstance(canvas, FigureCanvasAgg):          # another backend's figure: its own PNG writer
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi)
        buf.seek(0)
        with Image.open(buf) as im:
            return im.convert("RGB")
    old = fig.dpi
    try:
        fig.dpi = dpi                                    # as savefig(dpi=...) does, for the draw only
        canvas.draw()
        rgba = np.asarray(canvas.buffer_rgba())
        return Image.fromarray(np.ascontiguousarray(rgba[..., :3]))
    finally:
        fig.dpi = old


# ---- output folders ---------------------------------------------------------------------------

#: the file that marks a folder's outputs complete and names them (written last)
MANIFEST = "nhstab-manifest.json"
_STAGING = ".nhstab-staging-"


class OutputFolder:
    """Write one command's files into a folder so that the folder never mixes two runs.

    The protocol (documented in docs/reference/behaviour.md, "Output folders never mix two runs"):

    1. every file is written into a fresh staging folder inside the output folder
       (``.nhstab-staging-<pid>-<random>``), so nothing the command writes is visible before it
       has all been written. If the command fails or is interrupted before it commits, the staging
       folder is removed and the output folder is exactly as it was (an earlier run stays whole);
    2. commit: the old manifest is removed first (from then on the folder says it holds no complete
       run), then every file of the earlier output is removed (the files its manifest names, and
       the names this command writes, for folders made before manifests existed), then the new
       files are moved in (a rename each: same file system), and finally the new manifest
       ``nhstab-manifest.json`` is written (atomically), naming every file with its size and
       SHA-256.

    So a folder with a manifest holds exactly the files of one run, as the manifest lists them, and
    a folder without one (a commit cut short) holds files of at most one run and says it is
    incomplete. Other files in the folder (a batch's trials.sqlite, the user's own) are never
    touched. Use as a context manager::

        with OutputFolder(out_dir, "run", owned=RUN_FILES) as out:
            out.write_text("trajectory.csv", text)
            out.save_figure(fig, "run_map.png")
        out.written            # the final paths, manifest last
    """

    def __init__(self, out_dir, command: str, owned=(), info: dict | None = None):
        self.dir = Path(out_dir)
        self.command = command
        self.owned = tuple(owned)
        self.info = dict(info or {})
        self.names: list[str] = []
        self.written: list[Path] = []
        self.staging: Path | None = None

    # -- writing into the staging folder ---------------------------------------------------------
    def __enter__(self) -> "OutputFolder":
        if self.dir.exists() and not self.dir.is_dir():
            raise InputError("--out", "a folder (or a path where one can be made)", str(self.dir),
                             detail="it is a file")
        self.dir.mkdir(parents=True, exist_ok=True)
        self.staging = Path(tempfile.mkdtemp(prefix=f"{_STAGING}{os.getpid()}-", dir=self.dir))
        return self

    def path(self, name: str) -> Path:
        """Where to write ``name`` (a relative path) now: inside the staging folder."""
        rel = Path(name)
        if rel.is_absolute() or ".." in rel.parts or not rel.parts:
            raise ValueError(f"output names are relative paths inside the folder: {name!r}")
        if name not in self.names:
            self.names.append(name)
        target = self.staging / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        return target

    def write_text(self, name: str, text: str) -> Path:
        return write_text(self.path(name), text)

    def write_json(self, name: str, obj) -> Path:
        return write_json(self.path(name), obj)

    def write_npz(self, name: str, **arrays) -> Path:
        return write_npz(self.path(name), **arrays)

    def save_figure(self, fig, name: str, dpi: int = 110, fast_palette: bool = False) -> Path:
        return save_figure(fig, self.path(name), dpi=dpi, fast_palette=fast_palette)

    def final(self, name: str) -> Path:
        return self.dir / name

    def __exit__(self, kind, exc, tb) -> bool:
        try:
            if kind is None:
                self.commit()
        finally:
            if self.staging is not None:
                _rmtree(self.staging)
                self.staging = None
        return False

    # -- commit ----------------------------------------------------------------------------------
    def commit(self) -> list[Path]:
        import hashlib

        manifest = self.dir / MANIFEST
        old = read_manifest(self.dir)
        entries = []
        for name in self.names:
            data = (self.staging / name).read_bytes()
            entries.append({"name": name, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()})
        # 1. the folder no longer claims a complete run
        if manifest.exists() or manifest.is_symlink():
            manifest.unlink()
        # 2. the earlier output goes, whole
        stale = set(self.owned) | set(old.get("files", {}) if old else {})
        for name in sorted(stale):
            target = self._inside(name)
            if target is not None and (target.is_file() or target.is_symlink()):
                target.unlink()
        for name in sorted(stale, key=lambda n: -len(Path(n).parts)):      # empty subfolders we made
            target = self._inside(name)
            if target is not None and target.parent != self.dir:
                try:
                    target.parent.rmdir()
                except OSError:
                    pass
        # 3. the new files move in
        self.written = []
        for name in self.names:
            target = self.dir / name
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.staging / name, target)
            self.written.append(target)
        # 4. the manifest, last

        self.written.append(write_json(manifest, {
            "command": self.command, "nhstab_version": __version__, **self.info,
            "files": {e["name"]: {"bytes": e["bytes"], "sha256": e["sha256"]} for e in entries},
            "note": "written last: these files are one complete output; a folder without this file holds an "
                    "incomplete one"}))
        self._clean_dead_staging()
        return self.written

    def _inside(self, name: str) -> Path | None:
        rel = Path(name)
        if rel.is_absolute() or ".." in rel.parts or not rel.parts or rel.name == MANIFEST:
            return None
        return self.dir / rel

    def _clean_dead_staging(self) -> None:
        """Staging folders left by a writer that was killed (its process no longer exists)."""
        for d in self.dir.glob(f"{_STAGING}*"):
            try:
                pid = int(d.name[len(_STAGING):].split("-")[0])
            except ValueError:
                continue
            if pid != os.getpid() and not _alive(pid):
                _rmtree(d)


def read_manifest(folder) -> dict | None:
    """The manifest of an output folder (see :class:`OutputFolder`), or None if it has none or it is
    not readable."""
    try:
        data = json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("files"), dict):
        return None
    return data


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _rmtree(path: Path) -> None:
    import shutil

    shutil.rmtree(path, ignore_errors=True)
