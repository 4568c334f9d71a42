"""Geometric planning in Reeds-Shepp and Dubins spaces: a grid guide, exact local paths, OMPL's search.

The only module that imports ``ompl``. A plan is a sequence of local paths (shortest Reeds-Shepp or
Dubins paths, :mod:`nhstab.planning.local_paths`) between waypoints, each sampled every
``resolution`` metres and checked against the collision world (the distance field decides most
poses, FCL the rest: :meth:`nhstab.collision.CollisionWorld.motion_free`), so that the path is
sampled and checked the same way wherever it came from.

The search (``plan_path``):

1. the direct local path from start to goal, if it is free;
2. with ``guide`` (default), the **guided search**: a grid shortest path for the robot's inscribed
   disc (:class:`nhstab.planning.guide.Guide`) sets subgoals; from the current pose the planner joins
   the farthest subgoal within ``GUIDE_LOOKAHEAD_M`` whose local path is free (halving the distance
   until one is), and where none is, runs OMPL's planner (RRTConnect by default) between the current
   pose and a subgoal a few turning radii ahead, in a box around the two;
3. otherwise, or if the guided search fails (it stops after ``GUIDED_SHARE`` of the budget), OMPL's
   planner over the whole map for the rest of the budget.

OMPL searches with its own discrete motion validator (in C++, a motion's states in bisection order, so
a blocked motion costs a few checks) and nhstab's state validity checker (the distance field, then
FCL), every ``OMPL_CHECK_SPACING`` x ``resolution`` along a motion (its search and its shortcuts: a
motion it wrongly takes for free only costs a rejected edge); each edge of its solution is then
checked as nhstab's local path every ``resolution`` (split at OMPL's midpoint where two Reeds-Shepp
words of equal length made the two differ), so the result is checked as densely as any other path. Only exact solutions count. OMPL's RNG is process-wide, but in
OMPL 2 ``RNG.setSeed`` reseeds the seed generator that every new RNG draws from, even after
generators exist; each OMPL call here seeds it first and builds its planner afterwards, so the same
seed gives the same plan in-process, whatever ran before (tested against a fresh process).
``isolate=True`` still plans in a forked child process. OMPL's own log output is switched off: the
result carries the status.

A robot of several bodies (a car towing a trailer) plans the poses of one reference body (the
trailer's axle) with a *rig* (``plan_path(..., rig=...)``, :mod:`nhstab.planning.trailer`) that
brings its own local planner: a pose stands for a whole state of the robot (the rig), the rig
checks the pose (every body) and joins two poses with its own exact steering, checked with every
body (``rig.connect``); the search (direct, guided, OMPL) is the same. OMPL checks its motions with
``rig.connect`` too (a Python motion validator instead of its discrete one), so every motion of its
solution is a checked piece of the rig, and the path is sampled along those pieces (``rig.densify``).
Reeds-Shepp distances at the planning turning radius remain OMPL's metric.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..collision import CollisionWorld
from ..errors import InputError
from ..geometry import Footprint, wrap_angle
from ..limits import MAX_PLANNER_SEED, check_int
from ..robot import DEFAULT_SPACE, SPACES
from . import local_paths
from .guide import Guide

PLANNERS = ("rrtconnect", "rrt", "rrtstar", "informedrrtstar", "bitstar", "prmstar", "prm", "kpiece", "fmt")


@dataclass(frozen=True)
class PathOptions:
    """Options of the geometric planning stage.

    space: "reeds_shepp" (forward and reverse) or "dubins" (forward only); None: the robot's
    (``Robot.space``, filled in by planning.plan), else reeds_shepp; turning_radius [m] > 0;
    planner: one of PLANNERS (default rrtconnect: fast first solution); time_limit_s > 0;
    seed: OMPL's RNG seed; margin [m]: obstacles inflated by it; resolution [m]: validity checking
    step along motions; simplify: OMPL's path simplification (shortcutting) after an OMPL search;
    guide: the guided search (a grid shortest path sets subgoals, see the module docstring).
    """

    space: str | None = None                 # None: the robot's, else reeds_shepp (filled in by planning.plan)
    turning_radius: float | None = None      # None: the robot's (filled in by planning.plan)
    planner: str = "rrtconnect"
    time_limit_s: float = 1.0
    seed: int = 0
    margin: float | None = None              # None: the robot's (filled in by planning.plan)
    resolution: float = 0.05
    simplify: bool = True
    guide: bool = True

    def for_robot(self, robot) -> "PathOptions":
        """These options with the robot's space (:attr:`Robot.planning_space`), turning radius and margin
        where they are None."""
        return replace(self, space=robot.planning_space if self.space is None else self.space,
                       turning_radius=robot.turning_radius if self.turning_radius is None else self.turning_radius,
                       margin=robot.margin if self.margin is None else self.margin)

    def validated(self) -> "PathOptions":
        """These options checked; a space left None (no robot filled it in) is :data:`DEFAULT_SPACE`."""
        if self.space is None:
            return replace(self, space=DEFAULT_SPACE).validated()
        if self.space not in SPACES:
            raise InputError("space", "one of " + ", ".join(SPACES), self.space)
        if self.planner not in PLANNERS:
            raise InputError("planner", "one of " + ", ".join(PLANNERS), self.planner)
        for key in ("turning_radius", "time_limit_s", "resolution"):
            v = getattr(self, key)
            if v is not None and not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                      and v > 0):
                raise InputError(key, "a positive finite number", v)
        if self.margin is not None and not (isinstance(self.margin, (int, float)) and not isinstance(self.margin, bool)
                                            and math.isfinite(self.margin) and self.margin >= 0):
            raise InputError("margin", "a finite number >= 0", self.margin)

        check_int("seed", self.seed, 0, MAX_PLANNER_SEED, "an integer (OMPL's seed)")
        for key in ("simplify", "guide"):
            if not isinstance(getattr(self, key), bool):
                raise InputError(key, "true or false", getattr(self, key))
        for key in ("turning_radius", "margin"):
            if getattr(self, key) is None:
                raise InputError(key, "a number (planning.plan takes it from the robot when not given)", None)
        return self


@dataclass
class GeometricPath:
    """A planned SE(2) path: OMPL's waypoints, and the path sampled densely along its local paths."""

    status: str                    # "exact" | "approximate" | "failed"
    planner_status: str            # OMPL's own status string
    waypoints: np.ndarray          # (W, 3)
    samples: np.ndarray            # (S, 3) dense (x, y, theta) along the path, theta unwrapped
    sigma: np.ndarray              # (S,) arc length along the path [m]
    direction: np.ndarray          # (S-1,) +1 forward / -1 reverse, per sample interval
    length: float
    cusps: int
    planning_time_s: float
    validity_calls: int
    validity_time_s: float
    options: PathOptions
    info: dict = field(default_factory=dict)


def _ompl():
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    ou.setLogLevel(ou.LogLevel.LOG_NONE)     # statuses are reported by us, not printed by OMPL
    return ob, og, ou


def _planner(og, name: str, si):
    return {"rrtconnect": og.RRTConnect, "rrt": og.RRT, "rrtstar": og.RRTstar,
            "informedrrtstar": og.InformedRRTstar, "bitstar": og.BITstar, "prmstar": og.PRMstar,
            "prm": og.PRM, "kpiece": og.KPIECE1, "fmt": og.FMT}[name](si)


def make_space(opts: PathOptions, bounds):
    ob, _, _ = _ompl()
    if opts.space == "dubins":
        space = ob.DubinsStateSpace(float(opts.turning_radius), False)
    else:                                      # reeds_shepp, also for a space left None
        space = ob.ReedsSheppStateSpace(float(opts.turning_radius))
    b = ob.RealVectorBounds(2)
    b.setLow(0, bounds[0]); b.setHigh(0, bounds[2])   # noqa: E702
    b.setLow(1, bounds[1]); b.setHigh(1, bounds[3])   # noqa: E702
    space.setBounds(b)
    return space


def _state(space, pose):
    s = space.allocState()
    s.setX(float(pose[0])); s.setY(float(pose[1])); s.setYaw(float(wrap_angle(pose[2])))  # noqa: E702
    return s


def path_length(opts: PathOptions, a, b) -> float:
    """Length of the shortest Reeds-Shepp / Dubins path from pose a to pose b (no obstacles)."""
    space = make_space(opts, (-1e6, -1e6, 1e6, 1e6))
    return float(space.distance(_state(space, a), _state(space, b)))


def plan_path(world: CollisionWorld, fp: Footprint, start, goal, opts: PathOptions,
              isolate: bool = False, more_starts=(), more_goals=(), rig=None) -> GeometricPath:
    """Plan a collision-free (by ``opts.margin``) path from start to goal; never raises for "no path".

    The direct local path if it is free, else the guided search (``opts.guide``), else OMPL's planner
    over the map, within ``opts.time_limit_s`` in all (see the module docstring). With ``isolate``
    the search runs in a forked child process. ``more_starts`` / ``more_goals``: further poses the
    path may start / end at (OMPL's multiple start states and ``GoalStates``; the guided search joins
    ``start`` and ``goal`` themselves first where they are more than ``GUIDE_LOOKAHEAD_M`` apart); the result's ``info["start_index"]`` / ``info["goal_index"]`` say which (0:
    ``start`` / ``goal``, k: the k-th further pose).
    ``rig`` (optional): the local planner and checks of a robot of several bodies (module docstring):
    ``rig.pose_free(x, y, theta)``, ``rig.connect(a, b, stats) -> bool``, ``rig.densify(waypoints) ->
    (samples, sigma, direction, length)`` and ``rig.bounding_radius``; ``fp`` is then the planned body's
    footprint (the guide's).
    """
    opts = opts.validated()
    if world.bounds is None:
        raise InputError("world", "a collision world with bounds", None)
    world.clearance_field()                   # build once (in the parent, if a child plans)
    _ompl()
    if not isolate:
        return _plan_path(world, fp, start, goal, opts, more_starts, more_goals, rig)
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    def child():
        try:
            send.send(("ok", _plan_path(world, fp, start, goal, opts, more_starts, more_goals, rig)))
        except BaseException as exc:           # sent back and re-raised in the parent
            send.send(("error", exc))

    proc = ctx.Process(target=child, daemon=True)
    proc.start()
    send.close()
    try:
        try:
            kind, value = recv.recv()
        except EOFError:
            proc.join()
            raise RuntimeError(f"the planning process died (exit code {proc.exitcode})") from None
        proc.join()
    finally:
        # interrupted (Ctrl-C, SIGTERM) while the child plans: it must not outlive the call
        if proc.is_alive():
            proc.terminate()
            proc.join(5.0)
        recv.close()
    if kind == "error":
        raise value
    return value


#: the guided search joins subgoals at most this far along the guide [m] (at least 10 turning radii)
GUIDE_LOOKAHEAD_M = 40.0
#: an OMPL search between two guide subgoals gets at most this fraction of the whole budget (and at least
#: LOCAL_MIN_BUDGET_S, never more than what is left)
LOCAL_BUDGET_FRACTION = 0.15
LOCAL_MIN_BUDGET_S = 0.1
#: the guided search stops after this fraction of the budget, so that the unguided search over the whole
#: map keeps the rest (where the guide's corridor does not suit the robot, e.g. a car that must turn)
GUIDED_SHARE = 0.5
#: OMPL's own motion checks, in its search and its shortcuts, are this many times ``resolution`` apart
#: (the edges it returns are checked every ``resolution`` as nhstab's local paths). At 2 a motion takes
#: about half the checks it takes at 1, the searches are faster, and the warehouse replans and the cars'
#: depot and parking3 problems are all still solved
OMPL_CHECK_SPACING = 2.0


class _Search:
    """One planning call: the local paths, the checks and their counts, the deadline, OMPL calls."""

    def __init__(self, world: CollisionWorld, fp: Footprint, opts: PathOptions, start, goal, rig=None):
        self.world, self.fp, self.opts, self.rig = world, fp, opts, rig
        self.radius = float(opts.turning_radius)
        self.started = time.perf_counter()
        self.deadline = self.started + float(opts.time_limit_s)
        self.stats = {"states": 0, "fcl_states": 0, "time_s": 0.0}
        self.counts = {"connections_tried": 0, "connections_free": 0, "ompl_calls": 0, "ompl_exact": 0,
                       "ompl_solve_s": 0.0, "ompl_simplify_s": 0.0}
        self._check = world.state_checker(fp, opts.margin) if rig is None else rig.pose_free
        self.bounding_radius = float(fp.bounding_radius if rig is None else rig.bounding_radius)
        self.ompl_status = ""

    def left(self) -> float:
        return self.deadline - time.perf_counter()

    def pose_free(self, pose) -> bool:
        t0 = time.perf_counter()
        ok = self._check(float(pose[0]), float(pose[1]), float(pose[2]))
        self.stats["time_s"] += time.perf_counter() - t0
        self.stats["states"] += 1
        return ok

    def connect(self, a, b) -> bool:
        """Is the local path from pose a to pose b free (sampled every ``resolution`` m)?"""
        self.counts["connections_tried"] += 1
        if self.rig is not None:
            ok = bool(self.rig.connect(a, b, self.stats))
        else:
            seg = local_paths.local_path(self.opts.space, a, b, self.radius)
            poses = local_paths.sample_every(a, seg, self.radius, self.opts.resolution, include_start=False)
            ok = self.world.motion_free(poses, self.fp, self.opts.margin, self.stats)
        self.counts["connections_free"] += ok
        return ok

    def ompl(self, a, b, budget: float, bounds, seed: int, more_starts=(), more_goals=()):
        """OMPL's planner from a (or one of ``more_starts``) to b (or one of ``more_goals``) within
        ``bounds`` for at most ``budget`` s: the waypoints of an exact solution (simplified if asked),
        or None. ``self.start_index`` / ``self.goal_index`` say which start and goal it joins."""
        ob, og, ou = _ompl()
        ou.RNG.setSeed(int(seed))               # before anything in this call makes a generator
        self.counts["ompl_calls"] += 1
        space = make_space(self.opts, bounds)
        ss = og.SimpleSetup(space)
        ss.setStateValidityChecker(lambda st: self.pose_free((st.getX(), st.getY(), st.getYaw())))
        si = ss.getSpaceInformation()
        # OMPL's own discrete motion validator (C++: it visits a motion's states in bisection order, so
        # a motion through an obstacle costs a few state checks, and most motions RRT tries are such)
        si.setStateValidityCheckingResolution(min(0.5, OMPL_CHECK_SPACING * self.opts.resolution
                                                  / max(space.getMaximumExtent(), 1e-9)))
        if self.rig is not None:        # the rig's own pieces, every body checked (module docstring)
            self._validator = _rig_validator(ob, si, self)
            si.setMotionValidator(self._validator)
        starts = [np.asarray(a, dtype=float), *more_starts]
        goals = [np.asarray(b, dtype=float), *more_goals]
        if len(goals) == 1:
            ss.setStartAndGoalStates(_state(space, a), _state(space, b))
        else:
            ss.setStartState(_state(space, a))
            goal_set = ob.GoalStates(si)
            for p in goals:
                goal_set.addState(_state(space, p))
            ss.setGoal(goal_set)
        for p in starts[1:]:
            ss.addStartState(_state(space, p))
        ss.setPlanner(_planner(og, self.opts.planner, si))
        ss.setup()
        # OMPL checks its motions every OMPL_CHECK_SPACING x resolution, nhstab every resolution: an edge
        # OMPL took for free may come closer than the margin between OMPL's samples (its shortcuts
        # graze the obstacles most, and a start close to a wall makes that likely: a start 0.15 m from
        # a wall at margin 0.12 m). Such a solution is not the end of the search: its unsimplified
        # path is tried, then OMPL searches again (fresh trees, its generator running on) while the
        # budget lasts. ``ompl_rejected`` counts the solutions nhstab's check refused.
        end = time.perf_counter() + max(1e-3, float(budget))
        while True:
            t0 = time.perf_counter()
            status = ss.solve(max(1e-3, end - t0))
            self.counts["ompl_solve_s"] += time.perf_counter() - t0
            self.ompl_status = status.asString() if hasattr(status, "asString") else str(status)
            if not ss.haveExactSolutionPath():
                return None
            self.counts["ompl_exact"] += 1
            raw = ss.getSolutionPath()
            tries = [[space.cloneState(raw.getState(i)) for i in range(raw.getStateCount())]]
            if self.opts.simplify:
                t0 = time.perf_counter()
                ss.simplifySolution(max(0.05, min(self.left(), end - t0)))
                self.counts["ompl_simplify_s"] += time.perf_counter() - t0
                path = ss.getSolutionPath()
                tries.insert(0, [space.cloneState(path.getState(i)) for i in range(path.getStateCount())])
            for states in tries:
                out = self._adopt_path(space, states, starts, goals)
                if out is not None:
                    return out
            self.counts["ompl_rejected"] = self.counts.get("ompl_rejected", 0) + 1
            if end - time.perf_counter() <= 1e-3 or self.left() <= 0:
                self.ompl_status += " (refused by the check every resolution; budget spent)"
                return None
            ss.clear()

    def _adopt_path(self, space, states, starts, goals):
        """The waypoints of an OMPL solution (its states), each edge checked as nhstab's local path
        (:meth:`_adopt`), or None; sets ``start_index`` / ``goal_index``."""
        # which of the start / goal poses the path joins (OMPL stores the yaw wrapped)
        self.start_index = self.goal_index = 0
        for key, ends, st in (("start_index", starts, states[0]), ("goal_index", goals, states[-1])):
            w = np.array([st.getX(), st.getY(), st.getYaw()])
            err = [math.hypot(*(p[:2] - w[:2])) + abs(float(wrap_angle(p[2] - w[2]))) for p in ends]
            setattr(self, key, int(np.argmin(err)))
        a, b = starts[self.start_index], goals[self.goal_index]
        out = [np.asarray(a, dtype=float)]
        for k in range(len(states) - 1):
            piece = self._adopt(space, states[k], states[k + 1], 0)
            if piece is None:
                return None
            out.extend(piece)
        out[-1] = np.asarray(b, dtype=float)
        return np.array(out)

    def _adopt(self, space, sa, sb, depth: int):
        """The poses after sa of the edge sa -> sb of an OMPL solution, checked as nhstab's local paths.
        OMPL checked the edge along its own interpolation, which is the same local path except where two
        Reeds-Shepp words tie in length; such an edge is split at OMPL's midpoint (sub-paths of a
        shortest path are shortest) until nhstab's paths agree, or None."""
        pa = (sa.getX(), sa.getY(), sa.getYaw())
        pb = (sb.getX(), sb.getY(), sb.getYaw())
        if self.connect(pa, pb):
            return [np.array(pb)]
        if depth >= 6:
            return None
        mid = space.allocState()
        space.interpolate(sa, sb, 0.5, mid)
        first = self._adopt(space, sa, mid, depth + 1)
        second = None if first is None else self._adopt(space, mid, sb, depth + 1)
        return None if second is None else first + second


def _rig_validator(ob, si, search: "_Search"):
    """An OMPL motion validator that checks a motion as ``search.connect`` does (the rig's piece)."""

    class RigMotionValidator(ob.MotionValidator):
        def checkMotion(self, s1, s2, *rest):
            return search.connect((s1.getX(), s1.getY(), s1.getYaw()), (s2.getX(), s2.getY(), s2.getYaw()))

    return RigMotionValidator(si)


def _seed(seed: int, k: int) -> int:
    """OMPL's seed for the k-th OMPL call of a planning call with ``seed`` (k = 0: seed + 1, as before)."""
    if k == 0:
        return int(seed) + 1                   # OMPL refuses seed 0
    return int(np.random.SeedSequence([int(seed), int(k)]).generate_state(1)[0] % (2**31 - 2)) + 1


def _plan_path(world: CollisionWorld, fp: Footprint, start, goal, opts: PathOptions, more_starts=(),
               more_goals=(), rig=None) -> GeometricPath:
    start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
    search = _Search(world, fp, opts, start, goal, rig)
    info: dict = {"start_index": 0, "goal_index": 0}
    waypoints, used, status_text = None, None, ""
    if search.connect(start, goal):
        waypoints, used, status_text = np.array([start, goal]), "direct", "Exact solution (direct connection)"
    several = bool(more_starts or more_goals)
    if waypoints is None and opts.guide and (not several or math.dist(start[:2], goal[:2]) > GUIDE_LOOKAHEAD_M):
        # with several starts or goals (the car's maneuvers out of a slot) the guide joins the first of
        # each, the caller's best guess, where they are further apart than one lookahead of the guide
        # (closer, the guide reduces to the local path the caller tried already); OMPL then searches
        # from all of them
        waypoints = _guided(search, start, goal, info)
        if waypoints is not None:
            used, status_text = "guided", f"Exact solution (guided: {len(waypoints) - 1} local paths)"
    if waypoints is None and search.left() > 0:
        waypoints = search.ompl(start, goal, search.left(), world.bounds, _seed(opts.seed, 0), more_starts, more_goals)
        used, status_text = opts.planner, search.ompl_status
        if waypoints is not None:
            info.update(start_index=search.start_index, goal_index=search.goal_index)
    elapsed = time.perf_counter() - search.started
    st = search.stats
    info.update({"planner_used": used, **search.counts, "fcl_states": st["fcl_states"],
                 "fcl_fraction": st["fcl_states"] / max(st["states"], 1)})
    if waypoints is None:
        return GeometricPath("failed", status_text or "No solution (time limit)", np.zeros((0, 3)), np.zeros((0, 3)),
                             np.zeros(0), np.zeros(0), 0.0, 0, elapsed, st["states"], st["time_s"], opts, info)
    if rig is not None:
        samples, sigma, direction, length = rig.densify(waypoints)
        cusps = int(np.sum(direction[1:] != direction[:-1]))
    else:
        samples, sigma, length = densify(opts, waypoints, step=min(0.005, opts.resolution / 2))
        direction, cusps = path_directions(samples)
    return GeometricPath("exact", status_text, waypoints, samples, sigma, direction, length, cusps, elapsed,
                         st["states"], st["time_s"], opts, info)


def _guided(search: _Search, start, goal, info: dict):
    """The guided search (module docstring, step 2): waypoints (W, 3) joined by free local paths, or
    None (no guide path, or a gap that OMPL did not bridge in its share of the budget)."""
    opts, world = search.opts, search.world
    guide = Guide(world.clearance_field(), search.fp, opts.margin, start, goal,
                  cache=world.cache.setdefault("guide", {}))
    info["guide"] = guide.info
    if not guide.ok:
        return None
    info["guide"]["length_m"] = guide.length_m
    R = search.radius
    lookahead = max(GUIDE_LOOKAHEAD_M, 10.0 * R)
    min_step = max(0.5, R)
    window = max(1.0, R)
    local_reach = max(3.0, 3.0 * R)
    pad = max(2.0, 3.0 * R) + search.bounding_radius
    budget_cap = max(LOCAL_MIN_BUDGET_S, LOCAL_BUDGET_FRACTION * float(opts.time_limit_s))

    def subgoal(s: float):
        return guide.reference_pose(guide.point_at(s), guide.heading_at(s, window))

    pos, s_cur = start, guide.project(guide.start_xy)
    out = [start]
    k_ompl = 0
    share_end = search.started + GUIDED_SHARE * float(opts.time_limit_s)

    def left() -> float:
        return min(search.left(), share_end - time.perf_counter())

    while True:
        if left() <= 0:
            info["guide"]["failure"] = "its share of the time limit"
            return None
        rest = guide.length_m - s_cur
        cands = []
        if rest <= lookahead:
            cands.append((goal, guide.length_m))
        d = min(lookahead, rest)
        while d >= min_step:
            if s_cur + d < guide.length_m - 1e-9:
                cands.append((None, s_cur + d))
            d *= 0.5
        nxt = None
        for pose, s in cands:
            pose = subgoal(s) if pose is None else pose
            if (pose is goal or search.pose_free(pose)) and search.connect(pos, pose):
                nxt = (pose, s, [pose])
                break
        if nxt is None:
            # OMPL bridges the gap to a free subgoal a few turning radii ahead (or to the goal)
            for s in ([guide.length_m] if rest <= local_reach else []) + \
                     [s_cur + local_reach * f for f in (1.0, 1.5, 0.6, 2.0) if s_cur + local_reach * f < guide.length_m]:
                pose = goal if s >= guide.length_m else subgoal(s)
                if pose is not goal and not search.pose_free(pose):
                    continue
                lo = np.minimum(pos[:2], pose[:2]) - pad
                hi = np.maximum(pos[:2], pose[:2]) + pad
                b = world.bounds
                box = (max(b[0], lo[0]), max(b[1], lo[1]), min(b[2], hi[0]), min(b[3], hi[1]))
                k_ompl += 1
                pts = search.ompl(pos, pose, min(left(), budget_cap), box, _seed(opts.seed, k_ompl))
                if pts is not None:
                    nxt = (pose, s, list(pts[1:]))
                    break
                if left() <= 0:
                    break
            if nxt is None:
                info["guide"]["failure"] = f"no local path past guide arc length {s_cur:.2f} m"
                return None
        pos, s_cur = nxt[0], nxt[1]
        out.extend(nxt[2])
        if pos is goal:
            return np.array(out)


def local_length(opts: PathOptions, a, b) -> float:
    """The length of the shortest local path from pose a to pose b (no obstacles) [m]."""
    R = float(opts.turning_radius)
    return float(local_paths.path_length(local_paths.local_path(opts.space, a, b, R), R))


def local_segments(opts: PathOptions, a, b, tol: float = 1e-12) -> list[tuple[int, float, float]]:
    """The local path from pose a to pose b as its segments of constant curvature: [(direction +1/-1,
    curvature dtheta/dsigma [1/m], length [m]), ...], from the same numpy Reeds-Shepp / Dubins words
    that :func:`densify` samples (so a nominal built from them follows the checked path exactly).
    An L segment turns left when driven forward: dtheta/dsigma = +1/R forward, -1/R in reverse."""
    R = float(opts.turning_radius)
    out = []
    for kind, length in local_paths.local_path(opts.space, a, b, R):
        if abs(length) * R <= tol:
            continue
        direction = 1 if length > 0 else -1
        k = {"L": 1.0 / R, "R": -1.0 / R, "S": 0.0}[kind] * direction
        out.append((direction, k, abs(length) * R))
    return out


def local_path(opts: PathOptions, a, b, step: float = 0.005):
    """The shortest local path (Reeds-Shepp or Dubins at ``opts.turning_radius``, no obstacles) from
    pose a to pose b, sampled every ~step m: (samples (S, 3) from a to b, theta unwrapped; their arc
    length (S,); the length)."""
    return densify(opts, np.array([a, b], dtype=float), step)


def densify(opts: PathOptions, waypoints: np.ndarray, step: float = 0.005):
    """Sample the local paths between consecutive waypoints every ~step m, uniformly in arc length.

    Returns the samples (S, 3), theta unwrapped, their exact arc length, and the path's length."""
    R = float(opts.turning_radius)
    out, sig = [np.asarray(waypoints[:1], dtype=float)], [np.zeros(1)]
    offset = 0.0
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        seg = local_paths.local_path(opts.space, a, b, R)
        d = local_paths.path_length(seg, R)
        n = max(1, int(math.ceil(d / step)))
        pts = local_paths.sample(a, seg, R, np.arange(1, n + 1) / n)
        pts[-1] = b                                     # the waypoint itself (rounding)
        out.append(pts)
        sig.append(offset + d * np.arange(1, n + 1) / n)
        offset += d
    samples = np.vstack(out)
    samples[:, 2] = np.unwrap(samples[:, 2])
    return samples, np.concatenate(sig), offset


def path_directions(samples: np.ndarray):
    """Direction of travel per sample interval (+1 forward, -1 reverse) and the number of cusps."""
    d = np.diff(samples[:, :2], axis=0)
    ds = np.hypot(d[:, 0], d[:, 1])
    heading = samples[:-1, 2]
    along = d[:, 0] * np.cos(heading) + d[:, 1] * np.sin(heading)
    direction = np.where(along >= 0, 1.0, -1.0)
    moving = ds > 1e-12
    # carry the direction through zero-length intervals
    for k in range(1, len(direction)):
        if not moving[k]:
            direction[k] = direction[k - 1]
    cusps = int(np.sum(direction[1:] != direction[:-1]))
    return direction, cusps
