"""Fuzz tests of nhstab's 2-D geometry that check answers: on seeded random polygons, each operation
against an independent construction (the hand-written numpy baselines of ``nhstab bench geometry``,
or shapely's own construction of the same object), to stated tolerances."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from nhstab.bench.geometry import (
    baseline_convex_hull,
    baseline_point_in_polygon,
    baseline_point_polygon_distance,
    baseline_polygon_distance,
)
from nhstab.collision import _offset_convex, polygon_distance
from nhstab.geometry import convex_parts, is_convex, point_in_polygon, point_polygon_distance, polygon_area
from nhstab.maps.svg import convex_hull_2d

TOL = 1e-12          # metres, on coordinates of a few metres


def random_star(rng, k: int, centre=(0.0, 0.0), scale: float = 3.0) -> np.ndarray:
    """A simple polygon of k vertices: sorted random angles, random radii (star-shaped about centre)."""
    a = np.sort(rng.uniform(0.0, 2 * np.pi, k))
    r = scale * rng.uniform(0.2, 1.0, k)
    return np.column_stack([centre[0] + r * np.cos(a), centre[1] + r * np.sin(a)])


def polygons(seed: int, n: int):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        v = random_star(rng, int(rng.integers(3, 30)))
        if shapely.is_valid(shapely.Polygon(v)) and abs(polygon_area(v)) > 1e-3:
            yield rng, v


@pytest.mark.parametrize("seed", range(4))
def test_point_in_polygon_agrees_with_ray_casting_and_counts_vertices_inside(seed):
    for rng, v in polygons(seed, 60):
        pts = rng.uniform(-3.5, 3.5, (40, 2))
        g = shapely.Polygon(v)
        for x, y in pts:
            if shapely.distance(g.exterior, shapely.Point(x, y)) > 1e-9:      # clear of the boundary
                assert point_in_polygon(x, y, v) is baseline_point_in_polygon(x, y, v)
        for x, y in v:                                                       # on the boundary: inside
            assert point_in_polygon(x, y, v)


@pytest.mark.parametrize("seed", range(4))
def test_point_polygon_distance_agrees_with_vertex_to_edge_arrays(seed):
    for rng, v in polygons(seed, 60):
        for p in rng.uniform(-6.0, 6.0, (20, 2)):
            d = point_polygon_distance(p, v)
            assert d == pytest.approx(baseline_point_polygon_distance(p, v), abs=TOL)
            assert d >= 0.0


@pytest.mark.parametrize("seed", range(4))
def test_polygon_distance_agrees_with_vertex_to_edge_arrays_on_polygons_apart(seed):
    rng = np.random.default_rng(100 + seed)
    checked = 0
    for _ in range(200):
        a = random_star(rng, int(rng.integers(3, 12)), rng.uniform(-2, 2, 2), 1.5)
        b = random_star(rng, int(rng.integers(3, 12)), rng.uniform(-2, 2, 2) + [4.0, 0.0], 1.5)
        ga, gb = shapely.Polygon(a), shapely.Polygon(b)
        if not (ga.is_valid and gb.is_valid) or ga.intersects(gb):
            continue
        assert polygon_distance(a, b) == pytest.approx(baseline_polygon_distance(a, b), abs=TOL)
        assert polygon_distance(a, b[:2]) == pytest.approx(baseline_polygon_distance(a, b[:2]), abs=TOL)  # a segment
        checked += 1
    assert checked > 100


@pytest.mark.parametrize("seed", range(3))
def test_offset_convex_is_the_mitred_and_bevelled_buffer(seed):
    """The outer offset is GEOS's mitred buffer, the inner its bevelled buffer (the same areas to 1e-9
    relative), and every inner vertex lies on the rounded outline (distance d from the polygon)."""
    rng = np.random.default_rng(200 + seed)
    for _ in range(50):
        pts = rng.normal(size=(int(rng.integers(3, 12)), 2))
        v = convex_hull_2d(pts)
        if len(v) < 3 or abs(polygon_area(v)) < 1e-3:
            continue
        d = float(rng.uniform(0.01, 1.0))
        outer, inner = _offset_convex(v, d)
        g = shapely.Polygon(v)
        mitre = shapely.buffer(g, d, join_style="mitre", mitre_limit=1e6)
        bevel = shapely.buffer(g, d, join_style="bevel")
        assert abs(polygon_area(outer)) == pytest.approx(mitre.area, rel=1e-9)
        assert abs(polygon_area(inner)) == pytest.approx(bevel.area, rel=1e-9)
        assert shapely.distance(g, shapely.points(inner)) == pytest.approx(np.full(len(inner), d), abs=1e-12)
        assert shapely.Polygon(outer).buffer(1e-9).covers(shapely.buffer(g, d, quad_segs=64))


@pytest.mark.parametrize("seed", range(3))
def test_convex_hull_is_geos_hull_and_the_monotone_chain_on_points_in_general_position(seed):
    rng = np.random.default_rng(300 + seed)
    for i in range(200):
        k = int(rng.integers(1, 40))
        pts = rng.integers(0, 6, (k, 2)).astype(float) if i % 2 else rng.normal(size=(k, 2))
        hull = convex_hull_2d(pts)
        assert np.array_equal(hull, baseline_convex_hull(pts))        # integers: exact; normal: general position
        if len(hull) >= 3:
            assert polygon_area(hull) > 0 and is_convex(hull)
            assert shapely.Polygon(hull).area == pytest.approx(shapely.convex_hull(shapely.multipoints(pts)).area,
                                                              rel=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_convex_parts_cover_the_polygon_exactly(seed):
    for _, v in polygons(400 + seed, 40):
        parts = convex_parts(v)
        union = shapely.union_all([shapely.Polygon(p) for p in parts])
        assert sum(abs(polygon_area(p)) for p in parts) == pytest.approx(abs(polygon_area(v)), rel=1e-9)
        assert union.symmetric_difference(shapely.Polygon(v)).area <= 1e-9 * abs(polygon_area(v))
