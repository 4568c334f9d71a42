"""A run's random streams: one numpy SeedSequence per stream and call, spawned from the run's root seed.

The same root seed gives the same initial error, sensor noise, process noise and planner seeds, in a
run (:mod:`nhstab.execution.runner`), in the vectorised engine (:mod:`nhstab.batch.vector`) and in a
sampled tube's rollouts.
"""

from __future__ import annotations

import numpy as np

#: the streams of a run and their index in the SeedSequence's entropy
_SEED_STREAMS = {"initial": 0, "sensor": 1, "process": 2, "planner": 3}


def seed_for(root: int, stream: str, index: int = 0) -> np.random.SeedSequence:
    """The SeedSequence of one random stream of a run ("initial", "sensor", "process", "planner")."""
    return np.random.SeedSequence([int(root), _SEED_STREAMS[stream], int(index)])


def planner_seed(root: int, call: int) -> int:
    """OMPL's seed for the planning call number ``call`` of a run (a 31-bit integer)."""
    return int(seed_for(root, "planner", call).generate_state(1)[0] % (2**31 - 1))
