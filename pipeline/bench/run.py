"""``nhstab bench run``: replan latency, control update and sensor scan costs."""

from __future__ import annotations

import numpy as np

from ..collision import CollisionWorld
from ..execution import ControllerOptions, RunOptions, build_law, execute
from ..maps import load_map
from ..robot import default_footprint, default_robot
from ..sensing import RangeSensor
from .common import _best, machine, maps_dir

#: target of the replan latency's 95th percentile [s] (Nav2 replans at 1 Hz by default; the target is
#: half of that)
REPLAN_P95_MAX_S = 0.5


PHASES_NOTE = ("per successful replan attempt: search = the path search up to the path the plan uses "
               "(planning_time_s: guide, OMPL, local paths; when the car planner tried several paths, the "
               "earlier ones' nominals too); nominal_and_gains = the search margin, the nominal, its clearance "
               "check and the gain schedule (time_to_nominal_s - planning_time_s); rest = the rest of the "
               "latency (start and goal checks before the search, the feedback law); tube = the new plan's "
               "error tube, computed after the law is ready and not part of the latency (a fixed-margin run "
               "only reports it; with margin auto it chooses the margin and is inside the latency)")


def _add_phases(phases: dict, metrics: dict, attempt: dict) -> None:
    search = float(metrics["planning_time_s"])
    to_gains = float(metrics["time_to_nominal_s"])
    phases["search"].append(search)
    phases["nominal_and_gains"].append(to_gains - search)
    phases["rest"].append(float(attempt["latency_s"]) - to_gains)
    phases["tube"].append(float(attempt.get("tube_s", 0.0)))


def bench_run(runs: int = 10) -> dict:
    """The composite controller in closed loop: replan latency (detection to the new feedback law
    ready: the planning call's path, nominal, clearance check and gains; the error tube after it, timed
    beside), split into its phases (:data:`PHASES_NOTE`), over ``runs`` seeds of the replanning scenarios
    on the nav2 depot (unicycle) and our warehouse (rwd_car); and the cost of one control update
    (measure -> u, with the feedforward mean over the hold interval and saturation)."""
    maps = maps_dir()
    rows = []
    laws = {}
    for label, path in [("nav2 depot (scenario depot_blocked_aisle)", maps / "scenarios" / "depot_blocked_aisle.yaml"),
                        ("ours warehouse (scenario warehouse_aisle_a2)", maps / "scenarios" / "warehouse_aisle_a2.yaml")]:
        m = load_map(path)
        robot = m.robot["model"]
        rob = default_robot(robot)
        model = rob.model
        latencies, with_tube, statuses, replans, walls, sims = [], [], [], [], [], []
        phases = {"search": [], "nominal_and_gains": [], "rest": [], "tube": []}
        for seed in range(runs):
            r = execute(m, rob, m.start.as_array(), m.goal.as_array(), RunOptions(seed=seed))
            statuses.append(r.status)
            walls.append(r.wall_time_s)
            sims.append(float(r.log["t"][-1]) if len(r.log["t"]) else 0.0)
            for rec in r.plans[1:]:
                replans.append(rec.id)
                latencies.extend(a["latency_s"] for a in rec.attempts)
                with_tube.extend(a["latency_s"] + a.get("tube_s", 0.0) for a in rec.attempts)
                if rec.result is not None:       # where the replan's successful attempt spent its time
                    _add_phases(phases, rec.result.metrics, rec.attempts[-1])
            laws.setdefault(robot, (r.plans[0].law, model))
        rows.append({"scenario": label, "robot": robot, "runs": runs, "seeds": list(range(runs)),
                     "statuses": statuses, "replans": len(replans), "replan_latencies_s": latencies,
                     "replan_latency_median_s": float(np.median(latencies)) if latencies else None,
                     "replan_latency_p95_s": float(np.percentile(latencies, 95)) if latencies else None,
                     "replan_with_tube_s": with_tube,
                     "replan_with_tube_p95_s": float(np.percentile(with_tube, 95)) if with_tube else None,
                     "run_wall_time_s": walls, "simulated_s": sims,
                     "replan_phases_s": phases,
                     "replan_phase_medians_s": {k: float(np.median(v)) if v else None for k, v in phases.items()},
                     "replan_phases_note": PHASES_NOTE})
    # one control update, as the run loop does it
    steps = []
    for robot, (law, model) in laws.items():
        for kind in ("gramian", "tvlqr", "open-loop"):
            lw = law if kind == "gramian" else build_law(law.nominal, ControllerOptions(kind=kind),
                                                         default_robot(robot).stabilizer.as_dict())
            lim = model.input_limits()
            T = lw.h
            taus = lw.t[:-1]
            rng = np.random.default_rng(0)
            ys = lw.nominal.x[:-1] + 0.01 * rng.standard_normal((len(taus), model.n))

            def updates():
                for tau, y in zip(taus, ys):
                    u, _, _ = lw.control(float(tau), y.copy(), lw.mean_input(float(tau), float(tau) + T))
                    np.clip(u, lim[:, 0], lim[:, 1])

            best, median, _ = _best(updates, 3)
            steps.append({"robot": robot, "controller": kind, "updates": len(taus),
                          "us_per_update": 1e6 * best / len(taus), "us_per_update_median": 1e6 * median / len(taus)})
    # one scan of the run's range sensor (all round, 0.5 degree beams) from random free poses

    scans = []
    for label, path in [("nav2 depot (604x307 cells, 0.05 m)", maps / "nav2" / "depot.yaml"),
                        ("ours warehouse_corridor (vector shapes)", maps / "ours" / "warehouse_corridor.yaml")]:
        m = load_map(path)
        sensor, world = RangeSensor(m, RunOptions().sensor), CollisionWorld.from_map(m, "all")
        rng = np.random.default_rng(5)
        xmin, ymin, xmax, ymax = m.bounds
        poses = np.column_stack([rng.uniform(xmin, xmax, 400), rng.uniform(ymin, ymax, 400),
                                 rng.uniform(-np.pi, np.pi, 400)])
        poses = poses[world.free_many(poses, default_footprint("unicycle"))][:100]
        times = [_best(lambda p=p: sensor.scan(p), 3)[0] for p in poses]
        scans.append({"map": label, "beams": sensor.beams, "poses": len(poses),
                      "scan_ms_median": 1e3 * float(np.median(times)),
                      "scan_ms_p90": 1e3 * float(np.percentile(times, 90))})
    p95 = [r["replan_latency_p95_s"] for r in rows if r["replan_latency_p95_s"] is not None]
    return {"benchmark": "run", "machine": machine(), "scenarios": rows, "control_update": steps, "sensor_scan": scans,
            "targets": {"replan_latency_p95_s_max": REPLAN_P95_MAX_S, "control_update_us_max": 1000.0},
            "met": {**{f"replan p95 {r['scenario']}": bool(r["replan_latency_p95_s"] is not None
                                                          and r["replan_latency_p95_s"] < REPLAN_P95_MAX_S) for r in rows},
                    "control update": bool(all(s["us_per_update"] < 1000.0 for s in steps)),
                    "every scenario replanned": bool(p95 and len(p95) == len(rows))}}


def summary_lines(rr: dict) -> list[str]:
    """Rows of the benchmark summary table (benchmark | measure | value | target | met)."""
    lines = []
    for r in rr["scenarios"]:
        if r["replan_latency_p95_s"] is None:
            lines.append(f"| run | {r['scenario']}: replan latency | no replans in {r['runs']} runs | < {REPLAN_P95_MAX_S:g} s | NO |")
            continue
        met = r["replan_latency_p95_s"] < rr["targets"]["replan_latency_p95_s_max"]
        lines.append(f"| run | {r['scenario']}, {r['robot']}: replan latency median / p95 over "
                     f"{len(r['replan_latencies_s'])} replans in {r['runs']} runs | "
                     f"{r['replan_latency_median_s']:.2f} s / {r['replan_latency_p95_s']:.2f} s | p95 < {REPLAN_P95_MAX_S:g} s | "
                     f"{'yes' if met else 'NO'} |")
        ph = r.get("replan_phase_medians_s") or {}
        if all(ph.get(k) is not None for k in ("search", "nominal_and_gains", "rest", "tube")):
            lines.append(f"| run | {r['scenario']}: replan phases, median search / nominal and gains / rest (to the law) "
                         f"| {ph['search']:.2f} / {ph['nominal_and_gains']:.2f} / {ph['rest']:.2f} s | - | - |")
            lines.append(f"| run | {r['scenario']}: the new plan's error tube, computed after the law (not in the latency): "
                         f"median; replan p95 with it added | {ph['tube']:.2f} s; {r['replan_with_tube_p95_s']:.2f} s | - | - |")
        reached = sum(s == "reached" for s in r["statuses"])
        lines.append(f"| run | {r['scenario']}: runs reaching the goal | {reached} / {r['runs']} | - | - |")
    for sc in rr.get("sensor_scan", []):
        lines.append(f"| run | sensor scan ({sc['beams']} beams), {sc['map']}: median / p90 over {sc['poses']} poses | "
                     f"{sc['scan_ms_median']:.2f} / {sc['scan_ms_p90']:.2f} ms | - | - |")
    for st in rr["control_update"]:
        lines.append(f"| run | control update, {st['robot']}, {st['controller']} | {st['us_per_update']:.1f} us | "
                     f"< 1000 us | {'yes' if st['us_per_update'] < 1000 else 'NO'} |")
    return lines
