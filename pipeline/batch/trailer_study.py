"""The trailer suite measured (``nhstab trailer table``, ``figure`` and ``sweep``): whether the planner finds
the suite's maneuvers, and how the feedback laws hold the rig on them under noise.

**Table** (:func:`plan_table`). For every case of the trailer suite (``maps/trailer/suite/``, the rig of
its ``robot:`` block) and seeds 0 .. seeds-1: :func:`nhstab.planning.plan` with a search budget of
``budget_s`` seconds, and per plan its status, the wall time of the whole call, the nominal's cusps
(direction reversals), its smallest clearance over every body (:func:`nhstab.bodies.min_clearance`,
FCL at every sample of the nominal) and its largest hitch angle. A plan **succeeds** when its status is
"ok" and the call returned within the budget. A case that does not plan is a row with the reasons.

**Sweep** (:func:`run_sweep`, configured by a YAML file, :func:`load_sweep_config`). For every case, ONE
plan: the first plan of ``nhstab run example:NAME --seed PLAN_SEED --time-limit TIME_LIMIT_S`` (the run's own first planning call,
retried as the run retries it: :func:`nhstab.batch.parking_study.first_plan`). On that nominal, per law
(TVLQR with Q = I, R = I; the gramian law at every combination of the config's alpha, delta, gamma and
end strategy) and noise level (a multiple of ``nhstab run``'s default initial error, sensor noise and
process disturbance), ``trials`` runs of the run loop (:func:`nhstab.batch.vector.simulate_shared`,
bit-identical to ``nhstab run``'s tracking loop for the seeds of
:func:`nhstab.batch.tube_study.trial_seeds`). A trial ends, as the run ends it, at the first sample
where a hitch angle is beyond the jackknife limit (**jackknife**) or a body overlaps an obstacle
(**collision**, FCL, every body at every sample); otherwise it is **docked** when the trailer's axle and
heading end within the run's goal tolerance (0.3 m, 0.2 rad), else it **missed** the goal; a trial
whose loop diverges counts apart. With ``tube: true`` each cell also gets its error tube
(:func:`cell_tube`: the rig's sampled tube, every body measured on the rollouts, jackknifes counted) and
the report lists the cells whose tube is certified against the docking target. A case that does not
plan is a row with the reason, and no cells.

The results are JSON-ready; :func:`table_markdown` and :func:`sweep_markdown` write every number from
them.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from concurrent.futures import as_completed
from dataclasses import replace

import numpy as np

from .. import bodies
from ..collision import CollisionWorld
from ..control import END_STRATEGIES
from ..errors import InputError, NumericalError, PipelineError
from ..examples import data_root
from ..execution.config import PROCESS_PER, NoiseOptions, PlanningOptions, RunOptions, check_number
from ..execution.controllers import Q_FOOTPRINT, ControllerOptions, build_law
from ..execution.runner import final_errors
from ..limits import MAX_BATCH_TRIALS, MAX_GAMMA, MAX_NOISE_SCALE, MAX_SEED, MAX_STUDY_TRIALS, check_int, check_range
from ..maps import load_map
from ..planning import PathOptions, plan
from ..planning.rig_reach import RANGES, reach_text, rest_state, rig_reach
from ..report.maps import map_figure
from ..report.plans import plan_figure
from ..robot import robot_from_spec
from ..safe_io import read_yaml_mapping
from ..trailer_suite import read_suite_csv
from ..tubes import predict_tube, verdict
from .parking_study import first_plan, spawned_pool, stop_pool
from .tube_study import trial_seeds
from .vector import simulate_shared

#: the table's search budget per plan [s] and seeds per case
BUDGET_S = 10.0
#: the wall time of the reach search (nhstab.planning.rig_reach) on a case of the table without a plan [s]
REACH_BUDGET_S = 60.0
SEEDS = 3


# ---- the suite -------------------------------------------------------------------------------------------

def suite_rows() -> list[dict]:
    """The trailer suite's cases (maps/trailer/suite/suite.csv), in its order."""
    return read_suite_csv(data_root() / "trailer" / "suite" / "suite.csv")


def check_cases(names, key: str = "cases") -> list[dict]:
    """The suite rows of ``names`` (``example:`` optional), in the order given; all when empty or None.
    An unknown or repeated name is an InputError naming ``key``."""
    rows = suite_rows()
    if not names:
        return rows
    if not isinstance(names, (list, tuple)):
        raise InputError(key, "a list of case names of the trailer suite", names)
    by_name = {r["name"]: r for r in rows}
    out, seen = [], set()
    for j, raw in enumerate(names):
        name = raw[len("example:"):] if isinstance(raw, str) and raw.startswith("example:") else raw
        if name not in by_name:
            raise InputError(f"{key}[{j}]", "a case of the trailer suite (" + ", ".join(by_name) + ")", raw)
        if name in seen:
            raise InputError(f"{key}[{j}]", "each case once", raw)
        seen.add(name)
        out.append(by_name[name])
    return out


def _size(row: dict) -> str:
    if row["kind"] == "dock":
        return f"bay {row['bay_factor']:g} W, aisle {row['aisle_factor']:g} S"
    return f"aisle and corridor {row['aisle_factor']:g} S"


# ---- the table -------------------------------------------------------------------------------------------

def path_length(x: np.ndarray) -> float:
    """The length [m] of the car's rear-axle path along states x (N, n)."""
    return float(np.sum(np.hypot(np.diff(x[:, 0]), np.diff(x[:, 1]))))


def plan_case(name: str, seed: int, budget_s: float):
    """One plan of a suite case: (record, map, robot, PlanResult)."""
    m = load_map(f"example:{name}")
    robot = robot_from_spec(m.robot, source="map")
    t0 = time.perf_counter()
    res = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(time_limit_s=budget_s, seed=seed))
    wall = time.perf_counter() - t0
    rec = {"seed": int(seed), "status": res.status, "time_s": wall, "ok_within_budget": bool(res.ok and wall <= budget_s)}
    if res.nominal is not None:
        x = res.nominal.x
        world = CollisionWorld.from_map(m, "known")
        c, k, b = bodies.min_clearance(world, robot, x)
        v = res.nominal.u[:, 0]
        s = np.sign(v[np.abs(v) > 1e-9])
        rec.update(cusps=int(np.sum(s[1:] != s[:-1])), length_m=path_length(x),
                   duration_s=float(res.nominal.t[-1] - res.nominal.t[0]), min_clearance_m=c,
                   min_clearance_body=b, max_abs_hitch_rad=float(np.max(np.abs(robot.model.hitch_angles(x)))))
    if not res.ok:
        rec["message"] = " ".join(res.message.split())
        if "likely_cause" in res.metrics:
            rec["likely_cause"] = res.metrics["likely_cause"]["text"]
    return rec, m, robot, res


def plan_table(cases=None, seeds: int = SEEDS, budget_s: float = BUDGET_S, progress=None,
               reach_budget_s: float = REACH_BUDGET_S) -> dict:
    """Plan every case of the suite (or ``cases``) over seeds 0 .. seeds-1 (module docstring). A case
    that no seed planned within the budget also gets :func:`reach_table`'s verdict (the default grid,
    the map's margin, ``reach_budget_s`` of wall time; 0: not asked) in its row's ``reach``: whether
    any plan can exist there."""
    rows_csv = check_cases(cases)
    seeds = check_int("seeds", seeds, 1, 1000, "a number of seeds per case")
    budget_s = check_number("budget", budget_s, 0.0, lo_open=True)
    # checked before any plan, with the reach search's own range: nothing planned is lost to it
    reach_budget_s = check_range("reach_budget", reach_budget_s, *RANGES["budget_s"], "s")
    rows = []
    for spec in rows_csv:
        trials = []
        for seed in range(seeds):
            rec = plan_case(spec["name"], seed, budget_s)[0]
            trials.append(rec)
            if progress is not None:
                progress(f"{spec['name']} seed {seed}: {rec['status']} in {rec['time_s']:.1f} s")
        ok = [t for t in trials if t["ok_within_budget"]]

        def med(key, ok=ok):
            vals = [t[key] for t in ok if t.get(key) is not None]
            return float(np.median(vals)) if vals else None

        statuses: dict = {}
        for t in trials:
            key = t["status"] if t["status"] != "ok" or t["ok_within_budget"] else "ok_over_budget"
            statuses[key] = statuses.get(key, 0) + 1
        rows.append({**{k: spec[k] for k in ("name", "kind", "bay_factor", "aisle_factor", "bay_m", "aisle_m")},
                     "trials": trials, "statuses": statuses, "planned": len(ok), "seeds": seeds,
                     "median_time_s": med("time_s"), "median_cusps": med("cusps"),
                     "min_clearance_m": min((t["min_clearance_m"] for t in ok), default=None),
                     "max_abs_hitch_rad": max((t["max_abs_hitch_rad"] for t in ok), default=None)})
        if not ok and reach_budget_s > 0:
            rows[-1]["reach"] = reach_table([f"example:{spec['name']}"], None, reach_budget_s, progress)["rows"][0]
    return {"table": "trailer suite plans", "seeds": seeds, "budget_s": budget_s, "reach_budget_s": reach_budget_s,
            "planner": "nhstab.planning.plan with the map's rig, PathOptions(time_limit_s=budget, seed)",
            "rows": rows, "cases_planned": sum(1 for r in rows if r["planned"] > 0), "cases": len(rows)}


def _f(v, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def table_markdown(result: dict) -> str:
    """The table as markdown, every number from ``result``."""
    lines = ["# The trailer suite: plans", "",
             f"Produced by `nhstab trailer table` (nhstab.batch.trailer_study): per case of the trailer suite "
             f"(maps/trailer/suite/SOURCE.md) and seeds 0 .. {result['seeds'] - 1}, one plan with a search budget of "
             f"{result['budget_s']:g} s. Planned = status ok within the budget; time = the whole plan() call, median over "
             "the plans found; cusps = direction reversals of the nominal (median); min clearance = the smallest over "
             "every body and sample of the plans found (FCL); hitch = the largest |hitch angle| of those nominals.", "",
             "| case | kind | size | planned | median time [s] | cusps | min clearance [m] | max hitch [rad] "
             "| statuses |", "|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        st = ", ".join(f"{k} {v}" for k, v in sorted(r["statuses"].items()))
        lines.append(f"| {r['name']} | {r['kind']} | {_size(r)} | {r['planned']}/{r['seeds']} | "
                     f"{_f(r['median_time_s'], '.2f')} | {_f(r['median_cusps'], 'g')} | "
                     f"{_f(r['min_clearance_m'], '.3f')} | {_f(r['max_abs_hitch_rad'], '.3f')} | {st} |")
    lines += ["", f"{result['cases_planned']} of {result['cases']} cases planned with at least one seed.", ""]
    failures = [(r["name"], t) for r in result["rows"] for t in r["trials"] if not t["ok_within_budget"]]
    if failures:
        lines += ["## Why plans failed", ""]
        for name, t in failures:
            why = t.get("message") or f"ok, but {t['time_s']:.1f} s over the {result['budget_s']:g} s budget"
            lines.append(f"- {name}, seed {t['seed']} ({t['time_s']:.1f} s): {t['status']}: {why}"
                         + (f" ({t['likely_cause']})" if t.get("likely_cause") else ""))
        lines.append("")
    reached = [r for r in result["rows"] if r.get("reach")]
    if reached:
        lines += ["## Can any plan exist where none was found?", "",
                  "Per case without a plan, `nhstab trailer reach` on its map (nhstab.planning.rig_reach; the default "
                  f"grid, the map's margin, {result['reach_budget_s']:g} s): disconnected = every configuration one "
                  "end reaches was expanded and none came from the other end (no plan at this grid); undecided = "
                  "the budget ran out first (see how far each end got).", ""]
        lines += [f"- {r['name']}: {r['reach']['text']}" for r in reached]
        lines.append("")
    return "\n".join(lines)


def reach_table(maps, margin: float | None = None, budget_s: float = 60.0, progress=None, **grid) -> dict:
    """:func:`nhstab.planning.rig_reach.rig_reach` between the start and goal of each map (a path or
    example:NAME; default: every case of the trailer suite) with the rig of its ``robot:`` block, keeping
    ``margin`` (default: the robot's). ``grid``: cell_m, angle_rad, steer_levels, step_m."""
    names = list(maps) if maps else [f"example:{r['name']}" for r in suite_rows()]
    if margin is not None:
        margin = check_number("margin", margin, 0.0)
    cases = []
    for name in names:                  # every map is read and checked before any search
        m = load_map(name)
        if m.robot is None:
            raise InputError(f"{name}: robot", "a robot: block with a car_trailer", None)
        robot = robot_from_spec(m.robot, source="map")
        if not robot.trailers:
            raise InputError(f"{name}: robot.model", "car_trailer (a car with trailers)", robot.model.name)
        xs = rest_state(robot.model, robot.configuration(m.start.as_array(), "start"))
        xg = rest_state(robot.model, robot.configuration(m.goal.as_array(), "goal"))
        cases.append((name, m, robot, xs, xg))
    rows = []
    for name, m, robot, xs, xg in cases:
        kept = robot.margin if margin is None else margin
        r = rig_reach(CollisionWorld.from_map(m, "known"), robot, xs, xg, kept, budget_s=budget_s, **grid)
        rows.append({"map": name, **r, "text": reach_text(r)})
        if progress is not None:
            progress(f"{name}: {rows[-1]['text']} ({r['wall_s']:.1f} s)")
    return {"table": "can the rig get from start to goal (nhstab.planning.rig_reach)", "budget_s": budget_s,
            "margin_m": margin, "rows": rows}


def reach_markdown(result: dict) -> str:
    """The reach table as markdown, every number from ``result``."""
    lines = ["# The rig's reach: can it get from start to goal at all?", "",
             "Produced by `nhstab trailer reach` (nhstab.planning.rig_reach): per map, every configuration the rig "
             "reaches from its start and from its goal, on a grid, breadth first from both ends, with moves of a fixed "
             "length at a steering angle set at rest (so any steering rate will do), each hitch angle within the "
             "jackknife limit and every body free by the margin (FCL). **disconnected**: the configurations one "
             "end reaches ran out, none reached from the other (at this grid: evidence, not a proof); "
             "**connected**: a grid cell was reached from both; **undecided**: the budget of "
             f"{result['budget_s']:g} s (or the cap on cells) ran out first.", "",
             "| map | margin [m] | verdict | cells from start / goal | farthest from start / goal [m] | grid "
             "| wall [s] |",
             "|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        grid = (f"{r['cell_m']:g} m, {math.degrees(r['angle_rad']):g} deg, {r['steer_levels']} steering levels, "
                f"{r['step_m']:g} m moves")
        verdict = r["verdict"] + (f" ({r['closed_end']} closed)" if r["closed_end"] else "")
        lines.append(f"| {r['map']} | {r['margin_m']:g} | {verdict} | {r['start']['cells']} / {r['goal']['cells']} | "
                     f"{r['start']['farthest_m']:.2f} / {r['goal']['farthest_m']:.2f} | {grid} | {r['wall_s']:.1f} |")
    lines += ["", *[f"- {r['map']}: {r['text']}" for r in result["rows"]], ""]
    return "\n".join(lines)


def case_figure(name: str, seed: int = 0, budget_s: float = BUDGET_S):
    """The case's map, its start and goal rigs, and the plan of ``seed`` (every body along it), or the
    map alone with why there is no plan in the title. Returns (figure, plan record)."""
    rec, m, robot, res = plan_case(name, seed, budget_s)
    start, goal = m.start.as_array(), m.goal.as_array()
    if res.nominal is None or not res.ok:
        title = f"{name}: no plan with seed {seed} ({rec['status']}, {rec['time_s']:.1f} s)"
        return map_figure(m, start=start, goal=goal, footprint=robot.footprint, title=title, robot=robot), rec
    nom = res.nominal
    poses = nom.x[:, robot.pose_columns]
    title = (f"{name}, seed {seed}: {rec['length_m']:.1f} m, {rec['cusps']} cusp(s), min clearance "
             f"{rec['min_clearance_m']:.3f} m, planned in {rec['time_s']:.1f} s")
    fig = plan_figure(m, poses, np.sign(nom.u[:, 0]), robot.footprint, start, goal, title=title, robot=robot,
                      states=nom.x)
    return fig, rec


# ---- the sweep config --------------------------------------------------------------------------------------

_TOP = ("name", "cases", "plan_seed", "root_seed", "time_limit_s", "trials", "noise", "process_per", "tvlqr", "tvlqr_q",
        "gramian", "tube")
#: TVLQR's Q in a sweep (``tvlqr_q``): the identity, or the robot's outline (``controller.q: footprint``)
TVLQR_Q = ("identity", Q_FOOTPRINT)
_GRAMIAN = ("alpha", "delta", "gamma", "end_strategy")
#: the sweep's defaults where the config leaves a key out
DEFAULTS = {"plan_seed": 0, "root_seed": 2026, "time_limit_s": 2.0, "trials": 50, "noise": [0.5, 1.0, 2.0],
            "process_per": "second", "tvlqr": True, "tvlqr_q": ["identity"], "tube": False}
#: a cell's tube (``tube: true``): the run's default probability, its certificate's confidence and discards
TARGET_DOCKED = 0.95


def _values(key: str, v, check) -> list:
    if not isinstance(v, list) or not v:
        raise InputError(key, "a non-empty list", v)
    out = [check(f"{key}[{j}]", x) for j, x in enumerate(v)]
    if len(set(out)) != len(out):
        raise InputError(key, "each value once", v)
    return out


def _number(lo: float, hi: float, lo_open: bool, what: str):
    def check(key, x):
        ok = isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and \
            (x > lo if lo_open else x >= lo) and x <= hi
        if not ok:
            raise InputError(key, what, x)
        return float(x)
    return check


def _q_word(key, x):
    if x not in TVLQR_Q:
        raise InputError(key, "one of " + ", ".join(TVLQR_Q) + " (TVLQR's Q)", x)
    return x


def _strategy(key, x):
    if x not in END_STRATEGIES:
        raise InputError(key, "one of " + ", ".join(END_STRATEGIES), x)
    return x


def check_sweep_config(data: dict) -> dict:
    """The sweep's settings from a config mapping (the YAML file's), every key checked; an error names
    the key (``gramian.alpha[1]``, ``noise[0]``, ``cases[2]``). Keys left out take :data:`DEFAULTS`, and
    the gramian's the rig's own value."""
    if not isinstance(data, dict):
        raise InputError("config", "a mapping of sweep settings", data)
    for key in data:
        if key not in _TOP:
            raise InputError(key, "one of " + ", ".join(_TOP), key)
    name = data.get("name", "trailer-law-sweep")
    if not isinstance(name, str) or not name:
        raise InputError("name", "a non-empty string", name)
    rows = check_cases(data.get("cases"), "cases")
    plan_seed = check_int("plan_seed", data.get("plan_seed", DEFAULTS["plan_seed"]), 0, MAX_SEED, "a seed")
    root_seed = check_int("root_seed", data.get("root_seed", DEFAULTS["root_seed"]), 0, MAX_SEED - 1, "a seed")
    time_limit_s = check_number("time_limit_s", data.get("time_limit_s", DEFAULTS["time_limit_s"]), 0.0, lo_open=True)
    trials = check_int("trials", data.get("trials", DEFAULTS["trials"]), 1, MAX_STUDY_TRIALS,
                       "a number of trials per cell")
    noise = _values("noise", data.get("noise", DEFAULTS["noise"]),
                    _number(0.0, MAX_NOISE_SCALE, True, f"a noise scale in (0, {MAX_NOISE_SCALE:g}]"))
    process_per = data.get("process_per", DEFAULTS["process_per"])
    if process_per not in PROCESS_PER:
        raise InputError("process_per", "one of " + ", ".join(PROCESS_PER) + " (what the process disturbance acts per)",
                         process_per)
    tvlqr = data.get("tvlqr", DEFAULTS["tvlqr"])
    if not isinstance(tvlqr, bool):
        raise InputError("tvlqr", "true or false (TVLQR as the reference law)", tvlqr)
    tvlqr_q = _values("tvlqr_q", data.get("tvlqr_q", DEFAULTS["tvlqr_q"]), _q_word)
    tube = data.get("tube", DEFAULTS["tube"])
    if not isinstance(tube, bool):
        raise InputError("tube", "true or false (each cell's error tube, every body certified on rollouts)", tube)
    gram = data.get("gramian", {}) or {}
    if not isinstance(gram, dict):
        raise InputError("gramian", "a mapping of alpha, delta, gamma, end_strategy lists", gram)
    for key in gram:
        if key not in _GRAMIAN:
            raise InputError(f"gramian.{key}", "one of " + ", ".join(_GRAMIAN), key)
    checks = {"alpha": _number(0.0, math.inf, True, "a positive finite number"),
              "delta": _number(0.0, math.inf, True, "a positive finite number [s]"),
              "gamma": _number(0.5, MAX_GAMMA, False, f"a number in [1/2, {MAX_GAMMA:g}]"),
              "end_strategy": _strategy}
    gramian = {k: (None if k not in gram else _values(f"gramian.{k}", gram[k], checks[k])) for k in _GRAMIAN}
    laws = (len(tvlqr_q) if tvlqr else 0) + math.prod(len(v) if v else 1 for v in gramian.values())
    total = len(rows) * laws * len(noise) * trials
    if total > MAX_BATCH_TRIALS:
        raise InputError("trials", f"at most {MAX_BATCH_TRIALS:,} trials in the sweep (cases x laws x noise x trials)",
                         f"{len(rows)} x {laws} x {len(noise)} x {trials} = {total:,}")
    return {"name": name, "cases": [r["name"] for r in rows], "plan_seed": plan_seed, "root_seed": root_seed,
            "time_limit_s": time_limit_s,
            "trials": trials, "noise": noise, "process_per": process_per, "tvlqr": tvlqr, "tvlqr_q": tvlqr_q,
            "gramian": gramian,
            "tube": tube}


def load_sweep_config(path) -> dict:
    """:func:`check_sweep_config` of a YAML file."""
    return check_sweep_config(read_yaml_mapping(path, "CONFIG", "trailer sweep config (YAML)"))


# ---- the sweep ----------------------------------------------------------------------------------------------

def laws(settings: dict, defaults: dict) -> list[dict]:
    """The sweep's laws: TVLQR (if asked), then every gramian combination; values the config leaves out
    are the rig's own (``defaults``: its stabilizer)."""
    out = []
    if settings["tvlqr"]:
        # the identity's law is plain "tvlqr", as in sweeps made before tvlqr_q
        out += [{"controller": "tvlqr", **({} if q == "identity" else {"q": q})}
                for q in settings.get("tvlqr_q", DEFAULTS["tvlqr_q"])]
    g = settings["gramian"]
    lists = [g[k] if g[k] else [defaults[k]] for k in _GRAMIAN]
    for alpha, delta, gamma, end in itertools.product(*lists):
        out.append({"controller": "gramian", "alpha": float(alpha), "delta": float(delta), "gamma": float(gamma),
                    "end_strategy": end})
    return out


def law_label(law: dict) -> str:
    if law["controller"] == "tvlqr" and law.get("q"):
        return f"tvlqr q={law['q']}"
    if law["controller"] != "gramian":
        return law["controller"]
    return f"gramian a={law['alpha']:g} d={law['delta']:g} g={law['gamma']:g} {law['end_strategy']}"


def build_sweep_law(run, result, law: dict):
    """The feedback law of a sweep cell along the plan's nominal."""
    if law["controller"] == "gramian":
        copts = replace(run.opts.controller, kind="gramian", gains="default", alpha=law["alpha"], delta=law["delta"],
                        gamma=law["gamma"])
        return build_law(result.nominal, copts, {**run.stab_defaults, "end_strategy": law["end_strategy"]}, None)
    copts = ControllerOptions(kind=law["controller"], q=law.get("q"))
    return build_law(result.nominal, copts, run.stab_defaults, None, robot=run.robot)


def trial_outcomes(run, law, seeds, noise) -> dict:
    """The trials of one cell (module docstring): jackknifes, collisions, docked, missed, diverged."""
    sim = simulate_shared(law, seeds, noise, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps, model=run.model)
    K, S = len(seeds), len(sim.t)
    model, robot = run.model, run.robot
    ok = sim.completed
    outcome = np.array(["diverged"] * K, dtype=object)
    max_hitch = np.full(K, np.nan)
    for i in np.flatnonzero(ok):
        x = sim.x[i]
        hitch = np.abs(model.hitch_angles(x)).max(axis=1)
        max_hitch[i] = float(hitch.max())
        over = np.flatnonzero(hitch > model.jackknife_limit)
        free = bodies.free_many(run.known, robot, x, 0.0)
        hit = np.flatnonzero(~free)
        k_jack = int(over[0]) if len(over) else S
        k_hit = int(hit[0]) if len(hit) else S
        if k_jack < S and k_jack <= k_hit:
            outcome[i] = "jackknife"
        elif k_hit < S:
            outcome[i] = "collision"
        else:
            fe = final_errors(robot, sim.x_final[i], run.goal)      # the docked body: the last trailer
            tol = run.opts.tolerance
            docked = fe["trailer_position_m"][-1] <= tol.position_m and fe["trailer_heading_rad"][-1] <= tol.heading_rad
            outcome[i] = "docked" if docked else "missed"
    counts = {k: int(np.sum(outcome == k)) for k in ("docked", "jackknife", "collision", "missed", "diverged")}
    finite = np.isfinite(max_hitch)
    return {"trials": K, **counts,
            "median_max_hitch_rad": float(np.median(max_hitch[finite])) if finite.any() else None,
            "per_trial": {"seed": [int(s) for s in seeds], "outcome": outcome.tolist()}}


def sweep_case(name: str, settings: dict, progress=None) -> dict:
    """One case of the sweep: its plan, then every (law, noise) cell."""
    started = time.perf_counter()
    case = {"case": name}
    try:
        opts = RunOptions(seed=settings["plan_seed"],
                          planning=PlanningOptions(time_limit_s=settings.get("time_limit_s", DEFAULTS["time_limit_s"])),
                          noise=NoiseOptions(process_per=settings.get("process_per", DEFAULTS["process_per"])))
        run, attempts, result, law0, margin, _ = first_plan(name, opts)
    except PipelineError as exc:
        case.update(plan={"found": False, "reason": " ".join(str(exc).split())}, cells=[],
                    plan_wall_s=time.perf_counter() - started)
        _say(progress, f"{name}: no plan ({case['plan']['reason']})")
        return case
    case["plan_wall_s"] = time.perf_counter() - started
    if law0 is None:
        last = attempts[-1]
        case.update(plan={"found": False, "reason": f"{last.get('status')}: {' '.join(str(last.get('message')).split())}",
                          "attempts": len(attempts)}, cells=[])
        _say(progress, f"{name}: no plan ({case['plan']['reason']})")
        return case
    nom = result.nominal
    c, _, b = bodies.min_clearance(run.known, run.robot, nom.x)
    case["plan"] = {"found": True, "attempts": len(attempts), "margin_m": margin, "length_m": path_length(nom.x),
                    "duration_s": float(law0.t_end - law0.t0), "min_clearance_m": c, "min_clearance_body": b}
    _say(progress, f"{name}: plan {case['plan']['duration_s']:.1f} s, min clearance {c:.3f} m "
                   f"({case['plan_wall_s']:.1f} s)")
    seeds = trial_seeds(settings["trials"], settings["root_seed"])
    cells = []
    built = []          # (label, law) of the laws built so far: a law with the same gains is run once
    for law in laws(settings, run.stab_defaults):
        t0 = time.perf_counter()
        try:
            fl = build_sweep_law(run, result, law)
        except PipelineError as exc:
            for level in settings["noise"]:
                cells.append({**law, "noise": level, "error": " ".join(str(exc).split())})
            _say(progress, f"{name} {law_label(law)}: no law ({exc})")
            continue
        twin = next((lb for lb, other in built if same_gains(fl, other)), None)
        built.append((law_label(law), fl))
        if twin is not None:
            # the same gains along the same nominal: the same trials and tube, seed for seed
            done = {c["noise"]: c for c in cells if "error" not in c and law_label(c) == twin}
            for level in settings["noise"]:
                # the counts repeat the twin's; its per-trial outcomes are not stored twice
                cells.append({**{k: v for k, v in done[level].items() if k != "per_trial"}, **law,
                              "same_gains_as": twin, "wall_s": 0.0})
            why = end_note(fl)
            _say(progress, f"{name} {law_label(law)}: the same gains as {twin} on this plan"
                           + (f" ({why})" if why else "") + "; its cells are that law's")
            continue
        for level in settings["noise"]:
            noise = replace(run.opts.noise, scale=run.opts.noise.scale * level)
            out = trial_outcomes(run, fl, seeds, noise)
            cell = {**law, "noise": level, "max_gain_norm": fl.info.get("max_gain_norm"), **out}
            if settings.get("tube"):
                cell["tube"] = cell_tube(run, fl, noise, margin)
            cell["wall_s"] = time.perf_counter() - t0
            cells.append(cell)
            t0 = time.perf_counter()
            _say(progress, f"{name} {law_label(law)} x{level:g}: docked {out['docked']}/{out['trials']}, "
                           f"jackknifes {out['jackknife']}, collisions {out['collision']}"
                           + (f"; tube {tube_cell_text(cell['tube'])}" if "tube" in cell else ""))
    case["cells"] = cells
    case["wall_s"] = time.perf_counter() - started
    return case


def same_gains(a, b) -> bool:
    """Whether two feedback laws are the same law: kind, grid, nominal and gains equal bit for bit (their
    trials and tubes are then equal seed for seed)."""
    return (a.kind == b.kind and np.array_equal(a.t, b.t) and np.array_equal(a.K, b.K)
            and np.array_equal(a.nominal.x, b.nominal.x) and np.array_equal(a.nominal.u, b.nominal.u))


def end_note(law) -> str:
    """Why a gramian law's end strategy did not matter, when its schedule says so ('' otherwise)."""
    sch = getattr(law, "schedule", None)
    end = (sch.diagnostics.get("end", "") if sch is not None else "") or ""
    return end if end.startswith("none") else ""


def cell_tube(run, law, noise, margin) -> dict:
    """A cell's error tube: the sampled tube of the rig (every body measured on 2,097 rollouts of the run
    loop under ``noise``, jackknifes counted; :func:`nhstab.tubes.predict_tube` with the robot) at the
    run's probability and confidence, certified against the known obstacles, and its verdict."""
    to = run.opts.tube
    try:
        tube = predict_tube(law, noise, run.fp, run.known, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps,
                            model=run.model, probability=to.probability, confidence=to.confidence,
                            discards=to.discards, robot=run.robot)
    except NumericalError as exc:
        return {"error": " ".join(str(exc).split())}
    cap = min(bodies.configuration_clearance(run.known, run.robot, p) for p in (run.start, run.goal))
    v = verdict(tube, run.known, run.fp, margin, cap=cap)
    cert = tube.certificate
    return {"kind": tube.kind, "rollouts": cert.get("rollouts"), "discards": cert.get("discards"),
            "probability": tube.probability, "confidence": cert.get("confidence"), "certified": tube.certified,
            "certified_clearance_m": tube.certified_clearance, "jackknifes": cert.get("jackknifes"),
            "max_reach_m": float(tube.reach.max()), "tightest": v.get("tightest"),
            "needed_margin_m": v.get("needed_margin_m")}


def tube_cell_text(t: dict) -> str:
    """A cell's tube in a few words."""
    if "error" in t:
        return f"none ({t['error']})"
    if t["certified_clearance_m"] is None:
        return "not certified"
    word = "certified" if t["certified"] else "**no**"
    jack = t.get("jackknifes")
    return f"{word} {t['certified_clearance_m']:+.3f} m" + (f", {jack} jackknifes" if jack else "")


def _say(progress, text: str) -> None:
    if progress is True:
        print(text, file=sys.stderr, flush=True)
    elif progress is not None:
        progress(text)


def _case_task(args):
    name, settings = args
    return sweep_case(name, settings, progress=True)


def _in_processes(names, settings, workers, progress) -> list:
    """The cases over ``workers`` spawned processes, one BLAS thread each; results in the given order."""
    pool = spawned_pool(workers, len(names))
    cases = [None] * len(names)
    try:
        futures = {pool.submit(_case_task, (name, settings)): i for i, name in enumerate(names)}
        for fut in as_completed(futures):
            cases[futures[fut]] = fut.result()
            _say(progress, f"done {names[futures[fut]]} ({sum(c is not None for c in cases)}/{len(names)} cases)")
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)
    return cases


def run_sweep(settings: dict, progress=None, workers: int = 1) -> dict:
    """The sweep of checked ``settings`` (:func:`check_sweep_config`): per case its plan and cells, and
    per law and noise level the totals over the cases that planned. ``workers`` > 1 spreads the cases
    over processes (spawned, one BLAS thread each); the result does not depend on it."""
    workers = check_int("workers", workers, 1, 64, "a number of worker processes")
    started = time.perf_counter()
    opts = RunOptions()
    names = settings["cases"]
    if workers == 1 or len(names) == 1:
        cases = [sweep_case(name, settings, progress) for name in names]
    else:
        cases = _in_processes(names, settings, workers, progress)
    totals = {}
    for case in cases:
        for c in case.get("cells", []):
            if "error" in c:
                continue
            key = (law_label(c), c["noise"])
            t = totals.setdefault(key, {"law": law_label(c), "noise": c["noise"], "cases": 0, "trials": 0, "docked": 0,
                                        "jackknife": 0, "collision": 0, "missed": 0, "diverged": 0})
            t["cases"] += 1
            for k in ("trials", "docked", "jackknife", "collision", "missed", "diverged"):
                t[k] += c[k]
    rows = list(totals.values())
    verdicts = {label: _verdicts(rows, label) for label in ("tvlqr", f"tvlqr q={Q_FOOTPRINT}")}
    return {"sweep": "trailer laws", "settings": settings,
            "tolerance": {"position_m": opts.tolerance.position_m, "heading_rad": opts.tolerance.heading_rad},
            "cases": cases, "totals": rows, "matches_or_beats_tvlqr": verdicts["tvlqr"],
            **({"matches_or_beats_tvlqr_footprint": verdicts[f"tvlqr q={Q_FOOTPRINT}"]}
               if verdicts[f"tvlqr q={Q_FOOTPRINT}"] else {}),
            "cases_planned": sum(1 for c in cases if c["plan"].get("found")), "workers": workers,
            "wall_s": time.perf_counter() - started}


def _verdicts(rows: list, reference: str) -> dict:
    """Per gramian law: whether it has, at every noise level, no more jackknifes and no more collisions
    than the law labelled ``reference`` (a TVLQR) over the same cases and seeds ({} without it)."""
    ref = {r["noise"]: r for r in rows if r["law"] == reference}
    verdicts = {}
    for r in rows:
        if r["law"].startswith("tvlqr") or r["noise"] not in ref:
            continue
        q = ref[r["noise"]]
        v = verdicts.setdefault(r["law"], True)
        verdicts[r["law"]] = v and r["jackknife"] <= q["jackknife"] and r["collision"] <= q["collision"]
    return verdicts


def _tube_setting(result: dict, key: str) -> str:
    for c in result["cases"]:
        for cell in c.get("cells", []):
            if key in cell.get("tube", {}):
                return f"{cell['tube'][key]:g}"
    return "-"


def sweep_markdown(result: dict) -> str:
    """The sweep as markdown, every number from ``result``."""
    s = result["settings"]
    tol = result["tolerance"]
    lines = ["# The trailer suite: feedback laws under noise", "",
             f"Produced by `nhstab trailer sweep` (nhstab.batch.trailer_study), config `{s['name']}`: per case one plan "
             f"(the first plan of `nhstab run example:NAME --seed {s['plan_seed']} --time-limit "
             f"{s.get('time_limit_s', DEFAULTS['time_limit_s']):g}`), then per law and noise level "
             f"{s['trials']} trials of the run loop (seeds spawned from {s['root_seed']}). Jackknife = a hitch angle "
             "beyond the limit before any collision; collision = a body overlaps an obstacle (FCL, every sample); "
             f"docked = neither, and the trailer's axle within {tol['position_m']:g} m and {tol['heading_rad']:g} rad "
             "of its goal."
             + (" **The process disturbance acts per metre the rig travels** (`process_per: metre`: none while it "
                "stands), not per second as `nhstab run`'s default." if s.get("process_per") == "metre" else ""), "",
             f"{result['cases_planned']} of {len(result['cases'])} cases planned.", "",
             "## Plans", "", "| case | plan | duration [s] | min clearance [m] |", "|---|---|---|---|"]
    for c in result["cases"]:
        p = c["plan"]
        if p.get("found"):
            lines.append(f"| {c['case']} | found | {p['duration_s']:.1f} | {p['min_clearance_m']:.3f} |")
        else:
            tries = f" (the last of {p['attempts']} attempts)" if p.get("attempts") else ""
            lines.append(f"| {c['case']} | **no plan**{tries}: {p['reason']} | - | - |")
    lines += ["", "## Totals over the cases that planned", "",
              "| law | noise | cases | docked | jackknifes | collisions | missed | diverged |",
              "|---|---|---|---|---|---|---|---|"]
    if not result["totals"]:
        lines.append("| no case planned | | | | | | | |")
    for r in sorted(result["totals"], key=lambda r: (r["noise"], r["law"] != "tvlqr", r["law"])):
        lines.append(f"| {r['law']} | x{r['noise']:g} | {r['cases']} | {r['docked']}/{r['trials']} | {r['jackknife']} | "
                     f"{r['collision']} | {r['missed']} | {r['diverged']} |")
    twins = sorted({(c["case"], law_label(cell), cell["same_gains_as"]) for c in result["cases"]
                    for cell in c.get("cells", []) if cell.get("same_gains_as")})
    if twins:
        lines += ["", "## Laws that are the same law on a plan", "",
                  "Two settings whose gains along a case's nominal are equal bit for bit are one law there: the "
                  "sweep runs it once, and the second setting's cells repeat the first's (same seeds, same "
                  "trials). On a plan whose nominal carries its own continuation past its end (the trailer "
                  "planner's), every gramian window is whole, so the end strategy does not apply.", ""]
        for case, lb, twin in twins:
            lines.append(f"- {case}: {lb} = {twin}")
    lines += ["", "## Gramian laws against TVLQR", "",
              "A law matches or beats TVLQR when, at every noise level, it has no more jackknifes and no more "
              "collisions than TVLQR over the same cases and seeds.", ""]
    if result["matches_or_beats_tvlqr"]:
        for law, ok in sorted(result["matches_or_beats_tvlqr"].items()):
            lines.append(f"- {law}: {'**yes**' if ok else 'no'}")
    else:
        lines.append("Not evaluated (no TVLQR cells, or no case planned).")
    if result.get("matches_or_beats_tvlqr_footprint"):
        lines += ["", f"Against TVLQR with Q from the rig's outline (`q: {Q_FOOTPRINT}`), the same test:", ""]
        for law, ok in sorted(result["matches_or_beats_tvlqr_footprint"].items()):
            lines.append(f"- {law}: {'**yes**' if ok else 'no'}")
    tubes = s.get("tube", False)
    if tubes:
        lines += ["", "## Cells whose tube is certified", "",
                  f"Each cell's error tube (p = {_tube_setting(result, 'probability')}: the rig's sampled tube, every "
                  "body measured with FCL on the rollouts, the discarded rollouts left out; certified when the "
                  "certified clearance is at least 0 and no more rollouts jackknife than are left out). Target: "
                  f"at least {100 * TARGET_DOCKED:g} % docked in every certified cell.", ""]
        cert = [(c["case"], cell) for c in result["cases"] for cell in c.get("cells", [])
                if cell.get("tube", {}).get("certified")]
        if not cert:
            lines.append("No cell's tube is certified.")
        for case, cell in cert:
            ok = cell["docked"] >= TARGET_DOCKED * cell["trials"]
            lines.append(f"- {case}, {law_label(cell)}, x{cell['noise']:g}: docked {cell['docked']}/{cell['trials']} "
                         f"({'meets' if ok else '**below**'} the target)")
    lines += ["", "## Per case", "", "| case | law | noise | docked | jackknifes | collisions | missed | diverged "
              "| median max hitch [rad] |" + (" tube |" if tubes else ""),
              "|---|---|---|---|---|---|---|---|---|" + ("---|" if tubes else "")]
    for c in result["cases"]:
        for cell in c.get("cells", []):
            if "error" in cell:
                lines.append(f"| {c['case']} | {law_label(cell)} | x{cell['noise']:g} | no law: {cell['error']} "
                             "| | | | | |" + (" |" if tubes else ""))
                continue
            lines.append(f"| {c['case']} | {law_label(cell)} | x{cell['noise']:g} | {cell['docked']}/{cell['trials']} | "
                         f"{cell['jackknife']} | {cell['collision']} | {cell['missed']} | {cell['diverged']} | "
                         f"{_f(cell['median_max_hitch_rad'], '.3f')} |"
                         + (f" {tube_cell_text(cell['tube'])} |" if tubes else ""))
    lines += ["", f"Wall time: {result['wall_s']:.0f} s.", ""]
    return "\n".join(lines)
