"""The composite controller (Walsh et al. 1992, section 4) on a map: plan, stabilize, sense, monitor,
replan.

One run, step by step at the controller rate 1/T (zero-order hold):

1. **Plan** a nominal from the start to the goal on the robot's map (the known obstacles) with the
   planner of :mod:`nhstab.planning`, and the feedback law along it. The nominal is planned for
   the robot with its input limits scaled by ``headroom`` (default 0.8), so that the feedback has
   the rest of the real limits to work with.
2. Every control period: the robot's true state x is *measured* with sensor noise, y = x + n; the
   law gives u = u_ff - K(tau) (y - x0(tau)) (u_ff: the mean of u0 over the hold interval), clipped
   to the robot's input limits; the plant is integrated over the period under that constant input;
   a process disturbance (Wiener increments, and impulses at given times) is added to x.
3. **Sensing** at the sensor rate from the true pose: unknown obstacles hit by a beam are added to
   the robot's map (:mod:`nhstab.sensing`).
4. **Monitoring**, with FCL: (a) at the monitor rate, the remaining nominal over the look-ahead
   horizon against the *discovered* obstacles with the plan's margin (the known ones were checked
   when it was planned); a conflict triggers a replan. (b) at every control sample, the true pose
   against all real obstacles: a collision ends the run.
5. **Replanning** from the measured state to the goal on the known + discovered obstacles. While it
   runs the robot stops (u = 0) for ``replan.pause_s`` of simulated time (a fixed budget, so that a
   run is reproducible; the real latency, detection to the new feedback law ready, is recorded, and
   the time of the new plan's error tube, computed after it, beside). A
   failed attempt is retried with the next seed after another pause (from the third attempt on with
   ``replan.budget_growth`` times the budget); ``replan.max_attempts`` failures in a row end the run
   ("replan_failed"). The first plan is retried the same way (without pauses) before the run ends
   "no_plan". If the measured start is closer to an obstacle than the
   margin (the robot came close before it saw the obstacle), the replan uses half its clearance as
   margin and records that.
6. **End**: at the end of the last nominal the goal is "reached" if the position and heading errors
   are within the tolerances, else the run ends "missed_goal". Other ends: "collision", "timed_out"
   (simulated time beyond ``max_time_s``, or more than ``replan.max_replans`` replans),
   "numerical_failure" (a non-finite state or input), "no_plan" (no first plan), "interrupted"
   (Ctrl-C; what was computed is kept).

Randomness: one root seed; numpy SeedSequence children for the initial error, the sensor noise, the
process noise and the planner (one OMPL seed per planning call), all recorded.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .. import bodies
from ..collision import CollisionWorld, interpolate_poses
from ..control import StabilizerOptions
from ..errors import InputError, NumericalError, PipelineError, user_keys
from ..geometry import Footprint, wrap_angle
from ..interrupts import holding_interrupts
from ..limits import MAX_CONTROL_PERIODS
from ..maps import resolve_poses
from ..maps.base import Circle, Map
from ..models import Model
from ..planning import PathOptions, PlanResult, TimingOptions, check_map_budget, check_start_goal, plan, pose_columns
from ..robot import Robot, map_robot_where, resolve_robot
from ..sensing import RangeSensor
from ..tubes.base import tube_line, verdict
from ..tubes.fit import AUTO_MARGIN_START, SEVERAL_BODIES, choose_gains, fit_plan, plan_with_auto_margin
from ..tubes.predict import predict_tube
from ..tubes.sampled import cusp_stops, remaining_law, sampled_tube
from .config import RunOptions, distance_factor, position_states
from .controllers import FeedbackLaw, build_law
from .plant import Plant
from .seeds import planner_seed, seed_for

STATUSES = ("reached", "collision", "replan_failed", "timed_out", "missed_goal", "numerical_failure", "no_plan",
            "interrupted", "not_certified")
#: modes of the log: following a nominal, stopped while replanning, stopped at the end
MODES = ("track", "replanning", "done")


@dataclass
class PlanRecord:
    """One nominal of a run: id, when it became active (simulated time), why it was made."""

    id: int
    trigger: str                 # "initial" | "conflict"
    t_detect: float              # when the need was detected
    t_start: float               # when the robot began to follow it
    start: np.ndarray            # (3,) the pose it was planned from (measured)
    seed: int
    margin: float
    attempts: list               # one dict per planning call: seed, status, message, latency_s
    result: PlanResult | None = None
    law: FeedbackLaw | None = None
    conflict: dict | None = None  # for a replan: the first conflicting nominal pose and its clearance
    tube: object | None = None    # the predicted error tube (nhstab.tubes.Tube)
    verdict_line: str | None = None  # what the run said of its tube when it adopted the plan
    #: at each cusp: the rest of the maneuver's tube from the measured state, and a replan if it was not clear
    cusp_checks: list = field(default_factory=list)

    @property
    def nominal(self):
        return self.law.nominal if self.law is not None else None


@dataclass
class RunLog:
    """Per control sample k (time t_k): the true state, the measurement, the reference, the inputs."""

    t: list = field(default_factory=list)
    x: list = field(default_factory=list)
    y: list = field(default_factory=list)
    x0: list = field(default_factory=list)
    u: list = field(default_factory=list)
    u0: list = field(default_factory=list)
    plan_id: list = field(default_factory=list)
    mode: list = field(default_factory=list)

    def arrays(self, n: int, m: int) -> dict:
        def arr(v, width):
            return np.array(v, dtype=float).reshape(-1, width)

        return {"t": np.array(self.t, dtype=float), "x": arr(self.x, n), "y": arr(self.y, n), "x0": arr(self.x0, n),
                "u": arr(self.u, m), "u0": arr(self.u0, m), "plan_id": np.array(self.plan_id, dtype=int),
                "mode": np.array(self.mode, dtype=int)}


@dataclass
class RunResult:
    status: str
    message: str
    model: Model
    footprint: Footprint
    map: Map
    start: np.ndarray
    goal: np.ndarray
    options: RunOptions
    plans: list
    log: dict                         # arrays, see RunLog.arrays
    discovered: list                  # [{"index": i, "time": t, "pose": [...]}]
    collision: dict | None
    seeds: dict
    wall_time_s: float
    info: dict = field(default_factory=dict)
    #: the FCL world of every real obstacle (known and unknown) the run was checked against
    world: CollisionWorld | None = None
    #: the robot as used (model, footprint, margin, stabilizer defaults)
    robot: Robot | None = None

    @property
    def ok(self) -> bool:
        return self.status == "reached"


#: the input limits (scaled by RunOptions.headroom for planning). The steering angle is not scaled:
#: cars already plan at 1.25 times their minimum turning radius, which keeps the steering angle of
#: the path's arcs at or below atan(0.8 tan(max_steer)), 0.11 rad inside the rwd car's limit
_LIMITS = ("max_speed", "max_turn_rate", "max_steer_rate")


def derated(model: Model, factor: float) -> Model:
    """The same robot with its input limits scaled by ``factor``: nominals planned for it leave the
    rest of the real limits to the feedback."""
    params = {f.name: getattr(model, f.name) for f in dataclasses.fields(model) if f.init}
    for key in _LIMITS:
        if key in params:
            params[key] = params[key] * factor
    return type(model)(**params)


def _bounding_circle(shape) -> tuple[np.ndarray, float]:
    if isinstance(shape, Circle):
        return np.asarray(shape.center, dtype=float), float(shape.radius)
    v = np.asarray(shape.vertices, dtype=float)
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return c, float(np.max(np.hypot(*(v - c).T)))


def check_run(m: Map, robot: Robot, opts: RunOptions) -> RunOptions:
    """Everything a run of ``robot`` on ``m`` with ``opts`` checks before it plans: the options, the
    map against the planning budget, the planner's options for the robot (its turning radius), the
    gain schedule of the planner (the robot's stabilizer) and of the law (the controller's values over
    the robot's) against the nominal's time step 1 / rate_hz, and ``planning.margin: auto`` only for a
    robot of one body. Errors name the run option (``controller.delta``, ``planning.margin``) or the
    robot's key (``robot.stabilizer.delta``) the value comes from. Returns the validated options."""
    model = robot.model
    opts = opts.validated(model.state_names, model.m)
    check_map_budget(m, opts.planning.time_limit_s)
    if len(robot.footprints) > 1 and opts.planning.margin == "auto":
        raise InputError("planning.margin", SEVERAL_BODIES, "auto")
    p = opts.planning
    radius_key = "planning.turning_radius" if p.turning_radius is not None else robot.key("turning_radius")
    with user_keys({"turning_radius": radius_key, "space": "planning.space", "planner": "planning.planner",
                    "time_limit_s": "planning.time_limit_s", "margin": "planning.margin"}):
        path = PathOptions(space=p.space, turning_radius=p.turning_radius, planner=p.planner,
                           time_limit_s=p.time_limit_s, margin=0.0 if not isinstance(p.margin, (int, float)) else
                           p.margin, guide=p.guide).for_robot(robot).validated()
        if path.turning_radius < robot.min_turning_radius - 1e-9:
            raise InputError("turning_radius", f"at least the {model.name}'s minimum turning radius "
                             f"{robot.min_turning_radius:.4g} m", path.turning_radius)
        if robot.trailers and path.space != "reeds_shepp":
            raise InputError("space", "reeds_shepp (a car with a trailer reverses)", path.space)
    if robot.trailers > 1:
        raise InputError(robot.key("hitch_lengths"), "one hitch length (nhstab plans a car with one trailer)",
                         list(model.hitch_lengths))
    step = 1.0 / opts.rate_hz                 # the nominal's grid step (at most this)
    with user_keys(robot.stabilizer_keys()):
        StabilizerOptions(**robot.stabilizer.as_dict()).validated().check_step(step)
    ctrl = opts.controller
    if ctrl.kind == "gramian" and ctrl.gains != "auto":
        with user_keys(ctrl.stabilizer_keys(robot)):
            ctrl.stabilizer(robot.stabilizer.as_dict()).validated().check_step(step)
    return opts



class _Stop(Exception):
    def __init__(self, status: str, message: str):
        super().__init__(message)
        self.status, self.message = status, message


class CompositeRun:
    """State of one run; :func:`execute` drives it."""

    def __init__(self, m: Map, robot: Robot, start, goal, opts: RunOptions):
        model, fp = robot.model, robot.footprint
        # the planning configurations (x, y, theta, and a car_trailer's trailer headings): the rule of
        # Robot.configuration, so that nothing given is dropped and every record holds what was planned
        start, goal = robot.configuration(start, "start"), robot.configuration(goal, "goal")
        check_start_goal(start, goal)
        self.m, self.robot, self.model, self.fp = m, robot, model, fp
        opts = check_run(m, robot, opts)
        if opts.planning.margin is None:
            opts = dataclasses.replace(opts, planning=dataclasses.replace(opts.planning, margin=robot.margin))
        if opts.planning.space is None:
            opts = dataclasses.replace(opts, planning=dataclasses.replace(opts.planning, space=robot.planning_space))
        self.opts = opts
        self.start, self.goal = start, goal
        #: the planning configuration of the start (x, y, theta, and a car_trailer's trailer headings)
        self._start_configuration = start.copy()
        self.T = 1.0 / opts.rate_hz
        self.plant = Plant(model, self.T, opts.substeps)
        self.plan_model = derated(model, opts.headroom) if opts.headroom < 1.0 else model
        self.plan_robot = robot.with_model(self.plan_model)
        self.pose_idx = pose_columns(model)
        #: a robot of several bodies (a car with trailers): every body is checked, the hitch angles too
        self.multibody = len(robot.footprints) > 1
        self.known = CollisionWorld.from_map(m, "known")
        self.truth = CollisionWorld.from_map(m, "all")
        self.robot_world = self.known
        self.discovered_world: CollisionWorld | None = None
        self.discovered: list = []
        self.sensor = RangeSensor(m, opts.sensor)
        self.rng_sensor = np.random.default_rng(seed_for(opts.seed, "sensor"))
        self.rng_process = np.random.default_rng(seed_for(opts.seed, "process"))
        self.sigma_sensor = opts.noise.vector("sensor", model.state_names)
        self.sigma_process = opts.noise.process_step_std(model.state_names, self.T)
        # per metre travelled: the states whose move scales each increment (None: per second)
        self.process_xy = position_states(model.state_names) if opts.noise.per_metre else None
        self.impulses = opts.noise.impulse_list(model.state_names)
        lim = model.input_limits()
        self.u_lo, self.u_hi = lim[:, 0], lim[:, 1]
        self.stab_defaults = robot.stabilizer.as_dict()
        self.plans: list[PlanRecord] = []
        self.planning_calls = 0
        self.log = RunLog()
        self.collision = None
        self.k = 0
        self._margin_now = None
        #: wall time of each cusp check's tube [s]; replans tried at cusps
        self.cusp_timing: list = []
        self.cusp_replans = 0
        self._replan_at_cusp = False
        #: called with one line when a plan becomes active (its tube's verdict), or None
        self.notify = None

    # ---- planning ---------------------------------------------------------------------------
    def _path_options(self, seed: int, margin: float, budget_factor: float = 1.0) -> PathOptions:
        p = self.opts.planning
        radius = p.turning_radius if p.turning_radius is not None else self.robot.turning_radius
        return PathOptions(space=p.space, turning_radius=radius, planner=p.planner,
                           time_limit_s=p.time_limit_s * budget_factor, seed=seed, margin=margin, guide=p.guide)

    def _plan_once(self, start_pose: np.ndarray, attempt_index: int = 0):
        """One planning call (path, nominal, gains, error tube) from start_pose, the ``attempt_index``-th
        in a row (later attempts get a larger budget); returns (attempt record, result, law, margin used,
        tube). With ``planning.margin: auto`` the call is the tube loop of
        :func:`nhstab.tubes.plan_with_auto_margin` (its rounds share the call's seed)."""
        seed = planner_seed(self.opts.seed, self.planning_calls)
        self.planning_calls += 1
        auto = self.opts.planning.margin == "auto"
        margin = AUTO_MARGIN_START if auto else self.opts.planning.margin
        factor = self.opts.replan.budget_factor(attempt_index)
        attempt = {"seed": seed, "margin": margin, "time_limit_s": self.opts.planning.time_limit_s * factor}
        started = time.perf_counter()
        clearance = math.inf
        if self.plans:
            # the robot may have come closer to an obstacle than the margin before it saw it
            clearance = self._clearance(self.robot_world, start_pose)
            if 0 < clearance <= margin:
                margin = 0.5 * clearance
                attempt.update(margin=margin, margin_reduced_from=attempt["margin"], start_clearance_m=clearance)
        result, law, tube, law_ready = None, None, None, None
        try:
            if clearance <= 0:
                raise InputError("start", "a pose clear of the obstacles", start_pose.round(3).tolist(),
                                 detail=f"clearance {clearance:.3g} m")
            if auto:
                cap = min(clearance, self.robot_world.clearance(self.goal, self.fp)) - 1e-3
                result, law, tube, record = plan_with_auto_margin(
                    lambda mg: self._plan_at(start_pose, seed, mg, attempt, factor), self._tube_of,
                    self.robot_world, self.fp, cap=cap, start=margin)
                attempt["margin_auto"] = record
                if record["margin_m"] is not None:
                    margin = attempt["margin"] = record["margin_m"]
            else:
                # the latency ends with the feedback law: a fixed-margin run only reports the tube, so
                # it is computed after and timed beside (with margin auto the tube is in the loop above)
                result, law = self._plan_at(start_pose, seed, margin, attempt, factor)
                law_ready = time.perf_counter()
                tube = self._tube_of(law)
                if law is not None:
                    attempt["tube_s"] = time.perf_counter() - law_ready
            if self.opts.planning.fit and law is not None and tube is not None and tube.certified is False:
                fit_started = time.perf_counter()
                cap = min(self._clearance(self.robot_world, start_pose),
                          self._clearance(self.robot_world, self.goal)) - 1e-3
                result, law, tube, margin, record = fit_plan(
                    lambda mg, k: self._plan_at(start_pose, (seed + k) % (2**31 - 1), mg, attempt, factor),
                    self._tube_of, self.robot_world, self.fp, margin=margin, cap=cap, first=(result, law, tube))
                self._margin_now = attempt["margin"] = margin
                attempt["fit"] = record
                attempt["fit_s"] = time.perf_counter() - fit_started
            if law is not None and tube is None:
                attempt["tube"] = "none: the linearised closed loop diverges under these gains"
            if law is not None:
                attempt.update(status="ok", message=result.message)
            else:
                attempt.update(status=result.status, message=result.message)
                if "likely_cause" in result.metrics:
                    attempt["likely_cause"] = result.metrics["likely_cause"]
        except InputError as exc:
            if not self.plans:
                raise
            attempt.update(status="bad_request", message=str(exc))
        except PipelineError as exc:   # singular gramian for another window, Riccati failure
            attempt.update(status="not_stabilizable", message=str(exc))
        attempt["latency_s"] = (law_ready if law_ready is not None else time.perf_counter()) - started
        return attempt, (result if law is not None else None), law, margin, tube

    def _plan_at(self, start_pose, seed: int, margin: float, attempt: dict, budget_factor: float = 1.0):
        """plan() at ``margin`` and the feedback law along the nominal (``controller.gains: auto``: chosen
        by the tube, recorded in the attempt)."""
        self._margin_now, self._start_now = margin, start_pose
        p = self.opts.planning
        # the nominal's speed is the robot's limit scaled by headroom: a headroom other than the
        # default is named for it, else the robot's limit
        speed_key = ("headroom", self.opts.headroom) if self.opts.headroom != RunOptions().headroom \
            else (self.robot.key("max_speed"), getattr(self.model, "max_speed", None))
        with user_keys({"max_speed": speed_key,
                        "turning_radius": "planning.turning_radius" if p.turning_radius is not None
                        else self.robot.key("turning_radius")}):
            result = plan(self.m, self.plan_robot, start_pose, self.goal,
                          self._path_options(seed, margin, budget_factor), TimingOptions(dt=self.T),
                          world=self.robot_world)
        if not result.ok:
            return result, None
        if self.opts.controller.gains == "auto":
            law, record = choose_gains(result.nominal, self.stab_defaults, lambda lw: self._tube_of(lw, world=False),
                                       self.opts.controller.window)
            attempt["gains_auto"] = record
        else:
            with user_keys(self.opts.controller.stabilizer_keys(self.robot)):
                law = build_law(result.nominal, self.opts.controller, self.stab_defaults, result.schedule,
                                robot=self.robot)
        return result, law

    def _tube_of(self, law: FeedbackLaw, world=True, margin: float | None = None):
        """The error tube of a nominal of this run (:func:`nhstab.tubes.predict_tube`, of the kind
        ``tube.kind``) under the run's noise, rate and robot, certified against the obstacles the robot
        knows of now, with its verdict (:func:`nhstab.tubes.verdict`). The first plan starts from the
        initial error (with the impulses); a replan from a measured state after the pause: sensor noise
        plus the pause's process noise (impulses are not included). ``world`` False: an uncertified
        linear tube (``--gains auto`` compares settings with it)."""
        if law is None:
            return None
        names = self.model.state_names
        initial = None
        if self.plans:
            # a replan after a conflict starts where the robot stood still for the pause; one at a cusp
            # starts at once (the robot does not wait for it)
            pause = 0.0 if self._replan_at_cusp else self.opts.replan.pause_s
            # (a disturbance per metre travelled does not act while the robot stands)
            still = 0.0 if self.opts.noise.per_metre else pause
            initial = np.diag(self.opts.noise.vector("sensor", names) ** 2
                              + self.opts.noise.vector("process", names) ** 2 * still)
        to = self.opts.tube
        try:
            # a robot of several bodies is certified body by body on rollouts (predict_tube)
            certify = world
            tube = predict_tube(law, self.opts.noise, self.fp, self.robot_world if certify else None,
                                rate_hz=self.opts.rate_hz, substeps=self.opts.substeps, model=self.model,
                                initial_cov=initial, impulses=not self.plans, probability=to.probability,
                                kind=to.kind if world else "linear", confidence=to.confidence,
                                discards=to.discards, robot=self.robot)
        except NumericalError:
            if not world:
                raise                  # choose_gains skips the setting
            return None                # no tube: the loop diverges (the run says so)
        if world:
            cap = None
            if certify and getattr(self, "_start_now", None) is not None:
                cap = min(self._clearance(self.robot_world, self._start_now),
                          self._clearance(self.robot_world, self.goal))
            verdict(tube, self.robot_world if certify else None, self.fp,
                    margin if margin is not None else self._margin_now, cap=cap)
        return tube

    # ---- the loop -----------------------------------------------------------------------------
    def _record(self, t, x, y, x0, u, u0, plan_id, mode):
        lg = self.log
        lg.t.append(t)
        lg.x.append(x.copy())
        lg.y.append(y)
        lg.x0.append(x0)
        lg.u.append(u)
        lg.u0.append(u0)
        lg.plan_id.append(plan_id)
        lg.mode.append(mode)

    def _measure(self, x):
        return x + self.sigma_sensor * self.rng_sensor.standard_normal(self.model.n)

    def _advance(self, x, u, t):
        """The true state one period later: plant, disturbance, impulses; collision check."""
        x_new = self.plant.step(x, u)
        w = self.sigma_process * self.rng_process.standard_normal(self.model.n)
        if self.process_xy is not None:      # std intensity * sqrt(distance the position moved this period)
            ix, iy = self.process_xy
            dx, dy = x_new[ix] - x[ix], x_new[iy] - x[iy]
            w = w * distance_factor(dx * dx + dy * dy)
        x = x_new + w
        t_next = (self.k + 1) * self.T
        while self.impulses and self.impulses[0][0] < t_next - 1e-12:
            x = x + self.impulses.pop(0)[1]
        if not np.all(np.isfinite(x)):
            raise _Stop("numerical_failure", f"the state became non-finite at t = {t_next:.3f} s")
        self.k += 1
        self._check_collision(x, t_next)
        return x

    def _check_collision(self, x, t):
        pose = x[self.pose_idx]
        if not self.multibody:
            if self.truth.in_collision(pose, self.fp):
                self.collision = {"time_s": t, "pose": pose.tolist(), "obstacles": self.truth.hits(pose, self.fp)}
                raise _Stop("collision", f"collision at t = {t:.2f} s at pose {np.round(pose, 3).tolist()}")
            return
        # a jackknife (a hitch angle beyond the limit) is a collision of the rig with itself
        hitch = self.model.hitch_angles(x)
        over = np.flatnonzero(np.abs(hitch) > self.model.jackknife_limit)
        if len(over):
            i = int(over[0])
            self.collision = {"time_s": t, "pose": pose.tolist(), "kind": "jackknife", "body": i + 1,
                              "hitch_angle_rad": float(hitch[i])}
            raise _Stop("collision", f"jackknife at t = {t:.2f} s: hitch angle {i + 1} is {hitch[i]:.3f} rad, beyond "
                                     f"the limit {self.model.jackknife_limit:g} rad (pose {np.round(pose, 3).tolist()})")
        b = bodies.collides(self.truth, self.robot, x)
        if b is not None:
            where = self.robot.body_poses(x)[b]
            self.collision = {"time_s": t, "pose": pose.tolist(), "kind": "obstacle", "body": b,
                              "body_pose": where.tolist(), "obstacles": self.truth.hits(where, self.robot.footprints[b])}
            name = "the car" if b == 0 else f"trailer {b}"
            raise _Stop("collision", f"collision of {name} at t = {t:.2f} s at pose {np.round(where, 3).tolist()}")

    def _clearance(self, world: CollisionWorld, config) -> float:
        """The robot's clearance at a planning configuration (the smallest over its bodies)."""
        return bodies.configuration_clearance(world, self.robot, config)

    def _sense(self, x, t):
        scan = self.sensor.scan(x[self.pose_idx])
        seen = {d["index"] for d in self.discovered}
        new = sorted(i for i in scan.revealed if i not in seen)
        if not new:
            return False
        for i in new:
            self.discovered.append({"index": int(i), "time_s": t, "pose": x[self.pose_idx].tolist()})
        shapes = [self.m.unknown_obstacles[d["index"]] for d in self.discovered]
        self.robot_world = self.known.with_obstacles(shapes)
        self.discovered_world = CollisionWorld(shapes, walls=False)
        self.discovered_discs = [_bounding_circle(s) for s in shapes]
        return True

    def _conflict(self, rec: PlanRecord, tau: float) -> dict | None:
        """The first pose of the remaining nominal within the horizon that is not clear of the
        discovered obstacles by the plan's margin (FCL), or None. Only poses within reach of a
        discovered obstacle's bounding circle go to FCL. With ``planning.margin: auto`` the margin at
        each pose is the larger of the plan's margin and its error tube's reach there: a newly seen
        obstacle must clear the tube, as the known ones were certified to."""
        if not self.discovered:
            return None
        nom = rec.nominal
        i0, i1 = np.searchsorted(nom.t, [tau, tau + self.opts.monitor.horizon_s])
        if self.multibody:          # every body, at the plan's margin (the tube reach is for one body)
            return self._conflict_bodies(rec, nom.x[max(i0 - 1, 0):i1 + 1])
        lo = max(i0 - 1, 0)
        poses = nom.x[lo:i1 + 1][:, self.pose_idx]
        t_from = t_to = nom.t[lo:i1 + 1]             # the nominal's times at each pose (a span when interpolated)
        if len(poses) > 1:
            d = np.diff(poses, axis=0)
            if np.max(np.hypot(d[:, 0], d[:, 1])) > 0.05 or np.max(np.abs(wrap_angle(d[:, 2]))) > 0.05:
                times = t_from
                poses, seg = interpolate_poses(poses, 0.05, 0.05)
                t_from, t_to = times[seg], times[np.minimum(seg + 1, len(times) - 1)]
        margins = np.full(len(poses), rec.margin)
        tubed = self.opts.planning.margin == "auto" and rec.tube is not None
        if tubed:
            tb = rec.tube
            reach = np.maximum(np.interp(t_from - nom.t[0], tb.t, tb.reach), np.interp(t_to - nom.t[0], tb.t, tb.reach))
            margins = np.maximum(margins, reach)
        near = np.zeros(len(poses), dtype=bool)
        for centre, radius in self.discovered_discs:
            near |= np.hypot(poses[:, 0] - centre[0], poses[:, 1] - centre[1]) <= radius + self.fp.bounding_radius + margins
        for k in np.flatnonzero(near):
            if tubed:
                c = self.discovered_world.clearance(poses[k], self.fp)
                if c < margins[k]:
                    return {"pose": poses[k].tolist(), "clearance_m": c, "margin_m": float(margins[k]),
                            "tube_reach": True}
            elif not self.discovered_world.is_free(poses[k], self.fp, rec.margin):
                return {"pose": poses[k].tolist(), "clearance_m": self.discovered_world.clearance(poses[k], self.fp),
                        "margin_m": rec.margin}
        return None

    def _conflict_bodies(self, rec: PlanRecord, states: np.ndarray) -> dict | None:
        """:meth:`_conflict` for a robot of several bodies: every body's poses along the states
        (interpolated so that no body moves more than 5 cm between samples)."""
        states = bodies.interpolate_states(self.robot, states, 0.05, 0.05)
        poses = self.robot.body_poses(states)
        for b, fp in enumerate(self.robot.footprints):
            reach = fp.bounding_radius + rec.margin
            near = np.zeros(len(states), dtype=bool)
            for centre, radius in self.discovered_discs:
                near |= np.hypot(poses[:, b, 0] - centre[0], poses[:, b, 1] - centre[1]) <= radius + reach
            for k in np.flatnonzero(near):
                if not self.discovered_world.is_free(poses[k, b], fp, rec.margin):
                    return {"pose": states[k][self.pose_idx].tolist(), "body": b, "body_pose": poses[k, b].tolist(),
                            "clearance_m": self.discovered_world.clearance(poses[k, b], fp), "margin_m": rec.margin}
        return None

    def run(self) -> tuple[str, str]:
        opts, model = self.opts, self.model
        every_sense = max(1, round(opts.rate_hz / opts.sensor.rate_hz))
        every_monitor = max(1, round(opts.rate_hz / opts.monitor.rate_hz))
        # the first plan, retried like a replan (a new seed, then a larger budget), without pauses: the
        # robot has not moved yet
        attempts = []
        while True:
            attempt, result, law, margin, tube = self._plan_once(self._start_configuration, len(attempts))
            attempts.append(attempt)
            if law is not None or len(attempts) >= opts.replan.max_attempts:
                break
            if self.notify is not None:     # a failed attempt, as it happens (the next may take longer)
                self.notify(f"first plan, attempt {len(attempts)} of {opts.replan.max_attempts}: {attempt['status']} "
                            f"after {attempt['latency_s']:.1f} s"
                            + (f" ({attempt['likely_cause']['text']})" if "likely_cause" in attempt
                               and len(attempts) == 1 else "")
                            + f"; attempt {len(attempts) + 1} with a budget of "
                              f"{opts.planning.time_limit_s * opts.replan.budget_factor(len(attempts)):g} s ...")
        first = PlanRecord(0, "initial", 0.0, 0.0, self._start_configuration.copy(), attempt["seed"], margin,
                           attempts, result, law, tube=tube)
        self.plans.append(first)
        if law is None:
            raise _Stop("no_plan", f"no first plan in {len(attempts)} attempt{'s' if len(attempts) > 1 else ''} "
                                   f"(last: {attempt['status']}: {attempt['message']}){self._rate_hint(attempt)}")
        self._adopt(first)
        max_time = self._deadline(0.0, law)
        # the initial condition error, about the nominal's first state
        sigma0 = opts.noise.vector("initial", model.state_names)
        rng0 = np.random.default_rng(seed_for(opts.seed, "initial"))
        draw = rng0.standard_normal(model.n) if opts.noise.distribution == "gaussian" else \
            rng0.uniform(-1.0, 1.0, model.n)
        x = np.clip(law.nominal.x[0] + sigma0 * draw, *model.state_limits().T)
        self.x_initial = x.copy()
        self._check_collision(x, 0.0)
        rec, t_plan0, replans = first, 0.0, 0
        cusps = self._cusp_times(rec)
        zero_u = np.zeros(model.m)
        while True:
            t = self.k * self.T
            if t > max_time + 1e-9:
                raise _Stop("timed_out", f"the simulated time limit {max_time:.1f} s was reached")
            tau = t - t_plan0
            if self.k % every_sense == 0 and self._sense(x, t) or self.k % every_monitor == 0:
                conflict = self._conflict(rec, tau)
                if conflict is not None:
                    if replans >= opts.replan.max_replans:
                        raise _Stop("timed_out", f"more than replan.max_replans = {opts.replan.max_replans} "
                                                 f"replans were needed")
                    replans += 1
                    rec, x = self._replan(x, t, conflict)
                    t_plan0 = self.k * self.T
                    max_time = self._deadline(t_plan0, rec.law)
                    cusps = self._cusp_times(rec)
                    continue
            if tau >= rec.law.t_end - 1e-9:
                y = self._measure(x)
                self._record(t, x, y, rec.law.reference(tau)[0], zero_u, zero_u, rec.id, 2)
                return self._final(x)
            y = self._measure(x)
            if cusps and tau >= cusps[0] - 1e-9:
                cusps.pop(0)
                if replans < opts.replan.max_replans:
                    new = self._at_cusp(rec, tau, t, x, y)
                    if new is not None:                 # a certified plan of the rest, from now on
                        rec, replans = new, replans + 1
                        t_plan0 = self.k * self.T
                        max_time = self._deadline(t_plan0, rec.law)
                        cusps = self._cusp_times(rec)
                        continue
            u_ff = rec.law.mean_input(tau, tau + self.T)
            u, x0, _ = rec.law.control(tau, y, u_ff)
            if opts.saturate:
                u = np.clip(u, self.u_lo, self.u_hi)
            if not np.all(np.isfinite(u)):
                raise _Stop("numerical_failure", f"the input became non-finite at t = {t:.3f} s")
            self._record(t, x, y, x0, u, u_ff, rec.id, 0)
            x = self._advance(x, u, t)

    def _cusp_times(self, rec: PlanRecord) -> list[float]:
        """The plan times of the control samples where the robot comes to rest at the plan's cusps (the
        first sample of each stop whose motion reverses), when ``replan.at_cusps`` is on."""
        if not self.opts.replan.at_cusps or self.multibody or rec.law is None:
            return []
        return [math.ceil(a / self.T - 1e-9) * self.T for a, _ in cusp_stops(rec.law.nominal, self.pose_idx)]

    def _at_cusp(self, rec: PlanRecord, tau: float, t: float, x, y):
        """At a cusp (the robot at rest): the error tube of the rest of the maneuver from the measured
        state y (its rollouts start at y with the sensor noise's spread). Certified clear: nothing to
        do (None). Else the rest is replanned from y (at most ``replan.max_cusp_replans`` times a run),
        taken to finish within the stop (the robot steers in place there; the planning latency is
        measured and recorded), and the new plan is followed from now if its tube is certified clear;
        otherwise the old plan goes on. Returns the new plan, or None."""
        sub = remaining_law(rec.law, tau)
        if sub is None:
            return None
        names = self.model.state_names
        noise = self.opts.noise
        sens = noise.vector("sensor", names)
        raw = sens / noise.scale if noise.scale > 0 else np.zeros(self.model.n)
        start_noise = dataclasses.replace(noise, distribution="gaussian", impulses=(),
                                          initial={s: float(v) for s, v in zip(names, raw)})
        to = self.opts.tube
        started = time.perf_counter()
        try:
            rest = sampled_tube(sub, start_noise, self.fp, self.robot_world, rate_hz=self.opts.rate_hz,
                                substeps=self.opts.substeps, model=self.model, probability=to.probability,
                                confidence=to.confidence, x_start=y, why="the rest of the maneuver at a cusp",
                                discards=to.discards)
            verdict(rest, self.robot_world, self.fp, rec.margin)
        except NumericalError as exc:
            rest = None
            why = str(exc)
        check = {"time_s": t, "plan_time_s": tau, "measured_state": y.tolist(),
                 "certified_clearance_m": None if rest is None else rest.certified_clearance,
                 "certified": None if rest is None else rest.certified}
        if rest is None:
            check["tube_error"] = why
        rec.cusp_checks.append(check)
        self.cusp_timing.append(time.perf_counter() - started)
        if rest is not None and rest.certified:
            return None
        if self.cusp_replans >= self.opts.replan.max_cusp_replans:
            check["replanned"] = False
            check["why_not"] = f"replan.max_cusp_replans = {self.opts.replan.max_cusp_replans} reached"
            return None
        self.cusp_replans += 1
        start_pose = y[self.pose_idx]
        self._replan_at_cusp = True
        try:
            attempt, result, law, margin, tube = self._plan_once(start_pose, 0)
        finally:
            self._replan_at_cusp = False
        adopt = law is not None and tube is not None and tube.certified is True
        check.update(replanned=True, replan_status=attempt["status"], adopted=bool(adopt),
                     new_certified_clearance_m=None if tube is None else tube.certified_clearance,
                     latency_s=attempt.get("latency_s"))
        if not adopt:
            check["attempt"] = {k: v for k, v in attempt.items() if k not in ("latency_s", "tube_s")}
            return None
        new = PlanRecord(len(self.plans), "cusp", t, self.k * self.T, start_pose.copy(), attempt["seed"], margin,
                         [attempt], result, law, {"cusp_time_s": t, "rest_certified_clearance_m":
                                                  check["certified_clearance_m"]}, tube)
        self.plans.append(new)
        self._adopt(new)
        return new

    def _pause(self, x, y, plan_id: int):
        """The robot stands still (u = 0) for replan.pause_s of simulated time while a plan is made
        (sensing goes on); the first sample logs the measurement ``y`` already taken. Returns the state
        after the pause."""
        zero_u = np.zeros(self.model.m)
        every_sense = max(1, round(self.opts.rate_hz / self.opts.sensor.rate_hz))
        t_pause_end = self.k * self.T + self.opts.replan.pause_s
        first = True
        while self.k * self.T < t_pause_end - 1e-9 or first:
            t = self.k * self.T
            yk = y if first else self._measure(x)
            self._record(t, x, yk, np.full(self.model.n, np.nan), zero_u, zero_u, plan_id, 1)
            if self.k % every_sense == 0:
                self._sense(x, t)
            x = self._advance(x, zero_u, t)
            first = False
        return x

    def _adopt(self, rec: PlanRecord) -> None:
        """A plan is about to be followed: say its tube's verdict in one line (``notify``), and with
        ``tube.require_certified`` refuse it unless its tube is certified clear (the robot is at rest)."""
        tube = rec.tube
        if tube is None:
            line = f"plan {rec.id}: no error tube (the closed loop diverges under the law): NOT certified"
        else:
            line = tube_line(tube, self.opts.noise.scale, prefix=f"plan {rec.id} tube", noise=self.opts.noise)
        rec.verdict_line = line
        if self.notify is not None:
            self.notify(line)
        if self.opts.tube.require_certified and (tube is None or tube.certified is not True):
            why = ("no tube" if tube is None else "a robot of several bodies is not certified"
                   if tube.certified is None else f"certified clearance {tube.certified_clearance:+.3f} m")
            raise _Stop("not_certified", f"plan {rec.id} refused (tube.require_certified): its error tube is not "
                                         f"certified clear ({why}); the robot did not follow it")

    def _rate_hint(self, attempt: dict) -> str:
        """When a nominal failed its clearance check and the control period is long, say so: the
        nominal is sampled once per period, and samples far apart cut corners."""
        step = float(self.plan_model.input_limits()[0, 1]) * self.T
        if attempt.get("status") == "not_clear" and step > 0.05:
            return (f" (rate_hz = {self.opts.rate_hz:g}: the nominal is sampled every {self.T:g} s, up to "
                    f"{step:.2g} m apart, and cuts corners between samples; a rate of at least "
                    f"{math.ceil(float(self.plan_model.input_limits()[0, 1]) / 0.05):g} Hz keeps them within 5 cm)")
        return ""

    def _deadline(self, t_start: float, law: FeedbackLaw) -> float:
        """The simulated time limit: ``max_time_s`` if given; else twice the active nominal's duration
        plus 30 s from when it began (each replan moves it)."""
        if self.opts.max_time_s is not None:
            return self.opts.max_time_s
        deadline = t_start + 2.0 * (law.t_end - law.t0) + 30.0
        if deadline > MAX_CONTROL_PERIODS * self.T:
            if not self.plans or len(self.plans) == 1 and t_start == 0.0:
                raise InputError("max_time_s", f"given for a run this long: the default limit, 2 x the plan's "
                                 f"{law.t_end - law.t0:.0f} s + 30 s, is more than the {MAX_CONTROL_PERIODS:,} "
                                 f"control periods a run may simulate at rate_hz = {self.opts.rate_hz:g}", None,
                                 detail="set max_time_s, or a lower rate_hz")
            deadline = MAX_CONTROL_PERIODS * self.T
        return deadline

    def _replan(self, x, t_detect: float, conflict: dict):
        """Stop; plan from the measured state until a plan is found or attempts run out. Returns the new
        record (active from the current time) and the true state."""
        plan_id = len(self.plans)
        attempts = []
        while True:
            y = self._measure(x)
            start_pose = y[self.robot.configuration_columns] if self.multibody else y[self.pose_idx]
            attempt, result, law, margin, tube = self._plan_once(start_pose, len(attempts))
            attempts.append(attempt)
            x = self._pause(x, y, plan_id - 1)        # the robot stands still (sensing goes on)
            if law is not None:
                rec = PlanRecord(plan_id, "conflict", t_detect, self.k * self.T, start_pose.copy(), attempt["seed"],
                                 margin, attempts, result, law, conflict, tube)
                self.plans.append(rec)
                self._adopt(rec)
                return rec, x
            if len(attempts) >= self.opts.replan.max_attempts:
                self.plans.append(PlanRecord(plan_id, "conflict", t_detect, math.nan, start_pose.copy(),
                                             attempt["seed"], margin, attempts, None, None, conflict))
                raise _Stop("replan_failed", f"{len(attempts)} replanning attempts failed in a row "
                                             f"(last: {attempt['status']}: {attempt['message']})")

    def _final(self, x) -> tuple[str, str]:
        self.final_errors = final_errors(self.robot, x, self.goal)
        pos_err, head_err = self.final_errors["position_m"], self.final_errors["heading_rad"]
        tol = self.opts.tolerance
        text = f"position error {pos_err:.3f} m, heading error {head_err:.3f} rad"
        if self.multibody:      # the docked body: the last trailer (its axle and heading); the car's is reported
            pos_err = self.final_errors["trailer_position_m"][-1]
            head_err = self.final_errors["trailer_heading_rad"][-1]
            text = (f"trailer position error {pos_err:.3f} m, trailer heading error {head_err:.3f} rad (car: "
                    f"{self.final_errors['position_m']:.3f} m, {self.final_errors['heading_rad']:.3f} rad)")
        if pos_err <= tol.position_m and head_err <= tol.heading_rad:
            return "reached", f"goal reached: {text}"
        return "missed_goal", (f"the last nominal ended outside the goal tolerance ({text}; tolerance "
                               f"{tol.position_m:g} m, {tol.heading_rad:g} rad)")


def final_errors(robot: Robot, x, goal) -> dict:
    """Position and heading errors of the state x against the goal (a pose or a configuration): the
    robot's reference point, and for a car with trailers every trailer's axle and heading too."""
    x = np.asarray(x, dtype=float)
    pose = x[robot.pose_columns]
    out = {"position_m": float(np.hypot(*(pose[:2] - np.asarray(goal[:2], dtype=float)))),
           "heading_rad": float(abs(wrap_angle(pose[2] - goal[2])))}
    if robot.trailers:
        g = np.zeros(robot.model.n)
        g[robot.configuration_columns] = robot.configuration(goal, "goal")
        now, want = robot.body_poses(x)[1:], robot.body_poses(g)[1:]
        out["trailer_position_m"] = [float(v) for v in np.hypot(*(now[:, :2] - want[:, :2]).T)]
        out["trailer_heading_rad"] = [float(v) for v in np.abs(wrap_angle(now[:, 2] - want[:, 2]))]
    return out


def execute(m: Map, robot: Robot | None = None, start=None, goal=None, opts: RunOptions | None = None, *,
            notify=None) -> RunResult:
    """Run the composite controller once: plan, track under noise, monitor, replan.

    Parameters
    ----------
    m : Map
        The map (:func:`nhstab.load_map`), with its known and unknown obstacles.
    robot : Robot, optional
        The robot (:func:`nhstab.make_robot`); None takes ``opts.robot`` (a model name or a robot
        spec), else the map's ``robot:`` block, else the unicycle.
    start, goal : array_like, optional
        Poses x, y, theta (a car_trailer may add its trailer headings) or the model's full state with
        phi = 0 (:meth:`nhstab.robot.Robot.configuration`); None takes the run options', else the
        map's.
    opts : RunOptions, optional
        Controller, noise, sensing, replanning and tube options (default: all defaults).
    notify : callable, optional
        Called with one line of text each time a plan becomes active: its error tube's verdict
        (certified or not, where it is tightest, what would certify it), before the robot follows it.

    Returns
    -------
    RunResult
        The run's status, log, plans and metrics. What happens during the run (a collision, a missed
        goal, an interruption) is in its status, never raised.

    Raises
    ------
    InputError
        Bad input, before anything runs (a first plan that cannot be requested, e.g. a start in
        collision, is bad input).
    """
    if robot is not None and not isinstance(robot, Robot):
        raise InputError("robot", "a Robot (nhstab.make_robot(model, footprint=...)) or None", type(robot).__name__)
    if notify is not None and not callable(notify):
        raise InputError("notify", "a function of one line of text, or None", type(notify).__name__)
    given = {"robot": robot, "start": start, "goal": goal, "opts": opts}
    opts = given.get("opts") or RunOptions()
    if not isinstance(opts, RunOptions):
        raise InputError("opts", "a RunOptions", type(opts).__name__)
    if not isinstance(m, Map):
        raise InputError("map", "a Map (nhstab.load_map(path))", type(m).__name__)
    robot = resolve_robot(given.get("robot") if given.get("robot") is not None else opts.robot, m.robot,
                          source="run options" if given.get("robot") is None and opts.robot is not None else "",
                          map_where=map_robot_where(m))

    start, goal = resolve_poses(m, given.get("start") if given.get("start") is not None else opts.start,
                                given.get("goal") if given.get("goal") is not None else opts.goal)
    start, goal = robot.configuration(start, "start"), robot.configuration(goal, "goal")
    return _execute(m, robot, start, goal, opts, notify)


def _execute(m: Map, robot: Robot, start, goal, opts: RunOptions, notify=None) -> RunResult:
    started = time.perf_counter()
    run = CompositeRun(m, robot, start, goal, opts)
    run.notify = notify
    run.final_errors = None
    try:
        status, message = run.run()
    except _Stop as stop:
        status, message = stop.status, stop.message
    except KeyboardInterrupt:
        status, message = "interrupted", f"interrupted by the user at t = {run.k * run.T:.2f} s"
    except NumericalError as exc:
        status, message = "numerical_failure", str(exc)
    with holding_interrupts():          # the run has ended: from here a Ctrl-C does not lose it (nhstab.interrupts)
        return _result(run, robot, status, message, started)


def _result(run: CompositeRun, robot: Robot, status: str, message: str, started: float) -> RunResult:
    model, fp, opts = robot.model, robot.footprint, run.opts
    log = run.log.arrays(model.n, model.m)
    if run.final_errors is None and len(log["t"]):
        run.final_errors = final_errors(robot, log["x"][-1], run.goal)
    seeds = {"root": int(opts.seed), "planner_calls": [a["seed"] for p in run.plans for a in p.attempts],
             "streams": "numpy SeedSequence([root, stream, 0]); streams initial=0, sensor=1, process=2; "
                        "planner call i: SeedSequence([root, 3, i])"}
    return RunResult(status, message, model, fp, run.m, run.start, run.goal, run.opts, run.plans, log, run.discovered,
                     run.collision, seeds, time.perf_counter() - started,
                     {"final_errors": run.final_errors, "x_initial": getattr(run, "x_initial", None),
                      "period_s": run.T}, run.truth, robot)
