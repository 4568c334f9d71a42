"""A conservative raster distance field of a map's obstacles (no FCL here).

:class:`ClearanceField` gives, from a distance transform of a raster, a lower bound on the distance
from any point to the obstacles, and from it cheap certain answers for footprints at many poses:
certainly free (:meth:`ClearanceField.surely_free`), certainly colliding
(:meth:`ClearanceField.surely_colliding`), and lower bounds of the clearance from disc covers
(:func:`disc_cover`). :mod:`nhstab.collision` (FCL, the exact authority) uses it as a
prefilter, so that only the poses it cannot decide reach FCL.
"""

from __future__ import annotations

import math

import numpy as np

from .geometry import Footprint


class ClearanceField:
    """A lower bound on the distance from any point to the obstacles, from a raster.

    Cells of size r are marked occupied when an obstacle may touch them: cells whose centre lies in
    an obstacle, cells holding a point of its boundary sampled every r/2, then grown by one cell
    (so a corner clipped between two samples is covered too); an axis-aligned box whose corners lie
    on the raster's cell boundaries (the cells of an occupancy grid on its own raster) marks exactly
    the cells it is made of, which hold all of its points; circles mark every cell within
    radius + r/sqrt(2) of their centre; everything outside the bounds counts as occupied (the
    walls). With D the Euclidean distance transform between cell centres, every point p satisfies
    dist(p, obstacles) >= D(cell of p) - sqrt(2) r: p and the obstacle point each lie within
    r/sqrt(2) of their cells' centres.
    """

    MAX_CELLS = 4_000_000
    #: a map without grids (vector shapes only): cells along its larger side
    CELLS_PER_SIDE = 512
    #: mark axis-aligned boxes (a grid's cells) all at once (False: one by one, as other polygons;
    #: the same cells, tests/geometry/test_collision.py compares them)
    VECTORISED_BOXES = True
    #: elements of the (poses x footprint points) arrays of one vectorised block
    BLOCK = 1 << 16

    def __init__(self, bounds, resolutions, outlines):
        """``bounds`` (xmin, ymin, xmax, ymax); ``resolutions``: the cell sizes of the map's grids (the
        raster uses the finest, else 1/512 of the larger side); ``outlines``: the obstacles, each
        ("poly", vertices (k, 2) convex part or polygon) or ("circle", centre, radius)."""
        from scipy.ndimage import distance_transform_edt

        xmin, ymin, xmax, ymax = bounds
        r = min(resolutions, default=max(xmax - xmin, ymax - ymin) / self.CELLS_PER_SIDE)
        while ((xmax - xmin) / r + 4) * ((ymax - ymin) / r + 4) > self.MAX_CELLS:
            r *= 1.5
        pad = 2
        self.r = r
        self.x0, self.y0 = xmin - pad * r, ymin - pad * r
        cols = int(math.ceil((xmax - xmin) / r)) + 2 * pad
        rows = int(math.ceil((ymax - ymin) / r)) + 2 * pad
        occ = np.zeros((rows, cols), dtype=bool)
        xs = self.x0 + (np.arange(cols) + 0.5) * r
        ys = self.y0 + (np.arange(rows) + 0.5) * r
        occ[:, xs < xmin] = occ[:, xs > xmax] = True
        occ[ys < ymin, :] = occ[ys > ymax, :] = True
        more, self.inside = self._mark(outlines, occ.shape)
        self.lower_bound = distance_transform_edt(~(occ | more)) * r - math.sqrt(2) * r

    def with_outlines(self, outlines) -> "ClearanceField":
        """The field of these obstacles added to this one's, on the same raster: the distance to a union
        is the smaller of the distances, so only the new obstacles are rasterised."""
        from scipy.ndimage import distance_transform_edt

        new = object.__new__(ClearanceField)
        new.r, new.x0, new.y0 = self.r, self.x0, self.y0
        occ, inside = new._mark(outlines, self.lower_bound.shape)
        new.inside = self.inside | inside
        if occ.any():
            bound = distance_transform_edt(~occ) * self.r - math.sqrt(2) * self.r
            new.lower_bound = np.minimum(self.lower_bound, bound)
        else:
            new.lower_bound = self.lower_bound
        return new

    def _mark(self, outlines, shape):
        """(occupied, inside) rasters of the obstacles (see the class docstring)."""
        from matplotlib.path import Path as MplPath
        from scipy.ndimage import binary_dilation, binary_erosion

        r = self.r
        rows, cols = shape
        occ = np.zeros(shape, dtype=bool)
        xs = self.x0 + (np.arange(cols) + 0.5) * r
        ys = self.y0 + (np.arange(rows) + 0.5) * r
        grown = np.zeros_like(occ)
        # cells certainly inside an obstacle: per convex part, cells whose 3 x 3 block of centres is
        # inside (by convexity the cell lies in the square those centres span); per circle, cells
        # whose farthest corner is inside.
        self.inside = np.zeros_like(occ)
        # axis-aligned boxes (every merged cell block of a grid): all at once, as the loop below
        # would mark them one by one
        quads = [k for k, o in enumerate(outlines) if o[0] != "circle" and len(o[1]) == 4] if self.VECTORISED_BOXES else []
        if quads:
            v = np.stack([outlines[k][1] for k in quads])                       # (q, 4, 2)
            d = np.roll(v, -1, axis=1) - v
            aligned = np.all((np.abs(d[..., 0]) < 1e-12) | (np.abs(d[..., 1]) < 1e-12), axis=1)
            if aligned.any():
                va = v[aligned]
                self._add_boxes(np.column_stack([va[..., 0].min(1), va[..., 1].min(1), va[..., 0].max(1),
                                                 va[..., 1].max(1)]), occ, grown, xs, ys)
                done = {quads[k] for k in np.flatnonzero(aligned)}
                outlines = [o for k, o in enumerate(outlines) if k not in done]
        for outline in outlines:
            if outline[0] == "circle":
                (cx, cy), rad = outline[1], outline[2]
                ja, jb = self._span(cx - rad - r, cx + rad + r, self.x0, cols)
                ia, ib = self._span(cy - rad - r, cy + rad + r, self.y0, rows)
                X, Y = np.meshgrid(xs[ja:jb], ys[ia:ib])
                occ[ia:ib, ja:jb] |= np.hypot(X - cx, Y - cy) <= rad + r / math.sqrt(2)
                self.inside[ia:ib, ja:jb] |= np.hypot(np.abs(X - cx) + r / 2, np.abs(Y - cy) + r / 2) <= rad
                continue
            v = outline[1]
            ja, jb = self._span(v[:, 0].min(), v[:, 0].max(), self.x0, cols)
            ia, ib = self._span(v[:, 1].min(), v[:, 1].max(), self.y0, rows)
            if jb > ja and ib > ia:
                X, Y = np.meshgrid(xs[ja:jb], ys[ia:ib])
                inside = MplPath(v).contains_points(np.column_stack([X.ravel(), Y.ravel()])).reshape(X.shape)
                if axis_aligned_box(v):
                    # exactly the cells whose whole square lies in the box
                    tol = 1e-9 * r
                    inx = (xs[ja:jb] - r / 2 >= v[:, 0].min() - tol) & (xs[ja:jb] + r / 2 <= v[:, 0].max() + tol)
                    iny = (ys[ia:ib] - r / 2 >= v[:, 1].min() - tol) & (ys[ia:ib] + r / 2 <= v[:, 1].max() + tol)
                    cells = iny[:, None] & inx[None, :]
                    self.inside[ia:ib, ja:jb] |= cells
                    if _on_raster(v, self.x0, self.y0, r):
                        # a box made of whole raster cells (an occupancy grid's cells): those cells
                        # hold every point of it, so they alone are marked (the bound's premise)
                        occ[ia:ib, ja:jb] |= cells
                        continue
                    grown[ia:ib, ja:jb] |= inside
                else:
                    grown[ia:ib, ja:jb] |= inside
                    self.inside[ia:ib, ja:jb] |= binary_erosion(inside, structure=np.ones((3, 3), dtype=bool),
                                                                border_value=0)
            a, b = v, np.roll(v, -1, axis=0)
            n = np.maximum(1, np.ceil(np.hypot(*(b - a).T) / (r / 2))).astype(int)
            t = np.concatenate([np.arange(k + 1) / k for k in n])
            starts = np.repeat(a, n + 1, axis=0)
            ends = np.repeat(b, n + 1, axis=0)
            pts = starts + t[:, None] * (ends - starts)
            j = np.clip(np.floor((pts[:, 0] - self.x0) / r).astype(int), 0, cols - 1)
            i = np.clip(np.floor((pts[:, 1] - self.y0) / r).astype(int), 0, rows - 1)
            grown[i, j] = True
        if grown.any():
            occ |= binary_dilation(grown, structure=np.ones((3, 3), dtype=bool))
        return occ, self.inside

    def _add_boxes(self, b: np.ndarray, occ: np.ndarray, grown: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> None:
        """Axis-aligned boxes (k, 4) = (xmin, ymin, xmax, ymax), marked all at once with exactly the
        cells the loop in :meth:`_mark` marks for them one by one: ``inside`` gets the cells whose
        whole square lies in a box; a box made of whole raster cells (on the raster, and meeting it)
        puts those cells in ``occ``; any other box puts in ``grown`` every cell it touches (its
        boundary cells and the cells whose centre it contains: together, the index rectangle of its
        corners, clipped to the raster as the boundary samples are). Rectangles are filled through a
        2-D difference array: O(cells + boxes) instead of a Python loop per box (a grid's cells)."""
        rows, cols = grown.shape
        r = self.r
        tol = 1e-9 * r
        jlo = np.searchsorted(xs - r / 2, b[:, 0] - tol, side="left")
        jhi = np.searchsorted(xs + r / 2, b[:, 2] + tol, side="right")
        ilo = np.searchsorted(ys - r / 2, b[:, 1] - tol, side="left")
        ihi = np.searchsorted(ys + r / 2, b[:, 3] + tol, side="right")
        cells = _fill(rows, cols, ilo, jlo, ihi, jhi)
        self.inside |= cells
        # the loop's span test (cells whose centres may lie in the box) and _on_raster, per box
        ja = np.maximum(0, np.floor((b[:, 0] - self.x0) / r - 0.5)).astype(np.int64)
        jb = np.minimum(cols, np.ceil((b[:, 2] - self.x0) / r + 0.5)).astype(np.int64)
        ia = np.maximum(0, np.floor((b[:, 1] - self.y0) / r - 0.5)).astype(np.int64)
        ib = np.minimum(rows, np.ceil((b[:, 3] - self.y0) / r + 0.5)).astype(np.int64)
        u = np.column_stack([(b[:, 0] - self.x0) / r, (b[:, 2] - self.x0) / r, (b[:, 1] - self.y0) / r,
                             (b[:, 3] - self.y0) / r])
        on = np.all(np.abs(u - np.round(u)) <= 1e-9 * np.maximum(1.0, np.abs(u).max(axis=1))[:, None], axis=1)
        exact = on & (jb > ja) & (ib > ia)
        if exact.any():
            occ |= _fill(rows, cols, ilo[exact], jlo[exact], ihi[exact], jhi[exact])
        rest = ~exact
        if rest.any():
            c = b[rest]
            j0 = np.clip(np.floor((c[:, 0] - self.x0) / r).astype(np.int64), 0, cols - 1)
            i0 = np.clip(np.floor((c[:, 1] - self.y0) / r).astype(np.int64), 0, rows - 1)
            j1 = np.clip(np.floor((c[:, 2] - self.x0) / r).astype(np.int64), 0, cols - 1)
            i1 = np.clip(np.floor((c[:, 3] - self.y0) / r).astype(np.int64), 0, rows - 1)
            grown |= _fill(rows, cols, i0, j0, i1 + 1, j1 + 1)

    def _span(self, lo, hi, origin, n):
        """Index range [a, b) of the cells whose centres may lie in [lo, hi]."""
        return (max(0, int(math.floor((lo - origin) / self.r - 0.5))),
                min(n, int(math.ceil((hi - origin) / self.r + 0.5))))

    def at(self, x, y) -> np.ndarray:
        """Lower bound of the distance to the obstacles at points (x, y); -inf outside the raster."""
        j = np.floor((np.asarray(x) - self.x0) / self.r).astype(int)
        i = np.floor((np.asarray(y) - self.y0) / self.r).astype(int)
        rows, cols = self.lower_bound.shape
        ok = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
        out = np.full(np.shape(j), -np.inf)
        out[ok] = self.lower_bound[i[ok], j[ok]]
        return out

    def surely_colliding(self, poses: np.ndarray, fp: Footprint, spacing: float | None = None) -> np.ndarray:
        """Poses where a point of the footprint lies in a cell certainly inside an obstacle. The points:
        its reference point, vertices and edge midpoints; with ``spacing``, its outline sampled at
        that spacing too."""
        u, v = footprint_points(fp, spacing).T
        rows, cols = self.inside.shape
        hit = np.zeros(len(poses), dtype=bool)
        step = max(1, self.BLOCK // len(u))             # poses per block of (poses x points) arrays
        for lo in range(0, len(poses), step):
            p = poses[lo:lo + step]
            c, s = np.cos(p[:, 2:3]), np.sin(p[:, 2:3])
            j = np.floor((p[:, 0:1] + c * u - s * v - self.x0) / self.r).astype(int)
            i = np.floor((p[:, 1:2] + s * u + c * v - self.y0) / self.r).astype(int)
            ok = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
            hit[lo:lo + step] = np.any(self.inside[np.where(ok, i, 0), np.where(ok, j, 0)] & ok, axis=1)
        return hit

    def surely_free(self, poses: np.ndarray, fp: Footprint, margin: float) -> np.ndarray:
        """Poses whose footprint is provably more than ``margin`` from the obstacles: every disc of its
        coarse cover clear by its radius + margin, or, for those that fail, every disc of the fine
        cover (:func:`disc_cover`)."""
        ok = self._discs_clear(poses, disc_cover(fp), margin)
        if fp.radius is None and not ok.all():
            retry = np.flatnonzero(~ok)
            ok[retry] = self._discs_clear(poses[retry], disc_cover(fp, FINE_DISCS_PER_WIDTH), margin)
        return ok

    def cover_bound(self, poses: np.ndarray, cover) -> np.ndarray:
        """Lower bound of the clearance of the footprint a disc ``cover`` ((centres, radii), from
        :func:`disc_cover`) covers, at each of the poses (N, 3): the smallest over its discs of the field
        at the disc's centre less its radius (all discs in one lookup)."""
        centres, radii = cover
        uv = np.asarray(centres, dtype=float).reshape(-1, 2)
        u, v = uv[:, 0:1], uv[:, 1:2]
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        x = poses[:, 0] + c * u - s * v                     # (discs, N)
        y = poses[:, 1] + s * u + c * v
        return (self.at(x, y) - np.asarray(radii, dtype=float)[:, None]).min(axis=0, initial=np.inf)

    def _discs_clear(self, poses: np.ndarray, cover, margin: float) -> np.ndarray:
        centres, radii = cover
        ok = np.ones(len(poses), dtype=bool)
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        for (u, v), rad in zip(centres, radii):
            x = poses[:, 0] + c * u - s * v
            y = poses[:, 1] + s * u + c * v
            ok &= self.at(x, y) > rad + margin
        return ok


def _fill(rows: int, cols: int, i0, j0, i1, j1) -> np.ndarray:
    """The union of the index rectangles [i0, i1) x [j0, j1) (empty ones ignored), as a bool raster."""
    keep = (i1 > i0) & (j1 > j0)
    i0, j0, i1, j1 = i0[keep], j0[keep], i1[keep], j1[keep]
    diff = np.zeros((rows + 1, cols + 1), dtype=np.int64)
    np.add.at(diff, (i0, j0), 1)
    np.add.at(diff, (i0, j1), -1)
    np.add.at(diff, (i1, j0), -1)
    np.add.at(diff, (i1, j1), 1)
    return np.cumsum(np.cumsum(diff, axis=0), axis=1)[:rows, :cols] > 0


def footprint_points(fp: Footprint, spacing: float | None) -> np.ndarray:
    """The footprint's reference point (0, 0) first, then its vertices and edge midpoints, or with
    ``spacing`` its outline sampled at that spacing (robot frame, (k, 2))."""
    if fp.radius is not None:
        if spacing is None:
            return np.zeros((1, 2))
        n = max(8, int(math.ceil(2 * math.pi * fp.radius / spacing)))
        a = np.arange(n) * 2 * math.pi / n
        return np.vstack([[0.0, 0.0], fp.radius * np.column_stack([np.cos(a), np.sin(a)])])
    v = fp.vertices
    if spacing is None:
        return np.vstack([[0.0, 0.0], v, 0.5 * (v + np.roll(v, -1, axis=0))])
    b = np.roll(v, -1, axis=0)
    n = np.maximum(1, np.ceil(np.hypot(*(b - v).T) / spacing)).astype(int)
    t = np.concatenate([np.arange(k) / k for k in n])
    return np.vstack([[0.0, 0.0], np.repeat(v, n, axis=0) + t[:, None] * np.repeat(b - v, n, axis=0)])


def _on_raster(v: np.ndarray, x0: float, y0: float, r: float) -> bool:
    """Do the corners of an axis-aligned box lie on the raster's cell boundaries?"""
    u = np.concatenate([(v[:, 0] - x0) / r, (v[:, 1] - y0) / r])
    return bool(np.all(np.abs(u - np.round(u)) <= 1e-9 * max(1.0, float(np.abs(u).max()))))


def axis_aligned_box(v: np.ndarray) -> bool:
    if len(v) != 4:
        return False
    d = np.roll(v, -1, axis=0) - v
    return bool(np.all((np.abs(d[:, 0]) < 1e-12) | (np.abs(d[:, 1]) < 1e-12)))


#: the fine disc cover (:func:`disc_cover`) puts this many discs per width along the footprint
FINE_DISCS_PER_WIDTH = 3


def disc_cover(fp: Footprint, per_width: float = 1.0):
    """Discs (centres in the robot frame, radii) whose union contains the footprint: one row of equal
    discs along its bounding box, ``per_width`` per width of length (at least one). One per width
    (the coarse cover) overhangs a 4.4 m x 1.8 m car's sides by 0.26 m; three per width (the fine one,
    ``FINE_DISCS_PER_WIDTH``) by 0.04 m, at three times the lookups."""
    if fp.radius is not None:
        return [(0.0, 0.0)], [fp.radius]
    v = fp.vertices
    x0, y0 = v.min(axis=0)
    x1, y1 = v.max(axis=0)
    length, width = x1 - x0, y1 - y0
    k = max(1, int(math.ceil(per_width * length / max(width, 1e-9) - 1e-9)))
    seg = length / k
    radius = math.hypot(seg / 2, width / 2)
    return [(x0 + (q + 0.5) * seg, (y0 + y1) / 2) for q in range(k)], [radius] * k
