"""The error-tube study (``nhstab tubes study``): predicted tubes against the run loop, and the gain grid
(``nhstab tubes gains``).

**Study.** For each case (robot, bundled map) the first plan of ``nhstab run example:MAP --margin auto
--seed 0`` is made once (the nominal, planned with headroom 0.8, margin chosen by the gramian law's
tube at x1 noise). On that fixed nominal, for each controller (the gramian law with the robot's
default alpha, delta, gamma; TVLQR with Q = I, R = I) and noise level (x0.5, x1, x2 of ``nhstab run``'s
default initial error, sensor noise and process disturbance), the tube is predicted
(:func:`nhstab.tubes.predict_tube`) and ``trials`` trials of the run loop are simulated on that nominal
(:func:`nhstab.batch.vector.simulate_shared`: bit-identical to ``nhstab run``'s tracking loop with
seeds spawned from ``root_seed``; no sensing or replanning). Per cell:

* **coverage**: the fraction of all trial samples inside the p-tube (the pose region the spatial tube is
  built from; and the full-state p-ellipsoid), Wilson 95% over samples (correlated within a trial, so
  too narrow; the per-trial spread is given too);
* **std ratio** per state: sqrt(mean over samples of the observed variance across trials) over the same
  for the predicted variance: the RMS-over-time ratio of observed to predicted standard deviation (the
  sampling error of a std from 200 trials is 5 % per sample; the time average brings it well below);
* **mean error**: the largest gap between the observed and predicted mean, in predicted stds
  (nonlinearity shows first as a bias);
* **saturation**: the fraction of trials in which an input reached a limit (Wilson 95%) against the
  predicted upper bound;
* **collisions**: trials whose footprint overlapped a known obstacle at some sample (FCL);
* the 1-s window with the lowest coverage, and whether a cusp or the end of the nominal lies in it.

A cell **passes** when both coverages are within 1 percentage point of p and every state's std ratio is
within 10 % of 1; the failing cells are listed with their diagnostics.

**Gains.** On the same fixed nominals, the gain grid of ``--gains auto`` (alpha and delta as 0.5, 1, 2
times the robot's default, gamma 0.5, 1, 2): each setting's predicted mean reach and saturation bound;
the setting ``--gains auto`` picks; and a Monte Carlo check at x1 noise of the default and the pick
(observed RMS position error, 99.7th percentile of the footprint displacement bound, saturated trials).
Per robot, the recommended setting is the one with the smallest mean reach summed over the robot's maps
among those with a saturation bound under 1 % on every map.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import InputError
from ..execution.config import NoiseOptions, PlanningOptions, RunOptions
from ..execution.controllers import ControllerOptions, build_law
from ..execution.outputs import nominal_cusps
from ..execution.runner import CompositeRun
from ..limits import MAX_STUDY_TRIALS, check_int
from ..maps import load_map
from ..models import make_model
from ..planning import pose_columns
from ..records import read_json, record_file, save_figure, write_json_gz, write_text
from ..report import subplots
from ..report.plans import plan_figure
from ..robot import default_robot
from ..tubes.base import pose_indices
from ..tubes.fit import choose_gains
from ..tubes.predict import predict_tube
from .report import wilson
from .vector import simulate_shared

CASES = (("unicycle", "depot_blocked_aisle"), ("unicycle", "cluttered_room"),
         ("rwd_car", "warehouse_aisle_a2"), ("rwd_car", "parking_lot"))
CONTROLLERS = ("gramian", "tvlqr")
NOISE_LEVELS = (0.5, 1.0, 2.0)
TRIALS = 200
ROOT_SEED = 2026
PLAN_SEED = 0
PROBABILITY = 0.997
#: a cell passes when both coverages are within this of p and every std ratio within STD_TOLERANCE of 1
COVERAGE_TOLERANCE = 0.01
STD_TOLERANCE = 0.10
#: bootstrap resamples (over trials) for the std ratio's 95% interval
BOOTSTRAP = 100


def trial_seeds(trials: int, root_seed: int) -> list[int]:
    """As a batch: trial k's seed is child k of root_seed (32 bits)."""
    return [int(c.generate_state(1)[0]) for c in np.random.SeedSequence(root_seed).spawn(trials)]


def first_plan(robot: str, map_name: str, margin="auto", seed: int = PLAN_SEED):
    """The first plan of ``nhstab run example:MAP --robot ROBOT --margin MARGIN --seed SEED`` (its
    attempt record, result, gramian law, margin, tube) and the run object (map, robot, worlds)."""
    m = load_map(f"example:{map_name}")
    run = CompositeRun(m, default_robot(robot), m.start.as_array(), m.goal.as_array(),
                       RunOptions(seed=seed, planning=PlanningOptions(margin=margin)))
    attempt, result, law, used, tube = run._plan_once(run.start[:3])
    if law is None:
        raise InputError(f"{map_name}", "a map where nhstab run finds a first plan", attempt.get("message"))
    return run, attempt, result, law, used, tube


def _law(run, result, controller: str, **gains):
    return build_law(result.nominal, ControllerOptions(kind=controller, **gains), run.stab_defaults,
                     result.schedule if controller == "gramian" and not gains else None)


def cell_metrics(tube, sim, model, world, fp, cusps: list[float]) -> dict:
    """Compare one predicted tube with simulated trials on its nominal (see the module docstring)."""
    ok = sim.completed
    e = sim.e[ok]
    K, S, n = e.shape
    inside_state, inside_tube = tube.inside(e)
    out = {"trials": int(len(ok)), "completed": int(ok.sum()), "samples": int(K * S)}
    for key, arr in (("tube", inside_tube), ("state", inside_state)):
        rate, lo, hi = wilson(int(arr.sum()), arr.size)
        per = arr.mean(axis=1)
        out[f"coverage_{key}"] = {"rate": rate, "wilson_lo": lo, "wilson_hi": hi, "trial_sd": float(per.std(ddof=1)),
                                  "trial_min": float(per.min()), "trials_below_p": int(np.sum(per < tube.probability))}
    obs_sd = np.std(e, axis=0, ddof=1)
    obs_mean = e.mean(axis=0)
    pred_sd = tube.std
    ratio = np.sqrt(np.mean(obs_sd ** 2, axis=0) / np.maximum(np.mean(pred_sd ** 2, axis=0), 1e-300))
    per_sample = obs_sd / np.maximum(pred_sd, 1e-300)
    out["std_ratio"] = dict(zip(model.state_names, ratio.tolist()))
    # its sampling error: a bootstrap over trials (fixed generator), 95% percentile interval
    rng = np.random.default_rng(0)
    pred_ms = np.maximum(np.mean(pred_sd ** 2, axis=0), 1e-300)
    boot = np.array([np.sqrt(np.mean(np.var(e[rng.integers(0, K, K)], axis=0, ddof=1), axis=0) / pred_ms)
                     for _ in range(BOOTSTRAP)])
    lo, hi = np.percentile(boot, [2.5, 97.5], axis=0)
    out["std_ratio_bootstrap95"] = {name: [float(a), float(b)] for name, a, b in zip(model.state_names, lo, hi)}
    out["std_ratio_samples_off_10pct"] = dict(zip(model.state_names, np.mean(np.abs(per_sample - 1) > 0.1, axis=0).tolist()))
    bias = np.abs(obs_mean - tube.mean) / np.maximum(pred_sd, 1e-300)
    out["max_mean_gap_in_std"] = dict(zip(model.state_names, bias.max(axis=0).tolist()))
    # saturation: an applied input at a limit (the end sample applies none)
    u = sim.u[ok][:, :-1]
    lim = model.input_limits()[:, 1]
    at = np.any(np.isclose(np.abs(u), lim, rtol=0, atol=1e-12), axis=2)
    rate, lo, hi = wilson(int(at.any(axis=1).sum()), K)
    out["saturation"] = {"observed_trials": rate, "wilson_lo": lo, "wilson_hi": hi,
                         "observed_sample_fraction": float(at.mean()),
                         "predicted_run_bound": tube.saturation["run_bound"],
                         "predicted_fraction_bound": tube.saturation["expected_fraction_bound"]}
    # collisions with the known obstacles, at the samples
    poses = sim.x[ok][:, :, pose_indices(model)].reshape(-1, 3)
    free = world.free_many(poses, fp, 0.0).reshape(K, S)
    out["collisions"] = {"trials": int(np.sum(~free.all(axis=1))), "samples": int(np.sum(~free))}
    # where coverage is worst: 1-s windows
    per_t = inside_tube.mean(axis=0)
    T = float(tube.t[1] - tube.t[0])
    w = max(1, int(round(1.0 / T)))
    win = np.convolve(per_t, np.ones(w) / w, mode="valid")
    j = int(np.argmin(win))
    t0, t1 = float(tube.t[j]), float(tube.t[min(j + w - 1, S - 1)])
    out["worst_window"] = {"from_s": t0, "to_s": t1, "coverage": float(win[j]),
                           "cusp_inside": bool(any(t0 - 0.5 <= c <= t1 + 0.5 for c in cusps)),
                           "at_end": bool(t1 >= tube.t[-1] - 1.0), "at_start": bool(t0 <= 1.0)}
    out["tube"] = {k: v for k, v in tube.summary().items() if k != "construction"}
    passed_cov = all(abs(out[f"coverage_{k}"]["rate"] - tube.probability) <= COVERAGE_TOLERANCE for k in ("tube", "state"))
    passed_std = all(abs(r - 1.0) <= STD_TOLERANCE for r in ratio)
    out["passed"] = {"coverage": passed_cov, "std": passed_std, "all": passed_cov and passed_std}
    out["_curves"] = {"t": tube.t, "obs_sd": obs_sd, "pred_sd": pred_sd, "coverage_t": per_t,
                      "obs_mean": obs_mean, "pred_mean": tube.mean}
    return out


def diagnose(cell: dict) -> str:
    """A one-line reading of a failing cell's numbers."""
    parts = []
    ct, cs = cell["coverage_tube"]["rate"], cell["coverage_state"]["rate"]
    parts.append(f"coverage {100 * ct:.2f}% (tube) / {100 * cs:.2f}% (state)")
    off = {k: v for k, v in cell["std_ratio"].items() if abs(v - 1) > STD_TOLERANCE}
    if off:
        parts.append("std ratio " + ", ".join(f"{k} {v:.2f}" for k, v in off.items()))
    sat = cell["saturation"]
    if sat["observed_trials"] > 0.01:
        parts.append(f"inputs saturate in {100 * sat['observed_trials']:.0f}% of trials "
                     f"({100 * sat['observed_sample_fraction']:.2f}% of samples; bound {sat['predicted_run_bound']:.2g})")
    gap = max(cell["max_mean_gap_in_std"].values())
    if gap > 0.3:
        worst = max(cell["max_mean_gap_in_std"], key=cell["max_mean_gap_in_std"].get)
        parts.append(f"mean error off by up to {gap:.1f} std ({worst}): nonlinear")
    w = cell["worst_window"]
    where = "a cusp" if w["cusp_inside"] else ("the end" if w["at_end"] else ("the start" if w["at_start"] else "mid-run"))
    parts.append(f"worst 1-s window {w['from_s']:.1f}-{w['to_s']:.1f} s ({where}): {100 * w['coverage']:.1f}%")
    return "; ".join(parts)


def run_study(trials: int = TRIALS, root_seed: int = ROOT_SEED, cases=CASES, controllers=CONTROLLERS,
              noise_levels=NOISE_LEVELS, probability: float = PROBABILITY, progress=None) -> tuple[dict, dict]:
    """The study; returns (JSON-ready result, curves for the figures)."""
    trials = check_int("trials", trials, 2, MAX_STUDY_TRIALS, "a number of trials per cell")

    seeds = trial_seeds(trials, root_seed)
    out = {"probability": probability, "trials": trials, "root_seed": root_seed, "plan_seed": PLAN_SEED,
           "coverage_tolerance": COVERAGE_TOLERANCE, "std_tolerance": STD_TOLERANCE, "cases": []}
    curves, plans = {}, {}
    for robot, map_name in cases:
        started = time.perf_counter()
        run, attempt, result, law0, margin, tube0 = first_plan(robot, map_name)
        plan_s = time.perf_counter() - started
        cusps = nominal_cusps(law0.nominal)
        case = {"robot": robot, "map": map_name, "margin_m": margin, "margin_auto": attempt.get("margin_auto"),
                "plan": {"duration_s": float(law0.t_end - law0.t0), "length_m": result.metrics["length_m"],
                         "cusps": result.metrics["cusps"], "cusp_times_s": cusps,
                         "min_clearance_m": result.metrics["min_clearance_m"]},
                "plan_and_tube_wall_s": plan_s, "cells": []}
        plans[(robot, map_name)] = (run, result, tube0)
        for ctrl in controllers:
            law = law0 if ctrl == "gramian" else _law(run, result, ctrl)
            for level in noise_levels:
                noise = NoiseOptions(scale=level)
                tube = predict_tube(law, noise, run.fp, run.known, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps,
                                    model=run.model, probability=probability, kind="linear")
                sim = simulate_shared(law, seeds, noise, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps,
                                      model=run.model)
                cell = cell_metrics(tube, sim, run.model, run.known, run.fp, cusps)
                curves[(robot, map_name, ctrl, level)] = cell.pop("_curves")
                cell.update(controller=ctrl, noise=level)
                if not cell["passed"]["all"]:
                    cell["diagnosis"] = diagnose(cell)
                case["cells"].append(cell)
                if progress:
                    progress(f"{robot} {map_name} {ctrl} x{level:g}: coverage {100 * cell['coverage_tube']['rate']:.2f}% "
                             f"/ {100 * cell['coverage_state']['rate']:.2f}%, std ratio "
                             + ", ".join(f"{v:.3f}" for v in cell["std_ratio"].values())
                             + f", collisions {cell['collisions']['trials']}")
        out["cases"].append(case)
    return out, {"curves": curves, "plans": plans}


# ---- figures -------------------------------------------------------------------------------------------

def std_figure(curves: dict, robot: str, map_name: str, trials: int, controllers=CONTROLLERS,
               noise_levels=NOISE_LEVELS):
    """Rows: noise levels; columns: states. Observed std over trials (solid) against predicted (dashed)."""
    key0 = next(k for k in curves if k[0] == robot and k[1] == map_name)
    n = curves[key0]["pred_sd"].shape[1]

    names = make_model(robot).state_names
    fig, axes = subplots(len(noise_levels), n, figsize=(3.0 * n, 2.1 * len(noise_levels) + 0.6), squeeze=False,
                         sharex=True, layout="constrained")
    colors = {"gramian": "tab:blue", "tvlqr": "tab:green", "open-loop": "tab:red"}
    for i, level in enumerate(noise_levels):
        for ctrl in controllers:
            c = curves.get((robot, map_name, ctrl, level))
            if c is None:
                continue
            for j in range(n):
                ax = axes[i, j]
                ax.plot(c["t"], c["obs_sd"][:, j], color=colors.get(ctrl, "k"), lw=0.9, label=f"{ctrl}: observed")
                ax.plot(c["t"], c["pred_sd"][:, j], color=colors.get(ctrl, "k"), lw=1.0, ls="--",
                        label=f"{ctrl}: predicted")
        for j in range(n):
            axes[i, j].set_title(f"std of e_{names[j]}, noise x{level:g}", fontsize=8)
            axes[i, j].grid(alpha=0.3)
    axes[0, 0].legend(fontsize=6)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.suptitle(f"{map_name}, {robot}: std of the tracking error, predicted by the tube (dashed) and over "
                 f"{trials} trials of the run loop (solid)", fontsize=9)
    return fig


def coverage_figure(curves: dict, robot: str, map_name: str, probability: float, cusps: list[float],
                    controllers=CONTROLLERS, noise_levels=NOISE_LEVELS):
    fig, axes = subplots(len(controllers), 1, figsize=(8, 2.2 * len(controllers) + 0.5), squeeze=False, sharex=True,
                         layout="constrained")
    for i, ctrl in enumerate(controllers):
        ax = axes[i, 0]
        for level in noise_levels:
            c = curves.get((robot, map_name, ctrl, level))
            if c is not None:
                ax.plot(c["t"], 100 * c["coverage_t"], lw=0.9, label=f"noise x{level:g}")
        ax.axhline(100 * probability, color="k", lw=0.8, ls="--", label=f"p = {probability:g}")
        ax.axhline(100 * (probability - COVERAGE_TOLERANCE), color="0.5", lw=0.6, ls=":")
        for cu in cusps:
            ax.axvline(cu, color="tab:purple", lw=0.8, alpha=0.6)
        ax.set_ylabel(f"{ctrl}: % in tube", fontsize=8)
        ax.set_ylim(max(0.0, ax.get_ylim()[0]), 100.5)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="lower left")
    axes[-1, 0].set_xlabel("t [s] (purple: cusps)")
    fig.suptitle(f"{map_name}, {robot}: fraction of trials inside the tube at each sample", fontsize=9)
    return fig


def study_markdown(result: dict, gains: dict | None = None) -> str:
    p = result["probability"]
    lines = ["# Error tubes: predicted against the run loop", "",
             f"Produced by `nhstab tubes study --out results/tubes` (nhstab.batch.tube_study). Per case, the first plan "
             f"of `nhstab run example:MAP --margin auto --seed {result['plan_seed']}`, fixed; on it, per controller and "
             f"noise level, the predicted {p:g}-tube against {result['trials']} trials of the run loop "
             f"(simulate_shared, seeds spawned from {result['root_seed']}). Coverage: samples inside the tube's pose "
             "region (position ellipse and heading band the spatial tube is built from) and inside the full-state "
             f"ellipsoid; Wilson 95% over samples (correlated within a trial: too narrow). Std ratio: RMS over time "
             "of the observed std over the predicted one, per state, with a 95% bootstrap interval over trials. Pass: both coverages within "
             f"{100 * result['coverage_tolerance']:.0f} percentage point of p and every std ratio within "
             f"{100 * result['std_tolerance']:.0f} %.", ""]
    for case in result["cases"]:
        pl = case["plan"]
        auto = case.get("margin_auto") or {}
        lines += [f"## {case['map']}, {case['robot']}", "",
                  f"Plan: {pl['length_m']:.1f} m, {pl['duration_s']:.1f} s, {pl['cusps']} cusp(s) "
                  f"(at {', '.join(f'{c:.1f}' for c in pl['cusp_times_s']) or '-'} s), nominal min clearance "
                  f"{pl['min_clearance_m']:.3f} m. {auto.get('message', '')}", "",
                  "| controller | noise | coverage tube [Wilson] | coverage state | std ratio per state | max mean gap [std] "
                  "| saturated trials (bound) | collisions | certified clearance [m] | pass |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for c in case["cells"]:
            ct, cs, sat = c["coverage_tube"], c["coverage_state"], c["saturation"]
            lines.append(
                f"| {c['controller']} | x{c['noise']:g} | {100 * ct['rate']:.2f}% [{100 * ct['wilson_lo']:.2f}, "
                f"{100 * ct['wilson_hi']:.2f}] | {100 * cs['rate']:.2f}% | "
                + ", ".join(f"{k} {v:.3f} [{c['std_ratio_bootstrap95'][k][0]:.2f}, {c['std_ratio_bootstrap95'][k][1]:.2f}]"
                            for k, v in c["std_ratio"].items())
                + f" | {max(c['max_mean_gap_in_std'].values()):.2f} | {100 * sat['observed_trials']:.1f}% "
                  f"({sat['predicted_run_bound']:.2g}) | {c['collisions']['trials']} | "
                  f"{c['tube']['certified_clearance_m']:+.3f} | {'yes' if c['passed']['all'] else '**no**'} |")
        lines += ["", f"![std](std_{case['robot']}_{case['map']}.png)", "",
                  f"![coverage](coverage_{case['robot']}_{case['map']}.png)", ""]
    failing = [(case, c) for case in result["cases"] for c in case["cells"] if not c["passed"]["all"]]
    lines += ["## Cells that fail", ""]
    if not failing:
        lines.append("None.")
    for case, c in failing:
        lines.append(f"- {case['map']}, {case['robot']}, {c['controller']}, x{c['noise']:g}: {c['diagnosis']}")
    lines.append("")
    if gains:
        lines += gains_markdown(gains)
    return "\n".join(lines) + "\n"


# ---- gains ----------------------------------------------------------------------------------------------

def run_gains(trials: int = TRIALS, root_seed: int = ROOT_SEED, cases=CASES, noise_level: float = 1.0,
              plans: dict | None = None, progress=None) -> dict:
    """The ``--gains auto`` grid on the study's fixed nominals, with a Monte Carlo check of the default
    and the pick (see the module docstring)."""
    seeds = trial_seeds(trials, root_seed)
    noise = NoiseOptions(scale=noise_level)
    out = {"noise": noise_level, "trials": trials, "cases": [], "recommended": {}}
    for robot, map_name in cases:
        if plans and (robot, map_name) in plans:
            run, result, _ = plans[(robot, map_name)]
        else:
            run, _, result, _, _, _ = first_plan(robot, map_name)

        def tube_of(law, certify=False):
            return predict_tube(law, noise, run.fp, run.known if certify else None, rate_hz=run.opts.rate_hz,
                                substeps=run.opts.substeps, model=run.model, kind="linear")

        started = time.perf_counter()
        law, record = choose_gains(result.nominal, run.stab_defaults, tube_of)
        pick_s = time.perf_counter() - started
        entry = {"robot": robot, "map": map_name, "defaults": dict(run.stab_defaults), "choice": record["chosen"],
                 "met": record["met"], "grid": record["grid"], "choose_wall_s": pick_s, "monte_carlo": {}}
        defaults = {k: run.stab_defaults[k] for k in ("alpha", "delta", "gamma")}     # the controller's knobs
        for label, gains in (("default", defaults), ("auto", record["chosen"])):
            lw = _law(run, result, "gramian", **gains)
            tube = tube_of(lw, certify=True)
            sim = simulate_shared(lw, seeds, noise, rate_hz=run.opts.rate_hz, substeps=run.opts.substeps,
                                  model=run.model)
            ok = sim.completed
            e = sim.e[ok]
            ix, iy, ith = pose_indices(run.model)
            rho = run.fp.bounding_radius
            moved = np.hypot(e[:, :, ix], e[:, :, iy]) + 2 * rho * np.abs(np.sin(e[:, :, ith] / 2))
            u = sim.u[ok][:, :-1]
            at = np.any(np.isclose(np.abs(u), run.model.input_limits()[:, 1], rtol=0, atol=1e-12), axis=2)
            entry["monte_carlo"][label] = {
                "gains": gains, "predicted_mean_reach_m": float(tube.reach.mean()),
                "predicted_saturation_bound": tube.saturation["run_bound"],
                "certified_clearance_m": tube.certified_clearance,
                "observed_rms_position_error_m": float(np.sqrt(np.mean(e[:, :, ix] ** 2 + e[:, :, iy] ** 2))),
                "observed_p997_displacement_m": float(np.percentile(moved, 99.7)),
                "observed_mean_p997_displacement_m": float(np.mean(np.percentile(moved, 99.7, axis=0))),
                "observed_saturated_trials": float(at.any(axis=1).mean()), "completed": int(ok.sum())}
        out["cases"].append(entry)
        if progress:
            mc = entry["monte_carlo"]
            progress(f"{robot} {map_name}: auto {record['chosen']} mean reach {mc['auto']['predicted_mean_reach_m']:.3f} "
                     f"vs default {mc['default']['predicted_mean_reach_m']:.3f} m")
    for robot in sorted({c["robot"] for c in out["cases"]}):
        mine = [c for c in out["cases"] if c["robot"] == robot]
        keys = {}
        for c in mine:
            for r in c["grid"]:
                if "mean_reach_m" not in r:
                    keys.setdefault((r["alpha"], r["delta"], r["gamma"]), []).append(None)
                    continue
                keys.setdefault((r["alpha"], r["delta"], r["gamma"]), []).append(r)
        ok = {k: v for k, v in keys.items() if len(v) == len(mine) and all(r is not None and
                                                                          r["saturation_probability"] < 0.01 for r in v)}
        d = mine[0]["defaults"]
        dkey = (float(d["alpha"]), float(d["delta"]), float(d["gamma"]))
        rec = {"candidates": len(ok)}
        if ok:
            best = min(ok, key=lambda k: sum(r["mean_reach_m"] for r in ok[k]))
            rec.update(alpha=best[0], delta=best[1], gamma=best[2],
                       mean_reach_by_map={c["map"]: r["mean_reach_m"] for c, r in zip(mine, ok[best])})
        dflt = keys.get(dkey)
        if dflt and all(r is not None for r in dflt):
            rec["default_mean_reach_by_map"] = {c["map"]: r["mean_reach_m"] for c, r in zip(mine, dflt)}
            rec["default_saturation_by_map"] = {c["map"]: r["saturation_probability"] for c, r in zip(mine, dflt)}
        out["recommended"][robot] = rec
    return out


def gains_markdown(g: dict) -> list[str]:
    lines = ["## Gains: the `--gains auto` grid on the same nominals", "",
             f"Noise x{g['noise']:g}. Grid: alpha and delta at 0.5, 1, 2 times the robot's default, gamma 0.5, 1, 2. "
             "Objective: the tube's mean reach over the plan; constraint: saturation bound < 1 %. Monte Carlo "
             f"({g['trials']} trials of the run loop) of the default and the pick: RMS position error, the 99.7th "
             "percentile of the footprint displacement bound |d_xy| + 2 rho |sin(d_th/2)| over all samples, and the "
             "fraction of trials with an input at a limit.", "",
             "| map, robot | setting | alpha | delta | gamma | predicted mean reach [m] | saturation bound | certified "
             "clearance [m] | observed RMS position error [m] | observed 99.7% displacement [m] | saturated trials |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in g["cases"]:
        for label in ("default", "auto"):
            mc = c["monte_carlo"][label]
            gs = mc["gains"]
            lines.append(f"| {c['map']}, {c['robot']} | {label} | {gs['alpha']:g} | {gs['delta']:g} | {gs['gamma']:g} | "
                         f"{mc['predicted_mean_reach_m']:.3f} | {mc['predicted_saturation_bound']:.3g} | "
                         f"{mc['certified_clearance_m']:+.3f} | {mc['observed_rms_position_error_m']:.4f} | "
                         f"{mc['observed_p997_displacement_m']:.3f} | {100 * mc['observed_saturated_trials']:.1f}% |")
    lines += ["", "Recommended per robot (smallest mean reach summed over its maps, saturation bound < 1 % on each):", ""]
    for robot, rec in g["recommended"].items():
        if "alpha" not in rec:
            lines.append(f"- {robot}: no setting has a saturation bound under 1 % on every map")
            continue
        lines.append(f"- {robot}: alpha {rec['alpha']:g}, delta {rec['delta']:g}, gamma {rec['gamma']:g}: mean reach "
                     + ", ".join(f"{k} {v:.3f} m" for k, v in rec["mean_reach_by_map"].items())
                     + (" (defaults: " + ", ".join(f"{k} {v:.3f} m, saturation bound "
                                                   f"{rec['default_saturation_by_map'][k]:.2g}"
                                                   for k, v in rec["default_mean_reach_by_map"].items()) + ")"
                        if "default_mean_reach_by_map" in rec else ""))
    lines.append("")
    return lines


def case_plan_figure(case: dict, run, res, tube):
    """The plan figure of a study case (``plan_ROBOT_MAP.png``): its first plan with the gramian law's
    tube at x1 noise."""
    nom = res.nominal
    title = (f"{case['map']}: {case['robot']}, margin auto {case['margin_m']:.3f} m; {tube.probability:g}-tube "
             f"(gramian, x1): certified clearance {tube.certified_clearance:+.3f} m")
    return plan_figure(run.m, nom.x[:, pose_columns(run.model)], np.sign(nom.u[:, 0]), run.fp, run.start, run.goal,
                       title=title, tube=tube)


#: how closely a first plan made again must match the one the study records (relative, on its length,
#: duration, clearance and tube clearance) for :func:`redraw_study` to draw it
REDRAW_RTOL = 1e-9


def redraw_study(out_dir, progress=None) -> tuple[list, list]:
    """Redraw what a study's folder allows without its trials: study.md from study.json.gz (or an
    uncompressed study.json), and per case the plan figure from the case's first plan made again with
    its tube (:func:`first_plan`, deterministic), drawn only when they are the ones the record holds:
    the same cusps, and length, duration, nominal clearance and the tube's certified clearance equal to
    :data:`REDRAW_RTOL` (the margin auto's rounds may differ on the way). The std and coverage figures
    need the trials' series, which the record does not keep (``nhstab tubes study`` draws them).
    Returns (files written, one line per figure left and why)."""
    from pathlib import Path

    out_dir = Path(out_dir)
    src = record_file(out_dir, "study.json")                 # study.json.gz, or an uncompressed study.json
    try:
        result = read_json(src)
        cases = result["cases"]
        seed = int(result["plan_seed"])
        study_markdown(result, result.get("gains"))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError("DIR", "a folder with the study.json.gz nhstab tubes study writes", str(out_dir),
                         detail=f"{type(exc).__name__}: {exc}") from None
    written, left = [], []
    for case in cases:
        robot, map_name = case["robot"], case["map"]
        name = f"plan_{robot}_{map_name}.png"
        run, attempt, res, law, margin, tube = first_plan(robot, map_name, seed=seed)
        rec, met = case["plan"], res.metrics
        now = {"cusps": met["cusps"], "length_m": met["length_m"], "duration_s": float(law.t_end - law.t0),
               "min_clearance_m": met["min_clearance_m"], "certified_clearance_m": tube.certified_clearance}
        then = {**{k: rec[k] for k in ("cusps", "length_m", "duration_s", "min_clearance_m")},
                "certified_clearance_m": (case.get("margin_auto") or {}).get("certified_clearance_m")}
        off = [k for k in now if then[k] is None or not np.isclose(now[k], then[k], rtol=REDRAW_RTOL, atol=0.0)]
        if off:
            left.append(f"{name} left: planned again, " + ", ".join(f"{k} {now[k]:.6g} ({src.name}: {then[k]:.6g})"
                                                                    for k in off))
            continue
        if progress:
            progress(f"{robot} {map_name}: the plan and tube {src.name} records ({rec['length_m']:.1f} m, "
                     f"{rec['cusps']} cusp(s), certified clearance {tube.certified_clearance:+.3f} m)")
        written.append(save_figure(case_plan_figure(case, run, res, tube), out_dir / name, dpi=80))
    written.append(write_text(out_dir / "study.md", study_markdown(result, result.get("gains"))))
    return written, left


def write_study(out_dir, trials: int = TRIALS, root_seed: int = ROOT_SEED, gains: bool = True, progress=None,
                cases=CASES) -> list:
    """Run the study (and the gains part) and write study.json.gz (the record, gzip-compressed), study.md
    and the figures."""
    from pathlib import Path


    out_dir = Path(out_dir)
    started = time.perf_counter()
    result, extra = run_study(trials, root_seed, cases=cases, progress=progress)
    g = run_gains(trials, root_seed, cases=cases, plans=extra["plans"], progress=progress) if gains else None
    result["wall_s"] = time.perf_counter() - started
    written = []
    for case in result["cases"]:
        robot, map_name = case["robot"], case["map"]
        written.append(save_figure(std_figure(extra["curves"], robot, map_name, trials),
                                   out_dir / f"std_{robot}_{map_name}.png", dpi=80))
        written.append(save_figure(coverage_figure(extra["curves"], robot, map_name, result["probability"],
                                                   case["plan"]["cusp_times_s"]),
                                   out_dir / f"coverage_{robot}_{map_name}.png", dpi=80))
        run, res, tube = extra["plans"][(robot, map_name)]
        written.append(save_figure(case_plan_figure(case, run, res, tube), out_dir / f"plan_{robot}_{map_name}.png",
                                   dpi=80))
    if g is not None:
        result["gains"] = g
    written.append(write_json_gz(out_dir / "study.json.gz", result, indent=2))
    written.append(write_text(out_dir / "study.md", study_markdown(result, g)))
    return written
