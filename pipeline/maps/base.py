"""The one value every map format loads into, and its obstacle shapes. No FCL here.

Conventions: metres and radians; world frame x right, y up; a pose is (x, y, theta).
Polygons are simple (convex or not), vertices in order (either orientation accepted and stored
counter-clockwise). Occupancy grids store ``occupied[i, j]`` for the cell whose lower-left corner is
at origin + R(yaw) (j * resolution, i * resolution): row 0 is the *lowest* row in y (the loaders flip
image rows, whose row 0 is the top).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..limits import MAX_CELL_M, MAX_COORD_M, MAX_GRID_CELLS, MIN_CELL_M


def check_extent(what: str, values) -> None:
    """Refuse coordinates beyond +-MAX_COORD_M (see :mod:`nhstab.limits`), naming ``what``."""
    arr = np.asarray(values, dtype=float)
    if arr.size and float(np.max(np.abs(arr))) > MAX_COORD_M:
        raise InputError(what, f"coordinates within +-{MAX_COORD_M:g} m", f"{float(np.max(np.abs(arr))):.6g} m")


def check_grid_size(what: str, rows: int, cols: int) -> None:
    """Refuse a grid of more than MAX_GRID_CELLS cells before it is allocated, naming ``what``."""
    if rows * cols > MAX_GRID_CELLS:
        raise InputError(what, f"a grid of at most {MAX_GRID_CELLS:,} cells (4096 x 4096)",
                         f"{cols} x {rows} = {rows * cols:,} cells")


def check_cell_size(what: str, value) -> float:
    """A grid cell size within [MIN_CELL_M, MAX_CELL_M] metres, or an InputError naming ``what``."""
    from ..limits import check_range

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
    vertices: np.ndarray          # (k, 2), k >= 3, counter-clockwise

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3:
            raise InputError("polygon", "at least 3 (x, y) vertices", f"shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise InputError("polygon", "finite vertex coordinates", "NaN or inf")
        check_extent("polygon", v)
        if signed_area(v) < 0:
            v = v[::-1]
        object.__setattr__(self, "vertices", np.ascontiguousarray(v))

    @property
    def area(self) -> float:
        return abs(signed_area(self.vertices))

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


def signed_area(v: np.ndarray) -> float:
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
