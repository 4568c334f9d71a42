"""Bundled maps by name: ``example:NAME`` resolved to the file shipped in ``nhstab.data``.

Every map file under the data folder is an example named by its file stem; :mod:`nhstab.examples`
lists and describes them.
"""

from __future__ import annotations

import csv
import re
from functools import lru_cache
from pathlib import Path

from ..errors import InputError

#: the prefix that names a bundled example instead of a file
EXAMPLE_PREFIX = "example:"
#: the folder of the bundled run and batch configs (``example:NAME`` for ``nhstab run --config`` and
#: ``nhstab batch``), under the data folder; never maps
CONFIG_FOLDER = "configs"
#: map file suffixes, by format label
_FORMATS = {".svg": "Bench-MR SVG", ".map": "Moving AI", ".yaml": None, ".yml": None}


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


@lru_cache(maxsize=2)
def config_catalog(kind: str) -> dict[str, Path]:
    """The bundled configs of ``kind`` ("batch": those with ``trials``, or "run") by name (file stem)."""
    folder = data_root() / CONFIG_FOLDER
    if not folder.is_dir():
        return {}
    out = {}
    for p in sorted(folder.glob("*.yaml")):
        is_batch = bool(re.search(r"^trials:", p.read_text(encoding="utf-8", errors="replace"), flags=re.M))
        if is_batch == (kind == "batch"):
            out[p.stem] = p
    return out


def resolve_config_path(value, argument: str, kind: str) -> Path:
    """A ``kind`` ("run" or "batch") config: ``example:NAME`` -> the bundled config's path (an unknown
    name is an InputError naming ``argument`` and listing the names); anything else -> ``Path(value)``."""
    text = str(value)
    if not is_example(text):
        return Path(value)
    name = text[len(EXAMPLE_PREFIX):]
    catalog = config_catalog(kind)
    if name not in catalog:
        raise InputError(argument, f"a {kind} config file or example:NAME, one of " + ", ".join(catalog)
                         + " (see `nhstab examples`)", text)
    return catalog[name]


def example_path(name: str) -> Path:
    """The file of the bundled example ``name``."""
    catalog = _catalog()
    if name not in catalog:
        raise InputError("example", "one of " + ", ".join(sorted(catalog, key=str.lower)) + " (see `nhstab examples`)",
                         name)
    return catalog[name]


@lru_cache(maxsize=1)
def _catalog() -> dict[str, Path]:
    root = data_root()
    found: dict[str, Path] = {}
    for path in sorted(root.rglob("*")):
        if not path.is_file() or path.suffix.lower() not in _FORMATS:
            continue
        inside = path.parts[len(root.parts):-1]
        if path.name.startswith("_") or "batch" in inside or CONFIG_FOLDER in inside:
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


def _benchmr_rows(path: Path) -> list[dict]:
    scen = path.with_name("polygon_scenarios.csv")
    if not scen.is_file():
        return []
    with open(scen, encoding="utf-8", errors="replace", newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def _is_footprint_svg(path: Path) -> bool:
    """Bench-MR's robot shapes (car.svg, warehouse_robot.svg) sit beside the worlds; they are not maps."""
    return any(Path(r.get("robot_shape") or "").stem == path.stem for r in _benchmr_rows(path))
