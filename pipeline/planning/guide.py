"""A guide for the nonholonomic search: a shortest path on the map's grid for the robot's inscribed disc.

The conservative distance field of the collision world (:class:`nhstab.clearance_field.ClearanceField`)
is pooled to guide cells (about half the inscribed radius, at most ``MAX_CELLS``); a cell is passable
when its estimated clearance exceeds the inscribed radius plus the margin (the robot's inscribed disc,
centred on the footprint's centre, fits there). On the 8-connected graph of passable cells,
``scipy.sparse.csgraph.dijkstra`` from the goal gives a cost-to-go everywhere; the guide path follows
it from the start. Step costs are the step length times a factor that grows from 1 to 1 +
``WALL_PENALTY`` as the clearance above the need shrinks below ``band``, so the guide keeps off the
walls where there is room (as Smac's cost-aware heuristics do) and takes the shortest way where
there is not.

The guide is a heuristic, never an authority: the planner connects poses along it with local paths
checked exactly (``nhstab.planning.geometric``). ``shortest_length()`` is the plain grid shortest
path (no wall penalty) between the same cells: the reference of the path-quality ratio.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import Footprint

#: guide cells at most (the raster is pooled until it fits)
MAX_CELLS = 400_000
#: the step-cost factor next to a wall is 1 + WALL_PENALTY
WALL_PENALTY = 1.0
_STEPS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, math.sqrt(2.0)), (1, -1, math.sqrt(2.0)))


def inscribed_disc(fp: Footprint) -> tuple[np.ndarray, float]:
    """Centre (robot frame) and radius of a disc inside the footprint: the disc itself, or for a
    polygon the largest disc about the centre of its bounding box that its edges allow."""
    if fp.radius is not None:
        return np.zeros(2), float(fp.radius)
    v = np.asarray(fp.vertices, dtype=float)
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    e = np.roll(v, -1, axis=0) - v
    n = np.column_stack([e[:, 1], -e[:, 0]]) / np.hypot(e[:, 0], e[:, 1])[:, None]
    dist = np.abs(np.einsum("ij,ij->i", c - v, n))
    return c, float(dist.min())


class Guide:
    """Grid shortest path from ``start`` to ``goal`` (poses of the robot's reference point) for the
    footprint's inscribed disc with ``margin``. ``ok`` is False when the grid has no path (then the
    planner searches unguided). ``points`` (P, 2) is the path of the disc's centre, ``arc`` its arc
    length; ``length_m`` the guide path's length."""

    def __init__(self, field, fp: Footprint, margin: float, start, goal, band: float | None = None,
                 cache: dict | None = None):
        """``field``: the world's ClearanceField; ``cache``: a dict kept with the world (the grids and
        graphs depend only on the field, the inscribed radius, the margin and the band, so later plans
        on the same world reuse them)."""
        import time

        started = time.perf_counter()
        self.centre, self.radius = inscribed_disc(fp)
        self.need = self.radius + float(margin)
        self.band = float(band) if band is not None else float(np.clip(2.0 * self.radius, 0.5, 2.0))
        self._cache = {} if cache is None else cache.setdefault((id(field), self.need, self.band), {})
        if "clearance" not in self._cache:
            r = field.r
            lb = field.lower_bound
            f = max(1, int(math.floor(0.5 * self.radius / r)))
            while lb.size / (f * f) > MAX_CELLS:
                f += 1
            rows, cols = lb.shape[0] // f, lb.shape[1] // f
            pooled = lb[: rows * f, : cols * f].reshape(rows, f, cols, f).min(axis=(1, 3))
            # the field's bound is pessimistic by about sqrt(2) r; the guide uses the central estimate
            self._cache.update(clearance=pooled + math.sqrt(2.0) * r, cell=f * r)
        self.clearance = self._cache["clearance"]
        self.cell = self._cache["cell"]
        self.x0, self.y0 = field.x0, field.y0
        self.shape = self.clearance.shape
        rows, cols = self.shape
        self.passable = self.clearance > self.need
        self.start_xy = self._disc_centre(start)
        self.goal_xy = self._disc_centre(goal)
        self.info = {"cell_m": self.cell, "cells": rows * cols, "passable_fraction": float(self.passable.mean()),
                     "inscribed_radius_m": self.radius, "need_m": self.need}
        self.ok = False
        self.points = np.zeros((0, 2))
        self.arc = np.zeros(0)
        self.length_m = math.inf
        s_cell, g_cell = self._snap(self.start_xy), self._snap(self.goal_xy)
        if s_cell is None or g_cell is None:
            self.info["failure"] = "no passable guide cell near the " + ("start" if s_cell is None else "goal")
        else:
            self._s_cell, self._g_cell = s_cell, g_cell
            cells = self._search(s_cell, g_cell, penalised=True)
            if cells is None:
                self.info["failure"] = "the grid has no path for the inscribed disc"
            else:
                pts = np.column_stack([self.x0 + (cells[:, 1] + 0.5) * self.cell,
                                       self.y0 + (cells[:, 0] + 0.5) * self.cell])
                pts = np.vstack([self.start_xy, pts, self.goal_xy])
                keep = np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-9])
                self.points = pts[keep]
                self.arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(self.points, axis=0).T))])
                self.length_m = float(self.arc[-1])
                self.ok = True
        self.info["time_s"] = time.perf_counter() - started

    # ---- geometry --------------------------------------------------------------------------------------
    def _disc_centre(self, pose) -> np.ndarray:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        u, v = self.centre
        return np.array([pose[0] + c * u - s * v, pose[1] + s * u + c * v])

    def reference_pose(self, xy, theta: float) -> np.ndarray:
        """The robot's reference pose whose inscribed disc is centred at ``xy`` with heading theta."""
        c, s = math.cos(theta), math.sin(theta)
        u, v = self.centre
        return np.array([xy[0] - (c * u - s * v), xy[1] - (s * u + c * v), theta])

    def _cell_of(self, xy) -> tuple[int, int]:
        return int((xy[1] - self.y0) // self.cell), int((xy[0] - self.x0) // self.cell)

    def _snap(self, xy):
        """The passable cell of xy, or the nearest passable one within a few cells (a start close to a
        wall sits in a cell the disc does not fit)."""
        i, j = self._cell_of(xy)
        rows, cols = self.shape
        reach = max(2, int(math.ceil(2.0 * self.need / self.cell)))
        i0, i1, j0, j1 = max(0, i - reach), min(rows, i + reach + 1), max(0, j - reach), min(cols, j + reach + 1)
        if i0 >= i1 or j0 >= j1:
            return None
        win = self.passable[i0:i1, j0:j1]
        if not win.any():
            return None
        ii, jj = np.nonzero(win)
        k = int(np.argmin((ii + i0 - i) ** 2 + (jj + j0 - j) ** 2))
        return int(ii[k] + i0), int(jj[k] + j0)

    # ---- search ----------------------------------------------------------------------------------------
    def _graph(self, penalised: bool):
        key = "graph_penalised" if penalised else "graph_plain"
        if key not in self._cache:
            self._cache[key] = self._build_graph(penalised)
        return self._cache[key]

    def _build_graph(self, penalised: bool):
        import scipy.sparse as sp

        rows, cols = self.shape
        idx = np.arange(rows * cols).reshape(rows, cols)
        ok = self.passable
        if penalised:
            excess = np.clip((self.clearance - self.need) / self.band, 0.0, 1.0)
            factor = 1.0 + WALL_PENALTY * (1.0 - excess)
        src, dst, w = [], [], []
        for di, dj, length in _STEPS:
            a = (slice(0, rows - di), slice(max(0, -dj), cols - max(0, dj)))
            b = (slice(di, rows), slice(max(0, dj), cols - max(0, -dj)))
            m = ok[a] & ok[b]
            src.append(idx[a][m])
            dst.append(idx[b][m])
            w.append(length * (0.5 * (factor[a][m] + factor[b][m])) if penalised else np.full(int(m.sum()), length))
        src, dst, w = np.concatenate(src), np.concatenate(dst), np.concatenate(w)
        n = rows * cols
        return sp.csr_matrix((np.concatenate([w, w]), (np.concatenate([src, dst]), np.concatenate([dst, src]))),
                             shape=(n, n))

    def _search(self, s_cell, g_cell, penalised: bool):
        from scipy.sparse.csgraph import dijkstra

        cols = self.shape[1]
        s, g = s_cell[0] * cols + s_cell[1], g_cell[0] * cols + g_cell[1]
        dist, pred = dijkstra(self._graph(penalised), directed=True, indices=g, return_predecessors=True)
        if not math.isfinite(dist[s]):
            return None
        if not penalised:
            return float(dist[s])
        path = [s]
        while path[-1] != g:
            path.append(int(pred[path[-1]]))
        path = np.asarray(path)
        return np.column_stack([path // cols, path % cols])

    def shortest_length(self) -> float:
        """The grid shortest path between the guide's start and goal cells, without the wall
        penalty, plus the straight pieces from the start's and to the goal's disc centres [m]."""
        if not self.ok:
            return math.inf
        if not hasattr(self, "_shortest"):
            d = self._search(self._s_cell, self._g_cell, penalised=False)
            ends = [self._s_cell, self._g_cell]
            centres = [np.array([self.x0 + (j + 0.5) * self.cell, self.y0 + (i + 0.5) * self.cell]) for i, j in ends]
            self._shortest = (d * self.cell + float(np.hypot(*(centres[0] - self.start_xy)))
                              + float(np.hypot(*(centres[1] - self.goal_xy))))
        return self._shortest

    # ---- along the path --------------------------------------------------------------------------------
    def point_at(self, s) -> np.ndarray:
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.length_m)
        return np.stack([np.interp(s, self.arc, self.points[:, 0]), np.interp(s, self.arc, self.points[:, 1])], axis=-1)

    def heading_at(self, s: float, window: float) -> float:
        """The guide's direction at arc length s, smoothed over +-window m (a grid path zigzags)."""
        a, b = self.point_at(max(0.0, s - window)), self.point_at(min(self.length_m, s + window))
        d = b - a
        if math.hypot(*d) < 1e-9:
            d = self.point_at(self.length_m) - self.point_at(0.0)
        return math.atan2(d[1], d[0])

    def project(self, xy, s_from: float = 0.0, s_to: float | None = None) -> float:
        """The arc length of the guide point nearest to xy, among the vertices in [s_from, s_to]."""
        s_to = self.length_m if s_to is None else s_to
        sel = np.flatnonzero((self.arc >= s_from - 1e-9) & (self.arc <= s_to + 1e-9))
        if not len(sel):
            return float(s_from)
        d = np.hypot(self.points[sel, 0] - xy[0], self.points[sel, 1] - xy[1])
        return float(self.arc[sel[int(np.argmin(d))]])


def passage(world, fp: Footprint, start, goal, samples: int = 9) -> dict | None:
    """The widest way from start to goal for the footprint's inscribed disc: the largest margin m such
    that the disc (centred where the robot's is at each pose), kept m from the known obstacles, can go
    from the start's disc centre to the goal's (a max-min clearance path on the world's distance
    field), and where that way is narrowest. None when the world has no field (unbounded).

    The field's central estimate (the distance between cell centres; pooled to at most ``MAX_CELLS``
    cells, the smallest per block) sets the threshold by bisection
    (start and goal connected in ``{clearance >= c}``, :func:`scipy.ndimage.label`); the cells at the
    threshold along a shortest grid path through the cells above it are the narrowest places of that
    way. Up to ``samples`` of them are measured with
    FCL (the inscribed disc, best over a +-1 cell neighbourhood), and the smallest of those is
    ``margin_m``: the exact clearance of the inscribed disc where the way is narrowest, a value within
    about a cell of the true max-min (the start's and goal's own clearance bound it too: a start near a
    wall is the narrowest place). Returns {margin_m, at: [x, y], inscribed_radius_m,
    connected: False when even touching obstacles (margin 0) there is no way, roomiest_m and
    roomiest_at: the roomiest place the way can reach (the cell, among those joined to the start at that
    margin, farthest from the obstacles by the field) and its distance to them, measured with FCL}."""
    from scipy import ndimage

    field = world.clearance_field()
    if field is None:
        return None
    centre, radius = inscribed_disc(fp)
    r = field.r
    clear = field.lower_bound + math.sqrt(2.0) * r            # the central estimate (see ClearanceField)
    f = max(1, math.ceil(math.sqrt(clear.size / MAX_CELLS)))
    if f > 1:                       # a large raster: pooled to at most MAX_CELLS cells (the smallest per block)
        rows, cols = clear.shape[0] // f, clear.shape[1] // f
        clear = clear[: rows * f, : cols * f].reshape(rows, f, cols, f).min(axis=(1, 3))
        r = f * r
    rows, cols = clear.shape

    def cell_of(pose):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        x, y = pose[0] + c * centre[0] - s * centre[1], pose[1] + s * centre[0] + c * centre[1]
        return min(max(int((y - field.y0) // r), 0), rows - 1), min(max(int((x - field.x0) // r), 0), cols - 1)

    s_cell, g_cell = cell_of(start), cell_of(goal)
    eight = np.ones((3, 3), dtype=bool)

    def joined(c):
        lab, _ = ndimage.label(clear >= c, structure=eight)
        return lab if lab[s_cell] and lab[s_cell] == lab[g_cell] else None

    finite = clear[np.isfinite(clear)]
    if not len(finite):
        return None
    lo, hi = 0.0, float(finite.max()) + r
    if joined(0.0) is None:
        return {"connected": False, "inscribed_radius_m": radius}
    for _ in range(40):
        if hi - lo < 0.05 * r:
            break
        mid = 0.5 * (lo + hi)
        if joined(mid) is not None:
            lo = mid
        else:
            hi = mid
    # the narrowest places: the cells below hi on a shortest way through the cells at least lo
    ok = joined(lo) == joined(lo)[s_cell]
    # the roomiest place the way can reach: the cell of the way's region farthest from the obstacles
    k_room = np.unravel_index(int(np.argmax(np.where(ok, clear, -np.inf))), clear.shape)
    room_at = np.array([field.x0 + (k_room[1] + 0.5) * r, field.y0 + (k_room[0] + 0.5) * r, 0.0])
    roomiest = {"roomiest_m": float(world.clearance(room_at, Footprint.disc(1e-6))) + 1e-6,
                "roomiest_at": [float(room_at[0]), float(room_at[1])]}
    on_way = _grid_path(ok, s_cell, g_cell)
    ci, cj = on_way[:, 0], on_way[:, 1]
    narrow = clear[ci, cj] < hi
    ci, cj = ci[narrow], cj[narrow]
    if not len(ci):
        return {"connected": True, "margin_m": math.inf, "inscribed_radius_m": radius, **roomiest}
    order = np.argsort(np.hypot(ci - s_cell[0], cj - s_cell[1]))
    pick = order[np.linspace(0, len(order) - 1, min(samples, len(order))).round().astype(int)]
    disc = Footprint.disc(radius) if radius > 0 else Footprint.disc(1e-6)
    best = []
    for k in pick:
        x, y = field.x0 + (cj[k] + 0.5) * r, field.y0 + (ci[k] + 0.5) * r
        around = [(x + a * r, y + b * r) for a in (-1, -0.5, 0, 0.5, 1) for b in (-1, -0.5, 0, 0.5, 1)]
        vals = [world.clearance(np.array([px, py, 0.0]), disc) for px, py in around]
        j = int(np.argmax(vals))
        best.append((vals[j], around[j]))
    value, at = min(best)
    return {"connected": True, "margin_m": float(value), "at": [float(at[0]), float(at[1])],
            "inscribed_radius_m": float(radius), **roomiest}


def _grid_path(ok: np.ndarray, a, b) -> np.ndarray:
    """A shortest 8-connected path of cells (P, 2) from cell a to cell b through the cells where ``ok``
    (both in it and joined)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    rows, cols = ok.shape
    idx = np.arange(rows * cols).reshape(rows, cols)
    src, dst, w = [], [], []
    for di, dj, length in _STEPS:
        p = (slice(0, rows - di), slice(max(0, -dj), cols - max(0, dj)))
        q = (slice(di, rows), slice(max(0, dj), cols - max(0, -dj)))
        m = ok[p] & ok[q]
        src.append(idx[p][m])
        dst.append(idx[q][m])
        w.append(np.full(int(m.sum()), length))
    src, dst, w = np.concatenate(src), np.concatenate(dst), np.concatenate(w)
    n = rows * cols
    graph = sp.csr_matrix((np.concatenate([w, w]), (np.concatenate([src, dst]), np.concatenate([dst, src]))),
                          shape=(n, n))
    s, g = a[0] * cols + a[1], b[0] * cols + b[1]
    _, pred = dijkstra(graph, directed=True, indices=g, return_predecessors=True)
    path = [s]
    while path[-1] != g and pred[path[-1]] >= 0:
        path.append(int(pred[path[-1]]))
    path = np.asarray(path)
    return np.column_stack([path // cols, path % cols])


def likely_cause(world, fp: Footprint, start, goal, margin: float, turning_radius: float, budget_s: float,
                 model_name: str, pad: float = 0.0) -> dict:
    """Why a search found no path, most likely, in one line with its numbers (``text``), from
    :func:`passage`: the margin (the widest way fits the footprint's inscribed disc only with a
    smaller one: ``fits_margin_m``; the search keeps ``pad`` more than the margin, so the margin that
    fits is below ``fits_margin_m - pad``), the footprint (it does not fit even touching), no way at
    all, else the turning radius and the budget (the way is wide enough for the footprint's width)."""
    info = passage(world, fp, start, goal)
    out = {"margin_m": float(margin), "search_pad_m": float(pad), "turning_radius_m": float(turning_radius),
           "budget_s": float(budget_s)}
    if info is None:
        out.update(cause="budget", text=f"likely cause: the budget ({budget_s:g} s, --time-limit) or the turning "
                                        f"radius ({turning_radius:g} m)")
        return out
    r = info["inscribed_radius_m"]
    out["inscribed_radius_m"] = r
    width = "radius" if fp.radius is not None else "half-width"
    if not info["connected"]:
        out.update(cause="blocked", text=f"likely cause: the known obstacles: no way from start to goal is wide "
                                         f"enough for the footprint's {width} {r:.3g} m even touching them")
        return out
    fit, (x, y) = info["margin_m"], info.get("at", (math.nan, math.nan))
    out.update(fits_margin_m=fit, narrowest_at=[x, y])
    if r + fit <= 0:
        out.update(cause="blocked", text=f"likely cause: the known obstacles: no way from start to goal is wide "
                                         f"enough for the footprint's {width} {r:.3g} m even touching them")
    elif fit < 0:
        out.update(cause="footprint", text=f"likely cause: the footprint: the widest way from start to goal, "
                                           f"narrowest near ({x:.2f}, {y:.2f}), is {2 * (r + fit):.3g} m wide, less "
                                           f"than the footprint's {2 * r:.3g} m ({width} {r:.3g} m)")
    elif fit < margin + pad:
        searched = f" (the search keeps {margin + pad:.3g} m)" if pad > 0 else ""
        below = max(0.0, _floor_mm(fit - pad))
        out.update(cause="margin", fits_below_m=below,
                   text=f"likely cause: the margin: the widest way from start to goal, narrowest near ({x:.2f}, "
                        f"{y:.2f}), keeps the footprint ({width} {r:.3g} m) {fit:.3f} m from the obstacles, less "
                        f"than the margin {margin:.3g} m{searched}; it can fit only with --margin below {below:.3f} m")
    else:
        turn = (f"the turning radius {turning_radius:.3g} m (--turning-radius)" if model_name != "unicycle" else
                f"the turning radius {turning_radius:.3g} m of the path's arcs (--turning-radius)")
        out.update(cause="turning_radius_or_budget",
                   text=f"likely cause: {turn} or the budget {budget_s:g} s (--time-limit): the widest way keeps "
                        f"the footprint ({width} {r:.3g} m) {fit:.3f} m from the obstacles near ({x:.2f}, {y:.2f}), "
                        f"more than the {margin + pad:.3g} m the search keeps")
    return out


def _floor_mm(value: float) -> float:
    """``value`` rounded down to the millimetre."""
    return math.floor(value * 1000.0 + 1e-9) / 1000.0
