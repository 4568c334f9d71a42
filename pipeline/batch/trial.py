"""One batch trial: a full composite-controller run (plan, execute, monitor, replan) from its spec,
reduced to a record of metrics for the store. Runs in a worker process (local or Dask), so it takes
and returns plain data."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
import traceback

import numpy as np

#: the error-norm series of a trial is sampled every this many seconds (for the envelopes)
SERIES_DT = 0.2

_MAPS: dict = {}


def _load(path: str, cell_size):
    from ..maps import load_map

    key = (path, cell_size)
    if key not in _MAPS:
        _MAPS[key] = load_map(path, **({"cell_size": cell_size} if cell_size else {}))
    return _MAPS[key]


def trial_options(spec: dict):
    """The RunOptions of a trial: the batch's base options with the cell's controller, gains, noise
    level, robot and the trial's seed."""
    from ..execution.config import options_from_mapping

    cell = spec["cell_spec"]
    base = options_from_mapping(spec["run"], prefix="run.")
    ctrl = dataclasses.replace(base.controller, kind=cell["controller"],
                               **{k: cell[k] for k in ("alpha", "delta", "gamma") if cell[k] is not None})
    noise = dataclasses.replace(base.noise, scale=base.noise.scale * cell["noise"])
    return dataclasses.replace(base, controller=ctrl, noise=noise, seed=int(spec["seed"]),
                               robot=cell["robot"], start=tuple(cell["start"]), goal=tuple(cell["goal"]))


def run_trial(spec: dict) -> dict:
    """Run one trial; never raises: an exception becomes a record with status "error"."""
    from .store import versions

    started = time.perf_counter()
    record = {"id": spec["id"], "cell": spec["cell"], "trial": spec["trial"], "seed": spec["seed"], "spec": spec,
              "versions": versions()}
    try:
        record.update(_run(spec))
    except Exception as exc:          # recorded, never stops the batch
        record.update(status="error", error=f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                      metrics=None, series=None,
                      timings={"traceback": traceback.format_exc(limit=8)})
    record.setdefault("timings", {})["trial_wall_s"] = time.perf_counter() - started
    record["finished_at"] = time.time()
    return record


def _run(spec: dict) -> dict:
    from ..execution import execute, summary
    from ..robot import resolve_robot
    from .config import robot_label

    cell = spec["cell_spec"]
    m = _load(cell["map_path"], cell["cell_size"])
    opts = trial_options(spec)
    rob = resolve_robot(opts.robot, m.robot, source="batch")
    model = rob.model
    robot = robot_label(opts.robot) if opts.robot is not None else robot_label(m.robot or "unicycle")
    result = execute(m, rob, np.asarray(opts.start, float), np.asarray(opts.goal, float), opts)
    s = summary(result, cell["map_path"])
    first = result.plans[0]
    metrics = {
        "status": result.status, "reached": result.status == "reached", "collision": result.status == "collision",
        "margin_m": s["clearance"].get("margin_m"), "min_clearance_m": s["clearance"].get("min_executed_m"),
        "margin_violation": bool(s["clearance"].get("samples_below_margin", 0) > 0)
        if s["clearance"] else None,
        "final_position_error_m": (s["final_error"] or {}).get("position_m"),
        "final_heading_error_rad": (s["final_error"] or {}).get("heading_rad"),
        "replans": s["replans"], "discovered": len(s["discovered_obstacles"]),
        "rms_error_norm": s["tracking"].get("rms_error_norm"), "max_error_norm": s["tracking"].get("max_error_norm"),
        "rms_position_error_m": s["tracking"].get("rms_position_error_m"),
        "max_position_error_m": s["tracking"].get("max_position_error_m"),
        "duration_s": s["duration_s"], "robot": robot,
    }
    if first.result is not None:
        pm = first.result.metrics
        metrics.update({"first_plan_length_m": pm.get("length_m"), "first_plan_duration_s": first.law.t_end - first.law.t0})
        if first.law.schedule is not None:
            d = first.law.schedule.diagnostics
            metrics.update({"p_m": d["p_m"], "p_M": d["p_M"], "rate_bound": d["rate_bound"]})
    # ||e(t)|| while following the first plan (until the first replan stop), every SERIES_DT
    lg = result.log
    series = None
    if len(lg["t"]):
        sel = (lg["plan_id"] == 0) & (lg["mode"] == 0)
        if sel.any():
            stop = np.flatnonzero(~sel)
            last = stop[0] if len(stop) else len(sel)
            e = np.linalg.norm(model.state_error(lg["x"][:last], lg["x0"][:last]), axis=1)
            step = max(1, int(round(SERIES_DT / result.info["period_s"])))
            series = {"dt_s": step * result.info["period_s"], "error_norm": e[::step].tolist(),
                      "e0_norm": float(e[0])}
            metrics["e0_norm"] = float(e[0])
    timings = {"run_wall_s": result.wall_time_s, "replan_latencies_s": s["timing"]["replan_latencies_s"]}
    if rob.trailers:        # a car with trailers: the docked trailer's errors, the hitch, jackknifes
        fe = s["final_error"] or {}
        metrics.update({
            "final_trailer_position_error_m": (fe.get("trailer_position_m") or [None])[-1],
            "final_trailer_heading_error_rad": (fe.get("trailer_heading_rad") or [None])[-1],
            "max_abs_hitch_angle_rad": max(s["clearance"].get("max_abs_hitch_angle_rad") or [float("nan")]),
            "jackknife": bool(result.collision and result.collision.get("kind") == "jackknife")})
    metrics["robot_spec"] = rob.spec()          # the robot as used, in the store
    return {"status": result.status, "metrics": metrics, "series": series, "timings": timings,
            "error": None if result.status != "numerical_failure" else result.message}


def replay_config(record: dict) -> dict:
    """A run config (the ``nhstab run --config`` format) that replays the trial exactly."""
    from ..records import to_jsonable

    opts = trial_options(record["spec"])
    cell = record["spec"]["cell_spec"]
    d = dataclasses.asdict(opts)
    # the stored map path is relative to where the batch ran (like the workers); the run config
    # resolves paths relative to itself, so it gets the absolute path
    out = {"map": str(Path(cell["map_path"]).resolve()), "seed": opts.seed, "start": list(opts.start), "goal": list(opts.goal)}
    if opts.robot:
        out["robot"] = opts.robot
    for key in ("rate_hz", "substeps", "saturate", "headroom", "max_time_s"):
        if d[key] is not None:
            out[key] = d[key]
    out["controller"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in d["controller"].items() if v is not None}
    noise = opts.noise
    out["noise"] = {"scale": noise.scale, "initial": {"distribution": noise.distribution, **noise.initial},
                    "sensor": dict(noise.sensor), "process": dict(noise.process),
                    "impulses": [{"time": t, **j} for t, j in noise.impulses]}
    # radians as stored (a round trip through degrees could change the last bit)
    out["sensor"] = {**d["sensor"], "mount": list(d["sensor"]["mount"])}
    for key in ("monitor", "planning", "replan", "tolerance"):
        out[key] = {k: v for k, v in d[key].items() if v is not None}
    return to_jsonable(out)
