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
from .tracking import error_axis_label, unit_groups, with_unit

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
    for k, d in enumerate(result.discovered):
        shape = result.map.unknown_obstacles[d["index"]]
        patch = _draw_discovered(ax, shape)
        if k == 0:
            patch.set_label("unknown obstacle, seen at t")
        _seen_label(ax, shape, d["time_s"])

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
            ax.add_artist(patches.Rectangle((np.nan, np.nan), 0.0, 0.0, fill=False, edgecolor="0.35", lw=0.5,
                                            label="footprint, executed"))     # the legend's entry only
        else:
            for j, k in enumerate(np.linspace(0, len(p) - 1, footprints).astype(int)):
                ax.add_patch(patches.Polygon(result.footprint.outline_at(p[k]), closed=True, fill=False,
                                             edgecolor="0.35", lw=0.5, label="footprint, executed" if j == 0 else None))
    for rec in result.plans[1:]:
        ax.plot(*rec.start[:2], marker="X", color="tab:red", ms=8, ls="none",
                label="replan" if rec.id == 1 else None)
    _zoom(ax, result)
    if result.collision:
        _draw_collision(ax, result)
    map_legend(ax, result.map, fontsize=6)
    return fig


def _seen_label(ax, shape, time_s: float) -> None:
    """'seen at t' beside a discovered obstacle: dark text on a white box just above its outline."""
    xmin, ymin, xmax, ymax = shape.bounds()
    ax.annotate(f"seen at {time_s:.1f} s", ((xmin + xmax) / 2, ymax), xytext=(0, 3), textcoords="offset points",
                fontsize=7, color="darkred", ha="center", va="bottom", zorder=6,
                bbox=dict(boxstyle="round,pad=0.15", facecolor="white", edgecolor="darkred", lw=0.5, alpha=0.9))


#: an obstacle hit whose outline spans less than this many points on the figure is circled too
_SMALL_HIT_PT = 12.0


def _hit_outlines(m, hit) -> list[np.ndarray]:
    """The outlines (k, 2) of one obstacle named in a collision record (:meth:`CollisionWorld.hits`)."""
    source = hit.get("source")
    if source in ("obstacles", "unknown_obstacles"):
        shape = getattr(m, source)[hit["index"]]
        if isinstance(shape, Circle):
            a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
            return [np.column_stack([shape.center[0] + shape.radius * np.cos(a),
                                     shape.center[1] + shape.radius * np.sin(a)])]
        return [shape.vertices]
    if source == "grid":
        g = m.grids[hit["grid"]]
        ox, oy, yaw = g.origin
        c, s = np.cos(yaw), np.sin(yaw)
        out = []
        for i, j in hit["cells"]:
            uv = (np.array([[0, 0], [1, 0], [1, 1], [0, 1]]) + [j, i]) * g.resolution
            out.append(np.column_stack([ox + c * uv[:, 0] - s * uv[:, 1], oy + s * uv[:, 0] + c * uv[:, 1]]))
        return out
    if source == "bounds":
        xmin, ymin, xmax, ymax = m.bounds
        return [np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]])]
    return []


def _draw_collision(ax, result) -> None:
    """Where the run collided: the footprint there (star at its reference point), the obstacle hit
    outlined, circled when it is small on the figure, and named with its signed clearance."""
    col = result.collision
    where = np.asarray(col.get("body_pose", col["pose"]), dtype=float)
    kind = "jackknife" if col.get("kind") == "jackknife" else "collision"
    ax.plot(*where[:2], marker="*", color="red", mec="k", mew=0.5, ms=12, ls="none", zorder=7,
            label=f"{kind} at t = {col['time_s']:.2f} s")
    rig = _rig(result)
    body = rig.footprints[col["body"]] if rig is not None and "body_pose" in col else result.footprint
    ax.add_patch(patches.Polygon(body.outline_at(where), closed=True, fill=False, edgecolor="red", lw=1.2, zorder=7,
                                 label="footprint at the collision"))
    hits = col.get("obstacles") or []
    labelled = False
    for hit in hits:
        for outline in _hit_outlines(result.map, hit):
            ax.add_patch(patches.Polygon(outline, closed=True, fill=False, edgecolor="magenta", lw=2.0, zorder=7,
                                         label=None if labelled else "obstacle hit"))
            labelled = True
    if not hits:
        return
    pts = np.vstack([o for hit in hits for o in _hit_outlines(result.map, hit)])
    px = ax.transData.transform(pts)
    span_pt = float(np.max(px.max(axis=0) - px.min(axis=0))) * 72.0 / ax.figure.dpi
    centre = pts.mean(axis=0)
    if span_pt < _SMALL_HIT_PT:                  # a speck: a ring around it that the eye finds
        ax.plot(*centre, marker="o", mfc="none", mec="magenta", mew=1.5, ms=_SMALL_HIT_PT + 6, ls="none", zorder=7)
    text = "; ".join(f"hit {h['id']} ({h['clearance_m']:+.3f} m)" for h in hits[:2])
    ax.annotate(text, centre, xytext=(14, -18), textcoords="offset points", fontsize=7, color="k", zorder=8,
                arrowprops=dict(arrowstyle="->", color="magenta", lw=1.0),
                bbox=dict(boxstyle="round,pad=0.2", facecolor="white", edgecolor="magenta", lw=0.6, alpha=0.9))


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
    """The tracking error and the inputs against time, one panel per unit: the position error's size on
    a log scale, the state errors by unit (position in m, heading and other angles in rad) and the
    inputs by unit (applied solid, nominal dashed on top); replans marked on every panel."""
    lg, model = result.log, result.model
    t = lg["t"]
    e = model.state_error(lg["x"], lg["x0"])
    state_groups = unit_groups(model.state_names, model.state_units)
    input_groups = unit_groups(model.input_names, model.input_units)
    n_panels = 1 + len(state_groups) + len(input_groups)
    fig, axes = subplots(n_panels, 1, figsize=(8.5, 1.75 * n_panels + 0.8), sharex=True, layout="constrained")
    pos = [i for i, (s, u) in enumerate(zip(model.state_names, model.state_units)) if u == "m" and s in ("x", "y")]
    if len(pos) == 2:
        norm, top = np.hypot(e[:, pos[0]], e[:, pos[1]]), ("|(e_x, e_y)|", "position error size [m]")
    else:
        norm, top = np.linalg.norm(e, axis=1), ("||x - x0||", "error norm [-]")
    axes[0].semilogy(t, np.where(norm > 0, norm, np.nan), color="k", lw=1.0, label=top[0])
    axes[0].set_ylabel(top[1])
    k = 1
    for unit, idx in state_groups:
        for i in idx:
            axes[k].plot(t, e[:, i], lw=0.9, label=f"e_{model.state_names[i]}")
        axes[k].axhline(0.0, color="0.6", lw=0.6)
        axes[k].set_ylabel(error_axis_label([model.state_names[i] for i in idx], unit))
        k += 1
    for unit, idx in input_groups:
        for i in idx:
            s = model.input_names[i]
            line, = axes[k].plot(t, lg["u"][:, i], lw=0.9, label=f"{s} applied")
            axes[k].plot(t, lg["u0"][:, i], lw=0.9, ls="--", color="k" if len(idx) == 1 else line.get_color(),
                         zorder=3, label=f"{s} nominal")
        axes[k].set_ylabel(with_unit("input " + ", ".join(model.input_names[i] for i in idx), unit))
        k += 1
    axes[-1].set_xlabel("t [s]")
    for ax in axes:
        for rec in result.plans[1:]:
            ax.axvline(rec.t_detect, color="tab:red", lw=0.8, ls="--")
            if np.isfinite(rec.t_start):
                ax.axvspan(rec.t_detect, rec.t_start, color="tab:red", alpha=0.08)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
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
