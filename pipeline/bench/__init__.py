"""Benchmarks (``nhstab bench``). Each returns a JSON-ready dict with measured values, the baseline it
is compared with (named), and its targets.

Timings are wall-clock (time.perf_counter), best of several repetitions, measured in one process
so that ratios compare like with like on a shared, noisy machine. One module per benchmark; each
gives ``bench_<name>()`` and ``summary_lines(result)`` (rows of the summary table).
"""

from __future__ import annotations

from importlib import import_module

from .gains import hilare_sinusoid  # noqa: F401  (used by tests and the batch benchmark)

#: benchmark name -> module (in the order ``nhstab bench`` runs them)
_MODULES = ("startup", "gains", "collision", "planning", "parking", "run", "batch", "tube", "polygons", "geometry")


def _fn(name: str):
    def run(**kwargs):
        return getattr(import_module(f"{__name__}.{name}"), f"bench_{name}")(**kwargs)

    run.__name__ = f"bench_{name}"
    return run


BENCHMARKS = {name: _fn(name) for name in _MODULES}


def summary_markdown(results: dict) -> str:
    lines = ["# nhstab benchmarks", "", "Produced by `nhstab bench`. Measured value against target.", "",
             "| benchmark | measure | value | target | met |", "|---|---|---|---|---|"]
    for name in _MODULES:
        if results.get(name):
            lines.extend(import_module(f"{__name__}.{name}").summary_lines(results[name]))
    return "\n".join(lines) + "\n"
