import sys
from pathlib import Path

import numpy as np
import pytest

# the tests' shared helpers (nominals.py) import as top-level modules from any test folder
sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)
