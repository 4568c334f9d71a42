"""Fuzz tests of the map loaders that check answers: seeded random maps written in each format (nhstab
YAML, Bench-MR SVG, ROS map_server raster, Moving AI), loaded, and their obstacles compared with an
independent shapely construction from the same numbers: the collision world built from the loaded map
answers, at random points, whether a small disc there overlaps an obstacle, as the shapely union says
(points within twice the disc's radius of the union's boundary are skipped)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from nhstab.bench.geometry import baseline_drop_repeats
from nhstab.collision import CollisionWorld
from nhstab.geometry import Footprint
from nhstab.maps import load_map
from nhstab.maps.svg import CLOSE_TOLERANCE, _clean_ring, _kept
from nhstab.maps.yaml_format import _drop_repeats
from shapely import affinity

PROBE = Footprint.disc(1e-3)


def agree(m, union, rng, n: int = 400, walls: bool = False) -> int:
    """The loaded map's collision world against the shapely union at n random points in the bounds;
    returns how many were decided (not too near the boundary)."""
    world = CollisionWorld.from_map(m, "known", walls=walls)
    xmin, ymin, xmax, ymax = m.bounds
    checked = 0
    for x, y in np.column_stack([rng.uniform(xmin, xmax, n), rng.uniform(ymin, ymax, n)]):
        p = shapely.Point(x, y)
        if shapely.distance(union.boundary, p) <= 2 * PROBE.radius:
            continue
        assert world.in_collision((x, y, 0.0), PROBE) == bool(union.contains(p)), (x, y)
        checked += 1
    return checked


@pytest.mark.parametrize("seed", range(4))
def test_yaml_map_obstacles_are_the_boxes_circles_and_polygons_written(tmp_path, seed):
    rng = np.random.default_rng(seed)
    lines, shapes = [], []
    for _ in range(int(rng.integers(3, 9))):
        kind = rng.integers(3)
        cx, cy = (float(c) for c in rng.uniform(2, 18, 2))
        if kind == 0:
            lx, ly, yaw = *(float(s) for s in rng.uniform(0.3, 4.0, 2)), float(rng.uniform(-math.pi, math.pi))
            lines.append(f"  - box: {{center: [{cx!r}, {cy!r}], size: [{lx!r}, {ly!r}], yaw: {yaw!r}}}")
            shapes.append(affinity.rotate(shapely.box(cx - lx / 2, cy - ly / 2, cx + lx / 2, cy + ly / 2),
                                          yaw, origin=(cx, cy), use_radians=True))
        elif kind == 1:
            r = float(rng.uniform(0.2, 2.0))
            lines.append(f"  - circle: {{center: [{cx!r}, {cy!r}], radius: {r!r}}}")
            shapes.append(shapely.Point(cx, cy).buffer(r, quad_segs=256))
        else:
            a = np.sort(rng.uniform(0, 2 * math.pi, int(rng.integers(3, 12))))
            rad = rng.uniform(0.5, 2.5, len(a))
            v = np.column_stack([cx + rad * np.cos(a), cy + rad * np.sin(a)])
            if not shapely.Polygon(v).is_valid or shapely.Polygon(v).area < 1e-2:
                continue
            lines.append("  - polygon: [" + ", ".join(f"[{float(x)!r}, {float(y)!r}]" for x, y in v) + "]")
            shapes.append(shapely.Polygon(v))
    path = tmp_path / "fuzz.yaml"
    path.write_text("name: fuzz\nbounds: [0, 0, 20, 20]\nobstacles:\n" + "\n".join(lines) + "\n")
    m = load_map(path)
    assert len(m.obstacles) == len(shapes)
    # a circle's polygon (256 segments per quarter) lies within 1e-5 m of the true circle: skip that band too
    union = shapely.union_all(shapes)
    assert agree(m, union.buffer(0), rng) > 200


@pytest.mark.parametrize("seed", range(3))
def test_benchmr_svg_polygons_are_the_paths_drawn(tmp_path, seed):
    rng = np.random.default_rng(10 + seed)
    paths, shapes = [], []
    for _ in range(int(rng.integers(2, 7))):
        c = rng.uniform(40, 400, 2)
        a = np.sort(rng.uniform(0, 2 * math.pi, int(rng.integers(3, 14))))
        v = c + rng.uniform(10, 60, len(a))[:, None] * np.column_stack([np.cos(a), np.sin(a)])
        if not shapely.Polygon(v).is_valid:
            continue
        paths.append('<path d="M ' + " L ".join(f"{float(x)!r} {float(y)!r}" for x, y in v) + ' Z"/>')
        shapes.append(shapely.Polygon(v / 22.0 * [1.0, -1.0]))                  # Bench-MR: 1/22, y up
    path = tmp_path / "fuzz.svg"
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg">' + "".join(paths) + "</svg>")
    m = load_map(path)
    assert len(m.obstacles) == len(shapes)
    assert agree(m, shapely.union_all(shapes), rng) > 100


@pytest.mark.parametrize("seed", range(3))
def test_ros_raster_cells_are_the_dark_pixels(tmp_path, seed):
    rng = np.random.default_rng(20 + seed)
    h, w = (int(v) for v in rng.integers(8, 40, 2))
    res, ox, oy = float(rng.uniform(0.05, 0.5)), float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3))
    dark = rng.random((h, w)) < 0.3
    pixels = np.where(dark, 0, 254).astype(np.uint8)                          # row 0 is the top of the image
    (tmp_path / "fuzz.pgm").write_bytes(f"P5\n{w} {h}\n255\n".encode() + pixels.tobytes())
    (tmp_path / "fuzz.yaml").write_text(f"image: fuzz.pgm\nmode: trinary\nresolution: {res!r}\n"
                                        f"origin: [{ox!r}, {oy!r}, 0.0]\nnegate: 0\noccupied_thresh: 0.65\n"
                                        "free_thresh: 0.25\n")
    m = load_map(tmp_path / "fuzz.yaml")
    cells = [shapely.box(ox + j * res, oy + (h - 1 - i) * res, ox + (j + 1) * res, oy + (h - i) * res)
             for i, j in zip(*np.nonzero(dark))]
    assert agree(m, shapely.union_all(cells), rng) > 200


@pytest.mark.parametrize("seed", range(3))
def test_movingai_blocked_cells_are_the_blocked_characters(tmp_path, seed):
    rng = np.random.default_rng(30 + seed)
    h, w = (int(v) for v in rng.integers(6, 30, 2))
    cell = float(rng.uniform(0.2, 2.0))
    text = rng.choice(np.array(list(".G@OTSW")), size=(h, w), p=[0.45, 0.15, 0.1, 0.1, 0.1, 0.05, 0.05])
    (tmp_path / "fuzz.map").write_text(f"type octile\nheight {h}\nwidth {w}\nmap\n"
                                       + "\n".join("".join(row) for row in text) + "\n")
    m = load_map(tmp_path / "fuzz.map", cell_size=cell)
    blocked = ~np.isin(text, [".", "G"])
    cells = [shapely.box(x * cell, (h - 1 - y) * cell, (x + 1) * cell, (h - y) * cell)
             for y, x in zip(*np.nonzero(blocked))]
    assert agree(m, shapely.union_all(cells), rng) > 200


@pytest.mark.parametrize("seed", range(3))
def test_ring_cleaning_agrees_with_the_consecutive_comparisons(seed):
    """A YAML polygon's repeated vertices (GEOS's filter) against numpy's consecutive comparison, and a
    Bench-MR path's (each vertex against the last kept, to REPEAT_TOLERANCE) with and without its fast
    path, on seeded rings with exact and near repeats and closing vertices."""
    rng = np.random.default_rng(40 + seed)
    for i in range(400):
        k = int(rng.integers(2, 30))
        v = rng.integers(0, 3, (k, 2)).astype(float) * (1.0 if i % 2 else 1e-10) if i % 3 else rng.normal(size=(k, 2))
        v = np.repeat(v, rng.integers(1, 3, k), axis=0)
        if i % 4 == 0:
            v = np.vstack([v, v[:1]])
        assert np.array_equal(_drop_repeats(v), baseline_drop_repeats(v))
        slow = v[_kept(v)]
        while len(slow) > 1 and np.all(np.abs(slow[-1] - slow[0]) <= CLOSE_TOLERANCE):
            slow = slow[:-1]
        assert np.array_equal(_clean_ring(v), slow)
