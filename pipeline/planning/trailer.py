"""Planning a car with one trailer: a Reeds-Shepp path of the trailer's axle, searched with the whole
rig checked, then an exactly feasible motion of the rig along it: the model driven by a tracking law
and integrated, ending in one chained-form piece that meets the goal exactly (Tilbury, Laumond,
Murray, Sastry, Walsh 1992 for the chained form; Laumond, Jacobs, Taix, Murray 1994 for following a
geometric path).

The path
--------
The trailer's axle point is a flat output of the car with a trailer (:mod:`nhstab.planning.
trailer_charts`): the trailer moves like a car of wheelbase d "steered" by the hitch angle
D = theta - theta1, with curvature tan(D) / d. So the geometric search plans the *trailer's* path: a
Reeds-Shepp path at the planning turning radius R1 (:func:`~nhstab.planning.geometric.plan_path`, the
machinery every robot uses: the direct connection, the guided subgoals, OMPL's RRTConnect in the gaps;
only exact solutions count). Along it the hitch angle of steady motion is fixed by each segment's
turn, D = atan(d / R1) on a left arc, -atan(d / R1) on a right arc, 0 on a straight, forward and in
reverse alike, so the whole rig's place is known at every sample: the car's rear axle d ahead of the
trailer's along theta1, its heading theta1 + D. :class:`TrailerRig` checks every local path with both
bodies placed so (margin plus ``MARGIN_PAD``), and OMPL validates its motions with that check (a
Python motion validator). Cusps and reversing are Reeds-Shepp's own; the goal's trailer heading is
the goal pose of the trailer's path. Three constraints shape the path for the rig: every run between
cusps of a local path is at least ``MIN_RUN_HITCHES`` hitch lengths long (after a reversal the hitch
angle needs room to settle); the path leaves the start along a straight (``START_RUN_HITCHES``) and
arrives at the goal along a straight (``GOAL_RUN_HITCHES``, else the shorter one), with no cusp where
those straights join (:func:`_search`: the rig starts and ends straight); R1 is five times the
trailer's smallest steady turn (the robot's rule), where the steady steering angle is 0.23 rad.

The motion
----------
A Reeds-Shepp path's curvature jumps, and the hitch angle, which sets the trailer's curvature, is a
state that changes only gradually (D' = v (tan(phi)/L - sin(D)/d), |phi| limited). So the rig is
*driven* along the path, run by run (:class:`_Tracker`): a flat-output tracking law asks for the
trailer's curvature (the path's, a little ahead, corrected by the lateral and heading errors), i.e. a
hitch angle D*, steers so that D follows it (tan(phi) = L (sin(D)/d - k s (D - D*)), s the direction:
in reverse the car steers the trailer back, within the hitch angles it can still straighten,
asin(d tan(phi_max) / L)), and moves phi at a bounded rate; the model (RK4, 8 steps per control
period, inputs a first-order hold of the law's commands) is integrated, so the motion is exactly a
motion of the model. On the last run a chained-form polynomial piece
(:func:`~nhstab.planning.steering.steer_chained_polynomial` through
:func:`~nhstab.planning.trailer_charts.steer_trailer`) joins the calmest tracked state (smallest
steering and hitch angles) between 3 and 40 m before the goal to the goal state exactly, within the
limits (steering within ``STEER_FRACTION``, hitch within ``JACKKNIFE_FRACTION`` of the jackknife
limit) and clear of the obstacles. A path whose motion fails (no feasible final piece, the nominal
not clear) is replaced by another one (OMPL over the map with the next seed), ``NOMINAL_ATTEMPTS``
at most. The nominal carries a *tail* (:attr:`~nhstab.nominal.Nominal.tail`: the rig driving on past
the goal) so that the gramian law's future windows are whole up to the goal: the frozen end strategy
carries the last whole window along the linearised flow, which in reverse is unstable, and the gains
faded exactly where the trailer backs into the dock (tests/planning/test_trailer_planning.py).

Where the paths fail
--------------------
Where no Reeds-Shepp path of the trailer at R1 leads to a usable nominal (aisles and dock bays that a
circle of R1 does not fit), the lattice search over the whole rig (:mod:`nhstab.planning.
trailer_search`: Hybrid A* with primitives integrated from the model, rooted at the tighter of start
and goal, joined to the other with the chained-form piece) plans, and :func:`lattice_nominal` makes
its plan the same kind of nominal (the primitives' inputs integrated again with the tracker's RK4,
the piece, the tail). At each root the search runs on the rungs of ``LATTICE_RUNGS``: the plan's
lattice at the plan's caps; where it expands every cell it reaches, the same with primitives cut at
their first collision; where that exhausts too, the stop-and-steer primitives (the rig stops, steers,
drives a few tenths of a metre) with the hitch angle within ``TIGHT_JACKKNIFE_FRACTION`` of the
jackknife limit and the steering (and its rate) within ``TIGHT_STEER_FRACTION`` of its limits; where
that exhausts too, the finer lattice at those caps: the rig turns as tight as the space needs, and the
feedback keeps less room there. The nominal keeps the caps its plan was found at.

Budget
------
The two phases share the time limit T, counted from the start of the call. :func:`tight_space`
decides the order: when the largest free disc centred within R1 of the start's or the goal's
trailer axle has a radius below ``TIGHT_DISC_FRACTION`` R1, the lattice search runs first with all
of T and the Reeds-Shepp paths get what it leaves; otherwise the Reeds-Shepp paths run first with
``REEDS_SHEPP_SHARE`` T (every attempt within what is left of it) and the lattice search gets the
rest. No phase starts with less than ``MIN_PHASE_SHARE`` T left. Within the lattice search the first
root gets ``LATTICE_FIRST_SHARE`` of its budget, except that its stop-and-steer rung may run until
``STEER_RUNG_SHARE`` of it has passed (:func:`lattice_plan`), and the other root the rest. Outside the budget: making a path
found in time into a nominal, its clearance check and the gain schedule. The metrics record the
order and each phase's budget (``search_budget_s``).

Alternatives considered, and what they did on the loading dock
---------------------------------------------------------------
* A search whose local planner is the polynomial steering between poses where the rig stands straight
  (exact, nothing approximated after the search): between two such poses an 8 m piece along an arc
  keeps within 0.9 of the steering limit only from a radius of about 14 m on
  (tests/planning/test_trailer_planning.py), so OMPL found almost no feasible motions.
* Steering pieces between *calm* waypoints of the Reeds-Shepp path (the path's steady states, as the
  cars' planner joins its waypoints): a straight rig cannot enter an arc at once, and the pieces that
  must change the hitch angle across a curvature jump needed steering angles of 0.8-1.3 rad.
* Driving each reverse run backwards in time (forward motion is stable, and its time reversal is an
  exact motion): a Reeds-Shepp cusp joins arcs of opposite turn, so the runs on its two sides meet
  the cusp with opposite hitch angles and poses up to 2 m apart, and no piece joined them.
* A control-based OMPL planner on the model (``ompl.control``) reaches the goal only within a region
  and propagates the model in Python at every step; a Reeds-Shepp search for the *car* with the
  trailer integrated behind it jackknifes in reverse.
What remains hard is the reversal itself: at a Reeds-Shepp cusp the hitch angle must swing from one
arc's to the other's while reversing, and the tracked motion leaves the path there by up to a metre
(the search's pad and the final check cover it). N >= 2 trailers are modelled, simulated and checked,
but not planned: the chained chart here is the one-trailer one.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from .. import bodies
from ..collision import CollisionWorld
from ..control import StabilizerOptions, compute_schedule
from ..errors import InputError, PipelineError, SingularGramianError
from ..geometry import wrap_angle
from ..limits import nominal_grid
from ..maps.base import Map, MapError
from ..nominal import Nominal
from . import local_paths
from .cars import direction_reversals
from .geometric import GeometricPath, PathOptions, densify, path_directions, plan_path
from .guide import passage
from .result import PlanResult, schedule_metrics
from .timing import TimingOptions
from .trailer_charts import steer_trailer
from .trailer_search import PRIMITIVE_STEP_S, LatticeResult, lattice_search

#: plans keep every hitch angle within this fraction of the jackknife limit (room for the feedback)
JACKKNIFE_FRACTION = 0.8
#: and the steering angle within this fraction of its limit
STEER_FRACTION = 0.9
#: where the lattice search at those fractions expands every cell it reaches (a dock bay off a narrow aisle), its
#: finer lattice plans within these fractions of the jackknife limit and of the steering and steering-rate limits
#: (the space needs the rig's tighter turns; the feedback has less room)
TIGHT_JACKKNIFE_FRACTION = 0.95
TIGHT_STEER_FRACTION = 1.0
#: the lattice search's rungs at each root: (resolution, primitives cut at their first collision, hitch angle and
#: steering fractions, primitives); a rung runs only where the one before it expanded every cell it reached
LATTICE_RUNGS = ((0, False, JACKKNIFE_FRACTION, STEER_FRACTION, "hitch"),
                 (0, True, JACKKNIFE_FRACTION, STEER_FRACTION, "hitch"),
                 (0, False, TIGHT_JACKKNIFE_FRACTION, TIGHT_STEER_FRACTION, "steer"),
                 (1, True, TIGHT_JACKKNIFE_FRACTION, TIGHT_STEER_FRACTION, "hitch"))
#: the geometric search keeps this much more than the margin: the tracked motion leaves the path where
#: its curvature jumps (the hitch angle follows gradually)
MARGIN_PAD = 0.3
#: the path leaves the start along a straight this many hitch lengths long (forward or in reverse)
START_RUN_HITCHES = 1.25
#: the tracking law's gains: lateral error [1/m^2], heading error [1/m], hitch angle [1/m], steering
#: angle [1/s] (module docstring)
TRACK_GAINS = (0.15, 0.8, 3.0, 8.0)
#: the tracking law asks for hitch angles within this fraction of the largest one the car can still
#: straighten in reverse, asin(d tan(phi_max) / L)
RECOVERABLE_FRACTION = 0.6
#: the tracking law's curvature feedforward looks this many hitch lengths ahead along the path
PREVIEW_HITCHES = 0.3
#: a run between two cusps of a local path is at least this many hitch lengths long
MIN_RUN_HITCHES = 2.0
#: the path arrives at the goal along a straight this many hitch lengths long where there is room (the
#: tracked motion settles on it before the final piece), else along the shorter run-up
GOAL_RUN_HITCHES = 3.0
#: the straight-ends combinations are ordered by Reeds-Shepp length plus this much per cusp [m]
CUSP_COST_M = 10.0
#: a path whose nominal fails is replaced by another one (OMPL over the map, the next seed), at most this
#: many paths and while the Reeds-Shepp phase's budget lasts
NOMINAL_ATTEMPTS = 4
#: the two search phases share the time limit: the trailer's Reeds-Shepp paths get this share of it when they
#: run first, the lattice search everything left (module docstring, "Budget")
REEDS_SHEPP_SHARE = 0.4
#: a phase is not started with less than this share of the time limit left
MIN_PHASE_SHARE = 0.05
#: the space is tight for the Reeds-Shepp radius R1 (the lattice search runs first) when the largest free
#: disc centred within R1 of the start's or the goal's trailer axle has a radius below this fraction of R1
TIGHT_DISC_FRACTION = 0.5
#: the free discs of that test are centred on a grid of this spacing [m]
TIGHT_GRID_M = 0.25
#: the lattice search (nhstab.planning.trailer_search) keeps this much more than the margin (where the start
#: and goal allow it), and drives at this fraction of the speed limit
LATTICE_MARGIN_PAD = 0.005
LATTICE_SPEED_FRACTION = 0.6
#: the lattice search rooted at the tighter end gets this share of its budget, the other end the rest
LATTICE_FIRST_SHARE = 0.6
#: except that its stop-and-steer rung, which runs only where the rungs before it found that end enclosed (they
#: expanded every cell they reached), may run until this share of the budget has passed: a search from the
#: other end would have to find its way into that enclosure
STEER_RUNG_SHARE = 0.9
#: the nominal's tail (the motion continued past the goal for the gain schedule's windows) [s]
TAIL_S = 20.0
#: the final piece starts between the first and last of these distances from the goal (trailer's axle) [m]
FINAL_PIECE_M = (3.0, 4.5, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 25.0, 30.0, 40.0)
#: the final piece is tried from at most this many starts (the calmest in each band of FINAL_PIECE_M)
FINAL_TRIES = 10


class TrailerPlanningError(PipelineError):
    """The steering pieces could not follow the trailer's path feasibly, even lengthened or split."""


def trailer_pose(model, config) -> np.ndarray:
    """The trailer's axle pose (x1, y1, theta1) of a configuration (x, y, theta, theta1) or a state."""
    d = float(model.hitch_lengths[0])
    config = np.asarray(config, dtype=float)
    th1 = float(config[-1])
    return np.array([float(config[0]) - d * math.cos(th1), float(config[1]) - d * math.sin(th1), th1])


def _turn_signs(segments, fractions) -> np.ndarray:
    """+1 on a left turn, -1 on a right turn, 0 on a straight at the given fractions of a Reeds-Shepp
    path's length (a sample on a boundary belongs to the later segment, as in local_paths.sample). A
    towed body turns the same way forward and in reverse, so this fixes the steady hitch angle."""
    f = np.clip(np.asarray(fractions, dtype=float), 0.0, 1.0)
    lengths = np.array([abs(v) for _, v in segments])
    total = float(lengths.sum())
    if total <= 0.0:
        return np.zeros(len(f))
    signs = np.array([{"L": 1.0, "R": -1.0}.get(kind, 0.0) for kind, _ in segments])
    return signs[np.minimum(np.searchsorted(np.cumsum(lengths), f * total, side="right"), len(segments) - 1)]


def _runs(segments, radius: float) -> list[float]:
    """Lengths [m] of the runs of one direction of travel of a Reeds-Shepp path (zero-length segments
    dropped)."""
    runs: list[list] = []
    for _, v in segments:
        if abs(v) * radius < 1e-9:
            continue
        sign = v > 0
        if runs and runs[-1][0] == sign:
            runs[-1][1] += abs(v) * radius
        else:
            runs.append([sign, abs(v) * radius])
    return [r[1] for r in runs]


def _short_run(segments, radius: float, min_run: float) -> bool:
    """Has the path a cusp next to a run shorter than ``min_run``? (A path of one run has no cusp; a
    path's first and last runs count too, since the next local path may reverse again at the join.)"""
    runs = _runs(segments, radius)
    return len(runs) > 1 and any(r < min_run for r in runs)


def _cusp_count(segments, radius: float) -> int:
    return max(0, len(_runs(segments, radius)) - 1)


class TrailerRig:
    """The checks of the geometric search for a car with one trailer, planned by the trailer's axle
    pose (``rig`` of :func:`~nhstab.planning.geometric.plan_path`; module docstring)."""

    def __init__(self, world: CollisionWorld, robot, margin: float, opts: PathOptions):
        self.world, self.robot, self.margin, self.opts = world, robot, float(margin), opts
        self.car_fp, self.trailer_fp = robot.footprints
        self.d = float(robot.model.hitch_lengths[0])
        self.radius = float(opts.turning_radius)
        self.hitch_on_arcs = math.atan(self.d / self.radius)
        self._trailer = world.state_checker(self.trailer_fp, margin)
        self.bounding_radius = max(self.trailer_fp.bounding_radius, self.d + self.car_fp.bounding_radius)
        #: the poses where straight ends join the searched path, and the directions they are driven in
        self.depart, self.depart_dir, self.arrive, self.arrive_dir = None, 1.0, None, 1.0

    def pose_free(self, x: float, y: float, th: float) -> bool:
        """The trailer's body at its axle pose (x, y, th): a necessary condition for the rig (the car's
        place depends on how the path turns there)."""
        return self._trailer(x, y, th)

    def car_poses(self, poses: np.ndarray, turns: np.ndarray) -> np.ndarray:
        """The car's rear-axle poses with the trailer's axle at ``poses`` on segments turning ``turns``."""
        th = poses[:, 2]
        return np.column_stack([poses[:, 0] + self.d * np.cos(th), poses[:, 1] + self.d * np.sin(th),
                                th + np.asarray(turns) * self.hitch_on_arcs])

    def connect(self, a, b, stats: dict | None = None) -> bool:
        """Is the trailer's Reeds-Shepp path from pose a to b free for both bodies (sampled every
        ``resolution`` m), and, if it reverses, every run at least ``MIN_RUN_HITCHES`` hitch lengths
        long (the rig needs room to settle its hitch angle after each reversal)?"""
        seg = local_paths.reeds_shepp(a, b, self.radius)
        if _short_run(seg, self.radius, MIN_RUN_HITCHES * self.d):
            return False
        # no cusp where a straight end joins (see _search)
        moving = [v for _, v in seg if abs(v) * self.radius > 1e-9]
        for end, want, first in ((self.depart, self.depart_dir, True), (self.arrive, self.arrive_dir, False)):
            if end is not None and moving and np.allclose(a if first else b, end, atol=1e-9):
                if (moving[0] if first else moving[-1]) * want < 0:
                    return False
        n = max(1, int(math.ceil(local_paths.path_length(seg, self.radius) / self.opts.resolution)))
        fractions = np.arange(1, n + 1) / n
        poses = local_paths.sample(a, seg, self.radius, fractions)
        return (self.world.motion_free(poses, self.trailer_fp, self.margin, stats)
                and self.world.motion_free(self.car_poses(poses, _turn_signs(seg, fractions)), self.car_fp,
                                           self.margin, stats))

    def densify(self, waypoints):
        samples, sigma, length = densify(self.opts, waypoints, step=min(0.005, self.opts.resolution / 2))
        direction, _ = path_directions(samples)
        return samples, sigma, direction, length


def _search(world: CollisionWorld, robot, rig: TrailerRig, opts: PathOptions, x_start, x_goal,
            run: float) -> GeometricPath:
    """The trailer's path from start to goal, with straight ends: the rig starts and ends straight, and
    its hitch angle needs about ``2 run`` of path to settle on an arc, so the search joins a pose ``run``
    ahead of or behind the start (forward or reverse run-up) to one ``GOAL_RUN_HITCHES`` hitch lengths
    (else ``run``) before or beyond the goal (arriving forward or in reverse; the tracked motion settles
    on that straight before the final piece). The combinations are tried in order of their
    Reeds-Shepp length plus ``CUSP_COST_M`` per cusp (and once more for the short arrival) while the
    budget lasts, each with at least half of it, and then the path from the start to the goal itself."""
    model = robot.model
    ps, pg = trailer_pose(model, x_start), trailer_pose(model, x_goal)
    R = float(opts.turning_radius)

    def moved(p, dist):
        return np.array([p[0] + dist * math.cos(p[2]), p[1] + dist * math.sin(p[2]), p[2]])

    combos = []
    for ds in (run, -run):
        for dg in (GOAL_RUN_HITCHES * float(model.hitch_lengths[0]), run):
            for sign in (1.0, -1.0):
                s1, g1 = moved(ps, ds), moved(pg, sign * dg)
                seg = [("S", ds / R), *local_paths.reeds_shepp(s1, g1, R), ("S", -sign * dg / R)]
                cost = local_paths.path_length(seg, R) + CUSP_COST_M * _cusp_count(seg, R) + (CUSP_COST_M if dg == run
                                                                                               else 0.0)
                combos.append((cost, s1, g1))
    combos.sort(key=lambda c: c[0])
    started = time.perf_counter()
    budget = float(opts.time_limit_s)
    last = None
    for k, (_, s1, g1) in enumerate(combos):
        left = budget - (time.perf_counter() - started)
        if left <= 0.05 * budget:
            break
        rig.depart = rig.arrive = None
        if not (rig.pose_free(*s1) and rig.pose_free(*g1) and rig.connect(ps, s1) and rig.connect(g1, pg)):
            continue
        rig.depart, rig.depart_dir = s1, math.copysign(1.0, float(np.dot(s1[:2] - ps[:2], [math.cos(ps[2]), math.sin(ps[2])])))
        rig.arrive, rig.arrive_dir = g1, math.copysign(1.0, float(np.dot(pg[:2] - g1[:2], [math.cos(pg[2]), math.sin(pg[2])])))
        path = plan_path(world, rig.trailer_fp, s1, g1, replace(opts, time_limit_s=min(left, max(0.5 * budget, left / 2))
                                                                if k < len(combos) - 1 else left), rig=rig)
        last = path
        if path.status == "exact":
            waypoints = np.vstack([ps, path.waypoints, pg])
            samples, sigma, direction, length = rig.densify(waypoints)
            cusps = int(np.sum(direction[1:] != direction[:-1]))
            info = {**path.info, "start_straight_m": run, "goal_straight_m": float(np.hypot(*(g1[:2] - pg[:2])))}
            return replace(path, waypoints=waypoints, samples=samples, sigma=sigma, direction=direction,
                           length=length, cusps=cusps, planning_time_s=time.perf_counter() - started, info=info)
    rig.depart = rig.arrive = None
    left = budget - (time.perf_counter() - started)
    if left > 0.05 * budget or last is None:
        path = plan_path(world, rig.trailer_fp, ps, pg, replace(opts, time_limit_s=max(left, 1e-3)), rig=rig)
        return replace(path, planning_time_s=time.perf_counter() - started)
    return replace(last, planning_time_s=time.perf_counter() - started)


def lattice_plan(world: CollisionWorld, robot, path_opts: PathOptions, timing: TimingOptions, x_start, x_goal,
                 clearances: dict, budget: float, check_resolution: float = 0.05, started: float | None = None):
    """The lattice search (:mod:`nhstab.planning.trailer_search`) between full states ``x_start`` and
    ``x_goal`` for ``budget`` seconds, and its nominal checked at ``check_resolution``: (status,
    message, path, nominal, metrics) with status "ok", "no_path", "infeasible" or "not_clear".
    ``clearances``: the start's and goal's ({"start": ..., "goal": ...}, :func:`check_configuration`);
    ``started``: the clock reading the metrics' planning time counts from (default: now)."""
    started = time.perf_counter() if started is None else started
    model = robot.model
    margin = float(path_opts.margin)
    search_margin = max(margin, min(margin + LATTICE_MARGIN_PAD, min(clearances.values()) - 1e-3))
    max_speed = timing.max_speed or float(model.input_limits()[0, 1])
    speed = LATTICE_SPEED_FRACTION * max_speed
    step_s = float(timing.dt) * max(1, int(round(PRIMITIVE_STEP_S / float(timing.dt))))
    # rooted first at the tighter end (the smaller clearance): the primitives work their way out of it,
    # and the chained-form piece joins the roomier end; then at the other end with what is left
    order = (True, False) if clearances["goal"] < clearances["start"] else (False, True)
    began = time.perf_counter()
    messages, given, runs = [], [], []
    enclosed = None
    jk, mx, rate = float(model.jackknife_limit), float(model.max_steer), float(model.max_steer_rate)
    for k, from_goal in enumerate(order):
        left = budget - (time.perf_counter() - began)
        if k > 0 and left <= 0.0:
            break
        root_budget = LATTICE_FIRST_SHARE * budget if k == 0 else left
        root_began = time.perf_counter()
        # the rungs of LATTICE_RUNGS in turn, each with what is left of this root's share, the next one only where
        # the last expanded every cell it reached (the space needs more)
        for rung, (resolution, cut, hitch_f, steer_f, prims) in enumerate(LATTICE_RUNGS):
            limit = max(root_budget, STEER_RUNG_SHARE * budget) if k == 0 and prims == "steer" else root_budget
            give = limit - (time.perf_counter() - root_began) if rung else limit
            if give <= 0.0:
                break
            given.append(give)
            runs.append(("goal" if from_goal else "start", rung))
            found = lattice_search(world, robot, x_start, x_goal, margin=search_margin, speed=speed, step_s=step_s,
                                   hitch_cap=hitch_f * jk, steer_cap=steer_f * mx, rate_cap=steer_f * rate,
                                   max_speed=max_speed, budget_s=give, piece_margin=max(margin, search_margin - 1e-3),
                                   from_goal=from_goal, resolution=resolution, cut_primitives=cut,
                                   primitives=prims)
            messages.append(found.message)
            if prims == "steer" and found.info["exhausted"] and enclosed is None:
                enclosed = {"end": "goal" if from_goal else "start", "expansions": int(found.info["expansions"]),
                            "margin_m": float(search_margin)}
            if found.found or not found.info["exhausted"]:
                break
        if found.found:
            break
    if not found.found:
        found.message = "; ".join(messages)
    metrics = {"planner": path_opts.planner, "planner_used": "lattice", "planner_status": found.message,
               "planning_time_s": time.perf_counter() - started, "start_clearance_m": clearances["start"],
               "goal_clearance_m": clearances["goal"], "planned_body": "the whole rig (lattice search)",
               "search_margin_m": search_margin, "lattice_budgets_s": given,
               "lattice_runs": [f"{root} {rung}" for root, rung in runs], "lattice_enclosed": enclosed,
               **{f"lattice_{k}": v for k, v in found.info.items()
                                                      if not isinstance(v, np.ndarray)}}
    empty = GeometricPath("failed", found.message, np.array([trailer_pose(model, x_start)]),
                          np.array([trailer_pose(model, x_start)]), np.zeros(1), np.zeros(0), 0.0, 0,
                          found.info["search_time_s"], found.info.get("states_checked", 0), 0.0, path_opts,
                          {"planner_used": "lattice"})
    if not found.found:
        return "no_path", f"no collision-free path found: {found.message}", empty, None, metrics
    try:
        nominal, tinfo = lattice_nominal(robot, found, timing, world, margin, x_start, x_goal, speed)
    except TrailerPlanningError as exc:
        return ("infeasible", f"the lattice plan could not be made an exact nominal: {exc}", empty, None, metrics)
    samples = robot.body_poses(nominal.x)[:, 1]
    samples[:, 2] = np.unwrap(samples[:, 2])
    sigma = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(samples[:, :2], axis=0).T))])
    direction, cusps = path_directions(samples)
    waypoints = np.vstack([robot.body_poses(found.states)[:, 1], trailer_pose(model, x_goal)])
    path = GeometricPath("exact", found.message, waypoints, samples, sigma, direction, float(sigma[-1]), cusps,
                         found.info["search_time_s"], found.info.get("states_checked", 0), 0.0, path_opts,
                         {"planner_used": "lattice"})
    check = bodies.check_path(world, robot, nominal.x, margin=margin, resolution=check_resolution)
    metrics.update({
        "length_m": path.length, "cusps": cusps, "max_curvature_per_m": math.tan(found.info["hitch_cap_rad"])
        / float(model.hitch_lengths[0]), "waypoints": len(waypoints), **tinfo,
        "min_clearance_m": check.min_clearance, "min_clearance_pose": check.min_clearance_pose,
        "min_clearance_body": ("car", "trailer 1")[check.min_clearance_body],
        "clearance_check_resolution_m": check_resolution, "clearance_samples": check.samples,
        "max_abs_inputs": np.max(np.abs(nominal.u), axis=0), "input_limits": model.input_limits()[:, 1],
    })
    if not check.clear:
        return ("not_clear", f"the lattice nominal comes within {check.min_clearance:.3g} m of an obstacle (margin "
                f"{margin:g} m) with its {('car', 'trailer')[check.min_clearance_body]} at "
                f"{np.round(check.min_clearance_pose, 3).tolist()}", path, nominal, metrics)
    return "ok", "", path, nominal, metrics


def check_configuration(m: Map, robot, config, name: str, world: CollisionWorld) -> float:
    """A start or goal configuration of a car_trailer: the hitch angle within the jackknife limit, every
    body inside the map's bounds and clear of the obstacles; returns the smallest clearance over the
    bodies. Raises :class:`InputError` / :class:`MapError` naming ``name``."""
    model = robot.model
    hitch = float(wrap_angle(config[2] - config[3]))
    if abs(hitch) > model.jackknife_limit:
        raise InputError(name, f"a hitch angle |theta - theta1| within the jackknife limit "
                         f"{model.jackknife_limit:g} rad", np.round(config, 4).tolist(),
                         detail=f"|theta - theta1| = {abs(hitch):.3f} rad")
    x = np.array([config[0], config[1], config[2], 0.0, config[3]])
    names = ("car", "trailer")
    out = math.inf
    for b, (pose, fp) in enumerate(zip(robot.body_poses(x), robot.footprints)):
        where = m.source or m.name
        if not m.contains(pose[0], pose[1]):
            raise MapError(name, f"a configuration whose {names[b]} lies inside the bounds {list(m.bounds)} of {where}",
                           np.round(config, 4).tolist(), detail=f"the {names[b]} at {np.round(pose, 4).tolist()}")
        c = world.clearance(pose, fp)
        if c < 0:
            raise MapError(name, f"a configuration where the {names[b]}'s footprint is free of the obstacles of "
                           f"{where}", np.round(config, 4).tolist(),
                           detail=f"the {names[b]} at {np.round(pose, 4).tolist()} overlaps an obstacle by {-c:.3g} m")
        out = min(out, c)
    return out


# ---------------------------------------------------------------------------------------------
# the nominal along the trailer's path
# ---------------------------------------------------------------------------------------------
def _cusps(direction: np.ndarray, sigma: np.ndarray, min_run: float) -> list[int]:
    """Sample indices of the path's cusps, without those that bound a run shorter than ``min_run``
    (a run at an end loses its inner cusp, a run in between both of its cusps)."""
    n = len(sigma)
    cusps = [int(i) for i in np.flatnonzero(direction[1:] != direction[:-1]) + 1]
    while True:
        ends = [0, *cusps, n - 1]
        short = [k for k in range(len(ends) - 1) if sigma[ends[k + 1]] - sigma[ends[k]] < min_run]
        if not short or not cusps:
            return cusps
        k = short[0]
        drop = {ends[k], ends[k + 1]} - {0, n - 1}
        cusps = [c for c in cusps if c not in drop]


class _Tracker:
    """The rig driven along the trailer's path by a flat-output tracking law (module docstring), its
    inputs a first-order hold of the law's commands one control period late, integrated with RK4."""

    def __init__(self, robot, timing: TimingOptions, speed: float, substeps: int = 8):
        m = robot.model
        self.robot, self.model = robot, m
        self.L, self.d = float(m.wheelbase), float(m.hitch_lengths[0])
        self.dt, self.speed, self.substeps = float(timing.dt), float(speed), int(substeps)
        self.steer_cap = STEER_FRACTION * float(m.max_steer)
        self.rate_cap = STEER_FRACTION * float(m.max_steer_rate)
        # the hitch angle the car can still straighten in reverse: sin(D) / d < tan(phi) / L
        recoverable = math.asin(min(1.0, self.d * math.tan(self.steer_cap) / self.L))
        self.hitch_cap = min(JACKKNIFE_FRACTION * float(m.jackknife_limit), RECOVERABLE_FRACTION * recoverable)
        self.steps_per_m = 1.0 / max(self.speed * self.dt, 1e-9)

    def _command(self, x, ref, kappa_ref: float, direction: float) -> np.ndarray:
        """The law at state x about path pose ``ref`` with curvature ``kappa_ref`` (heading-forward)."""
        d, L = self.d, self.L
        th1 = float(x[4])
        x1, y1 = float(x[0]) - d * math.cos(th1), float(x[1]) - d * math.sin(th1)
        c, s = math.cos(ref[2]), math.sin(ref[2])
        e_y = -s * (x1 - ref[0]) + c * (y1 - ref[1])
        e_th = float(wrap_angle(th1 - ref[2]))
        kappa = kappa_ref - TRACK_GAINS[0] * e_y - TRACK_GAINS[1] * direction * math.sin(e_th)
        D_des = max(-self.hitch_cap, min(self.hitch_cap, math.atan(d * kappa)))
        D = float(wrap_angle(x[2] - th1))
        tan_phi = L * (math.sin(D) / d - TRACK_GAINS[2] * direction * (D - D_des))
        phi_des = max(-self.steer_cap, min(self.steer_cap, math.atan(tan_phi)))
        omega = max(-self.rate_cap, min(self.rate_cap, TRACK_GAINS[3] * (phi_des - float(x[3]))))
        return np.array([direction * self.speed, omega])

    def step(self, x, u0, u1) -> np.ndarray:
        """x one control period later under u linear from u0 to u1 (RK4, ``substeps`` steps; the model's
        right-hand side written out on Python floats, the same as ``CarTrailer.rhs`` for one trailer)."""
        L, d = self.L, self.d
        cos, sin, tan = math.cos, math.sin, math.tan

        def f(px, py, th, phi, th1, v, w):
            dl = th - th1
            return cos(th) * v, sin(th) * v, tan(phi) / L * v, w, v * sin(dl) / d

        h = self.dt / self.substeps
        s = [float(v) for v in x]
        v0, w0, dv, dw = float(u0[0]), float(u0[1]), float(u1[0] - u0[0]), float(u1[1] - u0[1])
        for k in range(self.substeps):
            a, b, c = k / self.substeps, (k + 0.5) / self.substeps, (k + 1) / self.substeps
            k1 = f(*s, v0 + a * dv, w0 + a * dw)
            k2 = f(*(si + 0.5 * h * ki for si, ki in zip(s, k1)), v0 + b * dv, w0 + b * dw)
            k3 = f(*(si + 0.5 * h * ki for si, ki in zip(s, k2)), v0 + b * dv, w0 + b * dw)
            k4 = f(*(si + h * ki for si, ki in zip(s, k3)), v0 + c * dv, w0 + c * dw)
            s = [si + (h / 6.0) * (p + 2.0 * q + 2.0 * r + t) for si, p, q, r, t in zip(s, k1, k2, k3, k4)]
        return np.array(s)

    def run(self, x, u, samples, sigma, kappa, i0: int, i1: int, direction: float, stop_before: float = 0.0):
        """Drive along samples i0 .. i1 (one run) from state x with the last input u, until the trailer's
        projection on the path is within ``stop_before`` of sample i1. Returns the states and inputs of
        every control sample after the first (lists), and the final state and input."""
        xs, us = [], []
        j = i0
        end_sigma = sigma[i1] - stop_before
        limit = int(4 * (sigma[i1] - sigma[i0] + 5.0) * self.steps_per_m) + 50
        d = self.d
        sx, sy = samples[:, 0].tolist(), samples[:, 1].tolist()
        for _ in range(limit):
            th1 = float(x[4])
            p = (float(x[0]) - d * math.cos(th1), float(x[1]) - d * math.sin(th1))
            # the projection: walk ahead while the samples come nearer (monotone along the run)
            best = (sx[j] - p[0]) ** 2 + (sy[j] - p[1]) ** 2
            while j < i1:
                nxt = (sx[j + 1] - p[0]) ** 2 + (sy[j + 1] - p[1]) ** 2
                if nxt > best:
                    break
                j, best = j + 1, nxt
            ref = samples[j]
            along = direction * ((p[0] - ref[0]) * math.cos(ref[2]) + (p[1] - ref[1]) * math.sin(ref[2]))
            if sigma[j] + along >= end_sigma - 1e-9 or j >= i1:
                break
            # the curvature a little ahead: the hitch angle needs that long to follow it
            k = min(int(np.searchsorted(sigma, sigma[j] + PREVIEW_HITCHES * d)), i1 - 1, len(kappa) - 1)
            cmd = self._command(x, ref, direction * float(kappa[max(k, j)]), direction)
            x = self.step(x, u, cmd)
            u = cmd
            xs.append(x)
            us.append(u)
        return xs, us, x, u


def trailer_nominal(robot, path: GeometricPath, timing: TimingOptions, world: CollisionWorld, margin: float,
                    start_state: np.ndarray, goal_state: np.ndarray, min_run: float = 0.5,
                    speed_fraction: float = 0.6) -> tuple[Nominal, dict]:
    """An exactly feasible nominal of the car with one trailer along ``path`` (the trailer axle's
    Reeds-Shepp path) from ``start_state`` to ``goal_state`` (full states): the rig driven by the
    tracking law up to a few metres before the goal, then one polynomial steering piece to the goal
    exactly (module docstring). Runs between cusps shorter than ``min_run`` (Reeds-Shepp's small
    back-and-forth moves) are skipped. Raises :class:`TrailerPlanningError` when no final piece is
    feasible or the tracked motion leaves the limits."""
    model = robot.model
    samples, sigma, direction = path.samples, path.sigma, path.direction
    n = len(samples)
    kappa = np.where(np.diff(sigma) > 1e-12, np.diff(samples[:, 2]) / np.maximum(np.diff(sigma), 1e-300), 0.0)
    max_speed = timing.max_speed or float(model.input_limits()[0, 1])
    tracker = _Tracker(robot, timing, speed_fraction * max_speed)
    # the tracked motion takes one step of dt per speed x dt of the path: refused before it is stepped
    # through when the nominal could not be that long
    nominal_grid(float(sigma[-1] - sigma[0]) / tracker.speed, timing.dt, "max_speed", max_speed, tracker.speed)
    ends = [0, *_cusps(direction, sigma, min_run), n - 1]
    x = np.array(start_state, dtype=float)
    u = np.zeros(2)
    xs, us = [x], [u]
    # every run but the last to its end, the last to its end too (the final piece starts before it)
    marks = []
    for k, (i0, i1) in enumerate(zip(ends[:-1], ends[1:])):
        dirn = 1.0 if float(np.sum(direction[i0:i1] * np.diff(sigma[i0:i1 + 1]))) >= 0 else -1.0
        new_x, new_u, x, u = tracker.run(x, u, samples, sigma, kappa, i0, i1, dirn)
        xs += new_x
        us += new_u
        marks.append((len(xs) - 1, dirn))
    last_dir = marks[-1][1]
    first_of_last = (marks[-2][0] if len(marks) > 1 else 0)
    x_arr, u_arr = np.array(xs), np.array(us)
    # the final piece: from a tracked state at least `lead` metres before the goal (trailer's axle)
    trailer_xy = robot.body_poses(x_arr)[:, 1, :2]
    goal_xy = robot.body_poses(goal_state)[1, :2]
    dist = np.hypot(*(trailer_xy - goal_xy).T)
    hitch_cap = JACKKNIFE_FRACTION * float(model.jackknife_limit)
    steer_cap = STEER_FRACTION * float(model.max_steer)
    final, tried = None, []
    # candidate starts of the final piece on the last run, FINAL_PIECE_M[0] to FINAL_PIECE_M[-1] from the
    # goal: the calmest first (smallest steering and hitch angles: the piece starts from them), at most
    # FINAL_TRIES of them, spread over the distances
    on_last = (np.arange(len(x_arr)) >= first_of_last) & (dist >= FINAL_PIECE_M[0]) & (dist <= FINAL_PIECE_M[-1])
    cand = np.flatnonzero(on_last)
    if len(cand):
        calm = np.abs(x_arr[cand, 3]) + np.abs(model.hitch_angles(x_arr[cand])[:, 0])
        bins = np.digitize(dist[cand], FINAL_PIECE_M)
        order = []
        for b in np.unique(bins):
            sel = cand[bins == b]
            order.append(int(sel[np.argmin(calm[bins == b])]))
        order.sort(key=lambda k: float(np.abs(x_arr[k, 3]) + abs(model.hitch_angles(x_arr[k])[0])))
        cand = order[:FINAL_TRIES]
    for k in cand:
        lead = float(dist[k])
        try:
            piece = steer_trailer(model, x_arr[k], goal_state, T=None, mode="polynomial")
            if piece.max_speed > tracker.speed:        # no faster than the tracked motion
                piece = steer_trailer(model, x_arr[k], goal_state, T=piece.T * piece.max_speed / tracker.speed,
                                      frame=piece.frame["heading"], mode="polynomial")
        except InputError as exc:
            tried.append(f"{lead:.1f} m: {exc.expected}")
            continue
        ok = (math.copysign(1.0, piece.plan.phases[0].v1) == last_dir and piece.max_abs_phi <= steer_cap + 1e-9
              and piece.max_abs_hitch <= hitch_cap + 1e-9 and piece.max_speed <= max_speed * 1.001
              and bool(bodies.free_many(world, robot, piece.x, margin).all()))
        tried.append(f"{lead:.1f} m: max |phi| {piece.max_abs_phi:.2f}, max |hitch| {piece.max_abs_hitch:.2f}")
        if ok:
            final = (k, piece)
            break
    if final is None:
        raise TrailerPlanningError("no feasible final piece from the tracked motion to the goal (" + "; ".join(tried)
                                   + ")")
    k, piece = final
    t_track = timing.dt * np.arange(k + 1)
    x_track, u_track = x_arr[: k + 1], u_arr[: k + 1]
    hitches = model.hitch_angles(x_track)[:, 0]
    if np.abs(hitches).max() > hitch_cap + 1e-6 or np.abs(x_track[:, 3]).max() > float(model.max_steer):
        raise TrailerPlanningError(f"the tracked motion leaves the limits (max |hitch| {np.abs(hitches).max():.3f} rad, "
                                   f"max |phi| {np.abs(x_track[:, 3]).max():.3f} rad)")
    joined = _TrackedThenPiece(model, t_track, x_track, u_track, piece)
    # the motion continued past the goal, for the gramian law's future windows only (Nominal.tail): the
    # rig driving on at its final speed with the steering held
    nominal = _nominal_of(model, timing, joined, max_speed, tracker.speed,
                          float(piece.inputs_at(np.array([piece.T]))[0, 0]))
    t = nominal.t
    hitches = model.hitch_angles(nominal.x)[:, 0]
    return nominal, {"duration_s": joined.duration, "tracked_s": float(t_track[-1]), "final_piece_s": piece.T,
                     "final_piece_from_goal_m": float(dist[k]), "runs": len(ends) - 1,
                     "direction_reversals": direction_reversals(robot.body_poses(nominal.x)[:, 1]),
                     "dt_s": float(t[1] - t[0]), "speed_m_s": tracker.speed,
                     "max_abs_hitch_angle_rad": float(np.abs(hitches).max()),
                     "jackknife_limit_rad": float(model.jackknife_limit),
                     "max_abs_steering_rad": float(np.abs(nominal.x[:, 3]).max()),
                     "steering_limit_rad": float(model.max_steer),
                     "final_piece_end_error": float(np.abs(piece.final_error).max())}


def _nominal_of(model, timing: TimingOptions, joined, max_speed: float, speed: float, v_end: float) -> Nominal:
    """The nominal of a joined motion on the timing's grid, with its tail: the rig driving on past the goal
    at its final speed ``v_end`` with the steering held, for the gramian law's future windows only
    (:attr:`~nhstab.nominal.Nominal.tail`)."""
    npts = nominal_grid(joined.duration, timing.dt, "max_speed", max_speed, speed)
    t = np.linspace(0.0, joined.duration, npts)
    nominal = Nominal.from_functions(model, joined.states, joined.inputs, t)
    t_tail = np.linspace(0.0, TAIL_S, int(round(TAIL_S / timing.dt)) + 1)
    nominal.tail = Nominal.from_inputs(model, lambda tau: np.tile([v_end, 0.0], (np.size(tau), 1)),
                                       nominal.x[-1], t_tail)
    return nominal


def lattice_nominal(robot, found: LatticeResult, timing: TimingOptions, world: CollisionWorld, margin: float,
                    x_start: np.ndarray, x_goal: np.ndarray, speed: float) -> tuple[Nominal, dict]:
    """The exact nominal of a lattice search's plan (:mod:`nhstab.planning.trailer_search`): its
    primitives' inputs (piecewise linear between knots on the nominal's grid) integrated again with the
    tracker's RK4 at the nominal's step, and its chained-form piece. Rooted at the start: the
    primitives from the start, then the piece recomputed from the state reached (same duration and
    frame) to the goal. Rooted at the goal: the piece from the start, then the primitives (reversed in
    time) from the piece's end. Raises :class:`TrailerPlanningError` when the motion so made leaves
    the limits or the margin."""
    model = robot.model
    dt = float(timing.dt)
    per = int(round(found.step_s / dt))
    max_speed = timing.max_speed or float(model.input_limits()[0, 1])
    tracker = _Tracker(robot, timing, speed)
    knots = found.knots
    nominal_grid(found.step_s * (len(knots) - 1) + found.piece.T, dt, "max_speed", max_speed, speed)
    frac = np.arange(per) / per
    if found.from_goal:
        knots = -knots[::-1]           # the order the search drove them in, away from the goal
    u_track = np.vstack([knots[k] + frac[:, None] * (knots[k + 1] - knots[k]) for k in range(len(knots) - 1)]
                        + [knots[-1:]])
    old = found.piece
    x = np.array(x_goal if found.from_goal else x_start, dtype=float)
    xs = [x]
    for k in range(len(u_track) - 1):
        x = tracker.step(x, u_track[k], u_track[k + 1])
        xs.append(x)
    x_track = np.array(xs)
    t_track = dt * np.arange(len(x_track))
    if found.from_goal:
        # integrated away from the goal (the direction in which the hitch angle is stable), then reversed in
        # time: the motion ends at the goal exactly; the piece is recomputed to where it starts
        x_track, u_track = x_track[::-1].copy(), -u_track[::-1]
    a, b = (x_start, x_track[0]) if found.from_goal else (x_track[-1], x_goal)
    try:
        piece = steer_trailer(model, a, b, T=old.T, frame=old.frame["heading"], mode="polynomial")
    except InputError as exc:
        raise TrailerPlanningError(f"the chained-form piece to the integrated state: {exc.expected}") from None
    end_error = float(np.abs(piece.final_error).max())
    hitch_cap = found.info.get("hitch_cap_rad", JACKKNIFE_FRACTION * float(model.jackknife_limit))
    steer_cap = found.info.get("steer_cap_rad", STEER_FRACTION * float(model.max_steer))
    hitches = model.hitch_angles(x_track)[:, 0]
    if (piece.max_abs_phi > steer_cap + 1e-6 or piece.max_abs_hitch > hitch_cap + 1e-6
            or np.abs(hitches).max() > hitch_cap + 1e-6 or np.abs(x_track[:, 3]).max() > steer_cap + 1e-6
            or not bool(bodies.free_many(world, robot, piece.x, margin).all())):
        raise TrailerPlanningError("the plan integrated again leaves the limits or the margin (max |hitch| "
                                   f"{max(np.abs(hitches).max(), piece.max_abs_hitch):.3f} rad)")
    if found.from_goal:
        joined = _PieceThenTracked(model, piece, t_track, x_track, u_track)
        v_end = float(u_track[-1, 0]) if len(u_track) > 1 else float(piece.inputs_at(np.array([piece.T]))[0, 0])
        nominal = _nominal_of(model, timing, joined, max_speed, speed, v_end)
    else:
        joined = _TrackedThenPiece(model, t_track, x_track, u_track, piece)
        nominal = _nominal_of(model, timing, joined, max_speed, speed,
                              float(piece.inputs_at(np.array([piece.T]))[0, 0]))
    hitches = model.hitch_angles(nominal.x)[:, 0]
    reversals = direction_reversals(robot.body_poses(nominal.x)[:, 1])
    piece_start = x_start if found.from_goal else x_track[-1]
    piece_end = piece.states_at(np.array([piece.T]))[0]
    return nominal, {"duration_s": joined.duration, "tracked_s": float(t_track[-1]), "final_piece_s": piece.T,
                     "final_piece_from_goal_m": float(np.hypot(*(trailer_pose(model, piece_start)[:2]
                                                                  - trailer_pose(model, piece_end)[:2]))),
                     "runs": reversals + 1, "direction_reversals": reversals,
                     "dt_s": float(nominal.t[1] - nominal.t[0]), "speed_m_s": speed,
                     "max_abs_hitch_angle_rad": float(np.abs(hitches).max()),
                     "jackknife_limit_rad": float(model.jackknife_limit),
                     "max_abs_steering_rad": float(np.abs(nominal.x[:, 3]).max()),
                     "steering_limit_rad": float(model.max_steer),
                     "final_piece_end_error": end_error}


class _TrackedThenPiece:
    """The tracked motion (samples on a uniform grid: x by cubic Hermite with the model's slopes, u
    linear, which is how it was integrated up to the RK4 error), then the final piece (closed form)."""

    def __init__(self, model, t, x, u, piece):
        from scipy.interpolate import CubicHermiteSpline

        self.model, self.piece = model, piece
        self.t_switch = float(t[-1])
        self.duration = self.t_switch + float(piece.T)
        self._x = CubicHermiteSpline(t, x, model.rhs(x, u), axis=0) if len(t) > 1 else None
        self._t, self._u, self._x0 = t, u, x[0]

    def _split(self, t):
        tt = np.clip(np.atleast_1d(np.asarray(t, dtype=float)).reshape(-1), 0.0, self.duration)
        return tt, tt <= self.t_switch

    def states(self, t) -> np.ndarray:
        tt, first = self._split(t)
        out = np.empty((len(tt), self.model.n))
        if first.any():
            out[first] = self._x(tt[first]) if self._x is not None else self._x0
        if (~first).any():
            out[~first] = self.piece.states_at(tt[~first] - self.t_switch)
        return out

    def inputs(self, t) -> np.ndarray:
        tt, first = self._split(t)
        out = np.empty((len(tt), 2))
        if first.any():
            for j in range(2):
                out[first, j] = np.interp(tt[first], self._t, self._u[:, j])
        if (~first).any():
            out[~first] = self.piece.inputs_at(tt[~first] - self.t_switch)
        return out


class _PieceThenTracked:
    """The chained-form piece from the start (closed form), then a driven motion from its end (samples
    on a uniform grid, as in :class:`_TrackedThenPiece`)."""

    def __init__(self, model, piece, t, x, u):
        from scipy.interpolate import CubicHermiteSpline

        self.model, self.piece = model, piece
        self.t_switch = float(piece.T)
        self.duration = self.t_switch + float(t[-1])
        self._x = CubicHermiteSpline(t, x, model.rhs(x, u), axis=0) if len(t) > 1 else None
        self._t, self._u, self._x0 = t, u, x[0]

    def _split(self, t):
        tt = np.clip(np.atleast_1d(np.asarray(t, dtype=float)).reshape(-1), 0.0, self.duration)
        return tt, tt < self.t_switch

    def states(self, t) -> np.ndarray:
        tt, first = self._split(t)
        out = np.empty((len(tt), self.model.n))
        if first.any():
            out[first] = self.piece.states_at(tt[first])
        if (~first).any():
            out[~first] = self._x(tt[~first] - self.t_switch) if self._x is not None else self._x0
        return out

    def inputs(self, t) -> np.ndarray:
        tt, first = self._split(t)
        out = np.empty((len(tt), 2))
        if first.any():
            out[first] = self.piece.inputs_at(tt[first])
        if (~first).any():
            for j in range(2):
                out[~first, j] = np.interp(tt[~first] - self.t_switch, self._t, self._u[:, j])
        return out


def tight_space(world: CollisionWorld, robot, x_start, x_goal, radius: float) -> tuple[bool, float]:
    """Is the space tight for the trailer's Reeds-Shepp paths at ``radius``? The largest free disc (by the
    world's conservative distance field) centred within ``radius`` of the start's and of the goal's
    trailer axle, on a grid of ``TIGHT_GRID_M``; tight when the smaller of the two radii is below
    ``TIGHT_DISC_FRACTION`` times ``radius`` (a turn of that radius needs about a disc of its diameter).
    Returns (tight, that smaller radius [m])."""
    fld = world.clearance_field()
    if fld is None:
        return False, math.inf
    best = []
    offsets = np.arange(-radius, radius + TIGHT_GRID_M / 2, TIGHT_GRID_M)
    dx, dy = np.meshgrid(offsets, offsets)
    near = np.hypot(dx, dy) <= radius
    for x in (x_start, x_goal):
        p = trailer_pose(robot.model, [x[0], x[1], x[2], x[-1]])
        best.append(float(np.max(fld.at(p[0] + dx[near], p[1] + dy[near]))))
    return min(best) < TIGHT_DISC_FRACTION * radius, min(best)


def _reeds_shepp_phase(world, robot, rig, search: PathOptions, path_opts: PathOptions, timing_opts: TimingOptions,
                       x_start, x_goal, run_up: float, clearances: dict, check_resolution: float, started: float,
                       deadline: float):
    """The trailer's Reeds-Shepp paths until ``deadline`` (a :func:`time.perf_counter` reading): up to
    ``NOMINAL_ATTEMPTS`` paths, each searched with the time left and made a nominal. Returns the last
    outcome (status, message, path, nominal, metrics) and the attempts' labels."""
    model = robot.model
    attempts: list = []
    result = None
    for k in range(NOMINAL_ATTEMPTS):
        left = deadline - time.perf_counter()
        if k > 0 and left < MIN_PHASE_SHARE * float(path_opts.time_limit_s):
            break
        # the first path from the guided search (if asked), the next ones from OMPL over the whole map with
        # the next seeds: a path whose motion the rig cannot follow is replaced by another one
        opts_k = replace(search, time_limit_s=max(left, 1e-3)) if k == 0 else replace(
            search, time_limit_s=max(left, 1e-3), guide=False, seed=int(
                np.random.SeedSequence([int(search.seed), 15, k]).generate_state(1)[0] % (2**31 - 2)))
        path = _search(world, robot, rig, opts_k, x_start, x_goal, run_up)
        metrics = {"planner": path_opts.planner, "planner_used": path.info.get("planner_used"),
                   "planner_status": path.planner_status, "planning_time_s": time.perf_counter() - started,
                   "validity_calls": path.validity_calls,
                   "validity_us_per_state": 1e6 * path.validity_time_s / max(path.validity_calls, 1),
                   "start_clearance_m": clearances["start"], "goal_clearance_m": clearances["goal"],
                   "planned_body": "trailer 1 (its axle)", "hitch_angle_on_arcs_rad": rig.hitch_on_arcs}
        if path.status != "exact":
            tried = (f"{path_opts.planner} for the trailer's axle in the reeds_shepp space (turning radius "
                     f"{path_opts.turning_radius:.3g} m, margin {path_opts.margin:.3g} m) for {opts_k.time_limit_s:g} s "
                     f"with seed {opts_k.seed}")
            result = ("no_path", f"no collision-free path found: tried {tried}; OMPL: {path.planner_status}", path,
                      None, metrics)
        else:
            try:
                nominal, tinfo = trailer_nominal(robot, path, timing_opts, world, path_opts.margin, x_start, x_goal)
            except TrailerPlanningError as exc:
                result = ("infeasible", f"the path was found but could not be made feasible for the car with a "
                          f"trailer: {exc}", path, None, metrics)
            else:
                check = bodies.check_path(world, robot, nominal.x, margin=path_opts.margin, resolution=check_resolution)
                metrics.update({
                    "length_m": path.length, "cusps": path.cusps,
                    "max_curvature_per_m": 1.0 / path_opts.turning_radius, "waypoints": len(path.waypoints), **tinfo,
                    "min_clearance_m": check.min_clearance, "min_clearance_pose": check.min_clearance_pose,
                    "min_clearance_body": ("car", "trailer 1")[check.min_clearance_body],
                    "clearance_check_resolution_m": check_resolution, "clearance_samples": check.samples,
                    "max_abs_inputs": np.max(np.abs(nominal.u), axis=0), "input_limits": model.input_limits()[:, 1],
                })
                if check.clear:
                    result = ("ok", "", path, nominal, metrics)
                    attempts.append("ok (guided)" if k == 0 and search.guide else f"ok (seed {opts_k.seed})")
                    break
                result = ("not_clear", f"the nominal comes within {check.min_clearance:.3g} m of an obstacle "
                          f"(margin {path_opts.margin:.3g} m) with its {('car', 'trailer')[check.min_clearance_body]} at "
                          f"{np.round(check.min_clearance_pose, 3).tolist()}", path, nominal, metrics)
        attempts.append(f"{result[0]} ({'guided' if k == 0 and search.guide else f'seed {opts_k.seed}'})")
    return result, attempts


def swept_path(robot, r1: float) -> tuple[float, float, float]:
    """(S, r_in, r_out) [m] of the rig's steady turn with the trailer's axle on a circle of radius ``r1``:
    every body turns about one centre, at (0, R_i) in its own frame (R_1 = r1 for the trailer, the car's
    rear axle at R_0 = hypot(r1, d)); r_out is the farthest point of any body from it, r_in the nearest
    (0 when a body covers it), and the swept annulus is S = r_out - r_in wide (the estimate of
    :mod:`nhstab.trailer_suite`, for any footprint: polygon vertices and edges, or discs)."""
    from shapely.geometry import Point, Polygon

    radii = (math.hypot(r1, float(robot.model.hitch_lengths[0])), float(r1))
    r_in, r_out = math.inf, 0.0
    for fp, radius in zip(robot.footprints, radii):
        centre = Point(0.0, radius)
        if fp.radius is not None:
            r_out = max(r_out, radius + fp.radius)
            r_in = min(r_in, max(radius - fp.radius, 0.0))
        else:
            v = np.asarray(fp.vertices, dtype=float)
            r_out = max(r_out, float(np.max(np.hypot(v[:, 0], v[:, 1] - radius))))
            r_in = min(r_in, float(Polygon(v).distance(centre)))
    return r_out - r_in, r_in, r_out


def rig_likely_cause(world: CollisionWorld, robot, x_start, x_goal, margin: float, turning_radius: float,
                     budget_s: float, pad: float, enclosed: dict | None = None) -> dict:
    """:func:`nhstab.planning.guide.likely_cause` for the rig: why its search found no path, in one line
    with its numbers (``text``). For each body, the widest way from its start pose to its goal pose for
    its inscribed disc (:func:`~nhstab.planning.guide.passage`); the body with the least room names the
    known obstacles (no way), the footprint (the way is narrower than the body) or the margin (it fits
    only with a smaller one; the search keeps ``pad`` more). Else the swept path: the roomiest place
    the ways can reach holds no free disc as wide as the rig's tightest steady turn sweeps
    (:func:`swept_path` at the model's smallest turning radius; a quarter turn's annulus holds such a
    disc) plus the kept margin each side, so the rig cannot make that turn anywhere between start and
    goal. Else, when the lattice's stop-and-steer search expanded every configuration it reached from one
    end (``enclosed``: the ``lattice_enclosed`` metric of :func:`lattice_plan`), that end is enclosed at
    the margin. Else the turning radius of the trailer's Reeds-Shepp paths or the budget."""
    r_min = float(robot.model.min_turning_radius)
    sweep = swept_path(robot, r_min)[0]
    kept = margin + pad
    out = {"margin_m": float(margin), "search_pad_m": float(pad), "turning_radius_m": float(turning_radius),
           "budget_s": float(budget_s), "min_turning_radius_m": r_min, "swept_path_m": sweep}
    names = ("car", "trailer") if robot.trailers == 1 else ("car",) + tuple(
        f"trailer {k + 1}" for k in range(robot.trailers))
    ends = robot.body_poses(np.stack([x_start, x_goal]))
    tightest, infos = None, []
    for b, fp in enumerate(robot.footprints):
        info = passage(world, fp, ends[0, b], ends[1, b])
        if info is None:
            continue
        infos.append(info)
        room = info["inscribed_radius_m"] + info["margin_m"] if info["connected"] else -math.inf
        if tightest is None or room < tightest[0]:
            tightest = (room, b, info)
    turn = (f"the turning radius {turning_radius:.3g} m of the trailer's paths (--turning-radius) or the budget "
            f"{budget_s:g} s (--time-limit)")
    if tightest is None:
        out.update(cause="turning_radius_or_budget", text=f"likely cause: {turn}")
        return out
    _, b, info = tightest
    body, r = names[b], info["inscribed_radius_m"]
    width = "radius" if robot.footprints[b].radius is not None else "half-width"
    out.update(body=body, inscribed_radius_m=r)
    if not info["connected"] or r + info["margin_m"] <= 0:
        out.update(cause="blocked", text=f"likely cause: the known obstacles: no way from start to goal is wide "
                                         f"enough for the {body}'s {width} {r:.3g} m even touching them")
        return out
    fit, (x, y) = info["margin_m"], info.get("at", (math.nan, math.nan))
    out.update(fits_margin_m=fit)
    if math.isfinite(fit):
        out.update(narrowest_at=[x, y], way_width_m=2.0 * (r + fit))
    where = f"the widest way from start to goal, narrowest near ({x:.2f}, {y:.2f}),"
    if fit < 0:
        out.update(cause="footprint", text=f"likely cause: the footprint: {where} is {2 * (r + fit):.3g} m wide, less "
                                           f"than the {body}'s {2 * r:.3g} m ({width} {r:.3g} m)")
        return out
    if fit < kept:
        searched = f" (the search keeps {kept:.3g} m)" if pad > 0 else ""
        below = max(0.0, math.floor((fit - pad) * 1000.0 + 1e-9) / 1000.0)
        out.update(cause="margin", fits_below_m=below,
                   text=f"likely cause: the margin: {where} keeps the {body} ({width} {r:.3g} m) {fit:.3f} m from the "
                        f"obstacles, less than the margin {margin:.3g} m{searched}; it can fit only with --margin below "
                        f"{below:.3f} m")
        return out
    room, (rx, ry) = max((i["roomiest_m"], i["roomiest_at"]) for i in infos)
    out.update(roomiest_width_m=2.0 * room, roomiest_at=[rx, ry])
    if 2.0 * room < sweep + 2.0 * kept:
        out.update(cause="swept_path",
                   text=f"likely cause: the rig's swept path: its tightest turn (the trailer's axle on {r_min:.3g} m) "
                        f"sweeps {sweep:.2f} m, plus the {kept:.3g} m the search keeps each side, and the roomiest place "
                        f"between start and goal, near ({rx:.2f}, {ry:.2f}), is {2 * room:.2f} m across: the rig "
                        f"cannot make that turn anywhere on the way")
    elif enclosed is not None:
        end = enclosed["end"]
        out.update(cause="enclosed", enclosed_end=end,
                   text=f"likely cause: the {end} is enclosed: the lattice's stop-and-steer search expanded every "
                        f"configuration of the rig it reached from the {end} ({enclosed['expansions']} expansions, "
                        f"keeping {enclosed['margin_m']:.3g} m) without a way to the "
                        f"{'start' if end == 'goal' else 'goal'}; a smaller --margin may open it (whether any plan "
                        f"exists: nhstab trailer reach MAP)")
    else:
        out.update(cause="turning_radius_or_budget",
                   text=f"likely cause: {turn}: the roomiest place between start and goal, near ({rx:.2f}, {ry:.2f}), "
                        f"is {2 * room:.2f} m across, room for the {sweep:.2f} m the rig's tightest turn sweeps plus the "
                        f"{kept:.3g} m the search keeps each side (whether any plan exists: nhstab trailer reach MAP)")
    return out


# ---------------------------------------------------------------------------------------------
# planning
# ---------------------------------------------------------------------------------------------
def plan_trailer(m: Map, robot, start, goal, path_opts: PathOptions, timing_opts: TimingOptions,
                 stab_opts: StabilizerOptions, check_resolution: float = 0.05, world: CollisionWorld | None = None,
                 searches: tuple | None = None):
    """:func:`nhstab.planning.plan` for a car_trailer with one trailer (module docstring). ``start`` and
    ``goal``: poses (x, y, theta) with the trailer in line, configurations (x, y, theta, theta1), or
    full states. ``searches``: the searches to run, a subset of ("reeds_shepp", "lattice") (default both,
    in the order the space asks for; one alone gets the whole budget: ``nhstab bench trailer``'s baseline)."""
    model = robot.model
    if model.trailers != 1:
        raise InputError("robot", "a car_trailer with one trailer (nhstab plans N = 1: its searches and its exact "
                         "end are written for one; the model, the laws and the run loop take any N, and `nhstab "
                         "trailer train` measures the laws on such a rig)", f"{model.trailers} trailers")
    world = world or CollisionWorld.from_map(m, "known")
    start_c, goal_c = robot.configuration(start, "start"), robot.configuration(goal, "goal")
    clearances = {"start": check_configuration(m, robot, start_c, "start", world),
                  "goal": check_configuration(m, robot, goal_c, "goal", world)}
    for key, c in clearances.items():
        if c <= path_opts.margin:
            value = start_c if key == "start" else goal_c
            raise InputError(key, f"a configuration whose every body is at least the margin {path_opts.margin:.3g} m "
                             f"from the known obstacles", np.round(value, 4).tolist(), detail=f"clearance {c:.3g} m")
    if path_opts.turning_radius < model.min_turning_radius - 1e-9:
        raise InputError("turning_radius", f"at least the trailer's smallest steady turning radius "
                         f"{model.min_turning_radius:.4g} m", path_opts.turning_radius)
    if path_opts.space != "reeds_shepp":
        raise InputError("space", "reeds_shepp (a car with a trailer reverses)", path_opts.space)
    started = time.perf_counter()
    x_start = np.array([start_c[0], start_c[1], start_c[2], 0.0, start_c[3]])
    x_goal = np.array([goal_c[0], goal_c[1], goal_c[2], 0.0, goal_c[3]])
    pad_margin = min(path_opts.margin + MARGIN_PAD, min(clearances.values()) - 1e-3)
    search = replace(path_opts, margin=max(path_opts.margin, pad_margin))
    rig = TrailerRig(world, robot, search.margin, search)
    run_up = START_RUN_HITCHES * float(model.hitch_lengths[0])
    limit = float(path_opts.time_limit_s)
    deadline = started + limit
    tight, discs = tight_space(world, robot, x_start, x_goal, float(path_opts.turning_radius))
    order = ("lattice", "reeds_shepp") if tight else ("reeds_shepp", "lattice")
    if searches is not None:
        if not searches or any(p not in order for p in searches):
            raise InputError("searches", "a subset of reeds_shepp, lattice", searches)
        order = tuple(p for p in order if p in searches)
    budgets = {"reeds_shepp": 0.0, "lattice": 0.0}
    attempts: list = []
    outcome: dict = {}
    for k, phase in enumerate(order):
        left = deadline - time.perf_counter()
        if k > 0 and left < MIN_PHASE_SHARE * limit:
            break
        give = (min(left, REEDS_SHEPP_SHARE * limit) if phase == "reeds_shepp" and k == 0 and len(order) > 1
                else max(left, 1e-3))
        budgets[phase] = give
        if phase == "reeds_shepp":
            res, tried = _reeds_shepp_phase(world, robot, rig, search, path_opts, timing_opts, x_start, x_goal,
                                            run_up, clearances, check_resolution, started, time.perf_counter() + give)
            attempts += tried
        else:
            res = lattice_plan(world, robot, path_opts, timing_opts, x_start, x_goal, clearances, give,
                               check_resolution, started)
            attempts.append(f"{res[0]} (lattice)")
        outcome[phase] = res
        if res[0] == "ok":
            break
    result = None
    last = outcome[list(outcome)[-1]]
    if last[0] == "ok":
        _, _, path, nominal, metrics = last
    elif "lattice" in outcome and (outcome["lattice"][0] != "no_path" or "reeds_shepp" not in outcome
                                   or outcome["reeds_shepp"][0] == "no_path"):
        rs = outcome.get("reeds_shepp")
        rs_note = (f"the trailer's Reeds-Shepp paths: {rs[1]}" if rs is not None else
                   "the trailer's Reeds-Shepp paths not tried: the time limit was spent")
        result = (outcome["lattice"][0], outcome["lattice"][1] + f" ({rs_note})", *outcome["lattice"][2:])
    else:
        result = outcome["reeds_shepp"]
    metrics = last[4] if result is None else result[4]
    metrics.update({"search_order": [p for p in order if p in outcome], "tight_space": tight,
                    "free_disc_m": discs, "search_budget_s": dict(budgets), "time_limit_s": limit})
    if result is not None:
        status, message, path, nominal, metrics = result
        metrics.update({"time_to_nominal_s": time.perf_counter() - started, "path_attempts": attempts})
        if status == "no_path":     # the pad of the search that keeps the least (the lattice's, when it ran)
            pad = (min(LATTICE_MARGIN_PAD, search.margin - path_opts.margin) if "lattice" in outcome
                   else search.margin - path_opts.margin)
            metrics["likely_cause"] = rig_likely_cause(world, robot, x_start, x_goal, path_opts.margin,
                                                       float(path_opts.turning_radius), limit, max(pad, 0.0),
                                                       metrics.get("lattice_enclosed"))
        if len(attempts) > 1:
            message += f" (after {len(attempts)} paths: " + ", ".join(attempts) + ")"
        return PlanResult(status, message, path, nominal, metrics=metrics)
    metrics["path_attempts"] = attempts
    try:
        schedule = compute_schedule(nominal, stab_opts)
    except SingularGramianError as exc:
        metrics["time_to_nominal_s"] = time.perf_counter() - started
        return PlanResult("not_stabilizable", str(exc), path, nominal, metrics=metrics)
    metrics.update(schedule_metrics(robot, stab_opts, schedule, started))
    return PlanResult("ok", "exact path of the trailer, feasible nominal of the rig, every body clear by the margin, "
                      "gain schedule computed", path, nominal, schedule, metrics)
