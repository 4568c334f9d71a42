"""What one run leaves behind: ``run.json`` (the summary), ``trajectory.csv`` (every control sample),
the figures, optionally an animation.

Everything in ``run.json`` except its ``timing`` section is a function of the inputs and the seed
(same seed, same bytes); wall-clock figures (planning latencies, run time) live under ``timing``.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np

from .. import __version__, bodies
from ..collision import CollisionWorld
from ..errors import InputError
from ..planning import pose_columns
from ..records import OutputFolder
from ..report.plans import plan_figure
from ..report.runs import run_map_figure, run_tracking_figure, write_animation
from ..robot import make_robot
from ..trajectory_io import float_rows, write_trajectory
from ..tubes.base import certified_text
from .runner import MODES, RunResult

#: a cusp's neighbourhood for the per-cusp error statistics [s]
CUSP_WINDOW_S = 1.0
#: a reversal is a cusp when the runs on both sides each cover at least this much [m]
CUSP_MIN_RUN_M = 0.5
#: plan metrics that are wall-clock measurements: moved to run.json's ``timing``
_TIMED = ("planning_time_s", "time_to_nominal_s", "validity_us_per_state", "validity_calls")


def csv_columns(result: RunResult) -> list[str]:
    model = result.model
    su, iu = model.state_units, model.input_units
    cols = ["t [s]", "plan_id", "mode"]
    cols += [f"{s} [{u}]" for s, u in zip(model.state_names, su)]
    cols += [f"{s}_nominal [{u}]" for s, u in zip(model.state_names, su)]
    cols += [f"{s}_measured [{u}]" for s, u in zip(model.state_names, su)]
    cols += [f"{s} [{u}]" for s, u in zip(model.input_names, iu)]
    cols += [f"{s}_nominal [{u}]" for s, u in zip(model.input_names, iu)]
    return cols


def trajectory_csv(result: RunResult) -> str:
    """The run's samples as CSV text (header, then one row per control sample; every float as its
    shortest round-trip repr), formatted column-wise (:func:`nhstab.trajectory_io.float_rows`)."""
    lg = result.log
    header = ",".join(csv_columns(result)) + "\n"
    if not len(lg["t"]):
        return header
    t = float_rows(np.asarray(lg["t"], dtype=float)[:, None]).split("\n")
    nums = float_rows(np.column_stack([lg["x"], lg["x0"], lg["y"], lg["u"], lg["u0"]])).split("\n")
    ids = map(str, np.asarray(lg["plan_id"]).astype(int).tolist())
    modes = (MODES[k] for k in np.asarray(lg["mode"]).tolist())
    return header + "".join(f"{a},{b},{c},{d}\n" for a, b, c, d in zip(t, ids, modes, nums))


def read_run_csv(path) -> dict:
    """trajectory.csv back into arrays: t, plan_id, mode (strings), and one array per column name
    (without its unit), e.g. ``x``, ``x_nominal``, ``v_measured``."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    out = {}
    for i, h in enumerate(header):
        name = h.split(" [")[0]
        col = [r[i] for r in body]
        out[name] = np.array(col) if name == "mode" else (
            np.array(col, dtype=int) if name == "plan_id" else np.array(col, dtype=float))
    return out


def _errors(result: RunResult):
    lg, model = result.log, result.model
    track = lg["mode"] == 0
    e = model.state_error(lg["x"], lg["x0"])
    e[~track] = np.nan
    return e, track


def nominal_cusps(nom, min_run_m: float = CUSP_MIN_RUN_M) -> list[float]:
    """Times of the nominal's cusps: reversals of the speed's sign between runs that each cover at
    least ``min_run_m`` (the short back-and-forth motions of the cars' sinusoidal steering pieces
    are not counted as cusps)."""
    v = nom.u[:, 0]
    s = np.sign(np.round(v, 9))
    moving = np.flatnonzero(s)
    if moving.size == 0:
        return []
    # runs of constant sign among the moving samples, with their arc length
    ds = np.abs(v) * np.gradient(nom.t)
    runs, first = [], moving[0]
    for a, b in zip(moving[:-1], moving[1:]):
        if s[b] != s[a]:
            runs.append((first, a))
            first = b
    runs.append((first, moving[-1]))
    lengths = [float(ds[i:j + 1].sum()) for i, j in runs]
    out = []
    for k in range(1, len(runs)):
        if lengths[k - 1] >= min_run_m and lengths[k] >= min_run_m:
            out.append(float(0.5 * (nom.t[runs[k - 1][1]] + nom.t[runs[k][0]])))
    return out


def _cusps(result: RunResult, e: np.ndarray) -> list[dict]:
    lg, out = result.log, []
    norms = np.linalg.norm(e, axis=1)
    pos = np.linalg.norm(e[:, :2], axis=1)
    for rec in result.plans:
        if rec.law is None:
            continue
        for tau in nominal_cusps(rec.law.nominal):
            t_cusp = rec.t_start + tau
            sel = (lg["plan_id"] == rec.id) & (np.abs(lg["t"] - t_cusp) <= CUSP_WINDOW_S) & np.isfinite(norms)
            if not np.any(sel):
                continue
            out.append({"plan_id": rec.id, "time_s": float(t_cusp),
                        "max_error_norm": float(norms[sel].max()), "max_position_error_m": float(pos[sel].max())})
    return out


def _observed_in_tube(result: RunResult, rec) -> dict | None:
    """How the run's own samples sat in a plan's predicted tube: the tracking samples that followed
    it, the fraction inside the full-state p-ellipsoid and inside the pose region of the spatial tube."""
    lg, tube = result.log, rec.tube
    sel = np.flatnonzero((lg["plan_id"] == rec.id) & (lg["mode"] == 0))
    if tube is None or not len(sel):
        return None
    k = np.rint((lg["t"][sel] - rec.t_start) / result.info["period_s"]).astype(int)
    ok = (k >= 0) & (k < len(tube.t))
    sel, k = sel[ok], k[ok]
    if not len(sel):
        return None
    e = np.zeros((len(tube.t), result.model.n))
    e[k] = result.model.state_error(lg["x"][sel], lg["x0"][sel])
    state, pose = tube.inside(e)
    return {"samples": int(len(k)), "inside_state_ellipsoid": float(state[k].mean()),
            "inside_tube": float(pose[k].mean()),
            "note": "this run's tracking samples on this plan inside the predicted p-regions (full-state "
                    "chi-square ellipsoid; position ellipse and heading band the spatial tube is built from)"}


def _plan_entry(rec, result: RunResult | None = None) -> tuple[dict, dict]:
    entry = {"id": rec.id, "trigger": rec.trigger, "t_detect_s": rec.t_detect, "t_start_s": rec.t_start,
             "start_pose": rec.start, "margin_m": rec.margin, "seed": rec.seed, "conflict": rec.conflict,
             "attempts": [{k: v for k, v in a.items() if k not in ("latency_s", "tube_s")} for a in rec.attempts]}
    timing = {"id": rec.id, "attempt_latencies_s": [a["latency_s"] for a in rec.attempts],
              "attempt_tube_s": [a.get("tube_s") for a in rec.attempts]}
    if rec.result is not None:
        metrics = dict(rec.result.metrics)
        for key in _TIMED:
            if key in metrics:
                timing[key] = metrics.pop(key)
        entry["metrics"] = {**metrics, "duration_s": float(rec.law.t_end - rec.law.t0),
                            "controller_max_gain_norm": rec.law.info.get("max_gain_norm")}
    if getattr(rec, "verdict_line", None):
        entry["tube_line"] = rec.verdict_line
    if getattr(rec, "cusp_checks", None):
        entry["cusp_checks"] = [{k: v for k, v in c.items()} for c in rec.cusp_checks]
    if getattr(rec, "tube", None) is not None:
        entry["tube"] = rec.tube.summary()
        observed = _observed_in_tube(result, rec) if result is not None else None
        if observed is not None:
            entry["tube"]["observed"] = observed
    return entry, timing


def summary(result: RunResult, map_path: str | None = None) -> dict:
    """The content of run.json."""
    lg, model, T = result.log, result.model, result.info["period_s"]
    e, track = _errors(result)
    norms = np.linalg.norm(e, axis=1)
    pos = np.linalg.norm(e[:, :2], axis=1)
    names = model.state_names
    head = np.abs(e[:, names.index("theta") if "theta" in names else 2])     # the heading (else the third state)
    tracking = {"samples": int(track.sum())}
    if track.any():
        tracking.update({
            "rms_error_norm": float(np.sqrt(np.nanmean(norms ** 2))), "max_error_norm": float(np.nanmax(norms)),
            "max_error_time_s": float(lg["t"][np.nanargmax(norms)]),
            "rms_position_error_m": float(np.sqrt(np.nanmean(pos ** 2))), "max_position_error_m": float(np.nanmax(pos)),
            "rms_heading_error_rad": float(np.sqrt(np.nanmean(head ** 2))), "max_heading_error_rad": float(np.nanmax(head)),
            "rms_error_by_state": dict(zip(model.state_names, np.sqrt(np.nanmean(e[track] ** 2, axis=0)).tolist())),
            "per_cusp": _cusps(result, e), "cusp_window_s": CUSP_WINDOW_S, "cusp_min_run_m": CUSP_MIN_RUN_M,
            "error_norm_note": "||x - x0|| over all states in SI units (angles wrapped), as in the paper"})
    # executed clearance, recomputed against every real obstacle

    poses = lg["x"][:, pose_columns(model)]
    clearance = {}
    robot = result.robot if result.robot is not None else make_robot(model, footprint=result.footprint)
    if len(poses) and len(robot.footprints) > 1:
        truth = result.world if result.world is not None else CollisionWorld.from_map(result.map, "all")
        c_min, i_min, b_min = bodies.min_clearance(truth, robot, lg["x"])
        margin = result.options.planning.margin
        if margin == "auto":           # the first plan's margin, as chosen by its tube
            margin = result.plans[0].margin if result.plans else 0.0
        free = bodies.free_many(truth, robot, lg["x"], margin)
        hitch = model.hitch_angles(lg["x"])
        clearance = {"min_executed_m": c_min, "time_s": float(lg["t"][i_min]), "pose": poses[i_min],
                     "body": "car" if b_min == 0 else f"trailer {b_min}",
                     "body_pose": robot.body_poses(lg["x"][i_min])[b_min],
                     "margin_m": margin, "samples_below_margin": int((~free).sum()), "samples": len(poses),
                     "max_abs_hitch_angle_rad": np.abs(hitch).max(axis=0).tolist(),
                     "jackknife_limit_rad": float(model.jackknife_limit),
                     "note": "signed clearance of every body's footprint (the car and each trailer) at every control "
                             "sample to known and unknown obstacles; the smallest over the bodies"}
    elif len(poses):
        truth = result.world if result.world is not None else CollisionWorld.from_map(result.map, "all")
        c_min, i_min = truth.min_clearance(poses, result.footprint)
        margin = result.options.planning.margin
        if margin == "auto":           # the first plan's margin, as chosen by its tube
            margin = result.plans[0].margin if result.plans else 0.0
        free = truth.free_many(poses, result.footprint, margin)
        clearance = {"min_executed_m": c_min, "time_s": float(lg["t"][i_min]), "pose": poses[i_min],
                     "margin_m": margin, "samples_below_margin": int((~free).sum()), "samples": len(poses),
                     "note": "signed clearance of the footprint at every control sample to known and unknown obstacles"}
    effort = {}
    if len(lg["t"]):
        dt = T
        effort = {"integral_u_squared": dict(zip(model.input_names, (np.sum(lg["u"] ** 2, axis=0) * dt).tolist())),
                  "integral_feedback_squared": dict(zip(model.input_names,
                                                        (np.sum((lg["u"] - lg["u0"]) ** 2, axis=0) * dt).tolist())),
                  "saturated_fraction": float(np.mean(np.any(
                      np.isclose(np.abs(lg["u"]), model.input_limits()[:, 1], rtol=0, atol=1e-12), axis=1)))}
    plans, timings = zip(*(_plan_entry(p, result) for p in result.plans)) if result.plans else ((), ())
    opts = dataclasses.asdict(dataclasses.replace(result.options, robot=None))
    opts["robot"] = robot.spec()
    return {
        "status": result.status, "message": result.message,
        "inputs": {"map": map_path, "map_name": result.map.name, "robot": robot.describe(),
                   "footprint": result.footprint.describe(),
                   **({"trailer_footprints": [f.describe() for f in robot.trailer_footprints]}
                      if robot.trailer_footprints else {}),
                   "start": result.start, "goal": result.goal,
                   "options": opts, "noise": result.options.noise.describe(model.state_names),
                   "controller": result.options.controller.describe(model.n, model.m, robot.stabilizer.as_dict()),
                   "nhstab_version": __version__},
        "seeds": result.seeds,
        "initial_state": result.info.get("x_initial"),
        "plans": list(plans),
        "replans": sum(1 for p in result.plans if p.trigger != "initial"),
        "discovered_obstacles": result.discovered,
        "collision": result.collision,
        "final_error": result.info.get("final_errors"),
        "tracking": tracking,
        "tube": plans[0].get("tube") if plans else None,
        "clearance": clearance,
        "control_effort": effort,
        "duration_s": float(lg["t"][-1]) if len(lg["t"]) else 0.0,
        "timing": {"wall_time_s": result.wall_time_s, "plans": list(timings),
                   "replan_latencies_s": [t["attempt_latencies_s"][-1] for t, p in zip(timings, result.plans)
                                          if p.trigger != "initial"],
                   "note": "wall-clock; everything outside this section is reproducible from the seed"},
    }


#: every file ``nhstab run`` may write into its folder (an earlier run's are all replaced)
RUN_FILES = ("run.json", "trajectory.csv", "run_map.png", "run_tracking.png", "run.gif")
#: every file ``nhstab plan`` may write into its folder
PLAN_FILES = ("plan.json", "trajectory.csv", "trajectory.npz", "plan.png", "tube.npz")


def write_run(result: RunResult, out_dir, map_path: str | None = None, figures: bool = True,
              animate: bool = False, extra_files: dict | None = None) -> list[Path]:
    """Write trajectory.csv, the figures, run.json (and ``extra_files``: {name: text or bytes}) into
    ``out_dir`` as one output (:class:`nhstab.records.OutputFolder`): an earlier run's files there
    are replaced as a whole, never mixed with these, and ``nhstab-manifest.json`` (last) names them.
    Returns the paths written, the manifest last."""
    with OutputFolder(out_dir, "run", owned=RUN_FILES + tuple(extra_files or ()),
                      info={"status": result.status}) as out:
        for name, content in (extra_files or {}).items():
            if isinstance(content, bytes):
                out.path(name).write_bytes(content)
            else:
                out.write_text(name, content)
        out.write_text("trajectory.csv", trajectory_csv(result))
        if figures:
            out.save_figure(run_map_figure(result), "run_map.png")
            out.save_figure(run_tracking_figure(result), "run_tracking.png")
        if animate:
            write_animation(result, out.path("run.gif"))
        out.write_json("run.json", summary(result, map_path))
    return out.written


def plan_record(result, map_label: str, robot, start, goal, path_options, tube=None,
                extra: dict | None = None) -> dict:
    """The content of plan.json: status, message, inputs (map, robot as used, footprint, poses,
    options, feasibility residual), the plan's metrics, its error ``tube`` (a
    :class:`nhstab.tubes.Tube`) and ``extra`` records (e.g. ``margin_auto``, ``gains_auto``, the
    tube's noise model)."""
    nom = result.nominal
    inputs = {"map": map_label, "robot": robot.describe(), "footprint": robot.footprint.describe(),
              "start": [float(v) for v in start], "goal": [float(v) for v in goal],
              "path_options": dict(path_options.__dict__),
              "feasibility_residual_m": None if nom is None else nom.feasibility_residual()}
    out = {"status": result.status, "message": result.message, "inputs": inputs, "metrics": result.metrics}
    if tube is not None:
        out["tube"] = tube.summary()
    out.update(extra or {})
    return out


def write_plan(result, out_dir, m, map_label: str, robot, start, goal, path_options,
               figures: bool = True, tube=None, extra: dict | None = None) -> list[Path]:
    """Write trajectory.csv, trajectory.npz, plan.png and plan.json for a successful plan of
    :func:`nhstab.planning.plan` on map ``m``, as one output (:class:`nhstab.records.OutputFolder`).
    With a ``tube``, plan.png draws it and tube.npz holds its per-sample arrays."""
    import time

    import numpy as np


    started = time.perf_counter()
    if not result.ok:
        raise InputError("result", "a successful plan (result.ok)", result.status)

    model, footprint = robot.model, robot.footprint
    path_options = path_options.for_robot(robot)
    nom = result.nominal
    with OutputFolder(out_dir, "plan", owned=PLAN_FILES) as out:
        write_trajectory(out.path("trajectory.csv"), nom)
        write_trajectory(out.path("trajectory.npz"), nom)
        if figures:
            met = result.metrics
            cusps = met["cusps"]
            title = (f"{m.name}: {model.name}, {met['length_m']:.1f} m, {cusps} cusp{'' if cusps == 1 else 's'}, "
                     f"min clearance {met['min_clearance_m']:.2f} m")
            if tube is not None:
                title += f"\n{tube.probability:g}-tube: reach up to {tube.reach.max():.2f} m, {certified_text(tube)}"
            fig = plan_figure(m, nom.x[:, pose_columns(model)],
                              np.sign(nom.u[:, 0]), footprint, start, goal, title=title, tube=tube,
                              robot=robot, states=nom.x)
            out.save_figure(fig, "plan.png", fast_palette=True)      # flat fills, lines and text
        if tube is not None:
            out.write_npz("tube.npz", t=tube.t, poses=tube.poses, mean=tube.mean, cov=tube.cov,
                          std=tube.std, position_radius=tube.position_radius,
                          heading_spread=tube.heading_spread, reach=tube.reach, u_mean=tube.u_mean,
                          u_std=tube.u_std, saturation_per_step=tube.saturation_per_step,
                          probability=tube.probability)
        record = plan_record(result, map_label, robot, start, goal, path_options, tube, extra)
        record["timing"] = {"outputs_s": time.perf_counter() - started,
                            "outputs_note": "writing this plan's outputs, until plan.json: the files, plan.png and "
                                            "the feasibility residual (wall clock, not a function of the inputs)"}
        out.write_json("plan.json", record)
    return out.written
