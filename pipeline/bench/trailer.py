"""``nhstab bench trailer``: planning on the trailer suite, against the trailer-axle search alone.

For every case of the trailer suite (``maps/trailer/suite/``, the rig of its ``robot:`` block) whose
widths are at least :data:`TARGET_FACTOR` of the rig's (a dock bay of at least 1.2 W off an aisle of at
least 1.2 S; a turn from an aisle of at least 1.2 S) and seeds 0 .. seeds-1: the plan ``nhstab plan``
makes (:func:`nhstab.planning.plan`, search budget ``budget_s``: the Reeds-Shepp search on the trailer's
axle and the lattice search over the whole rig, in the order the space asks for), and in turn the
**baseline**: the trailer-axle search alone with the whole budget (RRT-Connect in the Reeds-Shepp space
of the trailer's axle, joined with the exact chained-form steering: the planner a competent engineer
writes first for a car with a trailer, and the search nhstab tries first where the space allows),
both timed on the wall clock of the whole call.

Targets (the trailer suite's): a plan within 10 s for at least 95 % of the (case, seed) pairs, and a
median time to it under 2 s.
"""

from __future__ import annotations

import time

import numpy as np

from ..batch.trailer_study import suite_rows
from ..control import StabilizerOptions
from ..execution.config import check_number
from ..limits import check_int
from ..maps import load_map
from ..planning import PathOptions, TimingOptions
from ..planning.trailer import plan_trailer
from ..robot import robot_from_spec

#: the targets' widths: dock bays and aisles at least this factor of the rig's width and swept path
TARGET_FACTOR = 1.2
TARGET_RATE = 0.95
TARGET_MEDIAN_S = 2.0
BUDGET_S = 10.0
SEEDS = 3


def target_cases() -> list[dict]:
    """The suite's cases the targets cover (module docstring), in the suite's order."""
    out = []
    for row in suite_rows():
        aisle, bay = row["aisle_factor"], row["bay_factor"]
        if aisle >= TARGET_FACTOR - 1e-9 and (row["kind"] != "dock" or bay >= TARGET_FACTOR - 1e-9):
            out.append(row)
    return out


def _one(name: str, seed: int, budget_s: float, searches) -> dict:
    m = load_map(f"example:{name}")
    robot = robot_from_spec(m.robot, source="map")
    path = PathOptions(time_limit_s=budget_s, seed=seed).for_robot(robot).validated()
    stab = StabilizerOptions(**robot.stabilizer.as_dict()).validated()
    t0 = time.perf_counter()
    res = plan_trailer(m, robot, m.start.as_array(), m.goal.as_array(), path, TimingOptions().validated(), stab,
                       searches=searches)
    wall = time.perf_counter() - t0
    return {"seed": seed, "status": res.status, "time_s": wall, "ok": bool(res.ok and wall <= budget_s)}


def bench_trailer(seeds: int = SEEDS, budget_s: float = BUDGET_S, progress=None) -> dict:
    """The benchmark (module docstring): per target case and seed, nhstab's plan and the baseline's, in turn."""
    seeds = check_int("--seeds", seeds, 1, 100, "a number of seeds per case")
    budget_s = check_number("--budget", budget_s, 0.0, lo_open=True)
    say = progress or (lambda line: None)
    rows = []
    for spec in target_cases():
        name = spec["name"]
        row = {"case": name, "kind": spec["kind"], "aisle_factor": spec["aisle_factor"],
               "bay_factor": spec["bay_factor"] if spec["kind"] == "dock" else None, "nhstab": [], "baseline": []}
        for seed in range(seeds):
            row["nhstab"].append(_one(name, seed, budget_s, None))
            row["baseline"].append(_one(name, seed, budget_s, ("reeds_shepp",)))
            say(f"trailer {name} seed {seed}: nhstab {row['nhstab'][-1]['status']} {row['nhstab'][-1]['time_s']:.1f} s, "
                f"baseline {row['baseline'][-1]['status']} {row['baseline'][-1]['time_s']:.1f} s")
        rows.append(row)

    def totals(key):
        tries = [t for r in rows for t in r[key]]
        ok = [t["time_s"] for t in tries if t["ok"]]
        return {"plans": len(ok), "tries": len(tries), "rate": len(ok) / len(tries) if tries else None,
                "median_s": float(np.median(ok)) if ok else None}

    ours, base = totals("nhstab"), totals("baseline")
    return {"benchmark": "trailer", "seeds": seeds, "budget_s": budget_s, "target_factor": TARGET_FACTOR,
            "rows": rows, "nhstab": ours, "baseline": base,
            "baseline_description": "the trailer-axle search alone (RRT-Connect in the Reeds-Shepp space of the "
                                    "trailer's axle, exact chained-form steering), with the whole budget",
            "targets": {"rate_min": TARGET_RATE, "median_s_max": TARGET_MEDIAN_S},
            "met": {"rate": ours["rate"] is not None and ours["rate"] >= TARGET_RATE,
                    "median": ours["median_s"] is not None and ours["median_s"] < TARGET_MEDIAN_S}}


def summary_lines(b: dict) -> list[str]:
    lines = []
    for r in b["rows"]:
        size = (f"bay {r['bay_factor']:g} W, aisle {r['aisle_factor']:g} S" if r["bay_factor"] is not None
                else f"aisle {r['aisle_factor']:g} S")
        ours = [t for t in r["nhstab"] if t["ok"]]
        base = [t for t in r["baseline"] if t["ok"]]
        med = (lambda ts: f"{np.median([t['time_s'] for t in ts]):.2f} s" if ts else "-")
        lines.append(f"| trailer | {r['case']} ({size}): plans within {b['budget_s']:g} s over {len(r['nhstab'])} seeds, "
                     f"median; baseline (trailer-axle search alone) | {len(ours)}/{len(r['nhstab'])}, {med(ours)}; "
                     f"baseline {len(base)}/{len(r['baseline'])}, {med(base)} | - | - |")
    o, bl = b["nhstab"], b["baseline"]
    lines.append(f"| trailer | suite cases at >= {b['target_factor']:g}x widths: plans within {b['budget_s']:g} s "
                 f"({o['plans']}/{o['tries']}); baseline {bl['plans']}/{bl['tries']} | "
                 f"{100 * o['rate']:.0f} % | >= {100 * b['targets']['rate_min']:.0f} % | "
                 f"{'yes' if b['met']['rate'] else 'NO'} |")
    lines.append(f"| trailer | median time to a plan (baseline {'-' if bl['median_s'] is None else format(bl['median_s'], '.2f') + ' s'}) | "
                 f"{'-' if o['median_s'] is None else format(o['median_s'], '.2f') + ' s'} | "
                 f"< {b['targets']['median_s_max']:g} s | {'yes' if b['met']['median'] else 'NO'} |")
    return lines
