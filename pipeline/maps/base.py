"""The one value every map format loads into, and its obstacle shapes. No FCL here.

Conventions: metres and radians; world frame x right, y up; a pose is (x, y, theta).
Polygons are simple (convex or not), vertices in order (either orientation accepted and stored
counter-clockwise). A polygon may also be *thin*, wholly or in part: the pieces of its ring that are
traversed back and forth (a ring of zero area, collinear points, a spike drawn out and back, a line
or polyline drawn as :func:`polyline`) are segments of zero thickness (:attr:`Polygon.parts`). Occupancy grids store ``occupied[i, j]`` for the cell whose lower-left corner is
at origin + R(yaw) (j * resolution, i * resolution): row 0 is the *lowest* row in y (the loaders flip
image rows, whose row 0 is the top).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple

import numpy as np

from ..errors import InputError
from ..geometry import is_simple_polygon, polygon_area
from ..limits import MAX_CELL_M, MAX_COORD_M, MAX_GRID_CELLS, MAX_POLYGON_VERTICES, MIN_CELL_M, check_range


def check_extent(what: str, values) -> None:
    """Refuse coordinates beyond +-MAX_COORD_M (see :mod:`nhstab.limits`), naming ``what``."""
    arr = np.asarray(values, dtype=float)
    if arr.size and float(np.max(np.abs(arr))) > MAX_COORD_M:
        raise InputError(what, f"coordinates within +-{MAX_COORD_M:g} m", f"{float(np.max(np.abs(arr))):.6g} m")


def check_vertex_count(what: str, k: int, per: str = "vertices", most: int = MAX_POLYGON_VERTICES) -> None:
    """Refuse a polygon of more than MAX_POLYGON_VERTICES vertices (see :mod:`nhstab.limits`) before its
    geometry is checked, naming ``what``."""
    if k > most:
        raise InputError(what, f"at most {most:,} {per}", k)


def check_grid_size(what: str, rows: int, cols: int) -> None:
    """Refuse a grid of more than MAX_GRID_CELLS cells before it is allocated, naming ``what``."""
    if rows * cols > MAX_GRID_CELLS:
        raise InputError(what, f"a grid of at most {MAX_GRID_CELLS:,} cells (4096 x 4096)",
                         f"{cols} x {rows} = {rows * cols:,} cells")


def check_cell_size(what: str, value) -> float:
    """A grid cell size within [MIN_CELL_M, MAX_CELL_M] metres, or an InputError naming ``what``."""
    return check_range(what, value, MIN_CELL_M, MAX_CELL_M, "m per cell")


class MapError(InputError):
    """A map file is missing, unreadable or malformed. ``argument`` names the file (and key)."""


@dataclass(frozen=True)
class Pose:
    x: float
    y: float
    theta: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.theta])


@dataclass(frozen=True)
class Polygon:
    """A polygon obstacle: its ring ``vertices`` (k, 2), counter-clockwise where it has area. Its point
    set is :attr:`parts`: the area of the ring's simple part and the segments its ring traverses back
    and forth (thin: zero thickness). A ring of two vertices is one segment."""

    vertices: np.ndarray          # (k, 2), k >= 2, counter-clockwise

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 2:
            raise InputError("polygon", "at least 2 (x, y) vertices", f"shape {v.shape}")
        check_vertex_count("polygon", len(v))
        if not np.all(np.isfinite(v)):
            raise InputError("polygon", "finite vertex coordinates", "NaN or inf")
        check_extent("polygon", v)
        if polygon_area(v) < 0:
            v = v[::-1]
        object.__setattr__(self, "vertices", np.ascontiguousarray(v))

    @property
    def area(self) -> float:
        return abs(polygon_area(self.vertices))

    @cached_property
    def parts(self) -> "RingParts":
        """The ring split into its area (a simple counter-clockwise ring, or None) and its thin
        segments (m, 2, 2) (:func:`ring_parts`). A ring that does not split so (it crosses or touches
        itself) is all area, as it was drawn."""
        v = self.vertices
        if abs(polygon_area(v)) > 1e-12 * max(1.0, float(np.abs(v).max())) ** 2 and is_simple_polygon(v):
            return RingParts(v if polygon_area(v) > 0 else v[::-1], np.zeros((0, 2, 2)))   # all area (fast)
        try:
            return ring_parts(v)
        except ValueError:
            return RingParts(self.vertices, np.zeros((0, 2, 2)))

    @property
    def thin(self) -> bool:
        """No area at all: a line, a polyline, a ring of zero area (segments of zero thickness)."""
        return self.parts.area is None

    def bounds(self) -> tuple[float, float, float, float]:
        v = self.vertices
        return float(v[:, 0].min()), float(v[:, 1].min()), float(v[:, 0].max()), float(v[:, 1].max())


@dataclass(frozen=True)
class Circle:
    center: tuple[float, float]
    radius: float

    def __post_init__(self):
        c = tuple(float(v) for v in self.center)
        if len(c) != 2 or not all(math.isfinite(v) for v in c):
            raise InputError("circle.center", "two finite numbers", self.center)
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise InputError("circle.radius", "a positive finite number", self.radius)
        check_extent("circle", [abs(c[0]) + self.radius, abs(c[1]) + self.radius])
        object.__setattr__(self, "center", c)

    def bounds(self) -> tuple[float, float, float, float]:
        (x, y), r = self.center, self.radius
        return x - r, y - r, x + r, y + r


def box_polygon(cx: float, cy: float, length: float, width: float, yaw: float = 0.0) -> Polygon:
    """An oriented box (centre, length along yaw, width across) as a polygon."""
    if not (length > 0 and width > 0):
        raise InputError("box", "positive length and width", (length, width))
    c, s = math.cos(yaw), math.sin(yaw)
    half = np.array([[-length, -width], [length, -width], [length, width], [-length, width]]) / 2
    rot = np.array([[c, -s], [s, c]])
    return Polygon(half @ rot.T + [cx, cy])


@dataclass(frozen=True)
class OccupancyGrid:
    occupied: np.ndarray          # (H, W) bool, row 0 lowest in y
    resolution: float             # m per cell
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)   # pose of the lower-left corner of cell (0, 0)
    unknown: np.ndarray | None = None   # (H, W) bool: cells neither free nor occupied in the source

    def __post_init__(self):
        occ = np.asarray(self.occupied, dtype=bool)
        if occ.ndim != 2 or occ.size == 0:
            raise InputError("grid", "a non-empty 2-D array", f"shape {occ.shape}")
        check_grid_size("grid", *occ.shape)
        check_cell_size("resolution", self.resolution)
        origin = tuple(float(v) for v in self.origin)
        if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
            raise InputError("origin", "three finite numbers (x, y, yaw)", self.origin)
        object.__setattr__(self, "occupied", occ)
        object.__setattr__(self, "origin", origin)
        check_extent("grid", self.corners())

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupied.shape

    def cell_to_world(self, i, j):
        """World coordinates of the centre of cell (row i, column j)."""
        ox, oy, yaw = self.origin
        u = (np.asarray(j, dtype=float) + 0.5) * self.resolution
        v = (np.asarray(i, dtype=float) + 0.5) * self.resolution
        c, s = math.cos(yaw), math.sin(yaw)
        return ox + c * u - s * v, oy + s * u + c * v

    def world_to_cell(self, x, y):
        """(row i, column j) of the cell containing world point (x, y); may be out of range."""
        ox, oy, yaw = self.origin
        dx, dy = np.asarray(x, dtype=float) - ox, np.asarray(y, dtype=float) - oy
        c, s = math.cos(yaw), math.sin(yaw)
        u, v = c * dx + s * dy, -s * dx + c * dy
        return np.floor(v / self.resolution).astype(int), np.floor(u / self.resolution).astype(int)

    def corners(self) -> np.ndarray:
        """The four world corners of the grid, counter-clockwise from the origin."""
        H, W = self.shape
        ox, oy, yaw = self.origin
        c, s = math.cos(yaw), math.sin(yaw)
        uv = np.array([[0, 0], [W, 0], [W, H], [0, H]], dtype=float) * self.resolution
        return np.stack([ox + c * uv[:, 0] - s * uv[:, 1], oy + s * uv[:, 0] + c * uv[:, 1]], axis=1)

    def bounds(self) -> tuple[float, float, float, float]:
        c = self.corners()
        return float(c[:, 0].min()), float(c[:, 1].min()), float(c[:, 0].max()), float(c[:, 1].max())


Shape = Polygon | Circle


@dataclass(frozen=True)
class Problem:
    """A start/goal pair, e.g. one line of a Moving AI .scen file."""

    start: Pose
    goal: Pose
    label: str = ""
    reference_length: float | None = None


@dataclass(frozen=True)
class Map:
    """A 2-D world: bounds, known obstacles (shapes and grids), unknown obstacles, optional poses."""

    name: str
    bounds: tuple[float, float, float, float]           # xmin, ymin, xmax, ymax
    obstacles: tuple[Shape, ...] = ()                   # known a priori
    grids: tuple[OccupancyGrid, ...] = ()               # known a priori (occupied cells are obstacles)
    unknown_obstacles: tuple[Shape, ...] = ()           # in the world, not in the robot's map
    start: Pose | None = None
    goal: Pose | None = None
    robot: dict | None = None                           # default robot spec, e.g. {"model": "rwd_car"}
    problems: tuple[Problem, ...] = ()
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        b = tuple(float(v) for v in self.bounds)
        if len(b) != 4 or not all(math.isfinite(v) for v in b) or not (b[0] < b[2] and b[1] < b[3]):
            raise InputError("bounds", "finite [xmin, ymin, xmax, ymax] with xmin < xmax and ymin < ymax", self.bounds)
        check_extent("bounds", b)
        object.__setattr__(self, "bounds", b)

    def contains(self, x: float, y: float) -> bool:
        xmin, ymin, xmax, ymax = self.bounds
        return xmin <= x <= xmax and ymin <= y <= ymax

    @property
    def size(self) -> tuple[float, float]:
        return self.bounds[2] - self.bounds[0], self.bounds[3] - self.bounds[1]


class RingParts(NamedTuple):
    """A polygon's ring split by :func:`ring_parts`: ``area`` a simple counter-clockwise ring (k, 2) or
    None; ``segments`` (m, 2, 2) the pieces traversed back and forth (zero thickness)."""

    area: np.ndarray | None
    segments: np.ndarray


def ring_parts(v) -> RingParts:
    """Split the closed ring ``v`` (k, 2) into the area it encloses and its thin segments.

    Every edge is cut at the ring's vertices that lie on it (exactly, to 1e-12 of the coordinates'
    scale), so that overlapping edges share their pieces. A piece traversed as often one way as the
    other (out and back: a spike, a fold, a whole ring of zero area) encloses nothing: it is a thin
    segment. The pieces traversed once more one way than the other bound the area; they must chain
    into one simple ring (each vertex met once), else ValueError (a ring that crosses or touches
    itself). Consecutive vertices equal to each other are ignored."""
    v = np.asarray(v, dtype=float)
    keep = np.ones(len(v), dtype=bool)
    keep[1:] = np.any(v[1:] != v[:-1], axis=1)
    v = v[keep]
    while len(v) > 1 and np.array_equal(v[0], v[-1]):
        v = v[:-1]
    if len(v) < 2:
        raise ValueError("a ring of fewer than 2 distinct points")
    scale = max(1.0, float(np.abs(v).max()))
    tol = 1e-12 * scale
    pts = [tuple(p) for p in v.tolist()]
    uniq = list(dict.fromkeys(pts))
    U = np.array(uniq)
    index = {p: i for i, p in enumerate(uniq)}
    count: dict[tuple[int, int], int] = {}           # directed piece (i, j) -> times traversed
    # the ring's vertices lying on each edge: candidates from GEOS's tree of the points within tol of the
    # edge (O(k log k)), then their exact position along it
    import shapely

    ends = list(zip(pts, pts[1:] + pts[:1]))
    lines = shapely.linestrings(np.array([[a, b] for a, b in ends]))
    edge_of, point_of = shapely.STRtree(shapely.points(U)).query(lines, predicate="dwithin", distance=tol)
    near: dict[int, list[int]] = {}
    for e, q in zip(edge_of.tolist(), point_of.tolist()):
        near.setdefault(e, []).append(q)
    for e, (a, b) in enumerate(ends):
        A, B = np.array(a), np.array(b)
        d = B - A
        dd = float(d @ d)
        cand = np.array(near.get(e, []), dtype=int)
        rel = U[cand] - A
        t = rel @ d / dd
        off = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0]) / math.sqrt(dd)
        ok = (off <= tol) & (t > 0.0) & (t < 1.0)
        on, t_on = cand[ok], t[ok]
        chain = [index[a]] + [int(k) for k in on[np.argsort(t_on)]] + [index[b]]
        for i, j in zip(chain[:-1], chain[1:]):
            if i != j:
                count[(i, j)] = count.get((i, j), 0) + 1
    thin, area = [], []
    for (i, j), n in count.items():
        back = count.get((j, i), 0)
        if (j, i) in count and j < i:
            continue                                   # the pair is handled from (i < j)
        net = n - back
        if net == 0:
            thin.append((U[i], U[j]))
        elif abs(net) == 1:
            area.append((i, j) if net > 0 else (j, i))
        else:
            raise ValueError("a piece of the ring traversed twice the same way")
    segments = np.array(thin, dtype=float).reshape(-1, 2, 2)
    if not area:
        return RingParts(None, segments)
    nxt: dict[int, int] = {}
    for i, j in area:
        if i in nxt:
            raise ValueError("the ring touches itself")
        nxt[i] = j
    start = area[0][0]
    ring, k = [start], nxt[start]
    while k != start:
        if k not in nxt or len(ring) > len(area):
            raise ValueError("the ring's area is not one loop")
        ring.append(k)
        k = nxt[k]
    if len(ring) != len(area):
        raise ValueError("the ring's area is not one loop")
    R = U[ring]
    # drop vertices where the ring runs straight on (the cuts made above)
    prev, nextv = np.roll(R, 1, axis=0), np.roll(R, -1, axis=0)
    cross = (R[:, 0] - prev[:, 0]) * (nextv[:, 1] - R[:, 1]) - (R[:, 1] - prev[:, 1]) * (nextv[:, 0] - R[:, 0])
    dot = np.einsum("ij,ij->i", R - prev, nextv - R)
    straight = (np.abs(cross) <= tol * scale) & (dot > 0)
    R = R[~straight] if (~straight).sum() >= 3 else R
    if len(R) < 3 or abs(polygon_area(R)) <= 1e-12 * scale * scale:
        raise ValueError("the ring's area part has no area")
    if not is_simple_polygon(R):
        raise ValueError("the ring's area part crosses itself")
    return RingParts(R if polygon_area(R) > 0 else R[::-1], segments)


def polyline(points) -> Polygon:
    """A line or polyline of zero thickness (a curb, a thin wall) as a thin :class:`Polygon`: its ring
    runs along the points and back (p0 ... pk ... p1), so every piece is traversed both ways. The
    segments may cross each other. At least 2 distinct points; repeated consecutive points are
    dropped; a polyline that ends on its first point is a closed outline (still thin)."""
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise InputError("line", "a list of [x, y] points", f"shape {p.shape}")
    keep = np.ones(len(p), dtype=bool)
    keep[1:] = np.any(p[1:] != p[:-1], axis=1)
    p = p[keep]
    if len(p) < 2:
        raise InputError("line", "at least 2 distinct [x, y] points", f"{len(p)} distinct")
    ring = np.vstack([p, p[-2:0:-1]]) if len(p) > 2 else p
    return Polygon(ring)
