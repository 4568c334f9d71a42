"""Plain result records and atomic file writing. Imports nothing heavy."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np


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


def write_npz(path, **arrays) -> Path:
    return _atomic_write(Path(path), lambda fh: np.savez_compressed(fh, **arrays))


def save_figure(fig, path, dpi: int = 110) -> Path:
    """Save a matplotlib figure atomically as PNG (figures from :func:`nhstab.report.subplots` are not
    registered with pyplot, so there is nothing to close)."""
    return _atomic_write(Path(path), lambda fh: fig.savefig(fh, format="png", dpi=dpi))
