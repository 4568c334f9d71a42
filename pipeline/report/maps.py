"""Drawing maps: known obstacles solid, unknown dashed, bounds, poses with the robot footprint."""

from __future__ import annotations

import math

import numpy as np
from matplotlib import patches
from matplotlib.artist import Artist
from matplotlib.transforms import Affine2D

from ..collision import check_poses, grid_rectangles
from ..maps.base import Circle, Map, Polygon
from ..maps.raster import free_fraction
from . import subplots

KNOWN = "#4a4a4a"
UNKNOWN = "#c0392b"


def add_shape(ax, patch):
    """Add a patch to a map axes without matplotlib's data-limit update: the map figure fixes the view
    to the map's bounds, and that update walks every vertex in Python (a 9,000-sample tube band took
    about a second)."""
    ax.add_artist(patch)
    return patch


def _draw_shape(ax, s, known: bool):
    style = dict(facecolor=KNOWN, edgecolor=KNOWN, lw=0.8) if known else \
        dict(facecolor="none", edgecolor=UNKNOWN, lw=1.3, ls="--")
    if isinstance(s, Polygon):
        add_shape(ax, patches.Polygon(s.vertices, closed=True, **style))
    elif isinstance(s, Circle):
        add_shape(ax, patches.Circle(s.center, s.radius, **style))


def draw_pose(ax, pose, footprint=None, color="tab:blue", label=None):
    x, y, th = pose
    if footprint is not None:
        ax.add_patch(patches.Polygon(footprint.outline_at(pose), closed=True, facecolor=color, alpha=0.25,
                                     edgecolor=color, lw=1.2))
    size = 0.6 * (footprint.bounding_radius if footprint is not None else 0.05 * max(ax.get_xlim()[1] - ax.get_xlim()[0], 1))
    ax.annotate("", xy=(x + size * np.cos(th), y + size * np.sin(th)), xytext=(x, y),
                arrowprops=dict(arrowstyle="-|>", color=color, lw=1.5))
    ax.plot([x], [y], "o", color=color, ms=4, label=label)


def rig_state(robot, value) -> np.ndarray:
    """A full state of ``robot`` for drawing from a pose, a configuration or a state (steering 0)."""
    x = np.zeros(robot.model.n)
    x[robot.configuration_columns] = robot.configuration(value)
    return x


def draw_rig(ax, robot, value, color="tab:blue", label=None, fill: bool = True, lw: float = 1.2):
    """Every body of a robot (a car and its trailers) at a pose, configuration or state ``value``, the
    hitches as lines from each trailer's axle to the body ahead."""
    x = rig_state(robot, value) if np.size(value) != robot.model.n else np.asarray(value, dtype=float)
    poses = robot.body_poses(x)
    for pose, fp in zip(poses, robot.footprints):
        ax.add_patch(patches.Polygon(fp.outline_at(pose), closed=True, facecolor=color if fill else "none",
                                     alpha=0.25 if fill else 1.0, edgecolor=color, lw=lw))
    ax.plot(poses[:, 0], poses[:, 1], color=color, lw=0.8 * lw)
    if label is not None or fill:
        draw_pose(ax, poses[0], None, color, label)


#: grey levels of a grid's cells: free, occupied, unknown, unknown and occupied (KNOWN is 0x4a = 74)
_GREY = {"free": 255, "occupied": 74, "unknown": 217, "unknown_occupied": 140}
#: the map figure's margins [inches]: left (y tick labels and label), right, bottom (x tick labels and
#: label), top without the title, and per title line (fontsize 9)
_MARGINS_IN = (0.72, 0.12, 0.52, 0.12, 0.17)


def grid_image(g) -> np.ndarray:
    """The grid's cells as an (H, W, 4) uint8 RGBA image (origin at the first row): occupied cells in
    the known-obstacle grey, unknown ones lighter. RGBA bytes go to the axes as they are, with no
    colour mapping or alpha channel added at each draw."""
    level = np.full(g.shape, _GREY["free"], dtype=np.uint8)
    level[g.occupied] = _GREY["occupied"]
    if g.unknown is not None:
        level[g.unknown & ~g.occupied] = _GREY["unknown"]
        level[g.unknown & g.occupied] = _GREY["unknown_occupied"]
    rgba = np.empty(g.shape + (4,), dtype=np.uint8)
    rgba[..., :3] = level[:, :, None]
    rgba[..., 3] = 255
    return rgba


class GridRaster(Artist):
    """An axis-aligned grid drawn as an image by nearest-cell sampling at every output pixel's centre,
    in numpy (uint8 index lookups), and handed to the renderer as it is. The result is imshow's with
    ``interpolation="nearest"`` (the same cell at each pixel up to pixel-centre rounding), without
    its float RGBA resampling pass, a large part of a plan figure's drawing time."""

    zorder = 0

    def __init__(self, rgba: np.ndarray, extent):
        super().__init__()
        self.rgba = np.ascontiguousarray(rgba, dtype=np.uint8)      # (H, W, 4), row 0 the lowest
        self.extent = tuple(float(v) for v in extent)                # x0, x1, y0, y1 [m]

    def draw(self, renderer):
        if not self.get_visible():
            return
        ax = self.axes
        x0, x1, y0, y1 = self.extent
        H, W = self.rgba.shape[:2]
        to_px = ax.transData
        (px0, py0), (px1, py1) = to_px.transform([(x0, y0), (x1, y1)])
        box = ax.bbox                                   # the axes' pixel box: clip the image to it
        c0, c1 = max(math.floor(min(px0, px1)), math.floor(box.x0)), min(math.ceil(max(px0, px1)), math.ceil(box.x1))
        r0, r1 = max(math.floor(min(py0, py1)), math.floor(box.y0)), min(math.ceil(max(py0, py1)), math.ceil(box.y1))
        if c1 <= c0 or r1 <= r0:
            return
        back = to_px.inverted()
        xs = back.transform(np.column_stack([np.arange(c0, c1) + 0.5, np.full(c1 - c0, r0 + 0.5)]))[:, 0]
        ys = back.transform(np.column_stack([np.full(r1 - r0, c0 + 0.5), np.arange(r0, r1) + 0.5]))[:, 1]
        j = np.floor((xs - x0) / (x1 - x0) * W).astype(np.intp)
        i = np.floor((ys - y0) / (y1 - y0) * H).astype(np.intp)
        inside_j, inside_i = (j >= 0) & (j < W), (i >= 0) & (i < H)
        if not inside_j.any() or not inside_i.any():
            return
        cols, rows = np.flatnonzero(inside_j), np.flatnonzero(inside_i)
        # pixel row r0 + k (from the bottom, as the renderer takes an image) shows data row i[k]
        cells = self.rgba.view(np.uint32)[..., 0]                    # one 4-byte pixel per cell
        img = cells.take(i[rows], axis=0).take(j[cols], axis=1).view(np.uint8).reshape(len(rows), len(cols), 4)
        gc = renderer.new_gc()
        gc.set_clip_rectangle(box)
        renderer.draw_image(gc, c0 + cols[0], r0 + rows[0], img)
        gc.restore()
        self.stale = False


def _fixed_margins(fig, fig_w: float, fig_h: float, title_lines: int) -> None:
    """Place the map axes with fixed margins in inches instead of a layout engine: constrained layout
    measures every tick label again at each draw (a large part of a plan figure's drawing time);
    the map figure's contents (axis labels, tick labels of map coordinates, a title of a few lines)
    fit these margins."""
    left, right, bottom, top, per_line = _MARGINS_IN
    top_in = top + per_line * title_lines
    fig.subplots_adjust(left=left / fig_w, right=1 - right / fig_w, bottom=bottom / fig_h, top=1 - top_in / fig_h)


def layer_handles(m: Map) -> list:
    """Legend entries of the layers :func:`map_figure` draws for the map itself: known obstacles (shapes
    and occupied cells), unknown obstacles (dashed), a grid's unknown area (light grey; darker where it
    counts as occupied) and the map's bounds."""
    handles = []
    if m.obstacles or any(g.occupied.any() for g in m.grids):
        handles.append(patches.Patch(facecolor=KNOWN, label="known obstacle"))
    if m.unknown_obstacles:
        handles.append(patches.Patch(facecolor="none", edgecolor=UNKNOWN, ls="--", label="unknown obstacle"))
    grey = lambda key: tuple([_GREY[key] / 255] * 3)  # noqa: E731
    if any(g.unknown is not None and (g.unknown & ~g.occupied).any() for g in m.grids):
        handles.append(patches.Patch(facecolor=grey("unknown"), edgecolor="0.6", lw=0.5,
                                     label="unknown area (free for planning)"))
    if any(g.unknown is not None and (g.unknown & g.occupied).any() for g in m.grids):
        handles.append(patches.Patch(facecolor=grey("unknown_occupied"), label="unknown area (an obstacle for planning)"))
    handles.append(patches.Patch(facecolor="none", edgecolor="k", lw=1.0, label="map bounds"))
    return handles


#: the gap between the map axes and a legend beside them, and the figure's margin right of it [inches]
_LEGEND_GAP_IN = 0.12


def map_legend(ax, m: Map, fontsize: float = 7, **kw):
    """The legend of a map axes, beside it on the right (never over the map): the map's layers first
    (:func:`layer_handles`), then every labelled artist. The figure is widened by the legend's width
    and the axes keep their size in inches; a legend taller than the axes takes more columns."""
    fig = ax.figure
    handles = layer_handles(m) + ax.get_legend_handles_labels()[0]
    pos = ax.get_position()
    old_w, fig_h = fig.get_figwidth(), fig.get_figheight()
    renderer = fig.canvas.get_renderer()
    ncol, legend = 1, None
    while True:
        if legend is not None:
            legend.remove()
        legend = ax.legend(handles=handles, fontsize=fontsize, loc="upper left", bbox_to_anchor=(1.0, 1.0),
                           borderaxespad=0.0, framealpha=1.0, ncol=ncol, **kw)
        box = legend.get_window_extent(renderer)
        if box.height / fig.dpi <= pos.height * fig_h + 1e-9 or ncol >= 4:
            break
        ncol += 1
    legend.set_bbox_to_anchor((1.0 + _LEGEND_GAP_IN / (pos.width * old_w), 1.0))
    new_w = old_w + box.width / fig.dpi + 2 * _LEGEND_GAP_IN
    fig.set_figwidth(new_w)
    ax.set_anchor("W")          # an equal-aspect map narrower than its box keeps the legend next to it
    ax.set_position([pos.x0 * old_w / new_w, pos.y0, pos.width * old_w / new_w, pos.height])
    return legend


def map_figure(m: Map, start=None, goal=None, footprint=None, title: str | None = None, problems: int = 0,
               robot=None, legend: bool = True):
    """The map: grids as images, known obstacles solid, unknown dashed, bounds, start/goal with the
    footprint drawn at each (with ``robot`` of several bodies, every body). ``problems``: also mark
    that many start/goal problems of the map. ``legend=False``: no legend yet (a figure drawn over the
    map adds :func:`map_legend` once its own artists are in)."""
    xmin, ymin, xmax, ymax = m.bounds
    w, h = xmax - xmin, ymax - ymin
    scale = 7.5 / max(w, h)
    fig_w, fig_h = max(3.5, w * scale) + 0.6, max(3.0, h * scale) + 0.6
    fig, ax = subplots(figsize=(fig_w, fig_h))
    title_lines = (title or m.name).count("\n") + 1
    _fixed_margins(fig, fig_w, fig_h, title_lines)
    ax.set_xlim(xmin - 0.02 * w, xmax + 0.02 * w)
    ax.set_ylim(ymin - 0.02 * h, ymax + 0.02 * h)
    for g in m.grids:
        img = grid_image(g)
        H, W = g.shape
        ox, oy, yaw = g.origin
        if yaw == 0.0:       # axis-aligned: sampled per output pixel (a rotated grid takes imshow)
            ax.add_artist(GridRaster(img, (ox, ox + W * g.resolution, oy, oy + H * g.resolution)))
        else:
            im = ax.imshow(img, origin="lower", interpolation="nearest",
                           extent=(0, W * g.resolution, 0, H * g.resolution))
            im.set_transform(Affine2D().rotate(yaw).translate(ox, oy) + ax.transData)
    for s in m.obstacles:
        _draw_shape(ax, s, known=True)
    for s in m.unknown_obstacles:
        _draw_shape(ax, s, known=False)
    ax.add_patch(patches.Rectangle((xmin, ymin), w, h, fill=False, edgecolor="k", lw=1.0))
    for k, prob in enumerate(m.problems[:problems]):
        ax.plot([prob.start.x, prob.goal.x], [prob.start.y, prob.goal.y], color="tab:purple", lw=0.6, alpha=0.6,
                label="problems" if k == 0 else None)
    rig = robot is not None and len(robot.footprints) > 1
    for pose, color, label in ((start, "tab:green", "start"), (goal, "tab:blue", "goal")):
        if pose is None:
            continue
        if rig:
            draw_rig(ax, robot, pose, color, label)
        else:
            draw_pose(ax, pose, footprint, color, label)
    if legend:
        map_legend(ax, m)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or m.name, fontsize=9)
    return fig


def map_summary(m: Map, footprint=None) -> dict:
    """The facts ``nhstab map info`` prints: bounds, size, grids (cells, resolution, occupied, unknown,
    merged boxes), obstacle counts, free fraction, problems, start, goal, robot, and, with a
    footprint, the start's and goal's clearance (FCL)."""
    frac, cell = free_fraction(m)
    grids = []
    for g in m.grids:
        unknown = int(g.unknown.sum()) if g.unknown is not None else 0
        grids.append({"cells": list(g.shape), "resolution_m": g.resolution, "origin": list(g.origin),
                      "occupied_cells": int(g.occupied.sum()), "unknown_cells": unknown,
                      "merged_boxes": len(grid_rectangles(g.occupied))})
    info = {
        "name": m.name, "source": m.source, "bounds": list(m.bounds), "size_m": list(m.size),
        "known_obstacles": len(m.obstacles), "unknown_obstacles": len(m.unknown_obstacles),
        "grids": grids, "free_fraction": frac, "free_fraction_cell_m": cell,
        "problems": len(m.problems),
        "start": None if m.start is None else list(m.start.as_array()),
        "goal": None if m.goal is None else list(m.goal.as_array()),
        "robot": m.robot,
        "notes": list(m.meta.get("notes") or []),
    }
    if footprint is not None and (m.start is not None or m.goal is not None):
        clear = check_poses(m, footprint, {"start": None if m.start is None else m.start.as_array(),
                                           "goal": None if m.goal is None else m.goal.as_array()})
        info.update({f"{k}_clearance_m": v for k, v in clear.items()})
    return info
