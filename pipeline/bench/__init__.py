"""Benchmarks (``nhstab bench``). Each returns a JSON-ready dict with measured values, the baseline it
is compared with (named), and its targets.

Timings are wall-clock (time.perf_counter), best of several repetitions, measured in one process
so that ratios compare like with like on a shared, noisy machine. One module per benchmark; each
gives ``bench_<name>()`` and ``summary_lines(result)`` (rows of the summary table).
"""

from __future__ import annotations

from importlib import import_module

from ..errors import InputError
from ..records import read_json, record_file
from .gains import hilare_sinusoid  # noqa: F401  (used by tests and the batch benchmark)

#: benchmark name -> module (in the order ``nhstab bench`` runs them)
_MODULES = ("startup", "gains", "collision", "planning", "parking", "run", "batch", "tube", "polygons", "geometry", "trailer")


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


def select_benchmarks(only: str | None) -> list[str]:
    """The benchmarks to run: all of them (``only`` None), else the comma-separated names of ``only``,
    each once, in the order given; an unknown or empty selection raises :class:`InputError` naming
    ``--only``."""
    if only is None:
        return list(BENCHMARKS)
    names = list(dict.fromkeys(n.strip() for n in only.split(",") if n.strip()))     # each once
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown or not names:
        raise InputError("--only", f"benchmark names from {', '.join(BENCHMARKS)}", only)
    return names


def previous_results(out_dir) -> dict:
    """The results a partial run (``--only``) merges into: ``out_dir/bench.json.gz``'s benchmarks (or
    an uncompressed ``bench.json``'s) that still exist (an empty dict when there is neither). A file that is not readable JSON holding an object raises
    :class:`InputError` naming ``--out-dir``."""
    previous = record_file(out_dir, "bench.json")
    results = {}
    if previous.is_file():
        try:
            results = read_json(previous)
        except (OSError, ValueError) as exc:
            raise InputError("--out-dir", f"a folder whose {previous.name} is readable JSON (to merge into)",
                             f"{previous}: {exc}") from None
        if not isinstance(results, dict):
            raise InputError("--out-dir", f"a {previous.name} holding an object", str(previous))
    return {k: v for k, v in results.items() if k in BENCHMARKS}
