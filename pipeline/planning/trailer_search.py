"""A Hybrid-A* search over the whole car-with-one-trailer rig, in (x, y, theta, theta1) with the steering
angle carried along, for the spaces the trailer's Reeds-Shepp path cannot use (aisles, dock bays), with
the hitch-angle law's primitives or, where those cannot leave a bay, stop-and-steer ones.

Motion primitives
-----------------
A node is a full state (x, y, theta, phi, theta1) of the ``car_trailer`` model reached exactly, with
the input it was reached with. From a node the rig drives ``PRIMITIVE_STEPS`` steps of ``step_s``
seconds, forward or in reverse at the nominal's speed, under :func:`hitch_law`, which steers the
hitch angle D towards one of ``HITCH_LEVELS`` targets (so that D' = -``HITCH_GAIN`` |v| (D - target)
forward and in reverse alike: reversing stays stable), the steering angle within its cap and its
rate within the rate cap. The law's commands become the input knots one step late and the inputs
are linear between knots, as the tracker of :mod:`nhstab.planning.trailer` holds its commands. The
model's right-hand side is integrated with RK4 (``RK4_SUBSTEPS`` steps per knot interval), all
primitives of ``BATCH_NODES`` nodes at once; the nominal integrates the same knots again on its own
grid (:func:`nhstab.planning.trailer.lattice_nominal`), so the plan is exactly a motion of the model.
Nodes near the target's axis get one more primitive whose target hitch angle comes from the
tracker's curvature law towards that straight line (``APPROACH_GAINS``).

Stop-and-steer primitives
-------------------------
With ``primitives="steer"`` the search moves as a driver does in a tight bay: it stops, steers, drives.
From a node, for each of ``STEER_LEVELS`` steering angles over +- the steering cap and each direction:
unless the node is already moving that way at that angle, the speed falls to 0 over one knot interval,
the steering angle goes to the level at rest (the rate ramps up over one interval, holds within the rate
cap, ramps down over one; at rest only phi moves, phi' = omega, so the search sets it exactly), and the
rig drives ``STEER_DRIVE_STEPS`` intervals (the first ramping up from rest); a node moving that way at
that angle drives on at speed. The ramp to rest and the drive are integrated with RK4 and every state
is checked as below (the drive's last state first). These knots are the plan's inputs like any other
primitive's, so the nominal integrates them again exactly. Their duplicate cells are finer
(``STEER_CELL_M``, ``STEER_HEADING_BINS``, ``STEER_HITCH_BIN_RAD``, without the direction), a reversal
costs ``STEER_CUSP_COST_M`` and reversing no more than driving forward, and their heuristic, weighted
``STEER_HEURISTIC_WEIGHT``, is how far the trailer's axle is from the straight line through the target's
trailer axle along its heading (where the exact join below is tried), plus its heading error times the
trailer's radius d / tan(hitch_cap), the hitch angle times d, and the distance beyond
``ANALYTIC_RANGE_M`` along that line; at least the grid distance less ``ANALYTIC_RANGE_M``.

Checks
------
A primitive is kept when at every integrated state the hitch angle is within ``hitch_cap``, the
steering angle within ``steer_cap``, and both bodies (the car's and the trailer's footprints) are
free by the margin: the collision world's :meth:`~nhstab.collision.CollisionWorld.free_many` on the
states of all primitives of a batch at once (its conservative distance field decides most poses
vectorised, FCL the rest), in chunks of ``CHECK_CHUNK_STEPS`` knots so that no state past a
primitive's first collision is checked. With ``cut_primitives``, a primitive that leaves the limits
or collides is kept up to its last knot before that, when at least ``MIN_PRIMITIVE_STEPS`` knots
long: it is then exactly the primitive of the same law with fewer knots (a knot's command depends
on the states before it only), so the moves get shorter where the space is tight.

Resolution
----------
``resolution`` 0 merges duplicates by the cells below; 1 (the finer lattice) divides the position
cells and the hitch angle bins by ``FINE_DIVISOR``, has (``HITCH_LEVELS`` - 1) ``FINE_DIVISOR`` + 1
hitch angle levels, and memoises the Reeds-Shepp heuristic on a lattice ``FINE_DIVISOR`` times finer.
A search that ends without a plan and without reaching its budget or ``MAX_EXPANSIONS`` has expanded
every cell it reached (``info["exhausted"]``): the caller may then try a finer search
(:func:`nhstab.planning.trailer.lattice_plan`).

Cost and heuristic
------------------
The cost is the trailer axle's arc length, reversing costing ``REVERSE_FACTOR`` times as much, plus
``CUSP_COST_M`` per reversal and ``STEER_CHANGE_COST_M`` per radian of steering change. The
heuristic, weighted ``HEURISTIC_WEIGHT``, is the larger of the 8-connected grid distance (Dijkstra,
cells of ``GRID_CELL_M``) from the target's trailer axle through the cells where a disc of the
trailer footprint's inscribed radius about its axle keeps the margin (less a cell's slack), and the
obstacle-free Reeds-Shepp length of the trailer's axle at the radius d / tan(hitch_cap) (the
trailer's curvature is tan(D) / d) to a pose ``PRE_GOAL_M`` before or beyond the target on its
axis, or less where the rig standing straight on that axis would leave the free space
(:func:`straight_run`: a dock bay off a narrow aisle; a side with less than ``PRE_GOAL_MIN_M`` of
such room, a dock wall, is left out), plus that distance (on that stretch, near the axis: to the
target itself). The Reeds-Shepp lengths are memoised on a lattice of ``RS_CELL_M`` and
``RS_HEADING_BINS`` in the target's frame. The exact join
below needs that room. Duplicates are merged by cells of ``CELL_M`` (trailer axle position),
``HEADING_BINS`` (trailer heading), ``HITCH_BIN_RAD`` (hitch angle) and the direction.

Rooted at either end
--------------------
The car with a trailer is driftless (x' = g(x) u), so a motion run backwards in time is a motion
under the negated inputs. ``from_goal`` roots the search at the goal: the rig drives out of the
dock (forward, where the hitch angle is stable) towards the start, and the plan is that motion
reversed in time; the target is then the start.

Analytic expansion
------------------
From calm nodes (steering and hitch angles within ``ANALYTIC_CALM_RAD``) ``ANALYTIC_MIN_M`` to
``ANALYTIC_RANGE_M`` from the target along its axis, within ``ANALYTIC_CONE`` and
``ANALYTIC_HEADING_RAD``, and moving towards it (once per cell of ``ANALYTIC_CELL_M``), and always
from the root, the exact chained-form polynomial piece
(:func:`~nhstab.planning.trailer_charts.steer_trailer`) is tried from the node to the goal (rooted at
the goal: from the start to the node); it is taken when it keeps the steering angle within
``steer_cap``, the hitch angle within ``hitch_cap``, the speed within the nominal's, the steering
rate within the limit and both bodies free by the margin.

Budget
------
The search stops at the first reading of its clock at or past ``budget_s`` seconds (read before each
node's expansion after the root's, which always runs, and before each batch), or at
``MAX_EXPANSIONS`` expansions; the time to build the grid heuristic counts. Without a plan it reports
the node closest to the target (the trailer axle's distance and heading error, the heuristic there)
and why the pieces tried were refused.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .. import bodies
from ..collision import CollisionWorld
from ..errors import InputError
from ..geometry import wrap_angle
from . import local_paths
from .trailer_charts import TrailerSteering, steer_trailer

#: the duration of one knot interval of a primitive's inputs [s] (the planner rounds it to a whole number
#: of the nominal's steps)
PRIMITIVE_STEP_S = 0.1
#: knot intervals per primitive (with PRIMITIVE_STEP_S and the built-in rig: 1.08 m at 0.9 m/s)
PRIMITIVE_STEPS = 12
#: RK4 steps per knot interval in the search (every one of their states is checked)
RK4_SUBSTEPS = 2
#: a primitive that leaves the limits or collides is kept up to its last knot before that, when at least this
#: many knot intervals long
MIN_PRIMITIVE_STEPS = 3
#: the states of a batch's primitives are checked in chunks of this many knot intervals (after the first
#: MIN_PRIMITIVE_STEPS), a primitive's states past its first collision not at all
CHECK_CHUNK_STEPS = 3
#: the hitch angles the primitives aim at: this many levels (odd: straight is one) over +- this fraction of
#: the smaller of hitch_cap and the hitch angle the car can hold in reverse at the steering cap
HITCH_LEVELS = 5
HITCH_TARGET_FRACTION = 0.95
#: the primitives' law: hitch angle gain [1/m], steering angle gain [1/s], and the fraction of the steering
#: cap it asks for (room for the one-knot lag of its commands)
HITCH_GAIN = 3.0
STEER_GAIN = 5.0
LAW_STEER_FRACTION = 0.97
#: the approach primitives' law: lateral error [1/m^2], heading error [1/m] (the tracker's gains)
APPROACH_GAINS = (0.15, 0.8)
#: nodes expanded together (their primitives integrated and checked at once)
BATCH_NODES = 16
#: the duplicate cells: trailer axle position [m], trailer heading bins per turn, hitch angle [rad]
CELL_M = 0.5
HEADING_BINS = 72
HITCH_BIN_RAD = 0.2
#: the Reeds-Shepp part of the heuristic is memoised on a lattice of this spacing [m] and heading bins per turn in
#: the target's frame
RS_CELL_M = 0.5
RS_HEADING_BINS = 72
#: the finer lattice (``resolution`` 1): the duplicate cells and the hitch angle bins divided by this, and
#: (HITCH_LEVELS - 1) times this plus one hitch angle levels
FINE_DIVISOR = 2
#: cost factors: reversing per metre, per reversal [m], per radian of steering change over a primitive [m]
REVERSE_FACTOR = 1.5
CUSP_COST_M = 3.0
STEER_CHANGE_COST_M = 0.5
#: f = g + HEURISTIC_WEIGHT h
HEURISTIC_WEIGHT = 2.5
#: the grid of the distance heuristic [m]
GRID_CELL_M = 0.25
#: the Reeds-Shepp part of the heuristic leads to the poses this far before and beyond the target's trailer
#: pose on its axis [m] (where the exact join starts best), plus this distance; between such a pose and
#: the target, within PRE_GOAL_ZONE of its axis ([m], [rad] of heading), to the target itself
PRE_GOAL_M = 8.0
PRE_GOAL_ZONE = (1.0, 0.5)
#: a side of the target's axis where the rig standing straight stays free for less than this [m] is left out
PRE_GOAL_MIN_M = 4.0
#: analytic expansion from nodes whose trailer axle is ANALYTIC_MIN_M to ANALYTIC_RANGE_M from the target's
#: along its axis [m], moving towards it, within ANALYTIC_CONE (|across| / |along|) and ANALYTIC_HEADING_RAD,
#: with steering and hitch angles within ANALYTIC_CALM_RAD, once per cell of ANALYTIC_CELL_M [m] and 0.1 rad
ANALYTIC_MIN_M = 1.5
ANALYTIC_RANGE_M = 20.0
ANALYTIC_CONE = 0.35
ANALYTIC_HEADING_RAD = 0.6
ANALYTIC_CALM_RAD = 0.6
ANALYTIC_CELL_M = 0.5
#: nodes whose trailer axle is within APPROACH_RANGE_M of the target's along its axis, APPROACH_CONE and
#: APPROACH_HEADING_RAD get one more primitive, towards the target along its axis (APPROACH_GAINS)
APPROACH_RANGE_M = 25.0
APPROACH_CONE = 0.6
APPROACH_HEADING_RAD = 0.8
#: an upper bound on expansions, whatever the budget
MAX_EXPANSIONS = 200_000
#: the stop-and-steer primitives (``primitives="steer"``): this many steering levels over +- the steering cap
#: (odd: straight is one), and knot intervals driven per primitive at the nominal's speed
STEER_LEVELS = 9
STEER_DRIVE_STEPS = 4
#: their duplicate cells: trailer axle position [m], trailer heading bins per turn, hitch angle [rad]
STEER_CELL_M = 0.1
STEER_HEADING_BINS = 180
STEER_HITCH_BIN_RAD = math.radians(2.0)
#: their cost of a reversal [m] (no more than that of moving the trailer's axle 1 m: a bay needs reversals)
STEER_CUSP_COST_M = 1.0
#: their heuristic's weight: f = g + STEER_HEURISTIC_WEIGHT h
STEER_HEURISTIC_WEIGHT = 3.0


@dataclass
class LatticeResult:
    """The search's outcome. ``found``: a plan (``knots``: the primitives' inputs (K + 1, 2) at times
    ``step_s`` k, piecewise linear between them; ``states``: the node states in the order driven;
    ``piece``: the chained-form piece; with ``from_goal`` False the primitives start at the start and
    the piece ends at the goal, with ``from_goal`` True the piece starts at the start and the
    primitives (reversed in time) end at the goal); otherwise ``message`` says why, with the node
    closest to the search's target."""

    found: bool
    message: str
    step_s: float
    knots: np.ndarray
    states: np.ndarray
    piece: TrailerSteering | None
    info: dict = field(default_factory=dict)
    from_goal: bool = False


def inscribed_radius(fp) -> float:
    """The largest disc about the footprint's reference point that lies within it (0 if the point is
    outside it)."""
    if fp.radius is not None:
        return float(fp.radius)
    v = np.asarray(fp.vertices, dtype=float)
    a, b = v, np.roll(v, -1, axis=0)
    e = b - a
    t = np.clip(np.einsum("ij,ij->i", -a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0.0, 1.0)
    dist = float(np.min(np.hypot(*(a + t[:, None] * e).T)))
    cross = e[:, 0] * (-a[:, 1]) - e[:, 1] * (-a[:, 0])
    inside = bool(np.all(cross > 0) or np.all(cross < 0))
    return dist if inside else 0.0


def grid_distance(world: CollisionWorld, robot, margin: float, goal_xy, cell: float = GRID_CELL_M):
    """The Dijkstra distance [m] from ``goal_xy`` over an 8-connected grid of ``cell`` m on the world's
    bounds, through the cells whose centre is at least the trailer footprint's inscribed radius plus
    ``margin`` from the obstacles (by the world's distance field, less a cell's slack, so that it
    never exceeds the trailer axle's shortest free path). Returns (distances (rows, cols), x0, y0)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    fld = world.clearance_field()
    xmin, ymin, xmax, ymax = world.bounds
    cols, rows = int(math.ceil((xmax - xmin) / cell)), int(math.ceil((ymax - ymin) / cell))
    xs = xmin + (np.arange(cols) + 0.5) * cell
    ys = ymin + (np.arange(rows) + 0.5) * cell
    need = inscribed_radius(robot.footprints[1]) + margin - (cell / math.sqrt(2) + 2 * math.sqrt(2) * fld.r)
    free = fld.at(*np.meshgrid(xs, ys)) >= need
    gi = int(np.clip((goal_xy[1] - ymin) // cell, 0, rows - 1))
    gj = int(np.clip((goal_xy[0] - xmin) // cell, 0, cols - 1))
    free[gi, gj] = True
    idx = np.arange(rows * cols).reshape(rows, cols)
    src, dst, wts = [], [], []
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = free[max(0, -di):rows - max(0, di), max(0, -dj):cols - max(0, dj)]
        b = free[max(0, di):rows + min(0, di), max(0, dj):cols + min(0, dj)]
        ok = a & b
        ia = idx[max(0, -di):rows - max(0, di), max(0, -dj):cols - max(0, dj)][ok]
        ib = idx[max(0, di):rows + min(0, di), max(0, dj):cols + min(0, dj)][ok]
        src += [ia, ib]
        dst += [ib, ia]
        wts += [np.full(2 * len(ia), cell * math.hypot(di, dj))]
    src, dst = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.concatenate(wts), (src, dst)), shape=(rows * cols, rows * cols)).tocsr()
    dist = dijkstra(graph, indices=int(idx[gi, gj])).reshape(rows, cols)
    return dist, float(xmin), float(ymin)


def straight_run(world: CollisionWorld, robot, x, sign: float, margin: float, longest: float,
                 step: float = GRID_CELL_M) -> float:
    """How far [m] (up to ``longest``, in steps of ``step``) the rig at state ``x``, standing straight
    (hitch angle 0, the trailer's heading), can be moved back along that heading (``sign`` +1: the
    poses before it, from which it arrives driving forward) or ahead (``sign`` -1) with both bodies
    free by ``margin``; at least one step."""
    d = float(robot.model.hitch_lengths[0])
    th = float(x[4])
    c, s_ = math.cos(th), math.sin(th)
    dist = np.arange(1, int(math.floor(longest / step + 1e-9)) + 1) * step
    if not len(dist):
        return float(longest)
    px, py = float(x[0]) - sign * dist * c, float(x[1]) - sign * dist * s_
    car = np.column_stack([px, py, np.full(len(dist), th)])
    trailer = np.column_stack([px - d * c, py - d * s_, np.full(len(dist), th)])
    free = world.free_many(car, robot.footprints[0], margin) & world.free_many(trailer, robot.footprints[1], margin)
    bad = np.flatnonzero(~free)
    return float(dist[-1]) if not len(bad) else float(max(dist[bad[0] - 1] if bad[0] else step, step))


class _Rhs:
    """The car_trailer right-hand side for one trailer on (K, 5) arrays (CarTrailer.rhs written out)."""

    def __init__(self, model):
        self.L, self.d = float(model.wheelbase), float(model.hitch_lengths[0])

    def __call__(self, x, v, w):
        th, phi, th1 = x[:, 2], x[:, 3], x[:, 4]
        return np.stack([np.cos(th) * v, np.sin(th) * v, np.tan(phi) * v / self.L, w,
                         v * np.sin(th - th1) / self.d], axis=1)


def integrate_knots(model, x0, knots, step_s: float, substeps: int = RK4_SUBSTEPS) -> np.ndarray:
    """The model from states ``x0`` (K, 5) under inputs linear between ``knots`` (K, M + 1, 2) spaced
    ``step_s``: RK4 with ``substeps`` steps per interval; returns the states (K, M substeps + 1, 5)."""
    f = _Rhs(model)
    x = np.array(x0, dtype=float)
    knots = np.asarray(knots, dtype=float)
    K, M1 = knots.shape[:2]
    out = np.empty((K, (M1 - 1) * substeps + 1, 5))
    out[:, 0] = x
    h = step_s / substeps
    n = 0
    for k in range(M1 - 1):
        u0, du = knots[:, k], knots[:, k + 1] - knots[:, k]
        for s in range(substeps):
            a, b, c = s / substeps, (s + 0.5) / substeps, (s + 1) / substeps
            ua, ub, uc = u0 + a * du, u0 + b * du, u0 + c * du
            k1 = f(x, ua[:, 0], ua[:, 1])
            k2 = f(x + 0.5 * h * k1, ub[:, 0], ub[:, 1])
            k3 = f(x + 0.5 * h * k2, ub[:, 0], ub[:, 1])
            k4 = f(x + h * k3, uc[:, 0], uc[:, 1])
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            n += 1
            out[:, n] = x
    return out


def hitch_law(model, x, target, direction, speed: float, steer_cap: float, rate_cap: float) -> np.ndarray:
    """The primitives' command (v, omega_s) at states x (K, 5): drive at ``direction`` x ``speed`` and
    steer the hitch angle D towards ``target``: tan(phi*) = L (sin(D) / d - HITCH_GAIN s (D - target)),
    so that D' = -HITCH_GAIN |v| (D - target) forward and in reverse alike, phi* within
    ``LAW_STEER_FRACTION`` of ``steer_cap`` (room for the one-knot lag of the command),
    omega_s = STEER_GAIN (phi* - phi) within ``rate_cap``."""
    L, d = float(model.wheelbase), float(model.hitch_lengths[0])
    D = wrap_angle(x[:, 2] - x[:, 4])
    tan_phi = L * (np.sin(D) / d - HITCH_GAIN * direction * (D - target))
    phi_des = np.clip(np.arctan(tan_phi), -LAW_STEER_FRACTION * steer_cap, LAW_STEER_FRACTION * steer_cap)
    omega = np.clip(STEER_GAIN * (phi_des - x[:, 3]), -rate_cap, rate_cap)
    return np.stack([direction * speed, omega], axis=1)


def integrate_primitives(model, x0, u0, targets, directions, *, speed: float, steer_cap: float, rate_cap: float,
                         step_s: float, steps: int = PRIMITIVE_STEPS, substeps: int = RK4_SUBSTEPS,
                         approach=None, line=None, top: float = math.inf):
    """Primitives from states ``x0`` (K, 5) reached with inputs ``u0`` (K, 2): at every knot the
    command of :func:`hitch_law` for the primitive's target hitch angle and direction becomes the next
    knot (the inputs are linear between knots, one knot late, as the tracker holds its commands), and
    the model is integrated over the interval (:func:`integrate_knots`). Primitives flagged in
    ``approach`` (K,) take their target at every knot from the trailer axle's errors to the straight
    ``line`` (a pose: the goal's trailer axis): the curvature kappa = -APPROACH_GAINS[0] e_y -
    APPROACH_GAINS[1] s sin(e_theta), target atan(d kappa) within ``top``. Returns the states
    (K, steps substeps + 1, 5) and the knots (K, steps + 1, 2)."""
    x = np.array(x0, dtype=float)
    K = len(x)
    d = float(model.hitch_lengths[0])
    targets = np.array(targets, dtype=float)
    knots = np.empty((K, steps + 1, 2))
    knots[:, 0] = u0
    out = np.empty((K, steps * substeps + 1, 5))
    out[:, 0] = x
    sel = None if approach is None else np.flatnonzero(approach)
    for k in range(steps):
        if sel is not None and len(sel):
            p = _trailer_poses(d, x[sel])
            c, s_ = math.cos(line[2]), math.sin(line[2])
            e_y = -s_ * (p[:, 0] - line[0]) + c * (p[:, 1] - line[1])
            e_th = wrap_angle(p[:, 2] - line[2])
            kappa = -APPROACH_GAINS[0] * e_y - APPROACH_GAINS[1] * directions[sel] * np.sin(e_th)
            targets[sel] = np.clip(np.arctan(d * kappa), -top, top)
        knots[:, k + 1] = hitch_law(model, x, targets, directions, speed, steer_cap, rate_cap)
        seg = integrate_knots(model, x, knots[:, k:k + 2], step_s, substeps)
        out[:, k * substeps + 1:(k + 1) * substeps + 1] = seg[:, 1:]
        x = seg[:, -1]
    return out, knots


def _trailer_poses(d: float, x: np.ndarray) -> np.ndarray:
    th1 = x[..., 4]
    return np.stack([x[..., 0] - d * np.cos(th1), x[..., 1] - d * np.sin(th1), th1], axis=-1)


def lattice_search(world: CollisionWorld, robot, x_start, x_goal, *, margin: float, speed: float, step_s: float,
                   hitch_cap: float, steer_cap: float, rate_cap: float, max_speed: float, budget_s: float,
                   piece_margin: float | None = None, from_goal: bool = False, resolution: int = 0,
                   cut_primitives: bool = False, primitives: str = "hitch",
                   clock=time.perf_counter) -> LatticeResult:
    """Search from full state ``x_start`` to ``x_goal`` (module docstring). ``margin``: every body's
    clearance along the primitives; ``piece_margin`` (default ``margin``) along the final piece.
    ``from_goal``: root the search at the goal and join the start with the chained-form piece (module
    docstring: the motion reversed in time). ``primitives``: "hitch" (the hitch-angle law's primitives on
    the lattice of ``resolution``, cut with ``cut_primitives``) or "steer" (the stop-and-steer primitives
    on their own cells and heuristic, module docstring). ``clock``: the time in seconds the budget is
    counted on (read before every batch of expansions and every final piece tried)."""
    if from_goal:
        x_start, x_goal = x_goal, x_start
    started = clock()
    model = robot.model
    if model.name != "car_trailer" or model.trailers != 1:
        raise InputError("robot", "a car_trailer with one trailer", getattr(model, "name", model))
    d, L = float(model.hitch_lengths[0]), float(model.wheelbase)
    car_fp, trailer_fp = robot.footprints
    piece_margin = margin if piece_margin is None else piece_margin
    x_start = np.asarray(x_start, dtype=float)
    x_goal = np.asarray(x_goal, dtype=float)
    # the hitch angles the primitives aim at: within the cap, and within what the car can still hold in
    # reverse at the steering cap, sin(D) / d <= tan(steer_cap) / L
    holdable = math.asin(min(1.0, d * math.tan(steer_cap) / L))
    top = HITCH_TARGET_FRACTION * min(hitch_cap, holdable)
    if resolution not in (0, 1):
        raise InputError("resolution", "0 (the lattice's cells) or 1 (finer: FINE_DIVISOR)", resolution)
    if primitives not in ("hitch", "steer"):
        raise InputError("primitives", '"hitch" or "steer"', primitives)
    steer = primitives == "steer"
    div = FINE_DIVISOR if resolution else 1
    cell_m, hitch_bin = CELL_M / div, HITCH_BIN_RAD / div
    rs_cell, rs_bins = RS_CELL_M / div, RS_HEADING_BINS * div
    levels = np.linspace(-top, top, (HITCH_LEVELS - 1) * div + 1)
    goal_p1 = _trailer_poses(d, x_goal)
    r_h = d / math.tan(hitch_cap)
    dist, gx0, gy0 = grid_distance(world, robot, margin, goal_p1[:2])
    rows, cols = dist.shape
    cg, sg_ = math.cos(goal_p1[2]), math.sin(goal_p1[2])
    rs_cache: dict = {}
    # the poses the final piece starts from best: PRE_GOAL_M before the goal's trailer pose along its axis,
    # for arriving forward, and beyond it, for arriving in reverse, or as far as the rig standing straight on
    # the axis stays free (a dock bay off a narrow aisle)
    pre_m = [straight_run(world, robot, x_goal, sgn, margin, PRE_GOAL_M) for sgn in (1.0, -1.0)]
    pre = [np.array([goal_p1[0] - sgn * run * cg, goal_p1[1] - sgn * run * sg_, goal_p1[2]])
           for sgn, run in zip((1.0, -1.0), pre_m)]
    # a side where the rig cannot stand straight for PRE_GOAL_MIN_M (a dock wall) leaves the exact join too
    # little room: the heuristic leaves it out
    sides = [i for i in (0, 1) if pre_m[i] >= PRE_GOAL_MIN_M] or [0, 1]

    def grid_h(p):
        j = np.clip(((p[..., 0] - gx0) // GRID_CELL_M).astype(int), 0, cols - 1)
        i = np.clip(((p[..., 1] - gy0) // GRID_CELL_M).astype(int), 0, rows - 1)
        return dist[i, j]

    start_p1 = _trailer_poses(d, x_start)
    use_grid = bool(np.isfinite(grid_h(start_p1)))

    def rs_to(p, target):
        # the Reeds-Shepp length to ``target``, from its frame, memoised on a lattice of CELL_M and a heading
        # bin (the same lattice for every target)
        c, s_ = math.cos(target[2]), math.sin(target[2])
        dx, dy = p[0] - target[0], p[1] - target[1]
        q = (int(round((c * dx + s_ * dy) / rs_cell)), int(round((-s_ * dx + c * dy) / rs_cell)),
             int(round(float(wrap_angle(p[2] - target[2])) / (2 * math.pi) * rs_bins)))
        v = rs_cache.get(q)
        if v is None:
            a = (q[0] * rs_cell, q[1] * rs_cell, q[2] * 2 * math.pi / rs_bins)
            v = local_paths.path_length(local_paths.reeds_shepp(a, (0.0, 0.0, 0.0), r_h), r_h)
            rs_cache[q] = v
        return v

    def rs_h(p):
        # on the goal's axis between a pre-goal pose and the goal (within PRE_GOAL_ZONE of it): straight on
        dx, dy = p[0] - goal_p1[0], p[1] - goal_p1[1]
        along, across = cg * dx + sg_ * dy, -sg_ * dx + cg * dy
        if ((-pre_m[0] <= along <= pre_m[1]) and abs(across) <= PRE_GOAL_ZONE[0]
                and abs(float(wrap_angle(p[2] - goal_p1[2]))) <= PRE_GOAL_ZONE[1]):
            return rs_to(p, goal_p1)
        return min(rs_to(p, pre[i]) + pre_m[i] for i in sides)

    def axis_h(p, x):
        # the stop-and-steer primitives' heuristic at trailer poses p (N, 3) of states x (N, 5): how far the
        # trailer's axle is from the target's axis, where the exact join is tried, plus its heading error and
        # the hitch angle as lengths (the trailer's radius r_h and its hitch length), plus how far it is outside
        # the join's range along the axis; at least the grid distance beyond that range
        dx, dy = p[:, 0] - goal_p1[0], p[:, 1] - goal_p1[1]
        along, across = cg * dx + sg_ * dy, -sg_ * dx + cg * dy
        h = (np.abs(across) + r_h * np.abs(wrap_angle(p[:, 2] - goal_p1[2])) + d * np.abs(wrap_angle(x[:, 2] - x[:, 4]))
             + np.maximum(0.0, np.abs(along) - ANALYTIC_RANGE_M))
        return np.maximum(h, grid_h(p) - ANALYTIC_RANGE_M) if use_grid else h

    def heuristic(p, x):
        if steer:
            return float(axis_h(p[None], x[None])[0])
        return max(rs_h(p), float(grid_h(p)) if use_grid else 0.0)

    def steer_keys(p, x) -> list:
        # the stop-and-steer primitives' cells of trailer poses p (N, 3) of states x (N, 5) (no direction)
        return list(zip(np.floor(p[:, 0] / STEER_CELL_M).astype(int).tolist(),
                        np.floor(p[:, 1] / STEER_CELL_M).astype(int).tolist(),
                        (np.floor(wrap_angle(p[:, 2]) / (2 * math.pi) * STEER_HEADING_BINS).astype(int)
                         % STEER_HEADING_BINS).tolist(),
                        np.floor(wrap_angle(x[:, 2] - x[:, 4]) / STEER_HITCH_BIN_RAD).astype(int).tolist()))

    def key(p, x, direction):
        if steer:
            return steer_keys(p[None], x[None])[0]
        return (int(math.floor(p[0] / cell_m)), int(math.floor(p[1] / cell_m)),
                int(math.floor(float(wrap_angle(p[2])) / (2 * math.pi) * HEADING_BINS)) % HEADING_BINS,
                int(math.floor(float(wrap_angle(x[2] - x[4])) / hitch_bin)), direction)

    # nodes: state, last input (v, omega), g, parent, knots of the primitive that reached it (M + 1, 2)
    nodes = [(x_start, np.zeros(2), 0.0, -1, None)]
    # rooted at the goal, the root's primitives leave it at speed (the rig arrives at the goal moving, as
    # the chained-form piece makes it arrive); rooted at the start, the rig starts at rest
    best_g = {key(start_p1, x_start, 0): 0.0}
    weight = STEER_HEURISTIC_WEIGHT if steer else HEURISTIC_WEIGHT
    h0 = heuristic(start_p1, x_start)
    heap = [(weight * h0, 0, 0)]
    counter = 1
    closed = set()
    closest = (h0, 0)
    expansions = analytic_tries = 0
    refusals: dict = {}
    stats = {"primitives": 0, "states_checked": 0, "cut_by_limits": 0, "cut_by_car": 0, "cut_by_trailer": 0,
             "refused_short": 0, "refused_grid": 0, "skipped_closed": 0, "skipped_dearer": 0}
    n_lev = len(levels)
    targets = np.tile(np.repeat(levels, 2), 1)
    dirs = np.tile([1.0, -1.0], n_lev)

    tried: set = set()

    def aimed(p, direction):
        """Is the trailer's axle ANALYTIC_MIN_M to ANALYTIC_RANGE_M from the target's, moving towards it
        (as it last moved), within ANALYTIC_CONE of the target's axis and ANALYTIC_HEADING_RAD of its
        heading, in a cell not tried yet?"""
        dx, dy = p[0] - goal_p1[0], p[1] - goal_p1[1]
        along, across = cg * dx + sg_ * dy, -sg_ * dx + cg * dy
        if not ANALYTIC_MIN_M <= abs(along) <= ANALYTIC_RANGE_M or abs(across) > ANALYTIC_CONE * abs(along):
            return False
        if abs(float(wrap_angle(p[2] - goal_p1[2]))) > ANALYTIC_HEADING_RAD or direction * along > 0:
            return False
        cell = (int(along // ANALYTIC_CELL_M), int(across // ANALYTIC_CELL_M),
                int(round(float(wrap_angle(p[2] - goal_p1[2])) / 0.1)), direction)
        if cell in tried:
            return False
        tried.add(cell)
        return True

    def approach_direction(p) -> float:
        """The direction (+-1) of an approach primitive from trailer axle pose p, 0 for none: p within
        APPROACH_RANGE_M of the target's along its axis, within APPROACH_CONE and APPROACH_HEADING_RAD."""
        dx, dy = p[0] - goal_p1[0], p[1] - goal_p1[1]
        along, across = cg * dx + sg_ * dy, -sg_ * dx + cg * dy
        if not ANALYTIC_MIN_M <= abs(along) <= APPROACH_RANGE_M or abs(across) > APPROACH_CONE * abs(along):
            return 0.0
        if abs(float(wrap_angle(p[2] - goal_p1[2]))) > APPROACH_HEADING_RAD:
            return 0.0
        return -1.0 if along > 0 else 1.0

    def try_piece(x):
        nonlocal analytic_tries
        analytic_tries += 1
        try:
            a, b = (x_goal, x) if from_goal else (x, x_goal)
            piece = steer_trailer(model, a, b, T=None, mode="polynomial")
            if piece.max_speed > speed:
                piece = steer_trailer(model, a, b, T=piece.T * piece.max_speed / speed,
                                      frame=piece.frame["heading"], mode="polynomial")
        except InputError:
            refusals["outside the chained chart"] = refusals.get("outside the chained chart", 0) + 1
            return None
        why = None
        if piece.max_abs_phi > steer_cap + 1e-9:
            why = "steering"
        elif piece.max_abs_hitch > hitch_cap + 1e-9:
            why = "hitch angle"
        elif piece.max_speed > max_speed * 1.001 or piece.max_abs_omega_s > float(model.max_steer_rate) * 1.001:
            why = "inputs"
        elif not bool(bodies.free_many(world, robot, piece.x, piece_margin).all()):
            why = "collision"
        if why is not None:
            refusals[why] = refusals.get(why, 0) + 1
            return None
        return piece

    steer_levels = np.linspace(-steer_cap, steer_cap, STEER_LEVELS)

    def steer_knots(u0, ramp: bool, phi0: float, level: float, v: float, cont: bool) -> np.ndarray:
        """A stop-and-steer primitive's knots from the last input ``u0``: unless it continues the node's
        motion (``cont``), the speed falls to 0 over one interval (``ramp``: the node was moving), the
        steering goes from ``phi0`` to ``level`` at rest within the rate cap (the rate ramps up over one
        interval, holds, ramps down over one), then the rig drives STEER_DRIVE_STEPS intervals at ``v``
        (the first ramping up from rest)."""
        seq = [u0]
        if not cont:
            if ramp:
                seq.append((0.0, 0.0))
            delta = level - phi0
            m = int(math.ceil(abs(delta) / (rate_cap * step_s) - 1e-9))
            if m:
                w = delta / (step_s * m)
                seq += [(0.0, w)] * m + [(0.0, 0.0)]
        seq += [(v, 0.0)] * STEER_DRIVE_STEPS
        return np.array(seq, dtype=float)

    def expand_steer(batch):
        """Every node of ``batch`` with the stop-and-steer primitives: each steering level, forward and
        in reverse. At rest only the steering angle moves (phi' = omega), so it is set exactly; the
        ramp to rest and the drive are integrated (RK4, every state checked)."""
        nonlocal counter
        n2 = 2 * len(steer_levels)
        owner = np.repeat(np.array(batch), n2)
        lev = np.tile(np.repeat(steer_levels, 2), len(batch))
        dr = np.tile([1.0, -1.0], len(batch) * len(steer_levels))
        x0 = np.array([nodes[i][0] for i in owner])
        u0 = np.array([nodes[i][1] for i in owner])
        if from_goal:
            u0[owner == 0] = np.column_stack([speed * dr[owner == 0], np.zeros(int(np.sum(owner == 0)))])
        moving = u0[:, 0] != 0.0
        cont = moving & (np.sign(u0[:, 0]) == dr) & (np.abs(x0[:, 3] - lev) < 1e-9)
        ramp = moving & ~cont
        K = len(owner)
        stats["primitives"] += K
        xr = x0.copy()
        ramp_states = None
        if ramp.any():
            kn = np.stack([u0[ramp], np.zeros((int(ramp.sum()), 2))], axis=1)
            ramp_states = integrate_knots(model, x0[ramp], kn, step_s)
            xr[ramp] = ramp_states[:, -1]
        xr[~cont, 3] = lev[~cont]
        dk = np.zeros((K, STEER_DRIVE_STEPS + 1, 2))
        dk[:, 1:, 0] = (dr * speed)[:, None]
        dk[cont, 0] = u0[cont]
        drive = integrate_knots(model, xr, dk, step_s)
        ends = drive[:, -1]
        p_end = _trailer_poses(d, ends)
        keys = steer_keys(p_end, ends)
        ok = np.array([k not in closed for k in keys])
        stats["skipped_closed"] += int(np.sum(~ok))
        # the limits along the ramp and the drive (the steering levels are within the cap)
        ok &= np.all(np.abs(wrap_angle(drive[..., 2] - drive[..., 4])) <= hitch_cap, axis=1)
        ramp_ok = np.ones(K, dtype=bool)
        if ramp_states is not None:
            ramp_ok[ramp] = np.all(np.abs(wrap_angle(ramp_states[..., 2] - ramp_states[..., 4])) <= hitch_cap, axis=1)
        lim = ok & ramp_ok
        stats["cut_by_limits"] += int(np.sum(ok & ~lim))
        ok = lim
        p_drive = _trailer_poses(d, drive)
        if use_grid:
            reach = np.isfinite(grid_h(p_end))
            stats["refused_grid"] += int(np.sum(ok & ~reach))
            ok &= reach
        # the cost, known before the checks: a motion to a cell already reached as cheaply is not checked
        arc = np.sum(np.hypot(*np.diff(p_drive[..., :2], axis=1).transpose(2, 0, 1)), axis=1)
        if ramp_states is not None:
            pr = _trailer_poses(d, ramp_states)
            arc[ramp] += np.sum(np.hypot(*np.diff(pr[..., :2], axis=1).transpose(2, 0, 1)), axis=1)
        g_par = np.array([nodes[i][2] for i in owner])
        cusp = (u0[:, 0] != 0.0) & (np.sign(u0[:, 0]) != dr)
        gqs = g_par + arc + STEER_CHANGE_COST_M * np.abs(lev - x0[:, 3]) + STEER_CUSP_COST_M * cusp
        for q in np.flatnonzero(ok):
            if best_g.get(keys[q], math.inf) <= gqs[q]:
                ok[q] = False
                stats["skipped_dearer"] += 1
        def check(rows, states):
            # the primitives ``rows`` still kept, at their ``states`` (len(rows), S, 5): car, then trailer
            for body, fp in (("car", car_fp), ("trailer", trailer_fp)):
                sel = np.flatnonzero(ok[rows])
                if not len(sel) or not states.shape[1]:
                    return
                st = states[sel]
                flat = (st[..., :3] if body == "car" else _trailer_poses(d, st)).reshape(-1, 3)
                stats["states_checked"] += len(flat)
                free = world.free_many(flat, fp, margin).reshape(len(sel), -1).all(axis=1)
                stats[f"cut_by_{body}"] += int(np.sum(~free))
                ok[rows[sel[~free]]] = False

        # the drive's end states first (most collisions show there), then the states before them, then the ramps
        every = np.arange(K)
        check(every, drive[:, -1:])
        check(every, drive[:, 1:-1])
        if ramp_states is not None:
            check(np.flatnonzero(ramp), ramp_states[:, 1:])
        hs = np.zeros(K)
        if ok.any():
            hs[ok] = axis_h(p_end[ok], ends[ok])
        for q in np.flatnonzero(ok):
            ni = int(owner[q])
            x, u = nodes[ni][0], u0[q]
            dq = int(dr[q])
            gq = float(gqs[q])
            kq = keys[q]
            if best_g.get(kq, math.inf) <= gq:
                continue
            best_g[kq] = gq
            kn = steer_knots(u, bool(ramp[q]), float(x[3]), float(lev[q]), dq * speed, bool(cont[q]))
            nodes.append((ends[q], kn[-1].copy(), gq, ni, kn))
            heapq.heappush(heap, (gq + weight * float(hs[q]), counter, len(nodes) - 1))
            counter += 1

    found = None
    out_of_time = False
    while heap and found is None and not out_of_time:
        if expansions and clock() - started >= budget_s:
            out_of_time = True
            break
        if expansions >= MAX_EXPANSIONS:
            break
        batch = []
        while heap and len(batch) < BATCH_NODES:
            _, _, ni = heapq.heappop(heap)
            x, u, g, parent, _ = nodes[ni]
            direction = int(np.sign(u[0]))
            p1 = _trailer_poses(d, x)
            k = key(p1, x, direction)
            if k in closed:
                continue
            closed.add(k)
            expansions += 1
            hn = heuristic(p1, x)
            if hn < closest[0]:
                closest = (hn, ni)
            if ni != 0 and clock() - started >= budget_s:
                out_of_time = True
                break
            if ni == 0 or (abs(float(x[3])) <= ANALYTIC_CALM_RAD and abs(float(wrap_angle(x[2] - x[4])))
                           <= ANALYTIC_CALM_RAD and aimed(p1, direction)):
                piece = try_piece(x)
                if piece is not None:
                    found = (ni, piece)
                    break
            batch.append(ni)
        if found is not None or out_of_time or not batch:
            continue
        if steer:
            expand_steer(batch)
            continue
        owner, tg, dr, ap = [], [], [], []
        for i in batch:
            owner += [i] * (2 * n_lev)
            tg.append(targets)
            dr.append(dirs)
            ap += [False] * (2 * n_lev)
            s_ap = approach_direction(_trailer_poses(d, nodes[i][0]))
            if s_ap:
                owner.append(i)
                tg.append([0.0])
                dr.append([s_ap])
                ap.append(True)
        owner = np.array(owner)
        tg, dr, ap = np.concatenate(tg), np.concatenate(dr), np.array(ap)
        x0 = np.array([nodes[i][0] for i in owner])
        u0 = np.array([nodes[i][1] for i in owner])
        if from_goal:
            u0[owner == 0, 0] = speed * dr[owner == 0]
        states, knots = integrate_primitives(model, x0, u0, tg, dr, speed=speed, steer_cap=steer_cap,
                                             rate_cap=rate_cap, step_s=step_s, steps=PRIMITIVE_STEPS,
                                             approach=ap, line=goal_p1, top=top)
        stats["primitives"] += len(states)
        substeps = (states.shape[1] - 1) // (knots.shape[1] - 1)
        # every primitive is kept up to its last knot before the first state that leaves the limits or collides
        # (a shorter primitive of the same law: a knot's command depends on the states before it only), when
        # that is at least MIN_PRIMITIVE_STEPS knots long
        S = states.shape[1]
        idx = np.arange(S)
        limits_ok = ((np.abs(wrap_angle(states[..., 2] - states[..., 4])) <= hitch_cap)
                     & (np.abs(states[..., 3]) <= steer_cap + 1e-9))
        first = np.where(limits_ok.all(axis=1), S, np.argmin(limits_ok, axis=1))
        stats["cut_by_limits"] += int(np.sum(first < S))
        p1s = _trailer_poses(d, states)
        if not cut_primitives:
            # a primitive that ends in a cell already expanded would be dropped: it is not checked
            for q in range(len(states)):
                if first[q] == S and key(p1s[q, -1], states[q, -1], int(dr[q])) in closed:
                    first[q] = 0
                    stats["skipped_closed"] += 1
        # in chunks of knots along the primitives, so that the states past a primitive's first collision are not
        # checked; a primitive shorter than MIN_PRIMITIVE_STEPS after the first chunk is dropped
        lo = 1
        for hi in list(range(MIN_PRIMITIVE_STEPS, PRIMITIVE_STEPS, CHECK_CHUNK_STEPS)) + [PRIMITIVE_STEPS]:
            hi_state = min(hi * substeps, S - 1)
            for body, fp, poses in (("car", car_fp, states[..., :3]), ("trailer", trailer_fp, p1s)):
                need = (idx[None, :] >= lo) & (idx[None, :] <= hi_state) & (idx[None, :] < first[:, None])
                need &= (((first - 1) // substeps >= MIN_PRIMITIVE_STEPS) if cut_primitives else first == S)[:, None]
                if not need.any():
                    continue
                stats["states_checked"] += int(need.sum())
                free = np.ones(need.shape, dtype=bool)
                free[need] = world.free_many(poses[need], fp, margin)
                hit = np.where(free.all(axis=1), S, np.argmin(free, axis=1))
                stats[f"cut_by_{body}"] += int(np.sum(hit < first))
                first = np.minimum(first, hit)
            lo = hi_state + 1
        steps_ok = (first - 1) // substeps
        ends = steps_ok * substeps
        ok = steps_ok >= MIN_PRIMITIVE_STEPS
        if not cut_primitives:
            ok &= steps_ok >= PRIMITIVE_STEPS
        stats["refused_short"] += int(np.sum(~ok))
        rows_ = np.arange(len(states))
        p_end = p1s[rows_, ends]
        if use_grid:
            reach = np.isfinite(grid_h(p_end))
            stats["refused_grid"] += int(np.sum(ok & ~reach))
            ok &= reach
        seg = np.hypot(*np.diff(p1s[..., :2], axis=1).transpose(2, 0, 1))
        cum = np.concatenate([np.zeros((len(states), 1)), np.cumsum(seg, axis=1)], axis=1)
        arc = cum[rows_, ends]
        for q in np.flatnonzero(ok):
            ni = int(owner[q])
            x, u, g = nodes[ni][0], nodes[ni][1], nodes[ni][2]
            direction = int(np.sign(u[0]))
            xe = states[q, ends[q]]
            dq = int(dr[q])
            cost = arc[q] * (REVERSE_FACTOR if dq < 0 else 1.0) + STEER_CHANGE_COST_M * abs(float(xe[3] - x[3]))
            if direction != 0 and dq != direction:
                cost += CUSP_COST_M
            gq = g + cost
            kq = key(p_end[q], xe, dq)
            if kq in closed or best_g.get(kq, math.inf) <= gq:
                continue
            best_g[kq] = gq
            kn = knots[q, :steps_ok[q] + 1]
            nodes.append((xe, kn[-1].copy(), gq, ni, kn))
            heapq.heappush(heap, (gq + weight * heuristic(p_end[q], xe), counter, len(nodes) - 1))
            counter += 1
    elapsed = clock() - started
    info = {"search": "lattice", "budget_s": float(budget_s), "expansions": expansions, "nodes": len(nodes), "analytic_tries": analytic_tries,
            "search_time_s": elapsed, "grid_heuristic": use_grid, "heuristic_radius_m": r_h,
            "hitch_target_max_rad": float(top), "hitch_cap_rad": float(hitch_cap), "steer_cap_rad": float(steer_cap),
            "resolution": resolution, "hitch_levels": len(levels), "cut_primitives": bool(cut_primitives),
            "primitive_kind": primitives,
            "exhausted": bool(found is None and not out_of_time and expansions < MAX_EXPANSIONS), **stats}
    if found is None:
        hn, ni = closest
        xc = nodes[ni][0]
        pc = _trailer_poses(d, xc)
        off = float(np.hypot(*(pc[:2] - goal_p1[:2])))
        dth = abs(float(wrap_angle(pc[2] - goal_p1[2])))
        why = (f"the budget of {budget_s:.3g} s ran out" if out_of_time
               else "the expansion limit was reached" if expansions >= MAX_EXPANSIONS else "every reachable cell was "
               "expanded")
        refused = ", ".join(f"{n} {k}" for k, n in sorted(refusals.items())) or "none tried"
        target = "start" if from_goal else "goal"
        how = (", stop-and-steer primitives" if steer else (", cut primitives" if cut_primitives else "")
               + (", finer lattice" if resolution else ""))
        msg = (f"lattice search ({'from the goal' if from_goal else 'from the start'}{how}, hitch angle within "
               f"{hitch_cap:.3g} rad, steering within {steer_cap:.3g} rad): no plan, {why} after "
               f"{expansions} expansions in {elapsed:.2f} s; closest node: the trailer's axle {off:.2f} m from the "
               f"{target}'s, heading off by {dth:.2f} rad, heuristic {hn:.2f} m; "
               f"final pieces refused: {refused}")
        info.update({"closest_m": off, "closest_heading_rad": dth, "closest_state": xc})
        return LatticeResult(False, msg, step_s, np.zeros((1, 2)), x_start[None], None, info, from_goal)
    ni, piece = found
    chain = []
    while ni > 0:
        chain.append(ni)
        ni = nodes[ni][3]
    chain.reverse()
    first = np.zeros((1, 2))
    if from_goal and chain:
        first[0, 0] = nodes[chain[0]][4][0, 0]
    knots = np.vstack([first] + [nodes[i][4][1:] for i in chain])
    states = np.array([x_start] + [nodes[i][0] for i in chain])
    if from_goal:
        # the motion reversed in time: a driftless system's states run backwards under the negated inputs
        knots, states = -knots[::-1], states[::-1]
    info.update({"primitives_used": len(chain), "node_cost_m": nodes[chain[-1]][2] if chain else 0.0,
                 "rooted_at": "goal" if from_goal else "start"})
    return LatticeResult(True, f"lattice search: plan found after {expansions} expansions in {elapsed:.2f} s",
                         step_s, knots, states, piece, info, from_goal)
