"""``nhstab bench planning``: time to a feasible, stabilizable nominal."""

from __future__ import annotations

import time

import numpy as np

from .common import machine, maps_dir


def bench_planning(pairs: int = 20, budget_s: float = 5.0, seed: int = 2026) -> dict:
    """Time to a feasible, stabilizable nominal (plan + time-parameterisation + clearance check +
    gain schedule) over fixed start/goal pairs on the nav2 depot and a Bench-MR parking world, for
    the unicycle and the rwd car; and OMPL's validity checking time per state (Python callback)."""
    from ..collision import CollisionWorld
    from ..robot import default_robot
    from ..maps import load_map
    from ..planning import PathOptions, plan
    from ..planning.problems import random_problems

    maps = maps_dir()
    rows = []
    for label, path in [("nav2 depot", maps / "nav2" / "depot.yaml"),
                        ("bench-mr parking3", maps / "bench-mr" / "polygon_mazes" / "parking3.svg")]:
        m = load_map(path)
        world = CollisionWorld.from_map(m)
        for robot in ("unicycle", "rwd_car"):
            rob = default_robot(robot)
            fp = rob.footprint
            problems = random_problems(world, fp, pairs, seed=seed, clearance=0.5, min_distance=8.0)
            times, statuses, per_state = [], [], []
            for k, (start, goal) in enumerate(problems):
                opts = PathOptions(time_limit_s=budget_s, seed=k, margin=0.1)
                t0 = time.perf_counter()
                r = plan(m, rob, start, goal, opts, world=world)
                times.append(time.perf_counter() - t0)
                statuses.append(r.status)
                if r.metrics.get("validity_calls"):
                    per_state.append(r.metrics["validity_us_per_state"])
            ok = [t for t, s in zip(times, statuses) if s == "ok"]
            rows.append({
                "map": label, "robot": robot, "pairs": pairs, "pair_seed": seed, "budget_s": budget_s,
                "problems": [[list(map(float, s)), list(map(float, g))] for s, g in problems],
                "success_rate": len(ok) / pairs, "statuses": statuses,
                "median_s": float(np.median(ok)) if ok else None,
                "p95_s": float(np.percentile(ok, 95)) if ok else None,
                "times_s": times,
                "validity_us_per_state_median": float(np.median(per_state)) if per_state else None,
            })
    return {"benchmark": "planning", "machine": machine(), "rows": rows,
            "targets": {"median_s_max": 0.5, "success_rate_min": 0.95, "budget_s": budget_s},
            "met": {f"{r['map']} / {r['robot']}": bool(r["success_rate"] >= 0.95 and r["median_s"] is not None
                                                     and r["median_s"] < 0.5) for r in rows}}


def summary_lines(p: dict) -> list[str]:
    """Rows of the benchmark summary table (benchmark | measure | value | target | met)."""
    lines = []
    for r in p["rows"]:
        med = "-" if r["median_s"] is None else f"{r['median_s']:.2f} s"
        p95 = "-" if r["p95_s"] is None else f"{r['p95_s']:.2f} s"
        met = r["success_rate"] >= 0.95 and r["median_s"] is not None and r["median_s"] < 0.5
        lines.append(f"| planning | {r['map']}, {r['robot']}: success / median / p95 over {r['pairs']} pairs "
                     f"({r['budget_s']:g} s budget) | {100 * r['success_rate']:.0f} % / {med} / {p95} | "
                     f">= 95 % / < 0.5 s | {'yes' if met else 'NO'} |")
        lines.append(f"| planning | {r['map']}, {r['robot']}: OMPL validity check per state (Python) | "
                     f"{r['validity_us_per_state_median']:.1f} us | - | - |")
    return lines
