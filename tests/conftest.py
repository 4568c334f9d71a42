import os
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

# Hypothesis draws its examples from a seed fixed per test (derandomize) and keeps no example database,
# so that every run of the suite tests the same cases and a failure is reproducible. For a random
# exploration: HYPOTHESIS_PROFILE=explore.
settings.register_profile("nhstab", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "nhstab"))

TESTS = Path(__file__).parent
# the tests' shared helpers (nominals.py) import as top-level modules from any test folder
sys.path.insert(0, str(TESTS))

#: The test files whose tests take longest, longest first. ``--dist loadfile`` hands each worker one
#: file at a time in collection order as the worker runs out of work; starting with the longest files
#: keeps one long file from starting last and running on alone while the other workers are idle.
LONGEST_FIRST = (
    "parking/test_parking_runs.py",
    "batch/test_batch.py",
    "control/test_paper.py",
    "execution/test_run_scenarios.py",
    "execution/test_run_figures.py",
    "batch/test_batch_cluster.py",
    "tubes/test_tubes_use.py",
    "execution/test_trailer_run.py",
    "test_packaging.py",
    "planning/test_parking_planner.py",
    "cli/test_bench_sampled.py",
    "cli/test_cli_run.py",
    "parking/test_parking_study.py",
)


def pytest_configure(config):
    # pytest-xdist by default orders the files by their number of tests, which puts the long scenario
    # files (a few tests each) last; keep the collection order below instead
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}

    def key(item):
        try:
            name = item.path.relative_to(TESTS).as_posix()
        except ValueError:
            return len(rank)
        return rank.get(name, len(rank))

    items.sort(key=key)        # stable: the order within a file, and of the other files, is kept


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)
