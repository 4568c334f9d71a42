"""The bundled maps and scenarios, shipped inside the package (``nhstab.data``), by name.

Every map file under the data folder is an example named by its file stem (``depot_blocked_aisle``,
``parking3``, ``Berlin_0_256``, ...). Anywhere a map path is accepted (the command line, run and
batch configs, :func:`nhstab.maps.load_map`), ``example:NAME`` names a bundled one, so a user who
only ran ``pip install nhstab`` can run every scenario from any folder::

    nhstab examples
    nhstab run example:depot_blocked_aisle --out run1

Listing is cheap: it reads the YAML files' headers and counts problem lines, without loading
images or building grids.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from .errors import InputError, PipelineError
from .safe_io import load_yaml_file

#: the prefix that names a bundled example instead of a file
EXAMPLE_PREFIX = "example:"
#: map file suffixes, by format label
_FORMATS = {".svg": "Bench-MR SVG", ".map": "Moving AI", ".yaml": None, ".yml": None}


@dataclass(frozen=True)
class Example:
    """One bundled map: its name, file, format, robot and what happens on it."""

    name: str
    path: Path
    format: str
    robot: str
    kind: str            # "scenario" (start, goal, unknown obstacles), "problems" (start/goal pairs), "map"
    description: str

    def as_dict(self) -> dict:
        return {"name": self.name, "path": str(self.path), "relative_path": str(self.path.relative_to(data_root())),
                "format": self.format, "robot": self.robot, "kind": self.kind, "description": self.description}


def data_root() -> Path:
    """The folder of the bundled maps (``maps/`` in a source checkout, ``nhstab/data`` installed)."""
    from importlib.resources import files

    return Path(str(files("nhstab.data")))


def is_example(value) -> bool:
    """Whether ``value`` is a string of the form ``example:NAME``."""
    return isinstance(value, str) and value.startswith(EXAMPLE_PREFIX)


def resolve_map_path(value) -> Path:
    """``example:NAME`` -> the bundled file's path; anything else -> ``Path(value)``.

    An unknown example name raises :class:`InputError` listing the names that exist.
    """
    if isinstance(value, Path):
        if not is_example(str(value)):
            return value
        value = str(value)
    if is_example(value):
        return example_path(value[len(EXAMPLE_PREFIX):])
    if not isinstance(value, str):
        raise InputError("map", "a file path or example:NAME", f"{type(value).__name__} {value!r}")
    return Path(value)


def example_path(name: str) -> Path:
    """The file of the bundled example ``name``."""
    catalog = _catalog()
    if name not in catalog:
        raise InputError("example", "one of " + ", ".join(sorted(catalog, key=str.lower)) + " (see `nhstab examples`)",
                         name)
    return catalog[name]


def list_examples() -> list[Example]:
    """Every bundled example, scenarios first, then by name."""
    out = [_describe(name, path) for name, path in _catalog().items()]
    order = {"scenario": 0, "problems": 1, "map": 2}
    return sorted(out, key=lambda e: (order[e.kind], e.name.lower()))


@lru_cache(maxsize=1)
def _catalog() -> dict[str, Path]:
    root = data_root()
    found: dict[str, Path] = {}
    for path in sorted(root.rglob("*")):
        if not path.is_file() or path.suffix.lower() not in _FORMATS:
            continue
        if path.name.startswith("_") or "batch" in path.parts[len(root.parts):-1]:
            continue
        if path.suffix.lower() in (".yaml", ".yml") and _is_config(path):
            continue
        if path.suffix.lower() == ".svg" and _is_footprint_svg(path):
            continue
        name = path.stem
        if name in found:        # names must be unique; tests/test_packaging.py keeps them so
            name = f"{path.parent.name}/{path.stem}"
        found[name] = path
    return found


def _is_config(path: Path) -> bool:
    """Run and batch configs that sit beside maps are not maps."""
    head = path.read_text(encoding="utf-8", errors="replace")[:4000]
    return bool(re.search(r"^(map|maps|controllers|trials):", head, flags=re.M))


def _describe(name: str, path: Path) -> Example:
    suffix = path.suffix.lower()
    if suffix == ".map":
        n = _count_scen(path.with_name(path.name + ".scen"))
        return Example(name, path, "Moving AI", "any", "problems" if n else "map",
                       f"grid map; {n} start/goal problems from its .scen (use --problem N, --cell-size)")
    if suffix == ".svg":
        n, shape = _benchmr_problems(path)
        robot = {"car": "rwd_car (car.svg)", "warehouse_robot": "unicycle (warehouse_robot.svg)"}.get(shape or "", "any")
        return Example(name, path, "Bench-MR SVG", robot, "problems" if n else "map",
                       f"polygon world; {n} start/goal problem(s) from polygon_scenarios.csv")

    try:
        doc = load_yaml_file(path)
    except PipelineError:
        doc = None
    if not isinstance(doc, dict):
        return Example(name, path, "unreadable", "-", "map", "(could not be read)")
    if "image" in doc:
        res = doc.get("resolution")
        return Example(name, path, "ROS map_server", "any", "map",
                       f"occupancy grid at {res} m per cell (give --start and --goal)")
    from .maps import (
        load_map,  # nhstab YAML: load it, so that a base map's robot and obstacles count
    )

    try:
        m = load_map(path)
    except Exception as exc:  # noqa: BLE001 -- listing must not fail on one bad file
        return Example(name, path, "nhstab YAML", "-", "map", f"(does not load: {type(exc).__name__})")
    base = (m.meta.get("base") or {}).get("format")
    fmt = "nhstab YAML" + (f" on {base}" if base else "")
    robot = (m.robot or {}).get("model", "unicycle")
    has_poses = m.start is not None and m.goal is not None
    unknown = len(m.unknown_obstacles)
    kind = "scenario" if (has_poses and unknown) else ("problems" if m.problems else "map")
    text = m.meta.get("description")
    if not text:
        text = (f"{unknown} obstacle(s) not in the robot's map" if unknown else "known obstacles only") + \
               ("; start and goal given" if has_poses else "")
    return Example(name, path, fmt, robot, kind, " ".join(text.split()))


def _count_scen(path: Path) -> int:
    if not path.is_file():
        return 0
    with open(path, encoding="utf-8", errors="replace") as fh:
        return sum(1 for line in fh if line.strip() and not line.startswith("version"))


def _benchmr_rows(path: Path) -> list[dict]:
    scen = path.with_name("polygon_scenarios.csv")
    if not scen.is_file():
        return []
    with open(scen, encoding="utf-8", errors="replace", newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def _benchmr_problems(path: Path) -> tuple[int, str | None]:
    rows = [r for r in _benchmr_rows(path) if r.get("environment") == path.stem]
    shape = rows[0].get("robot_shape") if rows else None
    return len(rows), (Path(shape).stem if shape else None)


def _is_footprint_svg(path: Path) -> bool:
    """Bench-MR's robot shapes (car.svg, warehouse_robot.svg) sit beside the worlds; they are not maps."""
    return any(Path(r.get("robot_shape") or "").stem == path.stem for r in _benchmr_rows(path))
