"""Can the car with trailers get from its start to its goal at all? An exhaustive search of the
configurations the rig reaches, on a fine grid, from both ends at once.

The planner's searches (:mod:`nhstab.planning.trailer_search`, the trailer's Reeds-Shepp paths) stop at a
budget or on a lattice coarse enough to be fast. When they find nothing, the question a user asks next
is whether anything could. This search answers it at a stated resolution.

Moves
-----
From a configuration the rig drives ``step_m`` (the car's rear axle's arc length) forward or in reverse
with its steering angle held at one of ``steer_levels`` values spread evenly over [-max_steer,
max_steer]. The steering angle is set between moves, with the rig at rest, so no steering rate is
needed: a sequence of moves is a motion of the model that stops to steer wherever the steering angle
changes (as nhstab's car nominals do at cusps). Each move is integrated with RK4 (the model's own
right-hand side) in substeps of at most :data:`SUBSTEP_M`, and every substep is checked: each hitch angle
within the jackknife limit, every body free by the margin (:func:`nhstab.bodies.free_many`, exact FCL
where the distance field cannot decide).

Cells and verdict
-----------------
A configuration is kept when its cell was not reached before from the same end: the last trailer's axle
position in squares of ``cell_m``, its heading and every hitch angle in bins of ``angle_rad``. The start
and the goal grow breadth first, in turn, one layer of moves at a time. The rig is driftless, so a move
run backwards is a move: the ends are **connected** when one cell is reached from both (up to a cell: the
two configurations in it differ by less than its size). An end is **closed** when every cell it reaches
has been expanded and none was reached from the other end: then no sequence of these moves joins start
and goal at this resolution (``disconnected``). A grid search is evidence, not a proof: a finer grid,
more steering levels or shorter moves can join what a coarser one did not. The budget is wall time, read
between layers; a search that runs out of it, or reaches :data:`MAX_CELLS`, is ``undecided``.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .. import bodies
from ..errors import InputError
from ..geometry import wrap_angle
from ..limits import check_int, check_range

#: the longest RK4 substep of a move [m of the car's rear axle]; every substep's configuration is checked
SUBSTEP_M = 0.05
#: the default grid: cell [m], angle bin [rad], steering levels, move length [m]
CELL_M = 0.1
ANGLE_RAD = math.radians(2.0)
STEER_LEVELS = 9
STEP_M = 0.2
#: the most cells both ends may hold together (memory: about 200 bytes a cell); the search stops there
#: undecided, as at its budget
MAX_CELLS = 4_000_000
#: the ranges rig_reach accepts: (low, high) per argument
RANGES = {"cell_m": (1e-3, 10.0), "angle_rad": (1e-4, 1.0), "step_m": (1e-3, 10.0), "budget_s": (0.0, 1e7)}
MAX_STEER_LEVELS = 201


def rig_reach(world, robot, x_start, x_goal, margin: float, *, cell_m: float = CELL_M, angle_rad: float = ANGLE_RAD,
              steer_levels: int = STEER_LEVELS, step_m: float = STEP_M, budget_s: float = 60.0,
              max_cells: int = MAX_CELLS, clock=time.perf_counter) -> dict:
    """The search of the module docstring between full states ``x_start`` and ``x_goal`` (the model's
    state order, e.g. from :func:`rest_state`; the steering angle in them is ignored). Returns a dict:
    ``verdict`` ("connected", "disconnected" or "undecided"), ``closed_end`` (the end whose cells ran
    out, for "disconnected"), per end the cells reached, the layers grown, the least distance of its
    last trailer's axle from the other end's (``closest_m``) and the largest from its own
    (``farthest_m``), ``travel_m`` (the moves of both ends to the meeting cell, for "connected"), the
    resolution, the wall time and, for "undecided", what stopped it (``stopped``: "budget" or "cells",
    at ``max_cells`` cells of both ends together, checked between layers)."""
    model = robot.model
    if not getattr(robot, "trailers", 0):
        raise InputError("robot", "a car with at least one trailer", getattr(model, "name", model))
    cell_m = check_range("cell_m", cell_m, *RANGES["cell_m"], "m")
    angle_rad = check_range("angle_rad", angle_rad, *RANGES["angle_rad"], "rad")
    step_m = check_range("step_m", step_m, *RANGES["step_m"], "m")
    budget_s = check_range("budget_s", budget_s, *RANGES["budget_s"], "s")
    steer_levels = check_int("steer_levels", steer_levels, 1, MAX_STEER_LEVELS, "a number of steering angles")
    max_cells = check_int("max_cells", max_cells, 1, 10**9, "a number of cells")
    started = clock()
    heads = list(model.heading_columns)
    steer_col = list(model.state_names).index("phi")
    limit = float(model.jackknife_limit)
    steers = np.linspace(-model.max_steer, model.max_steer, steer_levels) if steer_levels > 1 else np.zeros(1)
    subs = max(1, int(math.ceil(step_m / SUBSTEP_M - 1e-9)))
    h = step_m / subs

    def axle(x):
        # the last trailer's axle position (its body pose's reference point)
        return robot.body_poses(x)[..., -1, :2]

    def keys(x):
        p = axle(x)
        ang = np.concatenate([wrap_angle(x[:, heads[-1:]]), model.hitch_angles(x)], axis=1)
        cells = np.concatenate([np.floor(p / cell_m), np.floor(ang / angle_rad)], axis=1).astype(np.int64)
        return [tuple(r) for r in cells]

    def rhs(x, v):
        u = np.zeros((len(x), model.m))
        u[:, 0] = v
        return model.rhs(x, u)

    ends = []
    for name, x in (("start", x_start), ("goal", x_goal)):
        x = np.array(x, dtype=float).reshape(1, -1)
        if x.shape[1] != model.n or not np.all(np.isfinite(x)):
            raise InputError(name, f"a finite state of {model.n} numbers ({', '.join(model.state_names)})",
                             np.asarray(x).ravel().tolist())
        x[:, steer_col] = 0.0
        if not (np.all(np.abs(model.hitch_angles(x)) <= limit) and bodies.free_many(world, robot, x, margin)[0]):
            raise InputError(name, f"a configuration within the jackknife limit whose every body keeps the margin "
                                   f"{margin:g} m", np.round(x.ravel(), 4).tolist())
        ends.append({"name": name, "frontier": x, "seen": set(keys(x)), "layers": 0, "xy": axle(x)[0],
                     "farthest_m": 0.0})
    for e, other in ((ends[0], ends[1]), (ends[1], ends[0])):
        e["closest_m"] = float(np.linalg.norm(e["xy"] - other["xy"]))

    def grow(e, other):
        # one layer of moves from e's frontier: the new configurations whose cells e had not reached;
        # returns the index of a configuration in a cell the other end reached, or None
        front = e["frontier"]
        kept = []
        for v in (1.0, -1.0):
            for phi in steers:
                x = front.copy()
                x[:, steer_col] = phi
                ok = np.ones(len(x), dtype=bool)
                for _ in range(subs):
                    k1 = rhs(x, v)
                    k2 = rhs(x + 0.5 * h * k1, v)
                    k3 = rhs(x + 0.5 * h * k2, v)
                    k4 = rhs(x + h * k3, v)
                    x = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
                    ok &= np.all(np.abs(model.hitch_angles(x)) <= limit, axis=1)
                    idx = np.flatnonzero(ok)
                    if len(idx):
                        ok[idx] = bodies.free_many(world, robot, x[idx], margin)
                    if not ok.any():
                        break
                kept.append(x[ok])
        cand = np.concatenate(kept) if kept else np.empty((0, model.n))
        new, meet = [], None
        for i, k in enumerate(keys(cand)):
            if k in e["seen"]:
                continue
            e["seen"].add(k)
            new.append(i)
            if meet is None and k in other["seen"]:
                meet = len(new) - 1
        e["frontier"] = cand[new]
        e["layers"] += 1
        if len(new):
            d = np.linalg.norm(axle(e["frontier"]) - other["xy"], axis=1)
            e["closest_m"] = min(e["closest_m"], float(d.min()))
            own = np.linalg.norm(axle(e["frontier"]) - e["xy"], axis=1)
            e["farthest_m"] = max(e["farthest_m"], float(own.max()))
        return meet

    verdict, closed, travel, stopped = "undecided", None, None, None
    if ends[0]["seen"] & ends[1]["seen"]:
        verdict, travel = "connected", 0.0
    while verdict == "undecided":
        empty = [e for e in ends if not len(e["frontier"])]
        if empty:
            verdict, closed = "disconnected", empty[0]["name"]
            break
        if clock() - started >= budget_s:
            stopped = "budget"
            break
        if len(ends[0]["seen"]) + len(ends[1]["seen"]) >= max_cells:
            stopped = "cells"
            break
        # the end with the smaller frontier grows by one layer of moves
        e = min(ends, key=lambda q: len(q["frontier"]))
        if grow(e, ends[1] if e is ends[0] else ends[0]) is not None:
            verdict = "connected"
            travel = (ends[0]["layers"] + ends[1]["layers"]) * step_m
    out = {"verdict": verdict, "closed_end": closed, "travel_m": travel, "stopped": stopped, "max_cells": max_cells,
           "cell_m": cell_m, "angle_rad": angle_rad, "steer_levels": steer_levels, "step_m": step_m,
           "margin_m": float(margin), "budget_s": budget_s, "wall_s": clock() - started}
    for e in ends:
        out[e["name"]] = {"cells": len(e["seen"]), "layers": e["layers"], "closest_m": e["closest_m"],
                          "farthest_m": e["farthest_m"]}
    return out


def reach_text(r: dict) -> str:
    """One line on a :func:`rig_reach` result."""
    res = (f"cells of {r['cell_m']:g} m and {math.degrees(r['angle_rad']):g} deg, {r['steer_levels']} steering "
           f"levels, moves of {r['step_m']:g} m, margin {r['margin_m']:g} m")
    if r["verdict"] == "connected":
        return f"connected: start and goal meet after {r['travel_m']:.1f} m of moves ({res})"
    if r["verdict"] == "disconnected":
        e = r[r["closed_end"]]
        return (f"disconnected: every configuration the rig reaches from its {r['closed_end']} was expanded "
                f"({e['cells']} cells, {e['layers']} layers of moves; its last trailer's axle at most "
                f"{e['farthest_m']:.2f} m from where it started and never nearer than {e['closest_m']:.2f} m to "
                f"the other end's), none reached from the other end ({res})")
    ends = "; ".join(f"from the {k}, {r[k]['cells']} cells, its last trailer's axle up to {r[k]['farthest_m']:.2f} m "
                     f"away" for k in ("start", "goal"))
    why = (f"the cap of {r['max_cells']:,} cells was reached" if r.get("stopped") == "cells"
           else f"the budget of {r['budget_s']:g} s ran out")
    return f"undecided: {why} before the ends met or one was closed ({ends}; {res})"


def rest_state(model, configuration) -> np.ndarray:
    """The full state (x, y, theta, phi, theta1 .. thetaN) of a configuration (x, y, theta, theta1 ..
    thetaN) with the wheels straight."""
    c = np.asarray(configuration, dtype=float)
    return np.insert(c, list(model.state_names).index("phi"), 0.0)
