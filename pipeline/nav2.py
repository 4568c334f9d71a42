"""The robot a Nav2 user already has: an nhstab robot read from a Nav2 parameters file.

A Nav2 parameters file (the layout of nav2_bringup's ``nav2_params.yaml``) describes the robot in
three places, and this module reads each of them:

* **the footprint**, in ``local_costmap.local_costmap.ros__parameters`` and
  ``global_costmap.global_costmap.ros__parameters`` (the one-level layout
  ``local_costmap.ros__parameters`` is read too): ``footprint``, a string of points
  ``"[[x, y], ...]"`` (or a YAML list of [x, y]) in the ``robot_base_frame``, else
  ``robot_radius``; and ``footprint_padding`` (Nav2's default 0.01 m). As in Nav2's costmap, a
  footprint other than ``""`` or ``"[]"`` wins over ``robot_radius``. The padding moves every polygon
  vertex outward by the padding in x and in y (Nav2's ``padFootprint``: x += sign(x) pad,
  y += sign(y) pad); a radius gives a disc of radius ``robot_radius + footprint_padding``. When both
  costmaps describe the robot, their (padded) footprints must agree.
* **the kinematics**, in ``planner_server.ros__parameters``: each planner plugin named in
  ``planner_plugins`` (default ``[GridBased]``). ``nav2_smac_planner/SmacPlannerHybrid`` with
  ``motion_model_for_search`` DUBIN (Nav2's default) or REEDS_SHEPP and ``minimum_turning_radius``
  R (Nav2's default 0.4 m) gives a car whose minimum turning radius L / tan(max_steer) is R, and
  which plans in the dubins space (forward only, the robot's ``space``) or reeds_shepp;
  ``SmacPlannerLattice`` (STATE_LATTICE) reads the motion model and turning radius from the
  ``lattice_metadata`` of its ``lattice_filepath`` (an ``ackermann`` lattice gives a car, in the dubins
  space unless ``allow_reverse_expansion``; ``diff`` and ``omni`` a unicycle). Any other planner (NavFn, Smac 2D, Theta*), no planner server or a radius of
  0 gives a unicycle: the robot turns in place.
* **the speed limits**, in ``controller_server.ros__parameters`` (each plugin in
  ``controller_plugins``, default ``[FollowPath]``: DWB's ``max_vel_x``, ``max_speed_xy`` and
  ``max_vel_theta``, Regulated Pure Pursuit's ``desired_linear_vel``, MPPI's ``vx_max`` and ``wz_max``)
  and ``velocity_smoother.ros__parameters.max_velocity`` [vx, vy, wz]: the smallest of those given
  is the robot's ``max_speed`` (and a unicycle's ``max_turn_rate``).

The car is an ``rwd_car`` whose reference point (the rear axle) is the costmap's
``robot_base_frame``; Nav2 does not know a wheelbase, so it keeps the model's ``max_steer`` and takes
L = R tan(max_steer), or takes a given wheelbase and max_steer = atan(L / R). Everything else (the
margin, the stabilizer, the steering rate) is the model's default. Every value is checked: a
malformed footprint string, NaN, a negative radius or speed is refused with an :class:`InputError`
naming its key path in the file (``nav2_params.yaml: local_costmap.local_costmap.ros__parameters.footprint``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .geometry import Footprint
from .limits import MAX_POLYGON_VERTICES
from .models import MODELS
from .robot import Robot, parse_footprint, robot_from_spec
from .safe_io import read_text, read_yaml_mapping

__all__ = ["NAV2_PREFIX", "Nav2Robot", "is_nav2_params", "parse_footprint_string", "read_nav2_robot"]

#: the prefix that marks a robot file as a Nav2 parameters file (``--robot-config nav2:FILE``)
NAV2_PREFIX = "nav2:"
COSTMAPS = ("local_costmap", "global_costmap")
#: the models a Nav2 robot may be given as
NAV2_MODELS = ("unicycle", "rwd_car", "fwd_car")
#: Nav2's own defaults for the keys this module reads (nav2_costmap_2d, nav2_smac_planner)
NAV2_DEFAULTS = {"footprint_padding": 0.01, "motion_model_for_search": "DUBIN", "minimum_turning_radius": 0.4}
HYBRID_MOTION_MODELS = {"DUBIN": "dubins", "REEDS_SHEPP": "reeds_shepp"}
#: per controller plugin class: (linear speed keys, angular speed keys)
CONTROLLER_KEYS = {
    "DWBLocalPlanner": (("max_vel_x", "max_speed_xy"), ("max_vel_theta",)),
    "RegulatedPurePursuitController": (("desired_linear_vel",), ()),
    "MPPIController": (("vx_max",), ("wz_max",)),
}
#: every Nav2 key the reader reads (docs/reference/nav2.md has a row for each)
NAV2_KEYS = ("footprint", "robot_radius", "footprint_padding", "planner_plugins", "plugin", "motion_model_for_search",
             "minimum_turning_radius", "lattice_filepath", "allow_reverse_expansion", "lattice_metadata",
             "motion_model", "turning_radius", "controller_plugins", "max_velocity",
             *(k for lin, ang in CONTROLLER_KEYS.values() for k in (*lin, *ang)))
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_SAME = 1e-9


@dataclass(frozen=True)
class Nav2Robot:
    """A robot read from a Nav2 parameters file, with what was read from where."""

    robot: Robot
    #: the planning space the Smac planner searches ("dubins", "reeds_shepp"), or None (a unicycle); the
    #: robot carries it (``robot.space``), so nhstab plans in it unless the planning options give another
    space: str | None
    #: one line per value taken: what, from which key (the CLI prints them)
    lines: tuple[str, ...]


def is_nav2_params(data) -> bool:
    """Whether a YAML mapping looks like a ROS 2 parameters file: a top-level node holds
    ``ros__parameters`` (``node: {ros__parameters: ...}`` or ``node: {node: {ros__parameters: ...}}``)."""
    if not isinstance(data, dict):
        return False
    for value in data.values():
        if isinstance(value, dict):
            if "ros__parameters" in value:
                return True
            if any(isinstance(v, dict) and "ros__parameters" in v for v in value.values()):
                return True
    return False


def read_nav2_robot(path, model: str | None = None, wheelbase: float | None = None,
                    margin: float | None = None) -> Nav2Robot:
    """The nhstab robot of a Nav2 parameters file (see the module docstring). ``model`` (one of
    :data:`NAV2_MODELS`) overrides the model inferred from the planner; ``wheelbase`` [m] sets a car's
    wheelbase (its max_steer then gives the Smac planner's minimum turning radius); ``margin`` [m] the
    planning margin (default: the model's)."""
    path = Path(path)
    data = read_yaml_mapping(path, "--robot-config", "Nav2 parameters file (YAML)")
    file = path.name
    if not is_nav2_params(data):
        raise InputError(f"{file}", "a ROS 2 parameters file (a node such as local_costmap with ros__parameters)",
                         "no node with ros__parameters")
    if model is not None and model not in NAV2_MODELS:
        raise InputError("model", "one of " + ", ".join(NAV2_MODELS), model)
    if margin is not None:
        margin = _number("margin", margin, lo=0.0)
    if wheelbase is not None:
        wheelbase = _number("wheelbase", wheelbase, lo=0.0, lo_open=True)
    lines: list[str] = []
    fp, fp_line = _footprint(data, file)
    lines.append(fp_line)
    kin = _kinematics(data, file, path.parent, model)
    lines.append(kin["line"])
    chosen = model or kin["model"]
    if model is not None and model != kin["model"]:
        lines.append(f"model {model} (given), where the planner suggests {kin['model']}")
    spec: dict = {"model": chosen, "name": path.stem}
    radius = kin["radius"]
    if chosen != "unicycle":
        if not radius:
            raise InputError(kin["radius_key"] or f"{file}: planner_server.ros__parameters",
                             f"a minimum turning radius > 0 for a {chosen} (a SmacPlannerHybrid or SmacPlannerLattice)",
                             radius if kin["radius_key"] else "none", detail="give the model unicycle for a robot "
                             "that turns in place")
        max_steer = _model_default(chosen, "max_steer")
        if wheelbase is None:
            spec["wheelbase"] = radius * math.tan(max_steer)
            lines.append(f"wheelbase {spec['wheelbase']:.4g} m = R tan(max_steer {max_steer:g} rad), so that "
                         f"L / tan(max_steer) = {radius:g} m")
        else:
            spec["wheelbase"] = float(wheelbase)
            spec["max_steer"] = math.atan(wheelbase / radius)
            lines.append(f"max_steer {spec['max_steer']:.4g} rad = atan(L {wheelbase:g} m / R {radius:g} m)")
    elif radius:
        spec["turning_radius"] = radius
        lines.append(f"planning turning radius {radius:g} m (the planner's)")
    (speed, speed_line), (turn, turn_line) = _speeds(data, file)
    if speed is not None:
        spec["max_speed"] = speed
    lines.append(speed_line)
    if turn is not None and chosen == "unicycle":
        spec["max_turn_rate"] = turn
        lines.append(turn_line)
    spec["footprint"] = _footprint_spec(fp)
    space = kin["space"] if chosen != "unicycle" else None
    if space is not None:
        spec["space"] = space
    if margin is not None:
        spec["margin"] = margin
    robot = robot_from_spec(spec, where=f"{file}: robot", source=f"{NAV2_PREFIX}{path}")
    lines = [line.replace(f"{file}: ", "") for line in lines]
    robot = dataclasses.replace(robot, footprint=fp, notes=tuple(lines))
    return Nav2Robot(robot=robot, space=space, lines=tuple(lines))


# ---- the footprint ------------------------------------------------------------------------------
def parse_footprint_string(text: str, key: str = "footprint") -> list[list[float]]:
    """The points of a Nav2 footprint string ``"[[x, y], [x, y], ...]"`` (commas or blanks between
    values, as Nav2's ``parseVVF`` reads them), parsed as text, never evaluated. Exactly two numbers per
    point, at least three points; anything else (NaN, inf, a missing bracket, text after the last
    bracket) raises :class:`InputError` naming ``key``. ``""`` and ``"[]"`` give [] (no footprint)."""
    expected = 'a footprint string of [x, y] points, e.g. "[[0.3, 0.2], [0.3, -0.2], [-0.3, -0.2], [-0.3, 0.2]]"'
    if not isinstance(text, str):
        raise InputError(key, expected, text)
    if text.strip() in ("", "[]"):
        return []
    shown = text if len(text) <= 80 else text[:77] + "..."
    points: list[list[float]] = []
    current: list[float] = []
    depth, i, n, done = 0, 0, len(text), False

    def fail(what: str):
        raise InputError(key, expected, shown, detail=f"{what} at character {i + 1}")

    while i < n:
        c = text[i]
        if c in " \t\r\n,":
            i += 1
            continue
        if done:
            fail(f"{c!r} after the closing bracket")
        if c == "[":
            depth += 1
            if depth > 2:
                fail("a third level of brackets")
            current = []
            i += 1
        elif c == "]":
            if depth == 0:
                fail("a ']' with no '['")
            if depth == 2:
                if len(current) != 2:
                    fail(f"a point of {len(current)} number(s), not 2")
                points.append(current)
                if len(points) > MAX_POLYGON_VERTICES:
                    raise InputError(key, f"at most {MAX_POLYGON_VERTICES:,} points", f"{len(points)} or more")
            depth -= 1
            done = depth == 0
            i += 1
        else:
            m = _NUMBER.match(text, i)
            if m is None:
                fail(f"{c!r}, not a number")
            if depth != 2:
                fail("a number outside a [x, y] point")
            value = float(m.group())
            if not math.isfinite(value):
                fail(f"{m.group()}, not a finite number")
            current.append(value)
            i = m.end()
            if i < n and text[i] not in " \t\r\n,]":
                fail(f"{text[i]!r} after a number")
    if depth != 0:
        raise InputError(key, expected, shown, detail=f"{depth} bracket(s) not closed")
    if len(points) < 3:
        raise InputError(key, expected, shown, detail=f"{len(points)} point(s): a footprint needs at least 3")
    return points


def _node(data: dict, name: str, file: str):
    """A node's ``ros__parameters`` mapping and its key path, or (None, None) if the file has none."""
    if name not in data:
        return None, None
    node = data[name]
    if not isinstance(node, dict):
        raise InputError(f"{file}: {name}", "a mapping (a ROS 2 node with ros__parameters)", _kind(node))
    if isinstance(node.get(name), dict) and "ros__parameters" in node[name]:
        node, path = node[name], f"{name}.{name}"
    else:
        path = name
    if "ros__parameters" not in node:
        raise InputError(f"{file}: {path}", "a node with ros__parameters", "no ros__parameters")
    params = node["ros__parameters"]
    if not isinstance(params, dict):
        raise InputError(f"{file}: {path}.ros__parameters", "a mapping", _kind(params))
    return params, f"{file}: {path}.ros__parameters"


def _footprint(data: dict, file: str) -> tuple[Footprint, str]:
    found = []
    for name in COSTMAPS:
        params, where = _node(data, name, file)
        if params is None:
            continue
        got = _costmap_footprint(params, where)
        if got is not None:
            found.append(got)
    if not found:
        raise InputError(f"{file}: local_costmap.local_costmap.ros__parameters.footprint",
                         "a footprint or robot_radius in local_costmap or global_costmap", "neither")
    (fp, text, key), rest = found[0], found[1:]
    for other_fp, other_text, other_key in rest:
        if not _same_footprint(fp, other_fp):
            raise InputError(other_key, f"the same footprint as {key} ({text})", other_text,
                             detail="the two costmaps describe different robots")
    return fp, f"footprint {text} (from {' and '.join(k for _, _, k in found)})"


def _costmap_footprint(params: dict, where: str):
    """(footprint, description, key) of one costmap, or None when it gives neither footprint nor robot_radius."""
    pad_given = "footprint_padding" in params
    pad = _number(f"{where}.footprint_padding", params.get("footprint_padding", NAV2_DEFAULTS["footprint_padding"]),
                  lo=0.0)
    pad_text = f"footprint_padding {pad:g} m" + ("" if pad_given else " (Nav2's default)")
    raw = params.get("footprint")
    key = f"{where}.footprint"
    if isinstance(raw, list):
        points = _point_list(raw, key)
    elif raw is None:
        points = []
    else:
        points = parse_footprint_string(raw, key)
    if points:
        padded = [[x + _sign(x) * pad, y + _sign(y) * pad] for x, y in points]
        try:
            fp = parse_footprint({"polygon": padded}, key)
        except InputError as exc:
            raise exc.renamed(key, got=raw if isinstance(raw, str) else points) from None
        return fp, f"polygon of {len(fp.vertices)} vertices with {pad_text}", key
    if "robot_radius" not in params:
        return None
    r = _number(f"{where}.robot_radius", params["robot_radius"], lo=0.0, lo_open=True)
    return Footprint.disc(r + pad), f"disc r = {r:g} m + {pad_text}", f"{where}.robot_radius"


def _point_list(raw: list, key: str) -> list[list[float]]:
    if len(raw) > MAX_POLYGON_VERTICES:
        raise InputError(key, f"at most {MAX_POLYGON_VERTICES:,} points", len(raw))
    pts = []
    for i, p in enumerate(raw):
        if not (isinstance(p, list) and len(p) == 2):
            raise InputError(f"{key}[{i}]", "[x, y] (two numbers)", p)
        pts.append([_number(f"{key}[{i}][{j}]", c) for j, c in enumerate(p)])
    if len(pts) < 3:
        raise InputError(key, "at least 3 [x, y] points", len(pts))
    return pts


def _same_footprint(a: Footprint, b: Footprint) -> bool:
    if (a.radius is None) != (b.radius is None):
        return False
    if a.radius is not None:
        return abs(a.radius - b.radius) <= _SAME
    return a.vertices.shape == b.vertices.shape and bool(np.all(np.abs(a.vertices - b.vertices) <= _SAME))


def _footprint_spec(fp: Footprint) -> dict:
    if fp.radius is not None:
        return {"radius": float(fp.radius)}
    return {"polygon": [[float(x), float(y)] for x, y in fp.vertices]}


def _sign(x: float) -> float:
    return -1.0 if x < 0 else (1.0 if x > 0 else 0.0)


# ---- the kinematics -----------------------------------------------------------------------------
def _class_name(plugin) -> str:
    """``nav2_smac_planner/SmacPlannerHybrid`` or ``nav2_smac_planner::SmacPlannerHybrid`` -> the class."""
    return re.split(r"/|::", plugin.strip())[-1] if isinstance(plugin, str) else ""


def _plugins(params: dict, where: str, list_key: str, default: str) -> list[tuple[str, dict, str]]:
    """(id, block, key path) of each plugin a server names in ``list_key`` (Nav2's default: [default])."""
    ids = params.get(list_key, [default])
    if not (isinstance(ids, list) and all(isinstance(p, str) for p in ids)):
        raise InputError(f"{where}.{list_key}", "a list of plugin names", _kind(ids))
    out = []
    for pid in ids:
        block = params.get(pid)
        if block is None:
            continue
        if not isinstance(block, dict):
            raise InputError(f"{where}.{pid}", "a mapping with plugin", _kind(block))
        out.append((pid, block, f"{where}.{pid}"))
    return out


def _kinematics(data: dict, file: str, folder: Path, model: str | None = None) -> dict:
    """model, radius (0: none), radius_key, space and a line saying where they came from. With ``model``
    unicycle given, a Lattice planner's file that cannot be read is not needed."""
    params, where = _node(data, "planner_server", file)
    unicycle = {"model": "unicycle", "radius": 0.0, "radius_key": None, "space": None}
    if params is None:
        return {**unicycle, "line": "model unicycle: no planner_server (a robot that turns in place)"}
    found = []
    others = []
    for pid, block, key in _plugins(params, where, "planner_plugins", "GridBased"):
        cls = _class_name(block.get("plugin"))
        if cls == "SmacPlannerHybrid":
            found.append(_hybrid(block, key))
        elif cls == "SmacPlannerLattice":
            try:
                found.append(_lattice(block, key, folder))
            except InputError:
                if model != "unicycle":
                    raise
                others.append(f"{pid} (SmacPlannerLattice, its lattice file not read: the model is given)")
        else:
            others.append(f"{pid} ({cls or 'no plugin'})")
    if not found:
        what = ", ".join(others) if others else "no planner plugin"
        return {**unicycle, "line": f"model unicycle: {what} plans for a robot that turns in place"}
    first = found[0]
    for other in found[1:]:
        if (other["model"], other["space"]) != (first["model"], first["space"]) or \
                abs(other["radius"] - first["radius"]) > _SAME:
            raise InputError(other["radius_key"], f"the same kinematics as {first['radius_key']} "
                             f"({first['model']}, R = {first['radius']:g} m)", other["radius"],
                             detail="two planner plugins describe different robots")
    return first


def _hybrid(block: dict, key: str) -> dict:
    mm_given = "motion_model_for_search" in block
    mm = block.get("motion_model_for_search", NAV2_DEFAULTS["motion_model_for_search"])
    if mm not in HYBRID_MOTION_MODELS:
        raise InputError(f"{key}.motion_model_for_search", "DUBIN or REEDS_SHEPP (SmacPlannerHybrid's motion models)",
                         mm)
    r_given = "minimum_turning_radius" in block
    r = _number(f"{key}.minimum_turning_radius", block.get("minimum_turning_radius",
                                                            NAV2_DEFAULTS["minimum_turning_radius"]), lo=0.0)
    src = f"{key} (SmacPlannerHybrid, {mm}{'' if mm_given else ', Nav2 default'}, minimum_turning_radius " \
          f"{r:g} m{'' if r_given else ', Nav2 default'})"
    if r == 0.0:
        return {"model": "unicycle", "radius": 0.0, "radius_key": f"{key}.minimum_turning_radius", "space": None,
                "line": f"model unicycle: minimum_turning_radius 0 in {src}"}
    return {"model": "rwd_car", "radius": r, "radius_key": f"{key}.minimum_turning_radius",
            "space": HYBRID_MOTION_MODELS[mm],
            "line": f"model rwd_car, {'forward only' if mm == 'DUBIN' else 'forward and reverse'} "
                    f"(space {HYBRID_MOTION_MODELS[mm]}): {src}"}


def _lattice(block: dict, key: str, folder: Path) -> dict:
    """SmacPlannerLattice: the motion model and radius are in its lattice file's ``lattice_metadata``."""
    fkey = f"{key}.lattice_filepath"
    name = block.get("lattice_filepath")
    if not isinstance(name, str) or not name.strip():
        raise InputError(fkey, "the path of the lattice primitives file (its lattice_metadata gives the minimum "
                         "turning radius)", _kind(name) if name is not None else "missing")
    p = Path(name)
    if not p.is_absolute():
        p = folder / p
    if not p.is_file():
        raise InputError(fkey, "a lattice primitives file nhstab can open (absolute, or relative to the parameters "
                         "file; launch substitutions are not expanded)", name)
    try:
        meta = json.loads(read_text(p, fkey, "lattice primitives file (JSON)"))["lattice_metadata"]
        motion, r = meta["motion_model"], meta["turning_radius"]
    except (ValueError, KeyError, TypeError):
        raise InputError(fkey, "a lattice primitives file (JSON) with lattice_metadata.motion_model and "
                         "turning_radius", name) from None
    r = _number(f"{fkey}: lattice_metadata.turning_radius", r, lo=0.0)
    reverse = block.get("allow_reverse_expansion", False)
    if not isinstance(reverse, bool):
        raise InputError(f"{key}.allow_reverse_expansion", "true or false", reverse)
    src = f"{key} (SmacPlannerLattice, STATE_LATTICE, lattice {motion}, turning_radius {r:g} m)"
    if motion in ("diff", "omni") or r == 0.0:
        return {"model": "unicycle", "radius": 0.0, "radius_key": fkey, "space": None,
                "line": f"model unicycle: {src}"}
    if motion != "ackermann":
        raise InputError(f"{fkey}: lattice_metadata.motion_model", "ackermann, diff or omni", motion)
    space = "reeds_shepp" if reverse else "dubins"
    return {"model": "rwd_car", "radius": r, "radius_key": fkey, "space": space,
            "line": f"model rwd_car, {'forward and reverse' if reverse else 'forward only'} "
                    f"(space {space}): {src}"}


# ---- the speeds ---------------------------------------------------------------------------------
def _speeds(data: dict, file: str) -> tuple[tuple, tuple]:
    """((max_speed or None, line), (max_turn_rate or None, line))."""
    linear: list[tuple[float, str]] = []
    angular: list[tuple[float, str]] = []
    params, where = _node(data, "controller_server", file)
    if params is not None:
        for _pid, block, key in _plugins(params, where, "controller_plugins", "FollowPath"):
            lin_keys, ang_keys = CONTROLLER_KEYS.get(_class_name(block.get("plugin")), ((), ()))
            for k in lin_keys:
                if k in block:
                    linear.append((_number(f"{key}.{k}", block[k], lo=0.0, lo_open=True), f"{key}.{k}"))
            for k in ang_keys:
                if k in block:
                    angular.append((_number(f"{key}.{k}", block[k], lo=0.0, lo_open=True), f"{key}.{k}"))
    params, where = _node(data, "velocity_smoother", file)
    if params is not None and "max_velocity" in params:
        key = f"{where}.max_velocity"
        mv = params["max_velocity"]
        if not (isinstance(mv, list) and len(mv) == 3):
            raise InputError(key, "[vx, vy, wz] (three numbers)", _kind(mv))
        vx = _number(f"{key}[0]", mv[0], lo=0.0, lo_open=True)
        wz = _number(f"{key}[2]", mv[2], lo=0.0, lo_open=True)
        linear.append((vx, f"{key}[0]"))
        angular.append((wz, f"{key}[2]"))
    out = []
    for values, what, unit in ((linear, "max_speed", "m/s"), (angular, "max_turn_rate", "rad/s")):
        if not values:
            out.append((None, f"{what}: the model's default (no controller_server or velocity_smoother limit read)"))
            continue
        value, key = min(values)
        more = f", the smallest of {len(values)}" if len(values) > 1 else ""
        out.append((value, f"{what} {value:g} {unit} (from {key}{more})"))
    return out[0], out[1]


# ---- values -------------------------------------------------------------------------------------
def _model_default(model: str, param: str) -> float:
    return float(next(f.default for f in dataclasses.fields(MODELS[model]) if f.name == param))


def _number(key: str, v, lo: float = -math.inf, lo_open: bool = False) -> float:
    """A finite number >= lo (> lo with ``lo_open``); ROS 2 parameter files may hold integers."""
    ok = isinstance(v, (int, float)) and not isinstance(v, bool)
    try:
        ok = ok and math.isfinite(v)
    except OverflowError:            # an integer too large for a float
        ok = False
    if ok:
        ok = v > lo if lo_open else v >= lo
    if not ok:
        bound = "" if lo == -math.inf else f" {'>' if lo_open else '>='} {lo:g}"
        raise InputError(key, f"a finite number{bound}", v)
    return float(v)


def _kind(value) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, str):
        return value
    return {dict: "a mapping", list: "a list", bool: "a boolean"}.get(type(value), repr(value))
