"""Fixed, seeded start/goal problems on a map (for tests and benchmarks)."""

from __future__ import annotations

import math

import numpy as np

from ..collision import CollisionWorld
from ..geometry import Footprint


def random_problems(world: CollisionWorld, fp: Footprint, count: int, seed: int, clearance: float = 0.5,
                    min_distance: float = 5.0, max_tries: int = 200_000) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` start/goal pairs drawn with ``numpy.random.default_rng(seed)``: poses whose footprint
    keeps ``clearance`` from the obstacles, start and goal at least ``min_distance`` apart."""
    rng = np.random.default_rng(seed)
    xmin, ymin, xmax, ymax = world.bounds
    check = world.state_checker(fp, clearance)
    out, pending = [], None
    for _ in range(max_tries):
        pose = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax), rng.uniform(-math.pi, math.pi)])
        if not check(*pose):
            continue
        if pending is None:
            pending = pose
        elif math.hypot(*(pose[:2] - pending[:2])) >= min_distance:
            out.append((pending, pose))
            pending = None
            if len(out) == count:
                return out
    raise RuntimeError(f"found only {len(out)} of {count} free start/goal pairs")


def benchmr_center_to_rear_axle(pose, length: float, rear_overhang: float) -> np.ndarray:
    """Bench-MR poses locate the car's centre; nhstab's cars are referenced to the rear axle."""
    x, y, th = pose
    back = length / 2 - rear_overhang
    return np.array([x - back * math.cos(th), y - back * math.sin(th), th])
