"""``nhstab bench polygons``: the checks on a polygon (a map obstacle, a robot footprint) up to the
accepted maximum, :data:`~nhstab.limits.MAX_POLYGON_VERTICES` vertices.

Three seeded shapes at each size k: a **star** (a five-pointed star's outline of short edges, the
common case: GEOS compares only the edges whose bounding boxes overlap, a few per edge); **spikes**
(the star of the hostile-size tests, radii alternating 2.0 and 2.8 m: every edge is a long radial
spike, and near the diagonals their bounding boxes overlap by thousands); and a **comb** of long
parallel teeth (the worst case for GEOS: every edge's bounding box overlaps almost every other's). Per shape and
size it times, best and median of several repeats, with the simplicity test's cache cleared before
each repeat (so that it hides no cost):

* ``simple``: :func:`nhstab.geometry.is_simple_polygon`, GEOS's ring simplicity test;
* ``footprint``: :func:`nhstab.robot.parse_footprint` on ``{"polygon": [[x, y], ...]}`` (a robot file's
  footprint: its numbers checked, repeated points dropped, simplicity, area);
* ``map``: the work of ``nhstab map info`` before its summary: ``load_map`` of a YAML map holding the
  polygon as its one obstacle (written to a temporary folder) and ``CollisionWorld.from_map(m, "known")``
  (the GEOS constrained Delaunay triangulation into FCL parts); its two parts are kept too;
* ``raster``: the map's free fraction (:func:`nhstab.maps.raster.free_fraction`, the scanline fill of
  :func:`~nhstab.maps.raster.ring_cells`), which ``nhstab map info`` prints;
* ``baseline``: the simplicity test a competent engineer writes without GEOS: the classic pairwise
  segment-intersection test (orientation signs, and collinear endpoints on the other segment),
  vectorised with numpy over blocks of edge pairs: O(k^2) work, but no Python loop per pair. It stops
  at the first block with a crossing.

The fitted scaling exponent of each method is the slope of log(median time) against log(k). The
baseline and GEOS must agree on every polygon measured and on a twin of it made non-simple (two
vertices half the ring apart swapped); the twin is not timed.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from .. import geometry
from ..collision import CollisionWorld
from ..limits import MAX_POLYGON_VERTICES
from ..maps import load_map
from ..maps.raster import free_fraction
from ..robot import parse_footprint
from .common import _best, machine

SIZES = (1_250, 2_500, 5_000, 10_000)
#: star: the common case, with the exponent target; spikes and comb: harder cases, measured without one
SHAPES = ("star", "spikes", "comb")
#: the methods timed, in the order of the summary (``map`` is ``map_load`` + ``map_world``)
METHODS = ("simple", "footprint", "map", "map_load", "map_world", "raster", "baseline")
#: the checks with the time target at the largest size
CHECKS = ("simple", "footprint", "map")
TARGET_S = 1.0
TARGET_STAR_EXPONENT = 1.5
BASELINE = ("pairwise segment-intersection test (orientations and collinear endpoints), numpy-vectorised over "
            "blocks of edge pairs: O(k^2) work without a Python loop per pair; stops at the first block with a crossing")

#: the map the polygon is drawn in (metres)
_BOUNDS = (0.0, 0.0, 12.0, 9.0)


# ---- the polygons ---------------------------------------------------------------------------------

def star(k: int, seed: int = 0, cx: float = 6.0, cy: float = 4.5) -> np.ndarray:
    """A five-pointed star's outline of ``k`` vertices at evenly spaced angles, radius 2.4 +- 0.4 m plus a
    seeded jitter of up to one vertex spacing: simple (star-shaped about its centre), every edge short
    (about 2.4 x 2 pi / k m), the common case."""
    rng = np.random.default_rng(seed)
    a = 2 * np.pi * np.arange(k) / k
    r = 2.4 + 0.4 * np.cos(5 * a) + rng.uniform(0.0, 2 * np.pi * 2.4 / k, k)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def spikes(k: int, seed: int = 0, cx: float = 6.0, cy: float = 4.5) -> np.ndarray:
    """The star of the hostile-size tests: ``k`` vertices at evenly spaced angles, radii alternating 2.0
    and 2.8 m (plus a seeded jitter of up to 0.1 m). Simple, but every edge is a 0.8 m spike, so that the
    bounding boxes of the edges near the diagonals overlap those of thousands of others."""
    rng = np.random.default_rng(seed)
    a = 2 * np.pi * np.arange(k) / k
    r = 2.0 + 0.8 * (np.arange(k) % 2) + rng.uniform(0.0, 0.1, k)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def comb(k: int, x0: float = 2.0, y0: float = 2.0, width: float = 2.0, reach: float = 4.0,
         height: float = 5.0) -> np.ndarray:
    """A simple ring of exactly ``k`` (>= 6) vertices: ``(k - 2) // 4`` teeth of long parallel diagonal
    edges (every edge's bounding box overlaps almost every other's: the worst case of tests by bounding
    boxes) on a base whose bottom is bent down by the 0-3 vertices left over."""
    teeth = (k - 2) // 4
    d = width / teeth
    pts = []
    for i in range(teeth):
        x = x0 + i * d
        pts += [(x, y0), (x + reach, y0 + height), (x + reach + d / 2, y0 + height), (x + d / 2, y0)]
    right = x0 + (teeth - 1) * d + d / 2
    pts.append((right, y0 - 0.5))
    extra = k - 4 * teeth - 2
    for s in (np.arange(1, extra + 1) / (extra + 1)):
        pts.append((right + s * (x0 - right), y0 - 0.5 - 0.2 * np.sin(np.pi * s)))
    pts.append((x0, y0 - 0.5))
    return np.array(pts)


def polygon(shape: str, k: int, seed: int = 0) -> np.ndarray:
    if shape == "star":
        return star(k, seed)
    if shape == "spikes":
        return spikes(k, seed)
    if shape == "comb":
        return comb(k)
    raise ValueError(shape)


def non_simple_twin(ring: np.ndarray, seed: int = 0) -> np.ndarray:
    """The ring with two vertices half of it apart swapped (at a seeded place): their four edges cross
    the ring's other side."""
    k = len(ring)
    j = int(np.random.default_rng(seed).integers(0, k))
    twin = ring.copy()
    twin[[j, (j + k // 2) % k]] = twin[[(j + k // 2) % k, j]]
    return twin


# ---- the baseline ---------------------------------------------------------------------------------

def pairwise_is_simple(v: np.ndarray, block_pairs: int = 1_000_000) -> bool:
    """The classic simplicity test of the closed ring ``v`` (k, 2), vectorised: every pair of edges
    (i < j), in blocks of about ``block_pairs`` pairs, intersects if the endpoints of each lie strictly
    on both sides of the other, or an endpoint lies on the other segment (zero orientation, within
    its bounding box). Neighbouring edges share their common vertex and no other point. Edges of zero
    length make the ring not simple (as in :func:`nhstab.geometry.is_simple_polygon`)."""
    v = np.asarray(v, dtype=float)
    k = len(v)
    if k < 3:
        return False
    a, b = v, np.roll(v, -1, axis=0)
    if np.any(np.all(a == b, axis=1)):
        return False
    lo, hi = np.minimum(a, b), np.maximum(a, b)

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    def within(p, low, high):
        return (p[..., 0] >= low[..., 0]) & (p[..., 0] <= high[..., 0]) & (p[..., 1] >= low[..., 1]) & (p[..., 1] <= high[..., 1])

    rows = max(1, block_pairs // k)
    for i0 in range(0, k - 1, rows):
        i = np.arange(i0, min(i0 + rows, k - 1))[:, None]
        j = np.arange(i0 + 1, k)[None, :]              # the pairs j > i of these rows (and a few j <= i, masked)
        P1, P2, Pl, Ph = a[i], b[i], lo[i], hi[i]
        Q1, Q2, Ql, Qh = a[j], b[j], lo[j], hi[j]
        o1, o2, o3, o4 = orient(P1, P2, Q1), orient(P1, P2, Q2), orient(Q1, Q2, P1), orient(Q1, Q2, P2)
        after = j == i + 1                             # edge j starts where edge i ends: b[i] == a[j]
        wrap = (i == 0) & (j == k - 1)                 # edge j ends where edge 0 starts: b[j] == a[0]
        touch = (((o1 == 0) & within(Q1, Pl, Ph) & ~after) | ((o2 == 0) & within(Q2, Pl, Ph) & ~wrap)
                 | ((o3 == 0) & within(P1, Ql, Qh) & ~wrap) | ((o4 == 0) & within(P2, Ql, Qh) & ~after))
        cross = (o1 * o2 < 0) & (o3 * o4 < 0)
        if np.any((j > i) & (cross | touch)):
            return False
    return True


# ---- the measures -----------------------------------------------------------------------------------

def _yaml_map(path: Path, ring: np.ndarray) -> Path:
    pts = ", ".join(f"[{x:.9f}, {y:.9f}]" for x, y in ring)
    path.write_text(f"name: polygon bench\nbounds: [{', '.join(f'{b:g}' for b in _BOUNDS)}]\nobstacles:\n"
                    f"  - polygon: [{pts}]\nstart: [1.0, 0.5, 0.0]\ngoal: [11.0, 0.5, 0.0]\nrobot: {{model: unicycle}}\n")
    return path


def _timed(fn, repeats: int) -> tuple[dict, object]:
    best, median, result = _best(fn, repeats)
    return {"best_s": best, "median_s": median, "repeats": repeats}, result


def _exponent(ks, times) -> float | None:
    ks, times = np.asarray(ks, dtype=float), np.asarray(times, dtype=float)
    if len(ks) < 2 or np.any(times <= 0):
        return None
    return float(np.polyfit(np.log(ks), np.log(times), 1)[0])


def _measure(shape: str, k: int, seed: int, repeats: int, baseline_repeats: int, folder: Path) -> dict:
    clear = geometry._is_simple_ring.cache_clear
    ring = polygon(shape, k, seed)
    times = {}
    times["simple"], simple = _timed(lambda: (clear(), geometry.is_simple_polygon(ring))[1], repeats)
    spec = {"polygon": ((ring - ring.mean(axis=0)) / 10).tolist()}        # a robot's size, about its centre
    times["footprint"], fp = _timed(lambda: (clear(), parse_footprint(spec))[1], repeats)
    path = _yaml_map(folder / f"{shape}_{k}.yaml", ring)
    loads, worlds = [], []
    for _ in range(repeats):
        clear()
        started = time.perf_counter()
        m = load_map(path)
        loaded = time.perf_counter()
        world = CollisionWorld.from_map(m, "known")
        loads.append(loaded - started)
        worlds.append(time.perf_counter() - loaded)
    for name, ts in (("map", np.add(loads, worlds)), ("map_load", loads), ("map_world", worlds)):
        times[name] = {"best_s": float(np.min(ts)), "median_s": float(np.median(ts)), "repeats": repeats}
    times["raster"], (free, cell) = _timed(lambda: free_fraction(m), repeats)
    times["baseline"], base = _timed(lambda: pairwise_is_simple(ring), baseline_repeats)
    twin = non_simple_twin(ring, seed)
    clear()
    twin_geos, twin_base = geometry.is_simple_polygon(twin), pairwise_is_simple(twin)
    return {"shape": shape, "k": k, "vertices": len(ring), "seed": seed,
            "geos_simple": simple, "baseline_simple": base,
            "twin_geos_simple": twin_geos, "twin_baseline_simple": twin_base,
            "agree": bool(simple == base and twin_geos == twin_base),
            "footprint_vertices": len(fp.vertices), "map_obstacles": len(m.obstacles),
            "world_objects": world.n_objects, "free_fraction": free, "free_fraction_cell_m": cell,
            "times": times}


def bench_polygons(sizes=SIZES, seed: int = 7, repeats: int | None = None, baseline_repeats: int | None = None,
                   progress=None) -> dict:
    """The polygon checks on the star and the comb at each of ``sizes`` vertices (default up to
    MAX_POLYGON_VERTICES), against the vectorised pairwise baseline. ``repeats`` (default 5 up to
    2,500 vertices, 3 above) and ``baseline_repeats`` (default 3) per measure."""
    sizes = tuple(int(k) for k in sizes)
    if not sizes or min(sizes) < 6 or max(sizes) > MAX_POLYGON_VERTICES:
        raise ValueError(f"sizes must lie in [6, {MAX_POLYGON_VERTICES}]: {sizes}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="nhstab-bench-polygons-") as tmp:
        _measure("star", 50, seed, 1, 1, Path(tmp))                     # warm-up: imports, first calls
        for shape in SHAPES:
            for k in sizes:
                n = repeats if repeats is not None else (5 if k <= 2_500 else 3)
                nb = baseline_repeats if baseline_repeats is not None else 3
                rows.append(_measure(shape, k, seed, n, nb, Path(tmp)))
                if progress is not None:
                    t = rows[-1]["times"]
                    progress(f"polygons: {shape} k={k}: " + ", ".join(f"{m} {t[m]['median_s'] * 1e3:.1f} ms" for m in METHODS))
    exponents = {shape: {m: _exponent([r["vertices"] for r in rows if r["shape"] == shape],
                                      [r["times"][m]["median_s"] for r in rows if r["shape"] == shape])
                         for m in METHODS} for shape in SHAPES}
    k_max = max(sizes)
    at_max = {shape: next(r for r in rows if r["shape"] == shape and r["k"] == k_max) for shape in SHAPES}
    speedup = {shape: at_max[shape]["times"]["baseline"]["median_s"] / at_max[shape]["times"]["simple"]["median_s"]
               for shape in SHAPES}
    met = {f"{m} at k = {k_max:,} within {TARGET_S:g} s, {shape}": bool(at_max[shape]["times"][m]["median_s"] <= TARGET_S)
           for shape in SHAPES for m in CHECKS}
    met.update({f"{m} exponent below {TARGET_STAR_EXPONENT:g}, star":
                bool(exponents["star"][m] is not None and exponents["star"][m] < TARGET_STAR_EXPONENT) for m in CHECKS})
    met["baseline and GEOS agree on every polygon"] = all(r["agree"] for r in rows)
    return {
        "benchmark": "polygons", "machine": machine(), "sizes": list(sizes), "seed": seed,
        "max_polygon_vertices": MAX_POLYGON_VERTICES, "at_max_size": k_max == MAX_POLYGON_VERTICES,
        "methods": {
            "simple": "nhstab.geometry.is_simple_polygon (GEOS ring simplicity test, its cache cleared)",
            "footprint": "nhstab.robot.parse_footprint({'polygon': [...]}) (the cache cleared)",
            "map": "load_map of a YAML map with the polygon as its one obstacle + CollisionWorld.from_map(m, 'known')",
            "map_load": "load_map (the YAML reader's checks)",
            "map_world": "CollisionWorld.from_map(m, 'known') (GEOS constrained Delaunay triangulation, FCL parts)",
            "raster": "nhstab.maps.raster.free_fraction(m) (the scanline fill that nhstab map info prints)",
            "baseline": BASELINE,
        },
        "baseline": BASELINE, "rows": rows, "exponents": exponents,
        "speedup_over_baseline_at_max": speedup,
        "targets": {"check_s_max": TARGET_S, "at_k": k_max, "checks": list(CHECKS),
                    "star_exponent_max": TARGET_STAR_EXPONENT},
        "met": met,
    }


def summary_lines(r: dict) -> list[str]:
    """Rows of the benchmark summary table (benchmark | measure | value | target | met)."""
    lines = []
    k_max = r["targets"]["at_k"]
    below = "" if r["at_max_size"] else f" (below the maximum {r['max_polygon_vertices']:,})"
    for shape in SHAPES:
        rows = [row for row in r["rows"] if row["shape"] == shape]
        for m in METHODS:
            times = ", ".join(f"{row['vertices']:,}: {row['times'][m]['median_s'] * 1e3:.3g}" for row in rows)
            e = r["exponents"][shape][m]
            lines.append(f"| polygons | {shape}, {m}: median ms at k = {times} | exponent "
                         f"{'n/a' if e is None else f'{e:.2f}'} | - | - |")
        at = next(row for row in rows if row["k"] == k_max)
        for m in CHECKS:
            v = at["times"][m]["median_s"]
            lines.append(f"| polygons | {shape}, {m} at k = {k_max:,}{below} | {v * 1e3:.1f} ms | <= {r['targets']['check_s_max']:g} s | "
                         f"{'yes' if v <= r['targets']['check_s_max'] else 'NO'} |")
        lines.append(f"| polygons | {shape}: GEOS simplicity test against the vectorised pairwise baseline at k = {k_max:,} | "
                     f"{r['speedup_over_baseline_at_max'][shape]:.1f}x faster | - | - |")
    for m in CHECKS:
        e = r["exponents"]["star"][m]
        lines.append(f"| polygons | star, {m}: scaling exponent (log time against log k) | "
                     f"{'n/a' if e is None else f'{e:.2f}'} | < {r['targets']['star_exponent_max']:g} | "
                     f"{'yes' if e is not None and e < r['targets']['star_exponent_max'] else 'NO'} |")
    agree = all(row["agree"] for row in r["rows"])
    lines.append(f"| polygons | baseline and GEOS agree on simplicity (each polygon and its non-simple twin) | "
                 f"{'yes' if agree else 'no'} | yes | {'yes' if agree else 'NO'} |")
    return lines
