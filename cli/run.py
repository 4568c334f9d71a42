"""``nhstab run``: the composite controller on a map, with noise, sensing, monitoring and replanning."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import click

from .map import load, map_options, parse_pose, pose_keys
from .options import cli_robot, effective_doc, effective_yaml, out_option, robot_options

#: exit codes: the run ended but did not reach the goal (collision, replan failed, ...); no first plan; a
#: plan refused because its error tube is not certified clear (--require-certified)
EXIT_NOT_REACHED = 4
EXIT_NO_PLAN = 3
EXIT_NOT_CERTIFIED = 5
EXIT_INTERRUPTED = 130


def parse_levels(name: str, text: str | None) -> dict | None:
    """``x=0.02,y=0.02,theta=0.01`` -> {"x": 0.02, ...}."""
    from nhstab.errors import InputError

    if text is None:
        return None
    out = {}
    for part in text.replace(" ", "").split(","):
        key, sep, value = part.partition("=")
        try:
            out[key] = float(value)
        except ValueError:
            raise InputError(name, "state=value pairs separated by commas, e.g. x=0.02,y=0.02,theta=0.01",
                             text) from None
        if not sep or not key:
            raise InputError(name, "state=value pairs separated by commas, e.g. x=0.02,y=0.02,theta=0.01", text)
    return out


@click.command()
@click.argument("map_file", metavar="MAP", required=False, type=click.Path(path_type=Path))
@click.option("--config", "config_file", type=click.Path(path_type=Path), default=None,
              help="Run config (YAML) giving any option; the command line overrides it.")
@robot_options
@click.option("--start", default=None, help="Start: the pose x,y,theta (a car_trailer may add its trailer angle theta1), or the robot's full state in its state order with phi = 0, e.g. rwd_car x,y,theta,0 (default: the map's).")
@click.option("--goal", default=None, help="Goal: the pose x,y,theta (a car_trailer may add its trailer angle theta1), or the robot's full state in its state order with phi = 0, e.g. rwd_car x,y,theta,0 (default: the map's).")
@click.option("--problem", type=int, default=None, help="Use the map's start/goal problem with this index.")
@click.option("--controller", default=None, help="gramian (default), tvlqr or open-loop.")
@click.option("--window", default=None,
              help="The gramian's window: future (default, Proposition 1), frozen-time (causal: no future nominal "
                   "needed) or past (Remark 2: not stabilizing in general, for study only).")
@click.option("--alpha", type=float, default=None, help="Gramian law: rate parameter (default: the robot's).")
@click.option("--delta", type=float, default=None, help="Gramian law: window length [s] (default: the robot's).")
@click.option("--gamma", type=float, default=None, help="Gramian law: gain factor >= 1/2 (default: the robot's).")
@click.option("--rate", "rate_hz", type=float, default=None, help="Controller rate [Hz] (default 50).")
@click.option("--noise", "noise_scale", type=float, default=None,
              help="Multiply every noise level by this (0: noiseless; default 1).")
@click.option("--initial-error", default=None, help="Initial error std per state, e.g. x=0.1,y=0.1,theta=0.05.")
@click.option("--sensor-std", default=None, help="Measurement noise std per state, e.g. x=0.02,y=0.02,theta=0.01.")
@click.option("--process-std", default=None,
              help="Process disturbance per state [unit/sqrt(s)], or [unit/sqrt(m)] with --process-per metre.")
@click.option("--process-per", type=click.Choice(["second", "metre"]), default=None,
              help="The process disturbance acts per second (default: at rest too) or per metre the robot "
                   "travels (none at rest: wheel slip and ground, not a push) (noise.process.per).")
@click.option("--seed", type=int, default=None, help="Root seed of the run (default 0).")
@click.option("--planner", default=None, help="OMPL planner (default rrtconnect).")
@click.option("--time-limit", type=float, default=None, help="Budget of each planning call [s] (default 2).")
@click.option("--guide/--no-guide", default=None,
              help="Guided search (default) or OMPL's planner over the whole map (planning.guide).")
@click.option("--margin", default=None,
              help="Clearance nominals keep from known obstacles [m] (default: the robot's margin), "
                   "or auto: per plan, the smallest margin whose error tube is certified clear.")
@click.option("--gains", default=None,
              help="default, or auto: the gramian law's alpha, delta, gamma chosen per plan (narrowest error tube "
                   "with a saturation probability under 1 %).")
@click.option("--tvlqr-q", "tvlqr_q", type=click.Choice(["footprint"]), default=None,
              help="With --controller tvlqr: Q from how far a state error moves the robot's outline (controller.q: "
                   "footprint; default: the config's, else the identity).")
@click.option("--fit", is_flag=True, default=None,
              help="When a plan's error tube is not certified clear, try the margin it needs and other maneuvers, "
                   "and follow the best (planning.fit).")
@click.option("--tube", "tube_kind", type=click.Choice(["auto", "linear", "sampled"]), default=None,
              help="Error tube of every plan: auto (default: linear where inputs do not saturate and the plan has "
                   "no stop, else sampled rollouts of the run loop), linear or sampled.")
@click.option("--probability", type=float, default=None, help="Probability p of the error tube (default 0.997).")
@click.option("--confidence", type=float, default=None,
              help="Confidence of the sampled tube's certificate (default 0.95: N >= ln(0.05) / ln(p) rollouts).")
@click.option("--require-certified", is_flag=True, default=None,
              help="Refuse a plan whose error tube is not certified clear: the robot does not follow it, the run "
                   "ends not_certified (exit code 5).")
@click.option("--cusp-replan/--no-cusp-replan", default=None,
              help="At each cusp, replan the rest of the maneuver from the measured state when its tube is not "
                   "certified clear (default on).")
@click.option("--max-time", type=float, default=None, help="Simulated time limit [s].")
@out_option("run", "run.json, trajectory.csv and the figures")
@click.option("--animate", is_flag=True, help="Also write run.gif.")
@click.option("--print-config", is_flag=True,
              help="Print the effective run config (YAML: the map, robot, start, goal and every option, its "
                   "defaults filled in) and exit without running; --config runs it as printed.")
@map_options
def run(map_file, config_file, robot, robot_config, start, goal, problem, controller, window, alpha, delta, gamma,
        rate_hz, noise_scale, initial_error, sensor_std, process_std, process_per, seed, planner, time_limit, guide,
        margin, gains, tvlqr_q, fit, tube_kind, probability, confidence, require_certified, cusp_replan, max_time,
        out_dir, animate, print_config, cell_size, unknown):
    """Run the composite controller on MAP: plan, stabilize under noise, sense, monitor with FCL, replan.

    Writes run.json, trajectory.csv, run_map.png and run_tracking.png (and run.gif with --animate)
    into OUT (default out/run). Before the robot follows a plan, one line says whether its error tube is certified
    clear, at which probability, where it is tightest and what would certify it. Exit code 0 when the
    goal is reached, 4 when the run ended otherwise (collision, replan failed, timed out, missed goal,
    numerical failure), 5 when --require-certified refused a plan (run.json records the plan and its
    tube; the robot did not follow it), 3 when there was no first plan, 2 for bad input, 130 when
    interrupted (the files then describe the interrupted run; a Ctrl-C once the simulation has ended
    does not stop the writing: the files describe the run as it ended).
    """
    from nhstab.errors import InputError, user_keys
    from nhstab.execution.config import RunOptions, load_run_config, merge
    from nhstab.limits import (
        MAX_NOISE_SCALE,
        MAX_RATE_HZ,
        MAX_SEED,
        MIN_RATE_HZ,
        check_int,
        check_probability,
        check_range,
    )

    from .plan import parse_margin

    # the flags are checked under their own names (the config's keys are checked when merged)
    if seed is not None:
        check_int("--seed", seed, 0, MAX_SEED, "a non-negative integer")
    if rate_hz is not None:
        check_range("--rate", rate_hz, MIN_RATE_HZ, MAX_RATE_HZ, "Hz")
    margin = parse_margin("--margin", margin)
    if probability is not None:
        check_probability("--probability", probability)
    if confidence is not None and not (0.0 < confidence < 1.0):
        raise InputError("--confidence", "a number in (0, 1)", confidence)
    if noise_scale is not None:
        check_range("--noise", noise_scale, 0.0, MAX_NOISE_SCALE)
    if probability is not None or confidence is not None:
        from nhstab.tubes.base import DEFAULT_CONFIDENCE, rollouts_needed

        try:
            rollouts_needed(probability if probability is not None else 0.997,
                            confidence if confidence is not None else DEFAULT_CONFIDENCE)
        except InputError as exc:
            raise InputError("--confidence" if confidence is not None else "--probability", exc.expected,
                             confidence if confidence is not None else probability, detail=exc.detail) from None

    base, cfg_map = RunOptions(), None
    if config_file is not None:
        extra, base = load_run_config(config_file)
        cfg_map = extra.get("map")
        if str(extra.get("map_given", "")).startswith("example:"):
            cfg_map = extra["map_given"]          # a bundled map, by the name the config gives
    map_path = map_file or cfg_map
    if map_path is None:
        raise InputError("MAP", "a map file (argument or the config's `map`)", None)
    levels = {k: parse_levels(flag, v) for k, flag, v in
              (("initial", "--initial-error", initial_error), ("sensor", "--sensor-std", sensor_std),
               ("process", "--process-std", process_std))}
    noise = base.noise.merged(levels, noise_scale)
    if process_per is not None:
        noise = replace(noise, process_per=process_per)
    opts = merge(base, seed=seed, rate_hz=rate_hz, max_time_s=max_time, noise=noise,
                 controller__kind=controller, controller__window=window, controller__alpha=alpha,
                 controller__delta=delta, controller__gamma=gamma, controller__gains=gains, controller__q=tvlqr_q,
                 planning__planner=planner,
                 planning__time_limit_s=time_limit, planning__margin=margin, planning__guide=guide,
                 tube__kind=tube_kind, tube__probability=probability, tube__confidence=confidence,
                 tube__require_certified=require_certified, replan__at_cusps=cusp_replan, planning__fit=fit)
    if tvlqr_q is not None and opts.controller.kind != "tvlqr":
        from nhstab.errors import InputError

        raise InputError("--tvlqr-q", "given with the tvlqr controller (Q is TVLQR's)",
                         f"the {opts.controller.kind} controller")
    from nhstab.maps import resolve_poses

    m = load(map_path, cell_size, unknown)
    rob = cli_robot(robot, robot_config, opts.robot, m.robot, m)
    s, g = resolve_poses(m, parse_pose("--start", start) or opts.start, parse_pose("--goal", goal) or opts.goal,
                         problem, names=("--start", "--goal", "--problem"))
    s_key = "--start" if start is not None else f"start (in {config_file})" if opts.start is not None else "start"
    g_key = "--goal" if goal is not None else f"goal (in {config_file})" if opts.goal is not None else "goal"
    if problem is not None:
        s_key, g_key = "start", "goal"
    robot_key = ("--robot" if robot else "--robot-config" if robot_config else
                 f"robot (in {config_file})" if opts.robot is not None else f"robot.model (in {map_path})")
    # the options given on the command line name the errors about their values (the config's keys
    # name the rest)
    flags = {"seed": ("--seed", seed), "rate_hz": ("--rate", rate_hz), "max_time_s": ("--max-time", max_time),
             "noise.scale": ("--noise", noise_scale), "controller": ("--controller", controller),
             "controller.window": ("--window", window), "controller.alpha": ("--alpha", alpha),
             "controller.delta": ("--delta", delta), "controller.gamma": ("--gamma", gamma),
             "controller.gains": ("--gains", gains), "controller.q": ("--tvlqr-q", tvlqr_q),
             "planning.planner": ("--planner", planner),
             "planning.time_limit_s": ("--time-limit", time_limit), "planning.margin": ("--margin", margin),
             "tube.kind": ("--tube", tube_kind), "tube.probability": ("--probability", probability),
             "tube.confidence": ("--confidence", confidence)}
    names = {key: flag for key, (flag, value) in flags.items() if value is not None}
    names.update(pose_keys(m, start, goal, problem, opts.start, opts.goal))
    for kind, flag in (("initial", "--initial-error"), ("sensor", "--sensor-std"), ("process", "--process-std")):
        names.update({f"noise.{kind}.{state}": f"{flag} {state}" for state in levels[kind] or {}})
    with user_keys(names):
        if print_config:
            click.echo(effective_config(m, str(map_path), opts, rob, s, g, robot_key, (s_key, g_key)), nl=False)
            return 0
        return execute_and_write(m, str(map_path), opts, rob, s, g, out_dir, animate, robot_key=robot_key,
                                 pose_names=(s_key, g_key))


def effective_config(m, map_path: str, opts, robot, start, goal, robot_key: str = "robot",
                     pose_names: tuple[str, str] = ("start", "goal")) -> str:
    """The run config ``nhstab run`` would run (YAML): the map, the robot's full description, start,
    goal and every option with its defaults filled in; checked as a run checks it."""
    from nhstab.execution.config import config_mapping
    from nhstab.execution.runner import check_run

    doc = effective_doc(m, map_path, robot, start, goal, robot_key, pose_names)
    check_run(m, robot, opts)
    doc.update({k: v for k, v in config_mapping(opts, robot).items() if k not in doc})
    return effective_yaml("the effective run config: every option with its default filled in (nhstab run --config "
                          "FILE runs it)", doc)


def execute_and_write(m, map_path: str, opts, robot, start, goal, out_dir: Path, animate: bool,
                      robot_key: str = "robot", extra_files: dict | None = None,
                      pose_names: tuple[str, str] = ("start", "goal")) -> int:
    from nhstab.execution import execute, write_run
    from nhstab.interrupts import holding_interrupts, interrupt_held
    from nhstab.planning import check_plannable
    from nhstab.tubes.base import certified_text

    check_plannable(robot, robot_key)
    # a pose, or the full state with phi = 0 (Robot.configuration): refused here, under the name it was given by
    start, goal = robot.configuration(start, pose_names[0]), robot.configuration(goal, pose_names[1])
    from nhstab.execution.runner import check_run

    check_run(m, robot, opts)                # every option checked before anything runs
    click.echo(f"running {opts.controller.kind} control of {robot.name} on {m.name} (seed {opts.seed}) ...", err=True)
    result = execute(m, robot, start, goal, opts, notify=lambda line: click.echo(line, err=True))
    with holding_interrupts():      # from here a Ctrl-C does not lose the finished run: its files are completed
        files = write_run(result, out_dir, map_path, animate=animate, extra_files=extra_files)
    replans = sum(1 for p in result.plans if p.trigger != "initial")
    click.echo(f"{result.status}: {result.message}")
    if result.status == "no_plan" and result.plans and "likely_cause" in result.plans[0].attempts[-1]:
        click.echo(result.plans[0].attempts[-1]["likely_cause"]["text"])
    for rec in result.plans:
        for attempt in rec.attempts:
            for key in ("margin_auto", "gains_auto", "fit"):
                if key in attempt:
                    click.echo(f"plan {rec.id}: {attempt[key]['message']}")
        if rec.tube is not None:
            tb = rec.tube
            click.echo(f"plan {rec.id} ({rec.trigger}): {certified_text(tb, explain=True)} at p = {tb.probability:g} ({tb.kind} tube)")
        elif rec.law is not None:
            click.echo(f"plan {rec.id} ({rec.trigger}): no error tube (the closed loop diverges under the law)")
        checks = rec.cusp_checks
        if checks:
            clear = sum(1 for c in checks if c.get("certified"))
            adopted = sum(1 for c in checks if c.get("adopted"))
            click.echo(f"plan {rec.id}: {len(checks)} cusp check(s): the rest certified clear at {clear}, replanned at "
                       f"{sum(1 for c in checks if c.get('replanned'))} ({adopted} new plan(s) followed)")
    executed = json.loads((Path(out_dir) / "run.json").read_text()).get("clearance") or {}
    closest = (f"closest {executed['min_executed_m']:.3f} m to an obstacle at t = {executed['time_s']:.1f} s (margin "
               f"{executed['margin_m']:.3g} m), " if "min_executed_m" in executed else "")
    click.echo(f"{replans} replan(s), {len(result.discovered)} obstacle(s) discovered, {closest}"
               f"{result.log['t'][-1] if len(result.log['t']) else 0:.1f} s simulated in {result.wall_time_s:.1f} s")
    click.echo("wrote " + ", ".join(str(f) for f in files))
    if interrupt_held():
        click.echo(f"nhstab: interrupted after the run ended ({result.status}); its files are complete", err=True)
        return EXIT_INTERRUPTED
    if result.status == "reached":
        return 0
    if result.status == "no_plan":
        return EXIT_NO_PLAN
    if result.status == "interrupted":
        return EXIT_INTERRUPTED
    if result.status == "not_certified":
        return EXIT_NOT_CERTIFIED
    return EXIT_NOT_REACHED
