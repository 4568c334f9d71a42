"""Robots of several bodies (a car and its trailers) against a collision world: every body checked.

A :class:`~nhstab.robot.Robot` maps a state to the pose of each of its bodies
(:meth:`~nhstab.robot.Robot.body_poses`: the car's rear axle, then each trailer's axle, each with its
own heading) and has one footprint per body (:attr:`~nhstab.robot.Robot.footprints`). The queries here
check every body with the world's own single-body queries (:class:`~nhstab.collision.CollisionWorld`,
the FCL owner): a state is free when every body is free, in collision when any body is, and its
clearance is the smallest over the bodies. A one-body robot makes exactly the world's one call, with
the same arguments, so its answers and costs are unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError
from .geometry import wrap_angle


def _states(states) -> np.ndarray:
    return np.atleast_2d(np.asarray(states, dtype=float))


def placed(robot, states) -> list[tuple[np.ndarray, object]]:
    """Per body: (its poses (N, 3) at the states (N, n), its footprint)."""
    poses = robot.body_poses(_states(states))
    return [(poses[:, b], fp) for b, fp in enumerate(robot.footprints)]


def collides(world, robot, x) -> int | None:
    """The index of the first body of state x that overlaps an obstacle, or None."""
    poses = robot.body_poses(np.asarray(x, dtype=float))
    for b, fp in enumerate(robot.footprints):
        if world.in_collision(poses[b], fp):
            return b
    return None


def clearance(world, robot, x) -> tuple[float, int]:
    """The smallest signed clearance over the bodies of state x, and the body it belongs to."""
    poses = robot.body_poses(np.asarray(x, dtype=float))
    values = [world.clearance(poses[b], fp) for b, fp in enumerate(robot.footprints)]
    b = int(np.argmin(values))
    return float(values[b]), b


def configuration_clearance(world, robot, config) -> float:
    """The robot's clearance at a planning configuration (x, y, theta[, theta1 .. thetaN]; the other
    states 0): the world's clearance of its footprint, or the smallest over its bodies."""
    config = np.asarray(config, dtype=float)
    if len(robot.footprints) == 1:
        return float(world.clearance(config[:3], robot.footprint))
    x = np.zeros(robot.model.n)
    x[robot.configuration_columns] = config
    return clearance(world, robot, x)[0]


def is_free(world, robot, x, margin: float = 0.0) -> bool:
    """Every body of state x keeps ``margin`` from the obstacles."""
    poses = robot.body_poses(np.asarray(x, dtype=float))
    return all(world.is_free(poses[b], fp, margin) for b, fp in enumerate(robot.footprints))


def free_many(world, robot, states, margin: float = 0.0) -> np.ndarray:
    """:func:`is_free` for many states (N, n) (each body with the world's batched ``free_many``)."""
    out = None
    for poses, fp in placed(robot, states):
        free = world.free_many(poses, fp, margin)
        out = free if out is None else out & free
    return out


def motion_free(world, robot, states, margin: float = 0.0, stats: dict | None = None) -> bool:
    """Are all states (N, n) of a motion free? Each body's poses with the world's ``motion_free``
    (the distance field first, FCL for the rest, stopping at the first pose not free)."""
    return all(world.motion_free(poses, fp, margin, stats) for poses, fp in placed(robot, states))


def min_clearance(world, robot, states) -> tuple[float, int, int]:
    """The smallest signed clearance over the states (N, n) and all bodies: (value, state index, body)."""
    best = (math.inf, 0, 0)
    for b, (poses, fp) in enumerate(placed(robot, states)):
        c, k = world.min_clearance(poses, fp)
        if c < best[0]:
            best = (float(c), int(k), b)
    return best


@dataclass
class BodiesCheck:
    """Result of :func:`check_path` (indices refer to the interpolated states)."""

    clear: bool
    margin: float
    samples: int
    first_conflict_index: int | None
    first_conflict_body: int | None
    first_conflict_pose: np.ndarray | None    # that body's pose
    min_clearance: float
    min_clearance_index: int
    min_clearance_body: int
    min_clearance_pose: np.ndarray            # that body's pose
    states: np.ndarray = field(repr=False)
    free: np.ndarray = field(repr=False)


def interpolate_states(robot, states: np.ndarray, resolution: float, angular_resolution: float) -> np.ndarray:
    """The states (N, n) with samples inserted linearly so that, between consecutive samples, no body
    moves more than ``resolution`` m and no heading more than ``angular_resolution`` rad (angle
    states taken along the shortest turn)."""
    states = _states(states)
    if len(states) < 2:
        return states.copy()
    d = np.diff(states, axis=0)
    angles = list(robot.model.angle_states)
    if angles:
        d[:, angles] = wrap_angle(d[:, angles])
    poses = robot.body_poses(states)
    moved = np.hypot(*np.moveaxis(np.diff(poses[..., :2], axis=0), -1, 0)).max(axis=1)
    turned = np.abs(wrap_angle(np.diff(poses[..., 2], axis=0))).max(axis=1)
    steps = np.maximum(1, np.ceil(np.maximum(moved / resolution, turned / angular_resolution))).astype(int)
    seg = np.repeat(np.arange(len(steps)), steps)
    first = np.concatenate([[0], np.cumsum(steps)[:-1]])
    a = ((np.arange(len(seg)) - first[seg]) / steps[seg])[:, None]
    return np.vstack([states[seg] + a * d[seg], states[-1:]])


def check_path(world, robot, states, margin: float = 0.0, resolution: float = 0.05,
               angular_resolution: float = 0.05) -> BodiesCheck:
    """Check a path of states (N, n): every body at samples no more than ``resolution`` m and
    ``angular_resolution`` rad apart, against ``margin``; the first conflict and the smallest
    clearance over all bodies, with the body. A one-body robot is checked by the world's own
    ``check_path`` on its poses."""
    states = _states(states)
    if states.shape[1] != robot.model.n or len(states) < 1 or not np.all(np.isfinite(states)):
        raise InputError("states", f"a finite (N, {robot.model.n}) array of states", f"shape {states.shape}")
    if len(robot.footprints) == 1:
        pc = world.check_path(states[:, robot.pose_columns], robot.footprint, margin, resolution, angular_resolution)
        return BodiesCheck(pc.clear, margin, pc.samples, pc.first_conflict_index, None if pc.clear else 0,
                           pc.first_conflict_pose, pc.min_clearance, pc.min_clearance_index, 0,
                           pc.min_clearance_pose, pc.poses, pc.free)
    samples = interpolate_states(robot, states, resolution, angular_resolution)
    poses = robot.body_poses(samples)
    free = np.ones(len(samples), dtype=bool)
    first_body = np.full(len(samples), -1)
    best = (math.inf, 0, 0)
    for b, fp in enumerate(robot.footprints):
        fb = world.free_many(poses[:, b], fp, margin)
        first_body[(~fb) & free] = b
        free &= fb
        c, k = world.min_clearance(poses[:, b], fp)
        if c < best[0]:
            best = (float(c), int(k), b)
    first = int(np.argmin(free)) if not free.all() else None
    fb = None if first is None else int(first_body[first])
    return BodiesCheck(first is None, margin, len(samples), first, fb,
                       None if first is None else poses[first, fb], best[0], best[1], best[2],
                       poses[best[1], best[2]], samples, free)
