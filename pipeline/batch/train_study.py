"""A car with several trailers under the feedback laws (``nhstab trailer train``): what nhstab can say of a
rig it does not plan for.

nhstab's planner plans a car with ONE trailer (:mod:`nhstab.planning.trailer`: its searches and its exact
end, the chained form, are written for one). The model, the feedback laws and the run loop take any
number. This study measures whether the laws stabilize a rig of several trailers along a nominal it can
drive, forward and in reverse, and compares it with the same drive by a one-trailer rig:

* **The nominal.** From a straight rest, the car drives an S-curve: speed ``SPEED`` m/s (ramped up and
  down over ``RAMP_S`` seconds at both ends), steering rate ``STEER_RATE_AMPLITUDE`` sin(2 pi t /
  ``PERIOD_S``; another amplitude on request), for ``DURATION_S`` seconds, integrated from the model
  (exact). **Reversed** is the same
  motion run backwards in time (these models are driftless: the same path, the inputs negated), so the
  rig backs its trailers along it. The nominal is refused, with its numbers, when its steering angle or
  a hitch angle leaves ``FEASIBLE_FRACTION`` of the limits (other hitch lengths can make it so).
* **Laws.** The gramian law with the rig's stabilizer defaults, TVLQR with Q = I and TVLQR with Q from the
  rig's outline (``q: footprint``). For the gramian law, the smallest eigenvalue of its window gramian over
  the nominal, and its largest gain norm: how far from singular the law is.
* **Trials.** ``trials`` runs of the run loop per (direction, law) at the noise asked
  (:func:`nhstab.batch.vector.simulate_shared`, bit-identical to ``nhstab run``'s tracking loop), seeds
  of :func:`nhstab.batch.tube_study.trial_seeds`. A trial **jackknifes** when any hitch angle passes the
  limit at some sample; per direction and law: jackknifes, the last trailer's axle error at the end
  (median and 99th percentile over the trials that did not jackknife) and the median of the largest
  hitch angle. No obstacles: this is the law, not the map.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import InputError, PipelineError
from ..execution.config import PROCESS_PER, NoiseOptions
from ..execution.controllers import Q_FOOTPRINT, ControllerOptions, build_law
from ..limits import MAX_NOISE_SCALE, MAX_SEED, MAX_STUDY_TRIALS, check_int
from ..models.car_trailer import MAX_TRAILERS
from ..nominal import Nominal
from ..robot import robot_from_spec
from .trailer_study import _f
from .tube_study import trial_seeds
from .vector import simulate_shared

#: the nominal: duration [s], speed [m/s], ramp [s], steering-rate amplitude [rad/s] and period [s]
DURATION_S, SPEED, RAMP_S, STEER_RATE_AMPLITUDE, PERIOD_S = 40.0, 0.8, 3.0, 0.07, 20.0
#: the nominal's grid step [s]
GRID_S = 0.01
#: the nominal's steering and hitch angles must stay within this fraction of their limits
FEASIBLE_FRACTION = 0.8
#: the laws compared: (label, controller options)
LAWS = (("gramian", ControllerOptions(kind="gramian")), ("tvlqr", ControllerOptions(kind="tvlqr")),
        (f"tvlqr q={Q_FOOTPRINT}", ControllerOptions(kind="tvlqr", q=Q_FOOTPRINT)))


def s_curve(model, steer_rate: float = STEER_RATE_AMPLITUDE) -> tuple[Nominal, Nominal]:
    """(forward, reversed): the module's S-curve of ``model`` from a straight rest (its steering rate's
    amplitude ``steer_rate`` [rad/s]), and the same motion backwards in time."""
    t = np.arange(0.0, DURATION_S + GRID_S / 2, GRID_S)

    def inputs(tt):
        tt = np.asarray(tt, dtype=float)
        ramp = np.clip(np.minimum(tt, DURATION_S - tt) / RAMP_S, 0.0, 1.0)
        return np.stack([SPEED * ramp, steer_rate * np.sin(2 * np.pi * tt / PERIOD_S)], -1)

    forward = Nominal.from_inputs(model, inputs, np.zeros(model.n), t)
    backward = Nominal.from_samples(model, t, forward.x[::-1].copy(), -forward.u[::-1].copy())
    return forward, backward


def check_train(hitch_lengths) -> tuple:
    """The hitch lengths [m] of the rig (1 to MAX_TRAILERS positive finite numbers), else an InputError."""
    vals = list(hitch_lengths) if isinstance(hitch_lengths, (list, tuple)) else None
    ok = vals is not None and 1 <= len(vals) <= MAX_TRAILERS and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0.3 <= v <= 30.0 for v in vals)
    if not ok:
        raise InputError("--hitch-lengths", f"1 to {MAX_TRAILERS} hitch lengths in [0.3, 30] m, comma-separated",
                         hitch_lengths)
    return tuple(float(v) for v in vals)


def train_study(hitch_lengths=(1.5, 3.0), trials: int = 200, noise: float = 1.0, process_per: str = "second",
                root_seed: int = 2026, reference: bool = True, steer_rate: float = STEER_RATE_AMPLITUDE) -> dict:
    """The study of the module docstring for a car_trailer with these hitch lengths (the built-in rig's
    other parameters and outlines); with ``reference`` the same for the one-trailer rig (the last hitch
    length alone); ``steer_rate``: the S-curve's steering-rate amplitude [rad/s] (smaller: a gentler
    curve). Returns a JSON-ready dict."""
    hitch_lengths = check_train(hitch_lengths)
    trials = check_int("--trials", trials, 1, MAX_STUDY_TRIALS, "a number of trials per cell")
    root_seed = check_int("--root-seed", root_seed, 0, MAX_SEED - 1, "a seed")
    if not (isinstance(noise, (int, float)) and math.isfinite(noise) and 0 < noise <= MAX_NOISE_SCALE):
        raise InputError("--noise", f"a noise scale in (0, {MAX_NOISE_SCALE:g}]", noise)
    if process_per not in PROCESS_PER:
        raise InputError("--process-per", "one of " + ", ".join(PROCESS_PER), process_per)
    if not (isinstance(steer_rate, (int, float)) and math.isfinite(steer_rate) and 0 < steer_rate <= 1.0):
        raise InputError("--steer-rate", "a steering-rate amplitude in (0, 1] rad/s", steer_rate)
    started = time.perf_counter()
    rigs = [hitch_lengths] + ([hitch_lengths[-1:]] if reference and len(hitch_lengths) > 1 else [])
    out = {"study": "trailer train", "nominal": {"duration_s": DURATION_S, "speed_m_s": SPEED, "ramp_s": RAMP_S,
                                                  "steer_rate_amplitude_rad_s": float(steer_rate),
                                                  "period_s": PERIOD_S, "grid_s": GRID_S},
           "trials": trials, "noise": noise, "process_per": process_per, "root_seed": root_seed, "rigs": []}
    seeds = trial_seeds(trials, root_seed)
    for lengths in rigs:
        out["rigs"].append(_rig(lengths, seeds, noise, process_per, steer_rate))
    out["wall_s"] = time.perf_counter() - started
    return out


def _rig(lengths: tuple, seeds, scale: float, process_per: str, steer_rate: float) -> dict:
    robot = robot_from_spec({"model": "car_trailer", "hitch_lengths": list(lengths)})
    model = robot.model
    forward, backward = s_curve(model, steer_rate)
    hitch = np.abs(model.hitch_angles(forward.x)).max(axis=0)
    phi = float(np.abs(forward.x[:, model.state_names.index("phi")]).max())
    rec = {"hitch_lengths_m": list(lengths), "trailers": len(lengths), "state_names": list(model.state_names),
           "jackknife_limit_rad": float(model.jackknife_limit), "max_steer_rad": float(model.max_steer),
           "nominal_max_hitch_rad": hitch.tolist(), "nominal_max_steer_rad": phi,
           "nominal_path_m": float(np.sum(np.hypot(*np.diff(forward.x[:, :2], axis=0).T)))}
    if phi > FEASIBLE_FRACTION * model.max_steer or hitch.max() > FEASIBLE_FRACTION * model.jackknife_limit:
        raise InputError("--hitch-lengths", f"a rig whose S-curve keeps the steering and hitch angles within "
                         f"{FEASIBLE_FRACTION:g} of their limits", list(lengths),
                         detail=f"steering {phi:.3f} of {model.max_steer:.3f} rad, hitch angles "
                                f"{', '.join(f'{h:.3f}' for h in hitch)} of {model.jackknife_limit:.3f} rad")
    noise = NoiseOptions(scale=scale, process_per=process_per)
    stab = robot.stabilizer.as_dict()
    rec["stabilizer"] = stab
    cells = []
    for direction, nom in (("forward", forward), ("reversed", backward)):
        for label, copts in LAWS:
            cell = {"direction": direction, "law": label}
            try:
                law = build_law(nom, copts, stab, robot=robot)
            except PipelineError as exc:
                cell["error"] = " ".join(str(exc).split())
                cells.append(cell)
                continue
            cell["max_gain_norm"] = float(law.info["max_gain_norm"])
            if law.schedule is not None:
                cell["min_gramian_eigenvalue"] = float(np.min(law.schedule.H_eigenvalues))
            cell.update(_trials(law, seeds, noise, robot))
            cells.append(cell)
    rec["cells"] = cells
    return rec


def _trials(law, seeds, noise, robot) -> dict:
    model = robot.model
    sim = simulate_shared(law, seeds, noise, model=model)
    K = len(seeds)
    hitch = np.abs(model.hitch_angles(sim.x.reshape(-1, model.n))).reshape(K, len(sim.t), -1).max(axis=(1, 2))
    jack = ~(hitch <= model.jackknife_limit)           # NaN (a failed trial) counts as a jackknife
    last = robot.body_poses(sim.x_final)[:, -1, :2] - robot.body_poses(sim.x0[-1])[-1, :2]
    err = np.hypot(last[:, 0], last[:, 1])[~jack]
    return {"trials": K, "jackknifes": int(jack.sum()), "diverged": int((~sim.completed).sum()),
            "final_last_axle_error_median_m": float(np.median(err)) if len(err) else None,
            "final_last_axle_error_p99_m": float(np.quantile(err, 0.99)) if len(err) else None,
            "median_max_hitch_rad": float(np.median(np.where(np.isfinite(hitch), hitch, np.pi)))}


def train_markdown(result: dict) -> str:
    """The study as markdown, every number from ``result``."""
    n = result["nominal"]
    lines = ["# A car with trailers under the feedback laws, forward and reversed", "",
             "Produced by `nhstab trailer train` (nhstab.batch.train_study). nhstab plans a car with one trailer; "
             "the laws and the run loop take more. Here the rig drives an S-curve from a straight rest "
             f"({n['duration_s']:g} s at {n['speed_m_s']:g} m/s, ramped over {n['ramp_s']:g} s at both ends, "
             f"steering rate {n['steer_rate_amplitude_rad_s']:g} sin(2 pi t / {n['period_s']:g} s)), and then backs "
             f"its trailers along the same path (the motion reversed in time). {result['trials']} trials of the run "
             f"loop per direction and law at noise x{result['noise']:g} (the process disturbance per "
             f"{result['process_per']}; seeds spawned from {result['root_seed']}); no obstacles. Jackknife = a hitch "
             "angle beyond the limit at "
             "some sample. Final error = the last trailer's axle from its nominal end, over the trials that did not "
             "jackknife.", ""]
    for rig in result["rigs"]:
        lengths = ", ".join(f"{d:g}" for d in rig["hitch_lengths_m"])
        hitches = ", ".join(f"{h:.3f}" for h in rig["nominal_max_hitch_rad"])
        lines += [f"## {rig['trailers']} trailer(s), hitch lengths {lengths} m",
                  "", f"The nominal: {rig['nominal_path_m']:.1f} m, steering up to {rig['nominal_max_steer_rad']:.3f} "
                  f"of {rig['max_steer_rad']:.3f} rad, hitch angles up to {hitches} of "
                  f"{rig['jackknife_limit_rad']:.3f} rad. "
                  f"The gramian law: alpha {rig['stabilizer']['alpha']:g}, delta {rig['stabilizer']['delta']:g} s, "
                  f"gamma {rig['stabilizer']['gamma']:g}.", "",
                  "| direction | law | jackknifes | final error median / p99 [m] | median max hitch [rad] "
                  "| max gain norm | smallest gramian eigenvalue |", "|---|---|---|---|---|---|---|"]
        for c in rig["cells"]:
            if "error" in c:
                lines.append(f"| {c['direction']} | {c['law']} | no law: {c['error']} | | | | |")
                continue
            lines.append(f"| {c['direction']} | {c['law']} | {c['jackknifes']}/{c['trials']} | "
                         f"{_f(c['final_last_axle_error_median_m'], '.3f')} / "
                         f"{_f(c['final_last_axle_error_p99_m'], '.3f')} | "
                         f"{c['median_max_hitch_rad']:.3f} | {c['max_gain_norm']:.3g} | "
                         f"{_f(c.get('min_gramian_eigenvalue'), '.3g')} |")
        lines.append("")
    lines.append(f"Wall time: {result['wall_s']:.0f} s.")
    return "\n".join(lines) + "\n"
