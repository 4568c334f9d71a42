"""The run figures: the legend never covers the path, start or goal; every axis has units; a
collision names and shows what was hit, a speck of two cells included."""

from __future__ import annotations

import numpy as np
import pytest
from nhstab.execution import RunOptions, execute
from nhstab.execution.config import NoiseOptions, TubeOptions
from nhstab.maps import load_map
from nhstab.maps.base import Map, OccupancyGrid, Pose
from nhstab.report.runs import run_map_figure, run_tracking_figure
from nhstab.robot import default_robot
from shapely.geometry import Point, box


def _legend_clear_of_the_drawing(fig) -> int:
    """Draw the figure and check, in display coordinates, that the legend's box meets none of the
    plotted path points, start and goal markers visible in the axes (marker extents included);
    returns the number of points checked."""
    fig.canvas.draw()
    ax = fig.axes[0]
    legend = ax.get_legend()
    lb = legend.get_window_extent()
    axes_box = ax.get_window_extent()
    fb = fig.bbox                                        # and the legend is wholly on the figure
    assert fb.x0 - 1 <= lb.x0 and lb.x1 <= fb.x1 + 1 and fb.y0 - 1 <= lb.y0 and lb.y1 <= fb.y1 + 1, (lb, fb)
    checked = 0
    for line in ax.get_lines():
        label = line.get_label()
        if label.startswith("_") and line.get_marker() in (None, "None", "") or not line.get_visible():
            continue
        xy = ax.transData.transform(np.column_stack(line.get_data()).astype(float))
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        inside = (xy[:, 0] >= axes_box.x0) & (xy[:, 0] <= axes_box.x1) & (xy[:, 1] >= axes_box.y0) & \
            (xy[:, 1] <= axes_box.y1)
        xy = xy[inside]
        r = 0.5 * line.get_markersize() * fig.dpi / 72.0 if line.get_marker() not in (None, "None", "") else 0.0
        hit = (xy[:, 0] + r >= lb.x0) & (xy[:, 0] - r <= lb.x1) & (xy[:, 1] + r >= lb.y0) & (xy[:, 1] - r <= lb.y1)
        assert not hit.any(), f"the legend covers {label} at {xy[hit][:3]}"
        checked += len(xy)
    return checked


@pytest.mark.parametrize("name", ["cluttered_room", "depot_blocked_aisle",
                                  pytest.param("warehouse_aisle_a2", marks=pytest.mark.slow)])
def test_the_run_map_legend_covers_no_path_start_or_goal(name):
    """Three bundled scenarios run (for time: the linear tube for the plans, and no discarded rollouts,
    N = 998 instead of 2,097, in the sampled tubes of the rest of the maneuver at the car's cusps: the
    tubes only decide the cusp replans; this test is about the drawing): the run map's legend lies clear
    of every nominal, the executed path, the replan points and the start and goal markers, in display
    coordinates after drawing, and it lists the map bounds and the footprints drawn along the path."""
    m = load_map(f"example:{name}")
    result = execute(m, opts=RunOptions(seed=0, tube=TubeOptions(kind="linear", discards=0)))
    fig = run_map_figure(result)
    assert _legend_clear_of_the_drawing(fig) > 1000
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    for needed in ("start", "goal", "executed", "footprint, executed", "map bounds", "nominal 0 (initial, from 0.0 s)"):
        assert needed in labels, (needed, labels)
    if result.discovered:
        assert "unknown obstacle, seen at t" in labels
        seen = [t for t in fig.axes[0].texts if t.get_text().startswith("seen at ")]
        assert len(seen) == len(result.discovered) and all(t.get_fontsize() >= 7 for t in seen)
        assert all(t.get_color() != "tab:red" for t in seen)
    fig = run_tracking_figure(result)
    for ax in fig.axes:
        assert ax.get_ylabel().endswith("]"), ax.get_ylabel()
    ylabels = [ax.get_ylabel() for ax in fig.axes]
    assert "position error [m]" in ylabels and any(y.startswith("heading") and y.endswith("[rad]") for y in ylabels)
    assert fig.axes[-1].get_xlabel() == "t [s]"


@pytest.mark.parametrize("unknown, label", [("occupied", "unknown area (an obstacle for planning)"),
                                            ("free", "unknown area (free for planning)")])
def test_a_grid_map_legend_lists_the_unknown_area(unknown, label):
    """The tb3 sandbox's Nav2 grid has unknown cells, drawn grey: the map figure's legend lists them as
    the loader counted them, and lies clear of the start and goal."""
    from nhstab.report.maps import map_figure

    m = load_map("example:tb3_sandbox", unknown=unknown)
    assert any(g.unknown is not None and g.unknown.any() for g in m.grids)
    fig = map_figure(m, start=m.start.as_array() if m.start else (0.0, 0.0, 0.0),
                     goal=m.goal.as_array() if m.goal else (1.0, 0.0, 0.0))
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert label in labels and "map bounds" in labels, labels
    assert _legend_clear_of_the_drawing(fig) >= 2


def test_a_collision_with_a_two_cell_speck_is_named_and_circled():
    """An impulse of 0.45 m at t = 0.1 s pushes the unicycle (a disc of 0.3 m) into a speck of two
    0.05 m cells 0.4 m beside its start: the run ends in a collision, run's record names the speck's
    two cells (they and only they meet the disc, checked with shapely), with a negative clearance, and
    the figure outlines the cells and circles them with a marker of at least 12 points, named in a
    label."""
    occ = np.zeros((80, 200), bool)
    occ[56, 20:22] = True                                  # cells (56, 20), (56, 21): x 1.00-1.10, y 2.80-2.85
    grid = OccupancyGrid(occ, 0.05)
    m = Map("speck", (0, 0, 10, 4), grids=(grid,), start=Pose(1.05, 2.0, 0.0), goal=Pose(8.0, 2.0, 0.0))
    opts = RunOptions(seed=1, tube=TubeOptions(kind="linear"),
                      noise=NoiseOptions(impulses=((0.1, {"y": 0.45}),)))
    r = execute(m, default_robot("unicycle"), opts=opts)
    assert r.status == "collision", r.message
    hits = r.collision["obstacles"]
    assert len(hits) == 1 and hits[0]["source"] == "grid", hits
    x, y = r.collision["pose"][:2]
    disc = Point(x, y).buffer(0.3, 512)
    expected = sorted([int(i), int(j)] for i, j in zip(*np.nonzero(occ))
                      if disc.intersection(box(j * 0.05, i * 0.05, (j + 1) * 0.05, (i + 1) * 0.05)).area > 0)
    assert hits[0]["cells"] == expected and len(expected) >= 1
    assert hits[0]["clearance_m"] < 0.0
    fig = run_map_figure(r)
    fig.canvas.draw()
    ax = fig.axes[0]
    rings = [ln for ln in ax.get_lines() if ln.get_marker() == "o" and ln.get_markeredgecolor() == "magenta"]
    assert len(rings) == 1 and rings[0].get_markersize() >= 12
    cx, cy = rings[0].get_data()
    assert np.hypot(float(cx[0]) - 1.05, float(cy[0]) - 2.825) < 0.06       # about the speck's centre
    named = [t for t in ax.texts if t.get_text().startswith("hit grid[0] cell")]
    assert len(named) == 1
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "obstacle hit" in labels and any(label.startswith("collision at t = ") for label in labels)
