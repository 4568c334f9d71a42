"""Drawing a plan: the map, the nominal path (forward and reverse), the footprint at intervals, and the
predicted error tube when there is one."""

from __future__ import annotations

import numpy as np
from matplotlib import patches

from .maps import add_shape, draw_rig, map_figure, map_legend


def grown_outline(fp, pose, radius: float, arc_points: int = 8) -> np.ndarray:
    """The outline of the footprint at ``pose`` grown by a disc of ``radius`` (a polygon footprint by
    its convex hull: a superset), as (k, 2) world points."""
    if fp.radius is not None:
        a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
        return np.column_stack([pose[0] + (fp.radius + radius) * np.cos(a),
                                pose[1] + (fp.radius + radius) * np.sin(a)])
    from scipy.spatial import ConvexHull

    v = fp.outline_at(pose)
    v = v[ConvexHull(v).vertices]                               # counter-clockwise
    e = np.roll(v, -1, axis=0) - v
    ang = np.arctan2(-e[:, 0], e[:, 1])                         # outward normal of edge i (v_i -> v_i+1)
    pts = []
    for i in range(len(v)):
        a0, a1 = ang[i - 1], ang[i]
        a1 = a0 + (a1 - a0) % (2 * np.pi)
        phi = np.linspace(a0, a1, arc_points)
        pts.append(v[i] + radius * np.column_stack([np.cos(phi), np.sin(phi)]))
    return np.vstack(pts)


def draw_tube(ax, tube, fp, color="tab:blue", footprints: int = 14, label: str | None = None,
              grown_label: bool = True):
    """The tube on a map axes: the band of the reference point's position radius r_k about the nominal
    (shaded) and the footprint grown by reach_k at intervals (dotted): the region the footprint may
    occupy at the tube's probability."""
    p, r = tube.poses, tube.position_radius
    nrm = np.column_stack([-np.sin(p[:, 2]), np.cos(p[:, 2])])
    left, right = p[:, :2] + r[:, None] * nrm, p[:, :2] - r[:, None] * nrm
    add_shape(ax, patches.Polygon(np.vstack([left, right[::-1]]), closed=True, facecolor=color, alpha=0.18, lw=0,
                                 label=label or f"{tube.probability:g}-tube: position radius"))
    for j, k in enumerate(np.linspace(0, len(p) - 1, footprints).astype(int)):
        add_shape(ax, patches.Polygon(grown_outline(fp, p[k], tube.reach[k]), closed=True, fill=False, edgecolor=color,
                                     lw=0.6, ls=":", label="footprint grown by the tube's reach" if j == 0 and grown_label else None))
    if tube.certified_index is not None:
        k = tube.certified_index
        ax.plot(*p[k, :2], marker="o", mfc="none", mec="tab:red" if tube.certified_clearance < 0 else color, ms=9,
                ls="none", label=f"certified clearance {tube.certified_clearance:+.3f} m")


def plan_figure(m, poses, direction, fp, start, goal, title=None, footprints: int = 14, tube=None, robot=None,
                states=None):
    """``poses`` (N, 3) along the nominal; ``direction`` (N,) sign of the speed (+1 / -1 / 0); the
    footprint is drawn at ``footprints`` evenly spaced samples, the ends excluded; ``tube``
    (optional): the plan's :class:`nhstab.tubes.Tube`. A robot of several bodies (``robot`` with the
    nominal's ``states``) is drawn with every body."""
    rig = robot if robot is not None and len(robot.footprints) > 1 and states is not None else None
    fig = map_figure(m, start=start, goal=goal, footprint=fp, title=title, robot=rig, legend=False)
    ax = fig.axes[0]
    if tube is not None:
        draw_tube(ax, tube, fp, footprints=footprints)
    fwd = np.where(direction >= 0, poses[:, 1], np.nan)
    rev = np.where(direction < 0, poses[:, 1], np.nan)
    ax.plot(poses[:, 0], fwd, color="tab:orange", lw=1.6, label="nominal, forward")
    if np.any(direction < 0):                  # a reverse entry only where the nominal reverses
        ax.plot(poses[:, 0], rev, color="tab:purple", lw=1.6, ls="--", label="nominal, reverse")
    for k in np.linspace(0, len(poses) - 1, footprints).astype(int)[1:-1]:
        if rig is not None:
            draw_rig(ax, rig, states[k], color="tab:orange", fill=False, lw=0.7)
            continue
        add_shape(ax, patches.Polygon(fp.outline_at(poses[k]), closed=True, fill=False, edgecolor="tab:orange",
                                     lw=0.7, alpha=0.7))
    map_legend(ax, m)
    return fig
