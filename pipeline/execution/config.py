"""Options of one composite-controller run, and the strict YAML run-config format.

A run config (``nhstab run --config FILE``) may give every option; the command line overrides it.
Every key is checked: an unknown key, a wrong type or a value out of range raises one
:class:`InputError` naming the key path (e.g. ``noise.sensor.theta``), what was expected and what
was given. The format::

    map: maps/scenarios/warehouse_pallets.yaml   # relative to the config file, or example:NAME
    robot: rwd_car                    # a model name, or a robot description (default: the map's):
                                      #   {model: rwd_car, wheelbase: 2.7, footprint: {...}, margin: 0.1, ...}
                                      #   (see nhstab.robot)
    start: [x, y, theta]              # default: the map's (car_trailer: [x, y, theta, theta1, ...] gives the
    goal: [x, y, theta]               #   trailers' headings; three numbers put them in line with the car;
                                      #   or the model's full state with phi = 0, see Robot.configuration)
    seed: 0                           # root seed: initial error, sensor and process noise, planner
    rate_hz: 50                       # controller rate (zero-order hold)
    substeps: 4                       # RK4 steps of the plant per control period
    saturate: true                    # clip inputs to the robot's limits
    headroom: 0.8                     # plan nominals within this fraction of the input limits
    max_time_s: 120                   # simulated time limit (default: 2 x the active plan + 30 s)
    controller: {kind: gramian, window: future, alpha: 0.1, delta: 6.0, gamma: 1.0, q: [..], r: [..]}
                                      # kind: gramian | tvlqr | open-loop; window (gramian): future |
                                      # frozen-time (causal) | past (Remark 2: not stabilizing, study only);
                                      # max_gain: frozen-time's hold threshold (default 50);
                                      # gains: auto picks alpha, delta, gamma per plan (gramian; nhstab.tubes)
    noise:
      scale: 1.0                      # multiplies every noise level below (0: noiseless)
      initial: {distribution: gaussian, x: 0.1, y: 0.1, theta: 0.05}   # std (uniform: half-width)
      sensor: {x: 0.02, y: 0.02, theta: 0.01}                          # measurement std per state
      process: {per: second, x: 0.02, y: 0.02, theta: 0.01}            # [unit / sqrt(s)]; per: metre makes
                                      # it a disturbance per distance travelled [unit / sqrt(m)], none at rest
      impulses: [{time: 4.0, x: 0.0, y: 0.3}]                          # state jumps at given times
    sensor: {range_m: 8.0, fov_deg: 360, rate_hz: 10, resolution_deg: 0.5}
    monitor: {rate_hz: 10, horizon_s: 8.0}
    planning: {planner: rrtconnect, time_limit_s: 2.0, margin: 0.3, space: reeds_shepp, guide: true, fit: false}
                                      # margin: the robot's; space: the robot's, else reeds_shepp (dubins:
                                      # forward only); auto plans with the error tube's clearance
                                      # (nhstab.tubes); fit: an uncertified plan is changed until its tube
                                      # is certified (the margin it needs, other maneuvers), the best kept
    replan: {pause_s: 1.0, max_attempts: 3, max_replans: 10, budget_growth: 4.0, at_cusps: true,
             max_cusp_replans: 3}      # at_cusps: at each cusp, replan the rest when its tube is not clear
    tolerance: {position_m: 0.3, heading_rad: 0.2}
    tube: {kind: auto, probability: 0.997, confidence: 0.95, discards: 2,
           require_certified: false}
                                      # every plan's error tube (nhstab.tubes): auto = linear where it holds,
                                      # sampled rollouts elsewhere; discards: rollouts the sampled tube's
                                      # reach and clearance leave out (more rollouts, a tighter tube);
                                      # require_certified: refuse a plan whose tube is not certified clear
                                      # (status not_certified)

Noise levels are given per state name; states not named get the robot's default (see
:data:`DEFAULT_NOISE`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from ..control.frozen import MAX_GAIN
from ..errors import InputError, user_keys
from ..examples import resolve_map_path
from ..limits import (
    DEFAULT_HEADROOM,
    MAX_CONTROL_PERIODS,
    MAX_NOISE_LEVEL,
    MAX_NOISE_SCALE,
    MAX_RATE_HZ,
    MAX_SEED,
    MAX_SUBSTEPS,
    MIN_RATE_HZ,
    _short_int,
    check_headings,
    check_int,
    check_probability,
    check_range,
    number_hint,
)
from ..maps.bundled import resolve_config_path
from ..models import MODELS
from ..models.base import NOISE_KINDS
from ..planning import PLANNERS, SPACES
from ..records import to_jsonable
from ..robot import robot_from_spec
from ..safe_io import read_yaml_mapping
from ..sensing import MAX_BEAMS, SensorOptions
from ..tubes.base import DEFAULT_DISCARDS, TUBE_KINDS, check_discards, rollouts_needed
from ..yaml_keys import schema_keys
from .controllers import ControllerOptions


def default_noise() -> dict:
    """The default noise per kind and state name: initial error std, sensor std, process intensity
    [unit/sqrt(s)]; the union of the registered models' ``noise_defaults`` (:class:`nhstab.models.Model`),
    which agree on the states they share (a test holds the built-in ones to it). Read at each call, so
    a model registered later (``nhstab.models.MODELS``) brings its own."""
    return {kind: {name: level for cls in MODELS.values() for name, level in cls.noise_defaults[kind].items()}
            for kind in NOISE_KINDS}


#: the built-in models' default noise per state name (:func:`default_noise`); a trailer's heading theta1 ..
#: theta8 (car_trailer) as the car's heading
DEFAULT_NOISE = default_noise()
DISTRIBUTIONS = ("gaussian", "uniform")
#: what the process disturbance's intensity is per: ``second`` (a Wiener process in time, [unit / sqrt(s)],
#: acting at rest too) or ``metre`` (in the distance the robot's reference point travels, [unit / sqrt(m)]:
#: the increment of a control period has std intensity * sqrt(distance moved in it), so none at rest)
PROCESS_PER = ("second", "metre")


def check_number(key: str, v, lo: float = -math.inf, lo_open: bool = False, integer: bool = False):
    """``v`` as a float (or an int with ``integer``) >= lo (> lo with ``lo_open``), else an InputError
    naming ``key``. Integers of any size are compared exactly (never converted to float first), and
    text such as ``1e9`` (a string to YAML 1.1) gets a hint on how to write it."""
    ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
    if ok and isinstance(v, (float, np.floating)):
        ok = math.isfinite(v) and (not integer or float(v).is_integer())
    if ok:
        ok = v > lo if lo_open else v >= lo
    if not ok:
        kind = "an integer" if integer else "a finite number"
        bound = "" if lo == -math.inf else f" {'>' if lo_open else '>='} {lo:g}"
        raise InputError(key, kind + bound, _short_int(v), detail=number_hint(v))
    if integer:
        return int(v)
    try:
        return float(v)
    except OverflowError:
        raise InputError(key, f"a finite number{'' if lo == -math.inf else ' of moderate size'}", _short_int(v)) \
            from None


def _noise_number(key: str, value, most: float) -> float:
    """A noise scale or level: a finite number in [0, most] (:data:`nhstab.limits.MAX_NOISE_SCALE`,
    :data:`~nhstab.limits.MAX_NOISE_LEVEL`), or an InputError naming ``key``."""
    v = check_number(key, value, 0.0)
    if v > most:
        raise InputError(key, f"a number in [0, {most:g}]", value)
    return v


def position_states(state_names) -> tuple[int, int]:
    """The states whose move is the distance a per-metre process disturbance counts: x and y, or for a
    model without them (the Heisenberg system) its first two states."""
    names = list(state_names)
    return (names.index("x"), names.index("y")) if "x" in names and "y" in names else (0, 1)


def distance_factor(d2):
    """sqrt of the distance moved in a control period (by :func:`position_states`), from its squared length
    d2 (a float or an array): sqrt(sqrt(d2)), the factor of a per-metre process increment. The run loop
    and the vectorised engine both compute d2 = dx * dx + dy * dy and this, so their increments are
    equal bit for bit."""
    return np.sqrt(np.sqrt(d2))


@dataclass(frozen=True)
class NoiseOptions:
    """Noise levels by state name (see :data:`DEFAULT_NOISE`); ``scale`` multiplies all of them;
    impulses: ((time, {state: jump}), ...); ``process_per``: what the process intensity is per
    (:data:`PROCESS_PER`)."""

    scale: float = 1.0
    distribution: str = "gaussian"
    initial: dict = field(default_factory=dict)
    sensor: dict = field(default_factory=dict)
    process: dict = field(default_factory=dict)
    impulses: tuple = ()
    process_per: str = "second"

    def validated(self, state_names) -> "NoiseOptions":
        _noise_number("noise.scale", self.scale, MAX_NOISE_SCALE)
        if self.distribution not in DISTRIBUTIONS:
            raise InputError("noise.initial.distribution", "one of " + ", ".join(DISTRIBUTIONS), self.distribution)
        if self.process_per not in PROCESS_PER:
            raise InputError("noise.process.per", "one of " + ", ".join(PROCESS_PER),
                             "null" if self.process_per is None else self.process_per)
        for kind in ("initial", "sensor", "process"):
            for name, v in getattr(self, kind).items():
                if name not in state_names:
                    raise InputError(f"noise.{kind}.{name}", "a state of the robot (" + ", ".join(state_names) + ")",
                                     name)
                _noise_number(f"noise.{kind}.{name}", v, MAX_NOISE_LEVEL)
        for i, (time_s, jump) in enumerate(self.impulses):
            check_number(f"noise.impulses[{i}].time", time_s, 0.0)
            for name, v in jump.items():
                if name not in state_names:
                    raise InputError(f"noise.impulses[{i}].{name}", "time or a state of the robot ("
                                     + ", ".join(state_names) + ")", name)
                if abs(check_number(f"noise.impulses[{i}].{name}", v)) > MAX_NOISE_LEVEL:
                    raise InputError(f"noise.impulses[{i}].{name}", f"a number in [-{MAX_NOISE_LEVEL:g}, "
                                     f"{MAX_NOISE_LEVEL:g}]", v)
        return self

    def merged(self, levels: dict | None = None, scale: float | None = None) -> "NoiseOptions":
        """These options with more levels: ``levels`` maps a kind (initial, sensor, process) to levels by
        state name, each over this kind's own (a kind None or absent keeps its levels); ``scale``, if
        given, replaces the scale. Not validated (see :meth:`validated`)."""
        out = replace(self, **{k: {**getattr(self, k), **v} for k, v in (levels or {}).items() if v is not None})
        return out if scale is None else replace(out, scale=scale)

    def vector(self, kind: str, state_names) -> np.ndarray:
        """The levels of one kind in state order, scaled."""
        given, defaults = getattr(self, kind), default_noise()[kind]
        return self.scale * np.array([float(given.get(s, defaults.get(s, 0.0))) for s in state_names])

    @property
    def per_metre(self) -> bool:
        """The process disturbance acts per distance travelled (none at rest)."""
        return self.process_per == "metre"

    def process_step_std(self, state_names, period: float) -> np.ndarray:
        """The process increment's std per state for one control period: intensity * sqrt(T) per second;
        per metre the intensity itself, which the loop multiplies by sqrt of the distance moved in the
        period (:func:`distance_factor`)."""
        v = self.vector("process", state_names)
        return v if self.per_metre else v * math.sqrt(period)

    def impulse_list(self, state_names) -> list[tuple[float, np.ndarray]]:
        return sorted(((float(t), self.scale * np.array([float(j.get(s, 0.0)) for s in state_names]))
                       for t, j in self.impulses), key=lambda item: item[0])      # stable: ties keep their order

    def describe(self, state_names) -> dict:
        return {"scale": self.scale, "initial_distribution": self.distribution,
                **{f"{k}_by_state": dict(zip(state_names, self.vector(k, state_names).tolist()))
                   for k in ("initial", "sensor", "process")},
                "process_per": self.process_per,
                "process_units": ("state unit / sqrt(m) (increments added every control period, std the intensity "
                                  "times sqrt of the distance the robot's position moved in it: none at rest)"
                                  if self.per_metre else
                                  "state unit / sqrt(s) (Wiener increments added every control period)"),
                "impulses": [{"time": t, "jump": j.tolist()} for t, j in self.impulse_list(state_names)]}


@dataclass(frozen=True)
class MonitorOptions:
    """rate_hz: how often the remaining nominal is checked against discovered obstacles;
    horizon_s: how far ahead along the nominal."""

    rate_hz: float = 10.0
    horizon_s: float = 8.0

    def validated(self) -> "MonitorOptions":
        check_number("monitor.rate_hz", self.rate_hz, 0.0, lo_open=True)
        if self.rate_hz > MAX_RATE_HZ:
            raise InputError("monitor.rate_hz", f"a rate in (0, {MAX_RATE_HZ:g}] Hz", self.rate_hz)
        check_number("monitor.horizon_s", self.horizon_s, 0.0, lo_open=True)
        return self


@dataclass(frozen=True)
class PlanningOptions:
    """The planner used for the first plan and every replan (see ``nhstab plan``). ``space``:
    reeds_shepp (forward and reverse) or dubins (forward only); None for the robot's (``Robot.space``),
    else reeds_shepp. ``margin``: the
    clearance every nominal keeps from the obstacles the robot knows of; None for the robot's
    (``Robot.margin``, see :mod:`nhstab.robot`); "auto" for the smallest margin whose error tube is
    certified clear (:func:`nhstab.tubes.plan_with_auto_margin`). ``guide``: the guided search (a grid
    shortest path sets the subgoals); false searches with OMPL's planner over the whole map. ``fit``:
    when a plan's error tube is not certified clear, try the margin it needs and other maneuvers, and
    keep the best (:func:`nhstab.tubes.fit_plan`)."""

    planner: str = "rrtconnect"
    space: str | None = None                 # None: the robot's (Robot.planning_space)
    time_limit_s: float = 2.0
    margin: float | str | None = None
    turning_radius: float | None = None
    guide: bool = True
    fit: bool = False

    def validated(self) -> "PlanningOptions":
        if self.planner not in PLANNERS:
            raise InputError("planning.planner", "one of " + ", ".join(PLANNERS), self.planner)
        if self.space is not None and self.space not in SPACES:
            raise InputError("planning.space", "one of " + ", ".join(SPACES), self.space)
        check_number("planning.time_limit_s", self.time_limit_s, 0.0, lo_open=True)
        if isinstance(self.margin, str):
            if self.margin != "auto":
                raise InputError("planning.margin", "a number >= 0 or auto", self.margin)
        elif self.margin is not None:
            check_number("planning.margin", self.margin, 0.0)
        if self.turning_radius is not None:
            check_number("planning.turning_radius", self.turning_radius, 0.0, lo_open=True)
        if not isinstance(self.guide, bool):
            raise InputError("planning.guide", "true or false", self.guide)
        if not isinstance(self.fit, bool):
            raise InputError("planning.fit", "true or false", self.fit)
        return self


@dataclass(frozen=True)
class ReplanOptions:
    """While a replan runs the robot stops (u = 0) for ``pause_s`` of simulated time (a fixed,
    documented budget, so that runs are reproducible; the real planning latency is recorded next to
    it). A failed attempt is retried after another pause with a new seed, up to ``max_attempts`` in a
    row; the attempts after the second get ``budget_growth`` times the planning budget. The first plan
    (before the robot moves, so without pauses) is retried the same way. At most ``max_replans``
    replans per run. ``at_cusps``: at each cusp of the active plan (the robot at rest), the error tube of
    the rest of the maneuver is predicted from the measured state; where it is not certified clear the
    rest is replanned from there (at most ``max_cusp_replans`` times a run), within the stop, and the
    new plan is followed if its tube is certified clear (a followed cusp replan counts as a replan)."""

    pause_s: float = 1.0
    max_attempts: int = 3
    max_replans: int = 10
    budget_growth: float = 4.0
    at_cusps: bool = True
    max_cusp_replans: int = 3

    def budget_factor(self, attempt: int) -> float:
        """The planning budget of attempt ``attempt`` (0, 1, ...) relative to planning.time_limit_s."""
        return 1.0 if attempt < 2 else float(self.budget_growth)

    def validated(self) -> "ReplanOptions":
        check_number("replan.pause_s", self.pause_s, 0.0)
        check_number("replan.max_attempts", self.max_attempts, 1.0, integer=True)
        check_number("replan.budget_growth", self.budget_growth, 1.0)
        check_number("replan.max_replans", self.max_replans, 0.0, integer=True)
        if not isinstance(self.at_cusps, bool):
            raise InputError("replan.at_cusps", "true or false", self.at_cusps)
        check_number("replan.max_cusp_replans", self.max_cusp_replans, 0.0, integer=True)
        return self


@dataclass(frozen=True)
class TubeOptions:
    """The error tube of every plan (:func:`nhstab.tubes.predict_tube`): ``kind`` auto (the linear tube
    where it holds, the sampled one elsewhere), linear or sampled; its ``probability`` p and, for the
    sampled tube, the certificate's ``confidence`` and ``discards`` r (N rollouts, the smallest with
    P[Binomial(N, 1 - p) <= r] <= 1 - confidence; r = 0: N >= ln(1 - confidence) / ln(p)); the reach and
    certified clearance leave out the r most extreme rollouts (:mod:`nhstab.tubes.sampled`).
    ``require_certified``: a plan whose tube is not certified clear is not executed (the run ends
    "not_certified" before the robot follows it; ``nhstab run`` exits with code 5)."""

    kind: str = "auto"
    probability: float = 0.997
    confidence: float = 0.95
    discards: int = DEFAULT_DISCARDS
    require_certified: bool = False

    def validated(self) -> "TubeOptions":
        if self.kind not in TUBE_KINDS:
            raise InputError("tube.kind", "one of " + ", ".join(TUBE_KINDS), self.kind)
        check_probability("tube.probability", check_number("tube.probability", self.probability, 0.0, lo_open=True))
        v = check_number("tube.confidence", self.confidence, 0.0, lo_open=True)
        if v >= 1.0:
            raise InputError("tube.confidence", "a number in (0, 1)", v)
        check_discards(self.discards, "tube.discards")
        try:
            rollouts_needed(self.probability, self.confidence)
        except InputError as exc:
            raise exc.renamed("tube.confidence") from None
        try:
            rollouts_needed(self.probability, self.confidence, self.discards)
        except InputError as exc:
            raise exc.renamed("tube.discards") from None
        if not isinstance(self.require_certified, bool):
            raise InputError("tube.require_certified", "true or false", self.require_certified)
        return self


@dataclass(frozen=True)
class ToleranceOptions:
    """The goal counts as reached when, at the end of the last nominal, the position error and the
    heading error are within these."""

    position_m: float = 0.3
    heading_rad: float = 0.2

    def validated(self) -> "ToleranceOptions":
        check_number("tolerance.position_m", self.position_m, 0.0, lo_open=True)
        check_number("tolerance.heading_rad", self.heading_rad, 0.0, lo_open=True)
        return self


@dataclass(frozen=True)
class RunOptions:
    #: a model name or a robot spec mapping (the YAML form of :mod:`nhstab.robot`); None: the map's
    robot: str | dict | None = None
    start: tuple | None = None
    goal: tuple | None = None
    seed: int = 0
    rate_hz: float = 50.0
    substeps: int = 4
    saturate: bool = True
    headroom: float = DEFAULT_HEADROOM
    max_time_s: float | None = None
    controller: ControllerOptions = field(default_factory=ControllerOptions)
    noise: NoiseOptions = field(default_factory=NoiseOptions)
    #: all round by default: a car reverses as much as it drives forward (one 270-degree lidar would
    #: leave it blind behind)
    sensor: SensorOptions = field(default_factory=lambda: SensorOptions(fov_rad=2 * math.pi))
    monitor: MonitorOptions = field(default_factory=MonitorOptions)
    planning: PlanningOptions = field(default_factory=PlanningOptions)
    replan: ReplanOptions = field(default_factory=ReplanOptions)
    tolerance: ToleranceOptions = field(default_factory=ToleranceOptions)
    tube: TubeOptions = field(default_factory=TubeOptions)

    def validated(self, state_names, n_inputs: int) -> "RunOptions":
        check_int("seed", self.seed, 0, MAX_SEED, "a non-negative integer")
        check_range("rate_hz", self.rate_hz, MIN_RATE_HZ, MAX_RATE_HZ, "Hz")
        check_int("substeps", self.substeps, 1, MAX_SUBSTEPS)
        check_number("headroom", self.headroom, 0.0, lo_open=True)
        if self.headroom > 1.0:
            raise InputError("headroom", "a number in (0, 1]", self.headroom)
        if not isinstance(self.saturate, bool):
            raise InputError("saturate", "true or false", self.saturate)
        if self.max_time_s is not None:
            check_number("max_time_s", self.max_time_s, 0.0, lo_open=True)
            periods = self.max_time_s * self.rate_hz
            if periods > MAX_CONTROL_PERIODS:
                raise InputError("max_time_s", f"at most {MAX_CONTROL_PERIODS:,} control periods at rate_hz = "
                                 f"{self.rate_hz:g} ({MAX_CONTROL_PERIODS / self.rate_hz:g} s)", self.max_time_s)
        self.controller.validated(len(state_names), n_inputs)
        self.noise.validated(state_names)
        self.sensor.validated()
        self.monitor.validated()
        self.planning.validated()
        self.replan.validated()
        self.tolerance.validated()
        self.tube.validated()
        return self


_SECTIONS = {"controller": ControllerOptions, "noise": NoiseOptions, "sensor": SensorOptions,
             "monitor": MonitorOptions, "planning": PlanningOptions, "replan": ReplanOptions,
             "tolerance": ToleranceOptions, "tube": TubeOptions}
#: the run config's keys (from its JSON Schema, nhstab.yaml_keys, written from RunOptions and its sections)
_TOP = set(schema_keys("run-config"))
#: keys a section accepts as other names of its own (translated before the key check)
_ALIASES = {"controller": ("type",), "sensor": ("fov_deg", "resolution_deg")}


def check_pose(key: str, v):
    """[x, y, theta], or for a car with trailers [x, y, theta, theta1, ...] (the robot checks the length)."""
    if not (isinstance(v, (list, tuple)) and 3 <= len(v) <= 12):
        raise InputError(key, "[x, y, theta] (three numbers; a car with trailers may add their headings)", v)
    pose = tuple(check_number(f"{key}[{i}]", c) for i, c in enumerate(v))
    check_headings(key, pose)
    return pose


def _noise(data: dict) -> NoiseOptions:
    if not isinstance(data, dict):
        raise InputError("noise", "a mapping", data)
    allowed = set(schema_keys("run-config", "properties", "noise"))
    for key in data:
        if key not in allowed:
            raise InputError(f"noise.{key}", "one of " + ", ".join(sorted(allowed)), key)
    kw = {}
    if "scale" in data:
        kw["scale"] = _noise_number("noise.scale", data["scale"], MAX_NOISE_SCALE)
    for kind in ("initial", "sensor", "process"):
        if kind in data:
            section = data[kind]
            if not isinstance(section, dict):
                raise InputError(f"noise.{kind}", "a mapping of state name to level", section)
            section = dict(section)
            if kind == "initial" and "distribution" in section:
                kw["distribution"] = section.pop("distribution")
            if kind == "process" and "per" in section:
                kw["process_per"] = section.pop("per")
            kw[kind] = section
    if "impulses" in data:
        items = data["impulses"]
        if not isinstance(items, list):
            raise InputError("noise.impulses", "a list of {time: t, <state>: jump, ...}", items)
        impulses = []
        for i, item in enumerate(items):
            if not isinstance(item, dict) or "time" not in item:
                raise InputError(f"noise.impulses[{i}]", "a mapping with a time and state jumps", item)
            rest = {k: v for k, v in item.items() if k != "time"}
            impulses.append((item["time"], rest))
        kw["impulses"] = tuple(impulses)
    return NoiseOptions(**kw)


def _section(name: str, data) -> object:
    if not isinstance(data, dict):
        raise InputError(name, "a mapping", data)
    data = dict(data)
    if name == "sensor":
        # degrees in files, radians inside: checked here, in the units the user wrote
        _sensor_degrees(data)
    if name == "controller" and "kind" not in data and "type" in data:
        data["kind"] = data.pop("type")
    names = [k for k in schema_keys("run-config", "properties", name) if k not in _ALIASES.get(name, ())]
    for key in data:
        if key not in names:
            shown = sorted(n.replace("_rad", "_deg") if name == "sensor" and n in ("fov_rad", "resolution_rad")
                           else n for n in names)
            raise InputError(f"{name}.{key}", "one of " + ", ".join(shown), key)
    for key in ("q", "r", "mount"):
        if key in data and isinstance(data[key], list):
            data[key] = tuple(data[key])
    return replace(getattr(RunOptions(), name), **data)


def _sensor_degrees(data: dict) -> None:
    """``fov_deg`` and ``resolution_deg`` checked in degrees (the errors name the keys the user
    wrote), then converted to the radians of :class:`SensorOptions` in place (an angle given both ways
    is refused)."""
    for deg, rad in (("fov_deg", "fov_rad"), ("resolution_deg", "resolution_rad")):
        if deg in data and rad in data:
            raise InputError(f"sensor.{rad}", f"left out when sensor.{deg} is given (one angle, one key)", data[rad])
    fov = None
    if "fov_deg" in data:
        fov = check_number("sensor.fov_deg", data.pop("fov_deg"), 0.0, lo_open=True)
        if fov > 360.0:
            raise InputError("sensor.fov_deg", "a number of degrees in (0, 360] (360: all round)", fov)
        data["fov_rad"] = math.radians(fov)
    if "resolution_deg" in data:
        res = check_number("sensor.resolution_deg", data.pop("resolution_deg"), 0.0, lo_open=True)
        fov_deg = fov if fov is not None else math.degrees(RunOptions().sensor.fov_rad)
        if res > fov_deg:
            raise InputError("sensor.resolution_deg", f"at most the field of view ({fov_deg:g} degrees)", res)
        if math.ceil(fov_deg / res - 1e-9) > MAX_BEAMS:
            raise InputError("sensor.resolution_deg", f"coarse enough for at most {MAX_BEAMS} beams over "
                             f"{fov_deg:g} degrees (>= {fov_deg / MAX_BEAMS:.3g})", res)
        data["resolution_rad"] = math.radians(res)


def options_from_mapping(data: dict, allowed=None, prefix: str = "") -> RunOptions:
    """RunOptions from a parsed mapping (the run-config keys except ``map``). ``allowed`` restricts
    the keys; errors name the key with ``prefix`` (e.g. ``run.noise.scale`` in a batch config)."""
    allowed = set(_TOP - {"map"}) if allowed is None else set(allowed)
    try:
        if not isinstance(data, dict):
            raise InputError("", "a mapping", type(data).__name__)
        for key in data:
            if key not in allowed:
                raise InputError(key, "one of " + ", ".join(sorted(allowed)), key)
        kw = {}
        for key, v in data.items():
            if key == "noise":
                kw[key] = _noise(v)
            elif key in _SECTIONS:
                kw[key] = _section(key, v)
            elif key in ("start", "goal"):
                kw[key] = check_pose(key, v)
            elif key == "robot":
                robot_from_spec(v, where="robot")          # checked here, kept as plain data
                kw[key] = v
            else:
                kw[key] = v
        return RunOptions(**kw)
    except InputError as exc:
        if not prefix:
            raise
        name = prefix.rstrip(".") if not exc.argument else prefix + exc.argument
        raise exc.renamed(name) from None


def load_run_config(path) -> tuple[dict, RunOptions]:
    """Read a run config (a file, or ``example:NAME``: a bundled one); returns ({"map": resolved path,
    "map_given": the text the config gives, when it has a map}, RunOptions). Strict, see module doc."""
    path = resolve_config_path(path, "--config", "run")
    data = read_yaml_mapping(path, "--config", "run config (YAML)", keys=sorted(_TOP))
    extra = {}
    if "map" in data:
        if not isinstance(data["map"], str):
            raise InputError("map", "a path to a map file", data["map"])
        with user_keys({"example": ("map", data["map"])}):
            m = resolve_map_path(data["map"])            # example:NAME, or relative to the config
        extra["map"] = m if m.is_absolute() else (path.parent / m)
        extra["map_given"] = data["map"]
    return extra, options_from_mapping({k: v for k, v in data.items() if k != "map"})


def config_mapping(opts: RunOptions, robot=None) -> dict:
    """``opts`` as a run config (the ``nhstab run --config`` keys, without ``map``), every section with
    every key; plain data that YAML and JSON write. Keys left at None (the robot's) are left out,
    unless ``robot`` (a :class:`~nhstab.robot.Robot`) is given: then they are filled with its values
    (planning.margin, turning_radius and space, controller.alpha, delta and gamma; max_gain with the
    frozen-time law's; every state's noise level). The sensor's angles are in radians as stored (``fov_rad``,
    ``resolution_rad``): a round trip through degrees could change the last bit. Read back by
    :func:`options_from_mapping`, it gives ``opts`` again (with the robot's values filled in)."""
    if robot is not None:
        st = robot.stabilizer.as_dict()
        c, p = opts.controller, opts.planning
        opts = replace(opts, controller=replace(
            c, alpha=c.alpha if c.alpha is not None else st.get("alpha"),
            delta=c.delta if c.delta is not None else st.get("delta"),
            gamma=c.gamma if c.gamma is not None else st.get("gamma"),
            max_gain=c.max_gain if c.max_gain is not None else MAX_GAIN),
            planning=replace(p, margin=p.margin if p.margin is not None else robot.margin,
                             turning_radius=p.turning_radius if p.turning_radius is not None
                             else robot.turning_radius,
                             space=p.space if p.space is not None else robot.planning_space))
    d = asdict(opts)
    out = {}
    for key in ("seed", "rate_hz", "substeps", "saturate", "headroom", "max_time_s"):
        if d[key] is not None:
            out[key] = d[key]
    if opts.robot is not None:
        out["robot"] = opts.robot
    if opts.start is not None:
        out["start"] = list(opts.start)
    if opts.goal is not None:
        out["goal"] = list(opts.goal)
    out["controller"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in d["controller"].items()
                         if v is not None}
    noise = opts.noise
    levels = {k: dict(getattr(noise, k)) for k in ("initial", "sensor", "process")}
    if robot is not None:           # every state's level, the defaults (DEFAULT_NOISE) filled in
        levels = {k: {s: float(v.get(s, DEFAULT_NOISE[k].get(s, 0.0))) for s in robot.state_names}
                  for k, v in levels.items()}
    out["noise"] = {"scale": noise.scale, "initial": {"distribution": noise.distribution, **levels["initial"]},
                    "sensor": levels["sensor"], "process": {"per": noise.process_per, **levels["process"]},
                    "impulses": [{"time": t, **j} for t, j in noise.impulses]}
    out["sensor"] = {**d["sensor"], "mount": list(d["sensor"]["mount"])}
    for key in ("monitor", "planning", "replan", "tolerance", "tube"):
        out[key] = {k: v for k, v in d[key].items() if v is not None}
    return to_jsonable(out)


def merge(base: RunOptions, **overrides) -> RunOptions:
    """Command-line overrides: ``section__key=value`` sets a key of a section, ``key=value`` a top key;
    None values are ignored."""
    top, sections = {}, {}
    for key, v in overrides.items():
        if v is None:
            continue
        if "__" in key:
            sec, sub = key.split("__", 1)
            sections.setdefault(sec, {})[sub] = v
        else:
            top[key] = v
    for sec, vals in sections.items():
        top[sec] = replace(getattr(base, sec), **vals)
    return replace(base, **top)
