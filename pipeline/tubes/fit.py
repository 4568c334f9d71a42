"""Plans that fit their tube: ``--margin auto``, ``--fit`` and ``--gains auto``, which plan again or choose gains
until the error tube is certified clear."""

from __future__ import annotations

import hashlib
from dataclasses import replace

import numpy as np

from ..bodies import configuration_clearance
from ..collision import CollisionWorld
from ..errors import InputError, NumericalError, PipelineError
from ..execution.config import NoiseOptions
from ..execution.controllers import ControllerOptions, build_law
from ..geometry import Footprint
from ..planning import plan
from .base import DEFAULT_PROBABILITY, tube_needs, verdict
from .predict import predict_tube

#: ``--margin auto``: the first margin tried [m], the rounds at most, and the room added to a deficit [m]
AUTO_MARGIN_START = 0.02


AUTO_MARGIN_ROUNDS = 5


AUTO_MARGIN_SLACK = 0.01


#: ``--gains auto``: the grid, as factors of the robot's default alpha and delta, and gamma values
AUTO_GAINS_ALPHA = (0.5, 1.0, 2.0)


AUTO_GAINS_DELTA = (0.5, 1.0, 2.0)


AUTO_GAINS_GAMMA = (0.5, 1.0, 2.0)


#: ``--gains auto`` admits settings whose run saturation bound is below this
AUTO_GAINS_MAX_SATURATION = 0.01


def plan_with_auto_margin(plan_at, tube_of, world, fp: Footprint, *, cap: float,
                          start: float = AUTO_MARGIN_START, rounds: int = AUTO_MARGIN_ROUNDS,
                          slack: float = AUTO_MARGIN_SLACK):
    """``--margin auto``: plan at a small margin, predict the tube, and while its certified clearance is
    negative replan with the margin the failing samples need, a few rounds at most.

    ``plan_at(margin)`` -> (PlanResult, FeedbackLaw or None); ``tube_of(law)`` -> a :class:`Tube` with a
    certified clearance against ``world`` (or None if the linearised loop diverges); ``cap``: the
    largest margin the request allows (the start's and goal's clearance, less 1 mm).

    After each plan, the samples whose grown footprint is not clear (:func:`failing_samples`) are split:
    those whose reach exceeds cap - slack cannot be certified by any margin the request allows (a tube
    wider than the start's or goal's own clearance, typically right at them); the others are fixable,
    and the next margin is max(m + slack, their largest reach + slack), so that a nominal keeping it
    certifies them if the tube stays as wide. A margin that finds no plan is bisected with the largest
    margin that found one. The loop stops when no fixable sample fails, when the margin cannot grow, or
    after ``rounds`` plans. The plan kept: the smallest margin with no fixable failure, else the one
    whose fixable samples come closest to clear. Returns (result, law, tube, record) (the failed first
    result and law None if no round found a plan; the first plan with tube None, not certified, if its
    linearised loop diverges); ``record`` says what happened."""
    history, cands, last = [], [], None
    record = {"mode": "auto", "rounds": history, "start_margin_m": min(start, cap), "cap_m": cap,
              "max_rounds": rounds, "slack_m": slack}
    margin = min(start, cap)
    ok_margin, fail_margin = None, None
    for i in range(rounds):
        result, law = plan_at(margin)
        entry = {"round": i, "margin_m": margin, "status": result.status}
        last = result
        history.append(entry)
        if law is None:
            entry["message"] = result.message
            if ok_margin is None:
                break
            fail_margin = margin if fail_margin is None else min(fail_margin, margin)
            if fail_margin - ok_margin < 2 * slack:
                entry["stopped"] = f"no plan at margin {fail_margin:.3g} m"
                break
            margin = 0.5 * (ok_margin + fail_margin)
            continue
        tube = tube_of(law)
        if tube is None:
            entry["stopped"] = "no tube: the linearised closed loop diverges"
            if not cands:               # the plan stands, its margin not chosen by a tube
                record.update(margin_m=margin, certified=False, certified_clearance_m=None,
                              message=f"margin auto: NOT certified: no tube at margin {margin:.3g} m (the "
                                      "linearised closed loop diverges under the law); kept that plan")
                return result, law, None, record
            break
        idx, need, gap = tube_needs(tube, world, fp) if tube.certified_clearance < 0 else \
            (np.zeros(0, dtype=int), np.zeros(0), np.zeros(0))
        pinned = need + slack > cap
        fix_gap = float(gap[~pinned].min()) if np.any(~pinned) else 0.0
        entry.update(certified_clearance_m=tube.certified_clearance,
                     nominal_min_clearance_m=result.metrics.get("min_clearance_m"),
                     max_reach_m=float(tube.reach.max()), failing_samples=int(len(idx)),
                     failing_beyond_cap=int(pinned.sum()), fixable_clearance_m=fix_gap)
        if pinned.any():
            entry["beyond_cap_times_s"] = [float(tube.t[idx[pinned]].min()), float(tube.t[idx[pinned]].max())]
            entry["beyond_cap_max_reach_m"] = float(need[pinned].max())
        cands.append(((1, -margin) if fix_gap >= 0.0 else (0, fix_gap), margin, result, law, tube, entry))
        if fix_gap >= 0.0 or i == rounds - 1:
            break
        ok_margin = margin if ok_margin is None else max(ok_margin, margin)
        nxt = min(cap, max(margin + slack, float(need[~pinned].max()) + slack))
        if fail_margin is not None and nxt >= fail_margin:
            if fail_margin - margin < 2 * slack:
                entry["stopped"] = f"no plan at margin {fail_margin:.3g} m"
                break
            nxt = 0.5 * (margin + fail_margin)
        if nxt <= margin + 1e-9:
            entry["stopped"] = f"the margin cannot grow past {cap:.3g} m (the start's or goal's clearance)"
            break
        margin = nxt
    if not cands:
        record.update(margin_m=None, certified=False,
                      message="margin auto: " + (history[-1].get("stopped")
                                                 or f"no plan at margin {history[-1]['margin_m']:.3g} m"))
        return last, None, None, record
    _, margin, result, law, tube, chosen = max(cands, key=lambda c: c[0])
    ok = tube.certified_clearance >= 0.0
    trail = ", ".join(f"{h['margin_m']:.3g} m -> " + (f"{h['certified_clearance_m']:+.3f} m" if "certified_clearance_m" in h
                                                       else h["status"]) for h in history)
    if ok:
        text = (f"margin auto: certified at margin {margin:.3g} m (tube clearance {tube.certified_clearance:+.3f} m "
                f"at p = {tube.probability:g}) after {len(history)} round(s): {trail}")
    elif chosen["fixable_clearance_m"] >= 0.0:
        a, b = chosen["beyond_cap_times_s"]
        text = (f"margin auto: margin {margin:.3g} m certifies every sample it can; NOT certified at "
                f"{chosen['failing_beyond_cap']} sample(s) in t = {a:.2f}-{b:.2f} s, where the tube reaches "
                f"{chosen['beyond_cap_max_reach_m']:.3f} m but the start's or goal's clearance allows a margin of "
                f"{cap:.3g} m at most (tube clearance {tube.certified_clearance:+.3f} m); rounds: {trail}")
    else:
        why = next((h["stopped"] for h in reversed(history) if "stopped" in h), f"{len(history)} rounds used")
        text = (f"margin auto: NOT certified ({why}); kept margin {margin:.3g} m, the closest to clear: tube clearance "
                f"{tube.certified_clearance:+.3f} m at t = {tube.t[tube.certified_index]:.2f} s; rounds: {trail}")
    record.update(margin_m=margin, certified=ok, certified_clearance_m=tube.certified_clearance,
                  certified_where_possible=bool(chosen["fixable_clearance_m"] >= 0.0), message=text)
    return result, law, tube, record


#: ``--fit``: the plans tried at most after the first (a margin that certifies, then other maneuvers)
FIT_TRIES = 4


def fit_plan(plan_at, tube_of, world, fp: Footprint, *, margin: float, cap: float, first, tries: int = FIT_TRIES,
             slack: float = AUTO_MARGIN_SLACK):
    """``--fit``: when the first plan's tube is not certified clear, change the plan until one is, cheapest
    first, and keep the best found.

    1. **The margin the tube needs**, where the room allows: a plan at the tube verdict's needed margin
       (the largest reach among the samples whose grown footprint is not clear) plus ``slack``, if that
       is below ``cap`` (the start's and goal's own clearance).
    2. **Halfway**: when that margin finds no plan, or a plan whose tube is less clear than the best so
       far (a larger margin can force a different maneuver, with more cusps or slower pieces, whose
       tube is wider), a plan at the margin halfway between the best plan's and that one.
    3. **Another maneuver**: plans with other seeds (``plan_at(margin, k)`` for k = 1, 2, ...) at the
       margin of the best plan so far, a different path through the same space (the car planner also
       falls back to its full steering range where its reserved lock finds nothing). A seed that
       gives a plan already tried (the same nominal) is recorded as such and its tube not predicted
       again.

    Each try is judged by its own tube. Two other remedies are not tried: slowing the nominal near
    obstacles and before cusps (process noise per second grows per second while a car corrects a lateral
    error per metre driven, so a slower car collides more often; per metre travelled it brings no more
    disturbance per metre) and other gain settings (gamma 2, delta 3 s
    or alpha x 3 are worse on parking plans, or singular). ``plan_at(margin, k)`` -> (PlanResult, FeedbackLaw or None);
    ``tube_of(law)`` -> a Tube with its verdict, or None; ``first`` = (result, law, tube) at ``margin``.
    Returns (result, law, tube, margin, record); the record lists every try."""
    result, law, tube = first
    rows = [{"try": "the plan", "margin_m": margin, "seed_offset": 0, "status": result.status,
             "certified_clearance_m": None if tube is None else tube.certified_clearance}]
    record = {"tries": rows, "max_tries": tries}
    if law is None or tube is None or tube.certified is not False:
        record.update(chosen=0, certified=None if tube is None else tube.certified,
                      message="fit: nothing to do" + ("" if tube is None or tube.certified is None
                                                       else " (the plan's tube is certified clear)"))
        return result, law, tube, margin, record
    cands = [(tube.certified_clearance, 0, result, law, tube, margin)]
    seen = {_plan_key(result): 0}

    def best():
        return max(cands, key=lambda c: (c[4].certified is True, c[0]))

    def attempt(label, mg, k):
        """Plan and judge one try: (found a plan, its tube is certified, its tube clearance or None)."""
        r, lw = plan_at(mg, k)
        row = {"try": label, "margin_m": mg, "seed_offset": k, "status": r.status, "certified_clearance_m": None}
        rows.append(row)
        if lw is None:
            return False, False, None
        key = _plan_key(r)
        if key in seen:
            j = seen[key]
            row.update(status=f"the same plan as try {j}", certified_clearance_m=rows[j]["certified_clearance_m"])
            return True, False, rows[j]["certified_clearance_m"]
        seen[key] = len(rows) - 1
        tb = tube_of(lw)
        if tb is None or tb.certified_clearance is None:
            return True, False, None
        row["certified_clearance_m"] = tb.certified_clearance
        cands.append((tb.certified_clearance, len(rows) - 1, r, lw, tb, mg))
        return True, tb.certified is True, tb.certified_clearance

    v = tube.info.get("verdict") or verdict(tube, world, fp, margin)
    need = v.get("needed_margin_m")
    left, done = tries, False
    if need is not None and left > 0:
        want = min(need + slack, cap)
        if want > margin + 1e-9:
            base = best()[0]
            found, done, clearance = attempt(f"margin {want:.3g} m (the tube's need)", want, 0)
            left -= 1
            worse = not found or clearance is None or clearance < base
            below = best()[5]
            if not done and worse and left > 0 and want - below > 2 * slack:
                half = 0.5 * (below + want)
                _, done, _ = attempt(f"margin {half:.3g} m (halfway)", half, 0)
                left -= 1
    k = 1
    while left > 0 and not done:
        _, done, _ = attempt(f"another maneuver (seed + {k}) at margin {best()[5]:.3g} m", best()[5], k)
        left -= 1
        k += 1
    clearance, i, result, law, tube, mg = best()
    record.update(chosen=i, certified=bool(tube.certified), margin_m=mg)
    trail = "; ".join(f"{r['try']}: " + (f"{r['certified_clearance_m']:+.3f} m" if r["certified_clearance_m"] is not None
                                         else r["status"]) for r in rows)
    record["message"] = (f"fit: {'certified' if tube.certified else 'NOT certified'} after {len(rows)} plan(s), "
                         f"kept {rows[i]['try']} (tube clearance {clearance:+.3f} m); {trail}")
    return result, law, tube, mg, record


def _plan_key(result) -> tuple:
    """A plan's identity for ``--fit``: its nominal's grid and states (two seeds can find the same path)."""
    nom = result.nominal
    return (len(nom.t), float(nom.t[-1]), hashlib.sha1(np.ascontiguousarray(nom.x).tobytes()).hexdigest())


def choose_gains(nominal, defaults: dict, tube_of, window: str = "future", *,
                 alphas=AUTO_GAINS_ALPHA, deltas=AUTO_GAINS_DELTA, gammas=AUTO_GAINS_GAMMA,
                 max_saturation: float = AUTO_GAINS_MAX_SATURATION):
    """``--gains auto``: the gramian law's (alpha, delta, gamma) for this nominal from a small grid
    (alpha and delta as factors of the robot's defaults, gamma as given), minimising the tube's mean
    reach over the samples subject to a run saturation bound below ``max_saturation``. Settings whose
    window does not fit the nominal or whose gramian is singular are skipped. ``tube_of(law)`` -> Tube
    (no world needed). Returns (law, record); if no setting meets the saturation bound, the one with
    the smallest bound, and the record says so."""
    rows, best, fallback = [], None, None
    for fa in alphas:
        for fd in deltas:
            for g in gammas:
                a, d = float(defaults["alpha"]) * fa, float(defaults["delta"]) * fd
                row = {"alpha": a, "delta": d, "gamma": float(g)}
                try:
                    law = build_law(nominal, ControllerOptions(kind="gramian", window=window, alpha=a, delta=d,
                                                               gamma=float(g)), defaults)
                    tube = tube_of(law)
                except PipelineError as exc:
                    row["skipped"] = " ".join(str(exc).split())[:160]
                    rows.append(row)
                    continue
                row.update(mean_reach_m=float(tube.reach.mean()), max_reach_m=float(tube.reach.max()),
                           saturation_probability=tube.saturation["run_bound"],
                           max_gain_norm=law.info.get("max_gain_norm"))
                rows.append(row)
                key = (row["mean_reach_m"], row["saturation_probability"])
                if row["saturation_probability"] < max_saturation and (best is None or key < best[0]):
                    best = (key, row, law)
                if fallback is None or row["saturation_probability"] < fallback[0]:
                    fallback = (row["saturation_probability"], row, law)
    default_row = next((r for r in rows if r["alpha"] == float(defaults["alpha"]) and r["delta"] == float(defaults["delta"])
                        and r["gamma"] == float(defaults["gamma"])), None)
    if best is None and fallback is None:
        raise InputError("--gains", "a gain grid with at least one usable setting for this nominal", "auto",
                         detail="every setting was skipped: " + (rows[-1].get("skipped", "") if rows else ""))
    chosen = best if best is not None else fallback
    row, law = chosen[1], chosen[2]
    met = best is not None
    text = (f"gains auto: alpha {row['alpha']:g}, delta {row['delta']:g} s, gamma {row['gamma']:g}: mean reach "
            f"{row['mean_reach_m']:.3f} m, saturation bound {row['saturation_probability']:.3g}")
    if default_row is not None and "mean_reach_m" in default_row:
        text += (f" (defaults alpha {default_row['alpha']:g}, delta {default_row['delta']:g}, gamma "
                 f"{default_row['gamma']:g}: {default_row['mean_reach_m']:.3f} m, "
                 f"{default_row['saturation_probability']:.3g})")
    if not met:
        text += f"; NO setting has a saturation bound below {max_saturation:g}: kept the smallest"
    record = {"mode": "auto", "chosen": {k: row[k] for k in ("alpha", "delta", "gamma")}, "objective": "mean reach",
              "max_saturation": max_saturation, "met": met, "default": default_row, "grid": rows, "message": text}
    return law, record


#: the refusal of ``margin: auto`` for a robot of several bodies (a car with trailers)
SEVERAL_BODIES = ("a margin in metres for a robot of several bodies (margin auto grows one footprint's margin by "
                  "the error tube's reach; it is for one-body robots)")


def plan_and_tube(m, robot, start, goal, path_options, timing_options, *, margin="auto",
                  gains: str = "default", noise=None, probability: float = DEFAULT_PROBABILITY,
                  rate_hz: float = 50.0, substeps: int = 4, world=None, plan_robot=None, tube_kind: str = "auto",
                  confidence: float | None = None, fit: bool = False):
    """``nhstab plan`` with its tube: plan (``margin`` a number, or "auto" for
    :func:`plan_with_auto_margin`), the gramian law with the robot's default parameters (``gains``
    "auto": :func:`choose_gains`), and the error tube under ``noise`` (a NoiseOptions; default: the run's
    default noise) at ``rate_hz``, certified against the map's known obstacles. ``robot`` is the real
    robot (a :class:`~nhstab.robot.Robot`: its limits, footprint, stabilizer defaults), ``plan_robot``
    the one the nominal is planned for (derated for headroom; default ``robot``). ``tube_kind`` and
    ``confidence``: the tube's kind and its certificate's confidence (:func:`predict_tube`); the tube
    carries its :func:`verdict`. ``fit``: an uncertified plan is changed by :func:`fit_plan` (record in
    ``extra["fit"]``).

    Returns (result, law, tube, extra) with extra = {"tube_model": ..., "margin_auto": ..., "gains_auto": ...,
    "tube_error": ...} (the records that apply); law and tube are None when no plan was found, the tube alone
    (with "tube_error" saying why) when the linearised loop diverges under the law."""


    if gains not in ("default", "auto"):
        raise InputError("--gains", "default or auto", gains)
    plan_robot = plan_robot or robot
    model, fp = plan_robot.model, robot.footprint
    noise = NoiseOptions() if noise is None else noise
    noise.validated(model.state_names)
    several = len(robot.footprints) > 1           # a car with trailers: every body certified on rollouts
    if several and margin == "auto":
        raise InputError("--margin", SEVERAL_BODIES, margin)
    world = world or CollisionWorld.from_map(m, "known")
    defaults = robot.stabilizer.as_dict()
    extra = {"tube_model": {"noise": noise.describe(model.state_names), "rate_hz": rate_hz, "substeps": substeps,
                            "input_limits": robot.model.input_limits()[:, 1].tolist(),
                            "controller": "gramian, future window",
                            "initial_error": "the noise's initial error about the nominal's start"}}
    path_options = path_options.for_robot(plan_robot)
    clear = [configuration_clearance(world, robot, p) for p in (start, goal)]

    def tube_of(law, certify=True):
        try:
            tube = predict_tube(law, noise, fp, world if certify else None, rate_hz=rate_hz,
                                substeps=substeps, model=robot.model, probability=probability,
                                kind=tube_kind if certify else "linear", confidence=confidence, robot=robot)
        except NumericalError as exc:
            if not certify:
                raise                       # choose_gains skips the setting
            extra["tube_error"] = str(exc)  # the plan stands; its tube could not be predicted
            return None
        if certify:
            verdict(tube, world if tube.certified is not None else None, fp, state["margin"], cap=min(clear))
        return tube

    state = {"margin": None}

    def plan_at(mg, k=0):
        state["margin"] = mg
        opts = replace(path_options, margin=mg, seed=(path_options.seed + k) % (2**31 - 1))
        result = plan(m, plan_robot, start, goal, opts, timing_options, world=world)
        if not result.ok:
            return result, None
        if gains == "auto":
            law, record = choose_gains(result.nominal, defaults, lambda lw: tube_of(lw, certify=False))
            extra["gains_auto"] = record
        else:
            law = build_law(result.nominal, ControllerOptions(kind="gramian"), defaults, result.schedule)
        return result, law

    if margin == "auto":
        result, law, tube, record = plan_with_auto_margin(plan_at, tube_of, world, fp, cap=min(clear) - 1e-3)
        extra["margin_auto"] = record
        used = record["margin_m"]
    else:
        result, law = plan_at(margin)
        tube, used = (tube_of(law) if law is not None else None), margin
    if fit and law is not None and tube is not None and tube.certified is False:
        result, law, tube, used, record = fit_plan(plan_at, tube_of, world, fp, margin=used, cap=min(clear) - 1e-3,
                                                   first=(result, law, tube))
        extra["fit"] = record
        if margin == "auto":
            extra["margin_auto"]["margin_m"] = used
        else:
            extra["fit_margin_m"] = used
        state["margin"] = used
    return result, law, tube, extra
