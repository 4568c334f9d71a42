# ---------------------------------------------------------------------------------------------
# The nhstab YAML map format (pipeline.maps.yaml_format.load_yaml_map; load_map picks it for a
# .yaml/.yml file whose top level has no `image` key).
#
# Units are metres and radians; world frame x right, y up; a pose is [x, y, theta].
#
#   name: parking-lot                   # optional non-empty string; default: the file stem
#   description: what happens here      # optional one-line string (listed by `nhstab examples`)
#   bounds: [xmin, ymin, xmax, ymax]    # required unless `base` gives them; replaces the base's
#   base:                               # optional: start from a map in another format
#     format: ros                       #   ros | movingai | benchmr_svg | nhstab (another of these
#                                       #   YAML files, nested at most 4 deep)
#     path: ../nav2/depot.yaml          #   relative to this YAML file (or absolute)
#     unknown: occupied                 #   ros only: how unknown cells count (occupied | free)
#     cell_size: 0.5                    #   movingai only: metres per cell (default 1.0)
#     convex_hull: false                #   benchmr_svg only: replace polygons by their hulls
#     scenarios: Berlin_0_256.map.scen  #   movingai / benchmr_svg only, optional: a .scen file or
#                                       #   polygon_scenarios.csv whose start/goal pairs become
#                                       #   the map's problems (relative to this YAML file)
#   obstacles:                          # known a priori (in the robot's map)
#     - polygon: [[x, y], [x, y], [x, y], ...]     # simple (convex or not), >= 3 points, either
#                                                  # orientation; a repeated closing point and
#                                                  # repeated consecutive points are dropped (noted
#                                                  # in `nhstab map info`). Edges drawn out and back
#                                                  # (a spike, a fold) are thin parts of zero
#                                                  # thickness, and a polygon of zero area (collinear
#                                                  # points, a ring folded onto itself) is thin as a
#                                                  # whole: its edges are the obstacle (noted)
#     - line: [[x, y], [x, y], ...]                # a curb, a thin wall: the segments joining
#                                                  # consecutive points, zero thickness; >= 2
#                                                  # distinct points; they may cross; end on the
#                                                  # first point for a closed outline (still thin)
#     - circle: {center: [x, y], radius: r}        # r > 0
#     - box: {center: [x, y], size: [length, width], yaw: 0.0}
#                                                  # length along yaw (radians, optional, default 0)
#   unknown_obstacles: [...]            # same shapes: present in the world, not in the robot's map
#   start: [x, y, theta]                # optional; exactly three numbers
#   goal: [x, y, theta]                 # optional; exactly three numbers
#   robot: {model: rwd_car, wheelbase: 2.5}   # optional default robot: a robot description
#                                       # (nhstab.robot: model, its parameters, footprint, margin,
#                                       # stabilizer, turning_radius), checked strictly, kept as a dict
#
# A base map contributes its occupancy grids, obstacles, unknown obstacles, bounds and problems,
# and its start, goal and robot where the YAML gives none; the YAML's obstacles are appended and
# its `bounds` replace the base's.
#
# Validation is strict. Each failure raises one MapError (an InputError, a ValueError) on one line
# that names the file and the key path (e.g. "parking_lot.yaml: obstacles[3].polygon"), what was
# expected and what was given:
#   * unknown keys at any level (`robot` is checked as a robot description), missing required keys;
#   * wrong types (booleans and quoted numbers are not numbers), NaN or infinite numbers, numbers
#     of magnitude above 1e6 (nhstab.limits.MAX_COORD_M);
#   * a polygon with fewer than 3 points (a line is `line`), or whose area part (what remains once
#     the edges drawn out and back are set aside) crosses or touches itself; a line with fewer than 2
#     distinct points; a non-positive radius or box size;
#   * bounds not ordered (xmin < xmax and ymin < ymax);
#   * start or goal outside the bounds, or its reference point (x, y) inside or on the boundary of a
#     known polygon or circle, or in an occupied cell of a known grid (pure geometry; unknown
#     obstacles may cover them, which is a legitimate experiment);
#   * a base file that is missing or fails to load (the error names both files);
#   * YAML syntax errors, an empty document, a file that is not UTF-8.
# ---------------------------------------------------------------------------------------------
"""nhstab's own YAML map format: :func:`load_yaml_map` (strict; every error names the file and key).

The format is documented in the comment block above, and with every key's type and default in
docs/reference/map-yaml.md.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from ..errors import PipelineError, number_hint
from ..geometry import is_simple_polygon, point_in_polygon, polygon_area
from ..limits import MAX_COORD_M, MAX_POLYGON_VERTICES, MAX_YAML_BYTES
from ..robot import robot_from_spec
from ..safe_io import check_keys, load_yaml, read_text
from ..safe_io import yaml_type_name as _type_name
from ..yaml_keys import schema, schema_keys, schema_required
from .base import Circle, Map, MapError, OccupancyGrid, Polygon, Pose, Problem, Shape, box_polygon, polyline, ring_parts
from .movingai import load_movingai_map, load_movingai_scenarios
from .ros import load_ros_map
from .svg import load_benchmr_scenarios, load_benchmr_svg

# the keys, from the format's JSON Schema (nhstab.yaml_keys): the top level, each base format's, the shapes'
_TOP_KEYS = schema_keys("map")
_BASE_KEYS = {name[len("base_"):]: schema_keys("map", "$defs", name)
              for name in schema("map")["$defs"] if name.startswith("base_")}
_BASE_REQUIRED = {fmt: schema_required("map", "$defs", f"base_{fmt}") for fmt in _BASE_KEYS}
#: each shape's schema by its key (polygon, line, circle, box)
_SHAPES = {kind: spec["properties"][kind] for spec in schema("map")["$defs"]["shape"]["oneOf"]
           for kind in spec["properties"]}
#: how deep nhstab-format base maps may nest (a file that is its own base would recurse forever)
_MAX_BASE_NESTING = 4
_nesting = [0]
_MAX_DEPTH = 64
#: largest magnitude accepted for any number in a YAML map (keeps products of coordinates finite)
MAX_ABS = MAX_COORD_M
#: a line of n points is a ring of 2 (n - 1) vertices
MAX_LINE_POINTS = MAX_POLYGON_VERTICES // 2 + 1


def load_yaml_map(path: str | Path) -> Map:
    """Load a map in nhstab's YAML format (see the module docstring) with strict validation."""
    path = Path(path)
    text = read_text(path, what="YAML map file", limit=MAX_YAML_BYTES, error=MapError)
    return parse_yaml_map(text, path)


def parse_yaml_map(text: str, path: str | Path) -> Map:
    """Build a :class:`Map` from YAML ``text``; ``path`` names it in errors and anchors relative paths."""
    path = Path(path)
    return _Reader(path).map(load_yaml(text, str(path), MapError))


def is_file(path: Path) -> bool:
    """``path.is_file()``, False instead of an exception for unrepresentable or over-long names."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def point_in_shape(x: float, y: float, shape: Shape) -> bool:
    """Whether (x, y) lies inside or on the boundary of a polygon or circle (pure geometry)."""
    if isinstance(shape, Circle):
        (cx, cy), r = shape.center, shape.radius
        return math.hypot(x - cx, y - cy) <= r
    return point_in_polygon(x, y, shape.vertices)


def point_in_grid(x: float, y: float, grid: OccupancyGrid) -> bool:
    """Whether (x, y) lies in an occupied cell of ``grid`` (points outside the grid are not)."""
    i, j = grid.world_to_cell(x, y)
    i, j = int(i), int(j)
    h, w = grid.shape
    return 0 <= i < h and 0 <= j < w and bool(grid.occupied[i, j])


class _Reader:
    """Validates one parsed YAML document; ``self.file`` prefixes every error's argument."""

    def __init__(self, path: Path):
        self.path = path
        self.file = str(path)
        #: what the reader changed in the input (e.g. repeated polygon vertices dropped), for map info
        self.notes: list[str] = []

    # -- errors and primitive checks -------------------------------------------------------------
    def err(self, key: str, expected: str, got: object = None, detail: str = "") -> MapError:
        where = f"{self.file}: {key}" if key else self.file
        return MapError(where, expected, got, detail=detail)

    def mapping(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> dict:
        return check_keys(value, allowed, self.file, key, MapError, required)

    def number(self, value: Any, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.err(key, "a number", _type_name(value) if not isinstance(value, str) else value,
                           detail=number_hint(value))
        try:
            x = float(value)
        except OverflowError:
            x = math.inf
        if not math.isfinite(x):
            raise self.err(key, "a finite number", value)
        if abs(x) > MAX_ABS:
            raise self.err(key, f"a number of magnitude at most {MAX_ABS:g}", value)
        return x

    def positive(self, value: Any, key: str) -> float:
        x = self.number(value, key)
        if x <= 0:
            raise self.err(key, "a positive number", value)
        return x

    def numbers(self, value: Any, key: str, n: int, what: str) -> tuple[float, ...]:
        if not isinstance(value, list) or len(value) != n:
            got = f"a list of {len(value)}" if isinstance(value, list) else _type_name(value)
            raise self.err(key, f"a list of {n} numbers {what}", got)
        return tuple(self.number(x, f"{key}[{i}]") for i, x in enumerate(value))

    def string(self, value: Any, key: str) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.err(key, "a non-empty string", _type_name(value) if not isinstance(value, str) else value)
        return value

    def boolean(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            raise self.err(key, "true or false", value)
        return value

    # -- shapes ------------------------------------------------------------------------------------
    def shape(self, item: Any, key: str) -> Shape:
        kinds = tuple(_SHAPES)
        if not isinstance(item, dict) or len(item) != 1:
            raise self.err(key, "a mapping with exactly one of the keys polygon, line, circle, box",
                           _type_name(item) if not isinstance(item, dict) else sorted(map(str, item)))
        self.mapping(item, key, kinds)
        (kind, spec), = item.items()
        sub = f"{key}.{kind}"
        if kind == "polygon":
            return self.polygon(spec, sub)
        if kind == "line":
            return self.line(spec, sub)
        if kind == "circle":
            spec = self.mapping(spec, sub, tuple(_SHAPES["circle"]["properties"]), tuple(_SHAPES["circle"]["required"]))
            center = self.numbers(spec["center"], f"{sub}.center", 2, "[x, y]")
            return Circle(center, self.positive(spec["radius"], f"{sub}.radius"))
        spec = self.mapping(spec, sub, tuple(_SHAPES["box"]["properties"]), tuple(_SHAPES["box"]["required"]))
        cx, cy = self.numbers(spec["center"], f"{sub}.center", 2, "[x, y]")
        length, width = self.numbers(spec["size"], f"{sub}.size", 2, "[length, width]")
        if length <= 0 or width <= 0:
            raise self.err(f"{sub}.size", "a positive [length, width]", spec["size"])
        yaw = self.number(spec.get("yaw", 0.0), f"{sub}.yaw")
        return box_polygon(cx, cy, length, width, yaw)

    def polygon(self, spec: Any, key: str) -> Polygon:
        if not isinstance(spec, list) or len(spec) < 3:
            got = f"{len(spec)} points" if isinstance(spec, list) else _type_name(spec)
            raise self.err(key, "a list of at least 3 [x, y] points", got,
                           detail="a line of zero thickness is drawn as line: [[x, y], [x, y], ...]")
        if len(spec) > MAX_POLYGON_VERTICES:
            raise self.err(key, f"at most {MAX_POLYGON_VERTICES:,} [x, y] points", len(spec))
        v = np.array([self.numbers(p, f"{key}[{i}]", 2, "[x, y]") for i, p in enumerate(spec)], dtype=float)
        cleaned = _drop_repeats(v)
        if len(cleaned) < len(v) - (1 if np.array_equal(v[0], v[-1]) else 0):
            self.notes.append(f"{key}: dropped {len(v) - len(cleaned)} repeated consecutive vertex(es)")
        v = cleaned
        if len(np.unique(v, axis=0)) < 2:
            raise self.err(key, "at least 2 distinct [x, y] points", f"{len(np.unique(v, axis=0))} distinct")
        if is_simple_polygon(v) and abs(polygon_area(v)) > 1e-12 * max(1.0, float(np.abs(v).max())) ** 2:
            return Polygon(v)
        # not simple: edges drawn out and back are thin parts (zero thickness); the rest must be simple
        try:
            parts = ring_parts(v)
        except ValueError as exc:
            raise self.err(key, "a simple polygon (no self-intersection or touching; edges drawn out and back are "
                           "thin parts)", spec, detail=str(exc)) from None
        if parts.area is None:
            self.notes.append(f"{key}: zero area: a thin obstacle of {len(parts.segments)} segment(s), zero thickness")
        else:
            self.notes.append(f"{key}: {len(parts.segments)} segment(s) drawn out and back: thin parts, zero thickness")
        return Polygon(v)

    def line(self, spec: Any, key: str) -> Polygon:
        """A line or polyline of zero thickness (:func:`nhstab.maps.base.polyline`)."""
        if not isinstance(spec, list) or len(spec) < 2:
            got = f"{len(spec)} points" if isinstance(spec, list) else _type_name(spec)
            raise self.err(key, "a list of at least 2 [x, y] points", got)
        if len(spec) > MAX_LINE_POINTS:
            raise self.err(key, f"at most {MAX_LINE_POINTS:,} [x, y] points (its ring runs there and back)",
                           len(spec))
        v = np.array([self.numbers(p, f"{key}[{i}]", 2, "[x, y]") for i, p in enumerate(spec)], dtype=float)
        keep = np.ones(len(v), dtype=bool)
        keep[1:] = np.any(v[1:] != v[:-1], axis=1)
        if not keep.all():
            self.notes.append(f"{key}: dropped {int((~keep).sum())} repeated consecutive point(s)")
        if len(np.unique(v, axis=0)) < 2:
            raise self.err(key, "at least 2 distinct [x, y] points", f"{len(np.unique(v, axis=0))} distinct")
        return polyline(v[keep])

    def shapes(self, value: Any, key: str) -> tuple[Shape, ...]:
        if value is None:
            return ()
        if not isinstance(value, list):
            raise self.err(key, "a list of shapes (polygon, line, circle or box)", _type_name(value))
        return tuple(self.shape(item, f"{key}[{i}]") for i, item in enumerate(value))

    # -- other keys --------------------------------------------------------------------------------
    def pose(self, value: Any, key: str) -> Pose:
        return Pose(*self.numbers(value, key, 3, "[x, y, theta]"))

    def robot(self, value: Any) -> dict:
        """The robot block, checked as a robot description (nhstab.robot) and kept as plain data."""
        if isinstance(value, str):
            value = {"model": value}
        spec = value if isinstance(value, dict) else None
        if spec is None:
            raise self.err("robot", "a mapping with at least the key model", _type_name(value))
        self.plain_data(spec, "robot", 0)
        try:
            robot = robot_from_spec(spec, where="robot")
        except PipelineError as exc:
            raise self.err(getattr(exc, "argument", "robot"), getattr(exc, "expected", str(exc)),
                           getattr(exc, "got", None), detail=getattr(exc, "detail", "")) from None
        self.notes.extend(robot.notes)
        return _deep_copy(spec)

    def plain_data(self, value: Any, key: str, depth: int) -> None:
        """Robot parameters: string keys, finite numbers, nested lists/mappings of bounded depth."""
        if depth > _MAX_DEPTH:
            raise self.err(key, f"data nested at most {_MAX_DEPTH} levels deep", "deeper (recursive alias?)")
        if isinstance(value, dict):
            for k, x in value.items():
                if not isinstance(k, str):
                    raise self.err(key, "string keys", k)
                self.plain_data(x, _join(key, k), depth + 1)
        elif isinstance(value, list):
            for i, x in enumerate(value):
                self.plain_data(x, f"{key}[{i}]", depth + 1)
        elif isinstance(value, float) and not math.isfinite(value):
            raise self.err(key, "a finite number", value)
        elif not (value is None or isinstance(value, (str, int, float, bool))):
            raise self.err(key, "a string, number, boolean, list or mapping", _type_name(value))

    def existing_file(self, rel: str, key: str, expected: str) -> Path:
        """``rel`` resolved against the YAML file's folder; MapError unless it is an existing file."""
        try:
            target = (self.path.parent / rel).resolve()
            ok = target.is_file()
        except (OSError, ValueError, RuntimeError) as exc:      # RuntimeError: a symlink loop
            raise self.err(key, expected, rel, detail=_one_line(exc)) from None
        if not ok:
            raise self.err(key, expected, f"{rel} (resolved {target})", detail="no such file")
        return target

    def base(self, value: Any) -> tuple[Map, dict]:
        if not isinstance(value, dict):
            raise self.err("base", "a mapping with keys format, path, ...", _type_name(value))
        if "format" not in value:
            raise self.err("base.format", "present", "missing", detail="required in base")
        fmt = value["format"]
        if not isinstance(fmt, str) or fmt not in _BASE_KEYS:
            raise self.err("base.format", f"one of {', '.join(_BASE_KEYS)}", fmt)
        spec = self.mapping(value, "base", _BASE_KEYS[fmt], _BASE_REQUIRED[fmt])
        rel = self.string(spec["path"], "base.path")
        scen_rel = self.string(spec["scenarios"], "base.scenarios") if "scenarios" in spec else None
        unknown = spec.get("unknown", "occupied")
        if unknown not in ("occupied", "free"):
            raise self.err("base.unknown", "occupied or free (how unknown cells count)", unknown)
        cell = self.positive(spec["cell_size"], "base.cell_size") if "cell_size" in spec else 1.0
        hull = self.boolean(spec["convex_hull"], "base.convex_hull") if "convex_hull" in spec else False
        target = self.existing_file(rel, "base.path", f"an existing {fmt} map file")
        scen = None if scen_rel is None else self.existing_file(scen_rel, "base.scenarios", "an existing scenario file")
        try:
            if fmt == "nhstab":
                if _nesting[0] >= _MAX_BASE_NESTING:
                    raise self.err("base.path", f"base maps nested at most {_MAX_BASE_NESTING} deep", rel,
                                   detail="a file that is (indirectly) its own base?")
                _nesting[0] += 1
                try:
                    base = load_yaml_map(target)
                finally:
                    _nesting[0] -= 1
            elif fmt == "ros":
                base = load_ros_map(target, unknown=unknown)
            elif fmt == "movingai":
                base = load_movingai_map(target, cell_size=cell)
                if scen is not None:
                    height = base.grids[0].shape[0] if base.grids else None
                    base = replace(base, problems=tuple(
                        load_movingai_scenarios(scen, cell_size=cell, map_height=height)))
            else:
                base = load_benchmr_svg(target, convex_hull=hull)
                if scen is not None:
                    base = replace(base, problems=load_benchmr_scenarios(scen).get(base.name, ()))
        except (PipelineError, OSError, ValueError, ImportError) as exc:
            raise self.err("base.path", f"a loadable {fmt} map", f"{rel} (resolved {target})",
                           detail=f"{type(exc).__name__}: {_one_line(exc)}") from None
        meta = {"format": fmt, "path": str(target), **({"scenarios": str(scen)} if scen else {})}
        return base, meta

    # -- the document ------------------------------------------------------------------------------
    def map(self, doc: Any) -> Map:
        if doc is None:
            raise self.err("", "a YAML mapping with at least bounds", "an empty document")
        doc = self.mapping(doc, "", _TOP_KEYS)
        name = self.string(doc["name"], "name") if "name" in doc else self.path.stem
        description = self.string(doc["description"], "description") if "description" in doc else None
        base, base_meta = self.base(doc["base"]) if "base" in doc else (None, None)
        if "bounds" in doc:
            bounds = self.numbers(doc["bounds"], "bounds", 4, "[xmin, ymin, xmax, ymax]")
            if not (bounds[0] < bounds[2] and bounds[1] < bounds[3]):
                raise self.err("bounds", "[xmin, ymin, xmax, ymax] with xmin < xmax and ymin < ymax", doc["bounds"])
        elif base is not None:
            bounds = base.bounds
        else:
            raise self.err("bounds", "present (no base map gives them)", "missing")
        obstacles = self.shapes(doc.get("obstacles"), "obstacles")
        unknown = self.shapes(doc.get("unknown_obstacles"), "unknown_obstacles")
        robot = self.robot(doc["robot"]) if "robot" in doc else None
        start = self.pose(doc["start"], "start") if "start" in doc else None
        goal = self.pose(doc["goal"], "goal") if "goal" in doc else None

        grids: tuple[OccupancyGrid, ...] = ()
        problems: tuple[Problem, ...] = ()
        if base is not None:
            obstacles = tuple(base.obstacles) + obstacles
            unknown = tuple(base.unknown_obstacles) + unknown
            grids, problems = tuple(base.grids), tuple(base.problems)
            start = start if start is not None else base.start
            goal = goal if goal is not None else base.goal
            robot = robot if robot is not None else base.robot

        m = Map(name=name, bounds=bounds, obstacles=obstacles, grids=grids, unknown_obstacles=unknown,
                start=start, goal=goal, robot=robot, problems=problems, source=str(self.path),
                meta={"format": "nhstab_yaml", "base": base_meta, "description": description,
                      "notes": list(self.notes) + list((base.meta.get("notes") or []) if base is not None else []),
                      "own_obstacles": len(doc.get("obstacles") or ()),
                      "own_unknown_obstacles": len(doc.get("unknown_obstacles") or ())})
        for key, pose in (("start", start), ("goal", goal)):
            if pose is not None:
                self.check_free(m, pose, key)
        return m

    def check_free(self, m: Map, pose: Pose, key: str) -> None:
        if not m.contains(pose.x, pose.y):
            raise self.err(key, f"a position inside the bounds {list(m.bounds)}", [pose.x, pose.y])
        for i, shape in enumerate(m.obstacles):
            if point_in_shape(pose.x, pose.y, shape):
                raise self.err(key, "a reference point outside every known obstacle", [pose.x, pose.y],
                               detail=f"inside known obstacle #{i} ({type(shape).__name__.lower()})")
        for i, grid in enumerate(m.grids):
            if point_in_grid(pose.x, pose.y, grid):
                raise self.err(key, "a reference point outside every known obstacle", [pose.x, pose.y],
                               detail=f"in an occupied cell of grid #{i}")


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def _drop_repeats(v: np.ndarray) -> np.ndarray:
    """A ring (k >= 2, finite) without repeated consecutive vertices, nor a repeated closing vertex
    (real data has them; they carry no shape). GEOS's repeated-point filter at tolerance 0 (shapely):
    exact equality, as numpy's, and faster (``nhstab bench geometry``)."""
    v = shapely.get_coordinates(shapely.remove_repeated_points(shapely.linestrings(v), 0.0))
    while len(v) > 1 and np.array_equal(v[-1], v[0]):
        v = v[:-1]
    return v


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (PyYAML's multi-line marks collapsed)."""
    return " ".join(str(exc).replace(' in "<unicode string>",', " at").split())


def _deep_copy(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _deep_copy(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_deep_copy(v) for v in value]
    return value
