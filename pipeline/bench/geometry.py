"""``nhstab bench geometry``: nhstab's 2-D geometry against shapely 2 (GEOS), on the inputs it meets.

Each case times one operation two ways in the same run, alternating the two in every repeat (so that
the machine's noise falls on both alike), and reports the best time of one block of calls over the
repeats (``ours_us``, ``shapely_us``; the medians beside them; a block is a share of the case's
inputs, or 20 calls on one), the ratio of the best times (the best is the least disturbed by other
work on a shared machine) and the largest difference between their answers over the inputs:

* where the library calls shapely, the other way is the **baseline**, the hand-written numpy code a
  competent engineer writes without GEOS (kept here, not in the library);
* where the library keeps its own numpy code, the other way is the shapely construction that does the
  same job, and the case states why the library's code stays.

The inputs are real: the Bench-MR warehouse's polygons (88 paths, the largest Bench-MR world), the
rwd_car's rectangle footprint, the convex parts of ``maps/ours/parking_lot.yaml`` and a 10,000-vertex
star (the accepted maximum), at seeded poses within the maps' bounds.
"""

from __future__ import annotations

import time

import numpy as np
import shapely

from .. import geometry
from ..collision import CollisionWorld, _offset_convex, _poly_distances, polygon_distance
from ..geometry import convex_parts, transform_points
from ..maps import load_map
from ..maps.svg import convex_hull_2d
from ..maps.yaml_format import _drop_repeats
from ..robot import default_footprint
from .common import machine, maps_dir
from .polygons import star

BASELINE = ("hand-written numpy code of the same answer (vertex-to-edge distance arrays, even-odd ray casting, "
            "Andrew's monotone chain in Python, consecutive comparisons)")
#: a ratio (baseline or kept code time over shapely's) at or above this keeps shapely
EQUAL_OR_FASTER = 1.0
#: the start of the reason of a case kept whatever its speed (equal answers elsewhere depend on it)
KEPT_FOR_IDENTITY = "the same vertex-to-edge formula"


# ---- the baselines: nhstab's hand-written geometry where the library now calls shapely -------------

def baseline_point_in_polygon(x: float, y: float, v: np.ndarray) -> bool:
    """Even-odd ray casting, with points on an edge (to 1e-12 relative) counted as inside."""
    a, b = v, np.roll(v, -1, axis=0)
    d = b - a
    p = np.array([x, y], dtype=float)
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    dist = np.hypot(*(a + t[:, None] * d - p).T)
    if dist.min() <= 1e-12 * max(1.0, float(np.abs(v).max())):
        return True
    crosses = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[:, 0] + (y - a[:, 1]) * d[:, 0] / d[:, 1]
    return bool(np.count_nonzero(crosses & (x < xi)) % 2)


def baseline_point_polygon_distance(p, v: np.ndarray) -> float:
    """Distance from point p to the closed polygon v (0 inside): point to every edge, and ray casting."""
    p = np.asarray(p, dtype=float)
    a = np.asarray(v, dtype=float)
    b = np.roll(a, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    d = float(np.min(np.hypot(*(a + t[:, None] * ab - p).T)))
    x, y = p
    with np.errstate(divide="ignore", invalid="ignore"):
        crosses = ((a[:, 1] > y) != (b[:, 1] > y)) & (x < a[:, 0] + (y - a[:, 1]) * ab[:, 0] / ab[:, 1])
    return 0.0 if np.count_nonzero(crosses) % 2 == 1 else d


def baseline_polygon_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between two polygons apart: the smallest vertex-to-edge distance, both ways."""
    def one_way(points, poly):
        e = np.roll(poly, -1, axis=0) - poly
        rel = points[:, None, :] - poly[None, :, :]
        t = np.clip(np.einsum("nmk,mk->nm", rel, e) / np.maximum(np.einsum("mk,mk->m", e, e), 1e-300), 0.0, 1.0)
        gap = rel - t[:, :, None] * e[None, :, :]
        return float(np.sqrt(np.min(np.einsum("nmk,nmk->nm", gap, gap))))

    return min(one_way(a, b), one_way(b, a))


def baseline_convex_hull(points: np.ndarray) -> np.ndarray:
    """Andrew's monotone chain, counter-clockwise from the lowest point in (x, y) order."""
    pts = np.unique(np.asarray(points, dtype=float), axis=0)
    if len(pts) < 3:
        return pts

    def half(seq):
        chain = []
        for p in seq:
            while len(chain) >= 2:
                (ax, ay), (bx, by) = chain[-2], chain[-1]
                if (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax) > 0:
                    break
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def baseline_drop_repeats(v: np.ndarray) -> np.ndarray:
    """A ring without repeated consecutive vertices nor a repeated closing vertex (exact equality)."""
    keep = np.ones(len(v), dtype=bool)
    keep[1:] = np.any(v[1:] != v[:-1], axis=1)
    v = v[keep]
    while len(v) > 1 and np.array_equal(v[-1], v[0]):
        v = v[:-1]
    return v


# ---- the shapely constructions of the jobs the library keeps --------------------------------------

def shapely_offset_convex(v: np.ndarray, d: float):
    """The outer (mitred) and inner (bevelled) offsets of a convex polygon as GEOS buffers."""
    g = shapely.Polygon(v)
    outer = shapely.buffer(g, d, join_style="mitre", mitre_limit=1e6)
    inner = shapely.buffer(g, d, join_style="bevel")
    return shapely.get_coordinates(outer.exterior)[:-1], shapely.get_coordinates(inner.exterior)[:-1]


def shapely_signed_area(v: np.ndarray) -> float:
    ring = shapely.linearrings(v)
    return float(shapely.area(shapely.polygons(ring))) * (1.0 if shapely.is_ccw(ring) else -1.0)


def shapely_is_convex(v: np.ndarray) -> bool:
    g = shapely.Polygon(v)
    return bool(abs(shapely.area(shapely.convex_hull(g)) - shapely.area(g)) <= 1e-12 * max(1.0, shapely.area(g)))


# ---- timing -----------------------------------------------------------------------------------------

def _timed_pair(fa, fb, calls: int, repeats: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """(best, median) seconds per block of ``calls`` calls of fa, and of fb, the two alternated in
    every repeat."""
    fa(), fb()                                                    # first calls (caches, imports)
    ta, tb = [], []
    for _ in range(repeats):
        for f, out in ((fa, ta), (fb, tb)):
            started = time.perf_counter()
            for _ in range(calls):
                f()
            out.append((time.perf_counter() - started) / calls)
    return (min(ta), float(np.median(ta))), (min(tb), float(np.median(tb)))


def _inputs(seed: int) -> dict:
    maps = maps_dir()
    svg = load_map(maps / "bench-mr" / "polygon_mazes" / "warehouse.svg")
    rings = [p.vertices for p in svg.obstacles if not p.thin]
    lot = load_map(maps / "ours" / "parking_lot.yaml")
    world = CollisionWorld.from_map(lot)
    boxes, polys, _circles, kind = world._shape_tables()
    fp = default_footprint("rwd_car")
    rng = np.random.default_rng(seed)
    xmin, ymin, xmax, ymax = svg.bounds
    points = np.column_stack([rng.uniform(xmin, xmax, 64), rng.uniform(ymin, ymax, 64)])
    lxmin, lymin, lxmax, lymax = lot.bounds
    poses = np.column_stack([rng.uniform(lxmin, lxmax, 64), rng.uniform(lymin, lymax, 64),
                             rng.uniform(-np.pi, np.pi, 64)])
    return {"rings": rings, "points": points, "fp": fp, "poses": poses, "boxes": boxes, "polys": polys,
            "kind": kind, "star": star(10_000, seed)}


def _separated_pairs(fp, rings, points):
    """(footprint outline, ring) pairs that do not overlap: the footprint at the points, heading 0.3."""
    pairs = []
    for p in points:
        rv = transform_points(fp.vertices, (p[0], p[1], 0.3))
        g = shapely.Polygon(rv)
        for v in rings:
            if not shapely.intersects(g, shapely.Polygon(v)):
                pairs.append((rv, v))
    return pairs


def _case(name, where, inputs, library, other, other_name, calls, repeats, agree, decision, reason=""):
    t_lib, t_other = _timed_pair(library, other, calls, repeats)
    shapely_in_library = decision == "shapely"
    t_shapely, t_ours = (t_lib, t_other) if shapely_in_library else (t_other, t_lib)
    return {"case": name, "where": where, "inputs": inputs, "library": decision, "other": other_name,
            "ours_us": t_ours[0] * 1e6, "shapely_us": t_shapely[0] * 1e6,
            "ours_median_us": t_ours[1] * 1e6, "shapely_median_us": t_shapely[1] * 1e6,
            "ours_over_shapely": t_ours[0] / t_shapely[0],
            "max_abs_difference": agree, "calls_per_repeat": calls, "repeats": repeats,
            "reason_kept": reason}


def bench_geometry(seed: int = 7, repeats: int = 9, progress=None) -> dict:
    """Every case of the module docstring; ``repeats`` alternated repeats per case."""
    d = _inputs(seed)
    rings, points, fp, poses = d["rings"], d["points"], d["fp"], d["poses"]
    rows = []

    def add(row):
        rows.append(row)
        if progress is not None:
            progress(f"geometry: {row['case']}: ours {row['ours_us']:.1f} us, shapely {row['shapely_us']:.1f} us")

    # point in polygon: a start or goal against each obstacle of a Bench-MR world
    pip_lib = [geometry.point_in_polygon(x, y, v) for x, y in points for v in rings]
    pip_base = [baseline_point_in_polygon(x, y, v) for x, y in points for v in rings]
    add(_case("point_in_polygon", "nhstab.geometry.point_in_polygon (YAML maps: start, goal, scenarios inside an "
              "obstacle?)", f"{len(points)} points x {len(rings)} Bench-MR warehouse polygons", 
              lambda: [geometry.point_in_polygon(x, y, v) for x, y in points[:4] for v in rings],
              lambda: [baseline_point_in_polygon(x, y, v) for x, y in points[:4] for v in rings],
              "baseline: even-odd ray casting in numpy", 1, repeats,
              float(np.count_nonzero(np.array(pip_lib) != np.array(pip_base))), "shapely"))
    # point to polygon: a disc robot's centre to an obstacle
    ppd = [(geometry.point_polygon_distance(p, v), baseline_point_polygon_distance(p, v)) for p in points for v in rings]
    add(_case("point_polygon_distance", "nhstab.geometry.point_polygon_distance (exact distance of a disc robot "
              "to a polygon of more than 8 corners)", f"{len(points)} points x {len(rings)} warehouse polygons",
              lambda: [geometry.point_polygon_distance(p, v) for p in points[:4] for v in rings],
              lambda: [baseline_point_polygon_distance(p, v) for p in points[:4] for v in rings],
              "baseline: point to every edge and ray casting in numpy", 1, repeats,
              float(np.max(np.abs(np.subtract(*np.array(ppd).T)))), "shapely"))
    # polygon to polygon: the car's outline to an obstacle it does not overlap
    pairs = _separated_pairs(fp, rings, points[:8])
    pd = [(polygon_distance(a, b), baseline_polygon_distance(a, b)) for a, b in pairs]
    add(_case("polygon_distance", "nhstab.collision.polygon_distance (exact distance of a polygon footprint to a "
              "polygon of more than 8 corners)", f"{len(pairs)} rwd_car outline / warehouse polygon pairs apart",
              lambda: [polygon_distance(a, b) for a, b in pairs[:40]],
              lambda: [baseline_polygon_distance(a, b) for a, b in pairs[:40]],
              "baseline: vertex to edge both ways in numpy", 1, repeats,
              float(np.max(np.abs(np.subtract(*np.array(pd).T)))), "shapely"))
    # convex hull: a Bench-MR world loaded with convex_hull=True, and the largest accepted polygon
    same = all(np.array_equal(convex_hull_2d(v), baseline_convex_hull(v)) for v in rings + [d["star"]])
    add(_case("convex_hull_2d (map)", "nhstab.maps.svg.convex_hull_2d (load_map(svg, convex_hull=True))",
              f"the {len(rings)} warehouse polygons", lambda: [convex_hull_2d(v) for v in rings],
              lambda: [baseline_convex_hull(v) for v in rings], "baseline: Andrew's monotone chain in Python",
              1, repeats, 0.0 if same else float("nan"), "shapely"))
    add(_case("convex_hull_2d (10,000 vertices)", "nhstab.maps.svg.convex_hull_2d", "a 10,000-vertex star",
              lambda: convex_hull_2d(d["star"]), lambda: baseline_convex_hull(d["star"]),
              "baseline: Andrew's monotone chain in Python", 1, repeats, 0.0 if same else float("nan"), "shapely"))
    # ring cleaning: a YAML map's polygons with every vertex written twice and the ring closed
    doubled = [np.vstack([np.repeat(v, 2, axis=0), v[:1]]) for v in rings] + [np.repeat(d["star"], 2, axis=0)]
    same = all(np.array_equal(_drop_repeats(v), baseline_drop_repeats(v)) for v in doubled)
    add(_case("drop repeated vertices", "nhstab.maps.yaml_format._drop_repeats (a YAML map's polygons)",
              f"the {len(rings)} warehouse rings and the 10,000-vertex star, every vertex twice",
              lambda: [_drop_repeats(v) for v in doubled], lambda: [baseline_drop_repeats(v) for v in doubled],
              "baseline: consecutive comparison in numpy", 1, repeats, 0.0 if same else float("nan"), "shapely"))
    # kept: the batched distances of a pose to the obstacles near it (the planner's hot path)
    sel = np.flatnonzero(d["kind"] == 1)
    quads = d["polys"][sel]
    near = [quads[np.argsort(np.hypot(*(quads.mean(axis=1) - p[:2]).T))[:8]] for p in poses]
    outlines = [transform_points(fp.vertices, p) for p in poses]
    geoms = [shapely.polygons(q) for q in near]
    hot = [(_poly_distances(fp, p, rv, q), shapely.distance(shapely.Polygon(rv), g))
           for p, rv, q, g in zip(poses, outlines, near, geoms)]
    hot = [(a[b > 0], b[b > 0]) for a, b in hot]         # the pairs apart (the only ones it measures)
    add(_case("batched polygon distances", "nhstab.collision._poly_distances (CollisionWorld's exact distances "
              "of one pose to the 8 nearest obstacles)", f"{len(poses)} rwd_car poses x the 8 nearest parking_lot "
              "parts", lambda: [_poly_distances(fp, p, rv, q) for p, rv, q in zip(poses[:8], outlines, near)],
              lambda: [shapely.distance(shapely.Polygon(rv), g) for rv, g in zip(outlines[:8], geoms)],
              "shapely.distance(footprint, obstacles built once)", 1, repeats,
              float(max(np.max(np.abs(a - b), initial=0.0) for a, b in hot)), "ours",
              "the same vertex-to-edge formula as CollisionWorld._near_batch, which decides many poses at once "
              "(poses x objects arrays): the pose-by-pose and batched answers are equal bit for bit, which the "
              "committed results rely on; GEOS's rounding differs (max_abs_difference)"))
    # kept: offsetting a convex footprint part by the margin (once per footprint and margin)
    part = convex_parts(fp.vertices)[0]
    o, i = _offset_convex(part, 0.3)
    so, si = shapely_offset_convex(part, 0.3)
    diff = max(float(abs(shapely.area(shapely.Polygon(o)) - shapely.area(shapely.Polygon(so)))),
               float(abs(shapely.area(shapely.Polygon(i)) - shapely.area(shapely.Polygon(si)))))
    add(_case("offset convex", "nhstab.collision._offset_convex (the inflated footprints of is_free with a "
              "margin)", "the rwd_car rectangle, margin 0.3 m", lambda: _offset_convex(part, 0.3),
              lambda: shapely_offset_convex(part, 0.3), "shapely.buffer mitre (outer) and bevel (inner)", 20,
              repeats, diff, "ours", "faster on a footprint's few corners (ratio below 1), and its vertices keep "
                                     "the corners' order, which the FCL prisms are built from"))
    # kept: signed area and convexity of small rings (every Polygon, Footprint and convex_parts call)
    small = [fp.vertices] + [b for b in convex_parts(rings[0])][:3] + rings[:4]
    add(_case("signed area", "nhstab.geometry.polygon_area (orientation of every polygon and footprint)",
              "the rwd_car rectangle and 7 warehouse rings and parts", lambda: [geometry.polygon_area(v) for v in small],
              lambda: [shapely_signed_area(v) for v in small], "shapely area and is_ccw", 20, repeats,
              float(max(abs(geometry.polygon_area(v) - shapely_signed_area(v)) for v in small)), "ours",
              "faster on small rings (ratio below 1); shapely has no signed area, it takes two calls"))
    conv = [(geometry.is_convex(v if geometry.polygon_area(v) > 0 else v[::-1]), shapely_is_convex(v)) for v in small]
    add(_case("is_convex", "nhstab.geometry.is_convex (convex_parts: a footprint or obstacle whole or triangulated)",
              "the rwd_car rectangle and 7 warehouse rings and parts", lambda: [geometry.is_convex(v) for v in small],
              lambda: [shapely_is_convex(v) for v in small], "shapely: area of the convex hull equals the area",
              20, repeats, float(sum(a != b for a, b in conv)), "ours",
              "faster on small rings (ratio below 1); shapely has no convexity test, it takes a hull and two areas"))
    replaced = [r["case"] for r in rows if r["library"] == "shapely"]
    met = {f"{r['case']}: the library's way is at least as fast": bool(
        (r["ours_over_shapely"] >= EQUAL_OR_FASTER) == (r["library"] == "shapely")) for r in rows
        if not r["reason_kept"].startswith(KEPT_FOR_IDENTITY)}
    met["every replaced case agrees with its baseline (max_abs_difference <= 1e-12)"] = all(
        r["max_abs_difference"] <= 1e-12 for r in rows if r["library"] == "shapely")
    return {"benchmark": "geometry", "machine": machine(), "shapely": shapely.__version__,
            "geos": shapely.geos_version_string, "seed": seed, "repeats": repeats, "baseline": BASELINE,
            "rows": rows, "replaced_by_shapely": replaced, "met": met}


def summary_lines(r: dict) -> list[str]:
    """Rows of the benchmark summary table (benchmark | measure | value | target | met)."""
    lines = []
    for row in r["rows"]:
        fast = row["ours_over_shapely"] >= EQUAL_OR_FASTER
        identity = row["reason_kept"].startswith(KEPT_FOR_IDENTITY)
        ok = "-" if identity else ("yes" if fast == (row["library"] == "shapely") else "NO")
        target = "- (kept: bit-identical to the batched path)" if identity else \
            (">= 1 for shapely" if row["library"] == "shapely" else "< 1 to keep ours")
        lines.append(f"| geometry | {row['case']} ({row['inputs']}): ours {row['ours_us']:.1f} us, shapely "
                     f"{row['shapely_us']:.1f} us; library uses {row['library']} | ours/shapely "
                     f"{row['ours_over_shapely']:.2f}, max diff {row['max_abs_difference']:.2g} | "
                     f"{target} | {ok} |")
    return lines
