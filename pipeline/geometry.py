"""SE(2) helpers, polygons and robot footprints.

A footprint is given in the robot frame, with the reference point of the model's (x, y) at the
origin and the heading along +x: the rear-axle midpoint for cars, the wheel-axis midpoint for the
unicycle.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import shapely

from .errors import InputError
from .limits import MAX_COORD_M, MAX_POLYGON_VERTICES


def wrap_angle(angle):
    """Wrap angles to [-pi, pi). Works elementwise on arrays."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def cos_sin(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of an array of angles from the tangent of their halves (t = tan(a / 2): cos a =
    (1 - t^2) / (1 + t^2), sin a = 2 t / (1 + t^2)), for the tubes' long arrays: where numpy's tangent
    is vectorised and its cosine and sine are not, this is faster than np.cos and np.sin together.
    Absolute error 2.2e-16 against them over |a| <= 50
    (tested); not finite where they are not. Not for the planner or the plant, whose arithmetic the
    committed results depend on."""
    a = np.asarray(angle, dtype=float)
    if a.ndim == 0:
        c, s = cos_sin(a.reshape(1))
        return c[0], s[0]
    t = np.multiply(a, 0.5)                       # in place from here: half the temporaries
    np.tan(t, out=t)
    t2 = t * t
    den = t2 + 1.0
    np.reciprocal(den, out=den)
    cos = np.subtract(1.0, t2, out=t2)
    cos *= den
    t += t
    t *= den
    return cos, t


def rotation(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def transform_points(points: np.ndarray, pose) -> np.ndarray:
    """Points (k, 2) in the robot frame to the world frame at pose (x, y, theta)."""
    x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
    return np.asarray(points, dtype=float) @ rotation(th).T + [x, y]


def polygon_area(v: np.ndarray) -> float:
    """Signed area (positive for counter-clockwise), the shoelace formula in numpy. Kept rather than
    shapely's area: faster on the small rings of footprints and obstacle parts, and shapely's area has
    no sign (``nhstab bench geometry``)."""
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.concatenate((y[1:], y[:1]))) - np.dot(y, np.concatenate((x[1:], x[:1]))))


def outline_geometry(v: np.ndarray):
    """The shapely geometry of an outline (k, 2): a polygon, or a segment (a line string) when k is 2."""
    v = np.asarray(v, dtype=float)
    return shapely.LineString(v) if len(v) == 2 else shapely.Polygon(v)


def point_in_polygon(x: float, y: float, v: np.ndarray) -> bool:
    """Does (x, y) lie in the polygon ring ``v`` (k, 2; a segment when k is 2) or on its boundary?
    GEOS's point location (shapely ``intersects_xy``): even-odd crossings for a ring that crosses
    itself, a point on an edge inside. Faster than numpy ray casting on one point (``nhstab bench geometry``)."""
    return bool(shapely.intersects_xy(outline_geometry(v), float(x), float(y)))


def is_simple_polygon(v: np.ndarray) -> bool:
    """True if the closed ring ``v`` (k, 2) has no self-intersection, touching or folded-back edges, and
    no edge of zero length. GEOS's ring simplicity test (shapely): it compares the edges whose bounding
    boxes overlap, near-linear on an outline of short edges, quadratic at worst (long parallel edges),
    hence :data:`~nhstab.limits.MAX_POLYGON_VERTICES`."""
    v = np.ascontiguousarray(v, dtype=float)
    k = len(v)
    if k < 3 or np.any(np.all(np.roll(v, -1, axis=0) == v, axis=1)):
        return False
    if polygon_area(v) < 0:
        v = np.ascontiguousarray(v[::-1])         # one key for both orientations (Polygon stores it ccw)
    return _is_simple_ring(v.tobytes())


@functools.lru_cache(maxsize=16)
def _is_simple_ring(ring: bytes) -> bool:
    """GEOS's test of the ring of float64 (x, y) pairs ``ring``, remembered: a map's reader, its
    polygon parts and the triangulation each ask about the same rings."""
    return bool(shapely.is_simple(shapely.linearrings(np.frombuffer(ring, dtype=float).reshape(-1, 2))))


def is_convex(v: np.ndarray, tol: float = 1e-12) -> bool:
    """True if the counter-clockwise polygon v is convex (collinear vertices allowed): every turn
    left, to ``tol`` relative. Kept rather than a shapely construction (the convex hull's area against
    the polygon's): faster on small rings, and shapely has no convexity test (``nhstab bench geometry``)."""
    d1 = np.concatenate((v[1:], v[:1])) - v
    d2 = np.concatenate((d1[1:], d1[:1]))
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    return bool(np.all(cross >= -tol * max(1.0, float(np.abs(v).max()) ** 2)))


def triangulate(v: np.ndarray) -> list[np.ndarray]:
    """A triangulation of the simple polygon ``v`` (k, 2) into counter-clockwise (3, 2) triangles: GEOS's
    constrained Delaunay triangulation (shapely), O(k log k) in practice, without the triangles of zero
    area that collinear vertices make (they cover nothing the others do not). A ring that is not simple
    (it crosses or touches itself) is refused."""
    v = np.asarray(v, dtype=float)
    if not is_simple_polygon(v):
        raise InputError("polygon", "a simple (non-self-intersecting) polygon", f"{len(v)} vertices")
    tris = shapely.get_coordinates(shapely.get_parts(shapely.constrained_delaunay_triangles(shapely.Polygon(v))))
    tris = tris.reshape(-1, 4, 2)[:, :3]            # each triangle's closed ring: its 3 corners and the first again
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    scale = max(1.0, float(np.abs(v).max())) ** 2
    tris = np.where((cross < 0)[:, None, None], tris[:, ::-1], tris)
    return list(tris[np.abs(cross) > 1e-15 * scale])


def convex_parts(v: np.ndarray) -> list[np.ndarray]:
    """The polygon itself if convex, else its triangles."""
    v = np.asarray(v, dtype=float)
    if polygon_area(v) < 0:
        v = v[::-1]
    return [v] if is_convex(v) else triangulate(v)


def point_polygon_distance(p, v: np.ndarray) -> float:
    """Euclidean distance from point p to the closed polygon v (0 inside or on it; a ring that crosses
    itself counts its inside even-odd). GEOS's distance (shapely), faster than numpy vertex-to-edge
    arrays on one point (``nhstab bench geometry``)."""
    return float(shapely.distance(outline_geometry(v), shapely.Point(float(p[0]), float(p[1]))))


@dataclass(frozen=True)
class Footprint:
    """A robot's shape in its own frame: a disc (``radius``) or a polygon (``vertices``, (k, 2))."""

    radius: float | None = None
    vertices: np.ndarray | None = None
    label: str = ""

    def __post_init__(self):
        if (self.radius is None) == (self.vertices is None):
            raise InputError("footprint", "either a radius or polygon vertices", (self.radius, self.vertices))
        if self.radius is not None and not (math.isfinite(self.radius) and 0 < self.radius <= MAX_COORD_M):
            raise InputError("footprint.radius", f"a number in (0, {MAX_COORD_M:g}] m", self.radius)
        if self.vertices is not None:
            v = np.asarray(self.vertices, dtype=float)
            if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 or not np.all(np.isfinite(v)):
                raise InputError("footprint.vertices", "at least 3 finite (x, y) points", f"shape {v.shape}")
            if len(v) > MAX_POLYGON_VERTICES:
                raise InputError("footprint.vertices", f"at most {MAX_POLYGON_VERTICES:,} points", len(v))
            if float(np.abs(v).max()) > MAX_COORD_M:
                raise InputError("footprint.vertices", f"coordinates within +-{MAX_COORD_M:g} m",
                                 f"{float(np.abs(v).max()):.6g} m")
            if polygon_area(v) < 0:
                v = v[::-1]
            object.__setattr__(self, "vertices", v)

    @classmethod
    def disc(cls, radius: float) -> "Footprint":
        return cls(radius=float(radius), label=f"disc r={radius:g} m")

    @classmethod
    def rectangle(cls, length: float, width: float, rear_overhang: float | None = None) -> "Footprint":
        """A rectangle ``length`` x ``width``. With ``rear_overhang`` the reference point (the rear
        axle) lies that far ahead of the rear edge (cars); without, the rectangle is centred."""
        if not (length > 0 and width > 0):
            raise InputError("footprint", "positive length and width", (length, width))
        if not (length <= MAX_COORD_M and width <= MAX_COORD_M):
            raise InputError("footprint", f"a length and width of at most {MAX_COORD_M:g} m", (length, width))
        back = length / 2 if rear_overhang is None else float(rear_overhang)
        if not (0 <= back <= length):
            raise InputError("footprint.rear_overhang", f"in [0, length = {length:g}]", rear_overhang)
        v = np.array([[-back, -width / 2], [length - back, -width / 2], [length - back, width / 2], [-back, width / 2]])
        label = f"rectangle {length:g} x {width:g} m" + ("" if rear_overhang is None else f", rear overhang {back:g} m")
        return cls(vertices=v, label=label)

    @classmethod
    def polygon(cls, vertices) -> "Footprint":
        return cls(vertices=np.asarray(vertices, dtype=float), label="polygon")

    @cached_property
    def convex(self) -> bool:
        """A disc, or a polygon with no reflex corner (either orientation)."""
        return self.radius is not None or is_convex(self.vertices) or is_convex(self.vertices[::-1])

    @property
    def bounding_radius(self) -> float:
        """Distance from the reference point to the farthest point of the footprint."""
        if self.radius is not None:
            return self.radius
        return float(np.max(np.hypot(self.vertices[:, 0], self.vertices[:, 1])))

    def outline_at(self, pose, n_circle: int = 48) -> np.ndarray:
        """World outline (k, 2) at a pose (discs as an n-gon, for drawing)."""
        if self.radius is not None:
            a = np.linspace(0, 2 * np.pi, n_circle, endpoint=False)
            return np.stack([pose[0] + self.radius * np.cos(a), pose[1] + self.radius * np.sin(a)], axis=1)
        return transform_points(self.vertices, pose)

    def describe(self) -> dict:
        if self.radius is not None:
            return {"type": "disc", "radius": self.radius}
        return {"type": "polygon", "vertices": self.vertices.tolist(), "label": self.label}
