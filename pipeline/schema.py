"""The JSON Schemas (draft 2020-12) of nhstab's four YAML formats, built from the code's own definitions.

``nhstab schema --out DIR`` writes them; the package ships them as ``nhstab/schemas/*.schema.json``
(:mod:`nhstab.yaml_keys` reads them for the loaders' key sets), and a test holds the shipped files to
what :func:`build_schemas` returns. What comes from the code:

* the run config: every section's keys, types and defaults from its dataclass
  (:class:`~nhstab.execution.config.RunOptions` and its sections), the enumerations (controller kinds,
  windows, gains, planners, spaces, tube kinds, noise distributions) from the registries;
* robot descriptions: the models and each model's parameters with their defaults (the model
  dataclasses of :data:`nhstab.models.MODELS`), the stabilizer's end strategies and cusp handling;
* maps and batch configs: their keys, with the bounds of :mod:`nhstab.limits`.

Every key carries a description: a key without one is refused here (:func:`_describe`), so a new
key cannot ship undocumented. The loaders keep their own checks of the values (errors name the key
path); the schemas state the same types, ranges and enumerations for editors and other tools.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path

from .control import END_STRATEGIES, WINDOWS
from .control.frozen import MAX_GAIN
from .control.gramian import CUSP_HANDLING
from .execution.config import DISTRIBUTIONS, PROCESS_PER, RunOptions
from .execution.controllers import CONTROLLERS, GAINS, Q_FOOTPRINT
from .limits import (
    MAX_BATCH_TRIALS,
    MAX_COORD_M,
    MAX_GAMMA,
    MAX_HEADING_RAD,
    MAX_NOISE_LEVEL,
    MAX_NOISE_SCALE,
    MAX_PROBABILITY,
    MAX_RATE_HZ,
    MAX_SEED,
    MAX_SUBSTEPS,
    MIN_RATE_HZ,
)
from .models import MODELS
from .planning import PLANNERS, SPACES
from .robot import LENGTH_PARAMS
from .tubes.base import MAX_DISCARDS, TUBE_KINDS
from .yaml_keys import FORMATS

DRAFT = "https://json-schema.org/draft/2020-12/schema"

# ---- building blocks ------------------------------------------------------------------------------


def _number(description: str, lo=None, lo_open: bool = False, hi=None, hi_open: bool = False,
            integer: bool = False, **extra) -> dict:
    out: dict = {"type": "integer" if integer else "number"}
    if lo is not None:
        out["exclusiveMinimum" if lo_open else "minimum"] = lo
    if hi is not None:
        out["exclusiveMaximum" if hi_open else "maximum"] = hi
    return {**out, **extra, "description": description}


def _enum(values, description: str, **extra) -> dict:
    return {"enum": list(values), **extra, "description": description}


def _coord(description: str = "a coordinate [m]") -> dict:
    return _number(description, -MAX_COORD_M, False, MAX_COORD_M)


def _point(description: str) -> dict:
    return {"type": "array", "items": _coord(), "minItems": 2, "maxItems": 2, "description": description}


def _pose(description: str, most: int = 3) -> dict:
    heading = _number("a heading [rad]", -MAX_HEADING_RAD, False, MAX_HEADING_RAD)
    return {"type": "array", "prefixItems": [_coord("x [m]"), _coord("y [m]")], "items": heading,
            "minItems": 3, "maxItems": most, "description": description}


def _object(properties: dict, description: str, required=(), **extra) -> dict:
    out: dict = {"type": "object", "properties": properties, "additionalProperties": False}
    if required:
        out["required"] = list(required)
    return {**out, **extra, "description": description}


def _with_default(sub: dict, default) -> dict:
    return {**sub, "default": default} if default is not None else sub


# ---- robot ----------------------------------------------------------------------------------------

_PARAM_TEXT = {
    "wheelbase": "distance from the rear axle to the front axle [m]",
    "max_speed": "largest speed [m/s]",
    "max_turn_rate": "largest turn rate [rad/s]",
    "max_steer": "largest steering angle [rad]",
    "max_steer_rate": "largest steering rate [rad/s]",
    "hitch_lengths": "one per trailer: the distance from the hitch to the trailer's axle [m]",
    "jackknife_limit": "largest hitch angle between the car and a trailer, or two trailers [rad]",
}


#: the model parameters that are angle limits: positive, below pi/2 (nhstab.models.base.angle_limit)
_ANGLE_PARAMS = ("max_steer", "jackknife_limit")


def _footprint() -> dict:
    return {"oneOf": [
        _object({"radius": _number("the disc's radius [m]", 0, True, MAX_COORD_M)},
                "a disc centred on the reference point", ["radius"]),
        _object({"rectangle": _object({
            "length": _number("length along x [m]", 0, True, MAX_COORD_M),
            "width": _number("width along y [m]", 0, True, MAX_COORD_M),
            "rear_overhang": _number("how far the body reaches behind the reference point [m]", -MAX_COORD_M,
                                     False, MAX_COORD_M, default=0.0)},
            "a rectangle along x", ["length", "width"])}, "a rectangle", ["rectangle"]),
        _object({"polygon": {"type": "array", "items": _point("a vertex [x, y] [m]"), "minItems": 3,
                             "description": "a simple polygon with area, in the robot's frame [m]"}},
                "a polygon", ["polygon"]),
    ], "description": "the body's outline in the robot's frame (x forward from the reference point, y to the "
                      "left): {radius: R}, {rectangle: {length, width, rear_overhang}} or {polygon: [[x, y], ...]}"}


def _robot_defs() -> dict:
    """``$defs`` of a robot description: ``robot`` (the mapping), ``robot_spec`` (it or a model name),
    ``footprint`` and ``stabilizer``."""
    stabilizer = _object({
        "alpha": _number("the decay parameter of the 6-alpha weighting [1/s]", 0, True),
        "delta": _number("the window length [s]", 0, True),
        "gamma": _number("the gain factor (>= 1/2, Proposition 1)", 0.5, False, MAX_GAMMA),
        "end_strategy": _enum(END_STRATEGIES, "how the gain schedule ends: frozen (the last whole window) or "
                                              "extend (the window slides along the continuation)"),
        "cusps": _enum(CUSP_HANDLING, "one schedule across cusps, or one per cusp-free piece"),
    }, "the gramian law's defaults for this robot (default: the model's)")
    conditions = []
    for name, cls in MODELS.items():
        params = {}
        for f in dataclasses.fields(cls):
            if not f.init:
                continue
            if isinstance(f.default, tuple):
                length = _number("[m]", 0, True, MAX_COORD_M)
                params[f.name] = {"oneOf": [{"type": "array", "items": length, "minItems": 1, "maxItems": 64},
                                            length],
                                  "default": list(f.default),
                                  "description": _describe(_PARAM_TEXT, f.name) + " (a single number is a list of one)"}
            elif f.name in LENGTH_PARAMS:
                params[f.name] = _number(_describe(_PARAM_TEXT, f.name), 0, True, MAX_COORD_M, default=f.default)
            elif f.name in _ANGLE_PARAMS:
                params[f.name] = _number(_describe(_PARAM_TEXT, f.name), 0, True, math.pi / 2, True, default=f.default)
            else:
                params[f.name] = _number(_describe(_PARAM_TEXT, f.name), 0, True, default=f.default)
        # the model's built-in robot (its robot_defaults): defaults of the keys a description leaves out
        defaults = cls.robot_defaults
        params["footprint"] = {"default": defaults["footprint"], "description": f"the {name}'s default footprint"}
        params["margin"] = {"default": defaults["margin"], "description": f"the {name}'s default margin [m]"}
        params["stabilizer"] = {"default": defaults["stabilizer"],
                                "description": f"the {name}'s default stabilizer parameters"}
        rule, value = defaults["turning_radius"]
        params["turning_radius"] = ({"default": value, "description": f"the {name}'s default [m]"} if rule == "fixed"
                                    else {"description": f"the {name}'s default: {value:g} x its smallest turning "
                                                         "radius"})
        params["trailer_footprint"] = ({"default": defaults["trailer_footprint"],
                                        "description": f"the {name}'s default trailer footprint"}
                                       if "trailer_footprint" in defaults else
                                       {"not": {}, "description": "only a model that tows trailers takes one"})
        conditions.append({"if": {"properties": {"model": {"const": name}}, "required": ["model"]},
                           "then": {"properties": params}})
    robot = {
        "type": "object",
        "properties": {
            "model": _enum(MODELS, "the kinematic model"),
            "footprint": {"$ref": "#/$defs/footprint", "description": "the body's outline (default: the model's)"},
            "margin": _number("planning margin: the clearance every nominal keeps from the known obstacles [m] "
                              "(default: the model's)", 0, False, MAX_COORD_M),
            "stabilizer": {"$ref": "#/$defs/stabilizer", "description": "the gramian law's defaults (default: the "
                                                                       "model's)"},
            "turning_radius": _number("the planning turning radius [m], at least the model's smallest (default: "
                                      "the model's rule)", 0, True, MAX_COORD_M),
            "name": {"type": "string", "minLength": 1, "description": "a label (batch cells and reports use it); "
                                                                       "default: the model's name"},
            "space": _enum(SPACES, "the planning space: reeds_shepp drives forward and reverse, dubins forward only "
                                   "(car_trailer: reeds_shepp); default: reeds_shepp, unless a run or plan says"),
            "trailer_footprint": {"oneOf": [{"$ref": "#/$defs/footprint"},
                                            {"type": "array", "items": {"$ref": "#/$defs/footprint"}, "minItems": 1}],
                                  "description": "car_trailer only: one footprint for every trailer, or one per "
                                                 "trailer, each in its trailer's frame (default: the model's)"},
        },
        "required": ["model"],
        "allOf": conditions,
        "unevaluatedProperties": False,
        "description": "a robot description: the model, its parameters by name (per model, with their "
                       "defaults), the footprint, margin, stabilizer and turning radius",
    }
    return {"robot": robot,
            "robot_spec": {"oneOf": [_enum(MODELS, "a model name: its built-in robot"), {"$ref": "#/$defs/robot"}],
                           "description": "a model name or a robot description"},
            "footprint": _footprint(), "stabilizer": stabilizer}


def robot_schema() -> dict:
    return {"$schema": DRAFT, "title": "nhstab robot description",
            "description": "a robot file (--robot-config): the robot description at the top level, or under "
                           "robot:",
            "oneOf": [{"$ref": "#/$defs/robot"},
                      _object({"robot": {"$ref": "#/$defs/robot", "description": "the robot description"}},
                              "the description under robot:", ["robot"])],
            "$defs": _robot_defs()}


# ---- map ------------------------------------------------------------------------------------------

def map_schema() -> dict:
    points = lambda n, what: {"type": "array", "items": _point("a point [x, y] [m]"), "minItems": n,  # noqa: E731
                              "description": what}
    shape = {"oneOf": [
        _object({"polygon": points(3, "a simple polygon, either orientation (thin parts allowed)")},
                "a polygon", ["polygon"]),
        _object({"line": points(2, "a curb or thin wall: the segments joining consecutive points")},
                "a polyline of zero thickness", ["line"]),
        _object({"circle": _object({"center": _point("the centre [x, y] [m]"),
                                    "radius": _number("the radius [m]", 0, True, MAX_COORD_M)},
                                   "a disc", ["center", "radius"])}, "a circle", ["circle"]),
        _object({"box": _object({"center": _point("the centre [x, y] [m]"),
                                 "size": {"type": "array", "items": _number("[m]", 0, True, MAX_COORD_M),
                                          "minItems": 2, "maxItems": 2, "description": "[length, width] [m]"},
                                 "yaw": _number("the length's direction [rad]", -MAX_COORD_M, False, MAX_COORD_M,
                                                default=0.0)},
                                "a rotated rectangle", ["center", "size"])}, "a box", ["box"]),
    ], "description": "an obstacle: exactly one of polygon, line, circle, box"}
    path = {"type": "string", "description": "the base map file, relative to this YAML file (or absolute)"}
    scen = {"type": "string", "description": "a .scen file or polygon_scenarios.csv whose start/goal pairs become "
                                             "the map's problems (relative to this YAML file)"}
    fmt = lambda name: {"const": name, "description": "the base map's format"}  # noqa: E731
    bases = {
        "base_ros": _object({"format": fmt("ros"), "path": path,
                             "unknown": _enum(("occupied", "free"), "how the grid's unknown cells count",
                                              default="occupied")}, "a ROS map_server map", ["format", "path"]),
        "base_movingai": _object({"format": fmt("movingai"), "path": path,
                                  "cell_size": _number("metres per cell", 0, True, default=1.0), "scenarios": scen},
                                 "a Moving AI .map", ["format", "path"]),
        "base_benchmr_svg": _object({"format": fmt("benchmr_svg"), "path": path,
                                     "convex_hull": {"type": "boolean", "default": False,
                                                     "description": "replace every polygon by its convex hull"},
                                     "scenarios": scen}, "a Bench-MR SVG", ["format", "path"]),
        "base_nhstab": _object({"format": fmt("nhstab"), "path": path},
                               "another nhstab YAML map (nested at most 4 deep)", ["format", "path"]),
    }
    shapes = lambda what: {"type": "array", "items": {"$ref": "#/$defs/shape"}, "default": [],  # noqa: E731
                           "description": what}
    top = {
        "name": {"type": "string", "minLength": 1, "description": "the map's name (default: the file stem)"},
        "description": {"type": "string", "description": "one line, listed by nhstab examples"},
        "bounds": {"type": "array", "items": _coord(), "minItems": 4, "maxItems": 4,
                   "description": "[xmin, ymin, xmax, ymax] [m] with xmin < xmax, ymin < ymax; required unless base "
                                  "gives them, and replaces the base's"},
        "base": {"oneOf": [{"$ref": f"#/$defs/{k}"} for k in bases],
                 "description": "start from a map in another format: its grids, obstacles, bounds, problems, and "
                                "its start, goal and robot where this file gives none"},
        "obstacles": shapes("obstacles known a priori (in the robot's map)"),
        "unknown_obstacles": shapes("obstacles in the world but not in the robot's map"),
        "start": _pose("the start pose [x, y, theta] (m, m, rad)"),
        "goal": _pose("the goal pose [x, y, theta] (m, m, rad)"),
        "robot": {"$ref": "#/$defs/robot_spec", "description": "the map's default robot"},
    }
    out = _object(top, "an nhstab YAML map")
    return {"$schema": DRAFT, "title": "nhstab YAML map", **out,
            "$defs": {"shape": shape, **bases, **_robot_defs()}}


# ---- run config -----------------------------------------------------------------------------------

#: every run-config key's description, by section (``""``: the top level)
_RUN_TEXT = {
    "": {
        "map": "a map file, relative to the config file, or example:NAME (default: the command line's MAP)",
        "robot": "the robot: a model name or a robot description (default: the map's robot, else the unicycle)",
        "start": "the start pose [x, y, theta] (m, m, rad); a car_trailer may add its trailers' headings "
                 "(default: the map's)",
        "goal": "the goal pose, as start (default: the map's)",
        "seed": "root seed: initial error, sensor and process noise, every planner call",
        "rate_hz": "controller rate [Hz] (zero-order hold)",
        "substeps": "RK4 steps of the plant per control period",
        "saturate": "clip the inputs to the robot's limits",
        "headroom": "plan nominals within this fraction of the input limits",
        "max_time_s": "simulated time limit [s] (default: 2 x the active plan's duration + 30 s)",
        "controller": "the feedback law", "noise": "noise levels by state name", "sensor": "the planar lidar",
        "monitor": "the collision monitor", "planning": "the planner of the first plan and every replan",
        "replan": "replanning", "tolerance": "when the goal counts as reached", "tube": "every plan's error tube",
    },
    "controller": {
        "kind": "the feedback law", "type": "another name for kind",
        "window": "the gramian's window: future (P_c, Proposition 1), frozen-time (causal), past (P_r, Remark 2: "
                  "not stabilizing, study only)",
        "alpha": "gramian law: decay parameter [1/s] (default: the robot's)",
        "delta": "gramian law: window length [s] (default: the robot's)",
        "gamma": "gramian law: gain factor (default: the robot's)",
        "max_gain": f"frozen-time law: the gain norm above which it holds its last admissible gramian "
                    f"(default {MAX_GAIN:g})",
        "q": "TVLQR: the diagonal of Q, one positive number per state (default: identity), or footprint: Q from "
             "how far a state error moves the robot's outline",
        "r": "TVLQR: the diagonal of R, one positive number per input (default: identity)",
        "gains": "auto (gramian only): alpha, delta and gamma chosen per plan by the error tube",
    },
    "noise": {
        "scale": "multiplies every noise level (0: noiseless)",
        "initial": "initial-error std (uniform: half-width) by state name, and its distribution",
        "sensor": "measurement-noise std by state name", "process": "process-noise intensity by state name "
                                                                    "[state unit / sqrt(s)], or per: metre "
                                                                    "[state unit / sqrt(m)]",
        "impulses": "state jumps at given times: [{time: t, <state>: jump, ...}]",
    },
    "sensor": {
        "range_m": "maximum range [m]", "fov_deg": "field of view [degrees], centred on the heading",
        "fov_rad": "the field of view in radians (instead of fov_deg)", "rate_hz": "scan rate [Hz]",
        "resolution_deg": "angle between beams [degrees], at most the field of view",
        "resolution_rad": "the angle between beams in radians (instead of resolution_deg)",
        "mount": "the sensor's position [x, y] in the robot frame [m]",
    },
    "monitor": {"rate_hz": "how often the rest of the nominal is checked against discovered obstacles [Hz]",
                "horizon_s": "how far ahead along the nominal [s]"},
    "planning": {
        "planner": "the OMPL planner", "space": "the OMPL state space (default: the robot's, else reeds_shepp)",
        "time_limit_s": "budget of each planning call [s]",
        "margin": "the clearance every nominal keeps from the known obstacles [m], or auto (from the error tube); "
                  "default: the robot's",
        "turning_radius": "the planning turning radius [m] (default: the robot's)",
        "guide": "the guided search (a grid shortest path sets the subgoals); false: OMPL over the whole map",
        "fit": "change a plan whose error tube is not certified clear (the margin it needs, other maneuvers)",
    },
    "replan": {
        "pause_s": "simulated time the robot stands still while a replan runs [s]",
        "max_attempts": "failed planning attempts in a row before the run gives up",
        "max_replans": "replans per run", "budget_growth": "from the third attempt on, the planning budget's factor",
        "at_cusps": "at each cusp, replan the rest when its predicted tube is not certified clear",
        "max_cusp_replans": "cusp replans per run",
    },
    "tolerance": {"position_m": "goal position tolerance [m]", "heading_rad": "goal heading tolerance [rad]"},
    "tube": {
        "kind": "auto: linear where it holds, sampled rollouts elsewhere",
        "probability": "the tube's probability p", "confidence": "the sampled tube's confidence",
        "discards": "rollouts the sampled tube's reach and clearance leave out",
        "require_certified": "refuse a plan whose tube is not certified clear (the run ends not_certified)",
    },
}

#: value constraints beyond the type, by "section.key" (enumerations and ranges of the validators)
_RUN_RANGES = {
    "seed": {"minimum": 0, "maximum": MAX_SEED},
    "rate_hz": {"minimum": MIN_RATE_HZ, "maximum": MAX_RATE_HZ},
    "substeps": {"minimum": 1, "maximum": MAX_SUBSTEPS},
    "headroom": {"exclusiveMinimum": 0, "maximum": 1},
    "max_time_s": {"exclusiveMinimum": 0},
    "controller.kind": {"enum": list(CONTROLLERS)},
    "controller.type": {"enum": list(CONTROLLERS)},
    "controller.window": {"enum": list(WINDOWS)},
    "controller.alpha": {"exclusiveMinimum": 0}, "controller.delta": {"exclusiveMinimum": 0},
    "controller.gamma": {"minimum": 0.5, "maximum": MAX_GAMMA}, "controller.max_gain": {"exclusiveMinimum": 0},
    "controller.q": {"items": {"type": "number", "exclusiveMinimum": 0}},
    "controller.r": {"items": {"type": "number", "exclusiveMinimum": 0}},
    "controller.gains": {"enum": list(GAINS)},
    "sensor.range_m": {"exclusiveMinimum": 0}, "sensor.fov_deg": {"exclusiveMinimum": 0, "maximum": 360},
    "sensor.fov_rad": {"exclusiveMinimum": 0, "maximum": 2 * math.pi}, "sensor.rate_hz": {"exclusiveMinimum": 0},
    "sensor.resolution_deg": {"exclusiveMinimum": 0, "maximum": 360},
    "sensor.resolution_rad": {"exclusiveMinimum": 0, "maximum": 2 * math.pi},
    "sensor.mount": {"prefixItems": [{"type": "number"}, {"type": "number"}], "minItems": 2, "maxItems": 2},
    "monitor.rate_hz": {"exclusiveMinimum": 0, "maximum": MAX_RATE_HZ},
    "monitor.horizon_s": {"exclusiveMinimum": 0},
    "planning.planner": {"enum": list(PLANNERS)}, "planning.space": {"enum": list(SPACES)},
    "planning.time_limit_s": {"exclusiveMinimum": 0},
    "planning.turning_radius": {"exclusiveMinimum": 0},
    "replan.pause_s": {"minimum": 0}, "replan.max_attempts": {"minimum": 1}, "replan.max_replans": {"minimum": 0},
    "replan.budget_growth": {"minimum": 1}, "replan.max_cusp_replans": {"minimum": 0},
    "tolerance.position_m": {"exclusiveMinimum": 0}, "tolerance.heading_rad": {"exclusiveMinimum": 0},
    "tube.kind": {"enum": list(TUBE_KINDS)},
    "tube.probability": {"exclusiveMinimum": 0, "maximum": MAX_PROBABILITY},
    "tube.confidence": {"exclusiveMinimum": 0, "exclusiveMaximum": 1},
    "tube.discards": {"minimum": 0, "maximum": MAX_DISCARDS},
}

#: JSON types of the dataclass annotations (``from __future__ import annotations``: text)
_TYPES = {"float": "number", "int": "integer", "bool": "boolean", "str": "string", "dict": "object",
          "tuple": "array", "None": "null"}


def _describe(table: dict, key: str) -> str:
    if key not in table:
        raise KeyError(f"no description of the key {key!r}: add one to nhstab.schema")
    return table[key]


def _field_schema(section: str, name: str, type_text: str, default) -> dict:
    """One dataclass field as a schema: its type from the annotation, its default, the constraints of
    :data:`_RUN_RANGES` and the description of :data:`_RUN_TEXT`."""
    path = f"{section}.{name}" if section else name
    names = [t.strip().split("[")[0] for t in str(type_text).split("|")]
    types = [_TYPES[t] for t in names]
    if "number" in types and "integer" in types:
        types.remove("integer")
    extra = dict(_RUN_RANGES.get(path, {}))
    if "enum" in extra:
        out = {"enum": extra.pop("enum") + ([None] if "null" in types else [])}
    else:
        out = {"type": types[0] if len(types) == 1 else types}
        if "array" in types and "items" not in extra and "prefixItems" not in extra:
            out["items"] = {"type": "number"}
    if name == "q" and section == "controller":
        out = {"oneOf": [{"type": "array", **extra}, {"const": Q_FOOTPRINT}, {"type": "null"}]}
        extra = {}
    if name == "margin" and section == "planning":
        out = {"oneOf": [{"type": "number", "minimum": 0, "maximum": MAX_COORD_M}, {"const": "auto"},
                         {"type": "null"}]}
    out.update(extra)
    if default is not None:
        out["default"] = list(default) if isinstance(default, tuple) else default
    out["description"] = _describe(_RUN_TEXT[section], name)
    return out


def _levels(description: str, extra: dict | None = None) -> dict:
    return {"type": "object", "properties": extra or {},
            "additionalProperties": _number("a level", 0, False, MAX_NOISE_LEVEL),
            "description": description}


def _noise_section() -> dict:
    text = _RUN_TEXT["noise"]
    jump = _number("a state jump", -MAX_NOISE_LEVEL, False, MAX_NOISE_LEVEL)
    return _object({
        "scale": _number(text["scale"], 0, False, MAX_NOISE_SCALE, default=1.0),
        "initial": _levels(text["initial"], {"distribution": _enum(DISTRIBUTIONS, "the initial error's distribution",
                                                                   default=DISTRIBUTIONS[0])}),
        "sensor": _levels(text["sensor"]),
        "process": _levels(text["process"], {"per": _enum(PROCESS_PER, "what the intensity is per: second (a "
                                                           "disturbance in time, at rest too) or metre (in the "
                                                           "distance travelled, none at rest)",
                                                           default=PROCESS_PER[0])}),
        "impulses": {"type": "array", "items": {"type": "object", "properties": {"time": _number("[s]", 0)},
                                                "required": ["time"], "additionalProperties": jump},
                     "description": text["impulses"]},
    }, _RUN_TEXT[""]["noise"])


def _run_sections() -> dict:
    """The properties of a run config but ``map``: RunOptions' fields, each section from its dataclass."""
    defaults = RunOptions()
    out = {}
    for f in dataclasses.fields(RunOptions):
        value = getattr(defaults, f.name)
        if f.name == "noise":
            out[f.name] = _noise_section()
        elif dataclasses.is_dataclass(value):
            props = {}
            for sf in dataclasses.fields(value):
                v = getattr(value, sf.name)
                if f.name == "sensor" and sf.name.endswith("_rad"):
                    deg = sf.name.replace("_rad", "_deg")
                    props[deg] = _field_schema("sensor", deg, sf.type, round(math.degrees(v), 9))
                    v = None                        # the radians key: the same angle, its default given in degrees
                props[sf.name] = _field_schema(f.name, sf.name, sf.type, v)
                if f.name == "controller" and sf.name == "kind":
                    props["type"] = _field_schema("controller", "type", sf.type, None)
            section = _object(props, _describe(_RUN_TEXT[""], f.name))
            if f.name == "sensor":
                section["not"] = {"anyOf": [{"required": ["fov_deg", "fov_rad"]},
                                            {"required": ["resolution_deg", "resolution_rad"]}]}
            out[f.name] = section
        elif f.name == "robot":
            out[f.name] = {"$ref": "#/$defs/robot_spec", "description": _RUN_TEXT[""]["robot"]}
        elif f.name in ("start", "goal"):
            out[f.name] = _pose(_RUN_TEXT[""][f.name], 12)
        else:
            out[f.name] = _field_schema("", f.name, f.type, value)
    return out


def run_config_schema() -> dict:
    props = {"map": {"type": "string", "description": _RUN_TEXT[""]["map"]}, **_run_sections()}
    return {"$schema": DRAFT, "title": "nhstab run config", **_object(props, "a run config (nhstab run --config)"),
            "$defs": _robot_defs()}


# ---- batch config ---------------------------------------------------------------------------------

#: the run-config keys a batch's run: block may not give (the batch sets them)
RUN_EXCLUDED = ("map", "robot", "start", "goal", "seed")


def batch_config_schema() -> dict:
    run = {k: v for k, v in _run_sections().items() if k not in RUN_EXCLUDED}
    positive_list = lambda item, what: {"type": "array", "items": item, "minItems": 1,  # noqa: E731
                                        "description": what}
    problems = {"oneOf": [
        {"const": "map", "description": "the map's start and goal"},
        {"type": "array", "minItems": 1, "items": _object({"start": _pose("[x, y, theta]", 12),
                                                           "goal": _pose("[x, y, theta]", 12)},
                                                          "one problem", ["start", "goal"])},
        _object({"first": _number("the first of the map's problems", 0, integer=True),
                 "count": _number("how many", 1, integer=True)}, "a range of the map's problems", ["first", "count"]),
    ], "default": "map", "description": "map (the map's start and goal), a list of {start, goal}, or {first, count}: "
                                        "a range of the map's problems"}
    entry = _object({"path": {"type": "string", "description": "a map file, relative to the config, or example:NAME"},
                     "problems": problems,
                     "cell_size": _number("metres per cell, for Moving AI maps", 0, True)},
                    "a map of the batch", ["path"])
    top = {
        "name": {"type": "string", "minLength": 1, "description": "the batch's name (default: the file stem)"},
        "root_seed": _number("trial k of every cell gets child k of this seed", 0, False, MAX_SEED, integer=True),
        "trials": _number("trials per cell", 1, False, MAX_BATCH_TRIALS, integer=True),
        "maps": positive_list(entry, "the maps; their labels (map names) differ"),
        "robots": positive_list({"$ref": "#/$defs/robot_spec"}, "the robots (default: each map's); labels differ"),
        "robot": {"$ref": "#/$defs/robot_spec", "description": "one robot: the same as robots: [that]; not with "
                                                               "robots"},
        "controllers": {**positive_list(_enum(CONTROLLERS, "a controller"), "one cell per controller"),
                        "default": ["gramian"]},
        "grid": _object({
            "noise": positive_list(_number("a noise scale", 0, False, MAX_NOISE_SCALE),
                                   "noise scales (multiplying every level of run.noise)"),
            "alpha": positive_list(_number("[1/s]", 0, True), "gramian only: alpha values (default: the robot's)"),
            "delta": positive_list(_number("[s]", 0, True), "gramian only: delta values (default: the robot's)"),
            "gamma": positive_list(_number("", 0.5, False, MAX_GAMMA), "gramian only: gamma values (default: the "
                                                                        "robot's)"),
            "window": positive_list(_enum(WINDOWS, "a window"), "gramian only: windows (default: "
                                                                "run.controller.window)"),
        }, "one cell per combination of its values", default={}),
        "run": _object(run, "the options of every trial: the run-config keys but map, robot, start, goal and seed",
                       default={}),
    }
    out = _object(top, "a batch config (nhstab batch CONFIG)", ["root_seed", "trials", "maps"])
    out["not"] = {"required": ["robot", "robots"]}
    return {"$schema": DRAFT, "title": "nhstab batch config", **out, "$defs": _robot_defs()}


# ---- all ------------------------------------------------------------------------------------------

_BUILDERS = {"map": map_schema, "robot": robot_schema, "run-config": run_config_schema,
             "batch-config": batch_config_schema}


def build_schemas() -> dict[str, dict]:
    """Every format's schema by name (:data:`nhstab.yaml_keys.FORMATS`)."""
    return {name: copy.deepcopy(_BUILDERS[name]()) for name in FORMATS}


def schema_text(schema: dict) -> str:
    """A schema as its shipped file's text (sorted by nothing: the properties keep the code's order)."""
    return json.dumps(schema, indent=2, ensure_ascii=False) + "\n"


def write_schemas(out: Path) -> list[Path]:
    """Write every schema into ``out`` as ``<name>.schema.json``; returns the files."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for name, schema in build_schemas().items():
        path = out / f"{name}.schema.json"
        path.write_text(schema_text(schema), encoding="utf-8")
        files.append(path)
    return files


def stale_schemas(folder: Path) -> list[str]:
    """The schema files of ``folder`` that differ from what :func:`write_schemas` writes (or are missing)."""
    folder = Path(folder)
    out = []
    for name, schema in build_schemas().items():
        path = folder / f"{name}.schema.json"
        if not path.is_file() or path.read_text(encoding="utf-8") != schema_text(schema):
            out.append(path.name)
    return out
