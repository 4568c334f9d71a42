"""Geometric planning in OMPL's Reeds-Shepp and Dubins state spaces, with FCL as validity checker.

The only module that imports ``ompl``. OMPL's RNG is process-wide and can be seeded only before the
first random number generator exists in the process. So that every planning call is reproducible
from its own seed, whatever ran before it, :func:`plan_path` runs the search in a forked child
process (which inherits the collision world) that seeds a fresh RNG, plans, and sends the path back;
``isolate=False`` plans in-process (then only the first call of a process is seeded). The child
exits without running interpreter finalisers, so nanobind's exit-time "leaked instances" report
never reaches users. OMPL's own log output is switched off: the result carries the status.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..collision import CollisionWorld
from ..errors import InputError
from ..geometry import Footprint, wrap_angle

PLANNERS = ("rrtconnect", "rrt", "rrtstar", "informedrrtstar", "bitstar", "prmstar", "prm", "kpiece", "fmt")
SPACES = ("reeds_shepp", "dubins")


@dataclass(frozen=True)
class PathOptions:
    """Options of the geometric planning stage.

    space: "reeds_shepp" (forward and reverse) or "dubins" (forward only); turning_radius [m] > 0;
    planner: one of PLANNERS (default rrtconnect: fast first solution); time_limit_s > 0;
    seed: OMPL's RNG seed; margin [m]: obstacles inflated by it; resolution [m]: validity checking
    step along motions; simplify: OMPL's path simplification (shortcutting) after solving.
    """

    space: str = "reeds_shepp"
    turning_radius: float | None = None      # None: the robot's (filled in by planning.plan)
    planner: str = "rrtconnect"
    time_limit_s: float = 1.0
    seed: int = 0
    margin: float | None = None              # None: the robot's (filled in by planning.plan)
    resolution: float = 0.05
    simplify: bool = True

    def for_robot(self, robot) -> "PathOptions":
        """These options with the robot's turning radius and margin where they are None."""
        return replace(self, turning_radius=robot.turning_radius if self.turning_radius is None else self.turning_radius,
                       margin=robot.margin if self.margin is None else self.margin)

    def validated(self) -> "PathOptions":
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
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise InputError("seed", "a non-negative integer", self.seed)
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
    if opts.space == "reeds_shepp":
        space = ob.ReedsSheppStateSpace(float(opts.turning_radius))
    else:
        space = ob.DubinsStateSpace(float(opts.turning_radius), False)
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
              isolate: bool = True, more_starts=(), more_goals=()) -> GeometricPath:
    """Plan a collision-free (by ``opts.margin``) path from start to goal; never raises for "no path".

    Tries the direct local path first; otherwise runs the chosen OMPL planner for at most
    ``opts.time_limit_s``. With ``isolate`` (default) the search runs in a forked child process
    seeded with ``opts.seed`` (see the module docstring). ``more_starts`` / ``more_goals``: further
    poses the path may start / end at (OMPL's multiple start states and ``GoalStates``); the
    result's ``info["start_index"]`` / ``info["goal_index"]`` say which (0: ``start`` / ``goal``,
    k: the k-th further pose).
    """
    opts = opts.validated()
    if world.bounds is None:
        raise InputError("world", "a collision world with bounds", None)
    world.clearance_field()                   # build once, in the parent: children inherit it
    _ompl()                                   # import once, in the parent (no generator is made)
    if not isolate:
        return _plan_path(world, fp, start, goal, opts, more_starts, more_goals)
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    def child():
        try:
            send.send(("ok", _plan_path(world, fp, start, goal, opts, more_starts, more_goals)))
        except BaseException as exc:           # sent back and re-raised in the parent
            send.send(("error", exc))

    proc = ctx.Process(target=child, daemon=True)
    proc.start()
    send.close()
    try:
        kind, value = recv.recv()
    except EOFError:
        proc.join()
        raise RuntimeError(f"the planning process died (exit code {proc.exitcode})") from None
    proc.join()
    if kind == "error":
        raise value
    return value


def _plan_path(world: CollisionWorld, fp: Footprint, start, goal, opts: PathOptions, more_starts=(),
               more_goals=()) -> GeometricPath:
    ob, og, ou = _ompl()
    ou.RNG.setSeed(int(opts.seed) + 1)      # before anything samples (OMPL refuses seed 0)
    space = make_space(opts, world.bounds)
    ss = og.SimpleSetup(space)
    check = world.state_checker(fp, opts.margin)
    counter = {"calls": 0, "time": 0.0}

    def valid(state) -> bool:
        t0 = time.perf_counter()
        ok = check(state.getX(), state.getY(), state.getYaw())
        counter["time"] += time.perf_counter() - t0
        counter["calls"] += 1
        return ok

    ss.setStateValidityChecker(valid)
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(min(0.5, opts.resolution / max(space.getMaximumExtent(), 1e-9)))
    s_start, s_goal = _state(space, start), _state(space, goal)
    starts = [np.asarray(start, dtype=float), *(np.asarray(p, dtype=float) for p in more_starts)]
    goals = [np.asarray(goal, dtype=float), *(np.asarray(p, dtype=float) for p in more_goals)]
    if len(goals) == 1:
        ss.setStartAndGoalStates(s_start, s_goal)
    else:
        ss.setStartState(s_start)
        goal_set = ob.GoalStates(si)
        for p in goals:
            goal_set.addState(_state(space, p))
        ss.setGoal(goal_set)
    for p in starts[1:]:
        ss.addStartState(_state(space, p))
    ss.setPlanner(_planner(og, opts.planner, si))
    ss.setup()
    started = time.perf_counter()
    if si.checkMotion(s_start, s_goal):
        # the direct (shortest) local path is free: no search needed
        exact, have, status_text, used = True, True, "Exact solution (direct connection)", "direct"
        waypoints = np.array([[float(v) for v in start], [float(v) for v in goal]])
    else:
        status = ss.solve(float(opts.time_limit_s))
        exact = bool(ss.haveExactSolutionPath())
        have = bool(ss.haveSolutionPath())
        status_text = status.asString() if hasattr(status, "asString") else str(status)
        used = opts.planner
        waypoints = None
        if have:
            if opts.simplify:
                ss.simplifySolution()
            path = ss.getSolutionPath()
            waypoints = np.array([[st.getX(), st.getY(), st.getYaw()]
                                  for st in (path.getState(i) for i in range(path.getStateCount()))])
    elapsed = time.perf_counter() - started
    info = {"planner_used": used, "start_index": 0, "goal_index": 0}
    if waypoints is not None and (len(starts) > 1 or len(goals) > 1):
        # which of the start / goal poses the path joins (OMPL stores the yaw wrapped)
        for key, ends, w in (("start_index", starts, waypoints[0]), ("goal_index", goals, waypoints[-1])):
            err = [math.hypot(*(p[:2] - w[:2])) + abs(float(wrap_angle(p[2] - w[2]))) for p in ends]
            info[key] = int(np.argmin(err))
        waypoints[0], waypoints[-1] = starts[info["start_index"]], goals[info["goal_index"]]
    if not have:
        return GeometricPath("failed", status_text, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0),
                             0.0, 0, elapsed, counter["calls"], counter["time"], opts, info)
    length = float(sum(space.distance(_state(space, a), _state(space, b)) for a, b in zip(waypoints[:-1], waypoints[1:])))
    samples, sigma = densify(space, waypoints, step=min(0.005, opts.resolution / 2))
    direction, cusps = path_directions(samples)
    return GeometricPath("exact" if exact else "approximate", status_text, waypoints, samples, sigma, direction,
                         length, cusps, elapsed, counter["calls"], counter["time"], opts, info)


_LOCAL_SPACES: dict = {}


def _local_space(opts: PathOptions):
    key = (opts.space, float(opts.turning_radius))
    space = _LOCAL_SPACES.get(key)
    if space is None:
        space = _LOCAL_SPACES[key] = make_space(opts, (-1e6, -1e6, 1e6, 1e6))
    return space


def local_length(opts: PathOptions, a, b) -> float:
    """The length of the shortest local path from pose a to pose b (no obstacles)."""
    space = _local_space(opts)
    return float(space.distance(_state(space, a), _state(space, b)))


def local_segments(opts: PathOptions, a, b, tol: float = 1e-8) -> list[tuple[int, float, float]]:
    """The local path from pose a to pose b as its segments of constant curvature: [(direction +1/-1,
    curvature dtheta/dsigma [1/m], length [m]), ...]. OMPL does not expose a Reeds-Shepp path's
    segments, so they are recovered from its exact interpolation: from the current point, a short
    probe gives the segment's curvature (snapped to 0 or +-1/R) and direction, and a bisection on the
    arc length finds where the interpolated poses stop matching that segment's closed form (to
    ``tol`` m and rad); the next segment starts there."""
    space = _local_space(opts)
    sa, sb = _state(space, a), _state(space, b)
    d = float(space.distance(sa, sb))
    tmp = space.allocState()
    R = float(opts.turning_radius)

    def pose(f):
        space.interpolate(sa, sb, min(max(f, 0.0), 1.0), tmp)
        return np.array([tmp.getX(), tmp.getY(), tmp.getYaw()])

    def drive(p, direction, k, s):
        u = direction * s
        th = p[2] + k * s
        if abs(k) < 1e-12:
            return np.array([p[0] + u * math.cos(p[2]), p[1] + u * math.sin(p[2]), p[2]])
        # heading advances by k per metre of path; position along the arc driven in `direction`
        kk = k * direction            # signed curvature of the motion: theta' = kk * u'
        return np.array([p[0] + (math.sin(p[2] + kk * u) - math.sin(p[2])) / kk,
                         p[1] - (math.cos(p[2] + kk * u) - math.cos(p[2])) / kk, th])

    def matches(p, direction, k, s, q):
        e = drive(p, direction, k, s)
        return (abs(e[0] - q[0]) <= tol and abs(e[1] - q[1]) <= tol
                and abs(float(wrap_angle(e[2] - q[2]))) <= tol)

    out = []
    if d <= tol:
        return out
    f, p = 0.0, np.asarray(a, dtype=float)
    p = np.array([p[0], p[1], float(wrap_angle(p[2]))])
    while f < 1.0 - 1e-15 and len(out) < 64:
        h = min(1e-4 / d, 1.0 - f)
        q = pose(f + h)
        step = d * h
        along = (q[0] - p[0]) * math.cos(p[2]) + (q[1] - p[1]) * math.sin(p[2])
        direction = 1 if along >= 0 else -1
        k = float(wrap_angle(q[2] - p[2])) / step
        for snap in (0.0, 1.0 / R, -1.0 / R):
            if abs(k - snap) < 1e-4:
                k = snap
        # the segment reaches at least fraction lo; find where it ends (exponential search, bisection)
        lo, hi = f + h, None
        g = h
        while hi is None:
            g *= 2
            cand = min(f + g, 1.0)
            if matches(p, direction, k, d * (cand - f), pose(cand)):
                lo = cand
                if cand >= 1.0:
                    hi = 1.0
            else:
                hi = cand
        if lo < 1.0:
            for _ in range(60):
                if hi - lo <= 1e-15:
                    break
                mid = 0.5 * (lo + hi)
                if matches(p, direction, k, d * (mid - f), pose(mid)):
                    lo = mid
                else:
                    hi = mid
        length = d * (lo - f)
        out.append((direction, k, length))
        f = lo
        p = pose(f)         # the next segment starts from OMPL's own pose (no drift)
    return out


def local_path(opts: PathOptions, a, b, step: float = 0.005):
    """The shortest local path (Reeds-Shepp or Dubins at ``opts.turning_radius``, no obstacles) from
    pose a to pose b, sampled every ~step m: (samples (S, 3) from a to b, theta unwrapped; their arc
    length (S,); the length)."""
    space = _local_space(opts)
    samples, sigma = densify(space, np.array([a, b], dtype=float), step)
    return samples, sigma, float(sigma[-1])


def densify(space, waypoints: np.ndarray, step: float = 0.005):
    """Sample the local (Reeds-Shepp / Dubins) paths between consecutive waypoints every ~step m.

    Returns the samples (S, 3), theta unwrapped, and their exact arc length: OMPL interpolates these
    paths uniformly in arc length, so sample k of n on a local path of length d sits at k d / n."""
    out, sig = [waypoints[:1]], [np.zeros(1)]
    tmp = space.allocState()
    offset = 0.0
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        sa, sb = _state(space, a), _state(space, b)
        d = float(space.distance(sa, sb))
        n = max(1, int(math.ceil(d / step)))
        pts = np.empty((n, 3))
        for k in range(1, n + 1):
            space.interpolate(sa, sb, k / n, tmp)
            pts[k - 1] = (tmp.getX(), tmp.getY(), tmp.getYaw())
        out.append(pts)
        sig.append(offset + d * np.arange(1, n + 1) / n)
        offset += d
    samples = np.vstack(out)
    samples[:, 2] = np.unwrap(samples[:, 2])
    return samples, np.concatenate(sig)


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
