"""Maps: one :class:`Map` value loaded from any supported file by :func:`load_map`.

Formats (dispatch on the file name):

* ``.svg`` -- a Bench-MR polygon world (:func:`nhstab.maps.svg.load_benchmr_svg`);
* ``.map`` -- a Moving AI grid map (:func:`nhstab.maps.movingai.load_movingai_map`);
* ``.yaml`` / ``.yml`` -- a ROS map_server map if the top-level mapping has an ``image`` key
  (:func:`nhstab.maps.ros.load_ros_map`), otherwise nhstab's own YAML map format
  (:func:`nhstab.maps.yaml_format.load_yaml_map`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..safe_io import content_digest, load_yaml_file, not_recorded, recording
from .base import Circle, Map, MapError, OccupancyGrid, Polygon, Pose, Problem, box_polygon
from .bundled import resolve_map_path
from .movingai import load_movingai_map, load_movingai_scenarios
from .ros import load_ros_map
from .svg import benchmr_robot_shapes, load_benchmr_scenarios, load_benchmr_svg
from .yaml_format import is_file, load_yaml_map

__all__ = ["Map", "Pose", "Polygon", "Circle", "OccupancyGrid", "Problem", "MapError", "box_polygon", "load_map",
           "content_hash", "resolve_poses"]

_OPTIONS = {
    "svg": ("convex_hull", "scenarios"),
    "map": ("cell_size", "scenarios"),
    "ros": ("unknown",),
    "yaml": (),
}
BENCHMR_SCENARIO_FILE = "polygon_scenarios.csv"


def load_map(path: str | Path, **options: Any) -> Map:
    """Load a map file of any supported format (see the module docstring).

    Options, by format (any other option raises :class:`InputError`):

    * ``.svg``: ``convex_hull=False`` (replace polygons by their hulls, as Bench-MR did);
      ``scenarios=True``: attach the start/goal pairs of ``polygon_scenarios.csv`` in the same folder
      (rows whose ``environment`` is the file stem) as ``Map.problems`` if that file exists
      (``False``: none; a path: that CSV file); the footprint named in its ``robot_shape`` column
      goes to ``meta["robot_shape"]``;
    * ``.map``: ``cell_size=1.0`` (metres per cell); ``scenarios=True``: attach ``<file>.scen``
      (Moving AI naming, e.g. ``Berlin_0_256.map.scen``) if it exists (``False``: none; a path: that file);
    * ROS ``.yaml``: ``unknown="occupied"`` (how unknown cells count);
    * nhstab ``.yaml``: no options.

    ``path`` may also be ``example:NAME``, a map bundled with nhstab (see :mod:`nhstab.examples`).

    A missing file or an unsupported extension raises :class:`MapError` naming the file. Every file
    is read through :mod:`nhstab.safe_io` (regular files of bounded size, YAML with bounded nesting,
    aliases and no duplicate keys), and everything built is checked against :mod:`nhstab.limits`.
    ``meta["files"]`` lists every file read with its SHA-256, and ``meta["content_hash"]`` is their
    combined digest (:func:`content_hash`).
    """
    path = resolve_map_path(path)
    if not is_file(path):
        raise MapError(str(path), "an existing map file", "no such file or not a file")
    with recording() as files:
        try:
            m = _dispatch(path, options)
        except MapError:
            raise
        except InputError as exc:       # a shape or grid beyond nhstab.limits: name the file too
            if exc.argument.startswith("load_map option") or exc.argument in _OPTION_NAMES:
                raise
            raise MapError(f"{path}: {exc.argument}", exc.expected, exc.got, detail=exc.detail) from None
    files = [dict(f) for f in files]
    return replace(m, meta={**m.meta, "files": files, "content_hash": content_digest(files)})


_OPTION_NAMES = {"cell_size", "unknown", "convex_hull", "scenarios"}


def content_hash(path: str | Path, **options: Any) -> str:
    """SHA-256 (hex) of the bytes of every file the map at ``path`` is built from, in the order they
    are read: the map file, its base maps, images and scenario lists. Loads the map (so the set of
    files is exactly what :func:`load_map` reads); the same value is in ``load_map(...).meta
    ["content_hash"]``, and ``meta["files"]`` lists the files with their own digests. Names do not
    enter: moving or renaming the files keeps the hash."""
    return load_map(path, **options).meta["content_hash"]


def _dispatch(path: Path, options: dict) -> Map:
    suffix = path.suffix.lower()
    if suffix == ".svg":
        _check_options(path, "svg", options)
        return _load_svg(path, **options)
    if suffix == ".map":
        _check_options(path, "map", options)
        return _load_movingai(path, **options)
    if suffix in (".yaml", ".yml"):
        if _is_ros_yaml(path):
            _check_options(path, "ros", options)
            return load_ros_map(path, **options)
        _check_options(path, "yaml", options)
        return load_yaml_map(path)
    raise MapError(str(path), "a map file ending in .svg, .map, .yaml or .yml", path.suffix or "no extension")


def _check_options(path: Path, kind: str, options: dict) -> None:
    allowed = _OPTIONS[kind]
    for key in options:
        if key not in allowed:
            expected = f"one of {', '.join(allowed)}" if allowed else "absent (this format takes no options)"
            raise InputError(f"load_map option {key!r} for {path.name}", expected, options[key])


def _scenario_path(value: Any, default: Path) -> Path | None:
    if value is False or value is None:
        return None
    if value is True:
        return default if default.is_file() else None
    if isinstance(value, (str, Path)):
        return Path(value)
    raise InputError("scenarios", "True, False or a path", value)


def _load_svg(path: Path, convex_hull: bool = False, scenarios: Any = True) -> Map:
    if not isinstance(convex_hull, bool):
        raise InputError("convex_hull", "True or False", convex_hull)
    m = load_benchmr_svg(path, convex_hull=convex_hull)
    csv_path = _scenario_path(scenarios, path.parent / BENCHMR_SCENARIO_FILE)
    if csv_path is None:
        return m
    problems = load_benchmr_scenarios(csv_path).get(m.name, ())
    meta = dict(m.meta, scenarios=str(csv_path))
    shape = benchmr_robot_shapes(csv_path).get(m.name)
    if shape:
        meta["robot_shape"] = shape
    return replace(m, problems=tuple(problems), meta=meta)


def _load_movingai(path: Path, cell_size: float = 1.0, scenarios: Any = True) -> Map:
    m = load_movingai_map(path, cell_size=cell_size)
    scen = _scenario_path(scenarios, path.with_name(path.name + ".scen"))
    if scen is None or m.problems:
        return m
    height = m.grids[0].shape[0] if m.grids else None
    problems = load_movingai_scenarios(scen, cell_size=cell_size, map_height=height)
    return replace(m, problems=tuple(problems), meta=dict(m.meta, scenarios=str(scen)))


def _is_ros_yaml(path: Path) -> bool:
    """Whether a YAML file's top level is a mapping with an ``image`` key (ROS map_server metadata).
    Read with the safe loader, and not recorded: the loader that follows reads the file again."""
    with not_recorded():
        doc = load_yaml_file(path, what="YAML map file", error=MapError)
    return isinstance(doc, dict) and "image" in doc


def resolve_poses(m: Map, start=None, goal=None, problem: int | None = None, *,
                  names: tuple[str, str, str] = ("start", "goal", "problem")):
    """The start and goal of a request as (3,) arrays: the map's problem ``problem`` if given, else
    ``start``/``goal`` where given, else the map's own. ``names`` are what errors call the three
    arguments (the command line passes its flags). Raises :class:`InputError` when a pose is missing
    or the problem index is out of range."""
    import numpy as np

    s_name, g_name, p_name = names
    if problem is not None:
        if isinstance(problem, bool) or not isinstance(problem, (int, np.integer)) or not (0 <= problem < len(m.problems)):
            raise InputError(p_name, f"an index in [0, {len(m.problems)}) ({m.name} has {len(m.problems)} problems)",
                             problem)
        p = m.problems[int(problem)]
        return p.start.as_array(), p.goal.as_array()
    s = _pose_or(start, m.start, s_name)
    g = _pose_or(goal, m.goal, g_name)
    if s is None or g is None:
        missing = " and ".join(n for n, v in ((s_name, s), (g_name, g)) if v is None)
        raise InputError(missing, f"a pose x,y,theta ({m.name} gives none)", None)
    return s, g


def _pose_or(value, default: Pose | None, name: str):
    import numpy as np

    if value is None:
        return None if default is None else default.as_array()
    if isinstance(value, Pose):
        return value.as_array()
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, "a pose of three numbers (x, y, theta)", value) from None
    if arr.ndim != 1 or not 3 <= arr.shape[0] <= 12 or not np.all(np.isfinite(arr)):
        raise InputError(name, "a pose of three finite numbers (x, y, theta; a car with trailers may add their "
                         "headings)", value)
    return arr
