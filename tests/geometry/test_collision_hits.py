"""CollisionWorld.hits names the obstacles a footprint overlaps, checked independently with shapely."""

import numpy as np
import pytest
from nhstab.collision import CollisionWorld
from nhstab.geometry import Footprint
from nhstab.maps.base import Circle, Map, OccupancyGrid, Polygon, box_polygon
from shapely.geometry import LineString, Point, box
from shapely.geometry import Polygon as SPolygon

#: several obstacles of every kind: convex and non-convex polygons, a thin polyline (a segment pair),
#: circles, and unknown obstacles beside the known ones
KNOWN = (Polygon(np.array([[2, 2], [6, 2], [6, 3], [3, 3], [3, 6], [2, 6]], float)),      # an L
         Circle((7, 7), 1.0),
         box_polygon(8, 2, 1.5, 0.8, 0.6),
         Polygon(np.array([[1, 8], [4, 8.5]], float)),                                   # a segment
         Circle((3.6, 3.6), 0.4))                                                         # in the L's corner
UNKNOWN = (box_polygon(8.5, 4.5, 0.6, 0.6, 0.3), Circle((4.5, 7.0), 0.3))
MAP = Map("hits", (0, 0, 10, 10), obstacles=KNOWN, unknown_obstacles=UNKNOWN)


def _shapely(shape):
    if isinstance(shape, Circle):
        return Point(shape.center).buffer(shape.radius, 512)
    v = shape.vertices
    return SPolygon(v) if len(v) > 2 else LineString(v)


@pytest.mark.parametrize("fp", [Footprint.rectangle(1.2, 0.6, rear_overhang=0.3), Footprint.disc(0.35)],
                         ids=["rectangle", "disc"])
@pytest.mark.slow
def test_hits_name_the_obstacles_shapely_finds_overlapped(fp):
    """On random poses over a map of seven obstacles (known and unknown) and its bounds, the obstacles named are the
    ones whose shapely geometry the footprint overlaps by more than 1e-6 m (poses within 1e-6 m of
    touching one are skipped), and each named one has a negative clearance."""
    world = CollisionWorld.from_map(MAP, "all")
    shapes = {**{f"obstacles[{k}]": _shapely(s) for k, s in enumerate(KNOWN)},
              **{f"unknown_obstacles[{k}]": _shapely(s) for k, s in enumerate(UNKNOWN)},
              "map bounds (left)": box(-1, -1, 0, 11), "map bounds (right)": box(10, -1, 11, 11),
              "map bounds (bottom)": box(-1, -1, 11, 0), "map bounds (top)": box(-1, 10, 11, 11)}
    rng = np.random.default_rng(7)
    checked = several = 0
    for pose in np.column_stack([rng.uniform(0.8, 9.2, 3000), rng.uniform(0.8, 9.2, 3000),
                                 rng.uniform(-np.pi, np.pi, 3000)]):
        body = Point(pose[:2]).buffer(fp.radius, 512) if fp.radius is not None else SPolygon(fp.outline_at(pose))
        inside = body.buffer(-1e-6)
        grown = body.buffer(1e-6)
        expected = {k for k, g in shapes.items() if inside.intersects(g)}
        if {k for k, g in shapes.items() if grown.intersects(g)} != expected:
            continue                                        # touching within 1e-6 m: either verdict is right
        hits = world.hits(pose, fp)
        assert {h["id"] for h in hits} == expected, pose
        assert all(h["clearance_m"] < 0 for h in hits)
        assert [h["clearance_m"] for h in hits] == sorted(h["clearance_m"] for h in hits)
        for h in hits:
            if h["source"] != "bounds":
                assert h["source"] in ("obstacles", "unknown_obstacles")
                assert h["id"] == f"{h['source']}[{h['index']}]"
        checked += bool(expected)
        several += len(expected) > 1
    assert checked >= 300 and several >= 10, (checked, several)


def test_a_disc_in_a_circle_has_the_closed_form_depth():
    """A disc of radius 0.35 overlapping the circle of radius 1 at (7, 7) by 0.2 m: clearance -0.2."""
    fp = Footprint.disc(0.35)
    world = CollisionWorld.from_map(MAP, "all")
    d = 1.0 + 0.35 - 0.2
    hits = world.hits((7 + d * np.cos(0.3), 7 + d * np.sin(0.3), 0.0), fp)
    assert [h["id"] for h in hits] == ["obstacles[1]"]
    assert hits[0]["clearance_m"] == pytest.approx(-0.2, abs=1e-4)
    assert world.hits((1.0, 1.0, 0.0), fp) == []


def test_hits_name_the_grid_cells_and_the_bounds():
    """A grid of 0.1 m cells with a 2-cell speck and a wall: the cells named are those whose squares
    shapely finds the footprint overlapping (by more than 1e-9 m^2); a pose past the map's edge names
    that side of the bounds."""
    occ = np.zeros((40, 60), bool)
    occ[20, 30:32] = True                          # the speck: cells (20, 30), (20, 31)
    occ[5:35, 50] = True                           # a wall
    grid = OccupancyGrid(occ, 0.1, origin=(0.0, 0.0, 0.0))
    m = Map("grid", (0, 0, 6, 4), grids=(grid,))
    world = CollisionWorld.from_map(m)
    fp = Footprint.rectangle(0.6, 0.4, rear_overhang=0.1)
    cells = [(i, j) for i, j in zip(*np.nonzero(occ))]
    for pose in [(3.0, 1.85, 0.2), (3.25, 2.2, -0.5), (2.9, 2.05, 1.0), (4.8, 2.03, 0.0), (4.9, 2.04, 0.1)]:
        body = SPolygon(fp.outline_at(pose))
        expected = sorted([int(i), int(j)] for i, j in cells
                          if body.intersection(box(j * 0.1, i * 0.1, (j + 1) * 0.1, (i + 1) * 0.1)).area > 1e-9)
        hits = world.hits(pose, fp)
        assert expected, pose
        assert len(hits) == 1 and hits[0]["source"] == "grid" and hits[0]["grid"] == 0, hits
        assert hits[0]["cells"] == expected, pose
        assert hits[0]["id"].startswith("grid[0] cell") and hits[0]["clearance_m"] < 0
    speck = world.hits((3.0, 1.85, 0.2), fp)[0]
    assert speck["cells"] == [[20, 30], [20, 31]]
    pose = (0.0, 2.0, 0.0)
    edge = world.hits(pose, fp)
    assert [h["id"] for h in edge] == ["map bounds (left)"]
    assert edge[0]["clearance_m"] == pytest.approx(fp.outline_at(pose)[:, 0].min(), abs=1e-6)   # past x = 0
