"""Cars (and the unicycle) in tight spaces: thin obstacles (lines, polylines, polygons of zero area),
the full steering range where the reserved lock finds nothing, and tight starts in winding passages.

Every geometric claim is checked against shapely; every scene is generated here (seeded), not taken
from a bundled map.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from nhstab.collision import CollisionWorld
from nhstab.errors import InputError
from nhstab.geometry import Footprint
from nhstab.maps.base import Map, MapError, Polygon, polyline
from nhstab.maps.svg import load_benchmr_svg
from nhstab.maps.yaml_format import parse_yaml_map
from nhstab.parking import _geometry, cars, case_yaml, parallel_case, parallel_min_length
from nhstab.planning import CarOptions, PathOptions, plan
from nhstab.robot import default_robot, make_robot, robot_from_spec
from shapely.geometry import LineString, Point
from shapely.geometry import Polygon as SPolygon
from shapely.ops import unary_union

CAR = Footprint.rectangle(4.2, 1.8, 0.9)
DISC = Footprint.disc(0.3)


def reference(shape: Polygon):
    """The obstacle's point set in shapely, built from its vertices alone: the ring's edges that are
    traversed once bound an area, those traversed out and back are lines (independent of ring_parts:
    shapely's polygonize of the edges, and the edges themselves)."""
    v = np.asarray(shape.vertices, dtype=float)
    edges = [LineString([v[i], v[(i + 1) % len(v)]]) for i in range(len(v)) if not np.array_equal(v[i], v[(i + 1) % len(v)])]
    lines = unary_union(edges)
    if len(v) >= 3:
        ring = SPolygon(v).buffer(0)          # the area enclosed (empty for a ring of zero area)
        if ring.area > 1e-12:
            return unary_union([ring, lines])
    return lines


# ---------------------------------------------------------------------------------------------
# item 1: thin obstacles
# ---------------------------------------------------------------------------------------------
THIN_YAML = """bounds: [0, 0, 30, 20]
obstacles:
  - line: [[2, 2], [12, 2]]                          # a curb: two points
  - line: [[2, 5], [8, 5], [8, 9], [8, 9], [4, 12]]  # a polyline (a repeated point dropped)
  - polygon: [[14, 2], [18, 2], [22, 2]]             # collinear points: zero area
  - polygon: [[14, 6], [20, 6], [20, 9], [20, 6]]    # folds onto itself: zero area
  - polygon: [[22, 10], [26, 10], [26, 12], [28, 12], [26, 12], [26, 14], [22, 14]]   # a spike drawn out and back
  - line: [[2, 15], [8, 19], [2, 19], [8, 15]]       # a polyline that crosses itself
start: [10, 8, 0]
"""


def test_yaml_lines_and_degenerate_polygons_load_as_thin_obstacles():
    m = parse_yaml_map(THIN_YAML, "thin.yaml")
    assert len(m.obstacles) == 6
    thin = [s.thin for s in m.obstacles]
    assert thin == [True, True, True, True, False, True]
    for shape in m.obstacles:
        area, segments = shape.parts
        mine = unary_union([LineString(s) for s in segments] + ([SPolygon(area)] if area is not None else []))
        ref = reference(shape)
        assert mine.symmetric_difference(ref).area < 1e-12 and mine.hausdorff_distance(ref) < 1e-12
    spike = m.obstacles[4]
    assert spike.parts.area is not None and SPolygon(spike.parts.area).area == pytest.approx(16.0)
    assert [s.tolist() for s in spike.parts.segments] == [[[26.0, 12.0], [28.0, 12.0]]]
    notes = " ".join(m.meta["notes"])
    assert "obstacles[2].polygon: zero area" in notes and "obstacles[4].polygon: 1 segment(s) drawn out and back" in notes
    # the start check sees a thin obstacle too: a reference point on a curb is refused
    with pytest.raises(MapError, match=r"thin.yaml: start"):
        parse_yaml_map(THIN_YAML.replace("start: [10, 8, 0]", "start: [5, 2, 0]"), "thin.yaml")


@pytest.mark.parametrize("entry,key", [
    ("line: [[1, 1]]", "obstacles[0].line"),
    ("line: [[1, 1], [1, 1]]", "obstacles[0].line"),
    ("line: [[1, 1], [.nan, 2]]", "obstacles[0].line[1][0]"),
    ("line: {a: 1}", "obstacles[0].line"),
    ("polygon: [[1, 1], [3, 1]]", "obstacles[0].polygon"),
    ("polygon: [[1, 1], [3, 3], [3, 1], [1, 3]]", "obstacles[0].polygon"),      # a bow tie still crosses itself
])
def test_thin_obstacle_errors_are_one_line_naming_the_key(entry, key):
    with pytest.raises(InputError) as ei:
        parse_yaml_map(f"bounds: [0, 0, 10, 10]\nobstacles:\n  - {entry}\n", "bad.yaml")
    msg = str(ei.value)
    assert f"bad.yaml: {key}" in msg and "\n" not in msg


def test_svg_lines_and_zero_area_paths_are_thin_obstacles(tmp_path):
    svg = tmp_path / "thin.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg">'
                   '<path d="M 0 0 L 220 0"/>'                      # a line: two points, no area
                   '<path d="M 0 100 L 110 100 L 220 100 Z"/>'      # collinear points
                   '<path d="M 0 200 L 220 200 L 220 300 L 0 300 Z"/>'   # an ordinary polygon
                   '</svg>')
    m = load_benchmr_svg(svg)
    assert [s.thin for s in m.obstacles] == [True, True, False]
    assert any("thin" in n for n in m.meta["notes"])
    for shape in m.obstacles:
        area, segments = shape.parts
        mine = unary_union([LineString(s) for s in segments] + ([SPolygon(area)] if area is not None else []))
        assert mine.hausdorff_distance(reference(shape)) < 1e-12
    hull = load_benchmr_svg(svg, convex_hull=True)
    assert [s.thin for s in hull.obstacles] == [True, True, False]


def _thin_shapes(rng, n=6):
    shapes = []
    for k in range(n):
        p0 = rng.uniform(2, 18, 2)
        pts = [p0]
        for _ in range(int(rng.integers(1, 4))):
            pts.append(pts[-1] + rng.normal(0, 2.5, 2))
        if k % 3 == 2:          # axis-aligned (the distance field's raster lines)
            pts = [p0, p0 + [rng.uniform(0.3, 6), 0.0]]
        shapes.append(polyline(np.clip(pts, 0.5, 19.5)))
    shapes.append(Polygon(np.array([[5.0, 1.0], [9.0, 1.0], [13.0, 1.0]])))                  # collinear polygon
    shapes.append(Polygon(np.array([[14.0, 14.0], [18.0, 14.0], [18.0, 17.0], [18.0, 14.0]])))  # folded
    return shapes


@pytest.mark.parametrize("fp", [CAR, DISC], ids=["car", "disc"])
def test_thin_obstacles_fcl_distance_field_and_batches_agree_with_shapely(fp):
    rng = np.random.default_rng(11)
    shapes = _thin_shapes(rng)
    world = CollisionWorld(shapes, bounds=(0.0, 0.0, 20.0, 20.0), walls=False)
    ref = unary_union([reference(s) for s in shapes])
    poses = np.column_stack([rng.uniform(1, 19, 600), rng.uniform(1, 19, 600), rng.uniform(-math.pi, math.pi, 600)])

    def body(p):
        return Point(p[0], p[1]).buffer(fp.radius, 512) if fp.radius is not None else SPolygon(fp.outline_at(p))

    dist = np.array([body(p).distance(ref) for p in poses])
    hits = np.array([body(p).intersects(ref) for p in poses])
    assert 20 < hits.sum() < 580, "the poses must test both sides"
    tol = 2e-5 if fp.radius is not None else 1e-9          # shapely's disc is a 512-gon
    sure = (dist > tol) | (hits & np.array([body(p).intersection(ref).length > 1e-6 for p in poses]))
    coll = np.array([world.in_collision(p, fp) for p in poses])
    assert np.array_equal(coll[sure], hits[sure])
    clear = np.array([world.clearance(p, fp) for p in poses])
    apart = ~hits & (dist > tol)
    assert np.allclose(clear[apart], dist[apart], atol=tol)
    assert np.all(clear[hits & sure] < 0)
    assert np.allclose(world.clearance_many(poses, fp)[apart], dist[apart], atol=tol)
    for margin in (0.0, 0.1, 0.3):
        decided = np.abs(dist - margin) > tol
        truth = (dist > margin) & ~hits
        assert np.array_equal(world.free_many(poses, fp, margin)[decided], truth[decided])
        assert all(world.is_free(p, fp, margin) == t for p, t, d in zip(poses, truth, decided) if d)
    # the distance field is a lower bound of the distance to the thin obstacles everywhere
    field = world.clearance_field()
    pts = rng.uniform(0, 20, (4000, 2))
    d_pts = np.array([Point(*q).distance(ref) for q in pts])
    assert np.all(field.at(pts[:, 0], pts[:, 1]) <= d_pts + 1e-12)
    # the minimum along a path, exact without measuring every pose
    best, k = world.min_clearance(poses[:80], fp)
    assert best == pytest.approx(float(np.min(clear[:80])), abs=tol)


def test_penetration_depth_of_a_line_is_exact():
    """FCL's EPA gave 6.3 m for a car straddling a curb lengthwise (the true depth is half its width):
    a thin obstacle's depth is the plane's, the shortest translation that separates them."""
    world = CollisionWorld([polyline([[0.0, 5.0], [10.0, 5.0]])], bounds=(-1.0, 0.0, 20.0, 10.0))
    for dy in (0.0, 0.3, -0.5):
        assert world.clearance((3.0, 5.0 + dy, 0.0), CAR) == pytest.approx(-(0.9 - abs(dy)), abs=1e-12)
    # across: the line runs through the car from side to side; the depth is the shorter way out
    for x in (2.0, 4.0, 5.5):
        expected = min(5.0 - (x - 0.9), (x + 3.3) - 5.0)        # back or ahead off the line
        w2 = CollisionWorld([polyline([[5.0, 0.5], [5.0, 9.5]])], bounds=(-1.0, 0.0, 20.0, 10.0))
        assert w2.clearance((x, 5.0, 0.0), CAR) == pytest.approx(-expected, abs=1e-12)


@pytest.mark.slow
def test_a_thin_obstacle_is_never_passed_between_checked_samples():
    """Motions sampled so that no footprint point moves more than delta between samples: wherever the
    checks find every sample free by delta/2 (and a millimetre), the motion sampled every 2 mm never
    touches a line (its clearance drops by at most delta/2 between samples, thin or not); wherever it
    does touch one, the checks find a sample that is not free."""
    rng = np.random.default_rng(5)
    delta = 0.05
    reach = CAR.bounding_radius
    touched = flagged = 0
    for trial in range(60):
        a = rng.uniform(6, 14, 2)
        line = polyline([a, a + rng.normal(0, 0.4, 2)])           # short lines: the hardest to hit
        world = CollisionWorld([line], bounds=(0.0, 0.0, 20.0, 20.0))
        ref = reference(line)
        x0 = np.r_[a + rng.normal(0, 3.5, 2), rng.uniform(-math.pi, math.pi)]
        kappa, direction = rng.uniform(-0.27, 0.27), rng.choice([-1, 1])
        length = 6.0
        ds = delta / (1 + reach * abs(kappa))
        s = np.linspace(0, length, int(math.ceil(length / ds)) + 1)
        dense = np.linspace(0, length, int(length / 0.002) + 1)

        def arc(sig):
            th = x0[2] + direction * kappa * sig
            chord = direction * sig * np.sinc(kappa * sig / (2 * np.pi))
            mid = x0[2] + direction * kappa * sig / 2
            return np.column_stack([x0[0] + chord * np.cos(mid), x0[1] + chord * np.sin(mid), th])

        poses, fine = arc(s), arc(dense)
        ok = world.motion_free(poses, CAR, delta / 2 + 1e-3)
        assert ok == bool(world.free_many(poses, CAR, delta / 2 + 1e-3).all())
        d = min(SPolygon(CAR.outline_at(p)).distance(ref) for p in fine[::1])
        if ok:
            assert d > 0.0
        if d == 0.0:
            touched += 1
            flagged += not ok
    assert touched > 5 and flagged == touched


def _curb_case(factor: float):
    """A parallel slot of the suite's layout whose curb is drawn as a line (YAML ``line``)."""
    spec = cars()["rwd_car"]
    case = parallel_case("rwd_car", spec, factor)
    text = case_yaml(case)
    curb = next(line for line in text.splitlines() if line.endswith("# curb and sidewalk"))
    text = text.replace(curb, f"  - line: [[0.0, 0.0], [{case.bounds[2]}, 0.0]]   # the curb, a line")
    return parse_yaml_map(text, "curb_line.yaml")


@pytest.mark.parametrize("factor", [1.0, 1.2])
def test_a_car_parks_against_a_curb_drawn_as_a_line(factor):
    m = _curb_case(factor)
    assert m.obstacles[0].thin
    robot = robot_from_spec(m.robot, source="map")
    r = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(time_limit_s=10.0))
    assert r.ok, r.message
    x = r.nominal.x
    assert np.allclose(x[-1, :3], m.goal.as_array(), atol=1e-6)
    curb = LineString([(0.0, 0.0), (m.bounds[2], 0.0)])
    others = unary_union([SPolygon(s.vertices) for s in m.obstacles[1:]])
    # every 2 mm of the path's footprint motion: the nominal's samples, densified
    t = np.linspace(r.nominal.t[0], r.nominal.t[-1], 6000)
    poses = np.column_stack([np.interp(t, r.nominal.t, x[:, k]) for k in range(3)])
    d_curb = np.array([SPolygon(robot.footprint.outline_at(p)).distance(curb) for p in poses])
    d_rest = np.array([SPolygon(robot.footprint.outline_at(p)).distance(others) for p in poses])
    assert d_curb.min() >= robot.margin - 0.02 and d_rest.min() >= robot.margin - 0.02
    assert d_curb.min() == pytest.approx(r.metrics["min_clearance_m"], abs=0.02) or \
        d_rest.min() == pytest.approx(r.metrics["min_clearance_m"], abs=0.02)
    assert min(d_curb.min(), d_rest.min()) >= r.metrics["min_clearance_m"] - 0.02


# ---------------------------------------------------------------------------------------------
# item 2: the full steering range where the reserved lock finds nothing
# ---------------------------------------------------------------------------------------------
def _between_single_maneuver_minima():
    """A parallel slot shorter than the single-maneuver minimum at the reserved lock and longer than
    the one at the full lock (both with the car's margin; nhstab.parking.parallel_min_length)."""
    spec = cars()["rwd_car"]
    g = _geometry(spec)
    m_ = spec["margin"]
    r_lock = g.wheelbase / math.tan(spec["max_steer"] - CarOptions().steering_reserve_rad)
    full, reserved = parallel_min_length(g, m_), parallel_min_length(g, m_, r_lock)
    slot = 0.5 * (full + reserved)
    case = parallel_case("rwd_car", spec, slot / parallel_min_length(g))
    assert full < case.size_m < reserved
    return parse_yaml_map(case_yaml(case), "between.yaml"), spec


def _no_reserve_times(r, max_steer, reserve):
    phi = np.abs(r.nominal.x[:, 3])
    return r.nominal.t[phi > max_steer - reserve + 1e-9]


def test_slot_between_the_single_maneuver_minima_plans_within_max_steer():
    m, spec = _between_single_maneuver_minima()
    robot = robot_from_spec(m.robot, source="map")
    r = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(time_limit_s=10.0))
    assert r.ok, r.message
    phi = np.abs(r.nominal.x[:, 3])
    assert phi.max() <= spec["max_steer"] + 1e-9
    sr = r.metrics["steering_reserve"]
    # the reserved lock finds a way (several maneuvers): the full range is not used, and it says so
    assert sr["lock"]["radius_m"] == pytest.approx(2.5 / math.tan(0.55))
    assert sr["full_range_used"] is False and sr["no_reserve_intervals_s"] == []
    assert phi.max() <= spec["max_steer"] - 0.05 + 1e-9


def test_full_steering_range_only_where_the_reserved_lock_finds_nothing():
    """One maneuver only (one arc per unparking sequence, no shuffle): at the reserved lock the slot
    cannot be left in one maneuver (it is shorter than that minimum), at the full lock it can. The
    planner falls back to the full range there, records it, and stays within max_steer."""
    m, spec = _between_single_maneuver_minima()
    robot = robot_from_spec(m.robot, source="map")
    opts = CarOptions(max_arcs=1, shuffle_expansions=1)
    r = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(time_limit_s=10.0), car_opts=opts)
    assert r.ok, r.message
    max_steer, reserve = spec["max_steer"], opts.steering_reserve_rad
    phi = np.abs(r.nominal.x[:, 3])
    assert max_steer - reserve + 1e-6 < phi.max() <= max_steer + 1e-9
    sr = r.metrics["steering_reserve"]
    assert sr["full_range_used"] is True and sr["lock"]["full_range"] is True
    assert "goal" in sr["lock"]["widened"]
    assert sr["lock"]["full_range_radius_m"] == pytest.approx(2.5 / math.tan(0.6))
    # the intervals without reserve are exactly the nominal's times beyond the reserved lock
    times = _no_reserve_times(r, max_steer, reserve)
    ivals = np.array(sr["no_reserve_intervals_s"])
    assert len(ivals) >= 1 and ivals[0, 0] == times[0] and ivals[-1, 1] == times[-1]
    inside = np.zeros(len(r.nominal.t), dtype=bool)
    for a, b in ivals:
        inside |= (r.nominal.t >= a) & (r.nominal.t <= b)
    assert np.array_equal(inside, phi > max_steer - reserve + 1e-9)
    assert sr["no_reserve_time_s"] == pytest.approx(float(np.sum(ivals[:, 1] - ivals[:, 0])))
    # the full range off: the reserved lock's one maneuver finds no way out of the slot
    off = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(time_limit_s=3.0),
               car_opts=CarOptions(max_arcs=1, shuffle_expansions=1, full_range=False))
    assert not off.ok or np.abs(off.nominal.x[:, 3]).max() <= max_steer - reserve + 1e-9


# ---------------------------------------------------------------------------------------------
# item 3: winding passages among polygons, 0.15 m clearance at the start
# ---------------------------------------------------------------------------------------------
def _offset(P, d):
    """A polyline offset by d to its left, mitred at its corners."""
    t = np.diff(P, axis=0)
    t /= np.hypot(t[:, 0], t[:, 1])[:, None]
    n = np.column_stack([-t[:, 1], t[:, 0]])
    out = [P[0] + d * n[0]]
    for i in range(1, len(P) - 1):
        out.append(P[i] + d * (n[i - 1] + n[i]) / (1 + n[i - 1] @ n[i]))
    out.append(P[-1] + d * n[-1])
    return np.array(out)


def winding_passage(robot, width: float, leg: float, seed: int, clearance: float = 0.15):
    """A passage of ``width`` winding left and right (6 legs of ``leg`` m, random turns of 0.5-0.8
    rad), its walls two non-convex polygons 1 m thick; the start on the first leg, heading along it,
    moved sideways until its clearance is ``clearance`` (bisection on the exact clearance); the goal
    on the last leg."""
    rng = np.random.default_rng(seed)
    P, ang = [np.zeros(2)], 0.0
    for k in range(6):
        P.append(P[-1] + leg * np.array([math.cos(ang), math.sin(ang)]))
        ang += (-1) ** k * rng.uniform(0.5, 0.8)
    P = np.array(P)
    walls = [Polygon(np.vstack([_offset(P, s * width / 2), _offset(P, s * (width / 2 + 1.0))[::-1]])) for s in (1, -1)]
    allv = np.vstack([w.vertices for w in walls])
    m = Map("winding", (*(allv.min(0) - 1.0), *(allv.max(0) + 1.0)), tuple(walls))
    world = CollisionWorld.from_map(m)
    t0 = (P[1] - P[0]) / np.hypot(*(P[1] - P[0]))
    n0 = np.array([-t0[1], t0[0]])
    base = P[0] + 0.25 * leg * t0 - (1.0 if robot.model.name != "unicycle" else 0.0) * t0
    th = math.atan2(t0[1], t0[0])
    lo, hi = 0.0, width / 2
    for _ in range(80):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if world.clearance(np.r_[base - mid * n0, th], robot.footprint) > clearance else (lo, mid)
    start = np.r_[base - lo * n0, th]
    tl = P[-1] - P[-2]
    goal = np.r_[P[-2] + 0.6 * tl, math.atan2(tl[1], tl[0])]
    return m, world, start, goal


def _shapely_clearance(m, fp, poses):
    walls = unary_union([SPolygon(s.vertices) for s in m.obstacles])
    body = (lambda p: Point(p[0], p[1]).buffer(fp.radius, 256)) if fp.radius is not None else \
        (lambda p: SPolygon(fp.outline_at(p)))
    return np.array([body(p).distance(walls) for p in poses])


@pytest.mark.parametrize("kind,seed", [("unicycle", s) for s in range(10)] + [("car", s) for s in range(3)])
def test_winding_passage_with_a_start_015_m_from_a_wall(kind, seed):
    robot = default_robot("unicycle") if kind == "unicycle" else make_robot("rwd_car", margin=0.1)
    width, leg = (1.0, 3.0) if kind == "unicycle" else (4.6, 11.0)
    m, world, start, goal = winding_passage(robot, width, leg, seed)
    assert _shapely_clearance(m, robot.footprint, [start])[0] == pytest.approx(0.15, abs=2e-4 if kind == "unicycle" else 1e-9)
    r = plan(m, robot, start, goal, PathOptions(time_limit_s=10.0, margin=0.1), world=world)
    assert r.ok, r.message
    poses = r.nominal.x[:, :3]
    # (the unicycle's nominal integrates its speed profile: it ends within a couple of centimetres of the goal)
    end = poses[-1] - goal
    end[2] = (end[2] + math.pi) % (2 * math.pi) - math.pi
    assert np.allclose(poses[0], start, atol=1e-9) and np.abs(end).max() <= (1e-6 if kind == "car" else 0.02)
    sample = poses[:: max(1, len(poses) // 1500)]
    tol = 2e-4 if kind == "unicycle" else 1e-9          # shapely's disc is a polygon
    assert _shapely_clearance(m, robot.footprint, sample).min() >= 0.1 - tol
