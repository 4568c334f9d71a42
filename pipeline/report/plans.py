"""Drawing a plan: the map, the nominal path (forward and reverse), the footprint at intervals."""

from __future__ import annotations

import numpy as np
from matplotlib import patches

from .maps import map_figure


def plan_figure(m, poses, direction, fp, start, goal, title=None, footprints: int = 14, robot=None, states=None):
    """``poses`` (N, 3) along the nominal; ``direction`` (N,) sign of the speed (+1 / -1 / 0). A robot
    of several bodies (``robot`` with the nominal's ``states``) is drawn with every body."""
    rig = robot if robot is not None and len(robot.footprints) > 1 and states is not None else None
    fig = map_figure(m, start=start, goal=goal, footprint=fp, title=title, robot=rig)
    ax = fig.axes[0]
    fwd = np.where(direction >= 0, poses[:, 1], np.nan)
    rev = np.where(direction < 0, poses[:, 1], np.nan)
    ax.plot(poses[:, 0], fwd, color="tab:orange", lw=1.6, label="nominal, forward")
    ax.plot(poses[:, 0], rev, color="tab:purple", lw=1.6, ls="--", label="nominal, reverse")
    for k in np.linspace(0, len(poses) - 1, footprints).astype(int)[1:-1]:
        if rig is not None:
            from .maps import draw_rig

            draw_rig(ax, rig, states[k], color="tab:orange", fill=False, lw=0.7)
            continue
        ax.add_patch(patches.Polygon(fp.outline_at(poses[k]), closed=True, fill=False, edgecolor="tab:orange",
                                     lw=0.7, alpha=0.7))
    ax.legend(fontsize=7, loc="upper right", framealpha=0.85)
    return fig
