"""Load Moving AI grid benchmarks (``.map`` octile grids and ``.scen`` scenario lists).

Format (movingai.com/benchmarks/formats.html): a ``.map`` file is the header lines ``type octile``,
``height H``, ``width W`` (either order), ``map``, then H rows of W characters. '.' and 'G' are
passable; every other printable character ('@', 'O', 'T', and also the special terrains 'S' swamp
and 'W' water) is blocked. Spaces, tabs and control characters inside a row are errors.

Coordinates. The text cell (x = column, y = row) has (0, 0) at the *top-left* of the text. The
loaded grid has origin (0, 0, 0) and resolution ``cell_size``; grid row i (lowest y first) is text
row ``H - 1 - i``, so the text cell (x, y) covers the world square
``[x, x + 1] * cell_size`` by ``[H - 1 - y, H - y] * cell_size`` and its centre is::

    ((x + 0.5) * cell_size, (H - 1 - y + 0.5) * cell_size)

(:func:`movingai_cell_to_world`; the inverse is :func:`world_to_movingai_cell`).

Scenarios. A ``.scen`` file starts with ``version 1`` (or ``version 1.0``), then one line per
problem with 9 tab-separated fields ``bucket map width height start_x start_y goal_x goal_y
optimal_length``. Each becomes ``Problem(start, goal, label=f"bucket {b} #{k}",
reference_length=optimal_length * cell_size)`` where ``k`` is the 0-based index of the problem in
the file (= its index in the returned tuple). Start and goal are cell centres as above, with the
row's ``height`` field (or ``map_height``) as H. The file gives no headings: both ``start.theta``
and ``goal.theta`` are the direction from start to goal in the world frame,
``atan2(goal.y - start.y, goal.x - start.x)`` (0 when start == goal). ``optimal_length`` is the
8-connected octile distance (diagonal sqrt 2, no corner cutting), a lower bound for a smooth path.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..limits import MAX_CELL_M, MAX_COORD_M, MIN_CELL_M
from ..safe_io import read_bytes
from .base import Map, MapError, OccupancyGrid, Pose, Problem, check_grid_size

__all__ = [
    "FREE_CHARACTERS",
    "load_movingai_map",
    "load_movingai_scenarios",
    "movingai_cell_to_world",
    "world_to_movingai_cell",
]

FREE_CHARACTERS = ".G"

_INT = re.compile(r"[0-9]+")
_FLOAT = re.compile(r"[+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")
_VERSION = re.compile(r"version\s+1(?:\.0)?")


def movingai_cell_to_world(x, y, height: int, cell_size: float = 1.0):
    """World (wx, wy) of the centre of text cell (column x, row y) of a map with ``height`` rows."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    return (x + 0.5) * cell_size, (height - 1 - y + 0.5) * cell_size


def world_to_movingai_cell(wx, wy, height: int, cell_size: float = 1.0):
    """Text cell (column x, row y) containing world point (wx, wy); may be out of range."""
    column = np.floor(np.asarray(wx, dtype=float) / cell_size).astype(int)
    row_from_bottom = np.floor(np.asarray(wy, dtype=float) / cell_size).astype(int)
    return column, height - 1 - row_from_bottom


def load_movingai_map(path, cell_size: float = 1.0) -> Map:
    """Load a Moving AI ``.map`` file as a :class:`Map` with one occupancy grid (no problems).

    ``meta`` holds width, height, cell_size, ``cells`` = counts of free and blocked cells, and
    ``characters`` = the count of each map character. Raises :class:`MapError` naming the file and
    line for a wrong header, wrong row count or width, bad characters, or a bad ``cell_size``.
    """
    path = Path(path)
    cell_size = _check_cell_size(cell_size, path)
    lines = _read_lines(path)

    if len(lines) < 4:
        raise MapError(f"{path}:{len(lines) + 1}", "the header lines 'type octile', 'height H', 'width W', 'map'",
                       detail="file ends inside the header")
    if lines[0].split() != ["type", "octile"]:
        raise MapError(f"{path}:1", "the header line 'type octile'", lines[0])
    dims: dict[str, int] = {}
    for lineno in (2, 3):
        fields = lines[lineno - 1].split()
        if len(fields) != 2 or fields[0] not in ("height", "width") or fields[0] in dims:
            raise MapError(f"{path}:{lineno}", "the header lines 'height H' and 'width W'", lines[lineno - 1])
        if not _INT.fullmatch(fields[1]) or int(fields[1]) < 1:
            raise MapError(f"{path}:{lineno}", f"a positive integer {fields[0]}", fields[1])
        dims[fields[0]] = int(fields[1])
    if lines[3].strip() != "map":
        raise MapError(f"{path}:4", "the header line 'map'", lines[3])
    height, width = dims["height"], dims["width"]
    _map_limits(path, height, width, cell_size)

    rows = lines[4:4 + height]
    if len(rows) < height:
        raise MapError(f"{path}:{4 + len(rows) + 1}", f"{height} map rows", f"{len(rows)} rows",
                       detail="file ends early")
    for k, row in enumerate(rows):
        if len(row) != width:
            raise MapError(f"{path}:{5 + k}", f"a map row of {width} characters", f"{len(row)} characters")
    for k, extra in enumerate(lines[4 + height:]):
        if extra.strip():
            raise MapError(f"{path}:{5 + height + k}", f"exactly {height} map rows", extra,
                           detail="text after the last row")

    chars = np.frombuffer("".join(rows).encode("ascii"), dtype=np.uint8).reshape(height, width)
    bad = (chars < 0x21) | (chars > 0x7E)
    if bad.any():
        row, col = (int(v[0]) for v in np.nonzero(bad))
        raise MapError(f"{path}:{5 + row}", "printable map characters ('.', 'G' free; '@', 'O', 'T', ... blocked)",
                       chr(chars[row, col]), detail=f"column {col}")
    free_text = np.isin(chars, np.frombuffer(FREE_CHARACTERS.encode("ascii"), dtype=np.uint8))
    occupied = np.ascontiguousarray(np.flipud(~free_text))
    grid = OccupancyGrid(occupied, cell_size, (0.0, 0.0, 0.0))

    codes, counts = np.unique(chars, return_counts=True)
    meta = {
        "format": "movingai",
        "width": width,
        "height": height,
        "cell_size": cell_size,
        "cells": {"free": int(free_text.sum()), "blocked": int(occupied.sum())},
        "characters": {chr(c): int(n) for c, n in zip(codes, counts)},
    }
    return Map(name=_stem(path), bounds=grid.bounds(), grids=(grid,), source=str(path), meta=meta)


def load_movingai_scenarios(path, cell_size: float = 1.0, map_height: int | None = None) -> tuple[Problem, ...]:
    """Load a Moving AI ``.scen`` file as problems in world coordinates (see the module docstring).

    ``map_height`` is the height H used for the row flip; by default each line's own height field.
    If given, it must equal every line's height field (Moving AI says a map whose size differs from
    the scenario's must be scaled to it, which this loader does not do). Raises :class:`MapError`
    naming the file and line for a bad version line, field count, number, NaN, or a start/goal
    outside the stated map size.
    """
    path = Path(path)
    cell_size = _check_cell_size(cell_size, path)
    if map_height is not None and (isinstance(map_height, bool) or not isinstance(map_height, (int, np.integer))
                                   or map_height < 1):
        raise MapError("map_height", "None or a positive integer number of rows", map_height,
                       detail=f"loading {path}")
    lines = _read_lines(path)
    if not lines or not _VERSION.fullmatch(lines[0].strip()):
        raise MapError(f"{path}:1", "the first line 'version 1' (or 'version 1.0')", lines[0] if lines else "")

    problems: list[Problem] = []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        where = f"{path}:{lineno}"
        text = line.rstrip()
        fields = text.split("\t") if "\t" in text else text.split()
        if len(fields) != 9:
            raise MapError(where, "9 tab-separated fields: bucket map width height start_x start_y goal_x goal_y "
                           "optimal_length", f"{len(fields)} fields")
        bucket_text, map_name, *int_texts, length_text = (f.strip() for f in fields)
        names = ("width", "height", "start_x", "start_y", "goal_x", "goal_y")
        values = {}
        for name, value in (("bucket", bucket_text), *zip(names, int_texts)):
            if not _INT.fullmatch(value):
                raise MapError(where, f"a non-negative integer {name}", value)
            values[name] = int(value)
        if not map_name:
            raise MapError(where, "a map name", map_name)
        if not _FLOAT.fullmatch(length_text) or not math.isfinite(float(length_text)):
            raise MapError(where, "a finite non-negative optimal_length", length_text)
        width, height = values["width"], values["height"]
        if width < 1 or height < 1:
            raise MapError(where, "a positive map width and height", f"{width} x {height}")
        if map_height is not None and height != map_height:
            raise MapError(where, f"map height {map_height} (the map_height given)", height,
                           detail="scenarios for a rescaled map are not supported")
        for axis, limit in (("x", width), ("y", height)):
            for end in ("start", "goal"):
                value = values[f"{end}_{axis}"]
                if value >= limit:
                    raise MapError(where, f"{end}_{axis} inside the {width} x {height} map", value)
        sx, sy = movingai_cell_to_world(values["start_x"], values["start_y"], height, cell_size)
        gx, gy = movingai_cell_to_world(values["goal_x"], values["goal_y"], height, cell_size)
        sx, sy, gx, gy = float(sx), float(sy), float(gx), float(gy)
        theta = math.atan2(gy - sy, gx - sx)
        k = len(problems)
        problems.append(Problem(start=Pose(sx, sy, theta), goal=Pose(gx, gy, theta),
                                label=f"bucket {values['bucket']} #{k}",
                                reference_length=float(length_text) * cell_size))
    return tuple(problems)


def _check_cell_size(cell_size, path: Path) -> float:
    if isinstance(cell_size, bool) or not isinstance(cell_size, (int, float, np.integer, np.floating)):
        raise MapError("cell_size", "a positive finite number of metres per cell", cell_size, detail=f"loading {path}")
    value = float(cell_size)
    if not (math.isfinite(value) and MIN_CELL_M <= value <= MAX_CELL_M):
        raise MapError("cell_size", f"a number of metres per cell in [{MIN_CELL_M:g}, {MAX_CELL_M:g}]", cell_size,
                       detail=f"loading {path}")
    return value


def _map_limits(path: Path, height: int, width: int, cell_size: float) -> None:
    """The grid's size and extent against nhstab.limits, before anything is allocated."""
    try:
        check_grid_size("grid", height, width)
    except InputError as exc:
        raise MapError(str(path), exc.expected, exc.got, detail=exc.detail) from None
    if max(height, width) * cell_size > MAX_COORD_M:
        raise MapError(f"{path}", f"a map within {MAX_COORD_M:g} m", f"{width} x {height} cells of {cell_size:g} m",
                       detail="reduce cell_size")


def _read_lines(path: Path) -> list[str]:
    """The file's lines without line endings (LF or CRLF); non-ASCII bytes are errors."""
    raw = read_bytes(path, what="Moving AI file", error=MapError)
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        lineno = raw.count(b"\n", 0, exc.start) + 1
        raise MapError(f"{path}:{lineno}", "ASCII text", f"byte 0x{raw[exc.start]:02x}") from None
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return [line[:-1] if line.endswith("\r") else line for line in lines]


def _stem(path: Path) -> str:
    """'64room_000.map' -> '64room_000'."""
    return path.name[:-4] if path.name.lower().endswith(".map") else path.stem
