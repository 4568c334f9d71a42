"""FCL collision worlds built from a :class:`~nhstab.maps.base.Map` (the only module importing fcl).

The 2-D world is modelled as prisms of equal height in 3-D, so that FCL's 3-D distances between
them are the 2-D distances of their cross-sections: polygons become convex prisms (non-convex ones
are triangulated first; the segments of thin polygons, lines and polylines, flat prisms of zero
thickness: :func:`polygon_pieces`), circles cylinders, occupied grid cells boxes (runs of cells merged into few
rectangles), and by default the map's bounds four walls just outside them. A DynamicAABBTree
broad-phase manager holds them.

Queries take a pose (x, y, theta) and a :class:`~nhstab.geometry.Footprint`:

- ``is_free(pose, fp, margin)``: no obstacle within ``margin`` of the footprint (the footprint
  against obstacles inflated by ``margin``, exactly: a Minkowski sum with a disc);
- ``clearance(pose, fp)``: signed distance from the footprint to the nearest obstacle, negative
  (minus the deepest penetration depth found) when they overlap. Between polygons FCL's distance is
  exact; GJK on curved shapes (discs, circles) stops at a tolerance of about 1e-5 m, so a nearest pair
  that involves a disc or circle is re-measured with exact plane geometry;
- ``check_path(poses, fp, margin, resolution)``: a whole path in one call, interpolated at the
  resolution, with the first conflict and the minimum clearance and where they occur.

``CollisionWorld.from_map(m, obstacles="known")`` uses the obstacles known a priori;
``obstacles="all"`` adds the map's unknown obstacles (the real world); ``with_obstacles(shapes)``
adds discovered ones.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import fcl
import numpy as np
import shapely

from .clearance_field import FINE_DISCS_PER_WIDTH, ClearanceField, disc_cover, footprint_points
from .errors import InputError
from .geometry import Footprint, convex_parts, outline_geometry, point_polygon_distance, transform_points, wrap_angle
from .limits import MAX_WORLD_OBJECTS
from .maps.base import Circle, Map, MapError, OccupancyGrid, Polygon

_Z = 1.0                 # prisms span z in [-_Z, _Z]
_WALL = 1.0              # thickness of the boundary walls [m]


def polygon_pieces(shape: Polygon) -> list[np.ndarray]:
    """The convex pieces of a polygon obstacle for FCL and the distance field: its convex parts (the
    polygon itself if convex, else its triangles), and for a thin polygon (a line, a polyline, a ring
    of zero area, spikes drawn out and back: :attr:`~nhstab.maps.base.Polygon.parts`) each segment as
    a piece of two vertices, a flat prism of zero thickness. FCL decides contact with a flat prism as
    with any convex one (tested against shapely); the plane distances measure a segment exactly
    (vertex to edge both ways); the distance field marks the cells along it."""
    area, segments = shape.parts
    if not len(segments):
        return convex_parts(shape.vertices)
    pieces = [] if area is None else convex_parts(area)
    return pieces + [np.array(seg, dtype=float) for seg in segments]


def _prism(v2: np.ndarray) -> fcl.Convex:
    k = len(v2)
    verts = np.vstack([np.column_stack([v2, np.full(k, -_Z)]), np.column_stack([v2, np.full(k, _Z)])])
    faces = [k, *range(k - 1, -1, -1), k, *range(k, 2 * k)]
    for i in range(k):
        j = (i + 1) % k
        faces += [4, i, j, k + j, k + i]
    return fcl.Convex(verts, k + 2, np.asarray(faces, dtype=np.int64))


def _object(geom, x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> fcl.CollisionObject:
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return fcl.CollisionObject(geom, fcl.Transform(R, np.array([x, y, 0.0])))


def grid_rectangles(occupied: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Cover the occupied cells exactly with few axis-aligned rectangles (i0, j0, i1, j1), half-open.

    Each row's runs of occupied cells are found with numpy; a run identical to one in the row below
    extends that rectangle upwards. Exact (every occupied cell covered once, no free cell covered).
    """
    occ = np.asarray(occupied, dtype=bool)
    H, W = occ.shape
    open_rects: dict[tuple[int, int], int] = {}      # (j0, j1) -> i0 of a rectangle still growing
    rects: list[tuple[int, int, int, int]] = []
    padded = np.zeros((H, W + 2), dtype=np.int8)
    padded[:, 1:-1] = occ
    edges = np.diff(padded, axis=1)
    for i in range(H):
        starts = np.flatnonzero(edges[i] == 1)
        ends = np.flatnonzero(edges[i] == -1)
        runs = set(zip(starts.tolist(), ends.tolist()))
        for run in list(open_rects):
            if run not in runs:
                rects.append((open_rects.pop(run), run[0], i, run[1]))
        for run in runs:
            open_rects.setdefault(run, i)
    for (j0, j1), i0 in open_rects.items():
        rects.append((i0, j0, H, j1))
    return rects


@dataclass
class PathCheck:
    """Result of :meth:`CollisionWorld.check_path` (indices refer to the interpolated samples)."""

    clear: bool                       # no sample within ``margin`` of an obstacle
    margin: float
    samples: int
    first_conflict_index: int | None
    first_conflict_pose: np.ndarray | None
    first_conflict_segment: int | None      # index i of the input segment (pose i to i + 1)
    min_clearance: float
    min_clearance_index: int
    min_clearance_pose: np.ndarray
    poses: np.ndarray = field(repr=False)   # (samples, 3) the interpolated poses
    free: np.ndarray = field(repr=False)    # (samples,) True where the sample keeps the margin


class CollisionWorld:
    """An FCL broad-phase world of the obstacles of a map (see the module docstring)."""

    #: free_many measures a free pose's clearance when the next pose FCL decides is this close [m]
    VOUCH_NEAR = 0.1
    #: and vouches for later poses up to this much less than the clearance beyond the margin [m]
    #: (well above FCL's distance tolerance, ~1e-5 m on curved shapes)
    VOUCH_GAP = 1e-3
    #: min_clearance lets a measured clearance bound this many poses either side
    VOUCH_SPAN = 16
    #: min_clearance_less bounds this many poses by their boxes first, and measures the lowest of them:
    #: a batch of exact distances costs a few tenths of a millisecond however small, a box bound a
    #: fraction of a microsecond per object; more poses first make it likelier that the best is among them
    FIRST_BATCH = 64
    #: the objects' box bounds are lowered by this much [m], far above their rounding, so that no pose
    #: whose measured clearance is the smallest is passed over because its bound rounded above it
    BOX_GUARD = 1e-9
    #: free_many and motion_free measure the poses the distance field leaves undecided in one batch of
    #: exact distances (:meth:`_near_batch`) when there are at least this many and they lie along a path
    #: (:func:`_along_a_path`; else, and for fewer, FCL pose by pose)
    BATCH_FROM = 8

    def __init__(self, shapes=(), grids: tuple[OccupancyGrid, ...] = (), bounds=None, walls: bool = True,
                 names=None):
        started = time.perf_counter()
        self.shapes = tuple(shapes)
        #: what each shape is in its map, (list name, index), e.g. ("obstacles", 3): :meth:`hits` names it
        self.names = tuple(names) if names is not None else tuple(("shapes", k) for k in range(len(self.shapes)))
        if len(self.names) != len(self.shapes):
            raise InputError("names", f"one (list, index) per shape ({len(self.shapes)})", len(self.names))
        self.grids = tuple(grids)
        self.bounds = None if bounds is None else tuple(float(b) for b in bounds)
        self.walls = walls
        self._outline: dict[int, tuple] = {}     # id(geometry) -> ("poly", vertices) | ("circle", centre, r)
        #: id(geometry) -> what it is part of: ("shape", k) | ("grid", g, (i0, j0, i1, j1)) | ("bounds", side)
        self._source: dict[int, tuple] = {}
        self._geoms: list = []                   # keeps the geometries (and so their ids) alive
        objects: list[fcl.CollisionObject] = []
        for k, shape in enumerate(self.shapes):
            if isinstance(shape, Polygon):
                for part in polygon_pieces(shape):
                    objects.append(self._add(_prism(part), ("poly", part), source=("shape", k)))
            elif isinstance(shape, Circle):
                objects.append(self._add(fcl.Cylinder(shape.radius, 2 * _Z), ("circle", shape.center, shape.radius),
                                         *shape.center, source=("shape", k)))
            else:
                raise InputError("obstacle", "a Polygon or a Circle", type(shape).__name__)
        self.n_grid_boxes = 0
        rectangles = [grid_rectangles(grid.occupied) for grid in self.grids]
        _check_world_size(len(objects) + sum(map(len, rectangles)))       # before any box is built
        for g, (grid, rects) in enumerate(zip(self.grids, rectangles)):
            ox, oy, yaw = grid.origin
            r = grid.resolution
            c, s = math.cos(yaw), math.sin(yaw)
            for i0, j0, i1, j1 in rects:
                u, v = (j0 + j1) / 2 * r, (i0 + i1) / 2 * r          # centre in the grid frame
                lx, ly = (j1 - j0) * r, (i1 - i0) * r
                cx, cy = ox + c * u - s * v, oy + s * u + c * v
                objects.append(self._add(fcl.Box(lx, ly, 2 * _Z), ("poly", _box(cx, cy, lx, ly, yaw)), cx, cy, yaw,
                                         source=("grid", g, (i0, j0, i1, j1))))
                self.n_grid_boxes += 1
        if walls and self.bounds is not None:
            xmin, ymin, xmax, ymax = self.bounds
            w, h = xmax - xmin, ymax - ymin
            for side, cx, cy, lx, ly in [("bottom", (xmin + xmax) / 2, ymin - _WALL / 2, w + 2 * _WALL, _WALL),
                                         ("top", (xmin + xmax) / 2, ymax + _WALL / 2, w + 2 * _WALL, _WALL),
                                         ("left", xmin - _WALL / 2, (ymin + ymax) / 2, _WALL, h),
                                         ("right", xmax + _WALL / 2, (ymin + ymax) / 2, _WALL, h)]:
                objects.append(self._add(fcl.Box(lx, ly, 2 * _Z), ("poly", _box(cx, cy, lx, ly, 0.0)), cx, cy,
                                         source=("bounds", side)))
        self._objects = objects
        self.manager = fcl.DynamicAABBTreeCollisionManager()
        if objects:
            self.manager.registerObjects(objects)
        self.manager.setup()
        self._robot_key = None
        self._robot_objs: list = []
        #: data derived from this world by its users and kept with it (the planner's guide grids)
        self.cache: dict = {}
        self.build_time_s = time.perf_counter() - started

    def _add(self, geom, outline, x=0.0, y=0.0, yaw=0.0, source=None) -> fcl.CollisionObject:
        self._geoms.append(geom)
        self._outline[id(geom)] = outline
        self._source[id(geom)] = source
        return _object(geom, x, y, yaw)

    # ---- construction ------------------------------------------------------------------------------
    @classmethod
    def from_map(cls, m: Map, obstacles: str = "known", walls: bool = True) -> "CollisionWorld":
        """``obstacles``: "known" (a priori), "unknown" (only those missing from the map) or "all"."""
        if obstacles not in ("known", "unknown", "all"):
            raise InputError("obstacles", "one of known, unknown, all", obstacles)
        shapes = () if obstacles == "unknown" else tuple(m.obstacles)
        names = tuple(("obstacles", k) for k in range(len(shapes)))
        if obstacles in ("unknown", "all"):
            shapes = shapes + tuple(m.unknown_obstacles)
            names = names + tuple(("unknown_obstacles", k) for k in range(len(m.unknown_obstacles)))
        grids = () if obstacles == "unknown" else m.grids
        return cls(shapes, grids, m.bounds, walls, names=names)

    def with_obstacles(self, shapes) -> "CollisionWorld":
        """A new world with ``shapes`` (e.g. discovered obstacles) added. If this world's distance field
        exists, the new one is derived from it (only the added shapes are rasterised)."""
        shapes = tuple(shapes)
        world = CollisionWorld(self.shapes + shapes, self.grids, self.bounds, self.walls,
                               names=self.names + tuple(("added", k) for k in range(len(shapes))))
        field = getattr(self, "_field", None)
        if field is not None:
            added = []
            for shape in shapes:
                if isinstance(shape, Polygon):
                    added.extend(("poly", part) for part in polygon_pieces(shape))
                else:
                    added.append(("circle", shape.center, shape.radius))
            world._field = field.with_outlines(added)
        return world

    @property
    def n_objects(self) -> int:
        return len(self._objects)

    # ---- robot -------------------------------------------------------------------------------------
    def _robot(self, fp: Footprint, pose) -> list[fcl.CollisionObject]:
        if self._robot_key is not fp:
            if fp.radius is not None:
                self._robot_objs = [_object(fcl.Cylinder(fp.radius, 2 * _Z))]
            else:
                self._robot_objs = [_object(_prism(part)) for part in convex_parts(fp.vertices)]
            self._robot_key = fp
        half = 0.5 * float(pose[2])            # rotation about z as a quaternion (w, x, y, z)
        tf = fcl.Transform(np.array([math.cos(half), 0.0, 0.0, math.sin(half)]),
                           np.array([float(pose[0]), float(pose[1]), 0.0]))
        for o in self._robot_objs:
            o.setTransform(tf)
        return self._robot_objs

    # ---- queries -----------------------------------------------------------------------------------
    # The public queries check their poses (an InputError naming the argument, not an IndexError or a
    # silently truncated state); the loops inside this class call the unchecked _versions.
    def in_collision(self, pose, fp: Footprint) -> bool:
        """Does the footprint at ``pose`` (x, y, theta) overlap an obstacle?"""
        return self._in_collision(_pose(pose), fp)

    def _in_collision(self, pose, fp: Footprint) -> bool:
        return self._any_contact(self._robot(fp, pose))

    def _any_contact(self, objs) -> bool:
        """Does one of the placed FCL objects ``objs`` touch an obstacle? (A Ctrl-C held meanwhile is raised.)"""
        for o in objs:
            data = fcl.CollisionData()
            self.manager.collide(o, data, _first_contact)
            if _PENDING_INTERRUPT[0]:
                _raise_pending_interrupt()
            if data.result.is_collision:
                return True
        return False

    def distance(self, pose, fp: Footprint) -> float:
        """Unsigned distance to the nearest obstacle (0 when touching or overlapping)."""
        return self._distance(_pose(pose), fp)

    def _distance(self, pose, fp: Footprint) -> float:
        near = self._distance_near(pose, fp)
        return 0.0 if near is None else near

    def _distance_near(self, pose, fp: Footprint):
        """The exact distance from the footprint at ``pose`` to the nearest obstacle when it is positive
        (inf in a world without obstacles), else None (touching or overlapping, as FCL decides). The
        objects are visited in increasing order of a lower bound of their distance (between the
        footprint's bounding box, or a disc's centre less its radius, and the object's bounding box)
        until that bound reaches the best distance found. FCL decides whether the footprint overlaps an
        object whose box it meets; the distance to a separated object is measured exactly in the plane
        (:func:`_poly_distances` and :func:`_circle_distances`: vertex to edge both ways, or a disc's centre
        to the edges; :func:`_exact_distance`, GEOS's distance, for a polygon of more than ``POLY_PAD``
        corners).
        FCL's own distance is not used for the value: for a car's prism it was off by up to 0.95 m at true
        distances of 0.3-2 m on grid maps (GJK), while its contact verdicts are exact."""
        return self._measure_near(pose, fp, math.inf)

    def _measure_near(self, pose, fp: Footprint, upto: float):
        """The exact distance from the footprint at ``pose`` to the nearest object (``upto`` infinite), or
        to the nearest of the objects whose box bound is at most ``upto`` (inf if none: then no object is
        within ``upto``); None on contact. The bound of each object: the distance between the footprint's
        bounding box (a disc's centre less its radius) and the object's box. With ``upto`` infinite, first
        the 8 objects of the smallest bounds (argpartition), then every object whose bound is below the
        best distance found: linear in the number of objects, no sort."""
        boxes, polys, circles, kind = self._shape_tables()
        n = len(boxes)
        if not n:
            return math.inf
        robot_v = None if fp.radius is not None else transform_points(fp.vertices, pose)
        if robot_v is None:                     # the disc's centre to each box, less the radius
            centre = np.asarray(pose[:2], dtype=float)
            lower = _box_gaps(boxes, centre, centre) - fp.radius
        else:                                   # the footprint's box to each box
            lower = _box_gaps(boxes, robot_v.min(axis=0), robot_v.max(axis=0))
        robot = None

        def measure(chunk) -> float | None:
            nonlocal robot
            best = math.inf
            for i in chunk[lower[chunk] <= 0.0]:     # boxes meet: FCL decides overlap (the authority on contact)
                if robot is None:
                    robot = self._robot(fp, pose)
                for o in robot:
                    if float(fcl.distance(o, self._objects[i], _DISTANCE_REQUEST, fcl.DistanceResult())) <= 0.0:
                        return None
            kinds = kind[chunk]                      # separated: the plane distance, exactly
            sel = chunk[kinds == 1]
            if len(sel):
                best = min(best, float(_poly_distances(fp, pose, robot_v, polys[sel]).min()))
            sel = chunk[kinds == 2]
            if len(sel):
                best = min(best, float(_circle_distances(fp, pose, robot_v, circles[sel]).min()))
            for i in chunk[kinds == 0]:
                best = min(best, _exact_distance(fp, pose, self._outline[id(self._geoms[i])]))
            return None if best <= 0.0 else best

        if math.isfinite(upto):
            return measure(np.flatnonzero(lower <= upto))
        first = np.argpartition(lower, 7)[:8] if n > 8 else np.arange(n)
        best = measure(first)
        if best is None or n <= 8:
            return best
        rest = np.flatnonzero(lower < best)
        rest = rest[~np.isin(rest, first)]
        if len(rest):
            more = measure(rest)
            if more is None:
                return None
            best = min(best, more)
        return best

    #: _near_batch: poses per chunk, and the objects nearest a chunk's box each pose of it looks at
    NEAR_CHUNK, NEAR_OBJECTS = 32, 48

    def _near_batch(self, poses: np.ndarray, fp: Footprint, nearest: int = 4, local: bool = True) -> np.ndarray:
        """:meth:`_distance_near` at many poses (N, 3) at once, where it can be decided without FCL: the
        ``nearest`` objects of the smallest bounding-box lower bound are measured exactly in the plane
        (vertex to edge both ways, as :func:`_poly_distances` and :func:`_circle_distances`), and a pose
        is decided when each of them is apart from the footprint (its box does not meet the footprint's,
        or, both being convex, a separating axis shows them apart: :func:`_separated`; a pose in contact
        stays with FCL, which measures the penetration), none is a polygon of more than ``POLY_PAD``
        corners, and the smallest
        distance found is no more than the next object's lower bound (so no other object is nearer).
        Poses go in chunks of ``NEAR_CHUNK`` (8 times more in a world of few objects); in a world of many
        objects each chunk first keeps the
        ``NEAR_OBJECTS`` objects nearest the box of all its footprints, and the objects it drops count
        with the smallest box distance among them as their bound (poses that bound leaves undecided, as
        scattered poses do, are tried again against all the objects).
        Returns the distances, NaN where undecided (the caller asks :meth:`_distance_near`)."""
        all_boxes, polys, circles, kind = self._shape_tables()
        n_poses, n_all = len(poses), len(all_boxes)
        if not n_all:
            return np.full(n_poses, np.inf)
        out = np.full(n_poses, np.nan)
        disc = fp.radius is not None
        radius = fp.radius if disc else 0.0
        verts = None if disc else np.asarray(fp.vertices, dtype=float)
        convex = self.__dict__["_convex"]
        convex_fp = fp.convex
        local = local and n_all > 2 * self.NEAR_OBJECTS
        size = self.NEAR_CHUNK if local else 8 * self.NEAR_CHUNK     # few objects: larger chunks
        for a in range(0, n_poses, size):
            p = poses[a:a + size]
            m = len(p)
            if disc:                                            # the centres, the radius off every bound
                lo = hi = p[:, :2]
            else:                                               # the outline at each pose (m, V, 2)
                c, s = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
                rv = np.stack([p[:, 0:1] + c * verts[:, 0] - s * verts[:, 1],
                               p[:, 1:2] + s * verts[:, 0] + c * verts[:, 1]], axis=-1)
                lo, hi = rv.min(axis=1), rv.max(axis=1)
            ids, beyond = None, np.inf
            boxes = all_boxes
            if local:                                           # the objects near this chunk's footprints
                gap = _box_gaps(all_boxes, lo.min(axis=0), hi.max(axis=0)) - radius
                part = np.argpartition(gap, self.NEAR_OBJECTS)
                ids, beyond = part[:self.NEAR_OBJECTS], float(gap[part[self.NEAR_OBJECTS]])
                boxes = all_boxes[ids]
            n = len(boxes)
            k = min(nearest, n)
            lower = _box_gaps(boxes, lo, hi) - radius                  # (m, n)
            if k < n:
                part = np.argpartition(lower, k, axis=1)
                cand, nxt = part[:, :k], np.minimum(lower[np.arange(m), part[:, k]], beyond)
            else:
                cand, nxt = np.broadcast_to(np.arange(n), (m, n)), np.full(m, beyond)
            meets = np.take_along_axis(lower, cand, axis=1) <= 0.0
            if ids is not None:
                cand = ids[cand]
            # a box that meets the footprint's: decided here only if both shapes are convex (a separating
            # axis, below), else by FCL pose by pose
            ok = (kind[cand] != 0).all(axis=1) & ~(meets & ~(convex_fp & convex[cand])).any(axis=1)
            if not ok.any():
                continue
            rows = np.flatnonzero(ok)
            cand, nxt, meets = cand[rows], nxt[rows], meets[rows]
            quads = polys[cand]                                     # (r, k, corners, 2)
            edges = self.__dict__["_poly_edges"][cand]
            circ = circles[cand]                                    # (r, k, 3)
            round_ = bool((kind[cand] == 2).any())                  # any circle among them
            r = len(rows)
            d_circ = np.inf
            if disc:
                centre = p[rows, None, None, :2]
                d_poly = np.sqrt(_segment_gaps2(np.broadcast_to(centre, (r, k, 1, 2)), quads, edges)
                                 .min(axis=(2, 3))) - fp.radius
                if round_:
                    d_circ = np.hypot(circ[..., 0] - centre[:, :, 0, 0], circ[..., 1] - centre[:, :, 0, 1]) \
                        - circ[..., 2] - fp.radius
            else:
                v = rv[rows]                                        # (r, V, 2)
                r_edges = np.roll(v, -1, axis=1) - v
                vb = np.broadcast_to(v[:, None], (r, k) + v.shape[1:])
                eb = np.broadcast_to(r_edges[:, None], (r, k) + v.shape[1:])
                one = _segment_gaps2(vb, quads, edges).min(axis=(2, 3))
                two = _segment_gaps2(quads, vb, eb).min(axis=(2, 3))
                d_poly = np.sqrt(np.minimum(one, two))
                if round_:
                    d_circ = np.sqrt(_segment_gaps2(circ[..., None, :2], vb, eb).min(axis=(2, 3))) - circ[..., 2]
            sel = np.flatnonzero(meets.any(axis=1))
            if len(sel):                    # separated, for the pairs whose boxes meet?
                apart = np.ones(meets.shape, dtype=bool)
                apart[sel] = _separated((p[rows, :2] if disc else v)[sel], fp.radius, quads[sel], edges[sel],
                                        circ[sel], kind[cand[sel]] == 1)
                d_poly = np.where(meets & ~apart, -np.inf, d_poly)
                if round_:
                    d_circ = np.where(meets & ~apart, -np.inf, d_circ)
            d = (np.where(kind[cand] == 1, d_poly, d_circ) if round_ else d_poly).min(axis=1)
            good = (d > 0.0) & (d <= nxt)
            out[a + rows[good]] = d[good]
            again = rows[(d > nxt) & (nxt >= beyond)] if ids is not None else ()
            if len(again):                  # the chunk's objects were too few for these poses
                out[a + again] = self._near_batch(p[again], fp, nearest, local=False)
        return out

    def _box_bounds(self, poses: np.ndarray, fp: Footprint) -> np.ndarray:
        """Lower bounds of the clearance at poses (N, 3), 0 where they say nothing: for each object the
        gap between its bounding box and the footprint's, the larger of two (each shape lies inside its
        box, so neither gap exceeds their distance): in the world's axes (the box of the footprint at the
        pose; a disc's centre, less its radius) and, for a polygon, in the robot's (its box in its own
        frame against the object's box turned into that frame); then the smallest over the objects. For a
        disc among axis-aligned boxes (a grid's cells) the bound is the clearance, and for a polygon
        parallel or square to its nearest boxes nearly so. In a world of many objects, poses go in chunks
        of ``NEAR_CHUNK``, each against the ``NEAR_OBJECTS`` objects nearest the world box of all its
        footprints, the others bounded together by the nearest of them to that box (and a pose that bound
        holds down, as a chunk of scattered poses does, against all the objects). Lowered by ``BOX_GUARD``."""
        boxes = self._shape_tables()[0]
        n_poses, n_all = len(poses), len(boxes)
        if not n_all:
            return np.full(n_poses, np.inf)
        disc = fp.radius is not None
        # (objects, poses) arrays: the operations run along the poses
        px, py = poses[:, 0], poses[:, 1]
        if disc:
            lox = hix = px
            loy = hiy = py
        else:
            verts = np.asarray(fp.vertices, dtype=float)
            own_lo, own_hi = verts.min(axis=0), verts.max(axis=0)
            c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
            vx, vy = verts[:, 0:1], verts[:, 1:2]
            x = px + c * vx - s * vy                                   # (corners, poses)
            y = py + s * vx + c * vy
            lox, hix, loy, hiy = x.min(axis=0), x.max(axis=0), y.min(axis=0), y.max(axis=0)
        centre, half = 0.5 * (boxes[:, :2] + boxes[:, 2:]), 0.5 * (boxes[:, 2:] - boxes[:, :2])

        def gaps2(ids, rows):                     # (objects, rows) squared gaps, the larger of the two
            bx = boxes if ids is None else boxes[ids]
            dx = np.maximum(np.maximum(bx[:, 0:1] - hix[rows], lox[rows] - bx[:, 2:3]), 0.0)
            dy = np.maximum(np.maximum(bx[:, 1:2] - hiy[rows], loy[rows] - bx[:, 3:4]), 0.0)
            dx *= dx
            dy *= dy
            g = np.add(dx, dy, out=dx)
            if not disc:
                ce, ha = (centre, half) if ids is None else (centre[ids], half[ids])
                cc, ss = c[rows], s[rows]
                rx, ry = ce[:, 0:1] - px[rows], ce[:, 1:2] - py[rows]
                ac, as_ = np.abs(cc), np.abs(ss)
                hx, hy = ha[:, 0:1], ha[:, 1:2]
                ex, ey = ac * hx + as_ * hy, as_ * hx + ac * hy
                qx, qy = cc * rx + ss * ry, cc * ry - ss * rx            # the box's centre in the robot's frame
                dx = np.maximum(np.maximum(qx - ex - own_hi[0], own_lo[0] - ex - qx), 0.0)
                dy = np.maximum(np.maximum(qy - ey - own_hi[1], own_lo[1] - ey - qy), 0.0)
                dx *= dx
                dy *= dy
                dx += dy
                np.maximum(g, dx, out=g)
            return g

        if n_all <= 2 * self.NEAR_OBJECTS:
            out = gaps2(None, slice(None)).min(axis=0)
        else:
            out = np.empty(n_poses)
            for a in range(0, n_poses, self.NEAR_CHUNK):
                rows = np.arange(a, min(a + self.NEAR_CHUNK, n_poses))
                gap = _box_gaps(boxes, [lox[rows].min(), loy[rows].min()], [hix[rows].max(), hiy[rows].max()])
                part = np.argpartition(gap, self.NEAR_OBJECTS)
                near, beyond = gaps2(part[:self.NEAR_OBJECTS], rows).min(axis=0), gap[part[self.NEAR_OBJECTS]] ** 2
                again = rows[near > beyond]     # the chunk's objects were too few for these (scattered) poses
                out[rows] = np.minimum(near, beyond)
                if len(again):
                    out[again] = gaps2(None, again).min(axis=0)
        np.sqrt(out, out=out)
        out -= (0.0 if fp.radius is None else fp.radius) + self.BOX_GUARD
        return np.maximum(out, 0.0, out=out)

    def _shape_tables(self):
        """The obstacle objects (in the order of ``_objects``) as arrays for :meth:`_distance_near`:
        (n, 4) bounding boxes (xmin, ymin, xmax, ymax); (n, c, 2) vertices of the polygons of at most
        POLY_PAD corners, c the most any has (repeating the last one: a zero-length edge changes no distance); (n, 3)
        circles (centre, radius); and the (n,) kind of each object (1 such a polygon, 2 a circle, 0 another
        polygon, measured one at a time)."""
        table = self.__dict__.get("_tables")
        if table is None:
            n = len(self._geoms)
            boxes, polys, circles = np.empty((n, 4)), np.zeros((n, POLY_PAD, 2)), np.zeros((n, 3))
            kind = np.zeros(n, dtype=np.int8)
            for i, geom in enumerate(self._geoms):
                outline = self._outline[id(geom)]
                if outline[0] == "circle":
                    (cx, cy), r = outline[1], float(outline[2])
                    boxes[i], circles[i], kind[i] = (cx - r, cy - r, cx + r, cy + r), (cx, cy, r), 2
                    continue
                v = np.asarray(outline[1], dtype=float)
                boxes[i] = (*v.min(axis=0), *v.max(axis=0))
                if len(v) <= POLY_PAD:
                    polys[i, :len(v)], polys[i, len(v):], kind[i] = v, v[-1], 1
            corners = max((len(self._outline[id(g)][1]) for g, k in zip(self._geoms, kind) if k == 1), default=1)
            polys = np.ascontiguousarray(polys[:, :corners])     # as many columns as the largest needs
            table = self.__dict__["_tables"] = (boxes, polys, circles, kind)
            # each polygon's edges (the padded corners' edges have zero length)
            d1 = self.__dict__["_poly_edges"] = np.roll(polys, -1, axis=1) - polys
            # which objects are convex (circles, and the polygons of convex outline): _near_batch
            # tells them apart from a footprint whose box they meet by a separating axis
            d2 = np.roll(d1, -1, axis=1)
            turn = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]   # zero at the padding
            tol = 1e-12 * np.maximum(1.0, np.abs(polys).max(axis=(1, 2))) ** 2
            self.__dict__["_convex"] = (kind == 2) | ((kind == 1) & (np.all(turn >= -tol[:, None], axis=1)
                                                                     | np.all(turn <= tol[:, None], axis=1)))
        return table

    def clearance(self, pose, fp: Footprint) -> float:
        """Signed clearance: the distance to the nearest obstacle, or minus the deepest penetration."""
        return self._clearance(_pose(pose), fp)

    def _clearance(self, pose, fp: Footprint) -> float:
        near = self._distance_near(pose, fp)
        if near is not None:
            return near
        if not self._in_collision(pose, fp):          # touching
            return 0.0
        deepest = 0.0
        for o in self._robot(fp, pose):
            data = fcl.CollisionData(request=fcl.CollisionRequest(num_max_contacts=100_000, enable_contact=True))
            self.manager.collide(o, data, fcl.defaultCollisionCallback)
            for contact in data.result.contacts:
                outline = self._outline.get(id(contact.o1)) or self._outline.get(id(contact.o2))
                if outline is not None and outline[0] == "poly" and len(outline[1]) == 2:
                    # a segment of zero thickness: EPA's depth for a flat prism is unreliable (it was off
                    # by metres), the plane's is exact
                    deepest = max(deepest, segment_depth(fp, pose, outline[1]))
                else:
                    deepest = max(deepest, float(contact.penetration_depth))
        return -deepest

    def hits(self, pose, fp: Footprint) -> list[dict]:
        """The obstacles the footprint at ``pose`` overlaps, deepest first, as FCL's contacts name them.

        Each is a dict: ``id`` (text: ``obstacles[3]``, ``unknown_obstacles[0]``, the grid cells
        ``grid[0] cells (row, col), ...`` or ``map bounds (left)``), ``source`` ("obstacles",
        "unknown_obstacles", "added", "shapes", "grid" or "bounds") with ``index`` (the shape's index in
        that list), ``grid`` and ``cells`` (every occupied cell [row, col] the footprint overlaps) or
        ``side``, and ``clearance_m``: minus the penetration depth (a segment's exactly in the plane, as
        :meth:`clearance` measures it). Empty when the pose is free."""
        pose = _pose(pose)
        deepest: dict = {}                       # source -> depth
        for o in self._robot(fp, pose):
            data = fcl.CollisionData(request=fcl.CollisionRequest(num_max_contacts=100_000, enable_contact=True))
            self.manager.collide(o, data, fcl.defaultCollisionCallback)
            for contact in data.result.contacts:
                geom = contact.o1 if id(contact.o1) in self._source else contact.o2
                source, outline = self._source.get(id(geom)), self._outline.get(id(geom))
                if source is None:
                    continue
                if outline[0] == "poly" and len(outline[1]) == 2:
                    # a segment: its depth exactly in the plane; FCL's default solver (libccd) also
                    # reports contacts with flat prisms a few centimetres apart, and those are no hit
                    depth = segment_depth(fp, pose, outline[1])
                    if depth <= 0.0:
                        continue
                else:
                    depth = float(contact.penetration_depth)
                deepest[source] = max(deepest.get(source, 0.0), depth)
        out: dict = {}
        for source, depth in deepest.items():
            if source[0] == "shape":
                name, k = self.names[source[1]]
                key = (name, k)
                hit = {"id": f"{name}[{k}]", "source": name, "index": int(k)}
            elif source[0] == "grid":
                key = ("grid", source[1])
                hit = out.get(key) or {"source": "grid", "grid": int(source[1]), "cells": []}
                hit["cells"] += self._cells_hit(pose, fp, source[1], source[2])
            else:
                key = source
                hit = {"id": f"map bounds ({source[1]})", "source": "bounds", "side": source[1]}
            hit["clearance_m"] = min(hit.get("clearance_m", 0.0), -float(depth))
            out[key] = hit
        for hit in out.values():
            if hit["source"] == "grid":
                hit["cells"] = sorted(hit["cells"])
                listed = ", ".join(f"({i}, {j})" for i, j in hit["cells"][:4])
                more = f" and {len(hit['cells']) - 4} more" if len(hit["cells"]) > 4 else ""
                hit["id"] = f"grid[{hit['grid']}] cell{'s' if len(hit['cells']) != 1 else ''} {listed}{more}"
        return sorted(out.values(), key=lambda h: h["clearance_m"])

    def _cells_hit(self, pose, fp: Footprint, g: int, rect) -> list[list[int]]:
        """The cells [row, col] of the merged rectangle ``rect`` = (i0, j0, i1, j1) of grid ``g`` that the
        footprint at ``pose`` overlaps (FCL, a box per cell near the footprint)."""
        grid = self.grids[g]
        i0, j0, i1, j1 = rect
        ox, oy, yaw = grid.origin
        r = grid.resolution
        c, s = math.cos(yaw), math.sin(yaw)
        reach = fp.bounding_radius
        u, v = c * (pose[0] - ox) + s * (pose[1] - oy), -s * (pose[0] - ox) + c * (pose[1] - oy)  # grid frame
        rows = range(max(i0, math.floor((v - reach) / r)), min(i1, math.floor((v + reach) / r) + 1))
        cols = range(max(j0, math.floor((u - reach) / r)), min(j1, math.floor((u + reach) / r) + 1))
        robot = self._robot(fp, pose)
        cells = []
        for i in rows:
            for j in cols:
                cu, cv = (j + 0.5) * r, (i + 0.5) * r
                cell = _object(fcl.Box(r, r, 2 * _Z), ox + c * cu - s * cv, oy + s * cu + c * cv, yaw)
                if any(fcl.collide(o, cell, _COLLIDE_REQUEST, fcl.CollisionResult()) for o in robot):
                    cells.append([int(i), int(j)])
        return cells

    def is_free(self, pose, fp: Footprint, margin: float = 0.0) -> bool:
        """No obstacle within ``margin`` of the footprint (margin 0: no overlap).

        With a margin, two inflated copies of the footprint decide most poses with intersection tests
        alone: the *outer* one (edges pushed out by the margin, mitred corners) contains the footprint
        grown by the margin, so if it touches nothing the pose is free; the *inner* one (chamfered
        corners: points of the rounded outline) lies inside it, so if it touches something the pose
        is not. Only poses between the two are measured (``_within``). The outer copy goes first: it
        contains the footprint, so a pose it clears is free without testing the footprint itself.
        """
        return self._is_free(_pose(pose), fp, margin)

    def _is_free(self, pose, fp: Footprint, margin: float = 0.0) -> bool:
        if margin <= 0.0:
            return not self._in_collision(pose, fp)
        outer, inner = self._inflated(fp, margin)
        if not self._collides(outer, pose):
            return True
        if self._collides(inner, pose) or self._in_collision(pose, fp):
            return False
        return not self._within(pose, fp, margin)

    def _inflated(self, fp: Footprint, margin: float):
        key = (id(fp), float(margin))
        cache = getattr(self, "_inflated_cache", None)
        if cache is None or cache[0] != key:
            if fp.radius is not None:
                band = max(1e-4, 1e-6 * fp.radius)          # GJK's tolerance on curved shapes
                outer = [_object(fcl.Cylinder(fp.radius + margin + band, 2 * _Z))]
                inner = [_object(fcl.Cylinder(fp.radius + margin - band, 2 * _Z))]
            else:
                outer, inner = [], []
                for part in convex_parts(fp.vertices):
                    o, i = _offset_convex(part, margin)
                    outer.append(_object(_prism(o)))
                    inner.append(_object(_prism(i)))
            self._inflated_cache = (key, (outer, inner), fp)
        return self._inflated_cache[1]

    def _collides(self, objs, pose) -> bool:
        half = 0.5 * float(pose[2])
        tf = fcl.Transform(np.array([math.cos(half), 0.0, 0.0, math.sin(half)]),
                           np.array([float(pose[0]), float(pose[1]), 0.0]))
        for o in objs:
            o.setTransform(tf)
        return self._any_contact(objs)

    def _within(self, pose, fp: Footprint, margin: float) -> bool:
        """Is some obstacle within ``margin`` of the footprint (which overlaps none)? The exact plane
        distance to the objects whose boxes are within ``margin`` of the footprint's
        (:meth:`_measure_near`). FCL's distance is not used: for a car's prism its GJK value was off by
        up to 0.95 m on grid maps."""
        d = self._measure_near(pose, fp, margin)
        return d is None or d <= margin

    def state_checker(self, fp: Footprint, margin: float = 0.0):
        """A fast scalar ``check(x, y, theta) -> bool`` equal to ``is_free`` (for planners that call
        Python once per state): the distance-field prefilter in plain Python, then FCL."""
        field = self.clearance_field()
        if field is None:
            return lambda x, y, th: self._is_free((x, y, th), fp, margin)
        # plain Python floats and ints throughout (numpy scalars are several times slower here)
        def discs_of(cover):
            return [(float(u), float(v), float(rad + margin)) for (u, v), rad in zip(*cover)]

        discs = discs_of(disc_cover(fp))
        fine = discs_of(disc_cover(fp, FINE_DISCS_PER_WIDTH)) if fp.radius is None else []
        pts = [(float(u), float(v)) for u, v in footprint_points(fp, None)]
        lower, inside = field.lower_bound, field.inside
        rows, cols = lower.shape
        x0, y0, r = float(field.x0), float(field.y0), float(field.r)

        def check(x: float, y: float, th: float) -> bool:
            c, s = math.cos(th), math.sin(th)
            for u, v, need in discs:               # every covering disc provably clear: free
                j = int((x + c * u - s * v - x0) // r)
                i = int((y + s * u + c * v - y0) // r)
                if not (0 <= i < rows and 0 <= j < cols) or lower[i, j] <= need:
                    break
            else:
                return True
            for u, v, need in fine:                # near something: the finer cover, before FCL
                j = int((x + c * u - s * v - x0) // r)
                i = int((y + s * u + c * v - y0) // r)
                if not (0 <= i < rows and 0 <= j < cols) or lower[i, j] <= need:
                    break
            else:
                if fine:
                    return True
            for u, v in pts:                       # a footprint point certainly inside an obstacle
                j = int((x + c * u - s * v - x0) // r)
                i = int((y + s * u + c * v - y0) // r)
                if 0 <= i < rows and 0 <= j < cols and inside[i, j]:
                    return False
            return self._is_free((x, y, th), fp, margin)

        return check

    def free_many(self, poses, fp: Footprint, margin: float = 0.0) -> np.ndarray:
        """``is_free`` for many poses (N, 3), with the same answers, faster.

        A conservative distance field (see :class:`~nhstab.clearance_field.ClearanceField`) first accepts, without FCL, the
        poses where every disc of a cover of the footprint is provably farther than ``margin`` from
        every obstacle; of the rest, when there are at least ``BATCH_FROM``, exact plane distances
        measured in one batch (:meth:`_near_batch`) decide those clear of contact; FCL decides the
        others. Along a path (the next such pose within
        ``VOUCH_NEAR`` m of footprint displacement) a pose FCL finds free also has its clearance c
        measured: a later pose is free too while no point of the footprint has moved more than
        c - margin - ``VOUCH_GAP`` from it (|translation| + reach |rotation|, reach = the farthest
        footprint point from the reference point), as clearance changes no faster than that.
        """
        poses = _poses(poses)
        out = np.zeros(len(poses), dtype=bool)
        field = self.clearance_field()
        if field is None:
            return np.array([self._is_free(p, fp, margin) for p in poses], dtype=bool)
        sure = field.surely_free(poses, fp, margin)
        out[sure] = True
        undecided = np.flatnonzero(~sure)
        undecided = undecided[~field.surely_colliding(poses[undecided], fp)]
        if len(undecided):
            # a finer look at the rest: the footprint's whole outline, sampled every half cell
            hit = field.surely_colliding(poses[undecided], fp, spacing=field.r / 2)
            undecided = undecided[~hit]
        if len(undecided) >= self.BATCH_FROM and _along_a_path(poses[undecided]):
            d = self._near_batch(poses[undecided], fp)          # exact distances where they decide, at once
            known = ~np.isnan(d)
            out[undecided[known]] = d[known] > margin
            undecided = undecided[~known]
        reach = fp.radius if fp.radius is not None else float(np.hypot(*fp.vertices.T).max())
        held = None                 # (a pose found free, how far the footprint may move from it and stay free)
        for n, k in enumerate(undecided):
            p = poses[k]
            if held is not None and _moved(held[0], p, reach) < held[1]:
                out[k] = True
                continue
            out[k] = self._is_free(p, fp, margin)
            held = None
            if out[k] and n + 1 < len(undecided) and _moved(p, poses[undecided[n + 1]], reach) < self.VOUCH_NEAR:
                held = (p, self._distance(p, fp) - margin - self.VOUCH_GAP)
        return out

    def motion_free(self, poses, fp: Footprint, margin: float = 0.0, stats: dict | None = None) -> bool:
        """Are all poses (N, 3) of a motion free (``is_free``)? The same answer as ``free_many(...).all()``,
        sooner: the distance field decides the poses it can, vectorised; a pose it finds certainly
        colliding ends the check; a batch of exact distances decides most of the rest (as in
        ``free_many``); FCL decides the others in order (with ``free_many``'s vouching along the
        path) and stops at the first pose that is not free. ``stats`` (if given) accumulates "states",
        "fcl_states" (poses that reached FCL) and "time_s"."""
        started = time.perf_counter()
        poses = _poses(poses)
        fcl_calls = 0
        try:
            field = self.clearance_field()
            if field is None:
                fcl_calls = len(poses)
                return all(self._is_free(p, fp, margin) for p in poses)
            sure = field.surely_free(poses, fp, margin)
            if sure.all():
                return True
            undecided = np.flatnonzero(~sure)
            pts = poses[undecided]
            if field.surely_colliding(pts, fp).any() or field.surely_colliding(pts, fp, spacing=field.r / 2).any():
                return False
            if len(undecided) >= self.BATCH_FROM and _along_a_path(poses[undecided]):
                d = self._near_batch(poses[undecided], fp)      # exact distances where they decide, at once
                known = ~np.isnan(d)
                if np.any(d[known] <= margin):
                    return False
                undecided = undecided[~known]
            reach = fp.radius if fp.radius is not None else float(np.hypot(*fp.vertices.T).max())
            held = None
            for n, k in enumerate(undecided):
                p = poses[k]
                if held is not None and _moved(held[0], p, reach) < held[1]:
                    continue
                fcl_calls += 1
                if not self._is_free(p, fp, margin):
                    return False
                held = None
                if n + 1 < len(undecided) and _moved(p, poses[undecided[n + 1]], reach) < self.VOUCH_NEAR:
                    held = (p, self._distance(p, fp) - margin - self.VOUCH_GAP)
            return True
        finally:
            if stats is not None:
                stats["states"] = stats.get("states", 0) + len(poses)
                stats["fcl_states"] = stats.get("fcl_states", 0) + fcl_calls
                stats["time_s"] = stats.get("time_s", 0.0) + time.perf_counter() - started

    def clearance_field(self) -> "ClearanceField | None":
        """The lazily built conservative distance field of this world's obstacles (None if unbounded)."""
        if getattr(self, "_field", None) is None and self.bounds is not None:
            self._field = ClearanceField(self.bounds, [g.resolution for g in self.grids], list(self._outline.values()))
        return getattr(self, "_field", None)

    def clearance_many(self, poses, fp: Footprint) -> np.ndarray:
        """``clearance`` at each of ``poses`` (N, 3): decided in batches where it can be
        (:meth:`_near_batch`), pose by pose elsewhere (near contact, or many objects equally near)."""
        return self._clearances(_poses(poses), fp)

    def _clearances(self, poses: np.ndarray, fp: Footprint) -> np.ndarray:
        c = self._near_batch(poses, fp)
        for i in np.flatnonzero(np.isnan(c)):
            c[i] = self._clearance(poses[i], fp)
        return c

    def min_clearance(self, poses, fp: Footprint) -> tuple[float, int]:
        """The smallest signed clearance over poses (N, 3) and its (first) index, exactly, without
        measuring every pose (:meth:`min_clearance_less`)."""
        best, k, _, _ = self.min_clearance_less(_poses(poses, at_least=1), fp)
        return best, k

    def min_clearance_less(self, poses: np.ndarray, fp: Footprint, offset: np.ndarray | None = None):
        """min_k [clearance(fp at poses[k]) - offset[k]] (offset 0 by default) exactly, with its first
        index, the clearance there and the number of poses measured, without measuring every pose.

        A branch and bound on lower bounds of clearance - offset. The first bound, of every pose: the
        footprint covered by discs (a polygon's fine cover), from the distance field. In increasing order
        of it, in two rounds (the ``FIRST_BATCH`` lowest, then all others it leaves at or below the best
        value found), the poses get the tighter bound of the objects' boxes (:meth:`_box_bounds`), and are
        measured (:meth:`_clearances`) in increasing order of that where it does not exceed the best value:
        in the first round the lowest alone, then the rest in one batch. A measured clearance c > 0 also
        bounds the poses up to ``VOUCH_SPAN`` either side by c - ``VOUCH_GAP`` - how far the footprint
        moved (|translation| + rho |rotation|, rho the farthest footprint point, 0 for a disc, which does
        not move when it turns). Nothing bounds a penetration depth, so a pose whose bounds are not
        positive is always measured."""
        poses = _poses(poses)
        n = len(poses)
        off = np.zeros(n) if offset is None else np.asarray(offset, dtype=float)
        if off.shape != (n,) or not np.all(np.isfinite(off)):
            raise InputError("offset", f"one finite number per pose ({n})",
                             offset if off.size <= 6 else f"an array of shape {off.shape}")
        if not n:
            return math.inf, -1, math.nan, 0
        field = self.clearance_field()
        if field is None:
            c = self._clearances(poses, fp)
            k = int(np.argmin(c - off))
            return float(c[k] - off[k]), k, float(c[k]), n
        # a polygon's fine cover (discs overhanging its sides by a few cm): for a car it leaves about a
        # sixth of the poses the coarse cover leaves below the best value, at twice its cost
        bound = field.cover_bound(poses, disc_cover(fp) if fp.radius is not None else disc_cover(fp, FINE_DISCS_PER_WIDTH))
        key = np.where(bound > 0.0, bound - off, -np.inf)
        vouched = np.full(n, -np.inf)
        span, rho = self.VOUCH_SPAN, 0.0 if fp.radius is not None else fp.bounding_radius
        best, best_k, best_c, evals = math.inf, -1, math.nan, 0
        # round 1: the FIRST_BATCH lowest keys; round 2: all other keys at or below the best found
        first = np.sort(np.argpartition(key, self.FIRST_BATCH)[:self.FIRST_BATCH]) if n > self.FIRST_BATCH \
            else np.arange(n)

        def live(ks, kb):                   # the poses whose bounds may still beat the best (ties included)
            return ks[(kb <= best) & ~((vouched[ks] > 0.0) & (vouched[ks] - off[ks] > best))]

        for round_ in (1, 2):
            if round_ == 1:
                chunk = first
            else:
                rest = key <= best
                rest[first] = False
                chunk = np.flatnonzero(rest)
            chunk = live(chunk, key[chunk])             # in path order: neighbours share their nearest objects
            if not len(chunk):
                continue
            # the objects' bounding boxes bound these poses more tightly than the field (a disc's clearance
            # among boxes exactly): measured in increasing order of the tighter bound, the lowest first when
            # nothing is measured yet, so that it sets the value the others must beat
            gap = self._box_bounds(poses[chunk], fp)
            kb = np.where(gap > 0.0, np.maximum(key[chunk], gap - off[chunk]), key[chunk])
            sub = np.argsort(kb, kind="stable")
            chunk, kb = chunk[sub], kb[sub]
            alone = 1 if best_k < 0 else 0
            for part, part_kb in ((chunk[:alone], kb[:alone]), (chunk[alone:], kb[alone:])):
                part = live(part, part_kb)
                if not len(part):
                    continue
                c = self._clearances(poses[part], fp)
                evals += len(part)
                g = c - off[part]
                gm = float(g.min())
                if gm <= best:              # the first index among the smallest values
                    j = int(np.flatnonzero(g == gm)[np.argmin(part[g == gm])])
                    if gm < best or part[j] < best_k:
                        best, best_k, best_c = gm, int(part[j]), float(c[j])
                pos_ = c > 0.0
                if pos_.any():              # each measured c > 0 bounds its neighbours (all at once)
                    ks = part[pos_]
                    near = np.clip(ks[:, None] + np.arange(-span, span + 1), 0, n - 1)
                    d = poses[near] - poses[ks][:, None]
                    np.maximum.at(vouched, near, c[pos_][:, None] - self.VOUCH_GAP - np.hypot(d[..., 0], d[..., 1])
                                  - rho * np.abs(d[..., 2]))
        if best_k < 0:                      # no obstacle anywhere: every clearance is infinite
            best_k, best_c = int(np.argmin(key)), math.inf
        return best, best_k, best_c, evals

    def check_path(self, poses, fp: Footprint, margin: float = 0.0, resolution: float = 0.05,
                   angular_resolution: float = 0.05) -> PathCheck:
        """Check a path of poses (N, 3), interpolated so that consecutive samples are at most
        ``resolution`` m and ``angular_resolution`` rad apart (linear in x, y; shortest turn in theta)."""
        poses = _poses(poses, at_least=1)
        if not (resolution > 0 and angular_resolution > 0):
            raise InputError("resolution", "positive", (resolution, angular_resolution))
        samples, segment = interpolate_poses(poses, resolution, angular_resolution)
        free = self.free_many(samples, fp, margin)
        best, k_min = self.min_clearance(samples, fp)
        first = int(np.argmin(free)) if not free.all() else None
        return PathCheck(
            clear=first is None, margin=margin, samples=len(samples),
            first_conflict_index=first, first_conflict_pose=None if first is None else samples[first],
            first_conflict_segment=None if first is None else int(segment[first]),
            min_clearance=best, min_clearance_index=k_min, min_clearance_pose=samples[k_min],
            poses=samples, free=free)


_COLLIDE_REQUEST = fcl.CollisionRequest()
_DISTANCE_REQUEST = fcl.DistanceRequest()


def _check_world_size(n: int) -> None:
    if n > MAX_WORLD_OBJECTS:
        raise InputError("map", f"obstacles that make at most {MAX_WORLD_OBJECTS:,} collision objects (convex parts "
                         "and merged rectangles of occupied cells)", f"{n:,}",
                         detail="a grid this fragmented is mostly isolated noise cells: clean or coarsen it")


def _along_a_path(poses: np.ndarray, step: float = 0.5) -> bool:
    """Do consecutive poses lie close together (median step at most ``step`` m), as samples of a path
    do? The batched distances gather the obstacles near chunks of consecutive poses; for scattered poses
    (random checks) they cost more than FCL pose by pose."""
    d = np.diff(poses[:, :2], axis=0)
    return bool(len(d)) and float(np.median(np.hypot(d[:, 0], d[:, 1]))) <= step


def _moved(a, b, reach: float) -> float:
    """An upper bound of how far any point of a footprint within ``reach`` of its reference point
    moves from pose a to pose b."""
    return math.hypot(b[0] - a[0], b[1] - a[1]) + reach * abs(b[2] - a[2])


def _first_contact(o1, o2, data) -> bool:
    """Broad-phase callback: narrow-phase test of one candidate pair, stop at the first contact
    (fcl.defaultCollisionCallback does the same with more bookkeeping per pair)."""
    if fcl.collide(o1, o2, _COLLIDE_REQUEST, data.result):
        data.done = True
    return data.done


#: a Ctrl-C kept for later by :func:`defer_interrupt`, raised when FCL returns
_PENDING_INTERRUPT = [False]


def defer_interrupt(frame) -> bool:
    """For a SIGINT handler, with the frame the signal interrupts: True when that frame is the
    broad-phase callback FCL calls from Cython, which would print a KeyboardInterrupt raised there
    ("Exception ignored in: 'fcl.fcl.CollisionCallBack'") and drop it, so that the query went on as if
    nothing had been pressed (also when the signal lands in Python code FCL calls from the callback, as
    the contacts it builds). The interrupt is then kept, and the query raises KeyboardInterrupt once FCL
    returns (a few microseconds later: the broad phase of one pose). ``nhstab``'s commands install such a handler."""
    code = _first_contact.__code__
    while frame is not None:
        if frame.f_code is code:
            _PENDING_INTERRUPT[0] = True
            return True
        frame = frame.f_back
    return False


def _raise_pending_interrupt() -> None:
    _PENDING_INTERRUPT[0] = False
    raise KeyboardInterrupt


def _offset_convex(v: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray]:
    """A convex counter-clockwise polygon grown by d: (outer, inner) polygons with
    inner <= polygon (+) disc(d) <= outer. Outer: edges moved out by d, corners mitred. Inner: each
    corner replaced by its two points moved out along the adjacent edges' normals (on the rounded
    outline, so their convex hull lies inside the grown polygon). numpy rather than shapely's mitred and
    bevelled buffers, which are slower on a footprint's few corners (``nhstab bench geometry``) and
    start their rings elsewhere (the FCL prisms are built from this order)."""
    e = np.roll(v, -1, axis=0) - v
    n = np.column_stack([e[:, 1], -e[:, 0]]) / np.hypot(e[:, 0], e[:, 1])[:, None]   # outward (CCW polygon)
    n_prev = np.roll(n, 1, axis=0)
    miter = (n_prev + n) / (1.0 + np.einsum("ij,ij->i", n_prev, n))[:, None]
    outer = v + d * miter
    inner = np.empty((2 * len(v), 2))
    inner[0::2] = v + d * n_prev
    inner[1::2] = v + d * n
    return outer, inner


def _box(cx, cy, lx, ly, yaw) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    half = np.array([[-lx, -ly], [lx, -ly], [lx, ly], [-lx, ly]]) / 2
    return half @ np.array([[c, -s], [s, c]]).T + [cx, cy]


def _exact_distance(fp: Footprint, pose, outline) -> float:
    """Exact plane distance between the footprint at pose and one obstacle outline (a polygon of more
    than ``POLY_PAD`` corners, or a circle), by GEOS (shapely) for polygons: FCL's GJK is not used (its
    tolerance on curved shapes is ~1e-5 m, and it erred on car prisms)."""
    if fp.radius is not None:
        centre = np.asarray(pose[:2], dtype=float)
        if outline[0] == "circle":
            return float(np.hypot(*(centre - outline[1])) - outline[2] - fp.radius)
        return point_polygon_distance(centre, outline[1]) - fp.radius
    robot = transform_points(fp.vertices, pose)
    if outline[0] == "circle":                  # polygon footprint, circle obstacle
        return point_polygon_distance(outline[1], robot) - outline[2]
    return polygon_distance(robot, np.asarray(outline[1], dtype=float))


def segment_depth(fp: Footprint, pose, seg) -> float:
    """The penetration depth of a segment (2, 2) into the footprint at ``pose``, exactly in the plane:
    the shortest translation that separates them (0 when they are apart). A disc: its radius less the
    distance from its centre to the segment. A polygon: per convex part, the smallest overlap of the two
    along the separating-axis candidates (the part's edge normals and the segment's normal), the
    largest over the parts."""
    seg = np.asarray(seg, dtype=float)
    if fp.radius is not None:
        c = np.asarray(pose[:2], dtype=float)
        d = math.sqrt(float(_segment_gaps2(c[None], seg[:1], (seg[1] - seg[0])[None]).min()))
        return max(0.0, fp.radius - d)
    deepest = 0.0
    e = seg[1] - seg[0]
    for part in convex_parts(fp.vertices):
        w = transform_points(part, pose)
        edges = np.roll(w, -1, axis=0) - w
        axes = np.vstack([np.column_stack([edges[:, 1], -edges[:, 0]]), [[e[1], -e[0]]]])
        axes = axes[np.hypot(axes[:, 0], axes[:, 1]) > 0]
        axes /= np.hypot(axes[:, 0], axes[:, 1])[:, None]
        pw, ps = w @ axes.T, seg @ axes.T
        overlap = np.minimum(pw.max(axis=0) - ps.min(axis=0), ps.max(axis=0) - pw.min(axis=0))
        deepest = max(deepest, float(max(0.0, overlap.min())))
    return deepest


def _segment_gaps2(points: np.ndarray, starts: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Squared distances from points (..., p, 2) to segments start + [0, 1] edge (..., e, 2): (..., p, e)."""
    rx = points[..., :, None, 0] - starts[..., None, :, 0]
    ry = points[..., :, None, 1] - starts[..., None, :, 1]
    ex, ey = edges[..., None, :, 0], edges[..., None, :, 1]
    t = np.clip((rx * ex + ry * ey) / np.maximum(ex * ex + ey * ey, 1e-300), 0.0, 1.0)
    gx, gy = rx - t * ex, ry - t * ey
    return gx * gx + gy * gy


def _box_gaps(boxes: np.ndarray, lo, hi) -> np.ndarray:
    """Distances between the boxes (n, 4: xmin, ymin, xmax, ymax) and the box [lo, hi] (corners (2,), or
    (m, 2) for m boxes: then (m, n)); 0 where they meet. With lo = hi, a point's distance to each box."""
    lo, hi = np.asarray(lo, dtype=float)[..., None, :], np.asarray(hi, dtype=float)[..., None, :]
    dx = np.maximum(np.maximum(boxes[:, 0] - hi[..., 0], lo[..., 0] - boxes[:, 2]), 0.0)
    dy = np.maximum(np.maximum(boxes[:, 1] - hi[..., 1], lo[..., 1] - boxes[:, 3]), 0.0)
    return np.hypot(dx, dy)


def _separated(robot, radius, quads, edges, circles, is_poly) -> np.ndarray:
    """(r, k): is each convex obstacle (quads (r, k, c, 2) with their edges, or circles (r, k, 3), as
    ``is_poly`` says) apart from the convex footprint of its row (a polygon ``robot`` (r, V, 2), or a disc
    of ``radius`` about the points ``robot`` (r, 2))? Polygons: a separating axis among the edge normals
    of both (padding edges of zero length give no axis). A disc or circle: its centre outside the
    polygon and farther than the radius from its edges (or the two circles apart)."""
    if radius is not None:                                    # a disc footprint
        c = robot[:, None, None, :]                           # (r, 1, 1, 2)
        rel = c - quads
        cross = edges[..., 0] * rel[..., 1] - edges[..., 1] * rel[..., 0]          # (r, k, c)
        inside = np.all(cross >= 0.0, axis=2) | np.all(cross <= 0.0, axis=2)
        gap = np.sqrt(_segment_gaps2(np.broadcast_to(c, quads.shape[:2] + (1, 2)), quads, edges).min(axis=(2, 3)))
        poly_apart = ~inside & (gap > radius)
        circ_apart = np.hypot(circles[..., 0] - robot[:, None, 0], circles[..., 1] - robot[:, None, 1]) \
            > circles[..., 2] + radius
        return np.where(is_poly, poly_apart, circ_apart)
    r, k = quads.shape[:2]
    V = robot.shape[1]
    rb = np.broadcast_to(robot[:, None], (r, k, V, 2))
    r_edges = np.roll(rb, -1, axis=2) - rb
    axes = np.concatenate([r_edges, edges], axis=2)[..., ::-1] * np.array([1.0, -1.0])   # normals (r, k, A, 2)
    pr = np.einsum("rkad,rkvd->rkav", axes, rb)
    pq = np.einsum("rkad,rkcd->rkac", axes, quads)
    live = np.any(axes != 0.0, axis=-1)
    poly_apart = np.any(live & ((pr.max(-1) < pq.min(-1)) | (pq.max(-1) < pr.min(-1))), axis=2)
    # circles: the centre outside the footprint and farther than the radius from its edges
    cen = circles[..., :2]                                                       # (r, k, 2)
    re = np.roll(robot, -1, axis=1) - robot                                      # (r, V, 2)
    rel = cen[:, :, None, :] - robot[:, None]                                    # (r, k, V, 2)
    cross = re[:, None, :, 0] * rel[..., 1] - re[:, None, :, 1] * rel[..., 0]
    inside = np.all(cross >= 0.0, axis=2) | np.all(cross <= 0.0, axis=2)
    gap = np.sqrt(_segment_gaps2(cen[:, :, None, :], rb, r_edges).min(axis=(2, 3)))
    circ_apart = ~inside & (gap > circles[..., 2])
    return np.where(is_poly, poly_apart, circ_apart)


#: obstacle polygons of at most this many corners are measured in batches (:meth:`CollisionWorld._shape_tables`)
POLY_PAD = 8


def _circle_distances(fp: Footprint, pose, robot_v, circles: np.ndarray) -> np.ndarray:
    """Exact distances from the footprint at ``pose`` to each of ``circles`` (k, 3: centre, radius),
    none of which it overlaps (so no centre lies inside the footprint)."""
    if robot_v is None:
        return np.hypot(circles[:, 0] - pose[0], circles[:, 1] - pose[1]) - circles[:, 2] - fp.radius
    r_edges = np.roll(robot_v, -1, axis=0) - robot_v
    return np.sqrt(_segment_gaps2(circles[:, :2], robot_v, r_edges).min(axis=1)) - circles[:, 2]


def _poly_distances(fp: Footprint, pose, robot_v, quads: np.ndarray) -> np.ndarray:
    """Exact distances from the footprint at ``pose`` (``robot_v``: its world outline, None for a disc)
    to each of the polygons ``quads`` (k, c, 2), none of which it overlaps: the disc's centre to the
    polygon's edges less its radius, or the smallest vertex-to-edge distance both ways. numpy, not GEOS,
    although shapely's distance is faster here (``nhstab bench geometry``): this is the formula of
    :meth:`CollisionWorld._near_batch`, which decides many poses at once, and the two must give equal
    answers bit for bit (GEOS rounds differently, by up to a few 1e-15 m)."""
    edges = np.roll(quads, -1, axis=1) - quads
    if robot_v is None:
        c = np.asarray(pose[:2], dtype=float)[None, None, :]
        return np.sqrt(_segment_gaps2(np.broadcast_to(c, (len(quads), 1, 2)), quads, edges).min(axis=(1, 2))) \
            - fp.radius
    r_edges = np.roll(robot_v, -1, axis=0) - robot_v
    k = len(quads)
    one = _segment_gaps2(np.broadcast_to(robot_v, (k,) + robot_v.shape), quads, edges).min(axis=(1, 2))
    two = _segment_gaps2(quads, np.broadcast_to(robot_v, (k,) + robot_v.shape),
                         np.broadcast_to(r_edges, (k,) + r_edges.shape)).min(axis=(1, 2))
    return np.sqrt(np.minimum(one, two))


def polygon_distance(a: np.ndarray, b: np.ndarray) -> float:
    """The distance between two outlines (k, 2) (polygons, or segments of two vertices) that do not
    overlap: GEOS's distance (shapely; exact in the plane to rounding, and faster than numpy
    vertex-to-edge arrays, ``nhstab bench geometry``)."""
    return float(shapely.distance(outline_geometry(a), outline_geometry(b)))


def _float_array(value, name: str, expected: str) -> np.ndarray:
    """``value`` as a float array, or an InputError naming ``name`` (None and what numpy cannot convert)."""
    if value is None:
        raise InputError(name, expected, "None")
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, expected, value) from None


def _pose(value, name: str = "pose") -> np.ndarray:
    """A pose (x, y, theta) as an array; anything but three finite numbers is an InputError naming
    ``name`` (a robot's full state, e.g. a car's (x, y, theta, phi), is not a pose: take its pose
    columns)."""
    p = _float_array(value, name, "a pose of three finite numbers (x, y, theta)")
    if p.shape != (3,) or not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])):
        raise InputError(name, "a pose of three finite numbers (x, y, theta)",
                         value if p.size <= 6 else f"an array of shape {p.shape}")
    return p


def _poses(value, name: str = "poses", at_least: int = 0) -> np.ndarray:
    """Poses as an (N, 3) array (one pose (3,) counts as N = 1); anything else is an InputError."""
    p = _float_array(value, name, "an (N, 3) array of poses (x, y, theta)")
    if p.shape == (3,):
        p = p.reshape(1, 3)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < at_least or not np.all(np.isfinite(p)):
        expected = f"an (N, 3) array of finite poses (x, y, theta){f', N >= {at_least}' if at_least else ''}"
        raise InputError(name, expected, value if p.size <= 6 else f"an array of shape {p.shape}")
    return p


def interpolate_poses(poses: np.ndarray, resolution: float, angular_resolution: float):
    """Samples along the polyline of poses; returns (samples (M, 3), segment index of each sample)."""
    if len(poses) == 1:
        return poses.copy(), np.zeros(1, dtype=int)
    d = np.diff(poses, axis=0)
    dth = wrap_angle(d[:, 2])
    steps = np.maximum(1, np.ceil(np.maximum(np.hypot(d[:, 0], d[:, 1]) / resolution,
                                            np.abs(dth) / angular_resolution))).astype(int)
    seg = np.repeat(np.arange(len(steps)), steps)
    first = np.concatenate([[0], np.cumsum(steps)[:-1]])
    a = ((np.arange(len(seg)) - first[seg]) / steps[seg])[:, None]      # k / n within each segment
    delta = np.column_stack([d[:, :2], dth])
    out = poses[seg] + a * delta[seg]
    return np.vstack([out, poses[-1:]]), np.concatenate([seg, [len(poses) - 2]])


def check_poses(m: Map, fp: Footprint, poses: dict, obstacles: str = "all", world: CollisionWorld | None = None) -> dict:
    """Signed clearance of named poses (e.g. {"start": ..., "goal": ...}); raises a MapError naming
    the pose (by its name in ``poses``: the caller's key for it) and saying which map, if one lies
    outside the bounds or its footprint overlaps an obstacle."""
    world = world or CollisionWorld.from_map(m, obstacles)
    out = {}
    for name, pose in poses.items():
        if pose is None:
            continue
        p = _pose(pose, name)
        if not m.contains(p[0], p[1]):
            raise MapError(name, f"inside the bounds {list(m.bounds)} of {m.source or m.name}", p.tolist())
        c = world.clearance(p, fp)
        if c < 0:
            raise MapError(name, f"a pose where the {fp.label or 'robot'} footprint is free of the obstacles of "
                           f"{m.source or m.name}", p.tolist(), detail=f"it overlaps an obstacle by {-c:.3g} m")
        out[name] = c
    return out
