"""``nhstab bench startup``: how long ``nhstab --help`` takes, against ``python -c pass``.

Both are whole processes of the same interpreter, timed alternately (so that machine noise hits
both alike), best and median of several runs. The command line imports only click and its own
modules to print help; numpy, scipy and matplotlib load when a command runs. The check that they
are not imported is a test (tests/test_packaging.py); here is the time.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np

from .common import machine


def _time(cmd: list[str]) -> float:
    started = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started


def bench_startup(repeats: int = 15) -> dict:
    help_cmd = [sys.executable, "-c", "import sys; from nhstab.cli.main import main; sys.argv = ['nhstab', '--help']; main()"]
    base_cmd = [sys.executable, "-c", "pass"]
    heavy = [sys.executable, "-c", "import sys; from nhstab.cli.main import main; "
                                   "print(sorted(m for m in ('numpy', 'scipy', 'matplotlib', 'ompl', 'fcl') if m in sys.modules))"]
    helps, bases = [], []
    _time(help_cmd), _time(base_cmd)                   # warm the file cache
    for _ in range(repeats):
        helps.append(_time(help_cmd))
        bases.append(_time(base_cmd))
    imported = subprocess.run(heavy, check=True, capture_output=True, text=True).stdout.strip()
    best_help, best_base = min(helps), min(bases)
    return {
        "benchmark": "startup", "machine": machine(), "repeats": repeats,
        "help_command": "nhstab --help (python -c, same interpreter as the console script)",
        "baseline_command": "python -c pass",
        "help_best_s": best_help, "help_median_s": float(np.median(helps)),
        "python_best_s": best_base, "python_median_s": float(np.median(bases)),
        "ratio_best": best_help / best_base, "extra_s": best_help - best_base,
        "heavy_modules_imported_by_help": imported,
        "targets": {"help_s_max": 0.3},
        "met": {"help under 0.3 s": bool(best_help < 0.3)},
    }


def summary_lines(r: dict) -> list[str]:
    return [f"| startup | `nhstab --help` against `python -c pass` (best of {r['repeats']}) | "
            f"{r['help_best_s'] * 1e3:.0f} ms vs {r['python_best_s'] * 1e3:.0f} ms ({r['ratio_best']:.1f}x) | "
            f"< 300 ms | {'yes' if r['met']['help under 0.3 s'] else 'NO'} |",
            f"| startup | heavy modules imported by `nhstab --help` | {r['heavy_modules_imported_by_help']} | [] | "
            f"{'yes' if r['heavy_modules_imported_by_help'] == '[]' else 'NO'} |"]
