"""``nhstab bench parking``: planning on the parking suite.

For every case of the bundled parking suite (``maps/parking/``, see its SOURCE.md) and seeds
0 .. seeds-1: plan with the map's own car (its ``robot:`` block: footprint, limits, margin 0.1 m)
from the start in the lane to the goal in the slot, with a search budget of ``budget_s``, and
record

- **success**: an exact, feasible, clear, stabilizable nominal (status ``ok``) within the budget,
  counted on the wall clock of the whole ``plan()`` call (search, nominal, clearance check, gain
  schedule);
- **time** to that nominal (median over the successes);
- **cusps**: the nominal's direction reversals;
- **duration** against the bound of a nominal worth tracking (:func:`nhstab.planning.tracking_metrics`),
  ``T_bound = 1.5 (length / max_speed + (2 cusps + 2) max_steer / max_steer_rate)``: the path's
  length at the speed limit, plus steering at the rate limit from straight to full lock at the
  start, across the whole range (full lock to full lock) at every cusp, and back to straight at the
  goal (the nominal starts and ends with the wheels straight, and may steer in place);
- the **largest gain norm** ||K|| of the schedule (robot's default stabilizer) against the bound
  the stabilizer defaults were chosen for, ``GAIN_BOUND`` = 50 of ``nhstab sweep``
  (nhstab.planning.sweep): at 50 Hz with zero-order hold, dt ||B K|| < 2;
- the steering's largest |phi| against the car's limit.

Targets: parallel slots >= 1.1 x L1 and every perpendicular and angled bay: 100 %
success with a median under 1 s; slots of 1.0-1.05 x L1: >= 90 %; 0.9 x L1: >= 50 % (``success_met``);
and every successful nominal within the duration, gain and steering bounds of a nominal worth
tracking (``bounds_met``). A case is ``met`` when both are.
"""

from __future__ import annotations

import time

import numpy as np

from ..control import GAIN_BOUND
from ..errors import InputError
from ..maps import load_map
from ..parking import read_suite_csv
from ..planning import PathOptions, plan
from ..robot import robot_from_spec
from .common import machine, maps_dir

BUDGET_S = 5.0
SEEDS = 10
MEDIAN_TARGET_S = 1.0


def target_rate(kind: str, factor: float) -> float:
    """The success-rate target of a case."""
    if kind != "parallel" or factor >= 1.1 - 1e-9:
        return 1.0
    if factor >= 1.0 - 1e-9:
        return 0.9
    return 0.5


def needs_fast_median(kind: str, factor: float) -> bool:
    return kind != "parallel" or factor >= 1.1 - 1e-9


def duration_bound(length_m: float, cusps: int, model) -> float:
    """1.5 x (length / max_speed + (2 cusps + 2) max_steer / max_steer_rate) [s] (see the module docstring)."""
    return 1.5 * (length_m / model.max_speed + (2 * cusps + 2) * model.max_steer / model.max_steer_rate)


def bench_parking(seeds: int = SEEDS, budget_s: float = BUDGET_S, cases=None, progress=None) -> dict:
    """Plan every case of the bundled parking suite (or the named ``cases``) over ``seeds`` seeds."""
    folder = maps_dir() / "parking"
    rows_csv = read_suite_csv(folder / "suite.csv")
    if cases:
        known = {r["name"] for r in rows_csv}
        unknown = [c for c in cases if c not in known]
        if unknown:
            raise InputError("case", "names of the parking suite (nhstab parking table)", ", ".join(unknown))
        rows_csv = [r for r in rows_csv if r["name"] in set(cases)]
    if not (isinstance(seeds, int) and seeds >= 1):
        raise InputError("seeds", "an integer >= 1", seeds)
    if not budget_s > 0:
        raise InputError("budget", "a positive number of seconds", budget_s)
    rows = []
    for spec in rows_csv:
        m = load_map(folder / f"{spec['name']}.yaml")
        robot = robot_from_spec(m.robot, source="map")
        model = robot.model
        start, goal = m.start.as_array(), m.goal.as_array()
        trials = []
        for seed in range(seeds):
            t0 = time.perf_counter()
            r = plan(m, robot, start, goal, PathOptions(time_limit_s=budget_s, seed=seed))
            wall = time.perf_counter() - t0
            mt = r.metrics
            trial = {"seed": seed, "status": r.status, "time_s": wall, "ok_within_budget": r.ok and wall <= budget_s}
            if r.nominal is not None:
                cusps = int(mt.get("direction_reversals", mt.get("cusps", 0)))
                bound = duration_bound(float(mt["length_m"]), cusps, model)
                steer = mt.get("max_abs_steering_rad")
                trial.update({"length_m": float(mt["length_m"]), "cusps": cusps, "duration_s": float(mt["duration_s"]),
                              "duration_bound_s": bound, "duration_within_bound": bool(mt["duration_s"] <= bound),
                              "max_abs_steering_rad": steer,
                              "steering_within_limit": steer is None or bool(steer <= model.max_steer + 1e-9)})
            if r.ok:
                trial.update({"max_gain_norm": float(mt["max_gain_norm"]),
                              "gain_within_bound": bool(mt["max_gain_norm"] <= GAIN_BOUND)})
            else:
                trial["message"] = r.message
            trials.append(trial)
            if progress is not None:
                progress(f"{spec['name']} seed {seed}: {r.status} in {wall:.2f} s")
        rows.append(_row(spec, robot, trials, budget_s))
    met = {r["name"]: r["met"] for r in rows}
    return {"benchmark": "parking", "machine": machine(), "seeds": seeds, "budget_s": budget_s,
            "planner": "rrtconnect (the default), the car's own robot description from each map",
            "gain_bound": GAIN_BOUND,
            "duration_bound": "1.5 x (length / max_speed + (2 cusps + 2) max_steer / max_steer_rate)",
            "targets": {"parallel >= 1.1 L1, perpendicular, angled": "100 % success, median < 1 s",
                        "parallel 1.0-1.05 L1": ">= 90 % success", "parallel 0.9 L1": ">= 50 % success",
                        "success": f"status ok and the whole plan() call within {budget_s:g} s",
                        "bounds": "every successful nominal: duration <= bound, max ||K|| <= gain bound, "
                                  "|phi| <= max_steer"},
            "rows": rows, "met": met, "all_met": bool(all(met.values()))}


def _row(spec: dict, robot, trials: list, budget_s: float) -> dict:
    ok = [t for t in trials if t["ok_within_budget"]]
    rate = len(ok) / len(trials)
    median = float(np.median([t["time_s"] for t in ok])) if ok else None
    kind, factor = spec["kind"], spec["factor"]
    need = target_rate(kind, factor)
    success_met = rate >= need - 1e-12 and (not needs_fast_median(kind, factor) or (
        median is not None and median < MEDIAN_TARGET_S))
    bounds_met = all(t["duration_within_bound"] and t["gain_within_bound"] and t["steering_within_limit"] for t in ok)
    statuses: dict = {}
    for t in trials:
        key = t["status"] if t["status"] != "ok" or t["ok_within_budget"] else "ok_over_budget"
        statuses[key] = statuses.get(key, 0) + 1

    def stat(key, fn):
        vals = [t[key] for t in ok if t.get(key) is not None]
        return fn(vals) if vals else None

    return {
        "name": spec["name"], "car": spec["car"], "kind": kind, "factor": factor, "size_m": spec["size_m"],
        "reference_m": spec["reference_m"], "robot": robot.describe(), "trials": trials, "statuses": statuses,
        "success_rate": rate, "median_time_s": median,
        "cusps_median": stat("cusps", lambda v: float(np.median(v))), "cusps_max": stat("cusps", max),
        "duration_median_s": stat("duration_s", lambda v: float(np.median(v))),
        "duration_over_bound_max": stat("duration_s", lambda v: max(
            t["duration_s"] / t["duration_bound_s"] for t in ok)),
        "durations_within_bound": stat("duration_within_bound", lambda v: int(sum(v))),
        "max_gain_norm_median": stat("max_gain_norm", lambda v: float(np.median(v))),
        "max_gain_norm_max": stat("max_gain_norm", max),
        "gains_within_bound": stat("gain_within_bound", lambda v: int(sum(v))),
        "steering_within_limit": stat("steering_within_limit", lambda v: int(sum(v))),
        "target_success_rate": need, "target_median_s": MEDIAN_TARGET_S if needs_fast_median(kind, factor) else None,
        "success_met": bool(success_met), "bounds_met": bool(bounds_met), "met": bool(success_met and bounds_met),
    }


def summary_lines(p: dict) -> list[str]:
    """Rows of the benchmark summary table (benchmark | measure | value | target | met)."""
    lines = []
    for r in p["rows"]:
        ok = round(r["success_rate"] * len(r["trials"]))
        med = "-" if r["median_time_s"] is None else f"{r['median_time_s']:.2f} s"
        target = f">= {100 * r['target_success_rate']:.0f} %" + (
            f" / < {r['target_median_s']:g} s" if r["target_median_s"] is not None else "") + ", nominals within bounds"
        extra = ""
        if ok:
            extra = (f"; cusps {r['cusps_median']:g} (max {r['cusps_max']}); duration within bound "
                     f"{r['durations_within_bound']}/{ok} (worst {r['duration_over_bound_max']:.2f} x bound); "
                     f"max ||K|| {r['max_gain_norm_max']:.3g} ({r['gains_within_bound']}/{ok} <= {p['gain_bound']:g}); "
                     f"steering within its limit {r['steering_within_limit']}/{ok}")
        size = ("slot" if r["kind"] == "parallel" else "aisle") + f" {r['factor']:g} x"
        lines.append(f"| parking | {r['name']} ({size}): success / median over {len(r['trials'])} seeds "
                     f"({p['budget_s']:g} s){extra} | {ok}/{len(r['trials'])} / {med} | {target} | "
                     f"{'yes' if r['met'] else 'NO'} |")
    return lines
