"""One batch trial: a full composite-controller run (plan, execute, monitor, replan) from its spec,
reduced to a record of metrics for the store. Runs in a worker process (local or Dask), so it takes
and returns plain data: the spec (robot description, run options, seed, poses) and the map as data
(a :class:`~nhstab.batch.bundle.MapBundle`, packed or not), never a path to read.

Where the map comes from, in order: the bundle passed with the trial (a Dask worker gets it this
way, scattered once per batch), the bundles provided to this process (:func:`provide_bundles`: a
local batch's workers get them when they start), and only for a library call that gives neither,
the spec's map path on this machine (read into a bundle, and checked against the spec's content
hash). Whichever it is, the map is loaded from the bundle, once per process (see
:mod:`nhstab.batch.bundle`)."""

from __future__ import annotations

import time
import traceback
import warnings
from pathlib import Path

import numpy as np

from ..errors import NotStabilizingWarning
from ..execution import execute, summary
from ..execution.config import config_mapping
from ..records import to_jsonable
from ..robot import resolve_robot
from .bundle import MapBundle, MapChangedError, loaded
from .config import robot_label, trial_options
from .store import versions

#: the error-norm series of a trial is sampled every this many seconds (for the envelopes)
SERIES_DT = 0.2

_PROVIDED: dict = {}


def provide_bundles(bundles: dict) -> None:
    """Make maps (``{bundle id: MapBundle or its packed bytes}``) available to the trials run by
    this process (a local batch's worker initializer calls this)."""
    _PROVIDED.update(bundles)


def withdraw_bundles(ids) -> None:
    for key in ids:
        _PROVIDED.pop(key, None)


def trial_map(spec: dict, bundle=None):
    """The map of a trial (see the module docstring), checked against the spec's bundle id and
    content hash (:class:`MapChangedError` otherwise)."""
    cell = spec["cell_spec"]
    key, digest, size = cell.get("map_bundle"), cell.get("map_hash"), cell.get("cell_size")
    if bundle is None and key is not None:
        m = loaded(key, size)
        if m is not None:
            return m
        bundle = _PROVIDED.get(key)
    if bundle is None:
        bundle = MapBundle.from_path(cell["map_path"], **({"cell_size": size} if size else {}))
    elif not isinstance(bundle, MapBundle):
        if key is not None and loaded(key, size) is not None:
            return loaded(key, size)
        bundle = MapBundle.unpack(bundle)
    if (key is not None and bundle.id != key) or (digest and bundle.content_hash != digest):
        raise MapChangedError(cell["map_path"], "the map the batch was configured with (its files unchanged)",
                              f"content hash {bundle.content_hash[:12]}",
                              detail=f"the batch's is {(digest or '?')[:12]}; the stored trials used that one: "
                                     "restore the map or start a new batch")
    return bundle.load(size)


def run_trial(spec: dict, bundle=None) -> dict:
    """Run one trial (its map from ``bundle``, a MapBundle or its packed bytes, or as the module
    docstring says). An exception becomes a record with status "error", except two that stop the
    batch instead: a map that is not the batch's (:class:`MapChangedError`), and Ctrl-C
    (KeyboardInterrupt, also when the run reports itself "interrupted"): an interrupted trial has no
    result and must not be stored."""
    started = time.perf_counter()
    record = {"id": spec["id"], "cell": spec["cell"], "trial": spec["trial"], "seed": spec["seed"], "spec": spec,
              "versions": versions()}
    try:
        with warnings.catch_warnings():
            # the batch warned once about a past window (run_batch); no repeat per trial and worker
            warnings.simplefilter("ignore", NotStabilizingWarning)
            record.update(_run(spec, bundle))
    except MapChangedError:
        raise
    except Exception as exc:          # recorded, never stops the batch
        record.update(status="error", error=f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                      metrics=None, series=None,
                      timings={"traceback": traceback.format_exc(limit=8)})
    if record.get("status") == "interrupted":
        raise KeyboardInterrupt
    record.setdefault("timings", {})["trial_wall_s"] = time.perf_counter() - started
    record["finished_at"] = time.time()
    return record


def _run(spec: dict, bundle=None) -> dict:
    cell = spec["cell_spec"]
    m = trial_map(spec, bundle)
    opts = trial_options(spec)
    rob = resolve_robot(opts.robot, m.robot, source="batch")
    model = rob.model
    robot = robot_label(opts.robot) if opts.robot is not None else robot_label(m.robot or "unicycle")
    result = execute(m, rob, np.asarray(opts.start, float), np.asarray(opts.goal, float), opts)
    if result.status == "interrupted":         # Ctrl-C inside the run: no result, the batch stops
        raise KeyboardInterrupt
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
    tube = (s["plans"][0].get("tube") or {}) if s["plans"] else {}
    if tube:
        observed = tube.get("observed") or {}
        metrics.update({"tube_certified_clearance_m": tube["certified_clearance_m"],
                        "tube_saturation_probability": tube["saturation_probability"],
                        "tube_max_position_radius_m": tube["max_position_radius_m"],
                        "tube_probability": tube["probability"], "tube_samples": observed.get("samples", 0),
                        "tube_inside_state": observed.get("inside_state_ellipsoid"),
                        "tube_inside": observed.get("inside_tube")})
    if first.result is not None:
        pm = first.result.metrics
        metrics.update({"first_plan_length_m": pm.get("length_m"), "first_plan_duration_s": first.law.t_end - first.law.t0})
        if first.law.schedule is not None:
            d = first.law.schedule.diagnostics
            metrics.update({"p_m": d["p_m"], "p_M": d["p_M"], "rate_bound": d["rate_bound"],
                            "rate_bound_printed": d["rate_bound_printed"], "window": d["window"]})
            if d.get("guarantee_until_s") is not None:      # a schedule split at cusps: its first cusp
                metrics["guarantee_until_s"] = d["guarantee_until_s"]
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
            if first.tube is not None:
                # per state: the observed error and the first plan's predicted mean and std, same samples
                k = np.arange(0, min(last, len(first.tube.t)), step)
                series.update({"state_names": list(model.state_names), "state_units": list(model.state_units),
                               "error_by_state": model.state_error(lg["x"][k], lg["x0"][k]).tolist(),
                               "tube_mean": first.tube.mean[k].tolist(), "tube_std": first.tube.std[k].tolist()})
            schedule = first.law.schedule
            if schedule is not None and schedule.options.window != "past":
                # the guaranteed bound of the noiseless linearised loop from this trial's true e(0)
                # (future window: the 3 alpha bound), at the series' samples
                e0 = model.state_error(lg["x"][0], lg["x0"][0])
                tau = lg["t"][:last:step] - first.t_start
                until = schedule.diagnostics.get("guarantee_until_s")
                if until is not None:           # a schedule split at cusps: the guarantee ends at the first
                    tau = tau[tau <= until]
                series["bound"] = schedule.error_bound(e0, np.clip(tau, schedule.t[0], schedule.t[-1])).tolist()
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


def replay_config(record: dict, map_path: str | None = None) -> dict:
    """A run config (the ``nhstab run --config`` format) that replays the trial exactly, on the map
    at ``map_path`` (relative to the config; ``nhstab batch replay`` writes the trial's map files
    beside it), or by default the absolute form of the path the trial records."""
    opts = trial_options(record["spec"])
    cell = record["spec"]["cell_spec"]
    if map_path is None:
        map_path = str(Path(cell["map_path"]).resolve())
    out = {"map": map_path, **config_mapping(opts)}
    return to_jsonable(out)
