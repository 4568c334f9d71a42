"""``nhstab bench batch``: batch throughput, vectorised against per-trial baselines."""

from __future__ import annotations

import math
import os
import time

import numpy as np

from .common import machine, maps_dir
from scipy.integrate import solve_ivp

from .gains import hilare_sinusoid

def _hilare_law():
    from ..execution import ControllerOptions, build_law
    from ..paper import CASES

    case = CASES["hilare-sinusoid"]
    return build_law(hilare_sinusoid(315), ControllerOptions(kind="gramian", alpha=case.alpha, delta=case.delta,
                                                             gamma=case.gamma), {})


def _shared_worker(args) -> tuple[float, int]:
    """Simulate ``k`` Hilare trials with sensor noise in this process; returns (seconds, trials)."""
    k, first_seed = args
    from ..batch.vector import simulate_shared
    from ..execution.config import NoiseOptions

    law = _hilare_law()
    seeds = list(range(first_seed, first_seed + k))
    started = time.perf_counter()
    simulate_shared(law, seeds, NoiseOptions(), record=False)
    return time.perf_counter() - started, k


def _naive_trials(law, seeds, noise) -> float:
    """The baseline: one trial at a time, every hold interval integrated with solve_ivp (RK45,
    rtol 1e-8), the same seeded noise and ZOH law. Returns the mean final error norm (a check that
    it computed the same thing)."""
    from ..execution.runner import seed_for

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

    from ..batch.config import load_batch_config
    from ..batch.trial import run_trial
    from ..batch.vector import simulate_shared
    from ..execution.config import NoiseOptions

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

    maps = maps_dir()
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


def summary_lines(b: dict) -> list[str]:
    """Rows of the benchmark summary table (benchmark | measure | value | target | met)."""
    lines = []
    sh, nv, mp_ = b["shared_nominal"], b["naive_baseline"], b["map_trials"]
    lines.append(f"| batch | Hilare trials/s sharing a nominal, one worker ({sh['trials_per_worker']} trials) | "
                 f"{sh['one_worker_trials_per_s']:.0f} | >= 1000 | {'yes' if b['met']['per core'] else 'NO'} |")
    lines.append(f"| batch | two workers: trials/s, scaling over one | {sh['two_workers_trials_per_s']:.0f}, "
                 f"{sh['scaling_two_over_one']:.2f}x | >= 1.7x | {'yes' if b['met']['scaling'] else 'NO'} |")
    lines.append(f"| batch | naive per-trial solve_ivp loop: trials/s (speed-up of one worker) | "
                 f"{nv['trials_per_s']:.2f} ({nv['speedup_one_worker']:.0f}x) | - | - |")
    lines.append(f"| batch | full map trials (plan, execute, monitor), {mp_['map']} | "
                 f"{mp_['trials_per_s']:.2f} trials/s | - | - |")
    return lines
