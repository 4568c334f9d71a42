"""The simulated range sensor (nhstab.sensing).

Reference values are computed here, independently of the sensor. Tolerances:

* closed-form distances to axis-aligned boxes (slab method), circles (the quadratic) and the map
  bounds: 1e-9 m;
* random non-convex polygon worlds: shapely's line/polygon intersection, 1e-9 m;
* grids: a brute-force walk along each beam at 1e-3 m steps that uses the grid's own
  ``world_to_cell``. The sensor's range is never beyond the first sample that lies in an occupied
  cell (+1e-9 m), so it skips no cell, and it is within 1e-3 m (the step) of that sample. The only
  exception is a beam that clips a cell corner along less than one step, which the walk can miss.
  There a walk at 1e-8 m steps around the sensor's range must find the cell within 1e-8 m of it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely.geometry as sg
from nhstab.errors import InputError
from nhstab.maps import Circle, Map, OccupancyGrid, Polygon, box_polygon, load_map
from nhstab.sensing import HIT_KNOWN, HIT_NOTHING, RangeSensor, Scan, SensorOptions

MAPS = Path(__file__).resolve().parents[2] / "maps"
TOL = 1e-9

#: 541 beams over 270 deg: the middle beam (index 270) points exactly along the heading
ODD = SensorOptions(resolution_rad=2 * math.pi * 270 / 360 / 541)


def world(obstacles=(), unknown=(), grids=(), bounds=(-50.0, -50.0, 50.0, 50.0)) -> Map:
    return Map("test", bounds, obstacles=tuple(obstacles), unknown_obstacles=tuple(unknown), grids=tuple(grids))


def box(x0, y0, x1, y1) -> Polygon:
    return box_polygon((x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0)


def slab_distance(o, a, lo, hi) -> float:
    """Distance from o along angle a to the axis-aligned box [lo, hi], inf if missed (o outside)."""
    d = np.array([math.cos(a), math.sin(a)])
    t0, t1 = -math.inf, math.inf
    for k in range(2):
        if abs(d[k]) < 1e-300:
            if not lo[k] <= o[k] <= hi[k]:
                return math.inf
            continue
        ta, tb = (lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    return t0 if t0 <= t1 and t0 >= 0 else math.inf


def circle_distance(o, a, c, r) -> float:
    """Distance from o along angle a to the circle (c, r), inf if missed (o outside)."""
    d = np.array([math.cos(a), math.sin(a)])
    w = np.asarray(o, float) - c
    b, q = float(d @ w), float(w @ w) - r * r
    disc = b * b - q
    if disc < 0:
        return math.inf
    t = -b - math.sqrt(disc)
    return t if t >= 0 else math.inf


def expected(ref: np.ndarray, R: float) -> np.ndarray:
    return np.where(ref <= R, ref, R)


# --------------------------------------------------------------------------------------------------
# Options


def test_default_options_and_beam_layout():
    opts = SensorOptions().validated()
    assert opts.beams == 540
    off = opts.offsets()
    assert np.allclose(np.diff(off), math.radians(0.5), atol=1e-12)
    assert off[0] == pytest.approx(-opts.fov_rad / 2 + math.radians(0.25), abs=1e-12)
    assert off[-1] == pytest.approx(opts.fov_rad / 2 - math.radians(0.25), abs=1e-12)
    assert np.allclose(off, -off[::-1], atol=1e-12)                       # symmetric about the heading
    d = opts.describe()
    assert d["beams"] == 540 and d["range_m"] == 8.0 and d["fov_deg"] == pytest.approx(270.0)
    assert d["mount"] == [0.0, 0.0] and d["rate_hz"] == 10.0
    full = SensorOptions(fov_rad=2 * math.pi).validated()
    assert full.beams == 720
    gaps = np.diff(np.concatenate([full.offsets(), full.offsets()[:1] + 2 * math.pi]))
    assert np.allclose(gaps, math.radians(0.5), atol=1e-12)             # no beam repeated around the circle
    assert ODD.beams == 541 and ODD.offsets()[270] == pytest.approx(0.0, abs=1e-15)


@pytest.mark.parametrize("field, value", [
    ("range_m", 0.0), ("range_m", -1.0), ("range_m", math.nan), ("range_m", math.inf), ("range_m", "8"),
    ("range_m", True),
    ("fov_rad", 0.0), ("fov_rad", 7.0), ("fov_rad", -math.pi), ("fov_rad", math.nan),
    ("rate_hz", 0.0), ("rate_hz", -10.0), ("rate_hz", math.inf),
    ("resolution_rad", 0.0), ("resolution_rad", math.nan), ("resolution_rad", 5.0), ("resolution_rad", 1e-12),
    ("mount", (math.nan, 0.0)), ("mount", (1.0,)), ("mount", "ab"), ("mount", None), ("mount", (0.0, math.inf)),
])
def test_bad_options_name_the_field(field, value):
    with pytest.raises(InputError, match=rf"^'sensor\.{field}' must be") as info:
        SensorOptions(**{field: value}).validated()
    assert info.value.argument == f"sensor.{field}"
    assert "\n" not in str(info.value)
    with pytest.raises(InputError, match=rf"sensor\.{field}"):
        RangeSensor(world(), SensorOptions(**{field: value}))


def test_bad_pose_is_an_input_error():
    sensor = RangeSensor(world())
    for pose in [(0.0, 0.0), (0.0, math.nan, 0.0), "abc", (1, 2, 3, 4)]:
        with pytest.raises(InputError, match="^'pose'"):
            sensor.scan(pose)


# --------------------------------------------------------------------------------------------------
# Closed-form distances


@pytest.mark.parametrize("known", [True, False])
def test_square_ranges_are_the_closed_form_distance(known):
    lo, hi = np.array([5.0, -0.5]), np.array([6.0, 0.5])
    sq = box(*lo, *hi)
    m = world(obstacles=[sq] if known else [], unknown=[] if known else [sq])
    sensor = RangeSensor(m, ODD)
    scan = sensor.scan((0.0, 0.0, 0.0))
    assert isinstance(scan, Scan) and scan.ranges.shape == scan.hit.shape == scan.angles.shape == (541,)
    assert scan.ranges[270] == pytest.approx(5.0, abs=TOL)              # straight at the face
    assert scan.hit[270] == (HIT_KNOWN if known else 0)
    ref = np.array([slab_distance((0.0, 0.0), a, lo, hi) for a in scan.angles])
    assert np.isfinite(ref).sum() == 11 * 2 + 1                          # beams within +-5.7 deg
    assert np.allclose(scan.ranges, expected(ref, 8.0), atol=TOL, rtol=0)
    missed = ~np.isfinite(ref)
    assert np.all(scan.hit[missed] == HIT_NOTHING) and np.all(scan.ranges[missed] == 8.0)
    assert np.all(scan.hit[~missed] == (HIT_KNOWN if known else 0))
    assert scan.revealed == (set() if known else {0})
    # end points: on the face for hits, at range_m for misses
    pts = scan.points()
    assert np.allclose(pts[~missed, 0], 5.0, atol=TOL)
    assert np.allclose(np.hypot(*pts[missed].T), 8.0, atol=TOL)


def test_rotated_pose_and_all_sides_of_a_box():
    lo, hi = np.array([-1.0, 2.0]), np.array([1.5, 3.0])
    sensor = RangeSensor(world(obstacles=[box(*lo, *hi)]), SensorOptions(fov_rad=2 * math.pi, range_m=10.0))
    for o in [(0.3, 0.0), (-3.0, 2.5), (3.0, 5.0), (0.0, 4.0)]:
        scan = sensor.scan((*o, 0.7))
        ref = np.array([slab_distance(o, a, lo, hi) for a in scan.angles])
        assert np.isfinite(ref).sum() > 20
        assert np.allclose(scan.ranges, expected(ref, 10.0), atol=TOL, rtol=0)
        assert np.array_equal(scan.hit == HIT_KNOWN, np.isfinite(ref))


def test_circle_ranges_are_the_closed_form_distance():
    c, r = np.array([6.0, 1.0]), 1.0
    m = world(obstacles=[Circle(tuple(c), r)], unknown=[Circle((-4.0, -4.0), 0.5)])
    sensor = RangeSensor(m, ODD)
    heading = math.atan2(1.0, 6.0)
    scan = sensor.scan((0.0, 0.0, heading))
    assert scan.ranges[270] == pytest.approx(math.sqrt(37.0) - 1.0, abs=TOL)     # at the centre
    ref = np.array([circle_distance((0.0, 0.0), a, c, r) for a in scan.angles])
    assert np.isfinite(ref).sum() > 30
    assert np.allclose(scan.ranges, expected(ref, 8.0), atol=TOL, rtol=0)
    assert np.array_equal(scan.hit == HIT_KNOWN, np.isfinite(ref))
    assert np.all(scan.hit[~np.isfinite(ref)] == HIT_NOTHING)
    # the unknown circle lies at 225 deg from +x, 215.5 deg off the heading: outside the +-135 deg
    # field of view, so it stays hidden; turning towards it reveals it
    assert scan.revealed == set()
    toward = sensor.scan((0.0, 0.0, math.radians(225.0)))
    assert toward.revealed == {0}
    assert toward.ranges[270] == pytest.approx(4.0 * math.sqrt(2) - 0.5, abs=TOL)


def test_map_bounds_stop_beams_within_range_only():
    bounds = (0.0, 0.0, 10.0, 5.0)
    sensor = RangeSensor(world(bounds=bounds), SensorOptions(fov_rad=2 * math.pi, range_m=20.0))
    o = (2.0, 2.0)
    scan = sensor.scan((*o, 0.3))
    exit_ = np.array([_exit(o, a, bounds) for a in scan.angles])
    assert np.allclose(scan.ranges, exit_, atol=TOL, rtol=0) and np.all(scan.hit == HIT_KNOWN)
    short = RangeSensor(world(bounds=bounds), SensorOptions(fov_rad=2 * math.pi, range_m=1.5)).scan((*o, 0.3))
    assert np.all(short.hit == HIT_NOTHING) and np.all(short.ranges == 1.5)


def _exit(o, a, bounds) -> float:
    d = (math.cos(a), math.sin(a))
    ts = []
    for k, (lo, hi) in enumerate(((bounds[0], bounds[2]), (bounds[1], bounds[3]))):
        if d[k] > 0:
            ts.append((hi - o[k]) / d[k])
        elif d[k] < 0:
            ts.append((lo - o[k]) / d[k])
    return min(ts)


# --------------------------------------------------------------------------------------------------
# Revealing: occlusion, range, field of view, mount


def test_unknown_obstacle_behind_a_known_wall_is_not_revealed():
    wall = box(3.0, -2.0, 3.2, 2.0)
    behind = box(5.0, -0.5, 5.5, 0.5)
    assert RangeSensor(world([wall], [behind])).scan((0.0, 0.0, 0.0)).revealed == set()
    in_front = box(1.5, -0.5, 2.0, 0.5)
    scan = RangeSensor(world([wall], [in_front])).scan((0.0, 0.0, 0.0))
    assert scan.revealed == {0}
    # only the beams that hit it first carry its index; beside it the wall is hit
    near = scan.hit == 0
    assert np.allclose(scan.ranges[near] * np.cos(scan.angles[near]), 1.5, atol=TOL)
    assert np.any(scan.hit == HIT_KNOWN)


def test_unknown_obstacles_occlude_each_other():
    front = box(2.0, -2.0, 2.3, 2.0)
    back = box(5.0, -0.5, 5.5, 0.5)
    assert RangeSensor(world((), [front, back])).scan((0.0, 0.0, 0.0)).revealed == {0}
    # half-hidden: the back one sticks out above the front one
    taller = box(5.0, 1.0, 5.5, 6.0)
    assert RangeSensor(world((), [front, taller])).scan((0.0, 0.0, 0.0)).revealed == {0, 1}


def test_range_limit():
    R = 8.0
    for gap, seen in [(0.01, False), (-0.01, True)]:
        c = Circle((R + 0.5 + gap, 0.0), 0.5)            # nearest point at R + gap
        scan = RangeSensor(world((), [c]), ODD).scan((0.0, 0.0, 0.0))
        assert (scan.revealed == {0}) == seen, gap
        if seen:
            assert scan.ranges[270] == pytest.approx(R + gap, abs=TOL)
        else:
            assert np.all(scan.ranges == R) and np.all(scan.hit == HIT_NOTHING)


def test_field_of_view():
    behind = Circle((-3.0, 0.0), 0.3)
    m = world((), [behind])
    assert RangeSensor(m).scan((0.0, 0.0, 0.0)).revealed == set()                 # 270 deg lidar
    full = RangeSensor(m, SensorOptions(fov_rad=2 * math.pi)).scan((0.0, 0.0, 0.0))
    assert full.revealed == {0}
    a = full.angles[np.argmin(full.ranges)]
    assert np.min(full.ranges) == pytest.approx(circle_distance((0.0, 0.0), a, np.array([-3.0, 0.0]), 0.3), abs=TOL)
    assert abs(math.cos(a) + 1) < 1e-4                                             # the beam 0.25 deg off +-pi
    # just inside / just outside the 270 deg edge (135 deg off the heading)
    for deg, seen in [(130.0, True), (140.0, False), (-130.0, True), (-140.0, False)]:
        a = math.radians(deg)
        c = Circle((3.0 * math.cos(a), 3.0 * math.sin(a)), 0.05)
        assert (RangeSensor(world((), [c])).scan((0.0, 0.0, 0.0)).revealed == {0}) == seen, deg


def test_mount_offset():
    lo, hi = np.array([5.0, -0.5]), np.array([6.0, 0.5])
    m = world([box(*lo, *hi)])
    base = RangeSensor(m, ODD).scan((0.0, 0.0, 0.0))
    ahead = RangeSensor(m, SensorOptions(resolution_rad=ODD.resolution_rad, mount=(1.0, 0.0))).scan((0.0, 0.0, 0.0))
    assert base.ranges[270] == pytest.approx(5.0, abs=TOL)
    assert ahead.ranges[270] == pytest.approx(4.0, abs=TOL)
    assert np.allclose(ahead.origin, [1.0, 0.0], atol=TOL)
    # rotated pose: mount (1, 0.5) at heading 90 deg is 1 m up and 0.5 m left (-x) of the robot
    m2 = world([box(-2.0, 5.0, 2.0, 6.0)])
    opts = SensorOptions(resolution_rad=ODD.resolution_rad, mount=(1.0, 0.5))
    scan = RangeSensor(m2, opts).scan((0.2, 0.0, math.pi / 2))
    assert np.allclose(scan.origin, [0.2 - 0.5, 1.0], atol=TOL)
    assert scan.ranges[270] == pytest.approx(4.0, abs=TOL)
    ref = np.array([slab_distance(scan.origin, a, (-2.0, 5.0), (2.0, 6.0)) for a in scan.angles])
    assert np.allclose(scan.ranges, expected(ref, 8.0), atol=TOL, rtol=0)
    assert np.allclose(scan.angles, math.pi / 2 + opts.offsets(), atol=1e-15)


def test_origin_inside_an_obstacle_gives_zero_ranges():
    known, unknown = box(-1.0, -1.0, 1.0, 1.0), Circle((5.0, 5.0), 1.0)
    sensor = RangeSensor(world([known], [Circle((9.0, 9.0), 0.5), unknown], bounds=(-10, -10, 10, 10)))
    for pose, hit in [((0.0, 0.0, 0.0), HIT_KNOWN), ((5.2, 4.9, 1.0), 1), ((11.0, 0.0, 0.0), HIT_KNOWN)]:
        scan = sensor.scan(pose)
        assert np.all(scan.ranges == 0.0) and np.all(scan.hit == hit), pose
    grid = OccupancyGrid(np.array([[False, True], [False, False]]), 1.0, (0.0, 0.0, 0.0))
    scan = RangeSensor(world(grids=[grid])).scan((1.5, 0.5, 0.0))
    assert np.all(scan.ranges == 0.0) and np.all(scan.hit == HIT_KNOWN)


# --------------------------------------------------------------------------------------------------
# Non-convex polygons against shapely


def _random_polygon_world(rng) -> tuple[list, list]:
    L = Polygon(np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]], float))
    U = Polygon(np.array([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]], float))
    star = Polygon(np.array([[math.cos(a) * (1.0 if k % 2 else 0.4), math.sin(a) * (1.0 if k % 2 else 0.4)]
                             for k, a in enumerate(np.linspace(0, 2 * np.pi, 10, endpoint=False))]))
    shapes = []
    for base in (L, U, star, L, U):
        th = rng.uniform(-np.pi, np.pi)
        c, s = math.cos(th), math.sin(th)
        v = base.vertices @ np.array([[c, s], [-s, c]]) * rng.uniform(0.8, 1.5) + rng.uniform(-6, 6, 2)
        shapes.append(Polygon(v))
    return shapes[:3], shapes[3:]


def test_non_convex_polygons_match_shapely(rng):
    R = 10.0
    for _ in range(4):
        known, unknown = _random_polygon_world(rng)
        m = world(known, unknown, bounds=(-9.0, -9.0, 9.0, 9.0))
        sensor = RangeSensor(m, SensorOptions(range_m=R, fov_rad=2 * math.pi, resolution_rad=math.radians(2)))
        geoms = [sg.Polygon(p.vertices) for p in known + unknown]
        owners = [HIT_KNOWN] * len(known) + list(range(len(unknown)))
        checked = 0
        while checked < 5:
            o = rng.uniform(-8.5, 8.5, 2)
            if any(g.covers(sg.Point(o)) for g in geoms):
                continue
            checked += 1
            scan = sensor.scan((*o, rng.uniform(-np.pi, np.pi)))
            for a, r, h in zip(scan.angles, scan.ranges, scan.hit, strict=True):
                end = o + R * np.array([math.cos(a), math.sin(a)])
                ray = sg.LineString([o, end])
                dists = [sg.Point(o).distance(g.intersection(ray)) if g.intersects(ray) else math.inf
                         for g in geoms]
                dists.append(_exit(o, a, m.bounds))
                k = int(np.argmin(dists))
                ref = dists[k]
                if ref > R:
                    assert r == R and h == HIT_NOTHING
                    continue
                assert r == pytest.approx(ref, abs=TOL)
                assert h == (owners[k] if k < len(geoms) else HIT_KNOWN)


# --------------------------------------------------------------------------------------------------
# Grids against a brute-force walk


def brute_force_ranges(m: Map, origin, angles, R: float, step: float) -> np.ndarray:
    """Distance to the first sample (multiples of ``step``) in an occupied cell or outside the bounds."""
    s = np.arange(0.0, R + step / 2, step)
    out = np.full(len(angles), np.inf)
    for k, a in enumerate(angles):
        out[k] = _first_blocked(m, origin, a, s)
    return out


def _first_blocked(m: Map, origin, a: float, s: np.ndarray) -> float:
    x, y = origin[0] + s * math.cos(a), origin[1] + s * math.sin(a)
    xmin, ymin, xmax, ymax = m.bounds
    blocked = (x < xmin) | (x > xmax) | (y < ymin) | (y > ymax)
    for g in m.grids:
        i, j = g.world_to_cell(x, y)
        H, W = g.shape
        inside = (i >= 0) & (i < H) & (j >= 0) & (j < W)
        blocked |= inside & g.occupied[np.where(inside, i, 0), np.where(inside, j, 0)]
    return float(s[np.argmax(blocked)]) if blocked.any() else math.inf


def check_against_brute_force(m: Map, scan: Scan, R: float, step: float = 1e-3) -> int:
    """Assert the scan agrees with the walk (see the module docstring); return the refined beams."""
    brute = brute_force_ranges(m, scan.origin, scan.angles, R, step)
    got = np.where(scan.hit == HIT_NOTHING, np.inf, scan.ranges)
    assert np.all(got <= brute + TOL), "the sensor skipped an occupied cell"
    close = got >= brute - step - TOL
    refined = 0
    for k in np.flatnonzero(~close):                      # the walk missed a corner the beam clips
        fine = got[k] + np.arange(-1e-6, step, 1e-8)
        assert abs(_first_blocked(m, scan.origin, scan.angles[k], fine) - got[k]) <= 1e-8 + TOL
        refined += 1
    assert refined <= 0.05 * len(got)
    assert np.all((scan.hit == HIT_KNOWN) == np.isfinite(got))
    assert np.all(scan.ranges[scan.hit == HIT_NOTHING] == R)
    return refined


@pytest.mark.parametrize("yaw", [0.0, 0.35, -2.0])
def test_synthetic_grid_matches_brute_force(rng, yaw):
    occ = rng.random((40, 60)) < 0.08
    grid = OccupancyGrid(occ, 0.1, (1.0, -2.0, yaw))
    m = world(grids=[grid], bounds=(-6.0, -8.0, 9.0, 7.0))
    R = 4.0
    sensor = RangeSensor(m, SensorOptions(range_m=R, fov_rad=2 * math.pi, resolution_rad=math.radians(3)))
    poses = 0
    while poses < 6:
        p = rng.uniform([-6, -8, -np.pi], [9, 7, np.pi])
        i, j = grid.world_to_cell(p[0], p[1])
        if 0 <= i < 40 and 0 <= j < 60 and occ[i, j]:
            continue
        poses += 1
        scan = sensor.scan(p)
        check_against_brute_force(m, scan, R)


def test_grid_beams_along_grid_lines_and_through_corners():
    # axis-aligned beams along cell boundaries and diagonals through cell corners
    occ = np.zeros((10, 10), bool)
    occ[5, 8] = occ[8, 5] = occ[8, 8] = True
    grid = OccupancyGrid(occ, 0.5, (0.0, 0.0, 0.0))
    m = world(grids=[grid], bounds=(0.0, 0.0, 5.0, 5.0))
    sensor = RangeSensor(m, SensorOptions(range_m=10.0, fov_rad=2 * math.pi, resolution_rad=math.pi / 4))
    # from the centre of cell (5, 5); the 8 beams lie at heading + 22.5 + 45 k deg: on 0, 45, 90, ...
    scan = sensor.scan((2.75, 2.75, math.pi / 8))
    ranges = dict(zip(np.round(np.degrees(scan.angles) % 360).astype(int), scan.ranges, strict=True))
    assert ranges[0] == pytest.approx(1.25, abs=TOL)                 # face of cell (5, 8)
    assert ranges[90] == pytest.approx(1.25, abs=TOL)                # face of cell (8, 5)
    assert ranges[45] == pytest.approx(1.25 * math.sqrt(2), abs=TOL)  # corner of cell (8, 8)
    assert ranges[180] == pytest.approx(2.75, abs=TOL)               # map boundary
    check_against_brute_force(m, scan, 10.0)


def test_depot_map_matches_brute_force(rng):
    m = load_map(MAPS / "nav2" / "depot.yaml")
    g = m.grids[0]
    sensor = RangeSensor(m)
    poses = 0
    while poses < 3:
        p = rng.uniform([2.0, 2.0, -np.pi], [28.0, 13.0, np.pi])
        i, j = g.world_to_cell(p[0], p[1])
        if g.occupied[max(i - 4, 0):i + 5, max(j - 4, 0):j + 5].any():     # a free spot, 0.2 m clear
            continue
        poses += 1
        scan = sensor.scan(p)
        assert np.mean(scan.hit == HIT_KNOWN) > 0.2                       # the walls are seen
        check_against_brute_force(m, scan, sensor.range_m)


# --------------------------------------------------------------------------------------------------
# The bundled warehouse map


def test_warehouse_pallets_revealed_from_aisle_a2_only():
    m = load_map(MAPS / "ours" / "warehouse_corridor.yaml")
    assert len(m.unknown_obstacles) == 2
    pallets = m.unknown_obstacles[0]                         # x 15.4..16.6, y 14..18
    assert pallets.bounds() == pytest.approx((15.4, 14.0, 16.6, 18.0), abs=TOL)
    sensor = RangeSensor(m)
    in_a2 = sensor.scan((10.0, 16.0, 0.0))                   # aisle A2 (y 13.5..18.5), looking +x
    assert 0 in in_a2.revealed
    assert in_a2.ranges[in_a2.hit == 0].min() == pytest.approx(5.4, abs=1e-3)
    assert sensor.scan((10.0, 16.0, math.pi)).revealed == set()     # looking back: out of the fov
    start = m.start                                          # a Pose is accepted as well as (x, y, theta)
    assert sensor.scan(start).revealed == set()
    assert np.array_equal(sensor.scan(start).pose, m.start.as_array())
    # hidden by the rack row between aisles A1 and A2 even with unlimited range and a full circle
    wide = RangeSensor(m, SensorOptions(range_m=100.0, fov_rad=2 * math.pi))
    assert 0 not in wide.scan(start).revealed


@pytest.mark.parametrize("yaw", [0.0, 0.6])
def test_single_free_cell_ranges_are_its_boundary(rng, yaw):
    # every cell occupied but one: each beam ends where it leaves that cell (slab distance in the
    # grid frame), wherever the origin lies in the cell, whatever the beam direction
    occ = np.ones((5, 5), bool)
    occ[2, 2] = False
    res = 0.2
    grid = OccupancyGrid(occ, res, (-1.0, 3.0, yaw))
    sensor = RangeSensor(world(grids=[grid]), SensorOptions(fov_rad=2 * math.pi, resolution_rad=math.radians(1)))
    c, s = math.cos(yaw), math.sin(yaw)
    for _ in range(20):
        uv = rng.uniform(2 * res + 1e-6, 3 * res - 1e-6, 2)        # grid frame, inside cell (2, 2)
        o = np.array([-1.0 + c * uv[0] - s * uv[1], 3.0 + s * uv[0] + c * uv[1]])
        scan = sensor.scan((*o, rng.uniform(-np.pi, np.pi)))
        ref = np.array([_exit(uv, a - yaw, (2 * res, 2 * res, 3 * res, 3 * res)) for a in scan.angles])
        assert np.allclose(scan.ranges, ref, atol=TOL, rtol=0)
        assert np.all(scan.hit == HIT_KNOWN)
