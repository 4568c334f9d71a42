"""Rasterising a map's obstacles onto a regular grid (free fraction, drawing, distance fields).

No FCL: polygons are tested with matplotlib's point-in-path on cell centres, circles analytically,
occupancy grids by looking up the cell each centre falls into.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.path import Path as MplPath

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
        inside = MplPath(s.vertices).contains_points(np.column_stack([X.ravel(), Y.ravel()])).reshape(X.shape)
    else:  # pragma: no cover - Map only holds these
        raise TypeError(type(s).__name__)
    occ[ia:ib, ja:jb] |= inside


def _mark_grid(occ, g: OccupancyGrid, xs, ys):
    X, Y = np.meshgrid(xs, ys)
    i, j = g.world_to_cell(X, Y)
    H, W = g.shape
    ok = (i >= 0) & (i < H) & (j >= 0) & (j < W)
    hit = np.zeros(X.shape, dtype=bool)
    hit[ok] = g.occupied[i[ok], j[ok]]
    occ |= hit
