"""A simulated planar range sensor (a 2-D lidar) that reveals the map's unknown obstacles.

:class:`RangeSensor` casts a fan of beams from the sensor's position and returns, per beam, the
distance to the first thing it hits (:class:`Scan`). What stops a beam:

* known polygons (convex or not) and circles (``Map.obstacles``) and the map's unknown obstacles
  (``Map.unknown_obstacles``): exact ray-segment and ray-circle intersections;
* occupied cells of the known grids (``Map.grids``, any yaw): an exact cell traversal. Every grid line
  a beam crosses is found in closed form, and the cell it enters there is looked up. The result is
  the distance to the boundary of the first occupied cell the beam enters, to rounding. A beam cannot
  skip a cell. A beam that passes exactly through a cell corner may or may not count as touching the
  two cells beside it; both answers are correct to within 1e-12 m;
* the map bounds: a beam that leaves ``Map.bounds`` within range hits a known obstacle there.

Beams. ``SensorOptions.beams`` = ceil(fov / resolution) beams split the field of view, centred on the
robot heading, into equal bins of width fov / beams, which is at most ``resolution_rad``. Each beam
points along the centre of its bin: beam k (0-based) is at heading - fov/2 + (k + 1/2) fov / beams.
The default 270 deg at 0.5 deg gives 540 beams at +-0.25, +-0.75, ... +-134.75 deg. With an even
number of beams no beam points exactly along the heading. A full circle (fov = 2 pi) gives evenly
spaced beams and repeats none. The sensor sits at ``mount`` in the robot frame (x forward, y left)
and looks along the robot heading.

Result. ``Scan.hit`` holds, per beam, the index into ``Map.unknown_obstacles`` of the first thing hit,
``HIT_KNOWN`` (-1) for a known shape, grid cell or the map boundary, or ``HIT_NOTHING`` (-2) when
nothing is within ``range_m``. In that last case the range is ``range_m``, never inf. A hit exactly at
``range_m`` counts. An unknown obstacle is revealed when at least one beam hits it before anything
else. Known and unknown obstacles both occlude. If a known and an unknown surface are hit at exactly
the same distance, the unknown one is reported (lowest index among unknown ones). When the sensor
origin is strictly inside an obstacle (or outside the map bounds), every beam has range 0 and hits
that obstacle. An unknown obstacle is preferred there, then a known one. An origin exactly on a
polygon's boundary gives range 0 on the beams that cross its edge line.

Cost: ``nhstab bench run`` times a scan on the depot grid and on a vector map
(``results/bench/summary.md``). Only the edges within range are intersected, and each only with the
beams inside the angle it subtends. Each beam's grid traversal stops at the nearest shape or
boundary hit (or at the range).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import InputError
from .geometry import wrap_angle
from .maps.base import Circle, Map, OccupancyGrid, Polygon

HIT_KNOWN = -1          # Scan.hit: a known shape, occupied grid cell or the map boundary
HIT_NOTHING = -2        # Scan.hit: nothing within range
MAX_BEAMS = 1 << 16     # refuse absurd beam counts (memory of the vectorised intersections)

_TWO_PI = 2.0 * math.pi
_S_TOL = 1e-12          # slack on the segment parameter, so that a beam through a vertex hits an edge
_CHUNK = 1 << 16        # grid traversal: about this many crossings per vectorised block
_PAD = 4                # grid traversal: free cells around each grid (a beam's lines overshoot by <= 3)


@dataclass(frozen=True)
class SensorOptions:
    """A planar lidar: maximum range [m], field of view [rad] centred on the heading (up to 2 pi),
    scan rate [Hz], angle between beams [rad] and the sensor position in the robot frame [m]."""

    range_m: float = 8.0
    fov_rad: float = 2 * math.pi * 270 / 360
    rate_hz: float = 10.0
    resolution_rad: float = math.radians(0.5)
    mount: tuple[float, float] = (0.0, 0.0)

    def validated(self) -> SensorOptions:
        """These options with plain float values, or an :class:`InputError` naming ``sensor.<field>``."""
        values = {}
        for key in ("range_m", "fov_rad", "rate_hz", "resolution_rad"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(v) or v <= 0:
                raise InputError(f"sensor.{key}", "a positive finite number", v)
            values[key] = float(v)
        if values["fov_rad"] > _TWO_PI * (1 + 1e-12):
            raise InputError("sensor.fov_rad", "at most 2 pi (a full circle)", self.fov_rad)
        values["fov_rad"] = min(values["fov_rad"], _TWO_PI)
        if values["resolution_rad"] > values["fov_rad"] * (1 + 1e-12):
            raise InputError("sensor.resolution_rad", f"at most sensor.fov_rad = {values['fov_rad']:.6g}",
                             self.resolution_rad)
        if _beam_count(values["fov_rad"], values["resolution_rad"]) > MAX_BEAMS:
            raise InputError("sensor.resolution_rad", f"coarse enough for at most {MAX_BEAMS} beams over the fov",
                             self.resolution_rad)
        mount = self.mount
        if isinstance(mount, (str, bytes)) or not hasattr(mount, "__len__") or len(mount) != 2 \
                or not all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                           and math.isfinite(v) for v in mount):
            raise InputError("sensor.mount", "two finite numbers (x forward, y left) [m]", mount)
        return replace(self, **values, mount=(float(mount[0]), float(mount[1])))

    @property
    def beams(self) -> int:
        """Number of beams, ceil(fov / resolution) (see the module docstring)."""
        return _beam_count(float(self.fov_rad), float(self.resolution_rad))

    def offsets(self) -> np.ndarray:
        """(beams,) beam angles relative to the robot heading, increasing (bin centres)."""
        fov = min(float(self.fov_rad), _TWO_PI)
        b = self.beams
        return -fov / 2 + (np.arange(b) + 0.5) * (fov / b)

    def describe(self) -> dict:
        return {"range_m": float(self.range_m), "fov_rad": float(self.fov_rad),
                "fov_deg": math.degrees(self.fov_rad), "rate_hz": float(self.rate_hz),
                "resolution_rad": float(self.resolution_rad), "resolution_deg": math.degrees(self.resolution_rad),
                "beams": self.beams, "mount": [float(v) for v in self.mount]}


def _beam_count(fov: float, resolution: float) -> int:
    return max(1, math.ceil(fov / resolution - 1e-9))


@dataclass
class Scan:
    """One sweep: per beam its world angle, range and what it hit (see the module docstring)."""

    pose: np.ndarray        # (3,) robot pose (x, y, theta)
    origin: np.ndarray      # (2,) sensor position in the world
    angles: np.ndarray      # (B,) world-frame beam angles
    ranges: np.ndarray      # (B,) distance to the first hit, range_m where nothing is hit
    hit: np.ndarray         # (B,) int: unknown-obstacle index, HIT_KNOWN (-1) or HIT_NOTHING (-2)

    def points(self) -> np.ndarray:
        """(B, 2) beam end points in the world (hit points, or the range limit)."""
        return self.origin + self.ranges[:, None] * np.stack([np.cos(self.angles), np.sin(self.angles)], axis=1)

    @property
    def revealed(self) -> set[int]:
        """Indices into ``Map.unknown_obstacles`` hit first by at least one beam."""
        return set(np.unique(self.hit[self.hit >= 0]).tolist())


@dataclass(frozen=True)
class _Grid:
    """An occupancy grid prepared for traversal (frame, size, flat occupancy)."""

    x0: float
    y0: float
    cos: float
    sin: float
    res: float
    rows: int
    cols: int
    padded: np.ndarray       # ((rows + 2 _PAD) * (cols + 2 _PAD),) bool, row-major, with a free border


class RangeSensor:
    """Simulated range sensor on a :class:`~nhstab.maps.base.Map`; :meth:`scan` takes a pose.

    The edge, circle and grid arrays are built once here; a scan is vectorised over beams.
    """

    def __init__(self, m: Map, options: SensorOptions | None = None):
        self.map = m
        self.options = (options if options is not None else SensorOptions()).validated()
        opts = self.options
        self.range_m = opts.range_m
        self.beams = opts.beams
        self.offsets = opts.offsets()
        self._fov = opts.fov_rad
        self._step = self._fov / self.beams
        self._mount = np.array(opts.mount, dtype=float)

        starts, vectors, owners, poly_ids, poly_owner = [], [], [], [], []
        centers, radii, circle_owner = [], [], []
        shapes = [(-1, s) for s in m.obstacles] + list(enumerate(m.unknown_obstacles))
        for owner, shape in shapes:
            if isinstance(shape, Polygon):
                v = np.asarray(shape.vertices, dtype=float)
                starts.append(v)
                vectors.append(np.roll(v, -1, axis=0) - v)
                owners.append(np.full(len(v), owner))
                poly_ids.append(np.full(len(v), len(poly_owner)))
                poly_owner.append(owner)
            elif isinstance(shape, Circle):
                centers.append(shape.center)
                radii.append(shape.radius)
                circle_owner.append(owner)
            else:
                where = "obstacles" if owner < 0 else f"unknown_obstacles[{owner}]"
                raise InputError(f"map.{where}", "Polygon or Circle shapes", type(shape).__name__)
        self._seg_a = np.concatenate(starts) if starts else np.zeros((0, 2))
        self._seg_d = np.concatenate(vectors) if vectors else np.zeros((0, 2))
        self._seg_len2 = np.einsum("ij,ij->i", self._seg_d, self._seg_d)
        self._seg_owner = np.concatenate(owners).astype(np.intp) if owners else np.zeros(0, np.intp)
        self._seg_poly = np.concatenate(poly_ids).astype(np.intp) if poly_ids else np.zeros(0, np.intp)
        self._poly_owner = np.array(poly_owner, dtype=np.intp)
        self._c_center = np.array(centers, dtype=float).reshape(-1, 2)
        self._c_radius = np.array(radii, dtype=float)
        self._c_owner = np.array(circle_owner, dtype=np.intp)
        self._grids = tuple(_prepare_grid(g) for g in m.grids)
        self._bounds = m.bounds

    # ------------------------------------------------------------------------------------------
    def sensor_origin(self, pose) -> np.ndarray:
        """(2,) world position of the sensor at robot pose (x, y, theta)."""
        x, y, th = _pose(pose)
        c, s = math.cos(th), math.sin(th)
        mx, my = self._mount
        return np.array([x + c * mx - s * my, y + s * mx + c * my])

    def scan(self, pose) -> Scan:
        """One sweep from robot pose (x, y, theta): ranges and hits of every beam."""
        x, y, th = _pose(pose)
        o = self.sensor_origin((x, y, th))
        angles = th + self.offsets
        cos, sin = np.cos(angles), np.sin(angles)
        B, R = self.beams, self.range_m
        pose_arr = np.array([x, y, th])

        inside = self._inside(o)
        if inside is not None:
            return Scan(pose_arr, o, angles, np.zeros(B), np.full(B, inside, dtype=np.intp))

        known = np.full(B, np.inf)          # nearest known hit per beam
        unknown = np.full(B, np.inf)        # nearest unknown hit per beam
        owner = np.full(B, HIT_NOTHING, dtype=np.intp)
        beam, t, who = self._shape_hits(o, th, cos, sin)
        if len(t):
            is_known = who < 0
            np.minimum.at(known, beam[is_known], t[is_known])
            u = ~is_known
            if np.any(u):
                np.minimum.at(unknown, beam[u], t[u])
                best = u & (t == unknown[beam])
                first = np.full(B, np.iinfo(np.intp).max, dtype=np.intp)
                np.minimum.at(first, beam[best], who[best])
                owner = np.where(np.isfinite(unknown), first, HIT_NOTHING)

        known = np.minimum(known, self._bounds_exit(o, cos, sin))
        for g in self._grids:
            limit = np.minimum(np.minimum(known, unknown), R)
            known = np.minimum(known, _grid_hits(g, o, cos, sin, limit))

        nearest = np.minimum(known, unknown)
        hit = np.where(unknown <= known, owner, HIT_KNOWN)
        nothing = nearest > R
        ranges = np.where(nothing, R, nearest)
        hit = np.where(nothing, HIT_NOTHING, hit).astype(np.intp)
        return Scan(pose_arr, o, angles, ranges, hit)

    # ------------------------------------------------------------------------------------------
    def _inside(self, o: np.ndarray) -> int | None:
        """What the origin is strictly inside: an unknown index, HIT_KNOWN, or None (free space)."""
        found: list[int] = []
        if len(self._seg_a):
            a = self._seg_a
            b = a + self._seg_d
            straddles = (a[:, 1] > o[1]) != (b[:, 1] > o[1])
            dy = np.where(straddles, self._seg_d[:, 1], 1.0)
            x_cross = a[:, 0] + (o[1] - a[:, 1]) * self._seg_d[:, 0] / dy
            crossings = np.bincount(self._seg_poly, weights=straddles & (o[0] < x_cross),
                                    minlength=len(self._poly_owner))
            found += self._poly_owner[crossings.astype(np.int64) % 2 == 1].tolist()
        if len(self._c_radius):
            d2 = np.sum((self._c_center - o) ** 2, axis=1)
            found += self._c_owner[d2 < self._c_radius ** 2].tolist()
        unknown = [k for k in found if k >= 0]
        if unknown:
            return min(unknown)
        if found or not self.map.contains(o[0], o[1]):
            return HIT_KNOWN
        for g in self._grids:
            u, v = _to_grid(g, o[0], o[1])
            i, j = math.floor(v), math.floor(u)
            if 0 <= i < g.rows and 0 <= j < g.cols and g.padded[(i + _PAD) * (g.cols + 2 * _PAD) + j + _PAD]:
                return HIT_KNOWN
        return None

    def _arc_beams(self, start: np.ndarray, width: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(arc, beam) index pairs: the beams whose direction lies in the arc [start, start + width]
        (angles relative to the heading, start in [-pi, pi), 0 <= width <= pi), one beam of slack on
        each side; the arc is also tried one turn lower (it may wrap past +pi)."""
        B, step = self.beams, self._step
        base = (start + self._fov / 2) / step - 0.5          # fractional beam index of the arc start
        span = width / step
        lo, hi = [], []
        for shift in (0.0, -_TWO_PI / step):
            lo.append(np.maximum(np.ceil(base + shift) - 1, 0))
            hi.append(np.minimum(np.floor(base + shift + span) + 1, B - 1))
        lo = np.concatenate(lo).astype(np.intp)
        hi = np.concatenate(hi).astype(np.intp)
        arc = np.concatenate([np.arange(len(start))] * 2)
        counts = np.maximum(hi - lo + 1, 0)
        total = int(counts.sum())
        arcs = np.repeat(arc, counts)
        beams = np.arange(total) - np.repeat(np.cumsum(counts) - counts - lo, counts)
        return arcs, beams

    def _shape_hits(self, o, heading, cos, sin) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(beam, t, owner) of every beam-shape intersection within range, polygons and circles."""
        R = self.range_m
        beams, ts, owners = [], [], []
        if len(self._seg_a):
            rel = self._seg_a - o                                # segment start relative to the origin
            d = self._seg_d
            lam = np.clip(-np.einsum("ij,ij->i", rel, d) / np.maximum(self._seg_len2, 1e-300), 0.0, 1.0)
            near = np.flatnonzero(np.hypot(rel[:, 0] + lam * d[:, 0], rel[:, 1] + lam * d[:, 1]) <= R)
            if len(near):
                p, e = rel[near], d[near]
                a1 = np.arctan2(p[:, 1], p[:, 0]) - heading
                a2 = np.arctan2(p[:, 1] + e[:, 1], p[:, 0] + e[:, 0]) - heading
                diff = wrap_angle(a2 - a1)
                start = wrap_angle(np.where(diff >= 0, a1, a2))
                arc, beam = self._arc_beams(start, np.abs(diff))
                seg = near[arc]
                dx, dy = cos[beam], sin[beam]
                wx, wy = rel[seg, 0], rel[seg, 1]
                ex, ey = d[seg, 0], d[seg, 1]
                den = dx * ey - dy * ex
                ok = np.abs(den) > 1e-14 * np.sqrt(self._seg_len2[seg])
                den = np.where(ok, den, 1.0)
                t = (wx * ey - wy * ex) / den
                s = (wx * dy - wy * dx) / den
                ok &= (s >= -_S_TOL) & (s <= 1 + _S_TOL) & (t >= 0) & (t <= R)
                beams.append(beam[ok])
                ts.append(t[ok])
                owners.append(self._seg_owner[seg[ok]])
        if len(self._c_radius):
            rel = self._c_center - o
            dist = np.hypot(rel[:, 0], rel[:, 1])
            near = np.flatnonzero(dist - self._c_radius <= R)
            if len(near):
                half = np.arcsin(np.minimum(self._c_radius[near] / dist[near], 1.0))
                start = wrap_angle(np.arctan2(rel[near, 1], rel[near, 0]) - heading - half)
                arc, beam = self._arc_beams(start, 2 * half)
                c = near[arc]
                b = cos[beam] * rel[c, 0] + sin[beam] * rel[c, 1]          # projection of the centre
                c2 = dist[c] ** 2 - self._c_radius[c] ** 2                 # > 0 outside
                disc = b * b - c2
                ok = (disc >= 0) & (b > 0)
                t = c2 / np.where(ok, b + np.sqrt(np.maximum(disc, 0.0)), 1.0)   # the nearer root, stably
                ok &= t <= R
                beams.append(beam[ok])
                ts.append(t[ok])
                owners.append(self._c_owner[c[ok]])
        if not ts:
            return np.zeros(0, np.intp), np.zeros(0), np.zeros(0, np.intp)
        return np.concatenate(beams), np.concatenate(ts), np.concatenate(owners)

    def _bounds_exit(self, o, cos, sin) -> np.ndarray:
        """Distance along each beam to where it leaves the map bounds (the origin is inside)."""
        xmin, ymin, xmax, ymax = self._bounds
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.where(cos > 0, (xmax - o[0]) / cos, np.where(cos < 0, (xmin - o[0]) / cos, np.inf))
            ty = np.where(sin > 0, (ymax - o[1]) / sin, np.where(sin < 0, (ymin - o[1]) / sin, np.inf))
        return np.maximum(np.minimum(tx, ty), 0.0)


# --------------------------------------------------------------------------------------------------
# Grid traversal


def _prepare_grid(g: OccupancyGrid) -> _Grid:
    x0, y0, yaw = g.origin
    rows, cols = g.shape
    padded = np.zeros((rows + 2 * _PAD, cols + 2 * _PAD), dtype=bool)
    padded[_PAD:-_PAD, _PAD:-_PAD] = g.occupied
    return _Grid(x0, y0, math.cos(yaw), math.sin(yaw), float(g.resolution), rows, cols, padded.ravel())


def _to_grid(g: _Grid, x, y):
    """World point(s) to grid coordinates (u along columns, v along rows) in cells."""
    dx, dy = x - g.x0, y - g.y0
    return (g.cos * dx + g.sin * dy) / g.res, (-g.sin * dx + g.cos * dy) / g.res


def _grid_hits(g: _Grid, o, cos, sin, limit: np.ndarray) -> np.ndarray:
    """Per beam, the distance to the first occupied cell of ``g`` entered before ``limit`` (else inf).

    The origin's own cell is free (checked by the caller). In grid coordinates (cells) a beam is
    (U0 + t du, V0 + t dv); the cells it visits are those it enters at the column lines and row lines
    it crosses, in closed form. Beams are grouped by how many lines they cross, to keep padding low.
    """
    B = len(cos)
    out = np.full(B, np.inf)
    U0, V0 = _to_grid(g, o[0], o[1])
    du = (g.cos * cos + g.sin * sin) / g.res              # cells per metre along the beam
    dv = (-g.sin * cos + g.cos * sin) / g.res
    # clip each beam to the grid rectangle [0, cols] x [0, rows] and to [0, limit]
    t_lo = np.zeros(B)
    t_hi = np.array(limit, dtype=float)
    for p0, dp, size in ((U0, du, g.cols), (V0, dv, g.rows)):
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (0.0 - p0) / dp, (size - p0) / dp
        flat = dp == 0
        inside_slab = 0.0 <= p0 <= size
        enter = np.where(flat, -np.inf if inside_slab else np.inf, np.minimum(ta, tb))
        leave = np.where(flat, np.inf if inside_slab else -np.inf, np.maximum(ta, tb))
        t_lo = np.maximum(t_lo, enter)
        t_hi = np.minimum(t_hi, leave)
    active = np.flatnonzero(t_lo <= t_hi)
    if not len(active):
        return out
    best = np.full(len(active), np.inf)
    W2 = g.cols + 2 * _PAD                                # row stride of the padded grid
    families = ((U0, V0, du[active], dv[active], 1, W2),      # column lines
                (V0, U0, dv[active], du[active], W2, 1))      # row lines
    for p0, q0, dp, dq, stride_p, stride_q in families:
        lo, hi = t_lo[active], t_hi[active]
        moving = np.abs(dp) > 1e-12
        n = np.where(moving, np.ceil((hi - lo) * np.abs(dp)) + 2, 0).astype(np.intp)
        order = np.argsort(n, kind="stable")
        sizes = n[order]
        k0 = int(np.searchsorted(sizes, 1))               # beams that cross no line of this family
        while k0 < len(order):
            cap = max(1.5 * sizes[k0], sizes[k0] + 16)    # block of similar lengths: padding < 50 %
            k1 = int(np.searchsorted(sizes, cap, side="right"))
            k1 = min(k1, k0 + max(1, _CHUNK // int(cap)))
            idx = order[k0:k1]
            N = int(sizes[k1 - 1])
            d, e = dp[idx], dq[idx]
            lo_b, hi_b = lo[idx, None], hi[idx, None]
            pos = p0 + lo[idx] * d                         # line coordinate where the beam enters the grid
            fwd = d > 0
            first = np.where(fwd, np.floor(pos), np.ceil(pos))     # a line at or before the entry
            line = first[:, None] + np.where(fwd, 1.0, -1.0)[:, None] * np.arange(N)
            t = (line - p0) / d[:, None]
            # The cell entered across each line, as a flat index into the padded grid. The first line
            # may lie before the beam's stretch in the grid: the cell across it is the one the beam is
            # in at the stretch's start (the origin's own cell, or where it enters the grid), so its
            # t is raised to that start. The other coordinate is taken at t capped at the stretch's
            # end, which keeps the index inside the padding however steep the beam. Lines past a
            # beam's own count (block padding) repeat its last cell at larger t, which cannot win.
            np.maximum(t, lo_b, out=t)
            q = np.minimum(t, hi_b)
            q *= e[:, None]
            q += q0 + _PAD
            np.floor(q, out=q)
            q *= stride_q
            last = first + np.where(fwd, 1.0, -1.0) * (n[idx] - 1)          # this beam's own last line
            np.clip(line, np.minimum(first, last)[:, None], np.maximum(first, last)[:, None], out=line)
            line += np.where(fwd, _PAD, _PAD - 1)[:, None]
            if stride_p != 1:
                line *= stride_p
            q += line
            t_occupied = np.where(g.padded[q.astype(np.intp)], t, np.inf).min(axis=1)
            best[idx] = np.minimum(best[idx], t_occupied)
            k0 = k1
    best = np.where(best <= t_hi[active], best, np.inf)       # entries beyond the limit do not count
    out[active] = best
    return out


# --------------------------------------------------------------------------------------------------


def _pose(pose) -> tuple[float, float, float]:
    """(x, y, theta) from a sequence of three numbers or a :class:`~nhstab.maps.base.Pose`."""
    if hasattr(pose, "as_array"):
        pose = pose.as_array()
    try:
        arr = np.asarray(pose, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError("pose", "three finite numbers (x, y, theta)", pose) from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError("pose", "three finite numbers (x, y, theta)", pose)
    return float(arr[0]), float(arr[1]), float(arr[2])
