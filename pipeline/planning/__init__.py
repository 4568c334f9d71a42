"""Planning: map + robot + start/goal -> a feasible, collision-free, stabilizable nominal trajectory.

Stages: geometric path in OMPL's Reeds-Shepp / Dubins space (``geometric``, the only module importing
ompl) with the FCL world as validity checker; time-parameterisation into x0(t), u0(t) (``timing``);
a clearance re-check of the nominal with FCL; the gain schedule of the stabilizer along it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..collision import CollisionWorld, check_poses
from ..control import GainSchedule, StabilizerOptions, compute_schedule
from ..errors import InputError, SingularGramianError
from ..maps.base import Map
from ..models import Model
from ..nominal import Nominal
from ..robot import Robot, default_robot, make_robot
from .geometric import PLANNERS, SPACES, GeometricPath, PathOptions, path_length, plan_path
from .timing import TimingOptions, unicycle_nominal

#: the geometric planner keeps this much more than the requested margin, so that the nominal still
#: clears the margin: the unicycle's follows the sampled path to a few millimetres. Cars get more room
#: for their steering pieces: the phased sinusoids wandered 0.1-0.5 m from the path (up to 1.1 m),
#: the constant-v1 pieces used first now stay within about 0.012 m (measured on the bundled warehouse,
#: parking lot and 10 Bench-MR parking3 problems), but a piece may still fall back to the phased ones
MARGIN_PAD = {"unicycle": 0.02, "rwd_car": 0.15, "fwd_car": 0.15}
PLANNABLE = ("unicycle", "rwd_car", "fwd_car", "car_trailer")


def pose_columns(model: Model) -> list[int]:
    """Indices of (x, y, theta) in the model's state."""
    names = list(model.state_names)
    return [names.index("x"), names.index("y"), names.index("theta")]


def min_turning_radius(model: Model) -> float:
    """Both cars: theta' = tan(phi) s / L for rear-axle speed s, so R_min = L / tan(max_steer)."""
    return float(model.wheelbase / math.tan(model.max_steer))


def default_turning_radius(model: Model) -> float:
    """The planning turning radius of the model's built-in robot (see :mod:`nhstab.robot`)."""
    return default_robot(model.name, **model.params()).turning_radius


@dataclass
class PlanResult:
    """status: "ok", or why there is no usable plan: "no_path" (the planner found none in its budget),
    "infeasible" (the car's local planner could not follow the path), "not_clear" (the nominal does not
    keep the margin), "not_stabilizable" (singular gramian)."""

    status: str
    message: str
    path: GeometricPath | None
    nominal: Nominal | None = None
    schedule: GainSchedule | None = None
    metrics: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def plan(m: Map, robot: Robot, *args, **kwargs) -> PlanResult:
    """Plan a nominal trajectory of ``robot`` from start to goal on the map's known obstacles:
    ``plan(m, robot, start, goal, path_opts=None, timing_opts=None, stab_opts=None,
    check_resolution=0.05, world=None)``.

    ``robot`` is a :class:`~nhstab.robot.Robot` (footprint, turning radius, margin and stabilizer
    defaults come from it where the options leave them None). The older form
    ``plan(m, model, footprint, start, goal, ...)`` is still accepted: the model's built-in robot
    with that footprint.

    Bad requests (start or goal outside the bounds or in collision, bad options, a model this planner
    does not handle) raise :class:`InputError`; a request the planner cannot satisfy returns a result
    whose ``status`` says why.
    """
    if isinstance(robot, Model):
        if not args:
            raise InputError("footprint", "a Footprint after the model (or pass a Robot)", None)
        fp, *args = args
        robot = make_robot(robot, footprint=fp)
    if not isinstance(robot, Robot):
        raise InputError("robot", "a Robot (nhstab.robot.make_robot) or a Model and a Footprint",
                         type(robot).__name__)
    return _plan(m, robot, *args, **kwargs)


def _plan(m: Map, robot: Robot, start, goal, path_opts: PathOptions | None = None,
          timing_opts: TimingOptions | None = None, stab_opts: StabilizerOptions | None = None,
          check_resolution: float = 0.05, world: CollisionWorld | None = None) -> PlanResult:
    model, fp = robot.model, robot.footprint
    if model.name not in PLANNABLE:
        raise InputError("robot", "one of " + ", ".join(PLANNABLE), model.name)
    path_opts = (path_opts or PathOptions()).for_robot(robot).validated()
    timing_opts = (timing_opts or TimingOptions()).validated()
    stab_opts = (stab_opts or StabilizerOptions(**robot.stabilizer)).validated()
    if model.name == "car_trailer":       # the trailer's path, the rig checked (nhstab.planning.trailer)
        from .trailer import plan_trailer

        return plan_trailer(m, robot, start, goal, path_opts, timing_opts, stab_opts, check_resolution, world)
    start, goal = _pose(start, "start", model), _pose(goal, "goal", model)
    if model.name != "unicycle" and path_opts.turning_radius < min_turning_radius(model) - 1e-9:
        raise InputError("turning_radius", f"at least the {model.name}'s minimum turning radius "
                         f"{min_turning_radius(model):.4g} m", path_opts.turning_radius)
    world = world or CollisionWorld.from_map(m, "known")
    clearances = check_poses(m, fp, {"start": start, "goal": goal}, world=world)
    for key, c in clearances.items():
        if c <= path_opts.margin:
            raise InputError(key, f"a pose at least the margin {path_opts.margin:g} m from the known obstacles",
                             np.round(start if key == "start" else goal, 4).tolist(), detail=f"clearance {c:.3g} m")
    started = time.perf_counter()
    # the extra room, as far as the start and goal allow
    pad_margin = min(path_opts.margin + MARGIN_PAD[model.name], min(clearances.values()) - 1e-3)
    search = replace(path_opts, margin=max(path_opts.margin, pad_margin))
    path = plan_path(world, fp, start, goal, search)
    metrics = {"planner": path_opts.planner, "planner_used": path.info.get("planner_used"),
               "planner_status": path.planner_status, "planning_time_s": path.planning_time_s,
               "validity_calls": path.validity_calls,
               "validity_us_per_state": 1e6 * path.validity_time_s / max(path.validity_calls, 1),
               "start_clearance_m": clearances["start"], "goal_clearance_m": clearances["goal"]}
    if path.status != "exact":
        tried = (f"{path_opts.planner} in the {path_opts.space} space (turning radius "
                 f"{path_opts.turning_radius:g} m, margin {path_opts.margin:g} m) for {path_opts.time_limit_s:g} s "
                 f"with seed {path_opts.seed}")
        return PlanResult("no_path", f"no collision-free path found: tried {tried}; OMPL: {path.planner_status}",
                          path, metrics=metrics)
    if model.name == "unicycle":
        nominal, tinfo = unicycle_nominal(model, path, timing_opts)
    else:
        from .cars import CarPlanningError, car_nominal

        try:
            nominal, tinfo = car_nominal(model, path, timing_opts, world, fp, path_opts.margin)
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
                 "steering_limit_rad": float(model.max_steer)}
    metrics.update({
        "length_m": path.length, "cusps": path.cusps, "max_curvature_per_m": 1.0 / path_opts.turning_radius,
        "waypoints": len(path.waypoints), **tinfo, **steer,
        "min_clearance_m": check.min_clearance, "min_clearance_pose": check.min_clearance_pose,
        "clearance_check_resolution_m": check_resolution, "clearance_samples": check.samples,
        "max_abs_inputs": np.max(np.abs(nominal.u), axis=0), "input_limits": u_lim[:, 1],
    })
    if not check.clear:
        metrics["time_to_nominal_s"] = time.perf_counter() - started
        return PlanResult("not_clear", f"the nominal comes within {check.min_clearance:.3g} m of an obstacle "
                          f"(margin {path_opts.margin:g} m) at {np.round(check.min_clearance_pose, 3).tolist()}",
                          path, nominal, metrics=metrics)
    try:
        schedule = compute_schedule(nominal, stab_opts)
    except SingularGramianError as exc:
        metrics["time_to_nominal_s"] = time.perf_counter() - started
        return PlanResult("not_stabilizable", str(exc), path, nominal, metrics=metrics)
    d = schedule.diagnostics
    metrics.update({"robot": robot.name, "stabilizer": stab_opts.describe(), "h_min_eigenvalue": d["h_min_eigenvalue"],
                    "h_min_eigenvalue_time_s": d["h_min_eigenvalue_time_s"], "max_gain_norm": d["max_gain_norm"],
                    "p_m": d["p_m"], "p_M": d["p_M"], "rate_bound": d["rate_bound"],
                    "time_to_nominal_s": time.perf_counter() - started})
    return PlanResult("ok", "exact path, feasible nominal, clear by the margin, gain schedule computed",
                      path, nominal, schedule, metrics)


def _pose(value, name: str, model: Model) -> np.ndarray:
    """A start or goal pose: (x, y, theta) finite numbers (a full state of the model is also
    accepted: its pose columns are used)."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, "a pose of three numbers (x, y, theta)", value) from None
    if arr.shape == (model.n,) and model.n != 3:
        arr = arr[pose_columns(model)]
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(name, "a pose of three finite numbers (x, y, theta)",
                         value if arr.size < 10 else f"shape {arr.shape}")
    return arr


__all__ = ["plan", "PlanResult", "PathOptions", "TimingOptions", "GeometricPath", "plan_path", "path_length",
           "PLANNERS", "SPACES", "PLANNABLE", "pose_columns", "default_turning_radius", "min_turning_radius"]
