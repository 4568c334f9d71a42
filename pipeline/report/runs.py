"""Figures of one composite-controller run: the map with every nominal, the executed path,
discovered obstacles and replan points; errors and inputs against time; an optional animation."""

from __future__ import annotations

import numpy as np
from matplotlib import patches

from ..maps.base import Circle
from ..planning import pose_columns
from ..records import _atomic_write
from . import subplots
from .maps import draw_rig, map_figure, map_legend
from .plans import draw_tube

MODE_TEXT = ("tracking", "stopped: replanning", "done")
PLAN_COLORS = ("tab:orange", "tab:purple", "tab:cyan", "tab:olive", "tab:brown", "tab:pink")


def _draw_discovered(ax, shape):
    style = dict(facecolor="tab:red", edgecolor="darkred", alpha=0.55, lw=0.8)
    patch = patches.Circle(shape.center, shape.radius, **style) if isinstance(shape, Circle) else \
        patches.Polygon(shape.vertices, closed=True, **style)
    ax.add_patch(patch)
    return patch


def _poses(result, x):
    return x[:, pose_columns(result.model)]


def _rig(result):
    """The run's robot when it has several bodies (a car with trailers), else None."""
    robot = getattr(result, "robot", None)
    return robot if robot is not None and len(robot.footprints) > 1 else None


def run_map_figure(result, footprints: int = 12):
    lg = result.log
    title = (f"{result.map.name}: {result.model.name}, {result.options.controller.kind} -- {result.status}, "
             f"{sum(p.trigger != 'initial' for p in result.plans)} replan(s)")
    rig = _rig(result)
    fig = map_figure(result.map, start=result.start, goal=result.goal, footprint=result.footprint, title=title,
                     robot=rig, legend=False)
    ax = fig.axes[0]
    for d in result.discovered:
        shape = result.map.unknown_obstacles[d["index"]]
        _draw_discovered(ax, shape)
        c = np.asarray(shape.center if isinstance(shape, Circle) else shape.vertices.mean(axis=0))
        ax.annotate(f"seen {d['time_s']:.1f} s", c, fontsize=6, color="tab:red", ha="center")

    for rec in result.plans:
        if getattr(rec, "tube", None) is not None:
            draw_tube(ax, rec.tube, result.footprint, color=PLAN_COLORS[rec.id % len(PLAN_COLORS)], footprints=8,
                      label=f"tube of nominal {rec.id} (p = {rec.tube.probability:g})", grown_label=rec.id == 0)
    for rec in result.plans:
        if rec.law is None:
            continue
        p = _poses(result, rec.law.nominal.x)
        ax.plot(p[:, 0], p[:, 1], color=PLAN_COLORS[rec.id % len(PLAN_COLORS)], lw=1.2, ls="--",
                label=f"nominal {rec.id} ({rec.trigger}, from {rec.t_start:.1f} s)")
    if len(lg["t"]):
        p = _poses(result, lg["x"])
        ax.plot(p[:, 0], p[:, 1], color="k", lw=1.0, label="executed")
        if rig is not None:         # every body, and the trailers' axle paths

            tp = rig.body_poses(lg["x"])
            for b in range(1, tp.shape[1]):
                ax.plot(tp[:, b, 0], tp[:, b, 1], color="k", lw=0.8, ls=":",
                        label="executed (trailer axle)" if b == 1 else None)
            for k in np.linspace(0, len(p) - 1, footprints).astype(int):
                draw_rig(ax, rig, lg["x"][k], color="0.35", fill=False, lw=0.5)
        else:
            for k in np.linspace(0, len(p) - 1, footprints).astype(int):
                ax.add_patch(patches.Polygon(result.footprint.outline_at(p[k]), closed=True, fill=False,
                                             edgecolor="0.35", lw=0.5))
    for rec in result.plans[1:]:
        ax.plot(*rec.start[:2], marker="X", color="tab:red", ms=8, ls="none",
                label="replan" if rec.id == 1 else None)
    if result.collision:
        where = result.collision.get("body_pose", result.collision["pose"])
        label = "jackknife" if result.collision.get("kind") == "jackknife" else "collision"
        ax.plot(*where[:2], marker="*", color="red", ms=14, ls="none", label=label)
    _zoom(ax, result)
    map_legend(ax, result.map, fontsize=6)
    return fig


def _zoom(ax, result, pad: float = 6.0):
    """On a large map, show the part the run used (every nominal, the path, start and goal) plus a
    margin, when that is less than half of the map's extent."""
    pts = [np.asarray(result.start[:2]), np.asarray(result.goal[:2])]
    pts += [_poses(result, r.law.nominal.x)[:, :2] for r in result.plans if r.law is not None]
    if len(result.log["t"]):
        pts.append(_poses(result, result.log["x"])[:, :2])
    pts = np.vstack([np.atleast_2d(p) for p in pts])
    lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
    xmin, ymin, xmax, ymax = result.map.bounds
    if (hi[0] - lo[0]) * (hi[1] - lo[1]) < 0.5 * (xmax - xmin) * (ymax - ymin):
        ax.set_xlim(max(lo[0], xmin), min(hi[0], xmax))
        ax.set_ylim(max(lo[1], ymin), min(hi[1], ymax))


def run_tracking_figure(result):
    lg, model = result.log, result.model
    t = lg["t"]
    e = model.state_error(lg["x"], lg["x0"])
    fig, axes = subplots(3, 1, figsize=(8, 7.5), sharex=True, layout="constrained")
    norm = np.linalg.norm(e, axis=1)
    axes[0].semilogy(t, np.where(norm > 0, norm, np.nan), color="k", lw=1.0, label="||x - x0||")
    axes[0].set_ylabel("error norm")
    for i, s in enumerate(model.state_names):
        axes[1].plot(t, e[:, i], lw=0.9, label=f"e_{s}")
    axes[1].set_ylabel("error e(t)")
    for i, s in enumerate(model.input_names):
        line, = axes[2].plot(t, lg["u"][:, i], lw=0.9, label=s)
        axes[2].plot(t, lg["u0"][:, i], lw=0.8, ls=":", color=line.get_color(), label=f"{s} nominal")
    axes[2].set_ylabel("inputs")
    axes[2].set_xlabel("t [s]")
    for ax in axes:
        for rec in result.plans[1:]:
            ax.axvline(rec.t_detect, color="tab:red", lw=0.8, ls="--")
            if np.isfinite(rec.t_start):
                ax.axvspan(rec.t_detect, rec.t_start, color="tab:red", alpha=0.08)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right", ncol=2)
    axes[0].set_title(f"{result.map.name}: tracking error and inputs (red: replans, shaded: stopped while "
                      f"replanning) -- {result.status}", fontsize=9)
    return fig


def write_animation(result, path, fps: int = 8, max_frames: int = 120, dpi: int = 60):
    """A GIF of the run: the robot's footprint moving along the executed path, the nominal in use,
    obstacles appearing when discovered. The static map is drawn once; each frame restores it and
    draws only the moving artists (blitting), and Pillow (which matplotlib already needs) writes the
    GIF."""
    from PIL import Image


    lg = result.log
    p = _poses(result, lg["x"])
    frames = np.unique(np.linspace(0, len(p) - 1, min(max_frames, len(p))).astype(int))
    rig = _rig(result)
    fig = map_figure(result.map, start=result.start, goal=result.goal, footprint=result.footprint,
                     title=f"{result.map.name}: {result.model.name}, {result.options.controller.kind} control",
                     robot=rig)
    fig.set_dpi(dpi)
    ax = fig.axes[0]
    canvas = fig.canvas
    canvas.draw()
    fig.set_layout_engine("none")
    background = canvas.copy_from_bbox(fig.bbox)
    trail, = ax.plot([], [], color="k", lw=1.0, animated=True)
    nominal, = ax.plot([], [], color="tab:orange", lw=1.0, ls="--", animated=True)
    shapes = rig.footprints if rig is not None else (result.footprint,)

    def outlines(k):
        if rig is None:
            return [result.footprint.outline_at(p[k])]
        return [fp.outline_at(q) for fp, q in zip(shapes, rig.body_poses(lg["x"][k]))]

    body = [patches.Polygon(o, closed=True, color="tab:green", alpha=0.6, animated=True) for o in outlines(0)]
    for b in body:
        ax.add_patch(b)
    label = ax.text(0.02, 0.02, "", transform=ax.transAxes, fontsize=8, animated=True,
                    bbox=dict(facecolor="white", alpha=0.8, lw=0))
    seen = []
    images = []
    for k in frames:
        canvas.restore_region(background)
        for d in result.discovered:
            if d["time_s"] <= lg["t"][k] and d["index"] not in [i for i, _ in seen]:
                patch = _draw_discovered(ax, result.map.unknown_obstacles[d["index"]])
                patch.set_animated(True)
                seen.append((d["index"], patch))
        rec = result.plans[lg["plan_id"][k]]
        if rec.law is not None:
            q = _poses(result, rec.law.nominal.x)
            nominal.set_data(q[:, 0], q[:, 1])
        trail.set_data(p[:k + 1, 0], p[:k + 1, 1])
        for b, o in zip(body, outlines(k)):
            b.set_xy(o)
        label.set_text(f"t = {lg['t'][k]:.1f} s   plan {rec.id}   {MODE_TEXT[lg['mode'][k]]}")
        for artist in (*(patch for _, patch in seen), nominal, trail, *body, label):
            ax.draw_artist(artist)
        canvas.blit(fig.bbox)
        images.append(Image.frombuffer("RGBA", canvas.get_width_height(), bytes(canvas.buffer_rgba()))
                      .convert("RGB").quantize(colors=64))


    def write(fh):
        images[0].save(fh, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)

    return _atomic_write(path, write)
