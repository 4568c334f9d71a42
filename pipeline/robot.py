"""A robot is one described value: model and parameters, footprint, limits, state layout, defaults.

Every stage takes the robot from here: the planner (footprint, turning radius, margin), the gain
schedule (stabilizer alpha, delta, gamma), the plant and its input limits, the collision monitor
and the outputs, which record :meth:`Robot.describe`. Users describe their own robot in YAML, as
``--robot-config FILE`` (a file whose top level is this block, or holds it under ``robot:``) or as
the ``robot:`` block of map, run and batch files::

    robot:
      model: rwd_car            # heisenberg | unicycle | fwd_car | rwd_car | car_trailer
      wheelbase: 2.7            # the model's parameters by their names: max_speed, max_steer,
      max_steer: 0.7            #   max_steer_rate, max_turn_rate, ...
      max_steer_rate: 0.6
      max_speed: 2.0
      footprint:                # one of: {radius: R} | {rectangle: {length, width, rear_overhang}} |
        polygon: [[-0.9, -0.95], [3.6, -0.95], [3.6, 0.95], [-0.9, 0.95]]   # {polygon: [...]}
      margin: 0.1               # planning margin [m]
      stabilizer: {alpha: 0.1, delta: 6.0, gamma: 1.0, end_strategy: extend, cusps: split}   # the gramian law's defaults
      turning_radius: 5.0       # planning turning radius [m] (default: the rule below)
      space: dubins             # the planning space: dubins (forward only) or reeds_shepp (forward and
                                #   reverse); default: none, the planner's (reeds_shepp)

A ``car_trailer`` also takes ``hitch_lengths: [d1, ...]`` (one per trailer, the model's list-valued
parameter) and ``trailer_footprint`` (one footprint spec for every trailer, or a list with one per
trailer, each in its trailer's frame: x forward from the trailer's axle centre); ``footprint`` is
the car's.

Every key but ``model`` is optional; an unknown key, a wrong type, NaN or a value out of range is
refused with one :class:`InputError` naming the key. A polygon footprint is in the robot's frame:
x forward from the reference point (the rear axle of a car, the centre of the unicycle), y to the
left; a rectangle's ``rear_overhang`` is how far the body reaches behind the reference point.

Defaults per model (:data:`MODEL_DEFAULTS`): the footprint, the planning margin, the stabilizer
parameters (alpha, delta, gamma chosen by ``nhstab sweep``, results/planning/sweep.md; the end of the
gain schedule, :data:`nhstab.control.gramian.END_STRATEGIES`) and the turning-radius rule. The cars'
schedules end with ``extend``: a car nominal that drives a straight run into its goal keeps its window
sliding along that run's continuation, where the last whole window carried along the flow
(``frozen``) let the largest gain grow to 55-80 on the parking suite's tight bays and ended the runs
farther from the goal (docs/theory/control-law.md, "Ends of a trajectory"). The
rule: the unicycle plans with a 0.5 m radius (it could turn in place; a radius keeps the path smooth
and the gramian well conditioned); a car plans with 1.25 times its minimum turning radius
R_min = L / tan(max_steer), so that the feedback keeps steering authority: on an arc of radius
1.25 R_min the nominal steers at atan(tan(max_steer) / 1.25), 0.11 rad inside the default rwd_car's
limit. Where a problem needs tighter turns (parking) the planner may go down to R_min;
``turning_radius`` overrides the rule.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError, number_hint, user_keys
from .geometry import Footprint, is_simple_polygon, polygon_area
from .limits import MAX_COORD_M, MAX_POLYGON_VERTICES
from .models import MODELS, Model, make_model
from .safe_io import read_yaml_mapping
from .yaml_keys import schema_keys

#: per-model defaults: footprint (a YAML footprint spec), planning margin [m], stabilizer, turning
#: radius rule (("fixed", metres) or ("factor", multiple of the minimum turning radius))
#: per model, the built-in robot's description (each model's ``robot_defaults``): footprint (a YAML
#: footprint spec), planning margin [m], stabilizer, turning radius (("fixed", metres) or ("factor", times
#: the model's smallest turning radius)), and a car_trailer's trailer footprint
MODEL_DEFAULTS: dict[str, dict] = {name: cls.robot_defaults for name, cls in MODELS.items()}
#: the robot keys other than the model's parameters (from the robot format's JSON Schema, nhstab.yaml_keys)
ROBOT_KEYS = schema_keys("robot", "$defs", "robot")
#: the planning spaces (OMPL state spaces): Reeds-Shepp paths drive forward and reverse, Dubins paths
#: forward only; a robot's ``space`` is one of them, or None (the planner's default, :data:`DEFAULT_SPACE`)
SPACES = ("reeds_shepp", "dubins")
DEFAULT_SPACE = "reeds_shepp"
STABILIZER_KEYS = schema_keys("robot", "$defs", "stabilizer")
#: the stabilizer keys that are numbers (end_strategy is one of the gain schedule's END_STRATEGIES, cusps
#: one of its CUSP_HANDLING)
STABILIZER_NUMBERS = ("alpha", "delta", "gamma")
#: the model parameters that are lengths [m] (bounded like a map's coordinates)
LENGTH_PARAMS = ("wheelbase", "hitch_lengths")
#: how close consecutive polygon vertices may be and still count as distinct [m]
_SAME_POINT = 1e-9


@dataclass(frozen=True)
class RobotStabilizer:
    """A robot's defaults for the gramian law: its ``stabilizer:`` block (alpha, delta [s], gamma,
    end_strategy, cusps), the gain schedule's parameters that a run or a plan does not set itself. A
    value None is one the robot does not set (the gain schedule's own default,
    :class:`nhstab.control.StabilizerOptions`); :meth:`as_dict` leaves it out. A built-in robot sets
    all but, for a model whose nominals have no cusps, ``cusps``."""

    alpha: float | None = None
    delta: float | None = None
    gamma: float | None = None
    end_strategy: str | None = None
    cusps: str | None = None

    def as_dict(self) -> dict:
        """The keys set, in :data:`STABILIZER_KEYS` order: keyword arguments of
        :class:`nhstab.control.StabilizerOptions`."""
        return {k: getattr(self, k) for k in STABILIZER_KEYS if getattr(self, k) is not None}


@dataclass(frozen=True)
class Robot:
    """One robot: its model (with parameters and limits), footprint, and defaults."""

    model: Model
    footprint: Footprint
    margin: float
    stabilizer: RobotStabilizer = field(default_factory=RobotStabilizer)
    turning_radius: float = 0.5                          # planning radius [m]
    #: the planning space the robot is limited to ("dubins": forward only; "reeds_shepp"), or None: the
    #: planner's default (:data:`DEFAULT_SPACE`); an explicit space in the planning options overrides it
    space: str | None = None
    name: str = ""                                       # a label (default: the model's name)
    #: where the description came from ("default", a file, "map", "run config", ...)
    source: str = "default"
    #: what the description did to its input (e.g. repeated polygon vertices dropped)
    notes: tuple = ()
    #: the trailers' footprints (a car_trailer's, one per trailer, each in its trailer's frame)
    trailer_footprints: tuple = ()
    #: how errors name this robot's keys: the block's key path as the user wrote it (``robot``,
    #: ``robots[1]``, ``car.yaml: robot``, ``maps/yard.yaml: robot``), and the keys the description gave
    where: str = field(default="robot", compare=False)
    given: frozenset = field(default=frozenset(), compare=False)

    # ---- layout -----------------------------------------------------------------------------
    @property
    def state_names(self) -> tuple[str, ...]:
        return self.model.state_names

    @property
    def pose_columns(self) -> list[int]:
        """Indices of (x, y, theta) in the state."""
        names = list(self.model.state_names)
        return [names.index("x"), names.index("y"), names.index("theta")]

    @property
    def steering_column(self) -> int | None:
        """Index of the steering angle phi in the state, or None."""
        names = list(self.model.state_names)
        return names.index("phi") if "phi" in names else None

    @property
    def configuration_columns(self) -> list[int]:
        """Indices of the planning configuration in the state: (x, y, theta), then a car_trailer's
        trailer headings theta1 .. thetaN."""
        names = list(self.model.state_names)
        return self.pose_columns + [names.index(f"theta{i}") for i in range(1, self.trailers + 1)]

    @property
    def trailers(self) -> int:
        return int(getattr(self.model, "trailers", 0))

    @property
    def footprints(self) -> tuple:
        """One footprint per body: the robot's, then each trailer's."""
        return (self.footprint, *self.trailer_footprints)

    def body_poses(self, x) -> np.ndarray:
        """Poses (..., bodies, 3) of every body's reference point at states x (..., n); a single-body
        robot's is its (x, y, theta)."""
        x = np.asarray(x, dtype=float)
        if self.trailers:
            return self.model.body_poses(x)
        return x[..., self.pose_columns][..., None, :]

    def configuration(self, value, name: str = "pose") -> np.ndarray:
        """A start or goal as the planning configuration (x, y, theta[, theta1 .. thetaN]).

        Accepted, for every model alike: the pose x, y, theta (a car_trailer's trailers then in line
        with the car), the configuration itself, or the model's full state in its state order
        (:attr:`state_names`). Every plan starts and ends with the steering angle at 0, so a full state
        is accepted only with phi = 0; any other phi, or any other length, raises :class:`InputError`
        naming ``name`` (no coordinate is dropped)."""
        expected = self.start_goal_text()
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise InputError(name, expected, value) from None
        cols = self.configuration_columns
        if arr.ndim != 1 or not np.all(np.isfinite(arr)):
            raise InputError(name, expected, value)
        shown = [float(v) for v in arr] if arr.size < 12 else f"{arr.size} numbers"
        if len(arr) == self.model.n and len(arr) != len(cols):
            k = self.steering_column
            if k is not None and arr[k] != 0.0:
                lo, hi = self.model.state_limits()[k]
                beyond = "" if lo <= arr[k] <= hi else f", beyond the steering limits [{lo:g}, {hi:g}] rad"
                raise InputError(name, expected, shown,
                                 detail=f"phi = {arr[k]:g} rad{beyond}: the plan starts and ends with phi = 0")
            return arr[cols]
        if len(arr) == len(cols):
            return arr.copy()
        if len(arr) == 3 and self.trailers:
            return np.concatenate([arr, np.full(self.trailers, arr[2])])
        raise InputError(name, expected, shown)

    def start_goal_text(self) -> str:
        """What a start or goal of this robot may be (for errors and help)."""
        pose = "a pose of three finite numbers x,y,theta"
        if self.trailers:
            pose += " (the trailers in line) or x,y,theta," + ",".join(f"theta{i}" for i in range(1, self.trailers + 1))
        if self.model.n == len(self.configuration_columns):
            return pose
        return f"{pose}, or the {self.model.name}'s full state {','.join(self.model.state_names)} with phi = 0"

    def key(self, name: str) -> str:
        """The key the user writes to set ``name`` of this robot (a model parameter, ``margin``,
        ``turning_radius``, ``stabilizer.delta``, ...), for errors about its value; a value the
        description did not give is named as the model's default."""
        own = name if self.where.startswith("--") else f"{self.where}.{name}"
        return own if name in self.given else f"{own} (the {self.model.name}'s default)"

    def stabilizer_keys(self) -> dict:
        """For :func:`nhstab.errors.user_keys`: the gain schedule's parameters (alpha, delta, gamma, ...)
        named as this robot's stabilizer keys."""
        return {k: self.key(f"stabilizer.{k}") for k in STABILIZER_KEYS}

    @property
    def min_turning_radius(self) -> float:
        """The model's :attr:`~nhstab.models.Model.min_turning_radius`: L / tan(max_steer) for the cars,
        a car_trailer's last trailer's axle's smallest steady turn, 0 for robots that turn in place."""
        return float(self.model.min_turning_radius)

    def input_limits(self) -> np.ndarray:
        return self.model.input_limits()

    def state_limits(self) -> np.ndarray:
        return self.model.state_limits()

    def with_model(self, model: Model) -> "Robot":
        """The same robot with another model of the same kind (e.g. derated limits for planning)."""
        return dataclasses.replace(self, model=model)

    # ---- records ----------------------------------------------------------------------------
    def spec(self) -> dict:
        """The YAML form of this robot (every key explicit, ``space`` when the robot has one):
        ``robot_from_spec(r.spec())`` gives it back."""
        fp = self.footprint
        trailers = {}
        if self.trailer_footprints:
            trailers = {"trailer_footprint": [_footprint_spec(f) for f in self.trailer_footprints]}
        return {"model": self.model.name, **{k: _plain(v) for k, v in self.model.params().items()},
                "footprint": _footprint_spec(fp), **trailers, "margin": float(self.margin),
                "stabilizer": {k: (float(v) if k in STABILIZER_NUMBERS else str(v))
                               for k, v in self.stabilizer.as_dict().items()},
                "turning_radius": float(self.turning_radius), **({"space": self.space} if self.space else {}),
                "name": self.name or self.model.name}

    @property
    def planning_space(self) -> str:
        """The space this robot plans in when the options give none: its own, else :data:`DEFAULT_SPACE`."""
        return self.space or DEFAULT_SPACE

    def describe(self) -> dict:
        """What results record: the spec, the state layout, the limits and where it came from."""
        labels = {"trailer_footprint_labels": [f.label for f in self.trailer_footprints]} \
            if self.trailer_footprints else {}
        return {**self.spec(), "state_names": list(self.model.state_names),
                "input_names": list(self.model.input_names), "footprint_label": self.footprint.label, **labels,
                "min_turning_radius_m": self.min_turning_radius, "source": self.source,
                **({"notes": list(self.notes)} if self.notes else {})}


def _plain(v):
    """A model parameter for YAML and JSON: floats, lists of floats."""
    if isinstance(v, (list, tuple)):
        return [float(a) for a in v]
    return float(v)


def _footprint_spec(fp: Footprint) -> dict:
    if fp.radius is not None:
        return {"radius": float(fp.radius)}
    return {"polygon": [[float(a), float(b)] for a, b in fp.vertices]}


def default_footprint(model_name: str) -> Footprint:
    """The footprint of a model's built-in robot (:data:`MODEL_DEFAULTS`)."""
    if model_name not in MODELS:
        raise InputError("model", "one of " + ", ".join(sorted(MODELS)), model_name)
    return parse_footprint(MODELS[model_name].robot_defaults["footprint"])


def default_robot(model_name: str = "unicycle", **params) -> Robot:
    """The built-in robot of a model, with optional model parameters (e.g. ``wheelbase=2.7``)."""
    return robot_from_spec({"model": model_name, **params})


def robot_preset(model_name: str, preset: str) -> dict:
    """The description (the ``robot:`` block) of a model's named robot (its ``robot_presets``, e.g. the
    rwd_car's ``van``): ``{"model": ..., "name": ..., <the preset's keys>}``; a fresh copy."""
    if model_name not in MODELS:
        raise InputError("model", "one of " + ", ".join(sorted(MODELS)), model_name)
    presets = MODELS[model_name].robot_presets
    if preset not in presets:
        raise InputError(f"{model_name} preset", "one of " + (", ".join(sorted(presets)) or "none"), preset)
    return copy.deepcopy({"model": model_name, "name": preset, **presets[preset]})


def make_robot(model: str | Model = "unicycle", footprint: Footprint | dict | None = None,
               margin: float | None = None, stabilizer: dict | RobotStabilizer | None = None,
               turning_radius: float | None = None, space: str | None = None, **params) -> Robot:
    """A robot from Python values: ``make_robot("rwd_car", wheelbase=2.7, margin=0.1,
    footprint={"rectangle": {"length": 4.5, "width": 1.9, "rear_overhang": 1.0}})``; a footprint
    may also be a :class:`Footprint`, a stabilizer a :class:`RobotStabilizer`; ``space`` ("dubins":
    forward only, or "reeds_shepp") the space it plans in when the planning options give none.
    Validated like the YAML form."""
    if isinstance(model, Model):
        params = {**{k: v for k, v in model.params().items()}, **params}
        model = model.name
    spec: dict = {"model": model, **params}
    fp_obj = None
    if isinstance(footprint, Footprint):
        fp_obj = footprint
    elif footprint is not None:
        spec["footprint"] = footprint
    if margin is not None:
        spec["margin"] = margin
    if stabilizer is not None:
        spec["stabilizer"] = stabilizer.as_dict() if isinstance(stabilizer, RobotStabilizer) else stabilizer
    if turning_radius is not None:
        spec["turning_radius"] = turning_radius
    if space is not None:
        spec["space"] = space
    robot = robot_from_spec(spec, source="python")
    return robot if fp_obj is None else dataclasses.replace(robot, footprint=fp_obj)


def robot_from_spec(spec, where: str = "robot", source: str = "default") -> Robot:
    """Build and validate a robot from its YAML form (a mapping, or a model name as a string).
    Errors name the key as ``<where>.<key>`` (e.g. ``robot.footprint.polygon[2]``)."""
    if isinstance(spec, str):
        spec = {"model": spec}
    if not isinstance(spec, dict):
        raise InputError(where, "a mapping with at least the key model (or a model name)", _kind(spec))
    if "model" not in spec:
        raise InputError(f"{where}.model", "present (one of " + ", ".join(sorted(MODELS)) + ")", "missing")
    name = spec["model"]
    if not isinstance(name, str) or name not in MODELS:
        raise InputError(f"{where}.model", "one of " + ", ".join(sorted(MODELS)), name)
    model_cls = MODELS[name]
    param_names = [f.name for f in dataclasses.fields(model_cls) if f.init]
    for key in spec:
        if not isinstance(key, str) or (key not in ROBOT_KEYS and key not in param_names):
            allowed = ", ".join([*ROBOT_KEYS, *param_names])
            raise InputError(f"{where}.{key}", f"a {name} robot key: one of {allowed}", key)
    lists = {f.name for f in dataclasses.fields(model_cls) if f.init and isinstance(f.default, tuple)}
    params = {k: (_numbers(f"{where}.{k}", spec[k]) if k in lists else
                  _length(f"{where}.{k}", spec[k]) if k in LENGTH_PARAMS else _number(f"{where}.{k}", spec[k], 0.0, lo_open=True))
              for k in param_names if k in spec}
    with user_keys({f"{name}.{k}": f"{where}.{k}" for k in param_names}):
        model = make_model(name, **params)
    defaults = MODELS[name].robot_defaults
    notes: list[str] = []
    fp = parse_footprint(spec.get("footprint", defaults["footprint"]), f"{where}.footprint", notes)
    margin = _length(f"{where}.margin", spec.get("margin", defaults["margin"]), lo_open=False)
    stab = dict(defaults["stabilizer"])
    if "stabilizer" in spec:
        given = spec["stabilizer"]
        if not isinstance(given, dict):
            raise InputError(f"{where}.stabilizer", "a mapping with alpha, delta, gamma, end_strategy", _kind(given))
        # deferred: control.gramian imports scipy.integrate (heavy); a robot without a stabilizer block
        # is read without it
        from .control.gramian import CUSP_HANDLING, END_STRATEGIES, StabilizerOptions

        for k, v in given.items():
            if k not in STABILIZER_KEYS:
                raise InputError(f"{where}.stabilizer.{k}", "one of " + ", ".join(STABILIZER_KEYS), k)
            if k in ("end_strategy", "cusps"):
                allowed = END_STRATEGIES if k == "end_strategy" else CUSP_HANDLING
                if v not in allowed:
                    raise InputError(f"{where}.stabilizer.{k}", "one of " + ", ".join(allowed), v)
                stab[k] = v
                continue
            lo, lo_open = (0.5, False) if k == "gamma" else (0.0, True)
            stab[k] = _number(f"{where}.stabilizer.{k}", v, lo, lo_open=lo_open)
        # the gain schedule's own checks (gamma's bound, ...), under the keys of this block
        with user_keys({k: f"{where}.stabilizer.{k}" for k in STABILIZER_KEYS}):
            StabilizerOptions(**stab).validated()
    trailer_fps: tuple = ()
    n_trailers = int(getattr(model, "trailers", 0))
    if "trailer_footprint" in spec and not n_trailers:
        raise InputError(f"{where}.trailer_footprint", "only with a model that tows trailers (car_trailer)", name)
    if n_trailers:
        given = spec.get("trailer_footprint", defaults.get("trailer_footprint"))
        if isinstance(given, list):
            if len(given) != n_trailers:
                raise InputError(f"{where}.trailer_footprint", f"one footprint for every trailer, or a list of "
                                 f"{n_trailers} (one per trailer)", f"a list of {len(given)}")
            trailer_fps = tuple(parse_footprint(g, f"{where}.trailer_footprint[{i}]", notes)
                                for i, g in enumerate(given))
        else:
            one = parse_footprint(given, f"{where}.trailer_footprint", notes)
            trailer_fps = (one,) * n_trailers
    r_min = float(model.min_turning_radius)
    if "turning_radius" in spec:
        radius = _length(f"{where}.turning_radius", spec["turning_radius"])
        if radius < r_min - 1e-9:
            what = ("the last trailer's smallest steady turning radius" if n_trailers else
                    "the car's minimum turning radius L / tan(max_steer)")
            raise InputError(f"{where}.turning_radius", f"at least {what} = {r_min:.4g} m", radius)
    else:
        kind, value = defaults["turning_radius"]
        radius = value if kind == "fixed" else value * r_min
    space = spec.get("space")
    if space is not None:
        if space not in SPACES:
            raise InputError(f"{where}.space", "one of " + ", ".join(SPACES) + " (or leave it out: the planner's)",
                             space)
        if n_trailers and space != "reeds_shepp":
            raise InputError(f"{where}.space", "reeds_shepp (a car with a trailer reverses)", space)
    label = spec.get("name", name)
    if not isinstance(label, str) or not label.strip():
        raise InputError(f"{where}.name", "a non-empty string", label)
    given = frozenset(spec) | frozenset(f"stabilizer.{k}" for k in spec.get("stabilizer") or ())
    return Robot(model=model, footprint=fp, margin=margin, stabilizer=RobotStabilizer(**stab),
                 turning_radius=float(radius), space=space,
                 name=label, source=source, notes=tuple(notes), trailer_footprints=trailer_fps, where=where,
                 given=given)


def parse_footprint(spec, where: str = "footprint", notes: list | None = None) -> Footprint:
    """A footprint from ``{radius: R}``, ``{rectangle: {length, width, rear_overhang}}`` or
    ``{polygon: [[x, y], ...]}``. Repeated consecutive polygon vertices (and a repeated closing
    vertex) are dropped and noted; a polygon must keep >= 3 distinct vertices, be simple and have
    area; the reference point need not lie inside it."""
    if isinstance(spec, Footprint):
        return spec
    if not isinstance(spec, dict) or len(spec) != 1:
        raise InputError(where, "one of {radius: R}, {rectangle: {length, width, rear_overhang}}, {polygon: [...]}",
                         _kind(spec))
    (kind, value), = spec.items()
    if kind == "radius":
        return Footprint.disc(_length(f"{where}.radius", value))
    if kind == "rectangle":
        if not isinstance(value, dict):
            raise InputError(f"{where}.rectangle", "a mapping with length, width and optionally rear_overhang",
                             _kind(value))
        for k in value:
            if k not in ("length", "width", "rear_overhang"):
                raise InputError(f"{where}.rectangle.{k}", "one of length, width, rear_overhang", k)
        for k in ("length", "width"):
            if k not in value:
                raise InputError(f"{where}.rectangle.{k}", "present", "missing")
        length = _length(f"{where}.rectangle.length", value["length"])
        width = _length(f"{where}.rectangle.width", value["width"])
        back = None
        if "rear_overhang" in value:
            back = _length(f"{where}.rectangle.rear_overhang", value["rear_overhang"], lo_open=False)
            if back > length:
                raise InputError(f"{where}.rectangle.rear_overhang", f"at most the length {length:g} m", back)
        return Footprint.rectangle(length, width, rear_overhang=back)
    if kind == "polygon":
        if not isinstance(value, list):
            raise InputError(f"{where}.polygon", "a list of [x, y] points", _kind(value))
        if len(value) > MAX_POLYGON_VERTICES:
            raise InputError(f"{where}.polygon", f"at most {MAX_POLYGON_VERTICES:,} [x, y] points", len(value))
        pts = []
        for i, p in enumerate(value):
            if not (isinstance(p, (list, tuple)) and len(p) == 2):
                raise InputError(f"{where}.polygon[{i}]", "[x, y] (two numbers)", p)
            pts.append([_length(f"{where}.polygon[{i}][{j}]", c, lo_open=False, lo=-math.inf) for j, c in enumerate(p)])
        v = np.array(pts, dtype=float).reshape(-1, 2)
        cleaned = clean_ring(v)
        if notes is not None and len(cleaned) != len(v):
            notes.append(f"{where}: dropped {len(v) - len(cleaned)} repeated vertex(es)")
        if len(cleaned) < 3:
            raise InputError(f"{where}.polygon", "at least 3 distinct points", f"{len(cleaned)} distinct")
        shown = pts if len(pts) <= 12 else f"{len(pts)} points"
        if _on_a_line(cleaned):
            raise InputError(f"{where}.polygon", "a polygon with area (not all points on a line)", shown)
        if not is_simple_polygon(cleaned):
            raise InputError(f"{where}.polygon", "a simple polygon (its edges must not cross or touch each other)",
                             shown, detail="it intersects itself")
        if abs(polygon_area(cleaned)) < 1e-12:
            raise InputError(f"{where}.polygon", "a polygon with area", shown)
        fp = Footprint.polygon(cleaned)
        return dataclasses.replace(fp, label=f"polygon {len(cleaned)} vertices")
    raise InputError(where, "one of the keys radius, rectangle, polygon", kind)


def clean_ring(v: np.ndarray, tol: float = _SAME_POINT) -> np.ndarray:
    """A polygon ring without repeated consecutive vertices (including a repeated closing vertex)."""
    if len(v) == 0:
        return v
    keep = [0]
    for i in range(1, len(v)):
        if np.max(np.abs(v[i] - v[keep[-1]])) > tol:
            keep.append(i)
    out = v[keep]
    while len(out) > 1 and np.max(np.abs(out[-1] - out[0])) <= tol:
        out = out[:-1]
    return out


def _on_a_line(v: np.ndarray) -> bool:
    """Every point within 1e-12 of the coordinates' scale of the line through the first point and the
    point farthest from it (or all points the same)."""
    d = v - v[0]
    far = d[int(np.argmax(np.hypot(d[:, 0], d[:, 1])))]
    n = math.hypot(*far)
    scale = max(1.0, float(np.abs(v).max()))
    return n <= 1e-12 * scale or bool(np.all(np.abs(d[:, 0] * far[1] - d[:, 1] * far[0]) / n <= 1e-12 * scale))


def load_robot(path) -> Robot:
    """Read a robot file (``--robot-config``): YAML whose top level is the robot block, or holds it
    under ``robot:``. Errors name the file and the key."""
    from pathlib import Path


    path = Path(path)
    data = read_yaml_mapping(path, "--robot-config", "robot description (YAML)")
    if set(data) == {"robot"}:
        data = data["robot"]
    return robot_from_spec(data, where=f"{path.name}: robot", source=str(path))


def resolve_robot(robot=None, map_robot=None, default: str = "unicycle", source: str = "", *,
                  where: str = "robot", map_where: str = "robot") -> Robot:
    """The robot a command uses: ``robot`` (a :class:`Robot`, a model name or a spec mapping) if
    given, else the map's ``robot:`` block, else the default model's built-in robot. ``where`` and
    ``map_where`` are how errors name the two blocks (e.g. ``robots[1]``, ``yard.yaml: robot``)."""
    if isinstance(robot, Robot):
        return robot
    if robot is not None:
        return robot_from_spec(robot, where=where, source=source or "argument")
    if map_robot is not None:
        return robot_from_spec(map_robot, where=map_where, source="map")
    return default_robot(default)


def map_robot_where(m) -> str:
    """How errors name a map's ``robot:`` block: the map file's key (as the map's own errors do)."""
    source = getattr(m, "source", "")
    return f"{source}: robot" if source else "robot"


def _number(key: str, v, lo: float = -math.inf, lo_open: bool = False, hi: float = math.inf,
            unit: str = "") -> float:
    """A finite number > lo (``lo_open``) or >= lo, and at most ``hi``, or an InputError naming ``key``."""
    ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
    try:
        ok = ok and math.isfinite(v)
    except OverflowError:            # an integer too large for a float
        ok, v = False, f"an integer of {v.bit_length()} bits"
    if ok:
        ok = (v > lo if lo_open else v >= lo) and v <= hi
    if not ok:
        u = f" {unit}" if unit else ""
        if hi < math.inf:
            low = "-" if lo == -math.inf else f"{lo:g}"
            expected = f"a number in {'(' if lo_open else '['}{low}, {hi:g}]{u}"
        else:
            expected = "a finite number" + ("" if lo == -math.inf else f" {'>' if lo_open else '>='} {lo:g}")
        raise InputError(key, expected, v, detail=number_hint(v))
    return float(v)


def _length(key: str, v, lo_open: bool = True, lo: float = 0.0) -> float:
    """A robot's length (a footprint's size or coordinate, a wheelbase, a hitch, a margin): finite, and
    within MAX_COORD_M, the bound on every coordinate of a map (see :mod:`nhstab.limits`)."""
    return _number(key, v, -MAX_COORD_M if lo == -math.inf else lo, lo_open=lo_open, hi=MAX_COORD_M, unit="m")


def _numbers(key: str, v) -> list[float]:
    """A list-valued model parameter (e.g. ``hitch_lengths``): a list of positive finite numbers (a
    single number is a list of one)."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        v = [v]
    if not isinstance(v, list) or not v or len(v) > 64:
        raise InputError(key, "a non-empty list of positive numbers, e.g. [3.0]", _kind(v))
    return [_length(f"{key}[{i}]", a) for i, a in enumerate(v)]


def _kind(value) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, str):
        return value                 # shown quoted; text like 1e9 gets the YAML hint (InputError)
    return {dict: "a mapping", list: "a list", bool: "a boolean"}.get(
        type(value), repr(value))
