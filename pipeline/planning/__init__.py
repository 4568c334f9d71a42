"""Planning: map + robot + start/goal -> a feasible, collision-free, stabilizable nominal trajectory.

Stages: geometric path in OMPL's Reeds-Shepp / Dubins space (``geometric``, the only module importing
ompl) with the FCL world as validity checker, for cars with unparking maneuvers where an end is
confined (``parking``); time-parameterisation into x0(t), u0(t) (``timing`` for the unicycle,
``cars`` for the cars, which drive their path exactly); a clearance re-check of the nominal with FCL;
the gain schedule of the stabilizer along it; for cars, whether the nominal is worth tracking
(:func:`tracking_metrics`: duration, steering, gains within their bounds), with further paths tried
while the budget lasts.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from ..collision import CollisionWorld, check_poses
from ..control import GAIN_BOUND, StabilizerOptions, compute_schedule
from ..errors import InputError, SingularGramianError, user_keys
from ..geometry import wrap_angle
from ..limits import FCL_CHECK_S, check_headings, check_turning_radius
from ..maps.base import Map
from ..models import MODELS, Model
from ..models.base import SteeredCar
from ..nominal import Nominal
from ..robot import Robot, default_robot
from .cars import CarPlanningError, car_nominal, exact_nominal
from .geometric import PLANNERS, SPACES, GeometricPath, PathOptions, path_length, plan_path
from .guide import likely_cause
from .parking import CarOptions, car_paths, failed_path
from .result import PlanResult, schedule_metrics
from .timing import TimingOptions, unicycle_nominal
from .trailer import plan_trailer

#: the geometric planner keeps this much more than the requested margin, so that the nominal still
#: clears the margin: the unicycle's follows the sampled path to a few millimetres. Cars get more room
#: for their steering pieces: the constant-v1 pieces used first stay within about 0.012 m of the path
#: (on the bundled warehouse, parking lot and 10 Bench-MR parking3 problems), but a piece may fall back
#: to the phased sinusoids, which stray 0.1-0.5 m from it (up to 1.1 m)
MARGIN_PAD = {name: cls.search_pad for name, cls in MODELS.items() if cls.search_pad is not None}
#: a car that drives its path exactly (held steering, steering in place where the curvature changes)
#: needs no room to stray; the search keeps this much more than the margin only so that poses between
#: the search's checked samples and the nominal's keep the margin too
EXACT_PAD = 0.01
#: the models the planner plans for (each model's ``plannable``)
PLANNABLE = tuple(name for name, cls in MODELS.items() if cls.plannable)


def pose_columns(model: Model) -> list[int]:
    """Indices of (x, y, theta) in the model's state."""
    names = list(model.state_names)
    return [names.index("x"), names.index("y"), names.index("theta")]


def check_map_budget(m: Map, time_limit_s: float, resolution: float = 0.05) -> None:
    """Refuse, before anything is built, a map too large for the planning budget: one crossing of
    its diagonal, checked every ``resolution`` m at the cost of a check that reaches FCL
    (:data:`nhstab.limits.FCL_CHECK_S`), must fit in ``time_limit_s``. Below that, the search and
    its simplification keep within the budget, and the distance field and collision world are
    bounded in size (:mod:`nhstab.limits`)."""
    w, h = m.size
    diagonal = math.hypot(w, h)
    largest = time_limit_s * resolution / FCL_CHECK_S
    if diagonal > largest:
        raise InputError("map", f"a map at most {largest:,.0f} m across for a planning budget of {time_limit_s:g} s "
                         f"(one crossing checked every {resolution:g} m costs up to {FCL_CHECK_S * 1e6:.0f} us per "
                         "check)", f"{m.name}: {w:,.6g} x {h:,.6g} m, {diagonal:,.0f} m across",
                         detail="crop its bounds or raise the time limit")


#: start and goal closer than this (in position, and in heading) are the same pose: there is nothing
#: to plan, and no trajectory along which the gramian could be invertible
SAME_POSE_M, SAME_POSE_RAD = 1e-6, 1e-6


def check_start_goal(start: np.ndarray, goal: np.ndarray) -> None:
    """Refuse a goal equal to the start (one line naming ``goal``)."""
    if math.hypot(*(goal[:2] - start[:2])) <= SAME_POSE_M and abs(float(wrap_angle(goal[2] - start[2]))) <= SAME_POSE_RAD:
        raise InputError("goal", "a pose different from the start (nothing to plan: the robot is there)",
                         np.round(goal, 6).tolist())


def min_turning_radius(model: Model) -> float:
    """The model's own :attr:`~nhstab.models.Model.min_turning_radius` (L / tan(max_steer) for a car)."""
    return float(model.min_turning_radius)


def check_plannable(robot: Robot, key: str = "robot") -> None:
    """Refuse a robot whose model the planner does not plan for (:data:`PLANNABLE`, each model's
    ``plannable``) with an :class:`InputError` naming ``key`` (where the robot was given)."""
    if robot.model.name not in PLANNABLE:
        raise InputError(key, "one of " + ", ".join(PLANNABLE) + " (the robots nhstab plans for)", robot.model.name)


def default_turning_radius(model: Model) -> float:
    """The planning turning radius of the model's built-in robot (see :mod:`nhstab.robot`)."""
    if getattr(model, "name", None) not in PLANNABLE:
        raise InputError("robot", "one of " + ", ".join(PLANNABLE) + " (the robots nhstab plans for)",
                         getattr(model, "name", model))
    return default_robot(model.name, **model.params()).turning_radius


def plan(m: Map, robot: Robot, start, goal, path_opts: PathOptions | None = None,
         timing_opts: TimingOptions | None = None, stab_opts: StabilizerOptions | None = None,
         check_resolution: float = 0.05, world: CollisionWorld | None = None,
         car_opts: CarOptions | None = None) -> PlanResult:
    """Plan a nominal trajectory of ``robot`` from ``start`` to ``goal`` on the map's known obstacles.

    Parameters
    ----------
    m : Map
        The map (:func:`nhstab.load_map`); only its known obstacles are planned around.
    robot : Robot
        The robot (:func:`nhstab.make_robot`, :func:`nhstab.load_robot`): its model, footprint,
        margin, turning radius and stabilizer defaults apply where the options leave them None.
    start, goal : array_like
        Poses x, y, theta (a car_trailer may add its trailer headings), or the model's full state with
        phi = 0 (the rule of :meth:`nhstab.robot.Robot.configuration`); the nominal starts and ends
        with phi = 0.
    path_opts : PathOptions, optional
        The search: planner, time budget, seed, margin, turning radius.
    timing_opts : TimingOptions, optional
        The time parameterisation: speed and acceleration limits.
    stab_opts : StabilizerOptions, optional
        The gramian stabilizer whose gain schedule is computed along the nominal (default: the
        robot's).
    check_resolution : float
        Spacing [m] at which the nominal's poses are checked against the obstacles.
    world : CollisionWorld, optional
        The collision world of the map's known obstacles, if already built (it is built otherwise).
    car_opts : CarOptions, optional
        The car planner's options (:mod:`nhstab.planning.parking`).

    Returns
    -------
    PlanResult
        ``status`` "ok" with the nominal, its path, gain schedule and metrics, or why there is no
        usable plan ("no_path", "infeasible", "not_clear", "not_stabilizable").

    Raises
    ------
    InputError
        For a bad request: start or goal outside the bounds or in collision, bad options, a model
        this planner does not handle.
    """
    if not isinstance(robot, Robot):
        raise InputError("robot", "a Robot (nhstab.make_robot(model, footprint=...) or nhstab.load_robot(path))",
                         type(robot).__name__)
    return _plan(m, robot, start, goal, path_opts, timing_opts, stab_opts, check_resolution, world, car_opts)


def search_margin(world: CollisionWorld, fp, margin: float, pad: float, poses, clearances: dict | None = None) -> float:
    """The margin the geometric search keeps: ``margin + pad`` where the given poses (the start and
    goal) allow it, judged by the rule the search itself applies. The padding leaves the car's local
    planner room to deviate from the path; a pose closer than that keeps its place: the search margin
    is at most its clearance (less 1 mm), and if the search's own validity check (``state_checker``,
    the same predicate as ``is_free``) still refuses a pose at the padded margin, the search runs at
    the requested margin, at which the start check accepted it with that same predicate. So the
    padding never rejects a start or goal the start check accepted."""
    if clearances is None:
        clearances = {k: world.clearance(p, fp) for k, p in enumerate(poses)}
    padded = min(margin + pad, min(clearances.values()) - 1e-3)
    if padded <= margin:
        return float(margin)
    check = world.state_checker(fp, padded)
    if all(check(*(float(v) for v in p)) for p in poses):
        return float(padded)
    return float(margin)


def _plan(m: Map, robot: Robot, start, goal, path_opts: PathOptions | None = None,
          timing_opts: TimingOptions | None = None, stab_opts: StabilizerOptions | None = None,
          check_resolution: float = 0.05, world: CollisionWorld | None = None,
          car_opts: CarOptions | None = None) -> PlanResult:
    model = robot.model
    if not isinstance(m, Map):
        raise InputError("map", "a Map (nhstab.load_map(path))", type(m).__name__)
    if model.name not in PLANNABLE:
        raise InputError("robot", "one of " + ", ".join(PLANNABLE), model.name)
    for name, opts, cls in (("path_opts", path_opts, PathOptions), ("timing_opts", timing_opts, TimingOptions),
                            ("stab_opts", stab_opts, StabilizerOptions)):
        if opts is not None and not isinstance(opts, cls):
            raise InputError(name, f"a {cls.__name__} or None", type(opts).__name__)
    path_opts = (path_opts or PathOptions()).for_robot(robot).validated()
    timing_opts = (timing_opts or TimingOptions()).validated()
    if stab_opts is None:
        # the gain schedule's parameters are the robot's: errors about them name its keys
        with user_keys(robot.stabilizer_keys()):
            return _plan_with(m, robot, start, goal, path_opts, timing_opts,
                              StabilizerOptions(**robot.stabilizer.as_dict()).validated(), check_resolution, world, car_opts,
                              robot.key("stabilizer.delta"))
    return _plan_with(m, robot, start, goal, path_opts, timing_opts, stab_opts.validated(), check_resolution, world,
                      car_opts, "delta")


def _plan_with(m: Map, robot: Robot, start, goal, path_opts: PathOptions, timing_opts: TimingOptions,
               stab_opts: StabilizerOptions, check_resolution: float, world: CollisionWorld | None,
               car_opts: CarOptions | None, delta_key: str) -> PlanResult:
    """:func:`_plan` with its options checked; ``delta_key`` is how errors name the window length."""
    model, fp = robot.model, robot.footprint
    check_map_budget(m, path_opts.time_limit_s, path_opts.resolution)
    check_turning_radius("turning_radius", path_opts.turning_radius, m.bounds)
    if robot.trailers:       # the trailer's path, the rig checked (nhstab.planning.trailer)
        return plan_trailer(m, robot, start, goal, path_opts, timing_opts, stab_opts, check_resolution, world)
    start, goal = _pose(start, "start", robot), _pose(goal, "goal", robot)
    check_start_goal(start, goal)
    if path_opts.turning_radius < model.min_turning_radius - 1e-9:
        raise InputError("turning_radius", f"at least the {model.name}'s minimum turning radius "
                         f"{model.min_turning_radius:.4g} m", path_opts.turning_radius)
    world = world or CollisionWorld.from_map(m, "known")
    clearances = check_poses(m, fp, {"start": start, "goal": goal}, world=world)
    ends = {"start": start, "goal": goal}
    check = world.state_checker(fp, path_opts.margin)     # the search's own rule (see search_margin)
    for key, c in clearances.items():
        if c <= path_opts.margin or not check(*(float(v) for v in ends[key])):
            raise InputError(key, f"a pose at least the margin {path_opts.margin:.3g} m from the known obstacles",
                             np.round(ends[key], 4).tolist(), detail=f"clearance {c:.3g} m")
    started = time.perf_counter()
    car_opts = (car_opts or CarOptions()).validated()
    car = isinstance(model, SteeredCar)        # else the unicycle's planner (a model that turns in place)
    pad = EXACT_PAD if car and car_opts.nominal == "exact" else MARGIN_PAD[model.name]
    search_m = search_margin(world, fp, path_opts.margin, pad, [start, goal], clearances)
    base = {"planner": path_opts.planner, "start_clearance_m": clearances["start"],
            "goal_clearance_m": clearances["goal"]}
    if not car:
        path = plan_path(world, fp, start, goal, replace(path_opts, margin=search_m))
        if path.status != "exact":
            return _no_path(path, path_opts, base, f"OMPL: {path.planner_status}",
                            likely_cause(world, fp, start, goal, path_opts.margin, path_opts.turning_radius,
                                         path_opts.time_limit_s, model.name, search_m - path_opts.margin))
        return _from_path(path, robot, world, path_opts, timing_opts, stab_opts, car_opts, check_resolution,
                          base, started, delta_key)
    # cars: the paths the car planner offers, best guess first, until a nominal worth tracking
    # (tracking_metrics: duration, steering, gains within their bounds) or the budget is spent; the best
    # usable one otherwise
    info: dict = {}
    best, attempts = None, 0
    for path in car_paths(world, fp, model, start, goal, path_opts, pad, search_m, clearances,
                          car_opts, speed=timing_opts.max_speed, info=info):
        attempts += 1
        t0 = time.perf_counter()
        result = _from_path(path, robot, world, path_opts, timing_opts, stab_opts, car_opts, check_resolution,
                            base, started, delta_key)
        # what a nominal costs: the searches for another path leave this much of the budget
        info["reserve_s"] = max(info.get("reserve_s", 0.0), 1.2 * (time.perf_counter() - t0))
        result.metrics["attempts"] = attempts
        if best is None or _better(result, best):
            best = result
        if best.ok and best.metrics["tracking"]["worth_tracking"] or attempts >= car_opts.attempts:
            break
        if time.perf_counter() - started > float(path_opts.time_limit_s) - info["reserve_s"]:
            break
    if best is not None:
        best.metrics["attempts"] = attempts
        return best
    path = failed_path(path_opts, info, started)
    return _no_path(path, path_opts, base, path.planner_status,
                    likely_cause(world, fp, start, goal, path_opts.margin, path_opts.turning_radius,
                                 path_opts.time_limit_s, model.name, search_m - path_opts.margin))


def _better(a: PlanResult, b: PlanResult) -> bool:
    """Is plan a preferable to plan b? Usable first, then worth tracking, then the smaller excess over
    the bounds of :func:`tracking_metrics` (the larger of gain / bound and duration / bound)."""
    if a.ok != b.ok:
        return a.ok
    if not a.ok:
        return False

    def excess(r):
        t = r.metrics["tracking"]
        return max(t["max_gain_norm"] / t["gain_bound"], t.get("duration_s", 0.0) / t.get("duration_bound_s", math.inf))

    wa, wb = a.metrics["tracking"]["worth_tracking"], b.metrics["tracking"]["worth_tracking"]
    if wa != wb:
        return wa
    return excess(a) < excess(b)


def _no_path(path: GeometricPath, path_opts: PathOptions, base: dict, why: str, cause: dict | None = None) -> PlanResult:
    """A search that found no path; ``cause``: :func:`~nhstab.planning.guide.likely_cause` (kept as the
    metrics' ``likely_cause``)."""
    metrics = {**base, **_path_metrics(path)}
    if cause is not None:
        metrics["likely_cause"] = cause
    radius = f"{path_opts.turning_radius:.3g} m"
    if path.info.get("lock_radius_m", math.inf) < path_opts.turning_radius:
        radius += f", then {path.info['lock_radius_m']:.4g} m with unparking maneuvers"
    tried = (f"{path_opts.planner} in the {path_opts.space} space (turning radius {radius}, margin "
             f"{path_opts.margin:g} m) for {path_opts.time_limit_s:g} s with seed {path_opts.seed}")
    return PlanResult("no_path", f"no collision-free path found: tried {tried}; {why}", path, metrics=metrics)


def _path_metrics(path: GeometricPath) -> dict:
    out = {"planner_used": path.info.get("planner_used"), "planner_status": path.planner_status,
           "planning_time_s": path.planning_time_s, "validity_calls": path.validity_calls,
           "validity_us_per_state": 1e6 * path.validity_time_s / max(path.validity_calls, 1)}
    if "stages" in path.info:
        out["search"] = {k: path.info[k] for k in ("stages", "lock_radius_m", "search_margin_m", "open_margin_m",
                                                   "how", "start_maneuver_segments", "goal_maneuver_segments",
                                                   "failure", "lock") if k in path.info}
    return out


def _from_path(path: GeometricPath, robot: Robot, world: CollisionWorld, path_opts: PathOptions,
               timing_opts: TimingOptions, stab_opts: StabilizerOptions, car_opts: CarOptions,
               check_resolution: float, base: dict, started: float, delta_key: str = "delta") -> PlanResult:
    """The nominal along an exact path, its clearance check and its gain schedule. A window longer than
    the nominal is the goal's fault (too near the start for the window ``delta_key`` names); any other
    error about delta (e.g. a window too short for the nominal's time step) names delta itself."""
    model, fp = robot.model, robot.footprint
    metrics = {**base, **_path_metrics(path)}
    if not isinstance(model, SteeredCar):
        nominal, tinfo = unicycle_nominal(model, path, timing_opts)
    else:
        try:
            if car_opts.nominal == "exact":
                nominal, tinfo = exact_nominal(model, path, timing_opts, arc_speed=car_opts.arc_speed_mps)
            else:
                nominal, tinfo = car_nominal(model, path, timing_opts, world, fp, path_opts.margin,
                                             arc_speed=car_opts.arc_speed_mps)
        except CarPlanningError as exc:
            metrics["time_to_nominal_s"] = time.perf_counter() - started
            return PlanResult("infeasible", f"the path was found but could not be made feasible for the car: {exc}",
                              path, metrics=metrics)
    poses = nominal.x[:, pose_columns(model)]
    check = world.check_path(poses, fp, margin=path_opts.margin, resolution=check_resolution)
    u_lim = model.input_limits()
    steer = {}
    if "phi" in model.state_names:
        j = list(model.state_names).index("phi")
        steer = {"max_abs_steering_rad": float(np.max(np.abs(nominal.x[:, j]))),
                 "steering_limit_rad": float(model.max_steer),
                 "steering_reserve": steering_reserve(nominal, j, float(model.max_steer),
                                                      car_opts.steering_reserve_rad, path.info.get("lock"))}
    metrics.update({
        "length_m": path.length, "cusps": path.cusps, "max_curvature_per_m": path_curvature(path),
        "waypoints": len(path.waypoints), **tinfo, **steer,
        "min_clearance_m": check.min_clearance, "min_clearance_pose": check.min_clearance_pose,
        "clearance_check_resolution_m": check_resolution, "clearance_samples": check.samples,
        "max_abs_inputs": np.max(np.abs(nominal.u), axis=0), "input_limits": u_lim[:, 1],
    })
    if not check.clear:
        metrics["time_to_nominal_s"] = time.perf_counter() - started
        return PlanResult("not_clear", f"the nominal comes within {check.min_clearance:.3g} m of an obstacle "
                          f"(margin {path_opts.margin:.3g} m) at {np.round(check.min_clearance_pose, 3).tolist()}",
                          path, nominal, metrics=metrics)
    try:
        schedule = compute_schedule(nominal, stab_opts)
    except InputError as exc:
        if exc.argument != "delta" or not stab_opts.delta > nominal.duration:
            raise
        start, goal = path.samples[0], path.samples[-1]
        apart = float(math.hypot(*(goal[:2] - start[:2])))
        raise InputError("goal", f"far enough from the start for the stabilizer: the nominal to it lasts "
                         f"{nominal.duration:.3g} s, shorter than the gain schedule's window delta = "
                         f"{stab_opts.delta:g} s", np.round(goal, 4).tolist(),
                         detail=f"start and goal are {apart:.3g} m apart; a smaller {delta_key} would fit") from None
    except SingularGramianError as exc:
        metrics["time_to_nominal_s"] = time.perf_counter() - started
        return PlanResult("not_stabilizable", str(exc), path, nominal, metrics=metrics)
    metrics.update(schedule_metrics(robot, stab_opts, schedule, started))
    metrics["tracking"] = tracking_metrics(model, path, nominal, metrics["max_gain_norm"], timing_opts.max_speed)
    return PlanResult("ok", "exact path, feasible nominal, clear by the margin, gain schedule computed",
                      path, nominal, schedule, metrics)


def steering_reserve(nominal: Nominal, j: int, max_steer: float, reserve: float, lock: dict | None) -> dict:
    """Where the car's nominal leaves the feedback no steering reserve: the times its steering angle
    (state column ``j``) is beyond max_steer - ``reserve``, as intervals [t0, t1] of the nominal's grid
    and their total, with the lock the path's maneuvers use (``lock``: the car planner's record, see
    :mod:`nhstab.planning.parking`: angle and radius, and whether the full range was used)."""
    phi = np.abs(nominal.x[:, j])
    t = np.asarray(nominal.t, dtype=float)
    beyond = phi > max_steer - reserve + 1e-9
    intervals = []
    if beyond.any():
        edges = np.diff(np.r_[0, beyond.astype(np.int8), 0])
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1):
            intervals.append([float(t[a]), float(t[b])])
    out = {"reserve_rad": float(reserve), "reserved_lock_rad": float(max_steer - reserve),
           "full_range_used": bool(beyond.any()), "no_reserve_intervals_s": intervals,
           "no_reserve_time_s": float(sum(b - a for a, b in intervals))}
    if lock:
        out["lock"] = {k: lock[k] for k in ("angle_rad", "radius_m", "full_range", "full_range_angle_rad",
                                            "full_range_radius_m", "widened") if k in lock}
    return out


def path_curvature(path: GeometricPath) -> float:
    """The largest |dtheta / dsigma| along the path's samples [1/m]."""
    ds = np.diff(path.sigma)
    ok = ds > 1e-9
    if not ok.any():
        return 0.0
    return float(np.max(np.abs(np.diff(path.samples[:, 2])[ok] / ds[ok])))


#: a nominal is worth tracking when it lasts at most this times the reference time (:func:`tracking_metrics`)
DURATION_FACTOR = 1.5


def cusp_steering(model: Model, path: GeometricPath) -> list[tuple[float, float]]:
    """(steering angle arriving, leaving) at each cusp of a car's path: atan(L kappa d) of the sample
    intervals either side (d the direction of travel), within the steering limit."""
    L, lim = float(model.wheelbase), float(model.max_steer)
    ds = np.diff(path.sigma)
    kappa = np.where(ds > 1e-12, np.diff(path.samples[:, 2]) / np.maximum(ds, 1e-300), 0.0)
    d = path.direction
    out = []
    for c in np.flatnonzero(d[1:] != d[:-1]) + 1:
        before = float(np.clip(math.atan(L * kappa[c - 1] * d[c - 1]), -lim, lim))
        after = float(np.clip(math.atan(L * kappa[c] * d[c]), -lim, lim))
        out.append((before, after))
    return out


def tracking_metrics(model: Model, path: GeometricPath, nominal: Nominal, max_gain_norm: float,
                     max_speed: float | None = None) -> dict:
    """Is the nominal worth tracking? For cars (steering angle a state):

    - duration within ``DURATION_FACTOR`` x (length / max speed + the time to steer through the cusps
      at the steering-rate limit: sum over cusps |phi_after - phi_before| / max_steer_rate);
    - steering within its limit (max |phi| of the nominal <= max_steer);
    - the largest gain norm within the bound the stabilizer defaults were chosen for: the sweep's
      max ||K|| <= 50 (:data:`nhstab.control.GAIN_BOUND`).
    The unicycle gets the gain criterion only (it has no steering and turns on the spot at cusps)."""
    out = {"max_gain_norm": float(max_gain_norm), "gain_bound": GAIN_BOUND,
           "gain_within_bound": bool(max_gain_norm <= GAIN_BOUND)}
    if "phi" not in model.state_names:
        return out
    v = float(max_speed or model.input_limits()[0, 1])
    steer = cusp_steering(model, path)
    steer_time = sum(abs(b - a) for a, b in steer) / float(model.max_steer_rate)
    reference = path.length / v + steer_time
    j = list(model.state_names).index("phi")
    max_phi = float(np.max(np.abs(nominal.x[:, j])))
    out.update({"duration_s": nominal.duration, "reference_time_s": reference, "cusp_steering_time_s": steer_time,
                "duration_bound_s": DURATION_FACTOR * reference,
                "duration_within_bound": bool(nominal.duration <= DURATION_FACTOR * reference),
                "max_abs_steering_rad": max_phi, "steering_limit_rad": float(model.max_steer),
                "steering_within_limit": bool(max_phi <= float(model.max_steer) + 1e-9)})
    out["worth_tracking"] = bool(out["duration_within_bound"] and out["steering_within_limit"]
                                 and out["gain_within_bound"])
    return out


def _pose(value, name: str, robot: Robot) -> np.ndarray:
    """A start or goal pose (x, y, theta) of a single-body robot: the rule of
    :meth:`~nhstab.robot.Robot.configuration` (a pose, or the full state with phi = 0)."""
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise InputError(name, robot.start_goal_text(), value)
    arr = robot.configuration(value, name)
    check_headings(name, arr)
    return arr


__all__ = ["plan", "PlanResult", "check_map_budget", "check_start_goal", "PathOptions", "TimingOptions", "CarOptions",
           "GeometricPath", "plan_path", "path_length", "search_margin", "tracking_metrics", "DURATION_FACTOR",
           "PLANNERS", "SPACES", "PLANNABLE", "pose_columns", "default_turning_radius", "min_turning_radius",
           "check_plannable"]
