"""Benchmarks (``nhstab bench``). Each returns a JSON-ready dict with measured values and targets.

Timings are wall-clock (time.perf_counter), best of several repetitions, measured in one process
so that ratios compare like with like on a shared, noisy machine.
"""

from __future__ import annotations

import math
import os
import platform
import time

import numpy as np
from scipy.integrate import quad_vec, solve_ivp

from .control import StabilizerOptions, compute_schedule
from .models import make_model
from .nominal import Nominal


def machine() -> dict:
    import scipy

    return {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
            "cpu_count": os.cpu_count(), "platform": platform.platform()}


def _best(fn, repeats: int) -> tuple[float, float, object]:
    times, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - started)
    return min(times), float(np.median(times)), result


def hilare_sinusoid(n_points: int) -> Nominal:
    """The paper's Hilare sinusoid nominal, u0 = (sin t, cos t) over 2 pi s, on n_points."""
    model = make_model("unicycle")
    t = np.linspace(0.0, 2.0 * math.pi, int(n_points))
    return Nominal.from_inputs(model, lambda tt: np.stack([np.sin(tt), np.cos(tt)], axis=-1), np.zeros(3), t)


def naive_schedule_P(nominal: Nominal, opts: StabilizerOptions) -> np.ndarray:
    """The naive way, as a baseline: for every grid point, integrate Phi(t, .) over its window with
    an adaptive ODE solver and the weighted gramian integrand with adaptive quadrature, then invert.
    Interior (whole future windows) only; the window end is clipped to the trajectory."""
    model = nominal.model
    n = model.n
    cw = opts.weight * opts.alpha
    out = np.empty((len(nominal.t), n, n))
    for i, t in enumerate(nominal.t):
        a = min(t, nominal.t_end - opts.delta)

        def phi_rhs(tau, z):
            x0, u0 = nominal.at(np.array([tau]))
            A, _ = model.linearize(x0[0], u0[0])
            return -(z.reshape(n, n) @ A).ravel()      # d/dtau Phi(t, tau) = -Phi(t, tau) A(tau)

        lo, hi = a, a + opts.delta
        fwd = solve_ivp(phi_rhs, (t, hi), np.eye(n).ravel(), method="DOP853", rtol=1e-11, atol=1e-13,
                        dense_output=True) if hi > t else None
        bwd = solve_ivp(phi_rhs, (t, lo), np.eye(n).ravel(), method="DOP853", rtol=1e-11, atol=1e-13,
                        dense_output=True) if lo < t else None

        def integrand(tau):
            sol = fwd if tau >= t else bwd
            X = sol.sol(tau).reshape(n, n)
            x0, u0 = nominal.at(np.array([tau]))
            XB = X @ model.g(x0[0])
            return math.exp(cw * (t - tau)) * (XB @ XB.T)

        H, _ = quad_vec(integrand, lo, hi, epsrel=1e-11, epsabs=1e-14)
        out[i] = np.linalg.inv(0.5 * (H + H.T))
    return out


def bench_gains(sizes=(1_000, 10_000, 100_000), naive_size: int = 1_000) -> dict:
    """Gain schedule on the Hilare sinusoid: linear growth and speed-up over the naive method."""
    opts = StabilizerOptions(alpha=0.1, delta=1.0, gamma=1.0)
    rows = []
    schedule_1k = None
    for N in sizes:
        nom = hilare_sinusoid(N)
        repeats = 7 if N <= 1_000 else (5 if N <= 10_000 else 3)
        compute_schedule(nom, opts)                  # warm-up
        best, median, sched = _best(lambda: compute_schedule(nom, opts), repeats)
        if N == naive_size:
            schedule_1k = sched
        rows.append({"grid_points": N, "best_s": best, "median_s": median, "repeats": repeats,
                     "us_per_point": best / N * 1e6})
    per_point = [r["us_per_point"] for r in rows]
    nom = hilare_sinusoid(naive_size)
    if schedule_1k is None:
        schedule_1k = compute_schedule(nom, opts)
    naive_best, _, P_naive = _best(lambda: naive_schedule_P(nom, opts), 1)
    interior = schedule_1k.t <= nom.t_end - opts.delta
    rel = (np.linalg.norm(schedule_1k.P[interior] - P_naive[interior], ord=2, axis=(1, 2))
           / np.linalg.norm(P_naive[interior], ord=2, axis=(1, 2)))
    fast_1k = next(r["best_s"] for r in rows if r["grid_points"] == naive_size)
    ratio = max(per_point) / min(per_point)
    speedup = naive_best / fast_1k
    return {
        "benchmark": "gains",
        "case": "hilare-sinusoid, alpha=0.1, delta=1, gamma=1, future window, 6-alpha weighting",
        "machine": machine(),
        "schedule": rows,
        "per_point_time_ratio": ratio,
        "naive": {"grid_points": naive_size, "seconds": naive_best,
                  "method": "per grid point: adaptive DOP853 for Phi plus adaptive quad_vec of the integrand"},
        "speedup_vs_naive": speedup,
        "max_relative_P_difference_vs_naive": float(rel.max()),
        "targets": {"per_point_time_ratio_max": 1.5, "speedup_vs_naive_min": 50.0},
        "met": {"linear": bool(ratio <= 1.5), "speedup": bool(speedup >= 50.0)},
    }


def _maps_dir():
    """The bundled maps: ./maps in the working directory, else beside the package (source checkout)."""
    from pathlib import Path

    from .errors import InputError

    for candidate in (Path.cwd() / "maps", Path(__file__).resolve().parent.parent / "maps"):
        if (candidate / "nav2" / "depot.yaml").is_file():
            return candidate
    raise InputError("maps folder", "the bundled maps/ (run from the root of a source checkout)", str(Path.cwd()))


def bench_collision(n_poses: int = 20_000, seed: int = 7) -> dict:
    """Build time of the FCL world and pose checks per second for a car footprint on the 512 x 512
    Moving AI rooms map (0.5 m cells) and the nav2 depot map; single calls and batched."""
    from .collision import CollisionWorld
    from .geometry import default_footprint
    from .maps import load_map

    maps = _maps_dir()
    fp = default_footprint("rwd_car")
    rows = []
    for label, path, options in [("movingai 64room_000 (512x512, 0.5 m cells)", maps / "movingai" / "64room_000.map",
                                  {"cell_size": 0.5}),
                                 ("nav2 depot (604x307, 0.05 m)", maps / "nav2" / "depot.yaml", {})]:
        m = load_map(path, **options)
        build_best, build_median, world = _best(lambda: CollisionWorld.from_map(m), 5)
        rng = np.random.default_rng(seed)
        xmin, ymin, xmax, ymax = m.bounds
        poses = np.column_stack([rng.uniform(xmin, xmax, n_poses), rng.uniform(ymin, ymax, n_poses),
                                 rng.uniform(-np.pi, np.pi, n_poses)])
        single_best, _, single = _best(lambda: [world.is_free(p, fp) for p in poses], 3)
        # the batched path's distance field is built once per world, on first use: timed on its own
        field_best, _, _ = _best(lambda: CollisionWorld.from_map(m).clearance_field(), 3)
        batch_best, _, batch = _best(lambda: world.free_many(poses, fp), 3)
        agree = bool(np.array_equal(np.asarray(single), batch))
        rows.append({"map": label, "objects": world.n_objects, "grid_boxes": world.n_grid_boxes,
                     "build_s": build_best, "build_median_s": build_median,
                     "distance_field_build_s": field_best - build_best,
                     "poses": n_poses, "free_fraction_of_poses": float(np.mean(batch)),
                     "single_checks_per_s": n_poses / single_best, "batched_checks_per_s": n_poses / batch_best,
                     "single_and_batched_agree": agree})
    return {
        "benchmark": "collision", "footprint": fp.describe(), "machine": machine(), "maps": rows,
        "targets": {"build_s_max": 1.0, "checks_per_s_min": 50_000},
        "met": {"build": all(r["build_s"] < 1.0 for r in rows),
                "single": all(r["single_checks_per_s"] >= 50_000 for r in rows),
                "batched": all(r["batched_checks_per_s"] >= 50_000 for r in rows)},
    }


def bench_planning(pairs: int = 20, budget_s: float = 5.0, seed: int = 2026) -> dict:
    """Time to a feasible, stabilizable nominal (plan + time-parameterisation + clearance check +
    gain schedule) over fixed start/goal pairs on the nav2 depot and a Bench-MR parking world, for
    the unicycle and the rwd car; and OMPL's validity checking time per state (Python callback)."""
    from .collision import CollisionWorld
    from .geometry import default_footprint
    from .maps import load_map
    from .models import make_model
    from .planning import PathOptions, default_turning_radius, plan
    from .planning.problems import random_problems

    maps = _maps_dir()
    rows = []
    for label, path in [("nav2 depot", maps / "nav2" / "depot.yaml"),
                        ("bench-mr parking3", maps / "bench-mr" / "polygon_mazes" / "parking3.svg")]:
        m = load_map(path)
        world = CollisionWorld.from_map(m)
        for robot in ("unicycle", "rwd_car"):
            model, fp = make_model(robot), default_footprint(robot)
            problems = random_problems(world, fp, pairs, seed=seed, clearance=0.5, min_distance=8.0)
            times, statuses, per_state = [], [], []
            for k, (start, goal) in enumerate(problems):
                opts = PathOptions(turning_radius=default_turning_radius(model), time_limit_s=budget_s, seed=k)
                t0 = time.perf_counter()
                r = plan(m, model, fp, start, goal, opts, world=world)
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


def bench_run(runs: int = 10) -> dict:
    """The composite controller in closed loop: replan latency (detection to the new gain schedule
    ready: planning, nominal, clearance check, gains) over ``runs`` seeds of the replanning scenarios
    on the nav2 depot (unicycle) and our warehouse (rwd_car); and the cost of one control update
    (measure -> u, with the feedforward mean over the hold interval and saturation)."""
    from .execution import ControllerOptions, RunOptions, build_law, execute
    from .geometry import default_footprint
    from .maps import load_map
    from .models import make_model
    from .planning import DEFAULT_STABILIZER

    maps = _maps_dir()
    rows = []
    laws = {}
    for label, path in [("nav2 depot (scenario depot_blocked_aisle)", maps / "scenarios" / "depot_blocked_aisle.yaml"),
                        ("ours warehouse (scenario warehouse_aisle_a2)", maps / "scenarios" / "warehouse_aisle_a2.yaml")]:
        m = load_map(path)
        robot = m.robot["model"]
        model, fp = make_model(robot), default_footprint(robot)
        latencies, statuses, replans, walls, sims = [], [], [], [], []
        for seed in range(runs):
            r = execute(m, model, fp, m.start.as_array(), m.goal.as_array(), RunOptions(seed=seed))
            statuses.append(r.status)
            walls.append(r.wall_time_s)
            sims.append(float(r.log["t"][-1]) if len(r.log["t"]) else 0.0)
            for rec in r.plans[1:]:
                replans.append(rec.id)
                latencies.extend(a["latency_s"] for a in rec.attempts)
            laws.setdefault(robot, (r.plans[0].law, model))
        rows.append({"scenario": label, "robot": robot, "runs": runs, "seeds": list(range(runs)),
                     "statuses": statuses, "replans": len(replans), "replan_latencies_s": latencies,
                     "replan_latency_median_s": float(np.median(latencies)) if latencies else None,
                     "replan_latency_p95_s": float(np.percentile(latencies, 95)) if latencies else None,
                     "run_wall_time_s": walls, "simulated_s": sims})
    # one control update, as the run loop does it
    steps = []
    for robot, (law, model) in laws.items():
        for kind in ("gramian", "tvlqr", "open-loop"):
            lw = law if kind == "gramian" else build_law(law.nominal, ControllerOptions(kind=kind),
                                                         DEFAULT_STABILIZER[robot])
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
    from .collision import CollisionWorld
    from .sensing import RangeSensor

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
            "targets": {"replan_latency_p95_s_max": 1.0, "control_update_us_max": 1000.0},
            "met": {**{f"replan p95 {r['scenario']}": bool(r["replan_latency_p95_s"] is not None
                                                          and r["replan_latency_p95_s"] < 1.0) for r in rows},
                    "control update": bool(all(s["us_per_update"] < 1000.0 for s in steps)),
                    "every scenario replanned": bool(p95 and len(p95) == len(rows))}}


def _hilare_law():
    from .execution import ControllerOptions, build_law
    from .paper import CASES

    case = CASES["hilare-sinusoid"]
    return build_law(hilare_sinusoid(315), ControllerOptions(kind="gramian", alpha=case.alpha, delta=case.delta,
                                                             gamma=case.gamma), {})


def _shared_worker(args) -> tuple[float, int]:
    """Simulate ``k`` Hilare trials with sensor noise in this process; returns (seconds, trials)."""
    k, first_seed = args
    from .batch.vector import simulate_shared
    from .execution.config import NoiseOptions

    law = _hilare_law()
    seeds = list(range(first_seed, first_seed + k))
    started = time.perf_counter()
    simulate_shared(law, seeds, NoiseOptions(), record=False)
    return time.perf_counter() - started, k


def _naive_trials(law, seeds, noise) -> float:
    """The baseline: one trial at a time, every hold interval integrated with solve_ivp (RK45,
    rtol 1e-8), the same seeded noise and ZOH law. Returns the mean final error norm (a check that
    it computed the same thing)."""
    from .execution.runner import seed_for

    model = law.nominal.model
    T = 0.02                                       # 50 Hz, as simulate_shared's default
    sig_s = noise.vector("sensor", model.state_names)
    sig_p = noise.vector("process", model.state_names) * math.sqrt(T)
    sig_0 = noise.vector("initial", model.state_names)
    lim = model.input_limits()
    finals = []
    for seed in seeds:
        r0 = np.random.default_rng(seed_for(seed, "initial"))
        rs = np.random.default_rng(seed_for(seed, "sensor"))
        rp = np.random.default_rng(seed_for(seed, "process"))
        x = law.nominal.x[0] + sig_0 * r0.standard_normal(model.n)
        k = 0
        while k * T < law.t_end - 1e-9:
            tau = k * T
            k += 1
            y = x + sig_s * rs.standard_normal(model.n)
            u, _, _ = law.control(tau, y.copy(), law.mean_input(tau, tau + T))
            u = np.clip(u, lim[:, 0], lim[:, 1])
            x = solve_ivp(lambda t, z: model.rhs(z, u), (0.0, T), x, rtol=1e-8, atol=1e-10).y[:, -1]
            x = x + sig_p * rp.standard_normal(model.n)
        finals.append(float(np.linalg.norm(model.state_error(x, law.nominal.x[-1]))))
    return float(np.mean(finals))


def bench_batch(k: int = 4000, naive_trials: int = 10, map_trials: int = 6, repeats: int = 5) -> dict:
    """Batch throughput: trials per second for the paper's Hilare sinusoid with sensor noise (2 pi s
    at 50 Hz) vectorised over trials that share the nominal, on one worker process and on two at once
    (each its own process, one thread; best of ``repeats``, wall time from submitting both to both
    done), against a naive per-trial solve_ivp loop; and full map trials (plan, execute, sense,
    monitor, replan) on the bundled cluttered room."""
    import multiprocessing as mp

    from .batch.config import load_batch_config
    from .batch.trial import run_trial
    from .batch.vector import simulate_shared
    from .execution.config import NoiseOptions

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    ctx = mp.get_context("fork")
    with ctx.Pool(1) as pool:
        one = min((pool.map(_shared_worker, [(k, 0)])[0][0] for _ in range(repeats)))
    with ctx.Pool(2) as pool:
        two = []
        for _ in range(repeats):
            started = time.perf_counter()
            pool.map(_shared_worker, [(k, 0), (k, k)])
            two.append(time.perf_counter() - started)
    two_wall = min(two)
    law = _hilare_law()
    noise = NoiseOptions()
    started = time.perf_counter()
    naive_final = _naive_trials(law, list(range(naive_trials)), noise)
    naive = time.perf_counter() - started
    vec = simulate_shared(law, list(range(naive_trials)), noise, record=False)
    # full map trials: the cluttered room, gramian law, default noise, on this process
    import tempfile
    from pathlib import Path

    maps = _maps_dir()
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / "b.yaml"
        cfg.write_text(f"name: bench\nroot_seed: 1\ntrials: {map_trials}\n"
                       f"maps: [{{path: {maps / 'ours' / 'cluttered_room.yaml'}}}]\n")
        specs = load_batch_config(cfg).trial_specs()
        run_trial(specs[0])                       # warm the map cache, as a worker would be
        started = time.perf_counter()
        statuses = [run_trial(sp)["status"] for sp in specs]
        map_wall = time.perf_counter() - started
    one_rate = k / one
    two_rate = 2 * k / two_wall
    naive_rate = naive_trials / naive
    return {
        "benchmark": "batch", "machine": machine(),
        "shared_nominal": {"case": "Hilare sinusoid, u0 = (sin t, cos t), 2 pi s, 315 control steps at 50 Hz, "
                                   "gramian law (alpha 0.1, delta 1, gamma 1), default noise",
                           "trials_per_worker": k, "one_worker_s": one, "one_worker_trials_per_s": one_rate,
                           "two_workers_wall_s": two_wall, "two_workers_trials_per_s": two_rate,
                           "scaling_two_over_one": two_rate / one_rate},
        "naive_baseline": {"trials": naive_trials, "wall_s": naive, "trials_per_s": naive_rate,
                           "method": "per trial, per hold interval solve_ivp RK45 rtol 1e-8",
                           "mean_final_error": naive_final,
                           "vectorised_mean_final_error_same_seeds": float(np.mean(vec.final_error_norm)),
                           "speedup_one_worker": one_rate / naive_rate},
        "map_trials": {"map": "ours/cluttered_room.yaml (unicycle, gramian, default noise, replanning)",
                       "trials": map_trials, "wall_s": map_wall, "trials_per_s": map_trials / map_wall,
                       "statuses": statuses},
        "targets": {"shared_trials_per_s_per_core_min": 1000, "two_worker_scaling_min": 1.7},
        "met": {"per core": bool(one_rate >= 1000), "scaling": bool(two_rate / one_rate >= 1.7)},
    }


BENCHMARKS = {"gains": bench_gains, "collision": bench_collision, "planning": bench_planning, "run": bench_run,
              "batch": bench_batch}


def summary_markdown(results: dict) -> str:
    lines = ["# nhstab benchmarks", "", "Produced by `nhstab bench`. Measured value against target.", "",
             "| benchmark | measure | value | target | met |", "|---|---|---|---|---|"]
    g = results.get("gains")
    if g:
        lines.append(f"| gains | time per point, max/min over N = "
                     f"{', '.join(str(r['grid_points']) for r in g['schedule'])} | {g['per_point_time_ratio']:.2f} | "
                     f"<= {g['targets']['per_point_time_ratio_max']} | {'yes' if g['met']['linear'] else 'NO'} |")
        lines.append(f"| gains | speed-up vs naive at N = {g['naive']['grid_points']} | {g['speedup_vs_naive']:.0f}x | "
                     f">= {g['targets']['speedup_vs_naive_min']:.0f}x | {'yes' if g['met']['speedup'] else 'NO'} |")
        for r in g["schedule"]:
            lines.append(f"| gains | N = {r['grid_points']}: best of {r['repeats']} | {r['best_s'] * 1e3:.1f} ms "
                         f"({r['us_per_point']:.1f} us/point) | - | - |")
    c = results.get("collision")
    if c:
        for r in c["maps"]:
            lines.append(f"| collision | {r['map']}: build ({r['objects']} objects) | {r['build_s'] * 1e3:.1f} ms | "
                         f"< {c['targets']['build_s_max'] * 1e3:.0f} ms | {'yes' if r['build_s'] < 1 else 'NO'} |")
            total = r["build_s"] + r["distance_field_build_s"]
            lines.append(f"| collision | {r['map']}: build with the batched path's distance field | "
                         f"{total * 1e3:.1f} ms | < {c['targets']['build_s_max'] * 1e3:.0f} ms | "
                         f"{'yes' if total < 1 else 'NO'} |")
            for kind in ("single", "batched"):
                v = r[f"{kind}_checks_per_s"]
                lines.append(f"| collision | {r['map']}: car pose checks/s, {kind} | {v:,.0f} | "
                             f">= {c['targets']['checks_per_s_min']:,} | {'yes' if v >= 50_000 else 'NO'} |")
    p = results.get("planning")
    if p:
        for r in p["rows"]:
            med = "-" if r["median_s"] is None else f"{r['median_s']:.2f} s"
            p95 = "-" if r["p95_s"] is None else f"{r['p95_s']:.2f} s"
            met = r["success_rate"] >= 0.95 and r["median_s"] is not None and r["median_s"] < 0.5
            lines.append(f"| planning | {r['map']}, {r['robot']}: success / median / p95 over {r['pairs']} pairs "
                         f"({r['budget_s']:g} s budget) | {100 * r['success_rate']:.0f} % / {med} / {p95} | "
                         f">= 95 % / < 0.5 s | {'yes' if met else 'NO'} |")
            lines.append(f"| planning | {r['map']}, {r['robot']}: OMPL validity check per state (Python) | "
                         f"{r['validity_us_per_state_median']:.1f} us | - | - |")
    rr = results.get("run")
    if rr:
        for r in rr["scenarios"]:
            if r["replan_latency_p95_s"] is None:
                lines.append(f"| run | {r['scenario']}: replan latency | no replans in {r['runs']} runs | < 1 s | NO |")
                continue
            met = r["replan_latency_p95_s"] < rr["targets"]["replan_latency_p95_s_max"]
            lines.append(f"| run | {r['scenario']}, {r['robot']}: replan latency median / p95 over "
                         f"{len(r['replan_latencies_s'])} replans in {r['runs']} runs | "
                         f"{r['replan_latency_median_s']:.2f} s / {r['replan_latency_p95_s']:.2f} s | p95 < 1 s | "
                         f"{'yes' if met else 'NO'} |")
            reached = sum(s == "reached" for s in r["statuses"])
            lines.append(f"| run | {r['scenario']}: runs reaching the goal | {reached} / {r['runs']} | - | - |")
        for sc in rr.get("sensor_scan", []):
            lines.append(f"| run | sensor scan ({sc['beams']} beams), {sc['map']}: median / p90 over {sc['poses']} poses | "
                         f"{sc['scan_ms_median']:.2f} / {sc['scan_ms_p90']:.2f} ms | - | - |")
        for st in rr["control_update"]:
            lines.append(f"| run | control update, {st['robot']}, {st['controller']} | {st['us_per_update']:.1f} us | "
                         f"< 1000 us | {'yes' if st['us_per_update'] < 1000 else 'NO'} |")
    b = results.get("batch")
    if b:
        sh, nv, mp_ = b["shared_nominal"], b["naive_baseline"], b["map_trials"]
        lines.append(f"| batch | Hilare trials/s sharing a nominal, one worker ({sh['trials_per_worker']} trials) | "
                     f"{sh['one_worker_trials_per_s']:.0f} | >= 1000 | {'yes' if b['met']['per core'] else 'NO'} |")
        lines.append(f"| batch | two workers: trials/s, scaling over one | {sh['two_workers_trials_per_s']:.0f}, "
                     f"{sh['scaling_two_over_one']:.2f}x | >= 1.7x | {'yes' if b['met']['scaling'] else 'NO'} |")
        lines.append(f"| batch | naive per-trial solve_ivp loop: trials/s (speed-up of one worker) | "
                     f"{nv['trials_per_s']:.2f} ({nv['speedup_one_worker']:.0f}x) | - | - |")
        lines.append(f"| batch | full map trials (plan, execute, monitor), {mp_['map']} | "
                     f"{mp_['trials_per_s']:.2f} trials/s | - | - |")
    return "\n".join(lines) + "\n"
