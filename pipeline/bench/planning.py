"""``nhstab bench planning``: time to a feasible, stabilizable nominal, on small maps and at map scale."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from ..collision import CollisionWorld
from ..errors import InputError
from ..execution.outputs import write_plan
from ..maps import load_map
from ..maps.base import MapError
from ..planning import PathOptions, plan, pose_columns
from ..planning.guide import Guide
from ..planning.problems import random_problems
from ..records import save_figure
from ..report.plans import plan_figure
from ..robot import default_robot
from ..trajectory_io import write_trajectory
from .common import machine, maps_dir

#: the scale series: robot -> (Moving AI map, cell size [m], budget [s], why this cell size)
SCALE_SERIES = {
    "unicycle": ("NewYork_1_512.map", 0.25, 5.0,
                 "0.25 m cells (128 m x 128 m; streets about 4.5 m wide at their narrowest)"),
    "rwd_car": ("NewYork_1_512.map", 0.5, 10.0,
                "0.5 m cells (256 m x 256 m): at 0.25 m the narrow streets (about 4.5 m) leave the 1.8 m wide car "
                "with a 4.6 m planning turning radius no room to turn; at 0.5 m they are about 9 m wide"),
}
#: targets of the scale series: robot -> (success rate within the budget, median time [s])
SCALE_TARGETS = {"unicycle": (0.99, 1.0), "rwd_car": (0.95, 3.0)}
EXPONENT_MAX = 1.2
LENGTH_RATIO_MAX = 1.15
VALIDITY_US_MAX = 2.0
#: the outputs after the nominal (residual, figure, files) within this share of a plan
DIAGNOSTICS_SHARE_MAX = 0.10
DIAGNOSTICS_PROBLEMS = 3
#: the planning margin of the scale series [m] (the built-in robots' own margins are for noisy runs)
SCALE_MARGIN_M = 0.1


def bench_planning(pairs: int = 20, budget_s: float = 5.0, seed: int = 2026, longest_buckets: int = 4,
                   per_bucket: int = 10, spread_buckets: int = 5, per_spread_bucket: int = 4) -> dict:
    """Time to a feasible, stabilizable nominal (plan + time-parameterisation + clearance check +
    gain schedule) over fixed start/goal pairs on the nav2 depot and a Bench-MR parking world, for the
    unicycle and the rwd car; and the scale series (see :func:`scale_series`)."""
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
    series = [scale_series(robot, longest_buckets, per_bucket, spread_buckets, per_spread_bucket)
              for robot in SCALE_SERIES]
    met = {f"{r['map']} / {r['robot']}": bool(r["success_rate"] >= 0.95 and r["median_s"] is not None
                                             and r["median_s"] < 0.5) for r in rows}
    for s in series:
        met.update({f"scale {s['robot']}: {k}": v for k, v in s["met"].items()})
    return {"benchmark": "planning", "machine": machine(), "rows": rows, "scale_series": series,
            "targets": {"median_s_max": 0.5, "success_rate_min": 0.95, "budget_s": budget_s,
                        "scale": {r: {"success_rate_min": a, "median_s_max": b} for r, (a, b) in SCALE_TARGETS.items()},
                        "exponent_max": EXPONENT_MAX, "unicycle_median_length_ratio_max": LENGTH_RATIO_MAX,
                        "validity_us_per_state_median_max": VALIDITY_US_MAX},
            "met": met}


def _select(problems, longest_buckets: int, per_bucket: int, spread_buckets: int, per_spread_bucket: int):
    """Problem indices: ``per_bucket`` of each of the ``longest_buckets`` longest buckets, and
    ``per_spread_bucket`` of ``spread_buckets`` buckets whose lengths halve from there (so that the
    exponent of time against length is fitted over a range of lengths)."""
    buckets: dict[int, list[int]] = {}
    for k, p in enumerate(problems):
        buckets.setdefault(int(p.label.split()[1]), []).append(k)
    order = sorted(buckets)
    chosen = [(b, buckets[b][:per_bucket]) for b in order[-longest_buckets:]]
    top = order[-1]
    for j in range(1, spread_buckets + 1):
        target = top / 2 ** j
        b = min(order, key=lambda q: abs(q - target))
        if b not in dict(chosen):
            chosen.append((b, buckets[b][:per_spread_bucket]))
    return [k for _, ks in sorted(chosen) for k in ks]


def scale_series(robot: str, longest_buckets: int = 4, per_bucket: int = 10, spread_buckets: int = 5,
                 per_spread_bucket: int = 4) -> dict:
    """Problems of the bundled Moving AI NewYork_1_512 scenarios (``SCALE_SERIES``): per problem the time
    to a stabilizable nominal, the path length and its ratio to the guide's grid shortest path, the
    validity check's cost per state and how many states reached FCL; the success rate within the
    budget, the median time and the exponent of time against path length fitted over the successes
    (least squares in log-log). Problems whose start or goal the robot does not fit (its footprint
    within the margin of a wall) are skipped and counted."""
    name, cell, budget, why = SCALE_SERIES[robot]
    m = load_map(maps_dir() / "bench-mr" / "moving_ai_scenarios" / name, cell_size=cell)
    world = CollisionWorld.from_map(m)
    world.clearance_field()
    rob = default_robot(robot)
    fp = rob.footprint
    indices = _select(m.problems, longest_buckets, per_bucket, spread_buckets, per_spread_bucket)
    out, skipped = [], []
    for k in indices:
        p = m.problems[k]
        start, goal = p.start.as_array(), p.goal.as_array()
        opts = PathOptions(time_limit_s=budget, seed=k, margin=SCALE_MARGIN_M)
        t0 = time.perf_counter()
        try:
            r = plan(m, rob, start, goal, opts, world=world)
        except (InputError, MapError) as exc:
            skipped.append({"problem": k, "label": p.label, "reason": str(exc)})
            continue
        elapsed = time.perf_counter() - t0
        row = {"problem": k, "label": p.label, "reference_length_m": p.reference_length, "status": r.status,
               "time_s": elapsed, "within_budget": bool(r.ok and elapsed <= budget)}
        if r.path is not None:
            info = r.path.info
            row.update({"search_s": r.path.planning_time_s, "planner_used": info.get("planner_used"),
                        "ompl_calls": info.get("ompl_calls"), "fcl_fraction": info.get("fcl_fraction"),
                        "validity_states": r.path.validity_calls,
                        "validity_us_per_state": 1e6 * r.path.validity_time_s / max(r.path.validity_calls, 1)})
        if r.ok:
            row.update({"length_m": r.path.length, "duration_s": r.metrics["duration_s"]})
            g = r.path.info.get("guide")
            if g is not None and math.isfinite(g.get("length_m", math.inf)):
                margin = g["need_m"] - g["inscribed_radius_m"]
                guide = Guide(world.clearance_field(), fp, margin, start, goal, cache=world.cache.setdefault("guide", {}))
                row["grid_shortest_m"] = guide.shortest_length()
                row["length_ratio"] = r.path.length / row["grid_shortest_m"]
        out.append(row)
    ok = [r for r in out if r["within_budget"]]
    diagnostics = _diagnostics_cost(m, rob, world, ok, DIAGNOSTICS_PROBLEMS) if robot == "unicycle" else None
    attempted = len(out)
    rate = len(ok) / attempted if attempted else 0.0
    times = np.array([r["time_s"] for r in ok])
    lengths = np.array([r["length_m"] for r in ok])
    exponent = float(np.polyfit(np.log(lengths), np.log(times), 1)[0]) if len(ok) >= 3 else None
    ratios = [r["length_ratio"] for r in ok if "length_ratio" in r]
    per_state = [r["validity_us_per_state"] for r in out if r.get("validity_states")]
    success_min, median_max = SCALE_TARGETS[robot]
    median = float(np.median(times)) if len(ok) else None
    met = {"success": bool(rate >= success_min), "median": bool(median is not None and median < median_max),
           "exponent": bool(exponent is not None and exponent <= EXPONENT_MAX),
           "validity check": bool(per_state and float(np.median(per_state)) <= VALIDITY_US_MAX)}
    if diagnostics is not None:
        share = diagnostics["command_median_share"]
        met["diagnostics share"] = bool(share is not None and share < DIAGNOSTICS_SHARE_MAX)
    if robot == "unicycle":
        met["length ratio"] = bool(ratios and float(np.median(ratios)) <= LENGTH_RATIO_MAX)
    return {"robot": robot, "map": f"movingai/{name}", "cell_size_m": cell, "cell_size_why": why,
            "budget_s": budget, "problems": out, "skipped": skipped, "attempted": attempted,
            "skipped_count": len(skipped), "success_rate": rate, "median_s": median,
            "p95_s": float(np.percentile(times, 95)) if len(ok) else None,
            "length_range_m": [float(lengths.min()), float(lengths.max())] if len(ok) else None,
            "time_length_exponent": exponent,
            "median_length_ratio": float(np.median(ratios)) if ratios else None,
            "validity_us_per_state_median": float(np.median(per_state)) if per_state else None,
            "fcl_fraction_median": float(np.median([r["fcl_fraction"] for r in out if r.get("fcl_fraction") is not None]))
            if out else None,
            "margin_m": SCALE_MARGIN_M, "diagnostics": diagnostics, "met": met}


def _diagnostics_cost(m, rob, world, ok_rows: list[dict], count: int) -> dict | None:
    """On the ``count`` longest nominals of the series: the time ``nhstab plan`` spends after the nominal
    and its gains are ready (:func:`nhstab.execution.outputs.write_plan`: the feasibility residual in
    plan.json, plan.png, trajectory.csv and .npz, written to a temporary folder) against the time to
    the nominal (the plan timed again, same seed). Measured in this process after one warm-up write, so
    neither includes Python's imports (matplotlib's import, about half a second, is paid once per
    process by any figure). Each part is then timed again on its own (``parts_s``: residual,
    trajectory.csv, trajectory.npz, building the figure, drawing and storing it), to show where the
    time goes; the share is the whole write's."""
    import shutil
    import tempfile


    rows = sorted(ok_rows, key=lambda r: -r["duration_s"])[:count]
    if not rows:
        return None
    tmp = Path(tempfile.mkdtemp(prefix="nhstab-bench-diag-"))
    out = []
    try:
        for i, row in enumerate(rows):
            p = m.problems[row["problem"]]
            start, goal = p.start.as_array(), p.goal.as_array()
            opts = PathOptions(time_limit_s=SCALE_SERIES[rob.name][2], seed=row["problem"], margin=SCALE_MARGIN_M)
            t0 = time.perf_counter()
            r = plan(m, rob, start, goal, opts, world=world)
            planned = time.perf_counter() - t0
            if not r.ok:
                continue
            if i == 0:                                   # warm-up: imports and font caches
                write_plan(r, tmp / "warm", m, "bench", rob, start, goal, opts)
            t1 = time.perf_counter()
            write_plan(r, tmp / f"p{i}", m, "bench", rob, start, goal, opts)
            written = time.perf_counter() - t1
            out.append({"problem": row["problem"], "duration_s": r.nominal.duration, "samples": len(r.nominal.t),
                        "plan_s": planned, "diagnostics_s": written, "share": written / (planned + written),
                        "parts_s": _output_parts(r, m, rob, start, goal, tmp / f"parts{i}")})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if not out:
        return None
    commands = _command_share(rob, [o["problem"] for o in out])
    timed = [c for c in commands if "error" not in c]
    shares = [o["share"] for o in out]
    parts = {k: float(np.median([o["parts_s"][k] for o in out])) for k in out[0]["parts_s"]}
    return {"problems": out, "median_share": float(np.median(shares)), "target_share_max": DIAGNOSTICS_SHARE_MAX,
            "commands": commands,
            "command_median_share": float(np.median([c["share"] for c in timed])) if timed else None,
            "median_parts_s": parts,
            "parts_note": "each part timed again on its own after the whole write (so they need not add up to it): "
                          "the feasibility residual, trajectory.csv, trajectory.npz, building the plan figure, "
                          "drawing it and storing it as a palette PNG"}


def _command_share(rob, problems: list[int]) -> list[dict]:
    """The share as a user meets it: ``nhstab plan`` on each problem as a user runs it (a new process: imports,
    map, plan, error tube, outputs), its wall time, and the time it spent writing its outputs (plan.json's
    ``timing.outputs_s``: the residual, the files, plan.png and tube.npz)."""
    import json
    import subprocess
    import sys
    import tempfile

    name, cell, budget, _ = SCALE_SERIES[rob.name]
    path = maps_dir() / "bench-mr" / "moving_ai_scenarios" / name
    def once(k, folder, *extra):
        cmd = [sys.executable, "-c", "from nhstab.cli.main import main; main()", "plan", str(path),
               "--robot", rob.name, "--cell-size", str(cell), "--problem", str(k), "--margin", str(SCALE_MARGIN_M),
               "--time-limit", str(budget), "--seed", str(k), "--out", str(folder), *extra]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or [""])[-1]
            return f"exit {done.returncode}: {last}"
        return wall, json.loads((folder / "plan.json").read_text())["timing"]["outputs_s"]

    out = []
    with tempfile.TemporaryDirectory(prefix="nhstab-bench-cli-") as tmp:
        for k in problems:
            full = once(k, Path(tmp) / str(k))
            bare = once(k, Path(tmp) / f"{k}-nofig", "--no-figure")
            failed = [r for r in (full, bare) if isinstance(r, str)]
            if failed:                   # counted and shown, not hidden
                out.append({"problem": k, "error": failed[0]})
                continue
            out.append({"problem": k, "wall_s": full[0], "outputs_s": full[1], "share": full[1] / full[0],
                        "no_figure_wall_s": bare[0], "no_figure_outputs_s": bare[1],
                        "no_figure_share": bare[1] / bare[0]})
    return out


def _output_parts(r, m, rob, start, goal, folder: Path) -> dict:
    """The parts of :func:`nhstab.execution.outputs.write_plan`, each timed on its own [s]."""
    nom = r.nominal
    folder.mkdir(parents=True, exist_ok=True)
    parts = {}
    t0 = time.perf_counter()
    nom.feasibility_residual()
    parts["residual"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    write_trajectory(folder / "trajectory.csv", nom)
    parts["trajectory.csv"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    write_trajectory(folder / "trajectory.npz", nom)
    parts["trajectory.npz"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fig = plan_figure(m, nom.x[:, pose_columns(rob.model)], np.sign(nom.u[:, 0]), rob.footprint, start, goal,
                      title=f"{m.name}: {rob.model.name}", robot=rob, states=nom.x)
    parts["figure built"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    save_figure(fig, folder / "plan.png", fast_palette=True)         # as write_plan stores it
    parts["figure drawn and stored"] = time.perf_counter() - t0
    return parts


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
        if r["validity_us_per_state_median"] is not None:
            lines.append(f"| planning | {r['map']}, {r['robot']}: validity check per state | "
                         f"{r['validity_us_per_state_median']:.2f} us | - | - |")
    for s in p.get("scale_series", []):
        yes = {k: "yes" if v else "NO" for k, v in s["met"].items()}
        head = f"scale series {s['map']} at {s['cell_size_m']:g} m, {s['robot']}"
        success_min, median_max = SCALE_TARGETS[s["robot"]]
        med = "-" if s["median_s"] is None else f"{s['median_s']:.2f} s"
        lines.append(f"| planning | {head}: success within {s['budget_s']:g} s over {s['attempted']} problems "
                     f"({s['skipped_count']} skipped: the robot does not fit at the start or goal) | "
                     f"{100 * s['success_rate']:.0f} % | >= {100 * success_min:.0f} % | {yes['success']} |")
        lines.append(f"| planning | {head}: median time to a stabilizable nominal (paths "
                     f"{s['length_range_m'][0]:.0f}-{s['length_range_m'][1]:.0f} m) | {med} | < {median_max:g} s | "
                     f"{yes['median']} |" if s["length_range_m"] else
                     f"| planning | {head}: median time | - | < {median_max:g} s | NO |")
        exp = "-" if s["time_length_exponent"] is None else f"{s['time_length_exponent']:.2f}"
        lines.append(f"| planning | {head}: fitted exponent of time against path length | {exp} | "
                     f"<= {EXPONENT_MAX:g} | {yes['exponent']} |")
        if s["median_length_ratio"] is not None:
            target = f"<= {LENGTH_RATIO_MAX:g}" if "length ratio" in s["met"] else "-"
            lines.append(f"| planning | {head}: median path length / guide's grid shortest path | "
                         f"{s['median_length_ratio']:.3f} | {target} | {yes.get('length ratio', '-')} |")
        d = s.get("diagnostics")
        if d:
            durations = ", ".join(f"{o['duration_s']:.0f}" for o in d["problems"])
            cs = d.get("command_median_share")
            timed = [c for c in d.get("commands", []) if "error" not in c]
            for c in d.get("commands", []):
                if "error" in c:
                    lines.append(f"| planning | {head}: `nhstab plan` on problem {c['problem']} failed | {c['error']} | - | NO |")
            if cs is not None:
                walls = ", ".join(f"{c['wall_s']:.2f}" for c in timed)
                outs = ", ".join(f"{1000 * c['outputs_s']:.0f}" for c in timed)
                lines.append(f"| planning | {head}: outputs (residual, plan.png, files) as a share of `nhstab plan`'s wall "
                             f"time (a new process, as a user runs it: imports, map, plan, tube, outputs), median over "
                             f"the {len(timed)} longest nominals ({durations} s; wall {walls} s; outputs {outs} ms) | "
                             f"{100 * cs:.0f} % | < {100 * d['target_share_max']:.0f} % | "
                             f"{'yes' if cs < d['target_share_max'] else 'NO'} |")
                nf = float(np.median([c["no_figure_share"] for c in timed]))
                nf_out = ", ".join(f"{1000 * c['no_figure_outputs_s']:.0f}" for c in timed)
                lines.append(f"| planning | {head}: the same with `nhstab plan --no-figure` (no plan.png, no matplotlib "
                             f"drawing stack; outputs {nf_out} ms) | {100 * nf:.0f} % | - | - |")
            lines.append(f"| planning | {head}: stricter, the same outputs against the plan call alone (warm process, no "
                         f"imports, map or tube) | {100 * d['median_share']:.0f} % | - | - |")
            if d.get("median_parts_s"):
                plan_s = float(np.median([o["plan_s"] for o in d["problems"]]))
                parts = ", ".join(f"{k} {1000 * v:.0f}" for k, v in d["median_parts_s"].items())
                lines.append(f"| planning | {head}: those outputs by part, median [ms] (plan {1000 * plan_s:.0f} ms) | "
                             f"{parts} | - | - |")
        if s["validity_us_per_state_median"] is not None:
            lines.append(f"| planning | {head}: validity check per state (median; states reaching FCL: "
                         f"{100 * s['fcl_fraction_median']:.1f} %) | {s['validity_us_per_state_median']:.2f} us | "
                         f"<= {VALIDITY_US_MAX:g} us | {yes['validity check']} |")
    return lines
