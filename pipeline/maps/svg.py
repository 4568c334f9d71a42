"""Bench-MR polygon worlds: Inkscape SVG obstacle files, robot footprints and start/goal poses.

Convention (Bench-MR's loader of the era of the stored files, see ``maps/bench-mr/SOURCE.md``):

* every ``<path d="...">`` element is one closed polygon obstacle. Only straight-line path commands
  are accepted: ``M m L l H h V v Z z`` (relative commands add to the current point; coordinates
  repeated after a command letter repeat the command, a ``m``/``M`` followed by more pairs continues
  with ``l``/``L``). Curves and arcs (``C c S s Q q T t A a``), several subpaths in one ``d``, and
  the other SVG shape elements (``rect``, ``circle``, ...) raise :class:`MapError` instead of being
  approximated;
* world coordinates are ``(x, -y) / 22`` of the SVG user coordinates (``BENCHMR_SCALE``); the
  ``transform`` attributes of groups and paths are ignored, as Bench-MR did;
* a closing vertex that repeats the first one (to ``CLOSE_TOLERANCE`` = 1e-4 world units: relative
  coordinates accumulate rounding) and consecutive repeated vertices (zero-length edges, to
  ``REPEAT_TOLERANCE`` = 1e-9 world units) are dropped; the repeated ones are noted in
  ``meta["notes"]`` (``nhstab map info`` shows them). Real drawings have them (a node placed twice);
  they carry no shape, so they are cleaned, not refused;
* a path of zero area (two points, collinear points, a path drawn out and back) is a *thin* obstacle,
  its segments of zero thickness, and the edges of a path drawn out and back (a spike) are thin parts
  of it (:attr:`nhstab.maps.base.Polygon.parts`; noted in ``meta["notes"]``); a path whose area part
  crosses or touches itself raises :class:`MapError`;
* Bench-MR replaced non-convex polygons by their convex hull. :func:`load_benchmr_svg` keeps the true
  shapes by default and offers the hull as ``convex_hull=True``;
* the map bounds are the axis-aligned bounding box of all polygons (Bench-MR's world has no other
  border);
* robot footprints (``car.svg``, ``warehouse_robot.svg``) are centred on their area centroid, then
  scaled the same way.
"""

from __future__ import annotations

import csv
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import shapely

from ..geometry import is_simple_polygon, polygon_area
from ..limits import MAX_COORD_M
from ..safe_io import read_bytes, read_text
from .base import Map, MapError, Polygon, Pose, Problem, ring_parts

BENCHMR_SCALE = 1.0 / 22.0
"""World units per SVG user unit in the Bench-MR polygon worlds (``polygon.scaling`` = 0.0454545)."""

REPEAT_TOLERANCE = 1e-9
"""World units: consecutive vertices this close are one vertex (a zero-length edge is dropped)."""

CLOSE_TOLERANCE = 1e-4
"""World units: a last vertex this close to the first one repeats it (Inkscape's relative coordinates
accumulate rounding, so a path drawn back to its start without ``z`` misses it by ~1e-5)."""

_SHAPE_TAGS = frozenset({"rect", "circle", "ellipse", "line", "polyline", "polygon"})
_TOKEN = re.compile(r"\s*,?\s*([A-Za-z]|[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")
_SUPPORTED = frozenset("MmLlHhVvZz")
_SCENARIO_COLUMNS = ("environment", "case", "start_x", "start_y", "start_theta",
                     "goal_x", "goal_y", "goal_theta", "robot_shape")


def load_benchmr_svg(path: str | Path, convex_hull: bool = False) -> Map:
    """Load a Bench-MR polygon world (``parking1.svg`` ...) as a :class:`Map` of polygon obstacles.

    ``convex_hull=False`` (default) keeps each polygon's true, possibly non-convex shape;
    ``convex_hull=True`` replaces every polygon by its convex hull, as Bench-MR's planners did.
    Bounds are the bounding box of all polygons; ``meta`` holds the scale and the polygon count.
    """
    path = Path(path)
    raw = _read_svg_polygons(path)
    if not raw:
        raise MapError(str(path), "an SVG with at least one <path> obstacle", "no <path> element")
    polygons, repeats, thin = [], {}, []
    for k, v in enumerate(raw):
        scaled = v * np.array([BENCHMR_SCALE, -BENCHMR_SCALE])
        v = _clean_ring(scaled)
        if _repeats(scaled):
            repeats[k] = _repeats(scaled)
        if convex_hull:
            v = convex_hull_2d(v)
        poly = _polygon(v, path, f"path #{k}")
        if len(poly.parts.segments):
            thin.append(k)
        polygons.append(poly)
    notes = []
    if repeats:
        which = ", ".join(f"#{k}" for k in list(repeats)[:8]) + (", ..." if len(repeats) > 8 else "")
        notes.append(f"{path.name}: dropped {sum(repeats.values())} repeated consecutive vertex(es) (zero-length "
                     f"edges) in {len(repeats)} of {len(raw)} paths ({which})")
    if thin:
        which = ", ".join(f"#{k}" for k in thin[:8]) + (", ..." if len(thin) > 8 else "")
        notes.append(f"{path.name}: {len(thin)} path(s) thin in whole or in part (zero area, or edges drawn out and "
                     f"back: segments of zero thickness) ({which})")
    allv = np.concatenate([p.vertices for p in polygons])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    if not np.all(hi > lo):
        # the bounds are the polygons' bounding box: thin paths along one line alone span no area
        which = ", ".join(f"path #{k}" for k in (thin or range(len(polygons)))[:8])
        raise MapError(f"{path.name}: {which}", "obstacles that span an area (a Bench-MR world's bounds are their "
                       "bounding box)", "thin paths along one line only", detail="add the world's border as a polygon")
    return Map(
        name=path.stem,
        bounds=(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])),
        obstacles=tuple(polygons),
        source=str(path),
        meta={"format": "benchmr_svg", "scale": BENCHMR_SCALE, "polygons": len(polygons),
              "convex_hull": bool(convex_hull), "bounds_from": "bounding box of all polygons", "notes": notes},
    )


def load_benchmr_footprint(path: str | Path) -> Polygon:
    """A Bench-MR robot footprint SVG (one path) as a polygon centred on its area centroid, in metres."""
    path = Path(path)
    raw = _read_svg_polygons(path)
    if len(raw) != 1:
        raise MapError(str(path), "a footprint SVG with exactly one <path>", f"{len(raw)} paths")
    v = raw[0] * np.array([BENCHMR_SCALE, -BENCHMR_SCALE])
    return _polygon(v - polygon_centroid(v), path, "footprint")


def load_benchmr_scenarios(csv_path: str | Path) -> dict[str, tuple[Problem, ...]]:
    """Read ``polygon_scenarios.csv``: ``{world name: (Problem, ...)}`` in file order.

    Lines starting with ``#`` are comments; the header names the columns
    ``environment, case, start_x, start_y, start_theta, goal_x, goal_y, goal_theta, robot_shape``.
    Each :class:`Problem` is labelled ``"<environment>#<case>"``.
    """
    csv_path = Path(csv_path)
    lines = read_text(csv_path, what="UTF-8 CSV file", error=MapError).splitlines()
    numbered = [(n, line) for n, line in enumerate(lines, 1) if line.strip() and not line.lstrip().startswith("#")]
    if not numbered:
        raise MapError(str(csv_path), "a header line and scenario rows", "no data")
    rows = list(csv.reader([line for _, line in numbered]))
    header = [h.strip() for h in rows[0]]
    missing = [c for c in _SCENARIO_COLUMNS if c not in header]
    if missing:
        raise MapError(f"{csv_path.name}: header", f"the columns {', '.join(_SCENARIO_COLUMNS)}",
                       header, detail=f"missing {', '.join(missing)}")
    col = {c: header.index(c) for c in _SCENARIO_COLUMNS}
    out: dict[str, list[Problem]] = {}
    for (lineno, _), row in zip(numbered[1:], rows[1:]):
        where = f"{csv_path.name}: line {lineno}"
        if len(row) != len(header):
            raise MapError(where, f"{len(header)} comma-separated fields", len(row))
        try:
            num = {c: float(row[col[c]]) for c in _SCENARIO_COLUMNS[2:8]}
        except ValueError as exc:
            raise MapError(where, "numeric start/goal fields", row, detail=str(exc)) from None
        if not all(math.isfinite(x) for x in num.values()):
            raise MapError(where, "finite start/goal fields", row)
        env, case = row[col["environment"]].strip(), row[col["case"]].strip()
        out.setdefault(env, []).append(Problem(
            start=Pose(num["start_x"], num["start_y"], num["start_theta"]),
            goal=Pose(num["goal_x"], num["goal_y"], num["goal_theta"]),
            label=f"{env}#{case}",
        ))
    return {env: tuple(problems) for env, problems in out.items()}


def benchmr_robot_shapes(csv_path: str | Path) -> dict[str, str]:
    """``{world name: footprint SVG file name}`` from the ``robot_shape`` column of ``polygon_scenarios.csv``."""
    csv_path = Path(csv_path)
    lines = read_text(csv_path, what="UTF-8 CSV file", error=MapError).splitlines()
    rows = list(csv.reader([ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]))
    if not rows or "environment" not in rows[0] or "robot_shape" not in rows[0]:
        raise MapError(f"{csv_path.name}: header", "the columns environment and robot_shape", rows[:1])
    e, r = rows[0].index("environment"), rows[0].index("robot_shape")
    return {row[e].strip(): row[r].strip() for row in rows[1:] if len(row) == len(rows[0])}


# ----------------------------------------------------------------------------------------------
# geometry helpers

def polygon_centroid(v: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon with vertices ``v`` (k, 2), either orientation."""
    x, y = v[:, 0], v[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    a = 0.5 * cross.sum()
    if abs(a) < 1e-15:
        raise MapError("footprint", "a polygon with non-zero area", "zero area")
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * a)


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """Convex hull of points (k, 2), counter-clockwise from its lowest vertex in (x, y) order, collinear
    points dropped; fewer than 3 distinct points give them sorted, points all on one line the line's two
    ends. GEOS's hull (shapely), faster than a monotone chain in Python (``nhstab bench geometry``); its
    orientation test is exact, so points that float cross products would call collinear with their
    neighbours but are not, by a few units of the last place, are kept."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    hull = shapely.convex_hull(shapely.multipoints(pts)) if len(pts) else None
    if not isinstance(hull, shapely.Polygon):                  # fewer than 3 points, or all on one line
        pts = np.unique(pts, axis=0)                           # sorted by x, then y
        return pts if len(pts) < 3 else pts[[0, -1]]
    ring = shapely.get_coordinates(hull.exterior)[:-1]
    if polygon_area(ring) < 0:
        ring = ring[::-1]
    first = np.lexsort((ring[:, 1], ring[:, 0]))[0]
    return np.roll(ring, -first, axis=0)


def _polygon(v: np.ndarray, path: Path, what: str) -> Polygon:
    v = _clean_ring(v)
    if len(v) and not float(np.max(np.abs(v))) <= MAX_COORD_M:
        raise MapError(f"{path.name}: {what}", f"coordinates within +-{MAX_COORD_M:g} m",
                       f"{float(np.max(np.abs(v))):.6g} m")
    if len(np.unique(v, axis=0)) < 2:
        raise MapError(f"{path.name}: {what}", "a path of at least 2 distinct vertices", f"{len(v)} vertices")
    if len(v) >= 3 and abs(polygon_area(v)) > 1e-12 and is_simple_polygon(v):
        return Polygon(v)
    try:
        ring_parts(v)               # thin (zero area), or an area part with thin spikes
    except ValueError as exc:
        if len(v) >= 3 and abs(polygon_area(v)) > 1e-12:
            return Polygon(v)       # as before: kept as drawn (triangulated by the collision world)
        raise MapError(f"{path.name}: {what}", "a polygon, or a path of zero area (a thin obstacle)",
                       f"{len(v)} vertices", detail=str(exc)) from None
    return Polygon(v)


def _clean_ring(v: np.ndarray, close_tol: float = CLOSE_TOLERANCE) -> np.ndarray:
    """Drop consecutive duplicate vertices (each within ``REPEAT_TOLERANCE`` in both coordinates of
    the last vertex kept) and closing vertices within ``close_tol`` of the first one. Not shapely's
    repeated-point filter, whose tolerance is a Euclidean distance."""
    if len(v) == 0:
        return v
    if not np.all(np.any(np.abs(np.diff(v, axis=0)) > REPEAT_TOLERANCE, axis=1)):
        v = v[_kept(v)]                         # some vertex near the one before it (else all are kept)
    while len(v) > 1 and np.all(np.abs(v[-1] - v[0]) <= close_tol):
        v = v[:-1]
    return v


def _kept(v: np.ndarray) -> list[int]:
    """The indices of the vertices :func:`_clean_ring` keeps, each against the last one kept."""
    keep = [0]
    for i in range(1, len(v)):
        if np.any(np.abs(v[i] - v[keep[-1]]) > REPEAT_TOLERANCE):
            keep.append(i)
    return keep


def _repeats(v: np.ndarray) -> int:
    """How many vertices repeat the one before them (not counting a closing vertex that repeats the first)."""
    if len(v) < 2:
        return 0
    same = ~np.any(np.abs(np.diff(v, axis=0)) > REPEAT_TOLERANCE, axis=1)
    n = int(same.sum())
    return n


# ----------------------------------------------------------------------------------------------
# SVG parsing

def _read_svg_polygons(path: Path) -> list[np.ndarray]:
    """Vertex arrays (SVG user units, SVG y-down) of every ``<path>`` element, in document order."""
    data = read_bytes(path, what="SVG file", error=MapError)
    try:
        root = ET.fromstring(data)
    except (ET.ParseError, UnicodeDecodeError, ValueError) as exc:
        raise MapError(str(path), "a well-formed SVG (XML) file", detail=str(exc)) from None
    out = []
    for k, elem in enumerate(e for e in root.iter() if isinstance(e.tag, str)):
        tag = elem.tag.rsplit("}", 1)[-1]
        if tag in _SHAPE_TAGS:
            raise MapError(f"{path.name}: <{tag}> element", "obstacles drawn as <path> elements only",
                           elem.get("id", f"element #{k}"))
        if tag != "path":
            continue
        d = elem.get("d")
        ident = elem.get("id", f"path #{len(out)}")
        if d is None:
            raise MapError(f"{path.name}: {ident}", "a <path> with a d attribute", "no d attribute")
        out.append(parse_path_d(d, f"{path.name}: {ident}"))
    return out


def parse_path_d(d: str, where: str = "path") -> np.ndarray:
    """Vertices (k, 2) of one straight-line SVG subpath ``d`` (commands M m L l H h V v Z z).

    Raises :class:`MapError` naming ``where`` for curves, arcs, several subpaths or bad syntax.
    """
    tokens = _tokenize(d, where)
    if not tokens or tokens[0] not in ("M", "m"):
        raise MapError(where, "a path starting with M or m", d[:40])
    pts: list[tuple[float, float]] = []
    cur = (0.0, 0.0)
    start = cur
    cmd = ""
    closed = False
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        if isinstance(tok, str):
            if tok not in _SUPPORTED:
                raise MapError(where, "straight-line path commands M m L l H h V v Z z",
                               tok, detail="curves and arcs are not approximated")
            cmd = tok
            i += 1
            if cmd in "Zz":
                if not pts:
                    raise MapError(where, "a path with vertices before Z", d[:40])
                cur, closed = start, True
                continue
            if closed or (cmd in "Mm" and pts):
                raise MapError(where, "a single subpath per <path>", "a second moveto",
                               detail="split it into several <path> elements")
        elif cmd in ("", "Z", "z"):
            raise MapError(where, "a command letter before coordinates", tok)
        n = 1 if cmd in "HhVv" else 2
        args = tokens[i:i + n]
        if len(args) < n or any(isinstance(a, str) for a in args):
            raise MapError(where, f"{n} number(s) after command {cmd}", args)
        i += n
        x, y = cur
        if cmd == "M" or cmd == "L":
            cur = (args[0], args[1])
        elif cmd == "m" or cmd == "l":
            cur = (x + args[0], y + args[1])
        elif cmd == "H":
            cur = (args[0], y)
        elif cmd == "h":
            cur = (x + args[0], y)
        elif cmd == "V":
            cur = (x, args[0])
        else:  # "v"
            cur = (x, y + args[0])
        if cmd in "Mm":
            start = cur
            cmd = "L" if cmd == "M" else "l"      # implicit lineto after a moveto
        pts.append(cur)
    v = np.array(pts, dtype=float).reshape(-1, 2)
    if not np.all(np.isfinite(v)):
        raise MapError(where, "finite coordinates", "NaN or inf")
    return v


def _tokenize(d: str, where: str) -> list[str | float]:
    tokens: list[str | float] = []
    pos, end = 0, len(d.rstrip())
    while pos < end:
        m = _TOKEN.match(d, pos)
        if m is None or m.end() == pos:
            raise MapError(where, "SVG path data (command letters and numbers)", d[pos:pos + 20])
        t = m.group(1)
        tokens.append(t if t.isalpha() else float(t))
        pos = m.end()
    return tokens
