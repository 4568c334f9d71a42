"""FCL collision worlds against independent geometry (shapely) and constructed cases."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from nhstab.collision import CollisionWorld, grid_rectangles
from nhstab.geometry import Footprint
from nhstab.maps.base import Circle, Map, OccupancyGrid, Polygon, box_polygon
from shapely.geometry import Point, box
from shapely.geometry import Polygon as SPolygon
from shapely.ops import unary_union

L_SHAPE = Polygon(np.array([[2, 2], [6, 2], [6, 3], [3, 3], [3, 6], [2, 6]], float))
POLY_MAP = Map("poly", (0, 0, 10, 10), obstacles=(L_SHAPE, Circle((7, 7), 1.0), box_polygon(8, 2, 1.5, 0.8, 0.6)))


def _reference_clearance(m: Map, fp: Footprint, pose) -> float:
    """Unsigned clearance by shapely: footprint vs obstacles and the bounds' walls (0 if overlapping)."""
    x, y = pose[0], pose[1]
    geoms = [SPolygon(o.vertices) for o in m.obstacles if isinstance(o, Polygon)]
    circles = [o for o in m.obstacles if isinstance(o, Circle)]
    xmin, ymin, xmax, ymax = m.bounds
    if fp.radius is not None:
        d = [Point(x, y).distance(g) - fp.radius for g in geoms]
        d += [np.hypot(x - c.center[0], y - c.center[1]) - c.radius - fp.radius for c in circles]
        d += [x - fp.radius - xmin, y - fp.radius - ymin, xmax - x - fp.radius, ymax - y - fp.radius]
    else:
        shape = SPolygon(fp.outline_at(pose))
        d = [shape.distance(g) for g in geoms]
        d += [shape.distance(Point(*c.center)) - c.radius for c in circles]
        bx = shape.bounds
        d += [bx[0] - xmin, bx[1] - ymin, xmax - bx[2], ymax - bx[3]]
    return max(0.0, min(d))


@pytest.mark.parametrize("fp", [Footprint.rectangle(1.2, 0.6, rear_overhang=0.3), Footprint.disc(0.35),
                                Footprint.polygon([[0, 0], [1, 0], [1, 0.2], [0.2, 0.2], [0.2, 0.8], [0, 0.8]])],
                         ids=["car-rectangle", "disc", "non-convex"])
def test_clearance_matches_shapely_on_polygon_map(fp, rng):
    world = CollisionWorld.from_map(POLY_MAP)
    checked = 0
    for _ in range(300):
        pose = np.array([rng.uniform(0, 10), rng.uniform(0, 10), rng.uniform(-np.pi, np.pi)])
        ref = _reference_clearance(POLY_MAP, fp, pose)
        c = world.clearance(pose, fp)
        if ref > 1e-9:
            assert abs(c - ref) < 1e-6, (pose, c, ref)
            assert world.is_free(pose, fp)
            checked += 1
        else:
            assert c <= 1e-9 and not world.is_free(pose, fp)
        for margin in (0.05, 0.3):                   # the inflated-footprint decisions, against shapely
            if abs(ref - margin) > 1e-6:
                assert world.is_free(pose, fp, margin) == (ref > margin), (pose, margin, ref)
    assert checked > 100


def test_clearance_on_grid_matches_union_of_cells(rng):
    occ = np.zeros((40, 60), dtype=bool)
    occ[10:14, 5:50] = True
    occ[20:35, 30:33] = True
    occ[rng.integers(0, 40, 30), rng.integers(0, 60, 30)] = True
    grid = OccupancyGrid(occ, resolution=0.25, origin=(-3.0, 1.0, 0.0))
    m = Map("grid", grid.bounds(), grids=(grid,))
    world = CollisionWorld.from_map(m)
    cells = unary_union([box(*grid.cell_to_world(i, j), *grid.cell_to_world(i, j)).buffer(0.125, cap_style=3)
                         for i, j in zip(*np.nonzero(occ))])
    fp = Footprint.rectangle(0.8, 0.4, rear_overhang=0.2)
    xmin, ymin, xmax, ymax = m.bounds
    for _ in range(150):
        pose = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax), rng.uniform(-3, 3)])
        shape = SPolygon(fp.outline_at(pose))
        b = shape.bounds
        ref = max(0.0, min(shape.distance(cells), b[0] - xmin, b[1] - ymin, xmax - b[2], ymax - b[3]))
        # exact against the cell geometry (well inside the one-cell-size tolerance of the issue)
        assert abs(world.clearance(pose, fp) - ref) < 1e-6 if ref > 1e-9 else world.clearance(pose, fp) <= 1e-9


def test_rotated_grid_is_placed_by_its_origin_yaw():
    occ = np.zeros((4, 4), dtype=bool)
    occ[0, 3] = True            # lower-right cell in the grid frame
    grid = OccupancyGrid(occ, resolution=1.0, origin=(10.0, 0.0, np.pi / 2))
    world = CollisionWorld([], (grid,), bounds=None)
    # the cell's centre (3.5, 0.5) in the grid frame is at (10 - 0.5, 3.5) in the world
    dot = Footprint.disc(0.05)
    assert world.in_collision((9.5, 3.5, 0.0), dot)
    assert not world.in_collision((9.5, 0.5, 0.0), dot)


@settings(max_examples=60, deadline=None)
@given(occ=arrays(bool, st.tuples(st.integers(1, 25), st.integers(1, 25))))
def test_grid_rectangles_cover_exactly(occ):
    covered = np.zeros(occ.shape, dtype=int)
    for i0, j0, i1, j1 in grid_rectangles(occ):
        covered[i0:i1, j0:j1] += 1
    np.testing.assert_array_equal(covered, occ.astype(int))


def test_grid_merging_keeps_boxes_few():
    occ = np.zeros((512, 512), dtype=bool)
    occ[::64, :] = True
    occ[:, ::64] = True
    assert len(grid_rectangles(occ)) < 600         # 262144 cells, 64512 occupied


def test_path_check_finds_conflict_between_samples():
    wall = box_polygon(5.0, 5.0, 0.1, 3.0)           # a 10 cm thick wall across the path at x = 5
    m = Map("wall", (0, 0, 10, 10), obstacles=(wall,))
    world = CollisionWorld.from_map(m)
    fp = Footprint.disc(0.05)
    path = np.array([[1.0, 5.0, 0.0], [9.0, 5.0, 0.0]])     # the two given samples are both free
    assert world.is_free(path[0], fp) and world.is_free(path[1], fp)
    coarse = world.check_path(path, fp, resolution=8.0)
    assert coarse.clear                                      # too coarse to see it: only the end points
    fine = world.check_path(path, fp, resolution=0.05)
    assert not fine.clear and fine.first_conflict_segment == 0
    assert 4.8 <= fine.first_conflict_pose[0] <= 5.0
    assert fine.min_clearance < 0


def test_path_clear_by_margin():
    m = Map("corridor", (0, 0, 20, 4), obstacles=(box_polygon(10, 3.5, 20, 1.0), box_polygon(10, 0.5, 20, 1.0)))
    world = CollisionWorld.from_map(m)
    fp = Footprint.rectangle(1.0, 0.6, rear_overhang=0.2)
    path = np.array([[1.0, 2.0, 0.0], [10.0, 2.0, 0.0], [18.0, 2.0, 0.0]])
    res = world.check_path(path, fp, margin=0.5, resolution=0.1)
    # the footprint is 0.3 m from y = 2 on each side; the walls are at y = 1 and y = 3: clearance 0.7
    assert res.clear and abs(res.min_clearance - 0.7) < 1e-9
    assert not world.check_path(path, fp, margin=0.75, resolution=0.1).clear
    assert world.is_free(path[1], fp, margin=0.69) and not world.is_free(path[1], fp, margin=0.71)


def test_known_unknown_and_discovered_obstacles():
    hidden = box_polygon(5, 5, 1, 1)
    m = Map("m", (0, 0, 10, 10), obstacles=(Circle((2, 2), 0.5),), unknown_obstacles=(hidden,))
    fp = Footprint.disc(0.2)
    known = CollisionWorld.from_map(m, "known")
    real = CollisionWorld.from_map(m, "all")
    assert known.is_free((5, 5, 0), fp) and not real.is_free((5, 5, 0), fp)
    assert not known.with_obstacles([hidden]).is_free((5, 5, 0), fp)
    assert not known.is_free((2, 2, 0), fp) and CollisionWorld.from_map(m, "unknown").is_free((2, 2, 0), fp)


def test_penetration_depth_is_negative_clearance():
    m = Map("m", (0, 0, 10, 10), obstacles=(box_polygon(5, 5, 2, 2),))
    world = CollisionWorld.from_map(m)
    fp = Footprint.disc(0.5)
    # disc centre 0.3 m inside the box's left face: overlap depth 0.8 m
    assert world.clearance((4.3, 5.0, 0.0), fp) == pytest.approx(-0.8, abs=1e-4)


REAL_MAPS = [("movingai/64room_000.map", {"cell_size": 0.5}), ("nav2/depot.yaml", {}),
             ("nav2/tb3_sandbox.yaml", {}), ("bench-mr/polygon_mazes/parking2.svg", {}),
             ("ours/cluttered_room.yaml", {}), ("ours/parking_lot.yaml", {})]


@pytest.mark.parametrize("path,options", REAL_MAPS, ids=[p for p, _ in REAL_MAPS])
def test_batched_checks_equal_single_checks_on_real_maps(path, options, rng):
    """The distance-field prefilter of free_many only ever decides what FCL would."""
    from pathlib import Path

    from nhstab.maps import load_map
    from nhstab.robot import default_footprint

    m = load_map(Path(__file__).parents[2] / "maps" / path, **options)
    world = CollisionWorld.from_map(m)
    xmin, ymin, xmax, ymax = m.bounds
    poses = np.column_stack([rng.uniform(xmin, xmax, 1500), rng.uniform(ymin, ymax, 1500), rng.uniform(-4, 4, 1500)])
    for fp in (default_footprint("rwd_car"), Footprint.disc(0.3)):
        for margin in (0.0, 0.2):
            single = np.array([world.is_free(p, fp, margin) for p in poses])
            np.testing.assert_array_equal(world.free_many(poses, fp, margin), single)
            check = world.state_checker(fp, margin)        # the planner's scalar checker
            np.testing.assert_array_equal(np.array([check(*p) for p in poses]), single)


ROOMY_MAPS = [REAL_MAPS[1], REAL_MAPS[3], REAL_MAPS[5]]        # the car fits in many places


@pytest.mark.parametrize("path,options", ROOMY_MAPS, ids=[p for p, _ in ROOMY_MAPS])
def test_batched_checks_along_paths_equal_single_checks(path, options, rng):
    """Along a path free_many lets a measured clearance vouch for the next poses: same answers."""
    from pathlib import Path

    from nhstab.maps import load_map
    from nhstab.robot import default_footprint

    m = load_map(Path(__file__).parents[2] / "maps" / path, **options)
    world = CollisionWorld.from_map(m)
    xmin, ymin, xmax, ymax = m.bounds
    for fp in (default_footprint("rwd_car"), Footprint.disc(0.3)):
        for margin in (0.0, 0.2):
            for _ in range(3):          # random walks with steps of a few millimetres, from near an obstacle
                start = [xmin - 1, ymin - 1, 0.0]
                while not (world.is_free(start, fp, margin) and world.distance(start, fp) < margin + 0.4):
                    start = [rng.uniform(xmin, xmax), rng.uniform(ymin, ymax), rng.uniform(-4, 4)]
                poses = start + np.cumsum(rng.normal(0.0, [0.004, 0.004, 0.002], (400, 3)), axis=0)
                single = np.array([world.is_free(p, fp, margin) for p in poses])
                np.testing.assert_array_equal(world.free_many(poses, fp, margin), single)


@pytest.mark.parametrize("path,options", REAL_MAPS[1:4], ids=[p for p, _ in REAL_MAPS[1:4]])
def test_min_clearance_is_the_minimum_over_all_poses(path, options, rng):
    """min_clearance skips poses by distance-field bounds: it returns what measuring every pose gives."""
    from pathlib import Path

    from nhstab.maps import load_map
    from nhstab.robot import default_footprint

    m = load_map(Path(__file__).parents[2] / "maps" / path, **options)
    world = CollisionWorld.from_map(m)
    xmin, ymin, xmax, ymax = m.bounds
    for fp in (default_footprint("rwd_car"), Footprint.disc(0.3)):
        for _ in range(4):             # short random walks: smooth paths passing near obstacles
            start = [rng.uniform(xmin, xmax), rng.uniform(ymin, ymax), rng.uniform(-4, 4)]
            poses = start + np.cumsum(rng.normal(0.0, [0.03, 0.03, 0.02], (150, 3)), axis=0)
            every = world.clearance_many(poses, fp)
            best, k = world.min_clearance(poses, fp)
            assert best == every.min() and k == int(np.argmin(every))


@pytest.mark.parametrize("path,options", REAL_MAPS, ids=[p for p, _ in REAL_MAPS])
def test_box_bounds_are_lower_bounds_and_a_discs_clearance_among_cells(path, options, rng):
    """``_box_bounds`` (the objects' boxes against the footprint's, in the world's and the robot's axes)
    never exceeds the clearance (to 1e-12 m), for a car, a disc and a non-convex polygon, at poses along
    a walk and scattered (the chunked branch's retry), on grid maps of many cells and polygon worlds. For
    a disc on a grid map (cells: axis-aligned boxes) it is the clearance wherever that is positive (to
    2e-9 m: its guard of 1e-9 m and rounding); in a polygon world it is positive at 90 % of the poses where the disc is 0.2 m clear."""
    from pathlib import Path

    from nhstab.maps import load_map
    from nhstab.robot import default_footprint

    m = load_map(Path(__file__).parents[2] / "maps" / path, **options)
    world = CollisionWorld.from_map(m)
    xmin, ymin, xmax, ymax = m.bounds
    ell = Footprint.polygon([[-0.4, -0.3], [0.6, -0.3], [0.6, 0.0], [0.0, 0.0], [0.0, 0.3], [-0.4, 0.3]])
    walk = np.array([0.5 * (xmin + xmax), 0.5 * (ymin + ymax), 0.0]) + np.cumsum(
        rng.normal(0.0, [0.05, 0.05, 0.03], (300, 3)), axis=0)
    scattered = np.column_stack([rng.uniform(xmin, xmax, 300), rng.uniform(ymin, ymax, 300),
                                 rng.uniform(-np.pi, np.pi, 300)])
    poses = np.vstack([walk, scattered])
    for fp in (default_footprint("rwd_car"), Footprint.disc(0.3), ell):
        bound = world._box_bounds(poses, fp)
        exact = world.clearance_many(poses, fp)
        assert np.all(bound >= 0.0) and np.all(bound <= np.maximum(exact, 0.0) + 1e-12)
        if fp.radius is not None and world.grids:
            pos = exact > 0
            assert pos.sum() > 100 and np.allclose(bound[pos], exact[pos], rtol=0, atol=2e-9)
        elif fp.radius is not None:                         # it says something where the disc is clear
            assert np.mean(bound[exact > 0.2] > 0) > 0.9


@pytest.mark.parametrize("trial", range(12))
def test_min_clearance_less_is_the_brute_force_minimum_in_random_worlds(trial):
    """The bounded search (distance field, the objects' boxes, measured neighbours) against measuring
    every pose, in random worlds of boxes, circles and convex polygons of 3 to 10 corners (a few objects,
    or hundreds: the chunked box bounds), for a disc, a car and a triangle along a random walk, with and
    without offsets: the same minimum (1e-12 m) and the same first index."""
    rng = np.random.default_rng(1000 + trial)
    obstacles = []
    for _ in range(int(rng.integers(3, 60) if trial % 4 else rng.integers(200, 800))):
        cx, cy, kind = rng.uniform(0, 30), rng.uniform(0, 20), trial + len(obstacles)
        if kind % 3 == 0:
            obstacles.append(box_polygon(cx, cy, rng.uniform(0.1, 3), rng.uniform(0.1, 3)))
        elif kind % 3 == 1:
            obstacles.append(Circle((cx, cy), rng.uniform(0.1, 1.0)))
        else:
            a = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 11))))
            r = rng.uniform(0.2, 1.5)
            obstacles.append(Polygon(tuple(map(tuple, np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])))))
    world = CollisionWorld.from_map(Map(name="random", bounds=(0, 0, 30, 20), obstacles=tuple(obstacles)), "known")
    fp = (Footprint.disc(0.4), Footprint.rectangle(4.2, 1.8),
          Footprint.polygon([[-0.5, -0.3], [0.7, 0.0], [-0.5, 0.3]]))[trial % 3]
    start = np.array([rng.uniform(0, 30), rng.uniform(0, 20), rng.uniform(-3, 3)])
    poses = start + np.cumsum(rng.normal(0.0, [0.05, 0.05, 0.03], (250, 3)), axis=0)
    offset = rng.uniform(0.0, 1.0, len(poses)) if trial % 2 else None
    best, k, _, _ = world.min_clearance_less(poses, fp, offset)
    brute = np.array([world.clearance(p, fp) for p in poses]) - (0.0 if offset is None else offset)
    assert best == pytest.approx(brute.min(), abs=1e-12) and k == int(np.argmin(brute))


@pytest.mark.parametrize("path,options", REAL_MAPS[:3], ids=[p for p, _ in REAL_MAPS[:3]])
def test_clearance_field_is_a_lower_bound(path, options, rng):
    from pathlib import Path

    from nhstab.maps import load_map

    m = load_map(Path(__file__).parents[2] / "maps" / path, **options)
    world = CollisionWorld.from_map(m)
    field = world.clearance_field()
    dot = Footprint.disc(1e-4)
    xmin, ymin, xmax, ymax = m.bounds
    pts = np.column_stack([rng.uniform(xmin, xmax, 400), rng.uniform(ymin, ymax, 400)])
    lower = field.at(pts[:, 0], pts[:, 1])
    for (x, y), lb in zip(pts, lower):
        true = world.distance((x, y, 0.0), dot) + 1e-4
        assert lb <= true + 1e-9


@pytest.mark.parametrize("path", ["maps/scenarios/depot_blocked_aisle.yaml", "maps/ours/parking_lot.yaml",
                                  "maps/ours/cluttered_room.yaml"])
def test_distance_field_with_added_obstacles_equals_the_one_built_anew(path):
    """A replan's world derives its distance field from the known world's: the same bound and the same
    certainly-inside cells as building it from all the obstacles."""
    from pathlib import Path

    from nhstab.maps import load_map

    m = load_map(Path(__file__).parents[2] / path)
    known = CollisionWorld.from_map(m, "known")
    known.clearance_field()
    derived = known.with_obstacles(m.unknown_obstacles).clearance_field()
    fresh = CollisionWorld(tuple(m.obstacles) + tuple(m.unknown_obstacles), m.grids, m.bounds).clearance_field()
    np.testing.assert_array_equal(derived.lower_bound, fresh.lower_bound)
    np.testing.assert_array_equal(derived.inside, fresh.inside)


@pytest.mark.parametrize("offset", [0.0, 0.37])
def test_vectorised_boxes_mark_the_same_field_as_the_loop(monkeypatch, offset):
    """Grid cells (axis-aligned boxes) are marked all at once; the field is identical, cell for cell,
    to marking them one by one, for grids on the raster (offset 0) and off it."""
    from nhstab.clearance_field import ClearanceField

    rng = np.random.default_rng(12)
    occ = rng.random((120, 90)) < 0.08
    grid = OccupancyGrid(occ, 0.1, (offset, -offset, 0.0))
    b = grid.bounds()
    m = Map("g", (b[0] + 0.55, b[1] - 0.3, b[2] - 1.2, b[3] + 0.45), grids=(grid,),
            obstacles=(Circle((3.0, 4.0), 0.7),))
    world = CollisionWorld.from_map(m, "known")
    args = (world.bounds, [g.resolution for g in world.grids], list(world._outline.values()))
    fast = ClearanceField(*args)
    monkeypatch.setattr(ClearanceField, "VECTORISED_BOXES", False)
    slow = ClearanceField(*args)
    assert np.array_equal(fast.lower_bound, slow.lower_bound) and np.array_equal(fast.inside, slow.inside)
    extra = [("poly", np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 1.5], [1.0, 1.5]]))]
    monkeypatch.setattr(ClearanceField, "VECTORISED_BOXES", True)
    derived_fast = fast.with_outlines(extra)
    monkeypatch.setattr(ClearanceField, "VECTORISED_BOXES", False)
    derived_slow = slow.with_outlines(extra)
    assert np.array_equal(derived_fast.lower_bound, derived_slow.lower_bound)


def test_a_cars_clearance_on_a_real_grid_map_is_exact_far_from_the_walls_too():
    """The rwd_car on the Nav2 depot (0.05 m cells): the clearance equals shapely's distance to the
    occupied cells (each cell its own box, read from the grid, and the bounds) to 1e-9 m at true
    distances of up to 3 m, and ``is_free`` with a margin agrees with it. FCL's own distance for the
    car's prism was off by up to 0.33 m at 1-2 m here (GJK), so the values are measured in the plane;
    FCL decides contact."""
    from nhstab.maps import load_map
    from nhstab.robot import default_robot
    from shapely.strtree import STRtree

    m = load_map("example:depot_blocked_aisle")
    world = CollisionWorld.from_map(m)
    fp = default_robot("rwd_car").footprint
    (grid,) = m.grids
    half = grid.resolution / 2
    cells = [box(x - half, y - half, x + half, y + half)
             for x, y in (grid.cell_to_world(i, j) for i, j in zip(*np.nonzero(grid.occupied)))]
    tree = STRtree(cells)
    xmin, ymin, xmax, ymax = m.bounds
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(1500):
        pose = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax), rng.uniform(-np.pi, np.pi)])
        shape = SPolygon(fp.outline_at(pose))
        bx = shape.bounds
        walls = min(bx[0] - xmin, bx[1] - ymin, xmax - bx[2], ymax - bx[3])
        ref = min(shape.distance(cells[tree.nearest(shape)]), walls)
        if not 1e-6 < ref <= 3.0:
            continue
        assert world.clearance(pose, fp) == pytest.approx(ref, abs=1e-9), pose
        for margin in (0.1, 0.3):              # the planner's margin decisions, also against shapely
            if abs(ref - margin) > 1e-9:
                assert world.is_free(pose, fp, margin) == (ref > margin), (pose, margin, ref)
        checked += 1
    assert checked > 200


@pytest.mark.parametrize("robot_name", ["unicycle", "rwd_car"])
def test_clearances_in_batches_equal_the_pose_by_pose_query_on_a_real_grid_map(robot_name):
    """``clearance_many`` (batched exact distances where they decide, FCL pose by pose near contact)
    equals ``clearance`` at each pose to 1e-12 m on the Nav2 depot, free and colliding poses alike, and
    ``min_clearance_less`` (the bounded batched search) equals the brute-force minimum of clearance -
    offset, index included, for offsets of 0 to 1 m."""
    from nhstab.maps import load_map
    from nhstab.robot import default_robot

    m = load_map("example:depot_blocked_aisle")
    world = CollisionWorld.from_map(m)
    fp = default_robot(robot_name).footprint
    xmin, ymin, xmax, ymax = m.bounds
    rng = np.random.default_rng(11)
    # a wandering path (consecutive poses close, as along a nominal) and scattered poses
    steps = rng.normal(0.0, [0.04, 0.04, 0.03], (600, 3))
    walk = np.array([0.5 * (xmin + xmax), 0.5 * (ymin + ymax), 0.0]) + np.cumsum(steps, axis=0)
    scattered = np.column_stack([rng.uniform(xmin, xmax, 400), rng.uniform(ymin, ymax, 400),
                                 rng.uniform(-np.pi, np.pi, 400)])
    poses = np.vstack([walk, scattered])
    one_by_one = np.array([world.clearance(p, fp) for p in poses])
    assert (one_by_one < 0).sum() > 20 and (one_by_one > 0.5).sum() > 20      # both kinds present
    assert np.allclose(world.clearance_many(poses, fp), one_by_one, rtol=0, atol=1e-12)
    for offset in (np.zeros(len(walk)), rng.uniform(0.0, 1.0, len(walk))):
        brute = one_by_one[:len(walk)] - offset
        best, k, c_k, evals = world.min_clearance_less(walk, fp, offset)
        assert best == pytest.approx(brute.min(), abs=1e-12)
        assert brute[k] == pytest.approx(brute.min(), abs=1e-12) and c_k == pytest.approx(one_by_one[k], abs=1e-12)
        assert evals <= len(walk)


@pytest.mark.parametrize("per_width", [1.0, 3.0])
@pytest.mark.parametrize("size", [(4.4, 1.8), (0.6, 0.5), (2.0, 2.0), (7.0, 2.2)])
def test_disc_covers_contain_the_footprint_and_overhang_as_stated(per_width, size):
    """Every point of a rectangle footprint (a 60 x 60 grid over it, edges included) lies in a disc of
    the cover, and the cover reaches at most r - w/2 beyond the sides (r the discs' radius): 0.26 m
    (coarse) and 0.04 m (fine) for a 4.4 m x 1.8 m car, as disc_cover's docstring states."""
    from nhstab.clearance_field import disc_cover

    length, width = size
    fp = Footprint.rectangle(length, width)
    centres, radii = disc_cover(fp, per_width)
    c, rad = np.asarray(centres), np.asarray(radii)
    (x0, y0), (x1, y1) = fp.vertices.min(axis=0), fp.vertices.max(axis=0)
    gx, gy = np.meshgrid(np.linspace(x0, x1, 60), np.linspace(y0, y1, 60))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    inside = (np.hypot(pts[:, None, 0] - c[:, 0], pts[:, None, 1] - c[:, 1]) <= rad + 1e-12).any(axis=1)
    assert inside.all()
    if size == (4.4, 1.8):
        assert rad.max() - width / 2 == pytest.approx(0.26 if per_width == 1.0 else 0.04, abs=0.005)


@pytest.mark.parametrize("footprint", ["car", "disc"])
@pytest.mark.slow
def test_the_separating_axis_test_agrees_with_shapely(footprint):
    """_separated (the batched distances' contact test for convex shapes whose boxes meet) against
    shapely's ``intersects`` on 4000 random pairs of a rotated car or a disc with rotated rectangles,
    triangles (padded to four corners, as the shape tables pad them) and circles placed so that about
    half overlap; pairs within 1e-9 m of touching are left out."""
    from nhstab.collision import _separated
    from nhstab.robot import default_robot

    rng = np.random.default_rng(5)
    fp = default_robot("rwd_car").footprint if footprint == "car" else Footprint.disc(0.4)
    n, k = 1000, 4
    spread = 3.5 if fp.radius is None else 2.0
    poses = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(-np.pi, np.pi, n)])
    quads = np.empty((n, k, 4, 2))
    circles = np.zeros((n, k, 3))
    is_poly = rng.random((n, k)) < 0.7
    for i in range(n):
        for j in range(k):
            c, a = rng.uniform(-spread, spread, 2), rng.uniform(-np.pi, np.pi)
            if rng.random() < 0.5:
                half = rng.uniform(0.05, 1.5, 2)
                local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
            else:
                local = rng.uniform(-1.2, 1.2, (3, 2))
                if (local[1, 0] - local[0, 0]) * (local[2, 1] - local[0, 1]) \
                        - (local[1, 1] - local[0, 1]) * (local[2, 0] - local[0, 0]) < 0:
                    local = local[::-1]
                local = np.vstack([local, local[-1:]])             # a triangle padded to four corners
            rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
            quads[i, j] = local @ rot.T + c
            circles[i, j] = (*c, rng.uniform(0.05, 1.0))
    edges = np.roll(quads, -1, axis=2) - quads
    if fp.radius is None:
        robot = np.stack([fp.outline_at(p) for p in poses])
        apart = _separated(robot, None, quads, edges, circles, is_poly)
        shapes = [SPolygon(r) for r in robot]
    else:
        apart = _separated(poses[:, :2], fp.radius, quads, edges, circles, is_poly)
        shapes = [Point(p[:2]).buffer(fp.radius, 256) for p in poses]
    checked = overlapping = 0
    for i in range(n):
        for j in range(k):
            other = SPolygon(quads[i, j, :3] if np.allclose(quads[i, j, 2], quads[i, j, 3]) else quads[i, j]) \
                if is_poly[i, j] else Point(circles[i, j, :2]).buffer(circles[i, j, 2], 256)
            gap = shapes[i].distance(other)
            if fp.radius is not None or not is_poly[i, j]:
                gap_tol = 1e-3           # shapely's discs are 256-gons: within 1e-4 m of the circle
            else:
                gap_tol = 1e-9
            if 0.0 < gap <= gap_tol or (gap == 0.0 and shapes[i].exterior.distance(other) < gap_tol
                                        and not shapes[i].intersection(other).area > 1e-6):
                continue
            assert apart[i, j] == (gap > 0.0), (i, j, gap)
            checked += 1
            overlapping += gap == 0.0
    assert checked > 3500 and 0.2 < overlapping / checked < 0.8


CTRL_C_IN_FCL = """
import sys
import numpy as np
from nhstab.cli.main import _sigint_handler
from nhstab.collision import CollisionWorld
from nhstab.maps import load_map
from nhstab.robot import resolve_robot

m = load_map("example:cluttered_room")
fp = resolve_robot(None, m.robot).footprint
w = CollisionWorld.from_map(m)
rng = np.random.default_rng(0)
lo, hi = np.array(w.bounds[:2]), np.array(w.bounds[2:])
poses = np.c_[lo + rng.random((400, 2)) * (hi - lo), rng.random(400) * 6.0]
poses = poses[[w.in_collision(p, fp) for p in poses]]   # FCL's callback runs for each, and finds contacts
got = 0
with _sigint_handler():
    while True:
        try:                               # each line is printed where the next signal is caught
            print(f"got {got}" if got else "ready", flush=True)
            while True:
                for p in poses:
                    w.in_collision(p, fp)
        except KeyboardInterrupt:
            got += 1
"""


def test_ctrl_c_during_collision_queries_is_never_lost(tmp_path):
    """A KeyboardInterrupt raised inside FCL's broad-phase callback is printed and dropped by FCL's
    Cython (the query goes on as if Ctrl-C had not been pressed): with Python's own handler 20 of 30
    signals were lost in this loop. With the handler nhstab's commands install, every signal reaches the
    caller as KeyboardInterrupt, and nothing is printed."""
    import select
    import signal
    import subprocess
    import sys

    script = tmp_path / "ctrl_c.py"
    script.write_text(CTRL_C_IN_FCL)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        assert proc.stdout.readline().strip() == "ready"
        for i in range(30):
            proc.send_signal(signal.SIGINT)
            ready, _, _ = select.select([proc.stdout], [], [], 10.0)
            assert ready, f"signal {i + 1} was lost"
            assert proc.stdout.readline().strip() == f"got {i + 1}"
    finally:
        proc.kill()
        _, err = proc.communicate()
    assert "Exception ignored" not in err and "Traceback" not in err, err
