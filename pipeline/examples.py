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

from dataclasses import dataclass
from pathlib import Path

from .errors import PipelineError
from .maps import load_map
from .maps.bundled import (  # noqa: F401 - the names a user resolves examples by, kept here too
    EXAMPLE_PREFIX,
    _benchmr_rows,
    _catalog,
    config_catalog,
    data_root,
    example_path,
    is_example,
    resolve_map_path,
)
from .safe_io import load_yaml_file


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


def list_examples() -> list[Example]:
    """Every bundled example, scenarios first, then by name."""
    out = [_describe(name, path) for name, path in _catalog().items()]
    order = {"scenario": 0, "problems": 1, "map": 2}
    return sorted(out, key=lambda e: (order[e.kind], e.name.lower()))


def list_configs() -> list[Example]:
    """The bundled batch configs (``nhstab batch example:NAME``), then the run configs (``nhstab run
    --config example:NAME``), each described by the first sentence of its leading comment."""
    out = []
    for kind in ("batch", "run"):
        for name, path in config_catalog(kind).items():
            head = []
            for line in path.read_text(encoding="utf-8").splitlines():
                if not line.startswith("#"):
                    break
                head.append(line.lstrip("#").strip())
            text = " ".join(h for h in head if h and not h.startswith("nhstab "))
            text = text.split(": ", 1)[-1] if text.lower().startswith(("batch:", "run config:")) else text
            out.append(Example(name, path, f"{kind} config", "-", f"{kind}_config", text.split(". ")[0].rstrip(".")))
    return out


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
    # nhstab YAML: load it, so that a base map's robot and obstacles count
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


def _benchmr_problems(path: Path) -> tuple[int, str | None]:
    rows = [r for r in _benchmr_rows(path) if r.get("environment") == path.stem]
    shape = rows[0].get("robot_shape") if rows else None
    return len(rows), (Path(shape).stem if shape else None)
