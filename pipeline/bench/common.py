"""Shared helpers of the benchmarks: the machine, best-of timing, the bundled maps."""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from ..examples import data_root


def machine() -> dict:
    import scipy

    return {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
            "cpu_count": os.cpu_count(), "platform": platform.platform()}


def _best(fn, repeats: int) -> tuple[float, float, object]:
    times, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - started)
    return min(times), float(np.median(times)), result


def maps_dir():
    """The bundled maps (the package data ``nhstab.data``), so that benchmarks run from an installed wheel."""
    return data_root()
