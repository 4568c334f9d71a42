"""Drawing a plan: the map, the nominal path (forward and reverse), the footprint at intervals."""

from __future__ import annotations

import numpy as np
from matplotlib import patches

from .maps import map_figure


def plan_figure(m, poses, direction, fp, start, goal, title=None, footprints: int = 14):
    """``poses`` (N, 3) along the nominal; ``direction`` (N,) sign of the speed (+1 / -1 / 0)."""
    fig = map_figure(m, start=start, goal=goal, footprint=fp, title=title)
    ax = fig.axes[0]
    fwd = np.where(direction >= 0, poses[:, 1], np.nan)
    rev = np.where(direction < 0, poses[:, 1], np.nan)
    ax.plot(poses[:, 0], fwd, color="tab:orange", lw=1.6, label="nominal, forward")
    ax.plot(poses[:, 0], rev, color="tab:purple", lw=1.6, ls="--", label="nominal, reverse")
    for k in np.linspace(0, len(poses) - 1, footprints).astype(int)[1:-1]:
        ax.add_patch(patches.Polygon(fp.outline_at(poses[k]), closed=True, fill=False, edgecolor="tab:orange",
                                     lw=0.7, alpha=0.7))
    ax.legend(fontsize=7, loc="upper right", framealpha=0.85)
    return fig
