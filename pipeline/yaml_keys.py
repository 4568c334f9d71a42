"""The keys of nhstab's YAML formats, read from their JSON Schemas: the one list each loader accepts.

The schemas (draft 2020-12) ship with the package as ``nhstab/schemas/<format>.schema.json``, one per
format of :data:`FORMATS`; :mod:`nhstab.schema` writes them (``nhstab schema --out DIR``) from the
code's own definitions (the run-config dataclasses and their defaults, the models' parameters, the
enumerations of controllers, windows, planners, spaces and tube kinds), and a test holds the shipped
files to what it writes. The loaders (:mod:`nhstab.maps.yaml_format`, :mod:`nhstab.robot`,
:mod:`nhstab.execution.config`, :mod:`nhstab.batch.config`) take their allowed keys from here, so a
key added to a schema is accepted and documented at once; they keep their own checks of the values,
whose errors name the key path.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

#: the folder of the shipped schemas
SCHEMA_DIR = Path(__file__).resolve().parent / "schemas"
#: the YAML formats, by schema name (the file is ``<name>.schema.json``)
FORMATS = ("map", "robot", "run-config", "batch-config")


@cache
def schema(name: str) -> dict:
    """The JSON Schema of the format ``name`` (one of :data:`FORMATS`), as shipped."""
    if name not in FORMATS:
        raise KeyError(f"no schema {name!r}; the formats are {', '.join(FORMATS)}")
    return json.loads((SCHEMA_DIR / f"{name}.schema.json").read_text(encoding="utf-8"))


def schema_keys(name: str, *path: str) -> tuple[str, ...]:
    """The property names of the (sub)schema at ``path`` inside the schema ``name``, in schema order:
    e.g. ``schema_keys("run-config", "properties", "planning")`` are the keys of ``planning:``."""
    node = schema(name)
    for part in path:
        node = node[part]
    return tuple(node["properties"])


def schema_required(name: str, *path: str) -> tuple[str, ...]:
    """The required property names of the (sub)schema at ``path`` (see :func:`schema_keys`)."""
    node = schema(name)
    for part in path:
        node = node[part]
    return tuple(node.get("required", ()))
