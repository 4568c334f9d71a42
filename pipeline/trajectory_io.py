"""Reading and writing nominal trajectories: CSV (header names columns and units) and NPZ.

CSV: one header line, then one row per time. Columns are ``t [s]``, then the model's states and
inputs by name with their units in brackets, e.g. for the unicycle::

    t [s],x [m],y [m],theta [rad],v [m/s],omega [rad/s]

Units in brackets are optional when reading; column order is free; every column must be present
and no other. NPZ: arrays ``t`` (N,), ``x`` (N, n), ``u`` (N, m).
"""

from __future__ import annotations

import csv
import io
import re
import zipfile
from pathlib import Path

import numpy as np

from .errors import InputError, TrajectoryError
from .limits import MAX_FILE_BYTES
from .models import Model
from .nominal import Nominal
from .records import write_npz, write_text
from .safe_io import read_bytes, read_text

_UNIT = re.compile(r"\s*\[[^\]]*\]\s*$")


def column_names(model: Model) -> list[str]:
    names = ["t [s]"]
    names += [f"{n} [{u}]" if u else n for n, u in zip(model.state_names, model.state_units or [""] * model.n)]
    names += [f"{n} [{u}]" if u else n for n, u in zip(model.input_names, model.input_units or [""] * model.m)]
    return names


def read_trajectory(path, model: Model) -> Nominal:
    path = Path(path)
    if not path.exists():
        raise InputError("trajectory", "an existing CSV or NPZ file", str(path))
    suffix = path.suffix.lower()
    if suffix == ".npz":
        raw = io.BytesIO(read_bytes(path, what="NPZ file"))
        try:
            with zipfile.ZipFile(raw) as z:         # a compressed array may expand: check before it does
                unpacked = sum(i.file_size for i in z.infolist())
            if unpacked > MAX_FILE_BYTES:
                raise InputError(path.name, f"an NPZ file of at most {MAX_FILE_BYTES:,} bytes unpacked",
                                 f"{unpacked:,} bytes")
            raw.seek(0)
            with np.load(raw, allow_pickle=False) as data:
                missing = [k for k in ("t", "x", "u") if k not in data.files]
                if missing:
                    raise TrajectoryError(f"{path.name}", "an NPZ file with arrays t, x, u", f"missing {missing}")
                return Nominal.from_samples(model, data["t"], data["x"], data["u"])
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(path.name, "a readable NPZ file", type(exc).__name__, detail=str(exc)) from None
    if suffix == ".csv":
        return _read_csv(path, model)
    raise InputError("trajectory", "a .csv or .npz file", path.name)


def _read_csv(path: Path, model: Model) -> Nominal:
    text = read_text(path, what="UTF-8 CSV file")
    rows = list(csv.reader(io.StringIO(text)))
    rows = [r for r in rows if r and not (len(r) == 1 and not r[0].strip())]
    if len(rows) < 3:
        raise TrajectoryError(path.name, "a header line and at least 2 rows", f"{len(rows)} line(s)")
    header = [_UNIT.sub("", h).strip() for h in rows[0]]
    wanted = ["t", *model.state_names, *model.input_names]
    unknown = [h for h in header if h not in wanted]
    missing = [w for w in wanted if w not in header]
    if unknown or missing:
        raise TrajectoryError(f"{path.name} header", "the columns " + ",".join(wanted) + f" for model {model.name}",
                              ",".join(header), detail=("missing " + ",".join(missing) if missing else "unknown " + ",".join(unknown)))
    try:
        data = np.array([[float(v) for v in r] for r in rows[1:]])
    except ValueError as exc:
        raise TrajectoryError(path.name, "numbers in every data row", str(exc)) from None
    if data.ndim != 2 or data.shape[1] != len(header):
        raise TrajectoryError(path.name, f"{len(header)} values per row", "rows of different lengths")
    col = {h: data[:, i] for i, h in enumerate(header)}
    x = np.stack([col[s] for s in model.state_names], axis=1)
    u = np.stack([col[s] for s in model.input_names], axis=1)
    return Nominal.from_samples(model, col["t"], x, u)


def write_trajectory(path, nominal: Nominal) -> Path:
    path = Path(path)
    if path.suffix.lower() == ".npz":
        return write_npz(path, t=nominal.t, x=nominal.x, u=nominal.u)
    header = ",".join(column_names(nominal.model))
    return write_text(path, header + "\n" + float_rows(np.column_stack([nominal.t, nominal.x, nominal.u])))


def float_rows(a: np.ndarray) -> str:
    """CSV lines of a 2-D float array, every number as Python's shortest round-trip ``repr`` (the
    same text as ``",".join(repr(float(v)) for v in row)`` per row, each line ending in a newline),
    formatted in C: the repr of the nested list, whose only separators are ``", "`` and ``"], ["``,
    rewritten into commas and newlines (a Python loop per row is many times slower)."""
    a = np.asarray(a, dtype=float)
    if a.ndim != 2:
        raise ValueError(f"float_rows needs a 2-D array, got {a.ndim}-D")
    if a.shape[0] == 0:
        return ""
    if a.shape[1] == 0:
        return "\n" * a.shape[0]
    text = repr(a.tolist())[2:-2]
    return text.replace(", ", ",").replace("],[", "\n") + "\n"
