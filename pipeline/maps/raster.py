"""Rasterising a map's obstacles onto a regular grid (free fraction, drawing, distance fields).

No FCL: polygons are filled row by row on cell centres (:func:`ring_cells`), circles analytically,
occupancy grids by looking up the cell each centre falls into.
"""

from __future__ import annotations

import math

import numpy as np

from .base import Circle, Map, OccupancyGrid, Polygon


def raster_shape(m: Map, resolution: float | None = None, max_cells: int = 2_000_000) -> tuple[int, int, float]:
    """(rows, cols, cell) covering the map's bounds, at ``resolution`` (default: the finest grid's,
    or 1/1000 of the larger side), coarsened if needed to stay within ``max_cells``."""
    w, h = m.size
    if resolution is None:
        resolution = min([g.resolution for g in m.grids], default=max(w, h) / 1000.0)
    cell = float(resolution)
    while math.ceil(w / cell) * math.ceil(h / cell) > max_cells:
        cell *= 1.5
    return math.ceil(h / cell), math.ceil(w / cell), cell


def occupancy(m: Map, which: str = "known", resolution: float | None = None) -> tuple[np.ndarray, float]:
    """Boolean raster (row 0 at ymin) of the obstacles: ``which`` is "known", "unknown" or "all".

    A cell counts as occupied when its centre lies in an obstacle."""
    rows, cols, cell = raster_shape(m, resolution)
    xmin, ymin = m.bounds[0], m.bounds[1]
    xs = xmin + (np.arange(cols) + 0.5) * cell
    ys = ymin + (np.arange(rows) + 0.5) * cell
    occ = np.zeros((rows, cols), dtype=bool)
    shapes = []
    if which in ("known", "all"):
        shapes += list(m.obstacles)
        for g in m.grids:
            _mark_grid(occ, g, xs, ys)
    if which in ("unknown", "all"):
        shapes += list(m.unknown_obstacles)
    for s in shapes:
        _mark_shape(occ, s, xs, ys)
    return occ, cell


def free_fraction(m: Map, resolution: float | None = None) -> tuple[float, float]:
    """Fraction of the bounds free of known obstacles, and the raster cell size it was measured at.

    For a map made of one axis-aligned grid whose cells tile the bounds this is the exact cell count.
    """
    if len(m.grids) == 1 and not m.obstacles and m.grids[0].origin[2] == 0.0 and \
            np.allclose(m.grids[0].bounds(), m.bounds):
        g = m.grids[0]
        return 1.0 - float(g.occupied.mean()), g.resolution
    occ, cell = occupancy(m, "known", resolution)
    return 1.0 - float(occ.mean()), cell


def _index_range(lo, hi, axis):
    a = int(np.searchsorted(axis, lo, side="left"))
    b = int(np.searchsorted(axis, hi, side="right"))
    return a, b


def _mark_shape(occ, s, xs, ys):
    x0, y0, x1, y1 = s.bounds()
    ja, jb = _index_range(x0, x1, xs)
    ia, ib = _index_range(y0, y1, ys)
    if ja >= jb or ia >= ib:
        return
    X, Y = np.meshgrid(xs[ja:jb], ys[ia:ib])
    if isinstance(s, Circle):
        inside = (X - s.center[0]) ** 2 + (Y - s.center[1]) ** 2 <= s.radius ** 2
    elif isinstance(s, Polygon):
        inside = ring_cells(s.vertices, xs[ja:jb], ys[ia:ib])
    else:  # pragma: no cover - Map only holds these
        raise TypeError(type(s).__name__)
    occ[ia:ib, ja:jb] |= inside


#: ring_cells handles the edges in chunks that cross at most this many rows in all (memory: 40 bytes each)
CROSSINGS_PER_CHUNK = 1 << 22


def ring_cells(v: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """The cells (len(ys), len(xs)) whose centres (xs[j], ys[i]), both increasing, lie inside the closed
    ring ``v`` (k, 2) by the even-odd rule (a ring drawn out and back encloses nothing). A scanline
    fill: each edge toggles, on every row whose centre line it crosses (ya <= y < yb either way), the
    cells to the right of the crossing. The work is the crossings, at most k x rows, whatever the
    shape, where a point-in-polygon test per cell is k x cells at worst."""
    v = np.asarray(v, dtype=float)
    a, b = v, np.roll(v, -1, axis=0)
    lo, hi = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
    i0 = np.searchsorted(ys, lo, side="left")
    i1 = np.searchsorted(ys, hi, side="left")        # rows with lo <= y < hi
    n = i1 - i0
    rows, cols = len(ys), len(xs)
    toggles = np.zeros(rows * (cols + 1), dtype=np.int64)
    cum = np.cumsum(n)
    start = 0
    while start < len(v):
        stop = int(np.searchsorted(cum, (cum[start - 1] if start else 0) + CROSSINGS_PER_CHUNK, side="right"))
        stop = max(stop, start + 1)
        e = np.arange(start, stop)
        e = e[n[e] > 0]
        start = stop
        if not len(e):
            continue
        edge = np.repeat(e, n[e])
        first = np.cumsum(n[e]) - n[e]
        row = i0[edge] + (np.arange(len(edge)) - np.repeat(first, n[e]))
        ax, ay, bx, by = a[edge, 0], a[edge, 1], b[edge, 0], b[edge, 1]
        x = ax + (ys[row] - ay) * (bx - ax) / (by - ay)
        col = np.searchsorted(xs, x, side="right")        # the first centre right of the crossing
        toggles += np.bincount(row * (cols + 1) + col, minlength=len(toggles))
    return (np.cumsum(toggles.reshape(rows, cols + 1), axis=1)[:, :cols] % 2).astype(bool)


def _mark_grid(occ, g: OccupancyGrid, xs, ys):
    X, Y = np.meshgrid(xs, ys)
    i, j = g.world_to_cell(X, Y)
    H, W = g.shape
    ok = (i >= 0) & (i < H) & (j >= 0) & (j < W)
    hit = np.zeros(X.shape, dtype=bool)
    hit[ok] = g.occupied[i[ok], j[ok]]
    occ |= hit
